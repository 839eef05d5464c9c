"""Slow plain-NumPy reference of the ray march (for tests on tiny grids).

Same physics as :mod:`swim.rt.march`, written independently: float64, SciPy's
``RegularGridInterpolator`` for the trilinear sampling, one uniform fine step size over the whole ray
instead of three segments, and a ray-by-ray Python loop. The JAX kernel is tested against it.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from ..constants import BACKSCATTER_FRACTION, EARTH_RADIUS_M, SPECIES
from ..frames import ray_sphere_intersections
from ..optics.phase import (
    anisotropic_reflectance_factor_kokhanovsky2004,
    blend_coefficient,
    delta_scaled_path_factor,
    diffuse_transmission_factor,
    effective_phase_function,
    forward_peak_mixture,
    phase_thin_mixture,
)
from ..optics.volume import grid_indices
from ..surface.lighting import surface_radiance
from ..optics.phase import G_LIQUID
from .march_inputs import aerosol_column_optical_depth, extended_surface, grid_geometry
from .surface_margin import surface_fade_cells
from .march_settings import FROM_ABOVE_BLEND, SKYLIGHT_SCALAR_FACTOR
from .march_inputs import surface_fields as march_surface_fields
from .march_inputs import surface_fields_outside as march_surface_fields_outside
from .solar import transmittance_delta_eddington


def _class_weights(o, d, s0, s1, volume, gas, radius):
    """[(class index, weight)] of the 3-D aerosol column at the ray's lowest point (as the kernel)."""
    class_aod = np.asarray(gas.aerosol_class_aod, float)
    if class_aod.size == 1:
        return [(0, 1.0)]
    p = o + float(np.clip(-(o @ d), s0, s1)) * d
    r = np.linalg.norm(p)
    i, j = grid_indices(volume.attrs, radius * p[0] / r, radius * p[1] / r)
    column = aerosol_column_optical_depth(volume).values.astype(float)
    ny, nx = column.shape
    value = float(RegularGridInterpolator((np.arange(ny), np.arange(nx)), column)(
        [[np.clip(float(j), 0, ny - 1), np.clip(float(i), 0, nx - 1)]])[0])
    f = float(np.interp(value, class_aod, np.arange(class_aod.size)))
    c0 = min(int(np.floor(f)), class_aod.size - 2)
    return [(c0, 1.0 - (f - c0)), (c0 + 1, f - c0)]


def _diffuse_source(o, d, s0, s1, heights, gas, sun, classes):
    """Diffuse source (n, 9) of :mod:`swim.rt.multiple_scattering` at the ray's heights.

    Local sun/view angles are taken at the ray's lowest point between s0 and s1 (as the kernel does), the
    table(s) of its aerosol column class ``classes`` (:func:`_class_weights`); 4-D linear interpolation
    with SciPy.
    """
    s_low = float(np.clip(-(o @ d), s0, s1))
    up = o + s_low * d
    up = up / np.linalg.norm(up)
    mu_v = float(up @ d)
    mu_s = float(up @ sun)
    cos_phi = (float(d @ sun) - mu_v * mu_s) / np.sqrt(max((1 - mu_v**2) * (1 - mu_s**2), 1e-12))
    phi = np.degrees(np.arccos(np.clip(cos_phi, -1, 1)))
    u = np.sqrt(np.clip(heights / gas.top_m, 0, 1))
    out = 0.0
    for c, w in classes:
        table = gas.diffuse_sources[c]
        axes = (table.t_s, table.mu_v, table.phi_deg, table.u)
        t_s = np.clip(np.sign(mu_s) * np.sqrt(min(abs(mu_s), 1.0)), table.t_s[0], 1.0)  # the table's sun axis
        points = np.stack(np.broadcast_arrays(t_s, mu_v, phi, u), axis=-1)
        out = out + w * np.stack([RegularGridInterpolator(axes, table.source[..., k].astype(float))(points)
                                  for k in range(table.source.shape[-1])], axis=-1)
    return out


