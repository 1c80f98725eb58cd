//! Connection hygiene against a real server on a loopback port, probed with raw TCP streams:
//! stalled headers, idle keep-alives, trickled bodies and responses left unread are let go after
//! their (short, test) timeouts, connections beyond the cap wait, and uploads that can be refused
//! without their body are answered before a byte of it is sent.

mod common;

use common::{cornell, settings, temp_dir, TestServer};
use pathfarm_server::ServerConfig;
use pathfarm_tracer::Accumulation;
use pathfarm_wire::api::{Lease, WorkerRegistration};
use pathfarm_wire::Slice;
use serde_json::Value;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// A bound on how long a test waits for what must happen; the timeouts under test are far shorter.
const PATIENCE: Duration = Duration::from_secs(20);

fn config(tag: &str) -> ServerConfig {
    let mut c = ServerConfig::new(format!(
        "sqlite://{}",
        temp_dir(tag).join("farm.db").display()
    ));
    c.monitor_interval = Duration::from_millis(100);
    c
}

fn host(server: &TestServer) -> &str {
    server.url.trim_start_matches("http://")
}

async fn connect(server: &TestServer) -> TcpStream {
    TcpStream::connect(host(server)).await.expect("connect")
}

/// Reads until the server closes the connection (EOF or reset), returning what it sent; panics
/// if it is still open after [`PATIENCE`].
async fn read_until_closed(stream: &mut TcpStream) -> Vec<u8> {
    let mut out = Vec::new();
    let mut buf = [0u8; 4096];
    let deadline = Instant::now() + PATIENCE;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match tokio::time::timeout(left, stream.read(&mut buf)).await {
            Err(_) => panic!(
                "the server kept the connection open for {PATIENCE:?}; it sent {:?}",
                String::from_utf8_lossy(&out)
            ),
            Ok(Ok(0)) | Ok(Err(_)) => return out,
            Ok(Ok(n)) => out.extend_from_slice(&buf[..n]),
        }
    }
}

/// One response: (status, headers in lowercase, body), read by its `Content-Length`.
async fn read_response(stream: &mut TcpStream) -> (u16, String, Vec<u8>) {
    let mut data = Vec::new();
    let mut buf = [0u8; 4096];
    let head_end = loop {
        if let Some(i) = data.windows(4).position(|w| w == b"\r\n\r\n") {
            break i + 4;
        }
        let n = tokio::time::timeout(PATIENCE, stream.read(&mut buf))
            .await
            .expect("a response in time")
            .expect("read");
        assert!(
            n > 0,
            "closed before a response: {:?}",
            String::from_utf8_lossy(&data)
        );
        data.extend_from_slice(&buf[..n]);
    };
    let head = String::from_utf8_lossy(&data[..head_end]).to_lowercase();
    let status = head[9..12].parse().expect("a status code");
    let length: usize = head
        .lines()
        .find_map(|l| l.strip_prefix("content-length:"))
        .map_or(0, |v| v.trim().parse().expect("a length"));
    while data.len() < head_end + length {
        let n = tokio::time::timeout(PATIENCE, stream.read(&mut buf))
            .await
            .expect("the body in time")
            .expect("read");
        assert!(n > 0, "closed in the body");
        data.extend_from_slice(&buf[..n]);
    }
    (status, head, data[head_end..head_end + length].to_vec())
}

fn error_code(body: &[u8]) -> String {
    let v: Value = serde_json::from_slice(body)
        .unwrap_or_else(|e| panic!("{e}: {:?}", String::from_utf8_lossy(body)));
    v["error"]["code"]
        .as_str()
        .expect("an error code")
        .to_string()
}

/// Asserts that the server's `/metrics` holds each of these lines (`name value`).
async fn assert_counters(server: &TestServer, lines: &[&str]) {
    let metrics = server.metrics_text().await;
    for line in lines {
        assert!(metrics.lines().any(|l| l == *line), "{line}: {metrics}");
    }
}

fn get_healthz(server: &TestServer) -> String {
    format!("GET /healthz HTTP/1.1\r\nHost: {}\r\n\r\n", host(server))
}

