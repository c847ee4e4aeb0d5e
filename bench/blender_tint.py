"""Runs inside Blender (the bpy wheel's interpreter): `PYTHON bench/blender_tint.py -- IOR`.
Which transmission tint Cycles' Principled BSDF applies to a textured glass solid: a UV
sphere, transmission 1, roughness 0, whose base colour is A = (0.64, 0.16, 0.36) on the half
facing the camera (y < 0) and B = (0.16, 0.64, 0.36) on the far half, under a white sky,
seen through its middle by an orthographic camera. It prints the middle pixels next to the
two candidates: A (a tint on entry only) and sqrt(A B) (sqrt(base) at each crossing).
This file imports only bpy, numpy and the standard library: it is not part of the package's
import graph.
"""
import math
import sys


def main(ior: float) -> None:
    import bpy
    import numpy as np

    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.cycles.samples = 16
    sc.cycles.use_denoising = False
    sc.cycles.max_bounces = sc.cycles.transmission_bounces = 16
    sc.render.resolution_x = sc.render.resolution_y = 33
    sc.view_settings.view_transform = "Standard"
    world = bpy.data.worlds.new("white")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (1, 1, 1, 1)
    sc.world = world
    bpy.ops.mesh.primitive_uv_sphere_add(segments=64, ring_count=32, radius=1)
    ob = bpy.context.object
    bpy.ops.object.shade_smooth()
    mat = bpy.data.materials.new("glass")
    mat.use_nodes = True
    nt = mat.node_tree
    bsdf = nt.nodes["Principled BSDF"]
    bsdf.inputs["Transmission Weight"].default_value = 1.0
    bsdf.inputs["Roughness"].default_value = 0.0
    bsdf.inputs["IOR"].default_value = ior
    # base colour by half: object-space y > 0 (away from the camera) takes B
    geo = nt.nodes.new("ShaderNodeNewGeometry")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(geo.outputs["Position"], sep.inputs[0])
    far = nt.nodes.new("ShaderNodeMath")
    far.operation = "GREATER_THAN"
    far.inputs[1].default_value = 0.0
    nt.links.new(sep.outputs["Y"], far.inputs[0])
    mix = nt.nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    a, b = (0.64, 0.16, 0.36), (0.16, 0.64, 0.36)
    mix.inputs[6].default_value = (*a, 1)
    mix.inputs[7].default_value = (*b, 1)
    nt.links.new(far.outputs[0], mix.inputs[0])
    nt.links.new(mix.outputs[2], bsdf.inputs["Base Color"])
    ob.data.materials.append(mat)
    cam_data = bpy.data.cameras.new("camera")
    cam_data.type = "ORTHO"
    cam_data.ortho_scale = 0.2  # the middle 10% of the sphere: near-normal incidence
    cam = bpy.data.objects.new("camera", cam_data)
    sc.collection.objects.link(cam)
    cam.location = (0, -5, 0)
    cam.rotation_euler = (math.pi / 2, 0, 0)
    sc.camera = cam
    sc.render.image_settings.file_format = "OPEN_EXR"
    out = "/tmp/blender_tint.exr"
    sc.render.filepath = out
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(out)
    px = np.array(img.pixels[:]).reshape(33, 33, 4)
    print(f"IOR {ior}: middle {px[12:21, 12:21, :3].reshape(-1, 3).mean(0).round(4)}; "
          f"entry only A {a}; per crossing sqrt(A B) {np.sqrt(np.multiply(a, b)).round(4)}")


if __name__ == "__main__":
    main(float(sys.argv[-1]) if len(sys.argv) > 1 and sys.argv[-2] == "--" else 1.0)
