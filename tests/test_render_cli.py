"""`asset-preview render`: outputs, linear frames, clear errors with the documented exit codes."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from PIL import Image
from test_render_physics import constant_env, opts, sphere_asset

from cli.main import main
from renderer.raster.render import render


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return str(tmp_path_factory.mktemp("render-cli-cache"))


def test_render_png_and_linear_npy(assets, cache, tmp_path):
    out, lin = tmp_path / "duck.png", tmp_path / "duck.npy"
    rc = main(["render", str(assets / "gltf/Duck.glb"), "--out", str(out), "--size", "96",
               "--width", "128", "--linear", str(lin), "--cache", cache, "--yaw", "30"])
    assert rc == 0
    img = Image.open(out)
    assert img.size == (128, 96)
    frame = np.load(lin)
    assert frame.shape == (96, 128, 4) and frame.dtype == np.float32 and np.isfinite(frame).all()
    # The duck is yellow: red and green well above blue at the image centre.
    r, g, b = np.asarray(img.convert("RGB"))[48, 64].astype(int)
    assert r > b + 60 and g > b + 40


def test_render_transparent_webp_and_exr(assets, cache, tmp_path):
    out, lin = tmp_path / "box.webp", tmp_path / "box.exr"
    assert main(["render", str(assets / "gltf/BoxTextured.glb"), "--out", str(out), "--size", "64",
                 "--background", "transparent", "--linear", str(lin), "--cache", cache]) == 0
    img = Image.open(out)
    assert img.mode == "RGBA" and img.getpixel((0, 0))[3] == 0
    import OpenEXR
    with OpenEXR.File(str(lin)) as f:
        assert f.channels()["RGBA"].pixels.shape == (64, 64, 4)


@pytest.mark.parametrize("argv, code, text", [
    (["--method", "magic"], 2, "invalid choice"),
    (["--background", "#12"], 2, "background"),
    (["--out-ext"], 2, "extension"),
    (["--transmission", "1", "--ior", "-3"], 2, "ior -3.0: Input should be greater than or equal to 1"),
    (["--roughness", "nan"], 2, "roughness nan: Input should be a finite number"),
])
def test_render_rejects_bad_options(assets, cache, tmp_path, capsys, argv, code, text):
    out = tmp_path / ("x.bmp" if argv == ["--out-ext"] else "x.png")
    args = ["render", str(assets / "gltf/Duck.glb"), "--out", str(out), "--cache", cache]
    args += [] if argv == ["--out-ext"] else argv
    try:
        rc = main(args)
    except SystemExit as exc:  # argparse rejects unknown choices itself
        rc = exc.code
    assert rc == code
    assert text in capsys.readouterr().err


def test_render_missing_asset_exits_3(tmp_path, cache, capsys):
    rc = main(["render", str(tmp_path / "nope.glb"), "--out", str(tmp_path / "x.png"), "--cache", cache])
    assert rc == 3
    assert capsys.readouterr().err.startswith("error: ")


def test_degenerate_normals_never_reach_the_image():
    """Zero normals (NaN after normalize in the shader) give black, finite pixels."""
    asset = sphere_asset(0.0, 0.5)
    bad = dataclasses.replace(asset, key="zero-normals",
                              meshes=[dataclasses.replace(asset.meshes[0], normals=np.zeros_like(asset.meshes[0].normals))])
    f = render(bad, constant_env(1.0), opts())
    assert np.isfinite(f.linear).all()
