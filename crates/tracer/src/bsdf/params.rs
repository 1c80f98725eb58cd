//! The BSDF's inputs: a glTF metallic-roughness material at one point, after texturing.

use glam::Vec3;

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
    /// KHR_materials_clearcoat clearcoat (factor × texture R): weight of the clear coat on top of
    /// everything else (0 removes it).
    pub clearcoat: f32,
    /// KHR_materials_clearcoat clearcoatRoughness (factor × texture G), perceptual; the coat's GGX α
    /// is its square. Exactly 0 makes the coat a mirror.
    pub clearcoat_roughness: f32,
    /// KHR_materials_sheen sheenColor (factor × texture RGB), linear: the sheen lobe's tint (black
    /// removes it).
    pub sheen_color: Vec3,
    /// KHR_materials_sheen sheenRoughness (factor × texture A), perceptual.
    pub sheen_roughness: f32,
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
            clearcoat: 0.0,
            clearcoat_roughness: 0.0,
            sheen_color: Vec3::ZERO,
            sheen_roughness: 0.0,
        }
    }
}
