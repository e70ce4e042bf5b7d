//! Backend `projection-pf` on the inventory model: the projection particle
//! filter of paper §IV ([`ProjectionPf`], Gaussian family, N particles)
//! behind the pipeline's [`BayesFilter`] trait.
//!
//! `predict(t, u)` only moves the clock: the system steps at samples, and
//! the order that entered x_k comes with the measurement (y_k, u_{k−1}).
//! `update` resamples from the projected belief θ̂_{k−1}, propagates every
//! particle through one period under u_{k−1} (censored at 0), weights by
//! N(y_k; x, σ²) and projects: θ̂_k = (m̂, σ̂²), the belief the `belief-mdp`
//! controller looks up. The first sample is x_0's: the filter draws from
//! the prior (x_0 known: a point mass) and only weights. The published
//! Gaussian is (m̂, β, 0) with variances (σ̂², β², 0): the last two state
//! entries (the period's demand and cost) are not estimated.

use super::{InventorySystem, STATE};
use crate::backends::FilterContext;
use crate::rng::SimRng;
use beliefbus_core::belief::Gaussian;
use beliefbus_core::filter::{
    check_measurement, check_predict, BayesFilter, FilterError, UpdateInfo,
};
use beliefbus_core::model::{Dims, Measurement};
use beliefbus_projection::inventory::Inventory;
use beliefbus_projection::{GaussianParams, ProjectionError, ProjectionPf};

/// The backend.
pub struct InventoryPpf {
    pf: ProjectionPf<beliefbus_projection::Gaussian>,
    model: Inventory,
    prior: GaussianParams,
    seed: u64,
    resets: u64,
    rng: SimRng,
    dims: Dims,
    time: f64,
    started: bool,
    belief: Gaussian,
}

impl InventoryPpf {
    /// From `[inventory.filter]`; the stream is `ctx.seed`. A resumed
    /// filter starts from the inventory entries of `ctx.start`.
    pub fn new(sys: &InventorySystem, ctx: &FilterContext) -> Result<Self, String> {
        let family = beliefbus_projection::Gaussian::new(1).map_err(|e| e.to_string())?;
        let prior = start_params(&family, &ctx.start)?;
        let pf = ProjectionPf::new(family, sys.params.filter.particles, &prior)
            .map_err(|e| e.to_string())?;
        let mut f = Self {
            pf,
            model: sys.model.clone(),
            prior,
            seed: ctx.seed,
            resets: 0,
            rng: crate::rng::stream(ctx.seed, 0),
            dims: crate::System::dims(sys),
            time: ctx.t0,
            started: false,
            belief: Gaussian::zeros(STATE),
        };
        f.summarise();
        Ok(f)
    }

    /// The projected belief θ̂.
    pub fn projected(&self) -> &GaussianParams {
        self.pf.params()
    }

    fn summarise(&mut self) {
        let p = self.pf.params();
        let b = self.model.demand_mean;
        let mut g = Gaussian::zeros(STATE);
        g.mean[0] = p.mean[0];
        g.mean[1] = b;
        g.set_cov(0, 0, p.cov[(0, 0)].max(0.0));
        g.set_cov(1, 1, b * b);
        self.belief = g;
    }
}

/// N(mean₀, var₀) of a start belief's inventory entry.
fn start_params(
    family: &beliefbus_projection::Gaussian,
    start: &Gaussian,
) -> Result<GaussianParams, String> {
    let (m, v) = (start.mean[0].max(0.0), start.cov_at(0, 0).max(0.0));
    family.params(&[m], &[v]).map_err(|e| format!("prior: {e}"))
}

fn filter_error(e: ProjectionError) -> FilterError {
    match e {
        ProjectionError::NoSupport => FilterError::Degenerate,
        _ => FilterError::Numerical("projection"),
    }
}

impl BayesFilter for InventoryPpf {
    fn name(&self) -> &'static str {
        super::PPF
    }
    fn dims(&self) -> Dims {
        self.dims
    }
    fn time(&self) -> f64 {
        self.time
    }
    fn reset(&mut self, t: f64, prior: &Gaussian) {
        // A fresh stream per reset keeps runs reproducible.
        self.resets += 1;
        self.rng = crate::rng::stream(self.seed, self.resets);
        if let Ok(p) = start_params(self.pf.family(), prior) {
            self.prior = p;
        }
        self.pf.reset(&self.prior);
        self.started = false;
        self.time = t;
        self.summarise();
    }
    fn predict(&mut self, t: f64, u: &[f64]) -> Result<(), FilterError> {
        check_predict(self.time, t, u, self.dims)?;
        self.time = t;
        Ok(())
    }
    fn update(&mut self, meas: &Measurement) -> Result<UpdateInfo, FilterError> {
        check_measurement(meas, self.dims)?;
        if !(meas.mask.contains(0) && meas.mask.contains(1)) {
            return Err(FilterError::Dimension {
                what: "observation mask (needs the count and the order)",
                got: meas.mask.count(),
                expected: 2,
            });
        }
        let (y, order) = (meas.y[0], meas.y[1]);
        if !(y.is_finite() && order.is_finite()) {
            return Err(FilterError::NonFinite("observation"));
        }
        if self.started {
            self.pf.predict(&self.model, &[order], &mut self.rng);
        } else {
            self.pf.initialize(&self.model, &mut self.rng);
            self.started = true;
        }
        self.pf.update(&self.model, &[y]).map_err(filter_error)?;
        self.summarise();
        let w = self.pf.weights();
        Ok(UpdateInfo {
            log_evidence: f64::NAN,
            ess: 1.0 / w.iter().map(|v| v * v).sum::<f64>(),
            resampled: true,
        })
    }
    fn belief(&self) -> Gaussian {
        self.belief
    }
}
