//! The Victoria Park scenario without the pipeline, on a synthetic
//! recording in the data set's format (no data files needed): the run's
//! assembly, the plant's schedule and encoding, the live SLAM backends
//! against the localization crate's filters stepped directly on the same
//! data and random numbers, and the GPS scoring.

use super::data::{assemble, parse_trees, Run, Tree};
use super::metrics::{fix_steps, VictoriaParkMetrics};
use super::plant::VictoriaParkPlant;
use super::*;
use crate::builtin::live_slam::{
    LiveSlam, BACKENDS, EKF_SLAM, FASTSLAM2, IMPLICIT_REFINE_SLAM, MAP_COMPONENT,
};
use crate::metrics::{BeliefView, TruthView};
use crate::{NextSample, Plant};
use beliefbus_core::belief::Gaussian;
use beliefbus_core::model::{Measurement, ObsMask};
use beliefbus_localization::experiments::slam_vp_data::GpsFix;
use beliefbus_localization::laser::{in_view, predict};
use beliefbus_localization::slam::assoc::RangeBearing;
use beliefbus_localization::slam::ekf::EkfSlam;
use beliefbus_localization::slam::fastslam::{FastSlam, Version};
use beliefbus_localization::slam::implicit::ImplicitSlam;
use beliefbus_localization::slam::SlamFilter;
use beliefbus_localization::vehicle::Control;
use beliefbus_localization::victoria::OdometrySample;

const DT: f64 = 0.025;
const T0: f64 = 20.0;
const SPEEDUP: f64 = 10.0;

/// A 30 s drive on a circle past two rings of trees, its scans every
/// 0.2137 s seeing the trees in the laser's forward half circle (exact
/// range and bearing), GPS at the true laser point every 0.2 s; and how
/// many trees were seen.
fn synthetic_seen() -> (Run, usize) {
    let ute = Ute::default();
    let (v, alpha) = (3.0, 0.1);
    let v_wheel = v * (ute.l - ute.h * f64::tan(alpha)) / ute.l;
    let n = 1200;
    let odometry: Vec<OdometrySample> = (0..=n)
        .map(|i| OdometrySample {
            time: T0 + i as f64 * DT,
            speed: v_wheel,
            steering: alpha,
        })
        .collect();
    let start = Pose::new(0.0, 0.0, 0.0);
    let mut path = vec![start];
    for _ in 0..n {
        let x = *path.last().unwrap();
        path.push(ute.predict_mean(&x, Control { v, alpha }));
    }
    // The circle's centre is to the left of the start.
    let radius = ute.l / alpha.tan();
    let mut trees_xy = Vec::new();
    for k in 0..16 {
        let a = k as f64 * std::f64::consts::TAU / 16.0;
        for r in [radius - 9.0, radius + 9.0] {
            trees_xy.push([r * a.cos(), radius + r * a.sin()]);
        }
    }
    let mut trees = Vec::new();
    let mut seen = vec![false; trees_xy.len()];
    let mut t = T0 + 0.013;
    while t < T0 + n as f64 * DT {
        let k = ((t - T0) / DT).ceil() as usize;
        for (i, m) in trees_xy.iter().enumerate() {
            if in_view(&path[k], *m, 30.0) {
                seen[i] = true;
                let (range, bearing) = predict(&path[k], *m);
                trees.push((
                    t,
                    Tree {
                        range,
                        bearing,
                        diameter: 0.4,
                    },
                ));
            }
        }
        t += 0.2137;
    }
    let gps: Vec<GpsFix> = (0..=n)
        .step_by(8)
        .map(|k| GpsFix {
            time: T0 + k as f64 * DT,
            x: path[k][0],
            y: path[k][1],
        })
        .collect();
    let run = assemble(&odometry, &trees, &gps, 1e9, 30.0, 10.0).unwrap();
    (run, seen.iter().filter(|&&s| s).count())
}

fn synthetic() -> Run {
    synthetic_seen().0
}

fn system() -> VictoriaParkSystem {
    let mut p = VictoriaParkParams {
        start_heading_deg: 0.0,
        ..VictoriaParkParams::default()
    };
    p.filter.particles = 20;
    VictoriaParkSystem::from_run(p, synthetic()).unwrap()
}

