//! Hostile submissions against a real `pathfarm serve` process while a real worker renders another
//! job: scenes that point outside (`../../etc/passwd`, `file://`, `http://`), a GLB whose chunk
//! lengths lie, a buffer that claims more bytes than it has, an upload over the size limit, a
//! 100k × 100k image request, a small PNG that decodes to a huge image, 10⁷ degenerate triangles
//! (one primitive of 60 MB, and a small file that instances a mesh 1,000 times: kept instanced,
//! read once), and 10⁸ real emissive triangles instanced from a small file (emitters are
//! flattened, so they count once per placement).
//!
//! All are sent at once. Each must get its own clear 4xx (status, JSON error code, a message that
//! names what is wrong), none may create a job, the server's peak memory must stay bounded (the
//! loader's limits and the server's two concurrent scene checks), and the job that was rendering
//! all along must complete byte-identical to a local render.

mod support;

use pathfarm_wire::api::JobSettings;
use pathfarm_worker::client::ClientError;
use std::io::Cursor;
use std::time::Duration;
use support::*;

/// The server's peak resident memory (VmHWM) in MiB.
fn peak_rss_mib(pid: libc::pid_t) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status"))
        .unwrap_or_else(|e| panic!("read /proc/{pid}/status: {e}"));
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        .map(|kib| kib / 1024)
        .unwrap_or_else(|| panic!("no VmHWM in /proc/{pid}/status"))
}

/// A GLB container: the JSON chunk and the BIN chunk, each padded to 4 bytes.
fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
    let mut j = json.as_bytes().to_vec();
    while !j.len().is_multiple_of(4) {
        j.push(b' ');
    }
    let mut b = bin.to_vec();
    while !b.len().is_multiple_of(4) {
        b.push(0);
    }
    let total = 12 + 8 + j.len() + 8 + b.len();
    let mut out = Vec::with_capacity(total);
    out.extend(b"glTF");
    out.extend(2u32.to_le_bytes());
    out.extend((total as u32).to_le_bytes());
    out.extend((j.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(&j);
    out.extend((b.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(&b);
    out
}

/// `triangles` triangles of a mesh instanced by `nodes` nodes: all the same real triangle when
/// `real`, else degenerate (every index 0 of a one-vertex mesh), of an emissive material when
/// `emissive` (which the loader flattens however often it is placed; others placed more than once
/// it keeps instanced, stored once). Indices are u16.
fn instanced(triangles: usize, nodes: usize, real: bool, emissive: bool) -> Vec<u8> {
    let index_bytes = triangles * 3 * 2;
    let mut bin = vec![0u8; 36 + index_bytes];
    if real {
        // Vertices (0,0,0), (1,0,0), (0,1,0); indices 0 1 2, 0 1 2, …
        bin[12..16].copy_from_slice(&1f32.to_le_bytes());
        bin[28..32].copy_from_slice(&1f32.to_le_bytes());
        for (k, index) in bin[36..].chunks_exact_mut(2).enumerate() {
            index.copy_from_slice(&((k % 3) as u16).to_le_bytes());
        }
    }
    let vertices = if real { 3 } else { 1 };
    let node_list: Vec<String> = (0..nodes).map(|_| r#"{"mesh":0}"#.to_string()).collect();
    let roots: Vec<String> = (0..nodes).map(|i| i.to_string()).collect();
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[{}]}}],"nodes":[{}],
        "meshes":[{{"name":"Mesh","primitives":[{{"attributes":{{"POSITION":0}},"indices":1{}}}]}}],{}
        "accessors":[{{"bufferView":0,"componentType":5126,"count":{vertices},"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                     {{"bufferView":1,"componentType":5123,"count":{},"type":"SCALAR"}}],
        "bufferViews":[{{"buffer":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":{index_bytes}}}],
        "buffers":[{{"byteLength":{}}}]}}"#,
        roots.join(","),
        node_list.join(","),
        if emissive { r#","material":0"# } else { "" },
        if emissive {
            r#""materials":[{"name":"Lamp","emissiveFactor":[1,1,1]}],"#
        } else {
            ""
        },
        triangles * 3,
        bin.len()
    );
    glb(&json, &bin)
}

/// A one-triangle scene whose buffer 0 has the given JSON (beyond `byteLength: 36`).
fn triangle_with_buffer(buffer: &str) -> Vec<u8> {
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}],
        "bufferViews":[{{"buffer":0,"byteLength":36}}],
        "buffers":[{buffer}]}}"#
    )
    .into_bytes()
}

