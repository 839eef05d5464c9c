"""US Standard Atmosphere 1976 against the Standard's printed values (NOAA-S/T 76-1562, Tables I-II)."""

import numpy as np
import pytest

from swim.errors import SwimInputError
from swim.optics.atmosphere import us_standard_atmosphere_1976

R0 = 6_356_766.0  # US76 earth radius for geopotential height [m]
M0, R_STAR = 28.9644, 8314.32  # US76 [kg kmol-1], [J kmol-1 K-1]


def _geometric(geopotential_m):
    return R0 * geopotential_m / (R0 - geopotential_m)


def test_sea_level():
    t, p, n = us_standard_atmosphere_1976(0.0)
    assert t == pytest.approx(288.15, abs=1e-9)
    assert p == pytest.approx(101_325.0, rel=1e-12)
    assert n == pytest.approx(2.5470e25, rel=1e-4)  # US76 sea-level number density
    assert p * M0 / (R_STAR * t) == pytest.approx(1.2250, rel=1e-4)  # US76 sea-level density [kg m-3]


def test_tropopause_at_11_km_geopotential():
    t, p, _ = us_standard_atmosphere_1976(_geometric(11_000.0))
    assert t == pytest.approx(216.65, abs=1e-6)
    assert p == pytest.approx(22_632.06, rel=1e-5)


@pytest.mark.parametrize(
    "z_m, t_k, p_pa",
    [
        (20_000.0, 216.650, 5_529.3),  # geometric heights, US76 Table I
        (50_000.0, 270.650, 79.779),
        (80_000.0, 198.639, 1.0524),
        (86_000.0, 186.87, 0.37338),
    ],
)
def test_published_rows(z_m, t_k, p_pa):
    t, p, _ = us_standard_atmosphere_1976(z_m)
    assert t == pytest.approx(t_k, abs=0.005)
    assert p == pytest.approx(p_pa, rel=1e-4)


def test_density_at_20_km():
    t, p, _ = us_standard_atmosphere_1976(20_000.0)
    assert p * M0 / (R_STAR * t) == pytest.approx(0.088910, rel=1e-4)


def test_extension_to_100_km_within_one_percent_of_the_standard():
    t, p, n = us_standard_atmosphere_1976(np.array([90_000.0, 100_000.0]))
    assert t[0] == pytest.approx(186.87, abs=0.01)
    assert t[1] == pytest.approx(195.08, abs=0.01)  # elliptical arc of US76 Sect. 1.3.2
    assert p[0] == pytest.approx(0.18359, rel=0.01)
    assert p[1] == pytest.approx(0.032011, rel=0.01)
    assert n[1] == pytest.approx(1.189e19, rel=0.01)


def test_shape_monotonic_pressure_and_continuity_at_86_km():
    z = np.linspace(0.0, 100_000.0, 2001).reshape(3, 667)
    t, p, n = us_standard_atmosphere_1976(z)
    assert t.shape == p.shape == n.shape == z.shape
    assert np.all(np.diff(p.ravel()) < 0)
    _, p_below, _ = us_standard_atmosphere_1976(86_000.0 - 1e-3)
    _, p_above, _ = us_standard_atmosphere_1976(86_000.0 + 1e-3)
    assert p_above == pytest.approx(p_below, rel=1e-6)


@pytest.mark.parametrize("bad", [-6_000.0, 100_001.0])
def test_out_of_range_raises(bad):
    with pytest.raises(SwimInputError, match="height_m"):
        us_standard_atmosphere_1976(np.array([0.0, bad]))
