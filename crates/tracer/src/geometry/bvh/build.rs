//! Building the 4-wide BVH, top down, by the surface area heuristic (`binned.rs` splits a range:
//! 32 bins per axis over the triangles' centres and sizes for large ranges, an exact sweep for
//! small ones).
//!
//! Each 4-wide node is formed the way the collapse of obvhs' binary tree formed it before: the
//! node's range is split in two, then the child with the largest surface area that is not a leaf is split
//! again, until there are four children (the big boxes are the ones most rays enter, so they gain
//! most from being tested at once). A range becomes a leaf when it has at most
//! [`MAX_PRIMS_PER_LEAF`] triangles and splitting it into two leaves would not lower its SAH cost,
//! a node visit costing [`COLLAPSE_TRAVERSAL_COST`] triangle tests. Each leaf's triangles are
//! packed into one SIMD packet.
//!
//! Speed and memory (10M triangles, 2 threads, docs/benchmarks.md): the builder moves one
//! 32-byte record per triangle (its padded box and index) and partitions it in place, so a
//! subtree owns a contiguous slice, the triangle order is the slice's order, and nothing but the
//! nodes is allocated during the build. Large ranges are binned in parallel, and the subtrees of
//! large nodes are built in parallel (rayon), each into a piece of its own, laid out in child order
//! and written once into the final node list (in parallel too).
//! Every choice depends only on the triangles, never on the thread count or on scheduling, so the
//! tree, the triangle order and so the image bits are the same on any machine.
//!
//! Why not obvhs' 8-wide CWBVH: its quantized nodes are made for GPUs and bandwidth; on a CPU the
//! dequantization and the per-primitive callback cost more than they save, and its leaves test one
//! triangle at a time. Here a node test is one 4-lane slab test and a leaf test checks four
//! triangles at once. Why not obvhs' binary PLOC builder, used before: on 10M triangles it took
//! 18.5 s and 2.76 GB where this one takes 10.3 s and 1.27 GB (the same machine, at the same time;
//! docs/benchmarks.md), and its trees render no faster.

use super::binned::{apply, plan, Info, Plan, Prim, Split};
use super::node::{Node4, NodeRef, TriPacket};
use super::Mesh;
use glam::{Vec3A, Vec4};
use rayon::prelude::*;
use std::mem::MaybeUninit;

/// The flattened result: nodes (root first), packets, and the triangle order (`order[k]` = the
/// mesh index of the tree's triangle k: the leaves, depth first, hold the triangles in this order).
pub(super) struct Built {
    pub nodes: Vec<Node4>,
    pub packets: Vec<TriPacket>,
    pub root: NodeRef,
    /// The order the mesh was put in: what the tests check the tree against.
    #[cfg_attr(not(test), allow(dead_code))]
    pub order: Vec<u32>,
    pub depth: usize,
}

/// The largest triangle count of a leaf: one packet. The SAH decides how many triangles a leaf gets
/// up to this bound. History (docs/benchmarks.md): leaves of up to eight triangles with a collapse
/// cost of 8 measured +4.8 % on the 330k scene when each ray was traced alone; once a vertex's
/// shadow and continuation rays were traced together, leaves of four with obvhs' default cost
/// measured +6.0 % ± 1.5 on the Cornell box and −0.1 % ± 0.9 on the 330k scene against them
/// (same-time A/B): fewer packet tests per ray (1.7 against 3.4 on the box) for a node test more.
pub(super) const MAX_PRIMS_PER_LEAF: u32 = 4;

/// The SAH cost of a node visit against one triangle test, for the leaf decision: obvhs' default,
/// kept from the builder before.
pub(super) const COLLAPSE_TRAVERSAL_COST: f64 = 3.0;

/// Nodes over at least this many triangles build their children's subtrees in parallel (and
/// decide the two halves of a split in parallel). Below, a subtree is built by one task into its
/// parent's node list: the appending and renumbering of a parallel child's nodes is not worth it.
const PAR_NODE_MIN: usize = 1 << 14;

