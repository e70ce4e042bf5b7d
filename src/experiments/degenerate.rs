//! `degenerate` — the chain filter on a rigid body whose noise enters
//! through forces only (F Fᵀ singular; `docs/degenerate-chains.md`): the
//! planar quadrotor with its attitude held (`model::planar_quadrotor::
//! attitude_held`, state (x, z, vx, vz), σ = 0.3 on the velocities, (x, z)
//! observed with σ = 0.1 at 100 Hz), 10 s flights under a PD controller on
//! the true state tracking x = sin 0.5t, z = 0.5 sin t. Every filter of one
//! invocation sees the same records and controls (run r: stream r of
//! `--seed`).
//!
//! Rows: the exact Kalman filter, the EKF and UKF (equal to it on a linear
//! model, up to the UKF's sigma points), bootstrap PFs, and the live chain
//! filter (moving frame, chain in the scaled metric λ = degenerate_scale(n))
//! per state count and placement:
//! - `steady`: one version of n states drawn around N(x̂₀, P∞), P∞ the
//!   posterior's steady-state covariance (data-free: the Kalman
//!   covariance after 3 s of steps), offered again as a new lineage at
//!   `recenter_hz` so that the frame is re-centred on the belief
//!   (`chain::snapshot::relabel`; an O(n) install, no build);
//! - `rebuild`: the pipeline's moving frame, a fresh version around the
//!   current belief at `rebuild_hz`;
//! - `prior`: as `steady` but drawn around the prior (to show why the
//!   shape matters).
//!
//! Per row: median over runs of the position RMSE (`rmse`, with the mean's
//! standard error `rmse_se`), the median RMS gap of the position mean to
//! the Kalman mean (`gap_kalman`), runs lost (RMSE above `lost_error` or a
//! refused step), median thread CPU per run (`time_s`, chain: filtering
//! and installs, `build_s` apart) and `cpu_vs_pf1000` = median (time_s +
//! build_s) / the median of the PF with the most particles. CPU is
//! measured in-process; on a loaded machine read the ratios.
//!
//! `--param model=6d`: the full 6-D planar quadrotor instead, with steady
//! versions around a data-free P∞ (see `degenerate_6d.rs`).

use anyhow::Result;
use std::time::Duration;

use super::chain_util::{mean_se, median, Params};
use super::{ExperimentArgs, ExperimentReport, Progress, Row};
use crate::belief::Gaussian;
use crate::chain::frame::{build_framed, FrameBuild};
use crate::chain::metric::{degenerate_scale, ScaledCoords};
use crate::chain::snapshot::{encode, relabel, SnapshotMeta};
use crate::chain::{ChainConfig, NearRule};
use crate::filter::ekf::{Ekf, EkfConfig};
use crate::filter::kalman::Kalman;
use crate::filter::live_chain::LiveChainFilter;
use crate::filter::pf::{Pf, PfConfig};
use crate::filter::ukf::{Ukf, UkfConfig};
use crate::filter::BayesFilter;
use crate::model::linear::LinearSde;
use crate::model::planar_quadrotor::{attitude_held, PlanarQuadrotorParams};
use crate::model::{simulate_observation, Measurement};
use crate::rng::stream;
use crate::rt::clock::thread_cpu_ns;

use beliefbus_core::experiment_params::{p, ParamDoc};

pub const PARAMS: &[ParamDoc] = &[
    p(
        "model",
        "4d",
        "4d: the attitude-held quadrotor; 6d: the full planar quadrotor (steady chains only, P∞ from the linearisation at hover)",
    ),
    p("states", "500,1000,2000,5000", "chain sizes n swept"),
    p(
        "particles",
        "300,1000",
        "PF sizes; the largest is the CPU reference",
    ),
    p(
        "placement",
        "steady",
        "chain versions: steady, rebuild, prior or all",
    ),
    p("horizon_s", "10", "length of each flight (s)"),
    p(
        "recenter_hz",
        "0",
        "steady/prior: rate at which the version is re-installed on the belief (0: 20 in 4d, 10 in 6d)",
    ),
    p("rebuild_hz", "5", "rebuild: rate of fresh versions"),
    p("knn_c", "1.5", "neighbour count constant c of k = c log n"),
    p("inflate", "2", "version states drawn with this × the std"),
    p(
        "lambda",
        "0",
        "scale λ of the noise-free coordinates (0: degenerate_scale(n) in 4d, 4 in 6d)",
    ),
    p(
        "lost_error",
        "0.3",
        "a flight whose position RMSE exceeds this (m) counts as lost",
    ),
];

