//! The web dashboard in a real headless browser (Debian's chromium driven by chromedriver over
//! WebDriver, through `fantoccini`) against a real `pathfarm up` farm: submit the Cornell box
//! through the form, watch the progress image change and the convergence chart grow while it
//! renders, switch to the heat maps, cancel a second job from the jobs page, see the first one
//! complete, see the workers (and one of them lost after it is killed), refuse a broken scene with
//! the server's message next to the form, and the same with a token-protected server whose token
//! the page asks for once.
//!
//! The assertions read the DOM (states, texts, the preview's object URL, the charts'
//! `data-points`) and the API; screenshots of every page land in `target/dashboard-screenshots/`
//! for people. Without `/usr/bin/chromium` and `/usr/bin/chromedriver` (or the paths in
//! `PATHFARM_CHROMIUM` and `PATHFARM_CHROMEDRIVER`) the tests print `SKIPPED` and pass, unless
//! `PATHFARM_REQUIRE_BROWSER=1` (`.ci/run` sets it), where they fail.
//!
//! Child processes (the farm, chromedriver and its chromium) run in process groups of their own,
//! killed when their guard is dropped, so a failing test leaves nothing running.

mod support;

use fantoccini::{Client, ClientBuilder, Locator};
use pathfarm_wire::api::{JobSettings, JobState, WorkerState};
use pathfarm_worker::client::ApiClient;
use serde_json::{json, Value};
use std::collections::BTreeSet;
use std::future::Future;
use std::io::{Read, Write};
use std::net::{Ipv4Addr, SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};
use support::{command, free_port, processes_with_args, Proc, TestDir, SCENE};

/// Debian's packages (`chromium`, `chromium-driver`); `PATHFARM_CHROMIUM` and
/// `PATHFARM_CHROMEDRIVER` point elsewhere.
fn chromium() -> String {
    std::env::var("PATHFARM_CHROMIUM").unwrap_or_else(|_| "/usr/bin/chromium".into())
}

fn chromedriver() -> String {
    std::env::var("PATHFARM_CHROMEDRIVER").unwrap_or_else(|_| "/usr/bin/chromedriver".into())
}

/// The render the form submits: long enough on two single-thread workers of a slow 2-core machine
/// to watch several merges (~10 s), short enough to keep the test quick.
const WIDTH: u32 = 128;
const HEIGHT: u32 = 128;
const SPP: u32 = 640;

/// One browser and one farm at a time: they share two cores, and the timings above assume it.
static SERIAL: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// Whether the browser is installed; without it, `SKIPPED` (or a failure when it is required).
fn browser_installed() -> bool {
    let missing: Vec<String> = [chromium(), chromedriver()]
        .into_iter()
        .filter(|p| !Path::new(p).exists())
        .collect();
    if missing.is_empty() {
        return true;
    }
    let required = std::env::var("PATHFARM_REQUIRE_BROWSER").is_ok_and(|v| v == "1");
    assert!(
        !required,
        "PATHFARM_REQUIRE_BROWSER=1 but not installed: {} (apt-get install chromium chromium-driver)",
        missing.join(" and ")
    );
    println!(
        "SKIPPED: the dashboard browser test needs {} (apt-get install chromium chromium-driver)",
        missing.join(" and ")
    );
    false
}

