"""Bulk optical properties of hydrometeors: extinction coefficient and effective radius.

Source: Albers et al. (2020), Atmos. Meas. Tech. 13, 3235-3261, doi:10.5194/amt-13-3235-2020, Eq. 7 and
Sect. 3.4 ("the paper"); Stephens (1978); Martin et al. (1994).

The functions compute in the array library of their inputs (:mod:`swim.arrays`): numpy input is validated
(raising :class:`swim.errors.SwimInputError`) and computed with numpy; JAX arrays, including tracers inside
``jax.jit``, are computed with ``jax.numpy`` without validation, because the ray-tracing kernel evaluates Eq. 7
on trilinearly interpolated contents (paper Sect. 3.4).
"""

from __future__ import annotations

import logging

import numpy as np

from ..arrays import array_namespace, is_jax
from ..constants import DEFAULT_EFFECTIVE_RADIUS, SPECIES
from ..errors import SwimInputError

_log = logging.getLogger(__name__)

#: Martin et al. (1994) ratio k = r_v³ / r_e³ for maritime air masses [-] (continental: 0.67).
MARTIN_K_MARITIME = 0.8
#: Default cloud droplet number concentration [m-3] (100 cm-3, between maritime ~75 and continental ~300).
DEFAULT_DROPLET_NUMBER_M3 = 1e8
#: Density of liquid water [kg m-3].
WATER_DENSITY = 1000.0
#: Range to which the Martin et al. (1994) cloud-liquid effective radius is clipped [m]: 4-20 µm, the span of
#: observed stratiform and cumuliform cloud means (Miles et al. 2000, J. Atmos. Sci. 57, 295-311).
LIQUID_EFFECTIVE_RADIUS_RANGE_M = (4e-6, 20e-6)


def _nonnegative(name, value, units):
    a = np.asarray(value, dtype=float)
    bad = ~np.isfinite(a) | (a < 0.0)
    if np.any(bad):
        raise SwimInputError(f"{name} must be finite and >= 0 [{units}]; got values such as {a[bad].flat[0]!r}")
    return a


def _positive(name, value, units):
    a = np.asarray(value, dtype=float)
    bad = ~np.isfinite(a) | (a <= 0.0)
    if np.any(bad):
        raise SwimInputError(f"{name} must be finite and > 0 [{units}]; got values such as {a[bad].flat[0]!r}")
    return a


def extinction_coefficient_stephens1978(content, effective_radius, density):
    """Volume extinction coefficient of a hydrometeor population (paper Eq. 7).

    Parameters
    ----------
    content : array_like
        Condensed water content CWC (mass of the species per volume of air) [kg m-3], ≥ 0.
    effective_radius : array_like
        Effective radius r_e [m], > 0.
    density : array_like
        Bulk density of the hydrometeor material r_h [kg m-3], > 0
        (:data:`swim.constants.HYDROMETEOR_DENSITY`).

    Returns
    -------
    numpy.ndarray or jax.Array
        β = 1.5 CWC / (r_e r_h) [m-1], broadcast shape (jax array if any input is one).

    Raises
    ------
    SwimInputError
        For numpy input with a negative or non-finite content, or a non-positive radius or density.

    Notes
    -----
    Geometric optics (extinction efficiency 2) for a size distribution with effective radius r_e: β = 2 π ∫ r²
    n(r) dr = (3/2) CWC / (ρ r_e). Example: LWC 0.3 g m-3, r_e = 10 µm: β = 0.045 m-1 = 45 km-1.

    Source: Stephens, G. L. (1978), Radiation profiles in extended water clouds. II: Parameterization
    schemes, J. Atmos. Sci. 35, 2123-2132, doi:10.1175/1520-0469(1978)035<2123:RPIEWC>2.0.CO;2; paper Eq. 7.
    """
    xp = array_namespace(content, effective_radius, density)
    if is_jax(xp):  # no validation: values cannot be inspected under tracing
        return 1.5 * xp.asarray(content) / (xp.asarray(effective_radius) * xp.asarray(density))
    cwc = _nonnegative("content", content, "kg m-3")
    r_e = _positive("effective_radius", effective_radius, "m")
    rho = _positive("density", density, "kg m-3")
    return 1.5 * cwc / (r_e * rho)


