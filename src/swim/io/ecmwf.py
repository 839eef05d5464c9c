"""Readers for ECMWF output: ERA5 (or IFS) on pressure levels and IFS/ERA5 on the L137 model levels, from netCDF or
GRIB, into the canonical scene, with a choice of sub-grid cloud treatment.

Quantities (ECMWF parameter database): ``clwc``, ``ciwc``, ``crwc``, ``cswc`` are grid-box mean "specific" cloud
liquid, cloud ice, rain and snow water contents [kg kg-1]: "mass of condensate / mass of moist air"; ``q`` specific
humidity [kg kg-1]; ``cc`` the fraction of the grid box covered by cloud [0-1] (Tiedtke 1993,
doi:10.1175/1520-0493(1993)121<3040:ROCILS>2.0.CO;2); ``z`` geopotential [m2 s-2]; ``sp`` surface pressure [Pa],
``lnsp`` its logarithm.

* content [kg m-3] = mixing ratio x density of the whole mixture, ``rho = p / (R_d T_rho)`` with the density
  temperature ``T_rho = T (1 + (1/eps - 1) q - q_c)`` (:func:`swim.io.ecmwf_levels.air_density`);
* heights: from ``z`` where the file has it (:func:`swim.io.grib.geometric_height` of ``z / g``), otherwise by
  the hypsometric equation from the surface (:mod:`swim.io.ecmwf_levels`);
* the cloud fraction: ``cloud_fraction=`` (:data:`CLOUD_FRACTION_TREATMENTS`,
  docs/decisions/0017-cloud-fraction.md).

Layouts read:

* ERA5 pressure levels (:func:`read_era5_pressure_levels`): CDS netCDF (``level`` or ``pressure_level`` [hPa],
  ``time`` or ``valid_time``, ``latitude``, ``longitude``) or GRIB (cfgrib ``isobaricInhPa``);
* IFS model levels (:func:`read_ifs_model_levels`): the NWP SAF 137-level profile set layout (``temp``, ``hum``,
  ``clw``, ``ciw``, ``cc``, ``paph``, ``psurf``, ``z0`` on (height, point)), or ECMWF model-level fields (``t``,
  ``q``, ``clwc``, ... on ``hybrid``/``level``/``model_level`` with ``lnsp`` or ``sp`` and the surface ``z``),
  from netCDF or GRIB (the hybrid coefficients from the GRIB ``pv`` array, from ``hyai``/``hybi`` or, for 137
  levels, ECMWF's L137 table).

Gridded data must be on a regular latitude-longitude grid; ``lat``/``lon``/``radius_deg`` cut a region of it as
for NCEP GFS (:func:`swim.io.grib.region_columns`). A single profile (the NWP SAF set, ``column=``) becomes a
small patch of ``subcolumns x subcolumns`` columns ``column_width_m`` wide around its place, so that the renderer,
which needs a (z, y, x) grid, shows it: its sub-columns, or the profile repeated (horizontally homogeneous).
:func:`read_ecmwf` picks the reader; :func:`ecmwf_kind` and :func:`is_ecmwf_grib` recognise the files.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from ..constants import STANDARD_GRAVITY
from ..errors import SwimInputError
from .ecmwf_levels import (
    L137_A,
    L137_B,
    air_density,
    half_level_pressure,
    hybrid_coefficients_from_pv,
    model_level_heights,
    pressure_level_heights,
)
from .grib import DEFAULT_RADIUS_DEG, MAX_RADIUS_DEG, geometric_height, is_grib_file, region_columns
from .scene import WIND_SPEED_RANGE_M_S, scene_from_arrays, to_utc_datetime64, validate_scene

logger = logging.getLogger(__name__)

__all__ = [
    "CLOUD_FRACTION_TREATMENTS",
    "DEFAULT_SUBCOLUMNS",
    "EFFECTIVE_THICKNESS_FACTOR",
    "IFS_COLUMN_WIDTH_M",
    "read_ecmwf",
    "read_era5_pressure_levels",
    "read_ifs_model_levels",
    "ecmwf_kind",
    "is_ecmwf_grib",
    "maximum_random_overlap",
    "subcolumn_contents",
]

#: The sub-grid cloud treatments of ``cloud_fraction=`` (docs/decisions/0017-cloud-fraction.md):
#: ``grid_mean`` fills the whole cell with the grid-mean content; ``subcolumns`` splits each column into
#: ``subcolumns x subcolumns`` sub-columns, cloudy or clear by a maximum-random overlap generator (Raisanen et al.
#: 2004), the in-cloud content ``q / cc`` in the cloudy ones (needs ``cc``); ``effective_thickness`` scales the
#: grid-mean cloud liquid and ice by :data:`EFFECTIVE_THICKNESS_FACTOR` (Cahalan et al. 1994; Tiedtke 1996);
#: ``auto`` (the default) is ``subcolumns`` where the file has ``cc`` and ``grid_mean`` where it has not.
CLOUD_FRACTION_TREATMENTS = ("auto", "grid_mean", "subcolumns", "effective_thickness")
#: Sub-columns per side of a grid column (``subcolumns`` treatment), and columns per side of the patch made of a
#: single profile.
DEFAULT_SUBCOLUMNS = 8
#: Reduction factor of the cloud optical depth for the plane-parallel albedo bias (Cahalan et al. 1994,
#: doi:10.1175/1520-0469(1994)051<2434:TAOFC>2.0.CO;2; the ECMWF radiation scheme's factor, Tiedtke 1996,
#: doi:10.1175/1520-0493(1996)124<0745:AEOCRP>2.0.CO;2).
EFFECTIVE_THICKNESS_FACTOR = 0.7
#: Width [m] of the patch a single IFS profile becomes: the grid spacing of the T1279 IFS (16 km) from which the
#: NWP SAF 137-level profiles come.
IFS_COLUMN_WIDTH_M = 16_000.0
#: Largest in-cloud content [kg m-3] the sub-column generator makes: where ``q / cc`` would exceed it, more
#: sub-columns are made cloudy (10 g m-3, twice the largest adiabatic liquid water content of deep convection).
MAX_IN_CLOUD_CONTENT = 0.01
#: (ERA5/IFS short name, NWP SAF name) of each species.
_SPECIES = {"cloud_liquid": ("clwc", "clw"), "cloud_ice": ("ciwc", "ciw"), "rain": ("crwc", "rain_kgperkg"),
            "snow": ("cswc", "snow_kgperkg")}
_MIXING_UNITS = {"kg kg**-1", "kg kg-1", "kg/kg", "kg.kg-1", "1", "kg kg^-1"}
_RENAMES = {"pressure_level": "level", "isobaricInhPa": "level", "valid_time": "time", "lat": "latitude",
            "lon": "longitude", "hybrid": "level", "model_level": "level"}
_HOW_TO = ("swim.io.read_era5_pressure_levels reads t, q and clwc/ciwc/crwc/cswc on pressure levels; "
           "swim.io.read_ifs_model_levels reads them on model levels with lnsp or sp (docs/scene-format.md)")


# ---------------------------------------------------------------------------------------------------------------
# sub-grid cloud


def maximum_random_overlap(cloud_fraction, n_subcolumns, rng):
    """Cloudy sub-columns by the maximum-random overlap generator of Raisanen et al. (2004).

    Parameters
    ----------
    cloud_fraction : array_like
        Shape (nz, m) [0-1], **top first**: the cloud fraction of ``m`` grid columns.
    n_subcolumns : int
        Sub-columns per grid column.
    rng : numpy.random.Generator
        The random numbers.

    Returns
    -------
    x : numpy.ndarray
        Shape (nz, n_subcolumns, m): the generator's rank in [0, 1); the sub-column is cloudy at level k where
        ``x > 1 - C_k``, so larger ranks are cloudier.
    cloudy : numpy.ndarray of bool
        Shape (nz, n_subcolumns, m).

    Notes
    -----
    ``x_1 = R_1``; ``x_k = x_{k-1}`` where the sub-column is cloudy at ``k - 1`` (adjacent cloudy layers overlap
    maximally), otherwise ``x_k = R_k (1 - C_{k-1})`` (a new draw in the clear part: layers separated by clear air
    overlap randomly). The expected cloudy share of level k is ``C_k`` and the total cover that of maximum-random
    overlap (Geleyn and Hollingsworth 1979).

    References
    ----------
    Raisanen, P., Barker, H. W., Khairoutdinov, M. F., Li, J. and Randall, D. A. (2004), Stochastic generation of
    subgrid-scale cloudy columns for large-scale models, Q. J. R. Meteorol. Soc. 130, 2047-2067,
    doi:10.1256/qj.03.99 (Sect. 2, the maximum-random generator).
    """
    c = np.clip(np.asarray(cloud_fraction, dtype=float), 0.0, 1.0)
    nz, m = c.shape
    x = np.empty((nz, n_subcolumns, m))
    x[0] = rng.random((n_subcolumns, m))
    for k in range(1, nz):
        above_cloudy = x[k - 1] > 1.0 - c[k - 1]
        x[k] = np.where(above_cloudy, x[k - 1], rng.random((n_subcolumns, m)) * (1.0 - c[k - 1]))
    return x, x > 1.0 - c[:, None, :]


def subcolumn_contents(contents: dict, cloud_fraction, side: int, seed: int = 0, cloud_species=None) -> dict:
    """Split grid-mean contents into ``side x side`` sub-columns per grid column (in-cloud content in the cloudy
    ones), conserving the grid-mean content of every level exactly.

    Parameters
    ----------
    contents : dict of str to numpy.ndarray
        Species name to grid-mean content, shape (nz, ny, nx) [kg m-3], **lowest level first**.
    cloud_fraction : array_like
        Shape (nz, ny, nx) [0-1].
    side : int
        Sub-columns per side (>= 1).
    seed : int
        Seed of the random generator (the result is reproducible).
    cloud_species : iterable of str, optional
        Species placed in the cloudy sub-columns only (default ``cloud_liquid`` and ``cloud_ice``); the others
        (rain, snow) stay spread over the whole cell.

    Returns
    -------
    dict of str to numpy.ndarray
        Shape (nz, ny side, nx side) [kg m-3]. In a cloudy sub-column of level k of a cell the content is
        ``q_k N / N_cloudy`` (N = side^2 sub-columns, N_cloudy of them cloudy, about ``C_k N``); a level with
        content but no cloudy sub-column (``cc`` 0 or too small for one of N) gets the sub-columns of largest
        rank, as many as keep the in-cloud content under :data:`MAX_IN_CLOUD_CONTENT`.
    """
    cloud_species = ("cloud_liquid", "cloud_ice") if cloud_species is None else tuple(cloud_species)
    c = np.asarray(cloud_fraction, dtype=float)
    nz, ny, nx = c.shape
    n = side * side
    x, cloudy = maximum_random_overlap(c[::-1].reshape(nz, ny * nx), n, np.random.default_rng(seed))
    x, cloudy = x[::-1], cloudy[::-1]  # back to lowest first; shape (nz, n, ny nx)
    total = sum(contents[s] for s in cloud_species if s in contents)
    out = {}
    if not np.isscalar(total):
        total = total.reshape(nz, 1, ny * nx)
        need = np.where(total > 0, np.maximum(1, np.ceil(total * n / MAX_IN_CLOUD_CONTENT)), 0)
        rank = np.argsort(np.argsort(-x, axis=1), axis=1)  # 0 for the largest x of a cell and level
        cloudy = (cloudy | (rank < need)) & (total > 0)
        share = n / np.maximum(cloudy.sum(axis=1, keepdims=True), 1)
    for name, value in contents.items():
        v = np.asarray(value, dtype=float).reshape(nz, 1, ny * nx)
        sub = np.where(cloudy, v * share, 0.0) if name in cloud_species else np.broadcast_to(v, (nz, n, ny * nx))
        out[name] = _sub_grid(sub, side, ny, nx)
    return out


def _sub_grid(sub: np.ndarray, side: int, ny: int, nx: int) -> np.ndarray:
    """(nz, side^2, ny nx) sub-column values to the (nz, ny side, nx side) grid (sub-column s at row s // side and
    column s % side of its cell)."""
    nz = sub.shape[0]
    grid = sub.reshape(nz, side, side, ny, nx).transpose(0, 3, 1, 4, 2)
    return np.ascontiguousarray(grid.reshape(nz, ny * side, nx * side))


def _refine(values: np.ndarray, side: int) -> np.ndarray:
    """Each cell of the last two axes repeated ``side x side`` times."""
    return np.repeat(np.repeat(values, side, axis=-2), side, axis=-1)


def _check_treatment(cloud_fraction, has_cc: bool, subcolumns, label: str) -> str:
    """The treatment to apply, after checking the option against :data:`CLOUD_FRACTION_TREATMENTS`."""
    if cloud_fraction not in CLOUD_FRACTION_TREATMENTS:
        raise SwimInputError(f"cloud_fraction={cloud_fraction!r}: expected one of "
                             f"{', '.join(CLOUD_FRACTION_TREATMENTS)} (docs/decisions/0017-cloud-fraction.md)")
    if not isinstance(subcolumns, (int, np.integer)) or not 1 <= int(subcolumns) <= 32:
        raise SwimInputError(f"subcolumns={subcolumns!r}: expected an integer in [1, 32] (sub-columns per side)")
    if cloud_fraction == "auto":
        return "subcolumns" if has_cc else "grid_mean"
    if cloud_fraction == "subcolumns" and not has_cc:
        raise SwimInputError(f"{label}: cloud_fraction='subcolumns' needs the cloud cover cc [0-1], which the file "
                             "lacks; use 'grid_mean' or 'effective_thickness'")
    return cloud_fraction


# ---------------------------------------------------------------------------------------------------------------
# profiles to scene


def _contents(prof: dict, label: str) -> dict:
    """Contents [kg m-3] (nz, ny, nx) of the species in ``prof['mix']`` (zero under the surface); a species that
    is zero everywhere is left out."""
    mix = prof["mix"]
    for name, value in mix.items():
        if np.any(value < -1e-9):
            logger.info("%s: clipped %d negative %s mixing ratio(s) (min %.3g kg kg-1) to 0", label,
                        int(np.sum(value < 0)), name, value.min())
        mix[name] = np.clip(value, 0.0, None)
    rho = air_density(prof["p"], prof["t"], prof["q"], sum(mix.values()))
    out = {}
    for name, value in mix.items():
        content = value * rho
        if prof.get("underground") is not None:
            content = np.where(prof["underground"], 0.0, content)
        if np.any(content > 0):
            out[name] = content
    return out


def _apply_treatment(prof: dict, contents: dict, treatment: str, side: int, seed: int) -> tuple[dict, int]:
    """The contents after the cloud-fraction ``treatment`` and the refinement (sub-columns per side) it made."""
    if treatment == "effective_thickness":
        return {k: v * EFFECTIVE_THICKNESS_FACTOR if k in ("cloud_liquid", "cloud_ice") else v
                for k, v in contents.items()}, 1
    if treatment == "subcolumns" and contents:
        return subcolumn_contents(contents, prof["cc"], side, seed), side
    return contents, 1


def _lat_lon_grid(lat: np.ndarray, lon: np.ndarray, side: int) -> tuple[np.ndarray, np.ndarray]:
    """2-D lat/lon (ny side, nx side) [deg] of a regular grid's sub-cells (centres ``(s + 1/2) / side - 1/2``
    spacings from the cell centre)."""
    offsets = (np.arange(side) + 0.5) / side - 0.5

    def axis(v):
        step = float(np.median(np.diff(v))) if v.size > 1 else 0.0
        return (v[:, None] + offsets[None] * step).ravel()

    return np.meshgrid(axis(lat), axis(lon), indexing="ij")


def _grid_scene(prof: dict, contents: dict, side: int, attrs: dict) -> xr.Dataset:
    """The validated scene of a regular lat-lon grid of profiles (each cell refined ``side x side``)."""
    dims3, dims2 = ("z", "y", "x"), ("y", "x")
    lat2, lon2 = _lat_lon_grid(prof["lat"], prof["lon"], side)
    data = {"height": xr.DataArray(_refine(prof["height"], side), dims=dims3)}
    data.update({f"{k}_content": xr.DataArray(v, dims=dims3) for k, v in contents.items()})
    data["lat"] = xr.DataArray(lat2, dims=dims2, attrs={"units": "degrees_north"})
    data["lon"] = xr.DataArray(lon2, dims=dims2, attrs={"units": "degrees_east"})
    for name, value in prof["surface"].items():
        refined = _refine(value, side)
        data[name] = xr.DataArray(refined, dims=dims2)
    coords = {} if prof.get("time") is None else {"time": xr.DataArray(prof["time"])}
    return validate_scene(xr.Dataset(data, coords=coords, attrs=attrs))


def _patch_scene(prof: dict, contents: dict, side: int, width_m: float, attrs: dict) -> xr.Dataset:
    """The validated scene of one profile: a ``side x side`` patch ``width_m`` wide centred on the column (the
    sub-columns, or the same column repeated)."""
    x = (np.arange(side) + 0.5 - side / 2.0) * (width_m / side)
    fields = {f"{k}_content": (v if v.shape[1] == side else np.broadcast_to(v, v.shape[:1] + (side, side))).copy()
              for k, v in contents.items()}
    height = np.broadcast_to(prof["height"][:, :1, :1], (prof["height"].shape[0], side, side))
    surface = {k: float(np.ravel(v)[0]) for k, v in prof["surface"].items()}
    if "land_mask" in surface:
        surface["land_mask"] = int(surface["land_mask"])
    scene = scene_from_arrays(x=x, y=x, z=height, reference_lat=float(prof["lat"][0]),
                              reference_lon=float(prof["lon"][0]), time=prof.get("time"),
                              title=attrs["title"], source=attrs["source"], **fields, **surface)
    scene.attrs.update({k: v for k, v in attrs.items() if k not in ("title", "source")})
    return validate_scene(scene)


def _to_scene(prof: dict, cloud_fraction: str, subcolumns: int, seed: int, width_m, attrs: dict,
              label: str) -> xr.Dataset:
    """The canonical scene of ``prof`` (lowest level first) after the cloud-fraction treatment."""
    treatment = _check_treatment(cloud_fraction, prof.get("cc") is not None, subcolumns, label)
    contents = _contents(prof, label)
    single = prof["height"].shape[1:] == (1, 1)
    contents, side = _apply_treatment(prof, contents, treatment, int(subcolumns), seed)
    attrs = dict(attrs, ecmwf_cloud_fraction=treatment, ecmwf_subcolumns=int(side))
    logger.info("%s: cloud_fraction=%s (%d x %d sub-columns per column)", label, treatment, side, side)
    try:
        if single:
            return _patch_scene(prof, contents, int(subcolumns), float(width_m or IFS_COLUMN_WIDTH_M), attrs)
        return _grid_scene(prof, contents, side, attrs)
    except SwimInputError as exc:
        raise SwimInputError(f"{label}: {exc}") from exc


# ---------------------------------------------------------------------------------------------------------------
# opening and naming


def _open(path_or_dataset, kind: str, level_type: str):
    """(dataset, label, source) of a path (netCDF, or GRIB read with cfgrib: the messages on ``level_type`` merged
    with the surface ones) or of an open dataset."""
    if isinstance(path_or_dataset, xr.Dataset):
        return path_or_dataset, kind, "xarray.Dataset"
    p = Path(path_or_dataset)
    if not p.is_file():
        raise SwimInputError(f"{kind} not found: {p}")
    label = f"{kind} {p.name}"
    if is_grib_file(p):
        return _open_grib(p, level_type, label), label, str(p)
    from .files import open_netcdf

    with open_netcdf(p, kind) as ds:
        return ds.load(), label, str(p)


def _open_grib(p: Path, level_type: str, label: str) -> xr.Dataset:
    """The GRIB messages on ``level_type`` with the surface fields (``sp``, ``lnsp``, ``z`` of the surface as
    ``z_surface``, ``lsm``) and, on hybrid levels, the ``pv`` coefficients as ``hyai``/``hybi``."""
    try:
        import cfgrib
    except ImportError as exc:
        raise SwimInputError(f"{label}: reading GRIB needs cfgrib and ecCodes: "
                             "pip install 'swim-imagery[grib]'") from exc
    try:
        groups = cfgrib.open_datasets(str(p), backend_kwargs={"indexpath": ""})
    except (EOFError, OSError, ValueError, RuntimeError) as exc:
        raise SwimInputError(f"{label}: not readable as GRIB ({exc}); {_HOW_TO}") from exc
    main = [g.load() for g in groups if level_type in g.dims]
    if not main:
        raise SwimInputError(f"{label}: no messages on more than one {level_type} level; {_HOW_TO}")
    out = xr.merge(main, compat="override", join="override")
    for g in groups:
        if level_type in g.dims:
            continue
        for name in ("sp", "lnsp", "z", "lsm"):
            if name in g.data_vars:
                da = g[name].load()
                out[name if name != "z" else "z_surface"] = da.drop_vars([c for c in da.coords if c not in da.dims])
    if level_type == "hybrid":
        _attach_pv(p, out)
    return out


def _attach_pv(p: Path, ds: xr.Dataset) -> None:
    """Add the ``pv`` hybrid coefficients of the first message on hybrid levels as ``hyai`` [Pa] and ``hybi``."""
    import eccodes

    with open(p, "rb") as f:
        while True:
            gid = eccodes.codes_grib_new_from_file(f)
            if gid is None:
                return
            try:
                if eccodes.codes_get(gid, "typeOfLevel") == "hybrid" and eccodes.codes_get(gid, "PVPresent"):
                    a, b = hybrid_coefficients_from_pv(eccodes.codes_get_array(gid, "pv"))
                    ds["hyai"], ds["hybi"] = xr.DataArray(a, dims="nhyi"), xr.DataArray(b, dims="nhyi")
                    return
            finally:
                eccodes.codes_release(gid)


def _standardise(ds: xr.Dataset) -> xr.Dataset:
    """The CDS/cfgrib naming variants mapped to one: ``level``, ``time`` (the valid time), ``latitude``,
    ``longitude``; a forecast reference time next to a valid time is kept as ``forecast_reference_time``."""
    if "valid_time" in ds.variables and "time" in ds.variables:
        ds = ds.rename({"time": "forecast_reference_time"})
    renames = {k: v for k, v in _RENAMES.items() if k in ds.dims or (k in ds.coords and ds[k].ndim <= 1
                                                                     and k not in ("lat", "lon"))}
    renames.update({k: v for k, v in (("lat", "latitude"), ("lon", "longitude")) if k in ds.dims})
    ds = ds.rename(renames)
    for dim in ("step", "number", "surface"):
        if dim in ds.dims and ds.sizes[dim] == 1:
            ds = ds.isel({dim: 0})
    return ds


def _select_time(ds: xr.Dataset, time, label: str) -> xr.Dataset:
    """``ds`` at one time: the only one, the first (``time=None``) or the nearest to ``time`` within 1.5 h."""
    if "time" not in ds.dims:
        return ds
    values = np.asarray(ds["time"].values)
    i = 0
    if time is not None:
        want = to_utc_datetime64(time)
        i = int(np.argmin(np.abs(values - want)))
        if abs(values[i] - want) > np.timedelta64(90, "m"):
            have = ", ".join(pd.Timestamp(t).strftime("%Y-%m-%dT%H:%MZ") for t in values)
            raise SwimInputError(f"time={time!r} is more than 1.5 h from every time of {label}: {have}")
    return ds.isel(time=i)


def _require(ds: xr.Dataset, names, label: str) -> None:
    """Refuse a dataset without the variables ``names`` or without any hydrometeor, naming what is missing."""
    missing = [n for n in names if n not in ds.variables]
    if not any(s[0] in ds.variables for s in _SPECIES.values()):
        missing.append("any of clwc, ciwc, crwc, cswc")
    if missing:
        raise SwimInputError(f"{label} lacks {', '.join(missing)}; {_HOW_TO}")


def _check_units(ds: xr.Dataset, label: str) -> None:
    """Refuse mixing ratios not in kg kg-1, temperatures not in K and cloud cover outside [0, 1]."""
    for name in ("q", "clwc", "ciwc", "crwc", "cswc", "clw", "ciw", "hum", "rain_kgperkg", "snow_kgperkg"):
        if name not in ds.variables:
            continue
        units = str(ds[name].attrs.get("units", ds[name].attrs.get("unit", "kg kg**-1"))).strip()
        if units not in _MIXING_UNITS:
            raise SwimInputError(f"{label}: {name} has units {units!r}; expected kg kg-1 (mass per kg of moist air)")
        if float(ds[name].max()) > 0.05:
            raise SwimInputError(f"{label}: {name} reaches {float(ds[name].max()):.3g}; expected kg kg-1 (< 0.05), "
                                 "not g kg-1")
    for name in ("t", "temp"):
        if name in ds.variables:
            units = str(ds[name].attrs.get("units", ds[name].attrs.get("unit", "K"))).strip()
            if units != "K" or not 100.0 < float(ds[name].min()) <= float(ds[name].max()) < 400.0:
                raise SwimInputError(f"{label}: {name} has units {units!r} and range [{float(ds[name].min()):.4g}, "
                                     f"{float(ds[name].max()):.4g}]; expected K in (100, 400)")
    if "cc" in ds.variables and not (float(ds["cc"].min()) >= -1e-6 and float(ds["cc"].max()) <= 1.0 + 1e-6):
        raise SwimInputError(f"{label}: cc in [{float(ds['cc'].min()):.3g}, {float(ds['cc'].max()):.3g}]; expected a "
                             "fraction in [0, 1] (not %)")


def _attrs(label: str, source: str, reader: str, when, extra=None) -> dict:
    """Title and source of a scene."""
    title = f"{label}" + ("" if when is None else f", valid {pd.Timestamp(when):%Y-%m-%d %H:%M} UTC")
    return {"title": title, "source": f"{source} read by swim.io.ecmwf.{reader}", **(extra or {})}


# ---------------------------------------------------------------------------------------------------------------
# ERA5 pressure levels


def _pressure_levels_hpa(ds: xr.Dataset, label: str) -> np.ndarray:
    """The ``level`` coordinate as pressures [hPa] (Pa converted)."""
    if "level" not in ds.dims:
        raise SwimInputError(f"{label} has no pressure-level dimension (level, pressure_level or isobaricInhPa)")
    levels = np.atleast_1d(ds["level"].values).astype(float)
    units = str(ds["level"].attrs.get("units", "hPa")).lower()
    if units == "pa" or levels.max() > 2000.0:
        levels = levels / 100.0
    if levels.size < 2:
        raise SwimInputError(f"{label}: {levels.size} pressure level; a scene needs at least 2")
    return levels


def _grid_field(ds: xr.Dataset, name: str, rows, cols, order=None) -> np.ndarray:
    """``ds[name]`` as float64 (level, latitude, longitude) or (latitude, longitude), rows south to north and
    columns west to east, levels in ``order``; non-finite values refused."""
    da = ds[name]
    dims = [d for d in ("level", "latitude", "longitude") if d in da.dims]
    extra = [d for d in da.dims if d not in dims]
    if extra:
        da = da.isel({d: 0 for d in extra})
    v = np.asarray(da.transpose(*dims).values, dtype=float)
    v = v[..., rows, :][..., cols]
    if order is not None and "level" in dims:
        v = v[order]
    if not np.all(np.isfinite(v)):
        raise SwimInputError(f"{name} has {int(np.sum(~np.isfinite(v)))} missing or non-finite value(s)")
    return v


def _surface_fields(ds: xr.Dataset, rows, cols) -> dict:
    """Terrain height [m] (the surface geopotential over g, or 0: sea level) and the land mask where present."""
    out = {}
    if "z_surface" in ds.variables:
        out["terrain_height"] = geometric_height(_grid_field(ds, "z_surface", rows, cols) / STANDARD_GRAVITY)
    if "lsm" in ds.variables:
        out["land_mask"] = (_grid_field(ds, "lsm", rows, cols) > 0.5).astype(np.int8)
    return out


def _region(ds: xr.Dataset, place, label: str):
    """Rows (south to north) and columns (west to east) of the grid, and their latitudes and longitudes [deg]:
    the whole grid, or with ``place`` = (lat, lon, radius_deg) the box of columns within ``radius_deg`` of
    (lat, lon) (:func:`swim.io.grib.region_columns`, across the 0/360 seam of a global grid)."""
    if not {"latitude", "longitude"} <= set(ds.dims):
        raise SwimInputError(f"{label}: not on a regular latitude-longitude grid (latitude and longitude must be "
                             "dimensions; a reduced Gaussian or spectral field must be interpolated first, e.g. MARS "
                             "or the CDS with grid=0.25/0.25)")
    lats = np.asarray(ds["latitude"].values, dtype=float)
    lons = np.asarray(ds["longitude"].values, dtype=float)
    lat, lon, radius_deg = place
    if lat is None or lon is None:
        rows, cols = np.argsort(lats), np.argsort(lons)
        return rows, cols, lats[rows], lons[cols]
    radius = DEFAULT_RADIUS_DEG if radius_deg is None else float(radius_deg)
    if not 0.0 < radius <= MAX_RADIUS_DEG:
        raise SwimInputError(f"radius_deg={radius_deg!r}: expected (0, {MAX_RADIUS_DEG:g}] deg")
    spacing = abs(float(np.median(np.diff(np.sort(lons))))) if lons.size > 1 else 360.0
    wrap = abs(lons.size * spacing - 360.0) < 1e-3 * spacing
    rows, cols, longitudes = region_columns(lats, lons, float(lat), float(lon), radius, wrap=wrap)
    logger.info("%s: %d x %d columns within %g deg of (%g, %g)", label, rows.size, cols.size, radius, lat, lon)
    return rows, cols, lats[rows], longitudes


def _era5_profiles(ds: xr.Dataset, label: str, place=(None, None, None)) -> dict:
    """The profiles (lowest level first, south to north, west to east) of an ERA5 pressure-level dataset."""
    levels = _pressure_levels_hpa(ds, label)
    order = np.argsort(-levels)
    rows, cols, lats, lons = _region(ds, place, label)
    t = _grid_field(ds, "t", rows, cols, order)
    p = np.broadcast_to((levels[order] * 100.0)[:, None, None], t.shape)
    prof = {"p": p, "t": t, "q": _grid_field(ds, "q", rows, cols, order),
            "lat": lats, "lon": lons,
            "mix": {s: _grid_field(ds, n[0], rows, cols, order) for s, n in _SPECIES.items() if n[0] in ds.variables},
            "cc": _grid_field(ds, "cc", rows, cols, order) if "cc" in ds.variables else None}
    surface = _surface_fields(ds, rows, cols)
    sp = _grid_field(ds, "sp", rows, cols) if "sp" in ds.variables else None
    if "z" in ds.variables and "level" in ds["z"].dims:
        prof["height"] = geometric_height(_grid_field(ds, "z", rows, cols, order) / STANDARD_GRAVITY)
    else:
        phi_s = None if "terrain_height" not in surface else _grid_field(ds, "z_surface", rows, cols)
        if sp is None:
            logger.info("%s: no geopotential z and no surface pressure: heights from the standard sea-level "
                        "pressure 1013.25 hPa at 0 m (about +-100 m)", label)
        prof["height"] = pressure_level_heights(levels[order] * 100.0, t, prof["q"], sp, phi_s)
    prof["underground"] = None if sp is None else p > sp[None]
    surface.setdefault("terrain_height", np.zeros(t.shape[1:]))
    prof["surface"] = surface
    prof["time"] = to_utc_datetime64(ds["time"].values) if "time" in ds.variables else None
    return prof


def read_era5_pressure_levels(path_or_dataset, time=None, cloud_fraction="auto", subcolumns=DEFAULT_SUBCOLUMNS,
                              seed=0, lat=None, lon=None, radius_deg=None, source=None) -> xr.Dataset:
    """Read ERA5 (or IFS) output on pressure levels, netCDF or GRIB, into the canonical scene.

    Parameters
    ----------
    path_or_dataset : str, os.PathLike or xarray.Dataset
        A CDS netCDF file (``grib_to_netcdf`` or the new CDS layout: ``level`` or ``pressure_level`` [hPa],
        ``time`` or ``valid_time``, ``latitude``, ``longitude``), a GRIB file (cfgrib ``isobaricInhPa``) or an
        open dataset. Variables: ``t`` [K], ``q`` [kg kg-1] and at least one of ``clwc``, ``ciwc``, ``crwc``,
        ``cswc`` [kg kg-1 of moist air]; optional ``z`` geopotential [m2 s-2] on the levels, ``cc`` [0-1], ``sp``
        [Pa] and, in GRIB, the surface ``z`` [m2 s-2] and ``lsm``.
    time : str, datetime or numpy.datetime64, optional
        Valid time (UTC): the nearest in the file within 1.5 h; None: the first.
    cloud_fraction : str
        Sub-grid cloud treatment, one of :data:`CLOUD_FRACTION_TREATMENTS`; default ``auto``
        (docs/decisions/0017-cloud-fraction.md).
    subcolumns : int
        Sub-columns per side of a grid column for ``subcolumns`` (1-32); default :data:`DEFAULT_SUBCOLUMNS`.
    seed : int
        Seed of the sub-column generator.
    lat, lon : float, optional
        Centre [deg] of the region to cut: the columns within ``radius_deg`` (default
        :data:`swim.io.grib.DEFAULT_RADIUS_DEG`, at most 30) of it (:func:`swim.io.grib.region_columns`); None:
        the whole grid. A global grid needs them (the scene frame is orthographic).
    radius_deg : float, optional
        Radius [deg] of that region.
    source : str, optional
        The ``source`` attribute (default: the path).

    Returns
    -------
    xarray.Dataset
        The validated canonical scene: (z, y, x) = (the pressure levels, highest pressure first; latitude south to
        north; longitude west to east; each refined ``subcolumns x subcolumns`` with the ``subcolumns``
        treatment). ``height`` [m] from ``z``, or hypsometric from ``t`` and ``q``
        (:func:`swim.io.ecmwf_levels.pressure_level_heights`: from ``sp`` at the surface height, or from
        1013.25 hPa at 0 m); ``terrain_height`` from the surface ``z`` or 0 m; ``<species>_content`` [kg m-3]
        (mixing ratio x :func:`swim.io.ecmwf_levels.air_density`, 0 where the level's pressure exceeds ``sp``);
        ``time``; attributes ``title``, ``source``, ``ecmwf_cloud_fraction``, ``ecmwf_subcolumns``.

    Raises
    ------
    SwimInputError
        If ``t``, ``q`` or every hydrometeor is missing, a unit is not the above (mixing ratios in g kg-1, cc in
        %), the file has no pressure-level dimension, ``time`` is more than 1.5 h from the file's times,
        ``cloud_fraction`` is unknown or ``subcolumns`` without ``cc``, or the scene fails validation.

    References
    ----------
    ECMWF parameter database (clwc, ciwc, crwc, cswc: "mass of condensate / mass of moist air"); Raisanen et al.
    (2004), doi:10.1256/qj.03.99; Cahalan et al. (1994), doi:10.1175/1520-0469(1994)051<2434:TAOFC>2.0.CO;2.
    """
    ds, label, opened = _open(path_or_dataset, "ERA5 pressure-level file", "isobaricInhPa")
    source = opened if source is None else str(source)
    ds = _select_time(_standardise(ds), time, label)
    _require(ds, ("t", "q", "latitude", "longitude"), label)
    _check_units(ds, label)
    prof = _era5_profiles(ds, label, (lat, lon, radius_deg))
    attrs = _attrs(label, source, "read_era5_pressure_levels", prof["time"])
    return _to_scene(prof, cloud_fraction, subcolumns, seed, None, attrs, label)


# ---------------------------------------------------------------------------------------------------------------
# IFS model levels


def _is_profile_set(ds: xr.Dataset) -> bool:
    """The NWP SAF 137-level profile-set layout (S3COM input): ``temp``, ``hum``, ``paph`` on (height, point)."""
    return {"temp", "hum", "paph", "psurf"} <= set(ds.variables) and "point" in ds.dims


def _profile_time(sel: xr.Dataset):
    """The NWP SAF date stamp (``year``, ``month``, ``day``) plus ``step`` hours, or None."""
    if not {"year", "month", "day"} <= set(sel.variables):
        return None
    base = pd.Timestamp(int(sel["year"]), int(sel["month"]), int(sel["day"]))
    step = float(sel["step"]) if "step" in sel.variables else 0.0
    return to_utc_datetime64(base + pd.Timedelta(hours=step))


def _profile_surface(sel: xr.Dataset) -> dict:
    """Terrain [m] (surface geopotential over g, or ``elevation``), land mask, snow-free albedo, snow cover (1 where
    the snow depth exceeds 1 cm of water) and 10 m wind speed of one profile, shaped (1, 1)."""
    one = (1, 1)
    if "z0" in sel.variables:
        terrain = geometric_height(float(sel["z0"]) / STANDARD_GRAVITY)
    else:
        terrain = float(sel["elevation"]) if "elevation" in sel.variables else 0.0
    out = {"terrain_height": np.full(one, terrain)}
    if "lsm" in sel.variables:
        out["land_mask"] = np.full(one, int(float(sel["lsm"]) > 0.5), dtype=np.int8)
    snowy = "sd" in sel.variables and float(sel["sd"]) > 0.01
    if snowy:
        out["snow_cover"] = np.ones(one)
    if "alb" in sel.variables and not snowy:
        out["surface_albedo"] = np.full(one, float(np.clip(sel["alb"], 0.0, 1.0)))
    if {"u10", "v10"} <= set(sel.variables):
        out["wind_speed_10m"] = np.full(one, float(np.clip(np.hypot(sel["u10"], sel["v10"]), *WIND_SPEED_RANGE_M_S)))
    return out


def _nearest_point(ds: xr.Dataset, lat, lon, label: str) -> int:
    """The index of the profile nearest (great circle) to (lat, lon), or 0 where they are not given."""
    if lat is None or lon is None:
        logger.info("%s: %d profiles; reading column 0 (column=, or lat=/lon= for the nearest)", label,
                    ds.sizes["point"])
        return 0
    la, lo = np.deg2rad(np.asarray(ds["lat"].values, dtype=float)), np.deg2rad(np.asarray(ds["lon"].values, float))
    la0, lo0 = np.deg2rad(float(lat)), np.deg2rad(float(lon))
    cos_d = np.sin(la) * np.sin(la0) + np.cos(la) * np.cos(la0) * np.cos(lo - lo0)
    return int(np.argmax(cos_d))


def _profile_set_column(ds: xr.Dataset, column, label: str) -> dict:
    """The profile (lowest level first, shape (nz, 1, 1)) of point ``column`` of an NWP SAF profile set."""
    npoint = ds.sizes["point"]
    if not isinstance(column, (int, np.integer)) or not 0 <= int(column) < npoint:
        raise SwimInputError(f"{label}: column={column!r}; expected an integer point index in [0, {npoint - 1}]")
    sel = ds.isel(point=int(column))
    missing = [n for n in ("clw", "ciw") if n not in sel.variables]
    if missing:
        raise SwimInputError(f"{label} lacks {', '.join(missing)} [kg kg-1]; {_HOW_TO}")

    def col(name):
        return np.asarray(sel[name].values, dtype=float)[::-1, None, None]

    ph = np.asarray(sel["paph"].values, dtype=float)
    phi_s = float(sel["z0"]) if "z0" in sel.variables else STANDARD_GRAVITY * float(sel.get("elevation", 0.0))
    mix_top = {s: np.asarray(sel[n[1]].values, dtype=float) for s, n in _SPECIES.items() if n[1] in sel.variables}
    if "rain_kgperkg" not in sel.variables and "rain" in sel.variables:
        logger.warning("%s: rain and snow are precipitation fluxes [kg m-2 s-1] only: left out", label)
    height = model_level_heights(ph, sel["temp"].values, sel["hum"].values, phi_s, sum(mix_top.values()))
    p = col("pap") if "pap" in sel.variables else 0.5 * (ph[:-1] + ph[1:])[::-1, None, None]
    return {"p": p, "t": col("temp"), "q": col("hum"), "height": height[::-1, None, None],
            "mix": {s: v[::-1, None, None] for s, v in mix_top.items()},
            "cc": col("cc") if "cc" in sel.variables else None, "underground": None,
            "lat": np.array([float(sel["lat"])]), "lon": np.array([float(sel["lon"])]),
            "surface": _profile_surface(sel), "time": _profile_time(sel)}


def _hybrid_coefficients(ds: xr.Dataset, numbers: np.ndarray, label: str):
    """Half-level ``a`` [Pa] and ``b`` of the model levels ``numbers`` (1-based, top first) and the levels below
    them: from ``hyai``/``hybi`` (CDO, or a GRIB ``pv``) or, with 137 levels, ECMWF's L137 table."""
    if {"hyai", "hybi"} <= set(ds.variables):
        a, b = np.asarray(ds["hyai"].values, dtype=float), np.asarray(ds["hybi"].values, dtype=float)
    else:
        a, b = L137_A, L137_B
        logger.info("%s: no hybrid coefficients in the file: ECMWF's L137 table", label)
    nlev = a.size - 1
    if numbers.max() != nlev or np.any(np.diff(numbers) != 1):
        raise SwimInputError(f"{label}: model levels {int(numbers.min())}-{int(numbers.max())} of {nlev}: the "
                             "heights need every level from the lowest ({nlev}) up, contiguous")
    return a[int(numbers[0]) - 1:], b[int(numbers[0]) - 1:]


def _model_level_profiles(ds: xr.Dataset, label: str, place=(None, None, None)) -> dict:
    """The profiles (lowest level first) of ECMWF model-level fields on a lat-lon grid (``level`` = model level
    numbers) with ``lnsp`` or ``sp`` and the surface geopotential (``z_surface`` or a 2-D ``z``)."""
    numbers = np.atleast_1d(ds["level"].values).astype(int)
    order = np.argsort(numbers)  # top first
    rows, cols, lats, lons = _region(ds, place, label)
    if "lnsp" in ds.variables:
        sp = np.exp(_grid_field(ds, "lnsp", rows, cols))
    elif "sp" in ds.variables:
        sp = _grid_field(ds, "sp", rows, cols)
    else:
        raise SwimInputError(f"{label} lacks the surface pressure (lnsp or sp); {_HOW_TO}")
    zname = "z_surface" if "z_surface" in ds.variables else "z"
    if zname not in ds.variables:
        raise SwimInputError(f"{label} lacks the surface geopotential z [m2 s-2]; {_HOW_TO}")
    phi_s = _grid_field(ds, zname, rows, cols)
    phi_s = phi_s.reshape(phi_s.shape[-2:]) if phi_s.ndim == 3 and phi_s.shape[0] == 1 else phi_s
    a, b = _hybrid_coefficients(ds, numbers[order], label)
    ph = half_level_pressure(sp, a, b)
    t, q = _grid_field(ds, "t", rows, cols, order), _grid_field(ds, "q", rows, cols, order)
    mix = {s: _grid_field(ds, n[0], rows, cols, order) for s, n in _SPECIES.items() if n[0] in ds.variables}
    height = model_level_heights(ph, t, q, phi_s, sum(mix.values()))
    cc = _grid_field(ds, "cc", rows, cols, order)[::-1] if "cc" in ds.variables else None
    surface = {"terrain_height": geometric_height(phi_s / STANDARD_GRAVITY), **_surface_fields(
        ds.drop_vars("z_surface", errors="ignore"), rows, cols)}
    return {"p": (0.5 * (ph[:-1] + ph[1:]))[::-1], "t": t[::-1], "q": q[::-1], "height": height[::-1],
            "mix": {s: v[::-1] for s, v in mix.items()}, "cc": cc, "underground": None,
            "lat": lats, "lon": lons, "surface": surface,
            "time": to_utc_datetime64(ds["time"].values) if "time" in ds.variables else None}


def read_ifs_model_levels(path_or_dataset, column=None, time=None, cloud_fraction="auto",
                          subcolumns=DEFAULT_SUBCOLUMNS, seed=0, column_width_m=IFS_COLUMN_WIDTH_M, lat=None, lon=None,
                          radius_deg=None, source=None) -> xr.Dataset:
    """Read IFS (or ERA5) output on hybrid model levels, netCDF or GRIB, into the canonical scene.

    Parameters
    ----------
    path_or_dataset : str, os.PathLike or xarray.Dataset
        Either an NWP SAF 137-level profile set (``temp`` [K], ``hum`` [kg kg-1], ``clw``, ``ciw``,
        ``rain_kgperkg``, ``snow_kgperkg`` [kg kg-1], ``cc`` [0-1], ``pap``/``paph`` [Pa], ``psurf`` [Pa], ``z0``
        [m2 s-2], ``lat``/``lon``, ``lsm``, ``alb``, ``sd``, ``u10``/``v10`` on (height, point), top first), or
        ECMWF model-level fields on a lat-lon grid (``t``, ``q``, ``clwc``, ``ciwc``, ``crwc``, ``cswc``,
        ``cc`` on ``hybrid``/``level``/``model_level``, with ``lnsp`` or ``sp`` [Pa] and the surface ``z``
        [m2 s-2]); GRIB messages carry their hybrid coefficients (``pv``), netCDF files may carry ``hyai``/
        ``hybi``, otherwise 137 levels take ECMWF's L137 table.
    column : int, optional
        Profile set only: the point (0-based) to read; default: the point nearest to (lat, lon) where they are
        given, else 0. A profile becomes a patch of ``subcolumns x subcolumns`` columns ``column_width_m`` wide
        around it: its sub-columns, or the profile repeated.
    time : optional
        Gridded files: the valid time (UTC) to read, nearest within 1.5 h; None: the first. A profile set has one
        time per point: ``time`` is not used to select (the renderer takes its own time for the sun).
    cloud_fraction : str
        One of :data:`CLOUD_FRACTION_TREATMENTS`; default ``auto`` (``subcolumns`` with ``cc``).
    subcolumns : int
        Sub-columns per side (1-32); default :data:`DEFAULT_SUBCOLUMNS`.
    seed : int
        Seed of the sub-column generator.
    column_width_m : float
        Width [m] of the patch of a single profile; default :data:`IFS_COLUMN_WIDTH_M`.
    lat, lon, radius_deg : float, optional
        Gridded files: the region to cut, as :func:`read_era5_pressure_levels`; profile set: (lat, lon) picks the
        nearest profile when ``column`` is None.
    source : str, optional
        The ``source`` attribute (default: the path).

    Returns
    -------
    xarray.Dataset
        The validated canonical scene, (z, y, x) = (model levels, lowest first; ...): ``height`` [m] by the
        IFS's hypsometric integration from the surface geopotential
        (:func:`swim.io.ecmwf_levels.model_level_heights`), ``terrain_height``, ``<species>_content`` [kg m-3],
        surface fields where present, ``time`` (profile set: date stamp plus ``step``), attributes as
        :func:`read_era5_pressure_levels` and ``ecmwf_column`` (profile set).

    Raises
    ------
    SwimInputError
        If the temperature, humidity, every hydrometeor, the surface pressure or the surface geopotential is
        missing; ``column`` is out of range; a unit is wrong; the model levels are not contiguous down to the
        lowest; or as :func:`read_era5_pressure_levels`.

    References
    ----------
    ECMWF, L137 model level definitions; IFS Documentation Cy47r3, Part III, Chap. 2 (Eqs. 2.20-2.23);
    Eresmaa, R. and McNally, A. P. (2014), Diverse profile datasets from the ECMWF 137-level short-range
    forecasts, NWP SAF report NWPSAF-EC-TR-017; docs/decisions/0017-cloud-fraction.md.
    """
    ds, label, opened = _open(path_or_dataset, "IFS model-level file", "hybrid")
    source = opened if source is None else str(source)
    if float(column_width_m) <= 0 or not np.isfinite(float(column_width_m)):
        raise SwimInputError(f"column_width_m={column_width_m!r}: expected a positive width [m]")
    if _is_profile_set(ds):
        _check_units(ds, label)
        column = _nearest_point(ds, lat, lon, label) if column is None else column
        prof = _profile_set_column(ds, column, label)
        extra = {"ecmwf_column": int(column)}
    else:
        ds = _select_time(_standardise(ds), time, label)
        _require(ds, ("t", "q", "latitude", "longitude"), label)
        _check_units(ds, label)
        if "level" not in ds.dims:
            raise SwimInputError(f"{label} has no model-level dimension (hybrid, level or model_level); {_HOW_TO}")
        prof, extra = _model_level_profiles(ds, label, (lat, lon, radius_deg)), {}
    attrs = _attrs(label, source, "read_ifs_model_levels", prof["time"], extra)
    return _to_scene(prof, cloud_fraction, subcolumns, seed, column_width_m, attrs, label)


# ---------------------------------------------------------------------------------------------------------------
# recognising ECMWF files


def ecmwf_kind(ds: xr.Dataset):
    """What an open netCDF dataset holds: ``"ifs_model_levels"``, ``"era5_pressure_levels"`` or None.

    The NWP SAF profile-set layout (``temp``, ``hum``, ``paph``, ``psurf`` on ``point``), or ``t``, ``q`` and a
    hydrometeor (``clwc``/``ciwc``/``crwc``/``cswc``) with ``lnsp`` or ``hyai``/``hybi`` or a ``hybrid`` /
    ``model_level`` dimension, are model levels; ``t``, ``q`` and a hydrometeor on ``level`` (units millibars or
    hPa), ``pressure_level`` or ``isobaricInhPa`` are pressure levels.
    """
    names = set(ds.variables)
    if _is_profile_set(ds):
        return "ifs_model_levels"
    if not ({"t", "q"} <= names and any(s[0] in names for s in _SPECIES.values())):
        return None
    if {"lnsp"} & names or {"hyai", "hybi"} <= names or {"hybrid", "model_level"} & set(ds.dims):
        return "ifs_model_levels"
    if {"pressure_level", "isobaricInhPa"} & set(ds.dims):
        return "era5_pressure_levels"
    if "level" in ds.dims and str(ds["level"].attrs.get("units", "")).lower() in ("millibars", "hpa", "mbar", "pa"):
        return "era5_pressure_levels"
    return None


def is_ecmwf_grib(path) -> bool:
    """True when the first GRIB message of ``path`` comes from ECMWF (``centre`` = ``ecmf``, ERA5 and IFS alike)."""
    try:
        import eccodes
    except ImportError:
        return False
    try:
        with open(path, "rb") as f:
            gid = eccodes.codes_grib_new_from_file(f)
            if gid is None:
                return False
            try:
                return str(eccodes.codes_get(gid, "centre")) == "ecmf"
            finally:
                eccodes.codes_release(gid)
    except (OSError, eccodes.CodesInternalError):
        return False


def _grib_kind(path) -> str:
    """``ifs_model_levels`` when the first ECMWF message is on hybrid levels, else ``era5_pressure_levels``."""
    import eccodes

    with open(path, "rb") as f:
        gid = eccodes.codes_grib_new_from_file(f)
        try:
            level = eccodes.codes_get(gid, "typeOfLevel")
        finally:
            eccodes.codes_release(gid)
    return "ifs_model_levels" if level == "hybrid" else "era5_pressure_levels"


def read_ecmwf(path_or_dataset, time=None, cloud_fraction="auto", subcolumns=DEFAULT_SUBCOLUMNS, seed=0, lat=None,
               lon=None, radius_deg=None, column=None, column_width_m=IFS_COLUMN_WIDTH_M, source=None) -> xr.Dataset:
    """Read ECMWF output of either kind with :func:`read_era5_pressure_levels` or :func:`read_ifs_model_levels`.

    The kind comes from :func:`ecmwf_kind` for a netCDF file or dataset, from the level type of the first message
    (``hybrid``: model levels) for GRIB. The options are those of the two readers; ``column`` and
    ``column_width_m`` apply to model levels only.

    Returns
    -------
    xarray.Dataset
        The validated canonical scene.

    Raises
    ------
    SwimInputError
        If the dataset is neither layout; ``column`` is given for pressure levels; or as the reader.
    """
    if not isinstance(path_or_dataset, xr.Dataset) and is_grib_file(path_or_dataset):
        kind = _grib_kind(path_or_dataset)
    else:
        ds, label, opened = _open(path_or_dataset, "ECMWF file", "isobaricInhPa")
        kind = ecmwf_kind(ds)
        if kind is None:
            raise SwimInputError(f"{label} is neither ERA5 pressure-level nor IFS model-level output; {_HOW_TO}")
        source = opened if source is None else source
        path_or_dataset = ds
    options = dict(time=time, cloud_fraction=cloud_fraction, subcolumns=subcolumns, seed=seed, lat=lat, lon=lon,
                   radius_deg=radius_deg, source=source)
    if kind == "ifs_model_levels":
        return read_ifs_model_levels(path_or_dataset, column=column, column_width_m=column_width_m, **options)
    if column is not None:
        raise SwimInputError(f"column={column!r} applies to a set of model-level profiles, not to pressure levels")
    return read_era5_pressure_levels(path_or_dataset, **options)
