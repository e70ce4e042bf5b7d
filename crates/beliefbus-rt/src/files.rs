//! Files a run writes, safe on a machine shared with other users.
//!
//! beliefbus may run as root in a world-writable `/tmp`, so a name another
//! user can predict is a name another user can plant a link at. Three rules
//! follow, one function each:
//! - run-time state (resume files, refine's checkpoint) lives in a fresh
//!   per-run directory made by `mkdtemp(3)` — mode 0700, a name nobody can
//!   predict, never an existing directory ([`PrivateDir`]);
//! - a file in it is written to a temporary created with
//!   `O_CREAT | O_EXCL | O_NOFOLLOW`, mode 0600, then renamed into place,
//!   and read back only from a directory that is ours and private
//!   ([`write_private`], [`read_private`]);
//! - an output the user names (`--report`, `--json`, `--plot`) is written
//!   the same way in the target's own directory and renamed over the
//!   target ([`replace_file`]): a link planted at the target is replaced,
//!   never followed, and a reader never sees half a file.

use std::ffi::CString;
use std::fs::File;
use std::io::{self, Write};
use std::os::unix::ffi::OsStrExt;
use std::os::unix::fs::{MetadataExt, OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

fn euid() -> u32 {
    // SAFETY: geteuid has no preconditions and cannot fail.
    unsafe { libc::geteuid() }
}

fn bad(msg: String) -> io::Error {
    io::Error::new(io::ErrorKind::PermissionDenied, msg)
}

/// `path` is a directory (not a link to one) owned by this user with no
/// group or other permission bits: nobody else can add, replace or read
/// what is in it.
pub fn check_private_dir(path: &Path) -> io::Result<()> {
    let m = std::fs::symlink_metadata(path)?;
    if m.file_type().is_symlink() || !m.is_dir() {
        return Err(bad(format!("{} is not a directory", path.display())));
    }
    if m.uid() != euid() {
        return Err(bad(format!(
            "{} belongs to uid {}, not to this user (uid {})",
            path.display(),
            m.uid(),
            euid()
        )));
    }
    if m.mode() & 0o077 != 0 {
        return Err(bad(format!(
            "{} has mode {:o}; a private directory must be 0700",
            path.display(),
            m.mode() & 0o777
        )));
    }
    Ok(())
}

/// Where per-run directories go: `$XDG_RUNTIME_DIR` when it is a private
/// directory of this user (it is, under systemd logins), else the temporary
/// directory (mkdtemp makes the run's own directory private there).
pub fn runtime_base() -> PathBuf {
    if let Some(d) = std::env::var_os("XDG_RUNTIME_DIR").map(PathBuf::from) {
        if d.is_absolute() && check_private_dir(&d).is_ok() {
            return d;
        }
    }
    std::env::temp_dir()
}

/// A fresh directory private to this user, removed with its contents when
/// dropped (a run that ends early on an error leaves nothing behind).
#[derive(Debug)]
pub struct PrivateDir(PathBuf);

impl PrivateDir {
    /// `<runtime_base>/<stem>XXXXXX`.
    pub fn create(stem: &str) -> io::Result<Self> {
        Self::create_in(&runtime_base(), stem)
    }

    /// `<parent>/<stem>XXXXXX`, the X's chosen by mkdtemp(3), which creates
    /// the directory with mode 0700 and fails rather than reuse a path.
    pub fn create_in(parent: &Path, stem: &str) -> io::Result<Self> {
        if stem.contains('/') {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("directory stem '{stem}' contains '/'"),
            ));
        }
        let template = parent.join(format!("{stem}XXXXXX"));
        let c = CString::new(template.as_os_str().as_bytes())
            .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "NUL in path"))?;
        let raw = c.into_raw();
        // SAFETY: `raw` is a writable NUL-terminated buffer that mkdtemp
        // fills in place; ownership is taken back right after the call.
        let r = unsafe { libc::mkdtemp(raw) };
        // SAFETY: `raw` came from CString::into_raw and was not freed.
        let filled = unsafe { CString::from_raw(raw) };
        if r.is_null() {
            return Err(io::Error::last_os_error());
        }
        let path = PathBuf::from(std::ffi::OsStr::from_bytes(filled.as_bytes()));
        check_private_dir(&path)?;
        Ok(Self(path))
    }

    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for PrivateDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A name in `dir` for a temporary beside `target` that nobody else can
