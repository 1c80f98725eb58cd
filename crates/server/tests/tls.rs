//! TLS end to end, in process: a real server terminating TLS with a self-signed certificate made
//! here (rcgen), a real worker and client trusting it through `--ca-cert`'s file; clients that do
//! not trust it, speak plain HTTP to it or `https://` to a plain server fail at once with a clear
//! error; a replaced certificate is served to new connections, a broken one is not; and the store
//! reached over TLS (`sslmode=require`) when PostgreSQL is there.

mod common;

use common::*;
use pathfarm_server::tls::{ServerCert, TlsError};
use pathfarm_worker::client::{ApiClient, ClientError, SetupError};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A self-signed certificate for `localhost` and 127.0.0.1, as PEM: (certificate, key).
fn self_signed() -> (String, String) {
    let c = rcgen::generate_simple_self_signed(vec!["localhost".into(), "127.0.0.1".into()])
        .expect("certificate");
    (c.cert.pem(), c.signing_key.serialize_pem())
}

/// Writes `pem` to `path` by a rename, as a deployment tool replaces a file.
fn replace(path: &Path, pem: &str) {
    let tmp = path.with_extension("new");
    std::fs::write(&tmp, pem).unwrap();
    std::fs::rename(&tmp, path).unwrap();
}

struct Files {
    dir: PathBuf,
    cert: PathBuf,
    key: PathBuf,
}

impl Files {
    fn new(tag: &str) -> (Files, String) {
        let dir = temp_dir(tag);
        let (cert_pem, key_pem) = self_signed();
        let files = Files {
            cert: dir.join("cert.pem"),
            key: dir.join("key.pem"),
            dir,
        };
        replace(&files.cert, &cert_pem);
        replace(&files.key, &key_pem);
        (files, cert_pem)
    }

    /// The certificate alone, as a client's `--ca-cert` file.
    fn ca(&self, name: &str, cert_pem: &str) -> PathBuf {
        let path = self.dir.join(name);
        std::fs::write(&path, cert_pem).unwrap();
        path
    }
}

