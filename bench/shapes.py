"""Extra geometry for the speed-vs-accuracy chart and the stability suite (bench.scenes kinds).

Each builder returns (positions N x 3 float32, normals N x 3 float32, indices M x 3 uint32)
centred at the origin with bounding radius 1, as `mesh_arrays` (below) gives every kind. The broken
ones (open, degenerate, flipped) start from the same icosphere as the "sphere" kind so that
the clean sphere's reference says what they should have looked like.
"""
from __future__ import annotations

import logging
import typing
from functools import lru_cache

import numpy as np

from bench.assets import ASSETS

log = logging.getLogger(__name__)

REAL_ASSETS = {"duck": "gltf/Duck.glb", "teapot": "usd/Teapot/Teapot.usd"}
SLAB_THICKNESS = 0.1     # of a 2 x 2 plate: thickness / width = 1/20
BOWL_WALL = 0.15         # wall thickness of the hemispherical bowl (outer radius 1)
DEGENERATE_EXTRA = 200   # zero-area triangles added to the sphere
MESH_FILES = {"bunny": "bunny.ply", "torus": "torus.STL"}
UV_SPHERE_LAT, UV_SPHERE_LON = 96, 192  # textured sphere: ~36k triangles, as smooth as the icosphere
VASE_WALL, VASE_BASE = 0.06, 0.15  # before normalising (vase height 2)
ICOSPHERE_SUBDIVISIONS = 5  # 20480 triangles: the smooth-normal error is far below the errors measured


