//! # pathfarm-tracer
//!
//! The Monte Carlo path tracer every pathfarm worker runs. It turns a glTF 2.0 scene (given as bytes)
//! and render settings into an [`Accumulation`]: exact, integer, per-pixel sums that can be added in any
//! order and any grouping with bit-identical results.
//!
//! Invariants (see `ARCHITECTURE.md`):
//! - no I/O besides decoding the bytes it is handed (external glTF URIs go through a caller-supplied
//!   [`gltf::ResourceResolver`]); no async, no clock;
//! - every random number is a pure function of (seed, pixel, sample index, dimension), so a tile and a
//!   sample range render the same bits wherever and whenever they are rendered.

pub mod accumulation;
pub mod bsdf;
pub mod camera;
#[doc(hidden)]
pub mod fuzzing; // the checks of the fuzz targets (fuzz/), shared with tests/fuzz_corpus.rs
pub mod geometry;
pub mod gltf;
pub mod guide;
pub mod integrator;
mod isa;
pub mod light;
pub mod material;
pub mod math;
pub mod output;
pub mod render;
pub mod sampler;
pub mod sampling;
pub mod scene;
pub mod settings;
pub mod stats;
#[cfg(test)]
mod testing;

pub use accumulation::{Accumulation, PixelAccum};
pub use render::{render_image, render_sample, render_samples, render_tile, Tile};
pub use scene::Scene;
pub use settings::{DirectStrategy, RenderSettings, RussianRoulette, SamplerKind};
