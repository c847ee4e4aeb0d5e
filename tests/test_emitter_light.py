"""Emissive triangles light their surroundings in the Fresnel tree (renderer.methods.raytrace,
`_emitter_hits`): a grey card under an emissive quad against the analytic form factor and
against the path integrator (which finds the emitter by BSDF sampling alone), the glossy
share split with the mirror child, and the compiled kernels against their numpy twins."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_render_physics import constant_env

from core.baked import BakedAsset, BakedMesh
from core.options import RenderOptions
from core.scene import Material
from renderer.methods import raytrace
from renderer.methods.raytrace import render_raytrace
from renderer.view.framing import asset_camera

HEIGHT = 1.0      # the emitter's plane above the card
HALF = 0.5        # the emitter is 2 HALF square, centred over the card
RADIANCE = 4.0    # its emitted radiance (factor 1 x strength 4)


def _card_under_emitter(grey: float = 0.5, radiance: float = RADIANCE, **card) -> BakedAsset:
    """A 4 x 4 card at z = 0 facing +z, and a one-sided emissive quad at z = HEIGHT facing it
    (seen from above through its culled back), emitting `radiance`."""
    card_pos = np.array([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]], np.float32)
    quad = np.array([[-HALF, -HALF, HEIGHT], [HALF, -HALF, HEIGHT], [HALF, HALF, HEIGHT],
                     [-HALF, HALF, HEIGHT]], np.float32)
    card_mat = Material(name="card", base_color=(grey, grey, grey, 1.0), metallic=0.0, **card)
    glow = Material(name="glow", base_color=(0.0, 0.0, 0.0, 1.0), roughness=1.0, ior=1.0,
                    emissive=(1.0, 1.0, 1.0), emissive_strength=radiance)
    meshes = [BakedMesh("card", card_pos, np.tile([0, 0, 1], (4, 1)).astype(np.float32),
                        np.array([[0, 1, 2], [0, 2, 3]], np.uint32), card_mat, np.eye(4)[None]),
              BakedMesh("glow", quad, np.tile([0, 0, -1], (4, 1)).astype(np.float32),
                        np.array([[0, 2, 1], [0, 3, 2]], np.uint32), glow, np.eye(4)[None])]
    return BakedAsset(key=f"card-under-emitter-{grey}-{radiance}-{sorted(card.items())}", source="test", format="test",
                      meshes=meshes, textures=[], bounds=np.array([[-2.0, -2, 0], [2, 2, HEIGHT]]))


def _options(**kw) -> RenderOptions:
    return RenderOptions(**{"width": 48, "height": 48, "tonemap": "none", "background": "transparent",
                            "yaw": 0.0, "pitch": 0.0, "shadow": 0.0, **kw})


def _corner(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Form factor from a point to an a x b rectangle parallel to it at height HEIGHT with a
    corner straight above it (signed in a and b, so rectangles add and subtract)."""
    x, y = np.abs(a) / HEIGHT, np.abs(b) / HEIGHT
    sx, sy = np.sqrt(1 + x * x), np.sqrt(1 + y * y)
    f = (x / sx * np.arctan(y / sx) + y / sy * np.arctan(x / sy)) / (2 * math.pi)
    return np.sign(a) * np.sign(b) * f


def _analytic(options: RenderOptions, asset: BakedAsset) -> tuple[np.ndarray, np.ndarray]:
    """(pixels on the card, their radiance): albedo x L x form factor to the quad."""
    cam = asset_camera(asset, options)[0]
    d = cam.ray_directions()
    t = -cam.position[2] / d[..., 2]
    p = cam.position + t[..., None] * d
    on = (np.abs(p[..., 0]) < 1.8) & (np.abs(p[..., 1]) < 1.8)
    x, y = p[..., 0], p[..., 1]
    f = (_corner(HALF - x, HALF - y) - _corner(-HALF - x, HALF - y)
         - _corner(HALF - x, -HALF - y) + _corner(-HALF - x, -HALF - y))
    return on, 0.5 * RADIANCE * f


def test_grey_card_matches_the_form_factor_and_the_path_tracer():
    """Lambert (IOR 1: no specular) under a black sky: all its light is the emitter's."""
    asset = _card_under_emitter(roughness=1.0, ior=1.0)
    env = constant_env(0.0)
    frame = render_raytrace(asset, env, _options())
    assert frame.plan["emitters"] == 2  # the quad's two triangles
    tree = frame.linear[..., :3].mean(-1)
    path = render_raytrace(asset, env, _options(integrator="path", samples=64, noise=0.0,
                                                bounces=4)).linear[..., :3].mean(-1)
    on, exact = _analytic(_options(), asset)
    # the card outside the emitter's shadow-free footprint; every pixel on it is lit
    assert on.sum() > 0.5 * on.size and (exact[on] > 0).all()
    mean_exact = exact[on].mean()
    # [measured: tree -0.3%, path -0.3%]
    assert abs(tree[on].mean() / mean_exact - 1) < 0.02, (tree[on].mean(), mean_exact)
    assert abs(path[on].mean() / mean_exact - 1) < 0.03, (path[on].mean(), mean_exact)
    # per pixel: 3 x 3 rays, one emitter point each, stratified [measured: 4.2% rms]
    rel = tree[on] / exact[on] - 1
    assert np.sqrt(np.mean(rel ** 2)) < 0.06
    # the radial falloff follows the form factor (centre over edge)
    centre = on & (exact > 0.8 * exact[on].max())
    edge = on & (exact < 1.5 * exact[on].min())
    ratio = tree[centre].mean() / tree[edge].mean()
    assert abs(ratio / (exact[centre].mean() / exact[edge].mean()) - 1) < 0.05


