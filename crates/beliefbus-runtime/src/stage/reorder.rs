//! Multi-sensor merging for ingest: accepted observations of several
//! channels are released in measurement-time order through a bounded
//! reorder window, and rejections are logged at a bounded rate.
//!
//! **Merge rule** (a watermark merge with a timeout). Every channel's
//! measurement times never decrease (ingest rejects a sample that goes
//! back), so once channel c has delivered a sample measured at `w_c`, no
//! later sample of c can be measured before `w_c`. The earliest pending
//! observation h (measured at `t_h`, arrived at `a_h`) is released when
//!
//! ```text
//! every other active channel c has w_c ≥ t_h     (nothing earlier can come)
//! or now ≥ a_h + W                               (bounded extra latency W)
//! or the buffer is full                          (bounded memory)
//! ```
//!
//! A channel is *active* once it has delivered a sample and until it has
//! been silent for `inactive_ns` (a dead sensor stops holding the others
//! back). With one channel, or channels that arrive in order, observations
//! leave at once; only genuinely interleaved channels pay up to W. A sample
//! measured before the last released observation arrives too late for the
//! filter (which cannot go back in time) and is rejected by [`ReorderBuffer::push`].

use crate::ipc::Observation;

/// A sample measured before the last released observation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Late {
    /// Its measurement time.
    pub t_ns: u64,
    /// The last released measurement time.
    pub released_ns: u64,
}

#[derive(Clone, Copy, Debug)]
struct Watermark {
    channel: u32,
    /// Latest measurement time delivered (0: never).
    t_ns: u64,
    /// Arrival of that sample.
    arrived_ns: u64,
}

#[derive(Clone, Copy, Debug)]
struct Pending {
    t_ns: u64,
    deadline_ns: u64,
    obs: Observation,
}

/// Observations waiting to be released in measurement-time order.
/// Allocation-free after construction.
#[derive(Debug)]
pub struct ReorderBuffer {
    /// Sorted by measurement time (stable: equal times keep arrival order).
    pending: Vec<Pending>,
    cap: usize,
    window_ns: u64,
    inactive_ns: u64,
    marks: Vec<Watermark>,
    released_ns: u64,
}

impl ReorderBuffer {
    /// A buffer for `channels`, holding at most `cap` (≥ 1) observations
    /// for at most `window_ns` each; a channel silent for `inactive_ns`
    /// stops holding the others back.
    pub fn new(channels: &[u32], cap: usize, window_ns: u64, inactive_ns: u64) -> Self {
        let cap = cap.max(1);
        Self {
            pending: Vec::with_capacity(cap + 1),
            cap,
            window_ns,
            inactive_ns,
            marks: channels
                .iter()
                .map(|&channel| Watermark {
                    channel,
                    t_ns: 0,
                    arrived_ns: 0,
                })
                .collect(),
            released_ns: 0,
        }
    }

    /// Observations waiting.
    pub fn len(&self) -> usize {
        self.pending.len()
    }

    /// Whether nothing is waiting.
    pub fn is_empty(&self) -> bool {
        self.pending.is_empty()
    }

    /// The last released measurement time (0: none yet).
    pub fn released_ns(&self) -> u64 {
        self.released_ns
    }

    /// Add an accepted observation (measured at `obs.header.t_valid_ns` on
    /// `obs.channel`) that arrived at `now_ns`. Call [`Self::pop_ready`]
    /// until it returns `None` after every push.
    pub fn push(&mut self, obs: &Observation, now_ns: u64) -> Result<(), Late> {
        let t = obs.header.t_valid_ns;
        if t < self.released_ns {
            return Err(Late {
                t_ns: t,
                released_ns: self.released_ns,
            });
        }
        if let Some(m) = self.marks.iter_mut().find(|m| m.channel == obs.channel) {
            m.t_ns = m.t_ns.max(t);
            m.arrived_ns = now_ns;
        }
        let at = self.pending.partition_point(|p| p.t_ns <= t);
        self.pending.insert(
            at,
            Pending {
                t_ns: t,
                deadline_ns: now_ns.saturating_add(self.window_ns),
                obs: *obs,
            },
        );
        Ok(())
    }

