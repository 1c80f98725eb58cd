//! Slice uploads: each merged exactly once (retries, stale leases, concurrency, two servers on one
//! store), and the fallback to the legacy slice type for a server that predates the generic one.

use super::*;

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
