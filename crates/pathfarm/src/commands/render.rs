//! `pathfarm render`: render a scene on this machine, in progressive passes, to EXR or PNG.

use super::output::{check_output, OutFormat};
use crate::resolver::DirectoryResolver;
use anyhow::{bail, Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use pathfarm_tracer::gltf::{self, LoadOptions};
use pathfarm_tracer::light::Environment;
use pathfarm_tracer::output::{decode_exr, encode_exr, encode_png, ExrChannels};
use pathfarm_tracer::{
    render_image, render_sample, Accumulation, DirectStrategy, RenderSettings, RussianRoulette,
    SamplerKind, Scene,
};
use pathfarm_wire::api::EnvironmentSettings;
use pathfarm_wire::{build_environment, EnvironmentSource as WireSource};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Render settings shared by `render` and (later) `submit`.
#[derive(Args, Clone, Debug)]
pub struct SettingsArgs {
    /// Image width in pixels.
    #[arg(long, default_value_t = 256)]
    pub width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 256)]
    pub height: u32,
    /// Samples (camera paths) per pixel.
    #[arg(long, default_value_t = 64)]
    pub spp: u32,
    /// Random seed: the image depends only on the scene, the settings and this.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Direct-lighting strategy: hemisphere, cosine, bsdf, light or mis.
    #[arg(long, default_value = "mis")]
    pub direct: DirectStrategy,
    /// Russian roulette: off, auto (the default: 0.5@0.1), max (survive with the largest throughput component after the 4th vertex), a fixed survival probability in (0, 1], or TERMINATE@BELOW
    /// (e.g. 0.5@0.25: terminate half of the paths whose throughput luminance is below 0.25).
    #[arg(long, default_value = "auto")]
    pub rr: RussianRoulette,
    /// Maximum number of bounces. Unlimited by default; a cap is biased (it drops longer paths).
    #[arg(long)]
    pub max_depth: Option<u32>,
    /// Sample generator: sobol (Owen-scrambled) or independent.
    #[arg(long, default_value = "sobol")]
    pub sampler: SamplerKind,
}

impl SettingsArgs {
    pub fn to_settings(&self) -> RenderSettings {
        RenderSettings {
            width: self.width,
            height: self.height,
            seed: self.seed,
            direct: self.direct,
            rr: self.rr,
            max_depth: self.max_depth,
            sampler: self.sampler,
        }
    }
}

/// The environment light, shared by `render` and `submit`: radiance from every direction a ray
/// leaves the scene in. glTF cannot carry Blender's world, so it is given here.
#[derive(Args, Clone, Debug, Default)]
pub struct EnvironmentArgs {
    /// Environment light: an equirectangular image (.exr or .hdr, mapped as Blender's Environment
    /// Texture maps it) or one linear radiance R,G,B (or a single grey value). None by default.
    #[arg(long, value_name = "FILE|R,G,B")]
    pub environment: Option<String>,
    /// Multiplies the environment's radiance.
    #[arg(long, default_value_t = 1.0, value_name = "S")]
    pub environment_strength: f32,
    /// Turns the environment image about the up axis, in degrees (as a Blender Mapping node's Z
    /// rotation on its vector).
    #[arg(
        long,
        default_value_t = 0.0,
        value_name = "DEGREES",
        allow_negative_numbers = true
    )]
    pub environment_rotation: f32,
}

/// A job's environment settings and the image to upload with them (bytes, file name), if any.
pub type JobEnvironment = (EnvironmentSettings, Option<(Vec<u8>, String)>);

/// What `--environment` names.
pub enum EnvironmentSource {
    Radiance(glam::Vec3),
    Image(PathBuf),
}

impl EnvironmentArgs {
    /// `--environment` read as a radiance when it is one or three numbers, as a file otherwise.
    pub fn source(&self) -> Option<EnvironmentSource> {
        let spec = self.environment.as_deref()?;
        let numbers: Result<Vec<f32>, _> = spec.split(',').map(|s| s.trim().parse()).collect();
        Some(match numbers.as_deref() {
            Ok(&[v]) => EnvironmentSource::Radiance(glam::Vec3::splat(v)),
            Ok(&[r, g, b]) => EnvironmentSource::Radiance(glam::Vec3::new(r, g, b)),
            _ => EnvironmentSource::Image(PathBuf::from(spec)),
        })
    }

