//! Every frame's image is the local render of that frame, also when a worker goes silent midway.

use super::*;

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
