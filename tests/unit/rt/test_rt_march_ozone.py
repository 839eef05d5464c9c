"""Ozone's absorption along the line of sight: the kernels' clear-air height table, the marches' optical depth and the
3-D diffuse field's air optics (docs/decisions/0023-ozone-and-twilight.md, docs/rendering.md "Ozone and twilight").

The outside numbers: the Bremen ozone cross sections at 233 K as 10 nm means (Serdyuchenko et al. 2014,
doi:10.5194/amt-7-625-2014): 4.305, 3.132 and 0.195 x 10^-21 cm2 at 615, 546 and 450 nm; the US standard ozone
column 345.5 DU (Anderson et al. 1986, AFGL-TR-86-0110); one Dobson unit 2.6867e20 molecules m-2.
"""

from __future__ import annotations

import numpy as np
import pytest

from swim.constants import EARTH_RADIUS_M, GAS_COLUMN_ROW, GAS_OZONE_ROW
from swim.frames import enu_from_azimuth_zenith
from swim.io.scene import scene_from_arrays
from swim.optics.rayleigh import rayleigh_phase_function
from swim.optics.volume import build_optical_volume
from swim.rt.gas import AerosolBackground, build_gas_tables
from swim.rt.march import trace_rays
from swim.rt.march_inputs import atmosphere_constants, grid_geometry, kernel_constants
from swim.rt.march_settings import ExecutionSettings, MarchSettings
from swim.rt.reference import reference_trace_ray
from swim.rt.solar import solar_transmittance

#: Bremen 233 K cross sections, 10 nm means at 615, 546, 450 nm [m2] (module docstring).
BREMEN_M2 = np.array([4.305e-25, 3.132e-25, 0.195e-25])
#: The US standard ozone column [DU] and one Dobson unit [m-2].
COLUMN_DU, DOBSON_M2 = 345.5, 2.6867e20
#: Vertical ozone optical depth of the US standard column at 615, 546, 450 nm (0.040, 0.029, 0.0018).
TAU_OZONE = BREMEN_M2 * COLUMN_DU * DOBSON_M2

WITH, WITHOUT = AerosolBackground(), AerosolBackground(ozone_du=0.0)


def _clear_scene():
    """A cloud-free 12 x 12 x 20 grid (400 m, 250 m) over flat land at sea level."""
    n, spacing = 12, 400.0
    x = (np.arange(n) - n / 2 + 0.5) * spacing
    z = np.arange(0.0, 5000.0, 250.0) + 125.0
    zero = np.zeros((z.size, n, n))
    return scene_from_arrays(x=x, y=x, z=z, reference_lat=30.0, reference_lon=10.0, terrain_height=np.zeros((n, n)),
                             cloud_liquid_content=zero, cloud_ice_content=zero, land_mask=1.0)


def _trace(aerosol, origins, dirs, sun, backend="numba"):
    """The march's outputs for rays (n, 3) from ``origins`` (n, 3) [m, scene frame], and its inputs."""
    volume = build_optical_volume(_clear_scene())
    transmittance = solar_transmittance(volume, sun)
    gas = build_gas_tables(aerosol)
    consts = kernel_constants(volume, transmittance, gas, sun)
    cos_theta = dirs @ sun
    phase = {"cos_theta": cos_theta, "cos_view_zenith": dirs[:, 2],
             "p_rayleigh": np.asarray(rayleigh_phase_function(cos_theta, gas.depolarization)),
             "p_aerosol": np.asarray(aerosol.type.phase_function(cos_theta)),
             "p_stratospheric": np.asarray(aerosol.stratospheric.phase_function(cos_theta))}
    settings = MarchSettings(execution=ExecutionSettings(backend=backend))
    return trace_rays(origins, dirs, consts, grid_geometry(volume), phase, settings), (volume, transmittance, gas,
                                                                                      phase)


def _rays():
    """From the ground: up and 60° from the zenith; from 400 km: straight down and 60° off nadir."""
    ground = np.array([0.0, 0.0, EARTH_RADIUS_M + 2.0])
    space = np.array([0.0, 0.0, EARTH_RADIUS_M + 400e3])
    dirs = np.array([[0.0, 0.0, 1.0], enu_from_azimuth_zenith(90.0, 60.0), [0.0, 0.0, -1.0],
                     enu_from_azimuth_zenith(90.0, 120.0)])
    return np.array([ground, ground, space, space]), dirs


