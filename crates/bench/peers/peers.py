"""Peer comparison: pathfarm against Mitsuba 3 and Blender Cycles on scenes with exact counterparts.

Run with Blender as a Python module (bpy 5.0.1), from the repository root:

    /work/venv-bpy/bin/python crates/bench/peers/peers.py --pathfarm target/release/pathfarm \
        --mitsuba-python /work/venv-mi/bin/python --out /tmp/pathfarm-peers
    ... --quick                # 64 x 64, 16 spp: checks that everything runs and agrees
    ... --only a,c             # scenes by letter (or name)

For each scene (scenes.py): build it in bpy, export it with Blender's glTF exporter (for the
tracer), convert it for Mitsuba (to_mitsuba.py: JSON + PLY), then render it with each renderer
twice with different seeds (2 threads, W x H, S spp) and time each render without scene loading,
BVH building or JIT compilation (README.md, "What is timed"). From the two renders of each
renderer: samples/s, the noise error (RMSE^2 ~ mean((A - B)^2) / 2, relative to the image mean),
efficiency RMSE^2 * t, the equal-time error against the best peer, and the bias check (image mean
and left/right half means against ours). Writes results.json, results.md and all EXRs to --out.
"""

import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

sys.dont_write_bytecode = True  # no __pycache__ in the source tree
HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.abspath(os.path.join(HERE, "..", "..", ".."))
sys.path.insert(0, HERE)

import scenes  # noqa: E402  (puts scenes/suite on sys.path and imports make_suite)
import to_mitsuba  # noqa: E402
from scenes import suite  # noqa: E402

import bpy  # noqa: E402
import numpy as np  # noqa: E402

RENDERERS = ("pathfarm", "cycles", "mitsuba")
THREADS = 2


# ----------------------------------------------------------------------------------------------
# Images


def load_exr_top(path):
    """An EXR read by Blender, as float64 H x W x 3 with row 0 at the top."""
    return suite.load_exr(path).astype(np.float64)[::-1]


def exr_header(path):
    """The attributes of a scanline EXR header as {name: (type, bytes)}."""
    with open(path, "rb") as f:
        data = f.read(1 << 16)
    assert data[:4] == b"\x76\x2f\x31\x01", f"{path}: not an EXR"
    i, out = 8, {}
    while data[i] != 0:
        j = data.index(b"\0", i)
        k = data.index(b"\0", j + 1)
        n = int.from_bytes(data[k + 1:k + 5], "little")
        out[data[i:j].decode()] = (data[j + 1:k].decode(), data[k + 5:k + 5 + n])
        i = k + 5 + n
    return out


def parse_hms(s):
    """Cycles' time_human_readable_from_seconds: [HH:]MM:SS.cc -> seconds."""
    secs = 0.0
    for part in s.strip().split(":"):
        secs = secs * 60 + float(part)
    return secs


# ----------------------------------------------------------------------------------------------
# Renderers


def render_pathfarm(args, glb, env, out_dir, name, spp, seeds):
    runs = []
    for seed in seeds:
        exr = os.path.join(out_dir, f"{name}_pathfarm_seed{seed}.exr")
        cmd = [args.pathfarm, "render", glb, "--width", str(args.width), "--height",
               str(args.height), "--spp", str(spp), "--seed", str(seed), "--threads",
               str(THREADS), "--out", exr]
        if env is not None:
            cmd += ["--environment", ",".join(repr(float(c)) for c in env)]
        t0 = time.perf_counter()
        p = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if p.returncode != 0:
            raise RuntimeError(f"pathfarm failed: {' '.join(cmd)}\n{p.stdout}\n{p.stderr}")
        m = re.search(r"rendered .* in ([0-9.]+) s:", p.stdout)
        if not m:
            raise RuntimeError(f"no render time in pathfarm's output:\n{p.stdout}")
        runs.append({"seed": seed, "seconds": float(m.group(1)), "wall_seconds": wall,
                     "exr": os.path.basename(exr), "stdout": p.stdout.strip()})
        print(f"  pathfarm seed {seed}: {runs[-1]['seconds']:.3f} s", flush=True)
    imgs = [load_exr_top(os.path.join(out_dir, r["exr"])) for r in runs]
    return runs, imgs, {"command": " ".join(cmd)}


