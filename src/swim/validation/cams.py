"""A CAMS/IFS model-aerosol column against DISORT with the per-layer optics of the IFS aerosol table.

The column: of the 32 IFS columns of ecRad's ``ecrad_meridian.nc`` (135° E, 2013-01-05), the one with the largest
AOD at 550 nm equatorward of 35° (30.5° N: sulfate, sea salt, organic matter and some dust, AOD 0.325 at 550 nm),
its own sun (zenith 59°), over a sea surface (albedo 0.06). Its 12 CAMS mass mixing ratios become per-species
extinction, ω and g with :func:`swim.optics.model_aerosol.cams_aerosol_optics`, on regular levels every 125 m up
to 19.875 km (the scene's levels; the column's AOD above holds 0.4 % of it and is left out of both).

Three references and one render (docs/aerosols.md §10, docs/validation.md §1, :func:`compare_cams_column`):

* **DISORT, per-layer mixture**: every layer its own ω and phase function, the scattering-weighted mixture of one
  Henyey-Greenstein function per species (the table gives each species' g only), and its own spectral extinction.
* **DISORT, effective type**: every layer the same ω, g (HG) and Ångström law of the column
  (:func:`swim.optics.model_aerosol.effective_aerosol_type`): what swim is told. Per-layer vs effective is the
  error of the one-type-per-scene approximation.
* **swim**: a horizontally uniform scene with the column's ``aerosol_extinction`` at 550 nm, rendered with the
  effective type, all-sky camera, sky dome 5-85° zenith every 10° by 15° in azimuth.

Used by ``tests/validation/test_cams_disort.py`` and ``scripts/make_validation_table.py``.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import xarray as xr

from ..constants import STANDARD_GRAVITY
from ..frames import enu_from_azimuth_zenith
from ..io.grib import moist_air_density
from ..io.scene import scene_from_arrays
from ..optics.legendre import phase_function_legendre_moments
from ..optics.model_aerosol import (
    cams_aerosol_optics,
    effective_aerosol_type,
    read_ifs_aerosol_optics,
    relative_humidity_liquid,
)
from ..rt.gas import AerosolBackground
from .disort import (
    _layer_edges,
    clear_sky_layers,
    compare_ground_sky,
    disort_layers_irradiance,
    disort_layers_radiance,
)

#: Spacing [m] and number of the scene's regular levels (0 ... 19.875 km).
SCENE_DZ_M = 125.0
SCENE_LEVELS = 160
#: Sea albedo of the comparison, the sun's azimuth [deg] of the render, Legendre moments of DISORT's phase functions.
SURFACE_ALBEDO = 0.06
SUN_AZIMUTH_DEG = 135.0
N_MOMENTS = 256
#: Longitude of the ecrad_meridian columns [deg E].
MERIDIAN_LON = 135.0
#: Species families of the 12 CAMS tracers (:data:`swim.optics.model_aerosol.CAMS_SPECIES_12`), for the text.
FAMILIES = {"sea salt": (0, 1, 2), "dust": (3, 4, 5), "organic matter": (6, 7), "black carbon": (8, 9),
            "sulfate": (10,), "stratospheric sulfate": (11,)}


def _paths(data_dir):
    d = Path(data_dir) / "ecrad"
    return d / "aerosol_ifs_49R1.nc", d / "ecrad_meridian.nc"


@functools.lru_cache(maxsize=2)
def cams_validation_column(data_dir):
    """The chosen IFS column's per-species optics on the scene's regular levels.

    Parameters
    ----------
    data_dir : str
        The shared data folder (with ``ecrad/aerosol_ifs_49R1.nc`` and ``ecrad/ecrad_meridian.nc``).

    Returns
    -------
    dict
        ``lat`` [deg], ``sun_zenith`` [deg] (the column's own), ``aod_550`` (the whole column's),
        ``aod_550_above_scene``, ``nodes`` (160,) [m], ``beta``, ``sca``, ``gsca`` (12, 160, 4): per-species
        extinction β [m-1], β ω and β ω g at 615, 546, 450, 550 nm on the nodes (linear in height, constant below
        the lowest model level); ``species_fraction`` (12,): each species' share of the column's 550-nm AOD.
    """
    table_path, meridian = _paths(data_dir)
    table = read_ifs_aerosol_optics(table_path)
    with xr.open_dataset(meridian) as ds:
        ph, th, q = ds["pressure_hl"].values, ds["temperature_hl"].values, ds["q"].values
        mmr, lat, mu0 = ds["aerosol_mmr"].values, ds["lat"].values, ds["cos_solar_zenith_angle"].values
    p, t = 0.5 * (ph[:, 1:] + ph[:, :-1]), 0.5 * (th[:, 1:] + th[:, :-1])
    rh = relative_humidity_liquid(q, t, p)
    rho = moist_air_density(p, t, rh)
    optics = cams_aerosol_optics(mmr, rh, rho, table, species_axis=1, return_species=True)
    dz = np.diff(ph, axis=1) / (STANDARD_GRAVITY * rho)  # hydrostatic layer thickness [m]
    aod = (optics["extinction"][..., 3] * dz).sum(axis=1)
    i = int(np.argmax(np.where(np.abs(lat) < 35.0, aod, -1.0)))
    z_hl = np.concatenate([np.cumsum(dz[i, ::-1])[::-1], [0.0]])  # half levels, top to bottom
    z_full = 0.5 * (z_hl[1:] + z_hl[:-1])[::-1]  # increasing
    beta = optics["species_extinction"][:, i, ::-1]  # (species, level, 4), increasing height
    sca = beta * optics["species_ssa"][:, i, ::-1]
    gsca = sca * optics["species_g"][:, i, ::-1]
    nodes = SCENE_DZ_M * np.arange(SCENE_LEVELS)

    def on_nodes(v):  # (species, level, 4) -> (species, node, 4): linear in height, constant below the lowest level
        return np.stack([np.stack([np.interp(nodes, z_full, v[s, :, c]) for c in range(4)], axis=-1)
                         for s in range(v.shape[0])])

    species_tau = (optics["species_extinction"][:, i, :, 3] * dz[i][None]).sum(axis=1)
    return {"lat": float(lat[i]), "sun_zenith": float(np.degrees(np.arccos(mu0[i]))), "aod_550": float(aod[i]),
            "aod_550_above_scene": float((optics["extinction"][i, :, 3] * dz[i])[z_hl[1:] >= nodes[-1]].sum()),
            "nodes": nodes, "beta": on_nodes(beta), "sca": on_nodes(sca), "gsca": on_nodes(gsca),
            "species_fraction": species_tau / species_tau.sum()}


def cams_effective_type(col):
    """:func:`~swim.optics.model_aerosol.effective_aerosol_type` of a :func:`cams_validation_column`."""
    beta = col["beta"].sum(axis=0)
    sca = col["sca"].sum(axis=0)
    return effective_aerosol_type(beta, sca / beta, col["gsca"].sum(axis=0) / sca, name="cams")


def cams_disort_layers(col, effective=None):
    """DISORT layers: swim's clear atmosphere (Rayleigh) plus the column's aerosol.

    Parameters
    ----------
    col : dict
        :func:`cams_validation_column`.
    effective : AerosolType, optional
        None: the per-layer mixture (each layer its species' extinction, β ω and Legendre moments
        Σ_s β_s ω_s g_s^l / Σ_s β_s ω_s); else every layer this type (its Ångström law on the 550-nm extinction,
        its ω and phase function).

    Returns
    -------
    dict
        As :func:`swim.validation.disort.clear_sky_layers`, with ``tau_aerosol`` (3,). The aerosol is piecewise
        linear between the nodes, which are layer edges (216 layers: the 60 clear-sky edges and the nodes).
    """
    nodes = col["nodes"]
    edges = np.union1d(_layer_edges(60), nodes)[::-1]
    layers = clear_sky_layers(AerosolBackground(aod_550=0.0), n_moments=N_MOMENTS, edges_m=edges)
    top, bottom = edges[:-1], edges[1:]
    mid, thick = 0.5 * (top + bottom), (top - bottom)
    inside = (mid < nodes[-1])[:, None]

    def layer(v):  # (species, nodes, 3) -> (species, layers, 3) optical depth of each layer
        return np.stack([np.stack([np.interp(mid, nodes, v[s, :, c]) for c in range(3)], -1)
                         for s in range(v.shape[0])]) * thick[None, :, None] * inside[None]

    l_mom = np.arange(N_MOMENTS + 1)[None, :, None]
    if effective is None:
        dtau_s, sca_s, gsca_s = layer(col["beta"]), layer(col["sca"]), layer(col["gsca"])
        g_s = np.where(sca_s > 0, gsca_s / np.where(sca_s > 0, sca_s, 1.0), 0.0)
        dtau_a, sca_a = dtau_s.sum(0), sca_s.sum(0)
        chi_sca = np.einsum("skc,sklc->klc", sca_s, g_s[:, :, None, :] ** l_mom[None])  # sum_s sca_s g_s^l
    else:
        tau550 = layer(col["beta"][:, :, 3:4].repeat(3, axis=-1)).sum(0)
        dtau_a = tau550 * effective.extinction_factor(np.array([615.0, 546.0, 450.0]))[None, :]
        sca_a = dtau_a * np.asarray(effective.ssa)[None, :]
        chi_e = phase_function_legendre_moments(lambda x: np.asarray(effective.phase_function(x)), N_MOMENTS)
        chi_sca = sca_a[:, None, :] * chi_e[None]
    sca_r = layers["dtau"] * layers["ssa"]  # Rayleigh (omega = 1) beside ozone's absorption
    dtau, sca = layers["dtau"] + dtau_a, sca_r + sca_a
    moments = (sca_r[:, None, :] * layers["moments"] + chi_sca) / sca[:, None, :]
    layers.update(dtau=dtau, ssa=np.clip(sca / dtau, 0.0, 1.0 - 1e-9), moments=moments, tau_aerosol=dtau_a.sum(0))
    return layers


@functools.lru_cache(maxsize=2)
def cams_layer_sets(data_dir):
    """(per-layer mixture, effective type) DISORT layers of :func:`cams_validation_column`."""
    col = cams_validation_column(data_dir)
    return cams_disort_layers(col), cams_disort_layers(col, cams_effective_type(col))


def cams_column_scene(col, n=7, half_width_m=300e3):
    """A horizontally uniform sea scene (n x n columns) with the column's ``aerosol_extinction`` at 550 nm."""
    x = np.linspace(-half_width_m, half_width_m, n)
    beta = np.broadcast_to(col["beta"][:, :, 3].sum(0)[:, None, None], (col["nodes"].size, n, n)).copy()
    return scene_from_arrays(x=x, y=x, z=col["nodes"], reference_lat=col["lat"], reference_lon=MERIDIAN_LON,
                             cloud_liquid_content=np.zeros_like(beta), aerosol_extinction=beta,
                             surface_albedo=SURFACE_ALBEDO, land_mask=0.0, title="CAMS column (DISORT validation)")


