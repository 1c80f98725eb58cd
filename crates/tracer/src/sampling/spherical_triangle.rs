//! Uniform directions within the solid angle a triangle subtends from a point (Arvo, "Stratified
//! Sampling of Spherical Triangles", SIGGRAPH 1995), density 1 / Ω.
//!
//! Sampled by area, a triangle close to the shading point gives samples whose weights r² / cos θ'
//! vary by orders of magnitude across it (a ceiling just above a lamp panel); sampled by solid
//! angle, every sample carries the same weight Ω, whatever the distances. The cost is a few
//! square roots, an arctangent and a sine and cosine per sample (`math::det`'s, so the same bits on
//! every machine), and the method loses precision for triangles that look tiny or fill nearly the
//! whole hemisphere: the light sampler decides when to use it (`light::area`).

use crate::math::det;
use glam::Vec3;

/// The spherical triangle that corners `corners` project to on the unit sphere around a point.
#[derive(Clone, Copy, Debug)]
pub struct SphericalTriangle {
    /// The unit directions from the point to the corners.
    a: Vec3,
    b: Vec3,
    c: Vec3,
    /// |a · (b × c)|: sin α · sin(ab) · sin(ac), α the angle at corner a.
    triple: f32,
    solid_angle: f32,
}

impl SphericalTriangle {
    /// The triangle `corners` as seen from `p`; None when a corner coincides with `p`.
    #[inline]
    pub fn new(corners: [Vec3; 3], p: Vec3) -> Option<SphericalTriangle> {
        let (s, valid) = SphericalTriangle::subtended(corners, p);
        valid.then_some(s)
    }

    /// [`SphericalTriangle::new`] without a branch, for lanes code: the triangle and whether it
    /// is one (false when a corner coincides with `p`, the triangle then holding NaNs).
    #[inline(always)]
    pub fn subtended(corners: [Vec3; 3], p: Vec3) -> (SphericalTriangle, bool) {
        let unit = |c: Vec3| {
            let d = c - p;
            let len = d.length();
            (d / len, len > 0.0)
        };
        let ((a, a_ok), (b, b_ok), (c, c_ok)) =
            (unit(corners[0]), unit(corners[1]), unit(corners[2]));
        // Van Oosterom and Strackee (1983): tan(Ω/2) = |a · (b × c)| / (1 + a·b + b·c + c·a),
        // accurate for small triangles as well (the angle excess α + β + γ − π is not).
        let triple = a.dot(b.cross(c)).abs();
        let solid_angle = 2.0 * det::atan2(triple, 1.0 + a.dot(b) + b.dot(c) + c.dot(a));
        let s = SphericalTriangle {
            a,
            b,
            c,
            triple,
            solid_angle,
        };
        (s, a_ok & b_ok & c_ok)
    }

    /// The solid angle Ω, in steradians: the area of the spherical triangle.
    #[inline]
    pub fn solid_angle(&self) -> f32 {
        self.solid_angle
    }

    /// A unit direction uniformly distributed over the spherical triangle (density 1 / Ω) from
    /// `u` ∈ [0, 1)². Arvo's map: `u.x` picks the area Â = u.x · Ω of a sub-triangle (a, b, ĉ) with
    /// ĉ on the arc from a to c, `u.y` a point on the arc from b to ĉ such that the area swept is
    /// uniform. Continuous and monotone in both numbers, so it keeps their stratification. Without
    /// branches (selects only), so that lanes code vectorises it.
    #[inline(always)]
    pub fn sample(&self, u: glam::Vec2) -> Vec3 {
        let (a, b, c) = (self.a, self.b, self.c);
        let cos_c = a.dot(b);
        // The angle α at corner a, between the arcs to b and to c: its sine and cosine are the
        // triple product and cos(bc) − cos(ab)·cos(ac), both over sin(ab)·sin(ac), so they are
        // that pair normalised (no arctangent, no sine).
        let (y, x) = (self.triple, b.dot(c) - cos_c * a.dot(c));
        let r = (x * x + y * y).sqrt();
        let (sin_alpha, cos_alpha) = (y / r, x / r);
        let (sin_alpha, cos_alpha) = if r > 0.0 {
            (sin_alpha, cos_alpha)
        } else {
            (0.0, 1.0)
        };
        // sin and cos of Â − α, Â = u.x · Ω ≤ 2π, from those of Â.
        let (sin_area, cos_area) = det::sin_cos_moderate(u.x * self.solid_angle);
        let s = sin_area * cos_alpha - cos_area * sin_alpha;
        let t = cos_area * cos_alpha + sin_area * sin_alpha;
        let uu = t - cos_alpha;
        let v = s + sin_alpha * cos_c;
        // q: the cosine of the arc from a to ĉ.
        let q = ((v * t - uu * s) * cos_alpha - v) / ((v * s + uu * t) * sin_alpha);
        let q = if q.is_nan() { 1.0 } else { q.clamp(-1.0, 1.0) };
        let c_hat = q * a + (1.0 - q * q).max(0.0).sqrt() * orthonormal_part(c, a);
        let z = 1.0 - u.y * (1.0 - c_hat.dot(b));
        let z = z.clamp(-1.0, 1.0);
        z * b + (1.0 - z * z).max(0.0).sqrt() * orthonormal_part(c_hat, b)
    }
}

/// The unit vector along the part of `v` orthogonal to the unit vector `axis` (zero when `v` is
/// parallel to it).
#[inline(always)]
fn orthonormal_part(v: Vec3, axis: Vec3) -> Vec3 {
    (v - v.dot(axis) * axis).normalize_or_zero()
}

/// The barycentrics (one per corner) of the point where the ray from `p` along `w` meets the plane
/// of the triangle `corners`, clamped into the triangle (a direction sampled within its solid angle
/// meets it inside but for rounding). None when `w` is parallel to the plane.
#[inline]
pub fn barycentrics_along(corners: [Vec3; 3], p: Vec3, w: Vec3) -> Option<Vec3> {
    let (b, valid) = barycentrics_along_unchecked(corners, p, w);
    valid.then_some(b)
}

/// [`barycentrics_along`] without a branch, for lanes code: the barycentrics and whether they
/// are valid (false when `w` is parallel to the plane).
#[inline(always)]
pub fn barycentrics_along_unchecked(corners: [Vec3; 3], p: Vec3, w: Vec3) -> (Vec3, bool) {
    let (e1, e2) = (corners[1] - corners[0], corners[2] - corners[0]);
    let s1 = w.cross(e2);
    let divisor = s1.dot(e1);
    let valid = divisor != 0.0 && divisor.is_finite();
    let s = p - corners[0];
    let b1 = (s.dot(s1) / divisor).clamp(0.0, 1.0);
    let b2 = (w.dot(s.cross(e1)) / divisor).clamp(0.0, 1.0);
    let sum = b1 + b2;
    let (b1n, b2n) = (b1 / sum, b2 / sum);
    let (b1, b2) = if sum > 1.0 { (b1n, b2n) } else { (b1, b2) };
    (Vec3::new((1.0 - b1 - b2).max(0.0), b1, b2), valid)
}
