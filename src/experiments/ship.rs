//! `ship` — paper 001 eq. 10–11 / thesis §3.4.1 (Fig. 3-2): the drifting
//! ship, e = 0.3, e₁ = e₂ = 0.03, filtered by the chain filter, a bootstrap
//! PF with 100 particles, the EKF and the UKF; the error is
//! E[(1/T) ∫ ‖x − x̂‖ dt] over the full 4-D state.
//!
//! Paper: chain 5.02e-3, PF-100 5.2e-3, EKF 1.36e-2 (100 "particles" for the
//! chain filter too; T, x(0), prior, δ, runs not given), and "the EKF error
//! is very large near (0, 0), when the observation nonlinearity is large".
//!
//! Chosen here, where the paper is silent: sampled range and bearing every
//! Δ = 0.01 s with σ = 0.03/√Δ = 0.3 (see `model::continuous_obs_std`),
//! δ = Δ; **the ship starts at rest at the sensor**, x(0) ~ N((0, 0, 0, 0),
//! diag(0.3², 0.3², 0.2², 0.2²)), which is also every filter's prior, and
//! T = 5 s; 100 runs. Why this start: the paper attributes the EKF's larger
//! error to the neighbourhood of (0, 0), where range ρ and bearing
//! atan2(x₂, x₁) are far from linear on the scale of the position
//! uncertainty (the bearing's gradient is 1/ρ, and at ρ ≲ 0.3 the prior
//! straddles every bearing). A ship that only passes the origin spends a
//! fraction of a second there and the time-averaged error is that of the
//! near-linear far field, where the EKF is close to optimal (the previous
//! start (3, 2, 1, −0.5) gave EKF 0.52 < PF 0.63 < chain 0.70: no ranking
//! to compare). Starting at the origin at rest with e = 0.3 velocity noise
//! keeps the ship within ≈ 1 of the sensor for the first seconds (velocity
//! random walk: ≈ 0.3 t^{3/2}/√3 displacement) and then lets it drift out,
//! so the run covers the strongly and the mildly nonlinear regime. Other
//! starts are `--param start_x1=… start_x2=… start_v1=… start_v2=…`
//! (prior std `prior_pos_std`, `prior_vel_std`, horizon `horizon_s`).
//!
//! The chain (moment-matching kernel, k = ⌈1.5 log n⌉, advected with step
//! τ = δ = Δ, 20,000 states) is built once on states concentrated by the
//! thesis's heuristic (the prior propagated through the dynamics by
//! simulation, 10 % uniform on S) and reused in every run. Every run
//! reseeds the PF; all filters see the same simulated record. The table
//! gives each filter's mean error with its 95 % confidence interval over
//! the runs, and the notes the paired per-run differences chain − PF and
//! EKF − chain with theirs.
//!
//! Measured with these defaults (100 runs; seeds 1 / 2 / 3; ± 95 % CI):
//! chain 0.492 ± 0.030 / 0.461 ± 0.021 / 0.454 ± 0.022, PF-100
//! 0.547 ± 0.037 / 0.509 ± 0.027 / 0.510 ± 0.026, EKF 1.60 ± 0.13 /
//! 1.48 ± 0.13 / 1.44 ± 0.11, UKF 0.415 ± 0.016 / 0.409 ± 0.015 /
//! 0.396 ± 0.014; paired chain − PF −0.055 ± 0.029 / −0.048 ± 0.028 /
//! −0.056 ± 0.025. So
//! chain ≈ PF (the chain ≈ 10 % lower), the EKF ≈ 3× worse; the UKF, not
//! in the paper, is best (its sigma points straddle the origin).
//!
//! The paper's figures are not reachable in this reading: the steady-state
//! Kalman–Bucy error of the model linearised away from the wall
//! ([`kalman_bucy_floor`], printed as a row at the runs' mean range) is
//! ≈ 0.5 at range 3, and 5e-3 would need all noises ≈ 100× smaller than
//! printed (e.g. increments e·dt instead of e·√dt at dt = 10⁻⁴) — the paper
//! states neither its time step nor its simulation. The ranking is what is
//! compared.

use anyhow::Result;

use super::chain_util::{
    compare_filters, draw_from, mean_se, paired_difference, result_row, simulate, Params,
};
use super::{ExperimentArgs, ExperimentReport, Progress, Row};
use crate::belief::Gaussian;
use crate::chain::{Chain, ChainConfig, NearRule};
use crate::filter::chain_filter::ChainFilter;
use crate::filter::pf::PfConfig;
use crate::model::ship::{Ship, ShipParams};
use crate::rng::stream;

