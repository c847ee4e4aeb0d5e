"""The Khronos material lobes (specular, IOR, clearcoat, sheen) under a uniform environment:
white-furnace energy checks per lobe against the baked LUT, which the numpy twins in
test_environment.py check in turn."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_render_physics import _LUT, constant_env, interior, make_env, opts, sphere_asset, sphere_geometry

from core.baked import BakedAsset
from core.options import RenderOptions
from renderer.raster.render import render

ENV = constant_env(1.0)
N = _LUT.shape[0]


def lobe_sphere(**material) -> BakedAsset:
    """The unit sphere of test_render_physics with Material fields set."""
    base = material.pop("base_color", (1.0, 1.0, 1.0, 1.0))
    a = sphere_asset(material.pop("metallic", 0.0), material.pop("roughness", 0.5), base)
    mesh = a.meshes[0]
    mat = dataclasses.replace(mesh.material, **material)
    return dataclasses.replace(a, key=f"{a.key}-{sorted(material.items())}",
                               meshes=[dataclasses.replace(mesh, material=mat)])


def furnace(asset: BakedAsset, min_cos: float = 0.2):
    """Linear RGB of the sphere's interior pixels and their N.V."""
    mask, n, d = sphere_geometry(opts())
    sel = interior(mask, n, d, min_cos)
    img = render(asset, ENV, opts()).linear[..., :3]
    return img[sel], np.einsum("...i,...i->...", n, -d)[sel]


def lut(nv: np.ndarray, roughness: float, channel: int) -> np.ndarray:
    row = _LUT[min(int(roughness * N), N - 1)]
    return row[np.clip((nv * N - 0.5).astype(int), 0, N - 1), channel]


def schlick(f0, nv):
    return f0 + (1 - f0) * (1 - nv) ** 5


# Tolerances: 0.02 mean absolute error against the LUT-based expectation covers the LUT's
# nearest-texel lookup here vs the renderer's bilinear one, half-float targets and MSAA edges;
# no pixel may exceed 1 + 0.01 (the frame's float precision): a lobe must never create energy.

@pytest.mark.parametrize("cc_roughness", [0.0, 0.5, 1.0])
def test_clearcoat_over_white_lambert_furnace(cc_roughness):
    """White Lambert base (specular 0: the base reflects exactly the environment's 1) under a
    full coat. The coat removes F_coat(N.V) and returns its single-scattering split sum
    0.04 A + B: the difference is the coat's loss (the split-sum's, up to 0.05 at roughness 1)."""
    px, nv = furnace(lobe_sphere(specular=0.0, clearcoat=1.0, clearcoat_roughness=cc_roughness))
    expected = 1 - schlick(0.04, nv) + 0.04 * lut(nv, cc_roughness, 0) + lut(nv, cc_roughness, 1)
    assert np.abs(px - expected[:, None]).mean() < 0.02
    assert px.max() <= 1.01
    # never more taken away than the coat's Fresnel reflects (the base beneath stays)
    assert (px.min(axis=1) >= 1 - schlick(0.04, nv) - 0.01).all()


@pytest.mark.parametrize("sheen_roughness", [0.3, 0.6, 1.0])
def test_sheen_on_black_furnace(sheen_roughness):
    """Black base, white sheen: the frame is the sheen albedo E plus what is left of the
    base's dielectric specular (scaled by 1 - E), never above 1."""
    px, nv = furnace(lobe_sphere(base_color=(0.0, 0.0, 0.0, 1.0), roughness=0.5,
                                 sheen_color=(1.0, 1.0, 1.0), sheen_roughness=sheen_roughness))
    e = lut(nv, sheen_roughness, 2)
    spec = 0.04 * lut(nv, 0.5, 0) + lut(nv, 0.5, 1)
    expected = spec * (1 - e) + e
    assert np.abs(px - expected[:, None]).mean() < 0.02
    assert px.max() <= 1.01
    assert px.mean() > spec.mean() + 0.03  # sheen makes a black cloth visible


