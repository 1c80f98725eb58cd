//! The GLB container: a 12-byte header, a JSON chunk and an optional BIN chunk. Every length is
//! checked here, before any byte reaches the `gltf` crate, so that a lying length gives a clear error.

use super::error::GltfError;

/// The chunks of a GLB file, borrowed from the input.
#[derive(Debug)]
pub(crate) struct Glb<'a> {
    pub json: &'a [u8],
    pub bin: Option<&'a [u8]>,
    /// Non-fatal oddities (unknown chunks, trailing bytes).
    pub warnings: Vec<String>,
}

const MAGIC: &[u8; 4] = b"glTF";
const CHUNK_JSON: u32 = 0x4E4F_534A; // "JSON"
const CHUNK_BIN: u32 = 0x004E_4942; // "BIN\0"

/// True if `bytes` start with the GLB magic.
pub(crate) fn is_glb(bytes: &[u8]) -> bool {
    bytes.starts_with(MAGIC)
}

fn u32_at(bytes: &[u8], offset: usize) -> Option<u32> {
    let b = bytes.get(offset..offset.checked_add(4)?)?;
    Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// Splits a GLB file into its chunks.
pub(crate) fn parse(bytes: &[u8]) -> Result<Glb<'_>, GltfError> {
    let err = |m: String| Err(GltfError::Glb(m));
    let size = bytes.len();
    if size < 12 {
        return err(format!(
            "file is {size} bytes, shorter than the 12-byte header"
        ));
    }
    if !is_glb(bytes) {
        return err("missing \"glTF\" magic".into());
    }
    let (Some(version), Some(length)) = (u32_at(bytes, 4), u32_at(bytes, 8)) else {
        return err(format!(
            "file is {size} bytes, shorter than the 12-byte header"
        ));
    };
    if version != 2 {
        return err(format!(
            "container version {version} is not supported (only version 2)"
        ));
    }
    let length = length as usize;
    if length > size {
        return err(format!("header length {length} exceeds file size {size}"));
    }
    let mut warnings = Vec::new();
    if length < size {
        warnings.push(format!(
            "GLB: {} bytes after the header's length {length} ignored",
            size - length
        ));
    }
    let data = &bytes[..length];
    let mut offset = 12usize;
    let mut json = None;
    let mut bin = None;
    let mut chunk_index = 0usize;
    while offset < length {
        let (Some(chunk_len), Some(chunk_type)) = (u32_at(data, offset), u32_at(data, offset + 4))
        else {
            return err(format!(
                "chunk {chunk_index}: truncated chunk header at byte {offset} (file size {length})"
            ));
        };
        let start = offset + 8;
        let end = start
            .checked_add(chunk_len as usize)
            .filter(|&e| e <= length);
        let Some(end) = end else {
            return err(format!(
                "chunk length {chunk_len} exceeds file size {length} (chunk {chunk_index} at byte {offset})"
            ));
        };
        let body = &data[start..end];
        match (chunk_index, chunk_type) {
            (0, CHUNK_JSON) => json = Some(body),
            (0, other) => {
                return err(format!(
                    "first chunk must be JSON, found type 0x{other:08x}"
                ));
            }
            (1, CHUNK_BIN) => bin = Some(body),
            (_, CHUNK_JSON) => return err(format!("chunk {chunk_index}: a second JSON chunk")),
            (_, CHUNK_BIN) => {
                return err(format!(
                    "chunk {chunk_index}: BIN chunk must be the second chunk"
                ))
            }
            (_, other) => warnings.push(format!("GLB: unknown chunk type 0x{other:08x} ignored")),
        }
        chunk_index += 1;
        offset = end;
    }
    let Some(json) = json else {
        return err("no JSON chunk".into());
    };
    Ok(Glb {
        json,
        bin,
        warnings,
    })
}

/// A `.glb` of a JSON document and an optional binary buffer (each chunk padded to four bytes:
/// JSON with spaces, the buffer with zeros), for tools that generate scenes. `None` when a chunk is
/// over the format's 4 GiB.
pub fn encode(json: &[u8], bin: Option<&[u8]>) -> Option<Vec<u8>> {
    let padded = |len: usize| len.div_ceil(4) * 4;
    let mut out = Vec::with_capacity(28 + padded(json.len()) + bin.map_or(0, |b| padded(b.len())));
    out.extend(MAGIC);
    out.extend(2u32.to_le_bytes());
    out.extend(0u32.to_le_bytes());
    out.extend(u32::try_from(padded(json.len())).ok()?.to_le_bytes());
    out.extend(b"JSON");
    out.extend(json);
    out.resize(out.len() + padded(json.len()) - json.len(), b' ');
    if let Some(bin) = bin {
        out.extend(u32::try_from(padded(bin.len())).ok()?.to_le_bytes());
        out.extend(b"BIN\0");
        out.extend(bin);
        out.resize(out.len() + padded(bin.len()) - bin.len(), 0);
    }
    let n = u32::try_from(out.len()).ok()?;
    out[8..12].copy_from_slice(&n.to_le_bytes());
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn glb(json: &[u8], bin: Option<&[u8]>) -> Vec<u8> {
        encode(json, bin).unwrap()
    }

    #[test]
    fn splits_chunks_and_rejects_lies() {
        let file = glb(b"{}  ", Some(&[1, 2, 3, 4]));
        let g = parse(&file).unwrap();
        assert_eq!(g.json, b"{}  ");
        assert_eq!(g.bin, Some(&[1u8, 2, 3, 4][..]));
        let mut lying = file.clone();
        lying[12..16].copy_from_slice(&99999u32.to_le_bytes());
        let e = parse(&lying).unwrap_err().to_string();
        assert!(e.contains("chunk length 99999 exceeds file size"), "{e}");
        let e = parse(&file[..file.len() - 2]).unwrap_err().to_string();
        assert!(e.contains("exceeds file size"), "{e}");
        assert!(parse(&file[..7]).is_err());
    }
}
