//! Replays the fuzz target `gltf_load` (fuzz/, see docs/fuzzing.md) on stable: every committed input
//! of `fuzz/corpus/gltf_load/` and every fixed crash of `fuzz/regressions/gltf_load/` goes through the
//! very check the fuzz target runs (`pathfarm_tracer::fuzzing::gltf_load`), so a regression shows up in
//! `cargo test --workspace` without nightly or cargo-fuzz.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

/// The files of `fuzz/<kind>/<target>/`, sorted. Panics if the directory is missing or empty: a
/// replay that finds nothing must not pass silently.
fn inputs(kind: &str, target: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../fuzz")
        .join(kind)
        .join(target);
    let entries =
        std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("cannot read {}: {e}", dir.display()));
    let mut files: Vec<PathBuf> = entries
        .map(|e| e.expect("directory entry").path())
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    assert!(!files.is_empty(), "{} holds no inputs", dir.display());
    files
}

/// Runs `check` on every file, naming each one that fails, and returns how many ran.
fn replay(files: &[PathBuf], check: fn(&[u8])) -> usize {
    let mut failed = Vec::new();
    for path in files {
        let bytes =
            std::fs::read(path).unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
        if catch_unwind(AssertUnwindSafe(|| check(&bytes))).is_err() {
            failed.push(path.display().to_string());
        }
    }
    assert!(failed.is_empty(), "fuzz check failed on: {failed:#?}");
    files.len()
}

#[test]
fn gltf_load_corpus_and_regressions() {
    let corpus = replay(
        &inputs("corpus", "gltf_load"),
        pathfarm_tracer::fuzzing::gltf_load,
    );
    let regressions = replay(
        &inputs("regressions", "gltf_load"),
        pathfarm_tracer::fuzzing::gltf_load,
    );
    eprintln!("gltf_load: replayed {corpus} corpus inputs and {regressions} regressions");
}

/// The same inputs through the animated loader (`fuzzing::gltf_animated`), and the animated scene
/// Blender exports.
#[test]
fn gltf_animated_corpus_and_regressions() {
    let check = pathfarm_tracer::fuzzing::gltf_animated;
    let corpus = replay(&inputs("corpus", "gltf_load"), check);
    let regressions = replay(&inputs("regressions", "gltf_load"), check);
    let blender = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/suite/animated.glb");
    replay(&[blender], check);
    eprintln!("gltf_animated: replayed {corpus} corpus inputs and {regressions} regressions");
}
