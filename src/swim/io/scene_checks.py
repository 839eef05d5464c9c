"""The checks of a canonical scene, one group of variables at a time, and the format rules they enforce.

:func:`swim.io.scene.validate_scene` calls the checks in order. Each refuses what the format does not allow with a
:class:`~swim.errors.SwimInputError` that names the variable and the expected units, and returns float64 copies
in canonical order with canonical attributes. The names, units and plausible ranges of the variables are defined
here (``docs/scene-format.md``); :mod:`swim.io.scene` imports them from this module and exports them.
"""

from __future__ import annotations

import logging

import numpy as np
import xarray as xr

from ..constants import DEFAULT_EFFECTIVE_RADIUS, EARTH_RADIUS_M, SPECIES, WAVELENGTHS_NM
from ..errors import SwimInputError
from ..frames import orthographic_xy
from ..workers import in_blocks
from .quantities import dequantified

# The checks run as part of validate_scene: they log under its module's name, where users look for them.
logger = logging.getLogger("swim.io.scene")

#: Names of the mass-content variables [kg m-3], in the order of :data:`swim.constants.SPECIES`.
CONTENT_VARIABLES = tuple(f"{s}_content" for s in SPECIES)
#: Names of the optional effective-radius variables [m].
RADIUS_VARIABLES = tuple(f"{s}_effective_radius" for s in SPECIES)
#: Largest plausible hydrometeor mass content [kg m-3] (50 g m-3); larger values mean wrong units.
MAX_CONTENT_KG_M3 = 0.05
#: Negative contents down to minus this value [kg m-3] are numerical noise and are clipped to 0.
NEGATIVE_NOISE_KG_M3 = 1e-12
#: Plausible range of an effective radius where there is content [m].
RADIUS_RANGE_M = (1e-7, 0.1)
#: Largest plausible smoke mass concentration [kg m-3]: 10 000 ug m-3, beyond the densest plumes measured near fires.
MAX_SMOKE_KG_M3 = 1e-5
#: Largest plausible aerosol extinction at 550 nm [m-1] (visibility ~ 80 m); larger values mean wrong units.
MAX_AEROSOL_EXTINCTION_M1 = 0.05
#: Plausible range of terrain height [m].
TERRAIN_RANGE_M = (-500.0, 9000.0)
#: Plausible range of the 10 m wind speed [m s-1] (the strongest measured gusts are about 113 m s-1, but a
#: grid-cell mean 10 m wind above 75 m s-1 means wrong units).
WIND_SPEED_RANGE_M_S = (0.0, 75.0)
#: 10 m wind speed [m s-1] the renderer assumes where the scene has no ``wind_speed_10m``.
DEFAULT_WIND_SPEED_M_S = 5.0

_LONG_NAMES = {
    "height": "height above sea level of the mass points",
    "lat": "latitude",
    "lon": "longitude",
    "terrain_height": "terrain height above sea level",
    "cloud_liquid_content": "cloud liquid water mass content",
    "cloud_ice_content": "cloud ice mass content",
    "rain_content": "rain mass content",
    "snow_content": "snow mass content",
    "graupel_content": "graupel mass content",
    "cloud_liquid_effective_radius": "cloud liquid effective radius",
    "cloud_ice_effective_radius": "cloud ice effective radius",
    "rain_effective_radius": "rain effective radius",
    "snow_effective_radius": "snow effective radius",
    "graupel_effective_radius": "graupel effective radius",
    "aerosol_extinction": "aerosol extinction coefficient at 550 nm",
    "smoke_mass_content": "smoke (biomass-burning aerosol) mass concentration",
    "surface_albedo": "surface spectral albedo",
    "land_mask": "land mask (1 land, 0 water)",
    "snow_cover": "fraction of the surface covered by snow or ice",
    "wind_speed_10m": "wind speed at 10 m above the surface",
    "upward_light_emission": "upward luminous exitance of the artificial light (city lights)",
    "x": "grid x (east) of the column in the scene frame",
    "y": "grid y (north) of the column in the scene frame",
    "wavelength": "wavelength",
    "time": "valid time (UTC)",
}

_UNITS = {
    "height": "m",
    "lat": "degrees_north",
    "lon": "degrees_east",
    "terrain_height": "m",
    "aerosol_extinction": "m-1",
    "smoke_mass_content": "kg m-3",
    "surface_albedo": "1",
    "land_mask": "1",
    "snow_cover": "1",
    "wind_speed_10m": "m s-1",
    "upward_light_emission": "lm m-2",
    "x": "m",
    "y": "m",
    "wavelength": "nm",
    **{name: "kg m-3" for name in CONTENT_VARIABLES},
    **{name: "m" for name in RADIUS_VARIABLES},
}

