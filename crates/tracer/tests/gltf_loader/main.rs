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

mod buffers;
mod compression;
mod corpus;
mod errors;
mod fuzz;
mod instancing;
mod lights_cameras;
mod materials;
mod meshes;
mod shared_scenes;
mod webp;

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

fn corpus_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf")
}

fn ext_file(name: &str) -> Vec<u8> {
    let path = corpus_dir().join("ext").join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}