/// The padding of the boxes of a mesh whose bounding box's largest extent is `extent`: a small
/// fraction of the scene's size (see [`padded`]).
pub(super) fn box_pad(extent: f32) -> f32 {
    extent * 1e-6 + f32::MIN_POSITIVE
}

/// The box from `lo` to `hi` padded by `pad` ([`box_pad`]) and a few ulps of its coordinates: flat
/// boxes (a triangle in an axis-aligned plane) and the rounding of the slab test must never cull a
/// box that the watertight triangle test would still hit. The tree's boxes and the flat test's
/// packet boxes are both made this way.
pub(super) fn padded(lo: Vec3A, hi: Vec3A, pad: f32) -> (Vec3A, Vec3A) {
    let (pad, ulps) = (Vec3A::splat(pad), |v: Vec3A| v.abs() * (4.0 * f32::EPSILON));
    (lo - pad - ulps(lo), hi + pad + ulps(hi))
}

/// Builds the tree over `mesh`.
pub(super) fn build(mesh: &Mesh) -> Built {
    let started = std::time::Instant::now();
    // Every triangle's box padded (`padded`), as a record the builder moves.
    let (lo, hi) = mesh.bounds();
    let pad = box_pad((hi - lo).max_element());
    let mut prims: Vec<Prim> = mesh
        .positions
        .par_iter()
        .enumerate()
        .map(|(i, t)| {
            let (a, b, c) = (Vec3A::from(t[0]), Vec3A::from(t[1]), Vec3A::from(t[2]));
            let (lo, hi) = padded(a.min(b).min(c), a.max(b).max(c), pad);
            Prim::new(lo, hi, i as u32)
        })
        .collect();
    let info = Info::of(&prims);
    let records_seconds = started.elapsed().as_secs_f64();
    let whole = Range {
        start: 0,
        len: prims.len(),
        info,
        plan: plan_range(&prims, &info, 0),
        depth: 0,
    };
    let mut piece = Piece::for_range(prims.len());
    let (mut root, depth) = match whole.plan {
        Plan::Leaf => (whole.leaf_ref(0), 1),
        Plan::Split(_) => node(&mut prims, 0, whole, 1, &mut piece),
    };
    // Laid out while the records are still held: measured, this peaks lower than after them (the
    // pieces' freed memory stays with the allocator).
    let len = piece.len;
    let mut nodes = Vec::with_capacity(len);
    piece.write_into(0, &mut nodes.spare_capacity_mut()[..len]);
    // SAFETY: `write_into` wrote every one of the first `len` slots (it asserts that the slots it is
    // given are as many as its piece's nodes, and its own nodes and tail pieces fill them).
    unsafe { nodes.set_len(len) };
    let tree_seconds = started.elapsed().as_secs_f64() - records_seconds;
    let order: Vec<u32> = prims.par_iter().map(Prim::index).collect();
    // The boxes are not needed any more: free them before the packets are made.
    drop(prims);
    let leaves = number_leaves(&mut nodes, &mut root);
    let packets = leaves
        .par_iter()
        .map(|&(first, count)| {
            TriPacket::new(
                &mesh.positions,
                &order[first as usize..(first + count) as usize],
            )
        })
        .collect();
    tracing::debug!(
        triangles = mesh.len(),
        records_seconds,
        tree_seconds,
        packets_seconds = started.elapsed().as_secs_f64() - records_seconds - tree_seconds,
        "built the 4-wide tree"
    );
    Built {
        nodes,
        packets,
        root,
        order,
        depth,
    }
}

/// A range of the primitives (`start` relative to the slice of the node being formed), with its
/// info, what to do with it, and its depth in the binary tree the 4-wide nodes collapse.
#[derive(Clone, Copy, Debug)]
struct Range {
    start: usize,
    len: usize,
    info: Info,
    plan: Plan,
    depth: usize,
}

impl Range {
    /// The leaf over this range, as a placeholder until [`number_leaves`] gives the leaves their
    /// packets: the first triangle (`base` + `start`) and the triangle count, in the packet fields.
    fn leaf_ref(&self, base: usize) -> NodeRef {
        NodeRef::leaf((base + self.start) as u32, self.len as u32)
    }
}

