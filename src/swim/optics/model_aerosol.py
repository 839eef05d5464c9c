"""Aerosol of atmospheric models: CAMS/IFS species mixing ratios and WRF-Chem/HRRR-Smoke smoke to extinction.

Two sources of a scene's 3-D aerosol:

* **CAMS / IFS species.** The mass mixing ratios of the IFS aerosol scheme (``aerosol_mmr`` [kg kg-1] of ecRad's
  input; sea salt, dust, organic matter, black carbon, sulfate, ...) become an extinction coefficient, a
  single-scattering albedo and an asymmetry parameter per voxel through the IFS aerosol optics table
  (``aerosol_ifs_49R1.nc`` of ecRad: mass extinction coefficient, ω and g per species against wavenumber and,
  for the hydrophilic species, relative humidity). The species are those of Bozzo et al. (2020),
  doi:10.5194/gmd-13-1007-2020; the mapping of the model's tracers to the table's entries is ecRad's
  ``i_aerosol_type_map`` (:data:`IFS_AEROSOL_TYPE_MAP_49R1`).
* **Smoke.** A smoke mass concentration (WRF-Chem ``smoke`` tracer or PM2.5, HRRR-Smoke ``MASSDEN``) becomes an
  extinction coefficient at 550 nm through a mass extinction efficiency of biomass-burning aerosol (Reid et al.
  2005, doi:10.5194/acp-5-827-2005), to be rendered with the ``smoke`` type.

The renderer uses one aerosol type per render (docs/aerosols.md §9): a scene carries ``aerosol_extinction``
[m-1 at 550 nm] (z, y, x), and the spectral ω, g and Ångström exponent of the mixture enter as one
:class:`swim.optics.aerosol_types.AerosolType` (:func:`effective_aerosol_type`), passed to the render as
``aerosol=aerosol_type`` (the same as ``aerosol=AerosolBackground(aod_550=0.0, optics=aerosol_type)``).
docs/aerosols.md §10 quantifies the error of that approximation against DISORT with the per-layer optics
(:mod:`swim.validation.cams`). CAMS datasets as downloaded (ADS model or pressure levels, ecRad's layout) go onto
a scene's grid with :func:`swim.optics.model_aerosol_fields.add_cams_aerosol`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import xarray as xr

from ..constants import EPSILON_WATER_VAPOUR, WAVELENGTHS_NM
from ..errors import SwimInputError
from ..io.grib import saturation_vapour_pressure_water
from .aerosol_types import AerosolType, aerosol_type, custom_aerosol_type

log = logging.getLogger(__name__)

#: Wavelengths of the optical properties returned here [nm]: the three SWIm wavelengths and 550 nm (the
#: reference of ``aerosol_extinction`` and of aerosol optical depths).
MODEL_AEROSOL_WAVELENGTHS_NM = np.array([*WAVELENGTHS_NM, 550.0])

#: ecRad's ``i_aerosol_type_map`` of the IFS, Cycle 49R1 (ecmwf-ifs/ecrad, test/ifs/configCY49R1.nam): for each
#: of the 12 CAMS tracers of ``aerosol_mmr`` the table entry, negative = hydrophilic (1-based), positive =
#: hydrophobic, 0 = ignored.
IFS_AEROSOL_TYPE_MAP_49R1 = (-1, -2, -3, 7, 8, 9, -4, 10, 11, 11, -5, 14)

#: The 12 CAMS tracers in that order (the namelist's comment): sea salt bins 1-3 (0.03-0.5, 0.5-5, 5-20 µm),
#: dust bins 1-3 (0.03-0.55, 0.55-0.9, 0.9-20 µm), hydrophilic and hydrophobic organic matter, hydrophilic and
#: hydrophobic black carbon, sulfate, and the 12th tracer (SO2 in older cycles) read as stratospheric sulfate.
CAMS_SPECIES_12 = ("sea_salt_1", "sea_salt_2", "sea_salt_3", "dust_1", "dust_2", "dust_3",
                   "organic_matter_hydrophilic", "organic_matter_hydrophobic", "black_carbon_hydrophilic",
                   "black_carbon_hydrophobic", "sulfate", "stratospheric_sulfate")

#: Mass extinction efficiency of biomass-burning smoke at 550 nm [m2 kg-1] (4.5 m2 g-1): mass scattering
#: efficiency 3.5-4.0 m2 g-1 plus mass absorption efficiency 0.5-1.0 m2 g-1 of aged smoke (Reid et al. 2005,
#: Atmos. Chem. Phys. 5, 827-849, doi:10.5194/acp-5-827-2005, Sects. 4-5), consistent with the ω ≈ 0.88 of the
#: ``smoke`` type.
SMOKE_MASS_EXTINCTION_EFFICIENCY = 4.5e3

_BOZZO2020 = ("Bozzo, A., Benedetti, A., Flemming, J., Kipling, Z. and Rémy, S. (2020), An aerosol climatology "
              "for global models based on the tropospheric aerosol scheme in the Integrated Forecasting System of "
              "ECMWF, Geosci. Model Dev. 13, 1007-1034, doi:10.5194/gmd-13-1007-2020")


@dataclass(frozen=True)
class IfsAerosolOpticsTable:
    """The IFS aerosol optics table at :data:`MODEL_AEROSOL_WAVELENGTHS_NM` (:func:`read_ifs_aerosol_optics`).

    Attributes
    ----------
    wavelength_nm : numpy.ndarray
        (4,) 615, 546, 450, 550 nm.
    rh_lower : numpy.ndarray
        (n_rh,) lower bounds of the relative-humidity bins of the hydrophilic species [-] (0, 0.1, ..., 0.95).
    philic_mass_ext, philic_ssa, philic_g : numpy.ndarray
        (n_philic, n_rh, 4): mass extinction coefficient [m2 kg-1], ω [-] and g [-] of the hydrophilic species.
    phobic_mass_ext, phobic_ssa, phobic_g : numpy.ndarray
        (n_phobic, 4): the same for the hydrophobic species.
    philic_codes, phobic_codes : tuple of str
        The table's species codes (SS, OM, SU, ... / DD, OM, BC, SU).
    source : str
        The file and its product version.
    """

    wavelength_nm: np.ndarray
    rh_lower: np.ndarray
    philic_mass_ext: np.ndarray
    philic_ssa: np.ndarray
    philic_g: np.ndarray
    phobic_mass_ext: np.ndarray
    phobic_ssa: np.ndarray
    phobic_g: np.ndarray
    philic_codes: tuple
    phobic_codes: tuple
    source: str

    def rh_weights(self, relative_humidity, rh_interpolation="bin"):
        """Weights of the RH bins (..., n_rh) for ``relative_humidity`` [-] (see :func:`cams_aerosol_optics`)."""
        rh = np.clip(np.asarray(relative_humidity, dtype=float), 0.0, 1.0)
        n = self.rh_lower.size
        w = np.zeros(rh.shape + (n,))
        if rh_interpolation == "bin":  # ecRad: the bin whose lower bound is the largest one below rh
            k = np.clip(np.searchsorted(self.rh_lower, rh, side="left"), 1, n) - 1
            np.put_along_axis(w, k[..., None], 1.0, axis=-1)
            return w
        if rh_interpolation != "linear":
            raise SwimInputError(f"rh_interpolation must be 'bin' or 'linear'; got {rh_interpolation!r}")
        centres = 0.5 * (self.rh_lower + np.append(self.rh_lower[1:], 1.0))
        x = np.clip(rh, centres[0], centres[-1])
        k = np.clip(np.searchsorted(centres, x, side="right") - 1, 0, n - 2)
        f = (x - centres[k]) / (centres[k + 1] - centres[k])
        np.put_along_axis(w, k[..., None], (1.0 - f)[..., None], axis=-1)
        np.put_along_axis(w, (k + 1)[..., None], f[..., None], axis=-1)
        return w


def _log_wavelength_interpolation(wavelength_m, values, target_nm, log_values):
    """``values`` (..., n_wavenumber) at ``target_nm``: linear in ln λ (and in ln value where ``log_values``)."""
    lam = np.asarray(wavelength_m, dtype=float) * 1e9
    order = np.argsort(lam)
    x = np.log(lam[order])
    v = np.asarray(values, dtype=float)[..., order]
    v = np.log(np.maximum(v, 1e-30)) if log_values else v
    flat = v.reshape(-1, x.size)
    out = np.stack([np.interp(np.log(target_nm), x, row) for row in flat]).reshape(v.shape[:-1] + (len(target_nm),))
    return np.exp(out) if log_values else out


def read_ifs_aerosol_optics(path) -> IfsAerosolOpticsTable:
    """Read the IFS aerosol optics table and interpolate it to 615, 546, 450 and 550 nm.

    Parameters
    ----------
    path : str or pathlib.Path
        ecRad's ``aerosol_ifs_49R1.nc`` (or a table of the same layout: ``mass_ext_hydrophilic``
        (hydrophilic, relative_humidity, wavenumber), ``mass_ext_hydrophobic`` (hydrophobic, wavenumber), ``ssa_*``,
        ``asymmetry_*``, ``wavelength`` [m], ``relative_humidity1`` [-]).

    Returns
    -------
    IfsAerosolOpticsTable
        Cached per path.

    Raises
    ------
    SwimInputError
        A missing file or one without the table's variables.

    Notes
    -----
    The table is monochromatic: 331 wavenumbers 5-50000 cm-1, the optics of each species computed at each one
    (Mie theory, Bozzo et al. 2020). Near the SWIm wavelengths they lie at 632.5, 604.0, 550.8, 526.1, 458.2 and
    437.6 nm (spacing 4.6 % in wavelength); the mass extinction coefficient is interpolated linearly in
    (ln λ, ln k_e) (a local Ångström law between the two neighbours), ω and g linearly in ln λ.

    References
    ----------
    Bozzo et al. (2020), Geosci. Model Dev. 13, 1007-1034, doi:10.5194/gmd-13-1007-2020; ecRad (Hogan and
    Bozzo 2018, J. Adv. Model. Earth Syst. 10, 1990-2008, doi:10.1029/2018MS001364), data/aerosol_ifs_49R1.nc.
    """
    return _read_table(str(Path(path).expanduser().resolve()))


@lru_cache(maxsize=4)
def _read_table(path: str) -> IfsAerosolOpticsTable:
    if not Path(path).is_file():
        raise SwimInputError(f"IFS aerosol optics table not found: {path} (ecRad's aerosol_ifs_49R1.nc)")
    target = MODEL_AEROSOL_WAVELENGTHS_NM
    with xr.open_dataset(path) as ds:
        needed = ("mass_ext_hydrophilic", "ssa_hydrophilic", "asymmetry_hydrophilic", "mass_ext_hydrophobic",
                  "ssa_hydrophobic", "asymmetry_hydrophobic", "wavelength", "relative_humidity1")
        missing = [v for v in needed if v not in ds]
        if missing:
            raise SwimInputError(f"{path} is not an IFS aerosol optics table: no {', '.join(missing)}")
        lam = ds["wavelength"].values
        philic = {k: ds[f"{k}_hydrophilic"].transpose("hydrophilic", "relative_humidity", "wavenumber").values
                  for k in ("mass_ext", "ssa", "asymmetry")}
        phobic = {k: ds[f"{k}_hydrophobic"].transpose("hydrophobic", "wavenumber").values
                  for k in ("mass_ext", "ssa", "asymmetry")}

        def codes(name):
            return tuple(c.decode() if isinstance(c, bytes) else str(c) for c in ds[name].values) if name in ds else ()

        table = IfsAerosolOpticsTable(
            wavelength_nm=target.copy(),
            rh_lower=np.asarray(ds["relative_humidity1"].values, dtype=float),
            philic_mass_ext=_log_wavelength_interpolation(lam, philic["mass_ext"], target, True),
            philic_ssa=_log_wavelength_interpolation(lam, philic["ssa"], target, False),
            philic_g=_log_wavelength_interpolation(lam, philic["asymmetry"], target, False),
            phobic_mass_ext=_log_wavelength_interpolation(lam, phobic["mass_ext"], target, True),
            phobic_ssa=_log_wavelength_interpolation(lam, phobic["ssa"], target, False),
            phobic_g=_log_wavelength_interpolation(lam, phobic["asymmetry"], target, False),
            philic_codes=codes("code_hydrophilic"),
            phobic_codes=codes("code_hydrophobic"),
            source=f"{path} (product_version {ds.attrs.get('product_version', '?')})",
        )
    log.info("IFS aerosol optics: %d hydrophilic, %d hydrophobic species from %s", table.philic_mass_ext.shape[0],
             table.phobic_mass_ext.shape[0], table.source)
    return table


def relative_humidity_liquid(specific_humidity, temperature, pressure):
    """Relative humidity over liquid water [-] from specific humidity, temperature and pressure.

    Parameters
    ----------
    specific_humidity : array_like
        q [kg kg-1], >= 0.
    temperature : array_like
        [K], broadcastable.
    pressure : array_like
        [Pa], broadcastable.

    Returns
    -------
    numpy.ndarray
        e / e_s(T), clipped to [0, 1], with the vapour pressure e = q p / (ε + (1 - ε) q) and e_s over liquid
        water (:func:`swim.io.grib.saturation_vapour_pressure_water`); the humidity ecRad's driver gives the
        aerosol optics (saturation with respect to liquid water at all temperatures).

    Raises
    ------
    SwimInputError
        Negative or non-finite q, or a non-positive temperature or pressure.
    """
    q = np.asarray(specific_humidity, dtype=float)
    t = np.asarray(temperature, dtype=float)
    p = np.asarray(pressure, dtype=float)
    if np.any(~np.isfinite(q)) or np.any(q < 0):
        raise SwimInputError("specific_humidity must be finite and >= 0 [kg kg-1]")
    if np.any(~(t > 0)) or np.any(~(p > 0)):
        raise SwimInputError("temperature [K] and pressure [Pa] must be finite and > 0")
    e = q * p / (EPSILON_WATER_VAPOUR + (1.0 - EPSILON_WATER_VAPOUR) * q)
    return np.clip(e / saturation_vapour_pressure_water(t), 0.0, 1.0)


def _species_table(table, type_map, rh_w):
    """Per-species (n_species, ..., 4) mass extinction, ω and g at the voxels' RH weights ``rh_w`` (..., n_rh)."""
    kes, ssas, gs = [], [], []
    n_philic, n_phobic = table.philic_mass_ext.shape[0], table.phobic_mass_ext.shape[0]
    for s, code in enumerate(type_map):
        code = int(code)
        if code < 0:
            if -code > n_philic:
                raise SwimInputError(f"type_map[{s}] = {code}: the table has {n_philic} hydrophilic species")
            ke_rh = table.philic_mass_ext[-code - 1]  # (n_rh, 4)
            sca_rh = ke_rh * table.philic_ssa[-code - 1]
            ke = rh_w @ ke_rh
            sca = rh_w @ sca_rh
            gsca = rh_w @ (sca_rh * table.philic_g[-code - 1])
            ssa, g = sca / np.maximum(ke, 1e-30), gsca / np.maximum(sca, 1e-30)
        elif code > 0:
            if code > n_phobic:
                raise SwimInputError(f"type_map[{s}] = {code}: the table has {n_phobic} hydrophobic species")
            shape = rh_w.shape[:-1] + (4,)
            ke = np.broadcast_to(table.phobic_mass_ext[code - 1], shape)
            ssa = np.broadcast_to(table.phobic_ssa[code - 1], shape)
            g = np.broadcast_to(table.phobic_g[code - 1], shape)
        else:
            ke = ssa = g = np.zeros(rh_w.shape[:-1] + (4,))
        kes.append(ke)
        ssas.append(ssa)
        gs.append(g)
    return np.stack(kes), np.stack(ssas), np.stack(gs)


