"""Separates the BSDF models from everything else: each material of the suite on a sphere under a
uniform white world (radiance 1), rendered by Cycles and by pathfarm from the same export.

A convex object under uniform radiance 1 shows, at each pixel, its material's directional albedo
for that view direction (no interreflection, no lamp, no sampling of a light's shape), so the two
renderers' means over the sphere's disc differ only by their BSDF models. A scene's difference
from Cycles that these explain is the models'; what they do not explain is something else.

    /work/venv-bpy/bin/python scenes/suite/material_furnace.py --pathfarm target/release/pathfarm

Writes furnace/NAME.glb and the table to stdout and furnace/results.json (in --out, default a
temporary directory). Every sphere is the same smooth UV sphere of radius 1 seen by an
orthographic camera; the mean is over pixels whose centre lies within 0.95 of the radius (the
rim's partial pixels are left out of both).
"""

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import make_suite as suite  # noqa: E402  (its helpers: reset, cycles_settings, material, …)

import bpy  # noqa: E402
import numpy as np  # noqa: E402

SIZE = 128
ORTHO = 2.2  # the camera's view is 2.2 wide: the sphere's diameter is 2

# (name, scene it comes from, material() arguments). Lambert is the control: an exact counterpart
# in both renderers, so its difference is the noise and the geometry's.
MATERIALS = [
    ("Lambert", "sunroom", dict(base=(0.8, 0.8, 0.8), roughness=1.0, specular=0.0)),
    ("Floor", "product_point", dict(base=(0.5, 0.5, 0.52), roughness=0.8)),
    ("Backdrop", "product_point", dict(base=(0.7, 0.7, 0.72), roughness=0.9)),
    ("Diffuse", "product_point", dict(base=(0.8, 0.3, 0.05), roughness=0.6)),
    ("Gold", "product_point", dict(base=(1.0, 0.77, 0.35), metallic=1.0, roughness=0.35)),
    ("Chrome", "product_point", dict(base=(0.95, 0.95, 0.95), metallic=1.0, roughness=0.1)),
    ("Clay", "instanced", dict(base=(0.8, 0.8, 0.8), roughness=0.5)),
    ("UncoatedRed", "clearcoat", dict(base=(0.7, 0.05, 0.04), roughness=0.6)),
    ("CoatedRed", "clearcoat",
     dict(base=(0.7, 0.05, 0.04), roughness=0.6, coat=1.0, coat_roughness=0.1)),
    ("CoatedMetal", "clearcoat",
     dict(base=(0.2, 0.35, 0.8), metallic=1.0, roughness=0.4, coat=1.0, coat_roughness=0.15)),
    ("Velvet", "clearcoat",
     dict(base=(0.15, 0.05, 0.3), roughness=0.9, sheen=1.0, sheen_roughness=0.3)),
]

# With --grid: the opaque dielectric (IOR 1.5) alone, black (its specular layer only) and white (the
# layer over the most diffuse it can carry), across roughness: which of the two parts differs.
GRID = [(f"{kind}{r:.2f}", "grid", dict(base=(b, b, b), roughness=r))
        for kind, b in (("Black", 0.0), ("White", 1.0))
        for r in (0.05, 0.2, 0.4, 0.6, 0.8, 1.0)]


def build(name, args):
    sc = suite.reset()
    sc.render.resolution_x = SIZE
    sc.render.resolution_y = SIZE
    bg = sc.world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (1, 1, 1, 1)
    bg.inputs["Strength"].default_value = 1.0
    m = suite.material(name, **args)
    suite.mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, m, radius=1.0, segments=128,
                   ring_count=64, smooth=True, name=name + "Sphere")
    cam = bpy.data.cameras.new("Camera")
    cam.type = "ORTHO"
    cam.ortho_scale = ORTHO
    o = suite.link(bpy.data.objects.new("Camera", cam))
    o.location = (0.0, -5.0, 0.0)
    suite.look_at(o, (0, 0, 0))
    sc.camera = o
    return sc


def disc_mask():
    c = (np.arange(SIZE) + 0.5) / SIZE * ORTHO - ORTHO / 2
    x, y = np.meshgrid(c, c)
    return np.hypot(x, y) < 0.95


def read_exr(path):
    px = suite.load_exr(path).astype(np.float64)
    return px[::-1]  # row 0 at the top, as pathfarm writes it (the mask is symmetric anyway)


def disc_mean(px, mask):
    return px[mask].mean(axis=0)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--pathfarm", required=True, help="the pathfarm binary")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--out", default="")
    ap.add_argument("--only", default="")
    ap.add_argument("--grid", action="store_true", help="the roughness grid instead")
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    args = ap.parse_args(argv)
    out = args.out or tempfile.mkdtemp(prefix="pathfarm_furnace_")
    os.makedirs(out, exist_ok=True)
    only = [n for n in args.only.split(",") if n]
    mask = disc_mask()
    rows = []
    for name, scene, margs in GRID if args.grid else MATERIALS:
        if only and name not in only:
            continue
        sc = build(name, margs)
        glb = os.path.join(out, f"{name}.glb")
        bpy.ops.export_scene.gltf(filepath=glb, export_format="GLB", export_cameras=True,
                                  export_lights=True)
        suite.cycles_settings(sc, args.spp, suite.BASE_SEED)
        cycles_exr = os.path.join(out, f"{name}_cycles.exr")
        sc.render.filepath = cycles_exr
        bpy.ops.render.render(write_still=True)
        ours_exr = os.path.join(out, f"{name}_pathfarm.exr")
        subprocess.run([args.pathfarm, "render", glb, "--environment", "1,1,1",
                        "--width", str(SIZE), "--height", str(SIZE), "--spp", str(args.spp),
                        "--threads", "2", "--out", ours_exr], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        cyc = disc_mean(read_exr(cycles_exr), mask)
        ours = disc_mean(read_exr(ours_exr), mask)
        ratio = ours / cyc
        rows.append({"material": name, "scene": scene, "args": margs,
                     "cycles_rgb": cyc.round(5).tolist(), "pathfarm_rgb": ours.round(5).tolist(),
                     "ratio_rgb": ratio.round(4).tolist(),
                     "ratio_mean": round(float(ours.mean() / cyc.mean()), 4)})
        print(f"{name:12s} {scene:14s} cycles {np.round(cyc, 4)} pathfarm {np.round(ours, 4)} "
              f"ours/cycles {np.round(ratio, 4)} (mean {rows[-1]['ratio_mean']:.4f})", flush=True)
    with open(os.path.join(out, "results.json"), "w") as f:
        json.dump({"spp": args.spp, "size": SIZE, "blender": bpy.app.version_string,
                   "materials": rows}, f, indent=1)
    print(f"written to {out}")


if __name__ == "__main__":
    main()
