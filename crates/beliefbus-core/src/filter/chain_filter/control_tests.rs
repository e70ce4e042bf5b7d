//! The reference control on every construction path, and the control's
//! tilt where F Fᵀ is singular.

use super::*;
use crate::belief::Gaussian;
use crate::chain::frame::{build_framed, FrameBuild};
use crate::chain::metric::ScaledCoords;
use crate::chain::{Chain, ChainConfig, NearRule, Sampler};
use crate::filter::chain_filter::ChainFilter;
use crate::filter::kalman::Kalman;
use crate::filter::BayesFilter;
use crate::model::linear::LinearSde;
use crate::model::{simulate_observation, Bounds, Dims, Measurement};
use nalgebra::DMatrix;

/// ẍ = −x − 0.5ẋ + u + σ ẇ: noise and control on the velocity only.
fn di(sigma: f64) -> LinearSde {
    di_in(sigma, Bounds::new_box(&[-1.5, -1.5], &[1.5, 1.5]).unwrap())
}

fn di_in(sigma: f64, bounds: Bounds) -> LinearSde {
    LinearSde::new(
        "di",
        DMatrix::from_row_slice(2, 2, &[0.0, 1.0, -1.0, -0.5]),
        DMatrix::from_row_slice(2, 1, &[0.0, 1.0]),
        DMatrix::from_row_slice(2, 1, &[0.0, sigma]),
        DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
        vec![0.1],
        bounds,
    )
}

/// `inner` with the control u₀ folded into its drift and no control input.
struct Folded<M> {
    inner: M,
    u0: Vec<f64>,
}

impl<M: SdeModel> SdeModel for Folded<M> {
    fn name(&self) -> &str {
        "folded"
    }
    fn dims(&self) -> Dims {
        Dims {
            control: 0,
            ..self.inner.dims()
        }
    }
    fn drift(&self, x: &[f64], _u: &[f64], f: &mut [f64]) {
        self.inner.drift(x, &self.u0, f)
    }
    fn diffusion(&self, x: &[f64], big_f: &mut [f64]) {
        self.inner.diffusion(x, big_f)
    }
    fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
        self.inner.obs_mean(x, g)
    }
    fn obs_std(&self, std: &mut [f64]) {
        self.inner.obs_std(std)
    }
    fn bounds(&self) -> &Bounds {
        self.inner.bounds()
    }
}

fn assert_same_chain(a: &Chain, b: &Chain) {
    assert_eq!(a.len(), b.len());
    assert_eq!(a.states(), b.states());
    for i in 0..a.len() {
        assert_eq!(a.drift_at(i), b.drift_at(i), "f at {i}");
        assert_eq!(
            a.holding()[i].to_bits(),
            b.holding()[i].to_bits(),
            "Δt at {i}"
        );
        assert_eq!(a.row(i), b.row(i), "row {i}");
    }
}

#[test]
fn a_chain_built_around_a_reference_control_is_the_chain_of_the_folded_drift() {
    let m = ScaledCoords::new(di(0.5), &[4.0, 1.0]).unwrap();
    let u0 = 0.7;
    let mut cfg = ChainConfig::moment_matched(2);
    cfg.control[0] = u0;
    let folded = Folded {
        inner: ScaledCoords::new(di(0.5), &[4.0, 1.0]).unwrap(),
        u0: vec![u0],
    };
    let pts = Sampler::Uniform.sample_many(m.bounds(), 1500, &mut crate::rng::stream(4, 0));
    // Batch, thesis and advected constructions.
    for step in [None, Some(0.05)] {
        let mut c = cfg.clone();
        c.step = step;
        let mut c0 = ChainConfig::moment_matched(2);
        c0.step = step;
        let a = Chain::batch(&m, c, &pts).unwrap();
        let b = Chain::batch(&folded, c0, &pts).unwrap();
        assert_eq!(a.reference_control(), &[u0]);
        assert_same_chain(&a, &b);
        // and the control matters: not the chain of u₀ = 0
        let z = Chain::batch(&m, ChainConfig::moment_matched(2), &pts).unwrap();
        assert!((0..z.len()).any(|i| z.drift_at(i) != a.drift_at(i)));
    }
    // Moving frame: drawn around a belief, built for f(x, u₀) − w.
    let fb = |chain: ChainConfig| FrameBuild {
        inflate: 2.0,
        uniform_fraction: 0.02,
        min_std_fraction: 0.01,
        chain: chain.with_near(NearRule::Knn { c: 1.5 }),
        dt: 0.05,
    };
    let g = Gaussian::diagonal(&[1.2, 0.3], &[0.2, 0.3]);
    let (a, _) =
        build_framed(&m, &g, 800, &fb(cfg.clone()), &mut crate::rng::stream(5, 0)).unwrap();
    let (b, _) = build_framed(
        &folded,
        &g,
        800,
        &fb(ChainConfig::moment_matched(2)),
        &mut crate::rng::stream(5, 0),
    )
    .unwrap();
    assert_same_chain(&a, &b);
}

