//! TLS terminated by a reverse proxy, as `docker/compose.yaml` deploys the farm: Debian's nginx
//! running the shipped `docker/nginx.conf` (its upstreams pointed at this test's servers, its
//! `listen` given `ssl` and a self-signed certificate the test makes), two `pathfarm serve`
//! behind it on one PostgreSQL database, with the client and worker tokens compose requires, and
//! two workers and the CLI that reach the farm only through `https://` and the proxy.
//!
//! Needs nginx (`/usr/sbin/nginx`, or `PATHFARM_NGINX`). Elsewhere it prints `SKIPPED`; with
//! `PATHFARM_REQUIRE_NGINX=1` (CI installs nginx) it fails instead. Without
//! `PATHFARM_TEST_POSTGRES_URL` one server on SQLite stands behind the proxy.

mod support;

use pathfarm_testkit::harness::PgDatabase;
use pathfarm_worker::client::ApiClient;
use std::path::{Path, PathBuf};
use std::time::Duration;
use support::*;

/// The nginx binary to run, or why there is none.
fn nginx() -> Result<PathBuf, String> {
    let path = std::env::var_os("PATHFARM_NGINX")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/sbin/nginx"));
    match std::process::Command::new(&path).arg("-v").output() {
        Ok(out) if out.status.success() => Ok(path),
        Ok(out) => Err(format!("{} -v exited with {}", path.display(), out.status)),
        Err(e) => Err(format!("cannot run {}: {e}", path.display())),
    }
}

