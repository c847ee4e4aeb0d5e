"""Raster refraction (`single`, `wyman`) against the committed Mitsuba references and invariants.

Errors are relative mean absolute errors of linear RGB over the object's pixels
(bench.reference.relative_mae). The environment is baked at 512 px faces, as in
tests/test_raytrace.py (at 256 px the cube resampling alone costs ~0.05 against Mitsuba).
Measured values are in brackets beside each threshold.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from bench import scenes
from bench.reference import load_reference, relative_mae
from core.baked import BakedAsset, BakedMesh
from core.options import MaterialOverride, RenderOptions
from core.scene import Material
from gl.context import get_context
from pipeline.interior.vectors import interior_vectors
from renderer.methods import refraction
from renderer.methods.optics import fresnel_dielectric, refract
from renderer.raster.render import render


def draw(name, reference_env, scene_cache, method, size=None, spec=None, **opts):
    spec = spec or scenes.scene(name)
    if size is None:
        size = load_reference(name).shape[0]
    frame = render(scenes.baked_asset(spec, scene_cache), reference_env,
                   RenderOptions(width=size, height=size, yaw=spec.yaw, pitch=spec.pitch,
                                 fov=spec.fov, distance=spec.camera_distance(size, size), method=method,
                                 **{"background": "env", **opts}))
    assert np.isfinite(frame.linear).all(), (name, method)
    assert frame.linear.min() >= 0, (name, method)
    return frame


def reference(name, size=None):
    """The committed reference, box-filtered down to `size` when that divides it."""
    ref = load_reference(name)
    k = ref.shape[0] // (size or ref.shape[0])
    return ref.reshape(ref.shape[0] // k, k, ref.shape[1] // k, k, 4).mean(axis=(1, 3))


def error(name, reference_env, scene_cache, method, size=None, **opts):
    frame = draw(name, reference_env, scene_cache, method, size=size, **opts)
    return relative_mae(frame.linear, reference(name, frame.width))


# --- GLSL twins of renderer.methods.optics -------------------------------------------------------------

_TWIN = """#version 430
layout(local_size_x = 64) in;
#include "refraction.glsl"
layout(std430, binding = 0) buffer In { vec4 cases[]; };   // cos_i, eta
layout(std430, binding = 1) buffer Out { vec4 result[]; }; // t.xyz, fresnel
void main() {
    uint i = gl_GlobalInvocationID.x;
    float c = cases[i].x, eta = cases[i].y;
    vec3 d = vec3(sqrt(max(1.0 - c * c, 0.0)), 0.0, -c);
    vec3 t;
    bool ok = refract_ray(d, vec3(0.0, 0.0, 1.0), eta, t);
    result[i] = vec4(t, ok ? fresnel_dielectric(c, eta) : -1.0);
}
"""


def test_glsl_snell_and_fresnel_match_numpy_optics():
    import shaders

    ctx = get_context()
    cos_i = np.linspace(0.0, 1.0, 32)
    eta = np.array([1 / 1.5, 1 / 2.4, 1.0, 1.5, 2.4, 1 / 1.3])
    c, e = (a.ravel() for a in np.meshgrid(cos_i, eta))
    cases = np.zeros((len(c), 4), np.float32)
    cases[:, 0], cases[:, 1] = c, e
    src = _TWIN.replace('#include "refraction.glsl"', shaders.load("refraction.glsl"))
    prog = ctx.compute_shader(src)
    inp, out = ctx.buffer(cases.tobytes()), ctx.buffer(reserve=cases.nbytes)
    inp.bind_to_storage_buffer(0)
    out.bind_to_storage_buffer(1)
    prog.run(len(c) // 64 + 1)
    got = np.frombuffer(out.read(), np.float32).reshape(-1, 4)
    for buf in (inp, out, prog):
        buf.release()
    d = np.stack([np.sqrt(1 - c ** 2), np.zeros_like(c), -c], -1)
    t, tir = refract(d, np.array([0.0, 0.0, 1.0]), e)
    assert np.array_equal(got[:, 3] < 0, tir)
    np.testing.assert_allclose(got[~tir, :3], t[~tir], atol=2e-4)
    np.testing.assert_allclose(got[~tir, 3], fresnel_dielectric(c, e)[~tir], atol=2e-5)


# --- invariants ------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["single", "wyman"])
def test_ior_one_sphere_is_invisible(method, reference_env, scene_cache):
    """IOR 1.0, roughness 0, no attenuation: the frame equals the frame without the object."""
    spec = scenes.scene("glass_sphere_ior1.0")
    glass = draw(spec.name, reference_env, scene_cache, method, size=128).linear
    asset = scenes.baked_asset(spec, scene_cache)
    empty = replace(asset, key="empty:" + asset.key, meshes=[])
    background = render(empty, reference_env, RenderOptions(
        background="env", yaw=spec.yaw, pitch=spec.pitch, width=128, height=128, method=method,
        distance=spec.camera_distance(128, 128))).linear
    mask = load_reference(spec.name)[..., 3] > 0
    diff = np.abs(glass[..., :3] - background[..., :3])
    assert diff[mask].sum() / background[..., :3][mask].sum() < 0.005  # [0.0014]
    assert np.percentile(diff[mask].max(axis=-1), 99) < 0.02


def test_opaque_scene_runs_no_refraction_pass(reference_env, scene_cache):
    """An opaque scene allocates no back-face textures and runs no back-face pass, under
    `auto` and even when `wyman` is asked for; a transmissive one does."""
    before = dict(refraction.stats)
    allocated = set(refraction.allocated())
    for method in ("auto", "wyman"):
        frame = draw("dielectric_sphere", reference_env, scene_cache, method, size=64)
        assert [o["method"] for o in frame.plan["objects"]] == ["opaque"]
    assert refraction.stats == before
    assert set(refraction.allocated()) == allocated
    frame = draw("glass_sphere_ior1.5", reference_env, scene_cache, "auto", size=64)
    assert frame.plan["objects"][0]["method"] == "wyman"   # auto: transmissive -> wyman
    assert refraction.stats["backface_passes"] == before["backface_passes"] + 1
    assert ("back", 64, 64) in refraction.allocated()
    assert refraction.stats["frontface_passes"] == before["frontface_passes"] + (
        frame.plan["auto"]["tir"] == "reflect")  # auto picks the TIR treatment (renderer.methods.auto)


# --- against the Mitsuba references ------------------------------------------------------------

@pytest.mark.parametrize("name,method,limit", [
    ("glass_sphere_ior1.5", "wyman", 0.12),    # [0.088] issue target 0.18
    ("glass_sphere_ior1.3", "wyman", 0.12),    # [0.080]
    ("glass_sphere_ior1.5", "single", 1.0),    # [0.934] = raytrace with 1 bounce [0.93]
    ("glass_sphere_ior1.3", "single", 1.25),   # [1.14]
    ("mirror_sphere", "single", 0.1),          # [0.080] opaque: the PBR path, no refraction
    ("mirror_sphere", "wyman", 0.1),           # [0.080]
])
def test_matches_mitsuba_reference(name, method, limit, reference_env, scene_cache):
    assert error(name, reference_env, scene_cache, method) < limit


def test_wyman_beats_single_on_sphere_and_bunny(reference_env, scene_cache):
    """The paper's Figure 4 claim, measured: two refractions beat one at IOR 1.5."""
    for name in ("glass_sphere_ior1.5", "glass_bunny_ior1.5"):   # [0.088 vs 0.93; 0.34 vs 0.58]
        w, s = error(name, reference_env, scene_cache, "wyman"), error(name, reference_env, scene_cache, "single")
        assert w < 0.75 * s, (name, w, s)


