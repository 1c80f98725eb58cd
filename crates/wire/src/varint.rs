//! Unsigned LEB128 variable-length integers: 7 bits per byte, high bit = more bytes follow.
//! Accumulation sums are mostly far below their `u128` range, so this shrinks them ~3×.

/// Appends `v` to `out`.
#[inline]
/// How many bytes [`put`] writes for `v`.
pub fn len(v: u128) -> usize {
    let bits = 128 - v.leading_zeros() as usize;
    bits.div_ceil(7).max(1)
}

pub fn put(out: &mut Vec<u8>, mut v: u128) {
    loop {
        let byte = (v & 0x7f) as u8;
        v >>= 7;
        if v == 0 {
            out.push(byte);
            return;
        }
        out.push(byte | 0x80);
    }
}

/// Why a varint could not be read.
#[derive(Debug, PartialEq, Eq)]
pub enum VarintError {
    /// The input ended inside the number.
    Truncated,
    /// More than `max_bits` bits, or a non-canonical (zero-padded) encoding.
    Invalid,
}

/// Reads one varint of at most `max_bits` bits from `input` at `*pos`, advancing `*pos`.
/// Rejects non-canonical encodings (a final byte of zero after the first), so every value has
/// exactly one encoding and a body's bytes are a function of its contents.
#[inline]
pub fn get(input: &[u8], pos: &mut usize, max_bits: u32) -> Result<u128, VarintError> {
    let mut v: u128 = 0;
    let mut shift = 0u32;
    loop {
        let Some(&byte) = input.get(*pos) else {
            return Err(VarintError::Truncated);
        };
        *pos += 1;
        let payload = (byte & 0x7f) as u128;
        if shift >= max_bits || (shift > 0 && payload >> (max_bits - shift).min(127) != 0) {
            return Err(VarintError::Invalid);
        }
        v |= payload << shift;
        if byte & 0x80 == 0 {
            if byte == 0 && shift > 0 {
                return Err(VarintError::Invalid);
            }
            return Ok(v);
        }
        shift += 7;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_and_rejects_bad_encodings() {
        for v in [
            0u128,
            1,
            127,
            128,
            300,
            u64::MAX as u128,
            u128::MAX >> 1,
            u128::MAX,
        ] {
            let mut buf = Vec::new();
            put(&mut buf, v);
            let mut pos = 0;
            assert_eq!(get(&buf, &mut pos, 128), Ok(v));
            assert_eq!(pos, buf.len());
            if buf.len() > 1 {
                let mut pos = 0;
                assert_eq!(
                    get(&buf[..buf.len() - 1], &mut pos, 128),
                    Err(VarintError::Truncated)
                );
            }
        }
        // 2^64 does not fit 64 bits.
        let mut buf = Vec::new();
        put(&mut buf, 1u128 << 64);
        assert_eq!(get(&buf, &mut 0, 64), Err(VarintError::Invalid));
        // Non-canonical: 1 encoded as two bytes.
        assert_eq!(get(&[0x81, 0x00], &mut 0, 64), Err(VarintError::Invalid));
        // Too long for u128.
        assert_eq!(get(&[0xff; 20], &mut 0, 128), Err(VarintError::Invalid));
    }
}
