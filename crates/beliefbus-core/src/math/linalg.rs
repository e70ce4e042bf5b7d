//! Tiny dense linear algebra on stack arrays (dimension ≤ 9, or the ≤ 45
//! moment equations of the LP kernel): the crate's one Cholesky
//! factorisation (definite and semi-definite), triangular solves, log
//! determinants and the spectral norm of a symmetric matrix.
//!
//! nalgebra's Cholesky serves only where the dimension is a type parameter:
//! here it is a run-time `n` and the callers — chain construction for every
//! state, every Gaussian-filter predict and update, the NNLS active set —
//! run per step, where a `DMatrix` factorisation would allocate twice. The
//! banded factorisation of the implicit path-integral Hessian
//! (`control::implicit::banded`) is a different algorithm on band storage
//! and stays there.
//!
//! Matrices are column-major `a[i + j * n]`, like the rest of the crate.

/// In-place Cholesky A = L Lᵀ of the symmetric n × n matrix `a` (lower
/// triangle read and overwritten with L; the strict upper triangle is
/// zeroed). Returns false when A is not numerically positive definite.
pub fn cholesky(a: &mut [f64], n: usize) -> bool {
    for j in 0..n {
        let mut s = a[j + j * n];
        for k in 0..j {
            s -= a[j + k * n] * a[j + k * n];
        }
        if !(s > 0.0) || !s.is_finite() {
            return false;
        }
        let d = s.sqrt();
        a[j + j * n] = d;
        for i in j + 1..n {
            let mut s = a[i + j * n];
            for k in 0..j {
                s -= a[i + k * n] * a[j + k * n];
            }
            a[i + j * n] = s / d;
        }
        for i in 0..j {
            a[i + j * n] = 0.0;
        }
    }
    true
}

/// Cholesky-like factor L with L Lᵀ = A of a symmetric positive
/// *semi*-definite n × n matrix, in place like [`cholesky`]: pivots below
/// 10⁻¹² · max diag count as zero (their column of L is zero). Returns false
/// on a clearly negative pivot (below −10⁻⁹ · max diag) or a non-finite one.
pub fn cholesky_psd(a: &mut [f64], n: usize) -> bool {
    let scale = (0..n).map(|i| a[i + i * n].abs()).fold(0.0, f64::max);
    let tol = 1e-12 * scale.max(f64::MIN_POSITIVE);
    for j in 0..n {
        let mut d = a[j + j * n];
        for k in 0..j {
            d -= a[j + k * n] * a[j + k * n];
        }
        if !d.is_finite() || d < -1e-9 * scale.max(f64::MIN_POSITIVE) {
            return false;
        }
        if d <= tol {
            for i in j..n {
                a[i + j * n] = 0.0;
            }
        } else {
            let d = d.sqrt();
            a[j + j * n] = d;
            for i in (j + 1)..n {
                let mut s = a[i + j * n];
                for k in 0..j {
                    s -= a[i + k * n] * a[j + k * n];
                }
                a[i + j * n] = s / d;
            }
        }
        for i in 0..j {
            a[i + j * n] = 0.0;
        }
    }
    true
}

/// Solve (L Lᵀ) X = B in place for B n × c (column-major), L from
/// [`cholesky`]: a forward and a backward substitution per column.
pub fn chol_solve(l: &[f64], n: usize, b: &mut [f64], c: usize) {
    for x in b[..n * c].chunks_exact_mut(n) {
        forward_sub(l, n, x);
        backward_sub_t(l, n, x);
    }
}

/// log det(L Lᵀ) = 2 Σ log L_ii from a Cholesky factor.
pub fn chol_log_det(l: &[f64], n: usize) -> f64 {
    (0..n).map(|i| 2.0 * l[i + i * n].ln()).sum()
}

/// Solve L y = b in place (`b` becomes y) for lower-triangular L.
pub fn forward_sub(l: &[f64], n: usize, b: &mut [f64]) {
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i + k * n] * b[k];
        }
        b[i] = s / l[i + i * n];
    }
}

/// The inverse M = L⁻¹ of the n × n lower-triangular `l` (non-singular),
/// packed by rows into `out` (length n(n+1)/2: M₀₀, M₁₀, M₁₁, M₂₀, …), so
/// that L⁻¹ y is a plain product (no division on the hot path).
/// Column j of M solves L m = e_j by forward substitution.
pub fn lower_inverse_packed(l: &[f64], n: usize, out: &mut [f64]) {
    let mut col = [0.0f64; 16];
    for j in 0..n {
        col[..n].fill(0.0);
        col[j] = 1.0;
        forward_sub(l, n, &mut col[..n]);
        for i in j..n {
            out[i * (i + 1) / 2 + j] = col[i];
        }
    }
}

/// Solve Lᵀ x = y in place for lower-triangular L.
pub fn backward_sub_t(l: &[f64], n: usize, b: &mut [f64]) {
    for i in (0..n).rev() {
        let mut s = b[i];
        for k in i + 1..n {
            s -= l[k + i * n] * b[k];
        }
        b[i] = s / l[i + i * n];
    }
}

