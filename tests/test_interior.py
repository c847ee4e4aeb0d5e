"""Interior vectors (paper §4.2.3.2): vertex -> exit point along -normal, object space."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from core.scene import Instance, Material, Mesh, Scene
from pipeline.bake import build_baked
from pipeline.interior.vectors import interior_vectors


def _run(m: trimesh.Trimesh, normals=None):
    return interior_vectors(m.vertices, m.vertex_normals if normals is None else normals, m.faces)


def _scene(m: trimesh.Trimesh, matrix=np.eye(4), transmission=1.0) -> Scene:
    mesh = Mesh("m", m.vertices.astype(np.float32), m.vertex_normals.astype(np.float32),
                m.faces.astype(np.uint32))
    glass = Material("glass", transmission=transmission, roughness=0.0, metallic=0.0)
    return Scene("test", "test", meshes=[mesh], materials=[glass],
                 instances=[Instance(0, 0, np.asarray(matrix, np.float64))])


def test_unit_sphere_vectors_span_the_diameter_along_the_normal():
    m = trimesh.creation.icosphere(subdivisions=4)
    r = _run(m)
    length = np.linalg.norm(r.vectors, axis=1)
    assert r.vectors.dtype == np.float32 and r.vectors.shape == (len(m.vertices), 3)
    assert r.misses == 0 and r.degenerate == 0 and r.rays >= len(m.vertices)
    np.testing.assert_allclose(length, 2.0, atol=0.01)
    # along the negated normal: unit vectors agree with -n
    np.testing.assert_allclose(r.vectors / length[:, None], -m.vertex_normals, atol=1e-5)
    assert r.rays_per_second > 0


def test_cube_split_and_smooth_normals():
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    smooth = _run(box)  # corner normals point along the diagonal: to the opposite corner
    np.testing.assert_allclose(np.linalg.norm(smooth.vectors, axis=1), 2 * np.sqrt(3), rtol=1e-3)
    split = box.copy()
    split.unmerge_vertices()  # seam-split: one vertex per face corner, face normals
    r = _run(split, np.repeat(split.face_normals, 3, axis=0))
    # the ray from a corner runs along two face planes (grazing) and must still reach the far face
    assert r.misses == 0
    np.testing.assert_allclose(np.linalg.norm(r.vectors, axis=1), 2.0, rtol=1e-3)


def test_ellipsoid_by_non_uniform_scale_transforms_correctly():
    sphere = trimesh.creation.icosphere(subdivisions=4)
    matrix = np.diag([2.0, 0.5, 1.0, 1.0])
    matrix[:3, 3] = (5.0, -1.0, 3.0)
    baked = build_baked(_scene(sphere, matrix))
    mesh = baked.meshes[0]
    assert mesh.interior is not None
    world_vertex = mesh.positions @ matrix[:3, :3].T + matrix[:3, 3]
    world_vector = mesh.interior @ matrix[:3, :3].T
    exit_point = world_vertex + world_vector - matrix[:3, 3]
    # exit points lie on the world-space ellipsoid x^2/4 + y^2/0.25 + z^2 = 1
    on_surface = (exit_point[:, 0] / 2) ** 2 + (exit_point[:, 1] / 0.5) ** 2 + exit_point[:, 2] ** 2
    np.testing.assert_allclose(on_surface, 1.0, atol=0.02)
    # and the chord is as long as the scaled object-space one (not the unscaled 2)
    along_x = np.abs(sphere.vertex_normals[:, 0]) > 0.999
    np.testing.assert_allclose(np.linalg.norm(world_vector[along_x], axis=1), 4.0, rtol=0.01)


def test_ellipsoid_mesh_rays_follow_its_own_normals():
    e = trimesh.creation.icosphere(subdivisions=4)
    e.apply_scale((3.0, 1.0, 1.0))
    r = _run(e)
    hit = e.vertices + r.vectors
    np.testing.assert_allclose((hit[:, 0] / 3) ** 2 + hit[:, 1] ** 2 + hit[:, 2] ** 2, 1.0, atol=0.03)
    assert r.misses == 0


def test_open_cylinder_misses_are_counted_and_finite():
    c = trimesh.creation.cylinder(radius=1.0, height=2.0, sections=32)
    keep = np.abs(c.face_normals[:, 2]) < 0.5  # drop both caps
    tube = trimesh.Trimesh(c.vertices, c.faces[keep], process=False)
    tube.remove_unreferenced_vertices()
    r = _run(tube)
    length = np.linalg.norm(r.vectors, axis=1)
    assert np.all(np.isfinite(r.vectors))
    assert 0 < r.misses < len(tube.vertices)
    diagonal = np.linalg.norm(np.ptp(tube.vertices, axis=0))
    assert np.all(length <= diagonal + 1e-5)
    # whatever hit crossed the tube: about the diameter
    assert np.median(length) == pytest.approx(2.0, rel=0.02)


def test_flat_sheet_gets_zero_length_fallback():
    quad = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    r = _run(quad)
    assert r.misses == 4
    np.testing.assert_allclose(r.vectors, 0.0, atol=1e-6)


def test_several_shells_and_seams_and_bad_normals():
    small = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    big = trimesh.creation.icosphere(subdivisions=3, radius=2.0)
    big.apply_translation((10.0, 0.0, 0.0))
    both = trimesh.util.concatenate([small, big])
    normals = both.vertex_normals.copy()
    normals[0] = 0.0  # a vertex without a usable normal
    r = _run(both, normals)
    length = np.linalg.norm(r.vectors, axis=1)
    n_small = len(small.vertices)
    assert r.degenerate == 1 and np.all(r.vectors[0] == 0)
    np.testing.assert_allclose(length[1:n_small], 1.0, rtol=0.02)
    np.testing.assert_allclose(length[n_small:], 4.0, rtol=0.02)
    # a UV seam: the same vertex twice gets the same vector
    dup = trimesh.Trimesh(np.vstack([small.vertices, small.vertices[:5]]), small.faces, process=False)
    dn = np.vstack([small.vertex_normals, small.vertex_normals[:5]])
    rd = _run(dup, dn)
    np.testing.assert_array_equal(rd.vectors[:5], rd.vectors[-5:])


def test_far_from_origin_uses_scale_aware_epsilon():
    m = trimesh.creation.icosphere(subdivisions=3, radius=0.01)
    m.apply_translation((1000.0, -2000.0, 500.0))
    r = _run(m)
    assert r.misses == 0
    np.testing.assert_allclose(np.linalg.norm(r.vectors, axis=1), 0.02, rtol=0.03)


def test_torus_from_sample_assets(assets):
    from pipeline.ingest import load_scene
    scene = load_scene(assets / "mesh" / "torus.STL")
    mesh = scene.meshes[0]
    r = interior_vectors(mesh.positions, mesh.normals, mesh.indices)
    tube = np.min(np.ptp(mesh.positions, axis=0))  # the torus' thickness = tube diameter
    length = np.linalg.norm(r.vectors, axis=1)
    assert r.misses == 0 and np.all(np.isfinite(length))
    # every normal of a torus passes through the tube's centre circle: chord = tube diameter
    np.testing.assert_allclose(np.median(length), tube, rtol=0.01)
    assert np.mean(np.abs(length - tube) < 0.05 * tube) > 0.95


def test_only_transmissive_meshes_get_interior():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    scene = _scene(sphere)
    scene.materials.append(Material("paint", transmission=0.0))
    scene.instances.append(Instance(0, 1, np.eye(4)))
    scene.instances.append(Instance(0, 0, np.diag([2.0, 2.0, 2.0, 1.0])))
    baked = build_baked(scene)
    by_material = {m.material.name: m for m in baked.meshes}
    assert by_material["paint"].interior is None
    assert by_material["glass"].interior.shape == (len(sphere.vertices), 3)
    assert len(by_material["glass"].transforms) == 2  # instances of one pair grouped
    assert baked.manifest["stats"]["interior"]["rays"] >= len(sphere.vertices)


def test_hit_at_almost_zero_distance_is_skipped():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    p0, n0 = sphere.vertices[0], sphere.vertex_normals[0]
    eps = 1e-4 * np.linalg.norm(np.ptp(sphere.vertices, axis=0))
    # a small patch just under the vertex (a decal, an inner skin): the ray starts in front of it
    u = np.cross(n0, [0.0, 0.0, 1.0] if abs(n0[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(n0, u)
    centre = p0 - n0 * 1.5 * eps
    patch = np.array([centre + 0.01 * u, centre - 0.01 * u + 0.01 * v, centre - 0.01 * u - 0.01 * v])
    vertices = np.vstack([sphere.vertices, patch])
    faces = np.vstack([sphere.faces, [[len(sphere.vertices) + i for i in range(3)]]])
    normals = np.vstack([sphere.vertex_normals, np.repeat([n0], 3, axis=0)])
    r = interior_vectors(vertices, normals, faces)
    assert np.linalg.norm(r.vectors[0]) == pytest.approx(2.0, abs=0.01)
    assert r.rays > len(vertices)  # the grazed ray was continued


def _embreex_reference(positions, normals, indices, epsilon):
    """The pass as it was before pipeline.interior.embree: embreex's own scene, one ray at a time.
    Kept here to hold the new engine to the old results."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    from pipeline.interior.vectors import GRAZE_RETRIES, _box_exit
    p = np.ascontiguousarray(positions, np.float32)
    n = np.asarray(normals, np.float32)
    tris = np.ascontiguousarray(indices, np.int32).reshape(-1, 3)
    length = np.linalg.norm(n, axis=1)
    usable = np.isfinite(length) & (length > 1e-8)
    direction = np.zeros_like(p)
    direction[usable] = -n[usable] / length[usable, None]
    todo = np.flatnonzero(usable)
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, p[tris])
    travelled = np.full(len(p), epsilon, np.float32)
    hit = np.zeros(len(p), bool)
    live = todo
    for attempt in range(GRAZE_RETRIES + 1):
        if len(live) == 0:
            break
        d = direction[live]
        q = scene.run(p[live] + d * travelled[live, None], d, output=1)
        t, found = q["tfar"], q["primID"] >= 0
        grazed = found & (t < epsilon) & (attempt < GRAZE_RETRIES)
        done = found & ~grazed
        travelled[live[done]] += t[done]
        hit[live[done]] = True
        travelled[live[grazed]] += t[grazed] + epsilon
        live = live[grazed]
    missed = todo[~hit[todo]]
    travelled[missed] = _box_exit(p[missed], direction[missed], p.min(0), p.max(0))
    out = np.zeros_like(p)
    out[todo] = direction[todo] * travelled[todo, None]
    return out, len(missed)


