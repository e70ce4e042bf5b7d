//! Refine restarts with its chain: a restarted refine resumes from
//! the last chain snapshot it published — same lineage, same stable state
//! ids, next version numbers — so the filter's swap to the first version
//! after the restart is an ordinary remap by id (no mass lost to a restart
//! from the Gaussian summary).
//!
//! Mechanism: a checkpoint file in the run's state directory
//! ([`Resume::write_checkpoint`], temporary file then rename, so a kill
//! mid-write leaves the previous checkpoint intact). It is written at the
//! publish cadence from the slice just written into shared memory, *before*
//! that sample is sent: every version a subscriber can have seen is covered
//! by a checkpoint of at least that version, so the version after a restart
//! is always greater than any version published before the kill. Why not
//! read the last snapshot back from shared memory: the sample lives in the
//! dead publisher's data segment, which the supervisor removes with the
//! dead node's stale resources before restarting the stage, and a new
//! subscriber gets history only from a live publisher (iceoryx2 0.10).
//!
//! File format (little-endian u64 words): `MAGIC`, next state id, snapshot
//! length in words, then the snapshot words ([`crate::chain::snapshot`]).
//! The next id is stored because it is not in a snapshot: ids of states
//! retired from the end of the chain must never be reused.
//!
//! The chain is rebuilt with [`Chain::from_view`] (states, ids, holding
//! times, radii, transition rows; caches recomputed from the model), δ is
//! refitted to the holding times, the sampler's stream is re-seeded per
//! incarnation, and the belief to grow around is the last published belief
//! the supervisor hands over (until the live belief channel delivers).

use super::{chain_config, Refiner};
use crate::chain::snapshot::SnapshotView;
use crate::chain::Chain;
use crate::config::PipelineConfig;
use crate::ipc::StageKind;
use crate::rt::Clock;
use crate::stage::resume::Resume;
use crate::stage::StageError;

/// "BBCKPT01".
const MAGIC: u64 = u64::from_le_bytes(*b"BBCKPT01");
const HEADER: usize = 3;

/// Why a checkpoint cannot be used (the stage then starts a new chain).
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("refine checkpoint: {0}")]
    Format(&'static str),
    #[error("refine checkpoint: {0}")]
    Snapshot(String),
    #[error("refine checkpoint: cannot rebuild the chain: {0}")]
    Chain(String),
}

/// Encode a checkpoint of `snapshot` into `out` (cleared; no allocation
/// once it has grown to the largest snapshot).
pub fn encode(next_id: u32, snapshot: &[u64], out: &mut Vec<u8>) {
    out.clear();
    for w in [MAGIC, next_id as u64, snapshot.len() as u64]
        .iter()
        .chain(snapshot)
    {
        out.extend_from_slice(&w.to_le_bytes());
    }
}

/// Decode a checkpoint: (next id, snapshot words).
pub fn decode(bytes: &[u8]) -> Result<(u32, Vec<u64>), CheckpointError> {
    if !bytes.len().is_multiple_of(8) || bytes.len() < HEADER * 8 {
        return Err(CheckpointError::Format("truncated"));
    }
    let mut words = bytes
        .chunks_exact(8)
        .map(|c| u64::from_le_bytes(c.try_into().expect("8 bytes")));
    let (magic, next, len) = (
        words.next().unwrap_or(0),
        words.next().unwrap_or(0),
        words.next().unwrap_or(0),
    );
    if magic != MAGIC {
        return Err(CheckpointError::Format("not a refine checkpoint"));
    }
    let snap: Vec<u64> = words.collect();
    if snap.len() as u64 != len || next > u32::MAX as u64 {
        return Err(CheckpointError::Format("length mismatch"));
    }
    Ok((next as u32, snap))
}

/// Writes refine's checkpoints (a no-op outside a supervised run) on a
/// thread of its own: writing a version's file (a megabyte for 2000
/// states) and renaming it into place takes longer than a refine round
/// should give to it. The file is not synced: it serves restarts within
/// the run, which a crash of the machine ends anyway
/// ([`crate::rt::files::Durability::RunScoped`]). The stage begins a checkpoint
/// ([`Checkpointer::begin`]) and sends the version only once it is durable
/// ([`Checkpointer::is_durable`]), so the guarantee of the module doc holds.
pub struct Checkpointer {
    writer: Option<Writer>,
    /// A checkpoint begun and not yet reported back by the writer.
    pending: bool,
    /// Checkpoints written, and failed writes (not fatal: the stage keeps
    /// publishing; a restart then resumes from an older checkpoint or none).
    pub written: u64,
    pub failed: u64,
}

/// The writer thread's ends: buffers go out to be written and come back
/// (with the write's outcome) to be reused, so no allocation per version.
struct Writer {
    to: std::sync::mpsc::Sender<Vec<u8>>,
    from: std::sync::mpsc::Receiver<(Vec<u8>, Result<(), String>)>,
    spare: Option<Vec<u8>>,
}