def cycles_render(sc, spp, seed, path):
    suite.cycles_settings(sc, spp, seed)
    sc.render.filepath = path
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    wall = time.perf_counter() - t0
    h = exr_header(path)
    stamp = {k: v[1].decode(errors="replace") for k, v in h.items()
             if k.startswith("cycles.") and v[0] == "string"}
    layer = [k for k in stamp if k.endswith(".render_time")]
    assert len(layer) == 1, stamp
    prefix = layer[0][:-len("render_time")]
    return {"wall_seconds": wall, "render_time": parse_hms(stamp[prefix + "render_time"]),
            "synchronization_time": parse_hms(stamp[prefix + "synchronization_time"]),
            "samples": int(stamp[prefix + "samples"])}


def render_cycles(args, out_dir, name, spp, seeds):
    sc = bpy.context.scene
    tmp = tempfile.mkdtemp(prefix="peers_cycles_")
    # 1 spp twice: the first absorbs any one-time start-up, the second is the fixed cost (sync,
    # BVH, image output) that the wall-clock cross-check subtracts.
    cycles_render(sc, 1, seeds[0], os.path.join(tmp, "warm.exr"))
    one = cycles_render(sc, 1, seeds[0], os.path.join(tmp, "one.exr"))
    shutil.rmtree(tmp, ignore_errors=True)
    runs = []
    for seed in seeds:
        exr = os.path.join(out_dir, f"{name}_cycles_seed{seed}.exr")
        r = cycles_render(sc, spp, seed, exr)
        assert r["samples"] == spp, r
        r["wall_minus_1spp_seconds"] = ((r["wall_seconds"] - one["wall_seconds"]) * spp
                                        / max(spp - 1, 1))
        r["seed"] = seed
        # Cycles' own render time (0.01 s resolution); the wall-clock difference if it reads 0.
        r["seconds"] = r["render_time"] if r["render_time"] > 0 else max(
            r["wall_minus_1spp_seconds"], 1e-3)
        r["seconds_source"] = "render_time" if r["render_time"] > 0 else "wall_minus_1spp"
        r["exr"] = os.path.basename(exr)
        runs.append(r)
        print(f"  cycles seed {seed}: {r['seconds']:.2f} s (Cycles render_time; wall "
              f"{r['wall_seconds']:.2f} s, sync {r['synchronization_time']:.2f} s, wall - 1 spp "
              f"scaled {r['wall_minus_1spp_seconds']:.2f} s)", flush=True)
    imgs = [load_exr_top(os.path.join(out_dir, r["exr"])) for r in runs]
    return runs, imgs, {"one_spp": one, "blender": bpy.app.version_string}


def render_mitsuba(args, desc_path, out_dir, name, spp, seeds):
    prefix = os.path.join(out_dir, f"{name}_mitsuba")
    cmd = [args.mitsuba_python, os.path.join(HERE, "mitsuba_render.py"), desc_path, "--spp",
           str(spp), "--seeds", ",".join(map(str, seeds)), "--out-prefix", prefix, "--threads",
           str(THREADS)]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"mitsuba failed: {' '.join(cmd)}\n{p.stdout}\n{p.stderr}")
    with open(prefix + ".json") as f:
        info = json.load(f)
    for r in info["runs"]:
        print(f"  mitsuba seed {r['seed']}: {r['seconds']:.3f} s ({r['kernel_seconds']:.3f} s in "
              f"kernels; {r['kernels_compiled']} kernels compiled while timed)", flush=True)
    imgs = [np.load(os.path.join(out_dir, r["npy"])).astype(np.float64) for r in info["runs"]]
    runs = info.pop("runs")
    return runs, imgs, info


# ----------------------------------------------------------------------------------------------
# Statistics


