//! Deforming meshes in animated scenes: morph targets (weights from the node, the mesh or a
//! channel) and skins (joint matrices from the joints' world transforms and the inverse bind
//! matrices, JOINTS_n / WEIGHTS_n), checked vertex by vertex; and the errors that name the
//! animation, channel, skin or primitive at fault.

#[path = "common/gltf_doc.rs"]
mod gltf_doc;

use glam::{Mat4, Quat, Vec3};
use gltf_doc::{j, Doc};
use pathfarm_tracer::geometry::Mesh;
use pathfarm_tracer::gltf::{AnimatedScene, GltfError, LoadOptions, NoExternalResources};
use pathfarm_tracer::Scene;

fn animated(bytes: &[u8]) -> Result<AnimatedScene, GltfError> {
    AnimatedScene::load(bytes, &NoExternalResources, &LoadOptions::default())
}

/// Every corner of the mesh's triangles, sorted (so that the order of triangles does not count).
fn corners(mesh: &Mesh) -> Vec<[f32; 3]> {
    let mut v: Vec<[f32; 3]> = mesh
        .positions
        .iter()
        .flatten()
        .map(|p| p.to_array())
        .collect();
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v.dedup();
    v
}

fn sorted(mut v: Vec<[f32; 3]>) -> Vec<[f32; 3]> {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v
}

/// The triangles of this frame's deformed meshes (one prototype, placed by the identity).
fn deformed(scene: &Scene) -> &Mesh {
    let last = scene.instances.prototypes.last().expect("a deformed mesh");
    &last.mesh
}

