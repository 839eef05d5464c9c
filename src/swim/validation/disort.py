"""Plane-parallel clear-sky reference radiances with DISORT (DisORT++, ``disortpp``).

An independent multiple-scattering solution for the same clear atmosphere that swim renders (Step 2 of
Albers et al. 2020, Eq. 3): the Rayleigh and background-aerosol extinction profiles of
:func:`swim.rt.gas.build_gas_tables`, the depolarised Rayleigh phase function of
:func:`swim.optics.rayleigh.rayleigh_phase_function` and the aerosol type's Eq. 28 phase function and
single-scattering albedo, and the ozone absorption of :mod:`swim.optics.ozone` (the aerosol's ``ozone_du``),
over a Lambertian surface. DISORT (Stamnes et al. 1988, Appl. Opt. 27, 2502,
doi:10.1364/AO.27.002502) solves the radiative transfer equation in a plane-parallel atmosphere with all
orders of scattering; swim's atmosphere is spherical, which matters only near the horizon (view zenith
angles above ~85°) and for low suns (sun zenith above ~75°).

Conventions (verified in ``tests/validation/test_clear_sky_disort.py``)
------------------------------------------------------------------------
* **Units.** DISORT's ``direct_beam_flux`` F0 is the flux of the incident beam per unit area *normal to the
  beam* (the horizontal flux is mu0 F0), and its intensities are per steradian in the same units. With
  F0 = 1 the solar-relative radiance of the paper's Eq. 2 is L' = 4 pi I. Checked against the
  single-scattering limit L' = omega P(theta) mu0 / (mu0 - mu) (e^{-tau/mu0} - e^{-tau/|mu|}) of a thin
  layer (mu < 0 downward), in which DISORT's phase-function normalisation (Legendre series
  sum (2l + 1) chi_l P_l, mean 1 over the sphere) is swim's.
* **Angles.** A *view* direction is where the observer looks (swim's camera convention): view zenith angle
  theta_v from the local vertical (< 90° looking up, > 90° looking down) and view azimuth clockwise from
  north. The radiance seen travels the opposite way, so DISORT's polar cosine of propagation (positive
  upwards) is ``mu = -cos(theta_v)``. The sun's azimuth is the direction *towards* the sun (swim's
  ``sun_azimuth``). ``relative_azimuth_deg`` = view azimuth - sun azimuth: 0 looks towards the sun's
  azimuth (forward scattering for a ground observer; the sun glint side for a satellite). DISORT's
  ``phi - phi0`` is the difference of the *propagation* azimuths of the radiance and of the beam; both are
  the look/sun azimuths plus 180°, so ``phi - phi0 = relative_azimuth_deg`` (tested: a forward-peaked
  phase function is brightest at relative azimuth 0 seen from the ground).
* **Direct beam.** DISORT's intensities are diffuse only; the sun's disk is not included.
"""

from __future__ import annotations

import numpy as np

from ..constants import ATMOSPHERE_TOP_M, WAVELENGTHS_NM
from ..diagnostics.irradiance import radiance_without_sun_disk, sky_irradiance
from ..errors import SwimInputError
from ..frames import enu_from_azimuth_zenith
from ..optics.legendre import phase_function_legendre_moments, rayleigh_legendre_moments
from ..rt.gas import AerosolBackground, build_gas_tables

__all__ = [
    "clear_sky_layers",
    "disort_clear_sky_radiance",
    "disort_clear_sky_irradiance",
    "CLOUD_HG_ASYMMETRY",
    "cloud_layer_layers",
    "disort_layers_radiance",
    "disort_layers_irradiance",
    "disort_cloud_layer_radiance",
    "disort_cloud_layer_irradiance",
]


def _layer_edges(n_layers, top=ATMOSPHERE_TOP_M):
    """Layer edges [m], top to bottom: quadratic in height (thin layers near the ground)."""
    u = np.linspace(0.0, 1.0, int(n_layers) + 1)
    return (top * u**2)[::-1]


