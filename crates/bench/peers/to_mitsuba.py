"""Converts the current Blender scene into a Mitsuba 3 scene description: a JSON file plus binary
little-endian PLY meshes, read by mitsuba_render.py (which runs in Mitsuba's own Python).

Runs inside bpy. Only what has an exact counterpart is accepted (anything else raises):

- meshes: the evaluated mesh of every visible mesh object, triangulated (loop triangles). A mesh
  used by one object is written in world space; a mesh shared by several objects (Blender linked
  duplicates) is written once in object space as a Mitsuba `shapegroup`, and each object becomes
  an `instance` with its world matrix. Smooth-shaded faces get Blender's corner normals (vertex
  normals on smooth faces, the face normal on flat faces of a mixed mesh); a mesh with no smooth
  face is written without normals (Mitsuba then shades with the face normal);
- materials (Principled BSDF inputs): Lambertian -> `diffuse`, perfect mirror -> `conductor`
  with `material: none` (reflectance 1), both wrapped in `twosided` (Cycles shades both sides;
  Mitsuba's diffuse and conductor are black from behind); smooth glass -> `dielectric` with
  int_ior = the IOR, ext_ior 1; an emissive black Lambertian -> an `area` emitter with radiance
  colour x strength on a black `diffuse`;
- textures (Lambertians only): an sRGB Image Texture node (Linear, Repeat, Flat, the default
  UV map) on Base Color -> a `bitmap` reflectance (bilinear, repeat); a Non-Color one through a
  tangent-space Normal Map node of strength 1 on Normal -> the `diffuse` wrapped in `normalmap`
  (its frame follows dP/du, which equals the MikkTSpace tangent of Cycles and the tracer on flat
  faces with unmirrored UVs: scenes.py puts normal maps only there). Textured meshes carry their
  UVs (v flipped: 1 - v) in the PLY;
- emitters are two-sided in Cycles (and exported doubleSided for the tracer) but one-sided in
  Mitsuba: an open emissive mesh gets a face-flipped copy of its triangles, displaced by
  FLIP_OFFSET behind the original, in the same shape (so one emitter, as in Blender). A closed
  emissive mesh (every edge shared by exactly two triangles) is seen only from outside and is
  written as it is;
- lamps: POINT (radius 0) -> `point` with intensity P / (4 pi) x colour [W/sr]; SUN (angle 0) ->
  `directional` with irradiance S x colour along the lamp's -Z; SPOT (radius 0, spot_blend 0)
  -> `spot` with the same intensity and cutoff_angle = beam_width = spot_size / 2;
- world: a uniform Background colour x strength -> `constant`;
- camera: `perspective` with fov = 2 atan(sensor_width / 2 / lens) on the larger image axis
  (Blender's sensor fit AUTO; fov_axis "larger"), to_world = look_at(origin, origin + forward,
  up) with forward = the camera's -Z column and up its +Y column.

Coordinates stay Blender's (Z-up): Mitsuba has no preferred up axis.
"""

import json
import math
import os
import shutil
import tempfile

import bpy
import numpy as np

# Distance between an open emitter's triangles and their flipped copy (metres). Small against every
# feature of the scenes (the smallest emitter is 1 cm wide) and much larger than the float spacing
# of coordinates of a few metres (~2.4e-7), so the nearest copy is always the one facing the ray.
FLIP_OFFSET = 1e-5


class Unsupported(Exception):
    pass


def _close(a, b, tol=1e-6):
    return abs(a - b) <= tol


