//! Top-down SAH splitting of a range of boxes, shared by the 4-wide triangle BVH (`build.rs`) and
//! the binary tree over instances ([`binary_tree`]).
//!
//! A range is split by the surface area heuristic: binned (Wald, "On fast Construction of
//! SAH-based Bounding Volume Hierarchies", 2007: [`BINS`] bins per axis over the bounds of the
//! primitives' keys) for large ranges, and by an exact sweep over the keys in order on each axis for
//! small ones, where bins are too coarse. The keys have four axes: the box's centre in x, y and z,
//! and its size ([`Prim::key`]), so that large and small primitives at the same place can be set
//! apart. The chosen split partitions the range in place, so every subtree owns a contiguous slice
//! and the final order of the primitives is the slice's order.
//!
//! Determinism: the result depends only on the boxes. Bins are merged with min, max and integer
//! counts, which give the same answer in any order, so the parallel binning of large ranges
//! (rayon, chunks of a fixed size) and the sequential one agree bit for bit; every SAH cost is a
//! sequential sum in one task. The sweeps' areas are worked out in `f32` from extents scaled by
//! the range's largest, so that boxes far beyond any sensible scene (scenes built by hand skip the
//! loader's coordinate bound) still compare; a range with no finite split cost (an infinite box),
//! or identical keys, falls back to a median split.

use glam::{BVec4A, DVec3, Mat4, UVec4, Vec3A, Vec4};
use rayon::prelude::*;

/// Bins per axis for a large range: 32 keeps the tree within about a percent of a full sweep's SAH
/// cost, and the sweep over them is negligible next to binning a large range.
const BINS: usize = 32;

/// Bins per axis for a range of fewer than [`MANY`] primitives: there the sweep over the bins
/// costs as much as binning the primitives, and a few dozen primitives gain little from more.
const FEW_BINS: usize = 16;
const MANY: usize = 256;

/// Ranges of at most this many primitives are split by the exact sweep (the keys in order on each
/// axis, [`orders`]): with few primitives, centroids often share a bin, and ordering a handful is
/// as cheap as binning.
const SWEEP_MAX: usize = 16;
// `orders` masks ranks with `SWEEP_MAX - 1`.
const _: () = assert!(SWEEP_MAX.is_power_of_two());

/// Ranges of more than this many primitives choose their split from a sample of about this many
/// (every k-th primitive of the range, k fixed by its length): for a range that large the sample's
/// SAH estimate chooses about as well as the whole range's (the trees' SAH costs differ by a few
/// tenths of a percent either way, docs/benchmarks.md), and the upper levels then cost one pass
/// (the partition) instead of two. The partition works out both sides' exact bounds, so the
/// tree's boxes never depend on the sample.
const SAMPLE: usize = 1 << 12;

/// Ranges of at least this many primitives have their info worked out in parallel, in chunks of
/// [`INFO_CHUNK`].
const PAR_INFO_MIN: usize = 1 << 16;
const INFO_CHUNK: usize = 1 << 14;

/// A node more this many binary levels below the root is split at the object median on its
/// widest centroid axis instead of by SAH: SAH alone makes chains on inputs such as geometrically
/// spaced triangles, and a median split bounds the depth (and the builder's recursion) at
/// `MEDIAN_DEPTH + log2 n`.
pub(super) const MEDIAN_DEPTH: usize = 96;

/// An axis-aligned box; empty as (+∞, −∞).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Box3 {
    pub lo: Vec3A,
    pub hi: Vec3A,
}

impl Box3 {
    pub const EMPTY: Box3 = Box3 {
        lo: Vec3A::INFINITY,
        hi: Vec3A::NEG_INFINITY,
    };

    #[inline(always)]
    pub fn grow(&mut self, lo: Vec3A, hi: Vec3A) {
        self.lo = self.lo.min(lo);
        self.hi = self.hi.max(hi);
    }

    #[inline(always)]
    fn union(self, other: Box3) -> Box3 {
        Box3 {
            lo: self.lo.min(other.lo),
            hi: self.hi.max(other.hi),
        }
    }

    /// Half the surface area, the products in `f64`: finite for any box narrower than `f32::MAX`
    /// (a wider one has an infinite area, and the builder falls back to median splits).
    #[inline(always)]
    pub fn half_area(&self) -> f64 {
        let d: DVec3 = (self.hi - self.lo).as_dvec3();
        d.x * d.y + d.y * d.z + d.z * d.x
    }
}

