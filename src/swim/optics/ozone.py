"""Ozone absorption of the clear atmosphere: the Chappuis band's cross sections and the standard ozone profile.

Ozone is the only gas that absorbs noticeably in swim's visible channels: its Chappuis band (400-700 nm, peak
near 600 nm) takes 3-4 % of the red and green light of a vertical beam through a column of ~345 DU and little
of the blue. For a sun near or below the horizon the slant path through the ozone layer (15-35 km) is 20-40
times the vertical one, so the red and green light that reaches the upper air is absorbed far more than the
blue: this keeps the zenith of the twilight sky blue (Hulburt 1953) where Rayleigh scattering alone would
redden it.

Cross sections
    Serdyuchenko et al. (2014) and Gorshelev et al. (2014), the IUP Bremen ozone spectra (213-1100 nm, 0.01-0.02
    nm sampling, 11 temperatures 193-293 K), at 233 K, a temperature typical of the ozone layer's peak (the
    Chappuis band changes by < 1 % between 223 and 243 K). :data:`CROSS_SECTION_233K_M2` holds their means over
    10 nm bins 400-410, ..., 690-700 nm (as tabulated in Bruneton's precomputed-atmosphere model, which averaged
    the Bremen 233 K data in each bin), here put at the bin centres 405, ..., 695 nm;
    :func:`ozone_cross_section` interpolates them linearly. A 10 nm mean is the value a smooth band-limited
    channel sees (the band's vibronic structure is ~10 nm wide); at 615 / 546 / 450 / 500 nm it gives
    4.305 / 3.132 / 0.195 / 1.191 x 10^-21 cm2.

Profile
    The US standard ozone profile of Anderson et al. (1986) (AFGL-TR-86-0110, "U.S. Standard" constituent
    profile, the ozone of the U.S. Standard Atmosphere 1976 and of libRadtran's ``afglus`` atmosphere): volume
    mixing ratio [ppmv] on 0-100 km (:data:`US_STANDARD_OZONE_PPMV`), times the air number density of
    :func:`swim.optics.atmosphere.us_standard_atmosphere_1976`. Its column is 345.5 DU
    (:data:`US_STANDARD_OZONE_DU`); :func:`ozone_number_density` scales the profile to another column.

References
----------
Serdyuchenko, A., Gorshelev, V., Weber, M., Chehade, W. and Burrows, J. P. (2014): High spectral resolution
ozone absorption cross-sections - Part 2: Temperature dependence, Atmos. Meas. Tech. 7, 625-636,
doi:10.5194/amt-7-625-2014.
Gorshelev, V., Serdyuchenko, A., Weber, M., Chehade, W. and Burrows, J. P. (2014): High spectral resolution
ozone absorption cross-sections - Part 1, Atmos. Meas. Tech. 7, 609-624, doi:10.5194/amt-7-609-2014.
Anderson, G. P., Clough, S. A., Kneizys, F. X., Chetwynd, J. H. and Shettle, E. P. (1986): AFGL atmospheric
constituent profiles (0-120 km), AFGL-TR-86-0110.
Hulburt, E. O. (1953): Explanation of the brightness and color of the sky, particularly the twilight sky,
J. Opt. Soc. Am. 43, 113-118, doi:10.1364/JOSA.43.000113.
"""

from __future__ import annotations

import numpy as np

from ..errors import SwimInputError
from .atmosphere import us_standard_atmosphere_1976

__all__ = ["CROSS_SECTION_233K_M2", "CROSS_SECTION_WAVELENGTHS_NM", "DOBSON_UNIT_M2", "US_STANDARD_OZONE_DU",
           "US_STANDARD_OZONE_PPMV", "ozone_absorption_coefficient", "ozone_column_du", "ozone_cross_section",
           "ozone_number_density"]

#: One Dobson unit: 2.6867e20 molecules per square metre (0.01 mm of pure ozone at 273.15 K, 101 325 Pa).
DOBSON_UNIT_M2 = 2.6867e20

#: Bin centres [nm] of :data:`CROSS_SECTION_233K_M2` (10 nm bins 400-410, ..., 690-700 nm).
CROSS_SECTION_WAVELENGTHS_NM = np.arange(405.0, 700.0, 10.0)
#: Ozone absorption cross section at 233 K, mean over each 10 nm bin [m2 molecule-1] (Serdyuchenko et al. 2014;
#: Gorshelev et al. 2014; module docstring).
CROSS_SECTION_233K_M2 = np.array([
    1.527e-27, 2.763e-27, 5.52e-27, 8.451e-27, 1.582e-26, 2.316e-26, 3.669e-26, 4.924e-26, 7.752e-26, 9.016e-26,
    1.48e-25, 1.602e-25, 2.139e-25, 2.755e-25, 3.091e-25, 3.5e-25, 4.266e-25, 4.672e-25, 4.398e-25, 4.701e-25,
    5.019e-25, 4.305e-25, 3.74e-25, 3.215e-25, 2.662e-25, 2.238e-25, 1.852e-25, 1.473e-25, 1.209e-25, 9.423e-26,
])

