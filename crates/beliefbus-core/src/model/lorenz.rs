//! Stochastic Lorenz-63 (E. N. Lorenz, "Deterministic nonperiodic flow",
//! J. Atmos. Sci. 20, 1963) with noise on every coordinate:
//!
//! ```text
//! dx = σ (y − x) dt       + e dw1
//! dy = (x (ρ − z) − y) dt + e dw2
//! dz = (x y − β z) dt     + e dw3
//! y_k = x(t_k) + v_k            (or (x, z)(t_k) + v_k),  v_k ~ N(0, s² I)
//! ```
//!
//! σ = 10, ρ = 28, β = 8/3 (the chaotic attractor). The project's other
//! models have noise on some coordinates only or two dimensions; this one
//! is the "unseen model" the chain filter's defaults are checked on
//! ([`crate::filter::chain_spec`]). S is a box around the attractor, which
//! spans |x| ≤ 20, |y| ≤ 27, 0 < z < 50: [−25, 25] × [−32, 32] × [−5, 55]
//! by default.
//!
//! Drift Jacobian (closed form):
//!
//! ```text
//! ∂f/∂x = [ −σ      σ    0  ]
//!         [ ρ − z   −1   −x ]
//!         [ y       x    −β ]
//! ```

use super::{Bounds, Dims, SdeJacobians, SdeModel};
use serde::{Deserialize, Serialize};

/// Parameters of the stochastic Lorenz-63 system.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LorenzParams {
    pub sigma: f64,
    pub rho: f64,
    pub beta: f64,
    /// Diffusion e of every coordinate (F = e I).
    pub e: f64,
    /// σ of one sampled measurement of each observed coordinate.
    pub obs_std: f64,
    /// Observe z as well as x.
    pub observe_z: bool,
    /// S = [−x_max, x_max] × [−y_max, y_max] × [z_min, z_max].
    pub x_max: f64,
    pub y_max: f64,
    pub z_min: f64,
    pub z_max: f64,
}

impl Default for LorenzParams {
    fn default() -> Self {
        Self {
            sigma: 10.0,
            rho: 28.0,
            beta: 8.0 / 3.0,
            e: 1.0,
            obs_std: 1.0,
            observe_z: false,
            x_max: 25.0,
            y_max: 32.0,
            z_min: -5.0,
            z_max: 55.0,
        }
    }
}

/// The stochastic Lorenz-63 model.
#[derive(Clone, Debug)]
pub struct Lorenz {
    pub params: LorenzParams,
    bounds: Bounds,
}

impl Lorenz {
    /// Build the model; noise levels must be positive and S non-empty.
    pub fn new(params: LorenzParams) -> Result<Self, String> {
        for (name, v) in [
            ("e", params.e),
            ("obs_std", params.obs_std),
            ("x_max", params.x_max),
            ("y_max", params.y_max),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!(
                    "lorenz.{name} must be positive and finite, got {v}"
                ));
            }
        }
        if ![params.sigma, params.rho, params.beta]
            .iter()
            .all(|v| v.is_finite())
        {
            return Err("lorenz.sigma, rho and beta must be finite".into());
        }
        let bounds = Bounds::new_box(
            &[-params.x_max, -params.y_max, params.z_min],
            &[params.x_max, params.y_max, params.z_max],
        )
        .map_err(|e| e.to_string())?;
        Ok(Self { params, bounds })
    }
}

impl SdeModel for Lorenz {
    fn name(&self) -> &str {
        "lorenz"
    }
    fn dims(&self) -> Dims {
        Dims {
            state: 3,
            noise: 3,
            obs: if self.params.observe_z { 2 } else { 1 },
            control: 0,
        }
    }
    fn drift(&self, x: &[f64], _u: &[f64], f: &mut [f64]) {
        let p = &self.params;
        f[0] = p.sigma * (x[1] - x[0]);
        f[1] = x[0] * (p.rho - x[2]) - x[1];
        f[2] = x[0] * x[1] - p.beta * x[2];
    }
    fn diffusion(&self, _x: &[f64], big_f: &mut [f64]) {
        big_f[..9].fill(0.0);
        for i in 0..3 {
            big_f[i + 3 * i] = self.params.e;
        }
    }
    fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
        g[0] = x[0];
        if self.params.observe_z {
            g[1] = x[2];
        }
    }
    fn obs_std(&self, std: &mut [f64]) {
        let m = self.dims().obs;
        std[..m].fill(self.params.obs_std);
    }
    fn bounds(&self) -> &Bounds {
        &self.bounds
    }
}

