//! The estimator's workspace, sized once, and its warm start (the last
//! most likely path, advanced as time moves on).

use super::super::maps::RandomMapWorkspace;
use super::super::newton::NewtonWorkspace;
use super::super::path::PathSetup;
use crate::model::affine::PathStructure;
use crate::rng::SimRng;
use crate::MAX_STATE;
use rand::RngExt;
use rand_distr::StandardNormal;

/// Workspace of the estimator, sized once: no allocation per estimate.
pub struct PathSampler {
    pub(super) setup: PathSetup,
    pub(super) cap_steps: usize,
    pub(super) cap_samples: usize,
    pub(super) cap_components: usize,
    pub(super) newton: NewtonWorkspace,
    pub(super) rmap: RandomMapWorkspace,
    /// Reference draws, cap_samples × N (common to all components).
    pub(super) xi: Vec<f64>,
    /// Warm start (nominal minimiser of the previous estimate) and its steps.
    pub(super) warm: Vec<f64>,
    pub(super) warm_steps: usize,
    /// Per component: μ (N) and δμ_j (p × N).
    pub(super) mu: Vec<f64>,
    pub(super) dmu: Vec<f64>,
    /// Per component and sample: log weight − φ_c, and the derivatives D_j.
    pub(super) lw: Vec<f64>,
    pub(super) dval: Vec<f64>,
    /// Scratch: a sample, a gradient, an FD minimiser, FD log weights.
    pub(super) xs: Vec<f64>,
    pub(super) gz: Vec<f64>,
    pub(super) zfd: Vec<f64>,
    pub(super) lw_fd: Vec<f64>,
    /// Per component: φ, pinned variable, log mass, FD log masses (2p).
    pub(super) comp_phi: Vec<f64>,
    pub(super) comp_pin: Vec<Option<usize>>,
    /// ∂F/∂e at the μ of the last `directions` call.
    pub(super) ge_mu: [f64; 2 * MAX_STATE],
    /// Stratified uniforms (j + U_j)/M for the gate marginal, and the column
    /// H⁻¹e_k of the gated coordinate.
    pub(super) strata: Vec<f64>,
    pub(super) gate_col: Vec<f64>,
    pub(super) log_mass: Vec<f64>,
    pub(super) fd_log_mass: Vec<f64>,
    pub(super) scratch_c: Vec<f64>,
}

impl PathSampler {
    /// A sampler for horizons up to `cap_steps`, up to `cap_samples` samples
    /// and `cap_components` components (initial states × basins).
    pub fn new(
        setup: PathSetup,
        cap_steps: usize,
        cap_samples: usize,
        cap_components: usize,
    ) -> Self {
        let nmax = setup.dim(cap_steps).max(1);
        let kd = setup.bandwidth();
        let p = setup.p;
        let cc = cap_components.max(1);
        let cm = cap_samples.max(1);
        Self {
            newton: NewtonWorkspace::new(nmax, kd),
            rmap: RandomMapWorkspace::new(nmax),
            xi: vec![0.0; cm * nmax],
            warm: vec![0.0; nmax],
            warm_steps: 0,
            mu: vec![0.0; cc * nmax],
            dmu: vec![0.0; cc * p * nmax],
            lw: vec![0.0; cc * cm],
            dval: vec![0.0; cc * cm * p],
            xs: vec![0.0; nmax],
            gz: vec![0.0; nmax],
            zfd: vec![0.0; nmax],
            lw_fd: vec![0.0; cm],
            comp_phi: vec![0.0; cc],
            comp_pin: vec![None; cc],
            ge_mu: [0.0; 2 * MAX_STATE],
            strata: vec![0.0; cm],
            gate_col: vec![0.0; nmax],
            log_mass: vec![0.0; cc],
            fd_log_mass: vec![0.0; cc * 2 * p],
            scratch_c: vec![0.0; 2 * cc],
            setup,
            cap_steps,
            cap_samples,
            cap_components: cc,
        }
    }

