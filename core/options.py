"""Everything a render request can set, declared once.

`RenderOptions` (with `MaterialOverride`) is the single schema of a render: each field's type,
range, default and help live here and nowhere else. The command line (`add_arguments` /
`from_arguments`) and the HTTP query model (service.http.models.ThumbnailParams, its OpenAPI
description included) are derived from `request_fields()`, the flat view of these two classes
that both surfaces share, and a request crosses the process boundary as a `RenderOptions`.
Adding a render parameter means adding one field here, plus its implementation.

The classes are frozen dataclasses declared with core.schema's `knob`: constructing one checks
it (a `ValueError`: pydantic's ValidationError, worded as pydantic words it), and
`dataclasses.replace` and `dataclasses.asdict` work as on any dataclass. Checking a valid request
imports no pydantic (a cold command line's first image does not wait for it); the service's
pydantic models are built from the same declaration.
"""
from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import re
import types
import typing
from typing import Annotated, Any, Literal, Mapping

import numpy as np

from core.colour import srgb_to_linear
from core.schema import Bounds, Param, after, before, check, declared, knob

if typing.TYPE_CHECKING:
    from core.scene import Material

Method = Literal["auto", "opaque", "single", "wyman", "raytrace"]
METHODS: tuple[str, ...] = typing.get_args(Method)
Tonemap = Literal["neutral", "aces", "none"]
TONEMAPS: tuple[str, ...] = typing.get_args(Tonemap)
Purpose = Literal["render", "proxy", "guide"]
PURPOSES: tuple[str, ...] = typing.get_args(Purpose)
MAX_VARIANT_SELECTIONS = 32
REPEATABLE = frozenset({"variant_set"})  # given once per value (CLI: append; HTTP: repeated key)

MAX_PIXELS = 8192 * 8192
MAX_SIDE = 8192
MAX_DISTANCE = 1e12  # scene units (metres); beyond it the projection's arithmetic overflows
MAX_FRAMES = 120  # frames of a turntable or an animated image: past it is a video's job
MAX_BUDGET_MS = 60_000.0  # a render's time budget cannot exceed the service's render deadline

Unit = Annotated[float, Bounds(ge=0.0, le=1.0)]
_HEX = re.compile(r"^#?([0-9a-fA-F]{6})$")
_CONFIG = {"extra": "forbid", "allow_inf_nan": False}  # pydantic's, when it checks (core.schema)


@dataclasses.dataclass(frozen=True)
class MaterialOverride:
    """Per-request material applied to every mesh ("preview any mesh as glass or steel").
    None leaves the asset's own value."""
    PYDANTIC_CONFIG: typing.ClassVar[dict] = _CONFIG
    base_color: tuple[Unit, Unit, Unit] | None = knob(None, description=(
        "override base colour for every mesh: sRGB hex RRGGBB, or linear r,g,b in 0..1"))
    metallic: float | None = knob(None, ge=0, le=1, description="override metalness for every mesh")
    roughness: float | None = knob(None, ge=0, le=1, description="override roughness for every mesh")
    ior: float | None = knob(None, ge=1, le=3, description=(
        "override index of refraction for every mesh (with transmission: glass); 1..3 covers "
        "every common dielectric, diamond is 2.42"))
    transmission: float | None = knob(None, ge=0, le=1, description="override transmission, 0..1")

    def __post_init__(self) -> None:
        check(self)

    @before("base_color")
    def _parse_color(v: Any) -> Any:
        return parse_color(v) if isinstance(v, str) else v

    def is_empty(self) -> bool:
        return all(v is None for v in dataclasses.asdict(self).values())


