//! Control: on each new belief (latest value — a belief that arrives while
//! the previous one is being processed supersedes any older unread one;
//! with `control.belief_queue` > 1 every belief, in arrival order),
//! advance the waypoint route by the believed position, compute the control
//! with the configured backend, publish it with the trace extended by the
//! control's in/out stamps, and only then let the backend prepare its next
//! call (MPPI draws its noise there), keeping that work off the
//! sensor→control path.
//!
//! With `control.max_belief_age_us` > 0 a belief that waited longer than
//! that (the controller was still busy with an earlier one) is skipped and
//! counted as dropped: a controller slower than the sensor then runs on
//! fresh beliefs only, trading control rate for latency.
//!
//! A controller failure publishes the last good control (zero before the
//! first) flagged `FALLBACK` and counts the reason. With backend `none`
//! (estimation-only scenarios) the stage consumes beliefs and publishes
//! nothing.

use super::resume::ResumeControl;
use super::{
    guarded, secs_since, stopped, DropReason, Metrics, SeqTracker, StageError, StageIdentity,
    StatsPort,
};
use crate::config::{ControlBackend, PipelineConfig};
use crate::control::cost::{PathCost, TrackingCost};
use crate::control::mppi::Mppi;
use crate::control::path_integral::PathIntegralController;
use crate::control::waypoints::WaypointTracker;
use crate::control::{ControlError, Controller};
use crate::ipc::{
    control_status, run_loop, Belief, Bus, Control, Hop, Publisher, StageKind, StageStats,
    Subscriber, Wake,
};
use crate::rt::Clock;
use crate::scenario::{DynAffine, DynModel};
use crate::{MAX_CONTROL, MAX_STATE};
use std::sync::atomic::AtomicBool;
use std::time::Duration;

/// Why a control computation failed (index into `rejected_by_reason`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, strum::IntoStaticStr, strum::VariantNames)]
#[strum(serialize_all = "snake_case")]
#[repr(usize)]
pub enum Reason {
    Dimension = 0,
    NonFinite = 1,
    Model = 2,
    Numerical = 3,
}

impl Reason {
    /// Every reason, in index order.
    pub const ALL: [Reason; 4] = [
        Reason::Dimension,
        Reason::NonFinite,
        Reason::Model,
        Reason::Numerical,
    ];

    /// Report name.
    pub fn name(self) -> &'static str {
        self.into()
    }

    fn of(e: &ControlError) -> Reason {
        match e {
            ControlError::Dimension { .. } => Reason::Dimension,
            ControlError::NonFinite => Reason::NonFinite,
            ControlError::Model(_) => Reason::Model,
            ControlError::Numerical(_) => Reason::Numerical,
        }
    }
}

/// The ports of the control stage.
pub struct ControlPorts {
    pub belief: Subscriber<Belief>,
    pub control: Publisher<Control>,
    pub stats: StatsPort,
}

impl ControlPorts {
    /// Open them on `bus`.
    pub fn open(bus: &Bus, id: StageIdentity, cfg: &PipelineConfig) -> Result<Self, StageError> {
        Ok(Self {
            belief: bus.subscriber_with(cfg.control.belief_queue, true)?,
            control: bus.publisher()?,
            stats: StatsPort::open(bus, id, cfg.run.stats_period_s)?,
        })
    }
}

/// A configured controller backend (concrete, so backend-specific steps
/// such as MPPI's `prepare` are reachable).
pub enum Backend {
    Mppi(Box<Mppi<DynModel>>),
    Implicit(Box<PathIntegralController<DynAffine>>),
    /// A controller the scenario supplies.
    Scenario(Box<dyn Controller>),
}

impl Backend {
    /// The controller behind it, boxed.
    pub fn into_controller(self) -> Box<dyn Controller> {
        match self {
            Backend::Mppi(m) => m,
            Backend::Implicit(c) => c,
            Backend::Scenario(c) => c,
        }
    }

    /// The controller behind it.
    pub fn controller(&mut self) -> &mut dyn Controller {
        match self {
            Backend::Mppi(m) => m.as_mut(),
            Backend::Implicit(c) => c.as_mut(),
            Backend::Scenario(c) => c.as_mut(),
        }
    }

    /// Work for the next call that does not depend on its belief.
    pub fn prepare(&mut self) {
        match self {
            Backend::Mppi(m) => m.prepare(),
            Backend::Implicit(_) => {}
            Backend::Scenario(c) => c.prepare(),
        }
    }

    /// Weight w of the control term w‖u‖² in the closed-loop cost: the
    /// backend's own (MPPI's `control_weight`; ½R for the path-integral
    /// controller's ½uᵀRu).
    pub fn control_weight(&self) -> f64 {
        match self {
            Backend::Mppi(m) => m.config().control_weight,
            Backend::Implicit(c) => 0.5 * c.config().control_cost,
            // Its cost is its own; the closed-loop cost needs `[control.cost]`.
            Backend::Scenario(_) => 0.0,
        }
    }
}

