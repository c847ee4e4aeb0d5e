"""Subdivision surfaces: ingest keeps the cage (pxr's count), bake refines coarse cages."""
from __future__ import annotations

import numpy as np
import pytest

from pipeline.bake import build_baked
from pipeline.ingest import load_scene
from pipeline.usd.subdivision import levels_for, loop_step

CUBE = """#usda 1.0
(
    metersPerUnit = 1
)
def Mesh "Cube"
{{
    int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]
    int[] faceVertexIndices = [0, 1, 3, 2, 2, 3, 5, 4, 4, 5, 7, 6, 6, 7, 1, 0, 1, 7, 5, 3, 6, 0, 2, 4]
    point3f[] points = [(-1, -1, 1), (1, -1, 1), (-1, 1, 1), (1, 1, 1), (-1, 1, -1), (1, 1, -1),
                        (-1, -1, -1), (1, -1, -1)]
    texCoord2f[] primvars:st = [{st}] (interpolation = "faceVarying")
    uniform token subdivisionScheme = "{scheme}"
}}
"""


def cube(tmp_path, scheme="catmullClark"):
    st = ", ".join(f"({i % 4 * 0.25}, {i // 4 * 0.1})" for i in range(24))  # every corner its own
    path = tmp_path / f"cube_{scheme}.usda"
    path.write_text(CUBE.format(scheme=scheme, st=st))
    return path


def watertight(positions, indices) -> bool:
    """Every edge of the position-welded surface is shared by exactly two triangles."""
    _, weld = np.unique(positions, axis=0, return_inverse=True)
    tri = weld.reshape(-1)[indices]
    edges = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return bool(np.all(counts == 2))


@pytest.mark.parametrize("scheme", ["catmullClark", "loop"])
def test_coarse_cage_is_refined_at_bake_and_stays_closed(tmp_path, scheme):
    scene = load_scene(cube(tmp_path, scheme))
    assert scene.triangle_count == 12 and scene.meshes[0].subdivision == scheme  # the cage
    baked = build_baked(scene)
    mesh = baked.meshes[0]
    assert len(mesh.indices) == 12 * 16  # two levels of a 12-triangle cage
    assert baked.manifest["stats"]["refined"] == 1
    r = np.linalg.norm(mesh.positions, axis=1)
    assert r.max() / r.min() < 1.25  # rounded (the cube's corners are sqrt(3) = 1.73 x its faces)
    assert watertight(mesh.positions, mesh.indices)  # welded across the split UV seams
    assert mesh.uv0 is not None and len(mesh.uv0) == len(mesh.positions)
    assert np.allclose(np.linalg.norm(mesh.normals, axis=1), 1, atol=1e-5)
    assert np.all(np.einsum("ij,ij->i", mesh.normals, mesh.positions) > 0)  # outward


def test_open_cage_keeps_its_corners(tmp_path):
    path = tmp_path / "quad.usda"
    path.write_text(CUBE.format(scheme="catmullClark", st="(0, 0)").replace(
        "[4, 4, 4, 4, 4, 4]", "[4]").replace("[0, 1, 3, 2, 2, 3, 5, 4, 4, 5, 7, 6, 6, 7, 1, 0, "
                                             "1, 7, 5, 3, 6, 0, 2, 4]", "[0, 1, 3, 2]")
                    .replace('(interpolation = "faceVarying")', '(interpolation = "constant")'))
    mesh = build_baked(load_scene(path)).meshes[0]
    assert len(mesh.indices) == 32
    np.testing.assert_allclose(mesh.positions.min(0)[:2], (-1, -1), atol=1e-6)
    np.testing.assert_allclose(mesh.positions.max(0)[:2], (1, 1), atol=1e-6)


def test_unauthored_scheme_is_drawn_as_the_cage(tmp_path):
    path = cube(tmp_path)
    path.write_text(path.read_text().replace('uniform token subdivisionScheme = "catmullClark"', ""))
    assert load_scene(path).meshes[0].subdivision is None


def test_scheme_none_and_levels_zero_keep_the_cage(tmp_path):
    assert len(build_baked(load_scene(cube(tmp_path, "none"))).meshes[0].indices) == 12
    scene = load_scene(cube(tmp_path))
    assert len(build_baked(scene, options={"subdivision_levels": 0}).meshes[0].indices) == 12


