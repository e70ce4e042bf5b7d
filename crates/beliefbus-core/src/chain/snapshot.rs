//! Versioned chain snapshots: the flat layout the refine stage writes **in
//! place** into a shared-memory slice of `u64` words and the filter reads in
//! place (DESIGN.md: "large data go on slice services, written once in
//! place by the publisher and read in place by subscribers").
//!
//! A snapshot carries everything the filter needs to propagate on the
//! time-equalised chain M_n^δ (thesis §3.3, eq. 3.8–3.9) without building
//! anything from it:
//!
//! ```text
//! p^δ(z | z)  = 1 − δ/Δt(z)                      → stay[z]
//! p^δ(z | z') = (δ/Δt(z')) p(z | z')  (z ≠ z')    → incoming CSR (in_off, in_src, in_w)
//! p(z' | z)   (jump chain, row order)             → outgoing CSR (row_offsets, cols, probs)
//! ```
//! plus states (n × d), stable ids (strictly increasing, never reused),
//! holding times Δt, Near radii, cell volumes r^d/|Near| (to turn densities
//! into masses), δ, the version number and a lineage id (a new lineage — a
//! refine restarted from scratch — means ids are not comparable with the
//! previous chain's).
//!
//! Layout (all sections padded to whole words; f64 and u32 arrays are the
//! words' bit patterns, every bit pattern being a valid value):
//!
//! ```text
//! word 0..16   header: MAGIC, version, lineage, dim, n, nnz, δ (f64 bits), t_pub_ns, total words
//! f64 sections states[n·d] holding[n] radius[n] volume[n] stay[n] in_w[nnz] probs[nnz]
//! u32 sections ids[n] row_offsets[n+1] cols[nnz] in_off[n+1] in_src[nnz]
//! ```
//! [`SnapshotView::parse`] checks the header and the section sizes (O(1));
//! [`SnapshotView::validate_rows`] checks the index ranges (O(nnz)), which
//! the filter does in chunks while it prepares a version, before it reads a
//! single transition.

use super::equalize::PropagationKernel;
use super::storage::ChainView;

/// `b"BBCHAIN1"` as a little-endian word: format version 1.
pub const MAGIC: u64 = u64::from_le_bytes(*b"BBCHAIN1");
/// Header words.
pub const HEADER_WORDS: usize = 16;

/// Why a slice is not a usable snapshot.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SnapshotError {
    #[error("snapshot: bad magic (not a beliefbus chain snapshot v1)")]
    Magic,
    #[error("snapshot: {0}")]
    Shape(&'static str),
    #[error("snapshot: index out of range in row {0}")]
    Index(usize),
    #[error("snapshot: ids are not strictly increasing at {0}")]
    Ids(usize),
    #[error("snapshot of {need} words does not fit in {have}")]
    TooLarge { need: usize, have: usize },
}

fn words_u32(k: usize) -> usize {
    k.div_ceil(2)
}

/// Words of a snapshot of `n` states of dimension `dim` with `nnz`
/// transitions.
pub fn words_needed(dim: usize, n: usize, nnz: usize) -> usize {
    Sections::new(dim, n, nnz).end
}

/// Section offsets (in words) of a snapshot.
#[derive(Clone, Copy, Debug)]
struct Sections {
    states: usize,
    holding: usize,
    radius: usize,
    volume: usize,
    stay: usize,
    in_w: usize,
    probs: usize,
    ids: usize,
    row_offsets: usize,
    cols: usize,
    in_off: usize,
    in_src: usize,
    end: usize,
}

impl Sections {
    fn new(dim: usize, n: usize, nnz: usize) -> Self {
        let mut at = HEADER_WORDS;
        let mut take = |w: usize| {
            let s = at;
            at += w;
            s
        };
        let states = take(n * dim);
        let holding = take(n);
        let radius = take(n);
        let volume = take(n);
        let stay = take(n);
        let in_w = take(nnz);
        let probs = take(nnz);
        let ids = take(words_u32(n));
        let row_offsets = take(words_u32(n + 1));
        let cols = take(words_u32(nnz));
        let in_off = take(words_u32(n + 1));
        let in_src = take(words_u32(nnz));
        Self {
            states,
            holding,
            radius,
            volume,
            stay,
            in_w,
            probs,
            ids,
            row_offsets,
            cols,
            in_off,
            in_src,
            end: at,
        }
    }
}

