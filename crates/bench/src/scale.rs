//! `pathfarm bench scale`: the loader and the BVHs at scale (issue 31 items 3 and 5). Each case is
//! written as a `.glb` in memory, as an exporter would write it (positions, normals, u32 indices;
//! one mesh, placed by one node or by many), and loaded as a user's file is: parsed and decoded
//! (`gltf::load_parts`), then built (`Scene::build`: the BVHs, the lights). Reported per case: the
//! load and build seconds, the tracer's estimate of the scene's bytes, the process's peak resident
//! memory during load and build above what it held before (the kernel's peak reset through
//! `/proc/self/clear_refs`), and samples/s of a short render. Each case runs in a process of its
//! own (the bench starts itself again with `--case`), so that no case reuses memory another freed. The instanced case of a million
//! placed triangles is also built flattened (every placement's triangles in world space), the
//! way it was before instancing, to show what the two levels cost a ray and save in memory.

use crate::error::write_file;
use crate::render::render_range;
use crate::{BenchError, Machine};
use pathfarm_tracer::gltf::{encode_glb, load_parts, LoadOptions, NoExternalResources};
use pathfarm_tracer::{RenderSettings, Scene};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// One scene to measure: a displaced sphere of about `triangles` triangles placed `placements`
/// times (once: a plain mesh, flattened by the loader; more: kept instanced).
#[derive(Clone, Copy, Debug)]
pub struct Case {
    pub name: &'static str,
    pub triangles: usize,
    pub placements: usize,
}

/// The cases of issue 31: ten million triangles in one mesh; 10,000 placements of a 100k-triangle
/// mesh (10⁹ placed triangles); a million placed triangles as 400 placements of 2,500.
pub const CASES: [Case; 3] = [
    Case {
        name: "mesh-10M",
        triangles: 10_000_000,
        placements: 1,
    },
    Case {
        name: "instances-10k-of-100k",
        triangles: 100_000,
        placements: 10_000,
    },
    Case {
        name: "instances-400-of-2.5k",
        triangles: 2_500,
        placements: 400,
    },
];

/// Smaller cases of the same shapes, for a smoke run.
pub const QUICK_CASES: [Case; 3] = [
    Case {
        name: "mesh-1M",
        triangles: 1_000_000,
        placements: 1,
    },
    Case {
        name: "instances-1k-of-100k",
        triangles: 100_000,
        placements: 1_000,
    },
    Case {
        name: "instances-400-of-2.5k",
        triangles: 2_500,
        placements: 400,
    },
];

#[derive(Clone, Debug)]
pub struct ScaleOptions {
    pub out_dir: PathBuf,
    /// The `pathfarm` executable, started once per case as `pathfarm bench scale --case NAME`;
    /// `None`: every case in this process (memory figures then include what earlier cases left).
    pub exe: Option<PathBuf>,
    pub threads: usize,
    pub quick: bool,
    /// Also write each case's `.glb` into `out_dir` (to render or profile it elsewhere).
    pub keep_files: bool,
    pub seed: u64,
    pub command_line: String,
}

/// What one case measured.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Measured {
    pub name: String,
    /// How the scene was built: "as loaded" or "flattened".
    pub build: String,
    /// Triangles stored (each instanced mesh once) and placed in the world.
    pub stored_triangles: usize,
    pub placed_triangles: u64,
    pub instances: usize,
    pub file_mib: f64,
    /// `load_parts`: parse, decode, the loader's work.
    pub load_seconds: f64,
    /// `Scene::build`: the BVHs (both levels) and the lights.
    pub build_seconds: f64,
    /// Of `build_seconds`, the world-space mesh's BVH (zero where every triangle is instanced).
    #[serde(default)]
    pub bvh_seconds: f64,
    /// The tracer's estimate of geometry, BVH and textures.
    pub scene_mib: f64,
    /// Peak resident memory during load and build above the resident memory before, MiB;
    /// `None` where `/proc` is missing.
    pub peak_rss_mib: Option<f64>,
    /// A 128×128 render at 32 spp from the file's camera.
    pub samples_per_second: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ScaleResults {
    pub command_line: String,
    pub machine: Machine,
    pub cases: Vec<Measured>,
}

