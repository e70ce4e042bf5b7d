//! The `latency`, `jitter` and (hidden) `latency-pong` subcommands: argument
//! parsing, output files and the console table. A bad argument prints one
//! line and exits with code 2.

use super::hdr::file_stem;
use super::hdr::HdrLog;
use super::jitter::probe;
use super::jitter::{
    baseline_entries, timer_baseline, JitterEntry, JitterReport, PipelineInfo, TimerConfig,
};
use super::load::LoadSample;
use super::paths::{Mode, PathKind};
use super::pipeline::{self, PipelineJitterConfig};
use super::plot::{write_svg, Row, Series};
use super::pong::{serve, PongConfig};
use super::report::now_iso8601;
use super::run::{run, LatencyConfig, LatencyRun};
use super::stress::Stress;
use super::LatencyError;
use crate::rt::LatencyHist;
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// `beliefbus latency`.
#[derive(clap::Args, Debug, Clone)]
pub struct LatencyArgs {
    /// How receivers wait: block on a notification (event), busy-poll
    /// (spin; needs a core per process), or poll briefly then block (hybrid).
    #[arg(long, value_enum, default_value_t = Mode::Event)]
    pub mode: Mode,
    /// Paths to measure: `all`, or a comma list of observation, belief,
    /// control and chain slice sizes (64, 4K, 16MiB, ...).
    #[arg(long, default_value = "all", value_name = "BYTES|all")]
    pub payload: String,
    /// Measured time in total, seconds (shared by all paths, ours and bare).
    #[arg(long, default_value_t = 10.0)]
    pub duration: f64,
    /// Cores of the two processes, `A,B` (default 0,1 when there are two;
    /// `none` to leave placement to the scheduler).
    #[arg(long, value_name = "A,B")]
    pub cores: Option<String>,
    /// Write the JSON report here.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// Write histogram and CDF plots (SVG) here.
    #[arg(long, value_name = "FILE.svg")]
    pub plot: Option<PathBuf>,
    /// Write HdrHistogram V2 interval logs into this directory.
    #[arg(long, value_name = "DIR")]
    pub hdr: Option<PathBuf>,
    /// Hybrid mode: poll this long before blocking, µs.
    #[arg(long, default_value_t = 50)]
    pub spin_us: u64,
    /// Run both processes at this SCHED_FIFO priority (1–99).
    #[arg(long, value_name = "PRIO")]
    pub fifo: Option<u8>,
    /// Longest slot of one path and implementation, ms.
    #[arg(long, default_value_t = 100)]
    pub slot_ms: u64,
}

/// `beliefbus jitter`.
#[derive(clap::Args, Debug, Clone)]
pub struct JitterArgs {
    /// Wake-ups (timer) and sensor samples (pipeline) per second (default:
    /// the config's sensor rate; 1000 with --timer-only).
    #[arg(long, value_name = "HZ")]
    pub rate: Option<f64>,
    /// Seconds to measure, for the timer and again for the pipeline.
    #[arg(long, default_value_t = 10.0)]
    pub duration: f64,
    /// Run N busy CPU threads and N memory-bandwidth threads meanwhile.
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub stress: usize,
    /// Write the JSON report here.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// Write histogram and CDF plots (SVG) here.
    #[arg(long, value_name = "FILE.svg")]
    pub plot: Option<PathBuf>,
    /// Write HdrHistogram V2 interval logs into this directory.
    #[arg(long, value_name = "DIR")]
    pub hdr: Option<PathBuf>,
    /// SCHED_FIFO priority of the timer threads (0: SCHED_OTHER).
    #[arg(long, default_value_t = 80, value_name = "PRIO")]
    pub fifo: u8,
    /// Cores to measure, `A,B,...` (default: every core).
    #[arg(long, value_name = "A,B,...")]
    pub cores: Option<String>,
    /// Pipeline config to run.
    #[arg(long, default_value = DEFAULT_JITTER_CONFIG, value_name = "FILE")]
    pub config: PathBuf,
    /// Override one config key by dotted path (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub sets: Vec<String>,
    /// Only the timer baseline, no pipeline.
    #[arg(long)]
    pub timer_only: bool,
    /// Seconds of the host stall probe after the timer baseline (one
    /// spinning thread per core; 0: off; default: --duration, at most 10).
    #[arg(long, value_name = "SECONDS")]
    pub probe: Option<f64>,
}

