//! A check that a wrapper of a model forwards every method a model may
//! override: a forgotten provided method (`drift_soa`, the Jacobians)
//! silently falls back to the trait's default and loses the model's fast or
//! exact version. [`Counting`] overrides each provided method with a
//! counting version; wrap it, run [`call_each`] through the wrapper, and
//! [`assert_forwarded`] fails unless each override was reached once.
//!
//! Test support for the wrappers in this crate and the crates above it
//! (compiled for tests and with the `test-support` feature).

use crate::model::{Bounds, Dims, SdeJacobians, SdeModel};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

/// Calls of each overridable method, by index.
#[derive(Default, Debug)]
pub struct Calls(pub [AtomicUsize; 8]);

impl Calls {
    pub fn get(&self, i: usize) -> usize {
        self.0[i].load(Ordering::Relaxed)
    }
    fn hit(&self, i: usize) {
        self.0[i].fetch_add(1, Ordering::Relaxed);
    }
}

/// Method indices of [`Calls`].
pub const DRIFT: usize = 0;
pub const DRIFT_SOA: usize = 1;
pub const RESIDUAL: usize = 2;
pub const DRIFT_JAC: usize = 3;
pub const OBS_JAC: usize = 4;

/// dx = −x dt + dw observed directly, overriding every provided
/// method with a counting version (results equal the defaults').
#[derive(Debug)]
pub struct Counting {
    pub calls: Arc<Calls>,
    bounds: Bounds,
}

impl Counting {
    pub fn new() -> Self {
        Self {
            calls: Arc::default(),
            bounds: Bounds::new_box(&[-5.0], &[5.0]).unwrap(),
        }
    }
}

impl Default for Counting {
    fn default() -> Self {
        Self::new()
    }
}

impl SdeModel for Counting {
    fn name(&self) -> &str {
        "counting"
    }
    fn dims(&self) -> Dims {
        Dims {
            state: 1,
            noise: 1,
            obs: 1,
            control: 0,
        }
    }
    fn drift(&self, x: &[f64], _u: &[f64], f: &mut [f64]) {
        self.calls.hit(DRIFT);
        f[0] = -x[0];
    }
    fn drift_soa(&self, n: usize, x: &[f64], _u: &[f64], f: &mut [f64]) {
        self.calls.hit(DRIFT_SOA);
        for k in 0..n {
            f[k] = -x[k];
        }
    }
    fn diffusion(&self, _x: &[f64], big_f: &mut [f64]) {
        big_f[0] = 1.0;
    }
    fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
        g[0] = x[0];
    }
    fn obs_std(&self, std: &mut [f64]) {
        std[0] = 0.1;
    }
    fn obs_residual(&self, y: &[f64], yhat: &[f64], r: &mut [f64]) {
        self.calls.hit(RESIDUAL);
        r[0] = y[0] - yhat[0];
    }
    fn bounds(&self) -> &Bounds {
        &self.bounds
    }
}

impl SdeJacobians for Counting {
    fn drift_jacobian(&self, _x: &[f64], _u: &[f64], jac: &mut [f64]) {
        self.calls.hit(DRIFT_JAC);
        jac[0] = -1.0;
    }
    fn obs_jacobian(&self, _x: &[f64], jac: &mut [f64]) {
        self.calls.hit(OBS_JAC);
        jac[0] = 1.0;
    }
}

/// Call every overridable method of `m` once (a wrapper of a
/// [`Counting`] model must reach each override exactly once).
pub fn call_each(m: &impl SdeJacobians) {
    let mut f = [0.0; 4];
    m.drift_soa(4, &[1.0, 2.0, 3.0, 4.0], &[], &mut f);
    assert_eq!(f, [-1.0, -2.0, -3.0, -4.0]);
    let mut r = [0.0];
    m.obs_residual(&[1.0], &[0.5], &mut r);
    m.drift_jacobian(&[1.0], &[], &mut r);
    assert_eq!(r, [-1.0]);
    m.obs_jacobian(&[1.0], &mut r);
    assert_eq!(r, [1.0]);
}

/// Every override reached once, and drift never (drift_soa and the
/// Jacobians must not fall back to the defaults, which call drift).
pub fn assert_forwarded(c: &Calls) {
    assert_eq!(c.get(DRIFT_SOA), 1, "drift_soa not forwarded");
    assert_eq!(c.get(RESIDUAL), 1, "obs_residual not forwarded");
    assert_eq!(c.get(DRIFT_JAC), 1, "drift_jacobian not forwarded");
    assert_eq!(c.get(OBS_JAC), 1, "obs_jacobian not forwarded");
    assert_eq!(c.get(DRIFT), 0, "a default implementation ran");
}
