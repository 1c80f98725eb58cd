//! Deformed primitives: morph targets (POSITION, NORMAL and TANGENT displacements, blended by the
//! node's weights) and skinning (each vertex moved by the weighted sum of its joints' matrices:
//! JOINTS_n / WEIGHTS_n, four influences a set, every set the primitive has).
//!
//! The per-vertex data is read once, beside the primitive, and cut down to the vertices its
//! triangles use as the primitive was (`compact`); at a time, [`Deformable::pose`] makes the
//! primitive's vertices, which are then emitted like any primitive's (`emit`). Morphing is plain
//! f32 sums (base + Σ wₖ·Δₖ, targets of weight 0 skipped, so zero weights give the base exactly);
//! skinning composes the matrix Σ w·J in f64 and moves positions by it, normals by its inverse
//! transpose and tangents by it (their handedness kept). A vertex whose influences weigh nothing
//! is placed by the node's own transform. Weights are used as the file gives them (glTF asks
//! exporters for sums of one; Blender normalises).

use super::error::AnimationError;
use crate::gltf::accessors::Accessors;
use crate::gltf::compact::gather;
use crate::gltf::emit::{LocalPrimitive, LocalTangents, TangentsRef, Vertices};
use crate::gltf::error::{GltfError, Warnings};
use crate::gltf::mesh::primitive_label;
use crate::gltf::primitive::ReadPrimitive;
use glam::{DMat3, DMat4, Vec3, Vec4};
use gltf::json;
use json::mesh::Semantic;
use json::validation::Checked;
use std::sync::Arc;

/// One morph target's displacements (only those of attributes the primitive keeps).
#[derive(Clone, Debug, Default)]
struct Target {
    positions: Option<Arc<[Vec3]>>,
    normals: Option<Arc<[Vec3]>>,
    tangents: Option<Arc<[Vec3]>>,
}

/// One JOINTS_n / WEIGHTS_n pair: per vertex, four joints (indices into the skin's) and weights.
#[derive(Clone, Debug)]
struct Influences {
    joints: Arc<[[u32; 4]]>,
    weights: Arc<[[f32; 4]]>,
}

/// A primitive that deforms, with what deforms it.
#[derive(Clone, Debug)]
pub(crate) struct Deformable {
    pub base: LocalPrimitive,
    targets: Vec<Target>,
    influences: Vec<Influences>,
}

/// A deformed primitive's vertices (the triangles and texture coordinates are the base's).
pub(crate) struct Posed {
    positions: Vec<Vec3>,
    normals: Option<Vec<Vec3>>,
    tangents: Option<PosedTangents>,
}

enum PosedTangents {
    Vertex(Vec<Vec4>),
    Corner(Vec<[Vec4; 3]>),
}