def cams_aerosol_optics(mmr, relative_humidity, air_density, table, type_map=IFS_AEROSOL_TYPE_MAP_49R1,
                        rh_interpolation="bin", species_axis=0, return_species=False):
    """Extinction coefficient, single-scattering albedo and asymmetry parameter of CAMS/IFS aerosol per voxel.

    Parameters
    ----------
    mmr : array_like
        Mass mixing ratios of the aerosol species [kg kg-1], >= 0, with the species along ``species_axis``
        (n_species = len(type_map)) and any grid shape S on the other axes (e.g. (z, y, x), or (level,) of a
        column; ecRad's ``aerosol_mmr`` (column, type, level) has ``species_axis=1``).
    relative_humidity : array_like
        Relative humidity over liquid water [-] (0-1; values outside are clipped), broadcastable to S
        (:func:`relative_humidity_liquid`).
    air_density : array_like
        Density of (moist) air [kg m-3], > 0, broadcastable to S (e.g. :func:`swim.io.grib.moist_air_density`).
    table : IfsAerosolOpticsTable or str or pathlib.Path
        The IFS optics (:func:`read_ifs_aerosol_optics`) or the path of the table file.
    type_map : sequence of int
        For each species, its table entry: -k the k-th hydrophilic (1-based), +k the k-th hydrophobic, 0
        ignored. Default :data:`IFS_AEROSOL_TYPE_MAP_49R1` (the 12 CAMS tracers of :data:`CAMS_SPECIES_12`).
    rh_interpolation : {"bin", "linear"}
        ``"bin"`` (default): the table's RH bin that contains the humidity, as ecRad and the IFS do (the
        hydrophilic optics jump at the bin edges 0.1, 0.2, ..., 0.95); ``"linear"``: linear between the bin
        centres (ke, ke ω and ke ω g are interpolated so that the mixture rules below hold).
    species_axis : int
        Axis of ``mmr`` holding the species.
    return_species : bool
        Also return the species' own optics.

    Returns
    -------
    dict
        ``extinction`` (S + (4,)) [m-1], ``ssa`` and ``g`` (S + (4,)) [-] at 615, 546, 450 and 550 nm (last axis;
        ``wavelength_nm`` (4,)). β = ρ Σ_s q_s k_e,s(RH); ω = Σ β_s ω_s / β; g = Σ β_s ω_s g_s / Σ β_s ω_s
        (extinction-weighted ω, scattering-weighted g: the exact mixing rules of an external mixture). Where β
        is 0, ω and g are those of an unweighted mean of the species (finite). With ``return_species``:
        ``species_extinction``, ``species_ssa``, ``species_g`` (n_species,) + S + (4,).

    Raises
    ------
    SwimInputError
        Negative or non-finite mixing ratios or density, a species count that does not match ``type_map``, or a
        type_map entry outside the table.

    References
    ----------
    Bozzo et al. (2020), Geosci. Model Dev. 13, 1007-1034, doi:10.5194/gmd-13-1007-2020 (the species and their
    optics); ecRad's radiation_aerosol_optics.F90 (RH bins, type map; Hogan and Bozzo 2018,
    doi:10.1029/2018MS001364).
    """
    table = table if isinstance(table, IfsAerosolOpticsTable) else read_ifs_aerosol_optics(table)
    q = np.moveaxis(np.asarray(mmr, dtype=float), species_axis, 0)
    if q.shape[0] != len(type_map):
        raise SwimInputError(f"mmr has {q.shape[0]} species along axis {species_axis}; type_map has {len(type_map)}")
    if np.any(~np.isfinite(q)) or np.any(q < 0):
        raise SwimInputError("mmr (aerosol mass mixing ratios) must be finite and >= 0 [kg kg-1]")
    rho = np.asarray(air_density, dtype=float)
    if np.any(~np.isfinite(rho)) or np.any(rho <= 0) or np.any(rho > 2.0):
        raise SwimInputError("air_density must be finite, > 0 and <= 2 [kg m-3] (got a value outside)")
    grid = np.broadcast_shapes(q.shape[1:], np.shape(relative_humidity), rho.shape)
    q = np.broadcast_to(q, (q.shape[0],) + grid)
    rh_w = table.rh_weights(np.broadcast_to(np.asarray(relative_humidity, dtype=float), grid), rh_interpolation)
    ke, ssa_s, g_s = _species_table(table, type_map, rh_w)
    beta_s = (q * np.broadcast_to(rho, grid))[..., None] * ke  # (n_species,) + S + (4,)
    beta = beta_s.sum(axis=0)
    sca_s = beta_s * ssa_s
    sca = sca_s.sum(axis=0)
    ssa = np.where(beta > 0, sca / np.where(beta > 0, beta, 1.0), ssa_s.mean(axis=0))
    g = np.where(sca > 0, (sca_s * g_s).sum(axis=0) / np.where(sca > 0, sca, 1.0), g_s.mean(axis=0))
    out = {"extinction": beta, "ssa": ssa, "g": g, "wavelength_nm": table.wavelength_nm.copy()}
    if return_species:
        out.update(species_extinction=beta_s, species_ssa=np.asarray(ssa_s), species_g=np.asarray(g_s))
    return out


