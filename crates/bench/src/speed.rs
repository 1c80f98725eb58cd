//! `pathfarm bench speed`: the tracer's speed targets, measured one by one and judged.
//!
//! Three measurements, in this order:
//! 1. `million`: the generated million-triangle scene — load and BVH build time, throughput at
//!    256×256 × 4 spp, and the process's peak resident memory (`VmHWM`) right after. It runs first
//!    so that the peak belongs to it: nothing before it has held more memory.
//! 2. `sphere330k`: the Cornell box plus a displaced sphere of 327,680 triangles — `Scene::build`
//!    (best of 3) and throughput at 256×256 × 16 spp.
//! 3. `cornell`: the shipped Cornell box at 256×256 — throughput at 64 spp (best of 3), and error
//!    against time: passes [0,1), [1,2), [2,4), … merged exactly into one accumulation, each
//!    measured against the independent Mitsuba reference `../shared/refs/cornell.exr`.
//!
//! Every render is MIS, Russian roulette `auto`, unlimited depth, Sobol, on a rayon pool of
//! exactly `threads` threads, through the bench's own [`render_range`] (the tracer's bits).

use crate::error::{write_file, BenchError};
use crate::render::{render_range, Rendered};
use crate::{scenes, Machine};
use pathfarm_tracer::output::{decode_exr, FloatImage};
use pathfarm_tracer::{
    Accumulation, DirectStrategy, RenderSettings, RussianRoulette, SamplerKind, Scene,
};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

mod report;

pub use report::markdown;
use report::targets;

/// The targets of the tracer's speed issue (set for 2 render threads). Cornell box throughput:
pub const TARGET_CORNELL_SAMPLES_PER_S: f64 = 6e6;
/// Relative RMSE ≤ 10 % within this many seconds of rendering.
pub const TARGET_10PCT_SECONDS: f64 = 1.3;
/// Relative RMSE ≤ 5 % within this many seconds of rendering.
pub const TARGET_5PCT_SECONDS: f64 = 3.5;
pub const TARGET_330K_BUILD_SECONDS: f64 = 0.5;
pub const TARGET_330K_SAMPLES_PER_S: f64 = 2e6;
/// Peak resident memory with the million-triangle scene loaded and rendered, MiB (1 GiB).
pub const TARGET_MILLION_RSS_MIB: f64 = 1024.0;

/// Image size of every render.
const SIZE: u32 = 256;
const MILLION_SPP: u32 = 4;
const SPHERE_SPP: u32 = 16;
const THROUGHPUT_SPP: u32 = 64;
/// Repetitions whose best is reported (the fastest run is the least disturbed by the machine).
const REPEATS: usize = 3;

/// What to run and where to write it.
#[derive(Clone, Debug)]
pub struct SpeedOptions {
    pub out_dir: PathBuf,
    /// The shipped scenes (`scenes/` of the repository).
    pub scenes_dir: PathBuf,
    /// The independent reference of the Cornell box (RGB EXR at 256×256).
    pub reference: PathBuf,
    pub threads: usize,
    pub seed: u64,
    /// The error-against-time passes stop at this many samples per pixel …
    pub max_spp: u32,
    /// … or after the pass during which this much render time has been spent, seconds.
    pub time_limit: f64,
    /// The command line, written into the report.
    pub command_line: String,
}

impl SpeedOptions {
    pub fn new(out_dir: PathBuf, scenes_dir: PathBuf) -> SpeedOptions {
        SpeedOptions {
            reference: default_reference(&scenes_dir),
            out_dir,
            scenes_dir,
            threads: 2,
            seed: 1,
            max_spp: 1024,
            time_limit: 10.0,
            command_line: String::new(),
        }
    }
}

/// `../shared/refs/cornell.exr` beside the repository whose `scenes/` is `scenes_dir`.
pub fn default_reference(scenes_dir: &Path) -> PathBuf {
    scenes_dir
        .parent()
        .unwrap_or(Path::new("."))
        .join("../shared/refs/cornell.exr")
}