/// have taken (opened with O_EXCL, so a clash only means another try).
fn temp_name(dir: &Path, target: &Path, attempt: u32) -> PathBuf {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    let base = target
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    dir.join(format!(
        ".{base}.{}-{n}-{nanos:x}-{attempt}.tmp",
        std::process::id()
    ))
}

/// Create a new file that must not exist yet and must not be a link.
fn create_exclusive(path: &Path, mode: u32) -> io::Result<File> {
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(mode)
        .custom_flags(libc::O_NOFOLLOW | libc::O_CLOEXEC)
        .open(path)
}

/// Whether a write reaches the disk before it is renamed into place.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Durability {
    /// Synced: the file survives a crash of the machine (outputs).
    Synced,
    /// Not synced: atomic for every process (the rename), lost with the
    /// machine. For state that lives only as long as the run — the run's
    /// shared memory is lost with the machine too — and is written often:
    /// a sync per write waits for the disk (milliseconds to tens of
    /// milliseconds) and makes the kernel write each version out at once.
    RunScoped,
}

/// Write `bytes` to a fresh temporary in `dir` (mode `mode`, before the
/// umask) and rename it to `target`, which `rename(2)` replaces whatever it
/// is — a planted link included — without following it.
fn write_and_rename(
    dir: &Path,
    target: &Path,
    bytes: &[u8],
    mode: u32,
    durability: Durability,
) -> io::Result<()> {
    let mut last = None;
    for attempt in 0..16 {
        let tmp = temp_name(dir, target, attempt);
        match create_exclusive(&tmp, mode) {
            Ok(mut f) => {
                let r = f
                    .write_all(bytes)
                    .and_then(|_| match durability {
                        Durability::Synced => f.sync_data(),
                        Durability::RunScoped => Ok(()),
                    })
                    .and_then(|_| std::fs::rename(&tmp, target));
                if r.is_err() {
                    let _ = std::fs::remove_file(&tmp);
                }
                return r;
            }
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => last = Some(e),
            Err(e) => return Err(e),
        }
    }
    Err(last.unwrap_or_else(|| io::Error::other("no temporary name")))
}

fn parent_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Write `path` (in a private directory: [`check_private_dir`]) atomically,
/// mode 0600.
pub fn write_private(path: &Path, bytes: &[u8], durability: Durability) -> io::Result<()> {
    let dir = parent_of(path);
    check_private_dir(&dir)?;
    write_and_rename(&dir, path, bytes, 0o600, durability)
}

/// Read `path` only if its directory is private to this user and the file
/// itself is a regular file of ours (never through a link).
pub fn read_private(path: &Path) -> io::Result<Vec<u8>> {
    check_private_dir(&parent_of(path))?;
    let mut f = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NOFOLLOW | libc::O_CLOEXEC)
        .open(path)?;
    let m = f.metadata()?;
    if !m.is_file() || m.uid() != euid() {
        return Err(bad(format!(
            "{} is not a regular file of this user",
            path.display()
        )));
    }
    let mut out = Vec::with_capacity(m.len() as usize);
    io::Read::read_to_end(&mut f, &mut out)?;
    Ok(out)
}

/// Write a user-named output: a temporary in the target's directory (mode
/// 0644 before the umask, like any tool's output), renamed over the target.
pub fn replace_file(path: &Path, bytes: &[u8]) -> io::Result<()> {
    if std::fs::symlink_metadata(path).is_ok_and(|m| m.is_dir()) {
        return Err(io::Error::new(
            io::ErrorKind::IsADirectory,
            format!("{} is a directory", path.display()),
        ));
    }
    write_and_rename(&parent_of(path), path, bytes, 0o644, Durability::Synced)
}

/// Open a user-named output that is written as it goes (a timeline): created
/// or truncated, but never through a link at `path` (that is an error).
pub fn create_no_follow(path: &Path) -> io::Result<File> {
    std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .mode(0o644)
        .custom_flags(libc::O_NOFOLLOW | libc::O_CLOEXEC)
        .open(path)
}

/// Mode bits of `path` (not following a link), for the documentation's
/// table and its test.
pub fn mode_of(path: &Path) -> io::Result<u32> {
    Ok(std::fs::symlink_metadata(path)?.permissions().mode() & 0o7777)
}

#[cfg(test)]
#[path = "files_tests.rs"]
mod tests;
