"""Animated USD previews posed by a UsdRig (issue 27, item 5): the stage composed and read
once, per frame only the prims that vary in time recomputed (moving transforms placed again,
deforming and skinned meshes read again alone, cameras and lights), the frames sharing one GPU
upload, and every frame the same as the stage read whole at that time."""
from __future__ import annotations

import logging

import numpy as np
import pytest

from core.animation import Moment
from core.options import RenderOptions
from pipeline.animate import frame_times, frames, posed
from pipeline.bake import bake_asset, bake_environment
from pipeline.usd import stage as usd_stage
from pipeline.usd.rig import RigUnsupported, UsdRig
from renderer.raster import gpu
from renderer.sequence import render_animation

# Z up, 10 codes per second over 2 s: a still ground; a spinning Xform with a cube and a
# sphere under it (the sphere's own transform static: it moves with its parent); a mesh
# whose points are time-sampled (no normals: flat ones); a dollying, zooming camera and a
# lamp whose intensity rises.
MIXED = """#usda 1.0
(
    startTimeCode = 0
    endTimeCode = 20
    timeCodesPerSecond = 10
    metersPerUnit = 1
    upAxis = "Z"
)
def Xform "World"
{
    def Mesh "Ground"
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)]
        normal3f[] normals = [(0, 0, 1), (0, 0, 1), (0, 0, 1), (0, 0, 1)] (interpolation = "vertex")
        color3f[] primvars:displayColor = [(0.2, 0.6, 0.2)]
    }
    def Xform "Spinner"
    {
        float xformOp:rotateZ.timeSamples = { 0: 0, 20: 180 }
        double3 xformOp:translate = (1, 0, 0.5)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateZ"]
        def Cube "Box"
        {
            double size = 0.5
            color3f[] primvars:displayColor = [(0.9, 0.2, 0.1)]
            double3 xformOp:translate = (0.6, 0, 0)
            uniform token[] xformOpOrder = ["xformOp:translate"]
        }
        def Sphere "Ball"
        {
            double radius = 0.2
            double3 xformOp:translate = (0, 0, 0.5)
            uniform token[] xformOpOrder = ["xformOp:translate"]
        }
    }
    def Mesh "Wave"
    {
        int[] faceVertexCounts = [3, 3]
        int[] faceVertexIndices = [0, 1, 2, 0, 2, 3]
        point3f[] points.timeSamples = {
            0: [(-1, -1, 1), (0, -1, 1), (0, 0, 1), (-1, 0, 1)],
            20: [(-1, -1, 1), (0, -1, 2), (0, 0, 1.5), (-1, 0, 1)],
        }
        color3f[] primvars:displayColor = [(0.2, 0.3, 0.9)]
    }
    def Camera "Cam"
    {
        float focalLength.timeSamples = { 0: 35, 20: 50 }
        double3 xformOp:translate.timeSamples = { 0: (0, -8, 2), 20: (2, -8, 2) }
        float xformOp:rotateX = 80
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateX"]
    }
    def SphereLight "Lamp"
    {
        float inputs:intensity.timeSamples = { 0: 10, 20: 30 }
        float inputs:radius = 0.1
        double3 xformOp:translate = (0, 0, 3)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
}
"""


@pytest.fixture(scope="module")
def mixed(tmp_path_factory):
    folder = tmp_path_factory.mktemp("usdrig")
    path = folder / "mixed.usda"
    path.write_text(MIXED)
    cache = str(folder / "cache")
    return path, cache, bake_asset(path, cache)