    /// The environment for a local render, or None. Built by the wire crate's
    /// `build_environment`, the function a farm worker builds a job's environment with, so a
    /// render and a farm job with the same flags light the scene with the same bits.
    pub fn load(&self) -> Result<Option<Environment>> {
        let (strength, rotation) = (self.environment_strength, self.environment_rotation);
        let env = match self.source() {
            None => return Ok(None),
            Some(EnvironmentSource::Radiance(l)) => {
                build_environment(WireSource::Radiance(l.to_array()), strength, rotation)
                    .context("invalid --environment radiance or --environment-strength")?
            }
            Some(EnvironmentSource::Image(path)) => {
                let bytes = std::fs::read(&path).with_context(|| {
                    format!("cannot read the environment image {}", path.display())
                })?;
                build_environment(WireSource::Image(&bytes), strength, rotation)
                    .with_context(|| format!("cannot load the environment {}", path.display()))?
            }
        };
        Ok(Some(env))
    }

    /// The environment as a job's settings, and the image to upload with it (its bytes and file
    /// name), for `submit`. The image's hash is set by the server from the uploaded part.
    pub fn job_settings(&self) -> Result<Option<JobEnvironment>> {
        let mut settings = EnvironmentSettings {
            strength: self.environment_strength,
            rotation_degrees: self.environment_rotation,
            ..EnvironmentSettings::default()
        };
        Ok(Some(match self.source() {
            None => return Ok(None),
            Some(EnvironmentSource::Radiance(l)) => {
                settings.radiance = Some(l.to_array());
                settings.validate().context(
                    "invalid --environment radiance, --environment-strength or \
                     --environment-rotation",
                )?;
                (settings, None)
            }
            Some(EnvironmentSource::Image(path)) => {
                let bytes = std::fs::read(&path).with_context(|| {
                    format!("cannot read the environment image {}", path.display())
                })?;
                let name = path
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_else(|| "environment".into());
                (settings, Some((bytes, name)))
            }
        }))
    }
}

