//! Who may publish on an internal channel (`obs`, `control`).
//!
//! Anything that can open a service of the run can publish on it (iceoryx2
//! has no access control between processes of the same user), so a stage
//! reading an internal channel admits a sample only from a publisher it
//! trusts, by the identity iceoryx2 records for each sample
//! ([`Origin`]: publishing port, node, the node's process):
//! - **under the launcher** (`beliefbus run` sets [`LAUNCHER_PID_ENV`] in
//!   every stage it spawns): publishers whose process is a child of that
//!   launcher — the run's own stages. Another process, even of the same
//!   user, cannot make itself the launcher's child.
//! - **started by hand** (no launcher): the first publisher heard from is
//!   bound; samples of any other are refused while it stays connected, and
//!   when it is gone (a restarted upstream stage) the next one is bound.
//!
//! Refused samples are counted by the caller (reason `foreign_publisher`).
//! See `docs/security.md` for what this does and does not stop.

use super::ports::{Message, Origin, Subscriber};

/// Environment variable carrying the launcher's pid to its stages.
pub const LAUNCHER_PID_ENV: &str = "BELIEFBUS_LAUNCHER_PID";

/// Verdicts remembered per publisher (a run has a handful).
const CACHE: usize = 64;

/// Admits the samples of trusted publishers on one channel.
#[derive(Debug)]
pub struct PublisherGate {
    launcher: Option<i32>,
    bound: Option<u128>,
    verdicts: Vec<(u128, bool)>,
}

impl PublisherGate {
    /// The policy of this process: under the launcher named by
    /// [`LAUNCHER_PID_ENV`], else first come.
    pub fn from_env() -> Self {
        let launcher = std::env::var(LAUNCHER_PID_ENV)
            .ok()
            .and_then(|v| v.parse::<i32>().ok())
            .filter(|&p| p > 0);
        match launcher {
            Some(p) => Self::under_launcher(p),
            None => Self::first_come(),
        }
    }

    /// Admit only publishers whose process is a child of `launcher`.
    pub fn under_launcher(launcher: i32) -> Self {
        Self {
            launcher: Some(launcher),
            bound: None,
            verdicts: Vec::new(),
        }
    }

    /// Admit the first publisher heard from while it stays connected.
    pub fn first_come() -> Self {
        Self {
            launcher: None,
            bound: None,
            verdicts: Vec::new(),
        }
    }

    /// Whether the sample from `o` (received on `sub`) is admitted.
    pub fn admit<M: Message>(&mut self, sub: &Subscriber<M>, o: &Origin) -> bool {
        match self.launcher {
            Some(l) => {
                if let Some(&(_, v)) = self.verdicts.iter().find(|(p, _)| *p == o.publisher) {
                    return v;
                }
                let v = o.pid > 0 && parent_of(o.pid) == Some(l);
                if self.verdicts.len() == CACHE {
                    self.verdicts.remove(0);
                }
                self.verdicts.push((o.publisher, v));
                v
            }
            None => match self.bound {
                Some(b) if b == o.publisher => true,
                Some(b) if sub.publisher_connected(b) => false,
                _ => {
                    self.bound = Some(o.publisher);
                    true
                }
            },
        }
    }
}

/// The parent of process `pid` (from `/proc/<pid>/stat`).
pub fn parent_of(pid: i32) -> Option<i32> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // "pid (comm) state ppid ...": comm may hold spaces and parentheses,
    // so read after the last ')'.
    let rest = &stat[stat.rfind(')')? + 1..];
    rest.split_whitespace().nth(1)?.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_parent_of_this_process_is_read_from_proc() {
        // SAFETY: getppid has no preconditions.
        let ppid = unsafe { libc::getppid() };
        assert_eq!(parent_of(std::process::id() as i32), Some(ppid));
        assert_eq!(parent_of(-5), None);
    }
}
