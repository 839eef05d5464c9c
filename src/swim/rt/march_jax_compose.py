"""The JAX kernel's composition: the pixel radiance from the march's state, the ground (Eq. 35), the clouds
(Eqs. 12-26 of Albers et al. 2020, doi:10.5194/amt-13-3235-2020) and the clear sky.

:mod:`swim.rt.march_jax` runs it after the march (:func:`swim.rt.march_jax._trace_chunk`) and imports these functions
back; the numba kernel composes the same per ray (:mod:`swim.rt.compose_cpu`, :mod:`swim.rt.ground_cpu`). The lookups
of the scene's tables stay in :mod:`swim.rt.march_jax` with the optimisation barriers they share (``_materialise``) and
are imported where they are called: that module imports this one.
"""

from __future__ import annotations

import jax.numpy as jnp

from ..optics.phase import (
    anisotropic_reflectance_factor_kokhanovsky2004,
    blend_coefficient,
    delta_scaled_path_factor,
    diffuse_transmission_factor,
    effective_phase_function,
    forward_peak_mixture,
    phase_thin_mixture,
)
from ..surface.lighting import surface_radiance
from .clouds import three_d
from .march_inputs import _ends_on_surface
from .march_settings import (FROM_ABOVE_BLEND, MarchSettings, TOP_MIN_MU0, TOP_MIN_SELF_TRANSMITTANCE,
                             TOP_REFLECTANCE_MIN_MU0)
from .solar import transmittance_delta_eddington
from .surface_margin import surface_fade_cells


def _compose(start, direction, bounds, ends_on_ground, valid, rays, consts, settings: MarchSettings, state,
             aerosol_class, ground=True):
    """The pixel radiance from the march's state: ground (Eq. 35), clouds (Eqs. 12-26), clear sky.

    ``ground`` (static): False where no ray of the batch ends on the ground, whose term is then 0 without being
    evaluated (as it is for such rays anyway). The chunks of an all-sky camera on the ground and the upper rows of a
    panorama see no ground, and the ground's BRDF is about half of the composition's cost
    (docs/decisions/0009-work-around-the-march.md)."""
    surface = _ends_on_surface(state, ends_on_ground)
    s_hit = state["s_hit"]
    if ground:
        l_surface = _ground_radiance(start, direction, rays, consts, settings, state, aerosol_class, surface, s_hit)
    else:
        l_surface = jnp.zeros_like(state["l_clear"])
    if three_d(consts):
        return _compose_three_d(consts, state, valid, surface, s_hit, l_surface)
    return _compose_clouds(rays, consts, state, valid, surface, s_hit, l_surface)


def _ground_radiance(start, direction, rays, consts, settings, state, aerosol_class, surface, s_hit):
    """The ground's part of the pixel radiance (n, 3), 0 where a ray does not end on the ground (``surface``):
    Eq. 35 on the terrain facet at ``s_hit`` [m], direct (BRDF) + diffuse (ARF = 1), seen through the clear sky and
    the hydrometeors on the way. The numba kernel's twin: :func:`swim.rt.ground_cpu.ground_radiance`."""
    from .march_jax import _gas_at, _point_geometry, bilinear_clamped, diffuse_at

    q = start + s_hit[:, None] * direction
    h, mu_s, k, j, i = _point_geometry(q, consts)
    _, _, _, _, t_sun, diffuse = _gas_at(h, mu_s, consts)
    if consts["class_aod"].shape[0] > 1:
        diffuse = diffuse_at(h, mu_s, aerosol_class, consts)
    # albedo (3), land, snow, wind, slope (2), and Step 1a at the ground: cloud T, terrain shadow, 3-D aerosol
    # tau to the sun (2-D fields, so a steep slope does not sample its neighbours' underground values);
    # beyond the grid they continue over a margin (swim.rt.march_inputs.extended_surface), and beyond that they fade
    # from its edge to the far ground, flat and unshaded
    jm, im = j + consts["surface_margin"], i + consts["surface_margin"]
    fields = surface_beyond_edge(bilinear_clamped(consts["surface"], jm, im), consts["surface_outside"],
                                 *consts["surface"].shape[1:], jm, im)
    slope = fields[:, 6:8]
    t_cloud = fields[:, 8]
    shadow = fields[:, 9]
    t_aerosol = jnp.exp(-fields[:, 10:11] * consts["angstrom"][None, :])
    # with the 3-D cloud scattering the diffuse light at the ground is the diffuse solution's (its ratio to the
    # clear sky's, channels 11-13), which includes the light between the ground and the cloud base
    clouds_3d = three_d(consts)
    diffuse = diffuse * (fields[:, 11:14] if clouds_3d else t_cloud[:, None])
    up = q + jnp.array([0.0, 0.0, 1.0], jnp.float32) * consts["radius"]
    up = up / jnp.linalg.norm(up, axis=1, keepdims=True)
    l_ground = surface_radiance(up, -direction, consts["sun"], slope, fields[:, :3], fields[:, 3], fields[:, 4],
                                fields[:, 5], t_sun * t_aerosol * (t_cloud * shadow)[:, None], diffuse,
                                model=settings.surface)
    if clouds_3d:  # seen through the delta-M scaled optical depth: the forward peak's light stays in the view
        t_hydro = jnp.exp(-(state["tau_species"] @ consts["backscatter_scaled"]))
        return jnp.where(surface[:, None], l_ground * (jnp.exp(-state["tau_clear"]) * t_hydro[:, None]), 0.0)
    # Seen from above, the ground under a cloud layer shines through the layer's total (direct + diffuse)
    # transmittance at the view angle (reciprocity), the same delta-Eddington T as in Step 1a; rays that do
    # not look down (blend as for the clouds) keep the direct e^{-tau} (docs/rendering.md, "Overcast accuracy").
    mu_down_ground = -rays["cos_view_zenith"]
    w_above_ground = jnp.clip(mu_down_ground / FROM_ABOVE_BLEND, 0.0, 1.0)
    tau_hydro = state["tau_h"]
    t_hydro = (1 - w_above_ground) * jnp.exp(-tau_hydro) + w_above_ground * transmittance_delta_eddington(
        tau_hydro, state["tau_species"] @ consts["backscatter"], jnp.maximum(mu_down_ground, FROM_ABOVE_BLEND))
    transmit = jnp.exp(-state["tau_clear"]) * t_hydro[:, None]
    return jnp.where(surface[:, None], l_ground * transmit, 0.0)