/// A real, valid PNG (8-bit grey, all black) of `w × h` pixels: small on disk, large decoded.
fn black_png(w: u32, h: u32) -> Vec<u8> {
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    use image::ImageEncoder;
    let pixels = vec![0u8; w as usize * h as usize];
    let mut out = Vec::new();
    PngEncoder::new_with_quality(
        Cursor::new(&mut out),
        CompressionType::Fast,
        FilterType::NoFilter,
    )
    .write_image(&pixels, w, h, image::ExtendedColorType::L8)
    .expect("encode the PNG");
    out
}

/// A textured triangle whose base colour image is `png`, in the BIN chunk of a GLB.
fn textured(png: &[u8]) -> Vec<u8> {
    let mut bin = Vec::new();
    for v in [[0f32, 0., 0.], [1., 0., 0.], [0., 1., 0.]] {
        for c in v {
            bin.extend(c.to_le_bytes());
        }
    }
    bin.extend(png);
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"material":0}}]}}],
        "materials":[{{"pbrMetallicRoughness":{{"baseColorTexture":{{"index":0}}}}}}],
        "textures":[{{"source":0}}],"images":[{{"name":"Wall","bufferView":1,"mimeType":"image/png"}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}],
        "bufferViews":[{{"buffer":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":{}}}],
        "buffers":[{{"byteLength":{}}}]}}"#,
        png.len(),
        bin.len()
    );
    glb(&json, &bin)
}

struct Case {
    name: &'static str,
    scene: Vec<u8>,
    settings: JobSettings,
    status: u16,
    code: &'static str,
    /// Substrings the message must contain: what is wrong, and where.
    mentions: Vec<&'static str>,
}