    /// Whether no active channel other than `channel` could still deliver
    /// a sample measured before `t_ns`.
    fn covered(&self, channel: u32, t_ns: u64, now_ns: u64) -> bool {
        self.marks.iter().all(|m| {
            m.channel == channel
                || m.t_ns == 0
                || now_ns.saturating_sub(m.arrived_ns) > self.inactive_ns
                || m.t_ns >= t_ns
        })
    }

    /// The next observation to forward, if one is ready at `now_ns`.
    pub fn pop_ready(&mut self, now_ns: u64) -> Option<Observation> {
        let head = self.pending.first()?;
        let ready = self.pending.len() > self.cap
            || now_ns >= head.deadline_ns
            || self.covered(head.obs.channel, head.t_ns, now_ns);
        if !ready {
            return None;
        }
        let p = self.pending.remove(0);
        self.released_ns = p.t_ns;
        Some(p.obs)
    }

    /// When the head becomes ready by timeout (None when empty).
    pub fn next_deadline(&self) -> Option<u64> {
        self.pending.first().map(|p| p.deadline_ns)
    }
}

/// Log lines about rejections, at most one per reason per period; the
/// rejections in between are counted and reported with the next line.
#[derive(Clone, Debug)]
pub struct RejectLog {
    period_ns: u64,
    last_ns: Vec<Option<u64>>,
    suppressed: Vec<u64>,
}

impl RejectLog {
    /// A log for `reasons` reasons with one line per `period_ns` each.
    pub fn new(reasons: usize, period_ns: u64) -> Self {
        Self {
            period_ns,
            last_ns: vec![None; reasons],
            suppressed: vec![0; reasons],
        }
    }

