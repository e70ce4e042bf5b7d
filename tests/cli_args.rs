//! The command line refuses bad experiment arguments at once: exit 2 and
//! one line, before any work (a long run must not end in a NaN table or an
//! unwritable output file).

use std::process::Command;

fn beliefbus(args: &[&str]) -> (Option<i32>, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_beliefbus"))
        .args(args)
        .current_dir(std::env::temp_dir())
        .output()
        .unwrap();
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stderr).to_string(),
    )
}

#[test]
fn bad_experiment_arguments_exit_2_with_one_line() {
    for (args, says) in [
        (&["experiment", "vanderpol", "--runs", "0"][..], "--runs"),
        (&["experiment", "warp-drive"][..], "unknown experiment"),
        (
            &[
                "experiment",
                "vanderpol",
                "--json",
                "/nonexistent-dir/out.json",
            ][..],
            "--json",
        ),
        (
            &["experiment", "vanderpol", "--json", "/tmp"][..],
            "directory",
        ),
        (
            &["experiment", "vanderpol", "--param", "warp=9"][..],
            "unknown parameter 'warp'",
        ),
        (
            &["experiment", "changepoint-cv2", "--param", "particle=9"][..],
            "unknown parameter 'particle'",
        ),
        (
            &["experiment", "vanderpol", "--param", "states"][..],
            "not KEY=VALUE",
        ),
    ] {
        let (code, err) = beliefbus(args);
        assert_eq!(code, Some(2), "{args:?}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: {err}");
    }
}

fn stdout_of(args: &[&str]) -> (Option<i32>, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_beliefbus"))
        .args(args)
        .current_dir(std::env::temp_dir())
        .output()
        .unwrap();
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stdout).to_string(),
    )
}

/// `experiment NAME --help` lists that experiment's own parameters with
/// their defaults and the paper figure, for experiments of every crate.
#[test]
fn experiment_help_lists_its_parameters() {
    for (name, key_default, table) in [
        (
            "vanderpol",
            ("curve_particles", "25,50,100,200,400,1000"),
            "paper 001",
        ),
        ("himmelblau", ("samples", "50"), "paper 003 Table 4"),
        (
            "changepoint-cv2",
            ("bounds", "0,0.5,1,2,4,10,20,30,inf"),
            "paper 002 Table 1",
        ),
        (
            "inventory-average",
            ("mc_samples", "500"),
            "paper 004 Table I",
        ),
    ] {
        let (code, out) = stdout_of(&["experiment", name, "--help"]);
        assert_eq!(code, Some(0), "{name}: {out}");
        let line = out
            .lines()
            .find(|l| l.trim_start().starts_with(key_default.0))
            .unwrap_or_else(|| panic!("{name}: no {} in\n{out}", key_default.0));
        assert!(line.contains(key_default.1), "{name}: {line}");
        assert!(out.contains(table), "{name}: {out}");
    }
    let (code, out) = stdout_of(&["experiment", "--help"]);
    assert_eq!(code, Some(0));
    assert!(out.contains("--param"), "{out}");
}
