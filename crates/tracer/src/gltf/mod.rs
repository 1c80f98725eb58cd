//! glTF 2.0 loading: `.gltf` (JSON, with embedded `data:` URIs or external files fetched through a
//! [`ResourceResolver`]) and `.glb`, into [`SceneParts`] or a built [`Scene`].
//!
//! The tracer does no I/O: external URIs (percent-decoded, relative to the scene file as written) are
//! handed to the caller's resolver, which decides what may be read ([`NoExternalResources`] refuses
//! everything, for servers that accept self-contained scenes only).
//!
//! # What is loaded
//! - The default scene (`scene`, else the first; with no scenes, every root node), its node hierarchy
//!   with TRS or matrix transforms composed parent → child. A node mirrored by its world transform
//!   (negative determinant) has two corners of each triangle swapped so counter-clockwise stays the
//!   front face; normals go through the inverse transpose.
//! - Primitives of mode TRIANGLES, TRIANGLE_STRIP and TRIANGLE_FAN (strips and fans are converted);
//!   POINTS and LINES are skipped with a warning. Indexed or not; u8/u16/u32 indices. POSITION
//!   (required), NORMAL, TEXCOORD_0/1 (float or normalized integers), TANGENT. Sparse accessors.
//!   Integer attributes of KHR_mesh_quantization (normalized or not, on every attribute).
//! - Compressed geometry: buffer views of EXT_meshopt_compression and KHR_meshopt_compression (all
//!   modes and filters; decoded once each, the fallback buffer never read) and primitives of
//!   KHR_draco_mesh_compression (attributes by the extension's ids; with uncompressed accessors and
//!   the extension not required, a stream that fails to decode falls back to them with a warning).
//!   Pure-Rust decoders (`meshoptimizer-rs`, `draco-core`); what they produce counts against
//!   [`MAX_DECOMPRESSED_BYTES`], checked before each decode allocates.
//! - Per-triangle arrays are stored only when used: normals when some primitive has NORMAL (the others
//!   get their flat normal), a UV set when some material's texture reads it, tangents when some material
//!   has a normal map. Primitives whose material has a normal map and that have no TANGENT get
//!   MikkTSpace tangents, as glTF asks and as the exporters that bake normal maps compute them
//!   (`tangents.rs`: `bevy_mikktspace` with a deterministic `acos`, once per primitive on its local
//!   vertices, then transformed per instance like a TANGENT; handedness making cross(N, T)·w point
//!   to decreasing v, "up" in the image, as glTF specifies). A primitive past MikkTSpace's limits
//!   (over 2 million triangles, or a point shared by thousands of corners: see `tangents.rs`) gets
//!   per-triangle tangents from its UVs (dP/du) instead, with a warning naming it.
//! - Materials: metallic-roughness, emissive × KHR_materials_emissive_strength, normal map, alpha
//!   mode, double-sidedness, KHR_materials_specular, _ior, _transmission, _volume, _clearcoat (with
//!   its own normal map) and _sheen, and KHR_texture_transform on every texture reference. Primitives without a material get
//!   `Material::default()`, added once after the file's (used) materials.
//! - Textures: PNG and JPEG, and WebP (lossy and lossless) through EXT_texture_webp, decoded once per
//!   image with limits ([`MAX_IMAGE_SIZE`], [`MAX_IMAGE_BYTES`], [`MAX_SCENE_TEXTURE_BYTES`]), checked
//!   from the image's header before decoding; a WebP that fails falls back to the texture's PNG/JPEG
//!   `source` with a warning unless EXT_texture_webp is required. Sampler wrap modes and NEAREST
//!   magnification.
//! - KHR_lights_punctual point, spot and directional lights, their candela and lux converted to W/sr
//!   and W/m² at 683 lm/W ([`LUMENS_PER_WATT`]; see `lights.rs`).
//! - The camera: the first camera node in traversal order, or the one named by [`LoadOptions::camera`];
//!   its node's scale is stripped.
//!
//! The `gltf` crate parses and validates the JSON (`gltf::Document::from_json`, what
//! `gltf::Gltf::from_slice` does); the GLB container is split here first so that lying lengths give
//! clear errors, and `extensionsRequired` is checked here (the crate refuses some extensions this
//! loader supports). All data is then read through bounds-checked code of this module rather than the
//! crate's readers, which may panic on inconsistent files.
//!
//! # What is refused or ignored
//! - `extensionsRequired` naming anything outside [`SUPPORTED_EXTENSIONS`] is an error.
//! - Triangles reaching beyond ±[`MAX_COORDINATE`] in world space are an error (the BVH's `f32`
//!   surface-area arithmetic would overflow).
//! - Vertex accessors are decoded once each, however many primitives share them; distinct accessors
//!   that together read more than 4 × the bytes of the buffers + 64 MiB (many accessors over the
//!   same data) are an error naming the accessor and primitive. Each instance transforms only the
//!   vertices its triangles use. The loader's warnings stop after the first 100 distinct ones, with
//!   one "… and N more warnings" for the rest.
//! - Ignored with one warning each (in `SceneParts::warnings` and through `tracing::warn!`):
//!   unsupported `extensionsUsed` (e.g. KHR_materials_iridescence, _unlit, KHR_texture_basisu
//!   as optional), COLOR_0, light `range`, TEXCOORD_2+ (TEXCOORD_1 is used); and by [`load`] and
//!   [`load_parts`], which render a file at rest, skins (bind pose), morph targets (base geometry)
//!   and animations. Occlusion textures, camera aspect ratio and clip planes, and texture min
//!   filters are ignored silently.
//!
//! # Animation
//! [`SceneSource`] loads a file for rendering at any time: a still file exactly as [`load`] does,
//! an animated one as an [`AnimatedScene`] (node translation, rotation and scale, morph weights,
//! skins; LINEAR, STEP and CUBICSPLINE; all animations at once), parsed once, whose
//! [`AnimatedScene::scene_at`] builds the scene at a time and shares what does not move between
//! frames. See `animated/mod.rs`.
//!
//! # Robustness
//! Every length, offset, index and count in the file is checked before use, and every error names the
//! object at fault (`mesh 3 "Chair", primitive 0: index 812 out of range (accessor 5 has 400
//! vertices)`). The load never panics on any input; as a last line of defence a panic is caught and
//! returned as [`GltfError::Internal`].

