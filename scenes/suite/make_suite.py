"""Builds the Blender scene suite from scratch, exports each scene with Blender's glTF exporter
and renders each with Cycles as the reference.

Run with Blender as a Python module (bpy from PyPI):

    /work/venv-bpy/bin/python scenes/suite/make_suite.py                 # everything
    /work/venv-bpy/bin/python scenes/suite/make_suite.py --only sunroom  # one scene
    /work/venv-bpy/bin/python scenes/suite/make_suite.py --no-render     # .glb and env only

Writes next to this file: NAME.glb, cycles/NAME.exr, env/sky.hdr + env/sky.exr, manifest.json.
Nothing is downloaded: every mesh is a Blender primitive, every texture is computed here.
See README.md for what each scene covers and what the numbers mean.
"""

import argparse
import json
import math
import os
import sys
import tempfile
import time

import bpy
import numpy as np
from mathutils import Vector

HERE = os.path.dirname(os.path.abspath(__file__))
SIZE = 256
THREADS = 2
# The reference is the average of PARTS renders with seeds BASE_SEED + k, each of spp / PARTS
# samples: an unbiased estimate with spp samples per pixel whose image-mean standard error is
# estimated from the spread of the parts' means (PARTS - 1 degrees of freedom).
PARTS = 4
BASE_SEED = 1000
BOUNCES = 64

# Samples per pixel of each reference (total over the parts), picked from timed test renders so that
# the whole suite renders in under half an hour on 2 busy cores and each mean's standard error stays well
# under 0.5 %.
SPP = {
    "sunroom": 512,
    "product_point": 512,
    "product_spot": 1024,
    "hdr_outdoor": 512,
    "glass_volume": 1024,
    "textured_pbr": 512,
    "clearcoat": 512,
    "instanced": 512,
}


# The part of a scene's difference from Cycles that its rough Principled dielectrics make: appended
# to the note of every scene that has them. `documented_difference` (in the scenes' returns) is
# the tracer's image-mean luminance against Cycles', (ours - Cycles) / Cycles, as `pathfarm bench
# blender --spp 64` measured it; tests/blender_suite.rs holds every scene to it within 1 %.
LAYER_NOTE = (" Not exact: the rough Principled dielectric differs by convention (Cycles: exact "
              "dielectric Fresnel, and a diffuse under the specular layer that loses up to 2.8 % at "
              "roughness 1; glTF: Schlick Fresnel, and the tracer gives the diffuse all the layer "
              "does not reflect), measured material by material by material_furnace.py "
              "(docs/blender-suite.md).")


# ----------------------------------------------------------------------------------------------
# Helpers


def reset():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.resolution_x = SIZE
    sc.render.resolution_y = SIZE
    sc.render.resolution_percentage = 100
    # Black world unless the scene sets an environment: glTF cannot carry a world.
    world = bpy.data.worlds.new("World")
    sc.world = world
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (0, 0, 0, 1)
    bg.inputs["Strength"].default_value = 0.0
    return sc


def cycles_settings(sc, samples, seed):
    sc.render.engine = "CYCLES"
    c = sc.cycles
    c.device = "CPU"
    sc.render.threads_mode = "FIXED"
    sc.render.threads = THREADS
    c.samples = samples
    c.seed = seed
    c.use_animated_seed = False
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.use_guiding = False
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    c.max_bounces = BOUNCES
    c.diffuse_bounces = BOUNCES
    c.glossy_bounces = BOUNCES
    c.transmission_bounces = BOUNCES
    c.volume_bounces = BOUNCES
    c.transparent_max_bounces = BOUNCES
    c.caustics_reflective = True
    c.caustics_refractive = True
    c.blur_glossy = 0.0
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    sc.render.film_transparent = False
    vs = sc.view_settings
    vs.view_transform = "Standard"
    vs.look = "None"
    vs.exposure = 0.0
    vs.gamma = 1.0
    im = sc.render.image_settings
    im.file_format = "OPEN_EXR"
    im.color_mode = "RGB"
    im.color_depth = "32"
    im.exr_codec = "ZIP"


def material(name, base=(0.8, 0.8, 0.8), metallic=0.0, roughness=0.5, specular=0.5, ior=1.5,
             transmission=0.0, emission=None, strength=0.0, coat=0.0, coat_roughness=0.03,
             sheen=0.0, sheen_roughness=0.5):
    """A Principled BSDF material. GGX (single scattering) rather than Blender's default
    multiscatter GGX, since glTF's BRDF is single-scattering GGX."""
    m = bpy.data.materials.new(name)
    p = m.node_tree.nodes["Principled BSDF"]
    p.distribution = "GGX"
    p.inputs["Base Color"].default_value = (*base, 1.0)
    p.inputs["Metallic"].default_value = metallic
    p.inputs["Roughness"].default_value = roughness
    p.inputs["Specular IOR Level"].default_value = specular
    p.inputs["IOR"].default_value = ior
    p.inputs["Transmission Weight"].default_value = transmission
    if emission is not None:
        p.inputs["Emission Color"].default_value = (*emission, 1.0)
        p.inputs["Emission Strength"].default_value = strength
    p.inputs["Coat Weight"].default_value = coat
    p.inputs["Coat Roughness"].default_value = coat_roughness
    p.inputs["Sheen Weight"].default_value = sheen
    p.inputs["Sheen Roughness"].default_value = sheen_roughness
    return m


def gltf_output_node(m, thickness):
    """The exporter's "glTF Material Output" node group with a Thickness (what makes it write
    KHR_materials_volume; see io_scene_gltf2/blender/exp/material/extensions/volume.py)."""
    name = "glTF Material Output"
    group = bpy.data.node_groups.get(name)
    if group is None:
        group = bpy.data.node_groups.new(name, "ShaderNodeTree")
        group.interface.new_socket("Occlusion", socket_type="NodeSocketFloat")
        t = group.interface.new_socket("Thickness", socket_type="NodeSocketFloat")
        t.default_value = 0.0
        group.nodes.new("NodeGroupOutput")
        group.nodes.new("NodeGroupInput").location = (-200, 0)
    node = m.node_tree.nodes.new("ShaderNodeGroup")
    node.node_tree = group
    node.inputs["Thickness"].default_value = thickness
    return node