/// Bounds of the primitives' split keys ([`Prim::key`]): lanes x, y, z the centroid, w the size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Keys {
    pub lo: Vec4,
    pub hi: Vec4,
}

impl Keys {
    const EMPTY: Keys = Keys {
        lo: Vec4::INFINITY,
        hi: Vec4::NEG_INFINITY,
    };

    #[inline(always)]
    fn grow(&mut self, k: Vec4) {
        self.lo = self.lo.min(k);
        self.hi = self.hi.max(k);
    }

    fn union(self, other: Keys) -> Keys {
        Keys {
            lo: self.lo.min(other.lo),
            hi: self.hi.max(other.hi),
        }
    }
}

/// A primitive as the builder moves it: its box, with its index stored in the w lane of the lower
/// corner and its size key ([`Prim::key`]'s w lane) in that of the upper one (32 bytes: the
/// partitions move one record, not a box and an index, and the key is not worked out again at
/// every level).
///
/// The w lane goes through every vector operation on the box, so the index is stored as the bits
/// of a normal float ([`INDEX_BIAS`] + index: 1.0 for index 0). Stored as is, a small index is a
/// subnormal float, and each operation on it takes a microcode assist: the build ran 30 times
/// slower.
#[derive(Clone, Copy, Debug)]
#[repr(C)]
pub(super) struct Prim {
    lo: Vec4,
    hi: Vec4,
}

/// See [`Prim`]: indices below 2³⁰ map to floats from 1.0 to 2¹²⁸ (exclusive), all normal.
const INDEX_BIAS: u32 = 0x3f80_0000;

impl Prim {
    #[inline(always)]
    pub fn new(lo: Vec3A, hi: Vec3A, index: u32) -> Prim {
        debug_assert!(index < 1 << 30);
        let d = hi - lo;
        let area = d.x * d.y + d.y * d.z + d.z * d.x;
        // The bits of any float over 2²³: zero or a normal float of at most 512, never NaN.
        let size = area.to_bits() as f32 * (1.0 / 8_388_608.0);
        Prim {
            lo: lo.extend(f32::from_bits(INDEX_BIAS + index)),
            hi: hi.extend(size),
        }
    }

    #[inline(always)]
    pub fn index(&self) -> u32 {
        self.lo.w.to_bits() - INDEX_BIAS
    }

    #[inline(always)]
    fn lo(&self) -> Vec3A {
        Vec3A::from_vec4(self.lo)
    }

    #[inline(always)]
    fn hi(&self) -> Vec3A {
        Vec3A::from_vec4(self.hi)
    }

    /// What the splits sort and bin by: in x, y and z the box's centre (halves added: no overflow
    /// near `f32::MAX`), in w its size, a piecewise linear log₂ of its half area (the float's bits
    /// over 2²³). Splitting by size too lets SAH set large triangles (a room's walls around a
    /// detailed object) apart from small ones at the same place, which centroids alone cannot: on
    /// a Cornell box around a 330k-triangle sphere, the nodes' summed area was 17 % higher without
    /// it (and the render 6.8 % slower than with the PLOC tree before). NaN lanes (an infinite box)
    /// become zero, so that key bounds and bins stay well defined.
    #[inline(always)]
    fn key(&self) -> Vec4 {
        let c = self.lo * 0.5 + self.hi * 0.5;
        let k = Vec4::select(BVec4A::new(true, true, true, false), c, self.hi);
        Vec4::select(k.cmpeq(k), k, Vec4::ZERO)
    }
}

/// What the builder knows of a range: the union of its boxes and the bounds of its keys.
#[derive(Clone, Copy, Debug)]
pub(super) struct Info {
    pub bounds: Box3,
    pub keys: Keys,
}

impl Info {
    const EMPTY: Info = Info {
        bounds: Box3::EMPTY,
        keys: Keys::EMPTY,
    };

    #[inline(always)]
    fn add(&mut self, p: &Prim) {
        self.bounds.grow(p.lo(), p.hi());
        self.keys.grow(p.key());
    }

    fn union(self, other: Info) -> Info {
        Info {
            bounds: self.bounds.union(other.bounds),
            keys: self.keys.union(other.keys),
        }
    }

