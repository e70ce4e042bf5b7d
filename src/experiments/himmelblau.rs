//! `himmelblau`: paper 003 §3.3, Table 4 — minimising Himmelblau's function
//! by stochastic optimal control, against plain Newton.
//!
//! dx = u dt + √σ dW from (−1, −4), cost E[f(x(t_f)) + ∫ ½ uᵀRu dt] with
//! R = σ = 0.01 (so γ = σR = 10⁻⁴ by condition (8); the paper leaves γ
//! unstated), Δt = 1, t_f = 20. At step k the controller minimises
//! F = Σ|y_i − y_{i−1}|²/(2σΔt) + f(y_n)/γ over the remaining n = 20 − k
//! steps (Newton, warm-started with the previous most likely path), draws 50
//! implicit samples, applies u_k = γR⁻¹∂ₓ log ψ and the state moves by
//! x_{k+1} = x_k + u_k Δt + √(σΔt) ξ_k. C = f(x(t_f)) + Σ ½ u_kᵀRu_k Δt.
//! Undamped Newton on f from the same start stops at the saddle
//! (−0.128, −1.954), f = 178.34.

use super::pi_common::{check_params, mean_std, param};
use super::{ExperimentArgs, ExperimentReport, Progress, Row};
use crate::control::implicit::{EstimatorOptions, PathSampler, PathSetup};
use crate::model::affine::ControlledBrownian;
use crate::model::himmelblau::{self, HimmelblauCost, MINIMA};
use crate::rng;
use rand::RngExt;
use rand_distr::StandardNormal;