fn tls_config(db: &str, files: &Files) -> pathfarm_server::ServerConfig {
    let mut c = config(db);
    let mut cert = ServerCert::load(&files.cert, &files.key).expect("certificate loads");
    cert.poll_interval = Duration::from_millis(50);
    c.tls = Some(Arc::new(cert));
    c
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_worker_renders_over_https_with_the_farm_s_ca_certificate() {
    let scene = cornell();
    for (store, db) in stores("tls-farm").await {
        let (files, cert_pem) = Files::new("tls-farm");
        let ca = files.ca("ca.pem", &cert_pem);
        let server = TestServer::start(tls_config(&db, &files)).await;
        assert!(
            server.url.starts_with("https://127.0.0.1:"),
            "{}",
            server.url
        );
        let client = ApiClient::with_ca_cert(&server.url, None, Some(&ca)).unwrap();
        let s = settings(24, 16, 4, 16);
        let expected = exr(&local_render(&scene, &s));
        let job = client
            .submit(scene.clone(), "cornell.gltf", &s)
            .await
            .unwrap();
        let mut wc = TestWorker::config(&server.url, None, Some(2));
        wc.ca_cert = Some(ca.clone());
        let worker = TestWorker::spawn_with(wc);
        let done = wait_final(&client, &job.id, Duration::from_secs(60)).await;
        assert!(worker.stop().await.slices >= 1);
        assert_completed(&done);
        let got = client.image_exr(&job.id, false).await.unwrap();
        assert!(
            got == expected,
            "{store}: the image differs from the local render"
        );
        server.stop().await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn clients_that_cannot_speak_to_the_server_fail_at_once_and_clearly() {
    let (files, _) = Files::new("tls-refusals");
    let db = format!("sqlite://{}", files.dir.join("farm.db").display());
    let server = TestServer::start(tls_config(&db, &files)).await;

    // Without the farm's CA certificate: a TLS error that says what to do, not worth retrying.
    let e = server.client(None).workers().await.unwrap_err();
    assert!(matches!(e, ClientError::Tls { .. }), "{e:?}");
    assert!(!e.is_transient());
    let text = e.to_string();
    assert!(
        text.contains("--ca-cert") && text.contains("certificate"),
        "{text}"
    );

    // A worker without it stops with that error instead of retrying forever.
    let t0 = Instant::now();
    let (_stop, rx) = tokio::sync::watch::channel(false);
    let run = pathfarm_worker::run(TestWorker::config(&server.url, None, None), rx);
    let e = tokio::time::timeout(Duration::from_secs(20), run)
        .await
        .expect("the worker gave up at once")
        .unwrap_err();
    assert!(e.to_string().contains("--ca-cert"), "{e}");
    assert!(t0.elapsed() < Duration::from_secs(10));

    // Plain HTTP to the TLS port: a 400 that says to use https://.
    let plain = server.url.replacen("https://", "http://", 1);
    let e = ApiClient::new(&plain, None)
        .unwrap()
        .workers()
        .await
        .unwrap_err();
    assert_eq!(e.status(), Some(reqwest::StatusCode::BAD_REQUEST), "{e:?}");
    assert!(e.to_string().contains("https://"), "{e}");
    // The server still serves TLS clients afterwards.
    let ca = files.ca("ca.pem", &std::fs::read_to_string(&files.cert).unwrap());
    let trusted = ApiClient::with_ca_cert(&server.url, None, Some(&ca)).unwrap();
    trusted.workers().await.unwrap();

    // https:// to a plain HTTP server: a TLS error too.
    let plain_server = TestServer::start(config(&format!(
        "sqlite://{}",
        files.dir.join("plain.db").display()
    )))
    .await;
    let https = plain_server.url.replacen("http://", "https://", 1);
    let e = ApiClient::new(&https, None)
        .unwrap()
        .workers()
        .await
        .unwrap_err();
    assert!(matches!(e, ClientError::Tls { .. }), "{e:?}");

    // A CA file that is missing or holds no certificate is refused when the client is made.
    for (path, what) in [
        (files.dir.join("missing.pem"), "cannot read"),
        (files.key.clone(), "no PEM certificate"),
    ] {
        let e = ApiClient::with_ca_cert(&server.url, None, Some(&path))
            .err()
            .expect("refused");
        assert!(matches!(e, SetupError::CaCert { .. }), "{e:?}");
        let text = e.to_string();
        assert!(
            text.contains("--ca-cert") && text.contains(&*path.to_string_lossy()),
            "{text}"
        );
        assert!(text.contains(what), "{text}");
    }
    plain_server.stop().await;
    server.stop().await;
}

#[test]
fn certificate_files_that_cannot_serve_are_refused_naming_the_file() {
    let (files, cert_pem) = Files::new("tls-bad-files");
    let (_, other_key) = self_signed();
    let err =
        |cert: &Path, key: &Path| -> TlsError { ServerCert::load(cert, key).expect_err("refused") };
    let missing = files.dir.join("missing.pem");
    let e = err(&missing, &files.key);
    assert_eq!(e.flag, "--tls-cert");
    assert!(e.to_string().contains(&*missing.to_string_lossy()), "{e}");
    let e = err(&files.cert, &missing);
    assert_eq!(e.flag, "--tls-key");
    // The key where the certificate should be, and the other way round.
    let e = err(&files.key, &files.key);
    assert_eq!(e.flag, "--tls-cert", "{e}");
    let e = err(&files.cert, &files.cert);
    assert_eq!(e.flag, "--tls-key", "{e}");
    // A key of another certificate.
    let stray = files.ca("stray-key.pem", &other_key);
    let e = err(&files.cert, &stray);
    assert_eq!(e.flag, "--tls-key", "{e}");
    assert!(e.to_string().contains("does not belong"), "{e}");
    assert!(
        ServerCert::load(&files.cert, &files.key).is_ok(),
        "{cert_pem}"
    );
}

/// Whether a new client trusting only `ca` gets an answer (a new client: a new connection).
async fn trusted_by(url: &str, ca: &Path) -> bool {
    let client = ApiClient::with_ca_cert(url, None, Some(ca)).unwrap();
    match client.workers().await {
        Ok(_) => true,
        Err(ClientError::Tls { .. }) => false,
        Err(e) => panic!("unexpected error: {e}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_replaced_certificate_is_served_to_new_connections_and_a_broken_one_is_not() {
    let (files, first_pem) = Files::new("tls-reload");
    let first = files.ca("first.pem", &first_pem);
    let db = format!("sqlite://{}", files.dir.join("farm.db").display());
    let server = TestServer::start(tls_config(&db, &files)).await;
    assert!(trusted_by(&server.url, &first).await);
    // A connection opened before the change keeps working after it.
    let kept = ApiClient::with_ca_cert(&server.url, None, Some(&first)).unwrap();
    kept.workers().await.unwrap();

    let (second_pem, second_key) = self_signed();
    let second = files.ca("second.pem", &second_pem);
    replace(&files.key, &second_key);
    replace(&files.cert, &second_pem);
    let t0 = Instant::now();
    while !trusted_by(&server.url, &second).await {
        assert!(t0.elapsed() < Duration::from_secs(10), "not reloaded");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(!trusted_by(&server.url, &first).await);
    kept.workers().await.unwrap();

    // A broken certificate file: the one in use stays.
    replace(&files.cert, "not a certificate\n");
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert!(trusted_by(&server.url, &second).await);
    server.stop().await;
}

/// The store over TLS: PostgreSQL with `ssl = on` (Debian's default, with its snakeoil
/// certificate) and `sslmode=require`; `verify-full` refuses that certificate, which no CA
/// vouches for.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn postgres_is_reached_over_tls_with_sslmode_require() {
    use sqlx::Connection;
    let Ok(base) = std::env::var("PATHFARM_TEST_POSTGRES_URL") else {
        eprintln!("SKIPPED: PostgreSQL over TLS (PATHFARM_TEST_POSTGRES_URL is not set)");
        return;
    };
    let with = |mode: &str| {
        let sep = if base.contains('?') { '&' } else { '?' };
        format!("{base}{sep}sslmode={mode}")
    };
    let mut conn = sqlx::PgConnection::connect(&with("require"))
        .await
        .unwrap_or_else(|e| panic!("sslmode=require (is ssl on in PostgreSQL?): {e}"));
    let (ssl,): (bool,) =
        sqlx::query_as("SELECT ssl FROM pg_stat_ssl WHERE pid = pg_backend_pid()")
            .fetch_one(&mut conn)
            .await
            .unwrap();
    assert!(ssl, "the connection is not encrypted");
    conn.close().await.unwrap();
    let e = sqlx::PgConnection::connect(&with("verify-full"))
        .await
        .expect_err("verify-full refuses a certificate no CA vouches for");
    eprintln!("verify-full: {e}");

    // The farm's store itself, over TLS.
    let db = fresh_postgres(&with("require")).await;
    let server = TestServer::start(config(&db)).await;
    let client = server.client(None);
    let job = client
        .submit(cornell(), "cornell.gltf", &settings(8, 8, 1, 8))
        .await
        .unwrap();
    let worker = TestWorker::spawn(&server.url, None, None);
    let done = wait_final(&client, &job.id, Duration::from_secs(60)).await;
    worker.stop().await;
    assert_completed(&done);
    server.stop().await;
}

/// A TLS handshake must finish within the header timeout of the accept; once it is done, the
/// connection is idle until its first request, as a plain one is from its accept (clients
/// connect ahead of need), so the header timeout does not close it while it waits.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stalled_handshake_is_let_go_and_a_finished_one_waits_for_its_first_request() {
    use rustls::pki_types::{pem::PemObject, CertificateDer, ServerName};
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let (files, cert_pem) = Files::new("tls-idle");
    let db = format!("sqlite://{}", files.dir.join("farm.db").display());
    let mut c = tls_config(&db, &files);
    c.connections.header_timeout = Duration::from_millis(300);
    c.connections.keep_alive_timeout = Duration::from_secs(30);
    let server = TestServer::start(c).await;
    let addr = server.url.trim_start_matches("https://").to_string();

    // A handshake record's first bytes, then nothing: closed at the header timeout.
    let opened = Instant::now();
    let mut stalled = tokio::net::TcpStream::connect(&addr).await.unwrap();
    stalled.write_all(&[0x16, 0x03, 0x01]).await.unwrap();
    let mut rest = Vec::new();
    tokio::time::timeout(Duration::from_secs(20), stalled.read_to_end(&mut rest))
        .await
        .expect("the stalled handshake was let go")
        .ok();
    assert!(rest.is_empty(), "{rest:?}");
    assert!(opened.elapsed() >= Duration::from_millis(300));

    // A finished handshake, then five header timeouts of silence: the request is still served.
    let mut roots = rustls::RootCertStore::empty();
    roots
        .add(CertificateDer::from_pem_slice(cert_pem.as_bytes()).unwrap())
        .unwrap();
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let client = rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .unwrap()
        .with_root_certificates(roots)
        .with_no_client_auth();
    let tcp = tokio::net::TcpStream::connect(&addr).await.unwrap();
    let mut tls = tokio_rustls::TlsConnector::from(Arc::new(client))
        .connect(ServerName::try_from("localhost").unwrap(), tcp)
        .await
        .expect("handshake");
    tokio::time::sleep(Duration::from_millis(1500)).await;
    tls.write_all(b"GET /healthz HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n")
        .await
        .unwrap();
    let mut answer = Vec::new();
    tls.read_to_end(&mut answer).await.ok();
    let answer = String::from_utf8_lossy(&answer);
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    server.stop().await;
}
