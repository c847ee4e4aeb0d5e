"""core.hull: the points kept for an object's bound have its convex hull (every qhull vertex
among them), found without scipy up to OUTER_MAX_POINTS; qhull past that and per pose."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from core import hull
from core.baked import BakedMesh
from core.scene import Material

ROOT = Path(__file__).resolve().parents[1]
_rng = np.random.default_rng(7)


def _sphere(n: int) -> np.ndarray:
    v = _rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


CLOUDS = {
    "ball": _rng.normal(size=(20000, 3)),
    "sphere shell": _sphere(6000),                                        # every point a hull vertex
    "grid box far from the origin": np.stack(np.meshgrid(*[np.linspace(-1, 1, 18)] * 3), -1)
    .reshape(-1, 3) * [100.0, 1.0, 3.0] + 1e4,                            # coplanar faces, large offset
    "thin slab": _rng.uniform(-1, 1, size=(8000, 3)) * [1.0, 1.0, 1e-4],
}


@pytest.mark.parametrize("name", CLOUDS)
def test_outer_points_keep_every_hull_vertex(name):
    points = CLOUDS[name]
    kept = hull._outer(points)
    vertices = points[ConvexHull(points).vertices]
    assert {tuple(v) for v in vertices} <= {tuple(k) for k in kept}
    assert len(kept) < len(points) or name == "sphere shell"
    assert ConvexHull(kept).volume == pytest.approx(ConvexHull(points).volume, rel=1e-12)


def test_flat_points_are_all_kept():
    flat = np.c_[_rng.normal(size=(5000, 2)), np.full(5000, 3.0)]
    assert len(hull._outer(flat)) == len(flat)


def _mesh(points: np.ndarray) -> BakedMesh:
    return BakedMesh(name="m", positions=points.astype(np.float32), normals=np.zeros_like(points, np.float32),
                     indices=np.zeros((0, 3), np.uint32), material=Material(), transforms=np.eye(4)[None])


def test_hull_points_bake_without_scipy_and_qhull_gives_the_same_hull():
    """A mesh past DIRECT_POINTS is bounded without importing scipy (its import was most of
    a cold bake); `qhull=True` (per pose) takes qhull's vertices: the same hull."""
    code = ("import sys, numpy as np; from core import hull; from core.baked import BakedMesh; "
            "from core.scene import Material; p = np.random.default_rng(1).normal(size=(9000, 3)); "
            "m = BakedMesh('m', p, p, np.zeros((0, 3), np.uint32), Material(), np.eye(4)[None]); "
            "kept = hull.hull_points([m]); "
            "assert 'scipy.spatial' not in sys.modules, 'scipy imported'; print(len(kept))")
    out = subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT, capture_output=True, text=True)
    assert 0 < int(out.stdout) < 9000
    points = _rng.normal(size=(9000, 3))
    ours, theirs = hull.hull_points([_mesh(points)]), hull.hull_points([_mesh(points)], qhull=True)
    assert theirs is not None and ours is not None and len(theirs) <= len(ours)
    assert ConvexHull(ours).volume == pytest.approx(ConvexHull(theirs).volume, rel=1e-6)


def test_past_the_budget_qhull_takes_over(monkeypatch):
    calls = []
    monkeypatch.setattr(hull, "_hull", lambda p: calls.append(len(p)) or p[:8])
    monkeypatch.setattr(hull, "OUTER_MAX_POINTS", 12000)
    meshes = [_mesh(_rng.normal(size=(5000, 3))) for _ in range(3)]
    hull.hull_points(meshes)
    assert calls == [5000]  # the first two by _outer (10000 of the 12000), the third by qhull
