//! The interval prior lets implicit MCL's scan steer the whole interval's
//! noise: on seeded synthetic car parks (a slalom recorded in the test,
//! scans about once per 8.5 odometry steps, no data files) implicit MCL
//! with few samples has a lower error with the prior than without, paired
//! over the seeds by more than three standard errors.

use beliefbus_core::rng::stream;
use beliefbus_localization::carpark::{CarPark, CarParkConfig};
use beliefbus_localization::experiments::mcl::score;
use beliefbus_localization::geometry::Pose;
use beliefbus_localization::mcl::implicit::ImplicitMcl;
use beliefbus_localization::mcl::newton::NewtonSettings;
use beliefbus_localization::mcl::{Localizer, Prior};
use beliefbus_localization::victoria::{OdometrySample, Recording};

/// 30 s at 40 Hz of a slalom at 2.5 m/s; scans every 0.212 s.
fn slalom() -> Recording {
    let odometry = (0..1200)
        .map(|i| {
            let t = i as f64 * 0.025;
            OdometrySample {
                time: t,
                speed: 2.5,
                steering: 0.2 * (0.4 * t).sin(),
            }
        })
        .collect();
    let laser_times = (0..140).map(|i| 0.02 + i as f64 * 0.212).collect();
    Recording {
        odometry,
        laser_times,
    }
}

#[test]
fn interval_prior_lowers_implicit_mcls_error_at_few_samples() {
    let rec = slalom();
    let cfg = CarParkConfig {
        start_time: 0.0,
        duration: 30.0,
        ..Default::default()
    };
    let prior = Prior {
        std: Pose::new(0.3, 0.3, 0.02),
    };
    let mut d = Vec::new();
    for s in 0..8 {
        let cp = CarPark::generate(&rec, &cfg, &mut stream(91, s)).unwrap();
        let e = |on: bool| {
            let mut f = ImplicitMcl::new(10, 0.5, NewtonSettings::default()).unwrap();
            f.set_interval_prior(on);
            score(&mut f, &cp, &prior, 3, s).unwrap().error_pct
        };
        d.push(e(true) - e(false));
    }
    let n = d.len() as f64;
    let mean = d.iter().sum::<f64>() / n;
    let se = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt();
    assert!(
        mean < 0.0 && -mean > 3.0 * se,
        "on − off: {mean} ± {se} ({d:?})"
    );
}
