//! The Blender suite (`scenes/suite/`, made by `make_suite.py`): scenes built in Blender and
//! exported by its own glTF exporter at default settings, each with a Cycles reference image. This
//! renders each with the tracer (the environment from the manifest where the scene has one) and
//! compares image means with Cycles': `pathfarm bench blender`, and `tests/blender_suite.rs` with
//! fewer samples. What each remaining difference is made of is in `docs/blender-suite.md`.

use crate::error::{write_file, BenchError};
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};
use pathfarm_tracer::light::Environment;
use pathfarm_tracer::{render_image, Accumulation, DirectStrategy, RenderSettings};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// One scene of `manifest.json`, as far as the comparison needs it.
#[derive(Clone, Debug)]
pub struct SuiteScene {
    pub name: String,
    pub glb: PathBuf,
    pub width: u32,
    pub height: u32,
    /// The environment image, its strength and rotation (degrees about the up axis).
    pub environment: Option<(PathBuf, f32, f32)>,
    /// Every material and light has an exact glTF counterpart (Blender's world, which glTF cannot
    /// carry, counts as one: it is given to the tracer as the environment): the means must agree.
    pub exact: bool,
    pub note: String,
    /// Where the scene is not exact: the difference from Cycles that `docs/blender-suite.md`
    /// explains, as (ours − Cycles) / Cycles of the mean luminance, measured at 64 spp.
    pub documented_difference: Option<f64>,
    /// Cycles' image mean, per channel, and its standard error.
    pub cycles_mean: [f64; 3],
    pub cycles_stderr: [f64; 3],
    pub cycles_seconds: f64,
    pub cycles_spp: u32,
}

#[derive(Deserialize)]
struct Manifest {
    scenes: std::collections::BTreeMap<String, ManifestScene>,
}

#[derive(Deserialize)]
struct ManifestScene {
    glb: String,
    width: u32,
    height: u32,
    environment: Option<ManifestEnvironment>,
    exact_counterparts: bool,
    #[serde(default)]
    exact_note: String,
    #[serde(default)]
    documented_difference: Option<f64>,
    cycles: ManifestCycles,
}

#[derive(Deserialize)]
struct ManifestEnvironment {
    file_exr: String,
    strength: f32,
    /// Blender's Mapping rotation (x, y, z); only z (about the up axis) has a meaning here.
    rotation_degrees: [f32; 3],
}

#[derive(Deserialize)]
struct ManifestCycles {
    spp: u32,
    render_seconds: f64,
    mean_rgb: [f64; 3],
    mean_rgb_stderr: [f64; 3],
}

/// The scenes of `dir/manifest.json`.
pub fn load_manifest(dir: &Path) -> Result<Vec<SuiteScene>, BenchError> {
    let path = dir.join("manifest.json");
    let bytes = std::fs::read(&path).map_err(|e| BenchError::io(&path, e))?;
    let manifest: Manifest = serde_json::from_slice(&bytes)
        .map_err(|e| BenchError::Invalid(format!("{}: {e}", path.display())))?;
    Ok(manifest
        .scenes
        .into_iter()
        .map(|(name, s)| SuiteScene {
            glb: dir.join(&s.glb),
            width: s.width,
            height: s.height,
            environment: s
                .environment
                .map(|e| (dir.join(e.file_exr), e.strength, e.rotation_degrees[2])),
            exact: s.exact_counterparts,
            note: s.exact_note,
            documented_difference: s.documented_difference,
            cycles_mean: s.cycles.mean_rgb,
            cycles_stderr: s.cycles.mean_rgb_stderr,
            cycles_seconds: s.cycles.render_seconds,
            cycles_spp: s.cycles.spp,
            name,
        })
        .collect())
}

/// One scene's comparison.
#[derive(Clone, Debug, Serialize)]
pub struct SuiteResult {
    pub name: String,
    pub exact: bool,
    /// The scene's documented difference from Cycles (none where it is exact).
    pub documented_difference: Option<f64>,
    pub triangles: usize,
    pub load_seconds: f64,
    pub spp: u32,
    pub render_seconds: f64,
    pub samples_per_second: f64,
    /// The tracer's image mean per channel and its standard error.
    pub mean: [f64; 3],
    pub stderr: [f64; 3],
    pub cycles_mean: [f64; 3],
    pub cycles_stderr: [f64; 3],
    /// (ours − Cycles) / Cycles of the mean luminance.
    pub relative_difference: f64,
    /// That difference in standard errors of both means.
    pub z: f64,
    pub cycles_seconds: f64,
    pub cycles_spp: u32,
    pub warnings: Vec<String>,
}

