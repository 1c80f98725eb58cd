use super::*;

// ---------------------------------------------------------------------------------------------
// Fuzzing: mutated files load or fail, never panic.

/// Iterations per fuzz test: `GLTF_FUZZ_ITERATIONS` (default 3000) — raise it for a longer hunt.
fn fuzz_iterations() -> usize {
    std::env::var("GLTF_FUZZ_ITERATIONS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3000)
}

struct XorShift(u64);

impl XorShift {
    fn next(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.0 = x;
        x
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

fn mutate(rng: &mut XorShift, input: &[u8]) -> Vec<u8> {
    let mut b = input.to_vec();
    for _ in 0..1 + rng.below(4) {
        if b.is_empty() {
            break;
        }
        let at = rng.below(b.len());
        match rng.below(7) {
            0 => b[at] = rng.next() as u8,
            1 => b[at] ^= 1 << rng.below(8),
            2 => b.truncate(at),
            3 => {
                let v = [0u32, 1, 0xFFFF_FFFF, 0x7FFF_FFFF, 99999, rng.next() as u32][rng.below(6)];
                for (k, byte) in v.to_le_bytes().iter().enumerate() {
                    if let Some(slot) = b.get_mut(at + k) {
                        *slot = *byte;
                    }
                }
            }
            4 => {
                // Change a digit in JSON text: valid JSON with wrong numbers.
                if let Some(pos) = (0..64)
                    .map(|k| (at + k) % b.len())
                    .find(|&p| b[p].is_ascii_digit())
                {
                    b[pos] = b"0123456789"[rng.below(10)];
                }
            }
            5 => {
                if let Some(pos) = (0..64)
                    .map(|k| (at + k) % b.len())
                    .find(|&p| b[p].is_ascii_digit())
                {
                    let ins: &[u8] = [&b"9"[..], b"0", b"-", b"e9", b"99999"][rng.below(5)];
                    b.splice(pos..pos, ins.iter().copied());
                }
            }
            _ => b.insert(at, rng.next() as u8),
        }
    }
    b
}

fn fuzz(seed: u64, input: &[u8], iterations: usize) -> (usize, usize) {
    let mut rng = XorShift(seed);
    let (mut ok, mut err) = (0, 0);
    for k in 0..iterations {
        let bytes = mutate(&mut rng, input);
        let outcome = std::panic::catch_unwind(|| {
            load(&bytes, &NoExternalResources, &LoadOptions::default())
        });
        match outcome {
            Ok(Ok(_)) => ok += 1,
            Ok(Err(GltfError::Internal(e))) => {
                panic!("iteration {k}: the loader panicked internally: {e}")
            }
            Ok(Err(_)) => err += 1,
            Err(_) => panic!("iteration {k}: load panicked"),
        }
    }
    eprintln!("fuzz seed {seed:#x}: {ok} loaded, {err} refused");
    (ok, err)
}

fn fuzz_seed_doc() -> Doc {
    let mut d = textured_doc(&png(2, 2, &[90; 16]));
    let n = d.floats(&[[0.0f32, 0.0, 1.0]; 3]);
    let uv = d.floats(&[[0.0f32, 0.0], [1.0, 0.0], [0.0, 1.0]]);
    let i = d.indices(&[0, 1, 2], 5123);
    let prim = &mut d.json["meshes"][0]["primitives"][0];
    prim["attributes"]["NORMAL"] = Value::from(n);
    prim["attributes"]["TEXCOORD_0"] = Value::from(uv);
    prim["indices"] = Value::from(i);
    d.json["materials"][0]["normalTexture"] = j(r#"{"index":0}"#);
    d.json["extensionsUsed"] = j(r#"["KHR_lights_punctual"]"#);
    d.json["extensions"] =
        j(r#"{"KHR_lights_punctual":{"lights":[{"type":"spot","spot":{"outerConeAngle":0.5}}]}}"#);
    let l = d.node(j(
        r#"{"translation":[0,0,2],"extensions":{"KHR_lights_punctual":{"light":0}}}"#,
    ));
    d.json["nodes"][0]["children"] = Value::Array(vec![Value::from(l)]);
    d.push(
        "cameras",
        j(r#"{"type":"perspective","perspective":{"yfov":0.8,"znear":0.1}}"#),
    );
    let c = d.node(j(r#"{"camera":0,"translation":[0,0,3]}"#));
    d.root(c);
    d
}

#[test]
fn fuzz_glb_never_panics() {
    let glb = fuzz_seed_doc().glb();
    assert!(load(&glb, &NoExternalResources, &LoadOptions::default()).is_ok());
    let n = fuzz_iterations();
    let (ok, err) = fuzz(0x9E37_79B9_7F4A_7C15, &glb, n);
    assert!(err > 0 && ok + err == n, "ok {ok}, err {err}");
}

#[test]
fn fuzz_gltf_never_panics() {
    let gltf = fuzz_seed_doc().gltf();
    assert!(load(&gltf, &NoExternalResources, &LoadOptions::default()).is_ok());
    let n = fuzz_iterations();
    let (ok, err) = fuzz(0xD1B5_4A32_D192_ED03, &gltf, n);
    assert!(err > 0 && ok + err == n, "ok {ok}, err {err}");
}

/// Structure-aware mutations: valid JSON with wrong numbers, missing keys, and corrupted binary data,
/// so that the fuzz loop reaches accessors, materials, textures and the scene build.
fn mutate_structured(rng: &mut XorShift, doc: &Doc) -> Vec<u8> {
    /// Calls `f` on the `target`-th node (pre-order) for which `pick` holds, counting them in `seen`.
    fn walk(
        v: &mut Value,
        pick: fn(&Value) -> bool,
        target: usize,
        seen: &mut usize,
        f: &mut dyn FnMut(&mut Value),
    ) {
        if pick(v) {
            if *seen == target {
                f(v);
            }
            *seen += 1;
        }
        match v {
            Value::Array(a) => a.iter_mut().for_each(|x| walk(x, pick, target, seen, f)),
            Value::Object(o) => o.values_mut().for_each(|x| walk(x, pick, target, seen, f)),
            _ => {}
        }
    }
    fn count(v: &mut Value, pick: fn(&Value) -> bool) -> usize {
        let mut seen = 0;
        walk(v, pick, usize::MAX, &mut seen, &mut |_| {});
        seen
    }
    let mut d = doc.clone();
    for _ in 0..1 + rng.below(3) {
        match rng.below(4) {
            0 | 1 => {
                let specials: [f64; 16] = [
                    0.0,
                    1.0,
                    -1.0,
                    2.0,
                    3.0,
                    7.0,
                    255.0,
                    65535.0,
                    1e9,
                    4294967295.0,
                    0.5,
                    1e38,
                    -1e38,
                    5121.0,
                    5125.0,
                    1e300,
                ];
                let value = if rng.below(4) == 0 {
                    (rng.next() % 100_000) as f64
                } else {
                    specials[rng.below(specials.len())]
                };
                let new = if value.fract() == 0.0 && value.abs() < 1e15 {
                    Value::from(value as i64)
                } else {
                    Value::from(value)
                };
                let n = count(&mut d.json, Value::is_number);
                let target = rng.below(n);
                walk(&mut d.json, Value::is_number, target, &mut 0, &mut |v| {
                    *v = new.clone()
                });
            }
            2 => {
                let n = count(&mut d.json, Value::is_object);
                let target = rng.below(n);
                let key_pick = rng.next() as usize;
                walk(&mut d.json, Value::is_object, target, &mut 0, &mut |v| {
                    if let Value::Object(o) = v {
                        if let Some(key) = o.keys().nth(key_pick % o.len().max(1)).cloned() {
                            o.remove(&key);
                        }
                    }
                });
            }
            _ => {
                if !d.bin.is_empty() {
                    for _ in 0..1 + rng.below(8) {
                        let at = rng.below(d.bin.len());
                        d.bin[at] = [0x00, 0xFF, 0x7F, 0xC0, rng.next() as u8][rng.below(5)];
                    }
                }
            }
        }
    }
    if rng.below(2) == 0 {
        d.glb()
    } else {
        d.gltf()
    }
}

#[test]
fn fuzz_structured_never_panics() {
    let doc = fuzz_seed_doc();
    let mut rng = XorShift(0x2545_F491_4F6C_DD1D);
    let (mut ok, mut err) = (0, 0);
    let mut kinds: HashMap<&'static str, usize> = HashMap::new();
    for k in 0..fuzz_iterations() {
        let bytes = mutate_structured(&mut rng, &doc);
        let outcome = std::panic::catch_unwind(|| {
            load(&bytes, &NoExternalResources, &LoadOptions::default())
        });
        match outcome {
            Ok(Ok(_)) => ok += 1,
            Ok(Err(GltfError::Internal(e))) => {
                panic!("iteration {k}: the loader panicked internally: {e}")
            }
            Ok(Err(e)) => {
                err += 1;
                let kind = match e {
                    GltfError::NotGltf(_) => "not-gltf",
                    GltfError::Glb(_) => "glb",
                    GltfError::Invalid(_) => "invalid",
                    GltfError::UnsupportedExtension(_) => "extension",
                    GltfError::Resource { .. } => "resource",
                    GltfError::Data { .. } => "data",
                    GltfError::Image { .. } => "image",
                    GltfError::Object { .. } => "object",
                    GltfError::CameraNotFound { .. } => "camera",
                    GltfError::Limit(_) => "limit",
                    GltfError::Scene(_) => "scene",
                    _ => "other",
                };
                *kinds.entry(kind).or_default() += 1;
            }
            Err(_) => panic!("iteration {k}: load panicked"),
        }
    }
    eprintln!("structured fuzz: {ok} loaded, {err} refused: {kinds:?}");
    assert!(
        ok > 100 && kinds.len() >= 4,
        "the mutations should reach deep into the loader"
    );
}
