"""Reader for ICON output: on its native triangular mesh (regridded to the scene around the camera,
:mod:`swim.io.unstructured`) or remapped to a regular latitude-longitude grid (e.g. ICON-LEM columns, read as they
are).

Formulas (Zaengl et al. 2015, doi:10.1002/qj.2378): ICON's moisture variables are specific contents, mass per kg
of moist air, so content = q x rho with the air density ``rho`` of the output, else from its equation of state
``rho = p / (R_d T_v)``, ``T_v = T (1 + (1/eps - 1) q_v - q_c - q_i - q_r - q_s - q_g)`` (condensate loading).
Heights are the geometric heights of the full levels ``z_mc`` (else the midpoints of the half levels ``z_ifc``);
ICON counts levels from the model top, the scene from the ground. With the two-moment scheme's droplet number
``qnc`` [kg-1] the cloud-liquid effective radius is ``r_e = (3 L / (4 pi rho_w k N))^(1/3)`` with ``L = q_c rho``,
``N = qnc rho`` and the continental ``k = 0.67`` (Martin et al. 1994,
doi:10.1175/1520-0469(1994)051<1823:TMAPOE>2.0.CO;2).
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd
import xarray as xr

from ..constants import DEFAULT_EFFECTIVE_RADIUS, HYDROMETEOR_DENSITY, SPECIES
from ..errors import SwimInputError
from .ecmwf_levels import air_density
from .scene import domain_centre, to_utc_datetime64, validate_scene
from .unstructured import (
    _check_range,
    _clip_negative,
    _open,
    _require,
    _wind,
    mesh_scene,
    select_time,
    unit_vectors,
)

logger = logging.getLogger(__name__)

__all__ = ["read_icon", "is_icon", "icon_air_density", "droplet_effective_radius"]

#: ICON output names of each quantity, first found is used (the CMOR-like names of ICON-LEM/ICON-A output first,
#: then the NWP names).
_NAMES = {
    "cloud_liquid": ("clw", "qc"),
    "cloud_ice": ("cli", "qi"),
    "rain": ("qr",),
    "snow": ("qs",),
    "graupel": ("qg",),
    "temperature": ("ta", "temp"),
    "pressure": ("pres",),
    "humidity": ("hus", "qv"),
    "density": ("rho",),
    "terrain": ("topography_c",),
    "land_fraction": ("fr_land", "FR_LAND"),
    "u10": ("u_10m",),
    "v10": ("v_10m",),
    "droplet_number": ("qnc",),
}
_SPECIES = SPECIES  # the canonical species, in their order
#: Accepted spellings of the units of a specific content.
_SPECIFIC_UNITS = {"kg kg-1", "kg/kg", "kg kg**-1", "kg kg^-1", "1", "", "-"}
#: Martin et al. (1994) ratio (r_v / r_e)^3 of continental clouds.
_K_MARTIN = 0.67
#: Range [m] the droplet effective radius from ``qnc`` is clipped to.
_RADIUS_RANGE_M = (1e-6, 50e-6)


def is_icon(ds: xr.Dataset) -> bool:
    """ICON output: cell centres ``clon``/``clat`` of the triangular mesh, or the ICON geometric heights
    ``z_mc``/``z_ifc`` with an ICON moisture variable (output remapped to a latitude-longitude grid)."""
    names = set(ds.variables)
    if {"clon", "clat"} <= names:
        return True
    moisture = {n for key in _SPECIES for n in _NAMES[key]}
    return bool(names & {"z_mc", "z_ifc"}) and bool(names & moisture)


def icon_air_density(pressure, temperature, humidity=None, condensate=None):
    """Density [kg m-3] of moist air with condensate, ICON's equation of state.

    Parameters
    ----------
    pressure : array_like
        Pressure [Pa].
    temperature : array_like
        Temperature [K].
    humidity : array_like, optional
        Specific humidity q_v [kg kg-1]; None: dry air.
    condensate : array_like, optional
        Total specific condensate q_c + q_i + q_r + q_s + q_g [kg kg-1].

    Returns
    -------
    numpy.ndarray
        ``p / (R_d T (1 + (1/eps - 1) q_v - q_cond))`` [kg m-3], the broadcast shape.

    References
    ----------
    Zaengl et al. (2015), doi:10.1002/qj.2378, Sect. 2; the density temperature of
    :func:`swim.io.ecmwf_levels.air_density`, the same equation of state.
    """
    return air_density(pressure, temperature, 0.0 if humidity is None else humidity,
                       0.0 if condensate is None else condensate)


def droplet_effective_radius(liquid_content, droplet_concentration):
    """Cloud-droplet effective radius [m] from the liquid content and the droplet number.

    Parameters
    ----------
    liquid_content : array_like
        Cloud liquid content L [kg m-3].
    droplet_concentration : array_like
        Droplet number concentration N [m-3].

    Returns
    -------
    numpy.ndarray
        ``(3 L / (4 pi rho_w k N))^(1/3)`` with k = 0.67, clipped to [1, 50] um; the default radius
        (:data:`swim.constants.DEFAULT_EFFECTIVE_RADIUS`) where L > 0 and N is not positive, NaN where L = 0.

    References
    ----------
    Martin et al. (1994), doi:10.1175/1520-0469(1994)051<1823:TMAPOE>2.0.CO;2, Eq. 11.
    """
    lwc = np.asarray(liquid_content, dtype=float)
    n = np.asarray(droplet_concentration, dtype=float)
    rho_w = HYDROMETEOR_DENSITY["cloud_liquid"]
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.cbrt(3.0 * lwc / (4.0 * np.pi * rho_w * _K_MARTIN * n))
    r = np.where(n > 0, np.clip(r, *_RADIUS_RANGE_M), DEFAULT_EFFECTIVE_RADIUS["cloud_liquid"])
    return np.where(lwc > 0, r, np.nan)


def _icon_times(ds: xr.Dataset):
    """The times of the file as datetime64 (nt,), or None: decoded CF times, or ICON's "day as %Y%m%d.%f"."""
    if "time" not in ds.variables:
        return None
    t = ds["time"]
    values = np.atleast_1d(t.values)
    if np.issubdtype(values.dtype, np.datetime64):
        return values.astype("datetime64[ns]")
    units = str(t.attrs.get("units", ""))
    if units.startswith("day as %Y%m%d"):
        out = []
        for v in values.astype(float):
            day = int(np.floor(v))
            stamp = pd.Timestamp(str(day)) + pd.Timedelta(seconds=round((v - day) * 86400.0))
            out.append(to_utc_datetime64(stamp))
        return np.array(out)
    logger.warning("ICON time has units %r, neither decoded nor 'day as %%Y%%m%%d.%%f': the scene has no time", units)
    return None


