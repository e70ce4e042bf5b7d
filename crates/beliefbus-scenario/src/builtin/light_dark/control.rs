//! Controller `pomdp`: the α-vector policy on the chain filter's
//! distribution,
//!
//! ```text
//! a_k = action(argmax_α α·b_k),   u_k = (control of a_k, 0) or (0, 1) for the terminal action
//! ```
//!
//! with b_k the `chain-pomdp` filter's probabilities over the chain states
//! (carried in the belief message, [`super::encoding`]). The lookup is
//! K·n multiply-adds over a flat preallocated table ([`FlatPolicy::act`]);
//! its time is measured on every call and published with the control.
//!
//! The policy file is loaded and checked when the controller is built —
//! at config validation — so a missing or stale file is a config error
//! naming the `beliefbus solve` command.
//!
//! **Swaps.** With `refine_round_s > 0` the controller starts, on its first
//! [`Controller::prepare`] (which the stage calls when it starts and after
//! each published control; never at validation), a background thread
//! that keeps solving the same POMDP from the policy in use (its α-vectors
//! seed the solver's lower bound, so V̲(b₀) never decreases), demoted to
//! SCHED_OTHER at nice 19 and moved off the control thread's core. When a
//! round raises V̲(b₀) it flattens the new policy (dropping dominated
//! vectors) off the hot path and sends it over a channel; `prepare` —
//! which the stage calls after publishing a control, off the
//! sensor→control path — takes it and swaps the table (a pointer swap;
//! the replaced table goes back to the solver thread to be freed there):
//! `compute` never waits for the solver. Each swap raises the policy
//! version published with the control.

use super::encoding::{read_chain, CONTROL, U_DECLARE, U_LOOKUP_NS, U_VELOCITY, U_VERSION};
use super::policy::FlatPolicy;
use super::LightDarkSystem;
use beliefbus_core::belief::Gaussian;
use beliefbus_core::control::{ControlError, ControlInfo, Controller};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, Sender, TryRecvError};
use std::sync::Arc;
use std::time::Instant;

/// The background solve's handle.
struct Background {
    rx: Receiver<Box<FlatPolicy>>,
    /// Replaced tables go back to the solver thread to be freed there.
    retire: Sender<Box<FlatPolicy>>,
    stop: Arc<AtomicBool>,
}

/// `pomdp`.
pub struct PomdpController {
    sys: LightDarkSystem,
    policy: Box<FlatPolicy>,
    version: u64,
    background: Option<Background>,
    /// The background solve ran (or is off).
    started: bool,
}

impl PomdpController {
    /// Load and check the policy file.
    pub fn new(sys: &LightDarkSystem) -> Result<Self, String> {
        let (p, lower) = sys.load_policy()?;
        Ok(Self::with_policy(
            sys,
            FlatPolicy::new(&p, sys.pomdp.n_chain(), lower),
        ))
    }

    /// With a given policy (tests, and the loaded one).
    pub fn with_policy(sys: &LightDarkSystem, policy: FlatPolicy) -> Self {
        Self {
            sys: sys.clone(),
            policy: Box::new(policy),
            version: 0,
            background: None,
            started: sys.params.policy.refine_round_s <= 0.0
                || sys.params.policy.refine_rounds == 0,
        }
    }

    /// The policy in use and its version (0: the file's; +1 per swap).
    pub fn policy(&self) -> (&FlatPolicy, u64) {
        (&self.policy, self.version)
    }

    /// Take an improved policy if one is waiting; true if swapped.
    pub fn try_swap(&mut self) -> bool {
        let Some(bg) = &self.background else {
            return false;
        };
        let mut swapped = false;
        loop {
            match bg.rx.try_recv() {
                Ok(p) => {
                    let old = std::mem::replace(&mut self.policy, p);
                    // Freed by the solver thread (or here if it has ended).
                    let _ = bg.retire.send(old);
                    self.version += 1;
                    swapped = true;
                }
                Err(TryRecvError::Empty) => break,
                Err(TryRecvError::Disconnected) => {
                    self.background = None;
                    break;
                }
            }
        }
        swapped
    }

    /// Start the background solve (once).
    pub fn start_background(&mut self) {
        if self.started {
            return;
        }
        self.started = true;
        let (tx, rx) = mpsc::channel();
        let (retire, retired) = mpsc::channel();
        let stop = Arc::new(AtomicBool::new(false));
        let sys = self.sys.clone();
        let first = (*self.policy).clone();
        let flag = stop.clone();
        // SAFETY: sched_getcpu has no preconditions.
        let core = unsafe { libc::sched_getcpu() };
        let spawned = std::thread::Builder::new()
            .name("pomdp-solve".into())
            .spawn(move || {
                demote_this_thread(core);
                background_solve(sys, first, tx, retired, flag)
            });
        if spawned.is_ok() {
            self.background = Some(Background { rx, retire, stop });
        }
    }

    /// The control for chain distribution `b`, and the lookup time (ns).
    #[inline]
    fn decide(&self, b: &[f64], u: &mut [f64]) {
        let a = self.policy.act(b);
        let cp = &self.sys.pomdp;
        match cp.control(a) {
            Some(c) => {
                u[U_VELOCITY] = c[0];
                u[U_DECLARE] = 0.0;
            }
            None => {
                u[U_VELOCITY] = 0.0;
                u[U_DECLARE] = 1.0;
            }
        }
    }
}

impl Drop for PomdpController {
    fn drop(&mut self) {
        if let Some(bg) = &self.background {
            bg.stop.store(true, Ordering::Relaxed);
        }
    }
}

/// Lower the calling thread to SCHED_OTHER, nice 19 (Linux: both apply
/// to the calling thread only), and move it off `core` (the control
/// thread's) onto the machine's other cores, so the solver neither delays
/// the control thread nor evicts its table from that core's caches.
/// Failures leave the thread as it was.
fn demote_this_thread(core: i32) {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: sched_setscheduler / setpriority / sched_setaffinity on the
    // calling thread (0) with valid arguments; cpu_set_t is plain data.
    unsafe {
        libc::sched_setscheduler(0, libc::SCHED_OTHER, &param);
        libc::setpriority(libc::PRIO_PROCESS, 0, 19);
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

/// Rounds of `refine_round_s` from the policy in use; each that raises
/// V̲(b₀) is sent to the controller.
fn background_solve(
    sys: LightDarkSystem,
    first: FlatPolicy,
    tx: Sender<Box<FlatPolicy>>,
    retired: Receiver<Box<FlatPolicy>>,
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
    for _ in 0..p.refine_rounds {
        if stop.load(Ordering::Relaxed) {
            return;
        }
        // Free the tables the controller replaced.
        while retired.try_recv().is_ok() {}
        let opts = sys.solve_options(p.refine_round_s, 1, seed.clone());
        let Ok(sol) = beliefbus_pomdp::solve(&cp.pomdp, &opts, |_| {}) else {
            return;
        };
        if sol.lower > best + 1e-9 * best.abs().max(1.0) {
            best = sol.lower;
            let flat = Box::new(FlatPolicy::new(&sol.policy, n, sol.lower));
            if tx.send(flat).is_err() {
                return;
            }
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
    /// Off the sensor→control path: start the background solve, swap in a
    /// policy it published.
    fn prepare(&mut self) {
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
        if b.len() != self.policy.n {
            return Err(ControlError::Dimension {
                got: b.len(),
                expected: self.policy.n,
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
