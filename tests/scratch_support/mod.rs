//! A test's scratch file (a report, a policy, a config) in its own
//! directory under the system temp dir: the project's [`PrivateDir`]
//! (mkdtemp, so parallel tests never share one; removed when dropped at
//! the test's end, so a suite run leaves nothing in /tmp). A failed test
//! keeps it and names it on stderr, so its report can be read.
#![allow(dead_code)] // each test binary uses its own subset

use beliefbus::rt::files::PrivateDir;
use std::ffi::OsStr;
use std::ops::Deref;
use std::path::{Path, PathBuf};

/// `<temp>/beliefbus-<tag>-XXXXXX/<name>`; the directory exists.
pub struct Scratch {
    dir: Option<PrivateDir>,
    path: PathBuf,
}

impl Scratch {
    pub fn new(tag: &str, name: &str) -> Self {
        let dir = PrivateDir::create_in(&std::env::temp_dir(), &format!("beliefbus-{tag}-"))
            .expect("a scratch directory in the temp dir");
        let path = dir.path().join(name);
        Self {
            dir: Some(dir),
            path,
        }
    }

    /// The directory holding the file (a working directory for a run).
    pub fn dir(&self) -> &Path {
        self.dir.as_ref().expect("present until dropped").path()
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
            if let Some(dir) = self.dir.take() {
                eprintln!(
                    "test failed: its files are kept in {}",
                    dir.path().display()
                );
                // Not dropped: PrivateDir's drop would remove the files.
                std::mem::forget(dir);
            }
        }
    }
}