def volume_absorption(m, color, density):
    """Cycles' Volume Absorption inside the material: absorption coefficient (1 - color) * density
    per metre (checked by a test render, see README). The exporter writes attenuationColor = color
    and attenuationDistance = 1 / density."""
    nt = m.node_tree
    v = nt.nodes.new("ShaderNodeVolumeAbsorption")
    v.inputs["Color"].default_value = (*color, 1.0)
    v.inputs["Density"].default_value = density
    nt.links.new(v.outputs[0], nt.nodes["Material Output"].inputs["Volume"])


def link(obj):
    bpy.context.scene.collection.objects.link(obj)
    return obj


def mesh_obj(op, mat=None, location=(0, 0, 0), rotation=(0, 0, 0), scale=(1, 1, 1), smooth=False,
             name=None, **kw):
    op(location=location, rotation=rotation, **kw)
    o = bpy.context.object
    o.scale = scale
    if name:
        o.name = name
        o.data.name = name
    if smooth:
        for poly in o.data.polygons:
            poly.use_smooth = True
    if mat is not None:
        o.data.materials.append(mat)
    return o


def box(mat, lo, hi, name=None):
    """An axis-aligned box from corner lo to corner hi (scale applied into the mesh)."""
    lo, hi = Vector(lo), Vector(hi)
    o = mesh_obj(bpy.ops.mesh.primitive_cube_add, mat, location=(lo + hi) / 2, size=1.0, name=name)
    o.scale = hi - lo
    bpy.ops.object.transform_apply(location=False, rotation=False, scale=True)
    return o


def plane(mat, location, size, rotation=(0, 0, 0), name=None, scale=(1, 1, 1)):
    return mesh_obj(bpy.ops.mesh.primitive_plane_add, mat, location=location, rotation=rotation,
                    size=size, name=name, scale=scale)


def look_at(obj, target):
    d = Vector(target) - obj.location
    obj.rotation_euler = d.to_track_quat("-Z", "Y").to_euler()


def camera(location, target, lens=50.0):
    cam = bpy.data.cameras.new("Camera")
    cam.lens = lens
    cam.sensor_width = 36.0
    cam.sensor_fit = "AUTO"
    o = link(bpy.data.objects.new("Camera", cam))
    o.location = location
    look_at(o, target)
    bpy.context.scene.camera = o
    return o


def lamp(kind, name, location, target=None, energy=100.0, color=(1, 1, 1), **kw):
    """A lamp that glTF can carry exactly: point/spot radius 0, sun angle 0 (delta lights)."""
    L = bpy.data.lights.new(name, kind)
    L.energy = energy
    L.color = color
    if kind == "SUN":
        L.angle = 0.0
    else:
        L.shadow_soft_size = 0.0
    for k, v in kw.items():
        setattr(L, k, v)
    o = link(bpy.data.objects.new(name, L))
    o.location = location
    if target is not None:
        look_at(o, target)
    return o


def image_from_array(name, rgb, non_color=False):
    """A Blender image holding rgb (H x W x 3 floats in [0, 1], row 0 at the top), packed as PNG."""
    h, w, _ = rgb.shape
    img = bpy.data.images.new(name, w, h, alpha=False)
    if non_color:
        img.colorspace_settings.name = "Non-Color"  # before the pixels: setting it reloads them
    rgba = np.ones((h, w, 4), dtype=np.float32)
    rgba[..., :3] = rgb[::-1]  # Blender's rows start at the bottom
    img.pixels.foreach_set(rgba.ravel())
    path = os.path.join(tempfile.gettempdir(), f"pathfarm_suite_{name}.png")
    img.filepath_raw = path
    img.file_format = "PNG"
    img.save()
    bpy.data.images.remove(img)
    img = bpy.data.images.load(path, check_existing=False)
    img.name = name
    if non_color:
        img.colorspace_settings.name = "Non-Color"
    px = np.empty(w * h * 4, dtype=np.float32)
    img.pixels.foreach_get(px)
    assert np.abs(px.reshape(h, w, 4)[::-1, :, :3] - rgb).max() < 1e-6, f"{name}: PNG differs"
    img.pack()
    return img


# ----------------------------------------------------------------------------------------------
# Scenes. Blender is Z-up; the exporter writes glTF Y-up (glTF (x, y, z) = Blender (x, z, -y)).


def scene_sunroom():
    wall = material("Wall", (0.8, 0.78, 0.74), roughness=1.0, specular=0.0)
    blue = material("BlueWall", (0.25, 0.4, 0.7), roughness=1.0, specular=0.0)
    floor = material("Floor", (0.55, 0.38, 0.24), roughness=1.0, specular=0.0)
    table = material("Table", (0.7, 0.15, 0.1), roughness=1.0, specular=0.0)
    t = 0.1  # wall thickness; interior x in [-2, 2], y in [-2.5, 2.5], z in [0, 2.6]
    box(floor, (-2 - t, -2.5 - t, -t), (2 + t, 2.5 + t, 0), "Floor")
    box(wall, (-2 - t, -2.5 - t, 2.6), (2 + t, 2.5 + t, 2.6 + t), "Ceiling")
    box(wall, (-2 - t, -2.5 - t, 0), (-2, 2.5 + t, 2.6), "WallWest")
    box(blue, (-2, 2.5, 0), (2, 2.5 + t, 2.6), "WallNorth")
    box(wall, (-2, -2.5 - t, 0), (2, -2.5, 2.6), "WallSouth")
    # East wall (x = 2) with a window y in [-1, 1], z in [0.8, 2.2]
    box(wall, (2, -2.5 - t, 0), (2 + t, 2.5 + t, 0.8), "WallEastLow")
    box(wall, (2, -2.5 - t, 2.2), (2 + t, 2.5 + t, 2.6), "WallEastHigh")
    box(wall, (2, -2.5 - t, 0.8), (2 + t, -1.0, 2.2), "WallEastLeft")
    box(wall, (2, 1.0, 0.8), (2 + t, 2.5 + t, 2.2), "WallEastRight")
    box(table, (-0.2, -0.5, 0), (0.6, 0.5, 0.55), "Block")
    mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, wall, location=(-0.9, 1.2, 0.35),
             radius=0.35, segments=32, ring_count=16, smooth=True, name="Ball")
    # Sun from the east, 40 degrees above the horizon, a little from the south.
    el, az = math.radians(40), math.radians(-15)
    d = Vector((math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)))
    sun = lamp("SUN", "Sun", (4, 0, 4), energy=20.0, color=(1.0, 0.95, 0.88))
    sun.rotation_euler = d.to_track_quat("Z", "Y").to_euler()  # the lamp shines along its -Z
    camera((-1.85, -2.3, 1.55), (0.6, 0.7, 0.6), lens=20.0)
    return {
        "covers": "Sun lamp (KHR directional) through a window into a closed room of Lambertian "
                  "walls: almost all light is indirect (long diffuse paths, colour bleeding).",
        "exact_counterparts": True,
        "exact_note": "Lambertian walls (Principled, Specular IOR Level 0, roughness 1 -> glTF "
                      "KHR_materials_specular specularFactor 0); sun angle 0 = a directional light; "
                      "black world.",
    }