def test_teapot_cage_refined_two_levels(assets):
    scene = load_scene(assets / "usd/Teapot/Teapot.usd")
    assert scene.triangle_count == 2472
    assert build_baked(scene).manifest["stats"]["triangles"] == 2472 * 16


def test_levels_follow_the_cage_size_and_loop_step_is_linear_in_attributes():
    assert [levels_for(n) for n in (100, 10_000, 100_000)] == [2, 1, 0]
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    new_pos, tri, attrs, _ = loop_step(pos, np.array([[0, 1, 2]]), {"uv0": pos[:, :2].copy()})
    assert len(tri) == 4 and len(new_pos) == 6
    np.testing.assert_allclose(attrs["uv0"][3:], [[0.5, 0], [0, 0.5], [0.5, 0.5]], atol=1e-12)


# The cube's 12 edges as chains of 2 points, and its 8 corners.
EDGES = [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 6), (1, 7), (2, 4), (3, 5)]


def creased(tmp_path, sharpness=None, corners=None, name="creased"):
    text = cube(tmp_path).read_text()
    extra = ""
    if isinstance(sharpness, (int, float)):
        sharpness = ", ".join([str(sharpness)] * 12)  # one per chain
    if sharpness is not None:
        extra += (f"    int[] creaseIndices = [{', '.join(f'{a}, {b}' for a, b in EDGES)}]\n"
                  f"    int[] creaseLengths = [{', '.join(['2'] * 12)}]\n"
                  f"    float[] creaseSharpnesses = [{sharpness}]\n")
    if corners is not None:
        extra += f"    int[] cornerIndices = [0, 1, 2, 3, 4, 5, 6, 7]\n" \
                 f"    float[] cornerSharpnesses = [{', '.join([str(corners)] * 8)}]\n"
    path = tmp_path / f"{name}.usda"
    path.write_text(text.replace("    uniform token subdivisionScheme", extra + "    uniform token subdivisionScheme"))
    return path


def off_cube(mesh) -> float:
    """Mean distance of the refined points from the cage cube's surface (0: still a cube)."""
    return float(np.mean(1.0 - np.abs(mesh.positions).max(axis=1)))


def test_infinitely_sharp_creases_keep_the_cube(tmp_path):
    mesh = build_baked(load_scene(creased(tmp_path, 10))).meshes[0]
    assert len(mesh.indices) == 12 * 16
    assert off_cube(mesh) < 1e-6  # every point on a face: edges stay sharp lines
    np.testing.assert_allclose(np.abs(mesh.positions).max(axis=0), 1.0, atol=1e-6)  # corners too
    assert watertight(mesh.positions, mesh.indices)
    # shading breaks along the crease: every normal is its face's (no soft band at the edges)
    np.testing.assert_allclose(np.abs(mesh.normals).max(axis=1), 1.0, atol=1e-5)


def test_semi_sharp_creases_round_less_as_sharpness_grows(tmp_path):
    smooth = off_cube(build_baked(load_scene(cube(tmp_path))).meshes[0])
    one = off_cube(build_baked(load_scene(creased(tmp_path, 1, name="one"))).meshes[0])
    half = off_cube(build_baked(load_scene(creased(tmp_path, 0.5, name="half"))).meshes[0])
    assert smooth > half > one > 0.0


def test_authored_corners_stay_put(tmp_path):
    mesh = build_baked(load_scene(creased(tmp_path, corners=10))).meshes[0]
    corners = np.abs(np.abs(mesh.positions) - 1).max(axis=1) < 1e-6
    assert corners.any()  # (+-1, +-1, +-1) survive
    welded = np.unique(mesh.positions[corners], axis=0)
    assert len(welded) == 8
    smooth = build_baked(load_scene(cube(tmp_path))).meshes[0]
    assert not (np.abs(np.abs(smooth.positions) - 1).max(axis=1) < 1e-6).any()


def test_mismatched_crease_arrays_are_a_warning(tmp_path):
    path = creased(tmp_path, "1, 2")  # two values for twelve chains of one edge
    scene = load_scene(path)
    assert any("creases ignored" in w for w in scene.warnings)
    assert scene.meshes[0].creases is None


