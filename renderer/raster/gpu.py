"""Baked data on the GPU: meshes, material textures and environments, kept in bounded LRUs.

Uploading is the expensive part of a warm thumbnail on a CPU rasteriser, so everything is
keyed by the bake's content key and kept until evicted: a second thumbnail of the same
asset (any camera, size or options) uploads nothing. `stats` counts uploads for the tests.
"""
from __future__ import annotations

import ctypes
import logging
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable, TypeVar

import moderngl
import numpy as np

from core.baked import BakedAsset, BakedEnvironment, BakedMesh, BakedTexture, quantise_directions, quantise_visibility
from core.config import renderer_settings
from core.mips import level_shapes, texture_size_for
from core.scene import CLAMP_TO_EDGE, MIRRORED_REPEAT, REPEAT, Light, is_srgb, point_box
from gl import context
from renderer.raster.lru import ReleasingLRU

log = logging.getLogger(__name__)

GL_SRGB8_ALPHA8 = 0x8C43
GL_TEXTURE_CUBE_MAP_SEAMLESS = 0x884F



@dataclass
class Budget:
    """How much stays uploaded per context (core.config.RendererSettings; the service
    sets its own with `set_budget`): meshes and textures in bytes, environments by count."""
    asset_bytes: int
    environments: int


_budget: Budget | None = None


def budget() -> Budget:
    global _budget
    if _budget is None:
        s = renderer_settings()
        _budget = Budget(int(s.gpu_bytes), s.gpu_environments)
    return _budget


def set_budget(asset_bytes: int, environments: int) -> None:
    """A new budget; what is uploaded now is released."""
    global _budget, _ctx_id
    _budget = Budget(asset_bytes, environments)
    clear()
    _ctx_id = None


def uploaded_bytes() -> int:
    return sum(a.nbytes for a in _assets.values_all()) if _assets is not None else 0


stats = {"asset_uploads": 0, "environment_uploads": 0, "evictions": 0,
         # frames of an animation on one upload (BakedAsset.gpu_key): buffers rewritten
         "poses": 0, "vertex_writes": 0, "instance_writes": 0}

# Vertex attributes by BakedMesh field: (shader name, moderngl format).
_ATTRIBUTES = {
    "positions": ("in_position", "3f"), "normals": ("in_normal", "3f"),
    "tangents": ("in_tangent", "4f"), "uv0": ("in_uv0", "2f"), "uv1": ("in_uv1", "2f"),
    "colors": ("in_color", "4f"),
    # baked ambient visibility, front and back (pipeline.occlusion): uint8 x 255 as the bake
    # stores it, read as normalised floats (a quarter of float32's buffer)
    "ao": ("in_ao", "2f1"),
    # bent normals, front and back (pipeline.occlusion): uint8 (x + 1) / 2 x 255, two attributes
    "bent": ("in_bent in_bent_back", "3f1 3f1"),
    "interior": ("in_interior", "3f"),  # refractive meshes only (renderer.methods.refraction)
}
# per instance: model and normal matrices, and its row in transforms (per-placement visibility)
_INSTANCE = ("16f 9f 1f/i", "in_model", "in_normal_matrix", "in_instance_row")
AO_ROWS_BINDING = 0  # shader storage binding of a mesh's per-placement visibility (pbr.vert)


