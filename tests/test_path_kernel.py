"""The path tracer's compiled BSDF (renderer.methods.path_kernel) against its numpy twin
(renderer.methods.path_bsdf.Bsdf): the same values per hit for every lobe, and the same frames."""
from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from test_raytrace_path import _path, _sphere
from test_render_physics import make_env

from renderer.methods import path_bsdf, path_kernel, path_trace
from renderer.methods.raytrace import render_raytrace

N = 6000


def _unit(a):
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def _hits(rng):
    """Random hits where every lobe (coat, sheen, anisotropic metal, plastic with specular,
    diffuse transmission, iridescence, glass) is on for a share of the rows, off elsewhere."""
    ng = _unit(rng.normal(size=(N, 3)))
    ns = _unit(ng + 0.3 * rng.normal(size=(N, 3)))
    wo = _unit(ng + rng.normal(size=(N, 3)))
    wo[np.einsum("ij,ij->i", wo, ng) < 0] *= -1
    bad = np.einsum("ij,ij->i", wo, ns) < 0
    ns[bad] = ng[bad]

    def some(v, share):
        return np.where(rng.random(N) < share, v, 0.0)

    hits = SimpleNamespace(
        metallic=some(rng.random(N), 0.5), transmission=some(rng.random(N), 0.3), roughness=rng.random(N),
        anisotropy=some(rng.random(N), 0.4), anisotropy_t=some(1.0, 0.4)[:, None] * _unit(rng.normal(size=(N, 3))),
        specular_color=rng.random((N, 3)), specular=rng.random(N), base=rng.random((N, 3)),
        diffuse_transmission=some(rng.random(N), 0.3), diffuse_transmission_color=rng.random((N, 3)),
        iridescence=some(rng.random(N), 0.3), iridescence_ior=1 + rng.random(N),
        iridescence_thickness=100 + 800 * rng.random(N),
        clearcoat=some(rng.random(N), 0.4), clearcoat_normal=_unit(ng + 0.2 * rng.normal(size=(N, 3))),
        clearcoat_roughness=rng.random(N),
        sheen_color=some(1.0, 0.4)[:, None] * rng.random((N, 3)), sheen_roughness=rng.random(N))
    return hits, ns, ng, wo, 1 + rng.random(N)


