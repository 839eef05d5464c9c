"""Rayleigh (molecular) scattering of air after Bodhaine et al. (1999).

Source: Bodhaine, B. A., Wood, N. B., Dutton, E. G. and Slusser, J. R. (1999), On Rayleigh optical depth
calculations, J. Atmos. Oceanic Technol. 16, 1854-1861, doi:10.1175/1520-0426(1999)016<1854:ORODC>2.0.CO;2
(referred to as B99). The recipe, from first principles as B99 recommend:

* refractive index of dry air with 300 ppm CO2 from Peck and Reeder (1972) (B99 Eq. 4), scaled to the
  requested CO2 by (n - 1) ∝ 1 + 0.54 (C_CO2 - 0.0003) (B99 Eq. 19, C_CO2 in parts per volume);
* King factor of air: the volume-weighted mean of N2 (1.034 + 3.17e-4 λ^-2), O2
  (1.096 + 1.385e-3 λ^-2 + 1.448e-4 λ^-4), Ar (1.00) and CO2 (1.15) (B99 Eqs. 5, 6 and 23, λ in µm);
* cross section σ = 24 π³ (n² - 1)² / (λ⁴ N_s² (n² + 2)²) F_air, with N_s = 2.546899e19 cm-3 the number
  density of the standard air (288.15 K, 1013.25 hPa) to which n refers (B99 Eq. 22);
* optical depth τ = σ P N_A / (m_a g), with m_a = 15.0556 C_CO2 + 28.9595 g mol-1 the mean molecular weight
  of dry air and g the List (1968) gravity at latitude φ, evaluated at the mass-weighted column height
  z_c = 0.73737 z + 5517.56 m (B99 Sect. 4).

B99's own closed fits (Eq. 29 for σ, Eq. 30 for τ at 1013.25 hPa, 45°, sea level, 360 ppm) are used only as
test references.

The phase function is the Chandrasekhar (1960) form with the molecular anisotropy, normalised to a mean
of 1 over the sphere (the SWIm convention, paper below Eq. 9); it computes in the array library of its inputs
(numpy, or ``jax.numpy`` for JAX arrays and tracers, :mod:`swim.arrays`) so the ray-tracing kernels can call it
inside ``jax.jit`` and the CPU renderer on numpy arrays.
"""

from __future__ import annotations

import logging

import numpy as np

from ..arrays import array_namespace
from ..errors import SwimInputError

_log = logging.getLogger(__name__)

#: Number density of the standard air to which the Peck and Reeder refractive index refers [m-3] (B99).
STANDARD_AIR_NUMBER_DENSITY_M3 = 2.546899e25
#: Avogadro constant as used by B99 [mol-1].
AVOGADRO_B99 = 6.0221367e23
#: Validity range of the Peck and Reeder (1972) dispersion formula [nm].
WAVELENGTH_RANGE_NM = (230.0, 1690.0)
#: Depolarisation ratio of air at the SWIm green reference wavelength 546 nm from the B99 King factor
#: (``rayleigh_depolarization_ratio(546.0)`` = 0.02834, 360 ppm CO2); default of the phase function.
DEPOLARIZATION_546NM = 0.02834


def _check_wavelength(wavelength_nm):
    lam = np.asarray(wavelength_nm, dtype=float)
    lo, hi = WAVELENGTH_RANGE_NM
    if np.any(~np.isfinite(lam)) or np.any((lam < lo) | (lam > hi)):
        raise SwimInputError(
            f"wavelength_nm must be finite and within {lo:.0f} ... {hi:.0f} nm (range of the Peck and Reeder "
            f"refractive index used by Bodhaine et al. 1999); got {wavelength_nm!r}"
        )
    return lam


def _check_co2(co2_ppm):
    c = np.asarray(co2_ppm, dtype=float)
    if np.any(~np.isfinite(c)) or np.any((c < 0.0) | (c > 1e5)):
        raise SwimInputError(f"co2_ppm must be a CO2 mixing ratio within 0 ... 1e5 ppm by volume; got {co2_ppm!r}")
    return c


def _refractive_index_minus_one(lam_um, co2_ppm):
    """(n - 1) of dry standard air (288.15 K, 1013.25 hPa) with the given CO2 (B99 Eq. 4 and CO2 scaling)."""
    s2 = lam_um**-2
    n300 = (8060.51 + 2_480_990.0 / (132.274 - s2) + 17_455.7 / (39.32957 - s2)) * 1e-8
    return n300 * (1.0 + 0.54 * (co2_ppm * 1e-6 - 0.0003))


