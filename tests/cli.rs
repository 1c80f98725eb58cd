//! The command line as a user meets it, with real files and a real server: glTF file names as
//! written on disk, the client commands for every API operation, and their errors.

mod support;

use base64::Engine;
use pathfarm_worker::client::ApiClient;
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

/// `pathfarm ARGS…` against `farm`, expected to succeed; its stdout.
async fn ok(farm: &Farm, args: &[&str]) -> String {
    let mut all: Vec<&str> = args.to_vec();
    all.extend(["--server", farm.url.as_str()]);
    let out = run_cli(&farm.dir, &all, Duration::from_secs(60)).await;
    assert_success(&out, &format!("pathfarm {}", args.join(" ")));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `pathfarm ARGS… --json` against `farm`: its stdout parsed (it must be one JSON document).
async fn json(farm: &Farm, args: &[&str]) -> serde_json::Value {
    let mut all = args.to_vec();
    all.push("--json");
    let stdout = ok(farm, &all).await;
    serde_json::from_str(&stdout).unwrap_or_else(|e| {
        panic!(
            "pathfarm {} --json printed no JSON ({e}):\n{stdout}",
            args.join(" ")
        )
    })
}

/// `pathfarm ARGS…` expected to fail: its stderr, which must be one line.
fn one_error_line(out: &std::process::Output, what: &str) -> String {
    assert!(!out.status.success(), "{what} succeeded");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "{what}: not one line of error:\n{stderr}");
    assert!(lines[0].starts_with("error: "), "{what}: {stderr}");
    lines[0].to_string()
}

/// Every API operation from the command line, against a real server and worker, each with
/// `--json` (one JSON document on stdout) and as text: submit, jobs, priority, pause, resume,
/// workers, job with --out (the EXR bit-identical to a local render), cancel, delete.
#[tokio::test]
async fn every_api_operation_has_a_command_that_works_with_and_without_json() {
    let farm = Farm::new("cli-ops");
    let _server = farm.serve("server", &[]).await;
    let settings = [
        "--width", "24", "--height", "16", "--spp", "8", "--seed", "3",
    ];
    let reference = render_reference(&farm.dir, "local.exr", &settings);

    // submit --json: the API's answer; the job waits, no worker runs yet.
    let mut submit = vec!["submit", SCENE];
    submit.extend(settings);
    let created = json(&farm, &submit).await;
    let id = created["id"].as_str().expect("an id").to_string();
    assert!(created["samples_planned"].as_u64() > Some(0), "{created}");

    let list = json(&farm, &["jobs"]).await;
    assert!(
        list["jobs"]
            .as_array()
            .is_some_and(|j| j.iter().any(|j| j["id"] == id.as_str())),
        "{list}"
    );
    assert!(ok(&farm, &["jobs"]).await.contains(&id));

    let j = json(&farm, &["priority", &id, "7"]).await;
    assert_eq!(j["priority"], 7, "{j}");
    let text = ok(&farm, &["priority", &id, "-3"]).await;
    assert!(text.contains("priority -3"), "{text}");
    assert_eq!(json(&farm, &["job", &id]).await["priority"], -3);

    let j = json(&farm, &["pause", &id]).await;
    assert_eq!(j["state"], "paused", "{j}");
    let j = json(&farm, &["resume", &id]).await;
    assert_eq!(j["state"], "queued", "{j}");
    let text = ok(&farm, &["pause", &id]).await;
    assert!(text.contains("paused"), "{text}");
    let text = ok(&farm, &["resume", &id]).await;
    assert!(text.contains("queued"), "{text}");

    // A worker renders it.
    let _worker = farm.worker("w1", 4);
    let api = farm.api();
    wait_completed(&api, &id, Duration::from_secs(120)).await;
    let workers = json(&farm, &["workers"]).await;
    assert!(
        workers["workers"]
            .as_array()
            .is_some_and(|w| w.iter().any(|w| w["name"] == "w1")),
        "{workers}"
    );
    assert!(ok(&farm, &["workers"]).await.contains("w1"));

    // job ID --history: the convergence history, as JSON and as a table of the same points.
    let h = json(&farm, &["job", &id, "--history"]).await;
    let points = h["points"].as_array().expect("points");
    let last = points.last().expect("a finished job has a history");
    assert_eq!(last["samples_done"], 24 * 16 * 8, "{h}");
    let text = ok(&farm, &["job", &id, "--history"]).await;
    assert!(text.starts_with(&format!("{:>10}", "seconds")), "{text}");
    assert_eq!(text.lines().count(), points.len() + 1, "{text}");
    assert!(
        text.lines()
            .last()
            .is_some_and(|l| l.contains(&(24 * 16 * 8).to_string())),
        "{text}"
    );

    // job ID --out: the image later, bit-identical to the local render; as PNG too.
    let exr = farm.dir.arg("job.exr");
    let text = ok(&farm, &["job", &id, "--out", &exr]).await;
    assert!(
        text.contains("wrote") && text.contains("completed"),
        "{text}"
    );
    let farm_exr = std::fs::read(&exr).expect("read the downloaded EXR");
    let local = reference.await.expect("the local render");
    assert_same_bytes(&farm_exr, &local, "job --out");
    let png = farm.dir.arg("job.png");
    let j = json(&farm, &["job", &id, "--out", &png, "--exposure", "-1"]).await;
    assert_eq!(j["state"], "completed", "{j}");
    let png_bytes = std::fs::read(&png).expect("read the downloaded PNG");
    assert!(png_bytes.starts_with(b"\x89PNG\r\n\x1a\n"), "not a PNG");

    // cancel --json (it was ignored once), then delete; the job is gone.
    let mut big = vec![
        "submit", SCENE, "--width", "64", "--height", "64", "--spp", "100000",
    ];
    big.push("--json");
    let mut args = big.clone();
    args.extend(["--server", farm.url.as_str()]);
    let out = run_cli(&farm.dir, &args, Duration::from_secs(30)).await;
    assert_success(&out, "submit");
    let created: serde_json::Value = serde_json::from_slice(&out.stdout).expect("submit --json");
    let id2 = created["id"].as_str().expect("an id").to_string();
    let j = json(&farm, &["cancel", &id2]).await;
    assert_eq!(j["state"], "cancelled", "{j}");
    let d = json(&farm, &["delete", &id2]).await;
    assert_eq!(d, serde_json::json!({"id": id2, "deleted": true}));
    let out = run_cli(
        &farm.dir,
        &["job", &id2, "--server", &farm.url],
        Duration::from_secs(30),
    )
    .await;
    let line = one_error_line(&out, "job of a deleted job");
    assert!(line.contains("404") && line.contains(&id2), "{line}");
    let text = ok(&farm, &["delete", &id]).await;
    assert!(text.contains(&format!("deleted job {id}")), "{text}");
}