    /// The info of `prims`, in parallel for a large range (min and max: the same in any order).
    pub fn of(prims: &[Prim]) -> Info {
        let seq = |chunk: &[Prim]| {
            let mut info = Info::EMPTY;
            chunk.iter().for_each(|p| info.add(p));
            info
        };
        if prims.len() >= PAR_INFO_MIN {
            prims
                .par_chunks(INFO_CHUNK)
                .map(seq)
                .reduce(|| Info::EMPTY, Info::union)
        } else {
            seq(prims)
        }
    }
}

/// 2²³: added to a float in [0, 2²³), it leaves the integer nearest to it in the low bits.
const MAGIC: f32 = 8_388_608.0;

/// The lanes of `v` (each in [0, 2²³)) rounded to the nearest integers, read from the bits of
/// `v + 2²³` ([`MAGIC`]): cheaper than four saturating float-to-integer casts.
#[inline(always)]
fn rounded(v: Vec4) -> [u32; 4] {
    (v + MAGIC)
        .to_array()
        .map(|x| x.to_bits() - MAGIC.to_bits())
}

/// Maps a key to its bin on each axis (x, y, z and size).
#[derive(Clone, Copy, Debug)]
pub(super) struct Mapper {
    /// Bins per axis ([`BINS`] at most).
    count: u32,
    origin: Vec4,
    /// Bins per unit length; zero on an axis whose centroids all coincide (or whose extent is not
    /// finite), which then offers no split.
    scale: Vec4,
}

impl Mapper {
    fn new(keys: &Keys, count: usize) -> Mapper {
        let extent = keys.hi - keys.lo;
        let scale = Vec4::select(
            extent.cmpgt(Vec4::ZERO),
            Vec4::splat(count as f32) / extent,
            Vec4::ZERO,
        );
        Mapper {
            count: count as u32,
            origin: keys.lo,
            scale,
        }
    }

    /// The bins of centroid `c`: its position in bins, less a half, clamped to the bins (NaN to the
    /// first: SSE's `max` and `f32::max` both return the other operand), then rounded to the
    /// nearest integer by adding 2²³ and read from the float's bits. Cheaper than saturating
    /// float-to-int casts, lane by lane; the bins' boundaries need only be the same in binning and
    /// partitioning, which both call this.
    #[inline(always)]
    fn bins(&self, c: Vec4) -> [u32; 4] {
        let last = Vec4::splat((self.count - 1) as f32);
        let v = ((c - self.origin) * self.scale - 0.5)
            .max(Vec4::ZERO)
            .min(last);
        rounded(v)
    }

    /// Whether `c` falls in a bin below `bin` on `axis`: `self.bins(c)[axis] < bin`, from the same
    /// rounded positions, compared as floats (integers below 2²⁴ are exact), with no lane taken out
    /// of the vector.
    #[inline(always)]
    fn below(&self, c: Vec4, axis: usize, bin: u32) -> bool {
        let last = Vec4::splat((self.count - 1) as f32);
        let v = ((c - self.origin) * self.scale - 0.5)
            .max(Vec4::ZERO)
            .min(last)
            + MAGIC;
        v.cmplt(Vec4::splat(MAGIC + bin as f32)).bitmask() & (1 << axis) != 0
    }
}

/// Per axis (x, y, z and size), the boxes and counts of the primitives whose keys fall in each of
/// `N` bins. Counts apart from the boxes, bin by bin (the sweep reads a bin's four counts as one
/// vector), and sized to the bins in use: a range of a few dozen primitives clears and sweeps
/// 2 KiB, not the 12 KiB of two full sets.
#[derive(Clone, Copy)]
struct Bins<const N: usize> {
    bounds: [[Box3; N]; 4],
    counts: [[u32; 4]; N],
}

/// The x, y and z of four vectors, one vector per coordinate (lane k: `v[k]`'s).
#[inline(always)]
fn transposed(v: [Vec4; 4]) -> [Vec4; 3] {
    let m = Mat4::from_cols(v[0], v[1], v[2], v[3]).transpose();
    [m.x_axis, m.y_axis, m.z_axis]
}

