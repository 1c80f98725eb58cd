//! End-to-end tests with real processes of the `pathfarm` binary: a server on a real SQLite file,
//! workers talking real HTTP to it, and the failures a farm must survive — a worker killed in the
//! middle of a task, a server restarted in the middle of a job, a worker asked to stop, and the
//! whole `pathfarm up` farm stopped with Ctrl-C.
//!
//! Every child process is held by a [`Proc`] guard that kills it when dropped, so a failing test
//! leaves nothing running; a failing test also prints the logs of its processes.

use pathfarm_server::scheduler::pass_ranges;
use pathfarm_wire::api::{JobState, JobView, TileProgress, WorkerState, WorkerView};
use pathfarm_worker::client::ApiClient;
use std::fs::File;
use std::future::Future;
use std::io::{Read, Write};
use std::net::{Ipv4Addr, SocketAddr, TcpListener, TcpStream};
use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus, Output, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_pathfarm");
const SCENE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/cornell.gltf");

/// A fresh directory per test; removed at the end unless the test failed or `PATHFARM_E2E_KEEP` is
/// set (then it is kept, and named, for the post-mortem).
struct TestDir(PathBuf);

impl TestDir {
    fn new(test: &str) -> TestDir {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        let dir = std::env::temp_dir().join(format!(
            "pathfarm-e2e-{test}-{}-{nanos}",
            std::process::id()
        ));
        std::fs::create_dir_all(&dir).expect("create the test directory");
        TestDir(dir)
    }

    fn path(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }

    fn arg(&self, name: &str) -> String {
        self.path(name).to_string_lossy().into_owned()
    }
}

