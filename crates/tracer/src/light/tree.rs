//! A light tree: chooses among many emitters in proportion to an estimate of what each sends to the
//! shading point, rather than to its power alone (pbrt-v4's `BVHLightSampler`, after Conty Estevez
//! and Kulla, "Importance Sampling of Many Lights with Adaptive Tree Splitting", 2018).
//!
//! Each node bounds its lights: a box, their summed power, and a cone of their normals
//! ([`LightBounds`]). The tree is built binary (split by pbrt-v4's surface area orientation
//! heuristic) and collapsed into 4-wide nodes whose children's bounds sit side by side, so that one
//! pass of vector arithmetic gives all four importances (a binary walk over an icosphere of 20k
//! emitters cost more time than its better choices saved). A sample walks from the root, at every
//! node choosing a child in proportion to its importance at the shading point (power over squared
//! distance, times bounds on the cosines at the light and at the receiver), and reaches one light
//! with the product of those choices as its probability. [`LightTree::pmf`] retraces the same
//! choices from the light's trail (two bits per level: the child slot), with the same arithmetic in
//! the same order, so the probability a BSDF-sampled ray's MIS weight uses is bit for bit the one
//! light sampling drew with.
//!
//! Unbiased: importance is a conservative bound, zero only where no light of the node can send
//! light to the point (behind every one-sided emitter of the node, or beyond the horizon of the
//! receiver's plane for every direction in the node's box); nodes of zero importance are never
//! chosen and nothing they could contribute is lost. A node's bounds are looser than its
//! children's, so a node may be chosen whose children are all out of reach: the sample then finds
//! no light (the probabilities of all lights sum to at most 1), which wastes the sample but
//! loses nothing that light could have sent. Deterministic: the build is sequential and
//! uses only IEEE arithmetic and `math::det`'s functions, so the tree, and every probability, has
//! the same bits on every machine.

use crate::math::det;
use glam::{Vec3, Vec4};
use std::f32::consts::{FRAC_PI_2, PI};

/// Buckets per axis when choosing a split (pbrt-v4's count).
const BUCKETS: usize = 12;

/// Below this depth splits are chosen by cost; from it on, at the middle of the index range. The
/// halving bounds the binary depth by this plus log₂ of the light count, and the 4-wide depth is at
/// most the binary one, which keeps every trail (two bits a level) within 128 bits for any count a
/// `u32` can index.
const COST_DEPTH: u32 = 30;

/// The most binary nodes between the root and a leaf.
const MAX_DEPTH: u32 = 63;

/// Cones are widened by this much in cosine: their axes and spreads are rounded, and a cone a
/// rounding too narrow could rule out a point that one of its lights still reaches.
const CONE_SLACK: f32 = 1e-4;

/// What a node knows of the lights under it: where they are, how much they emit and which way.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct LightBounds {
    pub lo: Vec3,
    pub hi: Vec3,
    /// Power, normalised so that the root's is 1 (no sum can overflow).
    pub phi: f32,
    /// Axis of the cone of the lights' normals (unit).
    pub w: Vec3,
    /// Cosine of the cone's half angle: every normal is within it of `w`.
    pub cos_o: f32,
    /// Cosine of how far beyond its normal a light emits (0: a hemisphere, as surfaces do).
    pub cos_e: f32,
    /// Whether some light emits from both faces (its normal's cone is then taken both ways).
    pub two_sided: bool,
}

#[inline(always)]
fn safe_sqrt(x: f32) -> f32 {
    x.max(0.0).sqrt()
}

impl LightBounds {
    /// One emitting triangle: its corners, unit normal, (normalised) power and sidedness.
    pub fn triangle(corners: [Vec3; 3], normal: Vec3, phi: f32, two_sided: bool) -> Self {
        LightBounds {
            lo: corners[0].min(corners[1]).min(corners[2]),
            hi: corners[0].max(corners[1]).max(corners[2]),
            phi,
            w: normal,
            cos_o: 1.0,
            cos_e: 0.0,
            two_sided,
        }
    }