_3D = ("z", "y", "x")
_2D = ("y", "x")
_CANONICAL_VARIABLES = (
    ("height", "lat", "lon", "terrain_height")
    + CONTENT_VARIABLES
    + RADIUS_VARIABLES
    + ("aerosol_extinction", "smoke_mass_content", "surface_albedo", "land_mask", "snow_cover", "wind_speed_10m",
       "upward_light_emission")
)

# ---------------------------------------------------------------------------------------------------------------
# units


def _normalise_units(units) -> str:
    """``units`` lower-cased, without spaces, dots, stars and carets, with ``u`` for micro."""
    s = str(units).strip().lower()
    for old, new in (("**", ""), ("^", ""), (" ", ""), (".", ""), ("·", ""), ("*", ""), ("μ", "u"), ("µ", "u")):
        s = s.replace(old, new)
    return s


_ACCEPTED_UNITS = {
    "kg m-3": {"kgm-3", "kg/m3"},
    "m": {"m", "meter", "meters", "metre", "metres"},
    "m-1": {"m-1", "1/m", "/m"},
    "degrees_north": {"degrees_north", "degree_north", "degrees_n", "degree_n", "degreesnorth", "degrees", "degree",
                      "deg", "°n", "°"},
    "degrees_east": {"degrees_east", "degree_east", "degrees_e", "degree_e", "degreeseast", "degrees", "degree", "deg",
                     "°e", "°"},
    "1": {"1", "", "-", "fraction", "dimensionless", "none", "0-1"},
    "nm": {"nm", "nanometer", "nanometers", "nanometre", "nanometres"},
    "m s-1": {"ms-1", "m/s", "mps"},
    "lm m-2": {"lmm-2", "lm/m2", "lux", "lx"},
}

_UNIT_HINTS = {
    "gm-3": "g m-3: multiply by 1e-3",
    "g/m3": "g m-3: multiply by 1e-3",
    "kgkg-1": "a mixing ratio: multiply by the air density",
    "kg/kg": "a mixing ratio: multiply by the air density",
    "gkg-1": "a mixing ratio in g kg-1: multiply by 1e-3 and by the air density",
    "g/kg": "a mixing ratio in g kg-1: multiply by 1e-3 and by the air density",
    "um": "micrometres: multiply by 1e-6",
    "micron": "micrometres: multiply by 1e-6",
    "microns": "micrometres: multiply by 1e-6",
    "micrometer": "micrometres: multiply by 1e-6",
    "micrometre": "micrometres: multiply by 1e-6",
    "km": "kilometres: multiply by 1e3",
    "km-1": "per kilometre: multiply by 1e-3",
    "1/km": "per kilometre: multiply by 1e-3",
    "%": "percent: divide by 100",
    "percent": "percent: divide by 100",
    "kmh-1": "km h-1: divide by 3.6",
    "km/h": "km h-1: divide by 3.6",
    "kt": "knots: multiply by 0.514444",
    "kts": "knots: multiply by 0.514444",
    "knot": "knots: multiply by 0.514444",
    "knots": "knots: multiply by 0.514444",
}


def _check_units(name: str, da: xr.DataArray) -> None:
    """Raise if ``da.attrs['units']`` is present and not a spelling of the canonical unit of ``name``."""
    expected = _UNITS[name]
    if "units" not in da.attrs:
        return
    got = _normalise_units(da.attrs["units"])
    if got in _ACCEPTED_UNITS[expected]:
        return
    hint = _UNIT_HINTS.get(got)
    hint = f" ('{da.attrs['units']}' looks like {hint})" if hint else ""
    raise SwimInputError(
        f"scene variable '{name}' has units '{da.attrs['units']}' but must be in {expected}{hint}; convert it and set "
        f"units='{expected}'"
    )


# ---------------------------------------------------------------------------------------------------------------
# helpers of the checks


