//! Malformed requests and tokens get their documented 4xx with a JSON error body, nothing is
//! created or changed, and the server keeps serving. Uses the router in process (`oneshot`) and a
//! real server for the multipart and size cases.

mod common;

use axum::body::Body;
use axum::http::{Request, StatusCode};
use common::*;
use pathfarm_server::{app, AppState};
use pathfarm_wire::api::{ErrorBody, JobSettings, WorkerRegistration, WORKER_CREDENTIAL_HEADER};
use tower::ServiceExt;

fn req(method: &str, uri: &str, ct: Option<&str>, body: impl Into<Body>) -> Request<Body> {
    let mut b = Request::builder().method(method).uri(uri);
    if let Some(ct) = ct {
        b = b.header("content-type", ct);
    }
    b.body(body.into()).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_requests_get_documented_errors() {
    for (store, url) in stores("bad-input").await {
        let mut cfg = config(&url);
        cfg.limits.max_scene_bytes = 64 << 10;
        cfg.limits.max_slice_bytes = 64 << 10;
        let state = AppState::open(cfg).await.unwrap();
        // The worker calls below are made as a registered worker: without its credential they
        // would all be the 401 of the last case.
        let (worker_id, cred) = state
            .store
            .register_worker(&WorkerRegistration {
                name: "w".into(),
                threads: 1,
                version: "t".into(),
                host: "h".into(),
            })
            .await
            .unwrap();
        let as_worker = |mut r: Request<Body>| {
            r.headers_mut()
                .insert(WORKER_CREDENTIAL_HEADER, cred.parse().unwrap());
            r
        };
        let ok_settings = r#"{"width":16,"height":16,"spp":2}"#;
        let cases: Vec<(Request<Body>, StatusCode, &str)> = vec![
            (
                req("GET", "/api/v1/jobs/nope", None, ""),
                StatusCode::NOT_FOUND,
                "not_found",
            ),
            (
                req("GET", "/api/v1/nothing-here", None, ""),
                StatusCode::NOT_FOUND,
                "not_found",
            ),
            (
                req("PUT", "/api/v1/jobs", None, ""),
                StatusCode::METHOD_NOT_ALLOWED,
                "method_not_allowed",
            ),
            (
                req(
                    "POST",
                    "/api/v1/jobs",
                    Some("application/json"),
                    ok_settings,
                ),
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
                "unsupported_media_type",
            ),
            (
                req(
                    "PATCH",
                    "/api/v1/jobs/x",
                    Some("application/json"),
                    "{not json",
                ),
                StatusCode::BAD_REQUEST,
                "bad_json",
            ),
            (
                req(
                    "PATCH",
                    "/api/v1/jobs/x",
                    Some("text/plain"),
                    r#"{"priority":1}"#,
                ),
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
                "unsupported_media_type",
            ),
            (
                req(
                    "POST",
                    "/api/v1/workers",
                    Some("application/json"),
                    r#"{"name":"w"}"#,
                ),
                StatusCode::BAD_REQUEST,
                "bad_json",
            ),
            // An array is not an object, even where serde would read the struct from it.
            (
                as_worker(req(
                    "POST",
                    &format!("/api/v1/workers/{worker_id}/heartbeat"),
                    Some("application/json"),
                    "[null, null]",
                )),
                StatusCode::BAD_REQUEST,
                "bad_json",
            ),
            (
                req(
                    "POST",
                    "/api/v1/workers",
                    Some("application/json"),
                    r#" ["w", 1, "t", "h"]"#,
                ),
                StatusCode::BAD_REQUEST,
                "bad_json",
            ),
            (
                req("GET", "/api/v1/jobs?state=sleeping", None, ""),
                StatusCode::BAD_REQUEST,
                "bad_query",
            ),
            (
                as_worker(req(
                    "POST",
                    "/api/v1/tasks/1/slices",
                    Some("application/json"),
                    "x",
                )),
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
                "unsupported_media_type",
            ),
            (
                as_worker(req(
                    "POST",
                    "/api/v1/tasks/1/slices",
                    Some("application/x-pathfarm-slice"),
                    "x",
                )),
                StatusCode::BAD_REQUEST,
                "missing_lease_token",
            ),
            (
                as_worker(
                    Request::builder()
                        .method("POST")
                        .uri("/api/v1/tasks/1/slices")
                        .header("content-type", "application/x-pathfarm-slice")
                        .header("pathfarm-lease-token", "t")
                        .body(Body::from(&b"PFSL\x01\x00garbage"[..]))
                        .unwrap(),
                ),
                // The lease is checked before the body is read: there is no task 1.
                StatusCode::NOT_FOUND,
                "not_found",
            ),
            (
                // Without a worker's credential, before anything else of the call.
                req(
                    "POST",
                    "/api/v1/tasks/1/slices",
                    Some("application/x-pathfarm-slice"),
                    "x",
                ),
                StatusCode::UNAUTHORIZED,
                "missing_worker_credential",
            ),
            (
                Request::builder()
                    .method("POST")
                    .uri("/api/v1/workers/x/lease")
                    .header(WORKER_CREDENTIAL_HEADER, "0".repeat(64))
                    .body(Body::empty())
                    .unwrap(),
                StatusCode::UNAUTHORIZED,
                "unknown_worker_credential",
            ),
            (
                // A declared length over the route's limit is refused before anything else.
                Request::builder()
                    .method("POST")
                    .uri("/api/v1/tasks/1/slices")
                    .header("content-type", "application/x-pathfarm-slice")
                    .header("content-length", 2 << 20)
                    .body(Body::from(vec![0u8; 2 << 20]))
                    .unwrap(),
                StatusCode::PAYLOAD_TOO_LARGE,
                "too_large",
            ),
        ];
        for (r, status, code) in cases {
            let what = format!("{} {}", r.method(), r.uri());
            let (s, body) = call::<ErrorBody>(&state, r).await;
            assert_eq!(
                (s, body.error.code.as_str()),
                (status, code),
                "{store}: {what}: {}",
                body.error.message
            );
        }
        // Submissions that must not create a job.
        let scene = cornell();
        let broken = b"{\"asset\":{\"version\":\"2.0\"},\"meshes\":[{\"name\":\"Chair\",\"primitives\":[{\"attributes\":{\"POSITION\":0}}]}]}";
        let bad_submissions: Vec<(Vec<u8>, String, StatusCode, &str, &str)> = vec![
            (
                broken.to_vec(),
                ok_settings.into(),
                StatusCode::UNPROCESSABLE_ENTITY,
                "invalid_scene",
                "Chair",
            ),
            (
                b"glTF\x02\x00\x00\x00\xff\xff\xff\x7f".to_vec(),
                ok_settings.into(),
                StatusCode::UNPROCESSABLE_ENTITY,
                "invalid_scene",
                "",
            ),
            (
                scene.clone(),
                r#"{"width":0,"height":16,"spp":2}"#.into(),
                StatusCode::UNPROCESSABLE_ENTITY,
                "invalid_settings",
                "width",
            ),
            (
                scene.clone(),
                r#"{"width":100000,"height":100000,"spp":2}"#.into(),
                StatusCode::UNPROCESSABLE_ENTITY,
                "invalid_settings",
                "100000",
            ),
            (
                scene.clone(),
                r#"{"width":16,"height":16,"spp":2,"direct":"magic"}"#.into(),
                StatusCode::UNPROCESSABLE_ENTITY,
                "invalid_settings",
                "magic",
            ),
            (
                scene.clone(),
                "[16, 16, 2]".into(),
                StatusCode::UNPROCESSABLE_ENTITY,
                "invalid_settings",
                "object",
            ),
            (
                scene.clone(),
                "nope".into(),
                StatusCode::UNPROCESSABLE_ENTITY,
                "invalid_settings",
                "",
            ),
            (
                vec![b' '; 100 << 10],
                ok_settings.into(),
                StatusCode::PAYLOAD_TOO_LARGE,
                "too_large",
                "",
            ),
        ];
        for (scene, settings, status, code, mentions) in bad_submissions {
            let (ct, body) = multipart(&scene, &settings);
            let (s, err) =
                call::<ErrorBody>(&state, req("POST", "/api/v1/jobs", Some(&ct), body)).await;
            assert_eq!(
                (s, err.error.code.as_str()),
                (status, code),
                "{store}: {}",
                err.error.message
            );
            assert!(
                err.error.message.contains(mentions),
                "{store}: {:?} should mention {mentions:?}",
                err.error.message
            );
        }
        // A scene that points outside: refused, nothing read.
        for uri in [
            "../../etc/passwd",
            "file:///etc/passwd",
            "http://example.com/b.bin",
        ] {
            let outside = format!(
                r#"{{"asset":{{"version":"2.0"}},"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
                "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
                "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}],
                "bufferViews":[{{"buffer":0,"byteLength":36}}],
                "buffers":[{{"uri":"{uri}","byteLength":36}}]}}"#
            );
            let (ct, body) = multipart(outside.as_bytes(), ok_settings);
            let (s, err) =
                call::<ErrorBody>(&state, req("POST", "/api/v1/jobs", Some(&ct), body)).await;
            assert_eq!(
                (s, err.error.code.as_str()),
                (StatusCode::UNPROCESSABLE_ENTITY, "invalid_scene"),
                "{uri}: {}",
                err.error.message
            );
            assert!(
                err.error.message.contains("buffer 0"),
                "{}",
                err.error.message
            );
        }
        assert_eq!(
            state.store.jobs(None, 0, 10).await.unwrap().1,
            0,
            "{store}: no job was created"
        );
        // The server still serves: a good submission works.
        let (ct, body) = multipart(&scene, ok_settings);
        let resp = app(state.clone())
            .oneshot(req("POST", "/api/v1/jobs", Some(&ct), body))
            .await
            .unwrap();
        assert_eq!(resp.status(), StatusCode::CREATED, "{store}");
        assert_eq!(state.store.jobs(None, 0, 10).await.unwrap().1, 1);
        state.store.close().await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tokens_separate_clients_from_workers() {
    let url = format!("sqlite://{}", temp_dir("tokens").join("t.db").display());
    let mut cfg = config(&url);
    cfg.client_tokens = vec!["client-secret".into()];
    cfg.worker_tokens = vec!["worker-secret".into()];
    // The test leases a task by hand and drops it: let it expire quickly.
    cfg.lease_duration = std::time::Duration::from_millis(500);
    let server = TestServer::start(cfg).await;
    let scene = cornell();
    let s = JobSettings::new(16, 16, 2);
    // No token, a wrong token: 401.
    for token in [None, Some("guess")] {
        let e = server
            .client(token)
            .submit(scene.clone(), "s", &s)
            .await
            .unwrap_err();
        assert_eq!(e.status(), Some(StatusCode::UNAUTHORIZED), "{e}");
    }
    // A worker token cannot submit or delete; a client token cannot register, lease or upload.
    let worker = server.client(Some("worker-secret"));
    let client = server.client(Some("client-secret"));
    let e = worker.submit(scene.clone(), "s", &s).await.unwrap_err();
    assert_eq!(e.status(), Some(StatusCode::FORBIDDEN), "{e}");
    let job = client.submit(scene.clone(), "s", &s).await.unwrap();
    let e = worker.delete_job(&job.id).await.unwrap_err();
    assert_eq!(e.status(), Some(StatusCode::FORBIDDEN));
    let reg = pathfarm_wire::api::WorkerRegistration {
        name: "w".into(),
        threads: 1,
        version: "t".into(),
        host: "h".into(),
    };
    assert_eq!(
        client.register(&reg).await.unwrap_err().status(),
        Some(StatusCode::FORBIDDEN)
    );
    let id = worker.register(&reg).await.unwrap().worker_id;
    assert_eq!(
        client.lease(&id).await.unwrap_err().status(),
        Some(StatusCode::FORBIDDEN)
    );
    let lease = worker.lease(&id).await.unwrap().unwrap();
    let e = client
        .upload_slice(lease.task_id, &lease.lease_token, vec![1, 2, 3])
        .await
        .unwrap_err();
    assert_eq!(e.status(), Some(StatusCode::FORBIDDEN));
    // Both can read.
    assert!(worker.job(&job.id).await.is_ok());
    assert!(client.job(&job.id).await.is_ok());
    // A real worker with the worker token completes the job.
    let w = TestWorker::spawn(&server.url, Some("worker-secret"), None);
    let done = wait_final(&client, &job.id, std::time::Duration::from_secs(60)).await;
    w.stop().await;
    assert_completed(&done);
    server.stop().await;
}
