//! The discrete-time view of an [`SdeModel`]: Euler–Maruyama transitions and
//! the Gaussian observation likelihood. These are the building blocks of the
//! particle filters and of the plant simulator.
//!
//! ```text
//! x_{k+1} = x_k + f(x_k, u) Δt + F(x_k) √Δt ξ,   ξ ~ N(0, I_k)
//! log p(y | x) = Σ_{i ∈ mask} [ −½ (r_i/σ_i)² − log σ_i − ½ log 2π ],  r = y ⊖ g(x)
//! ```

use super::{Measurement, SdeModel};
use crate::rng::SimRng;
use crate::{MAX_NOISE, MAX_OBS, MAX_STATE};
use rand::RngExt;
use rand_distr::StandardNormal;

const HALF_LOG_2PI: f64 = 0.918_938_533_204_672_8;

/// One Euler–Maruyama step of length `dt` from `x` under control `u`,
/// written into `out` (may not alias `x`).
pub fn em_step<M: SdeModel + ?Sized>(
    model: &M,
    x: &[f64],
    u: &[f64],
    dt: f64,
    rng: &mut SimRng,
    out: &mut [f64],
) {
    let dims = model.dims();
    let (d, k) = (dims.state, dims.noise);
    let mut f = [0.0; MAX_STATE];
    let mut big_f = [0.0; MAX_STATE * MAX_NOISE];
    let mut xi = [0.0; MAX_NOISE];
    model.drift(x, u, &mut f[..d]);
    model.diffusion(x, &mut big_f[..d * k]);
    let sq = dt.sqrt();
    for v in xi[..k].iter_mut() {
        *v = rng.sample::<f64, _>(StandardNormal) * sq;
    }
    for i in 0..d {
        let mut s = x[i] + f[i] * dt;
        for j in 0..k {
            s += big_f[i + j * d] * xi[j];
        }
        out[i] = s;
    }
}

/// Advance `x` in place over `duration` with steps of at most `max_dt`.
pub fn em_integrate<M: SdeModel + ?Sized>(
    model: &M,
    x: &mut [f64],
    u: &[f64],
    duration: f64,
    max_dt: f64,
    rng: &mut SimRng,
) {
    if !(duration > 0.0) {
        return;
    }
    let steps = (duration / max_dt).ceil().max(1.0) as usize;
    let dt = duration / steps as f64;
    let d = x.len();
    let mut tmp = [0.0; MAX_STATE];
    for _ in 0..steps {
        em_step(model, x, u, dt, rng, &mut tmp[..d]);
        x.copy_from_slice(&tmp[..d]);
    }
}

/// log p(y | x) for the masked components of `meas` under independent
/// Gaussian noise (the model's σ unless the measurement carries its own).
pub fn obs_log_likelihood<M: SdeModel + ?Sized>(model: &M, x: &[f64], meas: &Measurement) -> f64 {
    let m = model.dims().obs;
    let mut g = [0.0; MAX_OBS];
    let mut r = [0.0; MAX_OBS];
    let mut std = [0.0; MAX_OBS];
    model.obs_mean(x, &mut g[..m]);
    model.obs_residual(&meas.y[..m], &g[..m], &mut r[..m]);
    match meas.std {
        Some(s) => std[..m].copy_from_slice(&s[..m]),
        None => model.obs_std(&mut std[..m]),
    }
    let mut ll = 0.0;
    for i in meas.mask.iter().take_while(|&i| i < m) {
        let z = r[i] / std[i];
        ll -= 0.5 * z * z + std[i].ln() + HALF_LOG_2PI;
    }
    ll
}

/// Draw a measurement y = g(x) + v of the model at x into `y`.
pub fn simulate_observation<M: SdeModel + ?Sized>(
    model: &M,
    x: &[f64],
    rng: &mut SimRng,
    y: &mut [f64],
) {
    let m = model.dims().obs;
    let mut std = [0.0; MAX_OBS];
    model.obs_mean(x, &mut y[..m]);
    model.obs_std(&mut std[..m]);
    for i in 0..m {
        y[i] += std[i] * rng.sample::<f64, _>(StandardNormal);
    }
}
