//! The ablation and diagnostic hooks: imposed (known) association, ancestor
//! counts and the belief's position spread.

use super::driver::{pick_one_per_scan, run_carpark_with, RunOptions};
use super::ekf::EkfSlam;
use super::fastslam::{FastSlam, Version};
use super::implicit::ImplicitSlam;
use super::implicit_rb::ImplicitRbSlam;
use super::implicit_refine::ImplicitRefineSlam;
use super::particles::SlamParticles;
use super::{SlamFilter, SlamModel};
use crate::carpark::{CarPark, CarParkConfig};
use crate::geometry::Pose;
use crate::laser::LaserNoise;
use crate::mcl::newton::NewtonSettings;
use crate::vehicle::{Control, MotionNoise};
use crate::victoria::{OdometrySample, Recording};
use beliefbus_core::rng::stream;

fn straight(secs: f64) -> Recording {
    let n = (secs / 0.025) as usize;
    Recording {
        odometry: (0..n)
            .map(|i| OdometrySample {
                time: i as f64 * 0.025,
                speed: 3.0,
                steering: 0.05,
            })
            .collect(),
        laser_times: (0..(secs / 0.2) as usize)
            .map(|i| 0.01 + i as f64 * 0.2)
            .collect(),
    }
}

fn model() -> SlamModel {
    let d = MotionNoise::default();
    SlamModel {
        ute: Default::default(),
        motion: MotionNoise {
            p: d.p.map(|v| v * 1e-3),
            q: d.q.map(|v| v * 1e-3),
        },
        laser: LaserNoise::default(),
        assoc: Default::default(),
        max_range: 15.0,
    }
}

/// With the association imposed, every filter's map holds exactly one
/// landmark per true landmark seen, in the order of first sighting, each
/// nearest its true one; with the ML rule but gates that accept nothing, the
/// same returns start a landmark each, so the imposed association is what
/// decides.
#[test]
fn imposed_association_gives_one_landmark_per_true_landmark_in_order() {
    let rec = straight(20.0);
    let cfg = CarParkConfig {
        start_time: 0.0,
        duration: 20.0,
        gap_every: 0.0,
        motion: model().motion,
        truth_noise: 1.0,
        ..Default::default()
    };
    let cp = CarPark::generate(&rec, &cfg, &mut stream(3, 0)).unwrap();
    let picks = pick_one_per_scan(&cp, &mut stream(4, 0));
    let mut order: Vec<usize> = Vec::new();
    for p in &picks {
        if !order.contains(&p.landmark) {
            order.push(p.landmark);
        }
    }
    assert!(order.len() >= 3, "too few landmarks seen: {}", order.len());
    // Gates that accept no landmark: the ML rule alone would start one per
    // return.
    let mut blind = model();
    blind.assoc.gate = 1e-300;
    blind.assoc.new_threshold = 1e-300;
    let nw = NewtonSettings::default();
    let filters: Vec<Box<dyn SlamFilter>> = vec![
        Box::new(EkfSlam::new(blind).unwrap()),
        Box::new(FastSlam::new(blind, Version::One, 5, 0.5).unwrap()),
        Box::new(FastSlam::new(blind, Version::Two, 5, 0.5).unwrap()),
        Box::new(ImplicitSlam::new(blind, 5, 0.5, nw).unwrap()),
        Box::new(ImplicitRbSlam::new(blind, 5, 0.5, nw).unwrap()),
        Box::new(ImplicitRefineSlam::new(blind, 5, 0.5, nw).unwrap()),
    ];
    for mut f in filters {
        for known in [false, true] {
            let opt = RunOptions {
                known_association: known,
                marks: Vec::new(),
            };
            run_carpark_with(
                f.as_mut(),
                &cp,
                &picks,
                &mut stream(5, 0),
                &opt,
                |_, _, _| {},
            )
            .unwrap();
            let map = f.map();
            if !known {
                assert_eq!(map.len(), picks.len(), "{}: ML with closed gates", f.name());
                continue;
            }
            assert_eq!(map.len(), order.len(), "{}", f.name());
            // The k-th landmark is nearest the k-th true landmark seen.
            for (m, &l) in map.iter().zip(&order) {
                let dist = |t: &[f64; 2]| (m[0] - t[0]).hypot(m[1] - t[1]);
                let nearest = (0..cp.landmarks.len())
                    .min_by(|&a, &b| dist(&cp.landmarks[a]).total_cmp(&dist(&cp.landmarks[b])))
                    .unwrap();
                assert_eq!(nearest, l, "{}: landmark {l}", f.name());
            }
        }
    }
}

/// Ancestor labels follow the particles through resampling: one dominant
/// weight leaves one ancestor, even weights (no resampling) leave all.
#[test]
fn ancestor_counts_follow_resampling() {
    let mut set: SlamParticles<()> = SlamParticles::new(6, 0.5).unwrap();
    set.reset(&Pose::zeros());
    assert_eq!(set.distinct_ancestors(0), 6);
    set.logw.copy_from_slice(&[0.0, 0.0, 0.0, 0.0, 40.0, 0.0]);
    set.reweight(1, &mut stream(1, 0)).unwrap();
    assert_eq!(set.resamplings, 1);
    for slot in 0..super::particles::LINEAGE_SLOTS {
        assert_eq!(set.distinct_ancestors(slot), 1);
    }
    set.mark_ancestors(2);
    assert_eq!(set.distinct_ancestors(2), 6);
    assert_eq!(set.distinct_ancestors(1), 1);
    // Even weights: ESS = M, no resampling, labels unchanged.
    set.logw.fill(0.0);
    set.reweight(2, &mut stream(1, 1)).unwrap();
    assert_eq!(set.resamplings, 1);
    assert_eq!(set.distinct_ancestors(2), 6);
}

/// The particle cloud's spread is the weighted RMS distance to its mean;
/// EKF-SLAM's is √(trace of its position covariance), which after one
/// prediction from a known pose is that of one step's noise Σ₁.
#[test]
fn position_spread_is_the_weighted_rms_distance_and_the_ekf_trace() {
    let mut set: SlamParticles<()> = SlamParticles::new(2, 0.0).unwrap();
    set.x[0] = Pose::new(0.0, 0.0, 0.0);
    set.x[1] = Pose::new(3.0, 4.0, 1.0);
    set.w.copy_from_slice(&[0.75, 0.25]);
    // Mean (0.75, 1.0); squared distances 0.5625 + 1 and 5.0625 + 9.
    let want = (0.75 * 1.5625 + 0.25 * 14.0625f64).sqrt();
    assert!((set.position_spread() - want).abs() < 1e-12);
    let m = model();
    let mut ekf = EkfSlam::new(m).unwrap();
    ekf.reset(&Pose::new(1.0, 2.0, 0.3));
    assert_eq!(ekf.position_spread(), 0.0);
    let u = Control { v: 3.0, alpha: 0.1 };
    ekf.step(u, 0.025, &[], &mut stream(1, 2)).unwrap();
    let (_, noise) = m.step_noise(u, 0.025).unwrap();
    let s1 = super::fastslam::world_step_cov(&noise.chol, 0.3);
    let want = (s1[(0, 0)] + s1[(1, 1)]).sqrt();
    assert!(
        (ekf.position_spread() - want).abs() < 1e-12 * (1.0 + want),
        "{} vs {want}",
        ekf.position_spread()
    );
}
