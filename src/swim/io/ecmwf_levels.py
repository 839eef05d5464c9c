"""The ECMWF L137 hybrid sigma-pressure level definition and the hypsometric heights of pressure and model levels.

The 137-level vertical grid of the IFS (operational since June 2013) and of ERA5: the pressure of half level
``k + 1/2`` (k = 0 the model top, 137 the surface) is ``p = a[k] + b[k] p_s`` [Pa]. The coefficients below are
ECMWF's published table, "L137 model level definitions" (https://confluence.ecmwf.int/display/UDOC/L137+model+level+definitions);
a GRIB message on hybrid levels carries the same numbers in its ``pv`` array (first the 138 ``a``, then the 138 ``b``),
which :func:`hybrid_coefficients_from_pv` splits.

Heights (geometric, metres above sea level) come from the hypsometric equation with the virtual (density)
temperature, integrated upward from the surface:

* model levels: the IFS's own discretisation (ECMWF IFS Documentation Cy47r3, Part III: Dynamics and numerical
  procedures, Chap. 2, Eqs. 2.20-2.23; the same as ECMWF's ``compute_geopotential_on_ml.py``):
  ``Phi_{k+1/2} = Phi_s + sum_{j>k} R_d T_v,j ln(p_{j+1/2} / p_{j-1/2})`` and
  ``Phi_k = Phi_{k+1/2} + alpha_k R_d T_v,k`` with ``alpha_k = 1 - p_{k-1/2} / (p_{k+1/2} - p_{k-1/2})
  ln(p_{k+1/2} / p_{k-1/2})`` (``alpha = ln 2`` at the top, where ``p_{1/2} = 0``);
* pressure levels: ``Phi_{k+1} - Phi_k = R_d (T_v,k + T_v,k+1) / 2 ln(p_k / p_{k+1})`` (the trapezoidal rule in
  ln p), starting from the surface pressure at the surface height, or, without them, from the standard sea-level
  pressure 1013.25 hPa at 0 m (see :func:`pressure_level_heights` for the error this makes);
* geopotential to geometric height: :func:`swim.io.grib.geometric_height`.
"""

from __future__ import annotations

import numpy as np

from ..constants import EPSILON_WATER_VAPOUR, R_DRY_AIR, STANDARD_GRAVITY
from ..errors import SwimInputError
from .grib import geometric_height

__all__ = [
    "L137_A",
    "L137_B",
    "STANDARD_SEA_LEVEL_PRESSURE_PA",
    "density_temperature",
    "air_density",
    "hybrid_coefficients_from_pv",
    "half_level_pressure",
    "model_level_heights",
    "pressure_level_heights",
]

#: Standard sea-level pressure [Pa] (U.S. Standard Atmosphere 1976): the assumed surface of a pressure-level file
#: without surface pressure and geopotential.
STANDARD_SEA_LEVEL_PRESSURE_PA = 101_325.0