def require_real_numbers(label: str, dtype) -> None:
    """Refuse a field ``label`` of values that are not real numbers (float, integer or bool ``dtype``): a complex
    field would lose its imaginary part, text or objects would fail deep inside.

    Raises
    ------
    SwimInputError
        Naming ``label`` and the dtype.
    """
    if not (np.issubdtype(dtype, np.floating) or np.issubdtype(dtype, np.integer) or np.issubdtype(dtype, np.bool_)):
        raise SwimInputError(f"{label} holds {dtype} values; expected real numbers")


def _as_dataarray(name: str, ds: xr.Dataset) -> xr.DataArray:
    """The variable ``name`` of ``ds`` without its coordinates, refused unless it holds real numbers."""
    da = ds[name].reset_coords(drop=True)
    require_real_numbers(f"scene variable '{name}'", da.dtype)
    return da


def _check_dims(name: str, da: xr.DataArray, dims: tuple[str, ...]) -> xr.DataArray:
    """``da`` transposed to ``dims``, refused if it has other dimensions."""
    if set(da.dims) != set(dims) or len(da.dims) != len(dims):
        raise SwimInputError(f"scene variable '{name}' has dims {tuple(da.dims)}; expected {dims}")
    return da.transpose(*dims)


def _finite_or_raise(name: str, values: np.ndarray, not_finite: int | None = None) -> None:
    """Raise if ``values`` holds NaN or inf (``not_finite``: their count, where a scan has counted them)."""
    if not_finite is None:
        not_finite = int(np.count_nonzero(~np.isfinite(values)))
    if not_finite:
        raise SwimInputError(
            f"scene variable '{name}' has {int(not_finite)} non-finite value(s) (NaN or inf) out of {values.size}; "
            f"every value must be finite ({_UNITS.get(name, '')})"
        )


def _copied_and_scanned(values) -> tuple[np.ndarray, dict]:
    """A float64 copy of a 3-D array (level, y, x) and its statistics: ``not finite`` and ``negative`` (counts),
    ``min`` and ``max`` (of the finite values), from one compiled pass in blocks of levels on every core
    (:func:`swim.io.scan_cpu.copy_and_scan`; numba is imported at the first scan, not with :mod:`swim`)."""
    from .scan_cpu import STATS, copy_and_scan

    source = np.asarray(values)
    if source.dtype not in (np.float32, np.float64):  # one compiled version per dtype: the others converted first
        source = source.astype(np.float64)
    copy = np.empty(source.shape, np.float64)
    blocks = []

    def scan(k0, k1):
        stats = np.zeros(len(STATS))
        copy_and_scan(source, copy, k0, k1, stats)
        blocks.append(stats)

    in_blocks(scan, source.shape[0])
    stats = np.array(blocks).reshape(-1, len(STATS))
    return copy, {"not finite": int(stats[:, 0].sum()), "negative": int(stats[:, 1].sum()),
                  "min": float(stats[:, 2].min(initial=np.inf)), "max": float(stats[:, 3].max(initial=-np.inf))}


def _new_attrs(name: str, old: dict) -> dict:
    """The attributes ``old`` with the canonical ``units`` of ``name``, a ``long_name`` and no encoding keys."""
    attrs = {k: v for k, v in old.items()
             if k not in ("units", "long_name", "_FillValue", "missing_value", "coordinates")}
    attrs["units"] = _UNITS[name]
    attrs["long_name"] = str(old.get("long_name", _LONG_NAMES[name]))
    return attrs


def _clip_noise(name: str, values: np.ndarray, negative: int | None = None) -> np.ndarray:
    """Raise on negative values below -1e-12, clip the numerical noise in [-1e-12, 0) to 0 (logged). ``negative``:
    the count of negative values, where a scan has counted them."""
    if negative == 0:
        return values
    neg = values < 0
    if not neg.any():
        return values
    vmin = float(values.min())
    if vmin < -NEGATIVE_NOISE_KG_M3:
        raise SwimInputError(
            f"scene variable '{name}' has {int((values < -NEGATIVE_NOISE_KG_M3).sum())} negative value(s) (min "
            f"{vmin:.3g}); it must be >= 0 ({_UNITS[name]}); values down to -{NEGATIVE_NOISE_KG_M3:g} are clipped as "
            "numerical noise"
        )
    logger.info("%s: clipped %d negative value(s) >= %.1e (min %.3g) to 0", name, int(neg.sum()), -NEGATIVE_NOISE_KG_M3,
                vmin)
    return np.where(neg, 0.0, values)


# ---------------------------------------------------------------------------------------------------------------
# checks of the variable groups, in the order validate_scene calls them


