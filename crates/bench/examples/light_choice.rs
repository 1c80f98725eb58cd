//! The scene's own light choice (a light tree for many emitters or many lamps, each lamp's
//! contribution at the point for a few lamps) against choosing lights by power alone, at equal
//! time (both families are switched to power for the comparison):
//! `cargo run --release -p pathfarm-bench --example light_choice -- FILE.glb [THREADS] [SPP]
//! [ROUNDS] [FAMILY]`, FAMILY `all` (the default), `area` or `lamps`: which family the power
//! side chooses by power (the other keeps the scene's choice).
//!
//! Each choice renders the scene (256 × 256, MIS) with two seeds per round, the choices
//! alternating so that the VM's drift touches both alike. The noise of one render is estimated
//! without a reference, from the two seeds: RMSE² = mean over pixels of (a − b)² / 2 (luminance,
//! relative to the image mean). Equal-time error ratio = √(RMSE²_scene · t_scene / (RMSE²_power ·
//! t_power)): below 1, the scene's choice reaches a lower error in the same time. The image means are
//! compared too (both choices are unbiased: they must agree within their noise).

use pathfarm_bench::render::render_range;
use pathfarm_tracer::gltf::{load_parts, LoadOptions, NoExternalResources};
use pathfarm_tracer::Scene;

/// Per-pixel mean luminance of a render.
fn luminances(scene: &Scene, seed: u64, spp: u32) -> (Vec<f64>, f64) {
    let settings = pathfarm_bench::speed::settings(256, 256, seed);
    let r = render_range(scene, &settings, 0..spp);
    let lum = r
        .acc
        .pixels
        .iter()
        .map(|p| {
            let m = p.mean();
            0.2126 * m[0] + 0.7152 * m[1] + 0.0722 * m[2]
        })
        .collect();
    (lum, r.seconds)
}

#[derive(Default)]
struct Tally {
    seconds: f64,
    renders: u32,
    /// Σ over rounds of the relative noise² of one render.
    noise2: f64,
    means: Vec<f64>,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path = args
        .first()
        .ok_or("usage: light_choice FILE.glb [THREADS] [SPP] [ROUNDS] [all|area|lamps]")?;
    let threads: usize = args.get(1).map_or(Ok(2), |s| s.parse())?;
    let spp: u32 = args.get(2).map_or(Ok(16), |s| s.parse())?;
    let rounds: u32 = args.get(3).map_or(Ok(3), |s| s.parse())?;
    let family = args.get(4).map_or("all", String::as_str);
    if !["all", "area", "lamps"].contains(&family) {
        return Err(format!("FAMILY is all, area or lamps, not {family}").into());
    }
    let bytes = std::fs::read(path)?;
    let parts = load_parts(&bytes, &NoExternalResources, &LoadOptions::default())?;
    let scene = Scene::build(parts)?;
    if !scene.lights.area.has_tree()
        && scene.lights.punctual_tree.is_none()
        && !scene.lights.punctual_per_point
    {
        return Err(format!(
            "{path}: its {} light triangles and {} punctual lamps are chosen by power already",
            scene.lights.area.triangles.len(),
            scene.lights.punctual.len()
        )
        .into());
    }
    println!(
        "{path}: {} light triangles ({}), {} punctual lamps ({})",
        scene.lights.area.triangles.len(),
        if scene.lights.area.has_tree() {
            "tree"
        } else {
            "power"
        },
        scene.lights.punctual.len(),
        if scene.lights.punctual_tree.is_some() {
            "tree"
        } else if scene.lights.punctual_per_point {
            "per point"
        } else {
            "power"
        },
    );
    let mut power = scene.clone();
    if family != "lamps" {
        power.lights.area.choose_by_power();
    }
    if family != "area" {
        power.lights.choose_punctual_by_power();
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    let (mut t_tree, mut t_power) = (Tally::default(), Tally::default());
    for round in 0..rounds {
        for (scene, tally) in [(&scene, &mut t_tree), (&power, &mut t_power)] {
            let seeds = [2 * round as u64 + 1, 2 * round as u64 + 2];
            let (a, ta) = pool.install(|| luminances(scene, seeds[0], spp));
            let (b, tb) = pool.install(|| luminances(scene, seeds[1], spp));
            let n = a.len() as f64;
            let mean = (a.iter().sum::<f64>() + b.iter().sum::<f64>()) / (2.0 * n);
            let noise2 = a
                .iter()
                .zip(&b)
                .map(|(x, y)| (x - y) * (x - y) / 2.0)
                .sum::<f64>()
                / n;
            tally.noise2 += noise2 / (mean * mean);
            tally.seconds += ta + tb;
            tally.renders += 2;
            tally.means.push(mean);
        }
    }
    let report = |name: &str, t: &Tally| {
        let secs = t.seconds / t.renders as f64;
        let noise2 = t.noise2 / rounds as f64;
        let mean = t.means.iter().sum::<f64>() / t.means.len() as f64;
        println!(
            "{name:>5}: {:.3} M samples/s, relative RMSE {:.2} % at {spp} spp, image mean {mean:.5}",
            256.0 * 256.0 * spp as f64 / secs / 1e6,
            100.0 * noise2.sqrt(),
        );
        (noise2 * secs, mean)
    };
    let (e_tree, m_tree) = report("scene", &t_tree);
    let (e_power, m_power) = report("power", &t_power);
    println!(
        "equal-time error, scene's choice ÷ power: {:.3}; image means differ by {:+.2} %",
        (e_tree / e_power).sqrt(),
        100.0 * (m_tree / m_power - 1.0)
    );
    Ok(())
}