/// The pipeline `beliefbus jitter` runs by default (1 kHz closed loop).
pub const DEFAULT_JITTER_CONFIG: &str = "configs/ship-1khz.toml";

/// The hidden `latency-pong` subcommand (started by `latency`).
#[derive(clap::Args, Debug, Clone)]
pub struct PongArgs {
    #[arg(long)]
    pub prefix: String,
    #[arg(long, value_enum)]
    pub mode: Mode,
    #[arg(long, default_value_t = 50)]
    pub spin_us: u64,
    #[arg(long)]
    pub paths: String,
    #[arg(long)]
    pub core: Option<usize>,
    #[arg(long)]
    pub fifo: Option<u8>,
}

/// Print a user mistake as one line and exit 2.
fn bad_arg(e: LatencyError) -> ! {
    eprintln!("error: {e}");
    std::process::exit(2);
}

fn check<T>(r: Result<T, LatencyError>) -> Result<T> {
    match r {
        Err(LatencyError::BadArg(m)) => bad_arg(LatencyError::BadArg(m)),
        r => Ok(r?),
    }
}

fn parse_cores(s: &str) -> Result<Vec<usize>, LatencyError> {
    s.split(',')
        .map(|c| {
            c.trim()
                .parse::<usize>()
                .map_err(|_| LatencyError::BadArg(format!("--cores: '{c}' is not a core number")))
        })
        .collect()
}

fn duration(secs: f64) -> Result<Duration, LatencyError> {
    if !(secs.is_finite() && secs > 0.0 && secs <= 86_400.0) {
        return Err(LatencyError::BadArg(format!(
            "--duration must be in (0, 86400] seconds, got {secs}"
        )));
    }
    Ok(Duration::from_secs_f64(secs))
}

fn write_json<T: serde::Serialize>(path: &Path, v: &T) -> Result<()> {
    let text = serde_json::to_string_pretty(v)?;
    crate::rt::files::replace_file(path, (text + "\n").as_bytes())
        .with_context(|| format!("writing {}", path.display()))?;
    eprintln!("wrote {}", path.display());
    Ok(())
}

/// The latency configuration of the command line (pong: this executable).
pub fn latency_config(a: &LatencyArgs) -> Result<LatencyConfig, LatencyError> {
    let exe = std::env::current_exe()
        .map_err(|e| LatencyError::Spawn(format!("cannot find this executable: {e}")))?;
    let mut cfg = LatencyConfig::new(exe, vec!["latency-pong".into()]);
    cfg.mode = a.mode;
    cfg.paths = PathKind::parse_list(&a.payload)?;
    cfg.duration = duration(a.duration)?;
    cfg.slot = Duration::from_millis(a.slot_ms);
    cfg.spin = Duration::from_micros(a.spin_us);
    cfg.fifo = a.fifo;
    cfg.hdr_logs = a.hdr.is_some();
    match a.cores.as_deref() {
        None => {}
        Some("none") => cfg.cores = None,
        Some(s) => match parse_cores(s)?.as_slice() {
            [x, y] => cfg.cores = Some((*x, *y)),
            _ => return Err(LatencyError::BadArg("--cores takes two cores, A,B".into())),
        },
    }
    cfg.validate()?;
    Ok(cfg)
}

/// Write the plots and logs of a latency run.
pub fn latency_outputs(r: &LatencyRun, plot: Option<&Path>, hdr: Option<&Path>) -> Result<()> {
    if let Some(path) = plot {
        let rows: Vec<Row> = r
            .paths
            .iter()
            .map(|p| Row {
                title: format!(
                    "{} ({} B, {})",
                    p.kind.name(),
                    p.kind.payload_bytes(),
                    r.report.run.mode
                ),
                series: vec![
                    Series {
                        label: "ours".into(),
                        hist: &p.ours,
                    },
                    Series {
                        label: "bare iceoryx2".into(),
                        hist: &p.bare,
                    },
                ],
            })
            .collect();
        let title = format!(
            "beliefbus one-way latency (round trip / 2), {} mode, {}",
            r.report.run.mode, r.report.run.date
        );
        write_svg(path, &title, &rows)?;
        eprintln!("wrote {}", path.display());
    }
    if let Some(dir) = hdr {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        for p in &r.paths {
            for (which, log) in [("ours", &p.ours_log), ("bare", &p.bare_log)] {
                if let Some(log) = log {
                    let f = dir.join(format!("{}.{which}.hlog", file_stem(&p.kind.name())));
                    log.save(&f)
                        .with_context(|| format!("writing {}", f.display()))?;
                }
            }
        }
        eprintln!("wrote HdrHistogram logs to {}", dir.display());
    }
    Ok(())
}

