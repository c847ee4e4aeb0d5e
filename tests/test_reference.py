"""The committed Mitsuba references: present, sane, and in our direction conventions.

These checks use closed forms (an analytic sphere, the panorama itself), not our ray tracer,
so they hold the references to the conventions independently of the renderer under test.
"""
import numpy as np
import pytest

from bench import scenes
from bench.reference import DEFAULT_SET, load_reference, relative_mae, spec_camera
from core.cubemap import sample_equirect
from renderer.methods.optics import reflect


@pytest.fixture(scope="module")
def pano():
    return scenes.load_panorama("footprint_court").astype(np.float64)


@pytest.mark.parametrize("name", sorted(DEFAULT_SET))
def test_reference_committed_and_sane(name):
    ref = load_reference(name)
    assert ref.shape == (DEFAULT_SET[name], DEFAULT_SET[name], 4)
    assert np.isfinite(ref).all() and ref.min() >= 0
    coverage = ref[..., 3]
    assert coverage.max() == 1 and coverage[0, 0] == 0
    assert 0.03 < (coverage > 0).mean() < 0.9


def _camera_rays(name, size):
    cam = spec_camera(scenes.scene(name), size, size)
    return cam.position, cam.ray_directions()


def test_invisible_sphere_reference_is_the_panorama(pano):
    """IOR 1 glass in Mitsuba shows the panorama along the camera rays, unrotated."""
    ref = load_reference("glass_sphere_ior1.0")
    _, d = _camera_rays("glass_sphere_ior1.0", ref.shape[0])
    expected = sample_equirect(pano, d)
    whole = np.ones(ref.shape[:2], bool)
    assert relative_mae(expected, ref, whole) < 0.06  # pixel centres vs 256-spp box filter
    mirrored = sample_equirect(pano, d * [-1, 1, 1])
    assert relative_mae(mirrored, ref, whole) > 3 * relative_mae(expected, ref, whole)


def test_mirror_sphere_reference_follows_equirect_convention(pano):
    """An analytic mirror sphere (reflection about the exact sphere normal) lookup in the
    panorama with core.cubemap's convention reproduces Mitsuba's image; the mirrored
    convention (u -> 1 - u) does not."""
    ref = load_reference("mirror_sphere")
    o, d = _camera_rays("mirror_sphere", ref.shape[0])
    b = d @ o
    disc = b * b - (o @ o - 1.0)
    inner = disc > 0.05  # away from the silhouette, where pixel footprints straddle it
    t = -b - np.sqrt(np.maximum(disc, 0))
    n = o + d * t[..., None]
    r = reflect(d, n / np.linalg.norm(n, axis=-1, keepdims=True))
    mask = inner & (ref[..., 3] == 1)
    ours = relative_mae(sample_equirect(pano, r), ref, mask)
    flipped = relative_mae(sample_equirect(pano, r * [-1, 1, 1]), ref, mask)
    assert ours < 0.08, ours
    assert flipped > 3 * ours, (ours, flipped)


def test_relative_mae():
    ref = np.zeros((4, 4, 4), np.float32)
    ref[1:3, 1:3] = [0.5, 0.5, 0.5, 1.0]
    assert relative_mae(ref, ref) == 0
    img = ref.copy()
    img[1:3, 1:3, :3] *= 1.1
    assert relative_mae(img, ref) == pytest.approx(0.1, rel=1e-5)
    img[0, 0, :3] = 100.0  # outside the object: not counted by default
    assert relative_mae(img, ref) == pytest.approx(0.1, rel=1e-5)


@pytest.mark.slow
def test_regenerating_a_reference_reproduces_the_committed_one():
    """bench.reference renders the committed image again (smaller, fewer samples)."""
    pytest.importorskip("mitsuba", reason="the `reference` extra is not installed")
    from bench.reference import render_reference

    committed = load_reference("glass_sphere_ior1.5")            # 256 px, 256 spp
    small = render_reference(scenes.scene("glass_sphere_ior1.5"), 32, spp=256)
    box = committed.reshape(32, 8, 32, 8, 4).mean(axis=(1, 3))   # the same box filter
    assert relative_mae(small, box) < 0.04  # [0.020; sampling noise]
    np.testing.assert_allclose(small[..., 3], box[..., 3], atol=0.15)


@pytest.mark.slow
def test_bench_refraction_quick_writes_the_table(tmp_path, capsys):
    pytest.importorskip("mitsuba", reason="the `reference` extra is not installed")
    import csv

    from cli.main import main

    assert main(["bench", "refraction", "--quick", "--out", str(tmp_path),
                 "--cache", str(tmp_path / "cache")]) == 0
    rows = list(csv.DictReader(open(tmp_path / "refraction.csv")))
    methods = {r["method"] for r in rows}
    assert {"raytrace-1", "raytrace-2", "raytrace-8"} <= methods
    assert any(m.startswith("mitsuba-") for m in methods)
    errs = {r["method"]: float(r["rel_mae"]) for r in rows}
    assert errs["raytrace-8"] < errs["raytrace-1"]
    assert all(float(r["time_ms"]) > 0 for r in rows)
    assert "paper anchor" in capsys.readouterr().out
