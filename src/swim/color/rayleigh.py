"""Chromaticity of a pure Rayleigh sky, the paper's colour check (Sect. 3.8: x = y = 0.235)."""

from __future__ import annotations

import numpy as np

from swim.color._tables import astm_g173_extraterrestrial, cie_1931_cmfs
from swim.color.spectrum import solar_relative_to_XYZ
from swim.constants import WAVELENGTHS_NM
from swim.errors import SwimInputError

__all__ = ["rayleigh_sky_chromaticity", "RAYLEIGH_METHODS"]

#: Accepted values of ``method`` in :func:`rayleigh_sky_chromaticity`.
RAYLEIGH_METHODS = ("spectral", "three_wavelengths")


def rayleigh_sky_chromaticity(method: str = "spectral") -> np.ndarray:
    """CIE 1931 xy chromaticity of a pure (optically thin) Rayleigh-scattering sky.

    The sky radiance is taken proportional to ``lambda^-4 E(lambda)``, with ``E`` the ASTM G173-03
    extraterrestrial solar spectrum (optically thin single scattering; the weak wavelength
    dependence of the King factor and of the refractive index is neglected).

    Parameters
    ----------
    method : {"spectral", "three_wavelengths"}, optional
        - ``"spectral"``: the full spectrum ``lambda^-4 E(lambda)`` at the 1 nm resolution of the
          CIE table (360-830 nm, ``E`` linearly interpolated), trapezoidal integration against the
          CIE 1931 2-degree colour matching functions. Independent of the SWIm reconstruction.
        - ``"three_wavelengths"``: SWIm's own route: ``L' proportional to lambda^-4`` sampled at
          615, 546, 450 nm, then :func:`swim.color.solar_relative_to_XYZ` (quadratic
          interpolation/extrapolation, solar spectrum, CMFs).

    Returns
    -------
    numpy.ndarray, shape (2,)
        Chromaticity ``(x, y)`` [-]. Measured: spectral (0.2343, 0.2343); three wavelengths
        (0.2344, 0.2386). Paper: x = y = 0.235.

    Raises
    ------
    SwimInputError
        If ``method`` is unknown.
    """
    if method == "spectral":
        wl, xyz_bar = cie_1931_cmfs()
        swl, se = astm_g173_extraterrestrial()
        s = (wl / 550.0) ** -4 * np.interp(wl, swl, se)
        xyz = np.trapezoid(s[:, None] * xyz_bar, wl, axis=0)
    elif method == "three_wavelengths":
        xyz = solar_relative_to_XYZ((WAVELENGTHS_NM / 550.0) ** -4)
    else:
        raise SwimInputError(f"method must be one of {RAYLEIGH_METHODS}; got {method!r}")
    return xyz[:2] / xyz.sum()
