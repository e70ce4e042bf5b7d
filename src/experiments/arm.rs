//! `arm`: paper 003 §3.2, Fig. 4 — path-integral control of the two-link
//! arm (Table 3) through inverse dynamics, with a wrong payload model
//! (m₁ = 1.4 in the controller, 1 in the arm), against the truly optimal
//! controller with the exact model.
//!
//! The controller sees the feedback-linearised arm θ̈ = u + noise (eq. 17,
//! [`DoubleIntegrator`], σ = 1 so Q = I and γ = r by condition (8)) with
//! Φ = ½‖θ(t_f) − θ*‖² + ½‖θ̇(t_f)‖², V = 0, running cost ½ r‖u‖²; the path
//! integral over the 2n noise-driven velocities is Gaussian, so ψ needs no
//! samples (the paper: "no need for generating samples"); the control is
//! recomputed every Δt with the remaining horizon (shrinking). The torque is
//! τ = Ĉ(θ,θ̇)θ̇ + M̂(θ)u with the controller's parameters; the arm integrates
//! M θ̈ + C θ̇ = τ with the true ones (RK4, τ held over Δt).
//!
//! The optimal reference: τ = Cθ̇ + M u* with the exact model and u* the
//! continuous-time finite-horizon LQ control of θ̈ = u, u* = −R⁻¹Bᵀ P(t) (x − x*),
//! P from the Riccati ODE −Ṗ = AᵀP + PA − PBR⁻¹BᵀP, P(t_f) = I (RK4, 100
//! substeps per Δt).
//!
//! Parameters the paper leaves open (chosen here): t_f = 2 s, Δt = 0.01 s,
//! r = 0.01, θ(0) = (0, 0), θ̇(0) = 0, θ* = (1, −0.5) rad, no plant noise
//! (`noise=σ_τ` adds white torque noise σ_τ·ΔW/Δt shared by all runs).

use super::pi_common::{check_params, param};
use super::{ExperimentArgs, ExperimentReport, Row};
use crate::control::implicit::{DiagonalQuadraticCost, EstimatorOptions, PathSampler, PathSetup};
use crate::model::affine::DoubleIntegrator;
use crate::model::arm::ArmParams;
use crate::rng;
use rand::RngExt;
use rand_distr::StandardNormal;

/// Closed-loop record: states (θ, θ̇) and torques per step.
struct Run {
    x: Vec<[f64; 4]>,
    tau: Vec<[f64; 2]>,
}

