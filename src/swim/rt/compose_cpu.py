"""The clouds' part of the pixel radiance composed one ray at a time on the CPU (numba).

After the march, :func:`swim.rt.march_jax._compose_clouds` turns each ray's accumulated state into the radiance of the
hydrometeors it sees: Eq. 12 weighted by the effective phase function of Eq. 13 (thin-cloud lobes, Eqs. 16-18 and
B1-B3; thick-cloud terms, Eqs. 19-23) seen from below, blended with the cloud-top reflection of Eqs. 24-26 seen from
above (Albers et al. 2020, doi:10.5194/amt-13-3235-2020, with the decisions of docs/phase-functions.md and
docs/rendering.md, "Overcast accuracy"). In JAX that is one XLA program per chunk of rays; for the small chunks of
a small image its dispatch, its wait on XLA's threads and its share of the GIL cost more than its arithmetic (~1 ms
of a 41 x 41 render's ~15, docs/decisions/0009-work-around-the-march.md). This module computes the same per ray, without
the GIL, in the worker that marched the chunk, after the ground's term (Eq. 35, its BRDFs: :mod:`swim.rt.ground_cpu`).

Each function mirrors a function of :mod:`swim.optics.phase` or :mod:`swim.rt.solar` (named in its docstring) and
reads its coefficients from there; ``tests/unit/rt/test_compose_cpu.py`` holds this module to the JAX composition.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types
from numba.extending import overload

from ..constants import BACKSCATTER_FRACTION, SPECIES
from ..optics.phase import (
    ARF_DHG_FB,
    ARF_DHG_G,
    ARF_MIN_MU_SUM,
    DIFFUSE_TRANSMISSION_MIN_MU0,
    FORWARD_PEAK_FRACTION,
    G_LIQUID,
    KOKHANOVSKY_B1,
    KOKHANOVSKY_B2,
    LIQUID_FORWARD_WEIGHT_BASE,
    LIQUID_THIN_LOBES,
    THICK_HIGH_NUMERATOR,
    THIN_LOBES,
    VENUS_BRANCH_PHASE_ANGLE_DEG,
    VENUS_FAR_COEFFICIENTS,
    VENUS_MAX_PHASE_ANGLE_DEG,
    VENUS_NEAR_COEFFICIENTS,
)
from .march_settings import FROM_ABOVE_BLEND, TOP_MIN_MU0, TOP_MIN_SELF_TRANSMITTANCE, TOP_REFLECTANCE_MIN_MU0
from ..compilation.numba_jit import JIT_KERNEL, helper_jit
from .march_cpu import _P_RADIUS, _P_SUN
from .solar import ONE_MINUS_G_PER_BACKSCATTER

#: Index of cloud liquid in :data:`swim.constants.SPECIES`: its forward lobe depends on the wavelength.
_LIQUID = SPECIES.index("cloud_liquid")
#: Where :func:`swim.rt.march_cpu.pack_parameters` keeps mu0, the sun direction's vertical component [-].
P_MU0 = _P_SUN + 2
#: Where it keeps the sun's unit direction (3,) in the scene frame and the Earth's radius [m].
P_SUN, P_RADIUS = _P_SUN, _P_RADIUS
#: Height [m] of the sphere on which :func:`local_view_geometry` takes a ray's local vertical: about the middle of
#: the cloud layers seen from space. A cloud 6 km above or below it, seen 80 deg from its zenith, lies 34 km (0.3 deg
#: of great circle) from that point.
CLOUD_VERTICAL_HEIGHT_M = 4000.0

# The coefficients reach the compiled functions as arguments, not as globals: numba bakes globals into its cached
# machine code and checks only this file's time stamp, so a coefficient changed in swim.optics.phase would not reach
# a cached compilation.
(_K_FROM_ABOVE, _K_MIN_MU0, _K_FORWARD, _K_B1, _K_B2, _K_DHG_G, _K_DHG_FB, _K_MIN_MU_SUM, _K_THICK, _K_VENUS_MAX,
 _K_VENUS_BRANCH, _K_VENUS_NEAR, _K_VENUS_FAR, _K_LN_F1, _K_LIQUID_TOTAL, _K_LN_LIQUID_G_MIDDLE, _K_LIQUID_ISOTROPIC,
 _K_LIQUID_BACK, _K_LIQUID_G_BACK, _K_ONE_MINUS_G, _K_TOP_MIN_MU0, _K_TOP_MIN_T_SELF, _K_TOP_ARF_MIN_MU0) = (
    0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 15, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27)


def coefficients():
    """The scalars of the composition as one float64 vector (its layout: the ``_K_*`` indices of this module).

    g^tau' is computed as e^(tau' ln g), so the vector holds ln g where a g is raised to tau' (a ``pow`` per lobe
    cost as much as the rest of a ray)."""
    total, g_middle, isotropic, back, g_back = LIQUID_THIN_LOBES
    return np.array([FROM_ABOVE_BLEND, DIFFUSE_TRANSMISSION_MIN_MU0, FORWARD_PEAK_FRACTION, KOKHANOVSKY_B1,
                     KOKHANOVSKY_B2, ARF_DHG_G, ARF_DHG_FB, ARF_MIN_MU_SUM, THICK_HIGH_NUMERATOR,
                     VENUS_MAX_PHASE_ANGLE_DEG, VENUS_BRANCH_PHASE_ANGLE_DEG, *VENUS_NEAR_COEFFICIENTS,
                     *VENUS_FAR_COEFFICIENTS, math.log(LIQUID_FORWARD_WEIGHT_BASE), total, math.log(g_middle),
                     isotropic, back, g_back, ONE_MINUS_G_PER_BACKSCATTER, TOP_MIN_MU0, TOP_MIN_SELF_TRANSMITTANCE,
                     TOP_REFLECTANCE_MIN_MU0], dtype=np.float64)


def lobes():
    """The thin lobes of :data:`swim.optics.phase.THIN_LOBES` as rows (5, 7) in the order of SPECIES, with ln g in
    place of the two g that are raised to tau' (columns 1 and 3); cloud liquid's row is unused
    (:func:`coefficients`)."""
    rows = np.zeros((len(SPECIES), 7))
    for i, s in enumerate(SPECIES):
        if s in THIN_LOBES:
            rows[i] = THIN_LOBES[s]
            rows[i, [1, 3]] = np.log(rows[i, [1, 3]])
    return rows


#: :func:`coefficients`, :func:`lobes`, :data:`swim.optics.phase.G_LIQUID` and the species' backscatter fractions
#: (:data:`swim.constants.SPECIES`' order): the arrays that :func:`compose_clouds` takes.
COEFFICIENTS = coefficients()
LOBES = lobes()
G_LIQUID_ARRAY = np.array(G_LIQUID, dtype=np.float64)
BACKSCATTER_ARRAY = np.array([BACKSCATTER_FRACTION[s] for s in SPECIES], dtype=np.float64)
_LN10 = math.log(10.0)


def local_view_geometry(start, direction, radius, sun, height=CLOUD_VERTICAL_HEIGHT_M):
    """The cosines of the view zenith angle and of the solar zenith angle of each ray at its own vertical: where the
    ray meets the sphere ``height`` above the surface (first from outside it; from inside, where it leaves it; a ray
    that passes above it, at its closest approach), for :func:`compose_clouds` on a grid that spans a noticeable
    part of the sphere (docs/decisions/0020-per-column-sun.md).

    Parameters
    ----------
    start, direction : numpy.ndarray
        Shape (n, 3): the rays' rebased start [m] (scene frame, z less ``radius``, as the march takes them) and unit
        direction.
    radius : float
        The Earth's radius [m] of the scene frame.
    sun : numpy.ndarray
        Shape (3,): the unit direction towards the sun in the scene frame.
    height : float
        Height [m] of the sphere on which the vertical is taken.

    Returns
    -------
    cos_view_zenith : numpy.ndarray
        Shape (n,) float32: the ray's direction dotted with the local vertical [-] (negative looking down).
    mu0 : numpy.ndarray
        Shape (n,) float64: the sun's direction dotted with the local vertical [-].
    """
    centre = np.array(start, dtype=float)  # from the Earth's centre
    centre[:, 2] += radius
    direction = np.asarray(direction, dtype=float)
    b = np.einsum("ij,ij->i", centre, direction)
    c = np.einsum("ij,ij->i", centre, centre) - (radius + height) ** 2
    root = np.sqrt(np.maximum(b * b - c, 0.0))  # 0 where the ray misses the sphere: its closest approach
    s = np.where(c > 0.0, -b - root, -b + root)  # outside: the first crossing; inside: where it leaves
    point = centre + np.maximum(s, 0.0)[:, None] * direction
    up = point / np.linalg.norm(point, axis=1)[:, None]
    return (np.einsum("ij,ij->i", up, direction).astype(np.float32),
            up @ np.asarray(sun, dtype=float))


def ray_value(value, r):
    """``value`` for ray ``r``: the number itself, or entry ``r`` of an array of one value per ray. In compiled code
    each kind of ``value`` gets its own machine code (:func:`_ray_value_overload`): the number's is that of a scalar
    read, so a kernel that takes either compiles the scalar case as if it took only the number."""
    return value[r] if np.ndim(value) else value


@overload(ray_value, inline="always")
def _ray_value_overload(value, r):
    """numba's implementation of :func:`ray_value`, chosen by the type of ``value``."""
    if isinstance(value, types.Array):
        return lambda value, r: value[r]
    return lambda value, r: value