def _find(ds: xr.Dataset, key: str):
    return next((n for n in _NAMES[key] if n in ds.variables), None)


class _Layout:
    """How the horizontal dims of an ICON file map to cells: the cell dim of ``clon`` (unstructured) or the
    (lat, lon) dims of a remapped file, and the vertical order (ICON's top first)."""

    def __init__(self, ds: xr.Dataset, label: str):
        self.unstructured = "clon" in ds.variables
        if self.unstructured:
            self.horizontal = ds["clon"].dims
        else:
            self.horizontal = tuple(d for d in ("lat", "lon") if d in ds.dims)
            if len(self.horizontal) != 2:
                raise SwimInputError(f"{label}: neither clon/clat (triangular mesh) nor lat/lon dimensions (a "
                                     "latitude-longitude grid) found")
        self.label = label

    def values(self, ds, name, sel, levels=True):
        """``name`` as float64 (nz, ncells) or (ncells,), time selected, horizontal dims flattened."""
        da = ds[name].isel({k: v for k, v in sel.items() if k in ds[name].dims})
        extra = [d for d in da.dims if d not in self.horizontal]
        if len(extra) != (1 if levels else 0):
            raise SwimInputError(f"{self.label}: {name} has dims {da.dims}; expected "
                                 f"{'(level, ' if levels else '('}{', '.join(self.horizontal)})")
        da = da.transpose(*extra, *self.horizontal)
        a = np.asarray(da.values, dtype=float)
        return a.reshape(a.shape[:len(extra)] + (-1,))