/// `beliefbus latency ...`.
pub fn latency(a: LatencyArgs) -> Result<()> {
    let cfg = check(latency_config(&a))?;
    let stop = crate::ipc::install_stop_handler();
    let (slot, rounds) = cfg.schedule();
    eprintln!(
        "measuring {} paths × (ours, bare), {} mode, {rounds} rounds of {:.0} ms slots{}",
        cfg.paths.len(),
        cfg.mode.name(),
        slot.as_secs_f64() * 1e3,
        cfg.cores
            .map(|(x, y)| format!(", cores {x},{y}"))
            .unwrap_or_default()
    );
    let r = run(&cfg, stop)?;
    print!("{}", r.report.render());
    if r.stopped {
        eprintln!("stopped early: the figures cover the time measured");
    }
    if let Some(path) = &a.json {
        write_json(path, &r.report)?;
    }
    latency_outputs(&r, a.plot.as_deref(), a.hdr.as_deref())?;
    if r.report.run.shm_left > 0 {
        anyhow::bail!(
            "{} shared-memory files of the run could not be removed",
            r.report.run.shm_left
        );
    }
    Ok(())
}

/// The timer configuration of the command line at `rate_hz`.
pub fn timer_config(a: &JitterArgs, rate_hz: f64) -> Result<TimerConfig, LatencyError> {
    let cores = match a.cores.as_deref() {
        Some(s) => parse_cores(s)?,
        None => {
            let mut ids: Vec<usize> = core_affinity::get_core_ids()
                .unwrap_or_default()
                .into_iter()
                .map(|c| c.id)
                .collect();
            ids.sort_unstable();
            if ids.is_empty() {
                vec![0]
            } else {
                ids
            }
        }
    };
    let cfg = TimerConfig {
        rate_hz,
        duration: duration(a.duration)?,
        cores,
        fifo: (a.fifo > 0).then_some(a.fifo),
        hdr_logs: a.hdr.is_some(),
    };
    cfg.validate()?;
    Ok(cfg)
}

/// The pipeline run of the command line and its sensor rate (None with
/// `--timer-only`). An explicit `--rate` becomes `plant.sensor_rate_hz`.
pub fn pipeline_config(
    a: &JitterArgs,
) -> Result<Option<(PipelineJitterConfig, f64)>, LatencyError> {
    if a.timer_only {
        return Ok(None);
    }
    let mut sets = a.sets.clone();
    if let Some(r) = a.rate {
        sets.push(format!("plant.sensor_rate_hz={r}"));
    }
    let pcfg = crate::pipeline::config::load(&a.config, &sets)
        .map_err(|e| LatencyError::BadArg(e.to_string()))?;
    let exe = std::env::current_exe()
        .map_err(|e| LatencyError::Spawn(format!("cannot find this executable: {e}")))?;
    let warm_cores = if pcfg.run.keep_cores_warm {
        crate::ipc::StageKind::ALL
            .iter()
            .filter_map(|&k| pcfg.stages.get(k).core)
            .collect()
    } else {
        vec![]
    };
    Ok(Some((
        PipelineJitterConfig {
            exe,
            config: a.config.clone(),
            sets,
            duration: duration(a.duration)?,
            warm_cores,
        },
        pcfg.plant.sensor_rate_hz,
    )))
}

fn merged<'a>(hs: impl Iterator<Item = &'a LatencyHist>) -> LatencyHist {
    let mut m = LatencyHist::new();
    for h in hs {
        m.merge(h);
    }
    m
}

