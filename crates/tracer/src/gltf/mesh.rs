//! Mesh primitives → world-space triangles, or (for a mesh the loader keeps instanced, see
//! `instancing`) object-space prototypes and their placements.
//!
//! Each mesh is read once (however many nodes instance it) into local vertex arrays and index
//! triples, validated (every index below the vertex count, every float finite), then emitted per
//! instance: positions by the node's world matrix, normals by its inverse transpose, tangents by the
//! matrix with the handedness sign flipped under a mirroring transform. A negative determinant swaps
//! two corners so counter-clockwise stays the front face. Degenerate triangles (zero area or
//! non-finite corners after the transform) are dropped and counted as they are emitted, so a file of
//! millions of them costs no memory per triangle beyond its own index data.
//!
//! Work is bounded by the distinct accessors and the triangles, not vertices × primitives ×
//! instances: accessors are decoded once however many primitives share them (see `accessors`), and
//! a primitive whose indices use only some of its accessor's vertices keeps only those (renumbered in
//! the order its triangles first use them; the triangles, their order and their values are the same),
//! so each instance transforms only the vertices its triangles use.
//!
//! Tangents: a primitive whose material has a normal map but no TANGENT attribute gets MikkTSpace
//! tangents (see `tangents`), computed once per primitive on its local (compacted) vertices when it
//! is read, then transformed per instance like a file's TANGENT. Where MikkTSpace is not computed
//! (a primitive over its limits, with a warning) or leaves a corner without a tangent, the triangle
//! gets a per-triangle tangent from its UVs (the standard dP/du, with the sign chosen so that
//! cross(N, T)·w points to decreasing v, "up" in the image, as glTF specifies).

use super::accessors::Accessors;
use super::bounds::{outside, Far};
use super::compact::{compact, gather};
use super::draco;
use super::error::{label, GltfError, Warnings};
use super::tangents::{self, Tangents};
use crate::geometry::{renderable, Mesh, Placement};
use glam::{DMat3, DMat4, Vec2, Vec3, Vec4};
use gltf::json;
use json::mesh::{Mode, Semantic};
use json::validation::Checked;
use std::collections::HashMap;
use std::rc::Rc;

/// The most triangles a scene may store (flattened instances count once per node; a mesh kept
/// instanced counts once).
pub const MAX_TRIANGLES: usize = 100_000_000;

pub(crate) fn mesh_label(root: &json::Root, mesh: usize) -> String {
    label(
        "mesh",
        mesh,
        root.meshes.get(mesh).and_then(|m| m.name.as_deref()),
    )
}

pub(crate) fn primitive_label(root: &json::Root, mesh: usize, primitive: usize) -> String {
    format!("{}, primitive {primitive}", mesh_label(root, mesh))
}

/// Which optional per-triangle arrays the scene stores.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Needs {
    pub normals: bool,
    pub uv: [bool; 2],
    pub tangents: bool,
}

/// A primitive's material as the mesh builder sees it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PrimitiveMaterial {
    /// Index into the scene's materials.
    pub index: u32,
    /// The UV set of the material's normal map, if it has one.
    pub normal_map_uv: Option<u8>,
}

/// A triangle primitive of a mesh, from the JSON alone (no data read).
#[derive(Clone, Debug)]
pub(crate) struct PrimitiveInfo {
    pub primitive: usize,
    /// glTF material index (`None`: the default material).
    pub material: Option<usize>,
    pub has_normals: bool,
}

