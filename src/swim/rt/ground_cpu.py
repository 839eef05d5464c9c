"""The ground's part of the pixel radiance composed one ray at a time on the CPU (numba).

:func:`swim.rt.march_jax._ground_radiance` gives the radiance of the ground where a ray ends on it: Eq. 35 of the paper
(Albers et al. 2020, doi:10.5194/amt-13-3235-2020, Sect. 3.7) on the tilted terrain facet, with the land (RPV), snow
(Kokhanovsky) and water (Fresnel, Cox-Munk glint, water-leaving light) reflectance of :mod:`swim.surface`, lit by Step
1a's cloud transmittance and terrain shadow and seen through the clear sky and the hydrometeors on the way. In JAX it
is one XLA program per chunk whose tracing costs ~0.6 s in every new process (the README's render) and whose dispatch
costs a few per cent of a big warm render (docs/decisions/0009-work-around-the-march.md). This module computes the same
per ray, without the GIL, in the worker that marched the chunk, after :mod:`swim.rt.compose_cpu` has done the clouds'
part.

Each function mirrors one of :mod:`swim.surface.lighting`, :mod:`swim.surface.brdf`, :mod:`swim.surface.water` or
:mod:`swim.rt.march` (named in its docstring) and reads its constants and normalisation tables from there
(:func:`ground_tables`); it computes in float64 from the march's float32 tables and the float64 BRDF tables.
``tests/unit/rt/test_ground_cpu.py`` holds it to the JAX functions.
"""

from __future__ import annotations

import functools
import math
import threading

import numpy as np
from numba import njit

from ..surface import brdf, lighting, water
from .compose_cpu import _transmittance_delta_eddington
from .surface_margin import surface_fade_cells
from .march_settings import FROM_ABOVE_BLEND
from ..compilation.numba_jit import JIT_KERNEL, helper_jit
from .march_cpu import (_P_RADIUS, _P_SUN, _P_SURFACE_MARGIN, _P_TOP, _bilinear_at, _bilinear_index, _clip,
                        _point_geometry)

# The constants reach the compiled functions as arguments (numba bakes globals into its cached machine code and
# checks only this file's time stamp): the layout of ground_tables()'s vector.
(_G_MIN_VIEW_COSINE, _G_MIN_WATER_VIEW_COSINE, _G_MU_MIN, _G_RPV_K, _G_RPV_THETA, _G_RPV_HOT_SPOT, _G_SNOW_A,
 _G_SNOW_B, _G_SNOW_C, _G_SNOW_C1, _G_SNOW_E1, _G_SNOW_C2, _G_SNOW_E2, _G_SNOW_ALBEDO_MIN, _G_MSS_OFFSET,
 _G_MSS_PER_WIND, _G_GLINT_MU_FLOOR, _G_WATER_INDEX, _G_WATER_DIFFUSE, _G_FROM_ABOVE) = range(20)
# the workers of a render's first chunks may ask for the tables together: one builds them
_TABLES_LOCK = threading.Lock()


def ground_tables():
    """The constants of the ground's term as one float64 vector (layout: the ``_G_*`` indices of this module) and
    its arrays: copies of the RPV and snow normalisation tables of :mod:`swim.surface.brdf` (kept on disk between
    processes), the snow albedo and the water's subsurface reflectance at 615/546/450 nm, and the e-folding
    distances [cells] of the ground's fields beyond the grid (:func:`swim.rt.march_inputs.surface_fade_cells`). Made once
    per process (thread-safe).

    Returns
    -------
    dict
        ``coefficients`` (20,), ``rpv_q`` (257,), ``snow_table`` (11, 257), ``snow_albedo`` (3,),
        ``subsurface`` (3,), ``fade_cells`` (14,); float64, read-only.
    """
    with _TABLES_LOCK:
        return _ground_tables()


