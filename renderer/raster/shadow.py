"""Ground contact shadow: a soft shadow under the object on an invisible ground plane at the
bounds' minimum y, as product viewers draw one.

The object is drawn from straight above into a small map (once per asset: the map is kept) (shaders/shadow.frag: how close
each surface comes to the ground), blurred (shaders/shadow_blur.frag), and the final pass
darkens only the background where a view ray meets the ground (shaders/final.frag), so the
shadow is never drawn over the object. No light direction: it is the ambient occlusion of a
studio floor, not a cast shadow.
"""
from __future__ import annotations

import dataclasses
from collections import OrderedDict
from dataclasses import dataclass
from typing import cast

import moderngl
import numpy as np

from gl import context

MAP_SIZE = 32         # texels across the shadow map (blurred: no detail to keep; sigma 3 texels
                      # ~ 0.2 of the footprint)
SPREAD = 0.5          # the map reaches this fraction of the footprint beyond the object
FADE = 0.5            # surfaces this fraction of the object's height above the ground cast none
FLAT = 0.02           # height below this fraction of the footprint: no ground to stand on
FRAME_PAD = 0.08      # framing includes this much ground (fraction of the footprint) around it


@dataclass
class GroundShadow:
    texture: moderngl.Texture
    ground: float                      # world y
    rect: tuple[float, float, float, float]  # x0, z0, width, depth of the map on the ground
    strength: float
    # the part of `rect` where the map can shade at all (its nonzero texels, grown by the
    # bilinear footprint): outside it the final pass would compute no shade
    reach: tuple[float, float, float, float] | None = None


def decide(bounds: np.ndarray, camera_position: np.ndarray, strength: float,
           background: str) -> tuple[bool, str]:
    """Whether this frame gets a contact shadow, and why (for the render plan)."""
    lo, hi = np.asarray(bounds, np.float64)
    size = hi - lo
    if strength <= 0:
        return False, "shadow 0"
    if background == "env":
        return False, "background env: the panorama has its own ground"
    if size[1] < FLAT * max(size[0], size[2], 1e-12):
        return False, "flat object: no ground to stand on"
    if camera_position[1] <= lo[1] + 1e-6 * max(size.max(), 1e-12):
        return False, "camera at or below the ground"
    return True, f"strength {strength:g} on the ground at y = {lo[1]:.4g}"


def framed_bounds(bounds: np.ndarray) -> np.ndarray:
    """The object's bounds grown on the ground by the shadow's visible core, for framing."""
    lo, hi = np.array(bounds, np.float64)
    pad = FRAME_PAD * max(hi[0] - lo[0], hi[2] - lo[2])
    lo[[0, 2]] -= pad
    hi[[0, 2]] += pad
    return np.stack([lo, hi])


def ground_outline(bounds: np.ndarray, points: np.ndarray) -> np.ndarray:
    """`points` dropped onto the ground and pushed FRAME_PAD of the footprint outward: the
    part of the shadow framing keeps in view."""
    lo, hi = np.asarray(bounds, np.float64)
    pad = FRAME_PAD * max(hi[0] - lo[0], hi[2] - lo[2])
    g = np.array(points, np.float64)
    g[:, 1] = lo[1]
    v = g[:, [0, 2]] - (lo[[0, 2]] + hi[[0, 2]]) / 2
    g[:, [0, 2]] += v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12) * pad
    return g


MAX_CACHED = 32  # assets whose shadow maps stay on the GPU (2 KiB each)
_cache: OrderedDict = OrderedDict()  # asset key -> GroundShadow at strength 1
_scratch: dict = {}                  # id(ctx) -> two (texture, framebuffer) pairs


def _texture(ctx: moderngl.Context):
    tex = ctx.texture((MAP_SIZE, MAP_SIZE), 1, dtype="f2")
    tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
    tex.repeat_x = tex.repeat_y = False
    return tex, ctx.framebuffer([tex])


