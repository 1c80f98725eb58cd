//! The steps of a load that the still loader (`load_parts`) and the animated one
//! (`animated::load`) share, up to the geometry: the scene's nodes, the triangle budget checked
//! from the JSON before any geometry is read, which meshes are kept instanced, and the materials
//! and textures with the optional per-triangle arrays they need.

use super::animated::Motion;
use super::error::{GltfError, Warnings};
use super::mesh::{self, Needs, PrimitiveMaterial};
use super::resources::Resources;
use super::textures::TextureCache;
use super::{document, gpu_instancing, instancing, materials, nodes, LoadOptions, MAX_TRIANGLES};
use crate::material::Material;
use gltf::json;
use std::collections::{BTreeSet, HashMap};

/// What the JSON alone says about the scene.
pub(crate) struct Scan {
    /// The scene's nodes in depth-first pre-order, with their world transforms at rest.
    pub instances: Vec<nodes::Instance>,
    /// The meshes kept instanced (see `instancing`).
    pub instanced: BTreeSet<usize>,
    /// glTF materials the scene's primitives use, and whether some primitive has none.
    used_materials: BTreeSet<usize>,
    default_material: bool,
    any_normals: bool,
}

/// The mesh node `node` places, if any.
pub(crate) fn mesh_of(root: &json::Root, node: usize) -> Option<usize> {
    root.nodes.get(node).and_then(|n| n.mesh).map(|m| m.value())
}

/// The nodes of the scene to render, in depth-first pre-order, with their world transforms at
/// rest.
pub(crate) fn scene_nodes(
    root: &json::Root,
    warnings: &mut Warnings,
) -> Result<Vec<nodes::Instance>, GltfError> {
    let (roots, note) = nodes::scene_roots(root);
    if let Some(note) = note {
        warnings.once(note);
    }
    nodes::traverse(root, &roots)
}

/// The instancing decision for the scene's nodes `instances` (`motion` says which nodes move or
/// deform; the default for a still scene), the triangle budget and what the primitives use.
pub(crate) fn scan(
    root: &json::Root,
    instances: Vec<nodes::Instance>,
    options: &LoadOptions,
    motion: &Motion,
    warnings: &mut Warnings,
) -> Result<Scan, GltfError> {
    document::feature_warnings(root, &instances, motion.is_animated(), warnings);

    // What the geometry will cost, before any of it is read: a few bytes of JSON can place a
    // mesh ten thousand times. A mesh kept instanced is stored once; a flattened one per node.
    let instanced = instancing::instanced_meshes(root, &instances, motion)?;
    let limit = options.max_triangles.min(MAX_TRIANGLES as u64);
    let mut per_mesh = HashMap::new();
    let mut placed_instanced = BTreeSet::new();
    let mut declared = 0u64;
    for inst in &instances {
        let Some(m) = mesh_of(root, inst.node) else {
            continue;
        };
        let copies = if instanced.contains(&m) && !motion.deforms(inst.node) {
            u64::from(placed_instanced.insert(m))
        } else {
            gpu_instancing::placement_count(root, inst.node)?
        };
        let triangles = *per_mesh
            .entry(m)
            .or_insert_with(|| mesh::declared_triangles(root, m));
        declared = declared.saturating_add(copies.saturating_mul(triangles));
    }
    if declared > limit {
        return Err(GltfError::Limit(format!(
            "the scene declares {declared} triangles to store ({} mesh instances; {} instanced \
             meshes stored once), over the limit of {limit}",
            instances
                .iter()
                .filter(|i| mesh_of(root, i.node).is_some())
                .count(),
            instanced.len()
        )));
    }

    // What the scene's primitives use, from the JSON alone.
    let mut used_materials = BTreeSet::new();
    let mut default_material = false;
    let mut any_normals = false;
    let mut scanned = BTreeSet::new();
    for inst in &instances {
        let Some(m) = mesh_of(root, inst.node) else {
            continue;
        };
        if !scanned.insert(m) {
            continue;
        }
        for info in mesh::scan_mesh(root, m, motion.is_animated(), warnings) {
            match info.material {
                Some(i) => {
                    used_materials.insert(i);
                }
                None => default_material = true,
            }
            any_normals |= info.has_normals;
        }
    }
    Ok(Scan {
        instances,
        instanced,
        used_materials,
        default_material,
        any_normals,
    })
}

/// The scene's materials, converted, and what the mesh builder needs to know of them.
pub(crate) struct Materials<'r, 'a> {
    pub materials: Vec<Material>,
    map: HashMap<usize, PrimitiveMaterial>,
    default_index: u32,
    pub needs: Needs,
    pub textures: TextureCache<'r, 'a>,
}

impl<'r, 'a> Materials<'r, 'a> {
    /// Converts the materials `scan` found used (decoding their textures), then the default
    /// material if some primitive has none.
    pub fn convert(
        root: &'r json::Root,
        res: &'r Resources<'a>,
        scan: &Scan,
        warnings: &mut Warnings,
    ) -> Result<Self, GltfError> {
        let mut textures = TextureCache::new(root, res);
        let mut out: Vec<Material> = Vec::new();
        let mut map: HashMap<usize, PrimitiveMaterial> = HashMap::new();
        for &i in &scan.used_materials {
            let m = materials::convert(root, i, &mut textures, warnings)?;
            let normal_map_uv = m.tangent_space_map().map(|r| r.texcoord);
            map.insert(
                i,
                PrimitiveMaterial {
                    index: out.len() as u32,
                    normal_map_uv,
                },
            );
            out.push(m);
        }
        let default_index = out.len() as u32;
        if scan.default_material {
            out.push(Material::default());
        }
        let mut needs = Needs {
            normals: scan.any_normals,
            ..Needs::default()
        };
        for m in &out {
            for r in m.texture_refs() {
                needs.uv[(r.texcoord as usize).min(1)] = true;
            }
            needs.tangents |= m.tangent_space_map().is_some();
        }
        Ok(Materials {
            materials: out,
            map,
            default_index,
            needs,
            textures,
        })
    }

    /// The scene material of a primitive with glTF material `m` (`None`: the default material).
    pub fn of(&self, m: Option<usize>) -> PrimitiveMaterial {
        match m.and_then(|i| self.map.get(&i)) {
            Some(pm) => *pm,
            None => PrimitiveMaterial {
                index: self.default_index,
                normal_map_uv: None,
            },
        }
    }
}
