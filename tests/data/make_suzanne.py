# Writes the Blender-exported test meshes of tests/render/gltf_blender_test.cpp with Blender 3.4
# (Debian's `blender` package), run in the background from the repository root:
#
#   blender -b --factory-startup -noaudio --python tests/data/make_suzanne.py -- \
#       ~/.cache/compose/samples/monkey.obj tests/data
#
# * suzanne_clay.glb: the sample Suzanne (monkey.obj, with its normals) imported by Blender's OBJ
#   importer, given a "Clay" material of base colour (0.8, 0.35, 0.2) (linear, as Blender stores
#   it), and exported by Blender's glTF exporter (Y up, normals, no texture coordinates).
# * suzanne_checker.glb and suzanne_checker.obj/.mtl/.png: Blender's own Suzanne with its
#   texture coordinates, smooth shaded, and a 32x32 checker texture as the base colour, exported
#   by both of Blender's exporters (the OBJ keeps its quads; the glTF exporter triangulates).
import os
import sys

import bpy

argv = sys.argv[sys.argv.index("--") + 1:]
monkey_obj, out_dir = argv[0], argv[1]
out_dir = os.path.abspath(out_dir)


def reset():
    bpy.ops.wm.read_factory_settings(use_empty=True)


def export_glb(name, texcoords):
    bpy.ops.export_scene.gltf(filepath=os.path.join(out_dir, name), export_format='GLB',
                              export_yup=True, export_normals=True, export_texcoords=texcoords,
                              export_materials='EXPORT', export_colors=False, export_cameras=False,
                              export_lights=False, export_animations=False)


# The sample Suzanne with a plain base colour.
reset()
bpy.ops.wm.obj_import(filepath=monkey_obj)
ob = bpy.context.selected_objects[0]
clay = bpy.data.materials.new("Clay")
clay.use_nodes = True
bsdf = clay.node_tree.nodes["Principled BSDF"]
bsdf.inputs["Base Color"].default_value = (0.8, 0.35, 0.2, 1.0)
bsdf.inputs["Metallic"].default_value = 0.0
ob.data.materials.clear()
ob.data.materials.append(clay)
export_glb("suzanne_clay.glb", texcoords=False)

# Blender's Suzanne, textured.
reset()
bpy.ops.mesh.primitive_monkey_add(size=2.0, calc_uvs=True)
ob = bpy.context.active_object
bpy.ops.object.shade_smooth()
size = 32
image = bpy.data.images.new("suzanne_checker", size, size)
pixels = []
for y in range(size):
    for x in range(size):
        odd = ((x // 8) + (y // 8)) % 2
        pixels += [0.9, 0.3, 0.1, 1.0] if odd else [0.1, 0.4, 0.8, 1.0]
image.pixels = pixels
image.filepath_raw = os.path.join(out_dir, "suzanne_checker.png")
image.file_format = 'PNG'
image.save()
checker = bpy.data.materials.new("Checker")
checker.use_nodes = True
tree = checker.node_tree
bsdf = tree.nodes["Principled BSDF"]
bsdf.inputs["Metallic"].default_value = 0.0
texture = tree.nodes.new("ShaderNodeTexImage")
texture.image = image
tree.links.new(texture.outputs["Color"], bsdf.inputs["Base Color"])
ob.data.materials.append(checker)
export_glb("suzanne_checker.glb", texcoords=True)
bpy.ops.wm.obj_export(filepath=os.path.join(out_dir, "suzanne_checker.obj"),
                      export_materials=True, export_normals=True, export_uv=True,
                      export_triangulated_mesh=False, path_mode='RELATIVE')
