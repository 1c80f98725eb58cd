//! End-to-end tests with real processes of the `pathfarm` binary: a server on a real SQLite file,
//! workers talking real HTTP to it, and the failures a farm must survive — a worker killed in the
//! middle of a task, a server restarted in the middle of a job, a worker asked to stop, and the
//! whole `pathfarm up` farm stopped with Ctrl-C.
//!
//! Every child process is held by a [`Proc`] guard that kills it when dropped, so a failing test
//! leaves nothing running; a failing test also prints the logs of its processes.

mod support;

use pathfarm_wire::api::{JobState, WorkerState};
use pathfarm_worker::client::ApiClient;
use std::time::Duration;
use support::*;

/// A worker killed with SIGKILL in the middle of a task loses nothing: its lease expires, the
/// unmerged samples are queued again, another worker finishes them, and the image is bit-identical
/// to a local render with no sample counted twice.
#[tokio::test(flavor = "multi_thread")]
async fn killed_worker_loses_nothing() {
    let farm = Farm::new("killed-worker");
    let server = farm.serve("server", &["--lease-seconds", "1"]).await;
    let api = farm.api();

    // Long enough that the poll below finds A in the middle of a task: a worker uploads while it
    // renders, so 48 spp were done in half a second.
    let settings = [
        "--width", "64", "--height", "64", "--spp", "256", "--seed", "3",
    ];
    let mut submitted = settings.to_vec();
    submitted.extend_from_slice(&["--tile", "32"]);
    let id = submit(&farm.dir, &farm.url, &submitted).await;
    let planned = 64 * 64 * 256;
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

    let (done, _worker_b) =
        finish_after_a_killed_worker(&farm, &server, &id, planned, Duration::from_secs(120)).await;
    let tiles = done.tiles.as_deref().expect("per-tile progress");
    assert!(
        tiles.iter().all(|t| t.samples_per_pixel == 256),
        "{tiles:?} (worker A died on tile {tile:?})"
    );

    let exr = api.image_exr(&id, false).await.expect("GET image.exr");
    let local = reference.await.expect("the local render task");
    assert_same_bytes(&exr, &local, "killed worker");
}

