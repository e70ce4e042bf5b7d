//! What every stage executable does (`processes/beliefbus-<stage>.rs` is a
//! one-line call of [`main`]): parse the arguments, load the same config as
//! the launcher, install the stop handler, apply the stage's rt settings,
//! join the pipeline and run the stage loop.
//!
//! ```text
//! beliefbus-<stage> [CONFIG | --scenario NAME] [--set KEY=VALUE ...] [--prefix PREFIX] [--resume FILE]
//! ```
//! Without CONFIG the stage runs the config embedded for `--scenario NAME`
//! (no name: the default scenario's), exactly as `beliefbus run` does.
//! `--resume FILE` (given by the supervisor when it restarts a stage):
//! the state to resume from ([`crate::pipeline::supervisor_resume`]).
//! Started by hand (without `--prefix`), the last stage to stop removes the
//! prefix's remaining shared memory; under the launcher, the launcher does.
//!
//! Exit status: 0 after a clean stop (SIGINT/SIGTERM), 2 for a bad config or
//! bad arguments (one line on stderr), 1 for a runtime failure.

use crate::ipc::{self, StageKind};
use crate::pipeline::config;
use crate::rt::MonotonicClock;
use crate::scenario::Registry;
use crate::stage::resume::Resume;
use crate::stage::{run_stage_with, StageIdentity};
use clap::Parser;
use std::path::PathBuf;

/// Fingerprint of the sources this binary was built from (see `build.rs`).
pub const BUILD_ID: &str = env!("BELIEFBUS_BUILD_ID");

#[derive(Parser, Debug)]
struct Args {
    /// Pipeline config (TOML; default: the scenario's built-in config).
    config: Option<PathBuf>,
    /// Run the built-in config of this registered scenario.
    #[arg(long)]
    scenario: Option<String>,
    /// Override one config key by dotted path (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    sets: Vec<String>,
    /// Shared-memory prefix (overrides `run.prefix`; the launcher passes its
    /// per-run prefix).
    #[arg(long)]
    prefix: Option<String>,
    /// Resume from this state file (written by the supervisor on a restart).
    #[arg(long)]
    resume: Option<PathBuf>,
    /// Print the build fingerprint and exit (the launcher checks it).
    #[arg(long, hide = true)]
    build_id: bool,
}

/// Run stage `kind` as this process with the process's arguments and the
/// built-in scenarios; returns the exit status.
pub fn main(kind: StageKind) -> i32 {
    main_in(&Registry::builtin(), kind, std::env::args_os())
}

/// [`main`] with explicit arguments (the first is the program name).
pub fn main_with<I, T>(kind: StageKind, argv: I) -> i32
where
    I: IntoIterator<Item = T>,
    T: Into<std::ffi::OsString> + Clone,
{
    main_in(&Registry::builtin(), kind, argv)
}

/// [`main_with`] resolving scenarios in `registry` (a user's binary with
/// scenarios of its own runs its stages through this).
pub fn main_in<I, T>(registry: &Registry, kind: StageKind, argv: I) -> i32
where
    I: IntoIterator<Item = T>,
    T: Into<std::ffi::OsString> + Clone,
{
    let name = format!("beliefbus-{}", kind.name());
    let args = match Args::try_parse_from(argv) {
        Ok(a) => a,
        Err(e) if e.use_stderr() => {
            // One line: clap's first line names the problem.
            let msg = e.to_string();
            eprintln!("{name}: {}", msg.lines().next().unwrap_or("bad arguments"));
            return 2;
        }
        Err(e) => {
            let _ = e.print();
            return 0;
        }
    };
    if args.build_id {
        println!("{BUILD_ID}");
        return 0;
    }
    let mut sets = args.sets.clone();
    if let Some(p) = &args.prefix {
        sets.push(format!("run.prefix=\"{p}\""));
    }
    let cfg = match config::ConfigSource::from_args(args.config.clone(), args.scenario.clone())
        .and_then(|src| src.load(registry, &sets))
    {
        Ok(c) => c,
        Err(e) => {
            eprintln!("{name}: {e}");
            return 2;
        }
    };
    let resume = match &args.resume {
        Some(p) => match Resume::load(p) {
            Ok(r) => r,
            Err(e) => {
                eprintln!("{name}: {e}");
                return 2;
            }
        },
        None => Resume::default(),
    };
    let stop = ipc::install_stop_handler();
    let rt = crate::rt::apply_rt(&name, &cfg.stages.get(kind).rt());
    for w in &rt.warnings {
        eprintln!("warning: {w}");
    }
    if let Some(t) = crate::rt::sched::spin_after_from_env() {
        eprintln!("{name}: fault injection: will busy-loop {t} s from now (--chaos-spin)");
    }
    let id = StageIdentity::this_process(kind, &rt);
    let code = match run_stage_with(&cfg.bus(), &cfg, id, &MonotonicClock, stop, &resume) {
        Ok(_) => 0,
        Err(e) => {
            eprintln!("{name}: {e}");
            e.exit_code()
        }
    };
    // Started by hand (no launcher owns the prefix): the last stage out
    // removes what the prefix left (nothing is removed while any node of
    // it is alive).
    // Stages stopped together (Ctrl-C in their terminal) see each other
    // alive for a moment, so wait briefly for the others to go.
    if args.prefix.is_none() {
        let deadline = std::time::Instant::now() + std::time::Duration::from_millis(300);
        loop {
            match ipc::cleanup::remove_prefix(&cfg.run.prefix) {
                Ok(r) if r.alive_nodes == 0 => break,
                _ if std::time::Instant::now() > deadline => break,
                _ => std::thread::sleep(std::time::Duration::from_millis(20)),
            }
        }
    }
    code
}
