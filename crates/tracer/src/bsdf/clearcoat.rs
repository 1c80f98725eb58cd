//! KHR_materials_clearcoat: a GGX dielectric coat (ior 1.5) over the whole material, as the
//! extension's `fresnel_coat` layers it:
//!
//!   f = clearcoat · F(|wo · nc|) · D_c(h) · V_c(wo, wi) + (1 − clearcoat · F(|wo · nc|)) · f_base,
//!
//! with F Schlick's approximation for f0 = ((1.5 − 1)/(1.5 + 1))² = 0.04, D_c and V_c the GGX
//! distribution and height-correlated visibility of α = clearcoatRoughness² (a mirror at roughness
//! 0), and nc the clear coat's normal: its own normal map (clearcoatNormalTexture), else the
//! interpolated normal, *not* the base's normal-mapped one, as the extension says.
//!
//! This is the extension's formula as written, and it conserves energy as it is: the coat and the
//! base are weighted by the same F(wo · nc), evaluated at the view direction rather than per
//! microfacet, so the coat reflects clearcoat · F · E_ggx(μ) ≤ clearcoat · F and the base receives
//! the rest, 1 − clearcoat · F. No albedo-scaling variant (as `specular_layer.rs` needs for
//! KHR_materials_specular, whose Fresnel is per microfacet) is needed. What the formula loses is the
//! single-scattering GGX deficit of a rough coat, clearcoat · F · (1 − E_ggx), at most a few per cent
//! at grazing angles.
//!
//! The coat's lobe is evaluated against its own normal: f_c · |wi · nc| (as the Khronos sample
//! renderer does with its clearcoat NdotL), so that its directional albedo about nc is the GGX one
//! and the white furnace holds with a tilted coat normal too; directions below the coat's surface
//! (wo · nc ≤ 0 or wi · nc ≤ 0) get nothing from it. It is sampled by GGX visible normals about nc.

use super::albedo::AlbedoRow;
use super::fresnel::{f0_from_ior, schlick_weight};
use super::microfacet::Ggx;
use crate::math::Frame;
use glam::Vec3;

/// The clear coat's index of refraction, fixed by the extension.
pub(super) const COAT_IOR: f32 = 1.5;

/// The clear coat of one material.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Coat {
    /// clearcoat (factor × texture).
    pub weight: f32,
    pub ggx: Ggx,
    /// The coat's row of the GGX albedo tables (lobe selection).
    pub row: AlbedoRow,
    /// Roughness 0: the coat is a mirror.
    pub smooth: bool,
    /// The coat's normal in the shading frame (front side), when it is not the shading normal.
    pub normal: Option<Vec3>,
}

impl Coat {
    /// No clear coat.
    pub(super) const NONE: Coat = Coat {
        weight: 0.0,
        ggx: Ggx { alpha: 1.0 },
        row: AlbedoRow::NONE,
        smooth: true,
        normal: None,
    };

    /// A coat of weight `weight` and perceptual roughness `roughness` (both sanitised to [0, 1]),
    /// with the coat normal `normal` given in the shading frame when it differs from the shading
    /// normal.
    pub(super) fn new(weight: f32, roughness: f32, normal: Option<Vec3>) -> Self {
        Coat {
            weight,
            ggx: Ggx::from_roughness(roughness),
            row: AlbedoRow::new(roughness),
            smooth: roughness == 0.0,
            normal,
        }
    }

    /// clearcoat · F at a view cosine `cos_o` against the coat normal (the extension's abs()).
    #[inline]
    pub(super) fn weight_at(&self, cos_o: f32) -> f32 {
        let f0 = f0_from_ior(COAT_IOR);
        self.weight * (f0 + (1.0 - f0) * schlick_weight(cos_o.abs()))
    }

    /// Directional albedo of the white lobe D · V · cos about the coat normal at `mu` (1 for the
    /// mirror; the conservative table's A + B otherwise, capped at 1). Used to choose lobes.
    #[inline]
    pub(super) fn lobe_albedo(&self, mu: f32) -> f32 {
        if self.smooth {
            1.0
        } else {
            let (a, b) = self.row.lookup(mu);
            (a + b).min(1.0)
        }
    }

    /// The coat's local frame, inside the shading frame, for an outgoing direction on the side `s`
    /// (±1) of the shading surface (the lobes mirror wo to the upper hemisphere; the coat normal
    /// flips with it). `None`: the coat normal is the shading normal.
    #[inline]
    pub(super) fn frame(&self, s: f32) -> Option<Frame> {
        self.normal
            .map(|n| Frame::from_z(Vec3::new(n.x * s, n.y * s, n.z)))
    }
}

/// A direction in the coat's frame (the identity without one).
#[inline]
pub(super) fn to_coat(frame: &Option<Frame>, v: Vec3) -> Vec3 {
    match frame {
        Some(f) => f.to_local(v),
        None => v,
    }
}

/// A direction from the coat's frame back to the shading frame.
#[inline]
pub(super) fn from_coat(frame: &Option<Frame>, v: Vec3) -> Vec3 {
    match frame {
        Some(f) => f.to_world(v),
        None => v,
    }
}
