//! Frame jobs (animations) on the farm, on both stores: every frame's image is bit-identical to a
//! local render of the scene at that frame (`pathfarm render --frame N --fps F`), whatever the
//! workers, tiles and slices; the lease order is interleaved (every frame's first pass before any
//! second pass) or sequential (frame after frame); bad specifications are 4xx with JSON.

mod common;

use axum::http::StatusCode;
use common::*;
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources, SceneSource};
use pathfarm_tracer::{render_image, Accumulation};
use pathfarm_wire::api::{ErrorBody, FrameOrder, JobSettings, JobState, WorkerRegistration};
use std::path::PathBuf;
use std::time::Duration;

/// Blender's animated export: a cube that slides and turns, a camera on an arc, a lamp that
/// rises, a bending skinned bar, a bulging morphed sphere (frames 1–48 at 24 fps).
fn animated() -> Vec<u8> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenes/suite/animated.glb");
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// `pathfarm render --frame frame --fps fps` of the job's settings, as EXR bytes.
fn local_frame(scene: &[u8], s: &JobSettings, frame: i64) -> Vec<u8> {
    exr(&local_accumulation(scene, s, frame))
}

/// `pathfarm render --frame frame --fps fps` of the job's settings.
fn local_accumulation(scene: &[u8], s: &JobSettings, frame: i64) -> Accumulation {
    let source = SceneSource::load(scene, &NoExternalResources, &LoadOptions::default()).unwrap();
    let time = gltf::frame_time(frame, s.frames_per_second());
    let scene = source.into_scene_at(time).unwrap().with_environment(None);
    render_image(&scene, &s.render_settings(), 32, 0..s.spp, &|_| {})
}

