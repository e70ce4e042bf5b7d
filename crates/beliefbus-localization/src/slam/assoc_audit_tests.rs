//! The association audit ([`super::assoc_audit`]) through the filters,
//! against counts known from the returns alone: the imposed true
//! association scores no error; gates that accept nothing start a landmark
//! per return, so every re-sighting is a missed association; the tags
//! follow the maps through resampling; and scoring leaves every estimate
//! as it was.

use super::assoc::Association;
use super::assoc_audit::AuditCounts;
use super::diag_tests::{curve_no_gaps, model};
use super::driver::{run_carpark_with, Pick, RunOptions};
use super::ekf::EkfSlam;
use super::fastslam::{FastSlam, Version};
use super::implicit::ImplicitSlam;
use super::implicit_rb::ImplicitRbSlam;
use super::implicit_refine::ImplicitRefineSlam;
use super::particles::SlamParticles;
use super::{SlamFilter, SlamModel};
use crate::carpark::CarPark;
use crate::geometry::Pose;
use crate::mcl::newton::NewtonSettings;
use beliefbus_core::rng::stream;

const M: usize = 5;

/// (filter, maps it scores: M for a particle filter, 1 for EKF-SLAM).
fn filters(m: SlamModel) -> Vec<(Box<dyn SlamFilter>, usize)> {
    let nw = NewtonSettings::default();
    vec![
        (Box::new(EkfSlam::new(m).unwrap()), 1),
        (Box::new(FastSlam::new(m, Version::One, M, 0.5).unwrap()), M),
        (Box::new(FastSlam::new(m, Version::Two, M, 0.5).unwrap()), M),
        (Box::new(ImplicitSlam::new(m, M, 0.5, nw).unwrap()), M),
        (Box::new(ImplicitRbSlam::new(m, M, 0.5, nw).unwrap()), M),
        (Box::new(ImplicitRefineSlam::new(m, M, 0.5, nw).unwrap()), M),
    ]
}

fn run(f: &mut dyn SlamFilter, cp: &CarPark, picks: &[Pick], known: bool) -> Vec<Pose> {
    let opt = RunOptions {
        known_association: known,
        shared_association: false,
        marks: Vec::new(),
    };
    let mut est = vec![Pose::zeros(); cp.steps() + 1];
    run_carpark_with(f, cp, picks, &mut stream(5, 0), &opt, |n, e, _| est[n] = *e).unwrap();
    est
}

/// Imposed truth: every association right, every return scored once per
/// map. Closed gates: every return starts a landmark, so the returns of a
/// landmark seen before are missed associations, exactly
/// (returns − distinct landmarks) per map, and none is wrong.
#[test]
fn known_association_scores_no_error_and_closed_gates_miss_every_resighting() {
    let (cp, picks) = curve_no_gaps();
    let mut seen: Vec<usize> = picks.iter().map(|p| p.landmark).collect();
    seen.sort_unstable();
    seen.dedup();
    let (n, d) = (picks.len(), seen.len());
    assert!(n > 50 && d >= 3 && d < n, "{n} returns of {d} landmarks");
    for (mut f, maps) in filters(model()) {
        run(f.as_mut(), &cp, &picks, true);
        let want = AuditCounts {
            scored: n * maps,
            wrong: 0,
            missed: 0,
        };
        assert_eq!(f.stats().audit, want, "{} known", f.name());
    }
    let mut blind = model();
    blind.assoc.gate = 1e-300;
    blind.assoc.new_threshold = 1e-300;
    for (mut f, maps) in filters(blind) {
        run(f.as_mut(), &cp, &picks, false);
        let want = AuditCounts {
            scored: n * maps,
            wrong: 0,
            missed: (n - d) * maps,
        };
        assert_eq!(f.stats().audit, want, "{} closed gates", f.name());
    }
}

/// Scoring reads the associations and writes only its own tags: the path
/// estimates with and without the truth are the same to the last bit.
#[test]
fn scoring_leaves_the_estimates_unchanged() {
    let (cp, picks) = curve_no_gaps();
    for ((mut a, _), (mut b, _)) in filters(model()).into_iter().zip(filters(model())) {
        let with = run(a.as_mut(), &cp, &picks, false);
        // Without the truth: the same run stepped by hand, never told it.
        b.reset(&cp.truth[0]);
        let mut rng = stream(5, 0);
        let mut it = picks.iter().peekable();
        let mut without = vec![Pose::zeros(); cp.steps() + 1];
        for k in 1..=cp.steps() {
            let dt = cp.times[k] - cp.times[k - 1];
            let z: Vec<_> = it
                .next_if(|p| p.step == k)
                .map(|p| p.z)
                .into_iter()
                .collect();
            without[k] = b.step(cp.controls[k - 1], dt, &z, &mut rng).unwrap();
        }
        assert_eq!(with, without, "{}", a.name());
        assert_eq!(b.stats().audit, AuditCounts::default(), "{}", b.name());
        assert!(a.stats().audit.scored > 0, "{}", a.name());
    }
}

/// Two particles with different tags; a dominant weight on the second
/// copies its map and tags into all; the next step's association with the
/// second's landmark is then right in every particle.
#[test]
fn tags_follow_the_maps_through_resampling() {
    let mut set: SlamParticles<()> = SlamParticles::new(4, 0.5).unwrap();
    set.reset(&Pose::zeros());
    set.audit.set_truth(&[7]);
    for j in 0..4 {
        set.maps[j].push(());
        // Particles 0, 2, 3 tag their entry with 8 (a wrong start), 1 with 7.
        set.audit.set_truth(&[if j == 1 { 7 } else { 8 }]);
        set.audit_particle(j, 0, &[Association::New]);
    }
    set.logw.copy_from_slice(&[0.0, 40.0, 0.0, 0.0]);
    set.reweight(1, &mut stream(1, 0)).unwrap();
    assert_eq!(set.resamplings, 1);
    set.audit.set_truth(&[7]);
    for j in 0..4 {
        set.audit_particle(j, 1, &[Association::Known(0)]);
    }
    let c = set.stats_with(Default::default()).audit;
    assert_eq!(
        c,
        AuditCounts {
            scored: 8,
            wrong: 0,
            missed: 0
        }
    );
    // Without the resampling the three 8-tagged particles would be wrong.
    set.reset(&Pose::zeros());
    for j in 0..4 {
        set.maps[j].push(());
        set.audit.set_truth(&[if j == 1 { 7 } else { 8 }]);
        set.audit_particle(j, 0, &[Association::New]);
    }
    set.audit.set_truth(&[7]);
    for j in 0..4 {
        set.audit_particle(j, 1, &[Association::Known(0)]);
    }
    assert_eq!(set.stats_with(Default::default()).audit.wrong, 3);
}
