use glam::{Vec2, Vec3};

/// Uniform point on a triangle, as barycentric coordinates (b₀, b₁, b₂), density 1/area.
///
/// Uses the square-root parametrisation (b₀ = 1 − √ξ₁, b₁ = ξ₂√ξ₁): continuous and monotone in both
/// coordinates, so it preserves the stratification of low-discrepancy points.
#[inline]
pub fn sample_uniform_triangle(u: Vec2) -> Vec3 {
    let s = u.x.sqrt();
    let b0 = 1.0 - s;
    let b1 = u.y * s;
    Vec3::new(b0, b1, 1.0 - b0 - b1)
}
