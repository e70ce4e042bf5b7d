//! The fast RBPF against exact filters on short mean-shift sequences: as M
//! grows its estimate converges to the exact posterior mean, for every
//! resampling scheme, with the tilted proposal, and with ρ ~ Beta(α, β)
//! integrated out (against an exact filter over (C_t, n₁) written here
//! independently of the crate's code).

use beliefbus_changepoint::meanshift::exact::ExactMeanShift;
use beliefbus_changepoint::meanshift::rbpf::{MeanShiftRbpf, RbpfConfig, RhoPrior};
use beliefbus_changepoint::meanshift::MeanShiftModel;
use beliefbus_changepoint::resample::Scheme;
use beliefbus_changepoint::rng;
use std::collections::HashMap;

const N: usize = 120;
const SEEDS: u64 = 12;

fn data(model: MeanShiftModel, seed: u64) -> Vec<f64> {
    let (mut mu, mut y) = (vec![], vec![]);
    model.simulate(N, &mut rng::stream(seed, 1), &mut mu, &mut y);
    y
}

/// Mean over seeds and steps of (μ̂_RBPF − reference)², and the mean
/// posterior spread of the reference (for scale).
fn mse_to(reference: &dyn Fn(&[f64]) -> Vec<f64>, model: MeanShiftModel, cfg: RbpfConfig) -> f64 {
    let mut acc = 0.0;
    for seed in 0..SEEDS {
        let y = data(model, seed);
        let exact = reference(&y);
        let mut f = MeanShiftRbpf::new(model, cfg, rng::stream(seed, 2)).unwrap();
        for (t, &yt) in y.iter().enumerate() {
            let e = f.step(yt).unwrap() - exact[t];
            acc += e * e;
        }
    }
    acc / (SEEDS as usize * N) as f64
}

fn exact_means(model: MeanShiftModel, y: &[f64]) -> Vec<f64> {
    let mut f = ExactMeanShift::new(model).unwrap();
    y.iter().map(|&v| f.step(v).unwrap()).collect()
}

/// Error variance of a particle estimate falls like 1/M: going from M = 50
/// to M = 1600 must cut it by well over the factor 8 allowed here (theory
/// 32), and at M = 1600 it must be tiny against the levels' scale (σ² = 1).
fn assert_converges(
    model: MeanShiftModel,
    cfg: RbpfConfig,
    what: &str,
    reference: &dyn Fn(&[f64]) -> Vec<f64>,
) {
    let small = mse_to(
        reference,
        model,
        RbpfConfig {
            particles: 50,
            ..cfg
        },
    );
    let large = mse_to(
        reference,
        model,
        RbpfConfig {
            particles: 1600,
            ..cfg
        },
    );
    assert!(
        small > 0.0,
        "{what}: a particle filter with 50 particles cannot be exact"
    );
    assert!(
        large < small / 8.0,
        "{what}: mse {small:.2e} at M=50 vs {large:.2e} at M=1600"
    );
    assert!(large < 2e-3, "{what}: mse {large:.2e} at M=1600");
}

#[test]
fn rbpf_converges_to_the_exact_filter_for_every_scheme() {
    let model = MeanShiftModel::new(1.0, 0.03).unwrap();
    let reference = |y: &[f64]| exact_means(model, y);
    for scheme in Scheme::ALL {
        let cfg = RbpfConfig {
            scheme,
            cv2_bound: 1.0,
            ..RbpfConfig::default()
        };
        assert_converges(model, cfg, scheme.name(), &reference);
    }
}

#[test]
fn tilted_proposal_and_extreme_bounds_converge_too() {
    let model = MeanShiftModel::new(1.0, 0.03).unwrap();
    let reference = |y: &[f64]| exact_means(model, y);
    for (tilt, bound) in [(Some(0.15), 1.0), (None, 0.0), (Some(0.1), 4.0)] {
        let cfg = RbpfConfig {
            tilt,
            cv2_bound: bound,
            ..RbpfConfig::default()
        };
        assert_converges(
            model,
            cfg,
            &format!("tilt {tilt:?} bound {bound}"),
            &reference,
        );
    }
}

