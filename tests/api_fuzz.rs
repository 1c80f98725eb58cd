//! API fuzzing against `openapi.yaml` with schemathesis: a real `pathfarm serve` (SQLite, client and
//! worker tokens) is driven with thousands of generated requests, valid and invalid, through every
//! phase (examples, coverage, fuzzing, stateful). It must never answer 5xx, and every response must
//! match the spec: status code, content type, headers and body schema.
//!
//! A small real job is submitted first and its id handed to the job and image operations, so they
//! are exercised on an existing job and not only on unknown ids.
//!
//! Every check schemathesis has (its default), through every phase, the stateful one included,
//! with one exclusion, named where it is configured: positive-data acceptance for the submission,
//! whose scene must be glTF (JSON Schema cannot say so). Two runs, because an operation takes one
//! kind of token: the client token for jobs, images and health; the worker token, with a
//! registered worker's credential, for the worker and task operations. The slice upload is left
//! out: its body is the binary PFSL format, which schemathesis cannot generate; the Rust tests and
//! a fuzz target cover it.
//!
//! schemathesis comes from PyPI (`.ci/run` installs it in a virtualenv and sets
//! `PATHFARM_SCHEMATHESIS`). Without it the test prints SKIPPED, unless
//! `PATHFARM_REQUIRE_SCHEMATHESIS=1` (CI), where it fails. Reports go to
//! `target/schemathesis/`.

mod support;

use std::net::{Ipv4Addr, TcpListener};
use std::path::PathBuf;
use std::process::{Child, Command};
use std::time::{Duration, Instant};
use support::external_tool;

const BIN: &str = env!("CARGO_BIN_EXE_pathfarm");
const SPEC: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../openapi.yaml");

