//! The command-line client, one command per API operation: `submit`, `jobs`, `job` (with `--out`
//! to download the image), `cancel`, `pause`, `resume`, `delete`, `priority`, `workers`. Every one
//! takes `--json` (the API's own JSON on stdout instead of text).

use super::output::{check_archive, check_output, frame_path, Archive, OutFormat};
use super::render::{EnvironmentArgs, SettingsArgs};
use anyhow::{bail, Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use pathfarm_wire::api::{EnvironmentSettings, FrameOrder, JobSettings, JobView, WorkerView};
use pathfarm_worker::client::{ApiClient, Chunks, ClientError};
use pathfarm_worker::retry;
use pathfarm_worker::secret::Secret;
use serde::{Deserialize, Serialize};
use std::future::Future;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// How long `submit --wait` keeps retrying while the server cannot answer (no connection, 5xx):
/// the job goes on without the client, so a server restart must not end the wait.
pub const WAIT_PATIENCE: Duration = Duration::from_secs(300);

/// Where the server is and how to authenticate (`[client]`; see `crate::config`).
#[derive(Args, Clone, Debug, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[command(next_help_heading = "Server")]
pub struct ClientArgs {
    /// The server's URL (http:// or https://).
    #[arg(long, env = "PATHFARM_SERVER", default_value = "http://127.0.0.1:8080")]
    pub server: String,
    /// Client token (when the server requires one).
    #[arg(long, env = "PATHFARM_TOKEN", hide_env_values = true)]
    pub token: Option<Secret>,
    /// PEM file of CA certificates to trust besides the system's, for an https:// server with its
    /// own or a self-signed certificate.
    #[arg(long, env = "PATHFARM_CA_CERT")]
    pub ca_cert: Option<PathBuf>,
}

impl ClientArgs {
    fn client(&self) -> Result<ApiClient> {
        Ok(ApiClient::with_ca_cert(
            &self.server,
            self.token.as_ref().map(|t| t.expose().to_string()),
            self.ca_cert.as_deref(),
        )?)
    }
}

/// Prints `value` as pretty JSON on stdout.
fn print_json<T: Serialize>(value: &T) -> Result<()> {
    println!(
        "{}",
        serde_json::to_string_pretty(value).context("cannot write JSON")?
    );
    Ok(())
}

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

/// Runs `call` until it succeeds or fails for good, under the one retry policy
/// (`pathfarm_worker::retry`: a transient failure — no answer, 5xx — is retried with full jitter,
/// the ceiling growing from 0.2 s to 5 s, never sooner than a `Retry-After`) for up to `patience`.
/// `on_retry` hears of each failure retried.
async fn patiently<T, F, Fut>(
    patience: Duration,
    call: F,
    mut on_retry: impl FnMut(&ClientError),
) -> Result<T, ClientError>
where
    F: FnMut() -> Fut,
    Fut: Future<Output = Result<T, ClientError>>,
{
    let limits = retry::Limits {
        deadline: Some(Instant::now() + patience),
        stop: None,
    };
    retry::retry(retry::CLIENT, limits, call, |e, _| on_retry(e)).await
}

/// Writes frames `frames` of frame job `id` to the files of `--out` pattern `out` (`#`s filled
/// with each frame's number), each fetched patiently; says so for each file (on stderr with
/// `--json`, whose stdout is the JSON).
async fn write_frames(
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
async fn write_streamed(mut chunks: Chunks, out: &std::path::Path) -> Result<u64> {
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

/// One line: the environment as `render` flags would give it.
fn environment_line(e: &EnvironmentSettings) -> String {
    let source = match (&e.radiance, &e.image) {
        (Some([r, g, b]), _) => format!("radiance {r},{g},{b}"),
        (None, Some(hash)) => format!("image {hash}"),
        (None, None) => "none".into(),
    };
    format!(
        "{source}, strength {}, rotation {}°",
        e.strength, e.rotation_degrees
    )
}

/// The job's summary, its environment, a frame job's frames and the scene loader's warnings.
fn print_details(j: &JobView) {
    print_summary(j);
    if let Some(e) = &j.settings.environment {
        println!("environment: {}", environment_line(e));
    }
    if let Some(frames) = j.frames.as_deref().filter(|f| !f.is_empty()) {
        println!(
            "frames ({} of {} complete; the job's error is the worst frame's):",
            j.frames_done.unwrap_or(0),
            frames.len()
        );
        println!("  {:>8}  {:>10}  {:>8}  state", "frame", "spp", "error");
        for f in frames {
            println!(
                "  {:>8}  {:>10}  {:>8}  {}",
                f.frame,
                f.samples_per_pixel,
                f.relative_error
                    .map_or("n/a".into(), |e| format!("{:.2}%", e * 100.0)),
                if f.complete { "complete" } else { "rendering" }
            );
        }
    }
    if !j.warnings.is_empty() {
        println!("scene warnings ({}):", j.warnings.len());
        for w in &j.warnings {
            println!("  {w}");
        }
    }
}

fn print_summary(j: &JobView) {
    println!(
        "job {} ({}): {}, {}/{} samples, {:.2} M samples/s, estimated relative error {}{}",
        j.id,
        j.name,
        j.state.as_str(),
        j.samples_done,
        j.samples_planned,
        j.samples_per_second / 1e6,
        j.relative_error
            .map_or("n/a".into(), |e| format!("{:.2}%", e * 100.0)),
        j.message
            .as_ref()
            .map_or(String::new(), |m| format!(" ({m})"))
    );
}

#[derive(Args, Debug)]
pub struct JobsArgs {
    /// Only jobs in this state (queued, running, paused, completed, cancelled, failed).
    #[arg(long)]
    pub state: Option<String>,
    /// Page of the list, from 1 (newest jobs first).
    #[arg(long, default_value_t = 1)]
    pub page: u32,
    /// Jobs per page (at most 500).
    #[arg(long, default_value_t = 50)]
    pub per_page: u32,
    /// Print the API's JSON page instead of a table.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub client: ClientArgs,
}

pub async fn jobs(args: JobsArgs) -> Result<()> {
    let list = args
        .client
        .client()?
        .jobs(args.state.as_deref(), args.page, args.per_page)
        .await
        .context("listing jobs")?;
    if args.json {
        return print_json(&list);
    }
    println!(
        "{:<32}  {:<10} {:>4} {:>7} {:>9} {:>11}  NAME",
        "ID", "STATE", "PRIO", "DONE", "ERROR", "FRAMES"
    );
    for j in &list.jobs {
        // A frame job's complete frames of its frames; "-" for a still job.
        let frames = match (j.frames_done, j.frames_total) {
            (Some(done), Some(total)) => format!("{done}/{total}"),
            _ => "-".into(),
        };
        println!(
            "{:<32}  {:<10} {:>4} {:>6.1}% {:>9} {:>11}  {}",
            j.id,
            j.state.as_str(),
            j.priority,
            100.0 * j.samples_done as f64 / j.samples_planned.max(1) as f64,
            j.relative_error
                .map_or("-".into(), |e| format!("{:.2}%", e * 100.0)),
            frames,
            j.name
        );
    }
    println!(
        "{} of {} jobs (page {})",
        list.jobs.len(),
        list.total,
        list.page
    );
    Ok(())
}

#[derive(Args, Debug)]
pub struct JobArgs {
    /// The job's id (as `submit` and `jobs` print it).
    pub id: String,
    /// Print the API's JSON of the job instead of text.
    #[arg(long)]
    pub json: bool,
    /// Download the job's image to this file: .exr (float32 linear, the exact accumulation) or
    /// .png (tone-mapped); the current image of an unfinished job; checked before downloading.
    /// A frame job's frames: a pattern with # (`shots/frame_####.exr`, one file per rendered
    /// frame), .tar (every rendered frame as EXR) or .apng (the complete frames, animated).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// With --out FILE.png or FILE.apng: exposure in stops.
    #[arg(
        long,
        default_value_t = 0.0,
        allow_negative_numbers = true,
        requires = "out"
    )]
    pub exposure: f32,
    /// With --out FILE.exr: add the `variance` and `samples` channels.
    #[arg(long, requires = "out")]
    pub extra_channels: bool,
    /// Print the job's convergence history instead of its details: the error against time, one
    /// line a point (seconds since the first lease, samples merged, estimated relative error,
    /// samples per second).
    #[arg(long, conflicts_with = "out")]
    pub history: bool,
    /// With --history: the history of this frame of a frame job.
    #[arg(long, requires = "history", allow_negative_numbers = true)]
    pub frame: Option<i64>,
    #[command(flatten)]
    pub client: ClientArgs,
}

/// `job ID --history`: the convergence history as the API gives it (`--json`) or as a table.
async fn history(args: &JobArgs) -> Result<()> {
    let client = args.client.client()?;
    let history = match args.frame {
        Some(frame) => client.frame_convergence(&args.id, frame).await,
        None => client.convergence(&args.id).await,
    }
    .with_context(|| format!("the convergence history of job {}", args.id))?;
    if args.json {
        return print_json(&history);
    }
    println!(
        "{:>10}  {:>14}  {:>14}  {:>12}",
        "seconds", "samples", "relative error", "samples/s"
    );
    for p in &history.points {
        let error = p
            .relative_error
            .map_or("-".to_string(), |e| format!("{:.3} %", e * 100.0));
        println!(
            "{:>10.2}  {:>14}  {:>14}  {:>12.0}",
            p.elapsed_s, p.samples_done, error, p.samples_per_second
        );
    }
    Ok(())
}

pub async fn job(args: JobArgs) -> Result<()> {
    if args.history {
        return history(&args).await;
    }
    // Checked before anything is downloaded: the folder, and an archive or image format.
    let archive = args
        .out
        .as_deref()
        .map(check_archive)
        .transpose()?
        .flatten();
    let pattern = args
        .out
        .as_deref()
        .filter(|out| archive.is_none() && frame_path(out, 0).is_some());
    let format = match (&args.out, archive, pattern) {
        (Some(_), Some(_), _) => None,
        (_, _, Some(out)) => Some(check_output(&frame_path(out, 0).unwrap_or_default())?),
        (out, _, _) => out.as_deref().map(check_output).transpose()?,
    };
    if args.extra_channels && format != Some(OutFormat::Exr) && args.out.is_some() {
        bail!("--extra-channels needs an .exr --out");
    }
    let client = args.client.client()?;
    let j = client
        .job(&args.id)
        .await
        .with_context(|| format!("job {}", args.id))?;
    let what = match (&args.out, archive, pattern, format) {
        (Some(out), Some(kind), _, _) => {
            let chunks = match kind {
                Archive::Tar => client.frames_tar(&j.id).await,
                Archive::Apng => client.preview_apng(&j.id, args.exposure).await,
            }
            .with_context(|| format!("downloading the frames of job {}", j.id))?;
            let bytes = write_streamed(chunks, out).await?;
            Some(format!("wrote {}, {bytes} bytes", out.display()))
        }
        (_, _, Some(out), Some(format)) => {
            let Some(frames) = j.frames.as_ref() else {
                bail!(
                    "--out {}: job {} is a still image; a # pattern names one file per frame of \
                     a frame job",
                    out.display(),
                    j.id
                );
            };
            let rendered: Vec<i64> = frames
                .iter()
                .filter(|f| f.samples_done > 0)
                .map(|f| f.frame)
                .collect();
            write_frames(
                &client,
                &j.id,
                &rendered,
                out,
                format,
                args.exposure,
                args.json,
            )
            .await?;
            Some(format!(
                "wrote {} frames to {}",
                rendered.len(),
                out.display()
            ))
        }
        (Some(out), None, None, Some(format)) => {
            let bytes = match format {
                OutFormat::Exr => client.image_exr(&j.id, args.extra_channels).await,
                OutFormat::Png => client.preview_png(&j.id, args.exposure).await,
            }
            .with_context(|| format!("downloading the image of job {}", j.id))?;
            pathfarm_worker::files::write_atomic(out, &bytes)
                .with_context(|| format!("cannot write {}", out.display()))?;
            Some(format!("wrote {}", out.display()))
        }
        _ => None,
    };
    if let Some(what) = what {
        let line = format!(
            "{what} (job {}: {}, {}/{} samples)",
            j.id,
            j.state.as_str(),
            j.samples_done,
            j.samples_planned
        );
        if args.json {
            eprintln!("{line}");
        } else {
            println!("{line}");
            return Ok(());
        }
    }
    if args.json {
        print_json(&j)
    } else {
        print_details(&j);
        Ok(())
    }
}

/// `cancel`, `pause`, `resume` and `delete`: one job by id.
#[derive(Args, Debug)]
pub struct JobActionArgs {
    /// The job's id (as `submit` and `jobs` print it).
    pub id: String,
    /// Print the API's JSON answer (the job; for `delete`, {"id", "deleted"}) instead of text.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub client: ClientArgs,
}

/// What a job command asks of the server.
#[derive(Clone, Copy, Debug)]
pub enum JobAction {
    Cancel,
    Pause,
    Resume,
    Delete,
}

#[derive(Serialize)]
struct Deleted<'a> {
    id: &'a str,
    deleted: bool,
}

