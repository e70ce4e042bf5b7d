//! Each stage loop driven in one process: the stage runs on a thread with
//! its own bus on a private prefix; the test publishes its inputs and reads
//! its outputs through the real shared-memory ports.

use super::*;
use crate::config::load;
use crate::ipc::cleanup;
use crate::ipc::{Belief, Control, Message, Observation, SensorSample, Truth};
use crate::rt::{MonotonicClock, SimClock};
use crate::scenario::Plant;
use std::path::Path;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// `configs/default.toml` on a fresh prefix, with `sets` applied.
fn test_config(sets: &[&str]) -> PipelineConfig {
    let mut all = vec![format!("run.prefix=\"{}\"", cleanup::run_prefix())];
    all.extend(sets.iter().map(|s| s.to_string()));
    load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/default.toml"),
        &all,
    )
    .unwrap()
}

/// Removes the prefix's resources at the end of a test, even on failure.
struct Cleanup(String);
impl Drop for Cleanup {
    fn drop(&mut self) {
        let _ = cleanup::remove_prefix(&self.0);
    }
}

fn spawn(
    kind: StageKind,
    cfg: &PipelineConfig,
    stop: &Arc<AtomicBool>,
) -> JoinHandle<Result<StageStats, StageError>> {
    let cfg = cfg.clone();
    let stop = stop.clone();
    std::thread::spawn(move || {
        run_stage(
            &cfg.bus(),
            &cfg,
            StageIdentity::plain(kind),
            &MonotonicClock,
            &stop,
        )
    })
}

/// Wait until `n` stages have published their first report.
fn wait_ready(stats: &crate::ipc::Subscriber<StageStats>, n: usize) {
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut seen = std::collections::HashSet::new();
    while seen.len() < n {
        assert!(Instant::now() < deadline, "stages did not come up");
        while let Some(s) = stats.receive().unwrap() {
            seen.insert(s.stage);
        }
        std::thread::sleep(Duration::from_millis(2));
    }
}

fn poll_until<T>(timeout: Duration, mut f: impl FnMut() -> Option<T>) -> T {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(Instant::now() < deadline, "timed out");
        std::thread::sleep(Duration::from_micros(200));
    }
}

fn sample(channel: u32, seq: u64, t: u64, v: &[f64]) -> SensorSample {
    let mut s = SensorSample::new(channel, seq, t, v);
    s.t_pub_ns = t;
    s
}

mod filter_stage;
mod ingest_stage;
mod loops;
