"""WRF output after xwrf's ``Dataset.xwrf.postprocess()``: turned back into the raw ``wrfout`` layout that
:func:`swim.io.wrf.read_wrf` reads, so a dataset a user already holds through xwrf renders without re-opening the
file.

xwrf (https://xwrf.readthedocs.io) renames the dimensions (``bottom_top`` -> ``z``, ``south_north`` -> ``y``,
``west_east`` -> ``x``, the staggered ones to ``*_stag``), adds projection coordinates ``x``/``y`` [m], makes
``XLAT``/``XLONG`` coordinates without ``Time``, and replaces the split fields by their sums:
``geopotential = PH + PHB`` [m2 s-2], ``air_pressure = P + PB`` [Pa] and ``air_potential_temperature = T + 300``
[K] (``drop_diagnostic_variable_components``, its default, drops the parts). The mixing ratios, surface fields and
``Times`` keep their WRF names. xwrf keeps ``XLAT``/``XLONG`` of the first time only, which misplaces the later
times of a moving nest (the Katrina sample's columns move by 0.75 deg in 6 h): a warning says so.
"""

from __future__ import annotations

import logging

import xarray as xr

from ..errors import SwimInputError

logger = logging.getLogger(__name__)

__all__ = ["is_xwrf_dataset", "raw_wrf_layout", "WRF_UNITS"]

#: xwrf's dimension names -> WRF's.
_DIMS = {"z": "bottom_top", "z_stag": "bottom_top_stag", "y": "south_north", "y_stag": "south_north_stag",
         "x": "west_east", "x_stag": "west_east_stag"}
#: xwrf's summed fields -> (WRF's perturbation name, WRF's base-state name, the offset WRF's perturbation has).
_SUMS = {"geopotential": ("PH", "PHB", 0.0), "air_pressure": ("P", "PB", 0.0),
         "air_potential_temperature": ("T", None, -300.0)}
#: The units :func:`swim.io.wrf.read_wrf` works in, for unit-aware (pint) datasets (:mod:`swim.io.quantities`).
WRF_UNITS = {
    "PH": "m2 s-2", "PHB": "m2 s-2", "P": "Pa", "PB": "Pa", "T": "K", "HGT": "m", "XLAT": "degrees_north",
    "XLONG": "degrees_east", "U10": "m s-1", "V10": "m s-1", "SNOW": "kg m-2",
    **{q: "kg kg-1" for q in ("QVAPOR", "QCLOUD", "QICE", "QRAIN", "QSNOW", "QGRAUP")},
    **{r: "m" for r in ("RE_CLOUD", "RE_ICE", "RE_SNOW")},
    **{a: "1" for a in ("ALBEDO", "ALBBCK", "SNOALB", "SNOWC", "SEAICE")},
    "geopotential": "m2 s-2", "air_pressure": "Pa", "air_potential_temperature": "K",
}


def is_xwrf_dataset(ds: xr.Dataset) -> bool:
    """Whether ``ds`` is WRF output post-processed by xwrf: it has xwrf's ``geopotential`` and ``air_pressure`` on
    dimension ``z``/``z_stag`` and no raw ``PHB``."""
    return ("geopotential" in ds.variables and "air_pressure" in ds.variables and "PHB" not in ds.variables
            and "z" in ds["air_pressure"].dims)


def raw_wrf_layout(ds: xr.Dataset) -> xr.Dataset:
    """The raw ``wrfout`` layout of an xwrf-processed dataset (module docstring): WRF's dimension names, ``PH``/
    ``PHB``, ``P``/``PB`` and ``T`` from xwrf's sums (the base-state parts zero), ``XLAT``/``XLONG`` as
    variables, the projection coordinates dropped.

    Parameters
    ----------
    ds : xarray.Dataset
        Output of ``xarray.open_dataset(wrfout).xwrf.postprocess()`` (values plain or pint quantities already
        converted by :func:`swim.io.quantities.dequantified`).

    Returns
    -------
    xarray.Dataset
        A dataset :func:`swim.io.wrf.read_wrf` reads; attributes (``TITLE``, ``DX``, ``MAP_PROJ``, ...) kept.

    Raises
    ------
    SwimInputError
        When ``air_potential_temperature`` is missing (xwrf run without its base diagnostics).
    """
    if "air_potential_temperature" not in ds.variables:
        raise SwimInputError("xwrf dataset: air_potential_temperature [K] missing; run xwrf's postprocess() with "
                             "calculate_diagnostic_variables=True, or pass the raw wrfout file")
    projection = [n for n in ("x", "y", "x_stag", "y_stag", "wrf_projection") if n in ds.variables]
    out = ds.drop_vars(projection)
    for summed, (perturbation, base, offset) in _SUMS.items():
        if summed in out.variables and perturbation not in out.variables:
            total = out[summed]
            out[perturbation] = total + offset if offset else total
            if base is not None:
                out[base] = xr.zeros_like(total)
            out = out.drop_vars(summed)
    for name in ("XLAT", "XLONG"):
        if name in out.coords:
            out = out.reset_coords(name)
    out = out.rename_dims({d: w for d, w in _DIMS.items() if d in out.dims})
    if out.sizes.get("Time", 1) > 1 and "Time" not in out["XLAT"].dims:
        logger.warning("xwrf dataset: xwrf keeps the first time's XLAT/XLONG for all %d times; in a moving nest the "
                       "later times' columns are placed there (read the raw wrfout file to place them right)",
                       out.sizes["Time"])
    logger.info("read_wrf: an xwrf-processed dataset, read in the raw wrfout layout")
    return out
