//! A torque-controlled damped pendulum, written as a user would: the model
//! (drift, diffusion, sensor, bounds), its Jacobians, its control-affine
//! view for the implicit path-integral controller, and the scenario that
//! registers it with beliefbus.
//!
//! ```text
//! dθ = ω dt
//! dω = (−(g/l) sin θ − c ω + u/(m l²)) dt + σ dW      c = b/(m l²)
//! y  = θ + v,  v ~ N(0, σ_y²)                          (an encoder)
//! ```
//! The noise is a random torque: it enters through the angular velocity
//! only, like the control (paper 003 eq. 7 with G = [0; 1/(m l²)],
//! Q = σ m l², so condition (8) holds with γ = σ² (m l²)² R).

use beliefbus::model::affine::{ControlAffine, PathStructure};
use beliefbus::model::{Bounds, Dims, SdeJacobians, SdeModel};
use beliefbus::scenario::{
    BuildContext, DynAffine, DynModel, Dynamics, Scenario, SensorChannel, System,
};
use serde::{Deserialize, Serialize};

/// `[pendulum]`: the physical parameters (every key optional).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PendulumParams {
    /// Gravity g (m/s²).
    pub gravity: f64,
    /// Length l (m).
    pub length: f64,
    /// Bob mass m (kg).
    pub mass: f64,
    /// Viscous damping b (N·m·s).
    pub damping: f64,
    /// σ of the random torque per √s, as angular acceleration (rad/s²/√Hz).
    pub torque_noise: f64,
    /// σ of one encoder reading (rad).
    pub encoder_std: f64,
}

impl Default for PendulumParams {
    fn default() -> Self {
        Self {
            gravity: 9.81,
            length: 1.0,
            mass: 1.0,
            damping: 0.5,
            torque_noise: 0.5,
            encoder_std: 0.05,
        }
    }
}

/// The model.
#[derive(Clone, Debug)]
pub struct Pendulum {
    p: PendulumParams,
    /// g/l, c = b/(m l²), 1/(m l²).
    g_l: f64,
    c: f64,
    inv_inertia: f64,
    bounds: Bounds,
}

impl Pendulum {
    pub fn new(p: PendulumParams) -> Result<Self, String> {
        for (k, v) in [
            ("gravity", p.gravity),
            ("length", p.length),
            ("mass", p.mass),
            ("torque_noise", p.torque_noise),
            ("encoder_std", p.encoder_std),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("pendulum.{k} must be positive and finite, got {v}"));
            }
        }
        if !(p.damping.is_finite() && p.damping >= 0.0) {
            return Err(format!("pendulum.damping must be >= 0, got {}", p.damping));
        }
        let inertia = p.mass * p.length * p.length;
        // θ within a little more than a turn either way; ω bounded by the
        // speed a fall from upright reaches, with margin.
        let w_max = 3.0 * (p.gravity / p.length).sqrt() + 5.0;
        let bounds = Bounds::new_box(&[-7.0, -w_max], &[7.0, w_max]).map_err(|e| e.to_string())?;
        Ok(Self {
            g_l: p.gravity / p.length,
            c: p.damping / inertia,
            inv_inertia: 1.0 / inertia,
            p,
            bounds,
        })
    }
}

impl SdeModel for Pendulum {
    fn name(&self) -> &str {
        "pendulum"
    }
    fn dims(&self) -> Dims {
        Dims {
            state: 2,
            noise: 1,
            obs: 1,
            control: 1,
        }
    }
    fn drift(&self, x: &[f64], u: &[f64], f: &mut [f64]) {
        f[0] = x[1];
        f[1] = -self.g_l * x[0].sin() - self.c * x[1] + self.inv_inertia * u[0];
    }
    fn diffusion(&self, _x: &[f64], big_f: &mut [f64]) {
        big_f[0] = 0.0;
        big_f[1] = self.p.torque_noise;
    }
    fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
        g[0] = x[0];
    }
    fn obs_std(&self, std: &mut [f64]) {
        std[0] = self.p.encoder_std;
    }
    fn bounds(&self) -> &Bounds {
        &self.bounds
    }
}

