//! The existence rule ([`super::existence`]): the stated removal time, the
//! stated keeping rate, no penalty outside the field of view, and exact
//! agreement of every particle filter with the rule on and off when every
//! landmark predicted in view is observed.

use super::assoc::{Association, RangeBearing};
use super::existence::ExistenceConfig;
use super::fastslam::{FastSlam, Version};
use super::implicit::ImplicitSlam;
use super::implicit_rb::ImplicitRbSlam;
use super::implicit_refine::ImplicitRefineSlam;
use super::map::SharedMap;
use super::{SlamFilter, SlamModel};
use crate::geometry::{wrap_angle, Point, Pose};
use crate::mcl::newton::NewtonSettings;
use crate::vehicle::Control;
use beliefbus_core::rng::stream;
use std::f64::consts::FRAC_PI_2;

fn cfg() -> ExistenceConfig {
    // start 1, hit 1, miss 0.25, confirm 3; 15 m half circle, 1 m margin.
    ExistenceConfig::half_circle(15.0)
}

/// Run the rule on a one-landmark map for `scans` scans from pose x,
/// associating the landmark in the scans where `seen(scan)`; the map's
/// length after each scan.
fn run_one(m: Point, x: Pose, scans: usize, seen: impl Fn(usize) -> bool) -> Vec<usize> {
    let c = cfg();
    let mut map: SharedMap<Point> = SharedMap::new();
    let mut ev: SharedMap<f32> = SharedMap::new();
    // The scan that starts it.
    map.push(m);
    c.apply(&mut map, &mut ev, 0, &x, &[Association::New], |p| *p);
    let mut lens = Vec::new();
    for s in 0..scans {
        let before = map.len();
        let a: &[Association] = if before > 0 && seen(s) {
            &[Association::Known(0)]
        } else {
            &[Association::Discard]
        };
        c.apply(&mut map, &mut ev, before, &x, a, |p| *p);
        lens.push(map.len());
    }
    lens
}

#[test]
fn a_landmark_in_view_and_never_seen_again_goes_after_start_over_miss_scans() {
    let x = Pose::new(0.0, 0.0, 0.0);
    // 8 m straight ahead (heading 0 looks along +x).
    assert!(cfg().in_view(&x, [8.0, 0.0]));
    let lens = run_one([8.0, 0.0], x, 6, |_| false);
    // start / miss = 1 / 0.25 = 4 scans.
    assert_eq!(lens, vec![1, 1, 1, 0, 0, 0]);
}

#[test]
fn a_landmark_seen_at_more_than_miss_over_hit_plus_miss_is_kept() {
    let x = Pose::new(0.0, 0.0, 0.0);
    // Seen every 4th scan (rate 1/4 > 0.25/1.25 = 1/5): 1 → 0.25 → 1.25 →
    // … never reaches 0 and is confirmed after the third sighting.
    let lens = run_one([8.0, 0.0], x, 400, |s| s % 4 == 3);
    assert!(lens.iter().all(|&l| l == 1));
    // Seen every 5th scan (rate 1/5): four misses take 1 to 0 first.
    let lens = run_one([8.0, 0.0], x, 10, |s| s % 5 == 4);
    assert_eq!(lens[3], 0);
}

#[test]
fn a_landmark_outside_the_field_of_view_is_never_penalised() {
    let c = cfg();
    let x = Pose::new(1.0, 2.0, 0.7);
    // Behind, beyond the range, inside the edge margins: all out of view.
    let far = [x[0] + 14.5 * 0.7f64.cos(), x[1] + 14.5 * 0.7f64.sin()];
    let behind = [x[0] - 5.0 * 0.7f64.cos(), x[1] - 5.0 * 0.7f64.sin()];
    let b = 0.7 - FRAC_PI_2 + 0.05; // 0.05 rad inside the right edge, at 8 m
    let edge = [x[0] + 8.0 * b.cos(), x[1] + 8.0 * b.sin()];
    for m in [far, behind, edge] {
        assert!(!c.in_view(&x, m), "{m:?}");
        let lens = run_one(m, x, 1000, |_| false);
        assert!(lens.iter().all(|&l| l == 1));
    }
    // The evidence is untouched: a landmark never in view keeps `start`.
    let mut map: SharedMap<Point> = SharedMap::new();
    let mut ev: SharedMap<f32> = SharedMap::new();
    map.push(behind);
    c.apply(&mut map, &mut ev, 0, &x, &[Association::New], |p| *p);
    for _ in 0..50 {
        c.apply(&mut map, &mut ev, 1, &x, &[], |p| *p);
    }
    assert_eq!(ev.get(0), Some(&c.start));
}

