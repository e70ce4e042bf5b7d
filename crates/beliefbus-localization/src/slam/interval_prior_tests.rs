//! The interval prior of the particle SLAM filters
//! ([`super::particles::SlamParticles::predict_only`] with `deferred`,
//! [`super::step_setup::StepPrior`]) against independent answers.
//!
//! ```text
//! steps without returns:  x ← f(x, u),  C ← F C Fᵀ + Σ₁(β)
//! next step with returns: prior N(f, F C Fᵀ + Σ₁(β)) for the proposal, the gate and the weight
//! ```
//!
//! (1) C is the covariance of the motion model's own draws over the
//! interval (statistical bound; dropping F fails it); (2) the prior is
//! exactly the one-step prior when C = 0, and otherwise has the stated
//! covariance, precision, normaliser and draw factor; (3) after an interval
//! without returns, FastSLAM 2.0's, reading (i)'s and the
//! Rao–Blackwellised implicit step's weights are the predictive likelihoods
//! of a return under the motion model's distribution over the whole
//! interval (brute force over simulated paths; with a one-step prior they
//! are not).

use super::assoc::{innovation, RangeBearing};
use super::fastslam::{FastSlam, Landmark, Version};
use super::implicit::{ImplicitSlam, SampledLandmark};
use super::implicit_rb::ImplicitRbSlam;
use super::implicit_refine::ImplicitRefineSlam;
use super::particles::SlamParticles;
use super::refine::{newton, Objective};
use super::refined_map::{Past, RefinedLandmark};
use super::step_setup::StepSetup;
use super::{SlamFilter, SlamModel};
use crate::carpark::normal3;
use crate::geometry::{frame_rotation, Pose};
use crate::laser::{predict, LaserNoise};
use crate::mcl::newton::NewtonSettings;
use crate::vehicle::{Control, MotionNoise};
use beliefbus_core::rng::stream;
use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};
use rand::RngExt;
use rand_distr::StandardNormal;

/// Table 7's intensities × 0.05 (heading σ ≈ 0.03 rad per step, so the
/// interval's distribution is close to Gaussian) and a laser of the order
/// of the interval's spread.
fn model() -> SlamModel {
    let d = MotionNoise::default();
    SlamModel {
        ute: Default::default(),
        motion: MotionNoise {
            p: [d.p[0] * 0.05, d.p[1] * 0.05],
            q: [d.q[0] * 0.05, d.q[1] * 0.05, d.q[2] * 0.05],
        },
        laser: LaserNoise {
            var_range: 0.04,
            var_bearing: 0.04f64.powi(2),
        },
        assoc: Default::default(),
        max_range: 15.0,
    }
}

const U: Control = Control { v: 3.0, alpha: 0.1 };
const DT: f64 = 0.025;
/// Steps without returns before the step with one.
const K: usize = 8;

fn start() -> Pose {
    Pose::new(1.0, -2.0, 0.3)
}

/// Mean and covariance of poses.
fn moments(xs: &[Pose]) -> (Vector3<f64>, Matrix3<f64>) {
    let n = xs.len() as f64;
    let m = xs.iter().fold(Vector3::zeros(), |a, x| a + x) / n;
    let c = xs
        .iter()
        .fold(Matrix3::zeros(), |a, x| a + (x - m) * (x - m).transpose())
        / (n - 1.0);
    (m, c)
}