def scene_product_point():
    floor = material("Floor", (0.5, 0.5, 0.52), roughness=0.8)
    back = material("Backdrop", (0.7, 0.7, 0.72), roughness=0.9)
    orange = material("Diffuse", (0.8, 0.3, 0.05), roughness=0.6)
    gold = material("Gold", (1.0, 0.77, 0.35), metallic=1.0, roughness=0.35)
    chrome = material("Chrome", (0.95, 0.95, 0.95), metallic=1.0, roughness=0.1)
    panel = material("Panel", (0.0, 0.0, 0.0), roughness=1.0,
                     emission=(1.0, 0.97, 0.9), strength=12.0)
    plane(floor, (0, 0, 0), 12, name="Floor")
    plane(back, (0, 3, 3), 12, rotation=(math.radians(90), 0, 0), name="Backdrop")
    mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, orange, location=(-1.3, 0.2, 0.6), radius=0.6,
             segments=48, ring_count=24, smooth=True, name="DiffuseSphere")
    mesh_obj(bpy.ops.mesh.primitive_monkey_add, gold, location=(0.1, 0.5, 0.75),
             rotation=(math.radians(-10), 0, math.radians(-20)), size=1.2, smooth=True,
             name="GoldMonkey")
    mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, chrome, location=(1.4, -0.1, 0.55), radius=0.55,
             segments=48, ring_count=24, smooth=True, name="ChromeSphere")
    # Emissive panel, 1.6 x 0.8, upper left, facing the objects.
    p = plane(panel, (-2.8, -0.5, 2.2), 1.0, scale=(1.6, 0.8, 1.0), name="EmissivePanel")
    look_at(p, (0, 0.3, 0.5))
    p.rotation_euler = (Vector(p.location) - Vector((0, 0.3, 0.5))).to_track_quat("Z", "Y").to_euler()
    lamp("POINT", "Key", (2.5, -2.5, 3.5), energy=600.0, color=(1.0, 0.9, 0.8))
    lamp("POINT", "Fill", (-1.0, -3.5, 1.5), energy=120.0, color=(0.8, 0.9, 1.0))
    camera((0.0, -6.0, 2.3), (0.0, 0.3, 0.6), lens=45.0)
    return {
        "covers": "Point lamps (KHR point, candela) and an emissive panel (emissiveFactor x "
                  "KHR_materials_emissive_strength) on diffuse, rough-gold and near-mirror "
                  "metal Principled objects: the lamp/emitter unit balance.",
        "exact_counterparts": False,
        "exact_note": "Principled dielectric/metal with GGX (single scattering) -> glTF "
                      "metallic-roughness; Cycles' dielectric layering (albedo-scaled diffuse "
                      "under the specular layer) is not exactly glTF's fresnel_mix, so small "
                      "differences on rough dielectrics are expected." + LAYER_NOTE,
        "documented_difference": 0.031,
    }


def scene_product_spot():
    floor = material("Floor", (0.6, 0.6, 0.6), roughness=0.9)
    white = material("White", (0.8, 0.8, 0.8), roughness=0.7)
    red = material("Red", (0.7, 0.08, 0.06), roughness=0.5)
    glass = material("Glass", (1.0, 1.0, 1.0), roughness=0.0, transmission=1.0, ior=1.5)
    gltf_output_node(glass, 1.0)  # a closed refracting solid (KHR_materials_volume), no absorption
    plane(floor, (0, 0, 0), 12, name="Floor")
    mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, glass, location=(0.2, -0.3, 0.6), radius=0.6,
             segments=64, ring_count=32, smooth=True, name="GlassSphere")
    mesh_obj(bpy.ops.mesh.primitive_cube_add, glass, location=(1.5, 0.6, 0.4), size=0.8,
             rotation=(0, 0, math.radians(30)), name="GlassCube")
    mesh_obj(bpy.ops.mesh.primitive_cube_add, white, location=(-1.3, 0.8, 0.5), size=1.0,
             rotation=(0, 0, math.radians(-20)), name="WhiteCube")
    mesh_obj(bpy.ops.mesh.primitive_cylinder_add, red, location=(-0.6, -1.2, 0.35), radius=0.3,
             depth=0.7, vertices=48, name="RedCylinder")
    lamp("SPOT", "Spot", (1.5, -2.5, 4.5), target=(0, 0, 0.3), energy=1500.0,
         spot_size=math.radians(55), spot_blend=0.35, show_cone=False)
    camera((0.0, -6.5, 3.2), (0.0, 0.0, 0.4), lens=40.0)
    return {
        "covers": "A SPOT lamp with a soft blend (spot_size 55 deg, spot_blend 0.35) on glass "
                  "(transmission 1, roughness 0, IOR 1.5, closed solids) and diffuse objects.",
        "exact_counterparts": False,
        "exact_note": "Geometry and materials map exactly (glass = transmission 1 + "
                      "KHR_materials_volume thickness, no attenuation), but Blender's spot cone "
                      "falloff is not glTF's: Cycles uses smoothstep((cos t - cos(size/2)) / "
                      "(blend * (1 - cos(size/2)))), the exporter writes inner = size/2 * (1 - "
                      "blend), outer = size/2, and glTF's falloff is ((cos t - cos outer) / "
                      "(cos inner - cos outer))^2 clamped. Match Cycles by recovering size and "
                      "blend from the cone angles (see README). Caustics from the delta spot "
                      "through glass are unreachable by path tracing in both renderers.",
        "documented_difference": -0.2673,
    }


