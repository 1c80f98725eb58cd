//! `pathfarm submit`: a job from a scene file, with `--wait` and `--out` to follow it and fetch
//! its image or frames.

use super::jobs::print_summary;
use super::{patiently, print_json, ClientArgs, WAIT_PATIENCE};
use crate::commands::output::{check_output, frame_path, OutFormat};
use crate::commands::render::{EnvironmentArgs, SettingsArgs};
use anyhow::{bail, Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use pathfarm_wire::api::{FrameOrder, JobSettings};
use pathfarm_worker::client::{ApiClient, Chunks, ClientError};
use std::path::PathBuf;
use std::time::Duration;

#[derive(Args, Debug)]
pub struct SubmitArgs {
    /// The scene: a .glb, or a .gltf with embedded data.
    pub scene: PathBuf,
    #[command(flatten)]
    pub settings: SettingsArgs,
    #[command(flatten)]
    pub environment: EnvironmentArgs,
    /// Tile size in pixels (does not change the result).
    #[arg(long, default_value_t = 64)]
    pub tile: u32,
    /// Stop once the estimated relative error falls below this (e.g. 0.02).
    #[arg(long)]
    pub noise_target: Option<f64>,
    /// Stop after this many seconds of rendering.
    #[arg(long)]
    pub time_limit: Option<f64>,
    /// Render these frames of the scene's animation, one image each: `1-240`, `1-240x2` (every
    /// second frame), `1,5,10-12`. Each frame's image is `render --frame N --fps F`'s.
    #[arg(long)]
    pub frames: Option<String>,
    /// Frames per second of --frames (frame f is time f / fps) [default: 24].
    #[arg(long, requires = "frames")]
    pub fps: Option<f64>,
    /// interleaved: every frame gets each pass before any gets the next (all sharpen together);
    /// sequential: frame after frame [default: interleaved].
    #[arg(long, requires = "frames", value_parser = parse_frame_order)]
    pub frame_order: Option<FrameOrder>,
    /// Priority: higher runs first; equal priorities share the farm (`pathfarm priority` changes
    /// it later).
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    pub priority: i32,
    /// The job's name in lists and the dashboard (default: the scene's file name).
    #[arg(long)]
    pub name: Option<String>,
    /// Camera name (default: the scene's first camera).
    #[arg(long)]
    pub camera: Option<String>,
    /// Wait for the job to finish, showing progress.
    #[arg(long)]
    pub wait: bool,
    /// With --wait: save the final image (.exr float32, or .png tone-mapped). Checked before
    /// submitting.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// PNG exposure in stops.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub exposure: f32,
    /// Print JSON: the submission's answer, or with --wait the finished job.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub client: ClientArgs,
}

fn parse_frame_order(s: &str) -> Result<FrameOrder, String> {
    match s {
        "interleaved" => Ok(FrameOrder::Interleaved),
        "sequential" => Ok(FrameOrder::Sequential),
        _ => Err(format!("{s:?}: interleaved or sequential")),
    }
}

/// Writes frames `frames` of frame job `id` to the files of `--out` pattern `out` (`#`s filled
/// with each frame's number), each fetched patiently; says so for each file (on stderr with
/// `--json`, whose stdout is the JSON).
pub(super) async fn write_frames(
    client: &ApiClient,
    id: &str,
    frames: &[i64],
    out: &std::path::Path,
    format: OutFormat,
    exposure: f32,
    json: bool,
) -> Result<()> {
    let quiet = |e: &ClientError| eprintln!("no answer from the server ({e}); retrying");
    for &frame in frames {
        let path = frame_path(out, frame).context("--out has no # for the frame number")?;
        let bytes = match format {
            OutFormat::Png => {
                patiently(
                    WAIT_PATIENCE,
                    || client.frame_png(id, frame, exposure),
                    quiet,
                )
                .await
            }
            OutFormat::Exr => patiently(WAIT_PATIENCE, || client.frame_exr(id, frame), quiet).await,
        }
        .with_context(|| format!("fetching frame {frame} of job {id}"))?;
        pathfarm_worker::files::write_atomic(&path, &bytes)
            .with_context(|| format!("cannot write {}", path.display()))?;
        if json {
            eprintln!("wrote {}", path.display());
        } else {
            println!("wrote {}", path.display());
        }
    }
    Ok(())
}

/// Writes a streamed download to `out` as it arrives: into a temporary file beside it, synced
/// and renamed at the end, so a cut transfer leaves no partial file. The bytes written.
pub(super) async fn write_streamed(mut chunks: Chunks, out: &std::path::Path) -> Result<u64> {
    use std::io::Write;
    let dir = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.part-{}", std::process::id()));
    let result: Result<u64> = async {
        let mut file = std::fs::File::create(&tmp)
            .with_context(|| format!("cannot write {}", tmp.display()))?;
        let mut written = 0u64;
        while let Some(chunk) = chunks.next().await.context("downloading")? {
            file.write_all(&chunk)
                .with_context(|| format!("cannot write {}", tmp.display()))?;
            written += chunk.len() as u64;
        }
        file.sync_all()
            .with_context(|| format!("cannot write {}", tmp.display()))?;
        std::fs::rename(&tmp, out).with_context(|| format!("cannot write {}", out.display()))?;
        Ok(written)
    }
    .await;
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

pub async fn submit(args: SubmitArgs) -> Result<()> {
    if args.out.is_some() && !args.wait {
        bail!("--out needs --wait");
    }
    // Refused here, before anything is read or sent, in the server's words.
    let frames = args
        .frames
        .as_deref()
        .map(pathfarm_wire::frames::parse_frames)
        .transpose()
        .map_err(|e| anyhow::anyhow!("--{e}"))?;
    // Before anything is submitted: a job must not run only for its image to be refused. A frame
    // job's --out names one file per frame (`shots/frame_####.exr`).
    let format = match (&args.out, &frames) {
        (Some(out), Some(frames)) => {
            let Some(first) = frames.first().and_then(|&f| frame_path(out, f)) else {
                bail!(
                    "--out {} with --frames must name one file per frame with a run of # that \
                     the frame number fills, e.g. shots/frame_####.exr",
                    out.display()
                );
            };
            Some(check_output(&first)?)
        }
        (out, _) => out.as_deref().map(check_output).transpose()?,
    };
    let client = args.client.client()?;
    let bytes = std::fs::read(&args.scene)
        .with_context(|| format!("cannot read {}", args.scene.display()))?;
    let (environment, environment_image) = match args.environment.job_settings()? {
        Some((settings, image)) => (Some(settings), image),
        None => (None, None),
    };
    let s = &args.settings;
    let mut settings = JobSettings::new(s.width, s.height, s.spp);
    settings.seed = s.seed;
    settings.direct = s.direct;
    settings.rr = s.rr;
    settings.max_depth = s.max_depth;
    settings.sampler = s.sampler;
    settings.tile_size = args.tile;
    settings.noise_target = args.noise_target;
    settings.time_limit_s = args.time_limit;
    settings.priority = args.priority;
    settings.name = args.name.clone();
    settings.camera = args.camera.clone();
    settings.environment = environment;
    settings.frames = args.frames.clone();
    settings.fps = args.fps;
    settings.frame_order = args.frame_order;
    let file_name = args
        .scene
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene".into());
    let created = client
        .submit_with_environment(bytes, &file_name, &settings, environment_image)
        .await
        .with_context(|| format!("submitting {}", args.scene.display()))?;
    if !args.wait {
        if args.json {
            print_json(&created)?;
        } else {
            println!("{}", created.id);
        }
        return Ok(());
    }
    if !args.json {
        println!("{}", created.id);
    }
    let bar = ProgressBar::new(created.samples_planned);
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {wide_bar} {percent}% {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let retry_message = |e: &ClientError| {
        bar.set_message(format!("no answer from the server ({e}); retrying"));
    };
    let job = loop {
        let j = patiently(WAIT_PATIENCE, || client.job(&created.id), retry_message)
            .await
            .with_context(|| {
                format!(
                    "waiting for job {} (it goes on; `pathfarm job {}` shows it)",
                    created.id, created.id
                )
            })?;
        bar.set_position(j.samples_done);
        bar.set_message(format!(
            "{} · {:.2} M samples/s · error {}",
            j.state.as_str(),
            j.samples_per_second / 1e6,
            j.relative_error
                .map_or("n/a".into(), |e| format!("{:.2}%", e * 100.0))
        ));
        if j.state.is_final() {
            break j;
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    bar.finish_and_clear();
    if !args.json {
        print_summary(&job);
    }
    if let (Some(out), Some(format), Some(frames)) = (&args.out, format, &frames) {
        write_frames(
            &client,
            &job.id,
            frames,
            out,
            format,
            args.exposure,
            args.json,
        )
        .await?;
    } else if let (Some(out), Some(format)) = (&args.out, format) {
        let quiet = |e: &ClientError| eprintln!("no answer from the server ({e}); retrying");
        let bytes = match format {
            OutFormat::Png => {
                patiently(
                    WAIT_PATIENCE,
                    || client.preview_png(&job.id, args.exposure),
                    quiet,
                )
                .await
            }
            OutFormat::Exr => {
                patiently(WAIT_PATIENCE, || client.image_exr(&job.id, false), quiet).await
            }
        }
        .with_context(|| format!("fetching the image of job {}", job.id))?;
        pathfarm_worker::files::write_atomic(out, &bytes)
            .with_context(|| format!("cannot write {}", out.display()))?;
        if args.json {
            eprintln!("wrote {}", out.display());
        } else {
            println!("wrote {}", out.display());
        }
    }
    if args.json {
        print_json(&job)?;
    }
    if job.state.as_str() != "completed" {
        bail!("job {} ended {}", job.id, job.state.as_str());
    }
    Ok(())
}
