"""Clear-atmosphere tables for Step 2 (gas and the 1-D background aerosol in a spherical atmosphere).

Step 2 of the paper (Albers et al. 2020, Sect. 3.3, Eq. 3) integrates single scattering by molecules and
the horizontally uniform aerosol along each line of sight through a spherical atmosphere up to 100 km.
The kernels need, at any point of a ray, the extinction of the gas and the background aerosol and the
transmittance of the path towards the sun (Eq. 8's e^{-tau_R}); computing the latter by a nested ray per
sample would be slow, so, as in Bruneton's precomputed sky models, it is tabulated once per render as a
function of height h and the cosine mu_s of the local solar zenith angle (earth shadow included: a path
that meets the earth has zero transmittance).

Table layout (all float32 for the kernels):

* ``beta_rayleigh``, ``beta_aerosol`` (n_h, 3) [m-1] on uniform heights ``0 .. 100 km`` (step ``dh``);
* ``sun_transmittance`` (n_u, n_mu, 3) [-] on ``u = sqrt(h / H_top)`` (finer near the ground) and ``mu``
  uniform in [-1, 1];
* ``diffuse_horizontal`` (n_u, n_mu, 3) [-]: diffuse sky irradiance on a horizontal surface relative to
  E_TOA (a two-stream style single-scattering estimate, see :func:`diffuse_horizontal_estimate`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..constants import ATMOSPHERE_TOP_M, DEFAULT_AEROSOL, EARTH_RADIUS_M, WAVELENGTHS_NM
from ..optics.aerosol import exponential_aerosol_extinction
from ..errors import SwimInputError
from ..optics.aerosol_types import aerosol_type
from ..optics.atmosphere import us_standard_atmosphere_1976
from ..optics.rayleigh import rayleigh_cross_section_bodhaine1999, rayleigh_depolarization_ratio


@dataclass(frozen=True)
class AerosolBackground:
    """Horizontally uniform 1-D aerosol of a named type (issue 2 default: AOD 0.05 at 550 nm, 1.5 km).

    Attributes
    ----------
    aod_550 : float
        Aerosol optical depth at 550 nm [-], >= 0.
    scale_height_m : float
        Exponential scale height [m], > 0.
    type_name : str
        Aerosol type (:data:`swim.optics.aerosol_types.AEROSOL_TYPES`): phase function (Eq. 28), spectral
        single-scattering albedo and Angstrom exponent; also used for a scene's 3-D aerosol field.

    Raises
    ------
    SwimInputError
        Negative AOD, non-positive scale height or an unknown type.
    """

    aod_550: float = DEFAULT_AEROSOL["aod_550"]
    scale_height_m: float = DEFAULT_AEROSOL["scale_height_m"]
    type_name: str = DEFAULT_AEROSOL["type"]

    def __post_init__(self):
        if not (np.isfinite(self.aod_550) and self.aod_550 >= 0):
            raise SwimInputError(f"aerosol optical depth at 550 nm must be >= 0, got {self.aod_550}")
        if not (np.isfinite(self.scale_height_m) and self.scale_height_m > 0):
            raise SwimInputError(f"aerosol scale height must be > 0 m, got {self.scale_height_m}")
        object.__setattr__(self, "type_name", aerosol_type(self.type_name).name)

    @property
    def type(self):
        """The :class:`swim.optics.aerosol_types.AerosolType`."""
        return aerosol_type(self.type_name)

    @property
    def ssa(self):
        """Single-scattering albedo (3,) at 615/546/450 nm [-]."""
        return np.asarray(self.type.ssa, dtype=float)


@dataclass(frozen=True)
class GasTables:
    """Precomputed clear-atmosphere tables (see module docstring)."""

    dh: float
    beta_rayleigh: np.ndarray
    beta_aerosol: np.ndarray
    n_u: int
    n_mu: int
    sun_transmittance: np.ndarray
    diffuse_horizontal: np.ndarray
    depolarization: float
    aerosol: AerosolBackground
    angstrom_factor: np.ndarray
    top_m: float = ATMOSPHERE_TOP_M


def _slant_optical_depth(h, mu, heights, beta, top, radius, n_steps=400):
    """Optical depth [-] from height h towards direction cosine mu to the top (inf where the earth blocks)."""
    r0 = radius + h
    rt = radius + top
    s_top = -r0 * mu + np.sqrt(np.maximum(r0**2 * mu**2 + rt**2 - r0**2, 0.0))
    # Quadratic spacing: dense near the start, where the air is densest for upward paths.
    u = (np.arange(n_steps) + 0.5) / n_steps
    s = s_top[..., None] * u**2
    ds = s_top[..., None] * 2 * u / n_steps
    hh = np.sqrt(r0[..., None] ** 2 + s**2 + 2 * r0[..., None] * mu[..., None] * s) - radius
    tau = np.zeros(h.shape + (beta.shape[1],))
    for c in range(beta.shape[1]):
        tau[..., c] = np.sum(np.interp(hh, heights, beta[:, c]) * ds, axis=-1)
    blocked = (mu < 0) & (r0**2 * (1 - mu**2) < radius**2)
    tau[blocked] = np.inf
    return tau


def diffuse_horizontal_estimate(mu_s, tau_rayleigh, tau_aerosol, aerosol_ssa):
    """Clear-sky diffuse horizontal irradiance relative to E_TOA [-], a single-scattering estimate.

    Half of the Rayleigh-scattered and ~75 % of the (forward-peaked) aerosol-scattered direct beam reach
    the ground: ``mu_s [0.5 (1 - e^{-tau_R/mu_s}) + 0.75 omega (1 - e^{-tau_A/mu_s})]``. Used only to light
    the ground (Eq. 35 with ARF = 1); multiple scattering is left to issue 3.

    Parameters
    ----------
    mu_s : numpy.ndarray
        Cosine of the solar zenith angle [-]; no diffuse light for mu_s <= 0.
    tau_rayleigh, tau_aerosol : numpy.ndarray
        Vertical optical depths above the point [-], broadcastable with mu_s.
    aerosol_ssa : float or numpy.ndarray
        Aerosol single-scattering albedo [-] (per wavelength on the last axis).
    """
    mu = np.maximum(mu_s, 1e-3)
    d = mu * (0.5 * (1 - np.exp(-tau_rayleigh / mu)) + 0.75 * aerosol_ssa * (1 - np.exp(-tau_aerosol / mu)))
    return np.where(mu_s > 0, d, 0.0)


def build_gas_tables(aerosol: AerosolBackground = AerosolBackground(), wavelengths_nm=WAVELENGTHS_NM,
                     dh=100.0, n_u=96, n_mu=512, radius=EARTH_RADIUS_M) -> GasTables:
    """Build the Step 2 clear-atmosphere tables.

    Parameters
    ----------
    aerosol : AerosolBackground
        Background aerosol (set ``aod_550=0`` for a pure Rayleigh atmosphere).
    wavelengths_nm : array_like
        Shape (3,): wavelengths [nm].
    dh : float
        Height step of the extinction profiles [m].
    n_u, n_mu : int
        Size of the transmittance tables in sqrt-height and mu.
    radius : float
        Earth radius [m].

    Returns
    -------
    GasTables

    References
    ----------
    Albers et al. (2020), Eqs. 3 and 8; Bodhaine et al. (1999), doi:10.1175/1520-0426(1999)016<1854:ORODC>2.0.CO;2;
    US Standard Atmosphere (1976).
    """
    wl = tuple(float(w) for w in np.atleast_1d(wavelengths_nm))
    return _build_gas_tables_cached(aerosol, wl, float(dh), int(n_u), int(n_mu), float(radius))


@functools.lru_cache(maxsize=8)
def _build_gas_tables_cached(aerosol, wavelengths_nm, dh, n_u, n_mu, radius) -> GasTables:
    """Cached worker of :func:`build_gas_tables` (the tables depend only on these arguments)."""
    wl = np.asarray(wavelengths_nm, dtype=float)
    heights = np.arange(0.0, ATMOSPHERE_TOP_M + dh / 2, dh)
    _, _, number_density = us_standard_atmosphere_1976(heights)
    sigma = np.asarray(rayleigh_cross_section_bodhaine1999(wl))
    beta_r = number_density[:, None] * sigma[None, :]
    factor = np.asarray(aerosol.type.extinction_factor(wl), dtype=float)
    beta_a = np.asarray(exponential_aerosol_extinction(heights, aerosol.aod_550, aerosol.scale_height_m))[:, None] * factor[None, :]
    beta = beta_r + beta_a

    u = np.linspace(0.0, 1.0, n_u)
    hu = ATMOSPHERE_TOP_M * u**2
    mu = np.linspace(-1.0, 1.0, n_mu)
    H, M = np.meshgrid(hu, mu, indexing="ij")
    tau = _slant_optical_depth(H, M, heights, beta, ATMOSPHERE_TOP_M, radius)
    transmittance = np.exp(-tau)

    # Vertical optical depths above each table height, for the diffuse estimate.
    col_r = np.cumsum((beta_r * dh)[::-1], axis=0)[::-1]
    col_a = np.cumsum((beta_a * dh)[::-1], axis=0)[::-1]
    tr = np.stack([np.interp(hu, heights, col_r[:, c]) for c in range(3)], axis=-1)
    ta = np.stack([np.interp(hu, heights, col_a[:, c]) for c in range(3)], axis=-1)
    diffuse = diffuse_horizontal_estimate(M[..., None], tr[:, None, :], ta[:, None, :], aerosol.ssa)

    return GasTables(
        dh=dh,
        beta_rayleigh=beta_r.astype(np.float32),
        beta_aerosol=beta_a.astype(np.float32),
        n_u=n_u,
        n_mu=n_mu,
        sun_transmittance=transmittance.astype(np.float32),
        diffuse_horizontal=diffuse.astype(np.float32),
        depolarization=float(np.mean(rayleigh_depolarization_ratio(wl))),
        aerosol=aerosol,
        angstrom_factor=factor.astype(np.float32),
    )
