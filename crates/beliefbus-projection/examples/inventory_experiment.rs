//! Run one of the crate's experiments without the `beliefbus` binary:
//! `cargo run --release --example inventory_experiment -- <name> [--runs N] [--seed S]
//! [--param key=value]... [--json FILE]`.

use beliefbus_projection::experiments::{find, ExperimentArgs};

fn main() {
    if let Err(e) = run() {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<(), String> {
    let mut it = std::env::args().skip(1);
    let name = it
        .next()
        .ok_or("usage: experiment <name> [--runs N] [--seed S] [--param k=v] [--json FILE]")?;
    let exp = find(&name).ok_or_else(|| format!("unknown experiment {name}"))?;
    let mut args = ExperimentArgs::default();
    let mut json = None;
    while let Some(flag) = it.next() {
        let val = it.next().ok_or_else(|| format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--runs" => args.runs = Some(val.parse().map_err(|e| format!("--runs: {e}"))?),
            "--seed" => args.seed = val.parse().map_err(|e| format!("--seed: {e}"))?,
            "--param" => {
                let (k, v) = val.split_once('=').ok_or("--param wants key=value")?;
                args.params.push((k.to_string(), v.to_string()));
            }
            "--json" => json = Some(val),
            _ => return Err(format!("unknown flag {flag}")),
        }
    }
    let rep = (exp.run)(&args).map_err(|e| e.to_string())?;
    print!("{}", rep.render());
    if let Some(path) = json {
        let text = serde_json::to_string_pretty(&rep).map_err(|e| e.to_string())?;
        std::fs::write(&path, text).map_err(|e| format!("{path}: {e}"))?;
    }
    Ok(())
}
