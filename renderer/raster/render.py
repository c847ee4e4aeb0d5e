"""`render(asset, env, options) -> Frame`: one offscreen frame of a baked asset.

Passes: opaque and mask meshes, transmissive meshes by their method, blend meshes back to
front, all into one float framebuffer (one sample per pixel, then the edges smoothed by
renderer.raster.edges; or MSAA, antialias=msaa); then the final pass (resolve + background +
shadow + tone mapping, shaders/final.frag) into RGBA8, drawn per region with only the work
each region's pixels need (renderer.view.regions), and its readback. The linear float image is
drawn by the same pass and read only when the frame's `linear` is first asked for (a
thumbnail never asks): before the next frame draws over the target if the frame is still
referenced then.

Methods plug in per object: `register_method(name, fn)` adds a raster method (the refraction
module adds `single` and `wyman`), `register_frame_method(name, fn)` a whole-frame one
(`raytrace`). A method receives the `Pass` and the `DrawItem`s it owns.
"""
from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
import weakref
from dataclasses import dataclass, field
from typing import Callable, cast

import moderngl
import numpy as np

from core.baked import BakedAsset, BakedEnvironment
from core.cubemap import env_rotation_matrix
from core.options import RenderOptions, apply_override, background_rgb
from core.scene import Material, is_srgb
from gl import context
from renderer.frame import Frame, FrameTimings, alpha_is_mask, exposure_scale
from renderer.raster import edges, gpu, shadow
from renderer.view import regions
from renderer.view.camera import Camera
from renderer.view.framing import asset_camera

log = logging.getLogger(__name__)

MAX_LIGHTS = 8
GRADIENT = ((0.95, 0.95, 0.95), (0.80, 0.80, 0.81))  # background "gradient": sRGB top, bottom
_TONEMAPS = {"none": 0, "neutral": 1, "aces": 2}
_SLOTS = ("base_color", "metallic_roughness", "normal", "occlusion", "emissive",
          "specular", "specular_color", "clearcoat", "clearcoat_roughness", "clearcoat_normal",
          "sheen_color", "sheen_roughness", "transmission", "thickness", "iridescence",
          "iridescence_thickness", "anisotropy", "diffuse_transmission",
          "diffuse_transmission_color")
# Slots read only when their lobe is compiled in (Material.uses).
_LOBE_OF_SLOT = {"specular": "specular", "specular_color": "specular", "clearcoat": "clearcoat",
                 "clearcoat_roughness": "clearcoat", "clearcoat_normal": "clearcoat",
                 "sheen_color": "sheen", "sheen_roughness": "sheen",
                 "transmission": "transmission", "thickness": "transmission",
                 "iridescence": "iridescence", "iridescence_thickness": "iridescence",
                 "anisotropy": "anisotropy", "diffuse_transmission": "diffuse_transmission",
                 "diffuse_transmission_color": "diffuse_transmission"}
_LOBES = ("ior", "specular", "clearcoat", "sheen", "iridescence", "anisotropy",
          "diffuse_transmission", "dispersion")
# Texture units: 0 environment, 1 BRDF LUT, then one per material slot; passes that bind more
# (renderer.methods.refraction) start at FIRST_FREE_UNIT.
FIRST_FREE_UNIT = 2 + len(_SLOTS)
MATERIAL_DEBUG_VIEWS = {"base": 1, "clearcoat": 2, "sheen": 3, "specular": 4, "transmission": 5,
                        "iridescence": 6}


class UnsupportedMethod(ValueError):
    """A render method that this build does not provide (message says which exist)."""


@dataclass
class DrawItem:
    """One baked mesh as drawn this frame: its GPU data and its material after overrides."""
    mesh: gpu.GpuMesh
    material: Material
    method: str
    why: str


@dataclass
class _MaterialState:
    defines: dict
    uniforms: list[tuple[str, object]]
    textures: list[tuple[str, moderngl.Texture]]


@dataclass
class Pass:
    """What a method needs to draw into the frame being rendered."""
    ctx: moderngl.Context
    fbo: moderngl.Framebuffer
    camera: Camera
    env: gpu.GpuEnvironment
    asset: gpu.GpuAsset
    options: RenderOptions
    frame_defines: dict
    frame_uniforms: dict[str, bytes]
    opaque_drawn: bool = False  # the opaque pass has drawn into fbo (refraction reads it)
    _bound: set = field(default_factory=set)

    def program(self, item: DrawItem, fragment: str = "pbr.frag", vertex: str = "pbr.vert",
                extra_defines: dict | None = None) -> tuple[moderngl.Program, _MaterialState]:
        """The program for `item`'s material with this frame's uniforms set."""
        state = _material_state(item, self)
        defines = {**self.frame_defines, **state.defines, **(extra_defines or {})}
        prog = context.program(vertex, fragment, defines)
        if prog.glo not in self._bound:
            for name, data in self.frame_uniforms.items():
                if name in prog:
                    prog[name].write(data)  # type: ignore[union-attr]  # a uniform
            for unit, name in ((0, "u_env"), (1, "u_brdf_lut")):
                if name in prog:
                    prog[name].value = unit  # type: ignore[union-attr]  # a uniform
            self._bound.add(prog.glo)
        return prog, state

    def draw(self, item: DrawItem, prog: moderngl.Program, state: _MaterialState,
             cull: bool | None = None) -> None:
        """Draw every instance of `item` with `prog` (material uniforms and textures bound)."""
        for name, value in state.uniforms:
            if name in prog:
                prog[name].write(value)  # type: ignore[union-attr]  # a uniform
        for unit, (name, tex) in enumerate(state.textures, start=2):
            if name in prog:
                prog[name].value = unit  # type: ignore[union-attr]  # a uniform
                tex.use(unit)
        self.env.cube.use(0)
        self.env.lut.use(1)
        cull = (not item.material.double_sided) if cull is None else cull
        for mirrored, _, count in item.mesh.instances:
            # A mirroring transform turns the winding clockwise (glTF 2.0, "Instantiation"):
            # the front face follows it for culling and for gl_FrontFacing, which flips a
            # double-sided material's normal.
            self.ctx.front_face = "cw" if mirrored else "ccw"
            if cull:
                self.ctx.enable(moderngl.CULL_FACE)
            else:
                self.ctx.disable(moderngl.CULL_FACE)
            item.mesh.vao(prog, mirrored).render(moderngl.TRIANGLES, instances=count)
        self.ctx.front_face = "ccw"


