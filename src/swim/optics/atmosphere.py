"""U.S. Standard Atmosphere 1976 (US76) profile of temperature, pressure and number density, 0-100 km.

Source: U.S. Standard Atmosphere, 1976, NOAA-S/T 76-1562 (NOAA, NASA, USAF, Washington DC), Part 1,
Sects. 1.2-1.3 (defining constants, the seven geopotential layers up to 84.852 km, the molecular-weight
ratio table 80-86 km) and Sect. 1.3.2 (kinetic temperature above 86 km).

Below 86 km geometric height (84.852 km geopotential) this is the Standard's own closed form: the molecular-
scale temperature T_M is piecewise linear in geopotential height H = r0 Z / (r0 + Z), the pressure follows
from the hydrostatic equation with constant molecular weight M0, and the kinetic temperature is
T = T_M M/M0 (M/M0 < 1 only between 80 and 86 km).

Above 86 km the Standard computes the number densities of N2, O, O2, Ar, He and H from diffusion equations,
which is overkill for a visible-light renderer (the column above 86 km holds ~4e-6 of the air). Our
extension to 100 km uses the Standard's kinetic temperature (isothermal 86-91 km, then its elliptical arc
91-110 km) and integrates the hydrostatic equation numerically (trapezoid rule, 50 m steps) with gravity
g0 (r0 / (r0 + Z))**2 and the constant mean molecular weight of 86 km. Because real diffusive separation
lowers M above 86 km (M = 28.40 kg/kmol at 100 km), this extension underestimates the pressure by 0.13 % at
90 km, 0.46 % at 95 km and 0.64 % at 100 km (published: 0.18359, 0.075966, 0.032011 Pa).
"""

from __future__ import annotations

import logging

import numpy as np

from ..errors import SwimInputError

_log = logging.getLogger(__name__)

#: US76 effective earth radius used for geopotential height [m].
US76_EARTH_RADIUS_M = 6_356_766.0
#: US76 sea-level gravity [m s-2].
US76_G0 = 9.80665
#: US76 sea-level mean molecular weight of air [kg kmol-1].
US76_M0 = 28.9644
#: US76 universal gas constant [J kmol-1 K-1] (the Standard's value, not CODATA).
US76_R_STAR = 8314.32
#: US76 Boltzmann constant [J K-1] (the Standard's value, so that sea-level n = 2.5470e25 m-3).
US76_BOLTZMANN = 1.380622e-23
#: Lowest and highest geometric height accepted [m]: the Standard starts at -5 km; SWIm's model top is 100 km.
HEIGHT_RANGE_M = (-5_000.0, 100_000.0)

# Layer bases in geopotential height [m'] and molecular-scale temperature gradients [K m'-1] (US76 Table 4).
_H_BASE = np.array([0.0, 11_000.0, 20_000.0, 32_000.0, 47_000.0, 51_000.0, 71_000.0, 84_852.0])
_LAPSE = np.array([-6.5e-3, 0.0, 1.0e-3, 2.8e-3, 0.0, -2.8e-3, -2.0e-3])

# Molecular-weight ratio M/M0 at geometric heights 80.0 ... 86.0 km every 0.5 km (US76 Table 8): it turns
# the molecular-scale temperature into the kinetic temperature (a <0.05 % effect).
_M_RATIO_Z = np.arange(80_000.0, 86_000.0 + 1.0, 500.0)
_M_RATIO = np.array([1.000000, 0.999996, 0.999989, 0.999971, 0.999941, 0.999909, 0.999870,
                     0.999829, 0.999786, 0.999741, 0.999694, 0.999641, 0.999579])

# Kinetic temperature above 86 km (US76 Sect. 1.3.2): isothermal to 91 km, then an elliptical arc.
_T7 = 186.8673  # [K] at 86 km
_Z8 = 91_000.0  # [m]
_TC, _A_ELL, _a_ELL = 263.1905, -76.3232, -19_942.9  # [K], [K], [m]


def _base_temperatures_pressures():
    """Molecular-scale temperature and pressure at the base of each geopotential layer (US76 Table 4)."""
    t_b = [288.15]
    p_b = [101_325.0]
    for i, lapse in enumerate(_LAPSE):
        dh = _H_BASE[i + 1] - _H_BASE[i]
        t_top = t_b[i] + lapse * dh
        if lapse == 0.0:
            p_top = p_b[i] * np.exp(-US76_G0 * US76_M0 * dh / (US76_R_STAR * t_b[i]))
        else:
            p_top = p_b[i] * (t_b[i] / t_top) ** (US76_G0 * US76_M0 / (US76_R_STAR * lapse))
        t_b.append(t_top)
        p_b.append(p_top)
    return np.array(t_b), np.array(p_b)


