//! The exact Kalman filter on a linear-Gaussian SDE — the reference every
//! approximate filter is tested against.
//!
//! Model ([`LinearSde`]): `dx = (A x + B u) dt + F dw`, `y_k = C x_k + v_k`,
//! `v_k ~ N(0, diag σ²)`. Over Δ = t − t_k with u held constant the exact
//! transition is `x ↦ A_d x + B_d u + N(0, Q_d)` (Van Loan, see
//! [`LinearSde::discretize`]), so
//!
//! ```text
//! predict:  m⁻ = A_d m + B_d u,        P⁻ = A_d P A_dᵀ + Q_d
//! update:   Joseph form on the masked rows of C (see `gauss`)
//! ```
//!
//! The discretisation of the last Δ is cached: a fixed-rate sensor costs one
//! matrix exponential in total, a jittery one costs one per distinct Δ
//! (allocating; this filter is a reference, not a real-time backend).

use super::gauss::{self, Mat, ObsMat};
use super::gauss_state::{gaussian_info, predict_span, reset_or_keep, GaussState};
use super::{check_measurement, BayesFilter, FilterError, UpdateInfo};
use crate::belief::Gaussian;
use crate::model::linear::LinearSde;
use crate::model::{Dims, Measurement, SdeModel};
use crate::{MAX_CONTROL, MAX_OBS, MAX_STATE};

/// Two Δ closer than this (relative) share one cached discretisation.
const DT_REL_TOL: f64 = 1e-9;

/// Exact Kalman filter on a [`LinearSde`].
#[derive(Clone, Debug)]
pub struct Kalman {
    model: LinearSde,
    dims: Dims,
    s: GaussState,
    /// Observation matrix C (m × d) and σ, copied once.
    c: ObsMat,
    obs_std: [f64; MAX_OBS],
    /// Cached discretisation for `cached_dt` (NaN: none yet).
    cached_dt: f64,
    ad: Mat,
    bd: [f64; MAX_STATE * MAX_CONTROL],
    qd: Mat,
}

impl Kalman {
    /// A filter at time `t0` with the prior N(mean, cov).
    pub fn new(model: LinearSde, prior: &Gaussian, t0: f64) -> Result<Self, FilterError> {
        let dims = model.dims();
        if dims.state > MAX_STATE || dims.obs > MAX_OBS || dims.control > MAX_CONTROL {
            return Err(FilterError::Dimension {
                what: "model",
                got: dims.state.max(dims.obs),
                expected: MAX_STATE,
            });
        }
        let s = GaussState::new(dims.state, prior, t0)?;
        let mut c = [0.0; MAX_OBS * MAX_STATE];
        c[..dims.obs * dims.state].copy_from_slice(model.c.as_slice());
        let mut obs_std = [0.0; MAX_OBS];
        model.obs_std(&mut obs_std[..dims.obs]);
        Ok(Self {
            model,
            dims,
            s,
            c,
            obs_std,
            cached_dt: f64::NAN,
            ad: [0.0; MAX_STATE * MAX_STATE],
            bd: [0.0; MAX_STATE * MAX_CONTROL],
            qd: [0.0; MAX_STATE * MAX_STATE],
        })
    }

    /// The model being filtered.
    pub fn model(&self) -> &LinearSde {
        &self.model
    }

    /// Restart from `prior` at `t`, rejecting an invalid prior.
    pub fn try_reset(&mut self, t: f64, prior: &Gaussian) -> Result<(), FilterError> {
        self.s.try_reset(t, prior)
    }

    fn ensure_discretized(&mut self, dt: f64) {
        if (dt - self.cached_dt).abs() <= DT_REL_TOL * dt {
            return;
        }
        let Dims {
            state: d,
            control: c,
            ..
        } = self.dims;
        let disc = self.model.discretize(dt);
        self.ad[..d * d].copy_from_slice(disc.ad.as_slice());
        self.bd[..d * c].copy_from_slice(disc.bd.as_slice());
        self.qd[..d * d].copy_from_slice(disc.qd.as_slice());
        self.cached_dt = dt;
    }
}