fn frame_settings(frames: &str, order: Option<FrameOrder>, tile: u32) -> JobSettings {
    let mut s = settings(24, 16, 3, tile);
    s.frames = Some(frames.into());
    s.fps = Some(24.0);
    s.frame_order = order;
    s
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn every_frame_is_bit_identical_to_a_local_render_at_that_frame() {
    let scene = animated();
    let frames = [30, 1, 12];
    let s = frame_settings("30,1,12", None, 8);
    let local: Vec<Accumulation> = frames
        .iter()
        .map(|&f| local_accumulation(&scene, &s, f))
        .collect();
    let expected: Vec<Vec<u8>> = local.iter().map(exr).collect();
    // Each frame's error, as the local render estimates it.
    let errors: Vec<f64> = local
        .iter()
        .map(|a| a.relative_error().expect("an estimate at 3 spp"))
        .collect();
    assert_ne!(
        expected[0], expected[1],
        "the frames differ: the scene moves"
    );
    for (store, url) in stores("frames-exact").await {
        let server = TestServer::start(config(&url)).await;
        let client = server.client(None);
        // (workers, tile size, fixed slice size: None = timed, order)
        for (workers, tile, slice, order) in [
            (2, 8, Some(1), None),
            (3, 12, None, Some(FrameOrder::Sequential)),
        ] {
            let mut s = s.clone();
            s.tile_size = tile;
            s.frame_order = order;
            let job = client
                .submit(scene.clone(), "animated.glb", &s)
                .await
                .unwrap();
            assert_eq!(job.samples_planned, 24 * 16 * 3 * 3);
            let ws: Vec<_> = (0..workers)
                .map(|_| TestWorker::spawn(&server.url, None, slice))
                .collect();
            let done = wait_final(&client, &job.id, Duration::from_secs(300)).await;
            for w in ws {
                w.stop().await;
            }
            assert_completed(&done);
            let view = client.job(&job.id).await.unwrap();
            assert_eq!((view.frames_total, view.frames_done), (Some(3), Some(3)));
            let progress = view.frames.expect("per-frame progress in the job's view");
            assert_eq!(progress.iter().map(|f| f.frame).collect::<Vec<_>>(), frames);
            assert!(progress
                .iter()
                .all(|f| f.complete && f.samples_done == 24 * 16 * 3));
            for (f, want) in frames.iter().zip(&expected) {
                let got = client.frame_exr(&job.id, *f).await.unwrap();
                assert!(
                    got == *want,
                    "{store}: {workers} workers, tile {tile}, slice {slice:?}, {order:?}: \
                     frame {f} differs from the local render at that frame"
                );
            }
            // The job's own image is its first frame's.
            assert!(client.image_exr(&job.id, false).await.unwrap() == expected[0]);
            // Each frame's error is the local render's (summed from the tiles, so equal up to
            // the order of the sums), in the view and as the last point of its own history; the
            // job's is its worst frame's.
            let close = |got: f64, want: f64| (got - want).abs() <= want * 1e-12;
            for ((p, f), want) in progress.iter().zip(frames).zip(&errors) {
                let got = p.relative_error.expect("every frame's error");
                assert!(close(got, *want), "{store}: frame {f}: {got} vs {want}");
                let history = client.frame_convergence(&job.id, f).await.unwrap();
                let last = history
                    .points
                    .last()
                    .expect("a point in the frame's history");
                assert_eq!(last.samples_done, 24 * 16 * 3, "{store}: frame {f}");
                let got = last.relative_error.expect("the frame's last error");
                assert!(
                    close(got, *want),
                    "{store}: frame {f}'s history: {got} vs {want}"
                );
            }
            let worst = errors.iter().copied().fold(0.0, f64::max);
            let got = done.relative_error.expect("the job's error");
            assert!(
                close(got, worst),
                "{store}: the job's error {got}, worst frame {worst}"
            );
            eprintln!("{store}: {workers} workers, tile {tile}, {order:?}: every frame identical");
        }
        server.stop().await;
    }
}

/// With a noise target, each frame stops taking samples once its error reaches it (its queued
/// tasks cancelled, its samples no longer planned), so the farm's work goes to the frames still
/// above it, and the job ends when its worst frame reaches it. In sequential order a frame would
/// otherwise take its whole spp before the next starts.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_noise_target_stops_each_frame_where_it_reaches_it() {
    let scene = animated();
    let frames = [30, 1, 12];
    let mut s = frame_settings("30,1,12", Some(FrameOrder::Sequential), 16);
    (s.width, s.height, s.spp) = (64, 48, 1 << 14);
    // What the noisiest frame reaches at 256 spp.
    let mut probe = s.clone();
    probe.spp = 256;
    let target = frames
        .iter()
        .map(|&f| {
            local_accumulation(&scene, &probe, f)
                .relative_error()
                .unwrap()
        })
        .fold(0.0, f64::max);
    s.noise_target = Some(target);
    for (store, url) in stores("frames-noise").await {
        let mut cfg = config(&url);
        // Passes of 16, 32, 64, … spp: the target comes several passes in.
        cfg.min_task_samples = 16 * 256;
        let server = TestServer::start(cfg).await;
        let client = server.client(None);
        let job = client
            .submit(scene.clone(), "animated.glb", &s)
            .await
            .unwrap();
        let ws: Vec<_> = (0..2)
            .map(|_| TestWorker::spawn(&server.url, None, None))
            .collect();
        let done = wait_final(&client, &job.id, Duration::from_secs(300)).await;
        for w in ws {
            w.stop().await;
        }
        assert_eq!(
            done.state,
            JobState::Completed,
            "{store}: {:?}",
            done.message
        );
        let view = client.job(&job.id).await.unwrap();
        assert_eq!(view.frames_done, Some(3), "{store}");
        let progress = view.frames.expect("per-frame progress");
        for p in &progress {
            let err = p.relative_error.expect("every frame's error");
            assert!(p.complete, "{store}: frame {}", p.frame);
            assert!(
                err <= target,
                "{store}: frame {}: {err} > {target}",
                p.frame
            );
            assert!(
                p.samples_per_pixel < u64::from(s.spp) / 4,
                "{store}: frame {} was not stopped at its target: {} spp",
                p.frame,
                p.samples_per_pixel
            );
        }
        let merged: u64 = progress.iter().map(|p| p.samples_done).sum();
        assert_eq!(done.samples_done, merged, "{store}");
        assert!(done.relative_error.unwrap() <= target, "{store}");
        eprintln!(
            "{store}: noise target {target:.4}: frames stopped at {:?} spp",
            progress
                .iter()
                .map(|p| p.samples_per_pixel)
                .collect::<Vec<_>>()
        );
        server.stop().await;
    }
}

