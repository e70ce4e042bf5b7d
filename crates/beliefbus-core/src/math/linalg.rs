//! Tiny dense linear algebra on stack arrays (dimension ≤ 9, or the ≤ 45
//! moment equations of the LP kernel): Cholesky, triangular solves and the
//! spectral norm of a symmetric matrix. nalgebra's dynamic matrices allocate;
//! these run inside chain construction for every state, so they must not.
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
}
