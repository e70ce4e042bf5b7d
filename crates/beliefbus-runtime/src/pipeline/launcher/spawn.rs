//! Starting a stage process: which executable, with which arguments and
//! environment, in which process group.
//!
//! What a stage is started with is decided by pure functions
//! ([`stage_args`], [`stage_env`], [`spin_for`], [`own_executable`]) so it
//! can be checked without starting anything; [`spawn_child`] applies them.
//! The launcher sets no affinity or priority itself: each stage pins and
//! prioritises itself from `[stages.<name>]` of the config it is given.

use super::supervise::Stage;
use super::RunOptions;
use crate::ipc::{self, StageKind};
use crate::pipeline::stage_main::BUILD_ID;
use crate::pipeline::supervisor_resume::Resume;
use anyhow::{Context, Result};
use std::ffi::OsString;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};

/// The note printed when the stages run as `beliefbus stage <name>`.
pub(super) const MISSING_EXES_NOTE: &str =
    "stage executables next to beliefbus are missing or from another build \
     (`cargo run` builds only beliefbus); ran the stages as `beliefbus stage <name>`";

/// `beliefbus-<stage>` in `dir`: the stage's own executable.
pub(super) fn own_executable(dir: &Path, kind: StageKind) -> PathBuf {
    dir.join(format!("beliefbus-{}", kind.name()))
}

/// How to start stage `kind`: its own executable when it is next to us,
/// built from the same sources and the run uses only the built-in
/// scenarios, else our hidden `stage` subcommand (a user's binary with its
/// own registry always runs its stages itself). True if it is the stage's
/// own executable.
fn stage_command(kind: StageKind, builtin: bool) -> Result<(Command, bool)> {
    let me = std::env::current_exe().context("cannot locate the beliefbus executable")?;
    let dir = me.parent().unwrap_or(Path::new("."));
    let exe = own_executable(dir, kind);
    if builtin && exe.is_file() {
        let same = Command::new(&exe)
            .arg("--build-id")
            .output()
            .map(|o| String::from_utf8_lossy(&o.stdout).trim() == BUILD_ID)
            .unwrap_or(false);
        if same {
            return Ok((Command::new(exe), true));
        }
    }
    let mut c = Command::new(me);
    c.arg("stage").arg(kind.name());
    Ok((c, false))
}

/// The arguments after the executable (and after `stage <name>`): the
/// config source, the run's prefix, every `--set`, the resume file.
pub(super) fn stage_args(opts: &RunOptions, prefix: &str, resume: Option<&Path>) -> Vec<OsString> {
    let mut a = opts.config.stage_args();
    a.push("--prefix".into());
    a.push(prefix.into());
    for s in &opts.sets {
        a.push("--set".into());
        a.push(s.into());
    }
    if let Some(r) = resume {
        a.push("--resume".into());
        a.push(r.into());
    }
    a
}