def test_the_height_table_holds_ozone_in_its_own_row():
    """atmosphere_constants: four extinction profiles, ozone's in row GAS_OZONE_ROW with the Bremen cross sections'
    ratios as its spectrum, its column at 546 nm the US standard's, then the column row; without ozone that row is
    zero and every other row the same bits (the column row counts the scattering components only)."""
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    gas, bare = build_gas_tables(WITH), build_gas_tables(WITHOUT)
    c, c0 = atmosphere_constants(gas, sun), atmosphere_constants(bare, sun)
    table, spectra = np.asarray(c["beta_gas"], float), np.asarray(c["beta_gas_spectra"], float)
    assert GAS_OZONE_ROW == 3 and GAS_COLUMN_ROW == 4
    assert table.shape[0] == GAS_COLUMN_ROW + 1 and spectra.shape == (GAS_COLUMN_ROW, 3)
    np.testing.assert_allclose(spectra[GAS_OZONE_ROW], BREMEN_M2 / BREMEN_M2[0], rtol=2e-3)
    column = np.trapezoid(table[GAS_OZONE_ROW] * spectra[GAS_OZONE_ROW, 1], dx=float(c["dh"]))
    assert column == pytest.approx(TAU_OZONE[1], rel=5e-3)
    np.testing.assert_allclose(table[GAS_OZONE_ROW][:, None] * spectra[GAS_OZONE_ROW][None, :], gas.beta_ozone,
                               rtol=1e-5, atol=1e-12)
    bare_table = np.asarray(c0["beta_gas"])
    assert not np.any(bare_table[GAS_OZONE_ROW])
    rows = [r for r in range(table.shape[0]) if r != GAS_OZONE_ROW]
    np.testing.assert_array_equal(np.asarray(c["beta_gas"])[rows], bare_table[rows])
    np.testing.assert_array_equal(np.asarray(c["beta_gas_spectra"])[:GAS_OZONE_ROW],
                                  np.asarray(c0["beta_gas_spectra"])[:GAS_OZONE_ROW])


@pytest.mark.parametrize("backend", [pytest.param("jax", marks=pytest.mark.full), "numba"])
def test_the_line_of_sight_carries_the_ozone_column_and_no_light_from_it(backend):
    """The march's clear optical depth gains the ozone of the path: the vertical column (Bremen x 345.5 DU) looking
    up or down, the air mass in the ozone layer times it at 60° from the zenith or the nadir (within 1.5 %), as the
    float64 reference march finds. Ozone only absorbs: every radiance falls (most at 615 nm, the views from space by
    about the two-way path's e^-tau at 615 nm) and none gains light; at 450 nm (tau 0.002) the change is < 1 %."""
    sun = enu_from_azimuth_zenith(135.0, 30.0)
    origins, dirs = _rays()
    out, (volume, transmittance, gas, phase) = _trace(WITH, origins, dirs, sun, backend)
    bare, _ = _trace(WITHOUT, origins, dirs, sun, backend)
    # the slant rays' air mass in the ozone layer (its middle, ~25 km): sin(zenith) grows as 1 / (R + h)
    start = np.array([2.0, 2.0, 400e3, 400e3])
    sin_zenith = np.hypot(dirs[:, 0], dirs[:, 1]) * (EARTH_RADIUS_M + start) / (EARTH_RADIUS_M + 25e3)
    air_mass = 1.0 / np.sqrt(1.0 - sin_zenith**2)
    assert air_mass[1] == pytest.approx(1.98, abs=0.01) and air_mass[3] == pytest.approx(2.51, abs=0.01)
    gained = out["tau_clear"] - bare["tau_clear"]
    np.testing.assert_allclose(gained, air_mass[:, None] * TAU_OZONE[None, :], rtol=0.015)
    bare_gas = build_gas_tables(WITHOUT)
    for n in (1, 2):  # the reference march, with its own lookups of GasTables.beta_ozone, gains the same
        ref, ref0 = (reference_trace_ray(origins[n], dirs[n], volume, transmittance, g, sun, phase["p_rayleigh"][n],
                                         phase["p_aerosol"][n], step_m=200.0,
                                         p_stratospheric=phase["p_stratospheric"][n]) for g in (gas, bare_gas))
        np.testing.assert_allclose(gained[n], ref["tau_clear"] - ref0["tau_clear"], rtol=0.01)
        np.testing.assert_allclose(out["tau_clear"][n], ref["tau_clear"], rtol=0.03)
        np.testing.assert_allclose(out["radiance"][n], ref["radiance"], rtol=0.03)
        np.testing.assert_allclose(out["radiance"][n] / bare["radiance"][n], ref["radiance"] / ref0["radiance"],
                                   rtol=2e-3)
    ratio = out["radiance"] / bare["radiance"]
    assert np.all(ratio < 1.0) and np.all(ratio[:, 0] < ratio[:, 2]), ratio
    assert np.all(ratio[:, 2] > 0.99), ratio
    # from space the light crossed the column on its way down and again on its way up (mu0 = cos 30°, mu = 1)
    two_way = np.exp(-TAU_OZONE[0] * (1.0 / np.cos(np.radians(30.0)) + 1.0))
    assert ratio[2, 0] == pytest.approx(two_way, rel=0.02), (ratio[2, 0], two_way)


def test_the_diffuse_fields_air_absorbs_the_ozone_and_scatters_as_before():
    """swim.rt.diffuse_field's air optics: the extinction gains ozone's absorption coefficient (its column the
    US standard's), the scattering moments are the same bits."""
    from swim.rt.diffuse_field import _air_optics

    z = np.arange(0.0, 100e3, 250.0) + 125.0
    beta, sigma = _air_optics(build_gas_tables(WITH), z, 2)
    beta0, sigma0 = _air_optics(build_gas_tables(WITHOUT), z, 2)
    np.testing.assert_array_equal(sigma, sigma0)
    np.testing.assert_allclose(np.sum(beta - beta0, axis=0) * 250.0, TAU_OZONE, rtol=5e-3)
    assert np.all(beta - beta0 >= 0.0)
