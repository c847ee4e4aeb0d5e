"""The one registry of render methods. A raster method draws the objects it owns into the
frame being rendered (`Pass`, `DrawItem`s: renderer.raster.passes); a frame method makes the
whole frame itself. `opaque` (plain PBR raster) and `auto` (renderer.methods.auto picks per
object) are the frame orchestration's own (renderer.raster.render). A new method is a module
and one line here."""
from __future__ import annotations

from typing import Callable

from core.baked import BakedAsset, BakedEnvironment
from core.options import RenderOptions
from renderer.frame import Frame
from renderer.methods import refraction
from renderer.raster.passes import DrawItem, Pass

Method = Callable[[Pass, list[DrawItem]], None]
FrameMethod = Callable[[BakedAsset, BakedEnvironment, RenderOptions], Frame]


def render_raytrace(asset: BakedAsset, env: BakedEnvironment, options: RenderOptions) -> Frame:
    """renderer.methods.raytrace.render_raytrace, imported when a frame is traced: the tracer's
    modules are a tenth of a cold raster render's own imports."""
    from renderer.methods import raytrace
    return raytrace.render_raytrace(asset, env, options)


METHODS: dict[str, Method] = {
    "single": refraction.draw_single,  # one refraction at the front face
    "wyman": refraction.draw_wyman,    # two, with Wyman's exit estimate
}
FRAME_METHODS: dict[str, FrameMethod] = {
    "raytrace": render_raytrace,  # Embree rays through the glass
}


class UnsupportedMethod(ValueError):
    """A render method that this build does not provide (message says which exist)."""


def available_methods() -> list[str]:
    return ["auto", "opaque", *METHODS, *FRAME_METHODS]


def validate_options(o: RenderOptions) -> None:
    """UnsupportedMethod for a method this build does not provide. Everything else a request
    can get wrong is refused when its RenderOptions is built (core/options.py)."""
    if o.method not in available_methods():
        raise UnsupportedMethod(
            f"method {o.method!r} is not available; available: {', '.join(available_methods())}")
