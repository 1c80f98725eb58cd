//! Writes the benchmark scenes committed under `scenes/`, each stressing one estimator:
//!
//! ```text
//! cargo run --release -p pathfarm-tracer --example make_bench_scenes -- [OUT_DIR]
//! ```
//!
//! `OUT_DIR` defaults to `scenes`. The output is deterministic (same bytes on every run). Every
//! file is glTF 2.0 JSON with its buffer and images embedded as base64 `data:` URIs (the server
//! accepts nothing else), one perspective camera (aspect 1:1) and units of the Cornell data scaled
//! by 0.01 (the box spans 0..5.56 × 0..5.488 × 0..5.592, the camera looks along +z). Walls are
//! white Lambertian (metallic 0, roughness 1, KHR_materials_specular 0, albedo 0.725/0.71/0.68),
//! with the Cornell box's red wall on the left (x = 5.56) and green wall on the right (x = 0).
//! Lights are one-sided emissive quads facing down (emission = emissiveFactor ×
//! KHR_materials_emissive_strength). Curved surfaces are UV spheres with smooth vertex normals.
//!
//! - `smalllight.gltf`: a closed room (the Cornell box extended to z = −3 and closed at the front,
//!   the camera inside) with the Cornell box's two blocks, lit by one tiny square light 0.005 below
//!   the ceiling whose area is 1e-4 of the ceiling's. Its emissive strength is raised so that its
//!   power equals the Cornell box light's (L = 16 × (1, 0.75, 0.375) over 1.3 × 1.05). Hemisphere,
//!   cosine and BSDF sampling almost never hit the light; light sampling (and MIS) wins.
//! - `caustics.gltf`: the Cornell box's walls and light with a glass sphere (KHR_materials_
//!   transmission 1, roughness 0, KHR_materials_ior 1.5, KHR_materials_volume thickness > 0: a
//!   closed refracting volume) in front on the right and a mirror sphere (metallic 1, roughness 0,
//!   base color 0.95) at the back on the left. The caustic below the glass sphere and the light
//!   seen in the mirror are reached only through delta bounces, so only paths that hit the light
//!   by chance carry them: every direct-lighting strategy is equally poor there.
//! - `glossy.gltf`: a closed room with a glossy aluminium floor (metallic 1, roughness 0.2), a
//!   diffuse sphere and a diffuse block standing on it, and a 1.6 × 1.0 ceiling light near the
//!   back; the camera looks down so the floor shows glossy reflections of the light and the objects.
//!   Light sampling is noisy in the narrow glossy lobe, BSDF sampling on the diffuse surfaces: MIS
//!   wins.
//! - `textured.gltf`: the Cornell box's walls and light with a textured UV sphere (TEXCOORD_0,
//!   NORMAL, TANGENT; an sRGB checker baseColorTexture, a normalTexture of raised domes, one per
//!   check, and a metallicRoughnessTexture of alternating metal and rough dielectric bands) and a
//!   tiled floor (a repeating baseColorTexture). Stresses texture lookups and normal mapping.
//!
//! Each file is loaded back with `pathfarm_tracer::gltf::load`; the generator fails if the load
//! reports any warning or drops any degenerate triangle.

use base64::Engine as _;
use glam::{Mat3, Quat, Vec2, Vec3, Vec4};
use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{ExtendedColorType, ImageEncoder};
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};
use serde_json::{json, Value};
use std::error::Error;
use std::f32::consts::PI;
use std::path::{Path, PathBuf};

type Result<T> = std::result::Result<T, Box<dyn Error>>;
/// Makes one scene's glTF document.
type MakeScene = fn() -> Result<Value>;

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_INT: u32 = 5125;
const REPEAT: u32 = 10497;
const LINEAR: u32 = 9729;
const LINEAR_MIPMAP_LINEAR: u32 = 9987;

/// The Cornell box's extent (x, y, z), in its units (the Cornell data scaled by 0.01).
const BOX: [f32; 3] = [5.56, 5.488, 5.592];
/// The Cornell box's materials.
const WHITE: [f32; 3] = [0.725, 0.71, 0.68];
const RED: [f32; 3] = [0.63, 0.065, 0.05];
const GREEN: [f32; 3] = [0.14, 0.45, 0.091];
/// The Cornell box light: emissiveFactor × strength over a 1.3 × 1.05 quad 0.005 below the ceiling.
const CORNELL_LIGHT_COLOR: [f32; 3] = [1.0, 0.75, 0.375];
const CORNELL_LIGHT_STRENGTH: f32 = 16.0;
const CORNELL_LIGHT_X: [f32; 2] = [2.13, 3.43];
const CORNELL_LIGHT_Z: [f32; 2] = [2.27, 3.32];
/// Lights hang this far below the ceiling.
const LIGHT_DROP: f32 = 0.005;
/// The Cornell camera: at (2.78, 2.73, −8) looking along +z, vertical field of view 39.3°.
const CORNELL_EYE: [f32; 3] = [2.78, 2.73, -8.0];
const CORNELL_YFOV: f32 = 0.686_047_9;

