//! A 4-wide tree over boxes, one box a leaf: the top level of the instanced scenes' two-level BVH
//! (`geometry::instances`). Its nodes are the triangle tree's [`Node4`]s, so a node visit is the
//! same one slab test of four boxes ([`BoxRay::test`]) and the same branch-free ordering of the
//! children ([`sort_far_to_near`]); a leaf names a box by its position in the tree's order.
//!
//! It replaced a binary tree walked one box at a time, where a ray's walk through a few hundred
//! instances was most of an instanced scene's time (docs/benchmarks.md).

use super::binned::{binary_tree, BinaryNode};
use super::node::{Node4, NodeRef};
use super::stack::Stack;
use super::{key_child, key_near, sort_far_to_near, BoxRay, LANES_SET};
use glam::{Vec3, Vec3A};

/// Keys kept on the machine stack during a walk; a deeper walk spills the rest to the heap.
const TOP_STACK: usize = 48;

/// A 4-wide tree over boxes whose leaves are single boxes.
#[derive(Clone, Debug, Default)]
pub(crate) struct BoxTree {
    /// Root first; empty for no boxes.
    nodes: Vec<Node4>,
    /// The box around everything.
    bounds: Option<(Vec3, Vec3)>,
}

/// Boxes a tree can hold: a leaf's reference keeps the box's position in 28 bits.
pub(crate) const MAX_BOXES: usize = NodeRef::MAX_PACKETS as usize;

impl BoxTree {
    /// The tree over `boxes` (lower and upper corners; fewer than [`MAX_BOXES`]) and the order of
    /// its leaves: `order[k]` is the index in `boxes` of the box that the walks report as `k`.
    /// The binary SAH tree (`binary_tree`, a node visit costing `traversal_cost` box tests)
    /// collapsed to four children a node: the child with the largest surface area that is not a
    /// leaf is opened until a node has four, as the triangle tree's builder does.
    pub fn build(boxes: &[(Vec3A, Vec3A)], traversal_cost: f64) -> (BoxTree, Vec<u32>) {
        assert!(boxes.len() < MAX_BOXES, "{} boxes", boxes.len());
        if boxes.is_empty() {
            return (BoxTree::default(), Vec::new());
        }
        let (binary, order) = binary_tree(boxes, 1, traversal_cost);
        let mut nodes = vec![Node4::EMPTY];
        let mut pending = vec![(0usize, 0usize)];
        while let Some((slot, b)) = pending.pop() {
            let mut children = vec![b];
            if binary[b].count == 0 {
                children = vec![binary[b].first as usize, binary[b].first as usize + 1];
                while children.len() < 4 {
                    let area = |i: usize| {
                        let e = binary[i].hi - binary[i].lo;
                        e.x * e.y + e.y * e.z + e.z * e.x
                    };
                    let widest = (0..children.len())
                        .filter(|&c| binary[children[c]].count == 0)
                        .max_by(|&a, &c| area(children[a]).total_cmp(&area(children[c])));
                    let Some(c) = widest else { break };
                    let first = binary[children[c]].first as usize;
                    children[c] = first;
                    children.insert(c + 1, first + 1);
                }
            }
            let mut node = Node4::EMPTY;
            for (lane, &c) in children.iter().enumerate() {
                let BinaryNode {
                    lo,
                    hi,
                    count,
                    first,
                } = binary[c];
                for axis in 0..3 {
                    node.bounds[0][axis][lane] = lo[axis];
                    node.bounds[1][axis][lane] = hi[axis];
                }
                node.valid |= 1 << lane;
                node.child[lane] = if count > 0 {
                    debug_assert_eq!(count, 1);
                    NodeRef::leaf(first, 1)
                } else {
                    nodes.push(Node4::EMPTY);
                    pending.push((nodes.len() - 1, c));
                    NodeRef::inner((nodes.len() - 1) as u32)
                };
            }
            nodes[slot] = node;
        }
        let bounds = Some((binary[0].lo.into(), binary[0].hi.into()));
        (BoxTree { nodes, bounds }, order)
    }

