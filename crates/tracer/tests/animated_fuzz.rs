//! A deterministic mutation loop over the animated scene Blender exports: numbers of its JSON
//! changed (accessor, node, sampler and skin indices, counts, offsets, times) and bytes of its
//! binary chunk changed (keyframes, inverse bind matrices, joints, weights, morph targets). The
//! animated loader and every scene built from it must fail with an error, never a panic
//! (`pathfarm_tracer::fuzzing::gltf_animated`, the check of the `gltf_animated` fuzz target).

use std::panic::{catch_unwind, AssertUnwindSafe};

struct XorShift(u64);

impl XorShift {
    fn next(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.0 = x;
        x
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

fn iterations() -> usize {
    std::env::var("GLTF_FUZZ_ITERATIONS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(600)
}

#[test]
fn mutated_animated_files_never_panic() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../scenes/suite/animated.glb"
    );
    let glb = std::fs::read(path).unwrap();
    let json_len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let json = 20..20 + json_len;
    let bin = 20 + json_len + 8..glb.len();
    let digits: Vec<usize> = json.clone().filter(|&i| glb[i].is_ascii_digit()).collect();
    let mut rng = XorShift(0xA076_1D64_78BD_642F);
    let mut failed = Vec::new();
    for k in 0..iterations() {
        let mut b = glb.clone();
        for _ in 0..1 + rng.below(3) {
            if rng.below(2) == 0 {
                // A digit of the JSON (the chunk keeps its length).
                let at = digits[rng.below(digits.len())];
                b[at] = b"0123456789"[rng.below(10)];
            } else {
                let at = bin.start + rng.below(bin.len());
                match rng.below(3) {
                    0 => b[at] = rng.next() as u8,
                    1 => b[at] ^= 1 << rng.below(8),
                    // A float's sign and exponent byte: huge, tiny, negative or NaN values.
                    _ => b[at] = [0x7F, 0xFF, 0x80, 0x00, 0x4F][rng.below(5)],
                }
            }
        }
        let outcome = catch_unwind(AssertUnwindSafe(|| {
            pathfarm_tracer::fuzzing::gltf_animated(&b)
        }));
        if outcome.is_err() {
            failed.push(k);
        }
    }
    assert!(failed.is_empty(), "iterations that panicked: {failed:?}");
}