fn as_f64(w: &[u64]) -> &[f64] {
    // SAFETY: u64 and f64 have the same size and alignment and every bit
    // pattern is a valid f64.
    unsafe { std::slice::from_raw_parts(w.as_ptr() as *const f64, w.len()) }
}

fn as_f64_mut(w: &mut [u64]) -> &mut [f64] {
    // SAFETY: as in `as_f64`; the borrow is exclusive.
    unsafe { std::slice::from_raw_parts_mut(w.as_mut_ptr() as *mut f64, w.len()) }
}

fn as_u32(w: &[u64], len: usize) -> &[u32] {
    debug_assert!(len <= 2 * w.len());
    // SAFETY: a u64 slice is 8-aligned and holds 2·len(w) ≥ len u32s; every
    // bit pattern is a valid u32.
    unsafe { std::slice::from_raw_parts(w.as_ptr() as *const u32, len) }
}

fn as_u32_mut(w: &mut [u64], len: usize) -> &mut [u32] {
    debug_assert!(len <= 2 * w.len());
    // SAFETY: as in `as_u32`; the borrow is exclusive.
    unsafe { std::slice::from_raw_parts_mut(w.as_mut_ptr() as *mut u32, len) }
}

/// What a writer puts in the header.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SnapshotMeta {
    pub version: u64,
    pub lineage: u64,
    pub t_pub_ns: u64,
}

/// Write the snapshot of `chain` (a compact view), its cell volumes and its
/// propagation kernel `kern` (built for δ = `kern.delta()` from the same
/// view) into `out`. Returns the words written.
pub fn write(
    out: &mut [u64],
    meta: SnapshotMeta,
    chain: &ChainView,
    volume: &[f64],
    kern: &PropagationKernel,
) -> Result<usize, SnapshotError> {
    let (dim, n, nnz) = (chain.dim, chain.len(), chain.nnz());
    let need = words_needed(dim, n, nnz);
    if need > out.len() {
        return Err(SnapshotError::TooLarge {
            need,
            have: out.len(),
        });
    }
    let (in_off, in_src, in_w) = kern.incoming();
    if volume.len() != n || kern.len() != n || in_src.len() != nnz {
        return Err(SnapshotError::Shape(
            "kernel or volumes do not match the chain",
        ));
    }
    let s = Sections::new(dim, n, nnz);
    let h = &mut out[..HEADER_WORDS];
    h.fill(0);
    h[0] = MAGIC;
    h[1] = meta.version;
    h[2] = meta.lineage;
    h[3] = dim as u64;
    h[4] = n as u64;
    h[5] = nnz as u64;
    h[6] = kern.delta().to_bits();
    h[7] = meta.t_pub_ns;
    h[8] = s.end as u64;
    let f = |out: &mut [u64], at: usize, v: &[f64]| {
        as_f64_mut(&mut out[at..at + v.len()]).copy_from_slice(v)
    };
    f(out, s.states, chain.states);
    f(out, s.holding, chain.holding);
    f(out, s.radius, chain.radius);
    f(out, s.volume, volume);
    f(out, s.stay, kern.stay());
    f(out, s.in_w, in_w);
    f(out, s.probs, chain.probs);
    let u = |out: &mut [u64], at: usize, v: &[u32]| {
        let w = words_u32(v.len());
        let dst = as_u32_mut(&mut out[at..at + w], 2 * w);
        dst[..v.len()].copy_from_slice(v);
        // Padding: a defined value, never an index.
        dst[v.len()..].fill(0);
    };
    u(out, s.ids, chain.ids);
    u(out, s.row_offsets, chain.row_offsets);
    u(out, s.cols, chain.cols);
    u(out, s.in_off, in_off);
    u(out, s.in_src, in_src);
    Ok(s.end)
}

/// Cell volumes r(z)^d/|Near(z)| of every state of `chain`.
pub fn cell_volumes(chain: &super::Chain, out: &mut Vec<f64>) {
    out.clear();
    out.extend((0..chain.len()).map(|i| chain.cell_volume(i)));
}

/// A snapshot of `chain` at time step `delta` in a new vector (tests and
/// offline tools; the refine stage writes into shared memory with
/// [`write`]).
pub fn encode(chain: &mut super::Chain, delta: f64, meta: SnapshotMeta) -> Vec<u64> {
    let mut vol = Vec::new();
    cell_volumes(chain, &mut vol);
    let view = chain.view();
    let kern = PropagationKernel::build(&view, delta, false);
    let mut out = vec![0u64; words_needed(view.dim, view.len(), view.nnz())];
    write(&mut out, meta, &view, &vol, &kern).expect("sized for it");
    out
}

