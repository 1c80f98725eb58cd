"""Builds a small animated scene in Blender and exports it with Blender's glTF exporter:
scenes/suite/animated.glb (issue 34: animated scenes in the tracer).

Run with Blender as a Python module (bpy from PyPI, see README.md):

    /work/venv-bpy/bin/python scenes/suite/make_animated.py

What moves, over frames 1-48 at 24 fps (keys at the ends and in between, Bezier as Blender
makes them; the exporter bakes them to linear keys at every frame):
- a red cube slides across the floor and turns (object location and rotation keys);
- the camera sits on an empty at the scene's centre that turns a quarter turn (a parent's
  rotation moves its child: the camera's path is an arc);
- a point lamp rises and falls (a lamp's location keys);
- a bar skinned to a two-bone armature bends (the upper bone's rotation keys);
- a sphere bulges (a shape key's value keys: morph-target weights).
A grey floor and a back wall stay still, and a small emissive panel lights the scene beside the lamp.

Beside the .glb it writes animated.blender.json: what Blender itself evaluates at frames 1, 24
and 48 (the camera's, the lamp's and the cube's world positions, and every vertex of the bent bar
and the bulging sphere, deformed by the armature and the shape key), in glTF's axes. The tracer's
test (crates/tracer/tests/animated_blender.rs) holds its frames to them.

Exported like the suite: `bpy.ops.export_scene.gltf(filepath=..., export_format='GLB',
export_cameras=True, export_lights=True)`, every other setting the exporter's default (animation
mode "Actions": one glTF animation per action, which the tracer plays all together).
No Cycles reference is rendered: the tracer's tests check each frame against its own still scenes.
"""

import json
import math
import os
import sys

import bpy
from mathutils import Vector

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from make_suite import camera, lamp, link, material, mesh_obj, plane, reset  # noqa: E402

FRAMES = (1, 48)
FPS = 24


def key(obj, path, frame, value):
    setattr(obj, path, value)
    obj.keyframe_insert(data_path=path, frame=frame)


