"""Reference tables of the colour stage: the solar spectrum, the CIE 1931 colour matching functions
and the regular wavelength grid on which the spectral reconstruction of Sect. 3.8 is evaluated.

Everything here is computed once and cached; the arrays handed out are read-only. What comes from colour-science is
shipped with swim as a table (:func:`colour_science_data`), so that a render needs no colour-science: importing it
took ~0.6 s (~1.2 s where matplotlib is installed) and it weighs ~100 MB.

Sources
-------
- ASTM G173-03 extraterrestrial spectrum, as bundled with pvlib
  (:func:`pvlib.spectrum.get_reference_spectra`, column ``'extraterrestrial'``), W m-2 nm-1 at 1 AU,
  scaled by its publisher to a total solar irradiance of 1366.1 W m-2.
- CIE 1931 2-degree standard observer colour matching functions, 1 nm table from colour-science
  (``colour.MSDS_CMFS['CIE 1931 2 Degree Standard Observer']``; CIE 015:2018, Table 1), shipped in
  ``swim/data/colour_tables.npz`` with the sRGB matrix and the adaptation transforms (``scripts/make_colour_tables.py``).
"""

from __future__ import annotations

import functools
import warnings
from pathlib import Path

import numpy as np

from swim.constants import SOLAR_CONSTANT_W_M2
from swim.errors import SwimInputError

#: Regular wavelength grid of the reconstructed spectrum [nm]: 380-780 nm in 5 nm steps (81 samples),
#: the CIE 015 recommended summation interval for colorimetry.
SPECTRAL_GRID_NM = np.arange(380.0, 780.0 + 0.5, 5.0)
SPECTRAL_GRID_NM.flags.writeable = False
#: Step of :data:`SPECTRAL_GRID_NM` [nm].
SPECTRAL_STEP_NM = 5.0

#: Total solar irradiance to which the ASTM G173-03 extraterrestrial spectrum is scaled [W m-2].
ASTM_G173_TSI_W_M2 = 1366.1

#: Name of the colour-science CMF data set used throughout.
CMFS_NAME = "CIE 1931 2 Degree Standard Observer"


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.flags.writeable = False
    return a


