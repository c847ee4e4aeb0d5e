"""Shadow maps for the asset's punctual lights (KHR_lights_punctual, UsdLux lights mapped to them).

One depth pass per shadow view into a shared atlas: a directional light gets one orthographic
view fitted to the asset's bounds; a spot light of outer cone up to SPOT_MAX_CONE one
perspective view along its axis; a point light (and a wider spot: a rect or disk light is a
hemisphere spot) six 90-degree views, a cube map laid out as six tiles. shaders/punctual.glsl
picks the view (the cube face by the major axis from the light), offsets the receiver along its
normal and toward the light by a slope-scaled bias, and filters 3 x 3 bilinear depth
comparisons (PCF); light that a map says is blocked is multiplied by the light's shadow colour
(UsdLux shadow:color, black by default).

Bounded cost: at most MAX_SHADOW_LIGHTS lights cast shadows (the first ones, in the asset's
order, that have shadows on), every tile is `tile_size(w, h, views)` texels across (twice the
output's larger side as a power of two, 512 to 2048, shrunk so the atlas stays within
MAX_ATLAS), and the maps depend on the geometry and lights only, not on the camera, so they are
drawn once per asset and kept (turntable frames look them up). Casters are the opaque and mask
meshes; a mask's depth pass samples its base-colour alpha (factor x texture x vertex colour, as
shaders/material_info.glsl has it) and discards below the cutoff, so its cut-outs let light
through as the ray tracer's shadow rays pass them. Blend and transmissive meshes cast a tinted
shadow, as the ray tracer's shadow rays pass them: a transmissive one lets through
transmission x (1 - metallic) x its base colour (factor x map x vertex colour) per thin-walled
layer, x sqrt(base colour) per layer of volume glass (as its camera rays: a closed solid of one
colour gives base colour, a textured one sqrt(c_entry) x sqrt(c_exit)), a blended one 1 - alpha
(its factor's). They are drawn after the opaque casters into a colour atlas beside the depth
one (RGB multiplied by each layer's transmittance where no opaque caster is nearer the light, A
the nearest layer's depth),
which shaders/punctual.glsl applies to a receiver behind that depth.
"""
from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass
from typing import cast

import moderngl
import numpy as np

from gl import context
from renderer.raster import materials

MAX_SHADOW_LIGHTS = 4
MAX_ATLAS = 4096           # texels across the atlas, at most
SPOT_MAX_CONE = math.radians(55.0)  # wider spots are shadowed through a cube, as point lights
UNIT = 31                  # texture unit of the atlas (material textures start at 2)
CUBE_MARGIN = 3            # texels beyond 90 degrees on each side of a cube face: the PCF
                           # footprint near a face's edge reads its own tile
MAX_CACHED = 4             # assets whose atlases stay on the GPU (up to 64 MiB each)


TINT_UNIT = 30             # texture unit of the tint atlas


@dataclass
class ShadowViews:
    """What the shaders need (renderer.raster.passes: uniforms) and the atlas."""
    texture: moderngl.Texture
    tint: moderngl.Texture | None  # blend / transmissive casters' transmittance, or None
    matrices: np.ndarray      # V x 4 x 4 world -> atlas (u, v, depth, w)
    tiles: np.ndarray         # V x 4 the tile's usable uv rectangle (x0, y0, x1, y1)
    texel: np.ndarray         # V x 2 world size of a texel: x + y * distance along the view
    light_views: np.ndarray   # L x 2 first view, count (0: the light casts none)
    tile: int
    atlas: tuple[int, int]

    @property
    def views(self) -> int:
        return len(self.matrices)

    def describe(self) -> str:
        lights = int((self.light_views[:, 1] > 0).sum())
        return f"{lights} light(s), {self.views} view(s) of {self.tile} px"


