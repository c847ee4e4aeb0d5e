"""USD ingest (.usd .usda .usdc .usdz) with usd-core: a composed stage -> Scene.

Order of work, so that hostile input is refused before USD touches it:
1. `usd_layers.LayerGraph` opens the root layer and walks every sublayer, reference and
   payload with Sdf alone (all variants), refusing URIs, absolute paths, `..` and symlink
   escapes out of the asset's folder (or out of the `.usdz` package), and bounds the package.
2. The stage is composed from those already-open layers (payloads loaded, variants as
   authored) and checked to have used no other layer.
3. Prims are traversed with instance proxies (scene-graph instancing: a prototype's meshes
   are built once and placed per instance), skipping inactive, invisible, guide and proxy
   prims. Each UsdGeom.Mesh is triangulated (a vectorised fan per face, `leftHanded` flips
   winding, holes dropped); primvars (normals, every `st` a material reads, displayColor /
   displayOpacity) with constant / uniform / vertex / varying / faceVarying interpolation,
   indexed or not, are gathered per face-vertex and vertices are split only where a
   uniform or faceVarying value differs (numpy unique over the combined key). GeomSubsets
   bound to materials become one Mesh each. displayColor / displayOpacity become vertex
   colours where USD draws them: on prims with no UsdPreviewSurface, and where a material
   reads them through a primvar reader; never on top of a material's own diffuseColor.
4. `usd_materials` maps UsdPreviewSurface (see its docstring for opacity/ior -> transmission).

Conventions: USD `st` has v up (0 at the image bottom); the scene holds glTF UVs, v down,
so v' = 1 - v (texture transforms are converted to match). World matrices come from an
XformCache and are converted to the scene's +Y-up metres: upAxis Z is turned to Y by a -90
degree rotation about X, and metersPerUnit scales (USD's fallback is 0.01, centimetres,
when the stage does not author it). Time-varying values (xforms, points, normals, skeletal
animation, camera and light attributes) are read at the requested moment's time code
(pipeline.usd.time), else at the stage's start time code (or the earliest sample). Subdivision surfaces (catmullClark, loop) are read as their control cage
with smooth normals, marked for refinement at bake (`subdivision`) when the scheme is
authored. `model:drawMode` origin / bounds / cards stand-ins replace the subtrees they apply
to, as usdview draws them (`usd_drawmode`; draw_mode="full" draws the geometry). Implicit
shapes (Sphere, Cube, Cylinder, Cone, Capsule, Plane) are tessellated (`usd_shapes`).
Meshes bound to a UsdSkel skeleton are skinned (UsdSkel.Cache / SkinningQuery, linear blend
or dual quaternion as authored) and posed by the skeleton's animation at that time code, or
at its rest transforms without one, as usdview shows them: the animation's blend shape
weights first (UsdSkel.BlendShapeQuery, inbetweens included; normalOffsets of shapes without
inbetweens on vertex normals), then the joints; authored normals are skinned too
(UsdSkel.SkinNormals), so that they follow the pose. PointInstancers place their prototypes (one Mesh each, an Instance per unmasked point);
nested ones are skipped with a warning. BasisCurves become tubes and Points small
spheres of their widths (`usd_curves`; CURVE_BUDGET thins or refuses them, naming the prim);
NurbsCurves and HermiteCurves linear tubes through their points, a NurbsPatch the mesh of its
control hull (`usd_nurbs`), as Storm draws them. UsdLux distant / sphere /
rect / disk lights become KHR_lights_punctual lights (`_light`), a dome light's texture the
scene's environment; UsdGeomCameras are listed (`Scene.cameras`) for `render --camera PATH`.
"""
from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from pxr import Ar, Gf, Sdf, Tf, Usd, UsdGeom, UsdShade, UsdUtils, Vt

from core.animation import Moment
from core.errors import LimitExceeded, MalformedAsset, MissingFile, NotInAsset, UnsafeReference
from core.scene import Cage, Creases, Instance, Light, Mesh, Scene, SceneCamera
from pipeline import deadline
from pipeline.limits import Limits
from pipeline.normals import smooth_normals
from pipeline.usd import curves, drawmode, nurbs
from pipeline.usd.layers import LayerGraph
from pipeline.usd.materials import Binding, MaterialReader, authoring_layer
from pipeline.usd.shapes import SHAPES, tessellate
from pipeline.usd.time import time_code, time_range

if TYPE_CHECKING:
    from pxr import UsdSkel

log = logging.getLogger(__name__)
SPLIT_CACHE_CORNERS = 4096  # meshes up to this many face-vertices share their split by connectivity
CURVE_BUDGET = 2_000_000  # vertices of the tubes and spheres made for curves and points, per asset

Y_UP_FROM_Z_UP = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], np.float64)
PRUNED_TYPES = (UsdShade.Material, UsdShade.NodeGraph, UsdShade.Shader)
PURPOSES = (UsdGeom.Tokens.render, UsdGeom.Tokens.proxy, UsdGeom.Tokens.guide)
# The walk tests UsdSkel's and UsdLux's schemas by TfType (pxr knows them from plugInfo), so
# their Python modules are imported only where a stage has a skeleton or a light.
SKEL_ROOT, SKEL_ANIMATION, LIGHT_API = (Tf.Type.FindByName(n) for n in
                                        ("UsdSkelRoot", "UsdSkelAnimation", "UsdLuxLightAPI"))


def load(path: Path, limits: Limits, root: Path | None = None,
         moment: Moment | None = None, variant_sets: tuple[str, ...] = (),
         purposes: tuple[str, ...] = ("render",), draw_mode: str = "authored") -> Scene:
    """Read a USD file (any of its four forms) into a Scene; AssetError on bad input.
    Files it references must lie inside `root` (default: its folder; `paths.sandbox_root`).
    `variant_sets`: "[PRIM:]SET=NAME" selections (no PRIM: the default prim's set), applied
    in order, so a selection may name a set that an earlier one brought in. `purposes`: drawn
    besides default (usdview's render / proxy / guide toggles; render by default). `draw_mode`:
    "authored" draws model:drawMode stand-ins as usdview does, "full" the geometry instead."""
    path = Path(path)
    graph = LayerGraph(path, limits, root)
    try:
        return read_composed(graph, moment, variant_sets, purposes, draw_mode)[0]
    finally:
        graph.close()


def read_composed(graph: LayerGraph, moment: Moment | None = None, variant_sets: tuple[str, ...] = (),
                  purposes: tuple[str, ...] = ("render",), draw_mode: str = "authored"):
    """(scene, reader): `graph`'s stage composed (once: graph.stage) and read at `moment`;
    the graph stays open (pipeline.usd.rig reads the same stage again at other times)."""
    path = graph.path
    # pxr's own diagnostics (`Warning: in _ReportErrors at line ... of stage.cpp`) would go to
    # stderr, once per process and out of order; caught here they become the scene's warnings
    diagnostics = UsdUtils.CoalescingDiagnosticDelegate()
    try:
        if graph.stage is None:
            graph.stage = _compose(graph.open(), graph, variant_sets)
        stage = graph.stage
        scene = Scene(source=str(path), format=path.suffix.lower().lstrip("."))
        scene.variant_sets = list_variant_sets(stage)
        scene.warnings.extend(graph.warnings)
        scene.time_range = time_range(stage)
        reader = StageReader(stage, graph, scene, limits=graph.limits, moment=moment,
                              purposes=purposes, draw_mode=draw_mode)
        reader.read()
        scene.files = list(graph.files)
        scene.absent = list(graph.absent)
        _take_diagnostics(diagnostics, scene.warnings, (*graph.absent, *graph.unreadable))
        return scene, reader
    finally:
        del diagnostics  # unregisters the delegate


_PXR_CONTEXT = re.compile(r"\s*\((?:instantiating stage|in file|on stage) [^()]*(?:\([^()]*\)[^()]*)*\)\s*$")


def _take_diagnostics(delegate, warnings: list[str], reported: tuple[str, ...] = ()) -> None:
    """pxr's warnings and status messages as ours: each once, without the C++ source line or the
    stage's address, and not again when a composition error or the layer check (`reported`:
    the files it found absent or unreadable) already said it."""
    for diag in delegate.TakeUncoalescedDiagnostics():
        text = _PXR_CONTEXT.sub("", " ".join(str(diag.commentary).split()))
        if not text or any(f in text for f in reported):
            continue
        said = [w.partition(": ")[2].rstrip(".") for w in warnings if w.startswith("composition: ")]
        if any(s and s in text for s in said) or any(text in w for w in warnings):
            continue
        warnings.append(f"USD: {text}")


def _compose(root_layer: Sdf.Layer, graph: LayerGraph, variant_sets=()) -> Usd.Stage:
    try:
        stage = Usd.Stage.Open(root_layer, Usd.Stage.LoadAll)
    except Tf.ErrorException as exc:
        raise MalformedAsset(graph.path, f"USD stage does not compose: "
                                         f"{str(exc).strip().splitlines()[-1]}") from None
    if stage is None:
        raise MalformedAsset(graph.path, "USD stage does not compose")
    for text in variant_sets:
        _select_variant(stage, graph.path, text)
    for layer in stage.GetUsedLayers():
        if not layer.anonymous and layer.identifier not in graph.layers:
            raise UnsafeReference(graph.path, f"composition read layer {layer.identifier!r}, "
                                              "which the reference check did not see")
    for err in stage.GetCompositionErrors():
        text = f"composition: {str(err).strip().splitlines()[0]}"
        if text not in graph.warnings and not any(u in text for u in graph.unreadable):
            graph.warnings.append(text)
    return stage


