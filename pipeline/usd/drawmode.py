"""`model:drawMode` stand-ins (UsdGeomModelAPI) as usdview / Hydra Storm draws them.

Which prims: a model prim whose draw mode, resolved up the model hierarchy
(`UsdGeomModelAPI.ComputeModelDrawMode`: an authored value other than `inherited` wins, else
the nearest model ancestor's, else `default`), is origin / bounds / cards, and that has
`model:applyDrawMode` true, or has kind component and no authored `model:applyDrawMode`
(the schema's rule, and what Storm does on the usd-wg Teapot DrawModes stage, which authors
no applyDrawMode). Its subtree is replaced by the stand-in, drawn in the prim's own space:

- origin: its basis vectors, one stage unit long along +X, +Y, +Z, in `model:drawModeColor`;
- bounds: the 12 edges of its box (extentsHint, else the bounds of its default / proxy /
  render gprims, as UsdGeomBBoxCache computes them), in `model:drawModeColor`;
- cards: quads on the box (`box`: on its faces, facing out; `cross`: two back-to-back quads
  through its centre per axis), textured with `model:cardTexture{X,Y,Z}{Pos,Neg}`. With no
  texture authored all six quads are drawn in drawModeColor; otherwise only the axes that
  have one, a face without its own texture showing its opposite's (seen through, so
  mirrored), a texture that does not load showing drawModeColor. Lit as UsdPreviewSurface
  (diffuse = texture, roughness 0.5, metallic 0), texture alpha as a cutout at 0.1,
  one-sided (Storm culls the back).

Deviations, stated: our raster has no line primitive, so origin and bounds lines are thin
square tubes (LINE_WIDTH of the scene's diagonal wide, unlit) where Storm draws one-pixel
curves. `cardGeometry = fromTexture` reads each texture's `worldtoscreen` matrix from its
OpenEXR header, as Storm without OpenImageIO does (pipeline.images.world_to_screen; a PNG
or JPEG has none there, and that card is skipped with a warning, as usdview skips it).
`model:cardVisibility = "simple"` (USD 26) leaves out the box / cross cards across the
stage's up axis.
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np
from pxr import Kind, Usd, UsdGeom

from core.errors import MissingFile
from core.scene import Instance, Material, Mesh, TextureRef
from pipeline.images import world_to_screen
from pipeline.usd.materials import METALLIC, ROUGHNESS, authoring_layer

MODES = ("origin", "bounds", "cards")
DRAW_MODE_COLOR = (0.18, 0.18, 0.18)  # model:drawModeColor's fallback
LINE_WIDTH = 0.003  # of the scene's diagonal: about a pixel where the scene fills 256 px
CUTOUT = 0.1  # Storm's opacityThreshold for card textures

# The faces in texture order [XPos, YPos, ZPos, XNeg, YNeg, ZNeg]: (axis, sign). Each
# texture's st, in the box's unit coordinates (u, v, w), is the image as seen from outside
# that face (st = (y, z) for +X, ...); a face showing its opposite's texture uses that
# texture's own mapping, so the image is seen through the card, mirrored.
FACES = (("XPos", 0, 1), ("YPos", 1, 1), ("ZPos", 2, 1),
         ("XNeg", 0, -1), ("YNeg", 1, -1), ("ZNeg", 2, -1))


def _st(face: int, p: np.ndarray) -> np.ndarray:
    """USD st (t up) of texture `face` at unit-box points p (N x 3)."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    s, t = {0: (y, z), 1: (1 - x, z), 2: (x, y), 3: (1 - y, z), 4: (x, z), 5: (x, 1 - y)}[face]
    return np.stack([s, t], axis=1)


def _quad(face: int, level: float) -> np.ndarray:
    """The 4 corners (unit box coordinates) of the quad normal to FACES[face]'s axis at
    `level` along it, counter-clockwise seen from the side its sign points to."""
    axis, sign = FACES[face][1], FACES[face][2]
    a, b = (axis + 1) % 3, (axis + 2) % 3
    corners = [(0, 0), (1, 0), (1, 1), (0, 1)]
    if sign < 0:
        corners = corners[::-1]
    out = np.zeros((4, 3))
    for i, (ca, cb) in enumerate(corners):
        out[i, axis], out[i, a], out[i, b] = level, ca, cb
    return out


def applies(prim: Usd.Prim) -> str | None:
    """The stand-in mode drawn in place of `prim`'s subtree, or None (drawn as it is)."""
    if not prim.IsModel():
        return None
    api = UsdGeom.ModelAPI(prim)
    mode = str(api.ComputeModelDrawMode())
    if mode not in MODES:
        return None
    attr = api.GetModelApplyDrawModeAttr()
    if attr and attr.HasAuthoredValue():
        return mode if attr.Get() else None
    kind = Usd.ModelAPI(prim).GetKind()
    return mode if kind and Kind.Registry.IsA(kind, Kind.Tokens.component) else None


