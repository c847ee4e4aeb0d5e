"""Animated previews posed by a Rig (issue 27, item 5): the scene baked once, per frame only
what moves recomputed and rewritten on the GPU, and every frame the same as the asset read
whole at that time."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from gltf_builder import CUBE_INDICES, CUBE_POSITIONS, Builder

from core.animation import Moment
from core.options import RenderOptions
from pipeline.animate import frame_times, frames, posed
from pipeline.bake import bake_asset, bake_environment
from pipeline.gltf.rig import Rig
from pipeline.interior.vectors import interior_vectors
from renderer.raster import gpu
from renderer.sequence import render_animation

GLASS = {"KHR_materials_transmission": {"transmissionFactor": 1.0}}


def _rigged(path: Path) -> Path:
    """Four cubes: `still` (never animated), `glass` (a glass cube that only moves: translated
    and turned), `swell` (a glass cube whose morph target, weight animated, stretches its top
    face up: it deforms) and `skinned` (two joints, the top four corners on the second, which
    rises: it stretches too). No normals: ingest gives flat ones (each face its own vertices)."""
    b = Builder()
    b.doc["extensionsUsed"] = ["KHR_materials_transmission"]
    glass = b.material(name="glass", extensions=GLASS,
                       pbrMetallicRoughness={"baseColorFactor": [1, 1, 1, 1], "roughness": 0.0})
    plain = b.material(name="plain", pbrMetallicRoughness={"baseColorFactor": [0.8, 0.3, 0.2, 1]})
    top = (CUBE_POSITIONS[:, 1] > 0).astype(np.float32)
    b.node(b.mesh(CUBE_POSITIONS + np.array([0, 0, -6], np.float32), CUBE_INDICES, material=plain), name="still")
    moving = b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES, material=glass), name="glass")
    swell_mesh = b.mesh(CUBE_POSITIONS, CUBE_INDICES, material=glass)
    delta = np.zeros_like(CUBE_POSITIONS)
    delta[:, 1] = top  # weight 1: the top face 1 m higher
    b.doc["meshes"][swell_mesh]["primitives"][0]["targets"] = [{"POSITION": b.accessor(delta)}]
    b.doc["meshes"][swell_mesh]["weights"] = [0.0]
    swell = b.node(swell_mesh, name="swell", translation=[5.0, 0.0, 0.0])
    joints = np.zeros((8, 4), np.uint8)
    joints[:, 0] = top.astype(np.uint8)
    skinned = b.mesh(CUBE_POSITIONS + np.array([10, 0, 0], np.float32), CUBE_INDICES, material=plain,
                     JOINTS_0=joints, WEIGHTS_0=np.tile(np.array([1, 0, 0, 0], np.float32), (8, 1)))
    base_joint = b.node(None, name="hip")
    tip = b.node(None, name="tip")
    b.node(skinned, skin=0, name="skinned")
    b.doc["skins"] = [{"joints": [base_joint, tip]}]
    for mesh, name in zip(b.doc["meshes"], ("still", "glass", "swell", "skinned")):
        mesh["name"] = name
    times = b.accessor(np.array([0.0, 1.0, 2.0], np.float32))
    move = b.accessor(np.array([[0, 0, 0], [0, 0, 3], [0, 0, 0]], np.float32))
    s = np.sin(np.pi / 4)
    turn = b.accessor(np.array([[0, 0, 0, 1], [0, s, 0, s], [0, 1, 0, 0]], np.float32))
    weights = b.accessor(np.array([0.0, 1.0, 0.5], np.float32))
    lift = b.accessor(np.array([[0, 0, 0], [0, 2, 0], [0, 1, 0]], np.float32))
    b.doc["animations"] = [{"name": "all", "samplers": [
        {"input": times, "output": move}, {"input": times, "output": turn},
        {"input": times, "output": weights}, {"input": times, "output": lift}],
        "channels": [
            {"sampler": 0, "target": {"node": moving, "path": "translation"}},
            {"sampler": 1, "target": {"node": moving, "path": "rotation"}},
            {"sampler": 2, "target": {"node": swell, "path": "weights"}},
            {"sampler": 3, "target": {"node": tip, "path": "translation"}}]}]
    return b.write(path)


@pytest.fixture(scope="module")
def rigged(tmp_path_factory):
    root = tmp_path_factory.mktemp("rig")
    path = _rigged(root / "rigged.glb")
    cache = str(root / "cache")
    return path, bake_asset(path, cache), bake_environment("studio", cache, face_size=32)


def _by_name(asset) -> dict:
    return {m.name.split("/")[0]: m for m in asset.meshes}


def test_rig_poses_are_the_whole_reads(rigged):
    """At every time the rig's arrays equal those of the asset read whole at that time."""
    path, base, _ = rigged
    rig = Rig(path, base)
    for t in (0.0, 0.25, 0.8, 1.5, 2.0):
        a, b = rig.pose(t, f"t{t}"), posed(path, base, Moment(t))
        assert a.manifest["moment"] == b.manifest["moment"] == {"animation": "all", "time": t}
        assert np.allclose(a.bounds, b.bounds, atol=1e-6)
        assert len(a.meshes) == len(b.meshes) == 4
        for m, n in zip(a.meshes, b.meshes):
            assert m.name == n.name
            assert np.allclose(m.positions, n.positions, atol=1e-6), (t, m.name)
            assert np.allclose(m.normals, n.normals, atol=1e-6), (t, m.name)
            assert np.allclose(m.transforms, n.transforms, atol=1e-9), (t, m.name)
            assert (m.interior is None) == (n.interior is None)
            if m.interior is not None and n.interior is not None:
                assert np.allclose(m.interior, n.interior, atol=1e-5), (t, m.name)


