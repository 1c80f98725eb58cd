//! Cutting a primitive down to the vertices its triangles use, so that the work of every instance
//! (transforming, bounds, copying into the mesh) follows its triangles, not the size of the
//! accessors it reads (which may be shared by thousands of primitives).

use std::collections::HashMap;
use std::rc::Rc;

/// Renumbers `triangles` (indices into `n` vertices) to the vertices they use, in the order they are
/// first used, and returns those vertices' old indices; `None` (nothing changed) when they use all
/// `n`. Time and memory follow the triangles, however large `n` is.
pub(super) fn compact(triangles: &mut [[u32; 3]], n: usize) -> Option<Vec<u32>> {
    let corners = triangles.len().saturating_mul(3);
    let mut used = Vec::new();
    if n <= corners.saturating_mul(4) {
        // A dense table: n is within a small multiple of the corners.
        const UNSEEN: u32 = u32::MAX;
        let mut local = vec![UNSEEN; n];
        for &v in triangles.iter().flatten() {
            let slot = &mut local[v as usize];
            if *slot == UNSEEN {
                *slot = used.len() as u32;
                used.push(v);
            }
        }
        if used.len() == n {
            return None;
        }
        for v in triangles.iter_mut().flatten() {
            *v = local[*v as usize];
        }
    } else {
        let mut local: HashMap<u32, u32> = HashMap::with_capacity(corners.min(n));
        for v in triangles.iter_mut().flatten() {
            let next = used.len() as u32;
            let new = *local.entry(*v).or_insert(next);
            if new == next {
                used.push(*v);
            }
            *v = new;
        }
    }
    Some(used)
}

/// The elements of `all` at `used`.
pub(super) fn gather<T: Copy>(all: &[T], used: &[u32]) -> Rc<[T]> {
    used.iter().map(|&v| all[v as usize]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renumbers_in_order_of_first_use_and_keeps_full_primitives() {
        // Every vertex used: nothing changes.
        let mut full = [[2, 0, 1], [1, 2, 0]];
        assert_eq!(compact(&mut full, 3), None);
        assert_eq!(full, [[2, 0, 1], [1, 2, 0]]);
        // A dense table (n small against the corners) and a sparse map (n huge) agree.
        for n in [10, 1 << 30] {
            let mut tris = [[7, 3, 9], [3, 9, 5]];
            let used = compact(&mut tris, n).expect("vertices unused");
            assert_eq!(used, [7, 3, 9, 5]);
            assert_eq!(tris, [[0, 1, 2], [1, 2, 3]]);
            let all: Vec<u32> = (0..10).map(|v| v * 100).collect();
            let kept = gather(&all, &used[..]);
            assert_eq!(&kept[..], &[700, 300, 900, 500]);
        }
    }
}
