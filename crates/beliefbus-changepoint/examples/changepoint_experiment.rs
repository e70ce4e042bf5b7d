//! Run one of the crate's experiments without the `beliefbus` binary:
//! `cargo run --release --example changepoint_experiment -- <name> [--runs N] [--seed S]
//! [--param KEY=VALUE]... [--json FILE]`.

use beliefbus_changepoint::experiments;
use std::process::ExitCode;

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(name) = args.first() else {
        eprintln!("usage: experiment <name> [--runs N] [--seed S] [--param K=V]... [--json FILE]");
        for e in experiments::all() {
            eprintln!("  {:<26} {}", e.name, e.about);
        }
        return ExitCode::FAILURE;
    };
    let (mut runs, mut seed, mut params, mut json) = (None, 1u64, vec![], None);
    let mut i = 1;
    while i + 1 < args.len() + 1 && i < args.len() {
        let v = args.get(i + 1).cloned().unwrap_or_default();
        match args[i].as_str() {
            "--runs" => runs = v.parse().ok(),
            "--seed" => seed = v.parse().unwrap_or(1),
            "--json" => json = Some(v),
            "--param" => {
                if let Some((k, x)) = v.split_once('=') {
                    params.push((k.trim().to_string(), x.trim().to_string()));
                }
            }
            other => {
                eprintln!("unknown option {other}");
                return ExitCode::FAILURE;
            }
        }
        i += 2;
    }
    let Some(exp) = experiments::find(name) else {
        eprintln!("unknown experiment {name}");
        return ExitCode::FAILURE;
    };
    match (exp.run)(runs, seed, &params) {
        Ok(rep) => {
            print!("{}", rep.render());
            if let Some(path) = json {
                match serde_json::to_string_pretty(&rep) {
                    Ok(s) => {
                        if let Err(e) = std::fs::write(&path, s) {
                            eprintln!("writing {path}: {e}");
                            return ExitCode::FAILURE;
                        }
                    }
                    Err(e) => {
                        eprintln!("{e}");
                        return ExitCode::FAILURE;
                    }
                }
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
