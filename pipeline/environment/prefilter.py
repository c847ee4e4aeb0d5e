"""Environment bake (paper section 4.1): equirect panorama -> cube faces -> specular mip chain,
the irradiance cube the raster's diffuse reads (core.irradiance: the exact cosine integral of
the sharpest level's texels), 9 spherical-harmonic coefficients (kept for comparison: bench/
irradiance_cube.py), and the split-sum BRDF LUT (with the sheen albedo in its third channel).

Prefiltering runs as GLSL in the process's headless context (`gl.context`); every face of
a mip is drawn in one pass into an S x 6S atlas (shaders/cube_atlas.glsl) and read back as
6 x S x S x 3 float32 in `core.cubemap`'s face order and orientation.

Two methods, and the LOD the renderer must use for each (`roughness_to_lod`):
- "ggx" (default): mip m holds the environment convolved with the GGX lobe of roughness
  m / (levels - 1) under the split-sum N = V = R assumption (Karis 2013); mip 0 is the source
  resampled. Importance sampling with mip-filtered samples (the source LOD is chosen from the
  sample's pdf solid angle against the texel's, as Filament's cmgen does) keeps a few dozen
  samples free of fireflies; sampling is in direction space through a seamless cube lookup, so
  no seams. LOD = roughness x (levels - 1), linear.
- "paper": the paper's baseline, a plain mip chain where each level is the previous one blurred
  by a 3x3 Gaussian per face and halved (with the seams that causes). LOD = roughness x max LOD,
  the same linear map, with max LOD = levels - 1.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from core.cubemap import DEFAULT_FACE_SIZE, check_face_size, default_levels
from core.hammersley import ggx_reflections
from core.irradiance import IRRADIANCE_FACE, irradiance_cube
from core.sh import SH_C0, SH_C1, SH_C2, SH_C3, SH_C4
from pipeline.environment.panorama import DEFAULT_ENVIRONMENT, Panorama, list_bundled, load_panorama, synthetic_panorama  # noqa: F401

log = logging.getLogger(__name__)

METHODS = ("ggx", "paper")
PREFILTER_VERSION = 5      # bump when the filter's or the LUT's output changes (cache keys include it); 4: height-correlated Smith G, 5: LUT albedo <= 1
GGX_SAMPLES = 64           # per texel at mip 1, doubling per mip (coarse mips have few texels)
GGX_MAX_SAMPLES = 512
LUT_SIZE = 64
LUT_SAMPLES = 256



@dataclass
class EnvironmentArrays:
    specular: list[np.ndarray]        # mips, each 6 x S x S x 3 float32 (+X,-X,+Y,-Y,+Z,-Z)
    irradiance_sh: np.ndarray         # 9 x 3 radiance SH coefficients (basis above)
    brdf_lut: np.ndarray              # N x N x 3; row j: roughness (j+.5)/N, column i: N.V (i+.5)/N
    irradiance: np.ndarray            # 6 x F x F x 3 float32, E / pi (core.irradiance_cube)
    timings: dict = field(default_factory=dict)   # seconds per stage and "total"
    method: str = "ggx"


def roughness_to_lod(roughness, levels: int, method: str = "ggx"):
    """The cube LOD the renderer samples for a roughness, for either method: roughness x
    (levels - 1) (ggx: mip m was filtered for roughness m / (levels - 1); paper: its rule)."""
    if method not in METHODS:
        raise ValueError(f"unknown prefilter method {method!r}; one of {METHODS}")
    return np.clip(roughness, 0.0, 1.0) * (levels - 1)


def prefilter(pixels: np.ndarray, face_size: int = DEFAULT_FACE_SIZE, method: str = "ggx",
              levels: int | None = None) -> EnvironmentArrays:
    """Bake a linear H x W x 3 panorama into the specular mip chain, SH and BRDF LUT (see the
    module docstring for the methods and their LOD mapping)."""
    if method not in METHODS:
        raise ValueError(f"unknown prefilter method {method!r}; one of {METHODS}")
    check_face_size(face_size)
    levels = default_levels(face_size) if levels is None else int(levels)
    if not 1 <= levels <= int(math.log2(face_size)) + 1:
        raise ValueError(f"levels must be in 1..{int(math.log2(face_size)) + 1}, got {levels}")
    pixels = np.ascontiguousarray(pixels, dtype=np.float32)
    if pixels.ndim != 3 or pixels.shape[2] != 3 or pixels.shape[0] < 2 or pixels.shape[1] < 4:
        raise ValueError(f"panorama must be H x W x 3, got {pixels.shape}")
    if (pixels == pixels[0, 0]).all():
        return _uniform(pixels, face_size, levels, method)
    return _filtered(pixels, face_size, levels, method)


def _filtered(pixels: np.ndarray, face_size: int, levels: int, method: str) -> EnvironmentArrays:
    """The GL passes (the module docstring)."""
    from gl import context as gl  # EGL and moderngl: not for processes that only load bakes

    timings: dict[str, float] = {}
    t_start = t = time.perf_counter()
    ctx = gl.get_context()
    pixels = _fit_texture(pixels, ctx.info["GL_MAX_TEXTURE_SIZE"])
    timings["context"] = time.perf_counter() - t
    t = time.perf_counter()
    base_tex = _equirect_to_cube(ctx, gl, pixels, face_size)
    specular = [_read_atlas(base_tex, face_size)]
    timings["cube"] = time.perf_counter() - t
    t = time.perf_counter()
    if method == "ggx":
        specular += _ggx_mips(ctx, gl, specular[0], levels)
    else:
        specular += _paper_mips(ctx, gl, base_tex, face_size, levels)
    base_tex.release()
    timings["specular"] = time.perf_counter() - t
    arrays = _with_sh_and_lut(specular, pixels, timings, t_start, method)
    log.info("prefilter %s %dx%d -> %d px x %d mips in %.3f s", method, pixels.shape[1],
             pixels.shape[0], face_size, levels, timings["total"])
    return arrays


def _uniform(pixels: np.ndarray, face_size: int, levels: int, method: str) -> EnvironmentArrays:
    """A constant panorama's arrays without GL: any normalized filter of a constant (either
    method's mips, the cube resampling) is that constant, which the GL passes reproduce only to
    float rounding (a relative 1e-6); SH and LUT as for any panorama."""
    t_start = time.perf_counter()
    value = pixels[0, 0]
    specular = [np.broadcast_to(value, (6, face_size >> m, face_size >> m, 3)).copy() for m in range(levels)]
    timings = {"specular": time.perf_counter() - t_start}
    arrays = _with_sh_and_lut(specular, pixels, timings, t_start, method,
                              np.broadcast_to(value, (6, IRRADIANCE_FACE, IRRADIANCE_FACE, 3)).copy())
    log.info("prefilter: uniform panorama %s -> %d px x %d mips in %.3f s", value.tolist(), face_size,
             levels, timings["total"])
    return arrays


def _with_sh_and_lut(specular: list[np.ndarray], pixels: np.ndarray, timings: dict[str, float],
                     t_start: float, method: str, irradiance: np.ndarray | None = None) -> EnvironmentArrays:
    """The specular mips completed with the irradiance cube (integrated from mip 0 unless
    given), the panorama's SH and the BRDF LUT, every panorama's alike; `timings` gains their
    phases and the total since `t_start`."""
    t = time.perf_counter()
    if irradiance is None:
        irradiance = irradiance_cube(specular[0])
    timings["irradiance"] = time.perf_counter() - t
    t = time.perf_counter()
    sh = project_sh(pixels)
    timings["sh"] = time.perf_counter() - t
    t = time.perf_counter()
    lut = brdf_lut()
    timings["brdf_lut"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_start
    return EnvironmentArrays(specular=specular, irradiance_sh=sh, brdf_lut=lut, irradiance=irradiance,
                             timings=timings, method=method)


# GL passes ------------------------------------------------------------------------------------

def _fit_texture(pixels: np.ndarray, max_size: int) -> np.ndarray:
    """Halve (2x2 box) a panorama wider or taller than the GL texture limit."""
    while max(pixels.shape[:2]) > max_size:
        h, w = pixels.shape[0] // 2 * 2, pixels.shape[1] // 2 * 2
        pixels = pixels[:h, :w].reshape(h // 2, 2, w // 2, 2, 3).mean(axis=(1, 3), dtype=np.float32)
        log.info("panorama halved to %dx%d to fit the GL texture limit", w // 2, h // 2)
    return pixels


def _atlas(ctx, size: int):
    tex = ctx.texture((size, 6 * size), 4, dtype="f4")
    return tex, ctx.framebuffer(color_attachments=[tex])


def _draw(ctx, gl, fbo, prog) -> None:
    fbo.use()
    ctx.disable(ctx.BLEND | ctx.DEPTH_TEST | ctx.CULL_FACE)  # state the renderer may have left on
    fbo.viewport = (0, 0) + fbo.size
    gl.fullscreen_vao(prog).render(vertices=3)


def _read_atlas(tex, size: int) -> np.ndarray:
    data = np.frombuffer(tex.read(), dtype=np.float32)
    return data.reshape(6, size, size, 4)[..., :3].copy()


def _equirect_to_cube(ctx, gl, pixels: np.ndarray, size: int):
    """Cube faces (as an atlas texture) resampled bilinearly from the panorama, supersampled
    when the faces are coarser than the panorama (its width / 4 px per 90 degrees)."""
    h, w = pixels.shape[:2]
    supersample = int(min(8, max(1, math.ceil(w / 4 / size))))
    pano = ctx.texture((w, h), 3, pixels.tobytes(), dtype="f4")
    pano.repeat_x, pano.repeat_y = True, False
    pano.filter = (ctx.LINEAR, ctx.LINEAR)
    tex, fbo = _atlas(ctx, size)
    prog = gl.program("screen_triangle.vert", "equirect_to_cube.frag", {"SUPERSAMPLE": supersample})
    prog["u_size"].value = size
    prog["u_panorama"].value = 0
    pano.use(0)
    _draw(ctx, gl, fbo, prog)
    fbo.release()
    pano.release()
    return tex


def _ggx_mips(ctx, gl, base: np.ndarray, levels: int) -> list[np.ndarray]:
    size = base.shape[1]
    # Texels carry (L w, w), w their solid angle, so box-filtered mips and trilinear lookups
    # average radiance by solid angle: a plain box average over-weights the small corner texels
    # (a sun near a cube corner came out up to 15% too bright at high roughness).
    c = (np.arange(size) + 0.5) / size * 2 - 1
    w = (1 + c[:, None] ** 2 + c[None, :] ** 2) ** -1.5
    weighted = np.concatenate([base * w[None, :, :, None], np.broadcast_to(w[None, :, :, None], (6, size, size, 1))], axis=-1)
    src = ctx.texture_cube((size, size), 4, weighted.astype(np.float32).tobytes(), dtype="f4")
    src.build_mipmaps()
    src.filter = (ctx.LINEAR_MIPMAP_NEAREST, ctx.LINEAR)  # whole LODs: bilinear, no blend of two mips (2-3x faster on llvmpipe)
    max_lod = int(math.log2(size))
    prog = gl.program("screen_triangle.vert", "prefilter_ggx.frag", {"MAX_SAMPLES": GGX_MAX_SAMPLES})
    prog["u_source"].value = 0
    src.use(0)
    mips = []
    for m in range(1, levels):
        s = size >> m
        count = ggx_sample_count(m)
        samples = ggx_samples(m / (levels - 1), count, size, max_lod)
        tex, fbo = _atlas(ctx, s)
        prog["u_size"].value = s
        prog["u_count"].value = len(samples)
        prog["u_samples"].write(np.pad(samples, ((0, GGX_MAX_SAMPLES - len(samples)), (0, 0)))
                                .astype(np.float32).tobytes())
        _draw(ctx, gl, fbo, prog)
        mips.append(_read_atlas(tex, s))
        fbo.release()
        tex.release()
    src.release()
    return mips


def _paper_mips(ctx, gl, base_tex, size: int, levels: int) -> list[np.ndarray]:
    prog = gl.program("screen_triangle.vert", "downsample_paper.frag")
    prog["u_previous"].value = 0
    mips, previous = [], base_tex
    for m in range(1, levels):
        s = size >> m
        tex, fbo = _atlas(ctx, s)
        previous.use(0)
        prog["u_size"].value = s
        _draw(ctx, gl, fbo, prog)
        fbo.release()
        mips.append(_read_atlas(tex, s))
        if previous is not base_tex:
            previous.release()
        previous = tex
    if previous is not base_tex:
        previous.release()
    return mips


def ggx_sample_count(mip: int) -> int:
    """Samples per texel for a mip: mip-filtered sampling makes a few dozen enough for the
    narrow lobes; wide lobes get more, which is cheap because their mips are small."""
    return min(GGX_MAX_SAMPLES, GGX_SAMPLES << max(0, mip - 1))


def ggx_samples(roughness: float, count: int, source_size: int, max_lod: float) -> np.ndarray:
    """The GGX sample set for N = V (one per mip, shared by every texel): K x 4 rows of the
    light direction in the lobe's frame (z = N) and the source LOD to read it at. Samples below
    the horizon are dropped (their weight N.L would be 0)."""
    alpha = max(roughness * roughness, 1e-6)
    light, cos_h = ggx_reflections(alpha, count)
    d = alpha * alpha / (np.pi * (cos_h * cos_h * (alpha * alpha - 1) + 1) ** 2)
    pdf = d / 4  # D * N.H / (4 V.H) with N = V
    texel_solid_angle = 4 * np.pi / (6 * source_size * source_size)
    # +1: Karis's bias toward a blurrier mip, which hides the sample pattern
    lod = np.round(np.clip(0.5 * np.log2(1 / (count * pdf * texel_solid_angle)) + 1, 0, max_lod))
    keep = light[:, 2] > 1e-4
    return np.concatenate([light, lod[:, None]], axis=1)[keep]


DATA = Path(__file__).resolve().parent.parent / "data"


def shipped_lut_path(size: int = LUT_SIZE, samples: int = LUT_SAMPLES) -> Path:
    """Where the package ships the LUT for these constants: it depends on nothing but them
    and the shader, so a cold process loads it instead of drawing it (`make brdf-lut` writes
    it; tests/test_environment.py checks it against a fresh drawing)."""
    return DATA / f"brdf_lut.v{PREFILTER_VERSION}.{size}x{samples}.npy"


@lru_cache(maxsize=4)
def _brdf_lut_cached(size: int, samples: int) -> np.ndarray:
    shipped = shipped_lut_path(size, samples)
    lut = np.load(shipped) if shipped.is_file() else draw_brdf_lut(size, samples)
    lut.flags.writeable = False
    return lut


def draw_brdf_lut(size: int = LUT_SIZE, samples: int = LUT_SAMPLES) -> np.ndarray:
    """The LUT drawn now by shaders/brdf_lut.frag (what the shipped file must equal)."""
    from gl import context as gl  # as in prefilter_panorama
    ctx = gl.get_context()
    tex = ctx.texture((size, size), 4, dtype="f4")
    fbo = ctx.framebuffer(color_attachments=[tex])
    prog = gl.program("screen_triangle.vert", "brdf_lut.frag", {"SAMPLES": samples})
    prog["u_size"].value = size  # type: ignore[union-attr]  # a uniform
    _draw(ctx, gl, fbo, prog)
    lut = np.frombuffer(tex.read(), dtype=np.float32).reshape(size, size, 4)[..., :3].copy()
    fbo.release()
    tex.release()
    return lut


def brdf_lut(size: int = LUT_SIZE, samples: int = LUT_SAMPLES) -> np.ndarray:
    """The split-sum LUT (size x size x 3; row j: roughness (j+.5)/size, column i: N.V
    (i+.5)/size; values (scale, bias) for F0 and the sheen lobe's directional albedo at sheen
    roughness (j+.5)/size), drawn by shaders/brdf_lut.frag: loaded from the package's data for
    the default constants, else drawn once per process."""
    return _brdf_lut_cached(int(size), int(samples)).copy()


# Spherical harmonics --------------------------------------------------------------------------

def project_sh(pixels: np.ndarray) -> np.ndarray:
    """9 x 3 radiance SH coefficients of an H x W x 3 panorama. Each pixel is a constant-radiance
    cell and every basis function is integrated exactly over it (all are sums of f(theta) g(phi)
    with closed-form integrals), so a constant environment projects exactly onto Y00."""
    h, w = pixels.shape[:2]
    mu = np.cos(np.linspace(0.0, np.pi, h + 1))          # cos(theta) at row edges, decreasing
    sin = np.sqrt(np.maximum(1 - mu * mu, 0))
    rows = {  # antiderivatives in mu = cos(theta) of f(theta) (sin(theta) d(theta) = -d(mu))
        "1": mu, "c": mu * mu / 2, "s": (mu * sin + np.arcsin(mu)) / 2,
        "sc": -sin ** 3 / 3, "ss": mu - mu ** 3 / 3, "cc": mu ** 3 / 3,
    }
    rows = {k: v[:-1] - v[1:] for k, v in rows.items()}
    phi = (np.arange(w + 1) / w - 0.5) * 2 * np.pi       # x = -sin(phi) sin(theta), z = cos(phi) sin(theta)
    col_keys = ("1", "cos", "sin", "cos2", "sin2", "sincos")
    cols = np.stack([phi, np.sin(phi), -np.cos(phi), phi / 2 + np.sin(2 * phi) / 4,
                     phi / 2 - np.sin(2 * phi) / 4, np.sin(phi) ** 2 / 2], axis=-1)
    cols = cols[1:] - cols[:-1]                           # W x 6
    per_row = np.tensordot(pixels.astype(np.float64), cols, axes=([1], [0]))  # H x 3 x 6
    terms = [  # (constant, [(factor, row function, column function)]) per basis function
        (SH_C0, [(1, "1", "1")]),
        (SH_C1, [(1, "c", "1")]),                        # y
        (SH_C1, [(1, "s", "cos")]),                      # z
        (SH_C1, [(-1, "s", "sin")]),                     # x
        (SH_C2, [(-1, "sc", "sin")]),                    # xy
        (SH_C2, [(1, "sc", "cos")]),                     # yz
        (SH_C3, [(3, "ss", "cos2"), (-1, "1", "1")]),    # 3z^2 - 1
        (SH_C2, [(-1, "ss", "sincos")]),                 # xz
        (SH_C4, [(1, "ss", "sin2"), (-1, "cc", "1")]),   # x^2 - y^2
    ]
    sh = np.zeros((9, 3))
    for k, (c, parts) in enumerate(terms):
        for factor, rf, cf in parts:
            sh[k] += c * factor * (rows[rf] @ per_row[:, :, col_keys.index(cf)])
    return sh.astype(np.float32)


if __name__ == "__main__":  # `make brdf-lut`: (re)write the shipped LUT for the current constants
    for old in DATA.glob("brdf_lut.*.npy"):
        old.unlink()
    np.save(shipped_lut_path(), draw_brdf_lut())
    print(f"wrote {shipped_lut_path()}")
