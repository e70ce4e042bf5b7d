//! Bring your own model: a damped pendulum run by the whole beliefbus
//! pipeline (launcher, five stage processes, supervision, report) without
//! changing beliefbus. The model and its scenario are in `model.rs`; this
//! binary is the `beliefbus` command with one more scenario registered:
//!
//! ```text
//! cargo run --release --example pendulum -- run --duration 5
//! cargo run --release --example pendulum -- scenarios
//! cargo run --release --example pendulum -- run --set filter.backend=pf
//! ```

mod model;

use beliefbus::scenario::Registry;

fn main() {
    let registry = Registry::builtin().with::<model::PendulumScenario>();
    std::process::exit(beliefbus::cli::main_with(registry));
}