def _meshes(assets):
    bunny = trimesh.load(assets / "mesh" / "bunny.ply", process=False)
    torus = trimesh.creation.torus(1.0, 0.3, major_sections=250, minor_sections=200)  # 100k triangles
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    box.unmerge_vertices()
    cylinder = trimesh.creation.cylinder(radius=0.5, height=2.0, sections=48)
    cylinder.update_faces(np.abs(cylinder.face_normals[:, 2]) < 0.5)  # open: caps removed
    return {"bunny": (bunny.vertices, bunny.vertex_normals, bunny.faces),
            "torus 100k": (torus.vertices, torus.vertex_normals, torus.faces),
            "split box (grazing)": (box.vertices, np.repeat(box.face_normals, 3, axis=0), box.faces),
            "open cylinder (misses)": (cylinder.vertices, cylinder.vertex_normals, cylinder.faces)}


def test_vectors_equal_the_embreex_implementation(assets):
    for name, (p, n, f) in _meshes(assets).items():
        p, n = np.asarray(p, np.float32), np.asarray(n, np.float32)
        r = interior_vectors(p, n, f)
        diag = float(np.linalg.norm(np.ptp(p, axis=0)))
        eps = max(1e-4 * diag, 16 * float(np.spacing(np.float32(np.abs(p).max()))), 1e-12)
        ref, misses = _embreex_reference(p, n, f, eps)
        assert r.misses == misses, name
        np.testing.assert_allclose(r.vectors, ref, rtol=0, atol=1e-6 * diag, err_msg=name)
    assert len(f) < 1000 and r.misses > 0  # the open cylinder really exercised the fallback


