"""The Khronos lobes in the path tracer (renderer.methods.path_bsdf): a white furnace per
lobe (energy at most 1, and 1 where the lobe conserves it), each lobe's sampling against the
integral of its evaluation, the stored albedo tables against fresh quadrature, on the Khronos
test models in tests/assets/gltf-samples each lobe changes the pixels of the meshes that use
it, and (no Khronos model of them in tests/assets) diffuse transmission on a back-lit sheet and
dispersion on a glass sphere."""
from __future__ import annotations

import numpy as np
import pytest
from test_material_samples import luminance, strip, windows
from test_raytrace_path import _path, _sphere
from test_render_physics import constant_env

from core.baked import BakedAsset
from core.options import RenderOptions
from pipeline.bake import bake_asset, bake_environment
from renderer import render
from renderer.methods.raytrace import render_raytrace

# (material, channel statistic, lower, upper) of the sphere's centre under a white sky of 1.
# "max": the brightest channel (a coloured Fresnel returns 1 there and less in the others).
# Conserving: a coat or a white sheen over white Lambert (the base gets what they reflect
# less, view albedo scaling), smooth glass under a coat, a diffuse-transmitting shell (what
# passes through leaves the other side), dispersive glass. Below 1 by what they lose: a rough
# coat's single scattering, a sheen over black (E_sheen < 1). Iridescent plastic and coloured
# specular conserve in their brightest channel (diffuse scaled by 1 - max F).
LAMBERT = dict(ior=1.0, roughness=1.0)
FURNACE = [
    ("clearcoat_smooth", dict(LAMBERT, clearcoat=1.0, clearcoat_roughness=0.0), "mean", 0.98, 1.02),
    ("clearcoat_rough", dict(LAMBERT, clearcoat=1.0, clearcoat_roughness=0.6), "mean", 0.95, 1.01),
    ("clearcoat_glass", dict(transmission=1.0, roughness=0.0, clearcoat=1.0), "mean", 0.98, 1.02),
    ("sheen_white", dict(LAMBERT, sheen_color=(1.0, 1.0, 1.0), sheen_roughness=0.5), "mean", 0.97, 1.02),
    ("sheen_over_black", dict(LAMBERT, base_color=(0.0, 0.0, 0.0, 1.0), sheen_color=(1.0, 1.0, 1.0),
                              sheen_roughness=0.5), "mean", 0.01, 0.3),
    ("specular_coloured", dict(ior=1.5, roughness=0.4, specular=0.7, specular_color=(1.0, 0.4, 0.2)),
     "max", 0.96, 1.02),
    ("iridescence", dict(ior=1.5, roughness=0.3, iridescence=1.0, iridescence_thickness_range=(100.0, 400.0)),
     "max", 0.93, 1.02),
    ("iridescent_metal", dict(metallic=1.0, roughness=0.3, iridescence=1.0), "max", 0.9, 1.02),
    ("anisotropy", dict(metallic=1.0, roughness=0.4, anisotropy_strength=0.8), "mean", 0.95, 1.03),
    ("diffuse_transmission", dict(LAMBERT, diffuse_transmission=1.0), "mean", 0.97, 1.02),
    ("diffuse_transmission_half", dict(LAMBERT, diffuse_transmission=0.5), "mean", 0.97, 1.02),
    ("dispersion", dict(transmission=1.0, roughness=0.0, dispersion=5.0), "mean", 0.98, 1.02),
]


@pytest.mark.parametrize("label,mat,stat,lo,hi", FURNACE, ids=[f[0] for f in FURNACE])
def test_white_furnace_per_khronos_lobe(label, mat, stat, lo, hi):
    frame = render_raytrace(_sphere("lobe-" + label, metallic=mat.pop("metallic", 0.0),
                                    roughness=mat.pop("roughness", 0.5), **mat),
                            constant_env(1.0), _path())
    rgb = frame.linear[..., :3]
    assert np.isfinite(rgb).all() and rgb.min() >= 0
    centre = rgb[12:28, 12:28].reshape(-1, 3).mean(axis=0)
    value = centre.max() if stat == "max" else centre.mean()
    assert lo <= value <= hi, (label, centre)
    assert centre.max() <= 1.03, (label, centre)  # no channel makes energy


def _bsdf(n: int, mu: float, ior: float, **fields):
    from renderer.methods import path_bsdf
    from renderer.methods.trace_material import Hits
    h = Hits.empty(n)
    h.normal[:] = h.clearcoat_normal[:] = (0.0, 0.0, 1.0)
    h.base[:], h.roughness[:] = 1.0, 0.5
    for k, v in fields.items():
        getattr(h, k)[:] = v
    up = np.tile([0.0, 0.0, 1.0], (n, 1))
    wo = np.tile([np.sqrt(1 - mu * mu), 0.0, mu], (n, 1))
    return path_bsdf.build(h, up, up.copy(), wo, np.full(n, ior), True)


