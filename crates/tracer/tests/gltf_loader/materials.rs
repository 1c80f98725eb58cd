use super::*;

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
