//! The MCL filters' interval prior ([`super::interval_prior`]) against
//! independent answers: (1) the accumulated C of a straight drive is the
//! composed linear covariance Σ_i Fⁱ Σ₁ (Fⁱ)ᵀ with Fⁱ = I + iN (N from
//! finite differences of the mean model), and of a curved drive the sum of
//! J_i Σ₁(β_i) J_iᵀ with J_i the finite-difference Jacobian of the composed
//! mean model in the i-th step's noise; (2) with a scan at every step
//! (C = 0 at every update) the filters with the prior reproduce the ones
//! without bit for bit; (3) for a Gaussian F (no return) implicit MCL's
//! weights stay equal across particles whose accumulated C differ, which
//! takes the per-particle normaliser −½ log det Σ^j.

use super::implicit::ImplicitMcl;
use super::interval_prior::MotionStep;
use super::newton::NewtonSettings;
use super::standard::StandardMcl;
use super::{LaserStep, Localizer};
use crate::geometry::{frame_rotation, Point, Pose};
use crate::laser::{predict, LaserNoise, Observation};
use crate::vehicle::{Control, MotionNoise, StepNoise, Ute};
use beliefbus_core::rng::stream;
use nalgebra::Matrix3;

fn close(a: &Matrix3<f64>, b: &Matrix3<f64>, rel: f64) -> bool {
    (a - b).norm() <= rel * b.norm()
}

/// ∂f/∂x of the mean model at x by central differences.
fn fd_jacobian(ute: &Ute, x: &Pose, u: Control) -> Matrix3<f64> {
    let mut j = Matrix3::zeros();
    for k in 0..3 {
        let mut e = Pose::zeros();
        e[k] = 1e-6;
        let d = (ute.predict_mean(&(x + e), u) - ute.predict_mean(&(x - e), u)) / 2e-6;
        j.set_column(k, &d);
    }
    j
}

#[test]
fn straight_drive_accumulates_the_composed_linear_covariance() {
    let ute = Ute::default();
    let u = Control { v: 3.0, alpha: 0.0 };
    let noise = StepNoise::new(&ute, u, &MotionNoise::default()).unwrap();
    let ms = MotionStep::new(&ute, &noise);
    let x0 = Pose::new(1.0, -2.0, 0.4);
    let (mut x, mut c) = (x0, Matrix3::zeros());
    let k = 40;
    for _ in 0..k {
        ms.accumulate(&mut x, &mut c, u);
    }
    // Straight: the heading stays, F = I + N at every step with N² = 0,
    // so Fⁱ = I + iN, and Σ₁ is the same at every step.
    let n = fd_jacobian(&ute, &x0, u) - Matrix3::identity();
    assert!((n * n).norm() < 1e-8 && n[(2, 2)].abs() < 1e-8, "{n}");
    let t = frame_rotation(x0[2]);
    let s1 = t * ms.s0 * t.transpose();
    let mut want = Matrix3::zeros();
    for i in 0..k {
        let fi = Matrix3::identity() + n * i as f64;
        want += fi * s1 * fi.transpose();
    }
    assert!(close(&c, &want, 1e-7), "{c} vs {want}");
    assert!((x[2] - x0[2]).abs() < 1e-15);
    // The position's variance grows as k³ through the heading: not just k Σ₁.
    assert!(!close(&c, &(s1 * k as f64), 0.1));
}

#[test]
fn curved_drive_accumulates_the_noise_through_the_composed_mean_model() {
    let ute = Ute::default();
    let controls: Vec<Control> = (0..30)
        .map(|i| Control {
            v: 2.0 + 0.05 * i as f64,
            alpha: 0.3 - 0.02 * i as f64,
        })
        .collect();
    let noises: Vec<StepNoise> = controls
        .iter()
        .map(|&u| StepNoise::new(&ute, u, &MotionNoise::default()).unwrap())
        .collect();
    let x0 = Pose::new(0.5, 0.2, -0.7);
    let (mut x, mut c) = (x0, Matrix3::zeros());
    let mut path = vec![x0];
    for (u, nz) in controls.iter().zip(&noises) {
        MotionStep::new(&ute, nz).accumulate(&mut x, &mut c, *u);
        path.push(x);
    }
    // x_k as a function of the noise w_i added after step i (1-based).
    let compose = |i: usize, w: &Pose| {
        let mut y = x0;
        for (s, u) in controls.iter().enumerate() {
            y = ute.predict_mean(&y, *u);
            if s + 1 == i {
                y += w;
            }
        }
        y
    };
    let mut want = Matrix3::zeros();
    for i in 1..=controls.len() {
        let mut j = Matrix3::zeros();
        for k in 0..3 {
            let mut e = Pose::zeros();
            e[k] = 1e-6;
            j.set_column(k, &((compose(i, &e) - compose(i, &-e)) / 2e-6));
        }
        // Step i's noise is Σ₁ at the heading before the step.
        let t = frame_rotation(path[i - 1][2]);
        let s0 = noises[i - 1].chol * noises[i - 1].chol.transpose();
        want += j * t * s0 * t.transpose() * j.transpose();
    }
    assert!(close(&c, &want, 1e-6), "{c} vs {want}");
    assert!((x - path[controls.len()]).norm() == 0.0);
}

