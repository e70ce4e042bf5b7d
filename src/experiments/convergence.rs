//! `convergence` — thesis §2.6 / paper 001 §VII-A (Fig. 2-4): trajectories
//! of the chain versus the true process of eq. 2.9,
//! dx₁ = −x₁/2 dt + 0.03 dw₁, dx₂ = −x₂ dt + 0.03 dw₂, to T = 2 from the
//! state nearest (0.8, 0.8); first- and second-moment errors
//! |E[ξ_n(T)] − E[x(T)]| and ‖E[ξ_n ξ_nᵀ(T)] − E[x xᵀ(T)]‖₂ for n from
//! 1,000 to 100,000 (exact moments of the OU process from the same start).
//!
//! The paper gives no values (only the plot). Chosen here: S = [−1, 1]²,
//! uniform batch chains, k = ⌈1.5 log n⌉; 50,000 simulated chain
//! trajectories per n (the continuous-time interpolation: hold Δt(z), jump
//! by P(·|z)), plus the same moments computed exactly by propagating the
//! time-equalised chain (no Monte-Carlo noise). Both the thesis's Gaussian
//! kernel and the moment-matching kernel are run; the fitted log-log slope
//! of each error against n is reported.

use anyhow::Result;
use rand::RngExt;

use super::chain_util::Params;
use super::decoding::slope;
use super::{ExperimentArgs, ExperimentReport, Progress, Row};
use crate::chain::{Chain, ChainConfig, NearRule, PropagationKernel, Sampler, TimeEqualized};
use crate::model::linear::LinearSde;
use crate::model::Bounds;
use crate::rng::stream;
use nalgebra::DMatrix;

