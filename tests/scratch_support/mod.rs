//! A test's scratch file (a report, a policy, a config) in its own
//! directory under the system temp dir. The directory goes when the value
//! is dropped at the test's end, so a suite run leaves nothing in /tmp; a
//! failed test keeps it and names it on stderr, so its report can be read.
#![allow(dead_code)] // each test binary uses its own subset

use std::ffi::OsStr;
use std::ops::Deref;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Tests of one binary run in parallel and may ask for the same name: each
/// scratch gets its own number, so one test's cleanup never removes a
/// directory another is still using.
static NEXT: AtomicUsize = AtomicUsize::new(0);

/// `<temp>/beliefbus-<tag>-<pid>-<k>-<name>/<name>`, k unique within the
/// process; the directory exists.
pub struct Scratch {
    dir: PathBuf,
    path: PathBuf,
}

impl Scratch {
    /// A fresh directory for `name` (what an earlier, killed process of
    /// the same pid left there is removed first).
    pub fn new(tag: &str, name: &str) -> Self {
        let dir = std::env::temp_dir().join(format!(
            "beliefbus-{tag}-{}-{}-{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed),
            name.replace(['/', '.'], "_")
        ));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(name);
        Self { dir, path }
    }

    /// The directory holding the file (a working directory for a run).
    pub fn dir(&self) -> &Path {
        &self.dir
    }
}

impl Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.path
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        &self.path
    }
}

impl AsRef<OsStr> for Scratch {
    fn as_ref(&self) -> &OsStr {
        self.path.as_os_str()
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("test failed: its files are kept in {}", self.dir.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}