/// One timed render.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Throughput {
    pub spp: u32,
    pub seconds: f64,
    /// Camera samples (pixels × spp) per second.
    pub samples_per_second: f64,
    pub rays_per_second: f64,
}

impl Throughput {
    fn of(r: &Rendered, spp: u32) -> Throughput {
        let samples = u64::from(r.acc.width) * u64::from(r.acc.height) * u64::from(spp);
        let s = r.seconds.max(1e-9);
        Throughput {
            spp,
            seconds: r.seconds,
            samples_per_second: samples as f64 / s,
            rays_per_second: r.acc.rays as f64 / s,
        }
    }
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MillionResult {
    pub triangles: usize,
    /// Generating the sphere, loading the box and building the scene (BVH included), seconds.
    pub build_seconds: f64,
    pub render: Throughput,
    /// The tracer's own estimate of the scene's geometry, BVH and textures, MiB.
    pub scene_mib: f64,
    /// `VmHWM` of the whole bench process after the render, MiB; `None` where `/proc` is missing.
    pub peak_rss_mib: Option<f64>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SphereResult {
    pub triangles: usize,
    /// The fastest `Scene::build` of the parts (the sphere generated beforehand), seconds.
    pub build_seconds: f64,
    pub build_runs: Vec<f64>,
    /// The fastest of the throughput runs.
    pub render: Throughput,
    /// Every throughput run's seconds (this VM's speed drifts, so one run says little).
    pub render_runs: Vec<f64>,
}

/// One pass of the error-against-time measurement.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct Pass {
    /// Samples per pixel after the pass.
    pub spp: u32,
    /// Cumulative render time, seconds (error computations and merges not counted).
    pub seconds: f64,
    pub rel_rmse: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Convergence {
    pub reference: String,
    /// Mean of the reference over every pixel and channel (the denominator of the rel. RMSE).
    pub reference_mean: f64,
    /// The reference's own noise as a rel. RMSE (from `cornell.stderr.exr` beside it, when there):
    /// part of every measured error, in quadrature; not subtracted.
    pub reference_noise: Option<f64>,
    pub passes: Vec<Pass>,
    /// Interpolated render time at which the rel. RMSE first reaches 10 % / 5 %.
    pub seconds_to_10pct: Option<f64>,
    pub seconds_to_5pct: Option<f64>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct CornellResult {
    /// The fastest of the runs.
    pub throughput: Throughput,
    pub throughput_runs: Vec<f64>,
    pub convergence: Option<Convergence>,
    /// Why the error-against-time part was skipped.
    pub skipped: Option<String>,
}

/// One target and whether it was met (`None`: not measured).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Target {
    pub what: String,
    pub goal: String,
    pub measured: String,
    pub met: Option<bool>,
}

/// Everything `speed.json` holds.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SpeedResults {
    pub command_line: String,
    pub machine: Machine,
    pub size: u32,
    pub seed: u64,
    pub million: MillionResult,
    pub sphere330k: SphereResult,
    pub cornell: CornellResult,
    pub targets: Vec<Target>,
}

/// Runs the three measurements on a pool of exactly `opts.threads` threads, writes `speed.md` and
/// `speed.json` into `opts.out_dir`, and returns the results with the Markdown.
pub fn run(opts: &SpeedOptions) -> Result<(SpeedResults, String), BenchError> {
    // Before measuring: an unwritable output directory should not cost a minute of rendering.
    std::fs::create_dir_all(&opts.out_dir).map_err(|e| BenchError::io(&opts.out_dir, e))?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(opts.threads.max(1))
        .build()
        .map_err(|e| BenchError::Invalid(format!("cannot start {} threads: {e}", opts.threads)))?;
    let (million, sphere330k, cornell) = pool.install(|| -> Result<_, BenchError> {
        Ok((million(opts)?, sphere330k(opts)?, cornell(opts)?))
    })?;
    let targets = targets(&million, &sphere330k, &cornell);
    let results = SpeedResults {
        command_line: opts.command_line.clone(),
        machine: Machine::detect(opts.threads.max(1)),
        size: SIZE,
        seed: opts.seed,
        million,
        sphere330k,
        cornell,
        targets,
    };
    let json = serde_json::to_vec_pretty(&results)
        .map_err(|e| BenchError::Invalid(format!("speed.json: {e}")))?;
    write_file(&opts.out_dir.join("speed.json"), &json)?;
    let md = markdown(&results);
    write_file(&opts.out_dir.join("speed.md"), md.as_bytes())?;
    Ok((results, md))
}

/// MIS, roulette `auto`, unlimited depth, Sobol: the tracer's defaults, spelled out (also the
/// settings of the `throughput` and `wavefront_ceiling` examples).
pub fn settings(width: u32, height: u32, seed: u64) -> RenderSettings {
    RenderSettings {
        width,
        height,
        seed,
        direct: DirectStrategy::Mis,
        rr: RussianRoulette::Auto,
        max_depth: None,
        sampler: SamplerKind::Sobol,
    }
}

fn million(opts: &SpeedOptions) -> Result<MillionResult, BenchError> {
    tracing::info!("million: generating, loading and building");
    let loaded = scenes::load(&scenes::find("million")?, &opts.scenes_dir)?;
    let r = render_range(
        &loaded.scene,
        &settings(SIZE, SIZE, opts.seed),
        0..MILLION_SPP,
    );
    let peak_rss_mib = match peak_rss_kib() {
        Ok(kib) => Some(kib as f64 / 1024.0),
        Err(e) => {
            tracing::warn!(error = %e, "cannot read the peak resident memory");
            None
        }
    };
    let result = MillionResult {
        triangles: loaded.triangles,
        build_seconds: loaded.build_seconds,
        render: Throughput::of(&r, MILLION_SPP),
        scene_mib: loaded.scene.info.bytes as f64 / (1024.0 * 1024.0),
        peak_rss_mib,
    };
    tracing::info!(?result, "million measured");
    Ok(result)
}

fn sphere330k(opts: &SpeedOptions) -> Result<SphereResult, BenchError> {
    tracing::info!("sphere330k: generating and building");
    let (parts, _) =
        scenes::cornell_with_sphere("sphere330k", &opts.scenes_dir, scenes::FREQ_330K)?;
    let mut build_runs = Vec::with_capacity(REPEATS);
    let mut scene = None;
    for _ in 0..REPEATS {
        // The clone is not timed: `Scene::build` consumes its parts.
        let p = parts.clone();
        let started = Instant::now();
        let built = Scene::build(p).map_err(|e| BenchError::Scene {
            name: "sphere330k".into(),
            message: e.to_string(),
        })?;
        build_runs.push(started.elapsed().as_secs_f64());
        scene = Some(built); // the previous scene is dropped here, after the timer
    }
    drop(parts);
    let scene = scene.ok_or_else(|| BenchError::Invalid("no build ran".into()))?;
    let (render, render_runs) =
        best_throughput(&scene, &settings(SIZE, SIZE, opts.seed), SPHERE_SPP)?;
    let result = SphereResult {
        triangles: scene.info.triangles,
        build_seconds: build_runs.iter().copied().fold(f64::INFINITY, f64::min),
        build_runs,
        render,
        render_runs,
    };
    tracing::info!(?result, "sphere330k measured");
    Ok(result)
}

/// The fastest of [`REPEATS`] renders of `spp` samples per pixel, and every run's seconds.
fn best_throughput(
    scene: &Scene,
    settings: &RenderSettings,
    spp: u32,
) -> Result<(Throughput, Vec<f64>), BenchError> {
    let mut best: Option<Throughput> = None;
    let mut runs = Vec::with_capacity(REPEATS);
    for _ in 0..REPEATS {
        let t = Throughput::of(&render_range(scene, settings, 0..spp), spp);
        runs.push(t.seconds);
        if best.as_ref().is_none_or(|b| t.seconds < b.seconds) {
            best = Some(t);
        }
    }
    let best = best.ok_or_else(|| BenchError::Invalid("no throughput run".into()))?;
    Ok((best, runs))
}

fn cornell(opts: &SpeedOptions) -> Result<CornellResult, BenchError> {
    let loaded = scenes::load(&scenes::find("cornell")?, &opts.scenes_dir)?;
    let s = settings(SIZE, SIZE, opts.seed);
    let (throughput, throughput_runs) = best_throughput(&loaded.scene, &s, THROUGHPUT_SPP)?;
    tracing::info!(?throughput, "cornell throughput measured");
    // The reference is read only now, so the million scene's peak above is the bench's own.
    let (convergence, skipped) = match read_rgb(&opts.reference, SIZE) {
        Err(why) => {
            tracing::warn!(%why, "cornell error against time skipped");
            (None, Some(why))
        }
        Ok(reference) => {
            let passes =
                error_against_time(&loaded.scene, &s, &reference, opts.max_spp, opts.time_limit);
            let noise = read_rgb(&stderr_path(&opts.reference), SIZE)
                .ok()
                .map(|se| rms(&se) / reference.mean);
            (
                Some(Convergence {
                    reference: opts.reference.display().to_string(),
                    reference_mean: reference.mean,
                    reference_noise: noise,
                    seconds_to_10pct: time_to_reach(&passes, 0.10),
                    seconds_to_5pct: time_to_reach(&passes, 0.05),
                    passes,
                }),
                None,
            )
        }
    };
    Ok(CornellResult {
        throughput,
        throughput_runs,
        convergence,
        skipped,
    })
}

/// An RGB image as three channels, with the mean over every pixel and channel.
pub struct RgbImage {
    pub rgb: [Vec<f32>; 3],
    pub mean: f64,
}

impl RgbImage {
    pub fn new(rgb: [Vec<f32>; 3]) -> RgbImage {
        let n = rgb.iter().map(Vec::len).sum::<usize>().max(1) as f64;
        let mean = rgb.iter().flatten().map(|&v| v as f64).sum::<f64>() / n;
        RgbImage { rgb, mean }
    }
}

/// `cornell.stderr.exr` beside `cornell.exr`: the reference's per-pixel standard errors.
fn stderr_path(reference: &Path) -> PathBuf {
    let stem = reference
        .file_stem()
        .map_or("cornell".into(), |s| s.to_string_lossy());
    reference.with_file_name(format!("{stem}.stderr.exr"))
}

/// Reads an RGB EXR of `size`×`size` with a positive mean. The error is the reason to skip, as
/// the report says it (a missing reference is not a failure of the bench).
fn read_rgb(path: &Path, size: u32) -> Result<RgbImage, String> {
    let bytes = std::fs::read(path).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => format!("reference {} not found", path.display()),
        _ => format!("reference {}: {e}", path.display()),
    })?;
    let bad = |e: &dyn std::fmt::Display| format!("reference {}: {e}", path.display());
    let img: FloatImage = decode_exr(&bytes).map_err(|e| bad(&e))?;
    if (img.width, img.height) != (size as usize, size as usize) {
        return Err(bad(&format!(
            "{}×{}, not {size}×{size}",
            img.width, img.height
        )));
    }
    let ch = |c: &str| img.channel(c).map(<[f32]>::to_vec).map_err(|e| bad(&e));
    let image = RgbImage::new([ch("R")?, ch("G")?, ch("B")?]);
    if image.mean.is_finite() && image.mean > 0.0 {
        Ok(image)
    } else {
        Err(bad(&"its mean is not positive"))
    }
}

