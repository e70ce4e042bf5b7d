//! Symmetric banded matrices and their Cholesky factor.
//!
//! The Hessian of a path functional (paper 003 eq. 15) couples each path
//! point only with its neighbours, so it is block-tridiagonal (or banded with
//! a few more blocks for second-order models). Stored as a band of half-width
//! `kd`, the factorisation `H = L Lᵀ` costs O(N·kd²) and the triangular
//! solves O(N·kd): linear in the horizon. A dense matrix is the special case
//! `kd = N − 1`.
//!
//! Storage is LAPACK's lower band layout by columns: entry (i, j), j ≤ i ≤
//! j + kd, lives at `data[j·(kd+1) + (i − j)]`, so a column of the band is
//! contiguous. The buffer is sized once for a maximal dimension; `resize`
//! reuses it for a smaller one (a shrinking horizon) without allocating.
//!
//! This is not a second copy of the dense Cholesky in `math::linalg`: it
//! works on band storage and never touches the zeros outside the band.

/// The matrix was not positive definite: pivot `0` was not positive.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("matrix is not positive definite (pivot {0})")]
pub struct NotPositiveDefinite(pub usize);

/// A symmetric band matrix (lower half stored).
#[derive(Clone, Debug)]
pub struct SymBand {
    n: usize,
    kd: usize,
    cap: usize,
    data: Vec<f64>,
}

impl SymBand {
    /// A zero matrix of dimension `n` and half-bandwidth `kd`, able to hold
    /// any dimension up to `n` later.
    pub fn new(n: usize, kd: usize) -> Self {
        Self {
            n,
            kd,
            cap: n,
            data: vec![0.0; n.max(1) * (kd + 1)],
        }
    }

    /// Dimension N.
    pub fn dim(&self) -> usize {
        self.n
    }

    /// Half-bandwidth kd.
    pub fn kd(&self) -> usize {
        self.kd
    }

    /// Use dimension `n ≤ capacity` (same kd) and zero the matrix.
    pub fn resize(&mut self, n: usize) {
        assert!(
            n <= self.cap,
            "SymBand::resize {n} beyond capacity {}",
            self.cap
        );
        self.n = n;
        self.fill_zero();
    }

    /// Set every stored entry to zero.
    pub fn fill_zero(&mut self) {
        let len = self.n * (self.kd + 1);
        self.data[..len].fill(0.0);
    }

    /// Copy `other` (same dimension and bandwidth) into self.
    pub fn copy_from(&mut self, other: &SymBand) {
        debug_assert_eq!(self.kd, other.kd);
        assert!(other.n <= self.cap);
        self.n = other.n;
        let len = self.n * (self.kd + 1);
        self.data[..len].copy_from_slice(&other.data[..len]);
    }

    #[inline]
    fn idx(&self, i: usize, j: usize) -> usize {
        debug_assert!(j <= i && i - j <= self.kd && i < self.n);
        j * (self.kd + 1) + (i - j)
    }

    /// Entry (i, j) of the symmetric matrix (zero outside the band).
    pub fn get(&self, i: usize, j: usize) -> f64 {
        let (i, j) = if i >= j { (i, j) } else { (j, i) };
        if i - j > self.kd {
            0.0
        } else {
            self.data[self.idx(i, j)]
        }
    }

    /// Add `v` to entry (i, j) (and so to (j, i)); `|i − j| ≤ kd`.
    #[inline]
    pub fn add(&mut self, i: usize, j: usize, v: f64) {
        let (i, j) = if i >= j { (i, j) } else { (j, i) };
        let k = self.idx(i, j);
        self.data[k] += v;
    }

    /// Set entry (i, j) (and so (j, i)); `|i − j| ≤ kd`.
    pub fn set(&mut self, i: usize, j: usize, v: f64) {
        let (i, j) = if i >= j { (i, j) } else { (j, i) };
        let k = self.idx(i, j);
        self.data[k] = v;
    }

    /// Add `shift` to the diagonal.
    pub fn add_diagonal(&mut self, shift: f64) {
        for j in 0..self.n {
            let k = j * (self.kd + 1);
            self.data[k] += shift;
        }
    }

    /// Largest absolute diagonal entry.
    pub fn max_abs_diagonal(&self) -> f64 {
        (0..self.n)
            .map(|j| self.data[j * (self.kd + 1)].abs())
            .fold(0.0, f64::max)
    }

    /// Replace row and column `i` by those of the identity (a variable held
    /// fixed by a constraint).
    pub fn pin(&mut self, i: usize) {
        let lo = i.saturating_sub(self.kd);
        let hi = (i + self.kd).min(self.n - 1);
        for j in lo..=hi {
            self.set(i, j, 0.0);
        }
        self.set(i, i, 1.0);
    }

    /// y = A x.
    pub fn mul_vec(&self, x: &[f64], y: &mut [f64]) {
        let n = self.n;
        y[..n].fill(0.0);
        for j in 0..n {
            let col = &self.data[j * (self.kd + 1)..];
            y[j] += col[0] * x[j];
            let last = (j + self.kd).min(n - 1);
            for i in j + 1..=last {
                let a = col[i - j];
                y[i] += a * x[j];
                y[j] += a * x[i];
            }
        }
    }