@helper_jit(inline="always")
def _henyey_greenstein(mu, g):
    """:func:`swim.optics.phase.henyey_greenstein` (paper Eq. 9), the cancellation-free denominator."""
    d = (1.0 - g) ** 2 + 2.0 * g * (1.0 - mu)
    return (1.0 - g * g) / (d * math.sqrt(d))


@helper_jit()
def _phase_thick_high(mu, k):
    """:func:`swim.optics.phase.phase_thick_high` (paper Eq. 19, Mallama et al. 2006's Venus phase law)."""
    mu = min(max(mu, -1.0), 1.0)
    alpha = 180.0 - math.degrees(math.acos(mu))
    if alpha > k[_K_VENUS_MAX]:
        alpha = k[_K_VENUS_MAX]
        illuminated_fraction = math.sin(math.radians(180.0 - alpha) / 2.0) ** 2
    else:  # sin^2(theta / 2) = (1 - cos theta) / 2, exact in float64 for the float32 cosines the march gives
        illuminated_fraction = 0.5 * (1.0 - mu)
    if alpha < k[_K_VENUS_BRANCH]:
        c = _K_VENUS_NEAR
        m = alpha * (k[c] + alpha * (k[c + 1] + alpha * (k[c + 2] + alpha * k[c + 3])))
    else:
        c = _K_VENUS_FAR
        m = k[c] + alpha * (k[c + 1] + alpha * k[c + 2])
    return k[_K_THICK] * math.exp(-0.4 * _LN10 * m) / illuminated_fraction