impl Checkpointer {
    /// For a stage started with `resume` (its state directory, if any).
    pub fn new(resume: &Resume, max_words: usize) -> Self {
        let writer = resume.state_dir.as_ref().map(|_| {
            let (to, rx) = std::sync::mpsc::channel::<Vec<u8>>();
            let (tx, from) = std::sync::mpsc::channel();
            let r = resume.clone();
            std::thread::spawn(move || {
                for buf in rx {
                    let res = r
                        .write_checkpoint(StageKind::Refine, &buf)
                        .map_err(|e| e.to_string());
                    if tx.send((buf, res)).is_err() {
                        break;
                    }
                }
            });
            Writer {
                to,
                from,
                spare: Some(Vec::with_capacity((max_words + HEADER) * 8)),
            }
        });
        Self {
            writer,
            pending: false,
            written: 0,
            failed: 0,
        }
    }

    /// Begin saving `snapshot` (the words of the next version): encoded here
    /// (a copy), written by the writer thread. Waits for a
    /// previous checkpoint still in flight (the stage begins one only once
    /// the previous one is durable, so it does not wait).
    pub fn begin(&mut self, next_id: u32, snapshot: &[u64]) {
        while self.pending && !self.is_durable() {
            std::thread::yield_now();
        }
        let Some(w) = self.writer.as_mut() else {
            return;
        };
        let mut buf = w.spare.take().unwrap_or_default();
        encode(next_id, snapshot, &mut buf);
        if w.to.send(buf).is_ok() {
            self.pending = true;
        } else {
            self.failed += 1;
        }
    }

    /// Whether the last checkpoint begun is written (or failed: then a
    /// restart resumes from an older one, as before).
    pub fn is_durable(&mut self) -> bool {
        if !self.pending {
            return true;
        }
        let Some(w) = self.writer.as_mut() else {
            return true;
        };
        match w.from.try_recv() {
            Ok((buf, res)) => {
                w.spare = Some(buf);
                self.pending = false;
                match res {
                    Ok(()) => self.written += 1,
                    Err(e) => {
                        if self.failed == 0 {
                            eprintln!("refine: {e} (the chain will not survive a restart)");
                        }
                        self.failed += 1;
                    }
                }
                true
            }
            Err(std::sync::mpsc::TryRecvError::Empty) => false,
            Err(std::sync::mpsc::TryRecvError::Disconnected) => {
                self.pending = false;
                self.failed += 1;
                true
            }
        }
    }
}

/// The stage's builder: resumed from the run's refine checkpoint if there is
/// a usable one, else a new chain with a fresh lineage.
pub fn start(
    cfg: &PipelineConfig,
    clock: &dyn Clock,
    resume: &Resume,
) -> Result<Refiner, StageError> {
    if let Some(bytes) = resume.read_checkpoint(StageKind::Refine) {
        match Refiner::resumed(cfg, &bytes, resume) {
            Ok(r) => {
                eprintln!(
                    "refine: resumed chain lineage {:#x} at version {} ({} states)",
                    r.lineage(),
                    r.version(),
                    r.len()
                );
                return Ok(r);
            }
            Err(e) => eprintln!("refine: {e}; starting a new chain"),
        }
    }
    let lineage = crate::rng::splitmix64(clock.now_ns() ^ (std::process::id() as u64) << 32);
    Refiner::new(cfg, lineage)
}

impl Refiner {
    /// The builder resumed from a checkpoint: the chain of the snapshot with
    /// its lineage and version, growing around `resume`'s last belief.
    pub fn resumed(
        cfg: &PipelineConfig,
        bytes: &[u8],
        resume: &Resume,
    ) -> Result<Self, CheckpointError> {
        let (next_id, words) = decode(bytes)?;
        let snap = |e: &dyn std::fmt::Display| CheckpointError::Snapshot(e.to_string());
        let view = SnapshotView::parse(&words).map_err(|e| snap(&e))?;
        view.validate_rows(0, view.len()).map_err(|e| snap(&e))?;
        let mut r = Refiner::new(cfg, view.lineage).map_err(|e| snap(&e))?;
        let d = r.belief.dim;
        if view.dim != d || view.is_empty() {
            return Err(CheckpointError::Format("dimension or size"));
        }
        let chain = Chain::from_view(&r.model, chain_config(cfg, d), &view.chain_view())
            .map_err(|e| CheckpointError::Chain(e.to_string()))?;
        let mut chain = chain;
        chain.reserve_ids(next_id);
        r.eq.fit(chain.holding());
        r.chain = Some(chain);
        r.version = view.version;
        r.rng = crate::rng::stream(
            cfg.run.seed,
            0x5eed_c4a1 ^ crate::rng::splitmix64(resume.restarts as u64 + 1),
        );
        if let Some(g) = resume.belief.as_ref().and_then(|b| b.gaussian()) {
            r.set_belief(&g);
        }
        Ok(r)
    }

    /// The id the chain's next new state gets (0 without a chain).
    pub fn next_id(&self) -> u32 {
        self.chain.as_ref().map_or(0, |c| c.next_id())
    }

