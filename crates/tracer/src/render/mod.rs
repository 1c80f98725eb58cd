//! The render API.
