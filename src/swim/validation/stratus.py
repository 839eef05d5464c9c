"""swim against DISORT for a horizontally uniform stratus deck (the goal for overcast stratus of optical depth 5-50:
GHI within 10 %, zenith radiance within 15 %).

The scene (:func:`stratus_scene`) is a liquid cloud layer between 1.0 and 1.5 km with effective radius 10 um
over a sea of albedo 0.06, 600 km wide so that the all-sky camera sees cloud down to the horizon (at 89°
view zenith the line of sight meets the cloud 86 km away). Its liquid water content is set so that swim's
own optical volume (Eq. 7 extinction, resampled onto the regular levels) has the requested vertical optical
depth, and DISORT gets exactly that extinction profile (:func:`swim.validation.disort.cloud_layer_layers`
with ``cloud_profile``), so both codes see the same tau at every height. The reference cloud is
non-absorbing with a Henyey-Greenstein phase function of g = 0.85 (``CLOUD_HG_ASYMMETRY``).

:func:`compare_stratus` renders an all-sky image from sea level and a few tiny perspective images from space
that look at the scene's centre at chosen view angles, and compares with DISORT: GHI and DHI (swim's from
:func:`swim.diagnostics.sky_irradiance`), the zenith radiance, the radiance over the sky dome, and the
reflected radiance at the top of the atmosphere. :func:`stratus_table_rows` makes the rows of the accuracy
table.
"""

from __future__ import annotations

import logging

import numpy as np

from ..diagnostics.irradiance import radiance_without_sun_disk as _sky
from ..errors import SwimInputError
from ..frames import enu_from_azimuth_zenith
from ..rt.gas import AerosolBackground
from .disort import (
    CLOUD_HG_ASYMMETRY,
    _albedo3,
    _solve,
    cloud_layer_layers,
    disort_layers_irradiance,
    paper_method_settings,
    reference_settings,
    sky_dome_directions,
)

log = logging.getLogger(__name__)

__all__ = ["stratus_scene", "stratus_column_profile", "compare_stratus", "stratus_table_rows",
           "DEFAULT_SPACE_VIEWS", "STRATUS_TAUS", "STRATUS_SUN_ZENITHS"]

#: Optical depths and sun zenith angles of the comparison.
STRATUS_TAUS = (1.0, 2.0, 5.0, 10.0, 20.0, 50.0)
STRATUS_SUN_ZENITHS = (30.0, 60.0)
#: Views from space: (view zenith angle at the cloud [deg], look azimuth - sun azimuth [deg]).
DEFAULT_SPACE_VIEWS = ((0.0, 0.0), (30.0, 0.0), (30.0, 180.0), (60.0, 0.0), (60.0, 180.0))
#: Reference point of the stratus scene [deg].
_LAT0, _LON0 = 40.0, -105.0
_SPACE_DISTANCE_M = 400_000.0


