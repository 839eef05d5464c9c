"""City lights: the artificial light sent up from towns, scattered once by the clear air into each line of sight (the
sky glow) and reflected down by the cloud bases it reaches, as spectral radiance in the renderer's three channels.

Sources. A town (or a block of the scene's emission field, :mod:`swim.surface.city_lights`) is a source of upward
luminous flux Phi [lm] at a point on the ground, spread over a radius a (the 1 / r^2 of the light it sends to a point
is softened to 1 / (r^2 + a^2)). Its intensity follows Garstang's (1986, Eq. 5) emission law, per unit upward flux

    f(psi) = [2 G (1 - F) cos psi + 0.554 F psi^4] / (2 pi [F + G (1 - F)])  [sr-1],

psi the zenith angle of the emission: the part F of the lamps' light sent straight up (peaking towards the horizon,
psi^4) and the part 1 - F sent down and reflected by the ground (reflectance G) as a Lambertian surface. The
integral of f over the upper hemisphere is 1 (0.554 int psi^4 sin psi dpsi = 1.000 over 0-pi/2).

Lamps. The luminous flux becomes spectral flux per channel through a lamp spectrum (:data:`LAMP_SPECTRA`: high
pressure sodium, the orange street lighting, or a 4000 K white LED): the channel's band-mean spectral power over its
band (:data:`swim.rt.night_sky.CHANNEL_BANDS_NM`) divided by the spectrum's luminous efficacy of radiation
683 lm W-1 int S V / int S (V the CIE 1931 photopic y-bar).

Clear air. Molecules (Rayleigh, Bodhaine et al. 1999, with their 3/4 (1 + cos^2) phase function) and the background
aerosol (its type's phase function and single-scattering albedo), both exponential in height (scale heights
:data:`MOLECULAR_SCALE_HEIGHT_M` and the aerosol's), on a spherical earth: the optical depth of a path between two
points is its length times the mean of the exponential between the end points' true heights. A point of a line of
sight gets from each source (behind the ground as seen from neither: the emission must leave the ground upwards)

    dL = f(psi) Phi_c T(source -> point) / (r^2 + a^2) [beta_m P_m(Theta) + omega_a beta_a P_a(Theta)] / (4 pi) ds,

attenuated by T(point -> observer) (Garstang 1986, Eq. 12, single scattering; Theta the scattering angle). Multiple
scattering (about 10-30 % more at these optical depths; Garstang 1986, Sect. 4) is left out.

Clouds lit from below. A cloud on a line of sight is lit by the upward irradiance E reaching where the line of sight
enters it (the same sources and clear-air transmittance, on a horizontal surface facing down; the clouds between the
towns and that point are not traced) and reflects it as a Lambertian surface of the conservative two-stream
(Eddington) plane albedo R = x / (1 + x), x = 3/4 (1 - g) tau (Bohren 1987), tau the column's cloud optical depth:
L = R E / pi, weighted by the line of sight's cloud opacity 1 - exp(-tau_los); a cloud seen from above shows the
light it transmits, (1 - R) E / pi. The clear air's glow behind the cloud is attenuated by exp(-tau_los(s)) step by
step.

References
----------
Garstang, R. H. (1986), Model for artificial night-sky illumination, PASP 98, 364-375, doi:10.1086/131768. Walker,
M. F. (1977), The effects of urban lighting on the brightness of the night sky, PASP 89, 405-409,
doi:10.1086/130142. Bodhaine, B. A. et al. (1999), J. Atmos. Oceanic Technol. 16, 1854-1861. Bohren, C. F. (1987),
Am. J. Phys. 55, 524-533, doi:10.1119/1.15109. CIE 015:2018, Colorimetry (the photopic y-bar). Elvidge, C. D. et al.
(2010), Spectral identification of lighting type and character, Sensors 10, 3961-3988, doi:10.3390/s100403961 (the
lamps' spectra).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..color._tables import SPECTRAL_GRID_NM, cie_1931_cmfs_on_grid
from ..constants import EARTH_RADIUS_M, WAVELENGTHS_NM
from ..errors import SwimInputError
from ..optics.rayleigh import rayleigh_optical_depth_bodhaine1999
from ..surface.city_lights import DIRECT_UPWARD_FRACTION, GROUND_REFLECTANCE
from .night_sky import CHANNEL_BANDS_NM

#: Maximum luminous efficacy of radiation [lm W-1] (CIE: 683 lm W-1 at 555 nm).
KM_LM_PER_W = 683.0
#: Scale height of the molecular (Rayleigh) extinction [m] (Garstang 1986, Sect. 2: an exponential atmosphere).
MOLECULAR_SCALE_HEIGHT_M = 8000.0
#: Asymmetry parameter of the cloud in the plane albedo (as swim.pipeline.night_sky.CLOUD_ASYMMETRY).
CLOUD_ASYMMETRY = 0.85
#: Cosines of the scattering angle on which the aerosol's phase function is tabulated and interpolated (linearly).
PHASE_GRID_COS = np.linspace(-1.0, 1.0, 4001)
#: Heights above which the clear air scatters nothing that counts [m].
TOP_OF_GLOW_M = 40_000.0

#: Lamp spectra as sums of Gaussian bands (centre [nm], standard deviation [nm], weight [-]): "sodium", high pressure
#: sodium (the pressure-broadened, self-reversed Na D wings at 570-615 nm and the weaker lines at 467, 498, 515 and
#: 569 nm; Elvidge et al. 2010, Fig. 3), orange, 390 lm W-1; "led", a 4000 K phosphor-converted white LED (the
#: 450 nm blue pump and the broad phosphor band peaking near 600 nm; Elvidge et al. 2010, Fig. 9), warm white,
#: 323 lm W-1.
LAMP_SPECTRA = {
    "sodium": ((568.8, 3.0, 0.10), (580.0, 5.0, 0.22), (597.0, 6.0, 0.33), (610.0, 9.0, 0.18), (630.0, 15.0, 0.06),
               (498.0, 2.0, 0.04), (515.0, 2.0, 0.03), (467.0, 2.0, 0.02), (650.0, 30.0, 0.02)),
    "led": ((450.0, 11.0, 0.40), (595.0, 62.0, 0.80)),
}
#: The lamp spectrum of a source that names none.
DEFAULT_LAMP = "sodium"



def lamp_spectrum(lamp: str, wavelengths_nm=SPECTRAL_GRID_NM) -> np.ndarray:
    """Relative spectral power [-] of a lamp of :data:`LAMP_SPECTRA` at ``wavelengths_nm`` (any shape).

    Raises
    ------
    SwimInputError
        If ``lamp`` is not one of :data:`LAMP_SPECTRA`.
    """
    if lamp not in LAMP_SPECTRA:
        raise SwimInputError(f"lamp spectrum {lamp!r} is not one of {sorted(LAMP_SPECTRA)}")
    wl = np.asarray(wavelengths_nm, dtype=float)
    return sum(w * np.exp(-0.5 * ((wl - c) / s) ** 2) for c, s, w in LAMP_SPECTRA[lamp])



@functools.lru_cache(maxsize=8)
def luminous_efficacy(lamp: str = DEFAULT_LAMP) -> float:
    """Luminous efficacy of radiation [lm W-1] of a lamp's spectrum over 380-780 nm: 683 int S ybar / int S."""
    s = lamp_spectrum(lamp)
    return float(KM_LM_PER_W * np.sum(s * cie_1931_cmfs_on_grid()[:, 1]) / np.sum(s))



