//! KHR_lights_punctual: point, spot and directional lights placed by their node's world transform.
//! Spot and directional lights point along the node's −Z; `range` is ignored (lights fall off with
//! the inverse square).
//!
//! Units: the extension is photometric (point and spot `intensity` in candela, directional in lux),
//! the tracer radiometric (see [`crate::light`]). color × intensity is converted at
//! [`LUMENS_PER_WATT`] = 683 lm/W: point and spot cd / 683 = W/sr, directional lx / 683 = W/m².
//! That is the convention of Blender's glTF exporter (its default "Standard" lighting mode writes
//! W/(4π)·683 for point and spot lamps and W/m²·683 for the sun, and its importer divides by 683
//! again), so a Blender export renders at Blender's brightness. Emissive materials carry no such
//! factor (`emissiveFactor` × `emissiveStrength` is radiance as it is, as Blender writes it), so
//! lamps and emitters keep the balance they had in Blender.

use super::error::{label, GltfError, Warnings};
use super::nodes::node_label;
use crate::light::{DirectionalLight, PointLight, PunctualLight, SpotLight};
use glam::{DMat3, DMat4, DVec3, Vec3};
use gltf::json;
use json::extensions::scene::khr_lights_punctual::{Light, Type};
use json::validation::Checked;
use std::f32::consts::FRAC_PI_2;

/// Luminous efficacy used to convert the extension's photometric intensities (cd, lx) to the
/// tracer's radiometric ones (W/sr, W/m²): 683 lm/W, the peak of the photopic curve, as Blender's
/// exporter and importer use it.
pub const LUMENS_PER_WATT: f32 = 683.0;

fn lights(root: &json::Root) -> &[Light] {
    root.extensions
        .as_ref()
        .and_then(|e| e.khr_lights_punctual.as_ref())
        .map_or(&[], |l| l.lights.as_slice())
}

/// The light carried by node `node` (if any), in world space.
pub(crate) fn node_light(
    root: &json::Root,
    node: usize,
    world: &DMat4,
    warnings: &mut Warnings,
) -> Result<Option<PunctualLight>, GltfError> {
    let Some(ext) = root
        .nodes
        .get(node)
        .and_then(|n| n.extensions.as_ref())
        .and_then(|e| e.khr_lights_punctual.as_ref())
    else {
        return Ok(None);
    };
    let index = ext.light.value();
    let all = lights(root);
    let Some(light) = all.get(index) else {
        return Err(GltfError::Object {
            object: node_label(root, node),
            reason: format!(
                "refers to KHR_lights_punctual light {index}, but the file has {} lights",
                all.len()
            ),
        });
    };
    let object = format!(
        "{} (on {})",
        label("light", index, light.name.as_deref()),
        node_label(root, node)
    );
    let err = |reason: &str| GltfError::Object {
        object: object.clone(),
        reason: reason.to_string(),
    };
    if !light.color.iter().all(|c| c.is_finite()) || !light.intensity.is_finite() {
        return Err(err("non-finite color or intensity"));
    }
    if light.range.is_some() {
        warnings
            .once("KHR_lights_punctual range is ignored (lights fall off with the inverse square)");
    }
    let intensity = (Vec3::from(light.color) * (light.intensity / LUMENS_PER_WATT)).max(Vec3::ZERO);
    let position = world.transform_point3(DVec3::ZERO).as_vec3();
    let direction = (DMat3::from_mat4(*world) * DVec3::NEG_Z)
        .normalize_or_zero()
        .as_vec3();
    let ty = match light.type_ {
        Checked::Valid(t) => t,
        Checked::Invalid => return Err(err("invalid type")),
    };
    if ty != Type::Point && direction == Vec3::ZERO {
        warnings.once(format!(
            "{object}: degenerate node transform gives no direction; light skipped"
        ));
        return Ok(None);
    }
    if !position.is_finite() {
        return Err(err("position overflows"));
    }
    Ok(Some(match ty {
        Type::Point => PunctualLight::Point(PointLight {
            position,
            intensity,
        }),
        Type::Directional => PunctualLight::Directional(DirectionalLight {
            direction,
            illuminance: intensity,
        }),
        Type::Spot => {
            let (inner, outer) = light
                .spot
                .as_ref()
                .map_or((0.0, std::f32::consts::FRAC_PI_4), |s| {
                    (s.inner_cone_angle, s.outer_cone_angle)
                });
            if !inner.is_finite() || !outer.is_finite() {
                return Err(err("non-finite cone angles"));
            }
            let outer = outer.clamp(0.0, FRAC_PI_2);
            let inner = inner.clamp(0.0, outer);
            PunctualLight::Spot(SpotLight {
                position,
                direction,
                intensity,
                cos_inner: crate::math::det::cos(inner),
                cos_outer: crate::math::det::cos(outer),
            })
        }
    }))
}
