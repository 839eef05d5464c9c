"""Bidirectional reflectance of the land surface (vegetation/soil, snow) and the land/snow/water dispatcher.

The SWIm paper (Albers et al. 2020, AMT 13, 3235-3261, doi:10.5194/amt-13-3235-2020, Sect. 3.7, Eq. 35)
converts the spectral albedo a of the ground into the reflectance of direct sunlight with an anisotropic
reflectance factor, rho = a ARF, "with maximum values in the backscattering direction" over land and "in the
forward-scattering direction" for snow; diffuse sky light uses ARF = 1. This module supplies those shapes:
the Rahman-Pinty-Verstraete (1993) model for land and the asymptotic snow reflectance of Kokhanovsky and
co-workers, both **normalised** so that their directional-hemispherical reflectance equals the scene albedo
at every sun angle and kept exactly reciprocal (see docs/surface-reflectance.md). Water is in
:mod:`swim.surface.water`.

Conventions
-----------
* ``sun`` (..., 3): unit vector from the surface point towards the sun; ``view`` (..., 3): unit vector from
  the surface point towards the observer, i.e. minus the ray direction of :mod:`swim.frames`; ``normal``
  (..., 3): unit surface normal (terrain slope), default vertical (0, 0, 1). mu_i = sun . normal,
  mu_v = view . normal. View = sun is the backscatter (hot-spot) direction; the mirror image of the sun
  about the normal is the specular direction.
* Every function returns the bidirectional reflectance factor R [-]: the reflected radiance is
  ``L = R mu_i E_sun / pi``; a Lambertian surface of albedo a has R = a, and the ARF of the paper is R / a.
  R = 0 where mu_i <= 0 or mu_v <= 0. In Eq. 35 the direct part uses R (this module), the diffuse part the
  albedo with ARF = 1 (:func:`surface_diffuse_albedo`).
* Every function computes in the array library of its inputs (:mod:`swim.arrays`): numpy for numpy input,
  ``jax.numpy`` where any input is a JAX array or tracer (jittable, differentiable, float32-safe); any
  broadcastable leading shapes; the result is an array of that library. Model parameters (k, theta_hg,
  hot_spot) are static Python floats: they select a normalisation table that is built once in numpy (float64)
  and cached.
"""

from __future__ import annotations

import functools
import logging
from pathlib import Path

import numpy as np

from ..arrays import array_namespace
from .albedo import DEFAULT_SNOW_ALBEDO
from .water import (
    DEFAULT_WIND_SPEED,
    WATER_REFRACTIVE_INDEX,
    WATER_SUBSURFACE_REFLECTANCE,
    _dot,
    _normal_or_up,
    sun_glint_reflectance_factor_cox_munk1954,
    water_diffuse_albedo,
    water_leaving_reflectance,
)

_log = logging.getLogger(__name__)

#: RPV parameters of grass in the visible, Rahman, Pinty and Verstraete (1993), Table 1 (rho_0 = 0.183,
#: k = 0.780, Theta = -0.1, with the hot-spot parameter rho_c = rho_0): a bowl shape (k < 1), backward
#: scattering (Theta < 0) and a hot spot; the values used by the Eradiate RPV surface by default.
RPV_K = 0.78
RPV_THETA_HG = -0.1
RPV_HOT_SPOT = 0.183
#: Constants A, B, C of the reflection function R0 of a semi-infinite non-absorbing snow layer made of
#: fractal grains (Kokhanovsky and Breon 2012, doi:10.1109/LGRS.2012.2185775) [-].
SNOW_R0_A, SNOW_R0_B, SNOW_R0_C = 1.247, 1.186, 5.157
#: Phase function of the fractal snow grains, P(theta) = c1 exp(-e1 theta) + c2 exp(-e2 theta), theta [deg]
#: the scattering angle (180 = backscatter): (c1, e1, c2, e2).
SNOW_PHASE_COEFFS = (11.1, 0.087, 1.1, 0.014)
#: Spectral albedo of snow at 615, 546, 450 nm [-] used where the scene has snow cover: the one snow spectrum
#: of the project, :data:`swim.surface.albedo.DEFAULT_SNOW_ALBEDO` (CERES/SARB permanent snow, ~0.93-0.96;
#: fresh snow 0.96-0.99, aged snow ~0.9 in the visible; Warren 1982, doi:10.1029/RG020i001p00067).
SNOW_ALBEDO = tuple(float(a) for a in DEFAULT_SNOW_ALBEDO)
#: Lowest albedo for which the snow shape is evaluated [-]: darker "snow" (outside the weak-absorption regime
#: of the asymptotic theory) gets the shape of this albedo, scaled to its own albedo.
SNOW_SHAPE_ALBEDO_MIN = 0.5
#: Floor on mu_i and mu_v inside the shape functions [-] (keeps (mu_i + mu_v)^(k-1), 1 / (mu_i + mu_v) and
#: tan(theta) finite in float32; acts only within 0.006 deg of the horizon).
MU_MIN = 1e-4