def clear_sky_layers(aerosol: AerosolBackground = AerosolBackground(), n_layers=60, n_moments=256,
                     wavelengths_nm=WAVELENGTHS_NM, tau_scale=1.0, edges_m=None):
    """Layer optical properties of swim's clear atmosphere for DISORT.

    Parameters
    ----------
    aerosol : AerosolBackground
        Background aerosol (``aod_550=0`` for pure Rayleigh).
    n_layers : int
        Number of layers between 0 and 100 km (edges quadratic in height: 28 m at the ground for 60).
    n_moments : int
        Highest Legendre moment kept.
    wavelengths_nm : array_like
        The three swim wavelengths.
    tau_scale : float
        Factor applied to all optical depths (e.g. 0.01 for an optically thin test).
    edges_m : array_like, optional
        Layer edges [m], strictly decreasing from the top (100 km) to 0; overrides ``n_layers``.

    Returns
    -------
    dict
        ``edges_m`` (n_layers + 1,), ``dtau`` (n_layers, 3), ``ssa`` (n_layers, 3), ``moments``
        (n_layers, n_moments + 1, 3), ``tau_rayleigh``, ``tau_aerosol``, ``tau_stratospheric``, ``tau_ozone``
        (3,) columns (ozone absorbs only: the aerosol's ``ozone_du``, :mod:`swim.optics.ozone`) and
        ``depolarization``.
    """
    gas = build_gas_tables(aerosol, wavelengths_nm)
    beta_r = np.asarray(gas.beta_rayleigh, dtype=float) * tau_scale
    beta_a = np.asarray(gas.beta_aerosol, dtype=float) * tau_scale
    h = np.arange(beta_r.shape[0]) * gas.dh
    edges = _layer_edges(n_layers) if edges_m is None else np.asarray(edges_m, dtype=float)

    def column_above(beta):  # tau(z) above each height: trapezoid on the table grid, then interpolation
        seg = 0.5 * (beta[1:] + beta[:-1]) * gas.dh
        cum = np.concatenate([np.zeros((1, beta.shape[1])), np.cumsum(seg[::-1], axis=0)])[::-1]
        return np.stack([np.interp(edges, h, cum[:, c]) for c in range(beta.shape[1])], axis=-1)

    beta_s = np.asarray(gas.beta_stratospheric, dtype=float) * tau_scale
    # ozone (the aerosol's ozone_du, swim.optics.ozone): a pure absorber, in the layers' optical depth only
    beta_o = np.asarray(gas.ozone_extinction, dtype=float) * tau_scale
    col_r, col_a, col_s = column_above(beta_r), column_above(beta_a), column_above(beta_s)
    col_o = column_above(beta_o)
    dtau_r = np.diff(col_r, axis=0)  # edges go downwards, so tau increases
    dtau_a = np.diff(col_a, axis=0)
    dtau_s = np.diff(col_s, axis=0)
    ssa_a = np.asarray(aerosol.ssa, dtype=float)
    ssa_s = np.asarray(aerosol.stratospheric.ssa, dtype=float)
    sca_r, sca_a, sca_s = dtau_r, dtau_a * ssa_a, dtau_s * ssa_s
    dtau = dtau_r + dtau_a + dtau_s + np.maximum(np.diff(col_o, axis=0), 0.0)
    sca = sca_r + sca_a + sca_s
    ssa = np.where(dtau > 0, sca / np.where(dtau > 0, dtau, 1.0), 1.0)
    chi_r = rayleigh_legendre_moments(gas.depolarization, n_moments)
    chi_a = phase_function_legendre_moments(lambda x: np.asarray(aerosol.type.phase_function(x)), n_moments)
    safe = np.where(sca > 0, sca, 1.0)
    frac_a = np.where(sca > 0, sca_a / safe, 0.0)  # (n_layers, 3)
    frac_s = np.where(sca > 0, sca_s / safe, 0.0)
    moments = (1.0 - frac_a - frac_s)[:, None, :] * chi_r[None, :, None] + frac_a[:, None, :] * chi_a[None, :, :]
    if np.any(frac_s > 0):
        chi_s = phase_function_legendre_moments(lambda x: np.asarray(aerosol.stratospheric.phase_function(x)),
                                                n_moments)
        moments = moments + frac_s[:, None, :] * chi_s[None, :, :]
    return {
        "edges_m": edges,
        "dtau": dtau,
        "ssa": np.clip(ssa, 0.0, 1.0 - 1e-9),
        "moments": moments,
        "tau_rayleigh": col_r[-1],
        "tau_aerosol": col_a[-1],
        "tau_stratospheric": col_s[-1],
        "tau_ozone": col_o[-1],
        "depolarization": gas.depolarization,
    }


def _solve(layers, c, mu0, surface_albedo, n_streams, mu_user=None, phi_user=None, tau_user=None,
           fluxes_only=False, intensity_correction=True):
    """One DISORT solve at wavelength index c."""
    import disortpp

    n_layers = layers["dtau"].shape[0]
    n_mom = layers["moments"].shape[1] - 1
    cfg = disortpp.DisortConfig(n_layers, int(n_streams), n_mom)
    cfg.flags.use_lambertian_surface = True
    cfg.flags.comp_only_fluxes = bool(fluxes_only)
    if not fluxes_only:
        cfg.flags.use_user_tau = True
        cfg.flags.use_user_mu = True
        # Delta-M scaling is always applied by DISORT; the Nakajima-Tanaka TMS/IMS correction restores the
        # single-scattered intensity from the full (untruncated) moments for the forward-peaked aerosol.
        cfg.flags.intensity_corr_nakajima = bool(intensity_correction)
        cfg.num_user_tau = len(tau_user)
        cfg.num_user_mu = len(mu_user)
        cfg.num_phi = len(phi_user)
    cfg.allocate()
    cfg.delta_tau = [float(v) for v in layers["dtau"][:, c]]
    cfg.single_scat_albedo = [float(v) for v in layers["ssa"][:, c]]
    cfg.phase_function_moments = [[float(v) for v in layers["moments"][k, :, c]] for k in range(n_layers)]
    if not fluxes_only:
        cfg.tau_user = [float(v) for v in tau_user]
        cfg.mu_user = [float(v) for v in mu_user]
        cfg.phi_user = [float(v) for v in phi_user]
    cfg.bc.direct_beam_flux = 1.0
    cfg.bc.direct_beam_mu = float(mu0)
    cfg.bc.direct_beam_phi = 0.0
    cfg.bc.surface_albedo = float(surface_albedo[c])
    return disortpp.DisortSolver().solve(cfg)


def _albedo3(surface_albedo):
    a = np.broadcast_to(np.asarray(surface_albedo, dtype=float), (3,)).copy()
    if np.any(~np.isfinite(a)) or np.any((a < 0) | (a > 1)):
        raise SwimInputError(f"surface_albedo must be in [0, 1]; got {surface_albedo!r}")
    return a