@helper_jit()
def _reflectance_factor(mu_view, mu0, mu, k):
    """:func:`swim.optics.phase.anisotropic_reflectance_factor_kokhanovsky2004` (paper Eq. 25 corrected, with the
    double Henyey-Greenstein function of Eq. 27)."""
    mu_view = min(max(mu_view, 0.0), 1.0)
    mu0 = min(max(mu0, 0.0), 1.0)
    g = k[_K_DHG_G]
    one_g2 = 1.0 + g * g
    dhg = _henyey_greenstein(mu, g) + (1.0 - g * g) * (k[_K_DHG_FB] * (3.0 * mu * mu - 1.0)
                                                       / (2.0 * one_g2 * math.sqrt(one_g2)))
    return (k[_K_B1] + k[_K_B2] * mu_view * mu0 + dhg) / (4.0 * max(mu_view + mu0, k[_K_MIN_MU_SUM]))


@helper_jit()
def _transmittance_delta_eddington(tau_s, b_tau_s, mu0, k):
    """:func:`swim.rt.solar.transmittance_delta_eddington` (replaces paper Eqs. 4-6)."""
    x = k[_K_ONE_MINUS_G] * b_tau_s
    one_minus_g = min(max(x / max(tau_s, 1e-30), 0.0), 1.0)
    tau_prime = x * (2.0 - one_minus_g)
    kk = 0.5 + 0.75 * mu0
    return (kk + (1.0 - kk) * math.exp(-tau_prime)) / (1.0 + 0.75 * mu0 * x)


