use super::disk::sample_concentric_disk;
use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;

/// Uniform direction on the hemisphere z ≥ 0 (density 1/2π): z = ξ₁ is uniform because the solid
/// angle above height z is linear in z (Archimedes).
#[inline]
pub fn sample_uniform_hemisphere(u: Vec2) -> Vec3 {
    let z = u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (s, c) = crate::math::det::sin_cos_turns(u.y);
    Vec3::new(r * c, r * s, z)
}

#[inline]
pub fn uniform_hemisphere_pdf() -> f32 {
    0.5 * FRAC_1_PI
}

/// Uniform direction on the whole sphere (density 1/4π).
#[inline]
pub fn sample_uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (s, c) = crate::math::det::sin_cos_turns(u.y);
    Vec3::new(r * c, r * s, z)
}

#[inline]
pub fn uniform_sphere_pdf() -> f32 {
    0.25 * FRAC_1_PI
}

/// Cosine-weighted direction on the hemisphere z ≥ 0 (density cos θ / π), by Malley's method: a
/// uniform point on the disk projected up to the hemisphere.
#[inline]
pub fn sample_cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = sample_concentric_disk(u);
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    Vec3::new(d.x, d.y, z)
}

#[inline]
pub fn cosine_hemisphere_pdf(cos_theta: f32) -> f32 {
    cos_theta.max(0.0) * FRAC_1_PI
}
