use super::*;

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
