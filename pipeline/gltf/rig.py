"""A glTF asset held open to be posed many times: the frames of an animated preview.

The document is opened, its primitives and materials read and the scene baked once, at
rest (`Rig.template`: edges, support points, interior vectors, texture references). A pose
then costs only what moves: the node graph's world matrices at that time, each instance's
matrix from its node's, and, for the meshes that deform (skinned primitives, and morph
targets whose weights the animation drives), positions, normals and tangents from the
primitive's own attributes (read once) through pipeline.gltf.skin. Every other array of a
posed BakedAsset is the template's own object, which renderer.raster.gpu uses to rewrite only
the moved vertex buffers and the instance matrices of one upload (BakedAsset.gpu_key).

KHR_animation_pointer: the materials it drives are read again per pose from the document
with the pointers' values written in (factors, texture transforms), as are lights and
cameras (colour, intensity, yfov); node TRS through it are ordinary channels.

Glass: interior vectors are object-space (the vertex shader turns them with the model
matrix), so a rigidly moving glass part keeps the template's; a deforming one has them traced
again for its posed surface.

An asset this cannot pose (a deforming mesh whose vertices ingest had to split or thicken:
flat normals, points and lines) raises RigUnsupported; pipeline.animate then reads each
frame whole, as before.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import cast

import numpy as np

from core.animation import Animation, select
from core.baked import BakedAsset
from core.hull import hull_points, hull_support_points
from core.scene import Material, Scene
from pipeline.bake import POSED_OPTIONS, build_baked, framed_bounds, instance_groups
from pipeline.gltf.animation import write_pointers
from pipeline.gltf.materials import read_material
from pipeline.gltf.nodes import NodeGraph, camera, light
from pipeline.gltf.primitives import attribute
from pipeline.gltf.reader import Assembly, open_document
from pipeline.gltf.skin import morph
from pipeline.gltf.skin import skin as skin_vertices
from pipeline.ingest import finish, flat_normals
from pipeline.limits import Limits
from pipeline.normals import compute_tangents


class RigUnsupported(Exception):
    """The asset cannot be posed by a Rig (the reason says why); read each frame whole."""


@dataclasses.dataclass
class _Deformer:
    """One deforming primitive: its own attributes (bind space), morph deltas, skin sets."""
    node: int
    skin: int | None
    positions: np.ndarray
    normals: np.ndarray | None
    tangents: np.ndarray | None
    deltas: dict[str, list[np.ndarray | None]]
    rest_weights: tuple
    joints: list[np.ndarray]
    weights: list[np.ndarray]
    tangent_uv: np.ndarray | None = None  # tangents computed per pose from these UVs (none authored)
    corners: np.ndarray | None = None  # no normals: vertex k of the mesh is corners[k] (flat split)


class Rig:
    """`path`'s animation `animation` (name, index or None: the first), ready to pose."""

    def __init__(self, path, base: BakedAsset, animation: str | None = None, root=None,
                 limits: Limits | None = None):
        limits = limits or Limits.from_env()
        self.base = base
        d = self.d = open_document(Path(path), limits, None if root is None else Path(root))
        # which animation, before reading the scene: nodes whose weights it drives get
        # meshes of their own
        from pipeline.gltf.animation import read_animations
        probe = read_animations(d)
        self.animation: Animation = select(probe, animation, str(d.path))
        d.warnings.clear()  # the assembly reads them again, with its own warnings
        animated_weights = frozenset(c.node for c in self.animation.channels if c.path == "weights")
        asm = Assembly(d, own_weights=animated_weights)
        scene = asm.scene(None)
        deformers: dict[int, _Deformer] = {}  # by id(Mesh): ingest may drop and reorder meshes
        for mesh in scene.meshes:
            recipe = asm.recipes.get(id(mesh))
            deformer = None if recipe is None else self._deformer(recipe, animated_weights)
            if deformer is None:
                continue
            if mesh.normals is None:  # flat normals, split here so that the split is known
                if mesh.indices.shape[1] != 3:
                    raise RigUnsupported(f"mesh {mesh.name!r} is points or lines")
                deformer.corners = mesh.indices.reshape(-1).copy()
                flat_normals(mesh)
            deformers[id(mesh)] = deformer
        finish(scene, limits)
        self.nodes: NodeGraph = asm.nodes
        self.scene: Scene = scene
        self.groups = instance_groups(scene)
        options = (base.manifest or {}).get("options", {})
        self.epsilon = options.get("interior_epsilon")
        # one upload per asset and animation, its buffers rewritten by every frame of any
        # request for them (renderer.raster.gpu)
        self.template = build_baked(scene, f"{base.key}#rig={self.animation.name}",
                                    {**options, **POSED_OPTIONS})
        self.template.textures = base.textures  # one reader: the texture indices are the same
        self.deformers: dict[int, _Deformer] = {}
        for mi, mesh in enumerate(scene.meshes):
            if id(mesh) in deformers:
                df = self.deformers[mi] = deformers[id(mesh)]
                if df.tangents is None and mesh.tangents is not None:  # ingest computed them
                    df.tangent_uv = _tangent_uv(scene, mesh)
            elif asm.recipes.get(id(mesh)) is None and any(
                    inst.mesh == mi and inst.placement is not None and inst.placement[1]
                    for inst in scene.instances):
                raise RigUnsupported(f"mesh {mesh.name!r} was rebuilt at ingest (points or lines)")
        self.has_lights = bool(scene.lights) or bool(scene.cameras)
        # KHR_animation_pointer on materials: each pose reads those materials again from the
        # document with the pointers' values written in (lights and cameras are read per pose)
        self.asm = asm
        animated = {int(c.pointer.split("/")[2]) for c in self.animation.channels
                    if c.pointer.startswith("/materials/")}
        self.animated_materials = {scene_index: index for index, scene_index in asm.materials.items()
                                   if index is not None and index in animated}

    def _deformer(self, recipe: tuple, animated_weights: frozenset[int]) -> _Deformer | None:
        d = self.d
        mesh_index, p, prim, skin, node = recipe
        what = f"mesh {mesh_index} primitive {p}"
        attrs = d.obj(prim.get("attributes"), f"{what} attributes")
        targets = d.array(prim, "targets")
        sets = [(attrs[f"JOINTS_{k}"], attrs[f"WEIGHTS_{k}"]) for k in range(8)
                if f"JOINTS_{k}" in attrs and f"WEIGHTS_{k}" in attrs]
        skinned = skin is not None and bool(sets)
        morphing = bool(targets) and node in animated_weights
        if not skinned and not morphing:
            return None
        if "KHR_draco_mesh_compression" in d.obj(prim.get("extensions"), f"{what} extensions"):
            raise RigUnsupported(f"{what} is Draco-compressed (decoded per read)")
        positions = d.accessor(attrs["POSITION"], d.limits.max_vertices, f"{what} POSITION")
        n = len(positions)
        normals = attribute(d, what, attrs, "NORMAL", (3,), n)
        tangents = attribute(d, what, attrs, "TANGENT", (4,), n)
        deltas: dict[str, list[np.ndarray | None]] = {k: [] for k in ("POSITION", "NORMAL", "TANGENT")}
        for t, target in enumerate(targets):
            target = d.obj(target, f"{what} target {t}")
            for k, arr in deltas.items():
                arr.append(attribute(d, what, target, k, (3,), n))
        node_def = d.item("nodes", node, "node")
        mesh_def = d.item("meshes", mesh_index, "mesh")
        rest = node_def.get("weights", mesh_def.get("weights", ()))
        rest = d.numbers({"w": rest}, "w", (0.0,) * len(rest)) if rest else ()
        joints = [d.accessor(j, d.limits.max_vertices, f"{what} JOINTS") for j, _ in sets] if skinned else []
        weights = [cast(np.ndarray, attribute(d, what, attrs, f"WEIGHTS_{k}", (4,), n))
                   for k in range(len(sets))] if skinned else []
        return _Deformer(node, skin if skinned else None, positions.astype(np.float32), normals,
                         tangents, deltas, tuple(rest), joints, weights)

    def pose(self, t: float, key: str) -> BakedAsset:
        """The asset at `t` seconds of the animation, under `key`; arrays that do not move
        are the template's own."""
        pose = self.animation.pose(t)
        self.nodes.pose = pose
        materials = self._materials(t)
        placed = self.nodes.world_matrices()
        worlds = dict(placed)
        joint_cache: dict[int, np.ndarray] = {}
        moved: dict[int, tuple] = {}
        for mi, df in self.deformers.items():
            if df.skin is not None and df.skin not in joint_cache:
                joint_cache[df.skin] = self.nodes.joint_matrices(df.skin, worlds)
            moved[mi] = self._deform(df, mi, pose, joint_cache.get(df.skin) if df.skin is not None else None)
        matrices = []
        for inst in self.scene.instances:
            node, skinned, local = cast(tuple, inst.placement)
            matrices.append(local if skinned else worlds[node] @ local)
        meshes = []
        for tm, (mi, mat, _), members in zip(self.template.meshes, self.groups, self.groups.values()):
            transforms = np.stack([matrices[k] for k in members])
            if mat in materials:
                tm = dataclasses.replace(tm, material=materials[mat])
            if mi in moved:
                positions, normals, tangents = moved[mi]
                interior = None if tm.interior is None else _interior(
                    positions, normals, tm.indices, self.epsilon)
                mesh = dataclasses.replace(tm, positions=positions, normals=normals, tangents=tangents,
                                           transforms=transforms, support=hull_support_points(positions),
                                           interior=interior)
            else:
                mesh = dataclasses.replace(tm, transforms=transforms)
            meshes.append(mesh)
        bounds = framed_bounds(meshes, self.groups.values(), self.scene)
        lights, cameras = self._lights(placed) if self.has_lights else ([], [])
        hull = hull_points(meshes, qhull=True)
        return dataclasses.replace(
            self.template, key=key, meshes=meshes, bounds=bounds, lights=lights, cameras=cameras,
            hull=np.zeros((0, 3)) if hull is None else hull, gpu_key=self.template.key,
            manifest={**self.template.manifest,
                      "moment": {"animation": self.animation.name, "time": round(t, 6)}})

    def _materials(self, t: float) -> dict[int, Material]:
        """Scene material index -> the material at `t`, for those KHR_animation_pointer drives;
        the pointers' values are written into the document first (lights and cameras, read
        after this by _lights, see them too)."""
        pointers = self.animation.pointers(t)
        if not pointers:
            return {}
        d = self.d
        write_pointers(d, pointers)
        said = len(d.warnings)
        out = {mat: read_material(d, self.asm.textures, index)
               for mat, index in self.animated_materials.items()}
        del d.warnings[said:]  # the template's reading said them once
        return out

    def _deform(self, df: _Deformer, mi: int, pose: dict, joints: np.ndarray | None) -> tuple:
        weights = pose.get(df.node, {}).get("weights", df.rest_weights)
        p, n, tan = df.positions, df.normals, df.tangents
        if any(weights):
            p = morph(p, df.deltas["POSITION"], weights)
            n = None if n is None else morph(n, df.deltas["NORMAL"], weights)
            tan = None if tan is None else morph(tan, df.deltas["TANGENT"], weights)
        if joints is not None:
            p, n, tan = skin_vertices(joints, df.joints, df.weights, p, n, tan)
        template = self.scene.meshes[mi]
        if df.corners is not None:  # flat: each triangle its own vertices, normal its plane's
            p = p.take(df.corners, axis=0)
            tan = None if tan is None else tan.take(df.corners, axis=0)
            tri = p.reshape(-1, 3, 3).astype(np.float64)
            n = np.repeat(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), 3, axis=0)
        n = _unit(n) if n is not None else template.normals
        if df.tangent_uv is not None:
            tan = compute_tangents(p, n, df.tangent_uv, template.indices)
        elif tan is None:
            tan = template.tangents
        return p, n, tan

    def _lights(self, placed: list) -> tuple[list, list]:
        """Lights and cameras of the nodes at their posed world matrices (as the reader)."""
        d = self.d
        lights, cameras = [], []
        for index, world in placed:
            node = d.item("nodes", index, "node")
            ext = d.obj(node.get("extensions"), f"node {index} extensions")
            if "KHR_lights_punctual" in ext:
                spec = d.obj(ext["KHR_lights_punctual"], "KHR_lights_punctual")
                lights.append(light(d, spec.get("light"), world))
            if "camera" in node:
                cameras.append(camera(d, d.integer(node, "camera"), index, world))
        return lights, cameras


def _tangent_uv(scene: Scene, mesh) -> np.ndarray | None:
    """The UV set a mesh's normal map reads (as ingest chose it for its tangents)."""
    for inst in scene.instances:
        if scene.meshes[inst.mesh] is mesh:
            ref = scene.materials[inst.material].normal_texture
            if ref is not None:
                return mesh.uv0 if ref.uv_set == 0 else mesh.uv1
    return mesh.uv0


def _unit(v: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(v, axis=1, keepdims=True)
    return np.ascontiguousarray(v / np.where(length > 0, length, 1.0), np.float32)


def _interior(positions: np.ndarray, normals: np.ndarray, indices: np.ndarray,
              epsilon: float | None) -> np.ndarray:
    from pipeline.interior.vectors import interior_vectors  # numba: for glass only
    return interior_vectors(positions, normals, indices, epsilon=epsilon).vectors
