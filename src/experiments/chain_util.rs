//! Helpers shared by the Markov-chain experiments: typed
//! `--param` parsing that records every value in the report, truth and
//! observation simulation, and running a filter over a record.

use std::time::Instant;

use anyhow::{bail, Result};

use super::{ExperimentArgs, ExperimentReport};
use crate::belief::Gaussian;
use crate::filter::BayesFilter;
use crate::model::discrete::em_integrate;
use crate::model::{simulate_observation, Measurement, SdeModel};
use crate::rng::SimRng;
use beliefbus_core::experiment_params::debug_check_default;

/// `--param` values with defaults; every value read is recorded in the
/// report's params, and unknown keys are an error.
pub struct Params<'a> {
    args: &'a ExperimentArgs,
    used: Vec<String>,
}

impl<'a> Params<'a> {
    pub fn new(args: &'a ExperimentArgs) -> Self {
        Self { args, used: vec![] }
    }

    fn raw(&mut self, key: &str) -> Option<&'a str> {
        self.used.push(key.to_string());
        self.args
            .params
            .iter()
            .rev()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    /// A float parameter.
    pub fn f64(&mut self, rep: &mut ExperimentReport, key: &str, default: f64) -> Result<f64> {
        debug_check_default(self.args.doc, key, &default.to_string());
        let v = match self.raw(key) {
            Some(s) => s
                .parse::<f64>()
                .map_err(|_| anyhow::anyhow!("--param {key}={s}: not a number"))?,
            None => default,
        };
        if !v.is_finite() {
            bail!("--param {key}: must be finite");
        }
        rep.param(key, v);
        Ok(v)
    }

    /// An integer parameter.
    pub fn usize(
        &mut self,
        rep: &mut ExperimentReport,
        key: &str,
        default: usize,
    ) -> Result<usize> {
        debug_check_default(self.args.doc, key, &default.to_string());
        let v = match self.raw(key) {
            Some(s) => s
                .parse::<usize>()
                .map_err(|_| anyhow::anyhow!("--param {key}={s}: not a non-negative integer"))?,
            None => default,
        };
        rep.param(key, v);
        Ok(v)
    }

    /// A comma-separated list of integers.
    pub fn list(
        &mut self,
        rep: &mut ExperimentReport,
        key: &str,
        default: &[usize],
    ) -> Result<Vec<usize>> {
        debug_check_default(self.args.doc, key, &super::pi_common::join(default));
        let v = match self.raw(key) {
            Some(s) => s
                .split(',')
                .map(|x| x.trim().parse::<usize>())
                .collect::<Result<Vec<_>, _>>()
                .map_err(|_| anyhow::anyhow!("--param {key}={s}: not a list of integers"))?,
            None => default.to_vec(),
        };
        if v.is_empty() {
            bail!("--param {key}: empty list");
        }
        rep.param(key, serde_json::json!(v));
        Ok(v)
    }

    /// A string choice among `allowed`.
    pub fn choice(
        &mut self,
        rep: &mut ExperimentReport,
        key: &str,
        default: &str,
        allowed: &[&str],
    ) -> Result<String> {
        debug_check_default(self.args.doc, key, default);
        let v = self.raw(key).unwrap_or(default).to_string();
        if !allowed.contains(&v.as_str()) {
            bail!("--param {key}={v}: expected one of {allowed:?}");
        }
        rep.param(key, v.clone());
        Ok(v)
    }

    /// Fail on keys that were never read.
    pub fn finish(self) -> Result<()> {
        for (k, _) in &self.args.params {
            if !self.used.contains(k) {
                bail!("unknown --param '{k}' (known: {})", self.used.join(", "));
            }
        }
        Ok(())
    }
}

/// A simulated run: truth and sampled measurements at t_k = kΔ, k = 1..K.
pub struct Record {
    pub times: Vec<f64>,
    /// Truth at t₀ = 0 and at every t_k, (K + 1) × d.
    pub truth: Vec<f64>,
    /// Measurements, K × m.
    pub ys: Vec<f64>,
}