def _check_dataset(ds) -> xr.Dataset:
    """Check that ``ds`` is a dataset with the required variables; squeeze a time dimension of length 1 and log the
    variables that will be dropped."""
    if not isinstance(ds, xr.Dataset):
        raise SwimInputError(f"scene must be an xarray.Dataset; got {type(ds).__name__}")
    ds = dequantified(ds, _UNITS, "scene")
    if "time" in ds.dims and ds.sizes["time"] == 1:
        ds = ds.squeeze("time")
    missing = [name for name in ("height", "lat", "lon", "terrain_height") if name not in ds.variables]
    if missing:
        raise SwimInputError(
            f"scene lacks required variable(s) {missing}: needs height(z,y,x) [m above sea level], lat(y,x) "
            "[degrees_north], lon(y,x) [degrees_east] and terrain_height(y,x) [m]"
        )
    unknown = [str(n) for n in ds.data_vars if n not in _CANONICAL_VARIABLES]
    unknown += [str(n) for n in ds.coords if n not in _CANONICAL_VARIABLES + ("x", "y", "z", "wavelength", "time")]
    if unknown:
        logger.warning("validate_scene: dropping variable(s) that are not part of the canonical scene: %s", unknown)
    return ds


def _check_height(ds: xr.Dataset) -> tuple[xr.DataArray, np.ndarray]:
    """Check ``height`` [m above sea level]: a non-empty (z, y, x) grid of finite metres, increasing with z.

    Returns
    -------
    height : xarray.DataArray
        The canonical variable.
    values : numpy.ndarray
        Its float64 values, shape (nz, ny, nx).
    """
    height_da = _check_dims("height", _as_dataarray("height", ds), _3D)
    _check_units("height", height_da)
    nz, ny, nx = height_da.shape
    if min(nz, ny, nx) < 1:
        raise SwimInputError(f"scene grid is empty: (z, y, x) = {(nz, ny, nx)}")
    height, stats = _copied_and_scanned(height_da.values)
    _finite_or_raise("height", height, stats["not finite"])
    if stats["max"] > 100_000.0:
        raise SwimInputError(f"height: max {stats['max']:.4g} m is above 100 km; expected metres above sea level")
    if stats["max"] <= 25.0:
        raise SwimInputError(
            f"height: max {stats['max']:.4g} m; a scene only 25 m deep is implausible: expected metres above sea "
            "level, not km"
        )
    if nz > 1:
        _check_height_increases(height)
    return xr.DataArray(height, dims=_3D, attrs=_new_attrs("height", height_da.attrs)), height


def _check_height_increases(height: np.ndarray) -> None:
    """Refuse a (z, y, x) ``height`` that does not increase strictly with z in every column."""
    from .scan_cpu import flag_non_increasing

    nz, ny, nx = height.shape
    bad_cols = np.zeros((ny, nx), bool)
    in_blocks(lambda j0, j1: flag_non_increasing(height, j0, j1, bad_cols), ny)
    if bad_cols.any():
        raise SwimInputError(
            f"height must increase strictly with z in every column; {int(bad_cols.sum())} of {ny * nx} column(s) "
            "do not (is the z axis upside down, or is it pressure?)"
        )


def _horizontal(ds: xr.Dataset, name: str, shape: tuple[int, int]) -> tuple[xr.DataArray, np.ndarray]:
    """The (y, x) variable ``name`` of ``ds``, checked for dims, ``shape`` (ny, nx), units and finite values, and a
    float64 copy of its values."""
    da = _check_dims(name, _as_dataarray(name, ds), _2D)
    if da.shape != shape:
        raise SwimInputError(f"scene variable '{name}' has shape {da.shape}; expected (y, x) = {shape}")
    _check_units(name, da)
    values = np.array(da.values, dtype=float)
    _finite_or_raise(name, values)
    return da, values


def _volume(ds: xr.Dataset, name: str, shape: tuple[int, int, int]) -> tuple[xr.DataArray, np.ndarray, dict]:
    """The (z, y, x) variable ``name`` of ``ds``, checked for dims, ``shape`` (nz, ny, nx) and units, with a float64
    copy of its values and their statistics (:func:`_copied_and_scanned`)."""
    da = _check_dims(name, _as_dataarray(name, ds), _3D)
    if da.shape != shape:
        raise SwimInputError(f"scene variable '{name}' has shape {da.shape}; expected (z, y, x) = {shape}")
    _check_units(name, da)
    return (da,) + _copied_and_scanned(da.values)


