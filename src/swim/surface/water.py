"""Reflectance of water surfaces: Fresnel reflection, Cox-Munk sun glint and the water-leaving term.

The SWIm paper (Albers et al. 2020, AMT 13, 3235-3261, doi:10.5194/amt-13-3235-2020, Sect. 3.7) uses "a sun
glint model [after] Cox and Munk (1954) ... except that waves are given a random orientation without a
preferred direction", and considers "scattering from below the water surface". This module provides both as
bidirectional reflectance factors (see docs/surface-reflectance.md).

Conventions
-----------
* ``sun`` (..., 3): unit vector from the surface point towards the sun; ``view`` (..., 3): unit vector from
  the surface point towards the observer (minus the ray direction of :mod:`swim.frames`); ``normal``
  (..., 3): unit normal of the mean surface, default vertical ``(0, 0, 1)``. mu_i = sun . normal,
  mu_v = view . normal.
* Every reflectance is a bidirectional reflectance factor R [-]: the reflected radiance is
  ``L = R mu_i E_sun / pi``; a Lambertian surface of albedo a has R = a. R = 0 where mu_i <= 0 or mu_v <= 0.
* Every function computes in the array library of its inputs (:mod:`swim.arrays`): numpy for numpy input,
  ``jax.numpy`` where any input is a JAX array or tracer (jittable, differentiable, float32-safe); any
  broadcastable leading shapes; the result is an array of that library. No input validation (values cannot be
  inspected under tracing).
"""

from __future__ import annotations

import functools
import logging

import numpy as np

from ..arrays import array_namespace, erfc

_log = logging.getLogger(__name__)

#: Refractive index of sea water in the visible [-] (Hale and Querry 1973, doi:10.1364/AO.12.000555, plus
#: ~0.006 for salinity); its spectral variation over 450-615 nm (< 0.5 %) is neglected.
WATER_REFRACTIVE_INDEX = 1.334
#: Default wind speed [m s-1] at 12.5 m (the "fixed value of mean wave slope" of the paper): sigma^2 = 0.0286.
DEFAULT_WIND_SPEED = 5.0
#: Cox-Munk (1954) isotropic clean-surface mean-square slope: sigma^2 = a + b U, U [m s-1] at 12.5 m.
COX_MUNK_MSS_OFFSET = 0.003
COX_MUNK_MSS_PER_WIND = 0.00512
#: Floor on mu_i and mu_v in the glint denominator [-]: with the Smith shadowing the denominator stays finite
#: when one cosine goes to 0; the floor only acts when both do (sun and view within 0.6 deg of the horizon),
#: where R <= 2.6e5 (calm sea) and the radiance R mu_i E / pi <= ~800 E, below the solar disk's ~1.5e4 E.
GLINT_MU_FLOOR = 1e-2
#: Subsurface irradiance reflectance R = E_u / E_d just below the surface at 615, 546, 450 nm [-] for open
#: ocean (chlorophyll ~0.2 mg m-3), from R ~ 0.33 b_b / (a + b_b) (Gordon et al. 1975; Morel and Prieur 1977)
#: with pure-water a (Pope and Fry 1997) and b_b (Morel 1974) and the bio-optical a, b_b of Morel and
#: Maritorena (2001); see docs/surface-reflectance.md, section "Water-leaving term".
WATER_SUBSURFACE_REFLECTANCE = (0.002, 0.012, 0.034)

_UP = (0.0, 0.0, 1.0)


def _dot(a, b):
    xp = array_namespace(a, b)
    return xp.sum(a * b, axis=-1)


def _normal_or_up(normal, like):
    """``normal`` as an array of the library of ``normal`` and ``like``, or the vertical (0, 0, 1) in the dtype
    of ``like``."""
    xp = array_namespace(normal, like)
    if normal is None:
        return xp.asarray(_UP, dtype=xp.result_type(like))
    return xp.asarray(normal)


