//! Wire layouts (offsets, sizes, alignments) and message helpers.

use super::*;
use crate::rt::LatencyHist;
use core::mem::{align_of, offset_of, size_of};

#[test]
fn percentiles_of_a_histogram() {
    assert_eq!(
        Percentiles::from(&LatencyHist::new()),
        Percentiles::default()
    );
    let mut h = LatencyHist::new();
    for v in 1..=10_000u64 {
        h.record(v * 1_000); // 1 µs … 10 ms
    }
    let p = Percentiles::from(&h);
    assert_eq!(p.count, 10_000);
    // 3 significant digits: relative error ≤ 0.1 %.
    for (got, want) in [
        (p.p50_ns, 5_000_000.0),
        (p.p90_ns, 9_000_000.0),
        (p.p99_ns, 9_900_000.0),
        (p.p999_ns, 9_990_000.0),
        (p.max_ns, 10_000_000.0),
    ] {
        assert!((got as f64 - want).abs() / want < 1e-3, "{got} vs {want}");
    }
}

// Sensor ABI v1 is a published contract: these fail at compile time if the
// layout drifts.
const _: () = {
    assert!(size_of::<SensorSample>() == 232);
    assert!(align_of::<SensorSample>() == 8);
    assert!(offset_of!(SensorSample, seq) == 0);
    assert!(offset_of!(SensorSample, t_meas_ns) == 8);
    assert!(offset_of!(SensorSample, t_pub_ns) == 16);
    assert!(offset_of!(SensorSample, channel) == 24);
    assert!(offset_of!(SensorSample, dim) == 28);
    assert!(offset_of!(SensorSample, flags) == 32);
    assert!(offset_of!(SensorSample, reserved0) == 36);
    assert!(offset_of!(SensorSample, values) == 40);
    assert!(offset_of!(SensorSample, noise_std) == 104);
    assert!(offset_of!(SensorSample, reserved) == 168);
    assert!(size_of::<Header>() == 24);
};

#[test]
fn sensor_abi_v1_layout_and_name() {
    assert_eq!(size_of::<SensorSample>(), 232);
    assert_eq!(offset_of!(SensorSample, noise_std), 104);
    // SAFETY: type_name is unsafe only because implementers must keep it
    // unique; reading it is harmless.
    let name = unsafe { <SensorSample as ZeroCopySend>::type_name() };
    assert_eq!(name, "beliefbus.SensorSample.v1");
}

#[test]
fn message_type_names_are_versioned() {
    let names = unsafe {
        [
            <Observation as ZeroCopySend>::type_name(),
            <Belief as ZeroCopySend>::type_name(),
            <Control as ZeroCopySend>::type_name(),
            <Truth as ZeroCopySend>::type_name(),
            <StageStats as ZeroCopySend>::type_name(),
        ]
    };
    for n in names {
        let version = n.rsplit_once(".v").map(|(_, v)| v).unwrap_or("");
        assert!(
            n.starts_with("beliefbus.")
                && !version.is_empty()
                && version.bytes().all(|b| b.is_ascii_digit()),
            "{n}"
        );
    }
}

#[test]
fn trace_hops_need_both_stamps_in_order() {
    let t = Trace {
        t_sensor_pub_ns: 1_000,
        t_ingest_in_ns: 1_500,
        t_ingest_out_ns: 1_700,
        t_filter_in_ns: 2_000,
        t_filter_out_ns: 3_000,
        ..Trace::default()
    };
    assert_eq!(t.hop_ns(Hop::SensorToIngest), Some(500));
    assert_eq!(t.hop_ns(Hop::IngestToFilter), Some(300));
    assert_eq!(t.hop_ns(Hop::SensorToBelief), Some(2_000));
    assert_eq!(t.hop_ns(Hop::FilterToControl), None);
    assert_eq!(t.hop_ns(Hop::SensorToControl), None);
    let backwards = Trace {
        t_sensor_pub_ns: 5,
        t_ingest_in_ns: 4,
        ..Trace::default()
    };
    assert_eq!(backwards.hop_ns(Hop::SensorToIngest), None);
}

#[test]
fn belief_round_trips_a_gaussian() {
    let g = Gaussian::diagonal(&[1.0, -2.0, 0.5], &[0.1, 0.2, 0.3]);
    let mut b = Belief::default();
    b.set_gaussian(&g);
    assert_eq!(b.gaussian(), g);
}

#[test]
fn ids_round_trip() {
    for h in Hop::ALL {
        assert_eq!(Hop::from_id(h as u32), Some(h));
    }
    for s in StageKind::ALL {
        assert_eq!(StageKind::from_id(s as u32), Some(s));
        assert_eq!(StageKind::from_name(s.name()), Some(s));
    }
    assert_eq!(Hop::from_id(0), None);
}

// A miss slot is seven 8-byte words: no padding a C reader could misplace.
const _: () = {
    assert!(size_of::<MissStats>() == 56);
    assert!(align_of::<MissStats>() == 8);
    assert!(offset_of!(MissStats, start_ns) == 0);
    assert!(offset_of!(MissStats, cpu_ns) == 16);
    assert!(offset_of!(MissStats, kind) == 32);
    assert!(offset_of!(MissStats, minor_faults) == 40);
    assert!(offset_of!(MissStats, major_faults) == 48);
};

#[test]
fn a_miss_log_round_trips_through_the_stats_message() {
    use crate::rt::budget::MissKind;
    use crate::rt::miss_log::{Faults, Miss};
    let a = Miss {
        start_ns: 12_345_678_901,
        wall_ns: 115_800,
        cpu_ns: Some(116_400),
        switches: Some(0),
        faults: Some(Faults {
            minor: 240,
            major: 1,
        }),
        kind: MissKind::Overrun,
    };
    let b = Miss {
        start_ns: 12_400_000_000,
        wall_ns: 4_331_000,
        cpu_ns: None,
        switches: None,
        faults: None,
        kind: MissKind::Host,
    };
    let mut s = StageStats::default();
    assert_eq!(s.misses().count(), 0);
    s.miss_log[0] = MissStats::from(&a);
    s.miss_log[1] = MissStats::from(&b);
    assert_eq!(s.miss_log[1].cpu_ns, MISS_UNKNOWN);
    assert_eq!(s.miss_log[0].kind, 1);
    assert_eq!(
        (s.miss_log[0].minor_faults, s.miss_log[0].major_faults),
        (240, 1)
    );
    assert_eq!(
        (s.miss_log[1].minor_faults, s.miss_log[1].major_faults),
        (MISS_UNKNOWN, MISS_UNKNOWN)
    );
    assert_eq!(s.misses().collect::<Vec<_>>(), [a, b]);
    // An unknown kind id ends the list rather than inventing a miss.
    s.miss_log[1].kind = 9;
    assert_eq!(s.misses().collect::<Vec<_>>(), [a]);
}
