//! glTF 2.0 materials (metallic-roughness with the extensions pathfarm supports) and their textures.
//! A [`Material`] is evaluated at a hit point into the parameters of a [`crate::bsdf::Bsdf`].

mod texture;

pub use texture::{ColorSpace, Texture, TextureError, TextureSampler, WrapMode};

use crate::bsdf::PbrParams;
use glam::{Affine2, Vec2, Vec3, Vec4};

/// A reference from a material to a texture: which texture, which UV set, and an optional
/// `KHR_texture_transform`.
#[derive(Clone, Debug, PartialEq)]
pub struct TextureRef {
    /// Index into `Scene::textures`.
    pub texture: u32,
    /// 0 for TEXCOORD_0, 1 for TEXCOORD_1.
    pub texcoord: u8,
    pub transform: Option<Affine2>,
}

impl TextureRef {
    #[inline]
    pub fn uv(&self, uv: &[Vec2; 2]) -> Vec2 {
        let base = uv[(self.texcoord as usize).min(1)];
        match &self.transform {
            Some(t) => t.transform_point2(base),
            None => base,
        }
    }
}

/// How a material's alpha is used (glTF `alphaMode`).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum AlphaMode {
    /// Alpha is ignored.
    #[default]
    Opaque,
    /// Surfaces with alpha < cutoff are not there (cut-outs).
    Mask { cutoff: f32 },
    /// Alpha is the probability that a ray sees the surface (stochastic coverage), so that the
    /// expected image is the alpha blend, without sorting.
    Blend,
}

/// `KHR_materials_volume`: when thickness > 0 the closed mesh bounds a refracting, absorbing medium.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Volume {
    /// Absorption coefficient σ_a per unit length, from attenuationColor and attenuationDistance
    /// (σ = −ln(c) / d); zero where the distance is infinite.
    pub sigma_a: Vec3,
}

/// A material as the renderer uses it. Factors are the glTF factors; textures multiply them.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    pub name: Option<String>,
    /// Linear RGBA base color factor.
    pub base_color: Vec4,
    pub base_color_texture: Option<TextureRef>,
    pub metallic: f32,
    pub roughness: f32,
    /// glTF metallicRoughnessTexture: roughness in G, metallic in B (linear).
    pub metallic_roughness_texture: Option<TextureRef>,
    /// emissiveFactor × KHR_materials_emissive_strength (linear radiance).
    pub emissive: Vec3,
    pub emissive_texture: Option<TextureRef>,
    /// Tangent-space normal map and its scale.
    pub normal_texture: Option<(TextureRef, f32)>,
    pub alpha_mode: AlphaMode,
    pub double_sided: bool,
    /// KHR_materials_specular specularFactor (weight of the dielectric specular layer) and its texture
    /// (alpha channel).
    pub specular: f32,
    pub specular_texture: Option<TextureRef>,
    /// KHR_materials_specular specularColorFactor and texture (sRGB).
    pub specular_color: Vec3,
    pub specular_color_texture: Option<TextureRef>,
    /// KHR_materials_ior (1.5 by default).
    pub ior: f32,
    /// KHR_materials_transmission transmissionFactor and texture (R channel).
    pub transmission: f32,
    pub transmission_texture: Option<TextureRef>,
    /// KHR_materials_volume with thickness > 0; `None` means thin-walled.
    pub volume: Option<Volume>,
    /// KHR_materials_clearcoat clearcoatFactor and clearcoatTexture (R channel, linear).
    pub clearcoat: f32,
    pub clearcoat_texture: Option<TextureRef>,
    /// KHR_materials_clearcoat clearcoatRoughnessFactor and clearcoatRoughnessTexture (G channel,
    /// linear).
    pub clearcoat_roughness: f32,
    pub clearcoat_roughness_texture: Option<TextureRef>,
    /// KHR_materials_clearcoat clearcoatNormalTexture and its scale: the coat's own normal map
    /// (without it the coat takes the interpolated normal, not the base's normal map).
    pub clearcoat_normal_texture: Option<(TextureRef, f32)>,
    /// KHR_materials_sheen sheenColorFactor (linear) and sheenColorTexture (RGB, sRGB).
    pub sheen_color: Vec3,
    pub sheen_color_texture: Option<TextureRef>,
    /// KHR_materials_sheen sheenRoughnessFactor and sheenRoughnessTexture (alpha channel, linear).
    pub sheen_roughness: f32,
    pub sheen_roughness_texture: Option<TextureRef>,
}

