//! The drifting ship (paper 001 eq. 10–11; thesis §3.4.1, eq. 3.12–3.13,
//! after Kushner & Budhiraja), extended with a control force on the velocity
//! states for the closed-loop pipeline:
//!
//! ```text
//! dx1 = x3 dt + e dw1            dx3 = (f1(x) + u1) dt + e dw3
//! dx2 = x4 dt + e dw2            dx4 = (f2(x) + u2) dt + e dw4
//! f_i(x) = −K x_i/ρ · 1{ρ ≥ R} · 1{x1 x3 + x2 x4 ≥ 0},   ρ = √(x1² + x2²)
//! y1 = ρ + σ_r v1,    y2 = atan2(x2, x1) + σ_b v2
//! ```
//!
//! The paper's numbers: e = 0.3, e1 = e2 = 0.03 (continuous observation
//! coefficients), K = 50, disc radius R = 9. Choices the paper leaves open,
//! documented here and in `configs/`:
//! - bearing is `atan2(x2, x1)` instead of the printed `tan⁻¹(x2/x1)`, which
//!   cannot tell opposite quadrants apart; residuals are wrapped to (−π, π];
//! - sampled sensor σ = e_i/√Δ for a sensor period Δ (see
//!   [`super::continuous_obs_std`]), e.g. 0.3 at 100 Hz;
//! - velocities are bounded to [−v_max, v_max] (default 4) for the chain's
//!   compact set S; positions to the disc.

use super::{Bounds, Dims, SdeJacobians, SdeModel};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Parameters of the drifting ship.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ShipParams {
    /// Process-noise coefficient e on every state.
    pub e: f64,
    /// σ of one sampled range measurement.
    pub range_std: f64,
    /// σ of one sampled bearing measurement (radians).
    pub bearing_std: f64,
    /// Disc radius R at which the wall force acts.
    pub radius: f64,
    /// Wall force gain K (50 in the paper).
    pub wall_gain: f64,
    /// Velocity bound of the compact set S.
    pub v_max: f64,
}

impl ShipParams {
    /// The paper's parameters with the continuous observation noise
    /// e1 = e2 = 0.03 sampled every `sample_dt` seconds.
    pub fn paper(sample_dt: f64) -> Self {
        Self {
            e: 0.3,
            range_std: super::continuous_obs_std(0.03, sample_dt),
            bearing_std: super::continuous_obs_std(0.03, sample_dt),
            radius: 9.0,
            wall_gain: 50.0,
            v_max: 4.0,
        }
    }
}

/// The drifting ship model.
#[derive(Clone, Debug)]
pub struct Ship {
    pub params: ShipParams,
    bounds: Bounds,
}

impl Ship {
    /// Build the model; the parameters must be positive and finite.
    pub fn new(params: ShipParams) -> Result<Self, String> {
        let p = &params;
        for (name, v) in [
            ("e", p.e),
            ("range_std", p.range_std),
            ("bearing_std", p.bearing_std),
            ("radius", p.radius),
            ("v_max", p.v_max),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("ship.{name} must be positive and finite, got {v}"));
            }
        }
        if !(p.wall_gain.is_finite() && p.wall_gain >= 0.0) {
            return Err(format!(
                "ship.wall_gain must be non-negative, got {}",
                p.wall_gain
            ));
        }
        let r = p.radius;
        let v = p.v_max;
        let bounds = Bounds::new_box(&[-r, -r, -v, -v], &[r, r, v, v])
            .and_then(|b| b.with_disc((0, 1), r))
            .map_err(|e| e.to_string())?;
        Ok(Self { params, bounds })
    }

    /// The wall force (f1, f2) at x.
    ///
    /// Compares ρ² against R² and takes the square root only beyond the wall:
    /// `hypot` costs as much as a whole MPPI rollout step, and the drift is
    /// the innermost loop of every sampler.
    #[inline]
    pub fn wall_force(&self, x: &[f64]) -> (f64, f64) {
        let r = self.params.radius;
        let rho2 = x[0] * x[0] + x[1] * x[1];
        if rho2 >= r * r && x[0] * x[2] + x[1] * x[3] >= 0.0 {
            let k = -self.params.wall_gain / rho2.sqrt();
            (k * x[0], k * x[1])
        } else {
            (0.0, 0.0)
        }
    }
}

/// Wrap an angle to (−π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let mut w = (a + PI).rem_euclid(2.0 * PI) - PI;
    if w <= -PI {
        w += 2.0 * PI;
    }
    w
}