impl BayesFilter for Kalman {
    fn name(&self) -> &'static str {
        "kalman"
    }
    fn dims(&self) -> Dims {
        self.dims
    }
    fn time(&self) -> f64 {
        self.s.t
    }
    fn reset(&mut self, t: f64, prior: &Gaussian) {
        reset_or_keep("kalman", self.try_reset(t, prior));
    }

    fn predict(&mut self, t: f64, u: &[f64]) -> Result<(), FilterError> {
        let Some(dt) = predict_span(self.s.t, t, u, self.dims)? else {
            return Ok(());
        };
        let Dims {
            state: d,
            control: c,
            ..
        } = self.dims;
        self.ensure_discretized(dt);
        let mut m = [0.0; MAX_STATE];
        gauss::mul(&self.ad, d, d, &self.s.mean, 1, &mut m);
        for i in 0..d {
            for j in 0..c {
                m[i] += self.bd[i + j * d] * u[j];
            }
        }
        let mut tmp: Mat = [0.0; MAX_STATE * MAX_STATE];
        let mut p: Mat = [0.0; MAX_STATE * MAX_STATE];
        gauss::mul(&self.ad, d, d, &self.s.cov, d, &mut tmp);
        gauss::mul_bt(&tmp, d, d, &self.ad, d, &mut p);
        for i in 0..d * d {
            p[i] += self.qd[i];
        }
        gauss::symmetrize(&mut p, d);
        if !m[..d].iter().chain(&p[..d * d]).all(|v| v.is_finite()) {
            return Err(FilterError::Numerical("prediction is not finite"));
        }
        self.s.mean = m;
        self.s.cov = p;
        self.s.t = t;
        Ok(())
    }

    fn update(&mut self, meas: &Measurement) -> Result<UpdateInfo, FilterError> {
        check_measurement(meas, self.dims)?;
        let Dims {
            state: d, obs: m, ..
        } = self.dims;
        let mut yhat = [0.0; MAX_OBS];
        self.model.obs_mean(&self.s.mean[..d], &mut yhat[..m]);
        let mut r = [0.0; MAX_OBS];
        self.model
            .obs_residual(&meas.y[..m], &yhat[..m], &mut r[..m]);
        let std = meas.std.unwrap_or(&self.obs_std[..m]);
        let log_evidence = self.s.joseph_update(m, &self.c, &r, std, meas.mask)?;
        Ok(gaussian_info(log_evidence))
    }

    fn belief(&self) -> Gaussian {
        self.s.belief()
    }
}

/// Linear-Gaussian test models shared by the filter tests.
#[cfg(test)]
pub(crate) mod testmodels {
    use crate::model::linear::LinearSde;
    use crate::model::Bounds;
    use nalgebra::DMatrix;

