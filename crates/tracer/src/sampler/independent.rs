use super::{bits_to_unit, hash_u32};

/// Independent uniform samples: a counter-based hash of (pixel key, sample index, dimension). Plain
/// Monte Carlo, the baseline the low-discrepancy sampler is measured against.
#[inline]
pub fn independent_sample(pixel_key: u32, index: u32, dim: u32) -> f32 {
    let h = hash_u32(
        pixel_key ^ hash_u32(index ^ hash_u32(dim.wrapping_mul(0x9e37_79b9) ^ 0x85eb_ca6b)),
    );
    bits_to_unit(hash_u32(h.wrapping_add(index)))
}
