"""Raster refraction: the `single` and `wyman` methods (paper sections 3.2 and 4.2).

`single` refracts once at the front face and samples the environment. `wyman` (Wyman 2005 as
the paper adapts it) first draws the nearest back faces of the refractive objects into float
textures (world position + roughness, outward normal + coverage); the front pass refracts
once, estimates the exit distance between the view-ray depth D_d and the baked interior
vector's length D_I (transformed by the instance matrix) by theta_r / theta_i, moves that
estimate onto the back surface with EXIT_REFINE_STEPS Newton steps against the back-face
positions, projects the exit point to fetch the back-face normal (bilinear) and refracts out,
the exit's Fresnel-reflected share reading the environment (shaders/refraction.frag).
Total internal reflection at the exit: `tir="paper"` keeps the first refraction;
`tir="reflect"` reflects internally and marches the reflected ray between the nearest back
faces and the nearest front faces (one more pass, drawn only in this mode) to a second exit,
refracting out by the normal of the layer it crossed. DEFAULT_TIR has the lower error.

Thin-walled materials (glTF: no KHR_materials_volume, or thicknessFactor 0) are sheets with
no inside: both methods let their rays through unbent and unabsorbed (THIN_WALLED), tinted by
base colour and blurred by roughness. Every face is a sheet, so a ray through a closed
thin-walled mesh crosses two, as the tracers have it: both methods draw the nearest back faces
of the thin items first (the same pass as `wyman`'s, THIN_BACK) and the front pass multiplies
the front sheet's base colour by the back sheet's found straight behind it.

Both methods see the asset's own opaque parts: when the frame already holds opaque geometry,
its colour and depth are copied to textures and refracted rays march across them in screen
space before falling back to the environment.

The face textures exist only once some frame has had a `wyman` object: an opaque scene never
runs the passes or allocates them (`stats` counts both, for the tests).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import moderngl
import numpy as np

from renderer.raster.lru import ReleasingLRU
from renderer.raster.materials import FIRST_FREE_UNIT
from renderer.raster.passes import DrawItem, Pass

log = logging.getLogger(__name__)

# Measured at 128-256 px against the references (paper / reflect): sphere 1.5 0.088 / 0.088,
# cube 1.15 0.53 / 0.19, cube 1.5 0.52 / 0.33, bunny 0.316 / 0.317, torus 0.156 / 0.156,
# duck 0.315 / 0.308, teapot 0.327 / 0.325, sphere 2.4 0.154 / 0.156, torus 2.4 0.229 / 0.224.
DEFAULT_TIR = "reflect"
# Newton steps that move Wyman's exit estimate onto the back surface (shaders/refraction.frag
# refine_exit); 0 is the paper's interpolation alone. IOR 1.5 sphere vs Mitsuba: 0.34 with 0
# steps, 0.13 with 1, 0.088 with 2, 0.085 with 3 (the exact exit distance gives 0.085).
EXIT_REFINE_STEPS = 2
# How far (in pixel footprints at its distance) a refined exit may sit from the back surface
# and still count as on it, so its TIR is trusted and the internally reflected ray marched to
# a second exit: a tolerance relative to the exit distance alone fails where that distance is
# under a pixel or two (the rims of flat faces, where the view ray meets the face's far edge),
# and there the paper's fallback left a short path: rims too bright, too little absorbed
# (AttenuationTest). Against Mitsuba at 128 px (relative MAE, 2% alone / 1 / 2 / 3 / 4):
# cube 1.5 0.326 / 0.241 / 0.212 / 0.212 / 0.212, cube 2.4 0.328 / 0.284 / 0.256 / 0.241 /
# 0.241, bunny 1.5 0.349 / 0.350 / 0.352 / 0.353 / 0.352, duck 0.318 / 0.321 / 0.323 (2-4).
PIXEL_TOL = 3.0
DEBUG_VIEWS = {"backface_normals": 1, "tir": 2, "exit_distance": 3}
MAX_TARGETS = 6  # (kind, size) entries: back, front and opaque layers for two sizes
# Texture units above the material's (renderer.raster.passes.Pass.draw binds 0, 1 and one per material slot).
(_UNIT_BACK_POSITION, _UNIT_BACK_NORMAL, _UNIT_OPAQUE_COLOR, _UNIT_OPAQUE_DEPTH,
 _UNIT_FRONT_POSITION, _UNIT_FRONT_NORMAL, _UNIT_BACK_TINT) = range(FIRST_FREE_UNIT, FIRST_FREE_UNIT + 7)

stats = {"backface_passes": 0, "frontface_passes": 0, "back_allocations": 0,
         "front_allocations": 0, "opaque_allocations": 0, "opaque_copies": 0,
         "opaque_mipmaps": 0}


@dataclass
class _Targets:
    """Textures of one kind for one frame size, and their framebuffer."""
    fbo: moderngl.Framebuffer
    color: list[moderngl.Texture]
    depth: moderngl.Texture

    def release(self) -> None:
        resources: tuple[moderngl.Framebuffer | moderngl.Texture, ...] = (self.fbo, *self.color, self.depth)
        for r in resources:
            r.release()


_targets = ReleasingLRU(MAX_TARGETS)  # (kind, w, h) -> targets of the current context
_targets_ctx: int | None = None


def allocated() -> list[tuple]:
    """(kind, width, height) of the refraction textures alive now ("back", "opaque")."""
    return list(_targets)


def _get_targets(ctx: moderngl.Context, kind: str, w: int, h: int) -> _Targets:
    """Back / front faces: RGBA32F world position + roughness, RGBA16F outward normal + coverage,
    RGBA16F sqrt(base colour) (the crossing's transmission tint). Opaque copy: RGBA16F colour. Both with a depth texture; kept per size (small LRU)."""
    global _targets, _targets_ctx
    if _targets_ctx != id(ctx):
        _targets = ReleasingLRU(MAX_TARGETS)  # the old context's objects went with it
        _targets_ctx = id(ctx)
    key = (kind, w, h)
    t = _targets.get(key)
    if t is None:
        dtypes = ("f2",) if kind == "opaque" else ("f4", "f2", "f2")
        color = [ctx.texture((w, h), 4, dtype=dt) for dt in dtypes]
        for tex in color:
            tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
            tex.repeat_x = tex.repeat_y = False
        depth = ctx.depth_texture((w, h))
        depth.compare_func = ""  # read as values, not as a shadow comparison
        t = _Targets(ctx.framebuffer(color, depth), color, depth)
        stats[f"{kind}_allocations"] += 1
        _targets[key] = t
    return t


def _opaque_copy(p: Pass, rough: bool) -> _Targets:
    """Resolve the frame's opaque geometry (colour + depth) into textures the front pass reads;
    with mips when some refractive material is `rough` (its lobe reads a blurred copy)."""
    w, h = p.fbo.size
    t = _get_targets(p.ctx, "opaque", w, h)
    p.ctx.copy_framebuffer(t.fbo, p.fbo)
    if rough:
        t.color[0].build_mipmaps()
        stats["opaque_mipmaps"] += 1
    stats["opaque_copies"] += 1
    return t


def _rough(mat) -> bool:
    return mat.roughness > 0.0 and mat.ior != 1.0


def _surface_pass(p: Pass, items: list[DrawItem], side: str) -> _Targets:
    """The nearest `side` ("back" or "front") faces of the refractive objects: world position,
    roughness, outward normal and sqrt(base colour) (shaders/backface.frag)."""
    ctx = p.ctx
    w, h = p.fbo.size
    t = _get_targets(ctx, side, w, h)
    t.fbo.use()
    ctx.viewport = (0, 0, w, h)
    t.fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
    ctx.enable(moderngl.DEPTH_TEST)
    ctx.cull_face = "front" if side == "back" else "back"
    try:
        for it in items:
            prog, state = p.program(it, fragment="backface.frag")
            p.draw(it, prog, state, cull=True)
    finally:
        ctx.cull_face = "back"
    stats[f"{side}face_passes"] += 1
    return t


def tir_mode(options) -> str:
    mode = options.tir or DEFAULT_TIR
    if mode not in ("paper", "reflect"):
        raise ValueError(f"tir {options.tir!r}: use paper or reflect")
    return mode


def _draw_front(p: Pass, items: list[DrawItem], back: _Targets | None,
                front: _Targets | None, opaque: _Targets | None, thin_back: _Targets | None = None) -> None:
    wyman = back is not None
    cam = p.camera
    w, h = cam.width, cam.height
    radius = max(float(np.linalg.norm(np.subtract(*p.asset.bounds[::-1]))) / 2, 1e-6)
    defines: dict = {}
    if wyman:
        defines["WYMAN"] = 1
        defines["EXIT_REFINE"] = int(EXIT_REFINE_STEPS)
        defines["PIXEL_TOL"] = f"{PIXEL_TOL:.3f}"
        if tir_mode(p.options) == "reflect":
            defines["TIR_REFLECT"] = 1
        if p.options.debug:
            if p.options.debug not in DEBUG_VIEWS:
                raise ValueError(f"debug view {p.options.debug!r}: use {', '.join(DEBUG_VIEWS)}")
            defines["DEBUG_VIEW"] = DEBUG_VIEWS[p.options.debug]
    if opaque:
        defines["SCREEN_OPAQUE"] = 1
    if thin_back is not None:
        defines["THIN_BACK"] = 1
    p.fbo.use()
    p.ctx.viewport = (0, 0, w, h)
    for it in items:
        extra = dict(defines)
        if "interior" in it.mesh.buffers:
            extra["HAS_INTERIOR"] = 1
        if it.material.thin_walled:
            extra["THIN_WALLED"] = 1
        prog, state = p.program(it, fragment="refraction.frag", extra_defines=extra)
        mat = it.material
        values = {
            "u_viewport": (float(w), float(h)), "u_ior": float(max(mat.ior, 1e-3)),
            "u_transmission": float(min(max(mat.transmission, 0.0), 1.0)),
            "u_sigma": tuple(float(x) for x in mat.absorption()), "u_thickness": float(max(mat.thickness, 0.0)),
            "u_near_far": (float(cam.near), float(cam.far)),
            "u_camera_forward": tuple(float(x) for x in cam.basis()[2]),
            "u_trace_length": 2.0 * radius,
            "u_pixel_angle": 2.0 * float(np.tan(np.radians(cam.fov) / 2)) / float(h), "u_debug_scale": 0.5 / radius,
            "u_back_position": _UNIT_BACK_POSITION, "u_back_normal": _UNIT_BACK_NORMAL,
            "u_back_tint": _UNIT_BACK_TINT,
            "u_front_position": _UNIT_FRONT_POSITION, "u_front_normal": _UNIT_FRONT_NORMAL,
            "u_opaque_color": _UNIT_OPAQUE_COLOR, "u_opaque_depth": _UNIT_OPAQUE_DEPTH,
        }
        for name, value in values.items():
            if name in prog:
                prog[name].value = value  # type: ignore[union-attr]  # a uniform
        if back is not None:  # wyman
            back.color[0].use(_UNIT_BACK_POSITION)
            back.color[1].use(_UNIT_BACK_NORMAL)
            back.color[2].use(_UNIT_BACK_TINT)
        if thin_back is not None:  # the thin sheets' far sides
            thin_back.color[0].use(_UNIT_BACK_POSITION)
            thin_back.color[2].use(_UNIT_BACK_TINT)
        if front is not None:
            front.color[0].use(_UNIT_FRONT_POSITION)
            front.color[1].use(_UNIT_FRONT_NORMAL)
        if opaque:
            opaque.color[0].use(_UNIT_OPAQUE_COLOR)
            opaque.depth.use(_UNIT_OPAQUE_DEPTH)
        p.draw(it, prog, state)
        it.why = f"{it.why}; tir={tir_mode(p.options)}" if wyman else it.why


def _draw(p: Pass, items: list[DrawItem], wyman: bool) -> None:
    opaque = _opaque_copy(p, any(_rough(it.material) for it in items)) if p.opaque_drawn else None
    thin = [it for it in items if it.material.thin_walled]  # no inside, but a far sheet
    solid = [it for it in items if not it.material.thin_walled]
    if thin:
        _draw_front(p, thin, None, None, opaque, _surface_pass(p, thin, "back"))
    if solid:
        back = _surface_pass(p, solid, "back") if wyman else None
        front = _surface_pass(p, solid, "front") if wyman and tir_mode(p.options) == "reflect" else None
        _draw_front(p, solid, back, front, opaque)


def draw_single(p: Pass, items: list[DrawItem]) -> None:
    """One refraction at the front face; the refracted ray samples the environment."""
    _draw(p, items, wyman=False)


def draw_wyman(p: Pass, items: list[DrawItem]) -> None:
    """Back-face pass, then two refractions with Wyman's exit estimate."""
    _draw(p, items, wyman=True)

