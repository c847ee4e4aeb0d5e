"""Snell refraction and Fresnel reflectance against closed forms."""
import numpy as np
import pytest

from renderer.methods.optics import f0_from_ior, fresnel_dielectric, fresnel_sp, reflect, refract, schlick

N = np.array([0.0, 0.0, 1.0])


def incident(theta):
    """Unit directions travelling toward a surface with normal +Z at incidence angles theta."""
    theta = np.asarray(theta, np.float64)
    return np.stack([np.sin(theta), np.zeros_like(theta), -np.cos(theta)], axis=-1)


@pytest.mark.parametrize("n1,n2", [(1.0, 1.5), (1.5, 1.0), (1.0, 2.4), (1.33, 1.5)])
def test_snell_law_holds_in_vector_form(n1, n2):
    crit = np.arcsin(min(1.0, n2 / n1))
    theta = np.linspace(0, min(crit, np.pi / 2) - 1e-3, 50)
    t, tir = refract(incident(theta), N, n1 / n2)
    assert not tir.any()
    np.testing.assert_allclose(np.linalg.norm(t, axis=-1), 1.0, atol=1e-12)
    sin_t = np.hypot(t[:, 0], t[:, 1])
    np.testing.assert_allclose(n1 * np.sin(theta), n2 * sin_t, atol=1e-12)
    assert np.all(t[:, 2] < 0)            # continues through the surface
    assert np.all(np.abs(t[:, 1]) < 1e-12)  # stays in the plane of incidence
    assert np.all(t[1:, 0] > 0)           # on the far side of the normal


def test_normal_incidence_goes_straight_and_reflects_f0():
    for n2 in (1.0, 1.3, 1.5, 2.4):
        t, _ = refract(incident(0.0), N, 1.0 / n2)
        np.testing.assert_allclose(t, [0, 0, -1], atol=1e-12)
        r = fresnel_dielectric(1.0, 1.0 / n2)
        assert r == pytest.approx(((1 - n2) / (1 + n2)) ** 2, abs=1e-12)
        assert r == pytest.approx(f0_from_ior(n2), abs=1e-12)
    assert fresnel_dielectric(1.0, 1 / 1.5) == pytest.approx(0.04, abs=1e-12)


def test_ior_one_is_invisible():
    theta = np.linspace(0, np.pi / 2 - 1e-6, 100)
    d = incident(theta)
    t, tir = refract(d, N, 1.0)
    np.testing.assert_allclose(t, d, atol=1e-9)
    assert not tir.any()
    np.testing.assert_allclose(fresnel_dielectric(np.cos(theta), 1.0), 0.0, atol=1e-12)


@pytest.mark.parametrize("n1,n2", [(1.0, 1.5), (1.5, 1.0), (1.0, 2.4)])
def test_brewster_angle_zeroes_p_polarisation(n1, n2):
    brewster = np.arctan(n2 / n1)
    rs, rp = fresnel_sp(np.cos(brewster), n1 / n2)
    assert rp == pytest.approx(0.0, abs=1e-12)
    assert rs > 0.01
    rs2, rp2 = fresnel_sp(np.cos(brewster + 0.05), n1 / n2)
    assert rp2 > 1e-5


@pytest.mark.parametrize("n1", [1.3, 1.5, 2.4])
def test_total_internal_reflection_beyond_critical_angle(n1):
    crit = np.arcsin(1.0 / n1)
    below = np.linspace(0, crit - 1e-4, 20)
    above = np.linspace(crit + 1e-4, np.pi / 2, 20)
    assert np.all(fresnel_dielectric(np.cos(below), n1) < 1.0)
    np.testing.assert_allclose(fresnel_dielectric(np.cos(above), n1), 1.0)
    t, tir = refract(incident(above), N, n1)
    assert tir.all()
    np.testing.assert_allclose(t, reflect(incident(above), N), atol=1e-12)  # mirror, finite
    _, tir_below = refract(incident(below), N, n1)
    assert not tir_below.any()


@pytest.mark.parametrize("n1,n2", [(1.0, 1.5), (1.5, 1.0), (1.0, 2.4), (2.4, 1.0)])
def test_energy_conserved_reflectance_plus_transmittance(n1, n2):
    """R from fresnel_sp against T from the independent amplitude transmission coefficients."""
    theta = np.linspace(0, np.pi / 2 - 1e-3, 200)
    ci = np.cos(theta)
    sin_t = n1 / n2 * np.sin(theta)
    ok = sin_t < 1
    ci, ct = ci[ok], np.sqrt(1 - sin_t[ok] ** 2)
    ts = 2 * n1 * ci / (n1 * ci + n2 * ct)
    tp = 2 * n1 * ci / (n2 * ci + n1 * ct)
    factor = (n2 * ct) / (n1 * ci)
    rs, rp = fresnel_sp(ci, n1 / n2)
    np.testing.assert_allclose(rs + factor * ts ** 2, 1.0, atol=1e-12)
    np.testing.assert_allclose(rp + factor * tp ** 2, 1.0, atol=1e-12)


def test_fresnel_is_reciprocal():
    """Same reflectance for the pair of angles related by Snell's law, from either side."""
    theta_i = np.linspace(0, 1.2, 30)
    theta_t = np.arcsin(np.sin(theta_i) / 1.5)
    np.testing.assert_allclose(fresnel_dielectric(np.cos(theta_i), 1 / 1.5),
                               fresnel_dielectric(np.cos(theta_t), 1.5), atol=1e-12)


def test_schlick_approximates_exact_fresnel_entering_glass():
    c = np.linspace(0, 1, 200)
    exact = fresnel_dielectric(c, 1 / 1.5)
    approx = schlick(c, f0_from_ior(1.5))
    assert approx[-1] == pytest.approx(0.04) and approx[0] == pytest.approx(1.0)
    assert np.max(np.abs(exact - approx)) < 0.04  # worst near grazing (0.036 at cos 0.085)


def test_outputs_finite_for_degenerate_input():
    d = np.array([[0, 0, -1.0], [1, 0, 0.0], [0, 0, 1.0]])  # normal, grazing, from behind
    for eta in (1 / 1.5, 1.5, 1.0):
        t, _ = refract(d, N, eta)
        assert np.isfinite(t).all()
        assert np.isfinite(fresnel_dielectric(-(d @ N), eta)).all()
