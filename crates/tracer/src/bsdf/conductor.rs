//! The glTF metal BRDF: F_schlick(f0 = base_color, v·h) · D · V (GGX, height-correlated Smith), or a
//! perfect mirror of reflectance F_schlick(base_color, cos θo) when the roughness is zero. Single
//! scattering only: rough metals lose the energy of inter-reflections between microfacets.

use super::fresnel::schlick;
use glam::Vec3;

/// Fresnel reflectance of the metal at a microfacet with cos(v, h) = `cos_vh`.
#[inline]
pub(super) fn fresnel(base_color: Vec3, cos_vh: f32) -> Vec3 {
    schlick(base_color, cos_vh)
}

/// Reflectance of the smooth metal (the mirror's throughput) at cos θo = `mu`.
#[inline]
pub(super) fn mirror(base_color: Vec3, mu: f32) -> Vec3 {
    schlick(base_color, mu)
}

/// Mean over channels of the rough metal's directional albedo, given the GGX albedo terms (A, B)
/// at cos θo (see [`super::albedo`]); used to choose lobes.
#[inline]
pub(super) fn mean_albedo(mean_base: f32, (a, b): (f32, f32)) -> f32 {
    mean_base * a + b
}
