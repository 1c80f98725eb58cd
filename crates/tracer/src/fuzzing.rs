//! The checks behind the cargo-fuzz targets in `fuzz/` (see `docs/fuzzing.md`), here so that the
//! fuzz targets and the stable replay test (`tests/fuzz_corpus.rs`) run exactly the same code. Not
//! part of the tracer's API: hidden from the docs and free to change.

use crate::gltf::{self, GltfError, LoadOptions, NoExternalResources};
use crate::{render_sample, PixelAccum, RenderSettings};

/// Fuzz target `gltf_load`: `bytes` as a submitted `.gltf`/`.glb`, loaded as a worker loads it
/// (no external resources, the default camera). Errors are fine; a panic is a finding, and so is
/// [`GltfError::Internal`]: it is a panic the loader caught, still a bug. So is a [`gltf::check`]
/// (how the server validates a submission, without the build) that disagrees with the load: it
/// must give the same warnings, or the same error.
///
/// A scene that loads is then rendered the way a worker would, on a tiny image (4 × 4 pixels, one
/// sample each, at most 4 bounces so that a closed mirror box cannot keep a path going for long): a
/// scene the server accepts must not crash the workers that render it. The samples are rendered
/// with [`render_sample`] (what `render_tile` calls per sample) on the calling thread rather than
/// through `render_tile`'s rayon pool, so that a panic is deterministic and libFuzzer saves the input.
pub fn gltf_load(bytes: &[u8]) {
    let options = LoadOptions::default();
    let loaded = gltf::load(bytes, &NoExternalResources, &options);
    // The server's check of a submission must pass exactly what the workers will load.
    let checked = gltf::check(bytes, &NoExternalResources, &options).map_err(|e| e.to_string());
    let same = match &loaded {
        Ok(scene) => checked.as_ref() == Ok(&scene.info.warnings),
        Err(e) => checked.as_ref() == Err(&e.to_string()),
    };
    assert!(
        same,
        "gltf::check disagrees with gltf::load: {checked:?}, load: {:?}",
        loaded
            .as_ref()
            .map(|s| &s.info.warnings)
            .map_err(|e| e.to_string())
    );
    let scene = match loaded {
        Ok(scene) => scene,
        Err(GltfError::Internal(message)) => {
            panic!("the glTF loader panicked (caught as GltfError::Internal): {message}")
        }
        Err(_) => return,
    };
    let mut settings = RenderSettings::new(4, 4);
    settings.max_depth = Some(4);
    for y in 0..settings.height {
        for x in 0..settings.width {
            // Invalid radiance (NaN, negative, huge) is legal: the accumulation counts it apart.
            let mut pixel = PixelAccum::default();
            pixel.add_sample(render_sample(&scene, &settings, x, y, 0).radiance);
        }
    }
}

/// Fuzz target `gltf_animated`: `bytes` through the animated loader ([`gltf::AnimatedScene`], what
/// a frame of a farm job will load), then the scene built at the animation's ends, its middle and
/// outside it, and the middle frame's samples rendered as [`gltf_load`] renders them. The same
/// findings as [`gltf_load`]: a panic, or [`GltfError::Internal`].
pub fn gltf_animated(bytes: &[u8]) {
    let check = |r: Result<crate::Scene, GltfError>| match r {
        Err(GltfError::Internal(message)) => {
            panic!("the animated glTF loader panicked (caught as GltfError::Internal): {message}")
        }
        other => other.ok(),
    };
    let scene =
        match gltf::AnimatedScene::load(bytes, &NoExternalResources, &LoadOptions::default()) {
            Ok(scene) => scene,
            Err(GltfError::Internal(message)) => {
                panic!(
                    "the animated glTF loader panicked (caught as GltfError::Internal): {message}"
                )
            }
            Err(_) => return,
        };
    let span = scene.time_span().unwrap_or(gltf::TimeSpan {
        start: 0.0,
        end: 0.0,
    });
    for time in [span.start, span.end, -1.0, f32::NAN] {
        check(scene.scene_at(time));
    }
    let Some(frame) = check(scene.scene_at(0.5 * (span.start + span.end))) else {
        return;
    };
    let mut settings = RenderSettings::new(4, 4);
    settings.max_depth = Some(4);
    for y in 0..settings.height {
        for x in 0..settings.width {
            let mut pixel = PixelAccum::default();
            pixel.add_sample(render_sample(&frame, &settings, x, y, 0).radiance);
        }
    }
}