/// Steady-state Kalman–Bucy rms error √tr P of the ship linearised at range
/// ρ away from the wall: per axis a double integrator dx = v dt + e dw₁,
/// dv = e dw₂ observed in position with continuous noise r (radial r = e₁,
/// cross-range r = e₂ρ). For A = [[0,1],[0,0]], Q = e²I, C = [1 0] the
/// Riccati equation AP + PAᵀ + Q − PCᵀCP/r² = 0 has the closed form
/// P₁₂ = e r, P₁₁ = r √(2P₁₂ + e²), P₂₂ = P₁₁P₁₂/r².
pub fn kalman_bucy_floor(e: f64, e1: f64, e2: f64, rho: f64) -> f64 {
    let axis = |r: f64| {
        let p12 = e * r;
        let p11 = r * (2.0 * p12 + e * e).sqrt();
        let p22 = p11 * p12 / (r * r);
        p11 + p22
    };
    (axis(e1) + axis(e2 * rho)).sqrt()
}

/// Default prior mean (x₁, x₂, v₁, v₂), see the module doc.
pub const START: [f64; 4] = [0.0, 0.0, 0.0, 0.0];

pub fn run(args: &ExperimentArgs) -> Result<ExperimentReport> {
    let mut rep = ExperimentReport::new("ship");
    let mut p = Params::new(args);
    let runs = args.runs.unwrap_or(100);
    rep.param("runs", runs);
    rep.param("seed", args.seed);
    let t_end = p.f64(&mut rep, "horizon_s", 5.0)?;
    let dt = p.f64(&mut rep, "obs_period_s", 0.01)?;
    let n = p.usize(&mut rep, "states", 20_000)?;
    let particles = p.usize(&mut rep, "particles", 100)?;
    let c_knn = p.f64(&mut rep, "knn_c", 1.5)?;
    let uniform_fraction = p.f64(&mut rep, "uniform_fraction", 0.1)?;
    let step = p.f64(&mut rep, "step_s", dt)?;
    let flush_mass = p.f64(
        &mut rep,
        "flush_mass",
        crate::filter::chain_filter::FLUSH_MASS,
    )?;
    // an absolute flush threshold instead of the mass bound, if > 0
    let flush = p.f64(&mut rep, "flush", 0.0)?;
    let start = [
        p.f64(&mut rep, "start_x1", START[0])?,
        p.f64(&mut rep, "start_x2", START[1])?,
        p.f64(&mut rep, "start_v1", START[2])?,
        p.f64(&mut rep, "start_v2", START[3])?,
    ];
    let pos_std = p.f64(&mut rep, "prior_pos_std", 0.3)?;
    let vel_std = p.f64(&mut rep, "prior_vel_std", 0.2)?;
    p.finish()?;
    rep.param("e", 0.3);
    rep.param("e1_e2_continuous", 0.03);
    rep.param("kernel", "moment_matched");
    let model = Ship::new(ShipParams::paper(dt)).map_err(anyhow::Error::msg)?;
    let prior = Gaussian::diagonal(&start, &[pos_std, pos_std, vel_std, vel_std]);
    let steps = (t_end / dt).round() as usize;
    let t0 = std::time::Instant::now();
    let mut rng = stream(args.seed, 77);
    let pts = crate::chain::placement::predictive_points(
        &model,
        &prior,
        t_end,
        n,
        uniform_fraction,
        dt,
        &mut rng,
    )?;
    let mut cfg = ChainConfig::moment_matched(4);
    cfg.near = NearRule::Knn { c: c_knn };
    cfg.step = (step > 0.0).then_some(step);
    let chain = Chain::batch(&model, cfg, &pts)?;
    let mut cf = ChainFilter::new(model.clone(), chain, dt)?;
    cf.set_flush_mass(flush_mass);
    if flush > 0.0 {
        cf.set_flush_mass(flush_mass);
        if flush > 0.0 {
            cf.set_flush(flush);
        }
    }
    let build_s = t0.elapsed().as_secs_f64();
    let pf_cfg = PfConfig {
        particles,
        max_dt: dt,
        ..PfConfig::default()
    };
    let mut bar = Progress::new("ship", runs, args.progress);
    let res = compare_filters(
        &model, &prior, &mut cf, &pf_cfg, runs, args.seed, dt, steps, &mut bar,
    )?;
    for (name, v) in &res {
        let ok: Vec<f64> = v
            .iter()
            .filter(|r| !r.diverged)
            .map(|r| r.mean_error)
            .collect();
        let (_, se) = mean_se(&ok);
        let mut row = result_row(name, v).num("ci95", 1.96 * se);
        if *name == "chain" {
            row = row
                .int("n_states", n as u64)
                .num("build_s", build_s)
                .num("delta_s", cf.delta())
                .num("out_degree", cf.chain().mean_out_degree())
                .num("support", cf.mean_support());
        }
        if *name == "pf" {
            row = row.int("particles", particles as u64);
        }
        rep.results.push(row);
    }
    let by = |name: &str| &res.iter().find(|(n, _)| *n == name).expect("method").1;
    for (a, b) in [("chain", "pf"), ("ekf", "chain"), ("ukf", "chain")] {
        let (m, ci, k) = paired_difference(by(a), by(b));
        rep.notes.push(format!(
            "paired per-run difference {a} - {b}: {m:+.4} +- {ci:.4} (95% CI, {k} runs where neither diverged)"
        ));
    }
    rep.paper.push(
        Row::new("chain")
            .num("mean_error", 5.02e-3)
            .int("n_states", 100),
    );
    rep.paper.push(
        Row::new("pf")
            .num("mean_error", 5.2e-3)
            .int("particles", 100),
    );
    rep.paper.push(Row::new("ekf").num("mean_error", 1.36e-2));
    // The linearised Kalman–Bucy floor (see `kalman_bucy_floor`) at the
    // runs' time-averaged true range (the records re-simulated exactly as
    // `compare_filters` draws them).
    let mut range_sum = 0.0;
    for r in 0..runs {
        let mut rng = stream(args.seed, r as u64);
        let x0 = draw_from(&model, &prior, &mut rng);
        let rec = simulate(&model, &x0, dt, steps, 1e-3, &mut rng);
        let k = rec.times.len().max(1);
        range_sum += (1..=k)
            .map(|i| rec.truth[i * 4].hypot(rec.truth[i * 4 + 1]))
            .sum::<f64>()
            / k as f64;
    }
    let rho = range_sum / runs.max(1) as f64;
    let floor = kalman_bucy_floor(0.3, 0.03, 0.03, rho);
    rep.results.push(
        Row::new("kalman_bucy_floor")
            .num("rmse", floor)
            .num("range_m", rho),
    );
    rep.notes.push(format!(
        "steady-state Kalman-Bucy rms error of the model linearised at range {rho:.2} (the runs' mean true range) (double integrator per axis, e = 0.3, radial noise e1 = 0.03, cross-range e2*range): {floor:.3}; the paper's 5e-3 is ~{:.0}x below it, so it cannot be E||x - x^|| of eq. (10)-(11) with e, e1, e2 as continuous-time coefficients; the floor scales linearly with a common noise scale (it would take all noises x0.01, e.g. e*dt instead of e*sqrt(dt) increments at dt = 1e-4)",
        floor / 5.02e-3
    ));
    rep.notes.push("paper setting not fully specified (T, x0, prior, runs): compare the ranking, not the values".into());
    Ok(rep)
}