@functools.lru_cache(maxsize=8)
def channel_flux_per_lumen(lamp: str = DEFAULT_LAMP) -> np.ndarray:
    """Spectral radiant flux per lumen [W nm-1 lm-1] (3,) at 615, 546, 450 nm: the lamp's band-mean spectral power
    over each channel's band (:data:`swim.rt.night_sky.CHANNEL_BANDS_NM`) per lumen of its light."""
    wl = np.arange(380.0, 780.01, 0.5)
    s = lamp_spectrum(lamp, wl)
    ybar = np.interp(wl, SPECTRAL_GRID_NM, cie_1931_cmfs_on_grid()[:, 1])
    watts_per_unit = 1.0 / (KM_LM_PER_W * np.sum(s * ybar) * 0.5)  # W per unit of s such that the light is 1 lm
    band = [np.sum(s[(wl >= lo) & (wl < hi)]) * 0.5 / (hi - lo) for lo, hi in CHANNEL_BANDS_NM]
    out = np.asarray(band) * watts_per_unit
    out.setflags(write=False)
    return out



def garstang_intensity(cos_psi, direct_fraction=DIRECT_UPWARD_FRACTION, ground_reflectance=GROUND_REFLECTANCE):
    """Garstang's (1986, Eq. 5) upward emission law per unit upward flux [sr-1] (module docstring), at the cosine of
    the emission's zenith angle ``cos_psi`` [-] (any shape); zero below the horizon (cos_psi <= 0)."""
    c = np.clip(np.asarray(cos_psi, dtype=float), -1.0, 1.0)
    psi = np.arccos(c)
    f, g = float(direct_fraction), float(ground_reflectance)
    law = (2.0 * g * (1.0 - f) * c + 0.554 * f * psi**4) / (2.0 * np.pi * (f + g * (1.0 - f)))
    return np.where(c > 0.0, law, 0.0)



#: Emission within this angle of the horizon [deg] is tapered off linearly in cos psi (buildings, trees and terrain
#: block the lamps' light there; without the taper the psi^4 term, largest at the horizon, would switch on and off
#: as a point crosses a source's horizon on the curved earth), and the law renormalised.
HORIZON_TAPER_DEG = 5.0



@functools.lru_cache(maxsize=16)
def _taper_norm(direct_fraction, ground_reflectance):
    psi = np.linspace(0.0, np.pi / 2, 20001)
    f = garstang_intensity(np.cos(psi), direct_fraction, ground_reflectance) * _taper(np.cos(psi))
    y = f * 2.0 * np.pi * np.sin(psi)
    return float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(psi)))



def _taper(cos_psi):
    return np.clip(cos_psi / np.sin(np.radians(HORIZON_TAPER_DEG)), 0.0, 1.0)



def emission_law(cos_psi, direct_fraction=DIRECT_UPWARD_FRACTION, ground_reflectance=GROUND_REFLECTANCE):
    """The sources' emission per unit upward flux [sr-1]: :func:`garstang_intensity` tapered to zero over the last
    :data:`HORIZON_TAPER_DEG` above the horizon and renormalised (its integral over the upper hemisphere is 1)."""
    return garstang_intensity(cos_psi, direct_fraction, ground_reflectance) * _taper(np.asarray(cos_psi, dtype=float)) \
        / _taper_norm(float(direct_fraction), float(ground_reflectance))



