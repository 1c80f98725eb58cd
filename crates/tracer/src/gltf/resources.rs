//! Where the bytes of buffers and images come from: the GLB BIN chunk, `data:` URIs (base64 or
//! percent-encoded) and external URIs through the caller's [`ResourceResolver`]. Each buffer is fetched
//! at most once, and only if something the scene uses reads it.
//!
//! Buffer views compressed with EXT_meshopt_compression (or KHR_meshopt_compression) are decoded here,
//! once each, from the buffer their extension names; their own (fallback) buffer is never read.

use super::error::{label, GltfError};
use super::meshopt;
use super::ResourceResolver;
use base64::Engine as _;
use gltf::json;
use std::borrow::Cow;
use std::cell::{Cell, OnceCell};

type Fetched<'a> = Result<Cow<'a, [u8]>, (String, String)>;

/// Most bytes that decompression (EXT_meshopt_compression buffer views, KHR_draco_mesh_compression
/// primitives) may produce in one load, each decode checked against what is left before it
/// allocates: 4 GiB, the order of the largest scene [`super::MAX_TRIANGLES`] allows.
pub const MAX_DECOMPRESSED_BYTES: u64 = 4 << 30;

/// Why a decompressed view is not available (kept to be reported again to later readers).
#[derive(Clone, Debug)]
enum Failed {
    Data { object: String, reason: String },
    Limit(String),
}

impl From<Failed> for GltfError {
    fn from(f: Failed) -> Self {
        match f {
            Failed::Data { object, reason } => GltfError::Data { object, reason },
            Failed::Limit(m) => GltfError::Limit(m),
        }
    }
}

/// Lazily fetched buffers of one document.
pub(crate) struct Resources<'a> {
    root: &'a json::Root,
    bin: Option<&'a [u8]>,
    resolver: &'a dyn ResourceResolver,
    buffers: Vec<OnceCell<Fetched<'a>>>,
    /// Bytes of the buffers fetched so far, and of the buffer views decompressed.
    fetched: Cell<u64>,
    /// Decompressed buffer views (empty when no view is compressed).
    decoded: Vec<OnceCell<Result<Vec<u8>, Failed>>>,
    /// Bytes decompressed so far (see [`MAX_DECOMPRESSED_BYTES`]).
    decompressed: Cell<u64>,
}

pub(crate) fn buffer_label(root: &json::Root, index: usize) -> String {
    label(
        "buffer",
        index,
        root.buffers.get(index).and_then(|b| b.name.as_deref()),
    )
}

pub(crate) fn view_label(root: &json::Root, index: usize) -> String {
    label(
        "bufferView",
        index,
        root.buffer_views.get(index).and_then(|v| v.name.as_deref()),
    )
}

pub(crate) fn image_label(root: &json::Root, index: usize) -> String {
    label(
        "image",
        index,
        root.images.get(index).and_then(|i| i.name.as_deref()),
    )
}

impl<'a> Resources<'a> {
    pub fn new(
        root: &'a json::Root,
        bin: Option<&'a [u8]>,
        resolver: &'a dyn ResourceResolver,
    ) -> Self {
        let buffers = (0..root.buffers.len()).map(|_| OnceCell::new()).collect();
        let any_compressed = root.buffer_views.iter().any(|v| {
            v.extensions.as_ref().is_some_and(|e| {
                meshopt::EXTENSIONS
                    .iter()
                    .any(|n| e.others.contains_key(*n))
            })
        });
        let decoded = if any_compressed {
            (0..root.buffer_views.len())
                .map(|_| OnceCell::new())
                .collect()
        } else {
            Vec::new()
        };
        Resources {
            root,
            bin,
            resolver,
            buffers,
            fetched: Cell::new(0),
            decoded,
            decompressed: Cell::new(0),
        }
    }

    /// Counts `bytes` of decompressed data against [`MAX_DECOMPRESSED_BYTES`], before they are
    /// allocated.
    pub fn charge_decompressed(&self, bytes: u64, object: &str) -> Result<(), GltfError> {
        self.charge(bytes, object).map_err(GltfError::Limit)
    }