# normalisation tables: Gauss-Legendre quadrature in mu and in azimuth, output on a uniform mu grid
_N_MU_NODES = 96
_N_PHI_NODES = 96
_N_TABLE = 257
_SNOW_ALBEDO_NODES = np.linspace(SNOW_SHAPE_ALBEDO_MIN, 1.0, 11)


# --------------------------------------------------------------------------------------------------------
# shape functions, written for numpy (table building, float64) and jax.numpy (rendering)
# --------------------------------------------------------------------------------------------------------
def _rpv_reduced(xp, mu_i, mu_v, cos_sv, hot_g, k, theta, rho_c):
    """RPV shape without its (mu_i mu_v)^(k-1) factor: (mu_i + mu_v)^(k-1) F(g) [1 + (1 - rho_c) / (1 + G)]."""
    minnaert = (mu_i + mu_v) ** (k - 1.0)
    hg = (1.0 - theta * theta) / (1.0 + theta * theta + 2.0 * theta * cos_sv) ** 1.5
    hot = 1.0 + (1.0 - rho_c) / (1.0 + hot_g)
    return minnaert * hg * hot


def _snow_r0_q(xp, mu_i, mu_v, cos_sv):
    """R0 of non-absorbing snow and the exponent Q = K0(mu_i) K0(mu_v) / R0 (Kokhanovsky and Breon 2012)."""
    c1, e1, c2, e2 = SNOW_PHASE_COEFFS
    theta_deg = xp.degrees(xp.arccos(xp.clip(-cos_sv, -1.0, 1.0)))
    phase = c1 * xp.exp(-e1 * theta_deg) + c2 * xp.exp(-e2 * theta_deg)
    mu_sum = mu_i + mu_v
    r0 = (SNOW_R0_A + SNOW_R0_B * mu_sum + SNOW_R0_C * mu_i * mu_v + phase) / (4.0 * mu_sum)
    escape = (3.0 / 7.0) ** 2 * (1.0 + 2.0 * mu_i) * (1.0 + 2.0 * mu_v)
    return r0, escape / r0


def _snow_raw(xp, mu_i, mu_v, cos_sv, albedo):
    """R0 albedo^(K0(mu_i) K0(mu_v) / R0) of Kokhanovsky and Breon (2012), un-normalised."""
    r0, q = _snow_r0_q(xp, mu_i, mu_v, cos_sv)
    return r0 * xp.exp(xp.log(albedo) * q)


# --------------------------------------------------------------------------------------------------------
# normalisation tables (numpy, float64, built once per parameter set)
# --------------------------------------------------------------------------------------------------------
def _local_geometry(mu_1, mu_2, cos_phi):
    """cos(sun, view) and the RPV hot-spot distance G for zenith cosines mu_1, mu_2 and azimuth difference phi."""
    s1 = np.sqrt(1.0 - mu_1 * mu_1)
    s2 = np.sqrt(1.0 - mu_2 * mu_2)
    cos_sv = mu_1 * mu_2 + s1 * s2 * cos_phi
    t1, t2 = s1 / mu_1, s2 / mu_2
    hot_g = np.sqrt(np.maximum(t1 * t1 + t2 * t2 - 2.0 * t1 * t2 * cos_phi, 0.0))
    return cos_sv, hot_g