/// Build the configured backend (None for `none`). Its random stream is
/// seeded from `run.seed` mixed with `control.mppi.seed` or
/// `control.implicit.seed` (a scenario's controller: with its own stream id).
pub fn make_backend(cfg: &PipelineConfig) -> Result<Option<Backend>, StageError> {
    let c = &cfg.control;
    let build = |e: &dyn std::fmt::Display| StageError::Build {
        what: "controller",
        reason: e.to_string(),
    };
    match &c.backend {
        ControlBackend::None => Ok(None),
        ControlBackend::Scenario(name) => {
            let ctx = crate::scenario::ControlContext {
                // Its own stream id ("CTRL"), apart from the filter's.
                seed: crate::rng::splitmix64(cfg.run.seed ^ crate::rng::splitmix64(0x4354_524C)),
                sample_dt: cfg.sample_dt(),
            };
            match cfg.system().controller(name, &ctx) {
                Some(r) => r.map(|c| Some(Backend::Scenario(c))).map_err(|e| build(&e)),
                None => Err(build(&format!(
                    "the scenario offers no controller {name:?}"
                ))),
            }
        }
        ControlBackend::Mppi => {
            let model = cfg.model()?;
            let cost = c
                .cost
                .as_ref()
                .ok_or_else(|| build(&"control.cost missing"))?;
            let tc = TrackingCost::new(&cost.q, &cost.qf, cost.barrier);
            let mut mc = c.mppi.clone();
            mc.seed = crate::rng::splitmix64(cfg.run.seed ^ crate::rng::splitmix64(mc.seed));
            let m = Mppi::new(model, tc, &mc).map_err(|e| build(&e))?;
            Ok(Some(Backend::Mppi(Box::new(m))))
        }
        ControlBackend::Implicit => {
            let affine = cfg
                .system()
                .control_affine()
                .ok_or_else(|| build(&"the scenario has no control-affine view"))?;
            let cost = c
                .cost
                .as_ref()
                .ok_or_else(|| build(&"control.cost missing"))?;
            let tc = TrackingCost::new(&cost.q, &cost.qf, cost.barrier);
            let mut pc = c.implicit.clone();
            pc.seed = crate::rng::splitmix64(cfg.run.seed ^ crate::rng::splitmix64(pc.seed));
            let ctl = PathIntegralController::new(affine, tc, pc).map_err(|e| build(&e))?;
            Ok(Some(Backend::Implicit(Box::new(ctl))))
        }
    }
}

/// Run the control stage until `stop`; returns its final stats.
pub fn run(
    ports: ControlPorts,
    cfg: &PipelineConfig,
    clock: &dyn Clock,
    stop: &AtomicBool,
) -> Result<StageStats, StageError> {
    run_with(ports, cfg, clock, stop, None)
}

