"""glTF 2.0 (.gltf, .glb) into a Scene: `load` opens the document (pipeline.gltf.accessors),
refuses extensions it requires that we do not read, and walks the default scene's nodes
(pipeline.gltf.nodes), reading each primitive (pipeline.gltf.primitives) and material
(pipeline.gltf.materials, pipeline.gltf.variants) once.

The JSON is read with the standard library and accessors sliced out of the buffers with
numpy; pygltflib's object model is slow to build for large files, so it is used to write glTF
(tests), not to read it.
"""
from __future__ import annotations

from pathlib import Path
from typing import cast

import numpy as np

from core.animation import Moment, seconds, select
from core.errors import UnsupportedFormat
from core.scene import Instance, Material, Scene
from pipeline import deadline
from pipeline.gltf.accessors import Document
from pipeline.gltf.animation import read_animations, write_pointers
from pipeline.gltf.materials import MATERIAL_EXTENSIONS, Textures, read_material
from pipeline.gltf.nodes import NodeGraph, camera, light
from pipeline.gltf.primitives import TRIANGLES, primitive, thicken
from pipeline.gltf.variants import variant_materials, variant_names
from pipeline.limits import Limits

SUPPORTED_EXTENSIONS = frozenset({
    "KHR_materials_transmission", "KHR_materials_ior", "KHR_materials_volume",
    "KHR_materials_emissive_strength", "KHR_texture_transform", "KHR_mesh_quantization",
    "KHR_materials_unlit", "KHR_lights_punctual", "EXT_texture_webp",
    "KHR_draco_mesh_compression", "EXT_meshopt_compression", "KHR_meshopt_compression",
    "KHR_texture_basisu", "EXT_mesh_gpu_instancing", "KHR_materials_variants",
}) | MATERIAL_EXTENSIONS
# Read, with a documented approximation (README, "glTF extensions").
PARTIAL_EXTENSIONS = frozenset({
    "KHR_materials_pbrSpecularGlossiness",  # converted to metallic-roughness at ingest
    "KHR_animation_pointer",  # node TRS / weights, material, light and camera numbers
})


def load(path: Path, limits: Limits, root: Path | None = None,
         moment: Moment | None = None) -> Scene:
    """Read a .gltf or .glb file (checked against `limits`) into a Scene; its URIs must lie
    inside `root` (default: its folder; `paths.sandbox_root`). With a `moment`, nodes, skins
    and morph weights are posed by that animation at that time (pipeline.gltf.animation)."""
    return Assembly(open_document(path, limits, root)).scene(moment)


def open_document(path: Path, limits: Limits, root: Path | None = None) -> Document:
    """The document, refused when it requires extensions we do not read."""
    d = Document(Path(path), limits, root)
    unknown = sorted(set(d.array(d.doc, "extensionsRequired")) - SUPPORTED_EXTENSIONS
                     - PARTIAL_EXTENSIONS)
    if unknown:
        raise UnsupportedFormat(d.path, f"requires glTF extension(s) we do not support: "
                                        f"{', '.join(map(str, unknown))}")
    return d


def extension_report(d: Document) -> dict[str, str]:
    """Each extension in extensionsUsed: supported, partial or ignored. An ignored one
    (not required: required ones were refused at open) is also a warning."""
    report = {}
    for name in map(str, d.array(d.doc, "extensionsUsed")):
        status = ("supported" if name in SUPPORTED_EXTENSIONS else
                  "partial" if name in PARTIAL_EXTENSIONS else "ignored")
        report[name] = status
        if status == "ignored":
            d.warnings.append(f"extension {name} is not supported: ignored (the file "
                              "renders without it)")
    return report