#: L137 half-level coefficients ``a`` [Pa], index 0 = model top (k + 1/2 = 1/2) to 137 = surface (ECMWF, "L137
#: model level definitions").
L137_A = np.array([
    0.000000, 2.000365, 3.102241, 4.666084, 6.827977, 9.746966, 13.605424,
    18.608931, 24.985718, 32.985710, 42.879242, 54.955463, 69.520576,
    86.895882, 107.415741, 131.425507, 159.279404, 191.338562, 227.968948,
    269.539581, 316.420746, 368.982361, 427.592499, 492.616028, 564.413452,
    643.339905, 729.744141, 823.967834, 926.344910, 1037.201172, 1156.853638,
    1285.610352, 1423.770142, 1571.622925, 1729.448975, 1897.519287,
    2076.095947, 2265.431641, 2465.770508, 2677.348145, 2900.391357,
    3135.119385, 3381.743652, 3640.468262, 3911.490479, 4194.930664,
    4490.817383, 4799.149414, 5119.895020, 5452.990723, 5798.344727,
    6156.074219, 6526.946777, 6911.870605, 7311.869141, 7727.412109,
    8159.354004, 8608.525391, 9076.400391, 9562.682617, 10065.978516,
    10584.631836, 11116.662109, 11660.067383, 12211.547852, 12766.873047,
    13324.668945, 13881.331055, 14432.139648, 14975.615234, 15508.256836,
    16026.115234, 16527.322266, 17008.789063, 17467.613281, 17901.621094,
    18308.433594, 18685.718750, 19031.289063, 19343.511719, 19620.042969,
    19859.390625, 20059.931641, 20219.664063, 20337.863281, 20412.308594,
    20442.078125, 20425.718750, 20361.816406, 20249.511719, 20087.085938,
    19874.025391, 19608.572266, 19290.226563, 18917.460938, 18489.707031,
    18006.925781, 17471.839844, 16888.687500, 16262.046875, 15596.695313,
    14898.453125, 14173.324219, 13427.769531, 12668.257813, 11901.339844,
    11133.304688, 10370.175781, 9617.515625, 8880.453125, 8163.375000,
    7470.343750, 6804.421875, 6168.531250, 5564.382813, 4993.796875,
    4457.375000, 3955.960938, 3489.234375, 3057.265625, 2659.140625,
    2294.242188, 1961.500000, 1659.476563, 1387.546875, 1143.250000,
    926.507813, 734.992188, 568.062500, 424.414063, 302.476563, 202.484375,
    122.101563, 62.781250, 22.835938, 3.757813, 0.000000, 0.000000,
])
#: L137 half-level coefficients ``b`` [-], index 0 = model top to 137 = surface.
L137_B = np.array([0.0] * 55 + [
    0.000007, 0.000024, 0.000059, 0.000112, 0.000199, 0.000340, 0.000562, 0.000890,
    0.001353, 0.001992, 0.002857, 0.003971, 0.005378, 0.007133, 0.009261,
    0.011806, 0.014816, 0.018318, 0.022355, 0.026964, 0.032176, 0.038026,
    0.044548, 0.051773, 0.059728, 0.068448, 0.077958, 0.088286, 0.099462,
    0.111505, 0.124448, 0.138313, 0.153125, 0.168910, 0.185689, 0.203491,
    0.222333, 0.242244, 0.263242, 0.285354, 0.308598, 0.332939, 0.358254,
    0.384363, 0.411125, 0.438391, 0.466003, 0.493800, 0.521619, 0.549301,
    0.576692, 0.603648, 0.630036, 0.655736, 0.680643, 0.704669, 0.727739,
    0.749797, 0.770798, 0.790717, 0.809536, 0.827256, 0.843881, 0.859432,
    0.873929, 0.887408, 0.899900, 0.911448, 0.922096, 0.931881, 0.940860,
    0.949064, 0.956550, 0.963352, 0.969513, 0.975078, 0.980072, 0.984542,
    0.988500, 0.991984, 0.995003, 0.997630, 1.000000,
])


def density_temperature(temperature, specific_humidity, condensate=0.0):
    """Virtual (density) temperature [K] of moist air carrying condensate.

    Parameters
    ----------
    temperature : array_like
        [K].
    specific_humidity : array_like
        [kg kg-1] of moist air, broadcastable with ``temperature``.
    condensate : array_like
        Total condensate (cloud liquid, ice, rain, snow) [kg kg-1] of moist air; 0 gives the virtual temperature.

    Returns
    -------
    numpy.ndarray
        ``T_rho = T (1 + (1/eps - 1) q - q_c)`` [K], eps = :data:`swim.constants.EPSILON_WATER_VAPOUR`: the
        temperature for which ``p = rho R_d T_rho`` holds with ``rho`` the density of the whole mixture (dry air,
        vapour and condensate), since ``p = rho T (R_d (1 - q - q_c) + R_v q)``.

    References
    ----------
    Emanuel, K. A. (1994), Atmospheric Convection, Oxford University Press, Eq. 4.3.6 (density temperature);
    Wallace and Hobbs (2006), Atmospheric Science, 2nd ed., Eq. 3.59 (virtual temperature).
    """
    t = np.asarray(temperature, dtype=float)
    q = np.asarray(specific_humidity, dtype=float)
    return t * (1.0 + (1.0 / EPSILON_WATER_VAPOUR - 1.0) * q - np.asarray(condensate, dtype=float))