mod accessors;
mod animated;
mod bounds;
mod camera;
mod compact;
mod components;
mod document;
mod draco;
mod emit;
mod error;
mod glb;
mod gpu_instancing;
mod instancing;
mod lights;
mod materials;
mod mesh;
mod meshopt;
mod nodes;
mod prepare;
mod primitive;
mod resources;
mod tangents;
mod textures;

pub use animated::{
    frame_time, AnimatedScene, AnimationError, NodeTrs, SceneSource, TimeSpan, DEFAULT_FPS,
};
pub use bounds::MAX_COORDINATE;
pub use document::SUPPORTED_EXTENSIONS;
pub use error::GltfError;
pub use glb::encode as encode_glb;
pub use lights::LUMENS_PER_WATT;
pub use materials::texture_transform_matrix;
pub use mesh::MAX_TRIANGLES;
pub use resources::MAX_DECOMPRESSED_BYTES;
pub use textures::{MAX_IMAGE_BYTES, MAX_IMAGE_SIZE, MAX_SCENE_TEXTURE_BYTES};

use crate::scene::{Scene, SceneParts};
use accessors::Accessors;
use animated::Motion;
use error::Warnings;
use mesh::MeshBuilder;
use resources::Resources;
use std::panic::{catch_unwind, AssertUnwindSafe};

/// Fetches the bytes of an external URI (relative to the scene file). The tracer does no I/O itself.
///
/// `uri` is the glTF URI percent-decoded (`"my%20file.bin"` arrives as `"my file.bin"`); `data:` URIs
/// never reach the resolver. Refusing absolute paths, `..` or URL schemes is the resolver's job.
pub trait ResourceResolver {
    fn resolve(&self, uri: &str) -> Result<Vec<u8>, String>;
}

