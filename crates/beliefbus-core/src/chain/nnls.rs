//! Non-negative least squares, min ‖A x − b‖₂ subject to x ≥ 0, by the
//! active-set method of Lawson & Hanson (1974, ch. 23), and the
//! minimum-change projection used by the moment-matching ("LP") kernel.
//!
//! Why hand-written: the problems are tiny and dense (≤ 45 moment equations ×
//! ≤ 65 transition probabilities), solved once per (re)connected state —
//! 10⁵–10⁶ times per chain — so the solver must not allocate and must carry
//! no modelling layer. General LP/QP crates (minilp, clarabel, good_lp)
//! allocate per solve and would dominate construction time. Lawson–Hanson
//! terminates finitely, and its residual answers the LP's feasibility
//! question: zero residual ⇔ the moment equations have a non-negative
//! solution; otherwise it returns the least-violating kernel.
//!
//! Least-squares subproblems use the normal equations on the precomputed
//! Gram matrix AᵀA (rows are scaled to O(1) by the caller), with a tiny ridge
//! when a subset is rank deficient.

use super::linalg::{backward_sub_t, cholesky, forward_sub};

/// Largest number of rows (moment equations) supported.
pub const MAX_ROWS: usize = 48;
/// Largest number of unknowns supported.
pub const MAX_COLS: usize = 65;

/// Reusable buffers for [`Nnls::solve`]; allocate once, solve many times.
#[derive(Clone, Debug)]
pub struct Nnls {
    gram: Vec<f64>, // AᵀA, p × p
    atb: Vec<f64>,  // Aᵀb
    w: Vec<f64>,    // dual / gradient
    s: Vec<f64>,    // subproblem solution
    sub: Vec<f64>,  // |P| × |P| Cholesky workspace
    rhs: Vec<f64>,  // |P| right-hand side
    passive: Vec<bool>,
    idx: Vec<usize>,
}

impl Default for Nnls {
    fn default() -> Self {
        Self::new()
    }
}

impl Nnls {
    /// Buffers for up to [`MAX_ROWS`] × [`MAX_COLS`].
    pub fn new() -> Self {
        Self {
            gram: vec![0.0; MAX_COLS * MAX_COLS],
            atb: vec![0.0; MAX_COLS],
            w: vec![0.0; MAX_COLS],
            s: vec![0.0; MAX_COLS],
            sub: vec![0.0; MAX_COLS * MAX_COLS],
            rhs: vec![0.0; MAX_COLS],
            passive: vec![false; MAX_COLS],
            idx: vec![0; MAX_COLS],
        }
    }

    /// Solve min ‖A x − b‖ s.t. x ≥ 0 for the m × p column-major `a`.
    /// Writes x (length p) and returns the residual norm ‖A x − b‖₂.
    pub fn solve(&mut self, a: &[f64], m: usize, p: usize, b: &[f64], x: &mut [f64]) -> f64 {
        debug_assert!(m <= MAX_ROWS && p <= MAX_COLS);
        for j in 0..p {
            for i in 0..=j {
                let mut s = 0.0;
                for r in 0..m {
                    s += a[r + i * m] * a[r + j * m];
                }
                self.gram[i + j * p] = s;
                self.gram[j + i * p] = s;
            }
            self.atb[j] = (0..m).map(|r| a[r + j * m] * b[r]).sum();
        }
        x[..p].fill(0.0);
        self.passive[..p].fill(false);
        let scale = self.atb[..p].iter().fold(0.0f64, |acc, v| acc.max(v.abs()));
        let tol = 1e-12 * scale.max(1e-300) * p as f64;
        let max_outer = 3 * p + 10;
        for _ in 0..max_outer {
            self.gradient(x, p);
            let mut best = usize::MAX;
            let mut wmax = tol;
            for j in 0..p {
                if !self.passive[j] && self.w[j] > wmax {
                    wmax = self.w[j];
                    best = j;
                }
            }
            if best == usize::MAX {
                break;
            }
            self.passive[best] = true;
            let mut inner = 0;
            loop {
                inner += 1;
                self.solve_passive(p);
                let mut all_pos = true;
                for j in 0..p {
                    if self.passive[j] && self.s[j] <= 0.0 {
                        all_pos = false;
                    }
                }
                if all_pos || inner > 3 * p {
                    for j in 0..p {
                        x[j] = if self.passive[j] {
                            self.s[j].max(0.0)
                        } else {
                            0.0
                        };
                    }
                    break;
                }
                let mut alpha = f64::INFINITY;
                for j in 0..p {
                    if self.passive[j] && self.s[j] <= 0.0 {
                        let den = x[j] - self.s[j];
                        if den > 0.0 {
                            alpha = alpha.min(x[j] / den);
                        }
                    }
                }
                if !alpha.is_finite() {
                    alpha = 0.0;
                }
                for j in 0..p {
                    if self.passive[j] {
                        x[j] += alpha * (self.s[j] - x[j]);
                        if x[j] <= 1e-15 {
                            x[j] = 0.0;
                            self.passive[j] = false;
                        }
                    }
                }
            }
        }
        residual(a, m, p, b, x)
    }

