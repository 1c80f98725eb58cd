//! `pathfarm bench up`: the embedded farm against a direct render on the same cores, as a user
//! runs them — `pathfarm render --threads C` against `pathfarm up` (a server and its local
//! workers, real processes) rendering the same job submitted with `pathfarm submit --wait`:
//! the time ratio, the peak memory of all the farm's processes together, and whether the images
//! are the same bytes. Two layouts of `up`: its default (one worker process rendering on every
//! core, one copy of the scene) and one process per core, each with its own copy (`up`'s
//! default before it).

use crate::error::{farm_err, write_file};
use crate::scale::{sphere_glb, status_kib};
use crate::{BenchError, Machine};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

#[derive(Clone, Debug)]
pub struct UpOptions {
    /// The `pathfarm` binary: run as `render`, `up` and `submit`.
    pub exe: PathBuf,
    /// The shipped scenes (`cornell.gltf`).
    pub scenes_dir: PathBuf,
    pub out_dir: PathBuf,
    /// Cores given to the render and to the farm's workers together.
    pub threads: usize,
    pub quick: bool,
    /// Another `pathfarm` binary (an earlier build) whose `up` also runs, in its own default
    /// layout, for a before-and-after in one run.
    pub baseline: Option<PathBuf>,
    pub command_line: String,
}

/// A job of the comparison.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct UpCase {
    pub name: String,
    pub triangles: u64,
    pub width: u32,
    pub height: u32,
    pub spp: u32,
}

/// One way of rendering a case.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct UpRow {
    pub case: String,
    /// `render`, or `up W×T` (W worker processes of T threads).
    pub layout: String,
    pub round: u32,
    /// `render`: the process's wall time (scene load included); `up`: the job's
    /// `finished_at − created_at` (the workers' scene fetch and load included).
    pub seconds: f64,
    /// `seconds` over the direct render's of the same round.
    pub ratio: f64,
    /// The largest resident set of each process (`VmHWM`, sampled every 50 ms), summed over the
    /// processes: `up` and its workers.
    pub peak_rss_mib: f64,
    pub processes: usize,
    /// CPU seconds (user + system) of all its processes: the render's whole run; the farm's from
    /// the submission until `submit --wait` has the image (the server's and its workers').
    #[serde(default)]
    pub cpu_seconds: Option<f64>,
    /// The farm's server's part of `cpu_seconds` (merges, leases, the database, the API).
    #[serde(default)]
    pub server_cpu_seconds: Option<f64>,
    /// The farm's EXR is byte for byte the direct render's.
    pub identical: bool,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct UpResults {
    pub machine: Machine,
    pub command_line: String,
    pub cases: Vec<UpCase>,
    pub rows: Vec<UpRow>,
}

fn cases(quick: bool) -> Vec<(UpCase, Scene)> {
    if quick {
        vec![
            (case("cornell", 32, 128, 128, 64), Scene::Cornell),
            (
                case("sphere-20k", 20_000, 128, 128, 16),
                Scene::Sphere(20_000),
            ),
        ]
    } else {
        vec![
            (case("cornell", 32, 512, 512, 256), Scene::Cornell),
            (
                case("sphere-1M", 1_000_000, 256, 256, 256),
                Scene::Sphere(1_000_000),
            ),
        ]
    }
}

fn case(name: &str, triangles: u64, width: u32, height: u32, spp: u32) -> UpCase {
    UpCase {
        name: name.into(),
        triangles,
        width,
        height,
        spp,
    }
}

enum Scene {
    Cornell,
    /// The scale bench's sphere of this many triangles, with vertex normals, as a `.glb`.
    Sphere(usize),
}

