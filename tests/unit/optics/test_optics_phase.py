"""Phase functions of swim.optics.phase against analytic properties and published numbers.

Sphere means use Gauss-Legendre quadrature in u = ln(1 - cos θ), which resolves forward peaks down to
g = 0.999 (width ~1e-6 in 1 - cos θ); those evaluations run in float64 (``jax.enable_x64``).
"""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from numpy.polynomial.legendre import leggauss

from swim.constants import BACKSCATTER_FRACTION, SPECIES
from swim.optics import phase as ph

# jitted copies of the public functions: eager jax compiles every primitive once per shape, which is slow
_PUBLIC = [n for n, f in vars(ph).items() if callable(f) and not n.startswith("_") and f.__module__ == ph.__name__]
jph = SimpleNamespace(**{n: jax.jit(getattr(ph, n)) for n in _PUBLIC})
_X, _W = leggauss(200)


def sphere_mean(fn, *args, moment=0):
    """(1/4π) ∫ fn(cos θ, *args) cos^k θ dΩ = ½ ∫ fn(μ, *args) μ^k dμ over -1..1 (k = moment), μ = 1 - e^u."""
    a, b = -40.0, np.log(2.0)
    u = 0.5 * (b - a) * _X + 0.5 * (b + a)
    mu = 1.0 - np.exp(u)
    vals = np.asarray(fn(mu, *args), dtype=float)
    return 0.5 * np.sum(vals * mu**moment * np.exp(u) * 0.5 * (b - a) * _W)


def hg_ref(mu, g):
    """Independent float64 Henyey-Greenstein, paper Eq. 9."""
    return (1 - g * g) / (1 + g * g - 2 * g * mu) ** 1.5


TAUS = (0.0, 0.3, 1.0, 2.0, 5.0, 20.0, 100.0)
THIN = {
    "liquid_615": lambda mu, t: jph.phase_thin_cloud_liquid(mu, t, ph.G_LIQUID[0]),
    "liquid_450": lambda mu, t: jph.phase_thin_cloud_liquid(mu, t, ph.G_LIQUID[2]),
    "rain": jph.phase_thin_rain,
    "ice": jph.phase_thin_cloud_ice,
    "snow": jph.phase_thin_snow,
    "graupel": jph.phase_thin_graupel,
}


# --- Henyey-Greenstein and DHG -------------------------------------------------------------------------------


@pytest.mark.parametrize("g", [-0.6, 0.0, 0.5, 0.9, 0.99, 0.999])
def test_hg_mean_one_and_asymmetry_g(g):
    with jax.enable_x64(True):
        assert sphere_mean(jph.henyey_greenstein, g) == pytest.approx(1.0, abs=2e-6)
        assert sphere_mean(jph.henyey_greenstein, g, moment=1) == pytest.approx(g, abs=2e-6)


def test_hg_peak_values_and_float32_accuracy():
    g = 0.999
    mu = np.array([1.0, 0.99999, 0.0, -1.0])
    with jax.enable_x64(True):
        exact = np.asarray(jph.henyey_greenstein(mu, g))
    np.testing.assert_allclose(exact[[0, 3]], [(1 + g) / (1 - g) ** 2, (1 - g) / (1 + g) ** 2], rtol=1e-9)
    f32 = np.asarray(jph.henyey_greenstein(jnp.asarray(mu, jnp.float32), g))
    np.testing.assert_allclose(f32, exact, rtol=2e-3)  # no cancellation blow-up at the 2e6 peak


@pytest.mark.parametrize("g, fb", [(0.7, 0.4), (0.59, 0.55), (0.905, 0.55), (0.962, 0.55), (0.23, 0.562)])
def test_dhg_mean_one_asymmetry_g(g, fb):
    with jax.enable_x64(True):
        f = jph.double_henyey_greenstein
        assert sphere_mean(f, g, fb) == pytest.approx(1.0, abs=2e-6)
        assert sphere_mean(f, g, fb, moment=1) == pytest.approx(g, abs=2e-6)  # the P2 back lobe has zero mean cos θ