impl Deformable {
    /// Reads primitive `read` of mesh `mesh`'s morph targets and, for a skin (its label and
    /// number of joints), its joints and weights.
    pub fn read(
        acc: &Accessors<'_, '_>,
        mesh: usize,
        read: ReadPrimitive,
        skin: Option<(&str, usize)>,
        warnings: &mut Warnings,
    ) -> Result<Deformable, GltfError> {
        let root = acc.root();
        let base = read.local;
        let plabel = primitive_label(root, mesh, base.primitive);
        let mut out = Deformable {
            base,
            targets: Vec::new(),
            influences: Vec::new(),
        };
        let Some(prim) = root
            .meshes
            .get(mesh)
            .and_then(|m| m.primitives.get(out.base.primitive))
        else {
            return Ok(out);
        };
        let targets = prim.targets.as_deref().unwrap_or(&[]);
        let first = root
            .meshes
            .get(mesh)
            .and_then(|m| m.primitives.first())
            .and_then(|p| p.targets.as_ref())
            .map_or(0, Vec::len);
        if targets.len() != first {
            return Err(AnimationError::TargetCount {
                mesh: crate::gltf::mesh::mesh_label(root, mesh),
                primitive: out.base.primitive,
                got: targets.len(),
                expected: first,
            }
            .into());
        }
        let skinned = skin.is_some()
            && prim
                .attributes
                .contains_key(&Checked::Valid(Semantic::Joints(0)));
        if read.draco && (!targets.is_empty() || skinned) {
            warnings.once(format!(
                "{plabel}: a KHR_draco_mesh_compression primitive is not deformed (morph targets \
                 and skins are ignored)"
            ));
            return Ok(out);
        }
        let kept = read.kept.as_deref();
        let n = read.vertices;
        let count = |attribute: String, got: usize| -> Result<(), GltfError> {
            if got == n {
                Ok(())
            } else {
                Err(AnimationError::VertexCount {
                    primitive: plabel.clone(),
                    attribute,
                    got,
                    vertices: n,
                }
                .into())
            }
        };
        let vec3 = |index: usize, attribute: String| -> Result<Arc<[Vec3]>, GltfError> {
            let v = acc.vec3(index, &format!("{attribute} of {plabel}"))?;
            count(attribute, v.len())?;
            Ok(match kept {
                Some(k) => gather(&v, k).as_ref().into(),
                None => v.as_ref().into(),
            })
        };
        for (t, target) in targets.iter().enumerate() {
            let mut d = Target::default();
            if let Some(i) = target.positions {
                d.positions = Some(vec3(i.value(), format!("morph target {t} POSITION"))?);
            }
            if let (Some(i), true) = (target.normals, out.base.normals.is_some()) {
                d.normals = Some(vec3(i.value(), format!("morph target {t} NORMAL"))?);
            }
            if let (Some(i), Some(LocalTangents::Vertex(_))) = (target.tangents, &out.base.tangents)
            {
                d.tangents = Some(vec3(i.value(), format!("morph target {t} TANGENT"))?);
            }
            out.targets.push(d);
        }
        let Some((skin, joint_count)) = skin else {
            return Ok(out);
        };
        for set in 0u32.. {
            let attr = |s: Semantic| prim.attributes.get(&Checked::Valid(s)).map(|i| i.value());
            let (Some(j), Some(w)) = (attr(Semantic::Joints(set)), attr(Semantic::Weights(set)))
            else {
                break;
            };
            let (jname, wname) = (format!("JOINTS_{set}"), format!("WEIGHTS_{set}"));
            let js = acc.vec4(j, &format!("{jname} of {plabel}"))?;
            count(jname.clone(), js.len())?;
            let ws = acc.vec4(w, &format!("{wname} of {plabel}"))?;
            count(wname, ws.len())?;
            let mut joints = Vec::with_capacity(js.len());
            for (vertex, (jv, wv)) in js.iter().zip(ws.iter()).enumerate() {
                let mut four = [0u32; 4];
                for c in 0..4 {
                    let joint = jv[c];
                    let usable =
                        joint >= 0.0 && joint.fract() == 0.0 && (joint as usize) < joint_count;
                    if usable {
                        four[c] = joint as u32;
                    } else if wv[c] != 0.0 {
                        return Err(AnimationError::JointIndex {
                            primitive: plabel.clone(),
                            skin: skin.to_string(),
                            attribute: jname.clone(),
                            vertex,
                            joint,
                            joints: joint_count,
                        }
                        .into());
                    }
                }
                joints.push(four);
            }
            let weights: Vec<[f32; 4]> = ws.iter().map(|w| w.to_array()).collect();
            out.influences.push(match kept {
                Some(k) => Influences {
                    joints: gather(&joints, k).as_ref().into(),
                    weights: gather(&weights, k).as_ref().into(),
                },
                None => Influences {
                    joints: joints.into(),
                    weights: weights.into(),
                },
            });
        }
        Ok(out)
    }

