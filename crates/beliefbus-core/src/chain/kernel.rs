//! Holding time and transition kernels of `ConnectState` (thesis §2.4.1,
//! Alg. 2.2; paper 001 §IV-A).
//!
//! Holding time (thesis: κ_F = κ_f = 1):
//! ```text
//! Δt(z) = r² / (κ_F ‖F Fᵀ(z)‖₂ + κ_f r ‖f(z)‖₂)
//! ```
//!
//! **Gaussian kernel** (thesis, Lemma 2.3): over the neighbours z_k of z,
//! ```text
//! p(z_k | z) ∝ exp(−½ (z_k − z − fΔt)ᵀ (F Fᵀ Δt)⁻¹ (z_k − z − fΔt)),   Σ_k p = 1
//! ```
//!
//! **Moment-matching ("LP") kernel** (thesis §2.4.1, "local consistency
//! conditions translate into a linear program"; no objective or tolerance
//! given there). Unknowns p₀ (stay at z) and p_k ≥ 0 with
//! ```text
//! Σ p = 1,   Σ p_k Δz_k = f Δt,   Σ p_k Δz_k Δz_kᵀ = F Fᵀ Δt + f fᵀ Δt²   (upper triangle)
//! ```
//! i.e. eq. (2.6)–(2.7) met exactly over one step of length Δt. Choices made
//! here where the thesis is silent:
//! - the self-loop p₀ is an unknown. It makes small Δt always admissible, and
//!   the chain without self-loop is recovered exactly: holding time
//!   Δt/(1 − p₀), jump probabilities p_k/(1 − p₀) (the time-equalisation of
//!   eq. 3.8–3.9 read backwards);
//! - among feasible kernels we take the one closest (Euclidean) to the
//!   Gaussian kernel, found by projection with clamping ([`MinChange`]);
//!   when that heuristic fails, Lawson–Hanson NNLS decides feasibility and,
//!   if infeasible (drift-dominated states whose neighbours do not surround
//!   the required jump, boundary states), returns the least-violating kernel
//!   with the mean rows weighted ×[`MEAN_ROW_WEIGHT`] so drift is matched
//!   first and the residual becomes extra ("numerical") diffusion;
//! - rows are scaled by r and r² so the equations are O(1);
//! - at most [`MAX_LP_NEIGHBOURS`] nearest neighbours enter the program.
//!
//! Erratum found while implementing: with the thesis's Δt the Gaussian
//! kernel's standard deviation √(σ²Δt) equals r (σ² ≫ r‖f‖), i.e. the kernel
//! is truncated at one σ by the Near ball, and its covariance falls short of
//! F FᵀΔt by a factor that does not vanish as n → ∞ (≈ 0.23 in 2-D). Lemma
//! 2.3 holds only when the kernel is much narrower than r. The local-
//! consistency diagnostics report this; the moment-matching kernel meets
//! (2.7) exactly wherever it is feasible.

use super::nnls::{MinChange, Nnls, MAX_COLS, MAX_ROWS};

/// Largest neighbour count entering the moment-matching program.
pub const MAX_LP_NEIGHBOURS: usize = MAX_COLS - 1;
/// Weight of the mean rows relative to the second-moment rows in NNLS.
pub const MEAN_ROW_WEIGHT: f64 = 4.0;
/// Weight of the mean rows in the advected construction: there the
/// second moment is usually infeasible (F Fᵀ τ below the interpolation
/// variance of the neighbours), and the fit must keep the drift exact and
/// add as little variance as possible rather than trade drift for variance.
pub const ADVECTED_MEAN_ROW_WEIGHT: f64 = 30.0;
/// Weight of the Σ p = 1 row in NNLS.
const SUM_ROW_WEIGHT: f64 = 100.0;
/// Feasibility tolerance on the scaled equations.
const FEAS_TOL: f64 = 1e-9;

/// The transition kernel used by `ConnectState`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum KernelKind {
    /// The thesis's normalised Gaussian over Near.
    Gaussian,
    /// Moment matching (the thesis's LP): exact local consistency where
    /// feasible.
    MomentMatched,
}

/// How a kernel row came out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KernelOutcome {
    /// Gaussian weights.
    Gaussian,
    /// Moment equations met exactly (to 1e-9 in scaled units).
    Exact,
    /// Infeasible: least-violating moment fit.
    LeastSquares,
    /// No neighbours: the state is absorbing (infinite holding time).
    Absorbing,
}

/// Δt(z) = r² / (κ_F ‖FFᵀ‖₂ + κ_f r ‖f‖₂).
pub fn holding_time(r: f64, diff_norm: f64, drift_norm: f64, kappa_f: f64, kappa_d: f64) -> f64 {
    r * r / (kappa_f * diff_norm + kappa_d * r * drift_norm)
}

