//! The 1-D light-dark problem (thesis 000 §4.7.2, Fig. 4-6) as a chain
//! POMDP:
//!
//! ```text
//! dx = u dt + σ dw on [−2, 2],   y = x + G(x) v,   G(x) = ε if |x − b| < e_b, 1/ε otherwise
//! reward −|u|² per second; the terminal action ends the episode with
//! +R if |x − g| < e_g, −R otherwise;   γ = exp(−ρ h)
//! ```
//!
//! Built exactly as the `pomdp-light-dark` experiment builds its 1-D row:
//! n regular states (cell centres of [−2, 2]; n = 20: −1.9, −1.7, …, 1.9),
//! the Gaussian-kernel chain with Near radius 2 (ln n / n) (the grid
//! neighbours), controls {0, −1, 1} and uniform draws on [−1, 1] up to
//! ⌊5 ln n⌋ (seeded), the observation points the states, b₀ uniform, the
//! decision period the chain's step δ = min_{z,u} Δt(z,u).
//!
//! [`model_key`] fingerprints everything a policy's α-vectors depend on
//! (γ, b₀, every T, O and R entry, the states, the controls) and what the
//! live filter adds (the light, ε): a policy solved for another problem
//! is stale.

use super::LightDarkParams;
use crate::model::{Bounds, Dims, SdeModel};
use crate::rng::SimRng;
use beliefbus_core::chain::{Chain, ChainConfig, NearRule};
use beliefbus_pomdp::chain_pomdp::{self, ChainPomdp, ChainPomdpSpec, ObservationModel, Terminal};
use rand::{RngExt, SeedableRng};

/// dx = u dt + σ dw on [−2, 2].
#[derive(Clone, Debug)]
pub struct LightDark1d {
    pub sigma: f64,
    bounds: Bounds,
}

/// The domain's half-width.
pub const HALF: f64 = 2.0;

impl LightDark1d {
    pub fn new(sigma: f64) -> Result<Self, String> {
        let bounds = Bounds::new_box(&[-HALF], &[HALF]).map_err(|e| e.to_string())?;
        Ok(Self { sigma, bounds })
    }
}

impl SdeModel for LightDark1d {
    fn name(&self) -> &str {
        "light-dark"
    }
    fn dims(&self) -> Dims {
        Dims {
            state: 1,
            noise: 1,
            obs: 1,
            control: 1,
        }
    }
    fn drift(&self, _x: &[f64], u: &[f64], f: &mut [f64]) {
        f[0] = u[0];
    }
    fn diffusion(&self, _x: &[f64], big_f: &mut [f64]) {
        big_f[0] = self.sigma;
    }
    fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
        g[0] = x[0];
    }
    /// Nominal: the real noise depends on x ([`LightObs`]).
    fn obs_std(&self, std: &mut [f64]) {
        std[0] = 1.0;
    }
    fn bounds(&self) -> &Bounds {
        &self.bounds
    }
}

/// y = x + G(x) v, G = ε within the light |x − b| < e_b, 1/ε elsewhere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightObs {
    pub light: f64,
    pub light_width: f64,
    pub eps: f64,
}

impl LightObs {
    /// Whether x is lit.
    #[inline]
    pub fn lit(&self, x: f64) -> bool {
        (x - self.light).abs() < self.light_width
    }

    /// G(x).
    #[inline]
    pub fn std(&self, x: f64) -> f64 {
        if self.lit(x) {
            self.eps
        } else {
            1.0 / self.eps
        }
    }

    /// log p(y | x) up to a constant.
    #[inline]
    pub fn log_lik(&self, x: f64, y: f64) -> f64 {
        let s = self.std(x);
        let r = (y - x) / s;
        -0.5 * r * r - s.ln()
    }
}

impl ObservationModel for LightObs {
    fn log_likelihood(&self, z: &[f64], y: &[f64]) -> f64 {
        self.log_lik(z[0], y[0])
    }
}