fn cases() -> Vec<Case> {
    let small = JobSettings::new(16, 16, 1);
    let cornell = std::fs::read(SCENE).expect("read the Cornell box");
    let mut lying = glb(r#"{"asset":{"version":"2.0"}}"#, &[0; 8]);
    lying[20 + 28..24 + 28].copy_from_slice(&0x7fff_fff0u32.to_le_bytes());
    let mut out = vec![];
    for (name, uri) in [
        ("passwd.gltf", "../../etc/passwd"),
        ("file.gltf", "file:///etc/passwd"),
        ("http.gltf", "http://example.com/b.bin"),
    ] {
        out.push(Case {
            name,
            scene: triangle_with_buffer(&format!(r#"{{"uri":"{uri}","byteLength":36}}"#)),
            settings: small.clone(),
            status: 422,
            code: "invalid_scene",
            mentions: vec!["buffer 0", "external"],
        });
    }
    out.extend([
        Case {
            name: "lying-chunk.glb",
            scene: lying,
            settings: small.clone(),
            status: 422,
            code: "invalid_scene",
            mentions: vec!["GLB", "chunk length"],
        },
        Case {
            name: "short-buffer.gltf",
            scene: triangle_with_buffer(
                r#"{"uri":"data:application/octet-stream;base64,AAAAAA==","byteLength":1099511627776}"#,
            ),
            settings: small.clone(),
            status: 422,
            code: "invalid_scene",
            mentions: vec!["buffer 0", "has 4 bytes but its byteLength is 1099511627776"],
        },
        Case {
            name: "over-the-limit.gltf",
            scene: vec![b' '; 65 << 20],
            settings: small.clone(),
            status: 413,
            code: "too_large",
            mentions: vec!["64 MiB"],
        },
        Case {
            name: "huge-image.gltf",
            scene: cornell,
            settings: JobSettings::new(100_000, 100_000, 1),
            status: 422,
            code: "invalid_settings",
            mentions: vec!["100000"],
        },
        Case {
            name: "bomb-texture.glb",
            scene: textured(&black_png(16384, 8192)),
            settings: small.clone(),
            status: 422,
            code: "invalid_scene",
            mentions: vec!["image 0 \"Wall\"", "16384×8192 decodes to 512 MiB"],
        },
        Case {
            name: "dust-one-primitive.glb",
            scene: instanced(10_000_000, 1, false, false),
            settings: small.clone(),
            status: 422,
            code: "invalid_scene",
            mentions: vec!["all 10000000 triangles of the scene are degenerate"],
        },
        Case {
            // Kept instanced: its 10,000 triangles are read once.
            name: "dust-instanced.glb",
            scene: instanced(10_000, 1_000, false, false),
            settings: small.clone(),
            status: 422,
            code: "invalid_scene",
            mentions: vec!["all 10000 triangles of the scene are degenerate"],
        },
        Case {
            // 10⁸ real triangles from a file of 180 KB, emissive so that they would be flattened:
            // refused from the JSON before a byte of geometry is read.
            name: "instancing-bomb.glb",
            scene: instanced(10_000, 10_000, true, true),
            settings: small,
            status: 422,
            code: "invalid_scene",
            mentions: vec![
                "declares 100000000 triangles to store (10000 mesh instances; 0 instanced meshes stored once)",
                "over the limit of 20000000",
            ],
        },
    ]);
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hostile_scenes_get_clear_errors_while_another_job_renders() {
    let farm = Farm::new("hostile-scenes");
    let mut server = farm.serve("server", &["--max-scene-mib", "64"]).await;
    let api = farm.api();

    // The job that must keep rendering throughout.
    let settings = [
        "--width", "96", "--height", "96", "--spp", "96", "--seed", "21",
    ];
    let mut submitted = settings.to_vec();
    submitted.extend_from_slice(&["--tile", "32"]);
    let id = submit(&farm.dir, &farm.url, &submitted).await;
    let planned = 96 * 96 * 96;
    let _worker = farm.worker("worker", 4);
    poll(
        "the job to start rendering",
        Duration::from_secs(60),
        || async { (job(&api, &id).await.samples_done > 0).then_some(()) },
    )
    .await;
    let before = peak_rss_mib(server.pid());

    // Every hostile submission at once.
    let cases = cases();
    let mut handles = Vec::new();
    for case in cases {
        let client = farm.api();
        handles.push(tokio::spawn(async move {
            let got = client
                .submit(case.scene.clone(), case.name, &case.settings)
                .await;
            (case, got)
        }));
    }
    let mut failures = Vec::new();
    for h in handles {
        let (case, got) = h.await.expect("submission task");
        match got {
            Err(ClientError::Api {
                status,
                code,
                message,
                ..
            }) => {
                let missing: Vec<_> = case
                    .mentions
                    .iter()
                    .filter(|m| !message.contains(**m))
                    .collect();
                if status.as_u16() != case.status || code != case.code || !missing.is_empty() {
                    failures.push(format!(
                        "{}: got {status} {code} {message:?}; expected {} {} mentioning {:?}",
                        case.name, case.status, case.code, case.mentions
                    ));
                } else {
                    eprintln!("{}: {status} {code}: {message}", case.name);
                }
            }
            other => failures.push(format!("{}: expected a 4xx, got {other:?}", case.name)),
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert!(
        server.is_running(),
        "the server died: {}",
        server.log_text()
    );

    // Bounded memory (309 MiB measured): the worst case is two scene checks at once
    // (`--scene-checks 2`), each held to the loader's limits, plus the bodies in flight. Without
    // the limits the bomb texture alone would take 512 MiB of texels (twice over while
    // converting) and the one-primitive dust over 700 MiB.
    let peak = peak_rss_mib(server.pid());
    eprintln!("server peak RSS: {before} MiB before the hostile submissions, {peak} MiB after");
    assert!(
        peak < 640,
        "the server's peak memory reached {peak} MiB (it was {before} MiB before)"
    );

    // Nothing was created, and the job that was rendering all along ends byte-identical.
    let list = api.jobs(None, 0, 100).await.expect("list jobs");
    assert_eq!(list.total, 1, "only the real job exists: {:?}", list.jobs);
    let reference = render_reference(&farm.dir, "local.exr", &settings);
    let done = wait_completed(&api, &id, Duration::from_secs(300)).await;
    assert_eq!(done.samples_done, planned);
    assert_merged_once_and_identical(&api, &id, planned, &["worker"], reference, "hostile").await;
}