/// The triangle primitives of mesh `mesh`; warns (once each) about what is skipped or ignored.
pub(crate) fn scan_mesh(
    root: &json::Root,
    mesh: usize,
    warnings: &mut Warnings,
) -> Vec<PrimitiveInfo> {
    let Some(m) = root.meshes.get(mesh) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for (i, p) in m.primitives.iter().enumerate() {
        match p.mode {
            Checked::Valid(Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) => {}
            Checked::Valid(_) => {
                warnings.once("points and lines primitives are not rendered; skipped");
                continue;
            }
            Checked::Invalid => {
                warnings.once(format!(
                    "{}: invalid mode; skipped",
                    primitive_label(root, mesh, i)
                ));
                continue;
            }
        }
        if p.targets.as_ref().is_some_and(|t| !t.is_empty()) {
            warnings.once("morph targets are not supported; the base geometry is used");
        }
        if p.attributes
            .contains_key(&Checked::Valid(Semantic::Colors(0)))
        {
            warnings.once("vertex colors (COLOR_0) are not supported; ignored");
        }
        out.push(PrimitiveInfo {
            primitive: i,
            material: p.material.map(|m| m.value()),
            has_normals: p
                .attributes
                .contains_key(&Checked::Valid(Semantic::Normals)),
        });
    }
    out
}

/// The triangles mesh `mesh` declares, from the JSON alone (accessor counts; no data read): what
/// reading it would cost, degenerate triangles included.
pub(crate) fn declared_triangles(root: &json::Root, mesh: usize) -> u64 {
    let Some(m) = root.meshes.get(mesh) else {
        return 0;
    };
    let count = |i: usize| root.accessors.get(i).map_or(0, |a| a.count.0);
    m.primitives
        .iter()
        .map(|p| {
            let n = match &p.indices {
                Some(i) => count(i.value()),
                None => p
                    .attributes
                    .get(&Checked::Valid(Semantic::Positions))
                    .map_or(0, |i| count(i.value())),
            };
            match p.mode {
                Checked::Valid(Mode::Triangles) => n / 3,
                Checked::Valid(Mode::TriangleStrip | Mode::TriangleFan) => n.saturating_sub(2),
                _ => 0,
            }
        })
        .fold(0u64, u64::saturating_add)
}

/// One primitive's local data: the vertices its triangles use (the decoded accessors themselves,
/// shared, when they use all of them).
#[derive(Debug)]
struct Primitive {
    info: PrimitiveInfo,
    /// Corners as indices into the arrays below.
    triangles: Vec<[u32; 3]>,
    positions: Rc<[Vec3]>,
    normals: Option<Rc<[Vec3]>>,
    uv: [Option<Rc<[Vec2]>>; 2],
    /// The file's TANGENT, or MikkTSpace's when the material has a normal map and the file none.
    tangents: Option<Tangents>,
}

/// Accumulates the scene's triangles.
pub(crate) struct MeshBuilder<'r, 'a> {
    acc: &'r Accessors<'r, 'a>,
    needs: Needs,
    mesh: Mesh,
    /// Triangles dropped as degenerate.
    dropped: usize,
    /// Vertices transformed so far (positions, counted once per vertex and instance).
    transformed: u64,
    /// The first kept triangle corner beyond ±`MAX_COORDINATE`, and where it came from.
    far: Option<Far>,
    /// Each mesh's primitives that have triangles.
    cache: HashMap<usize, Rc<Vec<Primitive>>>,
    /// Instanced meshes, in object space, with their object-space corner bounds.
    prototypes: Vec<(Mesh, Vec3, Vec3)>,
    /// glTF mesh → its prototype.
    prototype_of: HashMap<usize, u32>,
    placements: Vec<Placement>,
}

/// What the builder made.
pub(crate) struct Built {
    /// The world-space triangles.
    pub mesh: Mesh,
    /// Instanced meshes in object space, and where nodes place them.
    pub prototypes: Vec<Mesh>,
    pub placements: Vec<Placement>,
    /// Triangles dropped as degenerate.
    pub dropped: usize,
    /// The first corner (or instance box corner) beyond ±`MAX_COORDINATE`.
    pub far: Option<Far>,
}