def _same(a, b) -> None:
    """A pose equals the whole read: meshes, placements, bounds, lights, cameras."""
    assert [m.name for m in a.meshes] == [m.name for m in b.meshes]
    for ma, mb in zip(a.meshes, b.meshes):
        np.testing.assert_allclose(ma.positions, mb.positions, atol=1e-5, err_msg=ma.name)
        np.testing.assert_allclose(ma.normals, mb.normals, atol=1e-5, err_msg=ma.name)
        assert np.array_equal(ma.indices, mb.indices)
        np.testing.assert_allclose(ma.transforms, mb.transforms, atol=1e-9, err_msg=ma.name)
    np.testing.assert_allclose(a.bounds, b.bounds, atol=1e-5)
    assert len(a.lights) == len(b.lights) and len(a.cameras) == len(b.cameras)
    for la, lb in zip(a.lights, b.lights):
        np.testing.assert_allclose(la.matrix, lb.matrix, atol=1e-9)
        assert la.intensity == pytest.approx(lb.intensity) and la.type == lb.type
    for ca, cb in zip(a.cameras, b.cameras):
        np.testing.assert_allclose(ca.matrix, cb.matrix, atol=1e-9)
        assert ca.yfov == pytest.approx(cb.yfov)
    assert a.manifest["moment"] == b.manifest["moment"]


def test_usd_rig_poses_are_the_whole_reads(mixed):
    path, _, base = mixed
    times, _ = frame_times(base, 4)
    assert len(times) == 8
    rig = UsdRig(path, base, times[0])
    try:
        for t in (times[0], 0.25, 0.75, times[-1], 0.6):  # 0.6: between the frames too
            _same(rig.pose(t, f"k{t}"), posed(path, base, Moment(t)))
        pose = rig.pose(0.5, "k")
    finally:
        rig.close()
    assert pose.cameras[0].matrix[0, 3] == pytest.approx(0.5)  # the dolly is a quarter on
    assert pose.lights[0].intensity > posed(path, base, Moment(0.0)).lights[0].intensity


def test_usd_rig_rereads_only_what_varies(mixed, monkeypatch):
    """Per frame only /World/Wave (time-sampled points) is read again by the stage reader;
    the ground, the spinner's cube and ball are not: the ground's arrays and placement are
    the template's own objects, the cube's and ball's placement alone is new."""
    path, _, base = mixed
    rig = UsdRig(path, base, 0.0)
    read: list[str] = []
    original = usd_stage.StageReader._gprim

    def counting(self, prim, *args, **kwargs):
        read.append(str(prim.GetPath()))
        return original(self, prim, *args, **kwargs)

    monkeypatch.setattr(usd_stage.StageReader, "_gprim", counting)
    try:
        poses = [rig.pose(t, f"k{t}") for t in (0.25, 0.5, 1.5)]
    finally:
        rig.close()
    assert read == ["/World/Wave"] * 3
    assert rig.reads == 3
    tm = {m.name: m for m in rig.template.meshes}
    for pose in poses:
        m = {x.name: x for x in pose.meshes}
        ground = m["/World/Ground"]
        for field in ("positions", "normals", "indices", "edges", "transforms", "support"):
            assert getattr(ground, field) is getattr(tm["/World/Ground"], field), field
        for name in ("/World/Spinner/Box", "/World/Spinner/Ball"):
            assert m[name].positions is tm[name].positions
            assert not np.allclose(m[name].transforms, tm[name].transforms)
        assert m["/World/Wave"].positions is not tm["/World/Wave"].positions
        assert m["/World/Wave"].indices is tm["/World/Wave"].indices


def test_usd_rig_skinned_arm_matches_whole_reads(assets):
    """tests/assets/usd/skel/bending_arm.usda (UsdSkel: joints and a blend shape animated)."""
    path = assets / "usd/skel/bending_arm.usda"
    import tempfile
    base = bake_asset(path, tempfile.mkdtemp())
    rig = UsdRig(path, base, 0.0)
    try:
        assert rig.reread == ["/Arm/Skin"]
        for t in (0.0, 0.25, 0.6, 1.0):
            _same(rig.pose(t, f"k{t}"), posed(path, base, Moment(t)))
    finally:
        rig.close()