    /// A point light at `position`: no extent, light in every direction (a cone of normals that
    /// is the whole sphere, as pbrt-v4 bounds it).
    pub fn point(position: Vec3, phi: f32) -> Self {
        LightBounds {
            lo: position,
            hi: position,
            phi,
            w: Vec3::Z,
            cos_o: -1.0,
            cos_e: 0.0,
            two_sided: false,
        }
    }

    /// A spot light at `position` pointing along unit `direction`, full inside the inner cone and
    /// fading to nothing at the outer one (pbrt-v4's bounds: the normals' cone is the inner cone,
    /// and the light reaches the outer angle beyond it), widened by [`CONE_SLACK`] so that
    /// rounding never rules out a point the spot still lights.
    pub fn spot(position: Vec3, direction: Vec3, cos_inner: f32, cos_outer: f32, phi: f32) -> Self {
        let (inner, outer) = (
            det::acos(cos_inner.clamp(-1.0, 1.0)),
            det::acos(cos_outer.clamp(-1.0, 1.0)),
        );
        LightBounds {
            lo: position,
            hi: position,
            phi,
            w: direction,
            cos_o: (cos_inner - CONE_SLACK).max(-1.0),
            cos_e: (det::cos((outer - inner).max(0.0)) - CONE_SLACK).max(-1.0),
            two_sided: false,
        }
    }

    /// The bounds of two nodes' lights together.
    fn union(&self, other: &LightBounds) -> LightBounds {
        let (w, cos_o) = cone_union((self.w, self.cos_o), (other.w, other.cos_o));
        LightBounds {
            lo: self.lo.min(other.lo),
            hi: self.hi.max(other.hi),
            phi: self.phi + other.phi,
            w,
            cos_o,
            cos_e: self.cos_e.min(other.cos_e),
            two_sided: self.two_sided || other.two_sided,
        }
    }

    /// The cost of a node with these bounds (pbrt-v4's surface area orientation heuristic): power
    /// times the solid angle its cone emits into times its box's area, with `kr` penalising thin
    /// boxes split across their thin side.
    fn cost(&self, kr: f32) -> f32 {
        let theta_o = det::acos(self.cos_o.clamp(-1.0, 1.0));
        let theta_e = det::acos(self.cos_e.clamp(-1.0, 1.0));
        let theta_w = (theta_o + theta_e).min(PI);
        let sin_o = safe_sqrt(1.0 - self.cos_o * self.cos_o);
        let m_omega = 2.0 * PI * (1.0 - self.cos_o)
            + FRAC_PI_2
                * (2.0 * theta_w * sin_o
                    - det::cos(theta_o - 2.0 * theta_w)
                    - 2.0 * theta_o * sin_o
                    + self.cos_o);
        let d = self.hi - self.lo;
        let area = 2.0 * (d.x * d.y + d.y * d.z + d.z * d.x);
        self.phi * m_omega * kr * area
    }
}

/// A cone (axis, cosine of the half angle) holding both cones (pbrt-v4's `DirectionCone::Union`),
/// widened by [`CONE_SLACK`].
fn cone_union(a: (Vec3, f32), b: (Vec3, f32)) -> (Vec3, f32) {
    let angle = |cos: f32| det::acos(cos.clamp(-1.0, 1.0));
    let (theta_a, theta_b) = (angle(a.1), angle(b.1));
    let theta_d = angle(a.0.dot(b.0));
    if (theta_d + theta_b).min(PI) <= theta_a {
        return a;
    }
    if (theta_d + theta_a).min(PI) <= theta_b {
        return b;
    }
    let theta_o = (theta_a + theta_d + theta_b) * 0.5;
    let axis = a.0.cross(b.0);
    if theta_o >= PI || axis.length_squared() == 0.0 {
        return (a.0, -1.0);
    }
    // Rotate a's axis towards b's by θo − θa (Rodrigues' formula).
    let k = axis.normalize();
    let (sin_r, cos_r) = det::sin_cos(theta_o - theta_a);
    let w = a.0 * cos_r + k.cross(a.0) * sin_r + k * (k.dot(a.0) * (1.0 - cos_r));
    let w = w.normalize();
    (w, (det::cos(theta_o) - CONE_SLACK).max(-1.0))
}

