"""The path-tracing integrator of the ray tracer (renderer.methods.path_trace): white furnaces
per lobe, the environment sampler's pdf, the tracer against the raster on a diffuse textured
quad, the time budget, noise-target stopping, determinism and finiteness at TIR and grazing."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_render_physics import constant_env, make_env, sphere_asset

from core.baked import BakedAsset, BakedMesh
from core.cubemap import face_directions, sample_cube
from core.options import RenderOptions
from core.scene import NEAREST, Material, Sampler, Texture, TextureRef
from renderer import render
from renderer.methods import path_trace
from renderer.methods.raytrace import render_raytrace


def _sphere(label: str, metallic: float = 0.0, roughness: float = 0.5, **mat) -> BakedAsset:
    a = sphere_asset(metallic, roughness)
    m = dataclasses.replace(a.meshes[0].material, **mat)
    return dataclasses.replace(a, key=a.key + label, meshes=[dataclasses.replace(a.meshes[0], material=m)])


def _path(samples: int = 32, size: int = 40, **kw) -> RenderOptions:
    return RenderOptions(width=size, height=size, background="env", tonemap="none",
                         integrator="path", samples=samples, noise=0.0, bounces=16, **kw)


# (material, lower, upper) of the mean over the sphere's centre under a white sky of 1.
# A white non-absorbing lobe returns 1: Lambert (F0 = 0 at IOR 1), smooth mirror, smooth glass
# and the glTF fresnel_mix of diffuse under GGX. Single-scattering GGX loses what its
# microfacets mask (no multiple-scattering paths between facets): rough metal and rough glass
# would sit below 1; with multiscatter (the default) the metal's lobe is compensated to 1,
# rough glass is not (it loses what its microfacets mask, as Mitsuba's roughdielectric). The tolerance covers 32 samples' noise over the centre's pixels.
FURNACE = [
    ("lambert", dict(ior=1.0, roughness=1.0), 0.98, 1.02),
    ("plastic", dict(ior=1.5, roughness=0.5), 0.97, 1.02),
    ("plastic_smooth", dict(ior=1.5, roughness=0.05), 0.97, 1.02),
    ("mirror", dict(metallic=1.0, roughness=0.0), 0.99, 1.01),
    ("rough_metal", dict(metallic=1.0, roughness=0.5), 0.98, 1.02),
    ("glass", dict(transmission=1.0, roughness=0.0), 0.99, 1.01),
    ("rough_glass", dict(transmission=1.0, roughness=0.3), 0.95, 1.01),
]


@pytest.mark.parametrize("label,mat,lo,hi", FURNACE, ids=[f[0] for f in FURNACE])
def test_white_furnace_per_lobe(label, mat, lo, hi):
    frame = render_raytrace(_sphere(label, **mat), constant_env(1.0), _path())
    rgb = frame.linear[..., :3]
    assert np.isfinite(rgb).all() and rgb.min() >= 0
    centre = rgb[12:28, 12:28].mean()
    assert lo <= centre <= hi, (label, centre)


def test_environment_sampler_pdf_integrates_to_one_and_is_unbiased():
    rng = np.random.default_rng(3)
    sun = np.array([0.3, 0.8, 0.52]) / np.linalg.norm([0.3, 0.8, 0.52])
    # a smooth sky with a bright lobe (as a sun), bilinear between texels as it is read
    faces = np.exp(30 * (face_directions(32) @ sun - 1))[..., None] * [1.0, 0.9, 0.8] + 0.05
    es = path_trace.EnvSampler(faces, None)
    u = rng.random((3, 200_000))
    d = es.sample(*u)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    z, phi = 1 - 2 * rng.random(400_000), 2 * np.pi * rng.random(400_000)
    r = np.sqrt(1 - z * z)
    uniform = np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)
    assert abs(es.pdf(uniform).mean() * 4 * np.pi - 1.0) < 0.01
    lum = sample_cube(faces, d) @ [0.2126, 0.7152, 0.0722]
    lum_u = sample_cube(faces, uniform) @ [0.2126, 0.7152, 0.0722]
    importance = (lum / es.pdf(d)).mean()
    assert abs(importance / (lum_u.mean() * 4 * np.pi) - 1.0) < 0.01
    # importance sampling beats uniform sampling by far on a peaked sky
    assert (lum / es.pdf(d)).std() < 0.2 * (lum_u * 4 * np.pi).std()


def _diffuse_quad() -> BakedAsset:
    rng = np.random.default_rng(11)
    img = rng.integers(40, 256, (8, 8, 4), dtype=np.uint8)
    img[..., 3] = 255
    pos = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32)
    # IOR 1: no specular, so both integrate the same Lambert lobe
    mat = Material(base_color_texture=TextureRef(0), metallic=0.0, roughness=1.0, ior=1.0)
    mesh = BakedMesh("quad", pos, np.tile([0, 0, 1], (4, 1)).astype(np.float32),
                     np.array([[0, 1, 2], [0, 2, 3]], np.uint32), mat, np.eye(4)[None], uv0=uv)
    tex = Texture("random", img, Sampler(mag_filter=NEAREST, min_filter=NEAREST))
    return BakedAsset(key="diffuse-quad-path", source="quad", format="test", meshes=[mesh],
                      textures=[tex], bounds=np.array([[-1.0, -1, 0], [1, 1, 0]]))


def test_path_tracer_matches_the_raster_on_a_diffuse_textured_quad():
    asset = _diffuse_quad()
    env = constant_env(1.0)  # irradiance pi under any normal: radiance = albedo in both
    o = RenderOptions(width=48, height=48, tonemap="none", background="transparent", yaw=0.0,
                      pitch=0.0, shadow=0.0, integrator="path", samples=16, noise=0.0)
    raster = render(asset, env, dataclasses.replace(o, method="opaque")).linear
    traced = render(asset, env, dataclasses.replace(o, method="raytrace")).linear
    both = (raster[..., 3] > 0.99) & (traced[..., 3] > 0.99)
    assert both.sum() > 0.3 * both.size
    a, b = raster[both, :3].mean(), traced[both, :3].mean()
    assert abs(b / a - 1) < 0.01, (a, b)
    # same texels: per-pixel colours follow the raster's
    assert np.corrcoef(raster[both, :3].ravel(), traced[both, :3].ravel())[0, 1] > 0.9


def test_budget_stops_within_one_pass():
    asset = _sphere("budget", roughness=0.4, ior=1.5)
    # the budget counts from the frame's start: a first frame's kernel loading is not the point
    render_raytrace(asset, constant_env(1.0), _path(samples=1, size=8))
    o = _path(samples=4096, size=48, budget_ms=1500.0)
    frame = render_raytrace(asset, constant_env(1.0), o)
    plan = frame.plan
    assert plan["stop"] == "budget", plan
    assert 1 < plan["passes"] < 4096
    # granularity: the frame up to its last pass (scene build included) overruns the budget by
    # at most the longest pass (or, where the work before the passes spent it all, that work
    # and the one pass that always runs: a first frame's compiling)
    before = plan["elapsed_ms"] - plan["path_ms"]
    assert plan["elapsed_ms"] <= max(1500.0, before) + plan["pass_ms_max"], plan


def test_budget_is_shared_by_a_dispersive_frames_channels():
    """A dispersive material traces one path pass per RGB channel; the three share the budget
    (each once took the whole budget: three times over)."""
    asset = _sphere("budget-dispersion", roughness=0.0, transmission=1.0, ior=1.5, dispersion=5.0)
    render_raytrace(asset, constant_env(1.0), _path(samples=1, size=8))  # kernels loaded
    o = _path(samples=4096, size=16, budget_ms=3000.0)
    plan = render_raytrace(asset, constant_env(1.0), o).plan
    got = {k: plan[k] for k in ("stop", "passes", "elapsed_ms", "path_ms", "pass_ms_max")}
    assert plan["stop"] == "budget", got
    assert plan["passes"] > 3, got  # more than the first pass each channel always runs
    # each channel stops by its share of what is left (a channel's first pass always runs)
    before = plan["elapsed_ms"] - plan["path_ms"]
    assert plan["elapsed_ms"] <= max(3000.0, before) + plan["pass_ms_max"], got


def test_noise_target_stops_early_and_converged_pixels_rest():
    o = dataclasses.replace(_path(samples=256, size=32), noise=0.05)
    frame = render_raytrace(_sphere("noise", ior=1.0, roughness=1.0), constant_env(1.0), o)
    plan = frame.plan
    assert plan["stop"] == "noise", plan
    assert plan["passes"] < 256
    assert plan["samples_mean"] <= plan["passes"]


def test_noise_target_spends_passes_where_the_noise_is():
    """The same noise target stops a Lambert sphere under a uniform sky (flat light) early and
    keeps rough glass under a sun going: passes follow each pixel's own variance."""
    env = make_env(lambda d: np.where(d[..., 1:2] > 0.95, 40.0, 0.5) * np.ones(3), key="sun-cap")
    o = dataclasses.replace(_path(samples=256, size=32), noise=0.05)
    card = render_raytrace(_sphere("noise-card", ior=1.0, roughness=1.0), constant_env(1.0), o).plan
    glass = render_raytrace(_sphere("noise-glass", roughness=0.3, transmission=1.0, ior=1.5), env, o).plan
    # measured: the card stops by noise after 65 passes, the glass's sun pixels run all 256
    assert card["stop"] == "noise", card
    assert glass["passes"] > 2 * card["passes"], (card, glass)