def specular_direction(sun, normal=None):
    """Mirror image of the sun direction about the surface normal: the view direction of specular reflection.

    Parameters
    ----------
    sun : array_like
        Shape (..., 3): unit vector towards the sun [-].
    normal : array_like, optional
        Shape (..., 3): unit surface normal [-]; default vertical (0, 0, 1).

    Returns
    -------
    numpy.ndarray or jax.Array
        Shape broadcast(sun, normal): ``2 (sun . n) n - sun``, a unit vector towards the observer that sees
        the mirror image of the sun [-]. It has the same cosine to the normal as ``sun``.
    """
    xp = array_namespace(sun, normal)
    sun = xp.asarray(sun)
    n = _normal_or_up(normal, sun)
    return 2.0 * _dot(sun, n)[..., None] * n - sun


def fresnel_reflectance(cos_incidence, refractive_index=WATER_REFRACTIVE_INDEX):
    """Unpolarised Fresnel reflectance of a plane air-to-dielectric interface (exact formula).

    Parameters
    ----------
    cos_incidence : array_like
        Cosine of the angle of incidence in air [-], any shape; clipped to 0...1.
    refractive_index : array_like, optional
        Real refractive index n > 1 of the medium relative to air [-], broadcastable; default 1.334 (water).

    Returns
    -------
    numpy.ndarray or jax.Array
        rho = (r_s^2 + r_p^2) / 2 [-], with r_s = (c - n c_t) / (c + n c_t), r_p = (n c - c_t) / (n c + c_t),
        c_t = sqrt(1 - (1 - c^2) / n^2). rho = ((n - 1) / (n + 1))^2 at normal incidence (0.0204 for
        n = 1.334) and 1 at grazing incidence (c = 0); it decreases monotonically with c. Also valid for
        light leaving the water, evaluated with the angle in air.

    Notes
    -----
    Born, M. and Wolf, E., Principles of Optics, 7th ed., Sect. 1.5.2, doi:10.1017/CBO9781139644181.
    """
    xp = array_namespace(cos_incidence, refractive_index)
    c = xp.asarray(cos_incidence)
    return _fresnel(xp, c, xp.asarray(refractive_index, dtype=xp.result_type(c)))


def _fresnel(xp, cos_incidence, n):
    """Fresnel formula in the array library ``xp`` (numpy or jax.numpy)."""
    c = xp.clip(cos_incidence, 0.0, 1.0)
    ct = xp.sqrt(1.0 - (1.0 - c * c) / (n * n))
    rs = (c - n * ct) / (c + n * ct)
    rp = (n * c - ct) / (n * c + ct)
    return 0.5 * (rs * rs + rp * rp)


def slope_variance_cox_munk1954(wind_speed):
    """Isotropic mean-square slope of the sea surface after Cox and Munk (1954), clean surface.

    Parameters
    ----------
    wind_speed : array_like
        Wind speed U [m s-1] at 12.5 m above the sea (the anemometer height of Cox and Munk; a 10 m wind is
        ~2 % lower, within the scatter of the fit), any shape; negative values are treated as 0.

    Returns
    -------
    numpy.ndarray or jax.Array
        sigma^2 = 0.003 + 0.00512 U [-], the total mean-square slope (sum over both axes; each axis has
        sigma^2 / 2), same shape as ``wind_speed``.

    Notes
    -----
    Cox, C. and Munk, W. (1954), J. Opt. Soc. Am. 44, 838-850, doi:10.1364/JOSA.44.000838, their
    sigma_u^2 + sigma_c^2 fit (r.m.s. error 0.004), used for waves of random orientation.
    """
    xp = array_namespace(wind_speed)
    u = xp.maximum(xp.asarray(wind_speed), 0.0)
    return COX_MUNK_MSS_OFFSET + COX_MUNK_MSS_PER_WIND * u


