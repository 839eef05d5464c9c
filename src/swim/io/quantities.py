"""Datasets whose values are unit-aware quantities (pint, as made by MetPy's ``Dataset.metpy.quantify()`` or
pint-xarray's ``Dataset.pint.quantify()``): converted once, at the reader's edge, to the plain float arrays and
``units`` attributes every reader and :func:`swim.io.scene.validate_scene` work with.

A quantity is converted to the unit the reader expects (``expected``), so a field that the user changed to other
units (pressure in hPa, a content in g m-3) arrives in SI, and one of the wrong dimension is refused by name. pint
is not imported here: a quantity carries its own registry (``quantity.to(unit)``), so swim works without pint
installed and with whatever registry (MetPy's or pint-xarray's) made the quantity.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping

import xarray as xr

from ..errors import SwimInputError

logger = logging.getLogger(__name__)

__all__ = ["is_quantity", "has_quantities", "dequantified", "PINT_SPELLING"]

#: pint spellings of the CF-style unit strings swim's readers name (pint reads "kg m-3" as kg·m − 3).
PINT_SPELLING = {
    "kg m-3": "kg / m**3", "kg kg-1": "kg / kg", "m-1": "1 / m", "m s-1": "m / s", "m2 s-2": "m**2 / s**2",
    "kg m-2": "kg / m**2", "degrees_north": "degree", "degrees_east": "degree", "degree_north": "degree",
    "degree_east": "degree", "1": "dimensionless", "-": "dimensionless", "%": "percent", "gpm": "m",
    "kg kg**-1": "kg / kg", "m s**-1": "m / s",
}


def is_quantity(values) -> bool:
    """Whether ``values`` (the ``.data`` of a DataArray) is a pint quantity: it has ``magnitude``, ``units`` and
    ``to``, and its class comes from pint."""
    return (type(values).__module__.split(".")[0] == "pint" and hasattr(values, "magnitude")
            and hasattr(values, "to"))


def has_quantities(ds: xr.Dataset) -> bool:
    """Whether any variable or coordinate of ``ds`` holds a pint quantity."""
    return any(is_quantity(v.data) for v in ds.variables.values())


def dequantified(ds: xr.Dataset, expected: Mapping[str, str] | None = None, label: str = "dataset") -> xr.Dataset:
    """``ds`` with every pint quantity replaced by its plain values and a ``units`` attribute.

    Parameters
    ----------
    ds : xarray.Dataset
        Any dataset; returned as it is when it holds no quantity.
    expected : mapping of str to str, optional
        Variable name -> the unit the caller works in, in CF spelling (``"kg m-3"``, ``"m-1"``, ``"Pa"``; see
        :data:`PINT_SPELLING`). A quantity of such a variable is converted to it and its ``units`` attribute
        set to that string. Other quantities keep their own unit, written as pint formats it.
    label : str
        The dataset's name in error messages.

    Returns
    -------
    xarray.Dataset
        A shallow copy with numpy (or dask) values.

    Raises
    ------
    SwimInputError
        When a quantity's unit cannot be converted to the expected one (a different dimension), naming the
        variable, its unit and the unit expected.
    """
    if not has_quantities(ds):
        return ds
    expected = dict(expected or {})
    out = ds.copy()
    for name, var in ds.variables.items():
        if not is_quantity(var.data):
            continue
        attrs = dict(var.attrs)
        target = expected.get(str(name))
        if target is None:
            values, units = var.data.magnitude, format(var.data.units, "~")
        else:
            values, units = _converted(var.data, target, f"{label}: variable {name}"), target
        attrs["units"] = units
        out[name] = xr.Variable(var.dims, values, attrs, var.encoding)
    logger.info("%s: unit-aware quantities converted to plain values", label)
    return out


def _converted(quantity, target: str, what: str):
    """The magnitude of ``quantity`` in ``target`` units (CF spelling)."""
    try:
        return quantity.to(PINT_SPELLING.get(target, target)).magnitude
    except Exception as err:  # pint's DimensionalityError and UndefinedUnitError: no common base class here
        raise SwimInputError(
            f"{what} is in {format(quantity.units, '~')!s}, which cannot be converted to the expected "
            f"{target} ({type(err).__name__}: {err})"
        ) from None
