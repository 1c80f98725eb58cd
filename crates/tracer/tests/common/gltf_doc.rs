//! A small glTF document builder for tests: JSON built as a `serde_json` value, one binary
//! buffer embedded as a base64 data URI. Included with `#[path]` by the tests that build files.
#![allow(dead_code)]

use base64::Engine as _;
use gltf::json::Value;

pub fn j(s: &str) -> Value {
    gltf::json::deserialize::from_str(s).unwrap()
}

#[derive(Clone)]
pub struct Doc {
    pub json: Value,
    pub bin: Vec<u8>,
}

impl Default for Doc {
    fn default() -> Self {
        Self::new()
    }
}

impl Doc {
    pub fn new() -> Self {
        Doc {
            json: j(
                r#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[]}],"nodes":[],
                "meshes":[],"accessors":[],"bufferViews":[]}"#,
            ),
            bin: Vec::new(),
        }
    }

    pub fn push(&mut self, key: &str, v: Value) -> usize {
        if !self.json[key].is_array() {
            self.json[key] = Value::Array(Vec::new());
        }
        let arr = self.json[key].as_array_mut().unwrap();
        arr.push(v);
        arr.len() - 1
    }

    /// An accessor over new bytes in the buffer.
    fn accessor(&mut self, bytes: &[u8], component_type: u32, count: usize, ty: &str) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        let view = self.push(
            "bufferViews",
            j(&format!(
                r#"{{"buffer":0,"byteOffset":{offset},"byteLength":{}}}"#,
                bytes.len()
            )),
        );
        self.push(
            "accessors",
            j(&format!(
                r#"{{"bufferView":{view},"componentType":{component_type},"count":{count},"type":"{ty}"}}"#
            )),
        )
    }

    /// A float accessor of `N`-vectors (1: SCALAR, 16: MAT4).
    pub fn floats<const N: usize>(&mut self, v: &[[f32; N]]) -> usize {
        let bytes: Vec<u8> = v.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        let ty = match N {
            1 => "SCALAR",
            2 => "VEC2",
            3 => "VEC3",
            4 => "VEC4",
            16 => "MAT4",
            _ => panic!("no accessor type of {N} components"),
        };
        self.accessor(&bytes, 5126, v.len(), ty)
    }

    /// Keyframe times (with the min and max glTF asks of animation inputs).
    pub fn times(&mut self, t: &[f32]) -> usize {
        let a = self.floats(&t.iter().map(|&x| [x]).collect::<Vec<_>>());
        let (lo, hi) = t
            .iter()
            .fold((f32::MAX, f32::MIN), |(l, h), &x| (l.min(x), h.max(x)));
        self.json["accessors"][a]["min"] = Value::from(vec![lo]);
        self.json["accessors"][a]["max"] = Value::from(vec![hi]);
        a
    }

    /// A POSITION accessor (with its min and max).
    pub fn positions(&mut self, p: &[[f32; 3]]) -> usize {
        let a = self.floats(p);
        let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
        for v in p {
            for k in 0..3 {
                lo[k] = lo[k].min(v[k]);
                hi[k] = hi[k].max(v[k]);
            }
        }
        self.json["accessors"][a]["min"] = Value::from(lo.to_vec());
        self.json["accessors"][a]["max"] = Value::from(hi.to_vec());
        a
    }

    /// An UNSIGNED_SHORT VEC4 accessor (JOINTS_n).
    pub fn joints(&mut self, v: &[[u16; 4]]) -> usize {
        let bytes: Vec<u8> = v.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        self.accessor(&bytes, 5123, v.len(), "VEC4")
    }

    /// A u32 index accessor.
    pub fn indices(&mut self, idx: &[u32]) -> usize {
        let bytes: Vec<u8> = idx.iter().flat_map(|x| x.to_le_bytes()).collect();
        self.accessor(&bytes, 5125, idx.len(), "SCALAR")
    }

    pub fn node(&mut self, v: Value) -> usize {
        self.push("nodes", v)
    }

    pub fn root(&mut self, node: usize) {
        self.json["scenes"][0]["nodes"]
            .as_array_mut()
            .unwrap()
            .push(Value::from(node));
    }

    /// Adds an animation of channels (node, path, input accessor, output accessor,
    /// interpolation), each with a sampler of its own.
    pub fn animation(&mut self, name: &str, channels: &[(usize, &str, usize, usize, &str)]) {
        let mut samplers = Vec::new();
        let mut chans = Vec::new();
        for (k, &(node, path, input, output, interpolation)) in channels.iter().enumerate() {
            samplers.push(j(&format!(
                r#"{{"input":{input},"output":{output},"interpolation":"{interpolation}"}}"#
            )));
            chans.push(j(&format!(
                r#"{{"sampler":{k},"target":{{"node":{node},"path":"{path}"}}}}"#
            )));
        }
        let mut a = j(&format!(r#"{{"name":"{name}"}}"#));
        a["samplers"] = Value::Array(samplers);
        a["channels"] = Value::Array(chans);
        self.push("animations", a);
    }

    /// `.gltf` bytes with the buffer as a base64 data URI.
    pub fn gltf(&self) -> Vec<u8> {
        let mut json = self.json.clone();
        if !self.bin.is_empty() {
            let uri = format!(
                "data:application/octet-stream;base64,{}",
                base64::engine::general_purpose::STANDARD.encode(&self.bin)
            );
            json["buffers"] = j(&format!(
                r#"[{{"byteLength":{},"uri":"{uri}"}}]"#,
                self.bin.len()
            ));
        }
        gltf::json::serialize::to_vec(&json).unwrap()
    }
}
