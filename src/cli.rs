//! The `beliefbus` command line as a library function, so that a user's
//! binary with scenarios of its own is the whole product:
//!
//! ```no_run
//! use beliefbus::scenario::Registry;
//! fn main() {
//!     // A user's crate adds its own: Registry::builtin().with::<MyScenario>()
//!     std::process::exit(beliefbus::cli::main_with(Registry::builtin()));
//! }
//! ```
//!
//! Subcommands: `run` (the launcher; `--sensor external` for external
//! sensor publishers), `plant` (the simulated plant as an external
//! publisher), `scenarios` (the registry), `experiment` (paper
//! reproductions), `latency` and `jitter`, `pomdp solve|simulate`, `solve`
//! (a scenario's offline policy); the hidden `stage NAME` runs one
//! stage in this process (how the launcher starts the stages of a binary
//! with its own registry, and its fallback when the stage executables next
//! to it are missing or from another build).

mod pomdp;
mod solve;

use crate::config::ConfigSource;
use crate::scenario::Registry;
use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "beliefbus",
    version,
    about = "Real-time estimation and control over zero-copy shared memory"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// `beliefbus run --sensor`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum SensorArg {
    Plant,
    External,
}

#[derive(Subcommand)]
enum Command {
    /// Run the pipeline: spawn the stages, report latency and accuracy.
    Run {
        /// Pipeline config (default: the built-in config of --scenario, or
        /// of the default scenario).
        config: Option<PathBuf>,
        /// Run this registered scenario's built-in config (see `scenarios`).
        #[arg(long)]
        scenario: Option<String>,
        /// Run length in seconds (default: run.duration_s; 0 = until Ctrl-C).
        #[arg(long)]
        duration: Option<f64>,
        /// Write the report JSON here.
        #[arg(long)]
        report: Option<PathBuf>,
        /// Override one config key by dotted path (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        sets: Vec<String>,
        /// No status line every second.
        #[arg(long)]
        quiet: bool,
        /// Where sensor samples come from: the built-in simulated `plant`, or
        /// `external` publishers (no plant; the run uses `run.prefix`; see
        /// docs/sensor-abi.md).
        #[arg(long, value_enum, default_value_t = SensorArg::Plant)]
        sensor: SensorArg,
        /// Fault injection: SIGKILL a random stage at this mean interval
        /// (seconds, exponential gaps); the supervisor restarts it.
        #[arg(long, value_name = "SECONDS")]
        chaos: Option<f64>,
        /// Seed of the chaos schedule (default: run.seed).
        #[arg(long)]
        chaos_seed: Option<u64>,
        /// Stages chaos may kill, comma-separated (default: all).
        #[arg(long, value_delimiter = ',')]
        chaos_stages: Vec<String>,
        /// Fault injection: STAGE busy-loops without blocking SECONDS after
        /// its first start (a runaway real-time stage), e.g. `plant:1`.
        #[arg(long, value_name = "STAGE:SECONDS")]
        chaos_spin: Option<String>,
        /// Write a timeline (JSON lines: RSS, shared-memory files, latency
        /// percentiles per period) to this file.
        #[arg(long)]
        timeline: Option<PathBuf>,
        /// Period of the timeline samples in seconds (0: none; default 60
        /// with --timeline, else 0).
        #[arg(long)]
        timeline_period: Option<f64>,
    },
    /// Run the simulated plant alone, as an external sensor publisher of a
    /// pipeline started with `run CONFIG --sensor external`.
    Plant {
        /// Pipeline config (the same as the run's; default: the built-in
        /// config of --scenario, or of the default scenario).
        config: Option<PathBuf>,
        /// The registered scenario whose built-in config the run uses.
        #[arg(long)]
        scenario: Option<String>,
        /// Seconds to publish (default: run.duration_s; 0 = until Ctrl-C).
        #[arg(long)]
        duration: Option<f64>,
        /// Override one config key by dotted path (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        sets: Vec<String>,
        /// Shared-memory prefix (default: run.prefix of the config).
        #[arg(long)]
        prefix: Option<String>,
        /// Seconds to wait for the pipeline's ingest before giving up.
        #[arg(long, default_value_t = 60.0)]
        wait: f64,
    },
    /// Run one stage in this process (what the launcher falls back to when
    /// the stage executables are missing or stale).
    #[command(hide = true)]
    Stage {
        /// ingest | filter | control | refine | plant
        name: String,
        /// The stage's own arguments.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<String>,
    },
    /// List the registered scenarios: dimensions, sensor channels and the
    /// filter and controller backends each supports.
    Scenarios,
    /// Reproduce a table of the reference papers (`--list` shows them;
    /// `experiment NAME --help` shows that experiment's parameters).
    #[command(disable_help_flag = true)]
    Experiment {
        /// Experiment name.
        name: Option<String>,
        /// List the experiments and exit.
        #[arg(long)]
        list: bool,
        /// Monte-Carlo repetitions (default: the paper's).
        #[arg(long)]
        runs: Option<usize>,
        /// Base seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Write the experiment JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Experiment-specific parameter KEY=VALUE (repeatable).
        #[arg(long = "param", value_name = "KEY=VALUE")]
        params: Vec<String>,
        /// No progress bar.
        #[arg(long)]
        quiet: bool,
        /// Print help (with NAME: that experiment's parameters and defaults).
        #[arg(long, short = 'h')]
        help: bool,
    },
    /// One-way latency of beliefbus's ports against bare iceoryx2, per message type.
    Latency(crate::latency::cli::LatencyArgs),
    /// Timer wake-up jitter baseline per core (cyclictest-style).
    Jitter(crate::latency::cli::JitterArgs),
    #[command(hide = true)]
    LatencyPong(crate::latency::cli::PongArgs),
    /// Discrete POMDPs in Cassandra's `.pomdp` format: `solve` (anytime
    /// bounds at the start belief, α-vector policy) and `simulate`.
    #[command(subcommand)]
    Pomdp(pomdp::PomdpCommand),
    /// Solve a scenario's offline part (e.g. the inventory scenario's
    /// belief-MDP policy table) and write it where its controller looks.
    Solve(solve::SolveArgs),
}

