"""The peer-comparison scenes, built in bpy from Blender primitives with make_suite's helpers.

Every material and light here has an exact counterpart in Cycles, Mitsuba 3 and glTF (what the
tracer reads), so any difference in image means between the three renderers is a conversion error
or a renderer's bias, not a model difference:

- Lambertian: Principled, metallic 0, roughness 1, Specular IOR Level 0 (glTF: specularFactor 0);
- perfect mirror: Principled metallic 1, roughness 0, base colour 1 (F82-tint with a white tint
  and base 1 reflects 1 at every angle; glTF: Schlick with f0 = 1, also 1);
- smooth glass: Principled transmission 1, roughness 0, IOR 1.5, base 1, a closed mesh, exported
  with KHR_materials_volume (thickness > 0) so that the tracer treats it as a solid;
- emitters: Principled with a black base, Specular IOR Level 0 (a black Lambertian) and emission;
- lamps of radius 0 (point, spot with spot_blend 0) and angle 0 (sun): delta lights;
- a uniform world colour (strength 1);
- image textures: an sRGB base colour on a Lambertian, and a tangent-space normal map on flat
  faces whose UVs are not mirrored (there every renderer's tangent frame is the same: Mitsuba
  builds its frame from dP/du, Cycles and the tracer from MikkTSpace).

Each scene function builds the Blender scene (after make_suite.reset()) and returns a dict with
"covers" (text) and "environment" (linear RGB radiance of the uniform world, or None).
Blender is Z-up; lengths are metres.
"""

import math
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "..",
                                "scenes", "suite"))
import make_suite as suite  # noqa: E402

import bpy  # noqa: E402
import numpy as np  # noqa: E402
from mathutils import Vector  # noqa: E402


# ----------------------------------------------------------------------------------------------
# Materials with exact counterparts


def lambert(name, rgb):
    return suite.material(name, tuple(rgb), metallic=0.0, roughness=1.0, specular=0.0)


def mirror(name):
    return suite.material(name, (1.0, 1.0, 1.0), metallic=1.0, roughness=0.0)


def glass(name, thickness):
    m = suite.material(name, (1.0, 1.0, 1.0), roughness=0.0, transmission=1.0, ior=1.5)
    suite.gltf_output_node(m, thickness)  # the exporter then writes KHR_materials_volume
    return m


def textured_lambert(name, base_image, normal_image=None):
    """A Lambertian whose albedo is an sRGB image texture (bilinear, repeat, the mesh's UVs),
    optionally with a tangent-space normal map (Non-Color image, strength 1): glTF
    baseColorTexture and normalTexture; Mitsuba `bitmap` and `normalmap`."""
    m = lambert(name, (1.0, 1.0, 1.0))
    nt = m.node_tree
    p = nt.nodes["Principled BSDF"]
    tb = nt.nodes.new("ShaderNodeTexImage")
    tb.image = base_image
    tb.interpolation = "Linear"
    nt.links.new(tb.outputs["Color"], p.inputs["Base Color"])
    if normal_image is not None:
        tn = nt.nodes.new("ShaderNodeTexImage")
        tn.image = normal_image
        tn.interpolation = "Linear"
        nm = nt.nodes.new("ShaderNodeNormalMap")
        nt.links.new(tn.outputs["Color"], nm.inputs["Color"])
        nt.links.new(nm.outputs["Normal"], p.inputs["Normal"])
    return m


def emitter(name, rgb, strength):
    return suite.material(name, (0.0, 0.0, 0.0), roughness=1.0, specular=0.0,
                          emission=tuple(rgb), strength=strength)


# ----------------------------------------------------------------------------------------------
# Geometry helpers


def activate(o):
    for other in bpy.context.view_layer.objects:
        other.select_set(False)
    bpy.context.view_layer.objects.active = o
    o.select_set(True)


def subdivide(o, levels, smooth=True):
    """Applies a Catmull-Clark subdivision to the mesh data (the glTF exporter does not apply
    modifiers by default, so the mesh itself must hold the final triangles for all three)."""
    activate(o)
    mod = o.modifiers.new("Subdivision", "SUBSURF")
    mod.levels = levels
    mod.render_levels = levels
    bpy.ops.object.modifier_apply(modifier=mod.name)
    for p in o.data.polygons:
        p.use_smooth = smooth
    return o