@functools.cache
def _ground_tables():
    c1, e1, c2, e2 = brdf.SNOW_PHASE_COEFFS
    k = np.array([lighting.MIN_VIEW_COSINE, lighting.MIN_WATER_VIEW_COSINE, brdf.MU_MIN, brdf.RPV_K, brdf.RPV_THETA_HG,
                  brdf.RPV_HOT_SPOT, brdf.SNOW_R0_A, brdf.SNOW_R0_B, brdf.SNOW_R0_C, c1, e1, c2, e2,
                  brdf.SNOW_SHAPE_ALBEDO_MIN, water.COX_MUNK_MSS_OFFSET, water.COX_MUNK_MSS_PER_WIND,
                  water.GLINT_MU_FLOOR, water.WATER_REFRACTIVE_INDEX, water.water_diffuse_albedo(), FROM_ABOVE_BLEND],
                 dtype=np.float64)
    out = {"coefficients": k, "rpv_q": np.array(brdf._rpv_table(brdf.RPV_K, brdf.RPV_THETA_HG, brdf.RPV_HOT_SPOT)),
           "snow_table": np.array(brdf._snow_table()), "snow_albedo": np.array(brdf.SNOW_ALBEDO, dtype=np.float64),
           "subsurface": np.array(water.WATER_SUBSURFACE_REFLECTANCE, dtype=np.float64),
           # the 11 fields of surface_fields, then the diffuse solution's 3 ratios of the ground's skylight
           # (cloud_scattering="discrete_ordinates"), which fade as the lighting does
           "fade_cells": surface_fade_cells(14).astype(np.float64)}
    for a in out.values():
        a.flags.writeable = False  # one compiled type for every call (read-only arrays)
    return out


@helper_jit(inline="always")
def _dot(a0, a1, a2, b0, b1, b2):
    return a0 * b0 + a1 * b1 + a2 * b2


@helper_jit()
def _lerp_mu(table, mu):
    """:func:`swim.surface.brdf._lerp_mu` on a 1-D table given on the uniform grid 0...1."""
    n = table.shape[0]
    x = _clip(mu, 0.0, 1.0) * (n - 1)
    i0 = int(_clip(math.floor(x), 0.0, n - 2.0))
    f = x - i0
    return table[i0] * (1.0 - f) + table[i0 + 1] * f


@helper_jit()
def _lerp_snow(table, mu, albedo, albedo_min):
    """:func:`swim.surface.brdf._lerp_snow`: the snow table (albedo nodes, uniform mu grid) at (albedo, mu)."""
    n_a, n_mu = table.shape
    y = (_clip(albedo, albedo_min, 1.0) - albedo_min) / (1.0 - albedo_min) * (n_a - 1)
    j0 = int(_clip(math.floor(y), 0.0, n_a - 2.0))
    fy = y - j0
    x = _clip(mu, 0.0, 1.0) * (n_mu - 1)
    i0 = int(_clip(math.floor(x), 0.0, n_mu - 2.0))
    fx = x - i0
    lo = table[j0, i0] * (1.0 - fx) + table[j0, i0 + 1] * fx
    hi = table[j0 + 1, i0] * (1.0 - fx) + table[j0 + 1, i0 + 1] * fx
    return lo * (1.0 - fy) + hi * fy


@helper_jit()
def _fresnel(c, n):
    """:func:`swim.surface.water.fresnel_reflectance` (Born and Wolf, Sect. 1.5.2)."""
    c = _clip(c, 0.0, 1.0)
    ct = math.sqrt(1.0 - (1.0 - c * c) / (n * n))
    rs = (c - n * ct) / (c + n * ct)
    rp = (n * c - ct) / (n * c + ct)
    return 0.5 * (rs * rs + rp * rp)


@helper_jit()
def _mu_times_smith_lambda(mu, sigma):
    """:func:`swim.surface.water._mu_times_smith_lambda` (Smith 1967 shadowing, isotropic Gaussian slopes)."""
    s = math.sqrt(max(1.0 - mu * mu, 1e-12))
    a = mu / (sigma * s)
    return 0.5 * (s * sigma / math.sqrt(math.pi) * math.exp(-a * a) - mu * math.erfc(a))


