"""Water surface reflectance (swim.surface.water) against analytic invariants and independent formulas.

Directions: ``sun`` and ``view`` point from the surface towards the sun and the observer. Hemispherical
integrals use Gauss-Legendre quadrature in the view zenith angle times a uniform azimuth grid.
"""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import erfc as erfc64

from swim.surface import water as wt

_PUBLIC = [n for n, f in vars(wt).items() if callable(f) and not n.startswith("_") and f.__module__ == wt.__name__]
_STATIC = {"sun_glint_reflectance_factor_cox_munk1954": ("shadowing", "refractive_index"),
           "water_leaving_reflectance": ("refractive_index",)}
jw = SimpleNamespace(**{n: jax.jit(getattr(wt, n), static_argnames=_STATIC.get(n, ()))
                        for n in _PUBLIC if n != "water_diffuse_albedo"})
N_WATER = 1.334


def vec(zenith_deg, azimuth_deg=0.0):
    """Unit vector (..., 3) from zenith and azimuth angles [deg] (azimuth from +x towards +y)."""
    z, a = np.radians(zenith_deg), np.radians(azimuth_deg)
    return np.stack(np.broadcast_arrays(np.sin(z) * np.cos(a), np.sin(z) * np.sin(a), np.cos(z)), axis=-1)


def dhr(fn, sun_zenith, n_theta=200, n_phi=512):
    """Directional-hemispherical reflectance (1/pi) int R(sun, view) mu_v dOmega_v of a reflectance factor."""
    x, w = np.polynomial.legendre.leggauss(n_theta)
    th = 0.25 * np.pi * (x + 1.0)
    w_th = 0.25 * np.pi * w
    ph = np.arange(n_phi) * 2 * np.pi / n_phi
    t, p = np.meshgrid(th, ph, indexing="ij")
    view = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)
    r = np.asarray(fn(vec(sun_zenith), view), dtype=float)  # (n_theta, n_phi) or (n_theta, n_phi, C)
    weight = (np.cos(t) * np.sin(t) * w_th[:, None]).reshape(t.shape + (1,) * (r.ndim - 2))
    return np.sum(r * weight, axis=(0, 1)) * (2 * np.pi / n_phi) / np.pi


def fresnel_ref(theta_i, n):
    """Independent float64 Fresnel reflectance from the incidence angle via Snell's law [rad]."""
    theta_t = np.arcsin(np.sin(theta_i) / n)
    rs = np.sin(theta_i - theta_t) / np.sin(theta_i + theta_t)
    rp = np.tan(theta_i - theta_t) / np.tan(theta_i + theta_t)
    return 0.5 * (rs**2 + rp**2)


