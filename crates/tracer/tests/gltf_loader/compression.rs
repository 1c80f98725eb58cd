use super::*;

// ---------------------------------------------------------------------------------------------
// Compression and texture extensions that web pipelines write: KHR_mesh_quantization,
// EXT_meshopt_compression (and KHR_meshopt_compression), KHR_draco_mesh_compression,
// EXT_texture_webp. Files made by real exporters are under `tests/data/gltf/ext/` (see its README).

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
