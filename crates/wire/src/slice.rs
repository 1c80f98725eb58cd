//! The slice body: an [`Accumulation`] of one tile over one sample range, as a worker uploads it.
//!
//! Layout, version 2 (all fixed-width integers little-endian; `v` = unsigned LEB128 varint, canonical):
//!
//! ```text
//! magic        4 bytes  "PFSL"
//! version      u16      2 (1 is read too)
//! flags        u16      0 (reserved)
//! x0 y0 w h    4 × u32  the tile
//! begin end    2 × u32  the sample range [begin, end)
//! rays         v (u64)
//! invalid      v (u64)  samples rejected as NaN/∞/negative/huge (≤ w × h × (end − begin))
//! recorded     v        number of recorded invalid samples (≤ 64, ≤ invalid), then for each: x, y,
//!                       index (v each)
//! pixels       w × h ×  count v(u64), sum R v(u128), sum G v(u128), sum B v(u128), Σ luminance² v(u128)
//! checksum     u64      CRC-32 (IEEE, as in gzip and PNG) of every byte before it, high 32 bits 0
//! ```
//!
//! Version 1 differs only in its checksum: FNV-1a 64 of the same bytes. It went byte by byte, a
//! multiply each, and took about as long as the rest of a tile's encoding or decoding; a server
//! decodes every upload and decodes and encodes the stored tile of every merge. CRC-32 runs on the
//! CPU's carry-less multiply (`crc32fast`) and detects what a checksum here is for, corruption in
//! transit or at rest (the decoder's own bounds catch lies). Version 1 bodies (older workers,
//! tiles stored by older servers) are still read; this build writes version 2, which older
//! servers refuse, so a farm upgrades its server before its workers.
//!
//! Varints make a slice about a third of the 72 bytes per pixel the accumulation holds in memory,
//! because the sums of a slice are far below the `u128` range. Decoding checks every length, range
//! and the checksum, and never panics: the server feeds it untrusted bytes. It also refuses pixel
//! sums that no honest set of `count` samples can produce (see [`max_sample_sums`]), so that the
//! server's merges of decoded slices stay far below the `u128` range.

use crate::varint::{self, VarintError};
use pathfarm_tracer::accumulation::{InvalidSample, MAX_RECORDED_INVALID, MAX_SAMPLE_VALUE};
use pathfarm_tracer::{Accumulation, PixelAccum};

pub const SLICE_MAGIC: [u8; 4] = *b"PFSL";
/// The version this build writes.
pub const SLICE_VERSION: u16 = 2;
/// The oldest version this build reads ([`SLICE_VERSION`] differs from it in the checksum only).
pub const SLICE_VERSION_FNV: u16 = 1;

/// An accumulation together with the sample range it covers.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Slice {
    pub sample_begin: u32,
    pub sample_end: u32,
    pub acc: Accumulation,
}

/// Bounds a decoder enforces before allocating anything.
#[derive(Clone, Copy, Debug)]
pub struct SliceLimits {
    /// Largest tile (width × height) accepted.
    pub max_pixels: u64,
}

impl Default for SliceLimits {
    fn default() -> Self {
        SliceLimits {
            max_pixels: 4096 * 4096,
        }
    }
}

/// Why a slice body was rejected.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum SliceError {
    #[error("not a pathfarm slice (bad magic)")]
    Magic,
    #[error("unsupported slice version {0} (this build reads version {SLICE_VERSION})")]
    Version(u16),
    #[error("reserved flags {0:#x} are set")]
    Flags(u16),
    #[error("slice body truncated in {0}")]
    Truncated(&'static str),
    #[error("invalid number in {0}")]
    Number(&'static str),
    #[error("tile {width}x{height} is empty or larger than the limit of {limit} pixels")]
    TileSize { width: u32, height: u32, limit: u64 },
    #[error("empty or reversed sample range [{begin}, {end})")]
    SampleRange { begin: u32, end: u32 },
    #[error("pixel {index} has {count} samples, more than the {range} in the sample range")]
    PixelCount { index: u64, count: u64, range: u32 },
    #[error(
        "pixel {index} holds sums that {count} samples cannot reach (a sample adds at most \
         {channel} to a channel sum and {lum_sq} to the luminance² sum, in units of 2⁻³²)"
    )]
    PixelValues {
        index: u64,
        count: u64,
        channel: u128,
        lum_sq: u128,
    },
    #[error("{0} recorded invalid samples (at most {MAX_RECORDED_INVALID})")]
    Recorded(u64),
    #[error("{count} invalid samples, more than the {max} samples the slice covers")]
    InvalidCount { count: u64, max: u128 },
    #[error("{recorded} recorded invalid samples, but only {count} counted")]
    RecordedCount { recorded: u64, count: u64 },
    #[error("recorded invalid sample ({x}, {y}) #{index} lies outside the slice")]
    RecordedOutside { x: u32, y: u32, index: u32 },
    #[error("checksum mismatch: the body was corrupted")]
    Checksum,
    #[error("{0} unexpected bytes after the checksum")]
    Trailing(usize),
}