/// The experiment entry point.
pub fn run(args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    check_params(args, &["samples", "r", "sigma", "t_final"])?;
    let runs = args.runs.unwrap_or(70);
    let samples: usize = param(args, "samples", 50)?;
    let r: f64 = param(args, "r", 0.01)?;
    let sigma: f64 = param(args, "sigma", 0.01)?;
    let t_final: f64 = param(args, "t_final", 20.0)?;
    let dt = 1.0;
    let n = (t_final / dt).round() as usize;
    anyhow::ensure!(
        n >= 1 && samples <= 100_000,
        "need t_final ≥ 1 and samples ≤ 1e5"
    );
    let x0 = [-1.0, -4.0];
    let model = ControlledBrownian { dim: 2, sigma };
    let setup = PathSetup::new(&model, &[r, 0.0, 0.0, r], dt)?;
    let gamma = setup.gamma;
    let mut sampler = PathSampler::new(setup, n, samples, 1);
    let opts = EstimatorOptions {
        samples,
        ..EstimatorOptions::default()
    };

    let mut rep = ExperimentReport::new("himmelblau");
    rep.param("runs", runs);
    rep.param("samples", samples);
    rep.param("r", r);
    rep.param("sigma", sigma);
    rep.param("gamma", format!("{gamma:.3e}"));
    rep.param("dt", dt);
    rep.param("t_final", t_final);
    rep.param("start", "(-1, -4)");
    rep.param("seed", args.seed);

    let mut bar = Progress::new("himmelblau", runs, args.progress);
    let (mut finals, mut costs, mut costs_paper) = (vec![], vec![], vec![]);
    let mut at_min = [0usize; 4];
    let mut failures = 0usize;
    let mut first_runs: Vec<Vec<f64>> = vec![];
    for run in 0..runs {
        let mut rg = rng::stream(args.seed, run as u64);
        let mut plant = rng::stream(args.seed ^ 0x4842, run as u64);
        sampler.reset_warm_start();
        let mut x = x0;
        let mut c_ctrl = 0.0;
        let mut fs = vec![himmelblau::f(&x)];
        for k in 0..n {
            let steps = n - k;
            if sampler.warm_steps() > 0 {
                sampler.shift_warm_start(1, steps);
            }
            let u = match sampler.estimate(&model, &HimmelblauCost, &x, steps, None, &opts, &mut rg)
            {
                Ok(e) => [e.u[0], e.u[1]],
                Err(_) => {
                    failures += 1;
                    sampler.reset_warm_start();
                    [0.0, 0.0]
                }
            };
            c_ctrl += 0.5 * r * (u[0] * u[0] + u[1] * u[1]) * dt;
            let s = (sigma * dt).sqrt();
            x = [
                x[0] + u[0] * dt + s * plant.sample::<f64, _>(StandardNormal),
                x[1] + u[1] * dt + s * plant.sample::<f64, _>(StandardNormal),
            ];
            fs.push(himmelblau::f(&x));
        }
        let ff = himmelblau::f(&x);
        finals.push(ff);
        costs.push(ff + c_ctrl);
        costs_paper.push(ff + 2.0 * c_ctrl);
        if let Some((i, _)) = MINIMA
            .iter()
            .enumerate()
            .map(|(i, m)| (i, (m[0] - x[0]).hypot(m[1] - x[1])))
            .filter(|&(_, d)| d < 0.5)
            .min_by(|a, b| a.1.total_cmp(&b.1))
        {
            at_min[i] += 1;
        }
        if run < 5 {
            first_runs.push(fs);
        }
        bar.tick();
    }
    let (mf, sf) = mean_std(&finals);
    let (mc, sc) = mean_std(&costs);
    let (mcp, _) = mean_std(&costs_paper);
    rep.results.push(
        Row::new("implicit")
            .int("samples", samples as u64)
            .num("mean_final_f", mf)
            .num("std_final_f", sf)
            .num("mean_cost", mc)
            .num("std_cost", sc)
            .num("mean_cost_uRu", mcp)
            .int("runs_at_min_3_2", at_min[0] as u64)
            .int("runs_at_min_-2.81_3.13", at_min[1] as u64)
            .int("runs_at_min_-3.78_-3.28", at_min[2] as u64)
            .int("runs_at_min_3.58_-1.85", at_min[3] as u64)
            .int("failed_controls", failures as u64),
    );
    let newton = himmelblau::newton_iterates(x0, n);
    let (fnw, xn) = *newton.last().unwrap();
    rep.results.push(
        Row::new("newton")
            .num("mean_final_f", fnw)
            .text("end_point", &format!("({:.6}, {:.6}) saddle", xn[0], xn[1])),
    );
    rep.paper.push(
        Row::new("implicit")
            .int("samples", 50)
            .num("mean_cost", 1.75)
            .text("end_point", "all 70 near (2.5, -2.5)"),
    );
    rep.paper
        .push(Row::new("newton").num("mean_final_f", 178.34));
    for (i, fs) in first_runs.iter().enumerate() {
        let s: Vec<String> = fs.iter().map(|v| format!("{v:.2}")).collect();
        rep.notes
            .push(format!("run {} f(x_k): {}", i + 1, s.join(" ")));
    }
    rep.notes.push(
        "mean_cost = f(x(t_f)) + Σ ½uᵀRu Δt (E2's convention); mean_cost_uRu counts uᵀRu as printed; runs_at_min_*: runs ending within 0.5 of that minimum"
            .into(),
    );
    rep.notes.extend(basin_notes(x0, sigma, t_final, dt));
    Ok(rep)
}