def panel(mat, center, size, target, name):
    """A square emitter (a plane, so open and two-sided in Cycles) at center facing target."""
    sx, sy = (size, size) if not isinstance(size, (tuple, list)) else size
    p = suite.plane(mat, center, 1.0, scale=(sx, sy, 1.0), name=name)
    p.rotation_euler = (Vector(target) - Vector(center)).to_track_quat("Z", "Y").to_euler()
    bpy.context.view_layer.update()
    return p


def open_box(white, red, green, half=1.0, height=2.0):
    """A Cornell-like box without a front wall: interior x, y in [-half, half], z in [0, height];
    walls are single planes (everything is two-sided in all three renderers)."""
    h = half
    suite.plane(white, (0, 0, 0), 2 * h, name="Floor")
    suite.plane(white, (0, 0, height), 2 * h, rotation=(math.pi, 0, 0), name="Ceiling")
    suite.plane(white, (0, h, height / 2), 1.0, rotation=(math.radians(90), 0, 0),
                scale=(2 * h, height, 1), name="BackWall")
    suite.plane(red, (-h, 0, height / 2), 1.0, rotation=(0, math.radians(90), 0),
                scale=(height, 2 * h, 1), name="LeftWall")
    suite.plane(green, (h, 0, height / 2), 1.0, rotation=(0, math.radians(-90), 0),
                scale=(height, 2 * h, 1), name="RightWall")


def rotated_box(mat, center, size, angle_deg, name):
    o = suite.mesh_obj(bpy.ops.mesh.primitive_cube_add, mat, location=center, size=1.0,
                       rotation=(0, 0, math.radians(angle_deg)), name=name)
    o.scale = size
    return o


WHITE = (0.725, 0.71, 0.68)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)


# ----------------------------------------------------------------------------------------------
# Scenes


def scene_cornell():
    white, red, green = lambert("White", WHITE), lambert("Red", RED), lambert("Green", GREEN)
    open_box(white, red, green)
    rotated_box(white, (-0.33, 0.3, 0.6), (0.6, 0.6, 1.2), 18, "TallBlock")
    rotated_box(white, (0.35, -0.3, 0.3), (0.6, 0.6, 0.6), -17, "ShortBlock")
    light = emitter("Light", (1.0, 0.85, 0.6), 12.0)
    panel(light, (0, 0, 1.98), 0.5, (0, 0, 0), "AreaLight")
    suite.camera((0, -3.9, 1.0), (0, 0, 1.0), lens=50.0)
    return {"covers": "Cornell-like open box of Lambertian walls and blocks lit by a 0.5 m square "
                      "two-sided emissive quad 2 cm under the ceiling (its back lights the "
                      "ceiling): diffuse interreflection, area-light sampling.",
            "environment": None}


def scene_smooth():
    white, red, green = lambert("White", WHITE), lambert("Red", RED), lambert("Green", GREEN)
    open_box(white, red, green)
    clay = lambert("Clay", (0.8, 0.7, 0.55))
    monkey = suite.mesh_obj(bpy.ops.mesh.primitive_monkey_add, clay, location=(-0.25, 0.1, 0.75),
                            rotation=(math.radians(-10), 0, math.radians(15)), size=1.1,
                            name="Monkey")
    subdivide(monkey, 4)
    suite.mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, white, location=(0.55, -0.35, 0.3),
                   radius=0.3, segments=192, ring_count=96, smooth=True, name="Sphere")
    light = emitter("Light", (1.0, 0.9, 0.75), 12.0)
    panel(light, (0, 0, 1.98), 0.5, (0, 0, 0), "AreaLight")
    suite.camera((0, -3.9, 1.0), (0, 0, 0.9), lens=50.0)
    return {"covers": "A Catmull-Clark subdivided monkey (level 4) and a fine UV sphere, smooth "
                      "shaded (interpolated normals), about 290k triangles, in the open box under "
                      "an area light: BVH traversal of a dense mesh, shading normals.",
            "environment": None}


