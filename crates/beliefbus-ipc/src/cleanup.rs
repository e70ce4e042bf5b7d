//! Removing every shared-memory resource of a prefix, including those of
//! crashed participants.
//!
//! iceoryx2 keeps data segments and management records in `/dev/shm` and
//! static service/node records under its root path (`/tmp/iceoryx2/`), every
//! file name starting with the prefix. A cleanly dropped node removes its
//! own files except the prefix-wide `…global_mgmt` segment; a killed one
//! leaves everything. [`remove_prefix`] first lets iceoryx2 remove the stale
//! resources of dead nodes (it also detaches them from the services), then —
//! only when no node of the prefix is alive — unlinks whatever file of the
//! prefix is left.
//!
//! Run prefixes made by [`run_prefix`] embed the creating process id, so
//! [`sweep_stale_runs`] can remove what earlier crashed runs left behind
//! without touching a run that is still going.

use super::IpcError;
use iceoryx2::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Stem of every prefix made by [`run_prefix`]. The `-` cannot occur in a
/// file name of iceoryx2's default prefix (`iox2_` + hex), so a sweep never
/// mistakes someone else's resources for ours.
pub const RUN_STEM: &str = "iox2_bb-";

/// Directory of POSIX shared memory.
const SHM_DIR: &str = "/dev/shm";

/// A fresh prefix for one run or test: `iox2_bb-<pid>-<nonce>_` (hex).
pub fn run_prefix() -> String {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let pid = std::process::id();
    let t = crate::rt::clock::now_ns();
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let nonce = crate::rng::splitmix64(t ^ (n << 48) ^ pid as u64) & 0xffff_ffff;
    format!("{RUN_STEM}{pid:x}-{nonce:08x}_")
}

/// The process id a run prefix was made by, if it is one.
pub fn run_prefix_pid(prefix: &str) -> Option<u32> {
    let rest = prefix.strip_prefix(RUN_STEM)?;
    let (pid, _) = rest.split_once('-')?;
    u32::from_str_radix(pid, 16).ok()
}

/// What a cleanup found and did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct CleanupReport {
    /// Nodes of the prefix still alive (their files were left alone).
    pub alive_nodes: usize,
    /// Dead nodes whose stale resources iceoryx2 removed.
    pub dead_nodes_removed: usize,
    /// Dead nodes iceoryx2 could not clean up.
    pub dead_nodes_failed: usize,
    /// Files unlinked afterwards.
    pub files_removed: usize,
}

fn iox_config(prefix: &str) -> Result<Config, IpcError> {
    super::init_logging();
    super::validate_prefix(prefix)?;
    let mut c = Config::global_config().clone();
    c.global.prefix = FileName::new(prefix.as_bytes()).map_err(|e| IpcError::InvalidName {
        what: "prefix",
        value: prefix.to_string(),
        reason: format!("{e:?}"),
    })?;
    Ok(c)
}

/// Let iceoryx2 remove the stale resources of the dead nodes of `prefix`.
/// Returns (alive, removed, failed) node counts.
pub fn remove_dead_nodes(prefix: &str) -> Result<(usize, usize, usize), IpcError> {
    super::init_logging();
    let cfg = iox_config(prefix)?;
    let (mut alive, mut removed, mut failed) = (0, 0, 0);
    Node::<ipc::Service>::list(&cfg, |state| {
        match state {
            NodeState::Alive(_) => alive += 1,
            NodeState::Dead(view) => match view.try_remove_stale_resources() {
                Ok(()) => removed += 1,
                Err(_) => failed += 1,
            },
            // Not ours to judge: count it as alive so its files are kept.
            NodeState::Inaccessible(_) | NodeState::Undefined(_) => alive += 1,
        }
        CallbackProgression::Continue
    })
    .map_err(|e| IpcError::Cleanup {
        prefix: prefix.to_string(),
        reason: format!("{e:?}"),
    })?;
    Ok((alive, removed, failed))
}

fn collect(dir: &Path, prefix: &str, depth: usize, out: &mut Vec<PathBuf>) {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return;
    };
    for e in rd.flatten() {
        let p = e.path();
        let name = e.file_name();
        let is_dir = e.file_type().map(|t| t.is_dir()).unwrap_or(false);
        if name.to_string_lossy().starts_with(prefix) {
            out.push(p);
        } else if is_dir && depth > 0 {
            collect(&p, prefix, depth - 1, out);
        }
    }
}