def _check_lat_lon(ds: xr.Dataset, shape: tuple[int, int]) -> tuple[xr.DataArray, xr.DataArray]:
    """Check ``lat`` in [-90, 90] and ``lon`` in [-360, 360] degrees; the returned ``lon`` is wrapped to
    [-180, 180)."""
    lat_da, lat = _horizontal(ds, "lat", shape)
    lon_da, lon = _horizontal(ds, "lon", shape)
    if lat.min() < -90.0 or lat.max() > 90.0:
        raise SwimInputError(f"lat: range [{lat.min():.4g}, {lat.max():.4g}] is outside [-90, 90] degrees_north")
    if lon.min() < -360.0 or lon.max() > 360.0:
        raise SwimInputError(f"lon: range [{lon.min():.4g}, {lon.max():.4g}] is outside [-360, 360] degrees_east")
    lon = (lon + 180.0) % 360.0 - 180.0
    return (xr.DataArray(lat, dims=_2D, attrs=_new_attrs("lat", lat_da.attrs)),
            xr.DataArray(lon, dims=_2D, attrs=_new_attrs("lon", lon_da.attrs)))


def _check_terrain(ds: xr.Dataset, shape: tuple[int, int]) -> xr.DataArray:
    """Check ``terrain_height`` [m above sea level] within :data:`TERRAIN_RANGE_M`."""
    terrain_da, terrain = _horizontal(ds, "terrain_height", shape)
    if terrain.min() < TERRAIN_RANGE_M[0] or terrain.max() > TERRAIN_RANGE_M[1]:
        raise SwimInputError(
            f"terrain_height: range [{terrain.min():.4g}, {terrain.max():.4g}] m is outside "
            f"[{TERRAIN_RANGE_M[0]:g}, {TERRAIN_RANGE_M[1]:g}] m above sea level"
        )
    return xr.DataArray(terrain, dims=_2D, attrs=_new_attrs("terrain_height", terrain_da.attrs))


def _check_contents(ds: xr.Dataset, shape: tuple[int, int, int]) -> tuple[dict, dict]:
    """Check the hydrometeor mass contents [kg m-3] present in ``ds``: finite, not negative beyond numerical noise
    (which is clipped to 0), at most :data:`MAX_CONTENT_KG_M3`.

    Returns
    -------
    variables : dict of xarray.DataArray
        The canonical ``<species>_content`` variables.
    contents : dict of numpy.ndarray
        Their values by species.
    """
    variables: dict[str, xr.DataArray] = {}
    contents: dict[str, np.ndarray] = {}
    for species, name in zip(SPECIES, CONTENT_VARIABLES):
        if name not in ds.variables:
            continue
        da, values, stats = _volume(ds, name, shape)
        _finite_or_raise(name, values, stats["not finite"])
        values = _clip_noise(name, values, stats["negative"])
        vmax = max(stats["max"], 0.0) if stats["negative"] else stats["max"]  # the noise clipped to 0
        if vmax > MAX_CONTENT_KG_M3:
            raise SwimInputError(
                f"{name}: max {vmax:.4g} kg m-3 exceeds {MAX_CONTENT_KG_M3:g} kg m-3 ({MAX_CONTENT_KG_M3 * 1e3:g} "
                "g m-3), which is impossible for a cloud; the values are most likely in g m-3 or g kg-1 (or a mixing "
                "ratio) given as kg m-3. Expected kg m-3"
            )
        contents[species] = values
        variables[name] = xr.DataArray(values, dims=_3D, attrs=_new_attrs(name, da.attrs))
    return variables, contents


def _warn_wet_below_terrain(height: np.ndarray, terrain: np.ndarray, contents: dict) -> None:
    """Log the cells below the terrain that hold hydrometeors: the renderer never sees them."""
    below = height < terrain[None]
    if below.any():
        wet_below = sum(int(np.count_nonzero(c[below] > 0)) for c in contents.values())
        if wet_below:
            logger.warning("validate_scene: %d cell(s) below the terrain hold hydrometeors (they are hidden)",
                           wet_below)