/// Root mean square over every pixel and channel.
fn rms(image: &RgbImage) -> f64 {
    let n = image.rgb.iter().map(Vec::len).sum::<usize>().max(1) as f64;
    let sq: f64 = image
        .rgb
        .iter()
        .flatten()
        .map(|&v| (v as f64).powi(2))
        .sum();
    (sq / n).sqrt()
}

/// RMSE of the mean image against `reference` over every pixel and the three channels, divided by
/// the reference's mean over the same. (The CLI's `render --reference` computes the same number;
/// the bench crate cannot depend on the binary, hence this copy.)
pub fn relative_rmse(acc: &Accumulation, reference: &RgbImage) -> f64 {
    let mut se = 0.0;
    for (i, p) in acc.pixels.iter().enumerate() {
        let m = p.mean();
        for (c, mc) in m.iter().enumerate() {
            let d = mc - reference.rgb[c][i] as f64;
            se += d * d;
        }
    }
    let n = (acc.pixels.len() * 3).max(1) as f64;
    (se / n).sqrt() / reference.mean
}

/// Renders passes [0,1), [1,2), [2,4), … on the current rayon pool, merged exactly into one
/// accumulation, until `max_spp` or until the pass during which `time_limit` seconds of render
/// time are reached; after each, the rel. RMSE of the image so far. Time is render time only, as
/// in the estimator study: the error computation and the merge are not counted.
pub fn error_against_time(
    scene: &Scene,
    settings: &RenderSettings,
    reference: &RgbImage,
    max_spp: u32,
    time_limit: f64,
) -> Vec<Pass> {
    let mut acc = Accumulation::new(0, 0, settings.width, settings.height);
    let (mut begin, mut seconds, mut passes) = (0u32, 0.0, Vec::new());
    while begin < max_spp && seconds < time_limit {
        let end = if begin == 0 {
            1
        } else {
            (begin * 2).min(max_spp)
        };
        let r = render_range(scene, settings, begin..end);
        seconds += r.seconds;
        // Same size and origin: the merge cannot fail.
        let _ = acc.merge(&r.acc);
        let rel_rmse = relative_rmse(&acc, reference);
        tracing::info!(spp = end, seconds, rel_rmse, "cornell pass");
        passes.push(Pass {
            spp: end,
            seconds,
            rel_rmse,
        });
        begin = end;
    }
    passes
}