/// Give the snapshot in `out` (written by [`write`] or [`encode`]) a new
/// version and lineage: offered again, the same chain is installed afresh
/// from the filter's Gaussian belief (a new lineage), which re-centres a
/// moving frame on the belief without building a chain.
pub fn relabel(out: &mut [u64], meta: SnapshotMeta) -> Result<(), SnapshotError> {
    if out.len() < HEADER_WORDS || out[0] != MAGIC {
        return Err(SnapshotError::Shape("not a snapshot"));
    }
    out[1] = meta.version;
    out[2] = meta.lineage;
    out[7] = meta.t_pub_ns;
    Ok(())
}

/// A snapshot read in place.
#[derive(Clone, Copy, Debug)]
pub struct SnapshotView<'a> {
    pub version: u64,
    pub lineage: u64,
    pub dim: usize,
    pub delta: f64,
    pub t_pub_ns: u64,
    pub states: &'a [f64],
    pub holding: &'a [f64],
    pub radius: &'a [f64],
    pub volume: &'a [f64],
    pub stay: &'a [f64],
    pub in_w: &'a [f64],
    pub probs: &'a [f64],
    pub ids: &'a [u32],
    pub row_offsets: &'a [u32],
    pub cols: &'a [u32],
    pub in_off: &'a [u32],
    pub in_src: &'a [u32],
}

/// The header of a snapshot and where its sections are: what
/// [`SnapshotView::parse`] checks once. A holder keeps it next to the words
/// ([`HeldSnapshot`]) and reads the view again without checking anything.
#[derive(Clone, Copy, Debug)]
pub struct SnapshotLayout {
    version: u64,
    lineage: u64,
    dim: usize,
    n: usize,
    nnz: usize,
    delta: f64,
    t_pub_ns: u64,
    sections: Sections,
}

impl SnapshotLayout {
    /// Read the header and locate the sections (O(1): no index is checked;
    /// see [`SnapshotView::validate_rows`]).
    pub fn parse(w: &[u64]) -> Result<Self, SnapshotError> {
        if w.len() < HEADER_WORDS {
            return Err(SnapshotError::Shape("shorter than its header"));
        }
        if w[0] != MAGIC {
            return Err(SnapshotError::Magic);
        }
        let small = |v: u64| usize::try_from(v).ok().filter(|&v| v < u32::MAX as usize);
        let (Some(dim), Some(n), Some(nnz)) = (small(w[3]), small(w[4]), small(w[5])) else {
            return Err(SnapshotError::Shape("sizes out of range"));
        };
        if dim == 0 || dim > crate::MAX_STATE {
            return Err(SnapshotError::Shape("state dimension out of range"));
        }
        let sections = Sections::new(dim, n, nnz);
        if w[8] != sections.end as u64 || sections.end > w.len() {
            return Err(SnapshotError::Shape(
                "total length does not match the sizes",
            ));
        }
        let delta = f64::from_bits(w[6]);
        if !(delta.is_finite() && delta > 0.0) {
            return Err(SnapshotError::Shape("δ must be positive and finite"));
        }
        Ok(Self {
            version: w[1],
            lineage: w[2],
            dim,
            n,
            nnz,
            delta,
            t_pub_ns: w[7],
            sections,
        })
    }

    /// The view of `w`, the words this layout was parsed from (or words
    /// at least as long with the same header). Slicing panics if `w` is
    /// shorter than the layout's end: a caller bug, never a bad snapshot.
    pub fn view<'a>(&self, w: &'a [u64]) -> SnapshotView<'a> {
        let (s, n, nnz, dim) = (&self.sections, self.n, self.nnz, self.dim);
        let fs = |at: usize, len: usize| as_f64(&w[at..at + len]);
        let us = |at: usize, len: usize| as_u32(&w[at..at + words_u32(len)], len);
        SnapshotView {
            version: self.version,
            lineage: self.lineage,
            dim,
            delta: self.delta,
            t_pub_ns: self.t_pub_ns,
            states: fs(s.states, n * dim),
            holding: fs(s.holding, n),
            radius: fs(s.radius, n),
            volume: fs(s.volume, n),
            stay: fs(s.stay, n),
            in_w: fs(s.in_w, nnz),
            probs: fs(s.probs, nnz),
            ids: us(s.ids, n),
            row_offsets: us(s.row_offsets, n + 1),
            cols: us(s.cols, nnz),
            in_off: us(s.in_off, n + 1),
            in_src: us(s.in_src, nnz),
        }
    }
}

