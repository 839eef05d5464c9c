"""The aerosol's own optics: a named type with its single-scattering albedo, asymmetry parameter, Angstrom exponent or
phase-function table replaced, from the API and the command line, held to analytic limits."""

import numpy as np
import pytest
import xarray as xr
from typer.testing import CliRunner

import swim
from swim.cli.main import app
from swim.errors import SwimInputError
from swim.optics.aerosol_types import (
    aerosol_type,
    custom_aerosol_type,
    read_phase_function_table,
)
from swim.rt.gas import AerosolBackground


def henyey_greenstein(mu, g):
    return (1 - g * g) / (1 + g * g - 2 * g * mu) ** 1.5


def test_replaced_properties_and_the_rest_kept():
    smoke = aerosol_type("smoke")
    t = custom_aerosol_type("smoke", ssa=[0.8, 0.82, 0.85], g=0.7, angstrom_exponent=1.9)
    assert t.ssa == (0.8, 0.82, 0.85) and t.angstrom_exponent == 1.9 and t.name == "smoke+custom"
    np.testing.assert_allclose(t.asymmetry_parameter(), 0.7)
    mu = np.linspace(-1, 1, 11)
    np.testing.assert_allclose(np.asarray(t.phase_function(mu))[:, 1], henyey_greenstein(mu, 0.7), rtol=1e-5)
    kept = custom_aerosol_type("smoke", ssa=0.9)
    assert kept.g1 == smoke.g1 and kept.fc == smoke.fc and kept.angstrom_exponent == smoke.angstrom_exponent


def test_a_tabulated_phase_function_is_normalised_and_keeps_its_shape():
    """A Henyey-Greenstein table (g 0.6) at 1 deg, scaled by 7: normalised back to mean 1 over the sphere, with the
    table's asymmetry parameter, and equal to the function between its angles."""
    angles = np.linspace(0.0, 180.0, 181)
    table = 7.0 * henyey_greenstein(np.cos(np.radians(angles)), 0.6)
    t = custom_aerosol_type("continental", phase_function=(angles, table))
    np.testing.assert_allclose(t.asymmetry_parameter(), 0.6, atol=2e-3)
    mu = np.cos(np.radians([0.0, 30.0, 90.0, 150.0, 180.0]))
    np.testing.assert_allclose(np.asarray(t.phase_function(mu))[:, 0], henyey_greenstein(mu, 0.6), rtol=2e-3)
    x = np.linspace(-1, 1, 20001)
    assert np.trapezoid(np.asarray(t.phase_function(x))[:, 2], x) / 2 == pytest.approx(1.0, abs=1e-4)


def test_custom_optics_change_the_render_as_they_should():
    """With the same optical depth, a more absorbing aerosol darkens the sky; the image records the optics."""
    # the paper's cloud scattering: each aerosol would otherwise cost a 3-D solve of the scene
    kw = {"camera_options": {"size": 15}, "sun_zenith": 40.0, "sun_azimuth": 150.0,
          "settings": swim.MarchSettings(cloud_scattering="albers2020")}
    bright = swim.render(swim.default_scene(), aerosol=AerosolBackground(
        aod_550=0.5, optics=custom_aerosol_type("continental", ssa=1.0)), **kw)
    dark = swim.render(swim.default_scene(), aerosol=AerosolBackground(
        aod_550=0.5, optics=custom_aerosol_type("continental", ssa=0.7)), **kw)
    clear = np.isfinite(bright["radiance_clear"].values)
    assert np.nanmean(dark["radiance_clear"].values[clear]) < 0.9 * np.nanmean(bright["radiance_clear"].values[clear])
    np.testing.assert_allclose(dark.attrs["aerosol_single_scattering_albedo"], 0.7)
    assert dark.attrs["aerosol_type"] == "continental+custom"


def test_bad_custom_optics():
    for kwargs, message in (({"ssa": 1.5}, "ssa"), ({"g": 1.2}, "g1"), ({"angstrom_exponent": 9}, "angstrom"),
                            ({"g": 0.5, "phase_function": ([0, 180], [1, 1])}, "not both"),
                            ({"phase_function": ([10, 180], [1, 1])}, "0 to 180"),
                            ({"phase_function": ([0, 180], [1, -1])}, "negative"),
                            ({"ssa": [0.9, 0.9]}, "three")):
        with pytest.raises(SwimInputError, match=message):
            custom_aerosol_type("continental", **kwargs)
    with pytest.raises(SwimInputError, match="AerosolType"):
        AerosolBackground(optics="smoke")


def test_the_command_line_takes_the_aerosol_s_own_optics(tmp_path):
    table = tmp_path / "phase.txt"
    table.write_text("# angle [deg], P\nangle P\n0, 10\n90, 0.4\n180, 0.2\n")
    angles, _values = read_phase_function_table(table)
    np.testing.assert_array_equal(angles, [0, 90, 180])
    nc = tmp_path / "a.nc"
    result = CliRunner().invoke(app, ["render", "--aerosol", "smoke", "--aod", "0.4", "--aerosol-ssa", "0.8,0.82,0.85",
                                      "--aerosol-angstrom", "2", "--aerosol-scale-height", "3", "--aerosol-phase",
                                      str(table), "--size", "9", "--sun-zenith", "40", "--sun-azimuth", "150",
                                      "--cloud-scattering", "albers2020", "--out", str(tmp_path / "a.png"),
                                      "--netcdf", str(nc)])
    assert result.exit_code == 0, result.output
    with xr.open_dataset(nc) as image:
        np.testing.assert_allclose(image.attrs["aerosol_single_scattering_albedo"], [0.8, 0.82, 0.85])
        assert image.attrs["aerosol_angstrom_exponent"] == 2.0 and image.attrs["aerosol_scale_height_m"] == 3000.0
    for args, message in ((["--aerosol-g", "0.7", "--aerosol-phase", str(table)], "not both"),
                          (["--aerosol-ssa", "high"], "--aerosol-ssa"),
                          (["--aerosol-phase", str(tmp_path / "missing.txt")], "not found"),
                          (["--aerosol", "none", "--aerosol-g", "0.5"], "no optics")):
        out = tmp_path / "x.png"
        result = CliRunner().invoke(app, ["render", *args, "--size", "9", "--out", str(out)])
        assert result.exit_code == 2 and message in result.output, result.output
        assert len(result.output.strip().splitlines()) == 1 and not out.exists()
