"""Render targets: the float framebuffer the geometry passes draw into and the final pass's
display and linear targets, kept per (size, samples) for the process's GL context."""
from __future__ import annotations

import threading
from dataclasses import dataclass

import moderngl

# One GL context per process and targets shared between frames: one frame at a time.
frame_lock = threading.RLock()


@dataclass
class Target:
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


_targets: dict[tuple, Target] = {}
_targets_ctx: int | None = None
MAX_TARGETS = 4


def get_target(ctx: moderngl.Context, w: int, h: int, msaa: int, supersample: int = 1,
            edge_aa: bool = False) -> Target:
    global _targets_ctx
    if _targets_ctx != id(ctx):
        _targets.clear()
        _targets_ctx = id(ctx)
    samples = 0 if msaa <= 1 else min(int(msaa), ctx.max_samples)
    key = (w, h, samples, supersample, edge_aa)
    t = _targets.pop(key, None)
    if t is None:
        t = make_target(ctx, w, h, samples, supersample, edge_aa)
    _targets[key] = t
    while len(_targets) > MAX_TARGETS:
        for r in _targets.pop(next(iter(_targets))).resources:
            r.release()
    return t


def make_target(ctx, w, h, samples, supersample=1, edge_aa=False) -> Target:
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
    return Target(samples, supersample, draw_fbo, frame_tex, display_fbo, linear_fbo,
                   [display_fbo, linear_fbo, draw_fbo, display, linear, mask, depth, frame_tex, *extra],
                   depth_tex=depth_tex, edge_tex=edge_tex, edge_fbo=edge_fbo)