_T_BASE, _P_BASE = _base_temperatures_pressures()


def _lower_atmosphere(z):
    """Kinetic temperature [K] and pressure [Pa] for geometric heights z <= 86 km [m]."""
    h = US76_EARTH_RADIUS_M * z / (US76_EARTH_RADIUS_M + z)
    i = np.clip(np.searchsorted(_H_BASE, h, side="right") - 1, 0, len(_LAPSE) - 1)
    lapse, t_b, p_b, dh = _LAPSE[i], _T_BASE[i], _P_BASE[i], h - _H_BASE[i]
    t_m = t_b + lapse * dh
    isothermal = lapse == 0.0
    safe_lapse = np.where(isothermal, 1.0, lapse)
    p = np.where(
        isothermal,
        p_b * np.exp(-US76_G0 * US76_M0 * dh / (US76_R_STAR * t_b)),
        p_b * (t_b / t_m) ** (US76_G0 * US76_M0 / (US76_R_STAR * safe_lapse)),
    )
    m_ratio = np.interp(z, _M_RATIO_Z, _M_RATIO, left=1.0, right=_M_RATIO[-1])
    return t_m * m_ratio, p


def _upper_temperature(z):
    """US76 kinetic temperature [K] for 86 km <= z <= 110 km geometric [m]."""
    arg = np.clip(1.0 - ((z - _Z8) / _a_ELL) ** 2, 0.0, 1.0)
    return np.where(z < _Z8, _T7, _TC + _A_ELL * np.sqrt(arg))


def _upper_log_pressure_table():
    """ln p on a 50 m grid 86-100 km: hydrostatic integration with constant M(86 km) (module docstring)."""
    z = np.linspace(86_000.0, 100_000.0, 281)
    m = US76_M0 * _M_RATIO[-1]
    g = US76_G0 * (US76_EARTH_RADIUS_M / (US76_EARTH_RADIUS_M + z)) ** 2
    integrand = m * g / (US76_R_STAR * _upper_temperature(z))
    # trapezoid cumulative integral of d ln p / dz = -M g / (R* T); the integrand is smooth, error < 1e-7
    steps = 0.5 * (integrand[1:] + integrand[:-1]) * np.diff(z)
    _, p86 = _lower_atmosphere(np.array(86_000.0))
    return z, np.log(p86) - np.concatenate([[0.0], np.cumsum(steps)])


_Z_UPPER, _LNP_UPPER = _upper_log_pressure_table()


def us_standard_atmosphere_1976(height_m):
    """Temperature, pressure and number density of the U.S. Standard Atmosphere 1976.

    Parameters
    ----------
    height_m : array_like
        Geometric height above mean sea level [m], any shape, within -5 000 ... 100 000 m.

    Returns
    -------
    temperature : numpy.ndarray
        Kinetic temperature [K], shape of ``height_m``.
    pressure : numpy.ndarray
        Pressure [Pa], shape of ``height_m``.
    number_density : numpy.ndarray
        Air number density n = p / (k T) [m-3], shape of ``height_m``.

    Raises
    ------
    SwimInputError
        If any height is outside -5 km ... 100 km (NaN is passed through).

    Notes
    -----
    Up to 86 km this is the Standard's defining closed form (reproduces its tables: 0 m 288.15 K,
    101 325 Pa, 2.5470e25 m-3; 20 km 216.65 K, 5 529.3 Pa; 86 km 186.87 K, 0.37338 Pa). 86-100 km is the
    documented hydrostatic extension of the module docstring (p(100 km) 0.64 % below the Standard's).
    Density, if needed, is p M0 / (R* T_M), i.e. ``pressure * 28.9644e-3 / (8.31432 * temperature)`` below
    80 km.

    Source: U.S. Standard Atmosphere, 1976, NOAA-S/T 76-1562.
    """
    z = np.asarray(height_m, dtype=float)
    lo, hi = HEIGHT_RANGE_M
    if np.any((z < lo) | (z > hi)):
        bad = z[(z < lo) | (z > hi)]
        raise SwimInputError(
            f"height_m must be a geometric height within {lo:.0f} ... {hi:.0f} m; got values such as {bad.flat[0]!r}"
        )
    upper = z > 86_000.0
    t_low, p_low = _lower_atmosphere(np.minimum(z, 86_000.0))
    t_up = _upper_temperature(np.maximum(z, 86_000.0))
    p_up = np.exp(np.interp(z, _Z_UPPER, _LNP_UPPER))
    temperature = np.where(upper, t_up, t_low)
    pressure = np.where(upper, p_up, p_low)
    number_density = pressure / (US76_BOLTZMANN * temperature)
    return temperature, pressure, number_density
