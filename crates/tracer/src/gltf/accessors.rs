//! Bounds-checked accessor reading. Every accessor is checked against its buffer view (offset +
//! stride·(count−1) + element size ≤ view length) and the view against its buffer before a byte is
//! read; components are decoded little-endian without alignment assumptions. Sparse accessors are
//! supported. Integer components of vertex attributes (KHR_mesh_quantization) are converted to float,
//! honouring `normalized`.

use super::error::{label, GltfError};
use super::resources::Resources;
use gltf::json;
use json::accessor::{ComponentType, Type};
use json::validation::Checked;
use std::cell::Cell;

/// Accessors without a buffer view are zero-filled from nothing in the file; more elements than this
/// (over the whole load) would let a tiny file claim gigabytes.
const MAX_ZERO_FILLED: u64 = 1 << 24;

/// Reads accessors of one document.
pub(crate) struct Accessors<'r, 'a> {
    root: &'r json::Root,
    res: &'r Resources<'a>,
    /// Zero-filled elements read so far.
    zero_filled: Cell<u64>,
}

fn component_size(ct: ComponentType) -> usize {
    match ct {
        ComponentType::I8 | ComponentType::U8 => 1,
        ComponentType::I16 | ComponentType::U16 => 2,
        ComponentType::U32 | ComponentType::F32 => 4,
    }
}

fn type_components(ty: Type) -> usize {
    match ty {
        Type::Scalar => 1,
        Type::Vec2 => 2,
        Type::Vec3 => 3,
        Type::Vec4 | Type::Mat2 => 4,
        Type::Mat3 => 9,
        Type::Mat4 => 16,
    }
}

fn type_name(ty: Type) -> &'static str {
    match ty {
        Type::Scalar => "SCALAR",
        Type::Vec2 => "VEC2",
        Type::Vec3 => "VEC3",
        Type::Vec4 => "VEC4",
        Type::Mat2 => "MAT2",
        Type::Mat3 => "MAT3",
        Type::Mat4 => "MAT4",
    }
}

fn component_name(ct: ComponentType) -> &'static str {
    match ct {
        ComponentType::I8 => "BYTE",
        ComponentType::U8 => "UNSIGNED_BYTE",
        ComponentType::I16 => "SHORT",
        ComponentType::U16 => "UNSIGNED_SHORT",
        ComponentType::U32 => "UNSIGNED_INT",
        ComponentType::F32 => "FLOAT",
    }
}

/// One component at `at`, as f32 (normalized integers per the glTF rules). `None` if out of bounds.
#[inline]
fn component(bytes: &[u8], at: usize, ct: ComponentType, normalized: bool) -> Option<f32> {
    let b = bytes.get(at..at.checked_add(component_size(ct))?)?;
    Some(match ct {
        ComponentType::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        ComponentType::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
        ComponentType::I8 => {
            let v = b[0] as i8 as f32;
            if normalized {
                (v / 127.0).max(-1.0)
            } else {
                v
            }
        }
        ComponentType::U8 => {
            let v = b[0] as f32;
            if normalized {
                v / 255.0
            } else {
                v
            }
        }
        ComponentType::I16 => {
            let v = i16::from_le_bytes([b[0], b[1]]) as f32;
            if normalized {
                (v / 32767.0).max(-1.0)
            } else {
                v
            }
        }
        ComponentType::U16 => {
            let v = u16::from_le_bytes([b[0], b[1]]) as f32;
            if normalized {
                v / 65535.0
            } else {
                v
            }
        }
    })
}

#[inline]
fn index_at(bytes: &[u8], at: usize, ct: ComponentType) -> Option<u32> {
    let b = bytes.get(at..at.checked_add(component_size(ct))?)?;
    match ct {
        ComponentType::U8 => Some(b[0] as u32),
        ComponentType::U16 => Some(u16::from_le_bytes([b[0], b[1]]) as u32),
        ComponentType::U32 => Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        _ => None,
    }
}

/// A located, bounds-checked accessor.
struct Located<'b> {
    /// The view's bytes (empty when the accessor has no view).
    data: &'b [u8],
    offset: usize,
    stride: usize,
    count: usize,
    ct: ComponentType,
    normalized: bool,
    has_view: bool,
}

impl<'r, 'a> Accessors<'r, 'a> {
    pub fn new(root: &'r json::Root, res: &'r Resources<'a>) -> Self {
        Accessors {
            root,
            res,
            zero_filled: Cell::new(0),
        }
    }