@dataclass
class GpuMesh:
    baked: BakedMesh
    buffers: dict[str, moderngl.Buffer]
    index_buffer: moderngl.Buffer
    # Instances split by the sign of the transform's determinant: a mirroring transform flips
    # the winding, so those draw with the opposite front face.
    instances: list[tuple[bool, moderngl.Buffer, int]]
    centers: np.ndarray          # K x 3 world-space instance centres (blend sorting)
    nbytes: int
    vaos: dict[tuple, moderngl.VertexArray] = field(default_factory=dict)
    states: dict = field(default_factory=dict)  # renderer's per-material state, by override
    edges: Any = None  # renderer.raster.edges.Adjacency, set up on the first edge-smoothed frame
    # the baked visibility as one row of vertices per placement (BakedMesh.ao_per_placement):
    # a storage buffer the vertex shader indexes by instance row and vertex (pbr.vert)
    ao_rows: moderngl.Buffer | None = None

    def vao(self, prog: moderngl.Program, mirrored: bool) -> moderngl.VertexArray:
        key = (prog.glo, mirrored)
        vao = self.vaos.get(key)
        if vao is None:
            content: list[tuple] = [(buf, _ATTRIBUTES[name][1], *_ATTRIBUTES[name][0].split())
                                   for name, buf in self.buffers.items()]
            inst = next(b for m, b, _ in self.instances if m == mirrored)
            content.append((inst, *_INSTANCE))
            vao = context.get_context().vertex_array(prog, content, self.index_buffer, 4,
                                                     skip_errors=True)
            self.vaos[key] = vao
        return vao

    def release(self) -> None:
        for vao in self.vaos.values():
            vao.release()
        for buf in [*self.buffers.values(), self.index_buffer, *(b for _, b, _ in self.instances),
                    *([self.ao_rows] if self.ao_rows is not None else [])]:
            buf.release()


@dataclass
class GpuAsset:
    key: str
    meshes: list[GpuMesh]
    textures: dict[tuple[int, bool], moderngl.Texture]  # (texture index, sRGB) -> texture
    lights: list[Light]
    bounds: np.ndarray
    nbytes: int
    # Per texture: (level-0 height, width) uploaded and its bytes. A render needing sharper
    # levels than a previous one uploaded re-specifies that texture in place (same GL object).
    texture_levels: dict[tuple[int, bool], tuple[tuple[int, int], int]] = field(default_factory=dict)

    def release(self) -> None:
        for m in self.meshes:
            m.release()
        for t in self.textures.values():
            t.release()


@dataclass
class GpuEnvironment:
    key: str
    cube: moderngl.TextureCube
    lut: moderngl.Texture
    irradiance: moderngl.TextureCube  # E / pi (core.irradiance), read along the bent normal
    max_lod: float
    prefilter: str

    def release(self) -> None:
        self.cube.release()
        self.lut.release()
        self.irradiance.release()


# Byte-weighed LRUs (renderer.raster.lru) of the current context, made with it.
_assets: ReleasingLRU | None = None
_environments: ReleasingLRU | None = None
_ctx_id: int | None = None


def _tables() -> tuple[ReleasingLRU, ReleasingLRU]:
    """Caches belong to one context; a new context (forked child) starts them empty."""
    global _ctx_id, _assets, _environments
    ctx = context.get_context()
    if _ctx_id != id(ctx) or _assets is None:
        b = budget()
        _assets = ReleasingLRU(b.asset_bytes, getsizeof=lambda a: max(1, a.nbytes))
        _environments = ReleasingLRU(b.environments)
        _ctx_id = id(ctx)
        ctx.enable_direct(GL_TEXTURE_CUBE_MAP_SEAMLESS)
    assert _environments is not None
    return _assets, _environments


_Gpu = TypeVar("_Gpu", GpuAsset, GpuEnvironment)


def _cached(table: ReleasingLRU, key: str, upload: Callable[[], _Gpu], stat: str) -> _Gpu:
    gpu = table.get(key)
    if gpu is None:
        before = table.evictions
        gpu = table[key] = upload()
        stats[stat] += 1
        stats["evictions"] += table.evictions - before
    return gpu


def asset(baked: BakedAsset, pixels: int = 1024) -> GpuAsset:
    """The GPU copy of `baked`, uploaded on first use and then reused (LRU by bake key), with
    texture levels sharp enough for a render of `pixels` (its longer side) and no sharper
    (core.mips.texture_size_for: up to twice its size, for atlases)."""
    table = _tables()[0]
    gpu = _cached(table, baked.gpu_key or baked.key, lambda: _upload_asset(baked), "asset_uploads")
    if baked.gpu_key is not None and (len(gpu.meshes) != len(baked.meshes) or any(
            gm.baked is not m for gm, m in zip(gpu.meshes, baked.meshes))):
        if not _repose(gpu, baked):  # another pose of what it holds, or of another rig
            before = table.evictions
            gpu = _upload_asset(baked)
            table.replace(gpu.key, gpu)
            stats["asset_uploads"] += 1
            stats["evictions"] += table.evictions - before
    if _upload_textures(gpu, baked, texture_size_for(pixels)):
        before = table.evictions
        table.reweigh(baked.key)  # it grew: others go while the budget needs it
        stats["evictions"] += table.evictions - before
    return gpu


