//! Controller `pomdp`: the α-vector policy on the chain filter's
//! distribution,
//!
//! ```text
//! a_k = action(argmax_α α·b_k),   u_k = (control of a_k, 0) or (0, 1) for the terminal action
//! ```
//!
//! with b_k the `chain-pomdp` filter's probabilities over the chain states
//! (carried in the belief message, [`super::encoding`]). The lookup is
//! K·n multiply-adds over a flat table of at most `lookup_capacity` rows
//! ([`FlatPolicy::act`]);
//! its time is measured on every call and published with the control.
//!
//! The policy file is loaded and checked when the controller is built —
//! at config validation — so a missing or stale file is a config error
//! naming the `beliefbus solve` command. The table the lookup scans is not
//! the solver's whole set but at most `policy.lookup_capacity` of its
//! vectors, those that attain the maximum at the beliefs a simulated
//! closed loop visits ([`super::prune`]), built at the first
//! [`Controller::prepare`] (the stage's start, before any decision).
//!
//! **Swaps.** With `refine_round_s > 0` the controller starts, on its first
//! [`Controller::prepare`] (which the stage calls when it starts and after
//! each published control; never at validation), a background thread
//! that keeps solving the same POMDP from the full set of the policy in
//! use (its α-vectors seed the solver's lower bound, so V̲(b₀) never
//! decreases), at SCHED_OTHER nice `refine_nice` (19) and moved off the
//! control thread's core. When a round raises V̲(b₀) it builds the new
//! bounded table on that thread and offers it through a lock-free mailbox
//! ([`super::swap`]); `prepare` — off the sensor→control path — takes it
//! with one atomic swap and a pointer exchange; the replaced table goes
//! back to the solver thread to be freed there. `compute` never waits for
//! the solver, and nothing is allocated or freed on the control thread.
//! Each swap raises the policy version published with the control.

use super::encoding::{read_chain, write_action, CONTROL, U_LOOKUP_NS, U_VERSION};
use super::flat::FlatPolicy;
use super::prune::bounded_table;
use super::swap::{Current, Mailbox};
use super::LightDarkSystem;
use beliefbus_core::belief::Gaussian;
use beliefbus_core::control::{ControlError, ControlInfo, Controller};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

/// The background solve's handle.
struct Background {
    mailbox: Arc<Mailbox<FlatPolicy>>,
    stop: Arc<AtomicBool>,
}

/// Seed of the simulated episodes that choose a table's vectors.
const PRUNE_SEED: u64 = 0x7072_756e_6573_6565;

/// `pomdp`.
pub struct PomdpController {
    sys: LightDarkSystem,
    policy: Current<FlatPolicy>,
    /// The full set the table came from: the background solve's seed
    /// (moved to its thread when it starts).
    full: Option<FlatPolicy>,
    /// The policy in use is the full set; bound it at the first prepare.
    unbounded: bool,
    version: u64,
    background: Option<Background>,
    /// The background solve ran (or is off).
    started: bool,
}

/// The bounded table of `full` with the system's capacity.
pub fn table_for(sys: &LightDarkSystem, full: &FlatPolicy, seed: u64) -> FlatPolicy {
    let p = &sys.params.policy;
    bounded_table(sys, full, p.lookup_capacity, p.prune_episodes, seed).0
}

impl PomdpController {
    /// Load and check the policy file. The bounded table is built on the
    /// first [`Controller::prepare`] (the stage's start), not here: config
    /// validation builds controllers too, and needs only the check.
    pub fn new(sys: &LightDarkSystem) -> Result<Self, String> {
        let (p, lower) = sys.load_policy()?;
        let mut c = Self::with_policy(sys, FlatPolicy::new(&p, sys.pomdp.n_chain(), lower));
        c.unbounded = true;
        Ok(c)
    }

    /// Acting with the bounded table of `full`.
    pub fn bounded(sys: &LightDarkSystem, full: FlatPolicy) -> Self {
        let mut c = Self::with_policy(sys, full);
        c.bound_table();
        c
    }

    /// Replace the policy in use, taken as the full set, by its bounded
    /// table (set-up: allocates).
    pub fn bound_table(&mut self) {
        self.unbounded = false;
        let table = table_for(&self.sys, self.policy.get(), PRUNE_SEED);
        self.full = Some(*self.policy.replace(Box::new(table)));
    }

    /// Acting with `policy` as given (every vector scanned).
    pub fn with_policy(sys: &LightDarkSystem, policy: FlatPolicy) -> Self {
        Self {
            sys: sys.clone(),
            policy: Current::new(Box::new(policy)),
            full: None,
            unbounded: false,
            version: 0,
            background: None,
            started: sys.params.policy.refine_round_s <= 0.0
                || sys.params.policy.refine_rounds == 0,
        }
    }

    /// The policy in use and its version (0: the file's; +1 per swap).
    pub fn policy(&self) -> (&FlatPolicy, u64) {
        (self.policy.get(), self.version)
    }

    /// Take an improved policy if one is waiting (a pointer exchange);
    /// true if swapped.
    pub fn try_swap(&mut self) -> bool {
        let Some(bg) = &self.background else {
            return false;
        };
        let swapped = self.policy.take_from(&bg.mailbox);
        if swapped {
            self.version += 1;
        }
        swapped
    }

