//! A job's states, priorities and stopping rules.

use super::*;

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