def effective_aerosol_type(extinction, ssa, g, weights=None, name="model_aerosol", base="continental") -> AerosolType:
    """One aerosol type for a whole scene: the mixture's column-mean ω, g and Ångström exponent.

    Parameters
    ----------
    extinction : array_like
        S + (4,): extinction coefficient [m-1] at 615, 546, 450, 550 nm (:func:`cams_aerosol_optics`).
    ssa, g : array_like
        S + (4,): single-scattering albedo and asymmetry parameter [-].
    weights : array_like, optional
        Broadcastable to S: the volume (or layer thickness) each voxel stands for [m or m3]; default 1 (voxels of
        equal size).
    name : str
        Name of the type (recorded in the image's ``aerosol_type`` attribute).
    base : str
        Named type whose back-scatter lobe and description the result keeps (:func:`custom_aerosol_type`).

    Returns
    -------
    AerosolType
        Henyey-Greenstein phase function with g = Σ w β ω g / Σ w β ω, ω = Σ w β ω / Σ w β (per wavelength, the
        optical-depth-weighted means: the single-scattering properties of the whole column), and the Ångström
        exponent α = -ln(τ_450 / τ_615) / ln(450 / 615) of the two outer SWIm wavelengths (the renderer scales
        the 550-nm extinction with it), clipped to [-1, 4].

    Raises
    ------
    SwimInputError
        If the scene holds no aerosol (all extinction 0) or the shapes do not match.

    Notes
    -----
    The approximation: every voxel gets the column's ω, g and spectral slope. Its error in sky radiance for a
    CAMS column (dust, sea salt and sulfate at different heights) is measured against DISORT in
    docs/aerosols.md §10.
    """
    beta = np.asarray(extinction, dtype=float)
    w_ssa, w_g = np.asarray(ssa, dtype=float), np.asarray(g, dtype=float)
    if beta.shape[-1:] != (4,) or w_ssa.shape != beta.shape or w_g.shape != beta.shape:
        raise SwimInputError("extinction, ssa and g must have the same shape, ending with 4 wavelengths "
                             "(615, 546, 450, 550 nm)")
    w = np.ones(beta.shape[:-1]) if weights is None else np.broadcast_to(np.asarray(weights, float), beta.shape[:-1])
    tau = (beta * w[..., None]).reshape(-1, 4).sum(axis=0)
    if not np.all(tau > 0):
        raise SwimInputError("the scene holds no aerosol: extinction is 0 everywhere")
    sca = (beta * w_ssa * w[..., None]).reshape(-1, 4).sum(axis=0)
    gsca = (beta * w_ssa * w_g * w[..., None]).reshape(-1, 4).sum(axis=0)
    ssa_col, g_col = sca / tau, gsca / sca
    alpha = float(np.clip(-np.log(tau[2] / tau[0]) / np.log(450.0 / 615.0), -1.0, 4.0))
    t = custom_aerosol_type(base, ssa=np.clip(ssa_col[:3], 1e-6, 1.0), g=np.clip(g_col[:3], 0.0, 0.99),
                            angstrom_exponent=alpha, name=name)
    log.info("effective aerosol type %s: AOD-weighted omega %s, g %s, alpha %.2f", name, np.round(ssa_col[:3], 3),
             np.round(g_col[:3], 3), alpha)
    return t