CONSISTENCY = [
    ("plastic", 1.5, dict()),
    ("aniso_metal_along", 1.5, dict(metallic=1.0, roughness=0.4, anisotropy=0.8, anisotropy_t=(1.0, 0.0, 0.0))),
    ("aniso_metal_across", 1.5, dict(metallic=1.0, roughness=0.4, anisotropy=0.8, anisotropy_t=(0.0, 1.0, 0.0))),
    ("coat", 1.0, dict(roughness=1.0, clearcoat=1.0, clearcoat_roughness=0.3)),
    ("sheen_over_black", 1.0, dict(base=0.0, sheen_color=1.0, sheen_roughness=0.5)),
    ("diffuse_transmission", 1.0, dict(roughness=1.0, diffuse_transmission=0.6)),
    ("iridescence", 1.5, dict(iridescence=1.0, iridescence_thickness=300.0)),
    ("specular", 1.5, dict(specular=0.7, specular_color=(1.0, 0.4, 0.2), roughness=0.4)),
]


@pytest.mark.parametrize("label,ior,fields", CONSISTENCY, ids=[c[0] for c in CONSISTENCY])
def test_sampling_matches_evaluation(label, ior, fields):
    """What the paths estimate (f cos / pdf over the BSDF's own samples) equals the integral of
    f cos over the sphere by uniform quadrature, to 1.5%: the pdf is the density the sampler
    draws, every lobe included (a mismatch is a bias no furnace at normal incidence sees)."""
    n, mu = 200_000, 0.6
    rng = np.random.default_rng(7)
    b = _bsdf(n, mu, ior, **fields)
    u = rng.random((5, n))
    glass = (u[0] >= b.p_coat + b.p_sheen) & (u[1] >= b.p_metal + b.p_plastic)
    wi, _, valid = b.sample(*u)
    f, p = b.eval(wi)
    use = (p > 0) & valid & ~glass
    est = np.where(use[:, None], f / np.maximum(p, 1e-300)[:, None], 0.0).mean(axis=0)
    z = rng.random(n) * 2 - 1
    phi = rng.random(n) * 2 * np.pi
    r = np.sqrt(1 - z * z)
    f_u, p_u = b.eval(np.stack([r * np.cos(phi), r * np.sin(phi), z], -1))
    ref = (f_u * 4 * np.pi).mean(axis=0)
    assert np.all(np.abs(est - ref) <= 0.015 * np.maximum(ref, 0.05)), (label, est, ref)
    # the pdf integrates to at most the reflective share (microfacet samples below the
    # horizon carry no density)
    assert (p_u * 4 * np.pi).mean() <= b.p_reflective[0] + 0.02


# --- the lobes on the Khronos test models (tests/assets/gltf-samples) -------------------------
SIZE = 96


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("path-lobe-cache")


@pytest.fixture(scope="module")
def env(cache):
    return bake_environment("footprint_court", cache, face_size=64)


@pytest.fixture(scope="module")
def sample(assets, cache):
    def load(name: str) -> BakedAsset:
        return bake_asset(assets / "gltf-samples" / name / "glTF" / f"{name}.gltf", cache)
    return load


def popts(**kw) -> RenderOptions:
    """The path tracer, face-on (the boards lie in the XY plane), linear, 4 passes."""
    return RenderOptions(**{"width": SIZE, "height": SIZE, "tonemap": "none", "yaw": 0.0, "pitch": 0.0,
                            "background": "env", "method": "raytrace", "integrator": "path",
                            "samples": 4, "noise": 0.0, **kw})


def _traced(asset, env, o):
    frame = render(asset, env, o)
    assert np.isfinite(frame.linear).all() and frame.plan["nonfinite"] == 0
    return frame.linear


def test_clearcoat_changes_exactly_the_coated_tiles(sample, env):
    """ClearCoatTest: every coated tile is brighter than with the coat removed (by > 10% of
    its mean: the coat's reflection of the court, measured +20% to +140%); uncoated tiles
    stay within 2% (only light bounced off a coated neighbour may differ: at 4 passes a few
    such paths, measured up to +1.3% on the darkest tile, +0.8% at 16 passes)."""
    asset = sample("ClearCoatTest")
    full = _traced(asset, env, popts())
    bare = _traced(strip(asset, clearcoat=0.0), env, popts())
    coated = windows(asset, popts(), lambda m: m.material.clearcoat > 0)
    plain = windows(asset, popts(), lambda m: m.material.clearcoat == 0 and "Label" not in m.name)
    assert len(coated) >= 6 and len(plain) >= 3
    for i, r, c in coated:
        a, b = luminance(full[r, c]).mean(), luminance(bare[r, c]).mean()
        assert a > 1.1 * b, (asset.meshes[i].name, a, b)
    for i, r, c in plain:
        a, b = luminance(full[r, c]).mean(), luminance(bare[r, c]).mean()
        assert abs(a - b) <= 0.02 * max(b, 0.01), (asset.meshes[i].name, a, b)