fn plan_range(prims: &[Prim], info: &Info, depth: usize) -> Plan {
    plan(
        prims,
        info,
        depth,
        MAX_PRIMS_PER_LEAF as usize,
        COLLAPSE_TRAVERSAL_COST,
    )
}

/// Splits `range` of `prims` by `split`, deciding both halves (in parallel for a large range).
fn open(prims: &mut [Prim], range: &Range, split: Split) -> (Range, Range) {
    let slice = &mut prims[range.start..range.start + range.len];
    let (mid, l, r) = apply(slice, &range.info, split);
    let (a, b) = slice.split_at(mid);
    let depth = range.depth + 1;
    let (pa, pb) = if range.len >= PAR_NODE_MIN {
        rayon::join(|| plan_range(a, &l, depth), || plan_range(b, &r, depth))
    } else {
        (plan_range(a, &l, depth), plan_range(b, &r, depth))
    };
    let left = Range {
        start: range.start,
        len: mid,
        info: l,
        plan: pa,
        depth,
    };
    let right = Range {
        start: range.start + mid,
        len: range.len - mid,
        info: r,
        plan: pb,
        depth,
    };
    (left, right)
}

/// Forms the 4-wide node over `prims` (triangles `base..` of the final order; `whole` covers all of
/// them and is to be split), at 4-wide depth `level`, appending it and its subtree to `out`.
/// Returns its reference and the depth of its deepest leaf.
fn node(
    prims: &mut [Prim],
    base: usize,
    whole: Range,
    level: usize,
    out: &mut Piece,
) -> (NodeRef, usize) {
    debug_assert!(whole.start == 0 && whole.len == prims.len());
    let mut kids = [whole; 4];
    let mut n = 1;
    while n < 4 {
        // The child to open: the largest by surface area that is to be split (the first of equals).
        let mut pick: Option<(usize, f64, Split)> = None;
        for (k, kid) in kids[..n].iter().enumerate() {
            if let Plan::Split(split) = kid.plan {
                let area = kid.info.bounds.half_area();
                if pick.is_none_or(|(_, a, _)| area > a) {
                    pick = Some((k, area, split));
                }
            }
        }
        let Some((k, _, split)) = pick else { break };
        let (a, b) = open(prims, &kids[k], split);
        kids.copy_within(k + 1..n, k + 2);
        kids[k] = a;
        kids[k + 1] = b;
        n += 1;
    }
    let kids = &kids[..n];

    let slot = out.push(Node4::EMPTY);
    let mut built = Node4::EMPTY;
    let mut lo = [[f32::INFINITY; 4]; 3];
    let mut hi = [[f32::INFINITY; 4]; 3];
    let mut depth = level;
    for (k, kid) in kids.iter().enumerate() {
        for axis in 0..3 {
            lo[axis][k] = kid.info.bounds.lo[axis];
            hi[axis][k] = kid.info.bounds.hi[axis];
        }
        built.valid |= 1 << k;
        if let Plan::Leaf = kid.plan {
            built.child[k] = kid.leaf_ref(base);
            depth = depth.max(level + 1);
        }
    }
    for axis in 0..3 {
        built.bounds[0][axis] = Vec4::from_array(lo[axis]);
        built.bounds[1][axis] = Vec4::from_array(hi[axis]);
    }

    // The inner children, each over its own slice of `prims`.
    let parallel = prims.len() >= PAR_NODE_MIN;
    let mut inner: Vec<(usize, &mut [Prim], &Range)> = Vec::with_capacity(4);
    let mut rest = &mut *prims;
    for (k, kid) in kids.iter().enumerate() {
        let (slice, tail) = rest.split_at_mut(kid.len);
        rest = tail;
        if let Plan::Split(_) = kid.plan {
            inner.push((k, slice, kid));
        }
    }
    let sub = |slice: &mut [Prim], kid: &Range, out: &mut Piece| {
        let whole = Range { start: 0, ..*kid };
        node(slice, base + kid.start, whole, level + 1, out)
    };
    if parallel && inner.len() > 1 {
        // Each child's subtree into a piece of its own, laid out after this one's nodes in child
        // order: the node numbers do not depend on which task finished first.
        let results: Vec<(usize, NodeRef, usize, Piece)> = inner
            .into_par_iter()
            .map(|(k, slice, kid)| {
                let mut own = Piece::for_range(kid.len);
                let (r, d) = sub(slice, kid, &mut own);
                (k, r, d, own)
            })
            .collect();
        for (k, r, d, own) in results {
            let offset = out.append(own);
            built.child[k] = NodeRef::inner(r.index() as u32 + offset);
            depth = depth.max(d);
        }
    } else {
        for (k, slice, kid) in inner {
            let (r, d) = sub(slice, kid, out);
            built.child[k] = r;
            depth = depth.max(d);
        }
    }
    out.nodes[slot] = built;
    (NodeRef::inner(slot as u32), depth)
}

