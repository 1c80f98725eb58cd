//! `pathfarm bench frames`: what an animation costs on the farm. A frame job of the Blender suite's
//! animated export (a cube that slides and turns, a camera on an arc, a lamp that rises, a
//! skinned bar, a morphed sphere) against a still job of the same scene with the same total
//! samples (every frame's samples in one image), each on a fresh `pathfarm up` (real processes:
//! the server and one worker process of `threads` render threads): the ratio of their samples per second is the cost of building the scene at each frame (and
//! of a frame job's extra tiles and tasks); the time until every frame has its first pass is
//! what an artist waits for a first look at the whole shot.

use crate::error::{farm_err, write_file};
use crate::job_watch::watch_job;
use crate::up::UpProcess;
use crate::{BenchError, Machine};
use pathfarm_wire::api::{FrameOrder, JobSettings, JobState, JobView};
use pathfarm_worker::client::ApiClient;
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The animated scene, relative to the scenes directory.
const SCENE: &str = "suite/animated.glb";

#[derive(Clone, Debug)]
pub struct FramesOptions {
    /// The `pathfarm` binary, run as `up`.
    pub exe: PathBuf,
    pub out_dir: PathBuf,
    /// The shipped scenes (`scenes/` of the repository).
    pub scenes_dir: PathBuf,
    /// Render threads of the one worker process.
    pub threads: usize,
    pub quick: bool,
    pub seed: u64,
    pub command_line: String,
}

impl FramesOptions {
    /// Frames of the frame job: 240 (ten seconds at 24 fps), 24 with `quick`.
    pub fn frames(&self) -> u32 {
        if self.quick {
            24
        } else {
            240
        }
    }

    /// Image size and samples per pixel of each frame.
    pub fn frame_size(&self) -> (u32, u32, u32) {
        if self.quick {
            (32, 18, 2)
        } else {
            (160, 90, 16)
        }
    }
}

/// One job as the farm rendered it.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FramesRow {
    pub label: String,
    pub frames: u32,
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub samples: u64,
    /// `finished_at − started_at` of the job view (server clock: first lease to last merge).
    pub seconds: f64,
    pub samples_per_second: f64,
    /// From just before the submission until the job view first showed every tile (of every
    /// frame) with at least one sample per pixel.
    pub first_pass_seconds: Option<f64>,
    /// Tasks the job was planned in and slices merged into it (from the server's metrics).
    pub tasks: u64,
    pub slices: u64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FramesResults {
    pub command_line: String,
    pub machine: Machine,
    pub scene: String,
    pub rows: Vec<FramesRow>,
    /// The frame job's samples per second over the still job's (the default, interleaved order).
    pub ratio: f64,
    /// The same with the frames in sequence.
    pub sequential_ratio: f64,
}

fn job_seconds(view: &JobView) -> Result<f64, BenchError> {
    let (Some(start), Some(end)) = (view.started_at_ms, view.finished_at_ms) else {
        return Err(farm_err(format!(
            "job {} has no start or finish time",
            view.id
        )));
    };
    Ok((end - start).max(1) as f64 / 1e3)
}

/// The server's counts of finished tasks and merged slices (`/metrics`).
async fn task_and_slice_counts(url: &str) -> Result<(u64, u64), BenchError> {
    let text = reqwest::get(format!("{url}/metrics"))
        .await
        .and_then(reqwest::Response::error_for_status)
        .map_err(|e| farm_err(format!("reading {url}/metrics: {e}")))?
        .text()
        .await
        .map_err(|e| farm_err(format!("reading {url}/metrics: {e}")))?;
    let value = |name: &str| {
        text.lines()
            .find_map(|l| l.strip_prefix(name)?.trim().parse::<f64>().ok())
            .map(|v| v as u64)
            .ok_or_else(|| farm_err(format!("{url}/metrics has no {name}")))
    };
    Ok((
        value("pathfarm_tasks{state=\"done\"}")?,
        value("pathfarm_slice_uploads_merged_total")?,
    ))
}

/// Renders `settings` on a fresh `pathfarm up` with one worker process of `threads` threads and
/// measures it.
fn measure(
    exe: &Path,
    scene: &[u8],
    settings: &JobSettings,
    threads: usize,
    dir: &Path,
    label: &str,
) -> Result<FramesRow, BenchError> {
    let farm = UpProcess::start(exe, dir, Some((1, threads)), 1)?;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| farm_err(format!("cannot start the async runtime: {e}")))?;
    let (watched, tasks, slices) = rt.block_on(async {
        let client =
            ApiClient::new(&farm.url, None).map_err(|e| farm_err(format!("HTTP client: {e}")))?;
        let t0 = Instant::now();
        let created = client
            .submit(scene.to_vec(), "animated.glb", settings)
            .await
            .map_err(|e| farm_err(format!("submitting the {label}: {e}")))?;
        let watched = watch_job(
            &client,
            &created.id,
            t0,
            Duration::from_millis(20),
            Duration::from_secs(3600),
        )
        .await?;
        let (tasks, slices) = task_and_slice_counts(&farm.url).await?;
        Ok::<_, BenchError>((watched, tasks, slices))
    })?;
    drop(farm);
    let view = &watched.view;
    if view.state != JobState::Completed || view.samples_done != view.samples_planned {
        return Err(farm_err(format!(
            "{label}: job {} ended {} with {} of {} samples",
            view.id,
            view.state.as_str(),
            view.samples_done,
            view.samples_planned
        )));
    }
    let seconds = job_seconds(view)?;
    let row = FramesRow {
        label: label.to_string(),
        frames: view.frames_total.map_or(1, |n| n as u32),
        width: settings.width,
        height: settings.height,
        spp: settings.spp,
        samples: view.samples_planned,
        seconds,
        samples_per_second: view.samples_planned as f64 / seconds,
        first_pass_seconds: watched.first_preview.map(|d| d.as_secs_f64()),
        tasks,
        slices,
    };
    tracing::info!(
        job = label,
        seconds = row.seconds,
        samples_per_second = row.samples_per_second,
        first_pass = ?row.first_pass_seconds,
        "frames bench"
    );
    Ok(row)
}