def test_sheen_lights_a_dark_cloth(sample, env):
    """SheenCloth with a near-black base (0.01): with the sheen the cloth's blue channel (its
    navy sheen texture) is at least 1.3 times what it is without (measured at 96 px: 1.45,
    the raster 1.54; the raster's sheen IBL is E_sheen x irradiance, an approximation)."""
    asset = strip(sample("SheenCloth"), base_color=(0.01, 0.01, 0.01, 1.0), base_color_texture=None)
    assert any(m.material.uses("sheen") for m in asset.meshes)
    o = popts(background="transparent")
    full = _traced(asset, env, o)
    cover = full[..., 3] > 0.99
    lit = full[..., 2][cover].mean()
    bare = _traced(strip(asset, sheen_color=(0.0, 0.0, 0.0)), env, o)[..., 2][cover].mean()
    assert lit > 1.3 * bare, (lit, bare)


def test_iridescence_colours_the_lamp_globe(sample, env):
    """IridescenceLamp: the film changes the globe by more than 5% of its mean, and not as a
    grey scale (the change differs between channels by a third or more)."""
    asset = sample("IridescenceLamp")
    o = popts(yaw=30.0, pitch=15.0)
    wins = windows(asset, o, lambda m: m.material.uses("iridescence") and m.material.transmission > 0)
    assert wins

    def pixels(img):
        return np.concatenate([img[r, c, :3].reshape(-1, 3) for _, r, c in wins]).astype(np.float64)
    film = pixels(_traced(asset, env, o))
    bare = pixels(_traced(strip(asset, iridescence=0.0), env, o))
    change = np.abs(film - bare).mean(0)
    assert change.mean() > 0.05 * bare.mean(), (change, bare.mean())
    assert change.max() > 1.33 * change.min(), change


def test_anisotropy_changes_the_brushed_donuts(sample, env):
    """AnisotropyRotationTest: the anisotropic meshes' pixels move by more than 5% of their
    mean (mean absolute change) against the same render with the strength at 0."""
    asset = sample("AnisotropyRotationTest")
    o = popts(pitch=20.0, fov=20.0)
    wins = windows(asset, o, lambda m: m.material.uses("anisotropy"))
    assert len(wins) == 4
    full = _traced(asset, env, o)
    iso = _traced(strip(asset, anisotropy_strength=0.0), env, o)
    for i, r, c in wins:
        a, b = luminance(full[r, c]), luminance(iso[r, c])
        assert np.abs(a - b).mean() > 0.05 * b.mean(), (asset.meshes[i].name, np.abs(a - b).mean(), b.mean())


def test_specular_factor_rows_rise(sample, env):
    """SpecularTest: along the specular-factor row the black spheres reflect more with each
    step (F0 and F90 scale with the factor)."""
    asset = sample("SpecularTest")
    o = popts(width=128, height=128, samples=8)
    img = luminance(_traced(asset, env, o))
    wins = windows(asset, o, lambda m: m.name.startswith("1.") or m.material.name[1:].startswith("1."))
    wins.sort(key=lambda w: w[2].start)
    values = [img[r, c].mean() for _, r, c in wins]
    assert len(values) == 5, [asset.meshes[i].name for i, _, _ in wins]
    assert all(b > a for a, b in zip(values, values[1:])), values