/// Largest absolute eigenvalue of the symmetric n × n matrix `a` (n ≤ 9),
/// by cyclic Jacobi rotations on a copy. Exact to rounding for these sizes.
pub fn sym_spectral_norm(a: &[f64], n: usize) -> f64 {
    let mut m = [0.0f64; 81];
    m[..n * n].copy_from_slice(&a[..n * n]);
    for _sweep in 0..30 {
        let mut off = 0.0;
        for j in 0..n {
            for i in 0..j {
                off += m[i + j * n] * m[i + j * n];
            }
        }
        let diag: f64 = (0..n).map(|i| m[i + i * n] * m[i + i * n]).sum();
        if off <= 1e-30 * diag.max(1e-300) {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                let apq = m[p + q * n];
                if apq == 0.0 {
                    continue;
                }
                let app = m[p + p * n];
                let aqq = m[q + q * n];
                let theta = (aqq - app) / (2.0 * apq);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let akp = m[k + p * n];
                    let akq = m[k + q * n];
                    m[k + p * n] = c * akp - s * akq;
                    m[k + q * n] = s * akp + c * akq;
                }
                for k in 0..n {
                    let apk = m[p + k * n];
                    let aqk = m[q + k * n];
                    m[p + k * n] = c * apk - s * aqk;
                    m[q + k * n] = s * apk + c * aqk;
                }
            }
        }
    }
    (0..n).map(|i| m[i + i * n].abs()).fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cholesky_solves_and_norm() {
        // A = [[4,2,0],[2,5,1],[0,1,3]]
        let a = [4.0, 2.0, 0.0, 2.0, 5.0, 1.0, 0.0, 1.0, 3.0];
        let mut l = a;
        assert!(cholesky(&mut l, 3));
        let mut b = [1.0, 2.0, 3.0];
        forward_sub(&l, 3, &mut b);
        backward_sub_t(&l, 3, &mut b);
        // check A x = (1,2,3)
        for i in 0..3 {
            let s: f64 = (0..3).map(|j| a[i + j * 3] * b[j]).sum();
            assert!((s - (i + 1) as f64).abs() < 1e-12);
        }
        let eig = nalgebra::DMatrix::from_column_slice(3, 3, &a).symmetric_eigenvalues();
        let want = eig.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!((sym_spectral_norm(&a, 3) - want).abs() < 1e-10);
        let mut bad = [1.0, 2.0, 2.0, 1.0];
        assert!(!cholesky(&mut bad, 2));
    }

    fn spd(n: usize, seed: u64) -> nalgebra::DMatrix<f64> {
        let mut rng = crate::rng::stream(seed, 0);
        use rand::RngExt;
        let a = nalgebra::DMatrix::from_fn(n, n, |_, _| rng.random_range(-1.0..1.0));
        &a * a.transpose() + nalgebra::DMatrix::identity(n, n) * 0.5
    }

    #[test]
    fn cholesky_and_solve_match_nalgebra() {
        use nalgebra::DMatrix;
        for n in 1..=crate::MAX_STATE {
            let a = spd(n, n as u64);
            let mut l = [0.0; 64];
            l[..n * n].copy_from_slice(a.as_slice());
            assert!(cholesky(&mut l, n));
            let ln = a.clone().cholesky().unwrap().l();
            for (x, y) in l[..n * n].iter().zip(ln.as_slice()) {
                assert!((x - y).abs() < 1e-12);
            }
            let b = DMatrix::from_fn(n, 2, |i, j| (i + 3 * j) as f64 - 1.5);
            let mut x = [0.0; 16];
            x[..2 * n].copy_from_slice(b.as_slice());
            chol_solve(&l, n, &mut x, 2);
            let xn = a.clone().lu().solve(&b).unwrap();
            for (p, q) in x[..2 * n].iter().zip(xn.as_slice()) {
                assert!((p - q).abs() < 1e-10);
            }
            assert!((chol_log_det(&l, n) - a.determinant().ln()).abs() < 1e-10);
        }
    }

    #[test]
    fn semidefinite_factor_reproduces_the_matrix() {
        use nalgebra::DMatrix;
        // rank-1 PSD matrix v vᵀ.
        let v = DMatrix::from_column_slice(3, 1, &[1.0, -2.0, 0.5]);
        let a = &v * v.transpose();
        let mut l = [0.0; 64];
        l[..9].copy_from_slice(a.as_slice());
        assert!(!cholesky(&mut l.clone(), 3));
        assert!(cholesky_psd(&mut l, 3));
        let lm = DMatrix::from_column_slice(3, 3, &l[..9]);
        assert!((&lm * lm.transpose() - a).abs().max() < 1e-12);
        let mut neg = [1.0, 0.0, 0.0, -1.0];
        assert!(!cholesky_psd(&mut neg, 2));
    }
}