impl<'r, 'a> MeshBuilder<'r, 'a> {
    pub fn new(acc: &'r Accessors<'r, 'a>, needs: Needs) -> Self {
        let mesh = empty_mesh(&needs);
        MeshBuilder {
            acc,
            needs,
            mesh,
            dropped: 0,
            transformed: 0,
            far: None,
            cache: HashMap::new(),
            prototypes: Vec::new(),
            prototype_of: HashMap::new(),
            placements: Vec::new(),
        }
    }

    /// Vertices transformed so far (one per vertex a primitive uses, per instance).
    #[cfg(test)]
    pub fn transformed(&self) -> u64 {
        self.transformed
    }

    /// The triangles, the prototypes and placements, how many triangles were dropped as
    /// degenerate, and the first kept corner beyond ±`MAX_COORDINATE` (with the node and primitive
    /// it came from).
    pub fn finish(self) -> Built {
        Built {
            mesh: self.mesh,
            prototypes: self.prototypes.into_iter().map(|(m, _, _)| m).collect(),
            placements: self.placements,
            dropped: self.dropped,
            far: self.far,
        }
    }

    /// Triangles stored so far (world-space and prototypes), with the dropped ones.
    fn stored(&self) -> usize {
        self.mesh.len() + self.dropped + self.prototypes.iter().map(|p| p.0.len()).sum::<usize>()
    }

    /// Places mesh `mesh` at node `node` (world transform `world`) as an instance of its prototype,
    /// made in object space on its first placement.
    pub fn add_placement(
        &mut self,
        node: usize,
        mesh: usize,
        world: &DMat4,
        material: &dyn Fn(Option<usize>) -> PrimitiveMaterial,
        warnings: &mut Warnings,
    ) -> Result<(), GltfError> {
        let prototype = match self.prototype_of.get(&mesh) {
            Some(&p) => p,
            None => {
                let index = self.prototypes.len() as u32;
                self.prototypes
                    .push((empty_mesh(&self.needs), Vec3::ZERO, Vec3::ZERO));
                self.prototype_of.insert(mesh, index);
                let prims = self.primitives(mesh, material, warnings)?;
                for p in prims.iter() {
                    self.check_limit(p)?;
                    let m = material(p.info.material);
                    self.emit(p, &DMat4::IDENTITY, m, node, mesh, Some(index), warnings);
                }
                let proto = &mut self.prototypes[index as usize];
                (proto.1, proto.2) = proto.0.bounds();
                index
            }
        };
        let (proto, lo, hi) = &self.prototypes[prototype as usize];
        if proto.is_empty() {
            return Ok(());
        }
        if self.far.is_none() {
            // The placed box's corners: what the top-level tree and the rays will see.
            for k in 0..8 {
                let pick = |bit: usize, a: f32, b: f32| if k & bit == 0 { a } else { b };
                let corner = Vec3::new(
                    pick(1, lo.x, hi.x),
                    pick(2, lo.y, hi.y),
                    pick(4, lo.z, hi.z),
                );
                let w = world.transform_point3(corner.as_dvec3()).as_vec3();
                if outside(w) || !w.is_finite() {
                    self.far = Some(Far {
                        node,
                        mesh,
                        primitive: 0,
                        corner: w,
                    });
                    break;
                }
            }
        }
        self.placements.push(Placement {
            prototype,
            to_world: *world,
        });
        Ok(())
    }

    fn check_limit(&self, p: &Primitive) -> Result<(), GltfError> {
        // Dropped triangles count too: reading them is the cost this limit bounds.
        let total = self.stored().saturating_add(p.triangles.len());
        if total > MAX_TRIANGLES {
            return Err(GltfError::Limit(format!(
                "the scene has more than {MAX_TRIANGLES} triangles (counting degenerate ones)"
            )));
        }
        Ok(())
    }

    /// Adds every triangle primitive of mesh `mesh` under the world transform `world` of node `node`.
    pub fn add_instance(
        &mut self,
        node: usize,
        mesh: usize,
        world: &DMat4,
        material: &dyn Fn(Option<usize>) -> PrimitiveMaterial,
        warnings: &mut Warnings,
    ) -> Result<(), GltfError> {
        let prims = self.primitives(mesh, material, warnings)?;
        for p in prims.iter() {
            self.check_limit(p)?;
            let m = material(p.info.material);
            self.emit(p, world, m, node, mesh, None, warnings);
        }
        Ok(())
    }