@helper_jit()
def _sun_glint(mu_i, mu_v, cos_sv, tan2, wind_speed, k):
    """:func:`swim.surface.water.sun_glint_reflectance_factor_cox_munk1954` with the Smith shadowing, given the
    cosines of sun and view to the normal, their mutual cosine and tan^2 of the tilt of the mirroring facet."""
    s2 = k[_G_MSS_OFFSET] + k[_G_MSS_PER_WIND] * max(wind_speed, 0.0)
    cos_omega = math.sqrt(_clip(0.5 * (1.0 + cos_sv), 0.0, 1.0))
    rho = _fresnel(cos_omega, k[_G_WATER_INDEX])
    facet = math.exp(-tan2 / s2) / (math.pi * s2) * (1.0 + tan2) ** 2
    mi = max(mu_i, k[_G_GLINT_MU_FLOOR])
    mv = max(mu_v, k[_G_GLINT_MU_FLOOR])
    sigma = math.sqrt(s2)
    denom = mi * mv + mv * _mu_times_smith_lambda(mi, sigma) + mi * _mu_times_smith_lambda(mv, sigma)
    return math.pi * rho * facet / (4.0 * denom)


@helper_jit()
def _rpv_shape(mi, mv, cos_sv, hot_g, k, rpv_q):
    """:func:`swim.surface.brdf._rpv_shape` of a visible geometry (RPV 1993, normalised)."""
    kk, theta, rho_c = k[_G_RPV_K], k[_G_RPV_THETA], k[_G_RPV_HOT_SPOT]
    minnaert = (mi + mv) ** (kk - 1.0)
    hg = (1.0 - theta * theta) / (1.0 + theta * theta + 2.0 * theta * cos_sv) ** 1.5
    hot = 1.0 + (1.0 - rho_c) / (1.0 + hot_g)
    return minnaert * hg * hot * _lerp_mu(rpv_q, mi) * _lerp_mu(rpv_q, mv)


@helper_jit()
def _snow_shape(mi, mv, phase_sv, albedo, k, snow_table):
    """:func:`swim.surface.brdf._snow_shape` of a visible geometry (Kokhanovsky and Breon 2012, normalised), with
    the snow grains' phase function at the scattering angle already evaluated (``phase_sv``)."""
    a = _clip(albedo, k[_G_SNOW_ALBEDO_MIN], 1.0)
    mu_sum = mi + mv
    r0 = (k[_G_SNOW_A] + k[_G_SNOW_B] * mu_sum + k[_G_SNOW_C] * mi * mv + phase_sv) / (4.0 * mu_sum)
    escape = (3.0 / 7.0) ** 2 * (1.0 + 2.0 * mi) * (1.0 + 2.0 * mv)
    raw = r0 * math.exp(math.log(a) * (escape / r0))
    albedo_min = k[_G_SNOW_ALBEDO_MIN]
    return raw * _lerp_snow(snow_table, mi, a, albedo_min) * _lerp_snow(snow_table, mv, a, albedo_min)


@helper_jit(inline="always")
def _diffuse_on_facet(sky_view, mu_s, albedo, direct, diffuse, c):
    """Diffuse irradiance on the facet / E_TOA at wavelength c: the sky it sees and the Lambertian ground around it
    (same albedo) lit by the global horizontal irradiance (:func:`swim.surface.lighting.surface_radiance`)."""
    return sky_view * diffuse[c] + (1.0 - sky_view) * albedo[c] * (mu_s * direct[c] + diffuse[c])


