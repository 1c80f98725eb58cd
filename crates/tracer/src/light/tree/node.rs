//! The 4-wide node: four children's bounds side by side, and their importances at a point.

use super::{safe_sqrt, LightBounds};
use glam::{Vec3, Vec4};

/// A child slot of a [`Node4`]: an inner node's index, or a light's (top bit set).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Slot(pub(super) u32);

impl Slot {
    pub(super) const LIGHT: u32 = 1 << 31;

    pub(super) fn light(self) -> Option<usize> {
        (self.0 & Self::LIGHT != 0).then_some((self.0 & !Self::LIGHT) as usize)
    }
}

/// Four children's bounds side by side, one lane each, so that one pass of vector arithmetic gives
/// all four importances. The fields are [`LightBounds`] turned into what
/// [`Node4::importances`] reads: centre, bounding-sphere radius², the distance clamp, sines.
/// Unused lanes have zero power (importance 0).
#[derive(Clone, Copy, Debug)]
pub(super) struct Node4 {
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
    pub(super) slots: [Slot; 4],
    pub(super) count: u32,
}

impl Node4 {
    pub(super) fn new(children: &[(LightBounds, Slot)]) -> Node4 {
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
    pub(super) fn importances(&self, p: Vec3, n: Vec3) -> Vec4 {
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
    pub(super) fn probabilities(&self, p: Vec3, n: Vec3) -> Option<[f32; 4]> {
        let i = self.importances(p, n).to_array();
        // Summed in lane order, the same in `sample` and `pmf`.
        let sum = i[0] + i[1] + i[2] + i[3];
        (sum > 0.0 && sum.is_finite()).then(|| i.map(|x| x / sum))
    }
}
