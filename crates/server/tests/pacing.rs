//! Back-pressure (issue 32, item 10): every lease and upload acknowledgement carries the slice
//! length the server asks for, which follows the active workers and the store's measured write
//! capacity; `/metrics` shows the estimate. Real handlers through the router (`oneshot`) on the
//! real stores. (The arithmetic is tested in `pacing.rs`; the load it holds is measured by
//! `farm-bench pressure`, the test kit's.)

mod common;

use axum::http::StatusCode;
use common::*;
use http_body_util::BodyExt;
use pathfarm_server::{app, AppState};
use std::time::Duration;
use tower::ServiceExt;

#[tokio::test]
async fn leases_and_acks_carry_a_slice_length_that_follows_the_workers() {
    for (store, url) in stores("pacing").await {
        // The whole capacity: one request at a time never goes past it, so nothing is refused.
        let mut cfg = config(&url);
        cfg.target_write_load = Some(1.0);
        let state = AppState::open(cfg).await.unwrap();
        let s = serde_json::to_string(&settings(64, 64, 8, 8)).unwrap();
        submit_ok(&state, None, &cornell(), &s).await;
        let mut workers = Vec::new();
        for _ in 0..30 {
            workers.push(register_in_process(&state).await);
        }
        // Each worker leases a task and uploads it one sample at a time.
        let mut leases = Vec::new();
        for w in &workers {
            let l = lease_in_process(&state, w).await.expect("a task");
            let hint = l.slice_seconds.expect("a lease names the slice length");
            assert!(hint.is_finite() && hint >= 0.0, "{store}: {hint}");
            leases.push(l);
        }
        for (w, l) in workers.iter().zip(&leases) {
            for b in l.sample_begin..l.sample_end {
                let ack = upload_grey(&state, w, l, (b, b + 1)).await;
                assert!(ack.slice_seconds.is_some(), "{store}: an ack names it too");
            }
        }
        // The next write after a window closes redoes the estimate.
        tokio::time::sleep(pathfarm_server::pacing::WINDOW + Duration::from_millis(50)).await;
        let l = lease_in_process(&state, &workers[0]).await.expect("a task");
        let view = state.pacing.view();
        assert_eq!(view.active_workers, 30, "{store}: {view:?}");
        let capacity = view.capacity.expect("a busy window was measured");
        assert!(capacity > 0.0, "{store}: {view:?}");
        // 30 workers' writes at the measured capacity.
        let expected = 30.0 * (1.0 + view.leases_per_upload) / capacity;
        assert!(
            (view.slice_seconds - expected).abs() <= 1e-9 * expected,
            "{store}: {view:?}"
        );
        assert!(view.slice_seconds > 0.0, "{store}: {view:?}");
        // (Through JSON, which serde_json reads back to within an ulp.)
        let asked = l.slice_seconds.expect("the lease names it");
        assert!(
            (asked - view.slice_seconds).abs() <= 1e-12 * view.slice_seconds,
            "{store}: {asked} against {view:?}"
        );

        let (status, _, body) = call_raw(&state, request("GET", "/metrics", &[], "")).await;
        assert_eq!(status, StatusCode::OK);
        let text = String::from_utf8(body.to_vec()).unwrap();
        assert!(
            text.contains("\npathfarm_pacing_active_workers 30\n"),
            "{store}"
        );
        assert!(text.contains("\npathfarm_pacing_slice_seconds "), "{store}");
        state.store.close().await;
    }
}

/// A lease that finds too many writes under way is answered 429 `slow_down` with a
/// `Retry-After`, while uploads go on being merged.
#[tokio::test]
async fn leases_beyond_the_store_s_pace_are_told_to_come_back_later() {
    for (store, url) in stores("pacing-admission").await {
        // Passes of any size (1, 2 and 5 samples): 16 tiles, 48 tasks, more than the 41 leased
        // one after the other below.
        let mut c = config(&url);
        c.min_task_samples = 1;
        let state = AppState::open(c).await.unwrap();
        let s = serde_json::to_string(&settings(128, 128, 32, 8)).unwrap();
        submit_ok(&state, None, &cornell(), &s).await;
        let mut workers = Vec::new();
        for _ in 0..100 {
            workers.push(register_in_process(&state).await);
        }
        // A measured window: a task each for 40 workers (80 writes: busy for longer than a window
        // must be to measure the store, however fast its writes), then the window closes.
        for w in &workers[..40] {
            let l = lease_in_process(&state, w).await.expect("a task");
            upload_grey(&state, w, &l, (l.sample_begin, l.sample_end)).await;
        }
        tokio::time::sleep(pathfarm_server::pacing::WINDOW + Duration::from_millis(50)).await;
        let late = lease_in_process(&state, &workers[40])
            .await
            .expect("a task");
        assert!(late.slice_seconds.unwrap() > 0.0, "{store}: measured");
        // Every worker leases three times, all at once: more writes under way than a lease may
        // wait behind.
        let tries: Vec<_> = workers
            .iter()
            .cloned()
            .map(|(id, cred)| {
                let state = state.clone();
                tokio::spawn(async move {
                    let mut answers = Vec::new();
                    for _ in 0..3 {
                        let uri = format!("/api/v1/workers/{id}/lease");
                        let resp = app(state.clone())
                            .oneshot(request(
                                "POST",
                                &uri,
                                &[("pathfarm-worker-credential", cred.as_str())],
                                "",
                            ))
                            .await
                            .unwrap();
                        let status = resp.status();
                        let retry_after = resp
                            .headers()
                            .get("retry-after")
                            .map(|v| v.to_str().unwrap().parse::<u32>().unwrap());
                        let body = resp.into_body().collect().await.unwrap().to_bytes();
                        answers.push((status, retry_after, body));
                    }
                    answers
                })
            })
            .collect();
        let t0 = std::time::Instant::now();
        let (mut granted, mut refused) = (0, 0);
        for t in tries {
            for (status, retry_after, body) in t.await.unwrap() {
                if status.is_success() {
                    granted += 1;
                    continue;
                }
                assert_eq!(status, StatusCode::TOO_MANY_REQUESTS, "{store}");
                let err: serde_json::Value = serde_json::from_slice(&body).unwrap();
                assert_eq!(err["error"]["code"], "slow_down", "{store}: {err}");
                let after = retry_after.expect("Retry-After");
                assert!((1..=60).contains(&after), "{store}: {after}");
                refused += 1;
            }
        }
        assert!(
            granted > 0 && refused > 0,
            "{store}: {granted} granted, {refused} refused in {:?}; {:?}",
            t0.elapsed(),
            state.pacing.view()
        );
        assert_eq!(state.pacing.view().leases_refused, refused, "{store}");
        // Uploads are never refused.
        upload_grey(
            &state,
            &workers[40],
            &late,
            (late.sample_begin, late.sample_end),
        )
        .await;
        state.store.close().await;
    }
}
