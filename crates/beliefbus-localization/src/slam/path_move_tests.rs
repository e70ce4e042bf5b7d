//! The resample-move kernel leaves its target invariant: a set of exact
//! draws of the window's poses, moved many times, keeps the exact means
//! and variances. Two independent answers: with no sightings the target is
//! the motion model's own path distribution (forward simulation); with
//! sightings of a known landmark it is the prior path reweighted by the
//! likelihood (self-normalised importance sampling over 200 000 prior
//! paths, a different estimator from the chain).

use super::assoc::RangeBearing;
use super::path_move::{MoveConfig, PathWindow};
use crate::carpark::normal3;
use crate::geometry::{Point, Pose};
use crate::laser::{predict, term_cost, LaserNoise, Observation};
use crate::vehicle::{Control, MotionNoise, StepNoise, Ute};
use beliefbus_core::rng::SimRng;
use rand::{RngExt, SeedableRng};

const W: usize = 5;

fn setup() -> (Ute, Control, StepNoise) {
    let ute = Ute {
        dt: 0.025,
        ..Ute::default()
    };
    let u = Control { v: 3.0, alpha: 0.2 };
    let noise = StepNoise::new(&ute, u, &MotionNoise::default()).unwrap();
    (ute, u, noise)
}

/// A path of W steps from the anchor by the motion model.
fn forward(ute: &Ute, u: Control, noise: &StepNoise, rng: &mut SimRng) -> [Pose; W + 1] {
    let mut p = [Pose::zeros(); W + 1];
    for s in 1..=W {
        p[s] = ute.predict_mean(&p[s - 1], u) + noise.draw(p[s - 1][2], &normal3(rng));
    }
    p
}

/// Mean and variance of coordinate c over `xs`.
fn moments(xs: &[Pose], c: usize) -> (f64, f64) {
    let n = xs.len() as f64;
    let m = xs.iter().map(|x| x[c]).sum::<f64>() / n;
    let v = xs.iter().map(|x| (x[c] - m).powi(2)).sum::<f64>() / n;
    (m, v)
}

/// Coordinate `c` of the moved poses `xs` against a reference mean and
/// variance: the mean within `k` standard errors `se`, the variance within
/// the relative tolerance `var_tol`.
#[allow(clippy::too_many_arguments)]
fn assert_moments(
    xs: &[Pose],
    c: usize,
    mean: f64,
    var: f64,
    se: f64,
    k: f64,
    var_tol: f64,
    what: &str,
) {
    let (m1, v1) = moments(xs, c);
    assert!(
        (m1 - mean).abs() < k * se,
        "{what} coord {c}: mean {m1} vs {mean} (se {se})"
    );
    assert!(
        (v1 / var - 1.0).abs() < var_tol,
        "{what} coord {c}: var {v1} vs {var}"
    );
}

/// Load `paths` into a window (one particle per path) with `sights` (step,
/// return) for every particle against landmark 0.
fn load(paths: &[[Pose; W + 1]], sights: &[(usize, RangeBearing)], cfg: MoveConfig) -> PathWindow {
    let (ute, u, noise) = setup();
    let mut w = PathWindow::new(paths.len(), cfg).unwrap();
    w.reset(&Pose::zeros());
    for s in 1..=W {
        w.advance(ute, u, noise);
        for (j, p) in paths.iter().enumerate() {
            w.set_pose(j, p[s]);
            for &(_, z) in sights.iter().filter(|(t, _)| *t == s) {
                w.add_sighting(j, 0, z);
            }
        }
    }
    w
}

/// Move every particle `sweeps` times; the poses at the given ages.
fn moved(
    w: &mut PathWindow,
    laser: &LaserNoise,
    theta: Point,
    rng: &mut SimRng,
    age: usize,
) -> Vec<Pose> {
    for j in 0..w_len(w) {
        w.move_particle(j, laser, |_| theta, rng);
    }
    (0..w_len(w)).map(|j| w.pose(j, age)).collect()
}

fn w_len(w: &PathWindow) -> usize {
    w.particles()
}