Method = Callable[[Pass, list[DrawItem]], None]
FrameMethod = Callable[[BakedAsset, BakedEnvironment, RenderOptions], Frame]

_METHODS: dict[str, Method] = {}
_FRAME_METHODS: dict[str, FrameMethod] = {}


def register_method(name: str, fn: Method) -> None:
    _METHODS[name] = fn


def register_frame_method(name: str, fn: FrameMethod) -> None:
    _FRAME_METHODS[name] = fn


def available_methods() -> list[str]:
    _load_plugins()
    return ["auto", "opaque", *_METHODS, *_FRAME_METHODS]


def _load_plugins() -> None:
    """Import the optional method modules once (they register themselves)."""
    if _load_plugins.done:  # type: ignore[attr-defined]  # a function attribute
        return
    _load_plugins.done = True  # type: ignore[attr-defined]
    import importlib
    for name in ("renderer.methods.refraction", "renderer.methods.raytrace"):
        try:
            importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:
                raise


_load_plugins.done = False  # type: ignore[attr-defined]


def render(asset: BakedAsset, env: BakedEnvironment, options: RenderOptions) -> Frame:
    """Render `asset` lit by `env` as `options` say. Raises UnsupportedMethod or ValueError
    for options this build cannot honour."""
    validate_options(options)
    asset = asset.with_variant(options.variant)  # KHR_materials_variants: its own GPU key
    if options.method in _FRAME_METHODS:
        return _FRAME_METHODS[options.method](asset, env, options)
    auto, raster_options = _plan_auto(asset, options)
    if auto is not None and auto.frame_method:
        from renderer.methods.auto import run_frame_method
        return run_frame_method(auto, _FRAME_METHODS[auto.frame_method], asset, env, options)
    with _lock:  # one GL context per process: one frame at a time
        return _render(asset, env, raster_options, auto)


def _plan_auto(asset: BakedAsset, options: RenderOptions):
    """For method "auto", renderer.methods.auto's plan (per object, or a frame method) and the options
    the raster frame is drawn with (the plan's TIR mode); (None, options) otherwise."""
    if options.method != "auto":
        return None, options
    from renderer.methods.auto import plan_request
    auto = plan_request(asset, options, available_methods())
    if auto.tir and not auto.frame_method:
        options = dataclasses.replace(options, tir=auto.tir)
    return auto, options


def render_supersampled(asset: BakedAsset, env: BakedEnvironment, options: RenderOptions,
                        factor: int = 4) -> Frame:
    """The raster frame with `factor` x `factor` samples per pixel, each shaded (no MSAA),
    averaged by the final pass before tone mapping as MSAA samples are: the anti-aliasing
    reference that the default frame's edges are measured against (bench thumbnail,
    tests/test_antialiasing.py). Slow: factor**2 times the shading work."""
    validate_options(options)
    asset = asset.with_variant(options.variant)
    if options.method in _FRAME_METHODS:
        raise UnsupportedMethod(f"method {options.method!r} draws no raster frame to supersample")
    auto, options = _plan_auto(asset, options)
    if auto is not None and auto.frame_method:
        raise UnsupportedMethod(f"auto chose {auto.frame_method}: no raster frame to supersample")
    with _lock:
        return _render(asset, env, dataclasses.replace(options, msaa=0), auto, int(factor))


_lock = threading.RLock()