def _normalise(pos: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    lo, hi = pos.min(0), pos.max(0)
    centre = (lo + hi) / 2
    scale = 1.0 / (np.linalg.norm(hi - lo) / 2)
    return (pos - centre) * scale, scale, centre


def _out(pos, nrm, idx):
    return (np.ascontiguousarray(pos, np.float32), np.ascontiguousarray(nrm, np.float32),
            np.ascontiguousarray(idx, np.uint32))


def _faceted(m):
    """Every triangle with its own corners and flat normal (sharp edges stay sharp)."""
    pos = m.vertices[m.faces].reshape(-1, 3)
    nrm = np.repeat(m.face_normals, 3, axis=0)
    return pos, nrm, np.arange(len(pos)).reshape(-1, 3)


def cube():
    """A 2 x 2 x 2 box, faceted (every triangle its own corners and flat normal); half-extent 1,
    not radius 1: the committed cube references were made from it so."""
    import trimesh

    return _out(*_faceted(trimesh.creation.box(extents=(2.0, 2.0, 2.0))))


def slab():
    """A thin plate 2 x 2 x SLAB_THICKNESS (faceted), normalised to radius 1."""
    import trimesh

    pos, nrm, idx = _faceted(trimesh.creation.box(extents=(2.0, 2.0, SLAB_THICKNESS)))
    pos, _, _ = _normalise(pos)
    return _out(pos, nrm, idx)


def prism():
    """A right-angle glass prism (faceted): its hypotenuse face looks along +z and the two
    legs meet behind it at 90 degrees, 2 long along y; normalised to radius 1. A ray through
    the hypotenuse meets each leg at 45 degrees, beyond the critical angle of any IOR above
    1.414: total internal reflection twice, and out the way it came (a Porro prism)."""
    import trimesh

    xz = [(-1.0, 0.5), (1.0, 0.5), (0.0, -0.5)]  # hypotenuse at z = 0.5, right angle at z = -0.5
    v = np.array([(x, y, z) for y in (-1.0, 1.0) for x, z in xz])
    faces = [(0, 1, 2), (3, 5, 4), (0, 3, 4), (0, 4, 1), (1, 4, 5), (1, 5, 2), (2, 5, 3), (2, 3, 0)]
    m = trimesh.Trimesh(v, faces, process=False)
    m.fix_normals()  # outward winding
    pos, nrm, idx = _faceted(m)
    pos, _, _ = _normalise(pos)
    return _out(pos, nrm, idx)


def bowl(sections: int = 96, steps: int = 24):
    """A closed hemispherical bowl (outer radius 1, wall BOWL_WALL, opening up): concave inside."""
    a = np.linspace(0.0, np.pi / 2, steps)
    r_in = 1.0 - BOWL_WALL
    outer = np.stack([np.cos(a), -np.sin(a)], 1)[::-1]          # bottom centre -> rim, outside
    inner = np.stack([r_in * np.cos(a), -r_in * np.sin(a)], 1)  # rim -> bottom centre, inside
    profile = np.concatenate([outer, inner])  # (radius, height), counter-clockwise: normals out
    # Smooth normals: the walls are curved; only the narrow rim ring is shaded too softly.
    return _revolved(profile, sections)


def uv_sphere(lat: int = UV_SPHERE_LAT, lon: int = UV_SPHERE_LON):
    """A latitude-longitude sphere of radius 1 (y up) with a UV seam at the back (-z), for
    textured scenes: u = 0.5 + azimuth / 2pi (0.5 faces the default camera, +z), v = polar
    angle / pi (0 at the top, as glTF's v runs down the image). Returns the three arrays of
    every kind and the N x 2 float32 UVs (see `mesh_uvs`)."""
    theta = np.linspace(0.0, np.pi, lat + 1)
    phi = np.linspace(-np.pi, np.pi, lon + 1)  # the seam column is duplicated
    t, f = np.meshgrid(theta, phi, indexing="ij")
    pos = np.stack([np.sin(t) * np.sin(f), np.cos(t), np.sin(t) * np.cos(f)], -1).reshape(-1, 3)
    uv = np.stack([0.5 + f / (2 * np.pi), t / np.pi], -1).reshape(-1, 2)
    i, j = np.meshgrid(np.arange(lat), np.arange(lon), indexing="ij")
    a = (i * (lon + 1) + j).ravel()
    b, c, d = a + lon + 1, a + 1, a + lon + 2
    # counter-clockwise seen from outside; the pole rows keep only their non-degenerate half
    top = np.stack([a, b, c], 1)[i.ravel() > 0]
    bottom = np.stack([c, b, d], 1)[i.ravel() < lat - 1]
    return (*_out(pos, pos, np.concatenate([top, bottom])), uv.astype(np.float32))


def vase(sections: int = 128, steps: int = 48):
    """A hollow glass vase (closed surface: outer wall, rounded lip, inner wall, thick base),
    y up, normalised to radius 1: walls ~VASE_WALL thick, so light crosses glass twice through
    each wall and a longer way through the base and the silhouette's edges."""
    from scipy.interpolate import CubicSpline

    h = np.linspace(0.0, 1.0, steps)
    # outer radius along the height: foot, belly, neck, flared lip
    knots_h, knots_r = [0.0, 0.25, 0.55, 0.8, 1.0], [0.42, 0.62, 0.42, 0.26, 0.36]
    r_out = CubicSpline(knots_h, knots_r)(h) * 1.0
    heights = h * 2.0
    base = VASE_BASE
    inner_h = heights[heights > base]
    r_in = np.interp(inner_h, heights, r_out) - VASE_WALL
    outer = np.stack([r_out, heights], 1)
    inner = np.stack([r_in, inner_h], 1)[::-1]
    profile = np.concatenate([[[0.0, 0.0]], outer, inner, [[0.0, inner_h[0]]]])
    return _revolved(profile[::-1], sections)


def _revolved(profile: np.ndarray, sections: int):
    """A closed surface of revolution of (radius, height) `profile` about y, outward-facing,
    normalised, with smooth normals."""
    import trimesh

    m = trimesh.creation.revolve(profile, sections=sections)
    m.merge_vertices()
    m.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))  # Z up -> Y up
    if m.volume < 0:
        m.invert()
    pos, _, _ = _normalise(np.asarray(m.vertices))
    return _out(pos, m.vertex_normals, m.faces)


def _sphere():
    return mesh_arrays("sphere")


def open_sphere():
    """The sphere with its top cap (y > 0.8) removed: interior rays from there find no surface."""
    pos, nrm, idx = _sphere()
    keep = pos[idx][:, :, 1].max(axis=1) <= 0.8
    return _out(pos, nrm, idx[keep])


