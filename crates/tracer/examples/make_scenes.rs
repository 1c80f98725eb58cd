//! Writes large test scenes as GLB files: the shared Cornell box plus one displaced sphere.
//!
//! ```text
//! cargo run --release -p pathfarm-tracer --example make_scenes -- [OUT_DIR] [CORNELL_GLTF]
//! ```
//!
//! - `cornell_sphere.glb`: the box + a displaced geodesic sphere of 327,680 triangles;
//! - `million.glb`: the box + a displaced geodesic sphere of 1,003,520 triangles.
//!
//! `OUT_DIR` defaults to `target/scenes`, `CORNELL_GLTF` to `../shared/scenes/cornell.gltf` beside
//! the repository. The sphere is white and Lambertian like the box's white (metallic 0, roughness 1,
//! KHR_materials_specular specularFactor 0), indexed with u32, without normals (flat shading). Each
//! file is loaded back with `pathfarm_tracer::gltf::load`; its triangle count and the time of
//! `Scene::build` (BVH build included) are printed.

#[path = "scene_gen/mod.rs"]
mod scene_gen;

use base64::Engine as _;
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};
use pathfarm_tracer::Scene;
use scene_gen::IndexedMesh;
use serde_json::{json, Value};
use std::error::Error;
use std::path::{Path, PathBuf};
use std::time::Instant;

type Result<T> = std::result::Result<T, Box<dyn Error>>;

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;

fn main() -> Result<()> {
    let mut args = std::env::args_os().skip(1);
    let out_dir = args
        .next()
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("target/scenes"));
    let cornell = args
        .next()
        .map(PathBuf::from)
        .unwrap_or_else(scene_gen::cornell_path);
    std::fs::create_dir_all(&out_dir)?;
    let base: Value = serde_json::from_slice(
        &std::fs::read(&cornell).map_err(|e| format!("{}: {e}", cornell.display()))?,
    )?;
    let base_dir = cornell.parent().unwrap_or(Path::new("."));

    for (name, freq) in [
        ("cornell_sphere.glb", scene_gen::FREQ_330K),
        ("million.glb", scene_gen::FREQ_1M),
    ] {
        let t = Instant::now();
        let sphere = scene_gen::bench_sphere(freq);
        let gen_s = t.elapsed().as_secs_f64();
        if !sphere.is_watertight() {
            return Err(format!("{name}: the generated sphere is not watertight").into());
        }
        let glb = cornell_plus_mesh(&base, base_dir, &sphere)?;
        let path = out_dir.join(name);
        std::fs::write(&path, &glb)?;
        let (lo, hi) = sphere.bounds();
        println!(
            "{}: {:.1} MB, sphere of {} triangles / {} vertices (generated in {gen_s:.2} s), bounds {lo:.3} .. {hi:.3}",
            path.display(),
            glb.len() as f64 / 1e6,
            sphere.triangle_count(),
            sphere.positions.len(),
        );
        verify(&path, sphere.triangle_count())?;
    }
    Ok(())
}

/// Loads the file back: once with `gltf::load`, once as parts with `Scene::build` timed alone.
fn verify(path: &Path, sphere_triangles: usize) -> Result<()> {
    let bytes = std::fs::read(path)?;
    let t = Instant::now();
    let scene = gltf::load(&bytes, &NoExternalResources, &LoadOptions::default())?;
    let load_s = t.elapsed().as_secs_f64();
    let info = &scene.info;
    if info.degenerate_dropped != 0
        || info.triangles < sphere_triangles
        || !info.warnings.is_empty()
    {
        return Err(format!("{}: unexpected load result: {info:?}", path.display()).into());
    }
    drop(scene);

    let t = Instant::now();
    let parts = gltf::load_parts(&bytes, &NoExternalResources, &LoadOptions::default())?;
    let parse_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let scene = Scene::build(parts)?;
    let build_s = t.elapsed().as_secs_f64();
    let info = &scene.info;
    println!(
        "  loaded: {} triangles ({} of the box), {} emissive, {} BVH nodes, ~{:.1} MB; gltf::load {:.3} s = load_parts {:.3} s + Scene::build {:.3} s (BVH build)",
        info.triangles,
        info.triangles - sphere_triangles,
        info.emissive_triangles,
        info.bvh_nodes,
        info.bytes as f64 / 1e6,
        load_s,
        parse_s,
        build_s,
    );
    Ok(())
}

/// Reads a glTF buffer's bytes: a base64 `data:` URI or a file next to the scene.
fn buffer_bytes(buffer: &Value, base_dir: &Path) -> Result<Vec<u8>> {
    let uri = buffer["uri"]
        .as_str()
        .ok_or("buffer without uri (the input must be a .gltf)")?;
    let bytes = if let Some(rest) = uri.strip_prefix("data:") {
        let (_, data) = rest
            .split_once(";base64,")
            .ok_or("data: URI is not base64")?;
        base64::engine::general_purpose::STANDARD.decode(data)?
    } else {
        std::fs::read(base_dir.join(uri))?
    };
    let declared = buffer["byteLength"]
        .as_u64()
        .ok_or("buffer without byteLength")? as usize;
    if bytes.len() < declared {
        return Err(format!("buffer has {} bytes, declares {declared}", bytes.len()).into());
    }
    Ok(bytes)
}

fn align4(bin: &mut Vec<u8>) {
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
}

