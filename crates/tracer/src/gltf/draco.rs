//! KHR_draco_mesh_compression: a primitive whose vertices and triangles are one Draco stream (in the
//! buffer view its extension names), decoded with the pure-Rust `draco-core` decoder. The extension's
//! `attributes` map each glTF attribute to a Draco attribute id; the triangles are the stream's faces.
//!
//! The primitive's own accessors still describe the data (count, type); when the extension is not
//! required they also hold an uncompressed copy. A stream that cannot be decoded is then a warning
//! and the copy is used; without a copy it is an error naming the mesh and primitive.
//!
//! Memory: the decoder's limits are set before it runs: faces at most what the primitive's indices
//! accessor declares (the triangle limit was checked against that), points at most three per face,
//! and decoded bytes at most what is left of the load's decompression budget.

use super::accessors::Accessors;
use super::error::{GltfError, Warnings};
use super::mesh::primitive_label;
use super::resources::view_label;
use draco_core::{DataType, DecodeLimits, DecoderBuffer, MeshDecoder, PointAttribute};
use glam::{Vec2, Vec3, Vec4};
use gltf::json;
use json::mesh::Semantic;
use json::validation::Checked;
use json::Value;
use std::rc::Rc;

pub(crate) const EXTENSION: &str = "KHR_draco_mesh_compression";

/// A primitive's data, decoded from its Draco stream.
pub(crate) struct DracoPrimitive {
    pub positions: Rc<[Vec3]>,
    pub normals: Option<Rc<[Vec3]>>,
    pub uv: [Option<Rc<[Vec2]>>; 2],
    pub tangents: Option<Rc<[Vec4]>>,
    /// Triangle corners (a triangle list).
    pub indices: Vec<u32>,
}

/// The primitive's extension object, if it has one.
fn extension(prim: &json::mesh::Primitive) -> Option<&Value> {
    prim.extensions.as_ref()?.others.get(EXTENSION)
}

/// The accessors the primitive would read without Draco (its attributes and indices).
fn accessors(prim: &json::mesh::Primitive) -> impl Iterator<Item = usize> + '_ {
    prim.attributes
        .iter()
        .filter(|(s, _)| {
            matches!(
                s,
                Checked::Valid(
                    Semantic::Positions
                        | Semantic::Normals
                        | Semantic::Tangents
                        | Semantic::TexCoords(0 | 1)
                )
            )
        })
        .map(|(_, i)| i.value())
        .chain(prim.indices.map(|i| i.value()))
}

/// Decodes mesh `mesh`'s primitive `p` from its Draco stream: `Ok(None)` when it has no Draco
/// extension, or when the stream failed and the uncompressed accessors are used instead (with a
/// warning).
pub(crate) fn decode_primitive(
    acc: &Accessors,
    mesh: usize,
    p: usize,
    warnings: &mut Warnings,
) -> Result<Option<DracoPrimitive>, GltfError> {
    let root = acc.root();
    let Some(prim) = root.meshes.get(mesh).and_then(|m| m.primitives.get(p)) else {
        return Ok(None);
    };
    let Some(ext) = extension(prim) else {
        return Ok(None);
    };
    let plabel = primitive_label(root, mesh, p);
    match decode(acc, prim, ext, &plabel) {
        Ok(d) => Ok(Some(d)),
        Err(e @ GltfError::Limit(_)) => Err(e),
        Err(e) => {
            let required = root.extensions_required.iter().any(|x| x == EXTENSION);
            let fallback = accessors(prim).all(|i| {
                root.accessors
                    .get(i)
                    .is_some_and(|a| a.buffer_view.is_some())
            });
            if fallback && !required {
                warnings.once(format!(
                    "{e}; using the primitive's uncompressed accessors instead"
                ));
                Ok(None)
            } else {
                Err(e)
            }
        }
    }
}