def _quadrature():
    x, w = np.polynomial.legendre.leggauss(_N_MU_NODES)
    mu = 0.5 * (x + 1.0)
    w_mu = 2.0 * mu * 0.5 * w  # DHR = 2 int R_bar(mu_v) mu_v dmu_v, R_bar the azimuthal mean
    xp_, wp_ = np.polynomial.legendre.leggauss(_N_PHI_NODES)
    phi = 0.5 * np.pi * (xp_ + 1.0)
    w_phi = 0.5 * wp_  # (1/pi) int_0^pi dphi
    grid = np.linspace(0.0, 1.0, _N_TABLE)
    return mu, w_mu, np.cos(phi), w_phi, np.maximum(grid, MU_MIN)


def _symmetric_scaling(kernel, w_mu):
    """g > 0 with g_i sum_j K_ij w_j g_j = 1 (symmetric K): scales K to unit DHR, keeping it symmetric."""
    g = 1.0 / np.sqrt(kernel @ w_mu)
    for it in range(10_000):
        g_new = np.sqrt(g / (kernel @ (w_mu * g)))
        if np.max(np.abs(g_new / g - 1.0)) < 1e-14:
            g = g_new
            break
        g = g_new
    else:  # pragma: no cover - the iteration contracts quickly for positive kernels
        _log.warning("surface BRDF normalisation did not converge to 1e-14")
    _log.debug("symmetric scaling converged after %d iterations", it + 1)
    return g


def _disk_cached(name, build, *args):
    """``build(*args)``, kept on disk between processes (:func:`swim.compilation.disk_cache.disk_cached`, keyed by
    the arguments and the code of every module of :mod:`swim.surface`, where all that the tables are built from
    lives): the two tables take ~0.45 s together, most of the ground's share of a new process's first render
    (docs/decisions/0009-work-around-the-march.md)."""
    from ..compilation.disk_cache import disk_cached  # here: swim.rt imports this module

    sources = sorted(Path(__file__).resolve().parent.glob("*.py"))
    return disk_cached("surface", (name, *args), lambda: build(*args), sources=sources)


@functools.cache
def _rpv_table(k, theta, rho_c):
    """q(mu) on the uniform grid: R = a (mu_i+mu_v)^(k-1) F H q(mu_i) q(mu_v) has DHR = a at every mu_i."""
    return _disk_cached("rpv_table", _build_rpv_table, k, theta, rho_c)


@functools.cache
def _snow_table():
    """g(a, mu) on (albedo nodes, uniform mu grid): R = a R_snow g(a, mu_i) g(a, mu_v) has DHR = a."""
    return _disk_cached("snow_table", _build_snow_table)


def _build_rpv_table(k, theta, rho_c):
    mu, w_mu, cos_phi, w_phi, grid = _quadrature()

    def kernel(mu_1, mu_2):  # azimuthal mean of the reduced shape, times mu_2^(k-1)
        m1, m2, c = mu_1[:, None, None], mu_2[None, :, None], cos_phi[None, None, :]
        cos_sv, hot_g = _local_geometry(m1, m2, c)
        shape = _rpv_reduced(np, m1, m2, cos_sv, hot_g, k, theta, rho_c)
        return (shape @ w_phi) * mu_2[None, :] ** (k - 1.0)

    k_nodes = kernel(mu, mu) * mu[:, None] ** (k - 1.0)  # full (symmetric) RPV kernel on the nodes
    g = _symmetric_scaling(k_nodes, w_mu)
    q = 1.0 / (kernel(grid, mu) @ (w_mu * g))  # Nystrom: q(mu) = mu^(k-1) g(mu)
    _log.debug("RPV table (k=%s, Theta=%s, rho_c=%s): q in [%.4g, %.4g]", k, theta, rho_c, q.min(), q.max())
    return q


