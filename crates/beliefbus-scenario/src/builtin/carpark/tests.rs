//! The car park's plant, filters and metrics without the pipeline, on a
//! synthetic recording (no data files needed): the live backends against
//! the localization crate's offline driver on the same data and random
//! numbers, the plant's schedule and encoding, the metrics against
//! hand-computable cases.

use super::encoding::{read_slot, write_laser, SlotError, MAX_FEATURES, OBS};
use super::filter::MclFilter;
use super::metrics::CarparkMetrics;
use super::plant::CarparkPlant;
use super::*;
use crate::metrics::{BeliefView, TruthView};
use crate::{NextSample, Plant};
use beliefbus_core::belief::Gaussian;
use beliefbus_core::model::{Measurement, ObsMask};
use beliefbus_localization::carpark::CarPark;
use beliefbus_localization::laser::Observation;
use beliefbus_localization::mcl::implicit::ImplicitMcl;
use beliefbus_localization::mcl::newton::NewtonSettings;
use beliefbus_localization::mcl::standard::StandardMcl;
use beliefbus_localization::mcl::{run as run_offline, Localizer, Prior};
use beliefbus_localization::victoria::{OdometrySample, Recording};

const DT: f64 = 0.025;

/// 40 Hz odometry driving an S-curve at 4 m/s; scans every 0.2137 s.
fn recording() -> Recording {
    let odometry = (0..2400)
        .map(|i| {
            let t = i as f64 * DT;
            OdometrySample {
                time: t,
                speed: 4.0,
                steering: 0.15 * (t / 9.0).sin(),
            }
        })
        .collect();
    let laser_times = (0..280).map(|i| 0.013 + i as f64 * 0.2137).collect();
    Recording {
        odometry,
        laser_times,
    }
}

fn params() -> CarparkParams {
    CarparkParams {
        start_time_s: 0.0,
        duration_s: 40.0,
        gap_every_s: 15.0,
        gap_len_s: 2.0,
        ..CarparkParams::default()
    }
}

fn system(p: CarparkParams, seed: u64) -> CarparkSystem {
    let mut rng = crate::rng::stream(seed, 0);
    let cp = CarPark::generate(&recording(), &p.carpark_config(), &mut rng).unwrap();
    CarparkSystem::from_carpark(p, cp, DT).unwrap()
}

/// Every sample of the plant: (channel index, time, y).
fn replay(sys: &CarparkSystem) -> Vec<(usize, f64, [f64; OBS])> {
    let mut plant = CarparkPlant::new(sys, &sys.initial_state(), 1).unwrap();
    let mut out = Vec::new();
    loop {
        match plant.next_sample() {
            NextSample::At { channel, t } => {
                // The announcement holds until the step.
                assert_eq!(plant.next_sample(), NextSample::At { channel, t });
                plant.step();
                let mut y = [0.0; OBS];
                plant.measure(&mut y);
                out.push((channel, t, y));
            }
            NextSample::Done => return out,
            NextSample::Periodic => panic!("the car park plant is multi-rate"),
        }
    }
}

fn ctx(sys: &CarparkSystem, seed: u64) -> FilterContext {
    let (m, s) = sys.prior();
    FilterContext {
        seed,
        sample_dt: DT,
        start: Gaussian::diagonal(&m, &s),
        resumed: false,
        t0: 0.0,
    }
}

/// Feed the replay to a live filter; the estimate after each odometry
/// sample.
fn live(sys: &CarparkSystem, f: &mut MclFilter) -> Vec<[f64; 3]> {
    let channels = sys.sensor_channels();
    let mut out = Vec::new();
    for (ch, t, y) in replay(sys) {
        let mut mask = ObsMask(0);
        for &c in &channels[ch].components {
            mask.0 |= 1 << c;
        }
        f.predict(t, &[0.0]).unwrap();
        f.update(&Measurement {
            y: &y,
            mask,
            std: None,
        })
        .unwrap();
        if ch == ODOMETRY as usize {
            let b = f.belief();
            out.push([b.mean[0], b.mean[1], b.mean[2]]);
        }
    }
    out
}

