"""CAMS aerosol fields onto a scene: species mass mixing ratios of a CAMS dataset to the scene's 3-D extinction.

:func:`add_cams_aerosol` takes CAMS forecasts or reanalysis as users download them from the Atmosphere Data Store
(ADS: "CAMS global atmospheric composition forecasts", EAC4) or ecRad's input layout, computes each CAMS voxel's
extinction, ω and g with the IFS aerosol optics table (:mod:`swim.optics.model_aerosol`), and puts the 550-nm
extinction onto the scene's columns: bilinear in latitude/longitude on a grid, nearest column for column data,
and conservatively in height (the optical depth of each scene layer is the CAMS optical depth between its
interfaces). It returns the scene with ``aerosol_extinction`` and the mixture's effective type (docs/aerosols.md
§10.4).

Species: the ADS/GRIB short names ``aermrNN`` map to the table's entries as in :data:`CAMS_ADS_SPECIES` (the
names and parameter ids of ECMWF's parameter database, as ecCodes decodes them; the table entries of ecRad's
``i_aerosol_type_map`` for the IFS, and for nitrate, ammonium and secondary organics the entries that the 49R1
table's ``description_hydrophilic`` names).
"""

from __future__ import annotations

import logging

import numpy as np
import xarray as xr

from ..constants import STANDARD_GRAVITY
from ..errors import SwimInputError
from ..io.grib import geometric_height, moist_air_density
from .model_aerosol import (
    IFS_AEROSOL_TYPE_MAP_49R1,
    IfsAerosolOpticsTable,
    cams_aerosol_optics,
    effective_aerosol_type,
    read_ifs_aerosol_optics,
    relative_humidity_liquid,
    scene_with_aerosol_extinction,
)

log = logging.getLogger(__name__)

#: CAMS aerosol mass mixing ratios [kg kg-1] by their ADS/GRIB short name: (ECMWF parameter id, the parameter
#: database's name, entry of the IFS aerosol optics table: -k the k-th hydrophilic, +k the k-th hydrophobic,
#: 1-based). aermr01-11: ecRad's ``i_aerosol_type_map`` for the IFS (test/ifs/configCY49R1.nam of
#: ecmwf-ifs/ecrad); aermr16-20: the 49R1 table's hydrophilic entries 9 (fine-mode nitrate, GLOMAP), 10 (coarse
#: nitrate), 8 (fine-mode ammonium sulfate, "for ammonia"), 6 and 7 (biogenic and anthropogenic secondary organic
#: aerosol, Moise et al. 2015). aermr12 ("SO2 precursor mixing ratio") is a gas and is not read.
CAMS_ADS_SPECIES = {
    "aermr01": (210001, "Sea Salt Aerosol (0.03 - 0.5 um) Mixing Ratio", -1),
    "aermr02": (210002, "Sea Salt Aerosol (0.5 - 5 um) Mixing Ratio", -2),
    "aermr03": (210003, "Sea Salt Aerosol (5 - 20 um) Mixing Ratio", -3),
    "aermr04": (210004, "Dust Aerosol (0.03 - 0.55 um) Mixing Ratio", 7),
    "aermr05": (210005, "Dust Aerosol (0.55 - 0.9 um) Mixing Ratio", 8),
    "aermr06": (210006, "Dust Aerosol (0.9 - 20 um) Mixing Ratio", 9),
    "aermr07": (210007, "Hydrophilic Organic Matter Aerosol Mixing Ratio", -4),
    "aermr08": (210008, "Hydrophobic Organic Matter Aerosol Mixing Ratio", 10),
    "aermr09": (210009, "Hydrophilic Black Carbon Aerosol Mixing Ratio", 11),
    "aermr10": (210010, "Hydrophobic Black Carbon Aerosol Mixing Ratio", 11),
    "aermr11": (210011, "Sulphate Aerosol Mixing Ratio", -5),
    "aermr16": (210247, "Nitrate fine mode aerosol mass mixing ratio", -9),
    "aermr17": (210248, "Nitrate coarse mode aerosol mass mixing ratio", -10),
    "aermr18": (210249, "Ammonium aerosol mass mixing ratio", -8),
    "aermr19": (210252, "Biogenic secondary organic aerosol mass mixing ratio", -6),
    "aermr20": (210253, "Anthropogenic secondary organic aerosol mass mixing ratio", -7),
}

