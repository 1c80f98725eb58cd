use super::*;

// ---------------------------------------------------------------------------------------------
// The shared scenes.

fn shared_scenes() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes");
    if dir.join("manifest.json").is_file() {
        Some(dir)
    } else {
        eprintln!("skipped: shared scenes not found at {}", dir.display());
        None
    }
}

#[test]
fn shared_scenes_load() {
    let Some(dir) = shared_scenes() else { return };
    let manifest: Value = j(&std::fs::read_to_string(dir.join("manifest.json")).unwrap());
    let entries = manifest.as_object().unwrap();
    assert!(entries.len() >= 3);
    for (name, entry) in entries {
        let file = entry["file"].as_str().unwrap();
        let bytes = std::fs::read(dir.join(file)).unwrap();
        let scene = load(&bytes, &NoExternalResources, &LoadOptions::default())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        let want = entry["triangles"].as_u64().unwrap() as usize;
        assert_eq!(scene.info.triangles, want, "{name}: triangles");
        assert_eq!(scene.info.degenerate_dropped, 0, "{name}");
        assert!(
            scene.mesh.normals.is_none() && scene.mesh.uv0.is_none(),
            "{name}: flat, untextured"
        );
        assert!(
            scene.info.warnings.is_empty(),
            "{name}: {:?}",
            scene.info.warnings
        );
        assert!(scene.info.emissive_triangles > 0, "{name}");
        // The camera is the file's, with its yfov.
        let json: Value = j(std::str::from_utf8(&bytes).unwrap());
        let yfov = json["cameras"][0]["perspective"]["yfov"].as_f64().unwrap() as f32;
        match scene.camera.projection {
            Projection::Perspective(p) => assert!((p.yfov - yfov).abs() < 1e-6, "{name}"),
            other => panic!("{name}: {other:?}"),
        }
    }
}

#[test]
fn cornell_box_materials_and_camera() {
    let Some(dir) = shared_scenes() else { return };
    let bytes = std::fs::read(dir.join("cornell.gltf")).unwrap();
    let parts = parts(&bytes);
    assert_eq!(parts.mesh.len(), 32);
    assert_eq!(parts.materials.len(), 4);
    let by_name = |n: &str| {
        parts
            .materials
            .iter()
            .find(|m| m.name.as_deref() == Some(n))
            .unwrap()
    };
    let white = by_name("white");
    assert!(close3(
        white.base_color.truncate(),
        Vec3::new(0.725, 0.71, 0.68)
    ));
    assert_eq!(
        (white.specular, white.metallic, white.roughness),
        (0.0, 0.0, 1.0)
    );
    assert!(white.emissive == Vec3::ZERO);
    let green = by_name("green");
    assert!(green.double_sided && green.specular == 0.0);
    let light = by_name("light");
    assert!(
        close3(light.emissive, Vec3::new(16.0, 12.0, 6.0)),
        "{}",
        light.emissive
    );
    assert!(!light.double_sided);
    assert_eq!(light.base_color.truncate(), Vec3::ZERO);
    let camera = parts.camera.unwrap();
    assert!(
        matches!(camera.projection, Projection::Perspective(p) if (p.yfov - 0.686_047_9).abs() < 1e-6)
    );
    assert!(close3(
        camera.to_world.translation.into(),
        Vec3::new(2.78, 2.73, -8.0)
    ));
    // Rotated 180° about Y: the camera's −Z looks down +Z, into the box.
    let forward: Vec3 = camera.to_world.transform_vector3(Vec3::NEG_Z);
    assert!(close3(forward, Vec3::Z), "{forward}");
    // The light faces down: its triangles' front normal is −Y.
    let light_index = parts
        .materials
        .iter()
        .position(|m| m.name.as_deref() == Some("light"))
        .unwrap() as u32;
    let tris: Vec<usize> = (0..parts.mesh.len())
        .filter(|&i| parts.mesh.material[i] == light_index)
        .collect();
    assert_eq!(tris.len(), 2);
    for i in tris {
        assert!(parts.mesh.cross(i).normalize().y < -0.999);
    }
}
