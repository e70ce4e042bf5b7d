//! The greedy variants and the backlog reading, simulated on the stated
//! model (known state) or with the bootstrap PF.

use beliefbus_projection::bootstrap::BootstrapPf;
use beliefbus_projection::inventory::policies::{greedy_action, Controller, Observation};
use beliefbus_projection::inventory::sim::{discounted_sum, filter_rng, run_closed_loop, Scenario};
use beliefbus_projection::inventory::Inventory;
use beliefbus_projection::model::Pomdp;
use beliefbus_projection::rng::{stream, SimRng};
use beliefbus_projection::ProjectionError;
use rand::RngExt;
use rand_distr::Exp1;

/// The simulated greedy variants on the stated model (zero lead, cost
/// after demand, mean 5) with a known state: a rule mapping (x_{k−1},
/// a_{k−1}, x_k, rng) to a_k.
pub(crate) fn simulate(
    rule: &dyn Fn(f64, usize, f64, &mut SimRng) -> usize,
    seed: u64,
) -> ((f64, f64), (f64, f64)) {
    let model = Inventory::paper(0.1).unwrap();
    let demand = |rng: &mut SimRng| -> f64 {
        let e: f64 = rng.sample(Exp1);
        5.0 * e
    };
    // Average: one run of 10^6 periods, 20 batch means.
    let mut env = stream(seed, 1);
    let mut pol = stream(seed, 2);
    let (mut x, mut xp, mut ap) = (5.0, 5.0, 0usize);
    let steps = 1_000_000;
    let batches = 20;
    let mut bm = vec![0.0; batches];
    for k in 0..steps {
        let a = rule(xp, ap, x, &mut pol);
        let u = demand(&mut env);
        bm[k / (steps / batches)] += model.cost(x, a, u) / (steps / batches) as f64;
        xp = x;
        ap = a;
        x = model.next_state(x, a, u);
    }
    let avg = mean_se(&bm);
    // Discounted: 20000 runs of 41 periods from x_0 = 5.
    let mut disc = Vec::with_capacity(20_000);
    for r in 0..20_000u64 {
        let mut env = stream(seed, 1000 + 2 * r);
        let mut pol = stream(seed, 1001 + 2 * r);
        let (mut x, mut xp, mut ap) = (5.0, 5.0, 0usize);
        let (mut total, mut g) = (0.0, 1.0);
        for _ in 0..41 {
            let a = rule(xp, ap, x, &mut pol);
            let u = demand(&mut env);
            total += g * model.cost(x, a, u);
            g *= 0.9;
            xp = x;
            ap = a;
            x = model.next_state(x, a, u);
        }
        disc.push(total);
    }
    (avg, mean_se(&disc))
}

pub(crate) fn mean_se(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, (var / n).sqrt())
}

/// Backlog instead of lost sales (x' = x + aQ − u, negative stock carried
/// and charged s per unit per period): threshold rules by simulation, 10⁶
/// periods on common demands, and the myopic rule (on x ≥ 0 the same
/// threshold 7.797; below zero it always orders).
pub(crate) fn backlog() {
    let model = Inventory::paper(1.0).unwrap();
    let mut env = stream(11, 1);
    let demands: Vec<f64> = (0..1_000_000)
        .map(|_| {
            let e: f64 = env.sample(Exp1);
            5.0 * e
        })
        .collect();
    let run = |l: f64| {
        let mut x = 5.0;
        let mut total = 0.0;
        for &u in &demands {
            let z = x + if x < l { model.q } else { 0.0 } - u;
            total += if z >= 0.0 { model.h * z } else { -model.s * z };
            x = z;
        }
        total / demands.len() as f64
    };
    let best = (0..=40).map(|i| 0.5 * i as f64).map(|l| (l, run(l))).fold(
        (f64::NAN, f64::INFINITY),
        |b, c| if c.1 < b.1 { c } else { b },
    );
    println!(
        "backlog: best threshold {:.1} average {:.3} (threshold 7.7: {:.3}, myopic 7.797: {:.3})",
        best.0,
        best.1,
        run(7.7),
        run(7.797)
    );
}