/// The checksum trailer of a body of `version` whose bytes before the trailer are `body`: CRC-32
/// (version 2) or FNV-1a 64 (version 1).
pub fn slice_checksum(version: u16, body: &[u8]) -> u64 {
    if version == SLICE_VERSION_FNV {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for &b in body {
            h ^= b as u64;
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
        h
    } else {
        u64::from(crc32fast::hash(body))
    }
}

/// Encodes a slice.
pub fn encode_slice(slice: &Slice) -> Vec<u8> {
    let acc = &slice.acc;
    let mut out = Vec::with_capacity(64 + acc.pixels.len() * 28);
    out.extend_from_slice(&SLICE_MAGIC);
    out.extend_from_slice(&SLICE_VERSION.to_le_bytes());
    out.extend_from_slice(&0u16.to_le_bytes());
    for v in [
        acc.x0,
        acc.y0,
        acc.width,
        acc.height,
        slice.sample_begin,
        slice.sample_end,
    ] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    varint::put(&mut out, acc.rays as u128);
    varint::put(&mut out, acc.invalid_count as u128);
    varint::put(&mut out, acc.invalid.len() as u128);
    for s in &acc.invalid {
        for v in [s.x, s.y, s.index] {
            varint::put(&mut out, v as u128);
        }
    }
    for p in &acc.pixels {
        varint::put(&mut out, p.count as u128);
        for v in [p.sum[0], p.sum[1], p.sum[2], p.sum_sq_lum] {
            varint::put(&mut out, v);
        }
    }
    let sum = slice_checksum(SLICE_VERSION, &out);
    out.extend_from_slice(&sum.to_le_bytes());
    out
}

struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl Reader<'_> {
    fn fixed<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N], SliceError> {
        let end = self.pos.checked_add(N).ok_or(SliceError::Truncated(what))?;
        let chunk = self
            .bytes
            .get(self.pos..end)
            .ok_or(SliceError::Truncated(what))?;
        self.pos = end;
        let mut out = [0u8; N];
        out.copy_from_slice(chunk);
        Ok(out)
    }

    fn u32(&mut self, what: &'static str) -> Result<u32, SliceError> {
        Ok(u32::from_le_bytes(self.fixed::<4>(what)?))
    }

    fn var(&mut self, bits: u32, what: &'static str) -> Result<u128, SliceError> {
        varint::get(self.bytes, &mut self.pos, bits).map_err(|e| match e {
            VarintError::Truncated => SliceError::Truncated(what),
            VarintError::Invalid => SliceError::Number(what),
        })
    }
}

/// The most one valid sample adds to a pixel's sums, in the fixed-point units of the sums:
/// `(channel, luminance²)`.
///
/// The tracer accumulates a sample only when every component is below
/// [`MAX_SAMPLE_VALUE`] (larger ones are counted as invalid), and each sum only grows with each
/// component, so the largest sample is every component at the largest `f32` below that value. Its
/// sums are computed by the tracer's own accumulation code
/// ([`PixelAccum::add_sample`](pathfarm_tracer::PixelAccum::add_sample)), so this bound follows the
/// fixed-point scale and the luminance weights wherever they are defined.
pub fn max_sample_sums() -> (u128, u128) {
    // The largest accumulated component: the f32 just below MAX_SAMPLE_VALUE (2³² − 2⁸).
    let largest = f32::from_bits(MAX_SAMPLE_VALUE.to_bits() - 1);
    // `add_sample` takes the tracer's vector type; `T::default() + c` is the vector with every
    // component `c`, built without naming that type here.
    fn splat<T: Default + std::ops::Add<f32, Output = T>>(c: f32) -> T {
        T::default() + c
    }
    let mut p = PixelAccum::default();
    let accumulated = p.add_sample(splat(largest));
    debug_assert!(accumulated, "the largest valid sample is accumulated");
    (p.sum[0].max(p.sum[1]).max(p.sum[2]), p.sum_sq_lum)
}

