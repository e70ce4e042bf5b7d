//! One estimate of ψ̄ and the control (eq. 16, eq. 10 with E4): check the
//! request, minimise F per initial state and basin, sample each component,
//! then combine the components' log masses and weights.

use super::super::path::{Gate, PathCost, PathFunctional, PathSetup};
use super::super::weights::log_sum_exp;
use super::components::log_sum_exp_components;
use super::{
    Estimate, EstimateError, EstimatorOptions, GateMode, GateSampling, GradientMethod, MapKind,
    PathSampler,
};
use crate::model::affine::ControlAffine;
use crate::rng::SimRng;
use crate::{MAX_CONTROL, MAX_STATE};

/// The shape of one estimate, fixed by its request.
struct Plan {
    /// Path variables N.
    nn: usize,
    n_states: usize,
    /// The gated path variable, if a gate applies.
    gate_var: Option<usize>,
    /// Basins per initial state (slits of the gate, or 1).
    basins: usize,
    n_comp: usize,
    /// Likelihood-ratio gradient; any weighted-gradient form (analytic or LR).
    lr: bool,
    analytic: bool,
    /// Samples M, and the slots per component (max(M, 1)).
    ms: usize,
    mstore: usize,
}

/// Running totals over the components.
struct Tally {
    iters: usize,
    phi_min: f64,
    passes: usize,
    evaluated: usize,
}

