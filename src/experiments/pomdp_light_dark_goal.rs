//! The terminal reward per chain state averaged over the region the state
//! stands for (`--param goal_reward=cell`), instead of the reward at the
//! state's own point (`state`, the thesis's):
//!
//! ```text
//! R(z_i) = (1/|V_i|) ∫_{V_i} r(x) dx,   r = +1000 in the goal, −1000 elsewhere,
//! V_i = {x in the box : z_i is the nearest state}                 (the Voronoi cell)
//! ```
//!
//! by the midpoint rule on a regular grid of the box. With rows that
//! split a move's mass between the states around its target (moment rows),
//! "the chain is at z_i" means "the truth is near z_i", not "at z_i": on a
//! coarse chain the goal's state stands for a region larger than the goal,
//! and the point reward pays +1000 for a belief that in the continuous
//! system is in the goal only part of the time. The cell average pays what
//! such a declaration is worth, so a coarse chain is not rewarded for its
//! coarseness.

use super::Boxes;

/// R(z_i) of the module doc for the flat `states` (n × d) in [lo, hi]^d,
/// `per_axis` midpoints per axis; a state with an empty cell keeps its
/// point reward.
pub fn cell_rewards(
    states: &[f64],
    d: usize,
    goal: &Boxes,
    lo: f64,
    hi: f64,
    per_axis: usize,
) -> Vec<f64> {
    let n = states.len() / d;
    let mut inside = vec![0usize; n];
    let mut count = vec![0usize; n];
    let step = (hi - lo) / per_axis as f64;
    let total = per_axis.pow(d as u32);
    let mut x = vec![0.0; d];
    for g in 0..total {
        let mut rest = g;
        for xc in x.iter_mut() {
            *xc = lo + (rest % per_axis) as f64 * step + 0.5 * step;
            rest /= per_axis;
        }
        let near = (0..n)
            .min_by(|&a, &b| {
                dist2(&states[a * d..(a + 1) * d], &x)
                    .total_cmp(&dist2(&states[b * d..(b + 1) * d], &x))
            })
            .unwrap_or(0);
        count[near] += 1;
        inside[near] += usize::from(goal.contains(&x));
    }
    (0..n)
        .map(|i| {
            if count[i] == 0 {
                if goal.contains(&states[i * d..(i + 1) * d]) {
                    1000.0
                } else {
                    -1000.0
                }
            } else {
                1000.0 * (2.0 * inside[i] as f64 / count[i] as f64 - 1.0)
            }
        })
        .collect()
}

fn dist2(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(p, q)| (p - q) * (p - q)).sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngExt;

    #[test]
    fn cells_of_random_states_match_a_monte_carlo_estimate_of_the_goals_share() {
        // Irregular states as the 2-D chain has them (uniform samples, a
        // few inside and on the border of the goal): each cell's share of
        // the goal estimated independently from uniform random points
        // (not the midpoint grid), within 4.5 binomial standard errors
        // plus the grid's own error (a cell's boundary cut by the grid).
        let mut rng = crate::rng::stream(11, 0);
        let goal = Boxes(vec![(vec![1.5, -1.5], 0.2)]);
        let mut pts: Vec<f64> = vec![1.5, -1.5, 1.341, -1.554, 1.69, -1.31];
        for _ in 0..57 {
            pts.push(rng.random_range(-2.0..2.0));
            pts.push(rng.random_range(-2.0..2.0));
        }
        let n = pts.len() / 2;
        let r = cell_rewards(&pts, 2, &goal, -2.0, 2.0, 400);
        let (mut inside, mut count) = (vec![0usize; n], vec![0usize; n]);
        for _ in 0..400_000 {
            let x = [rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0)];
            let near = (0..n)
                .min_by(|&a, &b| {
                    dist2(&pts[2 * a..2 * a + 2], &x).total_cmp(&dist2(&pts[2 * b..2 * b + 2], &x))
                })
                .unwrap();
            count[near] += 1;
            inside[near] += usize::from(goal.contains(&x));
        }
        let mut partial = 0;
        for i in 0..n {
            let f = inside[i] as f64 / count[i] as f64;
            let se = (f * (1.0 - f) / count[i] as f64).sqrt();
            let cell = (r[i] / 1000.0 + 1.0) / 2.0;
            assert!(
                (cell - f).abs() < 4.5 * se + 0.01,
                "state {i} ({}, {}): grid share {cell}, Monte Carlo {f} ± {se}",
                pts[2 * i],
                pts[2 * i + 1]
            );
            partial += usize::from(f > 0.05 && f < 0.95);
        }
        // The states near the goal's border stand for regions partly
        // outside it: their reward is well below the point reward's 1000.
        assert!(partial >= 2, "{partial} cells straddle the goal");
        assert!(
            r[1] < 600.0 && r[2] < 600.0,
            "border states: {} {}",
            r[1],
            r[2]
        );
    }

    #[test]
    fn cells_of_a_regular_grid_average_the_reward_exactly() {
        // 1-D grid −1.9, …, 1.9: the cell of −0.9 is (−1.0, −0.8), the goal
        // itself (+1000); every other cell lies outside (−1000).
        let pts: Vec<f64> = (0..20).map(|i| -1.9 + 0.2 * i as f64).collect();
        let goal = Boxes(vec![(vec![-0.9], 0.1)]);
        let r = cell_rewards(&pts, 1, &goal, -2.0, 2.0, 4000);
        for (i, v) in r.iter().enumerate() {
            let expect = if i == 5 { 1000.0 } else { -1000.0 };
            assert!((v - expect).abs() < 1.0, "state {i}: {v}");
        }
        // A 2-D state at the goal's corner: a quarter of its square cell
        // (side 0.4 on a 10 × 10 grid of [−2, 2]²) is inside a goal of
        // half-width 0.2 centred at the cell's corner: R = 1000(2 · 1/4 − 1)
        // = −500.
        let g: Vec<f64> = (0..10).map(|i| -1.8 + 0.4 * i as f64).collect();
        let pts: Vec<f64> = g
            .iter()
            .flat_map(|&a| g.iter().flat_map(move |&b| [a, b]))
            .collect();
        let goal = Boxes(vec![(vec![0.0, 0.0], 0.2)]);
        let r = cell_rewards(&pts, 2, &goal, -2.0, 2.0, 400);
        for (i, v) in r.iter().enumerate() {
            let (a, b) = (pts[2 * i], pts[2 * i + 1]);
            let expect = if a.abs() < 0.3 && b.abs() < 0.3 {
                -500.0
            } else {
                -1000.0
            };
            assert!((v - expect).abs() < 1.0, "state ({a}, {b}): {v}");
        }
    }
}