@dataclasses.dataclass(frozen=True)
class RenderOptions:
    PYDANTIC_CONFIG: typing.ClassVar[dict] = _CONFIG
    width: int = knob(256, ge=1, le=MAX_SIDE, description="image width in pixels")
    height: int = knob(256, ge=1, le=MAX_SIDE, description="image height in pixels")
    # The default view is three-quarter from above, so a box shows three faces (renderer/view/camera.py).
    yaw: float = knob(35.0, ge=-3600, le=3600, description=(
        "camera turn about +Y, degrees; 0 looks from +Z, positive turns toward +X"))
    pitch: float = knob(25.0, ge=-90, le=90, description="camera elevation, degrees; positive looks down from above")
    fov: float = knob(40.0, ge=1, le=170, description="vertical field of view, degrees")
    distance: float | None = knob(None, gt=0, le=MAX_DISTANCE, description=(
        "camera distance from the bounds centre in scene units (default: fit the object)"))
    method: Method = knob("auto", description=(
        "auto picks per object; opaque ignores transmission; single / wyman are raster "
        "refraction; raytrace is the slow, accurate method"))
    tonemap: Tonemap = knob("neutral", description="tone mapping: Khronos PBR Neutral, ACES or none")
    exposure: float = knob(0.0, ge=-16, le=16, description="stops (EV): radiance is scaled by 2**exposure")
    background: str = knob("gradient", description=(
        "gradient (a light studio grey) | env (the environment's panorama) | transparent | sRGB colour #RRGGBB"))
    background_blur: float = knob(0.0, ge=0, le=1, description=(
        "roughness of the prefiltered environment mip shown behind the asset, 0..1"))
    shadow: float = knob(0.8, ge=0, le=1, description=(
        "ground contact shadow under the object, 0..1 (0: none; never with background env)"))
    turntable: int = knob(0, ge=0, le=MAX_FRAMES, description=(
        "frames of an animated image turning about +Y (.webp / .gif); 0: one still image"))
    views: bool = knob(False, description="a labelled 2 x 2 sheet: front, side, top, three-quarter")
    override: MaterialOverride | None = knob(None)
    antialias: Literal["edges", "msaa"] = knob("edges", description=(
        "edges: one shaded sample per pixel; each pixel a silhouette or boundary edge crosses is "
        "blended with its neighbour across it by the edge's position (on a par with 4x MSAA at "
        "a fraction of its cost on a CPU rasteriser); msaa: `msaa` samples per pixel"))
    msaa: int = knob(4, ge=0, le=16, description=(
        "antialias msaa: samples per pixel (0 or 1: no anti-aliasing, with either antialias)"))
    lights: bool = knob(True, description="the asset's own KHR_lights_punctual lights")
    light_shadows: bool = knob(True, description=(
        "the asset's lights cast shadows (shadow maps in the raster; a USD light's "
        "inputs:shadow:enable false casts none either way)"))
    multiscatter: bool = knob(True, description=(
        "multiple-scattering energy compensation of the GGX lobes (Fdez-Aguera 2019), as "
        "reference viewers do; off: single scattering, rough metals darken"))
    target: tuple[float, float, float] | None = knob(None, description=(
        "look-at point x,y,z in world units (default: the bounds centre)"))
    env_rotation: float = knob(0.0, ge=-3600, le=3600, description=(
        "environment turn about +Y, degrees; positive turns what was at +Z toward +X"))
    alpha: Literal["auto", "coverage"] = knob("auto", description=(
        "auto: opaque over an environment or colour background, coverage when transparent; "
        "coverage: the object's coverage whatever the background"))
    tir: Literal["paper", "reflect"] | None = knob(None, description=(
        "wyman: total internal reflection treatment (default: reflect)"))
    # Defaults from issue 26's front (`bench accuracy --front`, bench/RESULTS.md): 12 bounces
    # with roulette (3 x 3 rays at 128-383 px) at ~0.4x the old default's (8, both, 4 x 4) time
    # for +0.011 mean FLIP, on most scenes' Pareto front, at about Mitsuba 16 spp's time.
    bounces: int = knob(12, ge=0, le=64, description="raytrace: path depth (0: the environment along each primary ray)")
    fresnel_split: Literal["both", "sample", "roulette"] = knob("roulette", description=(
        "raytrace: at each interface trace both the reflected and the refracted ray (both: "
        "no noise) or, past the first surface a camera ray meets, one of them chosen with "
        "probability proportional to its throughput and reweighted (sample: unbiased, about "
        "half the rays, some noise) or both but a child carrying under 10% by Russian "
        "roulette (roulette: unbiased, noise only in the weak paths)"))
    rough_lobes: Literal["sample", "prefilter"] = knob("sample", description=(
        "raytrace: rough glass reflects and refracts about GGX microfacet normals sampled per "
        "ray (sample: converges to the rough dielectric, some noise) or keeps the mirror "
        "direction and reads the prefiltered environment for the lobe width (prefilter: no "
        "noise, biased)"))
    integrator: Literal["tree", "path"] = knob("tree", description=(
        "raytrace: tree: the deterministic Fresnel tree (exact two-interface glass, no noise); "
        "path: unbiased path tracing of the whole metal-rough material with environment "
        "importance sampling and MIS, in passes until `noise`, `samples` or `budget_ms`"))
    samples: int = knob(64, ge=1, le=4096, description=(
        "raytrace integrator path: most paths per pixel (one per pass)"))
    noise: float = knob(0.02, ge=0, le=1, description=(
        "raytrace integrator path: a pixel stops when the relative standard error of its "
        "luminance is below this (0: run all samples or the budget)"))
    supersample: int | None = knob(None, ge=1, le=16, description=(
        "raytrace: rays per pixel side on and around the object (default: 4 below 128 px, "
        "3 below 384, else 2)"))
    aa_threshold: float = knob(0.0, ge=0, le=1, description=(
        "raytrace: adaptive anti-aliasing: with supersample above 2, pixels near the object "
        "get 2 x 2 rays first and the full grid only where those differ in coverage or in "
        "tone-mapped luminance L/(1+L) by more than this (0: the full grid everywhere)"))
    debug: Literal["backface_normals", "tir", "exit_distance"] | None = knob(None, description="wyman debug view")
    variant: str | None = knob(None, min_length=1, max_length=256, description=(
        "glTF KHR_materials_variants: bind the material variant of this name (inspect lists them)"))
    camera: str | None = knob(None, min_length=1, max_length=256, description=(
        "render through the asset's own camera, by index N or by name (inspect lists them); "
        "yaw, pitch and distance are then unused"))
    material_debug: Literal["base", "clearcoat", "sheen", "specular", "iridescence",
                            "transmission"] | None = knob(
        None, description=(
            "show one material lobe alone: base (diffuse + specular under the layers), "
            "clearcoat, sheen (each lit as in the frame), specular (the base's normal-incidence "
            "reflectance F0 from IOR and KHR_materials_specular), iridescence (the thin film's "
            "reflectance at the view angle) or transmission (the share "
            "that refracts through, tinted and attenuated by the volume)"))
    time: str | None = knob(None, max_length=32, description=(
        "pose the asset at this moment of its animation: SECONDS (glTF seconds; USD seconds from "
        "the stage's start, through timeCodesPerSecond) or poster (the middle of the animation); "
        "default: at rest (docs/animation.md)"))
    animation: str | None = knob(None, min_length=1, max_length=256, description=(
        "glTF: the animation --time and --animate play, by index N or by name (inspect lists "
        "them; default: the first)"))
    animate: float | None = knob(None, ge=1, le=60, description=(
        "frames per second of an animated image (.webp .gif .png) of the asset's animation, "
        "its whole duration (at most 120 frames); with turntable the camera also turns once"))
    budget_ms: float | None = knob(None, gt=0, le=MAX_BUDGET_MS, description=(
        "time budget in milliseconds: lets method auto ray trace objects where raster "
        "refraction fails or only approximates (attenuation, dispersion, textured glass), when "
        "the estimate fits; raytrace integrator path stops its passes "
        "before this is spent (granularity: one pass)"))
    # USD stage population: bake options (pipeline.bake.asset_options), so in the bake key too
    variant_set: tuple[str, ...] = knob((), max_length=MAX_VARIANT_SELECTIONS, description=(
        "USD: select a variant, [PRIM:]SET=NAME (repeatable, applied in order, so a selection "
        "may name a set an earlier one brought in; no PRIM: the default prim's set; inspect "
        "lists them)"))
    purposes: tuple[Purpose, ...] = knob(("render",), description=(
        "USD: the purposes drawn besides default, comma-separated from render, proxy, guide "
        "(usdview's toggles; default render; empty: default only)"))
    draw_mode: Literal["authored", "full"] = knob("authored", description=(
        "USD: authored draws the model:drawMode stand-ins a stage asks for (origin axes, "
        "bounds box, cards), as usdview does; full draws those models' geometry instead"))

    @before("background")
    def _background(v: Any) -> Any:
        if not isinstance(v, str):
            return v
        s = v.strip().lower()
        if s in ("gradient", "env", "transparent"):
            return s
        m = _HEX.match(s)
        if not m:
            raise ValueError(f"background {v!r}: use gradient, env, transparent or a colour #rrggbb")
        return "#" + m.group(1)

    @before("time")
    def _time(v: Any) -> Any:
        if v is None:
            return v
        s = str(v).strip().lower()
        if s == "poster":
            return s
        try:
            t = float(s)
        except ValueError:
            t = math.nan
        if not (math.isfinite(t) and abs(t) <= 1e6):
            raise ValueError(f"time {v!r}: use seconds (a finite number) or poster")
        return repr(t)

    @before("variant_set")
    def _variant_set(v: Any) -> Any:
        items = (v,) if isinstance(v, str) else tuple(v or ())
        for text in items:
            if not isinstance(text, str):
                return v  # pydantic names the type error
            where, _, choice = text.rpartition("=")
            if not where.rpartition(":")[2] or not choice or len(text) > 512:
                raise ValueError(f"variant_set {text!r}: expected [PRIM:]SET=NAME")
        return items

    @before("purposes")
    def _purposes(v: Any) -> Any:
        """"render,proxy" (CLI, query) or a sequence; one canonical order, so one key."""
        items = [v] if isinstance(v, str) else list(v or ())
        names = {p.strip().lower() for item in items if isinstance(item, str)
                 for p in item.split(",") if p.strip()}
        unknown = names - set(PURPOSES)
        if unknown:
            raise ValueError(f"purposes: unknown {', '.join(sorted(unknown))}; choose from "
                             f"{', '.join(PURPOSES)} (default is always drawn)")
        return tuple(p for p in PURPOSES if p in names)

    @before("target")
    def _target(v: Any) -> Any:
        if isinstance(v, str):
            try:
                v = tuple(float(x) for x in v.split(","))
            except ValueError:
                v = ()
            if len(v) != 3:
                raise ValueError("target: expected three numbers x,y,z")
        if v is not None and not all(math.isfinite(x) and abs(x) <= MAX_DISTANCE for x in v):
            raise ValueError(f"target: coordinates must be finite and within {MAX_DISTANCE:g}")
        return v

    def __post_init__(self) -> None:
        check(self)

    @after
    def _pixels(self) -> None:
        if self.width * self.height > MAX_PIXELS:
            raise ValueError(f"image size {self.width}x{self.height} is over {MAX_PIXELS} pixels")
        if self.turntable and self.views:
            raise ValueError("turntable and views cannot be combined")
        if self.animate and (self.views or self.time is not None):
            raise ValueError("animate plays the whole animation: it takes neither views nor time")
        if self.override is not None and all(v is None for v in dataclasses.asdict(self.override).values()):
            object.__setattr__(self, "override", None)  # one spelling of "no override"

    def replace(self, **changes) -> "RenderOptions":
        return dataclasses.replace(self, **changes)

    def key_dict(self) -> dict:
        """Every field, floats rounded so that equal requests give equal cache keys."""
        def norm(v):
            if isinstance(v, float):
                return round(v, 4)
            if isinstance(v, (tuple, list)):
                return [norm(x) for x in v]
            if isinstance(v, dict):
                return {k: norm(x) for k, x in v.items()}
            return v
        return norm(dataclasses.asdict(self))


