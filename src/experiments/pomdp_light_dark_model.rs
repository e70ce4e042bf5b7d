//! The light-dark problem of thesis 000 §4.7.2: dx = u dt + σ dw on
//! [−2, 2]^d, y = x + G(x) v with G = ε in the light boxes and 1/ε in the
//! dark, and the 2-D instance's light and goal boxes.

use crate::model::{Bounds, Dims, SdeModel};
use beliefbus_pomdp::chain_pomdp::ObservationModel;

/// dx = u dt + σ dw on [−2, 2]^d.
#[derive(Clone, Debug)]
pub struct LightDark {
    pub dim: usize,
    pub sigma: f64,
    bounds: Bounds,
}

impl LightDark {
    pub fn new(dim: usize, sigma: f64) -> Self {
        let bounds = Bounds::new_box(&vec![-2.0; dim], &vec![2.0; dim]).expect("valid box");
        LightDark { dim, sigma, bounds }
    }
}

impl SdeModel for LightDark {
    fn name(&self) -> &str {
        "light-dark"
    }
    fn dims(&self) -> Dims {
        Dims {
            state: self.dim,
            noise: self.dim,
            obs: self.dim,
            control: self.dim,
        }
    }
    fn drift(&self, _x: &[f64], u: &[f64], f: &mut [f64]) {
        f.copy_from_slice(u);
    }
    fn diffusion(&self, _x: &[f64], big_f: &mut [f64]) {
        big_f.fill(0.0);
        for i in 0..self.dim {
            big_f[i + i * self.dim] = self.sigma;
        }
    }
    fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
        g.copy_from_slice(x);
    }
    fn obs_std(&self, std: &mut [f64]) {
        std.fill(1.0);
    }
    fn bounds(&self) -> &Bounds {
        &self.bounds
    }
}

/// Boxes |x − c|_∞ < e.
#[derive(Clone, Debug)]
pub struct Boxes(pub Vec<(Vec<f64>, f64)>);

impl Boxes {
    pub fn contains(&self, x: &[f64]) -> bool {
        self.0
            .iter()
            .any(|(c, e)| c.iter().zip(x).all(|(c, x)| (x - c).abs() < *e))
    }
}

/// y = x + G(x) v with G = ε in the light, 1/ε in the dark.
pub struct LightDarkObs {
    pub light: Boxes,
    pub eps: f64,
}

impl ObservationModel for LightDarkObs {
    fn log_likelihood(&self, z: &[f64], y: &[f64]) -> f64 {
        let s = if self.light.contains(z) {
            self.eps
        } else {
            1.0 / self.eps
        };
        let q: f64 = z.iter().zip(y).map(|(a, b)| (a - b) * (a - b)).sum();
        -0.5 * q / (s * s) - z.len() as f64 * s.ln()
    }
}

/// The 2-D light boxes: beacons (±1.4, ±1.4), half-width 1.2.
pub fn light_2d() -> Boxes {
    Boxes(vec![(vec![1.4, 1.4], 1.2), (vec![-1.4, -1.4], 1.2)])
}

/// The 2-D goal: |x − (1.5, −1.5)|_∞ < 0.2.
pub fn goal_2d() -> Boxes {
    Boxes(vec![(vec![1.5, -1.5], 0.2)])
}

/// The 2-D chain's fixed states (flat x, y pairs) before the uniform
/// samples: the goal's centre; with `cross` also the four points at the
/// goal's half-width along each axis (the centre's Voronoi cell then lies
/// within half of it, so a cell-averaged goal reward is the full reward
/// there whatever the samples); with `edges` (moment rows) states every
/// 0.5 along the box's edges, so that the states' hull is the box and every
/// row's mean is the clamped z + u h — a point on an edge can only be a
/// mixture of states on that edge (with the corners alone, one 3.5 away;
/// without edge states the chain stops at its outermost samples where the
/// system stops at the wall).
pub fn seed_states_2d(edges: bool, cross: bool, goal: &Boxes) -> Vec<f64> {
    let (g, e) = &goal.0[0];
    let mut pts = g.clone();
    if cross {
        for (i, sign) in [(0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0)] {
            let mut x = g.clone();
            x[i] += sign * e;
            pts.extend(x);
        }
    }
    if edges {
        for k in 0..8 {
            let t = -2.0 + 0.5 * k as f64;
            pts.extend([t, -2.0, 2.0, t, -t, 2.0, -2.0, -t]);
        }
    }
    pts
}