def make_sky():
    """Equirect sky 512 x 256: a gradient plus a sun disc of high radiance. Returns (rgb with row 0
    at the top, sun direction in Blender coordinates)."""
    w, h = 512, 256
    u = (np.arange(w) + 0.5) / w
    v = 1.0 - (np.arange(h) + 0.5) / h  # row 0 (top) has v near 1
    U, V = np.meshgrid(u, v)
    phi = (0.5 - U) * 2 * np.pi  # Blender: u = 0.5 faces +X, u = 0.25 faces +Y
    el = (V - 0.5) * np.pi
    d = np.stack([np.cos(el) * np.cos(phi), np.cos(el) * np.sin(phi), np.sin(el)], -1)
    horizon = np.array([0.95, 0.97, 1.0])
    zenith = np.array([0.18, 0.35, 0.85])
    ground = np.array([0.12, 0.1, 0.08])
    s = np.clip(np.sin(el), 0, 1)[..., None]
    sky = horizon * (1 - s) ** 3 + zenith * (1 - (1 - s) ** 3)
    rgb = np.where(el[..., None] >= 0, sky, ground)
    sun_el, sun_az = math.radians(38), math.radians(25)
    sd = np.array([math.cos(sun_el) * math.cos(sun_az), math.cos(sun_el) * math.sin(sun_az),
                   math.sin(sun_el)])
    cosang = d @ sd
    sun_radius = math.radians(2.5)
    disc = cosang >= math.cos(sun_radius)
    rgb[disc] = np.array([1.0, 0.93, 0.82]) * 600.0
    return rgb.astype(np.float32), sd


def write_env():
    """Writes env/sky.hdr (what the World uses) and env/sky.exr with exactly the values Blender
    reads back from the .hdr (RGBE-quantised), so the two files hold the same numbers."""
    os.makedirs(os.path.join(HERE, "env"), exist_ok=True)
    rgb, sun = make_sky()
    h, w, _ = rgb.shape
    img = bpy.data.images.new("sky_gen", w, h, alpha=False, float_buffer=True)
    rgba = np.ones((h, w, 4), dtype=np.float32)
    rgba[..., :3] = rgb[::-1]
    img.pixels.foreach_set(rgba.ravel())
    hdr_path = os.path.join(HERE, "env", "sky.hdr")
    img.filepath_raw = hdr_path
    img.file_format = "HDR"
    img.save()
    back = bpy.data.images.load(hdr_path, check_existing=False)
    px = np.empty(w * h * 4, dtype=np.float32)
    back.pixels.foreach_get(px)
    exr = bpy.data.images.new("sky_exr", w, h, alpha=False, float_buffer=True)
    exr.pixels.foreach_set(px)
    exr_path = os.path.join(HERE, "env", "sky.exr")
    save_exr(exr, exr_path)
    chk = load_exr(exr_path)
    assert np.array_equal(chk, px.reshape(h, w, 4)[..., :3]), "sky.exr differs from sky.hdr"
    bpy.data.images.remove(img)
    bpy.data.images.remove(exr)
    return hdr_path, sun


def set_world_env(path, strength=1.0):
    world = bpy.context.scene.world
    nt = world.node_tree
    env = nt.nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.load(path)
    bg = nt.nodes["Background"]
    bg.inputs["Color"].default_value = (1, 1, 1, 1)
    bg.inputs["Strength"].default_value = strength
    nt.links.new(env.outputs["Color"], bg.inputs["Color"])
    return env


def scene_hdr_outdoor():
    hdr_path, sun = write_env()
    set_world_env(hdr_path, 1.0)
    ground = material("Ground", (0.35, 0.33, 0.3), roughness=1.0, specular=0.0)
    blue = material("Paint", (0.3, 0.45, 0.75), roughness=0.4)
    metal = material("Metal", (0.9, 0.9, 0.92), metallic=1.0, roughness=0.2)
    white = material("White", (0.8, 0.8, 0.8), roughness=0.8)
    plane(ground, (0, 0, 0), 100, name="Ground")
    mesh_obj(bpy.ops.mesh.primitive_monkey_add, blue, location=(0, 0, 0.62),
             rotation=(math.radians(-15), 0, math.radians(-130)), size=1.4, smooth=True,
             name="Monkey")
    mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, metal, location=(-0.6, 1.8, 0.6), radius=0.6,
             segments=48, ring_count=24, smooth=True, name="MetalSphere")
    mesh_obj(bpy.ops.mesh.primitive_cube_add, white, location=(1.4, 1.2, 0.4), size=0.8,
             rotation=(0, 0, math.radians(20)), name="Box")
    camera((4.0, -3.3, 1.5), (0.0, 0.7, 0.5), lens=35.0)
    return {
        "covers": "An environment map only (world Environment Texture, equirect, default "
                  "mapping, strength 1): a gradient sky with a small sun disc of radiance 600 "
                  "(about 2/3 of the ground's irradiance), on objects and a ground plane.",
        "exact_counterparts": False,
        "exact_note": "glTF cannot carry the world: the environment is given in 'environment' "
                      "(Blender's equirect convention, README). Cycles looks the map up with "
                      "bilinear interpolation ('Linear', the node's default) of pixel centres." + LAYER_NOTE,
        "environment": {
            "file": "env/sky.hdr",
            "file_exr": "env/sky.exr",
            "strength": 1.0,
            "rotation_degrees": [0.0, 0.0, 0.0],
            "width": 512,
            "height": 256,
            "interpolation": "Linear (bilinear), projection EQUIRECTANGULAR, extension REPEAT",
            "sun_direction_blender": [round(x, 6) for x in sun.tolist()],
            "sun_direction_gltf": [round(sun[0], 6), round(sun[2], 6), round(-sun[1], 6)],
            "sun_angular_radius_degrees": 2.5,
        },
        "documented_difference": -0.0009,
    }


