use super::*;

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