/// Four boxes, one per lane (lane k of `lo[c]` is box k's lower corner in coordinate c): the
/// sweeps work on the four axes at once, one axis per lane.
#[derive(Clone, Copy)]
struct Boxes4 {
    lo: [Vec4; 3],
    hi: [Vec4; 3],
}

impl Boxes4 {
    const EMPTY: Boxes4 = Boxes4 {
        lo: [Vec4::INFINITY; 3],
        hi: [Vec4::NEG_INFINITY; 3],
    };

    /// Lane k: `boxes[k]`.
    #[inline(always)]
    fn gather(boxes: [Box3; 4]) -> Boxes4 {
        Boxes4 {
            lo: transposed(boxes.map(|b| b.lo.extend(0.0))),
            hi: transposed(boxes.map(|b| b.hi.extend(0.0))),
        }
    }

    /// Lane k: the box of `prims[k]`.
    #[inline(always)]
    fn of_prims(prims: [&Prim; 4]) -> Boxes4 {
        Boxes4 {
            lo: transposed(prims.map(|p| p.lo)),
            hi: transposed(prims.map(|p| p.hi)),
        }
    }

    #[inline(always)]
    fn union(self, o: Boxes4) -> Boxes4 {
        Boxes4 {
            lo: [0, 1, 2].map(|c| self.lo[c].min(o.lo[c])),
            hi: [0, 1, 2].map(|c| self.hi[c].max(o.hi[c])),
        }
    }

    /// The half areas of the four boxes, their extents multiplied by `scale` first (see
    /// [`Bins::best`]).
    #[inline(always)]
    fn half_areas(&self, scale: f32) -> Vec4 {
        let [x, y, z] = [0, 1, 2].map(|c| (self.hi[c] - self.lo[c]) * scale);
        x * y + y * z + z * x
    }
}

impl<const N: usize> Bins<N> {
    const EMPTY: Self = Bins {
        bounds: [[Box3::EMPTY; N]; 4],
        counts: [[0; 4]; N],
    };

    #[inline(always)]
    fn add(&mut self, p: &Prim, map: &Mapper) {
        let (lo, hi) = (p.lo(), p.hi());
        for (axis, k) in map.bins(p.key()).into_iter().enumerate() {
            let k = (k as usize).min(N - 1);
            self.bounds[axis][k].grow(lo, hi);
            self.counts[k][axis] += 1;
        }
    }

    fn merge(&mut self, other: &Self) {
        for axis in 0..4 {
            for k in 0..N {
                self.bounds[axis][k] = self.bounds[axis][k].union(other.bounds[axis][k]);
                self.counts[k][axis] += other.counts[k][axis];
            }
        }
    }

    /// Adds every `stride`-th of `prims` (from the first) to `self` and `odd`, alternately: neighbours
    /// in a mesh mostly fall in the same bins, and with one set each update would wait for the
    /// previous one's store. The caller merges the two.
    fn fill(&mut self, odd: &mut Self, prims: &[Prim], stride: usize, map: &Mapper) {
        let mut it = prims.iter().step_by(stride);
        while let Some(a) = it.next() {
            self.add(a, map);
            match it.next() {
                Some(b) => odd.add(b, map),
                None => break,
            }
        }
    }