def tile_size(width: int, height: int, views: int) -> int:
    """Texels across one view: twice the output's larger side (a power of two, 512..2048),
    halved until the atlas's columns fit MAX_ATLAS."""
    side = 1 << max(0, math.ceil(math.log2(max(2 * max(width, height), 1))))
    side = min(max(side, 512), 2048)
    cols = math.ceil(math.sqrt(views))
    while side * cols > MAX_ATLAS and side > 64:
        side //= 2
    return side


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """A right-handed view matrix (looking down -Z) from eye toward target."""
    f = target - eye
    f = f / max(float(np.linalg.norm(f)), 1e-12)
    up = np.array([0.0, 1.0, 0.0]) if abs(f[1]) < 0.99 else np.array([1.0, 0.0, 0.0])
    s = np.cross(f, up)
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def _ortho(x0, x1, y0, y1, n, f) -> np.ndarray:
    m = np.eye(4)
    m[0, 0], m[0, 3] = 2 / (x1 - x0), -(x1 + x0) / (x1 - x0)
    m[1, 1], m[1, 3] = 2 / (y1 - y0), -(y1 + y0) / (y1 - y0)
    m[2, 2], m[2, 3] = -2 / (f - n), -(f + n) / (f - n)
    return m


def _perspective(tan_half: float, n: float, f: float) -> np.ndarray:
    m = np.zeros((4, 4))
    m[0, 0] = m[1, 1] = 1 / tan_half
    m[2, 2], m[2, 3] = -(f + n) / (f - n), -2 * f * n / (f - n)
    m[3, 2] = -1.0
    return m


def _corners(bounds: np.ndarray) -> np.ndarray:
    lo, hi = np.asarray(bounds, np.float64)
    return np.array([[(lo, hi)[i >> k & 1][k] for k in range(3)] for i in range(8)])


def _depth_range(view: np.ndarray, corners: np.ndarray, radius: float) -> tuple[float, float]:
    """Near and far planes of a perspective view that hold the bounds (a light inside them
    gets a near plane at 1/500 of the far one)."""
    z = -(corners @ view[:3, :3].T + view[:3, 3])[:, 2]
    far = max(float(z.max()) * 1.02, radius * 1e-3, 1e-6)
    near = max(float(z.min()) * 0.98, far * 2e-3)
    return near, far


def light_views(light, bounds: np.ndarray, tile: int) -> list[tuple[np.ndarray, tuple[float, float]]]:
    """(projection x view, texel size terms) of each shadow view of `light` (core.scene.Light)."""
    corners = _corners(bounds)
    lo, hi = np.asarray(bounds, np.float64)
    centre = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-9)
    mtx = np.asarray(light.matrix, np.float64)
    axis = -mtx[:3, 2] / max(float(np.linalg.norm(mtx[:3, 2])), 1e-12)
    pos = mtx[:3, 3]
    if light.type == "directional":
        view = look_at(centre - axis * 2 * radius, centre)
        p = corners @ view[:3, :3].T + view[:3, 3]
        pad = radius * 1e-3
        (x0, y0, z0), (x1, y1, z1) = p.min(axis=0) - pad, p.max(axis=0) + pad
        proj = _ortho(x0, x1, y0, y1, -z1, -z0)
        return [(proj @ view, (max(x1 - x0, y1 - y0) / tile, 0.0))]
    if light.type == "spot" and light.outer_cone <= SPOT_MAX_CONE:
        tan_half = math.tan(light.outer_cone) * (1 + 2 * CUBE_MARGIN / tile)
        view = look_at(pos, pos + axis)
        near, far = _depth_range(view, corners, radius)
        return [(_perspective(tan_half, near, far) @ view, (0.0, 2 * tan_half / tile))]
    tan_half = tile / (tile - 2 * CUBE_MARGIN)
    out = []
    for face in np.concatenate([np.eye(3), -np.eye(3)])[[0, 3, 1, 4, 2, 5]]:  # +X -X +Y -Y +Z -Z
        view = look_at(pos, pos + face)
        near, far = _depth_range(view, corners, radius)
        out.append((_perspective(tan_half, near, far) @ view, (0.0, 2 * tan_half / tile)))
    return out


# What a mask caster's depth pass takes from its material state: alpha, its map and UVs.
MASK_DEFINES = ("HAS_UV0", "HAS_UV1", "HAS_COLORS", "HAS_BASE_COLOR_MAP", "BASE_COLOR_UV")
MASK_UNIFORMS = ("u_base_color", "u_alpha_cutoff", "u_base_color_uvm")