def environment(baked: BakedEnvironment) -> GpuEnvironment:
    """The GPU copy of `baked` (cube with its prefiltered mips, BRDF LUT, SH), LRU by key."""
    return _cached(_tables()[1], baked.key, lambda: _upload_environment(baked), "environment_uploads")


def clear() -> None:
    """Release everything (tests; a service shrinking its memory)."""
    for cache in (_assets, _environments):
        if cache is not None:
            cache.clear()


def _vertex_data(name: str, arr: np.ndarray) -> np.ndarray:
    """One attribute's array as its buffer holds it (_ATTRIBUTES' format)."""
    if name == "ao":
        return np.ascontiguousarray(arr if arr.dtype == np.uint8 else quantise_visibility(arr))
    if name == "bent":
        return np.ascontiguousarray(arr if arr.dtype == np.uint8 else quantise_directions(arr))
    return np.ascontiguousarray(arr, np.float32)


def _upload_asset(baked: BakedAsset) -> GpuAsset:
    ctx = context.get_context()
    meshes = []
    for m in baked.meshes:
        buffers = {}
        for name in _ATTRIBUTES:
            arr = getattr(m, name)
            if arr is not None and len(arr) == len(m.positions):
                buffers[name] = ctx.buffer(_vertex_data(name, arr))
        ibo = ctx.buffer(np.ascontiguousarray(m.indices, np.uint32))
        transforms = np.asarray(m.transforms, np.float64).reshape(-1, 4, 4)
        det = np.linalg.det(transforms[:, :3, :3])
        instances = []
        for mirrored in (False, True):
            sel = transforms[(det < 0) == mirrored]
            if len(sel):
                instances.append((mirrored, ctx.buffer(_instance_data(transforms, det, mirrored)), len(sel)))
        centers = transforms[:, :3, :3] @ _centre(m) + transforms[:, :3, 3]
        ao_rows = ctx.buffer(_ao_rows_data(m)) if m.ao_per_placement else None
        nbytes = sum(b.size for b in buffers.values()) + ibo.size + (ao_rows.size if ao_rows else 0)
        meshes.append(GpuMesh(m, buffers, ibo, instances, centers, nbytes, ao_rows=ao_rows))
    nbytes = sum(m.nbytes for m in meshes)
    log.info("uploaded %s: %d meshes, %.1f MB", baked.key[:12], len(meshes), nbytes / 2**20)
    return GpuAsset(baked.gpu_key or baked.key, meshes, {}, list(baked.lights),
                    np.asarray(baked.bounds), nbytes)