def stratus_scene(tau, cloud_base_m=1000.0, cloud_top_m=1500.0, effective_radius_m=10e-6, surface_albedo=0.06,
                  half_width_m=300_000.0, n_columns=7, dz_m=50.0, species="cloud_liquid"):
    """A uniform cloud deck (liquid stratus by default) whose column optical depth in swim's optical volume is
    ``tau``.

    Parameters
    ----------
    tau : float
        Vertical optical depth of the deck [-], > 0.
    cloud_base_m, cloud_top_m : float
        Model levels in [base, top] hold the liquid [m above sea level].
    effective_radius_m : float
        Droplet effective radius [m].
    surface_albedo : float
        Sea albedo [-] (land_mask 0).
    half_width_m : float
        Half the width of the (square) domain [m].
    n_columns : int
        Columns per horizontal axis.
    dz_m : float
        Model level spacing [m], levels at dz/2, 3 dz/2, ... up to 500 m above the cloud's top (at least 2 km).
    species : str
        The deck's hydrometeor (one of :data:`swim.constants.SPECIES`), e.g. "cloud_ice" for a cirrus deck.

    Returns
    -------
    xarray.Dataset
        Canonical scene (:func:`swim.io.scene.scene_from_arrays`).
    """
    from ..io.scene import scene_from_arrays

    from ..constants import SPECIES

    if not tau > 0:
        raise SwimInputError(f"tau must be > 0; got {tau}")
    if species not in SPECIES:
        raise SwimInputError(f"species must be one of {SPECIES}; got {species!r}")
    x = np.linspace(-half_width_m, half_width_m, int(n_columns))
    z = np.arange(0.5 * dz_m, max(2000.0, cloud_top_m + 500.0), dz_m)
    shape = (z.size, x.size, x.size)
    inside = ((z >= cloud_base_m) & (z <= cloud_top_m))[:, None, None] * np.ones(shape)

    def make(lwc):
        fields = {f"{species}_content": lwc * inside, f"{species}_effective_radius": effective_radius_m}
        return scene_from_arrays(x=x, y=x, z=z, reference_lat=_LAT0, reference_lon=_LON0, surface_albedo=surface_albedo,
                                 land_mask=0.0, title=f"uniform {species} deck, tau {tau:g} (DISORT validation)",
                                 **fields)

    unit = make(1e-4)
    heights, beta = stratus_column_profile(unit, species)
    tau_unit = float(np.sum(0.5 * (beta[1:] + beta[:-1]) * np.diff(heights)))
    return make(1e-4 * float(tau) / tau_unit)


