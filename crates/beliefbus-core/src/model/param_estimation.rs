//! The parameter-estimation problem of paper 001 eq. 13 / thesis eq. 3.15
//! (modified from Doucet & Tadić 2003): the state is augmented with the
//! unknown parameter φ, given a small artificial noise:
//!
//! ```text
//! dx = x cos(2π φ x) dt + σ_x dw₁,    dφ = σ_φ dw₂,    y = x + σ v   (sampled)
//! ```
//!
//! Paper: σ_x = σ_v = σ_φ = 0.1 (σ_v is the continuous coefficient; the
//! sampled σ is σ_v/√Δ), true φ = 0.5, prior φ ~ N(0.8, 1). Chosen here: the
//! compact set S = [−3, 3] × [−2.5, 4] (φ: prior mean ± 3.2 σ).

use super::{Bounds, Dims, SdeJacobians, SdeModel};

/// Parameters of eq. 13.
#[derive(Clone, Debug, PartialEq)]
pub struct ParamEstimationParams {
    pub sigma_x: f64,
    pub sigma_phi: f64,
    /// σ of one sampled measurement of x.
    pub obs_std: f64,
    pub x_max: f64,
    pub phi_lo: f64,
    pub phi_hi: f64,
}

impl ParamEstimationParams {
    /// The paper's noise levels, observed every `dt`.
    pub fn paper(dt: f64) -> Self {
        Self {
            sigma_x: 0.1,
            sigma_phi: 0.1,
            obs_std: super::continuous_obs_std(0.1, dt),
            x_max: 3.0,
            phi_lo: -2.5,
            phi_hi: 4.0,
        }
    }
}

/// The augmented model (x, φ).
#[derive(Clone, Debug)]
pub struct ParamEstimation {
    pub params: ParamEstimationParams,
    bounds: Bounds,
}

impl ParamEstimation {
    /// Build; noise levels must be positive and the φ range non-empty.
    pub fn new(params: ParamEstimationParams) -> Result<Self, String> {
        for (k, v) in [
            ("sigma_x", params.sigma_x),
            ("sigma_phi", params.sigma_phi),
            ("obs_std", params.obs_std),
            ("x_max", params.x_max),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("param_estimation.{k} must be positive, got {v}"));
            }
        }
        let bounds = Bounds::new_box(
            &[-params.x_max, params.phi_lo],
            &[params.x_max, params.phi_hi],
        )
        .map_err(|e| e.to_string())?;
        Ok(Self { params, bounds })
    }
}

impl SdeModel for ParamEstimation {
    fn name(&self) -> &str {
        "param_estimation"
    }
    fn dims(&self) -> Dims {
        Dims {
            state: 2,
            noise: 2,
            obs: 1,
            control: 0,
        }
    }
    fn drift(&self, z: &[f64], _u: &[f64], f: &mut [f64]) {
        f[0] = z[0] * (2.0 * std::f64::consts::PI * z[1] * z[0]).cos();
        f[1] = 0.0;
    }
    fn diffusion(&self, _z: &[f64], big_f: &mut [f64]) {
        big_f[0] = self.params.sigma_x;
        big_f[1] = 0.0;
        big_f[2] = 0.0;
        big_f[3] = self.params.sigma_phi;
    }
    fn obs_mean(&self, z: &[f64], g: &mut [f64]) {
        g[0] = z[0];
    }
    fn obs_std(&self, std: &mut [f64]) {
        std[0] = self.params.obs_std;
    }
    fn bounds(&self) -> &Bounds {
        &self.bounds
    }
}

impl SdeJacobians for ParamEstimation {
    fn drift_jacobian(&self, z: &[f64], _u: &[f64], jac: &mut [f64]) {
        let w = 2.0 * std::f64::consts::PI;
        let (x, p) = (z[0], z[1]);
        let (s, c) = (w * p * x).sin_cos();
        jac[0] = c - x * s * w * p; // ∂f1/∂x
        jac[1] = 0.0;
        jac[2] = -x * s * w * x; // ∂f1/∂φ
        jac[3] = 0.0;
    }
    fn obs_jacobian(&self, _z: &[f64], jac: &mut [f64]) {
        jac[0] = 1.0;
        jac[1] = 0.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drift_jacobian_matches_finite_differences() {
        let m = ParamEstimation::new(ParamEstimationParams::paper(0.01)).unwrap();
        let z = [0.7, 0.45];
        let mut j = [0.0; 4];
        m.drift_jacobian(&z, &[], &mut j);
        for c in 0..2 {
            let (mut zp, mut zm) = (z, z);
            zp[c] += 1e-6;
            zm[c] -= 1e-6;
            let (mut fp, mut fm) = ([0.0; 2], [0.0; 2]);
            m.drift(&zp, &[], &mut fp);
            m.drift(&zm, &[], &mut fm);
            for r in 0..2 {
                assert!(((fp[r] - fm[r]) / 2e-6 - j[r + 2 * c]).abs() < 1e-6);
            }
        }
    }
}