#: US standard ozone profile (Anderson et al. 1986): geometric height [km] and volume mixing ratio [ppmv].
US_STANDARD_OZONE_PPMV = np.array([
    (0.0, 0.02660), (1.0, 0.02931), (2.0, 0.03237), (3.0, 0.03318), (4.0, 0.03387), (5.0, 0.03768),
    (6.0, 0.04112), (7.0, 0.05009), (8.0, 0.05966), (9.0, 0.09168), (10.0, 0.1313), (11.0, 0.2149),
    (12.0, 0.3095), (13.0, 0.3846), (14.0, 0.5030), (15.0, 0.6505), (16.0, 0.8701), (17.0, 1.187),
    (18.0, 1.587), (19.0, 2.030), (20.0, 2.579), (21.0, 3.028), (22.0, 3.647), (23.0, 4.168), (24.0, 4.627),
    (25.0, 5.118), (27.5, 5.803), (30.0, 6.553), (32.5, 7.373), (35.0, 7.837), (37.5, 7.800), (40.0, 7.300),
    (42.5, 6.200), (45.0, 5.250), (47.5, 4.100), (50.0, 3.100), (55.0, 1.800), (60.0, 1.100), (65.0, 0.7000),
    (70.0, 0.3000), (75.0, 0.2500), (80.0, 0.3000), (85.0, 0.5000), (90.0, 0.7000), (95.0, 0.7000),
    (100.0, 0.4000),
])


def ozone_cross_section(wavelength_nm):
    """Ozone absorption cross section at 233 K, 10 nm band mean.

    Parameters
    ----------
    wavelength_nm : array_like
        Wavelengths [nm], any shape, within 405-695 nm.

    Returns
    -------
    numpy.ndarray
        Cross section [m2 molecule-1], shape of ``wavelength_nm``.

    Raises
    ------
    SwimInputError
        A wavelength outside 405-695 nm (the centres of the tabulated bins) or not finite.

    References
    ----------
    Serdyuchenko et al. (2014), doi:10.5194/amt-7-625-2014; Gorshelev et al. (2014), doi:10.5194/amt-7-609-2014.
    """
    lam = np.asarray(wavelength_nm, dtype=float)
    lo, hi = CROSS_SECTION_WAVELENGTHS_NM[0], CROSS_SECTION_WAVELENGTHS_NM[-1]
    if np.any(~np.isfinite(lam)) or np.any((lam < lo) | (lam > hi)):
        raise SwimInputError(f"wavelength_nm for the ozone cross section must be within {lo:.0f}-{hi:.0f} nm; "
                             f"got {wavelength_nm!r}")
    return np.interp(lam, CROSS_SECTION_WAVELENGTHS_NM, CROSS_SECTION_233K_M2)


def _standard_number_density(height_m):
    """Ozone number density [m-3] of the US standard profile at heights [m] (0-100 km)."""
    z = np.clip(np.asarray(height_m, dtype=float), 0.0, 100_000.0)
    ppmv = np.interp(z, US_STANDARD_OZONE_PPMV[:, 0] * 1e3, US_STANDARD_OZONE_PPMV[:, 1])
    _, _, n_air = us_standard_atmosphere_1976(z)
    return ppmv * 1e-6 * n_air


def _standard_column_du():
    """Column of the US standard profile [DU] (trapezoid on 10 m steps)."""
    z = np.linspace(0.0, 100_000.0, 10_001)
    return float(np.trapezoid(_standard_number_density(z), z) / DOBSON_UNIT_M2)


#: Column of the US standard ozone profile, 0-100 km [DU].
US_STANDARD_OZONE_DU = round(_standard_column_du(), 1)


def ozone_number_density(height_m, column_du=None):
    """Ozone number density of the US standard profile, scaled to a column.

    Parameters
    ----------
    height_m : array_like
        Geometric heights [m], any shape (clamped to 0-100 km).
    column_du : float, optional
        Ozone column 0-100 km [DU], 0-1000; None: the profile's own (:data:`US_STANDARD_OZONE_DU`).

    Returns
    -------
    numpy.ndarray
        Number density [m-3], shape of ``height_m``.

    Raises
    ------
    SwimInputError
        A column outside 0-1000 DU or not finite.

    References
    ----------
    Anderson et al. (1986), AFGL-TR-86-0110 (U.S. standard ozone); U.S. Standard Atmosphere 1976 (air density).
    """
    n = _standard_number_density(height_m)
    if column_du is None:
        return n
    c = float(column_du)
    if not (np.isfinite(c) and 0.0 <= c <= 1000.0):
        raise SwimInputError(f"ozone column must be 0-1000 DU (Dobson units); got {column_du!r}")
    return n * (c / _standard_column_du())


def ozone_column_du(heights_m, number_density_m3):
    """Vertical column [DU] of an ozone profile (trapezoid rule).

    Parameters
    ----------
    heights_m : array_like
        Shape (n,): increasing heights [m].
    number_density_m3 : array_like
        Shape (n,): ozone number density [m-3].

    Returns
    -------
    float
        Column [DU].
    """
    return float(np.trapezoid(np.asarray(number_density_m3, float), np.asarray(heights_m, float)) / DOBSON_UNIT_M2)


def ozone_absorption_coefficient(heights_m, wavelengths_nm, column_du=None):
    """Absorption coefficient of ozone: a height profile times a spectrum.

    Parameters
    ----------
    heights_m : array_like
        Shape (n_h,): geometric heights [m] (clamped to 0-100 km).
    wavelengths_nm : array_like
        Shape (C,): wavelengths [nm], 405-695.
    column_du : float, optional
        Ozone column [DU]; None: the US standard column (:data:`US_STANDARD_OZONE_DU`).

    Returns
    -------
    numpy.ndarray
        Shape (n_h, C): absorption coefficient [m-1].

    Raises
    ------
    SwimInputError
        A wavelength outside 405-695 nm or a column outside 0-1000 DU.

    References
    ----------
    Serdyuchenko et al. (2014), doi:10.5194/amt-7-625-2014; Anderson et al. (1986), AFGL-TR-86-0110.
    """
    sigma = ozone_cross_section(np.atleast_1d(np.asarray(wavelengths_nm, dtype=float)))
    n = ozone_number_density(np.asarray(heights_m, dtype=float), column_du)
    return n[:, None] * sigma[None, :]