def disort_clear_sky_radiance(sun_zenith_deg, view_zenith_deg, relative_azimuth_deg,
                              aerosol: AerosolBackground = AerosolBackground(), surface_albedo=0.06,
                              observer="ground", n_streams=64, n_layers=60, n_moments=None, tau_scale=1.0,
                              intensity_correction=True):
    """Clear-sky radiance L' (paper Eq. 2) from DISORT, for views at the ground or the top of the atmosphere.

    Parameters
    ----------
    sun_zenith_deg : float
        Solar zenith angle [deg], 0 ... < 90.
    view_zenith_deg, relative_azimuth_deg : array_like
        Broadcast to (n_views,): zenith angle of the *look* direction [deg] (< 90 looking up for
        ``observer="ground"``, > 90 looking down for ``"toa"``; 90 is not allowed) and look azimuth minus
        sun azimuth [deg], both azimuths clockwise from north (swim's convention; 0 = towards the sun).
    aerosol : AerosolBackground
        Background aerosol of the same kind swim uses (``aod_550=0`` for pure Rayleigh).
    surface_albedo : float or array_like
        Lambertian albedo, scalar or (3,) at 615/546/450 nm.
    observer : {"ground", "toa"}
        At sea level or at 100 km.
    n_streams : int
        DISORT streams (even, >= 4).
    n_layers : int
        Layers from 0 to 100 km (quadratic spacing, thin near the ground).
    n_moments : int, optional
        Legendre moments of the phase functions; default max(2 n_streams, 256).
    tau_scale : float
        Multiply all optical depths (tests of the optically thin limit).
    intensity_correction : bool
        Nakajima-Tanaka intensity correction (recommended with delta-M for forward-peaked aerosol).

    Returns
    -------
    numpy.ndarray
        Shape (n_views, 3): diffuse L' = 4 pi I / F0 at 615, 546, 450 nm (no direct sun).

    Raises
    ------
    SwimInputError
        Bad angles, observer or albedo.
    """
    mu0 = float(np.cos(np.radians(sun_zenith_deg)))
    if not (0.0 < mu0 <= 1.0):
        raise SwimInputError(f"sun_zenith_deg must be in [0, 90); got {sun_zenith_deg}")
    _views(view_zenith_deg, relative_azimuth_deg, observer)  # check the angles before building layers
    n_moments = int(n_moments or max(2 * int(n_streams), 256))
    layers = clear_sky_layers(aerosol, n_layers=n_layers, n_moments=n_moments, tau_scale=tau_scale)
    return disort_layers_radiance(layers, sun_zenith_deg, view_zenith_deg, relative_azimuth_deg,
                                  surface_albedo=surface_albedo, observer=observer, n_streams=n_streams,
                                  intensity_correction=intensity_correction)


def disort_clear_sky_irradiance(sun_zenith_deg, aerosol: AerosolBackground = AerosolBackground(),
                                surface_albedo=0.06, n_streams=32, n_layers=60, n_moments=None):
    """Direct and diffuse horizontal irradiance at the ground relative to E_TOA (F0 = 1).

    Returns
    -------
    dict
        ``direct`` (3,) = mu0 e^{-tau/mu0} and ``diffuse`` (3,) downward diffuse flux, both per unit E_TOA.
    """
    mu0 = float(np.cos(np.radians(sun_zenith_deg)))
    albedo = _albedo3(surface_albedo)
    n_moments = int(n_moments or max(2 * int(n_streams), 256))
    layers = clear_sky_layers(aerosol, n_layers=n_layers, n_moments=n_moments)
    direct, diffuse = np.empty(3), np.empty(3)
    for c in range(3):
        res = _solve(layers, c, mu0, albedo, n_streams, fluxes_only=True)
        direct[c] = np.asarray(res.flux_direct_beam)[-1]
        diffuse[c] = np.asarray(res.flux_down)[-1]
    return {"direct": direct, "diffuse": diffuse}


# --------------------------------------------------------------------------------------------------------
# swim against DISORT for a ground observer
# --------------------------------------------------------------------------------------------------------
def sky_dome_directions(zenith_step_deg=10.0, azimuth_step_deg=15.0, max_zenith_deg=85.0):
    """Look directions over the sky dome: zenith 5, 15, ... <= max_zenith_deg by azimuth 0, 15, ... [deg].

    Returns
    -------
    zenith, azimuth : numpy.ndarray
        Flat arrays [deg] (azimuth clockwise from north), zenith included once.
    """
    zen = np.arange(zenith_step_deg / 2.0, max_zenith_deg + 1e-9, zenith_step_deg)
    az = np.arange(0.0, 360.0, azimuth_step_deg)
    z, a = np.meshgrid(zen, az, indexing="ij")
    return z.ravel(), a.ravel()


def clear_scene(surface_albedo=0.06):
    """A small cloud-free sea scene (zero hydrometeor contents, land_mask 0) for clear-sky renders."""
    from ..io.scene import scene_from_arrays

    x = np.linspace(-2000.0, 2000.0, 5)
    z = np.array([50.0, 250.0, 500.0, 1000.0, 2000.0])
    zero = np.zeros((z.size, x.size, x.size))
    return scene_from_arrays(x=x, y=x, z=z, reference_lat=40.0, reference_lon=-105.0,
                             cloud_liquid_content=zero, surface_albedo=surface_albedo, land_mask=0.0,
                             title="clear sea scene (DISORT validation)")