/// One flight: truth, measurements and the controls applied.
struct Record {
    truth: Vec<[f64; 4]>,
    ys: Vec<[f64; 2]>,
    us: Vec<[f64; 2]>,
}

/// PD control on the true state towards x = sin 0.5t, z = 0.5 sin t.
fn control(t: f64, x: &[f64]) -> [f64; 2] {
    let (xr, zr) = ((0.5 * t).sin(), 0.5 * t.sin());
    let (vxr, vzr) = (0.5 * (0.5 * t).cos(), 0.5 * t.cos());
    [
        4.0 * (xr - x[0]) + 3.0 * (vxr - x[2]),
        4.0 * (zr - x[1]) + 3.0 * (vzr - x[3]),
    ]
}

fn simulate(m: &LinearSde, steps: usize, dt: f64, seed: u64, run: u64) -> Record {
    let mut rng = stream(seed, run);
    let mut x = [0.0; 4];
    let mut rec = Record {
        truth: Vec::with_capacity(steps),
        ys: Vec::with_capacity(steps),
        us: Vec::with_capacity(steps),
    };
    for k in 0..steps {
        let u = control(k as f64 * dt, &x);
        crate::model::discrete::em_integrate(m, &mut x, &u, dt, 1e-3, &mut rng);
        let mut y = [0.0; 2];
        simulate_observation(m, &x, &mut rng, &mut y);
        rec.truth.push(x);
        rec.ys.push(y);
        rec.us.push(u);
    }
    rec
}

/// One filter over one record.
#[derive(Clone, Copy, Debug, Default)]
struct Score {
    rmse: f64,
    gap: f64,
    cpu_s: f64,
    build_s: f64,
    respreads: u64,
    collapses: u64,
    /// First time (s) the position error exceeded the lost threshold.
    t_lost: Option<f64>,
    /// Per axis, |truth − mean| / σ∞ when the error first exceeded the
    /// lost threshold (6-D only).
    z_lost: Option<[f64; 6]>,
    failed: bool,
}

/// Accumulates the position error and the gap to the Kalman means.
struct Tally<'a> {
    rec: &'a Record,
    kalman: Option<&'a [[f64; 2]]>,
    se: f64,
    gap: f64,
    means: Vec<[f64; 2]>,
}

impl<'a> Tally<'a> {
    fn new(rec: &'a Record, kalman: Option<&'a [[f64; 2]]>) -> Self {
        Self {
            rec,
            kalman,
            se: 0.0,
            gap: 0.0,
            means: Vec::with_capacity(rec.ys.len()),
        }
    }
    fn add(&mut self, k: usize, b: &Gaussian, unscale: f64) {
        let m = [b.mean[0] / unscale, b.mean[1] / unscale];
        let t = &self.rec.truth[k];
        let e2 = (m[0] - t[0]).powi(2) + (m[1] - t[1]).powi(2);
        self.se += if e2.is_finite() { e2 } else { 1e6 };
        if let Some(kf) = self.kalman {
            let g2 = (m[0] - kf[k][0]).powi(2) + (m[1] - kf[k][1]).powi(2);
            self.gap += if g2.is_finite() { g2 } else { 1e6 };
        }
        self.means.push(m);
    }
    fn score(&self) -> Score {
        let n = self.rec.ys.len().max(1) as f64;
        Score {
            rmse: (self.se / n).sqrt(),
            gap: (self.gap / n).sqrt(),
            ..Score::default()
        }
    }
}

/// A filter on its own (no versions) over `rec`.
fn run_plain(
    f: &mut dyn BayesFilter,
    rec: &Record,
    dt: f64,
    kalman: Option<&[[f64; 2]]>,
) -> (Score, Vec<[f64; 2]>) {
    let mut tally = Tally::new(rec, kalman);
    let c0 = thread_cpu_ns();
    let mut failed = false;
    for k in 0..rec.ys.len() {
        let t = (k + 1) as f64 * dt;
        failed |= f.predict(t, &rec.us[k]).is_err();
        failed |= f.update(&Measurement::full(&rec.ys[k])).is_err();
        tally.add(k, &f.belief(), 1.0);
    }
    let mut s = tally.score();
    s.cpu_s = (thread_cpu_ns() - c0) as f64 * 1e-9;
    s.failed = failed;
    (s, tally.means)
}