def test_stored_albedo_tables_match_fresh_quadrature():
    """renderer/methods/path_bsdf_tables.npz (the directional albedos the BSDF reads) against
    independent Monte Carlo of the same lobes at cells and between them, to 0.01."""
    from renderer.methods import path_bsdf as pb
    from renderer.methods.optics import reflect

    assert pb.TABLES.is_file()
    rng = np.random.default_rng(11)
    n = 200_000
    for mu, ax, ay, phi in ((0.9, 0.25, 0.25, 0.0), (0.45, 0.6, 0.6, 0.0), (0.7, 0.7, 0.16, 0.4), (0.3, 1.0, 0.05, 1.3)):
        st = np.sqrt(1 - mu * mu)
        wo = np.tile([st * np.cos(phi), st * np.sin(phi), mu], (n, 1))
        wi = reflect(-wo, pb.ggx_vndf(wo, ax, ay, rng.random(n), rng.random(n)))
        lv = pb.ggx_lambda(wo[:, 0], wo[:, 1], wo[:, 2], ax, ay)
        ll = pb.ggx_lambda(wi[:, 0], wi[:, 1], np.maximum(wi[:, 2], 1e-7), ax, ay)
        e = np.where(wi[:, 2] > 0, (1 + lv) / (1 + lv + ll), 0.0).mean()
        got = (pb.ggx_albedo(np.array([mu]), np.array([ax]))[0] if ax == ay else
               pb.ggx_albedo_aniso(np.array([mu]), np.array([phi]), np.array([ax]), np.array([ay]))[0])
        assert abs(got - e) < 0.01, (mu, ax, ay, phi, got, e)
    for mu, r in ((1.0, 0.5), (0.5, 0.3), (0.2, 0.8)):
        z = rng.random(n)
        ph = rng.random(n) * 2 * np.pi
        wi = np.stack([np.sqrt(1 - z * z) * np.cos(ph), np.sqrt(1 - z * z) * np.sin(ph), z], -1)
        h = wi + np.array([np.sqrt(1 - mu * mu), 0.0, mu])
        n_h = h[:, 2] / np.linalg.norm(h, axis=-1)
        e = (pb.sheen_dv(np.full(n, mu), z, n_h, np.full(n, r)) * z).mean() * 2 * np.pi
        got = pb.sheen_albedo(np.array([mu]), np.array([r]))[0]
        assert abs(got - e) < 0.01, (mu, r, got, e)


def _quad(label: str, **fields) -> BakedAsset:
    """A double-sided 2 x 2 quad in the XY plane facing +Z (the camera's side), IOR 1."""
    import dataclasses

    from core.baked import BakedMesh
    from core.scene import Material
    pos = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    mat = dataclasses.replace(Material(metallic=0.0, roughness=1.0, ior=1.0, double_sided=True), **fields)
    mesh = BakedMesh("quad", pos, np.tile([0, 0, 1], (4, 1)).astype(np.float32),
                     np.array([[0, 1, 2], [0, 2, 3]], np.uint32), mat, np.eye(4)[None])
    return BakedAsset(key=f"quad-{label}", source="quad", format="test", meshes=[mesh], textures=[],
                      bounds=np.array([[-1.0, -1, 0], [1, 1, 0]]))


def test_diffuse_transmission_shows_the_light_behind_a_leaf():
    """A thin diffusing sheet, dark sky (0.05) on the camera's side and bright (1) behind it:
    with diffuse transmission 1 and colour (1, 0.3, 0.3) the sheet glows red with the light
    from behind, near (1, 0.3, 0.3) (thin-walled Lambert: what passes is the colour); without
    it the sheet only reflects the dark front (about 0.05)."""
    from test_render_physics import make_env
    env = make_env(lambda d: np.where(d[..., 2:3] < 0, 1.0, 0.05) * np.ones(3), key="back-lit")
    o = _path(samples=16, size=32, yaw=0.0, pitch=0.0)
    lit = render_raytrace(_quad("dt", diffuse_transmission=1.0, diffuse_transmission_color=(1.0, 0.3, 0.3)),
                          env, o).linear[10:22, 10:22, :3].reshape(-1, 3).mean(0)
    bare = render_raytrace(_quad("no-dt"), env, o).linear[10:22, 10:22, :3].reshape(-1, 3).mean(0)
    assert np.allclose(lit, [1.0, 0.3, 0.3], atol=0.06), lit
    assert np.allclose(bare, 0.05, atol=0.01), bare


def test_dispersion_splits_the_channels_of_a_glass_sphere():
    """A smooth glass sphere under a sky whose colour turns with direction: with dispersion 5
    (IOR spread 0.0625 between red and blue) the refracted picture differs between the
    channels' own IORs, so the frame moves against the plain sphere's by more than the noise
    floor (the same options render the plain sphere twice identically)."""
    from test_render_physics import make_env
    env = make_env(lambda d: np.stack([0.6 + 0.4 * np.sin(6 * d[..., 0]), 0.6 + 0.4 * np.sin(6 * d[..., 1]),
                                       0.6 + 0.4 * np.cos(6 * d[..., 0])], -1), key="stripes")
    o = _path(samples=8, size=32)
    plain = render_raytrace(_sphere("plain", transmission=1.0, roughness=0.0), env, o).linear[..., :3]
    again = render_raytrace(_sphere("plain", transmission=1.0, roughness=0.0), env, o).linear[..., :3]
    disp = render_raytrace(_sphere("disp", transmission=1.0, roughness=0.0, dispersion=5.0), env, o).linear[..., :3]
    assert np.array_equal(plain, again)
    assert np.isfinite(disp).all()
    assert np.abs(disp - plain).mean() > 0.01, np.abs(disp - plain).mean()
