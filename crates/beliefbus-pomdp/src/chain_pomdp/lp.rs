//! A small dense two-phase simplex method for the linear programs of the
//! moment-consistent rows ([`super::rows_moment`]):
//!
//! ```text
//! min cᵀx   s.t.   A x = b,   x ≥ 0          (A: m × n, m small, n ≤ a few hundred)
//! ```
//!
//! Phase 1 minimises the sum of one artificial variable per row (rows with
//! b_i < 0 negated first); phase 2 minimises cᵀx from the feasible basis
//! phase 1 ends in, with the artificials barred from re-entering (one left
//! basic at zero marks a redundant row). Entering and leaving variables by
//! Bland's rule (smallest index among the improving columns; smallest basic
//! index among the tied ratios), which cannot cycle (Bland 1977). An optimum
//! is a basic solution: at most m non-zero entries — the property the
//! minimum-variance rows rest on (an optimal vertex has ≤ d + 1 support
//! points). The final basic values are re-solved from the basis columns by
//! Gaussian elimination (one correction of the tableau's accumulated
//! rounding).

/// What [`solve`] found.
#[derive(Clone, Debug, PartialEq)]
pub enum LpOutcome {
    /// An optimal basic solution x (length n).
    Optimal(Vec<f64>),
    Infeasible,
    Unbounded,
}

/// Relative tolerance of the reduced costs and the phase-1 objective (the
/// callers scale A and c to order one).
const TOL: f64 = 1e-11;
/// Smallest pivot magnitude.
const PIVOT: f64 = 1e-12;

/// Solves min cᵀx, A x = b, x ≥ 0 with `a` row-major m × n.
pub fn solve(m: usize, n: usize, a: &[f64], b: &[f64], c: &[f64]) -> LpOutcome {
    assert_eq!(a.len(), m * n, "A must be m × n");
    assert_eq!(b.len(), m, "b must have m entries");
    assert_eq!(c.len(), n, "c must have n entries");
    let w = n + m + 1;
    let mut t = vec![0.0; m * w];
    for i in 0..m {
        let s = if b[i] < 0.0 { -1.0 } else { 1.0 };
        for j in 0..n {
            t[i * w + j] = s * a[i * n + j];
        }
        t[i * w + n + i] = 1.0;
        t[i * w + w - 1] = s * b[i];
    }
    let mut basis: Vec<usize> = (n..n + m).collect();
    let phase1 = |j: usize| if j >= n { 1.0 } else { 0.0 };
    if !run(&mut t, &mut basis, m, w, n + m, &phase1) {
        // Phase 1 is bounded below by 0: unbounded cannot happen.
        return LpOutcome::Infeasible;
    }
    let scale = 1.0 + b.iter().fold(0.0f64, |s, v| s.max(v.abs()));
    let infeas: f64 = (0..m)
        .filter(|&i| basis[i] >= n)
        .map(|i| t[i * w + w - 1])
        .sum();
    if infeas > 1e-10 * scale {
        return LpOutcome::Infeasible;
    }
    // Drive the artificials out of the basis where a real column can
    // replace them (their value is 0, so the pivot keeps feasibility).
    for i in 0..m {
        if basis[i] < n {
            continue;
        }
        if let Some(j) = (0..n).find(|&j| !basis.contains(&j) && t[i * w + j].abs() > 1e-9) {
            pivot(&mut t, &mut basis, m, w, i, j);
        }
    }
    let phase2 = |j: usize| if j < n { c[j] } else { 0.0 };
    if !run(&mut t, &mut basis, m, w, n, &phase2) {
        return LpOutcome::Unbounded;
    }
    let mut x = vec![0.0; n];
    for i in 0..m {
        if basis[i] < n {
            x[basis[i]] = t[i * w + w - 1].max(0.0);
        }
    }
    polish(m, n, a, b, &basis, &mut x);
    LpOutcome::Optimal(x)
}

/// Simplex iterations with cost `cost(j)` over the columns `0..allowed`;
/// false when the objective is unbounded below.
fn run(
    t: &mut [f64],
    basis: &mut [usize],
    m: usize,
    w: usize,
    allowed: usize,
    cost: &dyn Fn(usize) -> f64,
) -> bool {
    let cmax = (0..allowed).fold(1.0f64, |s, j| s.max(cost(j).abs()));
    let max_iter = 50 * (allowed + m) + 1000;
    for _ in 0..max_iter {
        // Bland: the first column with a negative reduced cost.
        let entering = (0..allowed).find(|&j| {
            if basis.contains(&j) {
                return false;
            }
            let dj = cost(j) - (0..m).map(|i| cost(basis[i]) * t[i * w + j]).sum::<f64>();
            dj < -TOL * cmax
        });
        let Some(j) = entering else {
            return true;
        };
        let mut best: Option<(usize, f64)> = None;
        for i in 0..m {
            let aij = t[i * w + j];
            if aij <= PIVOT {
                continue;
            }
            let r = t[i * w + w - 1] / aij;
            best = match best {
                None => Some((i, r)),
                Some((bi, br)) => {
                    let tie = (r - br).abs() <= 1e-12 * (1.0 + br.abs());
                    if r < br && !tie || tie && basis[i] < basis[bi] {
                        Some((i, r))
                    } else {
                        Some((bi, br))
                    }
                }
            };
        }
        let Some((i, _)) = best else {
            return false;
        };
        pivot(t, basis, m, w, i, j);
    }
    // Bland's rule terminates; this guards against rounding only.
    true
}

