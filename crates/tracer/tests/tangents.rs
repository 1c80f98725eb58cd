//! MikkTSpace tangents for normal-mapped primitives without TANGENT: the loader's tangents against
//! an independent port of the reference implementation (the `mikktspace` crate, libm `acos`, the
//! reference's own sorting and welding) on a UV sphere, a bumpy grid with mirrored UVs and a
//! cylinder with a UV seam and degenerate triangles, each under a node transform; the handedness
//! of mirrored UVs; what is stored only when needed; the limits; and a normal map of a known
//! constant tilt rendered against the exact answer.

use base64::Engine as _;
use glam::{DMat3, DMat4, DQuat, DVec3, Vec3, Vec4};
use pathfarm_tracer::camera::{Camera, Orthographic, Projection};
use pathfarm_tracer::gltf::{load_parts, LoadOptions, NoExternalResources};
use pathfarm_tracer::light::{DirectionalLight, PunctualLight};
use pathfarm_tracer::scene::SceneParts;
use pathfarm_tracer::{render_image, RenderSettings, Scene};
use serde_json::{json, Value};
use std::f64::consts::PI;

/// An indexed triangle mesh as a glTF primitive holds it (glTF UVs: v down the image).
#[derive(Clone, Default)]
struct MeshData {
    positions: Vec<[f32; 3]>,
    normals: Option<Vec<[f32; 3]>>,
    uv: Vec<[f32; 2]>,
    indices: Vec<u32>,
}

impl MeshData {
    fn triangles(&self) -> impl Iterator<Item = [usize; 3]> + '_ {
        self.indices
            .chunks_exact(3)
            .map(|c| [c[0] as usize, c[1] as usize, c[2] as usize])
    }
}

/// A 2×2 PNG of one colour.
fn png(rgb: [u8; 3]) -> Vec<u8> {
    let px: Vec<u8> = (0..4).flat_map(|_| [rgb[0], rgb[1], rgb[2], 255]).collect();
    let img = image::RgbaImage::from_raw(2, 2, px).expect("2×2 pixels");
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .expect("encodes");
    out.into_inner()
}