@helper_jit()
def surface_radiance(up, view, sun, slope_x, slope_y, albedo, land_fraction, snow_cover, wind_speed, direct, diffuse,
                     lambertian, k, rpv_q, snow_table, snow_albedo, subsurface, out):
    """:func:`swim.surface.lighting.surface_radiance` at one point (Eq. 35 on a tilted facet), written to ``out``.

    Parameters
    ----------
    up, view, sun : numpy.ndarray
        Shape (3,): unit vectors of the local vertical, towards the observer and towards the sun [-].
    slope_x, slope_y : float
        Terrain gradient dh/dx, dh/dy [-].
    albedo : numpy.ndarray
        Shape (3,): snow-free spectral albedo at 615/546/450 nm [-].
    land_fraction, snow_cover, wind_speed : float
        Land fraction [-], snow cover of the land [-], wind speed at 10 m [m s-1].
    direct, diffuse : numpy.ndarray
        Shape (3,): direct-beam irradiance on a plane normal to the sun and diffuse irradiance on a horizontal plane,
        each / E_TOA [-].
    lambertian : bool
        R = albedo (``model="lambertian"``) instead of the land, snow and water BRDFs.
    k, rpv_q, snow_table, snow_albedo, subsurface : numpy.ndarray
        The constants and tables of :func:`ground_tables`.
    out : numpy.ndarray
        Shape (3,), written: L' [-] leaving the ground towards the observer.
    """
    u0, u1, u2 = up[0], up[1], up[2]
    # facet_normal: water is flat whatever a coastal cell's gradient says
    gx, gy = (slope_x, slope_y) if land_fraction >= 0.5 else (0.0, 0.0)
    g_up = gx * u0 + gy * u1
    n0, n1, n2 = u0 - (gx - g_up * u0), u1 - (gy - g_up * u1), u2 + g_up * u2
    norm = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    n0, n1, n2 = n0 / norm, n1 / norm, n2 / norm
    cos_i = max(_dot(n0, n1, n2, sun[0], sun[1], sun[2]), 0.0)
    sky_view = 0.5 * (1.0 + _dot(n0, n1, n2, u0, u1, u2))
    mu_s = max(_dot(u0, u1, u2, sun[0], sun[1], sun[2]), 0.0)
    if lambertian:
        for c in range(3):
            diffuse_facet = _diffuse_on_facet(sky_view, mu_s, albedo, direct, diffuse, c)
            out[c] = 4.0 * albedo[c] * (cos_i * direct[c] + diffuse_facet)
        return
    v0, v1, v2 = view[0], view[1], view[2]
    if _dot(n0, n1, n2, v0, v1, v2) <= k[_G_MIN_VIEW_COSINE]:  # seen edge-on or from behind: the local horizontal
        n0, n1, n2 = u0, u1, u2
    # surface_reflectance_factor's geometry (brdf._geometry) on the BRDF's normal
    s0, s1, s2 = sun[0], sun[1], sun[2]
    mu_i = _dot(s0, s1, s2, n0, n1, n2)
    mu_v = _dot(v0, v1, v2, n0, n1, n2)
    visible = mu_i > 0.0 and mu_v > 0.0
    f = _clip(land_fraction, 0.0, 1.0)
    s = _clip(snow_cover, 0.0, 1.0)
    n_w = k[_G_WATER_INDEX]
    rpv = 0.0
    glint = 0.0
    leaving = 0.0
    phase_sv = 0.0
    mi = max(mu_i, k[_G_MU_MIN])
    mv = max(mu_v, k[_G_MU_MIN])
    if visible:
        cos_sv = _clip(_dot(s0, s1, s2, v0, v1, v2), -1.0, 1.0)
        # the RPV hot-spot distance G: |tangent vector of the sun - that of the view| along the surface
        d0 = (s0 - mu_i * n0) / mi - (v0 - mu_v * n0) / mv
        d1 = (s1 - mu_i * n1) / mi - (v1 - mu_v * n1) / mv
        d2 = (s2 - mu_i * n2) / mi - (v2 - mu_v * n2) / mv
        rpv = _rpv_shape(mi, mv, cos_sv, math.sqrt(d0 * d0 + d1 * d1 + d2 * d2), k, rpv_q)
        theta_deg = math.degrees(math.acos(-cos_sv))
        phase_sv = (k[_G_SNOW_C1] * math.exp(-k[_G_SNOW_E1] * theta_deg)
                    + k[_G_SNOW_C2] * math.exp(-k[_G_SNOW_E2] * theta_deg))
        # Cox-Munk: the tilt of the facet that mirrors the sun into the view (half vector), from the mean normal
        mu_sum = max(mu_i + mu_v, 1e-6)
        w0 = s0 + v0 - (mu_i + mu_v) * n0
        w1 = s1 + v1 - (mu_i + mu_v) * n1
        w2 = s2 + v2 - (mu_i + mu_v) * n2
        tan2 = (w0 * w0 + w1 * w1 + w2 * w2) / (mu_sum * mu_sum)
        glint = _sun_glint(mu_i, mu_v, _dot(s0, s1, s2, v0, v1, v2), tan2, wind_speed, k)
        leaving = (1.0 - _fresnel(mu_i, n_w)) * (1.0 - _fresnel(mu_v, n_w)) / (n_w * n_w)
    rho_bar = k[_G_WATER_DIFFUSE]
    r_int = 1.0 - (1.0 - rho_bar) / (n_w * n_w)
    # water mirrors the (isotropic) sky with the Fresnel reflectance of the view angle
    mu_water = _clip(_dot(v0, v1, v2, u0, u1, u2), k[_G_MIN_WATER_VIEW_COSINE], 1.0)
    specular_sky = _fresnel(mu_water, n_w) - rho_bar
    for c in range(3):
        # the subsurface reflectance with the light reflected back down at the surface, R_sub / (1 - r_int R_sub)
        r_sub = subsurface[c] / (1.0 - r_int * subsurface[c])
        snow = snow_albedo[c] * _snow_shape(mi, mv, phase_sv, snow_albedo[c], k, snow_table) if visible else 0.0
        r_direct = f * ((1.0 - s) * rpv * albedo[c] + s * snow) + (1.0 - f) * (glint + leaving * r_sub)
        # surface_diffuse_albedo, plus the water's view-angle Fresnel mirror of the sky
        a_diffuse = (f * ((1.0 - s) * albedo[c] + s * snow_albedo[c])
                     + (1.0 - f) * (rho_bar + r_sub * (1.0 - rho_bar) ** 2 / (n_w * n_w) + specular_sky))
        out[c] = 4.0 * (r_direct * cos_i * direct[c]
                        + a_diffuse * _diffuse_on_facet(sky_view, mu_s, albedo, direct, diffuse, c))