#[test]
fn the_plant_publishes_each_scan_before_its_odometry_sample_and_decodes_exactly() {
    let sys = system(params(), 3);
    let cp = &sys.carpark;
    let samples = replay(&sys);
    let odo: Vec<_> = samples.iter().filter(|s| s.0 == 0).collect();
    assert_eq!(odo.len(), cp.steps());
    // Times never decrease; odometry n at t_n − t_0.
    assert!(samples.windows(2).all(|w| w[1].1 >= w[0].1));
    for (n, s) in odo.iter().enumerate() {
        assert!((s.1 - (cp.times[n + 1] - cp.times[0])).abs() < 1e-12);
        // The encoder speed gives back the centre speed.
        let u = cp.controls[n];
        let v = cp.ute.centre_speed(s.2[0], s.2[1]).unwrap();
        assert!((v - u.v).abs() < 1e-12 && s.2[1] == u.alpha);
    }
    // Every scan's features, exactly, at its step's time, before that
    // step's odometry sample.
    let mut i = 0;
    let mut published = 0;
    for sc in &cp.scans {
        assert!(sc.len <= MAX_FEATURES, "test data: a scan of {}", sc.len);
        let t = cp.times[sc.step] - cp.times[0];
        let mut got = Vec::new();
        while samples[i].1 < t || (samples[i].1 == t && samples[i].0 == 1) {
            if samples[i].0 == 1 && samples[i].1 == t {
                for k in 0..2 {
                    if let Some(o) = read_slot(&samples[i].2, k, cp.landmarks.len()).unwrap() {
                        got.push(o);
                    }
                }
            }
            i += 1;
        }
        assert_eq!(samples[i].0, 0, "the odometry sample follows");
        assert_eq!(got, cp.scan_obs(sc));
        published += got.len();
    }
    assert_eq!(published, cp.obs.len());
    assert!(cp.dropped_scans > 0 && cp.scans.len() > 100);
}

#[test]
fn a_scan_keeps_its_nearest_features_and_a_restart_continues_the_drive() {
    let mut p = params();
    p.max_features = 1;
    let sys = system(p, 3);
    let cp = &sys.carpark;
    let laser: Vec<_> = replay(&sys).into_iter().filter(|s| s.0 == 1).collect();
    assert_eq!(laser.len(), cp.scans.len());
    for (s, sc) in laser.iter().zip(&cp.scans) {
        let nearest = cp
            .scan_obs(sc)
            .iter()
            .map(|o| o.range)
            .fold(f64::INFINITY, f64::min);
        assert_eq!(s.2[2], nearest);
        assert_eq!(s.2[7], super::encoding::EMPTY);
    }
    // From the true pose of step 500: the next sample is at or after step
    // 501, its time counted from step 500.
    let x = cp.truth[500];
    let mut plant = CarparkPlant::new(&sys, &[x[0], x[1], x[2]], 1).unwrap();
    let NextSample::At { t, .. } = plant.next_sample() else {
        panic!("samples left")
    };
    assert!((t - (cp.times[501] - cp.times[500])).abs() < 1e-12);
    assert_eq!(plant.remaining_steps(), cp.steps() - 500);
}

/// The live backends, fed sample by sample, give the offline driver's
/// estimates on the same data set with the same random numbers.
#[test]
fn live_mcl_equals_the_offline_driver() {
    let sys = system(params(), 5);
    let cp = &sys.carpark;
    for implicit in [true, false] {
        let seed = 11;
        let mut f = MclFilter::new(&sys, &ctx(&sys, seed), implicit).unwrap();
        let ours = live(&sys, &mut f);
        let p = &sys.params.filter;
        let mut offline: Box<dyn Localizer> = if implicit {
            let newton = NewtonSettings {
                max_iter: p.newton_max_iter,
                tol: p.newton_tol,
            };
            Box::new(ImplicitMcl::new(p.particles, p.ess_threshold, newton).unwrap())
        } else {
            Box::new(StandardMcl::new(p.particles, p.ess_threshold).unwrap())
        };
        let prior = Prior {
            std: beliefbus_localization::geometry::Pose::new(0.3, 0.3, 0.02),
        };
        let mut theirs = Vec::new();
        run_offline(
            offline.as_mut(),
            cp,
            &prior,
            &mut crate::rng::stream(seed, 0),
            |_, e| theirs.push(*e),
        )
        .unwrap();
        assert_eq!(ours.len(), theirs.len());
        for (n, (a, b)) in ours.iter().zip(&theirs).enumerate() {
            let d = (a[0] - b[0]).abs() + (a[1] - b[1]).abs();
            let h = beliefbus_localization::geometry::wrap_angle(a[2] - b[2]).abs();
            assert!(
                d < 1e-6 && h < 1e-6,
                "implicit {implicit}, step {n}: {a:?} vs {b:?}"
            );
        }
        assert_eq!(
            f.localizer().particles().updates,
            offline.particles().updates
        );
        assert_eq!(f.localizer().particles().updates, cp.scans.len());
    }
}