/// A resolver that refuses every external URI (the server uses it; only data: URIs and GLB chunks work).
#[derive(Clone, Copy, Debug, Default)]
pub struct NoExternalResources;

impl ResourceResolver for NoExternalResources {
    fn resolve(&self, _uri: &str) -> Result<Vec<u8>, String> {
        Err(
            "external resources are not allowed (embed them as data: URIs or use a .glb)"
                .to_string(),
        )
    }
}

/// Choices made while loading.
#[derive(Clone, Debug)]
pub struct LoadOptions {
    /// Camera name (a camera's name, else the name of a node carrying a camera); default: the first
    /// camera of the scene's nodes in traversal order.
    pub camera: Option<String>,
    /// Most triangles the scene may declare, counting every instance and degenerate triangles,
    /// checked from the JSON before any geometry is read (default and ceiling: [`MAX_TRIANGLES`]).
    /// The server lowers it for submissions (`--max-scene-triangles`), since the triangles a scene
    /// holds are the memory loading it takes.
    pub max_triangles: u64,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions {
            camera: None,
            max_triangles: MAX_TRIANGLES as u64,
        }
    }
}

/// Loads a glTF or GLB file into the parts of a scene (not yet built).
pub fn load_parts(
    bytes: &[u8],
    resolver: &dyn ResourceResolver,
    options: &LoadOptions,
) -> Result<SceneParts, GltfError> {
    guarded(|| load_parts_unguarded(bytes, resolver, options))
}

/// Loads a glTF or GLB file and builds the scene ([`load_parts`] + [`Scene::build`]).
pub fn load(
    bytes: &[u8],
    resolver: &dyn ResourceResolver,
    options: &LoadOptions,
) -> Result<Scene, GltfError> {
    let parts = load_parts(bytes, resolver, options)?;
    guarded(|| Ok(Scene::build(parts)?))
}

/// Whether [`load`] of these bytes succeeds, without building the scene (no BVH, no light
/// distributions: see [`Scene::check`]); the load's warnings when it does. What a server checks a
/// submitted scene with, at a fraction of the build's time and memory.
pub fn check(
    bytes: &[u8],
    resolver: &dyn ResourceResolver,
    options: &LoadOptions,
) -> Result<Vec<String>, GltfError> {
    let parts = load_parts(bytes, resolver, options)?;
    guarded(|| Ok(Scene::check(parts)?))
}

fn guarded<T>(f: impl FnOnce() -> Result<T, GltfError>) -> Result<T, GltfError> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(result) => result,
        Err(payload) => {
            let message = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "panic".to_string());
            Err(GltfError::Internal(message))
        }
    }
}

fn load_parts_unguarded(
    bytes: &[u8],
    resolver: &dyn ResourceResolver,
    options: &LoadOptions,
) -> Result<SceneParts, GltfError> {
    load_parsed(document::parse(bytes)?, resolver, options)
}

/// The still load of a parsed document.
fn load_parsed(
    parsed: document::Parsed<'_>,
    resolver: &dyn ResourceResolver,
    options: &LoadOptions,
) -> Result<SceneParts, GltfError> {
    let root = &parsed.root;
    let mut warnings = Warnings::default();
    for w in parsed.warnings {
        warnings.once(w);
    }
    let instances = prepare::scene_nodes(root, &mut warnings)?;
    let scan = prepare::scan(root, instances, options, &Motion::default(), &mut warnings)?;
    let instances = &scan.instances;
    let res = Resources::new(root, parsed.bin, resolver);
    let mats = prepare::Materials::convert(root, &res, &scan, &mut warnings)?;
    let acc = Accessors::new(root, &res);
    let mut builder = MeshBuilder::new(&acc, mats.needs);
    let material_of = |m: Option<usize>| mats.of(m);
    let mut punctual_lights = Vec::new();
    for inst in instances {
        if let Some(m) = prepare::mesh_of(root, inst.node) {
            for world in gpu_instancing::placements(&acc, inst.node, &inst.world)? {
                if scan.instanced.contains(&m) {
                    builder.add_placement(inst.node, m, &world, &material_of, &mut warnings)?;
                } else {
                    builder.add_instance(inst.node, m, &world, &material_of, &mut warnings)?;
                }
            }
        }
        if let Some(light) = lights::node_light(root, inst.node, &inst.world, &mut warnings)? {
            punctual_lights.push(light);
        }
    }
    #[cfg(test)]
    tests::LAST_WORK.set(Work {
        decoded: acc.decoded(),
        transformed: builder.transformed(),
    });
    let built = builder.finish();
    bounds::check(root, built.far)?;
    let camera = camera::choose(root, instances, options.camera.as_deref())?;
    Ok(SceneParts {
        mesh: built.mesh,
        prototypes: built.prototypes,
        placements: built.placements,
        materials: mats.materials,
        textures: mats.textures.finish(),
        punctual_lights,
        camera,
        warnings: warnings.into_vec(),
        degenerate_dropped: built.dropped,
    })
}