impl Default for Material {
    /// The glTF default material: white, metallic 1, roughness 1, as the spec says.
    fn default() -> Self {
        Material {
            name: None,
            base_color: Vec4::ONE,
            base_color_texture: None,
            metallic: 1.0,
            roughness: 1.0,
            metallic_roughness_texture: None,
            emissive: Vec3::ZERO,
            emissive_texture: None,
            normal_texture: None,
            alpha_mode: AlphaMode::Opaque,
            double_sided: false,
            specular: 1.0,
            specular_texture: None,
            specular_color: Vec3::ONE,
            specular_color_texture: None,
            ior: 1.5,
            transmission: 0.0,
            transmission_texture: None,
            volume: None,
            clearcoat: 0.0,
            clearcoat_texture: None,
            clearcoat_roughness: 0.0,
            clearcoat_roughness_texture: None,
            clearcoat_normal_texture: None,
            sheen_color: Vec3::ZERO,
            sheen_color_texture: None,
            sheen_roughness: 0.0,
            sheen_roughness_texture: None,
        }
    }
}

/// The material evaluated at one surface point.
#[derive(Clone, Copy, Debug)]
pub struct ShadingInputs {
    pub params: PbrParams,
    /// Perturbed (normal-mapped) shading normal, unit, world space; equals the interpolated normal
    /// when there is no normal map.
    pub normal: Vec3,
    /// The clear coat's normal: the interpolated normal perturbed by the clearcoatNormalTexture, or
    /// the interpolated normal itself (never the base's normal map).
    pub coat_normal: Vec3,
}

impl Material {
    /// True if the surface can emit light at all.
    #[inline]
    pub fn is_emissive(&self) -> bool {
        self.emissive.max_element() > 0.0
    }

    /// True if rays may pass through the surface (MASK or BLEND).
    #[inline]
    pub fn has_alpha(&self) -> bool {
        !matches!(self.alpha_mode, AlphaMode::Opaque)
    }

    /// Emitted radiance towards a viewer on the `front` side (or either side when double-sided).
    #[inline]
    pub fn emission(&self, textures: &[Texture], uv: &[Vec2; 2], front: bool) -> Vec3 {
        if !(front || self.double_sided) || !self.is_emissive() {
            return Vec3::ZERO;
        }
        match &self.emissive_texture {
            Some(t) => self.emissive * sample(textures, t, uv, ColorSpace::Srgb).truncate(),
            None => self.emissive,
        }
    }

    /// Average emitted radiance over the surface (the factor times the texture's mean), for choosing
    /// lights in proportion to their power.
    pub fn average_emission(&self, textures: &[Texture]) -> Vec3 {
        match &self.emissive_texture {
            Some(t) => match textures.get(t.texture as usize) {
                Some(tex) => self.emissive * tex.average(ColorSpace::Srgb).truncate(),
                None => self.emissive,
            },
            None => self.emissive,
        }
    }

    /// Coverage at this point, in [0, 1] (base color alpha × texture alpha).
    #[inline]
    pub fn alpha(&self, textures: &[Texture], uv: &[Vec2; 2]) -> f32 {
        let a = self.base_color.w;
        match &self.base_color_texture {
            Some(t) => a * sample(textures, t, uv, ColorSpace::Srgb).w,
            None => a,
        }
    }

    /// Whether a ray passes through the surface at this point. `u` is a uniform random number used by
    /// BLEND's stochastic coverage.
    #[inline]
    pub fn passes_through(&self, textures: &[Texture], uv: &[Vec2; 2], u: f32) -> bool {
        match self.alpha_mode {
            AlphaMode::Opaque => false,
            AlphaMode::Mask { cutoff } => self.alpha(textures, uv) < cutoff,
            AlphaMode::Blend => u >= self.alpha(textures, uv),
        }
    }

