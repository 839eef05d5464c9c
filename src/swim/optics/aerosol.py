"""Background aerosol: exponential extinction profile and Ångström spectral scaling.

Source: Albers et al. (2020), Atmos. Meas. Tech. 13, 3235-3261, doi:10.5194/amt-13-3235-2020, Sects. 3.3 and
3.5 (horizontally uniform aerosol, extinction varying with wavelength through an Ångström exponent); defaults
in :data:`swim.constants.DEFAULT_AEROSOL`.

The functions compute in the array library of their inputs (:mod:`swim.arrays`). Numpy input is validated
(raising :class:`swim.errors.SwimInputError`); JAX arrays and tracers are computed with ``jax.numpy`` without
validation so the functions can run inside ``jax.jit``.
"""

from __future__ import annotations

import logging

import numpy as np

from ..arrays import array_namespace, is_jax
from ..constants import DEFAULT_AEROSOL
from ..errors import SwimInputError

_log = logging.getLogger(__name__)

#: Reference wavelength of the aerosol optical depth [nm].
REFERENCE_WAVELENGTH_NM = 550.0


def exponential_aerosol_extinction(
    height_m, aod_550=DEFAULT_AEROSOL["aod_550"], scale_height_m=DEFAULT_AEROSOL["scale_height_m"]
):
    """Aerosol extinction coefficient at 550 nm decreasing exponentially with height.

    Parameters
    ----------
    height_m : array_like
        Height above sea level [m].
    aod_550 : array_like, optional
        Column aerosol optical depth at 550 nm above sea level [-], ≥ 0. Default 0.05.
    scale_height_m : array_like, optional
        Scale height H [m], > 0. Default 1500 m.

    Returns
    -------
    numpy.ndarray or jax.Array
        β_550(h) = (AOD / H) exp(-h / H) [m-1], broadcast shape; ∫_0^∞ β dh = AOD.

    Raises
    ------
    SwimInputError
        For numpy input with a non-finite height, a negative AOD or a non-positive scale height.

    Notes
    -----
    Heights below sea level get the (slightly larger) extrapolated value; the column is anchored at sea level,
    so a site at altitude z sees AOD exp(-z / H) above it.

    Source: paper Sect. 3.5 (1D aerosol specification); profile shape after the standard exponential
    boundary-layer aerosol model, e.g. Hess, M., Koepke, P. and Schult, I. (1998), Bull. Am. Meteorol. Soc.
    79, 831-844, doi:10.1175/1520-0477(1998)079<0831:OPOAAC>2.0.CO;2.
    """
    xp = array_namespace(height_m, aod_550, scale_height_m)
    if is_jax(xp):  # no validation: values cannot be inspected under tracing
        h, aod, sh = xp.asarray(height_m), xp.asarray(aod_550), xp.asarray(scale_height_m)
        return aod / sh * xp.exp(-h / sh)
    h = np.asarray(height_m, dtype=float)
    aod = np.asarray(aod_550, dtype=float)
    sh = np.asarray(scale_height_m, dtype=float)
    if np.any(~np.isfinite(h)):
        raise SwimInputError(f"height_m must be finite [m]; got {height_m!r}")
    if np.any(~np.isfinite(aod)) or np.any(aod < 0.0):
        raise SwimInputError(f"aod_550 must be a finite optical depth >= 0 [-]; got {aod_550!r}")
    if np.any(~np.isfinite(sh)) or np.any(sh <= 0.0):
        raise SwimInputError(f"scale_height_m must be finite and > 0 [m]; got {scale_height_m!r}")
    return aod / sh * np.exp(-h / sh)


def angstrom_extinction(beta_550, wavelength_nm, angstrom_exponent=1.3):
    """Aerosol extinction at another wavelength from the Ångström law.

    Parameters
    ----------
    beta_550 : array_like
        Extinction coefficient (or optical depth) at 550 nm [m-1 or -], ≥ 0.
    wavelength_nm : array_like
        Wavelength [nm], > 0.
    angstrom_exponent : array_like, optional
        Ångström exponent α [-]. Default 1.3.

    Returns
    -------
    numpy.ndarray or jax.Array
        β_550 (λ / 550 nm)^(-α), same units as ``beta_550``, broadcast shape.

    Raises
    ------
    SwimInputError
        For numpy input with a negative or non-finite β, a non-positive wavelength or a non-finite exponent.

    Source: Ångström, A. (1929), On the atmospheric transmission of sun radiation and on dust in the air,
    Geogr. Ann. 11, 156-166, doi:10.1080/20014422.1929.11880498; paper Sect. 3.5.1.
    """
    xp = array_namespace(beta_550, wavelength_nm, angstrom_exponent)
    if is_jax(xp):  # no validation: values cannot be inspected under tracing
        ratio = xp.asarray(wavelength_nm) / REFERENCE_WAVELENGTH_NM
        return xp.asarray(beta_550) * ratio ** (-xp.asarray(angstrom_exponent))
    beta = np.asarray(beta_550, dtype=float)
    lam = np.asarray(wavelength_nm, dtype=float)
    alpha = np.asarray(angstrom_exponent, dtype=float)
    if np.any(~np.isfinite(beta)) or np.any(beta < 0.0):
        raise SwimInputError(f"beta_550 must be finite and >= 0; got {beta_550!r}")
    if np.any(~np.isfinite(lam)) or np.any(lam <= 0.0):
        raise SwimInputError(f"wavelength_nm must be finite and > 0 [nm]; got {wavelength_nm!r}")
    if np.any(~np.isfinite(alpha)):
        raise SwimInputError(f"angstrom_exponent must be finite [-]; got {angstrom_exponent!r}")
    return beta * (lam / REFERENCE_WAVELENGTH_NM) ** (-alpha)