def _build_snow_table():
    mu, w_mu, cos_phi, w_phi, grid = _quadrature()

    def r0_q(mu_1, mu_2):
        m1, m2, c = mu_1[:, None, None], mu_2[None, :, None], cos_phi[None, None, :]
        cos_sv, _ = _local_geometry(m1, m2, c)
        return _snow_r0_q(np, m1, m2, cos_sv)

    (r0_n, q_n), (r0_o, q_o) = r0_q(mu, mu), r0_q(grid, mu)
    table = np.empty((_SNOW_ALBEDO_NODES.size, _N_TABLE))
    for i, a in enumerate(_SNOW_ALBEDO_NODES):
        g = _symmetric_scaling((r0_n * np.exp(np.log(a) * q_n)) @ w_phi, w_mu)
        table[i] = 1.0 / (((r0_o * np.exp(np.log(a) * q_o)) @ w_phi) @ (w_mu * g))
    _log.debug("snow table: g in [%.4g, %.4g]", table.min(), table.max())
    return table


def _lerp_mu(table, mu):
    """Linear interpolation of ``table`` (..., _N_TABLE) given on the uniform grid 0..1 at ``mu`` (clipped)."""
    xp = array_namespace(table, mu)
    x = xp.clip(mu, 0.0, 1.0) * (_N_TABLE - 1)
    i0 = xp.clip(xp.floor(x), 0, _N_TABLE - 2).astype(xp.int32)
    f = x - i0
    return table[..., i0] * (1.0 - f) + table[..., i0 + 1] * f


def _lerp_snow(mu, albedo):
    """Bilinear interpolation of the snow table at (albedo, mu), albedo clipped to its node range."""
    xp = array_namespace(mu, albedo)
    table = xp.asarray(_snow_table(), dtype=xp.result_type(mu))
    n_a = _SNOW_ALBEDO_NODES.size
    y = (xp.clip(albedo, SNOW_SHAPE_ALBEDO_MIN, 1.0) - SNOW_SHAPE_ALBEDO_MIN) / (1.0 - SNOW_SHAPE_ALBEDO_MIN)
    y = y * (n_a - 1)
    j0 = xp.clip(xp.floor(y), 0, n_a - 2).astype(xp.int32)
    fy = y - j0
    x = xp.clip(mu, 0.0, 1.0) * (_N_TABLE - 1)
    i0 = xp.clip(xp.floor(x), 0, _N_TABLE - 2).astype(xp.int32)
    fx = x - i0
    lo = table[j0, i0] * (1.0 - fx) + table[j0, i0 + 1] * fx
    hi = table[j0 + 1, i0] * (1.0 - fx) + table[j0 + 1, i0 + 1] * fx
    return lo * (1.0 - fy) + hi * fy


# --------------------------------------------------------------------------------------------------------
# geometry
# --------------------------------------------------------------------------------------------------------
def _geometry(sun, view, normal):
    """Cosines (floored at MU_MIN), cos(sun, view), the RPV hot-spot distance G and the visibility mask."""
    xp = array_namespace(sun, view, normal)
    sun = xp.asarray(sun)
    view = xp.asarray(view)
    n = _normal_or_up(normal, sun)
    mu_i = _dot(sun, n)
    mu_v = _dot(view, n)
    visible = (mu_i > 0.0) & (mu_v > 0.0)
    mi = xp.maximum(mu_i, MU_MIN)
    mv = xp.maximum(mu_v, MU_MIN)
    # G = |tan-vector of sun - tan-vector of view| along the surface (0 at the hot spot, view = sun)
    d = (sun - mu_i[..., None] * n) / mi[..., None] - (view - mu_v[..., None] * n) / mv[..., None]
    hot_g = xp.sqrt(_dot(d, d))
    cos_sv = xp.clip(_dot(sun, view), -1.0, 1.0)
    return mi, mv, cos_sv, hot_g, visible