    /// The cheapest split of these bins by SAH on any axis whose scale is positive: its cost (the
    /// sides' half areas times their counts), axis and first right bin; the first of equal costs
    /// in the order of axes, then bins.
    ///
    /// The four axes are swept at once, one per lane, in `f32`, with every extent multiplied by
    /// the inverse of the largest extent of `bounds` (which holds every bin): areas are then at
    /// most 3 and never overflow, and the ratios between costs, all the choice depends on, are
    /// those of the unscaled areas to `f32`'s precision. The cost returned is unscaled (`f64`).
    fn best(&self, map: &Mapper, bounds: &Box3) -> Option<(f64, usize, u32)> {
        let scale = 1.0 / (bounds.hi - bounds.lo).max_element();
        if !(scale.is_finite() && scale > 0.0) {
            return None;
        }
        let boxes: [Boxes4; N] =
            std::array::from_fn(|i| Boxes4::gather([0, 1, 2, 3].map(|a| self.bounds[a][i])));
        let counts: [Vec4; N] =
            std::array::from_fn(|i| UVec4::from_array(self.counts[i]).as_vec4());
        // The right sides' areas and counts, from the last bin down: index i covers bins i.. .
        let mut right = [(Vec4::ZERO, Vec4::ZERO); N];
        let (mut acc, mut n) = (Boxes4::EMPTY, Vec4::ZERO);
        for i in (1..N).rev() {
            acc = acc.union(boxes[i]);
            n += counts[i];
            right[i] = (acc.half_areas(scale), n);
        }
        let usable = map.scale.cmpgt(Vec4::ZERO);
        let (mut best, mut best_bin) = (Vec4::INFINITY, Vec4::ZERO);
        let (mut acc, mut n) = (Boxes4::EMPTY, Vec4::ZERO);
        for i in 1..N {
            acc = acc.union(boxes[i - 1]);
            n += counts[i - 1];
            let (area, rn) = right[i];
            let c = acc.half_areas(scale) * n + area * rn;
            // Strictly lower, on an axis that offers splits, with primitives on both sides.
            let better = c.cmplt(best) & usable & n.cmpgt(Vec4::ZERO) & rn.cmpgt(Vec4::ZERO);
            best = Vec4::select(better, c, best);
            best_bin = Vec4::select(better, Vec4::splat(i as f32), best_bin);
        }
        let (cost, axis) = cheapest_axis(best);
        let unscale = f64::from(scale) * f64::from(scale);
        (cost < f32::INFINITY).then(|| (f64::from(cost) / unscale, axis, best_bin[axis] as u32))
    }
}

/// The lowest of the four axes' best costs (one per lane) and its axis, the first of equals in
/// axis order; the cost is infinite where no axis has a split.
#[inline(always)]
fn cheapest_axis(best: Vec4) -> (f32, usize) {
    let (mut cost, mut axis) = (f32::INFINITY, 0);
    for a in 0..4 {
        if best[a] < cost {
            (cost, axis) = (best[a], a);
        }
    }
    (cost, axis)
}

/// How to split a range.
#[derive(Clone, Copy, Debug)]
pub(super) enum Split {
    /// Keys in bins below `bin` on `axis` go left.
    Binned { map: Mapper, axis: usize, bin: u32 },
    /// In `order` (the range's positions in key order on the split's axis, as the search found
    /// them: not worked out again), the first `count` go left.
    Sorted {
        order: [u8; SWEEP_MAX],
        count: usize,
    },
    /// The lower half on the widest centroid axis goes left.
    Median,
}

/// What to do with a range: keep it as a leaf, or split it.
#[derive(Clone, Copy, Debug)]
pub(super) enum Plan {
    Leaf,
    Split(Split),
}

/// The best binned split of `prims` and its cost (estimated from a sample of a large range: see
/// [`SAMPLE`]), if any axis offers one with a finite cost.
fn best_binned(prims: &[Prim], info: &Info) -> Option<(f64, Split)> {
    fn with<const N: usize>(prims: &[Prim], info: &Info) -> Option<(f64, Split)> {
        let map = Mapper::new(&info.keys, N);
        if !map.scale.cmpgt(Vec4::ZERO).any() {
            return None;
        }
        // A sampled range's cost is the sample's, not comparable with the range's own leaf cost;
        // but only ranges of a leaf's size, never sampled, compare the two.
        let stride = prims.len().div_ceil(SAMPLE);
        let mut bins = Bins::<N>::EMPTY;
        if prims.len() >= MANY {
            let mut odd = Bins::<N>::EMPTY;
            bins.fill(&mut odd, prims, stride, &map);
            bins.merge(&odd);
        } else {
            // A few dozen primitives: a second set would cost more to clear and merge than the
            // waits on the stores it saves.
            prims.iter().for_each(|p| bins.add(p, &map));
        }
        let (cost, axis, bin) = bins.best(&map, &info.bounds)?;
        Some((cost, Split::Binned { map, axis, bin }))
    }
    if prims.len() >= MANY {
        with::<BINS>(prims, info)
    } else {
        with::<FEW_BINS>(prims, info)
    }
}

