//! Helpers shared by the crate's unit tests.

/// A deterministic stream of uniform values in [0, 1) (xorshift64, top 24 bits): reproducible
/// random cases without a dependency, the same on every run.
pub(crate) fn uniform_stream(seed: u64) -> impl FnMut() -> f32 {
    let mut s = seed;
    move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 40) as f32 / (1u64 << 24) as f32
    }
}
