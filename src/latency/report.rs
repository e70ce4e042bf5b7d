//! The latency report: JSON (`{"paths": [...], "run": {...}}`) and the
//! console table.

use super::load::LoadReport;
use super::stats::{ratios, PctBlock};
use serde::{Deserialize, Serialize};

/// One path: ours and bare one-way latency, and their ratios per quantile.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PathReport {
    pub name: String,
    pub mode: String,
    pub payload_bytes: usize,
    pub ours: PctBlock,
    pub bare: PctBlock,
    /// ours / bare at p50 (null when undefined).
    pub ratio_p50: Option<f64>,
    pub ratio_p90: Option<f64>,
    pub ratio_p99: Option<f64>,
    pub ratio_p999: Option<f64>,
    pub ratio_max: Option<f64>,
}

impl PathReport {
    /// A path's row from its two blocks.
    pub fn new(
        name: &str,
        mode: &str,
        payload_bytes: usize,
        ours: PctBlock,
        bare: PctBlock,
    ) -> Self {
        let r = ratios(&ours, &bare);
        Self {
            name: name.to_string(),
            mode: mode.to_string(),
            payload_bytes,
            ours,
            bare,
            ratio_p50: r[0],
            ratio_p90: r[1],
            ratio_p99: r[2],
            ratio_p999: r[3],
            ratio_max: r[4],
        }
    }
}

/// How the run was made.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunInfo {
    /// UTC date and time of the start, ISO 8601.
    pub date: String,
    pub mode: String,
    /// Measured time (slots × slot length).
    pub duration_s: f64,
    pub slot_ms: f64,
    pub rounds: usize,
    /// Cores of the ping and the pong process (null: not pinned).
    pub cores: Option<[usize; 2]>,
    /// SCHED_FIFO priority in effect (null: SCHED_OTHER).
    pub fifo_priority: Option<u8>,
    /// Spin time of hybrid mode, µs.
    pub spin_us: f64,
    /// Round trips dropped at the start of every slot.
    pub slot_warmup: u64,
    pub load: LoadReport,
    /// Shared-memory files of the run left after cleanup (should be 0).
    pub shm_left: usize,
    /// Warnings (refused priorities, pinning, ...).
    pub warnings: Vec<String>,
}

/// The whole report.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LatencyReport {
    pub paths: Vec<PathReport>,
    pub run: RunInfo,
}

fn fmt_ratio(r: Option<f64>) -> String {
    r.map(|x| format!("{x:.2}")).unwrap_or_else(|| "-".into())
}

fn fmt_us(x: f64) -> String {
    if x >= 100.0 {
        format!("{x:.0}")
    } else if x >= 10.0 {
        format!("{x:.1}")
    } else {
        format!("{x:.2}")
    }
}

impl LatencyReport {
    /// The console table: per path ours, bare and ours/bare.
    pub fn render(&self) -> String {
        let mut s = format!(
            "one-way latency (round trip / 2), mode {}, {:.1} s measured, µs\n",
            self.run.mode, self.run.duration_s
        );
        s += &format!(
            "{:<13} {:>9} {:<6} {:>9} {:>8} {:>8} {:>8} {:>8} {:>8}\n",
            "path", "bytes", "impl", "count", "p50", "p90", "p99", "p99.9", "max"
        );
        for p in &self.paths {
            for (label, b) in [("ours", &p.ours), ("bare", &p.bare)] {
                let name = if label == "ours" { p.name.as_str() } else { "" };
                let bytes = if label == "ours" {
                    p.payload_bytes.to_string()
                } else {
                    String::new()
                };
                s += &format!(
                    "{:<13} {:>9} {:<6} {:>9} {:>8} {:>8} {:>8} {:>8} {:>8}\n",
                    name,
                    bytes,
                    label,
                    b.count,
                    fmt_us(b.p50_us),
                    fmt_us(b.p90_us),
                    fmt_us(b.p99_us),
                    fmt_us(b.p999_us),
                    fmt_us(b.max_us)
                );
            }
            s += &format!(
                "{:<13} {:>9} {:<6} {:>9} {:>8} {:>8} {:>8} {:>8} {:>8}\n",
                "",
                "",
                "ratio",
                "",
                fmt_ratio(p.ratio_p50),
                fmt_ratio(p.ratio_p90),
                fmt_ratio(p.ratio_p99),
                fmt_ratio(p.ratio_p999),
                fmt_ratio(p.ratio_max)
            );
        }
        let find = |n: &str| self.paths.iter().find(|p| p.name == n);
        if let (Some(small), Some(big)) = (find("chain-64B"), find("chain-16MiB")) {
            s += &format!(
                "zero copy: chain-16MiB / chain-64B one-way p50, ours {}, bare {}\n",
                fmt_ratio(super::stats::ratio(big.ours.p50_us, small.ours.p50_us)),
                fmt_ratio(super::stats::ratio(big.bare.p50_us, small.bare.p50_us)),
            );
        }
        s += &self.run.load.line();
        s.push('\n');
        for w in &self.run.warnings {
            s += &format!("warning: {w}\n");
        }
        s
    }
}

/// `t` (seconds since the Unix epoch) as `YYYY-MM-DDTHH:MM:SSZ`.
pub fn iso8601_utc(t: u64) -> String {
    let days = (t / 86_400) as i64;
    let rem = t % 86_400;
    // Civil from days (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1_460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + (m <= 2) as i64;
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        rem / 3_600,
        rem % 3_600 / 60,
        rem % 60
    )
}

/// Now as `YYYY-MM-DDTHH:MM:SSZ`.
pub fn now_iso8601() -> String {
    let t = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    iso8601_utc(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_format_in_utc() {
        assert_eq!(iso8601_utc(0), "1970-01-01T00:00:00Z");
        assert_eq!(iso8601_utc(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(iso8601_utc(1_700_000_000), "2023-11-14T22:13:20Z");
    }

    #[test]
    fn rows_carry_consistent_ratios() {
        let ours = PctBlock {
            count: 5,
            p50_us: 3.0,
            p90_us: 4.0,
            p99_us: 6.0,
            p999_us: 9.0,
            max_us: 12.0,
        };
        let bare = PctBlock {
            count: 7,
            p50_us: 2.0,
            p90_us: 4.0,
            p99_us: 5.0,
            p999_us: 6.0,
            max_us: 24.0,
        };
        let p = PathReport::new("control", "event", 320, ours, bare);
        assert_eq!(p.ratio_p50, Some(1.5));
        assert_eq!(p.ratio_p90, Some(1.0));
        assert_eq!(p.ratio_p99, Some(1.2));
        assert_eq!(p.ratio_p999, Some(1.5));
        assert_eq!(p.ratio_max, Some(0.5));
        let v = serde_json::to_value(&p).unwrap();
        assert_eq!(v["ours"]["p50_us"], 3.0);
        assert_eq!(v["bare"]["count"], 7);
        assert_eq!(v["ratio_p99"], 1.2);
        let none = PathReport::new("x", "spin", 8, ours, PctBlock::default());
        assert!(serde_json::to_value(&none).unwrap()["ratio_p50"].is_null());
    }
}
