//! The traversal stack of the two walks: a fixed array whose slots are not initialised when a walk
//! starts. Filling the arrays (256 and 128 bytes) on every ray was a `memset` per query, about
//! 1.5 % of a Cornell sample's instructions (`valgrind --tool=cachegrind`).

use std::mem::MaybeUninit;

/// A stack of at most `N` entries. Pushes are branch-free: a step writes up to `K` entries above the
/// top and keeps as many of them as it has children to visit.
pub(super) struct Stack<T: Copy, const N: usize> {
    /// Invariant: `slots[..len]` are initialised (every slot below `len` was written since the
    /// stack was made, and `len` only grows over written slots).
    slots: [MaybeUninit<T>; N],
    len: usize,
}

impl<T: Copy, const N: usize> Stack<T, N> {
    #[inline(always)]
    pub fn new() -> Self {
        Stack {
            slots: [const { MaybeUninit::uninit() }; N],
            len: 0,
        }
    }

    /// Whether `k` more entries fit.
    #[inline(always)]
    pub fn has_room(&self, k: usize) -> bool {
        self.len + k <= N
    }

    /// Writes `values` above the top and keeps the first `keep` of them (`keep` ≤ K) on the stack.
    /// Call only when [`Stack::has_room`]`(K)`; otherwise it panics (a bounds check).
    #[inline(always)]
    pub fn push_first<const K: usize>(&mut self, values: [T; K], keep: usize) {
        debug_assert!(keep <= K);
        for (slot, v) in self.slots[self.len..self.len + K].iter_mut().zip(values) {
            slot.write(v);
        }
        self.len += keep.min(K);
    }

    /// Pushes those of `values` whose bit is set in `mask`, in order (the last of them on top).
    /// Branch-free: each value is written to the slot above the top, which its bit keeps or
    /// leaves to be overwritten. Call only when [`Stack::has_room`]`(K)`; otherwise it panics (a
    /// bounds check).
    #[inline(always)]
    pub fn push_masked<const K: usize>(&mut self, values: [T; K], mask: u32) {
        // The count kept in a local, and the writes into a window of K slots, so that the
        // compiler need not store the length and load it back after every write (it could not
        // tell the slot written from the length: a chain of store-to-load forwards per push).
        let window = &mut self.slots[self.len..self.len + K];
        let mut kept = 0;
        for (k, v) in values.into_iter().enumerate() {
            window[kept].write(v);
            kept += (mask >> k & 1) as usize;
        }
        self.len += kept;
    }

    #[inline(always)]
    pub fn pop(&mut self) -> Option<T> {
        if self.len == 0 {
            return None;
        }
        self.len -= 1;
        // SAFETY: `len` was above this slot, so the slot is initialised (the type's invariant:
        // `push_first` and `push_masked` write every slot before `len` moves over it).
        Some(unsafe { self.slots[self.len].assume_init() })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entries_come_back_last_in_first_out_and_only_the_kept_ones() {
        let mut s: Stack<u64, 8> = Stack::new();
        assert_eq!(s.pop(), None);
        s.push_first([1, 2, 3], 2);
        s.push_first([4, 5, 6], 0);
        s.push_first([7, 8, 9], 3);
        assert!(s.has_room(3) && !s.has_room(4));
        let all: Vec<u64> = std::iter::from_fn(|| s.pop()).collect();
        assert_eq!(all, vec![9, 8, 7, 2, 1]);
        assert!(s.has_room(8));
        s.push_masked([1, 2, 3, 4], 0b1010);
        s.push_masked([5, 6, 7, 8], 0);
        s.push_masked([9, 10, 11, 12], 0b1101);
        let all: Vec<u64> = std::iter::from_fn(|| s.pop()).collect();
        assert_eq!(all, vec![12, 11, 9, 4, 2]);
    }
}