def import_colour():
    """colour-science (the tables' source, for their script and the tests), imported when first needed.

    Returns
    -------
    module
        ``colour``, imported with its warnings about optional plotting dependencies silenced.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import colour
    return colour


#: The colorimetric tables taken from colour-science (``scripts/make_colour_tables.py``), shipped with swim.
COLOUR_TABLES_PATH = Path(__file__).resolve().parents[1] / "data" / "colour_tables.npz"


@functools.lru_cache(maxsize=1)
def _shipped_tables() -> dict:
    with np.load(COLOUR_TABLES_PATH) as data:
        return {key: data[key] for key in data.files}


@functools.lru_cache(maxsize=8)
def colour_science_data(transform: str | None = None) -> dict:
    """What the colour stage takes from colour-science, from the tables shipped with swim.

    ``src/swim/data/colour_tables.npz`` is made from colour-science by ``scripts/make_colour_tables.py`` and held to
    it by ``tests/unit/color/test_color.py``, so that a render does not need colour-science at all.

    Parameters
    ----------
    transform : str, optional
        A chromatic adaptation transform of colour-science (``colour.CHROMATIC_ADAPTATION_TRANSFORMS``), e.g.
        "Bradford"; its matrix is included.

    Returns
    -------
    dict
        ``cmfs_wavelength_nm`` (471,) [nm] and ``cmfs`` (471, 3) [-]: the CIE 1931 2-degree colour matching functions
        (``colour.MSDS_CMFS``); ``srgb_XYZ_to_RGB`` (3, 3) [-] and ``srgb_whitepoint_XYZ`` (3,) [-] (Y = 1): the
        sRGB colourspace's matrix and D65 white (``colour.RGB_COLOURSPACES["sRGB"]``); with ``transform``, ``cat``
        (3, 3) [-]: the transform's cone-response matrix.

    Raises
    ------
    swim.errors.SwimInputError
        If ``transform`` is not one of colour-science's chromatic adaptation transforms.
    """
    tables = _shipped_tables()
    data = {key: _readonly(tables[key]) for key in ("cmfs_wavelength_nm", "cmfs", "srgb_XYZ_to_RGB",
                                                    "srgb_whitepoint_XYZ")}
    if transform is not None:
        names = [str(n) for n in tables["cat_names"]]
        if not isinstance(transform, str) or transform not in names:
            raise unknown_transform(transform)
        data["cat"] = _readonly(tables["cat_matrices"][names.index(transform)])
    return data


def unknown_transform(transform) -> SwimInputError:
    """The error for a chromatic adaptation transform that colour-science does not know, naming those it does."""
    known = sorted(str(n) for n in _shipped_tables()["cat_names"])
    return SwimInputError(f"transform must be one of {known}; got {transform!r}")


@functools.lru_cache(maxsize=1)
def astm_g173_extraterrestrial() -> tuple[np.ndarray, np.ndarray]:
    """The ASTM G173-03 extraterrestrial solar spectrum at its native resolution.

    Returns
    -------
    wavelength_nm : numpy.ndarray, shape (2002,)
        Wavelengths [nm], 280-4000 nm (0.5 nm steps below 400 nm, 1 nm to 1700 nm, 5 nm beyond).
    irradiance : numpy.ndarray, shape (2002,)
        Spectral irradiance at normal incidence at 1 AU [W m-2 nm-1], as published (scaled to a
        total solar irradiance of 1366.1 W m-2).

    Notes
    -----
    Read through :func:`pvlib.spectrum.get_reference_spectra` (column ``'extraterrestrial'``).
    """
    import pvlib  # deferred: importing pvlib is slow and only needed once

    ref = pvlib.spectrum.get_reference_spectra()["extraterrestrial"]
    return _readonly(ref.index.to_numpy(dtype=float)), _readonly(ref.to_numpy(dtype=float))


@functools.lru_cache(maxsize=1)
def solar_irradiance_on_grid() -> np.ndarray:
    """Extraterrestrial solar spectral irradiance on :data:`SPECTRAL_GRID_NM`.

    Each value is the mean of the ASTM G173-03 extraterrestrial spectrum (linearly interpolated
    between its samples) over the 5 nm bin centred on the grid wavelength, so that the 5 nm
    samples represent band integrals rather than aliasing individual Fraunhofer lines. The
    spectrum is rescaled from the G173 total solar irradiance (1366.1 W m-2) to SWIm's
    :data:`swim.constants.SOLAR_CONSTANT_W_M2` (1362 W m-2, paper Sect. 3.1); the shape is unchanged.

    Returns
    -------
    numpy.ndarray, shape (81,)
        Spectral irradiance at normal incidence at 1 AU [W m-2 nm-1].
    """
    wl, e = astm_g173_extraterrestrial()
    half = 0.5 * SPECTRAL_STEP_NM
    # 0.5 nm sub-grid: the bin edges (grid +- 2.5 nm) lie on it, and it contains every G173 sample
    # in 380-780 nm, so trapezoidal integration of the linear interpolant is exact.
    fine = np.arange(SPECTRAL_GRID_NM[0] - half, SPECTRAL_GRID_NM[-1] + half + 0.25, 0.5)
    e_fine = np.interp(fine, wl, e)
    seg = 0.5 * (e_fine[1:] + e_fine[:-1]) * 0.5  # integral over each 0.5 nm segment
    per_bin = int(round(SPECTRAL_STEP_NM / 0.5))
    band = seg.reshape(-1, per_bin).sum(axis=1) / SPECTRAL_STEP_NM
    return _readonly(band * (SOLAR_CONSTANT_W_M2 / ASTM_G173_TSI_W_M2))


@functools.lru_cache(maxsize=1)
def cie_1931_cmfs() -> tuple[np.ndarray, np.ndarray]:
    """CIE 1931 2-degree colour matching functions at their native 1 nm resolution.

    Returns
    -------
    wavelength_nm : numpy.ndarray, shape (471,)
        360-830 nm in 1 nm steps.
    xyz_bar : numpy.ndarray, shape (471, 3)
        x-bar, y-bar, z-bar [-] (CIE 015:2018 Table 1, via colour-science).
    """
    data = colour_science_data()
    return _readonly(data["cmfs_wavelength_nm"]), _readonly(data["cmfs"])


@functools.lru_cache(maxsize=1)
def cie_1931_cmfs_on_grid() -> np.ndarray:
    """CIE 1931 2-degree colour matching functions sampled at :data:`SPECTRAL_GRID_NM`.

    The 1 nm CIE table was itself interpolated from the 5 nm table, so sampling it every 5 nm
    reproduces the official 5 nm values.

    Returns
    -------
    numpy.ndarray, shape (81, 3)
        x-bar, y-bar, z-bar [-].
    """
    wl, xyz_bar = cie_1931_cmfs()
    idx = np.searchsorted(wl, SPECTRAL_GRID_NM)
    if not np.allclose(wl[idx], SPECTRAL_GRID_NM):  # pragma: no cover - table layout guard
        raise RuntimeError("CIE 1931 table does not contain the 5 nm grid wavelengths")
    return _readonly(xyz_bar[idx])
