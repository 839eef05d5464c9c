"""City lights (swim.rt.city_lights, swim.surface.city_lights, swim.pipeline.city_lights): the emission law, the
lamps, the emission field and its proxies, the sky glow's and the lit cloud base's radiance, and bad input."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr
from scipy.integrate import quad

from swim.constants import EARTH_RADIUS_M
from swim.errors import SwimInputError
from swim.optics.volume import fit_grid_index_map
from swim.rt.city_lights import (CloudVolume, LightSources, channel_flux_per_lumen, city_lights_image, clear_air,
                                 cloud_extinction_at, cloud_plane_albedo, emission_law, garstang_intensity, glow_table,
                                 interpolate_table, lamp_spectrum, luminous_efficacy, sky_glow,
                                 sources_from_emission, upward_irradiance)
from swim.surface.city_lights import (cell_areas, check_emission, town_light_emission, upward_fraction,
                                      urban_light_emission)

R = EARTH_RADIUS_M


def _town(flux_lm=2.35e7, radius_m=2000.0, lamp="sodium"):
    return LightSources([[0.0, 0.0, R]], [flux_lm], [radius_m], lamp)


def _grid(n=21, spacing=2000.0):
    """A regular (y, x) grid about the scene frame's reference point: lat, lon [deg] and the x, y [m] of its columns."""
    x = (np.arange(n) - n // 2) * spacing
    gx, gy = np.meshgrid(x, x)
    lat = np.degrees(gy / R)
    lon = np.degrees(gx / R)
    return lat, lon, gx, gy


def _cloud_volume(tau=10.0, base_m=1000.0, top_m=2000.0, n=21, spacing=2000.0):
    """A horizontally uniform cloud layer of optical depth ``tau`` between ``base_m`` and ``top_m`` on a grid
    about the reference point, as the optical volume's extinction (level, y, x) and attributes."""
    _, _, gx, gy = _grid(n, spacing)
    centre, scale, coefficients, _ = fit_grid_index_map(gx, gy)
    bounds = np.array([(gx.min() - centre[0]) / scale, (gx.max() - centre[0]) / scale,
                       (gy.min() - centre[1]) / scale, (gy.max() - centre[1]) / scale])
    dz = 100.0
    levels = np.arange(0.0, 5000.0 + dz, dz)
    ext = np.zeros((levels.size, n, n))
    ext[(levels >= base_m) & (levels < top_m)] = tau / (top_m - base_m)
    attrs = {"z_bottom": 0.0, "dz": dz, "index_map_centre": centre, "index_map_scale": scale,
             "index_map_coefficients": coefficients.ravel(), "index_map_bounds": bounds}
    return CloudVolume(ext, attrs)


def test_garstang_law_is_normalised_over_the_upper_hemisphere_and_zero_below():
    # Garstang (1986): 0.554 int_0^pi/2 psi^4 sin psi dpsi = 1 and 2 int cos psi sin psi = 1, so f integrates to 1
    for f, g in ((0.1, 0.15), (1.0, 0.0), (0.0, 0.3)):
        total, _ = quad(lambda psi: garstang_intensity(np.cos(psi), f, g) * 2 * np.pi * np.sin(psi), 0, np.pi / 2)
        assert total == pytest.approx(1.0, abs=2e-3)
    assert garstang_intensity(np.array([-0.5, 0.0])).tolist() == [0.0, 0.0]
    # the sources' law, tapered over the last degrees above the horizon, keeps the upward flux
    total, _ = quad(lambda psi: emission_law(np.cos(psi)) * 2 * np.pi * np.sin(psi), 0, np.pi / 2, points=[1.48])
    assert total == pytest.approx(1.0, abs=2e-3)
    assert emission_law(np.cos(np.radians(89.9))) < 0.05 * emission_law(np.cos(np.radians(80.0)))
    assert emission_law(0.0) == 0.0
    # the direct part peaks towards the horizon: f(80 deg) > f(0) for the direct light alone
    assert garstang_intensity(np.cos(np.radians(80)), 1.0, 0.0) > garstang_intensity(1.0, 1.0, 0.0)


def test_lamp_spectra_sodium_is_orange_and_led_white_with_published_efficacies():
    sodium, led = channel_flux_per_lumen("sodium"), channel_flux_per_lumen("led")
    # high-pressure sodium puts most of its light in the red channel (580-700 nm) and little below 498 nm
    assert sodium[0] / sodium[2] > 10.0
    assert led[2] / led[1] > 0.25  # the LED's blue pump
    # luminous efficacies of radiation: HPS about 350-420 lm/W, 4000 K phosphor LEDs about 290-350 lm/W
    assert 330.0 < luminous_efficacy("sodium") < 430.0
    assert 280.0 < luminous_efficacy("led") < 360.0
    with pytest.raises(SwimInputError, match="lamp spectrum"):
        lamp_spectrum("mercury")


def test_upward_fraction_and_land_use_proxy():
    assert upward_fraction() == pytest.approx(0.1 + 0.15 * 0.9)
    lu = np.array([[1, 16], [1, 7]])  # USGS: 1 urban, 16 water, 7 grassland
    m = urban_light_emission("USGS", lu_index=lu, population_density_km2=2000.0, lumens_per_person=1000.0)
    # 2000 persons per km2 x 1000 lm x 0.235 = 0.47 lm m-2 on urban land, none elsewhere
    assert m == pytest.approx(np.array([[0.47, 0.0], [0.47, 0.0]]))
    fractions = np.zeros((20, 2, 2))
    fractions[12] = 0.5  # MODIS class 13, urban and built-up, half of each cell
    fractions[10] = 0.5
    m = urban_light_emission("MODIFIED_IGBP_MODIS_NOAH", landusef=fractions)
    assert m == pytest.approx(np.full((2, 2), 0.235))
    with pytest.raises(SwimInputError, match="lu_index"):
        urban_light_emission("USGS")


def test_town_emission_holds_the_population_light_and_sources_keep_it():
    lat, lon, _, _ = _grid(41, 1000.0)
    area = cell_areas(lat, lon)
    assert area.mean() == pytest.approx(1e6, rel=1e-3)
    m = town_light_emission(lat, lon, 0.0, 0.0, population=50_000)
    assert (m * area).sum() == pytest.approx(50_000 * 1000.0 * 0.235, rel=1e-9)
    sources = sources_from_emission(lat, lon, np.zeros_like(lat), m, 0.0, 0.0, max_sources=4)
    assert 1 <= sources.flux_lm.size <= 4
    assert sources.flux_lm.sum() == pytest.approx(50_000 * 1000.0 * 0.235, rel=1e-9)
    assert np.linalg.norm(sources.position, axis=1) == pytest.approx(R, abs=1.0)


def test_zero_emission_gives_zero_light():
    air = clear_air()
    dark = LightSources([[0.0, 0.0, R]], [0.0], [1000.0])
    dirs = np.array([[0.0, 0.0, 1.0], [0.0, 0.70710678, 0.70710678]])
    assert np.all(sky_glow(np.array([0.0, -5000.0, R + 2.0]), dirs, dark, air) == 0.0)
    az = np.full((3, 4), 30.0)
    out, n = city_lights_image(np.array([0.0, 0.0, R + 2.0]), np.eye(3), az, np.full((3, 4), 45.0),
                               np.tile([0.0, 0.7, 0.7], (12, 1)), np.zeros((3, 4)),
                               LightSources(np.zeros((0, 3)), np.zeros(0), np.zeros(0)), air)
    assert out.shape == (3, 3, 4) and np.all(out == 0.0) and n == 0


def test_image_shapes_and_glow_towards_the_town():
    air = clear_air()
    observer = np.array([0.0, -10_000.0, R + 2.0]) * 1.0
    azimuth = np.array([[0.0, 90.0, 180.0, np.nan]])  # north is towards the town
    zenith = np.array([[60.0, 60.0, 60.0, np.nan]])
    el = np.radians(90.0 - zenith)
    a = np.radians(azimuth)
    dirs = np.nan_to_num(np.stack([np.cos(el) * np.sin(a), np.cos(el) * np.cos(a), np.sin(el)], -1)).reshape(-1, 3)
    out, n = city_lights_image(observer, np.eye(3), azimuth, zenith, dirs, np.zeros((1, 4)), _town(), air)
    assert out.shape == (3, 1, 4) and n == 0
    assert out[1, 0, 0] > 3 * out[1, 0, 2] > 0.0  # towards the town brighter than away from it
    assert out[:, 0, 3].tolist() == [0.0, 0.0, 0.0]  # outside the field of view
    assert out[0, 0, 0] > out[2, 0, 0]  # sodium: red above blue


def test_table_interpolation_is_periodic_in_azimuth_and_matches_its_nodes():
    table = glow_table(np.array([0.0, -8000.0, R + 2.0]), np.eye(3), _town(), clear_air())
    direct = sky_glow(np.array([0.0, -8000.0, R + 2.0]), np.array([[0.0, np.cos(np.radians(30)), 0.5]]), _town(),
                      clear_air())
    node = interpolate_table(table.sum(axis=2), np.array([0.0, 360.0]), np.array([30.0, 30.0]))
    assert node[0] == pytest.approx(node[1])
    assert node[0] == pytest.approx(direct[0], rel=1e-9)


def test_cloud_over_the_town_is_lit_from_below_brighter_than_clear_sky():
    air = clear_air()
    cloud = _cloud_volume(tau=10.0)
    observer = np.array([0.0, -3000.0, R + 2.0])
    az, zen = np.array([[0.0]]), np.array([[20.0]])
    d = np.array([[0.0, np.sin(np.radians(20.0)), np.cos(np.radians(20.0))]])
    clear, _ = city_lights_image(observer, np.eye(3), az, zen, d, np.zeros((1, 1)), _town(), air, cloud)
    lit, n = city_lights_image(observer, np.eye(3), az, zen, d, np.full((1, 1), 10.0), _town(), air, cloud)
    assert n == 1
    assert np.all(lit[:, 0, 0] > 3.0 * clear[:, 0, 0])
    # the cloud base's radiance is near R E / pi of the irradiance at the base above the line of sight's entry
    entry = observer + d[0] * (1000.0 / d[0, 2])
    e_up = upward_irradiance(entry[None], _town(), air)[0]
    expected = cloud_plane_albedo(10.0) * e_up / np.pi
    assert lit[1, 0, 0] == pytest.approx(expected[1], rel=0.35)
    # the extinction lookup finds the layer and nothing above it
    pts = np.array([[0.0, 0.0, R + 1500.0], [0.0, 0.0, R + 3000.0]])
    assert cloud_extinction_at(pts, cloud.extinction, cloud.attrs) == pytest.approx([0.01, 0.0])


def test_bad_input_raises():
    with pytest.raises(SwimInputError, match="flux_lm"):
        LightSources([[0.0, 0.0, R]], [-1.0], [100.0])
    with pytest.raises(SwimInputError, match="radius_m"):
        LightSources([[0.0, 0.0, R]], [1.0], [0.0])
    with pytest.raises(SwimInputError, match="match"):
        LightSources([[0.0, 0.0, R]], [1.0, 2.0], [1.0])
    with pytest.raises(SwimInputError, match="aerosol optical depth"):
        clear_air(-0.1)
    with pytest.raises(SwimInputError, match="upward_light_emission"):
        check_emission(np.array([[-1.0, 0.0]]))
    with pytest.raises(SwimInputError, match="lm m-2"):
        check_emission(np.array([[np.nan]]))
    with pytest.raises(SwimInputError, match="population"):
        town_light_emission(*_grid()[:2], 0.0, 0.0, population=-5)
    with pytest.raises(SwimInputError, match="F and ground_reflectance G"):
        upward_fraction(1.5, 0.1)


def test_scene_variable_is_checked_by_validate_scene():
    from swim.io.scene import validate_scene
    from swim.io.default_scene import default_scene

    scene = default_scene()
    ny, nx = scene.sizes["y"], scene.sizes["x"]
    ok = scene.assign(upward_light_emission=(("y", "x"), np.full((ny, nx), 0.5), {"units": "lm m-2"}))
    assert "upward_light_emission" in validate_scene(ok)
    bad = scene.assign(upward_light_emission=(("y", "x"), np.full((ny, nx), -0.5), {"units": "lm m-2"}))
    with pytest.raises(SwimInputError, match="upward_light_emission"):
        validate_scene(bad)
    wrong = scene.assign(upward_light_emission=(("y", "x"), np.full((ny, nx), 0.5), {"units": "W m-2"}))
    with pytest.raises(SwimInputError, match="lm m-2"):
        validate_scene(wrong)


def test_stage_adds_nothing_by_day_or_without_emission():
    from types import SimpleNamespace

    from swim.pipeline.city_lights import add_city_lights, city_light_emission, with_city_lights_record

    radiance = np.ones((3, 2, 2), dtype=np.float32)
    view = SimpleNamespace(sun_enu=np.array([0.0, 0.0, 1.0]), height_asl=2.0)
    out, rec, lights = add_city_lights(radiance, np.arange(2), {}, view, None, None, None, object())
    assert out is radiance and lights is None
    assert city_light_emission(xr.Dataset({"lat": (("y", "x"), np.zeros((2, 2)))})) is None
    image = xr.Dataset()
    assert with_city_lights_record(image, None) is image


def test_night_render_adds_the_city_lights_plane_brightest_towards_the_town():
    import swim
    from swim.io.default_scene import default_scene

    scene = default_scene()
    lat, lon = scene.lat.values, scene.lon.values
    lat0, lon0 = float(scene.attrs["reference_lat"]), float(scene.attrs["reference_lon"])
    emission = town_light_emission(lat, lon, lat0, lon0 + 0.1, population=100_000)  # 8.5 km east
    scene = scene.assign(upward_light_emission=(("y", "x"), emission, {"units": "lm m-2"}))
    image = swim.render(scene, sun_zenith=120.0, sun_azimuth=0.0, camera="allsky", camera_options={"size": 33})
    city = image["radiance_city_lights"].values
    assert image.attrs["city_lights_sources"] >= 1
    assert image.attrs["city_lights_flux_lm"] == pytest.approx(100_000 * 1000.0 * 0.235, rel=1e-6)
    azimuth, zenith = image["view_azimuth"].values, image["view_zenith"].values
    low = (zenith > 60) & (zenith < 85)
    east = low & (np.abs(azimuth - 90.0) < 20.0)
    west = low & (np.abs(azimuth - 270.0) < 20.0)
    assert np.nanmean(city[1][east]) > 3.0 * np.nanmean(city[1][west]) > 0.0
    # sodium light: the red channel's solar-relative radiance above the blue's
    assert np.nanmean(city[0][east]) > np.nanmean(city[2][east])


@pytest.mark.realdata
def test_land_use_proxy_on_real_wps_land_use(shared_data):
    """The WRF-Fire tutorial's met_em file (Colorado, 42 x 42 at 60 m) is all evergreen needleleaf forest (USGS 14,
    its README): the proxy reads its LU_INDEX and LANDUSEF and finds no built-up land."""
    ds = xr.open_dataset(shared_data / "wrf_geo" / "met_em.d01.2005-08-28_12_00_00.nc")
    lu, fractions = ds["LU_INDEX"].values[0], ds["LANDUSEF"].values[0]
    assert np.unique(lu).tolist() == [14.0]
    for kwargs in ({"lu_index": lu}, {"landusef": fractions}):
        m = urban_light_emission(ds.attrs["MMINLU"], **kwargs)
        assert m.shape == (42, 42) and np.all(m == 0.0)
    town = lu.copy()
    town[10:20, 10:20] = 1  # ten by ten cells made built-up
    assert urban_light_emission(ds.attrs["MMINLU"], lu_index=town).sum() == pytest.approx(100 * 0.47)