def _select_variant(stage: Usd.Stage, path: Path, text: str) -> None:
    """Apply one "[PRIM:]SET=NAME" selection in the stage's session layer (every variant's
    arcs were checked by LayerGraph; _compose then checks the layers used, as without one)."""
    where, _, choice = text.rpartition("=")
    prim_text, _, set_name = where.rpartition(":")
    if not set_name or not choice:
        raise NotInAsset(path, f"variant selection {text!r} is not [PRIM:]SET=NAME")
    prim = stage.GetPrimAtPath(prim_text) if prim_text.startswith("/") else \
        stage.GetDefaultPrim() if not prim_text else None
    if not prim:
        raise NotInAsset(path, f"variant selection {text!r}: no prim "
                               f"{prim_text or '(the stage has no default prim)'}")
    sets = prim.GetVariantSets()
    if not sets.HasVariantSet(set_name):
        raise NotInAsset(path, f"{prim.GetPath()} has no variant set {set_name!r}; it has "
                               f"{', '.join(sets.GetNames()) or 'none'}")
    names = sets.GetVariantSet(set_name).GetVariantNames()
    if choice not in names:
        raise NotInAsset(path, f"{prim.GetPath()} variant set {set_name!r} has no variant "
                               f"{choice!r}; it has {', '.join(names)}")
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        sets.GetVariantSet(set_name).SetVariantSelection(choice)


def list_variant_sets(stage: Usd.Stage) -> list[dict]:
    """Every composed prim's variant sets: [{prim, set, variants, selection}] (for inspect)."""
    out = []
    for prim in stage.Traverse():
        sets = prim.GetVariantSets()
        for name in sets.GetNames():
            vset = sets.GetVariantSet(name)
            out.append({"prim": str(prim.GetPath()), "set": name,
                        "variants": list(vset.GetVariantNames()),
                        "selection": vset.GetVariantSelection()})
    return out


def stage_matrix(stage: Usd.Stage) -> np.ndarray:
    """Stage space -> scene space (+Y up, metres), for column vectors."""
    scale = np.diag([UsdGeom.GetStageMetersPerUnit(stage)] * 3 + [1.0])
    up = Y_UP_FROM_Z_UP if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z else np.eye(4)
    return up @ scale


@dataclass
class _Primvar:
    values: np.ndarray          # E x k
    interpolation: str
    indices: np.ndarray | None  # per element, into values


@dataclass
class _Topology:
    """A mesh triangulated and its vertices split once; subsets select triangles from it."""
    positions: np.ndarray
    tri: np.ndarray              # T x 3 vertex indices
    tri_face: np.ndarray         # T, face of each triangle
    normals: np.ndarray | None
    attrs: dict[str, np.ndarray] = field(default_factory=dict)
    subdivision: str | None = None  # catmullClark / loop / bilinear: refined at bake (pipeline/usd/subdivision.py)
    creases: Creases | None = None  # loop's, by position
    cage: Cage | None = None  # catmullClark / bilinear: the polygons, for every subset
    cage_order: np.ndarray | None = None  # per cage corner: its face-vertex
    corner_vertex: np.ndarray | None = None  # per face-vertex: its (split) vertex
    face_drawn: np.ndarray | None = None  # per USD face: not a hole
    corner_face: np.ndarray | None = None  # per face-vertex: its face
    interpolation: dict[str, str] = field(default_factory=dict)  # per attr: its primvar's


