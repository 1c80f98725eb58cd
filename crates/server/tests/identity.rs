//! Worker identities over real HTTP on both stores: a worker token does not act for every worker.
//! A worker leases, heartbeats, uploads, releases, signs off and downloads scenes for itself
//! alone (its registration's credential), holds at most its lease cap, and a registration left
//! idle expires, its leases queued again; the worker list pages through every worker.

mod common;

use common::*;
use pathfarm_server::store::ManualClock;
use pathfarm_server::{monitor, ServerConfig};
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};
use pathfarm_tracer::{render_tile, Tile};
use pathfarm_wire::api::{
    ErrorBody, Heartbeat, Lease, WorkerList, WorkerRegistered, WorkerRegistration, WorkerState,
    LEASE_TOKEN_HEADER, SLICE_CONTENT_TYPE, WORKER_CREDENTIAL_HEADER,
};
use pathfarm_wire::{encode_slice, Slice};
use pathfarm_worker::client::{ApiClient, ClientError};
use reqwest::StatusCode;
use std::collections::HashSet;
use std::sync::Arc;
use std::time::Duration;

const CLIENT: &str = "client-token";
const WORKER: &str = "worker-token";

fn with_tokens(url: &str) -> ServerConfig {
    let mut c = config(url);
    c.client_tokens = vec![CLIENT.into()];
    c.worker_tokens = vec![WORKER.into()];
    c
}

fn registration(name: &str) -> WorkerRegistration {
    WorkerRegistration {
        name: name.into(),
        threads: 1,
        version: "test".into(),
        host: "test".into(),
    }
}

/// A worker of its own client (as separate worker processes are).
async fn worker(server: &TestServer, name: &str) -> (ApiClient, WorkerRegistered) {
    let c = server.client(Some(WORKER));
    let reg = c.register(&registration(name)).await.unwrap();
    (c, reg)
}

fn slice_body(lease: &Lease) -> Vec<u8> {
    let scene = gltf::load(&cornell(), &NoExternalResources, &LoadOptions::default()).unwrap();
    let tile = Tile {
        x0: lease.tile.x0,
        y0: lease.tile.y0,
        width: lease.tile.width,
        height: lease.tile.height,
    };
    let range = lease.sample_begin..lease.sample_end;
    encode_slice(&Slice {
        sample_begin: range.start,
        sample_end: range.end,
        acc: render_tile(&scene, &lease.settings.render_settings(), tile, range),
    })
}

fn api_error(e: &ClientError) -> (StatusCode, String) {
    match e {
        ClientError::Api { status, code, .. } => (*status, code.clone()),
        other => panic!("expected an API error, got {other}"),
    }
}