/// A .gltf holding `mesh` on one node (`node`: its JSON, without the mesh), with a material that
/// has a normal texture of colour `normal_rgb` (or no material at all when `None`).
fn gltf(mesh: &MeshData, node: Value, normal_rgb: Option<[u8; 3]>, mode: u32) -> Vec<u8> {
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut add = |bytes: Vec<u8>, component: u32, count: usize, ty: &str, extra: Value| {
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        views.push(json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len()}));
        bin.extend(bytes);
        let mut a = json!({"bufferView": views.len() - 1, "componentType": component,
            "count": count, "type": ty});
        if let (Some(a), Value::Object(extra)) = (a.as_object_mut(), extra) {
            a.extend(extra);
        }
        accessors.push(a);
        accessors.len() - 1
    };
    let floats = |v: &[f32]| -> Vec<u8> { v.iter().flat_map(|x| x.to_le_bytes()).collect() };
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for p in &mesh.positions {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let n = mesh.positions.len();
    let pos = add(
        floats(mesh.positions.as_flattened()),
        5126,
        n,
        "VEC3",
        json!({"min": lo, "max": hi}),
    );
    let uv = add(floats(mesh.uv.as_flattened()), 5126, n, "VEC2", json!({}));
    let mut attributes = json!({"POSITION": pos, "TEXCOORD_0": uv});
    if let Some(normals) = &mesh.normals {
        attributes["NORMAL"] = json!(add(
            floats(normals.as_flattened()),
            5126,
            n,
            "VEC3",
            json!({})
        ));
    }
    let idx: Vec<u8> = mesh.indices.iter().flat_map(|i| i.to_le_bytes()).collect();
    let indices = add(idx, 5125, mesh.indices.len(), "SCALAR", json!({}));
    let mut primitive = json!({"attributes": attributes, "indices": indices, "mode": mode});
    let mut doc = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "meshes": [{"name": "M", "primitives": []}],
    });
    if let Some(rgb) = normal_rgb {
        primitive["material"] = json!(0);
        let b64 = base64::engine::general_purpose::STANDARD.encode(png(rgb));
        doc["images"] = json!([{"uri": format!("data:image/png;base64,{b64}")}]);
        doc["textures"] = json!([{"source": 0}]);
        doc["materials"] = json!([{"normalTexture": {"index": 0},
            "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 1.0}}]);
    }
    doc["meshes"][0]["primitives"] = json!([primitive]);
    let mut node = node;
    node["mesh"] = json!(0);
    doc["nodes"] = json!([node]);
    let b64 = base64::engine::general_purpose::STANDARD.encode(&bin);
    doc["buffers"] = json!([{"byteLength": bin.len(),
        "uri": format!("data:application/octet-stream;base64,{b64}")}]);
    doc["bufferViews"] = json!(views);
    doc["accessors"] = json!(accessors);
    serde_json::to_vec(&doc).expect("serializes")
}

fn parts(bytes: &[u8]) -> SceneParts {
    load_parts(bytes, &NoExternalResources, &LoadOptions::default())
        .unwrap_or_else(|e| panic!("load failed: {e}"))
}

/// The reference's tangents (per corner, bitangent sign in w), the way an exporter computes them:
/// on v' = 1 − v (v up), with the face normal where the mesh has no normals. `None` where it
/// computed none (it then writes its placeholder: tangent X, bitangent Y, magnitudes 1, sign −1).
fn oracle(mesh: &MeshData) -> Vec<[Option<[f32; 4]>; 3]> {
    struct G<'a> {
        m: &'a MeshData,
        tris: Vec<[usize; 3]>,
        out: Vec<[Option<[f32; 4]>; 3]>,
    }
    impl mikktspace::Geometry for G<'_> {
        fn num_faces(&self) -> usize {
            self.tris.len()
        }
        fn num_vertices_of_face(&self, _: usize) -> usize {
            3
        }
        fn position(&self, f: usize, v: usize) -> [f32; 3] {
            self.m.positions[self.tris[f][v]]
        }
        fn normal(&self, f: usize, v: usize) -> [f32; 3] {
            match &self.m.normals {
                Some(n) => Vec3::from(n[self.tris[f][v]]).normalize().to_array(),
                None => {
                    let [a, b, c] = self.tris[f].map(|i| Vec3::from(self.m.positions[i]));
                    (b - a).cross(c - a).normalize_or_zero().to_array()
                }
            }
        }
        fn tex_coord(&self, f: usize, v: usize) -> [f32; 2] {
            let [u, v] = self.m.uv[self.tris[f][v]];
            [u, 1.0 - v]
        }
        fn set_tangent(
            &mut self,
            t: [f32; 3],
            b: [f32; 3],
            mag_s: f32,
            mag_t: f32,
            preserves: bool,
            f: usize,
            v: usize,
        ) {
            let placeholder =
                t == [1.0, 0.0, 0.0] && b == [0.0, 1.0, 0.0] && mag_s == 1.0 && mag_t == 1.0;
            let w = if preserves { 1.0 } else { -1.0 };
            self.out[f][v] = (!placeholder).then_some([t[0], t[1], t[2], w]);
        }
    }
    let tris: Vec<[usize; 3]> = mesh.triangles().collect();
    let mut g = G {
        m: mesh,
        out: vec![[None; 3]; tris.len()],
        tris,
    };
    assert!(mikktspace::generate_tangents(&mut g));
    g.out
}

/// A node with rotation, non-uniform scale and translation (`mirror`: one scale negative), and
/// its matrix.
fn node(mirror: bool) -> (Value, DMat4) {
    let q = DQuat::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
    let q32 = q.as_quat().to_array();
    let s = [2.0f32, 0.5, if mirror { -1.5 } else { 1.5 }];
    let t = [1.0f32, 2.0, 3.0];
    let m = DMat4::from_scale_rotation_translation(
        Vec3::from(s).as_dvec3(),
        DQuat::from_array(q32.map(f64::from)),
        Vec3::from(t).as_dvec3(),
    );
    (json!({"rotation": q32, "scale": s, "translation": t}), m)
}

