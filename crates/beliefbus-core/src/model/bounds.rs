//! The compact state set S of a model: a box, optionally with one pair of
//! coordinates further restricted to a disc centred at the origin (the
//! drifting ship's "disc of radius 9", thesis §3.4.1).

use crate::rng::SimRng;
use crate::MAX_STATE;
use rand::RngExt;

/// A pair of coordinates (`axes`) confined to ‖(x_a, x_b)‖ ≤ `radius`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Disc {
    pub axes: (usize, usize),
    pub radius: f64,
}

/// Errors building a [`Bounds`].
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum BoundsError {
    #[error("bounds: lower and upper corners have different lengths ({0} vs {1})")]
    Length(usize, usize),
    #[error("bounds: dimension {0} is 0 or exceeds {MAX_STATE}")]
    Dimension(usize),
    #[error("bounds: coordinate {0} has lo >= hi or is not finite")]
    Empty(usize),
    #[error("bounds: disc axes out of range or equal, or radius not positive")]
    Disc,
}

/// The compact set S.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    dim: usize,
    lo: [f64; MAX_STATE],
    hi: [f64; MAX_STATE],
    disc: Option<Disc>,
}

impl Bounds {
    /// The box [lo, hi].
    pub fn new_box(lo: &[f64], hi: &[f64]) -> Result<Self, BoundsError> {
        if lo.len() != hi.len() {
            return Err(BoundsError::Length(lo.len(), hi.len()));
        }
        let dim = lo.len();
        if dim == 0 || dim > MAX_STATE {
            return Err(BoundsError::Dimension(dim));
        }
        let mut b = Self {
            dim,
            lo: [0.0; MAX_STATE],
            hi: [0.0; MAX_STATE],
            disc: None,
        };
        for i in 0..dim {
            if !(lo[i].is_finite() && hi[i].is_finite() && lo[i] < hi[i]) {
                return Err(BoundsError::Empty(i));
            }
            b.lo[i] = lo[i];
            b.hi[i] = hi[i];
        }
        Ok(b)
    }

    /// A box whose coordinates `axes` are further confined to a disc of
    /// `radius`; the box on those two axes becomes [−radius, radius].
    pub fn with_disc(mut self, axes: (usize, usize), radius: f64) -> Result<Self, BoundsError> {
        if axes.0 >= self.dim || axes.1 >= self.dim || axes.0 == axes.1 || !(radius > 0.0) {
            return Err(BoundsError::Disc);
        }
        for a in [axes.0, axes.1] {
            self.lo[a] = -radius;
            self.hi[a] = radius;
        }
        self.disc = Some(Disc { axes, radius });
        Ok(self)
    }

    /// Dimension d.
    pub fn dim(&self) -> usize {
        self.dim
    }
    /// Lower corner of the bounding box.
    pub fn lo(&self) -> &[f64] {
        &self.lo[..self.dim]
    }
    /// Upper corner of the bounding box.
    pub fn hi(&self) -> &[f64] {
        &self.hi[..self.dim]
    }
    /// The disc constraint, if any.
    pub fn disc(&self) -> Option<Disc> {
        self.disc
    }

    /// Whether x ∈ S.
    pub fn contains(&self, x: &[f64]) -> bool {
        let in_box = (0..self.dim).all(|i| x[i] >= self.lo[i] && x[i] <= self.hi[i]);
        in_box
            && self
                .disc
                .is_none_or(|d| x[d.axes.0].hypot(x[d.axes.1]) <= d.radius)
    }

    /// Lebesgue measure μ(S).
    pub fn volume(&self) -> f64 {
        let mut v: f64 = (0..self.dim).map(|i| self.hi[i] - self.lo[i]).product();
        if self.disc.is_some() {
            v *= std::f64::consts::PI / 4.0; // disc area πr² over its square (2r)²
        }
        v
    }

    /// Draw x uniformly from S (rejection from the box for the disc part;
    /// acceptance probability π/4).
    pub fn sample_uniform(&self, rng: &mut SimRng, x: &mut [f64]) {
        loop {
            for i in 0..self.dim {
                x[i] = rng.random_range(self.lo[i]..self.hi[i]);
            }
            if self.contains(x) {
                return;
            }
        }
    }

    /// Move x to the nearest point of S (radially into the disc, then clamp
    /// the remaining coordinates to the box).
    pub fn project(&self, x: &mut [f64]) {
        if let Some(d) = self.disc {
            let r = x[d.axes.0].hypot(x[d.axes.1]);
            if r > d.radius {
                let s = d.radius / r;
                x[d.axes.0] *= s;
                x[d.axes.1] *= s;
            }
        }
        for i in 0..self.dim {
            x[i] = x[i].clamp(self.lo[i], self.hi[i]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn disc_volume_and_uniform_sampling_agree() {
        let b = Bounds::new_box(&[0.0, 0.0, -1.0], &[1.0, 1.0, 1.0])
            .unwrap()
            .with_disc((0, 1), 2.0)
            .unwrap();
        // π·2² · 2 for the third axis.
        assert!((b.volume() - std::f64::consts::PI * 8.0).abs() < 1e-12);
        let mut rng = crate::rng::stream(1, 0);
        let mut x = [0.0; 3];
        let n = 20_000;
        let mut inner = 0;
        for _ in 0..n {
            b.sample_uniform(&mut rng, &mut x);
            assert!(b.contains(&x));
            if x[0].hypot(x[1]) <= 1.0 {
                inner += 1;
            }
        }
        // P(r ≤ 1) = 1/4 for a uniform disc of radius 2; 4σ binomial bound.
        let p = inner as f64 / n as f64;
        let sd = (0.25 * 0.75 / n as f64).sqrt();
        assert!((p - 0.25).abs() < 4.0 * sd, "p = {p}");
    }

    #[test]
    fn project_lands_inside() {
        let b = Bounds::new_box(&[-1.0, -1.0], &[1.0, 1.0])
            .unwrap()
            .with_disc((0, 1), 1.0)
            .unwrap();
        let mut x = [3.0, 4.0];
        b.project(&mut x);
        assert!(b.contains(&x));
        assert!((x[0] - 0.6).abs() < 1e-12 && (x[1] - 0.8).abs() < 1e-12);
    }

    #[test]
    fn rejects_bad_boxes() {
        assert_eq!(Bounds::new_box(&[0.0], &[0.0]), Err(BoundsError::Empty(0)));
        assert_eq!(
            Bounds::new_box(&[0.0], &[1.0, 2.0]),
            Err(BoundsError::Length(1, 2))
        );
        assert!(Bounds::new_box(&[0.0, 0.0], &[1.0, 1.0])
            .unwrap()
            .with_disc((0, 0), 1.0)
            .is_err());
    }
}
