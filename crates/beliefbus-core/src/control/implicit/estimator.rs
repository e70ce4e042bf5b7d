//! ψ and the optimal control by implicit sampling (paper 003 §3, eq. 16 and
//! eq. 10 with errata E4/E6):
//!
//! ```text
//! ψ(x,t) ≈ C_n · Σ_c e^{−φ_c} (2π)^{N/2} E_ξ[w_c(ξ)],   C_n = Δt^{−N/2} (det Σ_b)^{−n/2} J_z
//! u(x,t) = γ R⁻¹ Gᵀ ∂ₓ log ψ(x,t)
//! ```
//!
//! The sum runs over *components* c: one per initial state (the belief mean,
//! or draws from the belief, ψ̄ = (1/K) Σ_k ψ(x_k)) and per basin of F (one
//! per slit of a [`Gate`], each found by a constrained minimisation: the
//! unconstrained minimiser if it lies in the slit, otherwise the minimiser
//! with the gated coordinate pinned at the nearer slit edge — exact for
//! convex F). Every component uses the same reference draws ξ (common random
//! numbers), optionally antithetic (ξ, −ξ), which makes the linear-quadratic
//! case exact for any number of samples.
//!
//! Two ways to get ∂ₓ log ψ along the columns g_j of G:
//! - [`GradientMethod::FiniteDifference`] — the paper's: re-minimise and
//!   re-sample with the same ξ at x ± h g_j, central differences of log ψ
//!   (2p extra solves per component);
//! - [`GradientMethod::Analytic`] — the exact derivative of the linear-map
//!   estimator with the proposal centre moving as μ(x) (implicit function
//!   theorem, δμ = −H⁻¹ ∂²F/∂z∂x · δx) and L held fixed:
//!   `∂ log ψ̂ = −Σ_{c,k} W_{c,k} [∂ₓF(X_{c,k})·δx + ∇_z F(X_{c,k})·δμ_c]`,
//!   with the normalised weights W. It is exact whenever ∇²F does not depend
//!   on x (linear drift, quadratic costs), costs one banded solve per
//!   direction instead of a minimisation, and with M = 0 samples it reduces
//!   to the Laplace (most-likely-path) control −γR⁻¹Gᵀ∂ₓF(μ).

use super::maps::{linear_map, linear_map_log_weight, RandomMapWorkspace};
use super::newton::{NewtonError, NewtonOptions, NewtonWorkspace, Objective};
use super::path::{Gate, PathCost, PathFunctional, PathSetup};
use super::truncnorm;
use super::weights::log_sum_exp;
use crate::model::affine::{ControlAffine, PathStructure};
use crate::rng::SimRng;
use crate::{MAX_CONTROL, MAX_STATE};
use rand::RngExt;
use rand_distr::StandardNormal;

/// How ∂ₓ log ψ is computed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GradientMethod {
    /// Exact derivative of the linear-map estimator (see the module doc).
    Analytic,
    /// Central differences with step `h` and common random numbers.
    FiniteDifference { h: f64 },
    /// The likelihood-ratio (score) form ∂ₓ log ψ = −E_p[∂ₓF(Z; x)]
    /// estimated with the implicit-sampling weights at fixed samples:
    /// `∂ log ψ̂ = −Σ W_{c,k} ∂ₓF(X_{c,k})·δx`. For a control direction only
    /// the first K+1 steps of F depend on x, and to leading order in Δt the
    /// term is the first noise increment, u Δt ≈ B⁻¹ E_w[r₁] (the
    /// path-integral identity u dt = E_w[G dW₀]). No solve per direction
    /// and one value pass (not a gradient pass) per sample; consistent as
    /// M → ∞ (the analytic form is the exact derivative of the M-sample
    /// estimator), equal to it at M = 0 (envelope theorem) and exact for
    /// linear-quadratic problems with antithetic pairs.
    LikelihoodRatio,
}

/// Which map solves F(X) − φ = ½ξᵀξ.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MapKind {
    /// X = μ + L⁻ᵀξ, weight (6).
    Linear,
    /// X = μ + λ L⁻ᵀ ξ/|ξ|, Jacobian weight (E1).
    Random,
}

/// How a [`Gate`]'s basins are used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GateMode {
    /// Every basin, each sample weighted by (6) and by its slit's indicator.
    AllBasins,
    /// The paper's §3.1 recipe: only the basin of smallest φ, weight 1/det L
    /// times the fraction of samples passing any slit (no e^{F̂−F} factor).
    SmallestBasin,
}

/// How samples of a gated basin are generated (linear map, analytic gradient).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GateSampling {
    /// Draw the gated coordinate δ = X_k − μ_k from its Laplace marginal
    /// restricted to the slit, q(δ) ∝ e^{−g_k δ − δ²/(2s²)} (s² = (H⁻¹)_kk,
    /// g_k = ∂F/∂z_k(μ), non-zero at a pinned minimum), by its inverse CDF
    /// at stratified levels, and the other coordinates from the Gaussian
    /// N(μ, H⁻¹) conditioned on it; weight e^{−F}/q. Every sample passes
    /// the wall, and for quadratic F every weight is equal.
    Marginal,
    /// The plain linear map around the (constrained) minimum, samples
    /// outside the slit get weight 0 (about half of them).
    Rejection,
}

/// Settings of one estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EstimatorOptions {
    /// Samples M per component (0: Laplace approximation at the mode).
    pub samples: usize,
    /// Use antithetic pairs (ξ, −ξ).
    pub antithetic: bool,
    pub map: MapKind,
    pub gradient: GradientMethod,
    pub gate_mode: GateMode,
    /// Used with a gate, the linear map, all basins and the analytic gradient.
    pub gate_sampling: GateSampling,
    pub newton: NewtonOptions,
}

impl Default for EstimatorOptions {
    fn default() -> Self {
        Self {
            samples: 16,
            antithetic: true,
            map: MapKind::Linear,
            gradient: GradientMethod::Analytic,
            gate_mode: GateMode::AllBasins,
            gate_sampling: GateSampling::Marginal,
            newton: NewtonOptions::default(),
        }
    }
}