    /// The BSDF parameters when no texture varies them or the shading normal over the surface:
    /// what [`Material::shade`] returns everywhere (the emissive texture plays no part in them).
    pub fn constant_params(&self) -> Option<PbrParams> {
        let textured = self.base_color_texture.is_some()
            || self.metallic_roughness_texture.is_some()
            || self.specular_texture.is_some()
            || self.specular_color_texture.is_some()
            || self.transmission_texture.is_some()
            || self.normal_texture.is_some()
            || self.clearcoat_texture.is_some()
            || self.clearcoat_roughness_texture.is_some()
            || self.clearcoat_normal_texture.is_some()
            || self.sheen_color_texture.is_some()
            || self.sheen_roughness_texture.is_some();
        (!textured).then(|| self.shade(&[], &[Vec2::ZERO; 2], Vec3::Z, None).params)
    }

    /// The parameters of the factors alone (the textures left out), for a textured material
    /// whose textures change its lobes' colours and values and its shading normal but not which
    /// lobes there are, beyond a black base colour turning the diffuse lobe off (and, with
    /// transmission, the transmitted one: callers that need more check it): a base colour
    /// texture, a normal map, and a metallic-roughness texture where the metal's share cannot
    /// change a pure Lambertian into another kind (metallic 0 with no specular layer, or a
    /// specular layer on) and the roughness stays above zero (the factor times the texture's
    /// least green). `None` for any other material, untextured ones included
    /// ([`Material::constant_params`]).
    pub fn params_of_factors(&self, textures: &[Texture]) -> Option<PbrParams> {
        if self.constant_params().is_some() {
            return None;
        }
        if let Some(t) = &self.metallic_roughness_texture {
            let lambert = self.metallic == 0.0 && self.specular == 0.0;
            let least_green = textures.get(t.texture as usize).map_or(1.0, |tex| {
                tex.texels.iter().map(|c| c[1]).min().unwrap_or(0) as f32 / 255.0
            });
            // Half the least product: a bilinear blend of texels rounds within an ulp of them.
            let rough = self.roughness * least_green * 0.5 > 0.0;
            if !(lambert || (self.specular > 0.0 && rough)) {
                return None;
            }
        }
        Material {
            base_color_texture: None,
            metallic_roughness_texture: None,
            normal_texture: None,
            ..self.clone()
        }
        .constant_params()
    }

    /// Evaluates textures into BSDF parameters and the shading normal. `normal` is the interpolated
    /// unit shading normal facing the same side as the geometric normal's front; `tangent` the
    /// interpolated tangent with its bitangent sign (needed only with a normal map).
    pub fn shade(
        &self,
        textures: &[Texture],
        uv: &[Vec2; 2],
        normal: Vec3,
        tangent: Option<Vec4>,
    ) -> ShadingInputs {
        let mut base = self.base_color.truncate();
        if let Some(t) = &self.base_color_texture {
            base *= sample(textures, t, uv, ColorSpace::Srgb).truncate();
        }
        let (mut metallic, mut roughness) = (self.metallic, self.roughness);
        if let Some(t) = &self.metallic_roughness_texture {
            let mr = sample(textures, t, uv, ColorSpace::Linear);
            roughness *= mr.y;
            metallic *= mr.z;
        }
        let mut specular = self.specular;
        if let Some(t) = &self.specular_texture {
            specular *= sample(textures, t, uv, ColorSpace::Linear).w;
        }
        let mut specular_color = self.specular_color;
        if let Some(t) = &self.specular_color_texture {
            specular_color *= sample(textures, t, uv, ColorSpace::Srgb).truncate();
        }
        let mut transmission = self.transmission;
        if let Some(t) = &self.transmission_texture {
            transmission *= sample(textures, t, uv, ColorSpace::Linear).x;
        }
        let n = match (&self.normal_texture, tangent) {
            (Some((t, scale)), Some(tan)) => normal_mapped(textures, t, *scale, uv, normal, tan),
            _ => normal,
        };
        // The layers, read only where they are on (a zero factor disables a layer whatever its
        // textures say).
        let (mut clearcoat, mut clearcoat_roughness) = (self.clearcoat, self.clearcoat_roughness);
        let mut coat_normal = normal;
        if clearcoat > 0.0 {
            if let Some(t) = &self.clearcoat_texture {
                clearcoat *= sample(textures, t, uv, ColorSpace::Linear).x;
            }
            if let Some(t) = &self.clearcoat_roughness_texture {
                clearcoat_roughness *= sample(textures, t, uv, ColorSpace::Linear).y;
            }
            if let (Some((t, scale)), Some(tan)) = (&self.clearcoat_normal_texture, tangent) {
                coat_normal = normal_mapped(textures, t, *scale, uv, normal, tan);
            }
        }
        let (mut sheen_color, mut sheen_roughness) = (self.sheen_color, self.sheen_roughness);
        if sheen_color.max_element() > 0.0 {
            if let Some(t) = &self.sheen_color_texture {
                sheen_color *= sample(textures, t, uv, ColorSpace::Srgb).truncate();
            }
            if let Some(t) = &self.sheen_roughness_texture {
                sheen_roughness *= sample(textures, t, uv, ColorSpace::Linear).w;
            }
        }
        ShadingInputs {
            params: PbrParams {
                base_color: base.max(Vec3::ZERO),
                metallic: metallic.clamp(0.0, 1.0),
                roughness: roughness.clamp(0.0, 1.0),
                specular: specular.clamp(0.0, 1.0),
                specular_color: specular_color.max(Vec3::ZERO),
                ior: self.ior,
                transmission: transmission.clamp(0.0, 1.0),
                thin_walled: self.volume.is_none(),
                clearcoat: clearcoat.clamp(0.0, 1.0),
                clearcoat_roughness: clearcoat_roughness.clamp(0.0, 1.0),
                sheen_color: sheen_color.max(Vec3::ZERO),
                sheen_roughness: sheen_roughness.clamp(0.0, 1.0),
            },
            normal: n,
            coat_normal,
        }
    }

