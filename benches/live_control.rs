//! The control stage's controller exactly as a config builds it, driven
//! offline along a closed loop at the config's sensor rate: the true system
//! (Euler–Maruyama at `plant.integration_dt` with the controller's held
//! force), a belief centred near the truth (σ 0.1 on position, 0.05 on
//! velocity, as the live filters report), the waypoint route advanced by
//! the believed position as the control stage does.
//!
//! Prints, per variant, thread-CPU p50 / p99 / p99.9 per control, the ratio
//! of its p50 to the first variant's, and the closed loop's quality: the
//! cost rate q(x) + w‖u‖² at the truth (the control stage's closed-loop
//! cost) and the waypoints reached. Variants run interleaved in blocks of
//! 1 000 controls (each on its own loop and random stream), so a change in
//! the machine's load shows in every row alike, not in one.
//!
//! It separates what a control costs from what the live pipeline adds
//! (wake-ups, cache sharing with the refine stage): when the control
//! stage's compute percentiles in a run report sit well above these, the
//! difference is the process environment, not the algorithm.
//!
//! `cargo bench --bench live_control -- [CONFIG] [--seed S] [--controls N] [--vs 'KEY=VALUE,...']...`
//! (default `configs/flagship-1khz.toml`, 20 000 controls per variant: 20 s
//! of closed loop at 1 kHz; at 5 kHz give `--controls 100000` for as long).

use beliefbus::belief::Gaussian;
use beliefbus::config::{load, PipelineConfig};
use beliefbus::control::cost::TrackingCost;
use beliefbus::control::waypoints::WaypointTracker;
use beliefbus::model::path_cost::PathCost;
use beliefbus::model::SdeModel;
use beliefbus::rng::{stream, SimRng};
use beliefbus::rt::clock::thread_cpu_ns;
use beliefbus::scenario::DynModel;
use beliefbus::stage::control::{make_backend, Backend};
use hdrhistogram::Histogram;
use rand_distr::{Distribution, StandardNormal};
use std::hint::black_box;
use std::path::PathBuf;

const CALLS: usize = 20_000;
const BLOCK: usize = 1_000;

fn main() {
    let mut args = std::env::args().skip(1).filter(|a| a != "--bench");
    let mut path = PathBuf::from("configs/flagship-1khz.toml");
    let mut variants: Vec<String> = vec![String::new()];
    let mut seed = 7u64;
    let mut calls = CALLS;
    while let Some(a) = args.next() {
        if a == "--vs" {
            variants.extend(args.next());
        } else if a == "--seed" {
            seed = args.next().and_then(|s| s.parse().ok()).expect("--seed N");
        } else if a == "--controls" {
            calls = args
                .next()
                .and_then(|s| s.parse().ok())
                .expect("--controls N");
        } else {
            path = PathBuf::from(a);
        }
    }
    let mut loops: Vec<Loop> = variants
        .iter()
        .map(|v| {
            let sets: Vec<String> = v
                .split(',')
                .filter(|s| !s.is_empty())
                .map(str::to_owned)
                .collect();
            Loop::new(load(&path, &sets).expect("config"), seed)
        })
        .collect();
    println!(
        "config {} ({} Hz sensor), {calls} controls per variant, interleaved in blocks of {BLOCK}",
        path.display(),
        1.0 / loops[0].dt
    );
    for _ in 0..calls.div_ceil(BLOCK) {
        for l in loops.iter_mut() {
            l.run(BLOCK);
        }
    }
    println!(
        "{:>9} {:>9} {:>9} {:>9}  {:>10} {:>9}  variant",
        "cpu p50", "p99", "p99.9", "x first", "cost rate", "waypoints"
    );
    let q = |h: &Histogram<u64>, p: f64| h.value_at_quantile(p) as f64 / 1e3;
    let first = q(&loops[0].cpu, 0.5);
    for (l, v) in loops.iter().zip(&variants) {
        println!(
            "{:>9.1} {:>9.1} {:>9.1} {:>9.2}  {:>10.3} {:>9}  {}",
            q(&l.cpu, 0.5),
            q(&l.cpu, 0.99),
            q(&l.cpu, 0.999),
            q(&l.cpu, 0.5) / first,
            l.cost / l.time,
            l.route.reached(),
            if v.is_empty() {
                "(config as written)"
            } else {
                v
            }
        );
    }
}