/// A request with the worker token and `credential`, as a worker that presents its own
/// credential but names someone else's work. Its status and error code (empty on success).
async fn as_worker(
    rb: reqwest::RequestBuilder,
    credential: &str,
) -> (StatusCode, String, reqwest::header::HeaderMap) {
    let resp = rb
        .bearer_auth(WORKER)
        .header(WORKER_CREDENTIAL_HEADER, credential)
        .send()
        .await
        .unwrap();
    let status = resp.status();
    let headers = resp.headers().clone();
    let bytes = resp.bytes().await.unwrap();
    let code = if status.is_success() {
        String::new()
    } else {
        serde_json::from_slice::<ErrorBody>(&bytes)
            .unwrap_or_else(|e| panic!("{status}: not an error body ({e}): {bytes:?}"))
            .error
            .code
    };
    (status, code, headers)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_worker_acts_only_for_itself() {
    for (store, url) in stores("identity-own").await {
        let server = TestServer::start(with_tokens(&url)).await;
        let client = server.client(Some(CLIENT));
        // One tile, passes [0,1) and [1,2).
        let job = client
            .submit(cornell(), "c.gltf", &settings(16, 16, 2, 16))
            .await
            .unwrap();
        let (wa, a) = worker(&server, "victim").await;
        let (wb, b) = worker(&server, "thief").await;
        assert_ne!(a.credential, b.credential);
        assert_eq!(a.credential.len(), 64, "256 bits, hex");
        let la = wa.lease(&a.worker_id).await.unwrap().expect("work");

        // The thief, with its own valid credential, names the victim: refused, all of it.
        let http = reqwest::Client::new();
        let base = &server.url;
        let victim = &a.worker_id;
        let refused = [
            (
                "lease",
                http.post(format!("{base}/api/v1/workers/{victim}/lease")),
                "not_your_worker",
            ),
            (
                "heartbeat",
                http.post(format!("{base}/api/v1/workers/{victim}/heartbeat"))
                    .json(&Heartbeat {
                        task_id: Some(la.task_id),
                        lease_token: Some(la.lease_token.clone()),
                    }),
                "not_your_worker",
            ),
            (
                "sign-off",
                http.delete(format!("{base}/api/v1/workers/{victim}")),
                "not_your_worker",
            ),
            // Even with the victim's lease token (leaked): the task is not the thief's.
            (
                "upload",
                http.post(format!("{base}/api/v1/tasks/{}/slices", la.task_id))
                    .header(reqwest::header::CONTENT_TYPE, SLICE_CONTENT_TYPE)
                    .header(LEASE_TOKEN_HEADER, &la.lease_token)
                    .body(slice_body(&la)),
                "not_your_lease",
            ),
            (
                "release",
                http.post(format!("{base}/api/v1/tasks/{}/release", la.task_id))
                    .json(&serde_json::json!({"lease_token": la.lease_token})),
                "not_your_lease",
            ),
            (
                "scene",
                http.get(format!("{base}/api/v1/scenes/{}", la.scene_hash)),
                "not_your_scene",
            ),
        ];
        for (what, rb, code) in refused {
            let (status, got, _) = as_worker(rb, &b.credential).await;
            assert_eq!(
                (status, got.as_str()),
                (StatusCode::FORBIDDEN, code),
                "{store}: {what}"
            );
        }
        // A worker token without a credential, or with one nobody has, acts for nobody.
        let e = wb.lease(&a.worker_id).await.unwrap_err();
        assert_eq!(
            api_error(&e),
            (StatusCode::UNAUTHORIZED, "missing_worker_credential".into()),
            "{store}"
        );
        let (status, got, _) = as_worker(
            http.post(format!("{base}/api/v1/workers/{victim}/lease")),
            &"0".repeat(64),
        )
        .await;
        assert_eq!(
            (status, got.as_str()),
            (StatusCode::UNAUTHORIZED, "unknown_worker_credential"),
            "{store}"
        );

        // The victim's work survived: its lease holds, its scene downloads, its upload merges.
        let reply = wa
            .heartbeat(
                &a.worker_id,
                &Heartbeat {
                    task_id: Some(la.task_id),
                    lease_token: Some(la.lease_token.clone()),
                },
            )
            .await
            .unwrap();
        assert!(reply.lease_valid, "{store}");
        assert_eq!(wa.scene(&la.scene_hash).await.unwrap(), cornell());
        let ack = wa
            .upload_slice(la.task_id, &la.lease_token, slice_body(&la))
            .await
            .unwrap();
        assert!(!ack.duplicate && ack.task_complete, "{store}: {ack:?}");
        assert_eq!(client.job(&job.id).await.unwrap().samples_done, 256);
        let workers = client.workers().await.unwrap().workers;
        let state = |id: &str| workers.iter().find(|w| w.id == id).map(|w| w.state);
        assert_eq!(state(&a.worker_id), Some(WorkerState::Idle), "{store}");
        assert_eq!(state(&b.worker_id), Some(WorkerState::Idle), "{store}");
        // Each signs itself off.
        wa.deregister(&a.worker_id).await.unwrap();
        wb.deregister(&b.worker_id).await.unwrap();
        server.stop().await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_worker_holds_at_most_its_lease_cap() {
    for (store, url) in stores("identity-cap").await {
        let mut cfg = with_tokens(&url);
        cfg.max_leases_per_worker = 2;
        let server = TestServer::start(cfg).await;
        let client = server.client(Some(CLIENT));
        // 16 tiles of one pass: 16 tasks.
        client
            .submit(cornell(), "c.gltf", &settings(32, 32, 1, 8))
            .await
            .unwrap();
        let (wa, a) = worker(&server, "greedy").await;
        let (wb, b) = worker(&server, "fair").await;
        let first = wa.lease(&a.worker_id).await.unwrap().expect("work");
        wa.lease(&a.worker_id).await.unwrap().expect("work");
        let e = wa.lease(&a.worker_id).await.unwrap_err();
        assert_eq!(
            api_error(&e),
            (StatusCode::TOO_MANY_REQUESTS, "too_many_leases".into()),
            "{store}"
        );
        // The others still get work; a lease given back makes room.
        wb.lease(&b.worker_id).await.unwrap().expect("work");
        wa.release(first.task_id, &first.lease_token).await.unwrap();
        wa.lease(&a.worker_id).await.unwrap().expect("work");
        let job = &client.jobs(None, 1, 10).await.unwrap().jobs[0];
        assert_eq!(job.leased_tasks, 3, "{store}");
        server.stop().await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn idle_registrations_expire_and_their_leases_are_queued_again() {
    for (store, url) in stores("identity-expiry").await {
        let clock = Arc::new(ManualClock::new());
        let mut cfg = with_tokens(&url);
        cfg.clock = clock.clone();
        // A lease longer than the expiry, so that only the expiry can take the task back.
        cfg.lease_duration = Duration::from_secs(600);
        cfg.worker_expiry = Duration::from_secs(60);
        let server = TestServer::start(cfg).await;
        let client = server.client(Some(CLIENT));
        let job = client
            .submit(cornell(), "c.gltf", &settings(16, 16, 1, 16))
            .await
            .unwrap();
        let (wa, a) = worker(&server, "silent").await;
        let (wb, b) = worker(&server, "alive").await;
        let (wc, c) = worker(&server, "signed-off").await;
        wc.deregister(&c.worker_id).await.unwrap();
        let la = wa.lease(&a.worker_id).await.unwrap().expect("work");

        clock.advance(Duration::from_secs(40));
        wb.heartbeat(&b.worker_id, &Heartbeat::default())
            .await
            .unwrap();
        clock.advance(Duration::from_secs(21));
        monitor::step(&server.state).await.unwrap();

        // Only the worker seen within the expiry is left.
        let list = client.workers_page(1, 10).await.unwrap();
        assert_eq!(list.total, 1, "{store}: {list:?}");
        assert_eq!(list.workers[0].id, b.worker_id, "{store}");
        // The silent worker's credential is void: it must register again.
        for e in [
            wa.lease(&a.worker_id).await.unwrap_err(),
            wa.upload_slice(la.task_id, &la.lease_token, slice_body(&la))
                .await
                .unwrap_err(),
        ] {
            assert_eq!(
                api_error(&e),
                (StatusCode::UNAUTHORIZED, "unknown_worker_credential".into()),
                "{store}"
            );
        }
        // Its task went back to the queue, whole: another worker leases and finishes it.
        assert_eq!(client.job(&job.id).await.unwrap().leased_tasks, 0);
        let lb = wb
            .lease(&b.worker_id)
            .await
            .unwrap()
            .expect("the task again");
        assert_eq!((lb.task_id, lb.sample_begin), (la.task_id, 0), "{store}");
        wb.upload_slice(lb.task_id, &lb.lease_token, slice_body(&lb))
            .await
            .unwrap();
        assert_completed(&wait_final(&client, &job.id, Duration::from_secs(30)).await);
        server.stop().await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_worker_is_listed_page_by_page() {
    const N: usize = 2500;
    for (store, url) in stores("identity-pages").await {
        let server = TestServer::start(with_tokens(&url)).await;
        let mut registered = HashSet::new();
        for i in 0..N {
            let (id, _) = server
                .state
                .store
                .register_worker(&registration(&format!("w{i}")))
                .await
                .unwrap();
            registered.insert(id);
        }
        let client = server.client(Some(CLIENT));
        // Pages of the most a page holds, and of the default size.
        for per_page in [1000, 100] {
            let mut seen = HashSet::new();
            let mut page = 1;
            loop {
                let list: WorkerList = client.workers_page(page, per_page).await.unwrap();
                assert_eq!(list.total, N as u64, "{store}");
                assert_eq!((list.page, list.per_page), (page, per_page));
                if list.workers.is_empty() {
                    break;
                }
                for w in list.workers {
                    assert!(seen.insert(w.id), "{store}: a worker on two pages");
                }
                page += 1;
            }
            assert_eq!(seen, registered, "{store}: {per_page} a page");
        }
        // A page is never larger than 1000; the client's whole list pages through all of them.
        let big = client.workers_page(1, 5000).await.unwrap();
        assert_eq!((big.per_page, big.workers.len()), (1000, 1000), "{store}");
        let all = client.workers().await.unwrap();
        let ids: HashSet<String> = all.workers.into_iter().map(|w| w.id).collect();
        assert_eq!(ids, registered, "{store}");
        server.stop().await;
    }
}

/// Paging by cursor while the farm changes under the pages: workers register, sign off and are
/// collected between two pages. Every worker that was there before the first page and is still
/// there after the last is listed exactly once, and no worker twice (numbered pages would shift
/// under the collected ones and skip workers).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cursor_pages_list_every_worker_once_while_workers_come_and_go() {
    const N: usize = 300;
    const PER_PAGE: u32 = 50;
    for (store, url) in stores("identity-churn").await {
        let clock = Arc::new(ManualClock::new());
        let mut cfg = with_tokens(&url);
        cfg.clock = clock.clone();
        let server = TestServer::start(cfg).await;
        let db = &server.state.store;
        let mut before = Vec::new();
        for i in 0..N {
            // Several registrations in each millisecond: the id orders those.
            if i % 7 == 0 {
                clock.advance(Duration::from_millis(1));
            }
            before.push(
                db.register_worker(&registration(&format!("w{i}")))
                    .await
                    .unwrap()
                    .0,
            );
        }
        // Every third worker goes silent and is collected after the first page; of the others,
        // every fifth signs off (a state change, which reordered the old listing).
        let (collected, kept): (Vec<_>, Vec<_>) =
            before.iter().enumerate().partition(|(i, _)| i % 3 == 0);
        let kept: HashSet<String> = kept.into_iter().map(|(_, id)| id.clone()).collect();
        let collected: HashSet<String> = collected.into_iter().map(|(_, id)| id.clone()).collect();

        let client = server.client(Some(CLIENT));
        let mut seen = Vec::new();
        let mut after: Option<String> = None;
        let mut pages = 0;
        loop {
            let list = client
                .workers_after(after.as_deref(), PER_PAGE)
                .await
                .unwrap();
            assert_eq!(
                (list.page, list.per_page),
                (if pages == 0 { 1 } else { 0 }, PER_PAGE)
            );
            seen.extend(list.workers.iter().map(|w| w.id.clone()));
            pages += 1;
            if pages == 1 {
                clock.advance(Duration::from_secs(61));
                for id in &kept {
                    db.heartbeat(id, None, 30_000).await.unwrap();
                }
                assert_eq!(
                    db.collect_idle_workers(60_000).await.unwrap(),
                    collected.len() as u64,
                    "{store}"
                );
                for id in kept.iter().take(kept.len() / 5) {
                    db.deregister_worker(id).await.unwrap();
                }
                for i in 0..25 {
                    db.register_worker(&registration(&format!("new{i}")))
                        .await
                        .unwrap();
                }
            }
            match list.next {
                Some(next) => after = Some(next),
                None => break,
            }
        }
        let unique: HashSet<&String> = seen.iter().collect();
        assert_eq!(unique.len(), seen.len(), "{store}: a worker listed twice");
        for id in &kept {
            assert!(unique.contains(id), "{store}: worker {id} was skipped");
        }
        assert!(
            seen.iter()
                .all(|id| kept.contains(id) || collected.contains(id)),
            "{store}: only workers registered before the first page"
        );
        // The whole list by the client's cursor walk: the kept workers and the new ones.
        let all = client.workers().await.unwrap().workers;
        assert_eq!(all.len(), kept.len() + 25, "{store}");
        // A cursor not of the server's form is refused.
        for bad in ["", "12", "x.abc", "1.", "+5.abc", "1234567890123456789.a"] {
            let err = client.workers_after(Some(bad), 10).await.unwrap_err();
            assert_eq!(
                err.status(),
                Some(StatusCode::BAD_REQUEST),
                "{store}: {bad:?}"
            );
        }
        server.stop().await;
    }
}

/// At most `max_workers` registrations are kept: one more is answered 503 `too_many_workers`
/// with `Retry-After` (which the worker daemon waits out), and registering works again once idle
/// registrations were collected.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn registrations_beyond_the_cap_wait_for_idle_ones_to_expire() {
    for (store, url) in stores("identity-max-workers").await {
        let clock = Arc::new(ManualClock::new());
        let mut cfg = with_tokens(&url);
        cfg.clock = clock.clone();
        cfg.max_workers = 3;
        cfg.worker_expiry = Duration::from_secs(60);
        let server = TestServer::start(cfg).await;
        let c = server.client(Some(WORKER));
        for i in 0..3 {
            c.register(&registration(&format!("w{i}"))).await.unwrap();
        }
        let err = c.register(&registration("w3")).await.unwrap_err();
        assert_eq!(
            err.status(),
            Some(StatusCode::SERVICE_UNAVAILABLE),
            "{store}: {err}"
        );
        assert!(
            err.to_string().contains("too_many_workers"),
            "{store}: {err}"
        );
        assert_eq!(err.retry_after(), Some(Duration::from_secs(60)), "{store}");
        assert!(err.is_transient(), "{store}: the daemon retries it");
        let listed = server.client(Some(CLIENT)).workers().await.unwrap();
        assert_eq!(listed.workers.len(), 3, "{store}");
        // Registrations that expired free their places.
        clock.advance(Duration::from_secs(61));
        let collected = server
            .state
            .store
            .collect_idle_workers(60_000)
            .await
            .unwrap();
        assert_eq!(collected, 3, "{store}");
        c.register(&registration("w3")).await.unwrap();
        server.stop().await;
    }
}

/// The worker daemon registers again when the server forgot it (its registration expired), and
/// goes on rendering as a new worker.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_worker_daemon_registers_again_after_its_registration_expired() {
    let url = format!(
        "sqlite://{}",
        temp_dir("identity-daemon").join("farm.db").display()
    );
    let clock = Arc::new(ManualClock::new());
    let mut cfg = with_tokens(&url);
    cfg.clock = clock.clone();
    cfg.worker_expiry = Duration::from_secs(60);
    let server = TestServer::start(cfg).await;
    let client = server.client(Some(CLIENT));
    let daemon = TestWorker::spawn(&server.url, Some(WORKER), None);
    let t0 = std::time::Instant::now();
    let first = loop {
        if let Some(w) = client.workers().await.unwrap().workers.first() {
            break w.id.clone();
        }
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "the daemon never registered"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    // The daemon polls for work all the while (which counts as being seen): expire it between
    // two polls.
    let mut collected = 0;
    for _ in 0..100 {
        clock.advance(Duration::from_secs(61));
        collected = server
            .state
            .store
            .collect_idle_workers(60_000)
            .await
            .unwrap();
        if collected > 0 {
            break;
        }
    }
    assert_eq!(collected, 1, "the daemon's registration expired");
    let job = client
        .submit(cornell(), "c.gltf", &settings(16, 16, 2, 16))
        .await
        .unwrap();
    assert_completed(&wait_final(&client, &job.id, Duration::from_secs(60)).await);
    let workers = client.workers().await.unwrap().workers;
    assert_eq!(workers.len(), 1, "{workers:?}");
    assert_ne!(workers[0].id, first, "a new registration");
    assert!(workers[0].samples_done > 0);
    daemon.stop().await;
    server.stop().await;
}

/// Two servers on one PostgreSQL: a worker racing many leases through both never holds more than
/// its cap (each server's count would see only committed leases without the worker's lease lock).
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_lease_cap_holds_across_two_postgres_servers() {
    let Ok(base) = std::env::var("PATHFARM_TEST_POSTGRES_URL") else {
        eprintln!("SKIPPED: two servers on PostgreSQL (PATHFARM_TEST_POSTGRES_URL is not set)");
        return;
    };
    let url = fresh_postgres(&base).await;
    let mut cfg = with_tokens(&url);
    cfg.max_leases_per_worker = 1;
    let (s1, s2) = (
        TestServer::start(cfg.clone()).await,
        TestServer::start(cfg).await,
    );
    s1.client(Some(CLIENT))
        .submit(cornell(), "c.gltf", &settings(64, 64, 1, 8))
        .await
        .unwrap();
    let (c1, reg) = worker(&s1, "racer").await;
    let c2 = s2.client(Some(WORKER));
    c2.set_worker_credential(
        &reg.worker_id,
        &c1.worker_credential(&reg.worker_id).unwrap(),
    );
    for round in 0..10 {
        let tries = (0..8).map(|k| {
            let c = if k % 2 == 0 { &c1 } else { &c2 };
            c.lease(&reg.worker_id)
        });
        let results = futures_util::future::join_all(tries).await;
        let got: Vec<_> = results
            .into_iter()
            .filter_map(|r| r.ok().flatten())
            .collect();
        assert!(
            got.len() <= 1,
            "round {round}: {} leases at once",
            got.len()
        );
        for l in got {
            c1.release(l.task_id, &l.lease_token).await.unwrap();
        }
    }
    s1.stop().await;
    s2.stop().await;
}