    /// The problem constants.
    pub fn setup(&self) -> &PathSetup {
        &self.setup
    }

    /// Largest horizon.
    pub fn cap_steps(&self) -> usize {
        self.cap_steps
    }

    /// Largest number of samples.
    pub fn cap_samples(&self) -> usize {
        self.cap_samples
    }

    /// The nominal minimiser of the last estimate (the most likely path).
    pub fn warm_start(&self) -> &[f64] {
        &self.warm[..self.setup.dim(self.warm_steps)]
    }

    /// Steps of the stored warm start (0: none).
    pub fn warm_steps(&self) -> usize {
        self.warm_steps
    }

    /// Forget the warm start.
    pub fn reset_warm_start(&mut self) {
        self.warm_steps = 0;
    }

    /// Advance the warm start by `k` steps (time moved on) and resize it to
    /// `n` steps, extrapolating the tail linearly.
    pub fn shift_warm_start(&mut self, k: usize, n: usize) {
        self.advance_warm_start(k as f64, n);
    }

    /// Advance the warm start by `steps` path steps (time moved on by
    /// steps·Δt, not necessarily whole) and resize it to `n` steps. Whole
    /// steps drop blocks; the fraction φ re-samples the path between its
    /// grid points, z'_i = (1 − φ) z_i + φ z_{i+1}: the plan is a path of
    /// points at t + iΔt, so a control period shorter than Δt moves every
    /// point a fraction of a step along it. The block past the end and the
    /// tail up to n are extrapolated (constant for `Full`, linear for
    /// `SecondOrder` positions).
    pub fn advance_warm_start(&mut self, steps: f64, n: usize) {
        let b = self.setup.b;
        let old = self.warm_steps;
        if old == 0 || !(steps >= 0.0) || n == 0 || n > self.cap_steps {
            self.warm_steps = 0;
            return;
        }
        let k = steps.floor();
        if k >= old as f64 {
            self.warm_steps = 0;
            return;
        }
        let k = k as usize;
        let frac = steps - k as f64;
        if k > 0 {
            self.warm.copy_within(k * b..old * b, 0);
        }
        let have = old - k;
        let linear = self.setup.structure == PathStructure::SecondOrder;
        if frac > 1e-12 {
            for c in 0..b {
                let last = self.warm[(have - 1) * b + c];
                let prev = if have >= 2 {
                    self.warm[(have - 2) * b + c]
                } else {
                    last
                };
                let beyond = if linear { 2.0 * last - prev } else { last };
                for i in 0..have {
                    let next = if i + 1 < have {
                        self.warm[(i + 1) * b + c]
                    } else {
                        beyond
                    };
                    let v = &mut self.warm[i * b + c];
                    *v += frac * (next - *v);
                }
            }
        }
        for i in have..n {
            for c in 0..b {
                let last = self.warm[(i - 1) * b + c];
                let prev = if i >= 2 {
                    self.warm[(i - 2) * b + c]
                } else {
                    last
                };
                self.warm[i * b + c] = if linear { 2.0 * last - prev } else { last };
            }
        }
        self.warm_steps = n;
    }

    pub(super) fn draw(&mut self, rng: &mut SimRng, m: usize, nn: usize, antithetic: bool) {
        for j in 0..m {
            self.strata[j] = (j as f64 + rng.random::<f64>()) / m as f64;
        }
        for k in 0..m {
            if antithetic && k % 2 == 1 {
                let (a, b) = self.xi.split_at_mut(k * nn);
                for (d, s) in b[..nn].iter_mut().zip(&a[(k - 1) * nn..k * nn]) {
                    *d = -s;
                }
            } else {
                for v in self.xi[k * nn..(k + 1) * nn].iter_mut() {
                    *v = rng.sample(StandardNormal);
                }
            }
        }
    }
}
