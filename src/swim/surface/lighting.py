"""Radiance leaving the ground: Eq. 35 on sloped terrain with a BRDF.

The paper's Eq. 35 gives the solar-relative radiance of the surface, L' = 4 rho E_H / E, with rho = a ARF for the
direct light and ARF = 1 for the diffuse light. swim evaluates it on the *tilted* terrain facet under the ray:

* the facet normal n comes from the terrain gradient (``terrain_slope`` of the optical volume, bilinear, so
  slopes are shaded smoothly rather than per grid cell); the direct beam falls on it with cos i = n . sun (zero
  on slopes facing away from the sun: self-shadowing; cast shadows are already in Step 1a's T);
* the diffuse sky light reaches it through its sky-view factor (1 + n . up) / 2 (isotropic sky), and the
  light reflected by the surrounding ground through (1 - n . up) / 2 (a Lambertian neighbourhood of the same
  albedo lit by the horizontal global irradiance);
* the direct part uses the bidirectional reflectance factor R of :mod:`swim.surface.brdf` (RPV land with its
  hot spot, Kokhanovsky snow with its forward peak, Cox-Munk sun glint over water plus the water-leaving
  term), the diffuse part the hemispherical (diffuse) albedo (ARF = 1, Eq. 35), except that water mirrors
  the sky with the Fresnel reflectance of the view angle (bright towards the horizon); ``model="lambertian"`` gives
  R = a everywhere (the plane-parallel references of the validation suite assume it).

All inputs are per ray (the ground point of each ray); the functions compute in the array library of their
inputs (numpy, or ``jax.numpy`` for JAX arrays and tracers inside ``jax.jit``; :mod:`swim.arrays`) so that the
kernel and the float64 reference evaluate the same expressions. On CPUs the renderer evaluates the same expressions
one ray at a time in numba (:func:`swim.rt.ground_cpu.surface_radiance`), which ``tests/unit/rt/test_ground_cpu.py``
holds to this function.
"""

from __future__ import annotations

from ..arrays import array_namespace
from .brdf import surface_diffuse_albedo, surface_reflectance_factor
from .water import fresnel_reflectance, water_diffuse_albedo

#: Surface models: ``"brdf"`` (land RPV / snow / water glint, the default) or ``"lambertian"`` (R = albedo).
SURFACE_MODELS = ("brdf", "lambertian")
#: Smallest view cosine at which the water surface mirrors the sky with the Fresnel reflectance of the view
#: angle (0.35 at 0.1); waves keep a real sea from mirroring the horizon like a flat pane.
MIN_WATER_VIEW_COSINE = 0.1
#: Smallest cosine between the view and the facet normal for which the facet's BRDF is used; below it (a
#: facet seen edge-on or from behind, where the ray's coarse hit point and the smooth normal disagree) the
#: local horizontal is used instead, which avoids black speckles on silhouettes.
MIN_VIEW_COSINE = 0.02


def facet_normal(up, slope):
    """Unit normal (n, 3) of the terrain facet from the local up (n, 3) and the gradient dh/dx, dh/dy (n, 2).

    The scene frame's x and y axes stand in for local east and north (their difference is the earth's
    curvature across the domain, < 1 degree per 100 km); the gradient is projected onto the local horizontal.
    The result is an array of the library of the inputs (numpy or JAX, :mod:`swim.arrays`).
    """
    xp = array_namespace(up, slope)
    up = xp.asarray(up)
    slope = xp.asarray(slope)
    g = xp.concatenate([slope, xp.zeros_like(slope[:, :1])], axis=1)
    g = g - xp.sum(g * up, axis=1, keepdims=True) * up
    n = up - g
    return n / xp.linalg.norm(n, axis=1, keepdims=True)


