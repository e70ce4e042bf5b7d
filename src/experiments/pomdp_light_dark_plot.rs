//! The 1-D light-dark belief trajectory (thesis Fig. 4-6): belief mass per
//! state (grey) against decision step, the true state (blue), the light
//! (green) and the goal (red) bands, and the seeded run it draws.

use super::ChainPomdp;
use crate::rng::{self, SimRng};
use anyhow::{Context, Result};
use beliefbus_pomdp::AlphaPolicy;
use plotters::prelude::*;
use rand::RngExt;
use std::path::Path;

/// Whether the true state entered the light before the terminal action
/// (taken inside the goal).
pub fn visits_light_before_goal(cp: &ChainPomdp, traj: &[Step]) -> bool {
    let in_light = |s: usize| s < cp.n_chain() && (cp.state(s)[0] - 0.9).abs() < 0.1;
    let Some(first_light) = traj.iter().position(|st| in_light(st.state)) else {
        return false;
    };
    let Some(last) = traj.last() else {
        return false;
    };
    let declared = cp.control(last.action).is_none();
    let in_goal = last.state < cp.n_chain() && (cp.state(last.state)[0] + 0.9).abs() < 0.1;
    declared && in_goal && first_light + 1 < traj.len()
}

pub fn write(path: &Path, cp: &ChainPomdp, traj: &[Step]) -> Result<()> {
    let mut svg = String::new();
    {
        let err = |e: &dyn std::fmt::Debug| anyhow::anyhow!("{e:?}");
        let root = SVGBackend::with_string(&mut svg, (1000, 520)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let steps = traj.len().max(1) as f64;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                "light-dark 1-D: belief over the 20 chain states per decision (thesis Fig. 4-6)",
                ("sans-serif", 18),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(50)
            .build_cartesian_2d(-0.5..steps, -2.0..2.0)
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .x_desc("decision step")
            .y_desc("x")
            .draw()
            .map_err(|e| err(&e))?;
        let band = |c: f64, e: f64, color: RGBColor| {
            Rectangle::new([(-0.5, c - e), (steps, c + e)], color.mix(0.25).filled())
        };
        chart
            .draw_series([band(0.9, 0.1, GREEN), band(-0.9, 0.1, RED)])
            .map_err(|e| err(&e))?;
        let n = cp.n_chain();
        for (k, st) in traj.iter().enumerate() {
            let cells = (0..n).filter(|&z| st.belief[z] > 1e-3).map(|z| {
                let x = cp.state(z)[0];
                let w = st.belief[z].min(1.0);
                Rectangle::new(
                    [(k as f64 - 0.4, x - 0.1), (k as f64 + 0.4, x + 0.1)],
                    BLACK.mix(0.1 + 0.8 * w).filled(),
                )
            });
            chart.draw_series(cells).map_err(|e| err(&e))?;
        }
        let truth: Vec<(f64, f64)> = traj
            .iter()
            .enumerate()
            .filter(|(_, st)| st.state < n)
            .map(|(k, st)| (k as f64, cp.state(st.state)[0]))
            .collect();
        chart
            .draw_series(LineSeries::new(truth, BLUE.stroke_width(2)))
            .map_err(|e| err(&e))?;
        root.present().map_err(|e| err(&e))?;
    }
    beliefbus_rt::files::replace_file(path, svg.as_bytes())
        .with_context(|| format!("writing {}", path.display()))
}

/// One step of a seeded discrete run: true state, belief, action taken.
#[derive(Clone, Debug)]
pub struct Step {
    pub state: usize,
    pub belief: Vec<f64>,
    pub action: usize,
}

/// A seeded run of `policy` on the discrete POMDP until the terminal
/// action (or `max_steps`).
pub fn trajectory(cp: &ChainPomdp, policy: &AlphaPolicy, seed: u64, max_steps: usize) -> Vec<Step> {
    let p = &cp.pomdp;
    let mut rng: SimRng = rng::stream(seed, 0x7a);
    let draw = |rng: &mut SimRng, items: &mut dyn Iterator<Item = (usize, f64)>| {
        let u: f64 = rng.random();
        let mut acc = 0.0;
        let mut last = 0;
        for (i, q) in items {
            acc += q;
            last = i;
            if u < acc {
                return i;
            }
        }
        last
    };
    let mut s = draw(&mut rng, &mut p.start.iter().copied().enumerate());
    let mut b = p.start.clone();
    let mut pred = vec![0.0; b.len()];
    let mut out = Vec::new();
    for _ in 0..max_steps {
        let a = policy.actions[policy.best_dense(&b).0];
        out.push(Step {
            state: s,
            belief: b.clone(),
            action: a,
        });
        if cp.control(a).is_none() {
            break;
        }
        let (cols, vals) = p.trans[a].row(s);
        s = draw(
            &mut rng,
            &mut cols.iter().map(|&c| c as usize).zip(vals.iter().copied()),
        );
        let (os, qs) = p.obs[a].row(s);
        let o = draw(
            &mut rng,
            &mut os.iter().map(|&c| c as usize).zip(qs.iter().copied()),
        );
        cp.predict(&b, a, &mut pred);
        let mut total = 0.0;
        for (z, v) in pred.iter_mut().enumerate() {
            *v *= p.obs[a].get(z, o);
            total += *v;
        }
        if total > 0.0 {
            pred.iter_mut().for_each(|v| *v /= total);
            std::mem::swap(&mut b, &mut pred);
        }
    }
    out
}