def principled(mat):
    if mat is None or not mat.use_nodes:
        raise Unsupported(f"material {mat and mat.name}: no Principled BSDF")
    nodes = [n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED"]
    if len(nodes) != 1:
        raise Unsupported(f"material {mat.name}: expected one Principled BSDF")
    p = nodes[0]
    out = [n for n in mat.node_tree.nodes if n.type == "OUTPUT_MATERIAL"]
    for o in out:
        if o.inputs["Volume"].is_linked or o.inputs["Displacement"].is_linked:
            raise Unsupported(f"material {mat.name}: volume or displacement")
    for name, inp in p.inputs.items():
        if inp.is_linked and name not in ("Base Color", "Normal"):
            raise Unsupported(f"material {mat.name}: input {name} is linked")
    return p


def image_node(mat, socket, colorspace):
    """The Image Texture node feeding `socket` directly, checked to have the exact counterpart
    of a glTF texture and a Mitsuba `bitmap` (bilinear, repeat, the default UV map), and its
    image's file (a PNG on disk)."""
    links = socket.links
    node = links[0].from_node if links else None
    if node is None or node.type != "TEX_IMAGE" or links[0].from_socket.name != "Color":
        raise Unsupported(f"material {mat.name}: {socket.name} is not an image's colour")
    if node.interpolation != "Linear" or node.extension != "REPEAT" or \
            node.projection != "FLAT" or node.inputs["Vector"].is_linked:
        raise Unsupported(f"material {mat.name}: image {node.image.name} is not sampled "
                          "bilinearly with repeat at the mesh's UVs")
    img = node.image
    if img.colorspace_settings.name != colorspace:
        raise Unsupported(f"material {mat.name}: image {img.name} is not {colorspace}")
    if img.packed_file is not None:  # the PNG's bytes, written out for Mitsuba
        data = bytes(img.packed_file.data)
        if not data.startswith(b"\x89PNG"):
            raise Unsupported(f"material {mat.name}: image {img.name} is not a PNG")
        safe = "".join(ch if ch.isalnum() else "_" for ch in img.name)
        path = os.path.join(tempfile.gettempdir(), f"pathfarm_peers_{safe}.png")
        with open(path, "wb") as f:
            f.write(data)
        return path
    path = bpy.path.abspath(img.filepath)
    if not path.lower().endswith(".png") or not os.path.isfile(path):
        raise Unsupported(f"material {mat.name}: image {img.name} is not a PNG file")
    return path


def textured(mat):
    """Whether an image feeds the material's Principled BSDF (its mesh then needs its UVs)."""
    p = principled(mat)
    return p.inputs["Base Color"].is_linked or p.inputs["Normal"].is_linked


def bitmap(path, raw):
    """A Mitsuba `bitmap` of the PNG at `path` (copied beside the scene by `export`), filtered as
    Cycles' Linear and glTF's LINEAR: bilinear, repeat; sRGB decoded unless raw."""
    return {"type": "bitmap", "filename": path, "filter_type": "bilinear",
            "wrap_mode": "repeat", "raw": raw}


def base_color(mat, p):
    """The Mitsuba reflectance of the Base Color input: a uniform RGB or an sRGB image."""
    inp = p.inputs["Base Color"]
    if inp.is_linked:
        return bitmap(image_node(mat, inp, "sRGB"), raw=False)
    return {"type": "rgb", "value": [float(x) for x in inp.default_value[:3]]}


def normal_map(mat, p):
    """The PNG of the tangent-space normal map feeding the Normal input through a Normal Map
    node of strength 1, or None."""
    inp = p.inputs["Normal"]
    if not inp.is_linked:
        return None
    node = inp.links[0].from_node
    if node.type != "NORMAL_MAP" or node.space != "TANGENT" or node.uv_map != "" or \
            node.inputs["Strength"].is_linked or node.inputs["Strength"].default_value != 1.0:
        raise Unsupported(f"material {mat.name}: Normal is not a tangent-space Normal Map "
                          "node of strength 1")
    return image_node(mat, node.inputs["Color"], "Non-Color")


def classify(mat):
    """The Mitsuba BSDF dict of a Blender material and its emitted radiance (or None)."""
    p = principled(mat)
    v = lambda k: p.inputs[k].default_value  # noqa: E731
    base = [float(x) for x in v("Base Color")[:3]]  # unused where an image feeds it
    metallic, rough = float(v("Metallic")), float(v("Roughness"))
    spec, trans = float(v("Specular IOR Level")), float(v("Transmission Weight"))
    strength = float(v("Emission Strength"))
    emission = [float(x) * strength for x in v("Emission Color")[:3]]
    for k in ("Coat Weight", "Sheen Weight", "Subsurface Weight", "Thin Film Thickness"):
        if k in p.inputs and float(v(k)) != 0.0:
            raise Unsupported(f"material {mat.name}: {k} is not 0")
    if float(v("Alpha")) != 1.0:
        raise Unsupported(f"material {mat.name}: alpha")
    emits = strength > 0 and max(emission) > 0
    textured = p.inputs["Base Color"].is_linked or p.inputs["Normal"].is_linked
    if textured and not (metallic == 0.0 and spec == 0.0 and trans == 0.0 and not emits):
        raise Unsupported(f"material {mat.name}: textures only on a Lambertian")
    if emits:
        if max(base) != 0 or spec != 0 or metallic != 0 or trans != 0:
            raise Unsupported(f"material {mat.name}: emitter must be a black Lambertian")
        return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}, \
            emission
    if trans == 1.0 and metallic == 0.0:
        if rough != 0.0 or any(not _close(c, 1.0) for c in base) or not _close(spec, 0.5):
            raise Unsupported(f"material {mat.name}: glass must be smooth, white, specular 0.5")
        return {"type": "dielectric", "int_ior": float(v("IOR")), "ext_ior": 1.0}, None
    if trans != 0.0:
        raise Unsupported(f"material {mat.name}: partial transmission")
    if metallic == 1.0:
        if rough != 0.0 or any(not _close(c, 1.0) for c in base):
            raise Unsupported(f"material {mat.name}: metal must be a perfect mirror")
        return {"type": "twosided", "bsdf": {"type": "conductor", "material": "none"}}, None
    if metallic == 0.0 and spec == 0.0:
        bsdf = {"type": "diffuse", "reflectance": base_color(mat, p)}
        nmap = normal_map(mat, p)
        if nmap is not None:
            bsdf = {"type": "normalmap", "normalmap": bitmap(nmap, raw=True), "bsdf": bsdf}
        return {"type": "twosided", "bsdf": bsdf}, None
    raise Unsupported(f"material {mat.name}: neither Lambertian, mirror, glass nor emitter")