@helper_jit(inline="always")
def _ray_terms(tau, i_cloud_t, cos_theta, cos_view_zenith, from_above, low_sun):
    """A cloudy ray's scalars of :func:`compose_clouds`: Eq. 12's normalisation 1 - e^-min(tau, 2) (kept from 0),
    the scattering angle's cosine, the view's downward cosine, the weight of the view from above, the indirectly lit
    term's factor (``low_sun``: diffuse_transmission_factor's, for the view from below), the multiple-scattering
    order tau' of the lobes' g^tau', and the blend coefficient c1 (Eqs. 14, 22: c1 = c3) with the mean cloud
    transmittance T along the ray (``i_cloud_t``: Eq. 12's integral of T)."""
    norm = -math.expm1(-min(tau, 2.0))
    safe = max(norm, 1e-12)
    t_mean = min(max(i_cloud_t / safe, 0.0), 1.0)
    mu = cos_theta
    mu_view_down = -cos_view_zenith
    w_above = min(max(mu_view_down / from_above, 0.0), 1.0)
    low_factor = (1.0 - w_above) * low_sun + w_above
    tp = max(tau, 1.0)  # the multiple-scattering order tau' of the lobes' g^tau'
    c1 = math.exp(-((tau / 10.0) ** 2)) * t_mean  # blend_coefficient (Eqs. 14, 22): c1 = c3
    return safe, mu, mu_view_down, w_above, low_factor, tp, c1


