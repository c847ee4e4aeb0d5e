"""The ray-traced method against the committed Mitsuba references and physical invariants.

Errors are relative mean absolute errors of linear RGB over the object's pixels
(bench.reference.relative_mae). The environment is baked at 512 px faces: at 256 px the
cube-map resampling alone costs ~0.05 against Mitsuba, which reads the panorama itself.
"""
import math
from dataclasses import replace

import numpy as np
import pytest

from bench import scenes
from bench.reference import load_reference, relative_mae
from core.baked import BakedEnvironment
from core.options import MaterialOverride, RenderOptions
from pipeline.environment.prefilter import brdf_lut
from pipeline.ingest import load_scene
from renderer.frame import Frame
from renderer.methods.raytrace import render_raytrace


def render(name, reference_env, scene_cache, size=None, **opts):
    spec = scenes.scene(name)
    if size is None:
        size = load_reference(name).shape[0]
    options = RenderOptions(width=size, height=size, yaw=spec.yaw, pitch=spec.pitch,
                            fov=spec.fov, distance=spec.camera_distance(size, size), **{"background": "env", **opts})
    frame = render_raytrace(scenes.baked_asset(spec, scene_cache), reference_env, options)
    assert np.isfinite(frame.linear).all(), name
    assert frame.linear.min() >= 0, name
    return frame


