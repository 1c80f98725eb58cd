//! The cache of job images holds no more than its byte budget however many jobs are viewed, an
//! image it let go is built again bit for bit, and the encodings are the tracer's encodings of
//! the job's exact image, as before the cache had a budget (and before images were developed tile
//! by tile). Real handlers through the router (`oneshot`) on the real stores.

mod common;

use axum::body::Bytes;
use axum::http::StatusCode;
use common::*;
use pathfarm_server::heatmap;
use pathfarm_server::job_image::{cost, BYTES_PER_PIXEL};
use pathfarm_server::AppState;
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};
use pathfarm_tracer::output::{encode_png, encode_rgb8_png};
use pathfarm_tracer::{render_tile, Tile};
use pathfarm_wire::api::Lease;
use pathfarm_wire::Slice;
use serde_json::Value;

const JOBS: usize = 6;
const SIDE: u32 = 32;

/// Room for one build and the pixels of three images besides: with their encodings, and the
/// room each encoding takes while it is made, two or three images stay.
fn budget() -> usize {
    cost::build(SIDE, SIDE, SIDE) + 3 * (SIDE * SIDE) as usize * BYTES_PER_PIXEL
}

/// Submits `JOBS` jobs of one tile each (different seeds, so different images) and renders every
/// task of them by hand.
async fn render_jobs(
    state: &AppState,
    scene: &[u8],
) -> Vec<(String, pathfarm_wire::api::JobSettings)> {
    let mut jobs = Vec::new();
    for seed in 0..JOBS as u64 {
        let mut s = settings(SIDE, SIDE, 2, SIDE);
        s.seed = seed;
        let (ct, body) = multipart(scene, &serde_json::to_string(&s).unwrap());
        let (status, job): (_, Value) = call(
            state,
            request("POST", "/api/v1/jobs", &[("content-type", &ct)], body),
        )
        .await;
        assert_eq!(status, StatusCode::CREATED, "{job}");
        jobs.push((job["id"].as_str().unwrap().to_string(), s));
    }
    let (worker_id, cred) = register_in_process(state).await;
    let lease_uri = format!("/api/v1/workers/{worker_id}/lease");
    let cred = cred.as_str();
    let loaded = gltf::load(scene, &NoExternalResources, &LoadOptions::default()).unwrap();
    loop {
        let (status, lease): (_, Option<Lease>) = call(
            state,
            request(
                "POST",
                &lease_uri,
                &[("pathfarm-worker-credential", cred)],
                "",
            ),
        )
        .await;
        let Some(l) = lease else {
            assert_eq!(status, StatusCode::NO_CONTENT);
            break;
        };
        let tile = Tile {
            x0: l.tile.x0,
            y0: l.tile.y0,
            width: l.tile.width,
            height: l.tile.height,
        };
        let range = l.sample_begin..l.sample_end;
        let slice = Slice {
            sample_begin: l.sample_begin,
            sample_end: l.sample_end,
            acc: render_tile(&loaded, &l.settings.render_settings(), tile, range),
        };
        upload_in_process(state, cred, &l, &slice).await;
    }
    jobs
}

/// The job's images as the API serves them: EXR, PNG and the samples heat map.
async fn images(state: &AppState, id: &str) -> [Bytes; 3] {
    let mut out = Vec::new();
    for (path, ct) in [
        ("image.exr", "image/x-exr"),
        ("preview.png", "image/png"),
        ("preview.png?view=samples", "image/png"),
    ] {
        let uri = format!("/api/v1/jobs/{id}/{path}");
        let (status, got_ct, bytes) = call_raw(state, request("GET", &uri, &[], "")).await;
        assert_eq!(
            status,
            StatusCode::OK,
            "{uri}: {}",
            String::from_utf8_lossy(&bytes)
        );
        assert_eq!(got_ct.as_deref(), Some(ct), "{uri}");
        let cache = &state.images;
        assert!(
            cache.resident_bytes() <= cache.budget() && cache.reserved_bytes() <= cache.budget(),
            "after {uri}: {} bytes resident, {} reserved, over the budget of {}",
            cache.resident_bytes(),
            cache.reserved_bytes(),
            cache.budget()
        );
        out.push(bytes);
    }
    out.try_into().unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_image_cache_keeps_to_its_budget_and_rebuilds_what_it_let_go() {
    let scene = cornell();
    for (store, url) in stores("image-cache").await {
        let mut cfg = config(&url);
        cfg.image_cache_bytes = budget();
        let state = AppState::open(cfg).await.unwrap();
        let jobs = render_jobs(&state, &scene).await;

        let mut served = Vec::new();
        let mut kept_if_unbounded = 0;
        for (id, s) in &jobs {
            let got = images(&state, id).await;
            // The tracer's encodings of the job's exact image (a local render's).
            let local = local_render(&scene, s);
            let heat = heatmap::samples(&local);
            assert!(got[0] == exr(&local), "{store}: {id}: EXR");
            assert!(
                got[1] == encode_png(&local, 0.0).unwrap(),
                "{store}: {id}: PNG"
            );
            assert!(
                got[2] == encode_rgb8_png(SIDE, SIDE, &heat.rgb).unwrap(),
                "{store}: {id}: samples heat map"
            );
            let img = state
                .images
                .peek(id)
                .expect("the image just viewed is kept");
            kept_if_unbounded += img.pixel_bytes();
            served.push(got);
        }
        let besides_a_build = budget() - cost::build(SIDE, SIDE, SIDE);
        assert!(
            kept_if_unbounded > besides_a_build,
            "{store}: the test views more than the budget keeps ({kept_if_unbounded} bytes)"
        );
        let kept = state.images.len();
        assert!((1..JOBS).contains(&kept), "{store}: {kept} images kept");
        let (first, _) = &jobs[0];
        assert!(
            state.images.peek(first).is_none(),
            "{store}: the least recently used went"
        );

        // Viewed again: built again, the same bytes.
        let again = images(&state, first).await;
        assert!(again == served[0], "{store}: the rebuilt images differ");
        assert!(state.images.peek(first).is_some(), "{store}");
        state.store.close().await;

        // A budget smaller than one image: every image served, none kept.
        let mut cfg = config(&url);
        cfg.image_cache_bytes = 1 << 10;
        let state = AppState::open(cfg).await.unwrap();
        for ((id, _), expected) in jobs.iter().zip(&served) {
            assert!(&images(&state, id).await == expected, "{store}: {id}");
            assert_eq!(state.images.resident_bytes(), 0, "{store}");
            assert!(state.images.is_empty(), "{store}");
        }
        state.store.close().await;
    }
}