/// Run the `beliefbus` command line with the process's arguments and the
/// scenarios of `registry`; returns the exit status (0 done, 1 runtime
/// failure, 2 bad arguments or config).
pub fn main_with(registry: Registry) -> i32 {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) if e.use_stderr() => {
            // One line naming the problem (clap's first line), exit 2.
            let msg = e.to_string();
            eprintln!("{}", msg.lines().next().unwrap_or("bad arguments"));
            return 2;
        }
        Err(e) => {
            let _ = e.print();
            return 0;
        }
    };
    if let Command::Run {
        config,
        scenario,
        duration,
        report,
        sets,
        quiet,
        sensor,
        chaos,
        chaos_seed,
        chaos_stages,
        chaos_spin,
        timeline,
        timeline_period,
    } = &cli.command
    {
        use crate::pipeline::launcher::SensorSource;
        if let Some(c) = chaos {
            if !(c.is_finite() && *c > 0.0) {
                eprintln!("config: `--chaos`: must be a positive number of seconds, got {c}");
                return 2;
            }
        }
        let mut kinds = Vec::new();
        for n in chaos_stages {
            match crate::ipc::StageKind::from_name(n.trim()) {
                Some(k) => kinds.push(k),
                None => {
                    eprintln!("config: `--chaos-stages`: unknown stage '{n}' (ingest, filter, control, refine, plant)");
                    return 2;
                }
            }
        }
        let spin = match chaos_spin.as_deref().map(parse_spin).transpose() {
            Ok(s) => s,
            Err(e) => {
                eprintln!("config: `--chaos-spin`: {e}");
                return 2;
            }
        };
        let period = timeline_period.unwrap_or(if timeline.is_some() { 60.0 } else { 0.0 });
        if !(period.is_finite() && period >= 0.0) {
            eprintln!("config: `--timeline-period`: must be >= 0 seconds, got {period}");
            return 2;
        }
        let source = match ConfigSource::from_args(config.clone(), scenario.clone()) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("beliefbus: {e}");
                return 2;
            }
        };
        let opts = crate::pipeline::launcher::RunOptions {
            config: source,
            registry: Some(registry),
            sensor: match sensor {
                SensorArg::Plant => SensorSource::Plant,
                SensorArg::External => SensorSource::External,
            },
            duration_s: *duration,
            report: report.clone(),
            sets: sets.clone(),
            quiet: *quiet,
            chaos_s: *chaos,
            chaos_seed: *chaos_seed,
            chaos_stages: kinds,
            chaos_spin: spin,
            timeline: timeline.clone(),
            timeline_period_s: period,
        };
        return crate::pipeline::launcher::main(&opts);
    }
    if let Command::Plant {
        config,
        scenario,
        duration,
        sets,
        prefix,
        wait,
    } = &cli.command
    {
        let source = match ConfigSource::from_args(config.clone(), scenario.clone()) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("beliefbus: {e}");
                return 2;
            }
        };
        let opts = crate::pipeline::external::PlantOptions {
            config: source,
            registry: Some(registry),
            duration_s: *duration,
            sets: sets.clone(),
            prefix: prefix.clone(),
            wait_ingest_s: *wait,
        };
        return crate::pipeline::external::main(&opts);
    }
    if let Command::Stage { name, args } = &cli.command {
        let Some(kind) = crate::ipc::StageKind::from_name(name) else {
            eprintln!("unknown stage '{name}'");
            return 2;
        };
        let argv = std::iter::once(format!("beliefbus-{name}")).chain(args.iter().cloned());
        return crate::pipeline::stage_main::main_in(&registry, kind, argv);
    }
    if let Command::Experiment {
        name,
        runs,
        json,
        params,
        help,
        ..
    } = &cli.command
    {
        if *help {
            return experiment_help(name.as_deref());
        }
        if let Err(e) = check_experiment_args(name.as_deref(), *runs, json.as_deref(), params) {
            eprintln!("beliefbus: {e}");
            return 2;
        }
    }
    if let Command::Solve(a) = &cli.command {
        return match solve::run(&registry, a) {
            Ok(()) => 0,
            Err(e) => {
                eprintln!("error: {e:#}");
                1
            }
        };
    }
    if let Command::Scenarios = &cli.command {
        print!("{}", scenarios_table(&registry));
        return 0;
    }
    match run(cli) {
        Ok(()) => 0,
        Err(e) => {
            eprintln!("error: {e:#}");
            1
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Run { .. }
        | Command::Stage { .. }
        | Command::Plant { .. }
        | Command::Solve(_)
        | Command::Scenarios => {
            unreachable!("handled in main")
        }
        Command::Latency(a) => crate::latency::cli::latency(a),
        Command::Jitter(a) => crate::latency::cli::jitter(a),
        Command::LatencyPong(a) => crate::latency::cli::pong(a),
        Command::Pomdp(c) => pomdp::run(c),
        Command::Experiment {
            name,
            list,
            runs,
            seed,
            json,
            params,
            quiet,
            help: _,
        } => {
            if list || name.is_none() {
                for e in crate::experiments::all() {
                    println!("{:<18} {}", e.name, e.about);
                }
                return Ok(());
            }
            let name = name.unwrap_or_default();
            let Some(exp) = crate::experiments::find(&name) else {
                bail!("unknown experiment '{name}' (see `beliefbus experiment --list`)");
            };
            let kv = parse_params(&params).map_err(anyhow::Error::msg)?;
            let args = crate::experiments::ExperimentArgs {
                runs,
                seed,
                progress: !quiet,
                params: kv,
                doc: exp.params,
            };
            let report = (exp.run)(&args)?;
            print!("{}", report.render());
            if let Some(path) = json {
                let text = serde_json::to_string_pretty(&report)?;
                crate::rt::files::replace_file(&path, text.as_bytes())
                    .with_context(|| format!("writing {}", path.display()))?;
                eprintln!("wrote {}", path.display());
            }
            Ok(())
        }
    }
}

