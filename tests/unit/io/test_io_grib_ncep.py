"""Tests of swim.io.grib_ncep, the NOAA/NCEP HRRR and RAP GRIB2 reader.

No real HRRR or RAP file with 3-D hydrometeors is small enough to keep, so the 3-D tests read **synthetic** GRIB2
files written here into ``tmp_path`` (:func:`write_synthetic_grib`, well under a second each):

* HRRR-like: every message is a clone of the real HRRR message of ../shared/data/hrrr_smoke (its Lambert
  conformal grid definition, 3 km, LoV 262.5 E, standard parallel 38.5 N) on a 40 x 40 sub-grid over the Gulf of
  Mexico (first point moved to the HRRR grid point (row 37, column 1170)); the values are those of the WRF
  Hurricane Katrina sample of ../shared/data/wrf_katrina (2005-08-28 18 UTC, 10 km, 14 levels): PH + PHB, P + PB,
  T, QVAPOR, QCLOUD, QRAIN, HGT, U10, V10, PSFC, stretched over the sub-grid (sub-grid point (j, i) takes WRF
  column (j 48 / 40, i 48 / 40)), written as HGT, PRES, TMP, SPFH, CLMR, RWMR on hybrid levels 1-14 (``wrfnat``),
  or interpolated in log pressure to 1000-600 hPa (``wrfprs``); CIMIXR, SNMR and GRLE are written as zero fields
  (Katrina's WRF run has no ice species). MASSDEN at 8 m is the real HRRR-Smoke field at the sub-grid's points.
* RAP-like: clones of the real RAP ``wrfnat`` message of ../shared/data/rap_native (NCEP rotated lat-lon grid,
  template 3.32769) on a 10 x 12 sub-grid (section 3 patched: the number of points, Ni, Nj and the first and last
  points), with the values of the WRF Tibet sample of ../shared/data/wrf_tibet (27 levels, all five
  hydrometeors: QCLOUD, QICE, QRAIN, QSNOW, QGRAUP, 2005-09-21 00 UTC) stretched over the sub-grid; the
  header's time is the template's, 2020-12-20 06 UTC.
"""

import numpy as np
import pytest

from swim.errors import SwimInputError
from swim.io import validate_scene

eccodes = pytest.importorskip("eccodes")
netCDF4 = pytest.importorskip("netCDF4")

from swim.io.grib import geometric_height  # noqa: E402
from swim.io.grib_ncep import (  # noqa: E402
    DEFAULT_SMOKE_MIXING_DEPTH_M,
    dry_air_density,
    hrrr_smoke_content,
    read_ncep_grib,
    region_box,
    rotated_grid_latlon,
    smoke_profile,
)

HRRR_SMOKE = "hrrr_smoke/hrrr.t00z.wrfprsf00-atmo-chem.grib2"
RAP_NATIVE = "rap_native/rap.wrfnat.grib2"
KATRINA = "wrf_katrina/ci_test_file.nc"
TIBET = "wrf_tibet/wrf_d01_allvars_cropped.nc"
#: The HRRR sub-grid: first row and column in the full CONUS grid, rows and columns.
HRRR_SUBGRID = (37, 1170, 40, 40)
#: The RAP sub-grid: first row and column in the full rotated grid, rows and columns (50.5 N 124.6 W, the Coast
#: Mountains of British Columbia).
RAP_SUBGRID = (400, 380, 10, 12)
PRESSURE_LEVELS_HPA = (1000, 950, 900, 850, 800, 750, 700, 650, 600)
#: (discipline, category, number) of the NCEP fields written.
CODES = {"HGT": (0, 3, 5), "TMP": (0, 0, 0), "SPFH": (0, 1, 0), "PRES": (0, 3, 0), "CLMR": (0, 1, 22),
         "CIMIXR": (0, 1, 82), "RWMR": (0, 1, 24), "SNMR": (0, 1, 25), "GRLE": (0, 1, 32), "LAND": (2, 0, 0),
         "UGRD": (0, 2, 2), "VGRD": (0, 2, 3), "MASSDEN": (0, 20, 0)}
