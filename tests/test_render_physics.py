"""The renderer against physics: white furnace, mirror sphere, Lambert sphere, and sanity.

Environments here are built by hand (constant or a smooth function of direction) with a BRDF
LUT integrated independently in numpy, so a failure points at the renderer, not the bake.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import trimesh
from lobes_numpy import sheen_albedo

from core.baked import BakedAsset, BakedEnvironment, BakedMesh
from core.cubemap import face_directions, sample_cube
from core.irradiance import irradiance_cube
from core.options import MaterialOverride, RenderOptions
from core.scene import Material
from renderer.raster import gpu
from renderer.raster.render import UnsupportedMethod, render
from renderer.view.camera import frame_bounds
from renderer.view.framing import asset_camera

SIZE = 128


# --- hand-built inputs ----------------------------------------------------------------------

def _van_der_corput(n: int) -> np.ndarray:
    i = np.arange(n, dtype=np.uint64)
    out = np.zeros(n)
    f, k = 0.5, i.copy()
    while np.any(k):
        out += f * (k & 1)
        k >>= 1
        f /= 2
    return out


def g_smith(nv, nl, alpha):
    """Height-correlated Smith GGX, the renderer's G (shaders/brdf.glsl, glTF's V_GGX x 4 N.L N.V)."""
    a2 = alpha * alpha
    return 2 * nv * nl / (nl * np.sqrt(nv * nv * (1 - a2) + a2) + nv * np.sqrt(nl * nl * (1 - a2) + a2))


def numpy_brdf_lut(n: int = 32, samples: int = 1024) -> np.ndarray:
    """Split-sum LUT [roughness row, N.V column] -> (scale, bias), GGX importance sampling,
    and the sheen albedo (tests/lobes_numpy.py) as the third channel."""
    nv = (np.arange(n) + 0.5) / n
    xi1 = (np.arange(samples) + 0.5) / samples
    phi = 2 * np.pi * _van_der_corput(samples)
    lut = np.zeros((n, n, 3), np.float32)
    lut[..., 2] = sheen_albedo(n)
    for j, r in enumerate((np.arange(n) + 0.5) / n):
        a = r * r
        cos_h = np.sqrt((1 - xi1) / (1 + (a * a - 1) * xi1))
        sin_h = np.sqrt(1 - cos_h ** 2)
        h = np.stack([sin_h * np.cos(phi), sin_h * np.sin(phi), cos_h], -1)  # samples x 3
        v = np.stack([np.sqrt(1 - nv ** 2), np.zeros(n), nv], -1)           # n x 3
        vh = np.clip(v @ h.T, 0, 1)                                          # n x samples
        nl = 2 * vh * cos_h[None] - nv[:, None]
        ok = nl > 0
        g = g_smith(nv[:, None], np.clip(nl, 1e-6, 1), a)
        g_vis = np.where(ok, g * vh / (cos_h[None] * nv[:, None]), 0)
        fc = (1 - vh) ** 5
        lut[j, :, 0] = ((1 - fc) * g_vis).mean(1)
        lut[j, :, 1] = (fc * g_vis).mean(1)
    return lut


_LUT = numpy_brdf_lut()


def make_env(radiance_fn, size: int = 32, key: str = "env") -> BakedEnvironment:
    """An environment whose every mip is `radiance_fn(directions)` (exact for a constant; for a
    smooth function only mip 0 is used by the tests), with SH projected numerically."""
    levels = int(math.log2(size)) + 1
    mips = [radiance_fn(face_directions(size >> m)).astype(np.float32) for m in range(levels)]
    d = face_directions(64).reshape(-1, 3)
    # Texel solid angles are not uniform; weight by them so a constant projects exactly.
    c = (np.arange(64) + 0.5) / 64 * 2 - 1
    w1 = (1 + c[:, None] ** 2 + c[None, :] ** 2) ** -1.5
    w = np.tile(w1.ravel(), 6)
    w *= 4 * np.pi / w.sum()
    x, y, z = d.T
    basis = np.stack([0.282095 * np.ones_like(x), 0.488603 * y, 0.488603 * z, 0.488603 * x,
                      1.092548 * x * y, 1.092548 * y * z, 0.315392 * (3 * z * z - 1),
                      1.092548 * x * z, 0.546274 * (x * x - y * y)], 1)
    sh = (basis * w[:, None]).T @ radiance_fn(d)
    return BakedEnvironment(key=key, name=key, specular=mips, irradiance_sh=sh.astype(np.float32),
                            brdf_lut=_LUT, irradiance=irradiance_cube(mips[0]))


def constant_env(value: float = 1.0) -> BakedEnvironment:
    return make_env(lambda d: np.full(d.shape[:-1] + (3,), value), key=f"constant-{value}")


def gradient_radiance(d: np.ndarray) -> np.ndarray:
    return np.stack([0.6 + 0.4 * d[..., 0], 0.6 + 0.4 * d[..., 1], 0.6 + 0.4 * d[..., 2]], -1)


def sphere_asset(metallic: float, roughness: float, base=(1.0, 1.0, 1.0, 1.0)) -> BakedAsset:
    ico = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    pos = np.asarray(ico.vertices, np.float32)
    mat = Material(name="m", base_color=tuple(base), metallic=metallic, roughness=roughness)
    mesh = BakedMesh(name="sphere", positions=pos, normals=pos / np.linalg.norm(pos, axis=1, keepdims=True),
                     indices=np.asarray(ico.faces, np.uint32), material=mat,
                     transforms=np.eye(4)[None])
    bounds = np.array([[-1.0, -1, -1], [1, 1, 1]])
    return BakedAsset(key=f"sphere-{metallic}-{roughness}-{base}", source="icosphere", format="test",
                      meshes=[mesh], textures=[], bounds=bounds)


def sphere_geometry(options: RenderOptions, radius: float = 1.0):
    """Analytic sphere hits per pixel: (mask, unit normal, view ray directions)."""
    cam = asset_camera(sphere_asset(0.0, 0.0), options)[0]  # the render's camera
    d = cam.ray_directions()
    o = cam.position
    b = d @ o
    disc = b * b - (o @ o - radius * radius)
    t = -b - np.sqrt(np.maximum(disc, 0))
    n = (o + t[..., None] * d) / radius
    return disc > 0, n, d


def interior(mask: np.ndarray, n: np.ndarray, d: np.ndarray, min_cos: float) -> np.ndarray:
    """Pixels well inside the silhouette (N.V above `min_cos`), away from MSAA edges."""
    return mask & (np.einsum("...i,...i->...", n, -d) > min_cos)


def opts(**kw) -> RenderOptions:
    return RenderOptions(**{"width": SIZE, "height": SIZE, "yaw": 0.0, "pitch": 0.0, "tonemap": "none",
                            "background": "env", "shadow": 0.0, **kw})


# --- tests ----------------------------------------------------------------------------------

def _albedo(g, roughness: float, n: int = 32, samples: int = 2048) -> np.ndarray:
    """Directional albedo of the GGX specular lobe (F = 1) per N.V = (i + 0.5) / n, with G = g(v, l, alpha)."""
    a = roughness ** 2
    nv = (np.arange(n) + 0.5) / n
    xi1 = (np.arange(samples) + 0.5) / samples
    phi = 2 * np.pi * _van_der_corput(samples)
    cos_h = np.sqrt((1 - xi1) / (1 + (a * a - 1) * xi1))
    sin_h = np.sqrt(1 - cos_h ** 2)
    h = np.stack([sin_h * np.cos(phi), sin_h * np.sin(phi), cos_h], -1)
    v = np.stack([np.sqrt(1 - nv ** 2), np.zeros(n), nv], -1)
    vh = np.clip(v @ h.T, 0, 1)
    nl = 2 * vh * cos_h[None] - nv[:, None]
    gv = g(nv[:, None], np.clip(nl, 1e-6, 1), a)
    return np.where(nl > 0, gv * vh / (cos_h[None] * nv[:, None]), 0).mean(1)


def test_lut_masks_with_height_correlated_smith_not_the_separable_product():
    """The renderer's LUT (drawn by shaders/brdf_lut.frag with brdf.glsl's G) integrates the
    height-correlated Smith G that glTF specifies: on rough lobes seen at low angles it keeps
    clearly more than the separable G1(v) G1(l) (Mitsuba's; the Schlick k = alpha / 2 fit used
    before equals it at roughness 1), the sheen a rough dielectric shows under a bright sky."""
    from pipeline.environment.prefilter import brdf_lut

    def separable(c, nl, a):
        def g1(x):
            return 2 * x / (x + np.sqrt(a * a + (1 - a * a) * x * x))
        return g1(c) * g1(nl)

    lut = brdf_lut(32)
    for j in (23, 31):  # roughness 0.73, 0.98
        r = (j + 0.5) / 32
        got = lut[j, :, 0] + lut[j, :, 1]
        correlated, product = _albedo(g_smith, r), _albedo(separable, r)
        low = slice(4, 10)  # N.V 0.14 .. 0.30 (the LUT's Hammersley set is within 0.016 of this)
        assert np.abs(got[low] - correlated[low]).max() < 0.02, (r, got[low], correlated[low])
        assert (got[low] - product[low]).min() > 0.02, (r, got[low], product[low])


@pytest.mark.parametrize("method", ["opaque", "single", "raytrace"])
@pytest.mark.parametrize("roughness", [0.0, 0.5, 1.0])
def test_white_furnace(roughness, method):
    """Metal, base colour 1, radiance-1 environment, in the opaque pass, the refraction pass
    (`single`: the same metal through refraction.frag's lobes) and the ray tracer. With the
    default multiple-scattering compensation every pixel with N.V > 0.2 reflects 1 within
    0.2% (it was 2% before compensation was the default). With `multiscatter=False` the
    split-sum reflects only the single-scattering albedo E_ss = A + B from the LUT (down to
    ~0.3-0.8 for rough metal): that is the energy lost, and the frame must match it. A constant
    environment hides the other split-sum loss (the lobe is prefiltered as if N = V = R, so
    rough reflections at grazing angles are too sharp and lose their stretch)."""
    env = constant_env(1.0)
    asset = sphere_asset(1.0, roughness)
    o = opts(method=method,
             override=MaterialOverride(transmission=1.0) if method == "single" else None)
    mask, n, d = sphere_geometry(o)
    sel = interior(mask, n, d, 0.2)
    ms = render(asset, env, o).linear
    assert np.abs(ms[..., :3][sel] - 1).max() < 0.002
    ss = render(asset, env, dataclasses.replace(o, multiscatter=False)).linear[..., :3]
    nv = np.einsum("...i,...i->...", n, -d)[sel]
    row = _LUT[min(int(roughness * 32), 31)]
    cols = np.clip(((nv * 32) - 0.5).astype(int), 0, 31)
    expected = (row[cols, 0] + row[cols, 1])[:, None]
    assert np.abs(ss[sel] - expected).mean() < 0.02
    assert ss[sel].max() <= 1.01


@pytest.mark.parametrize("method", ["opaque", "raytrace"])
@pytest.mark.parametrize("roughness", [0.0, 0.5, 1.0])
def test_white_furnace_dielectric(roughness, method):
    """A white dielectric (base colour 1, F0 0.04) in a radiance-1 environment: the specular
    layer and the diffuse base weighted by 1 - the lobe's directional albedo sum to 1 (within
    0.2%) at every N.V > 0.2, rough or smooth: the layering neither loses nor makes energy."""
    env = constant_env(1.0)
    o = opts(method=method)
    mask, n, d = sphere_geometry(o)
    sel = interior(mask, n, d, 0.2)
    got = render(sphere_asset(0.0, roughness), env, o).linear[..., :3][sel]
    assert np.abs(got - 1).max() < 0.002


def test_mirror_sphere_reflects_the_environment():
    """Roughness-0 metal: each pixel is the environment in the analytically reflected direction."""
    env = make_env(gradient_radiance, size=64, key="gradient")
    o = opts(yaw=30, pitch=20)
    frame = render(sphere_asset(1.0, 0.0), env, o)
    mask, n, d = sphere_geometry(o)
    sel = interior(mask, n, d, 0.3)
    r = d - 2 * np.einsum("...i,...i->...", d, n)[..., None] * n
    expected = sample_cube(env.specular[0], r)
    ab = _LUT[0, -1, :2]
    err = np.abs(frame.linear[..., :3][sel] - expected[sel] * (ab[0] + ab[1]))
    assert err.mean() < 0.01 and np.percentile(err, 99) < 0.03


def test_mirror_background_matches_camera_rays():
    """The environment background is the environment seen along Camera.ray_directions."""
    env = make_env(gradient_radiance, size=64, key="gradient")
    o = opts(yaw=-50, pitch=10)
    frame = render(sphere_asset(1.0, 0.0), env, o)
    mask, n, d = sphere_geometry(o, radius=1.05)  # leave the anti-aliased silhouette out
    expected = sample_cube(env.specular[0], d)
    bg = ~mask
    err = np.abs(frame.linear[..., :3][bg] - expected[bg])
    assert err.mean() < 0.005 and err.max() < 0.03


@pytest.mark.parametrize("albedo", [0.2, 0.8])
def test_lambert_sphere_under_constant_environment(albedo):
    """Dielectric, roughness 1, constant radiance L: diffuse = albedo x L x (1 - E_spec),
    plus the specular E_spec x L (E_spec = 0.04 A + B from the LUT); at normal incidence
    this is within 2% of albedo x L for the dielectric F0 of 0.04."""
    L = 0.7
    env = constant_env(L)
    frame = render(sphere_asset(0.0, 1.0, (albedo, albedo, albedo, 1.0)), env, opts())
    mask, n, d = sphere_geometry(opts())
    sel = interior(mask, n, d, 0.95)
    a, b = _LUT[31, 31, :2]
    e_spec = 0.04 * a + b
    expected = L * (albedo * (1 - e_spec) + e_spec)
    got = frame.linear[..., :3][sel]
    assert np.abs(got - expected).max() < 0.01 * L
    assert abs(got.mean() / (albedo * L) - 1) < 0.2 * (0.04 / albedo) + 0.02


def test_frame_outputs_and_background_modes():
    env = constant_env(1.0)
    asset = sphere_asset(0.0, 0.5, (0.8, 0.2, 0.2, 1.0))
    f = render(asset, env, opts(background="transparent", tonemap="neutral"))
    assert f.linear.shape == (SIZE, SIZE, 4) and f.linear.dtype == np.float32
    assert f.rgba8.shape == (SIZE, SIZE, 4) and f.rgba8.dtype == np.uint8
    assert f.rgba8[0, 0, 3] == 0 and f.rgba8[SIZE // 2, SIZE // 2, 3] == 255
    assert f.rgba8[SIZE // 2, SIZE // 2, 0] > f.rgba8[SIZE // 2, SIZE // 2, 1]
    assert np.isfinite(f.linear).all()
    g = render(asset, env, opts(background="#3366cc", tonemap="neutral"))
    assert tuple(g.rgba8[0, 0]) == (0x33, 0x66, 0xCC, 255)
    assert g.encode("png")[:8] == b"\x89PNG\r\n\x1a\n"
    assert g.encode("jpeg")[:2] == b"\xff\xd8"
    assert g.encode("webp")[8:12] == b"WEBP"


def test_exposure_scales_linear_input_to_tonemapping():
    env = constant_env(0.25)
    asset = sphere_asset(0.0, 1.0, (0.5, 0.5, 0.5, 1.0))
    f0 = render(asset, env, opts(tonemap="none"))
    f1 = render(asset, env, opts(tonemap="none", exposure=1.0))
    c = SIZE // 2
    assert np.allclose(f0.linear[c, c], f1.linear[c, c])  # linear frame is radiance, unscaled
    assert f1.rgba8[c, c, 0] > f0.rgba8[c, c, 0] + 20


def test_extreme_exposure_saturates_instead_of_overflowing():
    # The numpy tone mapper (ray tracer, reference) clamps the exposure as the GPU pass does:
    # 2**5000 used to raise OverflowError out of `render --method raytrace --exposure 5000`.
    from renderer.frame import tonemap_srgb8
    linear = np.full((2, 2, 4), 0.5, np.float32)
    assert np.all(tonemap_srgb8(linear, "none", 5000.0)[..., :3] == 255)
    assert np.all(tonemap_srgb8(linear, "none", -5000.0)[..., :3] == 0)


def test_override_makes_any_mesh_steel():
    env = make_env(gradient_radiance, size=64, key="gradient")
    asset = sphere_asset(0.0, 1.0, (0.8, 0.1, 0.1, 1.0))
    steel = MaterialOverride(base_color=(0.9, 0.9, 0.9), metallic=1.0, roughness=0.0)
    f = render(asset, env, opts(override=steel))
    mirror = render(sphere_asset(1.0, 0.0, (0.9, 0.9, 0.9, 1.0)), env, opts())
    assert np.abs(f.linear - mirror.linear).max() < 1e-3


def test_second_thumbnail_uploads_nothing():
    env = constant_env(1.0)
    asset = sphere_asset(1.0, 0.3)
    render(asset, env, opts())
    before = dict(gpu.stats)
    f = render(asset, env, opts(width=64, height=48, yaw=90))
    assert gpu.stats["asset_uploads"] == before["asset_uploads"]
    assert gpu.stats["environment_uploads"] == before["environment_uploads"]
    assert f.plan["uploaded"] == {"asset_uploads": 0, "environment_uploads": 0}
    assert f.rgba8.shape == (48, 64, 4)


def test_far_camera_keeps_a_finite_projection():
    # distance +- radius rounds to one value this far out: near == far divided by zero.
    cam = frame_bounds(np.array([[-1e-6] * 3, [1e-6] * 3]), 32, 32, distance=1e12)
    assert cam.far > cam.near
    assert np.all(np.isfinite(cam.projection_matrix()))
    with pytest.raises(ValueError, match="distance"):
        render(sphere_asset(0.0, 0.5), constant_env(0.5), opts(distance=1e17))


def test_unavailable_and_bad_options_are_rejected_clearly():
    from renderer.methods.registry import METHODS
    env = constant_env(1.0)
    asset = sphere_asset(1.0, 0.3)
    if "wyman" not in METHODS:
        with pytest.raises(UnsupportedMethod, match="wyman"):
            render(asset, env, opts(method="wyman"))
    with pytest.raises(ValueError, match="method"):  # refused by the schema, before any render
        render(asset, env, opts(method="magic"))
    with pytest.raises(ValueError, match="background"):
        render(asset, env, opts(background="#12345"))
    with pytest.raises(ValueError, match="width"):
        render(asset, env, opts(width=0))
