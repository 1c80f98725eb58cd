//! Bounds-checked accessor reading. Every accessor is checked against its buffer view (offset +
//! stride·(count−1) + element size ≤ view length) and the view against its buffer before a byte is
//! read; components are decoded little-endian without alignment assumptions. Sparse accessors are
//! supported. Integer components of vertex attributes (KHR_mesh_quantization) are converted to float,
//! honouring `normalized`.
//!
//! The mesh builder reads through a cache: each accessor is decoded once however many primitives
//! use it (and accessors defined alike, the same bytes of the same view, share one decode), so what
//! a load decodes is bounded by the distinct accessors, not by the primitives that name them. Many
//! distinct accessors can still overlap the same bytes; `MAX_READ_OVERLAP` bounds that.

use super::components::{
    component, component_name, component_size, index_at, type_components, type_name,
};
use super::error::{label, GltfError};
use super::resources::Resources;
use glam::{Vec2, Vec3, Vec4};
use gltf::json;
use json::accessor::{ComponentType, Type};
use json::validation::Checked;
use std::cell::{Cell, RefCell};
use std::collections::HashMap;
use std::rc::Rc;

/// Accessors without a buffer view are zero-filled from nothing in the file; more elements than this
/// (over the whole load) would let a tiny file claim gigabytes.
const MAX_ZERO_FILLED: u64 = 1 << 24;

/// The vertex data read (the bytes of the file's encoding, each distinct accessor once) may total at
/// most this many times the bytes of the buffers fetched, plus [`READ_ALLOWANCE`]. A file reads each
/// byte once, or a few times where accessors share data; twenty thousand accessors over the same
/// megabyte would otherwise decode twenty gigabytes.
const MAX_READ_OVERLAP: u64 = 4;

/// Vertex data bytes every load may read beyond [`MAX_READ_OVERLAP`] × its buffers.
const READ_ALLOWANCE: u64 = 64 << 20;

/// What an accessor is read as.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Kind {
    Vec2,
    Vec3,
    Vec4,
    Indices,
}

/// A cache key: the accessor, or for an accessor with a buffer view and no sparse part, what it reads.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
enum Key {
    Accessor(usize, Kind),
    Data {
        view: usize,
        offset: u64,
        count: u64,
        ty: &'static str,
        ct: &'static str,
        normalized: bool,
        kind: Kind,
    },
}

/// A decoded accessor, shared by the primitives that use it.
#[derive(Clone)]
enum Decoded {
    Vec2(Rc<[Vec2]>),
    Vec3(Rc<[Vec3]>),
    Vec4(Rc<[Vec4]>),
    Indices(Rc<[u32]>),
}

/// Element types the cache holds.
trait Element: Sized {
    const KIND: Kind;
    fn wrap(v: Rc<[Self]>) -> Decoded;
    fn unwrap(d: &Decoded) -> Option<Rc<[Self]>>;
}

macro_rules! element {
    ($t:ty, $variant:ident) => {
        impl Element for $t {
            const KIND: Kind = Kind::$variant;
            fn wrap(v: Rc<[Self]>) -> Decoded {
                Decoded::$variant(v)
            }
            fn unwrap(d: &Decoded) -> Option<Rc<[Self]>> {
                match d {
                    Decoded::$variant(v) => Some(v.clone()),
                    _ => None,
                }
            }
        }
    };
}

element!(Vec2, Vec2);
element!(Vec3, Vec3);
element!(Vec4, Vec4);
element!(u32, Indices);