#[test]
fn without_sightings_the_move_keeps_the_motion_models_path_distribution() {
    let (ute, u, noise) = setup();
    let mut rng = SimRng::seed_from_u64(11);
    let n = 4000;
    let start: Vec<_> = (0..n).map(|_| forward(&ute, u, &noise, &mut rng)).collect();
    let reference: Vec<_> = (0..n).map(|_| forward(&ute, u, &noise, &mut rng)).collect();
    let cfg = MoveConfig {
        window: W,
        sweeps: 20,
        scale: 0.7,
    };
    let mut w = load(&start, &[], cfg);
    let laser = LaserNoise::default();
    for age in [0, 2, 4] {
        let xs = if age == 0 {
            moved(&mut w, &laser, [0.0, 0.0], &mut rng, 0)
        } else {
            (0..n).map(|j| w.pose(j, age)).collect()
        };
        let refs: Vec<Pose> = reference.iter().map(|p| p[W - age]).collect();
        let unmoved: Vec<Pose> = start.iter().map(|p| p[W - age]).collect();
        let changed = xs.iter().zip(&unmoved).filter(|(a, b)| a != b).count();
        assert!(
            changed > n / 2,
            "age {age}: only {changed} of {n} poses moved"
        );
        for c in 0..3 {
            let (_, v1) = moments(&xs, c);
            let (m2, v2) = moments(&refs, c);
            let se = ((v1 + v2) / n as f64).sqrt();
            assert_moments(&xs, c, m2, v2, se, 5.0, 0.15, &format!("age {age}"));
        }
    }
    let rate = w.accepted as f64 / w.proposed as f64;
    assert!(rate > 0.2 && rate < 0.95, "acceptance {rate}");
}

#[test]
fn with_sightings_the_move_keeps_the_posterior_of_importance_sampling() {
    let (ute, u, noise) = setup();
    let mut rng = SimRng::seed_from_u64(12);
    let theta: Point = [4.0, 6.0];
    // A broad laser, so that importance sampling from the prior is accurate.
    let laser = LaserNoise {
        var_range: 0.3,
        var_bearing: 0.03,
    };
    let truth = forward(&ute, u, &noise, &mut rng);
    let obs_at = [2usize, 5];
    let sights: Vec<(usize, RangeBearing)> = obs_at
        .iter()
        .map(|&s| {
            let (r, b) = predict(&truth[s], theta);
            let e = normal3(&mut rng);
            (
                s,
                RangeBearing {
                    range: r + laser.var_range.sqrt() * e[0],
                    bearing: b + laser.var_bearing.sqrt() * e[1],
                },
            )
        })
        .collect();
    let loglik = |p: &[Pose; W + 1]| -> f64 {
        sights
            .iter()
            .map(|(s, z)| {
                let o = Observation {
                    range: z.range,
                    bearing: z.bearing,
                    landmark: 0,
                };
                -term_cost(&p[*s], theta, &o, &laser)
            })
            .sum()
    };
    let big = 200_000;
    let prior: Vec<_> = (0..big)
        .map(|_| forward(&ute, u, &noise, &mut rng))
        .collect();
    let lw: Vec<f64> = prior.iter().map(loglik).collect();
    let mx = lw.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let wts: Vec<f64> = lw.iter().map(|l| (l - mx).exp()).collect();
    let tot: f64 = wts.iter().sum();
    let ess = tot * tot / wts.iter().map(|w| w * w).sum::<f64>();
    eprintln!("importance sampling ESS {ess}");
    assert!(ess > 5000.0, "importance sampling ESS {ess}");
    // Exact-ish posterior draws: multinomial resampling of the prior paths.
    let n = 4000;
    let mut cum = Vec::with_capacity(big);
    let mut acc = 0.0;
    for w in &wts {
        acc += w / tot;
        cum.push(acc);
    }
    let start: Vec<_> = (0..n)
        .map(|_| {
            let r: f64 = rng.random();
            prior[cum.partition_point(|&c| c < r).min(big - 1)]
        })
        .collect();
    let cfg = MoveConfig {
        window: W,
        sweeps: 30,
        scale: 0.5,
    };
    let mut w = load(&start, &sights, cfg);
    let x0 = moved(&mut w, &laser, theta, &mut rng, 0);
    for age in [0, 3] {
        let xs: Vec<Pose> = if age == 0 {
            x0.clone()
        } else {
            (0..n).map(|j| w.pose(j, age)).collect()
        };
        for c in 0..3 {
            let mean = prior
                .iter()
                .zip(&wts)
                .map(|(p, q)| q * p[W - age][c])
                .sum::<f64>()
                / tot;
            let var = prior
                .iter()
                .zip(&wts)
                .map(|(p, q)| q * (p[W - age][c] - mean).powi(2))
                .sum::<f64>()
                / tot;
            // The chain's draws are correlated through the resampled
            // duplicates; 6 SE of n independent draws plus the estimator's.
            let se = (var / n as f64 + var / ess).sqrt();
            assert_moments(&xs, c, mean, var, se, 6.0, 0.2, &format!("age {age}"));
        }
    }
    let rate = w.accepted as f64 / w.proposed as f64;
    assert!(rate > 0.1, "acceptance {rate}");
}
