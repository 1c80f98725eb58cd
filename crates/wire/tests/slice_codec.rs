//! The slice body round-trips real renders bit for bit, is compact, and rejects every corruption
//! without panicking.

use glam::Vec3;
use pathfarm_tracer::camera::{Camera, Perspective, Projection};
use pathfarm_tracer::geometry::Mesh;
use pathfarm_tracer::material::Material;
use pathfarm_tracer::scene::SceneParts;
use pathfarm_tracer::{render_tile, RenderSettings, Scene, Tile};
use pathfarm_wire::{
    decode_slice, encode_slice, slice_checksum, Slice, SliceError, SliceLimits, SLICE_VERSION,
    SLICE_VERSION_FNV,
};

fn scene() -> Scene {
    // A single emissive, reflective quad in front of the camera.
    let mut mesh = Mesh::default();
    let (a, b, c, d) = (
        Vec3::new(-1., -1., -2.),
        Vec3::new(1., -1., -2.),
        Vec3::new(1., 1., -2.),
        Vec3::new(-1., 1., -2.),
    );
    mesh.positions = vec![[a, b, c], [a, c, d]];
    mesh.material = vec![0, 0];
    let material = Material {
        emissive: Vec3::new(1.0, 0.5, 0.25),
        metallic: 0.0,
        ..Material::default()
    };
    Scene::build(SceneParts {
        mesh,
        materials: vec![material],
        camera: Some(Camera::new(
            Projection::Perspective(Perspective::new(1.0)),
            glam::Affine3A::IDENTITY,
        )),
        ..SceneParts::default()
    })
    .expect("builds")
}

fn sample_slice() -> Slice {
    let settings = RenderSettings::new(64, 48);
    let tile = Tile {
        x0: 8,
        y0: 16,
        width: 24,
        height: 20,
    };
    Slice {
        sample_begin: 4,
        sample_end: 12,
        acc: render_tile(&scene(), &settings, tile, 4..12),
    }
}

#[test]
fn round_trips_a_render_bit_for_bit_and_is_compact() {
    let slice = sample_slice();
    let bytes = encode_slice(&slice);
    let back = decode_slice(&bytes, &SliceLimits::default()).expect("decodes");
    assert_eq!(back, slice);
    let raw = slice.acc.pixels.len() * 72;
    eprintln!(
        "{} pixels: {} bytes encoded, {} in memory",
        slice.acc.pixels.len(),
        bytes.len(),
        raw
    );
    assert!(
        bytes.len() * 2 < raw,
        "encoding should at least halve the size"
    );
    // Deterministic: the same accumulation always gives the same bytes.
    assert_eq!(encode_slice(&back), bytes);
}

#[test]
fn rejects_corruption_truncation_and_lies() {
    let slice = sample_slice();
    let bytes = encode_slice(&slice);
    let limits = SliceLimits::default();
    assert_eq!(decode_slice(b"nope", &limits), Err(SliceError::Magic));
    let mut v9 = bytes.clone();
    v9[4] = 9;
    assert_eq!(decode_slice(&v9, &limits), Err(SliceError::Version(9)));
    // Every single-bit flip in the body is caught (by the checksum or a structural check).
    for i in 8..bytes.len() {
        let mut b = bytes.clone();
        b[i] ^= 0x10;
        assert!(
            decode_slice(&b, &limits).is_err(),
            "flip at byte {i} accepted"
        );
    }
    // Every truncation is an error.
    for n in 0..bytes.len() {
        assert!(
            decode_slice(&bytes[..n], &limits).is_err(),
            "truncation to {n} accepted"
        );
    }
    // A tile over the limit is refused before any allocation.
    let small = SliceLimits { max_pixels: 100 };
    assert!(matches!(
        decode_slice(&bytes, &small),
        Err(SliceError::TileSize { .. })
    ));
}

#[test]
fn rejects_semantic_lies_with_a_valid_checksum() {
    let mut slice = sample_slice();
    slice.acc.pixels[3].count = 9; // more samples than the range [4, 12) holds
    let bytes = encode_slice(&slice);
    assert!(matches!(
        decode_slice(&bytes, &SliceLimits::default()),
        Err(SliceError::PixelCount {
            index: 3,
            count: 9,
            range: 8
        })
    ));
    let mut slice = sample_slice();
    slice.sample_end = slice.sample_begin;
    assert!(matches!(
        decode_slice(&encode_slice(&slice), &SliceLimits::default()),
        Err(SliceError::SampleRange { .. })
    ));
}