/// A client that sends half a header and stalls is disconnected after the header timeout, and so
/// is one that trickles its header a byte at a time (each byte would reset a per-read timer).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stalled_or_trickled_header_is_disconnected_after_the_header_timeout() {
    let mut c = config("header-timeout");
    c.connections.header_timeout = Duration::from_millis(300);
    let server = TestServer::start(c).await;

    // Before the connect: the server's clock starts at its accept, which may come before the
    // client sees the connection.
    let started = Instant::now();
    let mut stalled = connect(&server).await;
    stalled
        .write_all(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        .await
        .unwrap();
    let sent = read_until_closed(&mut stalled).await;
    assert!(sent.is_empty(), "{:?}", String::from_utf8_lossy(&sent));
    assert!(started.elapsed() >= Duration::from_millis(300));

    let mut trickle = connect(&server).await;
    let header = get_healthz(&server).replace("\r\n\r\n", "\r\nX-Padding: ");
    let writer = async {
        for b in header.bytes().chain(std::iter::repeat(b'a')) {
            if trickle.write_all(&[b]).await.is_err() {
                return;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    };
    tokio::time::timeout(PATIENCE, writer)
        .await
        .expect("the server cut the trickled header off");

    assert_counters(&server, &["pathfarm_http_header_timeouts_total 2"]).await;
    server.stop().await;
}

/// An idle keep-alive connection is closed after the keep-alive timeout, and so is a new one that
/// never sent a byte; a short header timeout cuts neither the idle time between requests nor the
/// silence before a first request short (HTTP clients open connections ahead of need, and one
/// closed at the header timeout races the request sent on it then).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_idle_keep_alive_is_closed_after_the_idle_timeout() {
    let mut c = config("keep-alive");
    c.connections.keep_alive_timeout = Duration::from_millis(400);
    c.connections.header_timeout = Duration::from_secs(30);
    let server = TestServer::start(c).await;
    let opened = Instant::now();
    let mut silent = connect(&server).await;
    assert!(read_until_closed(&mut silent).await.is_empty());
    assert!(opened.elapsed() >= Duration::from_millis(400));
    let mut s = connect(&server).await;
    // Before the request: the server's idle time starts once its response is sent, which may be
    // before the client has read it.
    let idle_from = Instant::now();
    s.write_all(get_healthz(&server).as_bytes()).await.unwrap();
    let (status, _, _) = read_response(&mut s).await;
    assert_eq!(status, 200);
    assert!(read_until_closed(&mut s).await.is_empty());
    assert!(idle_from.elapsed() >= Duration::from_millis(400));

    let mut c = config("keep-alive-long");
    c.connections.keep_alive_timeout = Duration::from_secs(30);
    c.connections.header_timeout = Duration::from_millis(200);
    let server2 = TestServer::start(c).await;
    let mut s = connect(&server2).await;
    for _ in 0..3 {
        // Idle for five header timeouts (the first time, before any request): the connection is
        // still there for the next request.
        tokio::time::sleep(Duration::from_secs(1)).await;
        s.write_all(get_healthz(&server2).as_bytes()).await.unwrap();
        let (status, _, _) = read_response(&mut s).await;
        assert_eq!(status, 200);
    }
    assert_counters(
        &server,
        &[
            "pathfarm_http_keep_alive_timeouts_total 2",
            "pathfarm_http_header_timeouts_total 0",
        ],
    )
    .await;
    server.stop().await;
    server2.stop().await;
}

/// A request body trickled below the minimum rate (each piece well within the idle bound) is cut
/// off with 408 `body_timeout` and the connection closed; so is one that stops.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_trickled_or_stalled_body_is_cut_off_with_408() {
    let mut c = config("body-timeout");
    c.connections.body_timeout = Duration::from_millis(500);
    c.connections.body_min_rate = 1000;
    let server = TestServer::start(c).await;

    for trickle in [true, false] {
        let mut s = connect(&server).await;
        let head = format!(
            "POST /api/v1/workers HTTP/1.1\r\nHost: {}\r\nContent-Type: application/json\r\n\
             Content-Length: 60000\r\n\r\n",
            host(&server)
        );
        s.write_all(head.as_bytes()).await.unwrap();
        let (mut rd, mut wr) = s.into_split();
        let writer = tokio::spawn(async move {
            // 10 bytes every 100 ms: 100 bytes/s, a tenth of the minimum rate.
            loop {
                if wr.write_all(&[b' '; 10]).await.is_err() {
                    return;
                }
                if !trickle {
                    tokio::time::sleep(PATIENCE).await;
                }
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        });
        let mut answer = Vec::new();
        tokio::time::timeout(PATIENCE, rd.read_to_end(&mut answer))
            .await
            .expect("the server answered and closed")
            .ok();
        writer.abort();
        let text = String::from_utf8_lossy(&answer).to_string();
        assert!(text.starts_with("HTTP/1.1 408"), "{text}");
        assert!(text.to_lowercase().contains("connection: close"), "{text}");
        let body = &answer[text.find("\r\n\r\n").unwrap() + 4..];
        assert_eq!(error_code(body), "body_timeout", "{text}");
    }
    // The server is fine afterwards.
    let mut s = connect(&server).await;
    s.write_all(get_healthz(&server).as_bytes()).await.unwrap();
    assert_eq!(read_response(&mut s).await.0, 200);
    server.stop().await;
}

/// Beyond the cap, a connection waits to be accepted: it is answered once another closes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connections_beyond_the_cap_wait_until_one_closes() {
    let mut c = config("cap");
    c.connections.max_connections = 2;
    let server = TestServer::start(c).await;
    let held = [connect(&server).await, connect(&server).await];
    // Both are accepted (the server reads nothing from them yet).
    tokio::time::sleep(Duration::from_millis(200)).await;

    let mut third = connect(&server).await;
    third
        .write_all(get_healthz(&server).as_bytes())
        .await
        .unwrap();
    let mut buf = [0u8; 64];
    let early = tokio::time::timeout(Duration::from_millis(500), third.read(&mut buf)).await;
    assert!(
        early.is_err(),
        "the third connection was served while two were held: {early:?}"
    );

    drop(held);
    let (status, _, _) = read_response(&mut third).await;
    assert_eq!(status, 200);
    drop(third);
    server.stop().await;
}