G = 9.80665


def _path(shared_data, name):
    path = shared_data / name
    if not path.is_file():
        pytest.skip(f"{path} not found")
    return path


def wrf_state(path, time_index):
    """WRF state on the mass levels: (nz, ny, nx) HGT [gpm], PRES [Pa], TMP [K], SPFH [kg kg-1] and the five
    mixing ratios [kg kg-1] (zeros where the file lacks a species), (ny, nx) HGT_SFC, UGRD, VGRD, PRES_SFC,
    LAND."""
    with netCDF4.Dataset(path) as nc:
        def var(name):
            v = nc[name]
            return np.asarray(v[time_index] if v.dimensions[0] == "Time" else v[:], dtype=float)

        ph = (var("PH") + var("PHB")) / G
        p = var("P") + var("PB")
        qv = var("QVAPOR")
        out = {"HGT": 0.5 * (ph[1:] + ph[:-1]), "PRES": p, "TMP": (var("T") + 300.0) * (p / 1e5) ** 0.2857,
               "SPFH": qv / (1.0 + qv)}
        for name, wrf in (("CLMR", "QCLOUD"), ("CIMIXR", "QICE"), ("RWMR", "QRAIN"), ("SNMR", "QSNOW"),
                          ("GRLE", "QGRAUP")):
            out[name] = var(wrf) if wrf in nc.variables else np.zeros_like(p)
        out.update(HGT_SFC=var("HGT"), UGRD=var("U10"), VGRD=var("V10"), PRES_SFC=var("PSFC"),
                   LAND=var("LANDMASK") if "LANDMASK" in nc.variables else np.zeros_like(var("HGT")))
    return out


def _stretch(field, nj, ni):
    """``field`` (..., ny, nx) stretched over (nj, ni) points by nearest index."""
    jj = np.arange(nj) * field.shape[-2] // nj
    ii = np.arange(ni) * field.shape[-1] // ni
    return field[..., jj[:, None], ii[None, :]]


def to_pressure_levels(state, levels_pa):
    """``state`` interpolated linearly in log pressure to ``levels_pa``; below the ground HGT and TMP follow the
    hypsometric equation from the lowest level with its temperature, the mixing ratios are 0."""
    lnp = np.log(state["PRES"])
    out = {}
    for name in ("HGT", "TMP", "SPFH", "CLMR", "CIMIXR", "RWMR", "SNMR", "GRLE"):
        f = state[name]
        values = np.empty((len(levels_pa),) + f.shape[1:])
        for j, i in np.ndindex(f.shape[1:]):
            values[:, j, i] = np.interp(np.log(levels_pa), lnp[::-1, j, i], f[::-1, j, i])
        out[name] = values
    below = np.asarray(levels_pa)[:, None, None] > state["PRES"][0][None]
    extrapolated = state["HGT"][0][None] - 287.04 * state["TMP"][0][None] / G * np.log(
        np.asarray(levels_pa)[:, None, None] / state["PRES"][0][None])
    out["HGT"] = np.where(below, extrapolated, out["HGT"])
    for name in ("CLMR", "CIMIXR", "RWMR", "SNMR", "GRLE"):
        out[name] = np.where(below, 0.0, out[name])
    return out


def _message(template, values, code, level_type, level, date, hour):
    """A clone of ``template`` holding ``values`` as NCEP field ``code`` on one level."""
    h = eccodes.codes_clone(template)
    try:
        eccodes.codes_set(h, "discipline", code[0])
        eccodes.codes_set(h, "parameterCategory", code[1])
        eccodes.codes_set(h, "parameterNumber", code[2])
        eccodes.codes_set(h, "typeOfLevel", level_type)
        if level is not None:
            eccodes.codes_set(h, "level", level)
        eccodes.codes_set(h, "dataDate", date)
        eccodes.codes_set(h, "dataTime", hour * 100)
        eccodes.codes_set(h, "forecastTime", 0)
        eccodes.codes_set(h, "decimalScaleFactor", 0)
        eccodes.codes_set(h, "bitsPerValue", 24)
        eccodes.codes_set_values(h, np.ascontiguousarray(values, dtype=float).ravel())
        return eccodes.codes_get_message(h)
    finally:
        eccodes.codes_release(h)