def test_a_crease_chain_with_one_sharpness_per_edge(tmp_path):
    path = cube(tmp_path)
    path.write_text(path.read_text().replace("    uniform token subdivisionScheme",
                                             "    int[] creaseIndices = [0, 1, 3, 2, 0]\n"
                                             "    int[] creaseLengths = [5]\n"
                                             "    float[] creaseSharpnesses = [10, 10, 0, 2]\n"
                                             "    uniform token subdivisionScheme"))
    cage = load_scene(path).meshes[0].cage  # catmullClark: the creases are the cage's
    assert cage is not None and list(cage.crease_sharpness) == [10, 10, 2]  # the 0 is smooth
    assert cage.crease_edges.tolist() == [[0, 1], [1, 3], [2, 0]]
    loop = cube(tmp_path, "loop")
    loop.write_text(path.read_text().replace('"catmullClark"', '"loop"'))
    creases = load_scene(loop).meshes[0].creases  # loop: by position, on the triangles
    assert creases is not None and list(creases.edge_sharpness) == [10, 10, 2]
    np.testing.assert_allclose(creases.edges[0], [(-1, -1, 1), (1, -1, 1)])


# -- Catmull-Clark on the polygons (OpenSubdiv's rules, as Storm refines) ---------------------

def refined(path, levels=2, **options):
    return build_baked(load_scene(path), options={"subdivision_levels": levels, **options}).meshes


def points_of(mesh) -> np.ndarray:
    return np.unique(np.round(mesh.positions.astype(np.float64), 5), axis=0)


def same_set(a: np.ndarray, b: np.ndarray, tol=1e-5) -> bool:
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    return bool(d.min(axis=1).max() < tol and d.min(axis=0).max() < tol)


def test_cube_one_level_is_catmull_clarks_points(tmp_path):
    """Hand-computed: face points (0, 0, +-1) ...; edge points (a + b + f1 + f2) / 4, e.g.
    (0, 3/4, 3/4); vertex points (n-2)/n v + (sum of edge neighbours + sum of face points) / n^2
    with n = 3: 1/3 + 1/9 + 1/9 = 5/9 of each corner."""
    mesh = refined(cube(tmp_path), 1)[0]
    assert len(mesh.indices) == 6 * 4 * 2  # each quad into four, two triangles each
    perms = [(0, 1, 2), (1, 2, 0), (2, 0, 1)]
    expected = [np.array(c) * 5 / 9 for c in np.stack(np.meshgrid(*[[-1, 1]] * 3), -1).reshape(-1, 3)]
    expected += [np.array((0, sy * 0.75, sz * 0.75))[list(p)] for p in perms
                 for sy in (-1, 1) for sz in (-1, 1)]
    expected += [np.array((s, 0, 0))[list(p)] for p in perms for s in (-1, 1)]
    assert same_set(points_of(mesh), np.array(expected, float))


def test_cube_corner_converges_to_the_limit_point(tmp_path):
    """The Catmull-Clark limit of a valence-3 corner (Halstead et al.'s mask, as OpenSubdiv's
    assignSmoothLimitMask: 3/8 itself, 1/6 each edge neighbour, 1/24 each diagonal) is (1/2, 1/2,
    1/2) for the unit cube's (1, 1, 1); refined points approach it."""
    far = [float(refined(cube(tmp_path), n)[0].positions.sum(axis=1).max()) / 3 for n in (1, 2, 5)]
    assert far[0] == pytest.approx(5 / 9, abs=1e-6)
    assert far[0] > far[1] > far[2] > 0.5
    assert far[2] == pytest.approx(0.5, abs=2e-4)


def test_catmull_clark_keeps_the_cubes_symmetry_that_loop_breaks(tmp_path):
    """Loop's rules on the triangulated cage lean along each face's diagonal; Catmull-Clark on
    the quads is symmetric under the cube's mirrors, as Storm (OpenSubdiv) draws it."""
    mirror = np.array([-1.0, 1.0, 1.0])
    cc = points_of(refined(cube(tmp_path))[0])
    loop = points_of(refined(cube(tmp_path, "loop"))[0])
    assert same_set(cc, cc * mirror) and same_set(cc, cc[:, [1, 0, 2]])
    assert not same_set(loop, loop * mirror)


GRID = """#usda 1.0
(
    metersPerUnit = 1
)
def Mesh "Grid"
{{
    int[] faceVertexCounts = [4, 4, 4, 4, 4, 4, 4, 4, 4]
    int[] faceVertexIndices = [{indices}]
    point3f[] points = [{points}]
    texCoord2f[] primvars:st = [{st}] (interpolation = "{interp}")
{st_indices}    uniform token subdivisionScheme = "catmullClark"
{extra}}}
"""