def build():
    sc = reset()
    sc.frame_start, sc.frame_end = FRAMES
    sc.render.fps = FPS
    grey = material("Grey", base=(0.6, 0.6, 0.6), roughness=0.8)
    red = material("Red", base=(0.8, 0.1, 0.08), roughness=0.4)
    blue = material("Blue", base=(0.1, 0.25, 0.8), roughness=0.5)
    gold = material("Gold", base=(0.9, 0.7, 0.3), metallic=1.0, roughness=0.3)
    glow = material("Glow", base=(0, 0, 0), emission=(1.0, 0.9, 0.7), strength=8.0)

    plane(grey, (0, 0, 0), 8.0, name="Floor")
    plane(grey, (0, 3, 2), 8.0, rotation=(math.pi / 2, 0, 0), name="Wall")
    plane(glow, (-2.5, 2.9, 3.0), 0.8, rotation=(math.pi / 2, 0, 0), name="Panel")

    # The cube: location and rotation keys.
    cube = mesh_obj(bpy.ops.mesh.primitive_cube_add, red, location=(-2, -1, 0.5), size=1.0,
                    name="Cube")
    key(cube, "location", 1, Vector((-2.0, -1.0, 0.5)))
    key(cube, "location", 48, Vector((2.0, -0.5, 0.5)))
    key(cube, "rotation_euler", 1, (0.0, 0.0, 0.0))
    key(cube, "rotation_euler", 48, (0.0, 0.0, math.pi))

    # The sphere with a shape key (morph target) that bulges it.
    sphere = mesh_obj(bpy.ops.mesh.primitive_uv_sphere_add, blue, location=(1.8, 1.2, 0.7),
                      radius=0.6, segments=16, ring_count=8, smooth=True, name="Blob")
    sphere.shape_key_add(name="Basis")
    bulge = sphere.shape_key_add(name="Bulge")
    for v in bulge.data:
        p = v.co
        v.co = Vector((p.x * 1.5, p.y * 1.5, p.z * 0.6))
    bulge.value = 0.0
    bulge.keyframe_insert(data_path="value", frame=1)
    bulge.value = 1.0
    bulge.keyframe_insert(data_path="value", frame=24)
    bulge.value = 0.2
    bulge.keyframe_insert(data_path="value", frame=48)

    # The bar skinned to a two-bone armature; the upper bone bends.
    bpy.ops.object.armature_add(enter_editmode=True, location=(0, 1.0, 0))
    arm = bpy.context.object
    arm.name = "Rig"
    bones = arm.data.edit_bones
    lower = bones[0]
    lower.name = "Lower"
    lower.head, lower.tail = (0, 0, 0), (0, 0, 1.0)
    upper = bones.new("Upper")
    upper.head, upper.tail = (0, 0, 1.0), (0, 0, 2.0)
    upper.parent = lower
    upper.use_connect = True
    bpy.ops.object.mode_set(mode="OBJECT")
    bar = mesh_obj(bpy.ops.mesh.primitive_cylinder_add, gold, location=(0, 1.0, 1.0),
                   radius=0.15, depth=2.0, vertices=12, name="Bar")
    # Loop cuts along the bar so that it bends smoothly.
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="SELECT")
    bpy.ops.mesh.subdivide(number_cuts=6)
    bpy.ops.object.mode_set(mode="OBJECT")
    bar.select_set(True)
    arm.select_set(True)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.parent_set(type="ARMATURE_AUTO")
    pose = arm.pose.bones["Upper"]
    pose.rotation_mode = "XYZ"
    key(pose, "rotation_euler", 1, (0.0, 0.0, 0.0))
    key(pose, "rotation_euler", 24, (0.0, 1.1, 0.0))
    key(pose, "rotation_euler", 48, (0.0, -0.6, 0.0))

    # A point lamp that rises and falls.
    bulb = lamp("POINT", "Bulb", (1.0, -1.5, 2.0), energy=150.0)
    key(bulb, "location", 1, Vector((1.0, -1.5, 1.2)))
    key(bulb, "location", 24, Vector((1.0, -1.5, 3.0)))
    key(bulb, "location", 48, Vector((1.0, -1.5, 1.6)))

    # The camera on a turning empty.
    pivot = link(bpy.data.objects.new("Pivot", None))
    pivot.location = (0, 0, 0)
    cam = camera((0, -7.5, 3.0), (0, 0, 1.0), lens=35.0)
    cam.parent = pivot
    key(pivot, "rotation_euler", 1, (0.0, 0.0, -0.5))
    key(pivot, "rotation_euler", 48, (0.0, 0.0, 0.5))
    return sc


def gltf_axes(v):
    """Blender (x, y, z), Z up, in glTF's Y-up axes (x, z, -y), as the exporter writes them."""
    return [round(v.x, 6), round(v.z, 6), round(-v.y, 6)]


def evaluated(frames=(1, 24, 48)):
    """What Blender evaluates at each frame: object positions and the deformed vertices."""
    sc = bpy.context.scene
    out = {}
    for f in frames:
        sc.frame_set(f)
        dg = bpy.context.evaluated_depsgraph_get()
        at = {name: gltf_axes(bpy.data.objects[name].matrix_world.translation)
              for name in ("Camera", "Bulb", "Cube")}
        deformed = []
        for name in ("Bar", "Blob"):
            o = bpy.data.objects[name].evaluated_get(dg)
            m = o.to_mesh()
            deformed += [gltf_axes(o.matrix_world @ v.co) for v in m.vertices]
            o.to_mesh_clear()
        at["deformed"] = deformed
        out[str(f)] = at
    sc.frame_set(FRAMES[0])
    return out


def main():
    build()
    path = os.path.join(HERE, "animated.glb")
    bpy.ops.export_scene.gltf(filepath=path, export_format="GLB", export_cameras=True,
                              export_lights=True)
    print(f"wrote {path}: {os.path.getsize(path)} bytes")
    facts = os.path.join(HERE, "animated.blender.json")
    with open(facts, "w") as f:
        json.dump(evaluated(), f, separators=(",", ":"))
    print(f"wrote {facts}: {os.path.getsize(facts)} bytes")


if __name__ == "__main__":
    main()