def uniform_env(radiance=1.0, size=16) -> BakedEnvironment:
    mips = [np.full((6, s, s, 3), radiance, np.float32) for s in (size, size // 2, size // 4)]
    return BakedEnvironment(key="white", name="white", specular=mips,
                            irradiance_sh=np.zeros((9, 3), np.float32),
                            brdf_lut=brdf_lut(), irradiance=np.full((6, 16, 16, 3), radiance, np.float32))  # the bake's split-sum LUT: metals read it


# Thresholds: the value measured with the default supersampling in brackets (2 x 2 at 500 px
# gives 0.024 on the IOR 1.5 sphere); the margin covers float and bake differences.
@pytest.mark.parametrize("name,limit", [
    ("mirror_sphere", 0.025),           # [0.014]
    ("glass_sphere_ior1.3", 0.03),      # [0.021]
    ("glass_sphere_ior1.5", 0.03),      # [0.022]
    ("glass_sphere_ior1.0", 0.03),      # [0.018] cube-map resampling of the panorama
    ("glass_sphere_ior1.15", 0.03),     # [0.020]
    ("glass_cube_ior1.15", 0.02),       # [0.009]
])
def test_matches_mitsuba_reference(name, limit, reference_env, scene_cache):
    err = relative_mae(render(name, reference_env, scene_cache).linear, load_reference(name))
    assert err < limit, f"{name}: relative error {err:.4f} >= {limit}"


@pytest.mark.parametrize("name,limit", [
    ("glass_sphere_ior2.4", 0.04),      # [0.025]
    ("glass_ellipsoid_311_ior1.5", 0.05),  # [0.031] 3:1:1 non-uniform node scale
    ("glass_torus_ior1.5", 0.05),       # [0.032] genus 1
    ("glass_torus_ior2.4", 0.05),       # [0.035]
    ("glass_bunny_ior1.5", 0.13),       # [0.088] open mesh, sub-pixel detail at 128 px
    ("frosted_sphere_ior1.5_r0.3", 0.21),  # [0.173] sampled rough lobes, 9 rays a pixel (noise;
    #                                    0.128 at the 4 x 4 grid the default was before issue 26)
])
def test_hard_cases_finite_and_error_recorded(name, limit, reference_env, scene_cache):
    frame = render(name, reference_env, scene_cache)
    err = relative_mae(frame.linear, load_reference(name))
    assert err < limit, f"{name}: relative error {err:.4f} >= {limit}"
    assert frame.plan["rays"] > 0


def test_ior_one_sphere_is_invisible(reference_env, scene_cache):
    """IOR 1, no roughness, no attenuation: the frame equals the background seen through the
    same rays (bounces=0 reads the environment along every primary ray)."""
    glass = render("glass_sphere_ior1.0", reference_env, scene_cache, size=96)
    background = render("glass_sphere_ior1.0", reference_env, scene_cache, size=96, bounces=0)
    np.testing.assert_allclose(glass.linear, background.linear, atol=1e-5)


def test_more_bounces_converge_to_the_reference(reference_env, scene_cache):
    """One bounce is the single-refraction method, two the exact two-interface result."""
    ref = load_reference("glass_sphere_ior1.5")
    # the full tree on 4 x 4 rays (the defaults before issue 26), where the ratios were measured
    errs = [relative_mae(render("glass_sphere_ior1.5", reference_env, scene_cache, bounces=b,
                                fresnel_split="both", supersample=4).linear, ref)
            for b in (1, 2, 8)]
    assert errs[0] > 5 * errs[1] and errs[1] > 2 * errs[2], errs  # [0.92, 0.052, 0.022]


def test_orientation_matters(reference_env, scene_cache):
    """A mirrored image is far from the reference: the match above is not a coincidence."""
    ref = load_reference("mirror_sphere")
    img = render("mirror_sphere", reference_env, scene_cache).linear
    assert relative_mae(img[:, ::-1], ref) > 5 * relative_mae(img, ref)


@pytest.mark.parametrize("name", ["glass_sphere_ior1.5", "glass_sphere_ior2.4", "mirror_sphere",
                                  "glass_torus_ior2.4"])
def test_furnace_energy_conserved(name, scene_cache):
    """Under a uniform white sky, lossless glass and a perfect mirror vanish: Fresnel splits
    every ray's energy between its children and all of it reaches the sky (the full tree:
    roulette, the default, is exact only on average, test_roulette_split_is_unbiased_and_cheaper)."""
    frame = render(name, uniform_env(), scene_cache, size=48, fresnel_split="both")
    rgb = frame.linear[..., :3]
    assert np.abs(rgb - 1.0).max() < 0.01, rgb.min()


@pytest.mark.parametrize("name", ["glass_sphere_ior1.5", "glass_torus_ior2.4"])
def test_sampled_fresnel_split_conserves_energy(name, scene_cache):
    """fresnel_split=sample reweights the child it follows by 1 / its probability, so under a
    white sky every sample still carries all of its energy: no noise, no loss."""
    frame = render(name, uniform_env(), scene_cache, size=48, fresnel_split="sample")
    assert np.abs(frame.linear[..., :3] - 1.0).max() < 0.01


def test_sampled_fresnel_split_is_cheaper_and_close(reference_env, scene_cache):
    """One child per interface below the first: far fewer rays, deterministic, and near the
    reference (noise, not bias: [0.057] against [0.032] with both children, 4 x 4 rays a pixel
    at the reference's 128 px)."""
    ref = load_reference("glass_torus_ior1.5")
    both = render("glass_torus_ior1.5", reference_env, scene_cache, fresnel_split="both")
    sampled = render("glass_torus_ior1.5", reference_env, scene_cache, fresnel_split="sample")
    again = render("glass_torus_ior1.5", reference_env, scene_cache, fresnel_split="sample")
    np.testing.assert_array_equal(sampled.linear, again.linear)
    assert sampled.plan["rays"] < 0.7 * both.plan["rays"], (sampled.plan["rays"], both.plan["rays"])
    err = relative_mae(sampled.linear, ref)
    assert err < 0.08, err


def test_beer_lambert_attenuation(scene_cache):
    """The centre ray crosses 2 units of glass at normal incidence: exp(-2 sigma)."""
    dist, colour = 2.0, (0.5, 0.8, 1.0)
    spec = scenes.scene("glass_sphere_ior1.5")
    spec = replace(spec, material=replace(spec.material, attenuation_color=colour,
                                          attenuation_distance=dist))
    reference_env = uniform_env()
    opts = RenderOptions(background="env", yaw=0.0, pitch=0.0, width=33, height=33)
    clear = render_raytrace(scenes.baked_asset(scenes.scene("glass_sphere_ior1.5")), reference_env, opts)
    tinted = render_raytrace(scenes.baked_asset(spec), reference_env, opts)
    ratio = tinted.linear[16, 16, :3] / clear.linear[16, 16, :3]
    # The direct path carries (1-F0)^2 ~ 0.92 of the light; the 4% reflected off the front
    # face is not attenuated, which bounds the ratio from above.
    expected = np.exp(2.0 * np.log(colour) / dist)
    np.testing.assert_allclose(ratio, 0.92 * expected + 0.08 * np.array([1, 1, 1]) * 0.5,
                               atol=0.05)
    assert ratio[0] < ratio[1] < ratio[2]


def test_material_override_turns_a_mirror_into_glass(reference_env, scene_cache):
    spec = scenes.scene("mirror_sphere")
    asset = scenes.baked_asset(spec, scene_cache)
    opts = RenderOptions(background="env", yaw=0.0, pitch=0.0, width=64, height=64, override=MaterialOverride(
        metallic=0.0, transmission=1.0, ior=1.5, roughness=0.0, base_color=(1, 1, 1)))
    glass = render_raytrace(asset, reference_env, opts)
    ref = render_raytrace(scenes.baked_asset(scenes.scene("glass_sphere_ior1.5"), scene_cache), reference_env,
                          replace(opts, override=None))
    np.testing.assert_allclose(glass.linear, ref.linear, atol=1e-5)


def test_frame_and_transparent_background(reference_env, scene_cache):
    frame = render("glass_sphere_ior1.5", reference_env, scene_cache, size=64, background="transparent")
    assert isinstance(frame, Frame)
    assert frame.rgba8.shape == (64, 64, 4) and frame.rgba8.dtype == np.uint8
    alpha = frame.linear[..., 3]
    assert alpha[0, 0] == 0 and alpha[32, 32] == 1
    assert 0 < alpha.mean() < 1
    assert frame.plan["method"] == "raytrace" and frame.plan["bounces"] == 12
    assert set(frame.timings.stages_ms) >= {"build", "trace"} and frame.timings.total_ms > 0
    assert frame.plan["supersample"] == 4  # small frames get more rays per pixel


def test_every_instance_is_traced(reference_env):
    """Two placements of one mesh: both appear, left and right of the centre."""
    spec = scenes.scene("mirror_sphere")
    asset = scenes.baked_asset(spec)
    t = np.stack([np.eye(4), np.eye(4)])
    t[0, 0, 3], t[1, 0, 3] = -1.5, 1.5
    asset.meshes[0].transforms = t
    asset.bounds = np.array([[-2.5, -1, -1], [2.5, 1, 1]])
    frame = render_raytrace(asset, reference_env, RenderOptions(yaw=0.0, pitch=0.0, width=96, height=48,
                                                      background="transparent"))
    alpha = frame.linear[..., 3]
    assert alpha[:, :48].max() == 1 and alpha[:, 48:].max() == 1
    assert alpha[:, 47:49].max() == 0  # the gap between them
    assert alpha[:, :48].sum() == pytest.approx(alpha[:, 48:].sum(), rel=0.02)


def test_degenerate_geometry_stays_finite(reference_env):
    """Zero-area triangles, zero normals, a camera inside the object: finite output."""
    spec = scenes.scene("glass_sphere_ior2.4")
    asset = scenes.baked_asset(spec)
    mesh = asset.meshes[0]
    mesh.normals = mesh.normals.copy()
    mesh.normals[::7] = 0.0
    mesh.indices = np.concatenate([mesh.indices, np.array([[0, 0, 1], [2, 2, 2]], np.uint32)])
    for opts in (RenderOptions(background="env", yaw=0.0, pitch=0.0, width=40, height=40),
                 RenderOptions(background="env", yaw=0.0, pitch=0.0, width=40, height=40, distance=0.3, bounces=16)):
        frame = render_raytrace(asset, reference_env, opts)
        assert np.isfinite(frame.linear).all() and np.isfinite(frame.rgba8).all()
        assert math.isfinite(frame.timings.total_ms)


@pytest.mark.parametrize("name", ["glass_ellipsoid_311_ior1.5", "glass_torus_ior2.4",
                                  "mirror_sphere", "frosted_sphere_ior1.5_r0.3"])
def test_scene_glb_round_trips_through_ingest(name, tmp_path):
    """The generated .glb carries the material and node scale through pipeline ingest."""
    spec = scenes.scene(name)
    scene = load_scene(scenes.write_glb(spec, tmp_path / f"{name}.glb"))
    (mat,) = scene.materials
    want = spec.material
    assert mat.transmission == want.transmission and mat.ior == pytest.approx(want.ior)
    assert mat.roughness == pytest.approx(want.roughness)
    assert mat.metallic == pytest.approx(want.metallic)
    assert mat.material_class == ("transmissive" if want.transmission else "opaque")
    np.testing.assert_allclose(scene.instances[0].matrix, spec.matrix, atol=1e-6)
    pos, _, idx = scenes.mesh_arrays(spec.mesh)
    assert scene.triangle_count == len(idx)


def test_chunked_tracing_gives_the_same_image(reference_env, monkeypatch):
    """Large frames go through in chunks of pixels (bounded memory); the image is the same."""
    import renderer.methods.raytrace as rt

    asset = scenes.baked_asset(scenes.scene("glass_torus_ior1.5"))
    opts = RenderOptions(background="env", width=40, height=40, yaw=20, pitch=30)
    whole = render_raytrace(asset, reference_env, opts)
    monkeypatch.setattr(rt, "CHUNK_PIXELS", 37)
    chunked = render_raytrace(asset, reference_env, opts)
    np.testing.assert_allclose(chunked.linear, whole.linear, atol=1e-5)
    assert chunked.plan["rays"] == whole.plan["rays"]


@pytest.mark.parametrize("ior", [1.3, 1.5])
def test_furnace_seen_from_inside_the_glass_is_n_squared(ior):
    """Radiance inside a dielectric in equilibrium with a uniform sky is n^2 times the sky's
    (the eta^2 factor at each crossing; it cancels for a camera outside)."""
    spec = scenes.scene("glass_sphere_ior1.5")
    spec = replace(spec, material=replace(spec.material, ior=ior))
    frame = render_raytrace(scenes.baked_asset(spec), uniform_env(),
                            RenderOptions(background="env", yaw=0.0, pitch=0.0, width=24, height=24,
                                          distance=0.4, fresnel_split="both"))
    np.testing.assert_allclose(frame.linear[..., :3], ior * ior, rtol=0.01)


def test_camera_inside_matches_mitsuba(reference_env, scene_cache):
    """The stability suite's camera-inside case (bench.scenes), against its reference."""
    err = relative_mae(render("case_camera_inside", reference_env, scene_cache).linear,
                       load_reference("case_camera_inside"))
    assert err < 0.03, err  # [0.017]; 0.56 without the eta^2 radiance factor


# --- issue 17: the compiled kernel, traced rough lobes, roulette splitting -----------------

@pytest.mark.parametrize("name,opts", [
    ("glass_sphere_ior1.5", {}),
    ("glass_torus_ior2.4", {"fresnel_split": "sample"}),
    ("frosted_sphere_ior1.5_r0.3", {}),
    ("frosted_sphere_ior1.5_r0.3", {"rough_lobes": "prefilter"}),
    ("steel_sphere", {}),
    ("rough_metal_sphere", {}),
    ("dielectric_sphere", {}),
])
def test_compiled_kernel_matches_its_numpy_twin(name, opts, reference_env, scene_cache, monkeypatch):
    """renderer.methods.trace_kernel against the numpy shading it replaced (kept as _shade_numpy):
    the same rays and the same frame up to float rounding [max 1.2e-5 measured]."""
    from renderer.methods import raytrace
    fast = render(name, reference_env, scene_cache, size=48, **opts)
    monkeypatch.setattr(raytrace, "KERNEL", False)
    slow = render(name, reference_env, scene_cache, size=48, **opts)
    assert fast.plan["rays"] == slow.plan["rays"] and fast.plan["tir_events"] == slow.plan["tir_events"]
    np.testing.assert_allclose(fast.linear, slow.linear, atol=1e-4)


def test_traced_rough_lobes_converge_to_mitsuba(reference_env, scene_cache):
    """Frosted glass (roughness 0.3, Mitsuba's roughdielectric GGX at 1024 spp): sampled
    lobes get closer to the reference with more rays, well below the prefiltered mips'
    floor, and unbiased: the object's mean radiance matches [+0.5% at 16 bounces; +1.2% at 8,
    where the paths still inside read the sky without the exit's Fresnel loss]."""
    name = "frosted_sphere_ior1.5_r0.3"
    ref = load_reference(name)
    # roughdielectric is single scattering: so are ours here (the default puts back what
    # bounces between the facets: tests/test_glass_multiscatter.py)
    single = {"multiscatter": False}
    pre = render(name, reference_env, scene_cache, rough_lobes="prefilter", **single).linear
    s4 = render(name, reference_env, scene_cache, **single).linear
    s8 = render(name, reference_env, scene_cache, supersample=8, fresnel_split="roulette",
                bounces=16, **single).linear
    again = render(name, reference_env, scene_cache, **single).linear
    np.testing.assert_array_equal(s4, again)  # deterministic: seeds hashed from pixel and bounce
    e_pre, e4, e8 = (relative_mae(x, ref) for x in (pre, s4, s8))
    # [0.110, 0.128, 0.065]: at 16 rays a pixel the noise's mean absolute error exceeds the
    # prefilter's bias (FLIP ranks them the other way: 0.089 vs 0.139); 64 rays beat both
    assert e8 < 0.7 * e_pre and e8 < 0.7 * e4 and e8 < 0.08, (e_pre, e4, e8)
    mask = ref[..., 3] > 0.999  # pixels the object covers whole
    bias = s8[..., :3][mask].mean() / ref[..., :3][mask].mean() - 1
    assert abs(bias) < 0.01, bias


def test_roulette_split_is_unbiased_and_cheaper(reference_env, scene_cache):
    """fresnel_split=roulette: under a white sky the mean stays 1 (each faint child that goes
    on carries 1 / its survival probability); against Mitsuba it is within a little of the
    full tree with far fewer rays."""
    white = render("glass_torus_ior1.5", uniform_env(), scene_cache, size=48, fresnel_split="roulette")
    rgb = white.linear[..., :3]
    assert abs(rgb.mean() - 1.0) < 0.005 and np.abs(rgb - 1.0).max() < 0.25, (rgb.mean(), rgb.min(), rgb.max())
    ref = load_reference("glass_torus_ior1.5")
    both = render("glass_torus_ior1.5", reference_env, scene_cache, fresnel_split="both")
    rr = render("glass_torus_ior1.5", reference_env, scene_cache, fresnel_split="roulette")
    assert rr.plan["rays"] < 0.8 * both.plan["rays"], (rr.plan["rays"], both.plan["rays"])
    e_both, e_rr = relative_mae(both.linear, ref), relative_mae(rr.linear, ref)
    assert e_rr < e_both + 0.01, (e_rr, e_both)


def test_rough_glass_furnace_loses_only_what_microfacets_mask():
    """Sampled rough glass under a white sky: single-scattering microfacets (multiscatter off,
    as Mitsuba's roughdielectric) lose a little energy, masked light not traced further, and
    never gain; the default puts the lost share back, so its mean is nearer 1."""
    spec = scenes.scene("frosted_sphere_ior1.5_r0.3")

    def frame(multiscatter: bool) -> np.ndarray:
        return render_raytrace(scenes.baked_asset(spec), uniform_env(),
                               RenderOptions(background="env", width=48, height=48,
                                             distance=spec.camera_distance(48, 48), supersample=4,
                                             fresnel_split="both", multiscatter=multiscatter)
                               ).linear[..., :3]
    rgb = frame(False)
    centre = rgb[18:30, 18:30]
    assert 0.95 < centre.mean() <= 1.0 + 1e-3, centre.mean()
    assert rgb.max() <= 1.0 + 1e-3, rgb.max()
    compensated = frame(True)[18:30, 18:30].mean()
    assert centre.mean() < compensated < 1.0 + 5e-3, (centre.mean(), compensated)


def test_supersample_and_adaptive_options(reference_env, scene_cache):
    """supersample sets the grid (rays scale with its square); aa_threshold refines only the
    pixels whose 2 x 2 samples disagree, so it traces fewer rays than the full grid."""
    two = render("glass_sphere_ior1.5", reference_env, scene_cache, size=64, supersample=2)
    four = render("glass_sphere_ior1.5", reference_env, scene_cache, size=64, supersample=4)
    adaptive = render("glass_sphere_ior1.5", reference_env, scene_cache, size=64, supersample=4,
                      aa_threshold=0.05)
    assert two.plan["supersample"] == 2 and four.plan["supersample"] == 4
    assert 3.0 < four.plan["rays"] / two.plan["rays"] < 4.5
    assert two.plan["rays"] < adaptive.plan["rays"] < four.plan["rays"] + two.plan["rays"]
    ref = load_reference("glass_sphere_ior1.5")
    small = ref.reshape(64, 4, 64, 4, 4).mean(axis=(1, 3))
    # [2 x 2: 0.074, adaptive 0.035, 4 x 4: 0.022]
    assert relative_mae(adaptive.linear, small) < 0.6 * relative_mae(two.linear, small)


def test_default_grid_is_finer_on_rough_glass_only(reference_env, scene_cache):
    """With the default grid, pixels whose centre ray meets rough glass trace ROUGH_EXTRA more
    rays a side (their lobes are sampled with the pixel's rays): the frosted sphere gets more
    rays and less error than the plain grid; smooth glass is traced exactly as before."""
    from renderer.methods.raytrace import ROUGH_EXTRA, default_supersample
    assert ROUGH_EXTRA >= 1
    name = "frosted_sphere_ior1.5_r0.3"
    ref = load_reference(name)
    ss = default_supersample(ref.shape[1], ref.shape[0])
    plain = render(name, reference_env, scene_cache, supersample=ss)
    default = render(name, reference_env, scene_cache)
    assert plain.plan["rough_pixels"] == 0 and default.plan["rough_pixels"] > 0.2 * ref.shape[0] ** 2
    assert default.plan["rays"] > 1.3 * plain.plan["rays"]
    e_plain, e_default = relative_mae(plain.linear, ref), relative_mae(default.linear, ref)
    assert e_default < 0.9 * e_plain, (e_plain, e_default)
    smooth = "glass_sphere_ior1.5"
    a = render(smooth, reference_env, scene_cache, size=48)
    b = render(smooth, reference_env, scene_cache, size=48, supersample=default_supersample(48, 48))
    assert a.plan["rough_pixels"] == 0
    np.testing.assert_array_equal(a.linear, b.linear)


# (roughness, relative mean absolute error limit over the sphere, limit on the rim's mean
# bias). Measured at 32 px against 128 paths a pixel: roughness 1 error 0.067 (mirror
# direction: 0.154), rim bias +0.002 (+0.045); 0.6: 0.063 (0.079), +0.009 (-0.036). At 0.6 the
# error is mostly the paths' noise; the rim's mean tells the two directions apart.
@pytest.mark.parametrize("roughness,limit,rim_limit", [(1.0, 0.10, 0.02), (0.6, 0.075, 0.02)])
def test_rough_metal_reflection_follows_the_lobe_not_the_mirror(roughness, limit, rim_limit, reference_env):
    """glTF's default material (white, metallic 1) under the court: the tree's reflection child
    reads the prefiltered sky along the lobe's dominant direction, so it agrees with the path
    integrator, which samples the GGX lobe, over the pixels the sphere covers whole and on its
    rim (outer 30% of the radius), where the mirror direction it read before looks too far
    toward the horizon."""
    from test_render_physics import sphere_asset
    asset = sphere_asset(1.0, roughness)
    size = 32
    opts = RenderOptions(width=size, height=size, yaw=30.0, pitch=20.0, tonemap="none")
    tree = render_raytrace(asset, reference_env, opts).linear
    path = render_raytrace(asset, reference_env, replace(opts, integrator="path", samples=128,
                                                         noise=0.0, bounces=2)).linear
    mask = (tree[..., 3] > 0.999) & (path[..., 3] > 0.999)
    err = relative_mae(tree, path, mask)
    yy, xx = np.mgrid[:size, :size]
    radius = np.hypot(yy - (size - 1) / 2, xx - (size - 1) / 2)
    rim = mask & (radius > 0.7 * radius[mask].max())
    bias = tree[..., :3][rim].mean() / path[..., :3][rim].mean() - 1
    assert err < limit and abs(bias) < rim_limit, (roughness, err, bias)


def test_rough_reflections_probe_their_lobe_where_geometry_fills_it(assets, tmp_path, monkeypatch):
    """SimpleInstancing (125 white rough-metal cubes, glTF's default material): with the
    children drawn from their lobes (ROUGH_PROBE) neighbours are met by part of a pixel's rays,
    so the frame differs from children sent along the dominant direction; on a convex sphere
    every child escapes and reads its dominant direction either way: the same frame. The
    compiled kernel hands on each child's look as its numpy twin does."""
    from test_render_physics import sphere_asset

    from pipeline.bake import bake_asset, bake_environment
    from renderer.methods import raytrace
    env = bake_environment("footprint_court", tmp_path, face_size=64)
    cubes = bake_asset(assets / "gltf-samples" / "SimpleInstancing" / "glTF" / "SimpleInstancing.gltf", tmp_path)
    sphere = sphere_asset(1.0, 0.8)
    opts = RenderOptions(width=40, height=40, yaw=30.0, pitch=20.0, tonemap="none")
    assert raytrace.ROUGH_PROBE > 0
    probed = {k: render_raytrace(a, env, opts) for k, a in (("cubes", cubes), ("sphere", sphere))}
    monkeypatch.setattr(raytrace, "KERNEL", False)
    twin = render_raytrace(cubes, env, opts)
    assert twin.plan["rays"] == probed["cubes"].plan["rays"]
    np.testing.assert_allclose(twin.linear, probed["cubes"].linear, atol=1e-4)
    monkeypatch.setattr(raytrace, "KERNEL", True)
    monkeypatch.setattr(raytrace, "ROUGH_PROBE", 0.0)
    np.testing.assert_allclose(render_raytrace(sphere, env, opts).linear, probed["sphere"].linear, atol=1e-6)
    along = render_raytrace(cubes, env, opts).linear
    covered = probed["cubes"].linear[..., 3] > 0.999
    assert np.abs(along[..., :3] - probed["cubes"].linear[..., :3])[covered].max() > 0.02


@pytest.mark.parametrize("name", ["glass_bunny_ior1.5", "frosted_sphere_ior1.5_r0.3",
                                  "textured_glass_sphere_ior1.5"])
def test_frame_is_the_same_at_any_thread_count(name, reference_env, scene_cache):
    """The compiled kernels run their rows in fixed chunks over numba's threads and pack the
    outputs in row order: one thread and every thread give the same pixels, bit for bit (the
    sum of a pixel's rays would move in the last bits if the children came in another order)."""
    import numba

    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = render(name, reference_env, scene_cache, size=40)
    finally:
        numba.set_num_threads(threads)
    every = render(name, reference_env, scene_cache, size=40)
    assert np.array_equal(one.linear, every.linear)
    assert one.plan["rays"] == every.plan["rays"]


def test_compiled_environment_read_is_the_numpy_one(reference_env, scene_cache, monkeypatch):
    """env_kernel.sample_env (every row in one pass, mips read a chunk at a time) gives the
    numpy grouping's radiance to the bit: directions on every face and edge, roughness on and
    between the levels, below 0, above 1; and a frame that reads rough lobes is unchanged."""
    from renderer.methods import env_kernel, raytrace

    rng = np.random.default_rng(7)
    d = rng.normal(size=(5000, 3))
    d[:600] = np.round(d[:600])  # axes and cube edges (ties between faces)
    d[:600][~d[:600].any(axis=1)] = (0.0, 0.0, 1.0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    levels = len(reference_env.specular)
    rough = np.concatenate([rng.uniform(-0.2, 1.2, 3000), np.arange(2000) % levels / (levels - 1)])
    kernel = env_kernel.sample_env(env_kernel.cube_levels(reference_env.specular), d, rough,
                                   env_kernel.S_AXIS, env_kernel.S_SIGN, env_kernel.T_AXIS,
                                   env_kernel.T_SIGN)
    assert np.array_equal(kernel, raytrace._env(reference_env, d, rough))

    compiled = render("frosted_sphere_ior1.5_r0.3", reference_env, scene_cache, size=32,
                      env_rotation=30.0)
    monkeypatch.setattr(raytrace._Environment, "radiance", lambda self, d, r: raytrace._env(
        self.baked, d if self.to_env is None else d @ self.to_env.T, r))
    numpy = render("frosted_sphere_ior1.5_r0.3", reference_env, scene_cache, size=32,
                   env_rotation=30.0)
    assert np.array_equal(compiled.linear, numpy.linear)