/// Local dynamics of a state, cached by the chain.
#[derive(Clone, Copy, Debug)]
pub struct LocalDyn<'a> {
    /// f(z), length d.
    pub f: &'a [f64],
    /// F Fᵀ(z), d × d column-major.
    pub ff: &'a [f64],
    /// Cholesky factor of F Fᵀ(z) (lower), d × d; None if singular.
    pub chol: Option<&'a [f64]>,
}

/// Reusable buffers for the kernels.
#[derive(Clone, Debug, Default)]
pub struct KernelWork {
    logw: Vec<f64>,
    /// Δz of [`gaussian_gather_at`] in dimensions without a compiled form.
    dz: Vec<f64>,
    a: Vec<f64>,
    b: Vec<f64>,
    prior: Vec<f64>,
    x: Vec<f64>,
    nnls: Nnls,
    minc: MinChange,
}

impl KernelWork {
    pub fn new() -> Self {
        Self {
            logw: Vec::with_capacity(256),
            dz: Vec::with_capacity(256 * 16),
            a: vec![0.0; MAX_ROWS * MAX_COLS],
            b: vec![0.0; MAX_ROWS],
            prior: vec![0.0; MAX_COLS],
            x: vec![0.0; MAX_COLS],
            nnls: Nnls::new(),
            minc: MinChange::new(),
        }
    }
}

/// Gaussian weights N(Δz_k; fΔt, FFᵀΔt) normalised over the K neighbours,
/// `dz` flat K × d, into `p` (length K). Requires `dynl.chol`.
pub fn gaussian(
    d: usize,
    dz: &[f64],
    dt: f64,
    dynl: &LocalDyn,
    work: &mut KernelWork,
    p: &mut [f64],
) -> bool {
    let mut mean = [0.0f64; 16];
    for i in 0..d {
        mean[i] = dynl.f[i] * dt;
    }
    gaussian_at(d, dz, &mean[..d], dt, dynl, work, p)
}

/// Gaussian weights N(Δz_k; `mean`, FFᵀΔt) normalised over the K
/// neighbours (the advected form of [`gaussian`], `mean` being the flow's
/// displacement over Δt). Requires `dynl.chol`.
pub fn gaussian_at(
    d: usize,
    dz: &[f64],
    mean: &[f64],
    dt: f64,
    dynl: &LocalDyn,
    work: &mut KernelWork,
    p: &mut [f64],
) -> bool {
    let Some(l) = dynl.chol else {
        return false;
    };
    let k = dz.len() / d;
    work.logw.clear();
    let inv_dt = 1.0 / dt;
    let mut qmin = f64::INFINITY;
    let mut y = [0.0f64; 16];
    for j in 0..k {
        for i in 0..d {
            y[i] = dz[j * d + i] - mean[i];
        }
        // q = yᵀ (LLᵀ)⁻¹ y / Δt = |L⁻¹ y|² / Δt
        let mut q = 0.0;
        for i in 0..d {
            let mut s = y[i];
            for c in 0..i {
                s -= l[i + c * d] * y[c];
            }
            let v = s / l[i + i * d];
            y[i] = v;
            q += v * v;
        }
        let q = 0.5 * q * inv_dt;
        qmin = qmin.min(q);
        work.logw.push(q);
    }
    normalise_exp(&work.logw, qmin, p);
    true
}

/// [`gaussian_at`] with the inverse Cholesky factor L⁻¹ of F Fᵀ given
/// packed by rows ([`super::linalg::lower_inverse_packed`], cached per state
/// by the chain): |L⁻¹ y|² as a product instead of a forward substitution,
/// the same weights to rounding without d divisions per neighbour.
pub fn gaussian_packed_at(
    d: usize,
    dz: &[f64],
    mean: &[f64],
    dt: f64,
    linv: &[f64],
    work: &mut KernelWork,
    p: &mut [f64],
) {
    if d == 4 {
        return gaussian_packed_d::<4>(dz, mean, dt, linv, work, p);
    }
    let k = dz.len() / d;
    work.logw.clear();
    let inv_dt = 1.0 / dt;
    let mut qmin = f64::INFINITY;
    let mut y = [0.0f64; 16];
    for j in 0..k {
        for i in 0..d {
            y[i] = dz[j * d + i] - mean[i];
        }
        let q = 0.5 * packed_lower_sq_norm(linv, &y[..d]) * inv_dt;
        qmin = qmin.min(q);
        work.logw.push(q);
    }
    normalise_exp(&work.logw, qmin, p);
}