class StageReader:
    def __init__(self, stage: Usd.Stage, graph: LayerGraph, scene: Scene, limits: Limits,
                 moment: Moment | None = None, purposes: tuple[str, ...] = ("render",),
                 draw_mode: str = "authored"):
        self.stage, self.graph, self.scene, self.limits = stage, graph, scene, limits
        self.draw_mode = draw_mode
        self.drawn = (UsdGeom.Tokens.default_, *(p for p in PURPOSES if p in purposes))
        self.time = time_code(stage, moment)  # pipeline.usd.time
        if moment is not None:
            scene.moment = {"time_code": self.time.GetValue()}
        self.xforms = UsdGeom.XformCache(self.time)
        meters = UsdGeom.GetStageMetersPerUnit(stage)
        if not (math.isfinite(meters) and meters > 0):  # 0 collapses the scene, < 0 mirrors it
            raise MalformedAsset(graph.path, f"metersPerUnit = {meters} is not a positive number")
        self.to_scene = stage_matrix(stage)
        self.materials = MaterialReader(graph, scene, limits, self.time)
        self.standins = drawmode.StandIns(self)
        self._meshes: dict[tuple, int] = {}
        self._topology: dict[tuple, _Topology | None] = {}
        # the index work of a small mesh's triangulation and vertex split, by its connectivity:
        # a block world's thousands of cubes share one (pipeline.usd.stage._split)
        self._splits: dict[tuple, tuple] = {}
        self.triangles = 0
        self.vertices = 0
        self._swept_vertices = 0  # of curves and points (CURVE_BUDGET)
        self._nodes = 0
        self._skipped: dict[str, list[str]] = {}  # prim type -> the paths not drawn
        self._notes: set[str] = set()  # one line per stage: how a prim type is approximated
        self._skel: UsdSkel.Cache | None = None  # made at the first SkelRoot
        # (prim path, skinned) of the stage prim _gprim is placing (None: a PointInstancer's
        # prototype), kept on its Instances for pipeline.usd.rig to place them again
        self._placing: tuple | None = None
        self.light_prims: list[str] = []  # the lights and cameras read, in order (rig)
        if not stage.HasAuthoredMetadata(UsdGeom.Tokens.metersPerUnit):
            self._warn("metersPerUnit not authored: USD's fallback 0.01 (centimetres) used")

    def read(self) -> None:
        self._walk(self.stage.GetPseudoRoot(), None)
        self.standins.finish()
        for kind, paths in sorted(self._skipped.items()):
            more = f" and {len(paths) - 3} more" if len(paths) > 3 else ""
            self._warn(f"{kind} prims are not read; skipped: {', '.join(paths[:3])}{more}")
        for note in sorted(self._notes):
            self._warn(note)

    def _walk(self, root: Usd.Prim, placements: np.ndarray | None) -> None:
        """Read the gprims under `root`. `placements` (K x 4 x 4, row vectors, relative to
        `root`'s parent) places a PointInstancer prototype K times; None = the stage itself."""
        predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
        it = iter(Usd.PrimRange(root, predicate))
        purposes: dict[Sdf.Path, str] = {}  # computed purpose by path
        parent = root.GetParent()
        if parent and parent.IsA(UsdGeom.Imageable):  # a prototype's walk: its instancer's
            purposes[parent.GetPath()] = UsdGeom.Imageable(parent).ComputePurpose()
        for prim in it:
            self._nodes += 1
            if self._nodes > self.limits.max_nodes:
                raise LimitExceeded(self.graph.path, f"more than {self.limits.max_nodes} prims")
            if self._nodes % 256 == 0:
                deadline.check()
            if not prim.IsA(UsdGeom.Imageable):  # shading networks are not: tested only here
                if prim.IsA(SKEL_ANIMATION) and placements is None:
                    self._skel_animation(prim)
                if any(prim.IsA(t) for t in PRUNED_TYPES):
                    it.PruneChildren()
                continue
            img = UsdGeom.Imageable(prim)
            if img.GetVisibilityAttr().Get(self.time) == UsdGeom.Tokens.invisible:
                it.PruneChildren()
                continue
            # purpose as UsdGeom computes it: a prim's own authored value, else its parent's
            # (parents come first in the traversal); a render prim under a proxy Xform is
            # drawn with render purpose on, so a prim not drawn does not prune its children.
            # usdview's default draws default + render (an unknown token never)
            attr = img.GetPurposeAttr()
            purpose = attr.Get() if attr.HasAuthoredValue() else \
                purposes.get(prim.GetPath().GetParentPath(), UsdGeom.Tokens.default_)
            purposes[prim.GetPath()] = purpose
            if purpose not in self.drawn:
                if prim.IsA(UsdGeom.PointInstancer):
                    it.PruneChildren()  # its prototypes are not drawn in their own right
                continue
            if self.draw_mode == "authored" and (mode := drawmode.applies(prim)):
                it.PruneChildren()  # the stand-in is drawn in place of the subtree
                self.standins.add(prim, mode, self._matrices(prim, root, placements))
                continue
            if prim.IsA(SKEL_ROOT):
                self._skel_root(prim)
            if placements is None and prim.HasAPI(LIGHT_API) and not prim.IsA(UsdGeom.Gprim):
                self._light(prim)
                self.light_prims.append(str(prim.GetPath()))
                continue
            if placements is None and prim.IsA(UsdGeom.Camera):
                self._camera(prim)
                self.light_prims.append(str(prim.GetPath()))
                continue
            if prim.IsA(UsdGeom.Mesh) or str(prim.GetTypeName()) in SHAPES:
                skinned = self._skinned(prim) if placements is None and self._skel else None
                self._placing = None if placements is not None else \
                    (str(prim.GetPath()), skinned is not None)
                if skinned is not None:
                    self._gprim(prim, *skinned)
                else:
                    self._gprim(prim, self._matrices(prim, root, placements))
            elif prim.IsA(UsdGeom.Curves) or prim.IsA(UsdGeom.Points) or prim.IsA(UsdGeom.NurbsPatch):
                self._placing = None if placements is not None else (str(prim.GetPath()), False)
                self._gprim(prim, self._matrices(prim, root, placements))
            elif prim.IsA(UsdGeom.PointInstancer):
                it.PruneChildren()  # its prototypes are drawn only where it places them
                if placements is None:
                    self._point_instancer(UsdGeom.PointInstancer(prim))
                else:
                    self._skipped.setdefault("nested PointInstancer", []).append(str(prim.GetPath()))
            elif prim.IsA(UsdGeom.Gprim):
                self._skipped.setdefault(str(prim.GetTypeName()), []).append(str(prim.GetPath()))

    # -- UsdLux lights and UsdGeom cameras -----------------------------------------------------
    def _light(self, prim: Usd.Prim) -> None:
        """UsdLux -> KHR_lights_punctual (or the scene's environment for a dome light).

        Units, derived once: UsdLux's radiance is L = intensity x 2^exposure x colour (x the
        blackbody colour when enabled), divided by the light's size when `normalize` is on.
        Our directional light is an illuminance E (what a surface facing it receives) and our
        point / spot light a radiant intensity I (E = I / d^2).
        - DistantLight: a cap of half-angle t = angle/2 (0.53 degrees by default) seen with
          radiance L gives E = L x pi sin^2(t) (t <= 90 degrees; the hemisphere's pi beyond);
          normalized, L was divided by that same factor, so E = intensity. t = 0 is a delta
          light whose size factor is 1 (UsdLux's "Normalizing Distant Lights").
        - Sphere / rect / disk lights: a Lambertian emitter of area A (in m^2, world space: the
          xform's scale and metersPerUnit included) facing the point gives I = L x A_projected
          (pi r^2 for a sphere, w h for a rect, pi r^2 for a disk); normalized, I = intensity.
        - Cylinder lights: the side of a cylinder of radius r and length l along x, seen
          broadside: I = L x 2 r l (its projected area); normalized, I = intensity.
        Sphere and cylinder lights become point lights (spot with ShapingAPI's cone), rect
        and disk lights a one-sided 90 degree spot. Their extent is kept (Light.shape / size;
        a distant light's half-angle t): the ray tracer samples it, so its shadows have
        penumbrae, and the power above is unchanged (renderer/methods/trace_lights.py)."""
        from pxr import UsdLux
        api = UsdLux.LightAPI(prim)
        get = lambda a, d: _finite(a.Get(self.time), d)  # noqa: E731
        color = np.array(api.GetColorAttr().Get(self.time) or (1.0, 1.0, 1.0), np.float64)
        if api.GetEnableColorTemperatureAttr().Get(self.time):
            color = color * np.array(UsdLux.BlackbodyTemperatureAsRgb(
                get(api.GetColorTemperatureAttr(), 6500.0)))
        # the schema's fallback (1; 50,000 for a DistantLight) comes from Get()
        intensity = get(api.GetIntensityAttr(), 1.0) * 2.0 ** get(api.GetExposureAttr(), 0.0)
        normalize = bool(api.GetNormalizeAttr().Get(self.time))
        local = np.array(self.xforms.GetLocalToWorldTransform(prim)).T
        world = self.to_scene @ local
        axis_m = [float(np.linalg.norm(world[:3, i])) for i in range(3)]  # metres per light unit
        where = str(prim.GetPath())
        if prim.IsA(UsdLux.DomeLight):
            self._dome(prim, where, color * intensity)
            return
        self.scene.own_lighting = True
        if prim.IsA(UsdLux.DistantLight):
            half = math.radians(min(max(get(UsdLux.DistantLight(prim).GetAngleAttr(), 0.53),
                                        0.0), 360.0)) / 2
            kind = "directional"
            area = 1.0 if half <= 0 else math.pi * (math.sin(half) ** 2 if half <= math.pi / 2
                                                   else 1.0)
            shape, size = ("cone", (half, 0.0)) if half > 0 else ("", (0.0, 0.0))
        elif prim.IsA(UsdLux.SphereLight):
            light = UsdLux.SphereLight(prim)
            r = get(light.GetRadiusAttr(), 0.5) * float(np.mean(axis_m))
            kind = "point"
            point = bool(light.GetTreatAsPointAttr().Get(self.time))
            area = 1.0 if point else math.pi * r * r
            shape, size = ("", (0.0, 0.0)) if point or r <= 0 else ("sphere", (r, 0.0))
        elif prim.IsA(UsdLux.RectLight):
            light = UsdLux.RectLight(prim)
            kind = "rect"
            w = get(light.GetWidthAttr(), 1.0) * axis_m[0]
            h = get(light.GetHeightAttr(), 1.0) * axis_m[1]
            area, shape, size = w * h, "rect", (w, h)
        elif prim.IsA(UsdLux.DiskLight):
            kind = "rect"
            radius = get(UsdLux.DiskLight(prim).GetRadiusAttr(), 0.5)
            area = math.pi * radius ** 2 * axis_m[0] * axis_m[1]
            shape, size = "disk", (radius * axis_m[0], radius * axis_m[1])
        elif prim.IsA(UsdLux.CylinderLight):
            light = UsdLux.CylinderLight(prim)
            length = get(light.GetLengthAttr(), 1.0) * axis_m[0]
            r = get(light.GetRadiusAttr(), 0.5) * (axis_m[1] + axis_m[2]) / 2
            kind, area = "point", 2 * r * length
            if light.GetTreatAsLineAttr().Get(self.time):
                r = 0.0  # sampled along its axis only (its power still as wide as the radius)
            shape, size = "cylinder", (r, length)
        else:
            self._warn(f"{where}: {prim.GetTypeName()} lights are not drawn")
            return
        if normalize:
            area = 1.0
        r, g, b = (float(c) for c in np.clip(color, 0, None))
        out = Light(type="point", color=(r, g, b),
                    intensity=float(intensity * area), matrix=_orthonormal(world),
                    shape=shape, size=(float(size[0]), float(size[1])))
        if kind == "directional":
            out.type = "directional"
        elif kind == "rect":  # one-sided emitter along -Z: a hemisphere spot
            out.type, out.inner_cone, out.outer_cone = "spot", 0.0, math.pi / 2
        shaping = UsdLux.ShapingAPI(prim) if prim.HasAPI(UsdLux.ShapingAPI) else None
        cone = get(shaping.GetShapingConeAngleAttr(), 90.0) if shaping else 90.0
        if shaping and cone < 90.0:
            soft = min(max(get(shaping.GetShapingConeSoftnessAttr(), 0.0), 0.0), 1.0)
            out.type, out.outer_cone = "spot", math.radians(cone)
            out.inner_cone = out.outer_cone * (1.0 - soft)
        # ShadowAPI's inputs, read whether or not the API is applied (Hydra reads them by
        # name): shadow:enable falls back to true, shadow:color to black
        enable = prim.GetAttribute("inputs:shadow:enable")
        if enable and enable.HasAuthoredValue():
            out.shadow = bool(enable.Get(self.time))
        shade = prim.GetAttribute("inputs:shadow:color")
        if shade and shade.HasAuthoredValue() and shade.Get(self.time) is not None:
            out.shadow_color = tuple(float(c) for c in np.clip(shade.Get(self.time), 0, 1))  # type: ignore[assignment]
        self.scene.lights.append(out)

    def _dome(self, prim: Usd.Prim, where: str, radiance: np.ndarray) -> None:
        """A textured dome's panorama, times colour x intensity x 2^exposure (`dome_scale`,
        UsdLux), is the environment; an untextured one's radiance (that product from every
        direction) a uniform one."""
        from pxr import UsdLux
        attr = UsdLux.DomeLight(prim).GetTextureFileAttr()
        asset = attr.Get(self.time)
        if not asset or not asset.path:
            if self.scene.dome_radiance is None and self.scene.environment is None:
                self.scene.dome_radiance = tuple(float(c) for c in np.clip(radiance, 0, None))  # type: ignore[assignment]
                self.scene.own_lighting = True
            return
        try:
            identifier = self.graph.resolve(authoring_layer(attr, self.time), asset.path)
        except MissingFile as exc:
            self._warn(f"{where}: {exc.reason}; this dome gives no light")
            return
        if Ar.IsPackageRelativePath(identifier):
            self._warn(f"{where}: a dome texture inside a package is not read; this dome "
                       "gives no light")
            return
        if self.scene.environment is None:
            self.scene.environment = identifier
            # UsdLux: the dome's radiance is its texture x intensity x 2^exposure x colour
            self.scene.dome_scale = tuple(float(c) for c in np.clip(radiance, 0, None))  # type: ignore[assignment]
            self.graph.files.append(identifier)
            self.scene.own_lighting = True
        else:
            self._warn(f"{where}: a second dome light; the first one's texture is used")

    def _camera(self, prim: Usd.Prim) -> None:
        """A UsdGeomCamera as a SceneCamera (`render --camera PRIM_PATH`): vertical field of
        view (or, orthographic, half the vertical aperture as ymag), clipping range, in scene
        units; the output's aspect is used, as for glTF cameras."""
        cam = UsdGeom.Camera(prim).GetCamera(self.time)
        world = _orthonormal(self.to_scene @ np.array(self.xforms.GetLocalToWorldTransform(prim)).T)
        scale = UsdGeom.GetStageMetersPerUnit(self.stage)
        near, far = cam.clippingRange.min * scale, cam.clippingRange.max * scale
        out = SceneCamera(name=str(prim.GetPath()), matrix=world, znear=float(near),
                          zfar=float(far) if math.isfinite(far) else math.inf)
        if cam.projection == Gf.Camera.Orthographic:
            # apertures are in tenths of a scene unit for orthographic cameras (Gf.Camera)
            out.type = "orthographic"
            out.ymag = float(cam.verticalAperture * Gf.Camera.APERTURE_UNIT * scale / 2)
            out.xmag = float(cam.horizontalAperture * Gf.Camera.APERTURE_UNIT * scale / 2)
        else:
            out.yfov = math.radians(cam.GetFieldOfView(Gf.Camera.FOVVertical))
        self.scene.cameras.append(out)

    # -- UsdSkel: skinned meshes posed as usdview shows them --------------------------------
    def _skel_animation(self, prim: Usd.Prim) -> None:
        """What `inspect` lists of a SkelAnimation: its joints, blend shapes and the time
        codes its samples span (joint transforms and blend shape weights)."""
        from pxr import UsdSkel
        anim = UsdSkel.Animation(prim)
        codes: set[float] = set()
        for attr in (anim.GetTranslationsAttr(), anim.GetRotationsAttr(), anim.GetScalesAttr(),
                     anim.GetBlendShapeWeightsAttr()):
            codes.update(attr.GetTimeSamples())
        self.scene.skel_animations.append({
            "path": str(anim.GetPath()), "joints": len(anim.GetJointsAttr().Get() or []),
            "blend_shapes": [str(b) for b in anim.GetBlendShapesAttr().Get() or []],
            "samples": len(codes), "first": min(codes, default=None), "last": max(codes, default=None)})

    def _skel_root(self, prim: Usd.Prim) -> None:
        from pxr import UsdSkel
        if self._skel is None:
            self._skel = UsdSkel.Cache()
        self._skel.Populate(UsdSkel.Root(prim),
                            Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate))

    def _skinned(self, prim: Usd.Prim):
        """(world matrices, skinned points or None, the skin of its normals or None) of a mesh
        bound to a skeleton, posed by its animation at the read time (blend shapes, then the
        joints, as UsdSkel orders them), else at the skeleton's rest transforms; None when
        `prim` is not skinned. Skinned points are in the skeleton's space (the gprim's own
        transform does not apply, as UsdSkel specifies)."""
        assert self._skel is not None  # _walk calls this only once a SkelRoot was seen
        from pxr import UsdSkel
        query = self._skel.GetSkinningQuery(prim)
        skeleton = UsdSkel.BindingAPI(prim).GetInheritedSkeleton()
        if not query or not skeleton or not prim.IsA(UsdGeom.Mesh):
            return None
        skel_query = self._skel.GetSkelQuery(skeleton)
        xforms = skel_query.ComputeSkinningTransforms(self.time) if skel_query else None
        if not xforms:
            self._warn(f"{prim.GetPath()}: skeleton {skeleton.GetPath()} has no usable pose; "
                       "drawn unskinned")
            return None
        skel_world = np.array(self.xforms.GetLocalToWorldTransform(skeleton.GetPrim()))
        if query.IsRigidlyDeformed():
            rows = np.array(query.ComputeSkinnedTransform(xforms, self.time)) @ skel_world
            return self.to_scene @ rows.T[None], None, None
        points = UsdGeom.Mesh(prim).GetPointsAttr().Get(self.time)
        normal_deltas = None
        if points is not None:
            normal_deltas = self._blend_shapes(prim, query, skel_query, points)
        if points is None or not query.ComputeSkinnedPoints(xforms, points, self.time):
            self._warn(f"{prim.GetPath()}: skinning failed; drawn unskinned")
            return None
        return ((self.to_scene @ skel_world.T)[None], np.asarray(points, np.float32).reshape(-1, 3),
                self._normal_skin(query, xforms, normal_deltas))

    def _blend_shapes(self, prim: Usd.Prim, query, skel_query, points) -> np.ndarray | None:
        """Apply the animation's blend shape weights at the read time to `points` in place
        (UsdSkel.BlendShapeQuery: inbetweens included). Returns what the shapes'
        normalOffsets add to each point's normal (shapes without inbetweens; None: nothing),
        which the normal skin applies to vertex normals before the joints."""
        anim = skel_query.GetAnimQuery()
        if not query.HasBlendShapes() or not anim:
            return None
        weights = anim.ComputeBlendShapeWeights(self.time)
        mapper = query.GetBlendShapeMapper()
        if mapper and not mapper.IsNull() and not mapper.IsIdentity():
            weights = mapper.Remap(weights)
        if not weights:
            return None
        from pxr import UsdSkel
        binding = UsdSkel.BindingAPI(prim)
        shapes = UsdSkel.BlendShapeQuery(binding)
        sub_weights, shape_indices, sub_indices = shapes.ComputeSubShapeWeights(weights)
        if not shapes.ComputeDeformedPoints(sub_weights, shape_indices, sub_indices,
                                            shapes.ComputeBlendShapePointIndices(),
                                            shapes.ComputeSubShapePointOffsets(), points):
            self._warn(f"{prim.GetPath()}: blend shapes do not fit its points; not applied")
            return None
        deltas = None
        targets = binding.GetBlendShapeTargetsRel().GetTargets()
        for w, target in zip(weights, targets):
            shape = UsdSkel.BlendShape(self.stage.GetPrimAtPath(target))
            offsets = shape.GetNormalOffsetsAttr().Get() if shape and w != 0.0 else None
            if not offsets or shape.GetInbetweens():  # an inbetween's own normals: not read
                continue
            offsets = np.asarray(offsets, np.float64).reshape(-1, 3)
            which = np.asarray(shape.GetPointIndicesAttr().Get() or range(len(points)), np.int64)
            if len(which) != len(offsets) or (len(which) and not 0 <= which.min() <= which.max() < len(points)):
                self._warn(f"{target}: normalOffsets do not fit the points; not applied")
                continue
            deltas = np.zeros((len(points), 3)) if deltas is None else deltas
            np.add.at(deltas, which, float(w) * offsets)
        return deltas

    def _normal_skin(self, query, xforms, deltas: np.ndarray | None = None):
        """A function (normals E x 3, the point of each, whether they are per point) -> the
        normals skinned as the points were: per-point normals plus the blend shapes'
        `deltas`, then UsdSkel.SkinNormals with each joint's inverse-transpose 3 x 3, so that
        a bound mesh's authored normals follow its pose instead of staying in the bind pose."""
        from pxr import UsdSkel
        mapper = query.GetJointMapper()
        if mapper and not mapper.IsNull() and not mapper.IsIdentity():
            xforms = mapper.RemapTransforms(xforms)
        normal_xforms = Vt.Matrix3dArray([m.ExtractRotationMatrix().GetInverse().GetTranspose()
                                          for m in xforms])
        bind = query.GetGeomBindTransform(self.time).ExtractRotationMatrix().GetInverse().GetTranspose()
        indices, weights = query.ComputeJointInfluences(self.time)
        k = query.GetNumInfluencesPerComponent()
        indices = np.asarray(indices, np.int32).reshape(-1, k)
        weights = np.asarray(weights, np.float32).reshape(-1, k)
        method = query.GetSkinningMethod()

        def skin(normals: np.ndarray, point_of: np.ndarray, per_point: bool) -> np.ndarray | None:
            if len(point_of) and point_of.max() >= len(indices):
                return None
            normals = normals[:, :3]
            if deltas is not None and per_point and len(deltas) == len(normals):
                normals = normals + deltas  # UsdSkel: normalOffsets apply to vertex normals
            out = Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(normals, np.float32))
            ok = UsdSkel.SkinNormals(method, bind, normal_xforms,
                                     Vt.IntArray.FromNumpy(indices[point_of].reshape(-1)),
                                     Vt.FloatArray.FromNumpy(weights[point_of].reshape(-1)), k, out)
            return np.asarray(out, np.float32) if ok else None
        return skin

    def _matrices(self, prim: Usd.Prim, root: Usd.Prim, placements) -> np.ndarray:
        """World matrices (column vectors, scene space) of `prim`, once per placement."""
        if placements is None:
            rows = np.array(self.xforms.GetLocalToWorldTransform(prim))[None]
        else:
            rel = np.array(self.xforms.ComputeRelativeTransform(prim, root)[0]) \
                if prim != root else np.eye(4)
            rows = rel[None] @ placements
        return self.to_scene[None] @ np.transpose(rows, (0, 2, 1))

    def _point_instancer(self, pi: UsdGeom.PointInstancer) -> None:
        """Each prototype's gprims placed by the instancer's (unmasked) instance transforms."""
        protos = pi.GetPrototypesRel().GetForwardedTargets()
        indices = np.asarray(pi.GetProtoIndicesAttr().Get(self.time) or [], np.int64)
        if len(indices) > self.limits.max_nodes:
            raise LimitExceeded(self.graph.path, f"{pi.GetPath()}: {len(indices)} instances, "
                                                 f"over the limit of {self.limits.max_nodes}")
        if not len(indices) or not protos:
            return
        xforms = pi.ComputeInstanceTransformsAtTime(self.time, self.time,
                                                    UsdGeom.PointInstancer.IncludeProtoXform,
                                                    UsdGeom.PointInstancer.IgnoreMask)
        rows = np.array([np.array(m) for m in xforms]).reshape(-1, 4, 4)
        if len(rows) != len(indices):
            self._warn(f"{pi.GetPath()}: instance transforms do not match protoIndices; skipped")
            return
        mask = np.asarray(pi.ComputeMaskAtTime(self.time) or [True] * len(indices), bool)
        world = np.array(self.xforms.GetLocalToWorldTransform(pi.GetPrim()))
        for j, target in enumerate(protos):
            chosen = mask & (indices == j)
            proto = self.stage.GetPrimAtPath(target)
            if chosen.any() and proto:
                # prototype root's own transform is inside the instance transform already
                self._walk(proto, rows[chosen] @ world)

    # -- one mesh or implicit shape ----------------------------------------------------------
    def _gprim(self, prim: Usd.Prim, matrices: np.ndarray, points=None, skin=None) -> None:
        mesh = UsdGeom.Mesh(prim) if prim.IsA(UsdGeom.Mesh) else None
        source = prim.GetPrimInPrototype() if prim.IsInstanceProxy() else prim
        groups = self._groups(prim, mesh)
        swept = prim.IsA(UsdGeom.Curves) or prim.IsA(UsdGeom.Points)
        # a tube's open ends show its inside
        double_sided = bool(UsdGeom.Gprim(prim).GetDoubleSidedAttr().Get()) or \
            prim.IsA(UsdGeom.Curves)
        # authored here or on an ancestor: the schema declares displayColor on every gprim
        color_pv = UsdGeom.PrimvarsAPI(prim).FindPrimvarWithInheritance("displayColor")
        has_color = bool(color_pv) and color_pv.HasAuthoredValue()
        if has_color:  # displayOpacity under 1 anywhere: drawn blended, as Storm draws it
            opacity_pv = UsdGeom.PrimvarsAPI(prim).FindPrimvarWithInheritance("displayOpacity")
            values = opacity_pv.Get(self.time) if opacity_pv and opacity_pv.HasAuthoredValue() else None
            if values is not None and len(values) and float(np.min(values)) < 1.0:
                has_color = "translucent"
        # Storm draws points as screen-facing discs (hdSt points.glslfx: eye-space normal +Z)
        sprites = prim.IsA(UsdGeom.Points)
        bindings = [self.materials.bind(mat, double_sided, has_color, sprites) for _, mat, _ in groups]
        uv_sets = {n for b in bindings for n in b.uv_primvars if not n.startswith("=")}
        needed = sorted(uv_sets | {b.color_primvar for b in bindings if b.color_primvar})
        if not uv_sets:
            needed.append("st")  # no texture reads it, but keep the conventional UVs
        topo_key = (str(source.GetPath() if points is None else prim.GetPath()), tuple(needed))
        if topo_key not in self._topology:
            deadline.check()
            self._topology[topo_key] = self._triangulate(prim, mesh, needed, points, skin) if mesh \
                else self._swept(prim, needed) if swept else self._patch(prim, needed) \
                if prim.IsA(UsdGeom.NurbsPatch) else self._shape(prim, needed)
        topo = self._topology[topo_key]
        if topo is None:
            return
        for name in uv_sets - set(topo.attrs):
            self._warn(f"{prim.GetPath()}: its material reads primvar {name!r}, which the "
                       "prim does not have (or is invalid); textures there have no UVs")
        for (label, _, faces), binding in zip(groups, bindings):
            key = (topo_key, label, binding.uv_primvars, binding.color_primvar)
            if key not in self._meshes:
                built = self._emit(topo, faces, binding, f"{source.GetPath()}{label}")
                if built is None:
                    self._meshes[key] = -1
                    continue
                self.scene.meshes.append(built)
                self._meshes[key] = len(self.scene.meshes) - 1
            if self._meshes[key] >= 0:
                self.scene.instances.extend(Instance(self._meshes[key], binding.material, m,
                                                     placement=self._placing)
                                            for m in matrices)

    def _groups(self, prim: Usd.Prim, mesh: UsdGeom.Mesh | None):
        """[(label, material, faces or None)]: one per face subset of the materialBind family
        (the only family material bindings apply to, as Hydra draws them: subsets of other
        families would count their faces twice), then the faces no subset claims (faces None =
        all faces)."""
        own = self.materials.bound(prim)
        subsets = [] if mesh is None else [
            s for s in UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets()
            if s.GetElementTypeAttr().Get() == UsdGeom.Tokens.face]
        if mesh is not None:
            for s in UsdGeom.Subset.GetAllGeomSubsets(mesh):
                if s.GetFamilyNameAttr().Get() != UsdShade.Tokens.materialBind and \
                        UsdShade.MaterialBindingAPI(s.GetPrim()).GetDirectBindingRel().GetTargets():
                    self._warn(f"{s.GetPath()}: a material binding on a GeomSubset of family "
                               f"{s.GetFamilyNameAttr().Get()!r}, not materialBind; ignored, as "
                               "Hydra ignores it")
        if not subsets:
            return [("", own if own else None, None)]
        groups: list[tuple]  # (label, material, faces or ("rest", claimed faces))
        groups, claimed = [], []
        for subset in subsets:
            faces = np.asarray(subset.GetIndicesAttr().Get(self.time) or [], np.int64)
            mat = self.materials.bound(subset.GetPrim())
            groups.append((f":{subset.GetPrim().GetName()}", mat if mat else None, faces))
            claimed.append(faces)
        groups.append(("", own if own else None, ("rest", np.concatenate(claimed))))
        return groups

    # -- geometry --------------------------------------------------------------------------------
    def _triangulate(self, prim: Usd.Prim, mesh: UsdGeom.Mesh | nurbs.PatchHull, names: list[str],
                     skinned: np.ndarray | None = None, skin=None) -> _Topology | None:
        where = f"mesh {prim.GetPath()}"
        counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(self.time) or [], np.int64)
        fvi = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(self.time) or [], np.int64)
        points = skinned if skinned is not None else \
            np.asarray(mesh.GetPointsAttr().Get(self.time) or [], np.float32).reshape(-1, 3)
        if not len(counts) or not len(points):
            return None
        if counts.min() < 0:
            raise MalformedAsset(self.graph.path, f"{where}: negative faceVertexCounts")
        per_face = np.maximum(counts - 2, 0)
        n_tri = int(per_face.sum())
        if self.triangles + n_tri > self.limits.max_triangles:
            raise LimitExceeded(self.graph.path, f"{where}: faceVertexCounts make {n_tri} "
                                                 f"triangles, over the limit of "
                                                 f"{self.limits.max_triangles}")
        if self.vertices + len(points) > self.limits.max_vertices:
            raise LimitExceeded(self.graph.path, f"{where}: {len(points)} points, over the "
                                                 f"limit of {self.limits.max_vertices}")
        if int(counts.sum()) != len(fvi):
            raise MalformedAsset(self.graph.path, f"{where}: faceVertexCounts sum to "
                                                  f"{int(counts.sum())} but there are {len(fvi)} "
                                                  "faceVertexIndices")
        if len(fvi) and (fvi.min() < 0 or fvi.max() >= len(points)):
            raise MalformedAsset(self.graph.path, f"{where}: faceVertexIndices outside the "
                                                  f"{len(points)} points")
        left = mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded
        holes = np.asarray(mesh.GetHoleIndicesAttr().Get(self.time) or [], np.int64)

        primvars = {n: pv for n in names if (pv := self._primvar(prim, n, counts, fvi,
                                                                 len(points))) is not None}
        normals = self._normals(prim, mesh, counts, fvi, len(points))
        if normals is not None and skin is not None:
            normals = _skinned_normals(normals, skin, counts, fvi, len(points))
            if normals is None:
                self._warn(f"{where}: its normals could not be skinned; computed from the pose")
        if "displayColor" in primvars:
            opacity = self._primvar(prim, "displayOpacity", counts, fvi, len(points))
            if opacity is not None:
                primvars["displayOpacity"] = opacity

        everything = dict(primvars, **({"normals": normals} if normals else {}))
        varying = [pv for pv in everything.values() if pv.interpolation in ("uniform", "faceVarying")]
        key = None
        if len(fvi) <= SPLIT_CACHE_CORNERS:  # one key of the connectivity the split reads
            key = (counts.tobytes(), fvi.tobytes(), len(points), left, holes.tobytes(),
                   tuple((pv.interpolation, None if pv.indices is None else pv.indices.tobytes())
                         for pv in varying))
        split = self._splits.get(key) if key is not None else None
        if split is None:
            split = _split(counts, fvi, per_face, n_tri, left, holes, varying)
            if key is not None:
                for arr in split:
                    if arr is not None:
                        arr.flags.writeable = False  # shared by every mesh of this connectivity
                self._splits[key] = split
        corners, tri_face, face_of_corner, inverse, rep, tri = split
        if normals is None and mesh.GetSubdivisionSchemeAttr().Get() != UsdGeom.Tokens.none:
            normals = _Primvar(smooth_normals(points, fvi[corners]), "vertex", None)  # (not splitting)
        if rep is not None:
            point_of_vertex = fvi[rep]
            elem = lambda pv: _elements(pv, fvi, face_of_corner, rep)  # noqa: E731
        else:
            point_of_vertex = np.arange(len(points))
            elem = lambda pv: _point_elements(pv, len(points))  # noqa: E731
        # Only an authored scheme is refined: most exporters leave USD's fallback
        # (catmullClark) on hard-surface meshes, which usdview draws as cages by default.
        attr = mesh.GetSubdivisionSchemeAttr()
        scheme = str(attr.Get()) if attr.HasAuthoredValue() else "none"
        topo = _Topology(points[point_of_vertex], tri.astype(np.uint32), tri_face, None,
                         subdivision=scheme if scheme in ("catmullClark", "loop", "bilinear")
                         else None)
        if topo.subdivision == "loop":
            topo.creases = self._creases(prim, mesh, points, fvi)
        elif topo.subdivision:
            topo.cage, topo.cage_order = self._cage(prim, mesh, scheme, points, counts, fvi)
            topo.corner_vertex = inverse if rep is not None else fvi
            topo.corner_face = face_of_corner
            topo.face_drawn = np.ones(len(counts), bool)
            topo.face_drawn[holes[(holes >= 0) & (holes < len(counts))]] = False
        if normals is not None:
            topo.normals = normals.values[elem(normals)][:, :3].astype(np.float32)
        for name, pv in primvars.items():
            topo.attrs[name] = pv.values[elem(pv)].astype(np.float32)
            topo.interpolation[name] = pv.interpolation
        self.triangles += n_tri
        self.vertices += len(topo.positions)
        return topo

    def _cage(self, prim: Usd.Prim, mesh: UsdGeom.Mesh, scheme: str, points: np.ndarray,
              counts: np.ndarray, fvi: np.ndarray) -> tuple[Cage, np.ndarray]:
        """The polygon cage of a catmullClark / bilinear mesh, right-handed (a leftHanded
        face's corners reversed, its first kept), faces of fewer than 3 corners left out;
        and per cage corner, its face-vertex."""
        start = np.repeat(np.cumsum(counts) - counts, counts)
        size = np.repeat(counts, counts)
        order = np.arange(len(fvi))
        if mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded:
            order = start + (start - order) % size
        order = order[size >= 3]
        found = self._crease_indices(prim, mesh, len(points))
        edges, edge_s, c_idx, c_s = found if found is not None else (
            np.zeros((0, 2), np.int64), np.zeros(0), np.zeros(0, np.int64), np.zeros(0))

        def token(attr, allowed, fallback):
            value = str(attr.Get()) if attr.HasAuthoredValue() else fallback
            if value not in allowed:
                self._warn(f"{prim.GetPath()}: {attr.GetName()} = {value!r} is not one of "
                           f"{', '.join(allowed)}; {fallback} used")
                return fallback
            return value
        cage = Cage(scheme, counts[counts >= 3].astype(np.int64), fvi[order].astype(np.int64),
                    np.asarray(points, np.float64), edges, edge_s, c_idx, c_s,
                    interpolate_boundary=token(mesh.GetInterpolateBoundaryAttr(),
                                               ("none", "edgeOnly", "edgeAndCorner"),
                                               "edgeAndCorner"),
                    face_varying=token(mesh.GetFaceVaryingLinearInterpolationAttr(),
                                       ("none", "cornersOnly", "cornersPlus1", "cornersPlus2",
                                        "boundaries", "all"), "cornersPlus1"),
                    triangle_rule=token(mesh.GetTriangleSubdivisionRuleAttr(),
                                        ("catmullClark", "smooth"), "catmullClark"))
        return cage, order

    def _creases(self, prim: Usd.Prim, mesh: UsdGeom.Mesh, points: np.ndarray,
                 fvi: np.ndarray) -> Creases | None:
        """`_crease_indices` as end positions (Loop's refinement welds by position)."""
        found = self._crease_indices(prim, mesh, len(points))
        if found is None:
            return None
        edges, edge_s, c_idx, c_s = found
        return Creases(points[edges].astype(np.float32), edge_s.astype(np.float32),
                       points[c_idx].astype(np.float32), c_s.astype(np.float32))

    def _crease_indices(self, prim: Usd.Prim, mesh: UsdGeom.Mesh, n_points: int):
        """creaseIndices (chains of creaseLengths points; creaseSharpnesses one per chain or
        one per edge) and cornerIndices / cornerSharpnesses: (edges K x 2, sharpness K,
        corners C, sharpness C) by point index, those of sharpness > 0; None if none."""
        get = lambda a, kind: np.asarray(a.Get(self.time) or [], kind)  # noqa: E731
        idx, lengths = get(mesh.GetCreaseIndicesAttr(), np.int64), get(mesh.GetCreaseLengthsAttr(), np.int64)
        sharp = get(mesh.GetCreaseSharpnessesAttr(), np.float64)
        c_idx, c_sharp = get(mesh.GetCornerIndicesAttr(), np.int64), get(mesh.GetCornerSharpnessesAttr(), np.float64)
        if not len(idx) and not len(c_idx):
            return None
        where = f"{prim.GetPath()}"
        edges, edge_s = np.zeros((0, 2), np.int64), np.zeros(0)
        if len(idx):
            n_edges = int(np.maximum(lengths - 1, 0).sum())
            if lengths.min(initial=0) < 0 or int(lengths.sum()) != len(idx) or \
                    len(sharp) not in (len(lengths), n_edges) or idx.min() < 0 or idx.max() >= n_points:
                self._warn(f"{where}: creaseIndices / creaseLengths / creaseSharpnesses do not "
                           "agree; creases ignored")
            else:
                start = np.cumsum(lengths) - lengths
                chain = np.repeat(np.arange(len(lengths)), np.maximum(lengths - 1, 0))
                step = np.arange(n_edges) - np.repeat(np.cumsum(np.maximum(lengths - 1, 0))
                                                       - np.maximum(lengths - 1, 0),
                                                       np.maximum(lengths - 1, 0))
                first = start[chain] + step
                edges = np.stack([idx[first], idx[first + 1]], axis=1)
                edge_s = sharp[chain] if len(sharp) == len(lengths) and len(sharp) != n_edges \
                    else sharp
        if len(c_idx) and (len(c_sharp) != len(c_idx) or c_idx.min() < 0 or c_idx.max() >= n_points):
            self._warn(f"{where}: cornerIndices / cornerSharpnesses do not agree; corners ignored")
            c_idx, c_sharp = np.zeros(0, np.int64), np.zeros(0)
        keep, keep_c = edge_s > 0, c_sharp > 0
        if not keep.any() and not keep_c.any():
            return None
        return edges[keep], edge_s[keep], c_idx[keep_c], c_sharp[keep_c]

    def _shape(self, prim: Usd.Prim, names: list[str]) -> _Topology | None:
        """An implicit shape, tessellated; only constant primvars (colours) apply to it."""
        points, tri, normals = tessellate(prim, self.time)
        self.triangles += len(tri)
        self.vertices += len(points)
        topo = _Topology(points, tri.astype(np.uint32), np.arange(len(tri)), normals)
        for name in names + (["displayOpacity"] if "displayColor" in names else []):
            pv = self._primvar(prim, name, np.array([len(points)]), np.arange(len(points)),
                               len(points))
            if pv is not None:
                if pv.interpolation != "constant":
                    self._warn(f"{prim.GetPath()}: {pv.interpolation} primvar {name} on an "
                               "implicit shape: its first value is used")
                value = pv.values[0 if pv.indices is None else pv.indices[0]]
                topo.attrs[name] = np.repeat(value[None], len(points), axis=0)
        return topo

    def _patch(self, prim: Usd.Prim, names: list[str]) -> _Topology | None:
        """A NurbsPatch as Storm draws it: the mesh of its control hull (pipeline.usd.nurbs).
        Counts that do not match the points are skipped with a warning, a hull over the
        limits refused before its faces are made."""
        patch = UsdGeom.NurbsPatch(prim)
        where = f"NurbsPatch {prim.GetPath()}"
        nu = int(patch.GetUVertexCountAttr().Get(self.time) or 0)
        nv = int(patch.GetVVertexCountAttr().Get(self.time) or 0)
        points = patch.GetPointsAttr().Get(self.time)
        n = 0 if points is None else len(points)
        if nu < 2 or nv < 2 or nu * nv != n:
            self._warn(f"{where}: uVertexCount x vVertexCount = {nu} x {nv} does not match its "
                       f"{n} points (2 x 2 at least); skipped")
            return None
        n_tri = 2 * (nu - 1) * (nv - 1)
        if self.triangles + n_tri > self.limits.max_triangles:
            raise LimitExceeded(self.graph.path, f"{where}: a {nu} x {nv} hull makes {n_tri} "
                                                 f"triangles, over the limit of {self.limits.max_triangles}")
        if patch.GetTrimCurveCountsAttr().HasAuthoredValue():
            self._notes.add("NurbsPatch trim curves are not applied (Storm draws the patch whole)")
        self._notes.add("NurbsPatch prims are drawn as their control hulls, as Storm draws them")
        return self._triangulate(prim, nurbs.PatchHull(patch, nu, nv), names)

    def _swept(self, prim: Usd.Prim, names: list[str]) -> _Topology | None:
        """BasisCurves as tubes, Points as small spheres (pipeline.usd.curves), of their
        widths; primvars evaluated per USD's curve interpolation. Over the vertex budget
        (CURVE_BUDGET, and what the asset's limits leave) every k-th curve or point is drawn,
        with a warning naming the prim."""
        where = str(prim.GetPath())
        points = np.asarray(UsdGeom.PointBased(prim).GetPointsAttr().Get(self.time) or [],
                            np.float64).reshape(-1, 3)
        if not len(points):
            return None
        if not np.isfinite(points).all():
            self._warn(f"{where}: NaN or infinite points; skipped")
            return None
        n = len(points)
        is_curves = prim.IsA(UsdGeom.Curves)
        budget = min(CURVE_BUDGET - self._swept_vertices, self.limits.max_vertices - self.vertices)
        if is_curves:
            counts = np.asarray(UsdGeom.Curves(prim).GetCurveVertexCountsAttr().Get(self.time) or [],
                                np.int64)
            if prim.IsA(UsdGeom.BasisCurves):
                bc = UsdGeom.BasisCurves(prim)
                kind = str(bc.GetTypeAttr().Get() or "cubic")
                basis = str(bc.GetBasisAttr().Get() or "bezier")
                wrap = str(bc.GetWrapAttr().Get() or "nonperiodic")
            else:  # Storm's linear curves through the control points (or Hermite points)
                kind, basis, wrap = "linear", "bezier", "nonperiodic"
                self._notes.add(
                    f"{prim.GetTypeName()} prims are drawn as linear curves through their "
                    + ("control points (order and knots ignored)" if prim.IsA(UsdGeom.NurbsCurves)
                       else "points (tangents ignored)") + ", as Storm draws them")
            if basis not in curves.BASES and kind == "cubic":
                self._warn(f"{where}: basis {basis!r} is not one Storm draws; drawn linear")
                kind = "linear"
            if not len(counts) or counts.min() < 1 or counts.sum() != n:
                self._warn(f"{where}: curveVertexCounts (sum {int(counts.sum())}) do not match "
                           f"its {n} points; skipped")
                return None
            try:
                sizes, which = np.unique(counts, return_inverse=True)  # hair: one count
                n_vary = np.array([curves.varying_count(int(k), kind, basis, wrap)
                                   for k in sizes], np.int64)[which]
            except curves.CurveError as exc:
                self._warn(f"{where}: {exc}; skipped")
                return None
            open_end = 0 if wrap == "periodic" else 1
            segments = n_vary - open_end
            per_curve = (segments * 2 if kind == "linear" else
                         segments * curves.SAMPLES + open_end) * curves.SIDES
            elements = {"uniform": len(counts), "vertex": n, "varying": int(n_vary.sum())}
            elements["faceVarying"] = elements["varying"]
            total, count_word = int(per_curve.sum()), f"{len(counts)} curves"
        else:
            per_curve = np.full(n, curves.sphere_size(1)[0])
            elements = {k: n for k in ("uniform", "vertex", "varying", "faceVarying")}
            total, count_word = int(per_curve.sum()), f"{n} points"
        keep = np.ones(len(per_curve), bool)
        if total > budget:
            step = -(-total // max(budget, 1))
            keep = np.arange(len(per_curve)) % step == 0
            while int(per_curve[keep].sum()) > budget and keep.sum() > 1:
                step += 1
                keep = np.arange(len(per_curve)) % step == 0
            if budget <= 0 or int(per_curve[keep].sum()) > budget:
                self._warn(f"{where}: {count_word} would make {total} vertices, over the budget "
                           f"of {max(budget, 0)}; skipped")
                return None
            self._warn(f"{where}: {count_word} would make {total} vertices, over the budget of "
                       f"{budget}; every {_ordinal(step)} drawn")
        if is_curves:
            samples, lengths, closed = curves.sample_curves(counts, kind, basis, wrap, keep)
        else:
            chosen = np.flatnonzero(keep)
            zero = np.zeros((len(chosen), 7), np.float64)
            samples = curves.Samples(
                np.concatenate([chosen[:, None], zero.astype(np.int64)], axis=1),
                np.concatenate([np.ones((len(chosen), 1)), zero], axis=1),
                np.stack([chosen, chosen], axis=1), np.tile([1.0, 0.0], (len(chosen), 1)), chosen)

        def value(name: str, values, interpolation, indices) -> np.ndarray | None:
            arr = np.asarray(values, np.float64)
            arr = arr.reshape(len(arr), -1) if arr.ndim else arr.reshape(1, 1)
            if indices is not None and len(indices):
                idx = np.asarray(indices, np.int64)
                if idx.min() < 0 or idx.max() >= len(arr):
                    self._warn(f"{where}: primvar {name}: indices outside its values; ignored")
                    return None
                arr = arr[idx]
            if name == "widths" and len(arr) == 1:
                interpolation = "constant"  # one width, the schema's vertex default: Storm's reading
            expected = 1 if interpolation == "constant" else elements.get(str(interpolation))
            if expected is None or len(arr) < expected or not np.isfinite(arr).all():
                self._warn(f"{where}: primvar {name}: {len(arr)} values do not fit "
                           f"{interpolation!r} interpolation (or are not finite); ignored")
                return None
            return curves.evaluate(arr, str(interpolation), samples)

        geom = UsdGeom.Curves(prim) if is_curves else UsdGeom.Points(prim)
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("widths")  # primvars:widths wins
        if pv and pv.HasValue():
            widths = value("widths", pv.Get(self.time), pv.GetInterpolation(),
                           pv.GetIndices(self.time) if pv.IsIndexed() else None)
        else:
            raw = geom.GetWidthsAttr().Get(self.time)
            widths = None if raw is None or not len(raw) else \
                value("widths", raw, geom.GetWidthsInterpolation(), None)
        radii = np.full(len(samples.curve), curves.DEFAULT_WIDTH / 2) if widths is None \
            else np.maximum(widths[:, 0], 0.0) / 2
        centres = curves.evaluate(points, "vertex", samples)
        if is_curves:
            pos, nrm, tri, src = curves.tubes(centres, radii, lengths, closed)
        else:
            pos, nrm, tri, src = curves.spheres(centres, radii)
        pos = pos.astype(np.float32)
        corner = pos[tri]  # a corner's bridge between rings that share a vertex: zero area
        tri = tri[np.any(np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0]) != 0, axis=1)]
        if self.triangles + len(tri) > self.limits.max_triangles:
            raise LimitExceeded(self.graph.path, f"{where}: {len(tri)} triangles, over the "
                                                 f"limit of {self.limits.max_triangles}")
        self.triangles += len(tri)
        self.vertices += len(pos)
        self._swept_vertices += len(pos)
        topo = _Topology(pos.astype(np.float32), tri.astype(np.uint32),
                         np.zeros(len(tri), np.int64), nrm.astype(np.float32))
        for name in names + (["displayOpacity"] if "displayColor" in names else []):
            found = UsdGeom.PrimvarsAPI(prim).FindPrimvarWithInheritance(name)
            if not found or not found.HasValue():
                continue
            at = value(name, found.Get(self.time), found.GetInterpolation(),
                       found.GetIndices(self.time) if found.IsIndexed() else None)
            if at is not None:
                topo.attrs[name] = at[src].astype(np.float32)
        return topo

    def _primvar(self, prim, name, counts, fvi, n_points) -> _Primvar | None:
        pv = UsdGeom.PrimvarsAPI(prim).FindPrimvarWithInheritance(name)
        if not pv or not pv.HasValue():
            return None
        values = pv.Get(self.time)
        indices = pv.GetIndices(self.time) if pv.IsIndexed() else None
        return self._checked(prim, name, values, pv.GetInterpolation(), indices, counts, fvi,
                             n_points)

    def _normals(self, prim, mesh, counts, fvi, n_points) -> _Primvar | None:
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("normals")  # primvars:normals wins
        if pv and pv.HasValue():
            return self._checked(prim, "normals", pv.Get(self.time), pv.GetInterpolation(),
                                 pv.GetIndices(self.time) if pv.IsIndexed() else None,
                                 counts, fvi, n_points)
        values = mesh.GetNormalsAttr().Get(self.time)
        if values is None or not len(values):
            return None
        return self._checked(prim, "normals", values, mesh.GetNormalsInterpolation(), None,
                             counts, fvi, n_points)

    def _checked(self, prim, name, values, interpolation, indices, counts, fvi,
                 n_points) -> _Primvar | None:
        """A primvar whose element count fits its interpolation; None (with a warning) if not."""
        if values is None:
            return None
        arr = np.asarray(values, np.float32)
        arr = arr.reshape(len(arr), -1) if arr.ndim else arr.reshape(1, 1)
        expected = {"constant": 1, "uniform": len(counts), "vertex": n_points,
                    "varying": n_points, "faceVarying": len(fvi)}.get(str(interpolation))
        idx = None if indices is None or not len(indices) else np.asarray(indices, np.int64)
        count = len(idx) if idx is not None else len(arr)
        problem = None
        if expected is None:
            problem = f"interpolation {interpolation!r} is not one USD defines"
        elif count < expected:
            problem = f"{count} values for {expected} {interpolation} elements"
        elif idx is not None and len(idx) and (idx.min() < 0 or idx.max() >= len(arr)):
            problem = "indices outside its values"
        elif not np.isfinite(arr).all():
            problem = "NaN or infinite values"
        if problem:
            self._warn(f"{prim.GetPath()}: primvar {name}: {problem}; ignored")
            return None
        return _Primvar(arr, str(interpolation), idx)

    def _emit(self, topo: _Topology, faces, binding: Binding, name: str) -> Mesh | None:
        """The Mesh of the triangles whose faces are in `faces`, with only the vertices they
        use; UV sets and colours as `binding` asks."""
        tri = topo.tri
        if faces is not None:
            if isinstance(faces, tuple):  # ("rest", claimed faces)
                select = ~np.isin(topo.tri_face, faces[1])
            else:
                select = np.isin(topo.tri_face, faces)
            tri = tri[select]
        if not len(tri):
            return None
        # the vertices the triangles use, in order (np.unique's result, without its sort)
        mask = np.zeros(len(topo.positions), bool)
        mask[tri.reshape(-1)] = True
        used = np.flatnonzero(mask)
        local = (np.cumsum(mask) - 1)[tri.reshape(-1)]
        cage_corners = None
        if topo.cage is not None and topo.cage_order is not None and topo.corner_face is not None \
                and topo.corner_vertex is not None and topo.face_drawn is not None:
            own = topo.face_drawn.copy()
            if faces is not None:
                own &= ~np.isin(np.arange(len(own)), faces[1]) if isinstance(faces, tuple) \
                    else np.isin(np.arange(len(own)), faces)
            lut = np.full(len(topo.positions), -1, np.int64)
            lut[used] = np.arange(len(used))
            fv = topo.cage_order
            cage_corners = np.where(own[topo.corner_face[fv]], lut[topo.corner_vertex[fv]], -1)
        whole = len(used) == len(topo.positions)
        pick = (lambda a: a) if whole else (lambda a: a[used])  # noqa: E731
        uvs = [_constant_st(n, len(topo.positions)) if n.startswith("=") else topo.attrs.get(n)
               for n in binding.uv_primvars] or [topo.attrs.get("st")]
        uvs = [None if u is None else pick(_gltf_uv(u)) for u in uvs] + [None]
        colors = None
        if binding.color_primvar and binding.color_primvar in topo.attrs:
            rgb = topo.attrs[binding.color_primvar][:, :3]
            alpha = topo.attrs.get("displayOpacity") if binding.color_primvar == "displayColor" \
                else None
            alpha = np.ones((len(rgb), 1), np.float32) if alpha is None else alpha[:, :1]
            colors = pick(np.concatenate([np.broadcast_to(rgb, (len(rgb), 3)), alpha], axis=1))
        interpolation = None
        if cage_corners is not None:
            uv_names = [n for n in binding.uv_primvars] or ["st"]
            interpolation = {k: _cage_interpolation(topo, [n]) for k, n in zip(("uv0", "uv1"), uv_names)}
            if colors is not None:
                interpolation["colors"] = _cage_interpolation(
                    topo, [binding.color_primvar or "", "displayOpacity"])
        return Mesh(name=name, positions=pick(topo.positions),
                    normals=None if topo.normals is None else pick(topo.normals),  # type: ignore[arg-type]  # None: pipeline.ingest computes them
                    indices=local.reshape(-1, 3).astype(np.uint32),
                    uv0=uvs[0], uv1=uvs[1], colors=colors, subdivision=topo.subdivision,
                    creases=topo.creases, cage=topo.cage, cage_corners=cage_corners,
                    cage_interpolation=interpolation)

    def _warn(self, text: str) -> None:
        if text not in self.scene.warnings:
            self.scene.warnings.append(text)
            log.info("%s: %s", self.graph.path, text)  # said once, as the scene's warning


