//! The build: a binary tree split by surface area and orientation, collapsed into 4-wide nodes.

use super::bounds::cone_around;
use super::node::{Node4, Slot};
use super::{LightBounds, LightTree};
use glam::Vec3;

/// Buckets per axis when choosing a split (pbrt-v4's count).
const BUCKETS: usize = 12;

/// Below this depth splits are chosen by cost; from it on, at the middle of the index range. The
/// halving bounds the binary depth by this plus log₂ of the light count, and the 4-wide depth is at
/// most the binary one, which keeps every trail (two bits a level) within 128 bits for any count a
/// `u32` can index.
const COST_DEPTH: u32 = 30;

/// The most binary nodes between the root and a leaf.
const MAX_DEPTH: u32 = 63;

/// A node of the binary tree the build makes (then collapsed into [`Node4`]s).
struct Binary {
    bounds: LightBounds,
    /// Inner: the two children's indices. Leaf: the light's index, twice.
    children: [u32; 2],
    leaf: bool,
}

impl LightTree {
    /// Builds the tree over `lights` (bounds with powers normalised to sum to 1; light i is index
    /// i). Empty for no lights.
    pub(crate) fn new(lights: &[LightBounds]) -> LightTree {
        let mut tree = LightTree {
            nodes: Vec::new(),
            trails: vec![0; lights.len()],
        };
        if lights.is_empty() {
            return tree;
        }
        let mut binary = Vec::with_capacity(2 * lights.len());
        let mut order: Vec<u32> = (0..lights.len() as u32).collect();
        build_binary(lights, &mut order, 0, &mut binary);
        tree.nodes.reserve(lights.len() / 2 + 1);
        if binary[0].leaf {
            let root = Node4::new(&[(binary[0].bounds, Slot(Slot::LIGHT))]);
            tree.nodes.push(root);
        } else {
            tree.collapse(&binary, 0, 0, 0);
        }
        tree
    }

    /// Number of 4-wide nodes (for tests and memory reports).
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Approximate memory in bytes.
    pub fn bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<Node4>() + self.trails.len() * 16
    }

    /// Emits binary inner node `index` as a [`Node4`] whose children are its grandchildren (or
    /// deeper: the inner child of most power is opened until there are four), reached by `trail`
    /// at 4-wide depth `depth`. Returns the node's index.
    fn collapse(&mut self, binary: &[Binary], index: usize, trail: u128, depth: u32) -> usize {
        let mut children: Vec<usize> = binary[index].children.map(|c| c as usize).to_vec();
        while children.len() < 4 {
            let widest = children
                .iter()
                .enumerate()
                .filter(|(_, &c)| !binary[c].leaf)
                .max_by(|(_, &a), (_, &b)| binary[a].bounds.phi.total_cmp(&binary[b].bounds.phi))
                .map(|(k, _)| k);
            let Some(k) = widest else { break };
            let c = children.remove(k);
            // In place, so that lights keep their order across the slots.
            children.splice(k..k, binary[c].children.map(|c| c as usize));
        }
        let slot = self.nodes.len();
        self.nodes
            .push(Node4::new(&[(binary[index].bounds, Slot(0))]));
        let mut lanes = Vec::with_capacity(4);
        for (k, &c) in children.iter().enumerate() {
            let child_trail = trail | ((k as u128) << (2 * depth));
            let target = if binary[c].leaf {
                let light = binary[c].children[0];
                self.trails[light as usize] = child_trail;
                Slot(light | Slot::LIGHT)
            } else {
                Slot(self.collapse(binary, c, child_trail, depth + 1) as u32)
            };
            lanes.push((binary[c].bounds, target));
        }
        self.nodes[slot] = Node4::new(&lanes);
        slot
    }
}

/// Emits the binary subtree over `ids` (light indices) at `depth` into `out`; returns its index.
fn build_binary(
    lights: &[LightBounds],
    ids: &mut [u32],
    depth: u32,
    out: &mut Vec<Binary>,
) -> usize {
    let slot = out.len();
    if let [id] = *ids {
        out.push(Binary {
            bounds: lights[id as usize],
            children: [id, id],
            leaf: true,
        });
        return slot;
    }
    debug_assert!(depth < MAX_DEPTH);
    let mid = if depth < COST_DEPTH {
        split_by_cost(lights, ids).unwrap_or(ids.len() / 2)
    } else {
        ids.len() / 2
    };
    // Placeholder, filled in once both children are known.
    out.push(Binary {
        bounds: lights[ids[0] as usize],
        children: [0, 0],
        leaf: false,
    });
    let (first, second) = ids.split_at_mut(mid);
    let a = build_binary(lights, first, depth + 1, out);
    let b = build_binary(lights, second, depth + 1, out);
    out[slot] = Binary {
        bounds: out[a].bounds.union(&out[b].bounds),
        children: [a as u32, b as u32],
        leaf: false,
    };
    slot
}

