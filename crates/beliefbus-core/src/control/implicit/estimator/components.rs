//! Per-component work of the estimator: the proposal-centre derivatives
//! δμ, the samples and their log weights (plain linear or random map, or
//! the gate marginal), and the finite-difference re-solves.

use super::super::maps::{linear_map, linear_map_log_weight};
use super::super::newton::Objective;
use super::super::path::{Gate, PathCost, PathFunctional, PathSetup};
use super::super::truncnorm;
use super::super::weights::log_sum_exp;
use super::{EstimateError, EstimatorOptions, GateMode, GradientMethod, MapKind, PathSampler};
use crate::model::affine::ControlAffine;
use crate::{MAX_CONTROL, MAX_STATE};

impl PathSampler {
    /// δμ_j = −H⁻¹ (∂²F/∂z∂e) δe_j for each column g_j of G, with the factor
    /// in the workspace (pinned rows as identity, so pinned entries stay 0).
    pub(super) fn directions<M: ControlAffine + ?Sized, C: PathCost + ?Sized>(
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
    /// (log mass, samples with positive weight). One loop covers the three
    /// proposals (the mode, the linear map, the random map) and the three
    /// gradient forms over the same workspace borrows; split per case, each
    /// piece would take a dozen of them, so it stays one function.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn sample_component<M: ControlAffine + ?Sized, C: PathCost + ?Sized>(
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
        let p = st.p;
        let lp = st.prefix_len();
        let muc = &mu[c * nn..(c + 1) * nn];
        let phi = comp_phi[c];
        let log_det_l = newton.l.log_det_factor();
        let mstore = ms.max(1);
        let paper = gate.is_some() && opts.gate_mode == GateMode::SmallestBasin;
        let lr = matches!(opts.gradient, GradientMethod::LikelihoodRatio);
        let de = prefix_directions(st);
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
                let out = &mut dval[(c * mstore + k) * p..(c * mstore + k + 1) * p];
                directional_derivatives(&ge[..lp], &gz[..nn], &de, &dmu[c * p * nn..], lr, out);
            }
        }
        let lm = log_sum_exp(&lw[c * mstore..(c + 1) * mstore]) - (mstore as f64).ln();
        (lm, npass)
    }

    /// Sample component c with the gated coordinate k drawn from its Laplace
    /// marginal on [lo, hi] (see [`GateSampling::Marginal`]); the factor in
    /// the workspace is the unconstrained one at μ_c and `gate_col` = H⁻¹e_k.
    /// Kept whole: the truncated-normal set-up and the per-sample
    /// conditioning share the same dozen workspace borrows.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn sample_component_marginal<M: ControlAffine + ?Sized, C: PathCost + ?Sized>(
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
        let p = st.p;
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
        let de = prefix_directions(st);
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
                let out = &mut dval[(c * mstore + j) * p..(c * mstore + j + 1) * p];
                directional_derivatives(&ge[..lp], &gz[..nn], &de, &dmu[c * p * nn..], lr, out);
            }
        }
        let lm = log_sum_exp(&lw[c * mstore..(c + 1) * mstore]) - (mstore as f64).ln();
        (lm, npass)
    }

    /// Log mass of component c at the perturbed state held by `f`:
    /// re-minimise from μ_c with the same pin, refactor, same ξ.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn fd_mass<M: ControlAffine + ?Sized, C: PathCost + ?Sized>(
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

/// δe_j, the prefix direction of each column g_j of G.
fn prefix_directions(st: &PathSetup) -> [[f64; 2 * MAX_STATE]; MAX_CONTROL] {
    let (m, p) = (st.m, st.p);
    let mut de = [[0.0; 2 * MAX_STATE]; MAX_CONTROL];
    for j in 0..p {
        st.prefix_direction(&st.g[j * m..(j + 1) * m], &mut de[j]);
    }
    de
}

/// D_j = ∂F/∂e·δe_j, plus ∇_z F·δμ_j unless likelihood-ratio, for each
/// control direction j = 0..out.len(); `dmu` starts at the component's
/// δμ_0 (blocks of gz.len()).
fn directional_derivatives(
    ge: &[f64],
    gz: &[f64],
    de: &[[f64; 2 * MAX_STATE]; MAX_CONTROL],
    dmu: &[f64],
    lr: bool,
    out: &mut [f64],
) {
    let nn = gz.len();
    for (j, slot) in out.iter_mut().enumerate() {
        let mut d: f64 = (0..ge.len()).map(|r| ge[r] * de[j][r]).sum();
        if !lr {
            let dm = &dmu[j * nn..(j + 1) * nn];
            for i in 0..nn {
                d += gz[i] * dm[i];
            }
        }
        *slot = d;
    }
}

/// Whether sample x passes the gate: in its basin's slit (all basins) or
/// any slit (the paper's smallest-basin recipe); true without a gate.
pub(super) fn gate_pass(
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
pub(super) fn log_sum_exp_components(
    lw: &[f64],
    n_comp: usize,
    mstore: usize,
    log_mass: &[f64],
) -> f64 {
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
