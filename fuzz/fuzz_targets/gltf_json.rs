//! `gltf_json`: a structured companion of `gltf_load`. Byte mutations of a glTF file mostly break its
//! JSON or its base64, so they rarely reach the accessor, node, material, camera and light code with
//! values that are wrong in interesting ways. Here the fuzzer's bytes drive an `arbitrary`-derived
//! description of a document (buffers, views, accessors incl. sparse ones, primitives, nodes,
//! materials, textures, cameras, lights), which is written out as `.gltf` JSON with a base64 buffer or
//! as `.glb`, and goes through exactly the same check as `gltf_load`
//! (`pathfarm_tracer::fuzzing::gltf_load`).
//!
//! With `PATHFARM_FUZZ_DUMP=<dir>` set, every generated document is also written to `<dir>` (named by
//! its FNV-1a hash): that is how this target's corpus becomes plain files for `gltf_load`'s corpus,
//! which the stable replay test runs (see docs/fuzzing.md).
#![no_main]

use base64::Engine as _;
use libfuzzer_sys::arbitrary::{self, Arbitrary};
use libfuzzer_sys::fuzz_target;
use serde_json::{json, Map, Value};

/// A 2 × 2 RGBA PNG (red, half-transparent green / blue, transparent white).
const PNG: [u8; 78] = [
    137, 80, 78, 71, 13, 10, 26, 10, 0, 0, 0, 13, 73, 72, 68, 82, 0, 0, 0, 2, 0, 0, 0, 2, 8, 6, 0,
    0, 0, 114, 182, 13, 36, 0, 0, 0, 21, 73, 68, 65, 84, 120, 218, 99, 248, 207, 192, 240, 31, 8,
    27, 24, 128, 52, 8, 48, 0, 0, 67, 211, 8, 121, 120, 206, 33, 204, 0, 0, 0, 0, 73, 69, 78, 68,
    174, 66, 96, 130,
];

/// A number that is usually ordinary and sometimes extreme.
#[derive(Arbitrary, Debug, Clone, Copy)]
enum Num {
    Small(i8),
    Tenth(i16),
    Any(f32),
    Zero,
    One,
    Huge,
    Tiny,
}

impl Num {
    fn f(self) -> f64 {
        match self {
            Num::Small(v) => v as f64,
            Num::Tenth(v) => v as f64 / 10.0,
            // JSON has no NaN or infinity; serde_json writes them as null.
            Num::Any(v) => v as f64,
            Num::Zero => 0.0,
            Num::One => 1.0,
            Num::Huge => 3.0e38,
            Num::Tiny => 1.0e-38,
        }
    }
}

/// A count or length: usually small, sometimes at the edges.
#[derive(Arbitrary, Debug, Clone, Copy)]
enum Count {
    Small(u8),
    Medium(u16),
    Any(u32),
    Max,
}

impl Count {
    fn n(self) -> u64 {
        match self {
            Count::Small(v) => v as u64,
            Count::Medium(v) => v as u64,
            Count::Any(v) => v as u64,
            Count::Max => u32::MAX as u64,
        }
    }
}

#[derive(Arbitrary, Debug)]
struct View {
    buffer: u8,
    offset: Option<Count>,
    length: Count,
    stride: Option<u8>,
}

#[derive(Arbitrary, Debug)]
struct Sparse {
    count: Count,
    indices_view: u8,
    indices_offset: Option<Count>,
    indices_type: u8,
    values_view: u8,
    values_offset: Option<Count>,
}

#[derive(Arbitrary, Debug)]
struct Accessor {
    view: Option<u8>,
    offset: Option<Count>,
    component_type: u8,
    normalized: bool,
    count: Count,
    ty: u8,
    min_max: bool,
    sparse: Option<Sparse>,
}

#[derive(Arbitrary, Debug)]
struct Primitive {
    position: u8,
    normal: Option<u8>,
    texcoord0: Option<u8>,
    texcoord1: Option<u8>,
    tangent: Option<u8>,
    indices: Option<u8>,
    material: Option<u8>,
    mode: Option<u8>,
}

#[derive(Arbitrary, Debug)]
enum Transform {
    None,
    Trs {
        t: Option<[Num; 3]>,
        r: Option<[Num; 4]>,
        s: Option<[Num; 3]>,
    },
    Matrix([Num; 16]),
}

