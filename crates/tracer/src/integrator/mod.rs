//! The path integrator.