/// How the chain's versions are placed (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Placement {
    Steady,
    Rebuild,
    Prior,
}

/// The chain filter's settings.
#[derive(Clone, Copy, Debug)]
struct ChainRun {
    n: usize,
    placement: Placement,
    recenter_every: usize,
    rebuild_every: usize,
    knn_c: f64,
    inflate: f64,
    lambda: f64,
}

/// The posterior's steady-state covariance: `secs` of Kalman steps from
/// `prior` (the covariance of a linear-Gaussian filter does not depend on
/// the data, so zeros stand in for it).
fn steady_covariance(m: &LinearSde, prior: &Gaussian, dt: f64, secs: f64) -> Result<Gaussian> {
    let mut kf = Kalman::new(m.clone(), prior, 0.0)?;
    for j in 0..(secs / dt).round() as usize {
        kf.predict((j + 1) as f64 * dt, &[0.0, 0.0])?;
        kf.update(&Measurement::full(&[0.0, 0.0]))?;
    }
    Ok(kf.belief())
}

/// `g` in the scaled coordinates x' = S x.
fn scaled(g: &Gaussian, s: &[f64]) -> Gaussian {
    let mut out = *g;
    for a in 0..g.dim {
        out.mean_mut()[a] = g.mean[a] * s[a];
        for c in 0..g.dim {
            out.set_cov(a, c, g.cov_at(a, c) * s[a] * s[c]);
        }
    }
    out
}

/// The live chain filter over `rec` (see [`Placement`]).
fn run_chain(
    m: &LinearSde,
    prior: &Gaussian,
    steady: &Gaussian,
    rec: &Record,
    dt: f64,
    kalman: &[[f64; 2]],
    cr: ChainRun,
    rng_run: u64,
    seed: u64,
) -> Result<Score> {
    let lambda = if cr.lambda > 0.0 {
        cr.lambda
    } else {
        degenerate_scale(cr.n, 4, 2)
    };
    let scale = [lambda, lambda, 1.0, 1.0];
    let sm = ScaledCoords::new(m.clone(), &scale)?;
    let pr = scaled(prior, &scale);
    let ekf = Ekf::new(sm.clone(), &EkfConfig::default(), &pr, 0.0)?;
    let mut lf: LiveChainFilter<_, Vec<u64>> =
        LiveChainFilter::new(sm.clone(), Box::new(ekf), cr.n, &pr, 0.0);
    lf.set_moving_frame(true);
    let fb = FrameBuild {
        inflate: cr.inflate,
        uniform_fraction: 0.0,
        min_std_fraction: 0.002,
        chain: ChainConfig::moment_matched(4).with_near(NearRule::Knn { c: cr.knn_c }),
        dt,
    };
    let mut rng = stream(seed ^ 0xde9e, rng_run);
    let mut tally = Tally::new(rec, Some(kalman));
    let (mut build_ns, mut failed) = (0u64, false);
    let mut snap: Vec<u64> = Vec::new();
    let c0 = thread_cpu_ns();
    for k in 0..rec.ys.len() {
        let meta = SnapshotMeta {
            version: k as u64 + 1,
            lineage: k as u64 + 1,
            t_pub_ns: 0,
        };
        let build = match cr.placement {
            Placement::Rebuild => k % cr.rebuild_every == 0,
            Placement::Steady | Placement::Prior => k == 0,
        };
        if build {
            let b0 = thread_cpu_ns();
            let mut around = lf.belief();
            if cr.placement == Placement::Steady {
                let s = scaled(steady, &scale);
                around.cov_mut().copy_from_slice(s.cov());
            }
            let (mut c, eq) = build_framed(&sm, &around, cr.n, &fb, &mut rng)?;
            snap = encode(&mut c, eq.delta(), meta);
            build_ns += thread_cpu_ns() - b0;
            lf.offer(snap.clone())?;
            lf.advance(Duration::from_secs(10))?;
        } else if cr.placement != Placement::Rebuild && k % cr.recenter_every == 0 {
            // Counted as filtering: an install, O(n), no chain built.
            relabel(&mut snap, meta)?;
            lf.offer(snap.clone())?;
            lf.advance(Duration::from_secs(10))?;
        }
        let t = (k + 1) as f64 * dt;
        failed |= lf.predict(t, &rec.us[k]).is_err();
        failed |= lf.update(&Measurement::full(&rec.ys[k])).is_err();
        tally.add(k, &lf.belief(), lambda);
    }
    let mut s = tally.score();
    s.build_s = build_ns as f64 * 1e-9;
    s.cpu_s = (thread_cpu_ns() - c0) as f64 * 1e-9 - s.build_s;
    s.respreads = lf.respreads();
    s.collapses = lf.collapses();
    s.failed = failed;
    Ok(s)
}

