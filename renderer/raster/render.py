"""`render(asset, env, options) -> Frame`: one offscreen frame of a baked asset, orchestrated.

Passes (renderer.raster.passes): opaque and mask meshes, transmissive meshes by their method
(renderer.methods.registry), blend meshes back to front, all into one float framebuffer
(renderer.raster.targets; one sample per pixel, then the edges smoothed by
renderer.raster.edges; or MSAA, antialias=msaa); then the final pass (renderer.raster.final)
into RGBA8, and its readback. The linear float image is drawn by the same pass and read only
when the frame's `linear` is first asked for (a thumbnail never asks).
"""
from __future__ import annotations

import dataclasses
import time

import moderngl
import numpy as np

from core.baked import BakedAsset, BakedEnvironment
from core.options import RenderOptions, apply_override
from core.scene import Material
from gl import context
from renderer.frame import Frame, FrameTimings, alpha_is_mask
from renderer.methods.auto import plan_request, run_frame_method
from renderer.methods.registry import FRAME_METHODS, METHODS, UnsupportedMethod, available_methods, validate_options
from renderer.raster import area_lights, edges, final, gpu, light_shadows, passes, shadow, targets
from renderer.raster.passes import DrawItem, Pass
from renderer.raster.targets import frame_lock
from renderer.view import regions
from renderer.view.framing import asset_camera

__all__ = ["render", "render_supersampled", "UnsupportedMethod", "validate_options",
           "available_methods"]


def render(asset: BakedAsset, env: BakedEnvironment, options: RenderOptions) -> Frame:
    """Render `asset` lit by `env` as `options` say. Raises UnsupportedMethod or ValueError
    for options this build cannot honour."""
    validate_options(options)
    asset = asset.with_variant(options.variant)  # KHR_materials_variants: its own GPU key
    if options.method in FRAME_METHODS:
        return FRAME_METHODS[options.method](asset, env, options)
    auto, raster_options = _plan_auto(asset, options)
    if auto is not None and auto.frame_method:
        return run_frame_method(auto, FRAME_METHODS[auto.frame_method], asset, env, options)
    with frame_lock:  # one GL context per process: one frame at a time
        return _render(asset, env, raster_options, auto)


def _plan_auto(asset: BakedAsset, options: RenderOptions):
    """For method "auto", renderer.methods.auto's plan (per object, or a frame method) and the options
    the raster frame is drawn with (the plan's TIR mode); (None, options) otherwise."""
    if options.method != "auto":
        return None, options
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
    if options.method in FRAME_METHODS:
        raise UnsupportedMethod(f"method {options.method!r} draws no raster frame to supersample")
    auto, options = _plan_auto(asset, options)
    if auto is not None and auto.frame_method:
        raise UnsupportedMethod(f"auto chose {auto.frame_method}: no raster frame to supersample")
    with frame_lock:
        return _render(asset, env, dataclasses.replace(options, msaa=0), auto, int(factor))



