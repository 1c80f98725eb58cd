//! Helpers shared by the end-to-end tests: test directories, child-process guards, HTTP probes,
//! polling, and a farm of real `pathfarm` processes. Each test crate uses a part of it.
#![allow(dead_code)]

use pathfarm_server::scheduler::{max_per_pixel, opening_passes, pass_ranges};
pub use pathfarm_testkit::harness::PgDatabase;
use pathfarm_wire::api::{JobState, JobView, TileProgress, WorkerState, WorkerView};
use pathfarm_worker::client::ApiClient;
use std::fs::File;
use std::future::Future;
use std::io::{Read, Write};
use std::net::{Ipv4Addr, SocketAddr, TcpListener, TcpStream};
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus, Output, Stdio};
use std::time::{Duration, Instant};

pub const BIN: &str = env!("CARGO_BIN_EXE_pathfarm");
pub const SCENE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/cornell.gltf");
/// Blender's animated export (a cube that slides and turns, a camera on an arc).
pub const ANIMATED: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../scenes/suite/animated.glb"
);

/// A fresh directory per test; removed at the end unless the test failed or `PATHFARM_E2E_KEEP` is
/// set (then it is kept, and named, for the post-mortem).
pub struct TestDir(pub PathBuf);

impl TestDir {
    pub fn new(test: &str) -> TestDir {
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

    pub fn path(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }

    pub fn arg(&self, name: &str) -> String {
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

pub fn command(dir: &TestDir) -> Command {
    command_via(dir, &[])
}

/// `pathfarm` run through `wrapper` (e.g. `["ip", "netns", "exec", "NS"]`), with the environment
/// of [`command`].
pub fn command_via(dir: &TestDir, wrapper: &[&str]) -> Command {
    let mut cmd = match wrapper.split_first() {
        Some((program, args)) => {
            let mut c = Command::new(program);
            c.args(args).arg(BIN);
            c
        }
        None => Command::new(BIN),
    };
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

/// A running child process, killed (and reaped) when dropped; with `group`, the process group it
/// leads (the workers `up` starts, the browser chromedriver starts, nginx's workers).
pub struct Proc {
    pub name: String,
    pub child: Child,
    pub log: PathBuf,
    pub group: bool,
}

impl Proc {
    /// Starts `pathfarm ARGS…`, stdout and stderr going to `DIR/NAME.log`.
    pub fn start(name: &str, dir: &TestDir, args: &[&str]) -> Proc {
        Proc::start_via(name, dir, &[], args)
    }

    /// Starts `WRAPPER… pathfarm ARGS…` (see [`command_via`]); the wrapper must exec `pathfarm`
    /// in place (as `ip netns exec` does), so that signals reach it.
    pub fn start_via(name: &str, dir: &TestDir, wrapper: &[&str], args: &[&str]) -> Proc {
        let mut cmd = command_via(dir, wrapper);
        cmd.args(args);
        Proc::spawn(name, dir, cmd, false)
    }

    /// Starts `cmd` (any program), stdin empty, stdout and stderr going to `DIR/NAME.log`; with
    /// `group`, in a process group of its own, all of which is killed when dropped.
    pub fn spawn(name: &str, dir: &TestDir, mut cmd: Command, group: bool) -> Proc {
        let log = dir.path(&format!("{name}.log"));
        let out = File::create(&log).expect("create a log file");
        let err = out.try_clone().expect("clone the log file");
        if group {
            cmd.process_group(0);
        }
        let child = cmd
            .stdin(Stdio::null())
            .stdout(out)
            .stderr(err)
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
        Proc {
            name: name.to_string(),
            child,
            log,
            group,
        }
    }

    pub fn pid(&self) -> libc::pid_t {
        self.child.id() as libc::pid_t
    }

    pub fn signal(&self, sig: libc::c_int) {
        // SAFETY: kill(2) on a child this guard owns and has not reaped yet (so the pid is still
        // ours); it has no memory-safety preconditions.
        let rc = unsafe { libc::kill(self.pid(), sig) };
        assert_eq!(rc, 0, "kill({}, {sig}) failed", self.name);
    }

    pub fn is_running(&mut self) -> bool {
        matches!(self.child.try_wait(), Ok(None))
    }

    /// SIGKILL, and reap.
    pub fn kill_now(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// Waits for the process to exit; panics (with its log) after `timeout`.
    pub async fn wait_exit(&mut self, timeout: Duration) -> ExitStatus {
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

    pub fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if self.group {
            // SAFETY: kill(2) on the process group this guard's child leads (started with
            // process_group(0), so its id is the group's); no memory-safety preconditions.
            unsafe {
                libc::kill(-self.pid(), libc::SIGKILL);
            }
        } else if matches!(self.child.try_wait(), Ok(None)) {
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
pub async fn run_cli(dir: &TestDir, args: &[&str], timeout: Duration) -> Output {
    let mut cmd = tokio::process::Command::from(command(dir));
    cmd.args(args).kill_on_drop(true);
    match tokio::time::timeout(timeout, cmd.output()).await {
        Ok(out) => out.expect("run pathfarm"),
        Err(_) => panic!("pathfarm {args:?} did not finish within {timeout:?}"),
    }
}

pub fn assert_success(out: &Output, what: &str) {
    assert!(
        out.status.success(),
        "{what} failed ({}):\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A port nothing listens on right now (bound to 0 and released).
pub fn free_port() -> u16 {
    let l = TcpListener::bind((Ipv4Addr::LOCALHOST, 0)).expect("bind 127.0.0.1:0");
    l.local_addr().expect("local_addr").port()
}

/// The status code of `GET /healthz` (a bare HTTP/1.1 request), or `None` without an answer.
pub fn healthz_status(port: u16) -> Option<u16> {
    healthz_status_at(SocketAddr::from((Ipv4Addr::LOCALHOST, port)))
}

/// The status code of `GET /healthz` at `addr`, or `None` without an answer.
pub fn healthz_status_at(addr: SocketAddr) -> Option<u16> {
    let mut s = TcpStream::connect_timeout(&addr, Duration::from_secs(1)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(
        s,
        "GET /healthz HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    let mut answer = String::new();
    s.read_to_string(&mut answer).ok()?;
    answer.split_whitespace().nth(1)?.parse().ok()
}

/// Waits (30 s at most) until `GET /healthz` answers 200; fails early if `server` exits.
pub async fn wait_healthy(port: u16, server: &mut Proc) {
    wait_healthy_at(SocketAddr::from((Ipv4Addr::LOCALHOST, port)), server).await
}

/// Waits (30 s at most) until `GET /healthz` at `addr` answers 200; fails early if `server` exits.
pub async fn wait_healthy_at(addr: SocketAddr, server: &mut Proc) {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let status = tokio::task::spawn_blocking(move || healthz_status_at(addr))
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
pub async fn poll<T, F, Fut>(what: &str, timeout: Duration, mut check: F) -> T
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

pub async fn job(api: &ApiClient, id: &str) -> JobView {
    api.job(id)
        .await
        .unwrap_or_else(|e| panic!("GET /api/v1/jobs/{id}: {e}"))
}

pub async fn workers(api: &ApiClient) -> Vec<WorkerView> {
    api.workers()
        .await
        .unwrap_or_else(|e| panic!("GET /api/v1/workers: {e}"))
        .workers
}

pub fn named<'a>(list: &'a [WorkerView], name: &str) -> Option<&'a WorkerView> {
    list.iter().find(|w| w.name == name)
}

/// A tile whose task of the current pass is partly merged (its samples per pixel lie strictly
/// inside one of the job's passes), with the samples per pixel that task still lacks. The passes
/// are the server's own plan (`pathfarm_server::scheduler`) at the task sizes `serve` has by
/// default, as these tests' servers do.
pub fn partial_tile(j: &JobView) -> Option<(TileProgress, u64)> {
    let sizes = pathfarm_server::ServerConfig::new("sqlite::memory:").task_sizes();
    let tile = j.settings.tile_size;
    let passes = pass_ranges(
        j.settings.spp,
        opening_passes(tile, sizes, j.settings.frames.is_some()),
        max_per_pixel(tile, sizes.max),
    );
    j.tiles.as_ref()?.iter().find_map(|t| {
        let s = t.samples_per_pixel;
        passes
            .iter()
            .find(|&&(b, e)| (b as u64) < s && s < e as u64)
            .map(|&(_, e)| (t.clone(), e as u64 - s))
    })
}

/// `pathfarm submit SCENE --server URL SETTINGS…`; returns the job id it prints.
pub async fn submit(dir: &TestDir, url: &str, settings: &[&str]) -> String {
    submit_scene(dir, url, SCENE, settings).await
}

/// `pathfarm submit scene --server URL SETTINGS…`; returns the job id it prints.
pub async fn submit_scene(dir: &TestDir, url: &str, scene: &str, settings: &[&str]) -> String {
    let mut args = vec!["submit", scene, "--server", url];
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
pub fn render_reference(
    dir: &TestDir,
    name: &str,
    settings: &[&str],
) -> tokio::task::JoinHandle<Vec<u8>> {
    render_reference_of(dir, SCENE, name, settings)
}

/// [`render_reference`] of `scene`.
pub fn render_reference_of(
    dir: &TestDir,
    scene: &str,
    name: &str,
    settings: &[&str],
) -> tokio::task::JoinHandle<Vec<u8>> {
    let out_path = dir.path(name);
    let mut cmd = tokio::process::Command::from(command(dir));
    cmd.arg("render")
        .arg(scene)
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
pub async fn wait_completed(api: &ApiClient, id: &str, timeout: Duration) -> JobView {
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

pub fn assert_same_bytes(farm: &[u8], local: &[u8], what: &str) {
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
pub fn processes_with_args(needles: &[&str]) -> Vec<(i32, String)> {
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
pub struct Farm {
    pub dir: TestDir,
    pub port: u16,
    pub url: String,
    pub db: String,
}

impl Farm {
    pub fn new(test: &str) -> Farm {
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

    pub fn api(&self) -> ApiClient {
        ApiClient::new(&self.url, None).expect("API client")
    }

    /// `pathfarm serve` on this farm's port and database, once healthy.
    pub async fn serve(&self, name: &str, extra: &[&str]) -> Proc {
        let listen = format!("127.0.0.1:{}", self.port);
        let mut args = vec!["serve", "--listen", &listen, "--db", &self.db];
        args.extend_from_slice(extra);
        let mut server = Proc::start(name, &self.dir, &args);
        wait_healthy(self.port, &mut server).await;
        server
    }

    /// `pathfarm worker` with one render thread, fixed-size slices and a cache of its own.
    pub fn worker(&self, name: &str, slice_samples: u32) -> Proc {
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

/// How every test that kills `worker-a` (SIGKILL) in the middle of a job ends: a second worker,
/// `worker-b`, finishes it; the dead worker's lease came back by expiry (nothing else gives a dead
/// worker's lease back), the dead worker is marked lost (one lease after its last heartbeat), and
/// the two merged every planned sample exactly once between them, each some. Returns the finished
/// job and the second worker.
pub async fn finish_after_a_killed_worker(
    farm: &Farm,
    server: &Proc,
    id: &str,
    planned: u64,
    timeout: Duration,
) -> (JobView, Proc) {
    let api = farm.api();
    let worker_b = farm.worker("worker-b", 5);
    let done = wait_completed(&api, id, timeout).await;
    assert_eq!(
        (done.samples_planned, done.samples_done, done.leased_tasks),
        (planned, planned, 0),
        "{done:?}"
    );
    assert!(
        server.log_text().contains("lease expired"),
        "the server never expired worker A's lease"
    );
    let ws = poll(
        "worker A to be marked lost",
        Duration::from_secs(15),
        || async {
            let ws = workers(&api).await;
            (named(&ws, "worker-a")?.state == WorkerState::Lost).then_some(ws)
        },
    )
    .await;
    let merged = |name: &str| {
        named(&ws, name)
            .unwrap_or_else(|| panic!("{name} not listed: {ws:?}"))
            .samples_done
    };
    let (a, b) = (merged("worker-a"), merged("worker-b"));
    assert!(a > 0 && b > 0, "worker A merged {a}, worker B {b}");
    assert_eq!(a + b, planned, "a sample was lost or merged twice: {ws:?}");
    (done, worker_b)
}

/// The end state every fault test asserts: the named workers' merged samples add up to exactly
/// `planned` (nothing merged twice, nothing lost), and the job's image is byte-identical to the
/// local render `reference` yields.
pub async fn assert_merged_once_and_identical(
    api: &ApiClient,
    id: &str,
    planned: u64,
    worker_names: &[&str],
    reference: tokio::task::JoinHandle<Vec<u8>>,
    what: &str,
) {
    let ws = workers(api).await;
    let merged: u64 = worker_names
        .iter()
        .map(|n| {
            named(&ws, n)
                .unwrap_or_else(|| panic!("{n} not listed"))
                .samples_done
        })
        .sum();
    assert_eq!(merged, planned, "{what}: {ws:?}");
    let exr = api.image_exr(id, false).await.expect("GET image.exr");
    let local = reference.await.expect("the local render");
    assert_same_bytes(&exr, &local, what);
}

/// An external program a test drives (schemathesis, openapi-python-client): the path in `var`,
/// else `default` on PATH, if it answers `--version`. When it does not, the test is SKIPPED (it
/// prints why and returns None), unless `require_var` is `1` (CI, where `.ci/run` installs the
/// program): then it fails, saying how to install it.
pub fn external_tool(
    var: &str,
    default: &str,
    require_var: &str,
    install: &str,
) -> Option<PathBuf> {
    let exe = std::env::var_os(var)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(default));
    let answers = Command::new(&exe)
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if answers {
        return Some(exe);
    }
    if std::env::var(require_var).as_deref() == Ok("1") {
        panic!("{default} not found ({var} or PATH) and {require_var}=1; {install}");
    }
    eprintln!("SKIPPED: {default} not found; {install} or set {var}");
    None
}

/// The workspace's `target/` (or `CARGO_TARGET_DIR`): where tests leave reports.
pub fn target_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../target")))
}

/// Raises this process's open-file limit to its hard limit, for tests that hold hundreds of
/// connections (children started afterwards, such as a server, inherit it). CI machines often
/// start with a soft limit of 1024.
pub fn raise_fd_limit() {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit/setrlimit with a valid pointer to an rlimit this function owns.
    unsafe {
        if libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim) == 0 && lim.rlim_cur < lim.rlim_max {
            lim.rlim_cur = lim.rlim_max;
            let _ = libc::setrlimit(libc::RLIMIT_NOFILE, &lim);
        }
    }
}

/// A PostgreSQL database of a test's own (`pathfarm_TEST_…`), created beside the one `admin_url`
/// names and dropped, connections and all, when the value is dropped: the test kit's.
pub fn pg_test_database(admin_url: &str, test: &str) -> PgDatabase {
    PgDatabase::create_blocking(admin_url, &format!("pathfarm_{test}"))
        .unwrap_or_else(|e| panic!("cannot create the test database for {test}: {e}"))
}