def scene_with_aerosol_extinction(scene: xr.Dataset, extinction_550, source="model aerosol", add=False):
    """A copy of ``scene`` whose ``aerosol_extinction`` [m-1 at 550 nm] (z, y, x) is ``extinction_550``.

    Parameters
    ----------
    scene : xarray.Dataset
        Canonical scene (docs/scene-format.md).
    extinction_550 : array_like
        (z, y, x) extinction coefficient at 550 nm [m-1], finite, 0 ... 0.05.
    source : str
        Recorded in the variable's ``source`` attribute.
    add : bool
        Add to an ``aerosol_extinction`` the scene already has (the sum is rendered with one type).

    Returns
    -------
    xarray.Dataset

    Raises
    ------
    SwimInputError
        A shape other than the scene's (z, y, x), or values out of range.
    """
    beta = np.asarray(extinction_550, dtype=float)
    shape = scene["height"].shape
    if beta.shape != shape:
        raise SwimInputError(f"aerosol extinction must have the scene's shape (z, y, x) = {shape}; got {beta.shape}")
    if add and "aerosol_extinction" in scene:
        beta = beta + scene["aerosol_extinction"].values
    if np.any(~np.isfinite(beta)) or np.any(beta < 0) or np.any(beta > 0.05):
        raise SwimInputError("aerosol_extinction must be finite and in [0, 0.05] m-1 at 550 nm")
    out = scene.copy()
    out["aerosol_extinction"] = (("z", "y", "x"), beta, {"units": "m-1", "source": source,
                                                         "long_name": "aerosol extinction coefficient at 550 nm"})
    return out


