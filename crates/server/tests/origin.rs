//! A server without client tokens is safe on a workstation (issue 32, item 3): a web page cannot
//! use it through the user's browser. A cross-site form (its `Origin` another site's) cannot
//! submit or cancel a job, a page rebound to 127.0.0.1 (its `Host` its own name) can neither
//! change nor read anything, and the server's own pages, the worker and other programs go on
//! working. A real server on a real port, real HTTP.

mod common;

use common::*;
use pathfarm_wire::api::JobState;
use reqwest::header::{HOST, ORIGIN};
use reqwest::{Client, RequestBuilder, StatusCode};
use serde_json::{json, Value};
use std::time::Duration;

/// The status and the JSON error code of a response (after checking that an error is our JSON
/// error body).
async fn outcome(rb: RequestBuilder) -> (StatusCode, Option<String>) {
    let resp = rb.send().await.unwrap();
    let status = resp.status();
    if status.is_success() {
        return (status, None);
    }
    let body: Value = resp.json().await.unwrap();
    let code = body["error"]["code"].as_str().unwrap().to_string();
    assert!(body["error"]["message"].as_str().is_some(), "{body}");
    (status, Some(code))
}

fn submission(http: &Client, url: &str, s: &pathfarm_wire::api::JobSettings) -> RequestBuilder {
    let (ct, body) = multipart(&cornell(), &serde_json::to_string(s).unwrap());
    http.post(format!("{url}/api/v1/jobs"))
        .header("content-type", ct)
        .body(body)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cross_site_and_rebinding_requests_are_refused_without_tokens() {
    let server = TestServer::start(config(&format!(
        "sqlite://{}",
        temp_dir("origin").join("farm.db").display()
    )))
    .await;
    let url = &server.url;
    let port = url.rsplit(':').next().unwrap().to_string();
    let http = Client::new();
    let client = server.client(None);
    let s = settings(16, 16, 2, 16);
    let forbidden = |code: &str| (StatusCode::FORBIDDEN, Some(code.to_string()));

    // A cross-site form: refused, nothing submitted.
    for origin in [
        "http://evil.example",
        "null",
        &format!("https://127.0.0.1:{port}"),
    ] {
        let rb = submission(&http, url, &s).header(ORIGIN, origin);
        assert_eq!(outcome(rb).await, forbidden("cross_origin"), "{origin}");
    }
    let rb = submission(&http, url, &s).header("sec-fetch-site", "cross-site");
    assert_eq!(outcome(rb).await, forbidden("cross_origin"));
    assert_eq!(
        client.jobs(None, 1, 100).await.unwrap().total,
        0,
        "a job was submitted"
    );

    // The server's own page (under each of its names) and programs without Origin: accepted.
    let job = client.submit(cornell(), "c.gltf", &s).await.unwrap().id;
    for (host, origin) in [
        (
            format!("127.0.0.1:{port}"),
            format!("http://127.0.0.1:{port}"),
        ),
        (
            format!("localhost:{port}"),
            format!("http://localhost:{port}"),
        ),
        (format!("[::1]:{port}"), format!("http://[::1]:{port}")),
    ] {
        let rb = submission(&http, url, &s)
            .header(HOST, &host)
            .header(ORIGIN, &origin)
            .header("sec-fetch-site", "same-origin");
        assert_eq!(outcome(rb).await.0, StatusCode::CREATED, "{host} {origin}");
    }

    // Cancelling from another site: refused, the job stays queued. A read from another site is
    // no change (and the browser keeps the answer from the page): answered.
    let cancel = format!("{url}/api/v1/jobs/{job}/cancel");
    let rb = http.post(&cancel).header(ORIGIN, "http://evil.example");
    assert_eq!(outcome(rb).await, forbidden("cross_origin"));
    let rb = http
        .delete(format!("{url}/api/v1/jobs/{job}"))
        .header(ORIGIN, "http://evil.example");
    assert_eq!(outcome(rb).await, forbidden("cross_origin"));
    assert_eq!(client.job(&job).await.unwrap().state, JobState::Queued);
    let rb = http
        .get(format!("{url}/api/v1/jobs/{job}"))
        .header(ORIGIN, "http://evil.example");
    assert_eq!(outcome(rb).await.0, StatusCode::OK);

    // DNS rebinding: the page's own name (or another port) in Host. Nothing is answered, reads
    // and the dashboard included; health checks say nothing and are answered.
    let rebound = format!("attacker.example:{port}");
    let worker = json!({"name": "w", "threads": 1, "version": "t", "host": "h"});
    for (rb, what) in [
        (
            http.post(format!("{url}/api/v1/workers")).json(&worker),
            "register",
        ),
        (http.post(&cancel), "cancel"),
        (http.get(format!("{url}/api/v1/jobs")), "list"),
        (
            http.get(format!("{url}/api/v1/jobs/{job}/preview.png")),
            "preview",
        ),
        (http.get(format!("{url}/")), "dashboard"),
    ] {
        assert_eq!(
            outcome(rb.header(HOST, &rebound)).await,
            forbidden("bad_host"),
            "{what}"
        );
    }
    let other_port = format!("127.0.0.1:{}", port.parse::<u16>().unwrap() ^ 1);
    let rb = http
        .get(format!("{url}/api/v1/jobs"))
        .header(HOST, other_port);
    assert_eq!(outcome(rb).await, forbidden("bad_host"));
    let rb = http.get(format!("{url}/healthz")).header(HOST, &rebound);
    assert_eq!(outcome(rb).await.0, StatusCode::OK);
    assert_eq!(client.job(&job).await.unwrap().state, JobState::Queued);

    // The dashboard's page and the same-origin requests it makes.
    let rb = http.get(format!("{url}/"));
    assert_eq!(outcome(rb).await.0, StatusCode::OK);
    let rb = http
        .post(&cancel)
        .header(ORIGIN, url.as_str())
        .header("sec-fetch-site", "same-origin");
    assert_eq!(outcome(rb).await.0, StatusCode::OK);

    // A worker renders the rest.
    let worker = TestWorker::spawn(url, None, None);
    for j in client.jobs(None, 1, 100).await.unwrap().jobs {
        if !j.state.is_final() {
            assert_completed(&wait_final(&client, &j.id, Duration::from_secs(120)).await);
        }
    }
    worker.stop().await;
    server.stop().await;
}

/// With client tokens configured the checks are off (a page cannot know a token): a request
/// with its token is answered whatever its Host and Origin.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_tokens_the_token_decides() {
    let mut cfg = config(&format!(
        "sqlite://{}",
        temp_dir("origin-tokens").join("farm.db").display()
    ));
    cfg.client_tokens = vec!["client-secret".into()];
    cfg.worker_tokens = vec!["worker-secret".into()];
    let server = TestServer::start(cfg).await;
    let http = Client::new();
    let rb = submission(&http, &server.url, &settings(8, 8, 1, 8))
        .bearer_auth("client-secret")
        .header(HOST, "farm.example.org")
        .header(ORIGIN, "https://dashboard.example.org");
    assert_eq!(outcome(rb).await.0, StatusCode::CREATED);
    let rb = http
        .get(format!("{}/api/v1/jobs", server.url))
        .header(HOST, "farm.example.org");
    assert_eq!(
        outcome(rb).await,
        (StatusCode::UNAUTHORIZED, Some("unauthorized".into()))
    );
    server.stop().await;
}
