//! HdrHistogram interval logs (V2 compressed histograms, the format of
//! HdrHistogram's `HistogramLogWriter`), so runs can be merged and compared
//! with the standard tools (`HistogramLogProcessor`, HdrHistogram log
//! analyzers). Values are nanoseconds; one interval per measured slot.
//!
//! The log text is built in memory while the run goes (each interval is
//! compressed as it is added, a few hundred bytes) and written out at the
//! end, outside the measurement.

use crate::rt::LatencyHist;
use hdrhistogram::serialization::interval_log::{IntervalLogWriterBuilder, IntervalLogWriterError};
use hdrhistogram::serialization::V2DeflateSerializer;
use std::path::Path;
use std::time::{Duration, SystemTime};

/// One interval log under construction.
pub struct HdrLog {
    buf: Vec<u8>,
    ser: V2DeflateSerializer,
    intervals: usize,
}

impl std::fmt::Debug for HdrLog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HdrLog")
            .field("bytes", &self.buf.len())
            .field("intervals", &self.intervals)
            .finish()
    }
}

fn log_err<E: std::fmt::Debug>(e: IntervalLogWriterError<E>) -> std::io::Error {
    std::io::Error::other(format!("{e:?}"))
}

impl HdrLog {
    /// A log whose interval timestamps count from `start` (written as the
    /// log's StartTime and BaseTime), with `comment` lines at the top.
    pub fn new(start: SystemTime, comments: &[String]) -> std::io::Result<Self> {
        let mut log = Self {
            buf: Vec::new(),
            ser: V2DeflateSerializer::new(),
            intervals: 0,
        };
        let mut b = IntervalLogWriterBuilder::new();
        for c in comments {
            b.add_comment(c);
        }
        b.add_comment("values in nanoseconds");
        b.with_start_time(start).with_base_time(start);
        b.begin_log_with(&mut log.buf, &mut log.ser)?;
        Ok(log)
    }

    /// Add the histogram of the interval `[start, start + len)` (times
    /// relative to the log's base time). Empty histograms are skipped.
    pub fn add(&mut self, h: &LatencyHist, start: Duration, len: Duration) -> std::io::Result<()> {
        if h.count() == 0 {
            return Ok(());
        }
        // A builder without headers writes nothing before the interval.
        IntervalLogWriterBuilder::new()
            .begin_log_with(&mut self.buf, &mut self.ser)?
            .write_histogram(h.inner(), start, len, None)
            .map_err(log_err)?;
        self.intervals += 1;
        Ok(())
    }

    /// Intervals written so far.
    pub fn intervals(&self) -> usize {
        self.intervals
    }

    /// The log text.
    pub fn text(&self) -> &[u8] {
        &self.buf
    }

    /// Write the log to `path` (never through a link planted there).
    pub fn save(&self, path: &Path) -> std::io::Result<()> {
        crate::rt::files::replace_file(path, &self.buf)
    }
}

/// A file name made of `[A-Za-z0-9_.-]` from a path name (`sensor->control`
/// becomes `sensor-control`).
pub fn file_stem(name: &str) -> String {
    let mut s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' || c == '.' || c == '-' {
                c
            } else {
                '-'
            }
        })
        .collect();
    while s.contains("--") {
        s = s.replace("--", "-");
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use base64::Engine;
    use hdrhistogram::serialization::interval_log::{IntervalLogIterator, LogEntry};
    use hdrhistogram::serialization::Deserializer;
    use hdrhistogram::Histogram;

    #[test]
    fn a_log_reads_back_with_the_same_counts_and_times() {
        let start = SystemTime::UNIX_EPOCH + Duration::from_secs(1_700_000_000);
        let mut log = HdrLog::new(start, &["path observation, ours".into()]).unwrap();
        let mut h = LatencyHist::new();
        for v in [1_000u64, 2_000, 3_000, 1_000_000] {
            h.record(v);
        }
        log.add(&h, Duration::from_millis(100), Duration::from_millis(50))
            .unwrap();
        log.add(&LatencyHist::new(), Duration::ZERO, Duration::ZERO)
            .unwrap();
        h.reset();
        h.record(5_000);
        log.add(&h, Duration::from_millis(200), Duration::from_millis(50))
            .unwrap();
        assert_eq!(log.intervals(), 2);

        let text = log.text();
        assert!(std::str::from_utf8(text)
            .unwrap()
            .contains("#path observation, ours\n"));
        let mut counts = Vec::new();
        let mut starts = Vec::new();
        let mut saw_start = false;
        for e in IntervalLogIterator::new(text) {
            match e.unwrap() {
                LogEntry::StartTime(t) => {
                    saw_start = true;
                    assert_eq!(t.as_secs(), 1_700_000_000);
                }
                LogEntry::Interval(i) => {
                    starts.push(i.start_timestamp().as_millis());
                    let bytes = base64::engine::general_purpose::STANDARD
                        .decode(i.encoded_histogram())
                        .unwrap();
                    let h: Histogram<u64> = Deserializer::new()
                        .deserialize(&mut std::io::Cursor::new(bytes))
                        .unwrap();
                    counts.push((h.len(), h.max()));
                }
                _ => {}
            }
        }
        assert!(saw_start);
        assert_eq!(starts, vec![100, 200]);
        assert_eq!(counts[0].0, 4);
        assert!((counts[0].1 as f64 - 1e6).abs() / 1e6 < 1e-3);
        assert_eq!(counts[1].0, 1);
    }

    #[test]
    fn file_stems_are_plain() {
        assert_eq!(file_stem("sensor->control"), "sensor-control");
        assert_eq!(file_stem("chain-16MiB"), "chain-16MiB");
    }
}