/// Every sample of the plant: (channel index, time, y).
fn replay(sys: &VictoriaParkSystem) -> Vec<(usize, f64, [f64; 8])> {
    let mut plant = VictoriaParkPlant::new(sys.run.clone(), sys.params.speedup).unwrap();
    let mut out = Vec::new();
    loop {
        match plant.next_sample() {
            NextSample::At { channel, t } => {
                assert_eq!(plant.next_sample(), NextSample::At { channel, t });
                plant.step();
                let mut y = [0.0; 8];
                plant.measure(&mut y);
                out.push((channel, t, y));
            }
            NextSample::Done => return out,
            NextSample::Periodic => panic!("the plant is multi-rate"),
        }
    }
}

#[test]
fn the_run_assigns_each_scan_to_the_first_step_at_or_after_it() {
    let odo: Vec<OdometrySample> = (0..5)
        .map(|i| OdometrySample {
            time: 1.0 + 0.025 * i as f64,
            speed: 1.0,
            steering: 0.0,
        })
        .collect();
    let text = "time_s,scan_index,range_m,bearing_rad,diameter_m\n\
                0.99,0,5,1,0.3\n1.0,1,6,1,0.3\n1.01,2,7,1.5,0.2\n1.01,2,40,1.5,0.2\n\
                1.05,3,8,2,0.5\n1.051,4,9,2,0.5\n";
    let trees = parse_trees(text).unwrap();
    assert_eq!(trees.len(), 6);
    assert_eq!(
        trees[2],
        (
            1.01,
            Tree {
                range: 7.0,
                bearing: 1.5,
                diameter: 0.2
            }
        )
    );
    let gps = [GpsFix {
        time: 1.0,
        x: 2.0,
        y: 3.0,
    }];
    let run = assemble(&odo, &trees, &gps, 1e9, 30.0, 10.0).unwrap();
    // Scans at or before t_0 skipped; the 40 m tree cut; 1.05 is step 2
    // exactly, 1.051 step 3.
    let s: Vec<(usize, usize)> = run.scans.iter().map(|s| (s.step, s.len)).collect();
    assert_eq!(s, vec![(1, 1), (2, 1), (3, 1)]);
    assert_eq!(run.scan_trees(&run.scans[1])[0].range, 8.0);
    assert_eq!(run.steps(), 4);
    assert_eq!(run.start(0.5), Pose::new(2.0, 3.0, 0.5));
    assert!(parse_trees("time_s,scan_index,range_m,bearing_rad,diameter_m\n1,0,0,1,1\n").is_err());
    assert!(parse_trees("time,range\n").is_err());
    assert!(assemble(&odo[..1], &trees, &gps, 1e9, 30.0, 10.0).is_err());
}

#[test]
fn the_plant_streams_the_recording_in_time_order_at_the_speedup() {
    let sys = system();
    let run = &sys.run;
    let samples = replay(&sys);
    assert!(samples.windows(2).all(|w| w[1].1 >= w[0].1));
    let odo: Vec<_> = samples.iter().filter(|s| s.0 == 0).collect();
    assert_eq!(odo.len(), run.steps());
    for (i, s) in odo.iter().enumerate() {
        let k = i + 1;
        assert!((s.1 - (run.times[k] - run.times[0]) / SPEEDUP).abs() < 1e-12);
        assert_eq!([s.2[0], s.2[1]], run.odometry[k]);
    }
    // The expected sequence: each scan of step k as ⌈n/2⌉ samples after
    // odometry sample k − 1, at most the scan's time; then odometry k.
    let mut i = 0;
    let mut scans = run.scans.iter().peekable();
    for k in 1..=run.steps() {
        while let Some(sc) = scans.next_if(|sc| sc.step == k) {
            for pair in run.scan_trees(sc).chunks(2) {
                let (ch, t, y) = samples[i];
                assert_eq!(ch, 1, "sample {i}");
                assert!(t <= (sc.time - run.times[0]) / SPEEDUP + 1e-12);
                assert!(t > (run.times[k - 1] - run.times[0]) / SPEEDUP);
                for (j, tr) in pair.iter().enumerate() {
                    assert_eq!(y[2 + 3 * j..5 + 3 * j], [tr.range, tr.bearing, tr.diameter]);
                }
                if pair.len() == 1 {
                    assert_eq!(y[5..8], [0.0, 0.0, -1.0]);
                }
                i += 1;
            }
        }
        assert_eq!(samples[i].0, 0, "sample {i}");
        i += 1;
    }
    assert_eq!(i, samples.len());
    assert!(run.scans.len() > 100 && run.trees.len() > 2 * run.scans.len());
    // The truth is the latest GPS fix: after odometry sample 40, the fix
    // at step 40.
    let mut plant = VictoriaParkPlant::new(sys.run.clone(), SPEEDUP).unwrap();
    let mut odo = 0;
    while odo < 40 {
        if let NextSample::At { channel: 0, .. } = plant.next_sample() {
            odo += 1;
        }
        plant.step();
    }
    let g = run.gps[5];
    assert_eq!(g.time, run.times[40]);
    assert_eq!(plant.state(), &[g.x, g.y, 0.0]);
}