/// The cone around all of `normals` (each a cone: axis and cosine), found in two passes without
/// trigonometry: the axis is the normalised sum of the axes, the spread the largest angle from it to
/// a member's axis plus that member's spread. Used for a bucket's many lights, where
/// [`cone_union`] one at a time would cost an `acos` per light per level.
fn cone_around(members: impl Iterator<Item = (Vec3, f32)> + Clone) -> (Vec3, f32) {
    let sum: Vec3 = members.clone().map(|(w, _)| w).sum();
    let Some(axis) = sum.try_normalize() else {
        return (Vec3::Z, -1.0);
    };
    let mut cos = 1.0f32;
    for (w, cos_m) in members {
        // cos(angle(axis, w) + θm), or −1 once the sum reaches π.
        let cos_d = axis.dot(w).clamp(-1.0, 1.0);
        let sin_d = safe_sqrt(1.0 - cos_d * cos_d);
        let sin_m = safe_sqrt(1.0 - cos_m * cos_m);
        let c = if cos_d < -cos_m {
            -1.0
        } else {
            cos_d * cos_m - sin_d * sin_m
        };
        cos = cos.min(c);
    }
    (axis, (cos - CONE_SLACK).max(-1.0))
}

/// A node of the binary tree the build makes (then collapsed into [`Node4`]s).
struct Binary {
    bounds: LightBounds,
    /// Inner: the two children's indices. Leaf: the light's index, twice.
    children: [u32; 2],
    leaf: bool,
}

/// A child slot of a [`Node4`]: an inner node's index, or a light's (top bit set).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Slot(u32);

impl Slot {
    const LIGHT: u32 = 1 << 31;

    fn light(self) -> Option<usize> {
        (self.0 & Self::LIGHT != 0).then_some((self.0 & !Self::LIGHT) as usize)
    }
}

/// Four children's bounds side by side, one lane each, so that one pass of vector arithmetic gives
/// all four importances. The fields are [`LightBounds`] turned into what
/// [`Node4::importances`] reads: centre, bounding-sphere radius², the distance clamp, sines.
/// Unused lanes have zero power (importance 0).
#[derive(Clone, Copy, Debug)]
struct Node4 {
    center: [Vec4; 3],
    r2: Vec4,
    /// The smallest d² the importance divides by (half the box's diagonal, as pbrt-v4 clamps).
    d2_min: Vec4,
    phi: Vec4,
    w: [Vec4; 3],
    cos_o: Vec4,
    sin_o: Vec4,
    cos_e: Vec4,
    /// 1 where the lane's lights include a two-sided one, else 0.
    two_sided: Vec4,
    slots: [Slot; 4],
    count: u32,
}

impl Node4 {
    fn new(children: &[(LightBounds, Slot)]) -> Node4 {
        debug_assert!((1..=4).contains(&children.len()));
        let mut lanes = [[0.0f32; 4]; 15];
        let mut slots = [Slot(0); 4];
        // Unused lanes: no power, and a distance clamp of 1 so that nothing divides 0 by 0.
        lanes[4] = [1.0; 4];
        for (k, (b, slot)) in children.iter().enumerate() {
            let c = (b.lo + b.hi) * 0.5;
            let values = [
                c.x,
                c.y,
                c.z,
                (b.hi - c).length_squared(),
                (b.hi - b.lo).length() * 0.5,
                b.phi,
                b.w.x,
                b.w.y,
                b.w.z,
                b.cos_o,
                safe_sqrt(1.0 - b.cos_o * b.cos_o),
                b.cos_e,
                if b.two_sided { 1.0 } else { 0.0 },
                0.0,
                0.0,
            ];
            for (field, v) in values.into_iter().enumerate() {
                lanes[field][k] = v;
            }
            slots[k] = *slot;
        }
        let v = |field: usize| Vec4::from_array(lanes[field]);
        Node4 {
            center: [v(0), v(1), v(2)],
            r2: v(3),
            d2_min: v(4),
            phi: v(5),
            w: [v(6), v(7), v(8)],
            cos_o: v(9),
            sin_o: v(10),
            cos_e: v(11),
            two_sided: v(12),
            slots,
            count: children.len() as u32,
        }
    }