fn main() -> Result<()> {
    let out_dir = std::env::args_os()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("scenes"));
    std::fs::create_dir_all(&out_dir)?;
    let scenes: [(&str, MakeScene); 4] = [
        ("smalllight.gltf", small_light),
        ("caustics.gltf", caustics),
        ("glossy.gltf", glossy),
        ("textured.gltf", textured),
    ];
    for (name, make) in scenes {
        let doc = make()?;
        let mut bytes = serde_json::to_vec_pretty(&doc)?;
        bytes.push(b'\n');
        let path = out_dir.join(name);
        std::fs::write(&path, &bytes)?;
        verify(&path, &bytes)?;
    }
    Ok(())
}

/// Loads a written file back; any warning or dropped triangle is an error.
fn verify(path: &Path, bytes: &[u8]) -> Result<()> {
    let scene = gltf::load(bytes, &NoExternalResources, &LoadOptions::default())
        .map_err(|e| format!("{}: {e}", path.display()))?;
    let info = &scene.info;
    if !info.warnings.is_empty() || info.degenerate_dropped != 0 || info.emissive_triangles == 0 {
        return Err(format!("{}: unexpected load result: {info:?}", path.display()).into());
    }
    let light_area: f32 = scene
        .lights
        .area
        .triangles
        .iter()
        .map(|&t| scene.mesh.area(t as usize))
        .sum();
    println!(
        "{}: {} bytes, {} triangles ({} emissive, light area {light_area:.4}), {} materials, {} textures, bounds {:.3} .. {:.3}",
        path.display(),
        bytes.len(),
        info.triangles,
        info.emissive_triangles,
        scene.materials.len(),
        scene.textures.len(),
        info.bounds_min,
        info.bounds_max,
    );
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Geometry.

/// An indexed triangle list with optional smooth attributes (counter-clockwise = front).
#[derive(Default)]
struct Geometry {
    positions: Vec<Vec3>,
    normals: Option<Vec<Vec3>>,
    uvs: Option<Vec<Vec2>>,
    tangents: Option<Vec<Vec4>>,
    indices: Vec<u32>,
}

impl Geometry {
    /// Adds the quad `c` (corners in order around it) as two triangles, wound so that the front
    /// faces `facing`. With `uv`, the corners get those texture coordinates.
    fn quad(&mut self, c: [Vec3; 4], facing: Vec3, uv: Option<[Vec2; 4]>) -> &mut Self {
        let n = (c[1] - c[0]).cross(c[2] - c[0]);
        let order = if n.dot(facing) > 0.0 {
            [0, 1, 2, 3]
        } else {
            [0, 3, 2, 1]
        };
        let base = self.positions.len() as u32;
        self.positions.extend(order.map(|i| c[i]));
        if let Some(uv) = uv {
            self.uvs
                .get_or_insert_with(Vec::new)
                .extend(order.map(|i| uv[i]));
        }
        self.indices
            .extend([base, base + 1, base + 2, base, base + 2, base + 3]);
        self
    }

    /// An axis-aligned quad at `y` over `x` × `z`, facing up (+y) or down.
    fn horizontal(&mut self, x: [f32; 2], y: f32, z: [f32; 2], up: bool) -> &mut Self {
        let c = [
            Vec3::new(x[0], y, z[0]),
            Vec3::new(x[1], y, z[0]),
            Vec3::new(x[1], y, z[1]),
            Vec3::new(x[0], y, z[1]),
        ];
        self.quad(c, if up { Vec3::Y } else { Vec3::NEG_Y }, None)
    }

    /// A prism standing on the floor: the footprint `f` (x, z corners in order around it) from
    /// `y = 0` to `height`, faces pointing out, no bottom face.
    fn prism(&mut self, f: [[f32; 2]; 4], height: f32) -> &mut Self {
        let lo = f.map(|[x, z]| Vec3::new(x, 0.0, z));
        let hi = f.map(|[x, z]| Vec3::new(x, height, z));
        let centre = hi.iter().copied().sum::<Vec3>() / 4.0;
        self.quad(hi, Vec3::Y, None);
        for i in 0..4 {
            let j = (i + 1) % 4;
            let mid = 0.5 * (lo[i] + lo[j]);
            let out = (mid - Vec3::new(centre.x, 0.0, centre.z)).normalize();
            self.quad([lo[i], lo[j], hi[j], hi[i]], out, None);
        }
        self
    }

    /// Checks that every triangle faces away from `inside` (a point inside a convex solid), or
    /// towards it when `inward`.
    fn check_orientation(&self, inside: Vec3, inward: bool, what: &str) -> Result<()> {
        for t in self.indices.chunks_exact(3) {
            let [a, b, c] = [0, 1, 2].map(|k| self.positions[t[k] as usize]);
            let n = (b - a).cross(c - a);
            let out = (a + b + c) / 3.0 - inside;
            if (n.dot(out) > 0.0) == inward || n.length_squared() == 0.0 {
                return Err(format!("{what}: triangle {t:?} is wound the wrong way").into());
            }
        }
        Ok(())
    }
}

/// A UV sphere of `segments` × `rings` quads (triangles at the poles) around `centre`: smooth unit
/// normals, TEXCOORD_0 (u around from the +x axis, v from 0 at the north pole to 1 at the south
/// pole; the seam and the poles have their own vertices) and TANGENT (dP/du, w = +1: the texture
/// is not mirrored seen from outside).
fn uv_sphere(centre: Vec3, radius: f32, segments: u32, rings: u32) -> Geometry {
    let mut g = Geometry {
        normals: Some(Vec::new()),
        uvs: Some(Vec::new()),
        tangents: Some(Vec::new()),
        ..Geometry::default()
    };
    let (normals, uvs, tangents) = (
        g.normals.as_mut().unwrap(),
        g.uvs.as_mut().unwrap(),
        g.tangents.as_mut().unwrap(),
    );
    let row = segments + 1;
    for j in 0..=rings {
        let theta = PI * j as f32 / rings as f32;
        for i in 0..=segments {
            // The poles' vertices sit mid-segment in u, where their one triangle samples.
            let u = if j == 0 || j == rings {
                (i as f32 + 0.5) / segments as f32
            } else {
                i as f32 / segments as f32
            };
            let phi = 2.0 * PI * u;
            let (st, ct) = theta.sin_cos();
            let (sp, cp) = phi.sin_cos();
            // Exact poles, so that the two rings of pole vertices coincide.
            let n = if j == 0 {
                Vec3::Y
            } else if j == rings {
                Vec3::NEG_Y
            } else {
                Vec3::new(st * cp, ct, -st * sp)
            };
            g.positions.push(centre + radius * n);
            normals.push(n);
            uvs.push(Vec2::new(u, j as f32 / rings as f32));
            tangents.push(Vec4::new(-sp, 0.0, -cp, 1.0));
        }
    }
    for j in 0..rings {
        for i in 0..segments {
            let a = j * row + i;
            let b = a + row;
            if j + 1 < rings {
                g.indices.extend([a, b, b + 1]);
            }
            if j > 0 {
                g.indices.extend([a, b + 1, a + 1]);
            }
        }
    }
    g
}

/// Corners of the Cornell box's short and tall blocks (x, z around the footprint) and heights.
const SHORT_BLOCK: ([[f32; 2]; 4], f32) =
    ([[1.3, 0.65], [0.82, 2.25], [2.4, 2.72], [2.9, 1.14]], 1.65);
#[allow(clippy::approx_constant)] // 3.14 is the Cornell data's x, not π.
const TALL_BLOCK: ([[f32; 2]; 4], f32) = (
    [[4.23, 2.47], [2.65, 2.96], [3.14, 4.56], [4.72, 4.06]],
    3.3,
);

/// The walls of the room `[0, BOX.x] × [0, BOX.y] × [z_front, BOX.z]`, facing inwards: white
/// floor, ceiling, back (and front, if `closed`) in one geometry; the red left (x = BOX.x) and green
/// right (x = 0) walls apart.
fn room(z_front: f32, closed: bool) -> (Geometry, Geometry, Geometry) {
    let [sx, sy, sz] = BOX;
    let mut white = Geometry::default();
    white
        .horizontal([0.0, sx], 0.0, [z_front, sz], true)
        .horizontal([0.0, sx], sy, [z_front, sz], false);
    let back = [
        Vec3::new(0.0, 0.0, sz),
        Vec3::new(sx, 0.0, sz),
        Vec3::new(sx, sy, sz),
        Vec3::new(0.0, sy, sz),
    ];
    white.quad(back, Vec3::NEG_Z, None);
    if closed {
        white.quad(back.map(|p| Vec3::new(p.x, p.y, z_front)), Vec3::Z, None);
    }
    let side = |x: f32, facing: Vec3| {
        let mut g = Geometry::default();
        g.quad(
            [
                Vec3::new(x, 0.0, z_front),
                Vec3::new(x, 0.0, sz),
                Vec3::new(x, sy, sz),
                Vec3::new(x, sy, z_front),
            ],
            facing,
            None,
        );
        g
    };
    (white, side(sx, Vec3::NEG_X), side(0.0, Vec3::X))
}

/// A light quad over `x` × `z`, `LIGHT_DROP` below the ceiling, facing down.
fn ceiling_light(x: [f32; 2], z: [f32; 2]) -> Geometry {
    let mut g = Geometry::default();
    g.horizontal(x, BOX[1] - LIGHT_DROP, z, false);
    g
}

// ---------------------------------------------------------------------------------------------
// The glTF document.

/// Builds one glTF 2.0 document with a single embedded buffer.
struct Doc {
    root: Value,
    bin: Vec<u8>,
    extensions: Vec<&'static str>,
}

/// An f32 as the JSON number of its shortest decimal form (which reads back as the same f32).
fn num(x: f32) -> Value {
    json!(x
        .to_string()
        .parse::<f64>()
        .expect("a finite f32 prints as a number"))
}

fn nums(xs: &[f32]) -> Value {
    Value::Array(xs.iter().map(|&x| num(x)).collect())
}

impl Doc {
    fn new(name: &str, description: &str) -> Self {
        Doc {
            root: json!({
                "asset": {
                    "version": "2.0",
                    "generator": "pathfarm-tracer examples/make_bench_scenes.rs",
                    "extras": { "description": description },
                },
                "scene": 0,
                "scenes": [{ "name": name, "nodes": [] }],
            }),
            bin: Vec::new(),
            extensions: Vec::new(),
        }
    }

    fn push(&mut self, key: &str, v: Value) -> usize {
        let arr = self
            .root
            .as_object_mut()
            .expect("the root is an object")
            .entry(key)
            .or_insert_with(|| json!([]))
            .as_array_mut()
            .expect("top-level arrays are arrays");
        arr.push(v);
        arr.len() - 1
    }

    fn use_extension(&mut self, name: &'static str) {
        if !self.extensions.contains(&name) {
            self.extensions.push(name);
        }
    }

    /// A buffer view of `bytes` (4-byte aligned).
    fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        let mut v = json!({ "buffer": 0, "byteOffset": offset, "byteLength": bytes.len() });
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.push("bufferViews", v)
    }

    /// A float accessor of `N`-component vectors, with min and max when `bounds`.
    fn floats<const N: usize>(&mut self, data: &[[f32; N]], ty: &str, bounds: bool) -> usize {
        let bytes: Vec<u8> = data
            .iter()
            .flatten()
            .flat_map(|c| c.to_le_bytes())
            .collect();
        let view = self.view(&bytes, Some(ARRAY_BUFFER));
        let mut acc =
            json!({ "bufferView": view, "componentType": FLOAT, "count": data.len(), "type": ty });
        if bounds {
            let lo = data.iter().fold([f32::INFINITY; N], |mut m, v| {
                (0..N).for_each(|k| m[k] = m[k].min(v[k]));
                m
            });
            let hi = data.iter().fold([f32::NEG_INFINITY; N], |mut m, v| {
                (0..N).for_each(|k| m[k] = m[k].max(v[k]));
                m
            });
            acc["min"] = nums(&lo);
            acc["max"] = nums(&hi);
        }
        self.push("accessors", acc)
    }

    /// A material; `extensions` lists the extensions its JSON uses.
    fn material(&mut self, m: Value, extensions: &[&'static str]) -> usize {
        for e in extensions {
            self.use_extension(e);
        }
        self.push("materials", m)
    }

    /// A Lambertian material (metallic 0, roughness 1, specular 0) of linear albedo `c`.
    fn lambert(&mut self, name: &str, c: [f32; 3]) -> usize {
        self.material(
            json!({
                "name": name,
                "doubleSided": true,
                "pbrMetallicRoughness": {
                    "baseColorFactor": nums(&[c[0], c[1], c[2], 1.0]),
                    "metallicFactor": 0.0,
                    "roughnessFactor": 1.0,
                },
                "extensions": { "KHR_materials_specular": { "specularFactor": 0.0 } },
            }),
            &["KHR_materials_specular"],
        )
    }

    /// A one-sided emitter of radiance `color` × `strength` (black, Lambertian, otherwise).
    fn emitter(&mut self, name: &str, color: [f32; 3], strength: f32) -> usize {
        self.material(
            json!({
                "name": name,
                "doubleSided": false,
                "pbrMetallicRoughness": {
                    "baseColorFactor": [0.0, 0.0, 0.0, 1.0],
                    "metallicFactor": 0.0,
                    "roughnessFactor": 1.0,
                },
                "emissiveFactor": nums(&color),
                "extensions": {
                    "KHR_materials_specular": { "specularFactor": 0.0 },
                    "KHR_materials_emissive_strength": { "emissiveStrength": num(strength) },
                },
            }),
            &["KHR_materials_specular", "KHR_materials_emissive_strength"],
        )
    }

    /// An embedded PNG image and a texture of it with a repeating, linearly filtered sampler.
    fn texture(&mut self, name: &str, png: &[u8]) -> usize {
        let uri = format!(
            "data:image/png;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(png)
        );
        let image = self.push("images", json!({ "name": name, "uri": uri }));
        if self.root.get("samplers").is_none() {
            self.push(
                "samplers",
                json!({ "magFilter": LINEAR, "minFilter": LINEAR_MIPMAP_LINEAR, "wrapS": REPEAT, "wrapT": REPEAT }),
            );
        }
        self.push(
            "textures",
            json!({ "name": name, "sampler": 0, "source": image }),
        )
    }

    /// `g` as a mesh of one primitive with material `material`, in a node of the scene.
    fn mesh(&mut self, name: &str, g: &Geometry, material: usize) -> usize {
        let to3 = |v: &Vec<Vec3>| v.iter().map(|p| p.to_array()).collect::<Vec<_>>();
        let pos = to3(&g.positions);
        let mut attributes = json!({ "POSITION": self.floats(&pos, "VEC3", true) });
        if let Some(n) = &g.normals {
            attributes["NORMAL"] = json!(self.floats(&to3(n), "VEC3", false));
        }
        if let Some(uv) = &g.uvs {
            let uv: Vec<[f32; 2]> = uv.iter().map(|t| t.to_array()).collect();
            attributes["TEXCOORD_0"] = json!(self.floats(&uv, "VEC2", false));
        }
        if let Some(t) = &g.tangents {
            let t: Vec<[f32; 4]> = t.iter().map(|t| t.to_array()).collect();
            attributes["TANGENT"] = json!(self.floats(&t, "VEC4", false));
        }
        let (bytes, component) = if g.positions.len() <= u16::MAX as usize {
            let b: Vec<u8> = g
                .indices
                .iter()
                .flat_map(|&i| (i as u16).to_le_bytes())
                .collect();
            (b, UNSIGNED_SHORT)
        } else {
            let b: Vec<u8> = g.indices.iter().flat_map(|i| i.to_le_bytes()).collect();
            (b, UNSIGNED_INT)
        };
        let view = self.view(&bytes, Some(ELEMENT_ARRAY_BUFFER));
        let indices = self.push(
            "accessors",
            json!({ "bufferView": view, "componentType": component, "count": g.indices.len(), "type": "SCALAR" }),
        );
        let mesh = self.push(
            "meshes",
            json!({
                "name": name,
                "primitives": [{ "attributes": attributes, "indices": indices, "material": material, "mode": 4 }],
            }),
        );
        self.node(json!({ "name": name, "mesh": mesh }))
    }

    fn node(&mut self, n: Value) -> usize {
        let node = self.push("nodes", n);
        self.root["scenes"][0]["nodes"]
            .as_array_mut()
            .expect("the scene has a nodes array")
            .push(json!(node));
        node
    }

    /// A perspective camera (aspect 1:1) at `eye` looking at `target`, +y up.
    fn camera(&mut self, eye: Vec3, target: Vec3, yfov: f32) {
        let f = (target - eye).normalize();
        let right = f.cross(Vec3::Y).normalize();
        let up = right.cross(f);
        let q = Quat::from_mat3(&Mat3::from_cols(right, up, -f)).normalize();
        // The Cornell camera's rotation (0, 1, 0, 0) comes out with a −0 component; print it as 0.
        let q = q.to_array().map(|c| if c == 0.0 { 0.0 } else { c });
        let camera = self.push(
            "cameras",
            json!({
                "name": "camera",
                "type": "perspective",
                "perspective": { "yfov": num(yfov), "aspectRatio": 1.0, "znear": 0.01 },
            }),
        );
        self.node(json!({
            "name": "camera",
            "camera": camera,
            "translation": nums(&eye.to_array()),
            "rotation": nums(&q),
        }));
    }

    fn finish(mut self) -> Value {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let uri = format!(
            "data:application/octet-stream;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(&self.bin)
        );
        self.root["buffers"] = json!([{ "byteLength": self.bin.len(), "uri": uri }]);
        self.root["extensionsUsed"] = json!(self.extensions);
        self.root
    }
}

// ---------------------------------------------------------------------------------------------
// Textures.

/// PNG bytes of an 8-bit RGB image, `f(x, y)` per texel (row 0 at the top), best compression.
fn png(width: u32, height: u32, f: impl Fn(u32, u32) -> [u8; 3]) -> Result<Vec<u8>> {
    let mut pixels = Vec::with_capacity((width * height * 3) as usize);
    for y in 0..height {
        for x in 0..width {
            pixels.extend(f(x, y));
        }
    }
    let mut out = Vec::new();
    PngEncoder::new_with_quality(&mut out, CompressionType::Best, FilterType::Adaptive)
        .write_image(&pixels, width, height, ExtendedColorType::Rgb8)?;
    Ok(out)
}

/// Checks per texture: 16 around × 8 from pole to pole on the sphere.
const CHECKS: [u32; 2] = [16, 8];

/// The sphere's base color (sRGB): a cream / teal checker with a thin dark line around each check
/// and a red check at u ∈ [0, 1/16), v ∈ [3/8, 1/2) that shows the texture's orientation.
fn checker_png() -> Result<Vec<u8>> {
    let (w, h) = (256, 128);
    let cell = w / CHECKS[0];
    png(w, h, |x, y| {
        let (cx, cy) = (x / cell, y / cell);
        let (fx, fy) = (x % cell, y % cell);
        if fx == 0 || fy == 0 {
            [40, 40, 40]
        } else if cx == 0 && cy == 3 {
            [200, 30, 30]
        } else if (cx + cy) % 2 == 0 {
            [235, 222, 190]
        } else {
            [30, 110, 130]
        }
    })
}

/// A tangent-space normal map: one smooth round dome per check (height `BUMP`·cos²(π d / 2) at
/// distance d from the check's centre, in units of the dome's radius, 0.4 of a check), flat between
/// them. +x follows u, +y points to decreasing v ("up" in the image), as glTF specifies.
fn domes_png() -> Result<Vec<u8>> {
    const BUMP: f32 = 0.5;
    const RADIUS: f32 = 0.4;
    let (w, h) = (256, 128);
    let cell = (w / CHECKS[0]) as f32;
    png(w, h, |x, y| {
        let dx = (((x as f32 + 0.5) / cell).fract() - 0.5) / RADIUS;
        let dy_down = (((y as f32 + 0.5) / cell).fract() - 0.5) / RADIUS;
        let d = (dx * dx + dy_down * dy_down).sqrt();
        let n = if d < 1.0 && d > 0.0 {
            // dh/dd = −BUMP·(π/2)·sin(π d); the gradient points along (dx, dy_down) / d.
            let slope = -BUMP * PI / 2.0 * (PI * d).sin() / d;
            let (hx, hy_down) = (slope * dx, slope * dy_down);
            // n ∝ (−∂h/∂x, −∂h/∂y_up, 1) with y_up = −y_down.
            Vec3::new(-hx, hy_down, 1.0).normalize()
        } else {
            Vec3::Z
        };
        n.to_array()
            .map(|c| ((c * 0.5 + 0.5) * 255.0).round().clamp(0.0, 255.0) as u8)
    })
}

/// Metallic-roughness (linear; roughness in G, metallic in B): 8 bands from pole to pole,
/// alternately polished metal (roughness 0.3, metallic 1) and rough dielectric (0.7, 0).
fn bands_png() -> Result<Vec<u8>> {
    let (w, h) = (16, 64);
    png(w, h, |_, y| {
        if (y / 8) % 2 == 0 {
            [0, 77, 255]
        } else {
            [0, 179, 0]
        }
    })
}

/// The floor's tiles (sRGB): 2 × 2 tiles of two greys per repeat with darker grout.
fn tiles_png() -> Result<Vec<u8>> {
    let n = 64;
    png(n, n, |x, y| {
        let (tx, ty) = (x / 32, y / 32);
        let (fx, fy) = (x % 32, y % 32);
        if fx < 2 || fy < 2 {
            [90, 85, 80]
        } else if (tx + ty) % 2 == 0 {
            [215, 210, 200]
        } else {
            [175, 165, 150]
        }
    })
}

// ---------------------------------------------------------------------------------------------
// The scenes.

/// The room's walls (see [`room`]) with the Cornell box's materials; returns the white material.
fn cornell_walls(doc: &mut Doc, z_front: f32, closed: bool) -> Result<usize> {
    let (white_walls, red_wall, green_wall) = room(z_front, closed);
    let inside = Vec3::new(BOX[0] / 2.0, BOX[1] / 2.0, (z_front + BOX[2]) / 2.0);
    white_walls.check_orientation(inside, true, "white walls")?;
    red_wall.check_orientation(inside, true, "red wall")?;
    green_wall.check_orientation(inside, true, "green wall")?;
    let white = doc.lambert("white", WHITE);
    let red = doc.lambert("red", RED);
    let green = doc.lambert("green", GREEN);
    doc.mesh("walls_white", &white_walls, white);
    doc.mesh("wall_red_left", &red_wall, red);
    doc.mesh("wall_green_right", &green_wall, green);
    Ok(white)
}

fn cornell_light(doc: &mut Doc) {
    let light = doc.emitter("light", CORNELL_LIGHT_COLOR, CORNELL_LIGHT_STRENGTH);
    doc.mesh(
        "light",
        &ceiling_light(CORNELL_LIGHT_X, CORNELL_LIGHT_Z),
        light,
    );
}

fn cornell_light_area() -> f32 {
    (CORNELL_LIGHT_X[1] - CORNELL_LIGHT_X[0]) * (CORNELL_LIGHT_Z[1] - CORNELL_LIGHT_Z[0])
}

/// A 64 × 32 UV sphere (3,968 triangles), checked to face outwards; with texture coordinates and
/// tangents only when `textured`.
fn sphere_checked(centre: Vec3, radius: f32, textured: bool, what: &str) -> Result<Geometry> {
    let mut g = uv_sphere(centre, radius, 64, 32);
    g.check_orientation(centre, false, what)?;
    if !textured {
        g.uvs = None;
        g.tangents = None;
    }
    Ok(g)
}

fn small_light() -> Result<Value> {
    const Z_FRONT: f32 = -3.0;
    /// The light's area as a fraction of the ceiling's.
    const FRACTION: f32 = 1e-4;
    let mut doc = Doc::new(
        "smalllight",
        "Closed Cornell-like room (the Cornell box extended to z = -3 and closed, camera inside) with \
         its two blocks, lit by one tiny one-sided square light 0.005 below the ceiling: area 1e-4 of \
         the ceiling's, emission raised so its power equals the Cornell box light's. Light sampling \
         finds it; hemisphere, cosine and BSDF sampling almost never do.",
    );
    let white = cornell_walls(&mut doc, Z_FRONT, true)?;
    for (name, (footprint, height)) in [("short_block", SHORT_BLOCK), ("tall_block", TALL_BLOCK)] {
        let mut g = Geometry::default();
        g.prism(footprint, height);
        doc.mesh(name, &g, white);
    }
    let ceiling = BOX[0] * (BOX[2] - Z_FRONT);
    let side = (FRACTION * ceiling).sqrt();
    let strength = CORNELL_LIGHT_STRENGTH * cornell_light_area() / (side * side);
    // Centred over the Cornell light.
    let (cx, cz) = (
        0.5 * (CORNELL_LIGHT_X[0] + CORNELL_LIGHT_X[1]),
        0.5 * (CORNELL_LIGHT_Z[0] + CORNELL_LIGHT_Z[1]),
    );
    let light = doc.emitter("small_light", CORNELL_LIGHT_COLOR, strength.round());
    doc.mesh(
        "small_light",
        &ceiling_light(
            [cx - side / 2.0, cx + side / 2.0],
            [cz - side / 2.0, cz + side / 2.0],
        ),
        light,
    );
    // The light itself stays out of view (15° above the camera's horizon, the top of the view is at
    // 7°): seen directly, a light this bright makes its few pixels' coverage noise dominate any
    // error measure, identically for every direct-lighting strategy.
    doc.camera(
        Vec3::new(2.78, 4.0, Z_FRONT + 0.1),
        Vec3::new(2.78, 0.8, BOX[2]),
        55f32.to_radians(),
    );
    Ok(doc.finish())
}

fn caustics() -> Result<Value> {
    let mut doc = Doc::new(
        "caustics",
        "Cornell box walls and ceiling light with a glass sphere (transmission 1, roughness 0, ior 1.5, \
         volume) in front on the right and a mirror sphere (metallic 1, roughness 0) at the back on \
         the left: caustics under the glass sphere, the light seen through delta bounces.",
    );
    cornell_walls(&mut doc, 0.0, false)?;
    cornell_light(&mut doc);
    let glass = doc.material(
        json!({
            "name": "glass",
            "pbrMetallicRoughness": {
                "baseColorFactor": [1.0, 1.0, 1.0, 1.0],
                "metallicFactor": 0.0,
                "roughnessFactor": 0.0,
            },
            "extensions": {
                "KHR_materials_transmission": { "transmissionFactor": 1.0 },
                "KHR_materials_ior": { "ior": 1.5 },
                "KHR_materials_volume": { "thicknessFactor": 2.0 },
            },
        }),
        &[
            "KHR_materials_transmission",
            "KHR_materials_ior",
            "KHR_materials_volume",
        ],
    );
    let mirror = doc.material(
        json!({
            "name": "mirror",
            "pbrMetallicRoughness": {
                "baseColorFactor": [0.95, 0.95, 0.95, 1.0],
                "metallicFactor": 1.0,
                "roughnessFactor": 0.0,
            },
        }),
        &[],
    );
    let r = 1.0;
    let lift = 1e-3;
    let glass_centre = Vec3::new(1.85, r + lift, 1.5);
    let mirror_centre = Vec3::new(3.8, r + lift, 3.7);
    doc.mesh(
        "glass_sphere",
        &sphere_checked(glass_centre, r, false, "glass sphere")?,
        glass,
    );
    doc.mesh(
        "mirror_sphere",
        &sphere_checked(mirror_centre, r, false, "mirror sphere")?,
        mirror,
    );
    doc.camera(
        Vec3::from(CORNELL_EYE),
        Vec3::new(CORNELL_EYE[0], CORNELL_EYE[1], 0.0),
        CORNELL_YFOV,
    );
    Ok(doc.finish())
}

fn glossy() -> Result<Value> {
    const Z_FRONT: f32 = -4.0;
    let mut doc = Doc::new(
        "glossy",
        "Closed Cornell-like room with a glossy aluminium floor (metallic 1, roughness 0.2), a diffuse \
         sphere and a diffuse block on it and a 1.6 x 1.0 ceiling light near the back; the camera \
         looks down at glossy reflections of the light and the objects.",
    );
    // The walls, less the floor: the white geometry's first quad (two triangles) is the floor.
    let (mut white_walls, red_wall, green_wall) = room(Z_FRONT, true);
    let floor = Geometry {
        positions: white_walls.positions.drain(..4).collect(),
        indices: white_walls.indices.drain(..6).collect(),
        ..Geometry::default()
    };
    white_walls.indices.iter_mut().for_each(|i| *i -= 4);
    let inside = Vec3::new(BOX[0] / 2.0, BOX[1] / 2.0, (Z_FRONT + BOX[2]) / 2.0);
    for (g, what) in [
        (&white_walls, "white walls"),
        (&floor, "floor"),
        (&red_wall, "red wall"),
        (&green_wall, "green wall"),
    ] {
        g.check_orientation(inside, true, what)?;
    }
    let white = doc.lambert("white", WHITE);
    let red = doc.lambert("red", RED);
    let green = doc.lambert("green", GREEN);
    let metal = doc.material(
        json!({
            "name": "glossy_aluminium",
            "pbrMetallicRoughness": {
                "baseColorFactor": [0.91, 0.92, 0.92, 1.0],
                "metallicFactor": 1.0,
                "roughnessFactor": 0.2,
            },
        }),
        &[],
    );
    let orange = doc.lambert("orange", [0.8, 0.35, 0.08]);
    let blue = doc.lambert("blue", [0.12, 0.22, 0.6]);
    doc.mesh("walls_white", &white_walls, white);
    doc.mesh("wall_red_left", &red_wall, red);
    doc.mesh("wall_green_right", &green_wall, green);
    doc.mesh("floor_metal", &floor, metal);
    let r = 0.8;
    let centre = Vec3::new(3.75, r + 1e-3, 2.4);
    doc.mesh(
        "sphere",
        &sphere_checked(centre, r, false, "sphere")?,
        orange,
    );
    let mut block = Geometry::default();
    block.prism([[1.0, 2.6], [1.2, 3.9], [2.5, 3.7], [2.3, 2.4]], 1.8);
    doc.mesh("block", &block, blue);
    let (lx, lz) = ([1.98, 3.58], [3.4, 4.4]);
    let area = (lx[1] - lx[0]) * (lz[1] - lz[0]);
    let light = doc.emitter(
        "light",
        CORNELL_LIGHT_COLOR,
        CORNELL_LIGHT_STRENGTH * cornell_light_area() / area,
    );
    doc.mesh("light", &ceiling_light(lx, lz), light);
    doc.camera(
        Vec3::new(2.78, 4.9, Z_FRONT + 0.3),
        Vec3::new(2.78, 0.3, 3.2),
        58f32.to_radians(),
    );
    Ok(doc.finish())
}

fn textured() -> Result<Value> {
    let mut doc = Doc::new(
        "textured",
        "Cornell box walls and ceiling light with a textured UV sphere (sRGB checker base color, a \
         normal map of domes, a metallic-roughness map of metal and dielectric bands; TEXCOORD_0, \
         NORMAL, TANGENT) and a tiled, textured floor.",
    );
    // Walls without the floor, which gets its own textured quad.
    let (mut white_walls, red_wall, green_wall) = room(0.0, false);
    white_walls.positions.drain(..4);
    white_walls.indices.drain(..6);
    white_walls.indices.iter_mut().for_each(|i| *i -= 4);
    let white = doc.lambert("white", WHITE);
    let red = doc.lambert("red", RED);
    let green = doc.lambert("green", GREEN);
    doc.mesh("walls_white", &white_walls, white);
    doc.mesh("wall_red_left", &red_wall, red);
    doc.mesh("wall_green_right", &green_wall, green);
    cornell_light(&mut doc);

    let tiles = doc.texture("tiles", &tiles_png()?);
    let floor_material = doc.material(
        json!({
            "name": "floor_tiles",
            "pbrMetallicRoughness": {
                "baseColorTexture": { "index": tiles },
                "metallicFactor": 0.0,
                "roughnessFactor": 1.0,
            },
            "extensions": { "KHR_materials_specular": { "specularFactor": 0.0 } },
        }),
        &["KHR_materials_specular"],
    );
    let mut floor = Geometry::default();
    let (sx, sz) = (BOX[0], BOX[2]);
    // One texture repeat (2 × 2 tiles) per 1.4 units.
    let (u, v) = (sx / 1.4, sz / 1.4);
    floor.quad(
        [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(sx, 0.0, 0.0),
            Vec3::new(sx, 0.0, sz),
            Vec3::new(0.0, 0.0, sz),
        ],
        Vec3::Y,
        Some([
            Vec2::new(0.0, v),
            Vec2::new(u, v),
            Vec2::new(u, 0.0),
            Vec2::new(0.0, 0.0),
        ]),
    );
    doc.mesh("floor", &floor, floor_material);

    let checker = doc.texture("checker", &checker_png()?);
    let domes = doc.texture("domes_normal", &domes_png()?);
    let bands = doc.texture("bands_metallic_roughness", &bands_png()?);
    let sphere_material = doc.material(
        json!({
            "name": "textured_sphere",
            "pbrMetallicRoughness": {
                "baseColorTexture": { "index": checker },
                "metallicRoughnessTexture": { "index": bands },
                "metallicFactor": 1.0,
                "roughnessFactor": 1.0,
            },
            "normalTexture": { "index": domes, "scale": 1.0 },
        }),
        &[],
    );
    let r = 1.5;
    let centre = Vec3::new(2.78, r + 1e-3, 2.7);
    // Turned so that the red orientation check (u ≈ 0) faces the camera.
    let mut sphere = sphere_checked(centre, r, true, "textured sphere")?;
    let turn = Quat::from_rotation_y(PI / 2.0 - 0.5);
    for p in &mut sphere.positions {
        *p = centre + turn * (*p - centre);
    }
    for n in sphere.normals.iter_mut().flatten() {
        *n = turn * *n;
    }
    for t in sphere.tangents.iter_mut().flatten() {
        *t = (turn * t.truncate()).extend(t.w);
    }
    doc.mesh("sphere", &sphere, sphere_material);
    doc.camera(
        Vec3::from(CORNELL_EYE),
        Vec3::new(CORNELL_EYE[0], CORNELL_EYE[1], 0.0),
        CORNELL_YFOV,
    );
    Ok(doc.finish())
}