/// The nodes of a subtree as they are built: its own `nodes` (inner references relative to its
/// first node), then the pieces of the subtrees that were built in parallel, laid out after them
/// in order (each with its offset from this piece's first node). Nodes are copied once, into the
/// final list ([`Piece::write_into`]), instead of once into every parallel ancestor's list: at
/// 10M triangles the nodes are 200 MB and there are about five parallel levels.
struct Piece {
    nodes: Vec<Node4>,
    tail: Vec<(u32, Piece)>,
    /// The node count of the whole piece: `nodes` and every piece of `tail`.
    len: usize,
}

impl Piece {
    /// An empty piece for a subtree over `triangles`, with room for its nodes if it is built by one
    /// task (leaves of ~3 triangles, ~3.5 children a node); one whose children are built in
    /// parallel holds only a node or a few.
    fn for_range(triangles: usize) -> Piece {
        let room = if triangles < PAR_NODE_MIN {
            triangles / 6 + 1
        } else {
            4
        };
        Piece {
            nodes: Vec::with_capacity(room),
            tail: Vec::new(),
            len: 0,
        }
    }

    /// Appends `node` to this piece's own nodes: its index.
    fn push(&mut self, node: Node4) -> usize {
        // Parallel subtrees are appended only once their parent's nodes are all pushed: a node is
        // split in parallel only if it has two inner children or more, and then it is its own
        // piece's last node or its parent's only inner child.
        debug_assert!(self.tail.is_empty());
        self.nodes.push(node);
        self.len += 1;
        self.nodes.len() - 1
    }

    /// Lays `piece` out after everything in this one: its offset from this piece's first node.
    fn append(&mut self, piece: Piece) -> u32 {
        let offset = self.len as u32;
        self.len += piece.len;
        self.tail.push((offset, piece));
        offset
    }

    /// Writes the piece's nodes into `out`, exactly its [`Piece::len`] slots, its first at index
    /// `base` of the final list and its inner references made absolute: its own nodes, then its
    /// tail pieces' (in parallel: 200 MB of nodes at 10M triangles, written into fresh pages).
    fn write_into(self, base: u32, out: &mut [MaybeUninit<Node4>]) {
        assert_eq!(out.len(), self.len, "a piece's slots");
        let (own, mut rest) = out.split_at_mut(self.nodes.len());
        for (slot, mut n) in own.iter_mut().zip(self.nodes) {
            for (c, child) in n.child.iter_mut().enumerate() {
                if n.valid & (1 << c) != 0 && !child.is_leaf() {
                    *child = NodeRef::inner(child.0 + base);
                }
            }
            slot.write(n);
        }
        let mut tails = Vec::with_capacity(self.tail.len());
        for (offset, piece) in self.tail {
            let (slots, later) = rest.split_at_mut(piece.len);
            rest = later;
            tails.push((base + offset, piece, slots));
        }
        // What makes the caller's `set_len` sound: not a slot left unwritten.
        assert!(
            rest.is_empty(),
            "a piece's length is its nodes and its tails'"
        );
        tails
            .into_par_iter()
            .for_each(|(base, piece, slots)| piece.write_into(base, slots));
    }
}

