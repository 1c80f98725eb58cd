"""Measures what Cycles' lamp and volume settings mean, with tiny direct-lighting renders (a few
seconds): the claims of README.md "Units". Run:

    /work/venv-bpy/bin/python scenes/suite/check_units.py

1. POINT lamp of power P (radius 0) above a white Lambertian plane: radiance = (1/pi) * I cos / d^2
   with I = P / (4 pi) W/sr.
2. SPOT lamp (size 90 deg, blend 0.5): I = P / (4 pi) on the axis times
   smoothstep(0, 1, (cos t - cos(size/2)) / (blend * (1 - cos(size/2)))); not glTF's falloff.
3. SUN lamp of strength S (angle 0), 30 deg from the normal: irradiance S cos(30 deg).
4. Volume Absorption (colour C, density D): transmittance exp(-(1 - C) D) per metre, and an
   Emission shader of strength 1 seen directly: radiance 1.
"""

import math
import os
import tempfile

import bpy
import numpy as np

N = 64
TMP = tempfile.mkdtemp(prefix="pathfarm_units_")


def base_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    c = sc.cycles
    c.device = "CPU"
    sc.render.threads_mode = "FIXED"
    sc.render.threads = 2
    c.samples = 16
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    c.max_bounces = 0  # camera -> surface -> light only
    sc.view_settings.view_transform = "Standard"
    sc.render.resolution_x = sc.render.resolution_y = N
    w = bpy.data.worlds.new("W")
    sc.world = w
    w.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    sc.render.image_settings.file_format = "OPEN_EXR"
    sc.render.image_settings.color_depth = "32"
    return sc


def ortho_camera(z, scale):
    cam = bpy.data.cameras.new("c")
    cam.type = "ORTHO"
    cam.ortho_scale = scale
    o = bpy.data.objects.new("c", cam)
    bpy.context.scene.collection.objects.link(o)
    o.location = (0, 0, z)
    bpy.context.scene.camera = o


def shader_material(kind, **inputs):
    m = bpy.data.materials.new(kind)
    nt = m.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    n = nt.nodes.new(kind)
    for k, v in inputs.items():
        n.inputs[k].default_value = v
    socket = "Volume" if "Volume" in kind else "Surface"
    nt.links.new(n.outputs[0], out.inputs[socket])
    return m


def render():
    sc = bpy.context.scene
    sc.render.filepath = os.path.join(TMP, "u.exr")
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(sc.render.filepath, check_existing=False)
    px = np.empty(N * N * 4, dtype=np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px.reshape(N, N, 4)[..., :3].astype(np.float64)


def lamp_on_plane(kind, **props):
    """White Lambertian plane z = 0 seen from above (8 x 8 m), lamp at height 2."""
    base_scene()
    bpy.ops.mesh.primitive_plane_add(size=20)
    bpy.context.object.data.materials.append(
        shader_material("ShaderNodeBsdfDiffuse", Color=(1, 1, 1, 1)))
    ortho_camera(5, 8.0)
    L = bpy.data.lights.new("L", kind)
    for k, v in props.items():
        setattr(L, k, v)
    o = bpy.data.objects.new("L", L)
    bpy.context.scene.collection.objects.link(o)
    o.location = (0, 0, 2)
    if kind == "SUN":
        o.rotation_euler = (math.radians(30), 0, 0)
    return render()[..., 0]


def main():
    xs = (np.arange(N) + 0.5) / N * 8 - 4
    X, Y = np.meshgrid(xs, xs)
    r2 = X ** 2 + Y ** 2 + 4
    cos = 2 / np.sqrt(r2)
    P = 100.0
    L_point = (P / (4 * math.pi)) * cos / r2 / math.pi

    got = lamp_on_plane("POINT", energy=P, shadow_soft_size=0.0)
    ratio = got / L_point
    print(f"POINT {P} W: rendered / (I cos/d^2/pi with I = P/(4 pi)): mean {ratio.mean():.4f} "
          f"(pixel centre against pixel average: +-0.5 % at most: {ratio.min():.4f}..{ratio.max():.4f})")
    assert abs(ratio.mean() - 1) < 2e-3

    half, blend = math.radians(45), 0.5
    got = lamp_on_plane("SPOT", energy=P, shadow_soft_size=0.0, spot_size=2 * half, spot_blend=blend)
    ch = math.cos(half)
    t = np.clip((cos - ch) / (blend * (1 - ch)), 0, 1)
    blender = L_point * t * t * (3 - 2 * t)
    inner = half * (1 - blend)  # what the exporter writes
    g = np.clip((cos - ch) / (math.cos(inner) - ch), 0, 1) ** 2
    gltf = L_point * g
    row = N // 2
    print("SPOT 90 deg, blend 0.5, along a row from the axis: rendered | Blender smoothstep model | "
          "glTF falloff of the exported cone angles")
    for j in range(row, N, 3):
        print(f"  x={xs[j]:5.2f} m  {got[row, j]:.4f} | {blender[row, j]:.4f} | {gltf[row, j]:.4f}")
    inside = blender > 0.05 * L_point
    err_blender = np.abs(got - blender)[inside].max() / L_point.max()
    err_gltf = np.abs(got - gltf)[inside].max() / L_point.max()
    print(f"  max error in the cone: Blender model {err_blender:.4f}, glTF model {err_gltf:.4f}")
    assert err_blender < 0.01 < err_gltf

    S = 2.0
    got = lamp_on_plane("SUN", energy=S, angle=0.0)
    want = S * math.cos(math.radians(30)) / math.pi
    print(f"SUN {S} W/m^2 at 30 deg: radiance {got.mean():.6f}, S cos/pi = {want:.6f}")
    assert abs(got.mean() / want - 1) < 1e-4

    # Volume absorption: a 1 m cube of absorbing volume (no surface) in front of an emitter.
    base_scene()
    bpy.ops.mesh.primitive_plane_add(size=20, location=(0, 0, -2))
    bpy.context.object.data.materials.append(
        shader_material("ShaderNodeEmission", Strength=1.0))
    bpy.ops.mesh.primitive_cube_add(size=1)
    C = (0.5, 0.25, 1.0)
    bpy.context.object.data.materials.append(
        shader_material("ShaderNodeVolumeAbsorption", Color=(*C, 1), Density=1.0))
    ortho_camera(5, 0.5)
    got = render().mean(axis=(0, 1))
    want = np.exp(-(1 - np.array(C)))
    print(f"Volume Absorption C={C}, D=1, 1 m: transmittance {got.round(5)}, exp(-(1-C)D) = "
          f"{want.round(5)}, glTF's C^(1 m / distance) would be {np.array(C)}")
    assert np.abs(got - want).max() < 1e-4
    print("Emission strength 1 seen through nothing (blue channel, C=1): radiance", round(got[2], 6))
    assert abs(got[2] - 1) < 1e-5
    print("all unit checks passed")


if __name__ == "__main__":
    main()
