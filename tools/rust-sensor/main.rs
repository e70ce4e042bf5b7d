//! `beliefbus-example-sensor`: an example sensor publisher in Rust.
//!
//! It simulates the drifting ship (paper 001 eq. 10–11, [`Ship`]) with
//! Euler–Maruyama at a fine step — or follows a deterministic circle — and
//! publishes its range/bearing through [`SensorPublisher`] on a fixed
//! schedule (measurement time = the scheduled instant) — the same thing a
//! real sensor driver would do with real measurements. With `--truth` it also
//! publishes the true state on the `truth` channel so the run can report its
//! accuracy; `--faults` mixes in bad samples and a 10× rate burst and prints
//! what it injected (the schedule of `tools/python/sensor_publisher.py`).
//! See `tools/rust-sensor/README.md` and `docs/sensor-abi.md`.

use anyhow::{bail, Context, Result};
use beliefbus::ipc::sensor_api::{monotonic_now_ns, SensorPublisher};
use beliefbus::ipc::{install_stop_handler, Bus, BusConfig, Publisher, SensorSample, Truth};
use beliefbus::model::discrete::em_integrate;
use beliefbus::model::ship::{Ship, ShipParams};
use beliefbus::model::SdeModel;
use beliefbus::rng::SimRng;
use beliefbus::rt::clock::sleep_until_ns;
use clap::Parser;
use rand::RngExt;
use rand_distr::StandardNormal;
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
    /// `ship`: simulate the drifting ship; `circle`: a deterministic circle
    /// (several publishers given the same `--t0-ns` measure the same target).
    #[arg(long, value_enum, default_value_t = Trajectory::Ship)]
    trajectory: Trajectory,
    /// Circle radius.
    #[arg(long, default_value_t = 5.0)]
    radius: f64,
    /// Circle angular rate (rad/s).
    #[arg(long, default_value_t = 0.3)]
    omega: f64,
    /// Circle phase origin, CLOCK_MONOTONIC ns (0: now).
    #[arg(long, default_value_t = 0)]
    t0_ns: u64,
    /// Observation components to publish, in value order.
    #[arg(long, value_delimiter = ',', default_value = "range,bearing")]
    components: Vec<Component>,
    /// Inject bad samples (NaN, inf, dimension, time reversal, duplicate,
    /// unknown channel, too old) and a 10× rate burst; report them.
    #[arg(long)]
    faults: bool,
    /// One bad sample after every N good ones.
    #[arg(long, default_value_t = 5)]
    fault_every: usize,
    /// Good sample index after which the burst comes (default: half way).
    #[arg(long)]
    burst_at: Option<usize>,
    /// Samples in the 10× rate burst.
    #[arg(long, default_value_t = 30)]
    burst_len: usize,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum Trajectory {
    Ship,
    Circle,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum Component {
    Range,
    Bearing,
}

/// Faults injected by `--faults`, in turn, with the ingest reason each must
/// get (the same schedule as `tools/python/sensor_publisher.py`).
const FAULTS: [(&str, &str); 7] = [
    ("nan", "non_finite"),
    ("inf", "non_finite"),
    ("dimension", "dimension"),
    ("time_backwards", "time_backwards"),
    ("duplicate", "duplicate"),
    ("unknown_channel", "unknown_channel"),
    ("too_old", "too_old"),
];
const UNKNOWN_CHANNEL: u32 = 9999;
const TOO_OLD_NS: u64 = 5_000_000_000;

/// A bad sample right after a good one (`last_t`, `next_seq`) on `channel`.
fn fault_sample(
    kind: &str,
    channel: u32,
    next_seq: u64,
    last_t: u64,
    values: &[f64],
) -> SensorSample {
    let mut s = SensorSample::new(channel, next_seq, last_t, values);
    let n = values.len();
    match kind {
        "nan" => s.values[0] = f64::NAN,
        "inf" => s.values[n - 1] = f64::INFINITY,
        "dimension" => s.dim = n as u32 + 1,
        "time_backwards" => s.t_meas_ns = last_t - 1_000_000,
        "duplicate" => s.seq = next_seq - 1,
        "unknown_channel" => s.channel = UNKNOWN_CHANNEL,
        "too_old" => s.t_meas_ns = last_t - TOO_OLD_NS,
        _ => unreachable!("fault kinds are the FAULTS table"),
    }
    s
}

/// What is being measured.
enum Target {
    Ship {
        ship: Box<Ship>,
        rng: SimRng,
        x: [f64; 4],
        t_ns: u64,
        dt: f64,
    },
    Circle {
        radius: f64,
        omega: f64,
        t0_ns: u64,
        x: [f64; 4],
    },
}

impl Target {
    /// Move the target to time `t_ns` (the ship integrates; the circle is
    /// evaluated).
    fn advance(&mut self, t_ns: u64) {
        match self {
            Target::Ship {
                ship,
                rng,
                x,
                t_ns: t,
                dt,
            } => {
                let span = t_ns.saturating_sub(*t) as f64 * 1e-9;
                em_integrate(&**ship, &mut x[..], &[0.0, 0.0], span, *dt, rng);
                *t = t_ns;
            }
            Target::Circle {
                radius,
                omega,
                t0_ns,
                x,
            } => {
                let a = *omega * (t_ns as f64 - *t0_ns as f64) * 1e-9;
                let (r, w) = (*radius, *omega);
                *x = [r * a.cos(), r * a.sin(), -r * w * a.sin(), r * w * a.cos()];
            }
        }
    }

    fn state(&self) -> &[f64; 4] {
        match self {
            Target::Ship { x, .. } | Target::Circle { x, .. } => x,
        }
    }
}

fn main() {
    let args = Args::parse();
    match run(&args) {
        Ok(summary) => println!("{summary}"),
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::exit(1);
        }
    }
}

