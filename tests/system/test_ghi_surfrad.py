"""GHI forward operator end to end: clear sky at Alamosa (2317 m) against pvlib's clear-sky models and the
SURFRAD measurements of 2016-01-01 (docs/irradiance.md; ~2 min on 2 cores).

Atmosphere (the same for swim and the models): continental aerosol (Angstrom 1.4) with AOD 0.03 at 550 nm
above the site -- a plausible clean winter value for a dry high-altitude site (SURFRAD AOD climatology,
Augustine et al. 2008, doi:10.1029/2007JD009504) and the value at which the observed DNI is flat in its
ratio to swim's across air mass 2-7 (docs/irradiance.md) --, precipitable water from the station's
temperature and humidity (Gueymard 1994: 0.33 cm), ozone 0.30 atm-cm, the station's albedo (0.18).
"""

import numpy as np
import pandas as pd
import pvlib
import pytest
import typer
from typer.testing import CliRunner

from swim.diagnostics.ghi import (DEFAULT_SIZE, aerosol_for_site, attach_observations, clear_site_scene,
                                  error_statistics, ghi_at_sun_zeniths, ghi_time_series, pvlib_clear_sky,
                                  site_aod_550, time_range)
from swim.io.observations import clear_periods, observations_at, observed_albedo, observed_precipitable_water
from swim.io.surfrad import read_surfrad

pytestmark = [pytest.mark.realdata, pytest.mark.slow]

AOD_550 = 0.03
OZONE = 0.30


@pytest.fixture(scope="module")
def site(shared_data):
    path = shared_data / "obs" / "surfrad-slv16001.dat"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    obs = read_surfrad(path)
    lat, lon, elev = obs.attrs["latitude"], obs.attrs["longitude"], obs.attrs["elevation_m"]
    albedo = observed_albedo(obs)
    return {"obs": obs, "path": path, "lat": lat, "lon": lon, "elev": elev, "albedo": albedo,
            "pw": observed_precipitable_water(obs), "scene": clear_site_scene(lat, lon, elev, surface_albedo=albedo),
            "aerosol": aerosol_for_site(AOD_550, elev + 2.0, "continental")}


@pytest.fixture(scope="module")
def day(site):
    """30-min renders from 15:00 to 23:30 UTC (sunrise 14:20, sunset 00:05 UTC), with the observations."""
    times = time_range("2016-01-01T15:00Z", "2016-01-01T23:30Z", "30min")
    sim = ghi_time_series(site["scene"], site["lat"], site["lon"], times, aerosol=site["aerosol"],
                          precipitable_water_cm=site["pw"], ozone_atm_cm=OZONE)
    clear = clear_periods(site["obs"])
    return attach_observations(sim, observations_at(site["obs"], sim.index, clear=clear))


def _models(site, sim):
    return pvlib_clear_sky(sim["sun_zenith_deg"], elevation_m=sim.attrs["observer_height_asl_m"],
                           aod_550=site_aod_550(site["aerosol"], sim.attrs["observer_height_asl_m"]),
                           angstrom_exponent=site["aerosol"].type.angstrom_exponent, precipitable_water_cm=site["pw"],
                           ozone_atm_cm=OZONE, pressure_pa=sim.attrs["pressure_pa"],
                           earth_sun_distance_au=sim["earth_sun_distance_au"], surface_albedo=site["albedo"])


@pytest.fixture(scope="module")
def zeniths(site):
    sim = ghi_at_sun_zeniths(site["scene"], site["lat"], site["lon"], [0.0, 30.0, 60.0, 70.0], aerosol=site["aerosol"],
                             precipitable_water_cm=site["pw"], ozone_atm_cm=OZONE, earth_sun_distance_au=1.0)
    return sim, _models(site, sim)


def test_swim_sees_the_atmosphere_it_was_given(day, site):
    """The direct beam's non-Rayleigh extinction is the aerosol above the site, with its Angstrom exponent."""
    up = day["rendered"] & (day["sun_zenith_deg"] < 80)
    np.testing.assert_allclose(day.loc[up, "aod_550_fit"], AOD_550, rtol=0.05)
    np.testing.assert_allclose(day.loc[up, "angstrom_fit"], site["aerosol"].type.angstrom_exponent, atol=0.1)
    assert day.attrs["aerosol_aod_550_site"] == pytest.approx(AOD_550)


def test_clear_sky_against_pvlib_models_by_zenith(zeniths):
    """swim GHI vs pvlib for the same AOD, water vapour, ozone and pressure (docs/irradiance.md, Table 3).

    Measured (AOD 0.03, pw 0.33 cm, 2317 m), zenith 0/30/60/70 deg: vs Ineichen-Perez -2.97/-2.8/-1.1/+1.6 %
    (the margin at zenith 0 is small: the 3 % goal is the bound), vs simplified Solis +1.7 ... +2.5 %,
    vs SPCTRL2 +0.4 ... +1.8 %, vs Bird +3.5 ... +4.4 %.
    """
    sim, ref = zeniths
    for model, bound in (("ineichen", 3.0), ("solis", 3.0), ("spectrl2", 3.0)):
        err = 100 * (sim["ghi"].values / ref[f"{model}_ghi"].values - 1)
        assert np.all(np.abs(err) < bound), (model, err)
    # Bird & Hulstrom misses the 3 % goal by +0.5 ... +1.5 %: swim is 3.5-4.5 % brighter (next test: why).
    err_bird = 100 * (sim["ghi"].values / ref["bird_ghi"].values - 1)
    assert np.all((err_bird > 2.5) & (err_bird < 5.5)), err_bird