def scene_glass_volume():
    floor = material("Floor", (0.75, 0.75, 0.75), roughness=0.9, specular=0.0)
    back = material("Backdrop", (0.5, 0.55, 0.6), roughness=1.0, specular=0.0)
    glass_a = material("AmberGlass", (1.0, 1.0, 1.0), roughness=0.0, transmission=1.0, ior=1.5)
    volume_absorption(glass_a, (0.9, 0.55, 0.2), 2.0)
    gltf_output_node(glass_a, 1.4)
    glass_b = material("TealGlass", (1.0, 1.0, 1.0), roughness=0.0, transmission=1.0, ior=1.5)
    volume_absorption(glass_b, (0.3, 0.8, 0.75), 1.5)
    gltf_output_node(glass_b, 0.8)
    light = material("Emitter", (0.0, 0.0, 0.0), roughness=1.0,
                     emission=(1.0, 1.0, 1.0), strength=15.0)
    plane(floor, (0, 0, 0), 10, name="Floor")
    plane(back, (0, 2.5, 2.5), 10, rotation=(math.radians(90), 0, 0), name="Backdrop")
    mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, glass_a, location=(-0.6, 0.2, 0.7), radius=0.7,
             segments=64, ring_count=32, smooth=True, name="AmberSphere")
    mesh_obj(bpy.ops.mesh.primitive_cylinder_add, glass_b, location=(0.9, -0.2, 0.6), radius=0.4,
             depth=1.2, vertices=48, name="TealCylinder")
    # An area-like emitter mesh: a 1.5 x 1.5 quad above and in front, facing down at the objects.
    p = plane(light, (0.5, -2.0, 3.2), 1.5, name="AreaEmitter")
    p.rotation_euler = (Vector(p.location) - Vector((0, 0, 0.5))).to_track_quat("Z", "Y").to_euler()
    camera((0.0, -5.5, 2.2), (0.1, 0.1, 0.55), lens=45.0)
    return {
        "covers": "Solid glass with volume absorption (Principled transmission 1 + Volume "
                  "Absorption; exported as KHR_materials_transmission + KHR_materials_volume) lit "
                  "by an emissive quad: refraction, absorption with path length, caustics from an "
                  "area emitter (found by path tracing).",
        "exact_counterparts": False,
        "exact_note": "Absorption laws differ. Cycles' Volume Absorption (colour C, density D) "
                      "absorbs with sigma_a = (1 - C) * D per metre (checked by a test render: "
                      "transmittance through 1 m of C=(0.5,0.25,1), D=1 is (0.607,0.472,1) = "
                      "exp(-(1-C))). The exporter writes attenuationColor = C and "
                      "attenuationDistance = 1/D, which in glTF means sigma_a = -ln(C) * D. To "
                      "match Cycles use sigma_a = (1 - C) / attenuationDistance, i.e. the "
                      "attenuationColor given in 'cycles_equivalent_attenuation'.",
        "cycles_equivalent_attenuation": {
            "AmberGlass": {"attenuationDistance": 0.5,
                           "attenuationColor": [round(math.exp(-(1 - c)), 6)
                                                for c in (0.9, 0.55, 0.2)],
                           "sigma_a_per_m": [round((1 - c) * 2.0, 6) for c in (0.9, 0.55, 0.2)]},
            "TealGlass": {"attenuationDistance": round(1 / 1.5, 6),
                          "attenuationColor": [round(math.exp(-(1 - c)), 6)
                                               for c in (0.3, 0.8, 0.75)],
                          "sigma_a_per_m": [round((1 - c) * 1.5, 6) for c in (0.3, 0.8, 0.75)]},
        },
        "documented_difference": -0.0019,
    }


def tile_textures(n=512, tiles=8):
    """Base colour (sRGB), tangent-space normal map (OpenGL, +Y up) and glTF metallic-roughness
    (G roughness, B metallic) of a tiled floor: tiles of a few colours, grooves between them, every
    tile with its own roughness, some tiles metallic."""
    rng = np.random.default_rng(7)
    y, x = np.mgrid[0:n, 0:n].astype(np.float64) + 0.5
    ts = n / tiles
    tx, ty = (x // ts).astype(int), (y // ts).astype(int)
    fx, fy = (x % ts) / ts, (y % ts) / ts
    palette = np.array([[0.75, 0.72, 0.65], [0.55, 0.25, 0.18], [0.2, 0.32, 0.45],
                        [0.85, 0.8, 0.55], [0.35, 0.4, 0.3]])
    ids = rng.integers(0, len(palette), size=(tiles, tiles))
    base = palette[ids[ty, tx]]
    # Height: 1 on the tile, falling to 0 in a groove of width g at the edges.
    g = 0.08
    edge = np.minimum(np.minimum(fx, 1 - fx), np.minimum(fy, 1 - fy))
    hgt = np.clip(edge / g, 0, 1)
    hgt = hgt * hgt * (3 - 2 * hgt)
    groove = hgt < 0.999
    base = np.where(groove[..., None], base * 0.5, base)
    # Normal from the height (image rows go down, so d/dv = -d/drow).
    strength = 4.0 / ts
    dhdx = np.gradient(hgt, axis=1) / strength * 0.25
    dhdy = -np.gradient(hgt, axis=0) / strength * 0.25
    nrm = np.stack([-dhdx, -dhdy, np.ones_like(hgt)], -1)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    normal = nrm * 0.5 + 0.5
    rough = 0.25 + 0.6 * rng.random((tiles, tiles))
    metal = (rng.random((tiles, tiles)) < 0.25).astype(float)
    mr = np.zeros((n, n, 3))
    mr[..., 1] = np.where(groove, 0.9, rough[ty, tx])
    mr[..., 2] = np.where(groove, 0.0, metal[ty, tx])
    # Quantise to 8 bits here so that what Blender renders is what the PNG holds.
    q = lambda a: np.round(np.clip(a, 0, 1) * 255) / 255
    return q(base), q(normal), q(mr)


def textured_material(name, base, normal, mr, use_normal=True):
    m = bpy.data.materials.new(name)
    nt = m.node_tree
    p = nt.nodes["Principled BSDF"]
    p.distribution = "GGX"
    tb = nt.nodes.new("ShaderNodeTexImage")
    tb.image = base
    nt.links.new(tb.outputs["Color"], p.inputs["Base Color"])
    tm = nt.nodes.new("ShaderNodeTexImage")
    tm.image = mr
    sep = nt.nodes.new("ShaderNodeSeparateColor")
    nt.links.new(tm.outputs["Color"], sep.inputs["Color"])
    nt.links.new(sep.outputs["Green"], p.inputs["Roughness"])
    nt.links.new(sep.outputs["Blue"], p.inputs["Metallic"])
    if use_normal:
        tn = nt.nodes.new("ShaderNodeTexImage")
        tn.image = normal
        nm = nt.nodes.new("ShaderNodeNormalMap")
        nt.links.new(tn.outputs["Color"], nm.inputs["Color"])
        nt.links.new(nm.outputs["Normal"], p.inputs["Normal"])
    for t in (tb, tm) + ((tn,) if use_normal else ()):
        t.interpolation = "Linear"
    return m


def scene_textured_pbr():
    base, normal, mr = tile_textures()
    ib = image_from_array("tiles_basecolor", base)
    inn = image_from_array("tiles_normal", normal, non_color=True)
    imr = image_from_array("tiles_metallic_roughness", mr, non_color=True)
    tiles = textured_material("Tiles", ib, inn, imr, use_normal=True)
    plain = textured_material("TilesNoNormal", ib, inn, imr, use_normal=False)
    back = material("Backdrop", (0.6, 0.6, 0.6), roughness=0.9)
    plane(tiles, (0, 0, 0), 5, name="TiledFloor")
    plane(back, (0, 2.5, 2.5), 8, rotation=(math.radians(90), 0, 0), name="Backdrop")
    mesh_obj(bpy.ops.mesh.primitive_cube_add, tiles, location=(-0.7, 0.4, 0.6), size=1.2,
             rotation=(0, 0, math.radians(35)), name="TiledCube")
    mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, plain, location=(0.9, -0.3, 0.55), radius=0.55,
             segments=48, ring_count=24, smooth=True, name="TexturedSphere")
    lamp("POINT", "Key", (2.0, -2.0, 3.0), energy=500.0)
    lamp("POINT", "Rim", (-2.5, 1.0, 2.5), energy=250.0, color=(0.9, 0.95, 1.0))
    camera((0.3, -4.8, 2.8), (0.0, 0.2, 0.3), lens=40.0)
    return {
        "covers": "Textured PBR: sRGB base colour, tangent-space normal map and "
                  "metallic-roughness map (512 x 512, generated), on a floor, a cube (normal "
                  "mapped) and a smooth sphere (no normal map), under two point lamps.",
        "exact_counterparts": False,
        "exact_note": "Textures and maps map exactly. Tangents are not exported (exporter "
                      "default export_tangents=False): Cycles uses MikkTSpace tangents; normal "
                      "maps are only on flat faces, where per-triangle tangents from the UVs "
                      "agree. Cycles filters textures bilinearly ('Linear')." + LAYER_NOTE,
        "documented_difference": 0.0107,
    }