/// [`run`] resuming after a restart from the last published control: the
/// route continues at that control's waypoint with its count of reached
/// waypoints, and the control numbering continues. (The last belief itself
/// arrives from the belief channel's history on connection.)
pub fn run_with(
    mut ports: ControlPorts,
    cfg: &PipelineConfig,
    clock: &dyn Clock,
    stop: &AtomicBool,
    resume: Option<&ResumeControl>,
) -> Result<StageStats, StageError> {
    // Long on purpose: the stage's loop — set-up, then the per-message
    // body handed to `run_loop` — reads top to bottom in the order a
    // message takes on the latency path, and its preallocated state lives in
    // this function's locals, borrowed by the loop body.
    let rt = cfg.stages.get(StageKind::Control);
    let mut m = Metrics::new(
        rt.budget_ns(),
        &[Hop::FilterToControl, Hop::SensorToControl],
        (cfg.run.warmup_s * 1e9) as u64,
    );
    let dims = cfg.dims()?;
    let axes = cfg.system().position_axes();
    let mut backend = make_backend(cfg)?;
    let mut route = match (&backend, &cfg.control.route) {
        (Some(_), Some(r)) => Some(WaypointTracker::new(r.clone())),
        _ => None,
    };
    if let (Some(r), Some(c)) = (route.as_mut(), resume) {
        r.resume_at(c.goal, c.waypoints_reached);
    }
    let mut goal_set = false;
    let mut seq = SeqTracker::default();
    let mut epoch: Option<u64> = None;
    let mut last_good = [0.0; MAX_CONTROL];
    let mut u = [0.0; MAX_CONTROL];
    let mut out = Control {
        dim: dims.control as u32,
        ..Control::default()
    };
    let mut out_seq = resume.map(|c| c.seq + 1).unwrap_or(0);
    let mut err = None;
    let max_age_ns = (cfg.control.max_belief_age_us * 1e3) as u64;
    let in_order = cfg.control.belief_queue > 1;
    // Closed-loop cost: the running cost at the belief mean with the control
    // held until the next belief, q(x̂_k) + w‖u_k‖² over [t_k, t_{k+1}).
    let mut eval_cost = cfg
        .control
        .cost
        .as_ref()
        .map(|c| TrackingCost::new(&c.q, &c.qf, c.barrier));
    let w_u = backend.as_ref().map_or(0.0, |b| b.control_weight());
    let mut rate_since: Option<(f64, f64)> = None; // (cost rate, t) of the last control
    if let Some(b) = backend.as_mut() {
        b.prepare();
    }
    ports.stats.publish(&m, clock.now_ns(), false)?;
    let tick = Duration::from_secs_f64(cfg.run.stats_period_s.min(0.1));

    let belief = &ports.belief;
    let control = &mut ports.control;
    let stats = &mut ports.stats;
    // When the stage last ran out of work: a belief published after it
    // found the stage waiting, so if it still went stale the stage's own
    // backlog did not delay it.
    let mut idle_since = clock.now_ns();
    run_loop(&[belief], rt.wake_mode(), tick, stop, |w| {
        guarded(&mut err, || {
            // Latest value: one belief per wake-up, the newest; a queue:
            // every waiting belief in arrival order.
            if w == Wake::Data {
                loop {
                    let b = if in_order {
                        belief.receive()?
                    } else {
                        let (latest, skipped) = belief.latest()?;
                        m.count_drop(DropReason::Superseded, skipped);
                        latest
                    };
                    let Some(b) = b else { break };
                    let t_in = clock.now_ns();
                    m.budget.start();
                    m.count_drop(DropReason::Lost, seq.observe(b.header.seq));
                    if max_age_ns > 0 && t_in.saturating_sub(b.header.t_pub_ns) > max_age_ns {
                        // Stale: wait for a fresh one.
                        m.count_drop(DropReason::Stale, 1);
                        m.stale_while_idle += (b.header.t_pub_ns >= idle_since) as u64;
                        continue;
                    }
                    let Some(backend) = backend.as_mut() else {
                        m.processed += 1;
                        m.budget
                            .record_released(b.header.t_pub_ns, t_in, clock.now_ns());
                        continue;
                    };
                    let g = b.gaussian();
                    let epoch_ns = *epoch.get_or_insert(b.header.t_valid_ns);
                    let t = secs_since(epoch_ns, b.header.t_valid_ns);
                    if let Some((rate, t0)) = rate_since {
                        if t > t0 && m.past_warmup(b.trace.t_meas_ns) {
                            m.cost_integral += rate * (t - t0);
                            m.cost_time += t - t0;
                        }
                    }
                    if let Some(r) = route.as_mut() {
                        let mut pos = [0.0; MAX_STATE];
                        for (p, &a) in pos.iter_mut().zip(axes) {
                            *p = g.mean[a];
                        }
                        if r.update(&pos[..axes.len()]) || !goal_set {
                            let mut goal = [0.0; MAX_STATE];
                            for (&a, &w) in axes.iter().zip(r.goal()) {
                                goal[a] = w;
                            }
                            backend.controller().set_goal(&goal[..dims.state]);
                            if let Some(c) = eval_cost.as_mut() {
                                c.set_goal(&goal[..dims.state]);
                            }
                            goal_set = true;
                        }
                        out.goal = r.goal2();
                        out.waypoints_reached = r.reached();
                    }
                    let c = dims.control;
                    backend.controller().set_step(b.trace.sensor_seq);
                    match backend.controller().compute(t, &g, &mut u[..c]) {
                        Ok(info) => {
                            out.status = control_status::OK;
                            out.cost = info.cost;
                            last_good[..c].copy_from_slice(&u[..c]);
                        }
                        Err(e) => {
                            m.reject(Reason::of(&e) as usize);
                            out.status = control_status::FALLBACK;
                            out.cost = f64::NAN;
                            u[..c].copy_from_slice(&last_good[..c]);
                        }
                    }
                    if let Some(ec) = eval_cost.as_ref() {
                        let uu: f64 = u[..c].iter().map(|v| v * v).sum();
                        rate_since = Some((ec.running(&g.mean[..dims.state]) + w_u * uu, t));
                    }
                    out.u = u;
                    out.trace = b.trace;
                    out.trace.t_control_in_ns = t_in;
                    out.header.seq = out_seq;
                    out.header.t_valid_ns = b.header.t_valid_ns;
                    let now = clock.now_ns();
                    out.header.t_pub_ns = now;
                    out.trace.t_control_out_ns = now;
                    control.publish(&out)?;
                    out_seq += 1;
                    m.processed += 1;
                    m.budget.record_released(b.header.t_pub_ns, t_in, now);
                    m.record_hops(&out.trace);
                    // Off the critical path: the next call's noise.
                    backend.prepare();
                    if !in_order {
                        break;
                    }
                }
            }
            stats.tick(&m, clock.now_ns())?;
            idle_since = clock.now_ns();
            Ok(())
        })
    })?;
    let last = ports.stats.publish(&m, clock.now_ns(), true)?;
    match err {
        Some(e) if !stopped(stop) => Err(e),
        _ => Ok(last),
    }
}