def _check_radii(ds: xr.Dataset, shape: tuple[int, int, int], contents: dict) -> dict:
    """Check the effective radii [m] present in ``ds``: each needs its content and must lie in
    :data:`RADIUS_RANGE_M` where that is positive; elsewhere the species default is filled in.

    Returns
    -------
    dict of xarray.DataArray
        The canonical ``<species>_effective_radius`` variables.
    """
    variables: dict[str, xr.DataArray] = {}
    for species, name in zip(SPECIES, RADIUS_VARIABLES):
        if name not in ds.variables:
            continue
        if species not in contents:
            raise SwimInputError(f"scene has '{name}' but no '{species}_content'; give both or drop the radius")
        da, values, _ = _volume(ds, name, shape)
        cloudy = contents[species] > 0
        r = values[cloudy]
        bad = ~np.isfinite(r) | (r < RADIUS_RANGE_M[0]) | (r > RADIUS_RANGE_M[1])
        if bad.any():
            finite = r[np.isfinite(r)]
            rng = f"[{finite.min():.3g}, {finite.max():.3g}]" if finite.size else "[no finite value]"
            raise SwimInputError(
                f"{name}: {int(bad.sum())} value(s) where {species}_content > 0 are non-finite or outside "
                f"[{RADIUS_RANGE_M[0]:g}, {RADIUS_RANGE_M[1]:g}] m (range {rng}); expected metres (micrometres "
                "must be multiplied by 1e-6)"
            )
        values = np.where(cloudy, values, DEFAULT_EFFECTIVE_RADIUS[species])
        variables[name] = xr.DataArray(values, dims=_3D, attrs=_new_attrs(name, da.attrs))
    return variables


def _check_aerosol(ds: xr.Dataset, shape: tuple[int, int, int]) -> xr.DataArray:
    """Check ``aerosol_extinction`` [m-1 at 550 nm]: finite, not negative beyond numerical noise (clipped to 0), at
    most :data:`MAX_AEROSOL_EXTINCTION_M1`."""
    return _bounded_volume(ds, "aerosol_extinction", shape, MAX_AEROSOL_EXTINCTION_M1, "m-1",
                           "(visibility < 80 m); expected m-1 at 550 nm (km-1 must be multiplied by 1e-3)")


def _check_smoke(ds: xr.Dataset, shape: tuple[int, int, int]) -> xr.DataArray:
    """Check ``smoke_mass_content`` [kg m-3]: finite, not negative beyond numerical noise (clipped to 0), at most
    :data:`MAX_SMOKE_KG_M3`."""
    return _bounded_volume(ds, "smoke_mass_content", shape, MAX_SMOKE_KG_M3, "kg m-3",
                           "(10 000 ug m-3); expected kg m-3 (ug m-3 must be multiplied by 1e-9)")


def _bounded_volume(ds, name, shape, maximum, units, why) -> xr.DataArray:
    """The canonical (z, y, x) variable ``name``: finite, noise below 0 clipped, at most ``maximum`` [``units``]
    (else an error that says ``why``)."""
    da, values, stats = _volume(ds, name, shape)
    _finite_or_raise(name, values, stats["not finite"])
    values = _clip_noise(name, values, stats["negative"])
    if stats["max"] > maximum:
        raise SwimInputError(f"{name}: max {stats['max']:.4g} {units} exceeds {maximum:g} {units} {why}")
    return xr.DataArray(values, dims=_3D, attrs=_new_attrs(name, da.attrs))


def _check_surface(ds: xr.Dataset, shape: tuple[int, int]) -> tuple[dict, dict]:
    """Check the surface variables present in ``ds``: albedo, land mask, snow cover and 10 m wind speed.

    Returns
    -------
    variables : dict of xarray.DataArray
        The canonical surface variables.
    coords : dict of xarray.DataArray
        ``wavelength`` where there is an albedo.
    """
    variables: dict[str, xr.DataArray] = {}
    coords: dict[str, xr.DataArray] = {}
    if "surface_albedo" in ds.variables:
        variables["surface_albedo"], coords["wavelength"] = _validate_albedo(
            _as_dataarray("surface_albedo", ds), ds, *shape
        )
    for name, check in (("land_mask", _check_land_mask), ("snow_cover", _check_snow_cover),
                        ("wind_speed_10m", _check_wind_speed), ("upward_light_emission", _check_light_emission)):
        if name in ds.variables:
            variables[name] = check(*_horizontal(ds, name, shape))
    return variables, coords


def _check_land_mask(da: xr.DataArray, values: np.ndarray) -> xr.DataArray:
    """Check ``land_mask``: 1 (land) or 0 (water); stored as int8."""
    if not np.all((values == 0) | (values == 1)):
        raise SwimInputError(
            f"land_mask: values must be 1 (land) or 0 (water); got values in [{values.min():.3g}, {values.max():.3g}]"
        )
    return xr.DataArray(values.astype(np.int8), dims=_2D, attrs=_new_attrs("land_mask", da.attrs))