@dataclass(frozen=True)
class LightSources:
    """Upward light sources on the ground.

    Attributes
    ----------
    position : numpy.ndarray
        Shape (n, 3): where each source is, in an earth-centred Cartesian frame [m] (the scene frame).
    flux_lm : numpy.ndarray
        Shape (n,): the upward luminous flux of each source [lm] (the direct upward light plus the light reflected by
        the ground).
    radius_m : numpy.ndarray
        Shape (n,): the radius over which each source is spread [m] (> 0).
    lamp : str
        The lamps' spectrum (:data:`LAMP_SPECTRA`).
    direct_fraction, ground_reflectance : float
        Garstang's F and G [-].
    """

    position: np.ndarray
    flux_lm: np.ndarray
    radius_m: np.ndarray
    lamp: str = DEFAULT_LAMP
    direct_fraction: float = DIRECT_UPWARD_FRACTION
    ground_reflectance: float = GROUND_REFLECTANCE

    def __post_init__(self):
        pos = np.asarray(self.position, dtype=float).reshape(-1, 3)
        flux = np.asarray(self.flux_lm, dtype=float).reshape(-1)
        radius = np.broadcast_to(np.asarray(self.radius_m, dtype=float), flux.shape).copy()
        if pos.shape[0] != flux.size or not (np.all(np.isfinite(pos)) and np.all(np.isfinite(flux))):
            raise SwimInputError(f"light sources: position (n, 3) [m] and flux_lm (n,) [lm] must be finite and match; "
                                 f"got {pos.shape} and {flux.shape}")
        if np.any(flux < 0) or not np.all(radius > 0):
            raise SwimInputError("light sources: flux_lm [lm] must be >= 0 and radius_m [m] > 0")
        if not (0.0 <= self.direct_fraction <= 1.0 and 0.0 <= self.ground_reflectance <= 1.0
                and self.direct_fraction + self.ground_reflectance > 0.0):
            raise SwimInputError(f"light sources: direct_fraction F and ground_reflectance G must lie in [0, 1], not "
                                 f"both 0; got {self.direct_fraction}, {self.ground_reflectance}")
        lamp_spectrum(self.lamp, 550.0)  # raises for an unknown lamp
        object.__setattr__(self, "position", pos)
        object.__setattr__(self, "flux_lm", flux)
        object.__setattr__(self, "radius_m", radius)

    def spectral_flux(self) -> np.ndarray:
        """Upward spectral flux of each source (n, 3) [W nm-1] at 615, 546, 450 nm."""
        return self.flux_lm[:, None] * channel_flux_per_lumen(self.lamp)[None, :]



@dataclass(frozen=True)
class ClearAir:
    """The clear air's extinction, exponential in height: sea-level molecular ``beta_molecules`` (3,) [m-1] and aerosol
    ``beta_aerosol`` (3,) [m-1] extinction at 615, 546, 450 nm with their scale heights [m], the aerosol's
    single-scattering albedo ``ssa`` (3,) [-] and ``phase`` (a callable cos -> (..., 3), mean 1 over the sphere; None:
    Henyey-Greenstein with g = 0.7)."""

    beta_molecules: np.ndarray
    molecular_scale_height_m: float
    beta_aerosol: np.ndarray
    aerosol_scale_height_m: float
    ssa: np.ndarray = (0.95, 0.95, 0.95)
    phase: object = None

    def aerosol_phase(self, cos_theta) -> np.ndarray:
        """The aerosol's phase function (..., 3) [-] (mean 1 over the sphere)."""
        if self.phase is not None:
            return np.asarray(self.phase(cos_theta), dtype=float)
        g = 0.7
        p = (1.0 - g * g) / (1.0 + g * g - 2.0 * g * np.asarray(cos_theta)) ** 1.5
        return np.repeat(p[..., None], 3, axis=-1)



def clear_air(aod_550=0.05, aerosol_scale_height_m=1500.0, angstrom_exponent=1.3, ssa=(0.95, 0.95, 0.95),
              phase=None) -> ClearAir:
    """:class:`ClearAir` of the renderer's background: Rayleigh (Bodhaine et al. 1999, the sea-level optical depth
    over :data:`MOLECULAR_SCALE_HEIGHT_M`) and an exponential aerosol of AOD ``aod_550`` [-] at 550 nm, scale height
    [m] and Angstrom exponent [-].

    Raises
    ------
    SwimInputError
        A negative AOD or a non-positive scale height.
    """
    if not (np.isfinite(aod_550) and aod_550 >= 0 and np.isfinite(aerosol_scale_height_m)
            and aerosol_scale_height_m > 0):
        raise SwimInputError(f"aerosol optical depth at 550 nm must be >= 0 and its scale height > 0 m; got {aod_550}, "
                             f"{aerosol_scale_height_m}")
    tau_r = np.asarray(rayleigh_optical_depth_bodhaine1999(WAVELENGTHS_NM), dtype=float)
    tau_a = aod_550 * (WAVELENGTHS_NM / 550.0) ** -float(angstrom_exponent)
    return ClearAir(tau_r / MOLECULAR_SCALE_HEIGHT_M, MOLECULAR_SCALE_HEIGHT_M, tau_a / aerosol_scale_height_m,
                    float(aerosol_scale_height_m), np.asarray(ssa, dtype=float), phase)



def _mean_exp(h0, h1, scale):
    """Mean of exp(-h / scale) [-] over a path whose height runs linearly from h0 to h1 [m]."""
    dh = h1 - h0
    e0 = np.exp(-np.clip(h0, -2000.0, None) / scale)
    small = np.abs(dh) < 1e-3 * scale
    safe = np.where(small, 1.0, dh)
    return np.where(small, e0 * (1.0 - dh / (2.0 * scale)),
                    scale * (e0 - np.exp(-np.clip(h1, -2000.0, None) / scale)) / safe)



def _transmittance(air: ClearAir, h0, h1, length):
    """Clear-air transmittance (..., 3) [-] of paths of ``length`` [m] between heights h0 and h1 [m]."""
    tau = (length * _mean_exp(h0, h1, air.molecular_scale_height_m))[..., None] * air.beta_molecules \
        + (length * _mean_exp(h0, h1, air.aerosol_scale_height_m))[..., None] * air.beta_aerosol
    return np.exp(-tau)



def _source_geometry(points, sources: LightSources):
    """Per point (n) and source (m), each (n, m): the distance r [m], the vector from the source to the point
    (dx, dy, dz) [m], 1 / (r^2 + a^2) [m-2] and the intensity per unit upward flux f [sr-1]; and the points' (n,) and
    sources' (m,) heights [m]."""
    s_pos = sources.position
    dx, dy, dz = (points[:, k, None] - s_pos[None, :, k] for k in range(3))
    r2 = dx * dx + dy * dy + dz * dz
    r = np.sqrt(r2)
    s_norm = np.linalg.norm(s_pos, axis=1)
    s_up = s_pos / s_norm[:, None]
    cos_psi = (dx * s_up[:, 0] + dy * s_up[:, 1] + dz * s_up[:, 2]) / np.maximum(r, 1e-9)
    f = emission_law(cos_psi, sources.direct_fraction, sources.ground_reflectance)
    h_p = np.linalg.norm(points, axis=1) - EARTH_RADIUS_M
    return r, (dx, dy, dz), 1.0 / (r2 + sources.radius_m[None, :] ** 2), f, h_p, s_norm - EARTH_RADIUS_M



