"""USD variant sets: listed by inspect, chosen with --variant-set (nested selections too),
part of the bake key; unknown names are refused listing the choices. Purpose: default and
render drawn, as usdview's default; guide, proxy and unknown tokens not."""
from __future__ import annotations

import json

import numpy as np
import pytest

from cli.main import main
from core.errors import NotInAsset
from pipeline.bake import bake_or_load_asset
from pipeline.ingest import load_scene

KIT = """#usda 1.0
(
    defaultPrim = "Kit"
    metersPerUnit = 1
)
def Xform "Kit" (
    variants = { string wheels = "small" }
    prepend variantSets = "wheels"
)
{
    variantSet "wheels" = {
        "small" {
            def Cube "Car"
            {
                double size = 1
            }
        }
        "big" {
            def Xform "Car" (
                variants = { string rim = "plain" }
                prepend variantSets = "rim"
            )
            {
                def Cube "Body"
                {
                    double size = 4
                }
                variantSet "rim" = {
                    "plain" {
                    }
                    "spoked" {
                        def Sphere "Rim"
                        {
                            double radius = 3
                        }
                    }
                }
            }
        }
    }
    def Cube "Helper"
    {
        uniform token purpose = "guide"
    }
    def Cube "Stand"
    {
        uniform token purpose = "other"
    }
    def Xform "Low"
    {
        uniform token purpose = "proxy"
        def Cube "Inside"
        {
            uniform token purpose = "render"
        }
    }
}
"""


@pytest.fixture
def kit(tmp_path):
    path = tmp_path / "kit.usda"
    path.write_text(KIT)
    return path


def test_variant_sets_select_nested_and_are_listed(kit, capsys):
    scene = load_scene(kit)
    assert [(v["prim"], v["set"], v["variants"], v["selection"]) for v in scene.variant_sets] == \
        [("/Kit", "wheels", ["big", "small"], "small")]
    assert [m.name for m in scene.meshes] == ["/Kit/Car"]  # purpose guide/other/proxy not drawn
    small = scene.bounds

    scene = load_scene(kit, variant_sets=("wheels=big", "/Kit/Car:rim=spoked"))
    assert sorted(m.name for m in scene.meshes) == ["/Kit/Car/Body", "/Kit/Car/Rim"]
    assert ("/Kit/Car", "rim", ["plain", "spoked"], "spoked") in [
        (v["prim"], v["set"], v["variants"], v["selection"]) for v in scene.variant_sets]
    assert scene.bounds[1][0] > 4 * small[1][0]

    assert main(["inspect", str(kit), "--json", "--variant-set", "wheels=big"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert {(v["prim"], v["set"], v["selection"]) for v in info["variant_sets"]} == \
        {("/Kit", "wheels", "big"), ("/Kit/Car", "rim", "plain")}


@pytest.mark.parametrize("text, match", [
    ("wheels=huge", "no variant 'huge'; it has big, small"),
    ("tyres=big", "no variant set 'tyres'; it has wheels"),
    ("/Nope:wheels=big", "no prim /Nope"),
    ("wheels", "is not"),
])
def test_unknown_selection_is_refused_listing_the_choices(kit, text, match, capsys):
    with pytest.raises(NotInAsset, match=match):
        load_scene(kit, variant_sets=(text,))
    assert main(["inspect", str(kit), "--variant-set", text]) == 3


def test_variant_changes_the_key_and_the_pixels(kit, tmp_path):
    cache = tmp_path / "cache"
    small, _ = bake_or_load_asset(kit, cache)
    big, _ = bake_or_load_asset(kit, cache, variant_sets=("wheels=big",))
    assert small.key != big.key
    again, hit = bake_or_load_asset(kit, cache, variant_sets=("wheels=big",))
    assert hit and again.key == big.key

    def shot(*extra):
        out = tmp_path / "v.npy"
        assert main(["render", str(kit), "--out", str(out), "--size", "32", "--msaa", "0",
                     "--cache", str(cache), "--distance", "20", *extra]) == 0
        return np.load(out).astype(np.float64)

    assert np.abs(shot() - shot("--variant-set", "wheels=big")).max() > 0.1
