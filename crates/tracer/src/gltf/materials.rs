//! glTF materials → [`Material`]: metallic-roughness factors and textures, emissive ×
//! KHR_materials_emissive_strength, normal map and scale, alpha mode and cutoff, double-sidedness,
//! KHR_materials_specular, KHR_materials_ior, KHR_materials_transmission, KHR_materials_volume,
//! KHR_materials_clearcoat and KHR_materials_sheen, with KHR_texture_transform on every texture
//! reference. The occlusion texture is ignored (a path tracer computes occlusion).
//!
//! The `gltf` crate (1.4) has no types for KHR_materials_clearcoat and KHR_materials_sheen: they are
//! read from the material's `extensions.others` JSON here, their texture references through the
//! crate's own `textureInfo` / `normalTextureInfo` types, so they get the same checks and
//! KHR_texture_transform as every other texture.

use super::error::{label, GltfError, Warnings};
use super::textures::TextureCache;
use crate::material::{AlphaMode, Material, TextureRef, Volume};
use glam::{Affine2, Mat2, Vec2, Vec3, Vec4};
use gltf::json;
use json::extensions::texture::TextureTransform;
use json::validation::Checked;

pub(crate) fn material_label(root: &json::Root, index: usize) -> String {
    label(
        "material",
        index,
        root.materials.get(index).and_then(|m| m.name.as_deref()),
    )
}

/// KHR_texture_transform as an affine map: translation · rotation · scale, with the extension's
/// rotation matrix [[cos, sin], [−sin, cos]] (rows).
pub fn texture_transform_matrix(offset: [f32; 2], rotation: f32, scale: [f32; 2]) -> Affine2 {
    let (s, c) = crate::math::det::sin_cos(rotation);
    let rot = Mat2::from_cols(Vec2::new(c, -s), Vec2::new(s, c));
    let scl = Mat2::from_diagonal(Vec2::from(scale));
    Affine2::from_mat2_translation(rot * scl, Vec2::from(offset))
}

struct Converter<'c, 'r, 'a> {
    textures: &'c mut TextureCache<'r, 'a>,
    warnings: &'c mut Warnings,
    object: String,
    /// How many textures the file has (for the texture indices inside extensions the `gltf` crate
    /// does not validate).
    texture_count: usize,
}

