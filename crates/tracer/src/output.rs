//! Image encoding.