/// `submit --frames … --wait --out 'frame_##.exr'` writes one file per frame, each named by its
/// frame number and bit-identical to `pathfarm render --frame f --fps F`; a pattern without `#`
/// and a bad frame list are refused before anything is sent.
#[tokio::test]
async fn submit_frames_writes_one_file_per_frame_equal_to_local_renders() {
    let farm = Farm::new("cli-frames");
    let _server = farm.serve("server", &[]).await;
    let settings = [
        "--width", "20", "--height", "12", "--spp", "4", "--seed", "9",
    ];

    for (bad, want) in [
        (["--frames", "0-2", "--out", "shots.exr"], "run of #"),
        (["--frames", "2-1", "--out", "f_#.exr"], "frames item"),
    ] {
        let out_arg = farm.dir.arg(bad[3]);
        let mut args = vec!["submit", ANIMATED, "--wait", bad[0], bad[1], "--out"];
        args.push(&out_arg);
        args.extend(["--server", farm.url.as_str()]);
        let out = run_cli(&farm.dir, &args, Duration::from_secs(30)).await;
        let line = one_error_line(&out, &format!("submit {}", bad.join(" ")));
        assert!(line.contains(want), "{line}");
    }
    assert_eq!(
        farm.api()
            .jobs(None, 1, 100)
            .await
            .expect("jobs")
            .jobs
            .len(),
        0,
        "a refused submission reached the server"
    );

    let _worker = farm.worker("w1", 2);
    let pattern = farm.dir.arg("shots/frame_##.exr");
    std::fs::create_dir_all(farm.dir.path("shots")).expect("create shots/");
    let mut args = vec!["submit", ANIMATED];
    args.extend(settings);
    args.extend([
        "--frames", "0,7-8", "--fps", "12", "--wait", "--out", &pattern, "--server", &farm.url,
    ]);
    let out = run_cli(&farm.dir, &args, Duration::from_secs(240)).await;
    assert_success(&out, "submit --frames --wait --out");
    let stdout = String::from_utf8_lossy(&out.stdout);
    for frame in [0, 7, 8] {
        let name = format!("frame_{frame:02}.exr");
        assert!(stdout.contains(&name), "{name} not reported:\n{stdout}");
        let farm_exr = std::fs::read(farm.dir.path("shots").join(&name)).expect("read a frame");
        let local_path = farm.dir.path(&format!("local_{frame}.exr"));
        let f = frame.to_string();
        let mut local = vec!["render", ANIMATED];
        local.extend(settings);
        local.extend(["--frame", &f, "--fps", "12", "--threads", "1", "--out"]);
        let local_arg = local_path.to_string_lossy().into_owned();
        local.push(&local_arg);
        let out = run_cli(&farm.dir, &local, Duration::from_secs(120)).await;
        assert_success(&out, "pathfarm render --frame");
        let local = std::fs::read(&local_path).expect("read the local frame");
        assert_same_bytes(&farm_exr, &local, &name);
    }
    // Frames differ (the animation moves): the files are not one image written three times.
    let first = std::fs::read(farm.dir.path("shots/frame_00.exr")).expect("frame 0");
    let last = std::fs::read(farm.dir.path("shots/frame_08.exr")).expect("frame 8");
    assert_ne!(first, last, "frames 0 and 8 are the same image");

    // Later, `job ID --out`: the frames again by pattern, all of them as one tar (the same EXR
    // bytes, named by frame), and the animated preview.
    let jobs = farm.api().jobs(None, 1, 10).await.expect("jobs").jobs;
    let id = jobs[0].id.clone();
    // The text list counts the complete frames.
    let list = ok(&farm, &["jobs"]).await;
    let row = list
        .lines()
        .find(|l| l.starts_with(&id))
        .expect("the job's row");
    assert!(row.split_whitespace().any(|w| w == "3/3"), "{list}");
    // The job's details list each frame with its samples and error.
    let details = ok(&farm, &["job", &id]).await;
    for frame in ["0", "7", "8"] {
        let line = details
            .lines()
            .find(|l| l.split_whitespace().next() == Some(frame))
            .unwrap_or_else(|| panic!("no line for frame {frame}:\n{details}"));
        let cols: Vec<&str> = line.split_whitespace().collect();
        assert_eq!(cols[1], "4", "{line}");
        assert!(cols[2].ends_with('%') && cols[3] == "complete", "{line}");
    }
    // Each frame's own convergence history: frame 7's ends at its 20×12 pixels' 4 samples.
    let h = json(&farm, &["job", &id, "--history", "--frame", "7"]).await;
    let last = h["points"].as_array().and_then(|p| p.last()).cloned();
    assert_eq!(
        last.map(|p| p["samples_done"].clone()),
        Some((20 * 12 * 4).into()),
        "{h}"
    );
    let again = farm.dir.arg("again_###.exr");
    let text = ok(&farm, &["job", &id, "--out", &again]).await;
    assert!(text.contains("wrote 3 frames"), "{text}");
    assert_eq!(
        std::fs::read(farm.dir.path("again_007.exr")).expect("again_007.exr"),
        std::fs::read(farm.dir.path("shots/frame_07.exr")).expect("frame_07.exr")
    );
    let tar_path = farm.dir.arg("all.tar");
    let text = ok(&farm, &["job", &id, "--out", &tar_path]).await;
    assert!(
        text.contains("wrote") && text.contains("completed"),
        "{text}"
    );
    let tar_bytes = std::fs::read(&tar_path).expect("read all.tar");
    let mut names = Vec::new();
    for entry in tar::Archive::new(&tar_bytes[..]).entries().expect("a tar") {
        let mut entry = entry.expect("an entry");
        let name = entry.path().expect("a name").display().to_string();
        let mut bytes = Vec::new();
        std::io::Read::read_to_end(&mut entry, &mut bytes).expect("an entry's bytes");
        let frame: u32 = name[6..10].parse().expect("frame_NNNN.exr");
        let file = farm.dir.path(&format!("shots/frame_{frame:02}.exr"));
        assert!(
            bytes == std::fs::read(&file).expect("a frame file"),
            "{name}"
        );
        names.push(name);
    }
    assert_eq!(
        names,
        ["frame_0000.exr", "frame_0007.exr", "frame_0008.exr"]
    );
    let apng = farm.dir.arg("all.apng");
    ok(&farm, &["job", &id, "--out", &apng, "--exposure", "1"]).await;
    let apng = std::fs::read(&apng).expect("read all.apng");
    assert!(apng.starts_with(b"\x89PNG\r\n\x1a\n"), "not a PNG");
    assert!(apng.windows(4).any(|w| w == b"acTL"), "not animated");

    // A pattern or an archive of a still job is refused, naming the job.
    let still = submit(
        &farm.dir,
        &farm.url,
        &["--width", "8", "--height", "8", "--spp", "1"],
    )
    .await;
    for out in [farm.dir.arg("still_#.exr"), farm.dir.arg("still.tar")] {
        let out = run_cli(
            &farm.dir,
            &["job", &still, "--out", &out, "--server", &farm.url],
            Duration::from_secs(30),
        )
        .await;
        let line = one_error_line(&out, "job --out of a still job");
        assert!(line.contains(&still), "{line}");
    }
}