@dataclass
class Caster:
    mesh: object                                 # gpu.GpuMesh
    mask: materials.MaterialState | None = None  # alphaMode MASK: what cuts its shadow
    tint: tuple[float, float, float] | None = None  # blend / transmissive: what it lets through
    # transmissive with a base-colour map or vertex colours: the tint pass multiplies `tint`
    # (then transmission x (1 - metallic) alone) by the texel's colour, sqrt'd for a volume
    colour: materials.MaterialState | None = None
    volume: bool = False                         # volume glass: sqrt(colour) per crossing


def transmittance(m) -> tuple[float, float, float] | None:
    """What one layer of a blend or transmissive material (core.scene.Material) lets through
    to the surfaces it shadows, as the ray tracer's shadow rays have it; None for others. A
    volume glass's layer takes sqrt(base colour), so that its two layers (every face is drawn)
    give base colour, as its camera rays; a thin-walled sheet's takes base colour."""
    if m.material_class == "transmissive":
        through = m.transmission * (1.0 - m.metallic)
        c = m.base_color[:3] if m.thin_walled else [math.sqrt(max(x, 0.0)) for x in m.base_color[:3]]
        return (c[0] * through, c[1] * through, c[2] * through)
    if m.alpha_mode == "BLEND":
        clear = 1.0 - m.base_color[3]
        return (clear, clear, clear)
    return None


def casters(items, asset=None, options=None) -> list[Caster]:
    """The frame's draw items that cast shadows; a mask's with its material state (when the
    asset and options are given) so its cut-outs cut the shadow; a blend or transmissive
    one's with what it lets through."""
    out = []
    for it in items:
        m = it.material
        if m.face_viewer:  # a point's sphere would shadow its own disc; Storm's points cast none
            continue
        tint = transmittance(m)
        if tint is not None:
            state = materials.material_state(it.mesh, m, asset, options) \
                if m.material_class == "transmissive" and asset is not None and options is not None else None
            if state is not None and ("HAS_BASE_COLOR_MAP" in state.defines or "HAS_COLORS" in state.defines):
                through = m.transmission * (1.0 - m.metallic)  # the colour comes per texel
                out.append(Caster(it.mesh, tint=(through,) * 3, colour=state, volume=not m.thin_walled))
            else:
                out.append(Caster(it.mesh, tint=tint))
            continue
        mask = materials.material_state(it.mesh, m, asset, options) \
            if m.alpha_mode == "MASK" and asset is not None and options is not None else None
        out.append(Caster(it.mesh, mask))
    return out


_cache: OrderedDict = OrderedDict()  # (asset key, ...) -> ShadowViews
_ctx_id: list = [None]