    /// Bytes that may still be decompressed in this load.
    pub fn decompress_budget_left(&self) -> u64 {
        MAX_DECOMPRESSED_BYTES.saturating_sub(self.decompressed.get())
    }

    fn charge(&self, bytes: u64, object: &str) -> Result<(), String> {
        let total = self.decompressed.get().saturating_add(bytes);
        if total > MAX_DECOMPRESSED_BYTES {
            return Err(format!(
                "{object}: decompresses to {bytes} bytes; the scene's compressed data would take \
                 more than {} MiB decompressed",
                MAX_DECOMPRESSED_BYTES >> 20
            ));
        }
        self.decompressed.set(total);
        Ok(())
    }

    /// Buffer view `index` decompressed, if it is compressed with meshopt.
    fn decompressed_view(&self, index: usize) -> Option<Result<&[u8], GltfError>> {
        let view = self.root.buffer_views.get(index)?;
        let cell = self.decoded.get(index)?;
        if matches!(meshopt::compressed(view), Ok(None)) {
            return None;
        }
        let result = cell.get_or_init(|| {
            let object = view_label(self.root, index);
            let data = |reason: String| Failed::Data {
                object: object.clone(),
                reason,
            };
            let c = match meshopt::compressed(view) {
                Ok(Some(c)) => c,
                Ok(None) => return Err(data("is not compressed".into())),
                Err(reason) => return Err(data(reason)),
            };
            let source = self
                .buffer(c.buffer)
                .map_err(|e| data(format!("{}: {e}", c.extension)))?;
            let source = match c.byte_offset.checked_add(c.byte_length) {
                Some(end) if end <= source.len() as u64 => {
                    &source[c.byte_offset as usize..end as usize]
                }
                _ => {
                    return Err(data(format!(
                        "{}: byteOffset {} + byteLength {} exceeds the {} bytes of {}",
                        c.extension,
                        c.byte_offset,
                        c.byte_length,
                        source.len(),
                        buffer_label(self.root, c.buffer)
                    )))
                }
            };
            let Some(len) = c.decoded_len() else {
                return Err(data(format!(
                    "{}: count × byteStride overflows",
                    c.extension
                )));
            };
            self.charge(len, &object).map_err(Failed::Limit)?;
            let bytes = meshopt::decode(&c, source, len).map_err(data)?;
            self.fetched.set(self.fetched.get() + bytes.len() as u64);
            Ok(bytes)
        });
        Some(match result {
            Ok(bytes) => Ok(bytes),
            Err(f) => Err(f.clone().into()),
        })
    }

    /// The bytes of buffer `index`, exactly `byteLength` long.
    pub fn buffer(&self, index: usize) -> Result<&[u8], GltfError> {
        let Some(cell) = self.buffers.get(index) else {
            return Err(GltfError::Resource {
                object: format!("buffer {index}"),
                reason: format!(
                    "does not exist (the file has {} buffers)",
                    self.buffers.len()
                ),
            });
        };
        let fetched = cell.get_or_init(|| {
            let f = self.fetch_buffer(index);
            if let Ok(bytes) = &f {
                self.fetched.set(self.fetched.get() + bytes.len() as u64);
            }
            f
        });
        match fetched {
            Ok(bytes) => Ok(bytes),
            Err((object, reason)) => Err(GltfError::Resource {
                object: object.clone(),
                reason: reason.clone(),
            }),
        }
    }

