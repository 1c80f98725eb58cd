//! The lease and upload protocol, state changes and bad input, over real HTTP on both stores.

mod common;

use common::*;
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};
use pathfarm_tracer::{render_tile, Scene, Tile};
use pathfarm_wire::api::{JobState, Lease, WorkerState};
use pathfarm_wire::{encode_slice, Slice};
use pathfarm_worker::client::ClientError;
use reqwest::StatusCode;
use std::time::Duration;

fn load(scene: &[u8]) -> Scene {
    gltf::load(scene, &NoExternalResources, &LoadOptions::default()).unwrap()
}

fn slice_body(scene: &Scene, lease: &Lease, begin: u32, end: u32) -> Vec<u8> {
    let tile = Tile {
        x0: lease.tile.x0,
        y0: lease.tile.y0,
        width: lease.tile.width,
        height: lease.tile.height,
    };
    let acc = render_tile(scene, &lease.settings.render_settings(), tile, begin..end);
    encode_slice(&Slice {
        sample_begin: begin,
        sample_end: end,
        acc,
    })
}

fn code(e: &ClientError) -> (StatusCode, String) {
    match e {
        ClientError::Api { status, code, .. } => (*status, code.clone()),
        other => panic!("expected an API error, got {other}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn uploads_are_counted_once_and_stale_leases_are_fenced() {
    let bytes = cornell();
    let scene = load(&bytes);
    for (store, url) in stores("fencing").await {
        let mut cfg = config(&url);
        cfg.lease_duration = Duration::from_millis(400);
        cfg.monitor_interval = Duration::from_millis(50);
        // Tasks of any size, so that one tile has passes of a few samples each.
        cfg.min_task_samples = 1;
        let server = TestServer::start(cfg).await;
        let c = server.client(None);
        // One tile, three passes.
        let mut s = settings(16, 16, 8, 16);
        s.seed = 11;
        let job = c.submit(bytes.clone(), "c.gltf", &s).await.unwrap();
        assert_eq!(job.tasks, 3); // passes [0,1) [1,3) [3,8)
        let a = register(&c, "a").await;
        let b = register(&c, "b").await;

        let l0 = c.lease(&a).await.unwrap().expect("work");
        assert_eq!((l0.sample_begin, l0.sample_end), (0, 1));
        let body = slice_body(&scene, &l0, 0, 1);
        let ack = c
            .upload_slice(l0.task_id, &l0.lease_token, body.clone())
            .await
            .unwrap();
        assert!(!ack.duplicate && ack.task_complete);
        // The same upload again (a retry after a lost answer): acknowledged, not counted.
        let again = c
            .upload_slice(l0.task_id, &l0.lease_token, body)
            .await
            .unwrap();
        assert!(again.duplicate, "{store}");
        assert_eq!(c.job(&job.id).await.unwrap().samples_done, 256, "{store}");

        // Task [1,3): upload [1,2), then worker a goes silent.
        let l1 = c.lease(&a).await.unwrap().expect("work");
        assert_eq!((l1.sample_begin, l1.sample_end), (1, 3));
        let first = slice_body(&scene, &l1, 1, 2);
        c.upload_slice(l1.task_id, &l1.lease_token, first.clone())
            .await
            .unwrap();
        // A gap is refused: [2,3) must come before anything later.
        let e = c
            .upload_slice(
                l1.task_id,
                &l1.lease_token,
                slice_body(&scene, &l1, 2, 2 + 1).clone(),
            )
            .await;
        assert!(e.is_ok(), "{store}: the next slice in order is accepted");
        // Wrong shape: a slice of another tile size.
        let l2 = c.lease(&a).await.unwrap().expect("work");
        let mut wrong = l2.clone();
        wrong.tile.width = 8;
        let e = c
            .upload_slice(
                l2.task_id,
                &l2.lease_token,
                slice_body(&scene, &wrong, l2.sample_begin, l2.sample_begin + 1),
            )
            .await
            .unwrap_err();
        assert_eq!(
            code(&e),
            (StatusCode::UNPROCESSABLE_ENTITY, "slice_shape".into()),
            "{store}"
        );
        // Out of order within the task.
        let e = c
            .upload_slice(
                l2.task_id,
                &l2.lease_token,
                slice_body(&scene, &l2, l2.sample_begin + 1, l2.sample_begin + 2),
            )
            .await
            .unwrap_err();
        assert_eq!(
            code(&e),
            (StatusCode::CONFLICT, "slice_out_of_order".into()),
            "{store}"
        );
        // Merge one slice of l2, then let its lease expire: only the rest is queued again.
        c.upload_slice(
            l2.task_id,
            &l2.lease_token,
            slice_body(&scene, &l2, l2.sample_begin, l2.sample_begin + 1),
        )
        .await
        .unwrap();
        tokio::time::sleep(Duration::from_millis(700)).await;
        let l2b = loop {
            let l = c.lease(&b).await.unwrap().expect("work");
            if l.task_id == l2.task_id {
                break l;
            }
            // Another task: finish it properly so the queue moves on.
            let body = slice_body(&scene, &l, l.sample_begin, l.sample_end);
            c.upload_slice(l.task_id, &l.lease_token, body)
                .await
                .unwrap();
        };
        assert_eq!(
            l2b.sample_begin,
            l2.sample_begin + 1,
            "{store}: merged samples are not rendered again"
        );
        assert_ne!(l2b.lease_token, l2.lease_token);
        // The presumed-dead worker's late upload is fenced off.
        let e = c
            .upload_slice(
                l2.task_id,
                &l2.lease_token,
                slice_body(&scene, &l2, l2.sample_begin + 1, l2.sample_end),
            )
            .await
            .unwrap_err();
        assert_eq!(
            code(&e),
            (StatusCode::CONFLICT, "stale_lease".into()),
            "{store}"
        );
        let body = slice_body(&scene, &l2b, l2b.sample_begin, l2b.sample_end);
        c.upload_slice(l2b.task_id, &l2b.lease_token, body)
            .await
            .unwrap();
        // Finish the job with b and compare to a local render.
        while let Some(l) = c.lease(&b).await.unwrap() {
            let body = slice_body(&scene, &l, l.sample_begin, l.sample_end);
            c.upload_slice(l.task_id, &l.lease_token, body)
                .await
                .unwrap();
        }
        let done = c.job(&job.id).await.unwrap();
        assert_completed(&done);
        assert_eq!(
            c.image_exr(&job.id, false).await.unwrap(),
            exr(&local_render(&bytes, &s)),
            "{store}"
        );
        let workers = c.workers().await.unwrap().workers;
        assert!(
            workers
                .iter()
                .any(|w| w.id == a && w.state == WorkerState::Lost),
            "{store}: silent worker a is shown lost: {workers:?}"
        );
        server.stop().await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn job_states_priorities_and_stopping_rules() {
    let bytes = cornell();
    let scene = load(&bytes);
    for (store, url) in stores("states").await {
        let server = TestServer::start(config(&url)).await;
        let c = server.client(None);
        let low = c
            .submit(bytes.clone(), "low", &settings(16, 16, 4, 16))
            .await
            .unwrap();
        let mut hs = settings(16, 16, 4, 16);
        hs.priority = 5;
        let high = c.submit(bytes.clone(), "high", &hs).await.unwrap();
        let w = register(&c, "w").await;
        let l = c.lease(&w).await.unwrap().unwrap();
        assert_eq!(l.job_id, high.id, "{store}: higher priority first");
        c.release(l.task_id, &l.lease_token).await.unwrap();
        // Lower the high job's priority: now the low one (older) comes first.
        let mut patch = c.job(&high.id).await.unwrap();
        patch.priority = -1;
        let resp = reqwest::Client::new()
            .patch(format!("{}/api/v1/jobs/{}", server.url, high.id))
            .json(&serde_json::json!({ "priority": -1 }))
            .send()
            .await
            .unwrap();
        assert_eq!(resp.status(), StatusCode::OK);
        let l = c.lease(&w).await.unwrap().unwrap();
        assert_eq!(l.job_id, low.id, "{store}");
        // Fair share among equal priorities: a second worker gets the other job.
        let mut eq = settings(16, 16, 4, 16);
        eq.priority = 0;
        let other = c.submit(bytes.clone(), "other", &eq).await.unwrap();
        let w2 = register(&c, "w2").await;
        let l2 = c.lease(&w2).await.unwrap().unwrap();
        assert_eq!(
            l2.job_id, other.id,
            "{store}: the job without a leased task goes first"
        );
        // Pause: no new leases for it; the upload in hand is accepted and told to stop.
        let v = c.job_action(&low.id, "pause").await.unwrap();
        assert_eq!(v.state, JobState::Paused);
        let ack = c
            .upload_slice(
                l.task_id,
                &l.lease_token,
                slice_body(&scene, &l, l.sample_begin, l.sample_end),
            )
            .await
            .unwrap();
        assert!(!ack.duplicate);
        let e = c.job_action(&low.id, "pause").await.unwrap_err();
        assert_eq!(code(&e), (StatusCode::CONFLICT, "invalid_state".into()));
        assert_eq!(
            c.job_action(&low.id, "resume").await.unwrap().state,
            JobState::Running
        );
        // Cancel: outstanding leases are fenced.
        let v = c.job_action(&other.id, "cancel").await.unwrap();
        assert_eq!(v.state, JobState::Cancelled);
        let e = c
            .upload_slice(
                l2.task_id,
                &l2.lease_token,
                slice_body(&scene, &l2, l2.sample_begin, l2.sample_end),
            )
            .await
            .unwrap_err();
        assert_eq!(code(&e).0, StatusCode::CONFLICT);
        let e = c.job_action(&other.id, "resume").await.unwrap_err();
        assert_eq!(code(&e).0, StatusCode::CONFLICT);
        // Filtered, paged listing.
        let cancelled = c.jobs(Some("cancelled"), 1, 10).await.unwrap();
        assert_eq!(
            (cancelled.total, cancelled.jobs[0].id.clone()),
            (1, other.id.clone())
        );
        let page = c.jobs(None, 2, 2).await.unwrap();
        assert_eq!((page.total, page.jobs.len()), (3, 1));
        // Delete: gone, and its image too.
        c.delete_job(&other.id).await.unwrap();
        assert_eq!(
            code(&c.job(&other.id).await.unwrap_err()).0,
            StatusCode::NOT_FOUND
        );
        assert_eq!(
            code(&c.image_exr(&other.id, false).await.unwrap_err()).0,
            StatusCode::NOT_FOUND
        );

        // A noise target ends a job early; so does a time limit.
        // Far more samples than the target needs, so the workers cannot finish them before the
        // monitor's estimate (every 100 ms) finds the target reached, however slow the machine.
        let mut ns = settings(24, 24, 1 << 15, 24);
        ns.noise_target = Some(0.2);
        let noisy = c.submit(bytes.clone(), "noise", &ns).await.unwrap();
        let mut ts = settings(24, 24, 1 << 20, 24);
        ts.time_limit_s = Some(0.5);
        let timed = c.submit(bytes.clone(), "time", &ts).await.unwrap();
        c.job_action(&low.id, "cancel").await.unwrap();
        c.job_action(&high.id, "cancel").await.unwrap();
        let workers: Vec<_> = (0..2)
            .map(|_| TestWorker::spawn(&server.url, None, None))
            .collect();
        let n = wait_final(&c, &noisy.id, Duration::from_secs(60)).await;
        let t = wait_final(&c, &timed.id, Duration::from_secs(60)).await;
        for w in workers {
            w.stop().await;
        }
        assert_eq!(n.state, JobState::Completed, "{store}: {n:?}");
        assert!(n.samples_done < n.samples_planned, "{store}: stopped early");
        assert!(n.relative_error.unwrap() <= 0.2, "{store}: {n:?}");
        assert!(
            n.message.as_deref().unwrap_or("").contains("noise target"),
            "{n:?}"
        );
        assert_eq!(t.state, JobState::Completed, "{store}: {t:?}");
        assert!(
            t.message.as_deref().unwrap_or("").contains("time limit"),
            "{t:?}"
        );
        // Per-tile progress in the single-job view.
        let view = c.job(&noisy.id).await.unwrap();
        let tiles = view.tiles.unwrap();
        assert_eq!(tiles.len(), 1);
        assert!(tiles[0].samples_per_pixel >= 2);
        server.stop().await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn two_servers_on_one_postgres_render_one_correct_image() {
    let Ok(base) = std::env::var("PATHFARM_TEST_POSTGRES_URL") else {
        eprintln!("SKIPPED: two servers on PostgreSQL (PATHFARM_TEST_POSTGRES_URL is not set)");
        return;
    };
    let url = fresh_postgres(&base).await;
    let s1 = TestServer::start(config(&url)).await;
    let s2 = TestServer::start(config(&url)).await;
    let bytes = cornell();
    let s = settings(48, 40, 8, 16);
    let job = s1
        .client(None)
        .submit(bytes.clone(), "c", &s)
        .await
        .unwrap();
    let ws = vec![
        TestWorker::spawn(&s1.url, None, Some(1)),
        TestWorker::spawn(&s2.url, None, Some(2)),
        TestWorker::spawn(&s2.url, None, None),
    ];
    let done = wait_final(&s2.client(None), &job.id, Duration::from_secs(120)).await;
    let mut per_worker = Vec::new();
    for w in ws {
        per_worker.push(w.stop().await.slices);
    }
    assert_completed(&done);
    assert!(
        per_worker.iter().filter(|&&n| n > 0).count() >= 2,
        "work was shared: {per_worker:?}"
    );
    let expected = exr(&local_render(&bytes, &s));
    assert_eq!(
        s1.client(None).image_exr(&job.id, false).await.unwrap(),
        expected
    );
    assert_eq!(
        s2.client(None).image_exr(&job.id, false).await.unwrap(),
        expected
    );
    s1.stop().await;
    s2.stop().await;
}

/// Many uploads at once — on SQLite they are merged in shared transactions (group commit): each
/// slice is counted once however many copies race, a stale upload in the same batch is fenced
/// without failing its neighbours, and the final image is still the local render's.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn concurrent_uploads_merge_exactly_once() {
    let bytes = cornell();
    let scene = load(&bytes);
    for (store, url) in stores("group-commit").await {
        let server = TestServer::start(config(&url)).await;
        let client = server.client(None);
        let s = settings(32, 32, 1, 8); // 16 tiles, one pass of one sample
        let expected = exr(&local_render(&bytes, &s));
        let job = client
            .submit(bytes.clone(), "cornell.gltf", &s)
            .await
            .unwrap();
        let mut leases = Vec::new();
        for i in 0..16 {
            let w = register(&client, &format!("w{i}")).await;
            leases.push(client.lease(&w).await.unwrap().expect("a task"));
        }
        let mut uploads = tokio::task::JoinSet::new();
        for l in &leases {
            let body = slice_body(&scene, l, 0, 1);
            for copy in 0..3 {
                let (c, l, body) = (client.clone(), l.clone(), body.clone());
                uploads.spawn(async move {
                    (copy, c.upload_slice(l.task_id, &l.lease_token, body).await)
                });
            }
            // A stale token for the same task, racing the real ones.
            let (c, l, body) = (client.clone(), l.clone(), body.clone());
            uploads.spawn(async move { (9, c.upload_slice(l.task_id, "stale", body).await) });
        }
        let (mut merged, mut duplicates, mut fenced) = (0, 0, 0);
        while let Some(r) = uploads.join_next().await {
            match r.unwrap() {
                (9, Err(e)) => {
                    assert_eq!(code(&e), (StatusCode::CONFLICT, "stale_lease".into()));
                    fenced += 1;
                }
                (9, Ok(ack)) => panic!("{store}: a stale upload was accepted: {ack:?}"),
                (_, Ok(ack)) if ack.duplicate => duplicates += 1,
                (_, Ok(ack)) => {
                    assert!(ack.task_complete);
                    merged += 1;
                }
                (_, Err(e)) => panic!("{store}: upload failed: {e}"),
            }
        }
        assert_eq!((merged, duplicates, fenced), (16, 32, 16), "{store}");
        let done = wait_final(&client, &job.id, Duration::from_secs(30)).await;
        assert_completed(&done);
        assert_eq!(done.samples_done, 32 * 32);
        assert!(
            client.image_exr(&job.id, false).await.unwrap() == expected,
            "{store}"
        );
        server.stop().await;
    }
}

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

/// A pipelined worker leases its next task before its last task's final slice is merged: that
/// merge completes the last task but leaves the worker busy with the next (its current task and
/// job stay); the merge completing the task it is on makes it idle.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_task_completed_after_the_next_lease_leaves_the_worker_on_the_next() {
    let bytes = cornell();
    let scene = load(&bytes);
    for (store, url) in stores("lease-ahead").await {
        let server = TestServer::start(config(&url)).await;
        let c = server.client(None);
        let job = c
            .submit(bytes.clone(), "c.gltf", &settings(16, 16, 8, 16))
            .await
            .unwrap();
        let w = register(&c, "w").await;
        let first = c.lease(&w).await.unwrap().expect("work");
        let next = c.lease(&w).await.unwrap().expect("more work");
        let view = |c: &pathfarm_worker::client::ApiClient| {
            let c = c.clone();
            let w = w.clone();
            async move {
                let list = c.workers().await.unwrap();
                let v = list.workers.into_iter().find(|v| v.id == w).unwrap();
                (v.state, v.current_task, v.current_job)
            }
        };
        assert_eq!(
            view(&c).await,
            (WorkerState::Busy, Some(next.task_id), Some(job.id.clone())),
            "{store}"
        );
        let (b, e) = (first.sample_begin, first.sample_end);
        let ack = c
            .upload_slice(
                first.task_id,
                &first.lease_token,
                slice_body(&scene, &first, b, e),
            )
            .await
            .unwrap();
        assert!(ack.task_complete, "{store}");
        assert_eq!(
            view(&c).await,
            (WorkerState::Busy, Some(next.task_id), Some(job.id.clone())),
            "{store}: the completed task took the worker off its next one"
        );
        let (b, e) = (next.sample_begin, next.sample_end);
        c.upload_slice(
            next.task_id,
            &next.lease_token,
            slice_body(&scene, &next, b, e),
        )
        .await
        .unwrap();
        assert_eq!(view(&c).await, (WorkerState::Idle, None, None), "{store}");
        server.stop().await;
    }
}

/// Releasing is idempotent, as the contract says: a release repeated (a retry after a lost
/// answer), late (the task leased again since) or with a token that never held the task answers
/// 204 and changes nothing, so it never takes a task from the worker that holds it now.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_repeated_or_late_release_changes_nothing() {
    let bytes = cornell();
    let scene = load(&bytes);
    for (store, url) in stores("release-twice").await {
        let server = TestServer::start(config(&url)).await;
        let (first, second) = (server.client(None), server.client(None));
        let job = first
            .submit(bytes.clone(), "job", &settings(16, 16, 4, 16))
            .await
            .unwrap();
        let w1 = register(&first, "first").await;
        let w2 = register(&second, "second").await;
        let l1 = first.lease(&w1).await.unwrap().unwrap();
        first.release(l1.task_id, &l1.lease_token).await.unwrap();
        first.release(l1.task_id, &l1.lease_token).await.unwrap();
        let l2 = second.lease(&w2).await.unwrap().unwrap();
        assert_eq!(
            l2.task_id, l1.task_id,
            "{store}: the released task is queued again"
        );
        assert_ne!(l2.lease_token, l1.lease_token);
        // Late, and never valid: both leave the second worker's lease alone.
        first.release(l1.task_id, &l1.lease_token).await.unwrap();
        first.release(l1.task_id, "never-a-token").await.unwrap();
        let ack = second
            .upload_slice(
                l2.task_id,
                &l2.lease_token,
                slice_body(&scene, &l2, l2.sample_begin, l2.sample_end),
            )
            .await
            .unwrap();
        assert!(!ack.duplicate, "{store}");
        let view = first.job(&job.id).await.unwrap();
        assert_eq!(
            view.samples_done,
            u64::from(l2.sample_end - l2.sample_begin) * 16 * 16,
            "{store}"
        );
        // A release for the worker that holds it is still checked: not the first worker's.
        let l3 = second.lease(&w2).await.unwrap();
        if let Some(l3) = l3 {
            let e = first
                .release(l3.task_id, &l3.lease_token)
                .await
                .unwrap_err();
            assert_eq!(
                code(&e),
                (StatusCode::FORBIDDEN, "not_your_lease".to_string()),
                "{store}"
            );
        }
        server.stop().await;
    }
}

/// A worker upgraded before its server: slices go out as `application/octet-stream`, which a
/// server from before that change refuses with 415 before reading the body (as this one still
/// answers an unknown type); the worker then sends the same bytes as the slice's own type,
/// `application/x-pathfarm-slice`, and the upload goes through. The old server is stood in for by
/// its slice route alone, answering as it did.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_uploads_to_a_server_that_predates_octet_stream_slices() {
    use axum::http::{header, HeaderMap};
    use pathfarm_wire::api::{SLICE_CONTENT_TYPE, SLICE_CONTENT_TYPE_LEGACY};
    use std::sync::{Arc, Mutex};
    type Seen = Arc<Mutex<Vec<(String, Vec<u8>)>>>;
    let seen: Seen = Arc::default();
    let old_server = axum::Router::new().route(
        "/api/v1/tasks/{id}/slices",
        axum::routing::post(
            |axum::extract::State(seen): axum::extract::State<Seen>,
             headers: HeaderMap,
             body: axum::body::Bytes| async move {
                let ct = headers[header::CONTENT_TYPE].to_str().unwrap().to_string();
                seen.lock().unwrap().push((ct.clone(), body.to_vec()));
                if ct == SLICE_CONTENT_TYPE_LEGACY {
                    let ack = serde_json::json!({"duplicate": false, "task_samples_done": 4,
                        "task_complete": true, "keep_going": true});
                    (StatusCode::OK, ack.to_string())
                } else {
                    let error = serde_json::json!({"error": {"code": "unsupported_media_type",
                        "message": format!("expected Content-Type {SLICE_CONTENT_TYPE_LEGACY}, got {ct:?}")}});
                    (StatusCode::UNSUPPORTED_MEDIA_TYPE, error.to_string())
                }
            },
        ),
    );
    let old_server = old_server.with_state(seen.clone());
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    tokio::spawn(async move { axum::serve(listener, old_server).await });
    let client = pathfarm_worker::client::ApiClient::new(&url, None).unwrap();
    let body = b"PFSL and the rest of a slice".to_vec();
    let ack = client.upload_slice(7, "token", body.clone()).await.unwrap();
    assert!(ack.task_complete && !ack.duplicate, "{ack:?}");
    let seen = seen.lock().unwrap().clone();
    assert_eq!(
        seen,
        [
            (SLICE_CONTENT_TYPE.to_string(), body.clone()),
            (SLICE_CONTENT_TYPE_LEGACY.to_string(), body)
        ]
    );
}

/// A lease request with `wait_ms` is held while there is no work, and answered with a task as
/// soon as one may be leased: a job submitted, a paused job resumed, a task released, a lease
/// expired (the monitor's wake-up); without work it is answered 204 when its wait is over, and
/// at once when the server shuts down.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_long_polled_lease_waits_for_work_and_wakes_when_some_is_queued() {
    let bytes = cornell();
    for (store, url) in stores("long-poll").await {
        let mut cfg = config(&url);
        cfg.lease_duration = Duration::from_millis(500);
        cfg.monitor_interval = Duration::from_millis(50);
        let server = TestServer::start(cfg).await;
        let c = server.client(None);
        let a = register(&c, "a").await;
        let b = register(&c, "b").await;
        let long = Duration::from_secs(20);

        // Nothing queued: 204 once the wait is over, not before.
        let t0 = std::time::Instant::now();
        let none = c
            .lease_waiting(&a, Duration::from_millis(300))
            .await
            .unwrap();
        assert!(none.is_none(), "{store}");
        assert!(t0.elapsed() >= Duration::from_millis(300), "{store}");

        // A submission wakes a waiting request with the job's first task.
        let waiting = {
            let (c, a) = (c.clone(), a.clone());
            tokio::spawn(async move {
                let lease = c.lease_waiting(&a, long).await;
                (lease, std::time::Instant::now())
            })
        };
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert!(
            !waiting.is_finished(),
            "{store}: answered before there was work"
        );
        let s = settings(16, 16, 1, 16); // one tile, one sample: one task
        let submitted_at = std::time::Instant::now();
        let job = c.submit(bytes.clone(), "c.gltf", &s).await.unwrap();
        let (lease, answered_at) = waiting.await.unwrap();
        let l0 = lease.unwrap().expect("the submitted job's task");
        assert!(answered_at >= submitted_at, "{store}");
        assert_eq!((l0.job_id.as_str(), l0.sample_begin), (job.id.as_str(), 0));

        // Its one task is leased: a lease released wakes the waiter with it.
        let waiting = {
            let (c, b) = (c.clone(), b.clone());
            tokio::spawn(async move { c.lease_waiting(&b, long).await })
        };
        tokio::time::sleep(Duration::from_millis(200)).await;
        assert!(
            !waiting.is_finished(),
            "{store}: a leased task leased again"
        );
        c.release(l0.task_id, &l0.lease_token).await.unwrap();
        let again = waiting.await.unwrap().unwrap().expect("the released task");
        assert_eq!(again.task_id, l0.task_id, "{store}");

        // b goes silent: its lease expires, and the monitor wakes a's waiting request with it.
        let waiting = {
            let (c, a) = (c.clone(), a.clone());
            tokio::spawn(async move { c.lease_waiting(&a, long).await })
        };
        let expired = waiting.await.unwrap().unwrap().expect("the expired task");
        assert_eq!(expired.task_id, l0.task_id, "{store}");

        // Paused with its tasks queued: no work until it is resumed.
        c.release(expired.task_id, &expired.lease_token)
            .await
            .unwrap();
        c.job_action(&job.id, "pause").await.unwrap();
        let waiting = {
            let (c, b) = (c.clone(), b.clone());
            tokio::spawn(async move { c.lease_waiting(&b, long).await })
        };
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert!(!waiting.is_finished(), "{store}: leased from a paused job");
        c.job_action(&job.id, "resume").await.unwrap();
        let resumed = waiting
            .await
            .unwrap()
            .unwrap()
            .expect("a task of the resumed job");
        assert_eq!(resumed.job_id, job.id, "{store}");
        c.release(resumed.task_id, &resumed.lease_token)
            .await
            .unwrap();

        // More than the contract's maximum: 400 naming it.
        let err = c
            .lease_waiting(&a, Duration::from_millis(60_001))
            .await
            .unwrap_err();
        assert_eq!(code(&err), (StatusCode::BAD_REQUEST, "bad_query".into()));

        // Shutdown answers a waiting request at once instead of waiting it out.
        c.job_action(&job.id, "cancel").await.unwrap();
        let waiting = {
            let (c, a) = (c.clone(), a.clone());
            tokio::spawn(async move { c.lease_waiting(&a, long).await })
        };
        tokio::time::sleep(Duration::from_millis(200)).await;
        let t0 = std::time::Instant::now();
        server.stop().await;
        let answer = waiting.await.unwrap();
        assert!(
            matches!(answer, Ok(None)),
            "{store}: a waiting lease at shutdown: {answer:?}"
        );
        assert!(
            t0.elapsed() < long,
            "{store}: shutdown waited out the long poll"
        );
    }
}