fn luminance(c: [f64; 3]) -> f64 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

/// The image mean per channel and its standard error (from the spread of the pixel means, which
/// bounds the noise of the mean from above for independent pixels).
fn image_mean(acc: &Accumulation) -> ([f64; 3], [f64; 3], f64) {
    let n = acc.pixels.len() as f64;
    let mut mean = [0.0; 3];
    let mut var_lum = 0.0;
    for p in &acc.pixels {
        let m = p.mean();
        for c in 0..3 {
            mean[c] += m[c] / n;
        }
        var_lum += p.variance_of_mean().unwrap_or(0.0);
    }
    // Per channel, scale the luminance error by the channel's share (an estimate for the report).
    let lum_se = (var_lum / (n * n)).sqrt();
    let lum = luminance(mean).max(1e-12);
    let se = mean.map(|m| lum_se * m / lum);
    (mean, se, lum_se)
}

/// Loads and renders one scene at `spp` samples per pixel on the current rayon pool.
pub fn render_scene(scene: &SuiteScene, spp: u32, seed: u64) -> Result<SuiteResult, BenchError> {
    let err = |message: String| BenchError::Scene {
        name: scene.name.clone(),
        message,
    };
    let t0 = Instant::now();
    let bytes = std::fs::read(&scene.glb).map_err(|e| BenchError::io(&scene.glb, e))?;
    let environment = match &scene.environment {
        Some((path, strength, rotation)) => {
            let image = std::fs::read(path).map_err(|e| BenchError::io(path, e))?;
            Some(
                Environment::from_image(&image, *strength, *rotation)
                    .map_err(|e| err(e.to_string()))?,
            )
        }
        None => None,
    };
    let loaded = gltf::load(&bytes, &NoExternalResources, &LoadOptions::default())
        .map_err(|e| err(e.to_string()))?
        .with_environment(environment);
    let load_seconds = t0.elapsed().as_secs_f64();
    let settings = RenderSettings {
        seed,
        ..RenderSettings::new(scene.width, scene.height)
    };
    let t1 = Instant::now();
    let acc = render_image(&loaded, &settings, 32, 0..spp, &|_| {});
    let render_seconds = t1.elapsed().as_secs_f64();
    let (mean, stderr, lum_se) = image_mean(&acc);
    let (ours, theirs) = (luminance(mean), luminance(scene.cycles_mean));
    let cycles_lum_se = luminance(scene.cycles_stderr);
    Ok(SuiteResult {
        name: scene.name.clone(),
        exact: scene.exact,
        documented_difference: scene.documented_difference,
        triangles: loaded.info.triangles,
        load_seconds,
        spp,
        render_seconds,
        samples_per_second: acc.total_samples() as f64 / render_seconds,
        mean,
        stderr,
        cycles_mean: scene.cycles_mean,
        cycles_stderr: scene.cycles_stderr,
        relative_difference: (ours - theirs) / theirs,
        z: (ours - theirs) / (lum_se * lum_se + cycles_lum_se * cycles_lum_se).sqrt(),
        cycles_seconds: scene.cycles_seconds,
        cycles_spp: scene.cycles_spp,
        warnings: loaded.info.warnings.clone(),
    })
}

/// One direct-lighting strategy on an environment-lit scene: its noise after a fixed time.
#[derive(Clone, Debug, Serialize)]
pub struct EnvironmentStrategy {
    pub strategy: String,
    pub spp: u32,
    pub seconds: f64,
    /// The estimated relative error (RMS noise of the pixel means over the image's mean).
    pub relative_error: f64,
    /// That error scaled to one second of rendering (error ∝ 1/√time).
    pub error_at_one_second: f64,
}