def test_usd_rig_falls_back_when_something_else_varies(tmp_path, caplog):
    """Animated visibility is not a rig's: frames are read whole (and say why in the log)."""
    path = tmp_path / "blink.usda"
    path.write_text(MIXED.replace('color3f[] primvars:displayColor = [(0.2, 0.6, 0.2)]',
                                  'color3f[] primvars:displayColor = [(0.2, 0.6, 0.2)]\n'
                                  '        token visibility.timeSamples = { 0: "inherited", 10: "invisible" }'))
    base = bake_asset(path, str(tmp_path / "cache"))
    with pytest.raises(RigUnsupported, match="/World/Ground.visibility varies in time"):
        UsdRig(path, base, 0.0)
    times = [0.0, 1.5]
    with caplog.at_level(logging.INFO, logger="pipeline.animate"):
        out = frames(path, base, times)
    assert "each frame read whole" in caplog.text and "visibility" in caplog.text
    assert "/World/Ground" not in {m.name for m in out[1].meshes}  # invisible from code 10
    assert out[1].gpu_key is None


def test_usd_frames_share_one_upload_and_match_separate_frames(mixed):
    path, cache, base = mixed
    env = bake_environment("studio", cache, face_size=32)
    times, motion = frame_times(base, 4)
    options = RenderOptions(width=64, height=64, animate=4, antialias="msaa")
    gpu.clear()
    before = dict(gpu.stats)
    fast = render_animation(frames(path, base, times), env, options, motion)
    done = {k: gpu.stats[k] - before[k] for k in gpu.stats}
    assert fast[0].plan["animate"]["uploaded"]["asset_uploads"] == 1
    assert done["poses"] == len(times) - 1
    # per later frame only the Wave's positions and normals are written (its flat normals
    # follow its points); the ground's, cube's and ball's buffers stay as uploaded
    assert done["vertex_writes"] == 2 * (len(times) - 1)
    slow = render_animation([posed(path, base, Moment(t)) for t in times], env, options, motion)
    for i, (a, b) in enumerate(zip(fast, slow)):
        assert np.abs(a.rgba8.astype(int) - b.rgba8.astype(int)).max() <= 2, i
    assert np.abs(fast[0].rgba8.astype(int) - fast[5].rgba8.astype(int)).max() > 50


INSTANCED = """#usda 1.0
(
    startTimeCode = 0
    endTimeCode = 10
    timeCodesPerSecond = 10
    metersPerUnit = 1
    upAxis = "Y"
)
def PointInstancer "Crowd"
{
    point3f[] positions = [(0, 0, 0), (2, 0, 0)]
    int[] protoIndices = [0, 0]
    rel prototypes = [</Crowd/Protos/Pebble>]
    def Xform "Protos"
    {
        def Mesh "Pebble"
        {
            int[] faceVertexCounts = [3]
            int[] faceVertexIndices = [0, 1, 2]
            point3f[] points.timeSamples = {
                0: [(0, 0, 0), (1, 0, 0), (0, 1, 0)],
                10: [(0, 0, 0), (1, 0, 0), (0, 2, 0)],
            }
        }
    }
}
"""


def test_usd_rig_falls_back_for_a_point_instanced_prototype_that_deforms(tmp_path, caplog):
    """A PointInstancer's instances do not record the prim that placed them: a prototype
    whose points vary is read whole per frame, and those frames follow the points."""
    path = tmp_path / "crowd.usda"
    path.write_text(INSTANCED)
    base = bake_asset(path, str(tmp_path / "cache"))
    with pytest.raises(RigUnsupported, match="PointInstancers"):
        UsdRig(path, base, 0.0)
    with caplog.at_level(logging.INFO, logger="pipeline.animate"):
        out = frames(path, base, [0.0, 0.5])
    assert "each frame read whole" in caplog.text
    assert out[1].bounds[1, 1] == pytest.approx(1.5)  # halfway from 1 to 2
