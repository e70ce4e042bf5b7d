//! Restart with state: what a restarted stage resumes from.
//!
//! The supervisor's monitor sees every belief, control and truth of the run,
//! so it knows the last value each stage published. Before restarting stage
//! S it writes a [`Resume`] file into the run's state directory and starts S
//! with `--resume FILE`:
//! - filter: the last published belief — the new filter starts from that
//!   Gaussian at its time of validity (instead of the configured prior) and
//!   continues its sequence numbers;
//! - control: the last control — the waypoint route continues at the active
//!   waypoint and the sequence numbers continue; the last belief itself
//!   comes from the belief channel's history (the filter is alive);
//! - plant: the last truth — the simulation continues from that true state
//!   and the channel's numbering continues (docs/sensor-abi.md rule 2);
//! - any stage (refine's chain snapshots): [`Resume::state_dir`] is the
//!   run's private directory ([`crate::rt::files::PrivateDir`]: fresh, 0700)
//!   that outlives a stage's incarnations; a stage may checkpoint there
//!   ([`Resume::write_checkpoint`], atomic rename) and read it back after a
//!   restart ([`Resume::read_checkpoint`]). The directory is removed at the
//!   end of the run.
//!
//! A resume file is honoured only from such a directory: [`Resume::load`]
//! refuses a file whose directory is not this user's and private, or that
//! is a link, and the state directory is the file's own directory — never a
//! path read from the file, which could send a checkpoint anywhere.

use crate::ipc::{Belief, Control, StageKind, Truth};
use crate::rt::files;
use crate::{MAX_STATE, MAX_STATE as D};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The last belief (enough to rebuild the Gaussian and continue numbering).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ResumeBelief {
    pub seq: u64,
    pub t_valid_ns: u64,
    pub dim: u32,
    pub mean: Vec<f64>,
    /// Column-major d × d (stride d).
    pub cov: Vec<f64>,
}

/// The last control.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ResumeControl {
    pub seq: u64,
    pub goal: [f64; 2],
    pub waypoints_reached: u64,
}

/// The last truth of the plant.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ResumeTruth {
    pub seq: u64,
    pub t_valid_ns: u64,
    pub x: Vec<f64>,
}

/// What a restarted stage resumes from (empty on a first start).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Resume {
    /// Restarts of this stage before this incarnation.
    pub restarts: u32,
    /// Per-run directory for checkpoints (none outside the launcher): the
    /// directory the resume file was loaded from, never a field of the file.
    #[serde(skip)]
    pub state_dir: Option<PathBuf>,
    pub belief: Option<ResumeBelief>,
    pub control: Option<ResumeControl>,
    pub truth: Option<ResumeTruth>,
}

impl ResumeBelief {
    /// From a belief message.
    pub fn from_msg(b: &Belief) -> Self {
        let d = (b.dim as usize).min(MAX_STATE);
        Self {
            seq: b.header.seq,
            t_valid_ns: b.header.t_valid_ns,
            dim: d as u32,
            mean: b.mean[..d].to_vec(),
            cov: b.cov[..d * d].to_vec(),
        }
    }

    /// The Gaussian, if the stored one is consistent (dimensions, finite,
    /// symmetric-positive diagonal).
    pub fn gaussian(&self) -> Option<crate::belief::Gaussian> {
        let d = self.dim as usize;
        if d == 0 || d > D || self.mean.len() != d || self.cov.len() != d * d {
            return None;
        }
        if self.mean.iter().chain(&self.cov).any(|v| !v.is_finite()) {
            return None;
        }
        if (0..d).any(|i| self.cov[i * d + i] <= 0.0) {
            return None;
        }
        let mut g = crate::belief::Gaussian::zeros(d);
        g.mean[..d].copy_from_slice(&self.mean);
        g.cov[..d * d].copy_from_slice(&self.cov);
        Some(g)
    }
}

impl ResumeControl {
    pub fn from_msg(c: &Control) -> Self {
        Self {
            seq: c.header.seq,
            goal: c.goal,
            waypoints_reached: c.waypoints_reached,
        }
    }
}

impl ResumeTruth {
    pub fn from_msg(t: &Truth) -> Self {
        let d = (t.dim as usize).min(MAX_STATE);
        Self {
            seq: t.header.seq,
            t_valid_ns: t.header.t_valid_ns,
            x: t.x[..d].to_vec(),
        }
    }
}

/// Why a resume file could not be used.
#[derive(Debug, thiserror::Error)]
pub enum ResumeError {
    #[error("cannot read resume file {path}: {reason}")]
    Read { path: String, reason: String },
    #[error("cannot write {path}: {reason}")]
    Write { path: String, reason: String },
}

impl Resume {
    #[cfg(test)]
    fn default_json() -> String {
        serde_json::to_string(&Self::default()).unwrap()
    }