/// The pipeline config of an experiment that runs one (`--param
/// config=FILE`, the last one wins; default: the built-in ship scenario's
/// `configs/default.toml`, embedded in the binary so the experiment runs
/// from any directory), its name for the report, and the arguments without
/// it for [`Params`].
pub fn split_config_param(
    args: &ExperimentArgs,
) -> Result<(crate::config::PipelineConfig, String, ExperimentArgs)> {
    use crate::scenario::builtin::ShipScenario;
    use crate::scenario::Scenario;
    let path = args
        .params
        .iter()
        .rev()
        .find(|(k, _)| k == "config")
        .map(|(_, v)| v.clone());
    let (cfg, name) = match path {
        Some(p) => (crate::config::load(std::path::Path::new(&p), &[])?, p),
        None => (
            crate::config::load_str(ShipScenario::CONFIG, &[])?,
            "(built in) configs/default.toml".to_string(),
        ),
    };
    let params = args
        .params
        .iter()
        .filter(|(k, _)| k != "config")
        .cloned()
        .collect();
    let rest = ExperimentArgs {
        params,
        ..args.clone()
    };
    Ok((cfg, name, rest))
}

/// Simulate `steps` observation periods of `dt` from `x0` (Euler–Maruyama
/// with substeps ≤ `max_dt`, no control), drawing a measurement after each.
pub fn simulate<M: SdeModel>(
    model: &M,
    x0: &[f64],
    dt: f64,
    steps: usize,
    max_dt: f64,
    rng: &mut SimRng,
) -> Record {
    let u = vec![0.0; model.dims().control];
    simulate_under(model, x0, &u, dt, steps, max_dt, rng)
}

/// [`simulate`] with the control `u` held (a hover thrust, a cruise).
pub fn simulate_under<M: SdeModel>(
    model: &M,
    x0: &[f64],
    u: &[f64],
    dt: f64,
    steps: usize,
    max_dt: f64,
    rng: &mut SimRng,
) -> Record {
    let dims = model.dims();
    let (d, m) = (dims.state, dims.obs);
    let mut x = x0.to_vec();
    let mut rec = Record {
        times: Vec::with_capacity(steps),
        truth: Vec::with_capacity((steps + 1) * d),
        ys: Vec::with_capacity(steps * m),
    };
    rec.truth.extend_from_slice(&x);
    let mut y = vec![0.0; m];
    for k in 1..=steps {
        em_integrate(model, &mut x, u, dt, max_dt, rng);
        model.bounds().project(&mut x);
        simulate_observation(model, &x, rng, &mut y);
        rec.times.push(k as f64 * dt);
        rec.truth.extend_from_slice(&x);
        rec.ys.extend_from_slice(&y);
    }
    rec
}

/// Draw x ~ N(prior) restricted to S (rejection, then projection).
pub fn draw_from<M: SdeModel>(model: &M, prior: &Gaussian, rng: &mut SimRng) -> Vec<f64> {
    let d = prior.dim;
    let s = crate::chain::Sampler::around(prior, 1.0, 0.0).expect("positive-definite prior");
    let mut x = vec![0.0; d];
    s.sample(model.bounds(), rng, &mut x);
    x
}

/// Result of running a filter over a record.
#[derive(Clone, Copy, Debug, Default)]
pub struct RunResult {
    /// (1/T) Σ_k ‖x_k − x̂_k‖ Δ (time-average estimation error).
    pub mean_error: f64,
    /// Root mean square of ‖x_k − x̂_k‖.
    pub rmse: f64,
    /// Wall-clock seconds of predict + update + belief.
    pub time_s: f64,
    /// Thread CPU seconds of the same (immune to descheduling on a loaded
    /// machine; the figure compute comparisons use).
    pub cpu_s: f64,
    /// Whether the estimate became non-finite or left 10× the set S.
    pub diverged: bool,
}

/// Run `f` (already reset at t = 0) over `rec`. `dims_err` restricts the
/// error to the first components (all when None).
pub fn run_filter(f: &mut dyn BayesFilter, rec: &Record, dims_err: Option<usize>) -> RunResult {
    run_filter_every(f, rec, dims_err, 1)
}

