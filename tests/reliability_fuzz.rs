//! Message validation under arbitrary input, by property
//! tests (proptest): whatever bytes a sensor publisher puts into a
//! `SensorSample`, ingest's validator never panics, accepts only samples
//! that satisfy every rule of docs/sensor-abi.md, and a rejected sample
//! never blocks the good ones after it. The filters' input checks and the
//! supervisor's resume state hold up the same way.

use beliefbus::filter::ekf::Ekf;
use beliefbus::filter::BayesFilter;
use beliefbus::ipc::{Observation, SensorSample, SENSOR_MAX_DIM};
use beliefbus::model::{Measurement, ObsMask};
use beliefbus::pipeline::config;
use beliefbus::pipeline::supervisor_resume::ResumeBelief;
use beliefbus::stage::ingest::Validator;
use proptest::prelude::*;
use std::path::Path;

fn cfg() -> beliefbus::pipeline::PipelineConfig {
    config::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/default.toml"),
        &[],
    )
    .unwrap()
}

/// Any f64, with the special values well represented.
fn any_f64() -> impl Strategy<Value = f64> {
    prop_oneof![
        any::<f64>(),
        -1e3f64..1e3,
        Just(f64::NAN),
        Just(f64::INFINITY),
        Just(f64::NEG_INFINITY),
        Just(0.0),
        Just(-0.0),
        Just(f64::MIN_POSITIVE / 2.0),
    ]
}

prop_compose! {
    fn any_sample()(
        seq in any::<u64>(),
        t_meas in prop_oneof![any::<u64>(), 0u64..4_000_000_000],
        t_pub in any::<u64>(),
        channel in prop_oneof![any::<u32>(), 0u32..3],
        dim in prop_oneof![any::<u32>(), 0u32..10],
        flags in any::<u32>(),
        values in prop::array::uniform8(any_f64()),
        std in prop::array::uniform8(any_f64()),
    ) -> SensorSample {
        SensorSample {
            seq, t_meas_ns: t_meas, t_pub_ns: t_pub, channel, dim, flags,
            values, noise_std: std, ..SensorSample::default()
        }
    }
}

const NOW: u64 = 2_000_000_000;

fn good(seq: u64, t: u64) -> SensorSample {
    SensorSample::new(0, seq, t, &[3.0, 0.1])
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn ingest_accepts_only_valid_samples_and_recovers_after_bad_ones(
        samples in prop::collection::vec(any_sample(), 1..20)
    ) {
        let c = cfg();
        let mut v = Validator::new(&c).unwrap();
        let mut o = Observation::default();
        let mut last_t = 0u64;
        let mut last_seq = None;
        for s in &samples {
            if v.check(s, NOW, &mut o).is_ok() {
                // Every rule of the ABI holds for what was accepted.
                prop_assert_eq!(s.channel, 0);
                prop_assert_eq!(s.dim as usize, 2);
                prop_assert!(s.values[..2].iter().all(|x| x.is_finite()));
                if s.has_noise_std() {
                    prop_assert!(s.noise_std[..2].iter().all(|x| x.is_finite() && *x > 0.0));
                }
                prop_assert!(s.t_meas_ns > 0 && s.t_meas_ns >= last_t);
                prop_assert!(NOW.saturating_sub(s.t_meas_ns) <= 500_000_000);
                prop_assert!(s.t_meas_ns <= NOW + 500_000_000);
                prop_assert!(last_seq.is_none_or(|l| s.seq > l));
                prop_assert_eq!(&o.y[..2], &s.values[..2]);
                last_t = s.t_meas_ns;
                last_seq = Some(s.seq);
            }
        }
        // A good sample a second later, numbered next after the last
        // accepted one, is accepted whatever came before (rejected samples,
        // huge sequence jumps among them, poison nothing); unless an
        // accepted one already used the last sequence number.
        let later = NOW + 1_000_000_000;
        prop_assert!(last_t <= later);
        if last_seq != Some(u64::MAX) {
            let next = last_seq.map_or(0, |l| l + 1);
            let r = v.check(&good(next, later), later, &mut o);
            prop_assert!(r.is_ok(), "{:?}", r);
        }
    }

    #[test]
    fn dims_above_the_abi_maximum_are_rejected_not_truncated(
        n in (SENSOR_MAX_DIM + 1)..64usize, x in -10.0f64..10.0
    ) {
        let c = cfg();
        let mut v = Validator::new(&c).unwrap();
        let vals = vec![x; n];
        let s = SensorSample::new(0, 0, NOW, &vals);
        prop_assert_eq!(s.dim as usize, n);
        prop_assert!(v.check(&s, NOW, &mut Observation::default()).is_err());
    }

    #[test]
    fn the_filter_refuses_bad_measurements_with_a_typed_error(
        y in prop::array::uniform2(any_f64()),
        std in prop::option::of(prop::array::uniform2(any_f64())),
        mask in any::<u32>(),
        // Times a filter can reach: a prediction costs one substep per
        // `max_dt`, so a time far in the future (ingest rejects those) would
        // only take long, not fail.
        t in prop_oneof![-1.0f64..5.0, Just(f64::NAN), Just(f64::INFINITY)],
    ) {
        let c = cfg();
        let model = c.model().unwrap();
        let mut f = Ekf::new(model, &c.filter.ekf, &c.prior(), 0.0).unwrap();
        // Never a panic: Ok or a typed FilterError.
        let _ = f.predict(t, &[0.0, 0.0]);
        let meas = Measurement { y: &y, mask: ObsMask(mask), std: std.as_ref().map(|s| &s[..]) };
        if f.update(&meas).is_ok() {
            let b = f.belief();
            prop_assert!(b.mean[..4].iter().all(|m| m.is_finite()));
        }
    }

    #[test]
    fn a_resume_belief_is_used_only_when_consistent(
        dim in 0u32..12,
        mean in prop::collection::vec(any_f64(), 0..12),
        cov in prop::collection::vec(any_f64(), 0..150),
    ) {
        let rb = ResumeBelief { seq: 0, t_valid_ns: 0, dim, mean: mean.clone(), cov: cov.clone() };
        if let Some(g) = rb.gaussian() {
            let d = dim as usize;
            prop_assert_eq!(g.dim, d);
            prop_assert!(mean.len() == d && cov.len() == d * d);
            prop_assert!(mean.iter().chain(&cov).all(|v| v.is_finite()));
        }
    }
}