    fn fetch_buffer(&self, index: usize) -> Fetched<'a> {
        let object = buffer_label(self.root, index);
        let fail = |reason: String| Err((object.clone(), reason));
        let Some(buffer) = self.root.buffers.get(index) else {
            return fail("does not exist".into());
        };
        let declared = buffer.byte_length.0;
        let data: Cow<'a, [u8]> = match buffer.uri.as_deref() {
            None => match (index, self.bin) {
                (0, Some(bin)) => Cow::Borrowed(bin),
                _ if meshopt::is_fallback(buffer) => {
                    return fail(
                        "is a meshopt compression fallback buffer without data; only buffer views \
                         compressed with EXT_meshopt_compression may refer to it"
                            .into(),
                    )
                }
                (0, None) => return fail("has no uri and the file has no GLB BIN chunk".into()),
                _ => {
                    return fail("has no uri (only buffer 0 may refer to the GLB BIN chunk)".into())
                }
            },
            Some(uri) => match fetch_uri(uri, self.resolver) {
                Ok(bytes) => Cow::Owned(bytes),
                Err(reason) => return fail(reason),
            },
        };
        let have = data.len() as u64;
        if have < declared {
            return fail(format!("has {have} bytes but its byteLength is {declared}"));
        }
        // The BIN chunk may carry up to 3 padding bytes; views are checked against byteLength.
        let declared = declared as usize; // declared <= have, which fits in usize
        Ok(match data {
            Cow::Borrowed(b) => Cow::Borrowed(&b[..declared]),
            Cow::Owned(mut v) => {
                v.truncate(declared);
                Cow::Owned(v)
            }
        })
    }

    /// The bytes of the buffers fetched so far (each once).
    pub fn fetched_bytes(&self) -> u64 {
        self.fetched.get()
    }

    /// The bytes of buffer view `index`, after checking that the view lies inside its buffer.
    /// A view compressed with meshopt is decoded (once) from its extension's buffer instead.
    pub fn view(&self, index: usize) -> Result<&[u8], GltfError> {
        if let Some(decoded) = self.decompressed_view(index) {
            return decoded;
        }
        let Some(view) = self.root.buffer_views.get(index) else {
            return Err(GltfError::Data {
                object: format!("bufferView {index}"),
                reason: format!(
                    "does not exist (the file has {} buffer views)",
                    self.root.buffer_views.len()
                ),
            });
        };
        let buffer_index = view.buffer.value();
        let buffer = self.buffer(buffer_index)?;
        let offset = view.byte_offset.map_or(0, |o| o.0);
        let length = view.byte_length.0;
        match offset.checked_add(length) {
            Some(end) if end <= buffer.len() as u64 => Ok(&buffer[offset as usize..end as usize]),
            _ => Err(GltfError::Data {
                object: view_label(self.root, index),
                reason: format!(
                    "byteOffset {offset} + byteLength {length} exceeds the {} bytes of {}",
                    buffer.len(),
                    buffer_label(self.root, buffer_index)
                ),
            }),
        }
    }

    /// The encoded bytes of image `index` (from a buffer view, a data URI or the resolver).
    pub fn image_bytes(&self, index: usize) -> Result<Cow<'_, [u8]>, GltfError> {
        let object = image_label(self.root, index);
        let Some(image) = self.root.images.get(index) else {
            return Err(GltfError::Resource {
                object,
                reason: "does not exist".into(),
            });
        };
        match (&image.buffer_view, &image.uri) {
            (Some(view), _) => Ok(Cow::Borrowed(self.view(view.value())?)),
            (None, Some(uri)) => fetch_uri(uri, self.resolver)
                .map(Cow::Owned)
                .map_err(|reason| GltfError::Resource { object, reason }),
            (None, None) => Err(GltfError::Resource {
                object,
                reason: "has neither a uri nor a bufferView".into(),
            }),
        }
    }
}

/// Fetches a URI: decodes `data:` URIs here, hands anything else (percent-decoded) to the resolver.
fn fetch_uri(uri: &str, resolver: &dyn ResourceResolver) -> Result<Vec<u8>, String> {
    if let Some(rest) = strip_prefix_ignore_case(uri, "data:") {
        return decode_data_uri(rest).map_err(|e| format!("bad data URI: {e}"));
    }
    let path = percent_decode(uri).map_err(|e| format!("bad URI {uri:?}: {e}"))?;
    resolver
        .resolve(&path)
        .map_err(|e| format!("cannot read {path:?}: {e}"))
}