def aerosol_layer_scene(aerosol: AerosolBackground, surface_albedo=0.06, half_width_m=300e3, top_m=12_000.0,
                        n_levels=49):
    """A cloud-free sea scene whose 3-D ``aerosol_extinction`` field is ``aerosol``'s exponential profile.

    Horizontally uniform over 600 km (so that slant sky views stay inside it), levels quadratic in height up
    to ``top_m``; render it with ``AerosolBackground(aod_550=0, type_name=aerosol.type_name)`` and compare
    with DISORT for ``aerosol``: a test of the renderer's treatment of 3-D aerosol (single scattering in the
    kernel, multiple scattering through the mean column in the successive-orders table).
    """
    from ..io.scene import scene_from_arrays
    from ..optics.aerosol import exponential_aerosol_extinction

    x = np.linspace(-half_width_m, half_width_m, 7)
    z = top_m * np.linspace(0.0, 1.0, n_levels) ** 2
    beta = np.asarray(exponential_aerosol_extinction(z, aerosol.aod_550, aerosol.scale_height_m), dtype=float)
    field = np.broadcast_to(beta[:, None, None], (z.size, x.size, x.size)).copy()
    return scene_from_arrays(x=x, y=x, z=z, reference_lat=40.0, reference_lon=-105.0,
                             cloud_liquid_content=np.zeros_like(field), aerosol_extinction=field,
                             surface_albedo=surface_albedo, land_mask=0.0,
                             title=f"uniform 3-D {aerosol.type_name} aerosol layer (DISORT validation)")


def aerosol_plume_scene(aerosol: AerosolBackground, edge_x_m=200e3, spacing_m=50e3, half_width_m=450e3,
                        surface_albedo=0.06, top_m=12_000.0, n_levels=49):
    """A cloud-free sea scene whose 3-D aerosol is ``aerosol``'s column for x <= ``edge_x_m`` and clear beyond.

    The reference point (x = 0) lies inside the plume for ``edge_x_m > 0`` and in the clear air for
    ``edge_x_m < 0``, at least |edge_x_m| from the edge, so a ground observer's sky views and the line of
    sight of a view from space at the reference point stay in air of one column, which DISORT sees as
    ``aerosol`` (inside) or no aerosol (outside); render with ``AerosolBackground(aod_550=0,
    type_name=aerosol.type_name)``. The mean column of the scene is neither, so the test exercises the
    renderer's per-column treatment of a heterogeneous, absorbing aerosol (Eqs. 30-31, docs/aerosols.md §8).
    """
    from ..io.scene import scene_from_arrays
    from ..optics.aerosol import exponential_aerosol_extinction

    x = np.arange(-half_width_m, half_width_m + spacing_m / 2, spacing_m)
    z = top_m * np.linspace(0.0, 1.0, n_levels) ** 2
    beta = np.asarray(exponential_aerosol_extinction(z, aerosol.aod_550, aerosol.scale_height_m), dtype=float)
    inside = (x <= edge_x_m).astype(float)
    field = beta[:, None, None] * np.broadcast_to(inside[None, None, :], (1, x.size, x.size))
    return scene_from_arrays(x=x, y=x, z=z, reference_lat=40.0, reference_lon=-105.0,
                             cloud_liquid_content=np.zeros_like(field), aerosol_extinction=field,
                             surface_albedo=surface_albedo, land_mask=0.0,
                             title=(f"{aerosol.type_name} plume, AOD {aerosol.aod_550}, "
                                   f"edge at x = {edge_x_m / 1e3:g} km"))


def reference_settings(settings=None):
    """Renderer settings for comparisons with the reference solvers: ``settings`` (default
    ``MarchSettings()``) with a Lambertian ground, which is what DISORT and the Mitsuba scenes assume."""
    import dataclasses

    from ..rt.march_settings import MarchSettings

    return dataclasses.replace(MarchSettings() if settings is None else settings, surface="lambertian")


def paper_method_settings():
    """``MarchSettings(cloud_scattering="albers2020")``: the paper's cloud scattering (Eqs. 12-26), which the
    comparisons of its own phase functions (an HG cloud against DISORT, the RICO references) default to."""
    from ..rt.march_settings import MarchSettings

    return MarchSettings(cloud_scattering="albers2020")


def render_settings_variants():
    """Renderer settings to compare: ``{"default": MarchSettings()}``, plus ``"single scattering"`` (the
    renderer with ``multiple_scattering=False``) where :class:`swim.rt.march_settings.MarchSettings` has that field."""
    import dataclasses

    from ..rt.march_settings import MarchSettings

    variants = {"default": reference_settings()}
    if "multiple_scattering" in {f.name for f in dataclasses.fields(MarchSettings)}:
        default_ms = MarchSettings().multiple_scattering
        other = dataclasses.replace(reference_settings(), multiple_scattering=not default_ms)
        variants["multiple scattering off" if default_ms else "multiple scattering on"] = other
    return variants


