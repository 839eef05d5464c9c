"""Slow plain-NumPy reference of the ray march (for tests on tiny grids).

Same physics as :mod:`swim.rt.march`, written independently: float64, SciPy's
``RegularGridInterpolator`` for the trilinear sampling, one uniform fine step size over the whole ray
instead of three segments, and a ray-by-ray Python loop. The JAX kernel is tested against it.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from ..constants import BACKSCATTER_FRACTION, EARTH_RADIUS_M, SPECIES
from ..frames import ray_sphere_intersections
from ..optics.phase import (
    anisotropic_reflectance_factor_kokhanovsky2004,
    cloud_albedo_stephens1978,
    effective_phase_function,
)
from .march import FROM_ABOVE_BLEND, G_LIQUID, grid_geometry


def reference_trace_ray(origin, direction, volume, transmittance, gas, sun, p_rayleigh, p_aerosol,
                        step_m=50.0, radius=EARTH_RADIUS_M):
    """Trace one ray with fine uniform steps; returns the same quantities as the kernel (float64).

    Parameters
    ----------
    origin, direction : array_like
        Shape (3,): scene-frame origin [m] and unit direction.
    volume, transmittance : xarray.Dataset
        Optical volume and Step 1a result.
    gas : swim.rt.gas.GasTables
    sun : array_like
        Shape (3,): unit vector towards the sun (scene frame).
    p_rayleigh, p_aerosol : float
        Phase functions at this ray's scattering angle (mean 1 over the sphere).
    step_m : float
        Step length [m].

    Returns
    -------
    dict
        ``radiance``, ``radiance_clear``, ``radiance_cloud``, ``radiance_surface`` (3,);
        ``tau_hydrometeor`` (float); ``tau_clear`` (3,); ``surface`` (bool).
    """
    o = np.asarray(origin, float)
    d = np.asarray(direction, float)
    sun = np.asarray(sun, float)
    geo = grid_geometry(volume)
    nk, ny, nx = geo.shape
    axes = (np.arange(nk), np.arange(ny), np.arange(nx))
    ext = np.concatenate([volume["extinction"].values, volume["aerosol_extinction"].values[None]], axis=0)
    interp_ext = [RegularGridInterpolator(axes, ext[c].astype(float), bounds_error=False, fill_value=0.0) for c in range(ext.shape[0])]
    interp_t = RegularGridInterpolator(axes, transmittance["transmittance"].values.astype(float), bounds_error=False, fill_value=1.0)
    interp_terrain = RegularGridInterpolator(axes[1:], volume["terrain_height"].values.astype(float), bounds_error=False, fill_value=None)
    albedo = volume["surface_albedo"].values.astype(float)
    heights = np.arange(gas.beta_rayleigh.shape[0]) * gas.dh
    u_axis = np.linspace(0, 1, gas.n_u)
    mu_axis = np.linspace(-1, 1, gas.n_mu)
    t_sun_interp = RegularGridInterpolator((u_axis, mu_axis), gas.sun_transmittance.astype(float))
    diffuse_interp = RegularGridInterpolator((u_axis, mu_axis), gas.diffuse_horizontal.astype(float))

    t1, t2 = ray_sphere_intersections(o, d, radius + gas.top_m)
    if not np.isfinite(t2) or t2 <= 0:
        return None
    s0 = max(t1, 0.0)
    s1 = t2
    g1, _ = ray_sphere_intersections(o, d, radius)
    sea = np.isfinite(g1) and 0 < g1 < s1
    if sea:
        s1 = g1
    n = max(int(np.ceil((s1 - s0) / step_m)), 1)
    ds = (s1 - s0) / n

    def at(s):
        p = o + s * d
        r = np.linalg.norm(p)
        h = r - radius
        x, y = radius * p[:2] / r - geo.origin
        i, j = geo.inverse @ np.array([x, y])
        k = (h - geo.z_bottom) / geo.dz
        mu_s = p @ sun / r
        return h, mu_s, k, j, i

    def gas_at(h, mu_s):
        hh = np.clip(h, 0, gas.top_m)
        br = np.array([np.interp(hh, heights, gas.beta_rayleigh[:, c]) for c in range(3)])
        ba = np.array([np.interp(hh, heights, gas.beta_aerosol[:, c]) for c in range(3)])
        point = [[np.sqrt(hh / gas.top_m), np.clip(mu_s, -1, 1)]]
        return br, ba, t_sun_interp(point)[0], diffuse_interp(point)[0]

    tau_c = np.zeros(3)
    tau_sp = np.zeros(len(SPECIES))
    l_clear = np.zeros(3)
    i_gas = np.zeros(3)
    i_nogas = np.zeros(3)
    surface = sea
    s_end = s1
    prev_gap = None
    for m in range(n):
        s = s0 + (m + 0.5) * ds
        h, mu_s, k, j, i = at(s)
        inside = 0 <= i <= nx - 1 and 0 <= j <= ny - 1
        terrain = float(interp_terrain([[np.clip(j, 0, ny - 1), np.clip(i, 0, nx - 1)]])[0]) if inside else 0.0
        gap = h - terrain
        frac = 1.0
        if inside and gap < 0:
            frac = np.clip(prev_gap / (prev_gap - gap), 0, 1) if prev_gap is not None else 0.5
            surface = True
            s_end = s - 0.5 * ds + frac * ds
        prev_gap = gap
        point = [[k, j, i]]
        beta = np.array([f(point)[0] for f in interp_ext])
        beta_sp = beta[:-1]
        br, ba, t_sun, _ = gas_at(h, mu_s)
        beta_a3 = beta[-1] * gas.angstrom_factor
        e = t_sun * float(interp_t(point)[0])
        beta_clear = br + ba + beta_a3
        beta_h = beta_sp.sum()
        step = ds * frac
        # Exact attenuation within the step for a constant extinction.
        x = (beta_clear + beta_h) * step
        mean = np.where(x > 1e-8, -np.expm1(-x) / np.maximum(x, 1e-300), 1.0)
        t_obs = np.exp(-(tau_c + tau_sp.sum()))
        l_clear += t_obs * (br * p_rayleigh + (ba + beta_a3) * gas.aerosol.ssa * p_aerosol) * e * step * mean
        t0 = tau_sp.sum()
        t1_ = t0 + beta_h * step
        w = max(np.exp(-t0) - np.exp(-min(t1_, 2.0)), 0.0)
        i_nogas += e * w
        i_gas += e * np.exp(-tau_c) * w
        tau_c += beta_clear * step
        tau_sp += beta_sp * step
        if surface and s_end < s1:
            break

    tau = tau_sp.sum()
    l_surface = np.zeros(3)
    if surface:
        h, mu_s, k, j, i = at(s_end)
        _, _, t_sun, diffuse = gas_at(h, mu_s)
        t_cloud = float(interp_t([[k + 1.0, j, i]])[0])
        rho = np.array([RegularGridInterpolator(axes[1:], albedo[c], bounds_error=False, fill_value=None)(
            [[np.clip(j, 0, ny - 1), np.clip(i, 0, nx - 1)]])[0] for c in range(3)])
        e_h = (max(mu_s, 0.0) * t_sun + diffuse) * t_cloud
        l_surface = 4 * rho * e_h * np.exp(-(tau_c + tau))

    l_cloud = np.zeros(3)
    if tau > 1e-6:
        norm = -np.expm1(-min(tau, 2.0))
        e_mean = i_nogas / norm
        weights = tau_sp / tau
        cos_theta = float(d @ sun)
        phase = np.asarray(effective_phase_function(np.array([cos_theta]), np.array([d[2]]), np.array([tau]),
                                                    e_mean[None], weights[None, None, :], np.asarray(G_LIQUID)[None]))[0]
        l_12 = phase * (-np.expm1(-tau) / norm) * i_gas
        mu_down = -d[2]
        mu0 = sun[2]
        b_eff = weights @ np.array([BACKSCATTER_FRACTION[s] for s in SPECIES])
        a = float(cloud_albedo_stephens1978(tau * max(mu_down, 0) / max(mu0, 0.05), b_eff))
        arf = float(anisotropic_reflectance_factor_kokhanovsky2004(max(mu_down, 1e-3), max(mu0, 1e-3), cos_theta))
        l_top = 4 * max(mu0, 0) * arf * e_mean * (i_gas / np.maximum(i_nogas, 1e-300))
        w_above = np.clip(mu_down / FROM_ABOVE_BLEND, 0, 1)
        l_cloud = (1 - w_above) * l_12 + w_above * ((1 - a) * l_12 + a * l_top)
    return {
        "radiance": l_clear + l_cloud + l_surface,
        "radiance_clear": l_clear,
        "radiance_cloud": l_cloud,
        "radiance_surface": l_surface,
        "tau_hydrometeor": tau,
        "tau_clear": tau_c,
        "surface": surface,
    }