@pytest.mark.parametrize("specular,tint", [(0.0, 1.0), (1.0, 1.0), (1.0, 100.0)])
def test_specular_extremes_furnace(specular, tint):
    """Black dielectric: it reflects only its specular lobe, f0 A + f90 B with f0 = min(0.04
    tint, 1) x specular and f90 = specular, plus the default multiple-scattering share
    (Fdez-Aguera: Ems FssEss Favg / (1 - Ems Favg)). Specular 0 is black; tint 100 clamps F0
    to 1 and reflects everything, still never above 1."""
    px, nv = furnace(lobe_sphere(base_color=(0.0, 0.0, 0.0, 1.0), roughness=0.3,
                                 specular=specular, specular_color=(tint,) * 3))
    f0 = min(0.04 * tint, 1.0) * specular
    a, b = lut(nv, 0.3, 0), lut(nv, 0.3, 1)
    fss = f0 * a + specular * b
    ems, favg = 1 - (a + b), f0 + (1 - f0) / 21
    expected = fss + ems * fss * favg / (1 - ems * favg)
    assert np.abs(px - expected[:, None]).mean() < 0.02
    assert px.max() <= 1.01


def test_ior_sets_f0_of_an_opaque_dielectric():
    """KHR_materials_ior on an opaque material: F0 = ((ior - 1) / (ior + 1))^2, so the black
    sphere reflects more as the IOR rises (ior 1 leaves only Schlick's grazing term, F90 = 1)."""
    means = {}
    for ior in (1.0, 1.5, 2.5):
        px, nv = furnace(lobe_sphere(base_color=(0.0, 0.0, 0.0, 1.0), roughness=0.2, ior=ior),
                         min_cos=0.5)
        means[ior] = px.mean()
        f0 = ((ior - 1) / (ior + 1)) ** 2
        expected = f0 * lut(nv, 0.2, 0) + lut(nv, 0.2, 1)
        assert np.abs(px - expected[:, None]).mean() < 0.02, ior
    assert means[1.0] < means[1.5] - 0.02 and means[1.5] < means[2.5] - 0.05


def test_no_extension_compiles_no_lobe():
    """The switches: a plain material defines none of the lobes (it costs what it did)."""
    from core.lobes import SHADER_LOBES
    plain = sphere_asset(0.0, 0.5).meshes[0].material
    assert not any(plain.uses(lobe) for lobe in SHADER_LOBES)
    assert lobe_sphere(clearcoat=1.0).meshes[0].material.uses("clearcoat")


def test_material_debug_views_isolate_one_lobe():
    """`material_debug`: specular shows F0 (ior 2: 1/9); clearcoat is black without a coat;
    base is the frame with the coat taken off; sheen is E x colour under uniform light."""
    px, _ = furnace_opts(lobe_sphere(base_color=(0.0, 0.0, 0.0, 1.0), ior=2.0), material_debug="specular")
    assert np.abs(px - 1 / 9).max() < 2e-3
    px, _ = furnace_opts(lobe_sphere(), material_debug="clearcoat")
    assert px.max() < 1e-4
    coated, _ = furnace_opts(lobe_sphere(clearcoat=1.0, clearcoat_roughness=0.2), material_debug="base")
    bare, _ = furnace_opts(lobe_sphere())
    assert np.abs(coated - bare).max() < 2e-3
    px, nv = furnace_opts(lobe_sphere(sheen_color=(0.5, 0.5, 0.5), sheen_roughness=0.5),
                          material_debug="sheen")
    assert np.abs(px - 0.5 * lut(nv, 0.5, 2)[:, None]).mean() < 0.02


def furnace_opts(asset: BakedAsset, **options):
    mask, n, d = sphere_geometry(opts())
    sel = interior(mask, n, d, 0.2)
    img = render(asset, ENV, opts(**options)).linear[..., :3]
    return img[sel], np.einsum("...i,...i->...", n, -d)[sel]