def cams_scene_aerosol(scene: xr.Dataset, mmr, relative_humidity, air_density, table,
                       type_map=IFS_AEROSOL_TYPE_MAP_49R1, rh_interpolation="bin", name="cams"):
    """Put CAMS/IFS aerosol into a scene: its 550-nm extinction field and the mixture's effective type.

    Parameters
    ----------
    scene : xarray.Dataset
        Canonical scene with (z, y, x) mass points.
    mmr : array_like
        (n_species, z, y, x) mass mixing ratios [kg kg-1] on the scene's grid.
    relative_humidity, air_density : array_like
        (z, y, x) or broadcastable: RH over water [-], air density [kg m-3].
    table, type_map, rh_interpolation
        As :func:`cams_aerosol_optics`.
    name : str
        Name of the effective type.

    Returns
    -------
    scene : xarray.Dataset
        With ``aerosol_extinction`` [m-1 at 550 nm].
    aerosol_type : AerosolType
        :func:`effective_aerosol_type` of the field, each voxel weighted by its layer thickness. Render with
        ``swim.render(scene, aerosol=AerosolBackground(aod_550=0.0, optics=aerosol_type))``
        (:class:`swim.rt.gas.AerosolBackground`).

    Raises
    ------
    SwimInputError
        As :func:`cams_aerosol_optics`, or a scene without aerosol.
    """
    optics = cams_aerosol_optics(mmr, relative_humidity, air_density, table, type_map, rh_interpolation)
    z = np.asarray(scene["height"].values, dtype=float)
    thickness = np.gradient(z, axis=0) if z.shape[0] > 1 else np.ones_like(z)
    t = effective_aerosol_type(optics["extinction"], optics["ssa"], optics["g"], weights=thickness, name=name)
    return scene_with_aerosol_extinction(scene, optics["extinction"][..., 3], source="CAMS/IFS aerosol "
                                         "(IFS aerosol optics table, Bozzo et al. 2020)"), t


