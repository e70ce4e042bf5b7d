//! The launcher's bookkeeping of each stage process and the supervision
//! decisions taken from it.
//!
//! A [`Stage`] holds one stage's current process and what the supervisor
//! knows of its history (restarts, the pending restart time, heartbeat
//! misses, chaos kills, counters of earlier incarnations). The decisions —
//! what a death was and what it comes to ([`Stage::decide_death`], with
//! the restart policy and back-off of [`crate::pipeline::supervisor`]),
//! when a restart is due, when a heartbeat is overdue
//! ([`heartbeat_overdue`]), whom to kill when a hung stage cannot die
//! ([`starvers`]), whom chaos may kill ([`chaos_candidates`]), when a
//! recovery is complete ([`Recovery::ms`]) — are pure functions of that
//! state and of the clock values they are given, and are tested here with
//! synthetic exit statuses and instants. The loop that applies them to real
//! processes is [`super::run_loop`].

use crate::ipc::{MissStats, StageKind, StageStats, STATS_DROP_REASONS, STATS_MISSES};
use crate::pipeline::monitor::Output;
use crate::pipeline::supervisor::{Death, Decision, GiveUpReason, RestartPolicy, RestartState};
use crate::rt::sched::RtSettings;
use std::os::unix::process::ExitStatusExt;
use std::process::{Child, ExitStatus};
use std::time::{Duration, Instant};

/// How long the supervisor waits for a SIGKILLed stage to be reaped before
/// it gives up on it (a stage starved of CPU by a runaway SCHED_FIFO stage
/// on its core cannot even die): it never blocks on a child.
pub(super) const KILL_REAP_TIMEOUT: Duration = Duration::from_secs(2);

/// Number of counters carried over from earlier incarnations.
const CARRIED: usize = 12;

/// One stage of the run: its current process and its history.
pub(super) struct Stage {
    pub kind: StageKind,
    pub child: Option<Child>,
    pub pid: u32,
    pub exit: Option<ExitStatus>,
    /// When this incarnation was spawned.
    pub started: Instant,
    pub restart: RestartState,
    /// A restart is due at this time (no process meanwhile).
    pub restart_at: Option<Instant>,
    /// The supervisor killed this incarnation for a missed heartbeat.
    pub hung: bool,
    /// When chaos killed this incarnation (CLOCK_MONOTONIC ns).
    pub chaos_kill_ns: Option<u64>,
    pub heartbeat_misses: u64,
    pub chaos_kills: u64,
    /// Counters of earlier incarnations (processed, dropped, rejected,
    /// deadline misses, late, controls received, processed after warm-up,
    /// collapsed filter updates).
    pub earlier: [u64; CARRIED],
    /// `dropped_by_reason` of earlier incarnations.
    pub earlier_drops: [u64; STATS_DROP_REASONS],
    /// The latest misses of earlier incarnations (oldest first, at most
    /// [`STATS_MISSES`]) and how many of theirs are no longer listed.
    pub earlier_misses: Vec<MissStats>,
    pub earlier_misses_overwritten: u64,
    /// Causes of the deaths of earlier incarnations.
    pub deaths: Vec<String>,
}

/// What a death comes to.
#[derive(Debug, PartialEq)]
pub(super) struct DeathVerdict {
    /// `exit N`, `signal N`, `hang` or `chaos`.
    pub cause: String,
    /// When it died (the chaos kill's time if chaos killed it).
    pub t_death_ns: u64,
    pub decision: Decision,
}

impl Stage {
    /// The bookkeeping of a freshly started first incarnation.
    pub fn started(kind: StageKind, child: Child) -> Self {
        let mut s = Self::without_process(kind, child.id(), Instant::now());
        s.child = Some(child);
        s
    }

    /// The bookkeeping alone (no process attached).
    pub fn without_process(kind: StageKind, pid: u32, started: Instant) -> Self {
        Self {
            kind,
            child: None,
            pid,
            exit: None,
            started,
            restart: RestartState::default(),
            restart_at: None,
            hung: false,
            chaos_kill_ns: None,
            heartbeat_misses: 0,
            chaos_kills: 0,
            earlier: [0; CARRIED],
            earlier_drops: [0; STATS_DROP_REASONS],
            earlier_misses: Vec::new(),
            earlier_misses_overwritten: 0,
            deaths: Vec::new(),
        }
    }

    /// A process of this stage is running (spawned, not reaped).
    pub fn is_running(&self) -> bool {
        self.child.is_some()
    }