def _render(asset: BakedAsset, env: BakedEnvironment, options: RenderOptions,
            auto=None, supersample: int = 1) -> Frame:
    t0 = time.perf_counter()
    ctx = context.get_context()
    final.read_pending()
    uploads_before = dict(gpu.stats)
    gasset = gpu.asset(asset, max(options.width, options.height) * supersample)
    genv = gpu.environment(env)
    t_upload = time.perf_counter()

    w, h = options.width, options.height
    camera, shadowed, shadow_why = asset_camera(asset, options)
    items = _plan_items(gasset, options, auto)
    lights = gasset.lights[:passes.MAX_LIGHTS] if options.lights else []
    t_light_shadows = time.perf_counter()
    # by the pose's key, not the GPU upload's: a rig's frames share one upload but move
    views = (light_shadows.shadow_views(ctx, asset.key, lights, light_shadows.casters(items, gasset, options),
                                        asset.bounds, w * supersample, h * supersample)
             if lights and options.light_shadows else None)
    t_light_shadows = time.perf_counter() - t_light_shadows
    edge_aa = _edge_antialiasing(asset, options, supersample)
    target = targets.get_target(ctx, w, h, 0 if edge_aa else options.msaa, supersample, edge_aa)
    target.frames += 1
    emitters = area_lights.of_asset(asset)
    pass_ = Pass(ctx, target.draw_fbo, camera, genv, gasset, options,
                 passes.frame_defines(options, lights, views, len(emitters)),
                 {**passes.frame_uniforms(camera, genv, lights, options, views),
                  **area_lights.uniforms(emitters)},
                 shadow_map=views.texture if views else None,
                 shadow_tint=views.tint if views else None)
    # The object's bound for the final pass's regions: a rectangle for an edge-smoothed frame,
    # else a polygon marked before the geometry (llvmpipe draws it while Python goes on).
    polygon = rect = None
    if edge_aa:
        rect = regions.object_rect(camera, regions.hull_points(asset), w, h)
    else:
        polygon = regions.object_polygon(camera, regions.hull_points(asset), w, h)
        if polygon is not None:
            final.mark_object(ctx, target.display_fbo, polygon, w, h)

    _draw_geometry(pass_, target, items, supersample)
    t_draw = time.perf_counter()

    t_shadow = time.perf_counter()
    ground = (shadow.ground_shadow(ctx, asset.key, gasset.meshes, asset.bounds, options.shadow)
              if shadowed else None)
    t_draw_end = time.perf_counter()
    final_ = final.final_pass(target, camera, genv, options, ground, polygon, rect)
    rgba8 = final_.draw(ctx, final.DISPLAY)
    linear = final.linear_on_demand(ctx, final_)
    t_end = time.perf_counter()
    plan = _plan(options, env, items, lights, camera, target, edge_aa, supersample,
                 shadow_why if shadowed else f"none: {shadow_why}", uploads_before, auto)
    plan["light_shadows"] = views.describe() if views else "none"
    plan["area_lights"] = len(emitters)  # emissive polygons lighting the raster, unshadowed
    timings = FrameTimings((t_end - t0) * 1e3, {"upload": (t_upload - t0) * 1e3,
                                                "draw": (t_draw - t_upload - t_light_shadows) * 1e3,
                                                "light_shadows": t_light_shadows * 1e3,
                                                "shadow": (t_draw_end - t_shadow) * 1e3,
                                                "finish": (t_end - t_draw_end) * 1e3})
    return Frame(linear, rgba8, plan, timings, alpha_is_mask=alpha_is_mask(options))


def _draw_geometry(pass_: Pass, target: targets.Target, items: list[DrawItem], supersample: int) -> None:
    """Every mesh into the target's float framebuffer: opaque and mask meshes, then each
    method's, then blend ones back to front; then the edge lines to smooth (edge_fbo)."""
    ctx, options, camera = pass_.ctx, pass_.options, pass_.camera
    w, h = options.width, options.height
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
        passes.draw_opaque(pass_, by_method.pop("opaque"))
        pass_.opaque_drawn = True
    for method, its in by_method.items():
        METHODS[method](pass_, its)
        target.draw_fbo.use()
    if blend:
        passes.draw_blend(pass_, blend)
    ctx.disable(moderngl.CULL_FACE)
    ctx.disable(moderngl.DEPTH_TEST)
    ctx.disable(moderngl.BLEND)
    if target.edge_fbo is not None and target.depth_tex is not None:
        edges.draw(ctx, target.edge_fbo, target.depth_tex, passes.edge_segments(items, camera),
                   camera.projection_matrix() @ camera.view_matrix(), w, h)


def _plan(options: RenderOptions, env: BakedEnvironment, items: list[DrawItem], lights,
          camera, target: targets.Target, edge_aa: bool, supersample: int, shadow_why: str,
          uploads_before: dict, auto) -> dict:
    """What the frame did and why (Frame.plan)."""
    plan = {
        "method": options.method,
        "objects": [{"mesh": it.mesh.baked.name, "class": it.material.material_class,
                     "method": it.method, "why": it.why} for it in items],
        "lights": len(lights),
        "environment": env.name,
        "background": options.background,
        "shadow": shadow_why,
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
    return plan


def _edge_antialiasing(asset: BakedAsset, options: RenderOptions, supersample: int) -> bool:
    """Whether the frame is smoothed by renderer.raster.edges rather than by MSAA samples."""
    return (options.antialias == "edges" and options.msaa > 1 and supersample == 1
            and asset.triangle_count <= edges.MAX_TRIANGLES)


def _plan_items(gasset: gpu.GpuAsset, options: RenderOptions, auto=None) -> list[DrawItem]:
    items = []
    for i, gm in enumerate(gasset.meshes):
        mat = apply_override(gm.baked.material, options.override)
        method, why = auto.method_for(i) if auto is not None else _choose_method(mat, options)
        items.append(DrawItem(gm, mat, method, why, i))
    return items


def _choose_method(mat: Material, options: RenderOptions) -> tuple[str, str]:
    """The method a request names (`auto` is decided by renderer.methods.auto's plan instead)."""
    cls = mat.material_class
    if cls != "transmissive":
        return "opaque", f"{cls} material: PBR + IBL raster"
    if options.method == "opaque":
        return "opaque", "method opaque requested: transmission ignored"
    return options.method, f"method {options.method} requested"