    pub fn root(&self) -> &'r json::Root {
        self.root
    }

    /// `accessor 7 "name" (POSITION of mesh 0 "Box", primitive 0)`.
    pub fn label(&self, index: usize, usage: &str) -> String {
        let name = self
            .root
            .accessors
            .get(index)
            .and_then(|a| a.name.as_deref());
        format!("{} ({usage})", label("accessor", index, name))
    }

    fn err(&self, index: usize, usage: &str, reason: impl Into<String>) -> GltfError {
        GltfError::Data {
            object: self.label(index, usage),
            reason: reason.into(),
        }
    }

    fn locate(&self, index: usize, usage: &str, want: &[Type]) -> Result<Located<'_>, GltfError> {
        let Some(acc) = self.root.accessors.get(index) else {
            return Err(self.err(
                index,
                usage,
                format!(
                    "does not exist (the file has {} accessors)",
                    self.root.accessors.len()
                ),
            ));
        };
        let ty = match acc.type_ {
            Checked::Valid(t) => t,
            Checked::Invalid => return Err(self.err(index, usage, "invalid type")),
        };
        let ct = match acc.component_type {
            Checked::Valid(c) => c.0,
            Checked::Invalid => return Err(self.err(index, usage, "invalid componentType")),
        };
        if !want.contains(&ty) {
            let want: Vec<&str> = want.iter().map(|&t| type_name(t)).collect();
            return Err(self.err(
                index,
                usage,
                format!(
                    "type {} where {} is required",
                    type_name(ty),
                    want.join(" or ")
                ),
            ));
        }
        let ncomp = type_components(ty);
        let elem = (ncomp * component_size(ct)) as u64;
        let count = acc.count.0;
        let offset = acc.byte_offset.map_or(0, |o| o.0);
        let Some(view_ref) = acc.buffer_view else {
            let total = self.zero_filled.get().saturating_add(count);
            if total > MAX_ZERO_FILLED {
                return Err(self.err(
                    index,
                    usage,
                    format!(
                        "count {count} without a bufferView: accessors without data total more than \
                         {MAX_ZERO_FILLED} elements"
                    ),
                ));
            }
            self.zero_filled.set(total);
            return Ok(Located {
                data: &[],
                offset: 0,
                stride: elem as usize,
                count: count as usize,
                ct,
                normalized: acc.normalized,
                has_view: false,
            });
        };
        let view_index = view_ref.value();
        let data = self.res.view(view_index)?;
        let stride = match self
            .root
            .buffer_views
            .get(view_index)
            .and_then(|v| v.byte_stride)
        {
            Some(s) if (s.0 as u64) < elem => {
                return Err(self.err(
                    index,
                    usage,
                    format!(
                    "bufferView {view_index} byteStride {} is smaller than the element size {elem}",
                    s.0
                ),
                ))
            }
            Some(s) => s.0 as u64,
            None => elem,
        };
        let end = if count == 0 {
            Some(offset)
        } else {
            stride
                .checked_mul(count - 1)
                .and_then(|x| x.checked_add(offset))
                .and_then(|x| x.checked_add(elem))
        };
        match end {
            Some(end) if end <= data.len() as u64 => {}
            _ => {
                return Err(self.err(
                    index,
                    usage,
                    format!(
                        "byteOffset {offset} + stride {stride} × (count {count} − 1) + element size {elem} exceeds \
                         the {} bytes of bufferView {view_index}",
                        data.len()
                    ),
                ))
            }
        }
        // end <= data.len() so every quantity fits in usize.
        Ok(Located {
            data,
            offset: offset as usize,
            stride: stride as usize,
            count: count as usize,
            ct,
            normalized: acc.normalized,
            has_view: true,
        })
    }

    /// Reads a float vector attribute (`N` = 2, 3 or 4 components) with every value finite.
    pub fn read_vec<const N: usize>(
        &self,
        index: usize,
        usage: &str,
    ) -> Result<Vec<[f32; N]>, GltfError> {
        let ty = match N {
            2 => Type::Vec2,
            3 => Type::Vec3,
            4 => Type::Vec4,
            _ => return Err(GltfError::Internal(format!("read_vec::<{N}>"))),
        };
        let loc = self.locate(index, usage, &[ty])?;
        if loc.ct == ComponentType::U32 {
            return Err(self.err(
                index,
                usage,
                format!(
                    "componentType {} is not allowed here",
                    component_name(loc.ct)
                ),
            ));
        }
        let mut out = vec![[0.0f32; N]; loc.count];
        if loc.has_view {
            let csize = component_size(loc.ct);
            for (i, v) in out.iter_mut().enumerate() {
                let base = loc.offset + i * loc.stride;
                for (c, x) in v.iter_mut().enumerate() {
                    *x = component(loc.data, base + c * csize, loc.ct, loc.normalized).ok_or_else(
                        || self.err(index, usage, format!("element {i} out of bounds")),
                    )?;
                }
            }
        }
        self.apply_sparse(index, usage, loc.ct, loc.normalized, &mut out)?;
        for (i, v) in out.iter().enumerate() {
            if let Some(x) = v.iter().find(|x| !x.is_finite()) {
                let what = if x.is_nan() { "NaN" } else { "infinite" };
                return Err(self.err(index, usage, format!("{what} component at element {i}")));
            }
        }
        Ok(out)
    }

    fn apply_sparse<const N: usize>(
        &self,
        index: usize,
        usage: &str,
        ct: ComponentType,
        normalized: bool,
        out: &mut [[f32; N]],
    ) -> Result<(), GltfError> {
        let Some(sparse) = self
            .root
            .accessors
            .get(index)
            .and_then(|a| a.sparse.as_ref())
        else {
            return Ok(());
        };
        let count = sparse.count.0;
        let ict = match sparse.indices.component_type {
            Checked::Valid(c)
                if matches!(
                    c.0,
                    ComponentType::U8 | ComponentType::U16 | ComponentType::U32
                ) =>
            {
                c.0
            }
            _ => return Err(self.err(index, usage, "sparse indices: invalid componentType")),
        };
        let idx_bytes = self.res.view(sparse.indices.buffer_view.value())?;
        let val_bytes = self.res.view(sparse.values.buffer_view.value())?;
        let (isize_, vsize) = (component_size(ict) as u64, (N * component_size(ct)) as u64);
        let idx_end = count
            .checked_mul(isize_)
            .and_then(|n| n.checked_add(sparse.indices.byte_offset.0));
        let val_end = count
            .checked_mul(vsize)
            .and_then(|n| n.checked_add(sparse.values.byte_offset.0));
        if !matches!(idx_end, Some(e) if e <= idx_bytes.len() as u64) {
            return Err(self.err(
                index,
                usage,
                format!("sparse indices ({count}) exceed their bufferView"),
            ));
        }
        if !matches!(val_end, Some(e) if e <= val_bytes.len() as u64) {
            return Err(self.err(
                index,
                usage,
                format!("sparse values ({count}) exceed their bufferView"),
            ));
        }
        let (ioff, voff) = (
            sparse.indices.byte_offset.0 as usize,
            sparse.values.byte_offset.0 as usize,
        );
        for k in 0..count as usize {
            let target = index_at(idx_bytes, ioff + k * isize_ as usize, ict)
                .ok_or_else(|| self.err(index, usage, format!("sparse index {k} out of bounds")))?;
            let len = out.len();
            let Some(slot) = out.get_mut(target as usize) else {
                return Err(self.err(
                    index,
                    usage,
                    format!("sparse index {target} out of range (count {len})"),
                ));
            };
            let base = voff + k * vsize as usize;
            for (c, x) in slot.iter_mut().enumerate() {
                *x = component(val_bytes, base + c * component_size(ct), ct, normalized)
                    .ok_or_else(|| {
                        self.err(index, usage, format!("sparse value {k} out of bounds"))
                    })?;
            }
        }
        Ok(())
    }

    /// Reads an index accessor (SCALAR of UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT).
    pub fn read_indices(&self, index: usize, usage: &str) -> Result<Vec<u32>, GltfError> {
        let loc = self.locate(index, usage, &[Type::Scalar])?;
        if !matches!(
            loc.ct,
            ComponentType::U8 | ComponentType::U16 | ComponentType::U32
        ) {
            return Err(self.err(
                index,
                usage,
                format!(
                    "componentType {} is not allowed for indices",
                    component_name(loc.ct)
                ),
            ));
        }
        let mut out = vec![0u32; loc.count];
        if loc.has_view {
            for (i, v) in out.iter_mut().enumerate() {
                *v = index_at(loc.data, loc.offset + i * loc.stride, loc.ct)
                    .ok_or_else(|| self.err(index, usage, format!("element {i} out of bounds")))?;
            }
        }
        let mut as_float: Vec<[f32; 1]> = Vec::new();
        if self
            .root
            .accessors
            .get(index)
            .is_some_and(|a| a.sparse.is_some())
        {
            // Sparse index accessors are rare; go through f32 only when exact (< 2^24).
            as_float = out.iter().map(|&v| [v as f32]).collect();
            self.apply_sparse(index, usage, loc.ct, false, &mut as_float)?;
        }
        if !as_float.is_empty() {
            for (o, f) in out.iter_mut().zip(&as_float) {
                if !(f[0] >= 0.0 && f[0] < 16_777_216.0) {
                    return Err(self.err(
                        index,
                        usage,
                        "sparse index values beyond 2^24 are not supported",
                    ));
                }
                *o = f[0] as u32;
            }
        }
        Ok(out)
    }
}