/// `STAGE:SECONDS` of `--chaos-spin`.
fn parse_spin(s: &str) -> Result<(crate::ipc::StageKind, f64), String> {
    let (stage, secs) = s
        .split_once(':')
        .ok_or_else(|| format!("'{s}' is not STAGE:SECONDS"))?;
    let kind = crate::ipc::StageKind::from_name(stage.trim()).ok_or_else(|| {
        format!("unknown stage '{stage}' (ingest, filter, control, refine, plant)")
    })?;
    let t: f64 = secs
        .trim()
        .parse()
        .map_err(|_| format!("'{secs}' is not a number of seconds"))?;
    if !(t.is_finite() && (0.0..=3600.0).contains(&t)) {
        return Err(format!("{t} s is not within 0..=3600"));
    }
    Ok((kind, t))
}

/// `experiment [NAME] --help`: the experiment's parameters, or the
/// subcommand's own help without a name.
fn experiment_help(name: Option<&str>) -> i32 {
    use beliefbus_core::experiment_params::render_help;
    match name {
        Some(n) => match crate::experiments::find(n) {
            Some(e) => {
                print!("{}", render_help(e.name, e.about, e.reproduces, e.params));
                0
            }
            None => {
                eprintln!(
                    "beliefbus: unknown experiment '{n}' (see `beliefbus experiment --list`)"
                );
                2
            }
        },
        None => {
            use clap::CommandFactory;
            let mut cmd = Cli::command();
            let sub = cmd.find_subcommand_mut("experiment").cloned();
            match sub.map(|c| c.bin_name("beliefbus experiment").print_long_help()) {
                Some(Ok(())) => 0,
                _ => 1,
            }
        }
    }
}