class Assembly:
    """One scene being built: each (mesh, primitive, skin, weights) and each material read
    once, however many nodes place them. `own_weights`: nodes whose morph weights get a
    mesh of their own even where another node's are equal (a rig animates them apart);
    `recipes`: per scene mesh (by id), what it was read from, for pipeline.gltf.rig."""

    def __init__(self, d: Document, own_weights: frozenset[int] = frozenset()):
        self.own_weights = own_weights
        self.recipes: dict[int, tuple] = {}  # id(Mesh) -> (mesh index, primitive, prim, skin, node)
        self.d, self.textures, self.nodes = d, Textures(d), NodeGraph(d)
        self.out = Scene(source=str(d.path), format="glb" if d.glb_bin is not None or
                         d.path.suffix.lower() == ".glb" else "gltf")
        self.prim_meshes: dict[tuple, int | None] = {}
        self.materials: dict[int | None, int] = {}  # glTF material (None: default) -> scene's
        self.wire: dict[int, int] = {}  # scene mesh -> primitive mode, for points and lines
        self.skins: dict[int, np.ndarray] = {}

    def scene(self, moment: Moment | None = None) -> Scene:
        d, scene = self.d, self.out
        animations = self.animations = read_animations(d)
        scene.animations = [a.summary() for a in animations]
        if moment is not None:  # the node graph composes the animated values (NodeGraph.local)
            anim = select(animations, moment.animation, str(d.path))
            t = seconds(moment, anim)
            self.nodes.pose = anim.pose(t)
            write_pointers(d, anim.pointers(t))  # materials, lights, cameras: read below
            scene.moment = {"animation": anim.name, "time": round(t, 6)}
        placed = self.nodes.world_matrices()
        worlds = dict(placed)
        for index, world in placed:
            node = d.item("nodes", index, "node")
            node_ext = d.obj(node.get("extensions"), f"node {index} extensions")
            if "KHR_lights_punctual" in node_ext:
                spec = d.obj(node_ext["KHR_lights_punctual"], "KHR_lights_punctual")
                scene.lights.append(light(d, spec.get("light"), world))
            if "camera" in node:
                scene.cameras.append(camera(d, d.integer(node, "camera"), index, world))
            if "mesh" in node:
                self._place_mesh(index, node, world, worlds)
        if self.wire:
            thicken(scene, self.wire)
        scene.variants = variant_names(d)
        scene.textures = self.textures.textures
        scene.warnings = d.warnings
        scene.files = d.files
        scene.extensions = extension_report(d)
        return scene

    def _place_mesh(self, index: int, node: dict, world: np.ndarray, worlds: dict) -> None:
        """Instances of node `index`'s mesh, one per primitive and placement."""
        d = self.d
        mesh_index = d.integer(node, "mesh")
        mesh_def = d.item("meshes", mesh_index, f"node {index} mesh")
        prims = d.array(mesh_def, "primitives")
        weights = node.get("weights", mesh_def.get("weights", ()))
        if "weights" in self.nodes.pose.get(index, {}):
            weights = [float(w) for w in self.nodes.pose[index]["weights"]]
        weights = d.numbers({"w": weights}, "w", (0.0,) * len(weights)) if weights else ()
        skin = node.get("skin")
        if skin is not None and skin not in self.skins:
            self.skins[skin] = self.nodes.joint_matrices(d.integer(node, "skin"), worlds)
        # A skinned mesh ignores its node's transform: the joints place it (glTF 2.0 spec).
        placements = self.nodes.instancing(node, index, np.eye(4) if skin is not None else world)
        local = placements if skin is not None else self.nodes.instancing(node, index, np.eye(4))
        for p, prim in enumerate(prims):
            deadline.check()
            prim = d.obj(prim, f"mesh {mesh_index} primitive {p}")
            key = (mesh_index, p, skin, weights, index if index in self.own_weights else None)
            if key not in self.prim_meshes:
                self.prim_meshes[key] = self._mesh(mesh_index, p, prim, weights, skin, index)
            if self.prim_meshes[key] is None:
                continue
            mat = prim.get("material")
            if mat not in self.materials:
                self.materials[mat] = len(self.out.materials)
                # no material: the spec's default material (every property at its default:
                # white, metallic 1, roughness 1), as the Sample Viewer and three.js draw it
                self.out.materials.append(Material(name="default") if mat is None
                                          else read_material(d, self.textures,
                                                             d.integer(prim, "material")))
            variants = variant_materials(d, prim, self._scene_material)
            for matrix, at in zip(placements, local):
                self.out.instances.append(Instance(cast(int, self.prim_meshes[key]),
                                                   self.materials[mat], matrix, variants=variants,
                                                   placement=(index, skin is not None, at)))

    def _mesh(self, mesh_index: int, p: int, prim: dict, weights, skin, node: int) -> int | None:
        """Scene index of a newly read primitive (None when it is skipped)."""
        mesh = primitive(self.d, mesh_index, p, prim, weights,
                         None if skin is None else self.skins[skin])
        if mesh is None:
            return None
        self.recipes[id(mesh)] = (mesh_index, p, prim, skin, node)
        if mesh.indices.shape[1] != 3:
            self.wire[len(self.out.meshes)] = int(prim.get("mode", TRIANGLES))
        self.out.meshes.append(mesh)
        return len(self.out.meshes) - 1

    def _scene_material(self, mat: int) -> int:
        """Scene index of glTF material `mat`, read when first met."""
        if mat not in self.materials:
            self.materials[mat] = len(self.out.materials)
            self.out.materials.append(read_material(self.d, self.textures, mat))
        return self.materials[mat]
