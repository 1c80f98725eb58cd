//! A frame job's downloads (`frames.tar`, `preview.apng`) and per-frame image validators.

use super::*;

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