def compare_ground_sky(sun_zenith_deg, aerosol: AerosolBackground = AerosolBackground(), surface_albedo=0.06,
                       sun_azimuth_deg=135.0, settings=None, camera_size=121, sun_exclusion_deg=5.0,
                       n_streams=32, n_layers=60, zenith_step_deg=10.0, azimuth_step_deg=15.0,
                       max_zenith_deg=85.0, scene=None, render_aerosol=None):
    """Render the clear sky with swim and compare it with DISORT over the sky dome (ground observer).

    swim renders an all-sky image of a cloud-free sea scene (:func:`clear_scene`) with the sun set by
    ``sun_zenith``/``sun_azimuth``; the sky-dome directions of :func:`sky_dome_directions` are mapped to
    their nearest pixels (``camera.pixel_of_direction``) and DISORT is evaluated at the exact view
    directions of those pixels. Pixels within ``sun_exclusion_deg`` of the sun are dropped. ``scene`` and
    ``render_aerosol`` replace swim's scene and background aerosol (e.g. :func:`aerosol_layer_scene` with no
    background, whose 3-D aerosol field DISORT sees as ``aerosol``).

    Returns
    -------
    dict
        ``swim``, ``disort`` (n, 3) L'; ``rel_err`` (n, 3) = swim / DISORT - 1; ``view_zenith``,
        ``view_azimuth``, ``scattering_angle`` (n,) [deg]; ``median_abs``, ``p90_abs``, ``bias``
        (median signed), ``pearson_r`` (3,); ``diffuse_horizontal_swim``, ``diffuse_horizontal_disort`` (3,)
        diffuse irradiance on a horizontal surface / E_TOA (swim: integral of its all-sky image,
        :func:`swim.diagnostics.irradiance.sky_irradiance`); ``ghi_swim``, ``ghi_disort`` (3,) global
        horizontal irradiance / E_TOA (direct + diffuse).
    """
    from ..geometry.cameras import AllSkyCamera
    from ..pipeline import render

    settings = reference_settings(settings)
    scene = clear_scene(surface_albedo) if scene is None else scene
    ds = render(scene, camera="allsky", camera_options={"size": int(camera_size)}, sun_zenith=float(sun_zenith_deg),
                sun_azimuth=float(sun_azimuth_deg), aerosol=aerosol if render_aerosol is None else render_aerosol,
                settings=settings, height=0.0)
    cam = AllSkyCamera(size=int(camera_size))
    zen, az = sky_dome_directions(zenith_step_deg, azimuth_step_deg, max_zenith_deg)
    row, col = cam.pixel_of_direction(enu_from_azimuth_zenith(az, zen))
    rc = np.unique(np.stack([np.rint(row), np.rint(col)], axis=-1).astype(int), axis=0)
    r, c = rc[:, 0], rc[:, 1]
    sky = radiance_without_sun_disk(ds)
    vz = ds["view_zenith"].values[r, c].astype(float)
    va = ds["view_azimuth"].values[r, c].astype(float)
    sz, sa = float(ds.attrs["sun_zenith_deg"]), float(ds.attrs["sun_azimuth_deg"])
    scat = np.degrees(np.arccos(np.clip(enu_from_azimuth_zenith(va, vz) @ enu_from_azimuth_zenith(sa, sz), -1.0, 1.0)))
    keep = (scat > sun_exclusion_deg) & (vz <= max_zenith_deg + 1.0)
    r, c, vz, va, scat = r[keep], c[keep], vz[keep], va[keep], scat[keep]
    l_swim = sky[:, r, c].T.astype(float)
    l_ref = disort_clear_sky_radiance(sz, vz, va - sa, aerosol=aerosol, surface_albedo=surface_albedo,
                                      observer="ground", n_streams=n_streams, n_layers=n_layers)
    rel = l_swim / l_ref - 1.0

    # Irradiances / E_TOA: swim's from its all-sky image (exact pixel solid angles, direct beam explicit).
    irr = sky_irradiance(ds)
    e_swim = np.asarray(irr["dhi"].values, dtype=float)
    ref_irr = disort_clear_sky_irradiance(sz, aerosol=aerosol, surface_albedo=surface_albedo,
                                          n_streams=n_streams, n_layers=n_layers)
    e_ref = ref_irr["diffuse"]
    return {
        "swim": l_swim,
        "disort": l_ref,
        "rel_err": rel,
        "view_zenith": vz,
        "view_azimuth": va,
        "scattering_angle": scat,
        "median_abs": np.median(np.abs(rel), axis=0),
        "p90_abs": np.percentile(np.abs(rel), 90, axis=0),
        "bias": np.median(rel, axis=0),
        "pearson_r": np.array([np.corrcoef(l_swim[:, i], l_ref[:, i])[0, 1] for i in range(3)]),
        "diffuse_horizontal_swim": e_swim,
        "diffuse_horizontal_disort": e_ref,
        "ghi_swim": np.asarray(irr["ghi"].values, dtype=float),
        "ghi_disort": ref_irr["direct"] + ref_irr["diffuse"],
        "sun_zenith": sz,
        "sun_azimuth": sa,
    }


#: Views from space for the clear-sky comparison: (view zenith angle at the ground [deg], look azimuth - sun
#: azimuth [deg]); 0 looks towards the sun's azimuth, i.e. the observer is on the antisolar side.
CLEAR_SPACE_VIEWS = ((0.0, 0.0), (30.0, 0.0), (30.0, 90.0), (30.0, 180.0), (60.0, 0.0), (60.0, 90.0),
                     (60.0, 180.0))