impl Drop for TestDir {
    fn drop(&mut self) {
        if std::thread::panicking() || std::env::var_os("PATHFARM_E2E_KEEP").is_some() {
            eprintln!("test files kept in {}", self.0.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

fn command(dir: &TestDir) -> Command {
    let mut cmd = Command::new(BIN);
    // Every PATHFARM_* variable of the developer's shell is cleared, so that children run
    // only on what the test gives them (new settings need no list kept up to date here).
    for (k, _) in std::env::vars_os() {
        if k.to_string_lossy().starts_with("PATHFARM_") {
            cmd.env_remove(k);
        }
    }
    // Workers without --cache-dir (those `up` starts) cache scenes under the test directory.
    cmd.env("XDG_CACHE_HOME", dir.path("xdg-cache"))
        .env("RUST_LOG", "info")
        .current_dir(&dir.0)
        .stdin(Stdio::null());
    cmd
}

/// A running child process, killed (and reaped) when dropped.
struct Proc {
    name: String,
    child: Child,
    log: PathBuf,
}

impl Proc {
    /// Starts `pathfarm ARGS…`, stdout and stderr going to `DIR/NAME.log`.
    fn start(name: &str, dir: &TestDir, args: &[&str]) -> Proc {
        let log = dir.path(&format!("{name}.log"));
        let out = File::create(&log).expect("create a log file");
        let err = out.try_clone().expect("clone the log file");
        let child = command(dir)
            .args(args)
            .stdout(out)
            .stderr(err)
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
        Proc {
            name: name.to_string(),
            child,
            log,
        }
    }

    fn pid(&self) -> libc::pid_t {
        self.child.id() as libc::pid_t
    }

    fn signal(&self, sig: libc::c_int) {
        // SAFETY: kill(2) on a child this guard owns and has not reaped yet (so the pid is still
        // ours); it has no memory-safety preconditions.
        let rc = unsafe { libc::kill(self.pid(), sig) };
        assert_eq!(rc, 0, "kill({}, {sig}) failed", self.name);
    }

    fn is_running(&mut self) -> bool {
        matches!(self.child.try_wait(), Ok(None))
    }

    /// SIGKILL, and reap.
    fn kill_now(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// Waits for the process to exit; panics (with its log) after `timeout`.
    async fn wait_exit(&mut self, timeout: Duration) -> ExitStatus {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(status) = self.child.try_wait().expect("try_wait") {
                return status;
            }
            if Instant::now() > deadline {
                panic!(
                    "{} did not exit within {timeout:?}; its log:\n{}",
                    self.name,
                    self.log_text()
                );
            }
            tokio::time::sleep(Duration::from_millis(25)).await;
        }
    }

    fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
        if std::thread::panicking() {
            let log = self.log_text();
            let tail: String = {
                let lines: Vec<&str> = log.lines().collect();
                lines[lines.len().saturating_sub(40)..].join("\n")
            };
            eprintln!(
                "---- last lines of {} ({}) ----\n{tail}",
                self.name,
                self.log.display()
            );
        }
    }
}

/// Runs `pathfarm ARGS…` to completion (killed after `timeout`).
async fn run_cli(dir: &TestDir, args: &[&str], timeout: Duration) -> Output {
    let mut cmd = tokio::process::Command::from(command(dir));
    cmd.args(args).kill_on_drop(true);
    match tokio::time::timeout(timeout, cmd.output()).await {
        Ok(out) => out.expect("run pathfarm"),
        Err(_) => panic!("pathfarm {args:?} did not finish within {timeout:?}"),
    }
}

fn assert_success(out: &Output, what: &str) {
    assert!(
        out.status.success(),
        "{what} failed ({}):\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A port nothing listens on right now (bound to 0 and released).
fn free_port() -> u16 {
    let l = TcpListener::bind((Ipv4Addr::LOCALHOST, 0)).expect("bind 127.0.0.1:0");
    l.local_addr().expect("local_addr").port()
}

/// The status code of `GET /healthz` (a bare HTTP/1.1 request), or `None` without an answer.
fn healthz_status(port: u16) -> Option<u16> {
    let addr = SocketAddr::from((Ipv4Addr::LOCALHOST, port));
    let mut s = TcpStream::connect_timeout(&addr, Duration::from_secs(1)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(
        s,
        "GET /healthz HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    let mut answer = String::new();
    s.read_to_string(&mut answer).ok()?;
    answer.split_whitespace().nth(1)?.parse().ok()
}

/// Waits (30 s at most) until `GET /healthz` answers 200; fails early if `server` exits.
async fn wait_healthy(port: u16, server: &mut Proc) {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let status = tokio::task::spawn_blocking(move || healthz_status(port))
            .await
            .expect("healthz probe");
        if status == Some(200) {
            return;
        }
        if !server.is_running() {
            panic!(
                "{} exited before it was healthy; its log:\n{}",
                server.name,
                server.log_text()
            );
        }
        if Instant::now() > deadline {
            panic!(
                "{} not healthy within 30 s (last answer {status:?})",
                server.name
            );
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// Calls `check` every 25 ms until it returns `Some`; panics after `timeout`.
async fn poll<T, F, Fut>(what: &str, timeout: Duration, mut check: F) -> T
where
    F: FnMut() -> Fut,
    Fut: Future<Output = Option<T>>,
{
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(v) = check().await {
            return v;
        }
        if Instant::now() > deadline {
            panic!("timed out after {timeout:?} waiting for {what}");
        }
        tokio::time::sleep(Duration::from_millis(25)).await;
    }
}

async fn job(api: &ApiClient, id: &str) -> JobView {
    api.job(id)
        .await
        .unwrap_or_else(|e| panic!("GET /api/v1/jobs/{id}: {e}"))
}

async fn workers(api: &ApiClient) -> Vec<WorkerView> {
    api.workers()
        .await
        .unwrap_or_else(|e| panic!("GET /api/v1/workers: {e}"))
        .workers
}

fn named<'a>(list: &'a [WorkerView], name: &str) -> Option<&'a WorkerView> {
    list.iter().find(|w| w.name == name)
}

/// A tile whose task of the current pass is partly merged (its samples per pixel lie strictly
/// inside one of the job's passes), with the samples per pixel that task still lacks. The passes
/// are the server's own plan (`pathfarm_server::scheduler`), uncapped: the server caps a task at
/// `max_task_samples / tile pixels` samples per pixel (≥ 1024 here), far above these jobs' spp.
fn partial_tile(j: &JobView) -> Option<(TileProgress, u64)> {
    let passes = pass_ranges(j.settings.spp, u32::MAX);
    j.tiles.as_ref()?.iter().find_map(|t| {
        let s = t.samples_per_pixel;
        passes
            .iter()
            .find(|&&(b, e)| (b as u64) < s && s < e as u64)
            .map(|&(_, e)| (t.clone(), e as u64 - s))
    })
}

/// `pathfarm submit SCENE --server URL SETTINGS…`; returns the job id it prints.
async fn submit(dir: &TestDir, url: &str, settings: &[&str]) -> String {
    let mut args = vec!["submit", SCENE, "--server", url];
    args.extend_from_slice(settings);
    let out = run_cli(dir, &args, Duration::from_secs(30)).await;
    assert_success(&out, "pathfarm submit");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let id = stdout.lines().next().unwrap_or("").trim().to_string();
    assert!(
        !id.is_empty() && id.chars().all(|c| c.is_ascii_alphanumeric() || c == '-'),
        "submit printed no job id: {stdout:?}"
    );
    id
}

/// Starts `pathfarm render SCENE SETTINGS… --out DIR/NAME` in the background; the returned task
/// yields the bytes it wrote.
fn render_reference(
    dir: &TestDir,
    name: &str,
    settings: &[&str],
) -> tokio::task::JoinHandle<Vec<u8>> {
    let out_path = dir.path(name);
    let mut cmd = tokio::process::Command::from(command(dir));
    cmd.arg("render")
        .arg(SCENE)
        .args(settings)
        .arg("--out")
        .arg(&out_path)
        .kill_on_drop(true);
    tokio::spawn(async move {
        let out = tokio::time::timeout(Duration::from_secs(120), cmd.output())
            .await
            .expect("pathfarm render did not finish within 120 s")
            .expect("run pathfarm render");
        assert_success(&out, "pathfarm render");
        std::fs::read(&out_path).expect("read the local render")
    })
}

/// Polls the job until it is final (`timeout` at most); it must end completed.
async fn wait_completed(api: &ApiClient, id: &str, timeout: Duration) -> JobView {
    let j = poll("the job to end", timeout, || async {
        let j = job(api, id).await;
        j.state.is_final().then_some(j)
    })
    .await;
    assert_eq!(
        j.state,
        JobState::Completed,
        "job ended {} ({:?})",
        j.state.as_str(),
        j.message
    );
    j
}

fn assert_same_bytes(farm: &[u8], local: &[u8], what: &str) {
    if farm != local {
        let first = farm.iter().zip(local).position(|(a, b)| a != b);
        panic!(
            "{what}: the farm's EXR ({} bytes) differs from the local render ({} bytes); \
             first differing byte at {first:?}",
            farm.len(),
            local.len()
        );
    }
}

/// Live processes whose command line holds every one of `needles`.
fn processes_with_args(needles: &[&str]) -> Vec<(i32, String)> {
    let mut found = Vec::new();
    let Ok(entries) = std::fs::read_dir("/proc") else {
        return found;
    };
    for e in entries.flatten() {
        let Some(pid) = e.file_name().to_str().and_then(|s| s.parse::<i32>().ok()) else {
            continue;
        };
        let Ok(raw) = std::fs::read(e.path().join("cmdline")) else {
            continue;
        };
        let args: Vec<String> = raw
            .split(|&b| b == 0)
            .map(|a| String::from_utf8_lossy(a).into_owned())
            .collect();
        if needles.iter().all(|n| args.iter().any(|a| a == n)) {
            found.push((pid, args.join(" ")));
        }
    }
    found
}

/// A test's farm: its directory, a free port and the URL the server will have there.
struct Farm {
    dir: TestDir,
    port: u16,
    url: String,
    db: String,
}

impl Farm {
    fn new(test: &str) -> Farm {
        let dir = TestDir::new(test);
        let port = free_port();
        let db = dir.arg("farm.db");
        Farm {
            dir,
            port,
            url: format!("http://127.0.0.1:{port}"),
            db,
        }
    }

    fn api(&self) -> ApiClient {
        ApiClient::new(&self.url, None).expect("API client")
    }

    /// `pathfarm serve` on this farm's port and database, once healthy.
    async fn serve(&self, name: &str, extra: &[&str]) -> Proc {
        let listen = format!("127.0.0.1:{}", self.port);
        let mut args = vec!["serve", "--listen", &listen, "--db", &self.db];
        args.extend_from_slice(extra);
        let mut server = Proc::start(name, &self.dir, &args);
        wait_healthy(self.port, &mut server).await;
        server
    }

    /// `pathfarm worker` with one render thread, fixed-size slices and a cache of its own.
    fn worker(&self, name: &str, slice_samples: u32) -> Proc {
        let cache = self.dir.arg(&format!("cache-{name}"));
        let slice = slice_samples.to_string();
        Proc::start(
            name,
            &self.dir,
            &[
                "worker",
                "--server",
                &self.url,
                "--threads",
                "1",
                "--slice-samples",
                &slice,
                "--cache-dir",
                &cache,
                "--name",
                name,
            ],
        )
    }
}

/// A worker killed with SIGKILL in the middle of a task loses nothing: its lease expires, the
/// unmerged samples are queued again, another worker finishes them, and the image is bit-identical
/// to a local render with no sample counted twice.
#[tokio::test(flavor = "multi_thread")]
async fn killed_worker_loses_nothing() {
    let farm = Farm::new("killed-worker");
    let server = farm.serve("server", &["--lease-seconds", "1"]).await;
    let api = farm.api();

    let settings = [
        "--width", "64", "--height", "64", "--spp", "48", "--seed", "3",
    ];
    let mut submitted = settings.to_vec();
    submitted.extend_from_slice(&["--tile", "32"]);
    let id = submit(&farm.dir, &farm.url, &submitted).await;
    let planned = 64 * 64 * 48;
    assert_eq!(job(&api, &id).await.samples_planned, planned);

    let mut worker_a = farm.worker("worker-a", 1);
    // Kill A while it holds a lease on a task of which some slices are merged and several are
    // still to come (so that it cannot have finished the task when the signal lands).
    poll(
        "worker A to be in the middle of a task",
        Duration::from_secs(60),
        || async {
            let j = job(&api, &id).await;
            let ws = workers(&api).await;
            let a = named(&ws, "worker-a")?;
            let (_, left) = partial_tile(&j)?;
            (left >= 4 && a.state == WorkerState::Busy && a.current_task.is_some()).then_some(())
        },
    )
    .await;
    worker_a.kill_now();
    let at_kill = job(&api, &id).await;
    assert!(
        at_kill.samples_done > 0 && at_kill.samples_done < planned && !at_kill.state.is_final(),
        "the job ended before worker A was killed: {at_kill:?}"
    );
    assert_eq!(at_kill.leased_tasks, 1, "{at_kill:?}");
    let (tile, _) = partial_tile(&at_kill).expect("worker A died in the middle of a task");
    let reference = render_reference(&farm.dir, "local.exr", &settings);

    let _worker_b = farm.worker("worker-b", 5);
    let done = wait_completed(&api, &id, Duration::from_secs(120)).await;
    assert_eq!(done.samples_planned, planned);
    assert_eq!(done.samples_done, planned);
    assert_eq!(done.leased_tasks, 0);
    let tiles = done.tiles.as_deref().expect("per-tile progress");
    assert!(tiles.iter().all(|t| t.samples_per_pixel == 48), "{tiles:?}");
    // A's task came back through lease expiry (nothing else gives a dead worker's lease back).
    assert!(
        server.log_text().contains("lease expired"),
        "the server never expired worker A's lease (its task was on tile {tile:?})"
    );

    // The silent worker is marked lost (one lease duration after its last heartbeat).
    let ws = poll(
        "worker A to be marked lost",
        Duration::from_secs(15),
        || async {
            let ws = workers(&api).await;
            (named(&ws, "worker-a")?.state == WorkerState::Lost).then_some(ws)
        },
    )
    .await;
    // Every sample was merged exactly once, by one worker or the other.
    let a = named(&ws, "worker-a").expect("worker A listed");
    let b = named(&ws, "worker-b").expect("worker B listed");
    assert!(a.samples_done > 0, "worker A merged nothing: {a:?}");
    assert!(b.samples_done > 0, "worker B merged nothing: {b:?}");
    assert_eq!(a.samples_done + b.samples_done, planned, "{ws:?}");

    let exr = api.image_exr(&id, false).await.expect("GET image.exr");
    let local = reference.await.expect("the local render task");
    assert_same_bytes(&exr, &local, "killed worker");
}

/// The server stopped with SIGTERM in the middle of a job and started again on the same SQLite
/// file: the worker rides out the gap, and the job completes bit-identical to a local render.
#[tokio::test(flavor = "multi_thread")]
async fn server_restart_mid_job_resumes_bit_identical() {
    let farm = Farm::new("server-restart");
    let mut server = farm.serve("server-1", &[]).await;
    let api = farm.api();

    let settings = [
        "--width", "64", "--height", "64", "--spp", "64", "--seed", "11",
    ];
    let mut submitted = settings.to_vec();
    submitted.extend_from_slice(&["--tile", "32"]);
    let id = submit(&farm.dir, &farm.url, &submitted).await;
    let planned = 64 * 64 * 64;

    let mut worker = farm.worker("survivor", 2);
    // Stop the server while a task is partly merged.
    let before = poll(
        "a task to be partly merged",
        Duration::from_secs(60),
        || async {
            let j = job(&api, &id).await;
            partial_tile(&j).is_some().then_some(j)
        },
    )
    .await;
    assert!(
        before.samples_done < planned && !before.state.is_final(),
        "the job ended before the restart: {before:?}"
    );

    server.signal(libc::SIGTERM);
    let status = server.wait_exit(Duration::from_secs(15)).await;
    assert!(status.success(), "the server exited {status} on SIGTERM");
    drop(server);
    let reference = render_reference(&farm.dir, "local.exr", &settings);
    // A gap long enough that the worker (uploading every few milliseconds) runs into it.
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert!(
        worker.is_running(),
        "the worker gave up while the server was down"
    );

    let _server = farm.serve("server-2", &[]).await;
    let resumed = job(&api, &id).await;
    assert!(
        resumed.samples_done >= before.samples_done,
        "merged samples were lost across the restart: {before:?} then {resumed:?}"
    );

    let done = wait_completed(&api, &id, Duration::from_secs(120)).await;
    assert_eq!(done.samples_done, planned);
    assert_eq!(done.samples_planned, planned);
    assert!(
        worker.is_running(),
        "the worker did not survive the restart"
    );
    assert!(
        worker.log_text().contains("retrying"),
        "the worker never noticed that the server was gone"
    );
    let ws = workers(&api).await;
    assert_eq!(ws.len(), 1, "the worker registered again: {ws:?}");
    assert_eq!(ws[0].samples_done, planned, "{ws:?}");

    let exr = api.image_exr(&id, false).await.expect("GET image.exr");
    let local = reference.await.expect("the local render task");
    assert_same_bytes(&exr, &local, "server restart");
}

/// SIGTERM makes a worker upload the slice in hand, give its lease back and sign off: it exits 0,
/// shows offline, and its partly merged task is queued again at once (not after a lease expiry:
/// leases last 60 s here).
#[tokio::test(flavor = "multi_thread")]
async fn sigterm_worker_hands_back_and_exits_cleanly() {
    let farm = Farm::new("sigterm-worker");
    let server = farm.serve("server", &["--lease-seconds", "60"]).await;
    let api = farm.api();

    // One 64×64 tile, so the long passes ([15, 31), [31, 63), …) come after a few slices.
    let id = submit(
        &farm.dir,
        &farm.url,
        &[
            "--width", "64", "--height", "64", "--spp", "256", "--tile", "64", "--seed", "5",
        ],
    )
    .await;
    let mut worker = farm.worker("stopper", 1);
    // Stop it in the middle of a task with several slices to go.
    poll(
        "the worker to be in the middle of a task",
        Duration::from_secs(60),
        || async {
            let j = job(&api, &id).await;
            let ws = workers(&api).await;
            let w = named(&ws, "stopper")?;
            let (_, left) = partial_tile(&j)?;
            (left >= 6 && j.leased_tasks == 1 && w.state == WorkerState::Busy).then_some(())
        },
    )
    .await;

    worker.signal(libc::SIGTERM);
    let status = worker.wait_exit(Duration::from_secs(15)).await;
    assert!(status.success(), "the worker exited {status} on SIGTERM");
    let log = worker.log_text();
    assert!(log.contains("worker stopped"), "{log}");

    let ws = workers(&api).await;
    let w = named(&ws, "stopper").expect("the worker is listed");
    assert_eq!(w.state, WorkerState::Offline, "{w:?}");
    assert_eq!(w.current_task, None, "{w:?}");
    assert!(w.samples_done > 0, "{w:?}");
    let j = poll(
        "the lease to be handed back",
        Duration::from_secs(3),
        || async {
            let j = job(&api, &id).await;
            (j.leased_tasks == 0).then_some(j)
        },
    )
    .await;
    assert_eq!(j.state, JobState::Running, "{j:?}");
    assert!(
        j.samples_done > 0 && j.samples_done < j.samples_planned,
        "{j:?}"
    );
    assert_eq!(j.samples_done, w.samples_done, "{j:?} {w:?}");
    // The task it handed back keeps its merged slices.
    assert!(partial_tile(&j).is_some(), "{j:?}");
    assert!(
        !server.log_text().contains("lease expired"),
        "the lease expired instead of being handed back"
    );

    let out = run_cli(
        &farm.dir,
        &["cancel", &id, "--server", &farm.url],
        Duration::from_secs(30),
    )
    .await;
    assert_success(&out, "pathfarm cancel");
    let j = job(&api, &id).await;
    assert_eq!(j.state, JobState::Cancelled, "{j:?}");
    assert!(j.finished_at_ms.is_some(), "{j:?}");
}

/// `pathfarm up`: a server and two local worker processes render a submitted job; Ctrl-C stops the
/// workers cleanly (they sign off) and then the server, leaving no process behind.
#[tokio::test(flavor = "multi_thread")]
async fn up_runs_a_job_end_to_end() {
    let mut farm = Farm::new("up");
    farm.db = farm.dir.arg("up.db");
    let port = farm.port.to_string();
    let mut up = Proc::start(
        "up",
        &farm.dir,
        &["up", "--workers", "2", "--port", &port, "--db", &farm.db],
    );
    wait_healthy(farm.port, &mut up).await;
    let api = farm.api();

    let png = farm.dir.arg("farm.png");
    let out = run_cli(
        &farm.dir,
        &[
            "submit", SCENE, "--server", &farm.url, "--width", "48", "--height", "48", "--spp",
            "16", "--wait", "--out", &png,
        ],
        Duration::from_secs(90),
    )
    .await;
    assert_success(&out, "pathfarm submit --wait");
    let bytes = std::fs::read(&png).expect("read farm.png");
    assert!(
        bytes.starts_with(b"\x89PNG\r\n\x1a\n"),
        "farm.png is not a PNG ({} bytes)",
        bytes.len()
    );

    let ws = workers(&api).await;
    for name in ["local-1", "local-2"] {
        let w = named(&ws, name).unwrap_or_else(|| panic!("{name} not registered: {ws:?}"));
        assert_ne!(w.state, WorkerState::Offline, "{w:?}");
    }
    // The workers are processes of their own, started by `up` with the farm's URL.
    let worker_args = ["worker", "--server", farm.url.as_str()];
    assert_eq!(
        processes_with_args(&worker_args).len(),
        2,
        "expected two worker processes of this farm"
    );

    up.signal(libc::SIGINT);
    let status = up.wait_exit(Duration::from_secs(20)).await;
    assert!(status.success(), "`pathfarm up` exited {status} on SIGINT");
    let left = processes_with_args(&worker_args);
    for (pid, _) in &left {
        // SAFETY: kill(2) on a leftover worker of this test's own farm (its command line names
        // this test's port); no memory-safety preconditions.
        unsafe {
            libc::kill(*pid, libc::SIGKILL);
        }
    }
    assert!(left.is_empty(), "worker processes left behind: {left:?}");

    // The farm's state outlives it: a server on the same database shows both workers signed off.
    farm.port = free_port();
    farm.url = format!("http://127.0.0.1:{}", farm.port);
    let _server = farm.serve("server", &[]).await;
    let api = farm.api();
    let ws = workers(&api).await;
    assert_eq!(ws.len(), 2, "{ws:?}");
    for name in ["local-1", "local-2"] {
        let w = named(&ws, name).unwrap_or_else(|| panic!("{name} not listed: {ws:?}"));
        assert_eq!(w.state, WorkerState::Offline, "{w:?}");
    }
    let jobs = api.jobs(None, 1, 10).await.expect("GET /api/v1/jobs");
    assert_eq!(jobs.jobs.len(), 1, "{jobs:?}");
    assert_eq!(jobs.jobs[0].state, JobState::Completed, "{jobs:?}");
    assert_eq!(jobs.jobs[0].samples_done, 48 * 48 * 16, "{jobs:?}");
}

/// `--config FILE`: a server configured only by its TOML file listens where the file says, with the
/// file's tokens; a flag wins over the file; a worker reads its own table; a typo is an error that
/// names the file and the key, and nothing starts.
#[tokio::test(flavor = "multi_thread")]
async fn configuration_file_flags_win_over_it() {
    let dir = TestDir::new("config");
    let (port, other) = (free_port(), free_port());
    let db = dir.arg("farm.db");
    let config = dir.path("farm.toml");
    std::fs::write(
        &config,
        format!(
            "[serve]\nlisten = \"127.0.0.1:{port}\"\ndb = \"{db}\"\n\
             client-tokens = [\"client-secret\"]\nworker-tokens = [\"worker-secret\"]\n\
             [worker]\nserver = \"http://127.0.0.1:{port}\"\ntoken = \"worker-secret\"\n\
             name = \"from-the-file\"\nthreads = 1\n"
        ),
    )
    .expect("write the configuration");
    let config_arg = config.to_string_lossy().into_owned();

    let mut server = Proc::start("serve", &dir, &["serve", "--config", &config_arg]);
    wait_healthy(port, &mut server).await;
    let url = format!("http://127.0.0.1:{port}");
    // The file's tokens hold: no token is refused, the client token reads.
    let anonymous = ApiClient::new(&url, None).expect("client");
    assert!(anonymous.jobs(None, 1, 10).await.is_err());
    let api = ApiClient::new(&url, Some("client-secret".into())).expect("client");
    api.jobs(None, 1, 10)
        .await
        .expect("the file's client token");

    // The worker is configured by the file alone: it registers under the file's name.
    let _worker = Proc::start("worker", &dir, &["worker", "--config", &config_arg]);
    poll(
        "the worker from the file",
        Duration::from_secs(30),
        || async { named(&workers(&api).await, "from-the-file").map(|_| ()) },
    )
    .await;

    // A flag wins over the file.
    let mut second = Proc::start(
        "serve-flag",
        &dir,
        &[
            "serve",
            "--config",
            &config_arg,
            "--listen",
            &format!("127.0.0.1:{other}"),
            "--db",
            &dir.arg("second.db"),
        ],
    );
    wait_healthy(other, &mut second).await;

    // A typo names the file and the key.
    let bad = dir.path("bad.toml");
    std::fs::write(&bad, "[serve]\nlisten-address = \"127.0.0.1:1\"\n").expect("write");
    let out = run_cli(
        &dir,
        &["serve", "--config", &bad.to_string_lossy()],
        Duration::from_secs(30),
    )
    .await;
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("bad.toml") && err.contains("`listen-address`"),
        "{err}"
    );
}