    /// Note a rejection for `reason` at `now_ns`. Returns the number of
    /// rejections of that reason not logged since its last line when a line
    /// is due now (the caller then writes it), else `None`.
    pub fn note(&mut self, reason: usize, now_ns: u64) -> Option<u64> {
        let r = reason.min(self.last_ns.len().saturating_sub(1));
        let due = self.last_ns[r].is_none_or(|t| now_ns >= t.saturating_add(self.period_ns));
        if due {
            self.last_ns[r] = Some(now_ns);
            Some(std::mem::take(&mut self.suppressed[r]))
        } else {
            self.suppressed[r] += 1;
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn obs(channel: u32, t: u64) -> Observation {
        let mut o = Observation {
            channel,
            ..Observation::default()
        };
        o.header.t_valid_ns = t;
        o
    }

    fn drain(b: &mut ReorderBuffer, now: u64) -> Vec<(u32, u64)> {
        let mut out = Vec::new();
        while let Some(o) = b.pop_ready(now) {
            out.push((o.channel, o.header.t_valid_ns));
        }
        out
    }

    #[test]
    fn one_channel_passes_straight_through() {
        let mut b = ReorderBuffer::new(&[0], 16, 10 * MS, 500 * MS);
        for k in 1..5u64 {
            b.push(&obs(0, k * MS), k * MS + 1).unwrap();
            assert_eq!(drain(&mut b, k * MS + 1), vec![(0, k * MS)]);
        }
    }

    #[test]
    fn interleaved_channels_leave_in_measurement_order() {
        let mut b = ReorderBuffer::new(&[1, 2], 16, 50 * MS, 500 * MS);
        // Channel 1 has spoken at t = 0; channel 2 not yet (inactive).
        b.push(&obs(1, 10 * MS), 11 * MS).unwrap();
        assert_eq!(drain(&mut b, 11 * MS), vec![(1, 10 * MS)]);
        b.push(&obs(2, 12 * MS), 13 * MS).unwrap();
        assert_eq!(drain(&mut b, 13 * MS), vec![], "waits for channel 1");
        // Channel 1 at 20 ms arrives first, channel 2 at 15 ms later.
        b.push(&obs(1, 20 * MS), 21 * MS).unwrap();
        assert_eq!(drain(&mut b, 21 * MS), vec![(2, 12 * MS)]);
        b.push(&obs(2, 15 * MS), 22 * MS).unwrap();
        assert_eq!(drain(&mut b, 22 * MS), vec![(2, 15 * MS)]);
        b.push(&obs(2, 25 * MS), 26 * MS).unwrap();
        assert_eq!(drain(&mut b, 26 * MS), vec![(1, 20 * MS)]);
        assert_eq!(b.len(), 1);
    }

    #[test]
    fn the_window_bounds_the_wait_and_late_samples_are_refused() {
        let mut b = ReorderBuffer::new(&[1, 2], 16, 5 * MS, 500 * MS);
        b.push(&obs(2, MS), MS).unwrap();
        drain(&mut b, MS);
        b.push(&obs(1, 10 * MS), 10 * MS).unwrap();
        // Channel 2 (last at 1 ms) holds it back until the window expires.
        assert_eq!(drain(&mut b, 14 * MS), vec![]);
        assert_eq!(b.next_deadline(), Some(15 * MS));
        assert_eq!(drain(&mut b, 15 * MS), vec![(1, 10 * MS)]);
        // Channel 2's sample measured at 8 ms comes too late.
        assert_eq!(
            b.push(&obs(2, 8 * MS), 16 * MS),
            Err(Late {
                t_ns: 8 * MS,
                released_ns: 10 * MS
            })
        );
        // Equal times are not late.
        b.push(&obs(2, 10 * MS), 16 * MS).unwrap();
        assert_eq!(drain(&mut b, 16 * MS), vec![(2, 10 * MS)]);
    }

    #[test]
    fn a_silent_channel_stops_holding_the_others_back() {
        let mut b = ReorderBuffer::new(&[1, 2], 16, 100 * MS, 50 * MS);
        b.push(&obs(2, MS), MS).unwrap();
        drain(&mut b, MS);
        b.push(&obs(1, 40 * MS), 40 * MS).unwrap();
        assert_eq!(drain(&mut b, 40 * MS), vec![], "channel 2 still active");
        b.push(&obs(1, 60 * MS), 60 * MS).unwrap();
        // 59 ms of silence > 50 ms: channel 2 is inactive.
        assert_eq!(drain(&mut b, 60 * MS), vec![(1, 40 * MS), (1, 60 * MS)]);
    }

    #[test]
    fn a_full_buffer_releases_the_oldest() {
        let mut b = ReorderBuffer::new(&[1, 2], 3, 1_000 * MS, 1_000 * MS);
        b.push(&obs(2, MS), MS).unwrap();
        drain(&mut b, MS);
        for k in 0..3u64 {
            b.push(&obs(1, (10 + k) * MS), 10 * MS).unwrap();
            assert_eq!(drain(&mut b, 10 * MS), vec![]);
        }
        b.push(&obs(1, 13 * MS), 10 * MS).unwrap();
        assert_eq!(drain(&mut b, 10 * MS), vec![(1, 10 * MS)]);
        assert_eq!(b.len(), 3);
    }

    #[test]
    fn equal_times_keep_arrival_order() {
        let mut b = ReorderBuffer::new(&[1, 2], 8, 10 * MS, 500 * MS);
        b.push(&obs(2, 5 * MS), 5 * MS).unwrap();
        b.push(&obs(1, 5 * MS), 5 * MS).unwrap();
        assert_eq!(drain(&mut b, 5 * MS), vec![(2, 5 * MS), (1, 5 * MS)]);
    }

    #[test]
    fn the_reject_log_writes_at_most_one_line_per_reason_and_period() {
        let mut log = RejectLog::new(3, 1_000 * MS);
        assert_eq!(log.note(1, 0), Some(0));
        for k in 1..100u64 {
            assert_eq!(log.note(1, k * MS), None);
        }
        // Another reason has its own budget.
        assert_eq!(log.note(2, 50 * MS), Some(0));
        assert_eq!(log.note(1, 1_000 * MS), Some(99), "suppressed ones counted");
        assert_eq!(log.note(1, 1_001 * MS), None);
        // Out-of-range reasons share the last slot instead of panicking.
        assert_eq!(log.note(17, 60 * MS), None, "slot 2 logged at 50 ms");
        assert_eq!(log.note(17, 2_000 * MS), Some(1));
    }
}