def apply_override(mat: "Material", ov: MaterialOverride | None) -> "Material":
    """`mat` with the request's override applied (a texture an override replaces is dropped)."""
    if ov is None or ov.is_empty():
        return mat
    changes: dict = {}
    if ov.base_color is not None:
        changes["base_color"] = (*map(float, ov.base_color[:3]), mat.base_color[3])
        changes["base_color_texture"] = None
    for name in ("metallic", "roughness", "ior", "transmission"):
        if getattr(ov, name) is not None:
            changes[name] = float(getattr(ov, name))
    if ov.metallic is not None and ov.roughness is not None:
        changes["metallic_roughness_texture"] = None
    if ov.transmission is not None:
        changes["transmission_texture"] = None
        changes["thin_walled"] = False  # "preview as glass" means a solid of the mesh's shape
    return dataclasses.replace(mat, **changes)


def background_rgb(spec: str) -> tuple[float, float, float] | None:
    """A validated `background`: `gradient` / `env` / `transparent` -> None; `#rrggbb` -> sRGB in 0..1."""
    if spec in ("gradient", "env", "transparent"):
        return None
    s = spec.lstrip("#")
    return tuple(int(s[i:i + 2], 16) / 255 for i in (0, 2, 4))  # type: ignore[return-value]


def parse_color(text: str) -> tuple[float, float, float]:
    """`RRGGBB` / `#RRGGBB` (sRGB, as people pick colours) or `r,g,b` (linear) -> linear RGB."""
    m = _HEX.match(text.strip())
    if m:
        rgb8 = np.array([int(m.group(1)[i:i + 2], 16) for i in (0, 2, 4)], np.uint8)
        return tuple(round(float(c), 6) for c in srgb_to_linear(rgb8))  # type: ignore[return-value]
    try:
        rgb = tuple(float(x) for x in text.split(","))
    except ValueError:
        rgb = ()
    if len(rgb) != 3 or not all(math.isfinite(c) for c in rgb):
        raise ValueError(f"colour {text!r}: expected sRGB hex RRGGBB or linear r,g,b")
    return rgb  # type: ignore[return-value]