/// Mean over 60 steps of the chain mean − Kalman mean in v (the
/// coordinate the control drives), and the same for the Kalman filter run
/// without the control, under u held; the chain built for u₀ on the model
/// scaled by 3 on x.
fn controlled_gap(u0: f64, u: f64) -> (f64, f64, u64) {
    let model = di_in(0.5, Bounds::new_box(&[-2.5, -2.0], &[2.5, 2.0]).unwrap());
    let lambda = 3.0;
    let sm = ScaledCoords::new(model.clone(), &[lambda, 1.0]).unwrap();
    let dt = 0.05;
    let prior = Gaussian::diagonal(&[0.0, 0.0], &[0.1, 0.1]);
    let sprior = Gaussian::diagonal(&[0.0, 0.0], &[0.1 * lambda, 0.1]);
    let mut cfg = ChainConfig::moment_matched(2).with_step(dt);
    cfg.control[0] = u0;
    let mut cf = ChainFilter::from_samples(
        sm,
        cfg,
        &Sampler::Uniform,
        6000,
        dt,
        &mut crate::rng::stream(6, 1),
    )
    .unwrap();
    cf.reset(0.0, &sprior);
    let mut kf = Kalman::new(model.clone(), &prior, 0.0).unwrap();
    let mut k0 = Kalman::new(model.clone(), &prior, 0.0).unwrap();
    let mut rng = crate::rng::stream(6, 0);
    let mut x = [0.0, 0.0];
    let (mut gap, mut gap0) = (0.0f64, 0.0f64);
    for k in 1..=60 {
        let t = k as f64 * dt;
        crate::model::discrete::em_integrate(&model, &mut x, &[u], dt, 1e-3, &mut rng);
        let mut y = [0.0];
        simulate_observation(&model, &x, &mut rng, &mut y);
        cf.predict(t, &[u]).unwrap();
        kf.predict(t, &[u]).unwrap();
        k0.predict(t, &[0.0]).unwrap();
        for f in [&mut cf as &mut dyn BayesFilter, &mut kf, &mut k0] {
            f.update(&Measurement::full(&y)).unwrap();
        }
        let (kb, cb, b0) = (kf.belief(), cf.belief(), k0.belief());
        gap += (cb.mean[1] - kb.mean[1]) / 60.0;
        gap0 += (b0.mean[1] - kb.mean[1]) / 60.0;
    }
    (gap, gap0, cf.control_unapplied())
}

#[test]
fn the_tilt_follows_the_control_on_a_chain_with_noise_on_the_velocity_only() {
    // u = 1 against a chain built for u₀ = 0 (tilted on every row) and
    // for u₀ = 1 (no tilt): both follow the controlled Kalman answer, and
    // no row is left untilted.
    let (tilted, gap0, skipped) = controlled_gap(0.0, 1.0);
    let (built, _, skipped_b) = controlled_gap(1.0, 1.0);
    eprintln!("tilted {tilted:.4}, built for u {built:.4}, uncontrolled Kalman {gap0:.4}");
    assert_eq!((skipped, skipped_b), (0, 0));
    assert!(gap0.abs() > 0.05, "control must matter: {gap0}");
    assert!(tilted.abs() < 0.3 * gap0.abs(), "tilted {tilted} vs {gap0}");
    assert!(built.abs() < 0.3 * gap0.abs(), "built {built} vs {gap0}");
}

#[test]
fn a_control_on_a_noise_free_coordinate_is_counted_not_skipped() {
    // ẋ = v + u, v̇ = −x + σẇ: the control moves the noise-free x, which
    // no tilt of a kernel with Cov[Δx] = o(Δt) can follow.
    let m = LinearSde::new(
        "ctl-x",
        DMatrix::from_row_slice(2, 2, &[0.0, 1.0, -1.0, 0.0]),
        DMatrix::from_row_slice(2, 1, &[1.0, 0.0]),
        DMatrix::from_row_slice(2, 1, &[0.0, 0.5]),
        DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
        vec![0.1],
        Bounds::new_box(&[-1.5, -1.5], &[1.5, 1.5]).unwrap(),
    );
    let mut cf = ChainFilter::from_samples(
        m,
        ChainConfig::moment_matched(2),
        &Sampler::Uniform,
        500,
        0.05,
        &mut crate::rng::stream(7, 1),
    )
    .unwrap();
    cf.reset(0.0, &Gaussian::diagonal(&[0.0, 0.0], &[0.3, 0.3]));
    cf.predict(0.05, &[0.0]).unwrap();
    assert_eq!(cf.control_unapplied(), 0);
    cf.predict(0.1, &[0.5]).unwrap();
    let rows = (0..cf.chain().len())
        .filter(|&i| !cf.chain().row(i).0.is_empty())
        .count() as u64;
    assert_eq!(cf.control_unapplied(), rows);
}
