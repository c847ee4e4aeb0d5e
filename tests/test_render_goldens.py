"""Golden thumbnails of every sample asset (256 px, 3/4 view, bundled environment).

Compared with FLIP (flip-evaluator, LDR, on the tone-mapped sRGB image: CPU and GPU OpenGL
differ slightly, so never byte equality). `pytest --update-goldens` rewrites them on purpose;
look at tests/goldens/*.png after doing so. Every linear frame must be finite.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from core.cubemap import default_face_size
from core.options import RenderOptions
from pipeline.bake import bake_asset, bake_environment
from pipeline.environment.panorama import DEFAULT_ENVIRONMENT
from renderer import render

GOLDENS = Path(__file__).parent / "goldens"
SIZE = 256
MEAN_FLIP = 0.02      # mean FLIP over the image
BAD_PIXELS = 0.01     # share of pixels with FLIP > 0.5 (a visibly different pixel)

# Every sample asset: loose files, and in a folder of its own the file named like the folder.
SAMPLES = [
    "gltf/BoxTextured.glb", "gltf/CesiumMilkTruck.glb", "gltf/Duck.glb", "gltf/TestScene.gltf",
    "gltf/rgb_cube_with_primitives.gltf", "mesh/bunny.ply", "mesh/suzanne.ply", "mesh/torus.STL",
    "usd/Teapot/Teapot.usd", "usd/TextureCoordinateTest/TextureCoordinateTest.usda",
    "usd/primvar_interpolation.usda",
]


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("golden-cache")


@pytest.fixture(scope="module")
def env(cache):
    return bake_environment(DEFAULT_ENVIRONMENT, cache, face_size=default_face_size(SIZE))


def test_sample_list_is_complete(assets):
    """A new sample asset must get a golden: the list above covers the folders."""
    ext = (".glb", ".gltf", ".ply", ".stl", ".obj", ".usd", ".usda", ".usdc", ".usdz")
    found = {p.relative_to(assets).as_posix() for p in [*assets.glob("*/*"), *assets.glob("usd/*/*")]
             if p.suffix.lower() in ext and (p.parent.parent == assets or p.stem == p.parent.name)}
    assert found == set(SAMPLES)


@pytest.mark.slow
@pytest.mark.parametrize("sample", SAMPLES)
def test_golden(sample, assets, cache, env, update_goldens):
    import flip_evaluator as flip

    asset = bake_asset(assets / sample, cache)
    frame = render(asset, env, RenderOptions(width=SIZE, height=SIZE, yaw=30, pitch=20))
    assert np.isfinite(frame.linear).all()
    assert frame.linear[..., 3].min() >= 0 and frame.linear[..., :3].min() >= 0
    golden = GOLDENS / (sample.replace("/", "_") + ".png")
    if update_goldens:
        GOLDENS.mkdir(exist_ok=True)
        frame.save(golden)
        pytest.skip(f"rewrote {golden.name}")
    assert golden.exists(), f"no golden {golden.name}: run pytest --update-goldens and look at it"
    ref = np.asarray(Image.open(golden).convert("RGB"), np.float32) / 255
    test = frame.rgba8[..., :3].astype(np.float32) / 255
    error_map, mean_error, _ = flip.evaluate(ref, test, "LDR", applyMagma=False)
    bad = float((np.asarray(error_map) > 0.5).mean())
    assert mean_error < MEAN_FLIP and bad < BAD_PIXELS, (sample, mean_error, bad)