/// The files of `prefix` in `/dev/shm` and under iceoryx2's root path.
pub fn resources(prefix: &str) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if prefix.is_empty() {
        return out;
    }
    collect(Path::new(SHM_DIR), prefix, 0, &mut out);
    collect(&root_path(), prefix, 3, &mut out);
    out.sort();
    out
}

/// iceoryx2's root path (`/tmp/iceoryx2` unless configured).
pub fn root_path() -> PathBuf {
    super::init_logging();
    PathBuf::from(
        Config::global_config()
            .global
            .root_path()
            .as_string()
            .to_string(),
    )
}

/// The root path, when it exists, must be trustworthy: a real directory
/// (not a link) owned by this user or by root, writable by nobody else.
/// Another user who made `/tmp/iceoryx2` first, or left it writable, could
/// otherwise replace the run's service records. Checked by the launcher
/// once its own bus has made the directory, before any stage starts.
pub fn check_root(root: &Path) -> Result<(), String> {
    use std::os::unix::fs::MetadataExt;
    let m = match std::fs::symlink_metadata(root) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(format!("iceoryx2 root {}: {e}", root.display())),
    };
    // SAFETY: geteuid has no preconditions.
    let me = unsafe { libc::geteuid() };
    if m.file_type().is_symlink() || !m.is_dir() {
        return Err(format!(
            "iceoryx2 root {} is not a directory (a link or a file): remove it",
            root.display()
        ));
    }
    if m.uid() != me && m.uid() != 0 {
        return Err(format!(
            "iceoryx2 root {} belongs to uid {}, not to this user (uid {me}) or root: \
             another user could replace the run's service records; remove it, \
             or run under another root path",
            root.display(),
            m.uid()
        ));
    }
    if m.mode() & 0o022 != 0 {
        return Err(format!(
            "iceoryx2 root {} has mode {:o}: writable by others, who could replace \
             the run's service records; `chmod go-w` it",
            root.display(),
            m.mode() & 0o7777
        ));
    }
    Ok(())
}

/// The files of `prefix` in `/dev/shm` only (shared-memory segments).
pub fn shm_files(prefix: &str) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if !prefix.is_empty() {
        collect(Path::new(SHM_DIR), prefix, 0, &mut out);
    }
    out
}

/// Remove every resource of `prefix`: stale resources of dead nodes through
/// iceoryx2, then — if no node of the prefix is alive — every file left.
pub fn remove_prefix(prefix: &str) -> Result<CleanupReport, IpcError> {
    let (alive, removed, failed) = remove_dead_nodes(prefix)?;
    let mut report = CleanupReport {
        alive_nodes: alive,
        dead_nodes_removed: removed,
        dead_nodes_failed: failed,
        files_removed: 0,
    };
    if alive == 0 {
        for p in resources(prefix) {
            let ok = if p.is_dir() {
                std::fs::remove_dir_all(&p).is_ok()
            } else {
                std::fs::remove_file(&p).is_ok()
            };
            report.files_removed += ok as usize;
        }
    }
    Ok(report)
}

fn pid_alive(pid: u32) -> bool {
    // SAFETY: kill with signal 0 only checks for existence/permission.
    let r = unsafe { libc::kill(pid as libc::pid_t, 0) };
    r == 0 || std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
}

/// Run prefixes ([`run_prefix`]) that have resources on this machine.
pub fn run_prefixes() -> Vec<String> {
    let mut files = resources(RUN_STEM);
    files.retain(|p| p.file_name().is_some());
    let mut out: Vec<String> = files
        .iter()
        .filter_map(|p| {
            let name = p.file_name()?.to_string_lossy().to_string();
            let rest = name.strip_prefix(RUN_STEM)?;
            let end = rest.find('_')?;
            Some(format!("{RUN_STEM}{}_", &rest[..end]))
        })
        .collect();
    out.sort();
    out.dedup();
    out
}

/// Remove the launcher state directories (`<base>/<run prefix>state.XXXXXX`,
/// private: the resume files and refine's chain checkpoint) of runs whose
/// launcher is gone: a launcher killed with SIGKILL cannot remove its own.
/// Only this user's own directories are touched, never through a link.
/// Returns how many were removed.
pub fn sweep_stale_state_dirs(base: &std::path::Path) -> usize {
    let Ok(entries) = std::fs::read_dir(base) else {
        return 0;
    };
    let mut removed = 0;
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        let Some((prefix, _)) = name.rsplit_once("state.") else {
            continue;
        };
        match run_prefix_pid(prefix) {
            Some(pid) if !pid_alive(pid) => {}
            _ => continue,
        }
        if crate::rt::files::check_private_dir(&e.path()).is_ok()
            && std::fs::remove_dir_all(e.path()).is_ok()
        {
            removed += 1;
        }
    }
    removed
}