def _ordinal(k: int) -> str:
    return f"{k}{'th' if 10 <= k % 100 <= 20 else {1: 'st', 2: 'nd', 3: 'rd'}.get(k % 10, 'th')}"


def _finite(value, default: float) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return default
    return v if math.isfinite(v) else default


def _orthonormal(m: np.ndarray) -> np.ndarray:
    """`m` with its rotation part's columns normalised (lights and cameras: the scale a
    metersPerUnit or an Xform brings moves them, it does not stretch their frame)."""
    out = np.array(m, np.float64)
    for i in range(3):
        n = np.linalg.norm(out[:3, i])
        if n > 0:
            out[:3, i] /= n
    return out


def _skinned_normals(pv: _Primvar, skin, counts, fvi, n_points) -> _Primvar | None:
    """Normals posed by `skin` (stage._normal_skin): per point for vertex / varying ones,
    else per face-vertex (each by its point's influences), indices resolved first."""
    if pv.interpolation in ("vertex", "varying"):
        point_of = np.arange(n_points)
        values = pv.values[point_of if pv.indices is None else pv.indices[point_of]]
        interpolation = pv.interpolation
    else:
        corners = np.arange(len(fvi))
        values = pv.values[_elements(pv, fvi, np.repeat(np.arange(len(counts)), counts), corners)]
        point_of, interpolation = fvi, "faceVarying"
    posed = skin(values, point_of, interpolation != "faceVarying")
    return None if posed is None else _Primvar(posed, interpolation, None)