/// A worker killed with SIGKILL in the middle of an animation (frames behind it merged, a task of
/// a later frame half uploaded) loses only the slice it was rendering: its lease expires, another
/// worker takes the rest from where the merged samples end, no sample is merged twice, and every
/// frame is bit-identical to `pathfarm render --frame N` of the same settings.
#[tokio::test(flavor = "multi_thread")]
async fn killed_worker_mid_sequence_loses_only_its_slice() {
    let farm = Farm::new("killed-frame-worker");
    let server = farm.serve("server", &["--lease-seconds", "1"]).await;
    let api = farm.api();
    let settings = [
        "--width", "32", "--height", "24", "--spp", "256", "--seed", "5", "--fps", "24",
    ];
    let frames = [3, 9, 15, 21];
    let mut submitted = settings.to_vec();
    submitted.extend_from_slice(&[
        "--tile",
        "16",
        "--frames",
        "3-21x6",
        "--frame-order",
        "sequential",
    ]);
    let id = submit_scene(&farm.dir, &farm.url, ANIMATED, &submitted).await;
    let planned = 32 * 24 * 256 * frames.len() as u64;
    assert_eq!(job(&api, &id).await.samples_planned, planned);

    let mut worker_a = farm.worker("worker-a", 2);
    // Kill A once a frame is behind it and it is in the middle of a task of a later one.
    poll(
        "worker A to be in the middle of a later frame",
        Duration::from_secs(120),
        || async {
            let j = job(&api, &id).await;
            let a = named(&workers(&api).await, "worker-a")?.clone();
            let tiles = j.tiles.as_deref()?;
            let partial = tiles
                .iter()
                .find(|t| t.samples_per_pixel > 0 && t.samples_per_pixel + 8 < 256)?;
            let behind = j.frames_done? >= 1 && partial.frame != Some(frames[0]);
            (behind && a.state == WorkerState::Busy && a.current_task.is_some()).then_some(())
        },
    )
    .await;
    worker_a.kill_now();
    let at_kill = job(&api, &id).await;
    assert!(
        at_kill.samples_done < planned && !at_kill.state.is_final(),
        "the job ended before worker A was killed: {at_kill:?}"
    );
    let references: Vec<_> = frames
        .iter()
        .map(|f| {
            let mut args = settings.to_vec();
            let f = f.to_string();
            args.extend_from_slice(&["--frame", &f, "--threads", "1"]);
            render_reference_of(&farm.dir, ANIMATED, &format!("local-{f}.exr"), &args)
        })
        .collect();

    let (done, _worker_b) =
        finish_after_a_killed_worker(&farm, &server, &id, planned, Duration::from_secs(180)).await;
    assert_eq!(done.frames_done, Some(4), "{done:?}");
    for (frame, reference) in frames.iter().zip(references) {
        let exr = api
            .frame_exr(&id, *frame)
            .await
            .expect("GET image.exr?frame");
        let local = reference.await.expect("the local render of the frame");
        assert_same_bytes(
            &exr,
            &local,
            &format!("frame {frame} after a killed worker"),
        );
    }
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
/// workers cleanly (they sign off, every lane) and then the server, leaving no process behind.
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
    // Each process ran `up`'s default two task lanes: two workers of the farm each.
    let ws = workers(&api).await;
    assert_eq!(ws.len(), 4, "{ws:?}");
    for name in ["local-1", "local-1#2", "local-2", "local-2#2"] {
        let w = named(&ws, name).unwrap_or_else(|| panic!("{name} not listed: {ws:?}"));
        assert_eq!(w.state, WorkerState::Offline, "{w:?}");
    }
    let jobs = api.jobs(None, 1, 10).await.expect("GET /api/v1/jobs");
    assert_eq!(jobs.jobs.len(), 1, "{jobs:?}");
    assert_eq!(jobs.jobs[0].state, JobState::Completed, "{jobs:?}");
    assert_eq!(jobs.jobs[0].samples_done, 48 * 48 * 16, "{jobs:?}");
}

/// `pathfarm up` killed outright (SIGKILL: no chance to stop anything) takes its worker processes
/// with it instead of leaving them orphaned.
#[tokio::test(flavor = "multi_thread")]
async fn killed_up_takes_its_workers_with_it() {
    let farm = Farm::new("up-killed");
    let port = farm.port.to_string();
    let db = farm.dir.arg("up.db");
    let mut up = Proc::start(
        "up",
        &farm.dir,
        &["up", "--workers", "2", "--port", &port, "--db", &db],
    );
    wait_healthy(farm.port, &mut up).await;
    let worker_args = ["worker", "--server", farm.url.as_str()];
    poll("two worker processes", Duration::from_secs(30), || async {
        (processes_with_args(&worker_args).len() == 2).then_some(())
    })
    .await;
    up.kill_now();
    let left = poll_until_gone(&worker_args, Duration::from_secs(10)).await;
    for (pid, _) in &left {
        // SAFETY: kill(2) on a leftover worker of this test's own farm (its command line names
        // this test's port); no memory-safety preconditions.
        unsafe {
            libc::kill(*pid, libc::SIGKILL);
        }
    }
    assert!(left.is_empty(), "worker processes outlived `up`: {left:?}");
}

