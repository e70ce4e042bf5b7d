//! The scenarios that ship with beliefbus, registered through the same
//! [`Scenario`] API a user's crate uses.

use super::{BuildContext, DynAffine, DynModel, Dynamics, Scenario, SensorChannel, System};
use crate::model::ship::{Ship, ShipParams};
use crate::model::vanderpol::{VanDerPol, VanDerPolParams};

pub mod arx;
pub use arx::ArxScenario;
pub mod carpark;
pub use carpark::CarparkScenario;
pub mod inventory;
pub use inventory::InventoryScenario;
pub mod live_slam;
pub mod victoria_park;
pub use victoria_park::VictoriaParkScenario;
pub mod light_dark;
pub use light_dark::LightDarkScenario;

/// The drifting ship of paper 001 eq. (10)–(11) with a control force,
/// range–bearing sensor, waypoint route.
pub struct ShipScenario;

struct ShipSystem {
    model: DynModel,
    affine: DynAffine,
}

impl Scenario for ShipScenario {
    type Params = ShipParams;
    const NAME: &'static str = "ship";
    const SUMMARY: &'static str =
        "drifting ship in a walled disc (paper 001 eq. 10-11), range-bearing sensor, force control";
    const CONFIG: &'static str = include_str!("../../../configs/default.toml");
    fn defaults(ctx: &BuildContext) -> ShipParams {
        ShipParams::paper(ctx.sample_dt)
    }
    fn params_schema() -> Option<schemars::Schema> {
        Some(schemars::schema_for!(ShipParams))
    }
    fn build(p: ShipParams, _ctx: &BuildContext) -> Result<Box<dyn System>, String> {
        let ship = Ship::new(p)?;
        Ok(Box::new(ShipSystem {
            model: DynModel::new(ship.clone()),
            affine: DynAffine::new(ship),
        }))
    }
}

impl System for ShipSystem {
    fn dynamics(&self) -> Dynamics {
        Dynamics::Sde(self.model.clone())
    }
    fn control_affine(&self) -> Option<DynAffine> {
        Some(self.affine.clone())
    }
    fn position_axes(&self) -> &[usize] {
        &[0, 1]
    }
    /// (r cos b, r sin b).
    fn raw_position(&self, y: &[f64], out: &mut [f64]) -> bool {
        out[0] = y[0] * y[1].cos();
        out[1] = y[0] * y[1].sin();
        true
    }
    fn initial_state(&self) -> Vec<f64> {
        vec![3.0, 0.0, 0.0, 0.0]
    }
    fn prior(&self) -> (Vec<f64>, Vec<f64>) {
        (vec![3.0, 0.0, 0.0, 0.0], vec![0.5, 0.5, 0.3, 0.3])
    }
    fn sensor_channels(&self) -> Vec<SensorChannel> {
        vec![SensorChannel {
            id: 0,
            name: "range_bearing",
            components: vec![0, 1],
        }]
    }
}

/// The Van der Pol oscillator of paper 001 eq. (12), uncontrolled, x1
/// observed.
pub struct VanDerPolScenario;

struct VanDerPolSystem {
    model: DynModel,
}

impl Scenario for VanDerPolScenario {
    type Params = VanDerPolParams;
    const NAME: &'static str = "vanderpol";
    const SUMMARY: &'static str =
        "Van der Pol oscillator (paper 001 eq. 12), x1 observed, estimation only";
    const CONFIG: &'static str = include_str!("../../../configs/vanderpol.toml");
    fn defaults(_ctx: &BuildContext) -> VanDerPolParams {
        VanDerPolParams::default()
    }
    fn params_schema() -> Option<schemars::Schema> {
        Some(schemars::schema_for!(VanDerPolParams))
    }
    fn build(p: VanDerPolParams, _ctx: &BuildContext) -> Result<Box<dyn System>, String> {
        Ok(Box::new(VanDerPolSystem {
            model: DynModel::new(VanDerPol::new(p)?),
        }))
    }
}

