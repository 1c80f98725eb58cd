//! `gltf_animated`: arbitrary bytes as a scene loaded through the animated loader and built at a
//! few times (then rendered on a tiny tile). The check lives in
//! `pathfarm_tracer::fuzzing::gltf_animated`, shared with `crates/tracer/tests/fuzz_corpus.rs`.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    pathfarm_tracer::fuzzing::gltf_animated(data);
});