def compare_space_clear(sun_zenith_deg, aerosol: AerosolBackground = AerosolBackground(), surface_albedo=0.06,
                        sun_azimuth_deg=135.0, views=CLEAR_SPACE_VIEWS, settings=None, n_streams=32, n_layers=60,
                        scene=None, render_aerosol=None):
    """swim's top-of-atmosphere radiance of a clear sea scene against DISORT's (views from space).

    Each view renders a 3 x 3 perspective image (0.05° field of view) from 400 km away along the line of sight,
    aimed at the scene's reference point (:func:`swim.validation.stratus.render_space_views`), so the local
    view and sun angles at the target are exactly the requested ones; DISORT gives L' at 100 km for the same
    angles (``observer="toa"``). ``scene`` and ``render_aerosol`` as in :func:`compare_ground_sky`.

    Returns
    -------
    dict
        ``views`` (n, 2) [deg]; ``swim``, ``disort``, ``rel_err`` (n, 3); ``median_abs``, ``max_abs`` (3,).
    """
    from .stratus import render_space_views

    views = np.asarray(views, dtype=float)
    scene = clear_scene(surface_albedo) if scene is None else scene
    l_swim = render_space_views(scene, sun_zenith_deg, sun_azimuth_deg, views=views, settings=settings,
                                target_height_m=0.0, aerosol=aerosol if render_aerosol is None else render_aerosol)
    l_ref = disort_clear_sky_radiance(sun_zenith_deg, 180.0 - views[:, 0], views[:, 1], aerosol=aerosol,
                                      surface_albedo=surface_albedo, observer="toa", n_streams=n_streams,
                                      n_layers=n_layers)
    rel = l_swim / l_ref - 1.0
    return {"views": views, "swim": l_swim, "disort": l_ref, "rel_err": rel,
            "median_abs": np.median(np.abs(rel), axis=0), "max_abs": np.max(np.abs(rel), axis=0)}


# --------------------------------------------------------------------------------------------------------
# a horizontally uniform liquid cloud layer in the same clear atmosphere
# --------------------------------------------------------------------------------------------------------
#: Asymmetry parameter of the Henyey-Greenstein phase function of the reference liquid cloud. Mie theory for
#: water droplets with r_e = 10 um gives g = 0.86-0.87 in the visible (e.g. Hu and Stamnes 1993, J. Climate 6,
#: 728, doi:10.1175/1520-0442(1993)006<0728:AAPOTR>2.0.CO;2); 0.85 is the value commonly used for stratus.
#: HG lacks the Mie forward diffraction peak and the glory/rainbow, which matters for single-scattered
#: radiance near the sun and the antisolar point, little for the multiply scattered transmitted light and
#: the fluxes of a cloud of optical depth >= 5, which depend on the phase function mostly through
#: (1 - g) tau (similarity).
CLOUD_HG_ASYMMETRY = 0.85


def cloud_layer_layers(cloud_tau, cloud_base_m=1000.0, cloud_top_m=1500.0, cloud_profile=None,
                       aerosol: AerosolBackground = AerosolBackground(), n_layers=60, n_moments=256,
                       g=CLOUD_HG_ASYMMETRY, cloud_ssa=1.0):
    """Layer optical properties of swim's clear atmosphere plus a liquid cloud layer, for DISORT.

    Parameters
    ----------
    cloud_tau : float or array_like
        Vertical optical depth of the cloud [-], scalar or (3,) at 615/546/450 nm (swim's Eq. 7 extinction is
        the same at all three). With ``cloud_profile`` it rescales the profile to this column; None keeps the
        profile's own column.
    cloud_base_m, cloud_top_m : float
        Uniform extinction between these heights [m above sea level] (ignored with ``cloud_profile``).
    cloud_profile : tuple of array_like, optional
        ``(height_m, extinction_m-1)``: the cloud extinction, piecewise linear between the given heights
        (increasing) and zero outside, e.g. the column of swim's optical volume; every node becomes a layer
        edge, so each layer's optical depth is the exact integral of the profile.
    aerosol : AerosolBackground
        The clear atmosphere's background aerosol.
    n_layers : int
        Layers of the clear atmosphere between 0 and 100 km (the cloud's edges are added).
    n_moments : int
        Highest Legendre moment.
    g : float or array_like
        Henyey-Greenstein asymmetry parameter of the cloud (chi_l = g^l), or the cloud's Legendre moments chi_l,
        (n,) or (n, 3) at 615/546/450 nm (e.g. of a Mie phase function, :func:`swim.optics.cloud_phase.
        legendre_moments`), taken up to ``n_moments`` (zeros beyond the given ones).
    cloud_ssa : float
        Single-scattering albedo of the cloud (1: swim's liquid is non-absorbing in the visible).

    Returns
    -------
    dict
        As :func:`clear_sky_layers`, plus ``tau_cloud`` (3,) [-].
    """
    if cloud_profile is None:
        if not (0.0 <= cloud_base_m < cloud_top_m < ATMOSPHERE_TOP_M):
            raise SwimInputError(f"need 0 <= cloud_base_m < cloud_top_m < 100 km; got {cloud_base_m}, {cloud_top_m}")
        zc = np.array([cloud_base_m, cloud_top_m])
        bc = np.ones(2)
    else:
        zc = np.asarray(cloud_profile[0], dtype=float)
        bc = np.asarray(cloud_profile[1], dtype=float)
        if zc.ndim != 1 or zc.shape != bc.shape or np.any(np.diff(zc) <= 0) or np.any(bc < 0):
            raise SwimInputError("cloud_profile must be (increasing heights [m], extinction >= 0 [m-1]) of one shape")
        keep = np.flatnonzero((bc > 0) | (np.roll(bc, 1) > 0) | (np.roll(bc, -1) > 0))
        zc, bc = zc[keep], bc[keep]
        if zc.size < 2:
            raise SwimInputError("cloud_profile has no cloud")
    column = float(np.sum(0.5 * (bc[1:] + bc[:-1]) * np.diff(zc)))
    tau_target = column if cloud_tau is None else np.broadcast_to(np.asarray(cloud_tau, dtype=float), (3,))
    scale = np.broadcast_to(np.asarray(tau_target, dtype=float) / column, (3,))
    edges = np.union1d(_layer_edges(n_layers), np.clip(zc, 0.0, ATMOSPHERE_TOP_M))[::-1]
    layers = clear_sky_layers(aerosol, n_moments=n_moments, edges_m=edges)
    # cloud optical depth of each layer [top, bottom]: the profile is piecewise linear on nodes that are edges
    top, bottom = edges[:-1], edges[1:]
    mid = 0.5 * (top + bottom)
    beta_mid = np.interp(mid, zc, bc, left=0.0, right=0.0)
    inside = (mid > zc[0]) & (mid < zc[-1])
    dtau_c = np.where(inside, beta_mid * (top - bottom), 0.0)[:, None] * scale[None, :]
    sca_clear = layers["dtau"] * layers["ssa"]
    sca_cloud = dtau_c * cloud_ssa
    dtau = layers["dtau"] + dtau_c
    sca = sca_clear + sca_cloud
    chi_c = cloud_moments(g, n_moments)
    frac_c = np.where(sca > 0, sca_cloud / np.where(sca > 0, sca, 1.0), 0.0)
    moments = (1.0 - frac_c)[:, None, :] * layers["moments"] + frac_c[:, None, :] * chi_c[None, :, :]
    layers.update({
        "dtau": dtau,
        "ssa": np.clip(np.where(dtau > 0, sca / np.where(dtau > 0, dtau, 1.0), 1.0), 0.0, 1.0 - 1e-9),
        "moments": moments,
        "tau_cloud": dtau_c.sum(axis=0),
    })
    return layers