def grid(tmp_path, extra="", name="grid", bump=0.0, interp="vertex"):
    """A flat open 3 x 3 quad grid over [0, 3]^2, st = xy / 3 (the centre-left inner point's st
    moved by `bump`), one value a point; `interp` faceVarying: the same values indexed by the
    faces' corners (one face-varying region)."""
    pts = [(x, y) for y in range(4) for x in range(4)]
    idx = [v for y in range(3) for x in range(3)
           for v in (y * 4 + x, y * 4 + x + 1, y * 4 + x + 5, y * 4 + x + 4)]
    st = [(x / 3 + (bump if (x, y) == (1, 1) else 0), y / 3) for x, y in pts]
    path = tmp_path / f"{name}.usda"
    path.write_text(GRID.format(indices=", ".join(map(str, idx)),
                                points=", ".join(f"({x}, {y}, 0)" for x, y in pts),
                                st=", ".join(f"({u}, {v})" for u, v in st), extra=extra,
                                interp=interp, st_indices="" if interp != "faceVarying" else
                                f"    int[] primvars:st:indices = [{', '.join(map(str, idx))}]\n"))
    return path


def test_boundary_rules_on_an_open_grid(tmp_path):
    corner = refined(grid(tmp_path))[0]  # edgeAndCorner, USD's fallback
    np.testing.assert_allclose(corner.positions[:, :2].min(0), (0, 0), atol=1e-6)
    np.testing.assert_allclose(corner.positions[:, :2].max(0), (3, 3), atol=1e-6)
    assert ((np.abs(corner.positions[:, :2] - 1.5).max(axis=1) == 1.5).sum() > 4)  # border kept
    edge = refined(grid(tmp_path, '    uniform token interpolateBoundary = "edgeOnly"\n', "edge"))[0]
    def nearest_corner(m):
        return m.positions[np.argmin(np.linalg.norm(m.positions[:, :2], axis=1)), :2]
    np.testing.assert_allclose(nearest_corner(corner), (0, 0), atol=1e-6)
    # edgeOnly: the corner is smoothed as a border point, 3/4 v + 1/8 (a + b) = (1/8, 1/8)
    # after one level, toward the cubic B-spline's limit (v 4 + a + b) / 6 = (1/6, 1/6)
    assert np.all((nearest_corner(edge) > 0.125) & (nearest_corner(edge) < 1 / 6))
    # ... along a border that stays on the cage's border line x = 0 (the crease rule)
    assert np.isclose(edge.positions[:, 0], 0, atol=1e-6).sum() > 4
    none = refined(grid(tmp_path, '    uniform token interpolateBoundary = "none"\n', "none"))[0]
    assert len(none.indices) == 4 * 4 * 2  # only the centre face (no border vertex) is drawn
    assert none.positions[:, :2].min() > 1.0 - 1e-6 and none.positions[:, :2].max() < 2.0 + 1e-6


def test_uvs_follow_the_surface_and_face_varying_rules(tmp_path):
    """st = xy / 3 is affine, which Catmull-Clark reproduces: refined st match refined xy / 3
    (cornersPlus1, USD's fallback). With the inner point's st moved, `all` (bilinear) keeps the
    moved st at that point's child, cornersPlus1 smooths it."""
    mesh = refined(grid(tmp_path))[0]
    uv = mesh.uv0.astype(np.float64)
    np.testing.assert_allclose(uv[:, 0], mesh.positions[:, 0] / 3, atol=1e-6)
    np.testing.assert_allclose(1 - uv[:, 1], mesh.positions[:, 1] / 3, atol=1e-6)  # glTF's v
    at = {}
    for rule in ("cornersPlus1", "all"):
        extra = f'    uniform token faceVaryingLinearInterpolation = "{rule}"\n'
        m = refined(grid(tmp_path, extra, rule, bump=0.1, interp="faceVarying"))[0]
        # the child of cage point (1, 1): a flat regular grid's points stay put
        i = np.argmin(np.linalg.norm(m.positions[:, :2] - 1.0, axis=1))
        np.testing.assert_allclose(m.positions[i, :2], (1, 1), atol=1e-6)
        at[rule] = float(m.uv0[i, 0]) - 1 / 3
    assert at["all"] == pytest.approx(0.1, abs=1e-6)
    # smoothed toward its neighbours: 1/2 of itself + 1/16 of the four face points (which
    # hold 1/4 of it) after one level = 0.05625, less after two
    assert 0.0 < at["cornersPlus1"] < 0.05625