    /// The reaped incarnation is gone: name its death, record it and decide
    /// with `policy` at clock `now` (`now_ns` on CLOCK_MONOTONIC: the death
    /// time unless chaos killed it). A restart sets [`Self::restart_at`].
    pub fn decide_death(
        &mut self,
        policy: &RestartPolicy,
        now: Instant,
        now_ns: u64,
    ) -> DeathVerdict {
        let death = death_of(self.exit.as_ref(), self.hung);
        let chaos = self.chaos_kill_ns.take();
        let cause = cause_of(death, chaos.is_some());
        self.hung = false;
        self.deaths.push(cause.clone());
        let lived = now.saturating_duration_since(self.started);
        let decision = self.restart.decide(policy, death, lived);
        if let Decision::Restart { after, .. } = decision {
            self.restart_at = Some(now + after);
        }
        DeathVerdict {
            cause,
            t_death_ns: chaos.unwrap_or(now_ns),
            decision,
        }
    }

    /// Its pending restart is due at `now`.
    pub fn restart_due(&self, now: Instant) -> bool {
        self.restart_at.is_some_and(|t| now >= t)
    }

    /// A new incarnation with `pid` started at `now`.
    pub fn reincarnated(&mut self, pid: u32, now: Instant) {
        self.pid = pid;
        self.exit = None;
        self.started = now;
        self.restart_at = None;
    }

    /// Keep the counters of the dying incarnation's last report.
    pub fn carry(&mut self, st: &StageStats) {
        for (e, x) in self.earlier.iter_mut().zip(counters(st)) {
            *e += x;
        }
        for (e, d) in self.earlier_drops.iter_mut().zip(st.dropped_by_reason) {
            *e += d;
        }
        let (misses, gone) = latest_misses(&self.earlier_misses, st);
        self.earlier_misses = misses;
        self.earlier_misses_overwritten += st.miss_log_overwritten + gone;
    }

    /// `st` (the last incarnation's report) with the counters of the
    /// earlier incarnations added: counters span every incarnation,
    /// histograms are the last one's, the miss log holds the latest misses
    /// of all (deadline misses = listed + `miss_log_overwritten` still).
    pub fn with_earlier(&self, mut st: StageStats) -> StageStats {
        let e = &self.earlier;
        st.processed += e[0];
        st.dropped += e[1];
        st.rejected += e[2];
        st.deadline_misses += e[3];
        st.late += e[4];
        st.controls_received += e[5];
        st.processed_after_warmup += e[6];
        st.ess_collapses += e[7];
        st.deadline_misses_preempted += e[8];
        st.deadline_misses_host += e[9];
        st.dropped_stale_idle += e[10];
        st.deadline_misses_warmup += e[11];
        for (d, x) in st.dropped_by_reason.iter_mut().zip(self.earlier_drops) {
            *d += x;
        }
        let (misses, gone) = latest_misses(&self.earlier_misses, &st);
        st.miss_log_overwritten += self.earlier_misses_overwritten + gone;
        st.miss_log = [MissStats::default(); STATS_MISSES];
        st.miss_log[..misses.len()].copy_from_slice(&misses);
        st
    }