impl SdeModel for Ship {
    fn name(&self) -> &str {
        "ship"
    }
    fn dims(&self) -> Dims {
        Dims {
            state: 4,
            noise: 4,
            obs: 2,
            control: 2,
        }
    }
    #[inline]
    fn drift(&self, x: &[f64], u: &[f64], f: &mut [f64]) {
        let (f1, f2) = self.wall_force(x);
        let (u1, u2) = if u.len() >= 2 {
            (u[0], u[1])
        } else {
            (0.0, 0.0)
        };
        f[0] = x[2];
        f[1] = x[3];
        f[2] = f1 + u1;
        f[3] = f2 + u2;
    }
    /// The same drift for n states (SoA, see [`SdeModel::drift_soa`]),
    /// branch-free so that the loop over k vectorises: the wall force is
    /// computed for every state and selected where ρ² ≥ R² and ẋ·x ≥ 0.
    #[inline(always)]
    fn drift_soa(&self, n: usize, x: &[f64], u: &[f64], f: &mut [f64]) {
        let (r2, gain) = (
            self.params.radius * self.params.radius,
            self.params.wall_gain,
        );
        let (x1, rest) = x.split_at(n);
        let (x2, rest) = rest.split_at(n);
        let (x3, x4) = rest.split_at(n);
        let (u1, u2) = u.split_at(n);
        let (f1, rest) = f.split_at_mut(n);
        let (f2, rest) = rest.split_at_mut(n);
        let (f3, f4) = rest.split_at_mut(n);
        let (x4, u2, f4) = (&x4[..n], &u2[..n], &mut f4[..n]);
        for k in 0..n {
            let (a, b, va, vb) = (x1[k], x2[k], x3[k], x4[k]);
            let rho2 = a * a + b * b;
            let out = rho2 >= r2 && a * va + b * vb >= 0.0;
            // max(·, R²) keeps the root finite where the force is unused.
            let g = if out {
                -gain / rho2.max(r2).sqrt()
            } else {
                0.0
            };
            f1[k] = va;
            f2[k] = vb;
            f3[k] = g * a + u1[k];
            f4[k] = g * b + u2[k];
        }
    }
    fn diffusion(&self, _x: &[f64], big_f: &mut [f64]) {
        big_f[..16].fill(0.0);
        for i in 0..4 {
            big_f[i + 4 * i] = self.params.e;
        }
    }
    #[inline]
    fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
        // Positions are bounded by the disc, so the plain root cannot overflow.
        g[0] = (x[0] * x[0] + x[1] * x[1]).sqrt();
        g[1] = x[1].atan2(x[0]);
    }
    fn obs_std(&self, std: &mut [f64]) {
        std[0] = self.params.range_std;
        std[1] = self.params.bearing_std;
    }
    fn obs_residual(&self, y: &[f64], yhat: &[f64], r: &mut [f64]) {
        r[0] = y[0] - yhat[0];
        r[1] = wrap_angle(y[1] - yhat[1]);
    }
    fn bounds(&self) -> &Bounds {
        &self.bounds
    }
}