pub async fn job_action(action: JobAction, args: JobActionArgs) -> Result<()> {
    let client = args.client.client()?;
    let verb = match action {
        JobAction::Cancel => "cancel",
        JobAction::Pause => "pause",
        JobAction::Resume => "resume",
        JobAction::Delete => {
            client
                .delete_job(&args.id)
                .await
                .with_context(|| format!("deleting job {}", args.id))?;
            if args.json {
                return print_json(&Deleted {
                    id: &args.id,
                    deleted: true,
                });
            }
            println!("deleted job {}", args.id);
            return Ok(());
        }
    };
    let j = client
        .job_action(&args.id, verb)
        .await
        .with_context(|| format!("{verb} job {}", args.id))?;
    if args.json {
        print_json(&j)
    } else {
        print_summary(&j);
        Ok(())
    }
}

#[derive(Args, Debug)]
pub struct PriorityArgs {
    /// The job's id (as `submit` and `jobs` print it).
    pub id: String,
    /// The new priority: higher runs first; equal priorities share the farm.
    #[arg(allow_negative_numbers = true)]
    pub priority: i32,
    /// Print the API's JSON of the job instead of text.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub client: ClientArgs,
}

pub async fn priority(args: PriorityArgs) -> Result<()> {
    let j = args
        .client
        .client()?
        .set_priority(&args.id, args.priority)
        .await
        .with_context(|| format!("setting the priority of job {}", args.id))?;
    if args.json {
        print_json(&j)
    } else {
        print_summary(&j);
        println!("priority {}", j.priority);
        Ok(())
    }
}

