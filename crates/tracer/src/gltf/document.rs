//! From bytes to a validated glTF document: GLB or JSON detection, JSON parsing, the
//! `extensionsRequired` check against what this loader supports, and the `gltf` crate's validation.
//! Also the warnings about glTF features the loader ignores.

use super::error::{GltfError, Warnings};
use super::glb;
use super::mesh::primitive_label;
use super::nodes::Instance;
use gltf::json;
use json::mesh::Semantic;
use json::validation::Checked;

/// Extensions this loader implements (so a file may require them).
pub const SUPPORTED_EXTENSIONS: &[&str] = &[
    "EXT_mesh_gpu_instancing",
    "EXT_meshopt_compression",
    "EXT_texture_webp",
    "KHR_draco_mesh_compression",
    "KHR_lights_punctual",
    "KHR_materials_clearcoat",
    "KHR_materials_emissive_strength",
    "KHR_materials_ior",
    "KHR_materials_sheen",
    "KHR_materials_specular",
    "KHR_materials_transmission",
    "KHR_materials_volume",
    "KHR_mesh_quantization",
    "KHR_meshopt_compression",
    "KHR_texture_transform",
];

/// A parsed, validated document and the GLB BIN chunk, if any.
pub(crate) struct Parsed<'a> {
    pub root: json::Root,
    pub bin: Option<&'a [u8]>,
    pub warnings: Vec<String>,
}

fn describe_start(bytes: &[u8]) -> String {
    let head: Vec<String> = bytes.iter().take(8).map(|b| format!("{b:02x}")).collect();
    if head.is_empty() {
        "the input is empty".into()
    } else {
        format!(
            "neither GLB (magic \"glTF\") nor JSON; it starts with bytes {}",
            head.join(" ")
        )
    }
}

pub(crate) fn parse(bytes: &[u8]) -> Result<Parsed<'_>, GltfError> {
    let (json_bytes, bin, warnings) = if glb::is_glb(bytes) {
        let g = glb::parse(bytes)?;
        (g.json, g.bin, g.warnings)
    } else {
        (bytes, None, Vec::new())
    };
    let json_bytes = json_bytes
        .strip_prefix(b"\xEF\xBB\xBF")
        .unwrap_or(json_bytes);
    match json_bytes.iter().find(|b| !b.is_ascii_whitespace()) {
        Some(b'{') => {}
        _ if json_bytes.len() < bytes.len() => {
            return Err(GltfError::NotGltf(
                "the GLB JSON chunk is not a JSON object".into(),
            ));
        }
        _ => return Err(GltfError::NotGltf(describe_start(bytes))),
    }
    let mut root: json::Root = match json::deserialize::from_slice(json_bytes) {
        Ok(root) => root,
        Err(e) => {
            // A clearer message for glTF 1.0 and other versions, whose JSON does not deserialize.
            if let Ok(value) = json::deserialize::from_slice::<json::Value>(json_bytes) {
                if let Some(v) = value
                    .get("asset")
                    .and_then(|a| a.get("version"))
                    .and_then(|v| v.as_str())
                {
                    if !v.starts_with("2.") && v != "2" {
                        return Err(GltfError::NotGltf(format!(
                            "glTF version {v} is not supported (only 2.x)"
                        )));
                    }
                }
            }
            return Err(GltfError::NotGltf(format!("invalid glTF JSON: {e}")));
        }
    };
    if let Some(ext) = root
        .extensions_required
        .iter()
        .find(|e| !SUPPORTED_EXTENSIONS.contains(&e.as_str()))
    {
        return Err(GltfError::UnsupportedExtension(ext.clone()));
    }
    // All required extensions are supported here; the gltf crate refuses some of them, so hide them
    // from its validation (and put them back: EXT_texture_webp's fallback depends on them).
    let required = std::mem::take(&mut root.extensions_required);
    precheck(&root)?;
    validate(&root)?;
    root.extensions_required = required;
    Ok(Parsed {
        root,
        bin,
        warnings,
    })
}

/// What the `gltf` crate's validation would panic on rather than report.
fn precheck(root: &json::Root) -> Result<(), GltfError> {
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            if let Some(i) = prim.attributes.get(&Checked::Valid(Semantic::Positions)) {
                if i.value() >= root.accessors.len() {
                    return Err(GltfError::Data {
                        object: primitive_label(root, m, p),
                        reason: format!(
                            "POSITION refers to accessor {}, but the file has {} accessors",
                            i.value(),
                            root.accessors.len()
                        ),
                    });
                }
            }
        }
    }
    Ok(())
}

/// The `gltf` crate's validation (what `gltf::Document::from_json` runs), less one rule that
/// KHR_draco_mesh_compression breaks on purpose: the accessors a Draco primitive describes may have
/// no `bufferView` (their data is in the Draco stream).
fn validate(root: &json::Root) -> Result<(), GltfError> {
    use json::validation::Validate;
    let draco_accessors: std::collections::HashSet<usize> = root
        .meshes
        .iter()
        .flat_map(|m| &m.primitives)
        .filter(|p| {
            p.extensions
                .as_ref()
                .is_some_and(|e| e.others.contains_key(super::draco::EXTENSION))
        })
        .flat_map(|p| {
            p.attributes
                .values()
                .map(|i| i.value())
                .chain(p.indices.map(|i| i.value()))
        })
        .collect();
    let mut errors = Vec::new();
    root.validate(root, json::Path::new, &mut |path, error| {
        let path = path();
        let exempt = matches!(error, json::validation::Error::Missing)
            && draco_accessors
                .iter()
                .any(|i| path.as_str() == format!("accessors[{i}].bufferView"));
        if !exempt {
            errors.push((path, error));
        }
    });
    if errors.is_empty() {
        Ok(())
    } else {
        Err(validation_error(gltf::Error::Validation(errors)))
    }
}

fn validation_error(e: gltf::Error) -> GltfError {
    match e {
        gltf::Error::Validation(errors) => {
            const SHOWN: usize = 8;
            let mut parts: Vec<String> = errors
                .iter()
                .take(SHOWN)
                .map(|(path, err)| format!("{}: {}", path.as_str(), err))
                .collect();
            if errors.len() > SHOWN {
                parts.push(format!("and {} more", errors.len() - SHOWN));
            }
            GltfError::Invalid(parts.join("; "))
        }
        other => GltfError::Invalid(other.to_string()),
    }
}

/// One warning per ignored feature: unsupported `extensionsUsed`, and for a scene loaded still
/// (not at a time of its animation), skins and animations.
pub(crate) fn feature_warnings(
    root: &json::Root,
    instances: &[Instance],
    animated: bool,
    warnings: &mut Warnings,
) {
    for ext in &root.extensions_used {
        if !SUPPORTED_EXTENSIONS.contains(&ext.as_str()) {
            warnings.once(format!("extension {ext} is not supported; ignored"));
        }
    }
    if animated {
        return;
    }
    if instances
        .iter()
        .any(|i| root.nodes.get(i.node).is_some_and(|n| n.skin.is_some()))
    {
        warnings.once(
            "skins are applied only in animated scenes rendered at a time; skinned meshes are \
             rendered in their bind pose",
        );
    }
    if !root.animations.is_empty() {
        warnings.once(
            "the scene is rendered at rest, not at a time of its animations (render a frame with \
             gltf::SceneSource, or `pathfarm render --frame`)",
        );
    }
}
