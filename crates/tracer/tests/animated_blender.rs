//! The animated scene Blender exports (`scenes/suite/animated.glb`, made by
//! `scenes/suite/make_animated.py`): a sliding cube, a camera on a turning empty, a moving lamp, a
//! bar bent by an armature and a sphere with a shape key, over frames 1–48 at 24 fps. Every frame
//! loads from the one parse, renders, and moves what the animation moves — where Blender itself
//! puts it (`animated.blender.json`: Blender's evaluation of frames 1, 24 and 48).

use glam::Vec3;
use pathfarm_tracer::gltf::{frame_time, LoadOptions, NoExternalResources, SceneSource};
use pathfarm_tracer::light::PunctualLight;
use pathfarm_tracer::{render_image, RenderSettings, Scene};
use serde_json::Value;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

fn read(name: &str) -> Vec<u8> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes/suite")
        .join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn bytes() -> Vec<u8> {
    read("animated.glb")
}

fn point(v: &Value) -> Vec3 {
    let c = |k: usize| v[k].as_f64().unwrap() as f32;
    Vec3::new(c(0), c(1), c(2))
}

/// Each frame where Blender evaluates it: the camera, the lamp and the cube at their positions,
/// and every vertex of the armature-bent bar and the shape-keyed sphere among the frame's deformed
/// triangles (and no other), to Blender's six decimals.
#[test]
fn frames_are_where_blender_puts_them() {
    let bytes = bytes();
    let source = SceneSource::load(&bytes, &NoExternalResources, &LoadOptions::default()).unwrap();
    let blender: Value = serde_json::from_slice(&read("animated.blender.json")).unwrap();
    for frame in [1, 24, 48] {
        let scene = source.scene_at(frame_time(frame, 24.0)).unwrap();
        let want = &blender[frame.to_string()];
        let near = |a: Vec3, b: Vec3, what: &str| {
            assert!(
                (a - b).length() < 2e-5,
                "frame {frame}, {what}: {a} against Blender's {b}"
            )
        };
        near(
            scene.camera.to_world.translation.into(),
            point(&want["Camera"]),
            "camera",
        );
        let PunctualLight::Point(lamp) = scene.lights.punctual[0] else {
            panic!("a point lamp");
        };
        near(lamp.position, point(&want["Bulb"]), "lamp");
        // The cube is the one instanced mesh; the last prototype is the frame's deformed ones.
        let cube = scene
            .instances
            .instances
            .iter()
            .find(|i| i.prototype == 0)
            .unwrap();
        near(
            cube.to_world.translation.into(),
            point(&want["Cube"]),
            "cube",
        );
        let ours: Vec<Vec3> = scene
            .instances
            .prototypes
            .last()
            .unwrap()
            .mesh
            .positions
            .iter()
            .flatten()
            .copied()
            .collect();
        let theirs: Vec<Vec3> = want["deformed"]
            .as_array()
            .unwrap()
            .iter()
            .map(point)
            .collect();
        let farthest = |from: &[Vec3], to: &[Vec3]| {
            from.iter()
                .map(|p| {
                    to.iter()
                        .map(|q| (*p - *q).length())
                        .fold(f32::MAX, f32::min)
                })
                .fold(0.0, f32::max)
        };
        let (a, b) = (farthest(&theirs, &ours), farthest(&ours, &theirs));
        assert!(
            a < 2e-5 && b < 2e-5,
            "frame {frame}: Blender's deformed vertices {a} from ours, ours {b} from Blender's"
        );
    }
}

#[test]
fn blender_animation_renders_frame_by_frame() {
    let bytes = bytes();
    let started = Instant::now();
    let source = SceneSource::load(&bytes, &NoExternalResources, &LoadOptions::default()).unwrap();
    let load_seconds = started.elapsed().as_secs_f64();
    let SceneSource::Animated(anim) = &source else {
        panic!("the file has animations");
    };
    assert!(
        anim.warnings().is_empty(),
        "warnings: {:?}",
        anim.warnings()
    );
    // Blender's timeline, frames 1 to 48, exported at frame / 24 s.
    let span = source.time_span().unwrap();
    assert_eq!(span.frames(24.0), 1..=48);
    // The still parts are shared: the floor, wall and panel (an emitter that does not move).
    assert!(!anim.world_rebuilt_per_frame());

    let mut frames: Vec<Scene> = Vec::new();
    let started = Instant::now();
    for frame in [1, 24, 48] {
        frames.push(anim.scene_at(frame_time(frame, 24.0)).unwrap());
    }
    let frame_seconds = started.elapsed().as_secs_f64() / 3.0;
    eprintln!(
        "animated.glb: load {:.2} ms, scene_at {:.2} ms a frame ({} triangles stored, {} placed)",
        load_seconds * 1e3,
        frame_seconds * 1e3,
        frames[0].info.triangles,
        frames[0].info.instanced_triangles
    );
    let (first, last) = (&frames[0], &frames[2]);
    assert!(Arc::ptr_eq(&first.bvh, &last.bvh) && Arc::ptr_eq(&first.mesh, &last.mesh));
    assert_eq!(first.info.emissive_triangles, 2);
    assert_eq!(first.info.punctual_lights, 1);
    // The camera turns with its empty, the lamp rises, the cube slides.
    assert_ne!(format!("{:?}", first.camera), format!("{:?}", last.camera));
    assert_ne!(
        format!("{:?}", first.lights.punctual),
        format!("{:?}", frames[1].lights.punctual)
    );
    let placements = |s: &Scene| {
        s.instances
            .instances
            .iter()
            .map(|i| i.to_world.translation)
            .collect::<Vec<_>>()
    };
    assert_ne!(placements(first), placements(last));
    // The bar and the sphere deform: their triangles are this frame's own.
    let deformed = |s: &Scene| s.instances.prototypes.last().unwrap().mesh.bounds();
    let (a, b) = (deformed(first), deformed(&frames[1]));
    assert!((a.0 - b.0).abs().max_element() > 0.05 || (a.1 - b.1).abs().max_element() > 0.05);

    let settings = RenderSettings {
        seed: 1,
        ..RenderSettings::new(32, 32)
    };
    for (k, scene) in frames.iter().enumerate() {
        let acc = render_image(scene, &settings, 16, 0..4, &|_| {});
        assert_eq!(acc.invalid_count, 0, "frame {k}");
        let mean = acc.pixels.iter().map(|p| p.mean()[1]).sum::<f64>() / acc.pixels.len() as f64;
        assert!(mean > 1e-3, "frame {k} is lit: {mean}");
    }
}