impl SdeJacobians for Pendulum {
    fn drift_jacobian(&self, x: &[f64], _u: &[f64], jac: &mut [f64]) {
        jac[0] = 0.0; // ∂f1/∂θ
        jac[1] = -self.g_l * x[0].cos(); // ∂f2/∂θ
        jac[2] = 1.0; // ∂f1/∂ω
        jac[3] = -self.c; // ∂f2/∂ω
    }
    fn obs_jacobian(&self, _x: &[f64], jac: &mut [f64]) {
        jac[0] = 1.0;
        jac[1] = 0.0;
    }
}

impl ControlAffine for Pendulum {
    fn state_dim(&self) -> usize {
        2
    }
    fn control_dim(&self) -> usize {
        1
    }
    fn noise_dim(&self) -> usize {
        1
    }
    fn structure(&self) -> PathStructure {
        PathStructure::SecondOrder
    }
    fn drift0(&self, x: &[f64], f: &mut [f64]) {
        f[0] = x[1];
        f[1] = -self.g_l * x[0].sin() - self.c * x[1];
    }
    fn drift0_jacobian(&self, x: &[f64], jac: &mut [f64]) {
        self.drift_jacobian(x, &[0.0], jac);
    }
    /// Σ_k w_k ∇²f0_k: only f0₂ is curved, ∂²f0₂/∂θ² = (g/l) sin θ.
    fn drift0_curvature(&self, x: &[f64], w: &[f64], out: &mut [f64]) {
        out[..4].fill(0.0);
        out[0] = w[1] * self.g_l * x[0].sin();
    }
    fn input_matrix(&self, g: &mut [f64]) {
        g[0] = 0.0;
        g[1] = self.inv_inertia;
    }
    fn noise_matrix(&self, q: &mut [f64]) {
        q[0] = self.p.torque_noise / self.inv_inertia;
    }
}

/// The scenario: registered as `pendulum`, parameters in `[pendulum]`.
pub struct PendulumScenario;

struct PendulumSystem {
    model: DynModel,
    affine: DynAffine,
}

impl Scenario for PendulumScenario {
    type Params = PendulumParams;
    const NAME: &'static str = "pendulum";
    const SUMMARY: &'static str =
        "torque-controlled damped pendulum, encoder on the angle, noise on the velocity only";
    const CONFIG: &'static str = include_str!("pendulum.toml");
    fn defaults(_ctx: &BuildContext) -> PendulumParams {
        PendulumParams::default()
    }
    fn build(p: PendulumParams, _ctx: &BuildContext) -> Result<Box<dyn System>, String> {
        let m = Pendulum::new(p)?;
        Ok(Box::new(PendulumSystem {
            model: DynModel::new(m.clone()),
            affine: DynAffine::new(m),
        }))
    }
}

impl System for PendulumSystem {
    fn dynamics(&self) -> Dynamics {
        Dynamics::Sde(self.model.clone())
    }
    fn control_affine(&self) -> Option<DynAffine> {
        Some(self.affine.clone())
    }
    /// The angle is what the report scores and the set-points set.
    fn position_axes(&self) -> &[usize] {
        &[0]
    }
    /// The encoder reads the angle itself.
    fn raw_position(&self, y: &[f64], out: &mut [f64]) -> bool {
        out[0] = y[0];
        true
    }
    fn initial_state(&self) -> Vec<f64> {
        vec![0.3, 0.0]
    }
    fn prior(&self) -> (Vec<f64>, Vec<f64>) {
        (vec![0.0, 0.0], vec![0.5, 1.0])
    }
    fn sensor_channels(&self) -> Vec<SensorChannel> {
        vec![SensorChannel {
            id: 0,
            name: "encoder",
            components: vec![0],
        }]
    }
}
