//! `beliefbus`: the user-facing command. Subcommands: `run` (the launcher,
//! issue 2) and `experiment` (paper reproductions).

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

#[derive(Subcommand)]
enum Command {
    /// Reproduce a table of the reference papers (`--list` shows them).
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
    },
    /// One-way latency of beliefbus's ports against bare iceoryx2, per message type.
    Latency(beliefbus::latency::cli::LatencyArgs),
    /// Timer wake-up jitter baseline per core (cyclictest-style).
    Jitter(beliefbus::latency::cli::JitterArgs),
    #[command(hide = true)]
    LatencyPong(beliefbus::latency::cli::PongArgs),
}

fn main() {
    let cli = Cli::parse();
    let code = match run(cli) {
        Ok(()) => 0,
        Err(e) => {
            eprintln!("error: {e:#}");
            1
        }
    };
    std::process::exit(code);
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Latency(a) => beliefbus::latency::cli::latency(a),
        Command::Jitter(a) => beliefbus::latency::cli::jitter(a),
        Command::LatencyPong(a) => beliefbus::latency::cli::pong(a),
        Command::Experiment {
            name,
            list,
            runs,
            seed,
            json,
            params,
            quiet,
        } => {
            if list || name.is_none() {
                for e in beliefbus::experiments::all() {
                    println!("{:<18} {}", e.name, e.about);
                }
                return Ok(());
            }
            let name = name.unwrap_or_default();
            let Some(exp) = beliefbus::experiments::find(&name) else {
                bail!("unknown experiment '{name}' (see `beliefbus experiment --list`)");
            };
            let mut kv = Vec::new();
            for p in params {
                let (k, v) = p
                    .split_once('=')
                    .with_context(|| format!("--param '{p}' is not KEY=VALUE"))?;
                kv.push((k.trim().to_string(), v.trim().to_string()));
            }
            let args = beliefbus::experiments::ExperimentArgs {
                runs,
                seed,
                progress: !quiet,
                params: kv,
            };
            let report = (exp.run)(&args)?;
            print!("{}", report.render());
            if let Some(path) = json {
                let text = serde_json::to_string_pretty(&report)?;
                std::fs::write(&path, text)
                    .with_context(|| format!("writing {}", path.display()))?;
                eprintln!("wrote {}", path.display());
            }
            Ok(())
        }
    }
}