def _king_factor_air(lam_um, co2_ppm):
    """King correction factor F_air [-] of air (B99 Eqs. 5, 6 and 23; CO2 in percent by volume)."""
    s2 = lam_um**-2
    f_n2 = 1.034 + 3.17e-4 * s2
    f_o2 = 1.096 + 1.385e-3 * s2 + 1.448e-4 * s2**2
    c_pct = co2_ppm * 1e-4
    return (78.084 * f_n2 + 20.946 * f_o2 + 0.934 * 1.00 + c_pct * 1.15) / (78.084 + 20.946 + 0.934 + c_pct)


def rayleigh_cross_section_bodhaine1999(wavelength_nm, co2_ppm=360.0):
    """Rayleigh scattering cross section of one air molecule.

    Parameters
    ----------
    wavelength_nm : array_like
        Vacuum wavelength [nm], any shape, within 230 ... 1690 nm.
    co2_ppm : array_like, optional
        CO2 volume mixing ratio [ppm]; broadcasts with ``wavelength_nm``. Default 360 (B99's reference).

    Returns
    -------
    numpy.ndarray
        Cross section σ [m2 molecule-1], shape ``broadcast(wavelength_nm, co2_ppm)``.

    Raises
    ------
    SwimInputError
        If a wavelength is outside 230 ... 1690 nm or the CO2 mixing ratio is negative or absurd.

    Notes
    -----
    σ(550 nm) = 4.5105e-31 m2 (360 ppm); it agrees with the B99 fit (their Eq. 29,
    σ [1e-28 cm2] = (1.0455996 - 341.29061 λ^-2 - 0.90230850 λ²) / (1 + 0.0027059889 λ^-2 - 85.968563 λ²))
    to 1e-4 over 250-850 nm.

    Source: Bodhaine et al. (1999), Eqs. 4, 5, 6, 19, 22, 23; doi:10.1175/1520-0426(1999)016<1854:ORODC>2.0.CO;2.
    """
    lam_um = _check_wavelength(wavelength_nm) * 1e-3
    co2 = _check_co2(co2_ppm)
    nm1 = _refractive_index_minus_one(lam_um, co2)
    n2 = (1.0 + nm1) ** 2
    lam_m = lam_um * 1e-6
    return (
        24.0 * np.pi**3 * (n2 - 1.0) ** 2
        / (lam_m**4 * STANDARD_AIR_NUMBER_DENSITY_M3**2 * (n2 + 2.0) ** 2)
        * _king_factor_air(lam_um, co2)
    )


def rayleigh_optical_depth_bodhaine1999(
    wavelength_nm, pressure_pa=101_325.0, latitude_deg=45.0, altitude_m=0.0, co2_ppm=360.0
):
    """Rayleigh optical depth of the atmospheric column above a site.

    Parameters
    ----------
    wavelength_nm : array_like
        Vacuum wavelength [nm], within 230 ... 1690 nm.
    pressure_pa : array_like, optional
        Surface pressure at the site [Pa] (> 0). Default 101 325 Pa.
    latitude_deg : array_like, optional
        Geodetic latitude [deg], -90 ... 90. Default 45.
    altitude_m : array_like, optional
        Site altitude above sea level [m] (enters the effective gravity only). Default 0.
    co2_ppm : array_like, optional
        CO2 volume mixing ratio [ppm]. Default 360.

    Returns
    -------
    numpy.ndarray
        Vertical Rayleigh optical depth τ_R [-], shape of the broadcast inputs.

    Raises
    ------
    SwimInputError
        On a wavelength outside 230 ... 1690 nm, a non-positive pressure, a latitude outside ±90° or a
        non-finite altitude.

    Notes
    -----
    τ = σ P N_A / (m_a g) with g the List (1968) gravity [cm s-2]
    g0 = 980.6160 (1 - 0.0026373 cos 2φ + 0.0000059 cos² 2φ) evaluated at the mass-weighted column height
    z_c = 0.73737 z + 5517.56 m. Reproduces B99 Table 3 (1013.25 hPa, 45°, sea level, 360 ppm) to 1.2e-4
    (400 nm: 0.36022, 550 nm: 0.09707, 700 nm: 0.03642, see docs/phase-functions.md).

    Source: Bodhaine et al. (1999), Sect. 4 (τ = σ P A / (m_a g), List 1968 gravity);
    doi:10.1175/1520-0426(1999)016<1854:ORODC>2.0.CO;2.
    """
    sigma_cm2 = rayleigh_cross_section_bodhaine1999(wavelength_nm, co2_ppm) * 1e4
    p = np.asarray(pressure_pa, dtype=float)
    lat = np.asarray(latitude_deg, dtype=float)
    z = np.asarray(altitude_m, dtype=float)
    if np.any(~np.isfinite(p)) or np.any(p <= 0.0):
        raise SwimInputError(f"pressure_pa must be a positive pressure [Pa]; got {pressure_pa!r}")
    if np.any(~np.isfinite(lat)) or np.any(np.abs(lat) > 90.0):
        raise SwimInputError(f"latitude_deg must be within -90 ... 90 deg; got {latitude_deg!r}")
    if np.any(~np.isfinite(z)):
        raise SwimInputError(f"altitude_m must be a finite height [m]; got {altitude_m!r}")
    co2 = np.asarray(co2_ppm, dtype=float)
    c2 = np.cos(np.deg2rad(2.0 * lat))
    g0 = 980.6160 * (1.0 - 0.0026373 * c2 + 0.0000059 * c2**2)
    zc = 0.73737 * z + 5517.56
    g = (
        g0
        - (3.085462e-4 + 2.27e-7 * c2) * zc
        + (7.254e-11 + 1.0e-13 * c2) * zc**2
        - (1.517e-17 + 6.0e-20 * c2) * zc**3
    )  # [cm s-2]
    m_a = 15.0556 * co2 * 1e-6 + 28.9595  # [g mol-1]
    p_cgs = p * 10.0  # [dyn cm-2]
    return sigma_cm2 * p_cgs * AVOGADRO_B99 / (m_a * g)