def _repose(gpu: GpuAsset, baked: BakedAsset) -> bool:
    """Make `gpu` hold `baked`, another pose of the asset it holds: the vertex buffers whose
    arrays are other objects are rewritten (a pose shares every array that did not move with
    the one before), the instance matrices of every mesh; nothing else is uploaded. False,
    touching nothing, when `baked` is laid out otherwise (other meshes, triangles or
    attributes: another animation's rig): it needs an upload of its own."""
    if len(baked.meshes) != len(gpu.meshes):
        return False
    for gm, m in zip(gpu.meshes, baked.meshes):
        old = gm.baked
        if m.indices is not old.indices and not np.array_equal(m.indices, old.indices):
            return False
        have = {name for name in _ATTRIBUTES
                if (a := getattr(m, name)) is not None and len(a) == len(m.positions)}
        if have != set(gm.buffers) or len(m.positions) != len(old.positions):
            return False
        if m.ao_per_placement != (gm.ao_rows is not None) or (
                m.ao is not None and old.ao is not None and gm.ao_rows is not None
                and m.ao.nbytes != old.ao.nbytes):
            return False
    ctx = context.get_context()
    for gm, m in zip(gpu.meshes, baked.meshes):
        old = gm.baked
        for name, buf in gm.buffers.items():
            arr = getattr(m, name)
            if arr is getattr(old, name):
                continue
            buf.write(_vertex_data(name, arr))
            stats["vertex_writes"] += 1
        if gm.ao_rows is not None and m.ao is not old.ao:
            gm.ao_rows.write(_ao_rows_data(m))
        if m.positions is not old.positions:
            gm.edges = None  # the edge planes follow the surface (renderer.raster.edges)
        if m.material is not old.material:
            gm.states.clear()
        transforms = np.asarray(m.transforms, np.float64).reshape(-1, 4, 4)
        det = np.linalg.det(transforms[:, :3, :3])
        for mirrored, buf, count in gm.instances:
            sel = transforms[(det < 0) == mirrored]
            if len(sel) != count:  # a scale through zero turned some over: lay them out anew
                _instances_anew(ctx, gm, transforms, det)
                break
            buf.write(_instance_data(transforms, det, mirrored))
        else:
            if sum(c for _, _, c in gm.instances) != len(transforms):
                _instances_anew(ctx, gm, transforms, det)
        stats["instance_writes"] += 1
        gm.centers = transforms[:, :3, :3] @ _centre(m) + transforms[:, :3, 3]
        gm.baked = m
    gpu.lights, gpu.bounds = list(baked.lights), np.asarray(baked.bounds)
    stats["poses"] += 1
    return True


def _instances_anew(ctx, gm: GpuMesh, transforms: np.ndarray, det: np.ndarray) -> None:
    for vao in gm.vaos.values():
        vao.release()
    gm.vaos.clear()
    for _, buf, _ in gm.instances:
        buf.release()
    gm.instances = [(mirrored, ctx.buffer(_instance_data(transforms, det, mirrored)), len(sel))
                    for mirrored in (False, True)
                    if len(sel := transforms[(det < 0) == mirrored])]


def _centre(m: BakedMesh) -> np.ndarray:
    if not len(m.positions):
        return np.zeros(3)
    lo, hi = point_box(m.positions)
    return (lo + hi) / 2


def _upload_textures(gpu: GpuAsset, baked: BakedAsset, top: int) -> int:
    """Upload every texture the materials use at levels from `top` texels down, where what
    is on the GPU is coarser (or absent). Returns the bytes added."""
    todo = []
    for key in sorted({(ref.texture, is_srgb(slot)) for m in baked.meshes
                       for slot, ref in m.material.texture_refs().items()}):
        if not 0 <= key[0] < len(baked.textures):
            continue
        size = next((s for s in level_shapes(*baked.textures[key[0]].size) if max(s) <= top), (1, 1))
        have = gpu.texture_levels.get(key)
        if have is None or have[0][0] < size[0] or have[0][1] < size[1]:
            todo.append(key)
    if not todo:
        return 0

    def read(key: tuple[int, bool]) -> list[np.ndarray]:
        return baked.textures[key[0]].mips(key[1], top)
    # A cold start reads several big chains: their checksums and zstd release the GIL, so
    # they decompress side by side (~25 ms off an asset with three 8k textures on 2 cores).
    if len(todo) > 1:
        with ThreadPoolExecutor(min(len(todo), os.cpu_count() or 1)) as pool:
            chains = list(pool.map(read, todo))
    else:
        chains = [read(todo[0])]
    added = 0
    for key, chain in zip(todo, chains):
        have = gpu.texture_levels.get(key)
        gpu.textures[key] = _upload_texture(gpu.textures.get(key), baked.textures[key[0]], chain, key[1])
        nbytes = sum(lv.nbytes for lv in chain)
        added += nbytes - (have[1] if have else 0)
        gpu.texture_levels[key] = (chain[0].shape[:2], nbytes)
    gpu.nbytes += added
    return added


def _ao_rows_data(m: BakedMesh) -> bytes:
    """The per-placement visibility as pbr.vert reads it: uint8 pairs, padded to whole words."""
    raw = np.ascontiguousarray(m.ao, np.uint8).tobytes()
    return raw + bytes(-len(raw) % 4)


