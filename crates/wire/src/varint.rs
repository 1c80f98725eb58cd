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
///
/// The first nine bytes (63 bits, every pixel count and most sums) are gathered in a `u64` and
/// checked with narrow shifts; only longer numbers pay for `u128` arithmetic. A server decodes a
/// stored tile on every merge and every image build, and this loop was the largest part of it.
#[inline]
pub fn get(input: &[u8], pos: &mut usize, max_bits: u32) -> Result<u128, VarintError> {
    let mut short: u64 = 0;
    let mut shift = 0u32;
    while shift < 63 {
        let Some(&byte) = input.get(*pos) else {
            return Err(VarintError::Truncated);
        };
        *pos += 1;
        let payload = byte & 0x7f;
        check_room(payload, shift, max_bits)?;
        short |= u64::from(payload) << shift;
        if byte & 0x80 == 0 {
            if byte == 0 && shift > 0 {
                return Err(VarintError::Invalid);
            }
            return Ok(u128::from(short));
        }
        shift += 7;
    }
    let mut v = u128::from(short);
    loop {
        let Some(&byte) = input.get(*pos) else {
            return Err(VarintError::Truncated);
        };
        *pos += 1;
        let payload = byte & 0x7f;
        check_room(payload, shift, max_bits)?;
        v |= u128::from(payload) << shift;
        if byte & 0x80 == 0 {
            if byte == 0 {
                return Err(VarintError::Invalid);
            }
            return Ok(v);
        }
        shift += 7;
    }
}

/// Whether a 7-bit `payload` at bit `shift` stays within `max_bits` bits.
#[inline(always)]
fn check_room(payload: u8, shift: u32, max_bits: u32) -> Result<(), VarintError> {
    if shift >= max_bits {
        return Err(VarintError::Invalid);
    }
    let room = max_bits - shift;
    if shift > 0 && room < 7 && payload >> room != 0 {
        return Err(VarintError::Invalid);
    }
    Ok(())
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

    /// The straightforward decoder `get` replaced (`u128` throughout), kept as its oracle.
    fn get_reference(input: &[u8], pos: &mut usize, max_bits: u32) -> Result<u128, VarintError> {
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

    #[test]
    fn the_fast_decoder_agrees_with_the_reference_on_any_bytes() {
        let mut rng = fastrand::Rng::with_seed(7);
        for case in 0..200_000u32 {
            let len = rng.usize(0..24);
            let mut bytes: Vec<u8> = (0..len)
                .map(|_| match rng.u8(0..4) {
                    0 => rng.u8(..),
                    1 => 0x80 | rng.u8(..),
                    2 => 0xff,
                    _ => rng.u8(0..0x80),
                })
                .collect();
            // Valid encodings of values of every length, often.
            if case % 3 == 0 {
                bytes.clear();
                let v = rng.u128(..) >> rng.u32(0..128);
                put(&mut bytes, v);
            }
            for max_bits in [32, 63, 64, 65, 96, 127, 128] {
                let (mut a, mut b) = (0, 0);
                assert_eq!(
                    get(&bytes, &mut a, max_bits),
                    get_reference(&bytes, &mut b, max_bits),
                    "{bytes:02x?} at {max_bits} bits"
                );
                assert_eq!(a, b, "{bytes:02x?} at {max_bits} bits");
            }
        }
    }
}