def _render(asset: BakedAsset, env: BakedEnvironment, options: RenderOptions,
            auto=None, supersample: int = 1) -> Frame:
    t0 = time.perf_counter()
    ctx = context.get_context()
    _read_pending()
    uploads_before = dict(gpu.stats)
    gasset = gpu.asset(asset, max(options.width, options.height) * supersample)
    genv = gpu.environment(env)
    t_upload = time.perf_counter()

    w, h = options.width, options.height
    camera, shadowed, shadow_why = asset_camera(asset, options)
    items = _plan_items(gasset, options, auto)
    lights = gasset.lights[:MAX_LIGHTS] if options.lights else []
    edge_aa = _edge_antialiasing(asset, options, supersample)
    target = _target(ctx, w, h, 0 if edge_aa else options.msaa, supersample, edge_aa)
    target.frames += 1
    pass_ = Pass(ctx, target.draw_fbo, camera, genv, gasset, options,
                 _frame_defines(options, lights), _frame_uniforms(camera, genv, lights, options))
    # The object's bound for the final pass's regions: a rectangle for an edge-smoothed frame,
    # else a polygon marked before the geometry (llvmpipe draws it while Python goes on).
    polygon = rect = None
    if edge_aa:
        rect = regions.object_rect(camera, regions.hull_points(asset), w, h)
    else:
        polygon = regions.object_polygon(camera, regions.hull_points(asset), w, h)
        if polygon is not None:
            _mark_object(ctx, target.display_fbo, polygon, w, h)

    target.draw_fbo.use()
    ctx.viewport = (0, 0, w * supersample, h * supersample)
    # Cleared whole: llvmpipe clears a scissored part of an MSAA target by drawing, slower.
    target.draw_fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
    ctx.disable(moderngl.BLEND)
    ctx.enable(moderngl.DEPTH_TEST)
    target.draw_fbo.depth_mask = True

    by_method: dict[str, list[DrawItem]] = {}
    blend = []
    for it in items:
        if it.method == "opaque" and it.material.alpha_mode == "BLEND":
            blend.append(it)
        else:
            by_method.setdefault(it.method, []).append(it)
    if "opaque" in by_method:
        _draw_opaque(pass_, by_method.pop("opaque"))
        pass_.opaque_drawn = True
    for method, its in by_method.items():
        _METHODS[method](pass_, its)
        target.draw_fbo.use()
    if blend:
        _draw_blend(pass_, blend)
    ctx.disable(moderngl.CULL_FACE)
    ctx.disable(moderngl.DEPTH_TEST)
    ctx.disable(moderngl.BLEND)
    if target.edge_fbo is not None and target.depth_tex is not None:
        edges.draw(ctx, target.edge_fbo, target.depth_tex, _edge_segments(items, camera),
                   camera.projection_matrix() @ camera.view_matrix(), w, h)
    t_draw = time.perf_counter()

    t_shadow = time.perf_counter()
    ground = (shadow.ground_shadow(ctx, asset.key, gasset.meshes, asset.bounds, options.shadow)
              if shadowed else None)
    t_draw_end = time.perf_counter()
    final = _final_pass(target, camera, genv, options, ground, polygon, rect)
    rgba8 = final.draw(ctx, DISPLAY)
    linear = _LinearOnDemand(ctx, final)
    _pending.append(weakref.ref(linear))
    t_end = time.perf_counter()
    plan = {
        "method": options.method,
        "objects": [{"mesh": it.mesh.baked.name, "class": it.material.material_class,
                     "method": it.method, "why": it.why} for it in items],
        "lights": len(lights),
        "environment": env.name,
        "background": options.background,
        "shadow": shadow_why if shadowed else f"none: {shadow_why}",
        "view": {"yaw": options.yaw, "pitch": options.pitch,
                 "distance": round(float(np.linalg.norm(camera.position - camera.target)), 6)},
        "tonemap": options.tonemap,
        "antialias": "edges" if edge_aa else "msaa" if target.samples else "none",
        "msaa": target.samples,
        **({"supersample": supersample} if supersample > 1 else {}),
        "uploaded": {k: gpu.stats[k] - uploads_before[k] for k in ("asset_uploads", "environment_uploads")},
    }
    if auto is not None:
        plan["auto"] = auto.explain()
    timings = FrameTimings((t_end - t0) * 1e3, {"upload": (t_upload - t0) * 1e3,
                                                "draw": (t_draw - t_upload) * 1e3,
                                                "shadow": (t_draw_end - t_shadow) * 1e3,
                                                "finish": (t_end - t_draw_end) * 1e3})
    return Frame(linear, rgba8, plan, timings, alpha_is_mask=alpha_is_mask(options))


def _edge_antialiasing(asset: BakedAsset, options: RenderOptions, supersample: int) -> bool:
    """Whether the frame is smoothed by renderer.raster.edges rather than by MSAA samples."""
    return (options.antialias == "edges" and options.msaa > 1 and supersample == 1
            and asset.triangle_count <= edges.MAX_TRIANGLES)


def _edge_segments(items: list[DrawItem], camera: Camera) -> np.ndarray:
    """World endpoints of every drawn mesh's edges to smooth (renderer.raster.edges) from `camera`."""
    parts = []
    for it in items:
        if it.mesh.edges is None:  # once per upload, from the baked edges where there are some
            it.mesh.edges = edges.of_mesh(it.mesh.baked)
        parts.append(edges.segments(it.mesh.edges, it.mesh.baked.transforms, camera.position))
    return np.concatenate(parts) if parts else np.zeros((0, 2, 3))


def validate_options(o: RenderOptions) -> None:
    """UnsupportedMethod for a method this build does not provide. Everything else a request
    can get wrong is refused when its RenderOptions is built (renderer/options.py)."""
    _load_plugins()  # the method list is only complete once the plugins have registered
    if o.method not in ("auto", "opaque") and o.method not in _METHODS and o.method not in _FRAME_METHODS:
        raise UnsupportedMethod(
            f"method {o.method!r} is not available in this build (refraction and ray tracing "
            f"methods are not installed); available: {', '.join(available_methods())}")