#[derive(Args, Debug)]
pub struct RenderArgs {
    /// The scene: a .gltf (with embedded data or files next to it) or a .glb.
    pub scene: PathBuf,
    #[command(flatten)]
    pub settings: SettingsArgs,
    #[command(flatten)]
    pub environment: EnvironmentArgs,
    /// Worker threads (default: one per core).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Stop after the pass during which this many seconds of rendering have elapsed; every pixel
    /// keeps the same number of samples.
    #[arg(long)]
    pub time_limit: Option<f64>,
    /// Tile size in pixels (does not change the result).
    #[arg(long, default_value_t = 32)]
    pub tile: u32,
    /// Camera name (default: the scene's first camera).
    #[arg(long)]
    pub camera: Option<String>,
    /// Render the scene at this frame of its animation (time = frame / fps; every animation of
    /// the file plays at once). Without it an animated file renders at rest.
    #[arg(long, allow_negative_numbers = true)]
    pub frame: Option<i64>,
    /// Frames per second of --frame.
    #[arg(long, default_value_t = gltf::DEFAULT_FPS, requires = "frame")]
    pub fps: f64,
    /// PNG exposure in stops (the PNG tone map is ×2^exposure, clamp, sRGB).
    #[arg(long, default_value_t = 0.0)]
    pub exposure: f32,
    /// Add `variance` and `samples` channels to an EXR output.
    #[arg(long)]
    pub extra_channels: bool,
    /// Re-render one sample alone and print it: X,Y,INDEX (for debugging a reported invalid sample).
    #[arg(long, value_name = "X,Y,INDEX")]
    pub debug_sample: Option<String>,
    /// A reference EXR of the same size: after every pass, print the elapsed time and the RMSE
    /// against it as a fraction of the reference's mean (for speed-against-accuracy measurements).
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// Output file: .exr (float32 linear) or .png (tone-mapped sRGB). Its folder must exist;
    /// checked before the scene is loaded.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Reads and loads a scene file.
pub fn load_scene(path: &Path, camera: Option<String>) -> Result<Scene> {
    let bytes =
        std::fs::read(path).with_context(|| format!("cannot read scene {}", path.display()))?;
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let resolver = DirectoryResolver { base };
    let scene = gltf::load(
        &bytes,
        &resolver,
        &LoadOptions {
            camera,
            ..LoadOptions::default()
        },
    )
    .with_context(|| format!("cannot load {}", path.display()))?;
    Ok(scene)
}

/// Reads a scene file and builds it at frame `frame` of its animation at `fps` frames per second
/// (a file without animations is its still scene, with a warning).
pub fn load_scene_at(path: &Path, camera: Option<String>, frame: i64, fps: f64) -> Result<Scene> {
    if !(fps.is_finite() && fps > 0.0) {
        bail!("--fps must be a positive number, not {fps}");
    }
    let bytes =
        std::fs::read(path).with_context(|| format!("cannot read scene {}", path.display()))?;
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let resolver = DirectoryResolver { base };
    let options = LoadOptions {
        camera,
        ..LoadOptions::default()
    };
    let source = gltf::SceneSource::load(&bytes, &resolver, &options)
        .with_context(|| format!("cannot load {}", path.display()))?;
    match source.time_span() {
        Some(span) => {
            let frames = span.frames(fps);
            tracing::info!(
                first_frame = frames.start(),
                last_frame = frames.end(),
                fps,
                seconds = span.end - span.start,
                "animation"
            );
            if !frames.contains(&frame) {
                tracing::warn!(
                    frame,
                    "frame outside the animation's keys: the nearest key's pose is rendered"
                );
            }
        }
        None => tracing::warn!("{} has no animations; --frame ignored", path.display()),
    }
    let time = gltf::frame_time(frame, fps);
    source
        .into_scene_at(time)
        .with_context(|| format!("cannot build {} at frame {frame}", path.display()))
}

pub fn run(args: RenderArgs) -> Result<()> {
    let settings = args.settings.to_settings();
    if settings.width == 0 || settings.height == 0 {
        bail!("--width and --height must be positive");
    }
    if args.settings.spp == 0 && args.debug_sample.is_none() {
        bail!("--spp must be positive");
    }
    // The output file is checked before anything is loaded or rendered.
    let out = match (&args.out, &args.debug_sample) {
        (Some(out), _) => Some((out.clone(), check_output(out)?)),
        (None, Some(_)) => None,
        (None, None) => bail!("--out FILE.exr|FILE.png is required"),
    };
    if let Some(threads) = args.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads.max(1))
            .build_global()
            .context("cannot start threads")?;
    }
    let t_load = Instant::now();
    let environment = args.environment.load()?;
    let scene = match args.frame {
        Some(frame) => load_scene_at(&args.scene, args.camera.clone(), frame, args.fps)?,
        None => load_scene(&args.scene, args.camera.clone())?,
    }
    .with_environment(environment);
    let info = &scene.info;
    tracing::info!(
        triangles = info.triangles,
        degenerate_dropped = info.degenerate_dropped,
        emissive_triangles = info.emissive_triangles,
        punctual_lights = info.punctual_lights,
        megabytes = info.bytes as f64 / 1e6,
        seconds = t_load.elapsed().as_secs_f64(),
        "scene loaded"
    );

    if let Some(spec) = &args.debug_sample {
        let parts: Vec<u32> = spec
            .split(',')
            .map(|s| s.trim().parse())
            .collect::<Result<_, _>>()
            .context("--debug-sample expects X,Y,INDEX")?;
        let [x, y, index] = parts[..] else {
            bail!("--debug-sample expects X,Y,INDEX")
        };
        if x >= settings.width || y >= settings.height {
            bail!(
                "pixel ({x}, {y}) is outside the {}x{} image",
                settings.width,
                settings.height
            );
        }
        let r = render_sample(&scene, &settings, x, y, index);
        println!(
            "sample ({x}, {y}) #{index}: radiance = ({}, {}, {}), {} vertices, {} rays",
            r.radiance.x, r.radiance.y, r.radiance.z, r.vertices, r.rays
        );
        return Ok(());
    }
    let Some((out, format)) = out else {
        bail!("--out FILE.exr|FILE.png is required")
    };

    let reference = match &args.reference {
        Some(path) => {
            let bytes =
                std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
            let img =
                decode_exr(&bytes).with_context(|| format!("cannot decode {}", path.display()))?;
            if (img.width, img.height) != (settings.width as usize, settings.height as usize) {
                bail!(
                    "reference is {}x{}, the render {}x{}",
                    img.width,
                    img.height,
                    settings.width,
                    settings.height
                );
            }
            Some([
                img.channel("R")?.to_vec(),
                img.channel("G")?.to_vec(),
                img.channel("B")?.to_vec(),
            ])
        }
        None => None,
    };
    let (acc, elapsed) = render_progressive(
        &scene,
        &settings,
        args.settings.spp,
        args.tile,
        args.time_limit,
        reference.as_ref(),
    );
    let samples = acc.total_samples();
    let secs = elapsed.as_secs_f64();
    let bytes = match format {
        OutFormat::Png => encode_png(&acc, args.exposure)?,
        OutFormat::Exr => encode_exr(
            &acc,
            ExrChannels {
                variance: args.extra_channels,
                samples: args.extra_channels,
            },
        )?,
    };
    pathfarm_worker::files::write_atomic(&out, &bytes)
        .with_context(|| format!("cannot write {}", out.display()))?;
    if acc.invalid_count > 0 {
        // One line for them all (the tracer counts them rather than logging each).
        let first = acc
            .invalid
            .first()
            .map_or("-".to_string(), |s| format!("{},{},{}", s.x, s.y, s.index));
        tracing::warn!(
            count = acc.invalid_count,
            first = %first,
            "invalid samples (NaN, infinite, negative or huge) were dropped; re-render one with \
             --debug-sample X,Y,INDEX (the first: --debug-sample {first})"
        );
    }
    let rel = acc
        .relative_error()
        .map_or("n/a".to_string(), |e| format!("{:.2}%", e * 100.0));
    println!(
        "rendered {} in {:.3} s: {} spp, {:.2} M samples/s, {:.2} M rays/s, estimated relative error {}, {} invalid samples",
        out.display(),
        secs,
        samples / (settings.width as u64 * settings.height as u64),
        samples as f64 / secs / 1e6,
        acc.rays as f64 / secs / 1e6,
        rel,
        acc.invalid_count
    );
    Ok(())
}

