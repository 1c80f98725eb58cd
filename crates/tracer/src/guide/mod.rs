//! Caustic guiding: where light reaches a diffuse surface only through mirrors or smooth glass
//! (light → specular → … → diffuse), next-event estimation cannot find it and cosine sampling
//! finds it rarely, each find a bright single sample (the fireflies of a caustic). The guide
//! learns, once per scene, from which directions such light arrives where: photons are shot from
//! the emissive triangles at the specular objects (`photons.rs`, aimed at them by `casters.rs`;
//! lamps shoot none, as no path can meet a point or a direction), followed through their
//! specular bounces, and binned where they land, by grid cell and by direction.
//!
//! At a path vertex in a cell the photons reached, the continuation direction is drawn from the
//! mixture `α · guide + (1 − α) · BSDF` and weighted by `f · |cos| / p_mix` (one-sample MIS over the
//! two techniques, the mixture's density everywhere: unbiased whatever the guide holds, since the
//! BSDF's share covers every direction the BSDF does). The mixture's density is also what the
//! light sample's and the emission's MIS weights take as the BSDF strategy's (`GuideCell::mix_pdf`).
//!
//! The guide is a pure function of the scene (its photons' random numbers are a counter hash of
//! the photon's index, their sums made in a fixed order), so every worker that builds it builds
//! the same bits, and every tile renders as it would anywhere. Scenes without specular objects
//! or without emissive triangles that reach them have no guide, and render as they always did.

mod casters;
mod photons;
#[cfg(test)]
mod tests;

use crate::bsdf::{Bsdf, BsdfSample};
use crate::scene::Scene;
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// Direction bins: equal-area bands of cos θ (world z) by equal slices of φ.
const BANDS: usize = 16;
const SLICES: usize = 32;
const BINS: usize = BANDS * SLICES;
/// The solid angle of one bin.
const BIN_SOLID_ANGLE: f32 = 4.0 * PI / BINS as f32;
/// The guide's share of the continuation samples where a cell has a guide. On the peers' caustics
/// scene 0.3 and 0.5 measured the same error (docs/benchmarks.md); the smaller share costs less
/// where a cell's light is mostly not caustic.
pub(crate) const MIX: f32 = 0.3;
/// Cells with fewer photons than this have no guide (their directions would be mostly noise).
const MIN_PHOTONS: u32 = 16;

/// The learned directions of caustic light, per grid cell.
#[derive(Clone, Debug, PartialEq)]
pub struct CausticGuide {
    lo: Vec3,
    inv_cell: f32,
    dims: [u32; 3],
    /// Cells with a guide, sorted by key.
    keys: Vec<u64>,
    /// Per grid cell (by key), its index in `keys`, or `u32::MAX` where it has no guide: a path
    /// vertex finds its cell in one load instead of a search.
    index: Vec<u32>,
    /// Per cell (same order as `keys`), the range of its bins in `bins`.
    ranges: Vec<(u32, u32)>,
    /// Per cell (same order), which bins it has.
    occupancy: Vec<Occupancy>,
    /// (bin, cumulative probability up to and including this bin), by bin within each cell.
    bins: Vec<(u16, f32)>,
    /// Photons traced and landed, for the log.
    pub photons: u32,
    pub landed: u32,
}

/// The guide at one point: its cell's directions.
#[derive(Clone, Copy, Debug)]
pub struct GuideCell<'a> {
    bins: &'a [(u16, f32)],
    occupied: &'a Occupancy,
}

/// Which of the [`BINS`] bins a cell has, as a bit set with each word's count of the bits
/// before it: a bin's place among the cell's bins in one count instead of a search (the
/// density is read twice per guided vertex).
#[derive(Clone, Debug, PartialEq)]
struct Occupancy {
    words: [u64; BINS / 64],
    before: [u16; BINS / 64],
}

impl Occupancy {
    /// The bit set of `bins` (sorted by bin, each bin once).
    fn of(bins: &[(u16, f32)]) -> Occupancy {
        let mut words = [0u64; BINS / 64];
        for &(bin, _) in bins {
            words[usize::from(bin) / 64] |= 1 << (bin % 64);
        }
        let mut before = [0u16; BINS / 64];
        for k in 1..words.len() {
            before[k] = before[k - 1] + words[k - 1].count_ones() as u16;
        }
        Occupancy { words, before }
    }