_LAT_NAMES = ("latitude", "lat")
_LON_NAMES = ("longitude", "lon")
_MODEL_LEVEL_DIMS = ("model_level", "hybrid", "lev", "level")
_PRESSURE_LEVEL_DIMS = ("pressure_level", "isobaricInhPa", "plev", "level")  # "level": with units hPa or Pa
_TIME_DIMS = ("time", "valid_time", "step", "forecast_period", "forecast_reference_time")
_PRESSURE_UNITS = {"hPa": 100.0, "millibars": 100.0, "mbar": 100.0, "hectopascal": 100.0, "Pa": 1.0}


class CamsColumns:
    """CAMS aerosol optics per model column (:func:`cams_column_optics`).

    Attributes
    ----------
    lat, lon : numpy.ndarray
        (n,) [deg] of the columns.
    grid : tuple of numpy.ndarray or None
        (lat (n_lat,), lon (n_lon,)) where the columns are a lat/lon grid (row-major, lat ascending), else None.
    z_half : numpy.ndarray
        (n, L + 1) heights of the layer interfaces [m], increasing: above the CAMS surface where
        ``above_ground``, else above sea level.
    tau : numpy.ndarray
        (n, L, 12): each layer's optical depth τ, τ ω and τ ω g at 615, 546, 450, 550 nm.
    above_ground : bool
    source : str
    """

    def __init__(self, lat, lon, grid, z_half, tau, above_ground, source):
        self.lat, self.lon, self.grid = np.asarray(lat, float), np.asarray(lon, float), grid
        self.z_half, self.tau, self.above_ground, self.source = z_half, tau, bool(above_ground), source

    @property
    def aod_550(self):
        """(n,) column AOD at 550 nm."""
        return self.tau[:, :, 3].sum(axis=1)


def _first(names, pool):
    return next((n for n in names if n in pool), None)


def _select_time(ds: xr.Dataset, time) -> xr.Dataset:
    """One time of ``ds``: size-1 time dims dropped, longer ones at the time nearest to ``time``."""
    for dim in [d for d in _TIME_DIMS if d in ds.dims]:
        if ds.sizes[dim] == 1:
            ds = ds.isel({dim: 0})
            continue
        coord = ds[dim] if np.issubdtype(ds[dim].dtype, np.datetime64) else None
        if coord is None and "valid_time" in ds.coords and ds["valid_time"].dims == (dim,):
            coord = ds["valid_time"]
        if coord is None or time is None:
            raise SwimInputError(f"the CAMS dataset has {ds.sizes[dim]} values of {dim!r}: pass time= (or select "
                                 f"one time with ds.sel/isel)")
        k = int(np.argmin(np.abs(coord.values.astype("datetime64[s]") - np.datetime64(time, "s"))))
        ds = ds.isel({dim: k})
    return ds


def _species(ds: xr.Dataset, type_map):
    """(names, type map codes, mmr DataArrays) of the dataset's aerosol species."""
    if "aerosol_mmr" in ds:
        n = ds["aerosol_mmr"].sizes.get("aerosol_type", ds["aerosol_mmr"].shape[1])
        codes = IFS_AEROSOL_TYPE_MAP_49R1 if type_map is None else tuple(type_map)
        if len(codes) != n:
            raise SwimInputError(f"aerosol_mmr has {n} species; pass type_map= with {n} table entries "
                                 f"(the default is the 12 CAMS tracers of IFS Cycle 49R1)")
        dim = "aerosol_type" if "aerosol_type" in ds["aerosol_mmr"].dims else ds["aerosol_mmr"].dims[1]
        return [f"aerosol_mmr[{k}]" for k in range(n)], codes, [ds["aerosol_mmr"].isel({dim: k}) for k in range(n)]
    names = [v for v in CAMS_ADS_SPECIES if v in ds]
    if not names:
        raise SwimInputError("the CAMS dataset has no aerosol mass mixing ratios: expected ADS variables "
                             f"{', '.join(CAMS_ADS_SPECIES)} [kg kg-1] or ecRad's aerosol_mmr (column, aerosol_type, "
                             "level)")
    codes = tuple(CAMS_ADS_SPECIES[v][2] for v in names) if type_map is None else tuple(type_map[v] for v in names)
    for v in names:
        units = str(ds[v].attrs.get("units", "kg kg**-1")).replace(" ", "")
        if units not in ("kgkg**-1", "kgkg-1", "kg/kg", "1", "kgkg^-1"):
            raise SwimInputError(f"{v} must be a mass mixing ratio in kg kg-1; got units {units!r}")
    return names, codes, [ds[v] for v in names]