def _heights(ds, layout, sel, label):
    """Mass-point heights (nz, ncells) [m], the half levels when present, and the vertical flip (top first)."""
    if "z_mc" in ds.variables:
        height = layout.values(ds, "z_mc", sel)
    elif "z_ifc" in ds.variables:
        zi = layout.values(ds, "z_ifc", sel)
        height = 0.5 * (zi[1:] + zi[:-1])
    else:
        raise SwimInputError(f"{label} lacks z_mc and z_ifc (geometric heights of the full/half levels [m]); they are "
                             "in ICON's vertical-grid (constants) file: pass it as grid=")
    _check_range("z_mc", height, -1000.0, 100_000.0, "m", label)
    half = layout.values(ds, "z_ifc", sel) if "z_ifc" in ds.variables else None
    flip = bool(np.mean(height[0]) > np.mean(height[-1]))
    if flip:
        height = height[::-1]
        half = None if half is None else half[::-1]
    return height, half, flip


def _specific(ds, layout, name, sel, flip, label):
    units = str(ds[name].attrs.get("units", "kg kg-1")).strip()
    if units not in _SPECIFIC_UNITS:
        raise SwimInputError(f"{label}: {name} has units {units!r}; expected a specific content in kg kg-1")
    q = layout.values(ds, name, sel)
    q = q[::-1] if flip else q
    q = _clip_negative(name, q, label)
    _check_range(name, q, 0.0, 0.05, "kg kg-1", label)
    return q


def _density(ds, layout, sel, flip, condensate, label):
    name = _find(ds, "density")
    if name is not None:
        rho = layout.values(ds, name, sel)
        return rho[::-1] if flip else rho
    p_name, t_name = _find(ds, "pressure"), _find(ds, "temperature")
    if p_name is None or t_name is None:
        raise SwimInputError(f"{label} lacks rho, and pres and ta (temp) to compute the air density [kg m-3] that "
                             "turns specific contents into contents")
    p, t = (layout.values(ds, n, sel) for n in (p_name, t_name))
    p, t = (p[::-1], t[::-1]) if flip else (p, t)
    _check_range(p_name, p, 1.0, 1.2e5, "Pa", label)
    _check_range(t_name, t, 150.0, 350.0, "K", label)
    q_name = _find(ds, "humidity")
    if q_name is None:
        logger.warning("%s has no specific humidity (hus/qv): dry-air density (up to ~1.5 %% too high)", label)
        qv = None
    else:
        qv = layout.values(ds, q_name, sel)
        qv = np.clip(qv[::-1] if flip else qv, 0.0, None)
    return icon_air_density(p, t, qv, condensate)


def _icon_fields(ds: xr.Dataset, layout: _Layout, it: int, label: str) -> dict:
    """Canonical fields (cells last) of ICON output at time index ``it``."""
    sel = {"time": it} if "time" in ds.dims else {}
    height, half, flip = _heights(ds, layout, sel, label)
    names = {key: _find(ds, key) for key in _SPECIES}
    if not any(names.values()):
        raise SwimInputError(f"{label} has none of clw (qc), cli (qi), qr, qs, qg (specific contents [kg kg-1])")
    q = {key: _specific(ds, layout, name, sel, flip, label) for key, name in names.items() if name}
    for key, values in q.items():
        if values.shape != height.shape:
            raise SwimInputError(f"{label}: {names[key]} has shape {values.shape}, z_mc {height.shape} "
                                 "(levels x cells)")
    rho = _density(ds, layout, sel, flip, sum(q.values()), label)
    fields = {"height": height}
    fields.update({f"{key}_content": values * rho for key, values in q.items()})
    terrain = _find(ds, "terrain")
    fields["terrain_height"] = (layout.values(ds, terrain, sel, levels=False) if terrain
                                else half[0] if half is not None else height[0])
    number = _find(ds, "droplet_number")
    if number and "cloud_liquid_content" in fields:
        qnc = layout.values(ds, number, sel)
        qnc = np.clip(qnc[::-1] if flip else qnc, 0.0, None)
        fields["cloud_liquid_effective_radius"] = droplet_effective_radius(fields["cloud_liquid_content"], qnc * rho)
    land = _find(ds, "land_fraction")
    if land:
        fields["land_mask"] = (layout.values(ds, land, sel, levels=False) > 0.5).astype(float)
    u, v = _find(ds, "u10"), _find(ds, "v10")
    if u and v:
        fields["wind_speed_10m"] = _wind(layout.values(ds, u, sel, levels=False), layout.values(ds, v, sel, False))
    return fields