# --- planning -------------------------------------------------------------------------------

def _plan_items(gasset: gpu.GpuAsset, options: RenderOptions, auto=None) -> list[DrawItem]:
    items = []
    for i, gm in enumerate(gasset.meshes):
        mat = apply_override(gm.baked.material, options.override)
        method, why = auto.method_for(i) if auto is not None else _choose_method(mat, options)
        items.append(DrawItem(gm, mat, method, why))
    return items


def _choose_method(mat: Material, options: RenderOptions) -> tuple[str, str]:
    """The method a request names (`auto` is decided by renderer.methods.auto's plan instead)."""
    cls = mat.material_class
    if cls != "transmissive":
        return "opaque", f"{cls} material: PBR + IBL raster"
    if options.method == "opaque":
        return "opaque", "method opaque requested: transmission ignored"
    return options.method, f"method {options.method} requested"


# --- per-material and per-frame state --------------------------------------------------------

def _material_state(item: DrawItem, p: Pass) -> _MaterialState:
    """Defines, uniform bytes and textures for a mesh's material; cached on the GPU mesh."""
    ov = p.options.override
    key = ov
    cached = item.mesh.states.get(key)
    if cached is not None:
        return cached
    m, mesh = item.material, item.mesh.baked
    defines: dict = {}
    uv_sets = {0: mesh.uv0 is not None, 1: mesh.uv1 is not None}
    if uv_sets[0]:
        defines["HAS_UV0"] = 1
    textures = []
    uniforms: list[tuple[str, object]] = []
    lobes = {lobe for lobe in _LOBES if m.uses(lobe)}
    for lobe in lobes:
        defines[f"MATERIAL_{lobe.upper()}"] = 1
    if m.material_class == "transmissive":  # its maps are read by shaders/refraction.frag
        lobes.add("transmission")
    for slot in _SLOTS:
        ref = getattr(m, f"{slot}_texture")
        if ref is None or _LOBE_OF_SLOT.get(slot, "base") not in lobes | {"base"}:
            continue
        tex = p.asset.textures.get((ref.texture, is_srgb(slot)))
        if tex is None or not uv_sets.get(ref.uv_set, False):
            log.warning("%s: %s texture skipped (no image or no UV set %d)", mesh.name, slot, ref.uv_set)
            continue
        defines[f"HAS_{slot.upper()}_MAP"] = 1
        defines[f"{slot.upper()}_UV"] = f"v_uv{ref.uv_set}"
        if ref.uv_set == 1:
            defines["HAS_UV1"] = 1
        textures.append((f"u_{slot}_map", tex))
        uniforms.append((f"u_{slot}_uvm", _mat3_bytes(ref.uv_matrix())))
    needs_frame = {"HAS_NORMAL_MAP", "HAS_CLEARCOAT_NORMAL_MAP", "MATERIAL_ANISOTROPY"} & set(defines)
    if needs_frame and mesh.tangents is not None:
        defines["HAS_TANGENTS"] = 1
    if mesh.colors is not None:
        defines["HAS_COLORS"] = 1
    if m.double_sided:
        defines["DOUBLE_SIDED"] = 1
    if m.alpha_mode == "MASK":
        defines["ALPHA_MASK"] = 1
    elif m.alpha_mode == "BLEND":
        defines["ALPHA_BLEND"] = 1
    if m.unlit:
        defines["UNLIT"] = 1
    if ov is not None and ov.metallic is not None:
        defines["METALLIC_OVERRIDDEN"] = 1
    if ov is not None and ov.roughness is not None:
        defines["ROUGHNESS_OVERRIDDEN"] = 1
    f4 = np.float32
    emissive = np.asarray(m.emissive, f4) * f4(m.emissive_strength)
    uniforms += [
        ("u_base_color", np.asarray(m.base_color, f4).tobytes()),
        ("u_metallic", f4(m.metallic).tobytes()),
        ("u_roughness", f4(m.roughness).tobytes()),
        ("u_normal_scale", f4(m.normal_scale).tobytes()),
        ("u_occlusion_strength", f4(m.occlusion_strength).tobytes()),
        ("u_emissive", emissive.tobytes()),
        ("u_alpha_cutoff", f4(m.alpha_cutoff).tobytes()),
        ("u_ior", f4(max(m.ior, 1.0)).tobytes()),
    ]
    if "specular" in lobes:
        uniforms += [("u_specular", f4(m.specular).tobytes()),
                     ("u_specular_color", np.asarray(m.specular_color, f4).tobytes())]
    if "clearcoat" in lobes:
        uniforms += [("u_clearcoat", f4(m.clearcoat).tobytes()),
                     ("u_clearcoat_roughness", f4(m.clearcoat_roughness).tobytes()),
                     ("u_clearcoat_normal_scale", f4(m.clearcoat_normal_scale).tobytes())]
    if "dispersion" in lobes:  # shaders/refraction.frag
        iors = m.channel_iors()
        uniforms += [("u_dispersion", f4((iors[2] - iors[0]) / 2).tobytes())]
    if "diffuse_transmission" in lobes:
        uniforms += [("u_diffuse_transmission", np.asarray(
            [*m.diffuse_transmission_color, m.diffuse_transmission], f4).tobytes())]
    if "anisotropy" in lobes:
        c, s_ = math.cos(m.anisotropy_rotation), math.sin(m.anisotropy_rotation)
        uniforms += [("u_anisotropy", np.asarray([c, s_, m.anisotropy_strength], f4).tobytes())]
    if "iridescence" in lobes:
        uniforms += [("u_iridescence", f4(m.iridescence).tobytes()),
                     ("u_iridescence_ior", f4(m.iridescence_ior).tobytes()),
                     ("u_iridescence_thickness", np.asarray(m.iridescence_thickness_range, f4).tobytes())]
    if "sheen" in lobes:
        uniforms += [("u_sheen_color", np.asarray(m.sheen_color, f4).tobytes()),
                     ("u_sheen_roughness", f4(m.sheen_roughness).tobytes())]
    state = _MaterialState(defines, uniforms, textures)
    if len(item.mesh.states) >= 32:  # many distinct overrides (a service): keep it bounded
        item.mesh.states.clear()
    item.mesh.states[key] = state
    return state