def test_subsets_are_refined_as_one_surface(tmp_path):
    """A GeomSubset's faces are refined with the whole cage (OpenSubdiv refines the mesh, Hydra
    draws the subsets of the result): no border, no crease along the subset's edge."""
    path = cube(tmp_path)
    text = path.read_text().rstrip()[:-1] + (
        '    def GeomSubset "top" (prepend apiSchemas = ["MaterialBindingAPI"])\n    {\n'
        '        uniform token elementType = "face"\n        uniform token familyName = "materialBind"\n'
        '        int[] indices = [0, 1, 2]\n    }\n}\n')
    path.write_text(text)
    meshes = refined(path)
    assert len(meshes) == 2 and sum(len(m.indices) for m in meshes) == 12 * 16
    one = points_of(build_baked(load_scene(cube(tmp_path)), options={"subdivision_levels": 2}).meshes[0])
    both = np.unique(np.concatenate([points_of(m) for m in meshes]), axis=0)
    assert same_set(both, one)


TETRA = """#usda 1.0
(
    metersPerUnit = 1
)
def Mesh "Tetra"
{{
    int[] faceVertexCounts = [3, 3, 3, 3]
    int[] faceVertexIndices = [0, 2, 1, 0, 1, 3, 1, 2, 3, 2, 0, 3]
    point3f[] points = [(1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)]
    uniform token subdivisionScheme = "catmullClark"
{extra}}}
"""


def test_triangle_subdivision_rule_smooth(tmp_path):
    """Edge points between two triangles: 1/4 of each end and of each face point by default;
    with triangleSubdivisionRule = smooth, 0.47 of each face point, 0.03 of each end
    (OpenSubdiv's TRI_SUB_SMOOTH)."""
    out = {}
    for rule in ("catmullClark", "smooth"):
        path = tmp_path / f"{rule}.usda"
        path.write_text(TETRA.format(extra=f'    uniform token triangleSubdivisionRule = "{rule}"\n'))
        out[rule] = points_of(refined(path, 1)[0])
    p = np.array([(1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)], float)
    f1, f2 = p[[0, 1, 2]].mean(0), p[[0, 1, 3]].mean(0)  # the faces either side of edge 0-1
    for rule, vw, fw in (("catmullClark", 0.25, 0.25), ("smooth", 0.03, 0.47)):
        e = vw * (p[0] + p[1]) + fw * (f1 + f2)
        assert np.linalg.norm(out[rule] - e, axis=1).min() < 1e-5, rule


# -- Each primvar by its own interpolation (OpenSubdiv refines each channel on its own) ------

def grid_corners(tmp_path, name, primvars: str) -> "object":
    """The open 3 x 3 grid with `primvars` (USD lines) instead of its st."""
    text = grid(tmp_path, name=name).read_text()
    start = text.index("    texCoord2f[] primvars:st")
    end = text.index("\n", start) + 1
    path = tmp_path / f"{name}.usda"
    path.write_text(text[:start] + primvars + text[end:])
    return path


FACE_CORNERS = [((x, y), (x + 1, y), (x + 1, y + 1), (x, y + 1)) for y in range(3) for x in range(3)]


def per_corner(value) -> str:
    """`value(face_x, face_y, point)` at each face corner, as a USD array's items."""
    return ", ".join(str(tuple(value(face[0][0], face[0][1], p))) for face in FACE_CORNERS for p in face)


def values_at(mesh, point, attr="uv0", column=0) -> np.ndarray:
    near = np.linalg.norm(mesh.positions[:, :2] - np.asarray(point), axis=1) < 1e-6
    assert near.any()
    return np.unique(np.round(getattr(mesh, attr)[near, column].astype(np.float64), 6))


# displayColor red 0 left of x = 1, 1 right of it: a face-varying seam up the line x = 1
SEAM_COLOR = ('    color3f[] primvars:displayColor = [{}] (interpolation = "faceVarying")\n'
              .format(per_corner(lambda fx, fy, p: (0.0 if fx == 0 else 1.0, 0.5, 0.5))))