/// The orders of a small range (at most [`SWEEP_MAX`]) on each axis of its keys, ties in range
/// order: `orders[axis][r]` is the position in `prims` of the key of rank `r` on `axis`.
///
/// Each key's rank on all four axes at once, by comparing it with every other key (one vector
/// comparison a pair: a key before it counts if it is not greater, one after it if it is less),
/// instead of four sorts: n² comparisons without a branch cost less than four sorts' mispredicted
/// ones at these sizes. Keys are never NaN ([`Prim::key`]); −0 and +0 compare equal, so they keep
/// their range order.
#[inline(always)]
fn orders(prims: &[Prim]) -> [[u8; SWEEP_MAX]; 4] {
    let n = prims.len();
    debug_assert!(n <= SWEEP_MAX);
    let mut keys = [Vec4::ZERO; SWEEP_MAX];
    for (k, p) in prims.iter().enumerate() {
        keys[k] = p.key();
    }
    let mut orders = [[0u8; SWEEP_MAX]; 4];
    for i in 0..n {
        let ki = keys[i];
        let mut rank = Vec4::ZERO;
        for kj in &keys[..i] {
            rank += Vec4::select(kj.cmple(ki), Vec4::ONE, Vec4::ZERO);
        }
        for kj in &keys[i + 1..n] {
            rank += Vec4::select(kj.cmplt(ki), Vec4::ONE, Vec4::ZERO);
        }
        for (order, r) in orders.iter_mut().zip(rounded(rank)) {
            order[r as usize & (SWEEP_MAX - 1)] = i as u8;
        }
    }
    orders
}

/// The best split of a small range by a full sweep over its keys in order on each axis. Areas in
/// `f32` with the extents scaled as in [`Bins::best`]; the cost returned is unscaled.
///
/// The four axes are swept at once, one per lane, as [`Bins::best`] sweeps its bins: lane a of
/// `ranked[r]` is the box of rank r on axis a. The costs are those of one axis at a time, bit for
/// bit, and ties go to the first axis, then the first position, as they would in turn.
fn best_sorted(prims: &[Prim], info: &Info) -> Option<(f64, Split)> {
    let n = prims.len();
    let scale = 1.0 / (info.bounds.hi - info.bounds.lo).max_element();
    if !(scale.is_finite() && scale > 0.0) {
        return None;
    }
    let orders = orders(prims);
    let mut ranked = [Boxes4::EMPTY; SWEEP_MAX];
    for (r, boxes) in ranked[..n].iter_mut().enumerate() {
        *boxes = Boxes4::of_prims(orders.map(|order| &prims[order[r] as usize]));
    }
    // The right sides' areas: index i covers ranks i.. .
    let mut right = [Vec4::ZERO; SWEEP_MAX];
    let mut acc = Boxes4::EMPTY;
    for i in (1..n).rev() {
        acc = acc.union(ranked[i]);
        right[i] = acc.half_areas(scale);
    }
    let (mut best, mut best_count) = (Vec4::INFINITY, Vec4::ZERO);
    let mut left = Boxes4::EMPTY;
    for i in 1..n {
        left = left.union(ranked[i - 1]);
        let c = left.half_areas(scale) * i as f32 + right[i] * (n - i) as f32;
        let better = c.cmplt(best);
        best = Vec4::select(better, c, best);
        best_count = Vec4::select(better, Vec4::splat(i as f32), best_count);
    }
    let (cost, axis) = cheapest_axis(best);
    let unscale = f64::from(scale) * f64::from(scale);
    (cost < f32::INFINITY).then(|| {
        let split = Split::Sorted {
            order: orders[axis],
            count: best_count[axis] as usize,
        };
        (f64::from(cost) / unscale, split)
    })
}

/// The best SAH split of a range of at least two primitives, with its cost.
fn best_split(prims: &[Prim], info: &Info) -> Option<(f64, Split)> {
    if prims.len() <= SWEEP_MAX {
        best_sorted(prims, info)
    } else {
        best_binned(prims, info)
    }
}