def stratus_column_profile(scene, species="cloud_liquid"):
    """A species' extinction profile (cloud liquid by default) of the centre column of swim's optical volume.

    Returns
    -------
    height_m, extinction_m-1 : numpy.ndarray
        The regular levels [m] and the extinction there [m-1]; swim interpolates linearly between levels.
    """
    from ..optics.volume import build_optical_volume

    volume = build_optical_volume(scene)
    _, ny, nx = volume["aerosol_extinction"].shape
    beta = volume["extinction"].sel(species=species).values[:, ny // 2, nx // 2].astype(float)
    return volume["level"].values.astype(float), beta


def _disort_radiances(layers, sun_zenith_deg, ground_views, space_views, surface_albedo, n_streams):
    """DISORT L' for ground views (look zenith, relative azimuth) and TOA views in one solve per wavelength."""
    mu0 = float(np.cos(np.radians(sun_zenith_deg)))
    albedo = _albedo3(surface_albedo)
    gz, ga = (np.asarray(a, dtype=float) for a in ground_views)
    sz, sa = (np.asarray(a, dtype=float) for a in space_views)
    mu = np.round(np.concatenate([-np.cos(np.radians(gz)), -np.cos(np.radians(sz))]), 12)
    phi = np.round(np.mod(np.concatenate([ga, sa]), 360.0), 9)
    mu_u, mu_idx = np.unique(mu, return_inverse=True)
    phi_u, phi_idx = np.unique(phi, return_inverse=True)
    level = np.concatenate([np.ones(gz.size, int), np.zeros(sz.size, int)])  # 1: ground, 0: TOA
    out = np.empty((mu.size, 3))
    for c in range(3):
        tau_user = [0.0, float(layers["dtau"][:, c].sum())]
        res = _solve(layers, c, mu0, albedo, n_streams, mu_u, phi_u, tau_user)
        inten = np.asarray(res.intensity, dtype=float)  # (n_tau, n_mu, n_phi)
        out[:, c] = 4.0 * np.pi * inten[level, mu_idx, phi_idx]
    return out[: gz.size], out[gz.size:]



def render_space_views(scene, sun_zenith_deg, sun_azimuth_deg, views=DEFAULT_SPACE_VIEWS, settings=None,
                       target_height_m=1250.0, aerosol=None):
    """swim's TOA radiance L' (n_views, 3) looking at the scene's centre from 400 km away.

    Each view (zenith angle theta of the line of sight at the target, measured from the upward vertical to
    the observer, and look azimuth - sun azimuth) places the observer at 400 km from the target point (the
    reference point at ``target_height_m``) along that direction and renders a 3 x 3 perspective image of
    0.05° field of view pointed at the target; the centre pixel is returned. ``aerosol`` is passed to
    :func:`swim.render` (None: its default).
    """
    from ..frames import scene_to_geodetic
    from ..pipeline import render


    settings = reference_settings(settings)
    out = []
    for theta, rel_az in views:
        look_az = float(sun_azimuth_deg) + float(rel_az)
        towards_observer = enu_from_azimuth_zenith(look_az + 180.0, theta)
        target = np.array([0.0, 0.0, 6_371_000.0 + target_height_m])
        lat, lon, h = scene_to_geodetic(target + _SPACE_DISTANCE_M * towards_observer, _LAT0, _LON0)
        ds = render(scene, lat=float(lat), lon=float(lon), height=float(h), camera="perspective",
                    camera_options={"width": 3, "height": 3, "fov_deg": 0.05}, look_at=(_LAT0, _LON0, target_height_m),
                    sun_zenith=float(sun_zenith_deg), sun_azimuth=float(sun_azimuth_deg), settings=settings,
                    aerosol=aerosol)
        out.append(_sky(ds)[:, 1, 1].astype(float))
    return np.array(out)


def compare_stratus(tau, sun_zenith_deg, sun_azimuth_deg=135.0, camera_size=61, settings=None,
                    aerosol: AerosolBackground | None = None, surface_albedo=0.06, g=CLOUD_HG_ASYMMETRY,
                    n_streams=64, n_layers=30, sun_exclusion_deg=5.0, space_views=DEFAULT_SPACE_VIEWS,
                    zenith_step_deg=10.0, azimuth_step_deg=15.0, max_zenith_deg=85.0, return_images=False,
                    deck=None):
    """Render a uniform stratus deck with swim and compare with DISORT from the ground and from space.

    Parameters
    ----------
    tau : float
        Vertical cloud optical depth [-].
    sun_zenith_deg, sun_azimuth_deg : float
        The sun [deg].
    camera_size : int
        All-sky image size [pixels] (odd: the centre pixel looks at the zenith).
    settings : swim.rt.march_settings.MarchSettings, optional
        Renderer settings (default: ``cloud_scattering="albers2020"``, the paper's method, with its own phase
        functions; the 3-D method's comparisons pass its settings and its phase function's moments as ``g``).
    aerosol : AerosolBackground, optional
        Background aerosol for both codes (default: swim's default background).
    surface_albedo : float
        Sea albedo [-].
    g : float or array_like
        HG asymmetry parameter of DISORT's cloud [-], or its Legendre moments
        (:func:`swim.validation.disort.cloud_moments`).
    n_streams, n_layers : int
        DISORT streams (64 recommended; 32 agrees to ~1e-5 for this HG cloud, see docs/rendering.md) and
        clear-atmosphere layers.
    sun_exclusion_deg : float
        Sky-dome views within this angle of the sun are left out of the dome statistics [deg].
    space_views : sequence of (float, float)
        (view zenith [deg], look azimuth - sun azimuth [deg]) of the views from space; empty to skip.
    zenith_step_deg, azimuth_step_deg, max_zenith_deg : float
        Sky-dome directions (:func:`swim.validation.disort.sky_dome_directions`).
    return_images : bool
        Also return the all-sky Dataset under ``"image"``.
    deck : dict, optional
        Keyword arguments of :func:`stratus_scene` for the deck (e.g. ``species="cloud_ice"``, ``cloud_base_m``,
        ``cloud_top_m``, ``effective_radius_m``, ``dz_m``); default its liquid stratus.

    Returns
    -------
    dict
        ``tau`` (3,) as seen by both codes; ``ghi_swim``, ``ghi_disort``, ``dhi_swim``, ``dhi_disort``,
        ``ghi_err``, ``dhi_err`` (3,) [-] (relative errors swim / DISORT - 1); ``zenith_swim``,
        ``zenith_disort``, ``zenith_err`` (3,); sky dome: ``sky_swim``, ``sky_disort``, ``sky_rel_err``
        (n, 3), ``view_zenith``, ``view_azimuth`` (n,), ``median_abs``, ``p90_abs``, ``bias``, ``pearson_r``
        (3,); from space: ``space_views`` (m, 2), ``toa_swim``, ``toa_disort``, ``toa_err`` (m, 3); and the
        DISORT ``toa_up`` flux (3,).
    """
    from ..diagnostics.irradiance import sky_irradiance
    from ..geometry.cameras import AllSkyCamera
    from ..pipeline import render

    settings = reference_settings(paper_method_settings() if settings is None else settings)
    aerosol = AerosolBackground() if aerosol is None else aerosol
    deck = dict(deck or {})
    scene = stratus_scene(tau, surface_albedo=surface_albedo, **deck)
    profile = stratus_column_profile(scene, deck.get("species", "cloud_liquid"))
    ds = render(scene, camera="allsky", camera_options={"size": int(camera_size)}, sun_zenith=float(sun_zenith_deg),
                sun_azimuth=float(sun_azimuth_deg), aerosol=aerosol, settings=settings, height=0.0)
    cam = AllSkyCamera(size=int(camera_size))
    sz, sa = float(ds.attrs["sun_zenith_deg"]), float(ds.attrs["sun_azimuth_deg"])
    r, c, vz, va = _sky_dome_pixels(ds, cam, sz, sa, zenith_step_deg, azimuth_step_deg, max_zenith_deg,
                                    sun_exclusion_deg)
    centre = (int(camera_size) - 1) // 2
    sky = _sky(ds).astype(float)
    l_dome = sky[:, r, c].T
    l_zenith = sky[:, centre, centre]
    zenith_view = float(ds["view_zenith"].values[centre, centre])

    space_views = np.asarray(space_views, dtype=float).reshape(-1, 2)
    layers = cloud_layer_layers(None, cloud_profile=profile, aerosol=aerosol, n_layers=n_layers,
                                n_moments=max(2 * int(n_streams), 256), g=g)
    ground_vz = np.concatenate([[zenith_view], vz])
    ground_ra = np.concatenate([[0.0], va - sa])
    ref_ground, ref_space = _disort_radiances(layers, sz, (ground_vz, ground_ra),
                                              (180.0 - space_views[:, 0], space_views[:, 1]), surface_albedo,
                                              n_streams)
    flux = disort_layers_irradiance(layers, sz, surface_albedo, n_streams)
    out = _stratus_scores(layers, sz, sky_irradiance(ds), flux, l_zenith, l_dome, ref_ground, vz, va)
    out.update(space_views=space_views, toa_disort=ref_space, toa_up=flux["toa_up"])
    out["ghi_err"] = out["ghi_swim"] / out["ghi_disort"] - 1.0
    out["dhi_err"] = out["dhi_swim"] / out["dhi_disort"] - 1.0
    out["zenith_err"] = out["zenith_swim"] / out["zenith_disort"] - 1.0
    if len(space_views):
        middle = 0.5 * (deck.get("cloud_base_m", 1000.0) + deck.get("cloud_top_m", 1500.0))
        out["toa_swim"] = render_space_views(scene, sz, sa, space_views, settings, target_height_m=middle)
        out["toa_err"] = out["toa_swim"] / ref_space - 1.0
    if return_images:
        out["image"] = ds
    return out


def _sky_dome_pixels(ds, cam, sz, sa, zenith_step_deg, azimuth_step_deg, max_zenith_deg, sun_exclusion_deg):
    """The all-sky image's pixels nearest the sky-dome directions, away from the sun: rows, columns (n,) and their
    view zenith and azimuth (n,) [deg] (DISORT is solved at these exact directions)."""
    zen, az = sky_dome_directions(zenith_step_deg, azimuth_step_deg, max_zenith_deg)
    row, col = cam.pixel_of_direction(enu_from_azimuth_zenith(az, zen))
    rc = np.unique(np.stack([np.rint(row), np.rint(col)], axis=-1).astype(int), axis=0)
    r, c = rc[:, 0], rc[:, 1]
    vz = ds["view_zenith"].values[r, c].astype(float)
    va = ds["view_azimuth"].values[r, c].astype(float)
    scat = np.degrees(np.arccos(np.clip(enu_from_azimuth_zenith(va, vz) @ enu_from_azimuth_zenith(sa, sz), -1.0, 1.0)))
    keep = (scat > sun_exclusion_deg) & (vz <= max_zenith_deg + 1.0)
    return r[keep], c[keep], vz[keep], va[keep]


def _stratus_scores(layers, sz, irr, flux, l_zenith, l_dome, ref_ground, vz, va):
    """The ground's comparison of :func:`compare_stratus`: irradiances, zenith radiance and sky-dome statistics."""
    rel = l_dome / ref_ground[1:] - 1.0
    return {
        "tau": layers["tau_cloud"],
        "sun_zenith": sz,
        "ghi_swim": irr["ghi"].values, "ghi_disort": flux["global"],
        "dhi_swim": irr["dhi"].values, "dhi_disort": flux["diffuse"],
        "direct_swim": irr["direct_horizontal"].values, "direct_disort": flux["direct"],
        "zenith_swim": l_zenith, "zenith_disort": ref_ground[0],
        "sky_swim": l_dome, "sky_disort": ref_ground[1:], "sky_rel_err": rel,
        "view_zenith": vz, "view_azimuth": va,
        "median_abs": np.median(np.abs(rel), axis=0),
        "p90_abs": np.percentile(np.abs(rel), 90, axis=0),
        "bias": np.median(rel, axis=0),
        "pearson_r": np.array([np.corrcoef(l_dome[:, i], ref_ground[1:, i])[0, 1] for i in range(3)]),
    }


def stratus_table_rows(taus=STRATUS_TAUS, sun_zeniths=STRATUS_SUN_ZENITHS, camera_size=61, settings=None,
                       n_streams=64, space_views=DEFAULT_SPACE_VIEWS):
    """Rows of the stratus accuracy table: one per optical depth, sun zenith and wavelength.

    Returns
    -------
    list of dict
        Keys ``case`` ("uniform stratus"), ``tau``, ``sun_zenith_deg``, ``wavelength_nm``, ``ghi_error_pct``,
        ``dhi_error_pct``, ``zenith_radiance_error_pct``, ``sky_median_abs_error_pct``,
        ``sky_p90_abs_error_pct``, ``sky_bias_pct``, ``pearson_r``, ``ghi_swim``, ``ghi_disort`` [E_TOA],
        ``toa_nadir_error_pct`` and ``toa_max_abs_error_pct`` (over ``space_views``), ``toa_views``.
    """
    from ..constants import WAVELENGTHS_NM

    rows = []
    for sz in sun_zeniths:
        for tau in taus:
            res = compare_stratus(tau, sz, camera_size=camera_size, settings=settings, n_streams=n_streams,
                                  space_views=space_views)
            for i, wl in enumerate(WAVELENGTHS_NM):
                row = {
                    "case": "uniform stratus",
                    "tau": float(res["tau"][i]),
                    "sun_zenith_deg": float(sz),
                    "wavelength_nm": float(wl),
                    "ghi_error_pct": 100 * float(res["ghi_err"][i]),
                    "dhi_error_pct": 100 * float(res["dhi_err"][i]),
                    "zenith_radiance_error_pct": 100 * float(res["zenith_err"][i]),
                    "sky_median_abs_error_pct": 100 * float(res["median_abs"][i]),
                    "sky_p90_abs_error_pct": 100 * float(res["p90_abs"][i]),
                    "sky_bias_pct": 100 * float(res["bias"][i]),
                    "pearson_r": float(res["pearson_r"][i]),
                    "ghi_swim": float(res["ghi_swim"][i]),
                    "ghi_disort": float(res["ghi_disort"][i]),
                }
                if "toa_err" in res:
                    err = res["toa_err"][:, i]
                    nadir = np.flatnonzero(res["space_views"][:, 0] == 0.0)
                    row["toa_nadir_error_pct"] = 100 * float(err[nadir[0]]) if nadir.size else float("nan")
                    row["toa_max_abs_error_pct"] = 100 * float(np.max(np.abs(err)))
                    row["toa_views"] = [tuple(v) for v in res["space_views"]]
                rows.append(row)
    return rows
