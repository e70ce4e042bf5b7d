//! `beliefbus plant`: the simulated plant on its own, as one external sensor
//! publisher of a pipeline started with `beliefbus run --sensor external`
//! (or stages started by hand). It joins the instance under the config's
//! `run.prefix`, waits until the pipeline's ingest subscribes, then runs the
//! plant loop ([`crate::stage::plant`]: the true SDE with the pipeline's
//! controls as a zero-order hold, sensor samples at `plant.sensor_rate_hz`,
//! truth for the accuracy figures) for the duration or until Ctrl-C. Its
//! statistics reach the launcher like those of the built-in plant.

use super::config;
use crate::ipc::sensor_api::SensorPublisher;
use crate::ipc::{self, Bus, StageKind};
use crate::rt::{Clock, MonotonicClock};
use crate::stage::plant::{self, PlantPorts};
use crate::stage::StageIdentity;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// Options of `beliefbus plant`.
#[derive(Clone, Debug, Default)]
pub struct PlantOptions {
    pub config: config::ConfigSource,
    /// The scenarios to resolve it in (`None`: the built-in ones).
    pub registry: Option<crate::scenario::Registry>,
    /// Seconds to run (default `run.duration_s`; 0 = until Ctrl-C).
    pub duration_s: Option<f64>,
    pub sets: Vec<String>,
    /// Overrides `run.prefix`.
    pub prefix: Option<String>,
    /// Seconds to wait for the pipeline's ingest (0: do not wait).
    pub wait_ingest_s: f64,
}

/// What a `beliefbus plant` run did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PlantSummary {
    pub samples: u64,
    pub controls_received: u64,
}

/// Why `beliefbus plant` failed.
#[derive(Debug, thiserror::Error)]
pub enum PlantError {
    /// Bad config or options: exit 2.
    #[error(transparent)]
    Config(#[from] config::ConfigError),
    /// No ingest subscribed in time, or an iceoryx2 failure: exit 1.
    #[error("{0}")]
    Runtime(String),
}

/// Run the plant as an external publisher until done or `stop`.
pub fn run_plant(opts: &PlantOptions, stop: &AtomicBool) -> Result<PlantSummary, PlantError> {
    let mut sets = opts.sets.clone();
    if let Some(p) = &opts.prefix {
        sets.push(format!("run.prefix=\"{p}\""));
    }
    let registry = opts
        .registry
        .clone()
        .unwrap_or_else(crate::scenario::Registry::builtin);
    let cfg = opts.config.load(&registry, &sets)?;
    let duration = opts.duration_s.unwrap_or(cfg.run.duration_s);
    if !(duration.is_finite() && duration >= 0.0) {
        return Err(config::ConfigError {
            key: "--duration".into(),
            problem: format!("must be >= 0 seconds, got {duration}"),
        }
        .into());
    }
    let rt = |e: String| PlantError::Runtime(e);
    let bus_cfg = cfg.bus();
    let service = ipc::service_name(&cfg.run.instance, "sensor");
    if opts.wait_ingest_s > 0.0 {
        eprintln!(
            "plant: waiting for the pipeline's ingest on {service} (prefix {})",
            bus_cfg.prefix
        );
        let probe = SensorPublisher::connect_with(&bus_cfg, "plant-probe")
            .map_err(|e| rt(e.to_string()))?;
        let until = Instant::now() + Duration::from_secs_f64(opts.wait_ingest_s);
        while !probe.wait_for_subscribers(1, Duration::from_millis(100)) {
            if stop.load(Ordering::Relaxed) {
                return Ok(PlantSummary {
                    samples: 0,
                    controls_received: 0,
                });
            }
            if Instant::now() >= until {
                return Err(rt(format!(
                    "no ingest subscribed to {service} under prefix {} within {} s \
                     (start `beliefbus run CONFIG --sensor external` with the same config)",
                    bus_cfg.prefix, opts.wait_ingest_s
                )));
            }
        }
    }
    let bus = Bus::open(&bus_cfg, "plant").map_err(|e| rt(e.to_string()))?;
    let id = StageIdentity::plain(StageKind::Plant);
    let ports = PlantPorts::open(&bus, id, &cfg).map_err(|e| rt(e.to_string()))?;
    let max_samples =
        (duration > 0.0).then(|| (duration * cfg.plant.sensor_rate_hz).round() as u64);
    eprintln!(
        "plant: publishing {} at {} Hz{}",
        service,
        cfg.plant.sensor_rate_hz,
        match max_samples {
            Some(n) => format!(" ({n} samples)"),
            None => " until Ctrl-C".into(),
        }
    );
    let clock = MonotonicClock;
    let t0 = clock.now_ns();
    let fin =
        plant::run_for(ports, &cfg, &clock, stop, max_samples).map_err(|e| rt(e.to_string()))?;
    let summary = PlantSummary {
        samples: fin.processed,
        controls_received: fin.controls_received,
    };
    eprintln!(
        "plant: {} samples in {:.1} s, {} controls received",
        summary.samples,
        (clock.now_ns() - t0) as f64 * 1e-9,
        summary.controls_received
    );
    Ok(summary)
}

/// Entry of `beliefbus plant`: exit 0 when done, 2 for a bad config, 1 for
/// a runtime failure.
pub fn main(opts: &PlantOptions) -> i32 {
    let stop = ipc::install_stop_handler();
    match run_plant(opts, stop) {
        Ok(s) => {
            println!(
                "{{\"samples\": {}, \"controls_received\": {}}}",
                s.samples, s.controls_received
            );
            0
        }
        Err(PlantError::Config(e)) => {
            eprintln!("beliefbus: {e}");
            2
        }
        Err(PlantError::Runtime(e)) => {
            eprintln!("beliefbus plant: {e}");
            1
        }
    }
}
