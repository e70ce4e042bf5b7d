//! The registry's own checks.
use super::*;

/// Every experiment says what it reproduces, and no key is listed
/// twice (a second row would shadow the first in `--help`).
#[test]
fn every_entry_is_documented_once() {
    let all = all();
    assert_eq!(all.len(), 28, "the registry lost or gained an entry");
    for e in &all {
        assert!(
            !e.reproduces.is_empty() && !e.about.is_empty(),
            "{}",
            e.name
        );
        for (i, d) in e.params.iter().enumerate() {
            assert!(!d.help.is_empty(), "{}: {}", e.name, d.key);
            assert!(
                e.params[i + 1..].iter().all(|o| o.key != d.key),
                "{}: {} twice",
                e.name,
                d.key
            );
        }
    }
}
