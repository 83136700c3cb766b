"""Generates Loomlight's built-in product meshes with Blender's cloth simulator, and the mesh test fixtures.

Run with Debian's Blender 3.4 (what produced the committed files; see the PROVENANCE.md and README.md they sit in),
with Debian's python3-numpy installed (the glTF add-on needs it):

  blender -b --factory-startup --python-exit-code 1 -P scripts/blender/make_product_meshes.py -- \
      products server/render/scenes/meshes [--only NAME ...] [--preview DIR]
  blender -b --factory-startup --python-exit-code 1 -P scripts/blender/make_product_meshes.py -- \
      fixtures tests/data/meshes

products: drape_stand, folded_stack, hanging_drape (the product scenes) and garment_bench (the speed benchmark's
garment), each settled by the cloth simulator from a start shape, subdivided after the simulation for smooth
shading, and written as glTF 2.0 binary (+Y up, metres) with named materials, normals and UVs; PROVENANCE.md
beside them records the Blender version, the command, this script's git blob hash, the settings and the counts.
--preview renders each written file, imported back by Blender's glTF importer, to DIR/NAME.png (Cycles, CPU).
fixtures: small files for the mesh parser's tests, from Blender's own exporters (an independent producer).

UVs of the cloth are its rest (flat pattern) coordinates in metres: one UV unit spans one metre of cloth, and v runs
along the warp (the hanging direction of the curtain and the skirt, the swatch's and the stack's length).
"""

import hashlib
import json
import math
import os
import random
import struct
import sys
import time

import numpy

# Debian's numpy 1.24 removed numpy.bool, which Blender 3.4's glTF add-on still uses.
numpy.bool = bool

import bmesh  # noqa: E402
import bpy  # noqa: E402
from mathutils.bvhtree import BVHTree  # noqa: E402

SCRIPT_PATH = os.path.abspath(__file__)
FPS = 24


# ---------------------------------------------------------------------------------------------------------------
# Scene and mesh helpers


def reset_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps = FPS
    scene.unit_settings.system = 'METRIC'
    scene.unit_settings.scale_length = 1.0
    scene.gravity = (0.0, 0.0, -9.81)
    return scene


def material(name, colour):
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    mat.diffuse_color = (*colour, 1.0)
    mat.use_nodes = True
    mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (*colour, 1.0)
    return mat


def link(obj):
    bpy.context.scene.collection.objects.link(obj)
    return obj


def grid_object(name, nu, nv, position, uv, material_index=None, closed_u=False, materials=()):
    """A quad grid of (nu+1) x (nv+1) vertices (nu x (nv+1) when closed in u). position(i, j) -> (x, y, z) and
    uv(i, j) -> (u, v) per corner (i may equal nu on a closed grid: the seam's UVs); material_index(i, j) -> index
    of the quad whose low corner is (i, j)."""
    columns = nu if closed_u else nu + 1
    verts = [position(i, j) for j in range(nv + 1) for i in range(columns)]
    faces, face_corners = [], []
    for j in range(nv):
        for i in range(nu):
            i1 = (i + 1) % columns
            faces.append((j * columns + i, j * columns + i1, (j + 1) * columns + i1, (j + 1) * columns + i))
            face_corners.append(((i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)))
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    mesh.validate()
    for mat in materials:  # before the indices: an index is clamped to the slots there are
        mesh.materials.append(mat)
    uv_layer = mesh.uv_layers.new(name="UVMap")
    for poly, corners in zip(mesh.polygons, face_corners):
        for loop_index, corner in zip(poly.loop_indices, corners):
            uv_layer.data[loop_index].uv = uv(*corner)
        if material_index is not None:
            poly.material_index = material_index(*corners[0])
        poly.use_smooth = True
    return link(bpy.data.objects.new(name, mesh))


def add_start_shape(obj, start_position):
    """Keeps the mesh's own coordinates as the rest shape (Basis: the flat pattern) and adds the shape the
    simulation starts from as a shape key at full value; the cloth's rest lengths come from the Basis."""
    obj.shape_key_add(name="Basis", from_mix=False)
    start = obj.shape_key_add(name="Start", from_mix=False)
    for index, point in enumerate(start.data):
        point.co = start_position(index)
    start.value = 1.0


def primitive(kind, name, **kwargs):
    getattr(bpy.ops.mesh, "primitive_" + kind + "_add")(**kwargs)
    obj = bpy.context.active_object
    obj.name = name
    obj.data.name = name
    return obj


def collider(obj, thickness=0.004, friction=5.0):
    obj.modifiers.new("Collision", 'COLLISION')
    obj.collision.thickness_outer = thickness
    obj.collision.cloth_friction = friction
    obj.collision.damping = 0.5
    return obj


