//! The BVH's two traversals as step functions: [`Bvh::closest`] and [`Bvh::any`] run one walk each
//! to its end, `Bvh::closest_and_any` (`pair.rs`) advances two walks in turn.
//!
//! Neither walk is recursive (a subtree deeper than the fixed stack goes to the recursive
//! fallbacks), so that they inline into the ray queries: measured +3–5 % samples/s against the
//! recursive form.

use super::packet::PacketRay;
use super::stack::Stack;
use super::{
    key_child, key_near, sort_far_to_near, BoxRay, Bvh, Closest, NodeRef, LANES_SET, STACK,
};
use crate::geometry::TriangleHit;

/// The state of a closest-hit traversal between steps.
pub(super) struct ClosestWalk {
    /// Sorted keys (see `sort_far_to_near`): child and entry distance.
    stack: Stack<u64, STACK>,
    node: NodeRef,
    /// False once the walk has ended.
    pub live: bool,
}

/// The state of a shadow-ray traversal between steps.
pub(super) struct AnyWalk {
    stack: Stack<NodeRef, STACK>,
    node: NodeRef,
    /// False once the walk has ended.
    pub live: bool,
    /// Whether an accepted hit was found (the walk then ends at once).
    pub hit: bool,
}

impl ClosestWalk {
    #[inline(always)]
    pub fn new(root: NodeRef) -> ClosestWalk {
        ClosestWalk {
            stack: Stack::new(),
            node: root,
            live: true,
        }
    }
}

impl AnyWalk {
    #[inline(always)]
    pub fn new(root: NodeRef) -> AnyWalk {
        AnyWalk {
            stack: Stack::new(),
            node: root,
            live: true,
            hit: false,
        }
    }
}

impl Bvh {
    /// One step of the closest-hit walk of [`Bvh::closest_from`]: the current node is tested (a
    /// leaf's packets, or an inner node's boxes with the hit children pushed and the nearest taken
    /// next), and when nothing is taken the next subtree that can still hold a closer hit is popped.
    #[inline(always)]
    pub(super) fn closest_step(
        &self,
        w: &mut ClosestWalk,
        ray: &PacketRay<'_>,
        boxes: &BoxRay,
        best: &mut Closest,
        accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) {
        if w.node.is_leaf() {
            self.closest_in_leaf(w.node, ray, best, accept);
        } else {
            let n = &self.nodes[w.node.index()];
            let (mask, near) = boxes.test(n, best.t);
            if mask != 0 {
                let count = LANES_SET[mask as usize];
                let by_far = sort_far_to_near(mask, near, n);
                if w.stack.has_room(3) {
                    w.stack
                        .push_first([by_far[0], by_far[1], by_far[2]], count - 1);
                } else {
                    for &key in &by_far[..count - 1] {
                        self.closest_recursive(key_child(key), ray, boxes, best, accept);
                    }
                }
                w.node = key_child(by_far[count - 1]);
                return;
            }
        }
        loop {
            let Some(key) = w.stack.pop() else {
                w.live = false;
                return;
            };
            if key_near(key) <= best.t {
                w.node = key_child(key);
                return;
            }
        }
    }

    /// One step of the shadow-ray walk of [`Bvh::any_from`].
    #[inline(always)]
    pub(super) fn any_step(
        &self,
        w: &mut AnyWalk,
        ray: &PacketRay<'_>,
        boxes: &BoxRay,
        t_max: f32,
        accept: &mut impl FnMut(u32, &TriangleHit) -> bool,
    ) {
        if w.node.is_leaf() {
            if self.any_in_leaf(w.node, ray, t_max, accept) {
                w.hit = true;
                w.live = false;
                return;
            }
        } else {
            let n = &self.nodes[w.node.index()];
            let (mask, _) = boxes.test(n, t_max);
            if w.stack.has_room(4) {
                // The children are stored one by one: taking them through a table of lane
                // orders compiled to a gather for AVX-512 (docs/benchmarks.md). The last of them
                // is the next node at once rather than pushed and popped back (the same order,
                // without a store and its reload on the walk's chain).
                if mask != 0 {
                    let last = 31 - mask.leading_zeros();
                    w.stack.push_masked(n.child, mask & !(1 << last));
                    w.node = n.child[last as usize];
                    return;
                }
            } else {
                let mut m = mask;
                while m != 0 {
                    let k = m.trailing_zeros() as usize;
                    m &= m - 1;
                    if self.any_recursive(n.child[k], ray, boxes, t_max, accept) {
                        w.hit = true;
                        w.live = false;
                        return;
                    }
                }
            }
        }
        match w.stack.pop() {
            Some(node) => w.node = node,
            None => w.live = false,
        }
    }
}
