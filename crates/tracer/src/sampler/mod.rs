//! Sample generators. A sample value is a pure function of
//! `(seed, pixel, sample index, dimension)`: no state carries from one sample to the next, which is what
//! makes tiles and sample ranges render the same bits wherever and whenever they are rendered.
//!
//! The closed set of generators is [`SamplerKind`]; each lives in its own file. Dimensions are consumed
//! in a fixed layout ([`dims`]), so the same dimension always means the same decision.

mod hash;
mod independent;
mod sobol;

pub use hash::{hash_u32, hash_words};
pub use independent::independent_sample;
pub(crate) use sobol::owen_sobol_group_lanewise;
pub use sobol::{owen_sobol_pair, owen_sobol_sample, SobolPixel};

use crate::settings::SamplerKind;
use glam::Vec2;

/// The fixed assignment of sample dimensions to decisions. Dimensions come in groups of four because
/// the Sobol generator is 4-dimensional per padded group; the best-stratified pair (0,1) of each group
/// goes to the 2-D decision that matters most.
pub mod dims {
    /// Pixel-plane position (box filter), dimensions 0 and 1.
    pub const PIXEL: u32 = 0;
    /// First dimension of bounce 0; each bounce uses [`PER_BOUNCE`] dimensions.
    pub const BOUNCE_BASE: u32 = 4;
    pub const PER_BOUNCE: u32 = 12;
    /// Offsets within a bounce.
    pub const LIGHT_POINT: u32 = 0; // 2 dims: point on the chosen area light
    pub const LIGHT_SELECT: u32 = 2; // 1 dim: which area light
    pub const PUNCTUAL_SELECT: u32 = 3; // 1 dim: which punctual light
    pub const BSDF_DIR: u32 = 4; // 2 dims: BSDF-sampled continuation direction
    pub const BSDF_LOBE: u32 = 6; // 1 dim: BSDF lobe choice
    pub const ROULETTE: u32 = 7; // 1 dim: Russian roulette
    pub const DIRECT_DIR: u32 = 8; // 2 dims: hemisphere/cosine direct-lighting direction
    pub const ALPHA: u32 = 10; // 1 dim: stochastic alpha coverage
    pub const DIRECT_SIDE: u32 = 11; // 1 dim: which side of a transmissive surface to sample
}

/// Generates the sample values of one (pixel, sample index) pair.
#[derive(Clone, Copy, Debug)]
pub struct PixelSampler {
    kind: SamplerKind,
    /// Hash of (seed, pixel): every dimension group derives its scramble from it.
    pixel_key: u32,
    index: u32,
    /// `index` bit-reversed, computed once (the Sobol generator works on reversed indices).
    index_rev: u32,
    /// The pixel's Sobol scramble seeds (unused by the independent sampler).
    sobol: SobolPixel,
}

impl PixelSampler {
    #[inline]
    pub fn new(kind: SamplerKind, seed: u64, px: u32, py: u32, index: u32) -> Self {
        let pixel_key = hash_words(&[seed as u32, (seed >> 32) as u32, px, py]);
        PixelSampler {
            kind,
            pixel_key,
            index,
            index_rev: index.reverse_bits(),
            // The independent sampler never reads the Sobol seeds: not worth 80 hashes a pixel.
            sobol: match kind {
                SamplerKind::Sobol => SobolPixel::new(pixel_key),
                SamplerKind::Independent => SobolPixel::UNUSED,
            },
        }
    }

    /// The sampler of sample `index` of the same pixel (the pixel's seeds are not recomputed).
    #[inline]
    pub fn with_index(&self, index: u32) -> Self {
        let mut s = *self;
        s.set_index(index);
        s
    }

    /// Moves this sampler to sample `index` of the same pixel, in place.
    #[inline]
    pub fn set_index(&mut self, index: u32) {
        self.index = index;
        self.index_rev = index.reverse_bits();
    }

    /// The value of dimension `dim`, in [0, 1).
    #[inline]
    pub fn get1(&self, dim: u32) -> f32 {
        match self.kind {
            SamplerKind::Sobol => self.sobol.sample(self.index_rev, dim),
            SamplerKind::Independent => independent_sample(self.pixel_key, self.index, dim),
        }
    }

    #[inline(always)]
    pub fn get2(&self, dim: u32) -> Vec2 {
        match self.kind {
            SamplerKind::Sobol => {
                let (a, b) = self.sobol.pair(self.index_rev, dim);
                Vec2::new(a, b)
            }
            SamplerKind::Independent => Vec2::new(self.get1(dim), self.get1(dim + 1)),
        }
    }

    /// Dimension `offset` of bounce `bounce` (see [`dims`]).
    #[inline]
    pub fn bounce1(&self, bounce: u32, offset: u32) -> f32 {
        self.get1(bounce_dim(bounce, offset))
    }

    #[inline]
    pub fn bounce2(&self, bounce: u32, offset: u32) -> Vec2 {
        self.get2(bounce_dim(bounce, offset))
    }
}

/// The dimension of offset `offset` within bounce `bounce` (see [`dims`]).
#[inline(always)]
pub(crate) fn bounce_dim(bounce: u32, offset: u32) -> u32 {
    dims::BOUNCE_BASE
        .wrapping_add(bounce.wrapping_mul(dims::PER_BOUNCE))
        .wrapping_add(offset)
}

/// Converts 32 random bits to a float in [0, 1) (the top 24 bits, so every value is exact).
#[inline]
pub fn bits_to_unit(x: u32) -> f32 {
    (x >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pixels_sampler_moved_to_another_index_is_that_index_sampler() {
        for kind in [SamplerKind::Sobol, SamplerKind::Independent] {
            let pixel = PixelSampler::new(kind, 0x1234_5678_9abc, 17, 3, 0);
            for index in [0u32, 1, 7, 1000, u32::MAX] {
                let fresh = PixelSampler::new(kind, 0x1234_5678_9abc, 17, 3, index);
                let moved = pixel.with_index(index);
                for dim in 0..64 {
                    assert_eq!(moved.get1(dim).to_bits(), fresh.get1(dim).to_bits());
                }
                assert_ne!(
                    moved.get2(4),
                    pixel.with_index(index ^ 1).get2(4),
                    "the index matters"
                );
            }
        }
    }
}
