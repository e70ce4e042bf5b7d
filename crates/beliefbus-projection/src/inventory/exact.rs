//! Exact full-observation dynamic programming for the inventory model on a
//! fine lattice: the reference the simulated tables are judged against.
//!
//! The inventory x lives on the lattice x = i·d, i = 0..=M. The demand is
//! the exponential (mean β) rounded to the nearest lattice multiple,
//!
//! ```text
//! P(u = 0)  = 1 − e^{−d/(2β)}
//! P(u = kd) = e^{−(k−½)d/β} (1 − e^{−d/β}),   k ≥ 1,
//! ```
//!
//! whose mean is β up to O(d²), and lost sales put the whole tail
//! P(u ≥ (m−½)d) on x' = 0 from the post-order level z = m·d. The stage
//! cost is the exact E_u[g(x, a, u)] of the continuous demand
//! ([`Inventory::expected_cost`]), so the lattice errs only through the
//! transition, by O(d²). The geometric tail makes E[V(x') | z] and the
//! push-forward of a distribution O(M) each by one running sum, so
//! stationary distributions, finite-horizon values and relative value
//! iteration over M ≈ 10⁴ states take milliseconds.

use super::Inventory;
use crate::ProjectionError;

/// The lattice model.
#[derive(Clone, Debug)]
pub struct Lattice {
    model: Inventory,
    d: f64,
    /// Top state index M.
    top: usize,
    /// Q / d.
    q_steps: usize,
    /// e^{−d/β}.
    r: f64,
    /// P(u = 0).
    p0: f64,
    /// (1 − r) e^{d/(2β)}: p_k = this · r^k for k ≥ 1.
    scale: f64,
}

impl Lattice {
    /// Lattice step `d` on [0, `x_max`]; Q must be a multiple of d and
    /// x_max > Q (orders that would leave the lattice are not allowed).
    pub fn new(model: &Inventory, d: f64, x_max: f64) -> Result<Self, ProjectionError> {
        let q_steps = (model.q / d).round();
        if !(d > 0.0 && d.is_finite()) || (q_steps * d - model.q).abs() > 1e-9 * model.q {
            return Err(ProjectionError::invalid(
                "lattice step",
                format!("d = {d}: need d > 0 dividing Q = {}", model.q),
            ));
        }
        if !(x_max > model.q && x_max.is_finite()) {
            return Err(ProjectionError::invalid(
                "lattice top",
                format!("x_max = {x_max}: need a finite x_max > Q = {}", model.q),
            ));
        }
        let b = model.demand_mean;
        let r = (-d / b).exp();
        Ok(Self {
            model: model.clone(),
            d,
            top: (x_max / d).round() as usize,
            q_steps: q_steps as usize,
            r,
            p0: 1.0 - (-d / (2.0 * b)).exp(),
            scale: (1.0 - r) * (d / (2.0 * b)).exp(),
        })
    }

    /// Number of states M + 1.
    pub fn len(&self) -> usize {
        self.top + 1
    }

    /// Never empty (x_max > Q > 0).
    pub fn is_empty(&self) -> bool {
        false
    }

    /// The inventory of state i.
    #[inline]
    pub fn x(&self, i: usize) -> f64 {
        i as f64 * self.d
    }

    /// The state nearest to x (clamped to the lattice).
    pub fn index(&self, x: f64) -> usize {
        ((x / self.d).round().max(0.0) as usize).min(self.top)
    }

    /// Post-order index of action a at state i, None if it leaves the lattice.
    #[inline]
    fn post(&self, i: usize, a: usize) -> Option<usize> {
        let z = i + a * self.q_steps;
        (z <= self.top).then_some(z)
    }

    /// P(u ≥ (m − ½)d): the lost-sales mass sent to x' = 0 from z = m·d.
    #[inline]
    fn tail(&self, m: usize) -> f64 {
        if m == 0 {
            1.0
        } else {
            (-(m as f64 - 0.5) * self.d / self.model.demand_mean).exp()
        }
    }

    /// out[m] = E[v(x') | z = m·d] for every post-order index m.
    pub fn expect_next(&self, v: &[f64], out: &mut [f64]) {
        let mut acc = 0.0; // Σ_{k=1}^{m−1} r^k v(m−k)
        for m in 0..=self.top {
            out[m] = if m == 0 {
                v[0]
            } else {
                self.p0 * v[m] + self.scale * acc + self.tail(m) * v[0]
            };
            if m >= 1 {
                acc = self.r * (acc + v[m]);
            }
        }
    }

    /// The distribution of x' from the distribution `z_mass` of z.
    pub fn push(&self, z_mass: &[f64], out: &mut [f64]) {
        let mut back = 0.0; // Σ_{m>j} z_mass[m] r^{m−j}
        let mut zero = z_mass[0];
        for j in (1..=self.top).rev() {
            out[j] = self.p0 * z_mass[j] + self.scale * back;
            back = self.r * (z_mass[j] + back);
            zero += z_mass[j] * self.tail(j);
        }
        out[0] = zero;
    }

    /// The stage cost E_u[g] at post-order index z (action folded into z).
    #[inline]
    fn stage(&self, z: usize) -> f64 {
        self.model.expected_cost(self.x(z), 0)
    }