def rayleigh_depolarization_ratio(wavelength_nm, co2_ppm=360.0):
    """Depolarisation ratio ρ of air from the Bodhaine et al. (1999) King factor.

    Parameters
    ----------
    wavelength_nm : array_like
        Vacuum wavelength [nm], within 230 ... 1690 nm.
    co2_ppm : array_like, optional
        CO2 volume mixing ratio [ppm]. Default 360.

    Returns
    -------
    numpy.ndarray
        ρ [-] (0.02834 at 546 nm), shape of the broadcast inputs.

    Raises
    ------
    SwimInputError
        On a wavelength outside 230 ... 1690 nm.

    Notes
    -----
    Inverts F = (6 + 3ρ) / (6 - 7ρ): ρ = 6 (F - 1) / (3 + 7 F).

    Source: Bodhaine et al. (1999), Eq. 23 and the King-factor definition;
    doi:10.1175/1520-0426(1999)016<1854:ORODC>2.0.CO;2.
    """
    lam_um = _check_wavelength(wavelength_nm) * 1e-3
    f = _king_factor_air(lam_um, _check_co2(co2_ppm))
    return 6.0 * (f - 1.0) / (3.0 + 7.0 * f)


def rayleigh_phase_function(cos_theta, depolarization=DEPOLARIZATION_546NM):
    """Rayleigh phase function with molecular anisotropy, mean 1 over the sphere.

    Parameters
    ----------
    cos_theta : array_like
        Cosine of the scattering angle θ [-] (θ = 0 forward, see :mod:`swim.frames`); numpy or JAX, any shape.
    depolarization : array_like, optional
        Depolarisation ratio ρ [-], broadcasts with ``cos_theta``. Default 0.02834 (air at 546 nm).

    Returns
    -------
    numpy.ndarray or jax.Array
        P(θ) = 3 / (4 (1 + 2γ)) ((1 + 3γ) + (1 - γ) cos²θ) with γ = ρ / (2 - ρ), shape of the broadcast
        inputs; its integral over 4π sr is 4π. ρ = 0 gives the classical 3/4 (1 + cos²θ).

    Notes
    -----
    Computes in the array library of the inputs: numpy for numpy input, JAX-traceable (float32 inside
    ``jax.jit``) for JAX input; no input checks. Source: Chandrasekhar, S. (1960), Radiative
    Transfer (Dover), Sect. 18; the γ form as in Hansen, J. E. and Travis, L. D. (1974), Space Sci. Rev. 16,
    527-610, doi:10.1007/BF00168069, Sect. 2, rescaled to the SWIm normalisation (mean 1 over the sphere).
    """
    xp = array_namespace(cos_theta, depolarization)
    mu = xp.asarray(cos_theta)
    rho = xp.asarray(depolarization)
    gamma = rho / (2.0 - rho)
    return 0.75 / (1.0 + 2.0 * gamma) * ((1.0 + 3.0 * gamma) + (1.0 - gamma) * mu * mu)