/// A short drive past three landmarks with a scan at every step.
fn scans() -> (Ute, Vec<Control>, Vec<Point>, Vec<Vec<Observation>>) {
    let ute = Ute::default();
    let map = vec![[8.0, 3.0], [12.0, -4.0], [16.0, 2.0]];
    let u: Vec<Control> = (0..12)
        .map(|i| Control {
            v: 3.0,
            alpha: 0.1 - 0.02 * i as f64,
        })
        .collect();
    let mut x = Pose::new(0.0, 0.0, 0.05);
    let obs = u
        .iter()
        .map(|&c| {
            x = ute.predict_mean(&x, c);
            map.iter()
                .enumerate()
                .map(|(i, &m)| {
                    let (r, b) = predict(&x, m);
                    Observation {
                        range: r + 0.05 * (i as f64 - 1.0),
                        bearing: b + 0.003,
                        landmark: i,
                    }
                })
                .collect()
        })
        .collect();
    (ute, u, map, obs)
}

fn drive(f: &mut dyn Localizer, on: bool) {
    let (ute, us, map, obs) = scans();
    let laser = LaserNoise::default();
    let mut rng = stream(21, 4);
    f.set_interval_prior(on);
    f.particles_mut().init(
        &Pose::new(0.0, 0.0, 0.05),
        &Pose::new(0.3, 0.3, 0.02),
        &mut rng,
    );
    for (n, (&u, o)) in us.iter().zip(&obs).enumerate() {
        let noise = StepNoise::new(&ute, u, &MotionNoise::default()).unwrap();
        let s = LaserStep {
            ute: &ute,
            u,
            noise: &noise,
            obs: o,
            map: &map,
            laser: &laser,
            step: n + 1,
        };
        f.update(&s, &mut rng).unwrap();
    }
}

#[test]
fn with_no_accumulated_noise_the_prior_reproduces_the_blind_filters_bit_for_bit() {
    let newton = NewtonSettings::default();
    let pairs: [(Box<dyn Localizer>, Box<dyn Localizer>); 2] = [
        (
            Box::new(ImplicitMcl::new(30, 0.5, newton).unwrap()),
            Box::new(ImplicitMcl::new(30, 0.5, newton).unwrap()),
        ),
        (
            Box::new(StandardMcl::new(30, 0.5).unwrap()),
            Box::new(StandardMcl::new(30, 0.5).unwrap()),
        ),
    ];
    for (mut on, mut off) in pairs {
        drive(on.as_mut(), true);
        drive(off.as_mut(), false);
        let (a, b) = (on.particles(), off.particles());
        assert_eq!(a.x, b.x, "{}", on.name());
        assert_eq!(a.logw, b.logw);
        assert_eq!(a.w, b.w);
        assert_eq!(a.resamplings, b.resamplings);
        assert!(a.acc.iter().all(|c| *c == Matrix3::zeros()));
    }
}

#[test]
fn gaussian_f_with_accumulated_noise_gives_constant_implicit_weights() {
    let ute = Ute::default();
    let u = Control {
        v: 3.0,
        alpha: 0.15,
    };
    let noise = StepNoise::new(&ute, u, &MotionNoise::default()).unwrap();
    let ms = MotionStep::new(&ute, &noise);
    let mut f = ImplicitMcl::new(20, 0.0, NewtonSettings::default()).unwrap();
    f.set_interval_prior(true);
    let mut rng = stream(5, 9);
    for (j, (x, c)) in f.set.x.iter_mut().zip(f.set.acc.iter_mut()).enumerate() {
        *x = Pose::new(j as f64, -0.3 * j as f64, 0.2 * j as f64);
        // A different interval length per particle: different C and det Σ.
        for _ in 0..j {
            ms.accumulate(x, c, u);
        }
    }
    let norms: Vec<f64> = (0..f.set.len())
        .map(|j| ms.prior(&f.set.x[j], &f.set.acc[j], u).norm)
        .collect();
    let spread = norms
        .iter()
        .fold(0.0f64, |a, &b| a.max((b - norms[0]).abs()));
    assert!(spread > 1.0, "normalisers should differ: {norms:?}");
    let laser = LaserNoise::default();
    let s = LaserStep {
        ute: &ute,
        u,
        noise: &noise,
        obs: &[],
        map: &[],
        laser: &laser,
        step: 1,
    };
    f.update(&s, &mut rng).unwrap();
    let m = f.set.len() as f64;
    for &w in &f.set.w {
        assert!((w - 1.0 / m).abs() < 1e-9 / m, "{w}");
    }
    assert!(f.set.acc.iter().all(|c| *c == Matrix3::zeros()));
    assert_eq!(f.fallbacks, 0);
}