def smoke_extinction(mass_content, mass_extinction_efficiency=SMOKE_MASS_EXTINCTION_EFFICIENCY):
    """Extinction coefficient at 550 nm of smoke from its mass concentration.

    Parameters
    ----------
    mass_content : array_like
        Smoke (PM2.5) mass per volume of air [kg m-3], >= 0 (HRRR-Smoke ``MASSDEN``; WRF-Chem via
        :func:`wrf_chem_smoke_mass_content`).
    mass_extinction_efficiency : float
        [m2 kg-1], > 0; default :data:`SMOKE_MASS_EXTINCTION_EFFICIENCY` (4.5 m2 g-1, Reid et al. 2005).

    Returns
    -------
    numpy.ndarray
        β_550 = k_e c [m-1], the shape of ``mass_content``. The other wavelengths follow from the ``smoke`` type's
        Ångström exponent (1.9) in the renderer.

    Raises
    ------
    SwimInputError
        Negative or non-finite content, or an efficiency outside 0.5-20 m2 g-1.

    References
    ----------
    Reid, J. S., Eck, T. F., Christopher, S. A., Koppmann, R., Dubovik, O., Eleuterio, D. P., Holben, B. N.,
    Reid, E. A. and Zhang, J. (2005), A review of biomass burning emissions part III: intensive optical
    properties of biomass burning particles, Atmos. Chem. Phys. 5, 827-849, doi:10.5194/acp-5-827-2005.
    """
    c = np.asarray(mass_content, dtype=float)
    if np.any(~np.isfinite(c)) or np.any(c < 0):
        raise SwimInputError("smoke mass_content must be finite and >= 0 [kg m-3]")
    if not 500.0 <= float(mass_extinction_efficiency) <= 20e3:
        raise SwimInputError(f"mass_extinction_efficiency must be 500-20000 m2 kg-1 (0.5-20 m2 g-1); got "
                             f"{mass_extinction_efficiency!r}")
    if np.any(c > 1e-5):
        log.warning("smoke mass content up to %.3g kg m-3 (> 10 mg m-3): is it in kg m-3?", float(c.max()))
    return float(mass_extinction_efficiency) * c