/// Bad input fails at once with one line naming what is wrong: an unreachable server (reqwest's
/// message once, not twice), a log filter that does not parse, an output folder that does not
/// exist (before the render, not after it), `job --out` likewise before downloading.
#[tokio::test]
async fn errors_are_one_line_and_bad_input_is_refused_before_any_work() {
    let dir = TestDir::new("cli-errors");
    let dead = format!("http://127.0.0.1:{}", free_port());
    let out = run_cli(&dir, &["jobs", "--server", &dead], Duration::from_secs(30)).await;
    let line = one_error_line(&out, "jobs against a dead port");
    assert!(line.contains("cannot reach the server"), "{line}");
    assert_eq!(
        line.matches("error sending request").count(),
        1,
        "reqwest's message repeated: {line}"
    );

    for args in [
        vec!["--log", "pathfarm=loud", "jobs", "--server", dead.as_str()],
        vec![
            "jobs",
            "--log",
            "info,pathfarm_worker=loud",
            "--server",
            dead.as_str(),
        ],
    ] {
        let out = run_cli(&dir, &args, Duration::from_secs(30)).await;
        assert_eq!(out.status.code(), Some(2), "{args:?} was accepted");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            stderr.contains("--log") && stderr.contains("not a log filter"),
            "{args:?}: {stderr}"
        );
    }

    // A render that would take minutes fails at once on its output folder.
    let missing = dir.arg("missing_dir/x.exr");
    let t = std::time::Instant::now();
    let out = run_cli(
        &dir,
        &[
            "render", SCENE, "--width", "512", "--height", "512", "--spp", "100000", "--out",
            &missing,
        ],
        Duration::from_secs(60),
    )
    .await;
    let line = one_error_line(&out, "render --out missing_dir/x.exr");
    assert!(line.contains("missing_dir"), "{line}");
    assert!(
        t.elapsed() < Duration::from_secs(10),
        "refused only after {:?}",
        t.elapsed()
    );
    let out = run_cli(
        &dir,
        &["job", "any", "--out", &missing, "--server", &dead],
        Duration::from_secs(30),
    )
    .await;
    let line = one_error_line(&out, "job --out missing_dir/x.exr");
    assert!(
        line.contains("missing_dir") && !line.contains("cannot reach"),
        "{line}"
    );
    let out = run_cli(
        &dir,
        &[
            "submit", SCENE, "--wait", "--out", &missing, "--server", &dead,
        ],
        Duration::from_secs(30),
    )
    .await;
    let line = one_error_line(&out, "submit --out missing_dir/x.exr");
    assert!(line.contains("missing_dir"), "{line}");
}

