//! The check behind the cargo-fuzz target `slice_decode` in `fuzz/` (see `docs/fuzzing.md`), here so
//! that the fuzz target and the stable replay test (`tests/fuzz_corpus.rs`) run exactly the same code.
//! Not part of the crate's API: hidden from the docs and free to change.

use crate::{decode_slice, encode_slice, Slice, SliceLimits};
use pathfarm_tracer::Accumulation;

/// The server's limit on an upload's tile (`Limits::default().max_pixels` in `pathfarm-server`).
const SERVER_MAX_PIXELS: u64 = 8192 * 8192;

/// Fuzz target `slice_decode`: `bytes` as an uploaded slice body. Decoding must never panic, on the
/// bytes as given and on the bytes with their trailing checksum recomputed (random bytes almost never
/// carry a valid checksum, so without that second pass the fuzzer would hardly get past it).
/// See [`check_decoded`] for what a body that decodes must satisfy.
pub fn slice_decode(bytes: &[u8]) {
    check_decoded(bytes);
    if bytes.len() >= 8 {
        let mut fixed = bytes.to_vec();
        let body_len = fixed.len() - 8;
        let version = u16::from_le_bytes([fixed[4], fixed[5]]);
        let sum = crate::slice_checksum(version, &fixed[..body_len]);
        fixed[body_len..].copy_from_slice(&sum.to_le_bytes());
        if fixed != bytes {
            check_decoded(&fixed);
        }
    }
}

/// Decodes `bytes` with the server's limits; if they decode:
/// - the encoding is canonical: encoding the slice gives back exactly `bytes` (the format promises
///   that a body's bytes are a function of its contents), and that decodes to an equal slice;
/// - the server's accounting of the slice's samples does not overflow;
/// - the server's merge path works: the slice merges into an empty accumulation of its tile, and
///   the result, stored as the tile's accumulation over samples `[0, end)` (what the tile holds once
///   every slice up to this one has been merged, in order), decodes again without the upload limit,
///   as the server reads stored tiles back.
fn check_decoded(bytes: &[u8]) {
    let limits = SliceLimits {
        max_pixels: SERVER_MAX_PIXELS,
    };
    let Ok(slice) = decode_slice(bytes, &limits) else {
        return;
    };
    let encoded = encode_slice(&slice);
    // A body of the older version re-encodes in this one: the same bytes but the version and the
    // checksum.
    let older = bytes[4..6] == crate::SLICE_VERSION_FNV.to_le_bytes();
    let n = bytes.len() - 8;
    assert!(
        if older {
            encoded[..4] == bytes[..4]
                && encoded[6..n] == bytes[6..n]
                && encoded.len() == bytes.len()
        } else {
            encoded == bytes
        },
        "a decodable body does not re-encode to the same bytes"
    );
    let again = decode_slice(&encoded, &limits).expect("a re-encoded slice decodes");
    assert_eq!(again, slice, "re-encoding changed the slice");

    let a = &slice.acc;
    // The server's accounting check (`merge_slice` in crates/server/src/store/tasks.rs), with the
    // same plain arithmetic: it must not overflow for any slice the decoder accepts.
    let counted: u64 = a.pixels.iter().map(|p| p.count).sum::<u64>() + a.invalid_count;
    let expected = (slice.sample_end - slice.sample_begin) as u64 * a.pixels.len() as u64;
    std::hint::black_box(counted == expected);

    let mut tile = Accumulation::new(a.x0, a.y0, a.width, a.height);
    tile.merge(a).expect("a slice merges into its own tile");
    let stored = encode_slice(&Slice {
        sample_begin: 0,
        sample_end: slice.sample_end,
        acc: tile,
    });
    let unlimited = SliceLimits {
        max_pixels: u64::MAX,
    };
    decode_slice(&stored, &unlimited).expect("the stored tile accumulation decodes");
}
