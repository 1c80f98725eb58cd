use super::*;

// ---------------------------------------------------------------------------------------------
// The committed corpus (tests/data/gltf): `valid/` files load, `broken/` files fail with the
// substrings listed in their `.expect` files. `regenerate_corpus` (ignored) rewrites them.

fn corpus_files() -> Vec<(String, Vec<u8>, Option<Vec<String>>)> {
    let mut out: Vec<(String, Vec<u8>, Option<Vec<String>>)> = Vec::new();
    // Valid.
    let mut lit = textured_doc(&png(2, 2, &[200; 16]));
    lit.json["extensionsUsed"] = j(r#"["KHR_lights_punctual"]"#);
    lit.json["extensions"] =
        j(r#"{"KHR_lights_punctual":{"lights":[{"type":"point","intensity":5}]}}"#);
    let l = lit.node(j(
        r#"{"translation":[0,0,2],"extensions":{"KHR_lights_punctual":{"light":0}}}"#,
    ));
    lit.root(l);
    lit.push(
        "cameras",
        j(r#"{"name":"cam","type":"perspective","perspective":{"yfov":0.8,"znear":0.1}}"#),
    );
    let c = lit.node(j(r#"{"camera":0,"translation":[0.3,0.3,3]}"#));
    lit.root(c);
    out.push(("valid/textured_lit.gltf".into(), lit.gltf(), None));
    out.push(("valid/textured_lit.glb".into(), lit.glb(), None));
    // Broken.
    let glb = lit.glb();
    let expect = |v: &[&str]| Some(v.iter().map(|s| s.to_string()).collect());
    out.push((
        "broken/truncated.glb".into(),
        glb[..glb.len() / 2].to_vec(),
        expect(&["GLB:", "exceeds file size"]),
    ));
    let mut lying = glb.clone();
    lying[12..16].copy_from_slice(&99999u32.to_le_bytes());
    out.push((
        "broken/lying_chunk_length.glb".into(),
        lying,
        expect(&["GLB: chunk length 99999 exceeds file size"]),
    ));
    out.push((
        "broken/bad_json.gltf".into(),
        br#"{"asset":{"version":"2.0"},"nodes":[{]}"#.to_vec(),
        expect(&["not a glTF file"]),
    ));
    let mut oob = triangle_doc("{}");
    oob.json["accessors"][0]["count"] = Value::from(30);
    out.push((
        "broken/accessor_out_of_bounds.gltf".into(),
        oob.gltf(),
        expect(&[
            "accessor 0 (POSITION of mesh 0 \"Tri\", primitive 0)",
            "exceeds",
        ]),
    ));
    let mut idx = triangle_doc("{}");
    let i = idx.indices(&[0, 1, 812], 5123);
    idx.json["meshes"][0]["primitives"][0]["indices"] = Value::from(i);
    out.push((
        "broken/index_out_of_range.gltf".into(),
        idx.gltf(),
        expect(&["index 812 out of range (accessor 0 has 3 vertices)"]),
    ));
    out.push((
        "broken/missing_buffer.gltf".into(),
        triangle_doc("{}").gltf_external("missing.bin"),
        expect(&["buffer 0: cannot read \"missing.bin\""]),
    ));
    let mut basisu = triangle_doc("{}");
    basisu.json["extensionsRequired"] = j(r#"["KHR_texture_basisu"]"#);
    basisu.json["extensionsUsed"] = j(r#"["KHR_texture_basisu"]"#);
    out.push((
        "broken/required_basisu.gltf".into(),
        basisu.gltf(),
        expect(&["required extension KHR_texture_basisu is not supported"]),
    ));
    let mut nan = Doc::new();
    let p = nan.positions(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, f32::NAN, 0.0]]);
    nan.mesh(
        "Box",
        j(&format!(r#"[{{"attributes":{{"POSITION":{p}}}}}]"#)),
    );
    let n = nan.node(j(r#"{"mesh":0}"#));
    nan.root(n);
    out.push((
        "broken/nan_position.gltf".into(),
        nan.gltf(),
        expect(&[
            "accessor 0 (POSITION of mesh 0 \"Box\", primitive 0): NaN component at element 2",
        ]),
    ));
    let mut b64bad = triangle_doc("{}");
    b64bad.json["buffers"] =
        j(r#"[{"byteLength":36,"uri":"data:application/octet-stream;base64,#not-base64#"}]"#);
    out.push((
        "broken/bad_base64.gltf".into(),
        gltf::json::serialize::to_vec(&b64bad.json).unwrap(),
        expect(&["buffer 0: bad data URI"]),
    ));
    out.push((
        "broken/bad_image.gltf".into(),
        textured_doc(b"\x89PNG\r\n\x1a\nnot really").gltf(),
        expect(&["image 0 \"tex\": cannot decode"]),
    ));
    out
}

#[test]
#[ignore = "rewrites tests/data/gltf from the generator above"]
fn regenerate_corpus() {
    for (name, bytes, expect) in corpus_files() {
        let path = corpus_dir().join(&name);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, bytes).unwrap();
        if let Some(expect) = expect {
            std::fs::write(path.with_extension("expect"), expect.join("\n") + "\n").unwrap();
        }
    }
}

#[test]
fn committed_corpus() {
    let dir = corpus_dir();
    let mut seen = 0;
    for sub in ["valid", "broken"] {
        let mut entries: Vec<PathBuf> = std::fs::read_dir(dir.join(sub))
            .unwrap_or_else(|e| panic!("{}: {e}", dir.join(sub).display()))
            .map(|e| e.unwrap().path())
            .filter(|p| matches!(p.extension().and_then(|e| e.to_str()), Some("gltf" | "glb")))
            .collect();
        entries.sort();
        for path in entries {
            seen += 1;
            let bytes = std::fs::read(&path).unwrap();
            let result = load(&bytes, &NoExternalResources, &LoadOptions::default());
            match (sub, result) {
                ("valid", Ok(scene)) => assert!(scene.info.triangles > 0, "{}", path.display()),
                ("valid", Err(e)) => panic!("{}: {e}", path.display()),
                (_, Ok(_)) => panic!("{} loaded but should fail", path.display()),
                (_, Err(GltfError::Internal(e))) => {
                    panic!("{}: internal error {e}", path.display())
                }
                (_, Err(e)) => {
                    let expect = std::fs::read_to_string(path.with_extension("expect")).unwrap();
                    for line in expect.lines().filter(|l| !l.is_empty()) {
                        assert!(
                            e.to_string().contains(line),
                            "{}: {e:?} lacks {line:?}",
                            path.display()
                        );
                    }
                }
            }
        }
    }
    assert_eq!(
        seen,
        corpus_files().len(),
        "the committed corpus is stale: run the ignored regenerate_corpus test"
    );
}