def _lambert_subgrid(template_path, j0, i0, nj, ni):
    """The HRRR message on the (nj, ni) sub-grid that starts at row j0, column i0 of the full grid."""
    with open(template_path, "rb") as f:
        full = eccodes.codes_grib_new_from_file(f)
    try:
        corner = eccodes.codes_clone(full)  # a grid ending at the sub-grid's first point gives its position
        eccodes.codes_set(corner, "packingType", "grid_simple")
        eccodes.codes_set(corner, "Nx", i0 + 1)
        eccodes.codes_set(corner, "Ny", j0 + 1)
        eccodes.codes_set_values(corner, np.zeros((i0 + 1) * (j0 + 1)))
        lat1 = eccodes.codes_get_array(corner, "latitudes")[-1]
        lon1 = eccodes.codes_get_array(corner, "longitudes")[-1]
        eccodes.codes_set(corner, "Nx", ni)
        eccodes.codes_set(corner, "Ny", nj)
        eccodes.codes_set(corner, "latitudeOfFirstGridPointInDegrees", lat1)
        eccodes.codes_set(corner, "longitudeOfFirstGridPointInDegrees", lon1)
        eccodes.codes_set_values(corner, np.zeros(ni * nj))
        smoke = eccodes.codes_get_values(full).reshape(eccodes.codes_get(full, "Ny"), -1)[j0:j0 + nj, i0:i0 + ni]
        return corner, smoke.copy()
    finally:
        eccodes.codes_release(full)


def _rotated_subgrid(template_path, j0, i0, nj, ni):
    """The RAP message on the (nj, ni) sub-grid that starts at row j0, column i0 of the rotated grid: section 3
    patched (number of points, Ni, Nj, first and last point)."""
    with open(template_path, "rb") as f:
        full = eccodes.codes_grib_new_from_file(f)
    try:
        message = bytearray(eccodes.codes_get_message(full))
        s3 = eccodes.codes_get(full, "offsetSection3")
    finally:
        eccodes.codes_release(full)

    def read(octet):
        v = int.from_bytes(message[s3 + octet - 1:s3 + octet + 3], "big")
        return -(v & 0x7FFFFFFF) if v & 0x80000000 else v

    def write(octet, value):
        v = abs(int(round(value))) | (0x80000000 if value < 0 else 0)
        message[s3 + octet - 1:s3 + octet + 3] = v.to_bytes(4, "big")

    lat, lon = rotated_grid_latlon(read(31), read(35), *(read(o) * 1e-6 for o in (47, 51, 73, 77, 56, 60)))
    for octet, value in ((7, ni * nj), (31, ni), (35, nj), (47, lat[j0, i0] * 1e6),
                         (51, (lon[j0, i0] % 360.0) * 1e6), (73, lat[j0 + nj - 1, i0 + ni - 1] * 1e6),
                         (77, (lon[j0 + nj - 1, i0 + ni - 1] % 360.0) * 1e6)):
        write(octet, value)
    h = eccodes.codes_new_from_message(bytes(message))
    eccodes.codes_set(h, "packingType", "grid_simple")
    return h, (lat[j0:j0 + nj, i0:i0 + ni], lon[j0:j0 + nj, i0:i0 + ni])


