//! The contract works for generated clients: a Python client is generated from `openapi.yaml` with
//! `openapi-python-client` (pinned in `.ci/run`), which must print no warning (every operation,
//! body and response generated), and `tests/generated_client/drive.py` drives a whole job with
//! it against a real `pathfarm serve` and `pathfarm worker`: submit (optional settings left to
//! the server), pause, resume, priority, poll, convergence, both downloads revalidated with
//! `If-None-Match` (each representation its own `ETag`), workers, cancel, delete, and a refused
//! submission read as the error body. The image it downloads must be byte-identical to a local
//! `pathfarm render` with the same settings.
//!
//! `.ci/run` installs the generator in a virtualenv and sets `PATHFARM_OPENAPI_PYTHON_CLIENT`;
//! the drive script runs with that virtualenv's Python (which has the client's dependencies,
//! httpx and attrs). Without the generator the test prints SKIPPED, unless
//! `PATHFARM_REQUIRE_OPENAPI_PYTHON_CLIENT=1` (CI), where it fails.

mod support;

use std::path::{Path, PathBuf};
use std::process::Command;
use support::*;

const SPEC: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../openapi.yaml");
const DRIVE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../tests/generated_client/drive.py"
);

/// The Python of the generator's virtualenv (`python3` on PATH when it has none).
fn python_beside(exe: &Path) -> PathBuf {
    exe.parent()
        .map(|bin| bin.join("python"))
        .filter(|p| p.exists())
        .unwrap_or_else(|| PathBuf::from("python3"))
}

/// Generates the client into `dir` and returns the package's parent folder; panics on any
/// warning, naming it.
fn generate(exe: &Path, dir: &TestDir) -> PathBuf {
    let config = dir.path("generator.yaml");
    // No post-processing hooks (ruff): the generated code is used as generated.
    std::fs::write(&config, "post_hooks: []\n").expect("write the generator's config");
    let out = Command::new(exe)
        .args(["generate", "--path", SPEC, "--config"])
        .arg(&config)
        .arg("--output-path")
        .arg(dir.path("client"))
        .output()
        .expect("run openapi-python-client");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "the generator failed:\n{text}");
    assert!(
        !text.to_ascii_lowercase().contains("warning"),
        "the generator warned about openapi.yaml:\n{text}"
    );
    let package = dir.path("client").join("pathfarm_client");
    assert!(
        package
            .join("api")
            .join("tasks")
            .join("upload_slice.py")
            .exists()
            && package
                .join("api")
                .join("images")
                .join("get_job_image_exr.py")
                .exists(),
        "the generated client lacks an operation:\n{text}"
    );
    dir.path("client")
}

#[tokio::test(flavor = "multi_thread")]
async fn a_generated_python_client_drives_a_whole_job() {
    let Some(exe) = external_tool(
        "PATHFARM_OPENAPI_PYTHON_CLIENT",
        "openapi-python-client",
        "PATHFARM_REQUIRE_OPENAPI_PYTHON_CLIENT",
        "`pip install openapi-python-client`",
    ) else {
        return;
    };
    let python = python_beside(&exe);
    let farm = Farm::new("generated-client");
    let client_root = generate(&exe, &farm.dir);
    let _server = farm.serve("serve", &[]).await;
    let _worker = farm.worker("py-w", 16);
    let reference = render_reference(
        &farm.dir,
        "reference.exr",
        &["--width", "48", "--height", "48", "--spp", "1024"],
    );

    let out_dir = farm.dir.path("out");
    std::fs::create_dir_all(&out_dir).expect("create the output folder");
    let drive = tokio::process::Command::new(&python)
        .arg(DRIVE)
        .arg(&farm.url)
        .arg(SCENE)
        .arg(&out_dir)
        .env("PYTHONPATH", &client_root)
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .kill_on_drop(true)
        .output();
    let out = tokio::time::timeout(std::time::Duration::from_secs(300), drive)
        .await
        .expect("drive.py did not finish within 300 s")
        .expect("run drive.py");
    assert_success(&out, "drive.py (the generated client)");

    let summary: serde_json::Value = serde_json::from_slice(
        &std::fs::read(out_dir.join("summary.json")).expect("drive.py's summary"),
    )
    .expect("summary.json is JSON");
    assert_eq!(summary["samples_done"], 48 * 48 * 1024, "{summary}");
    assert_eq!(summary["workers"], serde_json::json!(["py-w"]), "{summary}");
    let tags = summary["etags"].as_array().expect("etags");
    assert_eq!(tags.len(), 3);
    assert!(
        tags[0] != tags[1] && tags[1] != tags[2] && tags[0] != tags[2],
        "{summary}"
    );

    let downloaded = std::fs::read(out_dir.join("image.exr")).expect("the downloaded image");
    let local = reference.await.expect("the local render");
    assert_same_bytes(&downloaded, &local, "the generated client's download");
}
