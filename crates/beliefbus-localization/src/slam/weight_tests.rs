//! The implicit SLAM step's weights against independent answers.
//!
//! One step from a known pose X, one return z. The particles are split into
//! groups that differ only in their map: a landmark at θ_A, one at θ_C (a
//! a quarter metre farther), or none (z starts a landmark). With equal prior
//! weights, the step's total weight of a group estimates that group's
//! predictive likelihood of z:
//!
//! ```text
//! known θ:  p(z | X, θ) = ∫ N(x; f, Σ₁) N(z; h(x, θ), Σ₂) dx        (brute force over prior draws)
//! new:      p(z | X)    = ∫ N(x; f, Σ₁) ∫ (1/A) N(z; h(x, θ), Σ₂) dθ dx = z_r / A   (polar Jacobian)
//! ```
//!
//! The weight rule W e^{−φ} e^{F̂−F}/det L with its normalisers (erratum
//! E8), the sign of the linear map's Jacobian, the 5-D joint draw of a new
//! feature and its flat-prior constant all enter these ratios; an error in
//! any of them moves a ratio by far more than the statistical bound used.

use super::assoc::{innovation, RangeBearing};
use super::implicit::{ImplicitSlam, SampledLandmark};
use super::{SlamFilter, SlamModel};
use crate::carpark::normal3;
use crate::geometry::Pose;
use crate::laser::{predict, LaserNoise};
use crate::mcl::newton::NewtonSettings;
use crate::vehicle::{Control, MotionNoise};
use beliefbus_core::rng::stream;
use nalgebra::Matrix2;

fn model() -> SlamModel {
    SlamModel {
        ute: Default::default(),
        // Table 7's intensities × 0.05: heading σ ≈ 0.03 rad per step, so
        // that the landmark's position given the pose is nearly Gaussian.
        motion: {
            let d = MotionNoise::default();
            MotionNoise {
                p: [d.p[0] * 0.05, d.p[1] * 0.05],
                q: [d.q[0] * 0.05, d.q[1] * 0.05, d.q[2] * 0.05],
            }
        },
        // Laser noise of the order of the one-step motion noise, so that
        // prior draws estimate p(z | X, θ) well.
        laser: LaserNoise {
            var_range: 0.01,
            var_bearing: 0.02f64.powi(2),
        },
        assoc: Default::default(),
        max_range: 15.0,
    }
}

/// log mean of exp(l) and its standard error (delta method).
fn log_mean_exp(l: &[f64]) -> (f64, f64) {
    let mx = l.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let e: Vec<f64> = l.iter().map(|v| (v - mx).exp()).collect();
    let n = e.len() as f64;
    let m = e.iter().sum::<f64>() / n;
    let var = e.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1.0);
    (mx + m.ln(), (var / n).sqrt() / m)
}

