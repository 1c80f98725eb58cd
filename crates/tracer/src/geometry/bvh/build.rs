//! Building the 4-wide BVH: `obvhs` builds a binary BVH (PLOC with reinsertion, leaves collapsed by
//! its SAH), which is then collapsed into 4-wide nodes, and each leaf's triangles are packed into
//! SIMD packets of four (a leaf holds one; the layout allows up to eight).
//!
//! Why not obvhs' own 8-wide CWBVH: its quantized nodes are made for GPUs and bandwidth; on a CPU
//! the dequantization and the per-primitive callback cost more than they save, and its leaves test
//! one triangle at a time. Here a node test is one 4-lane slab test and a leaf test checks four
//! triangles at once.

use super::node::{Node4, NodeRef, TriPacket, MAX_LEAF_PACKETS};
use super::Mesh;
use glam::{Vec3, Vec3A, Vec4};
use obvhs::aabb::Aabb;
use obvhs::bvh2::builder::build_bvh2;
use obvhs::bvh2::Bvh2;
use obvhs::{Boundable, BvhBuildParams};
use std::time::Duration;

/// A triangle's (padded) bounding box, as the BVH builder sees it.
struct PaddedBox(Aabb);

impl Boundable for PaddedBox {
    fn aabb(&self) -> Aabb {
        self.0
    }
}

/// The flattened result: nodes (root first), packets, and the triangle order
/// (`order[k]` = old index of new triangle k).
pub(super) struct Built {
    pub nodes: Vec<Node4>,
    pub packets: Vec<TriPacket>,
    pub root: NodeRef,
    pub order: Vec<u32>,
    pub depth: usize,
}

/// The largest triangle count of a binary leaf: one packet. obvhs' collapse decides by SAH how many
/// triangles a leaf gets up to this bound. History (docs/benchmarks.md): leaves of up to eight
/// triangles with a collapse cost of 8 measured +4.8 % on the 330k scene when each ray was traced
/// alone; once a vertex's shadow and continuation rays were traced together, leaves of four with
/// obvhs' default cost measured +6.0 % ± 1.5 on the Cornell box and −0.1 % ± 0.9 on the 330k scene
/// against them (same-time A/B): fewer packet tests per ray (1.7 against 3.4 on the box) for a
/// node test more.
const MAX_PRIMS_PER_LEAF: u32 = 4;

/// The SAH cost of a node visit against one triangle test, for obvhs' collapse of small subtrees
/// into leaves: obvhs' default.
const COLLAPSE_TRAVERSAL_COST: f32 = 3.0;

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

pub(super) fn build(mesh: &Mesh) -> Built {
    // Every triangle's box padded (`padded`).
    let mut scene = Aabb::empty();
    for t in &mesh.positions {
        for v in t {
            scene.extend(Vec3A::from(*v));
        }
    }
    let pad = box_pad(scene.diagonal().max_element());
    let boxes: Vec<PaddedBox> = mesh
        .positions
        .iter()
        .map(|t| {
            let b = Aabb::from_points(&[Vec3A::from(t[0]), Vec3A::from(t[1]), Vec3A::from(t[2])]);
            let (min, max) = padded(b.min, b.max, pad);
            PaddedBox(Aabb::new(min, max))
        })
        .collect();
    // No spatial pre-splits: every triangle appears exactly once, so the mesh can be reordered.
    let mut params = BvhBuildParams::medium_build();
    params.pre_split = false;
    params.max_prims_per_leaf = MAX_PRIMS_PER_LEAF;
    params.collapse_traversal_cost = COLLAPSE_TRAVERSAL_COST;
    let bvh2 = build_bvh2(&boxes, params, &mut Duration::default());

    let mut out = Collapser {
        bvh2: &bvh2,
        mesh,
        nodes: Vec::new(),
        packets: Vec::new(),
        order: Vec::with_capacity(mesh.len()),
        depth: 0,
    };
    let root = out.subtree(0, 1);
    Built {
        nodes: out.nodes,
        packets: out.packets,
        root,
        order: out.order,
        depth: out.depth,
    }
}

struct Collapser<'a> {
    bvh2: &'a Bvh2,
    mesh: &'a Mesh,
    nodes: Vec<Node4>,
    packets: Vec<TriPacket>,
    order: Vec<u32>,
    depth: usize,
}

impl Collapser<'_> {
    /// Emits the subtree of binary node `index` and returns the reference to it.
    fn subtree(&mut self, index: usize, depth: usize) -> NodeRef {
        self.depth = self.depth.max(depth);
        let node = &self.bvh2.nodes[index];
        if node.prim_count > 0 {
            let first = node.first_index as usize;
            let prims = &self.bvh2.primitive_indices[first..first + node.prim_count as usize];
            return self.leaf(prims);
        }
        // Open the internal child with the largest surface area until there are four children:
        // the big boxes are the ones most rays enter, so they gain most from being tested at once.
        let mut children: Vec<usize> =
            vec![node.first_index as usize, node.first_index as usize + 1];
        while children.len() < 4 {
            let widest = children
                .iter()
                .enumerate()
                .filter(|(_, &c)| self.bvh2.nodes[c].prim_count == 0)
                .max_by(|(_, &a), (_, &b)| {
                    let area = |i: usize| self.bvh2.nodes[i].aabb.half_area();
                    area(a).total_cmp(&area(b))
                })
                .map(|(k, _)| k);
            let Some(k) = widest else { break };
            let c = children.swap_remove(k);
            let first = self.bvh2.nodes[c].first_index as usize;
            children.push(first);
            children.push(first + 1);
        }
        let slot = self.nodes.len();
        self.nodes.push(Node4::EMPTY);
        let mut built = Node4::EMPTY;
        let mut lo = [[f32::INFINITY; 4]; 3];
        let mut hi = [[f32::INFINITY; 4]; 3];
        for (k, &c) in children.iter().enumerate() {
            let b = self.bvh2.nodes[c].aabb;
            for axis in 0..3 {
                lo[axis][k] = b.min[axis];
                hi[axis][k] = b.max[axis];
            }
            built.child[k] = self.subtree(c, depth + 1);
            built.valid |= 1 << k;
        }
        for axis in 0..3 {
            built.bounds[0][axis] = Vec4::from_array(lo[axis]);
            built.bounds[1][axis] = Vec4::from_array(hi[axis]);
        }
        self.nodes[slot] = built;
        NodeRef::inner(slot as u32)
    }

    /// Packs a leaf's triangles (old indices `prims`) into packets of four, appending them to the
    /// new triangle order.
    fn leaf(&mut self, prims: &[u32]) -> NodeRef {
        let first_packet = self.packets.len() as u32;
        for chunk in prims.chunks(4) {
            let base = self.order.len() as u32;
            let tris: Vec<[Vec3; 3]> = chunk
                .iter()
                .map(|&p| self.mesh.positions[p as usize])
                .collect();
            self.order.extend_from_slice(chunk);
            self.packets.push(TriPacket::new(&tris, base));
        }
        let count = self.packets.len() as u32 - first_packet;
        debug_assert!(count >= 1 && count as usize <= MAX_LEAF_PACKETS);
        NodeRef::leaf(first_packet, count)
    }
}

const _: () = assert!(MAX_PRIMS_PER_LEAF as usize <= 4 * MAX_LEAF_PACKETS);
