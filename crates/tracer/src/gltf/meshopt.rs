//! EXT_meshopt_compression (and KHR_meshopt_compression, its ratified successor, which adds vertex
//! codec version 1 and the COLOR filter): buffer views whose bytes are stored compressed in another
//! buffer, decoded with the pure-Rust `meshoptimizer-rs` port of meshoptimizer's decoders.
//!
//! A compressed view names, in its extension, the buffer range holding the compressed bytes, the
//! element count and stride, the mode (ATTRIBUTES, TRIANGLES, INDICES) and a filter (NONE,
//! OCTAHEDRAL, QUATERNION, EXPONENTIAL, and COLOR for KHR). The view's own `buffer` is then usually a
//! *fallback* buffer (extension `fallback: true`, often without data) that is never read here. The
//! decoded size, `count × byteStride` from the extension, is checked against the load's budget for
//! decompressed data ([`super::resources::MAX_DECOMPRESSED_BYTES`]) before anything is allocated, and
//! the decoder's own limits are set to what is left of it.

use gltf::json;
use json::Value;
use meshoptimizer_rs::codec::{self, Filter, Mode};
use meshoptimizer_rs::{Limits, Workspace};

/// The two names of the extension, newest last.
pub(crate) const EXTENSIONS: [&str; 2] = ["EXT_meshopt_compression", "KHR_meshopt_compression"];

/// A compressed buffer view, as its extension describes it.
#[derive(Clone, Debug)]
pub(crate) struct Compressed {
    pub extension: &'static str,
    pub buffer: usize,
    pub byte_offset: u64,
    pub byte_length: u64,
    pub byte_stride: u64,
    pub count: u64,
    pub mode: String,
    pub filter: String,
}

impl Compressed {
    /// The decoded size in bytes (`count × byteStride`), `None` on overflow.
    pub fn decoded_len(&self) -> Option<u64> {
        self.count.checked_mul(self.byte_stride)
    }
}

/// The meshopt extension of buffer view `view`, if it has one: `Ok(None)` without, an error
/// (the reason) for an extension object that is not well formed.
pub(crate) fn compressed(view: &json::buffer::View) -> Result<Option<Compressed>, String> {
    let Some(others) = view.extensions.as_ref().map(|e| &e.others) else {
        return Ok(None);
    };
    let Some((extension, v)) = EXTENSIONS
        .iter()
        .rev()
        .find_map(|&name| others.get(name).map(|v| (name, v)))
    else {
        return Ok(None);
    };
    let int = |key: &str, default: Option<u64>| -> Result<u64, String> {
        match v.get(key) {
            Some(x) => x
                .as_u64()
                .ok_or_else(|| format!("{extension}: {key} is not a non-negative integer")),
            None => default.ok_or_else(|| format!("{extension}: {key} is missing")),
        }
    };
    let text = |key: &str, default: Option<&str>| -> Result<String, String> {
        match v.get(key) {
            Some(Value::String(s)) => Ok(s.clone()),
            Some(_) => Err(format!("{extension}: {key} is not a string")),
            None => default
                .map(str::to_string)
                .ok_or_else(|| format!("{extension}: {key} is missing")),
        }
    };
    let buffer = int("buffer", None)?;
    Ok(Some(Compressed {
        extension,
        buffer: usize::try_from(buffer).unwrap_or(usize::MAX),
        byte_offset: int("byteOffset", Some(0))?,
        byte_length: int("byteLength", None)?,
        byte_stride: int("byteStride", None)?,
        count: int("count", None)?,
        mode: text("mode", None)?,
        filter: text("filter", Some("NONE"))?,
    }))
}

/// Whether buffer `buffer` is marked as a meshopt fallback buffer (its data, if any, is for loaders
/// without the extension and is never read here).
pub(crate) fn is_fallback(buffer: &json::buffer::Buffer) -> bool {
    buffer.extensions.as_ref().is_some_and(|e| {
        EXTENSIONS.iter().any(|name| {
            e.others
                .get(*name)
                .and_then(|v| v.get("fallback"))
                .and_then(Value::as_bool)
                == Some(true)
        })
    })
}

/// Decodes `source` as `c` describes, allocating at most `max_bytes` (the caller has checked the
/// decoded size against its budget already). The error is the reason, for a message naming the view.
pub(crate) fn decode(c: &Compressed, source: &[u8], max_bytes: u64) -> Result<Vec<u8>, String> {
    let what = || {
        format!(
            "{}: cannot decode mode {}, filter {}, count {}, byteStride {} from {} bytes",
            c.extension,
            c.mode,
            c.filter,
            c.count,
            c.byte_stride,
            source.len()
        )
    };
    let fail = |e: meshoptimizer_rs::Error| format!("{}: {e}", what());
    let mode = Mode::parse(&c.mode).map_err(|_| format!("{}: unknown mode", what()))?;
    let (count, stride) = match (usize::try_from(c.count), usize::try_from(c.byte_stride)) {
        (Ok(n), Ok(s)) => (n, s),
        _ => return Err(format!("{}: too large", what())),
    };
    let mut workspace = Workspace::new(Limits {
        // The output plus the decoder's scratch (a few blocks).
        max_bytes: usize::try_from(max_bytes.saturating_add(1 << 20)).unwrap_or(usize::MAX),
        ..Limits::default()
    });
    if c.extension == EXTENSIONS[0] {
        let filter = Filter::parse(&c.filter).map_err(|_| format!("{}: unknown filter", what()))?;
        return codec::decode_buffer_view(mode, filter, count, stride, source, &mut workspace)
            .map_err(fail);
    }
    // KHR_meshopt_compression: vertex codec versions 0 and 1, and the COLOR filter.
    if c.filter != "NONE" && mode != Mode::Attributes {
        return Err(format!("{}: filters apply to ATTRIBUTES only", what()));
    }
    if count == 0 {
        return Err(format!("{}: count must be positive", what()));
    }
    let mut out = match mode {
        Mode::Attributes => codec::decode_vertex_buffer(count, stride, source, &mut workspace),
        Mode::Triangles => codec::decode_index_buffer(count, stride, source, &mut workspace),
        Mode::Indices => codec::decode_index_sequence(count, stride, source, &mut workspace),
    }
    .map_err(fail)?;
    match c.filter.as_str() {
        "NONE" => Ok(()),
        "OCTAHEDRAL" => codec::decode_filter_oct(&mut out, count, stride, &mut workspace),
        "QUATERNION" => codec::decode_filter_quat(&mut out, count, stride, &mut workspace),
        "EXPONENTIAL" => codec::decode_filter_exp(&mut out, count, stride, &mut workspace),
        "COLOR" => codec::decode_filter_color(&mut out, count, stride, &mut workspace),
        _ => return Err(format!("{}: unknown filter", what())),
    }
    .map_err(fail)?;
    Ok(out)
}