    /// A damped, controlled oscillator observed in position and velocity:
    /// stable, coupled, with a control input — exercises every term.
    pub fn oscillator(obs_std: [f64; 2]) -> LinearSde {
        LinearSde::new(
            "osc",
            DMatrix::from_row_slice(2, 2, &[0.0, 1.0, -2.0, -0.6]),
            DMatrix::from_row_slice(2, 1, &[0.0, 1.0]),
            DMatrix::from_row_slice(2, 2, &[0.3, 0.0, 0.1, 0.5]),
            DMatrix::from_row_slice(2, 2, &[1.0, 0.0, 0.5, 1.0]),
            obs_std.to_vec(),
            Bounds::new_box(&[-10.0, -10.0], &[10.0, 10.0]).unwrap(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::testmodels::oscillator;
    use super::*;
    use crate::model::linear::ou_1d;
    use crate::model::ObsMask;

    #[test]
    fn scalar_update_is_the_conjugate_posterior() {
        // Prior N(1, 4), y = 2 with σ = 1: posterior precision 1/4 + 1,
        // mean (1/4 + 2)/(5/4) = 1.8, variance 0.8.
        let prior = Gaussian::diagonal(&[1.0], &[2.0]);
        let mut kf = Kalman::new(ou_1d(1.0, 0.5, 1.0, 10.0), &prior, 0.0).unwrap();
        let info = kf.update(&Measurement::full(&[2.0])).unwrap();
        let b = kf.belief();
        assert!((b.mean[0] - 1.8).abs() < 1e-12);
        assert!((b.cov[0] - 0.8).abs() < 1e-12);
        // Evidence: y ~ N(1, 4 + 1).
        let want = -0.5 * 1.0 / 5.0 - 0.5 * (2.0 * std::f64::consts::PI * 5.0).ln();
        assert!((info.log_evidence - want).abs() < 1e-12);
    }

    #[test]
    fn scalar_prediction_is_the_ou_transition() {
        let (a, s) = (1.5, 0.4);
        let prior = Gaussian::diagonal(&[2.0], &[0.3]);
        let mut kf = Kalman::new(ou_1d(a, s, 1.0, 10.0), &prior, 1.0).unwrap();
        kf.predict(1.7, &[]).unwrap();
        let e = (-a * 0.7f64).exp();
        let b = kf.belief();
        assert!((b.mean[0] - 2.0 * e).abs() < 1e-12);
        let var = 0.09 * e * e + s * s * (1.0 - e * e) / (2.0 * a);
        assert!((b.cov[0] - var).abs() < 1e-12);
        assert_eq!(kf.time(), 1.7);
    }

    #[test]
    fn prediction_is_a_semigroup_and_control_enters() {
        let prior = Gaussian::diagonal(&[1.0, -0.5], &[0.4, 0.2]);
        let mut one = Kalman::new(oscillator([0.1, 0.2]), &prior, 0.0).unwrap();
        let mut two = one.clone();
        let mut three = one.clone();
        one.predict(0.3, &[0.7]).unwrap();
        two.predict(0.1, &[0.7]).unwrap();
        two.predict(0.3, &[0.7]).unwrap();
        three.predict(0.3, &[0.0]).unwrap();
        let (b1, b2, b3) = (one.belief(), two.belief(), three.belief());
        for i in 0..4 {
            assert!((b1.cov[i] - b2.cov[i]).abs() < 1e-12);
        }
        for i in 0..2 {
            assert!((b1.mean[i] - b2.mean[i]).abs() < 1e-12);
        }
        assert!(
            (b1.mean[1] - b3.mean[1]).abs() > 0.1,
            "control has no effect"
        );
    }

    #[test]
    fn sequential_masked_updates_equal_the_joint_update() {
        // With diagonal R, updating on component 0 then component 1 is the
        // same as updating on both at once.
        let prior = Gaussian::diagonal(&[1.0, -0.5], &[0.4, 0.2]);
        let mut joint = Kalman::new(oscillator([0.1, 0.2]), &prior, 0.0).unwrap();
        let mut seq = joint.clone();
        let y = [0.8, -0.1];
        let ij = joint.update(&Measurement::full(&y)).unwrap();
        let mut ev = 0.0;
        for i in 0..2 {
            let info = seq
                .update(&Measurement {
                    y: &y,
                    mask: ObsMask(1 << i),
                    std: None,
                })
                .unwrap();
            ev += info.log_evidence;
        }
        let (a, b) = (joint.belief(), seq.belief());
        for i in 0..4 {
            assert!((a.cov[i] - b.cov[i]).abs() < 1e-12);
        }
        for i in 0..2 {
            assert!((a.mean[i] - b.mean[i]).abs() < 1e-12);
        }
        assert!((ij.log_evidence - ev).abs() < 1e-10);
    }

    #[test]
    fn std_override_and_empty_mask() {
        let prior = Gaussian::diagonal(&[1.0], &[2.0]);
        let mut kf = Kalman::new(ou_1d(1.0, 0.5, 5.0, 10.0), &prior, 0.0).unwrap();
        let before = kf.belief();
        let info = kf
            .update(&Measurement {
                y: &[3.0],
                mask: ObsMask(0),
                std: None,
            })
            .unwrap();
        assert_eq!(kf.belief(), before);
        assert_eq!(info.log_evidence, 0.0);
        kf.update(&Measurement {
            y: &[2.0],
            mask: ObsMask::all(1),
            std: Some(&[1.0]),
        })
        .unwrap();
        assert!((kf.belief().mean[0] - 1.8).abs() < 1e-12);
    }

    #[test]
    fn bad_inputs_are_typed_errors_and_keep_the_belief() {
        let prior = Gaussian::diagonal(&[1.0, -0.5], &[0.4, 0.2]);
        let mut kf = Kalman::new(oscillator([0.1, 0.2]), &prior, 1.0).unwrap();
        assert!(matches!(
            kf.predict(0.5, &[0.0]),
            Err(FilterError::TimeBackwards { .. })
        ));
        assert!(matches!(
            kf.predict(2.0, &[]),
            Err(FilterError::Dimension { .. })
        ));
        assert!(matches!(
            kf.update(&Measurement::full(&[f64::NAN, 0.0])),
            Err(FilterError::NonFinite(_))
        ));
        assert_eq!(kf.belief(), prior);
        assert!(Kalman::new(oscillator([0.1, 0.2]), &Gaussian::zeros(3), 0.0).is_err());
        let mut bad = prior;
        bad.set_cov(0, 0, -1.0);
        assert!(Kalman::new(oscillator([0.1, 0.2]), &bad, 0.0).is_err());
        kf.reset(0.0, &bad);
        assert_eq!(kf.belief(), prior);
    }
}