@pytest.mark.parametrize("interp", ["vertex", "faceVarying"])
def test_a_primvar_is_not_cut_by_another_primvars_seam(tmp_path, interp):
    """st smooth (its bump at cage point (1, 1) one level on: 1/2 b + 4 (b / 4) / 16 = 9/16 b,
    the interior vertex rule) though displayColor has a seam through that point; refined on
    one shared topology it took the seam's crease rule, 3/4 b."""
    bump = 0.1
    if interp == "vertex":
        st = ", ".join(f"({x / 3 + (bump if (x, y) == (1, 1) else 0)}, {y / 3})"
                       for y in range(4) for x in range(4))
    else:
        st = per_corner(lambda fx, fy, p: (p[0] / 3 + (bump if p == (1, 1) else 0), p[1] / 3))
    path = grid_corners(tmp_path, interp, f'    texCoord2f[] primvars:st = [{st}] '
                        f'(interpolation = "{interp}")\n' + SEAM_COLOR)
    mesh = refined(path, 1)[0]
    assert mesh.colors is not None
    np.testing.assert_allclose(values_at(mesh, (1, 1), "colors"), [0, 1], atol=1e-6)  # still cut
    np.testing.assert_allclose(values_at(mesh, (1, 1)), [1 / 3 + 9 / 16 * bump], atol=1e-6)


def test_varying_primvars_are_bilinear(tmp_path):
    """A varying primvar is interpolated linearly over each face (OpenSubdiv's
    InterpolateVarying): the bumped point's child keeps its value, an edge's midpoint the mean
    of its ends, a face's centre the mean of its corners; a vertex primvar is smoothed."""
    bump = 0.1
    st = ", ".join(f"({x / 3 + (bump if (x, y) == (1, 1) else 0)}, {y / 3})"
                   for y in range(4) for x in range(4))
    out = {}
    for interp in ("varying", "vertex"):
        path = grid_corners(tmp_path, interp, f'    texCoord2f[] primvars:st = [{st}] '
                            f'(interpolation = "{interp}")\n')
        out[interp] = refined(path, 1)[0]
    m = out["varying"]
    np.testing.assert_allclose(values_at(m, (1, 1)), [1 / 3 + bump], atol=1e-6)
    np.testing.assert_allclose(values_at(m, (1.5, 1)), [0.5 + bump / 2], atol=1e-6)
    np.testing.assert_allclose(values_at(m, (1.5, 1.5)), [0.5 + bump / 4], atol=1e-6)
    np.testing.assert_allclose(values_at(out["vertex"], (1, 1)), [1 / 3 + 9 / 16 * bump], atol=1e-6)


@pytest.mark.parametrize("case", ["dart", "one_face_region"])
def test_corners_plus2_sharpens_darts_and_both_values_beside_a_corner(tmp_path, case):
    """faceVaryingLinearInterpolation cornersPlus2 (OpenSubdiv's FVAR_LINEAR_CORNERS_PLUS2).
    dart: a seam on the cage edge (1, 0)-(1, 1) only (face (0, 0)'s u at (1, 0) is 0.3 more),
    so interior point (1, 1) has one value: cornersPlus1 moves it by the crease rule along the
    seam, 3/4 v + 1/8 (1/3 + 0.3 + 1/3) = 1/3 + 0.0375; cornersPlus2 keeps it, 1/3.
    one_face_region: face (0, 0) has its own u at (1, 1) (0.3 more): that one-face value is a
    corner under both; the other (three faces) is a crease under cornersPlus1,
    3/4 (1/3) + 1/8 (u(1, 0) + u(0, 1)) = 1/4 + 1/8 (1/3 + 0) = 7/24, kept (1/3) by cornersPlus2."""
    odd = (1, 0) if case == "dart" else (1, 1)
    st = per_corner(lambda fx, fy, p: (p[0] / 3 + (0.3 if (fx, fy) == (0, 0) and p == odd else 0),
                                       p[1] / 3))
    got = {}
    for rule in ("cornersPlus1", "cornersPlus2"):
        path = grid_corners(tmp_path, f"{case}_{rule}",
                            f'    texCoord2f[] primvars:st = [{st}] (interpolation = "faceVarying")\n'
                            f'    uniform token faceVaryingLinearInterpolation = "{rule}"\n')
        got[rule] = values_at(refined(path, 1)[0], (1, 1))
    if case == "dart":
        np.testing.assert_allclose(got["cornersPlus1"], [1 / 3 + 0.0375], atol=1e-6)
        np.testing.assert_allclose(got["cornersPlus2"], [1 / 3], atol=1e-6)
    else:
        np.testing.assert_allclose(got["cornersPlus1"], [7 / 24, 1 / 3 + 0.3], atol=1e-6)
        np.testing.assert_allclose(got["cornersPlus2"], [1 / 3, 1 / 3 + 0.3], atol=1e-6)