def _interpolators(volume, transmittance, gas):
    """The ray's samplers: SciPy interpolators of the volume, Step 1a, the ground and the gas tables."""
    geo = grid_geometry(volume)
    nk, ny, nx = geo.shape
    axes = (np.arange(nk), np.arange(ny), np.arange(nx))
    ext = np.concatenate([volume["extinction"].values, volume["aerosol_extinction"].values[None]], axis=0)
    interp_ext = [RegularGridInterpolator(axes, ext[c].astype(float), bounds_error=False, fill_value=0.0) for c in range(ext.shape[0])]
    interp_t = RegularGridInterpolator(axes, transmittance["transmittance"].values.astype(float), bounds_error=False, fill_value=1.0)
    # the cloud T alone dims the skylight; the terrain shadow (in "transmittance") only the direct beam
    interp_tc = RegularGridInterpolator(axes, transmittance["cloud_transmittance"].values.astype(float), bounds_error=False,
                                        fill_value=1.0)
    interp_tau_aer = RegularGridInterpolator(axes, transmittance["aerosol_tau_sun"].values.astype(float), bounds_error=False,
                                             fill_value=0.0)
    interp_terrain = RegularGridInterpolator(axes[1:], volume["terrain_height"].values.astype(float), bounds_error=False, fill_value=None)
    packed_surface = march_surface_fields(volume, transmittance)
    outside = march_surface_fields_outside(packed_surface)
    # the ground's fields with their margin beyond the grid, as the kernels read them
    extended, margin = extended_surface(volume, np.moveaxis(packed_surface, -1, 0), outside)
    surface_fields = [np.asarray(f, dtype=float) for f in extended]
    surface_axes = (np.arange(extended.shape[1]), np.arange(extended.shape[2]))
    heights = np.arange(gas.beta_rayleigh.shape[0]) * gas.dh
    u_axis = np.linspace(0, 1, gas.n_u)
    mu_axis = np.linspace(-1, 1, gas.n_mu)
    t_sun_interp = RegularGridInterpolator((u_axis, mu_axis), gas.sun_transmittance.astype(float))
    return SimpleNamespace(geo=geo, ext=interp_ext, t=interp_t, tc=interp_tc, tau_aer=interp_tau_aer,
                           terrain=interp_terrain, outside=outside, extended=extended, margin=margin,
                           surface_fields=surface_fields, surface_axes=surface_axes, heights=heights,
                           u_axis=u_axis, mu_axis=mu_axis, t_sun=t_sun_interp)


def _ray_span(o, d, gas, radius):
    """(s0, s1, sea): the ray's distances [m] inside the atmosphere, ending at the sea; None if it misses it."""
    t1, t2 = ray_sphere_intersections(o, d, radius + gas.top_m)
    if not np.isfinite(t2) or t2 <= 0:
        return None
    s0 = max(t1, 0.0)
    s1 = t2
    g1, _ = ray_sphere_intersections(o, d, radius)
    sea = bool(np.isfinite(g1) and 0 < g1 < s1)
    if sea:
        s1 = g1
    return s0, s1, sea


def _diffuse_horizontal(gas, classes, samplers):
    """Interpolator of the diffuse horizontal irradiance table, weighted over the aerosol column classes."""
    diffuse_tables = [(RegularGridInterpolator((samplers.u_axis, samplers.mu_axis),
                                               gas.diffuse_horizontal_classes[c].astype(float)), w)
                      for c, w in classes]

    def diffuse_interp(point):
        return sum(w * f(point) for f, w in diffuse_tables)

    return diffuse_interp


def _ray_points(s, o, d, volume, geo, sun, radius):
    """Height [m], local sun cosine and fractional grid indices (k, j, i) at distances ``s`` along the ray."""
    p = o + np.atleast_1d(s)[:, None] * d
    r = np.linalg.norm(p, axis=1)
    h = r - radius
    i, j = grid_indices(volume.attrs, radius * p[:, 0] / r, radius * p[:, 1] / r)
    k = (h - geo.z_bottom) / geo.dz
    return h, p @ sun / r, k, j, i


def _gas_at(h, mu_s, gas, samplers, diffuse_interp):
    """Rayleigh, aerosol and stratospheric extinction and ozone's absorption coefficient (n, 3) [m-1], sun
    transmittance and diffuse irradiance at heights h."""
    hh = np.clip(h, 0, gas.top_m)
    ozone = gas.ozone_extinction
    br, ba, bs, bo = (np.stack([np.interp(hh, samplers.heights, b[:, c]) for c in range(3)], axis=-1)
                      for b in (gas.beta_rayleigh, gas.beta_aerosol, gas.beta_stratospheric, ozone))
    point = np.stack([np.sqrt(hh / gas.top_m), np.clip(mu_s, -1, 1)], axis=-1)
    return br, ba, bs, bo, samplers.t_sun(point), diffuse_interp(point)