/// Remove the resources of run prefixes whose creating process is gone and
/// that have no alive node (and the state directories of such runs).
/// Returns the prefixes whose shared memory was removed.
pub fn sweep_stale_runs() -> Vec<String> {
    sweep_stale_state_dirs(&crate::rt::files::runtime_base());
    let mut swept = Vec::new();
    for prefix in run_prefixes() {
        match run_prefix_pid(&prefix) {
            Some(pid) if !pid_alive(pid) => {}
            _ => continue,
        }
        if let Ok(r) = remove_prefix(&prefix) {
            if r.alive_nodes == 0 {
                swept.push(prefix);
            }
        }
    }
    swept
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Belief, Bus, BusConfig};

    #[test]
    fn state_dirs_of_dead_launchers_are_swept_and_live_ones_kept() {
        use crate::rt::files::PrivateDir;
        let temp = PrivateDir::create("bb-sweep-").unwrap();
        let mk = |stem: &str| {
            let d = PrivateDir::create_in(temp.path(), stem).unwrap();
            std::fs::write(d.path().join("refine.ckpt"), b"x").unwrap();
            d
        };
        // pid 0x7ffffffe is above any pid_max, so its launcher is gone.
        let dead = mk(&format!("{RUN_STEM}7ffffffe-0badcafe_state."));
        let live = mk(&format!("{}state.", run_prefix()));
        let other = mk("unrelated_state.");
        // A directory of a dead launcher that is not private is not ours
        // to judge: left alone.
        let shared = temp
            .path()
            .join(format!("{RUN_STEM}7ffffffe-0badcafe_state.shared"));
        std::fs::create_dir(&shared).unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&shared, std::fs::Permissions::from_mode(0o755)).unwrap();
        assert_eq!(sweep_stale_state_dirs(temp.path()), 1);
        assert!(!dead.path().exists());
        assert!(live.path().exists() && other.path().exists() && shared.exists());
    }

    #[test]
    fn an_untrustworthy_iceoryx2_root_is_refused() {
        use crate::rt::files::PrivateDir;
        use std::os::unix::fs::PermissionsExt;
        let d = PrivateDir::create("bb-root-").unwrap();
        check_root(&d.path().join("absent")).unwrap();
        let root = d.path().join("iceoryx2");
        std::fs::create_dir(&root).unwrap();
        std::fs::set_permissions(&root, std::fs::Permissions::from_mode(0o750)).unwrap();
        check_root(&root).unwrap();
        std::fs::set_permissions(&root, std::fs::Permissions::from_mode(0o777)).unwrap();
        assert!(check_root(&root)
            .unwrap_err()
            .contains("writable by others"));
        let link = d.path().join("link");
        std::os::unix::fs::symlink(&root, &link).unwrap();
        assert!(check_root(&link).unwrap_err().contains("not a directory"));
    }

    #[test]
    fn run_prefixes_are_valid_unique_and_carry_the_pid() {
        let a = run_prefix();
        let b = run_prefix();
        assert_ne!(a, b);
        crate::validate_prefix(&a).unwrap();
        assert_eq!(run_prefix_pid(&a), Some(std::process::id()));
        assert_eq!(run_prefix_pid("iox2_bb3f00_"), None);
    }

    #[test]
    fn remove_prefix_leaves_nothing_after_a_clean_run() {
        let prefix = run_prefix();
        let cfg = BusConfig {
            prefix: prefix.clone(),
            instance: "cleanup".into(),
        };
        {
            let bus = Bus::open(&cfg, "t").unwrap();
            let mut p = bus.publisher::<Belief>().unwrap();
            let s = bus.subscriber::<Belief>().unwrap();
            p.publish(&Belief::default()).unwrap();
            assert!(s.receive().unwrap().is_some());
            assert!(!resources(&prefix).is_empty());
            // While a node is alive nothing is removed.
            let r = remove_prefix(&prefix).unwrap();
            assert_eq!(r.alive_nodes, 1);
            assert_eq!(r.files_removed, 0);
        }
        let r = remove_prefix(&prefix).unwrap();
        assert_eq!(r.alive_nodes, 0);
        assert!(resources(&prefix).is_empty(), "{:?}", resources(&prefix));
    }
}