/// The largest body an honest slice of `pixels` pixels can take when each pixel holds at most
/// `samples` samples: every pixel's count and sums at their largest ([`max_sample_sums`] times
/// `samples`), the header, the invalid-sample count and the most invalid samples a slice records,
/// and the checksum. A server that accepts tiles of `pixels` pixels must accept bodies this large.
pub fn max_slice_body_bytes(pixels: u64, samples: u64) -> u64 {
    let (sum, sum_sq) = max_sample_sums();
    let n = u128::from(samples);
    let pixel = varint::len(n)
        + 3 * varint::len(sum.saturating_mul(n))
        + varint::len(sum_sq.saturating_mul(n));
    let invalid = MAX_RECORDED_INVALID * 3 * varint::len(u128::from(u32::MAX));
    let fixed = 8 + 6 * 4 + 2 * varint::len(u128::from(u64::MAX)) + varint::len(64) + invalid + 8;
    pixels
        .saturating_mul(pixel as u64)
        .saturating_add(fixed as u64)
}

/// The fixed-size start of a slice body: its tile and sample range, read without decoding (or
/// checking) the rest, so that a server can see what an upload claims to be before it allocates
/// anything for its pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SliceHeader {
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
    pub sample_begin: u32,
    pub sample_end: u32,
}

impl SliceHeader {
    /// `width × height`.
    pub fn pixels(&self) -> u64 {
        self.width as u64 * self.height as u64
    }
}

/// Reads the header of a slice body (magic, version, flags, tile, sample range) without checking
/// the checksum or anything after it: a body whose header reads may still fail [`decode_slice`].
pub fn decode_slice_header(bytes: &[u8]) -> Result<SliceHeader, SliceError> {
    if bytes.len() < 4 || bytes[..4] != SLICE_MAGIC {
        return Err(SliceError::Magic);
    }
    let mut r = Reader { bytes, pos: 4 };
    let version = u16::from_le_bytes(r.fixed::<2>("header")?);
    if version != SLICE_VERSION && version != SLICE_VERSION_FNV {
        return Err(SliceError::Version(version));
    }
    let flags = u16::from_le_bytes(r.fixed::<2>("header")?);
    if flags != 0 {
        return Err(SliceError::Flags(flags));
    }
    // The fixed fields and the checksum.
    if bytes.len() < 8 + 32 {
        return Err(SliceError::Truncated("header"));
    }
    Ok(SliceHeader {
        x0: r.u32("tile")?,
        y0: r.u32("tile")?,
        width: r.u32("tile")?,
        height: r.u32("tile")?,
        sample_begin: r.u32("sample range")?,
        sample_end: r.u32("sample range")?,
    })
}

/// The version field of a body whose header reads ([`decode_slice_header`]).
fn slice_version(bytes: &[u8]) -> u16 {
    u16::from_le_bytes([bytes[4], bytes[5]])
}

