"""Triangles paired into Embree quads (pipeline.interior.pairing): the same triangles, half as many
primitives where the mesh allows."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import trimesh

from pipeline.interior.pairing import SPLIT_AT, pair_quads


def _halves(quads: np.ndarray) -> np.ndarray:
    """The triangles Embree makes of each quad, (v0, v1, v3) and (v2, v3, v1); the second half
    of a (a, b, c, c) quad is degenerate and dropped."""
    first, second = quads[:, [0, 1, 3]], quads[:, [2, 3, 1]]
    return np.concatenate([first, second[quads[:, 2] != quads[:, 3]]])


def _canonical(tris: np.ndarray) -> np.ndarray:
    """Each triangle rotated to start at its smallest index (winding kept), rows sorted."""
    t = np.asarray(tris, np.int64).reshape(-1, 3)
    r = np.argmin(t, axis=1)
    rows = np.arange(len(t))
    rot = np.stack([t[rows, r], t[rows, (r + 1) % 3], t[rows, (r + 2) % 3]], axis=1)
    return rot[np.lexsort(rot.T[::-1])]


def _meshes(assets):
    bunny = trimesh.load(assets / "mesh" / "bunny.ply", process=False)
    torus = trimesh.creation.torus(1.0, 0.3, major_sections=250, minor_sections=200)
    soup = trimesh.creation.box()
    soup.unmerge_vertices()
    rng = np.random.default_rng(3)
    shuffled = torus.faces[rng.permutation(len(torus.faces))]
    # a fin: three triangles on one edge (non-manifold), degenerate ones sharing a collapsed
    # edge, a duplicate
    odd = np.array([[0, 1, 2], [1, 0, 3], [1, 0, 4], [5, 5, 6], [0, 1, 2], [2, 1, 7], [5, 5, 8]])
    return {"bunny": bunny.faces, "torus": torus.faces, "shuffled torus": shuffled,
            "triangle soup": soup.faces, "odd": odd}


@pytest.mark.parametrize("split", [False, True])
def test_quads_hold_exactly_the_triangles(assets, split):
    pool = ThreadPoolExecutor(1) if split else None  # split: large meshes paired in two halves
    for name, faces in _meshes(assets).items():
        quads = pair_quads(faces, pool)
        assert quads.dtype == np.uint32 and quads.shape[1] == 4, name
        np.testing.assert_array_equal(_canonical(_halves(quads)), _canonical(faces), err_msg=name)
    if pool:
        pool.shutdown()
        bunny = _meshes(assets)["bunny"]
        assert len(bunny) >= SPLIT_AT  # the split really ran, at a small cost in pairs
        assert len(pair_quads(bunny)) < len(pair_quads(bunny, ThreadPoolExecutor(1))) < 0.6 * len(bunny)


@pytest.mark.parametrize("name, least", [("torus", 1.0), ("shuffled torus", 0.85), ("bunny", 0.85),
                                         ("triangle soup", 0.0)])
def test_pairing_rate(assets, name, least):
    faces = _meshes(assets)[name]
    paired = 2 * (len(faces) - len(pair_quads(faces))) / len(faces)
    assert paired >= least
    if name == "triangle soup":
        assert paired == 0  # no shared indices: every triangle is its own (a, b, c, c) quad


def test_empty_and_single():
    assert pair_quads(np.zeros((0, 3), np.uint32)).shape == (0, 4)
    np.testing.assert_array_equal(pair_quads(np.array([[4, 5, 6]])), [[4, 5, 6, 6]])