def _mat3_bytes(m: np.ndarray) -> bytes:
    return np.ascontiguousarray(np.asarray(m, np.float32).T).tobytes()  # GLSL: column-major


def _env_rotated(options: RenderOptions) -> bool:
    return options.env_rotation % 360.0 != 0.0


def _frame_defines(options: RenderOptions, lights) -> dict:
    d = {"LIGHT_COUNT": len(lights)}
    if options.multiscatter:
        d["MULTISCATTER"] = 1
    if options.material_debug:  # shaders/lobes.glsl: one lobe alone
        d["MATERIAL_DEBUG"] = MATERIAL_DEBUG_VIEWS[options.material_debug]
    if _env_rotated(options):
        d["ENV_ROTATED"] = 1
    return d


def _frame_uniforms(camera: Camera, env: gpu.GpuEnvironment, lights,
                    options: RenderOptions) -> dict[str, bytes]:
    f4 = np.float32
    view_proj = camera.projection_matrix() @ camera.view_matrix()
    u = {
        "u_view_proj": np.ascontiguousarray(view_proj.T, f4).tobytes(),
        "u_camera_position": np.asarray(camera.position, f4).tobytes(),
        "u_env_max_lod": f4(env.max_lod).tobytes(),
        "u_sh": env.sh.tobytes(),
    }
    if _env_rotated(options):
        u["u_env_rotation"] = _mat3_bytes(env_rotation_matrix(options.env_rotation))
    if lights:
        pos, direction, color, cone = [], [], [], []
        for light in lights:
            mtx = np.asarray(light.matrix, np.float64)
            axis = -mtx[:3, 2]
            axis = axis / max(float(np.linalg.norm(axis)), 1e-12)
            kind = {"directional": 0.0, "point": 1.0, "spot": 2.0}[light.type]
            pos.append([*mtx[:3, 3], kind])
            direction.append([*axis, light.range if math.isfinite(light.range) else 0.0])
            color.append(np.asarray(light.color) * light.intensity)
            scale = 1.0 / max(1e-3, math.cos(light.inner_cone) - math.cos(light.outer_cone))
            cone.append([scale, -math.cos(light.outer_cone) * scale])
        u["u_light_position"] = np.asarray(pos, f4).tobytes()
        u["u_light_direction"] = np.asarray(direction, f4).tobytes()
        u["u_light_color"] = np.asarray(color, f4).tobytes()
        u["u_light_cone"] = np.asarray(cone, f4).tobytes()
    return u


# --- passes ---------------------------------------------------------------------------------

def _draw_opaque(p: Pass, items: list[DrawItem]) -> None:
    for it in items:
        prog, state = p.program(it)
        p.draw(it, prog, state)


def _draw_blend(p: Pass, items: list[DrawItem]) -> None:
    """Meshes back to front by the distance of their first instance's centre (a mesh's own
    instances are not sorted among themselves)."""
    eye = p.camera.position
    order = sorted(((float(np.linalg.norm(c - eye)), i, it) for i, it in enumerate(items)
                    for c in it.mesh.centers[:1]), key=lambda t: -t[0])
    p.ctx.enable(moderngl.BLEND)
    p.ctx.blend_func = (moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA,  # type: ignore[assignment]  # stubs: 2 or 4
                        moderngl.ONE, moderngl.ONE_MINUS_SRC_ALPHA)
    p.fbo.depth_mask = False
    for _, _, it in order:
        prog, state = p.program(it)
        p.draw(it, prog, state)
    p.fbo.depth_mask = True
    p.ctx.disable(moderngl.BLEND)


# --- render targets and the final pass --------------------------------------------------------

