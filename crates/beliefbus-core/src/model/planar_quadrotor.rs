//! A planar quadrotor (a rigid body in the vertical plane; thrust along
//! its body axis, a torque about its centre), noise on the velocities only:
//!
//! ```text
//! dx  = vx dt                     dvx = −(u₁/m) sin θ dt + σ dw₁
//! dz  = vz dt                     dvz = ( (u₁/m) cos θ − g) dt + σ dw₂
//! dθ  = ω dt                      dω  = (u₂/J) dt + σ dw₃
//! y   = (x, z) + N(0, σ_y² I)
//! ```
//!
//! State (x, z, θ, vx, vz, ω), control (u₁ thrust, u₂ torque). F Fᵀ is
//! singular (zero on x, z, θ): the chain filter needs the degenerate
//! construction of [`crate::chain::degenerate`]. The input matrix depends
//! on θ, so the reference control u₀ the chain is built for (the hover
//! thrust u₁ = m g) shapes the chain's drift: at u₀ = 0 (free fall) θ
//! does not act on the velocities at all.

use super::linear::LinearSde;
use super::{Bounds, Dims, SdeJacobians, SdeModel};
use nalgebra::DMatrix;

/// Parameters of the planar quadrotor.
#[derive(Clone, Debug, PartialEq)]
pub struct PlanarQuadrotorParams {
    pub mass: f64,
    pub inertia: f64,
    pub gravity: f64,
    /// Process-noise σ on each velocity.
    pub sigma: f64,
    /// σ of one sampled measurement of x and of z.
    pub obs_std: f64,
    /// Half-widths of S: positions, attitude, linear and angular velocity.
    pub pos_max: f64,
    pub theta_max: f64,
    pub vel_max: f64,
    pub omega_max: f64,
}

impl Default for PlanarQuadrotorParams {
    fn default() -> Self {
        Self {
            mass: 1.0,
            inertia: 0.05,
            gravity: 9.81,
            sigma: 0.3,
            obs_std: 0.1,
            pos_max: 5.0,
            theta_max: 1.0,
            vel_max: 5.0,
            omega_max: 6.0,
        }
    }
}

/// The planar quadrotor model.
#[derive(Clone, Debug)]
pub struct PlanarQuadrotor {
    pub params: PlanarQuadrotorParams,
    bounds: Bounds,
}

impl PlanarQuadrotor {
    /// Build the model; every parameter must be positive and finite.
    pub fn new(params: PlanarQuadrotorParams) -> Result<Self, String> {
        let p = &params;
        for (name, v) in [
            ("mass", p.mass),
            ("inertia", p.inertia),
            ("gravity", p.gravity),
            ("sigma", p.sigma),
            ("obs_std", p.obs_std),
            ("pos_max", p.pos_max),
            ("theta_max", p.theta_max),
            ("vel_max", p.vel_max),
            ("omega_max", p.omega_max),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!(
                    "planar_quadrotor.{name} must be positive and finite, got {v}"
                ));
            }
        }
        let hi = [
            p.pos_max,
            p.pos_max,
            p.theta_max,
            p.vel_max,
            p.vel_max,
            p.omega_max,
        ];
        let lo = hi.map(|v| -v);
        let bounds = Bounds::new_box(&lo, &hi).map_err(|e| e.to_string())?;
        Ok(Self { params, bounds })
    }

    /// The hover control (m g, 0).
    pub fn hover(&self) -> [f64; 2] {
        [self.params.mass * self.params.gravity, 0.0]
    }
}

/// The quadrotor with its attitude held by an inner loop: the translational
/// part (x, z, vx, vz), the control being the net acceleration the held
/// attitude and thrust produce, a = (−(u₁/m) sin θ, (u₁/m) cos θ − g):
///
/// ```text
/// dx = vx dt,   dvx = a_x dt + σ dw₁
/// dz = vz dt,   dvz = a_z dt + σ dw₂,     y = (x, z) + N(0, σ_y² I)
/// ```
///
/// Linear-Gaussian, so its Kalman filter is exact; F Fᵀ is singular (zero on
/// x, z) as for the full model. Bounds: ±`pos_max`, ±`vel_max`.
pub fn attitude_held(params: &PlanarQuadrotorParams) -> Result<LinearSde, String> {
    PlanarQuadrotor::new(params.clone())?;
    let p = params;
    let a = DMatrix::from_row_slice(
        4,
        4,
        &[
            0.0, 0.0, 1.0, 0.0, //
            0.0, 0.0, 0.0, 1.0, //
            0.0, 0.0, 0.0, 0.0, //
            0.0, 0.0, 0.0, 0.0,
        ],
    );
    let b = DMatrix::from_row_slice(4, 2, &[0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0]);
    let f = DMatrix::from_row_slice(4, 2, &[0.0, 0.0, 0.0, 0.0, p.sigma, 0.0, 0.0, p.sigma]);
    let c = DMatrix::from_row_slice(2, 4, &[1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0]);
    let hi = [p.pos_max, p.pos_max, p.vel_max, p.vel_max];
    let bounds = Bounds::new_box(&hi.map(|v| -v), &hi).map_err(|e| e.to_string())?;
    Ok(LinearSde::new(
        "planar_quadrotor_attitude_held",
        a,
        b,
        f,
        c,
        vec![p.obs_std; 2],
        bounds,
    ))
}