def scene_caustics():
    floor = lambert("Floor", (0.7, 0.7, 0.7))
    wall = lambert("Wall", (0.6, 0.62, 0.65))
    suite.plane(floor, (0, 0.5, 0), 8, name="Floor")
    suite.plane(wall, (0, 2.5, 2.0), 1.0, rotation=(math.radians(90), 0, 0), scale=(8, 4, 1),
                name="BackWall")
    suite.mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, glass("Glass", 1.0),
                   location=(-0.65, 0.0, 0.5), radius=0.5, segments=128, ring_count=64,
                   smooth=True, name="GlassSphere")
    suite.mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, mirror("Mirror"),
                   location=(0.7, 0.4, 0.5), radius=0.5, segments=128, ring_count=64,
                   smooth=True, name="MirrorSphere")
    light = emitter("Light", (1.0, 0.95, 0.85), 300.0)
    panel(light, (0.2, -0.9, 2.6), 0.15, (0, 0.2, 0), "SmallLight")
    suite.camera((0.0, -4.5, 1.7), (0.0, 0.2, 0.4), lens=40.0)
    return {"covers": "A smooth glass sphere (IOR 1.5, solid) and a mirror sphere on a floor "
                      "before a wall, lit by a small (15 cm) emissive quad: caustics through "
                      "the glass and off the mirror, reached only by BSDF sampling "
                      "(diffuse -> specular -> light paths).",
            "environment": None}


def scene_tiny_light():
    wall = lambert("Wall", (0.7, 0.7, 0.68))
    floor = lambert("Floor", (0.55, 0.45, 0.35))
    blue = lambert("Blue", (0.2, 0.3, 0.6))
    t = 0.1  # walls: closed boxes; interior x in [-2, 2], y in [-2.5, 2.5], z in [0, 2.6]
    suite.box(floor, (-2 - t, -2.5 - t, -t), (2 + t, 2.5 + t, 0), "Floor")
    suite.box(wall, (-2 - t, -2.5 - t, 2.6), (2 + t, 2.5 + t, 2.6 + t), "Ceiling")
    suite.box(wall, (-2 - t, -2.5 - t, 0), (-2, 2.5 + t, 2.6), "WallWest")
    suite.box(wall, (2, -2.5 - t, 0), (2 + t, 2.5 + t, 2.6), "WallEast")
    suite.box(blue, (-2, 2.5, 0), (2, 2.5 + t, 2.6), "WallNorth")
    suite.box(wall, (-2, -2.5 - t, 0), (2, -2.5, 2.6), "WallSouth")
    suite.box(wall, (-0.9, 0.2, 0), (0.1, 1.4, 0.8), "Block")
    suite.mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, wall, location=(0.9, -0.4, 0.4),
                   radius=0.4, segments=64, ring_count=32, smooth=True, name="Ball")
    # 1 cm x 1 cm, two-sided, hanging 40 cm under the ceiling like a bare bulb, above and in
    # front of the camera but out of its view: seen directly, a light this small covers ~1 % of a
    # pixel and its rare camera hits (radiance 2e5) would dominate every image mean.
    bulb = emitter("Bulb", (1.0, 0.9, 0.75), 2.0e5)
    panel(bulb, (0.2, -1.3, 2.2), 0.01, (0.2, -1.3, 0.0), "TinyLight")
    suite.camera((0.4, -2.3, 1.4), (-0.2, 1.2, 0.5), lens=20.0)
    return {"covers": "A closed room (Lambertian walls, a block, a ball) lit only by a 1 cm^2 "
                      "two-sided emissive quad hanging under the ceiling: light that BSDF "
                      "sampling almost never hits (next-event estimation does the work), long "
                      "diffuse paths.",
            "environment": None}


