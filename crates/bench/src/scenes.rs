//! The bench scenes: the files the project ships under `scenes/`, plus one generated in memory.

use crate::error::BenchError;
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};
use pathfarm_tracer::scene::SceneParts;
use pathfarm_tracer::Scene;
use std::path::Path;
use std::time::Instant;

#[path = "../../tracer/examples/scene_gen/mod.rs"]
mod scene_gen;

/// Geodesic frequencies of the generated sphere: 327,680 and 1,003,520 triangles.
pub use scene_gen::{FREQ_1M, FREQ_330K};

/// Where a bench scene comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Source {
    /// A glTF file in the scenes directory.
    File(&'static str),
    /// The Cornell box plus a displaced sphere of 1,003,520 triangles, generated in memory (the
    /// generator of `crates/tracer/examples/make_scenes.rs`): 40 MB of GLB kept out of the repository.
    MillionTriangles,
}

/// One scene of the study.
#[derive(Clone, Copy, Debug)]
pub struct BenchScene {
    pub name: &'static str,
    pub source: Source,
    /// What the scene is and which estimator it stresses.
    pub description: &'static str,
    /// The exact luminance of every pixel, where it is known analytically.
    pub exact: Option<f64>,
    /// Exposure (EV) of the PNGs the report shows.
    pub exposure: f32,
}

/// Every bench scene, in report order.
pub const ALL: [BenchScene; 7] = [
    BenchScene {
        name: "cornell",
        source: Source::File("cornell.gltf"),
        description: "The Cornell box (32 triangles, one ceiling light): the everyday case.",
        exact: None,
        exposure: 0.0,
    },
    BenchScene {
        name: "furnace",
        source: Source::File("furnace.gltf"),
        description: "Camera inside a closed sphere whose every surface emits 1 and reflects \
                      50 % (Lambertian): the exact answer is 2.0 at every pixel.",
        exact: Some(2.0),
        exposure: -1.0,
    },
    BenchScene {
        name: "smalllight",
        source: Source::File("smalllight.gltf"),
        description: "A room lit by one very small, very bright light: directions sampled \
                      around the surface (hemisphere, cosine, BSDF) almost never find it; \
                      light sampling does.",
        exact: None,
        exposure: 0.0,
    },
    BenchScene {
        name: "caustics",
        source: Source::File("caustics.gltf"),
        description: "A glass sphere and a mirror sphere in a box: caustics, reached only by \
                      paths that hit the light through a delta lobe.",
        exact: None,
        exposure: 0.0,
    },
    BenchScene {
        name: "glossy",
        source: Source::File("glossy.gltf"),
        description: "A glossy metal floor: light sampling is poor on a narrow lobe, BSDF \
                      sampling is good, MIS takes the better of the two.",
        exact: None,
        exposure: 0.0,
    },
    BenchScene {
        name: "textured",
        source: Source::File("textured.gltf"),
        description: "A textured glTF model (base colour and normal map): the texture paths of \
                      the shading code.",
        exact: None,
        exposure: 0.0,
    },
    BenchScene {
        name: "million",
        source: Source::MillionTriangles,
        description: "The Cornell box with a displaced sphere of 1,003,520 triangles \
                      (generated in memory): ray traversal cost.",
        exact: None,
        exposure: 0.0,
    },
];

/// The scenes `--quick` uses unless `--scenes` says otherwise (the generated million-triangle scene
/// is left out: building it takes longer than the whole quick study).
pub const QUICK: [&str; 6] = [
    "cornell",
    "furnace",
    "smalllight",
    "caustics",
    "glossy",
    "textured",
];

/// The scene called `name`.
pub fn find(name: &str) -> Result<BenchScene, BenchError> {
    ALL.iter()
        .find(|s| s.name == name)
        .copied()
        .ok_or_else(|| BenchError::UnknownScene(name.to_string()))
}

/// A scene ready to render.
pub struct LoadedScene {
    pub scene: Scene,
    /// A hash of the scene's bytes (FNV-1a, stable across builds): the reference cache key.
    pub content_hash: u64,
    pub triangles: usize,
    /// Loading and building (BVH included), seconds.
    pub build_seconds: f64,
}

/// FNV-1a, 64-bit: a stable hash for cache keys (std's hasher may change between releases).
pub fn fnv1a(bytes: &[u8], mut h: u64) -> u64 {
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;

fn read(path: &Path) -> Result<Vec<u8>, BenchError> {
    std::fs::read(path).map_err(|e| BenchError::io(path, e))
}

/// Loads `scene` from `scenes_dir` (or generates it) and builds it.
pub fn load(scene: &BenchScene, scenes_dir: &Path) -> Result<LoadedScene, BenchError> {
    let started = Instant::now();
    let err = |message: String| BenchError::Scene {
        name: scene.name.to_string(),
        message,
    };
    let (built, content_hash) = match scene.source {
        Source::File(file) => {
            let path = scenes_dir.join(file);
            let bytes = read(&path)?;
            let built = gltf::load(&bytes, &NoExternalResources, &LoadOptions::default())
                .map_err(|e| err(format!("{}: {e}", path.display())))?;
            (built, fnv1a(&bytes, FNV_OFFSET))
        }
        Source::MillionTriangles => {
            let (parts, box_hash) = cornell_with_sphere(scene.name, scenes_dir, FREQ_1M)?;
            let built = Scene::build(parts).map_err(|e| err(e.to_string()))?;
            // The generator is deterministic: the box's bytes and the generator's version name it.
            (built, fnv1a(b"million-v1", box_hash))
        }
    };
    Ok(LoadedScene {
        triangles: built.info.triangles,
        scene: built,
        content_hash,
        build_seconds: started.elapsed().as_secs_f64(),
    })
}

/// The shipped Cornell box (`scenes_dir/cornell.gltf`) plus the generator's displaced sphere of
/// frequency `freq` (20·freq² triangles), not yet built, and the FNV-1a hash of the box's bytes.
/// What `scene_gen::cornell_with` makes for the tracer's criterion benches, but read from the
/// scenes directory given and with errors (named after `name`) where that one panics.
pub fn cornell_with_sphere(
    name: &str,
    scenes_dir: &Path,
    freq: u32,
) -> Result<(SceneParts, u64), BenchError> {
    let err = |message: String| BenchError::Scene {
        name: name.to_string(),
        message,
    };
    let path = scenes_dir.join("cornell.gltf");
    let bytes = read(&path)?;
    let mut parts = gltf::load_parts(&bytes, &NoExternalResources, &LoadOptions::default())
        .map_err(|e| err(format!("{}: {e}", path.display())))?;
    scene_gen::add_white_mesh(&mut parts, &scene_gen::bench_sphere(freq))
        .map_err(|e| err(format!("{}: {e}", path.display())))?;
    Ok((parts, fnv1a(&bytes, FNV_OFFSET)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_scene_name_is_unique_and_found() {
        for s in ALL {
            assert_eq!(find(s.name).unwrap().name, s.name);
            assert_eq!(ALL.iter().filter(|t| t.name == s.name).count(), 1);
        }
        for q in QUICK {
            assert!(find(q).is_ok(), "{q}");
        }
        assert!(matches!(find("nope"), Err(BenchError::UnknownScene(_))));
    }

    #[test]
    fn fnv1a_matches_the_published_test_vector() {
        assert_eq!(fnv1a(b"a", FNV_OFFSET), 0xaf63_dc4c_8601_ec8c);
    }
}