#[derive(Arbitrary, Debug)]
struct Node {
    mesh: Option<u8>,
    camera: Option<u8>,
    light: Option<u8>,
    children: Vec<u8>,
    transform: Transform,
}

#[derive(Arbitrary, Debug)]
struct TextureRef {
    index: u8,
    tex_coord: Option<u8>,
    transform: Option<TextureTransform>,
}

/// KHR_texture_transform.
#[derive(Arbitrary, Debug)]
struct TextureTransform {
    offset: [Num; 2],
    rotation: Num,
    scale: [Num; 2],
    tex_coord: Option<u8>,
}

#[derive(Arbitrary, Debug)]
struct Material {
    base_color: Option<[Num; 4]>,
    base_texture: Option<TextureRef>,
    metallic: Option<Num>,
    roughness: Option<Num>,
    mr_texture: Option<TextureRef>,
    normal_texture: Option<(TextureRef, Num)>,
    emissive: Option<[Num; 3]>,
    emissive_texture: Option<TextureRef>,
    emissive_strength: Option<Num>,
    alpha_mode: u8,
    alpha_cutoff: Option<Num>,
    double_sided: bool,
    ior: Option<Num>,
    transmission: Option<(Num, Option<TextureRef>)>,
    volume: Option<(Num, Num, [Num; 3])>,
    specular: Option<(Num, [Num; 3], Option<TextureRef>)>,
}

#[derive(Arbitrary, Debug)]
enum Image {
    Png,
    PngInView(u8),
    Bytes(Vec<u8>),
    External,
}

#[derive(Arbitrary, Debug)]
enum Camera {
    Perspective {
        yfov: Num,
        znear: Num,
        zfar: Option<Num>,
        aspect: Option<Num>,
    },
    Orthographic {
        xmag: Num,
        ymag: Num,
        znear: Num,
        zfar: Num,
    },
}

#[derive(Arbitrary, Debug)]
struct Light {
    kind: u8,
    color: Option<[Num; 3]>,
    intensity: Option<Num>,
    range: Option<Num>,
    cones: Option<(Num, Num)>,
}

#[derive(Arbitrary, Debug)]
struct Doc {
    glb: bool,
    buffer: Vec<u8>,
    /// Declared byteLength: the real length, or a lie.
    buffer_length: Option<Count>,
    views: Vec<View>,
    accessors: Vec<Accessor>,
    meshes: Vec<Vec<Primitive>>,
    nodes: Vec<Node>,
    scenes: Vec<Vec<u8>>,
    scene: Option<u8>,
    materials: Vec<Material>,
    textures: Vec<(u8, Option<u8>)>,
    samplers: Vec<(u8, u8, u8)>,
    images: Vec<Image>,
    cameras: Vec<Camera>,
    lights: Vec<Light>,
    extensions_required: Vec<u8>,
}

const COMPONENT_TYPES: [u64; 7] = [5120, 5121, 5122, 5123, 5125, 5126, 5124];
const TYPES: [&str; 7] = ["SCALAR", "VEC2", "VEC3", "VEC4", "MAT2", "MAT3", "MAT4"];
const EXTENSIONS: [&str; 10] = [
    "KHR_lights_punctual",
    "KHR_materials_emissive_strength",
    "KHR_materials_ior",
    "KHR_materials_specular",
    "KHR_materials_transmission",
    "KHR_materials_volume",
    "KHR_mesh_quantization",
    "KHR_texture_transform",
    "KHR_draco_mesh_compression",
    "KHR_materials_clearcoat",
];

fn pick<T: Copy>(options: &[T], i: u8) -> T {
    options[i as usize % options.len()]
}

fn nums<const N: usize>(v: &[Num; N]) -> Value {
    json!(v.iter().map(|n| n.f()).collect::<Vec<_>>())
}

fn texture_ref(t: &TextureRef) -> Value {
    let mut o = Map::new();
    o.insert("index".into(), json!(t.index));
    if let Some(c) = t.tex_coord {
        o.insert("texCoord".into(), json!(c % 4));
    }
    if let Some(tt) = &t.transform {
        let mut x = json!({ "offset": nums(&tt.offset), "rotation": tt.rotation.f(),
                            "scale": nums(&tt.scale) });
        if let Some(c) = tt.tex_coord {
            x["texCoord"] = json!(c % 4);
        }
        o.insert("extensions".into(), json!({ "KHR_texture_transform": x }));
    }
    Value::Object(o)
}