/// Loads `mesh` under `node` with a normal map and checks every emitted triangle's tangents against
/// the oracle's, transformed as glTF transforms a TANGENT (xyz by the upper 3×3, w times the sign of
/// its determinant; two corners swapped under a mirroring transform). Returns the emitted tangents
/// with the original triangle of each.
fn check_against_oracle(what: &str, mesh: &MeshData, mirror: bool) -> Vec<(usize, [Vec4; 3])> {
    let (node_json, world) = node(mirror);
    let parts = parts(&gltf(mesh, node_json, Some([128, 128, 255]), 4));
    let tangents = parts.mesh.tangents.as_ref().expect("tangents stored");
    let want = oracle(mesh);
    let m3 = DMat3::from_mat4(world);
    let sign = m3.determinant().signum() as f32;
    let order = if mirror { [0, 2, 1] } else { [0, 1, 2] };
    let (mut next, mut compared, mut skipped, mut worst) = (0, 0, 0, 0f32);
    let mut out = Vec::new();
    for (k, t) in mesh.triangles().enumerate() {
        let p = order.map(|i| {
            world
                .transform_point3(Vec3::from(mesh.positions[t[i]]).as_dvec3())
                .as_vec3()
        });
        let emitted = parts.mesh.positions.get(next);
        let matches = emitted.is_some_and(|e| (0..3).all(|i| (e[i] - p[i]).length() < 1e-4));
        if !matches {
            // Dropped by the loader: it must be a zero-area triangle.
            let area = (p[1] - p[0]).cross(p[2] - p[0]).length();
            assert!(area < 1e-6, "{what}: triangle {k} missing (area {area})");
            continue;
        }
        let got = tangents[next];
        next += 1;
        for (corner, &i) in order.iter().enumerate() {
            let g = got[corner];
            assert!(
                (g.truncate().length() - 1.0).abs() < 1e-5,
                "{what}: triangle {k} corner {i}: {g} is not a unit tangent"
            );
            let Some(o) = want[k][i].map(Vec4::from) else {
                // The reference computed no tangent here (a triangle degenerate in UV with no
                // healthy neighbour); the loader gave it the triangle's own.
                skipped += 1;
                continue;
            };
            let xyz = (m3 * o.truncate().as_dvec3()).normalize().as_vec3();
            let e = (g.truncate() - xyz).length();
            worst = worst.max(e);
            assert!(
                e < 1e-5 && g.w == o.w * sign,
                "{what}: triangle {k} corner {i}: got {g}, reference {o} → {xyz}, {}",
                o.w * sign
            );
            compared += 1;
        }
        out.push((k, got));
    }
    assert_eq!(
        next,
        parts.mesh.len(),
        "{what}: every emitted triangle matched"
    );
    eprintln!("{what}: {compared} corners compared, {skipped} without a reference tangent, worst {worst:e}");
    assert!(
        compared >= 9 * (compared + skipped) / 10,
        "{what}: too few compared"
    );
    out
}

/// A UV sphere: a seam at u = 0/1, and at each pole a ring of vertices at the same point (so one
/// triangle of each polar quad has zero area, and the loader drops it).
fn uv_sphere(rings: u32, segments: u32) -> MeshData {
    let mut m = MeshData::default();
    let mut normals = Vec::new();
    for i in 0..=rings {
        for j in 0..=segments {
            // Exactly one point at each pole and at u = 0 and 1 (sin π and sin 2π are not 0).
            let theta = PI * i as f64 / rings as f64;
            let phi = 2.0 * PI * (j % segments) as f64 / segments as f64;
            let (st, ct) = match i {
                0 => (0.0, 1.0),
                _ if i == rings => (0.0, -1.0),
                _ => theta.sin_cos(),
            };
            let p = [st * phi.cos(), ct, -st * phi.sin()];
            m.positions.push(p.map(|x| x as f32 * 1.5));
            normals.push(p.map(|x| x as f32));
            m.uv.push([j as f32 / segments as f32, i as f32 / rings as f32]);
        }
    }
    let at = |i: u32, j: u32| i * (segments + 1) + j;
    for i in 0..rings {
        for j in 0..segments {
            let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
            m.indices.extend([a, b, c, a, c, d]);
        }
    }
    m.normals = Some(normals);
    m
}