def air_density(pressure, temperature, specific_humidity, condensate=0.0):
    """Density [kg m-3] of moist air with its condensate: ``rho = p / (R_d T_rho)``
    (:func:`density_temperature`).

    Parameters
    ----------
    pressure : array_like
        [Pa].
    temperature, specific_humidity, condensate : array_like
        As :func:`density_temperature` ([K], [kg kg-1], [kg kg-1]), broadcastable with ``pressure``.

    Returns
    -------
    numpy.ndarray
        [kg m-3]. A mass mixing ratio per kg of moist air (ERA5/IFS ``clwc``, ``ciwc``, ``crwc``, ``cswc``)
        times this density is the mass content [kg m-3].
    """
    return np.asarray(pressure, dtype=float) / (R_DRY_AIR * density_temperature(temperature, specific_humidity,
                                                                               condensate))


def hybrid_coefficients_from_pv(pv):
    """The half-level ``a`` [Pa] and ``b`` [-] of a GRIB ``pv`` array (``a`` then ``b``, top first).

    Parameters
    ----------
    pv : array_like
        Shape (2 (nlev + 1),): the GRIB key ``pv`` of a message on hybrid levels.

    Returns
    -------
    a, b : numpy.ndarray
        Shape (nlev + 1,) each, index 0 at the model top.

    Raises
    ------
    SwimInputError
        If ``pv`` has an odd or too small length, or ``b`` does not end at 1 (the surface).
    """
    pv = np.asarray(pv, dtype=float).ravel()
    if pv.size < 4 or pv.size % 2:
        raise SwimInputError(f"GRIB pv: {pv.size} values; expected 2 (nlev + 1) hybrid coefficients (a [Pa], b)")
    a, b = pv[: pv.size // 2], pv[pv.size // 2:]
    if abs(b[-1] - 1.0) > 1e-6 or abs(a[-1]) > 1e-3:
        raise SwimInputError(f"GRIB pv: the last half level has a = {a[-1]:g} Pa, b = {b[-1]:g}; expected the surface "
                             "(a = 0, b = 1)")
    return a, b


def half_level_pressure(surface_pressure, a=L137_A, b=L137_B):
    """Half-level pressures [Pa] of a hybrid sigma-pressure grid, ``p_{k+1/2} = a_k + b_k p_s``.

    Parameters
    ----------
    surface_pressure : array_like
        Any shape S [Pa] (``exp(lnsp)`` for ``lnsp``).
    a, b : array_like
        Shape (nlev + 1,): the half-level coefficients [Pa] and [-], top first; default L137.

    Returns
    -------
    numpy.ndarray
        Shape (nlev + 1,) + S [Pa], top first.

    Raises
    ------
    SwimInputError
        If the surface pressure is not in [3e4, 1.2e5] Pa (hPa or ln p given instead).
    """
    ps = np.asarray(surface_pressure, dtype=float)
    if ps.size and not (np.all(ps >= 3.0e4) and np.all(ps <= 1.2e5)):
        raise SwimInputError(f"surface pressure in [{np.min(ps):.4g}, {np.max(ps):.4g}]: expected Pa in [3e4, 1.2e5] "
                             "(hPa must be multiplied by 100; lnsp must be exponentiated)")
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    shape = (a.size,) + (1,) * ps.ndim
    return a.reshape(shape) + b.reshape(shape) * ps[None]


def model_level_heights(half_pressure, temperature, specific_humidity, surface_geopotential, condensate=0.0):
    """Geometric heights [m above sea level] of the full (mass) levels of a hybrid grid, top first.

    Parameters
    ----------
    half_pressure : array_like
        Shape (nlev + 1, ...) [Pa], top first (index 0 the model top, 0 Pa allowed; the last the surface).
    temperature, specific_humidity : array_like
        Shape (nlev, ...) [K], [kg kg-1], top first.
    surface_geopotential : array_like
        Shape (...) [m2 s-2] (orography times g).
    condensate : array_like
        Shape (nlev, ...) total condensate [kg kg-1] (:func:`density_temperature`); default 0 (the IFS's own
        geopotential uses the virtual temperature of vapour only).

    Returns
    -------
    numpy.ndarray
        Shape (nlev, ...) [m], top first: ``Phi_k / g`` (IFS Documentation Cy47r3, Part III, Eqs. 2.20-2.23)
        converted by :func:`swim.io.grib.geometric_height`.
    """
    ph = np.asarray(half_pressure, dtype=float)
    tv = density_temperature(temperature, specific_humidity, condensate)
    nlev = tv.shape[0]
    if ph.shape[0] != nlev + 1:
        raise SwimInputError(f"half-level pressure has {ph.shape[0]} levels for {nlev} full levels; expected nlev + 1")
    upper, lower = ph[:-1], ph[1:]
    safe_upper = np.where(upper > 0, upper, 1.0)
    dlnp = np.where(upper > 0, np.log(lower / safe_upper), 0.0)
    alpha = np.where(upper > 0, 1.0 - upper / (lower - upper) * dlnp, np.log(2.0))
    # geopotential of the half level below each full level: the surface plus the layers under it
    layer = R_DRY_AIR * tv * dlnp
    below = np.asarray(surface_geopotential, dtype=float)[None] + np.cumsum(layer[::-1], axis=0)[::-1] - layer
    phi = below + alpha * R_DRY_AIR * tv
    return geometric_height(phi / STANDARD_GRAVITY)


def pressure_level_heights(pressure, temperature, specific_humidity, surface_pressure=None,
                           surface_geopotential=None):
    """Geometric heights [m above sea level] of pressure levels by the hypsometric equation, integrated upward.

    Parameters
    ----------
    pressure : array_like
        Shape (nz,) [Pa], strictly decreasing (the lowest level first).
    temperature, specific_humidity : array_like
        Shape (nz, ...) [K], [kg kg-1].
    surface_pressure : array_like, optional
        Shape (...) [Pa].
    surface_geopotential : array_like, optional
        Shape (...) [m2 s-2]; default 0 (sea level).

    Returns
    -------
    numpy.ndarray
        Shape (nz, ...) [m]. The lowest level lies ``R_d T_v,0 / g ln(p_s / p_0)`` above the surface (negative
        under it: extrapolated levels), with the lowest level's virtual temperature. Without ``surface_pressure``
        the surface is the standard sea-level pressure :data:`STANDARD_SEA_LEVEL_PRESSURE_PA` at 0 m (whatever
        ``surface_geopotential``): the 1000 hPa height is then about 110 m, where the true one follows the
        mean-sea-level pressure by about 8 m hPa-1 (-300 m at 975 hPa, +200 m at 1040 hPa). This error shifts
        the whole column by the same amount, not its thicknesses.

    Raises
    ------
    SwimInputError
        If the pressures do not decrease strictly.
    """
    p = np.asarray(pressure, dtype=float)
    if p.ndim != 1 or p.size < 2 or np.any(np.diff(p) >= 0):
        raise SwimInputError("pressure levels must decrease strictly from the lowest level [Pa]")
    tv = density_temperature(temperature, specific_humidity)
    shape = (p.size,) + (1,) * (tv.ndim - 1)
    if surface_pressure is None:
        ps, phi_s = STANDARD_SEA_LEVEL_PRESSURE_PA, 0.0
    else:
        ps = np.asarray(surface_pressure, dtype=float)
        phi_s = 0.0 if surface_geopotential is None else np.asarray(surface_geopotential, dtype=float)
    phi0 = phi_s + R_DRY_AIR * tv[0] * np.log(ps / p[0])
    dlnp = np.log(p[:-1] / p[1:]).reshape((p.size - 1,) + shape[1:])
    steps = R_DRY_AIR * 0.5 * (tv[:-1] + tv[1:]) * dlnp
    phi = np.concatenate([phi0[None] * np.ones_like(tv[:1]), phi0[None] + np.cumsum(steps, axis=0)], axis=0)
    return geometric_height(phi / STANDARD_GRAVITY)
