"""Thin-walled transmission (glTF: no KHR_materials_volume, or thicknessFactor 0): a sheet with
no inside lets what is behind it through unshifted, tinted by base colour; a sheet with a
thickness still refracts. Raster (single, wyman, auto) and ray tracer (tree and path)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from gltf_builder import CUBE_INDICES, CUBE_POSITIONS, Builder

from core.baked import BakedAsset, BakedMesh
from core.options import MaterialOverride, RenderOptions, apply_override
from core.scene import Material
from pipeline.gltf.accessors import Document
from pipeline.gltf.materials import Textures, read_material
from pipeline.limits import Limits
from renderer.methods.raytrace import render_raytrace
from renderer.raster.render import render

TINT = (0.3, 0.6, 0.9, 1.0)
SIZE = 96
BOX = (slice(34, 68), slice(28, 58))  # pixels the sheet covers (96 px, the view _draw fixes)


def _quad(x0: float, x1: float, y0: float, y1: float, z: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    pos = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], np.float32)
    nrm = np.tile(np.array([[0, 0, 1]], np.float32), (4, 1))
    return pos, nrm, np.array([[0, 1, 2], [0, 2, 3]], np.uint32)


def _scene(sheet: Material | None) -> BakedAsset:
    """Black and white stripes at z = -1, the glass sheet (if any) at z = 0 in front."""
    white = Material(name="white", base_color=(0.9, 0.9, 0.9, 1.0), metallic=0.0, roughness=0.8)
    black = Material(name="black", base_color=(0.02, 0.02, 0.02, 1.0), metallic=0.0, roughness=0.8)
    meshes = []
    for i in range(12):
        x0 = -1.5 + 0.25 * i
        pos, nrm, idx = _quad(x0, x0 + 0.25, -1.5, 1.5, -1.0)
        meshes.append(BakedMesh(f"stripe{i}", pos, nrm, idx, white if i % 2 else black, np.eye(4)[None]))
    key = "none"
    if sheet is not None:
        pos, nrm, idx = _quad(-0.8, 0.8, -0.8, 0.8, 0.0)
        meshes.append(BakedMesh("sheet", pos, nrm, idx, sheet, np.eye(4)[None]))
        key = f"{sheet.thin_walled}:{sheet.roughness}"
    # the key names the scene: the renderer keeps uploads per asset key
    return BakedAsset(f"test:thin_sheet:{key}", "test", "generated", meshes, [],
                      np.array([[-1.5, -1.5, -1.0], [1.5, 1.5, 0.0]]))


def _glass(thin: bool, roughness: float = 0.0) -> Material:
    return Material(name="sheet", base_color=TINT, metallic=0.0, roughness=roughness,
                    transmission=1.0, thin_walled=thin, thickness=0.0 if thin else 0.3,
                    double_sided=True)


def _draw(asset: BakedAsset, env, method: str) -> np.ndarray:
    # the view fixed: fitted, it would frame the scene with and without the sheet differently
    opts = RenderOptions(width=SIZE, height=SIZE, yaw=30.0, pitch=10.0, background="env",
                         distance=5.0, target=(0.0, 0.0, -0.5),
                         method="raytrace" if method.startswith("raytrace") else method,  # type: ignore[arg-type]
                         integrator="path" if method == "raytrace-path" else "tree")
    frame = render_raytrace(asset, env, opts) if opts.method == "raytrace" else render(asset, env, opts)
    assert np.isfinite(frame.linear).all()
    return frame.linear[BOX][..., :3].astype(np.float64)


def _alignment(seen: np.ndarray, bare: np.ndarray) -> float:
    """Correlation of the blue channel through the sheet with the bare backdrop's: near 1
    where the stripes line up, lower where refraction shifted them."""
    return float(np.corrcoef(seen[..., 2].ravel(), bare[..., 2].ravel())[0, 1])


@pytest.mark.parametrize("method", ["single", "wyman", "auto", "raytrace", "raytrace-path"])
def test_thin_sheet_shows_the_backdrop_unshifted_and_tinted(method, reference_env):
    bare = _draw(_scene(None), reference_env, method)
    thin = _draw(_scene(_glass(True)), reference_env, method)
    solid = _draw(_scene(_glass(False)), reference_env, method)
    assert _alignment(thin, bare) > 0.93, _alignment(thin, bare)  # the path tracer: noise
    assert _alignment(solid, bare) < _alignment(thin, bare) - 0.1, (_alignment(solid, bare), _alignment(thin, bare))
    # tinted by base colour: the white stripes come through blue, at about the tint's ratio
    white = bare[..., 2] > np.percentile(bare[..., 2], 75)
    ratio = thin[white].mean(axis=0) / bare[white].mean(axis=0)
    assert 0.2 < ratio[0] / ratio[2] < 0.5, ratio
    assert 0.75 < ratio[2] < 1.0, ratio  # the tint's blue, less what the sheet reflects


def test_rough_thin_sheet_blurs_the_backdrop_in_place(reference_env):
    sharp = _draw(_scene(_glass(True)), reference_env, "single")
    rough = _draw(_scene(_glass(True, roughness=0.6)), reference_env, "single")
    assert rough[..., 2].std() < 0.5 * sharp[..., 2].std()   # the stripes blur
    # to their average: still the backdrop, tinted, not the environment behind it
    assert abs(rough[..., 2].mean() - sharp[..., 2].mean()) < 0.1 * sharp[..., 2].mean()
    assert rough[..., 0].mean() < 0.75 * rough[..., 2].mean()  # blue, less the grey reflection


def _material(tmp_path, **extensions) -> Material:
    b = Builder()
    b.node(b.mesh(CUBE_POSITIONS, CUBE_INDICES, material=b.material(
        name="glass", extensions={"KHR_materials_transmission": {"transmissionFactor": 1.0}, **extensions})))
    d = Document(b.write(tmp_path / "m.glb"), Limits())
    return read_material(d, Textures(d), 0)


def test_gltf_thin_walled_follows_the_volume_extension(tmp_path):
    assert _material(tmp_path).thin_walled                                    # no volume
    assert _material(tmp_path, KHR_materials_volume={"thicknessFactor": 0}).thin_walled
    solid = _material(tmp_path, KHR_materials_volume={"thicknessFactor": 0.2})
    assert not solid.thin_walled and solid.thickness == 0.2
    # previewing a mesh as glass makes it a solid of its shape
    previewed = apply_override(_material(tmp_path), MaterialOverride(transmission=1.0))
    assert not previewed.thin_walled
    assert apply_override(_material(tmp_path), MaterialOverride(roughness=0.5)).thin_walled


def test_auto_draws_a_thin_sheet_with_single(reference_env):
    frame = render(_scene(_glass(True)), reference_env,
                   RenderOptions(width=32, height=32, method="auto", background="env"))
    sheet = [o for o in frame.plan["objects"] if o["mesh"] == "sheet"][0]
    assert sheet["method"] == "single" and "thin-walled" in sheet["why"], sheet
    solid = dataclasses.replace(_glass(False), name="solid")
    frame = render(_scene(solid), reference_env, RenderOptions(width=32, height=32, method="auto", background="env"))
    assert [o for o in frame.plan["objects"] if o["mesh"] == "sheet"][0]["method"] == "wyman"


NEAR_TINT = (0.9, 0.5, 0.3, 1.0)  # the half of the closed sheet facing the camera
FAR_TINT = (0.4, 0.8, 0.6, 1.0)   # the half behind
SKY = 0.5


def _closed_thin_ball() -> BakedAsset:
    """A closed thin-walled UV sphere (radius 0.5 at the origin), clear (IOR 1: no Fresnel,
    no bending), in two meshes: the half z > 0, toward the camera, NEAR_TINT, the other
    FAR_TINT."""
    lat, lon = np.meshgrid(np.linspace(0, np.pi, 25), np.linspace(0, 2 * np.pi, 49), indexing="ij")
    meshes = []
    for name, tint, sign in (("near", NEAR_TINT, 1.0), ("far", FAR_TINT, -1.0)):
        # lat from the pole on +z (near) or -z (far) to the equator: a hemisphere each
        half = lat[:13] * 1.0
        n = np.stack([np.sin(half) * np.cos(lon[:13]), np.sin(half) * np.sin(lon[:13]) * sign,
                      np.cos(half) * sign], -1).reshape(-1, 3)
        tris = []
        for i in range(12):
            for j in range(48):
                a, b = i * 49 + j, (i + 1) * 49 + j
                tris += [(a, b, b + 1), (a, b + 1, a + 1)]
        idx = np.array(tris, np.uint32)
        # outward winding: flip where the triangle's normal points in
        p = (0.5 * n).astype(np.float32)
        cross = np.cross(p[idx[:, 1]] - p[idx[:, 0]], p[idx[:, 2]] - p[idx[:, 0]])
        inward = np.einsum("ij,ij->i", cross, p[idx].mean(1)) < 0
        idx[inward] = idx[inward][:, ::-1]
        glass = Material(name=name, base_color=tint, metallic=0.0, roughness=0.0, ior=1.0,
                         transmission=1.0, thin_walled=True, thickness=0.0)
        meshes.append(BakedMesh(name, p, n.astype(np.float32), idx, glass, np.eye(4)[None]))
    return BakedAsset("test:thin_ball", "test", "generated", meshes, [],
                      np.array([[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]))


@pytest.mark.parametrize("method", ["single", "wyman", "auto", "raytrace", "raytrace-path"])
def test_closed_thin_sheet_tints_by_both_sheets(method, tmp_path_factory):
    """glTF's thin-walled model makes every face an infinitely thin sheet, so a ray through
    a closed thin-walled mesh crosses two: the sky through the ball's middle comes out
    x NEAR_TINT x FAR_TINT (IOR 1: nothing reflected) in the raster, which finds the far
    sheet in a back-face pass, and in the tracers, which tint at each hit."""
    from pipeline.bake import bake_environment
    from pipeline.environment import uniform
    sky = bake_environment(uniform.name((SKY,) * 3), tmp_path_factory.mktemp("sky"), face_size=32)
    opts = RenderOptions(width=48, height=48, yaw=0.0, pitch=0.0, background="env", distance=3.0,
                         target=(0.0, 0.0, 0.0), tonemap="none",
                         method="raytrace" if method.startswith("raytrace") else method,  # type: ignore[arg-type]
                         integrator="path" if method == "raytrace-path" else "tree",
                         samples=16)
    asset = _closed_thin_ball()
    frame = render_raytrace(asset, sky, opts) if opts.method == "raytrace" else render(asset, sky, opts)
    centre = frame.linear[22:26, 22:26, :3].reshape(-1, 3).mean(0)
    expected = SKY * np.asarray(NEAR_TINT[:3]) * np.asarray(FAR_TINT[:3])
    # raster and tree exact to float16 / 1%; the path tracer within its noise
    assert np.allclose(centre, expected, rtol=0.05 if method == "raytrace-path" else 0.02), (centre, expected)
