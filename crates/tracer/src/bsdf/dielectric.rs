//! The glTF transmission lobe (KHR_materials_transmission, _ior, _specular): a dielectric interface.
//!
//! At an interface (or a microfacet) where the exact unpolarised Fresnel reflectance is F
//! ([`super::fresnel::dielectric`]), the reflected fraction is, per channel,
//! R = specular · min(F · tint, 1), with tint = f0_tinted / f0 the KHR_materials_specular colour tint
//! of the normal-incidence reflectance (so R(0°) matches the opaque layer's tinted f0), and the
//! transmitted fraction is T = (1 − max R) · base_color (0 under total internal reflection). With
//! specular = 1 and a white specular colour this is the exact dielectric: R = F, T = (1 − F) base.
//!
//! - **Volume** (`thin_walled == false`): the surface bounds a medium of index `ior`, outside on the
//!   front side. η = n_t / n_i is `ior` when wo is on the front side and 1/`ior` on the back side.
//!   Smooth: a mirror and a Snell refraction. Rough: Walter et al. 2007's microfacet BTDF with the
//!   exact Fresnel on the microfacet normal and GGX visible-normal sampling, as pbrt-v4's
//!   `DielectricBxDF`; G2 = 1/(1 + Λo + Λi) for transmission too. Radiance transport: a refracted
//!   radiance is scaled by 1/η² (the path entering the denser medium carries radiance that left it, so
//!   it is divided by ior²; leaving it, multiplied by ior²). An `ior` of 1 makes the interface
//!   invisible: transmission is then always the straight delta, whatever the roughness.
//! - **Thin-walled**: a sheet of negligible thickness, η = ior on both sides, no radiance scaling.
//!   Smooth: the mirror plus a straight transmission wi = −wo with weight T at the incidence angle.
//!   Rough: as the Khronos glTF sample renderer does, the transmission lobe is the GGX reflection lobe
//!   mirrored through the surface plane: f_t(wo, wi) = T(v·h) D(h) V(wo, wi') with wi' the mirror image
//!   of wi and h = normalize(wo + wi'); it is sampled by sampling a visible normal, reflecting, and
//!   mirroring the result. (Its `applyIorToRoughness` tweak of the transmission roughness is not used.)
//!
//! Reflection and transmission are chosen in proportion to the channel means of R and T, evaluated on
//! the sampled microfacet normal (or the macro normal when smooth).

use super::fresnel::{dielectric, f0_from_ior};
use glam::Vec3;

/// An ior closer to 1 than this makes the volume interface a pure straight transmission.
pub(super) const INDEX_MATCHED: f32 = 1e-3;

/// The dielectric interface of the transmission lobe.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Interface {
    pub ior: f32,
    pub thin: bool,
    /// KHR_materials_specular specularFactor.
    pub weight: f32,
    /// Colour tint of the reflectance (tinted f0 / untinted f0).
    pub tint: Vec3,
}

/// How an interface splits the light at one incidence angle.
#[derive(Clone, Copy, Debug)]
pub(super) struct Split {
    /// Reflected fraction, per channel.
    pub r: Vec3,
    /// Transmitted fraction (tinted by the base colour), per channel; before any radiance scaling.
    pub t: Vec3,
    /// Probability of choosing reflection when sampling.
    pub p_r: f32,
}

impl Interface {
    /// No transmission lobe.
    pub(super) const NONE: Interface = Interface {
        ior: 1.5,
        thin: true,
        weight: 0.0,
        tint: Vec3::ZERO,
    };

    pub(super) fn new(ior: f32, thin: bool, specular: f32, specular_color: Vec3) -> Self {
        let f0 = f0_from_ior(ior);
        let tint = if f0 > 0.0 {
            (f0 * specular_color).min(Vec3::ONE) / f0
        } else {
            specular_color.min(Vec3::ONE)
        };
        Interface {
            ior,
            thin,
            weight: specular,
            tint: tint.max(Vec3::ZERO),
        }
    }

    /// η = n_t / n_i for an outgoing direction on the front (`entering`) or back side.
    #[inline]
    pub(super) fn eta(&self, entering: bool) -> f32 {
        if self.thin || entering {
            self.ior
        } else {
            1.0 / self.ior
        }
    }

    /// Reflected and transmitted fractions at incidence cosine `cos_i` (≥ 0) with relative index `eta`.
    #[inline]
    pub(super) fn split(&self, cos_i: f32, eta: f32, base_color: Vec3) -> Split {
        let f = dielectric(cos_i, eta);
        let r = self.weight * (f * self.tint).min(Vec3::ONE);
        let t = if f >= 1.0 {
            Vec3::ZERO
        } else {
            (1.0 - r.max_element()) * base_color
        };
        let (mr, mt) = (r.element_sum(), t.element_sum());
        let p_r = if mr + mt > 0.0 { mr / (mr + mt) } else { 1.0 };
        Split { r, t, p_r }
    }
}

/// The generalized half vector of a refraction pair (Walter et al. 2007): m ∝ o + η i, oriented to the
/// upper hemisphere. Returns (m, o·m, i·m) when the pair is a valid refraction through m (o above and i
/// below the microfacet), `None` otherwise.
#[inline]
pub(super) fn refraction_half_vector(o: Vec3, i: Vec3, eta: f32) -> Option<(Vec3, f32, f32)> {
    let h = o + eta * i;
    let len2 = h.length_squared();
    if len2 < 1e-24 {
        return None;
    }
    let mut m = h / len2.sqrt();
    if m.z < 0.0 {
        m = -m;
    }
    let (om, im) = (o.dot(m), i.dot(m));
    if om <= 0.0 || im >= 0.0 {
        return None;
    }
    Some((m, om, im))
}

/// Mirror of `o` about the microfacet normal `m`.
#[inline]
pub(super) fn reflect(o: Vec3, m: Vec3) -> Vec3 {
    2.0 * o.dot(m) * m - o
}
