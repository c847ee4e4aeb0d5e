"""KHR_animation_pointer (issue 27): material factors, a texture transform, a light's colour and
intensity, a camera's yfov and a node's translation animated through JSON pointers, read at a
time between keys against hand-computed interpolation, in a still (the document read whole)
and in the frames of an animated preview (pipeline.gltf.rig), whose pixels follow the colour."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from gltf_builder import CUBE_INDICES, CUBE_POSITIONS, Builder, png_bytes

from core.animation import Moment
from core.options import RenderOptions
from pipeline.animate import frame_times, frames, posed
from pipeline.bake import bake_asset, bake_environment
from pipeline.gltf.rig import Rig
from pipeline.ingest import load_scene
from renderer.sequence import render_animation

BASE = "/materials/0/pbrMetallicRoughness"
OFFSET = f"{BASE}/baseColorTexture/extensions/KHR_texture_transform/offset"
ROTATION = f"{BASE}/baseColorTexture/extensions/KHR_texture_transform/rotation"


def _pointer(sampler: int, pointer: str) -> dict:
    return {"sampler": sampler, "target": {"path": "pointer", "extensions": {
        "KHR_animation_pointer": {"pointer": pointer}}}}


def _asset(path: Path) -> Path:
    """A white-textured cube (material 0, its texture transform not authored), a point light,
    a camera and a second node, animated over 0 -> 2 s through pointers only."""
    b = Builder()
    b.doc["extensionsUsed"] = ["KHR_animation_pointer", "KHR_lights_punctual", "KHR_texture_transform"]
    white = b.image(png_bytes(np.full((4, 4, 3), 255, np.uint8)))
    b.material(name="paint", pbrMetallicRoughness={
        "baseColorFactor": [1, 0, 0, 1], "metallicFactor": 0.0, "roughnessFactor": 0.5,
        "baseColorTexture": {"index": white}})
    uv = (CUBE_POSITIONS[:, :2] > 0).astype(np.float32)
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES, material=0, TEXCOORD_0=uv), name="cube")
    mover = b.node(b.mesh(CUBE_POSITIONS * 0.25, CUBE_INDICES, material=0, TEXCOORD_0=uv),
                   name="mover", translation=[0.0, 3.0, 0.0])
    for mesh, name in zip(b.doc["meshes"], ("cube", "mover")):
        mesh["name"] = name
    b.doc["extensions"] = {"KHR_lights_punctual": {"lights": [
        {"type": "point", "color": [1, 1, 1], "intensity": 2.0}]}}
    b.node(None, name="lamp", translation=[0.0, 4.0, 4.0],
           extensions={"KHR_lights_punctual": {"light": 0}})
    b.doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": 0.5, "znear": 0.1}}]
    b.node(None, name="eye", camera=0, translation=[0.0, 0.0, 8.0])
    times = b.accessor(np.array([0.0, 2.0], np.float32))
    cubic_times = b.accessor(np.array([0.0, 2.0], np.float32))
    acc = b.accessor
    samplers = [
        {"input": times, "output": acc(np.array([[1, 0, 0, 1], [0, 0, 1, 1]], np.float32))},
        {"input": times, "output": acc(np.array([0.0, 1.0], np.float32)), "interpolation": "STEP"},
        {"input": times, "output": acc(np.array([[0, 0], [1, 0.5]], np.float32))},
        # CUBICSPLINE (in-tangent, value, out-tangent per key): 0 -> 1 leaving at 1 per second
        {"input": cubic_times, "output": acc(np.array([0, 0, 1, 0, 1, 0], np.float32)),
         "interpolation": "CUBICSPLINE"},
        {"input": times, "output": acc(np.array([[1, 1, 1], [0, 1, 0]], np.float32))},
        {"input": times, "output": acc(np.array([2.0, 6.0], np.float32))},
        {"input": times, "output": acc(np.array([0.5, 1.0], np.float32))},
        {"input": times, "output": acc(np.array([[0, 3, 0], [4, 3, 0]], np.float32))},
        {"input": times, "output": acc(np.array([0.0, 1.0], np.float32))},
        {"input": times, "output": acc(np.array([1.0, 2.0], np.float32))},
    ]
    b.doc["animations"] = [{"name": "pointers", "samplers": samplers, "channels": [
        _pointer(0, f"{BASE}/baseColorFactor"),
        _pointer(1, f"{BASE}/metallicFactor"),
        _pointer(2, OFFSET),
        _pointer(3, ROTATION),
        _pointer(4, "/extensions/KHR_lights_punctual/lights/0/color"),
        _pointer(5, "/extensions/KHR_lights_punctual/lights/0/intensity"),
        _pointer(6, "/cameras/0/perspective/yfov"),
        _pointer(7, f"/nodes/{mover}/translation"),
        _pointer(8, "/nodes/0/extensions/KHR_node_visibility/visible"),  # not read: a warning
        _pointer(9, "/materials/0/normalTexture/scale"),  # no normal texture: a warning
    ]}]
    return b.write(path)


@pytest.fixture(scope="module")
def animated(tmp_path_factory):
    root = tmp_path_factory.mktemp("pointer")
    path = _asset(root / "pointers.glb")
    cache = str(root / "cache")
    return path, bake_asset(path, cache), bake_environment("studio", cache, face_size=32)


# at t = 0.5 s of 0 -> 2 s: u = 0.25
U = 0.25
COLOR = (0.75, 0.0, 0.25, 1.0)
# Hermite at u = 0.25 with p0 = 0, p1 = 1, out-tangent 1 / s x 2 s, in-tangent 0
ROTATED = (U ** 3 - 2 * U ** 2 + U) * 2.0 + (-2 * U ** 3 + 3 * U ** 2) * 1.0


def _check(materials, lights, cameras, mover_matrix) -> None:
    (paint,) = {id(m): m for m in materials}.values()
    assert paint.base_color == pytest.approx(COLOR)
    assert paint.metallic == 0.0  # STEP holds the first key until t = 2
    assert paint.roughness == 0.5  # not animated
    ref = paint.base_color_texture
    assert ref is not None
    assert ref.offset == pytest.approx((0.25, 0.125))
    assert ref.rotation == pytest.approx(ROTATED) and ROTATED == pytest.approx(0.4375)
    assert ref.scale == (1.0, 1.0)
    (lamp,) = lights
    assert lamp.color == pytest.approx((0.75, 1.0, 0.75)) and lamp.intensity == pytest.approx(3.0)
    (eye,) = cameras
    assert eye.yfov == pytest.approx(0.625)
    np.testing.assert_allclose(mover_matrix[:3, 3], (1.0, 3.0, 0.0), atol=1e-9)


def test_pointers_in_a_still_between_keys(animated):
    path, _, _ = animated
    rest = load_scene(path)
    assert rest.materials[0].base_color == (1.0, 0.0, 0.0, 1.0)
    assert rest.lights[0].intensity == 2.0 and rest.cameras[0].yfov == 0.5
    ref = rest.materials[0].base_color_texture
    assert ref is not None and ref.offset == (0.0, 0.0)
    [summary] = rest.animations
    pointers = {t.get("pointer") for t in summary["targets"]}
    assert f"{BASE}/baseColorFactor" in pointers and OFFSET in pointers
    assert any(t["path"] == "translation" and t["name"] == "mover" for t in summary["targets"])
    assert summary["channels"] == 8  # the two it cannot animate are left out, with warnings
    said = " ".join(rest.warnings)
    assert "KHR_node_visibility/visible" in said and "normalTexture/scale" in said
    assert rest.extensions["KHR_animation_pointer"] == "partial"

    at = load_scene(path, moment=Moment(0.5))
    mover = next(i for i in at.instances if at.meshes[i.mesh].name.startswith("mover"))
    _check([at.materials[i.material] for i in at.instances], at.lights, at.cameras, mover.matrix)
    end = load_scene(path, moment=Moment(2.0))
    assert end.materials[0].metallic == 1.0 and end.materials[0].base_color == (0.0, 0.0, 1.0, 1.0)


def test_pointers_in_the_frames_of_an_animated_preview(animated):
    path, base, env = animated
    rig = Rig(path, base)
    pose = rig.pose(0.5, "half")
    mover = next(m for m in pose.meshes if m.name.startswith("mover"))
    _check([m.material for m in pose.meshes], pose.lights, pose.cameras, mover.transforms[0])
    # the rest pose's materials are not touched: a pose has materials of its own
    assert all(m.material.base_color == (1.0, 0.0, 0.0, 1.0) for m in rig.template.meshes)
    # the frames (rig) and the same times read whole agree, and the colour runs red -> blue
    times, motion = frame_times(base, 2)
    options = RenderOptions(width=64, height=64, animate=2, antialias="msaa")
    fast = render_animation(frames(path, base, times), env, options, motion)
    slow = render_animation([posed(path, base, Moment(t)) for t in times], env, options, motion)
    for i, (a, b) in enumerate(zip(fast, slow)):
        assert np.abs(a.rgba8.astype(int) - b.rgba8.astype(int)).max() <= 2, i
    centre = [f.rgba8[24:40, 24:40, :3].reshape(-1, 3).astype(float).mean(0) for f in fast]
    assert centre[0][0] > 2 * centre[0][2]  # red first
    # then through purple: at 1.5 s the factor is (0.25, 0, 0.75)
    assert centre[-1][0] < centre[0][0] - 40 and centre[-1][2] > centre[0][2] + 60