def test_without_emitter_samples_the_card_is_black(monkeypatch):
    monkeypatch.setattr(raytrace, "EMITTER_SAMPLES", 0)
    asset = _card_under_emitter(roughness=1.0, ior=1.0)
    tree = render_raytrace(asset, constant_env(0.0), _options()).linear[..., :3]
    on, _ = _analytic(_options(), asset)
    assert tree[on].max() == 0.0


@pytest.mark.parametrize("roughness,measured", [(0.05, 0.010), (0.2, 0.039), (0.5, 0.001)])
def test_glossy_share_is_not_counted_twice(roughness, measured):
    """A dark glossy dielectric card (base 0.05, IOR 1.5: the highlight is most of its light).
    Below roughness 0.15 the mirror children that meet the quad take the glossy light, from 0.3
    the emitter samples, between both by trace_lights.mirror_share: the sum agrees with the path
    integrator (BSDF sampling alone) over the card. (A power heuristic between the samples and
    the mirror child, which is no sample of the lobe, counted the tails twice: +10% at 0.2,
    +19% at 0.5.)"""
    asset = _card_under_emitter(0.05, roughness=roughness, ior=1.5)
    env = constant_env(0.0)
    o = _options(width=40, height=40)
    tree = render_raytrace(asset, env, o).linear[..., :3].mean(-1)
    path = render_raytrace(asset, env, dataclasses.replace(o, integrator="path", samples=512,
                                                           noise=0.0, bounces=4)).linear[..., :3].mean(-1)
    on, _ = _analytic(o, asset)
    assert abs(tree[on].mean() / path[on].mean() - 1) < 0.05, (tree[on].mean(), path[on].mean(), measured)


def test_mirror_share_hands_over_between_the_thresholds():
    from renderer.methods import trace_lights
    lo, hi = trace_lights.MIRROR_ROUGH
    share = trace_lights.mirror_share(np.array([0.0, lo, (lo + hi) / 2, hi, 1.0]))
    np.testing.assert_allclose(share, [1.0, 1.0, 0.5, 0.0, 0.0])


def test_compiled_kernel_matches_its_numpy_twin_with_emitters(monkeypatch):
    """The mirror share the kernel hands its children is the twin's: the same frame."""
    asset = _card_under_emitter(roughness=0.2, ior=1.5)
    env = constant_env(0.2)
    fast = render_raytrace(asset, env, _options(width=32, height=32))
    monkeypatch.setattr(raytrace, "KERNEL", False)
    slow = render_raytrace(asset, env, _options(width=32, height=32))
    assert fast.plan["rays"] == slow.plan["rays"]
    np.testing.assert_allclose(fast.linear, slow.linear, atol=1e-4)


def test_compiled_emitter_choice_matches_its_numpy_twin(monkeypatch):
    """trace_kernel.emitter_pick against trace_lights' numpy odds: the same emitter and
    probability at every point, one-sided emitters never chosen from behind."""
    from renderer.methods import trace_lights
    rng = np.random.default_rng(5)
    tri = rng.normal(size=(40, 3, 3))
    em = trace_lights.emitters_of(tri, np.arange(40) % 3, np.array([[1.0, 1, 1], [0, 0, 0], [2, 1, 0.5]]),
                                  np.ones(3, bool), np.array([False, False, True]))
    assert em is not None and len(em) == 27  # material 1 emits nothing
    x, u = rng.normal(size=(5000, 3)) * 3, rng.random(5000)
    fast = trace_lights.emitter_choice(em, x, u)
    fast_odds = trace_lights.emitter_odds(em, x, fast[0])
    monkeypatch.setattr(trace_lights, "KERNEL", False)
    slow = trace_lights.emitter_choice(em, x, u)
    assert np.array_equal(fast[0], slow[0])
    np.testing.assert_allclose(fast[1], slow[1], rtol=1e-12)
    np.testing.assert_allclose(fast_odds, trace_lights.emitter_odds(em, x, slow[0]), rtol=1e-12)
    np.testing.assert_allclose(fast_odds, fast[1], rtol=1e-12)
    behind = np.einsum("ij,ij->i", x - em.p0[fast[0]], em.normal[fast[0]]) <= 0
    assert not (behind & ~em.two_sided[fast[0]] & (fast[1] > 0)).any()
    # the odds over all emitters sum to one wherever any can light the point
    total = sum(trace_lights.emitter_odds(em, x, np.full(len(x), k)) for k in range(len(em)))
    np.testing.assert_allclose(total[total > 0], 1.0, rtol=1e-9)
