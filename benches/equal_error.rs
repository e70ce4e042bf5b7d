//! The chain filter against the bootstrap particle filter **at equal
//! error**, per step, on three models, both filters on the same simulated
//! records in the same process (the baseline measured in the same run):
//!
//! * `ship`: paper 001's drifting ship (thesis §3.4.1), range and bearing
//!   every 0.01 s, prior N(0, diag(0.3², 0.3², 0.2², 0.2²)), 10 s; PF with
//!   100 particles (the paper's comparison);
//! * `vanderpol`: the `vanderpol` experiment's setting (x₁ once a second,
//!   10 s); PF with 300 particles;
//! * `pendulum`: the example of "Bring your own model"
//!   (`examples/pendulum`, noise on the angular velocity only), encoder
//!   every 0.01 s, 10 s; PF with 1000 particles (its config's).
//!
//! The chain is the one [`ChainFilterSpec`] derives from the model (state
//! budget, δ, placement), plus chains at ½, 2 and 4 times that budget; the
//! CPU the chain needs to reach the PF's mean error is interpolated on that
//! curve (log CPU linear in the error between the bracketing sizes). The
//! figures are thread-CPU time per filter step (predict + update + belief),
//! medians over the runs; chain construction is one-off and printed apart.
//!
//! `cargo bench --bench equal_error` (BENCH_RUNS=N records per model,
//! default 20; BENCH_MODELS=ship,vanderpol,pendulum to choose).

#[path = "../examples/pendulum/model.rs"]
#[allow(dead_code)]
mod pendulum;

use beliefbus::belief::Gaussian;
use beliefbus::experiments::chain_defaults::{compare, summary, vanderpol_setting, Setting};
use beliefbus::experiments::vanderpol::equal_error_cpu;
use beliefbus::experiments::Progress;
use beliefbus::filter::chain_spec::ChainFilterSpec;
use beliefbus::model::ship::{Ship, ShipParams};
use beliefbus::model::SdeModel;

/// Run one model and print its row.
fn row<M: SdeModel + Clone + 'static>(
    name: &str,
    model: &M,
    set: &Setting,
    particles: usize,
    runs: usize,
) {
    let spec = ChainFilterSpec {
        period: set.period,
        obs_every: set.obs_every,
        horizon: set.horizon,
        seed: 1,
        ..ChainFilterSpec::default()
    };
    let steps = (set.horizon / set.period).round();
    let mut bar = Progress::new(name, runs, false);
    let out = match compare(
        model,
        set,
        &spec,
        particles,
        &[0.5, 2.0, 4.0],
        None,
        runs,
        1,
        &mut bar,
    ) {
        Ok(o) => o,
        Err(e) => {
            println!("{name:>10}  chain filter not built: {e:#}");
            return;
        }
    };
    let (pe, pse, pcpu, pdiv) = summary(&out.pf);
    let mut curve: Vec<(usize, f64, f64)> = out
        .curve
        .iter()
        .map(|(n, v)| {
            let (e, _, c, _) = summary(v);
            (*n, e, c)
        })
        .collect();
    curve.sort_by_key(|c| c.0);
    let per_step = |cpu_s: f64| cpu_s / steps * 1e6;
    println!(
        "{name:>10}  PF-{particles}: error {pe:.4} ± {pse:.4}, {:.1} µs/step, {pdiv} lost",
        per_step(pcpu)
    );
    for (n, v) in &out.curve {
        let (e, se, c, div) = summary(v);
        println!(
            "{:>10}  chain {n:>6} states: error {e:.4} ± {se:.4}, {:.1} µs/step ({:.2}× PF), {div} lost",
            "",
            per_step(c),
            c / pcpu
        );
    }
    match equal_error_cpu(&curve, pe) {
        Some(c) => println!(
            "{:>10}  at the PF's error: chain {:.1} µs/step = {:.2}× the PF's CPU (build {:.2} s once)",
            "",
            per_step(c),
            c / pcpu,
            out.build_cpu_s
        ),
        None => {
            let best = curve
                .iter()
                .cloned()
                .fold(None, |b: Option<(usize, f64, f64)>, c| match b {
                    Some(x) if x.1 <= c.1 => Some(x),
                    _ => Some(c),
                });
            match best {
                Some(_) if curve.iter().all(|c| c.1 <= pe) => {
                    let (n, _, c) = curve[0];
                    println!(
                        "{:>10}  every chain on the curve is at or below the PF's error: at most {:.2}× the PF's CPU ({n} states)",
                        "",
                        c / pcpu
                    )
                }
                Some((n, e, _)) => println!(
                    "{:>10}  no chain on the curve reaches the PF's error (best {e:.4} at {n} states)",
                    ""
                ),
                None => {}
            }
        }
    }
}

fn main() {
    // `cargo bench` passes harness flags (e.g. --bench); nothing to parse.
    let runs: usize = std::env::var("BENCH_RUNS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20);
    let models = std::env::var("BENCH_MODELS").unwrap_or_else(|_| "ship,vanderpol,pendulum".into());
    println!("chain filter vs bootstrap PF at equal error: {runs} records per model, thread-CPU per step (median over the records)");
    for m in models.split(',') {
        match m.trim() {
            "ship" => {
                let model = Ship::new(ShipParams::paper(0.01)).expect("ship");
                let set = Setting {
                    period: 0.01,
                    obs_every: 1,
                    horizon: 10.0,
                    prior: Gaussian::diagonal(&[0.0; 4], &[0.3, 0.3, 0.2, 0.2]),
                };
                row("ship", &model, &set, 100, runs);
            }
            "vanderpol" => {
                let (model, set) = vanderpol_setting().expect("van der pol");
                row("vanderpol", &model, &set, 300, runs);
            }
            "pendulum" => {
                let model =
                    pendulum::Pendulum::new(pendulum::PendulumParams::default()).expect("pendulum");
                let set = Setting {
                    period: 0.01,
                    obs_every: 1,
                    horizon: 10.0,
                    prior: Gaussian::diagonal(&[0.5, 0.0], &[0.1, 0.3]),
                };
                row("pendulum", &model, &set, 1000, runs);
            }
            other => println!("unknown model {other:?} (ship, vanderpol, pendulum)"),
        }
    }
}