/// One closed loop: truth, controller, route, and what was measured.
struct Loop {
    model: DynModel,
    backend: Backend,
    route: WaypointTracker,
    eval: TrackingCost,
    w_u: f64,
    axes: Vec<usize>,
    rng: SimRng,
    dt: f64,
    sub: usize,
    x: Vec<f64>,
    u: Vec<f64>,
    goal_set: bool,
    i: usize,
    cpu: Histogram<u64>,
    cost: f64,
    time: f64,
}

impl Loop {
    fn new(cfg: PipelineConfig, seed: u64) -> Self {
        let model = cfg.model().expect("model");
        let dt = cfg.sample_dt();
        let sub = (dt / cfg.plant.integration_dt).round().max(1.0) as usize;
        let backend = make_backend(&cfg).expect("backend").expect("a controller");
        let c = cfg.control.cost.as_ref().expect("control.cost");
        let w_u = backend.control_weight();
        Self {
            route: WaypointTracker::new(cfg.control.route.clone().expect("route")),
            eval: TrackingCost::new(&c.q, &c.qf, c.barrier),
            w_u,
            axes: cfg.system().position_axes().to_vec(),
            rng: stream(seed, 0),
            dt,
            sub,
            x: cfg.plant.initial_state.clone(),
            u: vec![0.0; model.dims().control],
            model,
            backend,
            goal_set: false,
            i: 0,
            cpu: Histogram::new(3).expect("histogram"),
            cost: 0.0,
            time: 0.0,
        }
    }

    fn run(&mut self, calls: usize) {
        let dims = self.model.dims();
        let (d, k) = (dims.state, dims.noise);
        let h = self.dt / self.sub as f64;
        let mut f = vec![0.0; d];
        let mut big_f = vec![0.0; d * k];
        let mut std = vec![0.05; d];
        for &a in &self.axes {
            std[a] = 0.1;
        }
        for _ in 0..calls {
            // Truth over one sensor period with the held control.
            for _ in 0..self.sub {
                let uu: f64 = self.u.iter().map(|v| v * v).sum();
                self.cost += (self.eval.running(&self.x) + self.w_u * uu) * h;
                self.time += h;
                self.model.drift(&self.x, &self.u, &mut f);
                self.model.diffusion(&self.x, &mut big_f);
                for r in 0..d {
                    let mut w = 0.0;
                    for c in 0..k {
                        let z: f64 = StandardNormal.sample(&mut self.rng);
                        w += big_f[r * k + c] * z;
                    }
                    self.x[r] += f[r] * h + w * h.sqrt();
                }
            }
            let mean: Vec<f64> = self
                .x
                .iter()
                .zip(&std)
                .map(|(v, s)| {
                    let z: f64 = StandardNormal.sample(&mut self.rng);
                    v + s * z
                })
                .collect();
            let g = Gaussian::diagonal(&mean, &std);
            let pos: Vec<f64> = self.axes.iter().map(|&a| g.mean[a]).collect();
            if self.route.update(&pos) || !self.goal_set {
                let mut goal = vec![0.0; d];
                for (&a, &w) in self.axes.iter().zip(self.route.goal()) {
                    goal[a] = w;
                }
                self.backend.controller().set_goal(&goal);
                self.eval.set_goal(&goal);
                self.goal_set = true;
            }
            let t = self.i as f64 * self.dt;
            let c0 = thread_cpu_ns();
            let r = self
                .backend
                .controller()
                .compute(black_box(t), black_box(&g), &mut self.u);
            self.cpu
                .record(thread_cpu_ns().saturating_sub(c0).max(1))
                .expect("record");
            if r.is_err() {
                self.u.fill(0.0);
            }
            self.backend.prepare();
            self.i += 1;
        }
    }
}
