//! Animated scenes (node translation, rotation and scale on meshes, the camera and a lamp): a
//! frame renders the same bits as the still file with the animated nodes placed where the
//! animation puts them; what does not move is shared between frames; still files are untouched.

#[path = "common/gltf_doc.rs"]
mod gltf_doc;

use gltf::json::Value;
use gltf_doc::{j, Doc};
use pathfarm_tracer::gltf::{
    frame_time, load, AnimatedScene, LoadOptions, NoExternalResources, SceneSource, TimeSpan,
};
use pathfarm_tracer::{render_image, Accumulation, RenderSettings, Scene};
use std::sync::Arc;

/// The corners of an axis-aligned unit cube and its faces, counter-clockwise seen from outside.
fn cube() -> (Vec<[f32; 3]>, Vec<u32>) {
    let corners = (0..8)
        .map(|i| {
            let c = |bit: usize| if i & bit == 0 { -0.5 } else { 0.5 };
            [c(1), c(2), c(4)]
        })
        .collect();
    let faces = [
        [0, 4, 6, 2],
        [1, 3, 7, 5],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 2, 3, 1],
        [4, 5, 7, 6],
    ];
    let idx = faces
        .iter()
        .flat_map(|[a, b, c, d]| [*a, *b, *c, *a, *c, *d])
        .collect();
    (corners, idx)
}

/// A quad's two triangles, counter-clockwise as given.
fn quad(d: &mut Doc, corners: [[f32; 3]; 4], material: usize) -> usize {
    let p = d.positions(&corners);
    let i = d.indices(&[0, 1, 2, 0, 2, 3]);
    d.push(
        "meshes",
        j(&format!(
            r#"{{"primitives":[{{"attributes":{{"POSITION":{p}}},"indices":{i},"material":{material}}}]}}"#
        )),
    )
}

/// Nodes of [`room`].
struct Room {
    doc: Doc,
    mover: usize,
    camera: usize,
    lamp: usize,
}

