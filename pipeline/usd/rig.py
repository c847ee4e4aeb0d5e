"""A USD stage held open to be posed many times: the frames of an animated preview.

The counterpart of pipeline.gltf.rig. The stage is composed once and read once, at the first
frame's time code, and baked (`UsdRig.template`). Which prims vary in time is asked of USD
itself: xformOps through UsdGeom.Xformable.TransformMightBeTimeVarying (the prim or an
ancestor), points and normals through Attribute.ValueMightBeTimeVarying, skinned meshes
(UsdSkel) always, cameras and lights always (a few attributes each). A pose then costs only
that: the world matrices of the moving rigid prims from an XformCache at the frame's time code,
the moving meshes (deforming points, skinned) read again alone by the stage reader at that
time, and the lights and cameras. Every other array of a posed BakedAsset is the template's
own object, so renderer.raster.gpu rewrites only the moved buffers of one upload.

A stage this cannot pose raises RigUnsupported (pipeline.animate then reads each frame
whole, as before): any other attribute varying in time (visibility, topology, materials,
primvars, PointInstancer arrays, a dome light), moving transforms on a stage with
PointInstancers or draw-mode stand-ins (their instances do not say which prim placed them),
a deforming mesh that is subdivided at bake, or a frame whose re-read mesh does not keep the
template's triangles.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import cast

import numpy as np
from pxr import Usd, UsdGeom, UsdLux, UsdSkel, UsdUtils

from core.animation import Moment
from core.baked import BakedAsset
from core.errors import AssetError
from core.hull import SUPPORT_BLOCK, hull_points, hull_support_points, support_points
from core.scene import Scene
from pipeline import deadline
from pipeline.bake import POSED_OPTIONS, build_baked, framed_bounds, instance_groups
from pipeline.ingest import finish
from pipeline.limits import Limits
from pipeline.usd.layers import LayerGraph
from pipeline.usd.stage import StageReader, read_composed

# attributes a Mesh may vary in time that a re-read of the mesh alone follows (extent,
# velocities and accelerations are not read)
DEFORMING = ("points", "normals", "primvars:normals")
UNREAD = ("extent", "velocities", "accelerations")


class RigUnsupported(Exception):
    """The stage cannot be posed by a UsdRig (the reason says why); read each frame whole."""


class UsdRig:
    """`path` (a USD stage; `base` its rest bake) composed once, ready to pose at seconds
    from its start (core.animation.Moment's time)."""

    def __init__(self, path, base: BakedAsset, first: float = 0.0, root=None,
                 limits: Limits | None = None):
        limits = limits or Limits.from_env()
        self.base = base
        opts = (base.manifest or {}).get("options", {})
        self.purposes = tuple(opts.get("purposes", ("render",)))
        self.draw_mode = opts.get("draw_mode", "authored")
        self.graph = LayerGraph(Path(path), limits, None if root is None else Path(root))
        self.limits = limits
        self.reads = 0  # meshes read again by poses (tests count them)
        try:
            with deadline.within(limits.ingest_seconds, str(path)):  # as load_scene's read
                scene, reader = read_composed(self.graph, Moment(first),
                                              tuple(opts.get("variant_sets", ())),
                                              self.purposes, self.draw_mode)
                finish(scene, limits)
        except Exception as exc:  # the whole read reports it as load_scene does
            self.close()
            raise RigUnsupported(f"the first frame does not read: {exc}") from None
        self.stage: Usd.Stage = reader.stage
        self.scene: Scene = scene
        self.light_prims = list(reader.light_prims)
        try:
            self._survey()
        except RigUnsupported:
            self.close()
            raise
        self.groups = instance_groups(scene)
        self.epsilon = opts.get("interior_epsilon")
        self.template = build_baked(scene, f"{base.key}#usdrig", {**opts, **POSED_OPTIONS})
        self.template.textures = base.textures
        self.options = opts

    def _survey(self) -> None:
        """Which prims a pose recomputes; RigUnsupported for what it cannot."""
        stage = self.stage
        deforming: set[str] = set()
        any_xform = False
        predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
        for prim in Usd.PrimRange(stage.GetPseudoRoot(), predicate):
            if prim.IsA(UsdGeom.Xformable) and UsdGeom.Xformable(prim).TransformMightBeTimeVarying():
                any_xform = True
            for attr in prim.GetAttributes():
                name = attr.GetName()
                if name.startswith("xformOp") or not attr.ValueMightBeTimeVarying():
                    continue
                if name in UNREAD:
                    continue
                if prim.IsA(UsdGeom.Mesh) and name in DEFORMING:
                    deforming.add(str(prim.GetPath()))
                elif prim.IsA(UsdGeom.Camera) or prim.IsA(UsdSkel.Animation) or prim.IsA(UsdSkel.Skeleton) \
                        or (prim.HasAPI(UsdLux.LightAPI) and not prim.IsA(UsdLux.DomeLight)):
                    continue  # read again per pose (cameras, lights) or by the skinned meshes
                else:
                    raise RigUnsupported(f"{prim.GetPath()}.{name} varies in time")
        instances = self.scene.instances
        if (any_xform or deforming) and any(inst.placement is None for inst in instances):
            raise RigUnsupported("transforms or points vary on a stage with PointInstancers or "
                                 "draw-mode stand-ins")
        # per instance: its prim path, and whether a pose re-reads it (deforming, skinned) or
        # only places it again (a moving transform); None: it stays
        self.moving: list[tuple[str, bool] | None] = []
        reread: dict[str, None] = {}  # ordered as read
        names = [m.name for m in self.scene.meshes]
        self.reread_meshes: set[int] = set()
        for inst in instances:
            if inst.placement is None:
                self.moving.append(None)
                continue
            path, skinned = inst.placement
            prim = stage.GetPrimAtPath(path)
            if skinned or path in deforming:
                mesh = self.scene.meshes[inst.mesh]
                if mesh.subdivision is not None:
                    raise RigUnsupported(f"{path} deforms and is subdivided at bake")
                material = self.scene.materials[inst.material]
                if any(self.scene.textures[r.texture].udim is not None
                       for r in material.texture_refs().values()):
                    raise RigUnsupported(f"{path} deforms and its vertices are split for UDIM "
                                         "tiles at bake")
                if names.count(mesh.name) != 1:
                    raise RigUnsupported(f"{path}: mesh name {mesh.name!r} is not unique")
                reread[path] = None
                self.reread_meshes.add(inst.mesh)
                self.moving.append((path, True))
            elif _moves(prim):
                self.moving.append((path, False))
            else:
                self.moving.append(None)
        self.reread = list(reread)

    def close(self) -> None:
        self.graph.close()

    def _reader(self, t: float) -> StageReader:
        scene = Scene(source=self.scene.source, format=self.scene.format)
        return StageReader(self.stage, self.graph, scene, self.limits, Moment(t), self.purposes,
                            self.draw_mode)

    def pose(self, t: float, key: str) -> BakedAsset:
        """The stage at `t` seconds from its start, under `key`; arrays that do not move are
        the template's own."""
        r = self._reader(t)
        matrices = [inst.matrix for inst in self.scene.instances]
        pseudo = self.stage.GetPseudoRoot()
        placed: dict[str, np.ndarray] = {}
        for k, moving in enumerate(self.moving):
            if moving is not None and not moving[1]:
                if moving[0] not in placed:
                    placed[moving[0]] = r._matrices(self.stage.GetPrimAtPath(moving[0]), pseudo, None)[0]
                matrices[k] = placed[moving[0]]
        moved = self._reread(r, matrices) if self.reread else {}
        lights, cameras = self._lights(r)
        meshes = []
        for tm, (mi, _, _), members in zip(self.template.meshes, self.groups, self.groups.values()):
            transforms = tm.transforms if not any(self.moving[k] for k in members) \
                else np.stack([matrices[k] for k in members])
            if mi in moved:
                mesh = moved[mi]
                interior = None if tm.interior is None else _interior(
                    mesh.positions, mesh.normals, tm.indices, self.epsilon)
                out = dataclasses.replace(tm, positions=mesh.positions, normals=mesh.normals,
                                          tangents=mesh.tangents if tm.tangents is not None else None,
                                          transforms=transforms, interior=interior,
                                          support=_support(mesh.positions))
            else:
                out = dataclasses.replace(tm, transforms=transforms)
            meshes.append(out)
        bounds = framed_bounds(meshes, self.groups.values(), self.scene)
        hull = hull_points(meshes)  # as the whole read's bake: scipy only for big meshes
        moment = Moment(t)
        manifest = {**self.template.manifest, "moment": {"time_code": r.time.GetValue()},
                    "options": {**self.options, "moment": dataclasses.asdict(moment)}}
        return dataclasses.replace(
            self.template, key=key, meshes=meshes, bounds=bounds, lights=lights, cameras=cameras,
            hull=np.zeros((0, 3)) if hull is None else hull, gpu_key=self.template.key,
            manifest=manifest)

    def _reread(self, r: StageReader, matrices: list) -> dict:
        """Template mesh index -> the mesh read again at `r`'s time (finished as ingest
        finishes it); the re-read prims' instance matrices written into `matrices`."""
        stage = self.stage
        # pxr's diagnostics were the rest read's to report, once
        diagnostics = UsdUtils.CoalescingDiagnosticDelegate()
        try:
            roots: set[str] = set()
            for prim in (stage.GetPrimAtPath(p) for p in self.reread):
                parent = prim
                while parent and not parent.IsA(UsdSkel.Root):
                    parent = parent.GetParent()
                if parent and str(parent.GetPath()) not in roots:  # as the walk met it
                    roots.add(str(parent.GetPath()))
                    r._skel_root(parent)
                skinned = r._skinned(prim) if r._skel else None
                r._placing = (str(prim.GetPath()), skinned is not None)
                if skinned is not None:
                    r._gprim(prim, *skinned)
                else:
                    r._gprim(prim, r._matrices(prim, stage.GetPseudoRoot(), None))
            scene = r.scene
            finish(scene, self.limits)
        except AssetError as exc:
            raise RigUnsupported(f"a frame's moving meshes do not read: {exc}") from None
        finally:
            diagnostics.TakeUncoalescedDiagnostics()
            del diagnostics
        self.reads += len(scene.meshes)
        by_name = {m.name: i for i, m in enumerate(self.scene.meshes) if i in self.reread_meshes}
        out = {}
        for mesh in scene.meshes:
            mi = by_name.get(mesh.name)
            template = self.scene.meshes[mi] if mi is not None else None
            if template is None or not np.array_equal(mesh.indices, template.indices):
                raise RigUnsupported(f"{mesh.name}: its triangles change between frames")
            out[mi] = mesh
        if set(out) != self.reread_meshes:
            raise RigUnsupported("a moving mesh is not there at every frame")
        # the re-read instances, per prim in the order read: the template's of that prim
        fresh: dict[str, list] = {}
        for inst in scene.instances:
            fresh.setdefault(cast(tuple, inst.placement)[0], []).append(inst.matrix)
        for k, moving in enumerate(self.moving):
            if moving is not None and moving[1]:
                if not fresh.get(moving[0]):
                    raise RigUnsupported(f"{moving[0]}: its instances change between frames")
                matrices[k] = fresh[moving[0]].pop(0)
        return out

    def _lights(self, r: StageReader) -> tuple[list, list]:
        if not self.light_prims:
            return [], []
        for path in self.light_prims:
            prim = self.stage.GetPrimAtPath(path)
            (r._camera if prim.IsA(UsdGeom.Camera) else r._light)(prim)
        return r.scene.lights, r.scene.cameras


def _moves(prim: Usd.Prim) -> bool:
    """Whether `prim`'s world transform may vary in time (its own xformOps or an ancestor's)."""
    while prim and not prim.IsPseudoRoot():
        if prim.IsA(UsdGeom.Xformable) and UsdGeom.Xformable(prim).TransformMightBeTimeVarying():
            return True
        if prim.IsA(UsdGeom.Xformable) and UsdGeom.Xformable(prim).GetResetXformStack():
            return False
        prim = prim.GetParent()
    return False


def _support(points: np.ndarray) -> np.ndarray:
    """The bake's support points; over the hull's vertices for a big mesh (qhull, whose scipy
    import a short preview of small meshes should not pay, beats N x 256 dot products there)."""
    return hull_support_points(points) if len(points) > SUPPORT_BLOCK else support_points(points)


def _interior(positions: np.ndarray, normals: np.ndarray, indices: np.ndarray,
              epsilon: float | None) -> np.ndarray:
    from pipeline.interior.vectors import interior_vectors  # numba: for glass only
    return interior_vectors(positions, normals, indices, epsilon=epsilon).vectors