    /// Mesh `mesh`'s primitives with triangles, read on first use.
    fn primitives(
        &mut self,
        mesh: usize,
        material: &dyn Fn(Option<usize>) -> PrimitiveMaterial,
        warnings: &mut Warnings,
    ) -> Result<Rc<Vec<Primitive>>, GltfError> {
        Ok(match self.cache.get(&mesh) {
            Some(p) => p.clone(),
            None => {
                let mut scratch = Warnings::default();
                let infos = scan_mesh(self.acc.root(), mesh, &mut scratch);
                let mut prims = Vec::with_capacity(infos.len());
                for info in infos {
                    let m = material(info.material);
                    let p = self.read_primitive(mesh, info, m, warnings)?;
                    // One with no triangles costs nothing per instance.
                    if !p.triangles.is_empty() {
                        prims.push(p);
                    }
                }
                let prims = Rc::new(prims);
                self.cache.insert(mesh, prims.clone());
                prims
            }
        })
    }

    fn read_primitive(
        &self,
        mesh: usize,
        info: PrimitiveInfo,
        material: PrimitiveMaterial,
        warnings: &mut Warnings,
    ) -> Result<Primitive, GltfError> {
        let root = self.acc.root();
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
        let draco = draco::decode_primitive(self.acc, mesh, info.primitive, warnings)?;
        let positions = match &draco {
            Some(d) => d.positions.clone(),
            None => self.acc.vec3(pos_index, &format!("POSITION of {plabel}"))?,
        };
        let n = positions.len();
        let same_count = |index: usize, name: &str, got: usize| -> Result<(), GltfError> {
            if got == n {
                Ok(())
            } else {
                Err(GltfError::Data {
                    object: self.acc.label(index, &format!("{name} of {plabel}")),
                    reason: format!(
                        "has {got} elements but POSITION (accessor {pos_index}) has {n}"
                    ),
                })
            }
        };
        let mut normals = None;
        if let (true, Some(i)) = (self.needs.normals, attr(Semantic::Normals)) {
            normals = match &draco {
                Some(d) => d.normals.clone(),
                None => Some(self.acc.vec3(i, &format!("NORMAL of {plabel}"))?),
            };
            if let Some(v) = &normals {
                same_count(i, "NORMAL", v.len())?;
            }
        }
        let mut uv: [Option<Rc<[Vec2]>>; 2] = [None, None];
        for (set, slot) in uv.iter_mut().enumerate() {
            if let (true, Some(i)) = (self.needs.uv[set], attr(Semantic::TexCoords(set as u32))) {
                let name = format!("TEXCOORD_{set}");
                *slot = match &draco {
                    Some(d) => d.uv[set].clone(),
                    None => Some(self.acc.vec2(i, &format!("{name} of {plabel}"))?),
                };
                if let Some(v) = slot {
                    same_count(i, &name, v.len())?;
                }
            }
        }
        let mut tangents = None;
        if let (true, Some(i)) = (self.needs.tangents, attr(Semantic::Tangents)) {
            let v = match &draco {
                Some(d) => d.tangents.clone(),
                None => Some(self.acc.vec4(i, &format!("TANGENT of {plabel}"))?),
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
                let idx = self.acc.indices(i, &format!("indices of {plabel}"))?;
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
        if let Some(used) = compact(&mut triangles, n) {
            p.positions = gather(&p.positions, &used);
            p.normals = p.normals.map(|v| gather(&v, &used));
            p.uv = p.uv.map(|v| v.map(|v| gather(&v, &used)));
            p.tangents = p.tangents.map(|t| match t {
                Tangents::Vertex(v) => Tangents::Vertex(gather(&v, &used)),
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
        if let (true, None, Some(uv)) = (self.needs.tangents, &p.tangents, normal_map_uv) {
            match tangents::mikktspace(&triangles, &p.positions, p.normals.as_deref(), &uv) {
                Ok(t) => p.tangents = Some(t),
                Err(why) => warnings.once(format!(
                    "{plabel}: {why}; per-triangle tangents used for its normal map"
                )),
            }
        }
        p.triangles = triangles;
        Ok(p)
    }

    /// Emits primitive `p` under `world`: into the world-space mesh, or into prototype
    /// `prototype` (with `world` the identity).
    #[allow(clippy::too_many_arguments)]
    fn emit(
        &mut self,
        p: &Primitive,
        world: &DMat4,
        mat: PrimitiveMaterial,
        node: usize,
        mesh: usize,
        prototype: Option<u32>,
        warnings: &mut Warnings,
    ) {
        self.transformed += p.positions.len() as u64;
        let m3 = DMat3::from_mat4(*world);
        let det = m3.determinant();
        let flip = det < 0.0;
        let sign = if flip { -1.0 } else { 1.0 };
        // Cofactor matrix = det · M^{-T}; times sign(det) it is |det| · M^{-T}, defined even if singular.
        let (c0, c1, c2) = (m3.x_axis, m3.y_axis, m3.z_axis);
        let normal_matrix = DMat3::from_cols(c1.cross(c2), c2.cross(c0), c0.cross(c1)) * sign;
        let wp: Vec<Vec3> = p
            .positions
            .iter()
            .map(|v| world.transform_point3(v.as_dvec3()).as_vec3())
            .collect();
        let wn: Option<Vec<Vec3>> = p.normals.as_ref().map(|ns| {
            ns.iter()
                .map(|n| (normal_matrix * n.as_dvec3()).normalize_or_zero().as_vec3())
                .collect()
        });
        let tangent = |t: &Vec4| {
            let xyz = (m3 * t.truncate().as_dvec3()).normalize_or_zero().as_vec3();
            let w = if t.w < 0.0 { -1.0 } else { 1.0 } * sign as f32;
            xyz.extend(w)
        };
        // Per vertex, or per corner (MikkTSpace split some vertex); at most one is set.
        let (wt, wt_corners): (Option<Vec<Vec4>>, Option<Vec<[Vec4; 3]>>) = match &p.tangents {
            Some(Tangents::Vertex(ts)) => (Some(ts.iter().map(tangent).collect()), None),
            Some(Tangents::Corner(ts)) => (
                None,
                Some(ts.iter().map(|c| c.map(|t| tangent(&t))).collect()),
            ),
            None => (None, None),
        };
        let tangent_uv = mat
            .normal_map_uv
            .and_then(|s| p.uv.get(s as usize).and_then(|u| u.as_ref()));
        if self.needs.tangents
            && mat.normal_map_uv.is_some()
            && p.tangents.is_none()
            && tangent_uv.is_none()
        {
            warnings.once(format!(
                "{}: normal map without TANGENT or texture coordinates; normal map ignored",
                primitive_label(self.acc.root(), mesh, p.info.primitive)
            ));
        }
        for (k, t) in p.triangles.iter().enumerate() {
            // The corners in the order they are stored (two swapped under a mirroring transform).
            let order = if flip { [0, 2, 1] } else { [0, 1, 2] };
            let [a, b, c] = order.map(|i| t[i]);
            let [a, b, c] = [a as usize, b as usize, c as usize];
            let pos = [wp[a], wp[b], wp[c]];
            if !renderable(&pos) {
                self.dropped += 1;
                continue;
            }
            if self.far.is_none() {
                if let Some(&corner) = pos.iter().find(|v| outside(**v)) {
                    self.far = Some(Far {
                        node,
                        mesh,
                        primitive: p.info.primitive,
                        corner,
                    });
                }
            }
            let out = match prototype {
                Some(i) => &mut self.prototypes[i as usize].0,
                None => &mut self.mesh,
            };
            out.positions.push(pos);
            out.material.push(mat.index);
            let flat = (pos[1] - pos[0]).cross(pos[2] - pos[0]).normalize_or_zero();
            if let Some(normals) = &mut out.normals {
                let corner = |i: usize| match &wn {
                    Some(wn) if wn[i] != Vec3::ZERO => wn[i],
                    _ => flat,
                };
                normals.push([corner(a), corner(b), corner(c)]);
            }
            for (set, slot) in [&mut out.uv0, &mut out.uv1].into_iter().enumerate() {
                if let Some(out) = slot {
                    out.push(match &p.uv[set] {
                        Some(uv) => [uv[a], uv[b], uv[c]],
                        None => [Vec2::ZERO; 3],
                    });
                }
            }
            if let Some(out) = &mut out.tangents {
                out.push(match (&wt, &wt_corners, tangent_uv) {
                    (Some(wt), _, _) => [wt[a], wt[b], wt[c]],
                    (None, Some(wc), _) => order.map(|i| wc[k][i]),
                    (None, None, Some(uv)) => [generate_tangent(pos, [uv[a], uv[b], uv[c]]); 3],
                    (None, None, None) => [Vec4::ZERO; 3],
                });
            }
        }
    }
}

/// A mesh with the attribute arrays the scene needs, and no triangles.
fn empty_mesh(needs: &Needs) -> Mesh {
    Mesh {
        normals: needs.normals.then(Vec::new),
        uv0: needs.uv[0].then(Vec::new),
        uv1: needs.uv[1].then(Vec::new),
        tangents: needs.tangents.then(Vec::new),
        ..Mesh::default()
    }
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

/// A per-triangle tangent from positions and UVs: dP/du, with w such that cross(N, T)·w follows
/// −dP/dv (image "up"), N the geometric (front) normal.
pub(crate) fn generate_tangent(p: [Vec3; 3], uv: [Vec2; 3]) -> Vec4 {
    let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
    let (d1, d2) = (uv[1] - uv[0], uv[2] - uv[0]);
    let n = e1.cross(e2);
    let fallback = || {
        let n = n.normalize_or_zero();
        if n == Vec3::ZERO {
            Vec4::new(1.0, 0.0, 0.0, 1.0)
        } else {
            n.any_orthonormal_vector().extend(1.0)
        }
    };
    let det = d1.x * d2.y - d2.x * d1.y;
    if det == 0.0 || !det.is_finite() {
        return fallback();
    }
    let r = 1.0 / det;
    let dpdu = (e1 * d2.y - e2 * d1.y) * r;
    let dpdv = (e2 * d1.x - e1 * d2.x) * r;
    let t = dpdu.normalize_or_zero();
    if t == Vec3::ZERO || !t.is_finite() {
        return fallback();
    }
    let w = if n.cross(t).dot(-dpdv) < 0.0 {
        -1.0
    } else {
        1.0
    };
    t.extend(w)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tangent_follows_u_and_image_up() {
        // Triangle in the XY plane facing +Z; u along +X, v = 1 − y (image top at y = 1).
        let p = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let uv = [
            Vec2::new(0.0, 1.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(0.0, 0.0),
        ];
        let t = generate_tangent(p, uv);
        assert!(
            (t.truncate() - Vec3::X).length() < 1e-6 && t.w == 1.0,
            "{t}"
        );
        // Mirrored UVs (v = y) flip the handedness.
        let uv = [
            Vec2::new(0.0, 0.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(0.0, 1.0),
        ];
        assert_eq!(generate_tangent(p, uv).w, -1.0);
        // Degenerate UVs fall back to some unit tangent.
        let t = generate_tangent(p, [Vec2::ZERO; 3]);
        assert!((t.truncate().length() - 1.0).abs() < 1e-6);
    }

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
