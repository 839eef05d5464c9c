"""CAMS aerosol fields onto scenes (swim.optics.model_aerosol_fields).

The CAMS-like datasets here are built from the real IFS columns of ecRad's ``ecrad_meridian.nc`` (135° E,
2013-01-05; the shared data's ``ecrad/``): their 12 CAMS mass mixing ratios, temperature, humidity and half-level
pressures, rearranged into the layouts users download from the Atmosphere Data Store (``aermr01`` ... ``aermr11``
on model levels with the hybrid coefficients, or on pressure levels) or kept in ecRad's layout. The reference is
each column's own AOD at 550 nm: Σ_levels Σ_s q_s k_e,s(RH) Δp / g over its 137 layers (the mass of each species
in the layer times its mass extinction coefficient, as the IFS computes it); the 30.5° N column's is 0.325
(docs/aerosols.md §10.1).
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
import xarray as xr

from swim.constants import STANDARD_GRAVITY
from swim.errors import SwimInputError
from swim.io.grib import moist_air_density
from swim.io.scene import layer_thickness, scene_from_arrays
from swim.optics.model_aerosol import cams_aerosol_optics, read_ifs_aerosol_optics, relative_humidity_liquid
from swim.optics.model_aerosol_fields import (
    CAMS_ADS_SPECIES,
    add_cams_aerosol,
    cams_column_optics,
    cams_neighbours,
)

COL_30N, COL_25N = 10, 11  # columns of ecrad_meridian.nc at 30.46° N and 24.92° N
TABLE = "ecrad/aerosol_ifs_49R1.nc"


@functools.lru_cache(maxsize=1)
def _meridian(data_dir):
    with xr.open_dataset(f"{data_dir}/ecrad/ecrad_meridian.nc") as ds:
        return ds.load()


def _own_state(ds, c):
    ph = ds["pressure_hl"].values[c].astype(float)
    th = ds["temperature_hl"].values[c].astype(float)
    p, t = 0.5 * (ph[1:] + ph[:-1]), 0.5 * (th[1:] + th[:-1])
    rh = relative_humidity_liquid(ds["q"].values[c].astype(float), t, p)
    return ph, p, t, rh


def _own_aod(data_dir, c, species=slice(0, 11)):
    """The column's own AOD at 550 nm from its layer masses: Σ q_s k_e,s(RH) Δp / g (the species given)."""
    ds = _meridian(data_dir)
    ph, p, t, rh = _own_state(ds, c)
    mmr = np.zeros((12, p.size))
    mmr[species] = ds["aerosol_mmr"].values[c][species]
    rho = moist_air_density(p, t, rh)
    beta = cams_aerosol_optics(mmr, rh, rho, read_ifs_aerosol_optics(f"{data_dir}/{TABLE}"))["extinction"][:, 3]
    return float((beta * np.diff(ph) / (STANDARD_GRAVITY * rho)).sum())


def _hybrid_coefficients(ds):
    """a [Pa], b of the 138 half levels from the 32 columns' half-level pressures (p = a + b p_s, least squares)."""
    ph = ds["pressure_hl"].values.astype(float)
    design = np.stack([np.ones(ph.shape[0]), ph[:, -1]], axis=1)
    (a, b), *_ = np.linalg.lstsq(design, ph, rcond=None)
    assert np.max(np.abs(design @ np.stack([a, b]) - ph)) < 1.0  # the file is on hybrid levels (to 1 Pa)
    return np.clip(a, 0.0, None), np.clip(b, 0.0, 1.0)