/// What a load did, for tests: elements decoded and vertices transformed.
#[cfg(test)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Work {
    decoded: u64,
    transformed: u64,
}

#[cfg(test)]
mod tests {
    use super::*;
    use base64::Engine as _;
    use std::cell::Cell;

    thread_local! {
        /// The work of the last load on this thread that got as far as building its mesh.
        pub(super) static LAST_WORK: Cell<Work> = const { Cell::new(Work { decoded: 0, transformed: 0 }) };
    }

    /// `n` positions (the first three a unit right triangle) and the u16 indices [0, 1, 2], then a
    /// document from `rest` (accessors 0 = POSITION, 1 = indices; `rest` adds meshes, nodes, scenes
    /// and maybe more accessors over bufferView 0).
    fn doc(n: usize, extra_accessors: &str, rest: &str) -> Vec<u8> {
        let extra_accessors = extra_accessors.replace("MINMAX", MINMAX);
        let mut buf = Vec::new();
        for i in 0..n {
            let p = match i {
                0 => [0.0, 0.0, 0.0],
                1 => [1.0, 0.0, 0.0],
                2 => [0.0, 1.0, 0.0],
                _ => [i as f32, 1.0, 2.0],
            };
            for v in p {
                buf.extend(f32::to_le_bytes(v));
            }
        }
        let pos_len = buf.len();
        for i in [0u16, 1, 2, 0] {
            buf.extend(i.to_le_bytes());
        }
        let uri = base64::engine::general_purpose::STANDARD.encode(&buf);
        format!(
            r#"{{"asset":{{"version":"2.0"}},
            "buffers":[{{"byteLength":{},"uri":"data:application/octet-stream;base64,{uri}"}}],
            "bufferViews":[{{"buffer":0,"byteLength":{pos_len}}},
                {{"buffer":0,"byteOffset":{pos_len},"byteLength":6}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":{n},"type":"VEC3",{MINMAX}}},
                {{"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"}}{extra_accessors}],
            {rest}}}"#,
            buf.len()
        )
        .into_bytes()
    }

    /// The min and max every POSITION accessor must have (for `n` ≥ 4 positions as `doc` makes).
    const MINMAX: &str = r#""min":[0,0,0],"max":[1e6,1,2]"#;

    fn load_with_work(bytes: &[u8]) -> (SceneParts, Work) {
        LAST_WORK.set(Work::default());
        let parts = load_parts(bytes, &NoExternalResources, &LoadOptions::default())
            .unwrap_or_else(|e| panic!("{e}"));
        (parts, LAST_WORK.get())
    }

    fn list(n: usize, item: impl Fn(usize) -> String) -> String {
        (0..n).map(item).collect::<Vec<_>>().join(",")
    }

    #[test]
    fn primitives_sharing_accessors_decode_them_once() {
        // 2,000 primitives over one POSITION accessor of 20,000 vertices and one index accessor of
        // one triangle: each was decoded (and transformed) in full for every primitive, 40 million
        // vertices; now once, and three transformed per primitive.
        let (n, prims) = (20_000, 2_000);
        let primitives = list(prims, |_| {
            r#"{"attributes":{"POSITION":0},"indices":1}"#.into()
        });
        let bytes = doc(
            n,
            "",
            &format!(
                r#""meshes":[{{"primitives":[{primitives}]}}],"nodes":[{{"mesh":0}}],
                "scenes":[{{"nodes":[0]}}]"#
            ),
        );
        let (parts, work) = load_with_work(&bytes);
        assert_eq!(parts.mesh.len(), prims);
        assert!(parts
            .mesh
            .positions
            .iter()
            .all(|t| *t == [glam::Vec3::ZERO, glam::Vec3::X, glam::Vec3::Y]));
        assert_eq!(
            work,
            Work {
                decoded: n as u64 + 3,
                transformed: 3 * prims as u64
            }
        );
    }

    #[test]
    fn instances_transform_only_the_vertices_their_triangles_use() {
        // One mesh of 20,000 vertices and one triangle on 1,000 nodes: 20 million transforms before.
        let (n, nodes) = (20_000, 1_000);
        let node_list = list(nodes, |i| {
            format!(r#"{{"mesh":0,"translation":[{i},0,0]}}"#)
        });
        let roots = list(nodes, |i| i.to_string());
        let bytes = doc(
            n,
            "",
            &format!(
                r#""meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],
                "nodes":[{node_list}],"scenes":[{{"nodes":[{roots}]}}]"#
            ),
        );
        let (parts, work) = load_with_work(&bytes);
        // Kept instanced: one prototype of one triangle, placed by every node.
        assert_eq!(parts.mesh.len(), 0);
        assert_eq!(parts.prototypes.len(), 1);
        assert_eq!(parts.prototypes[0].len(), 1);
        assert_eq!(parts.placements.len(), nodes);
        let parts = parts.flatten_instances();
        assert_eq!(parts.mesh.len(), nodes);
        for (i, t) in parts.mesh.positions.iter().enumerate() {
            let o = glam::Vec3::new(i as f32, 0.0, 0.0);
            assert_eq!(*t, [o, o + glam::Vec3::X, o + glam::Vec3::Y]);
        }
        assert_eq!(
            work,
            Work {
                decoded: n as u64 + 3,
                // The prototype's three vertices, once: placements transform nothing at load.
                transformed: 3
            }
        );
    }

    #[test]
    fn accessors_over_the_same_data_are_bounded() {
        // Distinct accessors defined alike (the same bytes) share one decode.
        let n = 100_000;
        let alike = list(200, |_| {
            format!(r#"{{"bufferView":0,"componentType":5126,"count":{n},"type":"VEC3",MINMAX}}"#)
        });
        let primitives = list(200, |k| {
            format!(r#"{{"attributes":{{"POSITION":{}}},"indices":1}}"#, k + 2)
        });
        let rest = format!(
            r#""meshes":[{{"name":"many","primitives":[{primitives}]}}],"nodes":[{{"mesh":0}}],
            "scenes":[{{"nodes":[0]}}]"#
        );
        let (parts, work) = load_with_work(&doc(n, &format!(",{alike}"), &rest));
        assert_eq!(parts.mesh.len(), 200);
        assert_eq!(work.decoded, n as u64 + 3);

        // Accessors over the same 1.2 MB at different offsets are each decoded, until they have
        // read more than 4 × the buffer + 64 MiB: then a clear error naming the primitive.
        let shifted = list(200, |k| {
            format!(
                r#"{{"bufferView":0,"byteOffset":{},"componentType":5126,"count":{},"type":"VEC3",MINMAX}}"#,
                12 * k,
                n - 200
            )
        });
        let e = load_parts(
            &doc(n, &format!(",{shifted}"), &rest),
            &NoExternalResources,
            &LoadOptions::default(),
        )
        .unwrap_err();
        assert!(matches!(e, GltfError::Limit(_)), "{e:?}");
        let e = e.to_string();
        // 1,197,600 bytes per accessor: the 61st (primitive 60) passes 4 × 1,200,008 + 64 MiB.
        assert!(
            e.contains("(POSITION of mesh 0 \"many\", primitive 60)")
                && e.contains("too many accessors over the same data"),
            "{e}"
        );
    }
}