@dataclass
class _Target:
    samples: int
    supersample: int                     # draw_fbo is this many times the output on each axis
    draw_fbo: moderngl.Framebuffer       # geometry: colour (premultiplied linear, MSAA or not) + depth
    frame_tex: moderngl.Texture          # its colour, read by the final pass
    display_fbo: moderngl.Framebuffer    # final pass: display RGBA8 (+ the regions' mask)
    linear_fbo: moderngl.Framebuffer     # the same pass's linear RGBA32F, drawn on demand
    resources: list
    rows: tuple | None = None            # the gradient per row: (linear, display) 1 x h textures
    frames: int = 0                      # frames drawn into it (the last one's can be read)
    depth_tex: moderngl.Texture | None = None   # edge anti-aliasing (renderer.raster.edges): the
    edge_tex: moderngl.Texture | None = None    # geometry's depth as a texture, and the
    edge_fbo: moderngl.Framebuffer | None = None  # target its edge lines are drawn into


_targets: dict[tuple, _Target] = {}
_targets_ctx: int | None = None
MAX_TARGETS = 4


def _target(ctx: moderngl.Context, w: int, h: int, msaa: int, supersample: int = 1,
            edge_aa: bool = False) -> _Target:
    global _targets_ctx
    if _targets_ctx != id(ctx):
        _targets.clear()
        _targets_ctx = id(ctx)
    samples = 0 if msaa <= 1 else min(int(msaa), ctx.max_samples)
    key = (w, h, samples, supersample, edge_aa)
    t = _targets.pop(key, None)
    if t is None:
        t = _make_target(ctx, w, h, samples, supersample, edge_aa)
    _targets[key] = t
    while len(_targets) > MAX_TARGETS:
        for r in _targets.pop(next(iter(_targets))).resources:
            r.release()
    return t


def _make_target(ctx, w, h, samples, supersample=1, edge_aa=False) -> _Target:
    # RGBA16F samples: half the memory traffic of 32F on a CPU rasteriser; 11-bit mantissa.
    size = (w * supersample, h * supersample)
    frame_tex = ctx.texture(size, 4, samples=samples, dtype="f2")
    depth_tex = edge_tex = edge_fbo = None
    if edge_aa:  # the edge lines read the depth (renderer.raster.edges)
        depth = depth_tex = ctx.depth_texture(size)
        depth_tex.compare_func = ""  # read as values, not as a shadow comparison
        edge_tex = ctx.texture((w, h), 2, dtype="f2")
        edge_fbo = ctx.framebuffer([edge_tex])
    else:
        depth = ctx.depth_renderbuffer(size, samples=samples)
    draw_fbo = ctx.framebuffer([frame_tex], depth)
    display = ctx.texture((w, h), 4, dtype="f1")
    linear = ctx.texture((w, h), 4, dtype="f4")
    mask = ctx.depth_renderbuffer((w, h))  # the final pass's regions (renderer.view.regions)
    display_fbo = ctx.framebuffer([display], mask)
    linear_fbo = ctx.framebuffer([linear], mask)
    extra = [edge_fbo, edge_tex] if edge_fbo is not None else []
    return _Target(samples, supersample, draw_fbo, frame_tex, display_fbo, linear_fbo,
                   [display_fbo, linear_fbo, draw_fbo, display, linear, mask, depth, frame_tex, *extra],
                   depth_tex=depth_tex, edge_tex=edge_tex, edge_fbo=edge_fbo)


_BACKGROUND_MODES = {"transparent": 0, "env": 2, "gradient": 3}
DISPLAY, LINEAR = 1, 2  # final.frag's OUTPUT


@dataclass
class _FinalPass:
    """One frame's final pass (resolve, background, shadow, tone map) as drawn: up to four
    programs over the regions that need them (renderer.view.regions): the object's work inside
    its silhouette bound (marked in the mask's depth by _mark_object, so the early depth test
    skips whole blocks), the shadow's inside its rectangle (scissor). The pixels are those of
    one full-screen pass doing everything. Drawn once for the display image and, when it is
    asked for, again for the linear one (while the frame is still the target's last)."""
    target: _Target
    camera: Camera
    env: gpu.GpuEnvironment
    options: RenderOptions
    ground: "shadow.GroundShadow | None"
    draws: list  # (has_object, depth_func, has_shadow, scissor rect)
    frame: int = 0  # target.frames when drawn

    def draw(self, ctx, output: int) -> np.ndarray:
        """Draw the pass's `output` (DISPLAY or LINEAR) and read it back."""
        w, h = self.options.width, self.options.height
        fbo = self.target.display_fbo if output == DISPLAY else self.target.linear_fbo
        self.draw_into(ctx, fbo, output)
        # final.frag writes rows top-first, so reading straight into numpy needs no flip or copy.
        if output == DISPLAY:
            out = np.empty((h, w, 4), np.uint8)
            fbo.read_into(out, components=4)
        else:
            out = np.empty((h, w, 4), np.float32)
            fbo.read_into(out, components=4, dtype="f4")
        return out

    def draw_into(self, ctx, fbo: moderngl.Framebuffer, output: int) -> None:
        """The regions' programs for `output` drawn into `fbo` (whose depth is the mask)."""
        target, options = self.target, self.options
        rows = options.background == "gradient"
        if rows:
            _gradient_rows(ctx, target, self.camera, self.env, options)
        fbo.use()
        ctx.viewport = (0, 0, options.width, options.height)
        target.frame_tex.use(0)
        uniforms = _final_uniforms(target, self.camera, self.env, options, self.ground, rows)
        fbo.depth_mask = False
        for has_object, depth_func, has_shadow, part in self.draws:
            if depth_func:
                ctx.enable(moderngl.DEPTH_TEST)
                ctx.depth_func = depth_func
            else:
                ctx.disable(moderngl.DEPTH_TEST)
            prog = _final_program(target, options, has_object, has_shadow, rows, uniforms, output)
            ctx.scissor = part  # the output's GL rows are image rows from the top (final.frag)
            context.fullscreen_vao(prog).render(moderngl.TRIANGLES, vertices=3)
        ctx.scissor = None
        ctx.disable(moderngl.DEPTH_TEST)
        ctx.depth_func = "<"
        fbo.depth_mask = True