    /// Every texture the material reads, with the normal maps.
    pub fn texture_refs(&self) -> impl Iterator<Item = &TextureRef> {
        [
            &self.base_color_texture,
            &self.metallic_roughness_texture,
            &self.emissive_texture,
            &self.specular_texture,
            &self.specular_color_texture,
            &self.transmission_texture,
            &self.clearcoat_texture,
            &self.clearcoat_roughness_texture,
            &self.sheen_color_texture,
            &self.sheen_roughness_texture,
        ]
        .into_iter()
        .flatten()
        .chain(self.normal_texture.as_ref().map(|(r, _)| r))
        .chain(self.clearcoat_normal_texture.as_ref().map(|(r, _)| r))
    }

    /// The normal map that decides the tangent frame's texture coordinates: the base's, else the
    /// clear coat's.
    pub fn tangent_space_map(&self) -> Option<&TextureRef> {
        self.normal_texture
            .as_ref()
            .or(self.clearcoat_normal_texture.as_ref())
            .map(|(r, _)| r)
    }
}

/// `normal` (unit, interpolated) perturbed by the tangent-space normal map `t` of scale `scale`,
/// with the interpolated tangent `tan` and its bitangent sign; `normal` itself where the frame or
/// the result degenerates.
#[inline]
fn normal_mapped(
    textures: &[Texture],
    t: &TextureRef,
    scale: f32,
    uv: &[Vec2; 2],
    normal: Vec3,
    tan: Vec4,
) -> Vec3 {
    let m = sample(textures, t, uv, ColorSpace::Linear);
    let tn = Vec3::new(
        (2.0 * m.x - 1.0) * scale,
        (2.0 * m.y - 1.0) * scale,
        2.0 * m.z - 1.0,
    );
    let t3 = tan.truncate();
    let t3 = (t3 - normal * normal.dot(t3)).normalize_or_zero();
    if t3 != Vec3::ZERO {
        let b = normal.cross(t3) * if tan.w < 0.0 { -1.0 } else { 1.0 };
        let mapped = (t3 * tn.x + b * tn.y + normal * tn.z).normalize_or_zero();
        if mapped != Vec3::ZERO && mapped.is_finite() {
            return mapped;
        }
    }
    normal
}

#[inline]
fn sample(textures: &[Texture], t: &TextureRef, uv: &[Vec2; 2], cs: ColorSpace) -> Vec4 {
    match textures.get(t.texture as usize) {
        Some(tex) => tex.sample(t.uv(uv), cs),
        None => Vec4::ONE,
    }
}
