"""UDIM textures as one atlas, and the bake's UV remap that reads them through it.

A UDIM texture is a set of tiles: tile 1001 + u + 10 v covers st [u, u+1] x [v, v+1]. Storm
samples a texture array per fragment; here the tiles that exist are packed into one atlas
texture (core.scene.UdimLayout: equal cells, a gutter of repeated edge texels around each,
empty cells transparent black as Storm reads a missing tile), and the bake gives each
triangle UVs into its tile's cell (st after the texture's transform): a triangle across tile
borders is first cut along them, each piece in one tile, and a vertex shared by triangles of
different tiles is split. Every renderer then samples an ordinary texture with ordinary UVs
from the same bake.

Approximate: inside a tile, wrap modes are those of the gutter (clamp to the tile's edge; a
repeat-wrapped tile differs in half a texel at its edge); the mips past the gutter's width (a
cell under 16 texels) blend neighbouring cells; past MAX_SPLIT triangles across borders in a
mesh (or one over MAX_SPAN tiles) the rest show their centroid's tile, with a warning.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from PIL import Image

from core.scene import (
    CLAMP_TO_EDGE,
    UDIM_GUTTER,
    Material,
    Mesh,
    Sampler,
    Texture,
    TextureRef,
    UdimLayout,
)


def layout_for(tiles: list[int]) -> UdimLayout:
    """Cells for `tiles` (sorted tile numbers) and one empty cell, in a near-square grid."""
    columns = math.ceil(math.sqrt(len(tiles) + 1))
    return UdimLayout(tuple(tiles), columns, math.ceil((len(tiles) + 1) / columns))


def cell_size(sizes: list[tuple[int, int]], layout: UdimLayout, max_pixels: int) -> tuple[int, int]:
    """(w, h) of a cell's tile part: the largest tile's, a multiple of 16 (so that the gutter,
    a sixteenth each side, is whole texels), shrunk until the atlas holds no more than
    `max_pixels` texels (the per-image limit)."""
    w = 16 * math.ceil(max(s[0] for s in sizes) / 16)
    h = 16 * math.ceil(max(s[1] for s in sizes) / 16)
    while w > 16 and h > 16 and \
            _padded(w) * layout.columns * _padded(h) * layout.rows > max_pixels:
        w, h = 16 * max(1, w // 32), 16 * max(1, h // 32)
    return w, h


def _padded(c: int) -> int:
    return c + c // 8  # the tile and a gutter of c / 16 each side


class UdimTexture(Texture):
    """The atlas of a UDIM texture's tiles (Textures with their pixels, decoded on first use),
    built when first read; `cell` is a tile's part of a cell in texels."""

    def __init__(self, name: str, tiles: dict[int, Texture], layout: UdimLayout,
                 cell: tuple[int, int], source: str):
        self.tiles, self.cell = tiles, cell
        self._pixels: np.ndarray | None = None
        super().__init__(name=name, image=None, source=source, udim=layout,  # type: ignore[arg-type]  # made on first use
                         sampler=Sampler(wrap_s=CLAMP_TO_EDGE, wrap_t=CLAMP_TO_EDGE))

    @property
    def image(self) -> np.ndarray:
        if self._pixels is None:
            layout = self.udim
            assert layout is not None
            w, h = self.cell
            pw, ph = _padded(w), _padded(h)
            out = np.zeros((ph * layout.rows, pw * layout.columns, 4), np.uint8)
            for k, number in enumerate(layout.tiles):
                tile = self.tiles[number]
                pixels = tile.image
                if pixels.shape[:2] != (h, w):
                    pixels = np.asarray(Image.fromarray(pixels, "RGBA").resize(
                        (w, h), Image.Resampling.BOX if pixels.shape[1] > w else
                        Image.Resampling.BILINEAR))
                tile.image = None  # type: ignore[assignment]  # decoded once, into the atlas
                row, col = divmod(k, layout.columns)
                gw, gh = (pw - w) // 2, (ph - h) // 2
                out[row * ph:(row + 1) * ph, col * pw:(col + 1) * pw] = np.pad(
                    pixels, ((gh, gh), (gw, gw), (0, 0)), mode="edge")
            self._pixels = out
        return self._pixels

    @image.setter
    def image(self, value) -> None:
        self._pixels = value