def _ads_model_levels(data_dir, rows, lats, lons=(134.5, 135.5)):
    """An ADS-like model-level dataset: row i of the latitude/longitude grid holds column ``rows[i]`` at both
    longitudes; latitudes descending as the ADS delivers them, longitudes 0-360."""
    ds = _meridian(data_dir)
    a, b = _hybrid_coefficients(ds)
    grid = (len(lats), len(lons))

    def field(v):  # (level,) per row -> (level, lat, lon)
        return np.broadcast_to(np.stack(v, axis=-1)[..., None], v[0].shape + grid).copy()

    states = [_own_state(ds, c) for c in rows]
    out = {f"aermr{k + 1:02d}": (("level", "latitude", "longitude"),
                                 field([ds["aerosol_mmr"].values[c][k].astype(float) for c in rows]),
                                 {"units": "kg kg**-1"}) for k in range(11)}
    out["t"] = (("level", "latitude", "longitude"), field([s[2] for s in states]), {"units": "K"})
    out["q"] = (("level", "latitude", "longitude"), field([ds["q"].values[c].astype(float) for c in rows]),
                {"units": "kg kg**-1"})
    sp = np.broadcast_to(np.array([s[0][-1] for s in states])[:, None], grid)
    out["lnsp"] = (("latitude", "longitude"), np.log(sp))
    out["hyai"], out["hybi"] = ("nhyi", a, {"units": "Pa"}), ("nhyi", b)
    return xr.Dataset(out, coords={"level": np.arange(1, 138), "latitude": np.asarray(lats, float),
                                   "longitude": np.asarray(lons, float)})


def _scene(lat, lon, terrain=0.0, top=20_000.0, n=5):
    x = np.linspace(-5e3, 5e3, n)
    return scene_from_arrays(x=x, y=x, z=np.arange(50.0, top, 100.0), reference_lat=lat, reference_lon=lon,
                             terrain_height=terrain)


def _scene_aod(scene):
    dz = layer_thickness(scene["height"].values, scene["terrain_height"].values)
    return (scene["aerosol_extinction"].values * dz).sum(axis=0)


def test_model_levels_reproduce_the_columns_aod(shared_data):
    """ADS model levels (hyai/hybi, lnsp) of the 30.5° N column on a 2 x 2 grid: the scene's AOD is the column's
    own (its 11 ADS species; the 12th tracer, SO2 in the ADS, holds 0.7 % of ecRad's AOD) within 1 %, the part
    above the scene's 20 km top aside; the effective type is a scattering fine/coarse mixture."""
    cams = _ads_model_levels(str(shared_data), [COL_30N, COL_30N], [31.0, 30.0])
    scene, t = add_cams_aerosol(_scene(30.4, 135.1), cams, shared_data / TABLE)
    own = _own_aod(str(shared_data), COL_30N)
    aod = _scene_aod(scene)
    assert 0.30 < own < 0.33  # the docs' 0.325 less the 12th tracer
    assert np.allclose(aod, own, rtol=0.01)
    assert 0.93 < min(t.ssa) and max(t.ssa) < 0.96
    assert 0.7 < t.angstrom_exponent < 1.1
    assert "aermr11" in scene["aerosol_extinction"].attrs["source"]


def test_bilinear_between_two_different_columns(shared_data):
    """Two columns (24.9° N, AOD ~0.2, and 30.5° N) on the grid's two latitude rows: a scene at 3/4 of the way
    gets 1/4 and 3/4 of their AODs; the weights of cams_neighbours sum to 1."""
    lats = [30.45755, 24.91993]
    cams = _ads_model_levels(str(shared_data), [COL_30N, COL_25N], lats)
    lat = lats[1] + 0.75 * (lats[0] - lats[1])
    scene, _ = add_cams_aerosol(_scene(lat, 135.0), cams, shared_data / TABLE)
    a30, a25 = _own_aod(str(shared_data), COL_30N), _own_aod(str(shared_data), COL_25N)
    assert abs(a30 - a25) > 0.05
    assert np.allclose(_scene_aod(scene), 0.75 * a30 + 0.25 * a25, rtol=0.01)
    cols = cams_column_optics(cams, shared_data / TABLE)
    index, weight = cams_neighbours(cols, np.array([lat, 28.0]), np.array([135.0, 135.2]))
    assert np.allclose(weight.sum(axis=0), 1.0) and index.shape == (4, 2)