/// P(t) of −Ṗ = AᵀP + PA − PBR⁻¹BᵀP for one joint of θ̈ = u (A = [0 1; 0 0],
/// B = [0; 1]) with P(t_f) = I; returns P at t = kΔt, k = 0..n.
fn riccati(r: f64, dt: f64, n: usize) -> Vec<[f64; 3]> {
    // P = [[a, b], [b, c]]; Ṗ = −(AᵀP + PA − PBBᵀP/r).
    let deriv = |p: [f64; 3]| {
        let (a, b, c) = (p[0], p[1], p[2]);
        // AᵀP + PA = [[0, a], [a, 2b]];  PBBᵀP = [[b², bc], [bc, c²]].
        [-(-b * b / r), -(a - b * c / r), -(2.0 * b - c * c / r)]
    };
    let sub = 100;
    let h = dt / sub as f64;
    let mut p = [1.0, 0.0, 1.0];
    let mut out = vec![[0.0; 3]; n + 1];
    out[n] = p;
    for k in (0..n).rev() {
        for _ in 0..sub {
            // Integrate backwards in time: dP/d(−t) = −Ṗ.
            let f = |q: [f64; 3]| {
                let d = deriv(q);
                [-d[0], -d[1], -d[2]]
            };
            let add = |q: [f64; 3], d: [f64; 3], s: f64| {
                [q[0] + s * d[0], q[1] + s * d[1], q[2] + s * d[2]]
            };
            let k1 = f(p);
            let k2 = f(add(p, k1, h / 2.0));
            let k3 = f(add(p, k2, h / 2.0));
            let k4 = f(add(p, k3, h));
            for i in 0..3 {
                p[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
            }
        }
        out[k] = p;
    }
    out
}

fn simulate(
    truth: &ArmParams,
    model: &ArmParams,
    x0: [f64; 4],
    dt: f64,
    n: usize,
    noise: &[[f64; 2]],
    mut u_of: impl FnMut(usize, [f64; 4]) -> [f64; 2],
) -> Run {
    let mut x = x0;
    let mut run = Run {
        x: vec![x],
        tau: Vec::with_capacity(n),
    };
    for k in 0..n {
        let u = u_of(k, x);
        let mut tau = model.torque([x[0], x[1]], [x[2], x[3]], u);
        tau[0] += noise[k][0];
        tau[1] += noise[k][1];
        x = truth.rk4_step(x, tau, dt);
        run.x.push(x);
        run.tau.push(tau);
    }
    run
}

/// The experiment entry point.
pub fn run(args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    check_params(
        args,
        &["r", "t_final", "dt", "m1", "noise", "theta1", "theta2"],
    )?;
    let r: f64 = param(args, "r", 0.01)?;
    let t_final: f64 = param(args, "t_final", 2.0)?;
    let dt: f64 = param(args, "dt", 0.01)?;
    let m1: f64 = param(args, "m1", 1.4)?;
    let noise_std: f64 = param(args, "noise", 0.0)?;
    let target = [param(args, "theta1", 1.0)?, param(args, "theta2", -0.5)?];
    let n = (t_final / dt).round() as usize;
    anyhow::ensure!(n >= 1 && r > 0.0, "need t_final ≥ dt and r > 0");
    let truth = ArmParams::table3();
    let wrong = ArmParams { m1, ..truth };
    let x0 = [0.0; 4];

    let mut rep = ExperimentReport::new("arm");
    rep.param("r", r);
    rep.param("gamma", r);
    rep.param("t_final", t_final);
    rep.param("dt", dt);
    rep.param("controller_m1", m1);
    rep.param("true_m1", truth.m1);
    rep.param("theta_target", format!("({}, {})", target[0], target[1]));
    rep.param("theta0", "(0, 0)");
    rep.param("torque_noise", noise_std);
    rep.param(
        "model",
        "Slotine-Li, a1 = m1 lc1² + m2(l1² + lc2²) + I1 + I2, M11 = a1 + 2 a3 cos θ2 (E13)",
    );

    let mut rg = rng::stream(args.seed, 0xA7);
    let noise: Vec<[f64; 2]> = (0..n)
        .map(|_| {
            let s = noise_std / dt.sqrt();
            [
                s * rg.sample::<f64, _>(StandardNormal),
                s * rg.sample::<f64, _>(StandardNormal),
            ]
        })
        .collect();

    // Truly optimal: continuous LQ control with the exact model.
    let p = riccati(r, dt, n);
    let optimal = simulate(&truth, &truth, x0, dt, n, &noise, |k, x| {
        let pk = p[k];
        let mut u = [0.0; 2];
        for j in 0..2 {
            let (e, v) = (x[j] - target[j], x[2 + j]);
            // u = −R⁻¹ Bᵀ P (x − x*) = −(b e + c v)/r.
            u[j] = -(pk[1] * e + pk[2] * v) / r;
        }
        u
    });

    // Path-integral controller on the linearised model.
    let di = DoubleIntegrator { p: 2, sigma: 1.0 };
    let setup = PathSetup::new(&di, &[r, 0.0, 0.0, r], dt)?;
    let mut cost = DiagonalQuadraticCost::new(&[0.0; 4], &[1.0; 4]);
    crate::control::implicit::PathCost::set_goal(&mut cost, &[target[0], target[1], 0.0, 0.0]);
    let opts = EstimatorOptions {
        samples: 0,
        ..EstimatorOptions::default()
    };
    let mut pi_run = |model: &ArmParams| -> anyhow::Result<Run> {
        let mut sampler = PathSampler::new(setup.clone(), n, 1, 1);
        let mut err = None;
        let run = simulate(&truth, model, x0, dt, n, &noise, |k, x| {
            if sampler.warm_steps() > 0 {
                sampler.shift_warm_start(1, n - k);
            }
            match sampler.estimate(&di, &cost, &x, n - k, None, &opts, &mut rg) {
                Ok(e) => [e.u[0], e.u[1]],
                Err(e) => {
                    err = Some(e);
                    [0.0, 0.0]
                }
            }
        });
        if let Some(e) = err {
            anyhow::bail!("path-integral control failed: {e}");
        }
        Ok(run)
    };
    let pi_exact = pi_run(&truth)?;
    let pi_wrong = pi_run(&wrong)?;

    let metrics = |name: &str, run: &Run| {
        let xf = run.x[n];
        let final_err = (xf[0] - target[0]).hypot(xf[1] - target[1]);
        let (mut s_th, mut max_th, mut s_tau, mut max_dtau, mut max_tau) =
            (0.0, 0.0f64, 0.0, 0.0f64, 0.0f64);
        for k in 0..=n {
            let d = (run.x[k][0] - optimal.x[k][0]).hypot(run.x[k][1] - optimal.x[k][1]);
            s_th += d * d;
            max_th = max_th.max(d);
        }
        for k in 0..n {
            let d = (run.tau[k][0] - optimal.tau[k][0]).hypot(run.tau[k][1] - optimal.tau[k][1]);
            s_tau += d * d;
            max_dtau = max_dtau.max(d);
            max_tau = max_tau.max(run.tau[k][0].abs()).max(run.tau[k][1].abs());
        }
        Row::new(name)
            .num("final_angle_err_rad", final_err)
            .num("final_speed", xf[2].hypot(xf[3]))
            .num("rms_dev_theta_rad", (s_th / (n + 1) as f64).sqrt())
            .num("max_dev_theta_rad", max_th)
            .num("rms_dev_tau_nm", (s_tau / n as f64).sqrt())
            .num("max_dev_tau_nm", max_dtau)
            .num("max_tau_nm", max_tau)
    };
    rep.results.push(metrics("optimal_exact", &optimal));
    rep.results.push(metrics("implicit_exact_model", &pi_exact));
    rep.results
        .push(metrics(&format!("implicit_m1_{m1}"), &pi_wrong));
    rep.paper.push(Row::new("implicit_m1_1.4").text(
        "result",
        "control and trajectories closely follow the truly optimal ones (Fig. 4, no numbers)",
    ));
    let pick = |run: &Run, k: usize| {
        format!(
            "θ=({:.3},{:.3}) τ=({:.2},{:.2})",
            run.x[k][0],
            run.x[k][1],
            run.tau[k.min(n - 1)][0],
            run.tau[k.min(n - 1)][1]
        )
    };
    for k in [0, n / 4, n / 2, 3 * n / 4, n] {
        rep.notes.push(format!(
            "t={:.2}: optimal {} | implicit m1={m1} {}",
            k as f64 * dt,
            pick(&optimal, k),
            pick(&pi_wrong, k)
        ));
    }
    rep.notes.push(
        "deviations are against the optimal_exact trajectory/torques at the same times".into(),
    );
    Ok(rep)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn implicit_control_tracks_the_optimal_controller() {
        let rep = run(&ExperimentArgs::default()).unwrap();
        let exact = &rep.results[1].metrics;
        let wrong = &rep.results[2].metrics;
        // Exact model: only the Δt discretisation separates it from the optimum.
        assert!(exact["max_dev_theta_rad"].as_f64().unwrap() < 0.02);
        // Wrong payload: still reaches the target and stays close.
        assert!(wrong["final_angle_err_rad"].as_f64().unwrap() < 0.1);
        assert!(wrong["max_dev_theta_rad"].as_f64().unwrap() < 0.1);
    }
}