def _vertices(ds: xr.Dataset):
    """Corners (ncells, nv, 3) of the triangles from ``clon_bnds``/``clat_bnds`` (or a grid file's
    ``clon_vertices``/``clat_vertices``) [rad]; None if absent."""
    for lon_name, lat_name in (("clon_bnds", "clat_bnds"), ("clon_vertices", "clat_vertices")):
        if {lon_name, lat_name} <= set(ds.variables):
            return unit_vectors(np.rad2deg(ds[lat_name].values), np.rad2deg(ds[lon_name].values))
    return None


def _radians(ds: xr.Dataset, name: str, label: str) -> np.ndarray:
    units = str(ds[name].attrs.get("units", "radian")).lower()
    values = np.asarray(ds[name].values, dtype=float)
    if units.startswith("rad"):
        return np.rad2deg(values)
    if units.startswith("degree"):
        return values
    raise SwimInputError(f"{label}: {name} has units {units!r}; expected radian (or degrees)")


def _latlon_scene(ds, layout, fields, lat, lon, time, attrs):
    """The scene of an ICON file on a latitude-longitude grid: its columns as they are, south to north."""
    lats, lons = np.asarray(ds["lat"].values, dtype=float), np.asarray(ds["lon"].values, dtype=float)
    ny, nx = lats.size, lons.size
    rows, cols = np.argsort(lats), np.argsort(lons)
    lat2, lon2 = np.meshgrid(lats[rows], lons[cols], indexing="ij")

    def grid(a):
        a = a.reshape(a.shape[:-1] + (ny, nx))
        return a[..., rows, :][..., cols]

    data = {name: xr.DataArray(grid(a), dims=("z", "y", "x") if a.ndim == 2 else ("y", "x"))
            for name, a in fields.items() if not (name.endswith("_content") and not np.any(a > 0))}
    for name in [n for n in data if n.endswith("_effective_radius")]:
        if name.replace("_effective_radius", "_content") not in data:
            data.pop(name)
    if "land_mask" in data:
        data["land_mask"] = data["land_mask"].astype(np.int8)
    data["lat"] = xr.DataArray(lat2, dims=("y", "x"), attrs={"units": "degrees_north"})
    data["lon"] = xr.DataArray(lon2, dims=("y", "x"), attrs={"units": "degrees_east"})
    lat0, lon0 = (float(lat), float(lon)) if lat is not None and lon is not None else domain_centre(lat2, lon2)
    attrs.update(reference_lat=lat0, reference_lon=(lon0 + 180.0) % 360.0 - 180.0)
    coords = {} if time is None else {"time": xr.DataArray(time)}
    return validate_scene(xr.Dataset(data, coords=coords, attrs=attrs))


def _cell_dim(ds: xr.Dataset):
    if "clon" in ds.variables:
        return ds["clon"].dims[0]
    return next((d for d in ("ncells", "cell") if d in ds.dims), None)


def _merge_grid(ds: xr.Dataset, grid, label: str) -> xr.Dataset:
    """``ds`` completed by the variables of an ICON grid or vertical-grid file that it lacks, on its cell dim."""
    extra, grid_label, _ = _open(grid, "ICON grid file")
    mine, theirs = _cell_dim(ds), _cell_dim(extra)
    if mine is not None and theirs is not None and mine != theirs:
        if extra.sizes[theirs] != ds.sizes[mine]:
            raise SwimInputError(f"{grid_label} has {extra.sizes[theirs]} cells, {label} {ds.sizes[mine]}: expected "
                                 "the grid of the data file")
        extra = extra.rename({theirs: mine})
    names = [n for n in extra.variables if n not in ds.variables and n not in extra.dims]
    return ds.merge(extra[names], compat="override")