impl Converter<'_, '_, '_> {
    fn finite(&self, field: &str, values: &[f32]) -> Result<(), GltfError> {
        if values.iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err(GltfError::Object {
                object: self.object.clone(),
                reason: format!("non-finite {field}"),
            })
        }
    }

    fn texcoord(&mut self, set: u32, field: &str) -> u8 {
        if set > 1 {
            self.warnings.once(format!(
                "{}: {field} uses TEXCOORD_{set}; only TEXCOORD_0 and TEXCOORD_1 are supported, using TEXCOORD_1",
                self.object
            ));
            1
        } else {
            set as u8
        }
    }

    fn reference(
        &mut self,
        texture: usize,
        tex_coord: u32,
        transform: Option<&TextureTransform>,
        field: &str,
    ) -> Result<TextureRef, GltfError> {
        let scene_texture = self.textures.texture(texture, self.warnings)?;
        let mut set = tex_coord;
        let mut affine = None;
        if let Some(t) = transform {
            if let Some(s) = t.tex_coord {
                set = s;
            }
            self.finite(
                &format!("{field} KHR_texture_transform"),
                &[t.offset.0[0], t.offset.0[1], t.rotation.0],
            )?;
            self.finite(&format!("{field} KHR_texture_transform"), &t.scale.0)?;
            affine = Some(texture_transform_matrix(
                t.offset.0,
                t.rotation.0,
                t.scale.0,
            ));
        }
        Ok(TextureRef {
            texture: scene_texture,
            texcoord: self.texcoord(set, field),
            transform: affine,
        })
    }

    fn info(
        &mut self,
        info: Option<&json::texture::Info>,
        field: &str,
    ) -> Result<Option<TextureRef>, GltfError> {
        let Some(info) = info else {
            return Ok(None);
        };
        let transform = info
            .extensions
            .as_ref()
            .and_then(|e| e.texture_transform.as_ref());
        self.reference(info.index.value(), info.tex_coord, transform, field)
            .map(Some)
    }

    /// A normal map and its scale, from a `normalTextureInfo`.
    fn normal_info(
        &mut self,
        nt: &json::material::NormalTexture,
        field: &str,
    ) -> Result<(TextureRef, f32), GltfError> {
        let transform: Option<TextureTransform> = nt
            .extensions
            .as_ref()
            .and_then(|e| e.others.get("KHR_texture_transform"))
            .and_then(|v| json::deserialize::from_value(v.clone()).ok());
        self.finite(&format!("{field} scale"), &[nt.scale])?;
        let r = self.reference(nt.index.value(), nt.tex_coord, transform.as_ref(), field)?;
        Ok((r, nt.scale))
    }

    /// An error naming the material and `field` of extension `ext`.
    fn invalid(&self, ext: &str, field: &str, what: &str) -> GltfError {
        GltfError::Object {
            object: self.object.clone(),
            reason: format!("{ext} {field} {what}"),
        }
    }

    /// A number of an extension object (`default` when absent), refused when it is not a finite
    /// number once read as f32.
    fn number(
        &self,
        ext: &str,
        obj: &json::Value,
        field: &str,
        default: f32,
    ) -> Result<f32, GltfError> {
        match obj.get(field) {
            None => Ok(default),
            Some(v) => match v.as_f64() {
                Some(x) => {
                    self.finite(&format!("{ext} {field}"), &[x as f32])?;
                    Ok(x as f32)
                }
                None => Err(self.invalid(ext, field, "is not a number")),
            },
        }
    }

    /// An RGB array of an extension object (`default` when absent), every component finite.
    fn rgb(
        &self,
        ext: &str,
        obj: &json::Value,
        field: &str,
        default: Vec3,
    ) -> Result<Vec3, GltfError> {
        let Some(v) = obj.get(field) else {
            return Ok(default);
        };
        let c: Vec<f32> = match v.as_array() {
            Some(a) if a.len() == 3 => a
                .iter()
                .map(|x| x.as_f64().map(|x| x as f32))
                .collect::<Option<_>>()
                .ok_or_else(|| self.invalid(ext, field, "is not an array of 3 numbers"))?,
            _ => return Err(self.invalid(ext, field, "is not an array of 3 numbers")),
        };
        self.finite(&format!("{ext} {field}"), &c)?;
        Ok(Vec3::new(c[0], c[1], c[2]))
    }

    /// A `textureInfo` of an extension object.
    fn ext_info(
        &mut self,
        ext: &str,
        obj: &json::Value,
        field: &str,
    ) -> Result<Option<TextureRef>, GltfError> {
        let Some(v) = obj.get(field) else {
            return Ok(None);
        };
        let info: json::texture::Info = json::deserialize::from_value(v.clone())
            .map_err(|e| self.invalid(ext, field, &format!("is not a textureInfo: {e}")))?;
        self.check_index(ext, field, info.index.value())?;
        self.info(Some(&info), field)
    }

    /// A `normalTextureInfo` of an extension object.
    fn ext_normal_info(
        &mut self,
        ext: &str,
        obj: &json::Value,
        field: &str,
    ) -> Result<Option<(TextureRef, f32)>, GltfError> {
        let Some(v) = obj.get(field) else {
            return Ok(None);
        };
        let nt: json::material::NormalTexture = json::deserialize::from_value(v.clone())
            .map_err(|e| self.invalid(ext, field, &format!("is not a normalTextureInfo: {e}")))?;
        self.check_index(ext, field, nt.index.value())?;
        self.normal_info(&nt, field).map(Some)
    }

    /// The `gltf` crate validated the core's texture indices, not those inside extensions it does
    /// not know.
    fn check_index(&self, ext: &str, field: &str, index: usize) -> Result<(), GltfError> {
        let count = self.texture_count;
        if index < count {
            Ok(())
        } else {
            Err(self.invalid(
                ext,
                field,
                &format!("refers to texture {index}, but the file has {count} textures"),
            ))
        }
    }
}