/// Leaf or split for a range, `depth` binary levels below the root: a range of more than
/// `max_leaf` is always split; a smaller one becomes a leaf unless splitting it into two leaves
/// costs less by SAH, with a node visit costing `traversal_cost` triangle tests (obvhs' leaf
/// collapse rule, applied top-down).
pub(super) fn plan(
    prims: &[Prim],
    info: &Info,
    depth: usize,
    max_leaf: usize,
    traversal_cost: f64,
) -> Plan {
    let n = prims.len();
    if n <= 1 || (n <= max_leaf && n as f64 <= traversal_cost) {
        return Plan::Leaf;
    }
    // Any split costs at least the sum of the primitives' own areas (each side's box holds its
    // primitives' boxes): a leaf that costs no more needs no search, as most leaves of a mesh.
    if n <= max_leaf {
        let own: f64 = prims
            .iter()
            .map(|p| {
                Box3 {
                    lo: p.lo(),
                    hi: p.hi(),
                }
                .half_area()
            })
            .sum();
        if info.bounds.half_area() * (n as f64 - traversal_cost) <= own {
            return Plan::Leaf;
        }
    }
    if depth >= MEDIAN_DEPTH {
        return if n <= max_leaf {
            Plan::Leaf
        } else {
            Plan::Split(Split::Median)
        };
    }
    match best_split(prims, info) {
        Some((c, _))
            if n <= max_leaf && info.bounds.half_area() * (n as f64 - traversal_cost) <= c =>
        {
            Plan::Leaf
        }
        Some((_, split)) => Plan::Split(split),
        None if n <= max_leaf => Plan::Leaf,
        None => Plan::Split(Split::Median),
    }
}

/// Partitions `prims` in place by `left` (a test of the key), returning the left count and both
/// sides' infos.
fn partition(prims: &mut [Prim], left: impl Fn(Vec4) -> bool) -> (usize, Info, Info) {
    let (mut i, mut j) = (0, prims.len());
    let (mut l, mut r) = (Info::EMPTY, Info::EMPTY);
    loop {
        while i < j {
            let p = &prims[i];
            if !left(p.key()) {
                break;
            }
            l.add(p);
            i += 1;
        }
        while i < j {
            let p = &prims[j - 1];
            if left(p.key()) {
                break;
            }
            r.add(p);
            j -= 1;
        }
        if i >= j {
            return (i, l, r);
        }
        // prims[i] goes right and prims[j - 1] left: swap them and take both.
        prims.swap(i, j - 1);
        l.add(&prims[i]);
        r.add(&prims[j - 1]);
        i += 1;
        j -= 1;
    }
}

/// Applies `split` to `prims` (whose info is `info`): the left count and both sides' infos.
pub(super) fn apply(prims: &mut [Prim], info: &Info, split: Split) -> (usize, Info, Info) {
    match split {
        Split::Binned { map, axis, bin } => partition(prims, |c| map.below(c, axis, bin)),
        Split::Sorted { order, count } => {
            let mut sorted = [prims[0]; SWEEP_MAX];
            for (slot, &k) in sorted.iter_mut().zip(&order[..prims.len()]) {
                *slot = prims[k as usize];
            }
            prims.copy_from_slice(&sorted[..prims.len()]);
            let (l, r) = prims.split_at(count);
            (count, Info::of(l), Info::of(r))
        }
        Split::Median => {
            let extent = info.keys.hi - info.keys.lo;
            // The widest axis (NaN extents, from infinite centroid bounds, compare as smallest).
            let mut axis = 0;
            for a in 1..3 {
                if extent[a] > extent[axis] {
                    axis = a;
                }
            }
            let mid = prims.len() / 2;
            prims.select_nth_unstable_by(mid, |a, b| a.key()[axis].total_cmp(&b.key()[axis]));
            let (l, r) = prims.split_at(mid);
            (mid, Info::of(l), Info::of(r))
        }
    }
}

/// `v` without what the w lane carried through the builder's vector operations (see [`Prim`]).
fn xyz(v: Vec3A) -> Vec3A {
    Vec3A::from_array(v.to_array())
}

/// A node of a binary tree: a box and either two children (`count` 0: at `first` and
/// `first + 1`) or `count` primitives from position `first` of the tree's order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct BinaryNode {
    pub lo: Vec3A,
    pub hi: Vec3A,
    pub count: u32,
    pub first: u32,
}