def _check_snow_cover(da: xr.DataArray, values: np.ndarray) -> xr.DataArray:
    """Check ``snow_cover``: a fraction in [0, 1]."""
    if values.min() < 0.0 or values.max() > 1.0:
        hint = " (percent must be divided by 100)" if values.max() <= 100.0 and values.min() >= 0.0 else ""
        raise SwimInputError(
            f"snow_cover: range [{values.min():.4g}, {values.max():.4g}] is outside [0, 1]; expected the fraction "
            f"of the surface covered by snow or ice (units 1){hint}"
        )
    return xr.DataArray(values, dims=_2D, attrs=_new_attrs("snow_cover", da.attrs))


def _check_light_emission(da: xr.DataArray, values: np.ndarray) -> xr.DataArray:
    """Check ``upward_light_emission`` [lm m-2]: >= 0 and plausible (:func:`swim.surface.city_lights.check_emission`);
    its ``lamp_spectrum`` attribute is kept."""
    from ..surface.city_lights import check_emission

    return xr.DataArray(check_emission(values), dims=_2D, attrs=_new_attrs("upward_light_emission", da.attrs))


def _check_wind_speed(da: xr.DataArray, values: np.ndarray) -> xr.DataArray:
    """Check ``wind_speed_10m`` [m s-1] within :data:`WIND_SPEED_RANGE_M_S`."""
    lo, hi = WIND_SPEED_RANGE_M_S
    if values.min() < lo:
        raise SwimInputError(
            f"wind_speed_10m: {int((values < lo).sum())} negative value(s) (min {values.min():.4g}); expected the "
            f"10 m wind speed in [{lo:g}, {hi:g}] m s-1 (a speed sqrt(u10^2 + v10^2), not a wind component)"
        )
    if values.max() > hi:
        raise SwimInputError(
            f"wind_speed_10m: max {values.max():.4g} exceeds {hi:g} m s-1; expected m s-1 in [{lo:g}, {hi:g}] "
            "(km h-1 must be divided by 3.6, knots multiplied by 0.514444)"
        )
    return xr.DataArray(values, dims=_2D, attrs=_new_attrs("wind_speed_10m", da.attrs))


def _check_xy(ds: xr.Dataset, lat: np.ndarray, lon: np.ndarray, reference_lat: float, reference_lon: float) -> dict:
    """Check the optional 1-D coordinates ``x``, ``y`` [m] against the orthographic projection of ``lat``/``lon``
    about the reference point; a coordinate on other dims is dropped (logged).

    Where both are present, the columns with ``x^2 + y^2 >= R^2`` (beyond the limb of the sea-level sphere seen from
    above the reference point, :func:`_beyond_limb`) have no orthographic lat/lon: they are not compared (their
    ``lat``/``lon`` are whatever the scene's maker put there), and ``x`` and ``y`` must then increase strictly (their
    positions rest on them alone). Every other column is compared.

    Returns
    -------
    dict of xarray.DataArray
        The canonical ``x`` and ``y`` that ``ds`` has.

    Raises
    ------
    SwimInputError
        Where a column on or inside the limb is further than max(1 m, 1 % of the spacing) from
        ``orthographic_xy(lat, lon)``, or where columns beyond the limb come with ``x`` or ``y`` not strictly
        increasing.
    """
    coords: dict[str, xr.DataArray] = {}
    given = {}
    for axis in ("x", "y"):
        if axis in ds.coords:
            c = ds.coords[axis]
            if c.dims != (axis,):
                logger.warning("validate_scene: dropping coordinate '%s' with dims %s (expected (%s,))", axis, c.dims,
                               axis)
                continue
            _check_units(axis, c)
            given[axis] = (np.array(c.values, dtype=float), c.attrs)
    if not given:
        return coords
    beyond = _beyond_limb(given, lat.shape)
    gx, gy = orthographic_xy(lat, lon, reference_lat, reference_lon)
    for axis, (values, attrs) in given.items():
        spacing = float(np.median(np.abs(np.diff(values)))) if values.size > 1 else 1000.0
        tol = max(1.0, 0.01 * spacing)
        grid = gx if axis == "x" else gy
        along = values[None, :] if axis == "x" else values[:, None]
        diff = np.abs(grid - along)
        err = float(np.max(diff, initial=0.0, where=~beyond))
        if err > tol:
            raise SwimInputError(
                f"coordinate '{axis}' [m] disagrees with lat/lon by up to {err:.4g} m (orthographic projection "
                f"about reference_lat/lon = {reference_lat:.4f}, {reference_lon:.4f}); expected "
                f"{axis} = orthographic_xy(lat, lon) within {tol:.3g} m"
            )
        coords[axis] = xr.DataArray(values, dims=(axis,), attrs=_new_attrs(axis, attrs))
    return coords


