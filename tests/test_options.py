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
from service.models import ThumbnailParams, render_options


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
           "background_blur": 0.5, "override": MaterialOverride(metallic=1.0), "msaa": 1,
           "lights": False, "multiscatter": True, "tir": "paper", "bounces": 2,
           "debug": "tir", "budget_ms": 10.0, "variant": "red", "camera": "0",
           "material_debug": "clearcoat"}


def test_key_covers_every_field():
    """Every input of a render changes the thumbnail key (service.core.thumbnail_key hashes it)."""
    base = RenderOptions()
    missing = {f.name for f in dataclasses.fields(RenderOptions)} - set(CHANGED)
    assert not missing, f"add a changed value for {missing}"
    for name, value in CHANGED.items():
        assert base.replace(**{name: value}).key_dict() != base.key_dict(), name