def _elements(pv: _Primvar, fvi, face_of_corner, corners) -> np.ndarray:
    """Index into pv.values for each face-vertex in `corners`."""
    if pv.interpolation == "constant":
        e = np.zeros(len(corners), np.int64)
    elif pv.interpolation == "uniform":
        e = face_of_corner[corners]
    elif pv.interpolation == "faceVarying":
        e = corners
    else:  # vertex, varying
        e = fvi[corners]
    return e if pv.indices is None else pv.indices[e]


def _point_elements(pv: _Primvar, n_points: int) -> np.ndarray:
    """Index into pv.values for each point (no uniform / faceVarying primvar in play)."""
    e = np.zeros(n_points, np.int64) if pv.interpolation == "constant" else np.arange(n_points)
    return e if pv.indices is None else pv.indices[e]


def _split(counts: np.ndarray, fvi: np.ndarray, per_face: np.ndarray, n_tri: int, left: bool,
           holes: np.ndarray, varying: list[_Primvar]) -> tuple:
    """The index work of a mesh's triangulation, from its connectivity alone: (corners
    (T x 3 face-vertices), tri_face, face_of_corner, inverse (per face-vertex its vertex) and
    rep (per vertex a face-vertex) where uniform / faceVarying primvars split the points, else
    None, None; and the triangles' vertices)."""
    # Fan per face, vectorised: triangle j of face f uses corners s_f, s_f+k, s_f+k+1.
    start = np.cumsum(counts) - counts
    tri_face = np.repeat(np.arange(len(counts)), per_face)
    k = np.arange(n_tri) - np.repeat(np.cumsum(per_face) - per_face, per_face) + 1
    a = start[tri_face]
    corners = np.stack([a, a + k, a + k + 1], axis=1)
    if left:
        corners = corners[:, [0, 2, 1]]
    if len(holes):
        keep = ~np.isin(tri_face, holes)
        corners, tri_face = corners[keep], tri_face[keep]
    # Per face-vertex element index of every primvar; split vertices on the varying ones.
    face_of_corner = np.repeat(np.arange(len(counts)), counts)
    columns = [fvi] + [_elements(pv, fvi, face_of_corner, np.arange(len(fvi))) for pv in varying]
    if len(columns) > 1:
        inverse, rep = _unique_rows(columns)
        return corners, tri_face, face_of_corner, inverse, rep, inverse[corners]
    return corners, tri_face, face_of_corner, None, None, fvi[corners]