def _rpv_shape(geom, k, theta, rho_c):
    mi, mv, cos_sv, hot_g, visible = geom
    xp = array_namespace(mi, mv, cos_sv, hot_g)
    q = xp.asarray(_rpv_table(k, theta, rho_c), dtype=mi.dtype)
    shape = _rpv_reduced(xp, mi, mv, cos_sv, hot_g, k, theta, rho_c) * _lerp_mu(q, mi) * _lerp_mu(q, mv)
    return xp.where(visible, shape, 0.0)


def _snow_shape(geom, albedo):
    """Normalised snow shape (DHR 1) for ``albedo`` broadcast against the geometry (channels last if any)."""
    mi, mv, cos_sv, _, visible = geom
    xp = array_namespace(mi, mv, cos_sv, albedo)
    a = xp.clip(albedo, SNOW_SHAPE_ALBEDO_MIN, 1.0)
    shape = _snow_raw(xp, mi, mv, cos_sv, a) * _lerp_snow(mi, a) * _lerp_snow(mv, a)
    return xp.where(visible, shape, 0.0)


def _static(value, name):
    try:
        return float(value)
    except Exception as err:  # a tracer: these parameters select a cached table
        raise TypeError(f"{name} must be a static Python float (it selects a normalisation table)") from err


# --------------------------------------------------------------------------------------------------------
# public functions
# --------------------------------------------------------------------------------------------------------
def reflectance_factor_lambertian(albedo):
    """Reflectance factor of a Lambertian surface: R = a.

    Parameters
    ----------
    albedo : array_like
        Albedo a [-], any shape (e.g. (..., 3) at 615, 546, 450 nm).

    Returns
    -------
    numpy.ndarray or jax.Array
        R = a [-], same shape. Directional-hemispherical reflectance a at every sun angle.
    """
    xp = array_namespace(albedo)
    return xp.asarray(albedo)


def reflectance_factor_rpv1993(sun, view, normal=None, albedo=1.0, k=RPV_K, theta_hg=RPV_THETA_HG,
                               hot_spot=RPV_HOT_SPOT):
    """Land reflectance with a backscatter (hot-spot) maximum: Rahman-Pinty-Verstraete (1993), normalised.

    Parameters
    ----------
    sun : array_like
        Shape (..., 3): unit vector from the surface towards the sun [-].
    view : array_like
        Shape (..., 3): unit vector from the surface towards the observer [-] (minus the ray direction).
    normal : array_like, optional
        Shape (..., 3): unit surface normal [-]; default vertical (0, 0, 1).
    albedo : array_like, optional
        Directional-hemispherical reflectance (albedo) a [-], broadcastable with ``sun.shape[:-1]``; give it
        a trailing channel axis, e.g. (..., 3), and pass ``sun[..., None, :]`` etc. for per-channel output,
        or multiply the default (a = 1) result by the albedo. Default 1 (the normalised shape).
    k : float, optional
        Static. Minnaert-like exponent [-]; k < 1 gives a bowl shape (brighter towards the horizon).
    theta_hg : float, optional
        Static. Henyey-Greenstein asymmetry Theta [-]; Theta < 0 scatters backwards.
    hot_spot : float, optional
        Static. Hot-spot parameter rho_c [-] of 1 + (1 - rho_c) / (1 + G): the peak is 2 - rho_c times the
        surroundings.

    Returns
    -------
    numpy.ndarray or jax.Array
        Shape broadcast(sun, view, normal)[:-1] broadcast with ``albedo``: R [-], 0 where mu_i <= 0 or
        mu_v <= 0. With cos g = sun . view (g the phase angle, 0 at the hot spot) and
        G = |tan theta_i e_i - tan theta_v e_v| (the distance of the two directions in the tangent plane),

            R = a N(mu_i) N(mu_v) [mu_i mu_v (mu_i + mu_v)]^(k-1) (1 - Theta^2)
                / (1 + Theta^2 + 2 Theta cos g)^(3/2) [1 + (1 - rho_c) / (1 + G)],

        where N(mu) > 0 is a tabulated factor chosen so that the directional-hemispherical reflectance
        (1/pi) int R mu_v dOmega_v equals a at every mu_i (to < 0.3 %) while R stays exactly reciprocal
        (symmetric in sun and view). It replaces rho_0 of the original model.

    Notes
    -----
    Rahman, H., Pinty, B. and Verstraete, M. M. (1993), J. Geophys. Res. 98, 20791-20801,
    doi:10.1029/93JD02072; default parameters from their Table 1 (grass, visible). The rho_0 amplitude
    is replaced by the normalisation (docs/surface-reflectance.md, "Normalisation").
    Cost: ~30 flops, 2 pow, 1 sqrt and two 257-entry table look-ups; the table is built once per
    (k, theta_hg, hot_spot) in ~0.1 s.
    """
    k, theta_hg, hot_spot = _static(k, "k"), _static(theta_hg, "theta_hg"), _static(hot_spot, "hot_spot")
    xp = array_namespace(sun, view, normal, albedo)
    geom = _geometry(xp.asarray(sun), xp.asarray(view), normal)
    return xp.asarray(albedo) * _rpv_shape(geom, k, theta_hg, hot_spot)