def _cosines(vector, r, directions):
    """Cosine (n, m) between the vectors (dx, dy, dz) (each (n, m)) of length r and unit ``directions`` (n, 3)."""
    dx, dy, dz = vector
    return (dx * directions[:, 0, None] + dy * directions[:, 1, None] + dz * directions[:, 2, None]) \
        / np.maximum(r, 1e-9)



def _tabulated(table, cos_theta):
    """``table`` (g,) on :data:`PHASE_GRID_COS` interpolated linearly at ``cos_theta`` (any shape)."""
    x = (np.clip(cos_theta, -1.0, 1.0) + 1.0) * (0.5 * (PHASE_GRID_COS.size - 1))
    i = np.minimum(x.astype(np.int64), PHASE_GRID_COS.size - 2)
    w = x - i
    return table[i] * (1.0 - w) + table[i + 1] * w



def _channel_sums(weights, r, h_p, h_s, air: ClearAir, flux):
    """For each of ``weights`` (each (n, m)): the sum over sources of weight x T_c(source -> point) x flux (m, c),
    (n, 3), T_c the clear air's transmittance of the paths of length r (n, m) from heights h_s (m,) to h_p (n,)."""
    mol = r * _mean_exp(h_s[None, :], h_p[:, None], air.molecular_scale_height_m)
    aer = r * _mean_exp(h_s[None, :], h_p[:, None], air.aerosol_scale_height_m)
    out = [np.empty((r.shape[0], 3)) for _ in weights]
    for c in range(3):
        t = np.exp(-(mol * air.beta_molecules[c] + aer * air.beta_aerosol[c])) * flux[None, :, c]
        for o, w in zip(out, weights):
            o[:, c] = np.sum(w * t, axis=1)
    return out



def upward_irradiance(points, sources: LightSources, air: ClearAir, chunk: int = 2048) -> np.ndarray:
    """Spectral irradiance [W m-2 nm-1] (n, 3) of the city light on a horizontal surface facing down at ``points``
    (n, 3) (earth-centred [m]): sum over sources of f(psi) Phi T cos(incidence) / (r^2 + a^2)."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    out = np.zeros((points.shape[0], 3))
    if sources.flux_lm.size == 0:
        return out
    flux = sources.spectral_flux()
    for i0 in range(0, points.shape[0], chunk):
        p = points[i0:i0 + chunk]
        r, vector, inv_r2, f, h_p, h_s = _source_geometry(p, sources)
        cos_inc = np.clip(_cosines(vector, r, p / np.linalg.norm(p, axis=1, keepdims=True)), 0.0, None)
        out[i0:i0 + chunk] = _channel_sums((f * inv_r2 * cos_inc,), r, h_p, h_s, air, flux)[0]
    return out



def scattered_radiance(points, view_dirs, sources: LightSources, air: ClearAir, chunk: int = 2048) -> np.ndarray:
    """Single-scattered city light [W m-2 sr-1 nm-1 per m of path] (n, 3) at ``points`` (n, 3) towards observers
    looking along ``view_dirs`` (n, 3) (unit, from the observer to the point): the path radiance's source term
    sum over sources of f Phi T(source -> point) / (r^2 + a^2) [beta_m P_m + omega beta_a P_a] / (4 pi).

    The aerosol's phase function is tabulated on :data:`PHASE_GRID_COS` and interpolated linearly, at 546 nm for all
    three channels (its asymmetry changes little across the visible).
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    view_dirs = np.asarray(view_dirs, dtype=float).reshape(-1, 3)
    out = np.zeros((points.shape[0], 3))
    if sources.flux_lm.size == 0:
        return out
    flux = sources.spectral_flux()
    phase_table = air.aerosol_phase(PHASE_GRID_COS)[:, 1]
    for i0 in range(0, points.shape[0], chunk):
        p, d = points[i0:i0 + chunk], view_dirs[i0:i0 + chunk]
        r, vector, inv_r2, f, h_p, h_s = _source_geometry(p, sources)
        cos_theta = -_cosines(vector, r, d)  # incident propagation . scattered propagation (towards -d)
        weight = f * inv_r2 / (4.0 * np.pi)
        molecules, aerosol = _channel_sums((weight * (0.75 * (1.0 + cos_theta**2)),
                                            weight * _tabulated(phase_table, cos_theta)), r, h_p, h_s, air, flux)
        out[i0:i0 + chunk] = (molecules * np.exp(-h_p / air.molecular_scale_height_m)[:, None] * air.beta_molecules
                              + aerosol * np.exp(-h_p / air.aerosol_scale_height_m)[:, None] * air.beta_aerosol
                              * air.ssa)
    return out



def path_distances(n_steps: int = 48, first_m: float = 20.0, last_m: float = 150_000.0):
    """Distances along a line of sight [m]: ``n_steps`` midpoints (n,) and lengths (n,) of steps growing
    geometrically from ``first_m`` to ``last_m`` (the path's end)."""
    edges = np.concatenate([[0.0], np.geomspace(first_m, last_m, int(n_steps))])
    return 0.5 * (edges[1:] + edges[:-1]), np.diff(edges)