impl SdeJacobians for Ship {
    fn drift_jacobian(&self, x: &[f64], _u: &[f64], jac: &mut [f64]) {
        jac[..16].fill(0.0);
        jac[2 * 4] = 1.0; // ∂f1/∂x3
        jac[1 + 3 * 4] = 1.0; // ∂f2/∂x4
        let rho = x[0].hypot(x[1]);
        if rho >= self.params.radius && x[0] * x[2] + x[1] * x[3] >= 0.0 {
            // f_i = −K x_i/ρ: ∂f_i/∂x_j = −K (δ_ij/ρ − x_i x_j/ρ³), i,j ∈ {1,2}.
            let k = self.params.wall_gain;
            let r3 = rho * rho * rho;
            for i in 0..2 {
                for j in 0..2 {
                    let delta = if i == j { 1.0 } else { 0.0 };
                    jac[(i + 2) + j * 4] = -k * (delta / rho - x[i] * x[j] / r3);
                }
            }
        }
    }
    fn obs_jacobian(&self, x: &[f64], jac: &mut [f64]) {
        let r2 = x[0] * x[0] + x[1] * x[1];
        let r = r2.sqrt().max(1e-12);
        let r2 = r2.max(1e-24);
        jac[..8].fill(0.0);
        // column-major 2×4: jac[i + 2 j]
        jac[0] = x[0] / r;
        jac[2] = x[1] / r;
        jac[1] = -x[1] / r2;
        jac[3] = x[0] / r2;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fd_check(ship: &Ship, x: &[f64]) {
        struct Fd<'a>(&'a Ship);
        impl SdeModel for Fd<'_> {
            fn name(&self) -> &str {
                "fd"
            }
            fn dims(&self) -> Dims {
                self.0.dims()
            }
            fn drift(&self, x: &[f64], u: &[f64], f: &mut [f64]) {
                self.0.drift(x, u, f)
            }
            fn diffusion(&self, x: &[f64], f: &mut [f64]) {
                self.0.diffusion(x, f)
            }
            fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
                self.0.obs_mean(x, g)
            }
            fn obs_std(&self, s: &mut [f64]) {
                self.0.obs_std(s)
            }
            fn obs_residual(&self, y: &[f64], yh: &[f64], r: &mut [f64]) {
                self.0.obs_residual(y, yh, r)
            }
            fn bounds(&self) -> &Bounds {
                self.0.bounds()
            }
        }
        impl SdeJacobians for Fd<'_> {}
        let fd = Fd(ship);
        let (mut a, mut b) = ([0.0; 16], [0.0; 16]);
        ship.drift_jacobian(x, &[0.0, 0.0], &mut a);
        fd.drift_jacobian(x, &[0.0, 0.0], &mut b);
        for i in 0..16 {
            assert!(
                (a[i] - b[i]).abs() < 1e-5,
                "drift jac {i}: {} vs {}",
                a[i],
                b[i]
            );
        }
        let (mut a, mut b) = ([0.0; 8], [0.0; 8]);
        ship.obs_jacobian(x, &mut a);
        fd.obs_jacobian(x, &mut b);
        for i in 0..8 {
            assert!(
                (a[i] - b[i]).abs() < 1e-6,
                "obs jac {i}: {} vs {}",
                a[i],
                b[i]
            );
        }
    }

    #[test]
    fn analytic_jacobians_match_finite_differences() {
        let ship = Ship::new(ShipParams::paper(0.01)).unwrap();
        fd_check(&ship, &[3.0, -2.0, 0.5, 0.1]);
        fd_check(&ship, &[-7.0, 6.5, -1.0, 1.0]); // outside the wall, moving out
        fd_check(&ship, &[-1.0, -0.5, 0.0, 0.0]);
    }

    #[test]
    fn wall_pushes_back_only_when_moving_outward() {
        let ship = Ship::new(ShipParams::paper(0.01)).unwrap();
        let mut f = [0.0; 4];
        ship.drift(&[9.5, 0.0, 1.0, 0.0], &[0.0, 0.0], &mut f);
        assert!((f[2] + 50.0).abs() < 1e-12 && f[3] == 0.0);
        ship.drift(&[9.5, 0.0, -1.0, 0.0], &[0.0, 0.0], &mut f);
        assert_eq!(f[2], 0.0);
    }

    #[test]
    fn bearing_residual_wraps() {
        let ship = Ship::new(ShipParams::paper(0.01)).unwrap();
        let mut r = [0.0; 2];
        ship.obs_residual(&[1.0, PI - 0.01], &[1.0, -PI + 0.01], &mut r);
        assert!((r[1] + 0.02).abs() < 1e-12);
        assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-12);
    }
    #[test]
    fn batched_drift_equals_the_per_state_drift() {
        use rand::RngExt;
        let ship = Ship::new(ShipParams::paper(0.01)).unwrap();
        let mut rng = crate::rng::stream(3, 0);
        // Odd n so no lane count divides it; states on both sides of the wall.
        let n = 37;
        let mut x = vec![0.0; 4 * n];
        let mut u = vec![0.0; 2 * n];
        for v in x.iter_mut() {
            *v = rng.random_range(-12.0..12.0);
        }
        for v in u.iter_mut() {
            *v = rng.random_range(-3.0..3.0);
        }
        let mut f = vec![0.0; 4 * n];
        ship.drift_soa(n, &x, &u, &mut f);
        let mut outside = 0;
        for k in 0..n {
            let xk = [x[k], x[n + k], x[2 * n + k], x[3 * n + k]];
            let mut fk = [0.0; 4];
            ship.drift(&xk, &[u[k], u[n + k]], &mut fk);
            if ship.wall_force(&xk) != (0.0, 0.0) {
                outside += 1;
            }
            for i in 0..4 {
                assert_eq!(f[i * n + k], fk[i], "state {k}, component {i}");
            }
        }
        assert!(outside > 0, "no state exercised the wall force");
    }
}
