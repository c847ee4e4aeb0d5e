"""USD surfaces drawn as usdview draws them (Hydra Storm, docs/usd.md "Back faces"): a
single-sided gprim is not culled (usdview's cullBackfaces is off by default) and its back
is shaded with the normal unflipped; a double-sided one turns the normal to the viewer;
`orientation = "leftHanded"` decides which side is the front. UsdPreviewSurface
displacement is not drawn, with a warning."""
from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.ingest import load_scene

CARD = """#usda 1.0
(
    metersPerUnit = 1
    upAxis = "Y"
)
def Xform "World"
{
    def Mesh "Card" ( prepend apiSchemas = ["MaterialBindingAPI"] )
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = INDICES
        point3f[] points = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
        uniform token orientation = "ORIENTATION"
        uniform bool doubleSided = DOUBLE
        rel material:binding = </World/Grey>
    }
    def Material "Grey"
    {
        token outputs:surface.connect = </World/Grey/S.outputs:surface>
        def Shader "S"
        {
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor = (0.5, 0.5, 0.5)
            float inputs:roughness = 1
            float inputs:ior = 1
            DISPLACEMENT
            token outputs:surface
        }
    }
    def DistantLight "Sun"
    {
        float inputs:intensity = 3
        bool inputs:normalize = 1
    }
}
"""
LIT = 0.5 / math.pi * 3.0  # albedo / pi x E, the card facing the light (and the camera)


def _stage(tmp_path, facing_camera: bool, double: bool, left: bool = False, displacement: str = ""):
    # counter-clockwise seen from +Z (the camera and the light's side) is the front when
    # right-handed; leftHanded makes the clockwise order the front
    ccw = facing_camera != left
    text = (CARD.replace("INDICES", "[0, 1, 2, 3]" if ccw else "[0, 3, 2, 1]")
            .replace("ORIENTATION", "leftHanded" if left else "rightHanded")
            .replace("DOUBLE", "1" if double else "0").replace("DISPLACEMENT", displacement))
    path = tmp_path / f"card_{int(facing_camera)}{int(double)}{int(left)}.usda"
    path.write_text(text)
    return path


def _shot(path, tmp_path):
    from cli.main import main
    out = tmp_path / f"{path.stem}.npy"
    assert main(["render", str(path), "--out", str(out), "--size", "32", "--yaw", "0",
                 "--pitch", "0", "--tonemap", "none", "--msaa", "0", "--background", "transparent",
                 "--cache", str(tmp_path / "cache")]) == 0
    return np.load(out).astype(np.float64)[12:20, 12:20]


@pytest.mark.parametrize("left", [False, True])
def test_back_faces_as_storm_draws_them(tmp_path, left):
    """Storm (bench usd on this stage: FLIP 0.019 -> 0.007 with this rule): the front lit;
    a single-sided back drawn, unlit by a light on the other side (its normal points
    away); a double-sided back lit as a front. Before, ours culled the single-sided back."""
    front = _shot(_stage(tmp_path, True, False, left), tmp_path)
    back = _shot(_stage(tmp_path, False, False, left), tmp_path)
    back_double = _shot(_stage(tmp_path, False, True, left), tmp_path)
    np.testing.assert_allclose(front[..., :3], LIT, rtol=0.02)
    assert back[..., 3].min() > 0.99  # drawn, not culled
    assert back[..., :3].max() < 0.02 * LIT  # and dark: the light is behind its normal
    np.testing.assert_allclose(back_double[..., :3], LIT, rtol=0.02)
    assert back_double[..., 3].min() > 0.99


def test_single_sided_material_flags(tmp_path):
    single = load_scene(_stage(tmp_path, True, False))
    double = load_scene(_stage(tmp_path, True, True))
    (m1,) = [m for m in single.materials if m.name.endswith("Grey")]
    (m2,) = [m for m in double.materials if m.name.endswith("Grey")]
    assert m1.show_back_faces and not m1.double_sided
    assert m2.double_sided


def test_displacement_is_not_drawn_and_says_so(tmp_path):
    scene = load_scene(_stage(tmp_path, True, False, displacement="float inputs:displacement = 0.3"))
    assert any("displacement" in w and "Grey" in w for w in scene.warnings)
    flat = load_scene(_stage(tmp_path, True, True, displacement="float inputs:displacement = 0"))
    assert not any("displacement" in w for w in flat.warnings)