@pytest.mark.parametrize("multiscatter", [True, False])
def test_compiled_bsdf_matches_its_numpy_twin(multiscatter):
    """eval_rows and sample_rows give Bsdf.eval's and Bsdf.sample's values, row for row, on
    hits mixing every lobe, through a row selection in any order [max relative 1e-9 measured]."""
    rng = np.random.default_rng(7)
    hits, ns, ng, wo, ior = _hits(rng)
    bsdf = path_bsdf.build(hits, ns, ng, wo, ior, multiscatter)
    packed = bsdf.packed()
    assert packed.shape == (N, path_kernel.WIDTH)
    assert (bsdf.p_coat > 0).any() and (bsdf.p_sheen > 0).any() and (bsdf.irid > 0).any()
    assert (bsdf.ax != bsdf.ay).any() and (bsdf.dt > 0).any()
    rows = rng.permutation(N)[: N // 2]
    sub = bsdf.rows(rows)
    wi = _unit(rng.normal(size=(len(rows), 3)))
    want_f, want_p = sub.eval(wi)
    got_f, got_p = path_kernel.eval_rows(packed, rows.astype(np.int64), wi)
    assert (want_p > 0).mean() > 0.3 and (want_f.max(axis=1) > 0).mean() > 0.3  # not all zeros
    np.testing.assert_allclose(got_f, want_f, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(got_p, want_p, rtol=1e-8, atol=1e-12)
    u = [rng.random(len(rows)) for _ in range(5)]
    w_wi, w_rough, w_valid = sub.sample(*u)
    w_f, w_p = sub.eval(w_wi)
    g_wi, g_rough, g_valid, g_f, g_p = path_kernel.sample_rows(packed, rows.astype(np.int64), *u)
    np.testing.assert_allclose(g_wi, w_wi, atol=1e-12)
    assert np.array_equal(g_rough, w_rough) and np.array_equal(g_valid, w_valid)
    assert not w_rough.all() and not w_valid.all()
    # near-delta lobes reach f, pdf ~1e6: relative
    np.testing.assert_allclose(g_f, w_f, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(g_p, w_p, rtol=1e-8, atol=1e-12)


def test_thin_film_matches_its_numpy_twin():
    """The compiled thin film (per hit, per channel phase) is path_bsdf.thin_film_fresnel,
    TIR inside the film included."""
    rng = np.random.default_rng(3)
    n = 500
    cos1, ior, thick = rng.random(n), 1 + rng.random(n), 900 * rng.random(n)
    ior[:20] = 0.5  # a film of lower index: TIR in it at grazing
    cos1[:20] = 0.05
    f0 = rng.random((n, 3))
    want = path_bsdf.thin_film_fresnel(cos1, ior, thick, f0)
    out, tmp = np.empty(3), np.empty(9)
    for i in range(n):
        path_kernel._thin_film(cos1[i], ior[i], thick[i], f0[i], out, tmp)
        np.testing.assert_allclose(out, want[i], rtol=1e-9, atol=1e-12)
    assert (want[:20] == 1.0).any()


_DUCK = Path(__file__).parent / "assets" / "gltf-samples" / "Duck" / "glTF-Binary" / "Duck.glb"


@pytest.mark.parametrize("case", ["layered", "duck", "smooth_glass", "rough_glass"])
def test_compiled_paths_render_the_twins_frame(case, tmp_path, monkeypatch):
    """A frame with path_kernel and the same frame with path_bsdf's numpy: the same rays and
    the same pixels up to float rounding (coat, sheen, iridescence, anisotropy and diffuse
    transmission on a sphere under a bright upper sky; the textured Duck under the default environment)."""
    if case == "layered":
        asset = _sphere("kernel-layered", metallic=0.3, roughness=0.4, clearcoat=0.7,
                        clearcoat_roughness=0.2, sheen_color=(0.6, 0.3, 0.2), sheen_roughness=0.5,
                        iridescence=0.8, anisotropy_strength=0.6, diffuse_transmission=0.3)
        env = make_env(lambda d: np.where(d[..., 1:2] > 0.5, 4.0, 0.2) * np.ones(3), key="kernel-sky")
        options = _path(samples=6, size=32)
    elif case.endswith("glass"):  # Glass: smooth or Walter's rough, TIR inside, roulette
        asset = _sphere("kernel-" + case, roughness=0.0 if case == "smooth_glass" else 0.3,
                        transmission=1.0, ior=1.5, base_color=(0.9, 0.8, 1.0, 1.0))
        env = make_env(lambda d: np.where(d[..., 1:2] > 0.5, 4.0, 0.2) * np.ones(3), key="kernel-sky")
        options = _path(samples=6, size=32)
    else:
        from pipeline.bake import bake_asset, bake_environment
        asset = bake_asset(str(_DUCK), tmp_path)
        env = bake_environment("footprint_court", tmp_path, face_size=64)
        options = _path(samples=4, size=32)
    fast = render_raytrace(asset, env, options)
    monkeypatch.setattr(path_trace, "KERNEL", False)
    slow = render_raytrace(asset, env, options)
    assert fast.plan["rays"] == slow.plan["rays"] and fast.plan["tir_events"] == slow.plan["tir_events"]
    assert slow.linear[..., :3].max() > 0.05 and math.isfinite(float(slow.linear.sum()))
    np.testing.assert_allclose(fast.linear, slow.linear, atol=1e-5)


@pytest.mark.parametrize("rotated", [False, True])
def test_compiled_environment_sampling_matches_its_numpy_twin(rotated, tmp_path):
    """EnvSampler.sample / pdf compiled (path_kernel.env_sample / env_pdf) against their numpy
    twins on a baked sky, with and without the environment's rotation: the same directions
    (the CDF's texel and the uniform share alike) and the same pdf."""
    from pipeline.bake import bake_environment
    env = bake_environment("footprint_court", tmp_path, face_size=32)
    a = 0.7
    rot = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]]) if rotated else None
    sampler = path_trace.EnvSampler(env.specular[0], rot)
    rng = np.random.default_rng(5)
    u1, u2, u3 = rng.random(20000), rng.random(20000), rng.random(20000)
    got, want = sampler.sample(u1, u2, u3), sampler.sample_numpy(u1, u2, u3)
    np.testing.assert_allclose(got, want, atol=1e-12)
    d = np.concatenate([got, _unit(rng.normal(size=(5000, 3))), np.eye(3), -np.eye(3)])
    np.testing.assert_allclose(sampler.pdf(d), sampler.pdf_numpy(d), rtol=1e-12)
    assert sampler.pdf(got).std() > 0  # importance: not a uniform pdf


@pytest.mark.parametrize("multiscatter", [True, False])
def test_compiled_build_matches_its_numpy_twin(multiscatter):
    """path_bsdf.build_packed (path_kernel.build_rows) is build(...).packed(): every column,
    the albedo tables' lookups (isotropic, anisotropic, sheen, Schlick share) included."""
    rng = np.random.default_rng(11)
    hits, ns, ng, wo, ior = _hits(rng)
    want = path_bsdf.build(hits, ns, ng, wo, ior, multiscatter).packed()
    got = path_bsdf.build_packed(hits, ns, ng, wo, ior, multiscatter)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)