def test_a_global_grid_wraps_in_longitude(shared_data):
    """A global grid (longitudes 0, 90, 180, 270) with twice the mixing ratios at 0°: a scene at 45° W (315°,
    midway between 270° and 360° = 0°) gets 1.5 times the column's AOD."""
    cams = _ads_model_levels(str(shared_data), [COL_30N, COL_30N], [31.0, 30.0], lons=(0.0, 90.0, 180.0, 270.0))
    factor = xr.DataArray([2.0, 1.0, 1.0, 1.0], dims="longitude", coords={"longitude": cams["longitude"]})
    cams = cams.assign({v: cams[v] * factor for v in cams.data_vars if v.startswith("aermr")})
    scene, _ = add_cams_aerosol(_scene(30.4, -45.0), cams, shared_data / TABLE)
    assert np.allclose(_scene_aod(scene), 1.5 * _own_aod(str(shared_data), COL_30N), rtol=0.01)


def test_ecrad_layout_takes_the_nearest_column(shared_data):
    """ecRad's own layout (aerosol_mmr (column, type, level), 12 species with the 49R1 type map): a scene at
    26° N gets the 24.9° N column (the nearest), all 12 species."""
    ds = _meridian(str(shared_data))
    scene, _ = add_cams_aerosol(_scene(26.0, 135.0), ds, shared_data / TABLE)
    assert np.allclose(_scene_aod(scene), _own_aod(str(shared_data), COL_25N, slice(0, 12)), rtol=0.01)


def test_terrain_following_and_cells_below_the_terrain(shared_data):
    """Heights above the CAMS ground are laid on the scene's terrain: a 1.5-km plateau gets the same AOD, and
    the scene's levels below the terrain no extinction."""
    cams = _ads_model_levels(str(shared_data), [COL_30N, COL_30N], [31.0, 30.0])
    flat, _ = add_cams_aerosol(_scene(30.4, 135.1), cams, shared_data / TABLE)
    high, _ = add_cams_aerosol(_scene(30.4, 135.1, terrain=1500.0, top=21_500.0), cams, shared_data / TABLE)
    assert np.allclose(_scene_aod(high), _scene_aod(flat), rtol=0.005)
    below = high["height"].values < 1500.0 - 50.0
    assert below.any() and np.all(high["aerosol_extinction"].values[below] == 0.0)


def test_pressure_levels_with_relative_humidity(shared_data):
    """The 30.5° N column on the 25 pressure levels of the ADS (1000 ... 1 hPa; mixing ratios and T linear in
    ln p, RH as ``r`` [%], with the surface pressure): the coarse levels keep the AOD within 3 % (measured
    +0.7 %)."""
    ds = _meridian(str(shared_data))
    ph, p, t, rh = _own_state(ds, COL_30N)
    levels = np.array([1, 2, 3, 5, 7, 10, 20, 30, 50, 70, 100, 150, 200, 250, 300, 400, 500, 600, 700, 800, 850,
                       900, 925, 950, 1000], dtype=float)

    def on_levels(v):
        return np.interp(np.log(levels * 100.0), np.log(p), v)[:, None, None] * np.ones((1, 2, 2))

    mmr = ds["aerosol_mmr"].values[COL_30N].astype(float)
    dims = ("pressure_level", "latitude", "longitude")
    data = {f"aermr{k + 1:02d}": (dims, on_levels(mmr[k])) for k in range(11)}
    data.update(t=(dims, on_levels(t)), r=(dims, 100.0 * on_levels(rh), {"units": "%"}),
                sp=(("latitude", "longitude"), np.full((2, 2), ph[-1])))
    cams = xr.Dataset(data, coords={"pressure_level": ("pressure_level", levels, {"units": "hPa"}),
                                    "latitude": [30.0, 31.0], "longitude": [-225.5, -224.5]})  # 134.5, 135.5 E
    scene, _ = add_cams_aerosol(_scene(30.4, 135.1), cams, shared_data / TABLE)
    assert np.allclose(_scene_aod(scene), _own_aod(str(shared_data), COL_30N), rtol=0.03)


