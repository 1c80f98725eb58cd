//! Where the bytes of buffers and images come from: the GLB BIN chunk, `data:` URIs (base64 or
//! percent-encoded) and external URIs through the caller's [`ResourceResolver`]. Each buffer is fetched
//! at most once, and only if something the scene uses reads it.

use super::error::{label, GltfError};
use super::ResourceResolver;
use base64::Engine as _;
use gltf::json;
use std::borrow::Cow;
use std::cell::{Cell, OnceCell};

type Fetched<'a> = Result<Cow<'a, [u8]>, (String, String)>;

/// Lazily fetched buffers of one document.
pub(crate) struct Resources<'a> {
    root: &'a json::Root,
    bin: Option<&'a [u8]>,
    resolver: &'a dyn ResourceResolver,
    buffers: Vec<OnceCell<Fetched<'a>>>,
    /// Bytes of the buffers fetched so far.
    fetched: Cell<u64>,
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
        Resources {
            root,
            bin,
            resolver,
            buffers,
            fetched: Cell::new(0),
        }
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
    pub fn view(&self, index: usize) -> Result<&[u8], GltfError> {
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
        percent_decode(payload)
            .map(String::into_bytes)
            .or_else(|_| percent_decode_bytes(payload))
    }
}

fn percent_decode_bytes(s: &str) -> Result<Vec<u8>, String> {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let b = bytes[i];
        if b == b'%' {
            let hex = bytes
                .get(i + 1..i + 3)
                .ok_or_else(|| format!("truncated escape at byte {i}"))?;
            let hex = std::str::from_utf8(hex).map_err(|_| format!("bad escape at byte {i}"))?;
            let v = u8::from_str_radix(hex, 16)
                .map_err(|_| format!("bad escape %{hex} at byte {i}"))?;
            out.push(v);
            i += 3;
        } else {
            out.push(b);
            i += 1;
        }
    }
    Ok(out)
}

/// RFC 3986 percent-decoding into a UTF-8 string.
pub(crate) fn percent_decode(s: &str) -> Result<String, String> {
    if !s.contains('%') {
        return Ok(s.to_string());
    }
    String::from_utf8(percent_decode_bytes(s)?)
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
    }
}