    /// Load a resume file from a private directory of this user
    /// ([`files::read_private`]); that directory becomes the state directory.
    pub fn load(path: &Path) -> Result<Self, ResumeError> {
        let err = |e: &dyn std::fmt::Display| ResumeError::Read {
            path: path.display().to_string(),
            reason: e.to_string(),
        };
        let bytes = files::read_private(path).map_err(|e| err(&e))?;
        let mut r: Self = serde_json::from_slice(&bytes).map_err(|e| err(&e))?;
        r.state_dir = path.parent().map(Path::to_path_buf);
        Ok(r)
    }

    /// Write it to `path` in a private directory (atomically: a fresh
    /// temporary, then rename).
    pub fn save(&self, path: &Path) -> Result<(), ResumeError> {
        let text = serde_json::to_string(self).map_err(|e| ResumeError::Write {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
        write(path, text.as_bytes())
    }

    /// The checkpoint file of `kind` in the state directory.
    pub fn checkpoint_path(&self, kind: StageKind) -> Option<PathBuf> {
        self.state_dir
            .as_ref()
            .map(|d| d.join(format!("{}.ckpt", kind.name())))
    }

    /// Save a checkpoint of `kind` (no-op without a state directory).
    pub fn write_checkpoint(&self, kind: StageKind, bytes: &[u8]) -> Result<(), ResumeError> {
        match self.checkpoint_path(kind) {
            Some(p) => write(&p, bytes),
            None => Ok(()),
        }
    }

    /// The last checkpoint of `kind`, if any.
    pub fn read_checkpoint(&self, kind: StageKind) -> Option<Vec<u8>> {
        files::read_private(&self.checkpoint_path(kind)?).ok()
    }
}

/// Resume files and checkpoints live in the run's state directory and
/// serve restarts within the run: atomic, not synced.
fn write(path: &Path, bytes: &[u8]) -> Result<(), ResumeError> {
    files::write_private(path, bytes, files::Durability::RunScoped).map_err(|e| {
        ResumeError::Write {
            path: path.display().to_string(),
            reason: e.to_string(),
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::belief::Gaussian;

    #[test]
    fn a_belief_round_trips_through_a_resume_file() {
        let g = Gaussian::diagonal(&[1.0, -2.0, 0.5, 0.25], &[0.1, 0.2, 0.3, 0.4]);
        let mut b = Belief::default();
        b.set_gaussian(&g);
        b.header.seq = 41;
        b.header.t_valid_ns = 123;
        let tmp = files::PrivateDir::create("bb-resume-").unwrap();
        let dir = tmp.path().to_path_buf();
        let r = Resume {
            restarts: 2,
            state_dir: Some(dir.clone()),
            belief: Some(ResumeBelief::from_msg(&b)),
            ..Resume::default()
        };
        let path = dir.join("filter.resume.json");
        r.save(&path).unwrap();
        let back = Resume::load(&path).unwrap();
        assert_eq!(back, r);
        assert_eq!(back.belief.as_ref().unwrap().gaussian().unwrap(), g);
        back.write_checkpoint(StageKind::Refine, b"chain v3")
            .unwrap();
        assert_eq!(
            back.read_checkpoint(StageKind::Refine).as_deref(),
            Some(&b"chain v3"[..])
        );
        assert_eq!(back.read_checkpoint(StageKind::Filter), None);
    }

    #[test]
    fn the_state_dir_is_where_the_file_is_never_what_it_says() {
        let tmp = files::PrivateDir::create("bb-resume-").unwrap();
        let path = tmp.path().join("refine.resume.json");
        let text = r#"{"restarts":1,"state_dir":"/etc","belief":null,"control":null,"truth":null}"#;
        files::write_private(&path, text.as_bytes(), files::Durability::RunScoped).unwrap();
        let r = Resume::load(&path).unwrap();
        assert_eq!(r.state_dir.as_deref(), Some(tmp.path()));
        assert_eq!(
            r.checkpoint_path(StageKind::Refine).unwrap(),
            tmp.path().join("refine.ckpt")
        );
    }

    #[test]
    fn a_resume_file_outside_a_private_directory_is_refused() {
        let tmp = files::PrivateDir::create("bb-resume-").unwrap();
        let open = tmp.path().join("open");
        std::fs::create_dir(&open).unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&open, std::fs::Permissions::from_mode(0o777)).unwrap();
        let path = open.join("filter.resume.json");
        std::fs::write(&path, Resume::default_json()).unwrap();
        let e = Resume::load(&path).unwrap_err().to_string();
        assert!(e.contains("0700"), "{e}");
    }

    #[test]
    fn an_inconsistent_belief_is_not_used() {
        let mut rb = ResumeBelief {
            seq: 0,
            t_valid_ns: 0,
            dim: 2,
            mean: vec![0.0, 0.0],
            cov: vec![1.0, 0.0, 0.0, 1.0],
        };
        assert!(rb.gaussian().is_some());
        rb.cov[3] = f64::NAN;
        assert!(rb.gaussian().is_none());
        rb.cov = vec![1.0];
        assert!(rb.gaussian().is_none());
        assert!(Resume::load(Path::new("/nonexistent/x.json")).is_err());
    }
}
