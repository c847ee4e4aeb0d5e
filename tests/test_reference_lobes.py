"""The lobes against Mitsuba 3 (`scalar_rgb`, the optional `reference` extra), rendered on the
fly at small sizes; skipped cleanly without Mitsuba. Relative mean absolute error over the
pixels the object covers (bench.reference.relative_mae), thresholds stated per lobe with the
values measured when they were set."""
from __future__ import annotations

import numpy as np
import pytest

from bench import scenes
from bench.reference import relative_mae, render_reference
from core.options import RenderOptions
from core.scene import Material
from renderer.raster.render import render

mi = pytest.importorskip("mitsuba")

SIZE = 64
SPP = 64   # Mitsuba noise at 64 spp on these spheres: ~0.02 relative (measured against 256)


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    from pipeline.bake import bake_environment
    return bake_environment("footprint_court", tmp_path_factory.mktemp("ref-env"),
                                     face_size=128)


def ours(spec: scenes.SceneSpec, env, method: str, tmp, multiscatter: bool = True) -> np.ndarray:
    asset = scenes.baked_asset(spec, tmp)
    # the background in too: the reference's edge pixels mix it in (its beauty pass shows it)
    return render(asset, env, RenderOptions(width=SIZE, height=SIZE, method=method, tonemap="none",
                                            yaw=spec.yaw, pitch=spec.pitch, fov=spec.fov,
                                            distance=spec.camera_distance(SIZE, SIZE),
                                            background="env", multiscatter=multiscatter)).linear


# (roughness, IOR) -> thresholds for raytrace and wyman, ~25% above what was measured at
# 64 px / 64 spp (raytrace, wyman): (0.1, 1.5) 0.089, 0.136; (0.3, 1.3) 0.132, 0.159;
# (0.6, 2.0) 0.231, 0.250. Before the transmitted share kept the lobe's single-scattering
# albedo (shaders/refraction.frag single_scatter_albedo) roughness 0.6 measured 0.81 / 0.80:
# the rough sphere was 1.8x too bright.
ROUGH_DIELECTRIC = {(0.1, 1.5): (0.11, 0.17), (0.3, 1.3): (0.165, 0.20), (0.6, 2.0): (0.29, 0.31)}


@pytest.mark.slow
@pytest.mark.parametrize("roughness,ior", sorted(ROUGH_DIELECTRIC))
def test_rough_dielectric_sphere_against_mitsuba(roughness, ior, env, tmp_path):
    spec = scenes.SceneSpec(f"rough_{roughness}_{ior}", "sphere", scenes.glass(ior, roughness))
    ref = render_reference(spec, SIZE, SPP)
    # Mitsuba's roughdielectric is single scattering: so are ours here (the default puts back
    # what bounces between the facets, tests/test_glass_multiscatter.py)
    errors = {m: relative_mae(ours(spec, env, m, tmp_path, multiscatter=False), ref)
              for m in ("raytrace", "wyman")}
    print(f"rough dielectric r={roughness} ior={ior}: {errors}")
    limits = dict(zip(("raytrace", "wyman"), ROUGH_DIELECTRIC[roughness, ior]))
    for m, e in errors.items():
        assert e < limits[m], (m, e, limits[m])


# The coat's own lobe: "coating only" (ClearCoatTest's third column), a full coat over a black
# base, against Mitsuba's `roughplastic` with a black diffuse base (a GGX coat of IOR 1.5,
# exact Fresnel and Smith masking). With a lit base the two models part by design: glTF's
# layering attenuates the base once by 1 - F_coat(N.V), where roughplastic refracts into the
# coat (radiance / eta^2) and adds internal reflections (measured 0.23 / 0.25 at roughness
# 0.1 / 0.4 with base 0.5, not tested). Measured 0.197 / 0.215 (Schlick and the split sum
# against exact Fresnel, strongest at the grazing rim of a 4% reflector); thresholds +25%.
CLEARCOAT = {0.1: 0.25, 0.4: 0.27}


@pytest.mark.slow
@pytest.mark.parametrize("cc_roughness", sorted(CLEARCOAT))
def test_clearcoat_lobe_against_mitsuba_roughplastic(cc_roughness, env, tmp_path, monkeypatch):
    mat = Material(name="coat_only", base_color=(0.0, 0.0, 0.0, 1.0), metallic=0.0,
                   roughness=1.0, specular=0.0, clearcoat=1.0, clearcoat_roughness=cc_roughness)
    spec = scenes.SceneSpec(f"coat_{cc_roughness}", "sphere", mat)
    import bench.reference as ref_mod
    coat = {"type": "roughplastic", "distribution": "ggx", "alpha": max(cc_roughness, 0.03) ** 2,
            "int_ior": 1.5, "ext_ior": 1.0, "nonlinear": False,
            "diffuse_reflectance": {"type": "rgb", "value": [0.0] * 3}}
    monkeypatch.setattr(ref_mod, "_bsdf", lambda m, texture=None: coat)
    ref = render_reference(spec, SIZE, SPP)
    err = relative_mae(ours(spec, env, "opaque", tmp_path), ref)
    print(f"clearcoat r={cc_roughness}: {err:.4f}")
    assert err < CLEARCOAT[cc_roughness]