/// How much the environment's importance sampling buys on an environment-lit scene: the same
/// scene rendered with BSDF sampling alone (the only way an unsampled environment is found) and
/// with the default MIS, each error scaled to equal time.
pub fn environment_strategies(
    scene: &SuiteScene,
    spp: u32,
    seed: u64,
) -> Result<Vec<EnvironmentStrategy>, BenchError> {
    let err = |message: String| BenchError::Scene {
        name: scene.name.clone(),
        message,
    };
    let Some((path, strength, rotation)) = &scene.environment else {
        return Ok(Vec::new());
    };
    let bytes = std::fs::read(&scene.glb).map_err(|e| BenchError::io(&scene.glb, e))?;
    let image = std::fs::read(path).map_err(|e| BenchError::io(path, e))?;
    let env =
        Environment::from_image(&image, *strength, *rotation).map_err(|e| err(e.to_string()))?;
    let loaded = gltf::load(&bytes, &NoExternalResources, &LoadOptions::default())
        .map_err(|e| err(e.to_string()))?
        .with_environment(Some(env));
    let mut out = Vec::new();
    for direct in [DirectStrategy::Bsdf, DirectStrategy::Mis] {
        let settings = RenderSettings {
            seed,
            direct,
            ..RenderSettings::new(scene.width, scene.height)
        };
        let t = Instant::now();
        let acc = render_image(&loaded, &settings, 32, 0..spp, &|_| {});
        let seconds = t.elapsed().as_secs_f64();
        let relative_error = acc.relative_error().unwrap_or(f64::NAN);
        out.push(EnvironmentStrategy {
            strategy: direct.to_string(),
            spp,
            seconds,
            relative_error,
            error_at_one_second: relative_error * seconds.sqrt(),
        });
    }
    Ok(out)
}

/// The report's table.
pub fn markdown(results: &[SuiteResult], command_line: &str) -> String {
    let mut s = format!(
        "# The Blender suite against Cycles\n\n`{command_line}`\n\n\
         | scene | exact counterparts | triangles | load s | spp | render s | samples/s | mean (ours) | mean (Cycles 5.0) | difference | documented | z | Cycles samples/s |\n\
         |---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n"
    );
    for r in results {
        s += &format!(
            "| {} | {} | {} | {:.3} | {} | {:.2} | {:.2} M | {:.5} | {:.5} | {:+.2} % | {} | {:+.1} | {:.2} M |\n",
            r.name,
            if r.exact { "yes" } else { "no" },
            r.triangles,
            r.load_seconds,
            r.spp,
            r.render_seconds,
            r.samples_per_second / 1e6,
            luminance(r.mean),
            luminance(r.cycles_mean),
            r.relative_difference * 100.0,
            r.documented_difference
                .map_or("—".to_string(), |d| format!("{:+.2} %", d * 100.0)),
            r.z,
            256.0 * 256.0 * r.cycles_spp as f64 / r.cycles_seconds / 1e6,
        );
    }
    s += "\nMeans are of luminance. \"documented\": the difference that `docs/blender-suite.md` \
          explains for a scene that is not exact (its conventions differ from Cycles'). Cycles' samples/s are from the manifest (its render time at 2 \
          threads, on a busy machine when the suite was made), not measured in this run.\n";
    s
}

/// Renders the whole suite and writes `blender.md` and `blender.json` into `out`.
pub fn run(
    dir: &Path,
    spp: u32,
    seed: u64,
    out: &Path,
    command_line: &str,
) -> Result<(Vec<SuiteResult>, String), BenchError> {
    let scenes = load_manifest(dir)?;
    let mut results = Vec::new();
    let mut strategies = Vec::new();
    for scene in &scenes {
        tracing::info!(scene = %scene.name, spp, "rendering");
        results.push(render_scene(scene, spp, seed)?);
        for s in environment_strategies(scene, spp, seed)? {
            strategies.push((scene.name.clone(), s));
        }
    }
    let mut md = markdown(&results, command_line);
    if !strategies.is_empty() {
        md += "\n## Environment sampling: equal-time error\n\n\
               | scene | strategy | spp | seconds | relative error | error after 1 s |\n\
               |---|---|---:|---:|---:|---:|\n";
        for (name, s) in &strategies {
            md += &format!(
                "| {name} | {} | {} | {:.2} | {:.4} | {:.4} |\n",
                s.strategy, s.spp, s.seconds, s.relative_error, s.error_at_one_second
            );
        }
    }
    write_file(&out.join("blender.md"), md.as_bytes())?;
    let json = serde_json::to_vec_pretty(&results)
        .map_err(|e| BenchError::Invalid(format!("blender.json: {e}")))?;
    write_file(&out.join("blender.json"), &json)?;
    Ok((results, md))
}