def _terrain_cut(h, j, i, s, ds, s1, sea, samplers):
    """(surface, s_end, step): where the ray first goes below the terrain, and the step lengths [m] up to there."""
    nk, ny, nx = samplers.geo.shape
    # the terrain continues beyond the grid at its edge heights (clamped), as in the kernel
    terrain = samplers.terrain(np.stack([np.clip(j, 0, ny - 1), np.clip(i, 0, nx - 1)], axis=-1))
    gap = h - terrain
    below = np.flatnonzero(gap < 0)
    surface = sea
    s_end = s1
    step = np.full(s.size, ds)
    if below.size:
        m = below[0]
        frac = np.clip(gap[m - 1] / (gap[m - 1] - gap[m]), 0, 1) if m > 0 else 0.5
        surface = True
        s_end = s[m] - 0.5 * ds + frac * ds
        step[m] *= frac
        step[m + 1:] = 0.0
    return surface, s_end, step


def _march_clear(o, d, s0, s1, sea, step_m, sun, gas, samplers, diffuse_interp, classes, volume, radius, p_rayleigh,
                 p_aerosol, p_stratospheric, multiple_scattering):
    """Sample the ray at once and accumulate the gas light and the hydrometeors' irradiance integrals step by step.

    Returns ``(surface, s_end, l_clear, i_nogas, i_gas, i_cloud_t, tau_c, tau_sp)``.
    """
    nk, ny, nx = samplers.geo.shape
    n = max(int(np.ceil((s1 - s0) / step_m)), 1)
    ds = (s1 - s0) / n
    s = s0 + (np.arange(n) + 0.5) * ds
    h, mu_s, k, j, i = _ray_points(s, o, d, volume, samplers.geo, sun, radius)
    inside = (i >= 0) & (i <= nx - 1) & (j >= 0) & (j <= ny - 1)
    surface, s_end, step = _terrain_cut(h, j, i, s, ds, s1, sea, samplers)
    points = np.stack([k, j, i], axis=-1)
    beta = np.stack([g(points) for g in samplers.ext], axis=-1)
    beta_sp = beta[:, :-1]
    br, ba, bs, bo, t_sun, diffuse_sky = _gas_at(h, mu_s, gas, samplers, diffuse_interp)
    beta_a3 = beta[:, -1:] * gas.angstrom_factor[None, :]
    t_aer = np.exp(-samplers.tau_aer(points)[:, None] * gas.angstrom_factor[None, :])
    e = t_sun * t_aer * samplers.t(points)[:, None]
    in_grid = ((k >= 0) & (k <= nk - 1) & inside)[:, None]
    e_h = np.where(in_grid, e + SKYLIGHT_SCALAR_FACTOR * diffuse_sky * samplers.tc(points)[:, None], e)
    beta_clear = br + ba + beta_a3 + bs + bo  # ozone absorbs: extinction, no source
    beta_h = beta_sp.sum(axis=1)
    x = (beta_clear + beta_h[:, None]) * step[:, None]
    mean = np.where(x > 1e-8, -np.expm1(-x) / np.maximum(x, 1e-300), 1.0)
    d_tau_c = beta_clear * step[:, None]
    d_tau_h = beta_h * step
    tau_c_before = np.cumsum(d_tau_c, axis=0) - d_tau_c
    tau_h_before = np.cumsum(d_tau_h) - d_tau_h
    t_obs = np.exp(-(tau_c_before + tau_h_before[:, None]))
    scat_a = (ba + beta_a3) * gas.aerosol.ssa
    scat_s = bs * np.asarray(gas.aerosol.stratospheric.ssa, float)
    p_strat = np.zeros(3) if p_stratospheric is None else np.asarray(p_stratospheric, float)
    source = (br * p_rayleigh + scat_a * p_aerosol + scat_s * p_strat) * e
    if multiple_scattering:
        js = _diffuse_source(o, d, s0, s1, h, gas, sun, classes)
        source = source + (br * js[:, :3] + scat_a * js[:, 3:6] + scat_s * js[:, 6:]) * samplers.tc(points)[:, None]
    l_clear = np.sum(t_obs * source * step[:, None] * mean, axis=0)
    w = np.maximum(np.exp(-tau_h_before) - np.exp(-np.minimum(tau_h_before + d_tau_h, 2.0)), 0.0)
    i_nogas = np.sum(e_h * w[:, None], axis=0)
    i_gas = np.sum(e_h * np.exp(-tau_c_before) * w[:, None], axis=0)
    i_cloud_t = np.sum(samplers.t(points) * w)
    tau_c = d_tau_c.sum(axis=0)
    tau_sp = (beta_sp * step[:, None]).sum(axis=0)
    return surface, s_end, l_clear, i_nogas, i_gas, i_cloud_t, tau_c, tau_sp