/// Publishes good samples and counts them (plus their truth).
struct Stream<'a> {
    a: &'a Args,
    sensor: SensorPublisher,
    truth: Option<Publisher<Truth>>,
    target: Target,
    model: Ship,
    rng: SimRng,
    sigma: f64,
    good: u64,
}

impl Stream<'_> {
    /// Measure the target at `t_meas` (waiting until then) and publish.
    fn publish_good(&mut self, t_meas: u64) -> Result<[f64; 2]> {
        while monotonic_now_ns() < t_meas {
            sleep_until_ns(t_meas);
        }
        self.target.advance(t_meas);
        let x = *self.target.state();
        let mut y = [0.0; 2];
        self.model.obs_mean(&x, &mut y);
        for v in y.iter_mut() {
            *v += self.sigma * self.rng.sample::<f64, _>(StandardNormal);
        }
        let mut values = [0.0; 2];
        for (v, c) in values.iter_mut().zip(&self.a.components) {
            *v = y[*c as usize];
        }
        let n = self.a.components.len();
        let seq = self
            .sensor
            .publish(self.a.channel, t_meas, &values[..n])
            .context("publishing a sample")?;
        self.good += 1;
        if let Some(p) = self.truth.as_mut() {
            let mut t = Truth {
                channel: self.a.channel,
                dim: 4,
                obs_dim: 2,
                control_dim: 2,
                ..Truth::default()
            };
            t.header.seq = seq;
            t.header.t_valid_ns = t_meas;
            t.header.t_pub_ns = monotonic_now_ns();
            t.x[..4].copy_from_slice(&x);
            t.y[..2].copy_from_slice(&y);
            p.publish(&t)?;
        }
        Ok(values)
    }
}

fn run(a: &Args) -> Result<serde_json::Value> {
    if !(a.rate > 0.0 && a.rate.is_finite()) {
        bail!("--rate must be positive");
    }
    if !(a.integration_dt > 0.0) {
        bail!("--integration-dt must be positive");
    }
    if a.components.is_empty() || a.components.len() > 2 || a.fault_every == 0 {
        bail!("--components takes range and/or bearing; --fault-every must be positive");
    }
    let stop = install_stop_handler();
    let period = 1.0 / a.rate;
    let model = Ship::new(ShipParams::paper(period)).map_err(anyhow::Error::msg)?;
    let sigma = model.params.range_std;
    let cfg = BusConfig {
        prefix: a.prefix.clone(),
        instance: a.instance.clone(),
    };
    let sensor = SensorPublisher::connect_with(&cfg, "rust-sensor")?;
    // Truth is a pipeline message, published through the plain bus API.
    let truth_bus = if a.truth {
        Some(Bus::open(&cfg, "rust-sensor-truth")?)
    } else {
        None
    };
    let truth = match &truth_bus {
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
    let now = monotonic_now_ns();
    let target = match a.trajectory {
        Trajectory::Ship => {
            let mut x = [0.0; 4];
            x.copy_from_slice(&a.initial_state);
            Target::Ship {
                ship: Box::new(model.clone()),
                rng: beliefbus::rng::stream(a.seed, 0x5e5),
                x,
                t_ns: now,
                dt: a.integration_dt,
            }
        }
        Trajectory::Circle => Target::Circle {
            radius: a.radius,
            omega: a.omega,
            t0_ns: if a.t0_ns == 0 { now } else { a.t0_ns },
            x: [0.0; 4],
        },
    };
    let mut st = Stream {
        a,
        sensor,
        truth,
        target,
        model,
        rng: beliefbus::rng::stream(a.seed, 0x0b5),
        sigma,
        good: 0,
    };
    let period_ns = (period * 1e9).round() as u64;
    let n = (a.duration * a.rate).round() as usize;
    let burst_at = a.burst_at.unwrap_or(n / 2);
    let mut injected = serde_json::Map::new();
    let mut burst = serde_json::Value::Null;
    let mut n_fault = 0;
    let mut t_next = now + period_ns;
    for k in 0..n {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        let values = st.publish_good(t_next)?;
        let mut last_t = t_next;
        let nv = a.components.len();
        if a.faults && (k + 1) % a.fault_every == 0 {
            let (kind, reason) = FAULTS[n_fault % FAULTS.len()];
            n_fault += 1;
            let next = st.sensor.next_seq(a.channel);
            st.sensor.publish_sample(&fault_sample(
                kind,
                a.channel,
                next,
                last_t,
                &values[..nv],
            ))?;
            let c = injected.entry(reason).or_insert(0.into());
            *c = (c.as_u64().unwrap_or(0) + 1).into();
        }
        if a.faults && k == burst_at && a.burst_len > 0 {
            // 10× the rate: valid samples, too many of them.
            let spacing = period_ns / 10;
            for _ in 0..a.burst_len {
                last_t += spacing;
                st.publish_good(last_t)?;
            }
            burst = serde_json::json!({"n": a.burst_len, "spacing_ns": spacing, "start_ns": t_next + spacing});
            t_next = last_t;
        }
        t_next += period_ns;
    }
    let mut out = serde_json::json!({
        "sent": st.sensor.sent(),
        "good": st.good,
        "period_ns": period_ns,
        "final_state": st.target.state(),
    });
    if a.faults {
        out["injected"] = injected.into();
        out["burst"] = burst;
    }
    Ok(out)
}