def _relative_humidity(ds, t, p, level_dims):
    """RH over liquid water [-] from ``q`` [kg kg-1] or ``r`` [%] (ECMWF's relative humidity)."""
    if "q" in ds:
        return relative_humidity_liquid(np.clip(_values(ds["q"], level_dims), 0.0, None), t, p)
    if "r" in ds:
        r = _values(ds["r"], level_dims)
        scale = 1.0 if str(ds["r"].attrs.get("units", "%")) in ("1", "fraction") else 0.01
        return np.clip(r * scale, 0.0, 1.0)
    raise SwimInputError("the CAMS dataset needs specific humidity 'q' [kg kg-1] or relative humidity 'r' [%] "
                         "(the hydrophilic species' optics depend on humidity)")


def _values(da: xr.DataArray, level_dims) -> np.ndarray:
    """(L, ...horizontal) float array, the level dimension first."""
    lev = [d for d in da.dims if d in level_dims]
    other = [d for d in da.dims if d not in lev]
    return np.asarray(da.transpose(*lev, *other).values, dtype=float)


def _surface_pressure(ds):
    if "sp" in ds:
        return np.asarray(ds["sp"].squeeze(drop=True).values, dtype=float)
    if "lnsp" in ds:
        return np.exp(np.asarray(ds["lnsp"].squeeze(drop=True).values, dtype=float))
    return None


def _model_level_pressure(ds, level_dim):
    """(p_top, p_bottom) (L, ...) [Pa] of model levels from hybrid half-level coefficients and surface pressure."""
    pair = next(((a, b) for a, b in (("hyai", "hybi"), ("a_half", "b_half")) if a in ds and b in ds), None)
    sp = _surface_pressure(ds)
    if pair is None or sp is None:
        return None
    a, b = (np.asarray(ds[v].values, dtype=float).ravel() for v in pair)
    n = ds.sizes[level_dim]
    if a.size == n + 1:
        top, bottom = np.arange(n), np.arange(1, n + 1)
    else:  # a subset of levels: their model-level numbers (1 = top) index the full set of half levels
        numbers = np.asarray(ds[level_dim].values).astype(int)
        if numbers.min() < 1 or numbers.max() >= a.size:
            raise SwimInputError(f"model levels {numbers.min()}-{numbers.max()} do not fit {a.size} half-level "
                                 f"coefficients ({pair[0]}, {pair[1]})")
        top, bottom = numbers - 1, numbers
    sp = np.broadcast_to(sp, np.shape(sp))
    p_top = a[top].reshape((-1,) + (1,) * sp.ndim) + b[top].reshape((-1,) + (1,) * sp.ndim) * sp
    p_bottom = a[bottom].reshape((-1,) + (1,) * sp.ndim) + b[bottom].reshape((-1,) + (1,) * sp.ndim) * sp
    if abs(b[bottom].max() - 1.0) > 1e-6:
        raise SwimInputError("the CAMS model levels must reach the surface (the lowest level's lower half level "
                             "with b = 1) for their heights to be integrated from the ground")
    return p_top, p_bottom


def _pressure_level_edges(ds, level_dim, horizontal_shape):
    """Level pressures and their layers (p_full, p_top, p_bottom) (L, ...) [Pa] of pressure-level data, top first;
    the lowest layer ends at the surface pressure where given (levels below it are dropped: their layer is empty),
    else half a level spacing below the lowest level."""
    units = str(ds[level_dim].attrs.get("units", "hPa"))
    if units not in _PRESSURE_UNITS:
        raise SwimInputError(f"pressure levels {level_dim!r} must be in hPa or Pa; got units {units!r}")
    p = np.asarray(ds[level_dim].values, dtype=float) * _PRESSURE_UNITS[units]
    mid = np.sqrt(p[1:] * p[:-1])  # p is sorted top first
    top = np.concatenate([[max(0.0, p[0] - 0.5 * (mid[0] - p[0]))], mid])
    bottom = np.concatenate([mid, [p[-1] + 0.5 * (p[-1] - mid[-1])]])
    shape = (p.size,) + tuple(horizontal_shape)
    full, top, bottom = (np.broadcast_to(v.reshape((-1,) + (1,) * len(horizontal_shape)), shape).copy()
                         for v in (p, top, bottom))
    sp = _surface_pressure(ds)
    if sp is not None:
        sp = np.broadcast_to(sp, tuple(horizontal_shape))[None]
        bottom = np.minimum(bottom, sp)
        top = np.minimum(top, sp)
    return full, top, bottom