    /// How much light each lane's lights may send to a point `p` whose surface has unit normal `n`
    /// (zero `n`: no receiver cosine), up to a common factor: power / squared distance, times the
    /// largest emitter cosine and the largest receiver cosine any point of the box allows (pbrt-v4's
    /// `LightBounds::Importance`). Zero only where no light of the lane reaches `p`. Vector
    /// arithmetic of IEEE operations only, so the same bits wherever it runs.
    #[inline(always)]
    fn importances(&self, p: Vec3, n: Vec3) -> Vec4 {
        let one = Vec4::ONE;
        let safe_sqrt = |x: Vec4| x.max(Vec4::ZERO).sqrt();
        // cos(max(θa − θb, 0)) and sin(max(θa − θb, 0)), lane by lane.
        let cos_sub = |sin_a: Vec4, cos_a: Vec4, sin_b: Vec4, cos_b: Vec4| {
            Vec4::select(cos_a.cmpgt(cos_b), one, cos_a * cos_b + sin_a * sin_b)
        };
        let sin_sub = |sin_a: Vec4, cos_a: Vec4, sin_b: Vec4, cos_b: Vec4| {
            Vec4::select(
                cos_a.cmpgt(cos_b),
                Vec4::ZERO,
                sin_a * cos_b - cos_a * sin_b,
            )
        };
        let t = [
            Vec4::splat(p.x) - self.center[0],
            Vec4::splat(p.y) - self.center[1],
            Vec4::splat(p.z) - self.center[2],
        ];
        let dist2 = t[0] * t[0] + t[1] * t[1] + t[2] * t[2];
        let d2 = dist2.max(self.d2_min);
        // 1 / distance, 0 at the centre itself (where the direction is taken as none).
        let positive = dist2.cmpgt(Vec4::ZERO);
        let inv_dist = Vec4::select(positive, one / dist2.sqrt(), Vec4::ZERO);
        let dot_w = self.w[0] * t[0] + self.w[1] * t[1] + self.w[2] * t[2];
        let mut cos_w = dot_w * inv_dist;
        cos_w = Vec4::select(self.two_sided.cmpgt(Vec4::ZERO), cos_w.abs(), cos_w);
        // sin² = 1 − (w · t)² / d², beside the cosine rather than after it.
        let sin_w = Vec4::select(positive, safe_sqrt(one - dot_w * dot_w / dist2), one);
        // The bounding sphere's half angle: sin² θb = r² / d², its sine and cosine both from that
        // ratio, side by side (each step of a walk down the tree waits on this arithmetic).
        let inside = dist2.cmplt(self.r2);
        let sin2_b = Vec4::select(positive, self.r2 / dist2, Vec4::ZERO);
        let cos_b = Vec4::select(inside, Vec4::splat(-1.0), safe_sqrt(one - sin2_b));
        let sin_b = Vec4::select(inside, Vec4::ZERO, safe_sqrt(sin2_b));
        let cos_x = cos_sub(sin_w, cos_w, self.sin_o, self.cos_o);
        let sin_x = sin_sub(sin_w, cos_w, self.sin_o, self.cos_o);
        let cos_p = cos_sub(sin_x, cos_x, sin_b, cos_b);
        let mut importance = self.phi / d2 * cos_p;
        if n != Vec3::ZERO {
            let cos_i = ((t[0] * n.x + t[1] * n.y + t[2] * n.z) * inv_dist).abs();
            let sin_i = safe_sqrt(one - cos_i * cos_i);
            importance *= cos_sub(sin_i, cos_i, sin_b, cos_b);
        }
        let reached = cos_p.cmpgt(self.cos_e);
        Vec4::select(reached, importance.max(Vec4::ZERO), Vec4::ZERO)
    }

