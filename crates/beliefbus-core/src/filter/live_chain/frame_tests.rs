//! The moving frame of [`LiveChainFilter`] against the exact Kalman filter
//! on a linear-Gaussian SDE with drift: a constant-velocity model
//! (position p, velocity v; dp = v dt + q_p dw₁, dv = u dt + q_v dw₂) with
//! position observations, driven as the pipeline drives it: every
//! `PUBLISH` filter steps a version is built by the refine stage's
//! moving-frame construction ([`crate::chain::frame::build_framed`])
//! around the filter's current belief, offered and installed.

use super::*;
use crate::chain::frame::{build_framed, sampler_around, FrameBuild};
use crate::chain::snapshot::{encode, SnapshotMeta};
use crate::chain::{Chain, ChainConfig, NearRule};
use crate::filter::ekf::{Ekf, EkfConfig};
use crate::filter::kalman::Kalman;
use crate::model::linear::LinearSde;
use crate::model::{simulate_observation, Bounds, Dims, SdeJacobians};
use nalgebra::DMatrix;
use std::time::Duration;

/// The constant-velocity model with S = [−p_half, p_half] × [−v_half,
/// v_half]. The runs below keep the belief inside the wide bounds
/// (40, 8); the narrow ones (8, 1.5) have it start outside them (p = −10,
/// v = 2) and cross them again: a version's cloud is then drawn around
/// the belief mean moved inside S ([`crate::chain::frame::cloud_centre`])
/// and the frame carries the offset. (Drawn around the mean itself, the
/// states were rejection-sampled into a slab on the face and the filter
/// broke down: with p ∈ [−20, 20] the belief crossed p = 20 at t ≈ 5.6 s,
/// gap 5.7 sd.)
fn cv_model(qp: f64, half: [f64; 2]) -> LinearSde {
    LinearSde::new(
        "cv",
        DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]),
        DMatrix::from_row_slice(2, 1, &[0.0, 1.0]),
        DMatrix::from_row_slice(2, 2, &[qp, 0.0, 0.0, 0.5]),
        DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
        vec![0.2],
        Bounds::new_box(&[-half[0], -half[1]], &[half[0], half[1]]).unwrap(),
    )
}

/// Half widths of S in the runs that keep the belief inside it.
const WIDE: [f64; 2] = [40.0, 8.0];

/// The constant-velocity model under a constant pull −g on v (gravity):
/// a hover needs the reference control u₀ = g.
#[derive(Clone)]
struct Pulled {
    inner: LinearSde,
    g: f64,
}

