//! Reading one mesh primitive: its accessors (or its KHR_draco_mesh_compression stream) decoded,
//! every index checked, every float finite, triangles assembled from TRIANGLES, TRIANGLE_STRIP or
//! TRIANGLE_FAN, cut down to the vertices they use (`compact`), and MikkTSpace tangents computed
//! where a normal map needs them and the file has none (see `mesh` for how the triangles are then
//! emitted, and `tangents`).

use super::accessors::Accessors;
use super::compact::{compact, gather};
use super::draco;
use super::emit::{LocalPrimitive, LocalTangents, TangentsRef, Vertices};
use super::error::{GltfError, Warnings};
use super::mesh::{primitive_label, Needs, PrimitiveInfo, PrimitiveMaterial};
use super::tangents::{self, Tangents};
use glam::{Vec2, Vec3};
use gltf::json;
use json::mesh::{Mode, Semantic};
use json::validation::Checked;
use std::rc::Rc;

/// One primitive's local data: the vertices its triangles use (the decoded accessors themselves,
/// shared, when they use all of them).
#[derive(Debug)]
pub(super) struct Primitive {
    pub info: PrimitiveInfo,
    /// Corners as indices into the arrays below.
    pub triangles: Vec<[u32; 3]>,
    pub positions: Rc<[Vec3]>,
    pub normals: Option<Rc<[Vec3]>>,
    pub uv: [Option<Rc<[Vec2]>>; 2],
    /// The file's TANGENT, or MikkTSpace's when the material has a normal map and the file none.
    pub tangents: Option<Tangents>,
}

impl Primitive {
    pub fn vertices(&self) -> Vertices<'_> {
        Vertices {
            primitive: self.info.primitive,
            triangles: &self.triangles,
            positions: &self.positions,
            normals: self.normals.as_deref(),
            uv: [self.uv[0].as_deref(), self.uv[1].as_deref()],
            tangents: self.tangents.as_ref().map(|t| match t {
                Tangents::Vertex(v) => TangentsRef::Vertex(v),
                Tangents::Corner(c) => TangentsRef::Corner(c),
            }),
        }
    }

    /// An owned copy, shareable between threads.
    pub fn to_local(&self, material: PrimitiveMaterial) -> LocalPrimitive {
        LocalPrimitive {
            primitive: self.info.primitive,
            material,
            triangles: self.triangles.as_slice().into(),
            positions: (*self.positions).into(),
            normals: self.normals.as_deref().map(Into::into),
            uv: [
                self.uv[0].as_deref().map(Into::into),
                self.uv[1].as_deref().map(Into::into),
            ],
            tangents: self.tangents.as_ref().map(|t| match t {
                Tangents::Vertex(v) => LocalTangents::Vertex((**v).into()),
                Tangents::Corner(c) => LocalTangents::Corner((**c).into()),
            }),
        }
    }
}

/// How a primitive's vertices relate to its accessors' (see [`ReadPrimitive`]).
pub(super) struct Kept {
    pub kept: Option<Vec<u32>>,
    pub vertices: usize,
    pub draco: bool,
}

/// A primitive read for an animated scene: its local data, and which of the accessors' vertices
/// it kept (`None`: all of them, in order), for the per-vertex data read beside it (morph targets,
/// joints and weights) to be cut down the same way.
pub(crate) struct ReadPrimitive {
    pub local: LocalPrimitive,
    pub kept: Option<Vec<u32>>,
    /// Vertices of the accessors (POSITION's count).
    pub vertices: usize,
    /// Its geometry came from a KHR_draco_mesh_compression stream.
    pub draco: bool,
}

