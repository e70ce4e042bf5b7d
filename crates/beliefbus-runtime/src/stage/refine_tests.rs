//! The refiner's bounded work: a version built in slices is the version
//! built at once, and the configuration refuses rounds longer than the
//! stage's budget.

use super::*;
use crate::config::load;
use std::path::Path;

fn cfg(over: &[&str]) -> Result<PipelineConfig, crate::config::ConfigError> {
    let mut o: Vec<String> = vec![
        "refine.max_states=600".into(),
        "refine.initial_states=200".into(),
    ];
    o.extend(over.iter().map(|s| s.to_string()));
    load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/default.toml"),
        &o,
    )
}

fn snapshot(r: &mut Refiner) -> Vec<u64> {
    let mut out = vec![0u64; r.snapshot_words()];
    let n = r.write_snapshot(&mut out, 7).unwrap();
    out.truncate(n);
    out
}

#[test]
fn moving_frame_versions_built_in_slices_are_the_versions_built_at_once() {
    let c = cfg(&[]).unwrap();
    assert!(c.refine.moving_frame);
    let (mut whole, mut sliced) = (Refiner::new(&c, 3).unwrap(), Refiner::new(&c, 3).unwrap());
    for (k, expect) in [(0, 200usize), (1, 600)] {
        whole.work(Duration::ZERO).unwrap();
        assert!(whole.version_ready());
        // Slices of 40 units: each call stops when its count runs out.
        let mut calls = 0;
        loop {
            calls += 1;
            let mut left = 40;
            let done = sliced
                .work_until(|| {
                    left -= 1;
                    left > 0
                })
                .unwrap();
            if done {
                break;
            }
            assert!(sliced.building() && !sliced.version_ready());
        }
        assert_eq!(calls, (2 * expect + 2).div_ceil(40), "version {k}");
        assert!(sliced.version_ready() && !sliced.building());
        assert_eq!(sliced.len(), expect);
        assert_eq!(sliced.delta(), whole.delta());
        // Same bytes but for nothing: same states, rows, P^δ, version.
        assert_eq!(snapshot(&mut sliced), snapshot(&mut whole));
        assert!(!sliced.version_ready());
    }
}

#[test]
fn the_incremental_chains_first_chain_is_built_in_slices_too() {
    let c = cfg(&["refine.moving_frame=false"]).unwrap();
    let mut r = Refiner::new(&c, 4).unwrap();
    let mut calls = 0;
    while !r.work_until(|| false).unwrap() {
        calls += 1;
        assert!(r.is_empty());
    }
    assert_eq!(calls + 1, 2 * 200 + 2);
    assert_eq!(r.len(), 200);
    // Then it grows by `work`, and work_until has nothing to do.
    assert!(!r.work_until(|| true).unwrap());
}

#[test]
fn a_round_longer_than_the_refine_budget_is_refused() {
    let e = cfg(&["refine.work_ms=10", "stages.refine.budget_us=10000"]).unwrap_err();
    assert!(e.to_string().contains("refine.work_ms"), "{e}");
    cfg(&["refine.work_ms=9.9", "stages.refine.budget_us=10000"]).unwrap();
    // No budget: any round length within the period.
    cfg(&["refine.work_ms=10", "stages.refine.budget_us=0"]).unwrap();
}
