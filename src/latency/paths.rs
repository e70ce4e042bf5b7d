//! What a latency run measures: the paths (one per message type and chain
//! slice size), the wake-up mode, and the interleaved schedule both
//! processes follow.

use super::LatencyError;
use crate::ipc::{Belief, Control, Observation};
use serde::{Deserialize, Serialize};
use std::fmt;

/// How the receiving side of each hop waits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Block until notified (iceoryx2 event; beliefbus's default).
    Event,
    /// Busy-poll the subscriber (no notification is sent).
    Spin,
    /// Poll for a bounded time, then block until notified.
    Hybrid,
}

impl Mode {
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Mode::Event => "event",
            Mode::Spin => "spin",
            Mode::Hybrid => "hybrid",
        }
    }

    /// Parse a lower-case name.
    pub fn parse(s: &str) -> Option<Mode> {
        [Mode::Event, Mode::Spin, Mode::Hybrid]
            .into_iter()
            .find(|m| m.name() == s)
    }

    /// Whether publishers notify and subscribers have listeners.
    pub fn notifies(self) -> bool {
        self != Mode::Spin
    }
}

/// One measured path: a message type, or a chain slice of a given size.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PathKind {
    Observation,
    Belief,
    Control,
    /// A slice of `bytes / 8` f64 values, written and read in place.
    Chain {
        bytes: usize,
    },
}

/// Chain slice sizes of `--payload all`: 64 B (the zero-copy reference)
/// and 4 KiB … 16 MiB.
pub const CHAIN_SIZES: [usize; 5] = [64, 4 << 10, 64 << 10, 1 << 20, 16 << 20];

/// Largest chain slice accepted (the data segments hold a few of them).
pub const MAX_CHAIN_BYTES: usize = 64 << 20;

fn human_bytes(b: usize) -> String {
    if b >= 1 << 20 && b.is_multiple_of(1 << 20) {
        format!("{}MiB", b >> 20)
    } else if b >= 1 << 10 && b.is_multiple_of(1 << 10) {
        format!("{}KiB", b >> 10)
    } else {
        format!("{b}B")
    }
}

/// Parse `4096`, `4K`, `4KiB`, `16M`, `16MiB`, `64B`.
fn parse_bytes(s: &str) -> Option<usize> {
    let s = s.trim();
    let split = s.find(|c: char| !c.is_ascii_digit()).unwrap_or(s.len());
    let (num, unit) = s.split_at(split);
    let n: usize = num.parse().ok()?;
    let mult = match unit.to_ascii_lowercase().as_str() {
        "" | "b" => 1,
        "k" | "kib" | "kb" => 1 << 10,
        "m" | "mib" | "mb" => 1 << 20,
        _ => return None,
    };
    n.checked_mul(mult)
}

impl PathKind {
    /// Every path of `--payload all`.
    pub fn all() -> Vec<PathKind> {
        let mut v = vec![PathKind::Observation, PathKind::Belief, PathKind::Control];
        v.extend(CHAIN_SIZES.iter().map(|&bytes| PathKind::Chain { bytes }));
        v
    }

    /// Report name: `observation`, `belief`, `control`, `chain-4KiB`, ...
    pub fn name(&self) -> String {
        match self {
            PathKind::Observation => "observation".into(),
            PathKind::Belief => "belief".into(),
            PathKind::Control => "control".into(),
            PathKind::Chain { bytes } => format!("chain-{}", human_bytes(*bytes)),
        }
    }

    /// Payload size in bytes.
    pub fn payload_bytes(&self) -> usize {
        match self {
            PathKind::Observation => std::mem::size_of::<Observation>(),
            PathKind::Belief => std::mem::size_of::<Belief>(),
            PathKind::Control => std::mem::size_of::<Control>(),
            PathKind::Chain { bytes } => *bytes,
        }
    }

    /// Whether this is a fixed-size message (the p50 ratio targets apply).
    pub fn is_fixed(&self) -> bool {
        !matches!(self, PathKind::Chain { .. })
    }