    /// The box around every box, or `None` for an empty tree.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        self.bounds
    }

    /// Approximate bytes held.
    pub fn bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<Node4>()
    }

    /// Visits the leaves whose boxes the ray from `o` along `d` enters within the current limit,
    /// nearer boxes first: `visit(k, limit)` gets the leaf's position `k` in the tree's order and
    /// returns the new limit (a hit found lowers it, culling the boxes beyond), or `None` to stop.
    #[inline(always)]
    pub fn walk(&self, o: Vec3, d: Vec3, limit: f32, visit: impl FnMut(u32, f32) -> Option<f32>) {
        self.walk_with::<TOP_STACK>(o, d, limit, visit);
    }

    /// [`BoxTree::walk`] with a stack of `N` keys (the tests' small ones spill).
    #[inline(always)]
    fn walk_with<const N: usize>(
        &self,
        o: Vec3,
        d: Vec3,
        mut limit: f32,
        mut visit: impl FnMut(u32, f32) -> Option<f32>,
    ) {
        if self.nodes.is_empty() {
            return;
        }
        let boxes = BoxRay::new(o, d);
        let mut stack: Stack<u64, N> = Stack::new();
        let mut spill: Vec<u64> = Vec::new();
        let mut node = NodeRef::inner(0);
        loop {
            if node.is_leaf() {
                match visit(node.packets().start as u32, limit) {
                    Some(l) => limit = l,
                    None => return,
                }
            } else {
                let n = &self.nodes[node.index()];
                let (mask, near) = boxes.test(n, limit);
                if mask != 0 {
                    let count = LANES_SET[mask as usize];
                    let by_far = sort_far_to_near(mask, near, n);
                    if stack.has_room(3) {
                        stack.push_first([by_far[0], by_far[1], by_far[2]], count - 1);
                    } else {
                        spill.extend_from_slice(&by_far[..count - 1]);
                    }
                    node = key_child(by_far[count - 1]);
                    continue;
                }
            }
            // A deferred child whose box begins beyond the limit found since is skipped.
            node = loop {
                let Some(key) = spill.pop().or_else(|| stack.pop()) else {
                    return;
                };
                if key_near(key) <= limit {
                    break key_child(key);
                }
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::uniform_stream;

    /// Every leaf whose box a ray enters within the limit is visited once, and no other, for
    /// trees of one to a thousand boxes, with the walk's stack and with one of four keys (which
    /// spills); a lowered limit culls the boxes that begin beyond it.
    #[test]
    fn walks_visit_exactly_the_boxes_the_ray_enters() {
        let mut rng = uniform_stream(11);
        for count in [1usize, 2, 3, 4, 5, 17, 300, 1000] {
            let line = count == 1000;
            let boxes: Vec<(Vec3A, Vec3A)> = (0..count)
                .map(|k| {
                    let lo = if line {
                        // Boxes along x, each twice the size of the one before: a deep tree.
                        Vec3A::new(1.5f32.powi(k as i32 % 60), 0.0, 0.0)
                    } else {
                        Vec3A::new(rng(), rng(), rng()) * 20.0 - 10.0
                    };
                    (lo, lo + Vec3A::new(rng(), rng(), rng()) * 3.0 + 0.01)
                })
                .collect();
            let (tree, order) = BoxTree::build(&boxes, 3.0);
            let mut seen = vec![0; count];
            order.iter().for_each(|&i| seen[i as usize] += 1);
            assert!(seen.iter().all(|&s| s == 1));
            for _ in 0..200 {
                let o = Vec3::new(rng(), rng(), rng()) * 30.0 - 15.0;
                let d = (Vec3::new(rng(), rng(), rng()) * 2.0 - 1.0).normalize();
                let limit = if rng() < 0.5 {
                    f32::INFINITY
                } else {
                    25.0 * rng()
                };
                let enters = |k: usize| {
                    let (lo, hi) = boxes[order[k] as usize];
                    let inv = Vec3A::ONE / Vec3A::from(d);
                    let (a, b) = ((lo - Vec3A::from(o)) * inv, (hi - Vec3A::from(o)) * inv);
                    let near = a.min(b).max_element().max(0.0);
                    let far = a.max(b).min_element().min(limit);
                    (near <= far).then_some(near)
                };
                let (mut visited, mut spilled) = (vec![0; count], vec![0; count]);
                tree.walk(o, d, limit, |k, l| {
                    assert_eq!(l, limit);
                    visited[k as usize] += 1;
                    Some(l)
                });
                tree.walk_with::<4>(o, d, limit, |k, l| {
                    spilled[k as usize] += 1;
                    Some(l)
                });
                assert_eq!(visited, spilled);
                for (k, &v) in visited.iter().enumerate() {
                    // The walk's far distance is widened by a few ulps: a grazing box may be
                    // visited that the exact test misses, never the other way round.
                    if enters(k).is_some() {
                        assert_eq!(v, 1, "box {k} of {count}");
                    } else {
                        assert!(v <= 1);
                    }
                }
                // A limit lowered to the first box visited: no box beginning beyond it is.
                let mut first: Option<f32> = None;
                tree.walk(o, d, limit, |k, l| {
                    let near = enters(k as usize).unwrap_or(0.0);
                    if let Some(f) = first {
                        assert!(near <= f * (1.0 + 1e-5), "box at {near} beyond {f}");
                    }
                    let f = *first.get_or_insert(near);
                    Some(l.min(f))
                });
            }
        }
        assert!(BoxTree::build(&[], 3.0).0.bounds().is_none());
    }
}