    /// The chain's lineage.
    pub fn lineage(&self) -> u64 {
        self.lineage
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::load;
    use std::path::Path;
    use std::time::Duration;

    fn cfg() -> PipelineConfig {
        load(
            &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/default.toml"),
            &[
                "filter.backend=\"chain\"".into(),
                // Resuming continues one incremental chain; moving-frame
                // versions are each a lineage of their own.
                "refine.moving_frame=false".into(),
                "refine.max_states=600".into(),
                "refine.initial_states=300".into(),
            ],
        )
        .unwrap()
    }

    fn publish(r: &mut Refiner) -> Vec<u64> {
        let mut out = vec![0u64; r.snapshot_words()];
        let n = r.write_snapshot(&mut out, 1).unwrap();
        out.truncate(n);
        out
    }

    #[test]
    fn a_resumed_refiner_continues_the_lineage_ids_and_versions() {
        let c = cfg();
        let mut a = Refiner::new(&c, 77).unwrap();
        a.work(Duration::from_millis(1)).unwrap();
        // Grow past max_states so states are retired (ids with gaps).
        while a.retired == 0 {
            a.work(Duration::from_millis(20)).unwrap();
        }
        let snap = publish(&mut a);
        let mut bytes = Vec::new();
        encode(a.next_id(), &snap, &mut bytes);
        let (next, words) = decode(&bytes).unwrap();
        assert_eq!((next, &words), (a.next_id(), &snap));

        let mut b = Refiner::resumed(&c, &bytes, &Resume::default()).unwrap();
        assert_eq!(b.lineage(), 77);
        assert_eq!(b.version(), a.version());
        assert_eq!(b.len(), a.len());
        assert_eq!(b.next_id(), a.next_id());
        assert_eq!(b.delta(), a.delta());
        // Same states with the same ids and the same transition rows.
        let snap_b = publish(&mut b);
        let (va, vb) = (
            SnapshotView::parse(&snap).unwrap(),
            SnapshotView::parse(&snap_b).unwrap(),
        );
        assert_eq!(vb.version, va.version + 1);
        assert_eq!(vb.lineage, va.lineage);
        assert_eq!(va.ids, vb.ids);
        assert_eq!(va.states, vb.states);
        assert_eq!(va.row_offsets, vb.row_offsets);
        assert_eq!(va.cols, vb.cols);
        assert_eq!(va.probs, vb.probs);
        // Growing on: new ids are above every id ever given out.
        let before = b.next_id();
        b.work(Duration::from_millis(10)).unwrap();
        let snap_c = publish(&mut b);
        let vc = SnapshotView::parse(&snap_c).unwrap();
        let old: std::collections::HashSet<u32> = va.ids.iter().copied().collect();
        for id in vc.ids.iter().filter(|i| !old.contains(i)) {
            assert!(*id >= before, "id {id} reused (next was {before})");
        }
        assert!(vc.ids.windows(2).all(|w| w[0] < w[1]));
    }

    #[test]
    fn a_damaged_checkpoint_is_refused_with_a_typed_error() {
        let c = cfg();
        let mut a = Refiner::new(&c, 5).unwrap();
        a.work(Duration::from_millis(1)).unwrap();
        let snap = publish(&mut a);
        let mut bytes = Vec::new();
        encode(a.next_id(), &snap, &mut bytes);
        let r = Resume::default();
        assert!(Refiner::resumed(&c, &bytes[..bytes.len() - 8], &r).is_err());
        assert!(Refiner::resumed(&c, &bytes[..13], &r).is_err());
        let mut bad = bytes.clone();
        bad[0] ^= 1;
        assert!(matches!(
            Refiner::resumed(&c, &bad, &r),
            Err(CheckpointError::Format(_))
        ));
        // A snapshot whose transition row points outside the chain.
        let view = SnapshotView::parse(&snap).unwrap();
        let n = view.len();
        let mut words = snap.clone();
        let col_pos = view.cols.as_ptr() as usize - snap.as_ptr() as usize;
        let w = col_pos / 8;
        words[w] = (n as u64 + 5) | ((n as u64 + 5) << 32);
        encode(a.next_id(), &words, &mut bad);
        assert!(Refiner::resumed(&c, &bad, &r).is_err());
    }

    #[test]
    fn a_checkpoint_begun_is_on_disk_once_it_is_durable() {
        use std::os::unix::fs::PermissionsExt;
        let dir = std::env::temp_dir().join(format!("bb-ckpt-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o700)).unwrap();
        let r = Resume {
            state_dir: Some(dir.clone()),
            ..Resume::default()
        };
        let mut ck = Checkpointer::new(&r, 16);
        for (k, words) in [vec![1u64, 2, 3], vec![9u64; 12]].into_iter().enumerate() {
            ck.begin(40 + k as u32, &words);
            while !ck.is_durable() {
                std::thread::yield_now();
            }
            assert_eq!(ck.written, k as u64 + 1);
            let (next, back) = decode(&r.read_checkpoint(StageKind::Refine).unwrap()).unwrap();
            assert_eq!((next, back), (40 + k as u32, words));
        }
        assert_eq!(ck.failed, 0);
        // Without a state directory nothing is written and all is durable.
        let mut none = Checkpointer::new(&Resume::default(), 16);
        none.begin(1, &[5]);
        assert!(none.is_durable());
        assert_eq!(none.written, 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