def test_quads_move_only_what_float_rounding_decides(assets):
    """The quads hold the mesh's own triangles, but a ray running within a face's plane (the
    flat panels of CesiumMilkTruck) is kept or lost by last-bit differences. Every vertex whose
    vector differs from embreex's triangle pass must be one that one-ulp nudges of the
    positions move in that same pass."""
    from pipeline.ingest import load_scene

    rng = np.random.default_rng(0)
    unstable_total = moved_total = 0
    for m in load_scene(assets / "gltf" / "CesiumMilkTruck.glb").meshes:
        p, n = m.positions.astype(np.float32), m.normals.astype(np.float32)
        diag = float(np.linalg.norm(np.ptp(p, axis=0)))
        eps = max(1e-4 * diag, 16 * float(np.spacing(np.float32(np.abs(p).max()))), 1e-12)
        ref, _ = _embreex_reference(p, n, m.indices, eps)
        moved = np.abs(interior_vectors(p, n, m.indices).vectors - ref).max(axis=1) > 1e-6 * diag
        unstable = np.zeros(len(p), bool)
        for _ in range(16):
            away = np.where(rng.random(p.shape) < 0.5, np.inf, -np.inf).astype(np.float32)
            nudged, _ = _embreex_reference(np.nextafter(p, away), n, m.indices, eps)
            unstable |= np.abs(nudged - ref).max(axis=1) > 1e-6 * diag
        assert not (moved & ~unstable).any(), f"{m.name}: {np.flatnonzero(moved & ~unstable)[:10]}"
        unstable_total += int(unstable.sum())
        moved_total += int(moved.sum())
    assert unstable_total > 100 and moved_total < unstable_total / 4  # the case is really there


def test_out_of_range_indices_and_short_normals_are_refused():
    with pytest.raises(ValueError, match="out of range"):
        interior_vectors(np.zeros((3, 3), np.float32), np.ones((3, 3), np.float32),
                         np.array([[0, 1, 3]], np.uint32))
    with pytest.raises(ValueError, match="2 normals for 3 vertices"):
        interior_vectors(np.zeros((3, 3), np.float32), np.ones((2, 3), np.float32),
                         np.array([[0, 1, 2]], np.uint32))
