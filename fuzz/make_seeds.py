#!/usr/bin/env python3
"""Writes the starting corpora of the fuzz targets (see docs/fuzzing.md).

    python3 fuzz/make_seeds.py [DIR]      # into DIR/{gltf_load,slice_decode}/, default fuzz/work/

gltf_load: tiny hand-made documents (a triangle; indexed, strip and fan primitives; a GLB with a BIN
chunk; a textured quad with a 2x2 PNG data URI and a normal map; a sparse accessor; quantized
texcoords; a node hierarchy; cameras; punctual lights; the material extensions), the loader tests'
files (crates/tracer/tests/data/gltf) and the small shipped scenes, minified.

slice_decode: slice bodies in the format of crates/wire/src/slice.rs (written here independently of
encode_slice; the replay test checks that the valid ones decode): tiles of 1x1 to 6x5 with and without
recorded invalid samples and with large sums.
"""

import base64
import json
import struct
import sys
import zlib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def png(w, h, rows, ctype=6):
    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)

    raw = b"".join(b"\x00" + r for r in rows)
    ihdr = struct.pack(">IIBBBBB", w, h, 8, ctype, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")


PNG_2x2 = png(2, 2, [bytes([255, 0, 0, 255, 0, 255, 0, 128]), bytes([0, 0, 255, 255, 255, 255, 255, 0])])
PNG_NORMAL = png(1, 1, [bytes([128, 128, 255])], ctype=2)


class Doc:
    """A glTF document under construction with one buffer."""

    def __init__(self):
        self.buf = bytearray()
        self.root = {"asset": {"version": "2.0"}, "bufferViews": [], "accessors": []}

    def view(self, data, stride=None):
        while len(self.buf) % 4:
            self.buf.append(0)
        v = {"buffer": 0, "byteOffset": len(self.buf), "byteLength": len(data)}
        if stride:
            v["byteStride"] = stride
        self.buf += data
        self.root["bufferViews"].append(v)
        return len(self.root["bufferViews"]) - 1

    def accessor(self, view, ctype, count, ty, **extra):
        a = {"componentType": ctype, "count": count, "type": ty, **extra}
        if view is not None:
            a["bufferView"] = view
        self.root["accessors"].append(a)
        return len(self.root["accessors"]) - 1

    def floats(self, rows, ty):
        flat = [x for r in rows for x in r]
        v = self.view(struct.pack(f"<{len(flat)}f", *flat))
        n = len(rows[0])
        return self.accessor(v, 5126, len(rows), ty,
                             min=[min(r[i] for r in rows) for i in range(n)],
                             max=[max(r[i] for r in rows) for i in range(n)])

    def indices(self, idx, ctype=5123):
        fmt = {5121: "B", 5123: "H", 5125: "I"}[ctype]
        return self.accessor(self.view(struct.pack(f"<{len(idx)}{fmt}", *idx)), ctype, len(idx), "SCALAR")

    def add(self, key, value):
        self.root.setdefault(key, []).append(value)
        return len(self.root[key]) - 1

    def finish(self):
        self.root["buffers"] = [{"byteLength": len(self.buf)}]
        if not self.root["accessors"]:
            del self.root["accessors"]
        if not self.root["bufferViews"]:
            del self.root["bufferViews"]

    def gltf(self):
        self.finish()
        uri = "data:application/octet-stream;base64," + base64.b64encode(bytes(self.buf)).decode()
        self.root["buffers"][0]["uri"] = uri
        return json.dumps(self.root, separators=(",", ":")).encode()

    def glb(self):
        self.finish()
        j = json.dumps(self.root, separators=(",", ":")).encode()
        j += b" " * (-len(j) % 4)
        b = bytes(self.buf) + b"\0" * (-len(self.buf) % 4)
        body = struct.pack("<I", len(j)) + b"JSON" + j + struct.pack("<I", len(b)) + b"BIN\0" + b
        return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body


TRI = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
QUAD = [[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]


def scene_with(d, mesh, extra_nodes=()):
    nodes = [d.add("nodes", {"mesh": mesh})]
    for n in extra_nodes:
        nodes.append(d.add("nodes", n))
    d.root["scenes"] = [{"nodes": nodes}]
    d.root["scene"] = 0


def triangle():
    d = Doc()
    p = d.floats(TRI, "VEC3")
    scene_with(d, d.add("meshes", {"primitives": [{"attributes": {"POSITION": p}}]}))
    return d


def gltf_seeds():
    out = {}
    out["triangle.gltf"] = triangle().gltf()
    out["triangle.glb"] = triangle().glb()

    # Indexed quad (u8, u16, u32), a strip and a fan, normals, a camera and a point light.
    d = Doc()
    p = d.floats(QUAD, "VEC3")
    n = d.floats([[0, 0, 1]] * 4, "VEC3")
    prims = [
        {"attributes": {"POSITION": p, "NORMAL": n}, "indices": d.indices([0, 1, 2, 0, 2, 3], 5121)},
        {"attributes": {"POSITION": p}, "indices": d.indices([0, 1, 3, 2], 5123), "mode": 5},
        {"attributes": {"POSITION": p}, "indices": d.indices([0, 1, 2, 3], 5125), "mode": 6},
        {"attributes": {"POSITION": p}, "mode": 1},
    ]
    cam = d.add("cameras", {"type": "perspective", "name": "cam", "perspective": {"yfov": 0.8, "znear": 0.1}})
    d.root["extensionsUsed"] = ["KHR_lights_punctual"]
    d.root["extensions"] = {"KHR_lights_punctual": {"lights": [
        {"type": "point", "intensity": 5, "color": [1, 0.5, 0.2]},
        {"type": "spot", "intensity": 9, "spot": {"innerConeAngle": 0.2, "outerConeAngle": 0.5}},
        {"type": "directional", "intensity": 2},
    ]}}
    scene_with(d, d.add("meshes", {"name": "quads", "primitives": prims}), [
        {"camera": cam, "translation": [0, 0, 3]},
        {"extensions": {"KHR_lights_punctual": {"light": 0}}, "translation": [0, 1, 2]},
        {"extensions": {"KHR_lights_punctual": {"light": 1}}, "rotation": [0.3826834, 0, 0, 0.9238795]},
        {"extensions": {"KHR_lights_punctual": {"light": 2}}, "matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]},
    ])
    out["quad_prims_lights.gltf"] = d.gltf()

    # Textured quad: base colour PNG as a data URI, normal map PNG in a buffer view, UVs, tangents,
    # a sampler, KHR_texture_transform, and every supported material extension.
    d = Doc()
    p = d.floats(QUAD, "VEC3")
    uv = d.floats([[0, 1], [1, 1], [1, 0], [0, 0]], "VEC2")
    t = d.floats([[1, 0, 0, 1]] * 4, "VEC4")
    nv = d.view(PNG_NORMAL)
    d.add("images", {"uri": "data:image/png;base64," + base64.b64encode(PNG_2x2).decode()})
    d.add("images", {"bufferView": nv, "mimeType": "image/png"})
    d.add("samplers", {"magFilter": 9728, "wrapS": 33648, "wrapT": 33071})
    d.add("textures", {"source": 0, "sampler": 0})
    d.add("textures", {"source": 1})
    ext = ["KHR_texture_transform", "KHR_materials_emissive_strength", "KHR_materials_ior",
           "KHR_materials_specular", "KHR_materials_transmission", "KHR_materials_volume"]
    d.root["extensionsUsed"] = ext
    d.root["extensionsRequired"] = ["KHR_texture_transform"]
    d.add("materials", {
        "pbrMetallicRoughness": {"baseColorTexture": {"index": 0, "extensions": {"KHR_texture_transform": {
            "offset": [0.5, 0], "rotation": 0.3, "scale": [2, 2]}}}, "metallicFactor": 0.2, "roughnessFactor": 0.4},
        "normalTexture": {"index": 1, "scale": 0.5},
        "emissiveFactor": [1, 1, 1],
        "alphaMode": "MASK", "alphaCutoff": 0.3, "doubleSided": True,
        "extensions": {
            "KHR_materials_emissive_strength": {"emissiveStrength": 3},
            "KHR_materials_ior": {"ior": 1.4},
            "KHR_materials_specular": {"specularFactor": 0.5, "specularColorFactor": [1, 0.9, 0.8]},
            "KHR_materials_transmission": {"transmissionFactor": 0.5},
            "KHR_materials_volume": {"thicknessFactor": 0.1, "attenuationDistance": 2,
                                     "attenuationColor": [0.9, 0.8, 0.7]},
        },
    })
    prim = {"attributes": {"POSITION": p, "TEXCOORD_0": uv, "TANGENT": t},
            "indices": d.indices([0, 1, 2, 0, 2, 3]), "material": 0}
    scene_with(d, d.add("meshes", {"primitives": [prim]}))
    out["textured_quad.gltf"] = d.gltf()
    out["textured_quad.glb"] = d.glb()

    # Sparse accessor (no bufferView: zeros, then two replaced vertices), quantized u16 texcoords,
    # an interleaved (strided) view, a hierarchy with TRS, a negative scale and an orthographic camera.
    d = Doc()
    inter = d.view(struct.pack("<12f", *[x for v in TRI for x in (v + [0, 0, 1])][:12]) + bytes(24), stride=24)
    p = d.accessor(inter, 5126, 3, "VEC3", min=[0, 0, 0], max=[1, 1, 1])
    sp_idx = d.view(struct.pack("<2H", 1, 2))
    sp_val = d.view(struct.pack("<6f", 1, 0, 0, 0, 1, 0))
    ps = d.accessor(None, 5126, 3, "VEC3", min=[0, 0, 0], max=[1, 1, 0], sparse={
        "count": 2, "indices": {"bufferView": sp_idx, "componentType": 5123},
        "values": {"bufferView": sp_val}})
    q = d.accessor(d.view(struct.pack("<6H", 0, 0, 65535, 0, 0, 65535)), 5123, 3, "VEC2", normalized=True)
    d.root["extensionsUsed"] = ["KHR_mesh_quantization"]
    d.root["extensionsRequired"] = ["KHR_mesh_quantization"]
    m = d.add("meshes", {"primitives": [{"attributes": {"POSITION": ps, "TEXCOORD_0": q}},
                                        {"attributes": {"POSITION": p}}]})
    cam = d.add("cameras", {"type": "orthographic",
                            "orthographic": {"xmag": 1, "ymag": 1, "znear": 0.01, "zfar": 100}})
    d.root["nodes"] = [
        {"children": [1, 2], "translation": [0, 0, -1], "scale": [1, -1, 1]},
        {"mesh": m, "rotation": [0, 0.7071068, 0, 0.7071068]},
        {"camera": cam, "name": "ortho", "translation": [0, 0, 5]},
    ]
    d.root["scenes"] = [{"nodes": [0]}]
    out["sparse_quantized_hierarchy.gltf"] = d.gltf()

    for path in sorted((ROOT / "crates/tracer/tests/data/gltf").rglob("*")):
        if path.suffix in (".gltf", ".glb"):
            out[f"testdata_{path.parent.name}_{path.name}"] = path.read_bytes()
    for name in ["cornell.gltf", "furnacebox.gltf", "smalllight.gltf"]:
        text = json.loads((ROOT / "scenes" / name).read_text())
        out[f"scene_{name}"] = json.dumps(text, separators=(",", ":")).encode()
    return out


def varint(v):
    out = bytearray()
    while True:
        b = v & 0x7F
        v >>= 7
        if v == 0:
            out.append(b)
            return bytes(out)
        out.append(b | 0x80)


def fnv1a64(data):
    h = 0xCBF29CE484222325
    for b in data:
        h = ((h ^ b) * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return h


def slice_body(x0, y0, w, h, begin, end, rays, invalid, recorded, pixels):
    out = bytearray(b"PFSL" + struct.pack("<HH", 1, 0) + struct.pack("<6I", x0, y0, w, h, begin, end))
    out += varint(rays) + varint(invalid) + varint(len(recorded))
    for s in recorded:
        out += b"".join(varint(v) for v in s)
    for count, r, g, b, y2 in pixels:
        out += varint(count) + varint(r) + varint(g) + varint(b) + varint(y2)
    return bytes(out + struct.pack("<Q", fnv1a64(out)))


def slice_seeds():
    out = {}
    one = 1 << 32  # 1.0 in the accumulation's fixed point
    out["1x1.slice"] = slice_body(0, 0, 1, 1, 0, 1, 3, 0, [], [(1, one // 2, one // 4, one // 8, one // 9)])
    out["2x2_invalid.slice"] = slice_body(
        8, 16, 2, 2, 4, 8, 40, 2, [(8, 16, 5), (9, 17, 7)],
        [(4, 4 * one, 3 * one, 2 * one, 5 * one), (3, one, one, one, one), (4, 0, 0, 0, 0), (3, 7, 8, 9, 10)])
    big = (1 << 64) - 1
    out["3x1_large_sums.slice"] = slice_body(
        100, 200, 3, 1, 0, 1000, 1 << 40, 0, [],
        [(1000, big * 900, big * 999, big, (1 << 96) * 999), (0, 0, 0, 0, 0), (17, 123456789, 1, 2, 3)])
    pixels = [(2, (i * 7919) % (3 * one), (i * 104729) % one, i, i * i) for i in range(30)]
    out["6x5.slice"] = slice_body(32, 32, 6, 5, 1, 3, 1234, 0, [], pixels)
    out["edge_coords.slice"] = slice_body(
        0xFFFFFFF0, 0xFFFFFFF0, 2, 1, 0xFFFFFFF0, 0xFFFFFFFF, 1, 1, [(0xFFFFFFF1, 0xFFFFFFF0, 0xFFFFFFFE)],
        [(5, 1, 1, 1, 1), (0, 0, 0, 0, 0)])
    # An invalid count near the top of its range: lets mutations reach counts near 2^64.
    out["huge_invalid_count.slice"] = slice_body(
        4, 4, 2, 1, 10, 20, 7, 1 << 63, [(5, 4, 19)], [(3, 1, 1, 1, 1), (10, 5, 6, 7, 8)])
    return out


def main():
    base = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "fuzz" / "work"
    for target, files in [("gltf_load", gltf_seeds()), ("slice_decode", slice_seeds())]:
        d = base / target
        d.mkdir(parents=True, exist_ok=True)
        for name, data in files.items():
            (d / name).write_bytes(data)
        print(f"{d}: {len(files)} files, {sum(len(v) for v in files.values())} bytes")


if __name__ == "__main__":
    main()