def _ecrad_layout(ds):
    """ecRad input: (p_full, p_top, p_bottom, temperature) (L, column) [Pa, K] from pressure_hl, temperature_hl."""
    for v in ("pressure_hl", "q"):
        if v not in ds:
            raise SwimInputError(f"ecRad-layout CAMS data (aerosol_mmr) needs {v!r}")
    ph = np.asarray(ds["pressure_hl"].transpose("half_level", ...).values, dtype=float)
    if "temperature_fl" in ds:
        t = np.asarray(ds["temperature_fl"].transpose("level", ...).values, dtype=float)
    elif "temperature_hl" in ds:
        th = np.asarray(ds["temperature_hl"].transpose("half_level", ...).values, dtype=float)
        t = 0.5 * (th[1:] + th[:-1])
    else:
        raise SwimInputError("ecRad-layout CAMS data needs temperature_hl or temperature_fl [K]")
    return 0.5 * (ph[1:] + ph[:-1]), ph[:-1], ph[1:], t


def _horizontal_names(ds):
    lat, lon = _first(_LAT_NAMES, ds.dims), _first(_LON_NAMES, ds.dims)
    if lat is None or lon is None:
        raise SwimInputError("gridded CAMS data need latitude and longitude dimensions (latitude/lat, "
                             f"longitude/lon); got dims {dict(ds.sizes)}")
    return lat, lon


def _grid_subset(ds, lat_name, lon_name, region):
    """``ds`` sorted by latitude and longitude and cut to the scene's box (one grid step around it)."""
    ds = ds.sortby(lat_name).sortby(lon_name)
    if region is None:
        return ds
    la, lo = (np.asarray(v, dtype=float) for v in region)
    glat, glon = ds[lat_name].values.astype(float), ds[lon_name].values.astype(float)
    if glat.size > 1:
        step = float(np.max(np.diff(glat)))
        keep = (glat >= la.min() - step) & (glat <= la.max() + step)
        _check_cover(keep, glat, la, "latitudes")
        ds = ds.isel({lat_name: np.flatnonzero(keep)})
    if glon.size > 1 and not _is_global(glon):
        step = float(np.max(np.diff(glon)))
        shifted = _lon_into(lo, glon[0])
        keep = (glon >= shifted.min() - step) & (glon <= shifted.max() + step)
        _check_cover(keep, glon, shifted, "longitudes")
        ds = ds.isel({lon_name: np.flatnonzero(keep)})
    return ds


def _check_cover(keep, grid, x, label):
    if not keep.any():
        raise SwimInputError(f"the scene lies outside the CAMS grid's {label} {grid[0]:g} ... {grid[-1]:g}: its "
                             f"points reach {x.min():g} ... {x.max():g}")


def _is_global(glon):
    return glon.size > 2 and (glon[-1] - glon[0]) + float(np.median(np.diff(glon))) >= 359.9


def _lon_into(lon, start):
    """Longitudes [deg] shifted by multiples of 360 into [start, start + 360)."""
    return start + np.mod(np.asarray(lon, dtype=float) - start, 360.0)


def _layers_from_pressure(p_top, p_bottom, rho):
    """Hydrostatic layer thickness dz = Δp / (g ρ) [m] (L, ...): the layer's mass per area over its density."""
    return np.clip(p_bottom - p_top, 0.0, None) / (STANDARD_GRAVITY * rho)