/// A bumpy grid over [−1, 1]² with u = |x|: the UVs mirrored about x = 0, whose column of vertices
/// both halves share.
fn mirrored_grid(n: u32) -> MeshData {
    let mut m = MeshData::default();
    let mut normals = Vec::new();
    for i in 0..=n {
        for j in 0..=n {
            let (x, y) = (
                -1.0 + 2.0 * j as f64 / n as f64,
                -1.0 + 2.0 * i as f64 / n as f64,
            );
            let z = 0.2 * (2.0 * x).sin() * (1.5 * y).cos();
            let (dzdx, dzdy) = (
                0.4 * (2.0 * x).cos() * (1.5 * y).cos(),
                -0.3 * (2.0 * x).sin() * (1.5 * y).sin(),
            );
            m.positions.push([x as f32, y as f32, z as f32]);
            normals.push(
                DVec3::new(-dzdx, -dzdy, 1.0)
                    .normalize()
                    .as_vec3()
                    .to_array(),
            );
            m.uv.push([x.abs() as f32, (0.5 - 0.5 * y) as f32]);
        }
    }
    let at = |i: u32, j: u32| i * (n + 1) + j;
    for i in 0..n {
        for j in 0..n {
            m.indices.extend([
                at(i, j),
                at(i, j + 1),
                at(i + 1, j + 1),
                at(i, j),
                at(i + 1, j + 1),
                at(i + 1, j),
            ]);
        }
    }
    m.normals = Some(normals);
    m
}

/// An open cylinder with a UV seam (the column at φ = 0 twice, u = 0 and u = 1), triangles of the
/// side whose three UVs are one point (degenerate in UV, their tangents borrowed from healthy
/// neighbours), a cap whose UVs are all one point (degenerate in UV, no healthy neighbour: its
/// normals differ from the side's) and a zero-area triangle. `collapse`: with the collapsed UVs.
fn seamed_cylinder(segments: u32, rows: u32, collapse: bool) -> MeshData {
    let mut m = MeshData::default();
    let mut normals = Vec::new();
    for i in 0..=rows {
        for j in 0..=segments {
            // The seam's two columns at exactly the same points.
            let phi = 2.0 * PI * (j % segments) as f64 / segments as f64;
            let (s, c) = phi.sin_cos();
            m.positions
                .push([c as f32, i as f32 / rows as f32 * 2.0, -s as f32]);
            normals.push([c as f32, 0.0, -s as f32]);
            m.uv.push([j as f32 / segments as f32, 1.0 - i as f32 / rows as f32]);
        }
    }
    let at = |i: u32, j: u32| i * (segments + 1) + j;
    for i in 0..rows {
        for j in 0..segments {
            let (a, b, c, d) = (at(i, j), at(i, j + 1), at(i + 1, j + 1), at(i + 1, j));
            m.indices.extend([a, b, c, a, c, d]);
        }
    }
    // Collapse the UVs of triangle [a, b, c] of a few quads of the middle row to one point.
    for j in if collapse { &[3, 8, 12][..] } else { &[] } {
        let (r, j) = (rows / 2, *j);
        let uv = m.uv[at(r, j) as usize];
        for v in [at(r, j + 1), at(r + 1, j + 1)] {
            m.uv[v as usize] = uv;
        }
    }
    // The top cap: a fan with its own vertices, every UV the same.
    let centre = m.positions.len() as u32;
    let top = 2.0f32;
    m.positions.push([0.0, top, 0.0]);
    normals.push([0.0, 1.0, 0.0]);
    m.uv.push([0.5, 0.5]);
    for j in 0..=segments {
        let phi = 2.0 * PI * j as f64 / segments as f64;
        let (s, c) = phi.sin_cos();
        m.positions.push([c as f32, top, -s as f32]);
        normals.push([0.0, 1.0, 0.0]);
        m.uv.push([0.5, 0.5]);
        if j > 0 {
            let k = m.positions.len() as u32 - 1;
            m.indices.extend([centre, k - 1, k]);
        }
    }
    // A zero-area triangle (two corners at one point) on the side.
    m.indices.extend([at(1, 1), at(1, 1), at(2, 2)]);
    m.normals = Some(normals);
    m
}