/// Converts glTF material `index`, decoding the textures it uses.
pub(crate) fn convert(
    root: &json::Root,
    index: usize,
    textures: &mut TextureCache<'_, '_>,
    warnings: &mut Warnings,
) -> Result<Material, GltfError> {
    let object = material_label(root, index);
    let Some(m) = root.materials.get(index) else {
        return Err(GltfError::Object {
            object,
            reason: "does not exist".into(),
        });
    };
    let mut cv = Converter {
        textures,
        warnings,
        object,
        texture_count: root.textures.len(),
    };
    let pbr = &m.pbr_metallic_roughness;
    cv.finite("baseColorFactor", &pbr.base_color_factor.0)?;
    cv.finite(
        "metallicFactor/roughnessFactor",
        &[pbr.metallic_factor.0, pbr.roughness_factor.0],
    )?;
    cv.finite("emissiveFactor", &m.emissive_factor.0)?;
    let mut out = Material {
        name: m.name.clone(),
        base_color: Vec4::from(pbr.base_color_factor.0),
        base_color_texture: cv.info(pbr.base_color_texture.as_ref(), "baseColorTexture")?,
        metallic: pbr.metallic_factor.0.clamp(0.0, 1.0),
        roughness: pbr.roughness_factor.0.clamp(0.0, 1.0),
        metallic_roughness_texture: cv.info(
            pbr.metallic_roughness_texture.as_ref(),
            "metallicRoughnessTexture",
        )?,
        emissive: Vec3::from(m.emissive_factor.0).max(Vec3::ZERO),
        emissive_texture: cv.info(m.emissive_texture.as_ref(), "emissiveTexture")?,
        double_sided: m.double_sided,
        ..Material::default()
    };
    if let Some(nt) = &m.normal_texture {
        out.normal_texture = Some(cv.normal_info(nt, "normalTexture")?);
    }
    out.alpha_mode = match m.alpha_mode {
        Checked::Valid(json::material::AlphaMode::Mask) => {
            let cutoff = m.alpha_cutoff.map_or(0.5, |c| c.0);
            cv.finite("alphaCutoff", &[cutoff])?;
            AlphaMode::Mask { cutoff }
        }
        Checked::Valid(json::material::AlphaMode::Blend) => AlphaMode::Blend,
        _ => AlphaMode::Opaque,
    };
    let ext = m.extensions.as_ref();
    if let Some(strength) = ext.and_then(|e| e.emissive_strength.as_ref()) {
        let s = strength.emissive_strength.0;
        cv.finite("KHR_materials_emissive_strength emissiveStrength", &[s])?;
        out.emissive *= s.max(0.0);
        cv.finite("emissive (factor × strength)", &out.emissive.to_array())?;
    }
    if let Some(spec) = ext.and_then(|e| e.specular.as_ref()) {
        cv.finite(
            "KHR_materials_specular specularFactor",
            &[spec.specular_factor.0],
        )?;
        cv.finite(
            "KHR_materials_specular specularColorFactor",
            &spec.specular_color_factor.0,
        )?;
        out.specular = spec.specular_factor.0.clamp(0.0, 1.0);
        out.specular_texture = cv.info(spec.specular_texture.as_ref(), "specularTexture")?;
        out.specular_color = Vec3::from(spec.specular_color_factor.0).max(Vec3::ZERO);
        out.specular_color_texture =
            cv.info(spec.specular_color_texture.as_ref(), "specularColorTexture")?;
    }
    if let Some(ior) = ext.and_then(|e| e.ior.as_ref()) {
        let v = ior.ior.0;
        cv.finite("KHR_materials_ior ior", &[v])?;
        // The extension allows 0 (meaning no refraction); below 1 is otherwise meaningless.
        out.ior = if v >= 1.0 { v } else { 1.0 };
    }
    if let Some(tr) = ext.and_then(|e| e.transmission.as_ref()) {
        cv.finite(
            "KHR_materials_transmission transmissionFactor",
            &[tr.transmission_factor.0],
        )?;
        out.transmission = tr.transmission_factor.0.clamp(0.0, 1.0);
        out.transmission_texture =
            cv.info(tr.transmission_texture.as_ref(), "transmissionTexture")?;
    }
    if let Some(vol) = ext.and_then(|e| e.volume.as_ref()) {
        let thickness = vol.thickness_factor.0;
        let distance = vol.attenuation_distance.0;
        let color = vol.attenuation_color.0;
        cv.finite("KHR_materials_volume attenuationColor", &color)?;
        if thickness > 0.0 {
            let sigma_a = if distance.is_finite() && distance > 0.0 {
                Vec3::from(color).map(|c| -crate::math::det::ln(c.clamp(1e-8, 1.0)) / distance)
            } else {
                Vec3::ZERO
            };
            out.volume = Some(Volume { sigma_a });
        }
    }
    if let Some(cc) = ext.and_then(|e| e.others.get(CLEARCOAT)) {
        clearcoat(&mut cv, cc, &mut out)?;
    }
    if let Some(sh) = ext.and_then(|e| e.others.get(SHEEN)) {
        sheen(&mut cv, sh, &mut out)?;
    }
    if let Some(ext) = ext {
        for name in ext.others.keys() {
            if name != CLEARCOAT && name != SHEEN {
                cv.warnings
                    .once(format!("extension {name} is not supported; ignored"));
            }
        }
    }
    Ok(out)
}