    /// In-place Cholesky factorisation A = L Lᵀ (right-looking, band
    /// preserved). On failure the content is garbage.
    pub fn cholesky_in_place(&mut self) -> Result<(), NotPositiveDefinite> {
        let n = self.n;
        let w = self.kd + 1;
        for j in 0..n {
            let base = j * w;
            let d = self.data[base];
            if !(d > 0.0) || !d.is_finite() {
                return Err(NotPositiveDefinite(j));
            }
            let ljj = d.sqrt();
            self.data[base] = ljj;
            let last = (j + self.kd).min(n - 1);
            let inv = 1.0 / ljj;
            for i in j + 1..=last {
                self.data[base + i - j] *= inv;
            }
            // Trailing update: A[i, l] -= L[i, j] L[l, j] for j < l ≤ i ≤ last.
            for l in j + 1..=last {
                let llj = self.data[base + l - j];
                if llj == 0.0 {
                    continue;
                }
                let lbase = l * w;
                for i in l..=last {
                    self.data[lbase + i - l] -= self.data[base + i - j] * llj;
                }
            }
        }
        Ok(())
    }

    /// With self = L (a factor): solve L y = b in place.
    pub fn solve_lower_in_place(&self, b: &mut [f64]) {
        let n = self.n;
        let w = self.kd + 1;
        for j in 0..n {
            let col = &self.data[j * w..];
            let yj = b[j] / col[0];
            b[j] = yj;
            let last = (j + self.kd).min(n - 1);
            for i in j + 1..=last {
                b[i] -= col[i - j] * yj;
            }
        }
    }

    /// With self = L (a factor): solve Lᵀ x = y in place.
    pub fn solve_upper_in_place(&self, y: &mut [f64]) {
        let n = self.n;
        let w = self.kd + 1;
        for j in (0..n).rev() {
            let col = &self.data[j * w..];
            let last = (j + self.kd).min(n - 1);
            let mut s = y[j];
            for i in j + 1..=last {
                s -= col[i - j] * y[i];
            }
            y[j] = s / col[0];
        }
    }

    /// With self = L: solve L Lᵀ x = b in place.
    pub fn solve_in_place(&self, b: &mut [f64]) {
        self.solve_lower_in_place(b);
        self.solve_upper_in_place(b);
    }

    /// With self = L: ‖Lᵀ d‖² = dᵀ L Lᵀ d (the quadratic form of the
    /// factored matrix).
    pub fn upper_norm_sq(&self, d: &[f64]) -> f64 {
        let n = self.n;
        let w = self.kd + 1;
        let mut s = 0.0;
        for j in 0..n {
            let col = &self.data[j * w..];
            let last = (j + self.kd).min(n - 1);
            let mut v = 0.0;
            for i in j..=last {
                v += col[i - j] * d[i];
            }
            s += v * v;
        }
        s
    }

    /// With self = L: log det L = Σ log L_ii (so log det A = 2 log det L).
    pub fn log_det_factor(&self) -> f64 {
        (0..self.n).map(|j| self.data[j * (self.kd + 1)].ln()).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, DVector};

    fn random_spd_band(n: usize, kd: usize, seed: u64) -> (SymBand, DMatrix<f64>) {
        use rand::RngExt;
        let mut rng = crate::rng::stream(seed, 0);
        let mut b = SymBand::new(n, kd);
        let mut d = DMatrix::zeros(n, n);
        for j in 0..n {
            for i in j..(j + kd + 1).min(n) {
                let v: f64 = if i == j {
                    2.0 * (kd as f64 + 1.0) + rng.random::<f64>()
                } else {
                    rng.random::<f64>() - 0.5
                };
                b.set(i, j, v);
                d[(i, j)] = v;
                d[(j, i)] = v;
            }
        }
        (b, d)
    }

    #[test]
    fn cholesky_and_solves_match_dense() {
        for &(n, kd) in &[(1, 0), (7, 1), (20, 3), (13, 12), (30, 7)] {
            let (mut b, d) = random_spd_band(n, kd, (n * 31 + kd) as u64);
            let x_true = DVector::from_fn(n, |i, _| (i as f64 * 0.7).sin());
            let rhs = &d * &x_true;
            let mut y = vec![0.0; n];
            b.mul_vec(x_true.as_slice(), &mut y);
            for i in 0..n {
                assert!((y[i] - rhs[i]).abs() < 1e-12);
            }
            b.cholesky_in_place().unwrap();
            let mut sol = rhs.as_slice().to_vec();
            b.solve_in_place(&mut sol);
            for i in 0..n {
                assert!((sol[i] - x_true[i]).abs() < 1e-10, "n={n} kd={kd}");
            }
            let quad = x_true.dot(&(&d * &x_true));
            let dense = d.clone().cholesky().unwrap();
            let ld: f64 = dense.l().diagonal().iter().map(|v| v.ln()).sum();
            assert!((b.log_det_factor() - ld).abs() < 1e-10);
            assert!((b.upper_norm_sq(x_true.as_slice()) - quad).abs() < 1e-9 * quad.max(1.0));
            // The factor's entries equal the dense factor's.
            let l = dense.l();
            for j in 0..n {
                for i in j..(j + kd + 1).min(n) {
                    assert!((b.get(i, j) - l[(i, j)]).abs() < 1e-10);
                }
            }
        }
    }

    #[test]
    fn rejects_indefinite() {
        let mut b = SymBand::new(2, 1);
        b.set(0, 0, 1.0);
        b.set(1, 0, 2.0);
        b.set(1, 1, 1.0);
        assert_eq!(b.cholesky_in_place(), Err(NotPositiveDefinite(1)));
    }

    #[test]
    fn resize_reuses_storage() {
        let mut b = SymBand::new(10, 2);
        b.resize(4);
        b.add_diagonal(4.0);
        b.add(1, 0, 1.0);
        b.cholesky_in_place().unwrap();
        assert_eq!(b.dim(), 4);
        assert!((b.get(0, 0) - 2.0).abs() < 1e-15);
        assert!((b.get(1, 0) - 0.5).abs() < 1e-15);
    }
}