/// `beliefbus jitter ...`.
pub fn jitter(a: JitterArgs) -> Result<()> {
    let pipe = check(pipeline_config(&a))?;
    let rate = a.rate.or(pipe.as_ref().map(|p| p.1)).unwrap_or(1000.0);
    let cfg = check(timer_config(&a, rate))?;
    let stop = crate::ipc::install_stop_handler();
    let date = now_iso8601();
    eprintln!(
        "timer baseline on cores {:?} at {} Hz for {:.1} s{}{}",
        cfg.cores,
        cfg.rate_hz,
        cfg.duration.as_secs_f64(),
        if a.stress > 0 {
            format!(", stress {0} cpu + {0} mem threads", a.stress)
        } else {
            String::new()
        },
        match &pipe {
            Some((p, _)) => format!(", then the pipeline {}", p.config.display()),
            None => String::new(),
        }
    );
    let load0 = LoadSample::now();
    let stress = Stress::start(a.stress, a.stress);
    // The baseline sees the machine as the pipeline will: with the
    // config's idle-class spinners when it keeps its cores warm.
    let warm = match &pipe {
        Some((p, _)) if !p.warm_cores.is_empty() => {
            eprintln!(
                "timer baseline with cores {:?} kept warm (run.keep_cores_warm)",
                {
                    let mut c = p.warm_cores.clone();
                    c.sort_unstable();
                    c.dedup();
                    c
                }
            );
            Some(crate::rt::KeepWarm::start(&p.warm_cores))
        }
        _ => None,
    };
    let host0 = crate::rt::host::snapshot();
    let cores = timer_baseline(&cfg, stop)?;
    let baseline_host = crate::rt::host::loss(&host0, &crate::rt::host::snapshot(), &cfg.cores);
    drop(warm);
    let probe_s = check(probe::seconds(a.probe, a.duration))?;
    let stalls = if probe_s > 0.0 && !stop.load(std::sync::atomic::Ordering::Relaxed) {
        eprintln!(
            "host stall probe on cores {:?} for {probe_s:.1} s",
            cfg.cores
        );
        let d = Duration::from_secs_f64(probe_s);
        crate::rt::stall::probe(&cfg.cores, d, cfg.fifo, stop).map_err(LatencyError::Spawn)?
    } else {
        Vec::new()
    };
    let measured = match &pipe {
        Some((p, _)) if !stop.load(std::sync::atomic::Ordering::Relaxed) => {
            eprintln!("pipeline: starting beliefbus run ...");
            Some(check(pipeline::measure(p, stop))?)
        }
        _ => None,
    };
    drop(stress);
    let load = load0.until(&LoadSample::now());
    let (baseline, per_core) = baseline_entries(&cfg, &cores);
    let mut warnings: Vec<String> = cores.iter().flat_map(|c| c.warnings.clone()).collect();
    warnings.extend(stalls.iter().flat_map(|c| c.warnings.clone()));
    if cfg.fifo.is_some() && cores.iter().any(|c| !c.fifo) {
        warnings.push("some timer threads ran SCHED_OTHER".into());
    }
    let mut paths = Vec::new();
    let mut info = None;
    let mut shm_left = 0;
    if let Some(m) = &measured {
        let budget = (m.e2e_budget_ns > 0).then(|| m.e2e_budget_ns as f64 / 1e3);
        let mut control = JitterEntry::new(
            "control",
            None,
            &m.control_period_jitter,
            &m.sensor_to_control,
            m.e2e_misses,
            budget,
        );
        control.missed_periods = m.control_period_misses;
        let mut sensor = JitterEntry::new(
            "sensor",
            None,
            &m.sensor_period_jitter,
            &m.sensor_to_ingest,
            0,
            None,
        );
        sensor.missed_periods = 0;
        paths.push(control.with_ratios(&baseline));
        paths.push(sensor.with_ratios(&baseline));
        shm_left = m.shm_left;
        if m.stopped {
            warnings.push("stopped early: the pipeline figures cover the time measured".into());
        }
        info = Some(PipelineInfo {
            config: pipe
                .as_ref()
                .map(|p| p.0.config.display().to_string())
                .unwrap_or_default(),
            sets: pipe.as_ref().map(|p| p.0.sets.clone()).unwrap_or_default(),
            sensor_rate_hz: m.sensor_rate_hz,
            controls: m.controls,
            stages: m.stages.iter().cloned().collect(),
            hops: m.report_hops.clone(),
            accuracy: m.report_accuracy.clone(),
            host: m.report_host.clone(),
        });
    }
    let thresholds = probe::thresholds(info.as_ref().map(|p: &PipelineInfo| &p.stages));
    let report = JitterReport {
        date,
        rate_hz: cfg.rate_hz,
        duration_s: cfg.duration.as_secs_f64(),
        stress_cpu_threads: a.stress,
        stress_mem_threads: a.stress,
        baseline,
        cores: per_core,
        paths,
        pipeline: info,
        load,
        shm_left,
        baseline_host,
        host_stalls: probe::rows(&stalls, &thresholds),
        host_stall_grid: probe::grid(&stalls),
        warnings,
    };
    print!("{}", report.render());
    if let Some(path) = &a.json {
        write_json(path, &report)?;
    }
    if let Some(path) = &a.plot {
        let wake_all = merged(cores.iter().map(|c| &c.wake));
        let jit_all = merged(cores.iter().map(|c| &c.period_jitter));
        let mut rows: Vec<Row> = cores
            .iter()
            .map(|c| Row {
                title: format!(
                    "timer core {} ({} Hz{})",
                    c.core,
                    cfg.rate_hz,
                    if c.fifo { ", SCHED_FIFO" } else { "" }
                ),
                series: vec![
                    Series {
                        label: "wake-up latency".into(),
                        hist: &c.wake,
                    },
                    Series {
                        label: "period jitter".into(),
                        hist: &c.period_jitter,
                    },
                ],
            })
            .collect();
        if let Some(m) = &measured {
            rows.push(Row {
                title: "period jitter: pipeline outputs vs timer".into(),
                series: vec![
                    Series {
                        label: "control".into(),
                        hist: &m.control_period_jitter,
                    },
                    Series {
                        label: "sensor (plant)".into(),
                        hist: &m.sensor_period_jitter,
                    },
                    Series {
                        label: "timer".into(),
                        hist: &jit_all,
                    },
                ],
            });
            rows.push(Row {
                title: "latency: sensor->control vs timer wake-up".into(),
                series: vec![
                    Series {
                        label: "sensor->control".into(),
                        hist: &m.sensor_to_control,
                    },
                    Series {
                        label: "timer wake-up".into(),
                        hist: &wake_all,
                    },
                ],
            });
        }
        write_svg(path, &format!("beliefbus jitter, {}", report.date), &rows)?;
        eprintln!("wrote {}", path.display());
    }
    if let Some(dir) = &a.hdr {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        for c in &cores {
            for (what, log) in [("wake", &c.wake_log), ("period-jitter", &c.jitter_log)] {
                if let Some(log) = log {
                    let f = dir.join(format!("timer-core{}.{what}.hlog", c.core));
                    log.save(&f)
                        .with_context(|| format!("writing {}", f.display()))?;
                }
            }
        }
        if let Some(m) = &measured {
            let start = std::time::SystemTime::now();
            for (name, h) in [
                ("control.period-jitter", &m.control_period_jitter),
                ("control.sensor-control", &m.sensor_to_control),
                ("sensor.period-jitter", &m.sensor_period_jitter),
            ] {
                // One interval: the pipeline's whole measured window.
                let mut log = HdrLog::new(start, &[format!("beliefbus jitter: pipeline {name}")])?;
                log.add(h, Duration::ZERO, Duration::from_secs_f64(a.duration))?;
                let f = dir.join(format!("{name}.hlog"));
                log.save(&f)
                    .with_context(|| format!("writing {}", f.display()))?;
            }
        }
        eprintln!("wrote HdrHistogram logs to {}", dir.display());
    }
    if shm_left > 0 {
        anyhow::bail!("{shm_left} shared-memory files of the pipeline run could not be removed");
    }
    Ok(())
}

/// `beliefbus latency-pong ...` (hidden; started by `latency`).
pub fn pong(a: PongArgs) -> Result<()> {
    let stop = crate::ipc::install_stop_handler();
    let paths = PathKind::parse_list(&a.paths)?;
    let cfg = PongConfig {
        prefix: a.prefix,
        mode: a.mode,
        spin: Duration::from_micros(a.spin_us),
        paths,
        core: a.core,
        fifo: a.fifo,
    };
    serve(&cfg, stop)?;
    Ok(())
}