impl PathSampler {
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
        let m = st.m;
        let plan = self.plan(&st, states, n, gate, opts)?;
        self.draw(rng, plan.ms, plan.nn, opts.antithetic);
        if self.warm_steps != n {
            st.initial_path(model, &states[..m], n, &mut self.warm);
            self.warm_steps = n;
        }
        let mut tally = Tally {
            iters: 0,
            phi_min: f64::INFINITY,
            passes: 0,
            evaluated: 0,
        };
        for si in 0..plan.n_states {
            let x = &states[si * m..(si + 1) * m];
            let mut f = PathFunctional::new(&st, model, cost, x, n, None);
            let c0 = si * plan.basins;
            let last_factored = self.minimise_basins(&f, c0, &plan, gate, opts, &mut tally)?;
            self.sample_basins(&mut f, x, c0, last_factored, &plan, gate, opts, &mut tally)?;
        }
        self.combine(&st, &plan, n, opts, &tally)
    }

    /// Check the request against the capacity and the supported option
    /// combinations; its [`Plan`].
    fn plan(
        &self,
        st: &PathSetup,
        states: &[f64],
        n: usize,
        gate: Option<Gate>,
        opts: &EstimatorOptions,
    ) -> Result<Plan, EstimateError> {
        let nn = st.dim(n);
        let n_states = states.len() / st.m;
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
        Ok(Plan {
            nn,
            n_states,
            gate_var,
            basins,
            n_comp,
            lr,
            analytic,
            ms: opts.samples,
            mstore: opts.samples.max(1),
        })
    }

    /// Unconstrained minimisation of F from the warm start into μ_{c0}, then
    /// one constrained minimum per slit: a basin whose slit misses the
    /// unconstrained minimiser is re-minimised with the gated coordinate
    /// pinned at the nearer edge. Returns the component whose (pinned)
    /// Hessian the workspace holds factored.
    fn minimise_basins<M: ControlAffine + ?Sized, C: PathCost + ?Sized>(
        &mut self,
        f: &PathFunctional<'_, M, C>,
        c0: usize,
        plan: &Plan,
        gate: Option<Gate>,
        opts: &EstimatorOptions,
        tally: &mut Tally,
    ) -> Result<Option<usize>, EstimateError> {
        let (nn, basins) = (plan.nn, plan.basins);
        self.mu[c0 * nn..(c0 + 1) * nn].copy_from_slice(&self.warm[..nn]);
        self.newton.pinned[..nn].fill(false);
        let r = self
            .newton
            .minimise(f, &mut self.mu[c0 * nn..(c0 + 1) * nn], &opts.newton)?;
        tally.iters += r.iterations;
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
            if let (Some(g), Some(gv)) = (gate, plan.gate_var) {
                let (lo, hi) = g.intervals[bi];
                let v = self.mu[c * nn + gv];
                if v < lo || v > hi {
                    self.mu[c * nn + gv] = if v < lo { lo } else { hi };
                    self.newton.pinned[..nn].fill(false);
                    self.newton.pinned[gv] = true;
                    let rc = self.newton.minimise(
                        f,
                        &mut self.mu[c * nn..(c + 1) * nn],
                        &opts.newton,
                    )?;
                    tally.iters += rc.iterations;
                    self.comp_phi[c] = rc.phi;
                    self.comp_pin[c] = Some(gv);
                    last_factored = Some(c);
                }
            }
            tally.phi_min = tally.phi_min.min(self.comp_phi[c]);
        }
        Ok(last_factored)
    }

    /// Sample every basin of the initial state `x` (components c0..):
    /// factor, δμ, samples and weights, and the finite-difference masses.
    #[allow(clippy::too_many_arguments)]
    fn sample_basins<M: ControlAffine + ?Sized, C: PathCost + ?Sized>(
        &mut self,
        f: &mut PathFunctional<'_, M, C>,
        x: &[f64],
        c0: usize,
        mut last_factored: Option<usize>,
        plan: &Plan,
        gate: Option<Gate>,
        opts: &EstimatorOptions,
        tally: &mut Tally,
    ) -> Result<(), EstimateError> {
        let (nn, basins, p) = (plan.nn, plan.basins, f.setup.p);
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
            let marginal = plan.gate_var.is_some()
                && plan.analytic
                && opts.map == MapKind::Linear
                && opts.gate_sampling == GateSampling::Marginal;
            self.factor_component(f, c, c0, last_factored, plan, marginal)?;
            last_factored = None;
            let interval = gate.map(|g| (g.intervals[bi], plan.gate_var.unwrap_or(0)));
            // With one component and no gate the workspace still holds ∇F(μ_c).
            let grad_valid = plan.n_comp == 1 && gate.is_none();
            let (lm, np) = self.sample_component(
                f,
                c,
                nn,
                plan.ms,
                interval,
                gate,
                opts,
                plan.analytic,
                grad_valid && !plan.lr,
                marginal,
            );
            self.log_mass[c] = lm;
            tally.passes += np;
            tally.evaluated += plan.mstore;
            if let GradientMethod::FiniteDifference { h } = opts.gradient {
                let mut xp = [0.0; MAX_STATE];
                let (m, st) = (f.setup.m, f.setup);
                for j in 0..p {
                    for (sgn, slot) in [(1.0, 0), (-1.0, 1)] {
                        for r in 0..m {
                            xp[r] = x[r] + sgn * h * st.g[r + j * m];
                        }
                        f.set_state(&xp[..m]);
                        let lmj = self.fd_mass(
                            f,
                            c,
                            nn,
                            plan.ms,
                            interval,
                            gate,
                            opts,
                            &mut tally.iters,
                        )?;
                        self.fd_log_mass[c * 2 * p + 2 * j + slot] = lmj;
                    }
                }
                f.set_state(x);
            }
        }
        Ok(())
    }

    /// Leave in the workspace the factor component c samples with, and its
    /// δμ for the analytic gradient. With a gate and a weighted gradient:
    /// the unconstrained factor at μ_c, the column H⁻¹e_k and δμ with the
    /// gated coordinate held (the slit does not move with x); otherwise the
    /// (pinned) Hessian at μ_c for δμ, then the unconstrained one for the
    /// samples (paper §3.1). A factor still current from the minimisation
    /// (`last_factored`) is reused.
    fn factor_component<M: ControlAffine + ?Sized, C: PathCost + ?Sized>(
        &mut self,
        f: &PathFunctional<'_, M, C>,
        c: usize,
        c0: usize,
        last_factored: Option<usize>,
        plan: &Plan,
        marginal: bool,
    ) -> Result<(), EstimateError> {
        let (nn, analytic, lr) = (plan.nn, plan.analytic, plan.lr);
        let pin = self.comp_pin[c];
        if plan.gate_var.is_some() && (marginal || analytic) {
            let current = pin.is_none()
                && (last_factored == Some(c)
                    || (last_factored == Some(c0) && self.comp_pin[c0].is_none()));
            if !current {
                self.newton.pinned[..nn].fill(false);
                self.newton.factor(f, &self.mu[c * nn..(c + 1) * nn])?;
            }
            let k = plan.gate_var.unwrap_or(0);
            self.gate_col[..nn].fill(0.0);
            self.gate_col[k] = 1.0;
            self.newton.l.solve_in_place(&mut self.gate_col[..nn]);
            if analytic && !lr {
                self.directions(f, c, nn, None, Some(k));
            }
        } else {
            // The factor in the workspace must be the (pinned) Hessian at μ_c.
            let pinned_matches = last_factored == Some(c)
                || (pin.is_none() && last_factored == Some(c0) && self.comp_pin[c0].is_none());
            if !pinned_matches {
                self.newton.pinned[..nn].fill(false);
                if let Some(k) = pin {
                    self.newton.pinned[k] = true;
                }
                self.newton.factor(f, &self.mu[c * nn..(c + 1) * nn])?;
            }
            if analytic && !lr {
                self.directions(f, c, nn, pin, None);
            }
            if pin.is_some() {
                // Samples use the unconstrained Hessian (paper §3.1).
                self.newton.pinned[..nn].fill(false);
                self.newton.factor(f, &self.mu[c * nn..(c + 1) * nn])?;
            }
        }
        Ok(())
    }

    /// ψ̄, the control and the diagnostics from the components' log masses
    /// and sample weights; stores the warm start for the next call.
    fn combine(
        &mut self,
        st: &PathSetup,
        plan: &Plan,
        n: usize,
        opts: &EstimatorOptions,
        tally: &Tally,
    ) -> Result<Estimate, EstimateError> {
        let (p, nn, n_comp, mstore) = (st.p, plan.nn, plan.n_comp, plan.mstore);
        let log_total = log_sum_exp(&self.log_mass[..n_comp]);
        if !log_total.is_finite() {
            return Err(EstimateError::NoMass);
        }
        // ψ = (2πΔt)^{−N/2}(det Σ_b)^{−n/2} J_z ∫e^{−F}, ∫e^{−F} = (2π)^{N/2} Σ_c e^{−φ_c} E[w_c].
        let log_psi = log_total - (plan.n_states as f64).ln() + st.log_psi_constant(n);
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
                if plan.analytic {
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
        let evaluated = tally.evaluated;
        Ok(Estimate {
            log_psi,
            grad_g,
            u,
            phi: tally.phi_min,
            ess: if ess_den > 0.0 {
                ess_num * ess_num / ess_den
            } else {
                0.0
            },
            samples: evaluated,
            pass_fraction: if evaluated > 0 {
                tally.passes as f64 / evaluated as f64
            } else {
                0.0
            },
            newton_iterations: tally.iters,
            components: n_comp,
        })
    }
}