def shadow_views(ctx: moderngl.Context, key: str, lights, meshes, bounds: np.ndarray,
                 width: int, height: int) -> ShadowViews | None:
    """The shadow maps of `lights` (those shadowing, up to MAX_SHADOW_LIGHTS) cast by `meshes`,
    or None when none casts a shadow. Kept per asset: the camera does not change them."""
    chosen = [i for i, light in enumerate(lights) if light.shadow][:MAX_SHADOW_LIGHTS]
    if not chosen or not meshes:
        return None
    per_light = {i: 1 if (lights[i].type == "directional" or
                          (lights[i].type == "spot" and lights[i].outer_cone <= SPOT_MAX_CONE)) else 6
                 for i in chosen}
    views = sum(per_light.values())
    tile = tile_size(width, height, views)
    cache_key = (key, tile, tuple(chosen), tuple((id(c.mesh), id(c.mask), c.tint, id(c.colour), c.volume) for c in meshes))
    if _ctx_id[0] != id(ctx):  # a new context: the old textures are gone with it
        _cache.clear()
        _ctx_id[0] = id(ctx)
    found = _cache.get(cache_key)
    if found is not None:
        _cache.move_to_end(cache_key)
        return found
    cols = math.ceil(math.sqrt(views))
    rows = math.ceil(views / cols)
    atlas = (cols * tile, rows * tile)
    matrices: list[tuple[np.ndarray, np.ndarray, tuple[int, int]]] = []
    tiles: list[tuple[float, float, float, float]] = []
    texels: list[tuple[float, float]] = []
    light_index = np.zeros((len(lights), 2), np.float32)
    for i in chosen:
        light_index[i] = (len(matrices), per_light[i])
        for view_proj, texel in light_views(lights[i], bounds, tile):
            v = len(matrices)
            x0, y0 = (v % cols) * tile, (v // cols) * tile
            sx, sy = tile / atlas[0], tile / atlas[1]
            ox, oy = x0 / atlas[0], y0 / atlas[1]
            # clip -> atlas uv (before the divide): the tile's rectangle; depth as the depth pass writes it
            b = np.array([[sx / 2, 0, 0, sx / 2 + ox], [0, sy / 2, 0, sy / 2 + oy],
                          [0, 0, 0.5, 0.5], [0, 0, 0, 1.0]])
            matrices.append((view_proj, b @ view_proj, (x0, y0)))
            inset_x, inset_y = 1.5 / atlas[0], 1.5 / atlas[1]  # bilinear taps stay in the tile
            tiles.append((ox + inset_x, oy + inset_y, ox + sx - inset_x, oy + sy - inset_y))
            texels.append(texel)
    texture, tint = _draw(ctx, meshes, matrices, tile, atlas)
    found = ShadowViews(texture, tint, np.asarray([m for _, m, _ in matrices], np.float64),
                        np.asarray(tiles, np.float64), np.asarray(texels, np.float64),
                        light_index, tile, atlas)
    _cache[cache_key] = found
    while len(_cache) > MAX_CACHED:
        old = _cache.popitem(last=False)[1]
        old.texture.release()
        if old.tint is not None:
            old.tint.release()
    return found


def _draw(ctx: moderngl.Context, meshes, matrices, tile: int,
          atlas: tuple[int, int]) -> tuple[moderngl.Texture, moderngl.Texture | None]:
    """Every view's depth into its tile of a new depth atlas, set up for sampler2DShadow; and
    where blend / transmissive casters are, the tint atlas (RGB transmittance, A depth)."""
    tex = ctx.depth_texture(atlas)
    tex.repeat_x = tex.repeat_y = False
    solid_casters = [c for c in meshes if c.tint is None]
    tinted = [c for c in meshes if c.tint is not None]
    tint = ctx.texture(atlas, 4, dtype="f2") if tinted else None
    fbo = ctx.framebuffer(color_attachments=[tint] if tint else [], depth_attachment=tex)
    fbo.scissor = None  # type: ignore[assignment]  # stubs: None is the whole atlas
    fbo.use()
    fbo.clear(1.0, 1.0, 1.0, 1.0, depth=1.0)
    ctx.enable(moderngl.DEPTH_TEST)
    ctx.disable(moderngl.CULL_FACE)  # one-sided surfaces (a ground quad) shadow both ways
    ctx.disable(moderngl.BLEND)
    if tint is not None:
        fbo.color_mask = (False, False, False, False)  # masks apply when the fbo is bound
        fbo.use()
    solid = context.program("pbr.vert", "depth.frag", {})
    for view_proj, _, (x0, y0) in matrices:
        ctx.viewport = (x0, y0, tile, tile)
        matrix = np.ascontiguousarray(view_proj.T, np.float32).tobytes()
        for caster in solid_casters:
            prog = solid if caster.mask is None else _mask_program(caster.mask)
            _render(prog, matrix, caster.mesh)
    if tint is not None:
        # Each layer nearer the light than every opaque caster multiplies the RGB by what it
        # lets through; A keeps the nearest layer's depth (MIN), so receivers before it are not
        # tinted. The depth atlas is tested, not written.
        fbo.color_mask = (True, True, True, True)
        fbo.depth_mask = False
        fbo.use()
        ctx.enable(moderngl.BLEND)
        ctx.blend_func = (moderngl.DST_COLOR, moderngl.ZERO, moderngl.ONE, moderngl.ONE)  # type: ignore[assignment]  # stubs: RGB and A factors
        ctx.blend_equation = (moderngl.FUNC_ADD, moderngl.MIN)
        plain = context.program("pbr.vert", "depth.frag", {"SHADOW_TINT_PASS": 1})
        for view_proj, _, (x0, y0) in matrices:
            ctx.viewport = (x0, y0, tile, tile)
            matrix = np.ascontiguousarray(view_proj.T, np.float32).tobytes()
            for caster in tinted:
                prog = plain if caster.colour is None else _colour_program(caster.colour, caster.volume)
                cast(dict, prog)["u_tint"].value = tuple(float(c) for c in cast(tuple, caster.tint))
                _render(prog, matrix, caster.mesh)
        ctx.blend_equation = moderngl.FUNC_ADD  # type: ignore[assignment]  # stubs: one for both
        ctx.blend_func = moderngl.DEFAULT_BLENDING  # type: ignore[assignment]  # stubs: a tuple
        ctx.disable(moderngl.BLEND)
        fbo.depth_mask = True
        tint.filter = (moderngl.NEAREST, moderngl.NEAREST)  # A is a depth: never blended
        tint.repeat_x = tint.repeat_y = False
    fbo.release()
    tex.compare_func = "<="  # sampler2DShadow: 1 where the receiver is not behind the map
    tex.filter = (moderngl.LINEAR, moderngl.LINEAR)  # bilinear comparisons
    return tex, tint


def _render(prog: moderngl.Program, matrix: bytes, mesh) -> None:
    cast(dict, prog)["u_view_proj"].write(matrix)
    for mirrored, _, count in mesh.instances:
        mesh.vao(prog, mirrored).render(moderngl.TRIANGLES, instances=count)


def _mask_program(state: materials.MaterialState) -> moderngl.Program:
    """The depth program of an alpha-mask caster, its alpha's uniforms and map bound."""
    return _caster_program(state, {"ALPHA_MASK": 1})


def _colour_program(state: materials.MaterialState, volume: bool) -> moderngl.Program:
    """The tint pass's program for a transmissive caster whose colour varies: its base colour
    (factor, map, vertex colours) bound, sqrt'd per layer for a volume."""
    return _caster_program(state, {"SHADOW_TINT_PASS": 1, "SHADOW_TINT_COLOUR": 1,
                                   **({"SHADOW_TINT_SQRT": 1} if volume else {})})


def _caster_program(state: materials.MaterialState, defines: dict) -> moderngl.Program:
    """depth.frag under `defines` plus the caster's base-colour defines, its base colour and
    alpha uniforms and its base-colour map bound."""
    defines = {**defines, **{k: v for k, v in state.defines.items() if k in MASK_DEFINES}}
    prog = context.program("pbr.vert", "depth.frag", defines)
    u = cast(dict, prog)
    for name, value in state.uniforms:
        if name in MASK_UNIFORMS and name in prog:
            u[name].write(value)
    for name, tex in state.textures:
        if name == "u_base_color_map" and name in prog:
            u[name].value = 2
            tex.use(2)
    return prog


def uniforms(views: ShadowViews | None, lights) -> dict[str, bytes]:
    """The per-frame uniforms shaders/punctual.glsl reads under SHADOW_VIEWS."""
    f4 = np.float32
    colors = np.asarray([light.shadow_color for light in lights], f4).reshape(-1, 3)
    if views is None:
        return {}
    return {
        "u_shadow_matrix": np.ascontiguousarray(views.matrices.transpose(0, 2, 1), f4).tobytes(),
        "u_shadow_tile": np.asarray(views.tiles, f4).tobytes(),
        "u_shadow_texel": np.asarray(views.texel, f4).tobytes(),
        "u_light_shadow": np.asarray(views.light_views[:len(lights)], f4).tobytes(),
        "u_shadow_color": colors.tobytes(),
        "u_shadow_step": np.asarray([1.0 / views.atlas[0], 1.0 / views.atlas[1]], f4).tobytes(),
    }
