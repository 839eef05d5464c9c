"""Reader for SHDOM-style LES cloud-field text files (the AT3D/SHDOM ``synthetic_cloud_fields`` format).

Format (as in AT3D's ``at3d.util.load_from_csv`` and the SHDOM distribution's ``les_stcu``):

* optional comment lines starting with ``#``;
* a line ``nx ny nz`` (comma or whitespace separated; a trailing ``# comment`` is ignored);
* ``dx dy`` [km], then the ``nz`` level heights [km], on one or more lines (``les_stcu.txt`` has dx, dy and
  the levels on one line; the RICO files put them on two);
* an optional column-name line (``i,j,k,lwc,reff`` or ``x,y,z,lwc,reff``);
* one row per listed cell: ``i j k lwc reff`` with ``lwc`` [g m-3] and ``reff`` [um]. Cells not listed are
  clear.

Indices are 0-based (AT3D's convention; the files hold 0 <= i < nx). A file whose indices reach exactly
``nx``, ``ny`` or ``nz`` (and start at 1 or more) is read as 1-based and logged.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import SwimInputError
from .scene import scene_from_arrays

logger = logging.getLogger(__name__)

__all__ = ["read_shdom_les", "read_shdom_les_header"]

_SPLIT = re.compile(r"[,\s]+")


def _numbers(line: str) -> list[float] | None:
    """The numbers on a line (comments after '#' removed); None if the line is not purely numeric."""
    text = line.split("#", 1)[0].strip()
    if not text:
        return []
    try:
        return [float(t) for t in _SPLIT.split(text) if t]
    except ValueError:
        return None


def read_shdom_les_header(path) -> dict:
    """Parse the header of an SHDOM-style LES file.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    dict
        ``nx, ny, nz`` (int), ``dx, dy`` [m], ``z`` (numpy.ndarray, shape (nz,)) [m], ``skiprows`` (int: header
        lines before the first data row, the column-name line included), ``sep`` (',' or whitespace regex),
        ``comment`` (the first comment line, or '').

    Raises
    ------
    SwimInputError
        If the file is missing or its header is malformed.
    """
    p = Path(path)
    if not p.is_file():
        raise SwimInputError(f"LES file not found: {p}")
    numbers: list[float] = []
    comment = ""
    dims = None
    skip = 0
    with p.open("r", encoding="utf-8", errors="replace") as f:
        for line in f:
            stripped = line.strip()
            if dims is not None and len(numbers) >= 2 + dims[2]:
                # header complete: this is either a column-name line or the first data row
                if _numbers(stripped) is None:
                    skip += 1
                first_data = stripped if _numbers(stripped) is not None else f.readline().strip()
                break
            skip += 1
            if stripped.startswith("#") or not stripped:
                if not comment and stripped.startswith("#"):
                    comment = stripped.lstrip("#").strip()
                continue
            vals = _numbers(stripped)
            if vals is None:
                raise SwimInputError(f"LES file {p.name}: header line {skip} is not numeric: {stripped[:60]!r}")
            if dims is None:
                if len(vals) < 3:
                    raise SwimInputError(f"LES file {p.name}: header line {skip} must give nx, ny, nz; got {stripped[:60]!r}")
                dims = tuple(int(v) for v in vals[:3])
                if min(dims) < 1 or any(v != int(v) for v in vals[:3]):
                    raise SwimInputError(f"LES file {p.name}: nx, ny, nz = {vals[:3]} must be positive integers")
                numbers.extend(vals[3:])
            else:
                numbers.extend(vals)
        else:
            first_data = ""
    if dims is None or len(numbers) < 2 + dims[2]:
        raise SwimInputError(
            f"LES file {p.name}: incomplete header; expected nx ny nz, dx dy [km] and {dims[2] if dims else 'nz'} "
            "level heights [km]"
        )
    nx, ny, nz = dims
    dx, dy = numbers[0] * 1e3, numbers[1] * 1e3
    z = np.asarray(numbers[2 : 2 + nz], dtype=float) * 1e3
    if dx <= 0 or dy <= 0:
        raise SwimInputError(f"LES file {p.name}: dx, dy = {numbers[:2]} km must be positive")
    if nz > 1 and np.any(np.diff(z) <= 0):
        raise SwimInputError(f"LES file {p.name}: the {nz} level heights [km] must increase strictly: {z / 1e3}")
    sep = "," if "," in first_data else r"\s+"
    return {"nx": nx, "ny": ny, "nz": nz, "dx": dx, "dy": dy, "z": z, "skiprows": skip, "sep": sep, "comment": comment}


def _index_base(name: str, idx: np.ndarray, n: int, label: str) -> int:
    if idx.size == 0:
        return 0
    lo, hi = int(idx.min()), int(idx.max())
    if lo >= 0 and hi <= n - 1:
        return 0
    if lo >= 1 and hi == n:
        logger.info("%s: index %s reaches %d = n%s: reading the indices as 1-based", label, name, n, name)
        return 1
    raise SwimInputError(f"{label}: index {name} spans [{lo}, {hi}], outside the grid of {n} points (0-based)")


def read_shdom_les(path, reference_lat: float | None = None, reference_lon: float | None = None, time=None):
    """Read an SHDOM-style LES liquid-water file into the canonical scene.

    Parameters
    ----------
    path : str or os.PathLike
        The text file (format in the module docstring), e.g. ``les/rico122x106x39.txt``, ``les/rico32x37x26.txt``
        or ``les/les_stcu.txt`` of the shared data.
    reference_lat, reference_lon : float, optional
        Where to put the centre of the LES domain [deg] (LES has no geolocation); default (0, 0), with a warning
        where neither is given: the sun's position from a time depends on it.
    time : str, datetime or numpy.datetime64, optional
        Valid time (UTC) to attach as the scalar coordinate ``time``; none by default.

    Returns
    -------
    xarray.Dataset
        Canonical scene of shape (nz, ny, nx): ``height`` [m] = the file's levels (above sea level, flat
        terrain at 0 m), ``cloud_liquid_content`` [kg m-3] (= lwc x 1e-3), ``cloud_liquid_effective_radius``
        [m] (= reff x 1e-6; the default where lwc is 0), ``terrain_height`` 0, ``land_mask`` 0 (sea), 1-D ``x``,
        ``y`` [m] centred on the reference point (``x = (i - (nx - 1) / 2) dx``).

    Raises
    ------
    SwimInputError
        If the file is missing or malformed, an index lies outside the grid, a cell is listed twice, a value is
        non-finite or negative, or a reff is outside [0.1, 1e5] um where lwc > 0.
    """
    p = Path(path)
    if reference_lat is None and reference_lon is None:
        logger.warning("LES file %s has no geolocation: placed at 0 deg N, 0 deg E (reference_lat/reference_lon; CLI "
                    "--scene-lat/--scene-lon), where the sun of a time is computed", p.name)
    reference_lat = 0.0 if reference_lat is None else reference_lat
    reference_lon = 0.0 if reference_lon is None else reference_lon
    header = read_shdom_les_header(p)
    nx, ny, nz = header["nx"], header["ny"], header["nz"]
    label = f"LES file {p.name}"
    try:
        table = pd.read_csv(
            p, skiprows=header["skiprows"], sep=header["sep"], header=None, comment="#", usecols=range(5),
            names=["i", "j", "k", "lwc", "reff"], skipinitialspace=True,
        )
    except (ValueError, pd.errors.ParserError) as exc:
        raise SwimInputError(f"{label}: cannot parse the rows 'i j k lwc[g m-3] reff[um]': {exc}") from exc
    table = table.dropna(how="all")
    if table.isna().any().any():
        raise SwimInputError(f"{label}: {int(table.isna().any(axis=1).sum())} row(s) lack one of i, j, k, lwc, reff")
    idx = {}
    for name, n in (("i", nx), ("j", ny), ("k", nz)):
        v = table[name].to_numpy(dtype=float)
        if np.any(v != np.round(v)):
            raise SwimInputError(f"{label}: index column {name} holds non-integers")
        v = v.astype(np.int64)
        idx[name] = v - _index_base(name, v, n, label)
    lwc = table["lwc"].to_numpy(dtype=float)
    reff = table["reff"].to_numpy(dtype=float)
    for name, v in (("lwc [g m-3]", lwc), ("reff [um]", reff)):
        if not np.all(np.isfinite(v)):
            raise SwimInputError(f"{label}: column {name} has {int(np.sum(~np.isfinite(v)))} non-finite value(s)")
        if np.any(v < 0):
            raise SwimInputError(f"{label}: column {name} has {int(np.sum(v < 0))} negative value(s)")
    wet = lwc > 0
    if np.any(wet & ((reff < 0.1) | (reff > 1e5))):
        raise SwimInputError(
            f"{label}: reff outside [0.1, 1e5] um in {int(np.sum(wet & ((reff < 0.1) | (reff > 1e5))))} cloudy cell(s); "
            "expected micrometres"
        )
    flat = np.ravel_multi_index((idx["k"], idx["j"], idx["i"]), (nz, ny, nx))
    if np.unique(flat).size != flat.size:
        raise SwimInputError(f"{label}: {flat.size - np.unique(flat).size} cell(s) are listed more than once")

    content = np.zeros((nz, ny, nx))
    radius = np.zeros((nz, ny, nx))
    content.ravel()[flat] = lwc * 1e-3
    radius.ravel()[flat] = np.where(wet, reff * 1e-6, 0.0)
    x = (np.arange(nx) - 0.5 * (nx - 1)) * header["dx"]
    y = (np.arange(ny) - 0.5 * (ny - 1)) * header["dy"]
    logger.info(
        "%s: %d x %d x %d grid, dx=%g m, dy=%g m, z %g-%g m, %d listed cells, max lwc %.3g g m-3",
        label, nx, ny, nz, header["dx"], header["dy"], header["z"][0], header["z"][-1], len(table), lwc.max(initial=0.0),
    )
    return scene_from_arrays(
        x=x,
        y=y,
        z=header["z"],
        reference_lat=reference_lat,
        reference_lon=reference_lon,
        terrain_height=0.0,
        cloud_liquid_content=content,
        cloud_liquid_effective_radius=radius,
        land_mask=0,
        time=time,
        title=f"LES cloud field {p.name}" + (f": {header['comment']}" if header["comment"] else ""),
        source=f"{p} read by swim.io.les.read_shdom_les",
    )