def test_the_gap_to_bird_is_birds_aerosol_and_gas_parameterisation(zeniths, site):
    """Bird's broadband aerosol transmittance (tau_a^0.873 law of the broadband AOD 0.2758 tau_380 +
    0.35 tau_500) removes 1.7-4.2 % more light (zenith 0-70 deg) than Beer-Lambert over the Angstrom
    spectrum that swim and SPCTRL2 use, and its aerosol-free DNI (0.9662 band factor, broadband gas fits)
    is 2.3-0.6 % below SPCTRL2's."""
    sim, ref = zeniths
    z = sim["sun_zenith_deg"].values
    am = pvlib.atmosphere.get_relative_airmass(z, "kastenyoung1989")
    p, pw, alpha = sim.attrs["pressure_pa"], site["pw"], site["aerosol"].type.angstrom_exponent
    aod = {lam: AOD_550 * (lam / 550.0) ** -alpha for lam in (380.0, 500.0)}
    bird = pvlib.clearsky.bird(z, am, aod[380.0], aod[500.0], pw, OZONE, p, dni_extra=1362.0)["dni"]
    bird0 = pvlib.clearsky.bird(z, am, 0.0, 0.0, pw, OZONE, p, dni_extra=1362.0)["dni"]
    clean = pvlib_clear_sky(pd.Series(z), elevation_m=site["elev"], aod_550=0.0, angstrom_exponent=alpha,
                            precipitable_water_cm=pw, ozone_atm_cm=OZONE, pressure_pa=p, surface_albedo=site["albedo"])
    spectral_aerosol = ref["spectrl2_dni"].values / clean["spectrl2_dni"].values
    assert np.all(bird / bird0 < spectral_aerosol - 0.015)  # Bird: 1.7-4.2 % more aerosol extinction
    assert np.all(bird0 < clean["spectrl2_dni"].values)  # and less aerosol-free DNI
    assert bird0[0] < 0.98 * clean["spectrl2_dni"].values[0]
    # Together they account for swim's DNI excess over Bird to within 1.5 %.
    predicted = (spectral_aerosol / (bird / bird0)) * (clean["spectrl2_dni"].values / bird0)
    np.testing.assert_allclose(sim["dni"].values / ref["bird_dni"].values, predicted, rtol=0.015)


def test_surfrad_clear_day(day):
    """SURFRAD Alamosa, 2016-01-01, clear 30-min instants with zenith < 85 deg (16 of them).

    Measured: GHI MBE -13.6 W m-2 (-3.3 %), RMSE 15.7 W m-2 (3.8 %); DNI -5.3 %; DHI +2.0 %. The paper's
    546 nm proxy: MBE +5.1 % (+12.3 % before the renderer's clear air absorbed in ozone's Chappuis band). Bound |MBE| < 5 %: the sum of the a priori aerosol uncertainty (AOD 0.03 +-
    0.02: +-2 %), the conversion (+1.7 % vs SMARTS) and the instruments' calibration (+-2 %).
    """
    mask = day["clear"].values & day["rendered"].values
    assert mask.sum() >= 14
    ghi = error_statistics(day["ghi"], day["ghi_obs"], mask)
    dni = error_statistics(day["dni"], day["dni_obs"], mask)
    dhi = error_statistics(day["dhi"], day["dhi_obs"], mask)
    proxy = error_statistics(day["ghi_546_proxy"], day["ghi_obs"], mask)
    print(f"\nSURFRAD Alamosa 2016-01-01, {ghi['n']} clear instants: GHI MBE {ghi['mbe']:+.1f} W m-2 "
          f"({ghi['mbe_pct']:+.1f} %), RMSE {ghi['rmse']:.1f} ({ghi['rmse_pct']:.1f} %); DNI MBE {dni['mbe_pct']:+.1f} %; "
          f"DHI MBE {dhi['mbe_pct']:+.1f} %; 546 nm proxy MBE {proxy['mbe_pct']:+.1f} %")
    assert abs(ghi["mbe_pct"]) < 5.0
    assert ghi["rmse_pct"] < 6.0
    assert abs(dhi["mbe_pct"]) < 15.0
    assert abs(dni["mbe_pct"]) < 8.0
    # The spectral conversion beats the paper's monochromatic 546 nm proxy.
    assert abs(proxy["mbe_pct"]) > 1.5 * abs(ghi["mbe_pct"])


def test_image_size_is_converged(site, day):
    """65 px against 129 px at noon: GHI within 0.5 % (measured 0.01 %)."""
    t = pd.DatetimeIndex(["2016-01-01T19:00Z"])
    big = ghi_time_series(site["scene"], site["lat"], site["lon"], t, size=2 * DEFAULT_SIZE - 1, aerosol=site["aerosol"],
                          precipitable_water_cm=site["pw"], ozone_atm_cm=OZONE)
    assert big["ghi"].iloc[0] == pytest.approx(day.loc[t[0], "ghi"], rel=0.005)
    assert big["dhi"].iloc[0] == pytest.approx(day.loc[t[0], "dhi"], rel=0.01)


def test_cli_with_observations(site, tmp_path):
    app = typer.Typer()
    from swim.cli.ghi import ghi

    app.command()(ghi)
    out = tmp_path / "alamosa.csv"
    res = CliRunner().invoke(app, ["--observed", str(site["path"]), "--start", "2016-01-01T18:30Z", "--end",
                                   "2016-01-01T19:30Z", "--step", "30min", "--aod", str(AOD_550), "--ozone", str(OZONE),
                                   "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "GHI vs observed, 3 clear instants" in res.output
    table = pd.read_csv(out, index_col=0, parse_dates=True)
    assert len(table) == 3 and table["clear"].all()
    np.testing.assert_allclose(table["ghi"], table["ghi_obs"], rtol=0.06)
