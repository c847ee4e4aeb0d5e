"""Runs inside Blender: either Debian's `blender -b --factory-startup --python-exit-code 3 -P
THIS -- JOB.json` or, with the bpy wheel (Blender as a Python module), `PYTHON THIS -- JOB.json`
in that wheel's interpreter (bench.fidelity picks). It imports one glTF with Blender's own importer and renders it with Cycles on the CPU under the
camera and panorama bench.fidelity computed, into a linear float RGBA OpenEXR (film
transparent: alpha is coverage, RGB premultiplied, as our `background=transparent` frame).

JOB: {"gltf", "panorama" (linear .hdr, already re-indexed into Blender's equirect convention),
"out", "size", "spp", "camera_matrix" (4 x 4 camera-to-world, Blender coordinates), "fov"
(vertical degrees), "clip": [near, far]}. With {"query": "extensions", "out"} it writes the
glTF extensions this Blender's importer handles (its own list) and renders nothing.
This file imports only bpy and the standard library: it is not part of the package's import
graph.
"""
import json
import math
import re
import sys


def _importer_extensions() -> list[str]:
    """What the importer reads: the extensions it accepts as required (its own list) and
    those it has a module for (blender/imp/gltf2_blender_KHR_*.py)."""
    import inspect
    import os

    import io_scene_gltf2
    from io_scene_gltf2.io.imp import gltf2_io_gltf
    source = inspect.getsource(gltf2_io_gltf.glTFImporter.__init__)
    names = set(re.findall(r"'(KHR_[A-Za-z_]+|EXT_[A-Za-z_]+)'", source))
    imp = os.path.join(os.path.dirname(io_scene_gltf2.__file__), "blender", "imp")
    for f in os.listdir(imp):
        # 3.x/4.x: gltf2_blender_KHR_*.py; 4.3+ (5.0): KHR_*.py
        m = re.match(r"(?:gltf2_blender_)?((?:KHR|EXT)_[A-Za-z_]+)\.py$", f)
        if m:
            names.add(m.group(1))
    return sorted(names)


def main(job: dict) -> None:
    import bpy
    from mathutils import Matrix

    if job.get("query") == "extensions":
        with open(job["out"], "w") as f:
            json.dump({"blender": bpy.app.version_string, "extensions": _importer_extensions()}, f)
        return
    bpy.ops.wm.read_factory_settings(use_empty=True)
    import numpy
    if not hasattr(numpy, "bool"):  # Debian's Blender 3.4 importer + numpy >= 1.24 (bookworm)
        numpy.bool = bool  # type: ignore[misc,assignment]
    # A still, like ours: the importer is kept from creating and applying animations, so
    # nodes, skins and morph weights keep the file's own values.
    try:  # the importer's modules lost their gltf2_blender_ prefix in Blender 4.3
        from io_scene_gltf2.blender.imp.animation import BlenderAnimation
    except ImportError:
        from io_scene_gltf2.blender.imp.gltf2_blender_animation import BlenderAnimation
    BlenderAnimation.anim = staticmethod(lambda gltf, anim_idx: None)  # type: ignore[method-assign]
    BlenderAnimation.restore_animation = staticmethod(lambda gltf, name: None)  # type: ignore[method-assign]
    bpy.ops.import_scene.gltf(filepath=job["gltf"])
    scene = bpy.context.scene
    # A primitive without a material takes glTF's default material (spec 3.9.6: white, metallic
    # 1, roughness 1, as the Sample Viewer and we draw it); Blender's importer leaves it empty,
    # which Cycles would shade with its own grey dielectric.
    default = None
    for me in bpy.data.meshes:
        empty = [i for i, m in enumerate(me.materials) if m is None] if len(me.materials) else None
        if empty == []:
            continue
        if default is None:
            default = bpy.data.materials.new("gltf_default")
            default.use_nodes = True
            bsdf = next(n for n in default.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
            bsdf.inputs["Base Color"].default_value = (1.0, 1.0, 1.0, 1.0)
            bsdf.inputs["Metallic"].default_value = 1.0
            bsdf.inputs["Roughness"].default_value = 1.0
        if empty is None:
            me.materials.append(default)
        else:
            for i in empty:
                me.materials[i] = default
    # Every reference viewer compensates multiple scattering: so do we, by default.
    for mat in bpy.data.materials:
        if mat.node_tree is None:
            continue
        for node in mat.node_tree.nodes:
            if node.type == "BSDF_PRINCIPLED":
                node.distribution = "MULTI_GGX"
    world = bpy.data.worlds.new("panorama")
    world.use_nodes = True
    nodes, links = world.node_tree.nodes, world.node_tree.links
    env = nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.load(job["panorama"])
    links.new(env.outputs["Color"], nodes["Background"].inputs["Color"])
    scene.world = world

    cam_data = bpy.data.cameras.new("camera")
    cam_data.sensor_fit = "VERTICAL"
    cam_data.angle_y = math.radians(job["fov"])
    cam_data.clip_start, cam_data.clip_end = job["clip"]
    cam = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(cam)
    cam.matrix_world = Matrix(job["camera_matrix"])
    scene.camera = cam

    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = int(job["spp"])
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.seed = 1
    scene.render.resolution_x = scene.render.resolution_y = int(job["size"])
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = True
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1
    scene.render.filter_size = 0.5  # close to our box-filtered MSAA
    # The EXR holds scene-linear radiance whatever the view transform; Standard (not Filmic or
    # AgX, the defaults of 3.x and 4.x+) keeps any display-referred use of the render plain.
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.image_settings.color_mode = "RGBA"
    scene.render.filepath = job["out"]
    bpy.ops.render.render(write_still=True)


if __name__ == "__main__":
    with open(sys.argv[sys.argv.index("--") + 1]) as f:
        main(json.load(f))
