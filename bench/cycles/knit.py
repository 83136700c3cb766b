# A fiber-level knit in Blender Cycles for the fabrics benchmark (bench/fabrics_bench.cpp): the fiber curves
# Loomlight generated, read from a binary file the benchmark wrote, rendered as Cycles hair curves (3D round curves,
# each fiber its own width) with the Principled Hair BSDF, under the knit scene's light: one sun of the scene's
# irradiance and a constant world of its ambient radiance (Loomlight's Eq. 7 ambient term, traced visibility).
# Loomlight is y-up; Blender is z-up: a Loomlight point (x, y, z) is Blender's (x, -z, y).
#
#   blender -b --factory-startup -noaudio --python knit.py -- --curves FILE --out DIR --size 512 --threads 2 \
#       --camera X,Y,Z --look-at X,Y,Z --fov DEG --toward-light X,Y,Z --irradiance E --ambient A \
#       --renders NAME:SPP:SEED:RUNS,...
#
# The curves file (little-endian): int64 curves, int64 points, uint32 point count per curve, float32 xyz per point,
# float32 width (diameter) per curve. Renders, times and the version as cycles_common.run_renders writes them.
import argparse
import math
import os
import sys

import bpy
import numpy as np
from mathutils import Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import cycles_common  # noqa: E402 (beside this script)


def loomlight_to_blender(v):
    return Vector((v[0], -v[2], v[1]))


def triple(text):
    values = [float(x) for x in text.split(",")]
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"expected X,Y,Z, got {text!r}")
    return values


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="knit.py")
    p.add_argument("--curves", required=True, help="the fiber curves (see the header)")
    p.add_argument("--out", required=True, help="directory for NAME.exr and times.tsv")
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--camera", type=triple, required=True)
    p.add_argument("--look-at", type=triple, required=True)
    p.add_argument("--fov", type=float, required=True, help="vertical field of view, degrees")
    p.add_argument("--toward-light", type=triple, required=True)
    p.add_argument("--irradiance", type=float, required=True)
    p.add_argument("--ambient", type=float, required=True)
    p.add_argument("--renders", required=True, help="NAME:SPP:SEED:RUNS,...")
    return p.parse_args(argv)


def read_curves(path):
    with open(path, "rb") as f:
        curves, points = np.frombuffer(f.read(16), dtype="<i8")
        counts = np.frombuffer(f.read(4 * curves), dtype="<u4").astype(np.int64)
        xyz = np.frombuffer(f.read(12 * points), dtype="<f4").reshape(-1, 3)
        widths = np.frombuffer(f.read(4 * curves), dtype="<f4")
    return counts, xyz, widths


def fiber_object(scene, counts, xyz, widths, material):
    """The fibers as a mesh of edges (one chain per fiber, with a per-point radius attribute) turned into hair
    curves by geometry nodes on a Curves object, which Cycles renders as curves."""
    mesh = bpy.data.meshes.new("fiber_edges")
    blender_xyz = np.stack([xyz[:, 0], -xyz[:, 2], xyz[:, 1]], axis=1).astype(np.float32)
    mesh.vertices.add(len(blender_xyz))
    mesh.vertices.foreach_set("co", blender_xyz.ravel())
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    first = np.concatenate([np.arange(s, s + c - 1) for s, c in zip(starts, counts)])
    edges = np.stack([first, first + 1], axis=1).astype(np.int32)
    mesh.edges.add(len(edges))
    mesh.edges.foreach_set("vertices", edges.ravel())
    radius = mesh.attributes.new("fiber_radius", "FLOAT", "POINT")
    radius.data.foreach_set("value", np.repeat(0.5 * widths, counts).astype(np.float32))
    mesh.update()
    source = bpy.data.objects.new("fiber_edges", mesh)
    scene.collection.objects.link(source)
    source.hide_render = True

    hair = bpy.data.objects.new("fibers", bpy.data.hair_curves.new("fibers"))
    scene.collection.objects.link(hair)
    hair.data.materials.append(material)
    tree = bpy.data.node_groups.new("fibers", "GeometryNodeTree")
    tree.inputs.new("NodeSocketGeometry", "Geometry")
    tree.outputs.new("NodeSocketGeometry", "Geometry")
    nodes, links = tree.nodes, tree.links
    info = nodes.new("GeometryNodeObjectInfo")
    info.inputs["Object"].default_value = source
    to_curve = nodes.new("GeometryNodeMeshToCurve")
    set_radius = nodes.new("GeometryNodeSetCurveRadius")
    named = nodes.new("GeometryNodeInputNamedAttribute")
    named.data_type = "FLOAT"
    named.inputs["Name"].default_value = "fiber_radius"
    set_material = nodes.new("GeometryNodeSetMaterial")
    set_material.inputs["Material"].default_value = material
    output = nodes.new("NodeGroupOutput")
    links.new(info.outputs["Geometry"], to_curve.inputs["Mesh"])
    links.new(to_curve.outputs["Curve"], set_radius.inputs["Curve"])
    links.new(named.outputs["Attribute"], set_radius.inputs["Radius"])
    links.new(set_radius.outputs["Curve"], set_material.inputs["Geometry"])
    links.new(set_material.outputs["Geometry"], output.inputs["Geometry"])
    hair.modifiers.new("fibers", "NODES").node_group = tree
    return hair


def build_scene(args):
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene

    # Cotton as hair: an off-white fiber colour, moderately rough (each renderer is measured against its own
    # converged image, so the material need only be alike, not equal).
    material = bpy.data.materials.new("cotton")
    material.use_nodes = True
    nodes = material.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    hair_bsdf = nodes.new("ShaderNodeBsdfHairPrincipled")
    hair_bsdf.parametrization = "COLOR"
    hair_bsdf.inputs["Color"].default_value = (0.8, 0.78, 0.72, 1.0)
    hair_bsdf.inputs["Roughness"].default_value = 0.4
    material.node_tree.links.new(hair_bsdf.outputs["BSDF"], nodes["Material Output"].inputs["Surface"])

    counts, xyz, widths = read_curves(args.curves)
    fiber_object(scene, counts, xyz, widths, material)
    scene.cycles_curves.shape = "THICK"  # round 3D curves, as Loomlight's round linear segments
    scene.cycles_curves.subdivisions = 0

    camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(camera)
    camera.location = loomlight_to_blender(args.camera)
    camera.rotation_mode = "QUATERNION"
    camera.rotation_quaternion = (loomlight_to_blender(args.look_at) - camera.location).to_track_quat("-Z", "Y")
    camera.data.sensor_fit = "VERTICAL"
    camera.data.angle_y = math.radians(args.fov)
    camera.data.clip_start = 1e-3
    scene.camera = camera

    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    scene.collection.objects.link(sun)
    sun.data.energy = args.irradiance  # W/m^2: the irradiance on a surface facing it
    sun.data.angle = 0
    sun.rotation_mode = "QUATERNION"
    sun.rotation_quaternion = (-loomlight_to_blender(args.toward_light)).to_track_quat("-Z", "Y")

    world = bpy.data.worlds.new("ambient")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (1, 1, 1, 1)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = args.ambient
    world.cycles_visibility.camera = False  # Loomlight's fiber scenes have no background
    scene.world = world

    cycles_common.configure_cycles(scene, args.threads, args.size, "RGB")
    return scene


def main():
    args = parse_args()
    scene = build_scene(args)
    os.makedirs(args.out, exist_ok=True)
    cycles_common.run_renders(scene, args.out, args.renders)


main()
