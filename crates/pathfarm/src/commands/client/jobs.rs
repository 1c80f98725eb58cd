//! `pathfarm jobs` and `pathfarm job`: the job list, one job's details, image, frames or
//! convergence history.

use super::submit::{write_frames, write_streamed};
use super::{print_json, ClientArgs};
use crate::commands::output::{check_archive, check_output, frame_path, Archive, OutFormat};
use anyhow::{bail, Context, Result};
use clap::Args;
use pathfarm_wire::api::{EnvironmentSettings, JobView};
use std::path::PathBuf;

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

pub(super) fn print_summary(j: &JobView) {
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