pub fn run(args: &ExperimentArgs) -> Result<ExperimentReport> {
    let mut rep = ExperimentReport::new("convergence");
    let mut p = Params::new(args);
    let trajectories = args.runs.unwrap_or(50_000);
    rep.param("trajectories", trajectories);
    rep.param("seed", args.seed);
    let sizes = p.list(&mut rep, "states", &[1000, 3000, 10000, 30000, 100000])?;
    let t_end = p.f64(&mut rep, "horizon_s", 2.0)?;
    p.finish()?;
    rep.param("system", "eq. 2.9, S = [-1,1]^2, start nearest (0.8, 0.8)");
    let (a1, a2, s) = (0.5, 1.0, 0.03);
    let model = LinearSde::new(
        "ou-2.9",
        DMatrix::from_row_slice(2, 2, &[-a1, 0.0, 0.0, -a2]),
        DMatrix::zeros(2, 0),
        DMatrix::from_diagonal_element(2, 2, s),
        DMatrix::identity(2, 2),
        vec![0.1, 0.1],
        Bounds::new_box(&[-1.0, -1.0], &[1.0, 1.0])?,
    );
    let mut bar = Progress::new("convergence", sizes.len() * 2, args.progress);
    type Curve = (&'static str, Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>);
    let mut curves: Vec<Curve> = vec![];
    for kind in ["gaussian", "moment_matched"] {
        let (mut e1, mut e2, mut x1, mut x2) = (vec![], vec![], vec![], vec![]);
        for &n in &sizes {
            let mut cfg = if kind == "gaussian" {
                ChainConfig::gaussian(2)
            } else {
                ChainConfig::moment_matched(2)
            };
            cfg.near = NearRule::Knn { c: 1.5 };
            let mut rng = stream(args.seed, n as u64);
            let mut chain = Chain::sample_batch(&model, cfg, &Sampler::Uniform, n, &mut rng)?;
            let mut near = vec![];
            chain.nearest(&[0.8, 0.8], 1, &mut near);
            let z0 = near[0].0 as usize;
            let x0 = [chain.state(z0)[0], chain.state(z0)[1]];
            // Local consistency (eq. 2.6–2.7) of the rows, away from ∂S:
            // what decides whether the chain converges to the diffusion.
            let lc = crate::chain::diagnostics::report(
                &chain,
                crate::model::SdeModel::bounds(&model),
                2.0,
            );

            // exact OU moments from x0
            let m = [x0[0] * (-a1 * t_end).exp(), x0[1] * (-a2 * t_end).exp()];
            let v = [
                s * s * (1.0 - (-2.0 * a1 * t_end).exp()) / (2.0 * a1),
                s * s * (1.0 - (-2.0 * a2 * t_end).exp()) / (2.0 * a2),
            ];
            let second = [
                m[0] * m[0] + v[0],
                m[0] * m[1],
                m[0] * m[1],
                m[1] * m[1] + v[1],
            ];
            // Monte Carlo over chain trajectories
            let mut sum = [0.0; 2];
            let mut sum2 = [0.0; 4];
            for _ in 0..trajectories {
                let mut z = z0;
                let mut t = 0.0;
                loop {
                    let h = chain.holding()[z];
                    if t + h > t_end || !h.is_finite() {
                        break;
                    }
                    t += h;
                    let (cols, probs) = chain.row(z);
                    let mut u = rng.random::<f64>();
                    let mut next = cols[cols.len() - 1];
                    for (c, p) in cols.iter().zip(probs) {
                        if u < *p {
                            next = *c;
                            break;
                        }
                        u -= p;
                    }
                    z = next as usize;
                }
                let x = chain.state(z);
                sum[0] += x[0];
                sum[1] += x[1];
                sum2[0] += x[0] * x[0];
                sum2[1] += x[0] * x[1];
                sum2[2] += x[0] * x[1];
                sum2[3] += x[1] * x[1];
            }
            let nt = trajectories as f64;
            let mc_m = [sum[0] / nt, sum[1] / nt];
            let mc_s: Vec<f64> = sum2.iter().map(|v| v / nt).collect();
            e1.push(((mc_m[0] - m[0]).powi(2) + (mc_m[1] - m[1]).powi(2)).sqrt());
            e2.push(sym2_norm(&[
                mc_s[0] - second[0],
                mc_s[1] - second[1],
                mc_s[3] - second[3],
            ]));
            // exact propagation on the equalised chain
            let mut eq = TimeEqualized::new(t_end / 64.0)?;
            eq.fit(chain.holding());
            let view = chain.view();
            let kern = PropagationKernel::build(&view, eq.delta(), false);
            let mut phi = vec![0.0; n];
            phi[z0] = 1.0;
            let mut tmp = vec![0.0; n];
            let (whole, frac) = eq.steps(t_end);
            for _ in 0..whole {
                kern.forward(&phi, &mut tmp);
                std::mem::swap(&mut phi, &mut tmp);
            }
            if frac > 0.0 {
                kern.forward_fraction(frac, &phi, &mut tmp);
                std::mem::swap(&mut phi, &mut tmp);
            }
            let mut em = [0.0; 2];
            let mut es = [0.0; 3];
            for (i, &w) in phi.iter().enumerate() {
                let x = view.state(i);
                em[0] += w * x[0];
                em[1] += w * x[1];
                es[0] += w * x[0] * x[0];
                es[1] += w * x[0] * x[1];
                es[2] += w * x[1] * x[1];
            }
            x1.push(((em[0] - m[0]).powi(2) + (em[1] - m[1]).powi(2)).sqrt());
            x2.push(sym2_norm(&[
                es[0] - second[0],
                es[1] - second[1],
                es[2] - second[3],
            ]));
            rep.results.push(
                Row::new(if kind == "gaussian" {
                    "chain_gaussian"
                } else {
                    "chain_lp"
                })
                .int("n_states", n as u64)
                .num("first_moment_err", *e1.last().unwrap())
                .num("second_moment_err", *e2.last().unwrap())
                .num("first_exact_prop", *x1.last().unwrap())
                .num("second_exact_prop", *x2.last().unwrap())
                .num("out_degree", view.nnz() as f64 / n as f64)
                .num("rel_drift_err", lc.rel_drift_err)
                .num("rel_cov_err", lc.rel_cov_err),
            );
            bar.tick();
        }
        curves.push((kind, e1, e2, x1, x2));
    }
    let lx: Vec<f64> = sizes.iter().map(|&n| (n as f64).ln()).collect();
    for (kind, e1, e2, x1, x2) in &curves {
        let l = |v: &Vec<f64>| {
            slope(
                &lx,
                &v.iter().map(|e| e.max(1e-300).ln()).collect::<Vec<_>>(),
            )
        };
        rep.notes.push(format!(
            "{kind}: log-log slopes vs n — first moment {:.3} (MC) / {:.3} (exact), second moment {:.3} (MC) / {:.3} (exact)",
            l(e1),
            l(x1),
            l(e2),
            l(x2)
        ));
    }
    rep.notes.push(
        "rel_drift_err / rel_cov_err: mean local-consistency error of the rows, ‖E[Δξ]/Δt − f‖ and ‖Cov[Δξ]/Δt − FFᵀ‖, over the mean ‖f‖ and ‖FFᵀ‖ (states farther than 2r from ∂S). This system is drift-dominated (‖f‖ ≈ 0.5, FFᵀ = 9e-4 I), so the holding time Δt = r²/(‖FFᵀ‖ + r‖f‖) ≈ r/‖f‖ and the Gaussian kernel's centre z + fΔt lies about r from z, at the edge of the k nearest states it is normalised over: the truncated, renormalised Gaussian falls short of the drift by a fixed fraction whatever n (rel_drift_err stays near 0.3 from 1k to 100k states), so the chain converges to a process with about 30 % too little drift — the flat first-moment error. The moment-matched (LP) kernel matches E[Δξ] = fΔt row by row (rel_drift_err falls from 0.06 to 0.008); its covariance error is the numerical diffusion r‖f‖ of jumps of length r (rel_cov_err ∝ r, 14 → 1 over the same range), which vanishes as r → 0, and its moment errors fall with n. The thesis states the Gaussian kernel's consistency only in the limit r → 0 with Δt ≫ the time the drift takes to cross r, which the holding time above never gives.".into(),
    );
    rep.paper.push(
        Row::new("chain")
            .text("first_moment_err", "decreasing in n (Fig. 2-4a, no values)")
            .text(
                "second_moment_err",
                "decreasing in n (Fig. 2-4b, no values)",
            ),
    );
    Ok(rep)
}

/// Spectral norm of the symmetric 2 × 2 matrix [[a, b], [b, c]].
fn sym2_norm(v: &[f64; 3]) -> f64 {
    let (a, b, c) = (v[0], v[1], v[2]);
    let m = 0.5 * (a + c);
    let r = (0.25 * (a - c).powi(2) + b * b).sqrt();
    (m + r).abs().max((m - r).abs())
}