/// Reorders `ids` so that the lights of the cheapest split (by [`LightBounds::cost`] over
/// [`BUCKETS`] buckets of centroids on each axis) come first, and returns how many there are; None
/// when no split separates them (every centroid the same).
fn split_by_cost(lights: &[LightBounds], ids: &mut [u32]) -> Option<usize> {
    let centroid = |id: u32| {
        let b = &lights[id as usize];
        (b.lo + b.hi) * 0.5
    };
    let (mut c_lo, mut c_hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    for &id in ids.iter() {
        let c = centroid(id);
        (c_lo, c_hi) = (c_lo.min(c), c_hi.max(c));
        let b = &lights[id as usize];
        (lo, hi) = (lo.min(b.lo), hi.max(b.hi));
    }
    let diagonal = hi - lo;
    let mut best: Option<(f32, usize, usize)> = None;
    for axis in 0..3 {
        let extent = c_hi[axis] - c_lo[axis];
        // Also skips NaN extents: only a positive extent can be binned.
        let binnable = extent > 0.0 && diagonal[axis] > 0.0;
        if !binnable {
            continue;
        }
        let bucket_of = |id: u32| {
            let t = (centroid(id)[axis] - c_lo[axis]) / extent;
            ((t * BUCKETS as f32) as usize).min(BUCKETS - 1)
        };
        let mut members: [Vec<u32>; BUCKETS] = Default::default();
        for &id in ids.iter() {
            members[bucket_of(id)].push(id);
        }
        let buckets: Vec<Option<LightBounds>> =
            members.iter().map(|m| bucket_bounds(lights, m)).collect();
        let kr = diagonal.max_element() / diagonal[axis];
        // Prefix unions from below and from above, then the cost of each split between buckets.
        let union = |acc: Option<LightBounds>, b: &Option<LightBounds>| match (acc, b) {
            (Some(a), Some(b)) => Some(a.union(b)),
            (a, b) => a.or(*b),
        };
        let mut below = [None; BUCKETS];
        let mut acc = None;
        for (k, b) in buckets.iter().enumerate() {
            acc = union(acc, b);
            below[k] = acc;
        }
        let mut acc = None;
        for split in (1..BUCKETS).rev() {
            acc = union(acc, &buckets[split]);
            let (Some(a), Some(b)) = (below[split - 1], acc) else {
                continue;
            };
            let cost = a.cost(kr) + b.cost(kr);
            if best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, axis, split));
            }
        }
    }
    let (_, axis, split) = best?;
    let extent = c_hi[axis] - c_lo[axis];
    // Stable partition: lights keep their relative order on each side.
    let (mut first, mut second): (Vec<u32>, Vec<u32>) = ids.iter().partition(|&&id| {
        let t = (centroid(id)[axis] - c_lo[axis]) / extent;
        ((t * BUCKETS as f32) as usize).min(BUCKETS - 1) < split
    });
    let mid = first.len();
    if mid == 0 || mid == ids.len() {
        return None;
    }
    first.append(&mut second);
    ids.copy_from_slice(&first);
    Some(mid)
}

/// The bounds of a bucket's lights, or None for an empty bucket.
fn bucket_bounds(lights: &[LightBounds], ids: &[u32]) -> Option<LightBounds> {
    let (&first, _) = ids.split_first()?;
    let mut b = lights[first as usize];
    for &id in ids {
        let l = &lights[id as usize];
        b.lo = b.lo.min(l.lo);
        b.hi = b.hi.max(l.hi);
        b.cos_e = b.cos_e.min(l.cos_e);
        b.two_sided |= l.two_sided;
    }
    b.phi = ids.iter().map(|&id| lights[id as usize].phi).sum();
    (b.w, b.cos_o) = cone_around(ids.iter().map(|&id| {
        let l = &lights[id as usize];
        (l.w, l.cos_o)
    }));
    Some(b)
}