/// The environment a stage gets on top of the launcher's: the launcher's
/// pid (the stages admit samples on internal channels only from processes
/// whose parent is this launcher, `ipc::trust`) and the busy-loop time of
/// `--chaos-spin`, removed when absent so an inherited one cannot leak into
/// a stage. `None`: remove the variable.
pub(super) fn stage_env(
    launcher_pid: u32,
    spin_after_s: Option<f64>,
) -> [(&'static str, Option<String>); 2] {
    [
        (ipc::trust::LAUNCHER_PID_ENV, Some(launcher_pid.to_string())),
        (
            crate::rt::sched::SPIN_AFTER_ENV,
            spin_after_s.map(|t| format!("{t}")),
        ),
    ]
}

/// The `--chaos-spin` time of stage `kind` (only its first incarnation
/// gets one; a restart must not spin again).
pub(super) fn spin_for(opts: &RunOptions, kind: StageKind) -> Option<f64> {
    opts.chaos_spin.filter(|(k, _)| *k == kind).map(|(_, t)| t)
}

/// Where the resume file of stage `kind` lives.
pub(super) fn resume_path(state_dir: &Path, kind: StageKind) -> PathBuf {
    state_dir.join(format!("{}.resume.json", kind.name()))
}

/// Push `note` unless it is already there.
pub(super) fn add_note(notes: &mut Vec<String>, note: &str) {
    if !notes.iter().any(|x| x == note) {
        notes.push(note.to_string());
    }
}

/// Start the first incarnation of `kind`.
pub(super) fn spawn(
    kind: StageKind,
    opts: &RunOptions,
    prefix: &str,
    notes: &mut Vec<String>,
    state_dir: &Path,
) -> Result<Stage> {
    // A first start gets the run's state directory too (refine checkpoints
    // its chain there from the start; see `supervisor_resume`).
    let first = Resume {
        state_dir: Some(state_dir.to_path_buf()),
        ..Resume::default()
    };
    let path = resume_path(state_dir, kind);
    first.save(&path)?;
    let child = spawn_child(kind, opts, prefix, notes, Some(&path), spin_for(opts, kind))?;
    eprintln!("supervisor: started {} (pid {})", kind.name(), child.id());
    Ok(Stage::started(kind, child))
}

/// Start one process of stage `kind`.
pub(super) fn spawn_child(
    kind: StageKind,
    opts: &RunOptions,
    prefix: &str,
    notes: &mut Vec<String>,
    resume: Option<&Path>,
    spin_after_s: Option<f64>,
) -> Result<Child> {
    let builtin = opts.registry.as_ref().is_none_or(|r| r.is_builtin());
    let (mut cmd, own) = stage_command(kind, builtin)?;
    if !own && builtin {
        add_note(notes, MISSING_EXES_NOTE);
    }
    cmd.args(stage_args(opts, prefix, resume));
    for (k, v) in stage_env(std::process::id(), spin_after_s) {
        match v {
            Some(v) => cmd.env(k, v),
            None => cmd.env_remove(k),
        };
    }
    // Own process group: a terminal's Ctrl-C reaches only the launcher, which
    // stops the stages in order. Parent-death signal: if the launcher dies,
    // the stages stop too (and release their shared memory).
    cmd.process_group(0);
    // SAFETY: prctl is async-signal-safe; nothing else runs between fork and exec.
    unsafe {
        cmd.pre_exec(|| {
            libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM);
            Ok(())
        });
    }
    cmd.spawn()
        .with_context(|| format!("cannot start the {} stage", kind.name()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::ConfigSource;

    fn strs(v: &[OsString]) -> Vec<&str> {
        v.iter().map(|s| s.to_str().unwrap()).collect()
    }

    #[test]
    fn args_carry_config_prefix_sets_and_resume_in_order() {
        let opts = RunOptions {
            config: ConfigSource::File("/x/ship.toml".into()),
            sets: vec!["filter.particles=64".into(), "run.seed=3".into()],
            ..RunOptions::default()
        };
        let a = stage_args(&opts, "bb_run_1_", Some(Path::new("/s/filter.resume.json")));
        assert_eq!(
            strs(&a),
            [
                "/x/ship.toml",
                "--prefix",
                "bb_run_1_",
                "--set",
                "filter.particles=64",
                "--set",
                "run.seed=3",
                "--resume",
                "/s/filter.resume.json"
            ]
        );
    }

    #[test]
    fn args_of_a_named_scenario_without_resume() {
        let opts = RunOptions {
            config: ConfigSource::Scenario(Some("pendulum".into())),
            ..RunOptions::default()
        };
        assert_eq!(
            strs(&stage_args(&opts, "p", None)),
            ["--scenario", "pendulum", "--prefix", "p"]
        );
        // The built-in default scenario: no config argument at all.
        assert_eq!(
            strs(&stage_args(&RunOptions::default(), "p", None)),
            ["--prefix", "p"]
        );
    }

    #[test]
    fn env_sets_launcher_pid_and_sets_or_removes_spin() {
        let e = stage_env(4242, Some(1.5));
        assert_eq!(e[0], (ipc::trust::LAUNCHER_PID_ENV, Some("4242".into())));
        assert_eq!(e[1], (crate::rt::sched::SPIN_AFTER_ENV, Some("1.5".into())));
        // Absent: removed, so an inherited value cannot make a stage spin.
        assert_eq!(
            stage_env(1, None)[1],
            (crate::rt::sched::SPIN_AFTER_ENV, None)
        );
    }

    #[test]
    fn chaos_spin_applies_to_its_stage_only() {
        let opts = RunOptions {
            chaos_spin: Some((StageKind::Filter, 2.0)),
            ..RunOptions::default()
        };
        assert_eq!(spin_for(&opts, StageKind::Filter), Some(2.0));
        assert_eq!(spin_for(&opts, StageKind::Control), None);
        assert_eq!(spin_for(&RunOptions::default(), StageKind::Filter), None);
    }

    #[test]
    fn executable_and_resume_file_names() {
        assert_eq!(
            own_executable(Path::new("/bin"), StageKind::Refine),
            Path::new("/bin/beliefbus-refine")
        );
        assert_eq!(
            resume_path(Path::new("/st"), StageKind::Control),
            Path::new("/st/control.resume.json")
        );
    }

    #[test]
    fn note_is_added_once() {
        let mut n = vec!["other".to_string()];
        add_note(&mut n, MISSING_EXES_NOTE);
        add_note(&mut n, MISSING_EXES_NOTE);
        assert_eq!(n, ["other", MISSING_EXES_NOTE]);
    }
}