/// Decodes and validates a slice body.
pub fn decode_slice(bytes: &[u8], limits: &SliceLimits) -> Result<Slice, SliceError> {
    let header = decode_slice_header(bytes)?;
    // The checksum covers everything before the last 8 bytes; check it before the fields behind
    // the header so corrupted bodies fail with the right reason.
    let body = &bytes[..bytes.len() - 8];
    let mut sum = [0u8; 8];
    sum.copy_from_slice(&bytes[bytes.len() - 8..]);
    if slice_checksum(slice_version(bytes), body) != u64::from_le_bytes(sum) {
        return Err(SliceError::Checksum);
    }
    let SliceHeader {
        x0,
        y0,
        width,
        height,
        sample_begin: begin,
        sample_end: end,
    } = header;
    let mut r = Reader {
        bytes: body,
        pos: 8 + 24,
    };
    let pixels = header.pixels();
    if pixels == 0 || pixels > limits.max_pixels {
        return Err(SliceError::TileSize {
            width,
            height,
            limit: limits.max_pixels,
        });
    }
    if begin >= end {
        return Err(SliceError::SampleRange { begin, end });
    }
    let range = end - begin;
    let rays = r.var(64, "rays")? as u64;
    let invalid_count = r.var(64, "invalid count")? as u64;
    // Each sample of each pixel is either accumulated (and counted in its pixel) or invalid, so a
    // slice cannot hold more invalid samples than it covers. Besides rejecting a lie, this bounds
    // the server's accounting (Σ pixel counts + invalid count ≤ 2 × pixels × range), which would
    // otherwise overflow on an invalid count near 2⁶⁴ (see "Findings" in docs/fuzzing.md).
    let max_invalid = pixels as u128 * range as u128;
    if invalid_count as u128 > max_invalid {
        return Err(SliceError::InvalidCount {
            count: invalid_count,
            max: max_invalid,
        });
    }
    let recorded = r.var(64, "recorded invalid samples")? as u64;
    if recorded > MAX_RECORDED_INVALID as u64 {
        return Err(SliceError::Recorded(recorded));
    }
    // The recorded samples are some of the counted ones.
    if recorded > invalid_count {
        return Err(SliceError::RecordedCount {
            recorded,
            count: invalid_count,
        });
    }
    let mut invalid = Vec::with_capacity(recorded as usize);
    for _ in 0..recorded {
        let x = r.var(32, "recorded invalid samples")? as u32;
        let y = r.var(32, "recorded invalid samples")? as u32;
        let index = r.var(32, "recorded invalid samples")? as u32;
        let inside = x >= x0
            && y >= y0
            && (x - x0) < width
            && (y - y0) < height
            && index >= begin
            && index < end;
        if !inside {
            return Err(SliceError::RecordedOutside { x, y, index });
        }
        invalid.push(InvalidSample { x, y, index });
    }
    // Each pixel takes at least 5 bytes: refuse bodies too short for their tile before allocating.
    if (body.len() - r.pos) as u64 / 5 < pixels {
        return Err(SliceError::Truncated("pixels"));
    }
    // A sample adds at most `max_channel` and `max_lum_sq` to the sums of its pixel: larger sums are
    // a lie. Bounded so, a tile's merged sums stay below its sample count × these (2⁶⁴ and about
    // 2⁹⁶), far below the u128 range for any job's samples per pixel; the server's merge checks
    // its additions all the same.
    let (max_channel, max_lum_sq) = max_sample_sums();
    let mut px = Vec::with_capacity(pixels as usize);
    for index in 0..pixels {
        let count = r.var(64, "pixel count")? as u64;
        if count > range as u64 {
            return Err(SliceError::PixelCount {
                index,
                count,
                range,
            });
        }
        let sum = [
            r.var(128, "pixel sum")?,
            r.var(128, "pixel sum")?,
            r.var(128, "pixel sum")?,
        ];
        let sum_sq_lum = r.var(128, "pixel sum")?;
        // count < 2³² (it is at most the range), max_channel < 2⁶⁴: no overflow.
        let channel_bound = count as u128 * max_channel;
        if sum.iter().any(|&s| s > channel_bound)
            || sum_sq_lum > (count as u128).saturating_mul(max_lum_sq)
        {
            return Err(SliceError::PixelValues {
                index,
                count,
                channel: max_channel,
                lum_sq: max_lum_sq,
            });
        }
        px.push(PixelAccum {
            sum,
            sum_sq_lum,
            count,
        });
    }
    if r.pos != body.len() {
        return Err(SliceError::Trailing(body.len() - r.pos));
    }
    Ok(Slice {
        sample_begin: begin,
        sample_end: end,
        acc: Accumulation {
            x0,
            y0,
            width,
            height,
            pixels: px,
            rays,
            invalid_count,
            invalid,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn slice(invalid_count: u64, invalid: Vec<InvalidSample>) -> Slice {
        let mut acc = Accumulation::new(10, 20, 2, 1);
        acc.pixels[0].count = 3;
        acc.invalid_count = invalid_count;
        acc.invalid = invalid;
        Slice {
            sample_begin: 5,
            sample_end: 8,
            acc,
        }
    }

    #[test]
    fn invalid_counts_are_bounded_by_the_samples_covered() {
        let limits = SliceLimits::default();
        let one = InvalidSample {
            x: 11,
            y: 20,
            index: 7,
        };
        // 2 pixels × 3 samples: up to 6 invalid ones.
        let ok = slice(6, vec![one]);
        assert_eq!(decode_slice(&encode_slice(&ok), &limits), Ok(ok));
        assert_eq!(
            decode_slice(&encode_slice(&slice(7, vec![])), &limits),
            Err(SliceError::InvalidCount { count: 7, max: 6 })
        );
        // Near 2⁶⁴ the server's Σ counts + invalid count would overflow.
        assert_eq!(
            decode_slice(&encode_slice(&slice(u64::MAX, vec![])), &limits),
            Err(SliceError::InvalidCount {
                count: u64::MAX,
                max: 6
            })
        );
        assert_eq!(
            decode_slice(&encode_slice(&slice(0, vec![one])), &limits),
            Err(SliceError::RecordedCount {
                recorded: 1,
                count: 0
            })
        );
    }

    #[test]
    fn pixel_sums_are_bounded_by_what_their_samples_carry() {
        let limits = SliceLimits::default();
        let (channel, lum_sq) = max_sample_sums();
        // Components below 2³² in units of 2⁻³²: below 2⁶⁴; luminance² about 2⁹⁶.
        assert_eq!(channel, (1u128 << 64) - (1u128 << 40));
        assert!(lum_sq > 1u128 << 95 && lum_sq < 1u128 << 97, "{lum_sq}");
        // Pixel 0 holds 3 samples: 3 of the largest are accepted, one unit more is not.
        let mut most = slice(3, vec![]);
        most.acc.pixels[0].sum = [3 * channel; 3];
        most.acc.pixels[0].sum_sq_lum = 3 * lum_sq;
        assert_eq!(
            decode_slice(&encode_slice(&most), &limits),
            Ok(most.clone())
        );
        let lie = |f: &dyn Fn(&mut PixelAccum)| {
            let mut s = most.clone();
            f(&mut s.acc.pixels[0]);
            decode_slice(&encode_slice(&s), &limits)
        };
        for f in [
            &(|p: &mut PixelAccum| p.sum[1] += 1) as &dyn Fn(&mut PixelAccum),
            &|p| p.sum_sq_lum += 1,
            // The review's crafted pixel: one sample, a sum of u128::MAX.
            &|p| {
                p.count = 1;
                p.sum[0] = u128::MAX
            },
        ] {
            assert!(matches!(
                lie(f),
                Err(SliceError::PixelValues { index: 0, .. })
            ));
        }
        // No sample, no sum.
        let mut empty = slice(6, vec![]);
        empty.acc.pixels[0].count = 0;
        empty.acc.pixels[1].sum_sq_lum = 1;
        assert!(matches!(
            decode_slice(&encode_slice(&empty), &limits),
            Err(SliceError::PixelValues {
                index: 1,
                count: 0,
                ..
            })
        ));
    }

    #[test]
    fn the_header_reads_without_the_pixels() {
        let s = slice(0, vec![]);
        let bytes = encode_slice(&s);
        let header = SliceHeader {
            x0: 10,
            y0: 20,
            width: 2,
            height: 1,
            sample_begin: 5,
            sample_end: 8,
        };
        assert_eq!(decode_slice_header(&bytes), Ok(header));
        // Only the fixed part is read: a body cut after it still shows its header.
        assert_eq!(decode_slice_header(&bytes[..40]), Ok(header));
        assert_eq!(
            decode_slice_header(&bytes[..39]),
            Err(SliceError::Truncated("header"))
        );
        assert_eq!(decode_slice_header(b"PFSX"), Err(SliceError::Magic));
    }
}