def ground_shadow(ctx: moderngl.Context, key: str, meshes, bounds: np.ndarray,
                  strength: float) -> GroundShadow:
    """The shadow of an asset (gpu.GpuMesh list) for the final pass. The map depends on the
    geometry only, not on the camera or the material, so it is drawn once per asset and kept
    with its upload: turntable frames and repeated thumbnails only look it up."""
    if id(ctx) not in _scratch:
        for g in _cache.values():
            g.texture.release()
        _cache.clear()
        _scratch.clear()
        _scratch[id(ctx)] = [_texture(ctx) for _ in range(2)]
    g = _cache.get(key)
    if g is None:
        g = _render_map(ctx, meshes, bounds, _scratch[id(ctx)])
        _cache[key] = g
        while len(_cache) > MAX_CACHED:
            _cache.popitem(last=False)[1].texture.release()
    _cache.move_to_end(key)
    return dataclasses.replace(g, strength=strength)


def _render_map(ctx: moderngl.Context, meshes, bounds: np.ndarray, scratch) -> GroundShadow:
    """Draw `meshes` from above into a map of their closeness to the ground, and blur it."""
    lo, hi = np.asarray(bounds, np.float64)
    centre = (lo + hi) / 2
    half = max(hi[0] - lo[0], hi[2] - lo[2]) / 2 * (1 + 2 * SPREAD)
    half = max(half, 1e-9)
    # World (x, z) -> clip (x, y); y is the height, written by the fragment shader, not depth.
    m = np.zeros((4, 4))
    m[0, 0], m[0, 3] = 1 / half, -centre[0] / half
    m[1, 2], m[1, 3] = 1 / half, -centre[2] / half
    m[3, 3] = 1.0
    prog = context.program("pbr.vert", "shadow.frag", {})
    u = cast(dict, prog)  # uniforms by name (moderngl's stubs type members as a union)
    u["u_view_proj"].write(np.ascontiguousarray(m.T, np.float32).tobytes())
    u["u_ground"].value = float(lo[1])
    u["u_fade"].value = float(max((hi[1] - lo[1]) * FADE, 1e-12))
    (tex0, fbo0), (tex1, fbo1) = scratch
    fbo0.use()
    ctx.viewport = (0, 0, MAP_SIZE, MAP_SIZE)
    fbo0.clear(0.0, 0.0, 0.0, 0.0)
    ctx.disable(moderngl.DEPTH_TEST)
    ctx.disable(moderngl.CULL_FACE)
    ctx.enable(moderngl.BLEND)
    ctx.blend_equation = (moderngl.MAX, moderngl.MAX)
    for mesh in meshes:
        for mirrored, _, count in mesh.instances:
            mesh.vao(prog, mirrored).render(moderngl.TRIANGLES, instances=count)
    ctx.blend_equation = (moderngl.FUNC_ADD, moderngl.FUNC_ADD)
    ctx.disable(moderngl.BLEND)
    out, out_fbo = _texture(ctx)
    blur = context.program("screen_triangle.vert", "shadow_blur.frag", {})
    b = cast(dict, blur)
    b["u_src"].value = 0
    vao = context.fullscreen_vao(blur)
    for src, dst, step in ((tex0, fbo1, (1 / MAP_SIZE, 0.0)), (tex1, out_fbo, (0.0, 1 / MAP_SIZE))):
        dst.use()
        src.use(0)
        b["u_step"].value = step
        vao.render(moderngl.TRIANGLES, vertices=3)
    rect = (centre[0] - half, centre[2] - half, 2 * half, 2 * half)
    texels = np.frombuffer(out_fbo.read(components=1, dtype="f2"), np.float16).reshape(MAP_SIZE, MAP_SIZE)
    out_fbo.release()
    return GroundShadow(out, float(lo[1]), rect, 1.0, _reach(texels, rect))


def _reach(texels: np.ndarray, rect) -> tuple[float, float, float, float] | None:
    """The ground rectangle outside which bilinear lookups of the map read only zeros
    (rows are z, columns x); None when it shades nowhere."""
    rows, cols = np.nonzero(texels > 0)
    if len(rows) == 0:
        return None
    step_x, step_z = rect[2] / MAP_SIZE, rect[3] / MAP_SIZE
    x0, x1 = max(int(cols.min()) - 1, 0), min(int(cols.max()) + 2, MAP_SIZE)
    z0, z1 = max(int(rows.min()) - 1, 0), min(int(rows.max()) + 2, MAP_SIZE)
    return (rect[0] + x0 * step_x, rect[1] + z0 * step_z, (x1 - x0) * step_x, (z1 - z0) * step_z)