/// A floor, an emissive panel, a box placed twice (still, and by the node "Mover"), a camera and
/// a point lamp; `animate` adds the animations.
fn room(animate: bool) -> Room {
    let mut d = Doc::new();
    d.json["materials"] = j(r#"[
        {"pbrMetallicRoughness":{"baseColorFactor":[0.6,0.6,0.6,1],"metallicFactor":0}},
        {"pbrMetallicRoughness":{"baseColorFactor":[0.8,0.2,0.1,1],"metallicFactor":0.2,"roughnessFactor":0.4}},
        {"pbrMetallicRoughness":{"baseColorFactor":[0,0,0,1]},"emissiveFactor":[1,0.9,0.8]}]"#);
    d.json["cameras"] = j(r#"[{"type":"perspective","perspective":{"yfov":0.9,"znear":0.1}}]"#);
    d.json["extensionsUsed"] = j(r#"["KHR_lights_punctual"]"#);
    d.json["extensions"] = j(r#"{"KHR_lights_punctual":{"lights":[
        {"type":"point","intensity":3000,"color":[1,1,1]}]}}"#);
    let floor = quad(
        &mut d,
        [[-5., 0., -5.], [-5., 0., 5.], [5., 0., 5.], [5., 0., -5.]],
        0,
    );
    let panel = quad(
        &mut d,
        [
            [-1., 3.9, -1.],
            [1., 3.9, -1.],
            [1., 3.9, 1.],
            [-1., 3.9, 1.],
        ],
        2,
    );
    let (corners, idx) = cube();
    let (p, i) = (d.positions(&corners), d.indices(&idx));
    let boxed = d.push(
        "meshes",
        j(&format!(
            r#"{{"name":"Box","primitives":[{{"attributes":{{"POSITION":{p}}},"indices":{i},"material":1}}]}}"#
        )),
    );
    for (mesh, name) in [(floor, "Floor"), (panel, "Panel")] {
        let n = d.node(j(&format!(r#"{{"name":"{name}","mesh":{mesh}}}"#)));
        d.root(n);
    }
    let still = d.node(j(&format!(
        r#"{{"name":"Still box","mesh":{boxed},"translation":[-2,0.5,-1.5]}}"#
    )));
    let mover = d.node(j(&format!(
        r#"{{"name":"Mover","mesh":{boxed},"translation":[0,0.5,0]}}"#
    )));
    let camera = d.node(j(r#"{"name":"Cam","camera":0,"translation":[0,1.5,6]}"#));
    let lamp = d.node(j(
        r#"{"name":"Lamp","translation":[0,3,1],"extensions":{"KHR_lights_punctual":{"light":0}}}"#,
    ));
    for n in [still, mover, camera, lamp] {
        d.root(n);
    }
    if animate {
        let t3 = d.times(&[0.0, 1.0, 2.0]);
        let t2 = d.times(&[0.0, 2.0]);
        let step = d.times(&[0.0, 1.0]);
        let (s, c) = (60f32.to_radians().sin(), 60f32.to_radians().cos());
        let moves = d.floats(&[[-1.5, 0.5, 0.0], [0.0, 1.0, 0.0], [1.5, 0.5, 0.5]]);
        let turns = d.floats(&[[0.0, 0.0, 0.0, 1.0], [0.0, s, 0.0, c]]);
        // Per key: in-tangent, value, out-tangent.
        let grows = d.floats(&[
            [0.0; 3],
            [1.0; 3],
            [0.5, 0.0, 0.0],
            [0.0; 3],
            [0.6, 1.2, 0.8],
            [0.0; 3],
        ]);
        let dolly = d.floats(&[
            [0.0; 3],
            [0.0, 1.5, 6.0],
            [1.0, 0.5, -1.0],
            [0.5, 0.0, 0.0],
            [1.0, 2.0, 5.0],
            [0.0; 3],
        ]);
        let (s, c) = (7.5f32.to_radians().sin(), 7.5f32.to_radians().cos());
        let pans = d.floats(&[[0.0, -s, 0.0, c], [0.0, s, 0.0, c]]);
        let hops = d.floats(&[[-1.0, 3.0, 1.0], [1.0, 3.2, 2.0]]);
        d.animation(
            "MoverAction",
            &[
                (mover, "translation", t3, moves, "LINEAR"),
                (mover, "rotation", t2, turns, "LINEAR"),
                (mover, "scale", t2, grows, "CUBICSPLINE"),
            ],
        );
        d.animation(
            "CameraAction",
            &[
                (camera, "translation", t2, dolly, "CUBICSPLINE"),
                (camera, "rotation", t2, pans, "LINEAR"),
            ],
        );
        d.animation("LampAction", &[(lamp, "translation", step, hops, "STEP")]);
    }
    Room {
        doc: d,
        mover,
        camera,
        lamp,
    }
}

fn render(scene: &Scene) -> Accumulation {
    let settings = RenderSettings {
        seed: 3,
        ..RenderSettings::new(24, 20)
    };
    render_image(scene, &settings, 8, 0..4, &|_| {})
}

fn animated(bytes: &[u8]) -> AnimatedScene {
    AnimatedScene::load(bytes, &NoExternalResources, &LoadOptions::default())
        .unwrap_or_else(|e| panic!("{e}"))
}

/// The still file that frame `time` stands for: no animations, each animated node's TRS the
/// animation's values at `time`.
fn still_at(room: &Room, scene: &AnimatedScene, time: f32) -> Vec<u8> {
    let mut doc = room.doc.clone();
    doc.json.as_object_mut().unwrap().remove("animations");
    for node in [room.mover, room.camera, room.lamp] {
        let trs = scene.node_trs_at(node, time).expect("an animated node");
        let n = &mut doc.json["nodes"][node];
        n["translation"] = Value::from(trs.translation.to_vec());
        n["rotation"] = Value::from(trs.rotation.to_vec());
        n["scale"] = Value::from(trs.scale.to_vec());
    }
    doc.gltf()
}

#[test]
fn a_frame_renders_as_the_still_file_of_its_pose() {
    let room = room(true);
    let scene = animated(&room.doc.gltf());
    assert_eq!(
        scene.time_span(),
        Some(TimeSpan {
            start: 0.0,
            end: 2.0
        })
    );
    // Before the first key, on keys, between them (every interpolation), after the last.
    for time in [-0.5, 0.0, 0.3, 1.0, 1.3, 2.0, 3.5] {
        let frame = scene.scene_at(time).unwrap();
        let still = load(
            &still_at(&room, &scene, time),
            &NoExternalResources,
            &LoadOptions::default(),
        )
        .unwrap();
        // The box is kept instanced in both (placed twice); the moving node moves its placement.
        assert_eq!(frame.info.instances, 2);
        assert_eq!(still.info.instances, 2);
        assert_eq!(
            format!("{:?}", frame.camera),
            format!("{:?}", still.camera),
            "camera at {time}"
        );
        assert_eq!(
            format!("{:?}", frame.lights.punctual),
            format!("{:?}", still.lights.punctual),
            "lamp at {time}"
        );
        let (a, b) = (render(&frame), render(&still));
        assert!(a.pixels.iter().any(|p| p.mean()[0] > 0.0));
        assert!(a == b, "frame at {time} s differs from its still file");
    }
    // The poses are the animation's: LINEAR halfway between keys, STEP holding, clamped ends.
    let at = |node, t| scene.node_trs_at(node, t).unwrap();
    assert_eq!(at(room.mover, 0.5).translation, [-0.75, 0.75, 0.0]);
    assert_eq!(at(room.mover, -1.0).translation, [-1.5, 0.5, 0.0]);
    assert_eq!(at(room.mover, 9.0).translation, [1.5, 0.5, 0.5]);
    assert_eq!(at(room.lamp, 0.99).translation, [-1.0, 3.0, 1.0]);
    assert_eq!(at(room.lamp, 1.0).translation, [1.0, 3.2, 2.0]);
    // The spline at s = 0.5 over [0, 2]: 0.5·1 + 2·0.125·0.5 + 0.5·0.6 + 2·(−0.125)·0 = 0.925.
    assert!((at(room.mover, 1.0).scale[0] - 0.925).abs() < 1e-6);
    // The camera and the lamp moved between frames.
    let (a, b) = (scene.scene_at(0.0).unwrap(), scene.scene_at(2.0).unwrap());
    assert_ne!(format!("{:?}", a.camera), format!("{:?}", b.camera));
    assert_ne!(
        format!("{:?}", a.lights.punctual),
        format!("{:?}", b.lights.punctual)
    );
}

#[test]
fn what_does_not_move_is_shared_between_frames() {
    let scene = animated(&room(true).doc.gltf());
    assert!(!scene.world_rebuilt_per_frame());
    let (a, b) = (scene.scene_at(0.25).unwrap(), scene.scene_at(1.75).unwrap());
    // The floor and the panel: one mesh, one BVH, for every frame.
    assert!(Arc::ptr_eq(&a.mesh, &b.mesh) && Arc::ptr_eq(&a.bvh, &b.bvh));
    assert!(Arc::ptr_eq(&a.textures, &b.textures));
    // The box: one prototype with its BVH, placed where each frame puts it.
    assert_eq!(a.instances.prototypes.len(), 1);
    assert!(Arc::ptr_eq(
        &a.instances.prototypes[0],
        &b.instances.prototypes[0]
    ));
    // Held by the loaded scene and the two frames.
    assert_eq!(Arc::strong_count(&a.bvh), 3);
    let moved = |s: &Scene| {
        s.instances
            .instances
            .iter()
            .map(|i| i.to_world.translation)
            .collect::<Vec<_>>()
    };
    assert_ne!(moved(&a), moved(&b));
}

/// A mesh that one moving node places is kept instanced (the still loader flattens it): each
/// frame places it where the still file's node is, and the surfaces agree.
#[test]
fn a_mesh_placed_once_by_a_moving_node_is_placed_each_frame() {
    let mut room = room(true);
    // Only the mover places the box.
    room.doc.json["scenes"][0]["nodes"] = j(&format!(
        "[0,1,{},{},{}]",
        room.mover, room.camera, room.lamp
    ));
    let scene = animated(&room.doc.gltf());
    for time in [0.4, 1.6] {
        let frame = scene.scene_at(time).unwrap();
        let still = load(
            &still_at(&room, &scene, time),
            &NoExternalResources,
            &LoadOptions::default(),
        )
        .unwrap();
        assert_eq!((frame.info.instances, still.info.instances), (1, 0));
        assert_eq!(frame.info.triangles, still.info.triangles);
        // The placed box is the flattened one, to rounding.
        let (lo, hi) = (frame.info.bounds_min, frame.info.bounds_max);
        assert!((lo - still.info.bounds_min).abs().max_element() < 1e-3);
        assert!((hi - still.info.bounds_max).abs().max_element() < 1e-3);
        let (a, b) = (render(&frame), render(&still));
        let mean = |acc: &Accumulation| {
            acc.pixels.iter().map(|p| p.mean()[0]).sum::<f64>() / acc.pixels.len() as f64
        };
        assert!(
            (mean(&a) - mean(&b)).abs() < 0.02 * mean(&b),
            "{} against {}",
            mean(&a),
            mean(&b)
        );
    }
}

/// An emitter that moves is world-space triangles (lights are sampled over them): every frame
/// builds the world's BVH again, with the emitter where its node is.
#[test]
fn a_moving_emitter_is_rebuilt_each_frame() {
    let mut room = room(true);
    // The panel's node slides along x.
    let t = room.doc.times(&[0.0, 1.0]);
    let slide = room.doc.floats(&[[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]]);
    room.doc
        .animation("PanelAction", &[(1, "translation", t, slide, "LINEAR")]);
    let scene = animated(&room.doc.gltf());
    assert!(scene.world_rebuilt_per_frame());
    let (a, b) = (scene.scene_at(0.0).unwrap(), scene.scene_at(1.0).unwrap());
    assert!(!Arc::ptr_eq(&a.bvh, &b.bvh));
    assert_eq!(
        (a.info.emissive_triangles, b.info.emissive_triangles),
        (2, 2)
    );
    let centre = |s: &Scene| {
        let l = &s.lights.area.triangles;
        l.iter()
            .map(|&t| s.mesh.positions[t as usize][0].x)
            .sum::<f32>()
            / l.len() as f32
    };
    assert!((centre(&b) - centre(&a) - 2.0).abs() < 1e-5);
}

/// A file without animations: `SceneSource` hands it to the still loader (the same scene, no
/// copy), and even the animated loader builds it exactly as the still loader does.
#[test]
fn still_files_are_unaffected() {
    let bytes = room(false).doc.gltf();
    let still = load(&bytes, &NoExternalResources, &LoadOptions::default()).unwrap();
    let source = SceneSource::load(&bytes, &NoExternalResources, &LoadOptions::default()).unwrap();
    assert!(matches!(source, SceneSource::Still(_)));
    assert_eq!(source.time_span(), None);
    let reference = render(&still);
    assert!(render(&source.scene_at(7.0).unwrap()) == reference);
    let at_rest = animated(&bytes);
    assert_eq!(at_rest.time_span(), None);
    assert!(render(&at_rest.scene_at(0.0).unwrap()) == reference);
    // The still loader renders an animated file at rest, and says so.
    let moving = room(true).doc.gltf();
    let rest = load(&moving, &NoExternalResources, &LoadOptions::default()).unwrap();
    assert!(rest
        .info
        .warnings
        .iter()
        .any(|w| w.contains("rendered at rest")));
    let source = SceneSource::load(&moving, &NoExternalResources, &LoadOptions::default()).unwrap();
    assert!(matches!(source, SceneSource::Animated(_)));
}

#[test]
fn frames_and_times() {
    assert_eq!(frame_time(48, 24.0), 2.0);
    assert_eq!(frame_time(1, 24.0), (1.0f64 / 24.0) as f32);
    // Blender's frames 1–48 at 24 fps: keys from 1/24 s to 2 s.
    let span = TimeSpan {
        start: (1.0f64 / 24.0) as f32,
        end: 2.0,
    };
    assert_eq!(span.frames(24.0), 1..=48);
    assert_eq!(span.frames(48.0), 2..=96);
}

/// The cost of a frame against a load, on the room with a floor of a million triangles: the load
/// parses the file and builds the floor's BVH once; a frame moves the box, the camera and the lamp
/// and builds the tree over two placements. (`cargo test --test animated_scenes -- --ignored
/// --nocapture frame_cost`; the figures are printed.)
#[test]
#[ignore]
fn frame_cost() {
    let mut room = room(true);
    let n = 708; // 2 · 707² ≈ 1.0 M triangles
    let mut p = Vec::new();
    for z in 0..=n {
        for x in 0..=n {
            let at = |k: usize| -5.0 + 10.0 * k as f32 / n as f32;
            p.push([at(x), 0.001 * ((x * 7 + z * 13) % 5) as f32, at(z)]);
        }
    }
    let mut idx = Vec::new();
    let v = |x: usize, z: usize| (z * (n + 1) + x) as u32;
    for z in 0..n {
        for x in 0..n {
            idx.extend([v(x, z), v(x, z + 1), v(x + 1, z + 1)]);
            idx.extend([v(x, z), v(x + 1, z + 1), v(x + 1, z)]);
        }
    }
    let (pa, ia) = (room.doc.positions(&p), room.doc.indices(&idx));
    room.doc.json["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = Value::from(pa);
    room.doc.json["meshes"][0]["primitives"][0]["indices"] = Value::from(ia);
    let bytes = room.doc.gltf();
    let time = |f: &mut dyn FnMut()| {
        let mut best = f64::MAX;
        for _ in 0..3 {
            let t = std::time::Instant::now();
            f();
            best = best.min(t.elapsed().as_secs_f64());
        }
        best
    };
    let mut scene = None;
    let load_s = time(&mut || scene = Some(animated(&bytes)));
    let scene = scene.unwrap();
    let mut k = 0;
    let frame_s = time(&mut || {
        k += 1;
        let f = scene.scene_at(0.1 * k as f32).unwrap();
        assert_eq!(f.info.triangles, 2 * n * n + 2 + 12);
    });
    let still = still_at(&room, &scene, 0.5);
    let still_s = time(&mut || {
        load(&still, &NoExternalResources, &LoadOptions::default()).unwrap();
    });
    eprintln!(
        "{} triangles: AnimatedScene::load {:.1} ms, scene_at {:.3} ms a frame, the still file of \
         a frame loaded anew {:.1} ms",
        2 * n * n + 14,
        load_s * 1e3,
        frame_s * 1e3,
        still_s * 1e3
    );
}