fn material(m: &Material) -> Value {
    let mut pbr = Map::new();
    if let Some(c) = &m.base_color {
        pbr.insert("baseColorFactor".into(), nums(c));
    }
    if let Some(t) = &m.base_texture {
        pbr.insert("baseColorTexture".into(), texture_ref(t));
    }
    if let Some(v) = m.metallic {
        pbr.insert("metallicFactor".into(), json!(v.f()));
    }
    if let Some(v) = m.roughness {
        pbr.insert("roughnessFactor".into(), json!(v.f()));
    }
    if let Some(t) = &m.mr_texture {
        pbr.insert("metallicRoughnessTexture".into(), texture_ref(t));
    }
    let mut o = Map::new();
    o.insert("pbrMetallicRoughness".into(), Value::Object(pbr));
    if let Some((t, scale)) = &m.normal_texture {
        let mut r = texture_ref(t);
        r["scale"] = json!(scale.f());
        o.insert("normalTexture".into(), r);
    }
    if let Some(e) = &m.emissive {
        o.insert("emissiveFactor".into(), nums(e));
    }
    if let Some(t) = &m.emissive_texture {
        o.insert("emissiveTexture".into(), texture_ref(t));
    }
    o.insert(
        "alphaMode".into(),
        json!(pick(&["OPAQUE", "MASK", "BLEND", "OTHER"], m.alpha_mode)),
    );
    if let Some(c) = m.alpha_cutoff {
        o.insert("alphaCutoff".into(), json!(c.f()));
    }
    o.insert("doubleSided".into(), json!(m.double_sided));
    let mut ext = Map::new();
    if let Some(s) = m.emissive_strength {
        ext.insert(
            "KHR_materials_emissive_strength".into(),
            json!({ "emissiveStrength": s.f() }),
        );
    }
    if let Some(ior) = m.ior {
        ext.insert("KHR_materials_ior".into(), json!({ "ior": ior.f() }));
    }
    if let Some((factor, texture)) = &m.transmission {
        let mut x = json!({ "transmissionFactor": factor.f() });
        if let Some(t) = texture {
            x["transmissionTexture"] = texture_ref(t);
        }
        ext.insert("KHR_materials_transmission".into(), x);
    }
    if let Some((thickness, distance, color)) = &m.volume {
        ext.insert(
            "KHR_materials_volume".into(),
            json!({ "thicknessFactor": thickness.f(), "attenuationDistance": distance.f(),
                    "attenuationColor": nums(color) }),
        );
    }
    if let Some((factor, color, texture)) = &m.specular {
        let mut x = json!({ "specularFactor": factor.f(), "specularColorFactor": nums(color) });
        if let Some(t) = texture {
            x["specularTexture"] = texture_ref(t);
        }
        ext.insert("KHR_materials_specular".into(), x);
    }
    if !ext.is_empty() {
        o.insert("extensions".into(), Value::Object(ext));
    }
    Value::Object(o)
}

fn accessor(a: &Accessor) -> Value {
    let ty = pick(&TYPES, a.ty);
    let components = match ty {
        "SCALAR" => 1,
        "VEC2" => 2,
        "VEC3" => 3,
        "VEC4" | "MAT2" => 4,
        "MAT3" => 9,
        _ => 16,
    };
    let mut o = Map::new();
    if let Some(v) = a.view {
        o.insert("bufferView".into(), json!(v));
    }
    if let Some(off) = a.offset {
        o.insert("byteOffset".into(), json!(off.n()));
    }
    o.insert(
        "componentType".into(),
        json!(pick(&COMPONENT_TYPES, a.component_type)),
    );
    o.insert("normalized".into(), json!(a.normalized));
    o.insert("count".into(), json!(a.count.n()));
    o.insert("type".into(), json!(ty));
    if a.min_max {
        o.insert("min".into(), json!(vec![-1.0; components]));
        o.insert("max".into(), json!(vec![1.0; components]));
    }
    if let Some(s) = &a.sparse {
        let mut indices = json!({ "bufferView": s.indices_view,
            "componentType": pick(&[5121u64, 5123, 5125, 5126], s.indices_type) });
        if let Some(off) = s.indices_offset {
            indices["byteOffset"] = json!(off.n());
        }
        let mut values = json!({ "bufferView": s.values_view });
        if let Some(off) = s.values_offset {
            values["byteOffset"] = json!(off.n());
        }
        o.insert(
            "sparse".into(),
            json!({ "count": s.count.n(), "indices": indices, "values": values }),
        );
    }
    Value::Object(o)
}