def reflectance_factor_snow_kokhanovsky2004(sun, view, normal=None, albedo=SNOW_ALBEDO[1]):
    """Snow reflectance with a forward-scattering maximum (asymptotic radiative transfer), normalised.

    Parameters
    ----------
    sun : array_like
        Shape (..., 3): unit vector from the surface towards the sun [-].
    view : array_like
        Shape (..., 3): unit vector from the surface towards the observer [-] (minus the ray direction).
    normal : array_like, optional
        Shape (..., 3): unit surface normal [-]; default vertical (0, 0, 1).
    albedo : array_like, optional
        Snow albedo a [-], broadcastable with ``sun.shape[:-1]`` (for per-channel output pass
        ``sun[..., None, :]`` and an albedo (..., 3)); default 0.95. Values below 0.5 use the shape of 0.5.

    Returns
    -------
    numpy.ndarray or jax.Array
        Shape broadcast(sun, view, normal)[:-1] broadcast with ``albedo``: R [-], 0 where mu_i <= 0 or
        mu_v <= 0. With theta the scattering angle (cos theta = -sun . view, 180 deg = backscatter),

            R0 = [A + B (mu_i + mu_v) + C mu_i mu_v + P(theta)] / (4 (mu_i + mu_v)),
            P(theta) = 11.1 exp(-0.087 theta) + 1.1 exp(-0.014 theta),  A, B, C = 1.247, 1.186, 5.157,
            R = a N(mu_i, a) N(mu_v, a) R0 a^(K0(mu_i) K0(mu_v) / R0),  K0(mu) = 3 (1 + 2 mu) / 7,

        where a takes the role of the spherical albedo exp(-alpha) of the theory and N > 0 is tabulated so
        that the directional-hemispherical reflectance equals a at every mu_i (to < 0.3 %) while R stays
        exactly reciprocal. Maximum towards grazing forward scattering (view near the specular direction).

    Notes
    -----
    Kokhanovsky, A. A. and Zege, E. P. (2004), Appl. Opt. 43, 1589-1602, doi:10.1364/AO.43.001589
    (R = R0 exp(-alpha K0 K0 / R0)); Kokhanovsky, A. A. and Breon, F.-M. (2012), IEEE Geosci. Remote Sens.
    Lett. 9, 928-932, doi:10.1109/LGRS.2012.2185775 (R0, P and K0 as used here); the fractal-grain model is
    compared with measurements by Kokhanovsky, A. A. et al. (2005), IEEE Trans. Geosci. Remote Sens. 43(7),
    1529-1535.
    Cost: ~40 flops, arccos, 4 exp and four table look-ups per albedo.
    """
    xp = array_namespace(sun, view, normal, albedo)
    geom = _geometry(xp.asarray(sun), xp.asarray(view), normal)
    a = xp.asarray(albedo)
    return a * _snow_shape(geom, a)


