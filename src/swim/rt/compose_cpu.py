"""The clouds' part of the pixel radiance composed one ray at a time on the CPU (numba).

After the march, :func:`swim.rt.march._compose_clouds` turns each ray's accumulated state into the radiance of the
hydrometeors it sees: Eq. 12 weighted by the effective phase function of Eq. 13 (thin-cloud lobes, Eqs. 16-18 and
B1-B3; thick-cloud terms, Eqs. 19-23) seen from below, blended with the cloud-top reflection of Eqs. 24-26 seen from
above (Albers et al. 2020, doi:10.5194/amt-13-3235-2020, with the decisions of docs/phase-functions.md and
docs/rendering.md, "Overcast accuracy"). In JAX that is one XLA program per chunk of rays; for the small chunks of
a small image its dispatch, its wait on XLA's threads and its share of the GIL cost more than its arithmetic (~1 ms
of a 41 x 41 render's ~15, docs/performance.md, section 35). This module computes the same per ray, without the GIL,
in the worker that marched the chunk. The ground's term (Eq. 35, its BRDFs) stays in JAX and is evaluated only for
chunks that have rays on the ground.

Each function mirrors a function of :mod:`swim.optics.phase` or :mod:`swim.rt.solar` (named in its docstring) and
reads its coefficients from there; ``tests/unit/test_compose_cpu.py`` holds this module to the JAX composition.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..constants import BACKSCATTER_FRACTION, SPECIES
from ..optics.phase import (
    G_LIQUID,
    ARF_DHG_FB,
    ARF_DHG_G,
    ARF_MIN_MU_SUM,
    DIFFUSE_TRANSMISSION_MIN_MU0,
    FORWARD_PEAK_FRACTION,
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
from .march import FROM_ABOVE_BLEND
from .march_cpu import _JIT, _P_SUN
from .solar import ONE_MINUS_G_PER_BACKSCATTER

#: Index of cloud liquid in :data:`swim.constants.SPECIES`: its forward lobe depends on the wavelength.
_LIQUID = SPECIES.index("cloud_liquid")
#: The thin lobes of :data:`swim.optics.phase.THIN_LOBES` as rows in the order of SPECIES (cloud liquid's row unused).
_LOBES = np.array([THIN_LOBES.get(s, (0.0,) * 7) for s in SPECIES], dtype=np.float64)
# g^tau' as e^(tau' ln g): the logarithms of the lobes' g once (a pow per lobe cost more than the rest of a ray)
_LN_LOBE_G = np.log(np.where(_LOBES[:, [1, 3]] > 0, _LOBES[:, [1, 3]], 1.0))
_LIQUID_TOTAL, _LIQUID_G_MIDDLE, _LIQUID_ISOTROPIC, _LIQUID_BACK, _LIQUID_G_BACK = LIQUID_THIN_LOBES
_LN_LIQUID_G_MIDDLE = math.log(_LIQUID_G_MIDDLE)
_LN_LIQUID_FORWARD_WEIGHT_BASE = math.log(LIQUID_FORWARD_WEIGHT_BASE)
_VENUS_C1, _VENUS_C2, _VENUS_C3, _VENUS_C4 = VENUS_NEAR_COEFFICIENTS
_VENUS_F0, _VENUS_F1, _VENUS_F2 = VENUS_FAR_COEFFICIENTS
_LN10 = math.log(10.0)
#: Where :func:`swim.rt.march_cpu.pack_parameters` keeps mu0, the sun direction's vertical component [-].
P_MU0 = _P_SUN + 2
#: :data:`swim.optics.phase.G_LIQUID` and the species' backscatter fractions (:data:`swim.constants.SPECIES`'
#: order) as the arrays :func:`compose_clouds` takes.
G_LIQUID_ARRAY = np.array(G_LIQUID, dtype=np.float64)
BACKSCATTER_ARRAY = np.array([BACKSCATTER_FRACTION[s] for s in SPECIES], dtype=np.float64)


@njit(**_JIT, inline="always")
def _henyey_greenstein(mu, g):
    """:func:`swim.optics.phase.henyey_greenstein` (paper Eq. 9), the cancellation-free denominator."""
    d = (1.0 - g) ** 2 + 2.0 * g * (1.0 - mu)
    return (1.0 - g * g) / (d * math.sqrt(d))


@njit(**_JIT)
def _phase_thick_high(mu):
    """:func:`swim.optics.phase.phase_thick_high` (paper Eq. 19, Mallama et al. 2006's Venus phase law)."""
    mu = min(max(mu, -1.0), 1.0)
    alpha = 180.0 - math.degrees(math.acos(mu))
    if alpha > VENUS_MAX_PHASE_ANGLE_DEG:
        alpha = VENUS_MAX_PHASE_ANGLE_DEG
        illuminated_fraction = math.sin(math.radians(180.0 - alpha) / 2.0) ** 2
    else:  # sin^2(theta / 2) = (1 - cos theta) / 2, exact in float64 for the float32 cosines the march gives
        illuminated_fraction = 0.5 * (1.0 - mu)
    if alpha < VENUS_BRANCH_PHASE_ANGLE_DEG:
        m = alpha * (_VENUS_C1 + alpha * (_VENUS_C2 + alpha * (_VENUS_C3 + alpha * _VENUS_C4)))
    else:
        m = _VENUS_F0 + alpha * (_VENUS_F1 + alpha * _VENUS_F2)
    return THICK_HIGH_NUMERATOR * math.exp(-0.4 * _LN10 * m) / illuminated_fraction


@njit(**_JIT)
def _reflectance_factor(mu_view, mu0, mu):
    """:func:`swim.optics.phase.anisotropic_reflectance_factor_kokhanovsky2004` (paper Eq. 25 corrected, with the
    double Henyey-Greenstein function of Eq. 27)."""
    mu_view = min(max(mu_view, 0.0), 1.0)
    mu0 = min(max(mu0, 0.0), 1.0)
    one_g2 = 1.0 + ARF_DHG_G * ARF_DHG_G
    dhg = _henyey_greenstein(mu, ARF_DHG_G) + (1.0 - ARF_DHG_G * ARF_DHG_G) * (
        ARF_DHG_FB * (3.0 * mu * mu - 1.0) / (2.0 * one_g2 * math.sqrt(one_g2)))
    return (KOKHANOVSKY_B1 + KOKHANOVSKY_B2 * mu_view * mu0 + dhg) / (4.0 * max(mu_view + mu0, ARF_MIN_MU_SUM))


@njit(**_JIT)
def _transmittance_delta_eddington(tau_s, b_tau_s, mu0):
    """:func:`swim.rt.solar.transmittance_delta_eddington` (replaces paper Eqs. 4-6)."""
    x = ONE_MINUS_G_PER_BACKSCATTER * b_tau_s
    one_minus_g = min(max(x / max(tau_s, 1e-30), 0.0), 1.0)
    tau_prime = x * (2.0 - one_minus_g)
    k = 0.5 + 0.75 * mu0
    return (k + (1.0 - k) * math.exp(-tau_prime)) / (1.0 + 0.75 * mu0 * x)


@njit(**_JIT, nogil=True)
def compose_clouds(tau_h, tau_packed, species, i_nogas, i_gas, i_cloud_t, l_clear, l_surface, valid, cos_theta,
                   cos_view_zenith, mu0, g_liquid, backscatter, radiance_out, cloud_out):
    """The clouds' radiance and the pixel radiance of n rays, as :func:`swim.rt.march._compose_clouds`.

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
        Shape (n,): cosines of the scattering angle and of the view zenith angle at the observer [-].
    mu0 : float
        Cosine of the solar zenith angle [-].
    g_liquid : numpy.ndarray
        Shape (3,): cloud liquid's forward-peak asymmetry parameter per wavelength (paper Eq. 16).
    backscatter : numpy.ndarray
        Shape (5,): backscatter fraction b of each species of SPECIES [-] (paper Sect. 3.4).
    radiance_out, cloud_out : numpy.ndarray
        Shape (n, 3), written: the pixel radiance L' (clear + clouds + ground, 0 where not valid) and the clouds'
        part [-].
    """
    n = tau_h.shape[0]
    n_species = species.shape[0]
    low_sun = (9.0 / 7.0) * max(mu0, DIFFUSE_TRANSMISSION_MIN_MU0)  # diffuse_transmission_factor (Eq. 21's c4)
    mu0_top = max(mu0, 0.05)
    one_f = 1.0 - FORWARD_PEAK_FRACTION
    ln_g_liquid = np.empty(3)
    for c in range(3):
        ln_g_liquid[c] = math.log(g_liquid[c])
    for r in range(n):
        tau = tau_h[r]
        for c in range(3):
            cloud_out[r, c] = 0.0
        if tau > 1e-6:
            norm = -math.expm1(-min(tau, 2.0))
            safe = max(norm, 1e-12)
            t_mean = min(max(i_cloud_t[r] / safe, 0.0), 1.0)
            mu = cos_theta[r]
            mu_view_down = -cos_view_zenith[r]
            w_above = min(max(mu_view_down / FROM_ABOVE_BLEND, 0.0), 1.0)
            low_factor = (1.0 - w_above) * low_sun + w_above
            tp = max(tau, 1.0)  # the multiple-scattering order tau' of the lobes' g^tau'
            c1 = math.exp(-((tau / 10.0) ** 2)) * t_mean  # blend_coefficient (Eqs. 14, 22): c1 = c3
            # phase_thick (Eqs. 19-21) with the indirectly lit term's low_factor
            thick = (2.0 * c1 * _phase_thick_high(mu)
                     + 4.0 * (1.0 - c1) * low_factor * (1.0 + 2.0 * max(cos_view_zenith[r], 0.0)) / 3.0)
            # the thin mixture (Eqs. 13, 18, B1-B3) without cloud liquid's wavelength-dependent forward lobe:
            # rest = every lobe but the forward ones, peak = the other species' forward lobes
            inv_tau = 1.0 / max(tau, 1e-12)
            rest = 0.0
            peak = 0.0
            w_liquid = 0.0
            b_eff = 0.0
            f1 = math.exp(tp * _LN_LIQUID_FORWARD_WEIGHT_BASE)
            for k in range(n_species):
                s = species[k]
                w = tau_packed[r, k] * inv_tau
                b_eff += w * backscatter[s]
                if s == _LIQUID:
                    w_liquid = w
                    rest += w * ((_LIQUID_TOTAL - f1) * _henyey_greenstein(mu, math.exp(tp * _LN_LIQUID_G_MIDDLE))
                                 + _LIQUID_ISOTROPIC + _LIQUID_BACK * _henyey_greenstein(mu, _LIQUID_G_BACK))
                else:
                    peak += w * _LOBES[s, 0] * _henyey_greenstein(mu, math.exp(tp * _LN_LOBE_G[s, 0]))
                    rest += w * (_LOBES[s, 2] * _henyey_greenstein(mu, math.exp(tp * _LN_LOBE_G[s, 1])) + _LOBES[s, 4]
                                 + _LOBES[s, 5] * _henyey_greenstein(mu, _LOBES[s, 6]))
            path = -math.expm1(-tau) / safe  # Eq. 12's 1 - e^-tau over its normalisation
            path_thin = -math.expm1(-one_f * tau) / one_f / safe  # delta_scaled_path_factor
            # seen from above: the cloud-top reflection (Eqs. 24-26) with the delta-Eddington albedo and T_self
            mu_down = max(mu_view_down, FROM_ABOVE_BLEND)
            tau_s = tau * mu_down / mu0_top
            albedo = 1.0 - _transmittance_delta_eddington(tau_s, b_eff * tau_s, mu0_top)
            lim = min(tau, 2.0)
            depth_s = (1.0 - (1.0 + lim) * math.exp(-lim)) / safe * mu_down / mu0_top
            t_self = max(_transmittance_delta_eddington(depth_s, b_eff * depth_s, mu0_top), 0.05)
            top = 4.0 * max(mu0, 0.0) * _reflectance_factor(mu_down, max(mu0, 1e-3), mu) / t_self
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