#[test]
fn accumulated_noise_is_the_covariance_of_the_motion_models_draws() {
    let model = model();
    let (ute, noise) = model.step_noise(U, DT).unwrap();
    let n = 40_000;
    let mut drawn = SlamParticles::<Landmark>::new(n, 0.5).unwrap();
    drawn.reset(&start());
    let mut deferred = SlamParticles::<Landmark>::new(1, 0.5).unwrap();
    deferred.deferred = true;
    deferred.reset(&start());
    let mut rng = stream(21, 0);
    // The naive sum of the steps' Σ₁ along the mean path: what the
    // accumulation would be without propagating through F.
    let mut naive = Matrix3::zeros();
    for _ in 0..K {
        let b = deferred.x[0][2];
        let t = frame_rotation(b);
        naive += t * noise.chol * noise.chol.transpose() * t.transpose();
        drawn.predict_only(&ute, &noise, U, &mut rng);
        deferred.predict_only(&ute, &noise, U, &mut rng);
    }
    let (m, c) = moments(&drawn.x);
    let acc = deferred.acc[0];
    // Every entry within 5 standard errors of the sample covariance
    // (SE² of c_ij ≈ (c_ii c_jj + c_ij²)/n), plus the mean.
    let within = |a: &Matrix3<f64>| {
        (0..3).all(|i| {
            (0..3).all(|j| {
                let se = ((c[(i, i)] * c[(j, j)] + c[(i, j)].powi(2)) / n as f64).sqrt();
                (a[(i, j)] - c[(i, j)]).abs() < 5.0 * se
            })
        })
    };
    assert!(within(&acc), "accumulated {acc:?}\nsample {c:?}");
    assert!(!within(&naive), "the test cannot tell F from no F");
    for i in 0..3 {
        let se = (c[(i, i)] / n as f64).sqrt();
        assert!(
            (deferred.x[0][i] - m[i]).abs() < 5.0 * se,
            "mean {i}: {} vs {}",
            deferred.x[0][i],
            m[i]
        );
    }
    // The deferred set's weights are untouched and its pose is the mean model.
    let mut x = start();
    for _ in 0..K {
        x = ute.predict_mean(&x, U);
    }
    assert_eq!(deferred.x[0], x);
}

fn setup(model: &SlamModel) -> StepSetup {
    let (ute, noise) = model.step_noise(U, DT).unwrap();
    let r = model.r();
    StepSetup {
        step: 1,
        ute,
        noise,
        model: *model,
        r,
        half_logdet_r: 0.5 * (r[(0, 0)] * r[(1, 1)]).ln(),
        ln2pi: (2.0 * std::f64::consts::PI).ln(),
        log_new: model.log_new_density(),
        s0: noise.chol * noise.chol.transpose(),
        motion_norm: -(0..3).map(|i| noise.chol[(i, i)].ln()).sum::<f64>(),
    }
}