def tile_of(s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """UDIM tile numbers at st points (v up); 0 outside the 10 x 10 tiles."""
    u, v = np.floor(s), np.floor(t)
    inside = (u >= 0) & (u < 10) & (v >= 0) & (v < 10)
    return np.where(inside, 1001 + u + 10 * v, 0).astype(np.int64)


def remap(mesh: Mesh, material: Material, layouts: list[UdimLayout | None],
          warn) -> tuple[Mesh, Material] | None:
    """`mesh` and `material` with the material's UDIM textures (those with a layout in
    `layouts`, by texture index) read through atlas UVs; None when it reads none. The UDIM
    slots read one UV set afterwards, untransformed: their own set when no other texture
    reads it, else the other set when that is free."""
    refs = {slot: ref for slot, ref in material.texture_refs().items()
            if 0 <= ref.texture < len(layouts) and layouts[ref.texture] is not None}
    if not refs:
        return None
    first_slot, first = next(iter(refs.items()))
    layout = layouts[first.texture]
    assert layout is not None
    source = first.uv_set
    for slot, ref in refs.items():
        if (layouts[ref.texture], ref.uv_set, ref.offset, ref.rotation, ref.scale) != \
                (layout, source, first.offset, first.rotation, first.scale):
            warn(f"{material.name}: {slot}'s UDIM texture has other tiles, UVs or transform "
                 f"than {first_slot}'s; read through the latter's layout")
    uv = mesh.uv0 if source == 0 else mesh.uv1
    if uv is None or not len(mesh.indices):
        return None
    others = {ref.uv_set for slot, ref in material.texture_refs().items() if slot not in refs}
    target = source
    if source in others:
        if 1 - source in others:
            warn(f"{material.name}: UDIM and other textures read both UV sets; the others read "
                 "the UDIM atlas's UVs")
        else:
            target = 1 - source
    m = first.uv_matrix().astype(np.float64)
    st = uv.astype(np.float64) @ m[:2, :2].T + m[:2, 2]
    st[:, 1] = 1.0 - st[:, 1]  # glTF v down -> UDIM's t up
    tri = mesh.indices.astype(np.int64)
    centre = st[tri].mean(axis=1)
    numbers = tile_of(centre[:, 0], centre[:, 1])
    arrays = {name: getattr(mesh, name) for name in ATTRIBUTES if getattr(mesh, name) is not None}
    tri, numbers, arrays, st = _split_at_tile_borders(tri, numbers, arrays, st, material.name, warn)
    lookup = np.full(1101, layout.empty_cell, np.int64)
    lookup[list(layout.tiles)] = np.arange(len(layout.tiles))
    cell = lookup[numbers]  # tile 0 (outside) -> the empty cell, as a missing tile
    cells = layout.empty_cell + 1
    keys = (tri * cells + cell[:, None]).reshape(-1)
    unique, inverse = np.unique(keys, return_inverse=True)
    vertex, vcell = unique // cells, unique % cells
    atlas = _atlas_uv(st[vertex], vcell, layout)
    out = dataclasses.replace(mesh, indices=inverse.reshape(-1, 3).astype(np.uint32),
                              subdivision=None, creases=None, cage=None, cage_corners=None,
                              cage_interpolation=None)
    for name, values in arrays.items():
        setattr(out, name, values[vertex])
    setattr(out, "uv0" if target == 0 else "uv1", atlas.astype(np.float32))
    read = dataclasses.replace(material)
    for slot, ref in refs.items():
        setattr(read, slot, TextureRef(ref.texture, target))
    return out, read


ATTRIBUTES = ("positions", "normals", "tangents", "uv0", "uv1", "colors")
MAX_SPLIT = 20_000  # triangles across tile borders cut per mesh (a Python loop each); past it,
MAX_SPAN = 16       # or for a triangle over more tiles than this, its centroid's tile is used
_EPS = 1e-6         # st within this of a border is on it (a corner on a border is not across)


def _split_at_tile_borders(tri, numbers, arrays, st, name, warn):
    """Triangles whose st crosses a tile border cut along the borders (each piece in one
    tile, as Storm switches tiles per fragment), new corners interpolated from the
    triangle's; (triangles, tile numbers, attributes, st) for the whole mesh."""
    lo = np.floor(st[tri].min(axis=1) + _EPS)
    hi = np.floor(st[tri].max(axis=1) - _EPS)
    span = (hi - lo + 1).clip(1, None)
    e1, e2 = st[tri[:, 1]] - st[tri[:, 0]], st[tri[:, 2]] - st[tri[:, 0]]
    area = np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    across = np.flatnonzero((span.prod(axis=1) > 1) & (area > 1e-12))
    if not len(across):
        return tri, numbers, arrays, st
    fits = span[across].prod(axis=1) <= MAX_SPAN
    if not fits.all() or len(across) > MAX_SPLIT:
        warn(f"{name}: {len(across)} triangles cross UDIM tile borders; past {MAX_SPLIT} (or "
             f"over {MAX_SPAN} tiles each) they show their centre's tile")
    across = across[fits][:MAX_SPLIT]
    corners: list[tuple[int, int, int, float, float, float]] = []  # source triangle, weights
    pieces: list[tuple[int, int, int]] = []
    tiles: list[int] = []
    base = len(st)
    for t in across.tolist():
        a, b, c = st[tri[t]].tolist()
        for v in range(int(lo[t, 1]), int(hi[t, 1]) + 1):
            for u in range(int(lo[t, 0]), int(hi[t, 0]) + 1):
                poly = _clip([(*a, 1.0, 0.0, 0.0), (*b, 0.0, 1.0, 0.0), (*c, 0.0, 0.0, 1.0)],
                             u, v)
                if len(poly) < 3:
                    continue
                first = base + len(corners)
                corners.extend((t, *p[2:]) for p in poly)  # type: ignore[misc]  # (int, 3 floats)
                pieces.extend((first, first + k, first + k + 1) for k in range(1, len(poly) - 1))
                tiles.extend([int(tile_of(np.array([u + 0.5]), np.array([v + 0.5]))[0])]
                             * (len(poly) - 2))
    if not pieces:
        return tri, numbers, arrays, st
    table = np.asarray(corners, np.float64)
    src = tri[table[:, 0].astype(np.int64)]  # K x 3 source vertices
    w = table[:, 1:]

    def blend(values: np.ndarray) -> np.ndarray:
        mixed = np.einsum("kj,kjc->kc", w, values[src].astype(np.float64))
        return mixed.astype(values.dtype)

    out = {}
    for key, values in arrays.items():
        new = blend(values)
        if key in ("normals", "tangents"):  # interpolated directions, unit again
            xyz = new[:, :3].astype(np.float64)
            xyz /= np.maximum(np.linalg.norm(xyz, axis=1, keepdims=True), 1e-12)
            new[:, :3] = xyz
            if key == "tangents":
                new[:, 3] = values[src[:, 0], 3]
        out[key] = np.concatenate([values, new])
    keep = np.ones(len(tri), bool)
    keep[across] = False
    return (np.concatenate([tri[keep], np.asarray(pieces, np.int64)]),
            np.concatenate([numbers[keep], np.asarray(tiles, np.int64)]), out,
            np.concatenate([st, blend(st)]))


def _clip(poly: list[tuple], u: int, v: int) -> list[tuple]:
    """Sutherland-Hodgman: the polygon (points (s, t, *weights)) inside tile [u, u+1] x
    [v, v+1], its winding kept."""
    for axis, bound, above in ((0, u, True), (0, u + 1, False), (1, v, True), (1, v + 1, False)):
        out = []
        for k, p in enumerate(poly):
            q = poly[k - 1]
            p_in = p[axis] >= bound if above else p[axis] <= bound
            q_in = q[axis] >= bound if above else q[axis] <= bound
            if p_in != q_in:
                f = (bound - q[axis]) / (p[axis] - q[axis])
                out.append(tuple(qa + f * (pa - qa) for qa, pa in zip(q, p)))
            if p_in:
                out.append(p)
        # a corner on the border comes back as its own crossing: once is enough
        poly = [p for k, p in enumerate(out) if p[:2] != out[k - 1][:2]] if len(out) > 1 else out
        if len(poly) < 3:
            return []
    return poly


def _atlas_uv(st: np.ndarray, cell: np.ndarray, layout: UdimLayout) -> np.ndarray:
    """Atlas UVs (glTF, v down) of st points, each in its cell's tile; the empty cell's centre
    for the points of triangles on no tile."""
    numbers = np.array([*layout.tiles, 1001], np.int64)[cell]
    u0, v0 = (numbers - 1001) % 10, (numbers - 1001) // 10
    local_s = st[:, 0] - u0
    local_t = st[:, 1] - v0
    empty = cell == layout.empty_cell
    local_s[empty], local_t[empty] = 0.5, 0.5
    row, col = np.divmod(cell, layout.columns)
    inner = 1.0 - 2.0 * UDIM_GUTTER
    u = (col + UDIM_GUTTER + local_s * inner) / layout.columns
    v = (row + UDIM_GUTTER + (1.0 - local_t) * inner) / layout.rows
    return np.stack([u, v], axis=1)