def wrf_chem_smoke_mass_content(smoke, units="ug kg-1", air_density=None):
    """Smoke mass per volume [kg m-3] from a WRF-Chem smoke tracer or PM2.5 field.

    Parameters
    ----------
    smoke : array_like
        The field, >= 0: the ``smoke`` tracer (``units="ug kg-1"``, per kg of dry air, WRF-Chem's
        ``chem_opt`` smoke and HRRR-Smoke tracers) or PM2.5 (``units="ug m-3"``, e.g. ``PM2_5_DRY``).
    units : {"ug kg-1", "ug m-3", "kg kg-1", "kg m-3"}
        Units of ``smoke``.
    air_density : array_like, optional
        [kg m-3], needed for the per-mass units (WRF: 1 / ``ALT``, the inverse of the dry air's specific volume).

    Returns
    -------
    numpy.ndarray
        [kg m-3], the broadcast shape.

    Raises
    ------
    SwimInputError
        Unknown units, a per-mass unit without ``air_density``, or negative values.
    """
    factors = {"ug kg-1": 1e-9, "ug/kg": 1e-9, "kg kg-1": 1.0, "ug m-3": 1e-9, "ug/m3": 1e-9, "kg m-3": 1.0}
    if units not in factors:
        raise SwimInputError(f"smoke units must be one of {sorted(factors)}; got {units!r}")
    s = np.asarray(smoke, dtype=float)
    if np.any(~np.isfinite(s)) or np.any(s < 0):
        raise SwimInputError(f"smoke must be finite and >= 0 [{units}]")
    out = s * factors[units]
    if units in ("ug kg-1", "ug/kg", "kg kg-1"):
        if air_density is None:
            raise SwimInputError(f"smoke in {units} needs air_density [kg m-3]")
        out = out * np.asarray(air_density, dtype=float)
    return out