fn push_array(root: &mut Value, key: &str, v: Value) -> usize {
    let arr = root
        .as_object_mut()
        .expect("glTF root is an object")
        .entry(key)
        .or_insert_with(|| json!([]))
        .as_array_mut()
        .expect("glTF top-level arrays are arrays");
    arr.push(v);
    arr.len() - 1
}

/// The box's glTF with all its buffers moved into one GLB BIN chunk, plus `mesh` as a new node of the
/// default scene with its own white material.
fn cornell_plus_mesh(base: &Value, base_dir: &Path, mesh: &IndexedMesh) -> Result<Vec<u8>> {
    let mut root = base.clone();

    // The existing buffers, concatenated (4-byte aligned) into one.
    let mut bin: Vec<u8> = Vec::new();
    let mut starts = Vec::new();
    for buffer in root["buffers"].as_array().cloned().unwrap_or_default() {
        align4(&mut bin);
        starts.push(bin.len());
        bin.extend(buffer_bytes(&buffer, base_dir)?);
    }
    if let Some(views) = root["bufferViews"].as_array_mut() {
        for view in views {
            let b = view["buffer"].as_u64().ok_or("bufferView without buffer")? as usize;
            let start = *starts
                .get(b)
                .ok_or("bufferView refers to a missing buffer")?;
            let offset = view["byteOffset"].as_u64().unwrap_or(0) as usize;
            view["buffer"] = json!(0);
            view["byteOffset"] = json!(start + offset);
        }
    }

    // The new mesh: positions (f32 VEC3) and indices (u32).
    align4(&mut bin);
    let pos_offset = bin.len();
    for p in &mesh.positions {
        for c in p.to_array() {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    let pos_len = bin.len() - pos_offset;
    let idx_offset = bin.len();
    for i in &mesh.indices {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    let idx_len = bin.len() - idx_offset;
    align4(&mut bin);

    let pos_view = push_array(
        &mut root,
        "bufferViews",
        json!({ "buffer": 0, "byteOffset": pos_offset, "byteLength": pos_len, "target": ARRAY_BUFFER }),
    );
    let idx_view = push_array(
        &mut root,
        "bufferViews",
        json!({ "buffer": 0, "byteOffset": idx_offset, "byteLength": idx_len, "target": ELEMENT_ARRAY_BUFFER }),
    );
    let (lo, hi) = mesh.bounds();
    // f64 of the f32 values: exactly the stored floats.
    let f64s = |v: glam::Vec3| v.to_array().map(|c| c as f64);
    let pos_acc = push_array(
        &mut root,
        "accessors",
        json!({
            "bufferView": pos_view, "componentType": FLOAT, "count": mesh.positions.len(), "type": "VEC3",
            "min": f64s(lo), "max": f64s(hi),
        }),
    );
    let idx_acc = push_array(
        &mut root,
        "accessors",
        json!({ "bufferView": idx_view, "componentType": UNSIGNED_INT, "count": mesh.indices.len(), "type": "SCALAR" }),
    );
    let w = scene_gen::WHITE;
    let material = push_array(
        &mut root,
        "materials",
        json!({
            "name": "sphere_white",
            "doubleSided": true,
            "pbrMetallicRoughness": {
                "baseColorFactor": [w[0] as f64, w[1] as f64, w[2] as f64, 1.0],
                "metallicFactor": 0.0,
                "roughnessFactor": 1.0,
            },
            "extensions": { "KHR_materials_specular": { "specularFactor": 0.0 } },
        }),
    );
    let gltf_mesh = push_array(
        &mut root,
        "meshes",
        json!({
            "name": "displaced_sphere",
            "primitives": [{ "attributes": { "POSITION": pos_acc }, "indices": idx_acc, "material": material, "mode": 4 }],
        }),
    );
    let node = push_array(
        &mut root,
        "nodes",
        json!({ "name": "displaced_sphere", "mesh": gltf_mesh }),
    );
    let scene = root["scene"].as_u64().unwrap_or(0) as usize;
    let scene_nodes = root["scenes"][scene]["nodes"]
        .as_array_mut()
        .ok_or("the default scene has no nodes array")?;
    scene_nodes.push(json!(node));
    let used = root["extensionsUsed"].as_array_mut();
    match used {
        Some(list) if !list.iter().any(|e| e == "KHR_materials_specular") => {
            list.push(json!("KHR_materials_specular"))
        }
        Some(_) => {}
        None => root["extensionsUsed"] = json!(["KHR_materials_specular"]),
    }
    root["asset"]["generator"] = json!(
        "pathfarm-tracer examples/make_scenes.rs (the shared cornell.gltf plus a displaced sphere)"
    );
    root["buffers"] = json!([{ "byteLength": bin.len() }]);

    Ok(glb(&serde_json::to_vec(&root)?, &bin))
}

/// A GLB 2.0 container: header, JSON chunk (padded with spaces), BIN chunk (padded with zeros).
fn glb(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let pad = |n: usize| (4 - n % 4) % 4;
    let json_len = json.len() + pad(json.len());
    let bin_len = bin.len() + pad(bin.len());
    let total = 12 + 8 + json_len + 8 + bin_len;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json_len as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(json);
    out.resize(out.len() + pad(json.len()), b' ');
    out.extend_from_slice(&(bin_len as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(bin);
    out.resize(out.len() + pad(bin.len()), 0);
    debug_assert_eq!(out.len(), total);
    out
}
