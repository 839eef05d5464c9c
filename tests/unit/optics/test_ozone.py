"""Ozone absorption (swim.optics.ozone) and its place in the clear-air tables (swim.rt.gas)."""

from __future__ import annotations

import numpy as np
import pytest

from swim.errors import SwimInputError
from swim.optics.ozone import (
    DOBSON_UNIT_M2,
    US_STANDARD_OZONE_DU,
    ozone_absorption_coefficient,
    ozone_column_du,
    ozone_cross_section,
    ozone_number_density,
)
from swim.rt.gas import AerosolBackground, build_gas_tables

HEIGHTS = np.arange(0.0, 100_001.0, 100.0)


def test_cross_sections_match_published_serdyuchenko_points():
    """Point values of the Bremen 233 K spectrum (Serdyuchenko et al. 2014, as sampled by CalcMySky at 548.0
    and 610.7 nm: 3.264e-21 and 4.544e-21 cm2): the 10 nm means agree within the band's fine structure (4 %)."""
    got = ozone_cross_section([548.0, 610.7]) * 1e4  # [cm2]
    np.testing.assert_allclose(got, [3.264e-21, 4.544e-21], rtol=0.04)


def test_chappuis_band_shape():
    """The Chappuis band peaks near 600 nm at ~5e-21 cm2 (Gorshelev et al. 2014, Fig. 9: 5.0-5.2e-21 at 603 nm) and
    is ~20 times weaker at 450 nm than at 615 nm."""
    lam = np.arange(405.0, 696.0, 1.0)
    sigma = ozone_cross_section(lam) * 1e4
    assert 595.0 <= lam[np.argmax(sigma)] <= 610.0
    assert 4.8e-21 <= sigma.max() <= 5.3e-21
    s615, s546, s450 = ozone_cross_section([615.0, 546.0, 450.0])
    assert s615 > s546 > 10 * s450


def test_cross_section_range_checked():
    with pytest.raises(SwimInputError, match="wavelength_nm"):
        ozone_cross_section(380.0)
    with pytest.raises(SwimInputError, match="wavelength_nm"):
        ozone_cross_section([np.nan])


def test_us_standard_column_and_peak():
    """The US standard ozone (Anderson et al. 1986) holds ~345 DU, with its number-density peak of ~4.9e12 cm-3 at
    20-25 km (AFGL-TR-86-0110: 3.647 ppmv x 1.342e18 cm-3 at 22 km)."""
    assert 340.0 <= US_STANDARD_OZONE_DU <= 350.0
    n = ozone_number_density(HEIGHTS)
    assert ozone_column_du(HEIGHTS, n) == pytest.approx(US_STANDARD_OZONE_DU, rel=2e-3)
    assert 20_000.0 <= HEIGHTS[np.argmax(n)] <= 25_000.0
    assert n.max() * 1e-6 == pytest.approx(4.89e12, rel=0.05)


def test_profile_scales_to_column():
    n = ozone_number_density(HEIGHTS, 250.0)
    assert ozone_column_du(HEIGHTS, n) == pytest.approx(250.0, rel=2e-3)
    assert np.all(ozone_number_density(HEIGHTS, 0.0) == 0.0)
    with pytest.raises(SwimInputError, match="DU"):
        ozone_number_density(HEIGHTS, -1.0)


def test_vertical_optical_depth():
    """Vertical optical depth of 345.5 DU: sigma x column, ~0.04 at 615 nm (e.g. Gueymard's 0.0385 at 600 nm per
    300 DU), < 0.002 at 450 nm."""
    beta = ozone_absorption_coefficient(HEIGHTS, [615.0, 546.0, 450.0])
    tau = np.trapezoid(beta, HEIGHTS, axis=0)
    np.testing.assert_allclose(tau, ozone_cross_section([615.0, 546.0, 450.0]) * US_STANDARD_OZONE_DU * DOBSON_UNIT_M2,
                               rtol=2e-3)
    assert 0.035 <= tau[0] <= 0.045 and tau[2] < 0.002


def test_aerosol_background_checks_ozone():
    assert AerosolBackground().ozone_du == US_STANDARD_OZONE_DU
    with pytest.raises(SwimInputError, match="ozone"):
        AerosolBackground(ozone_du=-5.0)
    with pytest.raises(SwimInputError, match="ozone"):
        AerosolBackground(ozone_du=float("nan"))


@pytest.fixture(scope="module")
def tables():
    clear = AerosolBackground(aod_550=0.0)
    return build_gas_tables(clear), build_gas_tables(AerosolBackground(aod_550=0.0, ozone_du=0.0))


def test_sun_transmittance_holds_the_ozone(tables):
    """Overhead sun at the ground: the ratio with / without ozone is e^-tau_O3; for a grazing sun at 10 km the
    ozone layer's long slant path takes most of the red and green light but little of the blue (twilight)."""
    gas, bare = tables
    assert gas.beta_ozone is not None and np.all(bare.beta_ozone == 0)
    tau = np.trapezoid(np.asarray(gas.beta_ozone, float), HEIGHTS, axis=0)
    mu = np.linspace(-1.0, 1.0, gas.n_mu)
    ratio = gas.sun_transmittance[0, -1] / bare.sun_transmittance[0, -1]
    np.testing.assert_allclose(ratio, np.exp(-tau), rtol=2e-3)
    u = np.linspace(0.0, 1.0, gas.n_u)
    iu, im = int(np.argmin(np.abs(u - np.sqrt(0.1)))), int(np.argmin(np.abs(mu)))  # 10 km, horizontal sun
    grazing = gas.sun_transmittance[iu, im] / bare.sun_transmittance[iu, im]
    assert grazing[0] < 0.6 and grazing[1] < 0.7 and grazing[2] > 0.95


def test_diffuse_tables_absorb(tables):
    """The multiple-scattering tables see the ozone: less diffuse light at 615 nm, almost none lost at 450 nm."""
    gas, bare = tables
    ratio = gas.diffuse_horizontal[0, -1] / bare.diffuse_horizontal[0, -1]
    assert 0.93 < ratio[0] < 0.985 and ratio[2] > 0.995
