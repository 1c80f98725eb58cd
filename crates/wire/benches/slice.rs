//! Slice codec micro-benchmarks: what a server spends per merge on the tile it stores and on the
//! upload it merges.
//!
//! ```text
//! cargo bench -p pathfarm-wire --bench slice
//! ```
//!
//! One 64² tile holding 64 samples a pixel (about 100 KB encoded, the stored tile of a 512² job at
//! the default tile size): `encode` (this build's version), `decode` of this version and of
//! version 1 (what older workers upload and older servers stored), and each version's checksum
//! alone. Throughputs are in bytes of the encoded body.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use pathfarm_tracer::Accumulation;
use pathfarm_wire::{
    decode_slice, encode_slice, slice_checksum, Slice, SliceLimits, SLICE_VERSION,
    SLICE_VERSION_FNV,
};
use std::hint::black_box;

fn tile() -> Slice {
    let samples = 64u32;
    let mut acc = Accumulation::new(0, 0, 64, 64);
    for (i, p) in acc.pixels.iter_mut().enumerate() {
        // Radiance 0.3–1.1 in the sums' 2⁻³² fixed point, varied so the varints vary.
        let v = (0.3 + (i % 17) as f64 * 0.05) * 2f64.powi(32);
        p.count = u64::from(samples);
        p.sum = [(v * f64::from(samples)) as u128; 3];
        p.sum_sq_lum = (v * v / 2f64.powi(32) * f64::from(samples)) as u128;
    }
    Slice {
        sample_begin: 0,
        sample_end: samples,
        acc,
    }
}

fn codec(c: &mut Criterion) {
    let slice = tile();
    let current = encode_slice(&slice);
    let body = current.len() - 8;
    let mut older = current.clone();
    older[4..6].copy_from_slice(&SLICE_VERSION_FNV.to_le_bytes());
    let sum = slice_checksum(SLICE_VERSION_FNV, &older[..body]);
    older[body..].copy_from_slice(&sum.to_le_bytes());
    let limits = SliceLimits::default();

    let mut g = c.benchmark_group("slice_64x64_64spp");
    g.throughput(Throughput::Bytes(current.len() as u64));
    g.bench_function("encode", |b| b.iter(|| encode_slice(black_box(&slice))));
    g.bench_function("decode", |b| {
        b.iter(|| decode_slice(black_box(&current), &limits))
    });
    g.bench_function("decode_version_1", |b| {
        b.iter(|| decode_slice(black_box(&older), &limits))
    });
    g.bench_function("checksum", |b| {
        b.iter(|| slice_checksum(SLICE_VERSION, black_box(&current[..body])))
    });
    g.bench_function("checksum_version_1", |b| {
        b.iter(|| slice_checksum(SLICE_VERSION_FNV, black_box(&current[..body])))
    });
    g.finish();
}

criterion_group!(benches, codec);
criterion_main!(benches);
