"""Renders one scene description written by to_mitsuba.py with Mitsuba 3 and times the renders.

Runs in Mitsuba's own Python (never inside bpy):

    python mitsuba_render.py SCENE.mitsuba.json --spp 256 --seeds 1,2 \
        --out-prefix DIR/NAME_mitsuba [--threads 2] [--variant llvm_ad_rgb]

Writes PREFIX_seedK.exr and PREFIX_seedK.npy (float32, H x W x 3, row 0 at the top) per seed and
PREFIX.json with the timings. What is timed: `mi.render(scene, spp=S, seed=k)` followed by
converting the image to numpy (which forces Dr.Jit to evaluate it), after one warm-up render of
WARMUP_SPP samples that traces and compiles the kernels (Dr.Jit keeps spp and the seed out of
the kernel, so the timed renders reuse it: the kernel history recorded during each timed render
is checked and reported). Scene loading (PLY parsing, BVH build) happens in `mi.load_dict`,
before and outside the timed calls. Each mi.render call still traces the integrator into a kernel
(then found in the cache): a fixed cost per call, small except with many shapes (instancing);
the kernels' own execution time from Dr.Jit's kernel history is recorded beside the wall time.
"""

import argparse
import json
import os
import time

import drjit as dr
import mitsuba as mi
import numpy as np

WARMUP_SPP = 1


def rgb(v):
    return {"type": "rgb", "value": [float(x) for x in v]}


def build(desc, base):
    T = mi.ScalarTransform4f
    cam = desc["camera"]
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": -1},
        "sensor": {
            "type": "perspective",
            "fov": cam["fov"],
            "fov_axis": cam["fov_axis"],
            "near_clip": cam["near_clip"],
            "far_clip": cam["far_clip"],
            "to_world": T().look_at(origin=cam["origin"], target=cam["target"], up=cam["up"]),
            "film": {"type": "hdrfilm", "width": desc["width"], "height": desc["height"],
                     "pixel_format": "rgb", "component_format": "float32",
                     "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": 1},
        },
    }
    def resolve(d):  # bitmap filenames are relative to the scene file's folder
        if isinstance(d, dict):
            d = {k: resolve(v) for k, v in d.items()}
            if d.get("type") == "bitmap":
                d["filename"] = os.path.join(base, d["filename"])
        return d

    for name, bsdf in desc["bsdfs"].items():
        scene[f"bsdf_{name}"] = dict(resolve(bsdf), id=f"bsdf_{name}")

    def ref(name):
        return {"type": "ref", "id": f"bsdf_{name}"}

    for i, s in enumerate(desc["shapes"]):
        sh = {"type": "ply", "filename": os.path.join(base, s["ply"]), "bsdf": ref(s["bsdf"]),
              "face_normals": not s["normals"]}
        if "radiance" in s:
            sh["emitter"] = {"type": "area", "radiance": rgb(s["radiance"])}
        scene[f"shape_{i}"] = sh
    for g in desc["shapegroups"]:
        scene[g["id"]] = {"type": "shapegroup",
                          "mesh": {"type": "ply", "filename": os.path.join(base, g["ply"]),
                                   "bsdf": ref(g["bsdf"]), "face_normals": not g["normals"]}}
    for i, inst in enumerate(desc["instances"]):
        scene[f"instance_{i}"] = {"type": "instance",
                                  "shapegroup": {"type": "ref", "id": inst["group"]},
                                  "to_world": T(inst["to_world"])}
    for i, e in enumerate(desc["emitters"]):
        t = e["type"]
        if t == "point":
            em = {"type": "point", "position": e["position"], "intensity": rgb(e["intensity"])}
        elif t == "directional":
            em = {"type": "directional", "direction": e["direction"],
                  "irradiance": rgb(e["irradiance"])}
        elif t == "spot":
            p, d = e["position"], e["direction"]
            em = {"type": "spot", "intensity": rgb(e["intensity"]),
                  "cutoff_angle": e["cutoff_angle"], "beam_width": e["beam_width"],
                  "to_world": T().look_at(origin=p, target=[a + b for a, b in zip(p, d)],
                                          up=e["up"])}
        elif t == "constant":
            em = {"type": "constant", "radiance": rgb(e["radiance"])}
        else:
            raise ValueError(t)
        scene[f"emitter_{i}"] = em
    return scene


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--spp", type=int, required=True)
    ap.add_argument("--seeds", default="1,2")
    ap.add_argument("--out-prefix", required=True)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    args = ap.parse_args()

    dr.set_thread_count(args.threads)
    mi.set_variant(args.variant)
    mi.set_log_level(mi.LogLevel.Warn)
    with open(args.scene) as f:
        desc = json.load(f)
    t0 = time.perf_counter()
    scene = mi.load_dict(build(desc, os.path.dirname(os.path.abspath(args.scene))))
    load_s = time.perf_counter() - t0

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()  # clear
    t0 = time.perf_counter()
    warm = np.array(mi.render(scene, spp=WARMUP_SPP, seed=0))
    warmup_s = time.perf_counter() - t0
    warm_hist = dr.kernel_history()
    compile_s = sum(k.get("codegen_time", 0) + k.get("backend_time", 0) for k in warm_hist
                    if not k.get("cache_hit", 1)) / 1000.0
    assert np.isfinite(warm).all()

    runs = []
    for seed in [int(s) for s in args.seeds.split(",")]:
        dr.kernel_history()
        t0 = time.perf_counter()
        img = mi.render(scene, spp=args.spp, seed=seed)
        arr = np.array(img, dtype=np.float32)  # forces evaluation
        secs = time.perf_counter() - t0
        hist = dr.kernel_history()
        misses = [k for k in hist if k.get("type") == dr.KernelType.JIT and not k.get("cache_hit")]
        path = f"{args.out_prefix}_seed{seed}"
        np.save(path + ".npy", arr[..., :3])
        mi.Bitmap(arr[..., :3]).write(path + ".exr")
        runs.append({"seed": seed, "seconds": secs, "exr": os.path.basename(path + ".exr"),
                     "npy": os.path.basename(path + ".npy"),
                     "kernels": len(hist), "kernels_compiled": len(misses),
                     # What Dr.Jit reports as the kernels' own execution: the render without the
                     # per-call tracing of the integrator into a kernel (see README).
                     "kernel_seconds": sum(k.get("execution_time", 0) for k in hist) / 1000.0,
                     "compile_seconds": sum(k.get("codegen_time", 0) + k.get("backend_time", 0)
                                            for k in misses) / 1000.0})
        print(f"mitsuba seed {seed}: {secs:.3f} s ({runs[-1]['kernel_seconds']:.3f} s in "
              f"kernels), {len(misses)} kernels compiled", flush=True)
    info = {"variant": args.variant, "mitsuba": mi.__version__, "drjit": dr.__version__,
            "threads": dr.thread_count(), "load_seconds": load_s, "warmup_spp": WARMUP_SPP,
            "warmup_seconds": warmup_s, "warmup_compile_seconds": compile_s, "runs": runs}
    with open(args.out_prefix + ".json", "w") as f:
        json.dump(info, f, indent=1)


if __name__ == "__main__":
    main()