/// A snapshot held as `S` (a shared-memory sample, a `Vec<u64>`) whose
/// header parsed: its view is read without re-checking, so code that holds
/// one never handles a parse error it cannot get. `S::as_ref` must return
/// the same words every time (true of every slice owner).
pub struct HeldSnapshot<S> {
    snap: S,
    layout: SnapshotLayout,
}

impl<S: AsRef<[u64]>> HeldSnapshot<S> {
    /// Parse the header of `snap` and keep both.
    pub fn new(snap: S) -> Result<Self, SnapshotError> {
        let layout = SnapshotLayout::parse(snap.as_ref())?;
        Ok(Self { snap, layout })
    }
    /// The snapshot read in place.
    pub fn view(&self) -> SnapshotView<'_> {
        self.layout.view(self.snap.as_ref())
    }
}

impl<'a> SnapshotView<'a> {
    /// Read the header and locate the sections (O(1): no index is checked;
    /// see [`Self::validate_rows`]).
    pub fn parse(w: &'a [u64]) -> Result<Self, SnapshotError> {
        Ok(SnapshotLayout::parse(w)?.view(w))
    }

    /// Number of states.
    pub fn len(&self) -> usize {
        self.ids.len()
    }
    /// Whether it has no state.
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }
    /// Number of transitions.
    pub fn nnz(&self) -> usize {
        self.cols.len()
    }
    /// State i.
    pub fn state(&self, i: usize) -> &'a [f64] {
        &self.states[i * self.dim..(i + 1) * self.dim]
    }

    /// Check the index structure of states `lo..hi`: offsets in range and
    /// non-decreasing, columns and sources < n, ids strictly increasing,
    /// masses and volumes finite. Checking `0..n` in pieces is the same as
    /// checking it at once.
    pub fn validate_rows(&self, lo: usize, hi: usize) -> Result<(), SnapshotError> {
        let n = self.len();
        let nnz = self.nnz();
        let hi = hi.min(n);
        if lo == 0 && (self.row_offsets[0] != 0 || self.in_off[0] != 0) {
            return Err(SnapshotError::Shape("offsets must start at 0"));
        }
        if hi == n && (self.row_offsets[n] as usize != nnz || self.in_off[n] as usize != nnz) {
            return Err(SnapshotError::Shape("offsets must end at nnz"));
        }
        for i in lo..hi {
            if i > 0 && self.ids[i] <= self.ids[i - 1] {
                return Err(SnapshotError::Ids(i));
            }
            for off in [self.row_offsets, self.in_off] {
                let (a, b) = (off[i] as usize, off[i + 1] as usize);
                if a > b || b > nnz {
                    return Err(SnapshotError::Index(i));
                }
            }
            let (a, b) = (
                self.row_offsets[i] as usize,
                self.row_offsets[i + 1] as usize,
            );
            if self.cols[a..b].iter().any(|&c| c as usize >= n) {
                return Err(SnapshotError::Index(i));
            }
            let (a, b) = (self.in_off[i] as usize, self.in_off[i + 1] as usize);
            if self.in_src[a..b].iter().any(|&c| c as usize >= n) {
                return Err(SnapshotError::Index(i));
            }
            if !(self.volume[i].is_finite() && self.volume[i] >= 0.0 && self.stay[i].is_finite()) {
                return Err(SnapshotError::Shape("volume or stay not finite"));
            }
        }
        Ok(())
    }

    /// The jump chain as a [`ChainView`] (for tools that use the library's
    /// chain code on a received snapshot).
    pub fn chain_view(&self) -> ChainView<'a> {
        ChainView {
            dim: self.dim,
            states: self.states,
            ids: self.ids,
            holding: self.holding,
            radius: self.radius,
            row_offsets: self.row_offsets,
            cols: self.cols,
            probs: self.probs,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chain::{Chain, ChainConfig, Sampler, TimeEqualized};
    use crate::model::linear::LinearSde;
    use crate::model::Bounds;
    use nalgebra::DMatrix;

    pub(crate) fn ou2() -> LinearSde {
        LinearSde::new(
            "ou2",
            DMatrix::from_row_slice(2, 2, &[-1.0, 0.5, -0.5, -1.0]),
            DMatrix::zeros(2, 0),
            DMatrix::from_row_slice(2, 2, &[0.5, 0.0, 0.0, 0.5]),
            DMatrix::identity(2, 2),
            vec![0.2, 0.2],
            Bounds::new_box(&[-2.5, -2.5], &[2.5, 2.5]).unwrap(),
        )
    }

    #[test]
    fn relabel_changes_only_the_version_lineage_and_time() {
        let m = ou2();
        let mut rng = crate::rng::stream(6, 0);
        let mut c = Chain::new(&m, ChainConfig::moment_matched(2)).unwrap();
        let mut t = vec![];
        c.grow(&m, &Sampler::Uniform, 101, &mut rng, &mut t)
            .unwrap();
        let meta = |v| SnapshotMeta {
            version: v,
            lineage: v + 10,
            t_pub_ns: v + 20,
        };
        let a = encode(&mut c, 0.01, meta(1));
        let mut b = a.clone();
        relabel(&mut b, meta(7)).unwrap();
        let s = SnapshotView::parse(&b).unwrap();
        assert_eq!((s.version, s.lineage, s.t_pub_ns), (7, 17, 27));
        let changed: Vec<usize> = (0..a.len()).filter(|&i| a[i] != b[i]).collect();
        assert_eq!(changed, vec![1, 2, 7]);
        let mut junk = vec![0u64; 4];
        assert!(relabel(&mut junk, meta(1)).is_err());
    }

    #[test]
    fn a_written_snapshot_reads_back_the_chain_and_its_kernel() {
        let m = ou2();
        let mut rng = crate::rng::stream(5, 0);
        let mut c = Chain::new(&m, ChainConfig::moment_matched(2)).unwrap();
        let mut t = vec![];
        c.grow(&m, &Sampler::Uniform, 301, &mut rng, &mut t)
            .unwrap();
        let mut eq = TimeEqualized::new(0.05).unwrap();
        eq.fit(c.holding());
        let vol: Vec<f64> = (0..c.len()).map(|i| c.cell_volume(i)).collect();
        let view = c.view();
        let kern = PropagationKernel::build(&view, eq.delta(), false);
        let need = words_needed(2, view.len(), view.nnz());
        let mut buf = vec![7u64; need + 5];
        let meta = SnapshotMeta {
            version: 3,
            lineage: 99,
            t_pub_ns: 1234,
        };
        assert_eq!(write(&mut buf, meta, &view, &vol, &kern).unwrap(), need);
        let s = SnapshotView::parse(&buf).unwrap();
        s.validate_rows(0, 100).unwrap();
        s.validate_rows(100, usize::MAX).unwrap();
        assert_eq!((s.version, s.lineage, s.t_pub_ns), (3, 99, 1234));
        assert_eq!(s.delta, eq.delta());
        assert_eq!(s.states, view.states);
        assert_eq!(s.ids, view.ids);
        assert_eq!(s.row_offsets, view.row_offsets);
        assert_eq!(s.cols, view.cols);
        assert_eq!(s.probs, view.probs);
        assert_eq!(s.volume, &vol[..]);
        let (io, isrc, iw) = kern.incoming();
        assert_eq!((s.in_off, s.in_src, s.in_w), (io, isrc, iw));
        assert_eq!(s.stay, kern.stay());
        s.chain_view().validate().unwrap();
        // Too small a buffer, a bad magic, a corrupted column: typed errors.
        let mut small = vec![0u64; need - 1];
        assert!(matches!(
            write(&mut small, meta, &view, &vol, &kern),
            Err(SnapshotError::TooLarge { .. })
        ));
        let mut bad = buf.clone();
        bad[0] ^= 1;
        assert_eq!(SnapshotView::parse(&bad).unwrap_err(), SnapshotError::Magic);
        let mut bad = buf.clone();
        bad[8] += 1;
        assert!(SnapshotView::parse(&bad).is_err());
        let mut bad = buf.clone();
        let sec = Sections::new(2, view.len(), view.nnz());
        bad[sec.cols] = u64::MAX; // cols[0], cols[1] = 0xffffffff
        let p = SnapshotView::parse(&bad).unwrap();
        assert_eq!(p.validate_rows(0, usize::MAX), Err(SnapshotError::Index(0)));
    }
}
