//! Measurement: the live chain filter (moving-frame versions in the scaled
//! metric) against Kalman and particle filters on the 4-D attitude-held
//! quadrotor (noise on the velocities only), 10 s flights at 100 Hz under
//! a PD controller on the true state. Run with
//! `cargo test -p beliefbus-core --lib --release rigid_body -- --ignored --nocapture`
//! (env: RB_SEEDS, RB_N="500,2000,5000", RB_PERIOD steps between versions,
//! RB_LAMBDA (0: degenerate_scale), RB_KNN, RB_ADVECTED, RB_INFLATE,
//! RB_SS=1 versions around the steady-state covariance, RB_RECENTER steps
//! between re-installs of the same version). The experiment `degenerate`
//! is the kept configuration.

use crate::belief::Gaussian;
use crate::chain::frame::{build_framed, FrameBuild};
use crate::chain::metric::{degenerate_scale, ScaledCoords};
use crate::chain::snapshot::{encode, SnapshotMeta};
use crate::chain::{ChainConfig, NearRule};
use crate::filter::ekf::{Ekf, EkfConfig};
use crate::filter::kalman::Kalman;
use crate::filter::live_chain::LiveChainFilter;
use crate::filter::pf::{Pf, PfConfig};
use crate::filter::BayesFilter;
use crate::model::linear::LinearSde;
use crate::model::planar_quadrotor::{attitude_held, PlanarQuadrotorParams};
use crate::model::{simulate_observation, Measurement};
use std::time::Duration;

/// Per method: name, RMSEs, gaps to Kalman, seconds.
type Row = (String, Vec<f64>, Vec<f64>, Vec<f64>);

const DT: f64 = 0.01;
const STEPS: usize = 1000;

fn clock_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

fn env<T: std::str::FromStr>(k: &str, d: T) -> T {
    std::env::var(k)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(d)
}

fn control(t: f64, x: &[f64]) -> [f64; 2] {
    let (xr, zr) = ((0.5 * t).sin(), 0.5 * t.sin());
    let (vxr, vzr) = (0.5 * (0.5 * t).cos(), 0.5 * t.cos());
    [
        4.0 * (xr - x[0]) + 3.0 * (vxr - x[2]),
        4.0 * (zr - x[1]) + 3.0 * (vzr - x[3]),
    ]
}

struct Record {
    truth: Vec<[f64; 4]>,
    ys: Vec<[f64; 2]>,
    us: Vec<[f64; 2]>,
}

fn simulate(m: &LinearSde, seed: u64) -> Record {
    let mut rng = crate::rng::stream(seed, 0);
    let mut x = [0.0; 4];
    let mut rec = Record {
        truth: vec![],
        ys: vec![],
        us: vec![],
    };
    for k in 0..STEPS {
        let u = control(k as f64 * DT, &x);
        crate::model::discrete::em_integrate(m, &mut x, &u, DT, 1e-3, &mut rng);
        let mut y = [0.0; 2];
        simulate_observation(m, &x, &mut rng, &mut y);
        rec.truth.push(x);
        rec.ys.push(y);
        rec.us.push(u);
    }
    rec
}

fn prior(lambda: f64) -> Gaussian {
    Gaussian::diagonal(&[0.0; 4], &[0.05 * lambda, 0.05 * lambda, 0.05, 0.05])
}

/// Position RMSE, RMS gap of the position mean to `kf_means` (if given),
/// wall seconds.
fn score(
    f: &mut dyn BayesFilter,
    rec: &Record,
    unscale: f64,
    kf: Option<&[[f64; 2]]>,
    means: &mut Vec<[f64; 2]>,
) -> (f64, f64, f64) {
    let c0 = clock_ns();
    let (mut se, mut gap) = (0.0, 0.0);
    for k in 0..STEPS {
        let t = (k + 1) as f64 * DT;
        if f.predict(t, &rec.us[k]).is_err() {
            return (f64::INFINITY, f64::INFINITY, 0.0);
        }
        let _ = f.update(&Measurement::full(&rec.ys[k]));
        let b = f.belief();
        let m = [b.mean[0] / unscale, b.mean[1] / unscale];
        means.push(m);
        let e2 = (m[0] - rec.truth[k][0]).powi(2) + (m[1] - rec.truth[k][1]).powi(2);
        se += if e2.is_finite() { e2 } else { 1e6 };
        if let Some(kf) = kf {
            let g2 = (m[0] - kf[k][0]).powi(2) + (m[1] - kf[k][1]).powi(2);
            gap += if g2.is_finite() { g2 } else { 1e6 };
        }
    }
    let cpu = (clock_ns() - c0) as f64 * 1e-9;
    ((se / STEPS as f64).sqrt(), (gap / STEPS as f64).sqrt(), cpu)
}