/// Leases every task of a frame job with one worker, recording (frame, first sample) in lease
/// order.
async fn lease_order(url: &str, order: Option<FrameOrder>) -> Vec<(i64, u32)> {
    let mut c = config(url);
    c.max_leases_per_worker = 1000;
    // Tasks of any size, so that a frame has passes to interleave.
    c.min_task_samples = 1;
    let server = TestServer::start(c).await;
    let client = server.client(None);
    // 2 tiles a frame, passes [0,1) [1,3) [3,7) [7,15).
    let mut s = frame_settings("5-9x2", order, 8);
    s.width = 16;
    s.height = 8;
    s.spp = 15;
    client.submit(animated(), "animated.glb", &s).await.unwrap();
    let worker = register(&client, "w").await;
    let mut got = Vec::new();
    while let Some(l) = client.lease(&worker).await.unwrap() {
        got.push((
            l.frame.expect("a frame job's lease names its frame"),
            l.sample_begin,
        ));
    }
    server.stop().await;
    got
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_are_leased_interleaved_by_default_or_in_sequence() {
    for (store, url) in stores("frames-order").await {
        let interleaved = lease_order(&url, None).await;
        assert_eq!(interleaved.len(), 3 * 2 * 4, "{store}");
        // Every frame's pass before any frame's next pass: the first samples never go back.
        assert!(
            interleaved.windows(2).all(|w| w[0].1 <= w[1].1),
            "{store}: {interleaved:?}"
        );
        assert_eq!(
            interleaved[..6].iter().map(|l| l.0).collect::<Vec<_>>(),
            [5, 5, 7, 7, 9, 9],
            "{store}"
        );
        let sequential = lease_order(&url, Some(FrameOrder::Sequential)).await;
        assert_eq!(sequential.len(), 3 * 2 * 4, "{store}");
        let frames: Vec<i64> = sequential.iter().map(|l| l.0).collect();
        assert_eq!(frames[..8], [5; 8], "{store}: {sequential:?}");
        assert_eq!(frames[8..16], [7; 8], "{store}: {sequential:?}");
        assert_eq!(frames[16..], [9; 8], "{store}: {sequential:?}");
        assert!(sequential[..8].windows(2).all(|w| w[0].1 <= w[1].1));
    }
}

/// A frame job is one job to the scheduler: leases share the farm between it and a still job of
/// the same priority (the job with fewer leased tasks first), and a job of higher priority is
/// served before both.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frame_jobs_share_the_farm_by_priority_and_fair_share() {
    for (store, url) in stores("frames-fair").await {
        let mut c = config(&url);
        c.max_leases_per_worker = 1000;
        c.min_task_samples = 1;
        let server = TestServer::start(c).await;
        let client = server.client(None);
        let mut s = frame_settings("1-3", None, 8);
        s.spp = 8;
        let frames = client.submit(animated(), "animated.glb", &s).await.unwrap();
        let still = client
            .submit(cornell(), "c.gltf", &settings(24, 16, 8, 8))
            .await
            .unwrap();
        let worker = register(&client, "w").await;
        let mut jobs = Vec::new();
        for _ in 0..8 {
            let l = client.lease(&worker).await.unwrap().expect("work");
            jobs.push(l.job_id);
        }
        let count = |id: &str| jobs.iter().filter(|j| *j == id).count();
        assert_eq!(
            (count(&frames.id), count(&still.id)),
            (4, 4),
            "{store}: {jobs:?}"
        );
        let mut urgent = settings(8, 8, 4, 8);
        urgent.priority = 5;
        let urgent = client.submit(cornell(), "c.gltf", &urgent).await.unwrap();
        let l = client.lease(&worker).await.unwrap().expect("work");
        assert_eq!(l.job_id, urgent.id, "{store}: priority first");
        server.stop().await;
    }
}

