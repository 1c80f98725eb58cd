//! Leases over their lifetime: pipelined leasing, repeated or late releases, and long polling.

use super::*;

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