const CLEARCOAT: &str = "KHR_materials_clearcoat";
const SHEEN: &str = "KHR_materials_sheen";

/// KHR_materials_clearcoat: clearcoatFactor (0) × clearcoatTexture R, clearcoatRoughnessFactor (0)
/// × clearcoatRoughnessTexture G, clearcoatNormalTexture with its scale.
fn clearcoat(
    cv: &mut Converter<'_, '_, '_>,
    obj: &json::Value,
    out: &mut Material,
) -> Result<(), GltfError> {
    if !obj.is_object() {
        return Err(cv.invalid(CLEARCOAT, "", "is not an object"));
    }
    out.clearcoat = cv
        .number(CLEARCOAT, obj, "clearcoatFactor", 0.0)?
        .clamp(0.0, 1.0);
    out.clearcoat_texture = cv.ext_info(CLEARCOAT, obj, "clearcoatTexture")?;
    out.clearcoat_roughness = cv
        .number(CLEARCOAT, obj, "clearcoatRoughnessFactor", 0.0)?
        .clamp(0.0, 1.0);
    out.clearcoat_roughness_texture = cv.ext_info(CLEARCOAT, obj, "clearcoatRoughnessTexture")?;
    out.clearcoat_normal_texture = cv.ext_normal_info(CLEARCOAT, obj, "clearcoatNormalTexture")?;
    Ok(())
}

/// KHR_materials_sheen: sheenColorFactor ([0, 0, 0]) × sheenColorTexture RGB (sRGB),
/// sheenRoughnessFactor (0) × sheenRoughnessTexture A.
fn sheen(
    cv: &mut Converter<'_, '_, '_>,
    obj: &json::Value,
    out: &mut Material,
) -> Result<(), GltfError> {
    if !obj.is_object() {
        return Err(cv.invalid(SHEEN, "", "is not an object"));
    }
    out.sheen_color = cv
        .rgb(SHEEN, obj, "sheenColorFactor", Vec3::ZERO)?
        .max(Vec3::ZERO);
    out.sheen_color_texture = cv.ext_info(SHEEN, obj, "sheenColorTexture")?;
    out.sheen_roughness = cv
        .number(SHEEN, obj, "sheenRoughnessFactor", 0.0)?
        .clamp(0.0, 1.0);
    out.sheen_roughness_texture = cv.ext_info(SHEEN, obj, "sheenRoughnessTexture")?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texture_transform_is_translation_rotation_scale() {
        let t = texture_transform_matrix([0.5, 0.25], std::f32::consts::FRAC_PI_2, [2.0, 3.0]);
        // S(1,0) = (2,0); R(2,0) = (2cos, −2sin) = (0,−2); + offset.
        let p = t.transform_point2(Vec2::new(1.0, 0.0));
        assert!((p - Vec2::new(0.5, -1.75)).length() < 1e-6, "{p}");
        let p = t.transform_point2(Vec2::new(0.0, 1.0));
        // S(0,1) = (0,3); R = (3 sin, 3 cos) = (3, 0); + offset.
        assert!((p - Vec2::new(3.5, 0.25)).length() < 1e-6, "{p}");
    }
}