def scene_lamps():
    floor = lambert("Floor", (0.6, 0.6, 0.6))
    wall = lambert("Wall", (0.7, 0.7, 0.7))
    orange = lambert("Orange", (0.8, 0.35, 0.08))
    blue = lambert("Blue", (0.15, 0.3, 0.7))
    white = lambert("White", (0.8, 0.8, 0.8))
    suite.plane(floor, (0, 0, 0), 10, name="Floor")
    suite.plane(wall, (0, 3, 2.5), 1.0, rotation=(math.radians(90), 0, 0), scale=(10, 5, 1),
                name="BackWall")
    suite.mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, orange, location=(-1.4, 0.3, 0.55),
                   radius=0.55, segments=64, ring_count=32, smooth=True, name="Sphere")
    rotated_box(blue, (1.4, 0.6, 0.45), (0.9, 0.9, 0.9), 25, "Cube")
    suite.mesh_obj(bpy.ops.mesh.primitive_monkey_add, white, location=(0.0, 0.0, 0.7),
                   rotation=(math.radians(-15), 0, 0), size=1.2, smooth=True, name="Monkey")
    suite.lamp("POINT", "Point", (-2.2, -2.0, 2.8), energy=400.0, color=(1.0, 0.9, 0.8))
    sun = suite.lamp("SUN", "Sun", (0, 0, 10), energy=1.5, color=(0.85, 0.92, 1.0))
    sun.rotation_euler = Vector((0.6, -0.5, 0.8)).normalized().to_track_quat("Z", "Y").to_euler()
    suite.lamp("SPOT", "Spot", (2.0, -1.5, 4.0), target=(0.6, 0.4, 0.0), energy=1500.0,
               color=(1.0, 0.75, 0.5), spot_size=math.radians(50), spot_blend=0.0,
               show_cone=False)
    suite.camera((0.0, -6.0, 2.4), (0.0, 0.4, 0.6), lens=40.0)
    return {"covers": "Delta lamps only: a point lamp, a sun (directional, angle 0) and a spot "
                      "with a hard cone (spot_size 50 deg, spot_blend 0) on Lambertian objects "
                      "and a floor/wall: direct lighting with hard shadows, one bounce of "
                      "indirect.",
            "environment": None}


ENV_RGB = (0.6, 0.75, 1.0)


def scene_environment():
    world = bpy.context.scene.world
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (*ENV_RGB, 1.0)
    bg.inputs["Strength"].default_value = 1.0
    floor = lambert("Floor", (0.5, 0.5, 0.5))
    clay = lambert("Clay", (0.75, 0.55, 0.45))
    suite.plane(floor, (0, 0, 0), 12, name="Floor")
    monkey = suite.mesh_obj(bpy.ops.mesh.primitive_monkey_add, clay, location=(-0.5, 0.0, 0.75),
                            rotation=(math.radians(-20), 0, math.radians(20)), size=1.4,
                            name="Monkey")
    subdivide(monkey, 2)
    suite.mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, mirror("Mirror"),
                   location=(1.0, 0.6, 0.5), radius=0.5, segments=96, ring_count=48,
                   smooth=True, name="MirrorSphere")
    suite.camera((0.5, -5.0, 2.6), (0.2, 0.2, 0.4), lens=38.0)
    return {"covers": "A subdivided Lambertian monkey and a mirror sphere on a finite floor "
                      "under a uniform environment of radiance (0.6, 0.75, 1.0) and nothing "
                      "else: environment sampling, ambient occlusion-like shading, the "
                      "environment seen directly and in the mirror.",
            "environment": list(ENV_RGB)}


def scene_emissive_mesh():
    white, red, green = lambert("White", WHITE), lambert("Red", RED), lambert("Green", GREEN)
    open_box(white, red, green)
    rotated_box(white, (-0.4, 0.35, 0.35), (0.7, 0.7, 0.7), 20, "Block")
    suite.mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, white, location=(0.45, -0.3, 0.3),
                   radius=0.3, segments=64, ring_count=32, smooth=True, name="Ball")
    glow = emitter("Glow", (1.0, 0.8, 0.55), 4.0)
    # An icosphere of subdivision 5: 20480 emissive triangles, closed (only its outside is seen).
    suite.mesh_obj(bpy.ops.mesh.primitive_ico_sphere_add, glow, location=(0.1, 0.1, 1.45),
                   radius=0.28, subdivisions=5, name="GlowSphere")
    suite.camera((0, -3.9, 1.0), (0, 0, 1.0), lens=50.0)
    return {"covers": "A closed icosphere of 20480 emissive triangles (flat shaded) lighting the "
                      "open box: light selection among many small emitters, most of which face "
                      "away from any given point.",
            "environment": None}


