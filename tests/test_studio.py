"""The default look: the generated studio light, the three-quarter view with screen-space
framing, the ground contact shadow, turntables and view sheets (issue 14)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from PIL import Image
from test_render_physics import sphere_asset

from cli.main import main
from core.baked import BakedAsset, BakedMesh
from core.options import RenderOptions
from core.scene import Material
from pipeline.bake import bake_asset, bake_environment
from pipeline.environment import prefilter, studio
from renderer.raster import gpu
from renderer.raster.render import render
from renderer.sequence import encode_animation, render_turntable, render_views, turntable_angles
from renderer.view.camera import FILL
from renderer.view.framing import asset_camera

S = 96


@pytest.fixture(scope="module")
def studio_env(tmp_path_factory):
    return bake_environment("studio", tmp_path_factory.mktemp("studio-env"), face_size=128)


def colour_cube(lift: float = 0.0) -> BakedAsset:
    """A unit cube, one unlit mesh per face in its own colour; its base at y = lift - 0.5."""
    meshes = []
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            u, v = np.eye(3)[(axis + 1) % 3] * 0.5, np.eye(3)[(axis + 2) % 3] * 0.5
            c = n * 0.5 + np.array([0, lift, 0])
            pos = np.array([c - u - v, c + u - v, c + u + v, c - u + v], np.float32)
            idx = np.array([[0, 1, 2], [0, 2, 3]], np.uint32)
            if np.dot(np.cross(pos[1] - pos[0], pos[2] - pos[0]), n) < 0:
                idx = idx[:, ::-1].copy()
            colour = (0.2 + 0.6 * (axis == 0), 0.2 + 0.6 * (axis == 1), 0.2 + 0.6 * (axis == 2))
            colour = tuple(x * (1.0 if sign > 0 else 0.5) for x in colour)
            mat = Material(name=f"face{axis}{sign:+.0f}", base_color=(*colour, 1.0), unlit=True)
            meshes.append(BakedMesh(name=mat.name, positions=pos, normals=np.tile(n, (4, 1)).astype(np.float32),
                                    indices=idx, material=mat, transforms=np.eye(4)[None]))
    bounds = np.array([[-0.5, lift - 0.5, -0.5], [0.5, lift + 0.5, 0.5]])
    return BakedAsset(key=f"colour-cube-{lift}", source="test", format="test", meshes=meshes,
                      textures=[], bounds=bounds)


def face_labels(frame, asset: BakedAsset) -> np.ndarray:
    """Per pixel: index of the face whose colour it shows, -1 for none."""
    cols = np.array([m.material.base_color[:3] for m in asset.meshes])
    lin = frame.linear[..., :3]
    dist = np.linalg.norm(lin[:, :, None, :] - cols[None, None], axis=-1)
    return np.where(dist.min(-1) < 0.02, dist.argmin(-1), -1)


# --- studio light ---------------------------------------------------------------------------

def unit_sphere_hits(sphere: BakedAsset, options: RenderOptions):
    """Per pixel of the default camera: view direction, ray-sphere discriminant (> 0: the ray
    hits the unit sphere) and the normal where it does."""
    cam = asset_camera(sphere, options)[0]
    d = cam.ray_directions()
    o = cam.position
    b = d @ o
    disc = b * b - (o @ o - 1)
    return d, disc, o + (-b - np.sqrt(np.maximum(disc, 0)))[..., None] * d


def test_white_lambert_sphere_is_near_white_in_the_middle(studio_env):
    """Default environment and tone map: the middle of a white diffuse sphere (N.V > 0.97)
    shows sRGB within 10% of white, neutral grey, and not clipped flat."""
    assert prefilter.DEFAULT_ENVIRONMENT == "studio"
    options = RenderOptions(width=S, height=S)
    sphere = sphere_asset(0.0, 1.0)
    frame = render(sphere, studio_env, options)
    d, disc, n = unit_sphere_hits(sphere, options)
    middle = (disc > 0) & (np.einsum("...i,...i", n, -d) > 0.97)
    assert middle.sum() > 20
    rgb = frame.rgba8[..., :3][middle].astype(float) / 255
    assert rgb.mean() >= 0.9, rgb.mean()
    assert np.ptp(rgb.mean(axis=0)) < 0.01  # neutral: no tint
    assert frame.linear[..., :3][middle].mean() < 1.3  # lit near 1, not blown out


def test_mirror_sphere_shows_the_studio_lights(studio_env):
    """A mirror sphere reflects the studio: rendered radiance follows studio.radiance() in the
    reflected direction, and the softboxes appear as bright patches."""
    options = RenderOptions(width=S, height=S, tonemap="none", background="env")
    sphere = sphere_asset(1.0, 0.0)
    frame = render(sphere, studio_env, options)
    d, disc, n = unit_sphere_hits(sphere, options)
    inside = (disc > 0) & (np.einsum("...i,...i", n, -d) > 0.3)
    r = d - 2 * np.einsum("...i,...i", d, n)[..., None] * n
    expected = studio.radiance(r)[inside]
    got = frame.linear[..., :3].mean(-1)[inside]
    lights = expected > 1.5
    assert lights.sum() > 10 and (~lights).sum() > 10
    assert got[lights].mean() > 3 * got[~lights].mean()
    assert np.corrcoef(got, expected)[0, 1] > 0.85


# --- the default view -----------------------------------------------------------------------

def test_default_view_of_a_cube_shows_three_faces():
    """Three faces (three distinct normals), each a fair share of the cube's pixels."""
    cube = colour_cube()
    frame = render(cube, bake_environment("studio", face_size=32),
                   RenderOptions(width=S, height=S, background="transparent"))
    labels = face_labels(frame, cube)
    covered = labels >= 0
    shares = np.bincount(labels[covered], minlength=6) / covered.sum()
    normals = [tuple(np.round(cube.meshes[i].normals[0]).astype(int)) for i in np.flatnonzero(shares > 0.08)]
    assert len(normals) == 3, shares
    assert set(normals) == {(1, 0, 0), (0, 1, 0), (0, 0, 1)}  # yaw > 0: +X side; pitch > 0: top