/// The render time at which the rel. RMSE first reaches `target`: interpolated linearly in
/// log(time)–log(error) between the last pass above it and the first at or below it (error falls
/// as a power of time, a straight line on those axes). The first pass's own time when that pass
/// already reaches it (nothing earlier was measured); `None` when no pass does.
pub fn time_to_reach(passes: &[Pass], target: f64) -> Option<f64> {
    let i = passes.iter().position(|p| p.rel_rmse <= target)?;
    let hi = passes[i];
    let Some(lo) = i.checked_sub(1).map(|j| passes[j]) else {
        return Some(hi.seconds);
    };
    let positive = [lo.seconds, hi.seconds, lo.rel_rmse, hi.rel_rmse, target];
    if positive.iter().any(|v| !(v.is_finite() && *v > 0.0)) || hi.seconds <= lo.seconds {
        // No straight line in log–log: the later pass's time is the honest bound.
        return Some(hi.seconds);
    }
    let f = (target.ln() - lo.rel_rmse.ln()) / (hi.rel_rmse.ln() - lo.rel_rmse.ln());
    Some((lo.seconds.ln() + f * (hi.seconds.ln() - lo.seconds.ln())).exp())
}

/// `VmHWM` (peak resident set) of this process, KiB. (The soak's reader in `farm::soak::memory`
/// reads another process and is private to it.)
fn peak_rss_kib() -> Result<u64, BenchError> {
    let path = Path::new("/proc/self/status");
    let status = std::fs::read_to_string(path).map_err(|e| BenchError::io(path, e))?;
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .ok_or_else(|| BenchError::Invalid(format!("{} has no VmHWM", path.display())))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn pass(spp: u32, seconds: f64, rel_rmse: f64) -> Pass {
        Pass {
            spp,
            seconds,
            rel_rmse,
        }
    }

    #[test]
    fn time_to_reach_interpolates_in_log_log() {
        // 20 % at 1 s, 5 % at 16 s: error ∝ t^(-1/2), so 10 % is reached at 4 s exactly.
        let passes = [pass(1, 0.5, 0.4), pass(2, 1.0, 0.2), pass(4, 16.0, 0.05)];
        assert!((time_to_reach(&passes, 0.10).unwrap() - 4.0).abs() < 1e-12);
        // Reached exactly at a pass: that pass's time.
        assert!((time_to_reach(&passes, 0.05).unwrap() - 16.0).abs() < 1e-12);
        // Already reached by the first pass: its time, the only bound measured.
        assert_eq!(time_to_reach(&passes, 0.5), Some(0.5));
        assert_eq!(time_to_reach(&passes, 0.01), None);
        assert_eq!(time_to_reach(&[], 0.1), None);
    }

    #[test]
    fn relative_rmse_by_hand() {
        // Two pixels: means (1,2,3) and (1,1,1); reference (1,2,3) and (3,1,1).
        let mut acc = Accumulation::new(0, 0, 2, 1);
        acc.pixels[0].add_sample(Vec3::new(1.0, 2.0, 3.0));
        acc.pixels[1].add_sample(Vec3::new(0.5, 0.5, 0.5));
        acc.pixels[1].add_sample(Vec3::new(1.5, 1.5, 1.5));
        let reference = RgbImage::new([vec![1.0, 3.0], vec![2.0, 1.0], vec![3.0, 1.0]]);
        // Reference mean 11/6; one error of 2 among 6 values: RMSE = √(4/6).
        assert!((reference.mean - 11.0 / 6.0).abs() < 1e-12);
        let expected = (4.0f64 / 6.0).sqrt() / (11.0 / 6.0);
        assert!((relative_rmse(&acc, &reference) - expected).abs() < 1e-9);
        assert!((rms(&reference) - (25.0f64 / 6.0).sqrt()).abs() < 1e-9);
    }

    #[test]
    fn error_against_time_on_a_tiny_cornell_box() {
        let bytes = std::fs::read(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../scenes/cornell.gltf"
        ))
        .expect("scenes/cornell.gltf");
        let scene = pathfarm_tracer::gltf::load(
            &bytes,
            &pathfarm_tracer::gltf::NoExternalResources,
            &pathfarm_tracer::gltf::LoadOptions::default(),
        )
        .unwrap();
        let s = settings(32, 32, 3);
        // The reference is the bench's own 8 spp image of the same seed: the passes, merged
        // exactly, must end on it bit for bit.
        let mean = render_range(&scene, &s, 0..8).acc.mean_image();
        let reference = RgbImage::new([0, 1, 2].map(|c| mean.iter().map(|p| p[c]).collect()));
        let passes = error_against_time(&scene, &s, &reference, 8, 60.0);
        let spp: Vec<u32> = passes.iter().map(|p| p.spp).collect();
        assert_eq!(spp, [1, 2, 4, 8]);
        assert!(passes.windows(2).all(|w| w[0].seconds <= w[1].seconds));
        // f32 rounding of the reference only.
        assert!(passes[3].rel_rmse < 1e-6, "{passes:?}");
        assert!(passes[0].rel_rmse > 0.05, "{passes:?}");
        assert!(time_to_reach(&passes, 0.01).is_some_and(|t| t <= passes[3].seconds));
        // The time limit ends the passes after the one during which it is reached.
        assert_eq!(
            error_against_time(&scene, &s, &reference, 8, 1e-12).len(),
            1
        );
        assert!(error_against_time(&scene, &s, &reference, 8, 0.0).is_empty());
    }
}