def test_exit_refinement_improves_on_the_paper_estimate(reference_env, scene_cache, monkeypatch):
    """EXIT_REFINE_STEPS = 0 is the paper's interpolated exit distance alone."""
    refined = error("glass_sphere_ior1.5", reference_env, scene_cache, "wyman")
    monkeypatch.setattr(refraction, "EXIT_REFINE_STEPS", 0)
    paper = error("glass_sphere_ior1.5", reference_env, scene_cache, "wyman")   # [0.31]
    assert refined < 0.5 * paper


def test_default_tir_treatment_has_the_lower_error(reference_env, scene_cache):
    """The default was chosen by this measurement: mean error over four shapes at 128 px."""
    names = ("glass_sphere_ior1.5", "glass_cube_ior1.15", "glass_bunny_ior1.5",
             "glass_torus_ior1.5")
    mean = {tir: np.mean([error(n, reference_env, scene_cache, "wyman", size=128, tir=tir) for n in names])
            for tir in ("paper", "reflect")}                    # [0.27 vs 0.17]
    assert refraction.DEFAULT_TIR == min(mean, key=mean.get)
    # The cube's bottom shows the sky by total internal reflection: only "reflect" has it.
    assert error("glass_cube_ior1.15", reference_env, scene_cache, "wyman", tir="reflect") < 0.25  # [0.19]
    assert error("glass_cube_ior1.15", reference_env, scene_cache, "wyman", tir="paper") > 0.4     # [0.53]