/// Exact filter with ρ ~ Beta(α, β) integrated out: the posterior over
/// (segment start, number of change indicators so far) is finite.
fn exact_beta_means(sigma: f64, alpha: f64, beta: f64, y: &[f64]) -> Vec<f64> {
    let s2 = sigma * sigma;
    let lnpdf = |x: f64, m: f64, v: f64| {
        -0.5 * ((2.0 * std::f64::consts::PI * v).ln() + (x - m).powi(2) / v)
    };
    // key (segment start c, n1) -> (n obs, sum, probability)
    let mut post: HashMap<(usize, u32), (f64, f64, f64)> = HashMap::new();
    let mut out = vec![];
    for (i, &yt) in y.iter().enumerate() {
        let t = i + 1;
        let mut next: HashMap<(usize, u32), (f64, f64, f64)> = HashMap::new();
        if t == 1 {
            next.insert((1, 1), (1.0, yt, alpha / (alpha + beta)));
            next.insert((1, 0), (1.0, yt, beta / (alpha + beta)));
        } else {
            let den = (t - 1) as f64 + alpha + beta;
            let fresh = lnpdf(yt, 0.0, 1.0 + s2).exp();
            for (&(c, n1), &(n, s, p)) in &post {
                let v = 1.0 / (n + 1.0 / s2);
                let stay =
                    p * ((t - 1) as f64 - n1 as f64 + beta) / den * lnpdf(yt, v * s, 1.0 + v).exp();
                let e = next.entry((c, n1)).or_insert((n + 1.0, s + yt, 0.0));
                e.2 += stay;
                let go = p * (n1 as f64 + alpha) / den * fresh;
                let e = next.entry((t, n1 + 1)).or_insert((1.0, yt, 0.0));
                e.2 += go;
            }
        }
        let z: f64 = next.values().map(|v| v.2).sum();
        let mut mean = 0.0;
        for v in next.values_mut() {
            v.2 /= z;
            mean += v.2 * v.1 / (v.0 + 1.0 / s2);
        }
        out.push(mean);
        post = next;
    }
    out
}

#[test]
fn beta_prior_filter_converges_to_its_exact_filter() {
    let (alpha, beta) = (2.0, 60.0);
    // Data from ρ = 0.03, the filter only knows the Beta prior.
    let model = MeanShiftModel::new(1.0, 0.03).unwrap();
    let reference = |y: &[f64]| exact_beta_means(1.0, alpha, beta, y);
    let cfg = RbpfConfig {
        rho_prior: RhoPrior::Beta { alpha, beta },
        ..RbpfConfig::default()
    };
    assert_converges(model, cfg, "beta prior", &reference);
}

/// The exact filter itself against brute force: enumerate all 2^(n−1)
/// indicator paths of a 10-step sequence.
#[test]
fn exact_filter_matches_enumeration_of_all_paths() {
    let model = MeanShiftModel::new(1.3, 0.2).unwrap();
    let (mut mu, mut y) = (vec![], vec![]);
    model.simulate(10, &mut rng::stream(5, 0), &mut mu, &mut y);
    let mut f = ExactMeanShift::new(model).unwrap();
    let s2 = model.sigma * model.sigma;
    for t in 1..=y.len() {
        let got = f.step(y[t - 1]).unwrap();
        let (mut num, mut den) = (0.0, 0.0);
        for path in 0..(1u32 << (t - 1)) {
            // bit k set: change at time k + 2. Joint density of y_{1:t}:
            // product over segments of the Gaussian marginal of the segment.
            let mut p = 1.0;
            let mut start = 0;
            for k in 0..t {
                let end_here = k + 1 == t || path & (1 << k) != 0;
                if k + 1 < t {
                    p *= if path & (1 << k) != 0 {
                        model.rho
                    } else {
                        1.0 - model.rho
                    };
                }
                if end_here {
                    p *= segment_marginal(&y[start..=k], s2);
                    start = k + 1;
                }
            }
            let last = (0..t - 1)
                .rev()
                .find(|&k| path & (1 << k) != 0)
                .map(|k| k + 1)
                .unwrap_or(0);
            let seg = &y[last..t];
            let m = seg.iter().sum::<f64>() / (seg.len() as f64 + 1.0 / s2);
            num += p * m;
            den += p;
        }
        assert!(
            (got - num / den).abs() < 1e-10,
            "t={t}: {got} vs {}",
            num / den
        );
    }
}

/// ∫ Π N(y_i; μ, 1) N(μ; 0, s2) dμ in closed form.
fn segment_marginal(seg: &[f64], s2: f64) -> f64 {
    let n = seg.len() as f64;
    let sum: f64 = seg.iter().sum();
    let sq: f64 = seg.iter().map(|v| v * v).sum();
    let prec = n + 1.0 / s2;
    (2.0 * std::f64::consts::PI).powf(-n / 2.0)
        * (s2 * prec).powf(-0.5)
        * (-0.5 * (sq - sum * sum / prec)).exp()
}