def test_dhg_positive_for_fb_up_to_one():
    mu = np.cos(np.linspace(0, np.pi, 721))[:, None, None]
    g = np.linspace(0.0, 0.99, 34)[None, :, None]
    fb = np.linspace(0.0, 1.0, 11)[None, None, :]
    assert float(jnp.min(jph.double_henyey_greenstein(mu, g, fb))) > 0.0


@pytest.mark.parametrize(
    "g1, g2, fb, fc",
    [(0.59, 0.895, 0.55, 0.12), (0.23, 0.915, 0.562, 0.58), (0.962, 0.50, 0.55, 0.06)],  # paper Table 3, Sect. 3.5.1
)
def test_two_term_dhg_normalised_and_obeys_eq29(g1, g2, fb, fc):
    with jax.enable_x64(True):
        f = jph.two_term_double_henyey_greenstein
        assert sphere_mean(f, g1, g2, fb, fc) == pytest.approx(1.0, abs=2e-6)
        # paper Eq. 29: the overall asymmetry factor is g = f_c g1 + (1 - f_c) g2
        assert sphere_mean(f, g1, g2, fb, fc, moment=1) == pytest.approx(fc * g1 + (1 - fc) * g2, abs=2e-6)


# --- thin-cloud effective phase functions ---------------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(THIN))
def test_thin_functions_normalised(name):
    with jax.enable_x64(True):
        for tau in TAUS:
            assert sphere_mean(THIN[name], tau) == pytest.approx(1.0, abs=1e-5), tau


def test_thin_functions_non_negative_for_all_angles_and_tau_0_to_100():
    theta = np.concatenate([np.linspace(0.0, 2.0, 201), np.linspace(2.0, 180.0, 891)])
    mu = np.cos(np.deg2rad(theta))[:, None]
    tau = np.concatenate([np.linspace(0.0, 5.0, 101), np.linspace(5.0, 100.0, 191)])[None, :]
    minima = jax.jit(lambda m, t: jnp.stack([jnp.min(f(m, t)) for f in THIN.values()]))(mu, tau)
    assert np.all(np.asarray(minima) > 0.0), dict(zip(THIN, np.asarray(minima)))


def test_thin_functions_equal_the_printed_equations_at_tau_one():
    """At τ_o = 1 the interpretation (τ' = max(τ_o, 1), f1 = 0.8^τ') coincides with the printed Eqs. 18, B1, B3."""
    mu = np.cos(np.deg2rad(np.linspace(0.5, 180.0, 50)))
    with jax.enable_x64(True):
        g = 0.950
        eq18 = 0.8 * hg_ref(mu, g) + (1.06 - 0.8) * hg_ref(mu, 0.6) + 0.02 * hg_ref(mu, -0.6) - 0.08
        np.testing.assert_allclose(jph.phase_thin_cloud_liquid(mu, 1.0, g), eq18, rtol=1e-9)
        for tau in (1.0, 3.0):  # for B1 and B3 the printed g^τ_o form holds for every τ_o >= 1
            b1 = 0.1 * hg_ref(mu, 0.99**tau) + 1.05 * hg_ref(mu, 0.75**tau) - 0.35 + 0.20 * hg_ref(mu, -0.2)
            b3 = 0.5 * hg_ref(mu, 0.999**tau) + 0.45 * hg_ref(mu, 0.991**tau) + 0.03 + 0.02 * hg_ref(mu, -0.2)
            np.testing.assert_allclose(jph.phase_thin_rain(mu, tau), b1, rtol=1e-9)
            np.testing.assert_allclose(jph.phase_thin_snow(mu, tau), b3, rtol=1e-9)


def test_thin_functions_flatten_with_optical_thickness():
    """Sect. 3.4.2: 'as τ_o increases ... the effective phase function becomes flatter' (asymmetry decreases)."""
    with jax.enable_x64(True):
        for name, f in THIN.items():
            g_eff = [sphere_mean(f, t, moment=1) for t in (1.0, 3.0, 10.0, 30.0)]
            assert np.all(np.diff(g_eff) < 0), name


