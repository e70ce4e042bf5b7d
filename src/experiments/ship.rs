//! `ship` — paper 001 eq. 10–11 / thesis §3.4.1 (Fig. 3-2): the drifting
//! ship, e = 0.3, e₁ = e₂ = 0.03, filtered by the chain filter, a bootstrap
//! PF with 100 particles, the EKF and the UKF; the error is
//! E[(1/T) ∫ ‖x − x̂‖ dt] over the full 4-D state.
//!
//! Paper: chain 5.02e-3, PF-100 5.2e-3, EKF 1.36e-2 (100 "particles" for the
//! chain filter too; T, x(0), prior, runs not given). Chosen here: sampled
//! range and bearing every Δ = 0.01 s with σ = 0.03/√Δ = 0.3 (see
//! `model::continuous_obs_std`), T = 10 s, x(0) ~ N((3, 2, 1, −0.5),
//! diag(0.3², 0.3², 0.2², 0.2²)) also the filters' prior, 20 runs. The chain
//! (moment-matching kernel, k = ⌈1.5 log n⌉, δ ≤ Δ) is built once on states
//! concentrated by the thesis's heuristic (the prior propagated through the
//! dynamics by simulation, 10 % uniform on S) and reused in every run.
//!
//! The paper's figures are not reachable in this reading: the steady-state
//! Kalman–Bucy error of the model linearised away from the wall
//! ([`kalman_bucy_floor`], printed as a row) is ≈ 0.52 at the prior's range,
//! and the EKF/UKF sit at it. With e, e₁, e₂ as continuous-time
//! coefficients no filter can average 5e-3 over the 4-D state; the floor
//! scales linearly with a common noise scale, so the paper's numbers need
//! all noises ≈ 100× smaller than printed (e.g. increments e·dt instead of
//! e·√dt at dt = 10⁻⁴) — the paper states neither its time step nor its
//! simulation. The ranking is what is compared.

use anyhow::Result;

use super::chain_util::{compare_filters, predictive_points, result_row, Params};
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

pub fn run(args: &ExperimentArgs) -> Result<ExperimentReport> {
    let mut rep = ExperimentReport::new("ship");
    let mut p = Params::new(args);
    let runs = args.runs.unwrap_or(20);
    rep.param("runs", runs);
    rep.param("seed", args.seed);
    let t_end = p.f64(&mut rep, "horizon_s", 10.0)?;
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
    p.finish()?;
    rep.param("e", 0.3);
    rep.param("e1_e2_continuous", 0.03);
    rep.param("prior", "N((3,2,1,-0.5), diag(0.3,0.3,0.2,0.2)^2)");
    rep.param("kernel", "moment_matched");
    let model = Ship::new(ShipParams::paper(dt)).map_err(anyhow::Error::msg)?;
    let prior = Gaussian::diagonal(&[3.0, 2.0, 1.0, -0.5], &[0.3, 0.3, 0.2, 0.2]);
    let steps = (t_end / dt).round() as usize;
    let t0 = std::time::Instant::now();
    let mut rng = stream(args.seed, 77);
    let pts = predictive_points(&model, &prior, t_end, n, uniform_fraction, dt, &mut rng);
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
        let mut row = result_row(name, v);
        if *name == "chain" {
            row = row
                .int("n_states", n as u64)
                .num("build_s", build_s)
                .num("delta_s", cf.delta())
                .num("out_degree", cf.chain().mean_out_degree());
        }
        if *name == "pf" {
            row = row.int("particles", particles as u64);
        }
        rep.results.push(row);
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
    // The linearised Kalman–Bucy floor (see `kalman_bucy_floor`).
    let rho = (prior.mean[0].powi(2) + prior.mean[1].powi(2)).sqrt();
    let floor = kalman_bucy_floor(0.3, 0.03, 0.03, rho);
    rep.results.push(
        Row::new("kalman_bucy_floor")
            .num("rmse", floor)
            .num("range_m", rho),
    );
    rep.notes.push(format!(
        "steady-state Kalman-Bucy rms error of the model linearised at range {rho:.2} (double integrator per axis, e = 0.3, radial noise e1 = 0.03, cross-range e2*range): {floor:.3}; the paper's 5e-3 is ~{:.0}x below it, so it cannot be E||x - x^|| of eq. (10)-(11) with e, e1, e2 as continuous-time coefficients; the floor scales linearly with a common noise scale (it would take all noises x0.01, e.g. e*dt instead of e*sqrt(dt) increments at dt = 1e-4)",
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
