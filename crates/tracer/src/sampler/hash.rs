/// A 32-bit integer hash with good avalanche (the "lowbias32" finaliser by Chris Wellons).
#[inline]
pub const fn hash_u32(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x21f0_aaad);
    x ^= x >> 15;
    x = x.wrapping_mul(0x735a_2d97);
    x ^= x >> 15;
    x
}

/// Hashes a short sequence of words into one (each word mixed into the running state).
#[inline]
pub fn hash_words(words: &[u32]) -> u32 {
    let mut h = 0x9e37_79b9u32;
    for &w in words {
        h = hash_u32(h ^ hash_u32(w.wrapping_add(0x632b_e5ab)));
    }
    h
}