    /// Start the background solve (once).
    pub fn start_background(&mut self) {
        if self.started {
            return;
        }
        self.started = true;
        let mailbox = Arc::new(Mailbox::default());
        let stop = Arc::new(AtomicBool::new(false));
        let sys = self.sys.clone();
        let first = self
            .full
            .take()
            .unwrap_or_else(|| self.policy.get().clone());
        let (flag, out) = (stop.clone(), mailbox.clone());
        let nice = sys.params.policy.refine_nice;
        // SAFETY: sched_getcpu has no preconditions.
        let core = unsafe { libc::sched_getcpu() };
        let spawned = std::thread::Builder::new()
            .name("pomdp-solve".into())
            .spawn(move || {
                demote_this_thread(core, nice);
                background_solve(sys, first, &out, flag)
            });
        if spawned.is_ok() {
            self.background = Some(Background { mailbox, stop });
        }
    }

    /// The control for chain distribution `b`.
    #[inline]
    fn decide(&self, b: &[f64], u: &mut [f64]) {
        write_action(&self.sys.pomdp, self.policy.get().act(b), u);
    }
}

impl Drop for PomdpController {
    fn drop(&mut self) {
        if let Some(bg) = &self.background {
            bg.stop.store(true, Ordering::Relaxed);
        }
    }
}

/// Lower the calling thread to SCHED_OTHER at `nice` (19 by default;
/// Linux applies both to the calling thread only; not SCHED_IDLE, which starves it outright
/// on a machine busy with other work, so no improved policy would ever
/// arrive), and move it off `core`
/// (the control thread's) onto the machine's other cores, so the solver
/// neither delays the control thread nor evicts its table from that
/// core's caches. Failures leave the thread as it was.
fn demote_this_thread(core: i32, nice: i32) {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: sched_setscheduler / setpriority / sched_setaffinity on the
    // calling thread (0) with valid arguments; cpu_set_t is plain data.
    unsafe {
        libc::sched_setscheduler(0, libc::SCHED_OTHER, &param);
        libc::setpriority(libc::PRIO_PROCESS, 0, nice);
        if core < 0 {
            return;
        }
        let online = libc::sysconf(libc::_SC_NPROCESSORS_ONLN).max(0) as usize;
        let mut others: libc::cpu_set_t = std::mem::zeroed();
        let mut any = false;
        for c in 0..online.min(libc::CPU_SETSIZE as usize) {
            if c != core as usize {
                libc::CPU_SET(c, &mut others);
                any = true;
            }
        }
        if any {
            libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &others);
        }
    }
}

/// Rounds of `refine_round_s` from the full set in use; each that raises
/// V̲(b₀) has its bounded table built here and offered to the controller.
fn background_solve(
    sys: LightDarkSystem,
    first: FlatPolicy,
    mailbox: &Mailbox<FlatPolicy>,
    stop: Arc<AtomicBool>,
) {
    let cp = sys.pomdp.clone();
    let n = cp.n_chain();
    let ns = cp.pomdp.n_states();
    // Seed with the file's vectors (the absorbing entry: the terminal
    // action's value there is 0, as every plan's after the episode ends).
    let mut seed: Vec<(Vec<f64>, usize)> = first
        .alphas
        .chunks_exact(n)
        .zip(&first.actions)
        .map(|(v, &a)| {
            let mut full = v.to_vec();
            full.resize(ns, 0.0);
            (full, a)
        })
        .collect();
    let mut best = first.lower_b0;
    let p = &sys.params.policy;
    for round in 0..p.refine_rounds {
        if stop.load(Ordering::Relaxed) {
            return;
        }
        // Free the tables the controller replaced.
        mailbox.collect();
        let opts = sys.solve_options(p.refine_round_s, 1, seed.clone());
        let Ok(sol) = beliefbus_pomdp::solve(&cp.pomdp, &opts, |_| {}) else {
            return;
        };
        if sol.lower > best + 1e-9 * best.abs().max(1.0) {
            best = sol.lower;
            let full = FlatPolicy::new(&sol.policy, n, sol.lower);
            let table = table_for(&sys, &full, PRUNE_SEED.wrapping_add(round + 1));
            if stop.load(Ordering::Relaxed) {
                return;
            }
            mailbox.publish(Box::new(table));
        }
        seed = sol
            .policy
            .vectors
            .into_iter()
            .zip(sol.policy.actions)
            .collect();
        if sol.converged {
            return;
        }
    }
}

impl Controller for PomdpController {
    fn name(&self) -> &'static str {
        super::POMDP
    }
    fn control_dim(&self) -> usize {
        CONTROL
    }
    /// The goal is the policy's.
    fn set_goal(&mut self, _goal: &[f64]) {}
    fn reset(&mut self) {}
    /// Off the sensor→control path: bound the table (first call), start the
    /// background solve, swap in a policy it published.
    fn prepare(&mut self) {
        if self.unbounded {
            self.bound_table();
        }
        self.start_background();
        self.try_swap();
    }
    fn compute(
        &mut self,
        _t: f64,
        belief: &Gaussian,
        u: &mut [f64],
    ) -> Result<ControlInfo, ControlError> {
        let t0 = Instant::now();
        if u.len() < CONTROL {
            return Err(ControlError::Dimension {
                got: u.len(),
                expected: CONTROL,
            });
        }
        let b = read_chain(belief).ok_or_else(|| {
            ControlError::Model(
                "the belief carries no chain distribution (filter.backend must be \"chain-pomdp\")"
                    .into(),
            )
        })?;
        if b.len() != self.policy.get().n {
            return Err(ControlError::Dimension {
                got: b.len(),
                expected: self.policy.get().n,
            });
        }
        if b.iter().any(|p| !p.is_finite()) {
            return Err(ControlError::NonFinite);
        }
        self.decide(b, u);
        u[U_VERSION] = self.version as f64;
        u[U_LOOKUP_NS] = t0.elapsed().as_nanos() as f64;
        Ok(ControlInfo {
            cost: f64::NAN,
            samples: 0,
            ess: 0.0,
        })
    }
}
