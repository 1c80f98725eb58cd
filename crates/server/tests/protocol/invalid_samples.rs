//! Slices with invalid samples: merged out of order, or holding nothing else.

use super::*;

/// A later pass of a tile may be merged before an earlier one (two workers on two passes). A
/// recorded invalid sample of the later pass then lies beyond the tile's sample count so far; the
/// stored tile must still decode, for the next merge and for the image.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn invalid_samples_of_a_later_pass_merged_first_keep_the_tile_readable() {
    use glam::Vec3;
    use pathfarm_tracer::accumulation::InvalidSample;
    use pathfarm_tracer::Accumulation;
    let bytes = cornell();
    let scene = load(&bytes);
    for (store, url) in stores("invalid-order").await {
        let mut cfg = config(&url);
        cfg.min_task_samples = 1;
        let server = TestServer::start(cfg).await;
        let c = server.client(None);
        // One 16×16 tile; passes [0,1) [1,3) [3,8).
        let job = c
            .submit(bytes.clone(), "c.gltf", &settings(16, 16, 8, 16))
            .await
            .unwrap();
        let a = register(&c, "a").await;
        let b = register(&c, "b").await;
        let first = c.lease(&a).await.unwrap().expect("work");
        let second = c.lease(&b).await.unwrap().expect("work");
        assert_eq!(
            (first.sample_end, second.sample_begin, second.sample_end),
            (1, 1, 3),
            "{store}"
        );
        // Pass [1,3) first, with its sample 2 of the corner pixel invalid (NaN on a worker).
        let t = &second.tile;
        let mut acc = Accumulation::new(t.x0, t.y0, t.width, t.height);
        for (i, p) in acc.pixels.iter_mut().enumerate() {
            for _ in 0..if i == 0 { 1 } else { 2 } {
                p.add_sample(Vec3::new(0.25, 0.5, 1.0));
            }
        }
        acc.invalid_count = 1;
        acc.invalid.push(InvalidSample {
            x: t.x0,
            y: t.y0,
            index: 2,
        });
        let body = encode_slice(&Slice {
            sample_begin: 1,
            sample_end: 3,
            acc,
        });
        c.upload_slice(second.task_id, &second.lease_token, body)
            .await
            .unwrap_or_else(|e| panic!("{store}: the later pass: {e}"));
        // Then the first pass, and the image: both read the stored tile back.
        c.upload_slice(
            first.task_id,
            &first.lease_token,
            slice_body(&scene, &first, 0, 1),
        )
        .await
        .unwrap_or_else(|e| panic!("{store}: the first pass after the later one: {e}"));
        c.image_exr(&job.id, true)
            .await
            .unwrap_or_else(|e| panic!("{store}: the image: {e}"));
        let j = c.job(&job.id).await.unwrap();
        assert_eq!(j.samples_done, 256 * 3, "{store}");
        server.stop().await;
    }
}

/// A slice of `lease`'s samples `begin..end` in which every sample is invalid (what a worker that
/// renders nothing could claim).
fn all_invalid_body(lease: &Lease, begin: u32, end: u32) -> Vec<u8> {
    let t = &lease.tile;
    let mut acc = pathfarm_tracer::Accumulation::new(t.x0, t.y0, t.width, t.height);
    acc.invalid_count = u64::from(end - begin) * acc.pixels.len() as u64;
    encode_slice(&Slice {
        sample_begin: begin,
        sample_end: end,
        acc,
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_slice_of_only_invalid_samples_completes_nothing() {
    let bytes = cornell();
    let scene = load(&bytes);
    for (store, url) in stores("all-invalid").await {
        let server = TestServer::start(config(&url)).await;
        let c = server.client(None);
        // One 16×16 tile, two passes: tasks [0, 1) and [1, 2).
        let job = c
            .submit(bytes.clone(), "c.gltf", &settings(16, 16, 2, 16))
            .await
            .unwrap();
        let (a, b, d) = (
            register(&c, "a").await,
            register(&c, "b").await,
            register(&c, "d").await,
        );
        let first = c.lease(&a).await.unwrap().expect("work");
        let e = c
            .upload_slice(
                first.task_id,
                &first.lease_token,
                all_invalid_body(&first, 0, 1),
            )
            .await
            .expect_err("an all-invalid slice is refused");
        assert_eq!(
            code(&e),
            (StatusCode::UNPROCESSABLE_ENTITY, "all_invalid".into()),
            "{store}"
        );
        let j = c.job(&job.id).await.unwrap();
        assert_eq!((j.state, j.samples_done), (JobState::Running, 0), "{store}");
        // Its worker is not given the task again; another worker is, and its honest slice merges.
        let second = c.lease(&a).await.unwrap().expect("the other task");
        assert_ne!(second.task_id, first.task_id, "{store}");
        let again = c
            .lease(&b)
            .await
            .unwrap()
            .expect("the refused task, queued again");
        assert_eq!(
            (again.task_id, again.sample_begin, again.sample_end),
            (first.task_id, 0, 1),
            "{store}"
        );
        c.upload_slice(
            again.task_id,
            &again.lease_token,
            slice_body(&scene, &again, 0, 1),
        )
        .await
        .unwrap_or_else(|e| panic!("{store}: the honest slice: {e}"));
        // The other task: all invalid on two workers is the scene's doing, and fails the job.
        c.upload_slice(
            second.task_id,
            &second.lease_token,
            all_invalid_body(&second, 1, 2),
        )
        .await
        .expect_err("refused");
        assert!(
            c.lease(&a).await.unwrap().is_none(),
            "{store}: nothing else for a"
        );
        let last = c.lease(&d).await.unwrap().expect("the second refused task");
        assert_eq!(last.task_id, second.task_id, "{store}");
        let e = c
            .upload_slice(
                last.task_id,
                &last.lease_token,
                all_invalid_body(&last, 1, 2),
            )
            .await
            .expect_err("refused");
        assert_eq!(code(&e).1, "all_invalid", "{store}");
        let j = c.job(&job.id).await.unwrap();
        assert_eq!(j.state, JobState::Failed, "{store}");
        assert_eq!(
            j.samples_done, 256,
            "{store}: only the honest slice was merged"
        );
        let message = j.message.unwrap_or_default();
        assert!(
            message.contains(&a) && message.contains(&d) && message.contains("invalid"),
            "{store}: {message}"
        );
        assert!(
            c.lease(&b).await.unwrap().is_none(),
            "{store}: a failed job leases nothing"
        );
        server.stop().await;
    }
}