def write_ply(path, positions, normals, faces, uvs=None):
    """Binary little-endian PLY: float32 x y z [nx ny nz] [u v], uint8 count + int32 indices."""
    n, m = len(positions), len(faces)
    props = "property float x\nproperty float y\nproperty float z\n"
    cols = [positions.astype(np.float32)]
    if normals is not None:
        props += "property float nx\nproperty float ny\nproperty float nz\n"
        cols.append(normals.astype(np.float32))
    if uvs is not None:
        props += "property float u\nproperty float v\n"
        cols.append(uvs.astype(np.float32))
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\n{props}"
              f"element face {m}\nproperty list uchar int vertex_indices\nend_header\n")
    verts = np.ascontiguousarray(np.hstack(cols), dtype="<f4")
    fdt = np.dtype([("n", "u1"), ("i", "<i4", (3,))])
    f = np.empty(m, dtype=fdt)
    f["n"] = 3
    f["i"] = faces
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(verts.tobytes())
        fh.write(f.tobytes())


def mesh_arrays(obj, depsgraph, with_uv=False):
    """Triangles of the evaluated mesh in object space: (positions, normals or None, faces,
    material index per triangle, closed?, UVs or None). With `with_uv`, the active UV map, v
    flipped (1 - v: Mitsuba's bitmaps, like glTF, put the image's top row at v = 0, Blender its
    bottom row)."""
    ev = obj.evaluated_get(depsgraph)
    me = ev.to_mesh()
    try:
        me.calc_loop_triangles()
        nt = len(me.loop_triangles)
        loops = np.empty(nt * 3, dtype=np.int64)
        me.loop_triangles.foreach_get("loops", loops)
        smooth = np.empty(nt, dtype=bool)
        me.loop_triangles.foreach_get("use_smooth", smooth)
        mat_idx = np.empty(nt, dtype=np.int64)
        me.loop_triangles.foreach_get("material_index", mat_idx)
        vidx = np.empty(len(me.loops), dtype=np.int64)
        me.loops.foreach_get("vertex_index", vidx)
        co = np.empty(len(me.vertices) * 3, dtype=np.float64)
        me.vertices.foreach_get("co", co)
        co = co.reshape(-1, 3)
        tri_v = vidx[loops].reshape(-1, 3)
        closed = edges_closed(tri_v)
        uv = None
        if with_uv:
            if me.uv_layers.active is None:
                raise Unsupported(f"object {obj.name}: a texture but no UV map")
            uv = np.empty(len(me.loops) * 2, dtype=np.float64)
            me.uv_layers.active.data.foreach_get("uv", uv)
            uv = uv.reshape(-1, 2)[loops]
            uv[:, 1] = 1.0 - uv[:, 1]
        if smooth.any() or uv is not None:
            # One vertex per distinct (vertex, corner normal, UV).
            cols = [vidx[loops][:, None].astype(np.float64)]
            cn = None
            if smooth.any():
                cn = np.empty(len(me.loops) * 3, dtype=np.float64)
                me.corner_normals.foreach_get("vector", cn)
                cn = cn.reshape(-1, 3)[loops]
                cols.append(np.round(cn, 6))
            if uv is not None:
                cols.append(uv)
            uniq, first, inv = np.unique(np.hstack(cols), axis=0, return_index=True,
                                         return_inverse=True)
            positions = co[vidx[loops][first]]
            normals = None if cn is None else cn[first]
            uvs = None if uv is None else uv[first]
            faces = inv.reshape(-1, 3)
        else:
            used, inv = np.unique(tri_v.ravel(), return_inverse=True)
            positions = co[used]
            normals = None
            uvs = None
            faces = inv.reshape(-1, 3)
        return positions, normals, faces, mat_idx, closed, uvs
    finally:
        ev.to_mesh_clear()