    /// The probability of each child at (`p`, `n`), or None when none can be reached.
    #[inline(always)]
    fn probabilities(&self, p: Vec3, n: Vec3) -> Option<[f32; 4]> {
        let i = self.importances(p, n).to_array();
        // Summed in lane order, the same in `sample` and `pmf`.
        let sum = i[0] + i[1] + i[2] + i[3];
        (sum > 0.0 && sum.is_finite()).then(|| i.map(|x| x / sum))
    }
}

/// Where a walk's step leads: down to a node, or to its end (the light and its probability, or
/// None).
enum Step<'t> {
    Down(&'t Node4),
    Done(Option<(usize, f32)>),
}

/// A light tree over a scene's emitters (see the module documentation).
#[derive(Clone, Debug, Default)]
pub struct LightTree {
    /// Root first.
    nodes: Vec<Node4>,
    /// Per light: the path from the root to it, two bits per level (the child slot).
    trails: Vec<u128>,
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

    /// Chooses a light for the point `p` with unit normal `n` (zero: none) from `u` in [0, 1).
    /// Returns its index and probability, or None when no light reaches `p`.
    #[inline]
    pub fn sample(&self, p: Vec3, n: Vec3, mut u: f32) -> Option<(usize, f32)> {
        let (mut node, mut pmf) = (self.nodes.first()?, 1.0f32);
        loop {
            match self.step::<true>(node, p, n, &mut u, &mut pmf) {
                Step::Down(next) => node = next,
                Step::Done(chosen) => return chosen,
            }
        }
    }

    /// [`LightTree::sample`] for `M` points at once, the same answers: the walks step by turns,
    /// so that the processor works on the others while one waits on its node's importances (each
    /// step waits on the one before).
    #[inline]
    pub fn sample_many<const M: usize>(
        &self,
        queries: [(Vec3, Vec3, f32); M],
    ) -> [Option<(usize, f32)>; M] {
        let Some(root) = self.nodes.first() else {
            return [None; M];
        };
        let mut nodes = [root; M];
        let mut u = queries.map(|q| q.2);
        let mut pmf = [1.0f32; M];
        let (mut chosen, mut live) = ([None; M], [true; M]);
        while live.iter().any(|&l| l) {
            for w in 0..M {
                if live[w] {
                    let (p, n, _) = queries[w];
                    match self.step::<false>(nodes[w], p, n, &mut u[w], &mut pmf[w]) {
                        Step::Down(next) => nodes[w] = next,
                        Step::Done(c) => (chosen[w], live[w]) = (c, false),
                    }
                }
            }
        }
        chosen
    }