def test_rig_by_hand(rigged):
    """t = 0.5: the glass cube lerps to z = 1.5 and slerps to 45 deg about +Y; the swelling
    cube's weight is 0.5 (top face at y = 1.5); the skin's tip joint at y = 1, its top corners
    with it."""
    path, base, _ = rigged
    m = _by_name(Rig(path, base).pose(0.5, "half"))
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    expected = np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 1.5], [0, 0, 0, 1]])
    assert np.allclose(m["glass"].transforms[0], expected, atol=1e-9)
    assert m["swell"].positions[:, 1].max() == pytest.approx(1.5)
    assert m["swell"].positions[:, 1].min() == pytest.approx(-1.0)
    sk = m["skinned"].positions
    assert sk[:, 1].max() == pytest.approx(2.0) and sk[:, 1].min() == pytest.approx(-1.0)
    assert sk[:, 0].min() == pytest.approx(9.0)  # x untouched by the lift


def test_only_what_moves_is_new(rigged):
    """Static and rigidly moving meshes keep the template's arrays (the same objects), the
    moving glass its interior vectors too: they are object-space and turn with the part.
    The deforming glass has them traced again, for its posed surface."""
    path, base, _ = rigged
    rig = Rig(path, base)
    tm = _by_name(rig.template)
    m = _by_name(rig.pose(0.7, "p"))
    for name in ("still", "glass"):
        for field in ("positions", "normals", "indices", "edges", "edge_faces", "support", "interior"):
            assert getattr(m[name], field) is getattr(tm[name], field), (name, field)
    assert m["glass"].interior is not None
    assert not np.allclose(m["glass"].transforms, tm["glass"].transforms)
    for name in ("swell", "skinned"):
        assert m[name].positions is not tm[name].positions
        assert m[name].indices is tm[name].indices and m[name].edges is tm[name].edges
    swell = m["swell"]
    assert swell.interior is not tm["swell"].interior
    fresh = interior_vectors(swell.positions, swell.normals, swell.indices).vectors
    assert np.allclose(swell.interior, fresh, atol=1e-6)
    # the top face rose by 0.7: vertical interior vectors from the bottom are 2.7 long now
    assert np.abs(swell.interior[:, 1]).max() == pytest.approx(2.7, abs=1e-4)


def test_frames_share_one_upload_and_match_separate_frames(rigged):
    """An animated preview uploads the asset once; each later frame rewrites only the
    deforming meshes' buffers (swell: positions, normals, interior; skinned: positions,
    normals) and every mesh's instance matrices; its pixels are the whole reads' pixels."""
    path, base, env = rigged
    times, motion = frame_times(base, 4)
    assert len(times) == 8
    options = RenderOptions(width=96, height=96, animate=4, antialias="msaa")
    gpu.clear()
    before = dict(gpu.stats)
    fast = render_animation(frames(path, base, times), env, options, motion)
    done = {k: gpu.stats[k] - before[k] for k in gpu.stats}
    assert fast[0].plan["animate"]["uploaded"]["asset_uploads"] == 1
    assert done["poses"] == len(times) - 1
    assert done["vertex_writes"] == 5 * (len(times) - 1)
    assert done["instance_writes"] == 4 * (len(times) - 1)
    slow = render_animation([posed(path, base, Moment(t)) for t in times], env, options, motion)
    assert slow[0].plan["animate"]["uploaded"]["asset_uploads"] == len(times)
    for i, (a, b) in enumerate(zip(fast, slow)):
        diff = np.abs(a.rgba8.astype(int) - b.rgba8.astype(int))
        assert diff.max() <= 2, i
    # the frames are not all alike: the motion is drawn
    assert np.abs(fast[0].rgba8.astype(int) - fast[3].rgba8.astype(int)).max() > 50