#[tokio::test]
async fn bad_frame_settings_are_4xx_naming_the_field() {
    for (store, url) in stores("frames-bad").await {
        let server = TestServer::start(config(&url)).await;
        let scene = animated();
        for (settings, field) in [
            (r#"{"width":8,"height":8,"spp":1,"frames":"5-1"}"#, "frames"),
            (r#"{"width":8,"height":8,"spp":1,"frames":""}"#, "frames"),
            (r#"{"width":8,"height":8,"spp":1,"frames":"1,x"}"#, "frames"),
            (
                r#"{"width":8,"height":8,"spp":1,"frames":"0-99999"}"#,
                "frames",
            ),
            (
                r#"{"width":8,"height":8,"spp":1,"frames":"1-3,2"}"#,
                "frames",
            ),
            // A wrong JSON type is serde's message, as for every settings field.
            (
                r#"{"width":8,"height":8,"spp":1,"frames":7}"#,
                "expected a string",
            ),
            (
                r#"{"width":8,"height":8,"spp":1,"frames":"1-3","fps":0}"#,
                "fps",
            ),
            (
                r#"{"width":8,"height":8,"spp":1,"frames":"1-3","fps":-24}"#,
                "fps",
            ),
            (r#"{"width":8,"height":8,"spp":1,"fps":24}"#, "fps"),
            (
                r#"{"width":8,"height":8,"spp":1,"frames":"1","frame_order":"random"}"#,
                "expected `interleaved` or `sequential`",
            ),
        ] {
            let (ct, body) = multipart(&scene, settings);
            let (status, err): (StatusCode, ErrorBody) = call(
                &server.state,
                request("POST", "/api/v1/jobs", &[("content-type", &ct)], body),
            )
            .await;
            assert!(status.is_client_error(), "{store}: {settings}: {status}");
            assert!(
                err.error.message.contains(field),
                "{store}: {settings}: {}",
                err.error.message
            );
        }
        // A frame that is not the job's, and a frame of a still job, are 4xx too.
        let client = server.client(None);
        let job = client
            .submit(scene.clone(), "a.glb", &frame_settings("1-2", None, 8))
            .await
            .unwrap();
        let still = client
            .submit(cornell(), "c.gltf", &settings(8, 8, 1, 8))
            .await
            .unwrap();
        // A frame the job does not have is not found (a still job has none); a frame that is
        // not an integer is a bad query.
        for (id, q, want) in [
            (&job.id, "frame=3", StatusCode::NOT_FOUND),
            (&job.id, "frame=x", StatusCode::BAD_REQUEST),
            (&still.id, "frame=1", StatusCode::NOT_FOUND),
        ] {
            for image in ["image.exr", "preview.png", "convergence"] {
                let (status, _): (StatusCode, ErrorBody) = call(
                    &server.state,
                    request("GET", &format!("/api/v1/jobs/{id}/{image}?{q}"), &[], ""),
                )
                .await;
                assert_eq!(status, want, "{store}: {image}?{q}");
            }
        }
        let view = client.job(&still.id).await.unwrap();
        assert_eq!((view.frames_total, view.frames_done), (None, None));
        assert!(view.state != JobState::Failed);
        server.stop().await;
    }
}

/// A worker that goes silent in the middle of a frame job (as a killed one does: no release, no
/// sign-off) loses only its unmerged slice: its lease expires, the rest of its task is queued
/// again and rendered by another worker, its merged slice counts once, and every frame ends
/// bit-identical to the local render.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_silenced_worker_loses_only_its_slice() {
    use pathfarm_tracer::{render_tile, Tile};
    use pathfarm_wire::{encode_slice, Slice};
    let scene = animated();
    let frames = [2, 20];
    let mut s = frame_settings("2,20", Some(FrameOrder::Sequential), 8);
    s.spp = 8;
    let expected: Vec<Vec<u8>> = frames.iter().map(|&f| local_frame(&scene, &s, f)).collect();
    for (store, url) in stores("frames-silenced").await {
        let mut cfg = config(&url);
        cfg.lease_duration = Duration::from_millis(500);
        cfg.monitor_interval = Duration::from_millis(50);
        let server = TestServer::start(cfg).await;
        let client = server.client(None);
        let job = client
            .submit(scene.clone(), "animated.glb", &s)
            .await
            .unwrap();
        let a = client
            .register(&WorkerRegistration {
                name: "a".into(),
                threads: 1,
                version: "test".into(),
                host: "test".into(),
            })
            .await
            .unwrap()
            .worker_id;
        // Worker A takes tasks until it holds one of at least two samples, merges the first
        // sample of it, and falls silent.
        let (lease, built) = loop {
            let l = client.lease(&a).await.unwrap().expect("work");
            let frame = l.frame.expect("a frame task");
            let source =
                SceneSource::load(&scene, &NoExternalResources, &LoadOptions::default()).unwrap();
            let built = source
                .into_scene_at(gltf::frame_time(frame, s.frames_per_second()))
                .unwrap();
            if l.sample_end - l.sample_begin >= 2 {
                break (l, built);
            }
            let tile = Tile {
                x0: l.tile.x0,
                y0: l.tile.y0,
                width: l.tile.width,
                height: l.tile.height,
            };
            let acc = render_tile(&built, &l.settings.render_settings(), tile, 0..1);
            let body = encode_slice(&Slice {
                sample_begin: 0,
                sample_end: 1,
                acc,
            });
            client
                .upload_slice(l.task_id, &l.lease_token, body)
                .await
                .unwrap();
        };
        let tile = Tile {
            x0: lease.tile.x0,
            y0: lease.tile.y0,
            width: lease.tile.width,
            height: lease.tile.height,
        };
        let (b, e) = (lease.sample_begin, lease.sample_begin + 1);
        let acc = render_tile(&built, &lease.settings.render_settings(), tile, b..e);
        let ack = client
            .upload_slice(
                lease.task_id,
                &lease.lease_token,
                encode_slice(&Slice {
                    sample_begin: b,
                    sample_end: e,
                    acc,
                }),
            )
            .await
            .unwrap();
        assert!(!ack.task_complete && !ack.duplicate);
        let w = TestWorker::spawn(&server.url, None, Some(1));
        let done = wait_final(&client, &job.id, Duration::from_secs(300)).await;
        let report = w.stop().await;
        assert_completed(&done);
        assert!(report.slices > 0);
        let view = client.job(&job.id).await.unwrap();
        assert_eq!(view.frames_done, Some(2), "{store}");
        for (f, want) in frames.iter().zip(&expected) {
            let got = client.frame_exr(&job.id, *f).await.unwrap();
            assert!(
                got == *want,
                "{store}: frame {f} differs after the silenced worker"
            );
        }
        server.stop().await;
    }
}

/// `GET path` through the router in process: status, content type, body.
async fn get(server: &TestServer, path: &str) -> (StatusCode, Option<String>, axum::body::Bytes) {
    call_raw(&server.state, request("GET", path, &[], "")).await
}

/// What [`png_frames`] reads: each frame's 8-bit RGB, the first frame's delay (`None` for a still
/// PNG) and the APNG's frame count.
type PngFrames = (Vec<Vec<u8>>, Option<(u16, u16)>, Option<u32>);

/// The 8-bit RGB of a PNG (or of each frame of an APNG), in order.
fn png_frames(bytes: &[u8]) -> PngFrames {
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .expect("a PNG");
    let info = reader.info();
    let count = info.animation_control().map(|a| a.num_frames);
    let delay = info.frame_control().map(|f| (f.delay_num, f.delay_den));
    let mut frames = Vec::new();
    for _ in 0..count.unwrap_or(1) {
        let mut buf = vec![0; reader.output_buffer_size().expect("a frame's size")];
        let frame = reader.next_frame(&mut buf).expect("a frame");
        buf.truncate(frame.buffer_size());
        frames.push(buf);
    }
    (frames, delay, count)
}

/// `frames.tar` holds every frame with a merged sample as `frame_NNNN.exr`, in the job's order,
/// each the bytes `image.exr?frame=N` serves (and so the local render of that frame);
/// `preview.apng` holds the complete frames, each as `preview.png?frame=N` shows it, at the
/// requested exposure and rate. Neither exists for a still job (404) or before the first sample
/// (409).
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn all_frames_download_as_a_tar_of_exrs_and_as_an_animated_png() {
    use std::io::Read;
    let scene = animated();
    let frames = [12, 3, 40];
    let s = frame_settings("12,3,40", None, 8);
    let local_first = local_frame(&scene, &s, 12);
    for (store, url) in stores("frames-downloads").await {
        let server = TestServer::start(config(&url)).await;
        let client = server.client(None);
        let job = client
            .submit(scene.clone(), "animated.glb", &s)
            .await
            .unwrap();
        let still = client
            .submit(cornell(), "c.gltf", &settings(8, 8, 1, 8))
            .await
            .unwrap();
        for (id, status, code) in [
            (&job.id, StatusCode::CONFLICT, "no_frames"),
            (&still.id, StatusCode::NOT_FOUND, "not_found"),
        ] {
            for path in ["frames.tar", "preview.apng"] {
                let (got, err): (StatusCode, ErrorBody) = call(
                    &server.state,
                    request("GET", &format!("/api/v1/jobs/{id}/{path}"), &[], ""),
                )
                .await;
                assert_eq!(
                    (got, err.error.code.as_str()),
                    (status, code),
                    "{store}: {path}"
                );
            }
        }
        let (got, _): (StatusCode, ErrorBody) = call(
            &server.state,
            request(
                "GET",
                &format!("/api/v1/jobs/{}/preview.apng?fps=0", job.id),
                &[],
                "",
            ),
        )
        .await;
        assert_eq!(got, StatusCode::BAD_REQUEST, "{store}: fps=0");

        let w = TestWorker::spawn(&server.url, None, Some(1));
        let done = wait_final(&client, &job.id, Duration::from_secs(300)).await;
        w.stop().await;
        assert_completed(&done);

        let (status, ct, body) = get(&server, &format!("/api/v1/jobs/{}/frames.tar", job.id)).await;
        assert_eq!(status, StatusCode::OK, "{store}");
        assert_eq!(ct.as_deref(), Some("application/x-tar"), "{store}");
        assert!(
            body.len() >= 1024 && body[body.len() - 1024..].iter().all(|&b| b == 0),
            "{store}: the archive does not end with its two blocks of zeros"
        );
        let mut names = Vec::new();
        let mut archive = tar::Archive::new(&body[..]);
        for entry in archive.entries().expect("a tar") {
            let mut entry = entry.expect("an entry");
            let name = entry.path().expect("a name").display().to_string();
            let mut bytes = Vec::new();
            entry.read_to_end(&mut bytes).expect("an entry's bytes");
            let frame: i64 = name
                .trim_start_matches("frame_")
                .trim_end_matches(".exr")
                .parse()
                .unwrap_or_else(|e| panic!("{store}: {name}: {e}"));
            let served = client.frame_exr(&job.id, frame).await.unwrap();
            assert!(
                bytes == served,
                "{store}: {name} differs from image.exr?frame={frame}"
            );
            if frame == 12 {
                assert!(
                    bytes == local_first,
                    "{store}: {name} differs from the local render"
                );
            }
            names.push(name);
        }
        assert_eq!(
            names,
            ["frame_0012.exr", "frame_0003.exr", "frame_0040.exr"],
            "{store}"
        );

        let (status, ct, body) = get(
            &server,
            &format!("/api/v1/jobs/{}/preview.apng?exposure=1.5&fps=12", job.id),
        )
        .await;
        assert_eq!(status, StatusCode::OK, "{store}");
        assert_eq!(ct.as_deref(), Some("image/apng"), "{store}");
        let (animation, delay, count) = png_frames(&body);
        assert_eq!(count, Some(3), "{store}: an APNG of the three frames");
        assert_eq!(delay, Some((83, 1000)), "{store}: 12 frames a second");
        for (f, rgb) in frames.iter().zip(&animation) {
            let png = client.frame_png(&job.id, *f, 1.5).await.unwrap();
            let (still_frames, still_delay, _) = png_frames(&png);
            assert_eq!(still_delay, None);
            assert!(
                *rgb == still_frames[0],
                "{store}: APNG frame {f} differs from preview.png?frame={f}"
            );
        }
        assert_ne!(animation[0], animation[2], "{store}: the frames move");
        server.stop().await;
    }
}

/// A slice of `lease`'s whole sample range with the same valid value in every sample (what it
/// shows does not matter here, only that it is merged).
fn flat_slice(lease: &pathfarm_wire::api::Lease) -> Vec<u8> {
    flat_slice_of(lease, lease.sample_begin, lease.sample_end)
}

/// [`flat_slice`] of samples `begin..end` of `lease`'s range.
fn flat_slice_of(lease: &pathfarm_wire::api::Lease, begin: u32, end: u32) -> Vec<u8> {
    let t = &lease.tile;
    let mut acc = pathfarm_tracer::Accumulation::new(t.x0, t.y0, t.width, t.height);
    for p in &mut acc.pixels {
        for _ in begin..end {
            p.add_sample(glam::Vec3::splat(0.5));
        }
    }
    pathfarm_wire::encode_slice(&pathfarm_wire::Slice {
        sample_begin: begin,
        sample_end: end,
        acc,
    })
}

/// Stopping a frame at the noise target ends its queued tasks as they stand — one partly merged
/// and given back keeps its merged samples (done), one not begun is cancelled — and takes their
/// unmerged samples off the plan, exactly; when the other frames are done that completes the job
/// by the one completion rule, with every planned sample merged and nothing queued or leased.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn stopping_a_frame_ends_its_queued_tasks_and_keeps_the_plan_exact() {
    for (store, url) in stores("frames-stop").await {
        let mut c = config(&url);
        c.max_leases_per_worker = 1000;
        c.min_task_samples = 1;
        c.monitor_interval = Duration::from_secs(3600);
        let server = TestServer::start(c).await;
        let client = server.client(None);
        // One tile a frame (tile 0 is frame 1's, tile 1 frame 2's); passes [0,1) [1,3) [3,7)
        // [7,15): four tasks a frame.
        let mut s = frame_settings("1,2", None, 32);
        s.spp = 15;
        let job = client.submit(animated(), "animated.glb", &s).await.unwrap();
        let px = 24 * 16;
        assert_eq!(job.samples_planned, 2 * 15 * px);
        let worker = register(&client, "w").await;
        let mut leases = Vec::new();
        while let Some(l) = client.lease(&worker).await.unwrap() {
            leases.push(l);
        }
        let of_frame =
            |f: i64| -> Vec<_> { leases.iter().filter(|l| l.frame == Some(f)).collect() };
        let (one, two) = (of_frame(1), of_frame(2));
        assert_eq!((one.len(), two.len()), (4, 4), "{store}");
        for l in two.iter().chain(&one[..2]) {
            client
                .upload_slice(l.task_id, &l.lease_token, flat_slice(l))
                .await
                .unwrap();
        }
        // Frame 1's third task: two of its four samples merged, then given back; its fourth
        // given back untouched.
        let (third, fourth) = (one[2], one[3]);
        assert_eq!((third.sample_begin, third.sample_end), (3, 7), "{store}");
        client
            .upload_slice(
                third.task_id,
                &third.lease_token,
                flat_slice_of(third, 3, 5),
            )
            .await
            .unwrap();
        client
            .release(third.task_id, &third.lease_token)
            .await
            .unwrap();
        client
            .release(fourth.task_id, &fourth.lease_token)
            .await
            .unwrap();
        let before = client.job(&job.id).await.unwrap();
        assert_eq!(before.samples_done, (15 + 5) * px, "{store}");
        assert_eq!(before.state, JobState::Running, "{store}");

        let stopped = server
            .state
            .store
            .stop_frames(&job.id, &[(0, 1)])
            .await
            .unwrap();
        assert_eq!(stopped.tasks, 2, "{store}");
        assert!(stopped.completed, "{store}: nothing planned is left");
        let done = client.job(&job.id).await.unwrap();
        assert_eq!(done.state, JobState::Completed, "{store}");
        assert_eq!(
            (done.samples_done, done.samples_planned, done.leased_tasks),
            ((15 + 5) * px, (15 + 5) * px, 0),
            "{store}"
        );
        let frames = done.frames.expect("per-frame progress");
        assert_eq!(
            frames
                .iter()
                .map(|f| (f.frame, f.samples_per_pixel))
                .collect::<Vec<_>>(),
            [(1, 5), (2, 15)],
            "{store}"
        );
        // Nothing queued is left to lease, and stopping again stops nothing.
        assert!(client.lease(&worker).await.unwrap().is_none(), "{store}");
        let again = server
            .state
            .store
            .stop_frames(&job.id, &[(0, 1)])
            .await
            .unwrap();
        assert_eq!(again.tasks, 0, "{store}");
        server.stop().await;
    }
}

/// `GET path` with `If-None-Match: tag` when given: status and ETag.
async fn image_tag(server: &TestServer, path: &str, tag: Option<&str>) -> (StatusCode, String) {
    use tower::ServiceExt;
    let headers: Vec<(&str, &str)> = tag.map(|t| ("If-None-Match", t)).into_iter().collect();
    let resp = pathfarm_server::app(server.state.clone())
        .oneshot(request("GET", path, &headers, ""))
        .await
        .unwrap();
    let etag = resp.headers()["etag"].to_str().unwrap().to_string();
    (resp.status(), etag)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_merge_into_one_frame_leaves_the_other_frames_images_current() {
    for (store, url) in stores("frames-versions").await {
        let mut c = config(&url);
        c.max_leases_per_worker = 1000;
        c.min_task_samples = 1;
        let server = TestServer::start(c).await;
        let client = server.client(None);
        // One tile a frame (tile 0 is frame 1's, tile 1 frame 2's).
        let job = client
            .submit(animated(), "animated.glb", &frame_settings("1,2", None, 32))
            .await
            .unwrap();
        let worker = register(&client, "w").await;
        let mut leases = Vec::new();
        while let Some(l) = client.lease(&worker).await.unwrap() {
            leases.push(l);
        }
        let of_frame = |f: i64| {
            leases
                .iter()
                .filter(move |l| l.frame == Some(f))
                .collect::<Vec<_>>()
        };
        let (one, two) = (of_frame(1), of_frame(2));
        assert!(
            one.len() >= 2 && two.len() >= 2,
            "{store}: passes per frame"
        );
        let upload = |l: &pathfarm_wire::api::Lease| {
            let (id, token, body) = (l.task_id, l.lease_token.clone(), flat_slice(l));
            let client = &client;
            async move { client.upload_slice(id, &token, body).await }
        };
        upload(one[0]).await.unwrap();
        let frame1 = format!("/api/v1/jobs/{}/image.exr?frame=1", job.id);
        let frame2 = format!("/api/v1/jobs/{}/image.exr?frame=2", job.id);
        let (status, tag1) = image_tag(&server, &frame1, None).await;
        assert_eq!(status, StatusCode::OK, "{store}");
        let (_, empty2) = image_tag(&server, &frame2, None).await;
        assert_eq!(
            empty2, "\"v0.f1.exr\"",
            "{store}: frame 2 has nothing merged yet"
        );
        let builds = server.state.images.builds();
        // Merges into frame 2 change neither frame 1's image nor its tag: no build, 304.
        upload(two[0]).await.unwrap();
        upload(two[1]).await.unwrap();
        assert_eq!(image_tag(&server, &frame1, None).await.1, tag1, "{store}");
        assert_eq!(
            image_tag(&server, &frame1, Some(&tag1)).await.0,
            StatusCode::NOT_MODIFIED,
            "{store}"
        );
        assert_eq!(
            server.state.images.builds(),
            builds,
            "{store}: frame 1 rebuilt"
        );
        // Frame 2's own image moved on; a merge into frame 1 moves frame 1's.
        let (_, tag2) = image_tag(&server, &frame2, None).await;
        assert_eq!(tag2, "\"v2.f1.exr\"", "{store}");
        upload(one[1]).await.unwrap();
        let (status, newer1) = image_tag(&server, &frame1, Some(&tag1)).await;
        assert_eq!(
            (status, newer1.as_str()),
            (StatusCode::OK, "\"v2.f0.exr\""),
            "{store}"
        );
        server.stop().await;
    }
}
