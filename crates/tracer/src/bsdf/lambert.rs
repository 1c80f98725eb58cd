//! The Lambertian (diffuse) lobe: f = albedo / π, sampled by cosine-weighted directions.

use crate::sampling::sample_cosine_hemisphere;
use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;

/// f · cos θi of a white Lambertian lobe (`cos_i` against the shading normal, ≥ 0).
#[inline]
pub(super) fn eval(cos_i: f32) -> f32 {
    cos_i * FRAC_1_PI
}

/// Density of [`sample`] (equal to [`eval`]: the lobe is sampled exactly).
#[inline]
pub(super) fn pdf(cos_i: f32) -> f32 {
    cos_i * FRAC_1_PI
}

/// Cosine-weighted direction in the upper hemisphere of the local frame.
#[inline]
pub(super) fn sample(u: Vec2) -> Vec3 {
    sample_cosine_hemisphere(u)
}
