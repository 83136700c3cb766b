# A product shot of bench/product_bench.cpp rebuilt in Blender Cycles: the same glTF mesh through Blender's own
# importer, the camera the benchmark gave Loomlight, the studio preset's softboxes (placed by the benchmark with
# render::PlaceLights) as rectangular area lights of the same centres, sizes, orientation and radiance, and the
# studio map as an equirectangular EXR the benchmark wrote from Environment::Studio(). Loomlight is y-up like
# glTF; Blender is z-up, and its importer maps a glTF point (x, y, z) to (x, -z, y), as this script maps the
# camera and lights.
#
#   blender -b --factory-startup -noaudio --python product.py -- --mesh MESH.glb --environment ENV.exr \
#       --camera PX,PY,PZ,LX,LY,LZ,UX,UY,UZ,FOV --lights LIGHTS.tsv --size 1600 --threads 2 \
#       --renders NAME:SPP:SEED:RUNS,... --out DIR
#
# LIGHTS.tsv: a line per softbox, "CX CY CZ FX FY FZ VX VY VZ WIDTH HEIGHT R G B": its centre, the direction it
# faces (emits toward), its height axis, its size and radiance, in Loomlight's coordinates. FOV is vertical.
#
# Each render NAME is rendered RUNS times (same seed, same image) and written to DIR/NAME.exr: RGBA, 32-bit
# float, premultiplied on a transparent film (the benchmark puts it over white as Loomlight's BACKGROUND_WHITE
# does). DIR/times.tsv gets "NAME SPP SEED SECONDS" per render, the fastest run's time in bpy's render operator
# (scene sync, BVH, world map and sampling; not Blender's start-up, the import nor the file write);
# DIR/import.txt the glTF import's seconds and the triangles imported; DIR/version.txt Blender's version. One
# untimed 1-sample render first warms Cycles up. Cycles on the CPU, direct light only (no bounces: Loomlight
# shades the camera ray's hit by the lights and the map, nothing bounced), no denoiser (Debian's Blender has no
# OpenImageDenoise), no adaptive sampling, a 1-pixel box filter (Loomlight's jittered pixel samples).
import argparse
import math
import os
import sys
import time

import numpy

# Debian's numpy 1.24 removed numpy.bool, which Blender 3.4's glTF importer still uses.
numpy.bool = bool

import bpy
from mathutils import Matrix, Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import cycles_common  # noqa: E402 (beside this script)


def to_blender(x, y, z):
    return Vector((x, -z, y))


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="product.py")
    p.add_argument("--mesh", required=True, help="glTF binary (.glb)")
    p.add_argument("--environment", required=True, help="equirectangular EXR in Blender's convention")
    p.add_argument("--camera", required=True, help="PX,PY,PZ,LX,LY,LZ,UX,UY,UZ,FOV (Loomlight coordinates)")
    p.add_argument("--lights", required=True, help="LIGHTS.tsv (see the header)")
    p.add_argument("--out", required=True, help="directory for NAME.exr, times.tsv, import.txt, version.txt")
    p.add_argument("--size", type=int, default=1600)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--renders", required=True, help="NAME:SPP:SEED:RUNS,...")
    return p.parse_args(argv)


def frame(position, forward, up):
    """A world matrix at `position` whose -Z looks along `forward` and whose +Y is `up` made perpendicular."""
    z = -forward.normalized()
    y = (up - up.dot(z) * z).normalized()
    x = y.cross(z)
    m = Matrix((x, y, z)).transposed().to_4x4()
    m.translation = position
    return m


def import_mesh(path):
    start = time.perf_counter()
    bpy.ops.import_scene.gltf(filepath=path)
    seconds = time.perf_counter() - start
    meshes = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    # Only the mesh is the product: the benchmark gives the camera and the lights.
    for o in list(bpy.context.scene.objects):
        if o.type in ("LIGHT", "CAMERA"):
            bpy.data.objects.remove(o)
    triangles = 0
    for o in meshes:
        o.data.calc_loop_triangles()
        triangles += len(o.data.loop_triangles)
    return meshes, seconds, triangles


def cloth_material():
    # Each renderer's noise is measured against its own converged image, so the material need only be alike:
    # a dark cotton with a soft sheen, like the woven cotton_twill Loomlight renders (kd about 0.04, a bright
    # specular along the threads), its base colour raised until the product's mean brightness came near
    # Loomlight's (the report gives both).
    material = bpy.data.materials.new("cloth")
    material.use_nodes = True
    bsdf = material.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.12, 0.11, 0.10, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.45
    bsdf.inputs["Specular"].default_value = 0.5
    bsdf.inputs["Sheen"].default_value = 1.0
    bsdf.inputs["Sheen Tint"].default_value = 0.0
    return material


def add_softbox(scene, index, values):
    cx, cy, cz, fx, fy, fz, vx, vy, vz, width, height, r, g, b = values
    light = bpy.data.lights.new(f"softbox{index}", "AREA")
    light.shape = "RECTANGLE"
    light.size = width
    light.size_y = height
    # Cycles' area light of power P and area A emits radiance P / (4 A) (measured: a white Lambertian plane
    # under a large area light of P = 10000 W, A = 10000 m^2 rendered 0.25), from its front (-Z) only.
    peak = max(r, g, b)
    light.color = (r / peak, g / peak, b / peak) if peak > 0 else (1, 1, 1)
    light.energy = 4 * width * height * peak
    obj = bpy.data.objects.new(f"softbox{index}", light)
    scene.collection.objects.link(obj)
    # -Z along the facing direction, +Y along the height axis (the rectangle is symmetric, so the signs of its
    # axes do not matter).
    obj.matrix_world = frame(to_blender(cx, cy, cz), to_blender(fx, fy, fz), to_blender(vx, vy, vz))
    # Loomlight's softboxes light the product and are not seen by the camera (the background is white).
    obj.visible_camera = False


def build_scene(args):
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    meshes, import_seconds, triangles = import_mesh(args.mesh)
    material = cloth_material()
    for o in meshes:
        if not o.data.materials:
            o.data.materials.append(material)
        for k in range(len(o.data.materials)):
            o.data.materials[k] = material

    px, py, pz, lx, ly, lz, ux, uy, uz, fov = (float(v) for v in args.camera.split(","))
    camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(camera)
    position = to_blender(px, py, pz)
    camera.matrix_world = frame(position, to_blender(lx, ly, lz) - position, to_blender(ux, uy, uz))
    camera.data.sensor_fit = "VERTICAL"
    camera.data.angle_y = math.radians(fov)
    camera.data.clip_start = 1e-3
    scene.camera = camera

    with open(args.lights) as lights:
        for index, line in enumerate(l for l in lights if l.strip()):
            add_softbox(scene, index, [float(v) for v in line.split()])

    # The studio map lights the product; the film is transparent, so the camera sees none of it.
    cycles_common.set_world_map(scene, args.environment, "studio")
    cycles_common.configure_cycles(scene, args.threads, args.size, "RGBA", transparent=True)
    return scene, import_seconds, triangles


def main():
    args = parse_args()
    os.makedirs(args.out, exist_ok=True)
    scene, import_seconds, triangles = build_scene(args)
    with open(os.path.join(args.out, "import.txt"), "w") as imported:
        imported.write(f"{import_seconds:.6f} {triangles}\n")
    cycles_common.run_renders(scene, args.out, args.renders)


main()