def _final_pass(target: _Target, camera: Camera, env: gpu.GpuEnvironment, options: RenderOptions,
                ground: "shadow.GroundShadow | None" = None,
                polygon: np.ndarray | None = None, rect: regions.Rect | None = None) -> _FinalPass:
    """The regions of the final pass and the programs each needs, by the object's bound:
    `polygon` (regions.object_polygon, marked by _mark_object) or `rect` (regions.object_rect,
    an edge-smoothed frame's); with neither, the object's program everywhere."""
    w, h = options.width, options.height
    full = (0, 0, w, h)
    shade: regions.Rect | None = None
    if ground is not None and ground.reach is None:
        ground = None  # a map of zeros: no pixel would be shaded
    if ground is not None and ground.reach is not None:  # (the second test narrows the type)
        x0, z0, dx, dz = ground.reach
        y = ground.ground
        shade = regions.screen_rect(camera, np.array(
            [[x0, y, z0], [x0 + dx, y, z0], [x0, y, z0 + dz], [x0 + dx, y, z0 + dz]]), w, h)
    draws = []
    if rect is not None:
        # By scissor alone: the object's program over the rectangle, the background's
        # elsewhere (with one sample per pixel the object's program costs less than marking
        # a tighter bound would spare).
        reach = rect if rect[2] > 0 and rect[3] > 0 else None
        inside = [reach] if reach is not None else []
        outside = regions.subtract(full, reach) if reach is not None else [full]
        for has_object, boxes in ((True, inside), (False, outside)):
            for box in boxes:
                draws += [(has_object, "", has_shadow, part) for has_shadow, part in _split(box, shade)]
        return _FinalPass(target, camera, env, options, ground, draws, target.frames)
    # Fragments of the full-screen triangle lie at depth 1: the object's program passes
    # where the bound wrote 0, the background's elsewhere.
    reach = regions.bounding_rect(polygon, w, h) if polygon is not None and len(polygon) else None
    kinds = [(True, ">"), (False, "<=")] if polygon is not None else [(True, "")]
    for has_object, depth_func in kinds:
        for has_shadow, box in _split(full, shade):
            part: regions.Rect | None = box
            if has_object and depth_func:  # the bound's rectangle: no blocks to reject beyond it
                part = regions.intersect(box, reach) if reach is not None else None
            if part is not None and part[2] > 0 and part[3] > 0:
                draws.append((has_object, depth_func, has_shadow, part))
    return _FinalPass(target, camera, env, options, ground, draws, target.frames)


def _split(rect: regions.Rect, shade: regions.Rect | None) -> list[tuple[bool, regions.Rect]]:
    """`rect` as (has_shadow, part)s: its part in the shadow's rectangle `shade`, the rest."""
    if shade is None:
        return [(False, rect)]
    cut = regions.intersect(rect, shade)
    return ([(True, cut)] if cut is not None else []) + [(False, r) for r in regions.subtract(rect, shade)]


class _LinearOnDemand:
    """A frame's linear image, drawn by its final pass and read when first asked for. A later
    frame draws over the target, so each render first reads the linear image of every earlier
    frame still referenced (`_pending`); unreferenced ones are never drawn."""

    def __init__(self, ctx: moderngl.Context, final: _FinalPass):
        self.ctx, self.final = ctx, final
        self.linear: np.ndarray | None = None

    def drawable(self) -> bool:
        """The frame is still its target's last, in this process's context (not a fork's)."""
        return self.final.frame == self.final.target.frames and context.get_context() is self.ctx

    def __call__(self) -> np.ndarray:
        with _lock:
            if self.linear is None:
                if not self.drawable():
                    raise RuntimeError("the frame's linear image is gone: its GL context ended")
                self.linear = self.final.draw(self.ctx, LINEAR)
            return self.linear


_pending: list[weakref.ref[_LinearOnDemand]] = []


def _read_pending() -> None:
    """Read the linear images still owed before a new frame draws over their targets."""
    for ref in _pending:
        src = ref()
        if src is not None and src.drawable():
            src()
    _pending.clear()


_mask_draw: dict[int, tuple[moderngl.Buffer, moderngl.VertexArray]] = {}
MAX_POLYGON = 64  # vertices: 4 frame corners cut by 16 half-planes leave at most 20