fn primitive(p: &Primitive) -> Value {
    let mut attributes = Map::new();
    attributes.insert("POSITION".into(), json!(p.position));
    for (name, a) in [
        ("NORMAL", p.normal),
        ("TEXCOORD_0", p.texcoord0),
        ("TEXCOORD_1", p.texcoord1),
        ("TANGENT", p.tangent),
    ] {
        if let Some(a) = a {
            attributes.insert(name.into(), json!(a));
        }
    }
    let mut o = Map::new();
    o.insert("attributes".into(), Value::Object(attributes));
    if let Some(i) = p.indices {
        o.insert("indices".into(), json!(i));
    }
    if let Some(m) = p.material {
        o.insert("material".into(), json!(m));
    }
    if let Some(m) = p.mode {
        o.insert("mode".into(), json!(m % 8));
    }
    Value::Object(o)
}

fn node(i: usize, n: &Node) -> Value {
    let mut o = Map::new();
    o.insert("name".into(), json!(format!("node{i}")));
    if let Some(m) = n.mesh {
        o.insert("mesh".into(), json!(m));
    }
    if let Some(c) = n.camera {
        o.insert("camera".into(), json!(c));
    }
    if let Some(l) = n.light {
        o.insert(
            "extensions".into(),
            json!({ "KHR_lights_punctual": { "light": l } }),
        );
    }
    if !n.children.is_empty() {
        o.insert("children".into(), json!(n.children));
    }
    match &n.transform {
        Transform::None => {}
        Transform::Trs { t, r, s } => {
            if let Some(t) = t {
                o.insert("translation".into(), nums(t));
            }
            if let Some(r) = r {
                o.insert("rotation".into(), nums(r));
            }
            if let Some(s) = s {
                o.insert("scale".into(), nums(s));
            }
        }
        Transform::Matrix(m) => {
            o.insert("matrix".into(), nums(m));
        }
    }
    Value::Object(o)
}

fn camera(c: &Camera) -> Value {
    match c {
        Camera::Perspective {
            yfov,
            znear,
            zfar,
            aspect,
        } => {
            let mut p = json!({ "yfov": yfov.f(), "znear": znear.f() });
            if let Some(z) = zfar {
                p["zfar"] = json!(z.f());
            }
            if let Some(a) = aspect {
                p["aspectRatio"] = json!(a.f());
            }
            json!({ "type": "perspective", "perspective": p })
        }
        Camera::Orthographic {
            xmag,
            ymag,
            znear,
            zfar,
        } => json!({ "type": "orthographic", "orthographic": {
            "xmag": xmag.f(), "ymag": ymag.f(), "znear": znear.f(), "zfar": zfar.f() } }),
    }
}

fn light(l: &Light) -> Value {
    let kind = pick(&["point", "spot", "directional", "area"], l.kind);
    let mut o = Map::new();
    o.insert("type".into(), json!(kind));
    if let Some(c) = &l.color {
        o.insert("color".into(), nums(c));
    }
    if let Some(i) = l.intensity {
        o.insert("intensity".into(), json!(i.f()));
    }
    if let Some(r) = l.range {
        o.insert("range".into(), json!(r.f()));
    }
    if let Some((inner, outer)) = l.cones {
        o.insert(
            "spot".into(),
            json!({ "innerConeAngle": inner.f(), "outerConeAngle": outer.f() }),
        );
    }
    Value::Object(o)
}