/// RMSE of the mean image against a reference, over all pixels and channels, divided by the
/// reference's mean.
pub fn relative_rmse(acc: &Accumulation, reference: &[Vec<f32>; 3]) -> f64 {
    let mut se = 0.0;
    let mut sum = 0.0;
    for (i, p) in acc.pixels.iter().enumerate() {
        let m = p.mean();
        for c in 0..3 {
            let r = reference[c][i] as f64;
            se += (m[c] - r) * (m[c] - r);
            sum += r;
        }
    }
    let n = acc.pixels.len() as f64 * 3.0;
    (se / n).sqrt() / (sum / n)
}

/// Renders in passes of growing sample ranges ([0,1), [1,2), [2,4), … up to `spp`), so a time limit
/// ends on a pass boundary with every pixel equally sampled. Returns the image and the render time.
pub fn render_progressive(
    scene: &Scene,
    settings: &RenderSettings,
    spp: u32,
    tile: u32,
    time_limit: Option<f64>,
    reference: Option<&[Vec<f32>; 3]>,
) -> (Accumulation, Duration) {
    let pixels = settings.width as u64 * settings.height as u64;
    let bar = ProgressBar::new(pixels * spp as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {wide_bar} {percent}% {msg} ETA {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let done = AtomicU64::new(0);
    let start = Instant::now();
    let mut image = Accumulation::new(0, 0, settings.width, settings.height);
    let mut begin = 0u32;
    while begin < spp {
        let end = if begin == 0 { 1 } else { (begin * 2).min(spp) };
        let pass = render_image(scene, settings, tile, begin..end, &|n| {
            let total = done.fetch_add(n, Ordering::Relaxed) + n;
            bar.set_position(total);
        });
        // Same-size accumulations always merge.
        let _ = image.merge(&pass);
        begin = end;
        let secs = start.elapsed().as_secs_f64();
        if let Some(reference) = reference {
            // The comparison costs about a millisecond; it is included in later passes' times.
            bar.suspend(|| {
                println!(
                    "pass to {begin:>5} spp: {secs:8.3} s, RMSE {:.2}% of the reference mean",
                    relative_rmse(&image, reference) * 100.0
                )
            });
        }
        bar.set_message(format!(
            "{begin} spp, {:.2} M samples/s",
            image.total_samples() as f64 / secs / 1e6
        ));
        if let Some(limit) = time_limit {
            if secs >= limit {
                tracing::info!(spp = begin, seconds = secs, "time limit reached");
                break;
            }
        }
    }
    bar.finish_and_clear();
    (image, start.elapsed())
}