def _gridded_state(ds, names, region):
    """Level pressures, temperature, humidity and mixing ratios of gridded (ADS) data, levels top first."""
    lat_name, lon_name = _horizontal_names(ds[names])
    ds = _grid_subset(ds, lat_name, lon_name, region).transpose(..., lat_name, lon_name)
    dims = [d for d in ds[names[0]].dims if d not in (lat_name, lon_name)]
    if len(dims) != 1:
        raise SwimInputError(f"{names[0]} must have one vertical dimension besides latitude and longitude "
                             f"(after selecting one time); got dims {ds[names[0]].dims}")
    level_dim = dims[0]
    ds = ds.sortby(level_dim)  # model-level numbers and pressures ascending: top first
    shape = (ds.sizes[lat_name], ds.sizes[lon_name])
    edges = _model_level_pressure(ds, level_dim) if level_dim in _MODEL_LEVEL_DIMS else None
    z_full = None
    if edges is not None:
        p_top, p_bottom = edges
        p_full = 0.5 * (p_top + p_bottom)
        kind = "model levels"
    elif level_dim in _PRESSURE_LEVEL_DIMS[:3] or ds[level_dim].attrs.get("units") in _PRESSURE_UNITS:
        p_full, p_top, p_bottom = _pressure_level_edges(ds, level_dim, shape)
        kind = "pressure levels"
        if _surface_pressure(ds) is None and "z" in ds:
            z_full = geometric_height(_values(ds["z"], (level_dim,)) / STANDARD_GRAVITY)
            kind += " (heights from the geopotential z)"
        elif _surface_pressure(ds) is None:
            log.warning("CAMS pressure levels without surface pressure (sp) or geopotential (z): the lowest level "
                        "is taken for the ground")
    else:
        raise SwimInputError(f"cannot place the CAMS levels ({level_dim!r}) in the vertical: model levels need "
                             "hybrid half-level coefficients (hyai/hybi) and surface pressure (sp or lnsp); "
                             "pressure levels need a level coordinate in hPa or Pa")
    if "t" not in ds:
        raise SwimInputError("the CAMS dataset needs temperature 't' [K] on its levels")
    t = _values(ds["t"], (level_dim,))
    p_full = np.broadcast_to(p_full, t.shape)
    rh = _relative_humidity(ds, t, p_full, (level_dim,))
    mmr = np.stack([_values(ds[n], (level_dim,)) for n in names])
    glat, glon = ds[lat_name].values.astype(float), ds[lon_name].values.astype(float)
    lat2, lon2 = np.meshgrid(glat, glon, indexing="ij")
    return {"p_full": p_full, "p_top": p_top, "p_bottom": p_bottom, "t": t, "rh": rh, "mmr": mmr,
            "z_full": z_full, "lat": lat2.ravel(), "lon": lon2.ravel(), "grid": (glat, glon), "kind": kind}


def _column_state(ds, names, arrays):
    """The same for ecRad's layout (column, level)."""
    p_full, p_top, p_bottom, t = _ecrad_layout(ds)
    q = np.clip(np.asarray(ds["q"].transpose("level", ...).values, dtype=float), 0.0, None)
    mmr = np.stack([np.asarray(a.transpose("level", ...).values, dtype=float) for a in arrays])
    lat = np.atleast_1d(np.asarray(ds["lat"].values, dtype=float)) if "lat" in ds else np.zeros(p_full.shape[1])
    lon = np.atleast_1d(np.asarray(ds["lon"].values, dtype=float)) if "lon" in ds else np.zeros(p_full.shape[1])
    return {"p_full": p_full, "p_top": p_top, "p_bottom": p_bottom, "t": t,
            "rh": relative_humidity_liquid(q, t, p_full), "mmr": mmr, "z_full": None, "lat": lat, "lon": lon,
            "grid": None, "kind": "ecRad columns"}


