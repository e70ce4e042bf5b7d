//! Helpers shared by the `tests/sensor_*.rs` integration tests: a Python with
//! the iceoryx2 package, per-test shared-memory prefixes, child processes
//! that are killed when a test fails.

#![allow(dead_code)]

use beliefbus::ipc::cleanup;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// Repository root.
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `tools/python`.
pub fn python_tools() -> PathBuf {
    root().join("tools/python")
}

fn has_iceoryx2(python: &Path) -> bool {
    Command::new(python)
        .args(["-c", "import iceoryx2"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .map(|s| s.success())
        .unwrap_or(false)
}

/// The Python interpreter with the `iceoryx2` package: `$BELIEFBUS_PYTHON`
/// (must work when set — CI sets it), else `.venv/bin/python` of the
/// repository if it has the package. `None` (after a loud message) when
/// neither exists: the Python tests then skip — except under CI (`$CI`
/// set), where that is a failure.
pub fn python(test: &str) -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("BELIEFBUS_PYTHON") {
        let p = PathBuf::from(p);
        assert!(
            has_iceoryx2(&p),
            "BELIEFBUS_PYTHON={} cannot `import iceoryx2` (pip install iceoryx2==0.10.0)",
            p.display()
        );
        return Some(p);
    }
    let venv = root().join(".venv/bin/python");
    if has_iceoryx2(&venv) {
        return Some(venv);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "{test}: CI must run the Python tests: set BELIEFBUS_PYTHON (see .ci/run)"
    );
    eprintln!(
        "\n!!!!!!!! SKIPPING {test}: no Python with the iceoryx2 package.\n\
         !!!!!!!! Set BELIEFBUS_PYTHON to a python with `pip install iceoryx2==0.10.0`\n\
         !!!!!!!! (e.g. python3 -m venv .venv && .venv/bin/pip install iceoryx2==0.10.0).\n"
    );
    None
}

/// A fresh run prefix; on drop every resource of it is removed, and the
/// test fails if anything is left.
pub struct TestPrefix(pub String);

impl TestPrefix {
    pub fn new() -> Self {
        Self(cleanup::run_prefix())
    }
}

impl Drop for TestPrefix {
    fn drop(&mut self) {
        let r = cleanup::remove_prefix(&self.0);
        let left = cleanup::resources(&self.0);
        if !std::thread::panicking() {
            assert!(r.is_ok(), "cleanup of {} failed: {r:?}", self.0);
            assert!(left.is_empty(), "resources left: {left:?}");
        }
    }
}

/// Which output stream of a child.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stream {
    Stdout,
    Stderr,
}

/// A child process whose output lines are collected as they come, killed
/// (and reaped) when dropped.
pub struct ChildGuard {
    child: Option<Child>,
    lines: mpsc::Receiver<(Stream, String)>,
    pub stdout: Vec<String>,
    pub stderr: Vec<String>,
}

fn forward(r: impl std::io::Read + Send + 'static, s: Stream, tx: mpsc::Sender<(Stream, String)>) {
    std::thread::spawn(move || {
        for line in BufReader::new(r).lines() {
            let Ok(line) = line else { break };
            if tx.send((s, line)).is_err() {
                break;
            }
        }
    });
}

impl ChildGuard {
    pub fn spawn(cmd: &mut Command) -> Self {
        let mut child = cmd
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {cmd:?}: {e}"));
        let (tx, rx) = mpsc::channel();
        forward(child.stdout.take().unwrap(), Stream::Stdout, tx.clone());
        forward(child.stderr.take().unwrap(), Stream::Stderr, tx);
        Self {
            child: Some(child),
            lines: rx,
            stdout: Vec::new(),
            stderr: Vec::new(),
        }
    }

    fn take(&mut self, (s, l): (Stream, String)) -> &str {
        let v = match s {
            Stream::Stdout => &mut self.stdout,
            Stream::Stderr => &mut self.stderr,
        };
        v.push(l);
        v.last().unwrap()
    }

    /// Wait (at most `limit`) for a line of `stream` that satisfies `pred`;
    /// every line read is kept.
    pub fn wait_line(
        &mut self,
        stream: Stream,
        limit: Duration,
        pred: impl Fn(&str) -> bool,
    ) -> Option<String> {
        let until = Instant::now() + limit;
        loop {
            let left = until.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok((s, l)) => {
                    let line = self.take((s, l)).to_string();
                    if s == stream && pred(&line) {
                        return Some(line);
                    }
                }
                Err(_) => return None,
            }
        }
    }

    /// Whether the child is still running.
    pub fn running(&mut self) -> bool {
        self.child
            .as_mut()
            .is_some_and(|c| c.try_wait().ok().flatten().is_none())
    }

    /// Send SIGINT (as Ctrl-C would).
    pub fn interrupt(&self) {
        if let Some(c) = &self.child {
            // SAFETY: plain kill(2) on our own child.
            unsafe { libc::kill(c.id() as libc::pid_t, libc::SIGINT) };
        }
    }

    /// Wait for exit (at most `limit`, then kill) and collect the rest of
    /// the output; returns the exit status (None if it had to be killed).
    pub fn finish(&mut self, limit: Duration) -> Option<ExitStatus> {
        let mut child = self.child.take().expect("child");
        let until = Instant::now() + limit;
        let mut status = None;
        while Instant::now() < until {
            if let Ok(Some(s)) = child.try_wait() {
                status = Some(s);
                break;
            }
            while let Ok(x) = self.lines.try_recv() {
                self.take(x);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        if status.is_none() {
            let _ = child.kill();
        }
        // Reaps the child (a no-op when try_wait already did).
        let reaped = child.wait();
        let status = status.and(reaped.ok());
        // The forwarders end at EOF once the process is gone.
        while let Ok(x) = self.lines.recv_timeout(Duration::from_secs(2)) {
            self.take(x);
        }
        status
    }

    /// Both outputs, for assertion messages.
    pub fn show(&self) -> String {
        format!(
            "--- stdout\n{}\n--- stderr\n{}",
            self.stdout.join("\n"),
            self.stderr.join("\n")
        )
    }
}

impl Drop for ChildGuard {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// `python tools/python/<script> args…`, run from `tools/python`.
pub fn python_command(python: &Path, script: &str, args: &[String]) -> Command {
    let mut c = Command::new(python);
    c.current_dir(python_tools()).arg(script).args(args);
    c
}

/// Poll `f` every millisecond until it returns `Some` or `limit` passes.
pub fn poll<T>(limit: Duration, mut f: impl FnMut() -> Option<T>) -> Option<T> {
    let until = Instant::now() + limit;
    loop {
        if let Some(v) = f() {
            return Some(v);
        }
        if Instant::now() >= until {
            return None;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}