impl SdeJacobians for Lorenz {
    fn drift_jacobian(&self, x: &[f64], _u: &[f64], jac: &mut [f64]) {
        let p = &self.params;
        // column-major: jac[i + 3 j] = ∂f_i/∂x_j
        jac[0] = -p.sigma;
        jac[1] = p.rho - x[2];
        jac[2] = x[1];
        jac[3] = p.sigma;
        jac[4] = -1.0;
        jac[5] = x[0];
        jac[6] = 0.0;
        jac[7] = -x[0];
        jac[8] = -p.beta;
    }
    fn obs_jacobian(&self, _x: &[f64], jac: &mut [f64]) {
        let m = self.dims().obs;
        jac[..m * 3].fill(0.0);
        jac[0] = 1.0; // ∂y1/∂x
        if m == 2 {
            jac[1 + 2 * 2] = 1.0; // ∂y2/∂z
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drift_jacobian_matches_central_differences() {
        let m = Lorenz::new(LorenzParams::default()).unwrap();
        for x in [[1.3, -2.1, 24.0], [-8.0, -9.5, 30.2], [0.0, 0.0, 0.0]] {
            let mut j = [0.0; 9];
            m.drift_jacobian(&x, &[], &mut j);
            let (mut fp, mut fm) = ([0.0; 3], [0.0; 3]);
            for c in 0..3 {
                let (mut xp, mut xm) = (x, x);
                let h = 1e-5;
                xp[c] += h;
                xm[c] -= h;
                m.drift(&xp, &[], &mut fp);
                m.drift(&xm, &[], &mut fm);
                for r in 0..3 {
                    let fd = (fp[r] - fm[r]) / (2.0 * h);
                    assert!((fd - j[r + 3 * c]).abs() < 1e-6, "({r},{c}) at {x:?}");
                }
            }
        }
    }

    #[test]
    fn observation_jacobian_matches_central_differences() {
        for observe_z in [false, true] {
            let m = Lorenz::new(LorenzParams {
                observe_z,
                ..LorenzParams::default()
            })
            .unwrap();
            let mobs = m.dims().obs;
            let x = [2.0, -3.0, 20.0];
            let mut closed = [0.0; 6];
            m.obs_jacobian(&x, &mut closed);
            // the trait's finite-difference default, via a wrapper that
            // does not override it
            struct Fd<'a>(&'a Lorenz);
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
                fn bounds(&self) -> &Bounds {
                    self.0.bounds()
                }
            }
            impl SdeJacobians for Fd<'_> {}
            let mut fd = [0.0; 6];
            Fd(&m).obs_jacobian(&x, &mut fd);
            for i in 0..mobs * 3 {
                assert!((fd[i] - closed[i]).abs() < 1e-8, "{observe_z}: {i}");
            }
        }
    }

    #[test]
    fn noiseless_orbit_stays_on_the_attractor_inside_the_bounds() {
        // RK4 from (1, 1, 1): after a transient the orbit visits both wings
        // (x changes sign), stays inside S, and its time-mean z is ≈ 23.5
        // (the Lorenz-63 attractor's mean z at ρ = 28 is 23.5–23.6).
        let m = Lorenz::new(LorenzParams::default()).unwrap();
        let mut x = [1.0, 1.0, 1.0];
        let h = 1e-3;
        let (mut zsum, mut count, mut pos, mut neg) = (0.0, 0usize, 0, 0);
        for k in 0..200_000 {
            let mut k1 = [0.0; 3];
            let mut k2 = [0.0; 3];
            let mut k3 = [0.0; 3];
            let mut k4 = [0.0; 3];
            m.drift(&x, &[], &mut k1);
            let y: Vec<f64> = (0..3).map(|i| x[i] + 0.5 * h * k1[i]).collect();
            m.drift(&y, &[], &mut k2);
            let y: Vec<f64> = (0..3).map(|i| x[i] + 0.5 * h * k2[i]).collect();
            m.drift(&y, &[], &mut k3);
            let y: Vec<f64> = (0..3).map(|i| x[i] + h * k3[i]).collect();
            m.drift(&y, &[], &mut k4);
            for i in 0..3 {
                x[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
            }
            if k > 10_000 {
                assert!(m.bounds().contains(&x), "{x:?} left S");
                zsum += x[2];
                count += 1;
                if x[0] > 0.0 {
                    pos += 1
                } else {
                    neg += 1
                }
            }
        }
        let zmean = zsum / count as f64;
        assert!((zmean - 23.55).abs() < 0.6, "mean z {zmean}");
        assert!(pos > count / 5 && neg > count / 5, "{pos} / {neg}");
    }
}