/// A scene whose light is too bright to accumulate makes many samples invalid: `render` and a
/// farm worker each say so once (count and first example), not once per sample.
#[tokio::test]
async fn invalid_samples_are_reported_once_with_a_count_not_once_each() {
    let farm = Farm::new("cli-invalid");
    let text = std::fs::read_to_string(SCENE).expect("read the Cornell box");
    let mut gltf: serde_json::Value = serde_json::from_str(&text).expect("parse it");
    let materials = gltf["materials"].as_array_mut().expect("materials");
    let light = materials
        .iter_mut()
        .find(|m| m.get("emissiveFactor").is_some())
        .expect("an emissive material");
    // Radiance 1e10 is above what a sample may carry (2^32): every path that sees it is invalid.
    light["extensions"]["KHR_materials_emissive_strength"]["emissiveStrength"] =
        serde_json::json!(1e10);
    let scene = farm.dir.arg("bright.gltf");
    std::fs::write(&scene, gltf.to_string()).expect("write the scene");

    let out_path = farm.dir.arg("bright.exr");
    let out = run_cli(
        &farm.dir,
        &[
            "render", &scene, "--width", "32", "--height", "32", "--spp", "8", "--out", &out_path,
        ],
        Duration::from_secs(120),
    )
    .await;
    assert_success(&out, "render of the bright scene");
    let stderr = String::from_utf8_lossy(&out.stderr);
    let warnings: Vec<&str> = stderr.lines().filter(|l| l.contains("invalid")).collect();
    assert_eq!(warnings.len(), 1, "{stderr}");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let count: u64 = stdout
        .trim()
        .split(", ")
        .find_map(|p| p.strip_suffix(" invalid samples")?.trim().parse().ok())
        .unwrap_or_else(|| panic!("no invalid-sample count in {stdout}"));
    assert!(
        count > 10,
        "only {count} invalid samples: the test needs many"
    );
    assert!(
        warnings[0].contains(&format!("count={count}")) && warnings[0].contains("--debug-sample"),
        "{}",
        warnings[0]
    );

    let _server = farm.serve("server", &[]).await;
    let id = submit(
        &farm.dir,
        &farm.url,
        &[
            "--width", "32", "--height", "32", "--spp", "8", "--tile", "16",
        ],
    )
    .await;
    // That submitted the plain Cornell box; now the bright one, on a worker with small slices.
    let out = run_cli(
        &farm.dir,
        &[
            "submit", &scene, "--width", "32", "--height", "32", "--spp", "8", "--tile", "16",
            "--server", &farm.url,
        ],
        Duration::from_secs(30),
    )
    .await;
    assert_success(&out, "submit of the bright scene");
    let bright = String::from_utf8_lossy(&out.stdout).trim().to_string();
    let mut worker = farm.worker("w1", 2);
    let api = farm.api();
    wait_completed(&api, &id, Duration::from_secs(120)).await;
    wait_completed(&api, &bright, Duration::from_secs(120)).await;
    worker.signal(libc::SIGTERM);
    worker.wait_exit(Duration::from_secs(30)).await;
    let log = worker.log_text();
    let warnings: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("invalid samples dropped"))
        .collect();
    assert_eq!(warnings.len(), 1, "{log}");
    assert!(
        warnings[0].contains(&bright) && warnings[0].contains("first="),
        "{}",
        warnings[0]
    );
    let stopped = log
        .lines()
        .find(|l| l.contains("worker stopped"))
        .unwrap_or_else(|| panic!("no `worker stopped` line:\n{log}"));
    assert!(!stopped.contains("invalid_samples=0"), "{stopped}");
}