def _mark_object(ctx, fbo: moderngl.Framebuffer, polygon: np.ndarray, w: int, h: int) -> None:
    """Depth 0 inside the silhouette bound, 1 elsewhere (colour untouched): the final pass
    (_FinalPass) tests against it."""
    fbo.use()
    ctx.viewport = (0, 0, w, h)
    fbo.color_mask = (False,) * 4  # type: ignore[assignment]  # stubs: a tuple per attachment
    fbo.clear(depth=1.0)
    if 3 <= len(polygon) <= MAX_POLYGON:  # fewer: the object is out of view
        prog = context.program("region_mask.vert", "region_mask.frag", {})
        cast(dict, prog)["u_size"].value = (float(w), float(h))
        if id(ctx) not in _mask_draw:
            buf = ctx.buffer(reserve=MAX_POLYGON * 8)
            _mask_draw.clear()
            _mask_draw[id(ctx)] = (buf, ctx.vertex_array(prog, [(buf, "2f", "in_pixel")]))
        buf, vao = _mask_draw[id(ctx)]
        buf.write(np.ascontiguousarray(polygon, np.float32).tobytes())
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.depth_func = "1"  # always passes: the bound is all that is drawn
        vao.render(moderngl.TRIANGLE_FAN, vertices=len(polygon))
        ctx.depth_func = "<"
        ctx.disable(moderngl.DEPTH_TEST)
    fbo.color_mask = (True,) * 4  # type: ignore[assignment]


def _gradient_rows(ctx, target: _Target, camera: Camera, env: gpu.GpuEnvironment,
                   options: RenderOptions) -> None:
    """The gradient's linear and display value per row, once per target: the background
    program drawn into a 1-pixel-wide target under the frame's viewport, so each row holds
    what the program computes anywhere on that row."""
    if target.rows is not None:
        return
    h = options.height
    linear = ctx.texture((1, h), 4, dtype="f4")
    display = ctx.texture((1, h), 4, dtype="f1")
    fbo = ctx.framebuffer([display, linear])
    fbo.use()
    ctx.viewport = (0, 0, options.width, h)  # the frame's: v_ndc is interpolated as there
    ctx.disable(moderngl.DEPTH_TEST)
    uniforms = _final_uniforms(target, camera, env, options, None, False)
    prog = _final_program(target, options, False, False, False, uniforms, DISPLAY | LINEAR)
    context.fullscreen_vao(prog).render(moderngl.TRIANGLES, vertices=3)
    target.rows = (linear, display)
    target.resources += [fbo, linear, display]


def _final_uniforms(target: _Target, camera: Camera, env: gpu.GpuEnvironment,
                    options: RenderOptions, ground: "shadow.GroundShadow | None",
                    rows: bool) -> dict:
    """Every uniform any region's final.frag reads, once per frame (each program takes the
    ones it has), and the textures bound to their units."""
    mode = _BACKGROUND_MODES.get(options.background, 1)
    u: dict = {"u_frame": 0, "u_height": options.height,
               "u_exposure_scale": exposure_scale(options.exposure)}
    if target.edge_tex is not None:
        u["u_edge"] = 5
        target.edge_tex.use(5)
    if rows and target.rows is not None:
        u.update(u_rows_linear=3, u_rows_display=4)
        target.rows[0].use(3)
        target.rows[1].use(4)
    if mode == 2 or ground is not None:
        th = math.tan(math.radians(camera.fov) / 2)
        u["u_camera_basis"] = np.ascontiguousarray(np.stack(camera.basis()), np.float32).tobytes()
        u["u_tan_half_fov"] = (th * camera.aspect, th)
    if ground is not None:
        u.update(u_camera_position=tuple(map(float, camera.position)), u_ground=ground.ground,
                 u_shadow_rect=ground.rect, u_shadow_strength=float(ground.strength), u_shadow=2)
        ground.texture.use(2)
    if mode == 1:
        u["u_background"] = background_rgb(options.background)
    elif mode == 3:
        u["u_gradient_top"], u["u_gradient_bottom"] = GRADIENT
    elif mode == 2:
        u.update(u_blur=float(min(max(options.background_blur, 0.0), 1.0)),
                 u_env_max_lod=env.max_lod, u_env=1)
        if _env_rotated(options):
            u["u_env_rotation"] = _mat3_bytes(env_rotation_matrix(options.env_rotation))
        env.cube.use(1)
    return u


def _final_program(target: _Target, options: RenderOptions, has_object: bool, has_shadow: bool,
                   rows: bool, uniforms: dict, output: int) -> moderngl.Program:
    """final.frag for one kind of region and `output` (DISPLAY, LINEAR or both), with the
    frame's `uniforms` it reads set."""
    mode = _BACKGROUND_MODES.get(options.background, 1)
    defines = {"TONEMAP": _TONEMAPS[options.tonemap], "BACKGROUND": mode,
               "SAMPLES": max(target.samples, 1), "SHADOW": int(has_shadow),
               "OBJECT": int(has_object), "SUPERSAMPLE": target.supersample, "ROWS": int(rows),
               "OUTPUT": output}
    if options.alpha == "coverage":
        defines["COVERAGE_ALPHA"] = 1
    if target.edge_tex is not None and has_object:
        defines["EDGE"] = 1
    if mode == 2 and _env_rotated(options):
        defines["ENV_ROTATED"] = 1
    prog = context.program("screen_triangle.vert", "final.frag", defines)
    members = cast(dict, prog)
    for name, value in uniforms.items():
        if name in prog:  # a region's program may lack some
            if isinstance(value, bytes):
                members[name].write(value)
            else:
                members[name].value = value
    return prog
