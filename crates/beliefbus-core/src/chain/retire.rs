//! Retiring states to keep an incrementally built chain bounded
//! ("a bounded chain: states that carry negligible belief mass and lie far
//! from the belief are retired and their neighbours reconnected").
//!
//! The thesis only grows chains. Removing a set R of states is the reverse
//! of Alg. 2.3's insertion: S ← S \ R, then ConnectState(z) for every kept z
//! whose Near set met R (its row lost columns), so every row is again a
//! kernel over existing neighbours with the current n. Kept states keep
//! their ids and relative order (ids stay strictly increasing) and ids are
//! never reused ([`Chain::reserve_ids`]).
//!
//! Cost: one pass over the transitions to filter the rows, an import of the
//! kept states ([`Chain::from_view`], O(n log n) for the k-d tree), and one
//! ConnectState per affected row — work for the refine stage, not the filter.

use super::build::Chain;
use super::storage::ChainView;
use super::ChainError;
use crate::model::SdeModel;

/// Remove the states whose `keep` flag is false. Returns the reduced chain;
/// `touched` receives the slots (in the new chain) that were reconnected.
///
/// About 85 lines: filtering the rows, importing the kept states and
/// reconnecting the affected rows are the three steps of one version
/// change (see the module doc), in order.
pub fn retire<M: SdeModel + ?Sized>(
    model: &M,
    chain: &mut Chain,
    keep: &[bool],
    touched: &mut Vec<u32>,
) -> Result<Chain, ChainError> {
    let n = chain.len();
    if keep.len() != n {
        return Err(ChainError::State("keep mask length differs from n"));
    }
    let d = chain.dim();
    let next_id = chain.next_id();
    let cfg = chain.config().clone();
    let view = chain.view();
    let mut map = vec![u32::MAX; n];
    let mut m = 0u32;
    for i in 0..n {
        if keep[i] {
            map[i] = m;
            m += 1;
        }
    }
    let m = m as usize;
    let mut states = Vec::with_capacity(m * d);
    let mut ids = Vec::with_capacity(m);
    let mut holding = Vec::with_capacity(m);
    let mut radius = Vec::with_capacity(m);
    let mut offsets = Vec::with_capacity(m + 1);
    let mut cols = Vec::with_capacity(view.nnz());
    let mut probs = Vec::with_capacity(view.nnz());
    let mut affected = Vec::new();
    offsets.push(0u32);
    for i in 0..n {
        if !keep[i] {
            continue;
        }
        states.extend_from_slice(view.state(i));
        ids.push(view.ids[i]);
        holding.push(view.holding[i]);
        radius.push(view.radius[i]);
        let (c, p) = view.row(i);
        let start = cols.len();
        let mut kept = 0.0;
        for (&j, &pj) in c.iter().zip(p) {
            let nj = map[j as usize];
            if nj != u32::MAX {
                cols.push(nj);
                probs.push(pj);
                kept += pj;
            }
        }
        if cols.len() - start != c.len() {
            affected.push(map[i]);
            if kept > 0.0 {
                for v in &mut probs[start..] {
                    *v /= kept;
                }
            } else {
                // Every neighbour retired: absorbing until reconnected.
                cols.truncate(start);
                probs.truncate(start);
            }
        }
        offsets.push(cols.len() as u32);
    }
    let reduced = ChainView {
        dim: d,
        states: &states,
        ids: &ids,
        holding: &holding,
        radius: &radius,
        row_offsets: &offsets,
        cols: &cols,
        probs: &probs,
    };
    let mut out = Chain::from_view(model, cfg, &reduced)?;
    out.reserve_ids(next_id);
    touched.clear();
    for &i in &affected {
        out.reconnect(i as usize)?;
        touched.push(i);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chain::{ChainConfig, Sampler};
    use crate::model::linear::LinearSde;
    use crate::model::Bounds;
    use nalgebra::DMatrix;

    #[test]
    fn retiring_keeps_ids_and_rows_valid_and_never_reuses_ids() {
        let m = LinearSde::new(
            "ou2",
            DMatrix::from_row_slice(2, 2, &[-1.0, 0.0, 0.0, -1.0]),
            DMatrix::zeros(2, 0),
            DMatrix::from_row_slice(2, 2, &[0.5, 0.0, 0.0, 0.5]),
            DMatrix::identity(2, 2),
            vec![0.2, 0.2],
            Bounds::new_box(&[-2.0, -2.0], &[2.0, 2.0]).unwrap(),
        );
        let mut rng = crate::rng::stream(9, 0);
        let mut c = Chain::new(&m, ChainConfig::moment_matched(2)).unwrap();
        let mut t = vec![];
        c.grow(&m, &Sampler::Uniform, 500, &mut rng, &mut t)
            .unwrap();
        // Retire the right half of the box and the newest state.
        let keep: Vec<bool> = (0..c.len())
            .map(|i| c.state(i)[0] < 0.0 && i != c.len() - 1)
            .collect();
        let kept_ids: Vec<u32> = (0..c.len())
            .filter(|&i| keep[i])
            .map(|i| c.ids()[i])
            .collect();
        let mut touched = vec![];
        let mut r = retire(&m, &mut c, &keep, &mut touched).unwrap();
        assert_eq!(r.ids(), &kept_ids[..]);
        assert!(!touched.is_empty());
        // Reconnected rows point only at kept states, with the kernel of the
        // new n; every row is a distribution.
        r.view().validate().unwrap();
        // The affected rows are the ones near the cut.
        for &i in &touched {
            assert!(r.state(i as usize)[0] > -1.5, "{:?}", r.state(i as usize));
        }
        // A new state gets an id above every id ever used.
        let before = c.ids().iter().max().copied().unwrap();
        let mut rec = vec![];
        let slot = r.add_state(&m, &[-0.5, 0.5], &mut rec).unwrap();
        assert!(r.ids()[slot as usize] > before);
    }
}