def write_synthetic_grib(out, template, state, nj, ni, levels="hybrid", smoke=None, date=20050828, hour=18):
    """Write the synthetic GRIB2 file ``out`` from the template message handle and a WRF ``state``
    (:func:`wrf_state`) stretched over (nj, ni) points; ``levels``: "hybrid" or "isobaric"."""
    state = {k: _stretch(v, nj, ni) for k, v in state.items()}
    messages = []
    if levels == "hybrid":
        names, level_type, values_at = ("HGT", "PRES", "TMP", "SPFH", "CLMR", "CIMIXR", "RWMR", "SNMR",
                                         "GRLE"), "hybrid", range(1, state["HGT"].shape[0] + 1)
        volume = state
    else:
        names, level_type, values_at = ("HGT", "TMP", "SPFH", "CLMR", "CIMIXR", "RWMR", "SNMR",
                                         "GRLE"), "isobaricInhPa", PRESSURE_LEVELS_HPA
        volume = to_pressure_levels(state, np.asarray(PRESSURE_LEVELS_HPA, dtype=float) * 100.0)
    for name in names:
        for k, level in enumerate(values_at):
            messages.append(_message(template, volume[name][k], CODES[name], level_type, level, date, hour))
    for name, field, level_type, level in (("HGT", "HGT_SFC", "surface", None), ("PRES", "PRES_SFC", "surface", None),
                                           ("LAND", "LAND", "surface", None), ("UGRD", "UGRD", "heightAboveGround", 10),
                                           ("VGRD", "VGRD", "heightAboveGround", 10)):
        messages.append(_message(template, state[field], CODES[name], level_type, level, date, hour))
    if smoke is not None:
        messages.append(_message(template, smoke, CODES["MASSDEN"], "heightAboveGround", 8, date, hour))
    out.write_bytes(b"".join(messages))
    return out


@pytest.fixture(scope="module")
def katrina(shared_data):
    return wrf_state(_path(shared_data, KATRINA), 2)


@pytest.fixture(scope="module")
def hrrr_files(shared_data, katrina, tmp_path_factory):
    """The HRRR-like files, hybrid and isobaric levels, and the sub-grid's MASSDEN values."""
    template, smoke = _lambert_subgrid(_path(shared_data, HRRR_SMOKE), *HRRR_SUBGRID)
    tmp = tmp_path_factory.mktemp("hrrr")
    try:
        native = write_synthetic_grib(tmp / "hrrr.wrfnat.grib2", template, katrina, 40, 40, smoke=smoke)
        prs = write_synthetic_grib(tmp / "hrrr.wrfprs.grib2", template, katrina, 40, 40, levels="isobaric")
    finally:
        eccodes.codes_release(template)
    return native, prs, smoke


@pytest.fixture(scope="module")
def native_scene(hrrr_files):
    return read_ncep_grib(hrrr_files[0])


@pytest.fixture(scope="module")
def rap_file(shared_data, tmp_path_factory):
    template, latlon = _rotated_subgrid(_path(shared_data, RAP_NATIVE), *RAP_SUBGRID)
    try:
        state = wrf_state(_path(shared_data, TIBET), 0)
        path = write_synthetic_grib(tmp_path_factory.mktemp("rap") / "rap.wrfnat.grib2", template, state,
                                    RAP_SUBGRID[2], RAP_SUBGRID[3], date=20201220, hour=6)
    finally:
        eccodes.codes_release(template)
    return path, latlon


# --- the NCEP rotated lat-lon grid (template 3.32769) of the real RAP message ---------------------------------

@pytest.fixture(scope="module")
def rap_grid(shared_data):
    from swim.io.grib_ncep import _Reader, _scan

    path = _path(shared_data, RAP_NATIVE)
    reader = _Reader(path, "RAP")
    return reader.grid(_scan(path, "RAP")[0])


def test_rotated_grid_reproduces_the_rap_corners_and_centre(rap_grid):
    """The RAP 13 km grid: first point -10.590603 N 220.914154 E, last point 46.591976 N 22.661009 E, centre
    54 N 254 E (section 3 of the message, as wgrib2 -grid prints it); the other two corners mirror them about
    the centre, and the centre of the grid's middle four points is the template's centre point."""
    lat, lon, description = rap_grid
    assert lat.shape == (834, 953) and "3.32769" in description
    assert lat[0, 0] == pytest.approx(-10.590603, abs=1e-6) and lon[0, 0] == pytest.approx(220.914154 - 360, abs=1e-6)
    assert lat[-1, -1] == pytest.approx(46.591976, abs=1e-6) and lon[-1, -1] == pytest.approx(22.661009, abs=1e-6)
    # mirror images: the rotated grid is symmetric about its centre meridian (254 E = -106)
    assert lat[0, -1] == pytest.approx(lat[0, 0], abs=1e-4)
    assert (lon[0, -1] + 106.0) == pytest.approx(-(lon[0, 0] + 106.0), abs=1e-4)
    assert lat[-1, 0] == pytest.approx(lat[-1, -1], abs=1e-4)
    from swim.io.scene import domain_centre

    mid = (slice(416, 418), slice(475, 478, 2))
    assert domain_centre(lat[mid], lon[mid]) == pytest.approx((54.0, -106.0), abs=1e-3)


