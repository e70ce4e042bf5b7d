//! Run any experiment of this crate without the `beliefbus` binary:
//! `cargo run --release -p beliefbus-localization --example experiment -- <name> [--runs N] [--seed S] [--json FILE] [key=value]...`
//!
//! `... --example experiment -- slam-plot OUT.svg A.json [B.json ...]` draws the
//! `slam` figure from reports of runs split by method (same data sets and
//! seed), keeping the first row of each (method, samples).

use beliefbus_localization::experiments::{slam_plot, Report, Row};

fn rows(v: &serde_json::Value, key: &str, seen: &mut Vec<(String, u64)>, out: &mut Vec<Row>) {
    for r in v[key].as_array().into_iter().flatten() {
        let m = r["method"].as_str().unwrap_or("?").to_string();
        let n = r["samples"].as_u64().unwrap_or(0);
        if seen.contains(&(m.clone(), n)) {
            continue;
        }
        seen.push((m.clone(), n));
        let mut row = Row::new(&m);
        for (k, x) in r.as_object().into_iter().flatten() {
            if let Some(u) = x.as_u64().filter(|_| k == "samples") {
                row = row.int(k, u);
            } else if let Some(f) = x.as_f64() {
                row = row.num(k, f);
            }
        }
        out.push(row);
    }
}

fn plot_from(out: &str, files: &[String]) -> Result<(), String> {
    let mut rep = Report::new("slam");
    let (mut s1, mut s2) = (Vec::new(), Vec::new());
    for f in files {
        let text = std::fs::read_to_string(f).map_err(|e| format!("{f}: {e}"))?;
        let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| format!("{f}: {e}"))?;
        rows(&v, "results", &mut s1, &mut rep.results);
        rows(&v, "paper", &mut s2, &mut rep.paper);
    }
    slam_plot::write_plot(out, &rep).map_err(|e| e.to_string())
}

fn main() {
    let mut args = std::env::args().skip(1);
    let Some(name) = args.next() else {
        eprintln!("usage: experiment <name> [--runs N] [--seed S] [--json FILE] [key=value]...");
        std::process::exit(2);
    };
    if name == "slam-plot" {
        let rest: Vec<String> = args.collect();
        if rest.len() < 2 {
            eprintln!("usage: experiment slam-plot OUT.svg A.json [B.json ...]");
            std::process::exit(2);
        }
        if let Err(e) = plot_from(&rest[0], &rest[1..]) {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
        return;
    }
    let (mut runs, mut seed, mut json, mut kv) = (None, 1u64, None, Vec::new());
    while let Some(a) = args.next() {
        match a.as_str() {
            "--runs" => runs = args.next().and_then(|s| s.parse().ok()),
            "--seed" => seed = args.next().and_then(|s| s.parse().ok()).unwrap_or(1),
            "--json" => json = args.next(),
            _ => {
                if let Some((k, v)) = a.split_once('=') {
                    kv.push((k.to_string(), v.to_string()));
                }
            }
        }
    }
    let Some(exp) = beliefbus_localization::experiments::find(&name) else {
        eprintln!("error: no experiment '{name}'");
        std::process::exit(2);
    };
    match (exp.run)(runs, seed, &kv) {
        Ok(r) => {
            print!("{}", r.render());
            if let Some(path) = json {
                if let Err(e) = std::fs::write(
                    &path,
                    serde_json::to_string_pretty(&r).expect("a report serialises"),
                ) {
                    eprintln!("error: {path}: {e}");
                    std::process::exit(1);
                }
            }
        }
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
}
