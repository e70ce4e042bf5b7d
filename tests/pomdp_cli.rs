//! `beliefbus pomdp solve` and `simulate` end to end: the bounds printed at
//! b0 bracket the exact value, the written policy reads back and simulates
//! within its bounds, and a bad file is one error line naming file and line.

use std::path::{Path, PathBuf};
use std::process::Command;

fn beliefbus(args: &[&str]) -> (Option<i32>, String, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_beliefbus"))
        .args(args)
        .output()
        .unwrap();
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stdout).to_string(),
        String::from_utf8_lossy(&o.stderr).to_string(),
    )
}

/// The two numbers of the `bounds at b0: [lower, upper]` line.
fn final_bounds(out: &str) -> (f64, f64) {
    let line = out
        .lines()
        .find(|l| l.starts_with("bounds at b0:"))
        .unwrap_or_else(|| panic!("no bounds line in:\n{out}"));
    let inner = &line[line.find('[').unwrap() + 1..line.find(']').unwrap()];
    let (a, b) = inner.split_once(", ").unwrap();
    (a.parse().unwrap(), b.parse().unwrap())
}

fn tmp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("beliefbus-pomdp-cli-{}-{name}", std::process::id()))
}

/// tiger.95 from the team's shared data beside the repository.
fn tiger() -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/pomdp/tiger.95.POMDP");
    assert!(
        p.is_file(),
        "{} is missing: the POMDP benchmarks live in shared/data/pomdp beside the repository",
        p.display()
    );
    p
}

#[test]
fn solve_then_simulate_tiger() {
    let file = tiger();
    let policy = tmp("tiger.policy");
    let (code, out, err) = beliefbus(&[
        "pomdp",
        "solve",
        file.to_str().unwrap(),
        "--precision",
        "1e-3",
        "--time",
        "60",
        "--out",
        policy.to_str().unwrap(),
    ]);
    assert_eq!(code, Some(0), "{out}{err}");
    // progress lines, each with upper ≥ lower
    let progress: Vec<&str> = out.lines().filter(|l| l.contains(" s  lower ")).collect();
    assert!(progress.len() >= 2, "{out}");
    for l in &progress {
        let w: Vec<&str> = l.split_whitespace().collect();
        let (lo, hi): (f64, f64) = (w[3].parse().unwrap(), w[5].parse().unwrap());
        assert!(hi >= lo, "{l}");
    }
    // the exact V*(b0) of tiger.95 is 19.3713683745
    let (lo, hi) = final_bounds(&out);
    assert!(
        hi - lo <= 1e-3 + 1e-6 && lo <= 19.3713683745 && hi >= 19.3713683745,
        "{out}"
    );
    let (code, sim, err) = beliefbus(&[
        "pomdp",
        "simulate",
        file.to_str().unwrap(),
        policy.to_str().unwrap(),
        "--runs",
        "4000",
        "--seed",
        "3",
    ]);
    std::fs::remove_file(&policy).unwrap();
    assert_eq!(code, Some(0), "{sim}{err}");
    let line = sim
        .lines()
        .find(|l| l.starts_with("discounted reward"))
        .unwrap();
    let w: Vec<&str> = line.split_whitespace().collect();
    let (mean, se): (f64, f64) = (w[2].parse().unwrap(), w[4].parse().unwrap());
    assert!(
        mean >= lo - 3.0 * se && mean <= hi + 3.0 * se,
        "{line} vs [{lo}, {hi}]"
    );
}

#[test]
fn bad_input_is_one_line_naming_file_and_line() {
    let bad = tmp("bad.pomdp");
    std::fs::write(
        &bad,
        "discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0 : 0 : 7 1\n",
    )
    .unwrap();
    let (code, _, err) = beliefbus(&["pomdp", "solve", bad.to_str().unwrap()]);
    std::fs::remove_file(&bad).unwrap();
    assert_eq!(code, Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains("bad.pomdp:5: state number 7 out of range"),
        "{err}"
    );
    let (code, _, err) = beliefbus(&[
        "pomdp",
        "solve",
        tiger().to_str().unwrap(),
        "--precision",
        "0",
    ]);
    assert_eq!(code, Some(1));
    assert!(err.contains("--precision"), "{err}");
}