/// [`gaussian_packed_at`] for a dimension known at compile time.
fn gaussian_packed_d<const D: usize>(
    dz: &[f64],
    mean: &[f64],
    dt: f64,
    linv: &[f64],
    work: &mut KernelWork,
    p: &mut [f64],
) {
    let k = dz.len() / D;
    work.logw.clear();
    let inv_dt = 1.0 / dt;
    let mut qmin = f64::INFINITY;
    let mut m = [0.0f64; 16];
    m[..D].copy_from_slice(&mean[..D]);
    let linv = &linv[..D * (D + 1) / 2];
    for z in dz.chunks_exact(D) {
        let mut y = [0.0f64; D];
        for i in 0..D {
            y[i] = z[i] - m[i];
        }
        let q = 0.5 * packed_lower_sq_norm(linv, &y) * inv_dt;
        qmin = qmin.min(q);
        work.logw.push(q);
    }
    debug_assert_eq!(work.logw.len(), k);
    normalise_exp(&work.logw, qmin, p);
}

/// [`gaussian_packed_at`] reading the neighbours straight from the chain's
/// flat `states` (slots `cols`, displacements Δz = z_j − x formed on the
/// fly, the same arithmetic as building Δz first) — no Δz buffer.
#[allow(clippy::too_many_arguments)]
pub fn gaussian_gather_at(
    d: usize,
    states: &[f64],
    cols: &[u32],
    x: &[f64],
    mean: &[f64],
    dt: f64,
    linv: &[f64],
    work: &mut KernelWork,
    p: &mut [f64],
) {
    match d {
        2 => gather_d::<2>(states, cols, x, mean, dt, linv, work, p),
        3 => gather_d::<3>(states, cols, x, mean, dt, linv, work, p),
        4 => gather_d::<4>(states, cols, x, mean, dt, linv, work, p),
        _ => {
            let mut dz = std::mem::take(&mut work.dz);
            dz.clear();
            for &j in cols {
                let z = &states[j as usize * d..(j as usize + 1) * d];
                dz.extend(z.iter().zip(x).map(|(a, b)| a - b));
            }
            gaussian_packed_at(d, &dz, mean, dt, linv, work, p);
            work.dz = dz;
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn gather_d<const D: usize>(
    states: &[f64],
    cols: &[u32],
    x: &[f64],
    mean: &[f64],
    dt: f64,
    linv: &[f64],
    work: &mut KernelWork,
    p: &mut [f64],
) {
    work.logw.clear();
    let inv_dt = 1.0 / dt;
    let mut qmin = f64::INFINITY;
    let x = &x[..D];
    let mean = &mean[..D];
    let linv = &linv[..D * (D + 1) / 2];
    for &j in cols {
        let z = &states[j as usize * D..j as usize * D + D];
        let mut y = [0.0f64; D];
        for i in 0..D {
            y[i] = (z[i] - x[i]) - mean[i];
        }
        let q = 0.5 * packed_lower_sq_norm(linv, &y) * inv_dt;
        qmin = qmin.min(q);
        work.logw.push(q);
    }
    normalise_exp(&work.logw, qmin, p);
}

/// ‖L⁻¹y‖² for L⁻¹ lower-triangular, packed by rows (row i holds its i + 1
/// leading entries). Inlined, so a fixed-size `y` unrolls.
#[inline(always)]
fn packed_lower_sq_norm(linv: &[f64], y: &[f64]) -> f64 {
    let mut q = 0.0;
    let mut row = 0;
    for i in 0..y.len() {
        let mut v = 0.0;
        for c in 0..=i {
            v += linv[row + c] * y[c];
        }
        row += i + 1;
        q += v * v;
    }
    q
}

/// p_j = exp(qmin − q_j) / Σ exp(qmin − q_j).
fn normalise_exp(q: &[f64], qmin: f64, p: &mut [f64]) {
    let mut sum = 0.0;
    for (pj, &qj) in p.iter_mut().zip(q) {
        let w = (qmin - qj).exp();
        *pj = w;
        sum += w;
    }
    let inv = 1.0 / sum;
    for v in p[..q.len()].iter_mut() {
        *v *= inv;
    }
}

/// Result of the moment-matching kernel.
#[derive(Clone, Copy, Debug)]
pub struct MomentFit {
    pub outcome: KernelOutcome,
    /// Holding time of the chain without self-loop, Δt/(1 − p₀).
    pub holding: f64,
}

/// The moment-matching kernel for `K = dz.len()/d ≤ MAX_LP_NEIGHBOURS`
/// neighbours at displacements `dz` (flat K × d), step `dt`, neighbourhood
/// scale `r`. Writes jump probabilities p_k/(1 − p₀) into `p` (length K).
pub fn moment_matched(
    d: usize,
    dz: &[f64],
    dt: f64,
    r: f64,
    dynl: &LocalDyn,
    work: &mut KernelWork,
    p: &mut [f64],
) -> MomentFit {
    let mut mean = [0.0f64; 16];
    for i in 0..d {
        mean[i] = dynl.f[i] * dt;
    }
    moment_matched_at(d, dz, &mean[..d], dt, r, MEAN_ROW_WEIGHT, dynl, work, p)
}

/// The moment-matching kernel with a given mean displacement `mean` (the
/// advected form: the flow's displacement over Δt instead of fΔt):
/// Σ p_k Δz_k = mean, Σ p_k Δz_k Δz_kᵀ = F Fᵀ Δt + mean meanᵀ.
/// `mean_weight` weights the mean rows in the least-violation fit.
///
/// One function of about 100 lines: the prior weights, the moment
/// matrix, the weighted NNLS (feasibility or least violation) and the
/// Gaussian fallback of a degenerate fit are consecutive steps on the same
/// scratch (`work`) and row (`p`), each read once in order.
#[allow(clippy::too_many_arguments)]
pub fn moment_matched_at(
    d: usize,
    dz: &[f64],
    mean: &[f64],
    dt: f64,
    r: f64,
    mean_weight: f64,
    dynl: &LocalDyn,
    work: &mut KernelWork,
    p: &mut [f64],
) -> MomentFit {
    let k = dz.len() / d;
    debug_assert!(k <= MAX_LP_NEIGHBOURS);
    let nsec = d * (d + 1) / 2;
    let m = 1 + d + nsec;
    let cols = k + 1;
    let inv_r = 1.0 / r;
    let inv_r2 = inv_r * inv_r;
    // Prior: Gaussian weights if available, else uniform, for the jumps;
    // the self-loop prior is 0.
    work.prior[0] = 0.0;
    if !gaussian_at(d, dz, mean, dt, dynl, work, &mut p[..k]) {
        p[..k].fill(1.0 / k as f64);
    }
    work.prior[1..cols].copy_from_slice(&p[..k]);
    // Column 0: stay (Δz = 0).
    let a = &mut work.a[..m * cols];
    a.fill(0.0);
    a[0] = 1.0;
    for j in 0..k {
        let col = (j + 1) * m;
        a[col] = 1.0;
        let z = &dz[j * d..(j + 1) * d];
        for i in 0..d {
            a[col + 1 + i] = z[i] * inv_r;
        }
        let mut row = 1 + d;
        for i in 0..d {
            for c in i..d {
                a[col + row] = z[i] * z[c] * inv_r2;
                row += 1;
            }
        }
    }
    let b = &mut work.b[..m];
    b[0] = 1.0;
    for i in 0..d {
        b[1 + i] = mean[i] * inv_r;
    }
    let mut row = 1 + d;
    for i in 0..d {
        for c in i..d {
            b[row] = (dynl.ff[i + c * d] * dt + mean[i] * mean[c]) * inv_r2;
            row += 1;
        }
    }
    let x = &mut work.x[..cols];
    let mut outcome = if work
        .minc
        .solve(a, m, cols, b, &work.prior[..cols], x, FEAS_TOL, 6)
    {
        KernelOutcome::Exact
    } else {
        KernelOutcome::LeastSquares
    };
    if outcome == KernelOutcome::LeastSquares {
        // Weighted NNLS: decides feasibility, else least violation.
        for j in 0..cols {
            a[j * m] *= SUM_ROW_WEIGHT;
            for i in 0..d {
                a[j * m + 1 + i] *= mean_weight;
            }
        }
        b[0] *= SUM_ROW_WEIGHT;
        for i in 0..d {
            b[1 + i] *= mean_weight;
        }
        let res = work.nnls.solve(a, m, cols, b, x);
        if res <= FEAS_TOL {
            outcome = KernelOutcome::Exact;
        }
    }
    let total: f64 = x.iter().sum();
    let jump: f64 = x[1..].iter().sum();
    if !(jump > 1e-12 * total) || !total.is_finite() {
        // Degenerate fit (all mass on the self-loop): fall back to Gaussian.
        if !gaussian_at(d, dz, mean, dt, dynl, work, &mut p[..k]) {
            p[..k].fill(1.0 / k as f64);
        }
        return MomentFit {
            outcome: KernelOutcome::Gaussian,
            holding: dt,
        };
    }
    for j in 0..k {
        p[j] = x[j + 1] / jump;
    }
    MomentFit {
        outcome,
        holding: dt * total / jump,
    }
}

#[cfg(test)]
#[path = "kernel_tests.rs"]
mod tests;