def line_of_sight_steps(origin, directions, sources: LightSources, air: ClearAir, distances=None,
                        ground_height_m: float = 0.0) -> np.ndarray:
    """Each step's contribution to the sky glow [W m-2 sr-1 nm-1] (n, k, 3) along lines of sight from ``origin``
    (3,) (earth-centred [m]) along unit ``directions`` (n, 3), the clear air's transmittance back to the observer
    included; zero beyond where the line of sight meets the ground (``ground_height_m`` [m above sea level]) or above
    :data:`TOP_OF_GLOW_M`. ``distances``: (midpoints, lengths) [m] (:func:`path_distances` by default)."""
    mid, ds = path_distances() if distances is None else (np.asarray(distances[0]), np.asarray(distances[1]))
    o = np.asarray(origin, dtype=float).reshape(3)
    d = np.asarray(directions, dtype=float).reshape(-1, 3)
    pts = o[None, None, :] + d[:, None, :] * mid[None, :, None]
    h = np.linalg.norm(pts, axis=-1) - EARTH_RADIUS_M  # (n, k)
    blocked = np.logical_or.accumulate(h < ground_height_m - 1.0, axis=1)
    live = ~blocked & (h < TOP_OF_GLOW_M)
    # the clear air's optical depth back to the observer: the steps' extinction summed (trapezoid-like, midpoints)
    ext = (np.exp(-h / air.molecular_scale_height_m)[..., None] * air.beta_molecules
           + np.exp(-np.clip(h, -2000.0, None) / air.aerosol_scale_height_m)[..., None] * air.beta_aerosol)
    tau = np.cumsum(ext * ds[None, :, None], axis=1) - 0.5 * ext * ds[None, :, None]
    out = np.zeros(h.shape + (3,))
    idx = np.nonzero(live)
    if idx[0].size:
        src = scattered_radiance(pts[idx], d[idx[0]], sources, air)
        out[idx] = src * np.exp(-tau[idx]) * ds[idx[1], None]
    return out



def cloud_plane_albedo(tau) -> np.ndarray:
    """Plane albedo [-] of a conservatively scattering cloud of optical depth ``tau`` [-] lit diffusely, in the
    Eddington two-stream approximation: x / (1 + x), x = 3/4 (1 - g) tau, g = :data:`CLOUD_ASYMMETRY` (Bohren 1987;
    0.85 at tau = 50)."""
    x = 0.75 * (1.0 - CLOUD_ASYMMETRY) * np.maximum(np.asarray(tau, dtype=float), 0.0)
    return x / (1.0 + x)



def sky_glow(origin, directions, sources: LightSources, air: ClearAir, distances=None, ground_height_m=0.0):
    """The city lights' sky glow [W m-2 sr-1 nm-1] (n, 3) along clear lines of sight from ``origin`` (3,) along
    ``directions`` (n, 3): :func:`line_of_sight_steps` summed."""
    return line_of_sight_steps(origin, directions, sources, air, distances, ground_height_m).sum(axis=1)