def scene_instancing():
    floor = lambert("Floor", (0.6, 0.6, 0.58))
    clay = lambert("Clay", (0.75, 0.55, 0.45))
    suite.plane(floor, (0, 0, 0), 40, name="Floor")
    bpy.ops.mesh.primitive_monkey_add(size=0.5)
    template = bpy.context.object
    subdivide(template, 1)
    template.data.name = "MonkeyMesh"
    template.data.materials.append(clay)
    rng = np.random.default_rng(11)
    n = 0
    for j in range(12):
        for i in range(25):
            x = (i - 12.0) * 0.55 + rng.uniform(-0.08, 0.08)
            y = (j - 3.0) * 0.7 + rng.uniform(-0.08, 0.08)
            o = suite.link(bpy.data.objects.new(f"Monkey.{n:03d}", template.data))
            s = rng.uniform(0.8, 1.2)
            o.scale = (s, s, s)
            o.location = (x, y, 0.25 * s)
            o.rotation_euler = (0, 0, math.pi + rng.uniform(-0.8, 0.8))
            n += 1
    bpy.data.objects.remove(template)  # the mesh stays, used by the 300 linked duplicates
    sun = suite.lamp("SUN", "Sun", (0, 0, 10), energy=3.0, color=(1.0, 0.96, 0.9))
    sun.rotation_euler = Vector((-0.4, -0.6, 0.7)).normalized().to_track_quat("Z", "Y").to_euler()
    suite.lamp("POINT", "Fill", (-4.0, -5.0, 3.0), energy=800.0, color=(0.8, 0.88, 1.0))
    suite.camera((0.0, -7.5, 3.6), (0.0, 1.0, 0.0), lens=35.0)
    return {"covers": "300 linked duplicates (own location, rotation, uniform scale) of one "
                      "subdivided smooth monkey mesh (3.9k triangles) on a floor, under a sun and "
                      "a point lamp: instancing (glTF: one mesh, 300 nodes; Mitsuba: shapegroup + "
                      "instance; Cycles: linked duplicates).",
            "environment": None}


def scene_textured():
    base, normal, _ = suite.tile_textures()
    base_img = suite.image_from_array("peers_tiles_basecolor", base)
    normal_img = suite.image_from_array("peers_tiles_normal", normal, non_color=True)
    tiles = textured_lambert("Tiles", base_img, normal_img)
    painted = textured_lambert("Painted", base_img)
    wall = lambert("Wall", (0.65, 0.65, 0.62))
    suite.plane(tiles, (0, 0.5, 0), 6, name="TiledFloor")
    suite.plane(wall, (0, 2.5, 2.0), 1.0, rotation=(math.radians(90), 0, 0), scale=(8, 4, 1),
                name="BackWall")
    suite.mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, painted, location=(0.8, 0.0, 0.6),
                   radius=0.6, segments=64, ring_count=32, smooth=True, name="PaintedSphere")
    rotated_box(painted, (-0.8, 0.6, 0.5), (1.0, 1.0, 1.0), 30, "PaintedCube")
    light = emitter("Light", (1.0, 0.93, 0.82), 25.0)
    panel(light, (-1.2, -1.4, 2.4), (0.8, 0.5), (0, 0.3, 0), "AreaLight")
    sun = suite.lamp("SUN", "Sun", (0, 0, 10), energy=2.0, color=(1.0, 0.95, 0.88))
    sun.rotation_euler = Vector((0.5, -0.7, 0.6)).normalized().to_track_quat("Z", "Y").to_euler()
    suite.camera((0.3, -4.6, 2.5), (0.0, 0.3, 0.3), lens=40.0)
    return {"covers": "Textured Lambertians: a floor tiled by a 512 x 512 sRGB base colour "
                      "texture and tangent-space normal map (grooves between the tiles), a "
                      "UV sphere (smooth) and a cube painted with the base colour only, before "
                      "a wall, under an area light and a sun: texture lookups and normal "
                      "mapping on every hit.",
            "environment": None}


# Letter -> (name, builder), in the order of the brief.
SCENES = {
    "a": ("cornell", scene_cornell),
    "b": ("smooth", scene_smooth),
    "c": ("caustics", scene_caustics),
    "d": ("tiny_light", scene_tiny_light),
    "e": ("lamps", scene_lamps),
    "f": ("environment", scene_environment),
    "g": ("emissive_mesh", scene_emissive_mesh),
    "h": ("instancing", scene_instancing),
    "i": ("textured", scene_textured),
}
