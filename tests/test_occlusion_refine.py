"""Visibility on large triangles (pipeline.occlusion's refinement, issue 30): a bake splits the
triangles whose traced visibility varies across them, so a 2-triangle floor holds the contact
shadow of a box standing on it; the split vertices carry every attribute linearly interpolated
(the surface and its texturing do not change); a mesh with nothing near it is left whole."""
from __future__ import annotations

import numpy as np

from core.baked import BakedMesh
from core.scene import Instance, Material, Mesh, Scene
from pipeline import occlusion
from pipeline.bake import build_baked
from pipeline.occlusion import Split, ambient_occlusion, split_mesh


def _quad(size: float, y: float = 0.0):
    """A square floor of 4 vertices and 2 triangles, facing +y."""
    h = size / 2
    pos = np.array([[-h, y, -h], [h, y, -h], [h, y, h], [-h, y, h]], np.float32)
    nrm = np.tile([0.0, 1.0, 0.0], (4, 1)).astype(np.float32)
    return pos, nrm, np.array([[0, 2, 1], [0, 3, 2]], np.uint32)


def _box(half: float, centre):
    """A closed box of 24 vertices (hard edges), faces wound outward."""
    pos, nrm, tris = [], [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            u, v = np.roll(np.eye(3), 1, axis=0)[axis], np.roll(np.eye(3), 2, axis=0)[axis]
            base = len(pos)
            for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                pos.append(np.asarray(centre) + half * (n + a * u + b * v))
                nrm.append(n)
            t = [[base, base + 1, base + 2], [base, base + 2, base + 3]]
            p = np.asarray(pos)
            if np.cross(p[base + 1] - p[base], p[base + 2] - p[base]) @ n < 0:
                t = [x[::-1] for x in t]
            tris += t
    return (np.asarray(pos, np.float32), np.asarray(nrm, np.float32), np.asarray(tris, np.uint32))


def _scene(*geometries) -> Scene:
    meshes = [Mesh(f"m{k}", *g) for k, g in enumerate(geometries)]
    return Scene(source="test.glb", format="test", meshes=meshes, materials=[Material()],
                 instances=[Instance(k, 0) for k in range(len(meshes))])


def _floor_visibility(mesh: BakedMesh, points: np.ndarray) -> np.ndarray:
    """The front visibility the raster interpolates at floor points (x, z): barycentric in the
    triangle of the (flat, y = 0) floor mesh that holds each."""
    vis = mesh.visibility()[:, 0]
    p = mesh.positions[:, [0, 2]].astype(np.float64)
    out = np.full(len(points), np.nan)
    for t in mesh.indices:
        a, b, c = p[t]
        m = np.array([b - a, c - a]).T
        if abs(np.linalg.det(m)) < 1e-12:
            continue
        uv = np.linalg.solve(m, (points - a).T).T
        w = np.stack([1 - uv.sum(1), uv[:, 0], uv[:, 1]], 1)
        inside = (w >= -1e-6).all(1) & np.isnan(out)
        out[inside] = w[inside] @ vis[t]
    assert not np.isnan(out).any()
    return out


def test_floor_beside_a_box_darkens():
    """A unit box on a 2-triangle floor of side 8: per vertex the floor's four corners see open
    sky, so the floor beside the box read as open; split where its visibility varies, it is
    darker there than far from the box, as a path tracer finds it."""
    baked = build_baked(_scene(_quad(8.0), _box(0.5, (0.0, 0.5, 0.0))), options={"occlusion": True})
    floor = baked.meshes[0]
    assert len(floor.positions) > 4 and len(floor.visibility()) == len(floor.positions)
    assert baked.manifest["stats"]["occlusion"]["vertices_added"] == \
        sum(len(m.positions) for m in baked.meshes) - 4 - 24
    beside = _floor_visibility(floor, np.array([[0.6, 0.0], [-0.6, 0.0], [0.0, 0.6], [0.0, -0.6]]))
    far = _floor_visibility(floor, np.array([[3.8, 3.8], [-3.8, 3.8], [3.0, -3.5]]))
    # the box hides about a quarter of the sky 0.1 from its face (the corners' 1.0 before)
    assert beside.max() < 0.85, beside
    assert far.min() > 0.95, far
    # the split floor is the same surface: flat, its outline the quad's, facing up
    assert np.all(floor.positions[:, 1] == 0.0) and np.abs(floor.positions).max() == 4.0
    e = np.cross(*(floor.positions[floor.indices[:, k]] - floor.positions[floor.indices[:, 0]]
                   for k in (1, 2)))
    assert np.all(e[:, 1] > 0)  # every triangle keeps the winding
    np.testing.assert_allclose(0.5 * e[:, 1].sum(), 64.0, rtol=1e-5)  # and they tile the quad


def test_nothing_near_keeps_the_mesh():
    """A convex box alone: every vertex and midpoint sees open sky, so no edge splits and the
    bake holds the very arrays it held without the refinement (and so draws the same frame)."""
    box = _box(0.5, (0.0, 0.0, 0.0))
    baked = build_baked(_scene(box), options={"occlusion": True})
    (mesh,) = baked.meshes
    assert baked.manifest["stats"]["occlusion"]["vertices_added"] == 0
    np.testing.assert_array_equal(mesh.positions, box[0])
    np.testing.assert_array_equal(mesh.indices, box[2])
    plain = ambient_occlusion([BakedMesh("m0", *box, Material(), np.eye(4)[None])],
                              np.asarray(baked.bounds), refine=False)
    np.testing.assert_array_equal(mesh.ao, plain.ao[0])
    np.testing.assert_array_equal(mesh.bent, plain.bent[0])


def test_split_attributes_interpolate_exactly():
    """On a floor whose every attribute is an affine function of position, each split vertex's
    attributes are that function of its position: linear along the edges, the texturing and
    shading do not move."""
    pos, nrm, tris = _quad(8.0)

    def affine(p: np.ndarray, rows: int, seed: int) -> np.ndarray:
        r = np.random.default_rng(seed)
        return (p.astype(np.float64) @ r.uniform(-1, 1, (3, rows)) + r.uniform(-1, 1, rows)).astype(np.float32)

    tilt = (nrm + affine(pos, 3, 1) * 0.1).astype(np.float32)
    mesh = Mesh("floor", pos, tilt, tris, tangents=affine(pos, 4, 2), uv0=affine(pos, 2, 3),
                uv1=affine(pos, 2, 4), colors=affine(pos, 4, 5))
    scene = _scene(_box(0.5, (0.0, 0.5, 0.0)))
    scene.meshes.insert(0, mesh)
    scene.instances = [Instance(0, 0), Instance(1, 0)]
    floor = build_baked(scene, options={"occlusion": True}).meshes[0]
    assert len(floor.positions) > 4
    p = floor.positions
    for name, rows, seed in (("tangents", 4, 2), ("uv0", 2, 3), ("uv1", 2, 4), ("colors", 4, 5)):
        np.testing.assert_allclose(getattr(floor, name), affine(p, rows, seed), atol=2e-5, err_msg=name)
    np.testing.assert_allclose(floor.normals, nrm[:1] + affine(p, 3, 1) * 0.1, atol=2e-5)


def test_split_mesh_carries_interior_and_budget(monkeypatch):
    """split_mesh interpolates the interior vectors too (a glass variant's), and the refinement
    never adds more vertices than its stated budget."""
    pos, nrm, tris = _quad(2.0)
    interior = np.arange(12, dtype=np.float32).reshape(4, 3)
    mesh = BakedMesh("q", pos, nrm, tris, Material(), np.eye(4)[None], interior=interior)
    split = Split(np.array([[0, 2], [0, 4]]), np.array([[0, 4, 1], [4, 2, 1], [0, 3, 2]], np.uint32), depth=2)
    out = split_mesh(mesh, split)
    np.testing.assert_allclose(out.interior[4], (interior[0] + interior[2]) / 2)
    np.testing.assert_allclose(out.interior[5], (interior[0] + out.interior[4]) / 2)
    np.testing.assert_allclose(out.positions[5], (pos[0] + (pos[0] + pos[2]) / 2) / 2)
    # the vertex budget holds (the box on the floor adds hundreds without it)
    monkeypatch.setattr(occlusion, "REFINE_MAX_VERTICES", 40)
    baked = build_baked(_scene(_quad(8.0), _box(0.5, (0.0, 0.5, 0.0))), options={"occlusion": True})
    assert 0 < baked.manifest["stats"]["occlusion"]["vertices_added"] <= 40
    assert sum(len(m.positions) for m in baked.meshes) == 28 + baked.manifest["stats"]["occlusion"]["vertices_added"]


def test_placements_kept_apart_share_the_split(monkeypatch):
    """A floor placed twice, a box on one of them: the split is the mesh's (both placements
    draw it), each placement keeps its own visibility row over the split vertices, and only
    the one with the box is dark beside it."""
    # each probe is traced per placement: both big triangles' lattices fit twice the rays
    monkeypatch.setattr(occlusion, "REFINE_MAX_RAYS", 2 * occlusion.REFINE_MAX_RAYS)
    scene = _scene(_quad(8.0), _box(0.5, (0.0, 0.5, 0.0)))
    far = np.eye(4)
    far[0, 3] = 10.0  # beside: no box shades it
    scene.instances.append(Instance(0, 0, matrix=far))
    baked = build_baked(scene, options={"occlusion": True})
    floor = next(m for m in baked.meshes if len(m.transforms) == 2)
    n = len(floor.positions)
    assert n > 4 and floor.ao_per_placement and floor.ao.shape == (2 * n, 2)
    at = np.array([[0.6, 0.0], [-0.6, 0.0], [0.0, 0.6], [0.0, -0.6]])
    near = np.argmin(np.abs(floor.transforms[:, 0, 3]))
    rows = [floor.visibility(k)[:, 0] for k in range(2)]
    beside = [_floor_visibility(dataclass_with(floor, rows[k]), at) for k in range(2)]
    assert beside[near].max() < 0.85 and beside[1 - near].min() > 0.95, beside


def dataclass_with(mesh: BakedMesh, vis: np.ndarray) -> BakedMesh:
    """`mesh` with one shared visibility row (both sides `vis`)."""
    import dataclasses

    from core.baked import quantise_visibility
    return dataclasses.replace(mesh, transforms=mesh.transforms[:1],
                               ao=quantise_visibility(np.stack([vis, vis], axis=1)))