/// [`run_filter`] with an observation at every `every`-th record time
/// only (k = every−1, 2·every−1, …): the filter predicts through the
/// times between and its error is scored there too, so the mean error is
/// the papers' (1/T)∫‖x − x̂‖dt on the record's grid, prediction phases
/// included, not only the instants right after an update.
pub fn run_filter_every(
    f: &mut dyn BayesFilter,
    rec: &Record,
    dims_err: Option<usize>,
    every: usize,
) -> RunResult {
    let u = vec![0.0; f.dims().control];
    run_filter_under(f, rec, &u, dims_err, every)
}

/// [`run_filter_every`] with the control `u` the record was simulated
/// under ([`simulate_under`]) passed to every prediction.
pub fn run_filter_under(
    f: &mut dyn BayesFilter,
    rec: &Record,
    u: &[f64],
    dims_err: Option<usize>,
    every: usize,
) -> RunResult {
    let every = every.max(1);
    let d = f.dims().state;
    let de = dims_err.unwrap_or(d);
    let m = f.dims().obs;
    let mut err_sum = 0.0;
    let mut sq_sum = 0.0;
    let mut diverged = false;
    let t0 = Instant::now();
    let c0 = crate::rt::clock::thread_cpu_ns();
    for (k, &t) in rec.times.iter().enumerate() {
        let y = &rec.ys[k * m..(k + 1) * m];
        if f.predict(t, u).is_err() {
            diverged = true;
        }
        if (k + 1) % every == 0 {
            let _ = f.update(&Measurement::full(y));
        }
        let b = f.belief();
        let x = &rec.truth[(k + 1) * d..(k + 2) * d];
        let e2: f64 = (0..de).map(|i| (b.mean[i] - x[i]).powi(2)).sum();
        if !e2.is_finite() || e2 > 1e8 {
            diverged = true;
        }
        err_sum += e2.sqrt();
        sq_sum += e2;
    }
    let k = rec.times.len().max(1) as f64;
    RunResult {
        mean_error: err_sum / k,
        rmse: (sq_sum / k).sqrt(),
        time_s: t0.elapsed().as_secs_f64(),
        cpu_s: (crate::rt::clock::thread_cpu_ns() - c0) as f64 * 1e-9,
        diverged,
    }
}

/// The live chain filter of a pipeline config, as the filter stage builds
/// it: the config's filter backend answers (from `prior` at t = 0) until
/// the first chain version is installed, with buffers for
/// `refine.max_states` states, taking controls relative to
/// `refine.reference_control`. Callers set reanchoring, frame and tuning.
pub fn live_chain_filter<M: SdeModel>(
    model: M,
    cfg: &crate::pipeline::PipelineConfig,
    prior: &Gaussian,
) -> Result<crate::filter::live_chain::LiveChainFilter<M, Vec<u64>>> {
    let mut f = crate::filter::live_chain::LiveChainFilter::new(
        model,
        crate::stage::filter::make_filter(cfg, 0.0)?,
        cfg.refine.max_states,
        prior,
        0.0,
    );
    if !cfg.refine.reference_control.is_empty() {
        f.set_reference_control(&cfg.refine.reference_control)?;
    }
    Ok(f)
}

/// Mean and 95 % half-width (1.96 standard errors) of the per-run error
/// differences a − b over the runs where neither diverged, and that count.
pub fn paired_difference(a: &[RunResult], b: &[RunResult]) -> (f64, f64, usize) {
    let d: Vec<f64> = a
        .iter()
        .zip(b)
        .filter(|(x, y)| !x.diverged && !y.diverged)
        .map(|(x, y)| x.mean_error - y.mean_error)
        .collect();
    let (m, se) = mean_se(&d);
    (m, 1.96 * se, d.len())
}

/// Mean and standard error of a sample.
pub fn mean_se(v: &[f64]) -> (f64, f64) {
    let n = v.len().max(1) as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (m, (var / n).sqrt())
}

/// Median of a sample.
pub fn median(v: &[f64]) -> f64 {
    let mut w = v.to_vec();
    w.sort_by(f64::total_cmp);
    if w.is_empty() {
        f64::NAN
    } else {
        w[w.len() / 2]
    }
}