/// Gives every leaf its packet, numbering the leaves in depth-first order (children in slot
/// order), which is the order of their triangles: returns each packet's first triangle and count.
fn number_leaves(nodes: &mut [Node4], root: &mut NodeRef) -> Vec<(u32, u32)> {
    let mut leaves = Vec::with_capacity(nodes.len() * 3 + 1);
    let mut take = |r: &mut NodeRef| {
        let tris = r.packets();
        debug_assert_eq!(
            tris.start as u32,
            leaves.last().map_or(0, |&(f, c): &(u32, u32)| f + c)
        );
        *r = NodeRef::leaf(leaves.len() as u32, 1);
        leaves.push((tris.start as u32, tris.len() as u32));
    };
    if root.is_leaf() {
        take(root);
        return leaves;
    }
    enum Item {
        Node(u32),
        Leaf(u32, usize),
    }
    let mut stack = vec![Item::Node(root.0)];
    while let Some(item) = stack.pop() {
        match item {
            Item::Leaf(i, k) => take(&mut nodes[i as usize].child[k]),
            Item::Node(i) => {
                let n = &nodes[i as usize];
                for k in (0..4).rev() {
                    if n.valid & (1 << k) != 0 {
                        let c = n.child[k];
                        stack.push(if c.is_leaf() {
                            Item::Leaf(i, k)
                        } else {
                            Item::Node(c.0)
                        });
                    }
                }
            }
        }
    }
    leaves
}