def cams_column_optics(cams: xr.Dataset, table, time=None, type_map=None, rh_interpolation="bin",
                       region=None) -> CamsColumns:
    """Optical depth, τ ω and τ ω g of every layer of every CAMS column, and the layers' heights.

    Parameters
    ----------
    cams : xarray.Dataset
        CAMS forecasts or reanalysis: ADS variables ``aermr01`` ... ``aermr11``, ``aermr16`` ... ``aermr20``
        [kg kg-1] (:data:`CAMS_ADS_SPECIES`; any subset) with temperature ``t`` [K] and ``q`` [kg kg-1] or ``r``
        [%], on a latitude/longitude grid, either on model levels (``model_level``/``level``/``hybrid``/``lev``,
        with half-level coefficients ``hyai`` [Pa] and ``hybi`` [1] of all levels and surface pressure ``sp``
        [Pa] or ``lnsp``) or on pressure levels (``pressure_level``/``isobaricInhPa``/``plev``/``level`` in hPa
        or Pa; optional ``sp`` [Pa], ``z`` [m2 s-2]); or ecRad's input layout (``aerosol_mmr`` (column,
        aerosol_type, level), ``pressure_hl``, ``temperature_hl``, ``q``, ``lat``, ``lon``).
    table : IfsAerosolOpticsTable or str or pathlib.Path
        The IFS aerosol optics (:func:`swim.optics.model_aerosol.read_ifs_aerosol_optics`).
    time : datetime-like, optional
        Selects the nearest time where the dataset holds several.
    type_map : dict or sequence, optional
        ADS data: {short name: table entry}; ecRad layout: one entry per species (default
        :data:`swim.optics.model_aerosol.IFS_AEROSOL_TYPE_MAP_49R1`).
    rh_interpolation : {"bin", "linear"}
        As :func:`swim.optics.model_aerosol.cams_aerosol_optics`.
    region : tuple of array_like, optional
        (lat, lon) [deg] of the points the columns are for: a grid is cut to their box first.

    Returns
    -------
    CamsColumns

    Raises
    ------
    SwimInputError
        No aerosol species, no humidity or temperature, levels that cannot be placed, several times without
        ``time``, or bad values (:func:`swim.optics.model_aerosol.cams_aerosol_optics`).

    Notes
    -----
    Heights: each layer's thickness is hydrostatic, dz = Δp / (g ρ) with ρ the moist-air density at the level
    (:func:`swim.io.grib.moist_air_density`; RH over liquid water), summed from the surface: heights above the
    CAMS ground (``above_ground``), so that a layer's optical depth is exactly q k_e Δp / g, the IFS's own. Model
    levels' half-level pressures are a + b p_s (IFS, full level: their mean); pressure levels' layers end
    midway (in ln p) between the levels and at the surface pressure, levels below it dropped. Pressure levels
    without ``sp`` but with the geopotential ``z`` are placed above sea level at z / g (geometric height,
    :func:`swim.io.grib.geometric_height`); without either, the lowest level is taken for the ground.
    """
    table = table if isinstance(table, IfsAerosolOpticsTable) else read_ifs_aerosol_optics(table)
    ds = _select_time(cams, time)
    names, codes, arrays = _species(ds, type_map)
    state = _column_state(ds, names, arrays) if "aerosol_mmr" in ds else _gridded_state(ds, names, region)
    rho = moist_air_density(state["p_full"], state["t"], state["rh"])
    opt = cams_aerosol_optics(state["mmr"], state["rh"], rho, table, codes, rh_interpolation)
    beta, sca = opt["extinction"], opt["extinction"] * opt["ssa"]
    q = np.concatenate([beta, sca, sca * opt["g"]], axis=-1)  # (L, ..., 12), levels top first
    n_lev = q.shape[0]
    q = q.reshape(n_lev, -1, 12)
    if state["z_full"] is None:
        dz = _layers_from_pressure(state["p_top"], state["p_bottom"], rho).reshape(n_lev, -1)[::-1]
        z_half = np.concatenate([np.zeros((1, dz.shape[1])), np.cumsum(dz, axis=0)])
    else:
        zf = state["z_full"].reshape(n_lev, -1)[::-1]  # bottom first
        mid = 0.5 * (zf[1:] + zf[:-1])
        z_half = np.concatenate([zf[:1] - (mid[:1] - zf[:1]), mid, zf[-1:] + (zf[-1:] - mid[-1:])])
        if np.any(np.diff(z_half, axis=0) <= 0):
            raise SwimInputError("the geopotential z of the CAMS pressure levels must increase upwards")
        dz = np.diff(z_half, axis=0)
    tau = (q[::-1] * dz[..., None]).transpose(1, 0, 2)
    cols = CamsColumns(state["lat"], state["lon"], state["grid"], z_half.T.copy(), tau,
                       state["z_full"] is None, f"CAMS {state['kind']}: {', '.join(names)}")
    log.info("CAMS aerosol: %d columns, %d levels (%s); AOD at 550 nm %.3f-%.3f", tau.shape[0], n_lev,
             state["kind"], float(cols.aod_550.min()), float(cols.aod_550.max()))
    return cols


def _bilinear_axis(grid, x, label, wrap=False):
    """Lower index and fraction along a sorted axis; points more than a tenth of a step outside raise."""
    if grid.size == 1:
        return np.zeros(x.shape, dtype=int), np.zeros(x.shape)
    if wrap:  # a global longitude axis: the first column again at +360
        grid = np.append(grid, grid[0] + 360.0)
    i = np.clip(np.searchsorted(grid, x, side="right") - 1, 0, grid.size - 2)
    f = (x - grid[i]) / (grid[i + 1] - grid[i])
    if np.any(f < -0.1) or np.any(f > 1.1):
        raise SwimInputError(f"the scene lies outside the CAMS grid's {label} {grid[0]:g} ... {grid[-1]:g}: "
                             f"its points reach {x.min():g} ... {x.max():g}")
    return i, np.clip(f, 0.0, 1.0)