    /// SIGKILL and reap within [`KILL_REAP_TIMEOUT`]; false if it could not
    /// be reaped in that time (the child stays registered, unreaped).
    pub fn kill_and_reap(&mut self) -> bool {
        signal(self.pid, libc::SIGKILL);
        let deadline = Instant::now() + KILL_REAP_TIMEOUT;
        loop {
            if self.poll_exit() {
                return true;
            }
            if Instant::now() > deadline {
                return false;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    /// Reap if exited; true if it has.
    pub fn poll_exit(&mut self) -> bool {
        if self.exit.is_some() {
            return true;
        }
        if let Some(c) = self.child.as_mut() {
            if let Ok(Some(s)) = c.try_wait() {
                self.exit = Some(s);
                self.child = None;
                return true;
            }
        }
        false
    }
}

/// The carried counters of a report, in the order of [`Stage::earlier`].
fn counters(st: &StageStats) -> [u64; CARRIED] {
    [
        st.processed,
        st.dropped,
        st.rejected,
        st.deadline_misses,
        st.late,
        st.controls_received,
        st.processed_after_warmup,
        st.ess_collapses,
        st.deadline_misses_preempted,
        st.deadline_misses_host,
        st.dropped_stale_idle,
        st.deadline_misses_warmup,
    ]
}

/// The latest [`STATS_MISSES`] of `earlier` (older) followed by the misses
/// listed in `st`, oldest first, and how many of them that pushed out
/// (`st`'s own `miss_log_overwritten` not included).
fn latest_misses(earlier: &[MissStats], st: &StageStats) -> (Vec<MissStats>, u64) {
    let listed = st.miss_log.iter().take_while(|m| m.miss().is_some());
    let mut all: Vec<MissStats> = earlier.iter().copied().chain(listed.copied()).collect();
    let gone = all.len().saturating_sub(STATS_MISSES);
    all.drain(..gone);
    (all, gone as u64)
}

/// `exit N`, `signal N` of a reaped process.
pub(super) fn describe(s: &ExitStatus) -> String {
    match (s.code(), s.signal()) {
        (Some(c), _) => format!("exit {c}"),
        (_, Some(sig)) => format!("signal {sig}"),
        _ => "unknown".into(),
    }
}

/// What ended an incarnation: a hang if the supervisor killed it for one,
/// else its exit status.
pub(super) fn death_of(exit: Option<&ExitStatus>, hung: bool) -> Death {
    if hung {
        return Death::Hang;
    }
    match exit.map(|s| (s.code(), s.signal())) {
        Some((Some(c), _)) => Death::Exit(c),
        Some((_, Some(sig))) => Death::Signal(sig),
        _ => Death::Exit(-1),
    }
}

/// The report's name of a death: `chaos` when chaos killed it and it died
/// of that SIGKILL.
pub(super) fn cause_of(death: Death, chaos_killed: bool) -> String {
    if chaos_killed && death == Death::Signal(libc::SIGKILL) {
        "chaos".to_string()
    } else {
        death.describe()
    }
}

/// Why a death ends the run, in words.
pub(super) fn give_up_text(why: GiveUpReason) -> &'static str {
    match why {
        GiveUpReason::PolicyNever => "its restart policy is \"never\"",
        GiveUpReason::CleanExit => "it exited cleanly (restart.on = \"failure\")",
        GiveUpReason::TooManyRestarts => "restart.max_restarts is used up",
        GiveUpReason::Fatal => "it reported an unrecoverable state (its message above)",
    }
}

/// The deadline a running incarnation missed at `now`, if it missed one:
/// `limit` since its last report, or `start_timeout` since it was started
/// when it has not reported yet.
pub(super) fn heartbeat_overdue(
    now: Instant,
    last_seen: Option<Instant>,
    started: Instant,
    limit: Duration,
    start_timeout: Duration,
) -> Option<Duration> {
    let (since, limit) = match last_seen {
        Some(t) => (t, limit),
        None => (started, start_timeout),
    };
    (now.saturating_duration_since(since) > limit).then_some(limit)
}

/// The running stages that may starve stage `i` (each `(kind, running)`):
/// on its core with a higher SCHED_FIFO priority, highest first. Killing
/// them is the escalation when `i` cannot die.
pub(super) fn starvers(
    i: usize,
    stages: &[(StageKind, bool)],
    rt: impl Fn(StageKind) -> RtSettings,
) -> Vec<usize> {
    let prio = |k: StageKind| rt(k).fifo_priority.unwrap_or(0);
    let (mine, my_prio) = (rt(stages[i].0).core, prio(stages[i].0));
    let mut v: Vec<usize> = (0..stages.len())
        .filter(|&j| j != i && stages[j].1)
        .filter(|&j| rt(stages[j].0).core == mine && prio(stages[j].0) > my_prio)
        .collect();
    v.sort_by_key(|&j| std::cmp::Reverse(prio(stages[j].0)));
    v
}

/// The stages chaos may kill: running and allowed (empty: all).
pub(super) fn chaos_candidates(stages: &[(StageKind, bool)], allowed: &[StageKind]) -> Vec<usize> {
    stages
        .iter()
        .enumerate()
        .filter(|(_, (k, running))| *running && (allowed.is_empty() || allowed.contains(k)))
        .map(|(i, _)| i)
        .collect()
}

/// One death and the recovery that followed it.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Recovery {
    pub kind: StageKind,
    pub cause: String,
    pub t_death_ns: u64,
    /// The new incarnation's pid (none before the restart).
    pub pid: Option<u32>,
    pub backoff_ms: f64,
    /// When the new incarnation first reported.
    pub reported_ns: Option<u64>,
    /// Publish time of the first output derived from a sensor sample
    /// published after the death.
    pub output_ns: Option<u64>,
}

impl Recovery {
    /// Death → recovered (new process reported and an output derived from
    /// post-death data was published), in ms.
    pub fn ms(&self) -> Option<f64> {
        let done = self.reported_ns?.max(self.output_ns?);
        Some(done.saturating_sub(self.t_death_ns) as f64 / 1e6)
    }

    /// Update with what is known at `now_ns`: whether the new incarnation
    /// has reported, and the outputs so far. Returns the recovery time once
    /// it is complete.
    pub fn observe(&mut self, reported: bool, outputs: &[Output], now_ns: u64) -> Option<f64> {
        self.pid?;
        if self.reported_ns.is_none() && reported {
            self.reported_ns = Some(now_ns);
        }
        if self.output_ns.is_none() {
            self.output_ns = outputs
                .iter()
                .filter(|o| o.t_sensor_pub_ns > self.t_death_ns)
                .map(|o| o.t_pub_ns)
                .min();
        }
        self.ms()
    }
}

/// Send `sig` to a child we spawned.
pub(super) fn signal(pid: u32, sig: libc::c_int) {
    // SAFETY: kill on a child we spawned and have not reaped yet.
    unsafe { libc::kill(pid as libc::pid_t, sig) };
}

#[cfg(test)]
mod tests;
