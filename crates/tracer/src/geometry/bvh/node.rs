//! The memory layout of the 4-wide BVH: nodes holding their four children's boxes as SIMD lanes,
//! and leaves made of packets of four triangles in structure-of-arrays form.

use glam::{UVec4, Vec3, Vec4};

/// The most packets one leaf may hold (the count is stored in three bits of a [`NodeRef`]).
pub(super) const MAX_LEAF_PACKETS: usize = 8;

/// A child reference: an inner node's index, a leaf (first packet and packet count), or nothing.
///
/// Bit 31 set: a leaf, with the packet count − 1 in bits 28–30 and the first packet in bits 0–27;
/// `u32::MAX`: an empty slot; otherwise the index of an inner node.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct NodeRef(pub u32);

impl NodeRef {
    pub const NONE: NodeRef = NodeRef(u32::MAX);
    const LEAF: u32 = 1 << 31;
    /// Packets a leaf can start at: 2²⁸, i.e. a billion triangles, far above the loader's limit.
    pub const MAX_PACKETS: u32 = 1 << 28;

    pub fn inner(index: u32) -> NodeRef {
        debug_assert!(index < Self::LEAF);
        NodeRef(index)
    }

    pub fn leaf(first_packet: u32, count: u32) -> NodeRef {
        debug_assert!(
            first_packet < Self::MAX_PACKETS && (1..=MAX_LEAF_PACKETS as u32).contains(&count)
        );
        NodeRef(Self::LEAF | ((count - 1) << 28) | first_packet)
    }

    #[inline(always)]
    pub fn is_leaf(self) -> bool {
        self.0 & Self::LEAF != 0
    }

    /// The packets of a leaf, as a range of indices.
    #[inline(always)]
    pub fn packets(self) -> std::ops::Range<usize> {
        let first = (self.0 & (Self::MAX_PACKETS - 1)) as usize;
        let count = ((self.0 >> 28) & 7) as usize + 1;
        first..first + count
    }

    #[inline(always)]
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

/// Four children's boxes (lane k = child k) and the children. Empty slots are masked out by
/// `valid` (no box value is rejected by the slab test for every ray: an inverted box becomes
/// (−∞, +∞) for a negative direction, a box at +∞ is met at +∞ by an unbounded ray).
#[derive(Clone, Copy, Debug)]
#[repr(C, align(16))]
pub(super) struct Node4 {
    /// `bounds[0][axis]`: the children's lower bounds on that axis (x, y, z); `bounds[1][axis]`:
    /// their upper bounds. Indexed by side so a ray picks its near and far planes by the signs of
    /// its direction once, instead of sorting every slab's two distances.
    pub bounds: [[Vec4; 3]; 2],
    pub child: [NodeRef; 4],
    /// Bit k set: slot k holds a child.
    pub valid: u32,
}

impl Node4 {
    pub const EMPTY: Node4 = Node4 {
        bounds: [[Vec4::INFINITY; 3]; 2],
        child: [NodeRef::NONE; 4],
        valid: 0,
    };
}

/// Four triangles, lane k holding mesh triangle `ids[k]`. A packet of fewer than four repeats its
/// first triangle in the unused lanes, whose id is [`TriPacket::UNUSED`] (what masks them out:
/// [`TriPacket::valid`]). The ids name the mesh's own triangles, so the mesh keeps its order: the
/// builder moves none of its attributes.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(16))]
pub(super) struct TriPacket {
    /// `v[vertex][axis]`: the lanes are the four triangles.
    pub v: [[Vec4; 3]; 3],
    /// The mesh index of each lane's triangle; [`TriPacket::UNUSED`] in unused lanes.
    pub ids: [u32; 4],
}

impl TriPacket {
    /// The id of an unused lane (never a triangle's: meshes hold fewer than 2³⁰).
    pub const UNUSED: u32 = u32::MAX;

    /// The packet of the triangles `ids` (one to four) of `positions`.
    pub fn new(positions: &[[Vec3; 3]], ids: &[u32]) -> TriPacket {
        debug_assert!((1..=4).contains(&ids.len()));
        let tris: [[Vec3; 3]; 4] =
            std::array::from_fn(|k| positions[ids[k.min(ids.len() - 1)] as usize]);
        let mut v = [[Vec4::ZERO; 3]; 3];
        for (vertex, row) in v.iter_mut().enumerate() {
            for (axis, lanes) in row.iter_mut().enumerate() {
                *lanes = Vec4::from_array(tris.map(|t| t[vertex][axis]));
            }
        }
        TriPacket {
            v,
            ids: std::array::from_fn(|k| ids.get(k).copied().unwrap_or(Self::UNUSED)),
        }
    }

    /// Bit k set: lane k holds a triangle.
    #[inline(always)]
    pub fn valid(&self) -> u32 {
        UVec4::from_array(self.ids)
            .cmpne(UVec4::splat(Self::UNUSED))
            .bitmask()
    }

    /// The triangle in lane `k`.
    #[inline]
    pub fn triangle(&self, k: usize) -> [Vec3; 3] {
        let get = |vertex: usize| {
            Vec3::new(
                self.v[vertex][0][k],
                self.v[vertex][1][k],
                self.v[vertex][2][k],
            )
        };
        [get(0), get(1), get(2)]
    }
}
