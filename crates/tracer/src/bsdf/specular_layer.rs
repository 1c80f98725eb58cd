//! The dielectric (non-metal, opaque) part of the glTF material: KHR_materials_specular's
//! `fresnel_mix` of a Lambertian base under a GGX specular layer.
//!
//! glTF defines, per channel, with f0 = min(((ior − 1)/(ior + 1))² · specular_color, 1) and
//! F = f0 + (1 − f0)(1 − |v·h|)⁵:
//!
//!   f = (1 − specular · max(F)) · base_color / π + specular · F · D · V.
//!
//! Taken literally (h = normalize(wo + wi) in the diffuse term too), this creates energy at grazing
//! view angles: the specular lobe reflects up to F(cos θo) → 1 there, while the diffuse term, whose
//! v·h stays away from 0 for most wi, is barely dimmed (a smooth white plastic seen at cos θo = 0.05
//! would reflect ≈ 1.7). We therefore replace the diffuse weight by **albedo scaling**:
//!
//!   f_diffuse = (1 − specular · max_c E_c(cos θo)) · base_color / π,
//!
//! where E_c is the directional albedo of the specular lobe F_c · D · V itself (exactly F_c(cos θo)
//! for the mirror, and f0_c · A + B from the conservative tables of [`super::albedo`] when rough).
//! The total is then specular · E_c + (1 − specular · max E) · base_c ≤ 1 for every wo, and the
//! diffuse receives exactly the energy the layer does not reflect (including what single-scattering
//! GGX loses). With specular = 0 it is exactly Lambertian with albedo base_color. The price is that
//! the diffuse term depends on wo alone and is not reciprocal, which a unidirectional path tracer
//! does not need.

use super::fresnel::{f0_from_ior, schlick};
use glam::Vec3;

/// The specular layer of the opaque dielectric.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct SpecularLayer {
    /// KHR_materials_specular specularFactor.
    pub weight: f32,
    /// Tinted normal-incidence reflectance.
    pub f0: Vec3,
    f0_max: f32,
    f0_mean: f32,
}

impl SpecularLayer {
    /// No specular layer.
    pub(super) const NONE: SpecularLayer = SpecularLayer {
        weight: 0.0,
        f0: Vec3::ZERO,
        f0_max: 0.0,
        f0_mean: 0.0,
    };

    pub(super) fn new(ior: f32, specular: f32, specular_color: Vec3) -> Self {
        let f0 = (f0_from_ior(ior) * specular_color)
            .min(Vec3::ONE)
            .max(Vec3::ZERO);
        SpecularLayer {
            weight: specular,
            f0,
            f0_max: f0.max_element(),
            f0_mean: f0.element_sum() / 3.0,
        }
    }

    /// The tinted f0's largest and mean channel (`glossy.rs`).
    pub(super) fn f0_summary(&self) -> (f32, f32) {
        (self.f0_max, self.f0_mean)
    }

    /// The layer of these values (those of [`SpecularLayer::new`] and
    /// [`SpecularLayer::f0_summary`]).
    #[inline(always)]
    pub(super) fn from_parts(weight: f32, f0: Vec3, f0_max: f32, f0_mean: f32) -> Self {
        SpecularLayer {
            weight,
            f0,
            f0_max,
            f0_mean,
        }
    }

    /// F at a microfacet with cos(v, h) = `cos_vh` (not yet multiplied by the weight).
    #[inline]
    pub(super) fn fresnel(&self, cos_vh: f32) -> Vec3 {
        schlick(self.f0, cos_vh)
    }

    /// Weight of the diffuse base under a rough layer, from the GGX albedo terms (A, B) at cos θo.
    #[inline]
    pub(super) fn diffuse_factor(&self, (a, b): (f32, f32)) -> f32 {
        (1.0 - self.weight * (self.f0_max * a + b)).max(0.0)
    }

    /// Weight of the diffuse base under a mirror-smooth layer whose Fresnel at cos θo is `f`.
    #[inline]
    pub(super) fn diffuse_factor_smooth(&self, f: Vec3) -> f32 {
        (1.0 - self.weight * f.max_element()).max(0.0)
    }

    /// Mean over channels of the rough layer's directional albedo (weight included).
    #[inline]
    pub(super) fn mean_albedo(&self, (a, b): (f32, f32)) -> f32 {
        self.weight * (self.f0_mean * a + b)
    }
}
