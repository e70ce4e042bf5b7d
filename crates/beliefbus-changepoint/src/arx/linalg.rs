//! Fixed-size dense helpers for the d = k + h dimensional regression
//! (d = 3 in the paper's experiments): stack arrays, no allocation.

/// Dimension-D vector.
pub type Vector<const D: usize> = [f64; D];
/// Dimension-D square matrix, row major.
pub type Matrix<const D: usize> = [[f64; D]; D];

/// aᵀb.
#[inline]
pub fn dot<const D: usize>(a: &Vector<D>, b: &Vector<D>) -> f64 {
    let mut s = 0.0;
    for i in 0..D {
        s += a[i] * b[i];
    }
    s
}

/// M x.
#[inline]
pub fn mat_vec<const D: usize>(m: &Matrix<D>, x: &Vector<D>) -> Vector<D> {
    let mut out = [0.0; D];
    for i in 0..D {
        out[i] = dot(&m[i], x);
    }
    out
}

/// The identity scaled by `s`.
pub fn scaled_identity<const D: usize>(s: f64) -> Matrix<D> {
    let mut m = [[0.0; D]; D];
    for i in 0..D {
        m[i][i] = s;
    }
    m
}

/// Cholesky factor L (lower) of a symmetric positive-definite matrix, or
/// None if it is not positive definite.
pub fn cholesky<const D: usize>(a: &Matrix<D>) -> Option<Matrix<D>> {
    let mut l = [[0.0; D]; D];
    for i in 0..D {
        for j in 0..=i {
            let mut s = a[i][j];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            if i == j {
                if !(s > 0.0) || !s.is_finite() {
                    return None;
                }
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    Some(l)
}

/// Solve A x = b given A's Cholesky factor L.
pub fn cholesky_solve<const D: usize>(l: &Matrix<D>, b: &Vector<D>) -> Vector<D> {
    let mut z = [0.0; D];
    for i in 0..D {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i][k] * z[k];
        }
        z[i] = s / l[i][i];
    }
    let mut x = [0.0; D];
    for i in (0..D).rev() {
        let mut s = z[i];
        for k in i + 1..D {
            s -= l[k][i] * x[k];
        }
        x[i] = s / l[i][i];
    }
    x
}

/// A⁻¹ for symmetric positive-definite A (None if not SPD).
pub fn spd_inverse<const D: usize>(a: &Matrix<D>) -> Option<Matrix<D>> {
    let l = cholesky(a)?;
    let mut inv = [[0.0; D]; D];
    for j in 0..D {
        let mut e = [0.0; D];
        e[j] = 1.0;
        let col = cholesky_solve(&l, &e);
        for i in 0..D {
            inv[i][j] = col[i];
        }
    }
    Some(inv)
}

/// One observation y = θᵀφ + ε, ε ~ N(0, 1), folded into the Gaussian
/// N(μ, V) on θ by the rank-one recursions under (14):
/// V ← V − Vφφᵀ V/(1 + φᵀVφ), μ ← μ + Vφ(y − φᵀμ)/(1 + φᵀVφ).
/// Returns (y − φᵀμ, 1 + φᵀVφ): the one-step predictive residual and
/// variance, the ingredients of (16).
#[inline]
pub fn kalman_update<const D: usize>(
    mu: &mut Vector<D>,
    v: &mut Matrix<D>,
    phi: &Vector<D>,
    y: f64,
) -> (f64, f64) {
    let vphi = mat_vec(v, phi);
    let s = 1.0 + dot(phi, &vphi);
    let r = y - dot(phi, mu);
    let inv_s = 1.0 / s;
    for i in 0..D {
        mu[i] += vphi[i] * r * inv_s;
        for j in 0..D {
            v[i][j] -= vphi[i] * vphi[j] * inv_s;
        }
    }
    // Keep V exactly symmetric against rounding.
    for i in 0..D {
        for j in 0..i {
            let m = 0.5 * (v[i][j] + v[j][i]);
            v[i][j] = m;
            v[j][i] = m;
        }
    }
    (r, s)
}

/// The predictive residual and variance of (16) without updating.
#[inline]
pub fn predictive<const D: usize>(
    mu: &Vector<D>,
    v: &Matrix<D>,
    phi: &Vector<D>,
    y: f64,
) -> (f64, f64) {
    let vphi = mat_vec(v, phi);
    (y - dot(phi, mu), 1.0 + dot(phi, &vphi))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_and_solve_are_exact_on_a_known_matrix() {
        let a = [[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]];
        let inv = spd_inverse(&a).unwrap();
        for i in 0..3 {
            for j in 0..3 {
                let p: f64 = (0..3).map(|k| a[i][k] * inv[k][j]).sum();
                assert!((p - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
        assert!(cholesky(&[[1.0, 2.0], [2.0, 1.0]]).is_none());
    }
}