/// A sphere of radius 1 with bumps, as a latitude × longitude grid of `n × n` quads (about
/// `triangles` triangles), with vertex normals: the `.glb` of one mesh placed by `placements` nodes
/// on a grid in the XZ plane, each turned and scaled a little differently, lit by a sun and seen
/// from above by a camera.
pub fn sphere_glb(triangles: usize, placements: usize) -> Result<Vec<u8>, BenchError> {
    let n = ((triangles as f64 / 2.0).sqrt().ceil() as usize).max(2);
    let (rows, cols) = (n + 1, n + 1);
    let mut positions = Vec::with_capacity(rows * cols * 3);
    let mut normals = Vec::with_capacity(rows * cols * 3);
    for i in 0..rows {
        let theta = std::f32::consts::PI * i as f32 / n as f32;
        for j in 0..cols {
            let phi = std::f32::consts::TAU * j as f32 / n as f32;
            let dir = glam::Vec3::new(
                theta.sin() * phi.cos(),
                theta.cos(),
                theta.sin() * phi.sin(),
            );
            let r = 1.0 + 0.04 * (7.0 * theta).sin() * (9.0 * phi).sin();
            positions.extend((dir * r).to_array());
            normals.extend(dir.to_array());
        }
    }
    let mut indices: Vec<u32> = Vec::with_capacity(n * n * 6);
    for i in 0..n {
        for j in 0..n {
            let v = |a: usize, b: usize| (a * cols + b) as u32;
            // Counter-clockwise seen from outside.
            indices.extend([v(i, j), v(i, j + 1), v(i + 1, j)]);
            indices.extend([v(i, j + 1), v(i + 1, j + 1), v(i + 1, j)]);
        }
    }
    let mut bin: Vec<u8> = Vec::with_capacity((positions.len() * 2 + indices.len()) * 4);
    let (lo, hi) =
        positions
            .chunks_exact(3)
            .fold(([f32::MAX; 3], [f32::MIN; 3]), |(mut lo, mut hi), p| {
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
                (lo, hi)
            });
    bin.extend(positions.iter().flat_map(|v| v.to_le_bytes()));
    bin.extend(normals.iter().flat_map(|v| v.to_le_bytes()));
    bin.extend(indices.iter().flat_map(|v| v.to_le_bytes()));
    let (pos_len, idx_len) = (positions.len() * 4, indices.len() * 4);
    let side = (placements as f64).sqrt().ceil() as usize;
    let nodes: Vec<serde_json::Value> = (0..placements)
        .map(|k| {
            let (x, z) = ((k % side) as f64 * 2.5, (k / side) as f64 * 2.5);
            let turn = 0.7 * k as f64;
            let s = 0.8 + 0.4 * ((k * 7919) % 101) as f64 / 100.0;
            serde_json::json!({
                "mesh": 0,
                "translation": [x, 0.0, z],
                "rotation": [0.0, (turn / 2.0).sin(), 0.0, (turn / 2.0).cos()],
                "scale": [s, s, s],
            })
        })
        .collect();
    // A sun from above at an angle (KHR_lights_punctual), so that paths bounce and cast shadows.
    let mut nodes = nodes;
    let (half, axis) = (0.5f64, [0.6f64, 0.0, 0.8]);
    nodes.push(serde_json::json!({
        "name": "Sun",
        "rotation": [axis[0] * half.sin(), 0.0, axis[2] * half.sin(), half.cos()],
        "extensions": {"KHR_lights_punctual": {"light": 0}},
    }));
    // A camera above the grid's near edge, looking down at 45° over it.
    let extent = (side.max(1) as f64) * 2.5;
    let pitch = -std::f64::consts::FRAC_PI_4;
    nodes.push(serde_json::json!({
        "name": "Camera",
        "camera": 0,
        "translation": [extent / 2.0 - 1.25, 0.45 * extent + 2.0, extent + 1.0],
        "rotation": [(pitch / 2.0).sin(), 0.0, 0.0, (pitch / 2.0).cos()],
    }));
    let json = serde_json::json!({
        "asset": {"version": "2.0", "generator": "pathfarm bench scale"},
        "cameras": [{"type": "perspective", "perspective": {"yfov": 0.9, "znear": 0.01}}],
        "extensionsUsed": ["KHR_lights_punctual"],
        "extensions": {"KHR_lights_punctual": {"lights": [
            {"type": "directional", "intensity": 3.0, "color": [1.0, 0.95, 0.9]}]}},
        "scene": 0,
        "scenes": [{"nodes": (0..placements + 2).collect::<Vec<_>>()}],
        "nodes": nodes,
        "meshes": [{"name": "Bumpy sphere", "primitives": [{
            "attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2, "material": 0}]}],
        "materials": [{"name": "Grey", "pbrMetallicRoughness": {
            "baseColorFactor": [0.7, 0.7, 0.7, 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0}}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": rows * cols, "type": "VEC3",
             "min": lo, "max": hi},
            {"bufferView": 1, "componentType": 5126, "count": rows * cols, "type": "VEC3"},
            {"bufferView": 2, "componentType": 5125, "count": indices.len(), "type": "SCALAR"},
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": pos_len},
            {"buffer": 0, "byteOffset": pos_len, "byteLength": pos_len},
            {"buffer": 0, "byteOffset": 2 * pos_len, "byteLength": idx_len},
        ],
        "buffers": [{"byteLength": bin.len()}],
    });
    let json =
        serde_json::to_vec(&json).map_err(|e| BenchError::Invalid(format!("glTF JSON: {e}")))?;
    encode_glb(&json, Some(&bin))
        .ok_or_else(|| BenchError::Invalid("the scene is over the .glb format's 4 GiB".into()))
}

/// Field `name` (e.g. `VmHWM:`) of `/proc/{process}/status` (`process`: `self` or a pid), KiB.
pub(crate) fn status_kib(process: &str, name: &str) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{process}/status")).ok()?;
    status
        .lines()
        .find_map(|l| l.strip_prefix(name))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
}

/// Resets the kernel's peak resident memory of this process to its current resident memory.
fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

fn scene_error(name: &str, e: impl std::fmt::Display) -> BenchError {
    BenchError::Scene {
        name: name.to_string(),
        message: e.to_string(),
    }
}

/// Loads `bytes`, builds the scene (flattened first where `flatten`) and renders it briefly.
fn measure(case: &Case, bytes: &[u8], flatten: bool, seed: u64) -> Result<Measured, BenchError> {
    let baseline = reset_peak_rss()
        .then(|| status_kib("self", "VmRSS:"))
        .flatten();
    let started = Instant::now();
    let mut parts = load_parts(bytes, &NoExternalResources, &LoadOptions::default())
        .map_err(|e| scene_error(case.name, e))?;
    if flatten {
        parts = parts.flatten_instances();
    }
    let load_seconds = started.elapsed().as_secs_f64();
    let started = Instant::now();
    let scene = Scene::build(parts).map_err(|e| scene_error(case.name, e))?;
    let build_seconds = started.elapsed().as_secs_f64();
    let peak_rss_mib = match (baseline, status_kib("self", "VmHWM:")) {
        (Some(before), Some(peak)) => Some(peak.saturating_sub(before) as f64 / 1024.0),
        _ => None,
    };
    let settings = RenderSettings {
        seed,
        ..crate::speed::settings(128, 128, seed)
    };
    let spp = 32;
    let r = render_range(&scene, &settings, 0..spp);
    let samples = 128.0 * 128.0 * spp as f64;
    let measured = Measured {
        name: case.name.to_string(),
        build: if flatten { "flattened" } else { "as loaded" }.to_string(),
        stored_triangles: scene.info.triangles,
        placed_triangles: scene.info.instanced_triangles
            + (scene.info.triangles - scene.instances.stored_triangles()) as u64,
        instances: scene.info.instances,
        file_mib: bytes.len() as f64 / (1024.0 * 1024.0),
        load_seconds,
        build_seconds,
        bvh_seconds: scene.info.bvh_seconds,
        scene_mib: scene.info.bytes as f64 / (1024.0 * 1024.0),
        peak_rss_mib,
        samples_per_second: samples / r.seconds.max(1e-9),
    };
    tracing::info!(?measured, "scale case measured");
    Ok(measured)
}

/// A case's name for `--case`: its name, and `:flat` for its flattened build.
fn case_id(case: &Case, flatten: bool) -> String {
    format!("{}{}", case.name, if flatten { ":flat" } else { "" })
}

/// Measures case `id` (see [`case_id`]) in this process, on the current rayon pool; writes its
/// `.glb` into `keep_in` if given.
pub fn measure_case(id: &str, seed: u64, keep_in: Option<&Path>) -> Result<Measured, BenchError> {
    let (name, flatten) = match id.strip_suffix(":flat") {
        Some(name) => (name, true),
        None => (id, false),
    };
    let case = CASES
        .iter()
        .chain(&QUICK_CASES)
        .find(|c| c.name == name)
        .ok_or_else(|| BenchError::UnknownScene(id.to_string()))?;
    tracing::info!(case = id, "scale: writing the file");
    let bytes = sphere_glb(case.triangles, case.placements)?;
    if let Some(dir) = keep_in {
        write_file(&dir.join(format!("{}.glb", case.name)), &bytes)?;
    }
    measure(case, &bytes, flatten, seed)
}

/// Runs case `id` in a child process (`exe bench scale --case ID`), which prints its result as
/// JSON on its last line of output.
fn in_child(exe: &Path, id: &str, opts: &ScaleOptions) -> Result<Measured, BenchError> {
    let out = std::process::Command::new(exe)
        .args(["bench", "scale", "--case", id, "--threads"])
        .arg(opts.threads.to_string())
        .args(["--seed", &opts.seed.to_string(), "--out"])
        .arg(&opts.out_dir)
        .args(opts.keep_files.then_some("--keep-files"))
        .stderr(std::process::Stdio::inherit())
        .output()
        .map_err(|e| BenchError::io(exe, e))?;
    let stdout = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        return Err(BenchError::Invalid(format!(
            "case {id}: {} exited with {}",
            exe.display(),
            out.status
        )));
    }
    let last = stdout.lines().last().unwrap_or_default();
    serde_json::from_str(last).map_err(|e| {
        BenchError::Invalid(format!("case {id}: cannot read its result {last:?}: {e}"))
    })
}

/// Measures every case (the quick ones with `quick`) on a pool of `threads`, and writes
/// `scale.md` and `scale.json` into the output directory.
pub fn run(opts: &ScaleOptions) -> Result<(ScaleResults, String), BenchError> {
    std::fs::create_dir_all(&opts.out_dir).map_err(|e| BenchError::io(&opts.out_dir, e))?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(opts.threads.max(1))
        .build()
        .map_err(|e| BenchError::Invalid(format!("cannot start {} threads: {e}", opts.threads)))?;
    let cases = if opts.quick { QUICK_CASES } else { CASES };
    let mut measured = Vec::new();
    for case in &cases {
        let placed = case.triangles as u64 * case.placements as u64;
        for flatten in [false, true] {
            if flatten && !(case.placements > 1 && placed <= 2_000_000) {
                continue;
            }
            let id = case_id(case, flatten);
            measured.push(match &opts.exe {
                Some(exe) => in_child(exe, &id, opts)?,
                None => pool.install(|| {
                    measure_case(&id, opts.seed, opts.keep_files.then_some(&opts.out_dir))
                })?,
            });
        }
    }
    let results = ScaleResults {
        command_line: opts.command_line.clone(),
        machine: Machine::detect(opts.threads.max(1)),
        cases: measured,
    };
    let json = serde_json::to_vec_pretty(&results)
        .map_err(|e| BenchError::Invalid(format!("scale.json: {e}")))?;
    write_file(&opts.out_dir.join("scale.json"), &json)?;
    let md = markdown(&results);
    write_file(&opts.out_dir.join("scale.md"), md.as_bytes())?;
    Ok((results, md))
}

fn markdown(r: &ScaleResults) -> String {
    let mut md = String::new();
    let _ = writeln!(md, "# Scenes at scale\n");
    let _ = writeln!(
        md,
        "`{}` on {} ({} threads of {} cores), {}.\n",
        r.command_line, r.machine.cpu, r.machine.threads, r.machine.logical_cores, r.machine.date
    );
    let _ = writeln!(
        md,
        "| scene | build | stored triangles | placed triangles | instances | file MiB | load s | \
         build s | world BVH s | scene MiB | peak RSS MiB | samples/s |"
    );
    let _ = writeln!(
        md,
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    for c in &r.cases {
        let rss = c
            .peak_rss_mib
            .map_or_else(|| "–".to_string(), |m| format!("{m:.0}"));
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {:.1} | {:.2} | {:.2} | {:.2} | {:.0} | {rss} | {:.2} M |",
            c.name,
            c.build,
            c.stored_triangles,
            c.placed_triangles,
            c.instances,
            c.file_mib,
            c.load_seconds,
            c.build_seconds,
            c.bvh_seconds,
            c.scene_mib,
            c.samples_per_second / 1e6
        );
    }
    let _ = writeln!(
        md,
        "\nPeak RSS: the process's peak resident memory during load and build above what it held \
         before (the file's bytes included in neither). World BVH s: the part of the build that made the \
         world-space mesh's BVH. Samples/s: 128×128, 32 spp, the file's camera \
         (above the grid, looking down at 45°) and sun, tracer defaults."
    );
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The generated file loads as the case says: one mesh placed by every node, kept instanced
    /// when placed more than once, with the triangle count asked for (to the grid's rounding).
    #[test]
    fn generated_scenes_load_as_described() {
        for placements in [1, 30] {
            let bytes = sphere_glb(5_000, placements).unwrap();
            let scene =
                pathfarm_tracer::gltf::load(&bytes, &NoExternalResources, &LoadOptions::default())
                    .unwrap();
            let n = 50; // ceil(sqrt(5000 / 2))
                        // The grid's pole rows are degenerate fans: dropped as they are read.
            assert_eq!(
                scene.info.triangles + scene.info.degenerate_dropped,
                2 * n * n
            );
            if placements == 1 {
                assert_eq!(scene.info.instances, 0);
            } else {
                assert_eq!(scene.info.instances, placements);
                assert_eq!(
                    scene.info.instanced_triangles,
                    (placements * scene.info.triangles) as u64
                );
            }
        }
    }
}