// A leaf is one packet.
const _: () = assert!(MAX_PRIMS_PER_LEAF as usize <= 4);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{triangle_soup, uniform_stream};
    use glam::Vec3;
    use std::time::Instant;

    /// A displaced sphere of about `n` triangles (as `pathfarm bench scale` makes), then `soup`
    /// random triangles scattered through it.
    fn mesh(n: usize, soup: usize) -> Mesh {
        let rows = ((n / 2) as f64).sqrt().max(2.0) as usize;
        let cols = n / (2 * rows).max(1);
        let point = |i: usize, j: usize| {
            let (th, ph) = (
                std::f32::consts::PI * i as f32 / rows as f32,
                std::f32::consts::TAU * j as f32 / cols as f32,
            );
            let r = 1.0 + 0.05 * (7.0 * th).sin() * (5.0 * ph).cos();
            Vec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin()) * r
        };
        let mut rng = uniform_stream(0x9e37_79b9_7f4a_7c15);
        let mut m = triangle_soup(&mut rng, soup, 7, |rng| {
            Vec3::new(rng(), rng(), rng()) * 2.0 - 1.0
        });
        for i in 0..rows {
            for j in 0..cols {
                let (a, b) = (point(i, j), point(i + 1, j));
                let (c, d) = (point(i + 1, j + 1), point(i, j + 1));
                for t in [[a, b, c], [a, c, d]] {
                    if crate::geometry::renderable(&t) {
                        m.positions.push(t);
                        m.material.push(0);
                    }
                }
            }
        }
        m
    }

    /// Checks the tree's invariants: `order` is a permutation, every leaf holds one packet of at
    /// most four triangles (in order, covering every triangle once), and every node's box holds
    /// the padded boxes of its subtree's triangles.
    fn check(mesh: &Mesh, b: &Built) {
        let n = mesh.len();
        let mut seen = vec![false; n];
        for &i in &b.order {
            assert!(!std::mem::replace(&mut seen[i as usize], true), "{i} twice");
        }
        assert_eq!(b.order.len(), n);
        let (lo, hi) = mesh.bounds();
        let pad = box_pad((hi - lo).max_element());
        let tri_box = |k: u32| {
            let t = mesh.positions[b.order[k as usize] as usize];
            let (a, b, c) = (Vec3A::from(t[0]), Vec3A::from(t[1]), Vec3A::from(t[2]));
            padded(a.min(b).min(c), a.max(b).max(c), pad)
        };
        // Depth-first: each child's box and the range of triangles under it.
        type Boxes = Vec<(Vec3A, Vec3A, u32, u32)>;
        fn visit(
            mesh: &Mesh,
            b: &Built,
            r: NodeRef,
            next: &mut u32,
            depth: usize,
            deepest: &mut usize,
            boxes: &mut Boxes,
        ) {
            *deepest = (*deepest).max(depth);
            if r.is_leaf() {
                let p = r.packets();
                assert_eq!(p.len(), 1);
                let packet = &b.packets[p.start];
                let count = packet.valid().count_ones();
                assert!((1..=MAX_PRIMS_PER_LEAF).contains(&count));
                assert_eq!(packet.valid(), (1 << count) - 1);
                let ids = &b.order[*next as usize..(*next + count) as usize];
                assert_eq!(&packet.ids[..count as usize], ids);
                for (k, &id) in ids.iter().enumerate() {
                    assert_eq!(packet.triangle(k), mesh.positions[id as usize]);
                }
                *next += count;
                return;
            }
            let node = &b.nodes[r.index()];
            assert!(node.valid != 0);
            for k in 0..4 {
                if node.valid & (1 << k) == 0 {
                    continue;
                }
                let corner = |side: usize| {
                    Vec3A::new(
                        node.bounds[side][0][k],
                        node.bounds[side][1][k],
                        node.bounds[side][2][k],
                    )
                };
                let first = *next;
                visit(mesh, b, node.child[k], next, depth + 1, deepest, boxes);
                boxes.push((corner(0), corner(1), first, *next));
            }
        }
        let (mut next, mut deepest, mut boxes) = (0, 0, Vec::new());
        visit(mesh, b, b.root, &mut next, 1, &mut deepest, &mut boxes);
        assert_eq!(next as usize, n);
        assert_eq!(deepest, b.depth);
        for (lo, hi, first, end) in boxes {
            for t in first..end {
                let (tl, th) = tri_box(t);
                assert!(
                    lo.cmple(tl).all() && th.cmple(hi).all(),
                    "triangle {t} outside its node box"
                );
            }
        }
    }

    #[test]
    fn any_thread_count_builds_the_same_tree() {
        let mesh = mesh(120_000, 30_000);
        let on = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| build(&mesh))
        };
        let (one, four) = (on(1), on(4));
        check(&mesh, &one);
        assert_eq!(one.order, four.order);
        assert_eq!(one.root, four.root);
        assert_eq!(one.depth, four.depth);
        assert_eq!(one.nodes.len(), four.nodes.len());
        for (a, b) in one.nodes.iter().zip(&four.nodes) {
            assert_eq!(a.child, b.child);
            assert_eq!(a.valid, b.valid);
            for (x, y) in a.bounds.iter().flatten().zip(b.bounds.iter().flatten()) {
                assert_eq!(
                    x.to_array().map(f32::to_bits),
                    y.to_array().map(f32::to_bits)
                );
            }
        }
        assert_eq!(one.packets.len(), four.packets.len());
    }

    #[test]
    fn small_and_degenerate_meshes() {
        let tri = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let shifted = |t: [Vec3; 3], s: f32, o: Vec3| t.map(|v| v * s + o);
        let mut cases: Vec<Mesh> = Vec::new();
        // One triangle; a few; the same triangle many times (every centroid equal).
        for count in [1, 2, 3, 4, 5, 17, 3000] {
            cases.push(Mesh {
                positions: vec![tri; count],
                material: vec![0; count],
                ..Mesh::default()
            });
        }
        // Huge and tiny coordinates together, and coordinates near the f32 range's end.
        let mut m = Mesh::default();
        for k in 0..500 {
            let f = k as f32;
            m.positions
                .push(shifted(tri, 1e-30, Vec3::splat(f * 1e-30)));
            m.positions
                .push(shifted(tri, 1e30, Vec3::new(f * 1e31, 0.0, -f * 1e31)));
            m.positions
                .push(shifted(tri, 1.0, Vec3::new(f, 2.0 * f, 0.5)));
        }
        m.material = vec![0; m.positions.len()];
        cases.push(m.clone());
        // The scene's extent beyond f32: infinite padding, every box the whole space.
        m.positions.push(shifted(tri, 1e37, Vec3::splat(-3e38)));
        m.positions.push(shifted(tri, 1e37, Vec3::splat(3e38)));
        m.material = vec![0; m.positions.len()];
        cases.push(m);
        for mesh in &cases {
            let built = build(mesh);
            check(mesh, &built);
            if mesh.len() <= MAX_PRIMS_PER_LEAF as usize {
                assert!(built.root.is_leaf(), "{} triangles: one leaf", mesh.len());
            }
        }
    }

    #[test]
    fn binary_trees_over_boxes() {
        let mut rng = uniform_stream(7);
        for count in [1usize, 2, 3, 50, 1000] {
            let boxes: Vec<(Vec3A, Vec3A)> = (0..count)
                .map(|k| {
                    let lo = Vec3A::new(rng(), rng(), rng()) * 100.0 + (k % 3) as f32;
                    (lo, lo + Vec3A::new(rng(), rng(), rng()) + 0.1)
                })
                .collect();
            let (nodes, order) = super::super::binned::binary_tree(&boxes, 1, 3.0);
            let mut seen = vec![0; count];
            order.iter().for_each(|&i| seen[i as usize] += 1);
            assert!(seen.iter().all(|&s| s == 1));
            assert_eq!(nodes.len(), 2 * count - 1);
            // Every node's box holds its primitives' boxes.
            fn prims(nodes: &[super::super::binned::BinaryNode], i: usize, out: &mut Vec<u32>) {
                let n = nodes[i];
                if n.count > 0 {
                    out.extend(n.first..n.first + n.count);
                } else {
                    prims(nodes, n.first as usize, out);
                    prims(nodes, n.first as usize + 1, out);
                }
            }
            for (i, n) in nodes.iter().enumerate() {
                assert!(n.count <= 1);
                let mut inside = Vec::new();
                prims(&nodes, i, &mut inside);
                for k in inside {
                    let (lo, hi) = boxes[order[k as usize] as usize];
                    assert!(n.lo.cmple(lo).all() && hi.cmple(n.hi).all());
                }
            }
        }
    }

    /// Build time of a large mesh: `BVH_BUILD_TRIANGLES=10000000 cargo test --release -p
    /// pathfarm-tracer --lib build_speed -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn build_speed() {
        let n = std::env::var("BVH_BUILD_TRIANGLES")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(1_000_000);
        // Random triangles through the sphere, as large as a room's walls are to an object.
        let soup = std::env::var("BVH_BUILD_SOUP")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(0);
        let mesh = mesh(n, soup);
        for _ in 0..2 {
            let t = Instant::now();
            let built = build(&mesh);
            println!(
                "{} triangles: {:.3} s, {} nodes, {} packets, depth {}, SAH cost {:.3}",
                mesh.len(),
                t.elapsed().as_secs_f64(),
                built.nodes.len(),
                built.packets.len(),
                built.depth,
                sah_cost(&built)
            );
        }
    }

    /// The tree's SAH cost in node and packet tests per ray that enters the root box: each child
    /// box's half area over the root's, summed over the inner nodes (a node test each) and the
    /// leaves (a packet test each).
    fn sah_cost(b: &Built) -> f64 {
        let half_area = |lo: Vec3A, hi: Vec3A| {
            let d = (hi - lo).as_dvec3();
            d.x * d.y + d.y * d.z + d.z * d.x
        };
        let Some(root) = b.nodes.first() else {
            return 1.0;
        };
        let corner = |n: &Node4, side: usize, k: usize| {
            Vec3A::new(
                n.bounds[side][0][k],
                n.bounds[side][1][k],
                n.bounds[side][2][k],
            )
        };
        let (mut lo, mut hi) = (Vec3A::INFINITY, Vec3A::NEG_INFINITY);
        for k in (0..4).filter(|k| root.valid & (1 << k) != 0) {
            lo = lo.min(corner(root, 0, k));
            hi = hi.max(corner(root, 1, k));
        }
        let whole = half_area(lo, hi);
        let mut cost = 1.0;
        for n in &b.nodes {
            for k in (0..4).filter(|k| n.valid & (1 << k) != 0) {
                cost += half_area(corner(n, 0, k), corner(n, 1, k)) / whole;
            }
        }
        cost
    }
}
