"""Ozone in the clear sky: the twilight zenith against libRadtran's MYSTIC, and the DISORT layers' ozone.

The reference is libRadtran's spherical Monte Carlo example (``UVSPEC_MC_SPHERICAL``: US standard atmosphere and
ozone, 500 nm, sun zenith 92°, no aerosol, albedo 0, earth radius 6370 km, zenith view): I = 4.027e-4 per unit
extraterrestrial irradiance (polarised), i.e. L' = 4 pi I = 5.06e-3 (Mayer 2009, EPJ Web of Conferences 1, 75-99,
doi:10.1140/epjconf/e2009-00912-1; Emde and Mayer 2007, Atmos. Chem. Phys. 7, 2259-2270,
doi:10.5194/acp-7-2259-2007). swim's scalar result must be within 20 % (docs/rendering.md, "Ozone and twilight").
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from swim.optics.ozone import DOBSON_UNIT_M2, US_STANDARD_OZONE_DU, ozone_cross_section
from swim.rt.gas import AerosolBackground
from swim.rt.march_settings import MarchSettings

pytestmark = pytest.mark.validation

#: MYSTIC's zenith radiance at 500 nm, sun zenith 92°: L' = 4 pi x 4.027e-4 (module docstring).
MYSTIC_ZENITH_500NM_SZA92 = 4.0 * np.pi * 4.027e-4


def _zenith_radiance(monkeypatch, sun_zenith_deg, aerosol, wavelength_nm=500.0, multiple_scattering=True):
    """swim's clear-sky zenith L' (3,) over a black sea at ``wavelength_nm`` in every channel (the gas tables of
    :func:`swim.rt.gas.build_gas_tables` at that wavelength)."""
    import swim.pipeline.tables as tables
    from swim.pipeline import render
    from swim.rt import gas
    from swim.validation.disort import clear_scene, reference_settings

    build = gas.build_gas_tables

    def at_wavelength(aer, *args, **kwargs):
        kwargs["wavelengths_nm"] = (wavelength_nm,) * 3
        return build(aer, *args, **kwargs)

    monkeypatch.setattr(tables, "build_gas_tables", at_wavelength)
    settings = reference_settings(dataclasses.replace(MarchSettings(), multiple_scattering=multiple_scattering))
    ds = render(clear_scene(0.0), camera="allsky", camera_options={"size": 21}, sun_zenith=float(sun_zenith_deg),
                sun_azimuth=270.0, aerosol=aerosol, settings=settings, height=0.0)
    return np.asarray(ds["radiance"].values[:, 10, 10], dtype=float)


def test_twilight_zenith_against_mystic(monkeypatch):
    """Sun 2° below the horizon, 500 nm: measured L' = 5.45e-3 (+7.8 % against MYSTIC's polarised 5.06e-3), of which
    single scattering is 4.19e-3 and the higher orders of the pseudo-spherical successive-orders table the rest
    (docs/decisions/0023-ozone-and-twilight.md)."""
    got = _zenith_radiance(monkeypatch, 92.0, AerosolBackground(aod_550=0.0))
    assert np.allclose(got, got[0], rtol=1e-5)
    assert abs(got[0] / MYSTIC_ZENITH_500NM_SZA92 - 1.0) < 0.20, got[0]
    single = _zenith_radiance(monkeypatch, 92.0, AerosolBackground(aod_550=0.0), multiple_scattering=False)
    # the higher orders are a fifth to a third of the twilight zenith (the earth's shadow's own light)
    assert 0.15 < 1.0 - single[0] / got[0] < 0.35, (single[0], got[0])


def test_twilight_zenith_ozone_absorption_size(monkeypatch):
    """The ozone's share of the twilight zenith at 500 nm: the sunlight that reaches the scattering air ~20 km above
    the observer crossed the ozone layer on a grazing path ~20-40 times the vertical column, so the ratio with / without
    ozone lies between e^(-40 tau) and e^(-10 tau), tau = sigma(500 nm) x 345.5 DU = 0.011."""
    with_o3 = _zenith_radiance(monkeypatch, 92.0, AerosolBackground(aod_550=0.0), multiple_scattering=False)
    without = _zenith_radiance(monkeypatch, 92.0, AerosolBackground(aod_550=0.0, ozone_du=0.0),
                               multiple_scattering=False)
    tau = float(ozone_cross_section(500.0)) * US_STANDARD_OZONE_DU * DOBSON_UNIT_M2
    ratio = with_o3[0] / without[0]
    assert np.exp(-40 * tau) < ratio < np.exp(-10 * tau), (ratio, tau)


def test_disort_layers_hold_the_ozone():
    """DISORT's layers carry the ozone column sigma x N (absorption only: the scattering is unchanged)."""
    from swim.validation.disort import clear_sky_layers

    with_o3 = clear_sky_layers(AerosolBackground(aod_550=0.0))
    without = clear_sky_layers(AerosolBackground(aod_550=0.0, ozone_du=0.0))
    tau = ozone_cross_section([615.0, 546.0, 450.0]) * US_STANDARD_OZONE_DU * DOBSON_UNIT_M2
    np.testing.assert_allclose(with_o3["tau_ozone"], tau, rtol=5e-3)
    np.testing.assert_allclose(with_o3["dtau"].sum(axis=0) - without["dtau"].sum(axis=0), tau, rtol=5e-3)
    np.testing.assert_allclose(with_o3["dtau"] * with_o3["ssa"], without["dtau"] * without["ssa"], rtol=1e-6)


def test_from_space_with_ozone_against_disort():
    """Views from space cross the whole ozone column twice, on the way down (the sun's transmittance table) and on
    the way up (the march's extinction along the line of sight): with ozone only in the former swim was 3-8 % too
    bright at 615 nm against DISORT (median 4.4 / 3.0 / 0.3 %); with both, the Rayleigh sky at sun zenith 30° is
    within 0.7 % (median 0.15 / 0.28 / 0.52 %), as close as without ozone (0.24 / 0.34 / 0.52 %)."""
    from swim.validation.disort import compare_space_clear

    r = compare_space_clear(30.0, AerosolBackground(aod_550=0.0))
    assert np.all(r["max_abs"] < 0.01), r["max_abs"]
    assert np.all(r["median_abs"] < 0.008), r["median_abs"]