def test_corrected_ice_asymmetry():
    # HG lobes keep their g as mean cos θ: 0.50·0.999 + 0.21·0.991 + 0.25·0 + 0.04·(-0.2) = 0.69961
    with jax.enable_x64(True):
        assert sphere_mean(jph.phase_thin_cloud_ice, 0.5, moment=1) == pytest.approx(0.69961, abs=1e-5)


def test_liquid_corona_peak_is_sharper_in_the_blue():
    near_sun = np.cos(np.deg2rad(0.5))
    red, green, blue = (float(jph.phase_thin_cloud_liquid(near_sun, 0.5, g)) for g in ph.G_LIQUID)
    assert red < green < blue


# --- Venus / thick-cloud terms -------------------------------------------------------------------------------


def test_venus_magnitude_published_polynomial():
    a = np.array([0.0, 90.0, 170.0])
    # hand evaluation of the Mallama et al. (2006) coefficients, minus V(1,0) = -4.384
    expected = [
        0.0,
        -1.044e-3 * 90 + 3.687e-4 * 90**2 - 2.814e-6 * 90**3 + 8.938e-9 * 90**4,
        236.05828 - 2.81914 * 170 + 8.39034e-3 * 170**2 + 4.384,
    ]
    np.testing.assert_allclose(jph.venus_magnitude_mallama2006(a), expected, atol=2e-4)


def test_venus_phase_integral_is_the_published_1_35():
    # Mallama et al. (2006) abstract: phase integral q = 1.35; q = 2 ∫_0^π 10^(-0.4 m(α)) sin α dα
    alpha = np.linspace(0.0, 179.0, 17901)
    with jax.enable_x64(True):
        phi = 10.0 ** (-0.4 * np.asarray(jph.venus_magnitude_mallama2006(alpha)))
    q = 2.0 * np.trapezoid(phi * np.sin(np.deg2rad(alpha)), np.deg2rad(alpha))
    assert q == pytest.approx(1.35, abs=0.01)


def test_thick_high_values_and_guard():
    cos_t = np.cos(np.deg2rad(np.array([180.0, 90.0, 1.0, 0.5, 0.0])))
    p = np.asarray(jph.phase_thick_high(cos_t))
    assert p[0] == pytest.approx(1.94, rel=1e-5)  # full phase: 1.94 / 1
    m90 = -1.044e-3 * 90 + 3.687e-4 * 90**2 - 2.814e-6 * 90**3 + 8.938e-9 * 90**4
    assert p[1] == pytest.approx(1.94 * 10 ** (-0.4 * m90) / 0.5, rel=1e-4)
    assert np.all(np.isfinite(p)) and np.all(p > 0)
    np.testing.assert_allclose(p[3:], p[2], rtol=1e-4)  # held constant inside θ = 1° (α = 179°)


def test_thick_high_backscatter_matches_white_lambertian():
    # Eq. 21 with c3 = 1 at θ = 180°: 2 × 1.94 = 3.88 ≈ 4, the L' of a white Lambertian surface (paper Eq. 2)
    assert float(jph.phase_thick(-1.0, 1.0, 1.0)) == pytest.approx(4.0, rel=0.03)


def test_thick_low_and_blend():
    p = np.asarray(jph.phase_thick_low(np.array([1.0, 0.5, 0.0, -0.5])))
    np.testing.assert_allclose(p, [1.0, 2.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0], rtol=1e-6)
    c = np.asarray(jph.blend_coefficient(np.array([0.0, 10.0, 0.0, 0.0]), np.array([1.0, 1.0, 0.5, 1.7])))
    np.testing.assert_allclose(c, [1.0, np.exp(-1.0), 0.5, 1.0], rtol=1e-6)
    np.testing.assert_allclose(jph.phase_thick(0.3, 0.8, 0.0), 4 * (1 + 2 * 0.8) / 3, rtol=1e-6)


# --- effective phase function (Eq. 13) ----------------------------------------------------------------------


def _weights(**fractions):
    return np.array([fractions.get(s, 0.0) for s in SPECIES])


