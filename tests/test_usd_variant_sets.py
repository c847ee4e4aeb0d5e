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
            double size = 0.5
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
    # purpose guide/other/proxy not drawn; Low/Inside's own "render" wins over Low's proxy
    assert sorted(m.name for m in scene.meshes) == ["/Kit/Car", "/Kit/Low/Inside"]
    small = scene.bounds

    scene = load_scene(kit, variant_sets=("wheels=big", "/Kit/Car:rim=spoked"))
    assert sorted(m.name for m in scene.meshes) == ["/Kit/Car/Body", "/Kit/Car/Rim", "/Kit/Low/Inside"]
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


def test_purposes_choose_what_is_drawn(kit):
    # a prim's own authored purpose wins over its parent's (UsdGeom's ComputePurpose): Low's
    # Inside is a render prim, drawn by default as Storm draws it, though Low is a proxy
    assert sorted(m.name for m in load_scene(kit).meshes) == ["/Kit/Car", "/Kit/Low/Inside"]
    drawn = sorted(m.name for m in load_scene(kit, purposes=("proxy",)).meshes)
    assert drawn == ["/Kit/Car"]
    drawn = sorted(m.name for m in load_scene(kit, purposes=("guide",)).meshes)
    assert drawn == ["/Kit/Car", "/Kit/Helper"]  # "other" is never drawn
    assert [m.name for m in load_scene(kit, purposes=()).meshes] == ["/Kit/Car"]  # default only
    with_proxy = kit.with_name("proxied.usda")  # a proxy under the car, drawn only when asked
    with_proxy.write_text(KIT.replace('def Cube "Stand"', 'def Cube "Stand2"\n    {\n        uniform token '
                                      'purpose = "proxy"\n    }\n    def Cube "Stand"'))
    assert "/Kit/Stand2" not in [m.name for m in load_scene(with_proxy).meshes]
    assert "/Kit/Stand2" in [m.name for m in load_scene(with_proxy, purposes=("proxy",)).meshes]


def test_variant_set_and_purposes_are_in_the_one_schema(kit, tmp_path, capsys):
    from core.options import from_arguments, from_request
    from pipeline.bake import asset_options
    o = from_request({"variant_set": ["wheels=big", "/Kit/Car:rim=spoked"], "purposes": "proxy,render"})
    assert o.variant_set == ("wheels=big", "/Kit/Car:rim=spoked")
    assert o.purposes == ("render", "proxy")  # one order, one key
    assert o.key_dict() != from_request({"variant_set": ["wheels=big"]}).key_dict()
    assert asset_options(o) == {"variant_sets": o.variant_set, "purposes": ("render", "proxy"),
                                "draw_mode": "authored"}
    with pytest.raises(ValueError, match="SET=NAME"):
        from_request({"variant_set": ["wheels"]})
    with pytest.raises(ValueError, match="unknown other"):
        from_request({"purposes": "render,other"})
    import argparse

    from core.options import add_arguments
    p = argparse.ArgumentParser()
    add_arguments(p)
    args = p.parse_args(["--variant-set", "wheels=big", "--variant-set", "/Kit/Car:rim=spoked",
                         "--purposes", "guide"])
    assert from_arguments(args).variant_set == ("wheels=big", "/Kit/Car:rim=spoked")
    assert from_arguments(args).purposes == ("guide",)

    cache = tmp_path / "cache"
    out = tmp_path / "x.npy"
    base = ["render", str(kit), "--out", str(out), "--size", "32", "--msaa", "0",
            "--cache", str(cache), "--distance", "20"]
    assert main(base) == 0
    plain = np.load(out).astype(np.float64)
    assert main([*base, "--purposes", "render,guide"]) == 0  # Helper: a 2 m cube around the 1 m car
    assert np.abs(np.load(out) - plain).max() > 0.1
    capsys.readouterr()
    assert main([*base, "--variant-set", "wheels=huge"]) == 3
    assert "no variant 'huge'; it has big, small" in capsys.readouterr().err
    assert main([*base, "--purposes", "nope"]) == 2


def test_variant_set_over_http(server, kit):
    from test_service import decode, upload
    r = upload(server, "kit.usda", kit.read_bytes())
    assert r.status_code in (200, 201), r.text
    rec = server.wait_status(r.json()["id"])
    assert rec["status"] == "ready", rec
    url = f"/assets/{rec['id']}/thumbnail"
    q = {"size": 48, "distance": 20, "msaa": 0}
    small = server.client.get(url, params=q)
    big = server.client.get(url, params=[*q.items(), ("variant_set", "wheels=big"),
                                         ("variant_set", "/Kit/Car:rim=spoked")])
    assert small.status_code == 200 and big.status_code == 200, big.text
    assert np.abs(decode(big.content) - decode(small.content)).max() > 20
    only_big = server.client.get(url, params=[*q.items(), ("variant_set", "wheels=big")])
    assert only_big.status_code == 200 and only_big.content != big.content  # both values were read
    r = server.client.get(url, params=[*q.items(), ("variant_set", "wheels=huge")])
    assert r.status_code == 422 and "it has big, small" in r.json()["detail"], r.text
    r = server.client.get(url, params={**q, "purposes": "guide"})
    assert r.status_code == 200 and r.content != small.content
    assert server.client.get(url, params={**q, "purposes": "other"}).status_code == 422