def cams_neighbours(columns: CamsColumns, lat, lon):
    """The CAMS columns of each point and their weights: bilinear on a grid, the nearest column otherwise.

    Parameters
    ----------
    columns : CamsColumns
    lat, lon : array_like
        (n,) [deg].

    Returns
    -------
    index : numpy.ndarray
        (4, n) column indices into ``columns``.
    weight : numpy.ndarray
        (4, n) weights, summing to 1 for each point.

    Raises
    ------
    SwimInputError
        A point outside the grid.
    """
    lat, lon = np.asarray(lat, dtype=float).ravel(), np.asarray(lon, dtype=float).ravel()
    if columns.grid is None:
        c = _unit(columns.lat, columns.lon)
        nearest = np.argmax(_unit(lat, lon) @ c.T, axis=1)
        dist = np.degrees(np.arccos(np.clip(np.sum(_unit(lat, lon) * c[nearest], axis=1), -1.0, 1.0)))
        if dist.max() > 5.0:
            log.warning("CAMS columns: the nearest column lies up to %.1f deg from the scene", float(dist.max()))
        index = np.zeros((4, lat.size), dtype=int)
        index[0] = nearest
        weight = np.zeros((4, lat.size))
        weight[0] = 1.0
        return index, weight
    glat, glon = columns.grid
    wrap = _is_global(glon)
    i, fy = _bilinear_axis(glat, lat, "latitudes")
    j, fx = _bilinear_axis(glon, _lon_into(lon, glon[0]), "longitudes", wrap)
    n_lon = glon.size
    i1 = np.minimum(i + 1, glat.size - 1)
    j1 = (j + 1) % n_lon if wrap else np.minimum(j + 1, n_lon - 1)
    index = np.stack([i * n_lon + j, i * n_lon + j1, i1 * n_lon + j, i1 * n_lon + j1])
    weight = np.stack([(1 - fy) * (1 - fx), (1 - fy) * fx, fy * (1 - fx), fy * fx])
    return index, weight


def _unit(lat, lon):
    la, lo = np.radians(np.asarray(lat, dtype=float)), np.radians(np.asarray(lon, dtype=float))
    return np.stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)], axis=-1)


def _layer_optical_depths(z_half, tau, interfaces):
    """Optical depths (nz, m, 12) between scene interfaces (nz + 1, m) [m] of one CAMS column (z_half (L + 1,),
    tau (L, 12)): the column's optical depth above each interface, linear within each CAMS layer, its lowest
    layer's extinction continued below it, differenced."""
    above = np.concatenate([np.cumsum(tau[::-1], axis=0)[::-1], np.zeros((1, tau.shape[1]))])  # (L + 1, 12)
    beta0 = tau[0] / max(float(z_half[1] - z_half[0]), 1e-9)
    h = interfaces.ravel()
    out = np.empty(h.shape + (tau.shape[1],))
    below = h < z_half[0]
    for q in range(tau.shape[1]):
        out[:, q] = np.interp(h, z_half, above[:, q])
    out[below] = above[0] + (z_half[0] - h[below])[:, None] * beta0
    out = out.reshape(interfaces.shape + (tau.shape[1],))
    return out[:-1] - out[1:]


def _scene_interfaces(scene):
    """(nz + 1, n) heights [m] of the scene's layer interfaces (:func:`swim.io.scene.layer_thickness`'s)."""
    from ..io.scene import layer_thickness

    h = np.asarray(scene["height"].transpose("z", "y", "x").values, dtype=float)
    thickness = layer_thickness(h, scene["terrain_height"].transpose("y", "x").values)
    top = h[-1] + 0.5 * (h[-1] - h[-2])
    inter = top - np.concatenate([np.cumsum(thickness[::-1], axis=0)[::-1], np.zeros((1,) + h.shape[1:])])
    return inter.reshape(inter.shape[0], -1)


