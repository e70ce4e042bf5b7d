//! The "bring your own model" example (`examples/pendulum`), as a user
//! meets it: its model checked against finite differences and condition
//! (8), then its binary — the beliefbus command with one more scenario —
//! run from outside the repository through the whole multi-process
//! pipeline.

#[path = "../examples/pendulum/model.rs"]
#[allow(dead_code)]
mod model;

use beliefbus::model::affine::{check_condition_8, ControlAffine};
use beliefbus::model::{fd_step, SdeJacobians, SdeModel};
use model::{Pendulum, PendulumParams};
use serde_json::Value;
use std::path::PathBuf;
use std::process::Command;

/// `target/<profile>/examples/pendulum`, built by `cargo test` with the
/// examples (this test runs from `target/<profile>/deps`).
fn example() -> PathBuf {
    let me = std::env::current_exe().unwrap();
    let exe = me
        .parent()
        .and_then(|deps| deps.parent())
        .unwrap()
        .join("examples/pendulum");
    assert!(
        exe.is_file(),
        "{} not built: `cargo test` builds the examples (or `cargo build --example pendulum`)",
        exe.display()
    );
    exe
}

/// A scratch directory outside the repository (the example must not need
/// the repository's files at run time).
fn scratch() -> PathBuf {
    let d = std::env::temp_dir().join(format!("beliefbus-pendulum-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn the_jacobian_and_curvature_match_finite_differences() {
    let m = Pendulum::new(PendulumParams::default()).unwrap();
    for x in [[0.3, -1.0], [2.0, 4.0], [-1.2, 0.5]] {
        let mut jac = [0.0; 4];
        m.drift_jacobian(&x, &[1.5], &mut jac);
        for j in 0..2 {
            let h = fd_step(x[j]);
            let (mut xp, mut xm) = (x, x);
            xp[j] += h;
            xm[j] -= h;
            let (mut fp, mut fm) = ([0.0; 2], [0.0; 2]);
            m.drift(&xp, &[1.5], &mut fp);
            m.drift(&xm, &[1.5], &mut fm);
            for i in 0..2 {
                let fd = (fp[i] - fm[i]) / (2.0 * h);
                assert!((jac[i + 2 * j] - fd).abs() < 1e-6, "∂f{i}/∂x{j} at {x:?}");
            }
        }
        // Curvature of w·f0 = the derivative of wᵀ∂f0/∂x.
        let w = [0.7, -1.3];
        let mut curv = [0.0; 4];
        m.drift0_curvature(&x, &w, &mut curv);
        for j in 0..2 {
            let h = fd_step(x[j]);
            let (mut xp, mut xm) = (x, x);
            xp[j] += h;
            xm[j] -= h;
            let (mut jp, mut jm) = ([0.0; 4], [0.0; 4]);
            m.drift0_jacobian(&xp, &mut jp);
            m.drift0_jacobian(&xm, &mut jm);
            for k in 0..2 {
                let gp = w[0] * jp[2 * k] + w[1] * jp[1 + 2 * k];
                let gm = w[0] * jm[2 * k] + w[1] * jm[1 + 2 * k];
                let fd = (gp - gm) / (2.0 * h);
                assert!((curv[k + 2 * j] - fd).abs() < 1e-5, "curvature {k},{j}");
            }
        }
    }
}

#[test]
fn the_control_affine_view_is_the_model_and_meets_condition_8() {
    let p = PendulumParams {
        mass: 2.0,
        length: 0.5,
        ..PendulumParams::default()
    };
    let m = Pendulum::new(p.clone()).unwrap();
    // f0(x) + G u = f(x, u).
    let x = [0.8, -0.4];
    let (mut f, mut f0, mut g) = ([0.0; 2], [0.0; 2], [0.0; 2]);
    m.drift(&x, &[3.0], &mut f);
    m.drift0(&x, &mut f0);
    m.input_matrix(&mut g);
    for i in 0..2 {
        assert!((f[i] - (f0[i] + g[i] * 3.0)).abs() < 1e-12);
    }
    // G Q = F: the noise enters through the control channel.
    let (mut q, mut big_f) = ([0.0], [0.0; 2]);
    m.noise_matrix(&mut q);
    m.diffusion(&x, &mut big_f);
    assert!((g[1] * q[0] - big_f[1]).abs() < 1e-12 && big_f[0] == 0.0);
    // γ = σ² (m l²)² R for R = 0.02.
    let gamma = check_condition_8(&m, &[0.02]).unwrap();
    let inertia = p.mass * p.length * p.length;
    let expect = (p.torque_noise * inertia).powi(2) * 0.02;
    assert!(
        (gamma - expect).abs() < 1e-9 * expect,
        "{gamma} vs {expect}"
    );
}

#[test]
fn the_example_binary_lists_its_scenario_beside_the_built_ins() {
    let o = Command::new(example())
        .arg("scenarios")
        .current_dir(scratch())
        .output()
        .unwrap();
    assert!(o.status.success());
    let out = String::from_utf8_lossy(&o.stdout);
    for s in ["ship:", "vanderpol:", "pendulum (default):"] {
        assert!(out.contains(s), "{s} missing:\n{out}");
    }
    // The chain filter is not listed for noise on the velocity only (it
    // serves it with refine.placement = "steady" only, which the listing
    // of the model alone cannot know).
    let pend = out.split("pendulum (default):").nth(1).unwrap();
    let line = pend.lines().find(|l| l.contains("filter.backend")).unwrap();
    assert!(
        !line.contains("chain") && line.contains("implicit"),
        "{line}"
    );
}

#[test]
fn a_backend_the_model_cannot_serve_is_refused_naming_the_scenario() {
    let o = Command::new(example())
        .args([
            "run",
            "--duration",
            "1",
            "--set",
            "filter.backend=chain",
            "--set",
            "refine.placement=belief",
        ])
        .current_dir(scratch())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains("filter.backend") && err.contains("pendulum"),
        "{err}"
    );
    // A bad parameter of the user's own section is named with its path.
    let o = Command::new(example())
        .args(["run", "--set", "pendulum.mass=-1"])
        .current_dir(scratch())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("pendulum.mass"), "{err}");
}

