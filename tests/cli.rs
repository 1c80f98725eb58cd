//! The command line as a user meets it, with real files and a real server: glTF file names as
//! written on disk, the client commands for every API operation, and their errors.

mod support;

use base64::Engine;
use std::time::Duration;
use support::*;

/// The Cornell box's one embedded buffer, decoded, and the scene's JSON.
fn cornell_with_external_buffer() -> (serde_json::Value, Vec<u8>) {
    let text = std::fs::read_to_string(SCENE).expect("read scenes/cornell.gltf");
    let gltf: serde_json::Value = serde_json::from_str(&text).expect("parse scenes/cornell.gltf");
    let uri = gltf["buffers"][0]["uri"]
        .as_str()
        .expect("the Cornell box's buffer has a uri");
    let (_, payload) = uri.split_once("base64,").expect("a base64 data: URI");
    let bytes = base64::engine::general_purpose::STANDARD
        .decode(payload)
        .expect("valid base64");
    (gltf, bytes)
}

/// A glTF URI is percent-decoded exactly once, by the loader, and the resulting name is the
/// file's: a space (`%20`), a literal `%20` in the name (`%2520`) and non-ASCII names, escaped or
/// written as they are, all load, through both loaders `render` uses (the still scene, and the
/// animated one behind `--frame`), and render the bits of the embedded scene.
#[tokio::test]
async fn buffer_files_named_with_spaces_percent_signs_and_non_ascii_load() {
    let dir = TestDir::new("uri-names");
    let (gltf, buffer) = cornell_with_external_buffer();
    let settings = [
        "--width",
        "12",
        "--height",
        "10",
        "--spp",
        "2",
        "--threads",
        "1",
    ];
    let render = |scene: String, out: String, frame: bool| {
        let mut args: Vec<String> = vec!["render".into(), scene];
        args.extend(settings.iter().map(|s| s.to_string()));
        if frame {
            args.extend(["--frame".into(), "0".into()]);
        }
        args.extend(["--out".into(), out]);
        let dir = &dir;
        async move {
            let args: Vec<&str> = args.iter().map(String::as_str).collect();
            run_cli(dir, &args, Duration::from_secs(120)).await
        }
    };
    let reference = dir.arg("reference.exr");
    let out = render(SCENE.to_string(), reference.clone(), false).await;
    assert_success(&out, "render of the embedded Cornell box");
    let reference = std::fs::read(&reference).expect("read the reference render");

    // (the file's name on disk, the URI the glTF gives it)
    let cases = [
        ("a b.bin", "a%20b.bin"),
        ("a%20b.bin", "a%2520b.bin"),
        ("100%.bin", "100%25.bin"),
        ("café.bin", "caf%C3%A9.bin"),
        ("crème brûlée.bin", "crème%20brûlée.bin"),
    ];
    for (i, (file, uri)) in cases.iter().enumerate() {
        let sub = dir.path(&format!("case{i}"));
        std::fs::create_dir_all(&sub).expect("create the case's directory");
        std::fs::write(sub.join(file), &buffer).expect("write the buffer file");
        let mut scene = gltf.clone();
        scene["buffers"][0]["uri"] = serde_json::Value::from(*uri);
        let scene_path = sub.join("scene.gltf");
        std::fs::write(&scene_path, scene.to_string()).expect("write the scene");
        for frame in [false, true] {
            let out_path = sub.join(format!("frame-{frame}.exr"));
            let out = render(
                scene_path.to_string_lossy().into_owned(),
                out_path.to_string_lossy().into_owned(),
                frame,
            )
            .await;
            assert_success(
                &out,
                &format!("render of {uri:?} (file {file:?}, --frame: {frame})"),
            );
            let image = std::fs::read(&out_path).expect("read the render");
            assert_same_bytes(&image, &reference, &format!("{uri:?} (--frame: {frame})"));
        }
    }

    // Decoded once means not twice: `a%2520b.bin` names `a%20b.bin`, never `a b.bin`. With only
    // `a b.bin` on disk the load fails, naming the file it looked for.
    let sub = dir.path("once");
    std::fs::create_dir_all(&sub).expect("create the directory");
    std::fs::write(sub.join("a b.bin"), &buffer).expect("write the buffer file");
    let mut scene = gltf.clone();
    scene["buffers"][0]["uri"] = serde_json::Value::from("a%2520b.bin");
    std::fs::write(sub.join("scene.gltf"), scene.to_string()).expect("write the scene");
    let out = render(
        sub.join("scene.gltf").to_string_lossy().into_owned(),
        sub.join("x.exr").to_string_lossy().into_owned(),
        false,
    )
    .await;
    assert!(!out.status.success(), "a%2520b.bin loaded a b.bin");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("a%20b.bin"), "{stderr}");

    // A malformed escape is an error naming the URI, not a file looked up as written.
    scene["buffers"][0]["uri"] = serde_json::Value::from("a%2.bin");
    std::fs::write(sub.join("scene.gltf"), scene.to_string()).expect("write the scene");
    let out = render(
        sub.join("scene.gltf").to_string_lossy().into_owned(),
        sub.join("x.exr").to_string_lossy().into_owned(),
        false,
    )
    .await;
    assert!(!out.status.success(), "a%2.bin was accepted");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("a%2.bin") && stderr.contains("bad escape"),
        "{stderr}"
    );
}
