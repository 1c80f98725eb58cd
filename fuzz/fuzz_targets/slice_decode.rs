//! `slice_decode`: arbitrary bytes as an uploaded slice body. The check itself (no panic; canonical
//! round trip; the server's merge and stored-tile path) lives in `pathfarm_wire::fuzzing::slice_decode`,
//! shared with the replay test `crates/wire/tests/fuzz_corpus.rs`.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    pathfarm_wire::fuzzing::slice_decode(data);
});