def cloud_moments(g, n_moments):
    """The cloud's Legendre moments chi_0..chi_n (n_moments + 1, 3): of Henyey-Greenstein for a scalar ``g``
    (g^l), else the given moments (n,) or (n, 3), cut or padded with zeros to n_moments + 1.

    Raises
    ------
    SwimInputError
        If the moments are not finite, chi_0 is not 1, or a scalar g is not in (-1, 1).
    """
    if np.ndim(g) == 0:
        if not -1.0 < float(g) < 1.0:
            raise SwimInputError(f"the cloud's asymmetry parameter g must be in (-1, 1), got {g!r}")
        return np.repeat((float(g) ** np.arange(n_moments + 1))[:, None], 3, axis=1)
    chi = np.asarray(g, dtype=float)
    chi = np.repeat(chi[:, None], 3, axis=1) if chi.ndim == 1 else chi
    if chi.ndim != 2 or chi.shape[1] != 3 or not np.all(np.isfinite(chi)) or not np.allclose(chi[0], 1.0, atol=1e-3):
        raise SwimInputError("the cloud's Legendre moments must be finite, (n,) or (n, 3), with chi_0 = 1")
    out = np.zeros((n_moments + 1, 3))
    m = min(chi.shape[0], n_moments + 1)
    out[:m] = chi[:m]
    return out


def _views(view_zenith_deg, relative_azimuth_deg, observer):
    """Flat, checked view zenith and relative azimuth arrays [deg] for a ground or TOA observer."""
    vz, ra = np.broadcast_arrays(np.atleast_1d(np.asarray(view_zenith_deg, dtype=float)),
                                 np.atleast_1d(np.asarray(relative_azimuth_deg, dtype=float)))
    vz, ra = vz.ravel(), ra.ravel()
    if observer == "ground":
        if np.any(~(vz >= 0) | ~(vz < 90)):
            raise SwimInputError("a ground observer looks up: view_zenith_deg must be in [0, 90)")
    elif observer == "toa":
        if np.any(~(vz > 90) | ~(vz <= 180)):
            raise SwimInputError("an observer at the top of the atmosphere looks down: view_zenith_deg in (90, 180]")
    else:
        raise SwimInputError(f"observer must be 'ground' or 'toa'; got {observer!r}")
    return vz, ra


def disort_layers_radiance(layers, sun_zenith_deg, view_zenith_deg, relative_azimuth_deg, surface_albedo=0.06,
                           observer="ground", n_streams=64, intensity_correction=True):
    """Diffuse radiance L' = 4 pi I (F0 = 1) for prepared layers (:func:`clear_sky_layers`,
    :func:`cloud_layer_layers`); arguments and conventions as :func:`disort_clear_sky_radiance`.

    Returns
    -------
    numpy.ndarray
        Shape (n_views, 3).
    """
    mu0 = float(np.cos(np.radians(sun_zenith_deg)))
    if not (0.0 < mu0 <= 1.0):
        raise SwimInputError(f"sun_zenith_deg must be in [0, 90); got {sun_zenith_deg}")
    vz, ra = _views(view_zenith_deg, relative_azimuth_deg, observer)
    albedo = _albedo3(surface_albedo)
    # DISORT: mu = cosine of the propagation direction (positive up) = -cos(look zenith).
    mu = np.round(-np.cos(np.radians(vz)), 12)
    phi = np.mod(ra, 360.0)
    mu_u, mu_idx = np.unique(mu, return_inverse=True)
    phi_u, phi_idx = np.unique(np.round(phi, 9), return_inverse=True)
    out = np.empty((vz.size, 3))
    for c in range(3):
        tau_user = [float(layers["dtau"][:, c].sum())] if observer == "ground" else [0.0]
        res = _solve(layers, c, mu0, albedo, n_streams, mu_u, phi_u, tau_user,
                     intensity_correction=intensity_correction)
        inten = np.asarray(res.intensity, dtype=float)[0]
        out[:, c] = 4.0 * np.pi * inten[mu_idx, phi_idx]
    return out