#[derive(Args, Debug)]
pub struct WorkersArgs {
    /// Print the API's JSON list instead of a table.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub client: ClientArgs,
}

fn print_worker(w: &WorkerView) {
    let state = if w.untrusted {
        format!("{}!", w.state.as_str())
    } else {
        w.state.as_str().to_string()
    };
    println!(
        "{:<24} {:<8} {:>7} {:>10.2} {:>13}  {}",
        w.name,
        state,
        w.threads,
        w.samples_per_second / 1e6,
        w.samples_done,
        w.current_job.as_deref().unwrap_or("-")
    );
}

pub async fn workers(args: WorkersArgs) -> Result<()> {
    let list = args
        .client
        .client()?
        .workers()
        .await
        .context("listing workers")?;
    if args.json {
        return print_json(&list);
    }
    println!(
        "{:<24} {:<8} {:>7} {:>10} {:>13}  JOB",
        "NAME", "STATE", "THREADS", "M SAMPLE/S", "SAMPLES"
    );
    for w in &list.workers {
        print_worker(w);
    }
    println!("{} workers", list.workers.len());
    if list.workers.iter().any(|w| w.untrusted) {
        println!("!: untrusted (merged a result other workers refuted; given no more work)");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against a real port nothing listens on: transient failures are retried until the patience
    /// runs out, then the last error is returned; a lasting failure is not retried.
    #[tokio::test]
    async fn transient_failures_are_retried_for_a_bounded_time() {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let client = ApiClient::new(&format!("http://127.0.0.1:{port}"), None).unwrap();
        let mut calls = 0;
        let mut retries = 0;
        let t = Instant::now();
        let e = patiently(
            Duration::from_millis(700),
            || {
                calls += 1;
                client.job("x")
            },
            |_| retries += 1,
        )
        .await
        .unwrap_err();
        assert!(e.is_transient(), "{e}");
        // Jittered waits (at most 0.2, 0.4, 0.8, … s) within 0.7 s: a few tries, each failure but
        // the last one retried.
        assert!(calls >= 2 && retries == calls - 1, "{calls} {retries}");
        assert!(
            t.elapsed() < Duration::from_millis(1500),
            "{:?}",
            t.elapsed()
        );

        let mut calls = 0;
        let e = patiently(
            Duration::from_secs(60),
            || {
                calls += 1;
                async { Err::<(), _>(ClientError::Protocol("bad".into())) }
            },
            |_| {},
        )
        .await
        .unwrap_err();
        assert!(!e.is_transient());
        assert_eq!(calls, 1);
    }
}
