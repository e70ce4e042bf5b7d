//! The grid G on projected parameters (paper §III, Algorithms 1–2) and its
//! nearest-neighbour map.
//!
//! G is a rectangular product of uniform axes (the inventory grid: mean
//! 0:0.5:15 × std 0:0.2:5, 31 × 26 = 806 points). The paper leaves the
//! nearest-neighbour metric unstated; we use the Euclidean distance in the
//! grid coordinates themselves (mean and standard deviation in state
//! units). On a product grid the Euclidean nearest point is the
//! per-coordinate nearest one, so the map is O(dim): round each coordinate
//! to its axis and clamp to the axis ends (a projected mean above 15 maps
//! to the edge 15). Ties (exactly half-way) go to the upper point.

use crate::ProjectionError;
use serde::{Deserialize, Serialize};

/// A uniform axis start, start + step, …, start + (count − 1)·step.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Axis {
    pub start: f64,
    pub step: f64,
    pub count: usize,
}

impl Axis {
    /// The MATLAB-style range start:step:stop.
    pub fn range(start: f64, step: f64, stop: f64) -> Result<Self, ProjectionError> {
        if !(start.is_finite()
            && stop.is_finite()
            && step > 0.0
            && step.is_finite()
            && stop >= start)
        {
            return Err(ProjectionError::invalid(
                "grid axis",
                format!("{start}:{step}:{stop} (need finite start <= stop and step > 0)"),
            ));
        }
        let count = ((stop - start) / step + 1e-9).floor() as usize + 1;
        Ok(Self { start, step, count })
    }

    /// The i-th value.
    pub fn value(&self, i: usize) -> f64 {
        self.start + i as f64 * self.step
    }

    /// The index of the nearest value, clamped to the axis.
    pub fn nearest(&self, x: f64) -> usize {
        let r = ((x - self.start) / self.step + 0.5).floor();
        if r <= 0.0 {
            0
        } else {
            (r as usize).min(self.count - 1)
        }
    }
}

/// A product grid; flat index = Σ_k i_k · stride_k with the last axis
/// fastest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ParamGrid {
    pub axes: Vec<Axis>,
}

impl ParamGrid {
    /// A grid from its axes.
    pub fn new(axes: Vec<Axis>) -> Result<Self, ProjectionError> {
        if axes.is_empty() || axes.iter().any(|a| a.count == 0) {
            return Err(ProjectionError::invalid(
                "grid",
                "needs at least one non-empty axis",
            ));
        }
        Ok(Self { axes })
    }

    /// The paper's inventory grid: mean 0:0.5:15 × std 0:0.2:5.
    pub fn inventory_paper() -> Self {
        Self {
            axes: vec![
                Axis::range(0.0, 0.5, 15.0).expect("valid constant range"),
                Axis::range(0.0, 0.2, 5.0).expect("valid constant range"),
            ],
        }
    }

    /// The number of coordinates.
    pub fn dim(&self) -> usize {
        self.axes.len()
    }

    /// The number of grid points.
    pub fn len(&self) -> usize {
        self.axes.iter().map(|a| a.count).product()
    }

    /// Never true for a grid built by [`ParamGrid::new`].
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The coordinates of point `idx` into `out`.
    pub fn point(&self, mut idx: usize, out: &mut [f64]) {
        for (k, a) in self.axes.iter().enumerate().rev() {
            out[k] = a.value(idx % a.count);
            idx /= a.count;
        }
    }

    /// The flat index of the nearest grid point to `coords`.
    pub fn nearest(&self, coords: &[f64]) -> Result<usize, ProjectionError> {
        ProjectionError::check_len("grid coordinates", self.dim(), coords.len())?;
        let mut idx = 0;
        for (a, &c) in self.axes.iter().zip(coords) {
            if c.is_nan() {
                return Err(ProjectionError::invalid("grid coordinates", "NaN"));
            }
            idx = idx * a.count + a.nearest(c);
        }
        Ok(idx)
    }
}