def test_non_uniform_scale_uses_transformed_interior_vectors(reference_env, scene_cache, monkeypatch):
    """The 3:1:1 ellipsoid: seen along its long axis, the paper's estimate at the centre is
    eta * D_d + (1 - eta) * D_I with D_d = D_I = 6 only if the baked vector (length 2 in
    object space) is scaled by the node matrix; untransformed it would be 4.67."""
    spec = scenes.scene("glass_ellipsoid_311_ior1.5")
    monkeypatch.setattr(refraction, "EXIT_REFINE_STEPS", 0)
    frame = draw(spec.name, reference_env, scene_cache, "wyman", size=65, spec=replace(spec, yaw=90.0),
                 debug="exit_distance")
    radius = math.sqrt(3 ** 2 + 1 + 1)
    d = frame.linear[32, 32, 0] * 2 * radius    # the view shows D * 0.5 / bounding radius
    assert d == pytest.approx(6.0, rel=0.03)
    monkeypatch.undo()
    ellipsoid = error(spec.name, reference_env, scene_cache, "wyman")            # [0.21]
    sphere = error("glass_sphere_ior1.5", reference_env, scene_cache, "wyman", size=128)   # [0.10]
    assert ellipsoid < 3.0 * sphere


@pytest.mark.parametrize("name,limit", [
    ("glass_sphere_ior2.4", 0.25),          # [0.157]
    ("glass_torus_ior1.5", 0.25),           # [0.162] genus 1: more than two interfaces
    ("glass_torus_ior2.4", 0.35),           # [0.242]
    ("frosted_sphere_ior1.5_r0.3", 0.18),   # [0.126] roughness through the prefiltered mips
])
def test_hard_cases_finite_and_error_recorded(name, limit, reference_env, scene_cache):
    for method in ("single", "wyman"):
        frame = draw(name, reference_env, scene_cache, method)   # finite and non-negative, checked in draw()
        err = relative_mae(frame.linear, load_reference(name))
        print(f"{name} {method}: relative error {err:.3f}")
        if method == "wyman":
            assert err < limit


# --- material, debug views, opaque parts -------------------------------------------------------

def test_beer_lambert_attenuation_over_the_path(reference_env, scene_cache):
    """Half transmittance per unit length: the centre ray crosses the diameter 2, so its
    refracted share drops to 1/4 (an opaque-black volume leaves the reflection alone)."""
    clear = scenes.scene("glass_sphere_ior1.5")

    def absorbing(color):
        return replace(clear, name=f"absorbing_sphere_{color}", material=scenes.glass(
            1.5, attenuation_color=(color,) * 3, attenuation_distance=1.0))
    for method in ("single", "wyman"):
        a, b, black = (draw(s.name, reference_env, scene_cache, method, size=33, spec=s).linear[16, 16, :3]
                       for s in (clear, absorbing(0.5), absorbing(0.0)))
        ratio = (b - black).sum() / (a - black).sum()
        assert ratio == pytest.approx(0.25, rel=0.05), method



def test_absorbing_cube_rims_absorb_along_the_internal_reflection(reference_env, scene_cache):
    """At the rims of a flat-faced absorbing cube (AttenuationTest's blocks) the view ray meets
    the hidden face a pixel or two in, reflects totally and crosses the cube: the path is long.
    The exit there used to count as off the surface (a tolerance relative to the sub-pixel exit
    distance alone), so the reflected ray was never marched and the rims kept a short, bright
    path. wyman against the ray tracer (exact for a cube) over a 4 px band inside the
    silhouette: relative error [0.15, was 0.47]."""
    spec = replace(scenes.scene("glass_cube_ior1.5"), name="absorbing_cube_ior1.5", yaw=35.0, pitch=25.0,
                   material=scenes.glass(1.5, attenuation_color=(0.1, 0.5, 0.9), attenuation_distance=1.0))
    asset = scenes.baked_asset(spec, scene_cache)
    options = RenderOptions(width=96, height=96, yaw=spec.yaw, pitch=spec.pitch, fov=spec.fov,
                            distance=spec.camera_distance(96, 96), background="transparent", shadow=0.0)
    ours = render(asset, reference_env, options.replace(method="wyman")).linear
    traced = render(asset, reference_env, options.replace(method="raytrace")).linear
    inside = (ours[..., 3] > 0.999) & (traced[..., 3] > 0.999)
    core = inside.copy()
    for _ in range(4):
        core &= np.roll(core, 1, 0) & np.roll(core, -1, 0) & np.roll(core, 1, 1) & np.roll(core, -1, 1)
    rim = inside & ~core
    assert rim.sum() > 300  # the band along the silhouette is there
    err = np.abs(ours[..., :3] - traced[..., :3])[rim].sum() / traced[..., :3][rim].sum()
    assert err < 0.25, err
    assert relative_mae(ours, traced) < 0.22  # the whole cube [0.15, was 0.28]

