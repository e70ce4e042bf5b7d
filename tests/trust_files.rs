//! The files a run writes and a runaway real-time stage (docs/security.md),
//! tried as a hostile local user and a faulty stage would, through the real
//! launcher. Waits are liveness guards only, never timing assertions.

mod launcher_support;

use beliefbus::ipc::cleanup;
use beliefbus::rt::files::{runtime_base, PrivateDir};
use launcher_support::Run;
use std::os::unix::fs::symlink;
use std::path::Path;

fn is_link(p: &Path) -> bool {
    std::fs::symlink_metadata(p).is_ok_and(|m| m.file_type().is_symlink())
}

#[test]
fn a_link_planted_at_the_report_path_is_replaced_not_followed() {
    let d = PrivateDir::create("bb-trust-report-").unwrap();
    let victim = d.path().join("victim");
    std::fs::write(&victim, b"precious").unwrap();
    let report = d.path().join("report.json");
    symlink(&victim, &report).unwrap();
    let r = Run::start(&[
        "run",
        "--quiet",
        "--duration",
        "1",
        "--report",
        report.to_str().unwrap(),
    ]);
    let (status, log) = r.wait();
    assert!(status.success(), "{}", log.join("\n"));
    assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
    assert!(!is_link(&report));
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    assert!(json["stages"]["filter"]["processed"].as_u64().unwrap() > 0);
}

#[test]
fn a_state_directory_planted_at_the_old_predictable_name_is_never_used() {
    // With --sensor external the prefix is the config's, known in advance:
    // the old state directory was `<temp>/<prefix>state`, reused as found.
    let prefix = format!("iox2_bbtrust{}_", std::process::id());
    let d = PrivateDir::create("bb-trust-state-").unwrap();
    let victim = d.path().join("victim");
    std::fs::write(&victim, b"precious").unwrap();
    let planted = std::env::temp_dir().join(format!("{prefix}state"));
    let _ = std::fs::remove_dir_all(&planted);
    std::fs::create_dir(&planted).unwrap();
    let names = [
        "filter.resume.json",
        "filter.resume.tmp",
        "refine.resume.tmp",
        "refine.ckpt",
        "refine.tmp",
    ];
    for n in names {
        symlink(&victim, planted.join(n)).unwrap();
    }
    let r = Run::start(&[
        "run",
        "--quiet",
        "--sensor",
        "external",
        "--duration",
        "2",
        "--set",
        &format!("run.prefix=\"{prefix}\""),
    ]);
    let (status, log) = r.wait();
    let left_dirs: Vec<_> = std::fs::read_dir(runtime_base())
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(&format!("{prefix}state.")))
        .collect();
    let planted_ok = names.iter().all(|n| is_link(&planted.join(n)));
    std::fs::remove_dir_all(&planted).unwrap();
    let _ = cleanup::remove_prefix(&prefix);
    assert!(status.success(), "{}", log.join("\n"));
    assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
    assert!(planted_ok, "the planted links were replaced or removed");
    assert!(
        left_dirs.is_empty(),
        "private state dirs left: {left_dirs:?}"
    );
    assert!(cleanup::resources(&prefix).is_empty());
}

/// The plant, SCHED_FIFO 80 on core 0 in the default config, busy-loops one
/// second into the run; ingest and the filter share its core at lower FIFO
/// priorities and get no CPU. The run must still end by itself at its
/// duration: the runaway is stopped (its real-time CPU limit, or the
/// supervisor's escalation) and restarted, and nothing is left behind.
#[test]
fn a_runaway_real_time_stage_does_not_wedge_the_run() {
    let d = PrivateDir::create("bb-trust-spin-").unwrap();
    let report = d.path().join("report.json");
    let mut r = Run::start(&[
        "run",
        "--quiet",
        "--duration",
        "6",
        "--chaos-spin",
        "plant:1",
        "--report",
        report.to_str().unwrap(),
    ]);
    let prefix = r.prefix();
    let (status, log) = r.wait();
    let text = log.join("\n");
    let pids: Vec<i32> = log
        .iter()
        .filter(|l| l.contains("(pid "))
        .map(|l| launcher_support::pid_of(l))
        .collect();
    assert!(text.contains("fault injection: will busy-loop"), "{text}");
    assert!(status.success(), "{text}");
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let plant = &json["stages"]["plant"];
    let deaths = plant["deaths"].as_array().cloned().unwrap_or_default();
    assert!(
        !deaths.is_empty(),
        "the runaway plant was neither stopped nor restarted: {plant}\n{text}"
    );
    // Every process the run started is gone, and its shared memory.
    for pid in pids {
        // SAFETY: signal 0 only checks for existence.
        let alive = unsafe { libc::kill(pid, 0) } == 0;
        assert!(!alive, "pid {pid} of the run is still alive\n{text}");
    }
    assert!(cleanup::resources(&prefix).is_empty());
}