    /// The vertices morphed by `weights` and, given joint matrices, skinned into world space
    /// (vertices whose influences weigh nothing placed by `node_world`).
    pub fn pose(&self, weights: &[f32], joints: Option<&[DMat4]>, node_world: &DMat4) -> Posed {
        let b = &self.base;
        let mut positions = b.positions.to_vec();
        let mut normals = b.normals.as_deref().map(<[Vec3]>::to_vec);
        let mut tangents = b.tangents.as_ref().map(|t| match t {
            LocalTangents::Vertex(v) => PosedTangents::Vertex(v.to_vec()),
            LocalTangents::Corner(c) => PosedTangents::Corner(c.to_vec()),
        });
        for (t, &w) in self.targets.iter().zip(weights) {
            if w == 0.0 {
                continue;
            }
            add(&mut positions, t.positions.as_deref(), w);
            if let Some(n) = &mut normals {
                add(n, t.normals.as_deref(), w);
            }
            if let (Some(PosedTangents::Vertex(v)), Some(d)) = (&mut tangents, &t.tangents) {
                for (v, d) in v.iter_mut().zip(d.iter()) {
                    *v = (v.truncate() + w * *d).extend(v.w);
                }
            }
        }
        let Some(joints) = joints else {
            return Posed {
                positions,
                normals,
                tangents,
            };
        };
        // Per vertex: the blended joint matrix.
        let skin: Vec<DMat4> = (0..positions.len())
            .map(|v| {
                let mut m = DMat4::ZERO;
                let mut total = 0.0;
                for set in &self.influences {
                    for c in 0..4 {
                        let w = set.weights[v][c];
                        if w != 0.0 {
                            m += joints[set.joints[v][c] as usize] * w as f64;
                            total += w as f64;
                        }
                    }
                }
                if total == 0.0 {
                    *node_world
                } else {
                    m
                }
            })
            .collect();
        for (p, m) in positions.iter_mut().zip(&skin) {
            *p = m.transform_point3(p.as_dvec3()).as_vec3();
        }
        if let Some(normals) = &mut normals {
            for (n, m) in normals.iter_mut().zip(&skin) {
                *n = (normal_matrix(m) * n.as_dvec3())
                    .normalize_or_zero()
                    .as_vec3();
            }
        }
        let tangent = |t: Vec4, m: &DMat4| {
            let xyz = (DMat3::from_mat4(*m) * t.truncate().as_dvec3())
                .normalize_or_zero()
                .as_vec3();
            xyz.extend(t.w)
        };
        match &mut tangents {
            Some(PosedTangents::Vertex(v)) => {
                for (t, m) in v.iter_mut().zip(&skin) {
                    *t = tangent(*t, m);
                }
            }
            Some(PosedTangents::Corner(c)) => {
                for (corners, tri) in c.iter_mut().zip(b.triangles.iter()) {
                    for (t, &v) in corners.iter_mut().zip(tri) {
                        *t = tangent(*t, &skin[v as usize]);
                    }
                }
            }
            None => {}
        }
        Posed {
            positions,
            normals,
            tangents,
        }
    }
}

fn add(v: &mut [Vec3], d: Option<&[Vec3]>, w: f32) {
    if let Some(d) = d {
        for (v, d) in v.iter_mut().zip(d) {
            *v += w * *d;
        }
    }
}

/// The inverse transpose of `m`'s linear part up to a positive factor (its cofactor matrix times
/// the sign of its determinant).
fn normal_matrix(m: &DMat4) -> DMat3 {
    let m3 = DMat3::from_mat4(*m);
    let sign = if m3.determinant() < 0.0 { -1.0 } else { 1.0 };
    let (c0, c1, c2) = (m3.x_axis, m3.y_axis, m3.z_axis);
    DMat3::from_cols(c1.cross(c2), c2.cross(c0), c0.cross(c1)) * sign
}

impl Posed {
    /// The posed primitive as `emit` takes it (the base's triangles and texture coordinates).
    pub fn vertices<'a>(&'a self, base: &'a LocalPrimitive) -> Vertices<'a> {
        Vertices {
            primitive: base.primitive,
            triangles: &base.triangles,
            positions: &self.positions,
            normals: self.normals.as_deref(),
            uv: [base.uv[0].as_deref(), base.uv[1].as_deref()],
            tangents: self.tangents.as_ref().map(|t| match t {
                PosedTangents::Vertex(v) => TangentsRef::Vertex(v),
                PosedTangents::Corner(c) => TangentsRef::Corner(c),
            }),
        }
    }
}