def scattering_angle(view_zenith, relative_azimuth, sun_zenith):
    """Scattering angle [deg] between the sun and a look direction (view zenith, view − sun azimuth) [deg]."""
    look = enu_from_azimuth_zenith(np.asarray(relative_azimuth, float), np.asarray(view_zenith, float))
    return np.degrees(np.arccos(np.clip(look @ enu_from_azimuth_zenith(0.0, sun_zenith), -1.0, 1.0)))


def radiance_statistics(test, reference, scattering_deg, ghi_test, ghi_reference, near_sun_deg=10.0):
    """Statistics of ``test`` / ``reference`` − 1 over the sky dome, per wavelength.

    Parameters
    ----------
    test, reference : array_like
        (n, 3) radiances.
    scattering_deg : array_like
        (n,) scattering angle of each view [deg].
    ghi_test, ghi_reference : array_like
        (3,) global horizontal irradiances (any common unit).
    near_sun_deg : float
        Views closer to the sun are left out of ``max_far``.

    Returns
    -------
    dict
        (3,) arrays: ``median_abs``, ``p90_abs``, ``bias`` (median signed), ``max_abs``, ``max_far`` (beyond
        ``near_sun_deg``), ``ghi`` (relative GHI error), ``pearson_r``; ``rel`` (n, 3).
    """
    a, b = np.asarray(test, float), np.asarray(reference, float)
    rel = a / b - 1.0
    far = np.asarray(scattering_deg) >= near_sun_deg
    return {"median_abs": np.median(np.abs(rel), axis=0), "p90_abs": np.percentile(np.abs(rel), 90, axis=0),
            "bias": np.median(rel, axis=0), "max_abs": np.max(np.abs(rel), axis=0),
            "max_far": np.max(np.abs(rel[far]), axis=0),
            "ghi": np.asarray(ghi_test, float) / np.asarray(ghi_reference, float) - 1.0,
            "pearson_r": np.array([np.corrcoef(a[:, i], b[:, i])[0, 1] for i in range(3)]), "rel": rel}