#[test]
fn implicit_step_weights_are_the_predictive_likelihoods_of_known_and_new_features() {
    let model = model();
    let (u, dt) = (Control { v: 3.0, alpha: 0.1 }, 0.025);
    let start = Pose::new(1.0, -2.0, 0.3);
    let (ute, noise) = model.step_noise(u, dt).unwrap();
    let f = ute.predict_mean(&start, u);
    let th_a = [f[0] + 6.0, f[1] + 5.0];
    let th_c = [th_a[0] + 0.2, th_a[1] + 0.15];
    let (r0, b0) = predict(&f, th_a);
    let z = RangeBearing {
        range: r0 + 0.05,
        bearing: b0 + 0.01,
    };

    // Brute force: p(z | X, θ) by prior draws, log N(z; h(x, θ), Σ₂).
    let r = model.r();
    let rinv = Matrix2::new(1.0 / r[(0, 0)], 0.0, 0.0, 1.0 / r[(1, 1)]);
    let norm = -(2.0 * std::f64::consts::PI).ln() - 0.5 * (r[(0, 0)] * r[(1, 1)]).ln();
    let mut rng = stream(11, 0);
    let k = 200_000;
    let (mut la, mut lc) = (Vec::with_capacity(k), Vec::with_capacity(k));
    let mut xs = Vec::with_capacity(k);
    for _ in 0..k {
        let x = f + noise.draw(start[2], &normal3(&mut rng));
        xs.push(x);
        for (th, out) in [(th_a, &mut la), (th_c, &mut lc)] {
            let (nu, _, _) = innovation(&x, th, &z);
            out.push(norm - 0.5 * nu.dot(&(rinv * nu)));
        }
    }
    let (exact_a, se_a) = log_mean_exp(&la);
    let (exact_c, se_c) = log_mean_exp(&lc);
    let exact_new = z.range.ln() + model.log_new_density();

    // The filter: three groups of n particles, no resampling.
    let n = 3000;
    let mut f_slam = ImplicitSlam::new(model, 3 * n, 0.0, NewtonSettings::default()).unwrap();
    f_slam.reset(&start);
    for j in 0..2 * n {
        let m = if j < n { th_a } else { th_c };
        f_slam.set.maps[j].push(SampledLandmark {
            m,
            cov: Matrix2::zeros(),
        });
    }
    let mut rng = stream(12, 0);
    f_slam.step(u, dt, &[z], &mut rng).unwrap();
    let st = f_slam.stats();
    assert_eq!((st.known, st.new, st.discarded), (2 * n, n, 0));
    let lw: Vec<f64> = f_slam.set.w.iter().map(|w| w.ln()).collect();
    let (ga, sa) = log_mean_exp(&lw[..n]);
    let (gc, sc) = log_mean_exp(&lw[n..2 * n]);
    let (gn, sn) = log_mean_exp(&lw[2 * n..]);
    // The new group's weights are nearly constant: the joint 5-D Laplace
    // proposal is close to the target where the heading is well known.
    assert!(sn < 0.01, "new-feature weights vary: se {sn}");
    let check = |what: &str, got: f64, want: f64, se: f64| {
        assert!(
            (got - want).abs() < 5.0 * se + 1e-3,
            "{what}: log ratio {got:.4} vs exact {want:.4} (5 se = {:.4})",
            5.0 * se
        );
    };
    check(
        "known A / new",
        ga - gn,
        exact_a - exact_new,
        (sa * sa + sn * sn + se_a * se_a).sqrt(),
    );
    check(
        "known C / new",
        gc - gn,
        exact_c - exact_new,
        (sc * sc + sn * sn + se_c * se_c).sqrt(),
    );
    check(
        "known A / known C",
        ga - gc,
        exact_a - exact_c,
        (sa * sa + sc * sc + se_a * se_a + se_c * se_c).sqrt(),
    );
    // The ratios are far from 1, so a wrong constant cannot pass by luck.
    assert!((exact_a - exact_new).abs() > 1.0 && (exact_a - exact_c).abs() > 0.3);

    // The pose posterior given θ_A: self-normalised prior draws against the
    // implicit draws of group A, coordinate by coordinate.
    for c in 0..3 {
        let (want, se_w) = weighted_mean(&la, xs.iter().map(|x| x[c]));
        let (got, se_g) = weighted_mean(&lw[..n], f_slam.set.x[..n].iter().map(|x| x[c]));
        let se = (se_w * se_w + se_g * se_g).sqrt();
        assert!(
            (got - want).abs() < 5.0 * se,
            "posterior mean {c}: {got:.5} vs {want:.5} (5 se = {:.5})",
            5.0 * se
        );
    }
}

/// Self-normalised weighted mean of `v` under log weights `l`, and its
/// standard error (delta method).
fn weighted_mean(l: &[f64], v: impl Iterator<Item = f64> + Clone) -> (f64, f64) {
    let mx = l.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let w: Vec<f64> = l.iter().map(|x| (x - mx).exp()).collect();
    let sw: f64 = w.iter().sum();
    let m = w.iter().zip(v.clone()).map(|(w, x)| w * x).sum::<f64>() / sw;
    let var = w
        .iter()
        .zip(v)
        .map(|(w, x)| (w * (x - m)).powi(2))
        .sum::<f64>()
        / (sw * sw);
    (m, var.sqrt())
}