/// The live backend fed the plant's samples gives, after every odometry
/// sample, the pose of the same filter stepped directly with the recorded
/// intervals, the same returns and the same random numbers.
#[test]
fn live_slam_follows_the_filter_stepped_on_the_recording() {
    let sys = system();
    let cfg = sys.slam_config();
    let samples = replay(&sys);
    let (m, s) = sys.prior();
    let ctx = FilterContext {
        seed: 7,
        sample_dt: DT / SPEEDUP,
        start: Gaussian::diagonal(&m, &s),
        resumed: false,
        t0: 0.0,
    };
    for name in BACKENDS {
        let mut live = LiveSlam::new(name, &cfg, sys.dims(), &ctx)
            .unwrap()
            .unwrap();
        let mut direct: Box<dyn SlamFilter> = match name {
            EKF_SLAM => Box::new(EkfSlam::new(cfg.model).unwrap()),
            FASTSLAM2 => Box::new(FastSlam::new(cfg.model, Version::Two, 20, 0.5).unwrap()),
            IMPLICIT_REFINE_SLAM => Box::new(
                beliefbus_localization::slam::implicit_refine::ImplicitRefineSlam::new(
                    cfg.model, 20, 0.5, cfg.newton,
                )
                .unwrap(),
            ),
            _ => Box::new(ImplicitSlam::new(cfg.model, 20, 0.5, cfg.newton).unwrap()),
        };
        direct.reset(&sys.start);
        // The live stage runs the particle filters with the interval prior.
        direct.set_interval_prior(true);
        let mut rng = crate::rng::stream(7, 0);
        let mut pending: Vec<RangeBearing> = Vec::new();
        let (mut k, mut worst, mut maps) = (0, 0.0f64, 0.0);
        for (ch, t, y) in &samples {
            let comps = &sys.sensor_channels()[*ch].components;
            let mask = ObsMask(comps.iter().map(|c| 1u32 << c).sum());
            live.predict(*t, &[0.0]).unwrap();
            live.update(&Measurement { y, mask, std: None }).unwrap();
            if *ch == 1 {
                for j in 0..2 {
                    if y[4 + 3 * j] != -1.0 {
                        pending.push(RangeBearing {
                            range: y[2 + 3 * j],
                            bearing: y[3 + 3 * j],
                        });
                    }
                }
                continue;
            }
            k += 1;
            let run = &sys.run;
            let v = cfg.model.ute.centre_speed(y[0], y[1]).unwrap();
            let u = Control { v, alpha: y[1] };
            let p = direct
                .step(u, run.times[k] - run.times[k - 1], &pending, &mut rng)
                .unwrap();
            pending.clear();
            let b = live.belief();
            worst = worst.max((b.mean[0] - p[0]).hypot(b.mean[1] - p[1]));
            assert_eq!(b.mean[MAP_COMPONENT], direct.map().len() as f64, "{name}");
            maps = b.mean[MAP_COMPONENT];
        }
        assert_eq!(k, sys.run.steps());
        assert!(worst < 1e-6, "{name}: live vs direct {worst} m");
        // The map: every tree seen, none duplicated (exact returns).
        let seen = synthetic_seen().1 as f64;
        assert!(seen >= 10.0);
        assert_eq!(maps, seen, "{name}");
    }
}