def test_effective_thin_limit_is_the_normalised_thin_function():
    w = _weights(cloud_liquid=1.0)
    with jax.enable_x64(True):
        assert sphere_mean(jph.effective_phase_function, 0.5, 0.0, 1.0, w, 0.95) == pytest.approx(1.0, abs=1e-5)
        mu = np.cos(np.linspace(0.0, np.pi, 200))
        np.testing.assert_allclose(jph.effective_phase_function(mu, 0.5, 0.0, 1.0, w, 0.95),
                                   jph.phase_thin_cloud_liquid(mu, 0.0, 0.95), rtol=1e-9)


def test_effective_thick_limit_is_the_dark_cloud_base():
    w = _weights(cloud_ice=0.3, snow=0.7)
    mu = np.linspace(-1.0, 1.0, 5)
    p = np.asarray(jph.effective_phase_function(mu, 0.6, 200.0, 0.9, w, 0.95))
    np.testing.assert_allclose(p, 4 * (1 + 2 * 0.6) / 3, rtol=1e-5)  # c1 = c3 = 0: 4 P_thick,l(z)


def test_effective_mixture_is_the_weighted_mean():
    mu, tau, cz, e = np.cos(np.deg2rad(30.0)), 2.0, 0.7, 0.8
    half = jph.effective_phase_function(mu, cz, tau, e, _weights(cloud_liquid=0.5, rain=0.5), 0.95)
    liq = jph.effective_phase_function(mu, cz, tau, e, _weights(cloud_liquid=1.0), 0.95)
    rain = jph.effective_phase_function(mu, cz, tau, e, _weights(rain=1.0), 0.95)
    assert float(half) == pytest.approx(0.5 * float(liq) + 0.5 * float(rain), rel=1e-6)


def test_effective_broadcasts_and_jits_in_float32():
    rng = np.random.default_rng(0)
    shape = (4, 3)
    w = rng.dirichlet(np.ones(5), size=shape)
    args = (
        rng.uniform(-1, 1, shape).astype(np.float32),
        rng.uniform(-1, 1, shape).astype(np.float32),
        rng.uniform(0, 30, shape).astype(np.float32),
        rng.uniform(0, 1, shape).astype(np.float32),
        w.astype(np.float32),
        np.float32(0.95),
    )
    out = jph.effective_phase_function(*args)
    assert out.shape == shape and out.dtype == jnp.float32
    assert bool(jnp.all(jnp.isfinite(out))) and bool(jnp.all(out >= 0))
    with jax.enable_x64(True):
        ref = np.asarray(jph.effective_phase_function(*[np.asarray(a, np.float64) for a in args]))
    np.testing.assert_allclose(np.asarray(out), ref, rtol=2e-4)


# --- cloud albedo and reflectance factor --------------------------------------------------------------------


def test_cloud_albedo_limits():
    b = BACKSCATTER_FRACTION["cloud_liquid"]
    a = np.asarray(jph.cloud_albedo_stephens1978(np.array([1e-4, 1.0 / b, 1e6]), b))
    np.testing.assert_allclose(a, [b * 1e-4, 0.5, 1.0], rtol=1e-4)


def test_arf_at_overhead_sun_and_view_is_close_to_one():
    # (1.48 + 7.76 + P_DHG(180°)) / (4 (1 + 1)); P_DHG(180°; 0.7, 0.4) = 0.51 (1/1.7³ + 0.4/1.49^1.5)
    p180 = 0.51 * (1.0 / 1.7**3 + 0.4 / 1.49**1.5)
    expected = (1.48 + 7.76 + p180) / 8.0
    arf = float(jph.anisotropic_reflectance_factor_kokhanovsky2004(1.0, 1.0, -1.0))
    assert arf == pytest.approx(expected, rel=1e-5)
    assert arf == pytest.approx(1.18, abs=0.005)


def test_arf_is_reciprocal():
    # Helmholtz reciprocity of a reflection function: R(μ, μ0, θ) = R(μ0, μ, θ)
    r1 = jph.anisotropic_reflectance_factor_kokhanovsky2004(0.3, 0.9, -0.2)
    r2 = jph.anisotropic_reflectance_factor_kokhanovsky2004(0.9, 0.3, -0.2)
    assert float(r1) == pytest.approx(float(r2), rel=1e-6)