#[test]
fn step_prior_is_the_one_step_prior_without_accumulated_noise_and_the_interval_one_with_it() {
    let model = model();
    let s = setup(&model);
    let x = start();
    let xi = Vector3::new(0.3, -1.2, 0.7);
    let p = s.prior(&x, &Matrix3::zeros(), U);
    let f = s.ute.predict_mean(&x, U);
    // Bit for bit the draws and matrices the filters used before.
    assert_eq!(p.f, f);
    assert_eq!(p.draw(&xi), f + s.noise.draw(x[2], &xi));
    assert_eq!(p.prec, s.noise.precision(x[2]));
    assert_eq!(p.norm, s.motion_norm);
    let t = frame_rotation(x[2]);
    assert_eq!(p.cov, t * s.s0 * t.transpose());

    let acc = Matrix3::new(0.04, 0.01, 0.002, 0.01, 0.03, -0.001, 0.002, -0.001, 0.0009);
    let p = s.prior(&x, &acc, U);
    let fx = super::ekf::motion_jacobian(&s.ute, x[2], U);
    let want = fx * acc * fx.transpose() + t * s.s0 * t.transpose();
    assert!((p.cov - want).norm() < 1e-15);
    assert!((p.prec * want - Matrix3::identity()).norm() < 1e-9);
    assert!((p.norm + 0.5 * want.determinant().ln()).abs() < 1e-12);
    // The draw factor: columns of draw(e_i) − f, times its transpose.
    let cols = Matrix3::from_columns(&[
        p.draw(&Vector3::x()) - f,
        p.draw(&Vector3::y()) - f,
        p.draw(&Vector3::z()) - f,
    ]);
    assert!((cols * cols.transpose() - want).norm() < 1e-12);
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

/// The interval's prior N(f, Σ) of a particle from `start()` after K steps
/// without returns and the step with one: f the mean model, Σ from the
/// accumulation (checked against the motion model's draws above).
fn interval_prior(model: &SlamModel) -> (Pose, Matrix3<f64>) {
    let (ute, noise) = model.step_noise(U, DT).unwrap();
    let mut set = SlamParticles::<Landmark>::new(1, 0.5).unwrap();
    set.deferred = true;
    set.reset(&start());
    let mut rng = stream(25, 0);
    for _ in 0..=K {
        set.predict_only(&ute, &noise, U, &mut rng);
    }
    (set.x[0], set.acc[0])
}

/// Brute force: log ∫ N(x; f, Σ) N(z; h(x, θ), Σ₂) dx over 200 000 draws
/// of x, and its standard error.
fn predictive(
    model: &SlamModel,
    (f, cov): (Pose, Matrix3<f64>),
    th: [f64; 2],
    z: &RangeBearing,
) -> (f64, f64) {
    let c = cov.cholesky().unwrap().l();
    let r = model.r();
    let rinv = Matrix2::new(1.0 / r[(0, 0)], 0.0, 0.0, 1.0 / r[(1, 1)]);
    let norm = -(2.0 * std::f64::consts::PI).ln() - 0.5 * (r[(0, 0)] * r[(1, 1)]).ln();
    let mut rng = stream(23, 0);
    let l: Vec<f64> = (0..200_000)
        .map(|_| {
            let x = f + c * normal3(&mut rng);
            let (nu, _, _) = innovation(&x, th, z);
            norm - 0.5 * nu.dot(&(rinv * nu))
        })
        .collect();
    log_mean_exp(&l)
}

/// Three groups of n particles (landmark at θ_A with zero covariance, at
/// θ_C, none); after K steps without returns one return near θ_A. The
/// groups' log weight ratios against the brute-force predictive
/// likelihoods over the whole interval.
fn check_interval_weights<F: SlamFilter>(
    name: &str,
    f: &mut F,
    push: impl Fn(&mut F, usize, [f64; 2]),
    w: impl Fn(&F) -> Vec<f64>,
    n: usize,
) {
    check_interval_weights_with(name, f, push, w, n, predictive);
}

/// [`check_interval_weights`] with the known groups' predictive likelihood
/// given by `pred(model, prior, θ, z)` (log and its standard error).
fn check_interval_weights_with<F: SlamFilter>(
    name: &str,
    f: &mut F,
    push: impl Fn(&mut F, usize, [f64; 2]),
    w: impl Fn(&F) -> Vec<f64>,
    n: usize,
    pred: impl Fn(&SlamModel, (Pose, Matrix3<f64>), [f64; 2], &RangeBearing) -> (f64, f64),
) {
    let model = model();
    let mut x = start();
    for _ in 0..=K {
        x = model.step_noise(U, DT).unwrap().0.predict_mean(&x, U);
    }
    let th_a = [x[0] + 6.0, x[1] + 5.0];
    let th_c = [th_a[0] + 0.3, th_a[1] + 0.2];
    let (r0, b0) = predict(&x, th_a);
    let z = RangeBearing {
        range: r0 + 0.1,
        bearing: b0 + 0.02,
    };
    assert!(f.set_interval_prior(true));
    f.reset(&start());
    for j in 0..2 * n {
        push(f, j, if j < n { th_a } else { th_c });
    }
    let mut rng = stream(24, 0);
    for _ in 0..K {
        f.step(U, DT, &[], &mut rng).unwrap();
    }
    f.step(U, DT, &[z], &mut rng).unwrap();
    let st = f.stats();
    assert_eq!((st.known, st.new), (2 * n, n), "{name}: associations");
    let lw: Vec<f64> = w(f).iter().map(|w| w.ln()).collect();
    let (ga, sa) = log_mean_exp(&lw[..n]);
    let (gc, sc) = log_mean_exp(&lw[n..2 * n]);
    let (gn, sn) = log_mean_exp(&lw[2 * n..]);
    let prior = interval_prior(&model);
    let (ea, se_a) = pred(&model, prior, th_a, &z);
    let (ec, se_c) = pred(&model, prior, th_c, &z);
    let en = z.range.ln() + model.log_new_density();
    let check = |what: &str, got: f64, want: f64, se: f64| {
        assert!(
            (got - want).abs() < 5.0 * se + 2e-3,
            "{name} {what}: log ratio {got:.4} vs {want:.4} (5 se = {:.4})",
            5.0 * se
        );
    };
    check(
        "A / new",
        ga - gn,
        ea - en,
        (sa * sa + sn * sn + se_a * se_a).sqrt(),
    );
    check(
        "C / new",
        gc - gn,
        ec - en,
        (sc * sc + sn * sn + se_c * se_c).sqrt(),
    );
    // Power: the one-step prior's predictive likelihood is far from the
    // interval's, so a filter still using one step's noise would fail.
    let (ute, noise) = model.step_noise(U, DT).unwrap();
    let mut before = start();
    for _ in 0..K {
        before = ute.predict_mean(&before, U);
    }
    let t = frame_rotation(before[2]);
    let one = t * noise.chol * noise.chol.transpose() * t.transpose();
    let (ea1, _) = pred(&model, (prior.0, one), th_a, &z);
    assert!((ea1 - ea).abs() > 0.2, "one step {ea1} vs interval {ea}");
}

fn landmark(th: [f64; 2]) -> Landmark {
    Landmark {
        m: Vector2::new(th[0], th[1]),
        p: Matrix2::zeros(),
    }
}

#[test]
fn fastslam2_weights_after_an_interval_are_its_predictive_likelihoods() {
    let n = 3000;
    let mut f = FastSlam::new(model(), Version::Two, 3 * n, 0.0).unwrap();
    check_interval_weights(
        "FastSLAM 2.0",
        &mut f,
        |f, j, th| {
            f.set.maps[j].push(landmark(th));
        },
        |f| f.set.w.clone(),
        n,
    );
}

#[test]
fn implicit_weights_after_an_interval_are_its_predictive_likelihoods() {
    let n = 3000;
    let mut f = ImplicitSlam::new(model(), 3 * n, 0.0, NewtonSettings::default()).unwrap();
    check_interval_weights(
        "implicit",
        &mut f,
        |f, j, m| {
            f.set.maps[j].push(SampledLandmark {
                m,
                cov: Matrix2::zeros(),
            });
        },
        |f| f.set.w.clone(),
        n,
    );
}

#[test]
fn implicit_rb_weights_after_an_interval_are_its_predictive_likelihoods() {
    let n = 3000;
    let mut f = ImplicitRbSlam::new(model(), 3 * n, 0.0, NewtonSettings::default()).unwrap();
    check_interval_weights(
        "implicit-rb",
        &mut f,
        |f, j, th| {
            f.set.maps[j].push(landmark(th));
        },
        |f| f.set.w.clone(),
        n,
    );
}

/// A landmark at θ seen before from six poses around it with exact returns:
/// F_past(θ') = Σ_i ½‖h(X_i, θ) − h(X_i, θ')‖²_{Σ₂⁻¹}, minimal (zero) at θ,
/// its conditional spread a few cm with the test's laser.
fn refined_past(model: &SlamModel, th: [f64; 2]) -> RefinedLandmark {
    let r = model.r();
    let rinv = Matrix2::new(1.0 / r[(0, 0)], 0.0, 0.0, 1.0 / r[(1, 1)]);
    let pose = |i: usize| {
        let a = -1.0 + 0.45 * i as f64;
        let d = 5.0 + 0.6 * i as f64;
        // Facing the landmark, 0.2 rad off.
        Pose::new(
            th[0] + d * a.cos(),
            th[1] + d * a.sin(),
            a + std::f64::consts::PI + 0.2,
        )
    };
    let exact = |x: &Pose| {
        let (range, bearing) = predict(x, th);
        RangeBearing { range, bearing }
    };
    let x0 = pose(0);
    let mut lm = RefinedLandmark::new(th, Matrix2::zeros(), &x0, &exact(&x0));
    for i in 1..6 {
        let x = pose(i);
        lm.add_sighting(&x, &exact(&x), &rinv);
    }
    lm
}

/// Draws of θ from p(θ | past) ∝ e^{−F_past(θ)} (flat prior) by importance
/// sampling from the Laplace approximation widened ×2: the draws, their
/// log weights.
fn past_draws(
    model: &SlamModel,
    lm: &RefinedLandmark,
    n: usize,
    seed: u64,
) -> Vec<([f64; 2], f64)> {
    let past = Past {
        lm,
        laser: model.laser,
    };
    let m = newton(&past, Vector2::new(lm.m[0], lm.m[1]), 50, 1e-12).unwrap();
    let mut rng = stream(seed, 0);
    (0..n)
        .map(|_| {
            let e = Vector2::new(rng.sample(StandardNormal), rng.sample(StandardNormal));
            let th = m.mu + 2.0 * m.l.tr_solve_lower_triangular(&e).unwrap();
            ([th[0], th[1]], -past.value(&th) + 0.5 * e.dot(&e))
        })
        .collect()
}

/// Brute force over (x, θ): log ∫∫ N(x; f, Σ) p(θ | past) N(z; h(x, θ), Σ₂)
/// dx dθ, self-normalised importance sampling over θ with 200 000 draws
/// (delta-method standard error of the ratio).
fn predictive_refined(
    model: &SlamModel,
    (f, cov): (Pose, Matrix3<f64>),
    th: [f64; 2],
    z: &RangeBearing,
) -> (f64, f64) {
    let lm = refined_past(model, th);
    let draws = past_draws(model, &lm, 200_000, 26);
    let c = cov.cholesky().unwrap().l();
    let r = model.r();
    let rinv = Matrix2::new(1.0 / r[(0, 0)], 0.0, 0.0, 1.0 / r[(1, 1)]);
    let norm = -(2.0 * std::f64::consts::PI).ln() - 0.5 * (r[(0, 0)] * r[(1, 1)]).ln();
    let mut rng = stream(27, 0);
    let wmax = draws.iter().map(|d| d.1).fold(f64::NEG_INFINITY, f64::max);
    let (mut a, mut b) = (
        Vec::with_capacity(draws.len()),
        Vec::with_capacity(draws.len()),
    );
    for (t, lw) in &draws {
        let x = f + c * normal3(&mut rng);
        let (nu, _, _) = innovation(&x, *t, z);
        let w = (lw - wmax).exp();
        a.push(w * (norm - 0.5 * nu.dot(&(rinv * nu))).exp());
        b.push(w);
    }
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    // log(ā/b̄): influence a_i/ā − b_i/b̄.
    let var = a
        .iter()
        .zip(&b)
        .map(|(ai, bi)| (ai / ma - bi / mb).powi(2))
        .sum::<f64>()
        / (n - 1.0);
    ((ma / mb).ln(), (var / n).sqrt())
}

/// `implicit-refine` after an interval: the known groups' landmarks carry
/// earlier sightings and their current values are draws from p(θ | past),
/// so the step's weight (joint draw of pose and θ, backward kernel for the
/// old θ) must average to the predictive likelihood with θ integrated out;
/// the new group goes through the same arrow as a 5-D joint F^j with the
/// interval's prior. Dropping the backward-kernel term or keeping the
/// one-step prior breaks the ratios.
#[test]
fn implicit_refine_weights_after_an_interval_are_its_predictive_likelihoods() {
    let n = 3000;
    let model = model();
    let mut f = ImplicitRefineSlam::new(model, 3 * n, 0.0, NewtonSettings::default()).unwrap();
    let pools: Vec<(RefinedLandmark, Vec<[f64; 2]>)> = {
        // θ_A and θ_C as check_interval_weights places them.
        let mut x = start();
        for _ in 0..=K {
            x = model.step_noise(U, DT).unwrap().0.predict_mean(&x, U);
        }
        let th_a = [x[0] + 6.0, x[1] + 5.0];
        let th_c = [th_a[0] + 0.3, th_a[1] + 0.2];
        [(th_a, 28), (th_c, 29)]
            .iter()
            .map(|&(th, seed)| {
                let lm = refined_past(&model, th);
                // Sampling-importance-resampling of n exact draws.
                let pool = past_draws(&model, &lm, 100_000, seed);
                let mx = pool.iter().map(|d| d.1).fold(f64::NEG_INFINITY, f64::max);
                let cum: Vec<f64> = pool
                    .iter()
                    .scan(0.0, |s, d| {
                        *s += (d.1 - mx).exp();
                        Some(*s)
                    })
                    .collect();
                let total = *cum.last().unwrap();
                let mut rng = stream(seed, 1);
                let picks = (0..n)
                    .map(|_| {
                        let u: f64 = rng.random::<f64>() * total;
                        pool[cum.partition_point(|&c| c < u).min(pool.len() - 1)].0
                    })
                    .collect();
                (lm, picks)
            })
            .collect()
    };
    check_interval_weights_with(
        "implicit-refine",
        &mut f,
        |f, j, _th| {
            let (lm, picks) = &pools[j / n];
            let mut lm = *lm;
            lm.m = picks[j % n];
            f.set.maps[j].push(lm);
        },
        |f| f.set.w.clone(),
        n,
        predictive_refined,
    );
}
