//! The noisy Van der Pol oscillator (paper 001 eq. 12; thesis eq. 3.14):
//!
//! ```text
//! dx1 = x2 dt + e1 dw1
//! dx2 = [−x1 + μ (1 − x1²) x2] dt + e2 dw2
//! y   = x1 + σ v
//! ```
//!
//! **Erratum.** Both documents print the second drift as
//! `−x1 + μ x1 (1 − x1²)`, which has no x2 and is a conservative double-well
//! (Duffing) oscillator without a limit cycle; the text says "a stable limit
//! cycle for μ > 0", which is the Van der Pol drift `−x1 + μ(1 − x1²) x2`
//! used here. μ = 2 as in the paper. Unstated in the paper and chosen here:
//! e1 = e2 = 0.1 (process), the sampled observation σ, and the compact set
//! S = [−3, 3] × [−6, 6] (the μ = 2 limit cycle spans |x1| ≤ 2.02,
//! |x2| ≤ 3.9).

use super::{Bounds, Dims, SdeJacobians, SdeModel};
use serde::{Deserialize, Serialize};

/// Parameters of the Van der Pol oscillator.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct VanDerPolParams {
    /// Damping μ of ẍ1 − μ(1 − x1²)ẋ1 + x1 = 0.
    pub mu: f64,
    /// Process-noise coefficient on x1.
    pub e1: f64,
    /// Process-noise coefficient on x2.
    pub e2: f64,
    /// σ of one sampled measurement of x1.
    pub obs_std: f64,
    /// Half-width of the compact set S in x1.
    pub x1_max: f64,
    /// Half-width of the compact set S in x2.
    pub x2_max: f64,
}

impl Default for VanDerPolParams {
    fn default() -> Self {
        Self {
            mu: 2.0,
            e1: 0.1,
            e2: 0.1,
            obs_std: 0.1,
            x1_max: 3.0,
            x2_max: 6.0,
        }
    }
}

/// The Van der Pol model.
#[derive(Clone, Debug)]
pub struct VanDerPol {
    pub params: VanDerPolParams,
    bounds: Bounds,
}

impl VanDerPol {
    /// Build the model; noise levels and bounds must be positive.
    pub fn new(params: VanDerPolParams) -> Result<Self, String> {
        for (name, v) in [
            ("e1", params.e1),
            ("e2", params.e2),
            ("obs_std", params.obs_std),
            ("x1_max", params.x1_max),
            ("x2_max", params.x2_max),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!(
                    "vanderpol.{name} must be positive and finite, got {v}"
                ));
            }
        }
        if !params.mu.is_finite() {
            return Err("vanderpol.mu must be finite".into());
        }
        let bounds = Bounds::new_box(
            &[-params.x1_max, -params.x2_max],
            &[params.x1_max, params.x2_max],
        )
        .map_err(|e| e.to_string())?;
        Ok(Self { params, bounds })
    }
}

impl SdeModel for VanDerPol {
    fn name(&self) -> &str {
        "vanderpol"
    }
    fn dims(&self) -> Dims {
        Dims {
            state: 2,
            noise: 2,
            obs: 1,
            control: 0,
        }
    }
    fn drift(&self, x: &[f64], _u: &[f64], f: &mut [f64]) {
        f[0] = x[1];
        f[1] = -x[0] + self.params.mu * (1.0 - x[0] * x[0]) * x[1];
    }
    fn diffusion(&self, _x: &[f64], big_f: &mut [f64]) {
        big_f[0] = self.params.e1;
        big_f[1] = 0.0;
        big_f[2] = 0.0;
        big_f[3] = self.params.e2;
    }
    fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
        g[0] = x[0];
    }
    fn obs_std(&self, std: &mut [f64]) {
        std[0] = self.params.obs_std;
    }
    fn bounds(&self) -> &Bounds {
        &self.bounds
    }
}

impl SdeJacobians for VanDerPol {
    fn drift_jacobian(&self, x: &[f64], _u: &[f64], jac: &mut [f64]) {
        let mu = self.params.mu;
        jac[0] = 0.0; // ∂f1/∂x1
        jac[1] = -1.0 - 2.0 * mu * x[0] * x[1]; // ∂f2/∂x1
        jac[2] = 1.0; // ∂f1/∂x2
        jac[3] = mu * (1.0 - x[0] * x[0]); // ∂f2/∂x2
    }
    fn obs_jacobian(&self, _x: &[f64], jac: &mut [f64]) {
        jac[0] = 1.0;
        jac[1] = 0.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drift_jacobian_matches_central_differences() {
        let m = VanDerPol::new(VanDerPolParams::default()).unwrap();
        let x = [0.7, -1.3];
        let mut j = [0.0; 4];
        m.drift_jacobian(&x, &[], &mut j);
        let mut fp = [0.0; 2];
        let mut fm = [0.0; 2];
        for c in 0..2 {
            let mut xp = x;
            let mut xm = x;
            xp[c] += 1e-6;
            xm[c] -= 1e-6;
            m.drift(&xp, &[], &mut fp);
            m.drift(&xm, &[], &mut fm);
            for r in 0..2 {
                let fd = (fp[r] - fm[r]) / 2e-6;
                assert!((fd - j[r + 2 * c]).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn deterministic_orbit_reaches_the_limit_cycle() {
        // Integrate the noiseless drift from near the origin: a Van der Pol
        // oscillator with μ = 2 settles on a cycle with max |x1| ≈ 2.02.
        let m = VanDerPol::new(VanDerPolParams::default()).unwrap();
        let mut x = [0.1, 0.0];
        let dt = 1e-3;
        let mut amax: f64 = 0.0;
        for k in 0..60_000 {
            let mut f = [0.0; 2];
            m.drift(&x, &[], &mut f);
            // Heun step
            let xp = [x[0] + dt * f[0], x[1] + dt * f[1]];
            let mut f2 = [0.0; 2];
            m.drift(&xp, &[], &mut f2);
            x[0] += 0.5 * dt * (f[0] + f2[0]);
            x[1] += 0.5 * dt * (f[1] + f2[1]);
            if k > 40_000 {
                amax = amax.max(x[0].abs());
            }
        }
        assert!((amax - 2.02).abs() < 0.03, "amplitude {amax}");
    }
}