def surface_radiance(up, view, sun, slope, albedo, land_fraction, snow_cover, wind_speed, direct, diffuse,
                     model="brdf"):
    """Solar-relative radiance L' (n, 3) leaving the ground towards the observer (Eq. 35 on a tilted facet).

    Parameters
    ----------
    up : array_like
        Shape (n, 3): local vertical at the ground point (unit).
    view : array_like
        Shape (n, 3): unit vector from the ground point towards the observer (minus the ray direction).
    sun : array_like
        Shape (3,) or (n, 3): unit vector towards the sun.
    slope : array_like
        Shape (n, 2): terrain gradient dh/dx, dh/dy [-] (0 for flat ground).
    albedo : array_like
        Shape (n, 3): spectral albedo a of the snow-free surface at 615/546/450 nm [-].
    land_fraction, snow_cover, wind_speed : array_like
        Shape (n,): land fraction [-] (1 land, 0 water; fractional on coasts), snow-covered fraction of the
        land [-], wind speed at 10 m [m s-1].
    direct : array_like
        Shape (n, 3): direct-beam irradiance on a plane normal to the sun / E_TOA [-] (gas, aerosol and Step
        1a's T, terrain shadows included).
    diffuse : array_like
        Shape (n, 3): diffuse irradiance on a horizontal plane / E_TOA [-] (clouds above included).
    model : {"brdf", "lambertian"}
        Surface reflectance model (static).

    Returns
    -------
    numpy.ndarray or jax.Array
        Shape (n, 3): L' [-] at the surface (before the attenuation towards the observer).

    References
    ----------
    Albers et al. (2020), Sect. 3.7, Eq. 35, doi:10.5194/amt-13-3235-2020; docs/surfaces.md.
    """
    xp = array_namespace(up, view, sun, slope, albedo, land_fraction, snow_cover, wind_speed, direct, diffuse)
    up = xp.asarray(up)
    view = xp.asarray(view)
    sun = xp.broadcast_to(xp.asarray(sun), up.shape)
    albedo = xp.asarray(albedo)
    direct = xp.asarray(direct)
    diffuse = xp.asarray(diffuse)
    # Water is flat whatever the terrain gradient of a coastal cell says (a glint on a tilted sea is wrong).
    land_fraction = xp.asarray(land_fraction)
    normal = facet_normal(up, xp.where((land_fraction >= 0.5)[:, None], xp.asarray(slope), 0.0))
    cos_i = xp.maximum(xp.sum(normal * sun, axis=1), 0.0)
    cos_slope = xp.sum(normal * up, axis=1)
    sky_view = 0.5 * (1.0 + cos_slope)
    mu_s = xp.maximum(xp.sum(up * sun, axis=1), 0.0)
    global_horizontal = mu_s[:, None] * direct + diffuse
    # Diffuse light on the facet: the sky it sees plus the ground around it (Lambertian, same albedo).
    diffuse_facet = sky_view[:, None] * diffuse + (1.0 - sky_view)[:, None] * albedo * global_horizontal
    if model == "lambertian":
        return 4.0 * albedo * (cos_i[:, None] * direct + diffuse_facet)
    if model != "brdf":
        raise ValueError(f"surface model must be one of {SURFACE_MODELS}, got {model!r}")
    facing = xp.sum(normal * view, axis=1) > MIN_VIEW_COSINE
    brdf_normal = xp.where(facing[:, None], normal, up)
    # The scene's albedo is that of the snow-free surface (docs/surfaces.md); the snow-covered part of the
    # land has the snow's own albedo and BRDF shape (forward peak).
    r_direct = surface_reflectance_factor(sun, view, brdf_normal, albedo, snow_cover, land_fraction, wind_speed)
    a_diffuse = surface_diffuse_albedo(albedo, snow_cover, land_fraction)
    # Water mirrors the (here isotropic) sky: its diffuse reflectance at the view angle is the Fresnel
    # reflectance there (0.02 looking down, ~0.35 near the horizon), whose cosine-weighted hemispheric mean
    # is the 0.067 of surface_diffuse_albedo (docs/surfaces.md §5).
    mu_water = xp.clip(xp.sum(view * up, axis=1), MIN_WATER_VIEW_COSINE, 1.0)
    specular_sky = fresnel_reflectance(mu_water) - water_diffuse_albedo()
    a_diffuse = a_diffuse + ((1.0 - xp.clip(land_fraction, 0.0, 1.0)) * specular_sky)[:, None]
    return 4.0 * (r_direct * cos_i[:, None] * direct + a_diffuse * diffuse_facet)