def test_firefly_clamp_leaves_direct_light_alone(monkeypatch):
    """path_trace.FIREFLY clamps only what a path adds after its first rough vertex: a convex
    Lambert sphere under a sun of 5000 (BSDF rays that meet the sun carry ~4000, far above the
    clamp) sees direct light alone, so its frame is the same without the clamp."""
    env = make_env(lambda d: np.where(d[..., 1:2] > 0.995, 5000.0, 0.2) * np.ones(3), key="clamp-sun")
    asset = _sphere("clamp", ior=1.0, roughness=1.0)
    o = _path(samples=4, size=24)
    clamped = render_raytrace(asset, env, o).linear
    monkeypatch.setattr(path_trace, "FIREFLY", 1e30)
    assert np.array_equal(render_raytrace(asset, env, o).linear, clamped)


def test_deterministic():
    env = make_env(lambda d: np.stack([1 + d[..., 0], 1 + d[..., 1], 1 + d[..., 2]], -1) * 0.5, key="tilt")
    asset = _sphere("det", ior=1.5, roughness=0.3)
    a = render_raytrace(asset, env, _path(samples=4, size=24)).linear
    b = render_raytrace(asset, env, _path(samples=4, size=24)).linear
    assert np.array_equal(a, b)


@pytest.mark.parametrize("ior,distance", [(2.4, None), (2.4, 0.9)], ids=["tir_outside", "camera_inside"])
def test_finite_at_total_internal_reflection_and_grazing(ior, distance):
    """A dense glass sphere under a sun disc of 50 (grazing rays at its silhouette) and a
    camera inside the glass."""
    env = make_env(lambda d: np.where(d[..., 1:2] > 0.9, 50.0, 0.3) * np.ones(3), key="sun-disc")
    asset = _sphere(f"tir{ior}", transmission=1.0, roughness=0.0, ior=ior)
    extra = {} if distance is None else dict(distance=distance)
    frame = render_raytrace(asset, env, _path(samples=8, size=32, **extra))
    assert np.isfinite(frame.linear).all() and frame.linear.min() >= 0
    assert frame.plan["nonfinite"] == 0
    assert frame.plan["passes"] == 8


def test_compiled_sampler_matches_its_numpy_twin():
    """trace_kernel.sobol_pair (the compiled per-pass uniforms) draws the very numbers of its
    numpy twin (trace_scene.sobol_samples) for every pass and stream, deep ones included."""
    sampler = path_trace._Sampler()
    pix = np.arange(0, 50_000, 7)
    for s, dim in ((0, path_trace._dim(path_trace.K_JITTER, 0)), (3, path_trace._dim(path_trace.K_LOBE, 11)),
                   (63, path_trace._dim(path_trace.K_LIGHT, 64, 205)), (1000, 5)):
        for got, want in zip(sampler(pix, s, dim), sampler.numpy(pix, s, dim)):
            assert np.array_equal(got, want)