def test_time_selection(shared_data):
    """Two forecast times, the second with twice the mixing ratios: time= picks it (twice the AOD), and without
    a time the choice is refused."""
    one = _ads_model_levels(str(shared_data), [COL_30N, COL_30N], [31.0, 30.0])
    names = [v for v in one.data_vars if v.startswith("aermr")]
    two = xr.concat([one, one.assign({v: 2 * one[v] for v in names})], dim="time")
    two = two.assign_coords(time=np.array(["2013-01-05T00", "2013-01-05T03"], dtype="datetime64[ns]"))
    two = two.assign({v: one[v] for v in ("hyai", "hybi", "lnsp", "t", "q")})
    s1, _ = add_cams_aerosol(_scene(30.4, 135.1), one, shared_data / TABLE)
    s2, _ = add_cams_aerosol(_scene(30.4, 135.1), two, shared_data / TABLE, time="2013-01-05T02")
    assert np.allclose(_scene_aod(s2), 2 * _scene_aod(s1), rtol=1e-6)
    with pytest.raises(SwimInputError, match="time"):
        add_cams_aerosol(_scene(30.4, 135.1), two, shared_data / TABLE)


def test_bad_inputs_are_refused(shared_data):
    cams = _ads_model_levels(str(shared_data), [COL_30N, COL_30N], [31.0, 30.0])
    with pytest.raises(SwimInputError, match="outside the CAMS grid"):
        add_cams_aerosol(_scene(40.0, 135.1), cams, shared_data / TABLE)
    with pytest.raises(SwimInputError, match="no aerosol mass mixing ratios"):
        add_cams_aerosol(_scene(30.4, 135.1), cams.drop_vars([v for v in cams if v.startswith("aermr")]),
                         shared_data / TABLE)
    with pytest.raises(SwimInputError, match="humidity"):
        add_cams_aerosol(_scene(30.4, 135.1), cams.drop_vars("q"), shared_data / TABLE)
    with pytest.raises(SwimInputError, match="hyai"):
        add_cams_aerosol(_scene(30.4, 135.1), cams.drop_vars(["hyai", "hybi"]), shared_data / TABLE)
    with pytest.raises(SwimInputError, match="kg kg-1"):
        bad = cams.assign(aermr01=cams["aermr01"].assign_attrs(units="ug kg-1"))
        add_cams_aerosol(_scene(30.4, 135.1), bad, shared_data / TABLE)


def test_short_names_are_ecmwfs():
    """The ADS short names, parameter ids and names of CAMS_ADS_SPECIES are those ecCodes decodes (ECMWF's
    parameter database)."""
    eccodes = pytest.importorskip("eccodes")
    for short, (param_id, name, _) in CAMS_ADS_SPECIES.items():
        h = eccodes.codes_grib_new_from_samples("GRIB2")
        try:
            eccodes.codes_set(h, "paramId", param_id)
            assert eccodes.codes_get(h, "shortName") == short
            assert eccodes.codes_get(h, "name") == name
        finally:
            eccodes.codes_release(h)


def test_species_map_matches_the_tables_descriptions(shared_data):
    """Each ADS species points at the table entry whose code names its species (SS, DD, OM, BC, SU, NI, AM, OB,
    OA in the table's code_hydrophilic / code_hydrophobic)."""
    expected = {"aermr01": "SS", "aermr02": "SS", "aermr03": "SS", "aermr04": "DD", "aermr05": "DD", "aermr06": "DD",
                "aermr07": "OM", "aermr08": "OM", "aermr09": "BC", "aermr10": "BC", "aermr11": "SU",
                "aermr16": "NI", "aermr17": "NI", "aermr18": "AM", "aermr19": "OB", "aermr20": "OA"}
    table = read_ifs_aerosol_optics(shared_data / TABLE)
    for short, (_, _, code) in CAMS_ADS_SPECIES.items():
        codes = table.philic_codes if code < 0 else table.phobic_codes
        assert codes[abs(code) - 1] == expected[short], short