/// Reads accessors of one document.
pub(crate) struct Accessors<'r, 'a> {
    root: &'r json::Root,
    res: &'r Resources<'a>,
    /// Zero-filled elements read so far.
    zero_filled: Cell<u64>,
    /// Bytes of vertex data read from buffer views so far (see [`MAX_READ_OVERLAP`]).
    read_bytes: Cell<u64>,
    /// Elements decoded so far (vertex attributes and indices).
    decoded: Cell<u64>,
    cache: RefCell<HashMap<Key, Decoded>>,
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
            read_bytes: Cell::new(0),
            decoded: Cell::new(0),
            cache: RefCell::new(HashMap::new()),
        }
    }

    /// Elements decoded so far (each cached accessor once).
    #[cfg(test)]
    pub fn decoded(&self) -> u64 {
        self.decoded.get()
    }

    /// Accessor `index` as 2-vectors (see [`Self::read_vec`]), decoded once and shared.
    pub fn vec2(&self, index: usize, usage: &str) -> Result<Rc<[Vec2]>, GltfError> {
        self.cached(index, || {
            Ok(self
                .read_vec::<2>(index, usage)?
                .into_iter()
                .map(Vec2::from)
                .collect())
        })
    }

    /// Accessor `index` as 3-vectors (see [`Self::read_vec`]), decoded once and shared.
    pub fn vec3(&self, index: usize, usage: &str) -> Result<Rc<[Vec3]>, GltfError> {
        self.cached(index, || {
            Ok(self
                .read_vec::<3>(index, usage)?
                .into_iter()
                .map(Vec3::from)
                .collect())
        })
    }

    /// Accessor `index` as 4-vectors (see [`Self::read_vec`]), decoded once and shared.
    pub fn vec4(&self, index: usize, usage: &str) -> Result<Rc<[Vec4]>, GltfError> {
        self.cached(index, || {
            Ok(self
                .read_vec::<4>(index, usage)?
                .into_iter()
                .map(Vec4::from)
                .collect())
        })
    }

    /// Index accessor `index` (see [`Self::read_indices`]), decoded once and shared.
    pub fn indices(&self, index: usize, usage: &str) -> Result<Rc<[u32]>, GltfError> {
        self.cached(index, || Ok(self.read_indices(index, usage)?.into()))
    }

    fn cached<T: Element>(
        &self,
        index: usize,
        read: impl FnOnce() -> Result<Rc<[T]>, GltfError>,
    ) -> Result<Rc<[T]>, GltfError> {
        let key = self.key(index, T::KIND);
        if let Some(v) = self.cache.borrow().get(&key).and_then(T::unwrap) {
            return Ok(v);
        }
        // Only successful reads are cached: a failed one ends the load.
        let v = read()?;
        self.cache.borrow_mut().insert(key, T::wrap(v.clone()));
        Ok(v)
    }

    fn key(&self, index: usize, kind: Kind) -> Key {
        let Some(acc) = self.root.accessors.get(index) else {
            return Key::Accessor(index, kind);
        };
        match (acc.buffer_view, &acc.sparse, acc.type_, acc.component_type) {
            (Some(view), None, Checked::Valid(ty), Checked::Valid(ct)) => Key::Data {
                view: view.value(),
                offset: acc.byte_offset.map_or(0, |o| o.0),
                count: acc.count.0,
                ty: type_name(ty),
                ct: component_name(ct.0),
                normalized: acc.normalized,
                kind,
            },
            _ => Key::Accessor(index, kind),
        }
    }

    pub fn root(&self) -> &'r json::Root {
        self.root
    }

    pub fn resources(&self) -> &'r Resources<'a> {
        self.res
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
        let data = self.res.view(view_index).map_err(|e| match e {
            // A compressed view's decoding error also names the accessor and its use.
            GltfError::Data { object, reason } if reason.contains("meshopt_compression") => {
                self.err(index, usage, format!("{object}: {reason}"))
            }
            e => e,
        })?;
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

    /// Reads a float vector attribute (`N` = 2, 3 or 4 components; 1 reads a SCALAR accessor, 16
    /// a MAT4 of floats) with every value finite.
    pub fn read_vec<const N: usize>(
        &self,
        index: usize,
        usage: &str,
    ) -> Result<Vec<[f32; N]>, GltfError> {
        let ty = match N {
            1 => Type::Scalar,
            2 => Type::Vec2,
            3 => Type::Vec3,
            4 => Type::Vec4,
            16 => Type::Mat4,
            _ => return Err(GltfError::Internal(format!("read_vec::<{N}>"))),
        };
        let loc = self.locate(index, usage, &[ty])?;
        // Integer matrices pad their columns to 4 bytes; only float ones are read (glTF's
        // inverseBindMatrices are float).
        if loc.ct == ComponentType::U32 || (N == 16 && loc.ct != ComponentType::F32) {
            return Err(self.err(
                index,
                usage,
                format!(
                    "componentType {} is not allowed here",
                    component_name(loc.ct)
                ),
            ));
        }
        if loc.has_view {
            let elem = (N * component_size(loc.ct)) as u64;
            let read = self
                .read_bytes
                .get()
                .saturating_add(elem.saturating_mul(loc.count as u64));
            let fetched = self.res.fetched_bytes();
            let allowed = fetched
                .saturating_mul(MAX_READ_OVERLAP)
                .saturating_add(READ_ALLOWANCE);
            if read > allowed {
                return Err(GltfError::Limit(format!(
                    "{}: the accessors read for vertex data total {read} bytes, more than \
                     {MAX_READ_OVERLAP} × the {fetched} bytes of the buffers + {READ_ALLOWANCE} \
                     (too many accessors over the same data)",
                    self.label(index, usage)
                )));
            }
            self.read_bytes.set(read);
        }
        self.decoded.set(self.decoded.get() + loc.count as u64);
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
        self.decoded.set(self.decoded.get() + loc.count as u64);
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
