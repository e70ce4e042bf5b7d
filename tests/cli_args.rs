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
    ] {
        let (code, err) = beliefbus(args);
        assert_eq!(code, Some(2), "{args:?}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: {err}");
    }
}