def random_directions(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ---------------------------------------------------------------------------------------------------- Fresnel
def test_fresnel_normal_incidence():
    assert float(jw.fresnel_reflectance(1.0)) == pytest.approx(((N_WATER - 1) / (N_WATER + 1)) ** 2, rel=1e-6)
    assert float(jw.fresnel_reflectance(1.0)) == pytest.approx(0.0205, abs=1e-4)
    assert float(jw.fresnel_reflectance(1.0, 1.5)) == pytest.approx(0.04, rel=1e-6)


def test_fresnel_grazing_is_one_and_clipped():
    np.testing.assert_allclose(np.asarray(jw.fresnel_reflectance(jnp.array([0.0, -0.3]))), 1.0, rtol=1e-6)
    assert float(jw.fresnel_reflectance(1.2)) == pytest.approx(float(jw.fresnel_reflectance(1.0)))


def test_fresnel_monotonic_and_matches_snell():
    c = np.linspace(0.0, 1.0, 2001)
    r = np.asarray(jw.fresnel_reflectance(c))
    assert np.all(np.diff(r) < 0)
    th = np.radians([10.0, 30.0, 53.1, 70.0, 85.0, 89.0])
    np.testing.assert_allclose(np.asarray(jw.fresnel_reflectance(np.cos(th))), fresnel_ref(th, N_WATER), rtol=2e-5)


def test_water_diffuse_albedo():
    x, w = np.polynomial.legendre.leggauss(400)
    th = 0.25 * np.pi * (x + 1.0)
    ref = np.sum(fresnel_ref(th, N_WATER) * 2 * np.cos(th) * np.sin(th) * 0.25 * np.pi * w)
    value = wt.water_diffuse_albedo()
    assert value == pytest.approx(ref, abs=2e-5)
    assert 0.064 < value < 0.068
    assert wt.water_diffuse_albedo(1.5) > value


# ------------------------------------------------------------------------------------------ slopes, shadowing
def test_slope_variance_cox_munk():
    np.testing.assert_allclose(np.asarray(jw.slope_variance_cox_munk1954(jnp.array([-2.0, 0.0, 10.0]))),
                               [0.003, 0.003, 0.003 + 0.0512], rtol=1e-6)


@pytest.mark.parametrize("wind", [0.0, 2.0, 7.0, 15.0])
def test_slope_pdf_integrates_to_one(wind):
    s2 = float(wt.slope_variance_cox_munk1954(wind))
    # polar coordinates in the slope plane, t = tan(beta) up to 12 sigma
    x, w = np.polynomial.legendre.leggauss(200)
    t = 6 * np.sqrt(s2) * (x + 1.0)
    total = 2 * np.pi * np.sum(np.asarray(jw.slope_pdf_isotropic_gaussian(t**2, s2), float) * t * 6 * np.sqrt(s2) * w)
    assert total == pytest.approx(1.0, abs=1e-5)


@pytest.mark.parametrize("mu", [0.05, 0.2, 0.5, 0.9])
def test_smith_lambda_is_projected_facet_area(mu):
    """mu (1 + Lambda(mu)) = int p(z) max(0, mu - z_x sin theta) dz: the visible facet area along the view."""
    s2 = float(wt.slope_variance_cox_munk1954(8.0))
    zx = np.linspace(-12, 12, 200_001) * np.sqrt(s2 / 2)
    px = np.exp(-zx**2 / s2) / np.sqrt(np.pi * s2)  # marginal density of one slope component
    area = np.sum(px * np.maximum(0.0, mu - zx * np.sqrt(1 - mu * mu))) * (zx[1] - zx[0])
    shadow = float(jw.shadowing_smith1967(mu, 1.0, s2))  # S = 1 / (1 + Lambda(mu) + Lambda(1)), Lambda(1) = 0
    assert mu / shadow == pytest.approx(area, rel=1e-4)
    # independent closed form of Lambda
    a = mu / np.sqrt(s2 * (1 - mu * mu))
    lam = 0.5 * (np.exp(-a * a) / (a * np.sqrt(np.pi)) - erfc64(a))
    assert 1.0 / shadow == pytest.approx(1.0 + lam, rel=1e-5)


# ----------------------------------------------------------------------------------------------------- glint
def test_specular_direction_is_mirror():
    rng = np.random.default_rng(1)
    n = random_directions(rng, 50)
    n[:, 2] = np.abs(n[:, 2])
    s = random_directions(rng, 50)
    r = np.asarray(jw.specular_direction(s, n))
    np.testing.assert_allclose(np.linalg.norm(r, axis=-1), 1.0, rtol=1e-5)
    np.testing.assert_allclose(np.sum(r * n, -1), np.sum(s * n, -1), atol=1e-6)  # same angle to the normal
    bisector = s + r
    np.testing.assert_allclose(np.cross(bisector, n), 0.0, atol=1e-5)  # s + r along n
    np.testing.assert_allclose(np.asarray(jw.specular_direction(vec(30.0, 10.0))), vec(30.0, 190.0), atol=1e-6)


def test_glint_peak_is_specular():
    """The facet density peaks at the specular direction; with the sun at the zenith R peaks at nadir, and for
    a calm sea and a high sun the maximum of R lies within 1.5 deg of the specular direction in the principal
    plane (the 1/(mu_v cos^4 beta) and Fresnel factors displace it slightly towards the horizon)."""
    for sun_zenith, wind, tol in [(0.0, 5.0, 0.0), (20.0, 1.0, 0.6), (40.0, 1.0, 1.5), (30.0, 0.0, 0.5)]:
        zen = np.linspace(0.0, 89.0, 891)
        az = np.linspace(150.0, 210.0, 61)
        t, p = np.meshgrid(zen, az, indexing="ij")
        r = np.asarray(jw.sun_glint_reflectance_factor_cox_munk1954(vec(sun_zenith), vec(t, p), None, wind))
        i = np.unravel_index(np.argmax(r), r.shape)
        assert abs(t[i] - sun_zenith) <= tol + 1e-9
        assert sun_zenith == 0.0 or p[i] == pytest.approx(180.0)
    # at the specular direction the facet tilt is 0: R = pi rho(mu_i) / (4 mu_i^2 pi sigma^2) S
    sun = vec(35.0)
    s2 = 0.003 + 0.00512 * 6.0
    mu = np.cos(np.radians(35.0))
    spec = wt.specular_direction(sun)
    r_spec = float(jw.sun_glint_reflectance_factor_cox_munk1954(sun, spec, None, 6.0, shadowing=False))
    assert r_spec == pytest.approx(fresnel_ref(np.radians(35.0), N_WATER) / (4 * mu * mu * s2), rel=2e-5)


@pytest.mark.parametrize("wind", [1.0, 5.0, 12.0])
@pytest.mark.parametrize("shadowing", [False, True])
def test_glint_width_matches_cox_munk(wind, shadowing):
    """Sun at the zenith, flat mean surface: tilting the view by alpha tilts the facet by alpha/2."""
    s2 = 0.003 + 0.00512 * wind
    alpha = np.radians(np.array([0.0, 2.0, 5.0, 10.0, 15.0, 20.0, 30.0]))
    view = vec(np.degrees(alpha), 37.0)
    r = np.asarray(jw.sun_glint_reflectance_factor_cox_munk1954(vec(0.0), view, None, wind, shadowing=shadowing))
    beta = alpha / 2
    ref = (np.pi * fresnel_ref(np.maximum(beta, 1e-9), N_WATER) * np.exp(-np.tan(beta) ** 2 / s2) / (np.pi * s2)
           / (4 * np.cos(alpha) * np.cos(beta) ** 4))
    if shadowing:
        a = np.cos(alpha) / np.sqrt(s2 * np.maximum(np.sin(alpha) ** 2, 1e-300))
        lam = 0.5 * (np.exp(-a * a) / (a * np.sqrt(np.pi)) - erfc64(a))
        ref = ref / (1.0 + lam)
    np.testing.assert_allclose(r, ref, rtol=5e-5)
    # the ratio to nadir is the Gaussian exp(-tan^2(alpha/2)/sigma^2) times the Fresnel/geometry factors
    ratio = r / r[0]
    gauss = np.exp(-np.tan(beta) ** 2 / s2)
    np.testing.assert_allclose(ratio / gauss, ref / ref[0] / gauss, rtol=5e-5)


def glint(wind, shadowing=True):
    return lambda s, v: jw.sun_glint_reflectance_factor_cox_munk1954(s, v, None, wind, shadowing=shadowing)


@pytest.mark.parametrize("sun_zenith, wind", [(0, 2), (0, 5), (0, 10), (20, 2), (20, 5), (20, 10), (40, 2)])
def test_glint_dhr_is_fresnel_at_high_sun(sun_zenith, wind):
    rho = fresnel_ref(max(np.radians(sun_zenith), 1e-9), N_WATER)
    assert dhr(glint(wind), sun_zenith, n_theta=300, n_phi=720) == pytest.approx(rho, rel=0.04)


def slope_space_dhr(sun_zenith, wind, shadowing):
    """Independent DHR: sum over the facet slopes z of p(z) rho_F(cos omega) cos omega / (mu_i cos beta) S,
    for the facets that face the sun and reflect it into the upper hemisphere."""
    s2 = 0.003 + 0.00512 * wind
    x, w = np.polynomial.legendre.leggauss(400)
    t = 5 * np.sqrt(s2) * (x + 1.0)  # tan(beta) up to 10 sigma
    w_t = 5 * np.sqrt(s2) * w
    psi = (np.arange(720) + 0.5) * 2 * np.pi / 720
    tt, pp = np.meshgrid(t, psi, indexing="ij")
    m = np.stack([-tt * np.cos(pp), -tt * np.sin(pp), np.ones_like(tt)], -1) / np.sqrt(1 + tt**2)[..., None]
    sun = vec(sun_zenith)
    cos_om = m @ sun
    view = 2 * cos_om[..., None] * m - sun
    mu_i, mu_v = sun[2], view[..., 2]
    ok = (cos_om > 0) & (mu_v > 0)
    cos_om = np.clip(cos_om, 1e-12, 1)
    val = (np.exp(-tt**2 / s2) / (np.pi * s2) * fresnel_ref(np.arccos(cos_om), N_WATER) * cos_om
           * np.sqrt(1 + tt**2) / mu_i)
    if shadowing:
        def lam(mu):
            a = mu / np.sqrt(s2 * np.maximum(1 - mu * mu, 1e-300))
            return 0.5 * (np.exp(-a * a) / (a * np.sqrt(np.pi)) - erfc64(a))
        val = val / (1 + lam(mu_i) + lam(np.clip(mu_v, 1e-12, 1)))
    return np.sum(np.where(ok, val, 0.0) * (tt * w_t[:, None])) * 2 * np.pi / 720


@pytest.mark.parametrize("sun_zenith, wind, shadowing", [(40, 5, True), (60, 10, True), (85, 5, True), (50, 3, False)])
def test_glint_dhr_matches_slope_space_integral(sun_zenith, wind, shadowing):
    """The hemispherical integral of R equals the facet-slope integral: checks the 1/(4 mu_i mu_v cos^4 beta)
    Jacobian and the shadowing independently of the view-space formula."""
    ref = slope_space_dhr(sun_zenith, wind, shadowing)
    assert dhr(glint(wind, shadowing), sun_zenith, n_theta=400, n_phi=1440) == pytest.approx(ref, rel=1e-3)


@pytest.mark.parametrize("wind", [0.0, 5.0, 20.0])
def test_glint_dhr_below_one(wind):
    for sun_zenith in (60.0, 80.0, 87.0, 89.5):
        assert 0.0 < dhr(glint(wind), sun_zenith, n_theta=300, n_phi=720) <= 1.0


def test_glint_reciprocity():
    rng = np.random.default_rng(2)
    s, v = random_directions(rng, 2000), random_directions(rng, 2000)
    s[:, 2], v[:, 2] = np.abs(s[:, 2]), np.abs(v[:, 2])
    wind = rng.uniform(0, 15, 2000)
    for shadowing in (True, False):
        r1 = np.asarray(jw.sun_glint_reflectance_factor_cox_munk1954(s, v, None, wind, shadowing=shadowing))
        r2 = np.asarray(jw.sun_glint_reflectance_factor_cox_munk1954(v, s, None, wind, shadowing=shadowing))
        np.testing.assert_allclose(r1, r2, rtol=2e-5, atol=1e-30)
    r1 = np.asarray(jw.water_leaving_reflectance(s, v))
    np.testing.assert_allclose(r1, np.asarray(jw.water_leaving_reflectance(v, s)), rtol=1e-6)


def test_float32_jit_random_directions_finite_and_zero_below_horizon():
    rng = np.random.default_rng(3)
    n = 20_000
    s = random_directions(rng, n).astype(np.float32)
    v = random_directions(rng, n).astype(np.float32)
    normal = random_directions(rng, n)
    normal[:, 2] = np.abs(normal[:, 2]) + 1.0
    normal = (normal / np.linalg.norm(normal, axis=-1, keepdims=True)).astype(np.float32)
    # exact special cases: grazing, view = sun, view = -sun, specular at grazing
    s[:6] = [[1, 0, 0], [0, 0, 1], [0.6, 0, 0.8], [0.6, 0, 0.8], [1, 0, 0], [0, 0, 1]]
    v[:6] = [[-1, 0, 0], [0, 0, 1], [-0.6, 0, -0.8], [0.6, 0, 0.8], [1, 0, 0], [1, 0, 0]]
    normal[:6] = [0, 0, 1]
    wind = rng.uniform(-1, 25, n).astype(np.float32)
    for fn in (lambda a, b, c: jw.sun_glint_reflectance_factor_cox_munk1954(a, b, c, wind),
               lambda a, b, c: jw.water_leaving_reflectance(a, b, c)):
        r = np.asarray(fn(s, v, normal))
        assert r.dtype == np.float32
        assert np.all(np.isfinite(r)) and np.all(r >= 0)
        below = (np.sum(s * normal, -1) <= 0) | (np.sum(v * normal, -1) <= 0)
        assert np.all(r[below] == 0) and np.any(r[~below] > 0)
    # sun and view at grazing specular geometry, calm sea: the floor keeps R finite and the reflected
    # radiance R mu_i E / pi far below the solar disk's radiance (E / 6.8e-5 sr)
    for zen in (89.0, 89.9, 89.999):
        sun = vec(zen).astype(np.float32)
        r = float(jw.sun_glint_reflectance_factor_cox_munk1954(sun, jw.specular_direction(sun), None, 0.0))
        assert np.isfinite(r) and r * sun[2] / np.pi < 1000.0


# each shape compiles its own JAX programs: the larger ones in the full tier
@pytest.mark.parametrize("shape", [(), pytest.param((7,), marks=pytest.mark.full),
                                   pytest.param((4, 5), marks=pytest.mark.full)])
def test_shapes(shape):
    rng = np.random.default_rng(4)
    s = np.broadcast_to(vec(30.0), shape + (3,))
    v = vec(rng.uniform(0, 80, shape), rng.uniform(0, 360, shape))
    wind = np.full(shape, 5.0)
    assert jw.sun_glint_reflectance_factor_cox_munk1954(s, v, None, wind).shape == shape
    assert jw.sun_glint_reflectance_factor_cox_munk1954(s, v).shape == shape  # default normal and wind
    assert jw.water_leaving_reflectance(s, v).shape == shape + (3,)
    assert jw.specular_direction(s).shape == shape + (3,)
    assert jw.fresnel_reflectance(np.full(shape, 0.5)).shape == shape
    # unbatched sun, batched view; numpy and jax input
    assert wt.sun_glint_reflectance_factor_cox_munk1954(jnp.asarray(vec(30.0)), v).shape == shape


def test_water_leaving_term():
    r_sub = np.array(wt.WATER_SUBSURFACE_REFLECTANCE)
    r_int = 1 - (1 - wt.water_diffuse_albedo()) / N_WATER**2
    assert r_int == pytest.approx(0.475, abs=0.002)
    rho0 = ((N_WATER - 1) / (N_WATER + 1)) ** 2
    nadir = np.asarray(jw.water_leaving_reflectance(vec(0.0), vec(0.0)))
    np.testing.assert_allclose(nadir, r_sub * (1 - rho0) ** 2 / (N_WATER**2 * (1 - r_int * r_sub)), rtol=1e-5)
    # spectral order of open ocean: blue > green > red, all small
    assert nadir[2] > nadir[1] > nadir[0] > 0 and nadir.max() < 0.03
    # DHR: (1 - rho(mu_i)) (1 - rho_bar) R_sub / (n^2 (1 - r_int R_sub)) <= R_sub (energy from below)
    for sun_zenith in (0.0, 50.0, 80.0):
        ref = ((1 - fresnel_ref(max(np.radians(sun_zenith), 1e-9), N_WATER)) * (1 - wt.water_diffuse_albedo())
               * r_sub / (N_WATER**2 * (1 - r_int * r_sub)))
        np.testing.assert_allclose(dhr(jw.water_leaving_reflectance, sun_zenith, 100, 16), ref, rtol=1e-3)
        assert np.all(ref < r_sub)
    custom = np.asarray(jw.water_leaving_reflectance(vec(0.0), vec(0.0), None, np.array([0.02])))
    assert custom.shape == (1,)