def add_cams_aerosol(scene: xr.Dataset, cams: xr.Dataset, table, time=None, type_map=None, rh_interpolation="bin",
                     name="cams", add=False):
    """Put CAMS aerosol onto a scene: its 550-nm extinction field and the mixture's effective type.

    Parameters
    ----------
    scene : xarray.Dataset
        Canonical scene (docs/scene-format.md): ``height`` (z, y, x) [m], ``lat``, ``lon``, ``terrain_height``
        (y, x).
    cams : xarray.Dataset
        CAMS data as :func:`cams_column_optics` reads them (ADS model or pressure levels, or ecRad's layout),
        covering the scene.
    table : IfsAerosolOpticsTable or str or pathlib.Path
        The IFS aerosol optics table (ecRad's ``aerosol_ifs_49R1.nc``).
    time : datetime-like, optional
        CAMS time to use where the dataset holds several; default the scene's ``time``.
    type_map, rh_interpolation
        As :func:`cams_column_optics`.
    name : str
        Name of the effective type.
    add : bool
        Add to an ``aerosol_extinction`` the scene already has.

    Returns
    -------
    scene : xarray.Dataset
        With ``aerosol_extinction`` (z, y, x) [m-1 at 550 nm].
    aerosol_type : AerosolType
        :func:`swim.optics.model_aerosol.effective_aerosol_type` of the aerosol on the scene (optical-depth
        weighted ω, g and the Ångström exponent of 450/615 nm). Render with ``swim.render(scene,
        aerosol=aerosol_type)``.

    Raises
    ------
    SwimInputError
        As :func:`cams_column_optics`, a scene outside the CAMS grid, or no aerosol on the scene.

    Notes
    -----
    Horizontal: bilinear in latitude and longitude between the four CAMS grid columns around each scene column
    (global grids wrap in longitude); the nearest column where the data are columns (ecRad layout). Vertical:
    each CAMS column's optical depth above a height is piecewise linear (constant extinction within a CAMS
    layer); a scene layer (interfaces midway between the mass points, the terrain at the bottom,
    :func:`swim.io.scene.layer_thickness`) gets the optical depth between its interfaces, so the scene's column
    AOD is the CAMS column's between the scene's ground and top. Heights above the CAMS ground (model levels,
    ecRad, pressure levels with ``sp``) are laid on the scene's terrain: the aerosol follows the scene's
    terrain, not the coarser CAMS orography; pressure levels placed by their geopotential are taken above sea
    level, and scene layers below the lowest CAMS layer get its extinction.
    """
    table = table if isinstance(table, IfsAerosolOpticsTable) else read_ifs_aerosol_optics(table)
    lat = np.asarray(scene["lat"].transpose("y", "x").values, dtype=float).ravel()
    lon = np.asarray(scene["lon"].transpose("y", "x").values, dtype=float).ravel()
    if time is None and "time" in scene.coords:
        time = scene["time"].values
    cols = cams_column_optics(cams, table, time, type_map, rh_interpolation, region=(lat, lon))
    index, weight = cams_neighbours(cols, lat, lon)
    h = _scene_interfaces(scene)
    if cols.above_ground:
        terrain = np.asarray(scene["terrain_height"].transpose("y", "x").values, dtype=float).ravel()
        h = np.clip(h - terrain[None], 0.0, None)
    dtau_550, totals = np.zeros((h.shape[0] - 1, lat.size)), np.zeros(12)
    for k in range(4):
        for c in np.unique(index[k][weight[k] > 0]):
            m = (index[k] == c) & (weight[k] > 0)
            dtau = _layer_optical_depths(cols.z_half[c], cols.tau[c], h[:, m]) * weight[k][m][None, :, None]
            dtau_550[:, m] += dtau[..., 3]
            totals += dtau.sum(axis=(0, 1))
    thickness = np.diff(h, axis=0)
    beta = np.where(thickness > 0, dtau_550 / np.where(thickness > 0, thickness, 1.0), 0.0)
    shape = scene["height"].transpose("z", "y", "x").shape
    tau, sca, gsca = totals[:4], totals[4:8], totals[8:]
    if not np.all(tau > 0):
        raise SwimInputError("the CAMS data put no aerosol on the scene (all mixing ratios 0 there)")
    aerosol_type = effective_aerosol_type(tau[None], (sca / tau)[None], (gsca / np.maximum(sca, 1e-30))[None],
                                          name=name)
    aod = dtau_550.sum(axis=0)
    log.info("CAMS aerosol on the scene: AOD at 550 nm %.3f-%.3f (mean %.3f)", aod.min(), aod.max(), aod.mean())
    out = scene_with_aerosol_extinction(scene, beta.reshape(shape), add=add,
                                        source=f"{cols.source} (IFS aerosol optics table, Bozzo et al. 2020)")
    return out, aerosol_type