@helper_jit(inline="always")
def _sky_coordinates(h, mu_s, top):
    """The sky table's coordinates at a point of height ``h`` [m] and local solar-zenith cosine ``mu_s``:
    sqrt(h / top) and (mu_s + 1) / 2, each in [0, 1] (``_gas_at``)."""
    return math.sqrt(_clip(h / top, 0.0, 1.0)), (mu_s + 1.0) * 0.5


@helper_jit(inline="always")
def _class_corners(fu, fm, c0, n_rows, nu_class, nmu_class):
    """The corners and weights of the skylight of the aerosol column class ``c0`` and of the next one
    (``diffuse_at``), in the classes' table of ``n_rows`` rows (``nu_class`` per class) and ``nmu_class`` columns,
    at the sky table's coordinates (fu, fm)."""
    fcu = _clip(fu * (nu_class - 1), 0.0, nu_class - 1.001)
    cu0, cv0, ca, cb = _bilinear_index(n_rows, nmu_class, c0 * nu_class + fcu, fm * (nmu_class - 1))
    cu1, cv1, ca1, cb1 = _bilinear_index(n_rows, nmu_class, (c0 + 1) * nu_class + fcu, fm * (nmu_class - 1))
    return cu0, cv0, ca, cb, cu1, cv1, ca1, cb1


@helper_jit(inline="always")
def _field_corner(j, i, margin, ny, nx):
    """The corner and weights of a clamped bilinear lookup of the ground's fields (ny, nx), which extend ``margin``
    cells beyond the grid, at the grid indices (j, i), and the distance [cells] of (j, i) beyond the fields' edge."""
    j += margin
    i += margin
    dj = max(max(-j, j - (ny - 1)), 0.0)
    di = max(max(-i, i - (nx - 1)), 0.0)
    d = math.sqrt(dj * dj + di * di)
    fj0, fi0, fa, fb = _bilinear_index(ny, nx, _clip(j, 0.0, ny - 1.0), _clip(i, 0.0, nx - 1.0))
    return fj0, fi0, fa, fb, d


