//! The ablation and diagnostic hooks: imposed (known) association, ancestor
//! counts and the belief's position spread.

use super::driver::{pick_one_per_scan, run_carpark_with, Pick, RunOptions};
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

/// A 20 s curve at 3 m/s with scans every 0.2 s and no gaps: its car park
/// (data stream 3) and one return picked per scan (stream 4).
pub(super) fn curve_no_gaps() -> (CarPark, Vec<Pick>) {
    let cfg = CarParkConfig {
        start_time: 0.0,
        duration: 20.0,
        gap_every: 0.0,
        motion: model().motion,
        truth_noise: 1.0,
        ..Default::default()
    };
    let cp = CarPark::generate(&straight(20.0), &cfg, &mut stream(3, 0)).unwrap();
    let picks = pick_one_per_scan(&cp, &mut stream(4, 0));
    (cp, picks)
}

/// The Ute with a thousandth of the default control noise, 15 m laser.
pub(super) fn model() -> SlamModel {
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
    let (cp, picks) = curve_no_gaps();
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
                shared_association: false,
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

/// Shared association: with every particle alike it is the per-particle
/// rule; with the particles spread to both sides of the truth it matches a
/// return each particle alone would take for a new landmark; with maps of
/// different lengths it declines.
#[test]
fn shared_association_scores_the_set_and_reduces_to_the_particle_rule() {
    use super::assoc::{innovation, AssocConfig, Association, Chooser, RangeBearing};
    use super::shared_assoc::shared_association;
    use crate::laser::predict;
    use nalgebra::{Matrix2, Matrix3};
    let ute = crate::vehicle::Ute::default();
    let u = Control { v: 2.0, alpha: 0.0 };
    let s0 = Matrix3::from_diagonal(&nalgebra::Vector3::new(1e-4, 1e-4, 1e-6));
    let r = Matrix2::new(0.0025, 0.0, 0.0, 1e-6);
    let cfg = AssocConfig::default();
    let cov = Matrix2::from_diagonal_element(1e-4);
    let truth = Pose::new(0.0, 0.0, 0.0);
    let mk = [0.0, 8.0];
    let f = ute.predict_mean(&truth, u);
    let (range, bearing) = predict(&f, mk);
    let z = RangeBearing { range, bearing };
    let lm = |l: &[f64; 2]| (*l, cov);
    // Every particle at the truth: the per-particle rule's answer.
    let mut set: SlamParticles<[f64; 2]> = SlamParticles::new(4, 0.5).unwrap();
    set.reset(&truth);
    for m in set.maps.iter_mut() {
        m.push(mk);
    }
    let a = shared_association(&set, &ute, u, &s0, &r, &z, &cfg, lm).unwrap();
    let (nu, hx, hm) = innovation(&f, mk, &z);
    let mut ch = Chooser::new();
    ch.offer(
        0,
        &nu,
        &(hx * s0 * hx.transpose() + hm * cov * hm.transpose() + r),
        &cfg,
    );
    assert_eq!(a, ch.decide(&cfg));
    assert_eq!(a, Association::Known(0));
    // Particles 1 m to either side: each alone starts a new landmark.
    for (j, dx) in [-1.0, 1.0, -1.0, 1.0].into_iter().enumerate() {
        set.x[j] = Pose::new(dx, 0.0, 0.0);
        let fj = ute.predict_mean(&set.x[j], u);
        let (nu, hx, hm) = innovation(&fj, mk, &z);
        let mut ch = Chooser::new();
        ch.offer(
            0,
            &nu,
            &(hx * s0 * hx.transpose() + hm * cov * hm.transpose() + r),
            &cfg,
        );
        assert_eq!(ch.decide(&cfg), Association::New);
    }
    let a = shared_association(&set, &ute, u, &s0, &r, &z, &cfg, lm).unwrap();
    assert_eq!(a, Association::Known(0));
    // Maps of different lengths: no shared indexing.
    set.maps[2].push([5.0, 5.0]);
    assert_eq!(
        shared_association(&set, &ute, u, &s0, &r, &z, &cfg, lm),
        None
    );
}

/// Over a run with shared association every particle filter keeps one
/// indexing: all its particles' maps have the same length.
#[test]
fn shared_association_keeps_the_particles_maps_aligned() {
    let rec = straight(20.0);
    let cfg = CarParkConfig {
        start_time: 0.0,
        duration: 20.0,
        gap_every: 10.0,
        gap_len: 1.0,
        motion: model().motion,
        truth_noise: 1.0,
        ..Default::default()
    };
    let cp = CarPark::generate(&rec, &cfg, &mut stream(3, 1)).unwrap();
    let picks = pick_one_per_scan(&cp, &mut stream(4, 1));
    let nw = NewtonSettings::default();
    let m = model();
    let opt = RunOptions {
        known_association: false,
        shared_association: true,
        marks: Vec::new(),
    };
    let mut fs = FastSlam::new(m, Version::Two, 20, 0.5).unwrap();
    run_carpark_with(&mut fs, &cp, &picks, &mut stream(5, 1), &opt, |_, _, _| {}).unwrap();
    let l = lens(&fs.set.maps);
    assert!(l[0] >= 3 && l.iter().all(|&x| x == l[0]), "{l:?}");
    let mut im = ImplicitSlam::new(m, 20, 0.5, nw).unwrap();
    run_carpark_with(&mut im, &cp, &picks, &mut stream(5, 1), &opt, |_, _, _| {}).unwrap();
    let l = lens(&im.set.maps);
    assert!(l[0] >= 3 && l.iter().all(|&x| x == l[0]), "{l:?}");
    let mut rf = ImplicitRefineSlam::new(m, 20, 0.5, nw).unwrap();
    run_carpark_with(&mut rf, &cp, &picks, &mut stream(5, 1), &opt, |_, _, _| {}).unwrap();
    let l = lens(&rf.set.maps);
    assert!(l[0] >= 3 && l.iter().all(|&x| x == l[0]), "{l:?}");
    let mut rb = ImplicitRbSlam::new(m, 20, 0.5, nw).unwrap();
    run_carpark_with(&mut rb, &cp, &picks, &mut stream(5, 1), &opt, |_, _, _| {}).unwrap();
    let l = lens(&rb.set.maps);
    assert!(l[0] >= 3 && l.iter().all(|&x| x == l[0]), "{l:?}");
}

fn lens<L: Clone>(maps: &[super::map::SharedMap<L>]) -> Vec<usize> {
    maps.iter().map(|x| x.len()).collect()
}
