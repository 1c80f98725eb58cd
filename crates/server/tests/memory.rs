//! What a request can make the server allocate: a job submission is checked against the tile and
//! task limits before anything is planned, and a slice upload reads at most the slice limit and
//! decodes no more pixels than the tile its lease may write to.
//!
//! This test binary's allocator records the largest single allocation, and refuses (aborting the
//! test process) any allocation over 256 MiB, which no request of these tests may need: the
//! unchecked plans of the review (tens of GB) end there instead of exhausting the machine.

mod common;

use axum::http::StatusCode;
use common::*;
use pathfarm_server::AppState;
use pathfarm_wire::api::Lease;
use serde_json::{json, Value};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

struct Recording;

static LARGEST: AtomicUsize = AtomicUsize::new(0);
const REFUSED_ABOVE: usize = 256 << 20;

unsafe impl GlobalAlloc for Recording {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if layout.size() > REFUSED_ABOVE {
            return std::ptr::null_mut();
        }
        LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        System.alloc(layout)
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if layout.size() > REFUSED_ABOVE {
            return std::ptr::null_mut();
        }
        LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        System.alloc_zeroed(layout)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > REFUSED_ABOVE {
            return std::ptr::null_mut();
        }
        LARGEST.fetch_max(new_size, Ordering::Relaxed);
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static ALLOCATOR: Recording = Recording;

/// The tests of this binary measure one process-wide number: one at a time.
static SERIAL: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

async fn send(
    state: &AppState,
    method: &str,
    uri: &str,
    headers: &[(&str, &str)],
    body: Vec<u8>,
) -> (StatusCode, Value) {
    call(state, request(method, uri, headers, body)).await
}

async fn submit(state: &AppState, scene: &[u8], settings: &str) -> (StatusCode, Value) {
    let (ct, body) = multipart(scene, settings);
    send(
        state,
        "POST",
        "/api/v1/jobs",
        &[("content-type", &ct)],
        body,
    )
    .await
}

fn sqlite(tag: &str) -> String {
    format!("sqlite://{}", temp_dir(tag).join("farm.db").display())
}

/// The review's submission (8192², tile 1, 2²⁰ spp: 67 million tiles, 1.4 billion tasks) and
/// one within the tile limit but far over the task limit are refused with 422 `limit` naming the
/// limit, without planning; a large job within both is planned and stored.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn plans_over_the_limits_are_refused_before_they_are_built() {
    let _serial = SERIAL.lock().await;
    let state = AppState::open(config(&sqlite("plan-limits")))
        .await
        .unwrap();
    let scene = cornell();
    for (settings, limit) in [
        (
            r#"{"width":8192,"height":8192,"spp":1048576,"tile_size":1}"#,
            "max_tiles",
        ),
        (
            r#"{"width":8192,"height":8192,"spp":1048576,"tile_size":64}"#,
            "max_tasks",
        ),
        (
            // One tile whose slices could not be uploaded under the slice limit.
            r#"{"width":4096,"height":4096,"spp":1,"tile_size":4096}"#,
            "max_slice_bytes",
        ),
    ] {
        LARGEST.store(0, Ordering::Relaxed);
        let (status, err) = submit(&state, &scene, settings).await;
        assert_eq!(
            (status, err["error"]["code"].as_str()),
            (StatusCode::UNPROCESSABLE_ENTITY, Some("limit")),
            "{settings}: {err}"
        );
        let message = err["error"]["message"].as_str().unwrap();
        assert!(message.contains(limit), "{message:?} names {limit}");
        let largest = LARGEST.load(Ordering::Relaxed);
        assert!(
            largest < 16 << 20,
            "{settings}: allocated {largest} bytes at once"
        );
    }
    // Within the limits: 4096 tiles × 2 passes (the one-sample preview, then the other 63: a
    // task of 16² pixels takes at least 256 samples a pixel after the preview).
    let (status, job) = submit(
        &state,
        &scene,
        r#"{"width":1024,"height":1024,"spp":64,"tile_size":16}"#,
    )
    .await;
    assert_eq!(status, StatusCode::CREATED, "{job}");
    assert_eq!(job["tasks"], 4096 * 2);
    // The largest tile whose largest slice fits the default slice limit is accepted.
    let (status, job) = submit(
        &state,
        &scene,
        r#"{"width":2048,"height":2048,"spp":1024,"tile_size":2048}"#,
    )
    .await;
    assert_eq!(status, StatusCode::CREATED, "{job}");
    assert_eq!(state.store.jobs(None, 0, 10).await.unwrap().1, 2);
    state.store.close().await;
}

