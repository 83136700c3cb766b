# Loomlight's SCENE_CYLINDERS (server/render/scene.cpp) rebuilt in Blender Cycles for the noise benchmark
# (bench/noise_bench.cpp): three open tubes (radius 0.4, length 1.6, at x = -1.1, 0, 1.1), the scene's camera
# and its built-in sky, given as an equirectangular EXR the benchmark wrote from the server's own sky. Loomlight
# is y-up; Blender is z-up: a Loomlight point (x, y, z) is Blender's (x, -z, y).
#
#   blender -b --factory-startup -noaudio --python cylinders.py -- --sky SKY.exr --out DIR --size 256 \
#       --threads 2 --renders NAME:SPP:SEED:RUNS,...
#
# Each render NAME is rendered RUNS times (same seed, same image) and written to DIR/NAME.exr (linear RGB,
# 32-bit float). DIR/times.tsv gets a tab-separated line "NAME SPP SEED SECONDS" per render: the fastest run's
# time in bpy's render operator (scene sync, BVH, world map and sampling; not Blender's start-up nor the file
# write); DIR/version.txt gets Blender's version. One untimed 1-sample render first warms Cycles up. Cycles on
# the CPU, direct light only (no bounces), no denoiser, no adaptive sampling, a 1-pixel box filter (Loomlight's
# jittered pixel samples).
import argparse
import math
import os
import sys

import bpy
from mathutils import Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import cycles_common  # noqa: E402 (beside this script)


def loomlight_to_blender(x, y, z):
    return Vector((x, -z, y))


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="cylinders.py")
    p.add_argument("--sky", required=True, help="equirectangular EXR in Blender's convention")
    p.add_argument("--out", required=True, help="directory for NAME.exr and times.tsv")
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--renders", required=True, help="NAME:SPP:SEED:RUNS,...")
    return p.parse_args(argv)


def build_scene(args):
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene

    # Cloth: a glossy, sheen-y Principled BSDF of about the satin's look in Loomlight (a dim mauve with the sky's
    # highlights); each renderer's noise is measured against its own converged image, so the material need only
    # be alike, not equal.
    material = bpy.data.materials.new("cloth")
    material.use_nodes = True
    bsdf = material.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.2, 0.14, 0.15, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.3
    bsdf.inputs["Sheen"].default_value = 0.5
    for x in (-1.1, 0.0, 1.1):
        bpy.ops.mesh.primitive_cylinder_add(vertices=512, radius=0.4, depth=1.6, end_fill_type="NOTHING",
                                            location=loomlight_to_blender(x, 0, 0))
        tube = bpy.context.object
        bpy.ops.object.shade_smooth()
        tube.data.materials.append(material)

    # The camera: at (0, 0.25, 5) looking at the origin, +y up, 36 degrees vertical field of view.
    camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(camera)
    camera.location = loomlight_to_blender(0, 0.25, 5)
    camera.rotation_mode = "QUATERNION"
    camera.rotation_quaternion = (loomlight_to_blender(0, 0, 0) - camera.location).to_track_quat("-Z", "Y")
    camera.data.sensor_fit = "VERTICAL"
    camera.data.angle_y = math.radians(36)
    scene.camera = camera

    cycles_common.set_world_map(scene, args.sky, "sky")
    cycles_common.configure_cycles(scene, args.threads, args.size, "RGB")
    return scene


def main():
    args = parse_args()
    scene = build_scene(args)
    os.makedirs(args.out, exist_ok=True)
    cycles_common.run_renders(scene, args.out, args.renders)


main()
