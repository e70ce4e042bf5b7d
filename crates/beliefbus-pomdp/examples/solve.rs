//! `cargo run --release --example solve -- FILE.pomdp [TIME_S] [PRECISION] [RUNS]`:
//! solves, prints the bounds at b0 as they tighten, then simulates the policy.
//! `THREADS=n` sets the backup threads, `OPEN_LOOP=h` the open-loop plans'
//! horizon (`SolveOptions::open_loop_horizon`; unset: the default),
//! `FOLLOW_LOWER=k` every k-th trial following the lower bound's plan.
use beliefbus_pomdp::*;
use std::time::Duration;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let p = parse_file(std::path::Path::new(&args[1])).unwrap_or_else(|e| panic!("{e}"));
    let time = args
        .get(2)
        .map(|s| s.parse::<f64>().unwrap())
        .unwrap_or(10.0);
    let precision = args
        .get(3)
        .map(|s| s.parse::<f64>().unwrap())
        .unwrap_or(1e-3);
    let runs = args
        .get(4)
        .map(|s| s.parse::<usize>().unwrap())
        .unwrap_or(2000);
    let opts = SolveOptions {
        precision,
        time_limit: Some(Duration::from_secs_f64(time)),
        threads: std::env::var("THREADS")
            .ok()
            .and_then(|t| t.parse().ok())
            .unwrap_or(2),
        open_loop_horizon: std::env::var("OPEN_LOOP")
            .ok()
            .and_then(|t| t.parse().ok())
            .unwrap_or(SolveOptions::default().open_loop_horizon),
        follow_lower_every: std::env::var("FOLLOW_LOWER")
            .ok()
            .and_then(|t| t.parse().ok())
            .unwrap_or(0),
        ..Default::default()
    };
    let sol = solve(&p, &opts, |pr| {
        println!(
            "{:8.3} s  lower {:.6}  upper {:.6}  gap {:.2e}  trials {}  alpha {}  points {}",
            pr.time_s,
            pr.lower,
            pr.upper,
            pr.upper - pr.lower,
            pr.trials,
            pr.alpha_vectors,
            pr.upper_points
        )
    })
    .unwrap();
    println!(
        "final [{:.6}, {:.6}] in {:.3} s converged={}",
        sol.lower, sol.upper, sol.time_s, sol.converged
    );
    let sim = simulate(
        &p,
        &sol.policy,
        &SimulateOptions {
            runs,
            seed: 1,
            ..Default::default()
        },
    )
    .unwrap();
    println!(
        "simulated {:.4} ± {:.4} (H = {}, {} runs)",
        sim.mean, sim.std_err, sim.horizon, sim.runs
    );
}
