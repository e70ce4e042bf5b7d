//! The implicit-sampling weights are exact: constant for a Gaussian F, and
//! the normalising constant ∫e^{−F} they estimate agrees with plain
//! importance sampling from the prior on a non-Gaussian (range/bearing) F.

use beliefbus_core::rng::stream;
use beliefbus_localization::carpark::normal3;
use beliefbus_localization::geometry::Pose;
use beliefbus_localization::laser::{predict, term_cost, LaserNoise, Observation};
use beliefbus_localization::mcl::implicit::ImplicitMcl;
use beliefbus_localization::mcl::newton::{minimise, NewtonSettings, Objective};
use beliefbus_localization::mcl::{LaserStep, Localizer};
use beliefbus_localization::vehicle::{Control, MotionNoise, StepNoise, Ute};
use nalgebra::{Matrix3, Vector3};

/// With no laser return F^j is the Gaussian prior: μ = f^j, φ = 0 and the
/// linear map reproduces it exactly, so every particle gets the same weight
/// 1/det L, whatever ξ and wherever the particle is.
#[test]
fn gaussian_f_gives_constant_weights() {
    let ute = Ute::default();
    let u = Control { v: 3.0, alpha: 0.2 };
    let noise = StepNoise::new(&ute, u, &MotionNoise::default()).unwrap();
    let mut f = ImplicitMcl::new(50, 0.0, NewtonSettings::default()).unwrap();
    let mut rng = stream(3, 0);
    for (j, x) in f.set.x.iter_mut().enumerate() {
        *x = Pose::new(j as f64, -0.5 * j as f64, 0.13 * j as f64);
    }
    let laser = LaserNoise::default();
    let scan = LaserStep {
        ute: &ute,
        u,
        noise: &noise,
        obs: &[],
        map: &[],
        laser: &laser,
        step: 1,
    };
    f.update(&scan, &mut rng).unwrap();
    let m = f.set.len() as f64;
    for &w in &f.set.w {
        assert!((w - 1.0 / m).abs() < 1e-12, "{w}");
    }
    assert_eq!(f.set.resamplings, 0);
    // And directly: the weight ½ξᵀξ − F(X) − log det L is the same for every ξ.
    let obj = Objective {
        f: Pose::new(1.0, 2.0, 0.3),
        prec: noise.precision(0.3),
        obs: &[],
        map: &[],
        laser: LaserNoise::default(),
    };
    let min = minimise(&obj, &NewtonSettings::default(), 0).unwrap();
    let mut first = None;
    for _ in 0..100 {
        let xi = normal3(&mut rng);
        let x = min.mu + min.l.tr_solve_lower_triangular(&xi).unwrap();
        let lw = 0.5 * xi.dot(&xi) - obj.value(&x) - min.log_det_l;
        let w0 = *first.get_or_insert(lw);
        assert!((lw - w0).abs() < 1e-9, "{lw} vs {w0}");
    }
}

/// log ∫ e^{−F} by the linear map (mean of e^{½ξᵀξ − F(X)}/det L) and by
/// sampling the Gaussian prior part of F (mean of e^{−likelihood terms}):
/// two independent estimators of one number, within 5 standard errors.
#[test]
fn linear_map_weights_estimate_the_normaliser_of_a_nonlinear_f() {
    let map = [[6.0, 2.0], [4.0, -5.0]];
    let truth = Pose::new(0.0, 0.0, 0.0);
    let laser = LaserNoise::default();
    let obs: Vec<Observation> = map
        .iter()
        .enumerate()
        .map(|(i, &m)| {
            let (r, b) = predict(&truth, m);
            Observation {
                range: r + 0.15,
                bearing: b - 0.02,
                landmark: i,
            }
        })
        .collect();
    // Prior: std 0.25 m, 0.25 m, 0.08 rad, centred off the truth.
    let sd = Vector3::new(0.25, 0.25, 0.08);
    let prec = Matrix3::from_diagonal(&sd.map(|s| 1.0 / (s * s)));
    let f = Pose::new(0.2, -0.15, 0.05);
    let obj = Objective {
        f,
        prec,
        obs: &obs,
        map: &map,
        laser,
    };
    let n = 200_000;
    let mut rng = stream(11, 1);
    let log_mean_se = |lw: &[f64]| {
        let mx = lw.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let w: Vec<f64> = lw.iter().map(|l| (l - mx).exp()).collect();
        let m = w.iter().sum::<f64>() / w.len() as f64;
        let v = w.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (w.len() - 1) as f64;
        (mx + m.ln(), (v / w.len() as f64).sqrt() / m)
    };
    // Implicit: ∫e^{−F} = (2π)^{3/2} E_ξ[e^{½ξᵀξ − F(X)}] / det L.
    let min = minimise(&obj, &NewtonSettings::default(), 0).unwrap();
    let lw_imp: Vec<f64> = (0..n)
        .map(|_| {
            let xi = normal3(&mut rng);
            let x = min.mu + min.l.tr_solve_lower_triangular(&xi).unwrap();
            0.5 * xi.dot(&xi) - obj.value(&x) - min.log_det_l
        })
        .collect();
    let (li, se_i) = log_mean_se(&lw_imp);
    // Prior sampling: ∫e^{−F} = (2π)^{3/2} det(prec)^{−1/2} E_prior[e^{−lik}].
    let lw_pri: Vec<f64> = (0..n)
        .map(|_| {
            let x = f + sd.component_mul(&normal3(&mut rng));
            -obs.iter()
                .map(|o| term_cost(&x, map[o.landmark], o, &laser))
                .sum::<f64>()
        })
        .collect();
    let (lp, se_p) = log_mean_se(&lw_pri);
    let lp = lp - 0.5 * prec.determinant().ln();
    let se = (se_i * se_i + se_p * se_p).sqrt();
    assert!(se < 0.05, "estimators too noisy: {se_i} {se_p}");
    assert!(
        (li - lp).abs() < 5.0 * se,
        "implicit {li} vs prior {lp} (se {se})"
    );
    // The linear map's weights are far more even than the prior's.
    let ess = |lw: &[f64]| beliefbus_core::math::weights::ess_from_log(lw) / lw.len() as f64;
    assert!(
        ess(&lw_imp) > 0.5 && ess(&lw_imp) > 5.0 * ess(&lw_pri),
        "{} {}",
        ess(&lw_imp),
        ess(&lw_pri)
    );
}
