//! The store's failures reach clients as the API's own errors: a database that fails is a 503
//! `database` whose message is the server's, never the database driver's text (which names
//! tables, queries or connection details); a refusal keeps its status and code.

mod common;

use axum::http::StatusCode;
use common::*;
use pathfarm_server::AppState;
use pathfarm_wire::api::ErrorBody;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn database_text_never_reaches_clients() {
    let url = format!(
        "sqlite://{}",
        temp_dir("store-errors").join("farm.db").display()
    );
    let state = AppState::open(config(&url)).await.unwrap();

    // A refusal of the store keeps its meaning: no such job is a 404 naming it.
    let (status, body) = call::<ErrorBody>(
        &state,
        request(
            "GET",
            "/api/v1/jobs/0123456789abcdef0123456789abcdef",
            &[],
            "",
        ),
    )
    .await;
    assert_eq!(
        (status, body.error.code.as_str()),
        (StatusCode::NOT_FOUND, "not_found")
    );
    assert!(body
        .error
        .message
        .contains("0123456789abcdef0123456789abcdef"));

    // The database goes away: every store failure is a 503 `database` in the server's words.
    state.store.close().await;
    for (method, uri) in [
        ("GET", "/api/v1/jobs"),
        ("GET", "/api/v1/jobs/0123456789abcdef0123456789abcdef"),
        ("GET", "/api/v1/workers"),
        ("POST", "/api/v1/tasks/1/release"),
    ] {
        // The worker call's credential is looked up in the store, which fails first.
        let headers: &[(&str, &str)] = &[
            ("content-type", "application/json"),
            ("pathfarm-worker-credential", "x"),
        ];
        let (status, body) = call::<ErrorBody>(
            &state,
            request(method, uri, headers, r#"{"lease_token":"t"}"#),
        )
        .await;
        assert_eq!(
            (status, body.error.code.as_str()),
            (StatusCode::SERVICE_UNAVAILABLE, "database"),
            "{method} {uri}: {}",
            body.error.message
        );
        let m = body.error.message.to_lowercase();
        for leak in ["pool", "sqlx", "sqlite", "closed", "connection", "error:"] {
            assert!(!m.contains(leak), "{method} {uri} leaks {leak:?}: {m}");
        }
    }
}
