"""Opening input files with clear errors (the readers' shared edge)."""

from __future__ import annotations

from pathlib import Path

import xarray as xr

from ..errors import SwimInputError

__all__ = ["open_netcdf"]


def open_netcdf(path, kind: str, chunks=None) -> xr.Dataset:
    """Open a netCDF file lazily, or raise :class:`~swim.errors.SwimInputError` naming ``kind`` and the file.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    kind : str
        What the file should be, for the message (e.g. ``"WRF file"``).
    chunks : dict, optional
        Passed to :func:`xarray.open_dataset`: ``{}`` makes the variables dask arrays (read on demand).

    Returns
    -------
    xarray.Dataset
        Open dataset; use it as a context manager to close the file.

    Raises
    ------
    SwimInputError
        If the file does not exist or no xarray backend can read it.
    """
    p = Path(path)
    if not p.is_file():
        raise SwimInputError(f"{kind} not found: {p}")
    try:
        return xr.open_dataset(p, chunks=chunks)
    except Exception as exc:  # noqa: BLE001 - any backend failure means "not a readable netCDF file"
        raise SwimInputError(f"{kind} {p} cannot be read as netCDF: {exc}") from exc
