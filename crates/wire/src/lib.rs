//! # pathfarm-wire
//!
//! The contract between pathfarm's server, its workers and its command-line client (`openapi.yaml`
//! describes it for everyone else): the JSON control messages in [`api`], and the binary body that
//! carries an [`Accumulation`](pathfarm_tracer::Accumulation) (a *slice*: one tile × one sample
//! range) in [`slice`].

pub mod api;
pub mod environment;
pub mod frames;
#[doc(hidden)]
pub mod fuzzing; // the checks of the fuzz targets (fuzz/), shared with tests/fuzz_corpus.rs
pub mod slice;
mod varint;

pub use environment::{
    build_environment, is_sha256_hex, EnvironmentSettingsError, EnvironmentSource,
};
pub use slice::{
    decode_slice, decode_slice_header, encode_slice, max_sample_sums, max_slice_body_bytes,
    slice_checksum, Slice, SliceError, SliceHeader, SliceLimits, SLICE_MAGIC, SLICE_VERSION,
    SLICE_VERSION_FNV,
};