    /// Post-order indices of a stationary policy `act(x)`.
    fn posts(&self, act: &dyn Fn(f64) -> usize) -> Result<Vec<usize>, ProjectionError> {
        (0..=self.top)
            .map(|i| {
                self.post(i, act(self.x(i))).ok_or_else(|| {
                    ProjectionError::invalid(
                        "lattice policy",
                        format!("orders at x = {} beyond the lattice top", self.x(i)),
                    )
                })
            })
            .collect()
    }

    /// Long-run average cost of the stationary policy `act` (stationary
    /// distribution by power iteration from x_0, to ‖Δπ‖₁ < 1e-14).
    pub fn average_cost(&self, act: &dyn Fn(f64) -> usize) -> Result<f64, ProjectionError> {
        let z = self.posts(act)?;
        let n = self.len();
        let (mut pi, mut zm, mut next) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        pi[self.index(self.model.x0)] = 1.0;
        for _ in 0..100_000 {
            zm.iter_mut().for_each(|v| *v = 0.0);
            for (i, &p) in pi.iter().enumerate() {
                zm[z[i]] += p;
            }
            self.push(&zm, &mut next);
            let diff: f64 = pi.iter().zip(&next).map(|(a, b)| (a - b).abs()).sum();
            std::mem::swap(&mut pi, &mut next);
            if diff < 1e-14 {
                break;
            }
        }
        Ok(pi.iter().zip(&z).map(|(p, &zi)| p * self.stage(zi)).sum())
    }

    /// E Σ_{k<periods} γ^k g_k of the stationary policy `act` from x_0.
    pub fn discounted_cost(
        &self,
        act: &dyn Fn(f64) -> usize,
        gamma: f64,
        periods: usize,
    ) -> Result<f64, ProjectionError> {
        let z = self.posts(act)?;
        let n = self.len();
        let (mut v, mut ev) = (vec![0.0; n], vec![0.0; n]);
        for _ in 0..periods {
            self.expect_next(&v, &mut ev);
            for (i, vi) in v.iter_mut().enumerate() {
                *vi = self.stage(z[i]) + gamma * ev[z[i]];
            }
        }
        Ok(v[self.index(self.model.x0)])
    }

    /// One Bellman step over both actions: (value, action) at state i.
    #[inline]
    fn best(&self, i: usize, ev: &[f64], gamma: f64) -> (f64, usize) {
        let mut best = (f64::INFINITY, 0);
        for a in 0..2 {
            if let Some(z) = self.post(i, a) {
                let q = self.stage(z) + gamma * ev[z];
                if q < best.0 {
                    best = (q, a);
                }
            }
        }
        best
    }

    /// The optimal finite-horizon E Σ_{k<periods} γ^k g_k from x_0 (the
    /// optimum over all policies, time-varying ones included).
    pub fn optimal_discounted(&self, gamma: f64, periods: usize) -> f64 {
        let n = self.len();
        let (mut v, mut ev) = (vec![0.0; n], vec![0.0; n]);
        for _ in 0..periods {
            self.expect_next(&v, &mut ev);
            for (i, vi) in v.iter_mut().enumerate() {
                *vi = self.best(i, &ev, gamma).0;
            }
        }
        v[self.index(self.model.x0)]
    }

    /// The optimal average cost over all stationary policies by relative
    /// value iteration (stops when the span of T h − h is below `eps`),
    /// and the optimal policy's order region as its largest ordering state
    /// (the policy is a threshold: order iff x ≤ that state).
    pub fn optimal_average(&self, eps: f64) -> Result<(f64, f64), ProjectionError> {
        let n = self.len();
        let (mut h, mut ev, mut th) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        for _ in 0..1_000_000 {
            self.expect_next(&h, &mut ev);
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for i in 0..n {
                th[i] = self.best(i, &ev, 1.0).0;
                lo = lo.min(th[i] - h[i]);
                hi = hi.max(th[i] - h[i]);
            }
            let base = th[0];
            for (hi_, t) in h.iter_mut().zip(&th) {
                *hi_ = t - base;
            }
            if hi - lo < eps {
                self.expect_next(&h, &mut ev);
                let last = (0..n)
                    .filter(|&i| self.best(i, &ev, 1.0).1 == 1)
                    .max()
                    .map_or(f64::NAN, |i| self.x(i));
                return Ok((0.5 * (lo + hi), last));
            }
        }
        Err(ProjectionError::invalid(
            "relative value iteration",
            "no convergence in 10^6 sweeps",
        ))
    }
}

/// The myopic rule of paper §VI on a known state, argmin_a E_u[g(x, a, u)],
/// is a threshold: E_u[g(x + Q)] − E_u[g(x)] = Qh − (h+s)βe^{−x/β}(1 − e^{−Q/β})
/// for x ≥ 0, negative iff x < β ln((h+s)β(1 − e^{−Q/β}) / (Qh)).
pub fn myopic_threshold(model: &Inventory) -> f64 {
    let (h, s, q, b) = (model.h, model.s, model.q, model.demand_mean);
    b * ((h + s) * b * (1.0 - (-q / b).exp()) / (q * h)).ln()
}
