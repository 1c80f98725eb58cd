//! glTF loader tests: the shared scenes, hand-built scenes (JSON with embedded base64 buffers, built
//! here), a broken corpus whose errors must name the object at fault, the committed corpus under
//! `tests/data/gltf/`, and a deterministic mutation fuzz loop that must never panic.

use base64::Engine as _;
use glam::{Affine2, Vec2, Vec3, Vec4};
use gltf::json::Value;
use pathfarm_tracer::camera::Projection;
use pathfarm_tracer::gltf::{
    load, load_parts, texture_transform_matrix, GltfError, LoadOptions, NoExternalResources,
    ResourceResolver,
};
use pathfarm_tracer::light::PunctualLight;
use pathfarm_tracer::material::{AlphaMode, ColorSpace, WrapMode};
use pathfarm_tracer::scene::{Scene, SceneParts};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

// ---------------------------------------------------------------------------------------------
// Helpers: a small glTF document builder.

fn j(s: &str) -> Value {
    gltf::json::deserialize::from_str(s).unwrap()
}

fn b64(bytes: &[u8]) -> String {
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

/// Pads to a multiple of 4 bytes.
fn pad4(v: &mut Vec<u8>, with: u8) {
    let pad = (4 - v.len() % 4) % 4;
    v.extend(std::iter::repeat_n(with, pad));
}

#[derive(Clone)]
struct Doc {
    json: Value,
    bin: Vec<u8>,
}

impl Doc {
    fn new() -> Self {
        Doc {
            json: j(
                r#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[]}],"nodes":[],"meshes":[],
                       "accessors":[],"bufferViews":[]}"#,
            ),
            bin: Vec::new(),
        }
    }

    fn push(&mut self, key: &str, v: Value) -> usize {
        if !self.json[key].is_array() {
            self.json[key] = Value::Array(Vec::new());
        }
        let arr = self.json[key].as_array_mut().unwrap();
        arr.push(v);
        arr.len() - 1
    }

    fn view(&mut self, bytes: &[u8], stride: Option<usize>) -> usize {
        pad4(&mut self.bin, 0);
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        let mut v = j(&format!(
            r#"{{"buffer":0,"byteOffset":{offset},"byteLength":{}}}"#,
            bytes.len()
        ));
        if let Some(s) = stride {
            v["byteStride"] = Value::from(s);
        }
        self.push("bufferViews", v)
    }

    fn accessor(&mut self, view: usize, component_type: u32, count: usize, ty: &str) -> usize {
        self.push(
            "accessors",
            j(&format!(
                r#"{{"bufferView":{view},"componentType":{component_type},"count":{count},"type":"{ty}"}}"#
            )),
        )
    }

    fn positions(&mut self, p: &[[f32; 3]]) -> usize {
        let bytes: Vec<u8> = p.iter().flatten().flat_map(|v| v.to_le_bytes()).collect();
        let view = self.view(&bytes, None);
        let a = self.accessor(view, 5126, p.len(), "VEC3");
        let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
        for v in p {
            for k in 0..3 {
                if v[k].is_finite() {
                    lo[k] = lo[k].min(v[k]);
                    hi[k] = hi[k].max(v[k]);
                }
            }
        }
        self.json["accessors"][a]["min"] = Value::from(lo.to_vec());
        self.json["accessors"][a]["max"] = Value::from(hi.to_vec());
        a
    }

    fn floats<const N: usize>(&mut self, v: &[[f32; N]]) -> usize {
        let bytes: Vec<u8> = v.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.view(&bytes, None);
        let ty = ["SCALAR", "VEC2", "VEC3", "VEC4"][N - 1];
        self.accessor(view, 5126, v.len(), ty)
    }

    /// Index accessor of component type 5121 (u8), 5123 (u16) or 5125 (u32).
    fn indices(&mut self, idx: &[u32], component_type: u32) -> usize {
        let bytes: Vec<u8> = match component_type {
            5121 => idx.iter().map(|&i| i as u8).collect(),
            5123 => idx.iter().flat_map(|&i| (i as u16).to_le_bytes()).collect(),
            _ => idx.iter().flat_map(|&i| i.to_le_bytes()).collect(),
        };
        let view = self.view(&bytes, None);
        self.accessor(view, component_type, idx.len(), "SCALAR")
    }

    fn mesh(&mut self, name: &str, primitives: Value) -> usize {
        self.push(
            "meshes",
            j(&format!(r#"{{"name":"{name}","primitives":{primitives}}}"#)),
        )
    }

    fn node(&mut self, v: Value) -> usize {
        self.push("nodes", v)
    }

    fn root(&mut self, node: usize) {
        self.json["scenes"][0]["nodes"]
            .as_array_mut()
            .unwrap()
            .push(Value::from(node));
    }

    fn finished_json(&self, uri: Option<String>) -> Value {
        let mut json = self.json.clone();
        if !self.bin.is_empty() {
            let mut buffer = j(&format!(r#"{{"byteLength":{}}}"#, self.bin.len()));
            if let Some(uri) = uri {
                buffer["uri"] = Value::from(uri);
            }
            json["buffers"] = Value::Array(vec![buffer]);
        }
        json
    }

    /// `.gltf` with the buffer as a base64 data URI.
    fn gltf(&self) -> Vec<u8> {
        let uri = format!("data:application/octet-stream;base64,{}", b64(&self.bin));
        gltf::json::serialize::to_vec(&self.finished_json(Some(uri))).unwrap()
    }

    /// `.gltf` with the buffer as an external file `uri`.
    fn gltf_external(&self, uri: &str) -> Vec<u8> {
        gltf::json::serialize::to_vec(&self.finished_json(Some(uri.to_string()))).unwrap()
    }

    /// `.glb` with the buffer as the BIN chunk.
    fn glb(&self) -> Vec<u8> {
        let mut json = gltf::json::serialize::to_vec(&self.finished_json(None)).unwrap();
        pad4(&mut json, b' ');
        let mut bin = self.bin.clone();
        pad4(&mut bin, 0);
        let mut out = b"glTF".to_vec();
        out.extend(2u32.to_le_bytes());
        out.extend(0u32.to_le_bytes());
        out.extend((json.len() as u32).to_le_bytes());
        out.extend(b"JSON");
        out.extend(&json);
        if !bin.is_empty() {
            out.extend((bin.len() as u32).to_le_bytes());
            out.extend(b"BIN\0");
            out.extend(&bin);
        }
        let n = out.len() as u32;
        out[8..12].copy_from_slice(&n.to_le_bytes());
        out
    }
}

const TRI: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

/// A document with one triangle mesh "Tri" (mesh 0) on one root node described by `node` (JSON
/// without the mesh reference).
fn triangle_doc(node: &str) -> Doc {
    let mut d = Doc::new();
    let p = d.positions(&TRI);
    d.mesh(
        "Tri",
        j(&format!(r#"[{{"attributes":{{"POSITION":{p}}}}}]"#)),
    );
    let mut n = j(node);
    n["mesh"] = Value::from(0);
    let n = d.node(n);
    d.root(n);
    d
}

fn parts(bytes: &[u8]) -> SceneParts {
    match load_parts(bytes, &NoExternalResources, &LoadOptions::default()) {
        Ok(p) => p,
        Err(e) => panic!("load failed: {e}"),
    }
}

fn error_of(bytes: &[u8]) -> String {
    error_with(bytes, &NoExternalResources, &LoadOptions::default())
}

fn error_with(bytes: &[u8], resolver: &dyn ResourceResolver, options: &LoadOptions) -> String {
    match load(bytes, resolver, options) {
        Ok(_) => panic!("expected an error"),
        Err(GltfError::Internal(e)) => {
            panic!("internal error (panic) instead of a clear error: {e}")
        }
        Err(e) => e.to_string(),
    }
}

fn assert_contains(message: &str, parts: &[&str]) {
    for p in parts {
        assert!(message.contains(p), "error message {message:?} lacks {p:?}");
    }
}

fn close3(a: Vec3, b: Vec3) -> bool {
    (a - b).length() < 1e-5
}

fn assert_tri(got: [Vec3; 3], want: [[f32; 3]; 3]) {
    for k in 0..3 {
        assert!(
            close3(got[k], Vec3::from(want[k])),
            "corner {k}: got {got:?}, want {want:?}"
        );
    }
}

fn png(width: u32, height: u32, rgba: &[u8]) -> Vec<u8> {
    let img = image::RgbaImage::from_raw(width, height, rgba.to_vec()).unwrap();
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

struct MapResolver(HashMap<String, Vec<u8>>);

impl ResourceResolver for MapResolver {
    fn resolve(&self, uri: &str) -> Result<Vec<u8>, String> {
        self.0
            .get(uri)
            .cloned()
            .ok_or_else(|| "No such file or directory (os error 2)".to_string())
    }
}

// ---------------------------------------------------------------------------------------------
// The shared scenes.

fn shared_scenes() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes");
    if dir.join("manifest.json").is_file() {
        Some(dir)
    } else {
        eprintln!("skipped: shared scenes not found at {}", dir.display());
        None
    }
}

#[test]
fn shared_scenes_load() {
    let Some(dir) = shared_scenes() else { return };
    let manifest: Value = j(&std::fs::read_to_string(dir.join("manifest.json")).unwrap());
    let entries = manifest.as_object().unwrap();
    assert!(entries.len() >= 3);
    for (name, entry) in entries {
        let file = entry["file"].as_str().unwrap();
        let bytes = std::fs::read(dir.join(file)).unwrap();
        let scene = load(&bytes, &NoExternalResources, &LoadOptions::default())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        let want = entry["triangles"].as_u64().unwrap() as usize;
        assert_eq!(scene.info.triangles, want, "{name}: triangles");
        assert_eq!(scene.info.degenerate_dropped, 0, "{name}");
        assert!(
            scene.mesh.normals.is_none() && scene.mesh.uv0.is_none(),
            "{name}: flat, untextured"
        );
        assert!(
            scene.info.warnings.is_empty(),
            "{name}: {:?}",
            scene.info.warnings
        );
        assert!(scene.info.emissive_triangles > 0, "{name}");
        // The camera is the file's, with its yfov.
        let json: Value = j(std::str::from_utf8(&bytes).unwrap());
        let yfov = json["cameras"][0]["perspective"]["yfov"].as_f64().unwrap() as f32;
        match scene.camera.projection {
            Projection::Perspective(p) => assert!((p.yfov - yfov).abs() < 1e-6, "{name}"),
            other => panic!("{name}: {other:?}"),
        }
    }
}

#[test]
fn cornell_box_materials_and_camera() {
    let Some(dir) = shared_scenes() else { return };
    let bytes = std::fs::read(dir.join("cornell.gltf")).unwrap();
    let parts = parts(&bytes);
    assert_eq!(parts.mesh.len(), 32);
    assert_eq!(parts.materials.len(), 4);
    let by_name = |n: &str| {
        parts
            .materials
            .iter()
            .find(|m| m.name.as_deref() == Some(n))
            .unwrap()
    };
    let white = by_name("white");
    assert!(close3(
        white.base_color.truncate(),
        Vec3::new(0.725, 0.71, 0.68)
    ));
    assert_eq!(
        (white.specular, white.metallic, white.roughness),
        (0.0, 0.0, 1.0)
    );
    assert!(white.emissive == Vec3::ZERO);
    let green = by_name("green");
    assert!(green.double_sided && green.specular == 0.0);
    let light = by_name("light");
    assert!(
        close3(light.emissive, Vec3::new(16.0, 12.0, 6.0)),
        "{}",
        light.emissive
    );
    assert!(!light.double_sided);
    assert_eq!(light.base_color.truncate(), Vec3::ZERO);
    let camera = parts.camera.unwrap();
    assert!(
        matches!(camera.projection, Projection::Perspective(p) if (p.yfov - 0.686_047_9).abs() < 1e-6)
    );
    assert!(close3(
        camera.to_world.translation.into(),
        Vec3::new(2.78, 2.73, -8.0)
    ));
    // Rotated 180° about Y: the camera's −Z looks down +Z, into the box.
    let forward: Vec3 = camera.to_world.transform_vector3(Vec3::NEG_Z);
    assert!(close3(forward, Vec3::Z), "{forward}");
    // The light faces down: its triangles' front normal is −Y.
    let light_index = parts
        .materials
        .iter()
        .position(|m| m.name.as_deref() == Some("light"))
        .unwrap() as u32;
    let tris: Vec<usize> = (0..parts.mesh.len())
        .filter(|&i| parts.mesh.material[i] == light_index)
        .collect();
    assert_eq!(tris.len(), 2);
    for i in tris {
        assert!(parts.mesh.cross(i).normalize().y < -0.999);
    }
}

// ---------------------------------------------------------------------------------------------
// Hand-built scenes.

#[test]
fn trs_and_matrix_hierarchy() {
    let mut d = Doc::new();
    let p = d.positions(&TRI);
    d.mesh(
        "Tri",
        j(&format!(r#"[{{"attributes":{{"POSITION":{p}}}}}]"#)),
    );
    // child: matrix = T(0,1,0)·S(2) (column-major); parent: T(1,0,0)·Rz(90°).
    let child = d.node(j(
        r#"{"mesh":0,"matrix":[2,0,0,0, 0,2,0,0, 0,0,2,0, 0,1,0,1]}"#,
    ));
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let parent = d.node(j(&format!(
        r#"{{"translation":[1,0,0],"rotation":[0,0,{h},{h}],"children":[{child}]}}"#
    )));
    d.root(parent);
    let parts = parts(&d.gltf());
    assert_eq!(parts.mesh.len(), 1);
    assert_tri(
        parts.mesh.positions[0],
        [[0.0, 0.0, 0.0], [0.0, 2.0, 0.0], [-2.0, 0.0, 0.0]],
    );
    assert_eq!(parts.materials.len(), 1, "the default material, added once");
    assert_eq!(
        parts.materials[0],
        pathfarm_tracer::material::Material::default()
    );
    assert!(parts.camera.is_none());
}

#[test]
fn negative_scale_flips_winding_and_keeps_normals_outward() {
    let mut d = Doc::new();
    let p = d.positions(&TRI);
    let n = d.floats(&[[0.0f32, 0.0, 1.0]; 3]);
    d.mesh(
        "Tri",
        j(&format!(
            r#"[{{"attributes":{{"POSITION":{p},"NORMAL":{n}}}}}]"#
        )),
    );
    let mirrored = d.node(j(r#"{"mesh":0,"scale":[-1,1,1]}"#));
    d.root(mirrored);
    // Two mirrors cancel: no flip.
    let inner = d.node(j(r#"{"mesh":0,"scale":[1,-1,1]}"#));
    let outer = d.node(j(&format!(r#"{{"scale":[-1,1,1],"children":[{inner}]}}"#)));
    d.root(outer);
    // Placed twice, the mesh is kept instanced; flattened, as the loader flattens a mesh placed
    // once.
    let parts = parts(&d.gltf()).flatten_instances();
    let mesh = &parts.mesh;
    assert_eq!(mesh.len(), 2);
    // Mirrored in X: corners (0,0,0), (−1,0,0), (0,1,0), two swapped so the front (+Z) is kept.
    assert_tri(
        mesh.positions[0],
        [[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]],
    );
    assert!(mesh.cross(0).normalize().z > 0.999);
    let normals = mesh.normals.as_ref().expect("NORMAL present → stored");
    for k in 0..3 {
        assert!(close3(normals[0][k], Vec3::Z), "{:?}", normals[0]);
    }
    // Rotated 180° about Z (two mirrors): winding kept, still facing +Z.
    assert_tri(
        mesh.positions[1],
        [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]].map(|v| [-v[0], -v[1], v[2]]),
    );
    assert!(mesh.cross(1).normalize().z > 0.999);
    assert!(close3(normals[1][0], Vec3::Z));
}

#[test]
fn mirrored_normals_use_the_inverse_transpose() {
    // A non-uniform scale with a mirror: normals must follow M^{-T}, not M.
    let mut d = Doc::new();
    let p = d.positions(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 1.0]]);
    let nn = Vec3::new(0.0, -1.0, 1.0).normalize();
    let n = d.floats(&[nn.to_array(); 3]);
    d.mesh(
        "Ramp",
        j(&format!(
            r#"[{{"attributes":{{"POSITION":{p},"NORMAL":{n}}}}}]"#
        )),
    );
    let node = d.node(j(r#"{"mesh":0,"scale":[-1,2,1]}"#));
    d.root(node);
    let parts = parts(&d.gltf());
    let geometric = parts.mesh.cross(0).normalize();
    let stored = parts.mesh.normals.as_ref().unwrap()[0][0];
    assert!(
        close3(geometric, stored),
        "geometric {geometric} vs vertex normal {stored}"
    );
    assert!(
        close3(stored, Vec3::new(0.0, -0.5, 1.0).normalize()),
        "{stored}"
    );
}

#[test]
fn indexed_and_non_indexed_agree() {
    let quad = [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
    ];
    let idx = [0u32, 1, 2, 0, 2, 3];
    let mut a = Doc::new();
    let p = a.positions(&quad);
    let i = a.indices(&idx, 5123);
    a.mesh(
        "Quad",
        j(&format!(
            r#"[{{"attributes":{{"POSITION":{p}}},"indices":{i},"mode":4}}]"#
        )),
    );
    let n = a.node(j(r#"{"mesh":0}"#));
    a.root(n);
    let mut b = Doc::new();
    let flat: Vec<[f32; 3]> = idx.iter().map(|&k| quad[k as usize]).collect();
    let p = b.positions(&flat);
    b.mesh(
        "Quad",
        j(&format!(r#"[{{"attributes":{{"POSITION":{p}}}}}]"#)),
    );
    let n = b.node(j(r#"{"mesh":0}"#));
    b.root(n);
    let (pa, pb) = (parts(&a.gltf()), parts(&b.gltf()));
    assert_eq!(pa.mesh.len(), 2);
    assert_eq!(pa.mesh.positions, pb.mesh.positions);
}

/// A document with one mesh of two primitives over the given vertex arrays (POSITION, NORMAL,
/// TEXCOORD_0, TANGENT on the first only) and index lists, with a normal-mapped material, on two
/// nodes (one mirrored, rotated and scaled).
fn two_primitive_doc(
    pos: &[[f32; 3]],
    nrm: &[[f32; 3]],
    uv: &[[f32; 2]],
    tan: &[[f32; 4]],
    idx: [&[u32]; 2],
) -> Doc {
    let mut d = Doc::new();
    let p = d.positions(pos);
    let n = d.floats(nrm);
    let u = d.floats(uv);
    let t = d.floats(tan);
    let i0 = d.indices(idx[0], 5125);
    let i1 = d.indices(idx[1], 5123);
    d.mesh(
        "Pair",
        j(&format!(
            r#"[{{"attributes":{{"POSITION":{p},"NORMAL":{n},"TEXCOORD_0":{u},"TANGENT":{t}}},
                  "indices":{i0},"material":0}},
                {{"attributes":{{"POSITION":{p},"NORMAL":{n},"TEXCOORD_0":{u}}},"indices":{i1},
                  "material":0}}]"#
        )),
    );
    let image = png(1, 1, &[128, 128, 255, 255]);
    d.push(
        "images",
        j(&format!(
            r#"{{"uri":"data:image/png;base64,{}"}}"#,
            b64(&image)
        )),
    );
    d.push("textures", j(r#"{"source":0}"#));
    d.push(
        "materials",
        j(r#"{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}},"normalTexture":{"index":0}}"#),
    );
    let a = d.node(j(
        r#"{"mesh":0,"translation":[0.5,-2,3],"rotation":[0.18257419,0.36514837,0.54772256,0.73029674],
            "scale":[-1.5,2,0.7]}"#,
    ));
    d.root(a);
    let b = d.node(j(r#"{"mesh":0,"scale":[3,0.25,1]}"#));
    d.root(b);
    d
}

#[test]
fn primitives_keep_only_the_vertices_they_use_with_identical_triangles() {
    // 30 vertices; the first primitive uses 5 of them (a dense renumbering), the second 4 (6
    // corners, under a quarter of 30: a hashed one). The same triangles from arrays holding only
    // the vertices used must give bit-identical results: positions, normals, UVs, given and
    // generated tangents, under a mirrored and a plain transform.
    let n = 30;
    let f = |i: usize, k: f32| ((i as f32 + 1.0) * k).sin();
    let pos: Vec<[f32; 3]> = (0..n)
        .map(|i| [2.0 * f(i, 1.3), f(i, 0.7), 0.1 * i as f32])
        .collect();
    let nrm: Vec<[f32; 3]> = (0..n)
        .map(|i| Vec3::new(f(i, 0.3), f(i, 0.9), 1.5).normalize().to_array())
        .collect();
    let uv: Vec<[f32; 2]> = (0..n).map(|i| [f(i, 2.1), f(i, 0.4)]).collect();
    let tan: Vec<[f32; 4]> = (0..n)
        .map(|i| {
            let w = if i % 3 == 0 { -1.0 } else { 1.0 };
            Vec3::new(1.0, f(i, 1.7), 0.2)
                .normalize()
                .extend(w)
                .to_array()
        })
        .collect();
    let idx0 = [7u32, 2, 5, 5, 2, 9, 9, 0, 7];
    let idx1 = [23u32, 8, 11, 11, 8, 26];
    let full = two_primitive_doc(&pos, &nrm, &uv, &tan, [&idx0, &idx1]);

    // The same, each attribute array cut down to the vertices used and the indices renumbered.
    let used: Vec<u32> = [7, 2, 5, 9, 0, 23, 8, 11, 26].to_vec();
    let renumber = |idx: &[u32]| -> Vec<u32> {
        idx.iter()
            .map(|v| used.iter().position(|u| u == v).unwrap() as u32)
            .collect()
    };
    let pos_c: Vec<[f32; 3]> = used.iter().map(|&u| pos[u as usize]).collect();
    let nrm_c: Vec<[f32; 3]> = used.iter().map(|&u| nrm[u as usize]).collect();
    let uv_c: Vec<[f32; 2]> = used.iter().map(|&u| uv[u as usize]).collect();
    let tan_c: Vec<[f32; 4]> = used.iter().map(|&u| tan[u as usize]).collect();
    let cut = two_primitive_doc(
        &pos_c,
        &nrm_c,
        &uv_c,
        &tan_c,
        [&renumber(&idx0), &renumber(&idx1)],
    );

    let (a, b) = (
        parts(&full.gltf()).flatten_instances(),
        parts(&cut.glb()).flatten_instances(),
    );
    assert_eq!(a.mesh.len(), 10, "5 triangles on each of 2 nodes");
    assert_eq!(a.mesh.positions, b.mesh.positions);
    assert_eq!(a.mesh.material, b.mesh.material);
    assert_eq!(a.mesh.normals, b.mesh.normals);
    assert_eq!(a.mesh.uv0, b.mesh.uv0);
    assert_eq!(a.mesh.tangents, b.mesh.tangents);
    assert!(a.mesh.normals.is_some() && a.mesh.uv0.is_some() && a.mesh.tangents.is_some());
    // And the corners are the vertices the indices name, transformed (two swapped: mirrored).
    let world = glam::Mat4::from_scale_rotation_translation(
        Vec3::new(-1.5, 2.0, 0.7),
        glam::Quat::from_xyzw(0.18257419, 0.36514837, 0.5477226, 0.73029674),
        Vec3::new(0.5, -2.0, 3.0),
    );
    let at = |v: usize| world.transform_point3(Vec3::from(pos[v]));
    assert_tri(
        a.mesh.positions[0],
        [at(7).to_array(), at(5).to_array(), at(2).to_array()],
    );
}

#[test]
fn index_component_types() {
    let quad = [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
    ];
    let idx = [0u32, 1, 2, 0, 2, 3];
    let mut results = Vec::new();
    for ct in [5121, 5123, 5125] {
        let mut d = Doc::new();
        let p = d.positions(&quad);
        let i = d.indices(&idx, ct);
        d.mesh(
            "Quad",
            j(&format!(
                r#"[{{"attributes":{{"POSITION":{p}}},"indices":{i}}}]"#
            )),
        );
        let n = d.node(j(r#"{"mesh":0}"#));
        d.root(n);
        results.push(parts(&d.gltf()).mesh.positions);
    }
    assert_eq!(results[0].len(), 2);
    assert_eq!(results[0], results[1]);
    assert_eq!(results[1], results[2]);
    assert_tri(results[0][1], [quad[0], quad[2], quad[3]]);
}

#[test]
fn strips_and_fans_are_converted() {
    let quad = [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
    ];
    // A strip zig-zags; a fan goes around its first vertex.
    let fan = [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
    ];
    for (mode, count, verts) in [(5, 2, quad), (6, 2, fan)] {
        let mut d = Doc::new();
        let p = d.positions(&verts);
        d.mesh(
            "S",
            j(&format!(
                r#"[{{"attributes":{{"POSITION":{p}}},"mode":{mode}}}]"#
            )),
        );
        let n = d.node(j(r#"{"mesh":0}"#));
        d.root(n);
        let parts = parts(&d.gltf());
        assert_eq!(parts.mesh.len(), count, "mode {mode}");
        for i in 0..parts.mesh.len() {
            assert!(
                parts.mesh.cross(i).z > 0.0,
                "mode {mode}: triangle {i} keeps counter-clockwise winding"
            );
        }
    }
    // Points are skipped with a warning.
    let mut d = Doc::new();
    let p = d.positions(&quad);
    d.mesh(
        "P",
        j(&format!(
            r#"[{{"attributes":{{"POSITION":{p}}},"mode":0}}]"#
        )),
    );
    let n = d.node(j(r#"{"mesh":0}"#));
    d.root(n);
    let parts = parts(&d.gltf());
    assert_eq!(parts.mesh.len(), 0);
    assert!(
        parts
            .warnings
            .iter()
            .any(|w| w.contains("points and lines")),
        "{:?}",
        parts.warnings
    );
}

#[test]
fn normals_stored_only_when_present() {
    let without = triangle_doc(r#"{"translation":[0,0,1]}"#);
    let p = parts(&without.gltf());
    assert!(p.mesh.normals.is_none());
    assert!(p.mesh.uv0.is_none() && p.mesh.uv1.is_none() && p.mesh.tangents.is_none());

    // Two primitives, one with NORMAL: the other gets its flat normal.
    let mut d = Doc::new();
    let pos = d.positions(&TRI);
    let nrm = d.floats(&[[0.0f32, 0.6, 0.8]; 3]);
    let pos2 = d.positions(&[[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]);
    d.mesh(
        "Two",
        j(&format!(
            r#"[{{"attributes":{{"POSITION":{pos},"NORMAL":{nrm}}}}},{{"attributes":{{"POSITION":{pos2}}}}}]"#
        )),
    );
    let n = d.node(j(r#"{"mesh":0,"rotation":[0,0,1,0]}"#));
    d.root(n);
    let p = parts(&d.gltf());
    let normals = p.mesh.normals.unwrap();
    assert_eq!(normals.len(), 2);
    // Rotated 180° about Z.
    assert!(
        close3(normals[0][1], Vec3::new(0.0, -0.6, 0.8)),
        "{:?}",
        normals[0]
    );
    assert!(
        close3(normals[1][2], Vec3::NEG_Z),
        "flat normal of the clockwise triangle: {:?}",
        normals[1]
    );
}

#[test]
fn texture_decodes_with_srgb_base_color() {
    let mut d = triangle_doc("{}");
    let uv = d.floats(&[[0.25f32, 0.5], [0.75, 0.5], [0.25, 0.5]]);
    d.json["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = Value::from(uv);
    d.json["meshes"][0]["primitives"][0]["material"] = Value::from(0);
    let image = png(2, 1, &[255, 0, 188, 255, 0, 255, 0, 128]);
    let view = d.view(&image, None);
    d.push(
        "images",
        j(&format!(
            r#"{{"bufferView":{view},"mimeType":"image/png","name":"img"}}"#
        )),
    );
    d.push(
        "samplers",
        j(r#"{"magFilter":9728,"wrapS":33071,"wrapT":33648}"#),
    );
    d.push("textures", j(r#"{"source":0,"sampler":0}"#));
    d.push(
        "materials",
        j(
            r#"{"name":"tex","pbrMetallicRoughness":{"baseColorTexture":{"index":0},"baseColorFactor":[1,1,1,1]},
             "alphaMode":"MASK"}"#,
        ),
    );
    let parts = parts(&d.gltf());
    assert_eq!(parts.textures.len(), 1);
    let t = &parts.textures[0];
    assert_eq!((t.width, t.height), (2, 1));
    assert_eq!(t.texels, vec![[255, 0, 188, 255], [0, 255, 0, 128]]);
    assert!(t.sampler.nearest);
    assert_eq!(
        (t.sampler.wrap_s, t.sampler.wrap_t),
        (WrapMode::ClampToEdge, WrapMode::MirroredRepeat)
    );
    let m = &parts.materials[0];
    assert_eq!(m.alpha_mode, AlphaMode::Mask { cutoff: 0.5 });
    let r = m.base_color_texture.as_ref().unwrap();
    assert_eq!((r.texture, r.texcoord, r.transform), (0, 0, None));
    let uv0 = parts
        .mesh
        .uv0
        .as_ref()
        .expect("uv0 used by the base color texture");
    assert_eq!(uv0[0][1], Vec2::new(0.75, 0.5));
    assert!(parts.mesh.uv1.is_none());
    // sRGB decoding of the base color: 188 → 0.5029, 255 → 1.
    let shade = m.shade(&parts.textures, &[uv0[0][0], Vec2::ZERO], Vec3::Z, None);
    assert!(
        (shade.params.base_color.x - 1.0).abs() < 1e-5
            && (shade.params.base_color.z - 0.5029).abs() < 1e-3
    );
    let texel = parts.textures[0].sample(Vec2::new(0.75, 0.5), ColorSpace::Srgb);
    assert!((texel.y - 1.0).abs() < 1e-6 && (texel.w - 128.0 / 255.0).abs() < 1e-6);
}

#[test]
fn texture_transform_and_generated_tangents() {
    let mut d = triangle_doc("{}");
    let uv = d.floats(&[[0.0f32, 1.0], [1.0, 1.0], [0.0, 0.0]]);
    d.json["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_1"] = Value::from(uv);
    d.json["meshes"][0]["primitives"][0]["material"] = Value::from(0);
    d.json["extensionsUsed"] = j(r#"["KHR_texture_transform","KHR_materials_iridescence"]"#);
    d.json["extensionsRequired"] = j(r#"["KHR_texture_transform"]"#);
    let image = png(1, 1, &[128, 128, 255, 255]);
    d.push(
        "images",
        j(&format!(
            r#"{{"uri":"data:image/png;base64,{}"}}"#,
            b64(&image)
        )),
    );
    d.push("textures", j(r#"{"source":0}"#));
    d.push(
        "materials",
        j(
            r#"{"pbrMetallicRoughness":{"baseColorTexture":{"index":0,"extensions":{"KHR_texture_transform":
                {"offset":[0.5,0.25],"rotation":1.5707964,"scale":[2,3],"texCoord":1}}}},
             "normalTexture":{"index":0,"scale":0.5,"texCoord":1,
                "extensions":{"KHR_texture_transform":{"offset":[0.1,0.2]}}},
             "extensions":{"KHR_materials_iridescence":{"iridescenceFactor":1}}}"#,
        ),
    );
    let parts = parts(&d.gltf());
    let m = &parts.materials[0];
    let r = m.base_color_texture.as_ref().unwrap();
    assert_eq!(r.texcoord, 1, "texCoord overridden by the transform");
    let want = texture_transform_matrix([0.5, 0.25], 1.5707964, [2.0, 3.0]);
    assert_eq!(r.transform, Some(want));
    let p = want.transform_point2(Vec2::X);
    assert!((p - Vec2::new(0.5, -1.75)).length() < 1e-5, "{p}");
    let (nr, scale) = m.normal_texture.as_ref().unwrap();
    assert_eq!(*scale, 0.5);
    assert_eq!(
        nr.transform,
        Some(Affine2::from_translation(Vec2::new(0.1, 0.2)))
    );
    assert_eq!(
        parts.textures.len(),
        1,
        "one image, one sampler: one texture"
    );
    assert!(parts.mesh.uv0.is_none() && parts.mesh.uv1.is_some());
    // No TANGENT attribute: generated from the UVs (u along +X, image up along +Y).
    let tangents = parts.mesh.tangents.as_ref().unwrap();
    for t in tangents[0] {
        assert!((t - Vec4::new(1.0, 0.0, 0.0, 1.0)).length() < 1e-5, "{t}");
    }
    assert!(
        parts
            .warnings
            .iter()
            .any(|w| w.contains("KHR_materials_iridescence")),
        "{:?}",
        parts.warnings
    );
    assert_eq!(
        parts
            .warnings
            .iter()
            .filter(|w| w.contains("KHR_materials_iridescence"))
            .count(),
        1
    );
}

#[test]
fn material_extensions() {
    let mut d = triangle_doc("{}");
    d.json["meshes"][0]["primitives"][0]["material"] = Value::from(0);
    d.push(
        "materials",
        j(
            r#"{"name":"glass","doubleSided":true,"alphaMode":"BLEND","emissiveFactor":[1,0.5,0.25],
             "pbrMetallicRoughness":{"metallicFactor":0.25,"roughnessFactor":0.125},
             "extensions":{
               "KHR_materials_emissive_strength":{"emissiveStrength":4},
               "KHR_materials_specular":{"specularFactor":0.5,"specularColorFactor":[1,0.5,0.25]},
               "KHR_materials_ior":{"ior":1.33},
               "KHR_materials_transmission":{"transmissionFactor":0.9},
               "KHR_materials_volume":{"thicknessFactor":1,"attenuationDistance":2,"attenuationColor":[0.5,1,0.25]}}}"#,
        ),
    );
    let parts = parts(&d.gltf());
    let m = &parts.materials[0];
    assert_eq!(m.name.as_deref(), Some("glass"));
    assert!(m.double_sided && m.alpha_mode == AlphaMode::Blend);
    assert_eq!((m.metallic, m.roughness), (0.25, 0.125));
    assert!(close3(m.emissive, Vec3::new(4.0, 2.0, 1.0)));
    assert_eq!(
        (m.specular, m.specular_color),
        (0.5, Vec3::new(1.0, 0.5, 0.25))
    );
    assert_eq!((m.ior, m.transmission), (1.33, 0.9));
    let sigma = m.volume.unwrap().sigma_a;
    assert!(
        close3(
            sigma,
            Vec3::new(-(0.5f32.ln()) / 2.0, 0.0, -(0.25f32.ln()) / 2.0)
        ),
        "{sigma}"
    );
    // Thickness 0 (the default): thin-walled.
    let mut d2 = d.clone();
    d2.json["materials"][0]["extensions"]["KHR_materials_volume"]["thicknessFactor"] =
        Value::from(0);
    assert!(parts_of(&d2).materials[0].volume.is_none());
}

fn parts_of(d: &Doc) -> SceneParts {
    parts(&d.gltf())
}

/// A material with KHR_materials_clearcoat and KHR_materials_sheen, every factor and texture set
/// (texCoord, KHR_texture_transform, the clear coat's normal map and its scale); required, so the
/// loader must also accept them in `extensionsRequired`.
fn layered_doc() -> Doc {
    let mut d = triangle_doc("{}");
    let uv = d.floats(&[[0.0f32, 0.0], [1.0, 0.0], [0.0, 1.0]]);
    d.json["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = Value::from(uv);
    d.json["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_1"] = Value::from(uv);
    d.json["meshes"][0]["primitives"][0]["material"] = Value::from(0);
    d.json["extensionsUsed"] =
        j(r#"["KHR_materials_clearcoat","KHR_materials_sheen","KHR_texture_transform"]"#);
    d.json["extensionsRequired"] = j(r#"["KHR_materials_clearcoat","KHR_materials_sheen"]"#);
    // Texel (R, G, B, A) = (128, 64, 188, 51): linear R 0.502, G 0.251, alpha 0.2; sRGB B 0.503.
    let image = png(1, 1, &[128, 64, 188, 51]);
    d.push(
        "images",
        j(&format!(
            r#"{{"uri":"data:image/png;base64,{}"}}"#,
            b64(&image)
        )),
    );
    d.push("textures", j(r#"{"source":0}"#));
    d.push("textures", j(r#"{"source":0,"name":"second"}"#));
    d.push(
        "materials",
        j(
            r#"{"name":"car paint","pbrMetallicRoughness":{"metallicFactor":0},
             "extensions":{
               "KHR_materials_clearcoat":{
                 "clearcoatFactor":0.75,
                 "clearcoatTexture":{"index":0},
                 "clearcoatRoughnessFactor":0.5,
                 "clearcoatRoughnessTexture":{"index":1,"texCoord":1},
                 "clearcoatNormalTexture":{"index":0,"scale":0.25,
                    "extensions":{"KHR_texture_transform":{"offset":[0.5,0],"texCoord":1}}}},
               "KHR_materials_sheen":{
                 "sheenColorFactor":[1,0.5,0.25],
                 "sheenColorTexture":{"index":1,
                    "extensions":{"KHR_texture_transform":{"scale":[2,2]}}},
                 "sheenRoughnessFactor":0.625,
                 "sheenRoughnessTexture":{"index":0,"texCoord":1}}}}"#,
        ),
    );
    d
}

#[test]
fn clearcoat_and_sheen_with_textures() {
    let parts = parts(&layered_doc().gltf());
    assert!(
        !parts
            .warnings
            .iter()
            .any(|w| w.contains("clearcoat") || w.contains("sheen")),
        "{:?}",
        parts.warnings
    );
    let m = &parts.materials[0];
    assert_eq!(m.name.as_deref(), Some("car paint"));
    assert_eq!((m.clearcoat, m.clearcoat_roughness), (0.75, 0.5));
    assert_eq!(
        (m.sheen_color, m.sheen_roughness),
        (Vec3::new(1.0, 0.5, 0.25), 0.625)
    );
    let t = m.clearcoat_texture.as_ref().unwrap();
    assert_eq!((t.texcoord, t.transform), (0, None));
    let t = m.clearcoat_roughness_texture.as_ref().unwrap();
    assert_eq!((t.texcoord, t.transform), (1, None));
    let (t, scale) = m.clearcoat_normal_texture.as_ref().unwrap();
    assert_eq!(*scale, 0.25);
    assert_eq!(t.texcoord, 1, "texCoord overridden by the transform");
    assert_eq!(
        t.transform,
        Some(Affine2::from_translation(Vec2::new(0.5, 0.0)))
    );
    let t = m.sheen_color_texture.as_ref().unwrap();
    assert_eq!(
        t.transform,
        Some(texture_transform_matrix([0.0, 0.0], 0.0, [2.0, 2.0]))
    );
    let t = m.sheen_roughness_texture.as_ref().unwrap();
    assert_eq!(t.texcoord, 1);
    assert!(
        m.constant_params().is_none(),
        "textured layers are shaded per hit"
    );
    // The clear coat's normal map needs tangents, and both UV sets are read.
    assert!(parts.mesh.tangents.is_some());
    assert!(parts.mesh.uv0.is_some() && parts.mesh.uv1.is_some());
    // Shading reads the channels the extensions name: clearcoat × R, roughness × G (linear),
    // sheen colour × RGB (sRGB), sheen roughness × A.
    let shade = m.shade(
        &parts.textures,
        &[Vec2::new(0.3, 0.3), Vec2::new(0.3, 0.3)],
        Vec3::Z,
        Some(Vec4::new(1.0, 0.0, 0.0, 1.0)),
    );
    let p = shade.params;
    let (r, g, a) = (128.0 / 255.0, 64.0 / 255.0, 51.0 / 255.0);
    assert!((p.clearcoat - 0.75 * r).abs() < 1e-5, "{}", p.clearcoat);
    assert!((p.clearcoat_roughness - 0.5 * g).abs() < 1e-5);
    assert!((p.sheen_roughness - 0.625 * a).abs() < 1e-5);
    let srgb = |c: f32| ((c + 0.055) / 1.055).powf(2.4);
    let want = Vec3::new(srgb(r), 0.5 * srgb(g), 0.25 * srgb(188.0 / 255.0));
    assert!(
        (p.sheen_color - want).abs().max_element() < 2e-3,
        "{}",
        p.sheen_color
    );
    // The coat's normal map: (0.502, 0.251, 0.737) → (0.004, −0.498, 0.475) with the x and y scaled
    // by 0.25, in the frame (T = X, B = Y, N = Z); the base has no normal map.
    assert_eq!(shade.normal, Vec3::Z);
    let tn = Vec3::new(
        (2.0 * r - 1.0) * 0.25,
        (2.0 * g - 1.0) * 0.25,
        2.0 * (188.0 / 255.0) - 1.0,
    )
    .normalize();
    assert!(
        (shade.coat_normal - tn).length() < 1e-5,
        "{}",
        shade.coat_normal
    );
}

#[test]
fn non_finite_or_malformed_layer_values_are_refused() {
    for (path, value, want) in [
        (
            ["KHR_materials_clearcoat", "clearcoatFactor"],
            j("1e39"),
            "non-finite KHR_materials_clearcoat clearcoatFactor",
        ),
        (
            ["KHR_materials_clearcoat", "clearcoatRoughnessFactor"],
            j("-1e39"),
            "non-finite KHR_materials_clearcoat clearcoatRoughnessFactor",
        ),
        (
            ["KHR_materials_sheen", "sheenColorFactor"],
            j("[1, 1e39, 0]"),
            "non-finite KHR_materials_sheen sheenColorFactor",
        ),
        (
            ["KHR_materials_sheen", "sheenRoughnessFactor"],
            j("1e40"),
            "non-finite KHR_materials_sheen sheenRoughnessFactor",
        ),
        (
            ["KHR_materials_sheen", "sheenColorFactor"],
            j("[1, 1]"),
            "KHR_materials_sheen sheenColorFactor is not an array of 3 numbers",
        ),
        (
            ["KHR_materials_clearcoat", "clearcoatFactor"],
            j(r#""much""#),
            "KHR_materials_clearcoat clearcoatFactor is not a number",
        ),
        (
            ["KHR_materials_clearcoat", "clearcoatTexture"],
            j(r#"{"index":7}"#),
            "KHR_materials_clearcoat clearcoatTexture refers to texture 7, but the file has 2 textures",
        ),
        (
            ["KHR_materials_sheen", "sheenRoughnessTexture"],
            j(r#"{"texCoord":0}"#),
            "KHR_materials_sheen sheenRoughnessTexture is not a textureInfo",
        ),
    ] {
        let mut d = layered_doc();
        d.json["materials"][0]["extensions"][path[0]][path[1]] = value;
        let e = error_of(&d.gltf());
        assert_contains(&e, &["material 0 \"car paint\"", want]);
    }
}

/// Photometric intensities become radiometric at 683 lm/W: 6830 cd is 10 W/sr, 2049 lx × 0.5 is
/// 1.5 W/m².
#[test]
fn punctual_lights() {
    let mut d = triangle_doc("{}");
    d.json["extensionsUsed"] = j(r#"["KHR_lights_punctual"]"#);
    d.json["extensions"] = j(r#"{"KHR_lights_punctual":{"lights":[
        {"type":"point","color":[1,0.5,0.25],"intensity":6830,"range":5},
        {"type":"spot","intensity":1366,"spot":{"innerConeAngle":0.2,"outerConeAngle":0.5}},
        {"type":"directional","color":[0.5,0.5,0.5],"intensity":2049}]}}"#);
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let point = d.node(j(
        r#"{"translation":[1,2,3],"extensions":{"KHR_lights_punctual":{"light":0}}}"#,
    ));
    let spot = d.node(j(&format!(
        r#"{{"translation":[0,4,0],"rotation":[-{h},0,0,{h}],"extensions":{{"KHR_lights_punctual":{{"light":1}}}}}}"#
    )));
    let sun = d.node(j(&format!(
        r#"{{"rotation":[0,{h},0,{h}],"extensions":{{"KHR_lights_punctual":{{"light":2}}}}}}"#
    )));
    // The point light's node is a child of a translated parent.
    let parent = d.node(j(&format!(
        r#"{{"translation":[10,0,0],"children":[{point}]}}"#
    )));
    d.root(parent);
    d.root(spot);
    d.root(sun);
    let parts = parts(&d.gltf());
    assert_eq!(parts.punctual_lights.len(), 3);
    match parts.punctual_lights[0] {
        PunctualLight::Point(l) => {
            assert!(close3(l.position, Vec3::new(11.0, 2.0, 3.0)));
            assert!(close3(l.intensity, Vec3::new(10.0, 5.0, 2.5)));
        }
        other => panic!("{other:?}"),
    }
    match parts.punctual_lights[1] {
        PunctualLight::Spot(l) => {
            assert!(close3(l.position, Vec3::new(0.0, 4.0, 0.0)));
            assert!(
                close3(l.direction, Vec3::NEG_Y),
                "spot points down: {}",
                l.direction
            );
            assert!(
                (l.cos_inner - 0.2f32.cos()).abs() < 1e-6
                    && (l.cos_outer - 0.5f32.cos()).abs() < 1e-6
            );
            assert!(close3(l.intensity, Vec3::splat(2.0)));
        }
        other => panic!("{other:?}"),
    }
    match parts.punctual_lights[2] {
        PunctualLight::Directional(l) => {
            assert!(
                close3(l.direction, Vec3::NEG_X),
                "travels along the node's −Z: {}",
                l.direction
            );
            assert!(close3(l.illuminance, Vec3::splat(1.5)));
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(
        parts
            .warnings
            .iter()
            .filter(|w| w.contains("range"))
            .count(),
        1,
        "{:?}",
        parts.warnings
    );
}

#[test]
fn orthographic_camera() {
    let mut d = triangle_doc("{}");
    d.push(
        "cameras",
        j(r#"{"type":"orthographic","orthographic":{"xmag":3,"ymag":2.5,"znear":0.1,"zfar":100}}"#),
    );
    let cam = d.node(j(r#"{"camera":0,"translation":[0,0,5],"scale":[3,3,3]}"#));
    d.root(cam);
    let camera = parts(&d.gltf()).camera.unwrap();
    assert_eq!(
        camera.projection,
        Projection::Orthographic(pathfarm_tracer::camera::Orthographic { ymag: 2.5 })
    );
    assert!(close3(
        camera.to_world.translation.into(),
        Vec3::new(0.0, 0.0, 5.0)
    ));
    assert!(
        close3(camera.to_world.transform_vector3(Vec3::X), Vec3::X),
        "scale stripped"
    );
}

#[test]
fn camera_chosen_by_name() {
    let mut d = triangle_doc("{}");
    d.push(
        "cameras",
        j(r#"{"name":"wide","type":"perspective","perspective":{"yfov":1.2,"znear":0.1}}"#),
    );
    d.push(
        "cameras",
        j(r#"{"name":"tele","type":"perspective","perspective":{"yfov":0.3,"znear":0.1}}"#),
    );
    let a = d.node(j(r#"{"name":"rig_a","camera":0,"translation":[0,0,10]}"#));
    // A scaled, rotated node: the camera keeps only rotation and translation.
    let b = d.node(j(
        r#"{"name":"rig_b","camera":1,"translation":[5,0,0],"rotation":[0,0.7071068,0,0.7071068],
                         "scale":[2,2,2]}"#,
    ));
    d.root(a);
    d.root(b);
    let bytes = d.gltf();
    let yfov = |options: &LoadOptions| {
        let c = load_parts(&bytes, &NoExternalResources, options)
            .unwrap()
            .camera
            .unwrap();
        match c.projection {
            Projection::Perspective(p) => (p.yfov, c),
            other => panic!("{other:?}"),
        }
    };
    assert_eq!(
        yfov(&LoadOptions::default()).0,
        1.2,
        "first in traversal order"
    );
    let (fov, cam) = yfov(&LoadOptions {
        camera: Some("tele".into()),
        ..LoadOptions::default()
    });
    assert_eq!(fov, 0.3);
    let forward = cam.to_world.transform_vector3(Vec3::NEG_Z);
    assert!(close3(forward, Vec3::NEG_X), "{forward}");
    assert!((cam.to_world.matrix3.determinant() - 1.0).abs() < 1e-5);
    assert_eq!(
        yfov(&LoadOptions {
            camera: Some("rig_b".into()),
            ..LoadOptions::default()
        })
        .0,
        0.3,
        "node names match too"
    );
    let e = error_with(
        &bytes,
        &NoExternalResources,
        &LoadOptions {
            camera: Some("nope".into()),
            ..LoadOptions::default()
        },
    );
    assert_contains(
        &e,
        &[
            "camera \"nope\" not found",
            "\"wide\"",
            "\"tele\"",
            "node 2 \"rig_b\"",
        ],
    );
}

#[test]
fn glb_round_trip() {
    let mut d = triangle_doc(r#"{"translation":[0,0,-2]}"#);
    let uv = d.floats(&[[0.0f32, 0.0], [1.0, 0.0], [0.0, 1.0]]);
    d.json["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = Value::from(uv);
    d.json["meshes"][0]["primitives"][0]["material"] = Value::from(0);
    let image = png(1, 2, &[10, 20, 30, 255, 40, 50, 60, 255]);
    let view = d.view(&image, None);
    d.push(
        "images",
        j(&format!(
            r#"{{"bufferView":{view},"mimeType":"image/png"}}"#
        )),
    );
    d.push("textures", j(r#"{"source":0}"#));
    d.push(
        "materials",
        j(r#"{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}"#),
    );
    let (from_gltf, from_glb) = (parts(&d.gltf()), parts(&d.glb()));
    assert_eq!(from_glb.mesh.positions, from_gltf.mesh.positions);
    assert_eq!(from_glb.mesh.uv0, from_gltf.mesh.uv0);
    assert_eq!(from_glb.textures, from_gltf.textures);
    assert_eq!(
        from_glb.textures[0].texels,
        vec![[10, 20, 30, 255], [40, 50, 60, 255]]
    );
    assert_tri(
        from_glb.mesh.positions[0],
        TRI.map(|v| [v[0], v[1], v[2] - 2.0]),
    );
    let scene = load(&d.glb(), &NoExternalResources, &LoadOptions::default()).unwrap();
    assert_eq!(scene.info.triangles, 1);
}

#[test]
fn external_buffer_through_the_resolver() {
    let d = triangle_doc("{}");
    let bytes = d.gltf_external("data/my%20mesh.bin");
    let resolver = MapResolver(HashMap::from([(
        "data/my mesh.bin".to_string(),
        d.bin.clone(),
    )]));
    let parts = load_parts(&bytes, &resolver, &LoadOptions::default()).unwrap();
    assert_tri(parts.mesh.positions[0], TRI);
}

#[test]
fn sparse_accessor_and_quantized_texcoords() {
    let mut d = triangle_doc("{}");
    // Sparse: move vertex 2 to (0, 5, 0).
    let idx = d.view(&[2u8, 0, 0, 0], None);
    let val: Vec<u8> = [0.0f32, 5.0, 0.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let val = d.view(&val, None);
    d.json["accessors"][0]["sparse"] = j(&format!(
        r#"{{"count":1,"indices":{{"bufferView":{idx},"componentType":5121}},"values":{{"bufferView":{val}}}}}"#
    ));
    d.json["accessors"][0]["max"] = j("[1,5,0]");
    // Normalized u16 TEXCOORD_0 with a byte stride.
    let uv_bytes: Vec<u8> = [[0u16, 65535], [65535, 0], [32768, 32768]]
        .iter()
        .flat_map(|p| {
            p.iter()
                .flat_map(|v| v.to_le_bytes())
                .chain([0xAA; 4])
                .collect::<Vec<u8>>()
        })
        .collect();
    let view = d.view(&uv_bytes, Some(8));
    let uv = d.accessor(view, 5123, 3, "VEC2");
    d.json["accessors"][uv]["normalized"] = Value::from(true);
    d.json["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = Value::from(uv);
    d.json["meshes"][0]["primitives"][0]["material"] = Value::from(0);
    let image = png(1, 1, &[1, 2, 3, 4]);
    d.push(
        "images",
        j(&format!(
            r#"{{"uri":"data:image/png;base64,{}"}}"#,
            b64(&image)
        )),
    );
    d.push("textures", j(r#"{"source":0}"#));
    d.push("materials", j(r#"{"emissiveTexture":{"index":0}}"#));
    let parts = parts(&d.gltf());
    assert_tri(
        parts.mesh.positions[0],
        [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 5.0, 0.0]],
    );
    let uv0 = parts.mesh.uv0.unwrap();
    assert_eq!(uv0[0][0], Vec2::new(0.0, 1.0));
    assert_eq!(uv0[0][1], Vec2::new(1.0, 0.0));
    assert!((uv0[0][2].x - 32768.0 / 65535.0).abs() < 1e-7);
}

#[test]
fn required_supported_extensions_load() {
    let mut d = triangle_doc("{}");
    d.json["extensionsUsed"] =
        j(r#"["KHR_materials_specular","KHR_materials_volume","KHR_lights_punctual"]"#);
    d.json["extensionsRequired"] = j(r#"["KHR_materials_specular","KHR_materials_volume"]"#);
    let parts = parts(&d.gltf());
    assert!(parts.warnings.is_empty(), "{:?}", parts.warnings);
}

// ---------------------------------------------------------------------------------------------
// The broken corpus, built here: every error names the object at fault.

#[test]
fn broken_glb_containers() {
    let glb = triangle_doc("{}").glb();
    let e = error_of(&glb[..glb.len() - 10]);
    assert_contains(&e, &["GLB:", "exceeds file size"]);
    let e = error_of(&glb[..9]);
    assert_contains(&e, &["GLB:", "shorter than the 12-byte header"]);
    let mut lying = glb.clone();
    lying[12..16].copy_from_slice(&99999u32.to_le_bytes());
    let e = error_of(&lying);
    assert_contains(
        &e,
        &[&format!(
            "GLB: chunk length 99999 exceeds file size {}",
            glb.len()
        )],
    );
    let mut version = glb.clone();
    version[4] = 1;
    assert_contains(&error_of(&version), &["GLB:", "version 1"]);
    // A BIN chunk shorter than the buffer's byteLength.
    let mut short = glb.clone();
    let json_len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let bin_at = 20 + json_len;
    let bin_len = u32::from_le_bytes(glb[bin_at..bin_at + 4].try_into().unwrap());
    short[bin_at..bin_at + 4].copy_from_slice(&(bin_len - 8).to_le_bytes());
    let n = short.len() - 8;
    short.truncate(n);
    short[8..12].copy_from_slice(&(n as u32).to_le_bytes());
    assert_contains(&error_of(&short), &["buffer 0", "byteLength is 36"]);
}

#[test]
fn broken_json() {
    assert_contains(
        &error_of(br#"{ "asset": "#),
        &["not a glTF file", "invalid glTF JSON"],
    );
    assert_contains(
        &error_of(b"\x89PNG\r\n\x1a\n"),
        &["not a glTF file", "89 50 4e 47"],
    );
    assert_contains(&error_of(b""), &["not a glTF file", "empty"]);
    assert_contains(
        &error_of(br#"{"asset":{"version":"1.0"},"scenes":{}}"#),
        &["not a glTF file", "version 1.0"],
    );
    // Schema violation reported by validation, with its path.
    let mut d = triangle_doc("{}");
    d.json["nodes"][0]["mesh"] = Value::from(7);
    assert_contains(&error_of(&d.gltf()), &["invalid glTF", "nodes[0].mesh"]);
}

#[test]
fn accessor_out_of_bounds() {
    let mut d = triangle_doc("{}");
    d.json["accessors"][0]["count"] = Value::from(4);
    assert_contains(
        &error_of(&d.gltf()),
        &[
            "accessor 0 (POSITION of mesh 0 \"Tri\", primitive 0)",
            "exceeds the 36 bytes of bufferView 0",
        ],
    );
    let mut d = triangle_doc("{}");
    d.json["accessors"][0]["byteOffset"] = Value::from(4);
    assert_contains(
        &error_of(&d.gltf()),
        &[
            "accessor 0 (POSITION of mesh 0 \"Tri\", primitive 0)",
            "byteOffset 4",
        ],
    );
    let mut d = triangle_doc("{}");
    d.json["bufferViews"][0]["byteLength"] = Value::from(40);
    assert_contains(
        &error_of(&d.gltf()),
        &["bufferView 0", "exceeds the 36 bytes of buffer 0"],
    );
    let mut d = triangle_doc("{}");
    d.json["bufferViews"][0]["byteStride"] = Value::from(8);
    assert_contains(
        &error_of(&d.gltf()),
        &[
            "accessor 0",
            "byteStride 8 is smaller than the element size 12",
        ],
    );
    let mut d = triangle_doc("{}");
    d.json["accessors"][0]["type"] = Value::from("VEC2");
    assert_contains(
        &error_of(&d.gltf()),
        &["accessor 0 (POSITION", "type VEC2 where VEC3 is required"],
    );
    // A sparse accessor without a bufferView claiming 20 million zero-filled elements.
    let mut d = triangle_doc("{}");
    let idx = d.view(&[0, 0, 0, 0], None);
    d.json["accessors"][0]["bufferView"] = Value::Null;
    d.json["accessors"][0]["count"] = Value::from(20_000_000);
    d.json["accessors"][0]["sparse"] = j(&format!(
        r#"{{"count":1,"indices":{{"bufferView":{idx},"componentType":5121}},"values":{{"bufferView":0}}}}"#
    ));
    assert_contains(
        &error_of(&d.gltf()),
        &[
            "accessor 0 (POSITION",
            "count 20000000 without a bufferView",
        ],
    );
    let mut d = triangle_doc("{}");
    d.json["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = Value::from(9);
    assert_contains(
        &error_of(&d.gltf()),
        &["mesh 0 \"Tri\", primitive 0: POSITION refers to accessor 9"],
    );
}

#[test]
fn index_out_of_range() {
    let mut d = triangle_doc("{}");
    let i = d.indices(&[0, 1, 7], 5123);
    d.json["meshes"][0]["primitives"][0]["indices"] = Value::from(i);
    assert_contains(
        &error_of(&d.gltf()),
        &["mesh 0 \"Tri\", primitive 0: index 7 out of range (accessor 0 has 3 vertices)"],
    );
}

#[test]
fn missing_external_buffer() {
    let d = triangle_doc("{}");
    let bytes = d.gltf_external("scene.bin");
    let e = error_with(&bytes, &NoExternalResources, &LoadOptions::default());
    assert_contains(&e, &["buffer 0: cannot read \"scene.bin\"", "not allowed"]);
    let e = error_with(
        &bytes,
        &MapResolver(HashMap::new()),
        &LoadOptions::default(),
    );
    assert_contains(&e, &["buffer 0: cannot read \"scene.bin\": No such file"]);
    let mut d = triangle_doc("{}");
    d.json["buffers"] =
        j(r#"[{"byteLength":36,"uri":"data:application/octet-stream;base64,@@@@"}]"#);
    let bytes = gltf::json::serialize::to_vec(&d.json).unwrap();
    assert_contains(
        &error_of(&bytes),
        &["buffer 0: bad data URI: invalid base64"],
    );
    // A buffer without a uri outside a GLB.
    let no_uri = gltf::json::serialize::to_vec(&d.finished_json(None)).unwrap();
    assert_contains(
        &error_of(&no_uri),
        &["buffer 0: has no uri and the file has no GLB BIN chunk"],
    );
}

#[test]
fn unsupported_required_extension() {
    let mut d = triangle_doc("{}");
    d.json["extensionsUsed"] = j(r#"["KHR_texture_basisu"]"#);
    d.json["extensionsRequired"] = j(r#"["KHR_texture_basisu"]"#);
    assert_contains(
        &error_of(&d.gltf()),
        &["required extension KHR_texture_basisu is not supported"],
    );
    // Merely used: one warning.
    d.json["extensionsRequired"] = j("[]");
    let parts = parts(&d.gltf());
    assert_eq!(
        parts.warnings,
        vec!["extension KHR_texture_basisu is not supported; ignored".to_string()]
    );
}

#[test]
fn nan_positions() {
    let mut d = Doc::new();
    let p = d.positions(&[[0.0, 0.0, 0.0], [f32::NAN, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    d.mesh(
        "Box",
        j(&format!(r#"[{{"attributes":{{"POSITION":{p}}}}}]"#)),
    );
    let n = d.node(j(r#"{"mesh":0}"#));
    d.root(n);
    assert_contains(
        &error_of(&d.gltf()),
        &["accessor 0 (POSITION of mesh 0 \"Box\", primitive 0): NaN component at element 1"],
    );
    let mut d2 = Doc::new();
    let p = d2.positions(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, f32::INFINITY, 0.0]]);
    d2.mesh(
        "Box",
        j(&format!(r#"[{{"attributes":{{"POSITION":{p}}}}}]"#)),
    );
    let n = d2.node(j(r#"{"mesh":0}"#));
    d2.root(n);
    assert_contains(&error_of(&d2.gltf()), &["infinite component at element 2"]);
}

#[test]
fn degenerate_triangles_are_dropped_as_they_are_read() {
    // One real triangle, a collinear one and a point; the mesh instanced twice, once flattened to
    // a line by a zero scale.
    let mut d = Doc::new();
    let p = d.positions(&[
        TRI[0],
        TRI[1],
        TRI[2],
        [0.0, 0.0, 0.0],
        [1.0, 1.0, 1.0],
        [2.0, 2.0, 2.0],
        [5.0, 5.0, 5.0],
        [5.0, 5.0, 5.0],
        [5.0, 5.0, 5.0],
    ]);
    d.mesh(
        "Mixed",
        j(&format!(r#"[{{"attributes":{{"POSITION":{p}}}}}]"#)),
    );
    let a = d.node(j(r#"{"mesh":0}"#));
    d.root(a);
    let b = d.node(j(r#"{"mesh":0,"scale":[1,0,1]}"#));
    d.root(b);
    // Placed twice, the mesh is kept instanced: its two degenerate triangles are dropped once,
    // and the placement that flattens it is dropped at build, its triangle counted as dropped.
    let loaded = parts(&d.gltf());
    assert_eq!(loaded.mesh.len(), 0);
    assert_eq!(loaded.prototypes.len(), 1);
    assert_eq!(
        loaded.prototypes[0].len(),
        1,
        "only the real triangle is kept"
    );
    assert_eq!(loaded.degenerate_dropped, 2);
    let scene = load(&d.gltf(), &NoExternalResources, &LoadOptions::default()).expect("loads");
    assert_eq!(
        (
            scene.info.triangles,
            scene.info.degenerate_dropped,
            scene.info.instances
        ),
        (1, 3, 1)
    );
    // Flattened, as the loader flattens a mesh placed once: the zero scale collapses the real
    // triangle of the second copy.
    let flat = Scene::build(loaded.flatten_instances()).expect("builds");
    assert_eq!((flat.info.triangles, flat.info.degenerate_dropped), (1, 3));

    // Nothing but degenerate triangles: an error, not an empty scene. Instancing makes 100 × 2
    // triangles out of two.
    let mut d = Doc::new();
    let p = d.positions(&[[0.0; 3], [1.0; 3], [2.0; 3], [4.0; 3], [4.0; 3], [4.0; 3]]);
    d.mesh(
        "Flat",
        j(&format!(r#"[{{"attributes":{{"POSITION":{p}}}}}]"#)),
    );
    for _ in 0..100 {
        let n = d.node(j(r#"{"mesh":0}"#));
        d.root(n);
    }
    assert_contains(
        &error_of(&d.gltf()),
        &["all 2 triangles of the scene are degenerate"],
    );
    // The declared count is checked from the JSON before anything is read: 100 placements of a
    // mesh of two triangles kept instanced store two, against a limit of 1.
    let options = LoadOptions {
        max_triangles: 1,
        ..LoadOptions::default()
    };
    assert_contains(
        &error_with(&d.gltf(), &NoExternalResources, &options),
        &["the scene declares 2 triangles to store (100 mesh instances; 1 instanced meshes stored once), over the limit of 1"],
    );
    // An emissive mesh is flattened however often it is placed: 200 triangles to store.
    d.json["materials"] = j(r#"[{"emissiveFactor":[1,1,1]}]"#);
    d.json["meshes"][0]["primitives"][0]["material"] = Value::from(0);
    let options = LoadOptions {
        max_triangles: 199,
        ..LoadOptions::default()
    };
    assert_contains(
        &error_with(&d.gltf(), &NoExternalResources, &options),
        &["the scene declares 200 triangles to store (100 mesh instances; 0 instanced meshes stored once), over the limit of 199"],
    );
}

/// A PNG whose IHDR claims `width × height` (valid CRCs, an empty IDAT: no image data).
fn png_header_only(width: u32, height: u32) -> Vec<u8> {
    fn crc32(data: &[u8]) -> u32 {
        let mut crc = 0xFFFF_FFFFu32;
        for &b in data {
            crc ^= b as u32;
            for _ in 0..8 {
                crc = if crc & 1 != 0 {
                    (crc >> 1) ^ 0xEDB8_8320
                } else {
                    crc >> 1
                };
            }
        }
        !crc
    }
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut chunk = b"IHDR".to_vec();
    chunk.extend(width.to_be_bytes());
    chunk.extend(height.to_be_bytes());
    chunk.extend([8, 6, 0, 0, 0]);
    out.extend(13u32.to_be_bytes());
    out.extend(&chunk);
    out.extend(crc32(&chunk).to_be_bytes());
    out.extend(0u32.to_be_bytes());
    out.extend(b"IDAT");
    out.extend(crc32(b"IDAT").to_be_bytes());
    out.extend(0u32.to_be_bytes());
    out.extend(b"IEND");
    out.extend(crc32(b"IEND").to_be_bytes());
    out
}

fn textured_doc(image_bytes: &[u8]) -> Doc {
    let mut d = triangle_doc("{}");
    d.json["meshes"][0]["primitives"][0]["material"] = Value::from(0);
    let view = d.view(image_bytes, None);
    d.push(
        "images",
        j(&format!(
            r#"{{"name":"tex","bufferView":{view},"mimeType":"image/png"}}"#
        )),
    );
    d.push("textures", j(r#"{"source":0}"#));
    d.push(
        "materials",
        j(r#"{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}"#),
    );
    d
}

#[test]
fn images_that_fail_to_decode() {
    let mut broken = png(2, 2, &[7; 16]);
    let n = broken.len();
    broken.truncate(n - 20);
    assert_contains(
        &error_of(&textured_doc(&broken).gltf()),
        &["image 0 \"tex\": cannot decode"],
    );
    assert_contains(
        &error_of(&textured_doc(b"not an image at all").gltf()),
        &["image 0 \"tex\": cannot decode", "not a PNG, JPEG or WebP"],
    );
    assert_contains(
        &error_of(&textured_doc(b"GIF89a\x01\x00\x01\x00").gltf()),
        &["image 0 \"tex\": cannot decode"],
    );
    // A decompression bomb header: refused by the limits, not attempted.
    let bomb = png_header_only(100_000, 100_000);
    assert_contains(
        &error_of(&textured_doc(&bomb).gltf()),
        &["image 0 \"tex\": cannot decode"],
    );
    // Within the largest side, but over the decoded size: refused from the header.
    let wide = png_header_only(16384, 8192);
    assert_contains(
        &error_of(&textured_doc(&wide).gltf()),
        &[
            "image 0 \"tex\"",
            "16384×8192 decodes to 512 MiB",
            "limit of 256 MiB",
        ],
    );
}

#[test]
fn camera_name_not_found() {
    let mut d = triangle_doc("{}");
    d.push(
        "cameras",
        j(r#"{"name":"main","type":"perspective","perspective":{"yfov":1,"znear":0.1}}"#),
    );
    let c = d.node(j(r#"{"camera":0}"#));
    d.root(c);
    let e = error_with(
        &d.gltf(),
        &NoExternalResources,
        &LoadOptions {
            camera: Some("other".into()),
            ..LoadOptions::default()
        },
    );
    assert_contains(
        &e,
        &["camera \"other\" not found", "camera 0 \"main\" on node 1"],
    );
    let plain = triangle_doc("{}");
    let e = error_with(
        &plain.gltf(),
        &NoExternalResources,
        &LoadOptions {
            camera: Some("x".into()),
            ..LoadOptions::default()
        },
    );
    assert_contains(&e, &["camera \"x\" not found; the scene's cameras: none"]);
}

#[test]
fn cyclic_and_shared_nodes() {
    let mut d = triangle_doc("{}");
    d.json["nodes"][0]["children"] = j("[1]");
    d.node(j(r#"{"children":[0]}"#));
    assert_contains(&error_of(&d.gltf()), &["node 0", "reached twice"]);
    // A long chain does not overflow the stack.
    let mut d = triangle_doc("{}");
    let depth = 20_000;
    for k in 1..depth {
        d.node(j("{}"));
        d.json["nodes"][k - 1]["children"] = Value::Array(vec![Value::from(k)]);
    }
    assert_eq!(parts(&d.gltf()).mesh.len(), 1);
}

// ---------------------------------------------------------------------------------------------
// The committed corpus (tests/data/gltf): `valid/` files load, `broken/` files fail with the
// substrings listed in their `.expect` files. `regenerate_corpus` (ignored) rewrites them.

fn corpus_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf")
}

fn corpus_files() -> Vec<(String, Vec<u8>, Option<Vec<String>>)> {
    let mut out: Vec<(String, Vec<u8>, Option<Vec<String>>)> = Vec::new();
    // Valid.
    let mut lit = textured_doc(&png(2, 2, &[200; 16]));
    lit.json["extensionsUsed"] = j(r#"["KHR_lights_punctual"]"#);
    lit.json["extensions"] =
        j(r#"{"KHR_lights_punctual":{"lights":[{"type":"point","intensity":5}]}}"#);
    let l = lit.node(j(
        r#"{"translation":[0,0,2],"extensions":{"KHR_lights_punctual":{"light":0}}}"#,
    ));
    lit.root(l);
    lit.push(
        "cameras",
        j(r#"{"name":"cam","type":"perspective","perspective":{"yfov":0.8,"znear":0.1}}"#),
    );
    let c = lit.node(j(r#"{"camera":0,"translation":[0.3,0.3,3]}"#));
    lit.root(c);
    out.push(("valid/textured_lit.gltf".into(), lit.gltf(), None));
    out.push(("valid/textured_lit.glb".into(), lit.glb(), None));
    // Broken.
    let glb = lit.glb();
    let expect = |v: &[&str]| Some(v.iter().map(|s| s.to_string()).collect());
    out.push((
        "broken/truncated.glb".into(),
        glb[..glb.len() / 2].to_vec(),
        expect(&["GLB:", "exceeds file size"]),
    ));
    let mut lying = glb.clone();
    lying[12..16].copy_from_slice(&99999u32.to_le_bytes());
    out.push((
        "broken/lying_chunk_length.glb".into(),
        lying,
        expect(&["GLB: chunk length 99999 exceeds file size"]),
    ));
    out.push((
        "broken/bad_json.gltf".into(),
        br#"{"asset":{"version":"2.0"},"nodes":[{]}"#.to_vec(),
        expect(&["not a glTF file"]),
    ));
    let mut oob = triangle_doc("{}");
    oob.json["accessors"][0]["count"] = Value::from(30);
    out.push((
        "broken/accessor_out_of_bounds.gltf".into(),
        oob.gltf(),
        expect(&[
            "accessor 0 (POSITION of mesh 0 \"Tri\", primitive 0)",
            "exceeds",
        ]),
    ));
    let mut idx = triangle_doc("{}");
    let i = idx.indices(&[0, 1, 812], 5123);
    idx.json["meshes"][0]["primitives"][0]["indices"] = Value::from(i);
    out.push((
        "broken/index_out_of_range.gltf".into(),
        idx.gltf(),
        expect(&["index 812 out of range (accessor 0 has 3 vertices)"]),
    ));
    out.push((
        "broken/missing_buffer.gltf".into(),
        triangle_doc("{}").gltf_external("missing.bin"),
        expect(&["buffer 0: cannot read \"missing.bin\""]),
    ));
    let mut basisu = triangle_doc("{}");
    basisu.json["extensionsRequired"] = j(r#"["KHR_texture_basisu"]"#);
    basisu.json["extensionsUsed"] = j(r#"["KHR_texture_basisu"]"#);
    out.push((
        "broken/required_basisu.gltf".into(),
        basisu.gltf(),
        expect(&["required extension KHR_texture_basisu is not supported"]),
    ));
    let mut nan = Doc::new();
    let p = nan.positions(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, f32::NAN, 0.0]]);
    nan.mesh(
        "Box",
        j(&format!(r#"[{{"attributes":{{"POSITION":{p}}}}}]"#)),
    );
    let n = nan.node(j(r#"{"mesh":0}"#));
    nan.root(n);
    out.push((
        "broken/nan_position.gltf".into(),
        nan.gltf(),
        expect(&[
            "accessor 0 (POSITION of mesh 0 \"Box\", primitive 0): NaN component at element 2",
        ]),
    ));
    let mut b64bad = triangle_doc("{}");
    b64bad.json["buffers"] =
        j(r#"[{"byteLength":36,"uri":"data:application/octet-stream;base64,#not-base64#"}]"#);
    out.push((
        "broken/bad_base64.gltf".into(),
        gltf::json::serialize::to_vec(&b64bad.json).unwrap(),
        expect(&["buffer 0: bad data URI"]),
    ));
    out.push((
        "broken/bad_image.gltf".into(),
        textured_doc(b"\x89PNG\r\n\x1a\nnot really").gltf(),
        expect(&["image 0 \"tex\": cannot decode"]),
    ));
    out
}

#[test]
#[ignore = "rewrites tests/data/gltf from the generator above"]
fn regenerate_corpus() {
    for (name, bytes, expect) in corpus_files() {
        let path = corpus_dir().join(&name);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, bytes).unwrap();
        if let Some(expect) = expect {
            std::fs::write(path.with_extension("expect"), expect.join("\n") + "\n").unwrap();
        }
    }
}

#[test]
fn committed_corpus() {
    let dir = corpus_dir();
    let mut seen = 0;
    for sub in ["valid", "broken"] {
        let mut entries: Vec<PathBuf> = std::fs::read_dir(dir.join(sub))
            .unwrap_or_else(|e| panic!("{}: {e}", dir.join(sub).display()))
            .map(|e| e.unwrap().path())
            .filter(|p| matches!(p.extension().and_then(|e| e.to_str()), Some("gltf" | "glb")))
            .collect();
        entries.sort();
        for path in entries {
            seen += 1;
            let bytes = std::fs::read(&path).unwrap();
            let result = load(&bytes, &NoExternalResources, &LoadOptions::default());
            match (sub, result) {
                ("valid", Ok(scene)) => assert!(scene.info.triangles > 0, "{}", path.display()),
                ("valid", Err(e)) => panic!("{}: {e}", path.display()),
                (_, Ok(_)) => panic!("{} loaded but should fail", path.display()),
                (_, Err(GltfError::Internal(e))) => {
                    panic!("{}: internal error {e}", path.display())
                }
                (_, Err(e)) => {
                    let expect = std::fs::read_to_string(path.with_extension("expect")).unwrap();
                    for line in expect.lines().filter(|l| !l.is_empty()) {
                        assert!(
                            e.to_string().contains(line),
                            "{}: {e:?} lacks {line:?}",
                            path.display()
                        );
                    }
                }
            }
        }
    }
    assert_eq!(
        seen,
        corpus_files().len(),
        "the committed corpus is stale: run the ignored regenerate_corpus test"
    );
}

// ---------------------------------------------------------------------------------------------
// Fuzzing: mutated files load or fail, never panic.

/// Iterations per fuzz test: `GLTF_FUZZ_ITERATIONS` (default 3000) — raise it for a longer hunt.
fn fuzz_iterations() -> usize {
    std::env::var("GLTF_FUZZ_ITERATIONS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3000)
}

struct XorShift(u64);

impl XorShift {
    fn next(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.0 = x;
        x
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

fn mutate(rng: &mut XorShift, input: &[u8]) -> Vec<u8> {
    let mut b = input.to_vec();
    for _ in 0..1 + rng.below(4) {
        if b.is_empty() {
            break;
        }
        let at = rng.below(b.len());
        match rng.below(7) {
            0 => b[at] = rng.next() as u8,
            1 => b[at] ^= 1 << rng.below(8),
            2 => b.truncate(at),
            3 => {
                let v = [0u32, 1, 0xFFFF_FFFF, 0x7FFF_FFFF, 99999, rng.next() as u32][rng.below(6)];
                for (k, byte) in v.to_le_bytes().iter().enumerate() {
                    if let Some(slot) = b.get_mut(at + k) {
                        *slot = *byte;
                    }
                }
            }
            4 => {
                // Change a digit in JSON text: valid JSON with wrong numbers.
                if let Some(pos) = (0..64)
                    .map(|k| (at + k) % b.len())
                    .find(|&p| b[p].is_ascii_digit())
                {
                    b[pos] = b"0123456789"[rng.below(10)];
                }
            }
            5 => {
                if let Some(pos) = (0..64)
                    .map(|k| (at + k) % b.len())
                    .find(|&p| b[p].is_ascii_digit())
                {
                    let ins: &[u8] = [&b"9"[..], b"0", b"-", b"e9", b"99999"][rng.below(5)];
                    b.splice(pos..pos, ins.iter().copied());
                }
            }
            _ => b.insert(at, rng.next() as u8),
        }
    }
    b
}

fn fuzz(seed: u64, input: &[u8], iterations: usize) -> (usize, usize) {
    let mut rng = XorShift(seed);
    let (mut ok, mut err) = (0, 0);
    for k in 0..iterations {
        let bytes = mutate(&mut rng, input);
        let outcome = std::panic::catch_unwind(|| {
            load(&bytes, &NoExternalResources, &LoadOptions::default())
        });
        match outcome {
            Ok(Ok(_)) => ok += 1,
            Ok(Err(GltfError::Internal(e))) => {
                panic!("iteration {k}: the loader panicked internally: {e}")
            }
            Ok(Err(_)) => err += 1,
            Err(_) => panic!("iteration {k}: load panicked"),
        }
    }
    eprintln!("fuzz seed {seed:#x}: {ok} loaded, {err} refused");
    (ok, err)
}

fn fuzz_seed_doc() -> Doc {
    let mut d = textured_doc(&png(2, 2, &[90; 16]));
    let n = d.floats(&[[0.0f32, 0.0, 1.0]; 3]);
    let uv = d.floats(&[[0.0f32, 0.0], [1.0, 0.0], [0.0, 1.0]]);
    let i = d.indices(&[0, 1, 2], 5123);
    let prim = &mut d.json["meshes"][0]["primitives"][0];
    prim["attributes"]["NORMAL"] = Value::from(n);
    prim["attributes"]["TEXCOORD_0"] = Value::from(uv);
    prim["indices"] = Value::from(i);
    d.json["materials"][0]["normalTexture"] = j(r#"{"index":0}"#);
    d.json["extensionsUsed"] = j(r#"["KHR_lights_punctual"]"#);
    d.json["extensions"] =
        j(r#"{"KHR_lights_punctual":{"lights":[{"type":"spot","spot":{"outerConeAngle":0.5}}]}}"#);
    let l = d.node(j(
        r#"{"translation":[0,0,2],"extensions":{"KHR_lights_punctual":{"light":0}}}"#,
    ));
    d.json["nodes"][0]["children"] = Value::Array(vec![Value::from(l)]);
    d.push(
        "cameras",
        j(r#"{"type":"perspective","perspective":{"yfov":0.8,"znear":0.1}}"#),
    );
    let c = d.node(j(r#"{"camera":0,"translation":[0,0,3]}"#));
    d.root(c);
    d
}

#[test]
fn fuzz_glb_never_panics() {
    let glb = fuzz_seed_doc().glb();
    assert!(load(&glb, &NoExternalResources, &LoadOptions::default()).is_ok());
    let n = fuzz_iterations();
    let (ok, err) = fuzz(0x9E37_79B9_7F4A_7C15, &glb, n);
    assert!(err > 0 && ok + err == n, "ok {ok}, err {err}");
}

#[test]
fn fuzz_gltf_never_panics() {
    let gltf = fuzz_seed_doc().gltf();
    assert!(load(&gltf, &NoExternalResources, &LoadOptions::default()).is_ok());
    let n = fuzz_iterations();
    let (ok, err) = fuzz(0xD1B5_4A32_D192_ED03, &gltf, n);
    assert!(err > 0 && ok + err == n, "ok {ok}, err {err}");
}

/// Structure-aware mutations: valid JSON with wrong numbers, missing keys, and corrupted binary data,
/// so that the fuzz loop reaches accessors, materials, textures and the scene build.
fn mutate_structured(rng: &mut XorShift, doc: &Doc) -> Vec<u8> {
    /// Calls `f` on the `target`-th node (pre-order) for which `pick` holds, counting them in `seen`.
    fn walk(
        v: &mut Value,
        pick: fn(&Value) -> bool,
        target: usize,
        seen: &mut usize,
        f: &mut dyn FnMut(&mut Value),
    ) {
        if pick(v) {
            if *seen == target {
                f(v);
            }
            *seen += 1;
        }
        match v {
            Value::Array(a) => a.iter_mut().for_each(|x| walk(x, pick, target, seen, f)),
            Value::Object(o) => o.values_mut().for_each(|x| walk(x, pick, target, seen, f)),
            _ => {}
        }
    }
    fn count(v: &mut Value, pick: fn(&Value) -> bool) -> usize {
        let mut seen = 0;
        walk(v, pick, usize::MAX, &mut seen, &mut |_| {});
        seen
    }
    let mut d = doc.clone();
    for _ in 0..1 + rng.below(3) {
        match rng.below(4) {
            0 | 1 => {
                let specials: [f64; 16] = [
                    0.0,
                    1.0,
                    -1.0,
                    2.0,
                    3.0,
                    7.0,
                    255.0,
                    65535.0,
                    1e9,
                    4294967295.0,
                    0.5,
                    1e38,
                    -1e38,
                    5121.0,
                    5125.0,
                    1e300,
                ];
                let value = if rng.below(4) == 0 {
                    (rng.next() % 100_000) as f64
                } else {
                    specials[rng.below(specials.len())]
                };
                let new = if value.fract() == 0.0 && value.abs() < 1e15 {
                    Value::from(value as i64)
                } else {
                    Value::from(value)
                };
                let n = count(&mut d.json, Value::is_number);
                let target = rng.below(n);
                walk(&mut d.json, Value::is_number, target, &mut 0, &mut |v| {
                    *v = new.clone()
                });
            }
            2 => {
                let n = count(&mut d.json, Value::is_object);
                let target = rng.below(n);
                let key_pick = rng.next() as usize;
                walk(&mut d.json, Value::is_object, target, &mut 0, &mut |v| {
                    if let Value::Object(o) = v {
                        if let Some(key) = o.keys().nth(key_pick % o.len().max(1)).cloned() {
                            o.remove(&key);
                        }
                    }
                });
            }
            _ => {
                if !d.bin.is_empty() {
                    for _ in 0..1 + rng.below(8) {
                        let at = rng.below(d.bin.len());
                        d.bin[at] = [0x00, 0xFF, 0x7F, 0xC0, rng.next() as u8][rng.below(5)];
                    }
                }
            }
        }
    }
    if rng.below(2) == 0 {
        d.glb()
    } else {
        d.gltf()
    }
}

#[test]
fn fuzz_structured_never_panics() {
    let doc = fuzz_seed_doc();
    let mut rng = XorShift(0x2545_F491_4F6C_DD1D);
    let (mut ok, mut err) = (0, 0);
    let mut kinds: HashMap<&'static str, usize> = HashMap::new();
    for k in 0..fuzz_iterations() {
        let bytes = mutate_structured(&mut rng, &doc);
        let outcome = std::panic::catch_unwind(|| {
            load(&bytes, &NoExternalResources, &LoadOptions::default())
        });
        match outcome {
            Ok(Ok(_)) => ok += 1,
            Ok(Err(GltfError::Internal(e))) => {
                panic!("iteration {k}: the loader panicked internally: {e}")
            }
            Ok(Err(e)) => {
                err += 1;
                let kind = match e {
                    GltfError::NotGltf(_) => "not-gltf",
                    GltfError::Glb(_) => "glb",
                    GltfError::Invalid(_) => "invalid",
                    GltfError::UnsupportedExtension(_) => "extension",
                    GltfError::Resource { .. } => "resource",
                    GltfError::Data { .. } => "data",
                    GltfError::Image { .. } => "image",
                    GltfError::Object { .. } => "object",
                    GltfError::CameraNotFound { .. } => "camera",
                    GltfError::Limit(_) => "limit",
                    GltfError::Scene(_) => "scene",
                    _ => "other",
                };
                *kinds.entry(kind).or_default() += 1;
            }
            Err(_) => panic!("iteration {k}: load panicked"),
        }
    }
    eprintln!("structured fuzz: {ok} loaded, {err} refused: {kinds:?}");
    assert!(
        ok > 100 && kinds.len() >= 4,
        "the mutations should reach deep into the loader"
    );
}

// ---------------------------------------------------------------------------------------------
// Compression and texture extensions that web pipelines write: KHR_mesh_quantization,
// EXT_meshopt_compression (and KHR_meshopt_compression), KHR_draco_mesh_compression,
// EXT_texture_webp. Files made by real exporters are under `tests/data/gltf/ext/` (see its README).

fn ext_file(name: &str) -> Vec<u8> {
    let path = corpus_dir().join("ext").join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Asserts that `got` has the triangles of `want` (in any order, each with its corners in any
/// rotation that keeps the winding), corners within `tol`, and normals (when `normal_tol` is given)
/// within it.
fn assert_same_triangles(got: &SceneParts, want: &SceneParts, tol: f32, normal_tol: Option<f32>) {
    assert_eq!(got.mesh.len(), want.mesh.len(), "triangle count");
    let mut used = vec![false; got.mesh.len()];
    for (w, wt) in want.mesh.positions.iter().enumerate() {
        let found = got.mesh.positions.iter().enumerate().find_map(|(g, gt)| {
            if used[g] {
                return None;
            }
            (0..3)
                .find(|&r| (0..3).all(|k| (gt[(k + r) % 3] - wt[k]).abs().max_element() <= tol))
                .map(|r| (g, r))
        });
        let Some((g, r)) = found else {
            panic!("triangle {w} {wt:?} has no match within {tol}");
        };
        used[g] = true;
        if let Some(nt) = normal_tol {
            let (gn, wn) = (
                &got.mesh.normals.as_ref().unwrap()[g],
                &want.mesh.normals.as_ref().unwrap()[w],
            );
            for k in 0..3 {
                assert!(
                    (gn[(k + r) % 3] - wn[k]).length() <= nt,
                    "triangle {w} corner {k}: normal {:?}, want {:?}",
                    gn[(k + r) % 3],
                    wn[k]
                );
            }
        }
    }
}

#[test]
fn mesh_quantization_integer_attributes() {
    // KHR_mesh_quantization: SHORT positions (not normalized, scaled by the node), normalized BYTE
    // normals and tangents, normalized UNSIGNED_BYTE texture coordinates, each 4-byte aligned.
    let mut d = Doc::new();
    d.json["extensionsUsed"] = j(r#"["KHR_mesh_quantization"]"#);
    d.json["extensionsRequired"] = j(r#"["KHR_mesh_quantization"]"#);
    let pos: Vec<u8> = [[0i16, 0, 0], [1000, 0, 0], [0, -1000, 0]]
        .iter()
        .flat_map(|p| {
            p.iter()
                .flat_map(|v| v.to_le_bytes())
                .chain([0, 0])
                .collect::<Vec<u8>>()
        })
        .collect();
    let view = d.view(&pos, Some(8));
    let p = d.accessor(view, 5122, 3, "VEC3");
    d.json["accessors"][p]["min"] = j("[0,-1000,0]");
    d.json["accessors"][p]["max"] = j("[1000,0,0]");
    let normals: Vec<u8> = [[0i8, 0, 127, 0], [0, 0, -127, 0], [-128, 0, 0, 0]]
        .iter()
        .flatten()
        .map(|&v| v as u8)
        .collect();
    let view = d.view(&normals, Some(4));
    let n = d.accessor(view, 5120, 3, "VEC3");
    d.json["accessors"][n]["normalized"] = Value::from(true);
    let tangents: Vec<u8> = [[127i8, 0, 0, 127], [0, 127, 0, -127], [0, 0, 127, 127]]
        .iter()
        .flatten()
        .map(|&v| v as u8)
        .collect();
    let view = d.view(&tangents, None);
    let t = d.accessor(view, 5120, 3, "VEC4");
    d.json["accessors"][t]["normalized"] = Value::from(true);
    let view = d.view(&[0, 255, 0, 0, 255, 0, 0, 0, 51, 102, 0, 0], Some(4));
    let uv = d.accessor(view, 5121, 3, "VEC2");
    d.json["accessors"][uv]["normalized"] = Value::from(true);
    d.mesh(
        "Quantized",
        j(&format!(
            r#"[{{"attributes":{{"POSITION":{p},"NORMAL":{n},"TANGENT":{t},"TEXCOORD_0":{uv}}},"material":0}}]"#
        )),
    );
    let image = d.view(&png(1, 1, &[128, 128, 255, 255]), None);
    d.push(
        "images",
        j(&format!(
            r#"{{"bufferView":{image},"mimeType":"image/png"}}"#
        )),
    );
    d.push("textures", j(r#"{"source":0}"#));
    d.push("materials", j(r#"{"normalTexture":{"index":0}}"#));
    let node = d.node(j(r#"{"mesh":0,"scale":[0.001,0.001,0.001]}"#));
    d.root(node);
    let parts = parts(&d.gltf());
    assert_tri(
        parts.mesh.positions[0],
        [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]],
    );
    let normals = parts.mesh.normals.as_ref().unwrap()[0];
    assert!(close3(normals[0], Vec3::Z) && close3(normals[1], -Vec3::Z));
    assert!(
        close3(normals[2], -Vec3::X),
        "-128 clamps to -1: {:?}",
        normals[2]
    );
    let tangents = parts.mesh.tangents.as_ref().unwrap()[0];
    assert_eq!(tangents[0], Vec4::new(1.0, 0.0, 0.0, 1.0));
    assert_eq!(tangents[1], Vec4::new(0.0, 1.0, 0.0, -1.0));
    let uv0 = parts.mesh.uv0.as_ref().unwrap()[0];
    assert_eq!(uv0[0], Vec2::new(0.0, 1.0));
    assert_eq!(uv0[1], Vec2::new(1.0, 0.0));
    assert!(
        (uv0[2] - Vec2::new(0.2, 0.4)).abs().max_element() < 1e-6,
        "{:?}",
        uv0[2]
    );
}

#[test]
fn meshopt_files_from_gltfpack_match_the_source() {
    // gltfpack's output (EXT_meshopt_compression; see tests/data/gltf/ext/README.md) against the
    // uncompressed source it was made from.
    let source = parts(&ext_file("source.glb"));
    assert_eq!(source.mesh.len(), 128);
    // Float attributes, no quantization: the same triangles (reordered by gltfpack) exactly.
    let noq = parts(&ext_file("meshopt_noq.glb"));
    assert_same_triangles(&noq, &source, 0.0, Some(1e-6));
    assert!(noq.warnings.is_empty(), "{:?}", noq.warnings);
    // 14-bit integer positions, OCTAHEDRAL-filtered 8-bit normals, TRIANGLES-coded indices.
    let cc = parts(&ext_file("meshopt_cc.glb"));
    assert_same_triangles(&cc, &source, 2.0 / 16383.0, Some(0.02));
    // EXPONENTIAL-filtered float positions.
    let vpf = parts(&ext_file("meshopt_vpf.glb"));
    assert_same_triangles(&vpf, &source, 2.0 / 16383.0, Some(0.02));
    // KHR_meshopt_compression (the ratified successor; vertex codec version 1).
    let khr = parts(&ext_file("meshopt_khr.glb"));
    assert_same_triangles(&khr, &source, 2.0 / 16383.0, Some(0.02));
    // With an uncompressed fallback buffer (an external file that is not there): never read.
    let fallback = parts(&ext_file("meshopt_fallback.glb"));
    assert_same_triangles(&fallback, &source, 2.0 / 16383.0, Some(0.02));
}

/// A document whose one triangle primitive (mesh "Packed") reads POSITION and indices from
/// meshopt-compressed views made by the `meshoptimizer-rs` encoder, over a fallback buffer with no
/// data. Returns the document and the uncompressed positions and indices.
fn meshopt_doc(index_mode: &str) -> (Doc, Vec<[f32; 3]>, Vec<u32>) {
    use meshoptimizer_rs::codec;
    use meshoptimizer_rs::Workspace;
    let n = 10;
    let positions: Vec<[f32; 3]> = (0..n * n)
        .map(|i| [(i % n) as f32, (i / n) as f32, ((i * 7) % 5) as f32 * 0.25])
        .collect();
    let mut indices = Vec::new();
    for y in 0..n - 1 {
        for x in 0..n - 1 {
            let a = (y * n + x) as u32;
            indices.extend([
                a,
                a + 1,
                a + n as u32 + 1,
                a,
                a + n as u32 + 1,
                a + n as u32,
            ]);
        }
    }
    let mut ws = Workspace::default();
    let raw: Vec<u8> = positions
        .iter()
        .flatten()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let vertices = codec::encode_vertex_buffer(
        &raw,
        positions.len(),
        12,
        codec::VertexEncoding::new(0, 0).unwrap(),
        &mut ws,
    )
    .unwrap();
    let encoded_indices = match index_mode {
        "TRIANGLES" => {
            codec::encode_index_buffer_generic(&indices, codec::IndexEncoding::DEFAULT, &mut ws)
        }
        _ => codec::encode_index_sequence_generic(&indices, codec::IndexEncoding::DEFAULT, &mut ws),
    }
    .unwrap();
    let mut d = Doc::new();
    d.json["extensionsUsed"] = j(r#"["EXT_meshopt_compression"]"#);
    d.json["extensionsRequired"] = j(r#"["EXT_meshopt_compression"]"#);
    // Buffer 0 (the document's own) holds the compressed bytes; buffer 1 is the fallback.
    pad4(&mut d.bin, 0);
    let v_off = d.bin.len();
    d.bin.extend(&vertices);
    pad4(&mut d.bin, 0);
    let i_off = d.bin.len();
    d.bin.extend(&encoded_indices);
    d.json["bufferViews"] = j(&format!(
        r#"[{{"buffer":1,"byteLength":{},"byteStride":12,"extensions":{{"EXT_meshopt_compression":
             {{"buffer":0,"byteOffset":{v_off},"byteLength":{},"byteStride":12,"mode":"ATTRIBUTES","count":{}}}}}}},
           {{"buffer":1,"byteOffset":{},"byteLength":{},"extensions":{{"EXT_meshopt_compression":
             {{"buffer":0,"byteOffset":{i_off},"byteLength":{},"byteStride":4,"mode":"{index_mode}","count":{}}}}}}}]"#,
        raw.len(),
        vertices.len(),
        positions.len(),
        raw.len(),
        indices.len() * 4,
        encoded_indices.len(),
        indices.len()
    ));
    let p = d.accessor(0, 5126, positions.len(), "VEC3");
    d.json["accessors"][p]["min"] = j("[0,0,0]");
    d.json["accessors"][p]["max"] = j("[9,9,1]");
    let i = d.accessor(1, 5125, indices.len(), "SCALAR");
    d.mesh(
        "Packed",
        j(&format!(
            r#"[{{"attributes":{{"POSITION":{p}}},"indices":{i}}}]"#
        )),
    );
    let node = d.node(j(r#"{"mesh":0}"#));
    d.root(node);
    (d, positions, indices)
}

/// `d` as a `.gltf` whose buffer 1 is a meshopt fallback buffer without data.
fn with_fallback_buffer(d: &Doc) -> Vec<u8> {
    let mut json: Value = gltf::json::deserialize::from_slice(&d.gltf()).unwrap();
    let fallback_len = 1 << 20;
    json["buffers"].as_array_mut().unwrap().push(j(&format!(
        r#"{{"byteLength":{fallback_len},"extensions":{{"EXT_meshopt_compression":{{"fallback":true}}}}}}"#
    )));
    gltf::json::serialize::to_vec(&json).unwrap()
}

#[test]
fn meshopt_views_decode_to_the_original_data() {
    for mode in ["TRIANGLES", "INDICES"] {
        let (d, positions, indices) = meshopt_doc(mode);
        let parts = parts(&with_fallback_buffer(&d));
        assert_eq!(parts.mesh.len(), indices.len() / 3, "{mode}");
        // The triangle codec may start a triangle at another corner (same winding); the sequence
        // codec keeps every index.
        for (t, tri) in parts.mesh.positions.iter().enumerate() {
            let want = |k: usize| Vec3::from(positions[indices[3 * t + k % 3] as usize]);
            let rotations = if mode == "TRIANGLES" { 0..3 } else { 0..1 };
            assert!(
                rotations
                    .into_iter()
                    .any(|r| (0..3).all(|k| tri[k] == want(k + r))),
                "{mode}: triangle {t}: {tri:?}"
            );
        }
    }
}

#[test]
fn meshopt_filters_decode() {
    use meshoptimizer_rs::codec;
    use meshoptimizer_rs::Workspace;
    // OCTAHEDRAL normals (8-bit) and EXPONENTIAL positions on one triangle.
    let mut ws = Workspace::default();
    let normals = [
        [0.0f32, 0.0, 1.0, 0.0],
        [0.6, 0.0, 0.8, 0.0],
        [0.0, -1.0, 0.0, 0.0],
    ];
    let flat: Vec<f32> = normals.iter().flatten().copied().collect();
    let oct = codec::encode_filter_oct(3, 4, 8, &flat, &mut ws).unwrap();
    let oct = codec::encode_vertex_buffer(
        &oct,
        3,
        4,
        codec::VertexEncoding::new(0, 0).unwrap(),
        &mut ws,
    )
    .unwrap();
    let pos: Vec<f32> = TRI.iter().flatten().map(|v| v * 3.0 + 0.5).collect();
    let exp = codec::encode_filter_exp(3, 12, 24, &pos, codec::ExpMode::Separate, &mut ws).unwrap();
    let exp = codec::encode_vertex_buffer(
        &exp,
        3,
        12,
        codec::VertexEncoding::new(0, 0).unwrap(),
        &mut ws,
    )
    .unwrap();
    let mut d = Doc::new();
    d.json["extensionsUsed"] = j(r#"["EXT_meshopt_compression"]"#);
    let o = d.bin.len();
    d.bin.extend(&exp);
    pad4(&mut d.bin, 0);
    let o2 = d.bin.len();
    d.bin.extend(&oct);
    d.json["bufferViews"] = j(&format!(
        r#"[{{"buffer":1,"byteLength":36,"byteStride":12,"extensions":{{"EXT_meshopt_compression":
             {{"buffer":0,"byteOffset":{o},"byteLength":{},"byteStride":12,"mode":"ATTRIBUTES","filter":"EXPONENTIAL","count":3}}}}}},
           {{"buffer":1,"byteOffset":36,"byteLength":12,"byteStride":4,"extensions":{{"EXT_meshopt_compression":
             {{"buffer":0,"byteOffset":{o2},"byteLength":{},"byteStride":4,"mode":"ATTRIBUTES","filter":"OCTAHEDRAL","count":3}}}}}}]"#,
        exp.len(),
        oct.len()
    ));
    let p = d.accessor(0, 5126, 3, "VEC3");
    d.json["accessors"][p]["min"] = j("[0.5,0.5,0.5]");
    d.json["accessors"][p]["max"] = j("[3.5,3.5,0.5]");
    let n = d.accessor(1, 5120, 3, "VEC3");
    d.json["accessors"][n]["normalized"] = Value::from(true);
    d.mesh(
        "Filtered",
        j(&format!(
            r#"[{{"attributes":{{"POSITION":{p},"NORMAL":{n}}}}}]"#
        )),
    );
    let node = d.node(j(r#"{"mesh":0}"#));
    d.root(node);
    let parts = parts(&with_fallback_buffer(&d));
    let want: Vec<[f32; 3]> = TRI.iter().map(|c| c.map(|v| v * 3.0 + 0.5)).collect();
    assert_tri(parts.mesh.positions[0], [want[0], want[1], want[2]]);
    let got = parts.mesh.normals.unwrap()[0];
    for k in 0..3 {
        let w = Vec3::new(normals[k][0], normals[k][1], normals[k][2]);
        assert!(
            (got[k] - w).length() < 0.02,
            "normal {k}: {:?}, want {w:?}",
            got[k]
        );
    }
}

#[test]
fn meshopt_errors_name_the_view_and_never_panic() {
    let (d, _, _) = meshopt_doc("TRIANGLES");
    // Truncated compressed vertex data.
    let mut t = d.clone();
    let len = t.json["bufferViews"][0]["extensions"]["EXT_meshopt_compression"]["byteLength"]
        .as_u64()
        .unwrap();
    t.json["bufferViews"][0]["extensions"]["EXT_meshopt_compression"]["byteLength"] =
        Value::from(len / 2);
    assert_contains(
        &error_of(&with_fallback_buffer(&t)),
        &[
            "accessor 0 (POSITION of mesh 0 \"Packed\", primitive 0)",
            "bufferView 0: EXT_meshopt_compression: cannot decode mode ATTRIBUTES",
        ],
    );
    // Corrupt bytes, all through the file: errors or loads, never a panic.
    for seed in 0..64u64 {
        let mut c = d.clone();
        let at = (seed as usize * 7919) % c.bin.len();
        c.bin[at] ^= 0x5a ^ seed as u8;
        if let Err(GltfError::Internal(e)) = load(
            &with_fallback_buffer(&c),
            &NoExternalResources,
            &LoadOptions::default(),
        ) {
            panic!("seed {seed}: panic {e}");
        }
    }
    // An unknown mode and a count × byteStride the data cannot hold.
    let mut m = d.clone();
    m.json["bufferViews"][1]["extensions"]["EXT_meshopt_compression"]["mode"] =
        Value::from("STRIPS");
    assert_contains(
        &error_of(&with_fallback_buffer(&m)),
        &["bufferView 1", "unknown mode"],
    );
    let mut big = d.clone();
    big.json["bufferViews"][0]["extensions"]["EXT_meshopt_compression"]["count"] =
        Value::from(1u64 << 40);
    let e = error_of(&with_fallback_buffer(&big));
    assert!(e.contains("bufferView 0"), "{e}");
    // A plain view over the fallback buffer: a clear error, not a read.
    let mut plain = d.clone();
    plain.json["bufferViews"][0]["extensions"] = Value::Null;
    plain.json["bufferViews"][0]
        .as_object_mut()
        .unwrap()
        .remove("extensions");
    assert_contains(
        &error_of(&with_fallback_buffer(&plain)),
        &["buffer 1", "fallback buffer without data"],
    );
}

#[test]
fn draco_files_from_gltf_transform_match_the_source() {
    let source = parts(&ext_file("source.glb"));
    for name in ["draco_edgebreaker.glb", "draco_sequential.glb"] {
        let draco = parts(&ext_file(name));
        // Draco's default quantization: 14 bits over the 2-unit extent, 10 bits for normals.
        assert_same_triangles(&draco, &source, 2.0 / 16383.0, Some(0.01));
        assert!(draco.warnings.is_empty(), "{name}: {:?}", draco.warnings);
    }
}

#[test]
fn draco_errors_and_fallback() {
    let bytes = ext_file("draco_edgebreaker.glb");
    // The JSON chunk and the BIN chunk (the Draco stream) of the GLB.
    let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let mut json: Value = gltf::json::deserialize::from_slice(&bytes[20..20 + json_len]).unwrap();
    let bin_start = 20 + json_len + 8;
    let stream = bytes[bin_start..].to_vec();
    let mut d = Doc::new();
    d.bin = stream.clone();
    d.json = json.clone();
    let stream_len = json["buffers"][0]["byteLength"].as_u64().unwrap() as usize;
    // Corrupt: the stream cut short, with no uncompressed accessors: an error naming the mesh.
    let mut cut = d.clone();
    cut.bin.truncate(stream_len / 2);
    cut.json["bufferViews"][0]["byteLength"] = Value::from(stream_len / 2);
    assert_contains(
        &error_of(&cut.gltf()),
        &["mesh 0 \"grid\", primitive 0: KHR_draco_mesh_compression: cannot decode bufferView 0"],
    );
    // Corrupt bytes: an error or a load, never a panic.
    for seed in 0..64u64 {
        let mut c = d.clone();
        let at = (seed as usize * 7919) % stream_len;
        c.bin[at] ^= 0xa5 ^ seed as u8;
        if let Err(GltfError::Internal(e)) =
            load(&c.gltf(), &NoExternalResources, &LoadOptions::default())
        {
            panic!("seed {seed}: panic {e}");
        }
    }
    // A broken stream with uncompressed accessors and the extension only used: those, with a
    // warning. Required, the same file is an error.
    let source = parts(&ext_file("source.glb"));
    let src_bytes = ext_file("source.glb");
    let src_json_len = u32::from_le_bytes(src_bytes[12..16].try_into().unwrap()) as usize;
    let src_json: Value =
        gltf::json::deserialize::from_slice(&src_bytes[20..20 + src_json_len]).unwrap();
    let src_bin = src_bytes[20 + src_json_len + 8..].to_vec();
    let mut fb = Doc {
        json: src_json.clone(),
        bin: src_bin,
    };
    pad4(&mut fb.bin, 0);
    let broken_view = fb.view(&stream[..stream_len / 2], None);
    fb.json["extensionsUsed"] = j(r#"["KHR_draco_mesh_compression"]"#);
    fb.json["meshes"][0]["primitives"][0]["extensions"] = j(&format!(
        r#"{{"KHR_draco_mesh_compression":{{"bufferView":{broken_view},"attributes":{{"POSITION":0,"NORMAL":1,"TEXCOORD_0":2}}}}}}"#
    ));
    let loaded = parts(&fb.gltf());
    assert_same_triangles(&loaded, &source, 0.0, Some(0.0));
    assert!(
        loaded
            .warnings
            .iter()
            .any(|w| w.contains("mesh 0 \"grid\", primitive 0")
                && w.contains("using the primitive's uncompressed accessors")),
        "{:?}",
        loaded.warnings
    );
    fb.json["extensionsRequired"] = j(r#"["KHR_draco_mesh_compression"]"#);
    assert_contains(
        &error_of(&fb.gltf()),
        &["mesh 0 \"grid\", primitive 0: KHR_draco_mesh_compression: cannot decode"],
    );
    // A stream that decodes more faces than the indices accessor declares is refused.
    json["accessors"][0]["count"] = Value::from(30);
    d.json = json;
    assert_contains(
        &error_of(&d.gltf()),
        &["mesh 0 \"grid\", primitive 0", "faces"],
    );
}

/// A textured triangle whose texture has EXT_texture_webp with `webp` as its image and, when
/// given, `fallback` as its PNG source.
fn webp_doc(webp: &[u8], fallback: Option<&[u8]>, required: bool) -> Doc {
    let mut d = triangle_doc("{}");
    d.json["meshes"][0]["primitives"][0]["material"] = Value::from(0);
    d.json["extensionsUsed"] = j(r#"["EXT_texture_webp"]"#);
    if required {
        d.json["extensionsRequired"] = j(r#"["EXT_texture_webp"]"#);
    }
    let view = d.view(webp, None);
    d.push(
        "images",
        j(&format!(
            r#"{{"name":"webp","bufferView":{view},"mimeType":"image/webp"}}"#
        )),
    );
    let mut texture = j(r#"{"extensions":{"EXT_texture_webp":{"source":0}}}"#);
    if let Some(png) = fallback {
        let view = d.view(png, None);
        let image = d.push(
            "images",
            j(&format!(
                r#"{{"name":"png","bufferView":{view},"mimeType":"image/png"}}"#
            )),
        );
        texture["source"] = Value::from(image);
    }
    d.push("textures", texture);
    d.push(
        "materials",
        j(r#"{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}"#),
    );
    d
}

fn gradient(w: u32, h: u32) -> Vec<u8> {
    (0..w * h)
        .flat_map(|i| [(i % w * 30) as u8, (i / w * 40) as u8, 200, 255 - i as u8])
        .collect()
}

fn webp_lossless(w: u32, h: u32, rgba: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    image::codecs::webp::WebPEncoder::new_lossless(&mut out)
        .encode(rgba, w, h, image::ExtendedColorType::Rgba8)
        .unwrap();
    out
}

#[test]
fn webp_textures_decode() {
    // Lossless (encoded here), required, with no fallback source: exactly the texels.
    let rgba = gradient(5, 3);
    let lossless = parts(&webp_doc(&webp_lossless(5, 3, &rgba), None, true).gltf());
    let t = &lossless.textures[0];
    assert_eq!((t.width, t.height), (5, 3));
    assert_eq!(t.texels.concat(), rgba);
    assert!(lossless.warnings.is_empty(), "{:?}", lossless.warnings);
    // Lossy (made by cwebp from gradient.png): close to the PNG it was made from; the PNG fallback
    // is present but not used.
    let png_bytes = ext_file("gradient.png");
    let d = webp_doc(&ext_file("gradient_lossy.webp"), Some(&png_bytes), false);
    let lossy = parts(&d.gltf());
    let png_texels = image::load_from_memory(&png_bytes).unwrap().into_rgba8();
    let t = &lossy.textures[0];
    assert_eq!((t.width, t.height), png_texels.dimensions());
    assert_eq!(t.name.as_deref(), Some("webp"));
    let worst = t
        .texels
        .concat()
        .iter()
        .zip(png_texels.as_raw())
        .map(|(a, b)| a.abs_diff(*b))
        .max()
        .unwrap();
    assert!(worst <= 24, "lossy WebP differs from its source by {worst}");
}

#[test]
fn webp_fallback_and_errors() {
    let rgba = [
        10, 20, 30, 255, 40, 50, 60, 255, 70, 80, 90, 255, 1, 2, 3, 4,
    ];
    let fallback = png(2, 2, &rgba);
    let mut broken = webp_lossless(2, 2, &rgba);
    broken.truncate(broken.len() - 6);
    // Optional extension, broken WebP, PNG source: the PNG, with a warning.
    let parts = parts(&webp_doc(&broken, Some(&fallback), false).gltf());
    assert_eq!(parts.textures[0].texels.concat(), rgba);
    assert!(
        parts.warnings.iter().any(|w| w
            .contains("texture 0: EXT_texture_webp image cannot be used")
            && w.contains("using its fallback image 1 \"png\"")),
        "{:?}",
        parts.warnings
    );
    // Required: no fallback, an error naming the image.
    assert_contains(
        &error_of(&webp_doc(&broken, Some(&fallback), true).gltf()),
        &["image 0 \"webp\": cannot decode"],
    );
    assert_contains(
        &error_of(&webp_doc(&broken, None, false).gltf()),
        &["image 0 \"webp\": cannot decode"],
    );
    // A header claiming a huge image: refused before decoding.
    let mut bomb = webp_lossless(2, 2, &rgba);
    // VP8L header: 14 bits width-1, 14 bits height-1 after the signature byte 0x2f at offset 20.
    let bits: u32 = 16383 | (16383 << 14);
    let old = u32::from_le_bytes(bomb[21..25].try_into().unwrap());
    bomb[21..25].copy_from_slice(&(bits | (old & 0xf000_0000)).to_le_bytes());
    assert_contains(
        &error_of(&webp_doc(&bomb, None, true).gltf()),
        &["image 0 \"webp\": cannot decode"],
    );
    // A texture with neither a source nor a WebP image (an unsupported image extension).
    let mut d = triangle_doc("{}");
    d.json["meshes"][0]["primitives"][0]["material"] = Value::from(0);
    d.push("images", j(r#"{"uri":"x.ktx2"}"#));
    d.push(
        "textures",
        j(r#"{"extensions":{"KHR_texture_basisu":{"source":0}}}"#),
    );
    d.push(
        "materials",
        j(r#"{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}"#),
    );
    assert_contains(
        &error_of(&d.gltf()),
        &["texture 0", "no source image", "KHR_texture_basisu"],
    );
}

/// A mesh placed by two or more nodes is kept once and placed (a prototype in object space);
/// one placed once is flattened; an emissive one is flattened however often it is placed, so
/// that light sampling sees every emitting triangle. Loaded and built, the scene renders the
/// instanced mesh through its placements.
#[test]
fn meshes_placed_twice_are_kept_instanced_unless_they_emit() {
    let mut d = Doc::new();
    let p = d.positions(&TRI);
    d.json["materials"] = j(r#"[{"name":"Grey"},{"name":"Lamp","emissiveFactor":[1,0.5,0]}]"#);
    for (name, material) in [("Shared", 0), ("Single", 0), ("Lamp", 1)] {
        d.mesh(
            name,
            j(&format!(
                r#"[{{"attributes":{{"POSITION":{p}}},"material":{material}}}]"#
            )),
        );
    }
    let place = |d: &mut Doc, mesh: usize, x: f32, mirror: bool| {
        let sx = if mirror { -1.0 } else { 1.0 };
        let n = d.node(j(&format!(
            r#"{{"mesh":{mesh},"translation":[{x},0,-3],"scale":[{sx},2,1]}}"#
        )));
        d.root(n);
    };
    for (k, x) in [0.0, 2.0, 4.0].into_iter().enumerate() {
        place(&mut d, 0, x, k == 1);
    }
    place(&mut d, 1, 6.0, false);
    place(&mut d, 2, 8.0, false);
    place(&mut d, 2, 10.0, false);
    let loaded = parts(&d.gltf());
    assert_eq!(
        loaded.prototypes.len(),
        1,
        "only the shared, non-emissive mesh"
    );
    assert_eq!(loaded.prototypes[0].positions, vec![TRI.map(Vec3::from)]);
    assert_eq!(loaded.placements.len(), 3);
    let x: Vec<f64> = loaded
        .placements
        .iter()
        .map(|p| p.to_world.w_axis.x)
        .collect();
    assert_eq!(x, [0.0, 2.0, 4.0]);
    assert_eq!(
        loaded.placements[1].to_world.x_axis.x, -1.0,
        "the mirror is kept"
    );
    assert_eq!(
        loaded.mesh.len(),
        3,
        "the single mesh and both lamps, flattened"
    );
    let scene = Scene::build(loaded).expect("builds");
    assert_eq!(scene.info.instances, 3);
    assert_eq!(scene.info.instanced_triangles, 3);
    assert_eq!(scene.info.emissive_triangles, 2);
    // A ray down the middle of each placed triangle hits it, mirrored or not, from its front.
    for (k, x) in [0.0f32, 2.0, 4.0].into_iter().enumerate() {
        let sx = if k == 1 { -1.0 } else { 1.0 };
        let o = Vec3::new(x + 0.25 * sx, 0.5, 0.0);
        let ray = pathfarm_tracer::geometry::Ray::new(o, -Vec3::Z);
        let hit = scene.intersect(&ray, f32::INFINITY, 0.5).expect("hit");
        assert_eq!(hit.t, 3.0);
        let si = scene.surface(&ray, &hit);
        assert!((si.p - Vec3::new(o.x, 0.5, -3.0)).length() < 1e-6);
        assert!(si.front && si.ng.z > 0.999, "placement {k}: {:?}", si.ng);
    }
}

/// EXT_mesh_gpu_instancing: a node places its mesh once per row of its TRANSLATION, ROTATION and
/// SCALE accessors (rotations as floats or as normalized shorts), at its world transform times the
/// row's T·R·S, kept instanced; the extension may be required; malformed rows are errors that name
/// the node.
#[test]
fn gpu_instancing_places_a_mesh_once_per_row() {
    let build = |rotation_shorts: bool, scale_rows: usize| {
        let mut d = Doc::new();
        let p = d.positions(&TRI);
        d.mesh(
            "Tree",
            j(&format!(r#"[{{"attributes":{{"POSITION":{p}}}}}]"#)),
        );
        let t = d.floats(&[[0.0f32, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, 7.0, 0.0]]);
        let h = std::f32::consts::FRAC_1_SQRT_2;
        // Identity, 90° about Z, identity.
        let quats = [
            [0.0f32, 0.0, 0.0, 1.0],
            [0.0, 0.0, h, h],
            [0.0, 0.0, 0.0, 1.0],
        ];
        let r = if rotation_shorts {
            let bytes: Vec<u8> = quats
                .iter()
                .flatten()
                .flat_map(|&v| ((v * 32767.0).round() as i16).to_le_bytes())
                .collect();
            let view = d.view(&bytes, None);
            let a = d.accessor(view, 5122, 3, "VEC4");
            d.json["accessors"][a]["normalized"] = Value::from(true);
            a
        } else {
            d.floats(&quats)
        };
        let s = d.floats(&vec![[2.0f32, 2.0, 2.0]; scale_rows]);
        let n = d.node(j(&format!(
            r#"{{"mesh":0,"translation":[0,0,-10],"extensions":{{"EXT_mesh_gpu_instancing":
                {{"attributes":{{"TRANSLATION":{t},"ROTATION":{r},"SCALE":{s}}}}}}}}}"#
        )));
        d.root(n);
        d.json["extensionsUsed"] = j(r#"["EXT_mesh_gpu_instancing"]"#);
        d.json["extensionsRequired"] = j(r#"["EXT_mesh_gpu_instancing"]"#);
        d
    };
    for shorts in [false, true] {
        let loaded = parts(&build(shorts, 3).gltf());
        assert!(loaded.warnings.is_empty(), "{:?}", loaded.warnings);
        assert_eq!(loaded.mesh.len(), 0);
        assert_eq!(loaded.prototypes.len(), 1, "three rows: kept instanced");
        assert_eq!(loaded.placements.len(), 3);
        let flat = loaded.flatten_instances();
        // Each row: the node's translation, then the row's T·R·S (scale 2).
        let want = [
            [[0.0, 0.0, -10.0], [2.0, 0.0, -10.0], [0.0, 2.0, -10.0]],
            [[5.0, 0.0, -10.0], [5.0, 2.0, -10.0], [3.0, 0.0, -10.0]],
            [[0.0, 7.0, -10.0], [2.0, 7.0, -10.0], [0.0, 9.0, -10.0]],
        ];
        for (got, want) in flat.mesh.positions.iter().zip(want) {
            for (g, w) in got.iter().zip(want) {
                assert!(
                    (*g - Vec3::from(w)).length() < 1e-3,
                    "shorts {shorts}: {got:?} against {want:?}"
                );
            }
        }
    }
    // Rows that disagree in number: an error naming the node and the extension.
    assert_contains(
        &error_of(&build(false, 2).gltf()),
        &[
            "node 0",
            "EXT_mesh_gpu_instancing",
            "SCALE has 2 elements but TRANSLATION has 3",
        ],
    );
}