/// A slice body over the slice limit is refused with 413 (JSON, naming the limit), a JSON body
/// over the JSON limit too; a slice that claims a tile other than its task's, or comes without
/// the task's lease, is refused before its pixels are decoded: the largest allocation stays
/// around the body's size, where decoding the claimed 40,000 pixels would take 2.9 MB. (A body
/// over the largest slice of its task's tile is refused before it is read: `connections/`.)
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slice_uploads_allocate_no_more_than_their_tile() {
    let _serial = SERIAL.lock().await;
    let mut cfg = config(&sqlite("slice-limits"));
    cfg.limits.max_slice_bytes = 4 << 20;
    let state = AppState::open(cfg).await.unwrap();
    let (status, job) = submit(&state, &cornell(), r#"{"width":64,"height":64,"spp":2}"#).await;
    assert_eq!(status, StatusCode::CREATED, "{job}");
    let (status, reg) = send(
        &state,
        "POST",
        "/api/v1/workers",
        &[("content-type", "application/json")],
        json!({"name": "w", "threads": 1, "version": "t", "host": "h"})
            .to_string()
            .into_bytes(),
    )
    .await;
    assert_eq!(status, StatusCode::CREATED);
    let worker = reg["worker_id"].as_str().unwrap().to_string();
    let cred = reg["credential"].as_str().unwrap().to_string();
    let uri = format!("/api/v1/workers/{worker}/lease");
    let (status, lease): (_, Lease) = call(
        &state,
        request("POST", &uri, &[("pathfarm-worker-credential", &cred)], ""),
    )
    .await;
    assert_eq!(status, StatusCode::OK);
    let uri = format!("/api/v1/tasks/{}/slices", lease.task_id);
    let token = lease.lease_token.as_str();

    // Over the slice limit: 413, and the message says which limit.
    let (status, err) = send(
        &state,
        "POST",
        &uri,
        &slice_headers(token, &cred),
        vec![0; (4 << 20) + 1],
    )
    .await;
    assert_eq!(
        (status, err["error"]["code"].as_str()),
        (StatusCode::PAYLOAD_TOO_LARGE, Some("too_large")),
        "{err}"
    );
    assert!(err["error"]["message"]
        .as_str()
        .unwrap()
        .contains("4194304"));
    // A JSON endpoint reads far less than a slice.
    let (status, err) = send(
        &state,
        "POST",
        "/api/v1/workers",
        &[("content-type", "application/json")],
        vec![b' '; 1 << 20],
    )
    .await;
    assert_eq!(status, StatusCode::PAYLOAD_TOO_LARGE, "{err}");

    // A well-formed body (valid checksum) claiming 200x200 pixels, all of them there: within
    // the largest slice of the task's 64x64 tile, so it is read, but decoded it would take 72
    // bytes a pixel.
    let pixels = 200 * 200;
    let mut body = Vec::with_capacity(4 << 20);
    body.extend_from_slice(b"PFSL");
    body.extend_from_slice(&1u16.to_le_bytes());
    body.extend_from_slice(&0u16.to_le_bytes());
    for v in [0u32, 0, 200, 200, 0, 1] {
        body.extend_from_slice(&v.to_le_bytes());
    }
    body.extend_from_slice(&[0, 0, 0]); // rays, invalid, recorded (invalid stays honest below)
    body.extend(std::iter::repeat_n(0u8, pixels * 5));
    let sum = fnv1a64(&body);
    body.extend_from_slice(&sum.to_le_bytes());
    assert!(body.len() <= 4 << 20);
    for (token, status, code) in [
        (token, StatusCode::UNPROCESSABLE_ENTITY, "slice_shape"),
        ("not-the-lease", StatusCode::CONFLICT, "stale_lease"),
    ] {
        LARGEST.store(0, Ordering::Relaxed);
        let (s, err) = send(
            &state,
            "POST",
            &uri,
            &slice_headers(token, &cred),
            body.clone(),
        )
        .await;
        let largest = LARGEST.load(Ordering::Relaxed);
        assert_eq!(
            (s, err["error"]["code"].as_str()),
            (status, Some(code)),
            "{err}"
        );
        assert!(
            largest <= 2 * body.len(),
            "{code}: allocated {largest} bytes at once for a body of {}",
            body.len()
        );
    }
    // A body claiming far more pixels than it carries: refused, nothing allocated for them.
    let mut short = body[..8].to_vec();
    for v in [0u32, 0, 8192, 8192, 0, 1] {
        short.extend_from_slice(&v.to_le_bytes());
    }
    short.extend_from_slice(&[0; 100]);
    let sum = fnv1a64(&short);
    short.extend_from_slice(&sum.to_le_bytes());
    LARGEST.store(0, Ordering::Relaxed);
    let (s, err) = send(&state, "POST", &uri, &slice_headers(token, &cred), short).await;
    assert_eq!(s, StatusCode::UNPROCESSABLE_ENTITY, "{err}");
    assert!(LARGEST.load(Ordering::Relaxed) < 1 << 20);
    state.store.close().await;
}

fn slice_headers<'a>(token: &'a str, cred: &'a str) -> [(&'a str, &'a str); 3] {
    [
        ("content-type", "application/x-pathfarm-slice"),
        ("pathfarm-lease-token", token),
        ("pathfarm-worker-credential", cred),
    ]
}

fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}