def slope_pdf_isotropic_gaussian(tan2_tilt, slope_variance):
    """Isotropic Gaussian probability density of the surface slopes (z_x, z_y) (Cox and Munk 1954).

    Parameters
    ----------
    tan2_tilt : array_like
        tan^2 beta = z_x^2 + z_y^2 of the facet tilt beta from the mean normal [-].
    slope_variance : array_like
        Total mean-square slope sigma^2 [-] (:func:`slope_variance_cox_munk1954`), broadcastable.

    Returns
    -------
    numpy.ndarray or jax.Array
        p = exp(-tan^2 beta / sigma^2) / (pi sigma^2) [-]; its integral over the slope plane dz_x dz_y is 1.
    """
    xp = array_namespace(tan2_tilt, slope_variance)
    s2 = xp.asarray(slope_variance)
    return xp.exp(-xp.asarray(tan2_tilt) / s2) / (xp.pi * s2)


def _mu_times_smith_lambda(mu, sigma):
    """mu Lambda(mu) of the Smith (1967) shadowing function for isotropic Gaussian slopes (total MSS sigma^2).

    Lambda(mu) = 1/2 [exp(-a^2) / (a sqrt(pi)) - erfc(a)], a = mu / (sigma sqrt(1 - mu^2)); multiplied by mu
    it stays finite at mu = 0 (sigma / (2 sqrt(pi))) and is 0 at mu = 1.
    """
    xp = array_namespace(mu, sigma)
    mu = xp.asarray(mu)
    s = xp.sqrt(xp.maximum(1.0 - mu * mu, 1e-12))
    a = mu / (sigma * s)
    return 0.5 * (s * sigma / xp.sqrt(xp.pi) * xp.exp(-a * a) - mu * erfc(a))


def shadowing_smith1967(mu_i, mu_v, slope_variance):
    """Bidirectional shadowing/masking factor S = 1 / (1 + Lambda(mu_i) + Lambda(mu_v)) for Gaussian slopes.

    Parameters
    ----------
    mu_i, mu_v : array_like
        Cosines of the sun and view zenith angles to the mean normal [-], in (0, 1], broadcastable.
    slope_variance : array_like
        Total mean-square slope sigma^2 [-], broadcastable.

    Returns
    -------
    numpy.ndarray or jax.Array
        S [-] in (0, 1]; 1 at mu = 1, -> 0 at grazing angles.

    Notes
    -----
    Smith, B. G. (1967), IEEE Trans. Antennas Propag. 15, 668-671, doi:10.1109/TAP.1967.1138991; form of
    Mishchenko, M. I. and Travis, L. D. (1997), J. Geophys. Res. 102, 16989-17013, doi:10.1029/96JD02425.
    Lambda satisfies mu (1 + Lambda(mu)) = integral of p(z) max(0, mu - z . v_h) dz (projected facet area),
    which the tests check.
    """
    xp = array_namespace(mu_i, mu_v, slope_variance)
    mu_i = xp.asarray(mu_i)
    mu_v = xp.asarray(mu_v)
    sigma = xp.sqrt(xp.asarray(slope_variance))
    num = mu_i * mu_v
    return num / (num + mu_v * _mu_times_smith_lambda(mu_i, sigma) + mu_i * _mu_times_smith_lambda(mu_v, sigma))


