//! A noise target per frame: each frame stops where it reaches it, and the plan stays exact.

use super::*;

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
