//! A particle filter on your own model (`cargo run -p beliefbus-core --example
//! filter_your_model`): an oscillator, noise on its velocity, position seen.
use beliefbus_core::belief::Gaussian;
use beliefbus_core::filter::{pf::PfConfig, BayesFilter};
use beliefbus_core::model::discrete::{em_integrate, simulate_observation};
use beliefbus_core::model::{Bounds, Dims, Measurement, SdeModel};

struct Oscillator(Bounds);
#[rustfmt::skip]
impl SdeModel for Oscillator {
    fn name(&self) -> &str { "oscillator" }
    fn dims(&self) -> Dims { Dims { state: 2, noise: 1, obs: 1, control: 0 } }
    fn drift(&self, x: &[f64], _u: &[f64], f: &mut [f64]) { f[0] = x[1]; f[1] = -x[0] - 0.2 * x[1]; }
    fn diffusion(&self, _x: &[f64], big_f: &mut [f64]) { big_f[0] = 0.0; big_f[1] = 0.3; }
    fn obs_mean(&self, x: &[f64], g: &mut [f64]) { g[0] = x[0]; }
    fn obs_std(&self, std: &mut [f64]) { std[0] = 0.1; }
    fn bounds(&self) -> &Bounds { &self.0 }
}
#[rustfmt::skip]
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let model = Oscillator(Bounds::new_box(&[-5.0, -5.0], &[5.0, 5.0])?);
    let prior = Gaussian::diagonal(&[1.0, 0.0], &[0.3, 0.3]);
    let cfg = PfConfig { particles: 500, seed: 7, ..PfConfig::default() };
    let mut pf = cfg.build(Oscillator(model.0), &prior, 0.0)?;
    let mut rng = beliefbus_core::rng::stream(7, 0);
    let (mut x, mut y, dt, mut sq_err) = (vec![1.0, 0.0], [0.0], 0.05, 0.0);
    for k in 1..=400 {
        em_integrate(&model, &mut x, &[], dt, 0.005, &mut rng);
        simulate_observation(&model, &x, &mut rng, &mut y);
        pf.predict(k as f64 * dt, &[])?;
        pf.update(&Measurement::full(&y))?;
        sq_err += (pf.belief().mean[1] - x[1]).powi(2);
    }
    // The velocity is never measured: the filter infers it from positions.
    println!("velocity RMSE {:.3}", (sq_err / 400.0).sqrt());
    Ok(())
}