def sun_glint_reflectance_factor_cox_munk1954(sun, view, normal=None, wind_speed=DEFAULT_WIND_SPEED,
                                              refractive_index=WATER_REFRACTIVE_INDEX, shadowing=True):
    """Sun glint: reflectance factor of a rough water surface with isotropic Gaussian wave slopes.

    Parameters
    ----------
    sun : array_like
        Shape (..., 3): unit vector from the surface towards the sun [-].
    view : array_like
        Shape (..., 3): unit vector from the surface towards the observer [-] (minus the ray direction).
    normal : array_like, optional
        Shape (..., 3): unit normal of the mean water surface [-]; default vertical (0, 0, 1).
    wind_speed : array_like, optional
        Wind speed [m s-1] at 12.5 m, shape broadcastable with ``sun.shape[:-1]``; default 5.
    refractive_index : float, optional
        Refractive index of water [-].
    shadowing : bool, optional
        Static. Include the Smith (1967) shadowing/masking factor (default). Without it R grows as
        1 / (mu_i mu_v) towards the horizon; either way mu_i, mu_v are floored at 0.01 in the denominator.

    Returns
    -------
    numpy.ndarray or jax.Array
        Shape broadcast(sun, view, normal)[:-1]: R [-], 0 where mu_i <= 0 or mu_v <= 0. With the facet
        normal h = (sun + view) / |sun + view|, its tilt beta from the mean normal and the angle of incidence
        omega on the facet (cos omega = sun . h),

            R = pi rho_F(cos omega) p(tan beta) / (4 mu_i mu_v cos^4 beta) S(mu_i, mu_v),

        p the isotropic Gaussian slope density (:func:`slope_pdf_isotropic_gaussian`) with
        sigma^2 = 0.003 + 0.00512 U and S the shadowing factor (:func:`shadowing_smith1967`). R is
        reciprocal (symmetric in sun and view) and peaks in the specular direction
        (:func:`specular_direction`); its directional-hemispherical reflectance is ~rho_F(mu_i) for a high
        sun and never exceeds 1.

    Notes
    -----
    Cox, C. and Munk, W. (1954), J. Opt. Soc. Am. 44, 838-850, doi:10.1364/JOSA.44.000838 (the isotropic,
    "random orientation" form that the SWIm paper uses, Sect. 3.7); Smith (1967) shadowing as in Mishchenko
    and Travis (1997), doi:10.1029/96JD02425. Single reflection only; no whitecaps.
    Cost: ~40 flops, one exp and one erfc per call (x2 for the shadowing).
    """
    xp = array_namespace(sun, view, normal, wind_speed, refractive_index)
    sun = xp.asarray(sun)
    view = xp.asarray(view)
    n = _normal_or_up(normal, sun)
    mu_i = _dot(sun, n)
    mu_v = _dot(view, n)
    visible = (mu_i > 0.0) & (mu_v > 0.0)
    s2 = slope_variance_cox_munk1954(xp.asarray(wind_speed))

    w = sun + view
    mu_sum = xp.maximum(mu_i + mu_v, 1e-6)
    w_t = w - (mu_i + mu_v)[..., None] * n  # component of sun + view along the mean surface
    tan2 = _dot(w_t, w_t) / (mu_sum * mu_sum)
    cos_omega = xp.sqrt(xp.clip(0.5 * (1.0 + _dot(sun, view)), 0.0, 1.0))
    rho = fresnel_reflectance(cos_omega, refractive_index)
    # 1 / cos^4 beta = (1 + tan^2 beta)^2; the exp(-tan^2/sigma^2) of p wins for large tilts
    facet = slope_pdf_isotropic_gaussian(tan2, s2) * (1.0 + tan2) ** 2

    mi = xp.maximum(mu_i, GLINT_MU_FLOOR)
    mv = xp.maximum(mu_v, GLINT_MU_FLOOR)
    denom = mi * mv
    if shadowing:
        sigma = xp.sqrt(s2)
        denom = denom + mv * _mu_times_smith_lambda(mi, sigma) + mi * _mu_times_smith_lambda(mv, sigma)
    r = xp.pi * rho * facet / (4.0 * denom)
    return xp.where(visible, r, 0.0)


@functools.cache
def _diffuse_albedo(refractive_index):
    x, w = np.polynomial.legendre.leggauss(256)
    mu = 0.5 * (x + 1.0)
    rho = _fresnel(np, mu, refractive_index)  # numpy float64: also callable while jax traces
    value = float(np.sum(rho * 2.0 * mu * 0.5 * w))
    _log.debug("Fresnel diffuse albedo for n = %s: %.5f", refractive_index, value)
    return value