def scene_clearcoat():
    floor = material("Floor", (0.55, 0.55, 0.55), roughness=0.8)
    back = material("Backdrop", (0.65, 0.65, 0.68), roughness=0.9)
    coated = material("CoatedRed", (0.7, 0.05, 0.04), roughness=0.6, coat=1.0, coat_roughness=0.1)
    uncoated = material("UncoatedRed", (0.7, 0.05, 0.04), roughness=0.6)
    coated_metal = material("CoatedMetal", (0.2, 0.35, 0.8), metallic=1.0, roughness=0.4,
                            coat=1.0, coat_roughness=0.15)
    sheen = material("Velvet", (0.15, 0.05, 0.3), roughness=0.9, sheen=1.0, sheen_roughness=0.3)
    strip = material("Strip", (0, 0, 0), roughness=1.0, emission=(1, 1, 1), strength=20.0)
    plane(floor, (0, 0, 0), 12, name="Floor")
    plane(back, (0, 3, 3), 12, rotation=(math.radians(90), 0, 0), name="Backdrop")
    mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, coated, location=(-1.2, 0.0, 0.55), radius=0.55,
             segments=48, ring_count=24, smooth=True, name="CoatedSphere")
    mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, uncoated, location=(0.05, 0.4, 0.55),
             radius=0.55, segments=48, ring_count=24, smooth=True, name="UncoatedSphere")
    mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, coated_metal, location=(1.3, 0.0, 0.55),
             radius=0.55, segments=48, ring_count=24, smooth=True, name="CoatedMetalSphere")
    mesh_obj(bpy.ops.mesh.primitive_monkey_add, sheen, location=(0.2, -1.2, 0.45), size=0.8,
             rotation=(math.radians(-20), 0, 0), smooth=True, name="VelvetMonkey")
    s = plane(strip, (0.0, -2.0, 3.0), 1.0, scale=(3.0, 0.3, 1.0), name="EmissiveStrip")
    s.rotation_euler = (Vector(s.location) - Vector((0, 0, 0.5))).to_track_quat("Z", "Y").to_euler()
    lamp("POINT", "Key", (2.5, -2.0, 3.0), energy=400.0)
    camera((0.0, -5.5, 2.0), (0.0, 0.0, 0.5), lens=42.0)
    return {
        "covers": "Principled coat (weight 1, coat roughness 0.1/0.15) over a rough dielectric "
                  "and a rough metal, beside the same base uncoated, and a sheen material "
                  "(KHR_materials_clearcoat, KHR_materials_sheen), under a point lamp and an "
                  "emissive strip.",
        "exact_counterparts": False,
        "exact_note": "glTF can express both (the exporter writes KHR_materials_clearcoat and "
                      "KHR_materials_sheen), but Cycles' models differ from glTF's: the coat "
                      "attenuates the base by its Fresnel albedo (energy-conserving layering) and "
                      "sheen is Cycles' microfibre model, not glTF's Charlie sheen. The tracer "
                      "ignores both extensions (warning) today.",
        "documented_difference": 0.0261,
    }


def scene_instanced():
    floor = material("Floor", (0.6, 0.6, 0.58), roughness=0.9, specular=0.0)
    clay = material("Clay", (0.75, 0.55, 0.45), roughness=0.7)
    metal = material("Steel", (0.8, 0.82, 0.85), metallic=1.0, roughness=0.3)
    plane(floor, (0, 0, 0), 30, name="Floor")
    bpy.ops.mesh.primitive_monkey_add(size=0.5)
    monkey = bpy.context.object
    monkey.data.name = "MonkeyMesh"
    for poly in monkey.data.polygons:
        poly.use_smooth = True
    monkey.data.materials.append(clay)
    bpy.ops.mesh.primitive_ico_sphere_add(radius=0.22, subdivisions=2)
    ball = bpy.context.object
    ball.data.name = "BallMesh"
    ball.data.materials.append(metal)
    rng = np.random.default_rng(3)
    n = 0
    for j in range(10):
        for i in range(20):
            x = (i - 9.5) * 0.6 + rng.uniform(-0.1, 0.1)
            y = (j - 2.0) * 0.75 + rng.uniform(-0.1, 0.1)
            src = ball if (i + j) % 4 == 0 else monkey
            o = link(bpy.data.objects.new(f"{src.data.name}.{n:03d}", src.data))
            s = rng.uniform(0.8, 1.2)
            o.scale = (s, s, s)
            z = 0.22 * s if src is ball else 0.25 * s
            o.location = (x, y, z)
            o.rotation_euler = (0, 0, rng.uniform(-0.8, 0.8) + (0 if src is ball else math.pi))
            n += 1
    # The templates go; their meshes stay, used by the 200 instances.
    bpy.data.objects.remove(monkey)
    bpy.data.objects.remove(ball)
    sun = lamp("SUN", "Sun", (0, 0, 10), energy=3.0, color=(1.0, 0.96, 0.9))
    d = Vector((-0.4, -0.6, 0.7)).normalized()
    sun.rotation_euler = d.to_track_quat("Z", "Y").to_euler()
    lamp("POINT", "Fill", (-4.0, -5.0, 3.0), energy=800.0, color=(0.8, 0.88, 1.0))
    camera((0.0, -7.5, 3.6), (0.0, 1.0, 0.0), lens=35.0)
    return {
        "covers": "200 linked duplicates of two meshes (a smooth monkey and an ico sphere) on a "
                  "floor: the exporter writes each mesh once, referenced by many nodes with their "
                  "own TRS; a sun lamp plus a point fill lamp.",
        "exact_counterparts": False,
        "exact_note": ("Principled clay/steel with GGX -> metallic-roughness; sun angle 0."
                       + LAYER_NOTE),
        "documented_difference": -0.002,
    }