# --- the flat request: what the CLI and HTTP surfaces expose ---------------------------------

SIZE_FIELD = Param(int, 256, "width and height in pixels, unless those are given", Bounds(ge=1, le=MAX_SIDE))


@functools.cache
def request_fields() -> Mapping[str, Param]:
    """RenderOptions flattened for a query string or a command line: `size` for width and
    height, and the MaterialOverride fields in place of `override`. Width and height default
    to None there (meaning: `size`). Built once (every HTTP thumbnail request checks against
    it), read-only."""
    out: dict[str, Param] = {"size": SIZE_FIELD}
    for name, info in declared(RenderOptions).items():
        if name == "override":
            out.update(_override_fields())
        elif name in ("width", "height"):
            out[name] = dataclasses.replace(info, annotation=info.annotation | None, default=None)
        elif name in ("target", "purposes"):  # "x,y,z" / "render,proxy" on both surfaces, parsed by RenderOptions
            out[name] = Param(str | None, None, info.description)
        else:
            out[name] = info
    return types.MappingProxyType(out)


def _override_fields() -> dict[str, Param]:
    fields = declared(MaterialOverride)
    fields["base_color"] = Param(str | None, None, fields["base_color"].description)  # parsed by MaterialOverride
    return fields


def from_request(values: Mapping[str, Any]) -> RenderOptions:
    """The RenderOptions of a flat request (unset or None values take their defaults)."""
    given = {k: v for k, v in values.items() if v is not None}
    unknown = set(given) - set(request_fields())
    if unknown:
        raise ValueError(f"unknown render parameter(s): {', '.join(sorted(unknown))}")
    size = given.pop("size", None)
    if size is not None:
        given.setdefault("width", size)
        given.setdefault("height", size)
    override_names = declared(MaterialOverride).keys()
    ov = {k: given.pop(k) for k in list(given) if k in override_names}
    if ov:
        given["override"] = MaterialOverride(**ov)
    return RenderOptions(**given)


