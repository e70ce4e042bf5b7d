//! A per-particle landmark map with shared structure: landmarks live in
//! fixed-size blocks behind `Arc`, so copying a particle's map on
//! resampling copies N/B pointers, not N landmarks, and a write to a shared
//! block copies that block alone (copy-on-write through `Arc::make_mut`).
//! M particles of N landmarks take O(M·N/B + distinct blocks) memory, at
//! most O(M·N) as the paper's implicit SLAM requires (paper 003 §4.2).
//!
//! Allocation happens only when a block is created or a shared block is
//! written; the resampling copy itself reuses the destination's buffer.

use std::sync::Arc;

/// Landmarks per block.
pub const BLOCK: usize = 16;

/// A map of landmarks of type `T`, indexed 0..len.
#[derive(Clone, Debug, Default)]
pub struct SharedMap<T: Clone> {
    blocks: Vec<Arc<Vec<T>>>,
    len: usize,
}

impl<T: Clone> SharedMap<T> {
    /// An empty map.
    pub fn new() -> Self {
        Self {
            blocks: Vec::new(),
            len: 0,
        }
    }

    /// Number of landmarks.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the map has no landmark.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Landmark k (None past the end).
    pub fn get(&self, k: usize) -> Option<&T> {
        self.blocks.get(k / BLOCK).and_then(|b| b.get(k % BLOCK))
    }

    /// Replace landmark k; copies its block first if another map shares it.
    /// Returns false if k is past the end.
    pub fn set(&mut self, k: usize, v: T) -> bool {
        if k >= self.len {
            return false;
        }
        Arc::make_mut(&mut self.blocks[k / BLOCK])[k % BLOCK] = v;
        true
    }

    /// Append a landmark; returns its index.
    pub fn push(&mut self, v: T) -> usize {
        let k = self.len;
        if k.is_multiple_of(BLOCK) {
            let mut b = Vec::with_capacity(BLOCK);
            b.push(v);
            self.blocks.push(Arc::new(b));
        } else {
            let last = self.blocks.len() - 1;
            Arc::make_mut(&mut self.blocks[last]).push(v);
        }
        self.len += 1;
        k
    }

    /// Remove landmark k, moving the last landmark into its place (the
    /// order is not kept); copies the touched blocks if shared. Returns
    /// false if k is past the end.
    pub fn swap_remove(&mut self, k: usize) -> bool {
        if k >= self.len {
            return false;
        }
        let last = self.len - 1;
        let lb = last / BLOCK;
        let v = Arc::make_mut(&mut self.blocks[lb])
            .pop()
            .expect("the last block holds the last landmark");
        if self.blocks[lb].is_empty() {
            self.blocks.pop();
        }
        self.len -= 1;
        if k < last {
            Arc::make_mut(&mut self.blocks[k / BLOCK])[k % BLOCK] = v;
        }
        true
    }

    /// Every landmark in index order.
    pub fn iter(&self) -> impl Iterator<Item = &T> {
        self.blocks.iter().flat_map(|b| b.iter())
    }

    /// Make `self` share `other`'s blocks (the resampling copy).
    pub fn share_from(&mut self, other: &Self) {
        self.blocks.clone_from(&other.blocks);
        self.len = other.len;
    }

    /// Number of blocks this map shares with `other` (for tests and memory
    /// accounting).
    pub fn shared_blocks_with(&self, other: &Self) -> usize {
        self.blocks
            .iter()
            .zip(&other.blocks)
            .filter(|(a, b)| Arc::ptr_eq(a, b))
            .count()
    }

    /// Distinct blocks over a set of maps (memory actually held).
    pub fn distinct_blocks<'a>(maps: impl Iterator<Item = &'a Self>) -> usize
    where
        T: 'a,
    {
        let mut ptrs: Vec<*const Vec<T>> = maps
            .flat_map(|m| m.blocks.iter().map(Arc::as_ptr))
            .collect();
        ptrs.sort_unstable();
        ptrs.dedup();
        ptrs.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn copies_share_blocks_until_written() {
        let mut a: SharedMap<u32> = SharedMap::new();
        for i in 0..40 {
            assert_eq!(a.push(i), i as usize);
        }
        assert_eq!(a.len(), 40);
        let mut b = SharedMap::new();
        b.share_from(&a);
        assert_eq!(b.shared_blocks_with(&a), 3);
        assert!(b.set(17, 1000));
        // Only the written block was copied; a is unchanged.
        assert_eq!(b.shared_blocks_with(&a), 2);
        assert_eq!(a.get(17), Some(&17));
        assert_eq!(b.get(17), Some(&1000));
        assert_eq!(SharedMap::distinct_blocks([&a, &b].into_iter()), 4);
        // Appending to a shared, partly filled last block copies it.
        b.push(99);
        assert_eq!(a.len(), 40);
        assert_eq!(b.get(40), Some(&99));
        assert_eq!(a.get(40), None);
        assert!(!a.set(40, 1));
        let v: Vec<u32> = b.iter().copied().collect();
        assert_eq!(v.len(), 41);
        assert_eq!(v[17], 1000);
        assert_eq!(v[39], 39);
    }

    #[test]
    fn swap_remove_moves_the_last_and_leaves_copies_alone() {
        let mut a: SharedMap<u32> = SharedMap::new();
        for i in 0..33 {
            a.push(i);
        }
        let mut b = SharedMap::new();
        b.share_from(&a);
        // Removing 5 moves 32 (alone in the third block) into slot 5.
        assert!(b.swap_remove(5));
        assert_eq!(b.len(), 32);
        assert_eq!(b.get(5), Some(&32));
        assert_eq!(b.get(32), None);
        assert_eq!(b.shared_blocks_with(&a), 1);
        assert_eq!(a.len(), 33);
        assert_eq!(a.get(5), Some(&5));
        // Removing the last element moves nothing.
        assert!(b.swap_remove(31));
        assert_eq!(b.len(), 31);
        assert_eq!(b.get(30), Some(&30));
        assert!(!b.swap_remove(31));
        let mut c: SharedMap<u32> = SharedMap::new();
        c.push(7);
        assert!(c.swap_remove(0));
        assert!(c.is_empty());
        assert_eq!(c.push(8), 0);
        assert_eq!(c.get(0), Some(&8));
    }
}