def _pixel_field(xp, value, lead_ndim, dtype):
    """A per-pixel field of shape (...) as an array of the library ``xp``; a trailing length-1 axis beyond the
    pixel rank (the channel-broadcastable form (..., 1)) is dropped, so that both forms give the same result."""
    x = xp.asarray(value, dtype=dtype)
    if x.ndim == lead_ndim + 1 and x.shape[-1] == 1:
        x = x[..., 0]
    return x


def surface_reflectance_factor(sun, view, normal, albedo, snow_cover=0.0, land_mask=1.0,
                               wind_speed=DEFAULT_WIND_SPEED, *, snow_albedo=SNOW_ALBEDO,
                               subsurface_reflectance=WATER_SUBSURFACE_REFLECTANCE, k=RPV_K, theta_hg=RPV_THETA_HG,
                               hot_spot=RPV_HOT_SPOT):
    """Reflectance factor of the ground for direct sunlight, per wavelength, over land, snow and water.

    Parameters
    ----------
    sun : array_like
        Shape (..., 3): unit vector from the surface point towards the sun [-].
    view : array_like
        Shape (..., 3): unit vector from the surface point towards the observer [-] (minus the ray direction).
    normal : array_like or None
        Shape (..., 3): unit terrain normal [-]; None for vertical. Used for land and water alike (pass the
        vertical for water if the terrain normal is not).
    albedo : array_like
        Shape (..., C), C = 3 at 615, 546, 450 nm: snow-free land albedo [-] (the scene's
        ``surface_albedo``). Not used over water.
    snow_cover : array_like, optional
        Shape (...): snow-covered fraction of the land, clipped to 0...1 [-]; default 0.
    land_mask : array_like, optional
        Shape (...): land fraction f, clipped to 0...1 [-]: 1 land, 0 water, fractions (coasts) blend the
        two linearly; default 1.
    wind_speed : array_like, optional
        Shape (...): wind speed at 12.5 m [m s-1] for the sun glint (a 10 m wind is within the fit's
        scatter); default 5.
    snow_albedo : array_like, optional
        Shape (C,) or (..., C): albedo of the snow [-]; default :data:`SNOW_ALBEDO`.
    subsurface_reflectance : array_like, optional
        Shape (C,) or (..., C): subsurface irradiance reflectance of the water [-]; default
        :data:`swim.surface.water.WATER_SUBSURFACE_REFLECTANCE`.
    k, theta_hg, hot_spot : float, optional
        Static RPV parameters (:func:`reflectance_factor_rpv1993`).

    Returns
    -------
    numpy.ndarray or jax.Array
        Shape broadcast of the leading shapes + (C,): R [-], 0 where mu_i <= 0 or mu_v <= 0,

            R = f [(1 - s) RPV(albedo) + s snow(snow_albedo)] + (1 - f) [glint + water-leaving],

        f the land fraction, s the snow cover; the Cox-Munk glint is the same in all channels. For diffuse
        sky light use :func:`surface_diffuse_albedo` with ARF = 1 (paper Eq. 35).

    Notes
    -----
    The per-pixel fields ``snow_cover``, ``land_mask`` and ``wind_speed`` may also be given as (..., 1)
    (broadcastable against the channels); the trailing axis is then dropped.
    Cost per call: RPV (~30 flops, 2 table look-ups) + snow per channel (~40 flops, arccos, 4 exp,
    4 look-ups) + glint (~40 flops, exp, 2 erfc) + water-leaving (2 Fresnel); every branch is evaluated
    (no control flow under jit).
    """
    k, theta_hg, hot_spot = _static(k, "k"), _static(theta_hg, "theta_hg"), _static(hot_spot, "hot_spot")
    xp = array_namespace(sun, view, normal, albedo, snow_cover, land_mask, wind_speed, snow_albedo,
                         subsurface_reflectance)
    sun = xp.asarray(sun)
    view = xp.asarray(view)
    n = _normal_or_up(normal, sun)
    geom = _geometry(sun, view, n)
    dtype = geom[0].dtype
    albedo = xp.asarray(albedo, dtype=dtype)
    lead_ndim = max(sun.ndim, view.ndim, n.ndim, albedo.ndim) - 1
    s = xp.clip(_pixel_field(xp, snow_cover, lead_ndim, dtype), 0.0, 1.0)[..., None]
    f = xp.clip(_pixel_field(xp, land_mask, lead_ndim, dtype), 0.0, 1.0)[..., None]
    wind = _pixel_field(xp, wind_speed, lead_ndim, dtype)

    rpv = _rpv_shape(geom, k, theta_hg, hot_spot)[..., None] * albedo
    geom_c = tuple(x[..., None] for x in geom)  # channel axis last
    a_snow = xp.asarray(snow_albedo, dtype=dtype)
    snow = a_snow * _snow_shape(geom_c, a_snow)
    land = (1.0 - s) * rpv + s * snow

    glint = sun_glint_reflectance_factor_cox_munk1954(sun, view, n, wind)
    water = glint[..., None] + water_leaving_reflectance(sun, view, n, subsurface_reflectance)
    return f * land + (1.0 - f) * water