#[test]
fn uv_sphere_tangents_match_the_reference() {
    let mesh = uv_sphere(12, 24);
    let got = check_against_oracle("UV sphere", &mesh, false);
    // The loader dropped the 2 × 24 zero-area polar triangles.
    assert_eq!(got.len(), 12 * 24 * 2 - 2 * 24);
    check_against_oracle("UV sphere, mirrored node", &mesh, true);
}

#[test]
fn mirrored_uvs_match_the_reference_and_flip_the_sign() {
    let mesh = mirrored_grid(16);
    let got = check_against_oracle("mirrored grid", &mesh, false);
    let (mut left, mut right) = (0, 0);
    for (k, t) in got {
        let tri = &mesh.indices[3 * k..3 * k + 3];
        let x: f32 = tri.iter().map(|&i| mesh.positions[i as usize][0]).sum();
        // u = |x|: on the left half u grows to −x, a mirrored mapping (w = −1); on the right, w = +1.
        let want = if x < 0.0 { -1.0 } else { 1.0 };
        assert!(
            t.iter().all(|c| c.w == want),
            "triangle {k} (x sum {x}): {t:?}"
        );
        if x < 0.0 {
            left += 1;
        } else {
            right += 1;
        }
    }
    assert_eq!((left, right), (256, 256));
    // Under a mirroring node, every sign flips.
    for (k, t) in check_against_oracle("mirrored grid, mirrored node", &mesh, true) {
        let tri = &mesh.indices[3 * k..3 * k + 3];
        let x: f32 = tri.iter().map(|&i| mesh.positions[i as usize][0]).sum();
        let want = if x < 0.0 { 1.0 } else { -1.0 };
        assert!(t.iter().all(|c| c.w == want), "triangle {k}: {t:?}");
    }
}

#[test]
fn seams_and_degenerate_uvs_match_the_reference() {
    let mesh = seamed_cylinder(16, 6, true);
    let got = check_against_oracle("seamed cylinder", &mesh, false);
    // Every triangle but the zero-area one is kept.
    assert_eq!(got.len(), mesh.indices.len() / 3 - 1);
    // Without normals, each face's own normal is used: still the reference's answer. (Not with
    // the collapsed UVs: there, with faceted normals, the weld that keeps the lowest index, which
    // the loader uses for its bounded cost, gives a few corners beside the UV-degenerate triangles
    // a tangent where the reference's weld gives none, or another neighbour's; see gltf/tangents.rs.)
    let flat = MeshData {
        normals: None,
        ..seamed_cylinder(16, 6, false)
    };
    check_against_oracle("seamed cylinder without normals", &flat, false);
}

#[test]
fn tangents_only_for_normal_mapped_primitives_and_within_limits() {
    // No normal map: no tangents stored, none computed.
    let mesh = uv_sphere(4, 8);
    let p = parts(&gltf(&mesh, json!({}), None, 4));
    assert!(p.mesh.tangents.is_none());
    // A fan with more corners at its centre than MikkTSpace is run for: per-triangle tangents and
    // a warning naming the primitive, not a stack overflow.
    let n = 3000u32;
    let mut fan = MeshData::default();
    fan.positions.push([0.0, 0.0, 0.0]);
    fan.uv.push([0.5, 0.5]);
    for i in 0..=n {
        let a = 6.0 * i as f64 / n as f64;
        fan.positions.push([a.cos() as f32, a.sin() as f32, 0.0]);
        fan.uv
            .push([0.5 + 0.5 * a.cos() as f32, 0.5 - 0.5 * a.sin() as f32]);
    }
    fan.indices = (0..n + 2).collect();
    let p = parts(&gltf(&fan, json!({}), Some([128, 128, 255]), 6));
    assert_eq!(p.mesh.len(), n as usize);
    assert!(
        p.warnings.iter().any(|w| w.contains("mesh 0 \"M\", primitive 0")
            && w.contains("per-triangle tangents")),
        "{:?}",
        p.warnings
    );
    // Per-triangle tangents of this fan: u along +X, image up along +Y: (1, 0, 0, +1).
    let t = p.mesh.tangents.as_ref().expect("tangents");
    let bad: Vec<_> = t
        .iter()
        .flatten()
        .filter(|t| (**t - Vec4::new(1.0, 0.0, 0.0, 1.0)).length() >= 1e-4)
        .collect();
    assert!(
        bad.is_empty(),
        "{} {:?}",
        bad.len(),
        &bad[..bad.len().min(5)]
    );
}