SCENES = {
    "sunroom": scene_sunroom,
    "product_point": scene_product_point,
    "product_spot": scene_product_spot,
    "hdr_outdoor": scene_hdr_outdoor,
    "glass_volume": scene_glass_volume,
    "textured_pbr": scene_textured_pbr,
    "clearcoat": scene_clearcoat,
    "instanced": scene_instanced,
}


# ----------------------------------------------------------------------------------------------
# Export, render, measure


def export_glb(name):
    path = os.path.join(HERE, f"{name}.glb")
    # Default settings; cameras and lamps are off by default in the exporter and are what we need.
    bpy.ops.export_scene.gltf(filepath=path, export_format="GLB", export_cameras=True,
                              export_lights=True)
    return path


def save_exr(img, path):
    sc = bpy.context.scene
    im = sc.render.image_settings
    im.file_format = "OPEN_EXR"
    im.color_mode = "RGB"
    im.color_depth = "32"
    im.exr_codec = "ZIP"
    img.save_render(path, scene=sc)


def load_exr(path):
    img = bpy.data.images.load(path, check_existing=False)
    w, h = img.size
    px = np.empty(w * h * 4, dtype=np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px.reshape(h, w, 4)[..., :3]  # row 0 at the bottom


def render_reference(name, spp):
    sc = bpy.context.scene
    per = spp // PARTS
    parts, means, secs = [], [], []
    tmp = tempfile.mkdtemp(prefix="pathfarm_suite_")
    for k in range(PARTS):
        cycles_settings(sc, per, BASE_SEED + k)
        sc.render.filepath = os.path.join(tmp, f"{name}_{k}.exr")
        t = time.time()
        bpy.ops.render.render(write_still=True)
        secs.append(time.time() - t)
        px = load_exr(sc.render.filepath).astype(np.float64)
        parts.append(px)
        means.append(px.mean(axis=(0, 1)))
        print(f"  {name} part {k}: {per} spp seed {BASE_SEED + k} {secs[-1]:.1f} s "
              f"mean {means[-1]}", flush=True)
    img = np.mean(parts, axis=0).astype(np.float32)
    means = np.array(means)
    se = means.std(axis=0, ddof=1) / math.sqrt(PARTS)
    h, w, _ = img.shape
    out = bpy.data.images.new(f"{name}_ref", w, h, alpha=False, float_buffer=True)
    rgba = np.ones((h, w, 4), dtype=np.float32)
    rgba[..., :3] = img
    out.pixels.foreach_set(rgba.ravel())
    os.makedirs(os.path.join(HERE, "cycles"), exist_ok=True)
    path = os.path.join(HERE, "cycles", f"{name}.exr")
    save_exr(out, path)
    back = load_exr(path)
    assert np.array_equal(back, img), f"{path} does not hold the rendered values"
    mean = img.astype(np.float64).mean(axis=(0, 1))
    return {
        "spp": spp,
        "render_seconds": round(sum(secs), 1),
        "mean_rgb": [round(float(x), 6) for x in mean],
        "mean_rgb_stderr": [round(float(x), 6) for x in se],
        "mean_rgb_rel_stderr": [round(float(s / m), 6) if m > 0 else None
                                for s, m in zip(se, mean)],
        "parts": {"count": PARTS, "spp_each": per,
                  "seeds": [BASE_SEED + k for k in range(PARTS)],
                  "means_rgb": [[round(float(x), 6) for x in m] for m in means],
                  "seconds": [round(s, 1) for s in secs]},
    }


def check_equirect_convention():
    """Renders tiny views of an environment whose quadrants have distinct colours and checks which
    image column faces which Blender axis (the README's convention)."""
    reset()
    w, h = 64, 32
    rgb = np.zeros((h, w, 3), dtype=np.float32)
    u = (np.arange(w) + 0.5) / w
    # Red = 1 + region of u centred on 0 (-X), 0.25 (+Y), 0.5 (+X), 0.75 (-Y) in Blender's convention
    region = np.floor(u * 4 + 0.5) % 4
    rgb[:, :, 0] = (region + 1)[None, :]
    rgb[: h // 4, :, 1] = 10.0  # top rows (v near 1) -> green
    img = bpy.data.images.new("conv", w, h, alpha=False, float_buffer=True)
    rgba = np.ones((h, w, 4), dtype=np.float32)
    rgba[..., :3] = rgb[::-1]
    img.pixels.foreach_set(rgba.ravel())
    world = bpy.context.scene.world
    nt = world.node_tree
    env = nt.nodes.new("ShaderNodeTexEnvironment")
    env.image = img
    env.interpolation = "Closest"
    nt.nodes["Background"].inputs["Strength"].default_value = 1.0
    nt.links.new(env.outputs["Color"], nt.nodes["Background"].inputs["Color"])
    sc = bpy.context.scene
    cycles_settings(sc, 1, 0)
    sc.render.resolution_x = sc.render.resolution_y = 4
    cam = camera((0, 0, 0), (1, 0, 0), lens=200.0)
    tmp = tempfile.mkdtemp(prefix="pathfarm_conv_")
    seen = {}
    for axis, target in {"+X": (1, 0, 0), "+Y": (0, 1, 0), "-X": (-1, 0, 0),
                         "-Y": (0, -1, 0), "+Z": (0.001, 0, 1)}.items():
        look_at(cam, target)
        sc.render.filepath = os.path.join(tmp, "c.exr")
        bpy.ops.render.render(write_still=True)
        px = load_exr(sc.render.filepath)
        seen[axis] = [round(float(x), 4) for x in px.mean(axis=(0, 1))]
    expect = {"-X": 1, "+Y": 2, "+X": 3, "-Y": 4}
    for axis, red in expect.items():
        assert abs(seen[axis][0] - red) < 1e-3 and seen[axis][1] == 0, (axis, seen)
    assert seen["+Z"][1] == 10, seen
    print("equirect convention check:", seen)
    return seen


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", default="")
    ap.add_argument("--no-render", action="store_true")
    ap.add_argument("--spp", type=int, default=0, help="override every scene's spp (tests)")
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    args = ap.parse_args(argv)
    names = [n for n in args.only.split(",") if n] or list(SCENES)
    manifest_path = os.path.join(HERE, "manifest.json")
    manifest = {}
    if os.path.exists(manifest_path):
        with open(manifest_path) as f:
            manifest = json.load(f)
    manifest.setdefault("scenes", {})
    conv = check_equirect_convention() if not args.no_render else None
    for name in names:
        print(f"== {name}", flush=True)
        sc = reset()
        info = SCENES[name]()
        cycles_settings(sc, 1, BASE_SEED)
        glb = export_glb(name)
        entry = {
            "glb": f"{name}.glb",
            "glb_bytes": os.path.getsize(glb),
            "width": SIZE,
            "height": SIZE,
            "blender_version": bpy.app.version_string,
            "environment": info.pop("environment", None),
        }
        entry.update(info)
        if not args.no_render:
            entry["cycles"] = render_reference(name, args.spp or SPP[name])
            entry["cycles"]["exr"] = f"cycles/{name}.exr"
        elif name in manifest["scenes"] and "cycles" in manifest["scenes"][name]:
            entry["cycles"] = manifest["scenes"][name]["cycles"]
        manifest["scenes"][name] = entry
        write_manifest(manifest_path, manifest, conv)
        print(json.dumps(entry.get("cycles", {}), indent=None)[:400], flush=True)
    write_manifest(manifest_path, manifest, conv)


def write_manifest(manifest_path, manifest, conv):
    manifest["generator"] = "scenes/suite/make_suite.py"
    manifest["blender_version"] = bpy.app.version_string
    manifest["cycles_settings"] = {
        "device": "CPU", "threads": THREADS, "resolution": [SIZE, SIZE],
        "parts": PARTS, "seeds": f"{BASE_SEED} + part index (0..{PARTS - 1})",
        "reference": "mean of the parts (each spp/parts samples), written as float32 EXR",
        "adaptive_sampling": False, "denoising": False, "path_guiding": False,
        "pixel_filter": "BOX", "filter_width_px": 1.0,
        "max_bounces": BOUNCES, "diffuse/glossy/transmission/volume/transparent_bounces": BOUNCES,
        "caustics_reflective": True, "caustics_refractive": True, "blur_glossy": 0.0,
        "sample_clamp_direct": 0.0, "sample_clamp_indirect": 0.0,
        "film_transparent": False, "view_transform": "Standard", "look": "None",
        "exposure": 0.0, "gamma": 1.0,
        "principled_distribution": "GGX (single scattering) on every Principled BSDF",
        "exr": "OPEN_EXR, RGB, 32-bit float, ZIP, linear Rec.709 scene radiance",
    }
    manifest["conventions"] = {
        "coordinates": "Blender is Z-up; the exporter writes glTF Y-up: glTF (x, y, z) = Blender "
                       "(x, z, -y).",
        "equirect": "Blender world Environment Texture, default mapping: for a direction d in "
                    "Blender coordinates u = 0.5 - atan2(d_y, d_x) / (2 pi) (mod 1), v = 0.5 + "
                    "asin(d_z) / pi; u = 0.5 faces +X, u = 0.25 +Y, u = 0.75 -Y, u = 0 -X; v = 1 "
                    "(the file's top row) is +Z (up). In glTF coordinates: u = 0.5 + atan2(d_z, "
                    "d_x) / (2 pi), v = 0.5 + asin(d_y) / pi. Pixel (i, j), j from the top row: "
                    "u = (i + 0.5) / W, v = 1 - (j + 0.5) / H; bilinear lookup ('Linear').",
        "lamps": "Exporter (Standard lighting mode): point/spot intensity [cd] = 683 * P / (4 pi) "
                 "* 2^exposure, sun [lx] = 683 * S * 2^exposure. Cycles: point/spot radiant "
                 "intensity P / (4 pi) W/sr (spot on its axis), sun irradiance S W/m^2. So "
                 "cd / 683 = W/sr and lx / 683 = W/m^2 reproduce Cycles (check_units.py).",
        "spot_cone": "Exporter: outerConeAngle = spot_size / 2, innerConeAngle = spot_size / 2 * "
                     "(1 - spot_blend). Cycles: smoothstep(0, 1, (cos t - cos(spot_size / 2)) / "
                     "(spot_blend * (1 - cos(spot_size / 2)))), not glTF's clamp((cos t - cos "
                     "outer) / (cos inner - cos outer))^2.",
        "emission": "Cycles emission of strength s, colour c: radiance c * s; exported as "
                    "emissiveFactor c, KHR_materials_emissive_strength s. Emitters are two-sided "
                    "in Cycles and exported doubleSided.",
        "camera": "yfov from the lens and the 36 mm sensor (sensor fit AUTO), aspectRatio = "
                  "256/256 = 1, znear 0.1, zfar 1000.",
        "volume_absorption": "Cycles Volume Absorption (C, D): sigma_a = (1 - C) * D per metre; "
                             "exported attenuationColor = C, attenuationDistance = 1 / D, which "
                             "glTF reads as sigma_a = -ln(C) * D.",
        "principled_dielectric": "Cycles' Principled dielectric reflects with the exact dielectric "
                                "Fresnel and scales the diffuse under it by an albedo estimate that "
                                "loses energy at high roughness; glTF (KHR_materials_specular) "
                                "writes Schlick's Fresnel. Metals agree (F82 tint with a white "
                                "tint is Schlick). Measured by material_furnace.py.",
    }
    if conv is not None:
        manifest["equirect_check"] = conv
    with open(manifest_path, "w") as f:
        json.dump(manifest, f, indent=2)
        f.write("\n")



if __name__ == "__main__":
    main()