# --- the command line ------------------------------------------------------------------------

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """One flag per request field: `--name-with-dashes`, type, choices and help from the schema."""
    group = parser.add_argument_group("render options (renderer/options.py)")
    for name, info in request_fields().items():
        flag = "--" + name.replace("_", "-")
        ann = _strip_optional(info.annotation)
        default = info.default
        help_text = (info.description or "") + (f" (default: {default})" if default is not None else "")
        help_text = help_text.replace("%", "%%")
        if ann is bool:
            group.add_argument(flag, dest=name, action=argparse.BooleanOptionalAction,
                               default=None, help=help_text)
        elif name in REPEATABLE:
            group.add_argument(flag, dest=name, action="append", default=None, help=help_text,
                               metavar=name.upper())
        elif typing.get_origin(ann) is Literal:
            group.add_argument(flag, dest=name, choices=typing.get_args(ann), default=None, help=help_text)
        else:
            kind = ann if ann in (int, float) else str
            group.add_argument(flag, dest=name, type=kind, default=None, help=help_text,
                               metavar=name.upper())


def from_arguments(args: argparse.Namespace) -> RenderOptions:
    """The RenderOptions of parsed `add_arguments` flags."""
    return from_request({name: getattr(args, name, None) for name in request_fields()})


def _strip_optional(ann):
    if typing.get_origin(ann) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(ann) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return ann


def describe_error(exc: ValueError) -> str:
    """A refused request as one line a person reads: `field: reason; field: reason` for
    pydantic's ValidationError (core.schema raises it), the message of any other ValueError."""
    if not callable(getattr(exc, "errors", None)):
        return str(exc)
    parts = []
    for e in exc.errors(include_url=False):  # type: ignore[attr-defined]  # a ValidationError
        loc = ".".join(str(x) for x in e["loc"] if x != "override") or "options"
        given = e.get("input")
        shown = f" {given!r}" if isinstance(given, (int, float, str)) and loc != "options" else ""
        parts.append(f"{loc}{shown}: {e['msg']}")
    return "; ".join(parts)