    /// The index of `bin` among the cell's bins, if it has it.
    #[inline]
    fn rank(&self, bin: usize) -> Option<usize> {
        let (word, bit) = (self.words[bin / 64], bin % 64);
        if word >> bit & 1 == 0 {
            return None;
        }
        let below = word & ((1u64 << bit) - 1);
        Some(usize::from(self.before[bin / 64]) + below.count_ones() as usize)
    }
}

impl CausticGuide {
    /// The guide of `scene`, or None where no photon reaches a diffuse surface through a
    /// specular one (no specular object, no light, or none lit).
    pub fn build(scene: &Scene) -> Option<CausticGuide> {
        photons::trace(scene)
    }

    /// The guide at `p`, if its cell has one.
    #[inline]
    pub fn cell(&self, p: Vec3) -> Option<GuideCell<'_>> {
        let key = self.key(p)?;
        let i = *self.index.get(key as usize)?;
        let (start, end) = *self.ranges.get(i as usize)?;
        Some(GuideCell {
            bins: &self.bins[start as usize..end as usize],
            occupied: self.occupancy.get(i as usize)?,
        })
    }

    /// Cells that have a guide.
    pub fn cells(&self) -> usize {
        self.keys.len()
    }

    /// Bytes the guide holds.
    pub fn bytes(&self) -> usize {
        self.keys.len() * 8
            + self.index.len() * 4
            + self.ranges.len() * 8
            + self.occupancy.len() * std::mem::size_of::<Occupancy>()
            + self.bins.len() * 8
    }

    #[inline]
    fn key(&self, p: Vec3) -> Option<u64> {
        let c = (p - self.lo) * self.inv_cell;
        if !(c.x >= 0.0 && c.y >= 0.0 && c.z >= 0.0) {
            return None;
        }
        let [x, y, z] = [c.x as u32, c.y as u32, c.z as u32];
        let [nx, ny, nz] = self.dims;
        (x < nx && y < ny && z < nz)
            .then(|| u64::from(x) + u64::from(nx) * (u64::from(y) + u64::from(ny) * u64::from(z)))
    }
}

/// The bin of direction `w` (unit).
#[inline]
fn bin_of(w: Vec3) -> usize {
    let band = (((w.z + 1.0) * 0.5 * BANDS as f32) as usize).min(BANDS - 1);
    band * SLICES + slice_of(w.x, w.y)
}

/// tan(k · π/16) for k = 1, 2, 3: the slices' edges within an octant.
const SLICE_EDGES: [f32; 3] = [0.198_912_37, 0.414_213_57, 0.668_178_6];
const _: () = assert!(SLICES == 32, "slice_of counts four slices per octant");

/// The slice of azimuth φ = atan2(y, x) ∈ (−π, π], ⌊(φ + π) / (2π) · 32⌋, found by comparisons
/// with the slices' edges instead of an arctangent (on the sample path, twice per guided vertex):
/// the same bits on every machine, as only products and comparisons decide it.
#[inline]
fn slice_of(x: f32, y: f32) -> usize {
    let (ax, ay) = (x.abs(), y.abs());
    // ⌊α / (π/16)⌋ of the angle α ∈ [0, π/2] of (|x|, |y|): 0–3 below the diagonal, 4–7 above.
    let below = |a: f32, b: f32| SLICE_EDGES.iter().filter(|&&t| a >= b * t).count();
    let k = match ay <= ax {
        true => below(ay, ax),
        false => 7 - below(ax, ay),
    };
    // φ = α, π − α, −α or −π + α by quadrant; ⌊φ / (π/16)⌋ + 16 of each.
    match (x < 0.0, y < 0.0) {
        (false, false) => 16 + k,
        (true, false) => 31 - k,
        (false, true) => 15 - k,
        (true, true) => k,
    }
}

