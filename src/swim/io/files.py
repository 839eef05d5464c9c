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
    _check_netcdf3_length(p, kind)
    try:
        return xr.open_dataset(p, chunks=chunks)
    except Exception as exc:  # noqa: BLE001 - any backend failure means "not a readable netCDF file"
        raise SwimInputError(f"{kind} {p} cannot be read as netCDF: {exc}") from exc


def _check_netcdf3_length(p: Path, kind: str) -> None:
    """Refuse a netCDF-3 file (classic or 64-bit offset: WRF's default output) that is shorter than its header says:
    a truncated copy or an interrupted write, whose missing values netCDF-C reads back as zeros without a word.
    SciPy's reader maps every variable from its header's offsets, which fails where the data would lie beyond the
    file's end; netCDF-4 (HDF5) files are left to their own library, which notices."""
    with open(p, "rb") as f:
        magic = f.read(4)
    if magic not in (b"CDF\x01", b"CDF\x02"):
        return
    from scipy.io import netcdf_file

    try:
        nc = netcdf_file(p, "r", mmap=True)
    except (ValueError, TypeError, OverflowError, IndexError) as exc:
        raise SwimInputError(f"{kind} {p} is truncated or damaged: its netCDF-3 header describes more data than its "
                             f"{p.stat().st_size} bytes hold ({exc})") from None
    nc.variables.clear()  # no array keeps the mapping open
    nc.close()