def test_override_previews_an_opaque_mesh_as_glass(reference_env, scene_cache):
    """A mesh baked without interior vectors, shown as glass: wyman falls back to D_d."""
    glass = MaterialOverride(base_color=(1, 1, 1), metallic=0.0, roughness=0.0, ior=1.5,
                             transmission=1.0)
    spec = scenes.scene("dielectric_sphere")
    assert scenes.baked_asset(spec, scene_cache).meshes[0].interior is None
    frame = draw(spec.name, reference_env, scene_cache, "wyman", size=128, spec=spec, override=glass)
    assert frame.plan["objects"][0]["method"] == "wyman"
    err = relative_mae(frame.linear, reference("glass_sphere_ior1.5", 128))
    assert err < 0.2  # [0.10]


def test_debug_views(reference_env, scene_cache):
    sphere = draw("glass_sphere_ior1.5", reference_env, scene_cache, "wyman", size=65,
                  debug="backface_normals").linear
    # The back face behind the centre faces away from the camera: normal -Z -> (0.5, 0.5, 0).
    np.testing.assert_allclose(sphere[32, 32, :3], [0.5, 0.5, 0.0], atol=0.03)
    tir = draw("glass_bunny_ior1.5", reference_env, scene_cache, "wyman", size=128, debug="tir",
               tir="paper").linear
    red = (tir[..., 0] > 0.99) & (tir[..., 1] < 0.01) & (tir[..., 2] < 0.01)
    assert 0.005 < red.mean() < 0.3   # the bunny has real TIR; the reference_env has no pure red
    clean = draw("glass_sphere_ior1.5", reference_env, scene_cache, "wyman", size=128, debug="tir").linear
    red = (clean[..., 0] > 0.99) & (clean[..., 1] < 0.01) & (clean[..., 2] < 0.01)
    assert red.mean() < 0.002         # a sphere has none (the paper's Fig. 6 rings were
    #                                   errors of the exit estimate, which refinement removes)
    with pytest.raises(ValueError, match="tir"):
        draw("glass_sphere_ior1.5", reference_env, scene_cache, "wyman", size=16, tir="bogus")


@pytest.mark.parametrize("method", ["single", "wyman"])
def test_refracted_rays_see_the_assets_opaque_parts(method, reference_env):
    """A red core inside a glass sphere shows through it (screen-space, from the opaque pass)."""
    pos, nrm, idx = scenes.mesh_arrays("sphere")
    glass = BakedMesh("glass", pos, nrm, idx, scenes.glass(1.5), np.eye(4)[None],
                      interior=interior_vectors(pos, nrm, idx).vectors)
    red = Material(name="red", base_color=(0.8, 0.02, 0.02, 1.0), metallic=0.0, roughness=0.5)
    core = BakedMesh("core", pos, nrm, idx, red, np.diag([0.35, 0.35, 0.35, 1.0])[None])
    asset = BakedAsset("test:glass_with_core", "test", "generated", [glass, core], [],
                       np.array([[-1.0] * 3, [1.0] * 3]))
    frame = render(asset, reference_env, RenderOptions(background="env", yaw=0.0, pitch=0.0, width=64, height=64, method=method))
    assert np.isfinite(frame.linear).all()
    c = frame.linear[32, 32, :3]
    assert c[0] > 4 * c[1] and c[0] > 4 * c[2], c    # the core, magnified by the glass
    rim = frame.linear[32, 8, :3]
    assert not (rim[0] > 4 * rim[1]), rim             # near the rim: the environment
    assert [o["method"] for o in frame.plan["objects"]] == [method, "opaque"]
