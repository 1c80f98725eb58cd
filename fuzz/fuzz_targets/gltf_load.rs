//! `gltf_load`: arbitrary bytes as a submitted `.gltf`/`.glb` scene, loaded exactly as the server
//! validates submissions (then rendered on a tiny tile as a worker would). The check itself lives in
//! `pathfarm_tracer::fuzzing::gltf_load`, shared with the replay test `crates/tracer/tests/fuzz_corpus.rs`.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    pathfarm_tracer::fuzzing::gltf_load(data);
});