def add_smoke_aerosol(scene: xr.Dataset, mass_extinction_efficiency=SMOKE_MASS_EXTINCTION_EFFICIENCY,
                      variable="smoke_mass_content"):
    """The scene with ``aerosol_extinction`` from its smoke mass, and the ``smoke`` aerosol type to render with.

    Parameters
    ----------
    scene : xarray.Dataset
        Canonical scene with ``smoke_mass_content`` [kg m-3] (z, y, x) (e.g. the HRRR-Smoke reader's).
    mass_extinction_efficiency : float
        [m2 kg-1], see :func:`smoke_extinction`.
    variable : str
        Name of the smoke variable.

    Returns
    -------
    scene : xarray.Dataset
        With ``aerosol_extinction`` [m-1 at 550 nm] = k_e c, added to any the scene already has, and without
        ``variable`` (whose extinction the renderer would otherwise add again).
    aerosol_type : AerosolType
        The ``smoke`` type; render with ``aerosol=AerosolBackground(aod_550=0.0, type_name="smoke")``.

    Raises
    ------
    SwimInputError
        A scene without ``variable``, or bad values (:func:`smoke_extinction`).
    """
    if variable not in scene:
        raise SwimInputError(f"the scene has no {variable!r} [kg m-3] (z, y, x)")
    beta = smoke_extinction(scene[variable].transpose("z", "y", "x").values, mass_extinction_efficiency)
    src = f"smoke: {variable} x {mass_extinction_efficiency:g} m2 kg-1 (Reid et al. 2005)"
    # the smoke is now in aerosol_extinction: the renderer would add smoke_mass_content's extinction a second time
    out = scene_with_aerosol_extinction(scene, beta, source=src, add=True).drop_vars(variable)
    return out, aerosol_type("smoke")
