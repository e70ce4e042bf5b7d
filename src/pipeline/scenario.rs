//! The scenarios a pipeline can run, as one concrete model type (the
//! filters and controllers are generic over their model, so the stages need
//! a single type that is any of the scenarios), and what "position" means in
//! each for the accuracy report.

use crate::model::ship::{Ship, ShipParams};
use crate::model::vanderpol::{VanDerPol, VanDerPolParams};
use crate::model::{Bounds, Dims, SdeJacobians, SdeModel};
use serde::{Deserialize, Serialize};

/// Which scenario a config runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Scenario {
    /// The drifting ship of paper 001 eq. (10)–(11) with a control force.
    Ship,
    /// The Van der Pol oscillator of paper 001 eq. (12), uncontrolled.
    Vanderpol,
}

impl Scenario {
    /// Lower-case name, as in the config and the report.
    pub fn name(self) -> &'static str {
        match self {
            Scenario::Ship => "ship",
            Scenario::Vanderpol => "vanderpol",
        }
    }
}

/// Any scenario's model.
#[derive(Clone, Debug)]
pub enum AnyModel {
    Ship(Ship),
    VanDerPol(VanDerPol),
}

impl AnyModel {
    /// Build the model of `scenario` from its parameters.
    pub fn build(
        scenario: Scenario,
        ship: &ShipParams,
        vdp: &VanDerPolParams,
    ) -> Result<Self, String> {
        match scenario {
            Scenario::Ship => Ship::new(ship.clone()).map(AnyModel::Ship),
            Scenario::Vanderpol => VanDerPol::new(vdp.clone()).map(AnyModel::VanDerPol),
        }
    }

    /// State components that make up the "position" of the accuracy report
    /// (ship: x1, x2; Van der Pol: x1).
    pub fn position_axes(&self) -> &'static [usize] {
        match self {
            AnyModel::Ship(_) => &[0, 1],
            AnyModel::VanDerPol(_) => &[0],
        }
    }

    /// The position obtained by inverting one raw measurement — the
    /// no-filter reference (`rmse_position_raw`). Ship: (r cos b, r sin b);
    /// Van der Pol: y = x1. Writes `position_axes().len()` values.
    pub fn raw_position(&self, y: &[f64], out: &mut [f64]) {
        match self {
            AnyModel::Ship(_) => {
                out[0] = y[0] * y[1].cos();
                out[1] = y[0] * y[1].sin();
            }
            AnyModel::VanDerPol(_) => out[0] = y[0],
        }
    }
}

macro_rules! delegate {
    ($self:ident, $m:ident => $e:expr) => {
        match $self {
            AnyModel::Ship($m) => $e,
            AnyModel::VanDerPol($m) => $e,
        }
    };
}

impl SdeModel for AnyModel {
    fn name(&self) -> &str {
        delegate!(self, m => m.name())
    }
    fn dims(&self) -> Dims {
        delegate!(self, m => m.dims())
    }
    fn drift(&self, x: &[f64], u: &[f64], f: &mut [f64]) {
        delegate!(self, m => m.drift(x, u, f))
    }
    fn diffusion(&self, x: &[f64], big_f: &mut [f64]) {
        delegate!(self, m => m.diffusion(x, big_f))
    }
    fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
        delegate!(self, m => m.obs_mean(x, g))
    }
    fn obs_std(&self, std: &mut [f64]) {
        delegate!(self, m => m.obs_std(std))
    }
    fn obs_residual(&self, y: &[f64], yhat: &[f64], r: &mut [f64]) {
        delegate!(self, m => m.obs_residual(y, yhat, r))
    }
    fn bounds(&self) -> &Bounds {
        delegate!(self, m => m.bounds())
    }
}

impl SdeJacobians for AnyModel {
    fn drift_jacobian(&self, x: &[f64], u: &[f64], jac: &mut [f64]) {
        delegate!(self, m => m.drift_jacobian(x, u, jac))
    }
    fn obs_jacobian(&self, x: &[f64], jac: &mut [f64]) {
        delegate!(self, m => m.obs_jacobian(x, jac))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn raw_ship_position_inverts_range_and_bearing() {
        let m = AnyModel::build(
            Scenario::Ship,
            &ShipParams::paper(0.01),
            &VanDerPolParams::default(),
        )
        .unwrap();
        let x = [-3.0, 4.0, 0.0, 0.0];
        let mut y = [0.0; 2];
        m.obs_mean(&x, &mut y);
        let mut p = [0.0; 2];
        m.raw_position(&y, &mut p);
        assert!((p[0] + 3.0).abs() < 1e-12 && (p[1] - 4.0).abs() < 1e-12);
        assert_eq!(m.position_axes(), &[0, 1]);
    }

    #[test]
    fn delegates_to_the_scenario_model() {
        let m = AnyModel::build(
            Scenario::Vanderpol,
            &ShipParams::paper(0.01),
            &VanDerPolParams::default(),
        )
        .unwrap();
        assert_eq!(m.dims().state, 2);
        assert_eq!(m.name(), "vanderpol");
        let mut f = [0.0; 2];
        m.drift(&[1.0, 1.0], &[], &mut f);
        assert_eq!(f, [1.0, -1.0]); // x2, −x1 + μ(1 − x1²)x2 with x1 = 1
    }
}