/// Graceful shutdown does not wait forever for a client that never finishes its header.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_lets_go_of_a_stalled_client() {
    let mut c = config("shutdown");
    c.connections.header_timeout = Duration::from_millis(300);
    let server = TestServer::start(c).await;
    let mut s = connect(&server).await;
    s.write_all(b"GET /healthz HTTP/1.1\r\n").await.unwrap();
    // Nor for one that never sent a byte (idle: its 60 s keep-alive timeout does not hold it).
    let _silent = connect(&server).await;
    tokio::time::sleep(Duration::from_millis(50)).await;
    tokio::time::timeout(PATIENCE, server.stop())
        .await
        .expect("the server stopped");
}

/// Sends a request's header only and reads the answer: the server must answer without the body,
/// which is never sent.
async fn headers_only(server: &TestServer, head: &str) -> (u16, String) {
    let mut s = connect(server).await;
    s.write_all(head.as_bytes()).await.unwrap();
    let (status, _, body) = read_response(&mut s).await;
    (status, error_code(&body))
}

/// A slice upload with a bogus lease token, the wrong content type or a declared length over the
/// limit, and a submission over the scene limit, without a client token or with the wrong content
/// type, are answered 4xx with a JSON error from their header alone: the 40–300 MiB bodies they
/// declare are never sent.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn uploads_are_refused_before_their_body_is_read() {
    let mut c = config("before-body");
    c.client_tokens = vec!["client".into()];
    c.worker_tokens = vec!["worker".into()];
    c.limits.max_scene_bytes = 50 << 20;
    let server = TestServer::start(c).await;
    let client = server.client(Some("client"));
    let worker = server.client(Some("worker"));
    client
        .submit(cornell(), "cornell.gltf", &settings(64, 64, 4, 64))
        .await
        .unwrap();
    let reg = worker
        .register(&WorkerRegistration {
            name: "w".into(),
            threads: 1,
            version: "t".into(),
            host: "h".into(),
        })
        .await
        .unwrap();
    let lease: Lease = worker.lease(&reg.worker_id).await.unwrap().expect("a task");

    let host = host(&server).to_string();
    let slice = |token: &str, ct: &str, length: u64| {
        format!(
            "POST /api/v1/tasks/{}/slices HTTP/1.1\r\nHost: {host}\r\nAuthorization: Bearer worker\r\n\
             Pathfarm-Worker-Credential: {}\r\n\
             Content-Type: {ct}\r\nPathfarm-Lease-Token: {token}\r\nContent-Length: {length}\r\n\r\n",
            lease.task_id, reg.credential
        )
    };
    let ok_ct = pathfarm_wire::api::SLICE_CONTENT_TYPE;
    let mib100 = 100 << 20;
    assert_eq!(
        headers_only(&server, &slice("bogus", ok_ct, mib100)).await,
        (409, "stale_lease".into())
    );
    assert_eq!(
        headers_only(&server, &slice(&lease.lease_token, "text/plain", mib100)).await,
        (415, "unsupported_media_type".into())
    );
    // Within the slice limit (256 MiB) but far over the largest slice of a 64x64 tile.
    assert_eq!(
        headers_only(&server, &slice(&lease.lease_token, ok_ct, mib100)).await,
        (413, "too_large".into())
    );
    assert_eq!(
        headers_only(&server, &slice(&lease.lease_token, ok_ct, 300 << 20)).await,
        (413, "too_large".into())
    );

    let submit = |auth: &str, ct: &str, length: u64| {
        format!(
            "POST /api/v1/jobs HTTP/1.1\r\nHost: {host}\r\n{auth}Content-Type: {ct}\r\n\
             Content-Length: {length}\r\n\r\n"
        )
    };
    let multipart = "multipart/form-data; boundary=x";
    let bearer = "Authorization: Bearer client\r\n";
    // 40 MiB: within the submission limit, so these are the token's and the content type's.
    let mib40 = 40 << 20;
    assert_eq!(
        headers_only(&server, &submit("", multipart, mib40)).await,
        (401, "unauthorized".into())
    );
    assert_eq!(
        headers_only(&server, &submit(bearer, "application/json", mib40)).await,
        (415, "unsupported_media_type".into())
    );
    assert_eq!(
        headers_only(&server, &submit(bearer, multipart, mib100)).await,
        (413, "too_large".into())
    );

    // With the lease and a length it may have, the body is read (and this empty one refused).
    let (status, code) = headers_only(&server, &slice(&lease.lease_token, ok_ct, 0)).await;
    assert_eq!((status, code.as_str()), (422, "invalid_slice"));
    server.stop().await;
}