/// Measures the frame job and the still job, writes `frames.md` and `frames.json` into
/// `out_dir`, and returns the results with the markdown. Synchronous: builds its own runtime.
pub fn run(opts: &FramesOptions) -> Result<(FramesResults, String), BenchError> {
    let scene_path = opts.scenes_dir.join(SCENE);
    let scene = std::fs::read(&scene_path).map_err(|e| BenchError::io(&scene_path, e))?;
    std::fs::create_dir_all(&opts.out_dir).map_err(|e| BenchError::io(&opts.out_dir, e))?;
    let dir = opts.out_dir.join("frames-work");
    std::fs::create_dir_all(&dir).map_err(|e| BenchError::io(&dir, e))?;
    let threads = opts.threads.max(1);
    let (width, height, spp) = opts.frame_size();
    let frames = opts.frames();
    let rows = (|| {
        let mut animation = JobSettings::new(width, height, spp);
        animation.seed = opts.seed;
        animation.frames = Some(format!("1-{frames}"));
        animation.fps = Some(24.0);
        let label = format!("{frames} frames, interleaved");
        let frame_row = measure(&opts.exe, &scene, &animation, threads, &dir, &label)?;
        // Frame after frame: each frame's scene built once by the worker, not once a pass.
        animation.frame_order = Some(FrameOrder::Sequential);
        let label = format!("{frames} frames, sequential");
        let sequential = measure(&opts.exe, &scene, &animation, threads, &dir, &label)?;
        let mut still = JobSettings::new(width, height, spp * frames);
        still.seed = opts.seed;
        let still_row = measure(&opts.exe, &scene, &still, threads, &dir, "still")?;
        Ok::<_, BenchError>(vec![frame_row, sequential, still_row])
    })();
    if let Err(e) = std::fs::remove_dir_all(&dir) {
        tracing::warn!(dir = %dir.display(), error = %e, "cannot remove the frames benchmark's scratch files");
    }
    let rows = rows?;
    let results = FramesResults {
        command_line: opts.command_line.clone(),
        machine: Machine::detect(threads),
        scene: SCENE.to_string(),
        ratio: rows[0].samples_per_second / rows[2].samples_per_second,
        sequential_ratio: rows[1].samples_per_second / rows[2].samples_per_second,
        rows,
    };
    let json = serde_json::to_vec_pretty(&results)
        .map_err(|e| BenchError::Invalid(format!("frames.json: {e}")))?;
    write_file(&opts.out_dir.join("frames.json"), &json)?;
    let md = markdown(&results);
    write_file(&opts.out_dir.join("frames.md"), md.as_bytes())?;
    Ok((results, md))
}

fn markdown(r: &FramesResults) -> String {
    let mut md = String::new();
    let _ = writeln!(md, "# Frame jobs\n");
    let _ = writeln!(
        md,
        "`{}` on {} ({} threads of {} cores), {}. Scene `scenes/{}`, each job on a fresh \
         `pathfarm up` with one worker process, SQLite.\n",
        r.command_line,
        r.machine.cpu,
        r.machine.threads,
        r.machine.logical_cores,
        r.machine.date,
        r.scene
    );
    let _ = writeln!(
        md,
        "| job | frames | size | spp | samples | seconds | samples/s | every frame's first pass, s | tasks | slices |"
    );
    let _ = writeln!(md, "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|");
    for row in &r.rows {
        let first = row
            .first_pass_seconds
            .map_or_else(|| "–".to_string(), |s| format!("{s:.2}"));
        let _ = writeln!(
            md,
            "| {} | {} | {}×{} | {} | {} | {:.2} | {:.3} M | {first} | {} | {} |",
            row.label,
            row.frames,
            row.width,
            row.height,
            row.spp,
            row.samples,
            row.seconds,
            row.samples_per_second / 1e6,
            row.tasks,
            row.slices
        );
    }
    let _ = writeln!(
        md,
        "\nWith the same total samples, the frame job renders at **{:.2}×** the still job's samples \
         per second in the default order (every frame's pass before any frame's next: the worker \
         builds each frame's scene once a pass) and at **{:.2}×** frame after frame (once a frame); \
         the rest is the frame job's tasks (a tile grid per frame) and their round trips.",
        r.ratio, r.sequential_ratio
    );
    md
}