/// Runs every case in every layout (two rounds, alternating, on a full run; one with `quick`),
/// writes `up.md` and `up.json`, and returns the results and the markdown.
pub fn run(opts: &UpOptions) -> Result<(UpResults, String), BenchError> {
    let work = opts.out_dir.join("up-work");
    std::fs::create_dir_all(&work).map_err(|e| BenchError::io(&work, e))?;
    let threads = opts.threads.max(1);
    let layouts = [(1, threads), (threads, 1)];
    let rounds = if opts.quick { 1 } else { 2 };
    let mut rows = Vec::new();
    let mut listed = Vec::new();
    for (case, scene) in cases(opts.quick) {
        let scene_path = match scene {
            Scene::Cornell => opts.scenes_dir.join("cornell.gltf"),
            Scene::Sphere(n) => {
                let path = work.join(format!("{}.glb", case.name));
                write_file(&path, &sphere_glb(n, 1)?)?;
                path
            }
        };
        for round in 1..=rounds {
            let direct = render(opts, &work, &scene_path, &case, threads)?;
            tracing::info!(case = case.name, seconds = direct.seconds, "direct render");
            rows.push(UpRow {
                case: case.name.clone(),
                layout: "render".into(),
                round,
                seconds: direct.seconds,
                ratio: 1.0,
                peak_rss_mib: direct.peak_rss_mib,
                processes: 1,
                cpu_seconds: direct.cpu_seconds,
                server_cpu_seconds: None,
                identical: true,
            });
            let mut farms: Vec<(String, &Path, Option<Shape>)> = layouts
                .iter()
                .map(|&(w, t)| (format!("up {w}×{t}"), opts.exe.as_path(), Some((w, t))))
                .collect();
            if let Some(exe) = &opts.baseline {
                farms.push(("baseline up (its default)".into(), exe.as_path(), None));
            }
            for (layout, exe, shape) in farms {
                let farm = up(opts, exe, &work, &scene_path, &case, shape)?;
                let identical = farm.exr == direct.exr;
                tracing::info!(
                    case = case.name,
                    layout,
                    seconds = farm.seconds,
                    identical,
                    "farm"
                );
                rows.push(UpRow {
                    case: case.name.clone(),
                    layout,
                    round,
                    seconds: farm.seconds,
                    ratio: farm.seconds / direct.seconds,
                    peak_rss_mib: farm.peak_rss_mib,
                    processes: farm.processes,
                    cpu_seconds: farm.cpu_seconds,
                    server_cpu_seconds: farm.server_cpu_seconds,
                    identical,
                });
            }
        }
        listed.push(case);
    }
    let _ = std::fs::remove_dir_all(&work);
    let results = UpResults {
        machine: Machine::detect(threads),
        command_line: opts.command_line.clone(),
        cases: listed,
        rows,
    };
    let md = markdown(&results);
    write_file(&opts.out_dir.join("up.md"), md.as_bytes())?;
    let json = serde_json::to_vec_pretty(&results)
        .map_err(|e| BenchError::Invalid(format!("up results: {e}")))?;
    write_file(&opts.out_dir.join("up.json"), &json)?;
    Ok((results, md))
}

struct Rendered {
    seconds: f64,
    peak_rss_mib: f64,
    processes: usize,
    cpu_seconds: Option<f64>,
    server_cpu_seconds: Option<f64>,
    exr: Vec<u8>,
}

/// A process's CPU time (user + system) so far, and whether it has exited (a zombie, not yet
/// reaped: its times are final).
fn cpu_of(pid: u32) -> Option<(f64, bool)> {
    let stat = procfs::process::Process::new(i32::try_from(pid).ok()?)
        .ok()?
        .stat()
        .ok()?;
    let seconds = (stat.utime + stat.stime) as f64 / procfs::ticks_per_second() as f64;
    Some((seconds, stat.state == 'Z'))
}

/// The CPU seconds of `pids` together (`None` if one cannot be read).
fn cpu_sum(pids: &[u32]) -> Option<f64> {
    pids.iter().map(|&p| cpu_of(p).map(|(s, _)| s)).sum()
}

fn job_args(case: &UpCase) -> Vec<String> {
    vec![
        "--width".into(),
        case.width.to_string(),
        "--height".into(),
        case.height.to_string(),
        "--spp".into(),
        case.spp.to_string(),
    ]
}

/// A `pathfarm` command that runs on its arguments only, not on the caller's `PATHFARM_*`.
fn pathfarm(exe: &Path) -> Command {
    let mut cmd = Command::new(exe);
    for (k, _) in std::env::vars_os() {
        if k.to_string_lossy().starts_with("PATHFARM_") {
            cmd.env_remove(k);
        }
    }
    cmd.stdin(Stdio::null());
    cmd
}

fn render(
    opts: &UpOptions,
    work: &Path,
    scene: &Path,
    case: &UpCase,
    threads: usize,
) -> Result<Rendered, BenchError> {
    let out = work.join(format!("{}-render.exr", case.name));
    let log = work.join("render.log");
    let log_file = std::fs::File::create(&log).map_err(|e| BenchError::io(&log, e))?;
    let started = Instant::now();
    let mut child = pathfarm(&opts.exe)
        .arg("render")
        .arg(scene)
        .args(job_args(case))
        .args(["--threads", &threads.to_string(), "--out"])
        .arg(&out)
        .stdout(Stdio::null())
        .stderr(log_file)
        .spawn()
        .map_err(|e| farm_err(format!("cannot start {}: {e}", opts.exe.display())))?;
    let mut peak = PeakRss::default();
    // Reaped only once its times are final (a zombie's stat), so that they are exact.
    let (status, cpu_seconds) = loop {
        peak.sample(&[child.id()]);
        let cpu = cpu_of(child.id());
        if matches!(cpu, Some((_, false))) {
            std::thread::sleep(Duration::from_millis(50));
            continue;
        }
        match child.try_wait() {
            Ok(Some(status)) => break (status, cpu.map(|(s, _)| s)),
            Ok(None) => std::thread::sleep(Duration::from_millis(50)),
            Err(e) => return Err(farm_err(format!("waiting for the render: {e}"))),
        }
    };
    let seconds = started.elapsed().as_secs_f64();
    if !status.success() {
        return Err(farm_err(format!(
            "pathfarm render exited {status}; see {}",
            log.display()
        )));
    }
    Ok(Rendered {
        seconds,
        peak_rss_mib: peak.total_mib(),
        processes: 1,
        cpu_seconds,
        server_cpu_seconds: None,
        exr: std::fs::read(&out).map_err(|e| BenchError::io(&out, e))?,
    })
}