/// `docker/nginx.conf` made to run here: its upstream servers replaced by `upstreams`, its
/// `listen 8080;` by a TLS listener on `port` with `cert` and `key`, and its logs and temporary
/// files under `dir` (each access logged with the upstream that answered it). Every piece of the
/// shipped file this relies on is checked to be there, so a change to the file fails here by
/// name rather than testing something else.
fn proxy_config(dir: &TestDir, upstreams: &[u16], port: u16, cert: &Path, key: &Path) -> String {
    let shipped = concat!(env!("CARGO_MANIFEST_DIR"), "/../../docker/nginx.conf");
    let text = std::fs::read_to_string(shipped).expect("read docker/nginx.conf");
    let swap = |text: String, from: &str, to: &str| {
        assert!(
            text.contains(from),
            "docker/nginx.conf no longer has {from:?}: update this test with it"
        );
        text.replacen(from, to, 1)
    };
    let servers: String = upstreams
        .iter()
        .map(|p| format!("server 127.0.0.1:{p};\n        "))
        .collect();
    let text = swap(
        text,
        "server server-a:8080;\n        server server-b:8080;\n        ",
        &servers,
    );
    let listen = format!(
        "listen 127.0.0.1:{port} ssl;\n        ssl_certificate {};\n        \
         ssl_certificate_key {};",
        cert.display(),
        key.display()
    );
    let text = swap(text, "listen 8080;", &listen);
    let logs = format!(
        "http {{\n    log_format upstream '$request_method $uri $status $upstream_addr';\n    \
         access_log {} upstream;\n    client_body_temp_path {};\n    proxy_temp_path {};\n    \
         fastcgi_temp_path {};\n    uwsgi_temp_path {};\n    scgi_temp_path {};\n",
        dir.arg("access.log"),
        dir.arg("client_body_temp"),
        dir.arg("proxy_temp"),
        dir.arg("fastcgi_temp"),
        dir.arg("uwsgi_temp"),
        dir.arg("scgi_temp"),
    );
    swap(text, "http {\n", &logs)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tls_terminating_proxy_in_front_of_two_servers_renders_a_job_bit_identical() {
    let nginx = match nginx() {
        Ok(path) => path,
        Err(why) => {
            if std::env::var_os("PATHFARM_REQUIRE_NGINX").is_some_and(|v| v == "1") {
                panic!("PATHFARM_REQUIRE_NGINX=1 but nginx cannot run: {why}");
            }
            eprintln!("SKIPPED: the TLS proxy test needs nginx ({why})");
            return;
        }
    };
    let dir = TestDir::new("tls-proxy");
    let (client_token, worker_token) = ("client-secret-tls-proxy", "worker-secret-tls-proxy");

    // Two servers on one PostgreSQL database, as compose runs them (one on SQLite without one).
    let pg = match std::env::var("PATHFARM_TEST_POSTGRES_URL") {
        Ok(admin) => Some(
            PgDatabase::create(&admin, "pathfarm_tls_proxy")
                .await
                .expect("a PostgreSQL database"),
        ),
        Err(_) => None,
    };
    let db = pg
        .as_ref()
        .map_or_else(|| dir.arg("farm.db"), |p| p.url.clone());
    let names: &[&str] = if pg.is_some() {
        &["server-a", "server-b"]
    } else {
        &["server-a"]
    };
    let mut servers = Vec::new();
    let mut ports = Vec::new();
    for name in names {
        let port = free_port();
        let listen = format!("127.0.0.1:{port}");
        let mut server = Proc::start(
            name,
            &dir,
            &[
                "serve",
                "--listen",
                &listen,
                "--db",
                &db,
                "--client-token",
                client_token,
                "--worker-token",
                worker_token,
            ],
        );
        wait_healthy(port, &mut server).await;
        servers.push(server);
        ports.push(port);
    }

    // nginx terminates TLS with a certificate the servers never see.
    let cert = rcgen::generate_simple_self_signed(vec!["localhost".into(), "127.0.0.1".into()])
        .expect("certificate");
    let (cert_path, key_path, ca) = (dir.path("cert.pem"), dir.path("key.pem"), dir.arg("ca.pem"));
    std::fs::write(&cert_path, cert.cert.pem()).expect("write cert.pem");
    std::fs::write(&key_path, cert.signing_key.serialize_pem()).expect("write key.pem");
    std::fs::write(&ca, cert.cert.pem()).expect("write ca.pem");
    let lb_port = free_port();
    let conf = dir.path("nginx.conf");
    std::fs::write(
        &conf,
        proxy_config(&dir, &ports, lb_port, &cert_path, &key_path),
    )
    .expect("write nginx.conf");
    let pid_file = dir.arg("nginx.pid");
    let mut cmd = std::process::Command::new(&nginx);
    cmd.arg("-p")
        .arg(&dir.0)
        .arg("-e")
        .arg(dir.path("error.log"))
        .arg("-c")
        .arg(&conf)
        .arg("-g")
        .arg(format!("daemon off; pid {pid_file};"));
    // Its group: nginx's own worker processes go with it.
    let _lb = Proc::spawn("nginx", &dir, cmd, true);

    let url = format!("https://127.0.0.1:{lb_port}");
    let client = ApiClient::with_ca_cert(&url, Some(client_token.into()), Some(Path::new(&ca)))
        .expect("client");
    let error_log = || std::fs::read_to_string(dir.path("error.log")).unwrap_or_default();
    poll("the proxy to answer", Duration::from_secs(30), || async {
        client.workers().await.ok()
    })
    .await;
    // The proxy is the only way in that the workers and the CLI are given; plain HTTP to its TLS
    // port is refused by nginx (a 400 page, not a job).
    assert_eq!(healthz_status(lb_port), Some(400), "{}", error_log());

    let settings = ["--width", "32", "--height", "24", "--spp", "8"];
    let reference = render_reference(&dir, "reference.exr", &settings);
    let mut worker_procs = Vec::new();
    for name in ["worker-a", "worker-b"] {
        let cache = dir.arg(&format!("cache-{name}"));
        worker_procs.push(Proc::start(
            name,
            &dir,
            &[
                "worker",
                "--server",
                &url,
                "--ca-cert",
                &ca,
                "--token",
                worker_token,
                "--threads",
                "1",
                "--slice-samples",
                "2",
                "--cache-dir",
                &cache,
                "--name",
                name,
            ],
        ));
    }
    let out_path = dir.arg("farm.exr");
    let mut submit_args = vec!["submit", SCENE, "--server", &url, "--ca-cert", &ca];
    submit_args.extend([
        "--token",
        client_token,
        "--wait",
        "--out",
        &out_path,
        "--tile",
        "16",
    ]);
    submit_args.extend_from_slice(&settings);
    let out = run_cli(&dir, &submit_args, Duration::from_secs(120)).await;
    assert_success(&out, "pathfarm submit --wait over the TLS proxy");
    assert_same_bytes(
        &std::fs::read(&out_path).expect("read farm.exr"),
        &reference.await.expect("reference"),
        "the image through the TLS proxy",
    );

    // Both workers registered through the proxy; with two servers, each answered some of the
    // workers' leases and slice uploads (nginx's round robin).
    let listed = workers(&client).await;
    for name in ["worker-a", "worker-b"] {
        assert!(
            named(&listed, name).is_some(),
            "{name} not listed: {listed:?}"
        );
    }
    let access = std::fs::read_to_string(dir.path("access.log")).expect("read access.log");
    for &port in &ports {
        let upstream = format!("127.0.0.1:{port}");
        let served = access
            .lines()
            .filter(|l| l.starts_with("POST") && l.contains(" 200 ") && l.ends_with(&upstream))
            .filter(|l| l.contains("/lease ") || l.contains("/slices "))
            .count();
        assert!(
            served > 0,
            "no lease or slice answered by {upstream} through nginx:\n{access}"
        );
    }
    for w in &mut worker_procs {
        assert!(w.is_running(), "{} exited:\n{}", w.name, w.log_text());
    }
    for s in &mut servers {
        assert!(s.is_running(), "{} exited:\n{}", s.name, s.log_text());
    }
}