def compare_cams_column(data_dir, camera_size=121, n_streams=32):
    """swim, DISORT with the per-layer mixture and DISORT with the effective type, over swim's sky-dome pixels.

    Parameters
    ----------
    data_dir : str or pathlib.Path
        The shared data folder.
    camera_size : int
        swim's all-sky image size.
    n_streams : int
        DISORT's streams for the aerosol references.

    Returns
    -------
    dict
        ``column`` (:func:`cams_validation_column`), ``effective`` (AerosolType), ``n_views``, ``n_layers``,
        ``scattering_angle`` (n,) [deg], and :func:`radiance_statistics` for ``swim_vs_mixture``,
        ``swim_vs_effective`` and ``effective_vs_mixture``.
    """
    data_dir = str(data_dir)
    col = cams_validation_column(data_dir)
    eff = cams_effective_type(col)
    r = compare_ground_sky(col["sun_zenith"], AerosolBackground(aod_550=0.0), surface_albedo=SURFACE_ALBEDO,
                           sun_azimuth_deg=SUN_AZIMUTH_DEG, scene=cams_column_scene(col), camera_size=camera_size,
                           render_aerosol=AerosolBackground(aod_550=0.0, optics=eff), n_streams=8)
    ra = r["view_azimuth"] - r["sun_azimuth"]
    mix_layers, eff_layers = cams_layer_sets(data_dir)
    args = (r["sun_zenith"], r["view_zenith"], ra, SURFACE_ALBEDO)
    mix = disort_layers_radiance(mix_layers, *args, n_streams=n_streams)
    effl = disort_layers_radiance(eff_layers, *args, n_streams=n_streams)
    f_mix = disort_layers_irradiance(mix_layers, r["sun_zenith"], SURFACE_ALBEDO, n_streams=n_streams)["global"]
    f_eff = disort_layers_irradiance(eff_layers, r["sun_zenith"], SURFACE_ALBEDO, n_streams=n_streams)["global"]
    scat = r["scattering_angle"]
    return {"column": col, "effective": eff, "n_views": len(scat), "n_layers": mix_layers["dtau"].shape[0],
            "camera_size": int(camera_size), "n_streams": int(n_streams), "sun_zenith": r["sun_zenith"],
            "scattering_angle": scat,
            "swim_vs_mixture": radiance_statistics(r["swim"], mix, scat, r["ghi_swim"], f_mix),
            "swim_vs_effective": radiance_statistics(r["swim"], effl, scat, r["ghi_swim"], f_eff),
            "effective_vs_mixture": radiance_statistics(effl, mix, scat, f_eff, f_mix)}


def species_shares(col, least=0.03):
    """The column's species families with at least ``least`` of its 550-nm AOD, largest first: [(name, share)]."""
    f = col["species_fraction"]
    shares = [(name, float(f[list(idx)].sum())) for name, idx in FAMILIES.items()]
    return sorted([s for s in shares if s[1] >= least], key=lambda s: -s[1])


__all__ = ["cams_validation_column", "cams_effective_type", "cams_disort_layers",
           "cams_layer_sets", "cams_column_scene", "scattering_angle", "radiance_statistics", "compare_cams_column",
           "species_shares"]