def test_rotated_grid_spacing_is_13_km(rap_grid):
    """RAP's native grid spacing is 13.545 km (NCEP grid 130 and the RAP rotated grid alike)."""
    lat, lon, _ = rap_grid
    la, lo = np.deg2rad(lat[417, 476:478]), np.deg2rad(lon[417, 476:478])
    cos_d = np.sin(la[0]) * np.sin(la[1]) + np.cos(la[0]) * np.cos(la[1]) * np.cos(lo[1] - lo[0])
    assert 6_371_229.0 * np.arccos(cos_d) == pytest.approx(13_545.0, rel=2e-3)
    dlat = np.deg2rad(lat[418, 476] - lat[417, 476])
    assert 6_371_229.0 * dlat == pytest.approx(13_545.0, rel=2e-3)


def test_the_real_rap_message_has_no_hydrometeors(shared_data):
    with pytest.raises(SwimInputError, match="no hydrometeor mixing ratio .*CLMR, CIMIXR, RWMR, SNMR, GRLE"):
        read_ncep_grib(_path(shared_data, RAP_NATIVE), lat=40.0, lon=-105.0)


# --- formulas against outside numbers -------------------------------------------------------------------------

def test_dry_air_density_against_the_ideal_gas():
    """Dry air at 1000 hPa and 0 deg C: 1.2754 kg m-3 (p / (R_d T), R_d = 287.05); with q = 10 g/kg at 1000 hPa
    the vapour pressure is 1.6 kPa and the dry air density 1.6 % less."""
    assert dry_air_density(1e5, 273.15) == pytest.approx(1.2754, rel=1e-3)
    e = 1598.0  # [Pa]: mixing ratio w = q / (1 - q) = 10.1 g/kg, e = w p / (0.622 + w)
    assert dry_air_density(1e5, 300.0, specific_humidity=0.01) == pytest.approx(
        dry_air_density(1e5, 300.0) * (1 - e / 1e5), rel=1e-6)
    # RH 100 % at 20 deg C: e_s = 2.34 kPa (Wallace and Hobbs Table)
    assert dry_air_density(1e5, 293.15, relative_humidity=1.0) == pytest.approx(
        (1e5 - 2339.0) / (287.05 * 293.15), rel=2e-3)


def test_smoke_profile_is_well_mixed_in_the_layer():
    height = np.array([10.0, 500.0, 1400.0, 1600.0, 3000.0])[:, None, None] + np.array([[0.0, 1000.0]])[None]
    terrain = np.array([[0.0, 1000.0]])
    smoke = smoke_profile(np.array([[2e-8, 5e-8]]), height, terrain)
    assert smoke.shape == (5, 1, 2)
    np.testing.assert_array_equal(smoke[:3, 0, 0], 2e-8)
    np.testing.assert_array_equal(smoke[:3, 0, 1], 5e-8)
    np.testing.assert_array_equal(smoke[3:], 0.0)
    assert DEFAULT_SMOKE_MIXING_DEPTH_M == 1500.0
    deeper = smoke_profile(np.array([[2e-8, 5e-8]]), height, terrain, mixing_depth=np.array([[2000.0, 100.0]]))
    assert deeper[3, 0, 0] == 2e-8 and deeper[1, 0, 1] == 0.0


