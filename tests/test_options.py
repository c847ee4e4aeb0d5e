"""The single request schema: CLI flags and HTTP parameters are derived from RenderOptions."""
import argparse
import dataclasses
import pickle

import pytest
from pydantic import ValidationError

from core.options import (
    METHODS,
    MaterialOverride,
    RenderOptions,
    add_arguments,
    from_arguments,
    from_request,
    request_fields,
)
from service.http.models import ThumbnailParams, render_options


def _cli(argv):
    p = argparse.ArgumentParser()
    add_arguments(p)
    return from_arguments(p.parse_args(argv))


def test_cli_and_http_expose_the_same_parameters():
    p = argparse.ArgumentParser()
    add_arguments(p)
    flags = {a.dest for a in p._actions if a.dest != "help"}
    assert flags == set(request_fields())
    assert set(ThumbnailParams.model_fields) == set(request_fields()) | {"format", "env"}


def test_the_same_request_gives_the_same_options_on_both_surfaces():
    cli = _cli(["--size", "64", "--method", "raytrace", "--ior", "1.7", "--transmission", "1",
                "--base-color", "ff8000", "--no-lights", "--budget-ms", "500"])
    http = render_options(ThumbnailParams.model_validate(
        {"size": "64", "method": "raytrace", "ior": "1.7", "transmission": "1",
         "base_color": "ff8000", "lights": "false", "budget_ms": "500"}))
    assert cli == http
    assert cli.override == MaterialOverride(base_color=cli.override.base_color, ior=1.7, transmission=1.0)
    assert cli.override.base_color[0] == 1.0 and 0.2 < cli.override.base_color[1] < 0.25  # sRGB -> linear


def test_every_method_is_accepted_everywhere():
    for m in METHODS:
        assert _cli(["--method", m]).method == m
        assert render_options(ThumbnailParams.model_validate({"method": m})).method == m


@pytest.mark.parametrize("bad", [{"ior": 5}, {"budget_ms": 600_000}, {"width": 0}, {"roughness": float("nan")},
                                 {"background": "#12"}, {"size": 9000}, {"method": "magic"}])
def test_one_range_for_every_surface(bad):
    with pytest.raises(ValueError):
        from_request(bad)
    with pytest.raises(ValidationError):
        render_options(ThumbnailParams.model_validate({k: str(v) for k, v in bad.items()}))


def test_options_cross_processes_as_themselves_and_replace_validates():
    o = RenderOptions(width=32, height=16, override=MaterialOverride(roughness=0.2))
    assert pickle.loads(pickle.dumps(o)) == o
    with pytest.raises(ValueError):
        dataclasses.replace(o, fov=0.0)
    assert RenderOptions(override=MaterialOverride()).override is None  # one spelling of "none"


CHANGED = {"width": 300, "height": 300, "yaw": 1.0, "pitch": 1.0, "fov": 50.0, "distance": 3.0,
           "method": "wyman", "tonemap": "aces", "exposure": 1.0, "background": "transparent",
           "background_blur": 0.5, "override": MaterialOverride(metallic=1.0), "msaa": 1, "antialias": "msaa",
           "lights": False, "light_shadows": False, "multiscatter": False, "tir": "paper", "bounces": 2, "fresnel_split": "sample",
           "rough_lobes": "prefilter", "supersample": 3, "aa_threshold": 0.05,
           "integrator": "path", "samples": 16, "noise": 0.05,
           "debug": "tir", "budget_ms": 10.0, "time": "0.5", "animation": "walk", "animate": 12.0, "variant": "red", "camera": "0",
           "material_debug": "clearcoat", "target": (0.0, 1.0, 0.0), "env_rotation": 90.0,
           "alpha": "coverage", "shadow": 0.2, "turntable": 12, "views": True,
           "variant_set": ("wheels=big",), "purposes": ("render", "proxy"),
           "draw_mode": "full"}


def test_key_covers_every_field():
    """Every input of a render changes the thumbnail key (service.thumbnails.ThumbnailService.thumbnail_key hashes it)."""
    base = RenderOptions()
    missing = {f.name for f in dataclasses.fields(RenderOptions)} - set(CHANGED)
    assert not missing, f"add a changed value for {missing}"
    for name, value in CHANGED.items():
        assert base.replace(**{name: value}).key_dict() != base.key_dict(), name


def test_camera_and_light_controls_from_both_surfaces():
    """target, env_rotation and alpha come from the schema on the command line and in a query;
    energy compensation is on by default and `--no-multiscatter` turns it off."""
    from core.options import add_arguments, from_arguments, from_request
    o = from_request({"target": "0.5,1,-2", "env_rotation": "45", "alpha": "coverage"})
    assert o.target == (0.5, 1.0, -2.0) and o.env_rotation == 45.0 and o.alpha == "coverage"
    assert RenderOptions().multiscatter is True and RenderOptions().target is None
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(["--no-multiscatter", "--target", "1,2,3", "--env-rotation", "-30"])
    o = from_arguments(args)
    assert o.multiscatter is False and o.target == (1.0, 2.0, 3.0) and o.env_rotation == -30.0
    for bad in ("1,2", "a,b,c", "1,2,nan", "1e13,0,0"):
        with pytest.raises(ValueError):
            from_request({"target": bad})