impl SdeModel for PlanarQuadrotor {
    fn name(&self) -> &str {
        "planar_quadrotor"
    }
    fn dims(&self) -> Dims {
        Dims {
            state: 6,
            control: 2,
            noise: 3,
            obs: 2,
        }
    }
    fn drift(&self, x: &[f64], u: &[f64], f: &mut [f64]) {
        let p = &self.params;
        let a = u[0] / p.mass;
        f[0] = x[3];
        f[1] = x[4];
        f[2] = x[5];
        f[3] = -a * x[2].sin();
        f[4] = a * x[2].cos() - p.gravity;
        f[5] = u[1] / p.inertia;
    }
    fn diffusion(&self, _x: &[f64], big_f: &mut [f64]) {
        // 6 × 3 column-major: σ on (vx, vz, ω).
        big_f[..18].fill(0.0);
        for j in 0..3 {
            big_f[(3 + j) + j * 6] = self.params.sigma;
        }
    }
    fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
        g[0] = x[0];
        g[1] = x[1];
    }
    fn obs_std(&self, std: &mut [f64]) {
        std[0] = self.params.obs_std;
        std[1] = self.params.obs_std;
    }
    fn bounds(&self) -> &Bounds {
        &self.bounds
    }
}

impl SdeJacobians for PlanarQuadrotor {
    fn drift_jacobian(&self, x: &[f64], u: &[f64], jac: &mut [f64]) {
        let a = u[0] / self.params.mass;
        jac[..36].fill(0.0);
        // column-major d × d: jac[row + col·6]
        jac[3 * 6] = 1.0;
        jac[1 + 4 * 6] = 1.0;
        jac[2 + 5 * 6] = 1.0;
        jac[3 + 2 * 6] = -a * x[2].cos();
        jac[4 + 2 * 6] = -a * x[2].sin();
    }
    fn obs_jacobian(&self, _x: &[f64], jac: &mut [f64]) {
        // m × d column-major: jac[row + col·2]
        jac[..12].fill(0.0);
        jac[0] = 1.0;
        jac[1 + 2] = 1.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::scale::fd_drift_jacobian;

    #[test]
    fn closed_form_jacobian_matches_finite_differences() {
        let m = PlanarQuadrotor::new(PlanarQuadrotorParams::default()).unwrap();
        let x = [0.3, -0.2, 0.4, 1.0, -0.5, 0.7];
        let u = [11.0, 0.2];
        let (mut a, mut b) = ([0.0; 36], [0.0; 36]);
        m.drift_jacobian(&x, &u, &mut a);
        fd_drift_jacobian(&m, &x, &u, &mut b);
        for i in 0..36 {
            assert!((a[i] - b[i]).abs() < 1e-6, "{i}: {} vs {}", a[i], b[i]);
        }
    }

    #[test]
    fn observation_jacobian_is_the_position_selector() {
        let m = PlanarQuadrotor::new(PlanarQuadrotorParams::default()).unwrap();
        let mut j = [0.0; 12];
        m.obs_jacobian(&[0.3, -0.2, 0.4, 1.0, -0.5, 0.7], &mut j);
        // ∂g_r/∂x_c at [r + 2c]
        for r in 0..2 {
            for c in 0..6 {
                assert_eq!(j[r + 2 * c], f64::from(u8::from(r == c)), "({r}, {c})");
            }
        }
    }

    #[test]
    fn hover_is_an_equilibrium_and_noise_is_on_the_velocities_only() {
        let m = PlanarQuadrotor::new(PlanarQuadrotorParams::default()).unwrap();
        let mut f = [0.0; 6];
        m.drift(&[1.0, 2.0, 0.0, 0.0, 0.0, 0.0], &m.hover(), &mut f);
        assert!(f.iter().all(|v| v.abs() < 1e-12), "{f:?}");
        let mut big_f = [0.0; 18];
        m.diffusion(&[0.0; 6], &mut big_f);
        let ff: Vec<f64> = (0..36)
            .map(|k| {
                let (r, c) = (k % 6, k / 6);
                (0..3).map(|j| big_f[r + j * 6] * big_f[c + j * 6]).sum()
            })
            .collect();
        assert_eq!(
            crate::chain::degenerate::noise_free_mask(6, &ff),
            Some(0b000111)
        );
        assert!(PlanarQuadrotor::new(PlanarQuadrotorParams {
            sigma: 0.0,
            ..Default::default()
        })
        .is_err());
    }
}