def test_region_box_holds_every_column_within_the_radius():
    lat, lon = np.meshgrid(np.arange(20.0, 50.0, 0.5), np.arange(-120.0, -70.0, 0.5), indexing="ij")
    rows, cols = region_box(lat, lon, 35.0, -95.0, 2.0)
    assert lat[rows, cols].min() == pytest.approx(33.0) and lat[rows, cols].max() == pytest.approx(37.0)
    # the cap's widest longitudes: +-arcsin(sin 2 deg / cos 35 deg) = +-2.44 deg, so columns -97 to -93 on this grid
    assert lon[rows, cols].min() == -97.0 and lon[rows, cols].max() == -93.0
    with pytest.raises(SwimInputError, match="holds 0 x 0 grid columns"):
        region_box(lat, lon, 0.0, 0.0, 2.0)


# --- the synthetic HRRR-like files ------------------------------------------------------------------------------

def test_native_levels_variables_units_and_time(native_scene, katrina):
    s = native_scene
    assert s.sizes == {"z": 14, "y": 40, "x": 40}
    for name, units in (("height", "m"), ("terrain_height", "m"), ("cloud_liquid_content", "kg m-3"),
                        ("rain_content", "kg m-3"), ("wind_speed_10m", "m s-1"), ("lat", "degrees_north")):
        assert s[name].attrs["units"] == units
    # Katrina's run has no ice species: their zero fields stay absent
    assert not {"cloud_ice_content", "snow_content", "graupel_content"} & set(s.data_vars)
    assert str(s["time"].values)[:16] == "2005-08-28T18:00"
    assert s.attrs["grib_centre"] == "kwbc" and s.attrs["title"].startswith("NCEP HRRR GRIB2")
    assert s["land_mask"].dtype == np.int8 and int(s["land_mask"].max()) == 0  # the Gulf of Mexico
    # contents: WRF mixing ratio [kg/kg dry air] x dry-air density, 0.3-1.3 kg m-3 between 0 and 6 km
    ratio = s["cloud_liquid_content"].values.max() / katrina["CLMR"].max()
    assert 0.6 < ratio < 1.3
    assert 1e-4 < s["rain_content"].values.max() < 5e-3


def test_native_heights_increase_and_match_the_wrf_geopotential(native_scene, katrina):
    h = native_scene["height"].values
    assert np.all(np.diff(h, axis=0) > 0)
    np.testing.assert_allclose(h[:, 0, 0], geometric_height(katrina["HGT"][:, 0, 0]), rtol=1e-6, atol=0.01)
    assert 20.0 < h[0].mean() < 60.0 and 5000.0 < h[-1].mean() < 6500.0


def _lambert_point(j, i):
    """Latitude and longitude [deg] of point (row j, column i) of the HRRR CONUS grid by Snyder's formulas for the
    Lambert conformal projection of a sphere, tangent at 38.5 N (Snyder 1987, USGS Prof. Paper 1395, Eqs. 15-1
    to 15-5, 14-4, 14-9 inverted): R = 6 371 229 m, LoV 262.5 E, first point 21.138123 N 237.280472 E, 3 km."""
    r, phi1, lon0 = 6_371_229.0, np.deg2rad(38.5), 262.5
    n = np.sin(phi1)
    f = np.cos(phi1) * np.tan(np.pi / 4 + phi1 / 2) ** n / n

    def rho(phi):
        return r * f / np.tan(np.pi / 4 + phi / 2) ** n

    rho0 = rho(phi1)
    theta1 = n * np.deg2rad(237.280472 - lon0)
    x = rho(np.deg2rad(21.138123)) * np.sin(theta1) + 3000.0 * i
    y = rho0 - rho(np.deg2rad(21.138123)) * np.cos(theta1) + 3000.0 * j
    rho_p = np.hypot(x, rho0 - y)
    lat = 2 * np.arctan((r * f / rho_p) ** (1 / n)) - np.pi / 2
    lon = lon0 + np.rad2deg(np.arctan2(x, rho0 - y) / n)
    return np.rad2deg(lat), (lon + 180.0) % 360.0 - 180.0