def degenerate_sphere():
    """The sphere plus DEGENERATE_EXTRA zero-area triangles (repeated and collinear corners)."""
    pos, nrm, idx = _sphere()
    rng = np.random.default_rng(7)
    a = rng.integers(0, len(pos), DEGENERATE_EXTRA)
    b = rng.integers(0, len(pos), DEGENERATE_EXTRA)
    # Half repeat a corner; half use a new vertex at the midpoint of two existing ones.
    half = DEGENERATE_EXTRA // 2
    mid = (pos[a[half:]] + pos[b[half:]]) / 2
    mid_n = nrm[a[half:]]
    new = np.arange(len(pos), len(pos) + len(mid))
    extra = np.concatenate([np.stack([a[:half], a[:half], b[:half]], 1),
                            np.stack([a[half:], new, b[half:]], 1)])
    return _out(np.concatenate([pos, mid]), np.concatenate([nrm, mid_n]),
                np.concatenate([idx, extra]))


def flipped_sphere():
    """The sphere with every stored vertex normal pointing inward (winding kept)."""
    pos, nrm, idx = _sphere()
    return _out(pos, -nrm, idx)


def real_asset(kind: str):
    """A sample asset's triangles in world space (every instance), through pipeline.ingest.load_scene."""
    from pipeline.ingest import load_scene

    s = load_scene(ASSETS / REAL_ASSETS[kind])
    ps, ns, ids, base = [], [], [], 0
    for inst in s.instances:
        m = s.meshes[inst.mesh]
        mtx = np.asarray(inst.matrix, np.float64)
        ps.append(m.positions @ mtx[:3, :3].T + mtx[:3, 3])
        n = m.normals @ np.linalg.inv(mtx[:3, :3])
        ns.append(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20))
        ids.append(m.indices.reshape(-1, 3).astype(np.int64) + base)
        base += len(m.positions)
    pos, _, _ = _normalise(np.concatenate(ps))
    return _out(pos, np.concatenate(ns), np.concatenate(ids))


BUILDERS = {
    "cube": cube, "slab": slab, "prism": prism, "bowl": bowl, "open_sphere": open_sphere,
    "degenerate_sphere": degenerate_sphere, "flipped_sphere": flipped_sphere,
    "uvsphere": lambda: uv_sphere()[:3], "vase": vase,
    "duck": lambda: real_asset("duck"), "teapot": lambda: real_asset("teapot"),
}


def mesh_uvs(kind: str) -> np.ndarray | None:
    """TEXCOORD_0 (N x 2 float32, glTF orientation) of a kind that has UVs, else None."""
    return uv_sphere()[3] if kind == "uvsphere" else None


@lru_cache(maxsize=None)
def mesh_arrays(kind: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(positions N x 3 float32, normals N x 3 float32, indices M x 3 uint32), centred at the
    origin with bounding radius 1 (before the spec's scale)."""
    import trimesh

    if kind == "sphere":
        m = trimesh.creation.icosphere(subdivisions=ICOSPHERE_SUBDIVISIONS, radius=1.0)
        pos = m.vertices / np.linalg.norm(m.vertices, axis=1, keepdims=True)
        return pos.astype(np.float32), pos.astype(np.float32), m.faces.astype(np.uint32)
    if kind in BUILDERS:
        return BUILDERS[kind]()
    if kind in MESH_FILES:
        m = typing.cast(trimesh.Trimesh, trimesh.load(ASSETS / "mesh" / MESH_FILES[kind], force="mesh"))
        lo, hi = m.bounds
        m.apply_translation(-(lo + hi) / 2)
        m.apply_scale(1.0 / (np.linalg.norm(hi - lo) / 2))
        nrm = np.array(m.vertex_normals)
        # Where face normals cancel (bunny: 22 vertices) take one adjacent face's normal, so
        # no vertex has a zero normal (Mitsuba turns those into NaN samples).
        bad = np.linalg.norm(nrm, axis=1) < 0.5
        if bad.any():
            one_face = np.zeros_like(nrm)
            for k in range(3):
                one_face[m.faces[:, k]] = m.face_normals
            nrm[bad] = one_face[bad]
        return (m.vertices.astype(np.float32), nrm.astype(np.float32), m.faces.astype(np.uint32))
    raise KeyError(f"unknown mesh {kind!r}")
