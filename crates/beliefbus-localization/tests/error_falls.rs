//! Each filter's error falls with the number of samples: on seeded
//! synthetic car parks (a recording made in the test, no data files), the
//! paired difference error(M small) − error(M large) over the seeds is
//! positive by more than three standard errors.

use beliefbus_core::rng::stream;
use beliefbus_localization::carpark::{CarPark, CarParkConfig};
use beliefbus_localization::experiments::mcl::score;
use beliefbus_localization::geometry::Pose;
use beliefbus_localization::mcl::implicit::ImplicitMcl;
use beliefbus_localization::mcl::newton::NewtonSettings;
use beliefbus_localization::mcl::standard::StandardMcl;
use beliefbus_localization::mcl::{Localizer, Prior};
use beliefbus_localization::victoria::{OdometrySample, Recording};

/// 40 s at 40 Hz: straight, then a left and a right turn; scans at ≈ 4.7 Hz.
fn recording() -> Recording {
    let odometry = (0..1600)
        .map(|i| {
            let t = i as f64 * 0.025;
            let steering = if t < 10.0 {
                0.0
            } else if t < 25.0 {
                0.25
            } else {
                -0.2
            };
            OdometrySample {
                time: t,
                speed: 3.0,
                steering,
            }
        })
        .collect();
    let laser_times = (0..187).map(|i| 0.01 + i as f64 * 0.214).collect();
    Recording {
        odometry,
        laser_times,
    }
}

fn paired_gain(
    make: impl Fn(usize) -> Box<dyn Localizer>,
    small: usize,
    large: usize,
) -> (f64, f64) {
    let rec = recording();
    let cfg = CarParkConfig {
        start_time: 0.0,
        duration: 40.0,
        ..Default::default()
    };
    let prior = Prior {
        std: Pose::new(0.3, 0.3, 0.02),
    };
    let seeds = 8;
    let mut d = Vec::new();
    for s in 0..seeds {
        let cp = CarPark::generate(&rec, &cfg, &mut stream(77, s)).unwrap();
        let e = |m| {
            score(make(m).as_mut(), &cp, &prior, 5, s)
                .unwrap()
                .error_pct
        };
        d.push(e(small) - e(large));
    }
    let n = d.len() as f64;
    let mean = d.iter().sum::<f64>() / n;
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

#[test]
fn standard_mcl_error_falls_with_samples() {
    let (gain, se) = paired_gain(|m| Box::new(StandardMcl::new(m, 0.5).unwrap()), 10, 300);
    assert!(gain > 3.0 * se && gain > 0.0, "gain {gain} ± {se}");
}

#[test]
fn implicit_mcl_error_falls_with_samples() {
    let (gain, se) = paired_gain(
        |m| Box::new(ImplicitMcl::new(m, 0.5, NewtonSettings::default()).unwrap()),
        3,
        100,
    );
    assert!(gain > 3.0 * se && gain > 0.0, "gain {gain} ± {se}");
}