/// A direction uniform within bin `bin`, from `u` in [0, 1)².
#[inline]
fn direction_in(bin: usize, u: Vec2) -> Vec3 {
    let (band, slice) = (bin / SLICES, bin % SLICES);
    let z = -1.0 + 2.0 * (band as f32 + u.x) / BANDS as f32;
    // φ in turns, −½ to ½ (−π to π).
    let turns = (slice as f32 + u.y) / SLICES as f32 - 0.5;
    let (sin, cos) = crate::math::det::sin_cos_turns(turns);
    let r = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new(r * cos, r * sin, z.clamp(-1.0, 1.0))
}

impl GuideCell<'_> {
    /// The guide's density (solid angle) of `w`.
    #[inline]
    pub fn pdf(&self, w: Vec3) -> f32 {
        let Some(i) = self.occupied.rank(bin_of(w)) else {
            return 0.0;
        };
        let below = if i == 0 { 0.0 } else { self.bins[i - 1].1 };
        (self.bins[i].1 - below) / BIN_SOLID_ANGLE
    }

    /// A direction drawn from the guide: a bin by `u_bin`, a point in it by `u`.
    #[inline]
    fn sample(&self, u_bin: f32, u: Vec2) -> Vec3 {
        let i = self
            .bins
            .partition_point(|&(_, cdf)| cdf <= u_bin)
            .min(self.bins.len() - 1);
        direction_in(usize::from(self.bins[i].0), u)
    }

    /// The mixture's density of `w`, where the BSDF's (non-delta) density is `bsdf_pdf`.
    #[inline]
    pub fn mix_pdf(&self, bsdf_pdf: f32, w: Vec3) -> f32 {
        mix_densities(self.pdf(w), bsdf_pdf)
    }

    /// The continuation from the mixture (see the module documentation): `u_mix` chooses the
    /// guide (below `α`) or the BSDF, and, rescaled, the guide's bin or the BSDF's lobe; `u` the
    /// direction. The sample's `pdf` is the mixture's density (a delta lobe's: its probability
    /// of being chosen, the mixture's share included), its `weight` f · |cos| / pdf.
    #[inline]
    pub fn sample_mixture(
        &self,
        bsdf: &Bsdf,
        wo: Vec3,
        ng: Vec3,
        u_mix: f32,
        u: Vec2,
    ) -> Option<BsdfSample> {
        if u_mix < MIX {
            let wi = self.sample((u_mix / MIX).min(ONE_BELOW), u);
            let (f, bsdf_pdf) = bsdf.eval_pdf(wo, wi);
            let pdf = self.mix_pdf(bsdf_pdf, wi);
            if pdf.is_nan() || pdf <= 0.0 {
                return None;
            }
            // Through the surface: `wi` on the other side of the geometric normal from `wo`.
            let transmitted = wo.dot(ng) * wi.dot(ng) < 0.0;
            return Some(BsdfSample {
                wi,
                weight: f / pdf,
                pdf,
                delta: false,
                transmitted,
            });
        }
        let u_lobe = ((u_mix - MIX) / (1.0 - MIX)).min(ONE_BELOW);
        let bs = bsdf.sample(wo, u_lobe, u)?;
        if bs.delta {
            return Some(BsdfSample {
                weight: bs.weight / (1.0 - MIX),
                pdf: bs.pdf * (1.0 - MIX),
                ..bs
            });
        }
        // The BSDF's sample carries f · |cos| / p and its density p (the one `Bsdf::eval_pdf`
        // gives, which MIS relies on everywhere): no second evaluation.
        let pdf = self.mix_pdf(bs.pdf, bs.wi);
        if pdf.is_nan() || pdf <= 0.0 {
            return None;
        }
        Some(BsdfSample {
            weight: bs.weight * (bs.pdf / pdf),
            pdf,
            ..bs
        })
    }
}

/// The mixture's density where the guide's is `guide_pdf` and the BSDF's `bsdf_pdf` (one home for
/// the formula: the wavefront's lanes mix the densities they evaluate in their own loops).
#[inline(always)]
pub(crate) fn mix_densities(guide_pdf: f32, bsdf_pdf: f32) -> f32 {
    MIX * guide_pdf + (1.0 - MIX) * bsdf_pdf
}

/// The largest `f32` below 1.
const ONE_BELOW: f32 = 1.0 - f32::EPSILON / 2.0;
