//! `GET /metrics`: the Prometheus exposition is well formed, its counters and gauges agree with
//! what the farm did, and request latencies are recorded per route template; on both stores.

mod common;

use common::*;
use std::collections::HashMap;
use std::time::Duration;

/// Parses the text exposition into `series → value`, checking every line's shape on the way.
fn parse(text: &str) -> HashMap<String, f64> {
    let mut out = HashMap::new();
    for line in text.lines() {
        if line.is_empty() {
            continue;
        }
        if let Some(rest) = line.strip_prefix("# ") {
            assert!(
                [
                    "HELP pathfarm_",
                    "TYPE pathfarm_",
                    "HELP process_",
                    "TYPE process_"
                ]
                .iter()
                .any(|p| rest.starts_with(p)),
                "bad comment line {line:?}"
            );
            continue;
        }
        let (series, value) = line.rsplit_once(' ').expect("series and value");
        assert!(
            series.starts_with("pathfarm_") || series.starts_with("process_"),
            "{line:?}"
        );
        if let Some(open) = series.find('{') {
            assert!(series.ends_with('}'), "{line:?}");
            for label in series[open + 1..series.len() - 1].split("\",") {
                let (k, v) = label.split_once("=\"").expect("label=\"value\"");
                assert!(
                    k.chars().all(|c| c.is_ascii_alphanumeric() || c == '_'),
                    "{line:?}"
                );
                assert!(!v.is_empty() || k == "route", "{line:?}");
            }
        }
        let v: f64 = value
            .parse()
            .unwrap_or_else(|_| panic!("bad value in {line:?}"));
        assert!(
            out.insert(series.to_string(), v).is_none(),
            "duplicate series {series}"
        );
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn metrics_agree_with_what_the_farm_did() {
    let scene = cornell();
    for (store, url) in stores("metrics").await {
        let server = TestServer::start(config(&url)).await;
        let client = server.client(None);
        let s = settings(32, 32, 4, 16);
        let job = client
            .submit(scene.clone(), "cornell.gltf", &s)
            .await
            .unwrap();
        let worker = TestWorker::spawn(&server.url, None, Some(1));
        let done = wait_final(&client, &job.id, Duration::from_secs(60)).await;
        let report = worker.stop().await;
        assert_completed(&done);

        let resp = reqwest::get(format!("{}/metrics", server.url))
            .await
            .unwrap();
        assert_eq!(resp.status().as_u16(), 200);
        assert!(resp.headers()["content-type"]
            .to_str()
            .unwrap()
            .starts_with("text/plain; version=0.0.4"));
        let m = parse(&resp.text().await.unwrap());
        let get = |k: &str| *m.get(k).unwrap_or_else(|| panic!("{store}: no series {k}"));

        assert_eq!(
            get("pathfarm_merged_samples_total"),
            done.samples_planned as f64,
            "{store}"
        );
        assert_eq!(
            get("pathfarm_slice_uploads_merged_total"),
            report.slices as f64,
            "{store}"
        );
        assert_eq!(get("pathfarm_slice_uploads_rejected_total"), 0.0, "{store}");
        assert_eq!(get("pathfarm_jobs{state=\"completed\"}"), 1.0, "{store}");
        assert_eq!(get("pathfarm_jobs{state=\"running\"}"), 0.0, "{store}");
        assert_eq!(
            get("pathfarm_tasks{state=\"done\"}"),
            job.tasks as f64,
            "{store}"
        );
        assert_eq!(get("pathfarm_tasks{state=\"queued\"}"), 0.0, "{store}");
        assert_eq!(get("pathfarm_workers{state=\"offline\"}"), 1.0, "{store}");
        assert!(get("pathfarm_leases_total") >= job.tasks as f64, "{store}");

        // Every slice upload went through one route template, whatever the task id, and every
        // one was answered with a success (the status is a label).
        let uploads = "pathfarm_http_request_duration_seconds_count\
                       {method=\"POST\",route=\"/api/v1/tasks/{id}/slices\",status=\"";
        let by_status: Vec<(&String, f64)> = m
            .iter()
            .filter(|(k, _)| k.starts_with(uploads))
            .map(|(k, v)| (k, *v))
            .collect();
        assert!(
            by_status
                .iter()
                .all(|(k, _)| k[uploads.len()..].starts_with('2')),
            "{store}: {by_status:?}"
        );
        let counted: f64 = by_status.iter().map(|(_, v)| v).sum();
        assert!(counted >= report.slices as f64, "{store}: {counted}");
        for (k, v) in &by_status {
            let inf = k
                .replace("_count{", "_bucket{")
                .replace("\"}", "\",le=\"+Inf\"}");
            assert_eq!(get(&inf), *v, "{store}: {inf}");
        }
        // A refused request is counted under its own status: 404 for a job that does not exist.
        let missing = reqwest::get(format!(
            "{}/api/v1/jobs/00000000-0000-4000-8000-000000000000",
            server.url
        ))
        .await
        .unwrap();
        assert_eq!(missing.status().as_u16(), 404);
        let after = parse(&server.metrics_text().await);
        assert_eq!(
            after.get(
                "pathfarm_http_request_duration_seconds_count\
                 {method=\"GET\",route=\"/api/v1/jobs/{id}\",status=\"404\"}"
            ),
            Some(&1.0),
            "{store}"
        );
        // The lease time is exported, the build and the process are described.
        assert!(get("pathfarm_lease_seconds_total") > 0.0, "{store}");
        assert!(
            m.keys()
                .any(|k| k.starts_with("pathfarm_build_info{version=\"")),
            "{store}"
        );
        assert!(get("process_resident_memory_bytes") > 1e6, "{store}");
        assert!(get("process_cpu_seconds_total") > 0.0, "{store}");
        assert!(get("process_open_fds") >= 3.0, "{store}");
        assert!(
            !m.keys().any(|k| k.contains(&job.id)),
            "{store}: a job id became a label"
        );
        server.stop().await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_need_a_token_when_the_server_has_tokens() {
    let dir = temp_dir("metrics-auth");
    let mut cfg = config(&format!("sqlite://{}", dir.join("db.sqlite").display()));
    cfg.client_tokens = vec!["client-secret".into()];
    cfg.worker_tokens = vec!["worker-secret".into()];
    let server = TestServer::start(cfg).await;
    let http = reqwest::Client::new();
    let url = format!("{}/metrics", server.url);
    assert_eq!(http.get(&url).send().await.unwrap().status().as_u16(), 401);
    for token in ["client-secret", "worker-secret"] {
        let resp = http.get(&url).bearer_auth(token).send().await.unwrap();
        assert_eq!(resp.status().as_u16(), 200, "{token}");
    }
    server.stop().await;
}