#[test]
fn removal_keeps_the_other_landmarks_and_their_evidence() {
    let c = cfg();
    let x = Pose::new(0.0, 0.0, 0.0);
    let mut map: SharedMap<Point> = SharedMap::new();
    let mut ev: SharedMap<f32> = SharedMap::new();
    // 0 and 2 in view, 1 behind; 0 is never seen again, 2 always.
    for m in [[8.0, 1.0], [-6.0, 0.0], [9.0, -2.0]] {
        map.push(m);
    }
    let new = [Association::New; 3];
    c.apply(&mut map, &mut ev, 0, &x, &new, |p| *p);
    let mut removed = 0;
    for _ in 0..4 {
        let k2 = (0..map.len()).find(|&k| map.get(k) == Some(&[9.0, -2.0]));
        let a = [Association::Known(k2.unwrap())];
        let before = map.len();
        removed += c.apply(&mut map, &mut ev, before, &x, &a, |p| *p);
    }
    assert_eq!(removed, 1);
    let left: Vec<Point> = map.iter().copied().collect();
    assert_eq!(left, vec![[9.0, -2.0], [-6.0, 0.0]]);
    // [9, −2] was confirmed (1 + 2 hits ≥ 3), [−6, 0] never touched.
    assert_eq!(ev.get(0), Some(&f32::INFINITY));
    assert_eq!(ev.get(1), Some(&c.start));
}

/// The exact (noise-free) return of landmark m from pose x.
fn exact_return(x: &Pose, m: Point) -> RangeBearing {
    let (d1, d2) = (m[0] - x[0], m[1] - x[1]);
    RangeBearing {
        range: d1.hypot(d2),
        bearing: wrap_angle(d2.atan2(d1) - x[2] + FRAC_PI_2),
    }
}

fn filters(model: SlamModel) -> Vec<Box<dyn SlamFilter>> {
    let n = NewtonSettings::default();
    vec![
        Box::new(ImplicitSlam::new(model, 20, 0.5, n).unwrap()),
        Box::new(ImplicitRefineSlam::new(model, 20, 0.5, n).unwrap()),
        Box::new(ImplicitRbSlam::new(model, 20, 0.5, n).unwrap()),
        Box::new(FastSlam::new(model, Version::One, 20, 0.5).unwrap()),
        Box::new(FastSlam::new(model, Version::Two, 20, 0.5).unwrap()),
    ]
}

/// Drive slowly along +x past four trees kept well inside the field of
/// view, every one returned at every scan (every 8th step); with `clutter`
/// the first scan also holds a return from nothing, far from the trees.
/// The path and the final map (sorted) and the landmarks removed.
fn drive(f: &mut dyn SlamFilter, clutter: bool) -> (Vec<Pose>, Vec<Point>, usize) {
    let trees = [[10.0, 3.0], [11.0, -4.0], [13.0, 1.0], [12.5, -1.5]];
    let ute = crate::vehicle::Ute::default();
    let u = Control { v: 1.0, alpha: 0.0 };
    let mut truth = Pose::new(0.0, 0.0, 0.0);
    f.reset(&truth);
    let mut rng = stream(11, 0);
    let mut path = Vec::new();
    for step in 0..160 {
        truth = ute.predict_mean(&truth, u);
        let mut obs: Vec<RangeBearing> = Vec::new();
        if step % 8 == 0 {
            obs.extend(trees.iter().map(|&m| exact_return(&truth, m)));
            if clutter && step == 0 {
                obs.push(exact_return(&truth, [7.0, 6.0]));
            }
        }
        path.push(f.step(u, 0.025, &obs, &mut rng).unwrap());
    }
    let mut map = f.map();
    map.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    (path, map, f.stats().removed)
}

#[test]
fn every_particle_filter_is_unchanged_by_the_rule_when_every_landmark_in_view_is_seen() {
    let model = super::diag_tests::model();
    for (mut off, mut on) in filters(model).into_iter().zip(filters(model)) {
        assert!(on.set_existence(Some(cfg())).unwrap());
        let (p0, m0, r0) = drive(off.as_mut(), false);
        let (p1, m1, r1) = drive(on.as_mut(), false);
        assert_eq!(m0.len(), 4, "{}", off.name());
        assert_eq!((r0, r1), (0, 0));
        assert_eq!(p0, p1, "{}", off.name());
        assert_eq!(m0, m1, "{}", off.name());
        // A clutter return: with the rule every particle drops its
        // landmark after four scans; since nothing was associated with
        // it, the path and the other landmarks are still exactly those
        // without the rule.
        let (p2, m2, r2) = drive(off.as_mut(), true);
        let (p3, m3, r3) = drive(on.as_mut(), true);
        assert_eq!(r2, 0);
        assert_eq!(r3, 20, "{}", on.name());
        assert_eq!(m2.len(), 5, "{}", off.name());
        let trees: Vec<Point> = m2
            .iter()
            .copied()
            .filter(|m| (m[0] - 7.0).hypot(m[1] - 6.0) > 1.0)
            .collect();
        assert_eq!(m3, trees, "{}", on.name());
        assert_eq!(p2, p3, "{}", on.name());
    }
}