@pytest.mark.parametrize("size", [(128, 128), (160, 96), (96, 160)])
def test_framing_fills_the_frame_with_the_projected_bounds(size):
    """Without a shadow the cube's projected corners span FILL of the tighter axis, centred."""
    w, h = size
    cube = colour_cube()
    frame = render(cube, bake_environment("studio", face_size=32),
                   RenderOptions(width=w, height=h, background="transparent", shadow=0))
    ys, xs = np.nonzero(frame.linear[..., 3] > 0.5)
    span_x, span_y = (xs.max() - xs.min() + 1) / w, (ys.max() - ys.min() + 1) / h
    assert max(span_x, span_y) == pytest.approx(FILL, abs=0.03), (span_x, span_y)
    assert abs((xs.max() + xs.min() + 1) / 2 - w / 2) <= 0.03 * w  # the slack axis is centred
    assert abs((ys.max() + ys.min() + 1) / 2 - h / 2) <= 0.03 * h  # in depth, not exactly on screen


# --- ground shadow --------------------------------------------------------------------------

def test_shadow_under_an_object_on_the_ground_never_over_it(studio_env):
    cube = colour_cube(lift=0.5)  # standing on y = 0
    base = RenderOptions(width=S, height=S, distance=3.2)  # one camera for all three frames
    on = render(cube, studio_env, dataclasses.replace(base, shadow=1.0))
    off = render(cube, studio_env, dataclasses.replace(base, shadow=0.0))
    alpha = render(cube, studio_env, dataclasses.replace(base, background="transparent", shadow=0.0))
    assert on.plan["shadow"].startswith("strength 1") and off.plan["shadow"].startswith("none")
    obj = alpha.linear[..., 3] > 0.999
    background = alpha.linear[..., 3] < 1e-6
    assert np.abs(on.linear[obj] - off.linear[obj]).max() < 1e-4  # never over the object
    darker = (off.linear[..., :3] - on.linear[..., :3]).mean(-1)
    assert darker[background].max() > 0.2  # a clear shadow ...
    ys, xs = np.nonzero(background & (darker > 0.05))
    assert ys.min() > np.nonzero(obj)[0].mean()  # ... on the ground, below the cube's middle
    assert darker[:S // 4].max() < 1e-4  # none in the sky
    # shadow 0: the background is exactly the gradient
    top = np.array([0.95, 0.95, 0.95])
    lin = np.where(top <= 0.04045, top / 12.92, ((top + 0.055) / 1.055) ** 2.4)
    assert np.abs(off.linear[0, :, :3] - lin).max() < 0.01
    # transparent: the shadow is alpha under the object, the object is untouched
    t_on = render(cube, studio_env, dataclasses.replace(base, background="transparent", shadow=1.0))
    assert t_on.linear[..., 3][background].max() > 0.2
    assert np.abs(t_on.linear[obj] - alpha.linear[obj]).max() < 1e-4


def test_no_shadow_without_a_clear_ground(studio_env):
    flat = colour_cube()
    flat.meshes = [m for m in flat.meshes if m.name == "face1+1"]  # one horizontal square
    flat.bounds = np.array([[-0.5, 0.5, -0.5], [0.5, 0.5, 0.5]])
    flat.key = "one-square"
    assert render(flat, studio_env, RenderOptions(width=32, height=32)).plan["shadow"].startswith("none: flat")
    cube = colour_cube()
    assert "background env" in render(cube, studio_env, RenderOptions(
        width=32, height=32, background="env")).plan["shadow"]
    assert "below the ground" in render(cube, studio_env, RenderOptions(
        width=32, height=32, pitch=-30)).plan["shadow"]


# --- turntable and views --------------------------------------------------------------------

def test_turntable_frames_share_one_upload(assets, studio_env, tmp_path):
    duck = bake_asset(assets / "gltf/Duck.glb", tmp_path)
    gpu.clear()  # count this test's uploads from nothing
    options = RenderOptions(width=48, height=48, turntable=12, yaw=10)
    before = dict(gpu.stats)
    frames = render_turntable(duck, studio_env, options)
    assert len(frames) == 12
    assert gpu.stats["asset_uploads"] - before["asset_uploads"] == 1
    assert frames[0].plan["turntable"]["uploaded"]["asset_uploads"] == 1
    assert all(f.plan["uploaded"]["asset_uploads"] == 0 for f in frames[1:])
    angles = turntable_angles(options)
    step = np.diff(angles + [angles[0] + 360])
    assert np.allclose(step, 30)  # evenly around, the last frame's next is the first
    diff = lambda a, b: np.abs(a.linear - b.linear).mean()  # noqa: E731
    # neighbours in angle look alike; the first and last frames are neighbours too
    wrap, next_, far = diff(frames[-1], frames[0]), diff(frames[0], frames[1]), diff(frames[0], frames[6])
    assert wrap < 0.8 * far and next_ < 0.8 * far and wrap < 1.5 * next_, (wrap, next_, far)
    # one distance for every frame
    assert len({round(f.plan["view"]["distance"], 9) for f in frames}) == 1
    for fmt in ("webp", "gif"):
        im = Image.open(__import__("io").BytesIO(encode_animation(frames, fmt)))
        assert im.n_frames == 12 and im.size == (48, 48)


def test_views_sheet(studio_env):
    cube = colour_cube()
    sheet = render_views(cube, studio_env, RenderOptions(width=96, height=96, shadow=0))
    assert sheet.rgba8.shape == (96, 96, 4) and sheet.plan["views"][0] == "front"
    labels = face_labels(sheet, cube)
    front, top = labels[:48, :48], labels[48:, :48]
    assert set(np.unique(front[front >= 0])) == {4}  # +Z face only (mesh order x+, x-, y+, y-, z+, z-)
    assert set(np.unique(top[top >= 0])) == {2}
    # its linear image, made on demand, is the four views' own, placed as the display ones
    side = render(cube, studio_env, RenderOptions(width=48, height=48, shadow=0, yaw=90.0, pitch=0.0))
    np.testing.assert_array_equal(sheet.linear[:48, 48:], side.linear)
    assert np.isfinite(sheet.linear).all() and sheet.linear[..., 3].max() > 0


def test_cli_turntable_one_bake(assets, tmp_path):
    out = tmp_path / "box.webp"
    cache = tmp_path / "cache"
    rc = main(["render", str(assets / "gltf/BoxTextured.glb"), "--out", str(out), "--size", "48",
               "--turntable", "6", "--cache", str(cache)])
    assert rc == 0
    assert Image.open(out).n_frames == 6
    assert len(list((cache / "assets").iterdir())) == 1
    assert len(list((cache / "environments").iterdir())) == 1
    assert main(["render", str(assets / "gltf/BoxTextured.glb"), "--out", str(tmp_path / "x.png"),
                 "--turntable", "4", "--cache", str(cache)]) == 2