@pytest.mark.parametrize("thickness", [250.0, 400.0, 550.0])
def test_iridescence_thin_film_against_numpy_twin_and_furnace(thickness):
    """KHR_materials_iridescence on a black dielectric: the debug view (the film's reflectance
    at N.V) matches tests/lobes_numpy.py's twin within 0.01 mean (half floats, the bilinear
    normal across a pixel); under uniform light the frame is coloured (the film's
    interference, where the bare sphere is grey) and never above 1 + 0.01."""
    from lobes_numpy import thin_film_fresnel
    film = dict(base_color=(0.0, 0.0, 0.0, 1.0), roughness=0.3, iridescence=1.0,
                iridescence_ior=1.3, iridescence_thickness_range=(100.0, thickness))
    px, nv = furnace_opts(lobe_sphere(**film), material_debug="iridescence")
    twin = thin_film_fresnel(nv, 1.3, thickness, np.full(3, 0.04))
    assert np.abs(px - twin).mean() < 0.01
    lit, _ = furnace(lobe_sphere(**film))
    assert lit.max() <= 1.01
    chroma = (lit.max(axis=1) - lit.min(axis=1)).mean() / lit.mean()
    bare, _ = furnace(lobe_sphere(base_color=(0.0, 0.0, 0.0, 1.0), roughness=0.3))
    assert chroma > 0.1 and (bare.max(axis=1) - bare.min(axis=1)).max() < 1e-3, chroma


def test_diffuse_transmission_furnace_and_back_light():
    """KHR_materials_diffuse_transmission on a white dielectric: under uniform light, what
    the diffuse lobe no longer reflects it lets through from behind, so the frame stays 1
    (within 0.02, never above 1.01). Lit only from the camera's half (+Z) of the
    environment, the front of a sphere transmitting half its diffuse reflects less: that half
    now comes from the dark hemisphere behind."""
    px, _ = furnace(lobe_sphere(diffuse_transmission=1.0))
    assert np.abs(px - 1).mean() < 0.02 and px.max() <= 1.01
    half = make_env(lambda d: np.where(d[..., 2:3] > 0, 1.0, 0.0) * np.ones(3), key="front-half")
    mask, n, d = sphere_geometry(opts())
    sel = interior(mask, n, d, 0.5)
    plain = render(lobe_sphere(), half, opts()).linear[..., :3][sel].mean()
    through = render(lobe_sphere(diffuse_transmission=0.5), half, opts()).linear[..., :3][sel].mean()
    assert through < plain - 0.05, (through, plain)


@pytest.mark.parametrize("method", ["single", "wyman", "raytrace"])
def test_dispersion_refracts_each_channel_by_its_ior(method):
    """KHR_materials_dispersion in every refraction method: each channel of a dispersive
    sphere (dispersion 5: IORs 1.4375 / 1.5 / 1.5625) is that channel of a plain sphere at the
    channel's IOR (within 1% of the mean), and the channels' IORs differ visibly (the plain
    spheres at the red and blue IORs differ by over 1% of the whole frame's mean, 2.6%
    measured for single, the sphere covering a third of the frame)."""
    from bench import scenes
    from pipeline.bake import bake_environment

    env = bake_environment("footprint_court", face_size=64)
    o = RenderOptions(width=96, height=96, method=method, tonemap="none", background="env",
                      yaw=30.0, pitch=15.0)  # the view the tolerances were measured at

    def frame(name, material):
        spec = scenes.SceneSpec(name, "sphere", material)
        return render(scenes.baked_asset(spec), env, o).linear[..., :3]
    mat = scenes.glass(1.5, dispersion=5.0)
    iors = mat.channel_iors()
    assert iors == pytest.approx((1.4375, 1.5, 1.5625))
    split = frame("dispersive", mat)
    for c, ior in enumerate(iors):
        plain = frame(f"plain-{ior}", scenes.glass(ior))
        scale = plain[..., c].mean()
        assert np.abs(split[..., c] - plain[..., c]).mean() < 0.01 * scale, (c, ior)
    red, blue = frame("red", scenes.glass(iors[0])), frame("blue", scenes.glass(iors[2]))
    assert np.abs(red - blue).mean() > 0.01 * red.mean()
