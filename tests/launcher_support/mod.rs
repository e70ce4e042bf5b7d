//! A `beliefbus run` launcher driven from an integration test, with its
//! stderr streamed line by line (shared by `tests/reliability.rs` and
//! `tests/anytime.rs`). A failed assertion must not leave the launcher (and
//! its stages and shared memory) running: dropping a [`Run`] stops it as
//! Ctrl-C would.
#![allow(dead_code)] // each test binary uses its own subset

use std::io::BufRead;
use std::path::Path;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

/// Liveness guard only: the suite runs test binaries in parallel on two
/// cores, so waits are generous; nothing asserts how fast anything is.
pub const PATIENCE: Duration = Duration::from_secs(180);

/// The crate's root (configs are named relative to it).
pub fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The pid in a launcher line `... <stage> (pid N ...`.
pub fn pid_of(line: &str) -> i32 {
    let rest = line.split("(pid ").nth(1).unwrap();
    rest.split(|c: char| !c.is_ascii_digit())
        .next()
        .unwrap()
        .parse()
        .unwrap()
}

/// A launcher process and the stderr lines seen so far.
pub struct Run {
    pub child: Child,
    lines: Receiver<String>,
    pub log: Vec<String>,
}

impl Run {
    /// Start `beliefbus ARGS` in the crate's root.
    pub fn start(args: &[&str]) -> Run {
        let mut child = Command::new(env!("CARGO_BIN_EXE_beliefbus"))
            .args(args)
            .current_dir(root())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let err = child.stderr.take().unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for l in std::io::BufReader::new(err).lines().map_while(Result::ok) {
                if tx.send(l).is_err() {
                    break;
                }
            }
        });
        Run {
            child,
            lines: rx,
            log: Vec::new(),
        }
    }

    /// Wait for a line containing `pat`; returns it.
    pub fn expect(&mut self, pat: &str) -> String {
        let deadline = Instant::now() + PATIENCE;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(l) => {
                    self.log.push(l.clone());
                    if l.contains(pat) {
                        return l;
                    }
                }
                Err(RecvTimeoutError::Timeout) => {
                    panic!("never saw '{pat}':\n{}", self.log.join("\n"))
                }
                Err(RecvTimeoutError::Disconnected) => {
                    panic!("launcher ended before '{pat}':\n{}", self.log.join("\n"))
                }
            }
        }
    }

    /// The run's shared-memory prefix, from the launcher's `bus:` line.
    pub fn prefix(&mut self) -> String {
        let l = self.expect("bus: prefix=");
        l.split_whitespace()
            .find_map(|w| w.strip_prefix("prefix="))
            .unwrap()
            .to_string()
    }

    /// Take the lines that arrived so far into the log (no waiting).
    pub fn catch_up(&mut self) {
        while let Ok(l) = self.lines.try_recv() {
            self.log.push(l);
        }
    }

    /// Ctrl-C, then the exit status once the launcher has ended (after its
    /// report is written); its last lines go into the log.
    pub fn interrupt(&mut self) -> ExitStatus {
        // SAFETY: signalling our own child.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGINT) };
        self.finish()
    }

    /// Ctrl-C, then the exit status and every line.
    pub fn interrupt_and_wait(mut self) -> (ExitStatus, Vec<String>) {
        let status = self.interrupt();
        (status, std::mem::take(&mut self.log))
    }

    /// Wait for the launcher to end by itself; the exit status and every
    /// line.
    pub fn wait(mut self) -> (ExitStatus, Vec<String>) {
        let status = self.finish();
        (status, std::mem::take(&mut self.log))
    }

    fn finish(&mut self) -> ExitStatus {
        let status = self.child.wait().unwrap();
        while let Ok(l) = self.lines.recv_timeout(Duration::from_secs(5)) {
            self.log.push(l);
        }
        status
    }
}

impl Drop for Run {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            // SAFETY: signalling our own child.
            unsafe { libc::kill(self.child.id() as i32, libc::SIGINT) };
            let _ = self.child.wait();
        }
    }
}