def _instance_data(all_transforms: np.ndarray, det: np.ndarray, mirrored: bool) -> np.ndarray:
    """Per instance of one winding (`mirrored`: negative determinant): the model matrix, the
    normal matrix (inverse transpose), column-major, and its row in `all_transforms`."""
    rows = np.flatnonzero((det < 0) == mirrored)
    transforms = all_transforms[rows]
    model = transforms.astype(np.float32)
    linear = transforms[:, :3, :3]
    with np.errstate(all="ignore"):
        normal = np.linalg.pinv(linear).transpose(0, 2, 1)
    normal = np.nan_to_num(normal).astype(np.float32)
    # GLSL matrices are column-major: transpose each before flattening.
    return np.ascontiguousarray(np.concatenate(
        [model.transpose(0, 2, 1).reshape(-1, 16), normal.transpose(0, 2, 1).reshape(-1, 9),
         rows.astype(np.float32)[:, None]], axis=1))


def _upload_texture(gl_tex: moderngl.Texture | None, tex: BakedTexture, chain: list[np.ndarray],
                    srgb: bool) -> moderngl.Texture:
    """`chain` (RGBA8, level 0 first, as baked) into `gl_tex`, or into a new texture."""
    # Row 0 of the image is its top and glTF's v = 0, and GL's t = 0 is the first row
    # uploaded: uploading rows in order makes glTF UVs sample the right way up.
    # The baked mips are uploaded level by level (glGenerateMipmap on llvmpipe JIT-compiles a
    # blit shader first, ~60 ms of a cold start, and would redo the bake's work).
    h, w = chain[0].shape[:2]
    fmt = GL_SRGB8_ALPHA8 if srgb else GL_RGBA8
    if gl_tex is None:
        gl_tex = context.get_context().texture((w, h), 4, None, internal_format=fmt if srgb else None)
    gl = _gl()
    gl_tex.use(0)
    for level, img in enumerate(chain):
        gl.glTexImage2D(GL_TEXTURE_2D, level, fmt, img.shape[1], img.shape[0], 0, GL_RGBA,
                        GL_UNSIGNED_BYTE, np.ascontiguousarray(img).ctypes.data)
    gl.glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAX_LEVEL, len(chain) - 1)
    gl_tex.filter = (tex.sampler.min_filter, tex.sampler.mag_filter)
    if tex.sampler.min_filter in MIPMAP_FILTERS:
        # Anisotropic filtering (GL_EXT_texture_filter_anisotropic; llvmpipe and every desktop
        # driver have it): a surface seen at an angle samples along its footprint's long axis
        # instead of taking the blurrier mip its long axis alone would pick.
        gl_tex.anisotropy = min(MAX_ANISOTROPY, context.get_context().max_anisotropy)
    # glTF wrap enums are GL's (REPEAT, CLAMP_TO_EDGE, MIRRORED_REPEAT); moderngl's repeat_x
    # knows only the first two, so set both axes directly on the bound texture.
    for axis, mode in ((GL_TEXTURE_WRAP_S, tex.sampler.wrap_s), (GL_TEXTURE_WRAP_T, tex.sampler.wrap_t)):
        gl.glTexParameteri(GL_TEXTURE_2D, axis, mode if mode in WRAP_MODES else REPEAT)
    return gl_tex