def _unique_rows(columns: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(inverse, representative) of the distinct rows of the stacked int columns."""
    sizes = [int(c.max()) + 1 if len(c) else 1 for c in columns]
    if float(np.prod([float(s) for s in sizes])) < 2.0 ** 62:  # one int64 key: fast path
        key = np.zeros(len(columns[0]), np.int64)
        for col, size in zip(columns, sizes):
            key = key * size + col
        _, rep, inverse = np.unique(key, return_index=True, return_inverse=True)
    else:
        _, rep, inverse = np.unique(np.stack(columns, axis=1), axis=0, return_index=True,
                                    return_inverse=True)
    return inverse.reshape(-1), rep


def _cage_interpolation(topo: _Topology, names: list[str]) -> str:
    """How a subdivision surface refines an attribute made of the primvars `names`: the most
    discontinuous of theirs (a colour of vertex displayColor and faceVarying displayOpacity is
    face-varying); constant where none is authored (a generated or constant st)."""
    found = [topo.interpolation[n] for n in names if n in topo.interpolation]
    for kind in ("faceVarying", "uniform", "varying", "vertex"):
        if kind in found:
            return kind
    return "constant"


def _constant_st(name: str, n: int) -> np.ndarray:
    """The st of materials.constant_st's name, for each of n vertices."""
    s, t = (float(v) for v in name[1:].split(","))
    return np.tile(np.array([[s, t]], np.float32), (n, 1))


def _gltf_uv(st: np.ndarray) -> np.ndarray:
    """USD st (v up from the image bottom) -> glTF uv (v down from the image top)."""
    uv = np.array(st[:, :2], np.float32)
    uv[:, 1] = 1.0 - uv[:, 1]
    return uv