/// A client that sends the whole of a refused upload before it reads the answer (as HTTP clients
/// do: reqwest writes the body first) still gets the answer: the server reads and discards what
/// it refused for a while (a lingering close) instead of closing the connection under the client,
/// which then saw a broken pipe and no answer.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_sends_a_refused_body_whole_still_reads_the_answer() {
    let mut c = config("linger");
    c.limits.max_scene_bytes = 4 << 20;
    let server = TestServer::start(c).await;
    let length = 48usize << 20;
    let head = format!(
        "POST /api/v1/jobs HTTP/1.1\r\nHost: {}\r\nContent-Type: multipart/form-data; \
         boundary=x\r\nContent-Length: {length}\r\n\r\n",
        host(&server)
    );
    let mut s = connect(&server).await;
    s.write_all(head.as_bytes()).await.unwrap();
    // Far more than the socket buffers hold: without the lingering close this write fails.
    s.write_all(&vec![b'x'; length])
        .await
        .expect("the refused body is read to its end");
    let (status, _, body) = read_response(&mut s).await;
    assert_eq!((status, error_code(&body).as_str()), (413, "too_large"));
    server.stop().await;
}

/// Bodies wait for room in the server's body budget before they are read: with the budget taken,
/// a submission is answered 503 `busy` with `Retry-After` after the wait, and goes through once
/// there is room again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bodies_wait_for_room_in_the_body_budget() {
    let mut c = config("body-budget");
    c.limits.body_budget_bytes = 4 << 20;
    c.limits.body_wait = Duration::from_millis(200);
    let state = pathfarm_server::AppState::open(c).await.unwrap();
    let settings = serde_json::to_string(&settings(16, 16, 1, 16)).unwrap();
    let taken = state.bodies.reserve(4 << 20, "the test").await.unwrap();
    let started = Instant::now();
    let (status, body) = common::submit_in_process(&state, None, &cornell(), &settings).await;
    assert_eq!(status.as_u16(), 503, "{body}");
    assert_eq!(body["error"]["code"], "busy");
    assert!(started.elapsed() >= Duration::from_millis(200));
    drop(taken);
    common::submit_ok(&state, None, &cornell(), &settings).await;
    assert_eq!(
        state.bodies.available(),
        4 << 20,
        "every reservation returned"
    );
}