/// A self-signed certificate for `localhost` and 127.0.0.1, as PEM: (certificate, key).
fn self_signed() -> (String, String) {
    let c = rcgen::generate_simple_self_signed(vec!["localhost".into(), "127.0.0.1".into()])
        .expect("certificate");
    (c.cert.pem(), c.signing_key.serialize_pem())
}

/// Writes `text` to `path` by a rename, as a deployment tool replaces a file.
fn replace(path: &std::path::Path, text: &str) {
    let tmp = path.with_extension("new");
    std::fs::write(&tmp, text).expect("write");
    std::fs::rename(&tmp, path).expect("rename");
}

/// `serve --tls-cert --tls-key` with the real binary: files that cannot serve are refused at
/// start naming them; a worker and the client commands with `--ca-cert` render a job over
/// `https://`; without it they stop at once with an error that names `--ca-cert`; SIGHUP serves
/// replaced files (with `--tls-reload-seconds 0`, only SIGHUP does; with 0.2, they are served
/// within moments without it).
#[tokio::test]
async fn serve_terminates_tls_for_workers_and_clients_and_reloads_on_sighup() {
    let farm = Farm::new("tls");
    let dir = &farm.dir;
    let (cert_pem, key_pem) = self_signed();
    let (cert, key, ca) = (dir.path("cert.pem"), dir.path("key.pem"), dir.arg("ca.pem"));
    replace(&cert, &cert_pem);
    replace(&key, &key_pem);
    std::fs::write(&ca, &cert_pem).expect("write ca.pem");
    let (cert_arg, key_arg) = (dir.arg("cert.pem"), dir.arg("key.pem"));
    let listen = format!("127.0.0.1:{}", farm.port);
    let serve = |tls: &[&str]| {
        let mut args = vec!["serve", "--listen", &listen, "--db", &farm.db];
        args.extend_from_slice(tls);
        args.into_iter().map(String::from).collect::<Vec<_>>()
    };
    let refused = |args: Vec<String>| async move {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let out = run_cli(dir, &args, Duration::from_secs(30)).await;
        assert!(!out.status.success(), "{args:?} started");
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let missing = dir.arg("missing.pem");
    let e = refused(serve(&["--tls-cert", &missing, "--tls-key", &key_arg])).await;
    assert!(e.contains("--tls-cert") && e.contains(&missing), "{e}");
    let e = refused(serve(&["--tls-cert", &cert_arg, "--tls-key", &cert_arg])).await;
    assert!(e.contains("--tls-key") && e.contains(&cert_arg), "{e}");
    let e = refused(serve(&["--tls-cert", &cert_arg])).await;
    assert!(e.contains("--tls-key"), "{e}");
    let bad = [
        "--tls-cert",
        &cert_arg,
        "--tls-key",
        &key_arg,
        "--tls-reload-seconds",
        "-1",
    ];
    let e = refused(serve(&bad)).await;
    assert!(e.contains("--tls-reload-seconds"), "{e}");

    let watching = |seconds: &str| {
        serve(&[
            "--tls-cert",
            &cert_arg,
            "--tls-key",
            &key_arg,
            "--tls-reload-seconds",
            seconds,
        ])
    };
    // Files not watched (0): only SIGHUP reads them again, as checked at the end.
    let args = watching("0");
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let mut server = Proc::start("server", dir, &args);
    let url = format!("https://127.0.0.1:{}", farm.port);
    let api = ApiClient::with_ca_cert(&url, None, Some(std::path::Path::new(&ca))).expect("client");
    let t0 = std::time::Instant::now();
    while api.workers().await.is_err() {
        assert!(server.is_running(), "serve exited:\n{}", server.log_text());
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "the TLS server does not answer"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }

    // Without the CA certificate: a clear error at once, from a client command and a worker.
    let out = run_cli(dir, &["jobs", "--server", &url], Duration::from_secs(30)).await;
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("--ca-cert"), "{e}");
    let mut lost = Proc::start("worker-without-ca", dir, &["worker", "--server", &url]);
    assert!(!lost.wait_exit(Duration::from_secs(20)).await.success());
    assert!(lost.log_text().contains("--ca-cert"), "{}", lost.log_text());

    // With it: a job rendered over https://, bit-identical to a local render.
    let settings = ["--width", "16", "--height", "12", "--spp", "2"];
    let reference = render_reference(dir, "reference.exr", &settings);
    let mut submitted = settings.to_vec();
    submitted.extend(["--ca-cert", ca.as_str()]);
    let id = submit(dir, &url, &submitted).await;
    let cache = dir.arg("cache");
    let _worker = Proc::start(
        "worker",
        dir,
        &[
            "worker",
            "--server",
            &url,
            "--ca-cert",
            &ca,
            "--threads",
            "1",
            "--cache-dir",
            &cache,
        ],
    );
    wait_completed(&api, &id, Duration::from_secs(60)).await;
    let out_path = dir.arg("farm.exr");
    let out = run_cli(
        dir,
        &[
            "job",
            &id,
            "--server",
            &url,
            "--ca-cert",
            &ca,
            "--out",
            &out_path,
        ],
        Duration::from_secs(30),
    )
    .await;
    assert_success(&out, "pathfarm job --out over https");
    let farm_image = std::fs::read(&out_path).expect("read farm.exr");
    assert_same_bytes(
        &farm_image,
        &reference.await.expect("reference"),
        "the TLS farm's image",
    );

    // A new certificate, picked up on SIGHUP by new connections.
    let (new_pem, new_key) = self_signed();
    let new_ca = dir.arg("new-ca.pem");
    std::fs::write(&new_ca, &new_pem).expect("write new-ca.pem");
    replace(&key, &new_key);
    replace(&cert, &new_pem);
    // Not watched: the old certificate is still served a while after the files changed.
    tokio::time::sleep(Duration::from_millis(700)).await;
    let old = ApiClient::with_ca_cert(&url, None, Some(std::path::Path::new(&ca))).expect("client");
    assert!(
        old.workers().await.is_ok(),
        "the certificate changed without SIGHUP although --tls-reload-seconds is 0"
    );
    server.signal(libc::SIGHUP);
    poll("the new certificate", Duration::from_secs(10), || async {
        let fresh = ApiClient::with_ca_cert(&url, None, Some(std::path::Path::new(&new_ca)))
            .expect("client");
        fresh.workers().await.ok()
    })
    .await;
    assert!(server.is_running());

    // Watched every 0.2 s: a third certificate is served without a signal.
    server.signal(libc::SIGTERM);
    assert!(server.wait_exit(Duration::from_secs(20)).await.success());
    let args = watching("0.2");
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let mut watched = Proc::start("server-watched", dir, &args);
    let second =
        ApiClient::with_ca_cert(&url, None, Some(std::path::Path::new(&new_ca))).expect("client");
    poll("the watched server", Duration::from_secs(30), || async {
        second.workers().await.ok()
    })
    .await;
    let (third_pem, third_key) = self_signed();
    let third_ca = dir.arg("third-ca.pem");
    std::fs::write(&third_ca, &third_pem).expect("write third-ca.pem");
    replace(&key, &third_key);
    replace(&cert, &third_pem);
    poll("the third certificate", Duration::from_secs(5), || async {
        let fresh = ApiClient::with_ca_cert(&url, None, Some(std::path::Path::new(&third_ca)))
            .expect("client");
        fresh.workers().await.ok()
    })
    .await;
    assert!(watched.is_running());
}

