//! Reads the files a `.gltf` refers to, next to the scene file. This is the only place scene I/O
//! happens; the tracer itself only sees bytes.

use pathfarm_tracer::gltf::ResourceResolver;
use std::path::PathBuf;

/// Resolves relative URIs against the scene file's directory.
pub struct DirectoryResolver {
    pub base: PathBuf,
}

impl ResourceResolver for DirectoryResolver {
    /// `uri` arrives percent-decoded by the tracer (the one place glTF URIs are decoded), so it is
    /// the file's name as it is: not decoded again here (a file named `a%20b.bin` is `a%20b.bin`).
    fn resolve(&self, uri: &str) -> Result<Vec<u8>, String> {
        if uri.contains("://") {
            return Err(format!("only relative file URIs are read, not {uri:?}"));
        }
        let path = self.base.join(uri);
        std::fs::read(&path).map_err(|e| format!("cannot read {}: {e}", path.display()))
    }
}