def _surface_radiance(o, d, s_end, sun, gas, samplers, diffuse_interp, volume, radius, tau, tau_sp, tau_c, backscatter,
                      surface_model):
    """Radiance (3,) of the ground where the ray ends, through the gas and the hydrometeors in front of it."""
    h, mu_s, k, j, i = _ray_points(s_end, o, d, volume, samplers.geo, sun, radius)
    _, _, _, _, t_sun, diffuse = _gas_at(h, mu_s, gas, samplers, diffuse_interp)
    # beyond the grid and its margin: from the margin's nearest edge cell's fields to the far ground,
    # e^(-distance / fade)
    jm, im = j[0] + samplers.margin, i[0] + samplers.margin
    jc, ic = np.clip(jm, 0, samplers.extended.shape[1] - 1), np.clip(im, 0, samplers.extended.shape[2] - 1)
    edge = np.array([RegularGridInterpolator(samplers.surface_axes, g)([[jc, ic]])[0] for g in samplers.surface_fields])
    w = np.exp(-np.hypot(jm - jc, im - ic) / surface_fade_cells())
    fields = samplers.outside + (edge - samplers.outside) * w
    # Step 1a at the ground: cloud T, terrain shadow and 3-D aerosol tau of the column's ground level
    t_cloud, shadow = fields[8], fields[9]
    t_aer_ground = np.exp(-fields[10] * gas.angstrom_factor)
    p_ground = o + s_end * d
    up = p_ground / np.linalg.norm(p_ground)
    l_ground = np.asarray(surface_radiance(
        up[None], -d[None], sun, fields[6:8][None], fields[:3][None],
        fields[3:4], fields[4:5], fields[5:6], (t_sun[0] * t_aer_ground * t_cloud * shadow)[None],
        (diffuse[0] * t_cloud)[None], model=surface_model), dtype=float)[0]
    # seen from above: the ground through the total transmittance of the hydrometeors (reciprocity)
    w_g = np.clip(-d[2] / FROM_ABOVE_BLEND, 0, 1)
    t_h = (1 - w_g) * np.exp(-tau) + w_g * float(transmittance_delta_eddington(
        tau, float(tau_sp @ backscatter), max(-d[2], FROM_ABOVE_BLEND)))
    return l_ground * np.exp(-tau_c) * t_h


def _cloud_radiance(d, sun, tau, tau_sp, i_nogas, i_gas, i_cloud_t, backscatter):
    """Radiance (3,) of the hydrometeors along the ray: Eq. 12 from below, blended with the reflection from above."""
    norm = -np.expm1(-min(tau, 2.0))
    e_mean = i_nogas / norm
    weights = tau_sp / tau
    cos_theta = float(d @ sun)
    t_mean = np.clip(i_cloud_t / norm, 0, 1)
    mu_down = -d[2]
    mu0 = sun[2]
    w_above = np.clip(mu_down / FROM_ABOVE_BLEND, 0, 1)
    # from below: the c4 term of Eq. 21 as diffusely transmitted light (docs/rendering.md, "Overcast accuracy")
    low_factor = (1 - w_above) * float(diffuse_transmission_factor(mu0)) + w_above
    phase = np.asarray(effective_phase_function(np.array([cos_theta]), np.array([d[2]]), np.array([tau]),
                                                np.array([[t_mean]]), weights[None, None, :],
                                                np.asarray(G_LIQUID)[None], low_factor))[0]
    eq12 = (-np.expm1(-tau) / norm) * i_gas
    # thin term: Eq. 12 with the forward peak kept in the beam outside the peak lobe (delta scaling)
    c1 = float(blend_coefficient(tau, t_mean))
    p_thin = np.asarray(phase_thin_mixture(np.array([[cos_theta]]), np.array([[tau]]), weights[None, None, :],
                                           np.asarray(G_LIQUID)[None]))[0]
    p_rest = p_thin - np.asarray(forward_peak_mixture(np.array([[cos_theta]]), np.array([[tau]]),
                                                      weights[None, None, :], np.asarray(G_LIQUID)[None]))[0]
    eq12_thin = (float(delta_scaled_path_factor(tau)) / norm) * i_gas
    l_12 = phase * eq12 + c1 * p_rest * (eq12_thin - eq12)
    # from above: c1 P_thin (Eq. 12) + (1 - c1) a 4 mu0 ARF E_top (docs/rendering.md, "Overcast accuracy")
    b_eff = float(weights @ backscatter)
    m_down = max(mu_down, FROM_ABOVE_BLEND)
    m0 = max(mu0, 0.05)
    tau_s = tau * m_down / m0
    a = 1.0 - float(transmittance_delta_eddington(tau_s, b_eff * tau_s, m0))
    lim = min(tau, 2.0)
    depth_s = (1.0 - (1.0 + lim) * np.exp(-lim)) / norm * m_down / m0
    t_self = max(float(transmittance_delta_eddington(depth_s, b_eff * depth_s, m0)), 0.05)
    arf = float(anisotropic_reflectance_factor_kokhanovsky2004(m_down, max(mu0, 1e-3), cos_theta))
    l_top = 4 * max(mu0, 0) * arf * (e_mean / t_self) * (i_gas / np.maximum(i_nogas, 1e-300))
    l_above = c1 * p_thin * eq12 + (1 - c1) * a * l_top
    return (1 - w_above) * l_12 + w_above * l_above


