//! Names that clients and workers give (issue 32's smaller items): limits counted in characters,
//! as the contract's `maxLength` counts them; control characters refused, since names reach
//! terminals and log lines; a scene's file name, used as the job's name when the settings give
//! none, cleaned to the same limits; and the bearer scheme matched without regard to case.
//! Real handlers through the router (`oneshot`) on the real stores.

mod common;

use axum::http::StatusCode;
use common::*;
use pathfarm_server::AppState;
use pathfarm_wire::api::{JobCreated, JobView};
use serde_json::{json, Value};

/// A submission whose scene part is named `file_name` (as raw header bytes would carry it).
fn submission(file_name: &str, settings: &str) -> (String, Vec<u8>) {
    let (ct, body) = multipart(&cornell(), settings);
    let named = String::from_utf8_lossy(&body).replacen(
        "filename=\"s.gltf\"",
        &format!("filename=\"{file_name}\""),
        1,
    );
    (ct, named.into_bytes())
}

async fn submit(state: &AppState, file_name: &str, settings: Value) -> (StatusCode, Value) {
    let (ct, body) = submission(file_name, &settings.to_string());
    call(
        state,
        request("POST", "/api/v1/jobs", &[("content-type", &ct)], body),
    )
    .await
}

async fn job_name(state: &AppState, created: Value) -> String {
    let created: JobCreated = serde_json::from_value(created).expect("a job created");
    let uri = format!("/api/v1/jobs/{}", created.id);
    let (status, job): (StatusCode, JobView) = call(state, request("GET", &uri, &[], "")).await;
    assert_eq!(status, StatusCode::OK);
    job.name
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn job_names_count_characters_and_refuse_control_characters() {
    for (store, url) in stores("names-jobs").await {
        let state = AppState::open(config(&url)).await.expect("the store opens");
        let base = json!({"width": 8, "height": 8, "spp": 1});
        let with_name = |name: &str| {
            let mut s = base.clone();
            s["name"] = json!(name);
            s
        };
        // 256 two-byte characters are 512 bytes: within the limit of 256 characters.
        let long = "é".repeat(256);
        let (status, created) = submit(&state, "s.gltf", with_name(&long)).await;
        assert_eq!(status, StatusCode::CREATED, "{store}: {created}");
        assert_eq!(job_name(&state, created).await, long, "{store}");
        let (status, err) = submit(&state, "s.gltf", with_name(&"é".repeat(257))).await;
        assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{store}: {err}");
        assert!(err["error"]["message"]
            .as_str()
            .unwrap()
            .contains("256 characters"));
        for bad in ["two\nlines", "bell\u{7}", "esc\u{1b}[31m", "c1\u{85}"] {
            let (status, err) = submit(&state, "s.gltf", with_name(bad)).await;
            assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{store}: {bad:?}");
            assert_eq!(err["error"]["code"], "invalid_settings", "{store}: {err}");
            assert!(err["error"]["message"]
                .as_str()
                .unwrap()
                .contains("control"));
        }

        // Without a name in the settings, the scene's file name names the job: cleaned of
        // control characters (a tab here) and cut at 256 characters.
        let (status, created) = submit(&state, "my\tscene.gltf", base.clone()).await;
        assert_eq!(status, StatusCode::CREATED, "{store}: {created}");
        assert_eq!(job_name(&state, created).await, "myscene.gltf", "{store}");
        let huge = format!("{}.gltf", "x".repeat(100_000));
        let (status, created) = submit(&state, &huge, base.clone()).await;
        assert_eq!(status, StatusCode::CREATED, "{store}: {created}");
        let name = job_name(&state, created).await;
        assert_eq!(name, "x".repeat(256), "{store}");
        // Nothing left of it: the default name.
        let (status, created) = submit(&state, "\t", base.clone()).await;
        assert_eq!(status, StatusCode::CREATED, "{store}: {created}");
        assert!(
            job_name(&state, created).await.starts_with("job "),
            "{store}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn worker_names_count_characters_and_refuse_control_characters() {
    for (store, url) in stores("names-workers").await {
        let state = AppState::open(config(&url)).await.expect("the store opens");
        let register = |name: String, version: String| {
            let body = json!({"name": name, "threads": 2, "version": version, "host": "h"});
            request(
                "POST",
                "/api/v1/workers",
                &[("content-type", "application/json")],
                body.to_string(),
            )
        };
        // 64 characters of three bytes each: 192 bytes, within the version's 64 characters.
        let (status, body): (StatusCode, Value) =
            call(&state, register("ü".repeat(128), "€".repeat(64))).await;
        assert_eq!(status, StatusCode::CREATED, "{store}: {body}");
        for (name, version) in [("ü".repeat(129), "1".into()), ("w".into(), "€".repeat(65))] {
            let (status, body): (StatusCode, Value) = call(&state, register(name, version)).await;
            assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{store}: {body}");
            assert_eq!(body["error"]["code"], "invalid_worker");
        }
        let (status, body): (StatusCode, Value) =
            call(&state, register("forged\nINFO line".into(), "1".into())).await;
        assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{store}: {body}");
        assert!(body["error"]["message"].as_str().unwrap().contains("name"));
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_bearer_scheme_is_matched_without_regard_to_case() {
    for (_, url) in stores("names-bearer").await {
        let mut cfg = config(&url);
        cfg.client_tokens = vec!["client-secret".into()];
        cfg.worker_tokens = vec!["worker-secret".into()];
        let state = AppState::open(cfg).await.expect("the store opens");
        for header in [
            "Bearer client-secret",
            "bearer client-secret",
            "BEARER client-secret",
        ] {
            let req = request("GET", "/api/v1/jobs", &[("authorization", header)], "");
            let (status, _): (StatusCode, Value) = call(&state, req).await;
            assert_eq!(status, StatusCode::OK, "{header}");
        }
        for header in ["Basic client-secret", "bearer client-secre", "bearer"] {
            let req = request("GET", "/api/v1/jobs", &[("authorization", header)], "");
            let (status, _): (StatusCode, Value) = call(&state, req).await;
            assert_eq!(status, StatusCode::UNAUTHORIZED, "{header}");
        }
    }
}