def _compose_three_d(consts, state, valid, surface, s_hit, l_surface):
    """The outputs of :func:`_compose` with the 3-D cloud scattering, whose hydrometeors' radiance was integrated
    along the rays (:mod:`swim.rt.clouds_device`), given the ground's part ``l_surface`` (n, 3); ``tau_narrow``
    (n,) is the optical depth that dims the beam but for the forward peak's narrow part (the circumsolar aureole,
    :func:`swim.optics.cloud_phase.split_phase_function`). The numba kernel's twin: :func:`_compose_numba`."""
    aureole = consts["species_matrix"].T @ consts["hydro_aureole"].astype(jnp.float32)  # (SPECIES,)
    radiance = jnp.where(valid[:, None], state["l_clear"] + state["l_cloud"] + l_surface, 0.0)
    return {
        "radiance": radiance,
        "radiance_clear": state["l_clear"],
        "radiance_cloud": state["l_cloud"],
        "radiance_surface": l_surface,
        "tau_hydrometeor": state["tau_h"],
        "tau_clear": state["tau_clear"],
        "surface": surface,
        "distance": jnp.where(surface, s_hit, jnp.nan),
        "tau_narrow": state["tau_species"] @ aureole,
    }


def _compose_clouds(rays, consts, state, valid, surface, s_hit, l_surface):
    """The clouds' part of the pixel radiance (Eq. 12 with the effective phase function of Eq. 13, seen from below,
    blended with the cloud-top reflection of Eqs. 24-26 seen from above; Albers et al. 2020,
    doi:10.5194/amt-13-3235-2020) and the outputs of :func:`_compose`, given the ground's part ``l_surface``
    (n, 3)."""
    # ---- clouds: Eq. 12 with the effective phase function of Eq. 13, blended with Eqs. 24-26 ----
    tau = state["tau_h"]
    norm = -jnp.expm1(-jnp.minimum(tau, 2.0))
    safe = jnp.maximum(norm, 1e-12)
    e_mean = state["i_nogas"] / safe[:, None]
    # How directly the visible cloud is lit, for c1 and c3 (Eqs. 14, 22): the cloud transmittance T of
    # Step 1a, not E/E_TOA with the gas extinction (docs/rendering.md).
    t_mean = jnp.clip(state["i_cloud_t"] / safe, 0.0, 1.0)
    weights = state["tau_species"] / jnp.maximum(tau, 1e-12)[:, None]
    cos_theta = rays["cos_theta"]
    cos_view_zenith = rays["cos_view_zenith"]
    mu_view_down = -cos_view_zenith
    mu0 = consts["mu0"]
    w_above = jnp.clip(mu_view_down / FROM_ABOVE_BLEND, 0.0, 1.0)[:, None]
    # Seen from below, the indirectly lit (c4) term of Eq. 21 is the diffusely transmitted light: 4 x the
    # transmitted flux mu0 T x the escape function, i.e. the factor (9/7) mu0 (docs/rendering.md, "Overcast
    # accuracy"); rays looking down keep Eq. 21 as printed.
    low_factor = (1 - w_above) * diffuse_transmission_factor(mu0) + w_above
    phase = effective_phase_function(cos_theta[:, None], cos_view_zenith[:, None], tau[:, None], t_mean[:, None],
                                     weights[:, None, :], consts["g_liquid"][None, :], low_factor)
    eq12 = (-jnp.expm1(-tau) / safe)[:, None] * state["i_gas"]
    # Thin-cloud term (c1 P_thin) with the forward (diffraction) peak kept in the beam: Eq. 12's 1 - e^{-tau}
    # delta-scaled to (1 - e^{-(1 - f) tau}) / (1 - f) (docs/rendering.md, "Overcast accuracy").
    eq12_thin = (delta_scaled_path_factor(tau) / safe)[:, None] * state["i_gas"]
    c1 = blend_coefficient(tau, t_mean)
    p_thin = phase_thin_mixture(cos_theta[:, None], tau[:, None], weights[:, None, :], consts["g_liquid"][None, :])
    p_rest = p_thin - forward_peak_mixture(cos_theta[:, None], tau[:, None], weights[:, None, :],
                                           consts["g_liquid"][None, :])
    l_12 = phase * eq12 + c1[:, None] * p_rest * (eq12_thin - eq12)
    # Seen from above (docs/rendering.md, "Overcast accuracy"): the thin part of Eq. 13 (c1 P_thin, Eq. 12)
    # plus, in place of its thick part (Eqs. 19-21, cloud sides and bases), the cloud-top reflection of
    # Eqs. 24-26, (1 - c1) a 4 mu0 ARF E_top: the albedo a = 1 - T of the layer seen (delta-Eddington, as in
    # Step 1a, along the sun path tau_s = tau mu_view / mu0) and the irradiance incident on the cloud top,
    # E_top = E / T_self (Eq. 12's mean E over the top two optical depths already carries the cloud's own
    # extinction, which the reflection function ARF includes).
    b_eff = weights @ consts["backscatter"]
    mu_down = jnp.maximum(mu_view_down, FROM_ABOVE_BLEND)
    mu0_top = jnp.maximum(mu0, TOP_MIN_MU0)
    tau_s = tau * mu_down / mu0_top
    albedo_cloud = 1.0 - transmittance_delta_eddington(tau_s, b_eff * tau_s, mu0_top)
    lim = jnp.minimum(tau, 2.0)
    depth = (1.0 - (1.0 + lim) * jnp.exp(-lim)) / safe  # Eq. 12's e^{-tau_o}-weighted mean tau_o
    depth_s = depth * mu_down / mu0_top
    t_self = jnp.maximum(transmittance_delta_eddington(depth_s, b_eff * depth_s, mu0_top), TOP_MIN_SELF_TRANSMITTANCE)
    arf = anisotropic_reflectance_factor_kokhanovsky2004(mu_down, jnp.maximum(mu0, TOP_REFLECTANCE_MIN_MU0), cos_theta)
    # guarded on both branches (the same values): a finite derivative where i_nogas = 0
    # (docs/decisions/0025-differentiable-forward-operator.md)
    lit = state["i_nogas"] > 1e-30
    gas_to_cloud = jnp.where(lit, state["i_gas"] / jnp.where(lit, state["i_nogas"], 1.0), state["i_gas"] / 1e-30)
    l_top = 4.0 * jnp.maximum(mu0, 0.0) * arf[:, None] * (e_mean / t_self[:, None]) * gas_to_cloud
    l_above = c1[:, None] * p_thin * eq12 + ((1 - c1) * albedo_cloud)[:, None] * l_top
    l_cloud = jnp.where(tau[:, None] > 1e-6, (1 - w_above) * l_12 + w_above * l_above, 0.0)

    radiance = state["l_clear"] + l_cloud + l_surface
    radiance = jnp.where(valid[:, None], radiance, 0.0)
    return {
        "radiance": radiance,
        "radiance_clear": state["l_clear"],
        "radiance_cloud": l_cloud,
        "radiance_surface": l_surface,
        "tau_hydrometeor": tau,
        "tau_clear": state["tau_clear"],
        "surface": surface,
        "distance": jnp.where(surface, s_hit, jnp.nan),
    }


def surface_beyond_edge(clamped, outside, ny, nx, j, i):
    """The ground's fields at indices (j, i) (n,) of the extended fields (the grid with its margin,
    :func:`swim.rt.march_inputs.extended_surface`, ny x nx), anywhere: inside them ``clamped`` (n, C), their bilinear
    lookup; beyond them a fade, with the distance d [cells] from their edge, from the nearest edge cell's values
    (``clamped``, the lookup at the clamped indices) to ``outside`` (C,) (:func:`surface_fields_outside`), weight
    e^(-d / L) with L of :func:`surface_fade_cells`. The margin has already faded most of the way to ``outside``
    (smoothed along the grid's edge, so that no edge feature runs on as a streak); the fade keeps the ground
    continuous at the margin's edge."""
    dj = jnp.maximum(jnp.maximum(-j, j - (ny - 1)), 0.0)
    di = jnp.maximum(jnp.maximum(-i, i - (nx - 1)), 0.0)
    w = jnp.exp(-jnp.sqrt(dj * dj + di * di)[:, None] / surface_fade_cells(clamped.shape[-1])[None, :])
    return outside[None, :] + (clamped - outside[None, :]) * w