def _upload_environment(baked: BakedEnvironment) -> GpuEnvironment:
    ctx = context.get_context()
    size = baked.face_size
    levels = len(baked.specular)
    # moderngl uploads only level 0 of a cube map, and allocating the other levels with
    # glGenerateMipmap costs a full CPU mip build on llvmpipe that is then thrown away, so
    # each (face, level) goes up with one glTexImage2D (float32 in, stored as half floats:
    # GL's conversion is faster than numpy's on llvmpipe).
    cube = ctx.texture_cube((size, size), 3, None, dtype="f2")
    gl = _gl()
    cube.use(0)
    for level, mip in enumerate(baked.specular):
        s = max(size >> level, 1)
        if mip.shape[:3] != (6, s, s):
            raise ValueError(f"environment {baked.name}: mip {level} is {mip.shape}, expected 6x{s}x{s}")
        rgb = np.ascontiguousarray(mip[..., :3], np.float32)
        for face in range(6):
            gl.glTexImage2D(GL_TEXTURE_CUBE_MAP_POSITIVE_X + face, level, GL_RGB16F, s, s, 0,
                            GL_RGB, GL_FLOAT, rgb[face].ctypes.data)
    gl.glTexParameteri(GL_TEXTURE_CUBE_MAP, GL_TEXTURE_MAX_LEVEL, levels - 1)
    cube.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
    lut_arr = np.ascontiguousarray(baked.brdf_lut[..., :3], np.float32)
    if lut_arr.shape[2] != 3:
        raise ValueError(f"environment {baked.name}: BRDF LUT has {lut_arr.shape[2]} channels, "
                         "expected 3 (scale, bias, sheen albedo); re-bake it")
    lut = ctx.texture((lut_arr.shape[1], lut_arr.shape[0]), 3, lut_arr, dtype="f4")
    lut.repeat_x = lut.repeat_y = False
    irradiance = irradiance_texture(baked.irradiance)
    log.info("uploaded environment %s: %d px faces, %d mips", baked.name, size, levels)
    return GpuEnvironment(baked.key, cube, lut, irradiance, float(levels - 1), baked.prefilter)


def irradiance_texture(faces: np.ndarray) -> moderngl.TextureCube:
    """The bake's irradiance cube (6 x S x S x 3, E / pi) as a float32 cube map read bilinearly
    (seamless across faces: _tables enables it), no mips: it is smooth at any footprint."""
    s = faces.shape[1]
    if faces.shape != (6, s, s, 3):
        raise ValueError(f"irradiance cube is {faces.shape}, expected 6 x S x S x 3; re-bake it")
    data = np.ascontiguousarray(faces, np.float32)
    tex = context.get_context().texture_cube((s, s), 3, data.tobytes(), dtype="f4")
    tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
    return tex


IRRADIANCE_UNIT = 29  # the irradiance cube's texture unit (material textures start at 2; shadows 30, 31)
GL_TEXTURE_2D = 0x0DE1
GL_RGBA, GL_RGBA8, GL_UNSIGNED_BYTE = 0x1908, 0x8058, 0x1401
GL_TEXTURE_CUBE_MAP = 0x8513
GL_TEXTURE_CUBE_MAP_POSITIVE_X = 0x8515
GL_TEXTURE_MAX_LEVEL = 0x813D
GL_TEXTURE_WRAP_S, GL_TEXTURE_WRAP_T = 0x2802, 0x2803
WRAP_MODES = (REPEAT, CLAMP_TO_EDGE, MIRRORED_REPEAT)
MIPMAP_FILTERS = (moderngl.NEAREST_MIPMAP_NEAREST, moderngl.LINEAR_MIPMAP_NEAREST,
                  moderngl.NEAREST_MIPMAP_LINEAR, moderngl.LINEAR_MIPMAP_LINEAR)
MAX_ANISOTROPY = 16.0  # what reference viewers ask for (three.js, Filament: the driver's maximum)
GL_RGB16F, GL_RGB, GL_FLOAT = 0x881B, 0x1907, 0x1406


def _gl():
    """The two GL entry points moderngl lacks, from the process's EGL (core functions are
    exported by EGL_KHR_get_all_proc_addresses, which Mesa and NVIDIA implement)."""
    global _GL
    if _GL is None:
        egl = ctypes.CDLL(context.library("EGL") or "libEGL.so.1")
        egl.eglGetProcAddress.restype = ctypes.c_void_p
        egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]

        def fn(name, *args):
            ptr = egl.eglGetProcAddress(name.encode())
            if not ptr:
                raise RuntimeError(f"OpenGL function {name} not found through EGL")
            return ctypes.CFUNCTYPE(None, *args)(ptr)
        c = ctypes
        _GL = type("GL", (), {})()
        _GL.glTexImage2D = fn("glTexImage2D", c.c_uint, c.c_int, c.c_int, c.c_int, c.c_int,
                              c.c_int, c.c_uint, c.c_uint, c.c_void_p)
        _GL.glTexParameteri = fn("glTexParameteri", c.c_uint, c.c_uint, c.c_int)
    return _GL


_GL = None