/// `pathfarm jobs --json` against `url` with the configuration file `config` and the environment
/// `env`, plus `extra` flags: whether the server let it in.
async fn jobs_allowed(
    dir: &TestDir,
    url: &str,
    config: &str,
    env: &[(&str, &str)],
    extra: &[&str],
) -> bool {
    let mut cmd = tokio::process::Command::from(command(dir));
    cmd.args(["jobs", "--json", "--config", config, "--server", url])
        .args(extra)
        .kill_on_drop(true);
    for (k, v) in env {
        cmd.env(k, v);
    }
    let out = tokio::time::timeout(Duration::from_secs(60), cmd.output())
        .await
        .expect("pathfarm jobs finishes")
        .expect("run pathfarm jobs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() || stderr.contains("401"),
        "neither allowed nor refused: {stderr}"
    );
    out.status.success()
}

/// The client token of `[client]` in the file, `PATHFARM_TOKEN` and `--token`: a flag wins over
/// the environment, which wins over the file, which wins over the default (none).
#[tokio::test]
async fn a_flag_wins_over_the_environment_which_wins_over_the_file() {
    let farm = Farm::new("config-precedence");
    let _server = farm
        .serve(
            "server",
            &["--client-token", "right", "--worker-token", "w"],
        )
        .await;
    let file = |name: &str, token: Option<&str>| {
        let path = farm.dir.path(name);
        let text = match token {
            Some(t) => format!("[client]\ntoken = \"{t}\"\n"),
            None => "[client]\n".to_string(),
        };
        std::fs::write(&path, text).expect("write the configuration");
        path.to_string_lossy().into_owned()
    };
    let (good, bad, none) = (
        file("good.toml", Some("right")),
        file("bad.toml", Some("wrong")),
        file("none.toml", None),
    );
    let d = &farm.dir;
    let url = farm.url.as_str();
    assert!(
        !jobs_allowed(d, url, &none, &[], &[]).await,
        "the default: no token"
    );
    assert!(
        jobs_allowed(d, url, &good, &[], &[]).await,
        "the file's token"
    );
    let env_right = [("PATHFARM_TOKEN", "right")];
    let env_wrong = [("PATHFARM_TOKEN", "wrong")];
    assert!(
        jobs_allowed(d, url, &bad, &env_right, &[]).await,
        "environment over file"
    );
    assert!(
        !jobs_allowed(d, url, &good, &env_wrong, &[]).await,
        "environment over file"
    );
    let flag_right = ["--token", "right"];
    let flag_wrong = ["--token", "wrong"];
    assert!(
        jobs_allowed(d, url, &bad, &env_wrong, &flag_right).await,
        "flag over all"
    );
    assert!(
        !jobs_allowed(d, url, &good, &env_right, &flag_wrong).await,
        "flag over all"
    );

    // A bad value in the file: one line naming the file and the key, nothing run.
    let typo = farm.dir.path("typo.toml");
    std::fs::write(&typo, "[client]\nserver = 8080\n").expect("write");
    let out = run_cli(
        &farm.dir,
        &["jobs", "--config", &typo.to_string_lossy()],
        Duration::from_secs(30),
    )
    .await;
    let line = one_error_line(&out, "a number for a URL");
    assert!(
        line.contains("typo.toml: key \"client.server\": invalid type"),
        "{line}"
    );
}

