//! `pathfarm bench frames`: what an animation costs on the farm. A frame job of the Blender suite's
//! animated export (a cube that slides and turns, a camera on an arc, a lamp that rises, a
//! skinned bar, a morphed sphere) against a still job of the same scene with the same total
//! samples (every frame's samples in one image), on one in-process farm with the same worker:
//! the ratio of their samples per second is the cost of building the scene at each frame (and
//! of a frame job's extra tiles and tasks); the time until every frame has its first pass is
//! what an artist waits for a first look at the whole shot.

use super::harness::{farm_err, unique_suffix, watch_job, Server, StoreSpec, WorkerSetup, Workers};
use crate::error::write_file;
use crate::{BenchError, Machine};
use pathfarm_server::ServerConfig;
use pathfarm_wire::api::{FrameOrder, JobSettings, JobState, JobView};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The animated scene, relative to the scenes directory.
const SCENE: &str = "suite/animated.glb";

#[derive(Clone, Debug)]
pub struct FramesOptions {
    pub out_dir: PathBuf,
    /// The shipped scenes (`scenes/` of the repository).
    pub scenes_dir: PathBuf,
    /// Render threads of the one worker.
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

/// Renders `settings` on a fresh worker of the farm at `server` and measures it.
async fn measure(
    server: &Server,
    scene: &[u8],
    settings: &JobSettings,
    threads: usize,
    dir: &Path,
    label: &str,
) -> Result<FramesRow, BenchError> {
    let client = server.client()?;
    let setup = WorkerSetup {
        threads,
        slice_seconds: 1.0,
        idle_poll: Duration::from_millis(20),
    };
    let tag = unique_suffix();
    let ws = Workers::start(server, 1, &setup, &dir.join(format!("cache-{tag}")), &tag).await?;
    let t0 = Instant::now();
    let watched = async {
        let created = client
            .submit(scene.to_vec(), "animated.glb", settings)
            .await
            .map_err(|e| farm_err(format!("submitting the {label}: {e}")))?;
        watch_job(
            &client,
            &created.id,
            t0,
            Duration::from_millis(20),
            Duration::from_secs(3600),
        )
        .await
    }
    .await;
    let report = ws.stop().await;
    let watched = watched?;
    let report = report?;
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
        tasks: report.tasks,
        slices: report.slices,
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
    let dir = std::env::temp_dir().join(format!("pathfarm-bench-frames-{}", unique_suffix()));
    std::fs::create_dir_all(&dir).map_err(|e| BenchError::io(&dir, e))?;
    let threads = opts.threads.max(1);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("frames-bench")
        .enable_all()
        .build()
        .map_err(|e| farm_err(format!("cannot start the async runtime: {e}")))?;
    let (width, height, spp) = opts.frame_size();
    let frames = opts.frames();
    let rows = rt.block_on(async {
        let store = StoreSpec::sqlite(&dir, "frames.db")?;
        let server = Server::start(ServerConfig::new(store.url())).await?;
        let result = async {
            let mut animation = JobSettings::new(width, height, spp);
            animation.seed = opts.seed;
            animation.frames = Some(format!("1-{frames}"));
            animation.fps = Some(24.0);
            let label = format!("{frames} frames, interleaved");
            let frame_row = measure(&server, &scene, &animation, threads, &dir, &label).await?;
            // Frame after frame: each frame's scene built once by the worker, not once a pass.
            animation.frame_order = Some(FrameOrder::Sequential);
            let label = format!("{frames} frames, sequential");
            let sequential = measure(&server, &scene, &animation, threads, &dir, &label).await?;
            let mut still = JobSettings::new(width, height, spp * frames);
            still.seed = opts.seed;
            let still_row = measure(&server, &scene, &still, threads, &dir, "still").await?;
            Ok::<_, BenchError>(vec![frame_row, sequential, still_row])
        }
        .await;
        let stopped = server.stop().await;
        let rows = result?;
        stopped?;
        Ok::<_, BenchError>(rows)
    });
    drop(rt);
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
        "`{}` on {} ({} threads of {} cores), {}. Scene `scenes/{}`, one in-process worker, \
         SQLite.\n",
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The quick run measures both jobs whole (every sample merged, every frame's first pass
    /// seen) and writes its report.
    #[test]
    fn the_quick_run_measures_a_frame_job_against_a_still_one() {
        let out = std::env::temp_dir().join(format!("pathfarm-frames-bench-{}", unique_suffix()));
        let opts = FramesOptions {
            out_dir: out.clone(),
            scenes_dir: PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes")),
            threads: 1,
            quick: true,
            seed: 3,
            command_line: "test".into(),
        };
        let (r, md) = run(&opts).unwrap();
        let (w, h, spp) = opts.frame_size();
        let samples = u64::from(w * h * spp * opts.frames());
        assert_eq!(r.rows.len(), 3);
        let frames: Vec<u32> = r.rows.iter().map(|row| row.frames).collect();
        assert_eq!(frames, [opts.frames(), opts.frames(), 1]);
        assert!(
            r.rows.iter().all(|row| row.samples == samples),
            "{:?}",
            r.rows
        );
        assert!(r.rows[0].first_pass_seconds.is_some(), "{:?}", r.rows[0]);
        assert!(
            r.rows[0].tasks >= u64::from(opts.frames()),
            "{:?}",
            r.rows[0]
        );
        assert!(r.ratio > 0.0 && r.ratio.is_finite(), "{}", r.ratio);
        assert!(r.sequential_ratio > 0.0 && r.sequential_ratio.is_finite());
        assert!(md.contains("24 frames"), "{md}");
        assert!(out.join("frames.json").is_file() && out.join("frames.md").is_file());
        let _ = std::fs::remove_dir_all(&out);
    }
}