/// A result row over runs.
fn row(method: &str, states: usize, v: &[Score], lost_error: f64, pf_cpu: f64) -> Row {
    let rmse: Vec<f64> = v.iter().map(|s| s.rmse).collect();
    let finite: Vec<f64> = rmse.iter().copied().filter(|e| e.is_finite()).collect();
    let (_, se) = mean_se(&finite);
    let lost = v
        .iter()
        .filter(|s| s.failed || !(s.rmse <= lost_error))
        .count();
    let cpu = median(&v.iter().map(|s| s.cpu_s).collect::<Vec<_>>());
    let build = median(&v.iter().map(|s| s.build_s).collect::<Vec<_>>());
    let total = median(&v.iter().map(|s| s.cpu_s + s.build_s).collect::<Vec<_>>());
    Row::new(method)
        .int("states", states as u64)
        .num("rmse", median(&rmse))
        .num("rmse_se", se)
        .num(
            "gap_kalman",
            median(&v.iter().map(|s| s.gap).collect::<Vec<_>>()),
        )
        .int("lost", lost as u64)
        .int("respreads", v.iter().map(|s| s.respreads).sum())
        .int("collapses", v.iter().map(|s| s.collapses).sum())
        .num("time_s", cpu)
        .num("build_s", build)
        .num("cpu_vs_pf", total / pf_cpu.max(1e-12))
}