def water_diffuse_albedo(refractive_index=WATER_REFRACTIVE_INDEX):
    """Reflectance of a flat water surface for uniform (isotropic) sky light, 2 int_0^1 rho_F(mu) mu dmu.

    Parameters
    ----------
    refractive_index : float, optional
        Static. Refractive index of water [-].

    Returns
    -------
    float
        The bihemispherical Fresnel reflectance [-], 0.0666 for n = 1.334 (computed once in float64 with
        256-point Gauss-Legendre quadrature of the formula of :func:`fresnel_reflectance`, and cached).
        The white-sky albedo of :func:`sun_glint_reflectance_factor_cox_munk1954` is lower, 0.060, 0.055,
        0.050 for U = 2, 5, 10 m s-1, because the single-reflection model drops the light that the shadowing
        removes at grazing incidence (in reality partly reflected again). It is also the fraction of diffuse light leaving the water that is
        reflected back at the air side; the internal value is 1 - (1 - this) / n^2 (0.475).
    """
    return _diffuse_albedo(float(refractive_index))


def water_leaving_reflectance(sun, view, normal=None, subsurface_reflectance=WATER_SUBSURFACE_REFLECTANCE,
                              refractive_index=WATER_REFRACTIVE_INDEX):
    """Reflectance factor of the light scattered back from below the water surface (water-leaving term).

    Parameters
    ----------
    sun, view : array_like
        Shape (..., 3): unit vectors towards the sun and towards the observer [-].
    normal : array_like, optional
        Shape (..., 3): unit normal of the mean water surface [-]; default vertical.
    subsurface_reflectance : array_like, optional
        Shape (C,) or (..., C): irradiance reflectance E_u / E_d just below the surface [-]; default
        :data:`WATER_SUBSURFACE_REFLECTANCE` at 615, 546, 450 nm (open ocean).
    refractive_index : float, optional
        Refractive index of water [-].

    Returns
    -------
    numpy.ndarray or jax.Array
        Shape broadcast(sun, view, normal)[:-1] + (C,): R [-], 0 where mu_i <= 0 or mu_v <= 0. The
        subsurface light field is taken as Lambertian:

            R = R_sub (1 - rho_F(mu_i)) (1 - rho_F(mu_v)) / (n^2 (1 - r_int R_sub)),

        transmission into the water for the sun, out of it towards the observer (Fresnel for the angle in
        air; 1/n^2 the radiance divergence), r_int = 1 - (1 - :func:`water_diffuse_albedo`) / n^2 = 0.475 the
        internal reflectance of the surface for diffuse upwelling light. ~0.54 R_sub at nadir. Reciprocal.

    Notes
    -----
    Austin, R. W. (1974), in Optical Aspects of Oceanography, Academic Press, 317-344 (the (1 - rho)(1 - rho)
    / n^2 transfer across the surface); Morel, A. and Gentili, B. (1996), Appl. Opt. 35, 4850-4862,
    doi:10.1364/AO.35.004850; values of R_sub: see docs/surface-reflectance.md.
    """
    xp = array_namespace(sun, view, normal, subsurface_reflectance)
    sun = xp.asarray(sun)
    view = xp.asarray(view)
    n = _normal_or_up(normal, sun)
    mu_i = _dot(sun, n)
    mu_v = _dot(view, n)
    visible = (mu_i > 0.0) & (mu_v > 0.0)
    r_sub = xp.asarray(subsurface_reflectance, dtype=xp.result_type(mu_i))
    n_w = float(refractive_index)
    r_int = 1.0 - (1.0 - water_diffuse_albedo(n_w)) / n_w**2
    t = (1.0 - fresnel_reflectance(mu_i, n_w)) * (1.0 - fresnel_reflectance(mu_v, n_w)) / n_w**2
    r = t[..., None] * (r_sub / (1.0 - r_int * r_sub))
    return xp.where(visible[..., None], r, 0.0)
