"""The final pass: the geometry's float image resolved (MSAA, supersampling, smoothed
edges), the background and ground shadow added and tone mapped (shaders/final.frag), drawn per
screen region with only the work each region's pixels need (renderer.view.regions); the
display image read back at once, the linear one on demand."""
from __future__ import annotations

import math
import weakref
from dataclasses import dataclass
from typing import cast

import moderngl
import numpy as np

from core.cubemap import env_rotation_matrix
from core.options import RenderOptions, background_rgb
from gl import context
from renderer.frame import exposure_scale
from renderer.raster import gpu, shadow, targets
from renderer.raster.materials import mat3_bytes
from renderer.raster.passes import env_rotated
from renderer.view import regions
from renderer.view.camera import Camera

GRADIENT = ((0.95, 0.95, 0.95), (0.80, 0.80, 0.81))  # background "gradient": sRGB top, bottom
_TONEMAPS = {"none": 0, "neutral": 1, "aces": 2}
_BACKGROUND_MODES = {"transparent": 0, "env": 2, "gradient": 3}
DISPLAY, LINEAR = 1, 2  # final.frag's OUTPUT


@dataclass
class FinalPass:
    """One frame's final pass (resolve, background, shadow, tone map) as drawn: up to four
    programs over the regions that need them (renderer.view.regions): the object's work inside
    its silhouette bound (marked in the mask's depth by mark_object, so the early depth test
    skips whole blocks), the shadow's inside its rectangle (scissor). The pixels are those of
    one full-screen pass doing everything. Drawn once for the display image and, when it is
    asked for, again for the linear one (while the frame is still the target's last)."""
    target: targets.Target
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


def final_pass(target: targets.Target, camera: Camera, env: gpu.GpuEnvironment, options: RenderOptions,
                ground: "shadow.GroundShadow | None" = None,
                polygon: np.ndarray | None = None, rect: regions.Rect | None = None) -> FinalPass:
    """The regions of the final pass and the programs each needs, by the object's bound:
    `polygon` (regions.object_polygon, marked by mark_object) or `rect` (regions.object_rect,
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
        return FinalPass(target, camera, env, options, ground, draws, target.frames)
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
    return FinalPass(target, camera, env, options, ground, draws, target.frames)


def _split(rect: regions.Rect, shade: regions.Rect | None) -> list[tuple[bool, regions.Rect]]:
    """`rect` as (has_shadow, part)s: its part in the shadow's rectangle `shade`, the rest."""
    if shade is None:
        return [(False, rect)]
    cut = regions.intersect(rect, shade)
    return ([(True, cut)] if cut is not None else []) + [(False, r) for r in regions.subtract(rect, shade)]


class LinearOnDemand:
    """A frame's linear image, drawn by its final pass and read when first asked for. A later
    frame draws over the target, so each render first reads the linear image of every earlier
    frame still referenced (`_pending`); unreferenced ones are never drawn."""

    def __init__(self, ctx: moderngl.Context, final: FinalPass):
        self.ctx, self.final = ctx, final
        self.linear: np.ndarray | None = None

    def drawable(self) -> bool:
        """The frame is still its target's last, in this process's context (not a fork's)."""
        return self.final.frame == self.final.target.frames and context.get_context() is self.ctx

    def __call__(self) -> np.ndarray:
        with targets.frame_lock:
            if self.linear is None:
                if not self.drawable():
                    raise RuntimeError("the frame's linear image is gone: its GL context ended")
                self.linear = self.final.draw(self.ctx, LINEAR)
            return self.linear


_pending: list[weakref.ref[LinearOnDemand]] = []


def read_pending() -> None:
    """Read the linear images still owed before a new frame draws over their targets."""
    for ref in _pending:
        src = ref()
        if src is not None and src.drawable():
            src()
    _pending.clear()


_mask_draw: dict[int, tuple[moderngl.Buffer, moderngl.VertexArray]] = {}
MAX_POLYGON = 64  # vertices: 4 frame corners cut by 16 half-planes leave at most 20


def mark_object(ctx, fbo: moderngl.Framebuffer, polygon: np.ndarray, w: int, h: int) -> None:
    """Depth 0 inside the silhouette bound, 1 elsewhere (colour untouched): the final pass
    (FinalPass) tests against it."""
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


def _gradient_rows(ctx, target: targets.Target, camera: Camera, env: gpu.GpuEnvironment,
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


def _final_uniforms(target: targets.Target, camera: Camera, env: gpu.GpuEnvironment,
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
        if env_rotated(options):
            u["u_env_rotation"] = mat3_bytes(env_rotation_matrix(options.env_rotation))
        env.cube.use(1)
    return u


def _final_program(target: targets.Target, options: RenderOptions, has_object: bool, has_shadow: bool,
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
    if mode == 2 and env_rotated(options):
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


def linear_on_demand(ctx: moderngl.Context, final: FinalPass) -> LinearOnDemand:
    """The frame's linear image, owed (read before the next frame draws) while referenced."""
    linear = LinearOnDemand(ctx, final)
    _pending.append(weakref.ref(linear))
    return linear