/// A client that asks for a large response and does not read it is let go after the body
/// timeout (counted as a send timeout), while one that reads gets it whole: the connection and
/// the response's bytes are not held for as long as the client likes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_does_not_take_its_response_is_let_go() {
    let mut c = config("send-timeout");
    c.connections.body_timeout = Duration::from_millis(500);
    c.connections.body_min_rate = 1000;
    let server = TestServer::start(c).await;
    let state = &server.state;
    // A 1024² image of noise: about 12 MB as an EXR (noise does not compress), more than the
    // sockets' buffers hold.
    let s = serde_json::to_string(&settings(1024, 1024, 1, 256)).unwrap();
    let job = common::submit_ok(state, None, &cornell(), &s).await;
    let worker = common::register_in_process(state).await;
    while let Some(l) = common::lease_in_process(state, &worker).await {
        let mut acc = Accumulation::new(l.tile.x0, l.tile.y0, l.tile.width, l.tile.height);
        let mut x = (l.task_id as u32).wrapping_mul(0x9e37_79b9) | 1;
        for p in acc.pixels.iter_mut() {
            for _ in l.sample_begin..l.sample_end {
                let mut next = || {
                    x ^= x << 13;
                    x ^= x >> 17;
                    x ^= x << 5;
                    x as f32 / u32::MAX as f32
                };
                p.add_sample(glam::Vec3::new(next(), next(), next()));
            }
        }
        let slice = Slice {
            sample_begin: l.sample_begin,
            sample_end: l.sample_end,
            acc,
        };
        common::upload_in_process(state, &worker.1, &l, &slice).await;
    }
    let path = format!("/api/v1/jobs/{job}/image.exr");
    let whole = reqwest::get(format!("{}{path}", server.url))
        .await
        .unwrap()
        .bytes()
        .await
        .unwrap();
    assert!(whole.len() > 10 << 20, "{} bytes", whole.len());

    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(4096).unwrap();
    let mut stalled = socket
        .connect(host(&server).parse().unwrap())
        .await
        .unwrap();
    let get = format!("GET {path} HTTP/1.1\r\nHost: {}\r\n\r\n", host(&server));
    stalled.write_all(get.as_bytes()).await.unwrap();
    let started = Instant::now();
    let timeouts = || {
        state
            .metrics
            .send_timeouts
            .load(std::sync::atomic::Ordering::Relaxed)
    };
    while timeouts() == 0 {
        assert!(started.elapsed() < PATIENCE, "the stalled client was kept");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // Closed: what it reads now is what the server had sent, then the end.
    let got = read_until_closed(&mut stalled).await;
    assert!(got.len() < whole.len(), "{} bytes", got.len());
    assert_counters(&server, &["pathfarm_http_send_timeouts_total 1"]).await;
    server.stop().await;
}