#[test]
fn bad_laser_samples_are_refused_with_a_typed_error() {
    let sys = system(params(), 5);
    let mut f = MclFilter::new(&sys, &ctx(&sys, 1), true).unwrap();
    let mut y = [0.0; OBS];
    let o = Observation {
        range: 5.0,
        bearing: 1.0,
        landmark: sys.carpark.landmarks.len(),
    };
    write_laser(&mut y, &o, None);
    let mask = ObsMask(0b1111_1100);
    f.predict(0.01, &[0.0]).unwrap();
    let e = f.update(&Measurement {
        y: &y,
        mask,
        std: None,
    });
    assert!(
        matches!(
            e,
            Err(beliefbus_core::filter::FilterError::Dimension { .. })
        ),
        "{e:?}"
    );
    assert_eq!(
        read_slot(&y, 0, 3),
        Err(SlotError::Landmark(o.landmark as f64))
    );
    y[4] = 1.5;
    assert_eq!(read_slot(&y, 0, 1000), Err(SlotError::Landmark(1.5)));
    // A mask that is neither channel.
    let e = f.update(&Measurement {
        y: &y,
        mask: ObsMask(0b1),
        std: None,
    });
    assert!(e.is_err());
    assert_eq!(f.pending_features(), 0);
    let mut p = params();
    p.max_features = 7;
    assert!(CarparkSystem::from_carpark(p, (*sys.carpark).clone(), DT).is_err());
}

/// With an exact model (no truth noise) dead reckoning from the published
/// odometry is the true path; an estimate 1 m and 0.1 rad off has exactly
/// that error.
#[test]
fn metrics_count_channels_and_score_against_dead_reckoning() {
    let mut p = params();
    p.truth_noise = 0.0;
    let sys = system(p, 7);
    let cp = sys.carpark.clone();
    let mut m = CarparkMetrics::new(&sys);
    let mut t_prev_scan = None;
    let (mut odo, mut laser) = (0u64, 0u64);
    for (seq, (ch, t, y)) in replay(&sys).into_iter().enumerate() {
        let t_ns = 1_000_000_000 + (t * 1e9).round() as u64;
        let n = (t / DT).round() as usize;
        let x = cp.truth[n];
        let xs = [x[0], x[1], x[2]];
        let tv = TruthView {
            seq: seq as u64,
            channel: ch as u32,
            t_ns,
            counted: true,
            x: &xs,
            u: &[0.0],
            y: &y,
        };
        m.truth(&tv);
        let mean = [x[0] + 1.0, x[1], x[2] + 0.1];
        let scan_step = ch == 0 && t_prev_scan == Some(t_ns);
        m.belief(
            &BeliefView {
                sensor_seq: seq as u64,
                sensor_channel: ch as u32,
                ess: if scan_step { 40.0 } else { 0.0 },
                filter_ns: if scan_step { 2000 } else { 100 },
                mean: &mean,
                cov: &[0.0; 9],
            },
            &tv,
        );
        if ch == 1 {
            t_prev_scan = Some(t_ns);
            laser += 1;
        } else {
            odo += 1;
        }
    }
    let r = m.report();
    assert_eq!(r["channels"]["odometry"]["samples"], odo);
    assert_eq!(r["channels"]["laser"]["beliefs"], laser);
    assert_eq!(r["channels"]["laser"]["features"], cp.obs.len() as u64);
    let f = |k: &str| r[k].as_f64().unwrap();
    assert!((f("pose_rmse_position_m") - 1.0).abs() < 1e-9, "{r}");
    assert!((f("pose_rmse_heading_rad") - 0.1).abs() < 1e-9);
    assert!(f("dead_reckoning_rmse_position_m") < 1e-4, "{r}");
    assert!(f("path_rmse_m") < 1e-12, "replayed: on the path");
    assert_eq!(r["laser_steps"], cp.scans.len() as u64);
    assert_eq!(f("ess_mean"), 40.0);
    assert_eq!(f("ess_min_fraction"), 0.4);
    assert_eq!(r["time_laser_step"]["p99_us"], 2.0);
    assert_eq!(r["time_prediction_step"]["p50_us"], 0.1);
}