def stats(imgs, runs, pixels, spp):
    a, b = imgs
    t = float(np.mean([r["seconds"] for r in runs]))
    mse = float(np.mean((a - b) ** 2) / 2)  # per render, pixels and channels
    mean = float((a.mean() + b.mean()) / 2)
    rel_mse = mse / mean ** 2 if mean > 0 else float("nan")
    # Standard error of the two-render average's image mean, from the per-pixel spread of the
    # channel average, assuming independent pixels (rough: samplers correlate pixels).
    ga, gb = a.mean(axis=2), b.mean(axis=2)
    se_mean = math.sqrt(float(np.mean((ga - gb) ** 2) / 2) / (2 * ga.size))
    h, w = a.shape[:2]
    avg = (a + b) / 2
    out = {} if "kernel_seconds" not in runs[0] else {
        "kernel_seconds": float(np.mean([r["kernel_seconds"] for r in runs]))}
    return out | {
        "seconds": t,
        "seconds_each": [r["seconds"] for r in runs],
        "samples_per_second": pixels * spp / t if t > 0 else float("inf"),
        "rmse": math.sqrt(mse),
        "rel_rmse": math.sqrt(rel_mse),
        "efficiency_rel_mse_times_s": rel_mse * t,
        "mean": mean,
        "mean_rgb": avg.mean(axis=(0, 1)).tolist(),
        "mean_each": [float(a.mean()), float(b.mean())],
        "se_mean": se_mean,
        "left_mean": float(avg[:, : w // 2].mean()),
        "right_mean": float(avg[:, w - w // 2:].mean()),
        "top_mean": float(avg[: h // 2].mean()),
        "bottom_mean": float(avg[h - h // 2:].mean()),
        "nonfinite": int((~np.isfinite(a)).sum() + (~np.isfinite(b)).sum()),
    }


def compare(res):
    """Equal-time error against the best other renderer and the bias check against ours."""
    have = [r for r in RENDERERS if r in res]
    for r in have:
        others = [o for o in have if o != r]
        if others:
            best = min(others, key=lambda o: res[o]["efficiency_rel_mse_times_s"])
            res[r]["equal_time_error_vs_best_other"] = math.sqrt(
                res[r]["efficiency_rel_mse_times_s"] / res[best]["efficiency_rel_mse_times_s"])
            res[r]["best_other"] = best
    if "pathfarm" in res:
        o = res["pathfarm"]
        for r in have:
            x = res[r]
            x["mean_vs_ours"] = x["mean"] / o["mean"] - 1
            x["mean_vs_ours_sigma"] = math.hypot(x["se_mean"], o["se_mean"]) / o["mean"]
            x["left_vs_ours"] = x["left_mean"] / o["left_mean"] - 1
            x["right_vs_ours"] = x["right_mean"] / o["right_mean"] - 1
            x["top_vs_ours"] = x["top_mean"] / o["top_mean"] - 1
            x["bottom_vs_ours"] = x["bottom_mean"] / o["bottom_mean"] - 1
            x["mean_rgb_vs_ours"] = [m / n - 1 for m, n in zip(x["mean_rgb"], o["mean_rgb"])]


def fmt_pct(x, sign=True):
    return "–" if x is None else (f"{x * 100:+.1f} %" if sign else f"{x * 100:.1f} %")


def table(results, args):
    lines = [f"{args.width} x {args.height}, {args.spp} spp, {THREADS} threads, seeds "
             f"{args.seeds}; time per render (mean of the two), for Mitsuba with its kernels' "
             "own time in brackets; Msamples/s, RMSE²·t and the equal-time error use the first "
             "time. rel. RMSE: one render's, relative to its image mean. Equal-time error ÷ best "
             "other: sqrt(RMSE²·t / the smallest RMSE²·t of the other two), below 1 = better. "
             "Mean vs ours: image mean / ours − 1 with its rough 1σ.", "",
             "| scene | renderer | time (s) | Msamples/s | rel. RMSE | RMSE²·t | equal-time error "
             "÷ best other | mean vs ours (±1σ) | left / right half vs ours |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, sres in results["scenes"].items():
        for r in RENDERERS:
            if r not in sres["renderers"]:
                continue
            x = sres["renderers"][r]
            et = x.get("equal_time_error_vs_best_other")
            et_s = "–" if et is None else f"{et:.2f} ({x['best_other']})"
            if r == "pathfarm" or "mean_vs_ours" not in x:
                bias, lr = "", ""
            else:
                bias = f"{fmt_pct(x['mean_vs_ours'])} (±{x['mean_vs_ours_sigma'] * 100:.1f} %)"
                lr = f"{fmt_pct(x['left_vs_ours'])} / {fmt_pct(x['right_vs_ours'])}"
            t_s = f"{x['seconds']:.3f}"
            if "kernel_seconds" in x:
                t_s += f" ({x['kernel_seconds']:.3f})"
            lines.append(f"| {sres['letter']}: {name} | {r} | {t_s} | "
                         f"{x['samples_per_second'] / 1e6:.2f} | {fmt_pct(x['rel_rmse'], False)} | "
                         f"{x['efficiency_rel_mse_times_s']:.3g} | {et_s} | {bias} | {lr} |")
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------------------


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pathfarm", default=os.path.join(REPO, "target", "release", "pathfarm"))
    ap.add_argument("--mitsuba-python",
                    default=os.environ.get("PEERS_MITSUBA_PYTHON", "/work/venv-mi/bin/python"
                                           if os.path.exists("/work/venv-mi/bin/python")
                                           else "python3"))
    ap.add_argument("--out", default=os.path.join(tempfile.gettempdir(), "pathfarm-peers"))
    ap.add_argument("--width", type=int, default=256)
    ap.add_argument("--height", type=int, default=256)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--seeds", default="1,2", help="two seeds: the two independent renders")
    ap.add_argument("--quick", action="store_true", help="64 x 64, 16 spp")
    ap.add_argument("--only", default="", help="scenes by letter or name, e.g. a,c or cornell")
    ap.add_argument("--renderers", default=",".join(RENDERERS))
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    args = ap.parse_args(argv)
    if args.quick:
        args.width, args.height, args.spp = 64, 64, 16
    seeds = [int(s) for s in args.seeds.split(",")]
    assert len(seeds) == 2 and seeds[0] != seeds[1], "--seeds takes two different seeds"
    renderers = [r for r in args.renderers.split(",") if r]
    assert all(r in RENDERERS for r in renderers), renderers
    args.pathfarm = os.path.abspath(args.pathfarm)
    sel = [s for s in args.only.split(",") if s]
    letters = [k for k, (n, _) in scenes.SCENES.items() if not sel or k in sel or n in sel]
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)

    results_path = os.path.join(out, "results.json")
    results = {"settings": {"width": args.width, "height": args.height, "spp": args.spp,
                            "seeds": seeds, "threads": THREADS, "pathfarm": args.pathfarm,
                            "blender": bpy.app.version_string,
                            "mitsuba_python": args.mitsuba_python},
               "scenes": {}}
    pixels = args.width * args.height
    for letter in letters:
        name, build = scenes.SCENES[letter]
        print(f"== {letter}: {name}", flush=True)
        suite.reset()
        info = build()
        sc = bpy.context.scene
        sc.render.resolution_x, sc.render.resolution_y = args.width, args.height
        sc.render.resolution_percentage = 100
        suite.cycles_settings(sc, args.spp, seeds[0])
        glb = os.path.join(out, f"{name}.glb")
        bpy.ops.export_scene.gltf(filepath=glb, export_format="GLB", export_cameras=True,
                                  export_lights=True)
        desc, msum = to_mitsuba.export(out, name, args.width, args.height)
        entry = {"letter": letter, "covers": info["covers"], "environment": info["environment"],
                 "glb": os.path.basename(glb), "mitsuba_scene": os.path.basename(desc),
                 "mitsuba_conversion": msum, "renderers": {}, "details": {}}
        print(f"  mitsuba conversion: {msum}", flush=True)
        for r in renderers:
            if r == "pathfarm":
                runs, imgs, det = render_pathfarm(args, glb, info["environment"], out, name,
                                                  args.spp, seeds)
            elif r == "cycles":
                runs, imgs, det = render_cycles(args, out, name, args.spp, seeds)
            else:
                runs, imgs, det = render_mitsuba(args, desc, out, name, args.spp, seeds)
            for img in imgs:
                assert img.shape == (args.height, args.width, 3), (r, img.shape)
            entry["renderers"][r] = stats(imgs, runs, pixels, args.spp)
            entry["details"][r] = {"runs": runs, **det}
        compare(entry["renderers"])
        for r, x in entry["renderers"].items():
            print(f"  {r:9s} mean {x['mean']:.5f} rgb {np.round(x['mean_rgb'], 5)} "
                  f"L {x['left_mean']:.5f} R {x['right_mean']:.5f} rel.RMSE {x['rel_rmse']:.4f} "
                  f"t {x['seconds']:.3f} s" + (f" vs ours {x['mean_vs_ours'] * 100:+.2f} %"
                                              if "mean_vs_ours" in x else ""), flush=True)
        results["scenes"][name] = entry
        with open(results_path, "w") as f:
            json.dump(results, f, indent=1)
    md = table(results, args)
    with open(os.path.join(out, "results.md"), "w") as f:
        f.write(md)
    print()
    print(md)
    print(f"written to {out}")


if __name__ == "__main__":
    main()