    /// Parse one item: a message name, a report name (`chain-4KiB`), or a
    /// chain slice size (`4096`, `4K`, `16MiB`; a multiple of 8 bytes).
    pub fn parse(item: &str) -> Result<PathKind, LatencyError> {
        let item = item.trim();
        match item {
            "observation" | "obs" => return Ok(PathKind::Observation),
            "belief" => return Ok(PathKind::Belief),
            "control" => return Ok(PathKind::Control),
            _ => {}
        }
        let size = item.strip_prefix("chain-").unwrap_or(item);
        let bytes = parse_bytes(size).ok_or_else(|| {
            LatencyError::BadArg(format!(
                "--payload: '{item}' is neither a message (observation, belief, control) nor a byte size"
            ))
        })?;
        if bytes == 0 || !bytes.is_multiple_of(8) || bytes > MAX_CHAIN_BYTES {
            return Err(LatencyError::BadArg(format!(
                "--payload: {bytes} bytes: a chain slice must be a positive multiple of 8 bytes up to {}",
                human_bytes(MAX_CHAIN_BYTES)
            )));
        }
        Ok(PathKind::Chain { bytes })
    }

    /// Parse `all` or a comma-separated list of items (duplicates dropped,
    /// order kept).
    pub fn parse_list(s: &str) -> Result<Vec<PathKind>, LatencyError> {
        if s.trim() == "all" {
            return Ok(Self::all());
        }
        let mut out: Vec<PathKind> = Vec::new();
        for item in s.split(',').filter(|i| !i.trim().is_empty()) {
            let k = Self::parse(item)?;
            if !out.contains(&k) {
                out.push(k);
            }
        }
        if out.is_empty() {
            return Err(LatencyError::BadArg("--payload: no path given".into()));
        }
        Ok(out)
    }
}

impl fmt::Display for PathKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name())
    }
}

/// Which implementation a slot measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Impl {
    /// beliefbus's own ports (`crate::ipc`).
    Ours,
    /// Minimal iceoryx2 code (the baseline).
    Bare,
}

/// Slot `k` of the schedule over `n_paths` paths: path `(k / 2) % n`, and
/// ours/bare alternate which goes first from one round to the next, so
/// neither always follows the other.
pub fn slot(k: usize, n_paths: usize) -> (usize, Impl) {
    let per_round = 2 * n_paths.max(1);
    let round = k / per_round;
    let i = k % per_round;
    let path = i / 2;
    let first = if round.is_multiple_of(2) {
        Impl::Ours
    } else {
        Impl::Bare
    };
    let which = match (i % 2, first) {
        (0, f) => f,
        (_, Impl::Ours) => Impl::Bare,
        (_, Impl::Bare) => Impl::Ours,
    };
    (path, which)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn payload_lists_parse_names_and_sizes() {
        assert_eq!(PathKind::parse_list("all").unwrap().len(), 8);
        let v = PathKind::parse_list("control, 4K,16MiB,chain-64B,4096").unwrap();
        assert_eq!(
            v,
            vec![
                PathKind::Control,
                PathKind::Chain { bytes: 4096 },
                PathKind::Chain { bytes: 16 << 20 },
                PathKind::Chain { bytes: 64 },
            ]
        );
        for bad in ["", "12", "0", "4X", "128M", "particles"] {
            assert!(PathKind::parse_list(bad).is_err(), "{bad}");
        }
        // Names round-trip (the pong process receives them).
        for k in PathKind::all() {
            assert_eq!(PathKind::parse(&k.name()).unwrap(), k);
        }
        assert_eq!(PathKind::Chain { bytes: 16 << 20 }.name(), "chain-16MiB");
        assert_eq!(PathKind::Chain { bytes: 64 }.payload_bytes(), 64);
    }

    #[test]
    fn the_schedule_visits_every_slot_once_per_round_and_alternates_order() {
        let n = 3;
        for round in 0..4 {
            let mut seen = Vec::new();
            for i in 0..2 * n {
                seen.push(slot(round * 2 * n + i, n));
            }
            for p in 0..n {
                assert!(seen.contains(&(p, Impl::Ours)));
                assert!(seen.contains(&(p, Impl::Bare)));
            }
            let first = if round % 2 == 0 {
                Impl::Ours
            } else {
                Impl::Bare
            };
            assert_eq!(seen[0], (0, first));
        }
    }
}
