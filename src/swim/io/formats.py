"""Which reader opens a file: the file's kind from its first bytes (GRIB, netCDF/HDF5, text), then, for netCDF,
the first format in :data:`NETCDF_FORMATS` whose variables the file holds. Suffixes are only a fallback for text
files. The table is the one place a new format is registered; ``docs/scene-format.md`` ("Formats") lists the same.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import xarray as xr

__all__ = ["SceneFormat", "NETCDF_FORMATS", "file_kind", "netcdf_format", "unsupported_message", "NETCDF_MAGIC"]

#: First bytes of netCDF classic/64-bit files and of netCDF-4 (HDF5) files.
NETCDF_MAGIC = (b"CDF\x01", b"CDF\x02", b"CDF\x05", b"\x89HDF\r\n\x1a\n")
GRIB_MAGIC = b"GRIB"
#: Suffixes of SHDOM-style LES text files (any text file whose header parses as one is read as one too).
LES_SUFFIXES = {".txt", ".lwc", ".dat"}


@dataclass(frozen=True)
class SceneFormat:
    """One netCDF layout swim reads.

    Attributes
    ----------
    name : str
        What users call it ("WRF wrfout").
    reader : str
        ``"module:function"`` of the reader, imported on first use; it takes the opened dataset (loaded) or, with
        ``takes_path``, the file's path, and the options :func:`swim.io.scene.open_scene` passes on.
    expects : str
        The variables that identify it, for messages.
    detect : callable
        ``detect(ds) -> bool`` on the opened (not loaded) dataset.
    takes_path : bool
        The reader opens the file itself (to read only what it needs).
    """

    name: str
    reader: str
    expects: str
    detect: Callable[[xr.Dataset], bool]
    takes_path: bool = False

    def load_reader(self) -> Callable:
        module, function = self.reader.split(":")
        return getattr(importlib.import_module(module), function)


def _has(*names: str) -> Callable[[xr.Dataset], bool]:
    return lambda ds: set(names) <= set(ds.variables)


def _is_wrf(ds: xr.Dataset) -> bool:
    title = str(ds.attrs.get("TITLE", ""))
    return ("WRF" in title.upper() and "PH" in ds.variables) or {"PH", "PHB", "Times"} <= set(ds.variables)


def _is_wps(ds: xr.Dataset) -> bool:
    return {"HGT_M", "XLAT_M", "XLONG_M"} <= set(ds.variables) and not {"height", "lat", "lon"} <= set(ds.variables)


def _ecmwf(kind: str) -> Callable[[xr.Dataset], bool]:
    def detect(ds: xr.Dataset) -> bool:
        from .ecmwf import ecmwf_kind

        return ecmwf_kind(ds) == kind

    return detect


def _mesh(kind: str) -> Callable[[xr.Dataset], bool]:
    def detect(ds: xr.Dataset) -> bool:
        if kind == "icon":
            from .icon import is_icon

            return is_icon(ds)
        from .unstructured import is_mpas

        return is_mpas(ds)

    return detect


#: The netCDF layouts, tried in order (the canonical scene last: another model's file may hold a ``height``).
NETCDF_FORMATS: list[SceneFormat] = [
    SceneFormat("WRF wrfout", "swim.io.wrf:read_wrf", "PH, PHB, Times (or a WRF TITLE)", _is_wrf),
    SceneFormat("WPS geo_em/met_em", "swim.io.wps:read_wps_geogrid", "HGT_M, XLAT_M, XLONG_M", _is_wps),
    SceneFormat("ECMWF pressure levels (ERA5)", "swim.io.ecmwf:read_era5_pressure_levels",
                "t, q, clwc/ciwc/crwc/cswc on level/pressure_level [hPa]", _ecmwf("era5_pressure_levels"),
                takes_path=True),
    SceneFormat("ECMWF model levels (IFS L137, NWP SAF profiles)", "swim.io.ecmwf:read_ifs_model_levels",
                "t, q, clwc.. with lnsp/sp and z; or temp, hum, paph, psurf on point", _ecmwf("ifs_model_levels"),
                takes_path=True),
    SceneFormat("ICON (triangular mesh or lat-lon)", "swim.io.icon:read_icon",
                "clon, clat (or lat, lon) with z_mc/z_ifc and clw/cli/qc/qi/qr/qs/qg", _mesh("icon"), takes_path=True),
    SceneFormat("MPAS (Voronoi mesh)", "swim.io.unstructured:read_mpas", "latCell, lonCell, zgrid", _mesh("mpas"),
                takes_path=True),
    SceneFormat("canonical scene", "swim.io.scene:validate_scene", "height, lat, lon, terrain_height (z, y, x)",
                _has("height", "lat", "lon")),
]


def file_kind(path: Path) -> str:
    """``"grib"``, ``"netcdf"``, ``"les"`` (an SHDOM-style text file) or ``"unknown"``, from the file's first
    bytes; a text file by its suffix or, failing that, by whether its header parses as an LES header."""
    with open(path, "rb") as f:
        head = f.read(8)
    if head.startswith(GRIB_MAGIC):
        return "grib"
    if head.startswith(NETCDF_MAGIC):
        return "netcdf"
    if path.suffix.lower() in LES_SUFFIXES:
        return "les"
    try:
        from .les import read_shdom_les_header

        read_shdom_les_header(path)
        return "les"
    except Exception:  # not an LES header (or not text): the caller names what was expected
        return "unknown"


def netcdf_format(ds: xr.Dataset) -> SceneFormat | None:
    """The first of :data:`NETCDF_FORMATS` whose ``detect`` accepts ``ds``, or None."""
    return next((f for f in NETCDF_FORMATS if f.detect(ds)), None)


def unsupported_message(name: str, what: str) -> str:
    """The message for a file no reader takes: what it is, the formats and their variables, and how to build a
    canonical scene instead."""
    formats = "; ".join(f"{f.name} ({f.expects})" for f in NETCDF_FORMATS)
    return (f"scene file {name}: {what}. swim reads GRIB (NCEP GFS, HRRR, RAP; ECMWF), SHDOM-style LES "
            f"text and these netCDF layouts: {formats}. For other model output build a canonical scene with "
            "swim.scene_from_arrays (docs/scene-format.md)")