def cloth(obj, frames, settings):
    """Adds a cloth modifier with the given settings (attribute name -> value on ClothSettings or, prefixed
    'collision_', on ClothCollisionSettings) and runs the simulation to its last frame."""
    mod = obj.modifiers.new("Cloth", 'CLOTH')
    for key, value in settings.items():
        if key.startswith("collision_"):
            setattr(mod.collision_settings, key[len("collision_"):], value)
        elif key == "rest_shape_key":
            mod.settings.rest_shape_key = obj.data.shape_keys.key_blocks[value]
        else:
            setattr(mod.settings, key, value)
    mod.point_cache.frame_start = 1
    mod.point_cache.frame_end = frames
    return mod


def simulate(frames):
    scene = bpy.context.scene
    scene.frame_start = 1
    scene.frame_end = frames
    start = time.time()
    for frame in range(1, frames + 1):
        scene.frame_set(frame)
        if frame % 10 == 0:
            print(f"frame {frame}/{frames}: {time.time() - start:.0f} s", flush=True)
    return time.time() - start


def freeze(obj, name=None):
    """The object's evaluated mesh (cloth result, modifiers applied) as a new plain object in world space."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    evaluated = obj.evaluated_get(depsgraph)
    mesh = bpy.data.meshes.new_from_object(evaluated)
    mesh.transform(obj.matrix_world)
    return link(bpy.data.objects.new(name or obj.name + "_final", mesh))


def apply_modifiers(obj, modifiers):
    """Adds (type, settings) modifiers and returns the frozen result."""
    for kind, settings in modifiers:
        mod = obj.modifiers.new(kind.lower(), kind)
        for key, value in settings.items():
            setattr(mod, key, value)
    return freeze(obj, obj.name + "_mod")


def join(objects, name):
    for obj in bpy.context.scene.objects:
        obj.select_set(False)
    for obj in objects:
        obj.select_set(True)
    bpy.context.view_layer.objects.active = objects[0]
    bpy.ops.object.join()
    joined = bpy.context.active_object
    joined.name = name
    bpy.ops.object.transform_apply(location=True, rotation=True, scale=True)
    return joined


def set_material(obj, mat):
    obj.data.materials.clear()
    obj.data.materials.append(mat)
    for poly in obj.data.polygons:
        poly.material_index = 0


def smooth(obj):
    for poly in obj.data.polygons:
        poly.use_smooth = True


def remove_except(keep):
    for obj in list(bpy.context.scene.objects):
        if obj not in keep:
            bpy.data.objects.remove(obj, do_unlink=True)


def export_glb(obj, path):
    remove_except([obj])
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    bpy.ops.export_scene.gltf(
        filepath=path, export_format='GLB', use_selection=True, export_apply=True, export_yup=True,
        export_texcoords=True, export_normals=True, export_tangents=False, export_colors=False,
        export_attributes=False, export_materials='EXPORT', export_cameras=False, export_lights=False,
        export_animations=False, export_skins=False, export_morph=False, export_extras=False)


def export_obj(obj, path):
    remove_except([obj])
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    bpy.ops.wm.obj_export(
        filepath=path, export_selected_objects=True, apply_modifiers=True, export_uv=True, export_normals=True,
        export_materials=True, export_triangulated_mesh=False, forward_axis='NEGATIVE_Z', up_axis='Y')


def glb_summary(path):
    """Triangles, vertices and materials per material as stored in the written file (its JSON chunk)."""
    with open(path, "rb") as f:
        data = f.read()
    length, kind = struct.unpack_from("<I4s", data, 12)
    doc = json.loads(data[20:20 + length])
    names = [m.get("name", "") for m in doc.get("materials", [])]
    per_material = {}
    for mesh in doc["meshes"]:
        for prim in mesh["primitives"]:
            name = names[prim["material"]] if "material" in prim else "(none)"
            entry = per_material.setdefault(name, {"triangles": 0, "vertices": 0})
            entry["triangles"] += doc["accessors"][prim["indices"]]["count"] // 3
            entry["vertices"] += doc["accessors"][prim["attributes"]["POSITION"]]["count"]
            attributes = sorted(prim["attributes"])
            entry["attributes"] = attributes
    return {"bytes": len(data), "materials": per_material,
            "triangles": sum(e["triangles"] for e in per_material.values()),
            "vertices": sum(e["vertices"] for e in per_material.values())}


def intersecting_faces(obj):
    """Pairs of faces that intersect and share no vertex (cloth through cloth or through a part), by material."""
    mesh = bmesh.new()
    mesh.from_mesh(obj.data)
    mesh.faces.ensure_lookup_table()
    tree = BVHTree.FromBMesh(mesh)
    counts = {}
    for a, b in tree.overlap(tree):
        face_a, face_b = mesh.faces[a], mesh.faces[b]
        if a < b and not {v.index for v in face_a.verts} & {v.index for v in face_b.verts}:
            key = " / ".join(sorted((obj.data.materials[face_a.material_index].name,
                                     obj.data.materials[face_b.material_index].name)))
            counts[key] = counts.get(key, 0) + 1
    mesh.free()
    return counts


def git_blob_hash(path):
    with open(path, "rb") as f:
        content = f.read()
    return hashlib.sha1(b"blob %d\0" % len(content) + content).hexdigest()


def stretch_stats(obj_rest_coords, obj):
    """Largest and smallest edge length ratio final/rest (a sign of an exploded or torn simulation)."""
    mesh = obj.data
    ratios = []
    for edge in mesh.edges:
        a, b = edge.vertices
        rest = (obj_rest_coords[a] - obj_rest_coords[b]).length
        if rest > 0:
            ratios.append((mesh.vertices[a].co - mesh.vertices[b].co).length / rest)
    return min(ratios), max(ratios)


def rest_coords(obj):
    key = obj.data.shape_keys.key_blocks["Basis"] if obj.data.shape_keys else None
    return [p.co.copy() for p in (key.data if key else obj.data.vertices)]


# ---------------------------------------------------------------------------------------------------------------
# Products

COTTON = dict(quality=6, mass=0.15, air_damping=3.0, tension_stiffness=15.0, compression_stiffness=15.0,
              shear_stiffness=5.0, bending_stiffness=0.05, tension_damping=5.0, compression_damping=5.0,
              shear_damping=5.0, bending_damping=0.5)


def drape_stand(report):
    """A 0.5 m square swatch dropped over a ball on a pole (a draping stand) and settled."""
    stand_mat, fabric_mat = material("stand", (0.8, 0.8, 0.78)), material("fabric", (0.6, 0.25, 0.2))
    ball_radius, ball_z, pole_radius = 0.11, 0.46, 0.012
    ball = collider(primitive("uv_sphere", "ball", segments=64, ring_count=32, radius=ball_radius,
                              location=(0, 0, ball_z)), friction=20.0)
    pole = collider(primitive("cylinder", "pole", vertices=32, radius=pole_radius, depth=ball_z,
                              location=(0, 0, ball_z / 2)), friction=20.0)
    base = collider(primitive("cylinder", "base", vertices=64, radius=0.12, depth=0.02, location=(0, 0, 0.01)))
    bpy.ops.object.modifier_add(type='BEVEL')
    base.modifiers["Bevel"].width, base.modifiers["Bevel"].segments = 0.006, 3
    collider(primitive("plane", "floor", size=2.0, location=(0, 0, 0)))
    size, n = 0.5, 56
    angle, offset = math.radians(17.0), (0.018, -0.011)
    drop_z = ball_z + ball_radius + 0.03

    def position(i, j):
        x, y = (i / n - 0.5) * size, (j / n - 0.5) * size
        return (offset[0] + x * math.cos(angle) - y * math.sin(angle),
                offset[1] + x * math.sin(angle) + y * math.cos(angle), drop_z)

    swatch = grid_object("swatch", n, n, position, lambda i, j: (i / n * size, j / n * size))
    swatch.data.materials.append(fabric_mat)
    settings = dict(COTTON, collision_distance_min=0.004, collision_use_self_collision=True,
                    collision_self_distance_min=0.003, collision_collision_quality=3, collision_self_friction=5.0)
    frames = 110
    cloth(swatch, frames, settings)
    rest = rest_coords(swatch)
    seconds = simulate(frames)
    cloth_final = freeze(swatch, "swatch_final")
    report["simulation"] = dict(grid=f"{n} x {n} quads ({(n + 1) ** 2} vertices), {size} m square, "
                                f"dropped from {drop_z - ball_z - ball_radius:.2f} m above the ball, "
                                f"turned {math.degrees(angle):.0f} degrees and {offset} m off centre",
                                frames=frames, seconds=round(seconds, 1), settings=settings,
                                colliders=f"ball r = {ball_radius} m at z = {ball_z} m (friction 20), pole r = "
                                f"{pole_radius} m, base disc r = 0.12 m, floor (not exported)")
    report["edge_ratio"] = stretch_stats(rest, cloth_final)
    # Cloth-ball clearance: the closest fabric vertex to the ball's centre.
    report["min_clearance_m"] = min((v.co - ball.location).length for v in cloth_final.data.vertices) - ball_radius
    cloth_smooth = apply_modifiers(cloth_final, [('SUBSURF', dict(levels=1, render_levels=1))])
    stand_parts = [freeze(o, o.name + "_part") for o in (ball, pole, base)]
    for part in stand_parts:
        set_material(part, stand_mat)
        smooth(part)
    fabric_obj = cloth_smooth
    set_material(fabric_obj, fabric_mat)
    remove_except([fabric_obj] + stand_parts)
    result = join([fabric_obj] + stand_parts, "drape_stand")
    report["uv"] = "fabric: its flat 0.5 m square, 1 UV unit = 1 m; stand: Blender's primitive UVs (not to scale)"
    return result


def folded_stack(report):
    """Three cloths, each folded in three (a Z-fold with rounded turns), stacked on a table and settled under their
    weight. The folded shape is the cloth's rest shape (pressed folds, as a shop folds them: with a flat rest the
    leaves sprang open into a heap); the UVs are the flat cloth's."""
    fabric_mat = material("fabric", (0.25, 0.35, 0.55))
    collider(primitive("plane", "table", size=2.0, location=(0, 0, 0)), thickness=0.002, friction=10.0)
    width, leaf, radius = 0.34, 0.24, 0.007
    nu, leaf_segments, bend_segments = 24, 18, 4
    rng = random.Random(46)
    # Arc-length parametrised fold path in (y, z): leaf, half turn, leaf back, half turn, leaf.
    bend_length = math.pi * radius
    length = 3 * leaf + 2 * bend_length
    stations = []  # arc length of each row
    s = 0.0
    for part in range(5):
        segs, seg_len = (leaf_segments, leaf) if part % 2 == 0 else (bend_segments, bend_length)
        for k in range(segs):
            stations.append(s + seg_len * k / segs)
        s += seg_len
    stations.append(length)

    def fold_point(s):
        if s <= leaf:
            return (s - leaf / 2, 0.0)
        s -= leaf
        if s <= bend_length:
            t = s / radius
            return (leaf / 2 + radius * math.sin(t), radius - radius * math.cos(t))
        s -= bend_length
        if s <= leaf:
            return (leaf / 2 - s, 2 * radius)
        s -= leaf
        if s <= bend_length:
            t = s / radius
            return (-leaf / 2 - radius * math.sin(t), 3 * radius - radius * math.cos(t))
        s -= bend_length
        return (-leaf / 2 + s, 4 * radius)

    nv = len(stations) - 1
    cloths = []
    layer_height = 4 * radius + 0.006
    for c in range(3):
        angle = math.radians(rng.uniform(-4.0, 4.0))
        shift = (rng.uniform(-0.008, 0.008), rng.uniform(-0.008, 0.008))
        base_z = 0.004 + c * layer_height

        def folded(i, j, angle=angle, shift=shift, base_z=base_z):
            x = (i / nu - 0.5) * width
            y, z = fold_point(stations[j])
            return (shift[0] + x * math.cos(angle) - y * math.sin(angle),
                    shift[1] + x * math.sin(angle) + y * math.cos(angle), base_z + z)

        cloths.append(grid_object(f"cloth{c}", nu, nv, folded, lambda i, j: (i / nu * width, stations[j])))
    stack = join(cloths, "stack")
    settings = dict(COTTON, mass=0.02, tension_stiffness=40.0, compression_stiffness=40.0, shear_stiffness=15.0,
                    bending_stiffness=2.0, collision_distance_min=0.002,
                    collision_use_self_collision=True, collision_self_distance_min=0.0015,
                    collision_collision_quality=4, collision_self_friction=10.0)
    frames = 50
    cloth(stack, frames, settings)
    rest = rest_coords(stack)
    seconds = simulate(frames)
    final = freeze(stack, "stack_final")
    report["simulation"] = dict(grid=f"3 cloths of {nu} x {nv} quads ({(nu + 1) * (nv + 1)} vertices each), "
                                f"{width} x {length:.3f} m flat, Z-folded (its rest shape) in three leaves of "
                                f"{leaf} m with {radius * 1000:.0f} mm turns, stacked with seeded turns of up to 4 "
                                f"degrees and shifts of up to 8 mm",
                                frames=frames, seconds=round(seconds, 1), settings=settings,
                                colliders="table plane at z = 0 (not exported)")
    report["edge_ratio"] = stretch_stats(rest, final)
    report["min_z_m"] = min(v.co.z for v in final.data.vertices)
    result = apply_modifiers(final, [('SUBSURF', dict(levels=1, render_levels=1))])
    set_material(result, fabric_mat)
    remove_except([result])
    result.name = "folded_stack"
    report["uv"] = "fabric: each cloth's flat pattern, 1 UV unit = 1 m, v along the cloth's length (across folds)"
    return result


