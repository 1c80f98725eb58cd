//! Mesh primitives → world-space triangles, or (for a mesh the loader keeps instanced, see
//! `instancing`) object-space prototypes and their placements.
//!
//! Each mesh is read once (however many nodes instance it) into local vertex arrays and index
//! triples (`primitive`: validated, every index below the vertex count, every float finite), then
//! emitted per instance (`emit`): positions by the node's world matrix, normals by its inverse
//! transpose, tangents by the matrix with the handedness sign flipped under a mirroring transform.
//! A negative determinant swaps two corners so counter-clockwise stays the front face. Degenerate
//! triangles (zero area or non-finite corners after the transform) are dropped and counted as they
//! are emitted, so a file of millions of them costs no memory per triangle beyond its own index
//! data.
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
//!
//! An animated scene (`animated`) asks for the primitives of the meshes it emits again at every
//! frame as owned copies (`local_primitives`), and adds the deformations nothing animates to the
//! world-space triangles once (`add_vertices`).

use super::accessors::Accessors;
use super::bounds::{outside, Far};
use super::emit::{emit, Emitted, Origin, Vertices};
use super::error::{label, GltfError, Warnings};
use super::primitive::{read_primitive, Primitive, ReadPrimitive};
use crate::geometry::{Mesh, Placement};
use glam::{DMat4, Vec3};
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
    animated: bool,
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
        if !animated && p.targets.as_ref().is_some_and(|t| !t.is_empty()) {
            warnings.once(
                "morph targets are applied only in animated scenes rendered at a time; the base \
                 geometry is used",
            );
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
    ) -> Result<bool, GltfError> {
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
            return Ok(false);
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
        Ok(true)
    }

    /// The prototype mesh `mesh` was made into, if it was placed.
    pub fn prototype_of(&self, mesh: usize) -> Option<u32> {
        self.prototype_of.get(&mesh).copied()
    }

    /// Adds the triangles of `v` (a primitive of mesh `mesh`, deformed by an animated scene) under
    /// `world` to the world-space mesh, for node `node`.
    pub fn add_vertices(
        &mut self,
        node: usize,
        mesh: usize,
        v: &Vertices<'_>,
        world: &DMat4,
        mat: PrimitiveMaterial,
    ) {
        self.transformed += v.positions.len() as u64;
        let done = emit(
            &mut self.mesh,
            v,
            world,
            mat,
            Origin { node, mesh },
            self.far.is_none(),
        );
        self.count(done);
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
                // Its warnings were given by the scan of the whole scene (`prepare::scan`).
                let infos = scan_mesh(self.acc.root(), mesh, true, &mut scratch);
                let mut prims = Vec::with_capacity(infos.len());
                for info in infos {
                    let m = material(info.material);
                    let (p, _) = read_primitive(self.acc, self.needs, mesh, info, m, warnings)?;
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

    /// Mesh `mesh`'s primitives with triangles, read again (through the accessor cache) as owned
    /// copies, with what [`ReadPrimitive`] tells of each: for the meshes an animated scene emits
    /// again at every frame.
    pub fn local_primitives(
        &mut self,
        mesh: usize,
        material: &dyn Fn(Option<usize>) -> PrimitiveMaterial,
        warnings: &mut Warnings,
    ) -> Result<Vec<ReadPrimitive>, GltfError> {
        let mut scratch = Warnings::default();
        // Its warnings were given by the scan of the whole scene (`prepare::scan`).
        let infos = scan_mesh(self.acc.root(), mesh, true, &mut scratch);
        let mut out = Vec::with_capacity(infos.len());
        for info in infos {
            let m = material(info.material);
            let (p, kept) = read_primitive(self.acc, self.needs, mesh, info, m, warnings)?;
            if !p.triangles.is_empty() {
                self.check_limit(&p)?;
                out.push(ReadPrimitive {
                    local: p.to_local(m),
                    kept: kept.kept,
                    vertices: kept.vertices,
                    draco: kept.draco,
                });
            }
        }
        Ok(out)
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
        let out = match prototype {
            Some(i) => &mut self.prototypes[i as usize].0,
            None => &mut self.mesh,
        };
        let done = emit(
            out,
            &p.vertices(),
            world,
            mat,
            Origin { node, mesh },
            self.far.is_none(),
        );
        self.count(done);
    }

    /// Counts what `emit` dropped, and keeps the first far triangle it found.
    fn count(&mut self, done: Emitted) {
        self.dropped += done.dropped;
        if self.far.is_none() {
            self.far = done.far;
        }
    }
}

/// A mesh with the attribute arrays the scene needs, and no triangles.
pub(crate) fn empty_mesh(needs: &Needs) -> Mesh {
    Mesh {
        normals: needs.normals.then(Vec::new),
        uv0: needs.uv[0].then(Vec::new),
        uv1: needs.uv[1].then(Vec::new),
        tangents: needs.tangents.then(Vec::new),
        ..Mesh::default()
    }
}
