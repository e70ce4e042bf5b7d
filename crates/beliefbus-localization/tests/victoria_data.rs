//! The real Victoria Park files, when present (they are third-party and
//! not in the repository): the reader returns the README's counts and
//! spans, and the default car park is a few hundred metres with scans.
//! Skips with a message when the folder is absent.

use beliefbus_core::rng::stream;
use beliefbus_localization::carpark::{CarPark, CarParkConfig};
use beliefbus_localization::victoria::{load, resolve_dir};

#[test]
fn the_recording_has_the_documented_shape() {
    let dir = resolve_dir(None);
    if !dir.join("odometry.csv").exists() {
        eprintln!(
            "skipped: Victoria Park data not found at {} (set BELIEFBUS_VICTORIA_PARK)",
            dir.display()
        );
        return;
    }
    let rec = load(&dir).unwrap();
    assert_eq!(rec.odometry.len(), 61_945);
    assert_eq!(rec.laser_times.len(), 7_249);
    assert_eq!(rec.odometry[0].time, 21.94);
    assert!((rec.odometry.last().unwrap().time - 1570.54).abs() < 1e-9);
    // 40 Hz without gaps.
    assert!(rec
        .odometry
        .windows(2)
        .all(|w| (w[1].time - w[0].time - 0.025).abs() < 1e-6));
    let cp = CarPark::generate(&rec, &CarParkConfig::default(), &mut stream(1, 0)).unwrap();
    assert_eq!(cp.steps(), 4_799);
    let len = cp.path_length();
    assert!((250.0..600.0).contains(&len), "path {len} m");
    assert!(cp.scans.len() > 400, "{} scans", cp.scans.len());
}