def _beyond_limb(given: dict, shape: tuple) -> np.ndarray:
    """Mask (y, x) of the columns with ``x^2 + y^2 >= R^2`` (none unless both ``x`` and ``y`` are given).

    Raises
    ------
    SwimInputError
        Where there are such columns and ``x`` or ``y`` does not increase strictly.
    """
    if set(given) != {"x", "y"}:
        return np.zeros(shape, dtype=bool)
    x, y = given["x"][0], given["y"][0]
    if (y.size, x.size) != tuple(shape) or not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        return np.zeros(shape, dtype=bool)  # the comparison reports it
    beyond = x[None, :] ** 2 + y[:, None] ** 2 >= EARTH_RADIUS_M**2
    if beyond.any():
        for axis, values in (("x", x), ("y", y)):
            if np.any(np.diff(values) <= 0):
                raise SwimInputError(
                    f"coordinate '{axis}' [m] must increase strictly where the grid reaches beyond the limb "
                    f"(x^2 + y^2 >= R^2, {int(beyond.sum())} columns): their positions rest on x and y alone"
                )
        logger.debug("validate_scene: %d columns beyond the limb (x^2 + y^2 >= R^2): x/y not compared with lat/lon",
                     int(beyond.sum()))
    return beyond


def _validate_albedo(da: xr.DataArray, ds: xr.Dataset, ny: int, nx: int):
    """Check ``surface_albedo`` (wavelength, y, x) or (y, x), a fraction in [0, 1], and return it on the three
    wavelengths of :data:`swim.constants.WAVELENGTHS_NM` with the ``wavelength`` coordinate."""
    name = "surface_albedo"
    _check_units(name, da)
    wl = xr.DataArray(WAVELENGTHS_NM.copy(), dims=("wavelength",), attrs=_new_attrs("wavelength", {}))
    if set(da.dims) == set(_2D) and da.ndim == 2:
        da = da.transpose(*_2D)
        values = np.broadcast_to(np.array(da.values, dtype=float), (WAVELENGTHS_NM.size, ny, nx)).copy()
        logger.debug("surface_albedo: broadcast a (y, x) albedo to the %d wavelengths", WAVELENGTHS_NM.size)
    else:
        da = _check_dims(name, da, ("wavelength",) + _2D)
        if "wavelength" in da.coords:
            given = np.asarray(da["wavelength"].values, dtype=float)
            if "wavelength" in ds.coords and "units" in ds["wavelength"].attrs:
                _check_units("wavelength", ds["wavelength"])
            try:
                da = da.sel(wavelength=WAVELENGTHS_NM, method="nearest", tolerance=0.5)
            except KeyError as exc:
                raise SwimInputError(
                    f"surface_albedo: wavelength coordinate {given.tolist()} must hold {WAVELENGTHS_NM.tolist()} nm"
                ) from exc
        elif da.sizes["wavelength"] != WAVELENGTHS_NM.size:
            raise SwimInputError(
                f"surface_albedo: {da.sizes['wavelength']} wavelengths without a coordinate; expected "
                f"{WAVELENGTHS_NM.size} in the order {WAVELENGTHS_NM.tolist()} nm"
            )
        values = np.array(da.values, dtype=float)
    if values.shape[1:] != (ny, nx):
        raise SwimInputError(f"surface_albedo has (y, x) shape {values.shape[1:]}; expected {(ny, nx)}")
    _finite_or_raise(name, values)
    if values.min() < 0.0 or values.max() > 1.0:
        raise SwimInputError(
            f"surface_albedo: range [{values.min():.4g}, {values.max():.4g}] is outside [0, 1] (a fraction; percent "
            "must be divided by 100)"
        )
    return xr.DataArray(values, dims=("wavelength",) + _2D, attrs=_new_attrs(name, da.attrs)), wl