/// A plane facing the camera, its left half with mirrored UVs (u = |x|), and a normal map of one
/// colour: a constant tilt in tangent space. Lit by a sun, each half shows ρ/π · E · (n · l) with n
/// the tilted normal in world space: toward +u is toward +X on the right half and −X on the left;
/// toward +y of the map ("up" in the image) is +Y on both. Wrong tangents or signs light a half
/// at the other half's value.
#[test]
fn a_constant_normal_map_tilt_shades_as_the_tilted_normal() {
    // Tilt 30° toward +u, or toward image up; the sun 30° from the zenith toward +X or +Y.
    let t = 30f64.to_radians();
    let byte = |x: f64| (((x + 1.0) / 2.0) * 255.0).round() as u8;
    let cases = [
        (
            "tilt +u, sun +X",
            [byte(t.sin()), 128, byte(t.cos())],
            DVec3::new(t.sin(), 0.0, t.cos()),
        ),
        (
            "tilt up, sun +Y",
            [128, byte(t.sin()), byte(t.cos())],
            DVec3::new(0.0, t.sin(), t.cos()),
        ),
    ];
    let mut grid = mirrored_grid(2);
    for p in &mut grid.positions {
        *p = [p[0] * 3.0, p[1] * 3.0, 0.0];
    }
    grid.normals = Some(vec![[0.0, 0.0, 1.0]; grid.positions.len()]);
    for (what, rgb, towards_sun) in cases {
        let mut parts = parts(&gltf(&grid, json!({}), Some(rgb), 4));
        let (rho, e) = (1.0f64, 2.0f64);
        parts.materials[0].base_color = Vec4::new(rho as f32, rho as f32, rho as f32, 1.0);
        parts.materials[0].specular = 0.0;
        parts.punctual_lights = vec![PunctualLight::Directional(DirectionalLight {
            direction: (-towards_sun).as_vec3(),
            illuminance: Vec3::splat(e as f32),
        })];
        parts.camera = Some(Camera::new(
            Projection::Orthographic(Orthographic { ymag: 1.0 }),
            glam::Affine3A::from_translation(Vec3::new(0.0, 0.0, 5.0)),
        ));
        let scene = Scene::build(parts).expect("builds");
        let settings = RenderSettings::new(16, 8);
        let acc = render_image(&scene, &settings, 8, 0..2, &|_| {});
        // The map's decoded tangent-space normal.
        let m = rgb.map(|c| 2.0 * c as f64 / 255.0 - 1.0);
        for half in [-1.0, 1.0] {
            // On the left half u grows toward −X.
            let n = DVec3::new(half * m[0], m[1], m[2]).normalize();
            let exact = rho / PI * e * n.dot(towards_sun).max(0.0);
            for y in 0..8 {
                for x in 0..16 {
                    if (x < 8) != (half < 0.0) {
                        continue;
                    }
                    let got = acc.pixels[y * 16 + x].mean()[0];
                    assert!(
                        (got - exact).abs() < 2e-3 * exact,
                        "{what}, pixel ({x}, {y}): {got}, exact {exact}"
                    );
                }
            }
        }
    }
}
