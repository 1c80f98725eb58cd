//! The one error type of the bench crate.

use std::path::PathBuf;

/// Everything that can stop a benchmark run. Each variant says what failed and where.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("scene {name:?}: {message}")]
    Scene { name: String, message: String },
    #[error("unknown bench scene {0:?} (see `pathfarm bench --help` for the list)")]
    UnknownScene(String),
    #[error("chart {path}: {message}")]
    Chart { path: PathBuf, message: String },
    #[error("image {path}: {message}")]
    Image { path: PathBuf, message: String },
    #[error("reference cache {path}: {message}")]
    Cache { path: PathBuf, message: String },
    #[error("farm benchmark: {0}")]
    Farm(String),
    #[error("{0}")]
    Invalid(String),
}

impl BenchError {
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> BenchError {
        BenchError::Io {
            path: path.into(),
            source,
        }
    }
}

/// A farm measurement's failure (`up`, `frames`, and the test kit's farm benchmarks).
pub fn farm_err(what: impl std::fmt::Display) -> BenchError {
    BenchError::Farm(what.to_string())
}

/// Writes `bytes` to `path`, creating its parent directory.
pub fn write_file(path: &std::path::Path, bytes: &[u8]) -> Result<(), BenchError> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| BenchError::io(dir, e))?;
    }
    std::fs::write(path, bytes).map_err(|e| BenchError::io(path, e))
}