def test_lambert_grid_of_the_hrrr_subgrid(native_scene):
    """The sub-grid's points are those of the HRRR CONUS grid from row 37, column 1170 (Snyder's formulas), and
    their spacing on the sphere is 3 km over the map factor, 1.0236 at 25.5 N (Snyder Eq. 15-4)."""
    lat, lon = native_scene["lat"].values, native_scene["lon"].values
    j0, i0 = HRRR_SUBGRID[:2]
    for j, i in ((0, 0), (39, 0), (0, 39), (39, 39), (20, 17)):
        assert (lat[j, i], lon[j, i]) == pytest.approx(_lambert_point(j0 + j, i0 + i), abs=2e-4)
    la, lo = np.deg2rad(lat[20, 20:22]), np.deg2rad(lon[20, 20:22])
    cos_d = np.sin(la[0]) * np.sin(la[1]) + np.cos(la[0]) * np.cos(la[1]) * np.cos(lo[1] - lo[0])
    assert 6_371_229.0 * np.arccos(cos_d) == pytest.approx(3000.0 / 1.0236, rel=5e-3)


def test_round_trip_through_validate_scene(native_scene):
    again = validate_scene(native_scene)
    assert set(again.data_vars) == set(native_scene.data_vars)
    for name in native_scene.data_vars:
        np.testing.assert_array_equal(again[name].values, native_scene[name].values)
    assert again.attrs == native_scene.attrs


def test_pressure_levels_mask_the_eye_underground(hrrr_files, native_scene):
    """In Katrina's eye the surface pressure is 939 hPa: the 1000 and 950 hPa surfaces lie under the sea there and
    hold no condensate; the heights of those surfaces are negative."""
    s = read_ncep_grib(hrrr_files[1])
    assert s.sizes["z"] == len(PRESSURE_LEVELS_HPA) and "isobaric" in s.attrs["title"]
    assert np.all(np.diff(s["height"].values, axis=0) > 0)
    assert s["height"].values[0].min() < 0.0
    below = s["height"].values < 0
    assert not np.any(s["rain_content"].values[below] > 0)
    assert 1e-4 < s["rain_content"].values.max() < 5e-3
    # 850 hPa is near 1.45-1.55 km (the standard atmosphere: 1457 m)
    assert 1200.0 < np.median(s["height"].values[3]) < 1600.0


def test_region_around_the_camera(hrrr_files):
    s = read_ncep_grib(hrrr_files[0], lat=25.5, lon=-89.0, radius_deg=0.2)
    assert s.sizes["y"] < 40 and s.sizes["x"] < 40 and s.sizes["y"] >= 14
    assert s.attrs["reference_lat"] == 25.5 and s.attrs["grib_region_radius_deg"] == 0.2
    d = np.hypot(s["lat"].values - 25.5, (s["lon"].values + 89.0) * np.cos(np.deg2rad(25.5)))
    assert d.min() < 0.03
    with pytest.raises(SwimInputError, match="holds 0 x 0 grid columns"):
        read_ncep_grib(hrrr_files[0], lat=45.0, lon=-89.0, radius_deg=1.0)


def test_time_selection(hrrr_files):
    assert str(read_ncep_grib(hrrr_files[0], time="2005-08-28T19:00")["time"].values)[:13] == "2005-08-28T18"
    with pytest.raises(SwimInputError, match="more than 1.5 h from every valid time"):
        read_ncep_grib(hrrr_files[0], time="2005-08-29T00:00")


def test_smoke_in_the_file_becomes_smoke_mass_content(native_scene, hrrr_files):
    """The 8 m MASSDEN fills the lowest 1.5 km (HRRR-Smoke's real values at the sub-grid's points: 0.1-2 ug m-3
    over the Gulf)."""
    smoke = native_scene["smoke_mass_content"]
    assert smoke.dims == ("z", "y", "x") and smoke.attrs["units"] == "kg m-3"
    height = native_scene["height"].values
    np.testing.assert_allclose(smoke.values[0], hrrr_files[2], rtol=1e-5)
    np.testing.assert_array_equal(smoke.values[height < 1400.0], np.broadcast_to(smoke.values[0], height.shape)[
        height < 1400.0])
    assert np.all(smoke.values[height > 1500.0] == 0.0)
    assert 1e-11 < smoke.values.max() < 5e-9
    thinner = read_ncep_grib(hrrr_files[0], smoke_mixing_depth=500.0)["smoke_mass_content"].values
    assert np.all(thinner[height > 500.0] == 0.0) and np.any(smoke.values[height > 500.0] > 0)