/// The processes whose parent is `pid`.
fn children_of(pid: i32) -> Vec<i32> {
    let Ok(entries) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    entries
        .flatten()
        .filter_map(|e| e.file_name().to_str()?.parse::<i32>().ok())
        .filter(|p| {
            std::fs::read_to_string(format!("/proc/{p}/stat"))
                .ok()
                .and_then(|s| {
                    let after = s.rsplit_once(')')?.1.split_whitespace().nth(1)?.to_string();
                    after.parse::<i32>().ok()
                })
                == Some(pid)
        })
        .collect()
}

/// `up` with its tokens in the configuration file (and a client token in its environment): its
/// worker registers, so it has the worker token, yet no token is in the worker's environment or
/// command line (read from `/proc`), nor any variable that may hold a secret. By default it is
/// one worker process rendering on every core.
#[tokio::test(flavor = "multi_thread")]
async fn up_keeps_tokens_out_of_its_workers_environment() {
    let dir = TestDir::new("up-secrets");
    let port = free_port();
    let config = dir.path("farm.toml");
    std::fs::write(
        &config,
        format!(
            "[serve]\ndb = \"{}\"\nclient-tokens = [\"client-secret-1\"]\n\
             worker-tokens = [\"worker-secret-1\"]\n[up]\nport = {port}\n",
            dir.arg("up.db")
        ),
    )
    .expect("write the configuration");
    let mut cmd = command(&dir);
    cmd.args(["up", "--config", &config.to_string_lossy()])
        .env("PATHFARM_CLIENT_TOKENS", "env-client-secret")
        .env("PATHFARM_DB", dir.arg("up.db"));
    let mut up = Proc::spawn("up", &dir, cmd, false);
    wait_healthy(port, &mut up).await;
    let url = format!("http://127.0.0.1:{port}");
    // The environment's client token won over the file's.
    let api = ApiClient::new(&url, Some("env-client-secret".into())).expect("client");
    let local = poll("the local worker", Duration::from_secs(60), || async {
        named(&workers(&api).await, "local-1").cloned()
    })
    .await;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    assert_eq!(local.threads as usize, cores, "{local:?}");
    let kids = children_of(up.pid());
    assert_eq!(kids.len(), 1, "one worker process: {kids:?}");
    for pid in kids {
        let environ = std::fs::read(format!("/proc/{pid}/environ")).expect("read environ");
        let cmdline = std::fs::read(format!("/proc/{pid}/cmdline")).expect("read cmdline");
        let (environ, cmdline) = (
            String::from_utf8_lossy(&environ).replace('\0', " "),
            String::from_utf8_lossy(&cmdline).replace('\0', " "),
        );
        assert!(cmdline.contains("--token-stdin"), "{cmdline}");
        for secret in [
            "worker-secret-1",
            "client-secret-1",
            "env-client-secret",
            "PATHFARM_DB",
            "PATHFARM_CLIENT_TOKENS",
            "PATHFARM_WORKER_TOKEN",
        ] {
            assert!(
                !environ.contains(secret),
                "{secret} in the worker's environment"
            );
            assert!(
                !cmdline.contains(secret),
                "{secret} on the worker's command line"
            );
        }
    }
    up.signal(libc::SIGINT);
    let status = up.wait_exit(Duration::from_secs(30)).await;
    assert!(status.success(), "`pathfarm up` exited {status}");
}

/// A store that cannot be opened is reported with its URL, the password hidden: in the user
/// info and in a `password` query parameter.
#[test]
fn a_failed_store_start_does_not_print_the_password() {
    let Some(base) = std::env::var("PATHFARM_TEST_POSTGRES_URL")
        .ok()
        .filter(|u| !u.is_empty())
    else {
        eprintln!("SKIPPED: PATHFARM_TEST_POSTGRES_URL is not set");
        return;
    };
    let dir = TestDir::new("store-password");
    let host = base
        .split_once("://")
        .and_then(|(_, rest)| rest.rsplit_once('@').map_or(Some(rest), |(_, h)| Some(h)))
        .and_then(|rest| rest.split_once('/'))
        .map(|(host, _)| host.to_string())
        .expect("a host in PATHFARM_TEST_POSTGRES_URL");
    for db in [
        format!("postgres://postgres:s3cret-pw@{host}/pathfarm_no_such_database"),
        format!("postgres://{host}/pathfarm_no_such_database?user=postgres&password=s3cret-pw"),
    ] {
        let out = command(&dir)
            .args(["serve", "--db", &db, "--listen", "127.0.0.1:0"])
            .output()
            .expect("run pathfarm serve");
        assert!(!out.status.success(), "{db}: serve started");
        let line = one_error_line(&out, "serve with a database that does not exist");
        assert!(!line.contains("s3cret-pw"), "{line}");
        assert!(
            line.contains("***") && line.contains("pathfarm_no_such_database"),
            "{line}"
        );
    }
}

