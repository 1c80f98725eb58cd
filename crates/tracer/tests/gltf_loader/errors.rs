use super::*;

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
