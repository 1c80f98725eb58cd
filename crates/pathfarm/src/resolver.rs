//! Reads the files a `.gltf` refers to, next to the scene file. This is the only place scene I/O
//! happens; the tracer itself only sees bytes.

use pathfarm_tracer::gltf::ResourceResolver;
use std::path::PathBuf;

/// Resolves relative URIs against the scene file's directory.
pub struct DirectoryResolver {
    pub base: PathBuf,
}

impl ResourceResolver for DirectoryResolver {
    fn resolve(&self, uri: &str) -> Result<Vec<u8>, String> {
        if uri.contains("://") {
            return Err(format!("only relative file URIs are read, not {uri:?}"));
        }
        let decoded = percent_decode(uri);
        let path = self.base.join(&decoded);
        std::fs::read(&path).map_err(|e| format!("cannot read {}: {e}", path.display()))
    }
}

/// Decodes %XX escapes (glTF URIs are URI-encoded, e.g. spaces as %20).
fn percent_decode(s: &str) -> String {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' && i + 2 < bytes.len() {
            let hex = std::str::from_utf8(&bytes[i + 1..i + 3]).ok();
            if let Some(v) = hex.and_then(|h| u8::from_str_radix(h, 16).ok()) {
                out.push(v);
                i += 3;
                continue;
            }
        }
        out.push(bytes[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

#[cfg(test)]
mod tests {
    #[test]
    fn percent_decoding() {
        assert_eq!(super::percent_decode("a%20b.bin"), "a b.bin");
        assert_eq!(super::percent_decode("100%"), "100%");
        assert_eq!(super::percent_decode("x%zz"), "x%zz");
    }
}