    fn gradient(&mut self, x: &[f64], p: usize) {
        for j in 0..p {
            let mut s = self.atb[j];
            for k in 0..p {
                s -= self.gram[j + k * p] * x[k];
            }
            self.w[j] = s;
        }
    }

    /// Unconstrained least squares on the passive set, into `s`.
    fn solve_passive(&mut self, p: usize) {
        let mut q = 0;
        for j in 0..p {
            if self.passive[j] {
                self.idx[q] = j;
                q += 1;
            }
        }
        let mut ridge = 0.0;
        loop {
            for (bi, &i) in self.idx[..q].iter().enumerate() {
                for (bj, &j) in self.idx[..q].iter().enumerate() {
                    self.sub[bi + bj * q] = self.gram[i + j * p];
                }
                self.sub[bi + bi * q] += ridge;
                self.rhs[bi] = self.atb[i];
            }
            if cholesky(&mut self.sub[..q * q], q) {
                break;
            }
            let diag = (0..q)
                .map(|b| self.gram[self.idx[b] * (p + 1)])
                .fold(0.0f64, f64::max);
            ridge = if ridge == 0.0 {
                1e-12 * diag.max(1e-300)
            } else {
                ridge * 100.0
            };
        }
        forward_sub(&self.sub[..q * q], q, &mut self.rhs[..q]);
        backward_sub_t(&self.sub[..q * q], q, &mut self.rhs[..q]);
        self.s[..p].fill(0.0);
        for b in 0..q {
            self.s[self.idx[b]] = self.rhs[b];
        }
    }
}

/// ‖A x − b‖₂ for the m × p column-major `a`.
pub fn residual(a: &[f64], m: usize, p: usize, b: &[f64], x: &[f64]) -> f64 {
    let mut r2 = 0.0;
    for i in 0..m {
        let mut s = -b[i];
        for j in 0..p {
            s += a[i + j * m] * x[j];
        }
        r2 += s * s;
    }
    r2.sqrt()
}

/// Reusable buffers for [`MinChange::solve`].
#[derive(Clone, Debug)]
pub struct MinChange {
    free: Vec<bool>,
    aat: Vec<f64>,
    y: Vec<f64>,
}

impl Default for MinChange {
    fn default() -> Self {
        Self::new()
    }
}

impl MinChange {
    pub fn new() -> Self {
        Self {
            free: vec![true; MAX_COLS],
            aat: vec![0.0; MAX_ROWS * MAX_ROWS],
            y: vec![0.0; MAX_ROWS],
        }
    }