    /// One step of a walk at `node`: the child chosen by `u` (rescaled for the steps below) and its
    /// probability multiplied into `pmf`. `BRANCHY`: the child chosen by a branch a child (for a
    /// lone walk) or by lane masks (for walks side by side); the same child either way.
    #[inline(always)]
    fn step<'t, const BRANCHY: bool>(
        &'t self,
        node: &'t Node4,
        p: Vec3,
        n: Vec3,
        u: &mut f32,
        pmf: &mut f32,
    ) -> Step<'t> {
        self.prefetch_children(node);
        let importances = node.importances(p, n);
        let i = importances.to_array();
        // The running sums in lane order; the last is the sum `probabilities` divides by (the
        // same bits: adding a lane's zero changes no sum).
        let below = [0.0, i[0], i[0] + i[1], i[0] + i[1] + i[2]];
        let sum = below[3] + i[3];
        if !(sum > 0.0 && sum.is_finite()) {
            return Step::Done(None);
        }
        // The first child that can be chosen whose share of [0, sum) holds u · sum: the
        // importances compared as they are, so that the next step waits on no division by the
        // sum (the probability, which the choice does not wait for, divides). Rounding can
        // leave u · sum past the last share, which then goes to the last child that can be
        // chosen.
        let target = *u * sum;
        let count = node.count as usize;
        let k = if BRANCHY {
            // A branch a child: the processor guesses past it (a lone walk gains).
            let mut k = usize::MAX;
            for (j, &ij) in i.iter().enumerate().take(count) {
                if ij > 0.0 {
                    k = j;
                    if target < below[j] + ij {
                        break;
                    }
                }
            }
            k
        } else {
            // Lane masks (a compare, a bit scan): nothing to mispredict, which would discard
            // the walks beside this one too.
            let running = Vec4::from_array(below) + importances;
            let open = importances.cmpgt(Vec4::ZERO).bitmask() & ((1 << count) - 1);
            let holds = Vec4::splat(target).cmplt(running).bitmask() & open;
            (if holds != 0 {
                holds.trailing_zeros()
            } else {
                31u32.saturating_sub(open.leading_zeros())
            }) as usize
        };
        let below = below[k];
        let ik = i[k];
        *u = ((target - below).max(0.0) / ik).min(ONE_BELOW);
        // `probabilities`' quotient, the same bits as `pmf` multiplies.
        let pk = ik / sum;
        if pk == 0.0 {
            // A share below the smallest float, reached only by rounding past the others.
            return Step::Done(None);
        }
        *pmf *= pk;
        match node.slots[k].light() {
            Some(light) => Step::Done(Some((light, *pmf))),
            None => Step::Down(&self.nodes[node.slots[k].0 as usize]),
        }
    }

    /// Asks the cache for the inner children of `node`, one of which the walk opens next: their
    /// loads then overlap the importances that choose among them.
    #[inline(always)]
    fn prefetch_children(&self, node: &Node4) {
        #[cfg(target_arch = "x86_64")]
        for slot in &node.slots[..node.count as usize] {
            if slot.light().is_none() {
                if let Some(child) = self.nodes.get(slot.0 as usize) {
                    let at = (child as *const Node4).cast::<i8>();
                    for line in (0..std::mem::size_of::<Node4>()).step_by(64) {
                        // SAFETY: a prefetch is a hint; it neither faults nor changes memory.
                        unsafe {
                            std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                                at.wrapping_add(line),
                            )
                        };
                    }
                }
            }
        }
    }

    /// The probability that [`LightTree::sample`] chooses light `light` at (`p`, `n`): the same
    /// probabilities multiplied in the same order, so the same bits.
    #[inline]
    pub fn pmf(&self, p: Vec3, n: Vec3, light: usize) -> f32 {
        let (Some(mut node), Some(&trail)) = (self.nodes.first(), self.trails.get(light)) else {
            return 0.0;
        };
        let (mut pmf, mut trail) = (1.0f32, trail);
        loop {
            let Some(probs) = node.probabilities(p, n) else {
                return 0.0;
            };
            let k = (trail & 3) as usize;
            trail >>= 2;
            pmf *= probs[k];
            match node.slots[k].light() {
                Some(_) => return pmf,
                None => node = &self.nodes[node.slots[k].0 as usize],
            }
        }
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

/// The largest f32 below 1.
pub(super) const ONE_BELOW: f32 = 1.0 - f32::EPSILON / 2.0;

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::uniform_stream;

    /// `count` random triangles in a 10 m box, some two-sided, powers from 0.1 to 10 (normalised).
    fn random_lights(count: usize, seed: u64) -> Vec<LightBounds> {
        let mut u = uniform_stream(seed);
        let mut point = |s: f32| Vec3::new(u() * s, u() * s, u() * s);
        let mut lights: Vec<LightBounds> = (0..count)
            .map(|i| {
                let a = point(10.0);
                let c = [a, a + point(0.5), a + point(0.5)];
                let n = (c[1] - c[0]).cross(c[2] - c[0]).normalize();
                LightBounds::triangle(c, n, 0.1 + 10.0 * (i % 7) as f32, i % 5 == 0)
            })
            .collect();
        let total: f32 = lights.iter().map(|l| l.phi).sum();
        for l in &mut lights {
            l.phi /= total;
        }
        lights
    }

    #[test]
    fn probabilities_sum_to_at_most_one_and_match_the_sampled_ones() {
        let lights = random_lights(300, 1);
        let tree = LightTree::new(&lights);
        assert!(
            tree.node_count() <= lights.len() / 2,
            "{} nodes",
            tree.node_count()
        );
        let mut u = uniform_stream(2);
        let mut whole = 0.0;
        for _ in 0..200 {
            let p = Vec3::new(u() * 14.0 - 2.0, u() * 14.0 - 2.0, u() * 14.0 - 2.0);
            let n = Vec3::new(u() - 0.5, u() - 0.5, u() - 0.5).normalize();
            let total: f64 = (0..lights.len()).map(|k| tree.pmf(p, n, k) as f64).sum();
            // At most 1: a node may be chosen whose children all are out of reach.
            assert!(total > 0.8 && total < 1.0 + 1e-4, "Σ pmf = {total} at {p}");
            whole += total;
            for _ in 0..20 {
                if let Some((k, pmf)) = tree.sample(p, n, u()) {
                    assert!(pmf > 0.0);
                    assert_eq!(pmf.to_bits(), tree.pmf(p, n, k).to_bits());
                }
            }
        }
        // Little is wasted: 1 % at the median point of this cloud of randomly facing lights.
        assert!(whole / 200.0 > 0.95, "mean Σ pmf {}", whole / 200.0);
    }

    /// Walks side by side choose what each alone chooses, with the same probabilities, bit for
    /// bit, the walks of different lengths, ending at no light or at one.
    #[test]
    fn walks_side_by_side_choose_what_each_alone_chooses() {
        let lights = random_lights(500, 3);
        let tree = LightTree::new(&lights);
        let mut u = uniform_stream(4);
        let mut query = || {
            let p = Vec3::new(u() * 14.0 - 2.0, u() * 14.0 - 2.0, u() * 14.0 - 2.0);
            let n = Vec3::new(u() - 0.5, u() - 0.5, u() - 0.5).normalize();
            // Some points far off and facing away from everything, where walks end early.
            let p = if u() < 0.1 { p * 1e3 } else { p };
            (p, n, u())
        };
        let (mut found, mut none) = (0, 0);
        for _ in 0..2000 {
            let queries: [(Vec3, Vec3, f32); 3] = [query(), query(), query()];
            let alone = queries.map(|(p, n, u)| tree.sample(p, n, u));
            let bits = |c: Option<(usize, f32)>| c.map(|(k, pmf)| (k, pmf.to_bits()));
            assert_eq!(tree.sample_many(queries).map(bits), alone.map(bits));
            let pair = tree.sample_many([queries[0], queries[2]]);
            assert_eq!(pair.map(bits), [bits(alone[0]), bits(alone[2])]);
            found += alone.iter().filter(|c| c.is_some()).count();
            none += alone.iter().filter(|c| c.is_none()).count();
        }
        assert!(found > 1000 && none > 0, "{found} found, {none} none");
        assert_eq!(LightTree::new(&[]).sample_many([query(); 2]), [None, None]);
    }

    /// Pearson's χ² of the lights chosen at a point against [`LightTree::pmf`], lights of small
    /// expected counts pooled.
    #[test]
    fn chosen_lights_follow_the_pmf() {
        let lights = random_lights(64, 3);
        let tree = LightTree::new(&lights);
        let mut u = uniform_stream(4);
        for &(p, n) in &[
            (Vec3::new(5.0, 5.0, 5.0), Vec3::Y),
            (Vec3::new(-3.0, 1.0, 12.0), Vec3::ZERO),
            (Vec3::new(9.0, 0.2, 3.0), Vec3::X),
        ] {
            let draws = 200_000;
            let mut counts = vec![0u32; lights.len()];
            let mut none = 0u32;
            for _ in 0..draws {
                match tree.sample(p, n, u()) {
                    Some((k, _)) => counts[k] += 1,
                    None => none += 1,
                }
            }
            // No light chosen is a cell of its own, of probability 1 − Σ pmf.
            let total: f64 = (0..lights.len()).map(|k| tree.pmf(p, n, k) as f64).sum();
            let e_none = (1.0 - total).max(0.0) * draws as f64;
            let (mut chi2, mut dof) = (0.0f64, 0usize);
            let (mut pooled_e, mut pooled_o) = (e_none, none as f64);
            for (k, &c) in counts.iter().enumerate() {
                let e = tree.pmf(p, n, k) as f64 * draws as f64;
                if e < 5.0 {
                    assert!(e > 0.0 || c == 0, "light {k} drawn with pmf 0");
                    (pooled_e, pooled_o) = (pooled_e + e, pooled_o + c as f64);
                    continue;
                }
                chi2 += (c as f64 - e).powi(2) / e;
                dof += 1;
            }
            if pooled_e > 0.0 {
                chi2 += (pooled_o - pooled_e).powi(2) / pooled_e.max(1.0);
                dof += 1;
            }
            // The 99.9th percentile of χ² with dof − 1 degrees of freedom (Wilson–Hilferty).
            let k = (dof - 1) as f64;
            let z = 3.09;
            let limit = k * (1.0 - 2.0 / (9.0 * k) + z * (2.0 / (9.0 * k)).sqrt()).powi(3);
            assert!(
                chi2 < limit,
                "χ² {chi2:.1} ≥ {limit:.1} ({dof} cells) at {p}"
            );
        }
    }

    #[test]
    fn a_point_behind_every_one_sided_light_gets_none_and_a_lit_one_gets_the_near_light_mostly() {
        // Two small lights facing +z at z = 0, one near the receiver, one far.
        let quad = |x: f32| {
            let c = [
                Vec3::new(x, 0.0, 0.0),
                Vec3::new(x + 0.1, 0.0, 0.0),
                Vec3::new(x, 0.1, 0.0),
            ];
            LightBounds::triangle(c, Vec3::Z, 0.5, false)
        };
        let tree = LightTree::new(&[quad(0.0), quad(20.0)]);
        assert_eq!(
            tree.sample(Vec3::new(0.0, 0.0, -1.0), Vec3::ZERO, 0.5),
            None
        );
        assert_eq!(tree.pmf(Vec3::new(0.0, 0.0, -1.0), Vec3::ZERO, 0), 0.0);
        let near = tree.pmf(Vec3::new(0.0, 0.0, 1.0), -Vec3::Z, 0);
        assert!(near > 0.99, "near light's probability {near}");
        // A receiver facing away still gets both (the receiver cosine is folded: glass transmits).
        assert!(tree.pmf(Vec3::new(0.0, 0.0, 1.0), Vec3::Z, 1) > 0.0);
    }

    #[test]
    fn the_tree_is_the_same_whatever_the_input_order_of_equal_lights_and_stays_shallow() {
        // 5,000 lights on one point with one normal: no split separates them; halving does.
        let c = [Vec3::ZERO, Vec3::X * 1e-3, Vec3::Y * 1e-3];
        let lights = vec![LightBounds::triangle(c, Vec3::Z, 1.0 / 5000.0, false); 5000];
        let tree = LightTree::new(&lights);
        // Thirteen binary levels, at least two per 4-wide level but the last: seven, two bits each.
        let deepest = tree.trails.iter().map(|t| 128 - t.leading_zeros()).max();
        assert!(deepest <= Some(14), "trail bits {deepest:?}");
        let p = Vec3::new(0.3, 0.1, 1.0);
        assert!((tree.pmf(p, Vec3::ZERO, 17) - 1.0 / 5000.0).abs() < 1e-7);
    }

    #[test]
    fn cones_hold_their_members() {
        let mut u = uniform_stream(9);
        for _ in 0..1000 {
            let mut dir = || Vec3::new(u() - 0.5, u() - 0.5, u() - 0.5).normalize();
            let (a, b) = (dir(), dir());
            let (w, cos) = cone_union((a, 1.0), (b, 1.0));
            assert!(w.dot(a) >= cos && w.dot(b) >= cos, "{a} {b} → {w} {cos}");
            let members = [(a, 1.0), (b, 1.0), (dir(), 0.9)];
            let (w, cos) = cone_around(members.iter().copied());
            for (m, cos_m) in members {
                // Member m's cone is within the union: angle(w, m) + θm ≤ θ.
                let angle = det::acos(w.dot(m).clamp(-1.0, 1.0)) + det::acos(cos_m);
                assert!(cos <= -1.0 || angle <= det::acos(cos) + 1e-5);
            }
        }
    }
}
