//! Type-erased handles on a scenario's model, so that one pipeline binary
//! runs any registered system: [`DynModel`] (the SDE model every filter and
//! MPPI is generic over) and [`DynAffine`] (the control-affine view the
//! implicit path-integral controller needs).
//!
//! A wrapper that forwards a trait must forward **every** method a model may
//! override: a forgotten provided method (`drift_soa`, the Jacobians)
//! silently falls back to the trait's default and loses the model's fast or
//! exact version. The tests below count calls through the handles.

use crate::model::affine::{ControlAffine, PathStructure};
use crate::model::{Bounds, Dims, SdeJacobians, SdeModel};
use std::sync::Arc;

/// Everything a pipeline model provides: the SDE and its Jacobians (the
/// Jacobians' finite-difference defaults serve models without closed forms).
pub trait PipelineModel: SdeJacobians {}
impl<T: SdeJacobians> PipelineModel for T {}

/// A shared, type-erased pipeline model. Cloning shares the model.
#[derive(Clone)]
pub struct DynModel(Arc<dyn PipelineModel>);

impl DynModel {
    /// Wrap `model`.
    pub fn new(model: impl PipelineModel + 'static) -> Self {
        Self(Arc::new(model))
    }
}

impl std::fmt::Debug for DynModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "DynModel({})", self.0.name())
    }
}

impl SdeModel for DynModel {
    fn name(&self) -> &str {
        self.0.name()
    }
    fn dims(&self) -> Dims {
        self.0.dims()
    }
    fn drift(&self, x: &[f64], u: &[f64], f: &mut [f64]) {
        self.0.drift(x, u, f)
    }
    fn drift_soa(&self, n: usize, x: &[f64], u: &[f64], f: &mut [f64]) {
        self.0.drift_soa(n, x, u, f)
    }
    fn diffusion(&self, x: &[f64], big_f: &mut [f64]) {
        self.0.diffusion(x, big_f)
    }
    fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
        self.0.obs_mean(x, g)
    }
    fn obs_std(&self, std: &mut [f64]) {
        self.0.obs_std(std)
    }
    fn obs_residual(&self, y: &[f64], yhat: &[f64], r: &mut [f64]) {
        self.0.obs_residual(y, yhat, r)
    }
    fn bounds(&self) -> &Bounds {
        self.0.bounds()
    }
}

impl SdeJacobians for DynModel {
    fn drift_jacobian(&self, x: &[f64], u: &[f64], jac: &mut [f64]) {
        self.0.drift_jacobian(x, u, jac)
    }
    fn obs_jacobian(&self, x: &[f64], jac: &mut [f64]) {
        self.0.obs_jacobian(x, jac)
    }
}

/// A shared, type-erased control-affine model (paper 003 eq. 7).
#[derive(Clone)]
pub struct DynAffine(Arc<dyn ControlAffine>);

impl DynAffine {
    /// Wrap `model`.
    pub fn new(model: impl ControlAffine + 'static) -> Self {
        Self(Arc::new(model))
    }
}

impl ControlAffine for DynAffine {
    fn state_dim(&self) -> usize {
        self.0.state_dim()
    }
    fn control_dim(&self) -> usize {
        self.0.control_dim()
    }
    fn noise_dim(&self) -> usize {
        self.0.noise_dim()
    }
    fn structure(&self) -> PathStructure {
        self.0.structure()
    }
    fn drift0(&self, x: &[f64], f: &mut [f64]) {
        self.0.drift0(x, f)
    }
    fn drift0_jacobian(&self, x: &[f64], jac: &mut [f64]) {
        self.0.drift0_jacobian(x, jac)
    }
    fn drift0_curvature(&self, x: &[f64], w: &[f64], out: &mut [f64]) {
        self.0.drift0_curvature(x, w, out)
    }
    fn input_matrix(&self, g: &mut [f64]) {
        self.0.input_matrix(g)
    }
    fn noise_matrix(&self, q: &mut [f64]) {
        self.0.noise_matrix(q)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::forwarding_check::{assert_forwarded, call_each, Counting, DRIFT, DRIFT_SOA};

    #[test]
    fn dyn_model_forwards_every_override() {
        let m = Counting::new();
        let calls = m.calls.clone();
        call_each(&DynModel::new(m));
        assert_forwarded(&calls);
    }

    /// The check itself: a wrapper that forwards only the required methods
    /// (as the old scenario enum did) is caught.
    #[test]
    fn a_wrapper_that_drops_drift_soa_is_caught() {
        struct Partial(Counting);
        impl SdeModel for Partial {
            fn name(&self) -> &str {
                self.0.name()
            }
            fn dims(&self) -> Dims {
                self.0.dims()
            }
            fn drift(&self, x: &[f64], u: &[f64], f: &mut [f64]) {
                self.0.drift(x, u, f)
            }
            fn diffusion(&self, x: &[f64], big_f: &mut [f64]) {
                self.0.diffusion(x, big_f)
            }
            fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
                self.0.obs_mean(x, g)
            }
            fn obs_std(&self, std: &mut [f64]) {
                self.0.obs_std(std)
            }
            fn obs_residual(&self, y: &[f64], yhat: &[f64], r: &mut [f64]) {
                self.0.obs_residual(y, yhat, r)
            }
            fn bounds(&self) -> &Bounds {
                self.0.bounds()
            }
        }
        impl SdeJacobians for Partial {
            fn drift_jacobian(&self, x: &[f64], u: &[f64], jac: &mut [f64]) {
                self.0.drift_jacobian(x, u, jac)
            }
            fn obs_jacobian(&self, x: &[f64], jac: &mut [f64]) {
                self.0.obs_jacobian(x, jac)
            }
        }
        let m = Counting::new();
        let calls = m.calls.clone();
        call_each(&Partial(m));
        let caught = std::panic::catch_unwind(|| assert_forwarded(&calls));
        assert!(caught.is_err());
        assert_eq!(calls.get(DRIFT_SOA), 0);
        assert_eq!(calls.get(DRIFT), 4);
    }

    #[test]
    fn dyn_affine_forwards_to_the_model() {
        use crate::model::ship::{Ship, ShipParams};
        let ship = Ship::new(ShipParams::paper(0.01)).unwrap();
        let h = DynAffine::new(ship.clone());
        let x = [9.5, 0.5, 1.0, 0.2];
        let (mut a, mut b) = ([0.0; 4], [0.0; 4]);
        ship.drift0(&x, &mut a);
        h.drift0(&x, &mut b);
        assert_eq!(a, b);
        let (mut ja, mut jb) = ([0.0; 16], [0.0; 16]);
        ship.drift0_jacobian(&x, &mut ja);
        h.drift0_jacobian(&x, &mut jb);
        assert_eq!(ja, jb);
        let (mut ca, mut cb) = ([0.0; 16], [0.0; 16]);
        ship.drift0_curvature(&x, &[1.0, -2.0, 0.5, 3.0], &mut ca);
        h.drift0_curvature(&x, &[1.0, -2.0, 0.5, 3.0], &mut cb);
        assert_eq!(ca, cb);
        assert_eq!(h.structure(), PathStructure::SecondOrder);
        assert_eq!((h.state_dim(), h.control_dim(), h.noise_dim()), (4, 2, 2));
    }
}
