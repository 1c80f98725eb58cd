use super::*;

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