def hanging_drape(report):
    """A curtain gathered on a rod: 1.9 m of cloth pinned along its top edge in pleats across a 1.1 m rod and left
    to hang. It starts with pleats of seeded depth that widen towards the hem (to 1.5 m) and drift sideways by
    seeded amounts, and its rest shape is the flat cloth, so the simulation relaxes them into the folds."""
    fabric_mat, rod_mat = material("fabric", (0.75, 0.7, 0.6)), material("rod", (0.3, 0.25, 0.2))
    rest_width, height, span, hem_span, top = 1.9, 1.5, 1.1, 1.5, 1.6
    nu, nv, pleats = 95, 60, 9
    rng = random.Random(4646)
    top_depths = numpy.array([rng.uniform(0.7, 1.3) for _ in range(pleats)])
    hem_depths = numpy.array([rng.uniform(0.5, 1.5) for _ in range(pleats)])
    drift = numpy.array([0.0] + [rng.uniform(-1.0, 1.0) for _ in range(pleats - 1)] + [0.0])
    fine = numpy.linspace(0.0, 1.0, 2001)

    def row_profile(t):
        """Row t (0 at the top, 1 at the hem): a pleated curve whose length is the cloth's rest width, resampled at
        the rest spacing of the row's vertices."""
        row_span = span + (hem_span - span) * t
        bounds = (numpy.arange(pleats + 1) / pleats + drift * 0.04 * t) * row_span - row_span / 2
        x = bounds[0] + fine * row_span
        pleat = numpy.clip(numpy.searchsorted(bounds, x, side="right") - 1, 0, pleats - 1)
        phase = (x - bounds[pleat]) / (bounds[pleat + 1] - bounds[pleat])
        shape = numpy.sin(phase * 2 * math.pi) * (top_depths + (hem_depths - top_depths) * t)[pleat]

        def arc(amplitude):
            steps = numpy.hypot(numpy.diff(x), numpy.diff(shape * amplitude))
            return numpy.concatenate(([0.0], numpy.cumsum(steps)))

        lo, hi = 0.0, 0.5
        for _ in range(40):  # the pleat amplitude at which the curve is as long as the cloth is wide
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if arc(mid)[-1] < rest_width else (lo, mid)
        lengths = arc(lo)
        s = numpy.arange(nu + 1) / nu * lengths[-1]
        return numpy.interp(s, lengths, x), numpy.interp(s, lengths, shape * lo), bounds, lo

    rows = [row_profile(j / nv) for j in range(nv + 1)]
    amplitude = rows[0][3]
    curtain = grid_object("curtain", nu, nv, lambda i, j: ((i / nu - 0.5) * rest_width, 0.0, top - j / nv * height),
                          lambda i, j: (i / nu * rest_width, height - j / nv * height))
    add_start_shape(curtain, lambda index: (rows[index // (nu + 1)][0][index % (nu + 1)],
                                            rows[index // (nu + 1)][1][index % (nu + 1)],
                                            top - (index // (nu + 1)) / nv * height))
    curtain.data.materials.append(fabric_mat)
    pin = curtain.vertex_groups.new(name="pin")
    pin.add(list(range(nu + 1)), 1.0, 'REPLACE')
    settings = dict(COTTON, mass=0.2, bending_stiffness=0.3, rest_shape_key="Basis", vertex_group_mass="pin",
                    pin_stiffness=5.0, collision_distance_min=0.005, collision_use_self_collision=True,
                    collision_self_distance_min=0.004, collision_collision_quality=2)
    frames = 120
    cloth(curtain, frames, settings)
    rest = rest_coords(curtain)
    seconds = simulate(frames)
    final = freeze(curtain, "curtain_final")
    report["simulation"] = dict(grid=f"{nu} x {nv} quads ({(nu + 1) * (nv + 1)} vertices), {rest_width} x {height} m "
                                f"flat, top row pinned along a {span} m pleated line ({pleats} pleats of seeded "
                                f"depth, amplitude {amplitude * 100:.1f} cm at the top), widening to {hem_span} m "
                                f"at the hem at the start",
                                frames=frames, seconds=round(seconds, 1), settings=settings, colliders="none")
    report["edge_ratio"] = stretch_stats(rest, final)
    result = apply_modifiers(final, [('SUBSURF', dict(levels=1, render_levels=1))])
    set_material(result, fabric_mat)
    rod_z = top + 0.025
    rod = primitive("cylinder", "rod", vertices=32, radius=0.015, depth=span + 0.2, location=(0, 0, rod_z),
                    rotation=(0, math.pi / 2, 0))
    rod = freeze(rod, "rod_part")
    finials = [freeze(primitive("uv_sphere", f"finial{k}", segments=32, ring_count=16, radius=0.03,
                                location=(side * (span / 2 + 0.1 + 0.02), 0, rod_z)), f"finial{k}_part")
               for k, side in enumerate((-1, 1))]
    rings = []
    for k in range(pleats + 1):
        x = rows[0][2][k]
        ring = primitive("torus", f"ring{k}", major_radius=0.022, minor_radius=0.003, major_segments=24,
                         minor_segments=8, location=(x, 0, rod_z), rotation=(0, math.pi / 2, 0))
        rings.append(freeze(ring, f"ring{k}_part"))
    for part in [rod] + finials + rings:
        set_material(part, rod_mat)
        smooth(part)
    remove_except([result, rod] + finials + rings)
    joined = join([result, rod] + finials + rings, "hanging_drape")
    report["uv"] = "fabric: the flat curtain, 1 UV unit = 1 m, v along the height (warp hangs); rod: primitive UVs"
    return joined


def garment_bench(report):
    """A half-circle skirt (a cone frustum pattern) pinned at the waist of a body proxy (hips and legs, not
    exported) and left to fall into its flutes; front and back panels, a waistband and a hem band, and a lining
    (an inner shell 4 mm in), subdivided to over 100,000 triangles for the speed benchmark."""
    mats = [material("body", (0.2, 0.3, 0.5)), material("waistband", (0.15, 0.15, 0.2)),
            material("hem", (0.3, 0.35, 0.55)), material("lining", (0.7, 0.7, 0.75))]
    waist_z, waist_r, hem_r, slant = 1.0, 0.15, 0.43, 0.56
    nu, nv, waist_rows, hem_rows = 80, 28, 2, 2
    sin_a = (hem_r - waist_r) / slant
    cos_a = math.sqrt(1 - sin_a * sin_a)
    r_inner = waist_r / sin_a  # the pattern's inner radius
    hips = primitive("uv_sphere", "hips", segments=48, ring_count=24, radius=1.0, location=(0, 0, waist_z - 0.17))
    hips.scale = (0.175, 0.135, 0.22)
    collider(hips, thickness=0.006, friction=5.0)
    for k, side in enumerate((-1, 1)):
        collider(primitive("cylinder", f"leg{k}", vertices=32, radius=0.068, depth=0.8,
                           location=(side * 0.088, 0, waist_z - 0.2 - 0.4)), thickness=0.006)

    def position(i, j):
        theta = i / nu * 2 * math.pi
        s = j / nv * slant
        r = waist_r + s * sin_a
        # theta = 0 at the front (-y, Blender's front view looks along +y).
        return (r * math.sin(theta), -r * math.cos(theta), waist_z - s * cos_a)

    def material_index(i, j):
        return 1 if j < waist_rows else 2 if j >= nv - hem_rows else 0

    skirt = grid_object("skirt", nu, nv, position, lambda i, j: (0.0, 0.0), material_index, closed_u=True,
                        materials=mats)
    # Each panel's flat pattern, a sector of an annulus with its centre line (the grain) along v, the back panel
    # beside the front; a face takes its panel from its centre, so the side seams (theta = 90 and 270 degrees)
    # split the UVs.
    uv_layer = skirt.data.uv_layers["UVMap"]
    for poly in skirt.data.polygons:
        centre_i = (poly.index % nu) + 0.5
        theta_c = centre_i / nu * 2 * math.pi
        back = math.pi / 2 < theta_c < 3 * math.pi / 2
        j0 = poly.index // nu
        for loop_index, (di, dj) in zip(poly.loop_indices, ((0, 0), (1, 0), (1, 1), (0, 1))):
            i = poly.index % nu + di
            theta = i / nu * 2 * math.pi
            local = theta - math.pi if back else (theta if theta <= math.pi / 2 + 1e-9 else theta - 2 * math.pi)
            phi = local * sin_a
            radius = r_inner + (j0 + dj) / nv * slant
            uv_layer.data[loop_index].uv = (radius * math.sin(phi) + (1.0 if back else 0.0),
                                            (r_inner + slant) - radius * math.cos(phi))
    # The grid's faces wind clockwise seen from outside: reversed, the skirt's normals face out (and the lining's
    # in).
    outward = bmesh.new()
    outward.from_mesh(skirt.data)
    bmesh.ops.reverse_faces(outward, faces=outward.faces)
    outward.to_mesh(skirt.data)
    outward.free()
    pin = skirt.vertex_groups.new(name="pin")
    pin.add(list(range(nu)), 1.0, 'REPLACE')
    settings = dict(COTTON, mass=0.1, bending_stiffness=0.1, vertex_group_mass="pin", pin_stiffness=5.0,
                    collision_distance_min=0.005, collision_use_self_collision=True,
                    collision_self_distance_min=0.004, collision_collision_quality=3)
    frames = 90
    cloth(skirt, frames, settings)
    rest = rest_coords(skirt)
    seconds = simulate(frames)
    final = freeze(skirt, "skirt_final")
    report["simulation"] = dict(grid=f"{nu} x {nv} quads ({nu * (nv + 1)} vertices), a cone frustum from r = "
                                f"{waist_r} m at the waist to r = {hem_r} m, {slant} m long (a half-circle skirt), "
                                f"waist row pinned", frames=frames, seconds=round(seconds, 1), settings=settings,
                                colliders="hips ellipsoid 0.175 x 0.135 x 0.22 m, two legs r = 0.068 m "
                                "(not exported)")
    report["edge_ratio"] = stretch_stats(rest, final)
    result = apply_modifiers(final, [
        # The lining: an inner shell 4 mm in, without rim faces (their UVs would be degenerate); every inner face
        # takes the last material (Blender clamps body, waistband and hem + 3 to it).
        ('SOLIDIFY', dict(thickness=0.004, offset=-1.0, use_rim=False, material_offset=3,
                          use_quality_normals=True)),
        ('SUBSURF', dict(levels=2, render_levels=2))])
    remove_except([result])
    result.name = "garment_bench"
    report["uv"] = ("each panel's flat pattern (front, back beside it at u + 1), 1 UV unit = 1 m, v along the grain "
                    "(down the centre front and back); waistband and hem bands share their panel's UVs; the "
                    "lining repeats the outer UVs")
    return result


PRODUCTS = {"drape_stand": drape_stand, "folded_stack": folded_stack, "hanging_drape": hanging_drape,
            "garment_bench": garment_bench}


# ---------------------------------------------------------------------------------------------------------------
# Preview: the written file imported back and rendered


def preview(glb_path, png_path):
    reset_scene()
    bpy.ops.import_scene.gltf(filepath=glb_path)
    objects = [o for o in bpy.context.scene.objects if o.type == 'MESH']
    corners = [o.matrix_world @ v.co for o in objects for v in o.data.vertices]
    lo = [min(c[k] for c in corners) for k in range(3)]
    hi = [max(c[k] for c in corners) for k in range(3)]
    centre = [(a + b) / 2 for a, b in zip(lo, hi)]
    extent = max(b - a for a, b in zip(lo, hi))
    scene = bpy.context.scene
    cam_data = bpy.data.cameras.new("cam")
    cam_data.lens = 50
    cam = link(bpy.data.objects.new("cam", cam_data))
    direction = (0.55, -1.0, 0.45)
    norm = math.sqrt(sum(d * d for d in direction))
    distance = extent * 2.2
    cam.location = [c + d / norm * distance for c, d in zip(centre, direction)]
    track = cam.constraints.new('TRACK_TO')
    target = link(bpy.data.objects.new("target", None))
    target.location = centre
    track.target = target
    scene.camera = cam
    for loc, energy in (((3, -3, 4), 800.0), ((-4, -1, 2), 250.0), ((0, 4, 3), 300.0)):
        light_data = bpy.data.lights.new("light", 'AREA')
        light_data.energy = energy * extent
        light_data.size = 2.0
        light = link(bpy.data.objects.new("light", light_data))
        light.location = [c + l * extent for c, l in zip(centre, loc)]
        light_track = light.constraints.new('TRACK_TO')
        light_track.target = target
    world = bpy.data.worlds.new("world")
    world.color = (0.8, 0.8, 0.8)
    scene.world = world
    scene.render.engine = 'CYCLES'
    scene.cycles.device = 'CPU'
    scene.cycles.samples = 24
    scene.cycles.use_denoising = False  # Debian's Blender has no OpenImageDenoise
    scene.render.resolution_x = scene.render.resolution_y = 480
    scene.render.filepath = png_path
    bpy.ops.render.render(write_still=True)


# ---------------------------------------------------------------------------------------------------------------
# Fixtures


def fixtures(out_dir):
    reset_scene()
    cloth_mat = material("cloth", (0.5, 0.5, 0.5))
    sphere = primitive("uv_sphere", "uv_sphere", segments=64, ring_count=32, radius=1.0, location=(0, 0, 0))
    set_material(sphere, cloth_mat)
    smooth(sphere)
    export_glb(sphere, os.path.join(out_dir, "uv_sphere.glb"))
    export_obj(sphere, os.path.join(out_dir, "uv_sphere.obj"))

    reset_scene()
    plane = primitive("plane", "rotated_uv_plane", size=1.0, location=(0, 0, 0))
    set_material(plane, material("cloth", (0.5, 0.5, 0.5)))
    uv_layer = plane.data.uv_layers.active
    for loop in uv_layer.data:
        u, v = loop.uv
        loop.uv = (1.0 - v, u)  # rotated 90 degrees counter-clockwise about the square's centre
    export_glb(plane, os.path.join(out_dir, "rotated_uv_plane.glb"))

    reset_scene()
    cube = primitive("cube", "two_materials", size=2.0, location=(0, 0, 0))
    cube.data.materials.append(material("a", (0.8, 0.2, 0.2)))
    cube.data.materials.append(material("b", (0.2, 0.2, 0.8)))
    for poly in cube.data.polygons:
        poly.material_index = 0 if poly.normal.z > 0.5 or poly.normal.x > 0.5 or poly.normal.y > 0.5 else 1
    export_obj(cube, os.path.join(out_dir, "two_materials.obj"))


# ---------------------------------------------------------------------------------------------------------------


def format_provenance(reports, argv):
    script_rel = "scripts/blender/make_product_meshes.py"
    lines = ["# Built-in product meshes: provenance", "",
             "Generated by Blender's cloth simulator from `" + script_rel + "`; do not edit by hand, rerun the "
             "script (and commit its new output with this file).", "",
             f"- Blender: {bpy.app.version_string} (Debian package, `blender -b --factory-startup`), build "
             f"{bpy.app.build_hash.decode()}; Python {sys.version.split()[0]}, numpy {numpy.__version__} (Debian's "
             "python3-numpy, which the glTF add-on needs)",
             f"- Script git blob hash (`git hash-object {script_rel}`): `{git_blob_hash(SCRIPT_PATH)}`",
             "- Command: `nice -n 10 blender -b --factory-startup --python-exit-code 1 -P " + script_rel + " -- "
             + " ".join(argv) + "`",
             f"- Date (UTC): {time.strftime('%Y-%m-%d %H:%M', time.gmtime())}",
             f"- Frame rate {FPS} fps, gravity 9.81 m/s^2; each cloth simulated frame by frame to its last frame,"
             " its evaluated mesh taken there, then subdivided (Catmull-Clark) for smooth shading.",
             "- Format: glTF 2.0 binary, +Y up (Blender's +Z), metres, float32 positions, normals and UVs "
             "(TEXCOORD_0), one primitive per material, no tangents, colours, animation or textures.", "",
             "UV scale: the cloth's UVs are its rest (flat pattern) coordinates in metres, so one UV unit spans one "
             "metre of cloth on every mesh here, and v runs along the warp (the exporter writes glTF's 1 - v: the "
             "scale is unchanged). Parts that are not cloth (stand, rod) carry Blender's primitive UVs, not to "
             "scale.", "",
             "The server embeds drape_stand, folded_stack and hanging_drape (CMakeLists.txt, cmake/EmbedFiles.cmake; "
             "server/render/scenes/builtin_meshes.h); garment_bench is the speed benchmark's garment, read from "
             "this folder. Colliders and the body proxy only shaped the cloth and are not in the files unless "
             "listed as a material. The stand's and the rod's parts are separate solids that overlap where they "
             "join (the pole in the ball, the finials on the rod): their intersections below are by construction; "
             "the cloth's are the ones that matter.", ""]
    for name, report in reports.items():
        summary = report["summary"]
        sim = report["simulation"]
        lines += [f"## {name}.glb", "", report["doc"], "",
                  f"- {summary['triangles']} triangles, {summary['vertices']} vertices, {summary['bytes']} bytes",
                  "- Materials: " + ", ".join(f"`{m}` ({e['triangles']} triangles)"
                                              for m, e in summary["materials"].items()),
                  "- Attributes: " + ", ".join(sorted({a for e in summary["materials"].values()
                                                       for a in e["attributes"]})),
                  f"- UVs: {report['uv']}",
                  f"- Cloth: {sim['grid']}; {sim['frames']} frames ({sim['seconds']} s here)",
                  f"- Colliders: {sim['colliders']}",
                  "- Cloth settings (Blender ClothSettings / collision_*: ClothCollisionSettings): "
                  + ", ".join(f"{k} {v}" for k, v in sim["settings"].items()),
                  f"- Check: final/rest edge length ratio {report['edge_ratio'][0]:.3f} to "
                  f"{report['edge_ratio'][1]:.3f}"]
        intersections = ", ".join(f"{count} {pair}" for pair, count in report["intersections"].items())
        lines.append("- Check: intersecting face pairs (sharing no vertex, before triangulation): "
                     + (intersections or "none"))
        if "min_clearance_m" in report:
            lines.append(f"- Check: nearest fabric vertex {report['min_clearance_m'] * 1000:.1f} mm outside the "
                         "ball's surface (before subdivision)")
        if "min_z_m" in report:
            lines.append(f"- Check: lowest fabric vertex {report['min_z_m'] * 1000:.1f} mm above the table "
                         "(before subdivision)")
        lines.append("")
    return "\n".join(lines)


def main():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    if len(argv) < 2 or argv[0] not in ("products", "fixtures"):
        raise SystemExit("usage: ... -- products|fixtures OUT_DIR [--only NAME ...] [--preview DIR]")
    mode, out_dir = argv[0], argv[1]
    os.makedirs(out_dir, exist_ok=True)
    if mode == "fixtures":
        fixtures(out_dir)
        return
    only = [argv[k + 1] for k in range(len(argv) - 1) if argv[k] == "--only"]
    preview_dir = next((argv[k + 1] for k in range(len(argv) - 1) if argv[k] == "--preview"), None)
    reports = {}
    for name, make in PRODUCTS.items():
        if only and name not in only:
            continue
        reset_scene()
        report = {"doc": " ".join(make.__doc__.split())}
        obj = make(report)
        report["intersections"] = intersecting_faces(obj)
        path = os.path.join(out_dir, name + ".glb")
        export_glb(obj, path)
        report["summary"] = glb_summary(path)
        print(name, json.dumps(report["summary"]), "edge ratio", report["edge_ratio"],
              report["simulation"]["seconds"], "s", flush=True)
        reports[name] = report
        if preview_dir:
            os.makedirs(preview_dir, exist_ok=True)
            preview(path, os.path.join(preview_dir, name + ".png"))
    if not only:
        with open(os.path.join(out_dir, "PROVENANCE.md"), "w") as f:
            f.write(format_provenance(reports, argv))


main()
