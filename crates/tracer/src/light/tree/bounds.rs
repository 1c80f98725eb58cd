//! What a node knows of its lights ([`LightBounds`]), and the cones of their normals.

use super::safe_sqrt;
use crate::math::det;
use glam::Vec3;
use std::f32::consts::{FRAC_PI_2, PI};

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
    pub(super) fn union(&self, other: &LightBounds) -> LightBounds {
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
    pub(super) fn cost(&self, kr: f32) -> f32 {
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
pub(super) fn cone_union(a: (Vec3, f32), b: (Vec3, f32)) -> (Vec3, f32) {
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
pub(super) fn cone_around(members: impl Iterator<Item = (Vec3, f32)> + Clone) -> (Vec3, f32) {
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