def edges_closed(tri_v):
    e = np.concatenate([tri_v[:, [0, 1]], tri_v[:, [1, 2]], tri_v[:, [2, 0]]])
    e.sort(axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return bool((counts == 2).all())


def to_world(m, positions, normals):
    M = np.array(m, dtype=np.float64)
    p = positions @ M[:3, :3].T + M[:3, 3]
    n = None
    if normals is not None:
        nm = np.linalg.inv(M[:3, :3]).T
        n = normals @ nm.T
        n /= np.linalg.norm(n, axis=1, keepdims=True)
    return p, n


def flipped_copy(positions, normals, faces):
    """Appends the triangles with reversed winding, moved FLIP_OFFSET along their back side."""
    a, b, c = (positions[faces[:, k]] for k in range(3))
    fn = np.cross(b - a, c - a)
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    # Per-vertex offset direction: the mean face normal at the vertex (planar emitters: exact).
    vn = np.zeros_like(positions)
    for k in range(3):
        np.add.at(vn, faces[:, k], fn)
    vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-30)
    back = positions - FLIP_OFFSET * vn
    pos = np.vstack([positions, back])
    nrm = None if normals is None else np.vstack([normals, -normals])
    fl = faces[:, ::-1] + len(positions)
    return pos, nrm, np.vstack([faces, fl])


def copy_images(bsdf, mesh_dir, out_dir):
    """The BSDF dict with every bitmap's PNG copied beside the meshes and named relative to
    out_dir (mitsuba_render.py resolves it against the scene file's folder)."""
    if isinstance(bsdf, dict):
        out = {k: copy_images(v, mesh_dir, out_dir) for k, v in bsdf.items()}
        if out.get("type") == "bitmap":
            dst = os.path.join(mesh_dir, os.path.basename(out["filename"]))
            shutil.copyfile(out["filename"], dst)
            out["filename"] = os.path.relpath(dst, out_dir)
        return out
    return bsdf


def matrix_list(m):
    return [[float(m[i][j]) for j in range(4)] for i in range(4)]


