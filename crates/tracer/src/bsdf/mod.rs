//! Scattering at surfaces: the glTF 2.0 metallic-roughness BSDF (core spec Appendix B, with
//! KHR_materials_specular, _ior and _transmission).
//!
//! Contract of [`Bsdf`] (every implementation detail below serves it):
//! - Directions are world-space unit vectors pointing *away* from the surface (`wo` towards the
//!   viewer, `wi` towards the light).
//! - [`Bsdf::eval`] returns f(wo, wi) · |cos θi| (cosine against the shading normal) for the
//!   non-delta lobes only; delta lobes (roughness 0 mirror and refraction) evaluate to zero.
//! - [`Bsdf::pdf`] returns the solid-angle density with which [`Bsdf::sample`] produces `wi` through its
//!   non-delta lobes (including the probability of choosing those lobes).
//! - [`Bsdf::sample`] returns a direction and weight = f·|cos|/pdf. For non-delta samples `pdf` is
//!   exactly `Bsdf::pdf(wo, wi)` and `weight` exactly `eval / pdf`; for delta samples `pdf` is the
//!   discrete probability of the chosen delta lobe and `weight` its throughput divided by it.
//! - Light never leaks: reflection requires wo and wi on the same side of the *geometric* normal,
//!   transmission on opposite sides; otherwise eval is zero.
//! - Energy: ∫ eval dwi ≤ 1 for every wo (white furnace).
//! - Radiance transport: refraction into a denser medium scales radiance by 1/η².
//!
//! Placeholder implementation: Lambertian only, to be replaced by the full model.

use crate::math::Frame;
use crate::sampling::{cosine_hemisphere_pdf, sample_cosine_hemisphere};
use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;

/// The glTF material at one surface point, after texturing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PbrParams {
    /// Linear base color (albedo of the diffuse lobe, F0 of metals, tint of transmission).
    pub base_color: Vec3,
    pub metallic: f32,
    /// Perceptual roughness; the GGX α is roughness². Exactly 0 gives delta lobes.
    pub roughness: f32,
    /// KHR_materials_specular specularFactor: weight of the dielectric specular layer (0 removes it,
    /// leaving a pure Lambertian for non-metals).
    pub specular: f32,
    /// KHR_materials_specular specularColorFactor (tints the dielectric F0).
    pub specular_color: Vec3,
    /// Index of refraction of the dielectric (KHR_materials_ior, default 1.5).
    pub ior: f32,
    /// KHR_materials_transmission transmissionFactor.
    pub transmission: f32,
    /// Thin-walled transmission (no KHR_materials_volume): light passes straight through without
    /// bending. Otherwise the surface bounds a refracting volume.
    pub thin_walled: bool,
}

impl PbrParams {
    /// A Lambertian surface of albedo `c`.
    pub fn diffuse(c: Vec3) -> Self {
        PbrParams {
            base_color: c,
            metallic: 0.0,
            roughness: 1.0,
            specular: 0.0,
            specular_color: Vec3::ONE,
            ior: 1.5,
            transmission: 0.0,
            thin_walled: true,
        }
    }
}

/// One sampled scattering direction.
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    pub wi: Vec3,
    /// f · |cos θi| / pdf.
    pub weight: Vec3,
    /// Solid-angle pdf (non-delta) or discrete lobe probability (delta).
    pub pdf: f32,
    /// Sampled from a delta lobe (perfect mirror or refraction).
    pub delta: bool,
    /// `wi` is on the other side of the surface from `wo`.
    pub transmitted: bool,
}

/// The BSDF at one surface point.
#[derive(Clone, Copy, Debug)]
pub struct Bsdf {
    frame: Frame,
    ng: Vec3,
    params: PbrParams,
}

impl Bsdf {
    /// `ns`: unit shading normal; `ng`: unit geometric normal, both on the same side;
    /// `tangent`: optional shading tangent (for anisotropy-free models only the frame's orientation).
    pub fn new(params: PbrParams, ns: Vec3, ng: Vec3, tangent: Option<Vec3>) -> Self {
        let frame = match tangent {
            Some(t) => Frame::from_zx(ns, t),
            None => Frame::from_z(ns),
        };
        Bsdf { frame, ng, params }
    }

    pub fn params(&self) -> &PbrParams {
        &self.params
    }

    /// True if some lobe is not a delta (light sampling can contribute).
    pub fn has_non_delta(&self) -> bool {
        true
    }

    /// True if a non-delta lobe transmits (direct lighting must consider both hemispheres).
    pub fn has_non_delta_transmission(&self) -> bool {
        false
    }

    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if wo.dot(self.ng) * wi.dot(self.ng) <= 0.0 {
            return Vec3::ZERO;
        }
        let lo = self.frame.to_local(wo);
        let li = self.frame.to_local(wi);
        if lo.z * li.z <= 0.0 {
            return Vec3::ZERO;
        }
        self.params.base_color * FRAC_1_PI * li.z.abs()
    }

    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        let lo = self.frame.to_local(wo);
        let li = self.frame.to_local(wi);
        if lo.z * li.z <= 0.0 {
            return 0.0;
        }
        cosine_hemisphere_pdf(li.z.abs())
    }

    pub fn sample(&self, wo: Vec3, _u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        let lo = self.frame.to_local(wo);
        let mut li = sample_cosine_hemisphere(u);
        if lo.z < 0.0 {
            li.z = -li.z;
        }
        let wi = self.frame.to_world(li);
        if wo.dot(self.ng) * wi.dot(self.ng) <= 0.0 || li.z == 0.0 {
            return None;
        }
        Some(BsdfSample {
            wi,
            weight: self.params.base_color,
            pdf: cosine_hemisphere_pdf(li.z.abs()),
            delta: false,
            transmitted: false,
        })
    }
}