impl System for VanDerPolSystem {
    fn dynamics(&self) -> Dynamics {
        Dynamics::Sde(self.model.clone())
    }
    fn position_axes(&self) -> &[usize] {
        &[0]
    }
    /// y = x1.
    fn raw_position(&self, y: &[f64], out: &mut [f64]) -> bool {
        out[0] = y[0];
        true
    }
    fn initial_state(&self) -> Vec<f64> {
        vec![2.0, 0.0]
    }
    fn prior(&self) -> (Vec<f64>, Vec<f64>) {
        (vec![2.0, 0.0], vec![0.3, 0.5])
    }
    fn sensor_channels(&self) -> Vec<SensorChannel> {
        vec![SensorChannel {
            id: 0,
            name: "x1",
            components: vec![0],
        }]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::SdeModel;
    use crate::Registry;

    fn build(name: &str) -> std::sync::Arc<dyn System> {
        Registry::builtin()
            .get(name)
            .unwrap()
            .build(None, &BuildContext { sample_dt: 0.01 })
            .unwrap()
    }

    #[test]
    fn raw_ship_position_inverts_range_and_bearing() {
        let s = build("ship");
        let x = [-3.0, 4.0, 0.0, 0.0];
        let mut y = [0.0; 2];
        s.sde_model().unwrap().obs_mean(&x, &mut y);
        let mut p = [0.0; 2];
        assert!(s.raw_position(&y, &mut p));
        assert!((p[0] + 3.0).abs() < 1e-12 && (p[1] - 4.0).abs() < 1e-12);
        assert_eq!(s.position_axes(), &[0, 1]);
    }

    #[test]
    fn vanderpol_builds_its_model() {
        let s = build("vanderpol");
        let m = s.sde_model().unwrap();
        assert_eq!(m.dims().state, 2);
        assert_eq!(m.name(), "vanderpol");
        let mut f = [0.0; 2];
        m.drift(&[1.0, 1.0], &[], &mut f);
        assert_eq!(f, [1.0, -1.0]); // x2, −x1 + μ(1 − x1²)x2 with x1 = 1
        assert!(s.control_affine().is_none());
    }

    #[test]
    fn the_ship_defaults_are_the_papers_at_the_sensor_rate() {
        let r = Registry::builtin();
        let e = r.get("ship").unwrap();
        let mut t = toml::Table::new();
        for (k, v) in [("e", 0.3), ("range_std", 0.3), ("bearing_std", 0.3)] {
            t.insert(k.into(), v.into());
        }
        for (k, v) in [("radius", 9.0), ("wall_gain", 50.0), ("v_max", 4.0)] {
            t.insert(k.into(), v.into());
        }
        let ctx = BuildContext { sample_dt: 0.01 };
        assert_eq!(
            ShipScenario::defaults(&ctx),
            ShipParams::paper(0.01),
            "defaults"
        );
        assert!(e.build(Some(&t), &ctx).is_ok());
        // A partial section keeps the other defaults.
        let mut partial = toml::Table::new();
        partial.insert("e".into(), 0.5.into());
        let sys = e.build(Some(&partial), &ctx).unwrap();
        let mut f = [0.0; 16];
        sys.sde_model()
            .unwrap()
            .diffusion(&[1.0, 1.0, 0.0, 0.0], &mut f);
        assert_eq!(f.iter().fold(0.0f64, |m, v| m.max(v.abs())), 0.5);
        let mut std = [0.0; 2];
        sys.sde_model().unwrap().obs_std(&mut std);
        assert_eq!(std[0], ShipParams::paper(0.01).range_std);
        t.insert("ee".into(), 1.0.into());
        let err = e.build(Some(&t), &ctx).err().unwrap();
        assert!(err.problem.contains("unknown field"), "{err:?}");
        t.remove("ee");
        t.insert("e".into(), "x".into());
        let err = e.build(Some(&t), &ctx).err().unwrap();
        assert_eq!(err.key, "e");
    }

    #[test]
    fn capabilities_are_listed() {
        let info = Registry::builtin().describe();
        let ship = info[0].as_ref().unwrap();
        assert_eq!((ship.name, ship.state, ship.control), ("ship", 4, 2));
        assert_eq!(ship.filters, ["chain", "pf", "ekf", "ukf", "projection-pf"]);
        assert_eq!(ship.controllers, ["implicit", "mppi", "none"]);
        let vdp = info[1].as_ref().unwrap();
        assert_eq!(vdp.controllers, ["none"]);
        // A discrete-time scenario offers only its own backends.
        let arx = info[2].as_ref().unwrap();
        assert_eq!(
            (arx.name, arx.state, arx.control, arx.obs),
            ("arx", 6, 1, 2)
        );
        assert_eq!(arx.filters, ["rbpf-changepoint"]);
        assert_eq!(arx.controllers, ["arx-adaptive", "none"]);
    }
}
