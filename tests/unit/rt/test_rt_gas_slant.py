"""The clear atmosphere's slant optical depth (swim.rt.gas._slant_optical_depth), which fills the sun-transmittance
table: against closed forms of a spherical shell and against a per-channel numpy.interp quadrature."""

import numpy as np
import pytest

from swim.constants import EARTH_RADIUS_M
from swim.rt.gas import ATMOSPHERE_TOP_M, _slant_optical_depth

TOP = ATMOSPHERE_TOP_M
HEIGHTS = np.arange(0.0, TOP + 50.0, 100.0)


def chord_to_top(h, mu, radius=EARTH_RADIUS_M, top=TOP):
    """Length [m] of the path from height h along direction cosine mu to the sphere of radius + top (law of cosines)."""
    r0, rt = radius + h, radius + top
    return -r0 * mu + np.sqrt(r0**2 * mu**2 + rt**2 - r0**2)


@pytest.mark.parametrize("shape", [(7,), (4, 5), (2, 3, 4)])
def test_a_constant_extinction_gives_beta_times_the_chord(shape):
    """beta constant in height: tau = beta * path length to the top, for any start height and upward or horizontal
    direction, per channel, over arrays of several shapes."""
    rng = np.random.default_rng(3)
    h = rng.uniform(0.0, 0.9 * TOP, shape)
    mu = rng.uniform(0.0, 1.0, shape)
    beta = np.ones((HEIGHTS.size, 3)) * np.array([1e-6, 2e-5, 3e-4])
    tau = _slant_optical_depth(h, mu, HEIGHTS, beta, TOP, EARTH_RADIUS_M)
    assert tau.shape == shape + (3,)
    np.testing.assert_allclose(tau, chord_to_top(h, mu)[..., None] * beta[0], rtol=1e-12)


def test_an_exponential_atmosphere_straight_up_matches_the_closed_form():
    """beta0 e^(-z/H) from z = h straight up to the top: beta0 H (e^(-h/H) - e^(-top/H)); the profile is linear between
    grid nodes 100 m apart, which with H = 8 km is within 2e-5 relative of the exponential."""
    scale, beta0 = 8000.0, 1.2e-5
    beta = (beta0 * np.exp(-HEIGHTS / scale))[:, None]
    h = np.array([0.0, 1500.0, 20000.0])
    tau = _slant_optical_depth(h, np.ones(3), HEIGHTS, beta, TOP, EARTH_RADIUS_M)[:, 0]
    exact = beta0 * scale * (np.exp(-h / scale) - np.exp(-TOP / scale))
    np.testing.assert_allclose(tau, exact, rtol=2e-5)


def test_paths_into_the_earth_are_opaque_and_grazing_ones_are_not():
    h = np.array([1000.0, 1000.0, 1000.0])
    mu_tangent = -np.sqrt(1 - (EARTH_RADIUS_M / (EARTH_RADIUS_M + 1000.0)) ** 2)
    mu = np.array([-0.5, mu_tangent * 0.99, mu_tangent * 1.01])  # down, just above the limb, just into the earth
    tau = _slant_optical_depth(h, mu, HEIGHTS, np.full((HEIGHTS.size, 1), 1e-5), TOP, EARTH_RADIUS_M)[:, 0]
    assert np.isinf(tau[0]) and np.isinf(tau[2])
    # the grazing path dips towards the limb and climbs out through the whole shell: ~1 250 km of air
    assert tau[1] == pytest.approx(1e-5 * chord_to_top(1000.0, mu[1]), rel=1e-12)
    assert tau[1] > 12.0


@pytest.mark.parametrize("dh", [100.0, 10.0])
def test_matches_the_same_quadrature_with_numpy_interp_per_channel(dh):
    """The same midpoint rule written with numpy.interp per channel (a simpler, slower implementation), on a
    profile with structure (a stratospheric layer, a boundary layer), the table's own grid of heights and cosines, and
    the default and a fine height grid."""
    rng = np.random.default_rng(11)
    heights = np.arange(0.0, TOP + dh / 2, dh)
    beta = (1.2e-5 * np.exp(-heights / 8000.0))[:, None] * rng.uniform(0.5, 2.0, 3)
    beta[(heights >= 15000.0) & (heights < 25000.0)] += 2e-6
    low = heights < 2000.0
    beta[low] += rng.uniform(0.0, 1e-4, (int(low.sum()), 3))
    u = np.linspace(0.0, 1.0, 24)
    h, mu = np.meshgrid(TOP * u**2, np.linspace(-1.0, 1.0, 64), indexing="ij")
    tau = _slant_optical_depth(h, mu, heights, beta, TOP, EARTH_RADIUS_M)

    n_steps, r0 = 400, EARTH_RADIUS_M + h
    s_top = -r0 * mu + np.sqrt(np.maximum(r0**2 * mu**2 + (EARTH_RADIUS_M + TOP) ** 2 - r0**2, 0.0))
    v = (np.arange(n_steps) + 0.5) / n_steps
    s, ds = s_top[..., None] * v**2, s_top[..., None] * 2 * v / n_steps
    hh = np.sqrt(r0[..., None] ** 2 + s**2 + 2 * r0[..., None] * mu[..., None] * s) - EARTH_RADIUS_M
    expected = np.stack([np.sum(np.interp(hh, heights, beta[:, c]) * ds, axis=-1) for c in range(3)], axis=-1)
    blocked = (mu < 0) & (r0**2 * (1 - mu**2) < EARTH_RADIUS_M**2)
    expected[blocked] = np.inf
    assert np.array_equal(np.isinf(tau), np.isinf(expected))
    finite = np.isfinite(expected)
    # (the cell found by division rather than by search: rounding, up to ~1e-11 where the noisy boundary layer jumps)
    np.testing.assert_allclose(tau[finite], expected[finite], rtol=1e-10, atol=1e-15)


def test_an_uneven_height_grid_is_refused():
    with pytest.raises(ValueError, match="equally spaced"):
        _slant_optical_depth(np.zeros(2), np.ones(2), np.array([0.0, 100.0, 300.0]), np.ones((3, 1)), 300.0,
                             EARTH_RADIUS_M)


@pytest.mark.parametrize("bad", ["h", "mu"])
def test_non_finite_start_points_are_refused(bad):
    h, mu = np.array([0.0, 500.0]), np.array([1.0, 0.5])
    (h if bad == "h" else mu)[1] = np.nan
    with pytest.raises(ValueError, match="finite"):
        _slant_optical_depth(h, mu, HEIGHTS, np.ones((HEIGHTS.size, 1)), TOP, EARTH_RADIUS_M)
