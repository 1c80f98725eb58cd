use super::*;

/// A mesh placed by two or more nodes is kept once and placed (a prototype in object space);
/// one placed once is flattened; an emissive one is flattened however often it is placed, so
/// that light sampling sees every emitting triangle. Loaded and built, the scene renders the
/// instanced mesh through its placements.
#[test]
fn meshes_placed_twice_are_kept_instanced_unless_they_emit() {
    let mut d = Doc::new();
    let p = d.positions(&TRI);
    d.json["materials"] = j(r#"[{"name":"Grey"},{"name":"Lamp","emissiveFactor":[1,0.5,0]}]"#);
    for (name, material) in [("Shared", 0), ("Single", 0), ("Lamp", 1)] {
        d.mesh(
            name,
            j(&format!(
                r#"[{{"attributes":{{"POSITION":{p}}},"material":{material}}}]"#
            )),
        );
    }
    let place = |d: &mut Doc, mesh: usize, x: f32, mirror: bool| {
        let sx = if mirror { -1.0 } else { 1.0 };
        let n = d.node(j(&format!(
            r#"{{"mesh":{mesh},"translation":[{x},0,-3],"scale":[{sx},2,1]}}"#
        )));
        d.root(n);
    };
    for (k, x) in [0.0, 2.0, 4.0].into_iter().enumerate() {
        place(&mut d, 0, x, k == 1);
    }
    place(&mut d, 1, 6.0, false);
    place(&mut d, 2, 8.0, false);
    place(&mut d, 2, 10.0, false);
    let loaded = parts(&d.gltf());
    assert_eq!(
        loaded.prototypes.len(),
        1,
        "only the shared, non-emissive mesh"
    );
    assert_eq!(loaded.prototypes[0].positions, vec![TRI.map(Vec3::from)]);
    assert_eq!(loaded.placements.len(), 3);
    let x: Vec<f64> = loaded
        .placements
        .iter()
        .map(|p| p.to_world.w_axis.x)
        .collect();
    assert_eq!(x, [0.0, 2.0, 4.0]);
    assert_eq!(
        loaded.placements[1].to_world.x_axis.x, -1.0,
        "the mirror is kept"
    );
    assert_eq!(
        loaded.mesh.len(),
        3,
        "the single mesh and both lamps, flattened"
    );
    let scene = Scene::build(loaded).expect("builds");
    assert_eq!(scene.info.instances, 3);
    assert_eq!(scene.info.instanced_triangles, 3);
    assert_eq!(scene.info.emissive_triangles, 2);
    // A ray down the middle of each placed triangle hits it, mirrored or not, from its front.
    for (k, x) in [0.0f32, 2.0, 4.0].into_iter().enumerate() {
        let sx = if k == 1 { -1.0 } else { 1.0 };
        let o = Vec3::new(x + 0.25 * sx, 0.5, 0.0);
        let ray = pathfarm_tracer::geometry::Ray::new(o, -Vec3::Z);
        let hit = scene.intersect(&ray, f32::INFINITY, 0.5).expect("hit");
        assert_eq!(hit.t, 3.0);
        let si = scene.surface(&ray, &hit);
        assert!((si.p - Vec3::new(o.x, 0.5, -3.0)).length() < 1e-6);
        assert!(si.front && si.ng.z > 0.999, "placement {k}: {:?}", si.ng);
    }
}

/// EXT_mesh_gpu_instancing: a node places its mesh once per row of its TRANSLATION, ROTATION and
/// SCALE accessors (rotations as floats or as normalized shorts), at its world transform times the
/// row's T·R·S, kept instanced; the extension may be required; malformed rows are errors that name
/// the node.
#[test]
fn gpu_instancing_places_a_mesh_once_per_row() {
    let build = |rotation_shorts: bool, scale_rows: usize| {
        let mut d = Doc::new();
        let p = d.positions(&TRI);
        d.mesh(
            "Tree",
            j(&format!(r#"[{{"attributes":{{"POSITION":{p}}}}}]"#)),
        );
        let t = d.floats(&[[0.0f32, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, 7.0, 0.0]]);
        let h = std::f32::consts::FRAC_1_SQRT_2;
        // Identity, 90° about Z, identity.
        let quats = [
            [0.0f32, 0.0, 0.0, 1.0],
            [0.0, 0.0, h, h],
            [0.0, 0.0, 0.0, 1.0],
        ];
        let r = if rotation_shorts {
            let bytes: Vec<u8> = quats
                .iter()
                .flatten()
                .flat_map(|&v| ((v * 32767.0).round() as i16).to_le_bytes())
                .collect();
            let view = d.view(&bytes, None);
            let a = d.accessor(view, 5122, 3, "VEC4");
            d.json["accessors"][a]["normalized"] = Value::from(true);
            a
        } else {
            d.floats(&quats)
        };
        let s = d.floats(&vec![[2.0f32, 2.0, 2.0]; scale_rows]);
        let n = d.node(j(&format!(
            r#"{{"mesh":0,"translation":[0,0,-10],"extensions":{{"EXT_mesh_gpu_instancing":
                {{"attributes":{{"TRANSLATION":{t},"ROTATION":{r},"SCALE":{s}}}}}}}}}"#
        )));
        d.root(n);
        d.json["extensionsUsed"] = j(r#"["EXT_mesh_gpu_instancing"]"#);
        d.json["extensionsRequired"] = j(r#"["EXT_mesh_gpu_instancing"]"#);
        d
    };
    for shorts in [false, true] {
        let loaded = parts(&build(shorts, 3).gltf());
        assert!(loaded.warnings.is_empty(), "{:?}", loaded.warnings);
        assert_eq!(loaded.mesh.len(), 0);
        assert_eq!(loaded.prototypes.len(), 1, "three rows: kept instanced");
        assert_eq!(loaded.placements.len(), 3);
        let flat = loaded.flatten_instances();
        // Each row: the node's translation, then the row's T·R·S (scale 2).
        let want = [
            [[0.0, 0.0, -10.0], [2.0, 0.0, -10.0], [0.0, 2.0, -10.0]],
            [[5.0, 0.0, -10.0], [5.0, 2.0, -10.0], [3.0, 0.0, -10.0]],
            [[0.0, 7.0, -10.0], [2.0, 7.0, -10.0], [0.0, 9.0, -10.0]],
        ];
        for (got, want) in flat.mesh.positions.iter().zip(want) {
            for (g, w) in got.iter().zip(want) {
                assert!(
                    (*g - Vec3::from(w)).length() < 1e-3,
                    "shorts {shorts}: {got:?} against {want:?}"
                );
            }
        }
    }
    // Rows that disagree in number: an error naming the node and the extension.
    assert_contains(
        &error_of(&build(false, 2).gltf()),
        &[
            "node 0",
            "EXT_mesh_gpu_instancing",
            "SCALE has 2 elements but TRANSLATION has 3",
        ],
    );
}