def export(out_dir, name, width, height):
    """Writes out_dir/NAME.mitsuba.json and its PLY files; returns the JSON path and a summary."""
    sc = bpy.context.scene
    depsgraph = bpy.context.evaluated_depsgraph_get()
    mesh_dir = os.path.join(out_dir, f"{name}_mitsuba_meshes")
    os.makedirs(mesh_dir, exist_ok=True)
    desc = {"width": width, "height": height, "bsdfs": {}, "shapes": [], "shapegroups": [],
            "instances": [], "emitters": []}
    summary = {"triangles": 0, "instanced_triangles": 0, "shapes": 0, "instances": 0,
               "flipped_emitters": [], "closed_emitters": []}

    users = {}
    for o in sc.objects:
        if o.type == "MESH" and not o.hide_render:
            users.setdefault(o.data.name, []).append(o)

    def bsdf_of(obj):
        mats = [s.material for s in obj.material_slots]
        if len(mats) != 1:
            raise Unsupported(f"object {obj.name}: expected exactly one material")
        return mats[0]

    groups = {}
    for mesh_name, objs in users.items():
        obj0 = objs[0]
        mat = bsdf_of(obj0)
        bsdf, emission = classify(mat)
        desc["bsdfs"].setdefault(mat.name, copy_images(bsdf, mesh_dir, out_dir))
        if obj0.modifiers:
            raise Unsupported(f"object {obj0.name}: modifiers (apply them before exporting)")
        uses_uv = textured(mat)
        pos, nrm, faces, _, closed, uvs = mesh_arrays(obj0, depsgraph, with_uv=uses_uv)
        safe = "".join(ch if ch.isalnum() else "_" for ch in mesh_name)
        if len(objs) > 1:
            if emission is not None:
                raise Unsupported(f"{mesh_name}: instanced emitter (Mitsuba shapegroups cannot "
                                  "hold emitters)")
            ply = os.path.join(mesh_dir, f"group_{safe}.ply")
            write_ply(ply, pos, nrm, faces, uvs)
            groups[mesh_name] = f"group_{safe}"
            desc["shapegroups"].append({"id": f"group_{safe}", "ply": os.path.relpath(ply, out_dir),
                                        "bsdf": mat.name, "normals": nrm is not None})
            for o in objs:
                if o.modifiers or bsdf_of(o) is not mat:
                    raise Unsupported(f"instance {o.name}: modifiers or another material")
                desc["instances"].append({"group": f"group_{safe}",
                                          "to_world": matrix_list(o.matrix_world)})
            summary["instanced_triangles"] += len(faces) * len(objs)
            summary["instances"] += len(objs)
            continue
        pos, nrm = to_world(obj0.matrix_world, pos, nrm)
        entry = {"bsdf": mat.name}
        if emission is not None:
            nrm = None  # uniform emission and a black BSDF: the face normal decides the side
            entry["radiance"] = emission
            if closed:
                summary["closed_emitters"].append(obj0.name)
            else:
                pos, nrm, faces = flipped_copy(pos, nrm, faces)
                summary["flipped_emitters"].append(obj0.name)
        ply = os.path.join(mesh_dir, f"{safe}.ply")
        write_ply(ply, pos, nrm, faces, uvs)
        entry["ply"] = os.path.relpath(ply, out_dir)
        entry["normals"] = nrm is not None
        entry["name"] = obj0.name
        desc["shapes"].append(entry)
        summary["triangles"] += len(faces)
        summary["shapes"] += 1

    for o in sc.objects:
        if o.type != "LIGHT" or o.hide_render:
            continue
        L = o.data
        M = o.matrix_world
        pos = [float(x) for x in M.translation]
        fwd = [-float(M[i][2]) for i in range(3)]
        n = math.sqrt(sum(x * x for x in fwd))
        fwd = [x / n for x in fwd]
        up = [float(M[i][1]) for i in range(3)]
        color = [float(c) for c in L.color]
        if L.exposure != 0.0:
            raise Unsupported(f"lamp {o.name}: exposure")
        if L.type == "POINT":
            if L.shadow_soft_size != 0.0:
                raise Unsupported(f"lamp {o.name}: radius > 0")
            desc["emitters"].append({"type": "point", "position": pos,
                                     "intensity": [c * L.energy / (4 * math.pi) for c in color]})
        elif L.type == "SUN":
            if L.angle != 0.0:
                raise Unsupported(f"lamp {o.name}: sun angle > 0")
            desc["emitters"].append({"type": "directional", "direction": fwd,
                                     "irradiance": [c * L.energy for c in color]})
        elif L.type == "SPOT":
            if L.shadow_soft_size != 0.0 or L.spot_blend != 0.0:
                raise Unsupported(f"lamp {o.name}: radius > 0 or spot_blend > 0")
            cutoff = math.degrees(L.spot_size / 2)
            desc["emitters"].append({"type": "spot", "position": pos, "direction": fwd, "up": up,
                                     "intensity": [c * L.energy / (4 * math.pi) for c in color],
                                     "cutoff_angle": cutoff, "beam_width": cutoff})
        else:
            raise Unsupported(f"lamp {o.name}: type {L.type}")

    world = sc.world
    if world is not None:
        nodes = world.node_tree.nodes
        bg = nodes["Background"]
        if bg.inputs["Color"].is_linked or bg.inputs["Strength"].is_linked:
            raise Unsupported("world: only a uniform colour")
        s = float(bg.inputs["Strength"].default_value)
        c = [float(x) * s for x in bg.inputs["Color"].default_value[:3]]
        if max(c) > 0:
            desc["emitters"].append({"type": "constant", "radiance": c})

    cam = sc.camera
    cd = cam.data
    if cd.type != "PERSP" or cd.sensor_fit != "AUTO" or cd.shift_x or cd.shift_y:
        raise Unsupported("camera: only perspective, sensor fit AUTO, no shift")
    M = cam.matrix_world
    origin = [float(x) for x in M.translation]
    fwd = [-float(M[i][2]) for i in range(3)]
    up = [float(M[i][1]) for i in range(3)]
    fov = math.degrees(2 * math.atan(cd.sensor_width / 2 / cd.lens))
    desc["camera"] = {"origin": origin, "target": [o + f for o, f in zip(origin, fwd)], "up": up,
                      "fov": fov, "fov_axis": "larger", "near_clip": float(cd.clip_start),
                      "far_clip": float(cd.clip_end)}
    path = os.path.join(out_dir, f"{name}.mitsuba.json")
    with open(path, "w") as f:
        json.dump(desc, f, indent=1)
    return path, summary