#[test]
fn the_example_runs_the_whole_pipeline_from_outside_the_repository() {
    let dir = scratch();
    let report = dir.join("pendulum.json");
    let o = Command::new(example())
        .args(["run", "--duration", "5", "--report"])
        .arg(&report)
        .current_dir(&dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "exit {:?}: {err}", o.status);
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(r["scenario"], "pendulum");
    // Five stage processes, each processed data and stopped cleanly.
    let mut pids = std::collections::HashSet::new();
    for s in ["ingest", "filter", "control", "refine", "plant"] {
        let st = &r["stages"][s];
        pids.insert(st["pid"].as_u64().unwrap());
        assert!(st["processed"].as_u64().unwrap() > 100, "{s}: {st}");
        assert_eq!(st["exit_status"], "exit 0", "{s}");
    }
    assert_eq!(pids.len(), 5);
    // At least 95 % of the sensor samples produced a control.
    let samples = r["stages"]["plant"]["processed"].as_f64().unwrap();
    let controls = r["stages"]["control"]["processed"].as_f64().unwrap();
    assert!(
        controls >= 0.95 * samples,
        "{controls} controls for {samples} samples"
    );
    // The filter beats reading the encoder, and the controller moved the
    // pendulum between its set-points.
    let acc = &r["accuracy"];
    let (rmse, raw) = (
        acc["rmse_position"].as_f64().unwrap(),
        acc["rmse_position_raw"].as_f64().unwrap(),
    );
    assert!(rmse < raw, "rmse {rmse} vs raw {raw}");
    assert!(
        r["control"]["waypoints_reached"].as_u64().unwrap() >= 1,
        "{}",
        r["control"]
    );
    // Nothing left in shared memory.
    let prefix = r["prefix"].as_str().unwrap();
    assert!(beliefbus::ipc::cleanup::resources(prefix).is_empty());
    assert_eq!(r["shared_memory"]["files_left"], 0);
    let _ = std::fs::remove_dir_all(&dir);
}