/// Closed loop without the pipeline: the plant drives itself with the
/// steering pure pursuit computes from (a) the true pose, (b) implicit
/// MCL's belief. Both keep the vehicle on the data set's path, which
/// steering straight ahead (a constant control) does not.
#[test]
fn pure_pursuit_keeps_the_self_driving_plant_on_the_path() {
    use super::control::{nearest, PurePursuit};
    use beliefbus_core::control::Controller;
    let sys = system(params(), 5);
    let cp = sys.carpark.clone();
    let channels = sys.sensor_channels();
    // Mean distance to the path over the drive, and the laser features seen.
    let drive = |mode: u8| -> (f64, usize) {
        let mut plant = CarparkPlant::new(&sys, &sys.initial_state(), 9).unwrap();
        let mut f = MclFilter::new(&sys, &ctx(&sys, 3), true).unwrap();
        let mut pp = PurePursuit::new(&sys).unwrap();
        let (mut se, mut n, mut idx, mut feats) = (0.0, 0usize, 0usize, 0usize);
        let mut u = [0.0];
        while let NextSample::At { channel, t } = plant.next_sample() {
            plant.set_control(&u);
            plant.step();
            let mut y = [0.0; OBS];
            plant.measure(&mut y);
            let mut mask = ObsMask(0);
            for &c in &channels[channel].components {
                mask.0 |= 1 << c;
            }
            f.predict(t, &u).unwrap();
            f.update(&Measurement {
                y: &y,
                mask,
                std: None,
            })
            .unwrap();
            let x = plant.state().to_vec();
            if channel == LASER as usize {
                feats += (0..2)
                    .filter(|&k| matches!(read_slot(&y, k, usize::MAX), Ok(Some(_))))
                    .count();
                continue;
            }
            let (i, d) = nearest(&cp, idx, x[0], x[1]);
            idx = i;
            se += d * d;
            n += 1;
            let belief = match mode {
                0 => Gaussian::diagonal(&x, &[0.01; 3]),
                _ => f.belief(),
            };
            u[0] = if mode == 2 {
                0.0
            } else {
                pp.compute(t, &belief, &mut u).unwrap();
                u[0]
            };
        }
        ((se / n as f64).sqrt(), feats)
    };
    let (truth_fed, feats) = drive(0);
    let (filter_fed, _) = drive(1);
    let (straight, _) = drive(2);
    assert!(
        feats > 100,
        "the self-driving plant's laser sees the map: {feats}"
    );
    assert!(
        truth_fed < 0.5,
        "pure pursuit on the true pose: {truth_fed} m"
    );
    assert!(
        filter_fed < 1.5,
        "pure pursuit on implicit MCL: {filter_fed} m"
    );
    assert!(
        straight > 5.0,
        "steering straight leaves the S-curve: {straight} m"
    );
}

/// The MPPI follower's cost: squared distance to a polyline, exact.
#[test]
fn the_mppi_path_cost_is_the_squared_distance_to_the_polyline() {
    use super::mppi::PolylineCost;
    use beliefbus_core::model::path_cost::PathCost;
    let mut c = PolylineCost::new(2.0, 5.0);
    // An L: (0,0) → (10,0) → (10,10).
    c.set_goal(&[0.0, 0.0, 10.0, 0.0, 10.0, 10.0]);
    assert_eq!(c.dist2(5.0, 3.0), 9.0);
    assert_eq!(c.dist2(13.0, 4.0), 9.0);
    assert_eq!(c.dist2(-3.0, -4.0), 25.0);
    assert_eq!(c.running(&[5.0, 3.0, 0.0, 1.0]), 18.0);
    assert_eq!(c.terminal(&[5.0, 3.0, 0.0, 1.0]), 45.0);
}

/// Closed loop without the pipeline: MPPI on the true pose keeps the
/// self-driving plant on the data set's path (steering straight ahead
/// leaves it by more than 5 m, see the pure-pursuit test), computing a
/// steering for every odometry sample.
#[test]
fn mppi_keeps_the_self_driving_plant_on_the_path() {
    use super::control::nearest;
    use super::mppi::MppiFollower;
    use beliefbus_core::control::Controller;
    let sys = system(params(), 5);
    let cp = sys.carpark.clone();
    let mut plant = CarparkPlant::new(&sys, &sys.initial_state(), 9).unwrap();
    let mut c = MppiFollower::new(&sys, 4).unwrap();
    let (mut se, mut n, mut idx, mut ok) = (0.0, 0usize, 0usize, 0usize);
    let mut u = [0.0];
    while let NextSample::At { channel, t } = plant.next_sample() {
        plant.set_control(&u);
        plant.step();
        if channel == LASER as usize {
            continue;
        }
        let x = plant.state().to_vec();
        let (i, d) = nearest(&cp, idx, x[0], x[1]);
        idx = i;
        se += d * d;
        n += 1;
        if c.compute(t, &Gaussian::diagonal(&x, &[0.01; 3]), &mut u)
            .is_ok()
        {
            ok += 1;
        }
        c.prepare();
    }
    assert_eq!(ok, n);
    let rms = (se / n as f64).sqrt();
    assert!(rms < 0.5, "MPPI on the true pose: {rms} m from the path");
}