/// Why an estimate failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EstimateError {
    #[error("minimisation failed: {0}")]
    Newton(#[from] NewtonError),
    #[error("no sample has positive weight (every path hits the wall)")]
    NoMass,
    #[error("{0}")]
    Unsupported(&'static str),
    #[error("problem exceeds the sampler's capacity: {0}")]
    Capacity(&'static str),
}

/// Result of one estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// log ψ̄ including every constant (comparable with an analytic ψ).
    pub log_psi: f64,
    /// Gᵀ ∂ₓ log ψ̄.
    pub grad_g: [f64; MAX_CONTROL],
    /// u = γ R⁻¹ Gᵀ ∂ₓ log ψ̄.
    pub u: [f64; MAX_CONTROL],
    /// Smallest φ over the components.
    pub phi: f64,
    /// Effective sample size of all weights together.
    pub ess: f64,
    /// Samples evaluated (all components, not counting FD re-evaluations).
    pub samples: usize,
    /// Fraction of samples with positive weight (paths through the gate).
    pub pass_fraction: f64,
    /// Newton iterations of all minimisations.
    pub newton_iterations: usize,
    /// Components (initial states × basins) used.
    pub components: usize,
}

/// Workspace of the estimator, sized once: no allocation per estimate.
pub struct PathSampler {
    setup: PathSetup,
    cap_steps: usize,
    cap_samples: usize,
    cap_components: usize,
    newton: NewtonWorkspace,
    rmap: RandomMapWorkspace,
    /// Reference draws, cap_samples × N (common to all components).
    xi: Vec<f64>,
    /// Warm start (nominal minimiser of the previous estimate) and its steps.
    warm: Vec<f64>,
    warm_steps: usize,
    /// Per component: μ (N) and δμ_j (p × N).
    mu: Vec<f64>,
    dmu: Vec<f64>,
    /// Per component and sample: log weight − φ_c, and the derivatives D_j.
    lw: Vec<f64>,
    dval: Vec<f64>,
    /// Scratch: a sample, a gradient, an FD minimiser, FD log weights.
    xs: Vec<f64>,
    gz: Vec<f64>,
    zfd: Vec<f64>,
    lw_fd: Vec<f64>,
    /// Per component: φ, pinned variable, log mass, FD log masses (2p).
    comp_phi: Vec<f64>,
    comp_pin: Vec<Option<usize>>,
    /// ∂F/∂e at the μ of the last `directions` call.
    ge_mu: [f64; 2 * MAX_STATE],
    /// Stratified uniforms (j + U_j)/M for the gate marginal, and the column
    /// H⁻¹e_k of the gated coordinate.
    strata: Vec<f64>,
    gate_col: Vec<f64>,
    log_mass: Vec<f64>,
    fd_log_mass: Vec<f64>,
    scratch_c: Vec<f64>,
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

    fn draw(&mut self, rng: &mut SimRng, m: usize, nn: usize, antithetic: bool) {
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

    /// Estimate ψ̄ and the control at the `K = states.len()/m` initial
    /// states in `states` (flat, m each) with a horizon of `n` steps.
    #[allow(clippy::too_many_arguments)]
    pub fn estimate<M: ControlAffine + ?Sized, C: PathCost + ?Sized>(
        &mut self,
        model: &M,
        cost: &C,
        states: &[f64],
        n: usize,
        gate: Option<Gate>,
        opts: &EstimatorOptions,
        rng: &mut SimRng,
    ) -> Result<Estimate, EstimateError> {
        let st = self.setup.clone();
        let (m, p) = (st.m, st.p);
        let nn = st.dim(n);
        let n_states = states.len() / m;
        if n == 0 || n > self.cap_steps {
            return Err(EstimateError::Capacity("horizon"));
        }
        if opts.samples > self.cap_samples {
            return Err(EstimateError::Capacity("samples"));
        }
        let gate_var = match gate {
            Some(g) => Some(st.gate_variable(&g).filter(|&v| v < nn).ok_or(
                EstimateError::Unsupported(
                    "gates need a Full-structure model and a step within the horizon",
                ),
            )?),
            None => None,
        };
        let basins = gate.map_or(1, |g| g.count);
        let n_comp = n_states * basins;
        if n_comp == 0 || n_comp > self.cap_components {
            return Err(EstimateError::Capacity("components"));
        }
        if gate.is_some() && opts.map == MapKind::Random {
            // At a pinned minimum ∇F ≠ 0 and F − φ is not monotone along
            // every ray: the random map would not be one-to-one.
            return Err(EstimateError::Unsupported(
                "the random map does not support gates; use the linear map",
            ));
        }
        // Both weighted-gradient forms need the linear map; the likelihood-
        // ratio form skips the proposal-centre derivatives δμ.
        let lr = matches!(opts.gradient, GradientMethod::LikelihoodRatio);
        let analytic = lr || matches!(opts.gradient, GradientMethod::Analytic);
        if analytic
            && (opts.map == MapKind::Random
                || (gate.is_some() && opts.gate_mode == GateMode::SmallestBasin))
        {
            return Err(EstimateError::Unsupported(
                "the analytic gradient needs the linear map with every basin weighted; use finite differences",
            ));
        }
        let ms = opts.samples;
        let mstore = ms.max(1);
        self.draw(rng, ms, nn, opts.antithetic);
        if self.warm_steps != n {
            st.initial_path(model, &states[..m], n, &mut self.warm);
            self.warm_steps = n;
        }
        let mut iters = 0;
        let mut phi_min = f64::INFINITY;
        let mut passes = 0usize;
        let mut evaluated = 0usize;
        for si in 0..n_states {
            let x = &states[si * m..(si + 1) * m];
            let mut f = PathFunctional::new(&st, model, cost, x, n, None);
            let c0 = si * basins;
            // Unconstrained minimisation, then one constrained minimum per slit.
            self.mu[c0 * nn..(c0 + 1) * nn].copy_from_slice(&self.warm[..nn]);
            self.newton.pinned[..nn].fill(false);
            let r = self
                .newton
                .minimise(&f, &mut self.mu[c0 * nn..(c0 + 1) * nn], &opts.newton)?;
            iters += r.iterations;
            let mut last_factored = Some(c0);
            if basins > 1 {
                self.zfd[..nn].copy_from_slice(&self.mu[c0 * nn..(c0 + 1) * nn]);
            }
            for bi in 0..basins {
                let c = c0 + bi;
                if bi > 0 {
                    // Every basin starts from the unconstrained minimiser.
                    self.mu[c * nn..(c + 1) * nn].copy_from_slice(&self.zfd[..nn]);
                }
                self.comp_phi[c] = r.phi;
                self.comp_pin[c] = None;
                if let (Some(g), Some(gv)) = (gate, gate_var) {
                    let (lo, hi) = g.intervals[bi];
                    let v = self.mu[c * nn + gv];
                    if v < lo || v > hi {
                        self.mu[c * nn + gv] = if v < lo { lo } else { hi };
                        self.newton.pinned[..nn].fill(false);
                        self.newton.pinned[gv] = true;
                        let rc = self.newton.minimise(
                            &f,
                            &mut self.mu[c * nn..(c + 1) * nn],
                            &opts.newton,
                        )?;
                        iters += rc.iterations;
                        self.comp_phi[c] = rc.phi;
                        self.comp_pin[c] = Some(gv);
                        last_factored = Some(c);
                    }
                }
                phi_min = phi_min.min(self.comp_phi[c]);
            }
            let best = (0..basins)
                .min_by(|&a, &b| self.comp_phi[c0 + a].total_cmp(&self.comp_phi[c0 + b]))
                .unwrap_or(0);
            for bi in 0..basins {
                let c = c0 + bi;
                if gate.is_some() && opts.gate_mode == GateMode::SmallestBasin && bi != best {
                    self.log_mass[c] = f64::NEG_INFINITY;
                    self.fd_log_mass[c * 2 * p..(c + 1) * 2 * p].fill(f64::NEG_INFINITY);
                    continue;
                }
                let pin = self.comp_pin[c];
                let marginal = gate_var.is_some()
                    && analytic
                    && opts.map == MapKind::Linear
                    && opts.gate_sampling == GateSampling::Marginal;
                if gate_var.is_some() && (marginal || analytic) {
                    // Unconstrained factor at μ_c, column H⁻¹e_k, and δμ with
                    // the gated coordinate held (the slit does not move with x).
                    let current = pin.is_none()
                        && (last_factored == Some(c)
                            || (last_factored == Some(c0) && self.comp_pin[c0].is_none()));
                    if !current {
                        self.newton.pinned[..nn].fill(false);
                        self.newton.factor(&f, &self.mu[c * nn..(c + 1) * nn])?;
                    }
                    let k = gate_var.unwrap_or(0);
                    self.gate_col[..nn].fill(0.0);
                    self.gate_col[k] = 1.0;
                    self.newton.l.solve_in_place(&mut self.gate_col[..nn]);
                    if analytic && !lr {
                        self.directions(&f, c, nn, None, Some(k));
                    }
                } else {
                    // The factor in the workspace must be the (pinned) Hessian at μ_c.
                    let pinned_matches = last_factored == Some(c)
                        || (pin.is_none()
                            && last_factored == Some(c0)
                            && self.comp_pin[c0].is_none());
                    if !pinned_matches {
                        self.newton.pinned[..nn].fill(false);
                        if let Some(k) = pin {
                            self.newton.pinned[k] = true;
                        }
                        self.newton.factor(&f, &self.mu[c * nn..(c + 1) * nn])?;
                    }
                    if analytic && !lr {
                        self.directions(&f, c, nn, pin, None);
                    }
                    if pin.is_some() {
                        // Samples use the unconstrained Hessian (paper §3.1).
                        self.newton.pinned[..nn].fill(false);
                        self.newton.factor(&f, &self.mu[c * nn..(c + 1) * nn])?;
                    }
                }
                last_factored = None;
                let interval = gate.map(|g| (g.intervals[bi], gate_var.unwrap_or(0)));
                // With one component and no gate the workspace still holds ∇F(μ_c).
                let grad_valid = n_comp == 1 && gate.is_none();
                let (lm, np) = self.sample_component(
                    &f,
                    c,
                    nn,
                    ms,
                    interval,
                    gate,
                    opts,
                    analytic,
                    grad_valid && !lr,
                    marginal,
                );
                self.log_mass[c] = lm;
                passes += np;
                evaluated += mstore;
                if let GradientMethod::FiniteDifference { h } = opts.gradient {
                    let mut xp = [0.0; MAX_STATE];
                    for j in 0..p {
                        for (sgn, slot) in [(1.0, 0), (-1.0, 1)] {
                            for r in 0..m {
                                xp[r] = x[r] + sgn * h * st.g[r + j * m];
                            }
                            f.set_state(&xp[..m]);
                            let lmj =
                                self.fd_mass(&f, c, nn, ms, interval, gate, opts, &mut iters)?;
                            self.fd_log_mass[c * 2 * p + 2 * j + slot] = lmj;
                        }
                    }
                    f.set_state(x);
                }
            }
        }
        let log_total = log_sum_exp(&self.log_mass[..n_comp]);
        if !log_total.is_finite() {
            return Err(EstimateError::NoMass);
        }
        // ψ = (2πΔt)^{−N/2}(det Σ_b)^{−n/2} J_z ∫e^{−F}, ∫e^{−F} = (2π)^{N/2} Σ_c e^{−φ_c} E[w_c].
        let log_psi = log_total - (n_states as f64).ln() + st.log_psi_constant(n);
        // Global normalised weights over (component, sample).
        let all = log_sum_exp_components(&self.lw, n_comp, mstore, &self.log_mass);
        let mut grad_g = [0.0; MAX_CONTROL];
        let (mut ess_num, mut ess_den) = (0.0, 0.0);
        for c in 0..n_comp {
            if self.log_mass[c] == f64::NEG_INFINITY {
                continue;
            }
            for k in 0..mstore {
                let l = self.lw[c * mstore + k];
                if l == f64::NEG_INFINITY {
                    continue;
                }
                let w = (l - all).exp();
                ess_num += w;
                ess_den += w * w;
                if analytic {
                    for j in 0..p {
                        grad_g[j] -= w * self.dval[(c * mstore + k) * p + j];
                    }
                }
            }
        }
        if let GradientMethod::FiniteDifference { h } = opts.gradient {
            for j in 0..p {
                let (lp, lm) = self.scratch_c.split_at_mut(n_comp);
                for c in 0..n_comp {
                    lp[c] = self.fd_log_mass[c * 2 * p + 2 * j];
                    lm[c] = self.fd_log_mass[c * 2 * p + 2 * j + 1];
                }
                grad_g[j] = (log_sum_exp(lp) - log_sum_exp(&lm[..n_comp])) / (2.0 * h);
            }
        }
        let mut u = [0.0; MAX_CONTROL];
        for i in 0..p {
            let v: f64 = (0..p).map(|j| st.rinv[i + j * p] * grad_g[j]).sum();
            u[i] = st.gamma * v;
        }
        // Warm start for the next call: the first initial state's minimiser
        // (unconstrained unless every basin was pinned).
        self.warm[..nn].copy_from_slice(&self.mu[..nn]);
        self.warm_steps = n;
        Ok(Estimate {
            log_psi,
            grad_g,
            u,
            phi: phi_min,
            ess: if ess_den > 0.0 {
                ess_num * ess_num / ess_den
            } else {
                0.0
            },
            samples: evaluated,
            pass_fraction: if evaluated > 0 {
                passes as f64 / evaluated as f64
            } else {
                0.0
            },
            newton_iterations: iters,
            components: n_comp,
        })
    }

    /// δμ_j = −H⁻¹ (∂²F/∂z∂e) δe_j for each column g_j of G, with the factor
    /// in the workspace (pinned rows as identity, so pinned entries stay 0).
    fn directions<M: ControlAffine + ?Sized, C: PathCost + ?Sized>(
        &mut self,
        f: &PathFunctional<'_, M, C>,
        c: usize,
        nn: usize,
        pinned: Option<usize>,
        project: Option<usize>,
    ) {
        let st = f.setup;
        let (m, p) = (st.m, st.p);
        let lp = st.prefix_len();
        let mut ge = [0.0; 2 * MAX_STATE];
        let mut cross = [0.0; 4 * MAX_STATE * MAX_STATE];
        f.prefix_derivatives(&self.mu[c * nn..(c + 1) * nn], &mut ge, &mut cross);
        self.ge_mu = ge;
        let mut de = [0.0; 2 * MAX_STATE];
        for j in 0..p {
            st.prefix_direction(&st.g[j * m..(j + 1) * m], &mut de);
            let d = &mut self.dmu[(c * p + j) * nn..(c * p + j + 1) * nn];
            d.fill(0.0);
            for row in 0..lp.min(nn) {
                let v: f64 = (0..lp).map(|col| cross[row + col * lp] * de[col]).sum();
                d[row] = -v;
            }
            if let Some(k) = pinned {
                d[k] = 0.0;
            }
            self.newton.l.solve_in_place(d);
            if let Some(k) = project {
                // Hold z_k: δμ ← δμ − (δμ_k / (H⁻¹)_kk) H⁻¹e_k, the solution of
                // the system with row k replaced by the constraint δμ_k = 0.
                let col = &self.gate_col[..nn];
                let a = d[k] / col[k];
                for i in 0..nn {
                    d[i] -= a * col[i];
                }
                d[k] = 0.0;
            }
        }
    }

    /// Sample component c around μ_c with the factor in the workspace; store
    /// log weights (minus φ_c) and, for the analytic gradient, D_j. Returns
    /// (log mass, samples with positive weight).
    #[allow(clippy::too_many_arguments)]
    fn sample_component<M: ControlAffine + ?Sized, C: PathCost + ?Sized>(
        &mut self,
        f: &PathFunctional<'_, M, C>,
        c: usize,
        nn: usize,
        ms: usize,
        interval: Option<((f64, f64), usize)>,
        gate: Option<Gate>,
        opts: &EstimatorOptions,
        analytic: bool,
        grad_valid: bool,
        marginal: bool,
    ) -> (f64, usize) {
        if marginal {
            if let Some(((lo, hi), k)) = interval {
                return self.sample_component_marginal(f, c, nn, ms, lo, hi, k, opts);
            }
        }
        let Self {
            newton,
            rmap,
            xi,
            xs,
            gz,
            lw,
            dval,
            dmu,
            mu,
            comp_phi,
            ge_mu,
            ..
        } = self;
        let st = f.setup;
        let (m, p) = (st.m, st.p);
        let lp = st.prefix_len();
        let muc = &mu[c * nn..(c + 1) * nn];
        let phi = comp_phi[c];
        let log_det_l = newton.l.log_det_factor();
        let mstore = ms.max(1);
        let paper = gate.is_some() && opts.gate_mode == GateMode::SmallestBasin;
        let lr = matches!(opts.gradient, GradientMethod::LikelihoodRatio);
        let mut de = [[0.0; 2 * MAX_STATE]; MAX_CONTROL];
        for j in 0..p {
            st.prefix_direction(&st.g[j * m..(j + 1) * m], &mut de[j]);
        }
        let mut ge = [0.0; 2 * MAX_STATE];
        let mut npass = 0;
        for k in 0..mstore {
            let xik = &xi[k * nn..(k + 1) * nn];
            let mut l = if ms == 0 {
                xs[..nn].copy_from_slice(muc);
                -log_det_l
            } else {
                match opts.map {
                    MapKind::Linear => {
                        linear_map(muc, &newton.l, xik, xs);
                        f64::NAN // weight computed below
                    }
                    MapKind::Random => match rmap.sample(f, muc, phi, &newton.l, xik, xs) {
                        Ok(s) => s.log_jacobian,
                        Err(_) => f64::NEG_INFINITY,
                    },
                }
            };
            if !gate_pass(xs, interval, gate, opts.gate_mode) {
                l = f64::NEG_INFINITY;
            } else if l.is_nan() {
                l = if paper {
                    -log_det_l
                } else {
                    let half_rho: f64 = xik.iter().map(|v| 0.5 * v * v).sum();
                    let fx = if lr {
                        f.prefix_gradient(&xs[..nn], &mut ge);
                        f.value(&xs[..nn])
                    } else if analytic {
                        f.gradient_with_prefix(&xs[..nn], gz, &mut ge)
                    } else {
                        f.value(&xs[..nn])
                    };
                    linear_map_log_weight(half_rho, fx, phi, log_det_l)
                };
            } else if analytic && l.is_finite() {
                if lr {
                    f.prefix_gradient(&xs[..nn], &mut ge);
                } else if ms == 0 && grad_valid {
                    // The mode itself: reuse ∇F(μ) from Newton and ∂F/∂e(μ).
                    gz[..nn].copy_from_slice(&newton.g[..nn]);
                    ge = *ge_mu;
                } else {
                    f.gradient_with_prefix(&xs[..nn], gz, &mut ge);
                }
            }
            if l.is_finite() {
                npass += 1;
            }
            lw[c * mstore + k] = if l.is_finite() {
                l - phi
            } else {
                f64::NEG_INFINITY
            };
            if analytic && l.is_finite() {
                for j in 0..p {
                    let mut d: f64 = (0..lp).map(|r| ge[r] * de[j][r]).sum();
                    if !lr {
                        let dm = &dmu[(c * p + j) * nn..(c * p + j + 1) * nn];
                        for i in 0..nn {
                            d += gz[i] * dm[i];
                        }
                    }
                    dval[(c * mstore + k) * p + j] = d;
                }
            }
        }
        let lm = log_sum_exp(&lw[c * mstore..(c + 1) * mstore]) - (mstore as f64).ln();
        (lm, npass)
    }

    /// Sample component c with the gated coordinate k drawn from its Laplace
    /// marginal on [lo, hi] (see [`GateSampling::Marginal`]); the factor in
    /// the workspace is the unconstrained one at μ_c and `gate_col` = H⁻¹e_k.
    #[allow(clippy::too_many_arguments)]
    fn sample_component_marginal<M: ControlAffine + ?Sized, C: PathCost + ?Sized>(
        &mut self,
        f: &PathFunctional<'_, M, C>,
        c: usize,
        nn: usize,
        ms: usize,
        lo: f64,
        hi: f64,
        k: usize,
        opts: &EstimatorOptions,
    ) -> (f64, usize) {
        let lr = matches!(opts.gradient, GradientMethod::LikelihoodRatio);
        let Self {
            newton,
            xi,
            xs,
            gz,
            lw,
            dval,
            dmu,
            mu,
            comp_phi,
            strata,
            gate_col,
            ..
        } = self;
        let st = f.setup;
        let (m, p) = (st.m, st.p);
        let lp = st.prefix_len();
        let muc = &mu[c * nn..(c + 1) * nn];
        let phi = comp_phi[c];
        let log_det_l = newton.l.log_det_factor();
        let s2 = gate_col[k];
        let s = s2.sqrt();
        let gk = newton.g[k];
        // δ = X_k − μ_k ~ N(m1, s²) restricted to [lo − μ_k, hi − μ_k], m1 = −g_k s².
        let m1 = -gk * s2;
        let alpha = (lo - muc[k] - m1) / s;
        let beta = (hi - muc[k] - m1) / s;
        let log_z = 0.5 * gk * gk * s2 + truncnorm::ln_mass(alpha, beta);
        let mstore = ms.max(1);
        let mut de = [[0.0; 2 * MAX_STATE]; MAX_CONTROL];
        for j in 0..p {
            st.prefix_direction(&st.g[j * m..(j + 1) * m], &mut de[j]);
        }
        let mut ge = [0.0; 2 * MAX_STATE];
        let mut npass = 0;
        for j in 0..mstore {
            let delta = if ms == 0 {
                m1.clamp(lo - muc[k], hi - muc[k])
            } else {
                m1 + s * truncnorm::quantile(alpha, beta, strata[j])
            };
            // Y = L⁻ᵀξ, then condition on Y_k = δ: X = μ + Y + H⁻¹e_k (δ − Y_k)/s².
            if ms == 0 {
                xs[..nn].fill(0.0);
            } else {
                xs[..nn].copy_from_slice(&xi[j * nn..(j + 1) * nn]);
                newton.l.solve_upper_in_place(&mut xs[..nn]);
            }
            let shift = (delta - xs[k]) / s2;
            for i in 0..nn {
                xs[i] += gate_col[i] * shift;
            }
            // F̂ − φ = ½ ‖Lᵀ(X − μ)‖², with X − μ still in xs.
            let half_quad = 0.5 * newton.l.upper_norm_sq(&xs[..nn]);
            for i in 0..nn {
                xs[i] += muc[i];
            }
            let fx = if lr {
                f.prefix_gradient(&xs[..nn], &mut ge);
                f.value(&xs[..nn])
            } else {
                f.gradient_with_prefix(&xs[..nn], gz, &mut ge)
            };
            let l = -log_det_l + log_z + half_quad - (fx - phi) + gk * delta;
            if l.is_finite() {
                npass += 1;
            }
            lw[c * mstore + j] = if l.is_finite() {
                l - phi
            } else {
                f64::NEG_INFINITY
            };
            if l.is_finite() {
                for jj in 0..p {
                    let mut d: f64 = (0..lp).map(|r| ge[r] * de[jj][r]).sum();
                    if !lr {
                        let dm = &dmu[(c * p + jj) * nn..(c * p + jj + 1) * nn];
                        for i in 0..nn {
                            d += gz[i] * dm[i];
                        }
                    }
                    dval[(c * mstore + j) * p + jj] = d;
                }
            }
        }
        let lm = log_sum_exp(&lw[c * mstore..(c + 1) * mstore]) - (mstore as f64).ln();
        (lm, npass)
    }

    /// Log mass of component c at the perturbed state held by `f`:
    /// re-minimise from μ_c with the same pin, refactor, same ξ.
    #[allow(clippy::too_many_arguments)]
    fn fd_mass<M: ControlAffine + ?Sized, C: PathCost + ?Sized>(
        &mut self,
        f: &PathFunctional<'_, M, C>,
        c: usize,
        nn: usize,
        ms: usize,
        interval: Option<((f64, f64), usize)>,
        gate: Option<Gate>,
        opts: &EstimatorOptions,
        iters: &mut usize,
    ) -> Result<f64, EstimateError> {
        let Self {
            newton,
            rmap,
            xi,
            xs,
            zfd,
            lw_fd,
            mu,
            comp_pin,
            ..
        } = self;
        let pin = comp_pin[c];
        zfd[..nn].copy_from_slice(&mu[c * nn..(c + 1) * nn]);
        newton.pinned[..nn].fill(false);
        if let Some(k) = pin {
            newton.pinned[k] = true;
        }
        let r = newton.minimise(f, &mut zfd[..nn], &opts.newton)?;
        *iters += r.iterations;
        if pin.is_some() {
            newton.pinned[..nn].fill(false);
            newton.factor(f, &zfd[..nn])?;
        }
        let phi = r.phi;
        let log_det_l = newton.l.log_det_factor();
        if ms == 0 {
            return Ok(-phi - log_det_l);
        }
        let paper = gate.is_some() && opts.gate_mode == GateMode::SmallestBasin;
        for k in 0..ms {
            let xik = &xi[k * nn..(k + 1) * nn];
            lw_fd[k] = match opts.map {
                MapKind::Linear => {
                    let hr = linear_map(&zfd[..nn], &newton.l, xik, xs);
                    if !gate_pass(xs, interval, gate, opts.gate_mode) {
                        f64::NEG_INFINITY
                    } else if paper {
                        -log_det_l
                    } else {
                        linear_map_log_weight(hr, f.value(&xs[..nn]), phi, log_det_l)
                    }
                }
                MapKind::Random => match rmap.sample(f, &zfd[..nn], phi, &newton.l, xik, xs) {
                    Ok(s) if gate_pass(xs, interval, gate, opts.gate_mode) => s.log_jacobian,
                    _ => f64::NEG_INFINITY,
                },
            };
        }
        Ok(log_sum_exp(&lw_fd[..ms]) - (ms as f64).ln() - phi)
    }
}

fn gate_pass(
    x: &[f64],
    interval: Option<((f64, f64), usize)>,
    gate: Option<Gate>,
    mode: GateMode,
) -> bool {
    match (interval, gate) {
        (Some(((lo, hi), gv)), Some(g)) => {
            let v = x[gv];
            match mode {
                GateMode::AllBasins => v >= lo && v <= hi,
                GateMode::SmallestBasin => g.interval_of(v).is_some(),
            }
        }
        _ => true,
    }
}

/// log Σ_{c,k} e^{lw[c,k]} over the components with positive mass.
fn log_sum_exp_components(lw: &[f64], n_comp: usize, mstore: usize, log_mass: &[f64]) -> f64 {
    let live = |c: &usize| log_mass[*c] != f64::NEG_INFINITY;
    let mx = (0..n_comp)
        .filter(live)
        .flat_map(|c| lw[c * mstore..(c + 1) * mstore].iter().copied())
        .fold(f64::NEG_INFINITY, f64::max);
    if mx == f64::NEG_INFINITY {
        return mx;
    }
    let s: f64 = (0..n_comp)
        .filter(live)
        .flat_map(|c| lw[c * mstore..(c + 1) * mstore].iter().copied())
        .map(|l| (l - mx).exp())
        .sum();
    mx + s.ln()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::implicit::path::DiagonalQuadraticCost;
    use crate::model::affine::{LinearAffine, PathStructure};
    use crate::model::double_slit::{DoubleSlit, SlitCost};
    use nalgebra::{Matrix2, Vector2};

    fn double_integrator(q: f64) -> LinearAffine {
        LinearAffine {
            m: 2,
            p: 1,
            r: 1,
            a: vec![0.0, 0.0, 1.0, 0.0],
            g: vec![0.0, 1.0],
            q: vec![q],
            structure: PathStructure::SecondOrder,
        }
    }

    /// P₀ of the discretised problem the path functional encodes: Euler
    /// dynamics y_i = y_{i−1} + (A y_{i−1} + G u_{i−1})Δt, control cost
    /// Δt·½uᵀRu, trapezoidal ½xᵀWx and terminal ½xᵀW_f x.
    fn discrete_riccati(
        a: Matrix2<f64>,
        g: Vector2<f64>,
        r: f64,
        w: Matrix2<f64>,
        wf: Matrix2<f64>,
        dt: f64,
        n: usize,
    ) -> Matrix2<f64> {
        let ad = Matrix2::identity() + a * dt;
        let bd = g * dt;
        let mut p = wf + w * (dt / 2.0);
        for i in (0..n).rev() {
            let c = if i == 0 { dt / 2.0 } else { dt };
            let s = dt * r + (bd.transpose() * p * bd)[(0, 0)];
            let k = (bd.transpose() * p * ad) / s;
            p = w * c + ad.transpose() * p * ad - (ad.transpose() * p * bd) * k;
        }
        p
    }

    fn sampler_for(model: &LinearAffine, r: f64, dt: f64, n: usize, m: usize) -> PathSampler {
        let setup = PathSetup::new(model, &[r], dt).unwrap();
        PathSampler::new(setup, n, m, 4)
    }

    /// Acceptance test: on a linear-quadratic problem the controller's
    /// u = γR⁻¹Gᵀ∂ₓ log ψ equals the Riccati control of the same
    /// discretisation (to 1e-6), for every gradient method and sample size.
    #[test]
    fn linear_quadratic_control_equals_discrete_riccati() {
        let model = double_integrator(0.7);
        let (r, dt, n) = (0.5, 0.05, 40);
        let cost = DiagonalQuadraticCost::new(&[1.0, 0.2], &[3.0, 1.0]);
        let p0 = discrete_riccati(
            Matrix2::new(0.0, 1.0, 0.0, 0.0),
            Vector2::new(0.0, 1.0),
            r,
            Matrix2::new(1.0, 0.0, 0.0, 0.2),
            Matrix2::new(3.0, 0.0, 0.0, 1.0),
            dt,
            n,
        );
        let x = [1.3, -0.4];
        let u_ref = -(p0 * Vector2::new(x[0], x[1]))[1] / r;
        let mut rng = crate::rng::stream(3, 0);
        for (samples, gradient) in [
            (0, GradientMethod::Analytic),
            (16, GradientMethod::Analytic),
            (0, GradientMethod::FiniteDifference { h: 1e-4 }),
            (16, GradientMethod::FiniteDifference { h: 1e-4 }),
            (0, GradientMethod::LikelihoodRatio),
            (16, GradientMethod::LikelihoodRatio),
        ] {
            let mut s = sampler_for(&model, r, dt, n, 16);
            let opts = EstimatorOptions {
                samples,
                gradient,
                ..EstimatorOptions::default()
            };
            let e = s
                .estimate(&model, &cost, &x, n, None, &opts, &mut rng)
                .unwrap();
            assert!(
                (e.u[0] - u_ref).abs() < 1e-6 * (1.0 + u_ref.abs()),
                "{samples} samples, {gradient:?}: u = {} vs Riccati {u_ref}",
                e.u[0]
            );
            // Quadratic F: every weight equal.
            assert!((e.ess - samples.max(1) as f64).abs() < 1e-6 * samples.max(1) as f64);
            // J = −γ log ψ: φ equals the discrete optimal cost-to-go over γ.
            let j = 0.5
                * (Vector2::new(x[0], x[1]).transpose() * p0 * Vector2::new(x[0], x[1]))[(0, 0)];
            assert!((e.phi * s.setup().gamma - j).abs() < 1e-8 * j);
        }
    }

    /// E5/E6 for partial noise: log ψ including every constant (Δt^{−N/2},
    /// (det Σ)^{−n/2} and the Jacobian of the velocity→position change of
    /// variables) equals the Gaussian integral done directly over the
    /// velocities v₁..v_n with positions q_i = q_{i−1} + v_{i−1}Δt.
    #[test]
    fn second_order_log_psi_equals_the_integral_over_velocities() {
        let (q, r, dt, n) = (0.7, 0.5, 0.1, 5);
        let model = double_integrator(q);
        let cost = DiagonalQuadraticCost::new(&[1.0, 0.2], &[3.0, 1.0]);
        let mut s = sampler_for(&model, r, dt, n, 4);
        let gamma = s.setup().gamma;
        let x = [0.4, -0.8];
        let e = s
            .estimate(
                &model,
                &cost,
                &x,
                n,
                None,
                &EstimatorOptions {
                    samples: 0,
                    ..EstimatorOptions::default()
                },
                &mut crate::rng::stream(1, 1),
            )
            .unwrap();
        // F over velocities, written out directly.
        let f = |v: &[f64]| {
            let vv = |i: usize| if i == 0 { x[1] } else { v[i - 1] };
            let mut qs = vec![x[0]];
            for i in 1..=n {
                qs.push(qs[i - 1] + vv(i - 1) * dt);
            }
            let pot = |i: usize| 0.5 * qs[i] * qs[i] + 0.5 * 0.2 * vv(i) * vv(i);
            let mut tot = (1.5 * qs[n] * qs[n] + 0.5 * vv(n) * vv(n)) / gamma;
            for i in 1..=n {
                tot += dt / (2.0 * gamma) * (pot(i) + pot(i - 1));
                tot += (vv(i) - vv(i - 1)).powi(2) / (2.0 * q * q * dt);
            }
            tot
        };
        // Quadratic: F(v) = c + bᵀv + ½vᵀAv, read off by (exact) differences.
        let h = 1.0;
        let zero = vec![0.0; n];
        let c0 = f(&zero);
        let mut a = nalgebra::DMatrix::zeros(n, n);
        let mut b = nalgebra::DVector::zeros(n);
        for i in 0..n {
            let mut ei = zero.clone();
            ei[i] = h;
            let fp = f(&ei);
            ei[i] = -h;
            let fm = f(&ei);
            b[i] = (fp - fm) / (2.0 * h);
            a[(i, i)] = (fp - 2.0 * c0 + fm) / (h * h);
            for j in 0..i {
                let mut eij = zero.clone();
                eij[i] = h;
                eij[j] = h;
                let fij = f(&eij);
                eij[i] = 0.0;
                let fj = f(&eij);
                let mut ei2 = zero.clone();
                ei2[i] = h;
                let fi = f(&ei2);
                a[(i, j)] = (fij - fi - fj + c0) / (h * h);
                a[(j, i)] = a[(i, j)];
            }
        }
        let chol = a.clone().cholesky().unwrap();
        let ainv_b = chol.solve(&b);
        let log_det_a: f64 = 2.0 * chol.l().diagonal().iter().map(|v| v.ln()).sum::<f64>();
        let nf = n as f64;
        let log_integral =
            -c0 + 0.5 * b.dot(&ainv_b) + 0.5 * nf * (2.0 * std::f64::consts::PI).ln()
                - 0.5 * log_det_a;
        let log_psi = log_integral
            - 0.5 * nf * (2.0 * std::f64::consts::PI * dt).ln()
            - 0.5 * nf * (q * q).ln();
        assert!(
            (e.log_psi - log_psi).abs() < 1e-8,
            "{} vs {log_psi}",
            e.log_psi
        );
    }

    /// Acceptance test: over a long horizon the control approaches the
    /// continuous-time LQR law of ẍ = u with cost ∫ ½(x₁² + u²): K = [1, √2].
    #[test]
    fn long_horizon_control_approaches_continuous_lqr() {
        let model = double_integrator(1.0);
        let (r, dt, n) = (1.0, 0.01, 1000);
        let cost = DiagonalQuadraticCost::new(&[1.0, 0.0], &[0.0, 0.0]);
        let mut s = sampler_for(&model, r, dt, n, 16);
        let mut rng = crate::rng::stream(4, 0);
        for x in [[1.0, 0.5], [-2.0, 0.3]] {
            let e = s
                .estimate(
                    &model,
                    &cost,
                    &x,
                    n,
                    None,
                    &EstimatorOptions::default(),
                    &mut rng,
                )
                .unwrap();
            let lqr = -(x[0] + 2f64.sqrt() * x[1]);
            // Euler with Δt = 0.01 moves the gain by O(Δt): 2 % tolerance.
            assert!(
                (e.u[0] - lqr).abs() < 0.02 * lqr.abs(),
                "u = {} vs LQR {lqr}",
                e.u[0]
            );
        }
    }

    /// Acceptance test: the discretised ψ of the double slit after the wall
    /// equals the analytic ψ (notes check 4: 0.191380 at x = 1, t = t₁).
    #[test]
    fn double_slit_psi_after_the_wall_matches_analytic() {
        let p = DoubleSlit::default();
        let model = p.model();
        let setup = PathSetup::new(&model, &[p.r], p.dt).unwrap();
        let mut s = PathSampler::new(setup, 100, 32, 4);
        let mut rng = crate::rng::stream(5, 0);
        for (x, t) in [(1.0, 1.0), (-4.5, 1.0), (2.0, 1.5), (7.0, 1.98)] {
            let n = p.steps_from(t);
            for samples in [0, 32] {
                let opts = EstimatorOptions {
                    samples,
                    ..EstimatorOptions::default()
                };
                let e = s
                    .estimate(&model, &SlitCost, &[x], n, None, &opts, &mut rng)
                    .unwrap();
                let exact = p.log_psi(x, t);
                assert!(
                    (e.log_psi - exact).abs() < 1e-9,
                    "x={x} t={t}: {} vs {exact}",
                    e.log_psi
                );
                assert!((e.u[0] - p.control(x, t)).abs() < 1e-7 * (1.0 + e.u[0].abs()));
            }
        }
        let e = s
            .estimate(
                &model,
                &SlitCost,
                &[1.0],
                50,
                None,
                &EstimatorOptions::default(),
                &mut rng,
            )
            .unwrap();
        assert!((e.log_psi.exp() - 0.191380).abs() < 1e-6);
        // The printed path term with γ instead of σ gives 0.058 (E7): the
        // discrete ψ is sensitive to it, so this test would catch it.
    }

    /// Before the wall: two basins, weighted samples. ψ(1, 0) and u(1, 0)
    /// agree with the erf solution within Monte Carlo error.
    #[test]
    fn double_slit_psi_before_the_wall_matches_analytic() {
        let p = DoubleSlit::default();
        let model = p.model();
        let setup = PathSetup::new(&model, &[p.r], p.dt).unwrap();
        let m = 4000;
        let mut s = PathSampler::new(setup, 100, m, 4);
        let mut rng = crate::rng::stream(6, 0);
        let n = p.steps_from(0.0);
        let gate = p.gate_from(0.0);
        assert_eq!(gate.unwrap().step, 50);
        for gradient in [
            GradientMethod::Analytic,
            GradientMethod::FiniteDifference { h: 1e-4 },
        ] {
            let opts = EstimatorOptions {
                samples: m,
                gradient,
                ..EstimatorOptions::default()
            };
            let e = s
                .estimate(&model, &SlitCost, &[1.0], n, gate, &opts, &mut rng)
                .unwrap();
            let exact = p.log_psi(1.0, 0.0);
            // Relative error of an importance-sampling mean ~ 1/√ESS: 4σ bound.
            let tol = 4.0 / e.ess.sqrt();
            assert!(e.ess > 50.0, "ESS {}", e.ess);
            assert!(
                (e.log_psi - exact).abs() < tol,
                "log ψ {} vs {exact} (tol {tol})",
                e.log_psi
            );
            let u = p.control(1.0, 0.0);
            assert!(
                (e.u[0] - u).abs() < 0.02 * u.abs(),
                "{gradient:?}: u {} vs {u}",
                e.u[0]
            );
            if gradient == GradientMethod::Analytic {
                // Gate marginal: every sample passes, all weights are equal
                // (F is quadratic) and ψ is exact to rounding.
                assert_eq!(e.pass_fraction, 1.0);
                // Equal weights within each slit; the upper slit carries e⁻⁹ of the mass.
                assert!(e.ess > 0.999 * m as f64, "ESS {}", e.ess);
                assert!(
                    (e.log_psi - exact).abs() < 1e-9,
                    "log ψ {} vs {exact}",
                    e.log_psi
                );
                assert!((e.u[0] - u).abs() < 1e-3 * u.abs(), "u {} vs {u}", e.u[0]);
            } else {
                // Rejection: both slits pinned at their inner edge, about half pass.
                assert!(
                    e.pass_fraction > 0.4 && e.pass_fraction < 0.6,
                    "{}",
                    e.pass_fraction
                );
            }
        }
        // The paper's recipe (smallest basin, indicator only) also lands near.
        let opts = EstimatorOptions {
            samples: m,
            gradient: GradientMethod::FiniteDifference { h: 1e-4 },
            gate_mode: GateMode::SmallestBasin,
            ..EstimatorOptions::default()
        };
        let e = s
            .estimate(&model, &SlitCost, &[1.0], n, gate, &opts, &mut rng)
            .unwrap();
        assert!(
            (e.u[0] - p.control(1.0, 0.0)).abs() < 0.2 * 5.1,
            "paper recipe u {}",
            e.u[0]
        );
    }

    /// The likelihood-ratio control −γR⁻¹Gᵀ E_w[∂ₓF] (no extra solves)
    /// against the analytic u(1, 0) of the double slit and the paper's
    /// finite differences: 40 independent estimates of 64 samples each; the
    /// mean agrees with both within 4 standard errors (of the difference).
    #[test]
    fn likelihood_ratio_control_agrees_with_fd_and_the_exact_double_slit_control() {
        let p = DoubleSlit::default();
        let model = p.model();
        let setup = PathSetup::new(&model, &[p.r], p.dt).unwrap();
        let m = 64;
        let mut s = PathSampler::new(setup, 100, m, 4);
        let mut rng = crate::rng::stream(8, 0);
        let n = p.steps_from(0.0);
        let gate = p.gate_from(0.0);
        let exact = p.control(1.0, 0.0);
        let mut stats = vec![];
        for gradient in [
            GradientMethod::LikelihoodRatio,
            GradientMethod::FiniteDifference { h: 1e-4 },
        ] {
            let opts = EstimatorOptions {
                samples: m,
                gradient,
                gate_sampling: GateSampling::Rejection,
                ..EstimatorOptions::default()
            };
            let us: Vec<f64> = (0..40)
                .map(|_| {
                    s.estimate(&model, &SlitCost, &[1.0], n, gate, &opts, &mut rng)
                        .unwrap()
                        .u[0]
                })
                .collect();
            let mean = us.iter().sum::<f64>() / us.len() as f64;
            let var = us.iter().map(|u| (u - mean).powi(2)).sum::<f64>() / (us.len() - 1) as f64;
            stats.push((mean, (var / us.len() as f64).sqrt()));
        }
        let ((lr, se_lr), (fd, se_fd)) = (stats[0], stats[1]);
        // Self-normalised weights bias the mean by O(1/M): allow 1 % of u.
        assert!(
            (lr - exact).abs() < 4.0 * se_lr + 0.01 * exact.abs(),
            "LR {lr} ± {se_lr} vs exact {exact}"
        );
        assert!(
            (lr - fd).abs() < 4.0 * (se_lr * se_lr + se_fd * se_fd).sqrt() + 0.01 * exact.abs(),
            "LR {lr} ± {se_lr} vs FD {fd} ± {se_fd}"
        );
        // The marginal gate sampler (every sample passes) gives it too.
        let opts = EstimatorOptions {
            samples: 1000,
            gradient: GradientMethod::LikelihoodRatio,
            ..EstimatorOptions::default()
        };
        let mut s = PathSampler::new(PathSetup::new(&model, &[p.r], p.dt).unwrap(), 100, 1000, 4);
        let e = s
            .estimate(&model, &SlitCost, &[1.0], n, gate, &opts, &mut rng)
            .unwrap();
        assert!(
            (e.u[0] - exact).abs() < 0.03 * exact.abs(),
            "{} vs {exact}",
            e.u[0]
        );
    }

    /// The warm start advanced by a fraction of a step re-samples the plan
    /// between its grid points: a second-order plan with positions linear in
    /// time moves exactly (tail extrapolated linearly), whole and
    /// fractional parts combine, and beyond the plan it resets.
    #[test]
    fn warm_start_advances_by_fractional_steps() {
        let model = double_integrator(1.0);
        let (dt, n) = (0.04, 20);
        let mut s = sampler_for(&model, 0.5, dt, n, 1);
        // z_i = q(t + (i+1)Δt) with q(τ) = 0.3 + 1.7 τ.
        let q = |tau: f64| 0.3 + 1.7 * tau;
        let mut rng = crate::rng::stream(1, 0);
        let cost = DiagonalQuadraticCost::new(&[1.0, 0.2], &[3.0, 1.0]);
        let opts = EstimatorOptions {
            samples: 0,
            ..EstimatorOptions::default()
        };
        s.estimate(&model, &cost, &[0.3, 1.7], n, None, &opts, &mut rng)
            .unwrap();
        for i in 0..n {
            s.warm[i] = q((i + 1) as f64 * dt);
        }
        s.advance_warm_start(0.25, n);
        for i in 0..n {
            let want = q((i as f64 + 1.25) * dt);
            assert!((s.warm_start()[i] - want).abs() < 1e-12, "{i}");
        }
        s.advance_warm_start(1.5, n - 2);
        assert_eq!(s.warm_steps(), n - 2);
        for i in 0..n - 2 {
            let want = q((i as f64 + 2.75) * dt);
            assert!((s.warm_start()[i] - want).abs() < 1e-12, "{i}");
        }
        // Whole steps still shift as before.
        s.shift_warm_start(1, n);
        assert!((s.warm_start()[0] - q(3.75 * dt)).abs() < 1e-12);
        assert!((s.warm_start()[n - 1] - q((n as f64 + 2.75) * dt)).abs() < 1e-12);
        s.advance_warm_start(n as f64 + 0.5, n);
        assert_eq!(s.warm_steps(), 0);
    }

    /// The random map gives the same ψ as the linear map on a Gaussian F.
    #[test]
    fn random_map_estimate_agrees_on_gaussian_paths() {
        let p = DoubleSlit::default();
        let model = p.model();
        let setup = PathSetup::new(&model, &[p.r], p.dt).unwrap();
        let mut s = PathSampler::new(setup, 60, 8, 2);
        let mut rng = crate::rng::stream(7, 0);
        let opts = EstimatorOptions {
            samples: 8,
            map: MapKind::Random,
            gradient: GradientMethod::FiniteDifference { h: 1e-4 },
            ..EstimatorOptions::default()
        };
        let e = s
            .estimate(&model, &SlitCost, &[1.0], 50, None, &opts, &mut rng)
            .unwrap();
        assert!((e.log_psi - p.log_psi(1.0, 1.0)).abs() < 1e-8);
        assert!((e.ess - 8.0).abs() < 1e-6);
        assert!((e.u[0] - p.control(1.0, 1.0)).abs() < 1e-5);
    }
}