def disort_layers_irradiance(layers, sun_zenith_deg, surface_albedo=0.06, n_streams=64):
    """Fluxes relative to E_TOA (F0 = 1) for prepared layers.

    Returns
    -------
    dict
        At the ground: ``direct`` (3,) = mu0 e^{-tau/mu0} (direct horizontal), ``diffuse`` (3,) (DHI),
        ``global`` (3,) (GHI), ``dni`` (3,) = e^{-tau/mu0}; at the top of the atmosphere: ``toa_up`` (3,)
        (reflected flux; plane albedo = toa_up / mu0).
    """
    mu0 = float(np.cos(np.radians(sun_zenith_deg)))
    if not (0.0 < mu0 <= 1.0):
        raise SwimInputError(f"sun_zenith_deg must be in [0, 90); got {sun_zenith_deg}")
    albedo = _albedo3(surface_albedo)
    direct, diffuse, up = np.empty(3), np.empty(3), np.empty(3)
    for c in range(3):
        res = _solve(layers, c, mu0, albedo, n_streams, fluxes_only=True)
        direct[c] = np.asarray(res.flux_direct_beam)[-1]
        diffuse[c] = np.asarray(res.flux_down)[-1]
        up[c] = np.asarray(res.flux_up)[0]
    return {"direct": direct, "diffuse": diffuse, "global": direct + diffuse, "dni": direct / mu0, "toa_up": up}


def disort_cloud_layer_radiance(sun_zenith_deg, view_zenith_deg, relative_azimuth_deg, cloud_tau,
                                cloud_base_m=1000.0, cloud_top_m=1500.0, cloud_profile=None,
                                aerosol: AerosolBackground = AerosolBackground(), surface_albedo=0.06,
                                observer="ground", g=CLOUD_HG_ASYMMETRY, n_streams=64, n_layers=60,
                                n_moments=None, intensity_correction=True):
    """Radiance L' (paper Eq. 2) under or above a uniform liquid cloud layer in swim's clear atmosphere (DISORT).

    The clear atmosphere of :func:`disort_clear_sky_radiance` plus a non-absorbing cloud of vertical optical
    depth ``cloud_tau`` with a Henyey-Greenstein phase function (``g``, default
    :data:`CLOUD_HG_ASYMMETRY`), see :func:`cloud_layer_layers`. Delta-M scaling with the Nakajima-Tanaka
    intensity correction; use >= 64 streams for cloud radiances (disortpp's corrected intensities differ
    from pydisort's by 3.5 % at 16 streams, 0.5 % at 32).

    Parameters
    ----------
    sun_zenith_deg : float
        Solar zenith angle [deg], 0 ... < 90.
    view_zenith_deg, relative_azimuth_deg : array_like
        Look directions [deg] as in :func:`disort_clear_sky_radiance` (< 90 from the ground, > 90 from the
        top of the atmosphere); relative azimuth = look azimuth - sun azimuth.
    cloud_tau : float or array_like
        Vertical cloud optical depth [-], scalar or (3,); None with ``cloud_profile`` keeps its column.
    cloud_base_m, cloud_top_m, cloud_profile
        Cloud geometry, see :func:`cloud_layer_layers`.
    aerosol : AerosolBackground
        Background aerosol.
    surface_albedo : float or array_like
        Lambertian albedo, scalar or (3,).
    observer : {"ground", "toa"}
        At sea level or at 100 km.
    g : float
        Cloud HG asymmetry parameter [-].
    n_streams, n_layers, n_moments, intensity_correction
        DISORT numerics; ``n_moments`` default max(2 n_streams, 256).

    Returns
    -------
    numpy.ndarray
        Shape (n_views, 3): diffuse L' = 4 pi I / F0 at 615, 546, 450 nm (no direct sun).
    """
    n_moments = int(n_moments or max(2 * int(n_streams), 256))
    layers = cloud_layer_layers(cloud_tau, cloud_base_m, cloud_top_m, cloud_profile, aerosol, n_layers, n_moments, g)
    return disort_layers_radiance(layers, sun_zenith_deg, view_zenith_deg, relative_azimuth_deg, surface_albedo,
                                  observer, n_streams, intensity_correction)


def disort_cloud_layer_irradiance(sun_zenith_deg, cloud_tau, cloud_base_m=1000.0, cloud_top_m=1500.0,
                                  cloud_profile=None, aerosol: AerosolBackground = AerosolBackground(),
                                  surface_albedo=0.06, g=CLOUD_HG_ASYMMETRY, n_streams=64, n_layers=60,
                                  n_moments=None):
    """GHI, DHI and direct irradiance at the ground and the reflected flux at the TOA, relative to E_TOA.

    Same cloud and atmosphere as :func:`disort_cloud_layer_radiance`.

    Returns
    -------
    dict
        See :func:`disort_layers_irradiance` (``global``, ``diffuse``, ``direct``, ``dni``, ``toa_up``,
        each (3,) [-]), plus ``tau_cloud`` (3,).
    """
    n_moments = int(n_moments or max(2 * int(n_streams), 256))
    layers = cloud_layer_layers(cloud_tau, cloud_base_m, cloud_top_m, cloud_profile, aerosol, n_layers, n_moments, g)
    out = disort_layers_irradiance(layers, sun_zenith_deg, surface_albedo, n_streams)
    out["tau_cloud"] = layers["tau_cloud"]
    return out