@pytest.mark.parametrize("mu0, lo, hi", [(1.0, 0.98, 1.02), (0.8, 0.95, 1.0), (0.5, 0.9, 0.97)])
def test_arf_conserves_energy_of_a_non_absorbing_cloud(mu0, lo, hi):
    """Plane albedo (1/π) ∫∫ R μ dμ dφ of a conservative semi-infinite cloud must be ≈ 1."""
    xm, wm = leggauss(48)
    mu = 0.5 * (xm + 1.0)
    phi = np.linspace(0.0, 2.0 * np.pi, 181)[:-1]
    m, p = np.meshgrid(mu, phi, indexing="ij")
    # reflected light leaves along (sin z cos φ, sin z sin φ, cos z); the observer's view direction is its opposite
    cos_theta = -(np.sqrt(1 - mu0**2) * np.sqrt(1 - m**2) * np.cos(p) + mu0 * m)
    with jax.enable_x64(True):
        r = np.asarray(jph.anisotropic_reflectance_factor_kokhanovsky2004(m, mu0, cos_theta))
    albedo = np.sum(r.mean(axis=1) * 2.0 * np.pi * mu * 0.5 * wm) / np.pi
    assert lo < albedo < hi


def test_effective_phase_function_is_the_blend_of_the_thin_mixture_and_the_thick_function():
    mu = np.linspace(-1.0, 1.0, 7)
    tau, t, up = 3.0, 0.7, 0.5
    weights = np.array([0.6, 0.1, 0.2, 0.1, 0.0])
    c1 = float(jph.blend_coefficient(tau, t))
    thin = np.asarray(jph.phase_thin_mixture(mu, tau, weights, 0.95))
    expected = c1 * thin + (1 - c1) * np.asarray(jph.phase_thick(mu, up, c1))
    got = np.asarray(jph.effective_phase_function(mu, up, tau, t, weights, 0.95))
    np.testing.assert_allclose(got, expected, rtol=1e-5)
    # a pure species gives its own thin function
    liquid = np.asarray(jph.phase_thin_mixture(mu, tau, np.eye(5)[0], 0.95))
    np.testing.assert_allclose(liquid, np.asarray(jph.phase_thin_cloud_liquid(mu, tau, 0.95)), rtol=1e-6)


def test_delta_scaled_path_factor_limits():
    """(1 - e^{-(1-f)tau})/(1-f): tau for thin paths, 1/(1-f) for thick ones, Eq. 12's factor at f = 0."""
    from swim.optics.phase import delta_scaled_path_factor

    assert float(delta_scaled_path_factor(1e-4, 0.5)) == pytest.approx(1e-4, rel=1e-3)
    assert float(delta_scaled_path_factor(100.0, 0.5)) == pytest.approx(2.0, rel=1e-6)
    assert float(delta_scaled_path_factor(1.0, 0.0)) == pytest.approx(1 - np.exp(-1.0), rel=1e-6)
    assert float(delta_scaled_path_factor(1.0)) == pytest.approx(2 * (1 - np.exp(-0.5)), rel=1e-6)


def test_forward_peak_mixture_is_the_first_lobe():
    """Liquid: f1 p(g^tau') with f1 = 0.8^tau'; ice: 0.50 p(0.999^tau'); below P_thin everywhere."""
    from swim.optics.phase import forward_peak_mixture, henyey_greenstein, phase_thin_mixture

    mu = np.cos(np.radians(np.array([0.0, 10.0, 30.0, 90.0, 180.0])))
    for tau in (0.5, 1.0, 3.0):
        liquid = np.eye(5)[0]
        tp = max(tau, 1.0)
        np.testing.assert_allclose(forward_peak_mixture(mu, tau, liquid, 0.95),
                                   0.8**tp * henyey_greenstein(mu, 0.95**tp), rtol=1e-5)
        ice = np.eye(5)[1]
        np.testing.assert_allclose(forward_peak_mixture(mu, tau, ice, 0.95), 0.5 * henyey_greenstein(mu, 0.999**tp),
                                   rtol=1e-5)
        for w in (liquid, ice, np.full(5, 0.2)):
            assert np.all(np.asarray(forward_peak_mixture(mu, tau, w, 0.95)) < np.asarray(phase_thin_mixture(mu, tau, w, 0.95)))
