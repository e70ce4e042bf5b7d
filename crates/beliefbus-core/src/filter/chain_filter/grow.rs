//! States added while filtering (Alg. 2.3 with reconnection): the density
//! φ/vol of each new state is the average over its Near set (the thesis's
//! `ApproximateDensity`, §3.5, applied to densities), reconnected states
//! keep their density while their volume shrinks, then φ is renormalised
//! and exponential backup refits δ.

use super::{normalise, ChainFilter, GrowInfo};
use crate::chain::{ChainError, Sampler};
use crate::model::SdeModel;
use crate::rng::SimRng;
use crate::MAX_STATE;

impl<M: SdeModel> ChainFilter<M> {
    /// Grow the chain by `count` states from `sampler` while filtering
    /// (Alg. 2.3 with reconnection), give new states neighbour-averaged
    /// density, run exponential backup over every touched state, and
    /// install the new version (kernel, observation means, buffers).
    pub fn grow(
        &mut self,
        sampler: &Sampler,
        count: usize,
        rng: &mut SimRng,
    ) -> Result<GrowInfo, ChainError> {
        let n_old = self.chain.len();
        let d = self.dims.state;
        // densities of the old states
        let mut rho: Vec<f64> = (0..n_old)
            .map(|i| self.phi[i] / self.chain.cell_volume(i).max(1e-300))
            .collect();
        let mut touched = Vec::with_capacity(count * 16);
        self.chain
            .grow(&self.model, sampler, count, rng, &mut touched)?;
        let n = self.chain.len();
        let mut near = Vec::new();
        for i in n_old..n {
            let x: [f64; MAX_STATE] = {
                let mut a = [0.0; MAX_STATE];
                a[..d].copy_from_slice(self.chain.state(i));
                a
            };
            let k = self.chain.near_count()[i].max(1) as usize;
            self.chain.nearest(&x[..d], k + 1, &mut near);
            let (mut s, mut c) = (0.0, 0usize);
            for &(j, _) in &near {
                if (j as usize) < i {
                    s += rho[j as usize];
                    c += 1;
                }
            }
            rho.push(if c > 0 { s / c as f64 } else { 0.0 });
        }
        self.phi.resize(n, 0.0);
        for i in 0..n {
            self.phi[i] = rho[i] * self.chain.cell_volume(i);
        }
        if !normalise(&mut self.phi) {
            self.phi.fill(1.0 / n as f64);
        }
        let halved = self.eq.backup(self.chain.holding(), &touched);
        self.install();
        self.refresh_obs_means(n_old);
        Ok(GrowInfo {
            added: n - n_old,
            reconnected: touched.len().saturating_sub(n - n_old),
            delta_halved: halved,
            delta: self.eq.delta(),
        })
    }
}