def test_missing_fields_are_named(hrrr_files, katrina, tmp_path, shared_data):
    template, _ = _lambert_subgrid(_path(shared_data, HRRR_SMOKE), *HRRR_SUBGRID)
    try:
        state = dict(katrina)
        path = write_synthetic_grib(tmp_path / "a.grib2", template, state, 40, 40)
        data = path.read_bytes()
    finally:
        eccodes.codes_release(template)
    messages = [b"GRIB" + m for m in data.split(b"GRIB")[1:]]
    # drop TMP on hybrid levels (messages 29-42: HGT, PRES, TMP come first, 14 levels each)
    (tmp_path / "no_tmp.grib2").write_bytes(b"".join(messages[:28] + messages[42:]))
    with pytest.raises(SwimInputError, match="lacks TMP on the hybrid levels 1, 2, 3"):
        read_ncep_grib(tmp_path / "no_tmp.grib2")
    (tmp_path / "no_orog.grib2").write_bytes(b"".join(messages[:-5] + messages[-4:]))
    with pytest.raises(SwimInputError, match="lacks HGT on the surface"):
        read_ncep_grib(tmp_path / "no_orog.grib2")


def test_not_grib_is_refused(tmp_path):
    path = tmp_path / "x.grib2"
    path.write_bytes(b"not a grib file at all")
    with pytest.raises(SwimInputError, match="x.grib2"):
        read_ncep_grib(path)


# --- the synthetic RAP-like file on the rotated grid ------------------------------------------------------------

def test_rap_native_all_five_species(rap_file):
    path, (lat, lon) = rap_file
    s = read_ncep_grib(path)
    assert s.attrs["title"].startswith("NCEP RAP GRIB2") and "3.32769" in s.attrs["grib_grid"]
    for name in ("cloud_liquid_content", "cloud_ice_content", "rain_content", "snow_content", "graupel_content"):
        assert name in s and s[name].attrs["units"] == "kg m-3" and s[name].values.max() > 0
    np.testing.assert_allclose(s["lat"].values, lat, atol=1e-5)
    np.testing.assert_allclose(s["lon"].values, lon, atol=1e-5)
    assert np.all(np.diff(s["height"].values, axis=0) > 0)
    assert s["terrain_height"].values.max() > 4000.0  # Tibet's plateau
    again = validate_scene(s)
    for name in s.data_vars:
        np.testing.assert_array_equal(again[name].values, s[name].values)


# --- the real HRRR-Smoke field ------------------------------------------------------------------------------------

def test_hrrr_smoke_on_a_scene_over_arkansas(shared_data):
    """The README's maximum, 1.77e-6 kg m-3 at 34.62 N 93.448 W, reaches the scene column there."""
    lat, lon = np.meshgrid(np.linspace(34.42, 34.82, 5), np.linspace(-93.65, -93.25, 5) + 0.002, indexing="ij")
    height = np.array([20.0, 800.0, 2000.0])[:, None, None] + np.zeros((1, 5, 5))
    smoke = hrrr_smoke_content(_path(shared_data, HRRR_SMOKE), lat, lon, height, np.zeros((5, 5)))
    assert smoke.shape == (3, 5, 5)
    assert smoke[0, 2, 2] == pytest.approx(1.77e-6, rel=0.02)
    np.testing.assert_array_equal(smoke[1], smoke[0])
    np.testing.assert_array_equal(smoke[2], 0.0)


def test_hrrr_smoke_file_alone_is_not_a_scene(shared_data):
    with pytest.raises(SwimInputError, match="hrrr_smoke_content"):
        read_ncep_grib(_path(shared_data, HRRR_SMOKE), lat=34.6, lon=-93.4)