def effective_radius_liquid_martin1994(lwc, number_concentration=DEFAULT_DROPLET_NUMBER_M3):
    """Cloud-droplet effective radius from liquid water content and droplet number (Martin et al. 1994).

    Parameters
    ----------
    lwc : array_like
        Cloud liquid water content [kg m-3], ≥ 0.
    number_concentration : array_like, optional
        Droplet number concentration N [m-3], > 0. Default 1e8 m-3 (100 cm-3).

    Returns
    -------
    numpy.ndarray or jax.Array
        r_e = (3 LWC / (4 π ρ_w k N))^{1/3} with k = 0.8 [m], clipped to 4 ... 20 µm; broadcast shape.
        With the default N: 6.7 µm at 0.1 g m-3, 9.6 µm at 0.3 g m-3, 11.4 µm at 0.5 g m-3.

    Raises
    ------
    SwimInputError
        For numpy input with a negative or non-finite LWC or a non-positive number concentration.

    Notes
    -----
    The clip keeps r_e physical where the relation is extrapolated: at cloud edges (LWC → 0 would give
    r_e → 0 and an unbounded β / LWC) and in drizzle-laden cores (sizes beyond 20 µm belong to the rain
    category).

    Source: Martin, G. M., Johnson, D. W. and Spice, A. (1994), The measurement and parameterization of
    effective radius of droplets in warm stratocumulus clouds, J. Atmos. Sci. 51, 1823-1842,
    doi:10.1175/1520-0469(1994)051<1823:TMAPOE>2.0.CO;2.
    """
    lo, hi = LIQUID_EFFECTIVE_RADIUS_RANGE_M
    xp = array_namespace(lwc, number_concentration)
    if is_jax(xp):  # no validation: values cannot be inspected under tracing
        r = xp.cbrt(3.0 * xp.asarray(lwc) / (4.0 * xp.pi * WATER_DENSITY * MARTIN_K_MARITIME
                                             * xp.asarray(number_concentration)))
        return xp.clip(r, lo, hi)
    q = _nonnegative("lwc", lwc, "kg m-3")
    n = _positive("number_concentration", number_concentration, "m-3")
    r = np.cbrt(3.0 * q / (4.0 * np.pi * WATER_DENSITY * MARTIN_K_MARITIME * n))
    clipped = np.count_nonzero((r < lo) | (r > hi))
    if clipped:
        _log.debug("effective_radius_liquid_martin1994: %d of %d values clipped to %g-%g m", clipped, r.size, lo, hi)
    return np.clip(r, lo, hi)


def effective_radius(species, content, scene_radius=None):
    """Effective radius of a hydrometeor species: the scene's where it gives one, else the default.

    Parameters
    ----------
    species : str
        One of :data:`swim.constants.SPECIES`.
    content : array_like
        Content of the species [kg m-3], ≥ 0 (used for cloud liquid, and for the output shape).
    scene_radius : array_like or None, optional
        Effective radius supplied by the scene [m], broadcastable with ``content``; values that are NaN or
        ≤ 0 mean "not given". ``None``: not given anywhere.

    Returns
    -------
    numpy.ndarray or jax.Array
        r_e [m], shape ``broadcast(content, scene_radius)``: the scene value where positive; otherwise
        :func:`effective_radius_liquid_martin1994` for cloud liquid and
        :data:`swim.constants.DEFAULT_EFFECTIVE_RADIUS` for the other species.

    Raises
    ------
    SwimInputError
        If ``species`` is unknown, or (numpy input) the content is negative or non-finite.

    Notes
    -----
    The paper makes r_e of cloud ice grow with content too (Sect. 3.4); no published relation is named, so
    ice uses the constant default unless the scene supplies r_e.

    Source: paper Sect. 3.4; Martin et al. (1994), doi:10.1175/1520-0469(1994)051<1823:TMAPOE>2.0.CO;2.
    """
    if species not in SPECIES:
        raise SwimInputError(f"species must be one of {SPECIES}; got {species!r}")
    xp = array_namespace(content, scene_radius)
    use_jax = is_jax(xp)
    if not use_jax:
        content = _nonnegative("content", content, "kg m-3")
    if species == "cloud_liquid":
        default = effective_radius_liquid_martin1994(content)
    else:
        default = xp.full(xp.shape(content), DEFAULT_EFFECTIVE_RADIUS[species])
    if scene_radius is None:
        return default
    given = xp.asarray(scene_radius) if use_jax else np.asarray(scene_radius, dtype=float)
    # NaN > 0 is False, so NaN falls back to the default as documented
    return xp.where(given > 0.0, given, default)
