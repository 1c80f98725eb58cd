//! Image work is bounded (issue 32, item 1): concurrent requests for a job's image share one
//! build, nothing is assembled before the job's first sample, and work that finds the server's
//! image budget taken is answered 503 `busy` with `Retry-After`. Real handlers through the router
//! (`oneshot`) on the real stores; the cache's counters say how many images were built.

mod common;

use axum::http::StatusCode;
use common::*;
use pathfarm_server::{monitor, AppState, ServerConfig};
use pathfarm_tracer::output::{encode_exr, encode_png, ExrChannels};
use pathfarm_tracer::Accumulation;
use serde_json::Value;
use std::time::Duration;

async fn submit(state: &AppState, width: u32, height: u32, spp: u32, tile: u32) -> String {
    let s = serde_json::to_string(&settings(width, height, spp, tile)).unwrap();
    submit_ok(state, None, &cornell(), &s).await
}

/// `GET` of one of the job's images: status, headers and body.
async fn get(
    state: &AppState,
    id: &str,
    path: &str,
) -> (StatusCode, axum::http::HeaderMap, Vec<u8>) {
    use http_body_util::BodyExt;
    use tower::ServiceExt;
    let req = request("GET", &format!("/api/v1/jobs/{id}/{path}"), &[], "");
    let resp = pathfarm_server::app(state.clone())
        .oneshot(req)
        .await
        .unwrap();
    let (status, headers) = (resp.status(), resp.headers().clone());
    let body = resp.into_body().collect().await.unwrap().to_bytes();
    (status, headers, body.to_vec())
}

/// A job without a merged slice is answered as an empty image (the tracer's encodings of an
/// empty accumulation) and estimated as having no error, without a build: nothing is read or
/// assembled, and an empty 4096² image keeps next to nothing. The first slice brings the first
/// build.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nothing_is_built_before_the_first_sample() {
    for (store, url) in stores("image-empty").await {
        let state = AppState::open(config(&url)).await.unwrap();
        let small = submit(&state, 48, 32, 1, 16).await;
        let empty = Accumulation::new(0, 0, 48, 32);
        let (status, _, png) = get(&state, &small, "preview.png?exposure=2").await;
        assert_eq!(status, StatusCode::OK, "{store}");
        assert!(
            png == encode_png(&empty, 2.0).unwrap(),
            "{store}: empty PNG"
        );
        let (_, _, exr) = get(&state, &small, "image.exr?extra=true").await;
        let all = ExrChannels {
            variance: true,
            samples: true,
        };
        assert!(
            exr == encode_exr(&empty, all).unwrap(),
            "{store}: empty EXR"
        );
        for view in ["samples", "noise"] {
            let (status, headers, _) =
                get(&state, &small, &format!("preview.png?view={view}")).await;
            assert_eq!(status, StatusCode::OK, "{store}: {view}");
            assert!(
                headers.contains_key("pathfarm-scale-max"),
                "{store}: {view}"
            );
        }

        let big = submit(&state, 4096, 4096, 1, 64).await;
        let (status, headers, _) = get(&state, &big, "preview.png").await;
        assert_eq!(status, StatusCode::OK, "{store}");
        assert_eq!(headers["etag"], "\"v0.png@0\"", "{store}");
        let img = state.images.peek(&big).expect("the empty image is kept");
        assert!(img.is_empty() && img.pixel_bytes() == 0, "{store}");
        assert!(
            state.images.reserved_bytes() < 1 << 20,
            "{store}: {} bytes reserved for empty images",
            state.images.reserved_bytes()
        );
        // The monitor records both jobs' (empty) estimates without building anything.
        monitor::step(&state).await.unwrap();
        for id in [&small, &big] {
            let job = state.store.job(id).await.unwrap();
            assert_eq!((job.rel_error_version, job.rel_error), (0, None), "{store}");
        }
        assert_eq!(
            state.images.builds(),
            0,
            "{store}: built before the first sample"
        );

        // The first slice: the monitor estimates it from the tiles' sums, building nothing; the
        // request builds the image once.
        let worker = register_in_process(&state).await;
        render_by_hand(&state, &worker, 1).await;
        monitor::step(&state).await.unwrap();
        let job = state.store.job(&small).await.unwrap();
        assert_eq!(job.rel_error_version, job.version, "{store}: not estimated");
        assert_eq!(
            state.images.builds(),
            0,
            "{store}: the monitor built an image"
        );
        let (status, headers, _) = get(&state, &small, "preview.png").await;
        assert_eq!(status, StatusCode::OK, "{store}");
        assert_eq!(headers["etag"], "\"v1.png@0\"", "{store}");
        monitor::step(&state).await.unwrap();
        assert_eq!(state.images.builds(), 1, "{store}");
        state.store.close().await;
    }
}

