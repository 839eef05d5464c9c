"""Plane-parallel clear-sky reference radiances with DISORT (DisORT++, ``disortpp``).

An independent multiple-scattering solution for the same clear atmosphere that swim renders (Step 2 of
Albers et al. 2020, Eq. 3): the Rayleigh and background-aerosol extinction profiles of
:func:`swim.rt.gas.build_gas_tables`, the depolarised Rayleigh phase function of
:func:`swim.optics.rayleigh.rayleigh_phase_function` and the aerosol type's Eq. 28 phase function and
single-scattering albedo, over a Lambertian surface. DISORT (Stamnes et al. 1988, Appl. Opt. 27, 2502,
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

import functools

import numpy as np

from ..constants import ATMOSPHERE_TOP_M, WAVELENGTHS_NM
from ..errors import SwimInputError
from ..rt.gas import AerosolBackground, build_gas_tables

__all__ = [
    "rayleigh_legendre_moments",
    "phase_function_legendre_moments",
    "clear_sky_layers",
    "disort_clear_sky_radiance",
    "disort_clear_sky_irradiance",
]


def rayleigh_legendre_moments(depolarization, n_moments):
    """Legendre moments chi_l of the depolarised Rayleigh phase function (DISORT normalisation).

    P(mu) = 3 / (4 (1 + 2 gamma)) ((1 + 3 gamma) + (1 - gamma) mu^2) with gamma = rho / (2 - rho)
    (:func:`swim.optics.rayleigh.rayleigh_phase_function`). Writing mu^2 = (1 + 2 P_2(mu)) / 3 gives
    P = 1 + (1 - gamma) / (2 (1 + 2 gamma)) P_2, i.e. with P = sum (2l + 1) chi_l P_l:
    chi_0 = 1, chi_1 = 0, chi_2 = (1 - gamma) / (10 (1 + 2 gamma)) = (1 - rho) / (5 (2 + rho)), chi_l>2 = 0
    (0.1 for rho = 0, the classical value).

    Parameters
    ----------
    depolarization : float
        Depolarisation ratio rho [-].
    n_moments : int
        Highest moment index (the array has n_moments + 1 entries), >= 2.

    Returns
    -------
    numpy.ndarray
        Shape (n_moments + 1,).
    """
    rho = float(depolarization)
    chi = np.zeros(int(n_moments) + 1)
    chi[0] = 1.0
    chi[2] = (1.0 - rho) / (5.0 * (2.0 + rho))
    return chi


def phase_function_legendre_moments(phase_function, n_moments, n_quad=None):
    """Legendre moments chi_l = 1/2 int_{-1}^{1} P(mu) P_l(mu) dmu by Gauss-Legendre quadrature.

    Parameters
    ----------
    phase_function : callable
        cos(theta) array (n,) -> P, shape (n,) or (n, k), normalised to mean 1 over the sphere.
    n_moments : int
        Highest moment index.
    n_quad : int, optional
        Quadrature points; default max(4 n_moments, 2048).

    Returns
    -------
    numpy.ndarray
        Shape (n_moments + 1,) or (n_moments + 1, k); chi_0 is 1 for a normalised P.
    """
    n_quad = int(n_quad or max(4 * n_moments, 2048))
    x, w = _gauss_legendre(n_quad)
    p = np.asarray(phase_function(x), dtype=float)
    # Legendre polynomials by the three-term recurrence, P_l(x) for l = 0..n_moments
    pl = np.empty((n_moments + 1, n_quad))
    pl[0] = 1.0
    if n_moments >= 1:
        pl[1] = x
    for l in range(1, n_moments):
        pl[l + 1] = ((2 * l + 1) * x * pl[l] - l * pl[l - 1]) / (l + 1)
    wp = p * w[:, None] if p.ndim == 2 else p * w
    return 0.5 * (pl @ wp)


@functools.lru_cache(maxsize=4)
def _gauss_legendre(n):
    """Gauss-Legendre nodes and weights on [-1, 1] (SciPy's O(n) algorithm; numpy's leggauss is O(n^3))."""
    from scipy.special import roots_legendre

    x, w = roots_legendre(int(n))
    x.flags.writeable = False
    w.flags.writeable = False
    return x, w


def _layer_edges(n_layers, top=ATMOSPHERE_TOP_M):
    """Layer edges [m], top to bottom: quadratic in height (thin layers near the ground)."""
    u = np.linspace(0.0, 1.0, int(n_layers) + 1)
    return (top * u**2)[::-1]


def clear_sky_layers(aerosol: AerosolBackground = AerosolBackground(), n_layers=60, n_moments=256,
                     wavelengths_nm=WAVELENGTHS_NM, tau_scale=1.0):
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

    Returns
    -------
    dict
        ``edges_m`` (n_layers + 1,), ``dtau`` (n_layers, 3), ``ssa`` (n_layers, 3), ``moments``
        (n_layers, n_moments + 1, 3), ``tau_rayleigh``, ``tau_aerosol`` (3,) columns and ``depolarization``.
    """
    gas = build_gas_tables(aerosol, wavelengths_nm)
    beta_r = np.asarray(gas.beta_rayleigh, dtype=float) * tau_scale
    beta_a = np.asarray(gas.beta_aerosol, dtype=float) * tau_scale
    h = np.arange(beta_r.shape[0]) * gas.dh
    edges = _layer_edges(n_layers)

    def column_above(beta):  # tau(z) above each height: trapezoid on the table grid, then interpolation
        seg = 0.5 * (beta[1:] + beta[:-1]) * gas.dh
        cum = np.concatenate([np.zeros((1, beta.shape[1])), np.cumsum(seg[::-1], axis=0)])[::-1]
        return np.stack([np.interp(edges, h, cum[:, c]) for c in range(beta.shape[1])], axis=-1)

    col_r, col_a = column_above(beta_r), column_above(beta_a)
    dtau_r = np.diff(col_r, axis=0)  # edges go downwards, so tau increases
    dtau_a = np.diff(col_a, axis=0)
    ssa_a = np.asarray(aerosol.ssa, dtype=float)
    sca_r, sca_a = dtau_r, dtau_a * ssa_a
    dtau = dtau_r + dtau_a
    sca = sca_r + sca_a
    ssa = np.where(dtau > 0, sca / np.where(dtau > 0, dtau, 1.0), 1.0)
    chi_r = rayleigh_legendre_moments(gas.depolarization, n_moments)
    chi_a = phase_function_legendre_moments(lambda x: np.asarray(aerosol.type.phase_function(x)), n_moments)
    frac_a = np.where(sca > 0, sca_a / np.where(sca > 0, sca, 1.0), 0.0)  # (n_layers, 3)
    moments = (1.0 - frac_a)[:, None, :] * chi_r[None, :, None] + frac_a[:, None, :] * chi_a[None, :, :]
    return {
        "edges_m": edges,
        "dtau": dtau,
        "ssa": np.clip(ssa, 0.0, 1.0 - 1e-9),
        "moments": moments,
        "tau_rayleigh": col_r[-1],
        "tau_aerosol": col_a[-1],
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
    albedo = _albedo3(surface_albedo)
    n_moments = int(n_moments or max(2 * int(n_streams), 256))
    layers = clear_sky_layers(aerosol, n_layers=n_layers, n_moments=n_moments, tau_scale=tau_scale)

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
        inten = np.asarray(res.intensity, dtype=float)[0]  # (n_mu, n_phi)
        out[:, c] = 4.0 * np.pi * inten[mu_idx, phi_idx]
    return out


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


def render_settings_variants():
    """Renderer settings to compare: ``{"default": MarchSettings()}``, plus ``"single scattering"`` (the
    renderer with ``multiple_scattering=False``) where :class:`swim.rt.march.MarchSettings` has that field."""
    import dataclasses

    from ..rt.march import MarchSettings

    variants = {"default": MarchSettings()}
    if "multiple_scattering" in {f.name for f in dataclasses.fields(MarchSettings)}:
        default_ms = MarchSettings().multiple_scattering
        other = dataclasses.replace(MarchSettings(), multiple_scattering=not default_ms)
        variants["multiple scattering off" if default_ms else "multiple scattering on"] = other
    return variants


def compare_ground_sky(sun_zenith_deg, aerosol: AerosolBackground = AerosolBackground(), surface_albedo=0.06,
                       sun_azimuth_deg=135.0, settings=None, camera_size=121, sun_exclusion_deg=5.0,
                       n_streams=32, n_layers=60, zenith_step_deg=10.0, azimuth_step_deg=15.0,
                       max_zenith_deg=85.0, scene=None):
    """Render the clear sky with swim and compare it with DISORT over the sky dome (ground observer).

    swim renders an all-sky image of a cloud-free sea scene (:func:`clear_scene`) with the sun set by
    ``sun_zenith``/``sun_azimuth``; the sky-dome directions of :func:`sky_dome_directions` are mapped to
    their nearest pixels (``camera.pixel_of_direction``) and DISORT is evaluated at the exact view
    directions of those pixels. Pixels within ``sun_exclusion_deg`` of the sun are dropped.

    Returns
    -------
    dict
        ``swim``, ``disort`` (n, 3) L'; ``rel_err`` (n, 3) = swim / DISORT - 1; ``view_zenith``,
        ``view_azimuth``, ``scattering_angle`` (n,) [deg]; ``median_abs``, ``p90_abs``, ``bias``
        (median signed), ``pearson_r`` (3,); ``diffuse_horizontal_swim``, ``diffuse_horizontal_disort`` (3,)
        diffuse irradiance on a horizontal surface / E_TOA (swim: integral of its all-sky image).
    """
    from ..geometry.cameras import AllSkyCamera
    from ..pipeline import render
    from ..rt.march import MarchSettings

    settings = MarchSettings() if settings is None else settings
    scene = clear_scene(surface_albedo) if scene is None else scene
    ds = render(scene, camera="allsky", camera_options={"size": int(camera_size)}, sun_zenith=float(sun_zenith_deg),
                sun_azimuth=float(sun_azimuth_deg), aerosol=aerosol, settings=settings, height=0.0)
    cam = AllSkyCamera(size=int(camera_size))
    zen, az = sky_dome_directions(zenith_step_deg, azimuth_step_deg, max_zenith_deg)
    th, ph = np.radians(zen), np.radians(az)
    dirs = np.stack([np.sin(th) * np.sin(ph), np.sin(th) * np.cos(ph), np.cos(th)], axis=-1)
    row, col = cam.pixel_of_direction(dirs)
    rc = np.unique(np.stack([np.rint(row), np.rint(col)], axis=-1).astype(int), axis=0)
    r, c = rc[:, 0], rc[:, 1]
    # swim's sky radiance without the sun's disk: the sum of its components
    sky = (ds["radiance_clear"] + ds["radiance_cloud"].fillna(0) + ds["radiance_surface"].fillna(0)).values
    vz = ds["view_zenith"].values[r, c].astype(float)
    va = ds["view_azimuth"].values[r, c].astype(float)
    sz, sa = float(ds.attrs["sun_zenith_deg"]), float(ds.attrs["sun_azimuth_deg"])
    look = np.stack([np.sin(np.radians(vz)) * np.sin(np.radians(va)), np.sin(np.radians(vz)) * np.cos(np.radians(va)),
                     np.cos(np.radians(vz))], axis=-1)
    sun = np.array([np.sin(np.radians(sz)) * np.sin(np.radians(sa)), np.sin(np.radians(sz)) * np.cos(np.radians(sa)),
                    np.cos(np.radians(sz))])
    scat = np.degrees(np.arccos(np.clip(look @ sun, -1.0, 1.0)))
    keep = (scat > sun_exclusion_deg) & (vz <= max_zenith_deg + 1.0)
    r, c, vz, va, scat = r[keep], c[keep], vz[keep], va[keep], scat[keep]
    l_swim = sky[:, r, c].T.astype(float)
    l_ref = disort_clear_sky_radiance(sz, vz, va - sa, aerosol=aerosol, surface_albedo=surface_albedo,
                                      observer="ground", n_streams=n_streams, n_layers=n_layers)
    rel = l_swim / l_ref - 1.0

    # diffuse horizontal irradiance / E_TOA: (1 / 4 pi) sum L' cos(theta) dOmega over the image
    vz_img = np.radians(ds["view_zenith"].values.astype(float))
    k = np.radians(cam.max_zenith_deg) / (cam.size / 2.0)
    d_omega = k**2 * np.sinc(vz_img / np.pi)  # equidistant fisheye: sin(theta) / theta per pixel^2
    wgt = np.where(np.isfinite(vz_img) & (vz_img < np.pi / 2), np.cos(vz_img) * d_omega, 0.0)
    e_swim = np.nansum(np.nan_to_num(sky) * wgt[None], axis=(1, 2)) / (4 * np.pi)
    e_ref = disort_clear_sky_irradiance(sz, aerosol=aerosol, surface_albedo=surface_albedo,
                                        n_streams=n_streams, n_layers=n_layers)["diffuse"]
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
        "sun_zenith": sz,
        "sun_azimuth": sa,
    }
