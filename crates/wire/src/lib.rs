//! # pathfarm-wire
//!
//! Formats that cross the network between pathfarm's server and its workers. This first part holds
//! the binary body that carries an [`Accumulation`] (a *slice*: one tile × one sample range), see
//! [`slice`]. JSON control messages will join it here, so that server and worker share one contract.

pub mod slice;
mod varint;

pub use slice::{
    decode_slice, encode_slice, Slice, SliceError, SliceLimits, SLICE_MAGIC, SLICE_VERSION,
};