/// The processes with `needles` in their command line still alive after `timeout` (none, once
/// they are all gone).
async fn poll_until_gone(needles: &[&str], timeout: Duration) -> Vec<(i32, String)> {
    let deadline = std::time::Instant::now() + timeout;
    loop {
        let left = processes_with_args(needles);
        if left.is_empty() || std::time::Instant::now() > deadline {
            return left;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// `submit --wait --out`: a bad `--out` is refused before anything is submitted; a server restart
/// while waiting does not end the wait (the job goes on, the client retries), and the image is
/// written once the job completes.
#[tokio::test(flavor = "multi_thread")]
async fn submit_wait_rides_out_a_server_restart() {
    let farm = Farm::new("submit-wait-restart");
    let mut server = farm.serve("server-1", &[]).await;
    let api = farm.api();
    let settings = [
        "--width", "16", "--height", "16", "--spp", "4", "--wait", "--server",
    ];

    let mut args = vec!["submit", SCENE];
    args.extend_from_slice(&settings);
    args.extend_from_slice(&[farm.url.as_str(), "--out", "image.jpg"]);
    let out = run_cli(&farm.dir, &args, Duration::from_secs(30)).await;
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--out must end in .exr or .png"), "{err}");
    let jobs = api.jobs(None, 1, 10).await.expect("GET /api/v1/jobs");
    assert!(jobs.jobs.is_empty(), "submitted anyway: {jobs:?}");

    // No worker yet: the job waits in the queue while the server goes away and comes back.
    let png = farm.dir.arg("image.png");
    let mut args = vec!["submit", SCENE];
    args.extend_from_slice(&settings);
    args.extend_from_slice(&[farm.url.as_str(), "--out", &png]);
    let mut cmd = tokio::process::Command::from(command(&farm.dir));
    cmd.args(&args).kill_on_drop(true);
    let client = tokio::spawn(async move { cmd.output().await });
    poll("the job", Duration::from_secs(30), || async {
        let jobs = api.jobs(None, 1, 10).await.ok()?;
        (jobs.jobs.len() == 1).then_some(())
    })
    .await;
    server.signal(libc::SIGTERM);
    let status = server.wait_exit(Duration::from_secs(15)).await;
    assert!(status.success(), "the server exited {status} on SIGTERM");
    drop(server);
    // Several polls (every 0.2 s) find no server.
    tokio::time::sleep(Duration::from_millis(1000)).await;
    assert!(
        !client.is_finished(),
        "submit --wait gave up while the server was down"
    );
    let _server = farm.serve("server-2", &[]).await;
    let _worker = farm.worker("w", 4);

    let out = tokio::time::timeout(Duration::from_secs(60), client)
        .await
        .expect("submit --wait did not finish within 60 s")
        .expect("join")
        .expect("run pathfarm submit");
    assert_success(&out, "pathfarm submit --wait across a server restart");
    let bytes = std::fs::read(&png).expect("read image.png");
    assert!(bytes.starts_with(b"\x89PNG\r\n\x1a\n"), "not a PNG");
    let names: Vec<String> = std::fs::read_dir(&farm.dir.0)
        .expect("list the test directory")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".tmp"))
        .collect();
    assert!(names.is_empty(), "temporary files left: {names:?}");
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

    // Global options before the command, one with a value (not to be taken for the command).
    let mut server = Proc::start(
        "serve",
        &dir,
        &["--log-format", "json", "serve", "--config", &config_arg],
    );
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

/// A small equirectangular sky as a Radiance `.hdr` file, written into the test's directory.
fn write_hdr_sky(path: &std::path::Path) {
    let (width, height) = (16usize, 8usize);
    let pixels: Vec<image::Rgb<f32>> = (0..width * height)
        .map(|i| {
            let (x, y) = (i % width, i / width);
            if (x, y) == (4, 2) {
                image::Rgb([30.0, 25.0, 20.0])
            } else {
                image::Rgb([0.2 + x as f32 / 16.0, 0.4, 1.0 - y as f32 / 10.0])
            }
        })
        .collect();
    let mut out = Vec::new();
    image::codecs::hdr::HdrEncoder::new(&mut out)
        .encode(&pixels, width, height)
        .expect("encode the sky");
    std::fs::write(path, out).expect("write the sky");
}

/// `pathfarm submit` with the environment flags of `pathfarm render` (an uploaded image, then a
/// uniform radiance) gives an EXR byte-identical to `pathfarm render` with the same flags, and
/// `pathfarm job ID` shows the environment and the scene loader's warnings.
#[tokio::test(flavor = "multi_thread")]
async fn submit_with_an_environment_matches_render_with_it() {
    let farm = Farm::new("environment");
    let _server = farm.serve("server", &[]).await;
    let _worker = farm.worker("w", 3);
    let sky = farm.dir.arg("sky.hdr");
    write_hdr_sky(std::path::Path::new(&sky));
    let flags = |env: &[&'static str]| {
        let mut f = vec![
            "--width", "32", "--height", "24", "--spp", "6", "--seed", "5",
        ];
        f.extend_from_slice(env);
        f
    };
    let image_env = [
        "--environment-strength",
        "2.5",
        "--environment-rotation",
        "-40",
    ];
    let mut with_image: Vec<&str> = flags(&image_env);
    with_image.extend_from_slice(&["--environment", &sky]);
    let uniform = flags(&[
        "--environment",
        "0.3,0.5,0.8",
        "--environment-strength",
        "1.7",
    ]);
    for (what, settings) in [("image", with_image), ("uniform", uniform)] {
        let reference = render_reference(&farm.dir, &format!("local-{what}.exr"), &settings);
        let out_path = farm.dir.arg(&format!("farm-{what}.exr"));
        let mut args = vec!["submit", SCENE, "--server", &farm.url];
        args.extend_from_slice(&settings);
        args.extend_from_slice(&["--tile", "16", "--wait", "--out", &out_path]);
        let out = run_cli(&farm.dir, &args, Duration::from_secs(120)).await;
        assert_success(&out, "pathfarm submit --environment --wait");
        let id = String::from_utf8_lossy(&out.stdout)
            .lines()
            .next()
            .unwrap_or("")
            .trim()
            .to_string();
        let farm_exr = std::fs::read(&out_path).expect("read the farm's EXR");
        let local = reference.await.expect("the local render task");
        assert_same_bytes(&farm_exr, &local, what);

        let shown = run_cli(
            &farm.dir,
            &["job", &id, "--server", &farm.url],
            Duration::from_secs(30),
        )
        .await;
        assert_success(&shown, "pathfarm job");
        let text = String::from_utf8_lossy(&shown.stdout);
        let expected = match what {
            "image" => "environment: image ",
            _ => "environment: radiance 0.3,0.5,0.8, strength 1.7",
        };
        assert!(text.contains(expected), "{what}: {text}");
    }

    // A scene with an extension the tracer ignores: `job` shows the warning, `job --json` has it.
    let mut gltf: serde_json::Value =
        serde_json::from_slice(&std::fs::read(SCENE).unwrap()).unwrap();
    gltf["extensionsUsed"] = serde_json::json!(["KHR_materials_iridescence"]);
    let scene = farm.dir.arg("iridescent.gltf");
    std::fs::write(&scene, serde_json::to_vec(&gltf).unwrap()).unwrap();
    let out = run_cli(
        &farm.dir,
        &[
            "submit", &scene, "--server", &farm.url, "--width", "8", "--height", "8", "--spp", "1",
        ],
        Duration::from_secs(30),
    )
    .await;
    assert_success(&out, "pathfarm submit");
    let id = String::from_utf8_lossy(&out.stdout).trim().to_string();
    let shown = run_cli(
        &farm.dir,
        &["job", &id, "--server", &farm.url],
        Duration::from_secs(30),
    )
    .await;
    let text = String::from_utf8_lossy(&shown.stdout);
    assert!(
        text.contains("scene warnings (") && text.contains("KHR_materials_iridescence"),
        "{text}"
    );
    let json = run_cli(
        &farm.dir,
        &["job", &id, "--json", "--server", &farm.url],
        Duration::from_secs(30),
    )
    .await;
    let view: pathfarm_wire::api::JobView =
        serde_json::from_slice(&json.stdout).expect("job --json is a job view");
    assert!(
        view.warnings
            .iter()
            .any(|w| w.contains("KHR_materials_iridescence")),
        "{view:?}"
    );
}
