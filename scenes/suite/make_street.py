"""Builds a street at night lit by many lamps in Blender and exports it with Blender's glTF
exporter: scenes/suite/lit_street.glb (issue 31, item 4: many lights).

Run with Blender as a Python module (bpy from PyPI, see README.md):

    /work/venv-bpy/bin/python scenes/suite/make_street.py

A 160 m street between two rows of houses (boxes with lit windows: small emissive quads), with
lamp posts every 5 m on both sides (64 posts: 32 POINT lamps on posts and 32 SPOT lamps hanging
over the road, pointing down), 32 SPOT lamps on the facades pointing up at the walls, and a dim
moon (SUN): 97 lamps.
The camera stands in the street looking along it, so most lamps are far off or light what it does
not see: the case where choosing a lamp by power alone wastes most samples.

Exported like the suite: `bpy.ops.export_scene.gltf(filepath=..., export_format='GLB',
export_cameras=True, export_lights=True)`, every other setting the exporter's default. No Cycles
reference is rendered: the tracer's test compares its two ways of choosing lamps with each other.
"""

import math
import os
import sys

import bpy

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from make_suite import box, camera, lamp, material, mesh_obj, plane, reset  # noqa: E402

LENGTH = 160.0
SPACING = 5.0


def build():
    reset()
    asphalt = material("Asphalt", base=(0.08, 0.08, 0.09), roughness=0.9)
    pavement = material("Pavement", base=(0.35, 0.34, 0.32), roughness=0.9)
    plaster = material("Plaster", base=(0.7, 0.62, 0.5), roughness=0.9)
    brick = material("Brick", base=(0.45, 0.18, 0.12), roughness=0.9)
    iron = material("Iron", base=(0.05, 0.05, 0.05), roughness=0.6)
    window = material("Window", base=(0, 0, 0), emission=(1.0, 0.75, 0.45), strength=3.0)

    plane(asphalt, (0, LENGTH / 2 - 10, 0), 1.0, scale=(8, LENGTH, 1), name="Road")
    for side in (-1, 1):
        plane(pavement, (side * 6, LENGTH / 2 - 10, 0.15), 1.0, scale=(4, LENGTH, 1),
              name=f"Pavement{side}")
    # Houses: boxes of varying height along both sides, every other one brick, each with two
    # lit windows facing the street.
    n_houses = int(LENGTH / 8)
    for side in (-1, 1):
        for i in range(n_houses):
            y0 = -10 + i * 8
            height = 6 + 4 * ((i * 7 + (side + 1) * 3) % 5) / 4
            box(brick if i % 2 else plaster, (side * 8, y0 + 0.2, 0), (side * 14, y0 + 7.8, height),
                name=f"House{side}_{i}")
            for k, y in enumerate((y0 + 2.0, y0 + 5.5)):
                if (i + k + side) % 3 == 0:
                    continue  # a dark window
                plane(window, (side * 7.99, y, 3.0), 1.0,
                      rotation=(math.pi / 2, 0, side * math.pi / 2), scale=(1.2, 1.4, 1),
                      name=f"Window{side}_{i}_{k}")
    n_posts = int(LENGTH / SPACING)
    for side in (-1, 1):
        for i in range(n_posts):
            y = -8 + i * SPACING + (SPACING / 2 if side > 0 else 0)
            mesh_obj(bpy.ops.mesh.primitive_cylinder_add, iron, location=(side * 4.6, y, 2.5),
                     radius=0.08, depth=5.0, vertices=12, name=f"Post{side}_{i}")
            if i % 2 == 0:
                lamp("POINT", f"Lamp{side}_{i}", (side * 4.6, y, 5.2), energy=400.0,
                     color=(1.0, 0.85, 0.6))
            else:
                lamp("SPOT", f"Hanging{side}_{i}", (side * 3.0, y, 5.6), target=(side * 3.0, y, 0),
                     energy=900.0, color=(1.0, 0.9, 0.75), spot_size=math.radians(100),
                     spot_blend=0.4)
    # Facade lights pointing up the walls.
    for side in (-1, 1):
        for i in range(16):
            y = -6 + i * 10
            lamp("SPOT", f"Facade{side}_{i}", (side * 7.7, y, 0.4), target=(side * 7.9, y, 8),
                 energy=300.0, color=(0.8, 0.9, 1.0), spot_size=math.radians(40), spot_blend=0.2)
    moon = lamp("SUN", "Moon", (0, 0, 30), target=(5, 20, 0), energy=0.05, color=(0.7, 0.8, 1.0))
    moon.data.angle = 0.0
    camera((1.5, -9.0, 1.7), (0.0, 30.0, 1.5), lens=30.0)


def main():
    build()
    out = os.path.join(HERE, "lit_street.glb")
    bpy.ops.export_scene.gltf(filepath=out, export_format="GLB", export_cameras=True,
                              export_lights=True)
    lamps = [o for o in bpy.data.objects if o.type == "LIGHT"]
    print(f"wrote {out}: {len(lamps)} lamps")


if __name__ == "__main__":
    main()