/// `pathfarm up` on a port of the system's choosing, on a fresh SQLite file; killed when dropped.
pub(crate) struct UpProcess {
    child: Child,
    pub url: String,
    /// Where its standard error goes.
    pub log: PathBuf,
}

impl Drop for UpProcess {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// (worker processes, threads each) of an `up`.
pub(crate) type Shape = (usize, usize);

impl UpProcess {
    /// Starts `exe up` with `shape` (its default layout if `None`) and returns once it listens
    /// and its `workers` worker processes have started (and had half a second to register: their
    /// start is not a job's time). Its database and log are `work/up.db` and `work/up.log`.
    pub(crate) fn start(
        exe: &Path,
        work: &Path,
        shape: Option<Shape>,
        workers: usize,
    ) -> Result<UpProcess, BenchError> {
        let db = work.join("up.db");
        for suffix in ["", "-wal", "-shm"] {
            let _ = std::fs::remove_file(format!("{}{suffix}", db.display()));
        }
        let log = work.join("up.log");
        let log_file = std::fs::File::create(&log).map_err(|e| BenchError::io(&log, e))?;
        let mut cmd = pathfarm(exe);
        cmd.args(["up", "--port", "0", "--db"])
            .arg(format!("sqlite://{}", db.display()));
        if let Some((workers, threads)) = shape {
            cmd.args(["--workers", &workers.to_string()])
                .args(["--threads-per-worker", &threads.to_string()]);
        }
        let mut child = cmd
            .stdout(Stdio::piped())
            .stderr(log_file)
            .spawn()
            .map_err(|e| farm_err(format!("cannot start {}: {e}", exe.display())))?;
        let stdout = child.stdout.take();
        let mut farm = UpProcess {
            child,
            url: String::new(),
            log,
        };
        let Some(stdout) = stdout else {
            return Err(farm_err("up's stdout is not piped"));
        };
        // `up` prints `pathfarm is up: dashboard and API at http://ADDR (…)` once it listens.
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in std::io::BufReader::new(stdout)
                .lines()
                .map_while(Result::ok)
            {
                if let Some(rest) = line.strip_prefix("pathfarm is up: dashboard and API at ") {
                    let url = rest.split_whitespace().next().unwrap_or_default();
                    let _ = tx.send(url.to_string());
                }
            }
        });
        farm.url = rx.recv_timeout(Duration::from_secs(60)).map_err(|_| {
            farm_err(format!(
                "pathfarm up did not start within a minute; see {}",
                farm.log.display()
            ))
        })?;
        let deadline = Instant::now() + Duration::from_secs(60);
        while children_of(farm.pid()).len() < workers {
            if Instant::now() > deadline {
                return Err(farm_err("up's workers did not start within a minute"));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        std::thread::sleep(Duration::from_millis(500));
        Ok(farm)
    }

    pub(crate) fn pid(&self) -> u32 {
        self.child.id()
    }
}

/// `exe`'s `up` with `shape`, or in its default layout.
fn up(
    opts: &UpOptions,
    exe: &Path,
    work: &Path,
    scene: &Path,
    case: &UpCase,
    shape: Option<Shape>,
) -> Result<Rendered, BenchError> {
    // Another build's default layout: at least one worker process (builds before November 29
    // started one per core, later ones one in all).
    let workers = shape.map_or(1, |(w, _)| w);
    let farm = UpProcess::start(exe, work, shape, workers)?;
    let up_pid = farm.pid();
    let out = work.join(format!("{}-farm.exr", case.name));
    let workers_of = || children_of(up_pid);
    let server_before = cpu_sum(&[up_pid]);
    let workers_before = cpu_sum(&workers_of());
    let mut submit = pathfarm(&opts.exe)
        .arg("submit")
        .arg(scene)
        .args(job_args(case))
        .args(["--server", &farm.url, "--wait", "--json", "--out"])
        .arg(&out)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .map_err(|e| farm_err(format!("cannot start pathfarm submit: {e}")))?;
    let mut peak = PeakRss::default();
    let status = loop {
        let mut pids = vec![up_pid];
        pids.extend(children_of(up_pid));
        peak.sample(&pids);
        match submit.try_wait() {
            Ok(Some(status)) => break status,
            Ok(None) => std::thread::sleep(Duration::from_millis(50)),
            Err(e) => return Err(farm_err(format!("waiting for pathfarm submit: {e}"))),
        }
    };
    let server_cpu = cpu_sum(&[up_pid])
        .zip(server_before)
        .map(|(after, before)| after - before);
    let workers_cpu = cpu_sum(&workers_of())
        .zip(workers_before)
        .map(|(after, before)| after - before);
    let mut answer = String::new();
    if let Some(mut s) = submit.stdout.take() {
        use std::io::Read;
        let _ = s.read_to_string(&mut answer);
    }
    if !status.success() {
        return Err(farm_err(format!(
            "pathfarm submit --wait exited {status}: {answer}; see {}",
            farm.log.display()
        )));
    }
    let view: serde_json::Value = serde_json::from_str(&answer)
        .map_err(|e| farm_err(format!("submit's answer is not JSON ({e}): {answer}")))?;
    let ms = |key: &str| view.get(key).and_then(serde_json::Value::as_i64);
    let (Some(created), Some(finished)) = (ms("created_at_ms"), ms("finished_at_ms")) else {
        return Err(farm_err(format!("the job has no start or end: {answer}")));
    };
    Ok(Rendered {
        seconds: (finished - created).max(1) as f64 / 1e3,
        peak_rss_mib: peak.total_mib(),
        processes: peak.max_kib.len(),
        cpu_seconds: server_cpu.zip(workers_cpu).map(|(s, w)| s + w),
        server_cpu_seconds: server_cpu,
        exr: std::fs::read(&out).map_err(|e| BenchError::io(&out, e))?,
    })
}

/// The children of `pid` (from `/proc/PID/task/*/children`).
pub(crate) fn children_of(pid: u32) -> Vec<u32> {
    let mut out = Vec::new();
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return out;
    };
    for task in tasks.flatten() {
        if let Ok(list) = std::fs::read_to_string(task.path().join("children")) {
            out.extend(
                list.split_whitespace()
                    .filter_map(|p| p.parse::<u32>().ok()),
            );
        }
    }
    out.sort_unstable();
    out.dedup();
    out
}