def read_icon(path_or_dataset, lat=None, lon=None, radius_deg=None, time=None, method: str = "conservative",
              spacing_km=None, grid=None) -> xr.Dataset:
    """Read ICON output (netCDF) into a canonical scene.

    Parameters
    ----------
    path_or_dataset : str, os.PathLike or xarray.Dataset
        The file. Variables used (first name found; dims (time,) level, cells or (time,) level, lat, lon):

        * mesh: ``clon``, ``clat`` [radian] (ncells), and ``clon_bnds``/``clat_bnds`` (ncells, 3) [radian], the
          triangles' corners, when present; or 1-D ``lat``/``lon`` [deg] dims of output remapped to a regular grid;
        * heights: ``z_mc`` (height, ncells) full levels [m], else ``z_ifc`` (height_2, ncells) half levels [m];
          ``topography_c`` [m] (else the lowest half level);
        * ``clw``/``qc``, ``cli``/``qi``, ``qr``, ``qs``, ``qg``: specific contents [kg kg-1], any present, at
          least one;
        * ``rho`` [kg m-3], else ``pres`` [Pa], ``ta``/``temp`` [K] and ``hus``/``qv`` [kg kg-1];
        * optional: ``qnc`` droplet number [kg-1] (the cloud-liquid effective radius), ``fr_land``/``FR_LAND``
          (land where > 0.5), ``u_10m``/``v_10m`` [m s-1], ``time`` (CF, or ICON's "day as %Y%m%d.%f").

        ``clc`` (cloud cover) is not used: the contents are grid-box means.
    lat, lon : float, optional
        The camera's place [deg]: centre and reference point of the scene (give it for a global mesh); default
        the centre of the cells.
    radius_deg, spacing_km, method
        Triangular mesh only: as :func:`swim.io.unstructured.mesh_scene` (default 15 deg, the mesh's cell size,
        ``"conservative"``). A file on a lat-lon grid keeps its columns.
    time : None, int, str or datetime, optional
        Time to read: None the first, an int an index along ``time``, else the nearest within 1.5 h.
    grid : str, os.PathLike or xarray.Dataset, optional
        A second file (ICON grid or vertical-grid/constants file) whose variables complete the first (e.g.
        ``clon``/``clat``/``clon_bnds`` or ``z_mc``/``z_ifc``/``topography_c``); its cell dim must match.

    Returns
    -------
    xarray.Dataset
        The validated canonical scene: (z, y, x) with z from the ground up; contents ``q x rho`` [kg m-3]; for a
        mesh a regular grid in the scene frame with ``x``/``y`` coordinates; for a lat-lon file the file's columns
        with 2-D ``lat``/``lon``.

    Raises
    ------
    SwimInputError
        If a needed variable is missing (named, with its units), a unit or value is out of range, the camera lies
        outside a regional mesh, or as :func:`swim.io.unstructured.mesh_scene`.

    References
    ----------
    Zaengl et al. (2015), doi:10.1002/qj.2378 (ICON); Martin et al. (1994),
    doi:10.1175/1520-0469(1994)051<1823:TMAPOE>2.0.CO;2 (effective radius).
    """
    ds, label, source = _open(path_or_dataset, "ICON file")
    if grid is not None:
        ds = _merge_grid(ds, grid, label)
    layout = _Layout(ds, label)
    times = _icon_times(ds)
    it = select_time(times, time, label)
    fields = _icon_fields(ds, layout, it, label)
    when = None if times is None else times[it]
    title = str(ds.attrs.get("title", "")).strip()
    attrs = {"title": title if "ICON" in title.upper() else f"ICON {title}".strip(),
             "source": f"{source} read by swim.io.icon.read_icon"}
    if not layout.unstructured:
        return _latlon_scene(ds, layout, fields, lat, lon, when, attrs)
    _require(ds, ["clat"], label, "cell-centre latitude [radian]")
    cell_lat, cell_lon = _radians(ds, "clat", label), _radians(ds, "clon", label)
    return mesh_scene(cell_lat, cell_lon, fields, lat=lat, lon=lon, radius_deg=radius_deg, spacing_km=spacing_km,
                      method=method, vertices=_vertices(ds), time=when, attrs=attrs, label=label)
