//! Gaussian summary of a belief, fixed-size so it is `Copy` and never
//! allocates: every filter backend reports its belief through it and the
//! controllers consume it.

use crate::MAX_STATE;

/// Mean and covariance of a belief over a state of dimension `dim`.
///
/// `cov` holds the `dim × dim` covariance in column-major order in its first
/// `dim²` entries (stride `dim`, not `MAX_STATE`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gaussian {
    pub dim: usize,
    pub mean: [f64; MAX_STATE],
    pub cov: [f64; MAX_STATE * MAX_STATE],
}

impl Gaussian {
    /// A zero-mean, zero-covariance belief of dimension `dim`.
    pub fn zeros(dim: usize) -> Self {
        assert!(dim <= MAX_STATE, "state dimension {dim} exceeds MAX_STATE");
        Self {
            dim,
            mean: [0.0; MAX_STATE],
            cov: [0.0; MAX_STATE * MAX_STATE],
        }
    }

    /// A belief with the given mean and a diagonal covariance `diag(std²)`.
    pub fn diagonal(mean: &[f64], std: &[f64]) -> Self {
        assert_eq!(mean.len(), std.len());
        let mut g = Self::zeros(mean.len());
        g.mean[..mean.len()].copy_from_slice(mean);
        for (i, s) in std.iter().enumerate() {
            g.set_cov(i, i, s * s);
        }
        g
    }

    /// The mean as a slice of length `dim`.
    pub fn mean(&self) -> &[f64] {
        &self.mean[..self.dim]
    }

    /// Mutable mean of length `dim`.
    pub fn mean_mut(&mut self) -> &mut [f64] {
        &mut self.mean[..self.dim]
    }

    /// The covariance, column-major `dim × dim`.
    pub fn cov(&self) -> &[f64] {
        &self.cov[..self.dim * self.dim]
    }

    /// Mutable covariance, column-major `dim × dim`.
    pub fn cov_mut(&mut self) -> &mut [f64] {
        let n = self.dim * self.dim;
        &mut self.cov[..n]
    }

    /// Entry (i, j) of the covariance.
    pub fn cov_at(&self, i: usize, j: usize) -> f64 {
        self.cov[i + j * self.dim]
    }

    /// Set entry (i, j) of the covariance (not its symmetric partner).
    pub fn set_cov(&mut self, i: usize, j: usize, v: f64) {
        self.cov[i + j * self.dim] = v;
    }

    /// True when the mean and covariance are all finite.
    pub fn is_finite(&self) -> bool {
        self.mean().iter().chain(self.cov()).all(|v| v.is_finite())
    }

    /// The mean as an owned nalgebra vector (allocates; not for hot paths).
    pub fn mean_vector(&self) -> nalgebra::DVector<f64> {
        nalgebra::DVector::from_column_slice(self.mean())
    }

    /// The covariance as an owned nalgebra matrix (allocates; not for hot paths).
    pub fn cov_matrix(&self) -> nalgebra::DMatrix<f64> {
        nalgebra::DMatrix::from_column_slice(self.dim, self.dim, self.cov())
    }

    /// Build from nalgebra mean and covariance.
    pub fn from_nalgebra(mean: &nalgebra::DVector<f64>, cov: &nalgebra::DMatrix<f64>) -> Self {
        let mut g = Self::zeros(mean.len());
        g.mean_mut().copy_from_slice(mean.as_slice());
        g.cov_mut().copy_from_slice(cov.as_slice());
        g
    }
}

/// Weighted mean and covariance of points, accumulated as offsets from a
/// centre c (near the mean, so the second moment does not cancel):
/// m = c + Σw(z−c)/Σw, P = Σw(z−c)(z−c)ᵀ/Σw − (m−c)(m−c)ᵀ.
pub struct WeightedMoments {
    d: usize,
    c: [f64; MAX_STATE],
    m1: [f64; MAX_STATE],
    m2: [f64; MAX_STATE * MAX_STATE],
    tot: f64,
}

impl WeightedMoments {
    /// An empty accumulator in dimension `c.len()` centred at `c`.
    pub fn new(c: &[f64]) -> Self {
        let mut centre = [0.0; MAX_STATE];
        centre[..c.len()].copy_from_slice(c);
        Self {
            d: c.len(),
            c: centre,
            m1: [0.0; MAX_STATE],
            m2: [0.0; MAX_STATE * MAX_STATE],
            tot: 0.0,
        }
    }

    /// Add the point `z` with weight `w ≥ 0`.
    #[inline]
    pub fn add(&mut self, w: f64, z: &[f64]) {
        let d = self.d;
        self.tot += w;
        let mut dz = [0.0; MAX_STATE];
        for a in 0..d {
            dz[a] = z[a] - self.c[a];
            self.m1[a] += w * dz[a];
        }
        for a in 0..d {
            let wa = w * dz[a];
            for b in a..d {
                self.m2[a + b * d] += wa * dz[b];
            }
        }
    }

    /// [`Self::add`] for a dimension `D` known at compile time (the same
    /// arithmetic in the same order, so the same result, with the loops
    /// unrolled); `D` must equal the accumulator's dimension.
    #[inline(always)]
    pub fn add_fixed<const D: usize>(&mut self, w: f64, z: &[f64]) {
        debug_assert_eq!(D, self.d);
        let z = &z[..D];
        self.tot += w;
        let mut dz = [0.0; D];
        for a in 0..D {
            dz[a] = z[a] - self.c[a];
            self.m1[a] += w * dz[a];
        }
        for a in 0..D {
            let wa = w * dz[a];
            for b in a..D {
                self.m2[a + b * D] += wa * dz[b];
            }
        }
    }

    /// The Gaussian with the accumulated mean and covariance.
    pub fn gaussian(&self) -> Gaussian {
        let d = self.d;
        let mut g = Gaussian::zeros(d);
        let tot = self.tot.max(1e-300);
        let mut m1 = [0.0; MAX_STATE];
        for a in 0..d {
            m1[a] = self.m1[a] / tot;
            g.mean[a] = self.c[a] + m1[a];
        }
        for a in 0..d {
            for b in a..d {
                let v = self.m2[a + b * d] / tot - m1[a] * m1[b];
                g.set_cov(a, b, v);
                g.set_cov(b, a, v);
            }
        }
        g
    }
}