    /// The smallest change x = w + Aᵀy of a prior `w` that satisfies A x = b,
    /// with coordinates that turn negative clamped to 0 and the projection
    /// repeated on the remaining ones (at most `max_rounds` times). Returns
    /// true when x ≥ 0 and ‖A x − b‖∞ ≤ `tol`; x is left unspecified
    /// otherwise. A fast path for the moment-matching kernel; NNLS decides
    /// when this heuristic fails.
    pub fn solve(
        &mut self,
        a: &[f64],
        m: usize,
        p: usize,
        b: &[f64],
        w: &[f64],
        x: &mut [f64],
        tol: f64,
        max_rounds: usize,
    ) -> bool {
        self.free[..p].fill(true);
        for _ in 0..max_rounds {
            let nfree = self.free[..p].iter().filter(|f| **f).count();
            if nfree < m {
                return false;
            }
            // (A_F A_Fᵀ) y = b − A_F w_F
            for i in 0..m {
                for k in 0..=i {
                    let mut s = 0.0;
                    for j in 0..p {
                        if self.free[j] {
                            s += a[i + j * m] * a[k + j * m];
                        }
                    }
                    self.aat[i + k * m] = s;
                    self.aat[k + i * m] = s;
                }
                let mut r = b[i];
                for j in 0..p {
                    if self.free[j] {
                        r -= a[i + j * m] * w[j];
                    }
                }
                self.y[i] = r;
            }
            if !cholesky(&mut self.aat[..m * m], m) {
                return false;
            }
            forward_sub(&self.aat[..m * m], m, &mut self.y[..m]);
            backward_sub_t(&self.aat[..m * m], m, &mut self.y[..m]);
            let mut any_neg = false;
            for j in 0..p {
                if self.free[j] {
                    let mut v = w[j];
                    for i in 0..m {
                        v += a[i + j * m] * self.y[i];
                    }
                    x[j] = v;
                    if v < 0.0 {
                        any_neg = true;
                    }
                } else {
                    x[j] = 0.0;
                }
            }
            if !any_neg {
                return max_abs_residual(a, m, p, b, x) <= tol;
            }
            for j in 0..p {
                if self.free[j] && x[j] < 0.0 {
                    self.free[j] = false;
                }
            }
        }
        false
    }
}

fn max_abs_residual(a: &[f64], m: usize, p: usize, b: &[f64], x: &[f64]) -> f64 {
    let mut worst = 0.0f64;
    for i in 0..m {
        let mut s = -b[i];
        for j in 0..p {
            s += a[i + j * m] * x[j];
        }
        worst = worst.max(s.abs());
    }
    worst
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::stream;
    use rand::RngExt;

    #[test]
    fn nnls_matches_kkt_conditions() {
        let mut rng = stream(5, 0);
        let mut nn = Nnls::new();
        for trial in 0..50 {
            let m = 3 + trial % 10;
            let p = 2 + trial % 17;
            let a: Vec<f64> = (0..m * p).map(|_| rng.random_range(-1.0..1.0)).collect();
            let b: Vec<f64> = (0..m).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mut x = vec![0.0; p];
            let res = nn.solve(&a, m, p, &b, &mut x);
            assert!((res - residual(&a, m, p, &b, &x)).abs() < 1e-12);
            // KKT: x ≥ 0; gradient g = Aᵀ(b − Ax) ≤ 0 where x = 0, = 0 where x > 0.
            for j in 0..p {
                assert!(x[j] >= 0.0);
                let g: f64 = (0..m)
                    .map(|i| {
                        let ax: f64 = (0..p).map(|k| a[i + k * m] * x[k]).sum();
                        a[i + j * m] * (b[i] - ax)
                    })
                    .sum();
                if x[j] > 1e-10 {
                    assert!(g.abs() < 1e-8, "trial {trial} j {j} g {g}");
                } else {
                    assert!(g < 1e-8, "trial {trial} j {j} g {g}");
                }
            }
        }
    }

    #[test]
    fn nnls_finds_feasible_point_and_min_change_agrees() {
        // b = A x* with x* ≥ 0: both solvers reach zero residual.
        let mut rng = stream(6, 0);
        let (m, p) = (6, 15);
        let a: Vec<f64> = (0..m * p).map(|_| rng.random_range(-1.0..1.0)).collect();
        let xs: Vec<f64> = (0..p).map(|_| rng.random_range(0.1..1.0)).collect();
        let b: Vec<f64> = (0..m)
            .map(|i| (0..p).map(|j| a[i + j * m] * xs[j]).sum())
            .collect();
        let mut x = vec![0.0; p];
        let res = Nnls::new().solve(&a, m, p, &b, &mut x);
        assert!(res < 1e-9, "residual {res}");
        let mut y = vec![0.0; p];
        let ok = MinChange::new().solve(&a, m, p, &b, &xs, &mut y, 1e-9, 5);
        assert!(ok);
        for j in 0..p {
            assert!((y[j] - xs[j]).abs() < 1e-9, "prior already feasible");
        }
    }
}