/// Run the chain filter `cf`, a bootstrap PF (`pf_cfg`, reseeded per run),
/// the EKF and the UKF over `runs` simulated records of `steps` periods of
/// `dt` from x₀ ~ prior; returns per-method results in that order.
#[allow(clippy::type_complexity)]
pub fn compare_filters<M>(
    model: &M,
    prior: &Gaussian,
    cf: &mut crate::filter::chain_filter::ChainFilter<M>,
    pf_cfg: &crate::filter::pf::PfConfig,
    runs: usize,
    seed: u64,
    dt: f64,
    steps: usize,
    bar: &mut super::Progress,
) -> Result<Vec<(&'static str, Vec<RunResult>)>>
where
    M: crate::model::SdeJacobians + Clone + 'static,
{
    use crate::filter::ekf::{Ekf, EkfConfig};
    use crate::filter::pf::Pf;
    use crate::filter::ukf::{Ukf, UkfConfig};
    let mut out: Vec<(&'static str, Vec<RunResult>)> = vec![
        ("chain", vec![]),
        ("pf", vec![]),
        ("ekf", vec![]),
        ("ukf", vec![]),
    ];
    for r in 0..runs {
        let mut rng = crate::rng::stream(seed, r as u64);
        let x0 = draw_from(model, prior, &mut rng);
        let rec = simulate(model, &x0, dt, steps, 1e-3, &mut rng);
        cf.reset(0.0, prior);
        out[0].1.push(run_filter(cf, &rec, None));
        let cfg = crate::filter::pf::PfConfig {
            seed: seed.wrapping_mul(1000).wrapping_add(r as u64),
            ..pf_cfg.clone()
        };
        let mut pf = Pf::new(model.clone(), &cfg, prior, 0.0)?;
        out[1].1.push(run_filter(&mut pf, &rec, None));
        let mut ekf = Ekf::new(model.clone(), &EkfConfig { max_dt: dt }, prior, 0.0)?;
        out[2].1.push(run_filter(&mut ekf, &rec, None));
        let mut ukf = Ukf::new(model.clone(), &UkfConfig::default(), prior, 0.0)?;
        out[3].1.push(run_filter(&mut ukf, &rec, None));
        bar.tick();
    }
    Ok(out)
}

/// One table row from per-run results: mean error over non-diverged runs,
/// its standard error, median, mean time, diverged count.
pub fn result_row(name: &str, v: &[RunResult]) -> super::Row {
    let ok: Vec<f64> = v
        .iter()
        .filter(|r| !r.diverged)
        .map(|r| r.mean_error)
        .collect();
    let (m, se) = mean_se(&ok);
    let (t, _) = mean_se(&v.iter().map(|r| r.time_s).collect::<Vec<_>>());
    let (c, _) = mean_se(&v.iter().map(|r| r.cpu_s).collect::<Vec<_>>());
    let rms: Vec<f64> = v.iter().filter(|r| !r.diverged).map(|r| r.rmse).collect();
    super::Row::new(name)
        .num("mean_error", m)
        .num("rmse", mean_se(&rms).0)
        .num("stderr", se)
        .num("median_error", median(&ok))
        .num("time_s", t)
        .num("cpu_s", c)
        .int("diverged", (v.len() - ok.len()) as u64)
}

#[cfg(test)]
mod tests {
    use super::{paired_difference, run_filter, run_filter_every, simulate, RunResult};
    use crate::belief::Gaussian;
    use crate::filter::kalman::Kalman;
    use crate::model::linear::ou_1d;

    /// Sparse observations: the exact Kalman filter on an OU process,
    /// updated at every third record time only, scores the same mean
    /// error as a scalar Kalman recursion written out here (prediction
    /// m e^{−aΔ}, P e^{−2aΔ} + s²(1 − e^{−2aΔ})/2a at every time, update
    /// only at k = 2, 5, 8, …), error averaged over all record times.
    #[test]
    fn observations_every_third_time_match_a_hand_written_kalman() {
        let (a, s, sigma, dt) = (1.0, 0.5, 0.3, 0.1);
        let model = ou_1d(a, s, sigma, 10.0);
        let mut rng = crate::rng::stream(11, 0);
        let rec = simulate(&model, &[0.4], dt, 30, 1e-3, &mut rng);
        let prior = Gaussian::diagonal(&[0.0], &[1.0]);
        let mut kf = Kalman::new(model.clone(), &prior, 0.0).unwrap();
        let got = run_filter_every(&mut kf, &rec, None, 3);

        let (phi, q) = (
            (-a * dt).exp(),
            s * s * (1.0 - (-2.0 * a * dt).exp()) / (2.0 * a),
        );
        let (mut m, mut p) = (0.0, 1.0);
        let mut err = 0.0;
        for k in 0..rec.times.len() {
            m *= phi;
            p = p * phi * phi + q;
            if (k + 1) % 3 == 0 {
                let g = p / (p + sigma * sigma);
                m += g * (rec.ys[k] - m);
                p *= 1.0 - g;
            }
            err += (rec.truth[k + 1] - m).abs();
        }
        err /= rec.times.len() as f64;
        assert!(
            (got.mean_error - err).abs() < 1e-9,
            "{} vs {err}",
            got.mean_error
        );
        // every = 1 is run_filter, and using all observations helps here
        let mut kf = Kalman::new(model, &prior, 0.0).unwrap();
        let all = run_filter(&mut kf, &rec, None);
        assert!(
            all.mean_error < got.mean_error,
            "{} vs {}",
            all.mean_error,
            got.mean_error
        );
    }

    #[test]
    fn paired_difference_skips_diverged_runs() {
        let r = |e: f64, div: bool| RunResult {
            mean_error: e,
            diverged: div,
            ..RunResult::default()
        };
        let a = [r(1.0, false), r(2.0, false), r(9.0, true), r(4.0, false)];
        let b = [r(0.5, false), r(1.0, false), r(0.0, false), r(1.5, false)];
        // differences 0.5, 1.0, 2.5: mean 4/3, sample variance 13/12
        let (m, ci, k) = paired_difference(&a, &b);
        assert_eq!(k, 3);
        assert!((m - 4.0 / 3.0).abs() < 1e-12);
        assert!((ci - 1.96 * (13.0f64 / 12.0 / 3.0).sqrt()).abs() < 1e-12);
    }

    #[test]
    fn build_gives_a_filter_with_the_planned_chain_that_tracks_a_linear_model() {
        // The defaults on an OU process: the filter has the planned δ and
        // number of states, and on a simulated record its error is within
        // 10 % of the exact Kalman filter's (independent answer).
        use crate::filter::chain_spec::ChainFilterSpec;
        use crate::filter::BayesFilter;
        let model = ou_1d(2.0, 0.6, 0.2, 4.0);
        let prior = Gaussian::diagonal(&[0.0], &[0.3]);
        let spec = ChainFilterSpec {
            period: 0.1,
            horizon: 10.0,
            seed: 4,
            ..ChainFilterSpec::default()
        };
        let plan = spec.plan(&model, &prior).unwrap();
        let mut f = spec
            .build_planned(model.clone(), &prior, 0.0, &plan)
            .unwrap();
        assert_eq!(f.chain().len(), plan.states);
        assert_eq!(f.delta(), plan.delta);
        let (mut ec, mut ek) = (0.0, 0.0);
        for r in 0..10 {
            let mut rng = crate::rng::stream(21, r);
            let rec = simulate(&model, &[0.1], 0.1, 100, 1e-3, &mut rng);
            f.reset(0.0, &prior);
            ec += run_filter(&mut f, &rec, None).mean_error;
            let mut kf = Kalman::new(model.clone(), &prior, 0.0).unwrap();
            ek += run_filter(&mut kf, &rec, None).mean_error;
        }
        assert!(ec < 1.1 * ek, "chain {ec} vs Kalman {ek}");
        // states given: no pilot, the given budget
        let given = ChainFilterSpec {
            states: Some(300),
            ..spec
        };
        let plan = given.plan(&model, &prior).unwrap();
        assert_eq!((plan.states, plan.cells), (300, 0));
        assert!(plan.posterior_std.is_empty());
    }
}