/// A triangle with one morph target that lifts its third corner by (0, 0, 1) and turns its
/// normal: mesh `weights` [0.25]; node 0 (at x = 10) animates the weight from 0 to 1 over one
/// second, node 1 (at x = 20, a copy of the mesh) keeps the mesh's weight.
fn morph_doc() -> Doc {
    let mut d = Doc::new();
    let tri = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let p = d.positions(&tri);
    let n = d.floats(&[[0.0, 0.0, 1.0]; 3]);
    let dp = d.floats(&[[0.0; 3], [0.0; 3], [0.0, 0.0, 1.0]]);
    let dn = d.floats(&[[0.0; 3], [0.0; 3], [1.0, 0.0, 0.0]]);
    let prim = format!(
        r#"[{{"attributes":{{"POSITION":{p},"NORMAL":{n}}},"targets":[{{"POSITION":{dp},"NORMAL":{dn}}}]}}]"#
    );
    for _ in 0..2 {
        d.push(
            "meshes",
            j(&format!(r#"{{"primitives":{prim},"weights":[0.25]}}"#)),
        );
    }
    let a = d.node(j(r#"{"mesh":0,"translation":[10,0,0]}"#));
    let b = d.node(j(r#"{"mesh":1,"translation":[20,0,0]}"#));
    d.root(a);
    d.root(b);
    let t = d.times(&[0.0, 1.0]);
    let w = d.floats(&[[0.0], [1.0]]);
    d.animation("Bulge", &[(a, "weights", t, w, "LINEAR")]);
    d
}

#[test]
fn morph_targets_follow_their_weights() {
    let scene = animated(&morph_doc().gltf()).unwrap();
    for (time, w) in [(0.5f32, 0.5f32), (0.25, 0.25), (-1.0, 0.0), (2.0, 1.0)] {
        let frame = scene.scene_at(time).unwrap();
        // The animated node: its triangle morphed by the channel's weight, placed at x = 10.
        assert_eq!(
            corners(deformed(&frame)),
            sorted(vec![[10.0, 0.0, 0.0], [11.0, 0.0, 0.0], [10.0, 1.0, w]]),
            "at {time} s"
        );
        // The shading normal of the lifted corner: (0, 0, 1) + w·(1, 0, 0), normalised.
        let m = deformed(&frame);
        let k = m.positions[0].iter().position(|p| p.y == 1.0).unwrap();
        let normal = m.normals.as_ref().unwrap()[0][k];
        assert!((normal - Vec3::new(w, 0.0, 1.0).normalize()).length() < 1e-6);
        // The other node keeps the mesh's default weight, 0.25: deformed once, at load, into the
        // world-space triangles (shared by every frame).
        assert_eq!(
            corners(&frame.mesh),
            sorted(vec![[20.0, 0.0, 0.0], [21.0, 0.0, 0.0], [20.0, 1.0, 0.25]])
        );
    }
    let (a, b) = (scene.scene_at(0.1).unwrap(), scene.scene_at(0.9).unwrap());
    assert!(std::sync::Arc::ptr_eq(&a.bvh, &b.bvh));
    assert!(!std::sync::Arc::ptr_eq(
        a.instances.prototypes.last().unwrap(),
        b.instances.prototypes.last().unwrap()
    ));
}

/// A strip of two quads along x (x = 0, 1, 2; y = 0, 1) skinned to two joints: "Root" at the
/// origin and "Tip" at (1, 0, 0), its child, which turns 90° about z over one second. Inverse bind
/// matrices: the identity and a translation by (−1, 0, 0). The vertices at x = 0 follow Root, at
/// x = 2 Tip, at x = 1 half each. The mesh's node sits at (5, 0, 0), which skinning ignores.
fn skin_doc(joints: &[[u16; 4]], bind_matrices: usize) -> Doc {
    let mut d = Doc::new();
    let p = d.positions(&[
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [2.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
        [2.0, 1.0, 0.0],
    ]);
    let i = d.indices(&[0, 1, 4, 0, 4, 3, 1, 2, 5, 1, 5, 4]);
    let js = d.joints(joints);
    let w = [
        [1.0, 0.0, 0.0, 0.0],
        [0.5, 0.5, 0.0, 0.0],
        [1.0, 0.0, 0.0, 0.0],
    ];
    let ws = d.floats(&[w[0], w[1], w[2], w[0], w[1], w[2]]);
    d.push(
        "meshes",
        j(&format!(
            r#"{{"name":"Strip","primitives":[{{"attributes":{{"POSITION":{p},"JOINTS_0":{js},"WEIGHTS_0":{ws}}},"indices":{i}}}]}}"#
        )),
    );
    let ibm = [
        Mat4::IDENTITY.to_cols_array(),
        Mat4::from_translation(Vec3::new(-1.0, 0.0, 0.0)).to_cols_array(),
    ];
    let ibm = d.floats(&ibm[..bind_matrices]);
    let tip = d.node(j(r#"{"name":"Tip","translation":[1,0,0]}"#));
    let root = d.node(j(&format!(r#"{{"name":"Root","children":[{tip}]}}"#)));
    let mesh = d.node(j(
        r#"{"name":"Skinned","mesh":0,"skin":0,"translation":[5,0,0]}"#,
    ));
    d.json["skins"] = j(&format!(
        r#"[{{"name":"Arm","joints":[{root},{tip}],"inverseBindMatrices":{ibm}}}]"#
    ));
    d.root(root);
    d.root(mesh);
    let t = d.times(&[0.0, 1.0]);
    let q = Quat::from_rotation_z(std::f32::consts::FRAC_PI_2);
    let turn = d.floats(&[[0.0, 0.0, 0.0, 1.0], q.to_array()]);
    d.animation("Bend", &[(tip, "rotation", t, turn, "LINEAR")]);
    d
}

const JOINTS: [[u16; 4]; 6] = [
    [0, 0, 0, 0],
    [0, 1, 0, 0],
    [1, 0, 0, 0],
    [0, 0, 0, 0],
    [0, 1, 0, 0],
    [1, 0, 0, 0],
];

#[test]
fn skinned_vertices_follow_their_joints() {
    let scene = animated(&skin_doc(&JOINTS, 2).gltf()).unwrap();
    // The same points, to rounding, each way.
    let close = |got: Vec<[f32; 3]>, want: Vec<[f32; 3]>| {
        let near = |a: &[f32; 3], b: &[f32; 3]| (Vec3::from(*a) - Vec3::from(*b)).length() < 1e-5;
        got.iter().all(|g| want.iter().any(|w| near(g, w)))
            && want.iter().all(|w| got.iter().any(|g| near(g, w)))
    };
    // At rest: the bind pose (the node's own translation ignored).
    let rest = corners(deformed(&scene.scene_at(0.0).unwrap()));
    let flat = vec![
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [2.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
        [2.0, 1.0, 0.0],
    ];
    assert!(close(rest.clone(), flat), "{rest:?}");
    // Turned 90° about the tip joint at (1, 0, 0): (2, 0) → (1, 1), (2, 1) → (0, 1); the middle
    // vertices blend the two joints: (1, 0) stays, (1, 1) → ½(1, 1) + ½(0, 0).
    let bent = corners(deformed(&scene.scene_at(1.0).unwrap()));
    let want = vec![
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.5, 0.5, 0.0],
        [0.0, 1.0, 0.0],
    ];
    assert!(close(bent.clone(), want), "{bent:?}");
    // Halfway: 45° (slerp), the tip's far corner at (1 + cos 45°, sin 45°).
    let half = corners(deformed(&scene.scene_at(0.5).unwrap()));
    let h = std::f32::consts::FRAC_1_SQRT_2;
    assert!(half
        .iter()
        .any(|p| (Vec3::from(*p) - Vec3::new(1.0 + h, h, 0.0)).length() < 1e-5));
}

fn error_of(bytes: &[u8]) -> String {
    match animated(bytes) {
        Ok(_) => panic!("expected an error"),
        Err(GltfError::Internal(e)) => panic!("a panic instead of an error: {e}"),
        Err(e) => e.to_string(),
    }
}

fn assert_contains(message: &str, parts: &[&str]) {
    for p in parts {
        assert!(message.contains(p), "{message:?} lacks {p:?}");
    }
}

#[test]
fn bad_skins_are_named() {
    let mut joints = JOINTS;
    joints[4] = [0, 7, 0, 0];
    let e = error_of(&skin_doc(&joints, 2).gltf());
    assert_contains(
        &e,
        &[
            "mesh 0 \"Strip\", primitive 0",
            "skin 0 \"Arm\"",
            "JOINTS_0 of vertex 4 names joint 7",
            "the skin has 2 joints",
        ],
    );
    // A joint of weight zero may be anything.
    joints[4] = [0, 1, 9, 0];
    assert!(animated(&skin_doc(&joints, 2).gltf()).is_ok());
    let e = error_of(&skin_doc(&JOINTS, 1).gltf());
    assert_contains(
        &e,
        &[
            "skin 0 \"Arm\"",
            "inverseBindMatrices has 1 matrices for 2 joints",
        ],
    );
}

#[test]
fn bad_channels_are_named() {
    // Output counts against the keys and the interpolation.
    let mut d = skin_doc(&JOINTS, 2);
    let t = d.times(&[0.0, 1.0, 2.0]);
    let v = d.floats(&[[0.0; 3], [1.0; 3]]);
    d.animation("Bad", &[(0, "translation", t, v, "LINEAR")]);
    let e = error_of(&d.gltf());
    assert_contains(
        &e,
        &[
            "animation 1 \"Bad\", channel 0 (translation of node 0 \"Tip\")",
            "LINEAR interpolation",
            "has 6 output values for 3 keys, expected 9",
        ],
    );
    let mut d = skin_doc(&JOINTS, 2);
    let t = d.times(&[0.0, 1.0]);
    let v = d.floats(&[[0.0; 3], [1.0; 3]]);
    d.animation("Spline", &[(1, "scale", t, v, "CUBICSPLINE")]);
    let e = error_of(&d.gltf());
    assert_contains(
        &e,
        &[
            "channel 0 (scale of node 1 \"Root\")",
            "CUBICSPLINE",
            "expected 18",
        ],
    );
    // Times that go back.
    let mut d = skin_doc(&JOINTS, 2);
    let t = d.times(&[0.0, 2.0, 1.0]);
    let v = d.floats(&[[0.0; 3], [1.0; 3], [2.0; 3]]);
    d.animation("Back", &[(1, "translation", t, v, "STEP")]);
    assert_contains(&error_of(&d.gltf()), &["\"Back\"", "decrease at key 2"]);
    // A node with a matrix cannot be animated.
    let mut d = skin_doc(&JOINTS, 2);
    d.json["nodes"][1]["matrix"] = j("[1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]");
    let t = d.times(&[0.0, 1.0]);
    let v = d.floats(&[[0.0; 3], [1.0; 3]]);
    d.animation("Matrix", &[(1, "translation", t, v, "LINEAR")]);
    assert_contains(&error_of(&d.gltf()), &["\"Matrix\"", "has a matrix"]);
    // An interpolation glTF does not define: the document's validation names it.
    let mut d = skin_doc(&JOINTS, 2);
    d.json["animations"][0]["samplers"][0]["interpolation"] = j("\"QUADRATIC\"");
    assert_contains(
        &error_of(&d.gltf()),
        &["animations[0].samplers[0].interpolation"],
    );
    // Weights for a node without morph targets: ignored, with a warning.
    let mut d = skin_doc(&JOINTS, 2);
    let t = d.times(&[0.0, 1.0]);
    let v = d.floats(&[[0.0], [1.0]]);
    d.animation("NoTargets", &[(2, "weights", t, v, "LINEAR")]);
    let scene = animated(&d.gltf()).unwrap();
    assert!(scene
        .warnings()
        .iter()
        .any(|w| w.contains("no mesh with morph targets")));
}