fn glb(json: &[u8], bin: &[u8]) -> Vec<u8> {
    // Chunks are padded to 4 bytes: JSON with spaces, BIN with zeros.
    let mut json = json.to_vec();
    json.resize(json.len().next_multiple_of(4), b' ');
    let mut bin = bin.to_vec();
    bin.resize(bin.len().next_multiple_of(4), 0);
    let mut out = b"glTF".to_vec();
    out.extend(2u32.to_le_bytes());
    out.extend(0u32.to_le_bytes());
    out.extend((json.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(&json);
    out.extend((bin.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(&bin);
    let n = out.len() as u32;
    out[8..12].copy_from_slice(&n.to_le_bytes());
    out
}

fn build(d: &Doc) -> Vec<u8> {
    let mut buffer = d.buffer.clone();
    let b64 = base64::engine::general_purpose::STANDARD;
    // Images whose bytes live in a view get the PNG appended to the buffer and a view of their own.
    let mut views: Vec<Value> = d
        .views
        .iter()
        .map(|v| {
            let mut o = json!({ "buffer": v.buffer % 2, "byteLength": v.length.n() });
            if let Some(off) = v.offset {
                o["byteOffset"] = json!(off.n());
            }
            if let Some(s) = v.stride {
                o["byteStride"] = json!(s);
            }
            o
        })
        .collect();
    let images: Vec<Value> = d
        .images
        .iter()
        .map(|image| match image {
            Image::Png => json!({ "uri": format!("data:image/png;base64,{}", b64.encode(PNG)) }),
            Image::PngInView(mime) => {
                let offset = buffer.len();
                buffer.extend(PNG);
                views.push(json!({ "buffer": 0, "byteOffset": offset, "byteLength": PNG.len() }));
                json!({ "bufferView": views.len() - 1,
                        "mimeType": pick(&["image/png", "image/jpeg"], *mime) })
            }
            Image::Bytes(bytes) => {
                json!({ "uri": format!("data:image/png;base64,{}", b64.encode(bytes)) })
            }
            Image::External => json!({ "uri": "texture.png" }),
        })
        .collect();
    let length = d.buffer_length.map_or(buffer.len() as u64, |c| c.n());
    let buffer_json = if d.glb {
        json!({ "byteLength": length })
    } else {
        json!({ "byteLength": length,
                "uri": format!("data:application/octet-stream;base64,{}", b64.encode(&buffer)) })
    };
    let required: Vec<&str> = d
        .extensions_required
        .iter()
        .map(|&i| pick(&EXTENSIONS, i))
        .collect();
    let mut root = json!({
        "asset": { "version": "2.0" },
        "buffers": [buffer_json],
        "bufferViews": views,
        "accessors": d.accessors.iter().map(accessor).collect::<Vec<_>>(),
        "meshes": d.meshes.iter().map(|prims| json!({
            "primitives": prims.iter().map(primitive).collect::<Vec<_>>() })).collect::<Vec<_>>(),
        "nodes": d.nodes.iter().enumerate().map(|(i, n)| node(i, n)).collect::<Vec<_>>(),
        "scenes": d.scenes.iter().map(|nodes| json!({ "nodes": nodes })).collect::<Vec<_>>(),
        "materials": d.materials.iter().map(material).collect::<Vec<_>>(),
        "textures": d.textures.iter().map(|(source, sampler)| {
            let mut t = json!({ "source": source });
            if let Some(s) = sampler { t["sampler"] = json!(s); }
            t
        }).collect::<Vec<_>>(),
        "samplers": d.samplers.iter().map(|&(s, t, mag)| json!({
            "wrapS": pick(&[33071u64, 33648, 10497, 1], s),
            "wrapT": pick(&[33071u64, 33648, 10497, 1], t),
            "magFilter": pick(&[9728u64, 9729, 1], mag) })).collect::<Vec<_>>(),
        "images": images,
        "cameras": d.cameras.iter().map(camera).collect::<Vec<_>>(),
        "extensionsUsed": EXTENSIONS,
        "extensions": { "KHR_lights_punctual": {
            "lights": d.lights.iter().map(light).collect::<Vec<_>>() } },
    });
    if !required.is_empty() {
        root["extensionsRequired"] = json!(required);
    }
    if let Some(s) = d.scene {
        root["scene"] = json!(s);
    }
    let text = serde_json::to_vec(&root).expect("a serde_json::Value always serializes");
    if d.glb {
        glb(&text, &buffer)
    } else {
        text
    }
}

fn fnv1a64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

fuzz_target!(|doc: Doc| {
    let bytes = build(&doc);
    if let Some(dir) = std::env::var_os("PATHFARM_FUZZ_DUMP") {
        let ext = if doc.glb { "glb" } else { "gltf" };
        let path = std::path::Path::new(&dir).join(format!("{:016x}.{ext}", fnv1a64(&bytes)));
        std::fs::write(&path, &bytes).expect("PATHFARM_FUZZ_DUMP is a writable directory");
    }
    pathfarm_tracer::fuzzing::gltf_load(&bytes);
});