def sources_from_emission(lat, lon, terrain_height, emission, lat0, lon0, max_sources: int = 128,
                          lamp: str = DEFAULT_LAMP, cell_area=None) -> LightSources:
    """The emission field (y, x) [lm m-2] on a grid of columns ``lat``, ``lon`` [deg] (terrain [m]) as at most
    ``max_sources`` :class:`LightSources` in the scene frame of (``lat0``, ``lon0``): the grid coarse-grained into
    blocks of b x b columns (the smallest b that leaves at most ``max_sources`` lit blocks), each block a source at
    its emission-weighted centre with the block's flux [lm] and a radius of half the block's width. ``cell_area``
    (y, x) [m2]: default :func:`swim.surface.city_lights.cell_areas`."""
    from ..frames import geodetic_to_scene
    from ..surface.city_lights import cell_areas, check_emission

    m = check_emission(emission)
    area = cell_areas(lat, lon) if cell_area is None else np.asarray(cell_area, dtype=float)
    flux = m * area
    lat, lon = np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)
    pos = geodetic_to_scene(lat, lon, np.asarray(terrain_height, dtype=float), lat0, lon0)
    ny, nx = flux.shape
    b = 1
    while True:
        by, bx = -(-ny // b), -(-nx // b)
        pad = ((0, by * b - ny), (0, bx * b - nx))
        blocks = np.pad(flux, pad).reshape(by, b, bx, b).sum(axis=(1, 3))
        if np.count_nonzero(blocks > 0) <= max_sources or b >= max(ny, nx):
            break
        b += 1
    lit = blocks > 0
    if not lit.any():
        return LightSources(np.zeros((0, 3)), np.zeros(0), np.zeros(0), lamp)
    weighted = np.stack([np.pad(flux * pos[..., k], pad).reshape(by, b, bx, b).sum(axis=(1, 3)) for k in range(3)],
                        axis=-1)
    centre = weighted[lit] / blocks[lit][:, None]
    width = np.sqrt(np.pad(area, pad).reshape(by, b, bx, b).sum(axis=(1, 3))[lit])
    return LightSources(centre, blocks[lit], 0.5 * np.maximum(width, 1.0), lamp)



def _grid_coordinates(points, attrs):
    """Fractional (level, row, column) coordinates (n,) each of ``points`` (n, 3) (scene frame [m]) in an optical
    volume with ``attrs`` (``z_bottom``, ``dz`` and the grid's map): by the affine fit of the columns where it holds
    to a tenth of a cell (``affine_origin``, ``affine_matrix``, ``affine_max_residual_m``), else by the cubic index
    map (:func:`swim.optics.volume.grid_indices`)."""
    from ..optics.volume import grid_indices

    p = np.asarray(points, dtype=float).reshape(-1, 3)
    norm = np.linalg.norm(p, axis=1)
    x, y = EARTH_RADIUS_M * p[:, 0] / norm, EARTH_RADIUS_M * p[:, 1] / norm
    k = (norm - EARTH_RADIUS_M - float(attrs["z_bottom"])) / float(attrs["dz"])
    matrix = attrs.get("affine_matrix")
    if matrix is not None:
        matrix = np.asarray(matrix, dtype=float).reshape(2, 2)
        spacing = float(np.sqrt(abs(np.linalg.det(matrix))))
        if float(attrs.get("affine_max_residual_m", np.inf)) <= 0.1 * spacing:
            origin = np.asarray(attrs["affine_origin"], dtype=float)
            i, j = np.linalg.inv(matrix) @ np.stack([x - origin[0], y - origin[1]])
            return k, j, i
    i, j = grid_indices(attrs, x, y)
    return k, np.asarray(j, dtype=float), np.asarray(i, dtype=float)



def _interpolated(field, coords) -> np.ndarray:
    """Multilinear interpolation of ``field`` (one axis per coordinate) at fractional ``coords`` (each (n,));
    zero outside the field's cells."""
    coords = [np.nan_to_num(np.asarray(c, dtype=float), nan=-2.0) for c in coords]
    inside = np.ones(coords[0].shape, dtype=bool)
    for c, size in zip(coords, field.shape):
        inside &= (c >= -0.5) & (c <= size - 0.5)
    out = np.zeros(coords[0].shape)
    where = np.flatnonzero(inside)
    if where.size == 0:
        return out
    lows, weights = [], []
    for c, size in zip(coords, field.shape):
        c = np.clip(c[where], 0.0, size - 1.0)
        lo = np.minimum(c.astype(np.int64), max(size - 2, 0))
        lows.append(lo)
        weights.append(c - lo if size > 1 else np.zeros_like(c))
    strides = np.cumprod((1,) + field.shape[::-1][:-1])[::-1]
    flat = np.ascontiguousarray(field).reshape(-1)
    base = sum(lo * st for lo, st in zip(lows, strides))
    value = np.zeros(where.size)
    for corner in range(1 << field.ndim):
        offset, w = 0, 1.0
        for axis in range(field.ndim):
            up = (corner >> axis) & 1 and field.shape[axis] > 1
            offset += int(up) * int(strides[axis])
            w = w * (weights[axis] if up else 1.0 - weights[axis])
        value += w * flat[base + offset]
    out[where] = value
    return out



def cloud_extinction_at(points, extinction, attrs, levels=None) -> np.ndarray:
    """Cloud extinction [m-1] (n,) at ``points`` (n, 3) (scene frame [m]), interpolated (trilinear) in
    ``extinction`` (level, y, x) [m-1] of an optical volume (attributes ``z_bottom``, ``dz`` and the grid's map,
    :func:`_grid_coordinates`); zero outside the grid and outside ``levels`` (lowest, highest level index with cloud;
    default all), whose points are not mapped onto the grid."""
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    lo, hi = (0, extinction.shape[0] - 1) if levels is None else levels
    k = (np.linalg.norm(p, axis=1) - EARTH_RADIUS_M - float(attrs["z_bottom"])) / float(attrs["dz"])
    near = np.flatnonzero((k > lo - 1.0) & (k < hi + 1.0))
    out = np.zeros(p.shape[0])
    if near.size:
        out[near] = _interpolated(extinction, _grid_coordinates(p[near], attrs))
    return out



#: The glow table's elevations [deg]: dense near the horizon, where the glow of distant towns changes fastest; those
#: below it matter to cameras above the ground (a ground camera's lines of sight there end at once and cost nothing).
TABLE_ELEVATIONS_DEG = np.array([-90.0, -60.0, -35.0, -20.0, -12.0, -7.0, -4.0, -2.0, -1.0, 0.0, 0.5, 1.0, 2.0, 3.0,
                                 4.5, 6.0, 8.0, 10.0, 13.0, 16.0, 20.0, 25.0, 30.0, 36.0, 43.0, 51.0, 60.0, 70.0, 80.0,
                                 90.0])
#: The glow table's azimuth step [deg].
TABLE_AZIMUTH_STEP_DEG = 5.0



def glow_table(origin, enu_to_frame, sources: LightSources, air: ClearAir, distances=None, ground_height_m=0.0):
    """Each step's sky glow [W m-2 sr-1 nm-1] (n_az, n_el, k, 3) on a table of view azimuths (every
    :data:`TABLE_AZIMUTH_STEP_DEG`, from 0) and elevations (:data:`TABLE_ELEVATIONS_DEG`) of an observer at
    ``origin`` (3,) [m], ``enu_to_frame`` (3, 3) turning its ENU vectors into the frame's (row vectors:
    ``v_frame = v_enu @ enu_to_frame``); :func:`line_of_sight_steps`."""
    az = np.radians(np.arange(0.0, 360.0, TABLE_AZIMUTH_STEP_DEG))
    el = np.radians(TABLE_ELEVATIONS_DEG)
    a, e = np.meshgrid(az, el, indexing="ij")
    enu = np.stack([np.cos(e) * np.sin(a), np.cos(e) * np.cos(a), np.sin(e)], axis=-1).reshape(-1, 3)
    steps = line_of_sight_steps(origin, enu @ np.asarray(enu_to_frame, dtype=float), sources, air, distances,
                                ground_height_m)
    return steps.reshape(a.shape + steps.shape[1:])



def interpolate_table(table, azimuth_deg, elevation_deg) -> np.ndarray:
    """Bilinear interpolation of a :func:`glow_table` (n_az, n_el, ...) at view azimuths and elevations [deg] (n,)
    (periodic in azimuth; elevations clamped to the table's): (n, ...)."""
    n_az = table.shape[0]
    fa = np.mod(np.asarray(azimuth_deg, dtype=float), 360.0) / TABLE_AZIMUTH_STEP_DEG
    a0 = np.floor(fa).astype(np.int64) % n_az
    wa = fa - np.floor(fa)
    el = np.clip(np.asarray(elevation_deg, dtype=float), TABLE_ELEVATIONS_DEG[0], TABLE_ELEVATIONS_DEG[-1])
    e0 = np.clip(np.searchsorted(TABLE_ELEVATIONS_DEG, el, side="right") - 1, 0, TABLE_ELEVATIONS_DEG.size - 2)
    we = (el - TABLE_ELEVATIONS_DEG[e0]) / (TABLE_ELEVATIONS_DEG[e0 + 1] - TABLE_ELEVATIONS_DEG[e0])
    a1 = (a0 + 1) % n_az
    shape = (-1,) + (1,) * (table.ndim - 2)
    wa, we = wa.reshape(shape), we.reshape(shape)
    return ((1 - wa) * (1 - we) * table[a0, e0] + wa * (1 - we) * table[a1, e0]
            + (1 - wa) * we * table[a0, e0 + 1] + wa * we * table[a1, e0 + 1])



#: Hydrometeor optical depth of a line of sight [-] above which its pixel is treated as cloudy (its glow attenuated
#: step by step and its cloud base lit).
CLOUDY_TAU = 0.01



@dataclass(frozen=True)
class CloudVolume:
    """The clouds of an optical volume: total hydrometeor ``extinction`` (level, y, x) [m-1] and the volume's
    ``attrs`` (``z_bottom``, ``dz`` [m] and the grid's index map)."""

    extinction: np.ndarray
    attrs: dict

    @property
    def levels(self):
        """(lowest, highest) level index [-] with any cloud, (0, -1) where there is none; computed once."""
        cached = self.__dict__.get("_levels")
        if cached is None:
            cloudy = np.flatnonzero(np.any(self.extinction > 0, axis=(1, 2)))
            cached = (int(cloudy[0]), int(cloudy[-1])) if cloudy.size else (0, -1)
            object.__setattr__(self, "_levels", cached)
        return cached



#: Sub-steps per step of a cloudy line of sight where it is near cloud (the cloud's extinction sampled finer than the
#: glow's steps, so that the attenuation and the cloud's entry follow the cloud base smoothly).
CLOUD_SUBSTEPS = 8
#: Optical depth from the observer [-] beyond which a step is not sub-sampled (exp(-5) = 0.7 % of the glow left).
DEEP_CLOUD_TAU = 5.0



def _cloud_steps(origin, dirs, cloud: CloudVolume, distances):
    """Cloud optical depth along lines of sight (c, 3): each step's sub-steps' optical depth (c, k, s) [-] and
    extinction (c, k, s) [m-1]: the steps' midpoints' extinction, sampled at :data:`CLOUD_SUBSTEPS` sub-steps instead
    in the steps where a cloud starts (and the steps before them) and where the line of sight enters the cloud
    (:func:`_lit_cloud`), where they are longer than a level and start less than :data:`DEEP_CLOUD_TAU` into it."""
    mid, ds = distances
    ext = np.zeros((dirs.shape[0], mid.size))
    cum = np.zeros(dirs.shape[0])
    alive = np.arange(dirs.shape[0])
    top = float(cloud.attrs["z_bottom"]) + float(cloud.attrs["dz"]) * (cloud.levels[1] + 1)
    for k in range(mid.size):  # step by step, each line of sight until it is opaque or above the clouds for good
        p = origin[None, :] + dirs[alive] * mid[k]
        ext[alive, k] = e = cloud_extinction_at(p, cloud.extinction, cloud.attrs, cloud.levels)
        cum[alive] += e * ds[k]
        norm = np.linalg.norm(p, axis=1)
        rising = np.einsum("ij,ij->i", p, dirs[alive]) > 0.0
        alive = alive[(cum[alive] < 2.0 * DEEP_CLOUD_TAU) & ~(rising & (norm - EARTH_RADIUS_M > top))]
        if alive.size == 0:
            break
    # refined: the steps where a cloud starts and those before them, and where the optical depth from the observer
    # reaches the cloud's entry (min(1, tau / 2)); not deep inside the cloud, nor steps shorter than a level
    cloudy = ext > 0
    near = cloudy.copy()
    near[:, 1:] &= ~cloudy[:, :-1]
    near[:, :-1] |= near[:, 1:]
    cum_end = np.cumsum(ext * ds[None, :], axis=1)
    threshold = np.minimum(1.0, 0.5 * cum_end[:, -1:])
    near |= (cum_end >= threshold) & (cum_end - ext * ds[None, :] < threshold)
    near &= (cum_end - ext * ds[None, :] < DEEP_CLOUD_TAU) & (ds[None, :] > float(cloud.attrs["dz"]))
    ext_sub = np.repeat(ext[..., None], CLOUD_SUBSTEPS, axis=2)
    ci, ki = np.nonzero(near)
    if ci.size:
        frac = (np.arange(CLOUD_SUBSTEPS) + 0.5) / CLOUD_SUBSTEPS
        s_sub = (mid[ki] - 0.5 * ds[ki])[:, None] + frac[None, :] * ds[ki][:, None]
        p_sub = origin[None, None, :] + dirs[ci][:, None, :] * s_sub[..., None]
        ext_sub[ci, ki] = cloud_extinction_at(p_sub.reshape(-1, 3), cloud.extinction, cloud.attrs,
                                              cloud.levels).reshape(s_sub.shape)
    return ext_sub * (ds / CLOUD_SUBSTEPS)[None, :, None], ext_sub



def _lit_cloud(origin, dirs, steps, sources, air, cloud: CloudVolume, distances, tau_los=None):
    """Glow (c, 3) behind-cloud-attenuated and the lit cloud base's radiance (c, 3) [W m-2 sr-1 nm-1] of cloudy
    lines of sight along ``dirs`` (c, 3), whose steps' clear glow is ``steps`` (c, k, 3); ``tau_los`` (c,): their
    hydrometeor optical depth [-] (the march's, finer than these steps far away; default: these steps')."""
    mid, ds = distances
    dtau, ext_sub = _cloud_steps(origin, dirs, cloud, distances)
    n, k, m = dtau.shape
    cum_end = np.cumsum(dtau.reshape(n, -1), axis=1)  # optical depth from the observer to each sub-step's end
    glow = np.einsum("ckq,ck->cq", steps, np.exp(-(cum_end.reshape(n, k, m) - 0.5 * dtau)).mean(axis=2))
    total = cum_end[:, -1] if tau_los is None else np.asarray(tau_los, dtype=float)
    found = (total > CLOUDY_TAU) & (cum_end[:, -1] > 0.0)
    base = np.zeros_like(glow)
    if found.any():
        c = np.flatnonzero(found)
        # where the optical depth from the observer reaches min(1, tau_los / 2), linear within the sub-step (the
        # last sub-step with cloud where the steps' optical depth stays below it)
        threshold = np.minimum(np.minimum(1.0, 0.5 * total[c]), cum_end[c, -1])
        j = np.argmax(cum_end[c] >= threshold[:, None], axis=1)
        step, sub = j // m, j % m
        ext_j = ext_sub.reshape(n, -1)[c, j]
        before = cum_end[c, j] - dtau.reshape(n, -1)[c, j]
        s_e = mid[step] - 0.5 * ds[step] + sub * ds[step] / m + (threshold - before) / np.maximum(ext_j, 1e-12)
        entry = origin[None, :] + dirs[c] * s_e[:, None]
        column = cloud.extinction.sum(axis=0) * float(cloud.attrs["dz"])
        column_tau = _interpolated(column, _grid_coordinates(entry, cloud.attrs)[1:])
        h_o = float(np.linalg.norm(origin)) - EARTH_RADIUS_M
        h_e = np.linalg.norm(entry, axis=1) - EARTH_RADIUS_M
        t = _transmittance(air, np.full(c.size, h_o), h_e, s_e)
        e_up = upward_irradiance(entry, sources, air)
        albedo = cloud_plane_albedo(column_tau)
        # seen from above (the line of sight descends into the cloud): the top shows the light the cloud transmits
        from_above = np.einsum("ck,ck->c", dirs[c], entry / np.linalg.norm(entry, axis=1, keepdims=True)) < 0.0
        albedo = np.where(from_above, 1.0 - albedo, albedo)[:, None]
        base[c] = albedo * e_up / np.pi * t * (1.0 - np.exp(-total[c]))[:, None]
    return glow, base



def city_lights_image(origin, enu_to_frame, azimuth_deg, zenith_deg, dirs_frame, tau_hydrometeor,
                      sources: LightSources, air: ClearAir, cloud: CloudVolume | None = None, ground_height_m=0.0,
                      n_steps: int = 48, chunk: int = 4096):
    """The city lights seen by a camera: spectral radiance [W m-2 sr-1 nm-1] (3, ny, nx), the sky glow plus the
    cloud bases lit from below, and the number of cloudy pixels.

    Parameters
    ----------
    origin : array_like
        Shape (3,): the observer in the scene frame [m].
    enu_to_frame : array_like
        Shape (3, 3): the observer's ENU axes in the scene frame (``v_frame = v_enu @ enu_to_frame``).
    azimuth_deg, zenith_deg : array_like
        Shape (ny, nx): each pixel's view azimuth and zenith angle [deg] (NaN outside the field of view).
    dirs_frame : array_like
        Shape (ny * nx, 3): each pixel's unit view direction in the scene frame.
    tau_hydrometeor : array_like
        Shape (ny, nx): the hydrometeor optical depth of each line of sight [-] (the march's).
    sources, air : LightSources, ClearAir
    cloud : CloudVolume, optional
        Where the cloudy lines of sight meet cloud; None: every line of sight clear.
    ground_height_m : float
        The ground's height under the observer [m above sea level] (the lines of sight end below it).
    n_steps : int
        Steps along each line of sight (:func:`path_distances`).
    """
    az = np.asarray(azimuth_deg, dtype=float)
    shape = az.shape
    el = 90.0 - np.asarray(zenith_deg, dtype=float)
    seen = np.isfinite(az) & np.isfinite(el)
    out = np.zeros((3,) + shape)
    if sources.flux_lm.size == 0 or not seen.any():
        return out, 0
    origin = np.asarray(origin, dtype=float).reshape(3)
    distances = path_distances(n_steps)
    table = glow_table(origin, enu_to_frame, sources, air, distances, ground_height_m)
    tau_h = np.nan_to_num(np.asarray(tau_hydrometeor, dtype=float).reshape(shape), nan=0.0)
    cloudy = seen & (tau_h > CLOUDY_TAU) if cloud is not None else np.zeros(shape, dtype=bool)
    clear = seen & ~cloudy
    out[:, clear] = interpolate_table(table.sum(axis=2), az[clear], el[clear]).T
    flat = np.flatnonzero(cloudy.reshape(-1))
    dirs = np.asarray(dirs_frame, dtype=float).reshape(-1, 3)
    view = out.reshape(3, -1)
    for i0 in range(0, flat.size, chunk):
        pix = flat[i0:i0 + chunk]
        steps = interpolate_table(table, az.reshape(-1)[pix], el.reshape(-1)[pix])
        glow, base = _lit_cloud(origin, dirs[pix], steps, sources, air, cloud, distances, tau_h.reshape(-1)[pix])
        view[:, pix] = (glow + base).T
    return out, int(flat.size)



def luminance(radiance) -> np.ndarray:
    """Luminance [cd m-2] (...) of a spectral radiance (3, ...) [W m-2 sr-1 nm-1] given as band means over the
    channels' bands (:data:`swim.rt.night_sky.CHANNEL_BANDS_NM`): 683 sum_c L_c int_band ybar dlambda."""
    wl = np.arange(380.0, 780.01, 0.5)
    ybar = np.interp(wl, SPECTRAL_GRID_NM, cie_1931_cmfs_on_grid()[:, 1])
    weights = np.array([KM_LM_PER_W * np.sum(ybar[(wl >= lo) & (wl < hi)]) * 0.5 for lo, hi in CHANNEL_BANDS_NM])
    radiance = np.asarray(radiance, dtype=float)
    return np.tensordot(weights, radiance, axes=(0, 0))