#[cfg(test)]
mod tests {
    use super::kalman_bucy_floor;
    use crate::filter::kalman::Kalman;
    use crate::filter::BayesFilter;
    use crate::model::linear::LinearSde;
    use crate::model::{Bounds, Measurement};
    use nalgebra::DMatrix;

    #[test]
    fn floor_matches_the_kalman_filter_at_steady_state() {
        // One axis (e2 = 0 would be degenerate, so compare the radial axis
        // with ρ chosen to give the same noise on both): a discrete Kalman
        // filter on the double integrator sampled finely converges to the
        // continuous Riccati solution.
        let (e, r) = (0.3, 0.03);
        let dt: f64 = 1e-3;
        let model = LinearSde::new(
            "di",
            DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]),
            DMatrix::zeros(2, 0),
            DMatrix::from_diagonal_element(2, 2, e),
            DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
            vec![r / dt.sqrt()],
            Bounds::new_box(&[-1e3, -1e3], &[1e3, 1e3]).unwrap(),
        );
        let prior = crate::belief::Gaussian::diagonal(&[0.0, 0.0], &[1.0, 1.0]);
        let mut kf = Kalman::new(model, &prior, 0.0).unwrap();
        for k in 1..=20_000 {
            kf.predict(k as f64 * dt, &[]).unwrap();
            kf.update(&Measurement::full(&[0.0])).unwrap();
        }
        let p = kf.belief();
        let tr = p.cov[0] + p.cov[3];
        let floor = kalman_bucy_floor(e, r, r, 1.0);
        // both axes equal here: floor² = 2 tr P (sampling adds O(√dt))
        let rel = (floor * floor / 2.0 - tr).abs() / tr;
        assert!(
            rel < 0.05,
            "floor² / 2 {} vs Kalman tr P {tr}",
            floor * floor / 2.0
        );
    }
}