/// A binary SAH tree over `boxes` (each box's lower and upper corner, finite or not, lower ≤
/// upper) with leaves of at most `max_leaf` boxes: its nodes, root first, and the order of the
/// boxes (`order[k]` = index in `boxes` of the tree's primitive k). Sequential: meant for the few
/// thousand boxes of a top-level tree. `boxes` must not be empty.
pub(crate) fn binary_tree(
    boxes: &[(Vec3A, Vec3A)],
    max_leaf: usize,
    traversal_cost: f64,
) -> (Vec<BinaryNode>, Vec<u32>) {
    assert!(!boxes.is_empty() && max_leaf >= 1);
    let mut prims: Vec<Prim> = boxes
        .iter()
        .enumerate()
        .map(|(i, &(lo, hi))| Prim::new(lo, hi, i as u32))
        .collect();
    let info = Info::of(&prims);
    let mut nodes = vec![BinaryNode {
        lo: xyz(info.bounds.lo),
        hi: xyz(info.bounds.hi),
        count: 0,
        first: 0,
    }];
    // Explicit stack: (slot, first primitive, count, info, depth).
    let mut stack = vec![(0usize, 0usize, prims.len(), info, 0usize)];
    while let Some((slot, first, count, info, depth)) = stack.pop() {
        let range = &mut prims[first..first + count];
        let split = match plan(range, &info, depth, max_leaf, traversal_cost) {
            Plan::Leaf => {
                nodes[slot].count = count as u32;
                nodes[slot].first = first as u32;
                continue;
            }
            Plan::Split(split) => split,
        };
        let (mid, l, r) = apply(range, &info, split);
        let children = nodes.len();
        nodes[slot].first = children as u32;
        for side in [l, r] {
            nodes.push(BinaryNode {
                lo: xyz(side.bounds.lo),
                hi: xyz(side.bounds.hi),
                count: 0,
                first: 0,
            });
        }
        stack.push((children + 1, first + mid, count - mid, r, depth + 1));
        stack.push((children, first, mid, l, depth + 1));
    }
    let order = prims.iter().map(Prim::index).collect();
    (nodes, order)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ranks give each axis the order a stable sort by key gives, ties (many, and −0 against
    /// +0) in range order, for every size of a small range.
    #[test]
    fn ranks_order_keys_as_a_stable_sort() {
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        let mut next = |k: u64| {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng % k
        };
        for round in 0..2_000 {
            let n = 1 + round % SWEEP_MAX;
            // Few distinct coordinates, so that ties are common.
            let values = [-2.0f32, -0.0, 0.0, 0.5, 1.0, 3.0];
            let prims: Vec<Prim> = (0..n)
                .map(|i| {
                    let mut pick = || values[next(values.len() as u64) as usize];
                    let lo = Vec3A::new(pick(), pick(), pick());
                    let d = Vec3A::new(pick().abs(), pick().abs(), pick().abs());
                    Prim::new(lo, lo + d, i as u32)
                })
                .collect();
            let got = orders(&prims);
            for (axis, order) in got.iter().enumerate() {
                let mut want: Vec<usize> = (0..n).collect();
                // Stable: equal keys keep their range order; −0 equals +0.
                want.sort_by(|&a, &b| {
                    let (ka, kb) = (prims[a].key()[axis], prims[b].key()[axis]);
                    ka.partial_cmp(&kb).expect("keys are never NaN")
                });
                let got: Vec<usize> = order[..n].iter().map(|&k| usize::from(k)).collect();
                assert_eq!(got, want, "axis {axis}, round {round}");
            }
        }
    }

    /// The partition's test agrees with the binning, for keys inside, outside and on the edges of
    /// the bins, infinite and NaN.
    #[test]
    fn the_partitions_test_agrees_with_the_binning() {
        let keys = Keys {
            lo: Vec4::new(-1.0, 0.0, 1e-30, 3.0),
            hi: Vec4::new(1.0, 0.0, 1e30, 3.5),
        };
        let mut rng = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            f32::from_bits(rng as u32)
        };
        let special = [
            0.0,
            -0.0,
            1.0,
            -1.0,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            3.25,
        ];
        for count in [FEW_BINS, BINS] {
            let map = Mapper::new(&keys, count);
            for k in 0..20_000 {
                let c = if k < special.len() {
                    Vec4::splat(special[k])
                } else {
                    Vec4::new(next(), next() * 1e-30, next(), next())
                };
                let all = map.bins(c);
                for (axis, &b) in all.iter().enumerate() {
                    assert!(b < count as u32);
                    for bin in 0..=count as u32 {
                        assert_eq!(map.below(c, axis, bin), b < bin, "{c:?} on axis {axis}");
                    }
                }
            }
        }
    }
}