fn strip_prefix_ignore_case<'s>(s: &'s str, prefix: &str) -> Option<&'s str> {
    let head = s.get(..prefix.len())?;
    if head.eq_ignore_ascii_case(prefix) {
        s.get(prefix.len()..)
    } else {
        None
    }
}

/// Decodes what follows `data:`: `[<mediatype>][;base64],<data>`.
pub(crate) fn decode_data_uri(rest: &str) -> Result<Vec<u8>, String> {
    let Some((header, payload)) = rest.split_once(',') else {
        return Err("no ',' separating the header from the data".into());
    };
    let is_base64 = header
        .rsplit(';')
        .next()
        .is_some_and(|p| p.trim().eq_ignore_ascii_case("base64"));
    if is_base64 {
        let cleaned: Vec<u8> = payload
            .bytes()
            .filter(|b| !b.is_ascii_whitespace())
            .collect();
        base64::engine::general_purpose::STANDARD_PAD_INDIFFERENT
            .decode(&cleaned)
            .map_err(|e| format!("invalid base64: {e}"))
    } else {
        // RFC 2397: the data are percent-encoded bytes (not necessarily UTF-8).
        check_escapes(payload)?;
        Ok(percent_encoding::percent_decode_str(payload).collect())
    }
}

/// Refuses a `%` not followed by two hexadecimal digits, naming where: the `percent-encoding`
/// crate passes such a `%` through as it is, and a URI that carries one is malformed (RFC 3986).
fn check_escapes(s: &str) -> Result<(), String> {
    let bytes = s.as_bytes();
    for (i, _) in s.match_indices('%') {
        let hex = bytes.get(i + 1..i + 3);
        if !hex.is_some_and(|h| h.iter().all(u8::is_ascii_hexdigit)) {
            let shown: String = s[i..].chars().take(3).collect();
            return Err(format!("bad escape {shown:?} at byte {i}"));
        }
    }
    Ok(())
}

/// RFC 3986 percent-decoding of a file URI into the UTF-8 path the resolver is given. This is the
/// only place a glTF URI is decoded: resolvers take the result as it is (a file literally named
/// `a%20b.bin` is written `a%2520b.bin` in the glTF).
pub(crate) fn percent_decode(s: &str) -> Result<String, String> {
    check_escapes(s)?;
    percent_encoding::percent_decode_str(s)
        .decode_utf8()
        .map(|p| p.into_owned())
        .map_err(|_| "percent-decoded URI is not UTF-8".to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn data_uris_and_percent_decoding() {
        assert_eq!(
            decode_data_uri("application/octet-stream;base64,AAEC").unwrap(),
            vec![0, 1, 2]
        );
        assert_eq!(decode_data_uri(";base64,AAE").unwrap(), vec![0, 1]);
        assert_eq!(
            decode_data_uri("text/plain,a%20b").unwrap(),
            b"a b".to_vec()
        );
        assert!(decode_data_uri("application/octet-stream;base64,A!==").is_err());
        assert!(decode_data_uri("base64").is_err());
        assert_eq!(percent_decode("my%20file.bin").unwrap(), "my file.bin");
        assert!(percent_decode("bad%2").is_err());
        assert!(percent_decode("bad%zz").is_err());
        assert!(percent_decode("bad%").is_err());
        // Decoded once: an escaped '%' stays a '%'; UTF-8 escapes give their characters.
        assert_eq!(percent_decode("a%2520b.bin").unwrap(), "a%20b.bin");
        assert_eq!(percent_decode("caf%C3%A9.bin").unwrap(), "café.bin");
        assert_eq!(percent_decode("café.bin").unwrap(), "café.bin");
        assert!(percent_decode("%FF.bin").is_err());
        assert_eq!(decode_data_uri(",%FF%00").unwrap(), vec![0xff, 0]);
    }
}