/// Why the runs end where they do: the weight of each minimum's basin in
/// ψ(x₀, 0) = E[exp(−f(x(t_f))/γ)] under the uncontrolled process, whose
/// u = γR⁻¹∂ₓ log ψ is the exact optimal control. With x(t_f) ~ N(x₀,
/// σ t_f I) and a Laplace approximation of exp(−f/γ) at each minimum m
/// (f(m) = 0, Hessian H_m):
///
/// ```text
/// log w_m = −‖m − x₀‖² / (2σ t_f) − ½ log det H_m + const
/// ```
///
/// (the Gaussian factor is flat over the basin's width √γ, so the path
/// energy decides). Also the expected final f of a run that ends in m:
/// ½ σΔt tr H_m, from the last step's noise that no control can correct.
fn basins(x0: [f64; 2], sigma: f64, t_final: f64, dt: f64) -> Vec<Basin> {
    let mut out: Vec<Basin> = MINIMA
        .iter()
        .map(|&m| {
            let (mut g, mut h) = ([0.0; 2], [0.0; 4]);
            himmelblau::derivatives(&m, &mut g, &mut h);
            let det = h[0] * h[3] - h[1] * h[2];
            let d2 = (m[0] - x0[0]).powi(2) + (m[1] - x0[1]).powi(2);
            Basin {
                min: m,
                distance: d2.sqrt(),
                log_weight: -d2 / (2.0 * sigma * t_final) - 0.5 * det.ln(),
                expected_f: 0.5 * sigma * dt * (h[0] + h[3]),
            }
        })
        .collect();
    let best = out
        .iter()
        .map(|b| b.log_weight)
        .fold(f64::NEG_INFINITY, f64::max);
    for b in &mut out {
        b.log_weight -= best;
    }
    out
}

/// One minimum's basin as [`basins`] weighs it.
struct Basin {
    min: [f64; 2],
    distance: f64,
    /// log w_m relative to the heaviest basin (0 for it).
    log_weight: f64,
    expected_f: f64,
}

fn basin_notes(x0: [f64; 2], sigma: f64, t_final: f64, dt: f64) -> Vec<String> {
    let mut notes: Vec<String> = basins(x0, sigma, t_final, dt)
        .iter()
        .map(|b| {
            format!(
                "basin of ({:.2}, {:.2}): distance {:.2}, log weight in ψ(x₀) {:.1} relative to the heaviest, expected final f ½σΔt·tr H = {:.2}",
                b.min[0], b.min[1], b.distance, b.log_weight, b.expected_f
            )
        })
        .collect();
    notes.push(
        "With the stated R, σ, Δt, t_f and start (f(x₀) = 260.00, as the table's first row), the exact optimal control steers to the heaviest basin, (−3.78, −3.28), which outweighs the one near the paper's \"(2.5, −2.5)\", (3.58, −1.85), by the factor above: our runs end there, and their mean final f matches that basin's ½σΔt·tr H. The paper's basin is a local minimiser of the path functional, not the problem's optimum; its lower curvature would give a lower final f (0.67 vs 1.02), which the paper's mean cost 1.75 does not show either."
            .into(),
    );
    notes
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn controlled_runs_escape_the_saddle() {
        let args = ExperimentArgs {
            runs: Some(3),
            doc: crate::experiments::find("himmelblau").unwrap().params,
            ..ExperimentArgs::default()
        };
        let rep = run(&args).unwrap();
        let f = rep.results[0].metrics["mean_final_f"].as_f64().unwrap();
        let newton = rep.results[1].metrics["mean_final_f"].as_f64().unwrap();
        assert!((newton - 178.337).abs() < 0.01);
        assert!(f < 10.0, "controlled runs end near a minimum: mean f {f}");
    }

    /// The basin weights: the nearest minimum (−3.78, −3.28) is the
    /// heaviest by the path energy ‖m − x₀‖²/(2σt_f) (20.6 vs 64.0 nats
    /// for (3.58, −1.85)), and its expected final f is ½σΔt·tr H.
    #[test]
    fn the_nearest_basin_dominates_psi() {
        let b = basins([-1.0, -4.0], 0.01, 20.0, 1.0);
        assert_eq!(b[2].log_weight, 0.0, "(−3.78, −3.28) is the heaviest");
        assert!((b[2].distance - 2.87).abs() < 0.01);
        // −(5.06² − 2.87²)/0.4 − ½ log(det H₃/det H₂) ≈ −43.4 + 0.57
        assert!((b[3].log_weight + 42.8).abs() < 0.3, "{}", b[3].log_weight);
        assert!((b[2].expected_f - 1.02).abs() < 0.01 && (b[3].expected_f - 0.67).abs() < 0.01);
    }
}