/// Greedy variants that read the bootstrap PF (N = 200, resampled every
/// step) differently from the stated rule.
#[derive(Clone, Copy, Debug)]
pub(crate) enum PfGreedy {
    /// The stated rule: Σ_i w_i E_u[g(x_i, a, u)].
    Stated,
    /// The stated rule on the observation taken as the state.
    OnObservation,
    /// The stated rule on the predicted belief (before weighting by y_k).
    Predicted,
    /// One sampled demand per decision, shared by both actions, at the
    /// posterior mean.
    OneDemand,
    /// The filter propagates its particles as if no order were placed.
    FilterBlindToOrders,
}

pub(crate) struct PfGreedyCtl {
    pf: BootstrapPf,
    kind: PfGreedy,
    ones: Vec<f64>,
}

impl Controller for PfGreedyCtl {
    fn name(&self) -> &'static str {
        "greedy-variant"
    }
    fn reset(&mut self, model: &Inventory, _: &mut SimRng) -> Result<(), ProjectionError> {
        self.pf.initialize_at(&[model.x0])
    }
    fn act(
        &mut self,
        model: &Inventory,
        obs: Observation,
        prev: Option<usize>,
        rng: &mut SimRng,
    ) -> Result<usize, ProjectionError> {
        if let Some(a) = prev {
            self.pf.resample(rng);
            let a = if matches!(self.kind, PfGreedy::FilterBlindToOrders) {
                0
            } else {
                a
            };
            self.pf.predict(model, model.action_control(a), rng);
        }
        if matches!(self.kind, PfGreedy::Predicted) {
            let a = greedy_action(model, self.pf.particles(), &self.ones);
            self.pf.update(model, &[obs.y])?;
            return Ok(a);
        }
        self.pf.update(model, &[obs.y])?;
        Ok(match self.kind {
            PfGreedy::OnObservation => greedy_action(model, &[obs.y.max(0.0)], &[1.0]),
            PfGreedy::OneDemand => {
                let mut m = [0.0];
                self.pf.mean(&mut m);
                let e: f64 = rng.sample(Exp1);
                let u = model.demand_mean * e;
                usize::from(model.cost(m[0], 1, u) < model.cost(m[0], 0, u))
            }
            _ => greedy_action(model, self.pf.particles(), self.pf.weights()),
        })
    }
}

/// (average over one H = 10^5 run, discounted mean ± se over 1000 runs of
/// 41 periods) of a PF greedy variant at σ, common random numbers of `seed`.
pub(crate) fn pf_variant(kind: PfGreedy, sigma: f64, seed: u64) -> (f64, f64, f64) {
    let model = Inventory::paper(sigma).unwrap();
    let mut ctl = PfGreedyCtl {
        pf: BootstrapPf::new(200, 1).unwrap(),
        kind,
        ones: vec![1.0 / 200.0; 200],
    };
    let sc = Scenario::new(&model, seed, 0, 100_000);
    let mut costs = vec![0.0; 100_000];
    run_closed_loop(&model, &mut ctl, &sc, &mut filter_rng(seed, 0), &mut costs).unwrap();
    let avg = costs.iter().sum::<f64>() / costs.len() as f64;
    let mut costs = vec![0.0; 41];
    let disc: Vec<f64> = (0..1000u64)
        .map(|r| {
            let sc = Scenario::new(&model, seed, r, 41);
            run_closed_loop(&model, &mut ctl, &sc, &mut filter_rng(seed, r), &mut costs).unwrap();
            discounted_sum(&costs, 0.9)
        })
        .collect();
    let (m, se) = mean_se(&disc);
    (avg, m, se)
}

pub(crate) fn pf_variants() {
    println!("PF greedy variants (N = 200, seed 0): variant | sigma | average (1 run 1e5) | discounted ± se (1000 x 41)");
    for kind in [
        PfGreedy::Stated,
        PfGreedy::OnObservation,
        PfGreedy::Predicted,
        PfGreedy::OneDemand,
        PfGreedy::FilterBlindToOrders,
    ] {
        for sigma in [0.1, 1.5, 3.3] {
            let (a, d, se) = pf_variant(kind, sigma, 0);
            println!("{kind:?} | {sigma} | {a:.3} | {d:.2} ± {se:.2}");
        }
    }
}