/// The n regular states: cell centres of [−2, 2].
pub fn grid(n: usize) -> Vec<f64> {
    let h = 2.0 * HALF / n as f64;
    (0..n).map(|i| -HALF + (i as f64 + 0.5) * h).collect()
}

/// The POMDP of the module doc.
pub fn build(p: &LightDarkParams) -> Result<ChainPomdp, String> {
    let m = LightDark1d::new(p.noise)?;
    let pts = grid(p.states);
    let cfg = ChainConfig::gaussian(1).with_near(NearRule::Radius { gamma: 2.0 });
    let chain = Chain::batch(&m, cfg, &pts).map_err(|e| format!("chain: {e}"))?;
    let mut rng = SimRng::seed_from_u64(p.control_seed);
    let mut controls = vec![vec![0.0], vec![-1.0], vec![1.0]];
    while controls.len() < chain_pomdp::log_count(5.0, p.states) {
        controls.push(vec![rng.random_range(-1.0..1.0)]);
    }
    let obs_pts: Vec<Vec<f64>> = pts.iter().map(|&x| vec![x]).collect();
    let n = chain.len();
    let spec = ChainPomdpSpec {
        controls,
        observations: obs_pts,
        delta_max: f64::INFINITY,
        decision_min: 0.0,
        discount_rate: p.rate,
        start: vec![1.0 / n as f64; n],
        row_flush: 1e-9,
        obs_flush: 1e-6,
        // The chain filter's own rows (as the experiment's light-dark), so
        // the policy's belief update is the filter's.
        match_mean: false,
        terminal: Some(Terminal {
            reward: (0..n)
                .map(|i| {
                    if p.in_goal(chain.state(i)[0]) {
                        p.reward
                    } else {
                        -p.reward
                    }
                })
                .collect(),
        }),
    };
    let quadratic = |_z: &[f64], u: &[f64]| u.iter().map(|v| v * v).sum::<f64>();
    chain_pomdp::build(&chain, &m, &p.obs(), &quadratic, &spec).map_err(|e| e.to_string())
}

/// FNV-1a, 64 bit: a fingerprint stable across builds and platforms
/// (std's hasher is not promised to be).
#[derive(Clone, Copy, Debug)]
pub struct Fnv(u64);

impl Default for Fnv {
    fn default() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv {
    pub fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 ^= u64::from(x);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    pub fn f64(&mut self, v: f64) {
        self.bytes(&v.to_bits().to_le_bytes());
    }
    pub fn u64(&mut self, v: u64) {
        self.bytes(&v.to_le_bytes());
    }
    pub fn finish(&self) -> u64 {
        self.0
    }
}

/// The fingerprint of the module doc, as 16 hex digits.
pub fn model_key(cp: &ChainPomdp, obs: &LightObs) -> String {
    let mut h = Fnv::default();
    let p = &cp.pomdp;
    h.bytes(b"light-dark chain pomdp 1");
    h.f64(p.discount);
    h.u64(p.n_states() as u64);
    h.u64(p.n_actions() as u64);
    h.u64(p.n_obs() as u64);
    p.start.iter().for_each(|&v| h.f64(v));
    for rows in p.trans.iter().chain(&p.obs) {
        for i in 0..rows.n_rows() {
            let (cols, vals) = rows.row(i);
            h.u64(cols.len() as u64);
            cols.iter().for_each(|&c| h.u64(u64::from(c)));
            vals.iter().for_each(|&v| h.f64(v));
        }
    }
    p.reward.iter().flatten().for_each(|&v| h.f64(v));
    cp.states.iter().for_each(|&v| h.f64(v));
    cp.controls.iter().flatten().for_each(|&v| h.f64(v));
    h.f64(cp.period);
    h.f64(obs.light);
    h.f64(obs.light_width);
    h.f64(obs.eps);
    format!("{:016x}", h.finish())
}
