//! The tracer's throughput on one bench scene, for profiling and for checking that an optimisation
//! keeps every bit: `cargo run --release -p pathfarm-bench --example throughput -- [SCENE] [THREADS]
//! [SPP]` with SCENE `cornell` (the shipped box, default) or `sphere330k` (the box plus the
//! 327,680-triangle displaced sphere of `pathfarm bench speed`), or the path of a `.glb` (such as
//! `scenes/suite/instanced.glb`; with `:flat` after it, its instanced meshes flattened into world
//! triangles, to compare the two levels with one). `+sky` after any of them lights the scene with
//! a uniform sky as well (radiance 0.6, 0.75, 1.0: the peer comparison's environment scene's), and
//! `+unguided` after that renders it without its caustic guide (built, where it has one, before
//! the clock starts).
//! Prints samples and rays per second and a hash of the accumulation: the hash must not change
//! unless the image is meant to.

use pathfarm_bench::render::render_range;
use pathfarm_bench::scenes;
use pathfarm_tracer::gltf::{load_parts, LoadOptions, NoExternalResources};
use pathfarm_tracer::light::Environment;
use pathfarm_tracer::Scene;
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let full_name = args.first().map_or("cornell", String::as_str);
    let (name, unguided) = match full_name.strip_suffix("+unguided") {
        Some(name) => (name, true),
        None => (full_name, false),
    };
    let (name, sky) = match name.strip_suffix("+sky") {
        Some(name) => (name, true),
        None => (name, false),
    };
    let threads: usize = args.get(1).map_or(Ok(2), |s| s.parse())?;
    let spp: u32 = args.get(2).map_or(Ok(64), |s| s.parse())?;
    let dir = Path::new("scenes");
    let scene = match name {
        "sphere330k" => {
            let (parts, _) = scenes::cornell_with_sphere(name, dir, scenes::FREQ_330K)?;
            Scene::build(parts)?
        }
        file if file.ends_with(".glb") || file.ends_with(".glb:flat") => {
            let (path, flat) = match file.strip_suffix(":flat") {
                Some(path) => (path, true),
                None => (file, false),
            };
            let bytes = std::fs::read(path)?;
            let parts = load_parts(&bytes, &NoExternalResources, &LoadOptions::default())?;
            Scene::build(if flat {
                parts.flatten_instances()
            } else {
                parts
            })?
        }
        _ => scenes::load(&scenes::find(name)?, dir)?.scene,
    };
    let scene = match sky {
        true => {
            scene.with_environment(Some(Environment::uniform(glam::Vec3::new(0.6, 0.75, 1.0))?))
        }
        false => scene,
    };
    let scene = match unguided {
        true => scene.without_caustic_guide(),
        false => scene,
    };
    // The caustic guide (where the scene has one) is built before the clock starts: what is
    // timed is the samples.
    if let Some(guide) = scene.caustic_guide() {
        println!("caustic guide: {} cells", guide.cells());
    }
    let settings = pathfarm_bench::speed::settings(256, 256, 1);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    let r = pool.install(|| render_range(&scene, &settings, 0..spp));
    let samples = 256.0 * 256.0 * spp as f64;
    let hash = r.acc.pixels.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, p| {
        let words = [p.sum[0], p.sum[1], p.sum[2], p.sum_sq_lum, p.count as u128];
        words
            .iter()
            .fold(h, |h, w| scenes::fnv1a(&w.to_le_bytes(), h))
    });
    println!(
        "{full_name}: {threads} threads, {spp} spp: {:.3} s, {:.3} M samples/s, {:.2} M rays/s, hash {hash:016x}",
        r.seconds,
        samples / r.seconds / 1e6,
        r.acc.rays as f64 / r.seconds / 1e6,
    );
    Ok(())
}