/// Without returns the live particle filters draw no odometry noise
/// (the interval prior defers it to the next returns), so their particles
/// coincide and the pose covariance they publish is the accumulated one,
/// C ← F C Fᵀ + Σ₁: exactly EKF-SLAM's pose covariance after the same
/// predictions.
#[test]
fn between_scans_the_live_particle_filters_publish_the_ekf_pose_covariance() {
    let sys = system();
    let cfg = sys.slam_config();
    let samples = replay(&sys);
    let (m, s) = sys.prior();
    let ctx = FilterContext {
        seed: 3,
        sample_dt: DT / SPEEDUP,
        start: Gaussian::diagonal(&m, &s),
        resumed: false,
        t0: 0.0,
    };
    // Odometry only: the scans are left out, so no step has returns.
    let odometry: Vec<_> = samples
        .iter()
        .filter(|(ch, _, _)| *ch == 0)
        .take(40)
        .collect();
    assert_eq!(odometry.len(), 40);
    let step = |f: &mut LiveSlam, (ch, t, y): &(usize, f64, [f64; 8])| {
        let comps = &sys.sensor_channels()[*ch].components;
        let mask = ObsMask(comps.iter().map(|c| 1u32 << c).sum());
        f.predict(*t, &[0.0]).unwrap();
        f.update(&Measurement { y, mask, std: None }).unwrap();
    };
    const POSE: usize = 3;
    for name in BACKENDS.iter().filter(|&&n| n != EKF_SLAM) {
        let mut live = LiveSlam::new(name, &cfg, sys.dims(), &ctx)
            .unwrap()
            .unwrap();
        let mut ekf = LiveSlam::new(EKF_SLAM, &cfg, sys.dims(), &ctx)
            .unwrap()
            .unwrap();
        for smp in &odometry {
            step(&mut live, smp);
            step(&mut ekf, smp);
            let (a, b) = (live.belief(), ekf.belief());
            for i in 0..POSE {
                for j in 0..POSE {
                    let (x, y) = (a.cov()[j * a.dim + i], b.cov()[j * b.dim + i]);
                    assert!(
                        (x - y).abs() <= 1e-9 * (1.0 + y.abs()),
                        "{name}: cov[{i}][{j}] {x} vs EKF {y}"
                    );
                }
            }
        }
        // Not a comparison of two zeros: the uncertainty has grown.
        let b = ekf.belief();
        let tr: f64 = (0..POSE).map(|i| b.cov()[i * b.dim + i]).sum();
        assert!(tr > 1e-6, "{name}: trace {tr}");
    }
}

#[test]
fn the_error_against_gps_is_scored_at_the_nearest_step() {
    let sys = system();
    let run = &sys.run;
    let fixes = fix_steps(run);
    // GPS every 8 steps at the odometry times: fix f at step 8 f.
    assert!(fixes.iter().all(|&(s, f)| s == 8 * f));
    let mut m = VictoriaParkMetrics::new(&sys);
    // Beliefs 1 m east of the fixes at steps 8 and 16, 3 m at 24; none
    // elsewhere scored.
    for (k, off) in [(8usize, 1.0), (16, 1.0), (24, 3.0), (5, 100.0)] {
        let g = run.gps.iter().find(|g| g.time == run.times[k]);
        let (gx, gy) = g.map_or((0.0, 0.0), |g| (g.x, g.y));
        let x = [gx, gy, 0.0];
        let truth = TruthView {
            seq: (k - 1) as u64,
            channel: ODOMETRY,
            t_ns: 0,
            counted: true,
            x: &x,
            u: &[0.0],
            y: &[0.0, 0.0],
        };
        let mean = [gx + off, gy, 0.0, 12.0];
        m.truth(&truth);
        m.belief(
            &BeliefView {
                sensor_seq: truth.seq,
                sensor_channel: ODOMETRY,
                ess: 10.0,
                filter_ns: 1000,
                mean: &mean,
                cov: &[0.0; 16],
            },
            &truth,
        );
    }
    let r = m.report();
    assert_eq!(r["gps_fixes_scored"], 3);
    let rms = r["gps_rms_m"].as_f64().unwrap();
    assert!((rms - (11.0f64 / 3.0).sqrt()).abs() < 1e-12, "{r}");
    assert_eq!(r["gps_p95_m"].as_f64().unwrap(), 3.0);
    assert_eq!(r["map_landmarks"].as_f64().unwrap(), 12.0);
    assert_eq!(r["steps_reached"], 24);
    // Dead reckoning on this noise-free drive is the true path: 0 error.
    assert!(
        r["dead_reckoning_gps_rms_m"].as_f64().unwrap() < 1e-9,
        "{r}"
    );
}

#[test]
fn a_missing_data_folder_says_where_to_get_the_data() {
    let e = data::load(std::path::Path::new("/nonexistent/vp"), 1e9, 30.0, 10.0).unwrap_err();
    assert!(
        e.contains("victoria_park.htm") && e.contains("data_dir") && e.contains("RFS-SLAM"),
        "{e}"
    );
    let p = VictoriaParkParams {
        speedup: 0.0,
        ..VictoriaParkParams::default()
    };
    assert!(VictoriaParkSystem::from_run(p, synthetic())
        .unwrap_err()
        .contains("speedup"));
}