pub(super) fn read_primitive(
    acc: &Accessors<'_, '_>,
    needs: Needs,
    mesh: usize,
    info: PrimitiveInfo,
    material: PrimitiveMaterial,
    warnings: &mut Warnings,
) -> Result<(Primitive, Kept), GltfError> {
    let root = acc.root();
    let plabel = primitive_label(root, mesh, info.primitive);
    let perr = |reason: String| GltfError::Data {
        object: plabel.clone(),
        reason,
    };
    let Some(prim) = root
        .meshes
        .get(mesh)
        .and_then(|m| m.primitives.get(info.primitive))
    else {
        return Err(perr("does not exist".into()));
    };
    let attr = |s: Semantic| prim.attributes.get(&Checked::Valid(s)).map(|i| i.value());
    let Some(pos_index) = attr(Semantic::Positions) else {
        return Err(perr("has no POSITION attribute".into()));
    };
    // KHR_draco_mesh_compression: the arrays come from the Draco stream instead of the accessors.
    let draco = draco::decode_primitive(acc, mesh, info.primitive, warnings)?;
    let positions = match &draco {
        Some(d) => d.positions.clone(),
        None => acc.vec3(pos_index, &format!("POSITION of {plabel}"))?,
    };
    let n = positions.len();
    let same_count = |index: usize, name: &str, got: usize| -> Result<(), GltfError> {
        if got == n {
            Ok(())
        } else {
            Err(GltfError::Data {
                object: acc.label(index, &format!("{name} of {plabel}")),
                reason: format!("has {got} elements but POSITION (accessor {pos_index}) has {n}"),
            })
        }
    };
    let mut normals = None;
    if let (true, Some(i)) = (needs.normals, attr(Semantic::Normals)) {
        normals = match &draco {
            Some(d) => d.normals.clone(),
            None => Some(acc.vec3(i, &format!("NORMAL of {plabel}"))?),
        };
        if let Some(v) = &normals {
            same_count(i, "NORMAL", v.len())?;
        }
    }
    let mut uv: [Option<Rc<[Vec2]>>; 2] = [None, None];
    for (set, slot) in uv.iter_mut().enumerate() {
        if let (true, Some(i)) = (needs.uv[set], attr(Semantic::TexCoords(set as u32))) {
            let name = format!("TEXCOORD_{set}");
            *slot = match &draco {
                Some(d) => d.uv[set].clone(),
                None => Some(acc.vec2(i, &format!("{name} of {plabel}"))?),
            };
            if let Some(v) = slot {
                same_count(i, &name, v.len())?;
            }
        }
    }
    let mut tangents = None;
    if let (true, Some(i)) = (needs.tangents, attr(Semantic::Tangents)) {
        let v = match &draco {
            Some(d) => d.tangents.clone(),
            None => Some(acc.vec4(i, &format!("TANGENT of {plabel}"))?),
        };
        if let Some(v) = v {
            same_count(i, "TANGENT", v.len())?;
            tangents = Some(Tangents::Vertex(v));
        }
    }
    let Ok(n32) = u32::try_from(n) else {
        return Err(perr(format!("{n} vertices are too many")));
    };
    let mut triangles = match (&draco, prim.indices) {
        (Some(d), _) => {
            if let Some(&bad) = d.indices.iter().find(|&&v| v >= n32) {
                return Err(perr(format!(
                    "{}: index {bad} out of range (the stream has {n} vertices)",
                    draco::EXTENSION
                )));
            }
            assemble(
                &d.indices,
                Checked::Valid(Mode::Triangles),
                &plabel,
                warnings,
            )
        }
        (None, Some(i)) => {
            let i = i.value();
            let idx = acc.indices(i, &format!("indices of {plabel}"))?;
            if let Some(&bad) = idx.iter().find(|&&v| v >= n32) {
                return Err(perr(format!(
                    "index {bad} out of range (accessor {pos_index} has {n} vertices)"
                )));
            }
            assemble(&idx, prim.mode, &plabel, warnings)
        }
        (None, None) => {
            let idx: Vec<u32> = (0..n32).collect();
            assemble(&idx, prim.mode, &plabel, warnings)
        }
    };
    let mut p = Primitive {
        info,
        triangles: Vec::new(),
        positions,
        normals,
        uv,
        tangents,
    };
    let kept = compact(&mut triangles, n);
    if let Some(used) = &kept {
        p.positions = gather(&p.positions, used);
        p.normals = p.normals.map(|v| gather(&v, used));
        p.uv = p.uv.map(|v| v.map(|v| gather(&v, used)));
        p.tangents = p.tangents.map(|t| match t {
            Tangents::Vertex(v) => Tangents::Vertex(gather(&v, used)),
            // Only MikkTSpace makes these, below.
            corners => corners,
        });
    }
    // MikkTSpace only where the material's normal map needs it and the file has no TANGENT,
    // once per primitive (not per instance), on the local vertices: what an exporter would
    // have computed and written as TANGENT.
    let normal_map_uv = material
        .normal_map_uv
        .and_then(|s| p.uv.get(s as usize).and_then(|u| u.clone()));
    if let (true, None, Some(uv)) = (needs.tangents, &p.tangents, normal_map_uv) {
        match tangents::mikktspace(&triangles, &p.positions, p.normals.as_deref(), &uv) {
            Ok(t) => p.tangents = Some(t),
            Err(why) => warnings.once(format!(
                "{plabel}: {why}; per-triangle tangents used for its normal map"
            )),
        }
    }
    p.triangles = triangles;
    Ok((
        p,
        Kept {
            kept,
            vertices: n,
            draco: draco.is_some(),
        },
    ))
}

/// Index list → triangles for TRIANGLES, TRIANGLE_STRIP and TRIANGLE_FAN (the glTF spec's orders).
fn assemble(
    indices: &[u32],
    mode: Checked<Mode>,
    plabel: &str,
    warnings: &mut Warnings,
) -> Vec<[u32; 3]> {
    let n = indices.len();
    match mode {
        Checked::Valid(Mode::TriangleStrip) => (0..n.saturating_sub(2))
            .map(|i| {
                let (x, y) = if i % 2 == 0 {
                    (i + 1, i + 2)
                } else {
                    (i + 2, i + 1)
                };
                [indices[i], indices[x], indices[y]]
            })
            .collect(),
        Checked::Valid(Mode::TriangleFan) => (1..n.saturating_sub(1))
            .map(|i| [indices[i], indices[i + 1], indices[0]])
            .collect(),
        _ => {
            let leftover = n % 3;
            if leftover > 0 {
                warnings.once(format!(
                    "{plabel}: {leftover} trailing indices (not a whole triangle) ignored"
                ));
            }
            indices
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strips_and_fans_keep_winding() {
        let mut w = Warnings::default();
        let strip = assemble(
            &[0, 1, 2, 3],
            Checked::Valid(Mode::TriangleStrip),
            "p",
            &mut w,
        );
        assert_eq!(strip, vec![[0, 1, 2], [1, 3, 2]]);
        let fan = assemble(
            &[0, 1, 2, 3],
            Checked::Valid(Mode::TriangleFan),
            "p",
            &mut w,
        );
        assert_eq!(fan, vec![[1, 2, 0], [2, 3, 0]]);
        let tris = assemble(&[0, 1, 2, 3], Checked::Valid(Mode::Triangles), "p", &mut w);
        assert_eq!(tris, vec![[0, 1, 2]]);
        assert_eq!(w.into_vec().len(), 1);
    }
}