impl SdeModel for Pulled {
    fn name(&self) -> &str {
        "cv-pulled"
    }
    fn dims(&self) -> Dims {
        self.inner.dims()
    }
    fn drift(&self, x: &[f64], u: &[f64], f: &mut [f64]) {
        self.inner.drift(x, u, f);
        f[1] -= self.g;
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

/// A constant pull leaves the Jacobians unchanged.
impl SdeJacobians for Pulled {
    fn drift_jacobian(&self, x: &[f64], u: &[f64], jac: &mut [f64]) {
        self.inner.drift_jacobian(x, u, jac)
    }
    fn obs_jacobian(&self, x: &[f64], jac: &mut [f64]) {
        self.inner.obs_jacobian(x, jac)
    }
}

fn frame_build(dt: f64) -> FrameBuild {
    FrameBuild {
        inflate: 2.0,
        uniform_fraction: 0.02,
        min_std_fraction: 0.0025,
        chain: ChainConfig::moment_matched(2).with_near(NearRule::Knn { c: 1.5 }),
        dt,
    }
}

/// Gaps to Kalman over a run, in Kalman standard deviations.
#[derive(Debug, Default)]
struct Gap {
    /// Mean over steps (after the first version) of max_i |Δmean_i| / sd_i.
    mean: f64,
    /// Largest of the same.
    max: f64,
    /// Mean over steps of max_i |log(sd_i / sd_kalman_i)|.
    log_sd: f64,
    /// Largest over components of the mean of sign(u)·Δmean_i / sd_i: a
    /// bias that follows the control.
    u_bias: f64,
}

/// One run's setting.
#[derive(Clone, Copy)]
struct Case {
    /// Moving frame (versions built for f − w); otherwise each version is
    /// the same construction built for f itself (a fresh fixed chain
    /// around the belief, the control by transport).
    moving: bool,
    /// Position noise (F = diag(q_p, 0.5)).
    qp: f64,
    /// Filter step and steps between versions.
    dt: f64,
    publish: usize,
    /// States per version.
    n: usize,
    steps: usize,
    /// u = ±amp, switching every `hold` steps.
    amp: f64,
    hold: usize,
    /// Pull −g on v and the reference control u₀ = g the versions are
    /// built for (u = u₀ ± amp); `tell`: whether the filter is given u₀.
    g: f64,
    tell: bool,
    /// Half widths of S (p, v).
    half: [f64; 2],
}

/// Run `case` from a moving start (v = 2), seeded.
/// About 110 lines: one closed simulation (truth, refine's versions,
/// the filter, Kalman and the gap statistics) whose steps share the loop
/// state; split, the pieces would pass it all around.
fn run(case: Case, seed: u64) -> Gap {
    let Case {
        moving,
        qp,
        dt,
        publish,
        n,
        steps,
        amp,
        hold,
        g: pull,
        tell,
        half,
    } = case;
    // The offset from u₀ (its sign, also of ±0, orients the bias).
    let du = |k: usize| {
        if (k / hold).is_multiple_of(2) {
            amp
        } else {
            -amp
        }
    };
    let u = |k: usize| pull + du(k);
    let lin = cv_model(qp, half);
    let m = Pulled {
        inner: lin.clone(),
        g: pull,
    };
    let trace = std::env::var("LC_TRACE").is_ok();
    let prior = Gaussian::diagonal(&[-10.0, 2.0], &[0.3, 0.5]);
    let ekf = Ekf::new(m.clone(), &EkfConfig::default(), &prior, 0.0).unwrap();
    let mut lf: LiveChainFilter<Pulled, Vec<u64>> =
        LiveChainFilter::new(m.clone(), Box::new(ekf), n, &prior, 0.0);
    lf.set_moving_frame(moving);
    if tell {
        lf.set_reference_control(&[pull]).unwrap();
    }
    // The exact answer: the linear model under u − g.
    let mut kf = Kalman::new(lin, &prior, 0.0).unwrap();
    let mut p = frame_build(dt);
    p.chain.control[0] = pull;
    let mut rng_build = crate::rng::stream(seed, 2);
    let mut rng = crate::rng::stream(seed, 0);
    let mut x = [-10.0, 2.0];
    let mut y = [0.0];
    let mut gap = Gap::default();
    let mut counted = 0usize;
    let mut bias = [0.0f64; 2];
    for k in 0..steps {
        if k % publish == 0 {
            let g = lf.belief();
            let (mut c, eq) = if moving {
                build_framed(&m, &g, n, &p, &mut rng_build).unwrap()
            } else {
                let smp = sampler_around(&m, &g, &g.mean[..2], &p).unwrap();
                let mut pts = vec![0.0; 2 * n];
                for z in pts.chunks_exact_mut(2) {
                    smp.sample(m.bounds(), &mut rng_build, z);
                }
                let c = Chain::batch(&m, p.chain.clone(), &pts).unwrap();
                let mut eq = crate::chain::TimeEqualized::new(dt).unwrap();
                eq.fit(c.holding());
                (c, eq)
            };
            let meta = SnapshotMeta {
                version: k as u64 + 1,
                lineage: k as u64 + 1,
                t_pub_ns: 0,
            };
            lf.offer(encode(&mut c, eq.delta(), meta)).unwrap();
            let before = lf.belief();
            lf.advance(Duration::from_secs(10)).unwrap().unwrap();
            if trace {
                let (a, gk) = (lf.belief(), kf.belief());
                let (w, f) = lf.frame();
                eprintln!(
                    "install k {k}: Δmean {:+.4} {:+.4} (was {:+.4} {:+.4}) sd {:.4} {:.4} (was {:.4} {:.4}, K {:.4} {:.4}) w {:+.3} {:+.3} F {:+.3} {:+.3}",
                    a.mean[0] - gk.mean[0], a.mean[1] - gk.mean[1],
                    before.mean[0] - gk.mean[0], before.mean[1] - gk.mean[1],
                    a.cov_at(0, 0).sqrt(), a.cov_at(1, 1).sqrt(),
                    before.cov_at(0, 0).sqrt(), before.cov_at(1, 1).sqrt(),
                    gk.cov_at(0, 0).sqrt(), gk.cov_at(1, 1).sqrt(), w[0], w[1], f[0], f[1]
                );
            }
        }
        let t = (k + 1) as f64 * dt;
        let uk = [u(k)];
        crate::model::discrete::em_integrate(&m, &mut x, &uk, dt, 1e-3, &mut rng);
        simulate_observation(&m, &x, &mut rng, &mut y);
        lf.predict(t, &uk).unwrap();
        kf.predict(t, &[uk[0] - pull]).unwrap();
        lf.update(&Measurement::full(&y)).unwrap();
        kf.update(&Measurement::full(&y)).unwrap();
        let (g, gk) = (lf.belief(), kf.belief());
        let (mut e, mut s) = (0.0f64, 0.0f64);
        for i in 0..2 {
            let sd = gk.cov_at(i, i).sqrt();
            e = e.max((g.mean[i] - gk.mean[i]).abs() / sd);
            bias[i] += du(k).signum() * (g.mean[i] - gk.mean[i]) / sd;
            s = s.max((g.cov_at(i, i).sqrt() / sd).ln().abs());
        }
        if trace {
            eprintln!(
                "k {k} u {:+.2}: Δmean/sd {:+.3} {:+.3} sd ratio {:.3} {:.3}",
                uk[0],
                (g.mean[0] - gk.mean[0]) / gk.cov_at(0, 0).sqrt(),
                (g.mean[1] - gk.mean[1]) / gk.cov_at(1, 1).sqrt(),
                (g.cov_at(0, 0) / gk.cov_at(0, 0)).sqrt(),
                (g.cov_at(1, 1) / gk.cov_at(1, 1)).sqrt()
            );
        }
        gap.mean += e;
        gap.max = gap.max.max(e);
        gap.log_sd += s;
        counted += 1;
    }
    gap.mean /= counted as f64;
    gap.log_sd /= counted as f64;
    gap.u_bias = bias
        .iter()
        .map(|b| (b / counted as f64).abs())
        .fold(0.0, f64::max);
    gap
}

/// Mean-gap bounds, in Kalman standard deviations. Measured (seed 7):
/// n 500 → 0.23–0.33, n 2000 → 0.14–0.20 over the four cases, shrinking
/// with n (the chain's discretisation error); with the frame integrated by
/// Euler (before the fix) the 5 Hz controlled case at n 2000 was 0.27 (its
/// uncontrolled level ~0.14: a bias of u·dt²/2 per step), which GAP_2000
/// rejects.
const GAP_500: f64 = 0.5;
const GAP_2000: f64 = 0.25;
const MAX_GAP: f64 = 1.5;
const U_BIAS: f64 = 0.1;
const LOG_SD: f64 = 0.2;

/// The moving frame against Kalman, driven as the stage drives it, on a
/// constant-velocity model moving at ~2 units/s under ±2 switching
/// controls at 20 Hz (a version every 4 steps, the default scenario's
/// 200 ms) and at 5 Hz (a version every step), with and without position
/// noise. Asserted per case: the time-averaged mean gap below GAP_500 /
/// GAP_2000 Kalman sd at 500 / 2000 states and shrinking with the chain
/// size, the largest gap below MAX_GAP, the sd within exp(LOG_SD) on
/// average, and no bias that follows the control (U_BIAS). For contrast
/// the same versions built for f (no frame, control by transport) are
/// measured on the first case.
#[test]
fn moving_frame_tracks_the_kalman_filter_on_a_constant_velocity_model() {
    let only = std::env::var("LC_CASE").ok();
    let base = Case {
        moving: true,
        qp: 0.1,
        dt: 0.05,
        publish: 4,
        n: 500,
        steps: 120,
        amp: 2.0,
        hold: 20,
        g: 0.0,
        tell: true,
        half: WIDE,
    };
    let slow = Case {
        dt: 0.2,
        publish: 1,
        steps: 40,
        hold: 5,
        ..base
    };
    let cases = [
        ("20 Hz, u = 0", Case { amp: 0.0, ..base }),
        ("20 Hz, u = ±2", base),
        ("5 Hz, u = ±2", slow),
        ("5 Hz, u = ±2, q_p = 0", Case { qp: 0.0, ..slow }),
    ];
    for (ci, (name, case)) in cases.into_iter().enumerate() {
        if only.as_ref().is_some_and(|o| *o != ci.to_string()) {
            continue;
        }
        let small = run(case, 7);
        let large = run(Case { n: 2000, ..case }, 7);
        eprintln!("{name}: n 500 {small:?}\n  n 2000 {large:?}");
        if ci == 1 {
            let fixed = run(
                Case {
                    moving: false,
                    ..case
                },
                7,
            );
            eprintln!("  fixed chain, n 500: {fixed:?}");
        }
        assert!(small.mean < GAP_500, "{name}: n 500 {small:?}");
        assert!(large.mean < GAP_2000, "{name}: n 2000 {large:?}");
        assert!(large.mean < small.mean, "{name}: {large:?} vs {small:?}");
        for g in [&small, &large] {
            assert!(g.max < MAX_GAP, "{name}: {g:?}");
            assert!(g.u_bias < U_BIAS, "{name}: {g:?}");
            assert!(g.log_sd < LOG_SD, "{name}: {g:?}");
        }
    }
}

/// A hover: the model pulled by g = 9.81 on v, versions built for the
/// reference control u₀ = g, controls u₀ ± 2. The moving frame given u₀
/// meets the bounds of the u₀ = 0 cases at 500 states. Fixed versions
/// (control by transport of f(x̂, u) − f(x̂, u₀)) given u₀ track too; left
/// at u₀ = 0 they transport the whole control on top of a chain that
/// already holds u₀ — g too much — and are far off. (For the moving frame
/// of a control-affine model with constant B, u₀ cancels between the
/// chain's drift f(z, u₀) − w(u₀) and the frame's velocity; it matters
/// there only when B depends on the state.)
#[test]
fn versions_built_around_a_hover_control_track_the_kalman_filter() {
    let hover = Case {
        moving: true,
        qp: 0.1,
        dt: 0.05,
        publish: 4,
        n: 500,
        steps: 120,
        amp: 2.0,
        hold: 20,
        g: 9.81,
        tell: true,
        half: WIDE,
    };
    let framed = run(hover, 7);
    let fixed = run(
        Case {
            moving: false,
            ..hover
        },
        7,
    );
    let untold = run(
        Case {
            moving: false,
            tell: false,
            ..hover
        },
        7,
    );
    // The same flights without the pull (u₀ = 0, u = ±2).
    let free = Case { g: 0.0, ..hover };
    let (framed0, fixed0) = (
        run(free, 7),
        run(
            Case {
                moving: false,
                ..free
            },
            7,
        ),
    );
    eprintln!("hover, moving frame: {framed:?}\n  fixed, u₀ given: {fixed:?}\n  fixed, u₀ not given: {untold:?}");
    assert!(framed.mean < GAP_500, "{framed:?}");
    assert!(framed.max < MAX_GAP, "{framed:?}");
    assert!(framed.u_bias < U_BIAS, "{framed:?}");
    // Built around u₀ = g, the pulled model's chains and filters are the
    // unpulled ones (f(x, g) − g B = f(x, 0) for this affine model).
    assert!(
        (framed.mean - framed0.mean).abs() < 1e-9,
        "{framed:?} vs {framed0:?}"
    );
    assert!(
        (fixed.mean - fixed0.mean).abs() < 1e-9,
        "{fixed:?} vs {fixed0:?}"
    );
    assert!(untold.mean > 3.0 * fixed.mean, "{untold:?} vs {fixed:?}");
}

/// The moving frame against Kalman when S is narrower than the flight:
/// p ∈ [−8, 8] and v ∈ [−1.5, 1.5], the belief starting outside both
/// (p = −10, v = 2) and leaving v's interval again under the ±2 controls.
/// Every version is drawn inside S around the moved centre and the frame
/// carries the offset, so the filter meets the bounds of the wide-S runs
/// (500 states). Measured before the centre was moved (states rejection-
/// sampled into a slab on the face): see `cv_model`.
#[test]
fn moving_frame_tracks_the_kalman_filter_when_the_belief_leaves_s() {
    let narrow = Case {
        moving: true,
        qp: 0.1,
        dt: 0.05,
        publish: 4,
        n: 500,
        steps: 120,
        amp: 2.0,
        hold: 20,
        g: 0.0,
        tell: true,
        half: [8.0, 1.5],
    };
    for seed in [7, 8] {
        let gap = run(narrow, seed);
        eprintln!("narrow S, seed {seed}: {gap:?}");
        assert!(gap.mean < GAP_500, "{gap:?}");
        assert!(gap.max < MAX_GAP, "{gap:?}");
        assert!(gap.u_bias < U_BIAS, "{gap:?}");
        assert!(gap.log_sd < LOG_SD, "{gap:?}");
    }
}
