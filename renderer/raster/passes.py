"""The geometry passes: what a method draws with (`Pass`, `DrawItem`), the per-frame
defines and uniforms every material program shares, and the opaque and blend passes."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import moderngl
import numpy as np

from core import horizon
from core.cubemap import env_rotation_matrix
from core.options import RenderOptions
from core.scene import Material
from gl import context
from renderer.raster import edges, gpu, light_shadows
from renderer.raster.materials import MaterialState, mat3_bytes, material_state
from renderer.view.camera import Camera

MAX_LIGHTS = 8
MATERIAL_DEBUG_VIEWS = {"base": 1, "clearcoat": 2, "sheen": 3, "specular": 4, "transmission": 5,
                        "iridescence": 6}


@dataclass
class DrawItem:
    """One baked mesh as drawn this frame: its GPU data and its material after overrides."""
    mesh: gpu.GpuMesh
    material: Material
    method: str
    why: str
    index: int = -1  # of the mesh in the asset (an emitter is not lit by its own area lights)


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
    shadow_map: moderngl.Texture | None = None  # the lights' depth atlas (light_shadows)
    shadow_tint: moderngl.Texture | None = None  # their tint atlas (see-through casters)
    _bound: set = field(default_factory=set)

    def program(self, item: DrawItem, fragment: str = "pbr.frag", vertex: str = "pbr.vert",
                extra_defines: dict | None = None) -> tuple[moderngl.Program, MaterialState]:
        """The program for `item`'s material with this frame's uniforms set."""
        state = material_state(item.mesh, item.material, self.asset, self.options)
        defines = {**self.frame_defines, **state.defines, **(extra_defines or {})}
        prog = context.program(vertex, fragment, defines)
        if prog.glo not in self._bound:
            for name, data in self.frame_uniforms.items():
                if name in prog:
                    prog[name].write(data)  # type: ignore[union-attr]  # a uniform
            for unit, name in ((0, "u_env"), (1, "u_brdf_lut"), (gpu.IRRADIANCE_UNIT, "u_irradiance"),
                               (light_shadows.UNIT, "u_shadow_map"), (light_shadows.TINT_UNIT, "u_shadow_tint")):
                if name in prog:
                    prog[name].value = unit  # type: ignore[union-attr]  # a uniform
            self._bound.add(prog.glo)
        return prog, state

    def draw(self, item: DrawItem, prog: moderngl.Program, state: MaterialState,
             cull: bool | None = None) -> None:
        """Draw every instance of `item` with `prog` (material uniforms and textures bound)."""
        for name, value in state.uniforms:
            if name in prog:
                prog[name].write(value)  # type: ignore[union-attr]  # a uniform
        if "u_area_self" in prog:
            prog["u_area_self"].value = float(item.index)  # type: ignore[union-attr]  # a uniform
        for unit, (name, tex) in enumerate(state.textures, start=2):
            if name in prog:
                prog[name].value = unit  # type: ignore[union-attr]  # a uniform
                tex.use(unit)
        self.env.cube.use(0)
        self.env.lut.use(1)
        self.env.irradiance.use(gpu.IRRADIANCE_UNIT)
        if self.shadow_map is not None:
            self.shadow_map.use(light_shadows.UNIT)
        if self.shadow_tint is not None:
            self.shadow_tint.use(light_shadows.TINT_UNIT)
        cull = not (item.material.double_sided or item.material.show_back_faces) if cull is None else cull
        if item.mesh.ao_rows is not None:
            item.mesh.ao_rows.bind_to_storage_buffer(gpu.AO_ROWS_BINDING)
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


def env_rotated(options: RenderOptions) -> bool:
    return options.env_rotation % 360.0 != 0.0


def frame_defines(options: RenderOptions, lights,
                  shadows: light_shadows.ShadowViews | None = None, area_lights: int = 0) -> dict:
    d: dict[str, int | str] = {"LIGHT_COUNT": len(lights),
                               "SHADOW_VIEWS": shadows.views if shadows else 0,
                               "AREA_LIGHT_COUNT": area_lights}
    if shadows is not None and shadows.tint is not None:
        d["SHADOW_TINT"] = 1
    if options.multiscatter:
        d["MULTISCATTER"] = 1
    d["HORIZON_TABLE"] = horizon.glsl_table()  # the split-sum's horizon (shaders/ibl.glsl)
    if options.material_debug:  # shaders/lobes.glsl: one lobe alone
        d["MATERIAL_DEBUG"] = MATERIAL_DEBUG_VIEWS[options.material_debug]
    if env_rotated(options):
        d["ENV_ROTATED"] = 1
    return d


def frame_uniforms(camera: Camera, env: gpu.GpuEnvironment, lights, options: RenderOptions,
                   shadows: light_shadows.ShadowViews | None = None) -> dict[str, bytes]:
    f4 = np.float32
    view_proj = camera.projection_matrix() @ camera.view_matrix()
    u = {
        "u_view_proj": np.ascontiguousarray(view_proj.T, f4).tobytes(),
        "u_camera_position": np.asarray(camera.position, f4).tobytes(),
        "u_view_axis": np.asarray(-camera.basis()[2], f4).tobytes(),  # toward the viewer
        "u_env_max_lod": f4(env.max_lod).tobytes(),
    }
    if env_rotated(options):
        u["u_env_rotation"] = mat3_bytes(env_rotation_matrix(options.env_rotation))
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
        u.update(light_shadows.uniforms(shadows, lights))
    return u


def draw_opaque(p: Pass, items: list[DrawItem]) -> None:
    for it in items:
        prog, state = p.program(it)
        p.draw(it, prog, state)


def draw_blend(p: Pass, items: list[DrawItem]) -> None:
    """Meshes back to front by the distance of their first instance's centre (a mesh's own
    instances are not sorted among themselves)."""
    eye = p.camera.position
    order = sorted(((float(np.linalg.norm(c - eye)), i, it) for i, it in enumerate(items)
                    for c in it.mesh.centers[:1]), key=lambda t: -t[0])
    p.ctx.enable(moderngl.BLEND)
    p.fbo.depth_mask = False
    for _, _, it in order:
        # premultiplied-opacity materials (USD) weight their own colour in the shader
        src = moderngl.ONE if it.material.opacity_premultiplied else moderngl.SRC_ALPHA
        p.ctx.blend_func = (src, moderngl.ONE_MINUS_SRC_ALPHA,  # type: ignore[assignment]  # stubs: 2 or 4
                            moderngl.ONE, moderngl.ONE_MINUS_SRC_ALPHA)
        prog, state = p.program(it)
        if it.material.double_sided or it.material.show_back_faces:
            # its far side first, then its near side: the order a per-pixel sort gives a
            # convex mesh (Storm sorts translucent fragments); in one draw the triangles'
            # index order decided which side lay over the other
            p.ctx.cull_face = "front"
            p.draw(it, prog, state, cull=True)
            p.ctx.cull_face = "back"
        p.draw(it, prog, state, cull=True if it.material.double_sided or it.material.show_back_faces else None)
    p.fbo.depth_mask = True
    p.ctx.disable(moderngl.BLEND)


def edge_segments(items: list[DrawItem], camera: Camera) -> np.ndarray:
    """World endpoints of every drawn mesh's edges to smooth (renderer.raster.edges) from `camera`."""
    parts: list[np.ndarray] = []
    ranks: list[np.ndarray] = []
    ordered = any(it.mesh.baked.edge_order is not None for it in items)
    for it in items:
        if it.mesh.edges is None:  # once per upload, from the baked edges where there are some
            it.mesh.edges = edges.of_mesh(it.mesh.baked)
        order = it.mesh.baked.edge_order
        if ordered and order is None:  # unbatched mesh in a batched bake made at render time
            order = np.zeros(1, np.int32)
        ends, rank = edges.ranked_segments(it.mesh.edges, it.mesh.baked.transforms, camera.position, order)
        parts.append(ends)
        if rank is not None:
            ranks.append(rank)
    if not parts:
        return np.zeros((0, 2, 3))
    world = np.concatenate(parts)
    if ordered:  # strips overlap and the last drawn wins: the order the unbatched meshes had
        world = world[np.argsort(np.concatenate(ranks), kind="stable")]
    return world
