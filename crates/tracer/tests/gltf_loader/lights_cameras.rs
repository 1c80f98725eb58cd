use super::*;

/// Photometric intensities become radiometric at 683 lm/W: 6830 cd is 10 W/sr, 2049 lx × 0.5 is
/// 1.5 W/m².
#[test]
fn punctual_lights() {
    let mut d = triangle_doc("{}");
    d.json["extensionsUsed"] = j(r#"["KHR_lights_punctual"]"#);
    d.json["extensions"] = j(r#"{"KHR_lights_punctual":{"lights":[
        {"type":"point","color":[1,0.5,0.25],"intensity":6830,"range":5},
        {"type":"spot","intensity":1366,"spot":{"innerConeAngle":0.2,"outerConeAngle":0.5}},
        {"type":"directional","color":[0.5,0.5,0.5],"intensity":2049}]}}"#);
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let point = d.node(j(
        r#"{"translation":[1,2,3],"extensions":{"KHR_lights_punctual":{"light":0}}}"#,
    ));
    let spot = d.node(j(&format!(
        r#"{{"translation":[0,4,0],"rotation":[-{h},0,0,{h}],"extensions":{{"KHR_lights_punctual":{{"light":1}}}}}}"#
    )));
    let sun = d.node(j(&format!(
        r#"{{"rotation":[0,{h},0,{h}],"extensions":{{"KHR_lights_punctual":{{"light":2}}}}}}"#
    )));
    // The point light's node is a child of a translated parent.
    let parent = d.node(j(&format!(
        r#"{{"translation":[10,0,0],"children":[{point}]}}"#
    )));
    d.root(parent);
    d.root(spot);
    d.root(sun);
    let parts = parts(&d.gltf());
    assert_eq!(parts.punctual_lights.len(), 3);
    match parts.punctual_lights[0] {
        PunctualLight::Point(l) => {
            assert!(close3(l.position, Vec3::new(11.0, 2.0, 3.0)));
            assert!(close3(l.intensity, Vec3::new(10.0, 5.0, 2.5)));
        }
        other => panic!("{other:?}"),
    }
    match parts.punctual_lights[1] {
        PunctualLight::Spot(l) => {
            assert!(close3(l.position, Vec3::new(0.0, 4.0, 0.0)));
            assert!(
                close3(l.direction, Vec3::NEG_Y),
                "spot points down: {}",
                l.direction
            );
            assert!(
                (l.cos_inner - 0.2f32.cos()).abs() < 1e-6
                    && (l.cos_outer - 0.5f32.cos()).abs() < 1e-6
            );
            assert!(close3(l.intensity, Vec3::splat(2.0)));
        }
        other => panic!("{other:?}"),
    }
    match parts.punctual_lights[2] {
        PunctualLight::Directional(l) => {
            assert!(
                close3(l.direction, Vec3::NEG_X),
                "travels along the node's −Z: {}",
                l.direction
            );
            assert!(close3(l.illuminance, Vec3::splat(1.5)));
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(
        parts
            .warnings
            .iter()
            .filter(|w| w.contains("range"))
            .count(),
        1,
        "{:?}",
        parts.warnings
    );
}

#[test]
fn orthographic_camera() {
    let mut d = triangle_doc("{}");
    d.push(
        "cameras",
        j(r#"{"type":"orthographic","orthographic":{"xmag":3,"ymag":2.5,"znear":0.1,"zfar":100}}"#),
    );
    let cam = d.node(j(r#"{"camera":0,"translation":[0,0,5],"scale":[3,3,3]}"#));
    d.root(cam);
    let camera = parts(&d.gltf()).camera.unwrap();
    assert_eq!(
        camera.projection,
        Projection::Orthographic(pathfarm_tracer::camera::Orthographic { ymag: 2.5 })
    );
    assert!(close3(
        camera.to_world.translation.into(),
        Vec3::new(0.0, 0.0, 5.0)
    ));
    assert!(
        close3(camera.to_world.transform_vector3(Vec3::X), Vec3::X),
        "scale stripped"
    );
}

#[test]
fn camera_chosen_by_name() {
    let mut d = triangle_doc("{}");
    d.push(
        "cameras",
        j(r#"{"name":"wide","type":"perspective","perspective":{"yfov":1.2,"znear":0.1}}"#),
    );
    d.push(
        "cameras",
        j(r#"{"name":"tele","type":"perspective","perspective":{"yfov":0.3,"znear":0.1}}"#),
    );
    let a = d.node(j(r#"{"name":"rig_a","camera":0,"translation":[0,0,10]}"#));
    // A scaled, rotated node: the camera keeps only rotation and translation.
    let b = d.node(j(
        r#"{"name":"rig_b","camera":1,"translation":[5,0,0],"rotation":[0,0.7071068,0,0.7071068],
                         "scale":[2,2,2]}"#,
    ));
    d.root(a);
    d.root(b);
    let bytes = d.gltf();
    let yfov = |options: &LoadOptions| {
        let c = load_parts(&bytes, &NoExternalResources, options)
            .unwrap()
            .camera
            .unwrap();
        match c.projection {
            Projection::Perspective(p) => (p.yfov, c),
            other => panic!("{other:?}"),
        }
    };
    assert_eq!(
        yfov(&LoadOptions::default()).0,
        1.2,
        "first in traversal order"
    );
    let (fov, cam) = yfov(&LoadOptions {
        camera: Some("tele".into()),
        ..LoadOptions::default()
    });
    assert_eq!(fov, 0.3);
    let forward = cam.to_world.transform_vector3(Vec3::NEG_Z);
    assert!(close3(forward, Vec3::NEG_X), "{forward}");
    assert!((cam.to_world.matrix3.determinant() - 1.0).abs() < 1e-5);
    assert_eq!(
        yfov(&LoadOptions {
            camera: Some("rig_b".into()),
            ..LoadOptions::default()
        })
        .0,
        0.3,
        "node names match too"
    );
    let e = error_with(
        &bytes,
        &NoExternalResources,
        &LoadOptions {
            camera: Some("nope".into()),
            ..LoadOptions::default()
        },
    );
    assert_contains(
        &e,
        &[
            "camera \"nope\" not found",
            "\"wide\"",
            "\"tele\"",
            "node 2 \"rig_b\"",
        ],
    );
}