def card_visibility(prim: Usd.Prim) -> str:
    """`model:cardVisibility` resolved as model:drawMode is: the prim's own value other than
    `inherited`, else the nearest ancestor's, else `full`. `simple` leaves out the cards in
    the stage's up-axis direction (the schema's words; USD 26 adds the attribute)."""
    p = prim
    while p and not p.IsPseudoRoot():
        attr = p.GetAttribute("model:cardVisibility")
        if attr and attr.HasAuthoredValue():
            value = str(attr.Get())
            if value in ("full", "simple"):
                return value
        p = p.GetParent()
    return "full"


@dataclass
class Lines:
    """Line segments (world space, scene units) waiting for the scene's size to know their
    width; `finish` turns them into tubes."""
    name: str
    segments: np.ndarray  # K x 2 x 3
    color: tuple[float, float, float]


class StandIns:
    """Builds the stand-ins of one stage into its Scene; `reader` is the StageReader."""

    def __init__(self, reader):
        # a proxy: a reader <-> stand-ins cycle would keep the stage, and pxr's registry its
        # layers, alive until a GC pass (a file rewritten meanwhile would read as it was)
        self.reader = weakref.proxy(reader)
        self.lines: list[Lines] = []
        self._bbox = UsdGeom.BBoxCache(reader.time, [UsdGeom.Tokens.default_, UsdGeom.Tokens.proxy,
                                                     UsdGeom.Tokens.render], useExtentsHint=True)

    def add(self, prim: Usd.Prim, mode: str, matrices: np.ndarray) -> None:
        """`matrices`: K x 4 x 4 world matrices (column vectors, scene space) of the prim."""
        api = UsdGeom.ModelAPI(prim)
        color = tuple(float(c) for c in (api.GetModelDrawModeColorAttr().Get() or DRAW_MODE_COLOR))
        name = str(prim.GetPath())
        if mode == "origin":
            local = np.array([[[0, 0, 0], [1, 0, 0]], [[0, 0, 0], [0, 1, 0]],
                              [[0, 0, 0], [0, 0, 1]]], np.float64)
            self._lines(f"{name}:origin", local, color, matrices)
            return
        box = self._bbox.ComputeUntransformedBound(prim).ComputeAlignedRange()
        if box.IsEmpty():
            self.reader._warn(f"{name}: model:drawMode {mode} on a prim with no extent; "
                              "nothing drawn there")
            return
        lo, hi = np.array(box.GetMin(), np.float64), np.array(box.GetMax(), np.float64)
        if mode == "bounds":
            c = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float64)
            edges = [(i, j) for i in range(8) for j in range(i + 1, 8)
                     if np.abs(c[i] - c[j]).sum() == 1]
            local = lo + np.array([[c[i], c[j]] for i, j in edges]) * (hi - lo)
            self._lines(f"{name}:bounds", local, color, matrices)
        else:
            self._cards(prim, api, name, lo, hi, color, matrices)

    def _lines(self, name, local: np.ndarray, color, matrices: np.ndarray) -> None:
        pts = np.concatenate([local.reshape(-1, 3), np.ones((local.size // 3, 1))], axis=1)
        for k, m in enumerate(matrices):
            world = (pts @ m.T)[:, :3].reshape(-1, 2, 3)
            self.lines.append(Lines(name if len(matrices) == 1 else f"{name}[{k}]", world, color))

    def _cards(self, prim, api, name, lo, hi, color, matrices) -> None:
        geometry = str(api.GetModelCardGeometryAttr().Get() or "cross")
        getters = {"XPos": api.GetModelCardTextureXPosAttr, "YPos": api.GetModelCardTextureYPosAttr,
                   "ZPos": api.GetModelCardTextureZPosAttr, "XNeg": api.GetModelCardTextureXNegAttr,
                   "YNeg": api.GetModelCardTextureYNegAttr, "ZNeg": api.GetModelCardTextureZNegAttr}
        attrs = [getters[f[0]]() for f in FACES]
        paths = [a.Get(self.reader.time) if a else None for a in attrs]
        authored = [bool(p and p.path) for p in paths]
        if geometry == "fromTexture":
            self._cards_from_texture(name, attrs, paths, authored, color, matrices)
            return
        if any(authored):
            drawn = [authored[i] or authored[(i + 3) % 6] for i in range(6)]
        else:
            drawn = [True] * 6
        if card_visibility(prim) == "simple":  # the cards across the up axis are left out
            up = 2 if UsdGeom.GetStageUpAxis(prim.GetStage()) == UsdGeom.Tokens.z else 1
            drawn = [d and FACES[i][1] != up for i, d in enumerate(drawn)]
        base = Material(name=f"{name}:card", base_color=(*color, 1.0), metallic=METALLIC,
                        roughness=ROUGHNESS)
        materials = self.reader.materials
        for i in range(6):
            if not drawn[i]:
                continue
            tex_face = i if authored[i] else (i + 3) % 6 if authored[(i + 3) % 6] else None
            mat = base
            if tex_face is not None:
                texture = self._texture(name, FACES[tex_face][0], attrs[tex_face],
                                        str(paths[tex_face].path))  # type: ignore[union-attr]  # authored: not None
                if texture is not None:
                    mat = Material(name=f"{name}:card{FACES[tex_face][0]}",
                                   base_color_texture=TextureRef(texture), metallic=METALLIC,
                                   roughness=ROUGHNESS, alpha_mode="MASK", alpha_cutoff=CUTOUT)
            level = 1.0 if FACES[i][2] > 0 else 0.0
            if geometry == "cross":
                level = 0.5
            unit = _quad(i, level)
            st = _st(tex_face if tex_face is not None else i, unit)
            positions = (lo + unit * (hi - lo)).astype(np.float32)
            normal = np.zeros(3, np.float32)
            normal[FACES[i][1]] = FACES[i][2]
            uv = np.stack([st[:, 0], 1.0 - st[:, 1]], axis=1).astype(np.float32)  # glTF v down
            mesh = Mesh(name=f"{name}:cards{FACES[i][0]}", positions=positions,
                        normals=np.tile(normal, (4, 1)),
                        indices=np.array([[0, 1, 2], [0, 2, 3]], np.uint32), uv0=uv)
            self.reader.scene.meshes.append(mesh)
            index = materials.add_material(mat)
            self.reader.scene.instances.extend(
                Instance(len(self.reader.scene.meshes) - 1, index, m) for m in matrices)

    def _cards_from_texture(self, name, attrs, paths, authored, color, matrices) -> None:
        """cardGeometry fromTexture as UsdImaging's draw-mode stand-in builds it: one quad per
        texture whose metadata has a `worldtoscreen` matrix W, the screen square's corners
        (1,-1), (-1,-1), (-1,1), (1,1) (z 0) taken back through W^-1 (row vectors, with the
        projective divide, as GfMatrix4d.Transform) into the prim's space, st (1,1), (0,1),
        (0,0), (1,0). A texture without the matrix is no card (Storm warns and skips it); no
        opposite face is borrowed and no untextured box is drawn."""
        screen = np.array([[1, -1, 0, 1], [-1, -1, 0, 1], [-1, 1, 0, 1], [1, 1, 0, 1]], np.float64)
        st = np.array([[1, 1], [0, 1], [0, 0], [1, 0]], np.float32)
        drawn = 0
        for i, face in enumerate(FACES):
            if not authored[i]:
                continue
            label = f"{name}: model:cardTexture{face[0]}"
            try:
                identifier = self.reader.graph.resolve(authoring_layer(attrs[i], self.reader.time),
                                                       str(paths[i].path))
            except MissingFile as exc:
                self.reader._warn(f"{label}: {exc.reason}; no fromTexture card there")
                continue
            matrix, why = world_to_screen(self.reader.graph.read_bytes(identifier), identifier)
            if matrix is None:
                self.reader._warn(f"{label} {identifier}: {why}; no fromTexture card there "
                                  "(usdview skips it too)")
                continue
            h = screen @ np.linalg.inv(matrix)
            if np.any(np.abs(h[:, 3]) < 1e-12):
                self.reader._warn(f"{label} {identifier}: its worldtoscreen matrix sends the card "
                                  "to infinity; no card there")
                continue
            positions = (h[:, :3] / h[:, 3:]).astype(np.float32)
            normal = np.cross(positions[1] - positions[0], positions[2] - positions[0])
            length = float(np.linalg.norm(normal))
            if not np.isfinite(length) or length == 0:
                self.reader._warn(f"{label} {identifier}: its worldtoscreen matrix gives a "
                                  "degenerate card; no card there")
                continue
            texture = self.reader.materials.texture(identifier, ("clamp", "clamp"))
            if texture is None:
                mat = Material(name=f"{name}:card", base_color=(*color, 1.0), metallic=METALLIC,
                               roughness=ROUGHNESS)
            else:
                mat = Material(name=f"{name}:card{face[0]}", base_color_texture=TextureRef(texture),
                               metallic=METALLIC, roughness=ROUGHNESS, alpha_mode="MASK",
                               alpha_cutoff=CUTOUT)
            uv = np.stack([st[:, 0], 1.0 - st[:, 1]], axis=1)  # glTF v down
            mesh = Mesh(name=f"{name}:cards{face[0]}", positions=positions,
                        normals=np.tile((normal / length).astype(np.float32), (4, 1)),
                        indices=np.array([[0, 1, 2], [0, 2, 3]], np.uint32), uv0=uv)
            self.reader.scene.meshes.append(mesh)
            index = self.reader.materials.add_material(mat)
            self.reader.scene.instances.extend(
                Instance(len(self.reader.scene.meshes) - 1, index, m) for m in matrices)
            drawn += 1
        if not drawn:
            self.reader._warn(f"{name}: model:cardGeometry fromTexture and no card texture with a "
                              "worldtoscreen matrix: nothing drawn for it, as in usdview")

    def _texture(self, name: str, face: str, attr: Usd.Attribute, path: str) -> int | None:
        try:
            identifier = self.reader.graph.resolve(authoring_layer(attr, self.reader.time), path)
        except MissingFile as exc:
            self.reader._warn(f"{name}: model:cardTexture{face}: {exc.reason}; that card is "
                              "drawn in model:drawModeColor")
            return None
        return self.reader.materials.texture(identifier, ("clamp", "clamp"))

    def finish(self) -> None:
        """The lines as thin square tubes, LINE_WIDTH of the scene's diagonal (the stand-in
        lines included) wide, unlit in their colour."""
        if not self.lines:
            return
        scene = self.reader.scene
        points = [s.segments.reshape(-1, 3) for s in self.lines]
        for inst in scene.instances:
            p = scene.meshes[inst.mesh].positions
            if len(p):
                lo, hi = p.min(axis=0), p.max(axis=0)
                corners = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                                    for z in (lo[2], hi[2])])
                points.append((corners @ inst.matrix.T)[:, :3])
        allp = np.concatenate(points)
        diagonal = float(np.linalg.norm(allp.max(axis=0) - allp.min(axis=0))) or 1.0
        width = LINE_WIDTH * diagonal
        for line in self.lines:
            mesh = tubes(line.name, line.segments, width)
            if mesh is None:
                continue
            scene.meshes.append(mesh)
            mat = Material(name=f"{line.name}:line", base_color=(*line.color, 1.0), metallic=0.0,
                           roughness=1.0, unlit=True)
            scene.instances.append(Instance(len(scene.meshes) - 1,
                                            self.reader.materials.add_material(mat), np.eye(4)))
        self.lines = []


def tubes(name: str, segments: np.ndarray, width: float) -> Mesh | None:
    """Square tubes `width` wide around each segment (K x 2 x 3), extended by half the width
    at both ends so that the corners of a box close; None when every segment is degenerate."""
    verts: list[np.ndarray] = []
    normals: list[np.ndarray] = []
    faces: list[list[int]] = []
    for a, b in segments:
        d = b - a
        length = float(np.linalg.norm(d))
        if length <= 0:
            continue
        d = d / length
        helper = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
        u = np.cross(d, helper)
        u /= np.linalg.norm(u)
        v = np.cross(d, u)
        h = width / 2
        a, b = a - d * h, b + d * h
        # four sides, each its own quad (flat normals), then the two end caps
        for n, e1 in ((u, v), (v, -u), (-u, -v), (-v, u)):
            base = len(verts)
            c = n * h
            verts += [a + c - e1 * h, a + c + e1 * h, b + c + e1 * h, b + c - e1 * h]
            normals += [n] * 4
            faces += [[base, base + 2, base + 1], [base, base + 3, base + 2]]
        for end, n in ((a, -d), (b, d)):
            base = len(verts)
            verts += [end + (su * u + sv * v) * h for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
            normals += [n] * 4
            faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    if not verts:
        return None
    pos = np.array(verts, np.float32)
    nrm = np.array(normals, np.float32)
    tri = np.array(faces, np.int64)
    # wind every triangle to face its normal (outward)
    face_n = np.cross(pos[tri[:, 1]] - pos[tri[:, 0]], pos[tri[:, 2]] - pos[tri[:, 0]])
    flip = np.einsum("ij,ij->i", face_n, nrm[tri[:, 0]]) < 0
    tri[flip] = tri[flip][:, [0, 2, 1]]
    return Mesh(name=name, positions=pos, normals=nrm, indices=tri.astype(np.uint32))
