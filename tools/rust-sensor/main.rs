//! `beliefbus-example-sensor`: an example sensor publisher in Rust.
//!
//! It simulates the drifting ship (paper 001 eq. 10–11, [`Ship`]) with
//! Euler–Maruyama at a fine step and publishes its range/bearing through
//! [`SensorPublisher`] at a fixed rate — the same thing a real sensor driver
//! would do with real measurements. With `--truth` it also publishes the
//! true state on the `truth` channel so the run can report its accuracy.
//! See `tools/rust-sensor/README.md` and `docs/sensor-abi.md`.

use anyhow::{bail, Context, Result};
use beliefbus::ipc::sensor_api::{monotonic_now_ns, SensorPublisher};
use beliefbus::ipc::{install_stop_handler, Bus, BusConfig, Publisher, Truth};
use beliefbus::model::ship::{Ship, ShipParams};
use beliefbus::model::{discrete::em_integrate, simulate_observation, SdeModel};
use beliefbus::rt::clock::sleep_until_ns;
use clap::Parser;
use std::sync::atomic::Ordering;
use std::time::Duration;

#[derive(Parser, Debug)]
#[command(
    name = "beliefbus-example-sensor",
    about = "Example sensor publisher: a simulated ship's range/bearing at a fixed rate"
)]
struct Args {
    /// Shared-memory prefix of the run (printed by `beliefbus run`).
    #[arg(long, default_value = "iox2_beliefbus_")]
    prefix: String,
    /// Pipeline instance (`run.instance` of the config).
    #[arg(long, default_value = "ship")]
    instance: String,
    /// Sensor channel id.
    #[arg(long, default_value_t = 0)]
    channel: u32,
    /// Samples per second.
    #[arg(long, default_value_t = 100.0)]
    rate: f64,
    /// Seconds to publish.
    #[arg(long, default_value_t = 10.0)]
    duration: f64,
    /// Simulation step (seconds).
    #[arg(long, default_value_t = 1e-3)]
    integration_dt: f64,
    /// Initial true state x1 x2 x3 x4.
    #[arg(long, num_args = 4, default_values_t = [3.0, 0.0, 0.0, 0.0])]
    initial_state: Vec<f64>,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Also publish the true state (`truth` channel).
    #[arg(long)]
    truth: bool,
    /// Seconds to wait for the pipeline's ingest to subscribe (0: don't).
    #[arg(long, default_value_t = 10.0)]
    wait_ingest: f64,
}

fn main() {
    let args = Args::parse();
    match run(&args) {
        Ok(sent) => println!("{{\"sent\": {sent}}}"),
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::exit(1);
        }
    }
}

fn run(a: &Args) -> Result<u64> {
    if !(a.rate > 0.0 && a.rate.is_finite()) {
        bail!("--rate must be positive");
    }
    if !(a.integration_dt > 0.0) {
        bail!("--integration-dt must be positive");
    }
    let stop = install_stop_handler();
    let period = 1.0 / a.rate;
    let ship = Ship::new(ShipParams::paper(period)).map_err(anyhow::Error::msg)?;
    let cfg = BusConfig {
        prefix: a.prefix.clone(),
        instance: a.instance.clone(),
    };
    let mut sensor = SensorPublisher::connect_with(&cfg, "rust-sensor")?;
    // Truth is a pipeline message, published through the plain bus API.
    let truth_bus = if a.truth {
        Some(Bus::open(&cfg, "rust-sensor-truth")?)
    } else {
        None
    };
    let mut truth: Option<Publisher<Truth>> = match &truth_bus {
        Some(b) => Some(b.publisher()?),
        None => None,
    };
    if a.wait_ingest > 0.0
        && !sensor.wait_for_subscribers(1, Duration::from_secs_f64(a.wait_ingest))
    {
        bail!(
            "no subscriber on {} after {} s (is the pipeline running with this prefix?)",
            sensor.service(),
            a.wait_ingest
        );
    }
    let dims = ship.dims();
    let mut x = a.initial_state.clone();
    let mut rng = beliefbus::rng::stream(a.seed, 0x5e5);
    let mut y = [0.0; 2];
    let period_ns = (period * 1e9).round() as u64;
    let n = (a.duration * a.rate).round() as u64;
    let mut t_next = monotonic_now_ns() + period_ns;
    let u = [0.0; 2];
    for _ in 0..n {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        sleep_until_ns(t_next);
        em_integrate(&ship, &mut x, &u, period, a.integration_dt, &mut rng);
        simulate_observation(&ship, &x, &mut rng, &mut y[..dims.obs]);
        let t_meas = monotonic_now_ns();
        let seq = sensor
            .publish(a.channel, t_meas, &y)
            .context("publishing a sample")?;
        if let Some(p) = truth.as_mut() {
            let mut t = Truth {
                channel: a.channel,
                dim: dims.state as u32,
                obs_dim: dims.obs as u32,
                control_dim: dims.control as u32,
                ..Truth::default()
            };
            t.header.seq = seq;
            t.header.t_valid_ns = t_meas;
            t.header.t_pub_ns = monotonic_now_ns();
            t.x[..dims.state].copy_from_slice(&x);
            t.y[..dims.obs].copy_from_slice(&y);
            p.publish(&t)?;
        }
        t_next += period_ns;
    }
    Ok(sensor.sent())
}