struct Kill(Child);
impl Drop for Kill {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn report_dir() -> PathBuf {
    let dir = support::target_dir().join("schemathesis");
    std::fs::create_dir_all(&dir).expect("create target/schemathesis");
    dir
}

#[test]
fn the_api_never_fails_and_always_matches_its_spec() {
    let Some(st) = external_tool(
        "PATHFARM_SCHEMATHESIS",
        "schemathesis",
        "PATHFARM_REQUIRE_SCHEMATHESIS",
        "`pip install schemathesis`",
    ) else {
        return;
    };
    let port = TcpListener::bind((Ipv4Addr::LOCALHOST, 0))
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port();
    let dir = std::env::temp_dir().join(format!("pathfarm-fuzz-{}-{port}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let reports = report_dir();
    let log = std::fs::File::create(reports.join("serve.log")).expect("serve log");
    let mut cmd = Command::new(BIN);
    for (k, _) in std::env::vars() {
        if k.starts_with("PATHFARM_") {
            cmd.env_remove(k);
        }
    }
    let server = Kill(
        cmd.args([
            "serve",
            "--listen",
            &format!("127.0.0.1:{port}"),
            "--db",
            &dir.join("fuzz.db").to_string_lossy(),
            "--client-token",
            "fuzz-client",
            "--worker-token",
            "fuzz-worker",
            // Lease requests are long polls: held at most this long when there is no work,
            // well inside schemathesis' request timeout (10 s).
            "--lease-wait-seconds",
            "0.2",
        ])
        .env("RUST_LOG", "warn")
        .stdout(log.try_clone().expect("log"))
        .stderr(log)
        .spawn()
        .expect("start pathfarm serve"),
    );
    let url = format!("http://127.0.0.1:{port}");
    let deadline = Instant::now() + Duration::from_secs(30);
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(Instant::now() < deadline, "pathfarm serve did not start");
        std::thread::sleep(Duration::from_millis(50));
    }

    // Real jobs, so that the job and image operations reach more than 404s: schemathesis'
    // generated scenes are never valid glTF, so it cannot create one itself. Their ids are given
    // to those operations through schemathesis' configuration file: one job for every operation
    // but the deletion, which gets a job of its own (deleted at its first success, then 404).
    let submit = || {
        let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/cornell.gltf");
        let submitted = Command::new(BIN)
            .args([
                "submit", scene, "--width", "16", "--height", "16", "--spp", "2",
            ])
            .args(["--server", &url, "--token", "fuzz-client"])
            .output()
            .expect("pathfarm submit");
        assert!(submitted.status.success(), "submit: {submitted:?}");
        let job_id = String::from_utf8_lossy(&submitted.stdout)
            .trim()
            .to_string();
        assert!(
            job_id.len() == 32 && job_id.chars().all(|c| c.is_ascii_hexdigit()),
            "unexpected job id {job_id:?}"
        );
        job_id
    };
    let (job_id, doomed_id) = (submit(), submit());
    // A registered worker holding a lease on the job, so that the worker operations act as that
    // worker (its credential in a header) and the scene download is allowed.
    let (worker_id, credential, scene_hash) = registered_worker_with_a_lease(&url);
    // The one exclusion: a submission's scene must be glTF, which JSON Schema cannot say, so no
    // generated submission is valid and "positive data acceptance" cannot hold for it.
    std::fs::write(
        dir.join("schemathesis.toml"),
        format!(
            "[[operations]]\ninclude-tag = \"jobs\"\nexclude-operation-id = \"deleteJob\"\n\
             parameters = {{ id = \"{job_id}\" }}\n\n\
             [[operations]]\ninclude-operation-id = \"deleteJob\"\n\
             parameters = {{ id = \"{doomed_id}\" }}\n\n\
             [[operations]]\ninclude-tag = \"images\"\nparameters = {{ id = \"{job_id}\" }}\n\n\
             [[operations]]\ninclude-tag = \"workers\"\n\
             parameters = {{ id = \"{worker_id}\" }}\n\n\
             [[operations]]\ninclude-operation-id = \"getScene\"\n\
             parameters = {{ hash = \"{scene_hash}\" }}\n\n\
             [[operations]]\ninclude-operation-id = \"submitJob\"\n\
             checks.positive_data_acceptance.enabled = false\n"
        ),
    )
    .expect("write schemathesis.toml");

    // Every check (schemathesis' default; `--checks` would override the file's exclusion).
    let credential_header = format!("pathfarm-worker-credential: {credential}");
    let runs: [(&str, &str, Vec<&str>); 2] = [
        (
            "client",
            "fuzz-client",
            vec!["--exclude-tag", "workers", "--exclude-tag", "tasks"],
        ),
        (
            "worker",
            "fuzz-worker",
            vec![
                "-H",
                credential_header.as_str(),
                "--include-tag",
                "workers",
                "--include-tag",
                "tasks",
                "--exclude-operation-id",
                "uploadSlice",
            ],
        ),
    ];
    let mut failures = Vec::new();
    for (name, token, filter) in runs {
        let out = Command::new(&st)
            .args(["run", SPEC, "--url", &url])
            .args(["-H", &format!("Authorization: Bearer {token}")])
            .args(&filter)
            .args(["--max-examples", "40", "--workers", "1"])
            .args(["--generation-deterministic"])
            .env("NO_COLOR", "1")
            .env("SCHEMATHESIS_HOOKS", "")
            .current_dir(&dir)
            .output()
            .expect("run schemathesis");
        let text = format!(
            "{}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        std::fs::write(reports.join(format!("{name}.txt")), &text).expect("write the report");
        let summary: String = text
            .lines()
            .skip_while(|l| !l.contains("SUMMARY"))
            .collect::<Vec<_>>()
            .join("\n");
        eprintln!("schemathesis ({name} token):\n{summary}");
        // Something must have been tested: a run that generated nothing proves nothing.
        assert!(
            text.contains("generated") && !text.contains(" 0 generated"),
            "{name}: schemathesis generated no test cases:\n{text}"
        );
        if !out.status.success() {
            failures.push(format!("{name} token run failed ({}):\n{text}", out.status));
        }
    }
    drop(server);
    let _ = std::fs::remove_dir_all(&dir);
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}

/// Registers a worker and leases a task for it: its id, its credential and the leased job's
/// scene hash.
fn registered_worker_with_a_lease(url: &str) -> (String, String, String) {
    pathfarm_worker::client::install_crypto_provider();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("a runtime");
    runtime.block_on(async {
        let client = pathfarm_worker::client::ApiClient::new(url, Some("fuzz-worker".into()))
            .expect("a client");
        let reg = client
            .register(&pathfarm_wire::api::WorkerRegistration {
                name: "fuzz".into(),
                threads: 1,
                version: "fuzz".into(),
                host: "fuzz".into(),
            })
            .await
            .expect("register");
        let lease = client
            .lease(&reg.worker_id)
            .await
            .expect("lease")
            .expect("a task to lease");
        (reg.worker_id, reg.credential, lease.scene_hash)
    })
}
