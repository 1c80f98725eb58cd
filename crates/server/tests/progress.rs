//! What the dashboard reads besides the image: the convergence history recorded as a job renders,
//! and the per-pixel sample-count and noise heat maps, on both stores.

mod common;

use common::*;
use pathfarm_server::heatmap::{viridis, NOISE_SCALE};
use pathfarm_wire::api::{JobCreated, JobState, PreviewView};
use pathfarm_worker::client::{ApiClient, ClientError};
use std::time::Duration;

fn decode(png: &[u8]) -> image::RgbImage {
    image::load_from_memory_with_format(png, image::ImageFormat::Png)
        .expect("a PNG")
        .to_rgb8()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn convergence_history_and_heat_maps() {
    let scene = cornell();
    for (store, url) in stores("progress").await {
        let server = TestServer::start(config(&url)).await;
        let client = server.client(None);
        let s = settings(48, 32, 40, 16);
        let job = client
            .submit(scene.clone(), "cornell.gltf", &s)
            .await
            .unwrap();
        let worker = TestWorker::spawn(&server.url, None, Some(1));
        let done = wait_final(&client, &job.id, Duration::from_secs(120)).await;
        worker.stop().await;
        assert_completed(&done);

        // The monitor records the last image's point shortly after the last merge.
        let mut history = client.convergence(&job.id).await.unwrap();
        for _ in 0..100 {
            if history.points.last().map(|p| p.samples_done) == Some(done.samples_planned) {
                break;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
            history = client.convergence(&job.id).await.unwrap();
        }
        let points = &history.points;
        assert_eq!(history.job_id, job.id);
        assert!(!points.is_empty(), "{store}: no convergence points");
        assert_eq!(
            points.last().unwrap().samples_done,
            done.samples_planned,
            "{store}: the last point is the final image: {points:?}"
        );
        for w in points.windows(2) {
            assert!(w[0].elapsed_s < w[1].elapsed_s, "{store}: {points:?}");
            assert!(
                w[0].samples_done <= w[1].samples_done,
                "{store}: {points:?}"
            );
        }
        assert!(points
            .iter()
            .all(|p| p.samples_per_second.is_finite() && p.samples_per_second >= 0.0));
        assert!(
            points.iter().any(|p| p.samples_per_second > 0.0),
            "{store}: {points:?}"
        );
        let last_err = points
            .last()
            .unwrap()
            .relative_error
            .expect("final error estimate");
        assert!(last_err > 0.0 && last_err < 1.0, "{store}: {last_err}");
        // With more samples the estimate falls (roughly as 1/√n): the first estimate, made with
        // fewer samples, is larger than the last.
        if let Some(first) = points.iter().find_map(|p| p.relative_error) {
            if points.iter().filter(|p| p.relative_error.is_some()).count() > 1 {
                assert!(first > last_err, "{store}: {points:?}");
            }
        }

        // Sample counts: every pixel has the full count at the end, so the scale is 0…spp and
        // every pixel is the top colour.
        let (png, scale) = client
            .preview_view(&job.id, PreviewView::Samples)
            .await
            .unwrap();
        assert_eq!(scale, Some((0.0, s.spp as f64)), "{store}");
        let img = decode(&png);
        assert_eq!((img.width(), img.height()), (s.width, s.height));
        assert!(img.pixels().all(|p| p.0 == viridis(1.0)), "{store}");

        // Noise: the fixed log scale, and the map varies over the image (the light and the dark
        // corners are not equally noisy).
        let (png, scale) = client
            .preview_view(&job.id, PreviewView::Noise)
            .await
            .unwrap();
        assert_eq!(scale, Some(NOISE_SCALE), "{store}");
        let img = decode(&png);
        assert_eq!((img.width(), img.height()), (s.width, s.height));
        let first = img.get_pixel(0, 0).0;
        assert!(
            img.pixels().any(|p| p.0 != first),
            "{store}: a flat noise map"
        );

        // The plain image has no scale headers.
        let (png, scale) = client
            .preview_view(&job.id, PreviewView::Image)
            .await
            .unwrap();
        assert_eq!(scale, None);
        assert_eq!(png, client.preview_png(&job.id, 0.0).await.unwrap());

        // Conditional requests: the current version's ETag gets a 304 without a body.
        let url = format!("{}/api/v1/jobs/{}/preview.png", server.url, job.id);
        let http = reqwest::Client::new();
        let first = http.get(&url).send().await.unwrap();
        let tag = first.headers()["etag"].to_str().unwrap().to_string();
        let again = http
            .get(&url)
            .header("If-None-Match", &tag)
            .send()
            .await
            .unwrap();
        assert_eq!(again.status().as_u16(), 304, "{store}");
        assert_eq!(again.headers()["etag"].to_str().unwrap(), tag);
        assert!(again.bytes().await.unwrap().is_empty());
        let other = http
            .get(format!("{url}?view=noise"))
            .header("If-None-Match", "\"v0\"")
            .send()
            .await
            .unwrap();
        assert_eq!(
            other.status().as_u16(),
            200,
            "{store}: an old version is sent again"
        );
        // Each representation has its own tag: the image view's current tag is no match for
        // another view, another exposure, the EXR, or the same PNG sent as bytes.
        let exr_url = format!("{}/api/v1/jobs/{}/image.exr", server.url, job.id);
        let mut tags = vec![tag.clone()];
        for (url, accept) in [
            (format!("{url}?view=noise"), None),
            (format!("{url}?exposure=1"), None),
            (exr_url.clone(), None),
            (format!("{exr_url}?extra=true"), None),
            (url.clone(), Some("application/octet-stream")),
        ] {
            let mut request = http.get(&url).header("If-None-Match", &tag);
            if let Some(accept) = accept {
                request = request.header("Accept", accept);
            }
            let answer = request.send().await.unwrap();
            assert_eq!(answer.status().as_u16(), 200, "{store}: {url} {accept:?}");
            let own = answer.headers()["etag"].to_str().unwrap().to_string();
            assert!(
                !tags.contains(&own),
                "{store}: {url} {accept:?} reuses {own}"
            );
            tags.push(own.clone());
            // And its own tag gets a 304.
            let mut request = http.get(&url).header("If-None-Match", &own);
            if let Some(accept) = accept {
                request = request.header("Accept", accept);
            }
            let again = request.send().await.unwrap();
            assert_eq!(again.status().as_u16(), 304, "{store}: {url} {accept:?}");
        }
        // A client that takes only bytes gets the same bytes as application/octet-stream.
        let as_png = http.get(&url).send().await.unwrap();
        assert_eq!(as_png.headers()["content-type"], "image/png");
        let png = as_png.bytes().await.unwrap();
        let as_bytes = http
            .get(&url)
            .header("Accept", "application/octet-stream")
            .send()
            .await
            .unwrap();
        assert_eq!(
            as_bytes.headers()["content-type"],
            "application/octet-stream",
            "{store}"
        );
        assert_eq!(as_bytes.headers()["vary"], "accept", "{store}");
        assert_eq!(as_bytes.bytes().await.unwrap(), png, "{store}");

        // Unknown job and unknown view.
        match client.convergence("nope").await {
            Err(ClientError::Api { status, code, .. }) => {
                assert_eq!(status.as_u16(), 404);
                assert_eq!(code, "not_found");
            }
            other => panic!("{store}: expected 404, got {other:?}"),
        }
        let resp = reqwest::get(format!(
            "{}/api/v1/jobs/{}/preview.png?view=sparkles",
            server.url, job.id
        ))
        .await
        .unwrap();
        assert_eq!(resp.status().as_u16(), 400);

        // Deleting the job deletes its history.
        client.delete_job(&job.id).await.unwrap();
        assert!(client.convergence(&job.id).await.is_err());
        server.stop().await;
    }
}

/// A client that waits for the end reads the final image's error in the same answer that says the
/// job ended, even when the monitor (which keeps estimates current while a job runs) has not run
/// since the last merge: here it effectively never runs.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_finished_job_reports_its_final_error_at_once() {
    let scene = cornell();
    for (store, url) in stores("final_error").await {
        let mut cfg = config(&url);
        cfg.monitor_interval = Duration::from_secs(3600);
        let server = TestServer::start(cfg).await;
        let client = server.client(None);
        let s = settings(32, 24, 8, 16);
        let job = client
            .submit(scene.clone(), "cornell.gltf", &s)
            .await
            .unwrap();
        let worker = TestWorker::spawn(&server.url, None, Some(2));
        let done = wait_final(&client, &job.id, Duration::from_secs(120)).await;
        worker.stop().await;
        assert_completed(&done);
        let want = local_render(&scene, &s)
            .relative_error()
            .expect("an estimate at 8 spp");
        // The local render's estimate (the merged image is bit-identical to it; the JSON number
        // may differ in the last digit: serde_json parses floats to within an ulp).
        let got = done
            .relative_error
            .expect("the final error in the final answer");
        assert!(
            (got - want).abs() <= want * 1e-12,
            "{store}: {got} against the local render's {want}"
        );
        // Estimated once: the history holds the final point.
        let history = client.convergence(&job.id).await.unwrap();
        let last = history.points.last().expect("a point");
        assert_eq!(last.samples_done, done.samples_planned, "{store}");
        let last_err = last.relative_error.expect("the last point's error");
        assert!(
            (last_err - want).abs() <= want * 1e-12,
            "{store}: {last_err}"
        );
        server.stop().await;
    }
}

/// A server whose monitor does not run during the test (so only the test records estimates), its
/// client, and a small Cornell box job on it.
async fn server_without_monitor(url: &str) -> (TestServer, ApiClient, JobCreated) {
    let mut cfg = config(url);
    cfg.monitor_interval = Duration::from_secs(3600);
    let server = TestServer::start(cfg).await;
    let client = server.client(None);
    let job = client
        .submit(cornell(), "cornell.gltf", &settings(16, 16, 4, 16))
        .await
        .unwrap();
    (server, client, job)
}

/// Estimates without a value (too few samples yet) and with one, alternating: each is stored as
/// given, through the sentinel the store binds instead of a NULL. (sqlx's `Any` driver sends a
/// NULL `f64` to PostgreSQL as a float4; the monitor's later estimates then failed on that
/// connection with "incorrect binary data format in bind parameter 1", which PostgreSQL's log
/// showed during the progress tests and which once reached a client as a 503 from `GET
/// /jobs/{id}`. This test checks the round trip; it did not reproduce the driver's failure alone.)
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn estimates_with_and_without_a_value_are_stored_on_every_connection() {
    use pathfarm_server::store::Estimate;
    for (store, url) in stores("estimates").await {
        let (server, _, job) = server_without_monitor(&url).await;
        for version in 0..40i64 {
            let value = (version % 3 != 0).then_some(0.5 / (version + 1) as f64);
            let e = Estimate {
                version,
                relative_error: value,
                samples: version as u64,
                last: false,
            };
            server
                .state
                .store
                .record_estimate(&job.id, &e)
                .await
                .unwrap_or_else(|err| panic!("{store}: estimate {version}: {err}"));
            let row = server.state.store.job(&job.id).await.unwrap();
            assert_eq!(row.rel_error_version, version, "{store}");
            assert_eq!(row.rel_error, value, "{store}: version {version}");
        }
        server.stop().await;
    }
}

/// Sets the job's start and end on the store's clock (no end: still running).
async fn set_times(server: &TestServer, job: &str, started_ms: i64, finished_ms: Option<i64>) {
    let q = match finished_ms {
        Some(f) => sqlx::query("UPDATE jobs SET started_ms = $1, finished_ms = $2 WHERE id = $3")
            .bind(started_ms)
            .bind(f),
        None => sqlx::query("UPDATE jobs SET started_ms = $1, finished_ms = NULL WHERE id = $2")
            .bind(started_ms),
    };
    q.bind(job)
        .execute(server.state.store.pool())
        .await
        .unwrap();
}

/// Records an estimate of the job's image at `version` (its error 1 / (version + 1)).
async fn record(server: &TestServer, job: &str, version: i64, samples: u64, last: bool) {
    let e = pathfarm_server::store::Estimate {
        version,
        relative_error: Some(1.0 / (version + 1) as f64),
        samples,
        last,
    };
    server.state.store.record_estimate(job, &e).await.unwrap();
}

/// A job's last image can land in the same millisecond as the point recorded before it (its final
/// merges come close together, all the more as the tracer gets faster): the history must still end
/// with the final image. (Found by CI: the point before the last merge stayed the last one, and
/// the final image's point, at the same elapsed time, was dropped.)
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_last_image_ends_the_history_even_in_the_same_millisecond() {
    use pathfarm_server::store::now_ms;
    for (store, url) in stores("same_millisecond").await {
        let (server, client, job) = server_without_monitor(&url).await;
        // Started a second ago and finished half a second later: every estimate from now on is
        // at elapsed 500 ms.
        let now = now_ms();
        set_times(&server, &job.id, now - 1000, Some(now - 500)).await;
        record(&server, &job.id, 1, 700, false).await;
        record(&server, &job.id, 2, 1024, true).await;
        let points = client.convergence(&job.id).await.unwrap().points;
        assert_eq!(points.len(), 1, "{store}: {points:?}");
        assert_eq!(points[0].samples_done, 1024, "{store}: {points:?}");
        assert_eq!(points[0].elapsed_s, 0.5, "{store}: {points:?}");
        assert_eq!(points[0].relative_error, Some(1.0 / 3.0), "{store}");
        server.stop().await;
    }
}

/// On PostgreSQL an estimate can read the job still running and time its point at "now" while
/// the finishing merge, which stamped `finished_ms` a moment earlier, has not committed yet: the
/// final estimate, timed at `finished_ms`, is then *earlier* than the point before it. It must
/// still end the history (it replaces that point), not be dropped. (Found by CI on the frame
/// tests: a frame's history ended at 1008 of its 1152 samples.)
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_last_image_ends_the_history_even_when_timed_before_the_point_before_it() {
    use pathfarm_server::store::now_ms;
    for (store, url) in stores("last_before").await {
        let (server, client, job) = server_without_monitor(&url).await;
        let now = now_ms();
        // Running for a second: the point is at about 1 s.
        set_times(&server, &job.id, now - 1000, None).await;
        record(&server, &job.id, 1, 700, false).await;
        let before = client.convergence(&job.id).await.unwrap().points;
        assert_eq!(before.len(), 1, "{store}: {before:?}");
        assert!(before[0].elapsed_s >= 1.0, "{store}: {before:?}");
        // …and it had finished at 0.5 s.
        set_times(&server, &job.id, now - 1000, Some(now - 500)).await;
        record(&server, &job.id, 2, 1024, true).await;
        let points = client.convergence(&job.id).await.unwrap().points;
        assert_eq!(points.len(), 1, "{store}: {points:?}");
        assert_eq!(points[0].samples_done, 1024, "{store}: {points:?}");
        assert_eq!(points[0].elapsed_s, before[0].elapsed_s, "{store}");
        assert_eq!(points[0].relative_error, Some(1.0 / 3.0), "{store}");
        server.stop().await;
    }
}

/// Tiles merged before the server kept error sums (migration 0010 left them NULL) are summed
/// when the monitor starts, for the jobs that have not ended, to the sums a merge would have
/// written: the estimate is the same to the bit. A job that ended is left as it ended.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn tiles_merged_before_the_error_sums_are_summed_at_start() {
    let forget = "UPDATE tiles SET err_var = NULL, err_lum = NULL, err_unestimated = NULL \
                  WHERE job_id = $1";
    for (store, url) in stores("backfill").await {
        let (server, client, ended) = server_without_monitor(&url).await;
        let st = &server.state.store;
        let running = client
            .submit(cornell(), "cornell.gltf", &settings(32, 24, 1 << 16, 16))
            .await
            .unwrap();
        let worker = TestWorker::spawn(&server.url, None, Some(2));
        // Until the small job has ended and every pixel of the big one has two samples.
        let deadline = std::time::Instant::now() + Duration::from_secs(60);
        loop {
            let images = st.image_estimates(&running.id).await.unwrap();
            let over = client.job(&ended.id).await.unwrap().state.is_final();
            if over && images[0].relative_error.is_some() {
                break;
            }
            assert!(std::time::Instant::now() < deadline, "{store}: no estimate");
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        worker.stop().await;
        let before = st.image_estimates(&running.id).await.unwrap();
        assert_eq!(
            client.job(&running.id).await.unwrap().state,
            JobState::Running,
            "{store}"
        );
        for id in [&running.id, &ended.id] {
            sqlx::query(forget)
                .bind(id)
                .execute(st.pool())
                .await
                .unwrap();
        }
        assert_eq!(
            st.image_estimates(&running.id).await.unwrap()[0].relative_error,
            None
        );
        let summed = st.backfill_error_sums().await.unwrap();
        assert_eq!(summed, 4, "{store}: the running job's four tiles");
        assert_eq!(
            st.image_estimates(&running.id).await.unwrap(),
            before,
            "{store}"
        );
        let ended = st.image_estimates(&ended.id).await.unwrap();
        assert_eq!(
            ended[0].relative_error, None,
            "{store}: the ended job was summed"
        );
        server.stop().await;
    }
}