def reference_trace_ray(origin, direction, volume, transmittance, gas, sun, p_rayleigh, p_aerosol,
                        step_m=50.0, radius=EARTH_RADIUS_M, multiple_scattering=True, p_stratospheric=None,
                        surface_model="brdf"):
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
    p_rayleigh : float
        Rayleigh phase function at this ray's scattering angle (mean 1 over the sphere).
    p_aerosol : array_like
        Shape (3,): aerosol phase function per wavelength at this ray's scattering angle.
    step_m : float
        Step length [m].
    p_stratospheric : array_like, optional
        Shape (3,): phase function of the stratospheric aerosol at this ray's scattering angle (needed when
        the atmosphere has a stratospheric layer).
    multiple_scattering : bool
        As :class:`swim.rt.march_settings.MarchSettings`.
    surface_model : {"brdf", "lambertian"}
        ``MarchSettings.surface`` (the same :func:`swim.surface.lighting.surface_radiance`).

    Returns
    -------
    dict
        ``radiance``, ``radiance_clear``, ``radiance_cloud``, ``radiance_surface`` (3,);
        ``tau_hydrometeor`` (float); ``tau_clear`` (3,); ``surface`` (bool).
    """
    o = np.asarray(origin, float)
    d = np.asarray(direction, float)
    sun = np.asarray(sun, float)
    samplers = _interpolators(volume, transmittance, gas)
    span = _ray_span(o, d, gas, radius)
    if span is None:
        return None
    s0, s1, sea = span
    classes = _class_weights(o, d, s0, s1, volume, gas, radius)
    diffuse_interp = _diffuse_horizontal(gas, classes, samplers)
    # Sample everything along the ray at once, then accumulate step by step with cumulative sums.
    surface, s_end, l_clear, i_nogas, i_gas, i_cloud_t, tau_c, tau_sp = _march_clear(
        o, d, s0, s1, sea, step_m, sun, gas, samplers, diffuse_interp, classes, volume, radius, p_rayleigh, p_aerosol,
        p_stratospheric, multiple_scattering)

    tau = tau_sp.sum()
    backscatter = np.array([BACKSCATTER_FRACTION[s] for s in SPECIES])
    l_surface = np.zeros(3)
    if surface:
        l_surface = _surface_radiance(o, d, s_end, sun, gas, samplers, diffuse_interp, volume, radius, tau, tau_sp,
                                      tau_c, backscatter, surface_model)

    l_cloud = np.zeros(3)
    if tau > 1e-6:
        l_cloud = _cloud_radiance(d, sun, tau, tau_sp, i_nogas, i_gas, i_cloud_t, backscatter)
    return {
        "radiance": l_clear + l_cloud + l_surface,
        "radiance_clear": l_clear,
        "radiance_cloud": l_cloud,
        "radiance_surface": l_surface,
        "tau_hydrometeor": tau,
        "tau_clear": tau_c,
        "surface": surface,
    }
