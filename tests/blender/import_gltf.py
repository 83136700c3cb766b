# Imports one glTF or GLB file into an empty Blender scene with Blender's own importer and prints what it made, as
# one line "LOOMLIGHT_IMPORT {json}" among Blender's own output; tests/material_export_test.cpp reads it.
#     blender -b --factory-startup --python-exit-code 1 --python import_gltf.py -- FILE
# Per material: the Principled BSDF's base colour, metallic and roughness, and the Velvet BSDF the importer adds
# for KHR_materials_sheen (Blender 3.4: Color = sheenColorFactor, Sigma = sheenRoughnessFactor) with whether it
# reaches the material output. Per mesh: its polygons, vertices, material slots and KHR_materials_variants
# mapping (slot, material, variant indices); the scene's variants in order.
import json
import sys

import bpy
import numpy

# Debian's numpy 1.24 removed numpy.bool, which Blender 3.4's glTF add-on still uses (as
# scripts/blender/make_product_meshes.py says).
if not hasattr(numpy, 'bool'):
    numpy.bool = bool


def linked_to_output(node):
    """Whether node's shader reaches a Material Output through the links (the importer adds it through an Add
    Shader)."""
    seen = set()
    frontier = [node]
    while frontier:
        current = frontier.pop()
        if current.type == 'OUTPUT_MATERIAL':
            return True
        if current.name in seen:
            continue
        seen.add(current.name)
        for output in current.outputs:
            frontier.extend(link.to_node for link in output.links)
    return False


def describe_material(material):
    found = {'name': material.name}
    if not material.use_nodes:
        return found
    for node in material.node_tree.nodes:
        if node.type == 'BSDF_PRINCIPLED':
            found['base_color'] = list(node.inputs['Base Color'].default_value)[:3]
            found['metallic'] = node.inputs['Metallic'].default_value
            found['roughness'] = node.inputs['Roughness'].default_value
            found['principled_reaches_output'] = linked_to_output(node)
        elif node.type == 'BSDF_VELVET':
            found['velvet_color'] = list(node.inputs['Color'].default_value)[:3]
            found['velvet_sigma'] = node.inputs['Sigma'].default_value
            found['velvet_reaches_output'] = linked_to_output(node)
    return found


def describe_mesh(mesh):
    return {
        'name': mesh.name,
        'polygons': len(mesh.polygons),
        'vertices': len(mesh.vertices),
        'slots': [m.name if m else None for m in mesh.materials],
        'variant_mappings': [{
            'slot': data.material_slot_index,
            'material': data.material.name if data.material else None,
            'variants': [v.variant.variant_idx for v in data.variants],
        } for data in mesh.gltf2_variant_mesh_data],
    }


def main():
    path = sys.argv[sys.argv.index('--') + 1]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    result = bpy.ops.import_scene.gltf(filepath=path)
    if result != {'FINISHED'}:
        raise RuntimeError('the glTF importer returned %s' % result)
    scene = bpy.data.scenes[0]
    report = {
        'blender': bpy.app.version_string,
        'materials': [describe_material(m) for m in bpy.data.materials],
        'meshes': [describe_mesh(m) for m in bpy.data.meshes],
        'variants': [{'index': v.variant_idx, 'name': v.name} for v in scene.gltf2_KHR_materials_variants_variants],
    }
    print('LOOMLIGHT_IMPORT ' + json.dumps(report), flush=True)


main()
