"""Clear-atmosphere tables for Step 2 (gas and the 1-D background aerosol in a spherical atmosphere).

Step 2 of the paper (Albers et al. 2020, Sect. 3.3, Eq. 3) integrates single scattering by molecules and
the horizontally uniform aerosol along each line of sight through a spherical atmosphere up to 100 km.
The kernels need, at any point of a ray, the extinction of the gas and the background aerosol and the
transmittance of the path towards the sun (Eq. 8's e^{-tau_R}); computing the latter by a nested ray per
sample would be slow, so, as in Bruneton's precomputed sky models, it is tabulated once per render as a
function of height h and the cosine mu_s of the local solar zenith angle (earth shadow included: a path
that meets the earth has zero transmittance).

Table layout (all float32 for the kernels):

* ``beta_rayleigh``, ``beta_aerosol``, ``beta_stratospheric`` (n_h, 3) [m-1] on uniform heights
  ``0 .. 100 km`` (step ``dh``): molecules, the background aerosol and the stratospheric aerosol layer;
* ``beta_ozone`` (n_h, 3) [m-1]: ozone's absorption (:mod:`swim.optics.ozone`, ``AerosolBackground.ozone_du``), in
  the sun's transmittance and the diffuse tables (docs/decisions/0023-ozone-and-twilight.md);
* ``sun_transmittance`` (n_u, n_mu, 3) [-] on ``u = sqrt(h / H_top)`` (finer near the ground) and ``mu``
  uniform in [-1, 1];
* ``diffuse_horizontal`` (n_u, n_mu, 3) [-]: diffuse sky irradiance on a horizontal surface relative to
  E_TOA, all orders of scattering, from the successive-orders solution of
  :mod:`swim.rt.multiple_scattering`;
* ``diffuse_source``: that module's :class:`~swim.rt.multiple_scattering.DiffuseSourceTable`, the
  directional source of the higher scattering orders that the ray march adds to Eq. 3.

A scene's 3-D aerosol field enters the multiple-scattering solution by *column classes* (the project's
form of the paper's Eqs. 30-31, absorbing aerosol layers and their multiple-scattering albedo omega'): one
successive-orders table per class of column aerosol optical depth (``aerosol_class_aod``), each for the
scene's mean aerosol profile scaled to that column; the kernel interpolates between the two classes that
bracket the column of each ray (docs/aerosols.md, §8). Absorption inside the plume then darkens its
multiply scattered light exactly as in a plane-parallel column of the same optical depth and omega.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..constants import ATMOSPHERE_TOP_M, DEFAULT_AEROSOL, EARTH_RADIUS_M, WAVELENGTHS_NM
from ..optics.aerosol import exponential_aerosol_extinction
from ..errors import SwimInputError
from ..optics.aerosol_types import AerosolType, aerosol_type
from ..optics.atmosphere import us_standard_atmosphere_1976
from ..optics.ozone import US_STANDARD_OZONE_DU, ozone_absorption_coefficient
from ..optics.rayleigh import (rayleigh_cross_section_bodhaine1999, rayleigh_depolarization_ratio,
                              rayleigh_phase_function)
from ..compilation.disk_cache import disk_cached, package_sources
from .multiple_scattering import DiffuseSourceTable, diffuse_source_table


@dataclass(frozen=True)
class AerosolBackground:
    """Horizontally uniform 1-D aerosol of a named type (default: AOD 0.05 at 550 nm, 1.5 km).

    Attributes
    ----------
    aod_550 : float
        Aerosol optical depth at 550 nm [-], >= 0.
    scale_height_m : float
        Exponential scale height [m], > 0.
    type_name : str
        Aerosol type (:data:`swim.optics.aerosol_types.AEROSOL_TYPES`): phase function (Eq. 28), spectral
        single-scattering albedo and Angstrom exponent; also used for a scene's 3-D aerosol field.
    stratospheric_aod_550 : float
        Optical depth at 550 nm of the stratospheric aerosol layer [-], >= 0 (paper Sect. 3.3: "a 1D
        stratospheric variable" for Step 2). Default 0 (background stratosphere neglected).
    stratospheric_height_m : float
        Height of the layer's peak [m], 10-50 km (default 20 km, the Junge layer).
    stratospheric_width_m : float
        Gaussian standard deviation of the layer [m], 0.5-15 km (default 3 km).
    stratospheric_type : str
        Aerosol type of the layer (default ``stratospheric_sulfate``).
    optics : AerosolType, optional
        The aerosol's own optics (:func:`swim.optics.aerosol_types.custom_aerosol_type`) in place of the named
        type's; ``type_name`` becomes its name.
    ozone_du : float
        Ozone column of the clear atmosphere [DU], 0-1000 (default 345.5, the US standard profile's,
        :data:`swim.optics.ozone.US_STANDARD_OZONE_DU`; 0 leaves ozone out): the US standard ozone profile
        scaled to this column absorbs in the Chappuis band (:mod:`swim.optics.ozone`, docs/rendering.md,
        "Ozone and twilight").

    Raises
    ------
    SwimInputError
        Negative AOD, non-positive scale height, a stratospheric layer out of range, an unknown type or an
        ozone column outside 0-1000 DU.
    """

    aod_550: float = DEFAULT_AEROSOL["aod_550"]
    scale_height_m: float = DEFAULT_AEROSOL["scale_height_m"]
    type_name: str = DEFAULT_AEROSOL["type"]
    stratospheric_aod_550: float = 0.0
    stratospheric_height_m: float = 20_000.0
    stratospheric_width_m: float = 3_000.0
    stratospheric_type: str = "stratospheric_sulfate"
    optics: AerosolType | None = None
    ozone_du: float = US_STANDARD_OZONE_DU

    def __post_init__(self):
        if not (np.isfinite(self.ozone_du) and 0.0 <= self.ozone_du <= 1000.0):
            raise SwimInputError(f"ozone column ozone_du must be 0-1000 DU (Dobson units), got {self.ozone_du}")
        if not (np.isfinite(self.aod_550) and self.aod_550 >= 0):
            raise SwimInputError(f"aerosol optical depth at 550 nm must be >= 0, got {self.aod_550}")
        if not (np.isfinite(self.scale_height_m) and self.scale_height_m > 0):
            raise SwimInputError(f"aerosol scale height must be > 0 m, got {self.scale_height_m}")
        if not (np.isfinite(self.stratospheric_aod_550) and self.stratospheric_aod_550 >= 0):
            raise SwimInputError("stratospheric aerosol optical depth at 550 nm must be >= 0, "
                                 f"got {self.stratospheric_aod_550}")
        if not (10_000.0 <= self.stratospheric_height_m <= 50_000.0):
            raise SwimInputError("stratospheric aerosol peak height must be 10000-50000 m, "
                                 f"got {self.stratospheric_height_m}")
        if not (500.0 <= self.stratospheric_width_m <= 15_000.0):
            raise SwimInputError("stratospheric aerosol layer width must be 500-15000 m, "
                                 f"got {self.stratospheric_width_m}")
        if self.optics is not None:
            if not isinstance(self.optics, AerosolType):
                raise SwimInputError(f"aerosol optics must be an AerosolType (swim.optics.aerosol_types."
                                     f"custom_aerosol_type); got {type(self.optics).__name__}")
            object.__setattr__(self, "type_name", self.optics.name)
        else:
            object.__setattr__(self, "type_name", aerosol_type(self.type_name).name)
        object.__setattr__(self, "stratospheric_type", aerosol_type(self.stratospheric_type).name)

    @property
    def type(self):
        """The :class:`swim.optics.aerosol_types.AerosolType`: ``optics`` where given, else the named type."""
        return self.optics if self.optics is not None else aerosol_type(self.type_name)

    @property
    def ssa(self):
        """Single-scattering albedo (3,) at 615/546/450 nm [-]."""
        return np.asarray(self.type.ssa, dtype=float)

    @property
    def stratospheric(self):
        """The :class:`swim.optics.aerosol_types.AerosolType` of the stratospheric layer."""
        return aerosol_type(self.stratospheric_type)

    def stratospheric_extinction(self, heights_m, wavelengths_nm=WAVELENGTHS_NM):
        """Extinction coefficient of the stratospheric layer (n_h, C) [m-1] at heights [m].

        A Gaussian in height whose integral over 0-100 km is ``stratospheric_aod_550``, scaled to the
        wavelengths with the type's Angstrom exponent.

        Parameters
        ----------
        heights_m : array_like
            Shape (n_h,): heights [m].
        wavelengths_nm : array_like
            Shape (C,): wavelengths [nm].

        Returns
        -------
        numpy.ndarray
            Shape (n_h, C): extinction coefficient [m-1].

        Source: Albers et al. (2020), Sect. 3.3 (the 1-D stratospheric variable of Step 2); the profile is a
        project choice (docs/aerosols.md, §7).
        """
        h = np.asarray(heights_m, dtype=float)
        shape = np.exp(-0.5 * ((h - self.stratospheric_height_m) / self.stratospheric_width_m) ** 2)
        fine = np.linspace(0.0, ATMOSPHERE_TOP_M, 20001)
        norm = np.trapezoid(np.exp(-0.5 * ((fine - self.stratospheric_height_m) / self.stratospheric_width_m) ** 2),
                            fine)
        factor = np.asarray(self.stratospheric.extinction_factor(np.asarray(wavelengths_nm, float)), dtype=float)
        return (self.stratospheric_aod_550 * shape / norm)[:, None] * factor[None, :]


@dataclass(frozen=True)
class GasTables:
    """Precomputed clear-atmosphere tables (see module docstring)."""

    dh: float
    beta_rayleigh: np.ndarray
    beta_aerosol: np.ndarray
    beta_stratospheric: np.ndarray
    n_u: int
    n_mu: int
    sun_transmittance: np.ndarray
    diffuse_horizontal: np.ndarray
    depolarization: float
    aerosol: AerosolBackground
    angstrom_factor: np.ndarray
    diffuse_source: DiffuseSourceTable
    surface_albedo: tuple
    top_m: float = ATMOSPHERE_TOP_M
    #: Column optical depth at 550 nm of the scene's 3-D aerosol in each class (n_class,) [-]; [0] without
    #: a 3-D field, (mean,) when the field has a single class.
    aerosol_class_aod: np.ndarray | None = None
    #: One :class:`DiffuseSourceTable` per class (``diffuse_source`` is the class nearest the mean column).
    diffuse_sources: tuple = ()
    #: ``diffuse_horizontal`` of each class, (n_class, n_u, n_mu, 3) [-].
    diffuse_horizontal_classes: np.ndarray | None = None
    #: Ozone absorption coefficient (n_h, 3) [m-1] on the heights of ``beta_rayleigh`` (:mod:`swim.optics.ozone`):
    #: in ``sun_transmittance`` and the diffuse tables; a pure absorber (no scattering).
    beta_ozone: np.ndarray | None = None

    @property
    def ozone_extinction(self) -> np.ndarray:
        """``beta_ozone`` (n_h, 3) [m-1], zeros of ``beta_rayleigh``'s shape and type where there is none."""
        return np.zeros_like(self.beta_rayleigh) if self.beta_ozone is None else self.beta_ozone


def _slant_optical_depth(h, mu, heights, beta, top, radius, n_steps=400):
    """Optical depth [-] from height h [m] towards direction cosine mu to the top ``top`` [m] (inf where the earth
    blocks), by the midpoint rule over ``n_steps`` quadratically spaced steps of a spherical atmosphere.

    Parameters
    ----------
    h, mu : numpy.ndarray
        Shapes that broadcast to (...): start heights [m] (at most ``top``) and direction cosines [-].
    heights : numpy.ndarray
        Shape (n,): an equally spaced height grid [m], n >= 2.
    beta : numpy.ndarray
        Shape (n, C): extinction coefficients [m-1] on ``heights``, linearly interpolated between them (and held at
        the end values beyond them, as ``numpy.interp``).
    top : float
        Height of the top of the atmosphere [m].
    radius : float
        Radius of the earth [m].
    n_steps : int
        Midpoint steps per path [-].

    Returns
    -------
    numpy.ndarray
        Shape (..., C) [-].

    Raises
    ------
    ValueError
        If ``heights`` is not equally spaced, or ``h`` or ``mu`` is not finite.
    """
    heights, beta = np.asarray(heights, float), np.asarray(beta, float)
    dh = (heights[-1] - heights[0]) / (heights.size - 1)
    if not np.allclose(np.diff(heights), dh, rtol=1e-9, atol=0.0):
        raise ValueError("_slant_optical_depth needs an equally spaced height grid")
    h, mu = np.broadcast_arrays(np.asarray(h, float), np.asarray(mu, float))
    if not (np.all(np.isfinite(h)) and np.all(np.isfinite(mu))):
        raise ValueError("_slant_optical_depth needs finite start heights h [m] and direction cosines mu [-]")
    r0 = (radius + h).reshape(-1)
    mu_flat = mu.reshape(-1)
    rt = radius + top
    s_top = -r0 * mu_flat + np.sqrt(np.maximum(r0**2 * mu_flat**2 + rt**2 - r0**2, 0.0))
    # Quadratic spacing: dense near the start, where the air is densest for upward paths.
    u = (np.arange(n_steps) + 0.5) / n_steps
    tau = np.empty((r0.size, beta.shape[1]))
    # Blocks of start points bound the temporaries. The height grid is equally spaced, so a sample's cell is its
    # height over the spacing, found once for all channels (numpy.interp searched the grid for every sample and
    # channel), and each channel is gathered from its own contiguous column (docs/decisions/0008-cold-start.md).
    block = max(1, 262144 // n_steps)
    n_nodes = heights.size
    columns = np.ascontiguousarray(beta.T)
    for first in range(0, r0.size, block):
        rb, mb, sb = (a[first:first + block, None] for a in (r0, mu_flat, s_top))
        s = sb * u**2
        # height index f of each sample: (radius + height)^2 = r0^2 + s (s + 2 r0 mu)
        f = np.sqrt(rb**2 + s * (s + 2 * rb * mb))
        f -= radius + heights[0]
        f *= 1.0 / dh
        np.clip(f, 0.0, n_nodes - 1.0, out=f)
        i = np.minimum(f.astype(np.intp), n_nodes - 2)
        ds = sb * (2 * u / n_steps)
        w_hi = ds * (f - i)  # the step's length times the upper node's weight
        w_lo = ds - w_hi
        for c, b in enumerate(columns):
            tau[first:first + block, c] = np.sum(np.take(b, i) * w_lo + np.take(b, i + 1) * w_hi, axis=-1)
    tau = tau.reshape(h.shape + (beta.shape[1],))
    blocked = (mu < 0) & ((radius + h) ** 2 * (1 - mu**2) < radius**2)
    tau[blocked] = np.inf
    return tau


def phase_functions(cos_theta, depolarization, aerosol_type, stratospheric_type):
    """The clear air's phase functions [-] (mean 1 over the sphere) at scattering-angle cosines ``cos_theta`` (n,) [-]:
    Rayleigh (n,) (:func:`swim.optics.rayleigh.rayleigh_phase_function` with the air's ``depolarization`` [-]), and
    the background and stratospheric aerosol's (n, 3), each :class:`swim.optics.aerosol_types.AerosolType`'s two-term
    DHG (paper Eq. 28). In the array library of ``cos_theta`` (numpy on the host, JAX in the device's ray table,
    :mod:`swim.arrays`).

    References
    ----------
    Albers, S. C. et al. (2020): A fast visible-wavelength 3D radiative transfer procedure for NWP visualization and
    forward modeling, Atmos. Meas. Tech. 13, 3235-3261, doi:10.5194/amt-13-3235-2020.
    """
    return (rayleigh_phase_function(cos_theta, depolarization), aerosol_type.phase_function(cos_theta),
            stratospheric_type.phase_function(cos_theta))


def _surface_albedo3(surface_albedo):
    """(3,) tuple of albedos rounded to 0.005 (the cache key of the tables)."""
    a = np.broadcast_to(np.asarray(surface_albedo, dtype=float), (3,))
    if not np.all(np.isfinite(a)) or np.any(a < 0) or np.any(a > 1):
        raise SwimInputError(f"surface albedo for the clear-sky tables must be in [0, 1]; got {a}")
    return tuple(float(x) for x in np.round(a / 0.005) * 0.005)


def aerosol_column_classes(column_aod, fractions=(0.0, 0.125, 0.25, 0.5, 1.0)):
    """Classes of column aerosol optical depth for the multiple-scattering tables of a 3-D aerosol field.

    Parameters
    ----------
    column_aod : array_like
        Column optical depth at 550 nm of the scene's 3-D aerosol, any shape (usually (y, x)) [-], >= 0.
    fractions : sequence of float
        Class positions between the smallest and the largest column, 0 and 1 included (denser towards thin
        columns, where the diffuse source changes fastest with the optical depth).

    Returns
    -------
    tuple of float or None
        Increasing class optical depths rounded to 3 significant digits; None when the field is empty or so
        uniform (spread <= 5 % of the largest column + 0.005) that the mean column serves every ray.

    Raises
    ------
    SwimInputError
        Negative or non-finite column optical depths.

    References
    ----------
    Albers et al. (2020), Sect. 3.5.4, Eqs. 30-31 (absorbing aerosol layers; docs/aerosols.md, §8).
    """
    a = np.asarray(column_aod, dtype=float)
    if a.size == 0:
        return None
    if np.any(~np.isfinite(a)) or np.any(a < 0):
        raise SwimInputError("column aerosol optical depth of the 3-D aerosol field must be finite and >= 0 [-]")
    lo, hi = float(a.min()), float(a.max())
    if hi <= 0 or hi - lo <= 0.05 * hi + 0.005:
        return None
    values = sorted({float(f"{lo + (hi - lo) * f:.3g}") for f in fractions})
    return tuple(values)


def build_gas_tables(aerosol: AerosolBackground = AerosolBackground(), wavelengths_nm=WAVELENGTHS_NM,
                     dh=100.0, n_u=96, n_mu=512, radius=EARTH_RADIUS_M, surface_albedo=0.1,
                     scene_aerosol_profile=None, aerosol_class_aod=None) -> GasTables:
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
    surface_albedo : float or array_like
        Lambertian albedo of the ground (scalar or (3,), the scene mean) that reflects light back into the
        sky in the multiple-scattering solution [-], in [0, 1]; rounded to 0.005.
    scene_aerosol_profile : tuple of numpy.ndarray, optional
        (heights [m], extinction at 550 nm [m-1]) of the horizontal mean of the scene's 3-D aerosol field.
        It joins the background aerosol in the multiple-scattering solution only (the kernel has the 3-D
        field itself), so that the diffuse light of a hazy or smoky scene is that of its mean aerosol
        column. Rounded to 3 significant digits (the cache key).
    aerosol_class_aod : sequence of float, optional
        Column optical depths at 550 nm [-] of the classes of :func:`aerosol_column_classes`: one table per
        class, for ``scene_aerosol_profile`` scaled to that column (needs the profile). None: one table for
        the mean column.

    Returns
    -------
    GasTables

    Raises
    ------
    SwimInputError
        Albedo outside [0, 1].

    References
    ----------
    Albers et al. (2020), Eqs. 3 and 8; Bodhaine et al. (1999), doi:10.1175/1520-0426(1999)016<1854:ORODC>2.0.CO;2;
    US Standard Atmosphere (1976).
    """
    wl = tuple(float(w) for w in np.atleast_1d(wavelengths_nm))
    profile = _profile_key(scene_aerosol_profile)
    classes = None
    if aerosol_class_aod is not None:
        classes = tuple(float(f"{float(c):.3g}") for c in np.atleast_1d(aerosol_class_aod))
        if len(classes) < 2 or np.any(np.diff(classes) <= 0) or classes[0] < 0:
            raise SwimInputError("aerosol_class_aod must hold >= 2 increasing column optical depths >= 0; "
                                 f"got {classes}")
        if profile is None:
            raise SwimInputError("aerosol_class_aod needs scene_aerosol_profile (the 3-D field's mean profile)")
    return _build_gas_tables_cached(aerosol, wl, float(dh), int(n_u), int(n_mu), float(radius),
                                    _surface_albedo3(surface_albedo), profile, classes)


def _profile_key(profile):
    """Hashable, rounded (heights, extinction) of a mean aerosol profile; None when absent or all zero."""
    if profile is None:
        return None
    h, beta = (np.asarray(a, dtype=float).ravel() for a in profile)
    if h.shape != beta.shape or h.size < 2 or np.any(~np.isfinite(h)) or np.any(np.diff(h) <= 0):
        raise SwimInputError("scene_aerosol_profile must be (heights [m] increasing, extinction [m-1]) of equal length")
    if np.any(~np.isfinite(beta)) or np.any(beta < 0):
        raise SwimInputError("scene aerosol extinction profile must be finite and >= 0 [m-1]")
    if not np.any(beta > 0):
        return None
    return tuple(float(x) for x in np.round(h, 1)), tuple(float(f"{x:.3g}") for x in beta)


@functools.lru_cache(maxsize=8)
def _build_gas_tables_cached(*args) -> GasTables:
    """Cached worker of :func:`build_gas_tables`: in memory, and on disk across processes
    (:func:`swim.compilation.disk_cache.disk_cached`), because the successive-orders tables take seconds."""
    return disk_cached("gas", args, lambda: _build_gas_tables(*args), sources=package_sources())


def _build_gas_tables(aerosol, wavelengths_nm, dh, n_u, n_mu, radius, surface_albedo,
                      scene_profile=None, classes=None) -> GasTables:
    """Worker of :func:`build_gas_tables` (the tables depend only on these arguments)."""
    wl = np.asarray(wavelengths_nm, dtype=float)
    heights = np.arange(0.0, ATMOSPHERE_TOP_M + dh / 2, dh)
    _, _, number_density = us_standard_atmosphere_1976(heights)
    sigma = np.asarray(rayleigh_cross_section_bodhaine1999(wl))
    beta_r = number_density[:, None] * sigma[None, :]
    factor = np.asarray(aerosol.type.extinction_factor(wl), dtype=float)
    beta_a = (np.asarray(exponential_aerosol_extinction(heights, aerosol.aod_550, aerosol.scale_height_m))[:, None]
              * factor[None, :])
    beta_s = aerosol.stratospheric_extinction(heights, wl)
    beta_o = (ozone_absorption_coefficient(heights, wl, aerosol.ozone_du) if aerosol.ozone_du > 0
              else np.zeros_like(beta_r))
    beta = beta_r + beta_a + beta_s + beta_o

    u = np.linspace(0.0, 1.0, n_u)
    hu = ATMOSPHERE_TOP_M * u**2
    mu = np.linspace(-1.0, 1.0, n_mu)
    H, M = np.meshgrid(hu, mu, indexing="ij")
    tau = _slant_optical_depth(H, M, heights, beta, ATMOSPHERE_TOP_M, radius)
    transmittance = np.exp(-tau)

    # Multiple scattering: successive orders in the plane-parallel equivalent of this atmosphere, lit by the sun's
    # pseudo-spherical beam (down to the sun 24 deg below the horizon; swim.rt.multiple_scattering).
    depolarization = float(np.mean(rayleigh_depolarization_ratio(wl)))
    # The 3-D aerosol of the scene: its mean profile, or that profile scaled to each column class.
    profiles_3d, class_aod, column = [np.zeros_like(heights)], np.zeros(1), 0.0
    if scene_profile is not None:
        mean3d = np.interp(heights, scene_profile[0], scene_profile[1], left=0.0, right=0.0)
        column = float(np.trapezoid(mean3d, heights))
        if classes is None:
            profiles_3d, class_aod = [mean3d], np.array([column])
        else:
            profiles_3d = [mean3d * (c / column) for c in classes]
            class_aod = np.asarray(classes, dtype=float)
    sources = []
    for beta_3d in profiles_3d:
        beta_class = beta + beta_3d[:, None] * factor[None, :]

        def beam(h, mu_s, beta_class=beta_class):
            """The sun's transmittance (n_h, n_mu, C) through the spherical shell: the tables' pseudo-spherical beam."""
            hh, mm = np.meshgrid(np.minimum(h, ATMOSPHERE_TOP_M), mu_s, indexing="ij")
            return np.exp(-_slant_optical_depth(hh, mm, heights, beta_class, ATMOSPHERE_TOP_M, radius))

        sources.append(diffuse_source_table(
            heights, [beta_r, beta_a + beta_3d[:, None] * factor[None, :], beta_s],
            [np.ones(3), aerosol.ssa, np.asarray(aerosol.stratospheric.ssa, float)],
            [lambda c: rayleigh_phase_function(np.asarray(c, np.float32), depolarization),
             lambda c: aerosol.type.phase_function(np.asarray(c, np.float32)),
             lambda c: aerosol.stratospheric.phase_function(np.asarray(c, np.float32))],
            surface_albedo, ATMOSPHERE_TOP_M, absorption=beta_o, beam_transmittance=beam))
    # Their downward diffuse irradiance on the transmittance grid (bilinear in u and the tables' sun coordinate).
    fu = np.interp(u, sources[0].u, np.arange(sources[0].u.size))
    fs = np.interp(np.sign(mu) * np.sqrt(np.abs(mu)), sources[0].t_s, np.arange(sources[0].t_s.size))
    diffuse = np.stack([np.stack([_bilinear(src.diffuse_down[..., c], fu, fs) for c in range(3)], axis=-1)
                        for src in sources]).astype(np.float32)
    nearest = int(np.argmin(np.abs(class_aod - column)))

    return GasTables(
        dh=dh,
        beta_rayleigh=beta_r.astype(np.float32),
        beta_aerosol=beta_a.astype(np.float32),
        beta_stratospheric=beta_s.astype(np.float32),
        n_u=n_u,
        n_mu=n_mu,
        sun_transmittance=transmittance.astype(np.float32),
        diffuse_horizontal=diffuse[nearest],
        depolarization=depolarization,
        aerosol=aerosol,
        angstrom_factor=factor.astype(np.float32),
        diffuse_source=sources[nearest],
        surface_albedo=surface_albedo,
        aerosol_class_aod=class_aod,
        diffuse_sources=tuple(sources),
        diffuse_horizontal_classes=diffuse,
        beta_ozone=beta_o.astype(np.float32),
    )


def _bilinear(table, fu, fv):
    """table (n_u, n_v) at fractional indices fu (n,) x fv (m,) -> (n, m)."""
    u0 = np.clip(np.floor(fu).astype(int), 0, table.shape[0] - 2)
    v0 = np.clip(np.floor(fv).astype(int), 0, table.shape[1] - 2)
    a = (fu - u0)[:, None]
    b = (fv - v0)[None, :]
    return (table[u0][:, v0] * (1 - a) * (1 - b) + table[u0 + 1][:, v0] * a * (1 - b)
            + table[u0][:, v0 + 1] * (1 - a) * b + table[u0 + 1][:, v0 + 1] * a * b)