/// `pathfarm bench frames --quick` runs a frame job, the same frames in sequence and a still of
/// the same total samples, each on a fresh `pathfarm up` (real processes), and reports every one
/// whole: every sample merged, every frame's first pass seen, tasks and slices counted.
#[test]
fn bench_frames_measures_a_frame_job_against_a_still_one() {
    let dir = TestDir::new("bench-frames");
    let scenes = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes");
    let out = command(&dir)
        .args([
            "bench",
            "frames",
            "--quick",
            "--threads",
            "1",
            "--seed",
            "3",
        ])
        .args(["--scenes-dir", scenes, "--out", &dir.arg("report")])
        .output()
        .expect("run pathfarm bench frames");
    assert!(
        out.status.success(),
        "pathfarm bench frames failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json = std::fs::read(dir.path("report").join("frames.json")).expect("read frames.json");
    let r: serde_json::Value = serde_json::from_slice(&json).expect("frames.json is JSON");
    let rows = r["rows"].as_array().expect("rows");
    let frames: Vec<u64> = rows
        .iter()
        .map(|row| row["frames"].as_u64().unwrap_or(0))
        .collect();
    assert_eq!(frames, [24, 24, 1], "{r}");
    // --quick: 24 frames of 32×18 at 2 spp, and the still with all of them.
    let samples = 32 * 18 * 2 * 24;
    for row in rows {
        assert_eq!(row["samples"].as_u64(), Some(samples), "{row}");
        assert!(
            row["samples_per_second"].as_f64().unwrap_or(0.0) > 0.0,
            "{row}"
        );
        assert!(row["slices"].as_u64().unwrap_or(0) >= row["tasks"].as_u64().unwrap_or(0));
    }
    assert!(rows[0]["first_pass_seconds"].as_f64().is_some(), "{r}");
    assert!(rows[0]["tasks"].as_u64().unwrap_or(0) >= 24, "{r}");
    assert!(rows[2]["tasks"].as_u64().unwrap_or(0) >= 1, "{r}");
    for key in ["ratio", "sequential_ratio"] {
        let v = r[key].as_f64().unwrap_or(0.0);
        assert!(v > 0.0 && v.is_finite(), "{key} {v}");
    }
    let md = std::fs::read_to_string(dir.path("report").join("frames.md")).expect("frames.md");
    assert!(md.contains("24 frames"), "{md}");
    assert!(!dir.path("report").join("frames-work").exists());
}

/// `pathfarm bench up --quick`: the direct render and `up` in both layouts, as real processes,
/// give the same bytes; the report counts the farm's processes (up and its workers), their
/// memory and their CPU time.
#[test]
fn bench_up_compares_the_farm_with_a_direct_render() {
    let dir = TestDir::new("bench-up");
    let scenes = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes");
    let out = command(&dir)
        .args([
            "bench",
            "up",
            "--quick",
            "--threads",
            "2",
            "--scenes-dir",
            scenes,
        ])
        .args(["--out", &dir.arg("report")])
        .output()
        .expect("run pathfarm bench up");
    assert!(
        out.status.success(),
        "pathfarm bench up failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json = std::fs::read(dir.path("report").join("up.json")).expect("read up.json");
    let results: serde_json::Value = serde_json::from_slice(&json).expect("up.json is JSON");
    let rows = results["rows"].as_array().expect("rows");
    let cases = results["cases"].as_array().expect("cases");
    assert_eq!(rows.len(), 3 * cases.len(), "{results}");
    for row in rows {
        assert_eq!(row["identical"], true, "{row}");
        let (layout, processes) = (
            row["layout"].as_str().unwrap_or_default(),
            row["processes"].as_u64().unwrap_or_default(),
        );
        let expected = match layout {
            "render" => 1,
            "up 1×2" => 2,
            "up 2×1" => 3,
            other => panic!("unexpected layout {other}"),
        };
        assert_eq!(processes, expected, "{row}");
        assert!(row["seconds"].as_f64().unwrap_or_default() > 0.0, "{row}");
        if layout != "render" {
            assert!(
                row["peak_rss_mib"].as_f64().unwrap_or_default() > 1.0,
                "{row}"
            );
        }
        // CPU time: the render's or the farm's (rendering took some), and the server's part of
        // the farm's (a part: the workers rendered).
        let cpu = row["cpu_seconds"].as_f64().expect("CPU seconds");
        assert!(cpu > 0.0, "{row}");
        match row["server_cpu_seconds"].as_f64() {
            None => assert_eq!(layout, "render", "{row}"),
            Some(server) => assert!((0.0..cpu).contains(&server), "{row}"),
        }
    }
    assert!(dir.path("report").join("up.md").is_file());
}