/// A configuration whose budget cannot keep the test's 256² image (20 bytes a pixel): every
/// image is built for the requests waiting for it and let go after.
fn unkept(url: &str, wait: Duration) -> ServerConfig {
    let mut cfg = config(url);
    cfg.image_cache_bytes = 1 << 20;
    cfg.image_wait = wait;
    cfg
}

/// Sixteen concurrent requests for the image of one job version get one build and one encoding
/// between them, the same bytes each; the image is too large to keep, so a later request builds
/// it again. The budget holds throughout.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn concurrent_requests_share_one_build() {
    for (store, url) in stores("image-single-flight").await {
        let state = AppState::open(unkept(&url, Duration::from_secs(20)))
            .await
            .unwrap();
        let id = submit(&state, 256, 256, 1, 64).await;
        let worker = register_in_process(&state).await;
        render_by_hand(&state, &worker, 16).await;
        // Hold the whole budget, so that the first request's build waits and the others find it
        // under way.
        let held = state.images.hold(usize::MAX).expect("the budget is free");
        let requests: Vec<_> = (0..16)
            .map(|_| {
                let (state, id) = (state.clone(), id.clone());
                tokio::spawn(async move { get(&state, &id, "preview.png").await })
            })
            .collect();
        // Every request waits on the one build before room is made: the first started it, the
        // other fifteen joined it (a fixed sleep here was too short on a loaded machine).
        let t0 = std::time::Instant::now();
        while state.images.joined_builds() < 15 {
            assert!(
                t0.elapsed() < Duration::from_secs(20),
                "{store}: requests did not join"
            );
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        assert_eq!(state.images.builds(), 0, "{store}: built without room");
        drop(held);
        let mut bodies = Vec::new();
        for r in requests {
            let (status, headers, body) = r.await.unwrap();
            assert_eq!(status, StatusCode::OK, "{store}");
            assert_eq!(headers["etag"], "\"v16.png@0\"", "{store}");
            bodies.push(body);
        }
        assert!(bodies.windows(2).all(|w| w[0] == w[1]), "{store}");
        assert_eq!(
            state.images.builds(),
            1,
            "{store}: one build for sixteen requests"
        );
        assert_eq!(state.images.encodings(), 1, "{store}");
        assert!(
            state.images.peek(&id).is_none(),
            "{store}: too large to keep"
        );
        let t0 = std::time::Instant::now();
        while state.images.reserved_bytes() > 0 {
            assert!(t0.elapsed() < Duration::from_secs(5), "{store}: room kept");
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        let (status, _, again) = get(&state, &id, "preview.png").await;
        assert_eq!(status, StatusCode::OK, "{store}");
        assert_eq!(again, bodies[0], "{store}");
        assert_eq!(
            state.images.builds(),
            2,
            "{store}: not kept, so built again"
        );
        state.store.close().await;
    }
}

/// Image work that finds no room within the wait is answered 503 `busy` with `Retry-After` and
/// the JSON error body, and served once the room is back; the job itself can still be read.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn work_over_the_budget_gets_503_with_retry_after() {
    for (store, url) in stores("image-busy").await {
        let state = AppState::open(unkept(&url, Duration::from_millis(300)))
            .await
            .unwrap();
        let id = submit(&state, 64, 64, 1, 64).await;
        let worker = register_in_process(&state).await;
        render_by_hand(&state, &worker, 1).await;
        let held = state.images.hold(usize::MAX).expect("the budget is free");
        for path in ["preview.png", "image.exr"] {
            let (status, headers, body) = get(&state, &id, path).await;
            assert_eq!(status, StatusCode::SERVICE_UNAVAILABLE, "{store}: {path}");
            assert_eq!(headers["retry-after"], "2", "{store}: {path}");
            assert_eq!(headers["content-type"], "application/json", "{store}");
            let err: Value = serde_json::from_slice(&body).unwrap();
            assert_eq!(err["error"]["code"], "busy", "{store}: {err}");
            assert!(
                err["error"]["message"].as_str().unwrap().contains("MiB"),
                "{store}: {err}"
            );
        }
        assert!(state.images.refused() >= 2, "{store}");
        let (status, job): (_, Value) = call(
            &state,
            request("GET", &format!("/api/v1/jobs/{id}"), &[], ""),
        )
        .await;
        assert_eq!(status, StatusCode::OK, "{store}: {job}");
        drop(held);
        let (status, _, _) = get(&state, &id, "preview.png").await;
        assert_eq!(status, StatusCode::OK, "{store}");
        state.store.close().await;
    }
}