/// The chain filter with versions every `period` steps; returns (rmse,
/// gap, filter seconds, build seconds, respreads).
fn chain_run(
    m: &LinearSde,
    rec: &Record,
    kf: &[[f64; 2]],
    n: usize,
    lambda: f64,
    period: usize,
    seed: u64,
) -> (f64, f64, f64, f64, u64) {
    let sm = ScaledCoords::new(m.clone(), &[lambda, lambda, 1.0, 1.0]).unwrap();
    let pr = prior(lambda);
    let ekf = Ekf::new(sm.clone(), &EkfConfig::default(), &pr, 0.0).unwrap();
    let mut lf: LiveChainFilter<_, Vec<u64>> =
        LiveChainFilter::new(sm.clone(), Box::new(ekf), n, &pr, 0.0);
    lf.set_moving_frame(true);
    let mut cfg = ChainConfig::moment_matched(4).with_near(NearRule::Knn {
        c: env("RB_KNN", 1.5),
    });
    if env("RB_ADVECTED", 0) == 1 {
        cfg = cfg.with_step(DT);
    }
    let fb = FrameBuild {
        inflate: env("RB_INFLATE", 2.0),
        uniform_fraction: 0.0,
        min_std_fraction: 0.002,
        chain: cfg,
        dt: DT,
    };
    let mut rng = crate::rng::stream(seed, 9);
    let (mut built, mut se, mut gap) = (0.0, 0.0, 0.0);
    let recenter: usize = env("RB_RECENTER", 0);
    let mut snap: Vec<u64> = vec![];
    let c0 = clock_ns();
    for k in 0..STEPS {
        if recenter > 0 && k % period != 0 && k % recenter == 0 {
            // The same version re-offered as a new lineage: installed from
            // the Gaussian belief with the frame re-centred on it.
            let b0 = clock_ns();
            let mut s2 = snap.clone();
            s2[1] = k as u64 + 1;
            s2[2] = k as u64 + 1;
            lf.offer(s2).unwrap();
            lf.advance(Duration::from_secs(10)).unwrap();
            built += (clock_ns() - b0) as f64 * 1e-9 * 0.0;
        }
        if k % period == 0 {
            let b0 = clock_ns();
            let mut g = lf.belief();
            if env("RB_SS", 0) == 1 {
                // The posterior's steady-state covariance (data-free for a
                // linear model): 3 s of Kalman steps, scaled.
                let mut kf = Kalman::new(m.clone(), &prior(1.0), 0.0).unwrap();
                for j in 0..300 {
                    kf.predict((j + 1) as f64 * DT, &[0.0, 0.0]).unwrap();
                    kf.update(&Measurement::full(&[0.0, 0.0])).unwrap();
                }
                let p = kf.belief();
                let sc = [lambda, lambda, 1.0, 1.0];
                for a in 0..4 {
                    for c in 0..4 {
                        g.set_cov(a, c, p.cov_at(a, c) * sc[a] * sc[c]);
                    }
                }
                if k == 0 {
                    eprintln!(
                        "steady-state std {:?}",
                        (0..4).map(|a| p.cov_at(a, a).sqrt()).collect::<Vec<_>>()
                    );
                }
            }
            let (mut c, eq) = build_framed(&sm, &g, n, &fb, &mut rng).unwrap();
            let meta = SnapshotMeta {
                version: k as u64 + 1,
                lineage: k as u64 + 1,
                t_pub_ns: 0,
            };
            snap = encode(&mut c, eq.delta(), meta);
            lf.offer(snap.clone()).unwrap();
            lf.advance(Duration::from_secs(10)).unwrap();
            built += (clock_ns() - b0) as f64 * 1e-9;
        }
        let t = (k + 1) as f64 * DT;
        if lf.predict(t, &rec.us[k]).is_err() {
            return (f64::INFINITY, f64::INFINITY, 0.0, built, 0);
        }
        let _ = lf.update(&Measurement::full(&rec.ys[k]));
        let b = lf.belief();
        let mm = [b.mean[0] / lambda, b.mean[1] / lambda];
        let e2 = (mm[0] - rec.truth[k][0]).powi(2) + (mm[1] - rec.truth[k][1]).powi(2);
        se += if e2.is_finite() { e2 } else { 1e6 };
        let g2 = (mm[0] - kf[k][0]).powi(2) + (mm[1] - kf[k][1]).powi(2);
        gap += if g2.is_finite() { g2 } else { 1e6 };
    }
    let cpu = (clock_ns() - c0) as f64 * 1e-9 - built;
    (
        (se / STEPS as f64).sqrt(),
        (gap / STEPS as f64).sqrt(),
        cpu,
        built,
        lf.respreads(),
    )
}

fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

#[test]
#[ignore = "measurement: chain vs Kalman vs PF on the attitude-held quadrotor"]
fn rigid_body_chain_vs_kalman_and_pf() {
    let m = attitude_held(&PlanarQuadrotorParams::default()).unwrap();
    let seeds: u64 = env("RB_SEEDS", 20);
    let ns: Vec<usize> = std::env::var("RB_N")
        .unwrap_or_else(|_| "500,2000,5000".into())
        .split(',')
        .map(|s| s.parse().unwrap())
        .collect();
    let period: usize = env("RB_PERIOD", 20);
    let lam_fix: f64 = env("RB_LAMBDA", 0.0);
    let lost = 0.3;
    let mut rows: Vec<Row> = vec![];
    let mut push = |name: String, r: f64, g: f64, c: f64| {
        if let Some(row) = rows.iter_mut().find(|x| x.0 == name) {
            row.1.push(r);
            row.2.push(g);
            row.3.push(c);
        } else {
            rows.push((name, vec![r], vec![g], vec![c]));
        }
    };
    for s in 0..seeds {
        let rec = simulate(&m, 100 + s);
        let pr = prior(1.0);
        let mut kf = Kalman::new(m.clone(), &pr, 0.0).unwrap();
        let mut kfm = vec![];
        let r = score(&mut kf, &rec, 1.0, None, &mut kfm);
        push("kalman".into(), r.0, 0.0, r.2);
        for np in [300usize, 1000] {
            let cfg = PfConfig {
                particles: np,
                max_dt: DT,
                seed: 7 + s,
                ..PfConfig::default()
            };
            let mut pf = Pf::new(m.clone(), &cfg, &pr, 0.0).unwrap();
            let r = score(&mut pf, &rec, 1.0, Some(&kfm), &mut vec![]);
            push(format!("pf-{np}"), r.0, r.1, r.2);
        }
        for &n in &ns {
            let lambda = if lam_fix > 0.0 {
                lam_fix
            } else {
                degenerate_scale(n, 4, 2)
            };
            let r = chain_run(&m, &rec, &kfm, n, lambda, period, s);
            push(format!("chain-{n}"), r.0, r.1, r.2);
            push(format!("chain-{n}+builds"), r.0, r.1, r.2 + r.3);
            if r.4 > 0 {
                eprintln!("seed {s} n {n}: respreads {}", r.4);
            }
        }
    }
    let pf_cpu = median(&rows.iter().find(|r| r.0 == "pf-1000").unwrap().3);
    for (name, e, g, c) in &rows {
        let nl = e.iter().filter(|v| **v > lost).count();
        eprintln!(
            "{name:18} median rmse {:.4} gap-to-KF {:.4}  lost {nl}/{seeds}  cpu / pf-1000 {:.2}",
            median(e),
            median(g),
            median(c) / pf_cpu
        );
    }
}