fn decode(
    acc: &Accessors,
    prim: &json::mesh::Primitive,
    ext: &Value,
    plabel: &str,
) -> Result<DracoPrimitive, GltfError> {
    let root = acc.root();
    let err = |reason: String| GltfError::Data {
        object: plabel.to_string(),
        reason: format!("{EXTENSION}: {reason}"),
    };
    let Some(view) = ext
        .get("bufferView")
        .and_then(Value::as_u64)
        .and_then(|v| usize::try_from(v).ok())
    else {
        return Err(err("bufferView is missing or not an index".into()));
    };
    let Some(ids) = ext.get("attributes").and_then(Value::as_object) else {
        return Err(err("attributes is missing or not an object".into()));
    };
    let vlabel = view_label(root, view);
    let bytes = acc.resources().view(view).map_err(|e| err(e.to_string()))?;

    // What the primitive declares bounds what the stream may decode.
    let count = |i: Option<usize>| {
        i.and_then(|i| root.accessors.get(i))
            .map_or(0, |a| a.count.0)
    };
    let position = prim
        .attributes
        .get(&Checked::Valid(Semantic::Positions))
        .map(|i| i.value());
    let declared_corners = match prim.indices {
        Some(i) => count(Some(i.value())),
        None => count(position),
    };
    let max_faces = declared_corners / 3;
    let left = acc.resources().decompress_budget_left();
    let limits = DecodeLimits::default()
        .with_max_faces(max_faces)
        .with_max_points(max_faces.saturating_mul(3))
        .with_max_decoded_bytes(left);
    let mut buffer = DecoderBuffer::new(bytes).with_limits(limits);
    let mut decoder = MeshDecoder::new();
    let mut mesh = draco_core::Mesh::new();
    decoder.decode(&mut buffer, &mut mesh).map_err(|e| {
        err(format!(
            "cannot decode {vlabel} ({} bytes): {e}",
            bytes.len()
        ))
    })?;

    let points = mesh.num_points();
    let faces = mesh.faces();
    // What the decoded arrays take (f32 components and u32 corners), against the budget.
    let components: usize = [
        ("POSITION", 3),
        ("NORMAL", 3),
        ("TEXCOORD_0", 2),
        ("TEXCOORD_1", 2),
        ("TANGENT", 4),
    ]
    .iter()
    .filter(|(name, _)| ids.contains_key(*name))
    .map(|(_, n)| n)
    .sum();
    let decoded_bytes = (points as u64)
        .saturating_mul(components as u64 * 4)
        .saturating_add(faces.len() as u64 * 12);
    acc.resources().charge_decompressed(decoded_bytes, plabel)?;

    let attribute = |name: &str, n: usize| -> Result<Option<Vec<f32>>, GltfError> {
        let Some(id) = ids.get(name) else {
            return Ok(None);
        };
        let Some(id) = id.as_u64().and_then(|v| u32::try_from(v).ok()) else {
            return Err(err(format!("attribute id of {name} is not an integer")));
        };
        let Some(a) = mesh.attribute_by_unique_id(id) else {
            return Err(err(format!(
                "{name} refers to Draco attribute {id}, which the stream in {vlabel} does not have"
            )));
        };
        if (a.num_components() as usize) < n {
            return Err(err(format!(
                "{name} (Draco attribute {id}) has {} components where {n} are needed",
                a.num_components()
            )));
        }
        let values = read(a, points, n);
        if let Some(i) = values.iter().position(|x| !x.is_finite()) {
            return Err(err(format!(
                "{name} has a non-finite component at vertex {}",
                i / n
            )));
        }
        Ok(Some(values))
    };
    let Some(positions) = attribute("POSITION", 3)? else {
        return Err(err("attributes has no POSITION".into()));
    };
    let positions: Rc<[Vec3]> = positions.chunks_exact(3).map(Vec3::from_slice).collect();
    let normals = attribute("NORMAL", 3)?.map(|v| {
        v.chunks_exact(3)
            .map(Vec3::from_slice)
            .collect::<Rc<[Vec3]>>()
    });
    let uv0 = attribute("TEXCOORD_0", 2)?.map(|v| {
        v.chunks_exact(2)
            .map(Vec2::from_slice)
            .collect::<Rc<[Vec2]>>()
    });
    let uv1 = attribute("TEXCOORD_1", 2)?.map(|v| {
        v.chunks_exact(2)
            .map(Vec2::from_slice)
            .collect::<Rc<[Vec2]>>()
    });
    let tangents = attribute("TANGENT", 4)?.map(|v| {
        v.chunks_exact(4)
            .map(Vec4::from_slice)
            .collect::<Rc<[Vec4]>>()
    });
    let indices: Vec<u32> = faces.iter().flat_map(|f| f.map(|p| p.0)).collect();
    Ok(DracoPrimitive {
        positions,
        normals,
        uv: [uv0, uv1],
        tangents,
        indices,
    })
}

/// The first `n` components of every point of `a`, as glTF would read them (normalized integers
/// scaled to [0, 1] or [-1, 1]).
fn read(a: &PointAttribute, points: usize, n: usize) -> Vec<f32> {
    let mut v = a.read_f32s(points, n);
    if a.normalized() {
        let scale = |x: f32, max: f32, signed: bool| {
            if signed {
                (x / max).max(-1.0)
            } else {
                x / max
            }
        };
        let (max, signed) = match a.data_type() {
            DataType::Int8 => (127.0, true),
            DataType::Uint8 => (255.0, false),
            DataType::Int16 => (32767.0, true),
            DataType::Uint16 => (65535.0, false),
            _ => return v,
        };
        for x in &mut v {
            *x = scale(*x, max, signed);
        }
    }
    v
}