#[test]
fn the_largest_valid_samples_decode_and_larger_sums_do_not() {
    // The decoder's bound is what the tracer's accumulation adds for its largest valid sample.
    let largest = f32::from_bits(pathfarm_tracer::accumulation::MAX_SAMPLE_VALUE.to_bits() - 1);
    let mut p = pathfarm_tracer::PixelAccum::default();
    for _ in 0..8 {
        assert!(p.add_sample(Vec3::splat(largest)));
    }
    let (channel, lum_sq) = pathfarm_wire::max_sample_sums();
    assert_eq!(p.sum, [8 * channel; 3]);
    assert_eq!(p.sum_sq_lum, 8 * lum_sq);
    let mut slice = sample_slice(); // range [4, 12): 8 samples a pixel
    slice.acc.pixels[0] = p;
    let bytes = encode_slice(&slice);
    assert_eq!(
        decode_slice(&bytes, &SliceLimits::default()),
        Ok(slice.clone())
    );
    slice.acc.pixels[0].sum[2] += 1;
    assert!(matches!(
        decode_slice(&encode_slice(&slice), &SliceLimits::default()),
        Err(SliceError::PixelValues {
            index: 0,
            count: 8,
            ..
        })
    ));
}

#[test]
fn random_garbage_never_panics() {
    let bytes = encode_slice(&sample_slice());
    let mut s = 0x1234_5678u64;
    for _ in 0..20_000 {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        let mut b = bytes.clone();
        let n = (s % 8) as usize + 1;
        for k in 0..n {
            let i = ((s >> (8 * k)) as usize) % b.len();
            b[i] = (s >> (3 * k)) as u8;
        }
        let cut = (s >> 40) as usize % (b.len() + 1);
        let _ = decode_slice(&b[..cut], &SliceLimits::default());
        // Again with a valid checksum, so the structural checks behind it are exercised too.
        if b.len() > 8 {
            let body = b.len() - 8;
            let version = u16::from_le_bytes([b[4], b[5]]);
            let sum = slice_checksum(version, &b[..body]);
            b[body..].copy_from_slice(&sum.to_le_bytes());
            let _ = decode_slice(&b, &SliceLimits::default());
        }
    }
}

#[test]
fn version_1_bodies_are_still_read_with_their_own_checksum() {
    // What older workers upload and older servers stored: the same layout, version 1, FNV-1a 64.
    let slice = sample_slice();
    let current = encode_slice(&slice);
    assert_eq!(current[4..6], SLICE_VERSION.to_le_bytes());
    let body = current.len() - 8;
    let mut old = current.clone();
    old[4..6].copy_from_slice(&SLICE_VERSION_FNV.to_le_bytes());
    let fnv = slice_checksum(SLICE_VERSION_FNV, &old[..body]);
    old[body..].copy_from_slice(&fnv.to_le_bytes());
    assert_eq!(
        decode_slice(&old, &SliceLimits::default()),
        Ok(slice.clone())
    );
    // Each version's checksum is its own: a version 2 body with a version 1 checksum (or the
    // other way round) is corrupt.
    let mut mixed = current.clone();
    mixed[body..].copy_from_slice(&fnv.to_le_bytes());
    assert_eq!(
        decode_slice(&mixed, &SliceLimits::default()),
        Err(SliceError::Checksum)
    );
    let mut mixed = old.clone();
    mixed[body..].copy_from_slice(&current[body..]);
    assert_eq!(
        decode_slice(&mixed, &SliceLimits::default()),
        Err(SliceError::Checksum)
    );
    // Version 2's checksum is CRC-32 (IEEE) of the bytes before it, as gzip and PNG compute it:
    // the check value of the standard's test string.
    assert_eq!(slice_checksum(SLICE_VERSION, b"123456789"), 0xCBF4_3926);
    // A version this build does not know is refused as such.
    let mut future = current;
    future[4..6].copy_from_slice(&3u16.to_le_bytes());
    assert_eq!(
        decode_slice(&future, &SliceLimits::default()),
        Err(SliceError::Version(3))
    );
}

#[test]
fn the_largest_honest_slice_fits_its_bound() {
    // Every pixel at the largest sums its 8 samples can carry, the most recorded invalid samples
    // and the largest counters: the body a server must accept for this tile and sample count.
    let largest = f32::from_bits(pathfarm_tracer::accumulation::MAX_SAMPLE_VALUE.to_bits() - 1);
    let mut p = pathfarm_tracer::PixelAccum::default();
    for _ in 0..8 {
        assert!(p.add_sample(Vec3::splat(largest)));
    }
    let mut slice = sample_slice(); // range [4, 12): 8 samples a pixel
    for pixel in &mut slice.acc.pixels {
        *pixel = p;
    }
    slice.acc.rays = u64::MAX;
    slice.acc.invalid_count = u64::MAX;
    slice.acc.invalid = (0..pathfarm_tracer::accumulation::MAX_RECORDED_INVALID as u32)
        .map(|i| pathfarm_tracer::accumulation::InvalidSample {
            x: u32::MAX - i,
            y: u32::MAX,
            index: u32::MAX,
        })
        .collect();
    let pixels = slice.acc.pixels.len() as u64;
    let bytes = encode_slice(&slice).len() as u64;
    let bound = pathfarm_wire::max_slice_body_bytes(pixels, 8);
    assert!(bytes <= bound, "{bytes} bytes over the bound {bound}");
    // The bound is the encoding's own size, not a loose multiple of it.
    assert!(bound - bytes < 64, "{bytes} bytes, bound {bound}");
    // More samples a pixel can only need more room.
    assert!(pathfarm_wire::max_slice_body_bytes(pixels, 1 << 20) > bound);
}