pub fn run(args: &ExperimentArgs) -> Result<ExperimentReport> {
    let mut rep = ExperimentReport::new("degenerate");
    let mut p = Params::new(args);
    let runs = args.runs.unwrap_or(20);
    rep.param("runs", runs);
    rep.param("seed", args.seed);
    let model_name = p.choice(&mut rep, "model", "4d", &["4d", "6d"])?;
    let sizes = p.list(&mut rep, "states", &[500, 1000, 2000, 5000])?;
    let particles = p.list(&mut rep, "particles", &[300, 1000])?;
    let placement = p.choice(
        &mut rep,
        "placement",
        "steady",
        &["steady", "rebuild", "prior", "all"],
    )?;
    let t_end = p.f64(&mut rep, "horizon_s", 10.0)?;
    let recenter_hz = p.f64(&mut rep, "recenter_hz", 0.0)?;
    let rebuild_hz = p.f64(&mut rep, "rebuild_hz", 5.0)?;
    let knn_c = p.f64(&mut rep, "knn_c", 1.5)?;
    let inflate = p.f64(&mut rep, "inflate", 2.0)?;
    let lambda = p.f64(&mut rep, "lambda", 0.0)?;
    let lost_error = p.f64(&mut rep, "lost_error", 0.3)?;
    p.finish()?;
    if sizes.iter().any(|&n| n < 50) || !(recenter_hz >= 0.0 && rebuild_hz > 0.0) {
        anyhow::bail!("states must be ≥ 50, recenter_hz ≥ 0 and rebuild_hz > 0");
    }
    let recenter_hz = match (recenter_hz > 0.0, model_name.as_str()) {
        (true, _) => recenter_hz,
        (false, "6d") => six::DEFAULT_RECENTER_HZ,
        (false, _) => 20.0,
    };
    if lambda < 0.0 {
        anyhow::bail!("lambda must be ≥ 0");
    }
    let dt = 0.01;
    let steps = (t_end / dt).round() as usize;
    let every = |hz: f64| ((1.0 / (hz * dt)).round() as usize).max(1);
    if model_name == "6d" {
        if placement != "steady" {
            anyhow::bail!("model=6d runs the steady placement only");
        }
        let s = six::Settings {
            runs,
            seed: args.seed,
            sizes,
            particles,
            steps,
            recenter_every: every(recenter_hz),
            knn_c,
            inflate,
            lambda,
            lost_error,
            progress: args.progress,
        };
        six::run(&mut rep, &s)?;
        return Ok(rep);
    }
    let placements: Vec<Placement> = match placement.as_str() {
        "steady" => vec![Placement::Steady],
        "rebuild" => vec![Placement::Rebuild],
        "prior" => vec![Placement::Prior],
        _ => vec![Placement::Steady, Placement::Rebuild, Placement::Prior],
    };
    let model = attitude_held(&PlanarQuadrotorParams::default()).map_err(anyhow::Error::msg)?;
    let prior = Gaussian::diagonal(&[0.0; 4], &[0.05; 4]);
    let steady = steady_covariance(&model, &prior, dt, 3.0)?;
    let n_methods = 3 + particles.len() + placements.len() * sizes.len();
    let mut bar = Progress::new("degenerate", runs * n_methods, args.progress);
    let mut scores: Vec<(String, usize, Vec<Score>)> = Vec::new();
    let mut push = |name: String, n: usize, s: Score| match scores
        .iter_mut()
        .find(|r| r.0 == name && r.1 == n)
    {
        Some(r) => r.2.push(s),
        None => scores.push((name, n, vec![s])),
    };
    for r in 0..runs {
        let rec = simulate(&model, steps, dt, args.seed, r as u64);
        let mut kf = Kalman::new(model.clone(), &prior, 0.0)?;
        let (s, kmeans) = run_plain(&mut kf, &rec, dt, None);
        push("kalman".into(), 0, s);
        let mut ekf = Ekf::new(model.clone(), &EkfConfig::default(), &prior, 0.0)?;
        push(
            "ekf".into(),
            0,
            run_plain(&mut ekf, &rec, dt, Some(&kmeans)).0,
        );
        let mut ukf = Ukf::new(model.clone(), &UkfConfig::default(), &prior, 0.0)?;
        push(
            "ukf".into(),
            0,
            run_plain(&mut ukf, &rec, dt, Some(&kmeans)).0,
        );
        bar.inc(3);
        for &np in &particles {
            let cfg = PfConfig {
                particles: np,
                max_dt: dt,
                seed: args.seed.wrapping_mul(1000).wrapping_add(r as u64),
                ..PfConfig::default()
            };
            let mut pf = Pf::new(model.clone(), &cfg, &prior, 0.0)?;
            push(
                "pf".into(),
                np,
                run_plain(&mut pf, &rec, dt, Some(&kmeans)).0,
            );
            bar.tick();
        }
        for &pl in &placements {
            for &n in &sizes {
                let cr = ChainRun {
                    n,
                    placement: pl,
                    recenter_every: every(recenter_hz),
                    rebuild_every: every(rebuild_hz),
                    knn_c,
                    inflate,
                    lambda,
                };
                let s = run_chain(
                    &model, &prior, &steady, &rec, dt, &kmeans, cr, r as u64, args.seed,
                )?;
                let name = format!("chain-{}", format!("{pl:?}").to_lowercase());
                push(name, n, s);
                bar.tick();
            }
        }
    }
    let np_max = *particles.iter().max().unwrap_or(&1000);
    let pf_cpu = scores
        .iter()
        .find(|r| r.0 == "pf" && r.1 == np_max)
        .map(|r| median(&r.2.iter().map(|s| s.cpu_s).collect::<Vec<_>>()))
        .unwrap_or(f64::NAN);
    for (name, n, v) in &scores {
        rep.results.push(row(name, *n, v, lost_error, pf_cpu));
    }
    rep.notes.push(format!(
        "cpu_vs_pf: median thread CPU per run incl. chain builds over the PF-{np_max}'s, same run; the steady version is built once per run (data-free, it could be shared by every run)"
    ));
    rep.notes.push(
        "no paper figure: acceptance is the chain reaching the PF-1000's error at ≤ 1× (goal 0.5×) its CPU with no run lost".into(),
    );
    Ok(rep)
}

#[path = "degenerate_6d.rs"]
mod six;

#[cfg(test)]
#[path = "degenerate_tests.rs"]
mod tests;