fn pivot(t: &mut [f64], basis: &mut [usize], m: usize, w: usize, r: usize, j: usize) {
    let p = t[r * w + j];
    for k in 0..w {
        t[r * w + k] /= p;
    }
    for i in 0..m {
        if i == r {
            continue;
        }
        let f = t[i * w + j];
        if f != 0.0 {
            for k in 0..w {
                t[i * w + k] -= f * t[r * w + k];
            }
            t[i * w + j] = 0.0;
        }
    }
    basis[r] = j;
}

/// Re-solves the basic values from A_B x_B = b (the rows of redundant
/// constraints, whose artificial stayed basic, dropped by least squares
/// through the normal equations); keeps `x` if the system is singular or
/// the solution leaves the non-negative orthant beyond rounding.
fn polish(m: usize, n: usize, a: &[f64], b: &[f64], basis: &[usize], x: &mut [f64]) {
    let cols: Vec<usize> = basis.iter().copied().filter(|&j| j < n).collect();
    let k = cols.len();
    if k == 0 {
        return;
    }
    // Normal equations (A_Bᵀ A_B) x_B = A_Bᵀ b: exact for a consistent system.
    let mut g = vec![0.0; k * k];
    let mut r = vec![0.0; k];
    for (p, &jp) in cols.iter().enumerate() {
        for (q, &jq) in cols.iter().enumerate() {
            g[p * k + q] = (0..m).map(|i| a[i * n + jp] * a[i * n + jq]).sum();
        }
        r[p] = (0..m).map(|i| a[i * n + jp] * b[i]).sum();
    }
    let Some(sol) = super::rows::solve_small(k, &mut g, &r) else {
        return;
    };
    if sol.iter().any(|v| !v.is_finite() || *v < -1e-9) {
        return;
    }
    let resid = |x: &[f64]| -> f64 {
        (0..m)
            .map(|i| ((0..n).map(|j| a[i * n + j] * x[j]).sum::<f64>() - b[i]).abs())
            .fold(0.0, f64::max)
    };
    let mut y = x.to_vec();
    for (&j, v) in cols.iter().zip(&sol) {
        y[j] = v.max(0.0);
    }
    if resid(&y) <= resid(x) {
        x.copy_from_slice(&y);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_textbook_lp_and_its_vertex() {
        // max 3x + 2y s.t. x + y ≤ 4, x + 3y ≤ 6, x ≤ 3 (slacks s1..s3):
        // the optimum is x = 3, y = 1, value 11.
        let a = [
            1.0, 1.0, 1.0, 0.0, 0.0, //
            1.0, 3.0, 0.0, 1.0, 0.0, //
            1.0, 0.0, 0.0, 0.0, 1.0,
        ];
        let b = [4.0, 6.0, 3.0];
        let c = [-3.0, -2.0, 0.0, 0.0, 0.0];
        let LpOutcome::Optimal(x) = solve(3, 5, &a, &b, &c) else {
            panic!("optimal expected");
        };
        assert!(
            (x[0] - 3.0).abs() < 1e-12 && (x[1] - 1.0).abs() < 1e-12,
            "{x:?}"
        );
    }

    #[test]
    fn infeasible_and_unbounded_are_told_apart() {
        // x1 + x2 = −1 with x ≥ 0: infeasible.
        assert_eq!(
            solve(1, 2, &[1.0, 1.0], &[-1.0], &[1.0, 1.0]),
            LpOutcome::Infeasible
        );
        // x1 − x2 = 1, min −x1: x1 = 1 + x2 grows without bound.
        assert_eq!(
            solve(1, 2, &[1.0, -1.0], &[1.0], &[-1.0, 0.0]),
            LpOutcome::Unbounded
        );
    }

    #[test]
    fn a_redundant_row_keeps_the_optimum() {
        // x1 + x2 = 1 twice; min x1 − x2 → x = (0, 1).
        let a = [1.0, 1.0, 2.0, 2.0];
        let LpOutcome::Optimal(x) = solve(2, 2, &a, &[1.0, 2.0], &[1.0, -1.0]) else {
            panic!("optimal expected");
        };
        assert!(x[0].abs() < 1e-12 && (x[1] - 1.0).abs() < 1e-12, "{x:?}");
    }
}
