# Fitted glTF materials of bench/materials_out_bench.cpp rendered by Blender Cycles on Loomlight's `sphere` scene:
# each .glb (server/export/gltf_export.h's preview sphere with a gltf_sheen fit: glTF metallic-roughness plus
# KHR_materials_sheen) through Blender's own glTF importer, which makes the sheen a Velvet BSDF added to the
# Principled BSDF, scaled about the origin to the scene's sphere radius; the sphere scene's camera and its built-in
# sky, given as an equirectangular EXR the benchmark wrote from the server's own sky (bench/cycles/cylinders.py
# does the same for the cylinders). Loomlight is y-up like glTF; Blender is z-up, and its importer maps a glTF
# point (x, y, z) to (x, -z, y), as this script maps the camera.
#
#   blender -b --factory-startup -noaudio --python gltf_fit.py -- --sky SKY.exr \
#       --camera PX,PY,PZ,LX,LY,LZ,FOV --radius 1 --size 256 --threads 2 --samples 256 --seed 1 \
#       --glb NAME=FILE.glb [--glb NAME=FILE.glb ...] --out DIR
#
# The camera looks from P at L with Loomlight's +y up (the sphere scene's); FOV is vertical, in degrees. Each
# NAME is rendered once with the one seed and written to DIR/NAME.exr (linear RGB, 32-bit float, the sky behind
# the sphere as Loomlight's BACKGROUND_ENVIRONMENT shows it). DIR/times.tsv gets "NAME SPP SEED SECONDS" per
# render (bpy's render operator: scene sync, BVH, world map and sampling; not Blender's start-up, the import nor
# the file write); DIR/NAME.nodes.txt the imported material's shader nodes and the inputs the fit set
# ("NODE_TYPE INPUT VALUE..." lines), so the benchmark can say what Cycles rendered; DIR/version.txt Blender's
# version. One untimed 1-sample render first warms Cycles up. Cycles as cycles_common.py sets it up: the CPU,
# direct light only (Loomlight shades the camera ray's hit by the sky, nothing bounced), no denoiser, no adaptive
# sampling, a 1-pixel box filter.
import argparse
import math
import os
import sys

import numpy

# Debian's numpy 1.24 removed numpy.bool, which Blender 3.4's glTF importer still uses.
numpy.bool = bool

import bpy
from mathutils import Matrix, Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import cycles_common  # noqa: E402 (beside this script)

# The node inputs the glTF importer sets from the fitted material, reported per node type.
REPORTED_INPUTS = {
    "BSDF_PRINCIPLED": ("Base Color", "Metallic", "Roughness", "Specular", "Sheen"),
    "BSDF_VELVET": ("Color", "Sigma"),
}


def to_blender(x, y, z):
    return Vector((x, -z, y))


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="gltf_fit.py")
    p.add_argument("--sky", required=True, help="equirectangular EXR in Blender's convention")
    p.add_argument("--camera", required=True, help="PX,PY,PZ,LX,LY,LZ,FOV (Loomlight coordinates, +y up)")
    p.add_argument("--radius", type=float, default=1.0, help="the scene's sphere radius: each mesh is scaled to it")
    p.add_argument("--glb", action="append", required=True, help="NAME=FILE.glb, one per material")
    p.add_argument("--out", required=True, help="directory for NAME.exr, NAME.nodes.txt, times.tsv, version.txt")
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--samples", type=int, default=256)
    p.add_argument("--seed", type=int, default=1)
    return p.parse_args(argv)


def build_scene(args):
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    px, py, pz, lx, ly, lz, fov = (float(v) for v in args.camera.split(","))
    camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(camera)
    camera.location = to_blender(px, py, pz)
    camera.rotation_mode = "QUATERNION"
    # -Z toward the look-at point, +Y toward Blender's +z (Loomlight's +y, the scene's up).
    camera.rotation_quaternion = (to_blender(lx, ly, lz) - camera.location).to_track_quat("-Z", "Y")
    camera.data.sensor_fit = "VERTICAL"
    camera.data.angle_y = math.radians(fov)
    scene.camera = camera
    cycles_common.set_world_map(scene, args.sky, "sky")
    cycles_common.configure_cycles(scene, args.threads, args.size, "RGB")
    return scene


def import_glb(path, radius):
    """The file's meshes, scaled about the origin so that their farthest vertex lies at `radius`."""
    before = set(bpy.context.scene.objects)
    bpy.ops.import_scene.gltf(filepath=path)
    imported = [o for o in bpy.context.scene.objects if o not in before]
    meshes = [o for o in imported if o.type == "MESH"]
    for o in imported:
        if o.type in ("LIGHT", "CAMERA"):
            bpy.data.objects.remove(o)
    bpy.context.view_layer.update()
    farthest = max((o.matrix_world @ v.co).length for o in meshes for v in o.data.vertices)
    for top in [o for o in bpy.context.scene.objects if o not in before and o.parent is None]:
        top.matrix_world = Matrix.Scale(radius / farthest, 4) @ top.matrix_world
    bpy.context.view_layer.update()
    return [o for o in bpy.context.scene.objects if o not in before]


def value_text(value):
    try:
        return " ".join(f"{v:.6g}" for v in value)
    except TypeError:
        return f"{value:.6g}"


def write_nodes(objects, path):
    with open(path, "w") as out:
        for o in objects:
            if o.type != "MESH":
                continue
            for material in o.data.materials:
                if material is None or not material.use_nodes:
                    continue
                for node in material.node_tree.nodes:
                    inputs = REPORTED_INPUTS.get(node.type, ())
                    if not inputs:
                        out.write(f"{node.type}\n")
                    for name in inputs:
                        if name in node.inputs:
                            out.write(f"{node.type} {name.replace(' ', '_')} "
                                      f"{value_text(node.inputs[name].default_value)}\n")


def main():
    args = parse_args()
    os.makedirs(args.out, exist_ok=True)
    scene = build_scene(args)
    with open(os.path.join(args.out, "version.txt"), "w") as version:
        version.write(bpy.app.version_string + "\n")
    warmed = False
    with open(os.path.join(args.out, "times.tsv"), "w") as times:
        for job in args.glb:
            name, path = job.split("=", 1)
            objects = import_glb(path, args.radius)
            write_nodes(objects, os.path.join(args.out, name + ".nodes.txt"))
            if not warmed:
                cycles_common.render(scene, 1, 0)
                warmed = True
            seconds = cycles_common.render(scene, args.samples, args.seed)
            bpy.data.images["Render Result"].save_render(os.path.join(args.out, name + ".exr"))
            times.write(f"{name}\t{args.samples}\t{args.seed}\t{seconds:.6f}\n")
            times.flush()
            print(f"cycles: {name}, {args.samples} samples per pixel: {seconds:.3f} s", file=sys.stderr)
            for o in objects:
                bpy.data.objects.remove(o)


main()