@njit(**JIT_KERNEL, nogil=True)
def compose_clouds(tau_h, tau_packed, species, i_nogas, i_gas, i_cloud_t, l_clear, l_surface, valid, cos_theta,
                   cos_view_zenith, mu0, g_liquid, backscatter, coefficients, lobes, radiance_out, cloud_out):
    """The clouds' radiance and the pixel radiance of n rays, as :func:`swim.rt.march_jax._compose_clouds`.

    Parameters
    ----------
    tau_h : numpy.ndarray
        Shape (n,): hydrometeor optical depth along each ray [-].
    tau_packed : numpy.ndarray
        Shape (n, m): the optical depths of the m packed species [-] (the march's state before
        ``species_matrix``), whose indices into :data:`swim.constants.SPECIES` are ``species`` (m,) int.
    i_nogas, i_gas : numpy.ndarray
        Shape (n, 3): Eq. 12's integrals of the irradiance ratio over e^-tau_o without and with the gas and aerosol
        extinction to the observer [-].
    i_cloud_t : numpy.ndarray
        Shape (n,): the same integral of Step 1a's cloud transmittance T [-].
    l_clear, l_surface : numpy.ndarray
        Shape (n, 3): the clear-sky and the ground's radiance L' [-] (zeros where a chunk has no ray on the ground).
    valid : numpy.ndarray
        Shape (n,) bool: rays of the camera's pixels (the others get radiance 0).
    cos_theta, cos_view_zenith : numpy.ndarray
        Shape (n,): cosines of the scattering angle and of the view zenith angle [-]: the ray's direction dotted
        with the vertical at the reference point, or on a grid whose columns take their own sun with the local
        vertical where the ray meets the clouds (:func:`local_view_geometry`).
    mu0 : float or numpy.ndarray
        Cosine of the solar zenith angle [-]: at the reference point, or (shape (n,)) of each ray's local vertical.
        Each kind compiles to its own machine code (:func:`ray_value`); the same value for every ray gives the
        scalar's result bit for bit.
    g_liquid : numpy.ndarray
        Shape (3,): cloud liquid's forward-peak asymmetry parameter per wavelength (paper Eq. 16).
    backscatter : numpy.ndarray
        Shape (5,): backscatter fraction b of each species of SPECIES [-] (paper Sect. 3.4).
    coefficients, lobes : numpy.ndarray
        :data:`COEFFICIENTS` and :data:`LOBES`.
    radiance_out, cloud_out : numpy.ndarray
        Shape (n, 3), written: the pixel radiance L' (clear + clouds + ground, 0 where not valid) and the clouds'
        part [-].
    """
    k = coefficients
    n = tau_h.shape[0]
    n_species = species.shape[0]
    one_f = 1.0 - k[_K_FORWARD]
    from_above = k[_K_FROM_ABOVE]
    ln_g_liquid = np.empty(3)
    for c in range(3):
        ln_g_liquid[c] = math.log(g_liquid[c])
    for r in range(n):
        tau = tau_h[r]
        for c in range(3):
            cloud_out[r, c] = 0.0
        if tau > 1e-6:
            mu0_ray = ray_value(mu0, r)
            low_sun = (9.0 / 7.0) * max(mu0_ray, k[_K_MIN_MU0])  # diffuse_transmission_factor (Eq. 21's c4)
            mu0_top = max(mu0_ray, k[_K_TOP_MIN_MU0])
            safe, mu, mu_view_down, w_above, low_factor, tp, c1 = _ray_terms(tau, i_cloud_t[r], cos_theta[r],
                                                                            cos_view_zenith[r], from_above, low_sun)
            # phase_thick (Eqs. 19-21) with the indirectly lit term's low_factor
            thick = (2.0 * c1 * _phase_thick_high(mu, k)
                     + 4.0 * (1.0 - c1) * low_factor * (1.0 + 2.0 * max(cos_view_zenith[r], 0.0)) / 3.0)
            # the thin mixture (Eqs. 13, 18, B1-B3) without cloud liquid's wavelength-dependent forward lobe:
            # rest = every lobe but the forward ones, peak = the other species' forward lobes
            inv_tau = 1.0 / max(tau, 1e-12)
            rest = 0.0
            peak = 0.0
            w_liquid = 0.0
            b_eff = 0.0
            f1 = math.exp(tp * k[_K_LN_F1])
            for j in range(n_species):
                s = species[j]
                w = tau_packed[r, j] * inv_tau
                b_eff += w * backscatter[s]
                if s == _LIQUID:
                    w_liquid = w
                    middle = _henyey_greenstein(mu, math.exp(tp * k[_K_LN_LIQUID_G_MIDDLE]))
                    back = _henyey_greenstein(mu, k[_K_LIQUID_G_BACK])
                    rest += w * ((k[_K_LIQUID_TOTAL] - f1) * middle + k[_K_LIQUID_ISOTROPIC] + k[_K_LIQUID_BACK] * back)
                else:
                    peak += w * lobes[s, 0] * _henyey_greenstein(mu, math.exp(tp * lobes[s, 1]))
                    rest += w * (lobes[s, 2] * _henyey_greenstein(mu, math.exp(tp * lobes[s, 3])) + lobes[s, 4]
                                 + lobes[s, 5] * _henyey_greenstein(mu, lobes[s, 6]))
            path = -math.expm1(-tau) / safe  # Eq. 12's 1 - e^-tau over its normalisation
            path_thin = -math.expm1(-one_f * tau) / one_f / safe  # delta_scaled_path_factor
            # seen from above: the cloud-top reflection (Eqs. 24-26) with the delta-Eddington albedo and T_self
            mu_down = max(mu_view_down, from_above)
            tau_s = tau * mu_down / mu0_top
            albedo = 1.0 - _transmittance_delta_eddington(tau_s, b_eff * tau_s, mu0_top, k)
            lim = min(tau, 2.0)
            depth_s = (1.0 - (1.0 + lim) * math.exp(-lim)) / safe * mu_down / mu0_top
            t_self = max(_transmittance_delta_eddington(depth_s, b_eff * depth_s, mu0_top, k), k[_K_TOP_MIN_T_SELF])
            top = (4.0 * max(mu0_ray, 0.0) * _reflectance_factor(mu_down, max(mu0_ray, k[_K_TOP_ARF_MIN_MU0]), mu, k)
                   / t_self)
            for c in range(3):
                p_thin = rest + peak + w_liquid * f1 * _henyey_greenstein(mu, math.exp(tp * ln_g_liquid[c]))
                phase = c1 * p_thin + (1.0 - c1) * thick  # effective_phase_function (Eq. 13)
                eq12 = path * i_gas[r, c]
                l_12 = phase * eq12 + c1 * rest * (path_thin * i_gas[r, c] - eq12)
                # E_mean times the gas-to-cloud factor i_gas / i_nogas
                e_gas = i_nogas[r, c] / safe * (i_gas[r, c] / max(i_nogas[r, c], 1e-30))
                l_above = c1 * p_thin * eq12 + (1.0 - c1) * albedo * top * e_gas
                cloud_out[r, c] = (1.0 - w_above) * l_12 + w_above * l_above
        for c in range(3):
            radiance_out[r, c] = l_clear[r, c] + cloud_out[r, c] + l_surface[r, c] if valid[r] else 0.0
