"""core.schema: the fast check takes only what pydantic takes, converted as pydantic converts
it (pydantic, built from the same declaration, decides and words the rest), the usual inputs
take the fast path, and a cold command-line render imports no pydantic."""
import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import pytest
from pydantic import ValidationError

from core.config import RendererSettings
from core.options import MaterialOverride, RenderOptions, from_request
from core.schema import declared, fast_values, pydantic_class
from pipeline.limits import Limits, PipelineSettings
from service.settings import Settings

ROOT = Path(__file__).resolve().parents[1]
CLASSES = [MaterialOverride, RenderOptions, Limits, PipelineSettings, RendererSettings, Settings]

# What flags, queries, variables and callers give, and what they should not.
VALUES = [None, 0, 1, -1, 2, 3, 0.0, 0.5, 1.0, 1.5, 3.0, -0.0, 1e-9, 255, 256, 9000, 65536, 1e13, True, False,
          "0", "1", "3", " 3 ", "+3", "-2", "3.0", "2.5", ".5", "5.", "1e3", "-1E-2", "1_000", "0x10", "\u0663",
          "abc", "", "true", "False", "YES", "off", "t", "2", " true ", "On", "\t2.5\t", "+.5", "1e+3", "00012",
          "-0", "inf", "nan", math.nan, math.inf, -math.inf,
          [1, 2, 3], (0.5, 0.5, 0.5), [0.5, 2, 0.1], (1, 2), [], (), ["a=b"], ("a=b", "c:d=e"), "1,2,3",
          "ff8000", "#ff8000", "#12", "a=b", ["render", "proxy"], "render,guide", "bogus", "auto", "raytrace",
          "poster", "12.5", "x" * 300, "edges", "full", " Transparent ", "local", "ray", "/tmp/x", "16G",
          {"metallic": 0.5}, {"metallic": 5}, {"nope": 1}, MaterialOverride(roughness=0.2), b"x", Path("x"), 10**400]


def _plain(v):
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return (type(v).__name__, tuple(_plain(getattr(v, f.name)) for f in dataclasses.fields(v)))
    if isinstance(v, tuple):
        return tuple(_plain(x) for x in v)
    return (type(v), v)


def _pydantic(cls, raw):
    given = {k: dataclasses.asdict(v) if k == "override" and isinstance(v, MaterialOverride) else v
             for k, v in raw.items()}  # as core.schema passes a valid nested object
    try:
        model = pydantic_class(cls)(**given)
    except ValidationError:
        return None
    return {n: _plain(getattr(model, n)) for n in declared(cls)}


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_the_fast_check_takes_only_what_pydantic_takes_and_converts_alike(cls):
    defaults = {n: p.default for n, p in declared(cls).items()}
    assert fast_values(cls, defaults) is not None, "the defaults must not need pydantic"
    taken = refused = 0
    for name in defaults:
        for v in VALUES:
            raw = {**defaults, name: v}
            try:
                fast = fast_values(cls, raw)
            except TypeError:  # a `before` function's own (target=0): pydantic lets it through too
                with pytest.raises(TypeError):
                    _pydantic(cls, raw)
                continue
            if fast is None:
                refused += 1
                continue
            taken += 1
            expected = _pydantic(cls, raw)
            assert expected is not None, f"{cls.__name__}.{name} = {v!r}: taken here, refused by pydantic"
            assert {n: _plain(x) for n, x in fast.items()} == expected, f"{cls.__name__}.{name} = {v!r}"
    assert taken and refused


def test_refusals_are_pydantics_own():
    """A refused value raises pydantic's ValidationError, nested fields located as before."""
    with pytest.raises(ValidationError) as e:
        RenderOptions(fov=0, override={"metallic": 5})
    assert [err["loc"] for err in e.value.errors()] == [("fov",), ("override", "metallic")]
    assert e.value.errors()[0]["msg"] == "Input should be greater than or equal to 1"
    with pytest.raises(ValidationError, match="turntable and views cannot be combined"):
        from_request({"turntable": 3, "views": True})
    # what only pydantic converts still converts: a bool for an int, a dict for the override
    o = RenderOptions(turntable=True, override={"roughness": "0.25"})
    assert o.turntable == 1 and type(o.turntable) is int and o.override == MaterialOverride(roughness=0.25)


def test_flags_queries_and_variables_take_the_fast_path(monkeypatch):
    defaults = {n: p.default for n, p in declared(RenderOptions).items()}
    cli = {"width": 64, "height": 64, "fov": 30.0, "method": "raytrace", "background": "#FF8000",
           "time": "poster", "target": "1,2,3", "purposes": "render,proxy", "variant_set": ["a=b"],
           "lights": False, "override": MaterialOverride(base_color="ff8000", ior=1.7)}
    assert fast_values(RenderOptions, {**defaults, **cli}) is not None
    text = {"max_vertices": "1234", "ingest_seconds": "2.5", "max_archive_ratio": " 10 "}
    assert fast_values(Limits, {**{n: p.default for n, p in declared(Limits).items()}, **text}) is not None
    env = {"cache": "/tmp/somewhere", "bake_workers": "2", "executor": "ray", "cache_max_bytes": "2G"}
    assert fast_values(PipelineSettings, {**{n: p.default for n, p in declared(PipelineSettings).items()}, **env})
    assert fast_values(Settings, {**{n: p.default for n, p in declared(Settings).items()},
                                  "public_read": "true", "port": "8080", "samples": "/tmp/s"}) is not None


def test_a_cold_render_imports_no_pydantic():
    """What `asset-preview render` builds before its first image (the options from its flags,
    the pipeline's and renderer's settings, the bake and render modules) needs no pydantic."""
    code = """if True:
        import sys
        from cli.main import build_parser
        argv = ["render", "a.usda", "--out", "x.png", "--size", "64", "--background", "transparent",
                "--target", "0,1,0", "--base-color", "ff0000", "--env-rotation", "30"]
        args = build_parser(argv).parse_args(argv)
        from core.config import renderer_settings
        from core.options import from_arguments
        from pipeline.limits import Limits, pipeline_settings
        import pipeline.bake, pipeline.usd.stage, renderer.raster.render, renderer.sequence
        from_arguments(args); Limits.from_env(); pipeline_settings(); renderer_settings()
        print(sorted(m for m in sys.modules if m.split(".")[0] in ("pydantic", "pydantic_core")))
    """
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