/// `KEY=VALUE` pairs of `--param`.
fn parse_params(params: &[String]) -> Result<Vec<(String, String)>, String> {
    params
        .iter()
        .map(|p| {
            p.split_once('=')
                .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()))
                .ok_or_else(|| format!("--param '{p}' is not KEY=VALUE"))
        })
        .collect()
}

/// Refuse what would only fail (or print nonsense) after a long run: an
/// unknown experiment or parameter, zero runs, a `--json` path that cannot
/// be written.
fn check_experiment_args(
    name: Option<&str>,
    runs: Option<usize>,
    json: Option<&std::path::Path>,
    params: &[String],
) -> Result<(), String> {
    if let Some(n) = name {
        let Some(exp) = crate::experiments::find(n) else {
            return Err(format!(
                "unknown experiment '{n}' (see `beliefbus experiment --list`)"
            ));
        };
        let kv = parse_params(params)?;
        if let Some(k) = beliefbus_core::experiment_params::unknown_key(exp.params, &kv) {
            return Err(format!(
                "experiment {n}: unknown parameter '{k}' (see `beliefbus experiment {n} --help`)"
            ));
        }
    }
    if runs == Some(0) {
        return Err("experiment: `--runs`: must be at least 1".into());
    }
    if let Some(path) = json {
        if path.is_dir() {
            return Err(format!("`--json`: {} is a directory", path.display()));
        }
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let c = std::ffi::CString::new(dir.as_os_str().as_encoded_bytes())
            .map_err(|_| format!("`--json`: bad path {}", path.display()))?;
        // SAFETY: `c` is a valid NUL-terminated path for the call's duration.
        let writable = dir.is_dir() && unsafe { libc::access(c.as_ptr(), libc::W_OK) } == 0;
        if !writable {
            return Err(format!(
                "`--json`: cannot write into {} (missing or not writable)",
                dir.display()
            ));
        }
    }
    Ok(())
}

/// `beliefbus scenarios`: one block per registered scenario.
pub fn scenarios_table(registry: &Registry) -> String {
    use std::fmt::Write;
    let default = registry.default_entry().map(|e| e.name);
    let mut out = String::new();
    for info in registry.describe() {
        match info {
            Ok(i) => {
                let mark = if Some(i.name) == default {
                    " (default)"
                } else {
                    ""
                };
                let _ = writeln!(out, "{}{mark}: {}", i.name, i.summary);
                let _ = writeln!(
                    out,
                    "  state {}, control {}, observation {}; sensor channels: {}",
                    i.state,
                    i.control,
                    i.obs,
                    i.channels.join(", ")
                );
                let _ = writeln!(
                    out,
                    "  filter.backend: {}; control.backend: {}",
                    i.filters.join(" | "),
                    i.controllers.join(" | ")
                );
            }
            Err(e) => {
                let _ = writeln!(out, "{e} (cannot be built with its defaults)");
            }
        }
    }
    out
}
