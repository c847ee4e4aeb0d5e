"""The Khronos lobes in the path tracer (renderer.methods.path_bsdf): a white furnace per
lobe (energy at most 1, and 1 where the lobe conserves it), and on the Khronos test models in
tests/assets/gltf-samples each lobe changes the pixels of exactly the meshes that use it."""
from __future__ import annotations

import numpy as np
import pytest
from test_raytrace_path import _path, _sphere
from test_render_physics import constant_env

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