/// The status code of `GET PATH` (a bare HTTP/1.1 request), or `None` without an answer.
fn http_status(port: u16, path: &str) -> Option<u16> {
    let addr = SocketAddr::from((Ipv4Addr::LOCALHOST, port));
    let mut s = TcpStream::connect_timeout(&addr, Duration::from_secs(1)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    // Only the status line: chromedriver keeps the connection open despite `Connection: close`.
    let mut answer = Vec::new();
    let mut buf = [0u8; 256];
    while !answer.windows(2).any(|w| w == b"\r\n") {
        let n = s.read(&mut buf).ok()?;
        if n == 0 {
            break;
        }
        answer.extend_from_slice(&buf[..n]);
    }
    String::from_utf8_lossy(&answer)
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()
}

/// Waits (30 s at most) until `GET PATH` answers 200; fails early if `proc` exits.
async fn wait_http_ok(port: u16, path: &'static str, proc: &mut Proc) {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let status = tokio::task::spawn_blocking(move || http_status(port, path))
            .await
            .expect("HTTP probe");
        if status == Some(200) {
            return;
        }
        assert!(
            proc.is_running(),
            "{} exited before it answered; its log:\n{}",
            proc.name,
            proc.log_text()
        );
        assert!(
            Instant::now() < deadline,
            "{} did not answer {path} within 30 s (last answer {status:?})",
            proc.name
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// Calls `check` every 100 ms until it returns `Some`; panics after `timeout`, naming `what`.
async fn until<T, F, Fut>(what: &str, timeout: Duration, mut check: F) -> T
where
    F: FnMut() -> Fut,
    Fut: Future<Output = Option<T>>,
{
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(v) = check().await {
            return v;
        }
        assert!(
            Instant::now() < deadline,
            "timed out after {timeout:?} waiting for {what}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// Where screenshots go: `target/dashboard-screenshots/` (the target directory of this build).
fn screenshot_dir() -> PathBuf {
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .or_else(|| {
            // target/<profile>/deps/dashboard-<hash>
            let exe = std::env::current_exe().ok()?;
            Some(exe.parent()?.parent()?.parent()?.to_path_buf())
        })
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../target")));
    let dir = target.join("dashboard-screenshots");
    std::fs::create_dir_all(&dir).expect("create the screenshot directory");
    dir
}

/// A headless chromium session, driven over WebDriver.
struct Browser {
    client: Client,
    /// chromedriver, and chromium in its process group.
    _driver: Proc,
    variant: &'static str,
    shots: PathBuf,
}

impl Browser {
    async fn start(dir: &TestDir, variant: &'static str) -> Browser {
        let port = free_port();
        let mut cmd = Command::new(chromedriver());
        cmd.arg(format!("--port={port}"));
        let mut driver = Proc::spawn("chromedriver", dir, cmd, true);
        wait_http_ok(port, "/status", &mut driver).await;
        let profile = dir.arg("chromium-profile");
        let caps = json!({
            "browserName": "chrome",
            "goog:chromeOptions": {
                "binary": chromium(),
                "args": [
                    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                    "--no-first-run", "--disable-background-networking",
                    "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage",
                    "--window-size=1280,800", format!("--user-data-dir={profile}"),
                ],
            },
        });
        let Value::Object(caps) = caps else {
            unreachable!("a JSON object")
        };
        // Plain HTTP to the local chromedriver: no TLS stack needed.
        let connector = hyper_util::client::legacy::connect::HttpConnector::new();
        let client = ClientBuilder::new(connector)
            .capabilities(caps)
            .connect(&format!("http://127.0.0.1:{port}"))
            .await
            .unwrap_or_else(|e| {
                panic!(
                    "cannot start a chromium session: {e}\nchromedriver log:\n{}",
                    driver.log_text()
                )
            });
        Browser {
            client,
            _driver: driver,
            variant,
            shots: screenshot_dir(),
        }
    }

    async fn goto(&self, url: &str) {
        self.client.goto(url).await.expect("navigate");
    }

    async fn find(&self, css: &str) -> fantoccini::elements::Element {
        self.client
            .wait()
            .at_most(Duration::from_secs(20))
            .for_element(Locator::Css(css))
            .await
            .unwrap_or_else(|e| panic!("no element {css:?} on the page: {e}"))
    }

    async fn click(&self, css: &str) {
        self.find(css)
            .await
            .click()
            .await
            .unwrap_or_else(|e| panic!("cannot click {css:?}: {e}"));
    }

    /// Replaces the value of the input `css` with `text`, as a user typing would.
    async fn type_into(&self, css: &str, text: &str) {
        let e = self.find(css).await;
        e.clear().await.expect("clear an input");
        e.send_keys(text).await.expect("type into an input");
    }

    /// Runs `script` (a function body; `arguments[i]` are `args`) in the page.
    async fn js(&self, script: &str, args: Vec<Value>) -> Value {
        self.client
            .execute(script, args)
            .await
            .unwrap_or_else(|e| panic!("script failed: {e}\n{script}"))
    }

    /// The text of the first element matching `css`, or `None` when there is none.
    async fn text(&self, css: &str) -> Option<String> {
        let v = self
            .js(
                "const e = document.querySelector(arguments[0]); return e ? e.textContent.trim() : null;",
                vec![json!(css)],
            )
            .await;
        v.as_str().map(str::to_string)
    }

    async fn hash(&self) -> String {
        let v = self.js("return location.hash;", vec![]).await;
        v.as_str().unwrap_or_default().to_string()
    }

    /// Waits until the text of `css` satisfies `ok`; returns it.
    async fn wait_text(&self, what: &str, css: &str, ok: impl Fn(&str) -> bool) -> String {
        let mut last = None;
        let found = tokio::time::timeout(Duration::from_secs(60), async {
            loop {
                let t = self.text(css).await;
                if let Some(t) = t.as_deref().filter(|t| ok(t)) {
                    return t.to_string();
                }
                last = t;
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        })
        .await;
        found.unwrap_or_else(|_| panic!("timed out waiting for {what} ({css}); last text {last:?}"))
    }

    async fn dialog_open(&self, id: &str) -> bool {
        self.js(
            "const d = document.getElementById(arguments[0]); return !!(d && d.open);",
            vec![json!(id)],
        )
        .await
            == json!(true)
    }

    /// The error notices the page showed (a failed API call is shown there).
    async fn error_notice(&self) -> Option<String> {
        let v = self
            .js(
                "const n = document.getElementById('notice'); \
                 return n.dataset.kind === 'error' && n.textContent ? n.textContent : null;",
                vec![],
            )
            .await;
        v.as_str().map(str::to_string)
    }

    async fn screenshot(&self, name: &str) {
        let png = self.client.screenshot().await.expect("screenshot");
        let path = self.shots.join(format!("{}-{name}.png", self.variant));
        std::fs::write(&path, png).expect("write a screenshot");
    }

    /// Whether the page is wider than the window (a horizontal scroll bar).
    async fn overflows(&self) -> bool {
        self.js(
            "return document.documentElement.scrollWidth > window.innerWidth + 1;",
            vec![],
        )
        .await
            == json!(true)
    }
}

/// What the job page shows right now (read in one round trip).
#[derive(Debug)]
struct JobPage {
    state: String,
    src: String,
    /// The preview's decoded picture is on screen (loaded, with pixels): never a blank frame.
    painted: bool,
    view: String,
    error_points: u64,
    rate_points: u64,
}

async fn job_page(b: &Browser) -> JobPage {
    let v = b
        .js(
            r#"const q = (s) => document.querySelector(s);
               const img = q('[data-testid="preview-image"]');
               return {
                 state: q('[data-testid="job-state"]')?.textContent ?? '',
                 src: img?.getAttribute('src') ?? '',
                 painted: !!img && img.complete && img.naturalWidth > 0,
                 view: img?.dataset.view ?? '',
                 error_points: Number(q('[data-testid="error-chart"]')?.dataset.points ?? 0),
                 rate_points: Number(q('[data-testid="rate-chart"]')?.dataset.points ?? 0),
               };"#,
            vec![],
        )
        .await;
    JobPage {
        state: v["state"].as_str().unwrap_or_default().to_string(),
        src: v["src"].as_str().unwrap_or_default().to_string(),
        painted: v["painted"] == json!(true),
        view: v["view"].as_str().unwrap_or_default().to_string(),
        error_points: v["error_points"].as_u64().unwrap_or(0),
        rate_points: v["rate_points"].as_u64().unwrap_or(0),
    }
}

/// The whole flow against `pathfarm up`, with tokens when `tokens` is `(client, worker)`.
async fn dashboard_flow(variant: &'static str, tokens: Option<(&str, &str)>) {
    let _one_at_a_time = SERIAL.lock().await;
    if !browser_installed() {
        return;
    }
    let started = Instant::now();
    let dir = TestDir::new(variant);
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let (port_arg, db) = (port.to_string(), dir.arg("farm.db"));
    // Short leases, so a killed worker is shown as lost within seconds.
    let mut args = vec![
        "up",
        "--workers",
        "2",
        "--port",
        &port_arg,
        "--db",
        &db,
        "--lease-seconds",
        "3",
    ];
    if let Some((client, worker)) = tokens {
        args.extend(["--client-token", client, "--worker-token", worker]);
    }
    let mut cmd = command(&dir);
    cmd.args(&args);
    let mut up = Proc::spawn("up", &dir, cmd, true);
    wait_http_ok(port, "/healthz", &mut up).await;
    let api = ApiClient::new(&url, tokens.map(|(c, _)| c.to_string())).expect("API client");
    let b = Browser::start(&dir, variant).await;

    // ---- the page loads from the binary; with tokens it asks for one, once
    b.goto(&format!("{url}/#/jobs")).await;
    if let Some((client_token, _)) = tokens {
        until("the token prompt", Duration::from_secs(20), || async {
            b.dialog_open("token-dialog").await.then_some(())
        })
        .await;
        b.screenshot("token-prompt").await;
        // A wrong token is refused and asked for again.
        b.type_into("#token-input", "not-the-token").await;
        b.click("[data-testid=token-save]").await;
        b.wait_text("the refused-token prompt", "#token-reason", |t| {
            t.contains("refused")
        })
        .await;
        assert!(
            b.dialog_open("token-dialog").await,
            "the prompt closed on a wrong token"
        );
        b.type_into("#token-input", client_token).await;
        b.click("[data-testid=token-save]").await;
        // The dialog's `close` event, which stores the token, comes a moment after it closes.
        until(
            "the token kept in local storage",
            Duration::from_secs(20),
            || async {
                let kept = b
                    .js("return localStorage.getItem('pathfarm-token');", vec![])
                    .await;
                (kept == json!(client_token) && !b.dialog_open("token-dialog").await).then_some(())
            },
        )
        .await;
    }
    b.wait_text("the empty jobs list", "[data-testid=jobs-count]", |t| {
        t == "0 jobs"
    })
    .await;
    b.screenshot("jobs-empty").await;

    // ---- a broken scene: the server's 422 message next to the form, no job
    let broken = dir.path("broken.gltf");
    std::fs::write(&broken, "{\"asset\":").expect("write broken.gltf");
    b.click("nav a[data-nav=submit]").await;
    b.find("[data-testid=submit-form]").await;
    b.find("#scene")
        .await
        .send_keys(&broken.to_string_lossy())
        .await
        .expect("choose broken.gltf");
    b.click("[data-testid=submit-button]").await;
    let message = b
        .wait_text(
            "the broken scene's error",
            "[data-testid=submit-error]",
            |t| !t.is_empty(),
        )
        .await;
    assert!(
        message.contains("invalid_scene") && message.contains("cannot be loaded"),
        "the form shows {message:?}, not the server's invalid_scene message"
    );
    assert!(
        b.js(
            "return !document.querySelector('[data-testid=submit-error]').hidden;",
            vec![]
        )
        .await
            == json!(true),
        "the error is hidden"
    );
    assert_eq!(b.hash().await, "#/submit", "a refused scene left the form");
    b.screenshot("submit-broken-scene").await;
    let jobs = api.jobs(None, 1, 10).await.expect("GET /jobs");
    assert_eq!(jobs.total, 0, "a broken scene created a job: {jobs:?}");

    // ---- the Cornell box through the form
    b.client.refresh().await.expect("reload the form");
    b.find("[data-testid=submit-form]").await;
    let name = format!("cornell-{variant}");
    b.type_into("#name", &name).await;
    b.type_into("#width", &WIDTH.to_string()).await;
    b.type_into("#height", &HEIGHT.to_string()).await;
    b.type_into("#spp", &SPP.to_string()).await;
    b.type_into("#seed", "7").await;
    b.type_into("#priority", "5").await;
    b.find("#direct")
        .await
        .select_by_value("mis")
        .await
        .expect("choose MIS");
    // A uniform environment, white at strength 0.5.
    b.click("[data-testid=submit-environment-section] summary")
        .await;
    b.find("#env_kind")
        .await
        .select_by_value("uniform")
        .await
        .expect("choose a uniform environment");
    b.type_into("#env_strength", "0.5").await;
    let scene = std::fs::canonicalize(SCENE).expect("scenes/cornell.gltf");
    b.find("#scene")
        .await
        .send_keys(&scene.to_string_lossy())
        .await
        .expect("choose the Cornell box");
    b.screenshot("submit").await;
    b.click("[data-testid=submit-button]").await;
    let hash = until(
        "the job page after submitting",
        Duration::from_secs(30),
        || async {
            let h = b.hash().await;
            h.strip_prefix("#/jobs/").map(str::to_string)
        },
    )
    .await;
    let id1 = hash;
    let job1 = api.job(&id1).await.expect("GET the submitted job");
    assert_eq!(job1.name, name);
    assert_eq!(
        (
            job1.settings.width,
            job1.settings.height,
            job1.settings.spp,
            job1.settings.seed
        ),
        (WIDTH, HEIGHT, SPP, 7),
        "the form's settings: {:?}",
        job1.settings
    );
    assert_eq!(job1.priority, 5);
    let env = job1
        .settings
        .environment
        .as_ref()
        .expect("the form's environment");
    assert_eq!(
        (
            env.radiance,
            env.image.as_deref(),
            env.strength,
            env.rotation_degrees
        ),
        (Some([1.0, 1.0, 1.0]), None, 0.5, 0.0),
        "{env:?}"
    );
    b.wait_text("the job's name", "[data-testid=job-title]", |t| t == name)
        .await;
    b.wait_text(
        "the job's environment",
        "[data-testid=job-environment]",
        |t| t == "uniform 1, 1, 1, strength 0.5",
    )
    .await;

    // A second job, below the first in priority so it waits in the queue; cancelled later.
    let mut settings = JobSettings::new(WIDTH, HEIGHT, 4096);
    settings.name = Some(format!("second-{variant}"));
    settings.priority = -1;
    let scene_bytes = std::fs::read(&scene).expect("read the scene");
    let id2 = api
        .submit(scene_bytes, "cornell.gltf", &settings)
        .await
        .expect("submit the second job")
        .id;

    // ---- the job page while the job renders: the image changes (a new object URL, decoded
    // before it is shown), the convergence chart gains points
    let mut srcs = BTreeSet::new();
    let mut points_seen = BTreeSet::new();
    let mut saw_running = false;
    let mut shot = false;
    let watch_deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let p = job_page(&b).await;
        if !p.src.is_empty() {
            assert!(p.src.starts_with("blob:"), "preview src {:?}", p.src);
            assert!(p.painted, "a blank preview frame: {p:?}");
            if p.state == "running" {
                srcs.insert(p.src.clone());
                if p.error_points > 0 {
                    points_seen.insert(p.error_points);
                }
                saw_running = true;
            }
        }
        if !shot && srcs.len() >= 2 && p.error_points >= 2 {
            b.screenshot("job-running").await;
            shot = true;
        }
        if srcs.len() >= 3 && points_seen.len() >= 2 {
            break;
        }
        assert!(
            p.state == "queued" || p.state == "running" || p.state.is_empty(),
            "the job left the running state before the page saw it render: {p:?}, \
             {} distinct images, chart points seen {points_seen:?}",
            srcs.len()
        );
        assert!(
            Instant::now() < watch_deadline,
            "the progress image changed {} times and the chart showed {points_seen:?} points \
             while running (last: {p:?})",
            srcs.len()
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(saw_running);
    assert!(
        b.error_notice().await.is_none(),
        "{:?}",
        b.error_notice().await
    );

    // The heat maps: sample counts and noise, each with its scale from the response headers.
    for view in ["samples", "noise"] {
        b.click(&format!("[data-testid=view-{view}]")).await;
        until(
            &format!("the {view} heat map"),
            Duration::from_secs(20),
            || async {
                let p = job_page(&b).await;
                (p.view == view && p.painted).then_some(())
            },
        )
        .await;
        let max = b
            .wait_text(
                &format!("the {view} legend"),
                "[data-testid=legend-max]",
                |t| !t.is_empty(),
            )
            .await;
        let legend_shown = b
            .js(
                "return !document.querySelector('[data-testid=legend]').hidden;",
                vec![],
            )
            .await;
        assert_eq!(
            legend_shown,
            json!(true),
            "{view} legend hidden (max {max})"
        );
        b.screenshot(&format!("job-{view}")).await;
    }
    b.click("[data-testid=view-image]").await;

    // ---- the jobs page: cancel the second job through its button and the confirmation
    b.click("nav a[data-nav=jobs]").await;
    let row2 = format!("tr[data-job-id=\"{id2}\"]");
    b.find(&row2).await;
    let state2 = b
        .text(&format!("{row2} [data-testid=job-state]"))
        .await
        .unwrap_or_default();
    assert!(
        state2 == "queued" || state2 == "running",
        "second job {state2}"
    );
    // Its priority, typed into its field (Enter sends it), then pause and resume.
    b.type_into(&format!("{row2} input[data-testid=priority]"), "-3\u{E007}")
        .await;
    until("the new priority", Duration::from_secs(20), || async {
        let j = api.job(&id2).await.ok()?;
        (j.priority == -3).then_some(())
    })
    .await;
    b.click(&format!("{row2} button[data-action=pause]")).await;
    b.wait_text(
        "the second job paused",
        &format!("{row2} [data-testid=job-state]"),
        |t| t == "paused",
    )
    .await;
    b.click(&format!("{row2} button[data-action=resume]")).await;
    b.wait_text(
        "the second job resumed",
        &format!("{row2} [data-testid=job-state]"),
        |t| t == "queued" || t == "running",
    )
    .await;
    b.click(&format!("{row2} button[data-action=cancel]")).await;
    until("the confirmation", Duration::from_secs(10), || async {
        b.dialog_open("confirm-dialog").await.then_some(())
    })
    .await;
    b.screenshot("jobs-confirm-cancel").await;
    b.click("[data-testid=confirm-yes]").await;
    b.wait_text(
        "the second job cancelled",
        &format!("{row2} [data-testid=job-state]"),
        |t| t == "cancelled",
    )
    .await;
    assert_eq!(
        api.job(&id2).await.expect("GET the second job").state,
        JobState::Cancelled
    );

    // ---- the first job completes, on the jobs page and on its own page
    let row1 = format!("tr[data-job-id=\"{id1}\"]");
    b.wait_text(
        "the first job completed",
        &format!("{row1} [data-testid=job-state]"),
        |t| t == "completed",
    )
    .await;
    let progress = b
        .text(&format!("{row1} [data-testid=job-progress]"))
        .await
        .unwrap_or_default();
    assert!(progress.contains("(100 %)"), "progress {progress:?}");
    // The thumbnail comes in within a few seconds of the end.
    until("the first job's thumbnail", Duration::from_secs(20), || async {
        let v = b
            .js(
                "const i = document.querySelector(arguments[0]); \
                 return !!i && (i.getAttribute('src') || '').startsWith('blob:') && i.naturalWidth > 0;",
                vec![json!(format!("{row1} img[data-testid=thumb]"))],
            )
            .await;
        (v == json!(true)).then_some(())
    })
    .await;
    b.screenshot("jobs").await;
    let done = api.job(&id1).await.expect("GET the first job");
    assert_eq!(done.state, JobState::Completed);
    assert_eq!(done.samples_done, u64::from(WIDTH * HEIGHT * SPP));

    // Deleting the cancelled job, confirmed, removes its row and the job.
    b.click(&format!("{row2} button[data-action=delete]")).await;
    until(
        "the delete confirmation",
        Duration::from_secs(10),
        || async { b.dialog_open("confirm-dialog").await.then_some(()) },
    )
    .await;
    b.click("[data-testid=confirm-yes]").await;
    until(
        "the deleted job's row gone",
        Duration::from_secs(20),
        || async { b.text(&row2).await.is_none().then_some(()) },
    )
    .await;
    assert!(api.job(&id2).await.is_err(), "the second job still exists");
    b.wait_text("one job left", "[data-testid=jobs-count]", |t| t == "1 job")
        .await;

    b.click(&format!("{row1} a[data-testid=job-link]")).await;
    b.wait_text("the completed job page", "[data-testid=job-state]", |t| {
        t == "completed"
    })
    .await;
    let final_page = until(
        "the final image and charts",
        Duration::from_secs(20),
        || async {
            let p = job_page(&b).await;
            (p.painted && p.error_points >= 2 && p.rate_points >= 2).then_some(p)
        },
    )
    .await;
    assert!(final_page.src.starts_with("blob:"), "{final_page:?}");
    let samples = b
        .text("[data-testid=stat-samples]")
        .await
        .unwrap_or_default();
    assert!(samples.contains("(100.0 %)"), "samples {samples:?}");
    b.screenshot("job-completed").await;
    b.js(
        "document.querySelector('[data-testid=error-chart]').scrollIntoView();",
        vec![],
    )
    .await;
    b.screenshot("job-charts").await;

    // ---- the workers page: both local workers, then one killed and shown as lost
    b.click("nav a[data-nav=workers]").await;
    for worker in ["local-1", "local-2"] {
        b.find("tr[data-testid=worker-row] th[data-testid=worker-name]")
            .await;
        let state = until(&format!("{worker} listed"), Duration::from_secs(20), || async {
            let v = b
                .js(
                    "for (const r of document.querySelectorAll('tr[data-testid=worker-row]')) \
                       if (r.querySelector('[data-testid=worker-name]').textContent === arguments[0]) \
                         return r.querySelector('[data-testid=worker-state]').textContent; \
                     return null;",
                    vec![json!(worker)],
                )
                .await;
            v.as_str().map(str::to_string)
        })
        .await;
        assert!(
            state == "idle" || state == "busy",
            "{worker} shown as {state}"
        );
    }
    b.screenshot("workers").await;
    let victims = processes_with_args(&["worker", "--server", &url, "--name", "local-2"]);
    assert_eq!(victims.len(), 1, "the local-2 worker process: {victims:?}");
    // SAFETY: kill(2) on a worker process of this test's own farm (its command line names this
    // test's server URL); no memory-safety preconditions.
    unsafe {
        libc::kill(victims[0].0, libc::SIGKILL);
    }
    until("local-2 shown as lost", Duration::from_secs(30), || async {
        let v = b
            .js(
                "for (const r of document.querySelectorAll('tr[data-testid=worker-row]')) \
                   if (r.querySelector('[data-testid=worker-name]').textContent === 'local-2') \
                     return r.dataset.state + ':' + r.querySelector('[data-testid=worker-state]').textContent; \
                 return null;",
                vec![],
            )
            .await;
        (v == json!("lost:lost")).then_some(())
    })
    .await;
    let ws = api.workers().await.expect("GET /workers").workers;
    let lost = ws.iter().find(|w| w.name == "local-2").expect("local-2");
    assert_eq!(lost.state, WorkerState::Lost);
    b.screenshot("workers-lost").await;

    // ---- a scene with a feature the renderer ignores: its warning on the job page
    let mut gltf: Value = serde_json::from_slice(&std::fs::read(&scene).expect("read the scene"))
        .expect("the scene is JSON");
    gltf["extensionsUsed"] = json!(["KHR_materials_iridescence"]);
    let mut small = JobSettings::new(8, 8, 1);
    small.name = Some(format!("iridescent-{variant}"));
    let id3 = api
        .submit(
            serde_json::to_vec(&gltf).expect("encode the scene"),
            "iridescent.gltf",
            &small,
        )
        .await
        .expect("submit the iridescent scene")
        .id;
    b.goto(&format!("{url}/#/jobs/{id3}")).await;
    let warning = b
        .wait_text("the scene's warning", "[data-testid=job-warning]", |t| {
            !t.is_empty()
        })
        .await;
    assert!(
        warning.contains("KHR_materials_iridescence"),
        "the job page shows {warning:?}"
    );
    b.wait_text("no environment", "[data-testid=job-environment]", |t| {
        t == "none"
    })
    .await;

    // ---- a frame job: the strip shows each frame's progress, a click shows that frame, the
    // player steps through the frames by itself, the downloads and the jobs list know frames
    let animated = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../scenes/suite/animated.glb"
    ))
    .expect("read animated.glb");
    let mut anim = JobSettings::new(16, 12, 2);
    anim.name = Some(format!("animated-{variant}"));
    anim.frames = Some("1,10,20".into());
    anim.fps = Some(8.0);
    let id4 = api
        .submit(animated, "animated.glb", &anim)
        .await
        .expect("submit the frame job")
        .id;
    until(
        "the frame job to complete",
        Duration::from_secs(120),
        || async {
            let j = api.job(&id4).await.ok()?;
            (j.state == JobState::Completed).then_some(())
        },
    )
    .await;
    b.goto(&format!("{url}/#/jobs/{id4}")).await;
    b.wait_text(
        "every frame complete",
        "[data-testid=frames-summary]",
        |t| t.starts_with("3 of 3 complete"),
    )
    .await;
    let cells = b
        .js(
            "return [...document.querySelectorAll('[data-testid=frame-cell]')]\
               .map((c) => c.dataset.frame + ':' + c.dataset.complete);",
            vec![],
        )
        .await;
    assert_eq!(cells, json!(["1:true", "10:true", "20:true"]));
    // Each cell carries its frame's estimated error (every pixel has its two samples).
    let errors = b
        .js(
            "return [...document.querySelectorAll('[data-testid=frame-cell]')]\
               .map((c) => Number(c.dataset.error) > 0);",
            vec![],
        )
        .await;
    assert_eq!(errors, json!([true, true, true]));
    let shown_frame = || async {
        b.js(
            "const i = document.querySelector('[data-testid=preview-image]'); \
             return i.complete && i.naturalWidth > 0 ? (i.dataset.frame ?? null) : null;",
            vec![],
        )
        .await
        .as_str()
        .map(String::from)
    };
    until("frame 1 shown", Duration::from_secs(20), || async {
        (shown_frame().await.as_deref() == Some("1")).then_some(())
    })
    .await;
    b.click("[data-testid=frame-cell][data-frame=\"20\"] button")
        .await;
    until("frame 20 shown", Duration::from_secs(20), || async {
        (shown_frame().await.as_deref() == Some("20")).then_some(())
    })
    .await;
    // The charts follow the selected frame: its own history.
    b.wait_text(
        "the charts of frame 20",
        "[data-testid=charts-frame]",
        |t| t.contains("frame 20"),
    )
    .await;
    let charted = b
        .js(
            "const e = document.querySelector('[data-testid=error-chart]'); \
             const r = document.querySelector('[data-testid=rate-chart]'); \
             return [e.dataset.frame, Number(r.dataset.points)];",
            vec![],
        )
        .await;
    assert_eq!(charted[0], json!("20"), "{charted}");
    assert!(
        charted[1].as_f64().is_some_and(|n| n >= 1.0),
        "frame 20's history is not charted: {charted}"
    );
    b.screenshot("frame-job").await;
    b.click("[data-testid=frame-play]").await;
    let mut seen = BTreeSet::new();
    let deadline = Instant::now() + Duration::from_secs(30);
    while seen.len() < 3 && Instant::now() < deadline {
        if let Some(f) = shown_frame().await {
            seen.insert(f);
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert_eq!(seen.len(), 3, "the player showed only frames {seen:?}");
    b.click("[data-testid=frame-play]").await;
    let playing = b
        .js(
            "return document.querySelector('.frames').dataset.playing;",
            vec![],
        )
        .await;
    assert_eq!(playing, json!("false"), "Pause did not stop the player");
    b.find("[data-testid=download-frames-tar]").await;
    b.find("[data-testid=download-apng]").await;
    b.goto(&format!("{url}/#/jobs")).await;
    let row4 = format!("tr[data-job-id=\"{id4}\"]");
    b.wait_text(
        "the frame count in the jobs list",
        &format!("{row4} [data-testid=job-progress]"),
        |t| t.ends_with("3 / 3 frames"),
    )
    .await;

    // ---- a phone: one column, nothing wider than the screen
    b.client
        .set_window_size(390, 844)
        .await
        .expect("phone-sized window");
    for (page, hash) in [
        ("jobs", "#/jobs".to_string()),
        ("job", format!("#/jobs/{id1}")),
    ] {
        b.goto(&format!("{url}/{hash}")).await;
        b.find("[data-testid=job-state]").await;
        tokio::time::sleep(Duration::from_millis(500)).await;
        assert!(
            !b.overflows().await,
            "the {page} page is wider than a phone"
        );
        b.screenshot(&format!("phone-{page}")).await;
    }
    if tokens.is_some() {
        // Reloaded pages used the kept token: the prompt never came back.
        assert!(
            !b.dialog_open("token-dialog").await,
            "asked for the token again"
        );
    }
    assert!(
        b.error_notice().await.is_none(),
        "{:?}",
        b.error_notice().await
    );

    b.client.close().await.expect("close the browser");
    up.signal(libc::SIGINT);
    let status = up.wait_exit(Duration::from_secs(30)).await;
    assert!(status.success(), "`pathfarm up` exited {status}");
    eprintln!("{variant}: dashboard flow took {:?}", started.elapsed());
}

#[tokio::test(flavor = "multi_thread")]
async fn dashboard_drives_a_farm() {
    dashboard_flow("open", None).await;
}

#[tokio::test(flavor = "multi_thread")]
async fn dashboard_with_tokens() {
    dashboard_flow("tokens", Some(("client-secret", "worker-secret"))).await;
}