def surface_diffuse_albedo(albedo, snow_cover=0.0, land_mask=1.0, *, snow_albedo=SNOW_ALBEDO,
                           subsurface_reflectance=WATER_SUBSURFACE_REFLECTANCE,
                           refractive_index=WATER_REFRACTIVE_INDEX):
    """Albedo for diffuse sky light (ARF = 1, paper Eq. 35), consistent with :func:`surface_reflectance_factor`.

    Parameters
    ----------
    albedo : array_like
        Shape (..., C): snow-free land albedo [-].
    snow_cover, land_mask : array_like, optional
        Shape (...) or (..., 1): snow fraction [-] and land fraction (1 land, 0 water) [-], as in
        :func:`surface_reflectance_factor`.
    snow_albedo, subsurface_reflectance : array_like, optional
        Shape (C,) or (..., C) [-], as in :func:`surface_reflectance_factor`.
    refractive_index : float, optional
        Static. Refractive index of water [-].

    Returns
    -------
    numpy.ndarray or jax.Array
        Shape (..., C) [-]: f [(1 - s) a + s a_snow] + (1 - f) a_water, with the water albedo the Fresnel
        reflectance for a uniform sky (:func:`swim.surface.water.water_diffuse_albedo`, 0.067) plus the
        water-leaving part R_sub (1 - 0.067)^2 / (n^2 (1 - r_int R_sub)) (~0.49 R_sub). Over land this is the
        directional-hemispherical reflectance of :func:`surface_reflectance_factor` at every sun angle.
    """
    xp = array_namespace(albedo, snow_cover, land_mask, snow_albedo, subsurface_reflectance)
    albedo = xp.asarray(albedo)
    lead_ndim = albedo.ndim - 1
    s = xp.clip(_pixel_field(xp, snow_cover, lead_ndim, albedo.dtype), 0.0, 1.0)[..., None]
    f = xp.clip(_pixel_field(xp, land_mask, lead_ndim, albedo.dtype), 0.0, 1.0)[..., None]
    land = (1.0 - s) * albedo + s * xp.asarray(snow_albedo, dtype=albedo.dtype)
    n_w = float(refractive_index)
    rho_bar = water_diffuse_albedo(n_w)
    r_int = 1.0 - (1.0 - rho_bar) / n_w**2
    r_sub = xp.asarray(subsurface_reflectance, dtype=albedo.dtype)
    water = rho_bar + r_sub * (1.0 - rho_bar) ** 2 / (n_w**2 * (1.0 - r_int * r_sub))
    return f * land + (1.0 - f) * water
