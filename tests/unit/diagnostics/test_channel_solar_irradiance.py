"""The extraterrestrial spectral irradiance at the renderer's wavelengths, which turns L' into absolute radiance:
against the ASTM G173-03 table itself (its 0.5-1 nm resolution data, not the binned package copy) and written to
netCDF as ``radiance_absolute``."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from swim.constants import SOLAR_CONSTANT_W_M2, SOLAR_SPECTRAL_IRRADIANCE_W_M2_NM, WAVELENGTHS_NM
from swim.diagnostics.broadband import ASTM_G173_TSI_W_M2, channel_solar_irradiance
from swim.errors import SwimInputError
from swim.io.outputs import with_absolute_radiance, write_netcdf


def test_the_constant_is_the_spectrum_at_the_channels():
    np.testing.assert_allclose(SOLAR_SPECTRAL_IRRADIANCE_W_M2_NM, channel_solar_irradiance(), atol=6e-5)
    np.testing.assert_allclose(channel_solar_irradiance(earth_sun_distance_au=0.983),
                               channel_solar_irradiance() / 0.983**2, rtol=1e-12)


@pytest.mark.realdata
def test_against_the_astm_g173_table(shared_data):
    table = np.genfromtxt(shared_data / "obs" / "ASTMG173.csv", delimiter=",", skip_header=2)
    wl, etr = table[:, 0], table[:, 1]
    scale = SOLAR_CONSTANT_W_M2 / ASTM_G173_TSI_W_M2
    for w, e in zip(WAVELENGTHS_NM, channel_solar_irradiance()):
        window = (wl >= w - 10) & (wl <= w + 10)  # the 20 nm around the wavelength: the Fraunhofer lines averaged
        assert e == pytest.approx(scale * etr[window].mean(), rel=0.04)


def test_bad_arguments_are_named():
    with pytest.raises(SwimInputError, match="wavelengths_nm"):
        channel_solar_irradiance([100.0])
    with pytest.raises(SwimInputError, match="earth_sun_distance_au"):
        channel_solar_irradiance(earth_sun_distance_au=0.0)


def test_netcdf_holds_the_absolute_radiance(tmp_path):
    radiance = np.full((3, 2, 2), 4.0 * np.pi, np.float32)
    image = xr.Dataset({"radiance": (("wavelength", "y", "x"), radiance)},
                       coords={"wavelength": WAVELENGTHS_NM},
                       attrs={"toa_spectral_irradiance": SOLAR_SPECTRAL_IRRADIANCE_W_M2_NM})
    path = write_netcdf(image, tmp_path / "x.nc")
    with xr.open_dataset(path) as out:
        np.testing.assert_allclose(out["radiance_absolute"].values[:, 0, 0], SOLAR_SPECTRAL_IRRADIANCE_W_M2_NM,
                                   rtol=1e-6)
        assert out["radiance_absolute"].attrs["units"] == "W m-2 sr-1 nm-1"
    assert with_absolute_radiance(image.drop_attrs()).equals(image.drop_attrs())
