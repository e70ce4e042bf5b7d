//! `ship-states --param placement=recentred`: one chain of n states built
//! once in a local frame and carried with the belief
//! ([`crate::filter::chain_filter::recentred`]): the ship inside the disc
//! has the affine drift (v, 0), so a Galilean frame c moves every state
//! alike and one chain serves wherever the ship goes. The belief is
//! re-installed on it every `every` observations (and when its effective
//! number of states falls below `ess_fraction` · n) by importance weights
//! N(z; x̂, P̂)/q(z) or by cell volumes.
//!
//! The local states are drawn from q = N(0, spread² P_ref) (then, with
//! `even`, 4n candidates thinned to n by sample elimination), P_ref either
//! the prior's covariance (`around=prior`) or the data-free steady-state
//! posterior of the model linearised at range `ref_range` on the x₁ axis
//! (`chain::steady::steady_posterior`, discrete Riccati at the sensor
//! period), averaged over rotations: the ship's free dynamics and noise
//! are rotation invariant, its posterior's orientation follows the bearing,
//! so the chain is given the orientation-free shape.

use anyhow::Result;

use crate::belief::Gaussian;
use crate::chain::steady::steady_posterior;
use crate::chain::{Chain, ChainConfig, Sampler};
use crate::filter::chain_filter::recentred::{Install, RecentredChainFilter, RecentredConfig};
use crate::model::ship::Ship;
use crate::model::SdeModel;
use crate::rng::SimRng;

/// How the re-centred chain is made (see the module doc).
#[derive(Clone, Copy, Debug)]
pub struct Recentred {
    pub every: usize,
    pub ess_fraction: f64,
    pub importance: bool,
    /// P_ref: the steady posterior at `ref_range` (true) or the prior.
    pub steady: bool,
    pub ref_range: f64,
    pub spread: f64,
    pub even: bool,
    pub cov_match: usize,
}

/// R P Rᵀ averaged over 16 rotations R = diag(R_α, R_α) of the position
/// and velocity planes.
fn rotation_average(p: &Gaussian) -> Gaussian {
    let mut out = Gaussian::zeros(4);
    let k = 16;
    for j in 0..k {
        let a = 2.0 * std::f64::consts::PI * j as f64 / k as f64;
        let (s, c) = a.sin_cos();
        let mut r = [[0.0; 4]; 4];
        for b in [0, 2] {
            r[b][b] = c;
            r[b][b + 1] = -s;
            r[b + 1][b] = s;
            r[b + 1][b + 1] = c;
        }
        for i in 0..4 {
            for l in 0..4 {
                let mut v = 0.0;
                for a1 in 0..4 {
                    for a2 in 0..4 {
                        v += r[i][a1] * p.cov_at(a1, a2) * r[l][a2];
                    }
                }
                out.set_cov(i, l, out.cov_at(i, l) + v / k as f64);
            }
        }
    }
    out
}

/// The local sampling law q = N(0, spread² P_ref).
pub fn sampling_law(model: &Ship, prior: &Gaussian, rc: &Recentred, dt: f64) -> Result<Gaussian> {
    let mut q = if rc.steady {
        let s = steady_posterior(model, &[rc.ref_range, 0.0, 0.0, 0.0], &[0.0, 0.0], dt)?;
        rotation_average(&s)
    } else {
        *prior
    };
    q.mean_mut().fill(0.0);
    for v in q.cov_mut() {
        *v *= rc.spread * rc.spread;
    }
    Ok(q)
}

/// The filter on a chain of `n` states drawn from [`sampling_law`], built
/// with `cfg`.
pub fn filter(
    model: &Ship,
    q: &Gaussian,
    n: usize,
    rc: &Recentred,
    cfg: ChainConfig,
    dt: f64,
    rng: &mut SimRng,
) -> Result<RecentredChainFilter<Ship>> {
    let sampler =
        Sampler::around(q, 1.0, 0.0).ok_or_else(|| anyhow::anyhow!("singular sampling law"))?;
    let d = model.dims().state;
    let m = if rc.even { 4 * n } else { n };
    let mut cand = vec![0.0; m * d];
    for x in cand.chunks_exact_mut(d) {
        sampler.sample(model.bounds(), rng, x);
    }
    let pts = if rc.even {
        crate::chain::placement::eliminate(&cand, d, n)
    } else {
        cand
    };
    let chain = Chain::batch(model, cfg, &pts)?;
    let rcfg = RecentredConfig {
        every: rc.every,
        ess_fraction: rc.ess_fraction,
        install: if rc.importance {
            Install::Importance
        } else {
            Install::Volume
        },
        cov_match: rc.cov_match,
    };
    Ok(RecentredChainFilter::new(
        model.clone(),
        chain,
        q,
        dt,
        rcfg,
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rotation average keeps the trace of each block and makes the
    /// position block isotropic.
    #[test]
    fn rotation_average_is_isotropic_and_keeps_traces() {
        let mut p = Gaussian::diagonal(&[0.0; 4], &[0.1, 0.5, 0.2, 0.7]);
        p.set_cov(0, 2, 0.01);
        p.set_cov(2, 0, 0.01);
        let a = rotation_average(&p);
        let tr = |g: &Gaussian, i: usize| g.cov_at(i, i) + g.cov_at(i + 1, i + 1);
        assert!((tr(&a, 0) - tr(&p, 0)).abs() < 1e-12);
        assert!((tr(&a, 2) - tr(&p, 2)).abs() < 1e-12);
        assert!((a.cov_at(0, 0) - a.cov_at(1, 1)).abs() < 1e-12);
        assert!(a.cov_at(0, 1).abs() < 1e-12);
        assert!((a.cov_at(0, 2) - 0.005).abs() < 1e-12);
    }
}