/// The peak resident set of each process seen.
#[derive(Default)]
struct PeakRss {
    max_kib: std::collections::BTreeMap<u32, u64>,
}

impl PeakRss {
    fn sample(&mut self, pids: &[u32]) {
        for &pid in pids {
            if let Some(kib) = status_kib(&pid.to_string(), "VmHWM:") {
                let e = self.max_kib.entry(pid).or_default();
                *e = (*e).max(kib);
            }
        }
    }

    fn total_mib(&self) -> f64 {
        self.max_kib.values().sum::<u64>() as f64 / 1024.0
    }
}

fn markdown(r: &UpResults) -> String {
    let mut md = String::new();
    let _ = writeln!(md, "# `pathfarm up` against `pathfarm render`\n");
    let _ = writeln!(
        md,
        "{} ({} logical cores), {} threads, {}. `{}`\n",
        r.machine.cpu, r.machine.logical_cores, r.machine.threads, r.machine.date, r.command_line
    );
    for c in &r.cases {
        let _ = writeln!(
            md,
            "- {}: {} triangles, {}×{}, {} spp",
            c.name, c.triangles, c.width, c.height, c.spp
        );
    }
    let _ = writeln!(
        md,
        "\nrender: the process's wall time; up: the job's time on the server's clock (both with \
         the scene's load). up W×T: W worker processes of T render threads each, each with \
         `up`'s default task lanes. Peak memory: the largest resident set of each process, \
         summed. CPU: user + system seconds of all its processes (the farm's from the \
         submission until the client has the image), and the server's part of it.\n"
    );
    let _ = writeln!(
        md,
        "| case | layout | round | seconds | ÷ render | CPU s | server CPU s | peak MiB | processes | identical |"
    );
    let _ = writeln!(md, "|---|---|---:|---:|---:|---:|---:|---:|---:|---|");
    let secs = |s: Option<f64>| s.map_or_else(|| "–".to_string(), |s| format!("{s:.2}"));
    for row in &r.rows {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:.2} | {:.3} | {} | {} | {:.0} | {} | {} |",
            row.case,
            row.layout,
            row.round,
            row.seconds,
            row.ratio,
            secs(row.cpu_seconds),
            secs(row.server_cpu_seconds),
            row.peak_rss_mib,
            row.processes,
            if row.identical { "yes" } else { "**no**" }
        );
    }
    md
}