@helper_jit(inline="always")
def _local_vertical(q0, q1, q2, radius):
    """The unit vector of the local vertical at the point q (scene frame, rebased; the earth's centre at
    (0, 0, -radius))."""
    pz = q2 + radius
    norm = math.sqrt(q0 * q0 + q1 * q1 + pz * pz)
    return q0 / norm, q1 / norm, pz / norm


@helper_jit(inline="always")
def _view_from_above(cos_view_zenith, from_above):
    """The view's downward cosine and the weight of the view from above (``FROM_ABOVE_BLEND``: ``from_above``)."""
    mu_down = -cos_view_zenith
    return mu_down, _clip(mu_down / from_above, 0.0, 1.0)


@njit(**JIT_KERNEL, nogil=True)
def ground_radiance(start, direction, s_hit, surface, cos_view_zenith, tau_h, tau_clear, tau_packed, species,
                    class_lower, class_weight, p, coef, sky, diffuse_classes, n_class, fields, fields_outside,
                    angstrom, backscatter, lambertian, compose_coefficients, k, rpv_q, snow_table, snow_albedo,
                    subsurface, fade_cells, cloud_mode, out):
    """The ground's part of the pixel radiance of n rays, as :func:`swim.rt.march_jax._ground_radiance` (Eq. 35).

    Parameters
    ----------
    start, direction : numpy.ndarray
        Shape (n, 3): the rays' rebased start [m] and unit direction (float64, as the march takes them).
    s_hit : numpy.ndarray
        Shape (n,): distance along each ray to its ground point [m].
    surface : numpy.ndarray
        Shape (n,) bool: rays that end on the ground (the others get 0).
    cos_view_zenith : numpy.ndarray
        Shape (n,): cosine of the view zenith angle at the observer [-].
    tau_h, tau_clear, tau_packed : numpy.ndarray
        Shapes (n,), (n, 3), (n, m): the march's hydrometeor, clear-sky (per wavelength) and packed species' optical
        depths along each ray [-]; ``species`` (m,) int: the packed species' indices into
        :data:`swim.constants.SPECIES`.
    class_lower, class_weight : numpy.ndarray
        Shape (n,): each ray's aerosol column class and its weight towards the next (:func:`swim.rt.march_cpu.
        prepare_rays`).
    p, coef, sky, diffuse_classes, n_class, angstrom : numpy.ndarray or int
        The march's tables (:func:`swim.rt.march._numba_tables`).
    fields : numpy.ndarray
        Shape (11, ny + 2 m, nx + 2 m): :func:`swim.rt.march_inputs.surface_fields`, channel-major, with a margin of m
        cells (``p``'s surface margin) beyond the grid (:func:`swim.rt.march_inputs.extended_surface`);
        ``fields_outside`` (11,): the ground far beyond it (:func:`swim.rt.march_inputs.surface_fields_outside`).
    backscatter : numpy.ndarray
        Shape (5,): backscatter fraction of each species of SPECIES [-].
    lambertian : bool
        Lambertian ground (``MarchSettings.surface == "lambertian"``) instead of the BRDFs.
    compose_coefficients : numpy.ndarray
        :data:`swim.rt.compose_cpu.COEFFICIENTS` (the delta-Eddington transmittance's constant).
    k, rpv_q, snow_table, snow_albedo, subsurface, fade_cells : numpy.ndarray
        :func:`ground_tables`.
    cloud_mode : bool
        ``cloud_scattering="discrete_ordinates"``: ``fields`` has 14 channels, channel 8 is the direct beam's scaled
        transmittance e^{-tau*_s} and 11-13 the ratio of the ground's diffuse irradiance to the clear sky's (the
        3-D diffuse solution, :mod:`swim.rt.diffuse_field`), which light the ground in place of T; ``backscatter``
        holds each species' 1 - f (delta-M), and the ground is seen through e^{-tau*} of the scaled optical depth.
    out : numpy.ndarray
        Shape (n, 3), written: L' of the ground seen by the observer [-].
    """
    radius, top, margin = p[_P_RADIUS], p[_P_TOP], p[_P_SURFACE_MARGIN]
    nu_sky, nmu_sky, n_rows, nmu_class = sky.shape[1], sky.shape[2], diffuse_classes.shape[1], diffuse_classes.shape[2]
    nu_class = n_rows // n_class
    n_fields, ny, nx = fields.shape
    sun = p[_P_SUN:_P_SUN + 3]
    up, view, albedo, direct, diffuse, radiance = (np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty(3),
                                                   np.empty(3))
    value = np.empty(n_fields)
    for r in range(start.shape[0]):
        if not surface[r]:
            for c in range(3):
                out[r, c] = 0.0
            continue
        q0 = start[r, 0] + s_hit[r] * direction[r, 0]
        q1 = start[r, 1] + s_hit[r] * direction[r, 1]
        q2 = start[r, 2] + s_hit[r] * direction[r, 2]
        h, mu_s, _, j, i = _point_geometry(q0, q1, q2, p, coef)
        # _gas_at's sun transmittance and diffuse irradiance, or diffuse_at's of the ray's aerosol class
        fu, fm = _sky_coordinates(h, mu_s, top)
        su0, sv0, sa, sb = _bilinear_index(nu_sky, nmu_sky, fu * (nu_sky - 1), fm * (nmu_sky - 1))
        for c in range(3):
            direct[c] = _bilinear_at(sky, c, su0, sv0, sa, sb)
            diffuse[c] = _bilinear_at(sky, 3 + c, su0, sv0, sa, sb)
        if n_class > 1:
            wc = class_weight[r]
            cu0, cv0, ca, cb, cu1, cv1, ca1, cb1 = _class_corners(fu, fm, class_lower[r], n_rows, nu_class, nmu_class)
            for c in range(3):
                diffuse[c] = (_bilinear_at(diffuse_classes, c, cu0, cv0, ca, cb) * (1 - wc)
                              + _bilinear_at(diffuse_classes, c, cu1, cv1, ca1, cb1) * wc)
        # the ground's fields (surface_beyond_edge of bilinear_clamped): beyond their margin a fade from the margin's
        # edge to the far ground
        fj0, fi0, fa, fb, d = _field_corner(j, i, margin, ny, nx)
        for c in range(n_fields):
            w = math.exp(-d / fade_cells[c])
            value[c] = fields_outside[c] + (_bilinear_at(fields, c, fj0, fi0, fa, fb) - fields_outside[c]) * w
        t_cloud, shadow = value[8], value[9]
        for c in range(3):
            albedo[c] = value[c]
            direct[c] *= math.exp(-value[10] * angstrom[c]) * (t_cloud * shadow)
            diffuse[c] *= value[11 + c] if cloud_mode else t_cloud
        up[0], up[1], up[2] = _local_vertical(q0, q1, q2, radius)
        view[0], view[1], view[2] = -direction[r, 0], -direction[r, 1], -direction[r, 2]
        surface_radiance(up, view, sun, value[6], value[7], albedo, value[3], value[4], value[5], direct, diffuse,
                         lambertian, k, rpv_q, snow_table, snow_albedo, subsurface, radiance)
        # seen from above, the ground under a cloud layer shines through the layer's total (direct + diffuse)
        # transmittance at the view angle; rays that do not look down keep the direct e^-tau
        mu_down, w_above = _view_from_above(cos_view_zenith[r], k[_G_FROM_ABOVE])
        b_tau = 0.0
        for m in range(species.shape[0]):
            b_tau += tau_packed[r, m] * backscatter[species[m]]
        # cloud_mode: through the delta-M scaled optical depth, so that the forward peak stays in the view
        t_hydro = math.exp(-b_tau) if cloud_mode else ((1.0 - w_above) * math.exp(-tau_h[r]) + w_above * (
            _transmittance_delta_eddington(tau_h[r], b_tau, max(mu_down, k[_G_FROM_ABOVE]), compose_coefficients)))
        for c in range(3):
            out[r, c] = radiance[c] * math.exp(-tau_clear[r, c]) * t_hydro
