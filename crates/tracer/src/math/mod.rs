//! Small math helpers on top of `glam`: orthonormal frames, luminance, and ray-origin offsetting.

pub mod det;
mod frame;
mod offset;

pub use frame::Frame;
pub(crate) use offset::offset_unit_normal;
pub use offset::{offset_ray_origin, spawn_clearance};

use glam::Vec3;

/// Rec. 709 / sRGB luminance of a linear RGB value.
#[inline]
pub fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// True if every component is zero (±0). The three comparisons are combined without
/// short-circuiting: `v == Vec3::ZERO` compares one component after the other, a branch each, and
/// on the sample path whether a throughput or a BSDF value is black is hard to predict.
#[inline(always)]
pub fn is_black(v: Vec3) -> bool {
    (v.x == 0.0) & (v.y == 0.0) & (v.z == 0.0)
}

/// Mirror `v` about the normal `n` (both pointing away from the surface).
#[inline]
pub fn reflect(v: Vec3, n: Vec3) -> Vec3 {
    2.0 * v.dot(n) * n - v
}
