"""Phase functions of the hydrometeors for the 3-D cloud scattering (``cloud_scattering="discrete_ordinates"``).

Each species gets a phase function P(theta) at 615, 546 and 450 nm, normalised to a mean of 1 over the sphere
(the paper's convention, Eq. 3), tabulated on one grid of scattering angles that resolves diffraction peaks of
~0.1 deg (:func:`angles_deg`):

* ``"mie"``: liquid droplets with a gamma size distribution (effective variance 0.1) from Mie theory, tabulated by
  effective radius 2-40 um (``swim/data/mie_liquid_phase.npz``, made by ``scripts/make_mie_tables.py`` with
  ``miepython``; water's refractive index from Hale and Querry 1973). Rain takes the largest droplets' table:
  outside its diffraction peak the phase function of large drops hardly depends on their size, and the peak of
  millimetre drops (~0.01 deg) is far narrower than any pixel.
* ``"roughened_aggregate"``: ice (and snow, graupel): half of the extinction is diffraction (extinction
  efficiency 2) into an Airy peak of the particles' projected size, the other half a featureless two-term
  Henyey-Greenstein function (g 0.55 forward with 5 % of g -0.3 back: g = 0.5), so that the whole has g = 0.75,
  the asymmetry parameter of the severely roughened aggregates of Yang et al. (2013), whose phase functions have
  no halos and a smooth side-scattering plateau. A documented fit, not their table (which is not available here):
  docs/decisions/0001-cloud-diffuse-solution.md.
* ``("hg", g)``: Henyey-Greenstein with asymmetry g (the I3RC convention for intercomparisons).

:func:`cloud_optics` gathers the species' functions (``"physical"``: Mie liquid and rain, the roughened aggregate
for ice, snow and graupel), their Legendre moments and the delta-M truncation (Wiscombe 1977) that the diffuse
solution and the march share.

References
----------
Hansen, J. E. and Travis, L. D. (1974): Light scattering in planetary atmospheres, Space Sci. Rev. 16, 527-610,
doi:10.1007/BF00168069 (the gamma size distribution).
Hale, G. M. and Querry, M. R. (1973): Optical constants of water in the 200-nm to 200-um wavelength region, Appl.
Opt. 12, 555-563, doi:10.1364/AO.12.000555.
Yang, P. et al. (2013): Spectrally consistent scattering, absorption, and polarization properties of atmospheric
ice crystals at wavelengths from 0.2 to 100 um, J. Atmos. Sci. 70, 330-347, doi:10.1175/JAS-D-12-039.1.
Wiscombe, W. J. (1977): The delta-M method, J. Atmos. Sci. 34, 1408-1422,
doi:10.1175/1520-0469(1977)034<1408:TDMRYA>2.0.CO;2.
Henyey, L. G. and Greenstein, J. L. (1941): Diffuse radiation in the galaxy, Astrophys. J. 93, 70-83,
doi:10.1086/144246.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from importlib import resources

import numpy as np
from scipy.special import j1

from ..constants import DEFAULT_EFFECTIVE_RADIUS, SPECIES, WAVELENGTHS_NM
from ..errors import SwimInputError

__all__ = ["henyey_greenstein", "mie_liquid_phase", "roughened_aggregate_phase", "legendre_moments",
           "split_phase_function", "AUREOLE_HALF_ANGLE_RAD",
           "CloudOptics", "cloud_optics", "PHASE_METHODS", "angles_deg", "ICE_ASYMMETRY"]

#: Extinction-weighted asymmetry parameter of the ice model [-] (Yang et al. 2013, severely roughened aggregates).
ICE_ASYMMETRY = 0.75
#: Share of the ice model's scattering in its diffraction peak [-] (extinction efficiency 2: half diffracted).
ICE_DIFFRACTION_FRACTION = 0.5
#: The refracted part's two-term Henyey-Greenstein: forward g, backward g and backward weight.
ICE_REFRACTED_HG = (0.55, -0.3, 0.05)
#: Largest effective radius [m] whose diffraction peak the table resolves (larger particles take its width).
LARGEST_RESOLVED_RADIUS_M = 100e-6
#: Half-angle [rad] of the circumsolar aureole: light that the forward peak scatters within it is delivered to the
#: image as a circumsolar term beside the sun's disk (a pyrheliometer's half-angle, 2.5 deg).
AUREOLE_HALF_ANGLE_RAD = math.radians(2.5)
#: Phase-function models of a species.
PHASE_METHODS = ("mie", "roughened_aggregate", "hg")
#: The species' models of ``cloud_phase_function="physical"``.
PHYSICAL = {"cloud_liquid": ("mie",), "rain": ("mie",), "cloud_ice": ("roughened_aggregate",),
            "snow": ("roughened_aggregate",), "graupel": ("roughened_aggregate",)}


@functools.lru_cache(maxsize=1)
def _mie_table():
    with resources.files("swim.data").joinpath("mie_liquid_phase.npz").open("rb") as f:
        data = np.load(f)
        return {k: np.asarray(data[k]) for k in data.files}


def angles_deg() -> np.ndarray:
    """Scattering angles [deg] of every tabulated phase function: the Mie table's, 0.01 deg apart below 2 deg,
    0.05 deg below 10 deg and 0.25 deg beyond (1 045 angles)."""
    return _mie_table()["theta_deg"]


_angles = angles_deg


def henyey_greenstein(cos_theta, g):
    """Henyey-Greenstein phase function (mean 1 over the sphere) of asymmetry ``g`` in (-1, 1), at ``cos_theta``."""
    mu = np.asarray(cos_theta, dtype=float)
    g = float(g)
    if not -1.0 < g < 1.0:
        raise SwimInputError(f"henyey_greenstein: g must be in (-1, 1), got {g}")
    return (1.0 - g * g) / (1.0 + g * g - 2.0 * g * mu) ** 1.5


def mie_liquid_phase(effective_radius_m) -> np.ndarray:
    """Bulk Mie phase function of liquid droplets, (n_angles, 3) on :func:`angles_deg` at 615/546/450 nm.

    Parameters
    ----------
    effective_radius_m : float
        Effective radius [m]; clamped to the table's 2-40 um (linear interpolation between its radii).

    Returns
    -------
    numpy.ndarray
        (n_angles, 3) [-], mean 1 over the sphere.
    """
    t = _mie_table()
    re = np.asarray(t["effective_radius_um"], float)
    r = float(np.clip(float(effective_radius_m) * 1e6, re[0], re[-1]))
    k = int(np.clip(np.searchsorted(re, r) - 1, 0, re.size - 2))
    w = (r - re[k]) / (re[k + 1] - re[k])
    p = (1 - w) * t["phase"][k] + w * t["phase"][k + 1]  # (3, n_angles)
    return _normalised(np.asarray(p, float).T)


def roughened_aggregate_phase(effective_radius_m) -> np.ndarray:
    """The ice model (module docstring), (n_angles, 3) on :func:`angles_deg` at 615/546/450 nm.

    Parameters
    ----------
    effective_radius_m : float
        Effective radius [m] (the diffraction peak's width ~ wavelength / (2 pi r_e)), capped at
        :data:`LARGEST_RESOLVED_RADIUS_M`.

    Returns
    -------
    numpy.ndarray
        (n_angles, 3) [-], mean 1 over the sphere, asymmetry parameter :data:`ICE_ASYMMETRY`.
    """
    theta = np.radians(_angles())
    mu = np.cos(theta)
    g1, g2, b = ICE_REFRACTED_HG
    refracted = (1 - b) * henyey_greenstein(mu, g1) + b * henyey_greenstein(mu, g2)
    r = min(max(float(effective_radius_m), 1e-6), LARGEST_RESOLVED_RADIUS_M)
    out = np.empty((theta.size, 3))
    for c, wl in enumerate(WAVELENGTHS_NM):
        # Airy pattern of discs whose radii spread over 0.5-1.5 r_e (no rings, as for a size distribution)
        peak = np.zeros_like(theta)
        for a in np.linspace(0.5, 1.5, 21) * r:
            x = 2 * math.pi * a / (wl * 1e-9) * np.sin(theta)
            airy = np.where(x > 1e-8, (2 * j1(np.maximum(x, 1e-8)) / np.maximum(x, 1e-8)) ** 2, 1.0)
            peak += airy * (a * a) ** 2  # intensity ~ area^2 at the peak, weight ~ area (a distribution by area)
        peak = np.where(theta < math.pi / 2, peak, 0.0)
        peak = _normalised(peak[:, None])[:, 0]
        out[:, c] = ICE_DIFFRACTION_FRACTION * peak + (1 - ICE_DIFFRACTION_FRACTION) * refracted
    return _normalised(out)


def _normalised(p):
    """``p`` (n_angles, k) scaled to a mean of 1 over the sphere (trapezoids in cos theta on the table's angles)."""
    mu = np.cos(np.radians(_angles()))
    norm = 0.5 * np.trapezoid(p[::-1], mu[::-1], axis=0)
    return p / norm


def legendre_moments(p, n_moments) -> np.ndarray:
    """Legendre moments chi_l = 1/2 int P P_l dmu, l = 0..``n_moments``, of a tabulated phase function.

    Parameters
    ----------
    p : numpy.ndarray
        (n_angles, k) on :func:`angles_deg`.
    n_moments : int
        Highest moment.

    Returns
    -------
    numpy.ndarray
        (n_moments + 1, k); chi_0 = 1 for a normalised P, chi_1 = g.
    """
    mu = np.cos(np.radians(_angles()))[::-1]
    pp = np.asarray(p, float)[::-1]
    out = np.empty((n_moments + 1,) + pp.shape[1:])
    p_prev, p_cur = np.ones_like(mu), mu.copy()
    for l in range(n_moments + 1):
        pl = np.ones_like(mu) if l == 0 else (mu if l == 1 else None)
        if l >= 2:
            pl = ((2 * l - 1) * mu * p_cur - (l - 1) * p_prev) / l
            p_prev, p_cur = p_cur, pl
        out[l] = 0.5 * np.trapezoid(pp * pl[:, None], mu, axis=0)
    return out


def _check_model(spec, species):
    """Raise :class:`SwimInputError` unless ``spec`` is ("mie",), ("roughened_aggregate",) or ("hg", g), g in
    (-1, 1)."""
    if not isinstance(spec, tuple) or not spec or spec[0] not in PHASE_METHODS:
        raise SwimInputError(f"cloud_phase_function[{species!r}] must be ('mie',), ('roughened_aggregate',) or "
                             f"('hg', g); got {spec!r}")
    if spec[0] == "hg":
        if len(spec) != 2:
            raise SwimInputError(f"cloud_phase_function[{species!r}] = ('hg', g) needs one asymmetry parameter g; "
                                 f"got {spec!r}")
        try:
            g = float(spec[1])
        except (TypeError, ValueError):
            raise SwimInputError(f"cloud_phase_function[{species!r}]: g must be a number, got {spec[1]!r}") from None
        if not -1.0 < g < 1.0:
            raise SwimInputError(f"cloud_phase_function[{species!r}]: g must be in (-1, 1), got {g}")
    elif len(spec) != 1:
        raise SwimInputError(f"cloud_phase_function[{species!r}] = ({spec[0]!r},) takes no parameters; got {spec!r}")


def _species_phase(spec, species, effective_radius_m):
    """(n_angles, 3) phase function of one species for a model ``spec`` (a tuple)."""
    _check_model(spec, species)
    if spec[0] == "hg":
        p = henyey_greenstein(np.cos(np.radians(_angles())), float(spec[1]))[:, None]
        return np.repeat(_normalised(p), 3, axis=1)
    if spec[0] == "mie":
        return mie_liquid_phase(effective_radius_m)
    return roughened_aggregate_phase(effective_radius_m)


def resolve_phase_spec(phase_function) -> dict:
    """The model of every species from ``cloud_phase_function``: "physical" or a mapping of species (or
    "liquid" for cloud liquid and rain, "ice" for ice, snow and graupel) to ("mie",), ("roughened_aggregate",) or
    ("hg", g); species not named keep their physical model.

    Raises
    ------
    SwimInputError
        If a name or a model is not one of these.
    """
    spec = dict(PHYSICAL)
    if isinstance(phase_function, str):
        if phase_function != "physical":
            raise SwimInputError(f"cloud_phase_function must be 'physical' or a mapping of species to models; got "
                                 f"{phase_function!r}")
        return spec
    if not hasattr(phase_function, "items"):
        raise SwimInputError(f"cloud_phase_function must be 'physical' or a mapping, got "
                             f"{type(phase_function).__name__}")
    groups = {"liquid": ("cloud_liquid", "rain"), "ice": ("cloud_ice", "snow", "graupel")}
    for name, model in phase_function.items():
        model = tuple(model) if isinstance(model, (list, tuple)) else (model,)
        _check_model(model, name)
        targets = groups.get(name, (name,))
        for s in targets:
            if s not in SPECIES:
                raise SwimInputError(f"cloud_phase_function: unknown species {name!r}; expected one of "
                                     f"{SPECIES + tuple(groups)}")
            spec[s] = model
    return spec


@dataclass(frozen=True)
class CloudOptics:
    """The hydrometeors' phase functions and their delta-M truncation (for the species ``SPECIES``).

    Attributes
    ----------
    phase : numpy.ndarray
        (5, n_angles, 3) [-]: P of each species on :func:`angles_deg`.
    moments : numpy.ndarray
        (5, L + 2, 3) [-]: Legendre moments chi_0..chi_{L+1}.
    truncation : numpy.ndarray
        (5,) [-]: the delta-M forward fraction f = chi_{L+1} at 546 nm, the same at every wavelength (the
        hydrometeors' scaled extinction beta (1 - f) is then grey, as their extinction is).
    scaled_moments : numpy.ndarray
        (5, L + 1, 3) [-]: chi*_l = (chi_l - f) / (1 - f).
    max_degree : int
        L.
    spec : tuple
        The species' models, for cache keys.
    phase_scaled, phase_unscaled : numpy.ndarray
        (5, n_angles, 3) [-]: the single scattering's split of P (:func:`split_phase_function`): the part that
        scatters the delta-M scaled direct beam and the forward excess (outside the aureole) that scatters the beam
        dimmed by all but the aureole's share of the forward peak.
    narrow : numpy.ndarray
        (5,) [-]: the forward peak's share within :data:`AUREOLE_HALF_ANGLE_RAD` (at 546 nm).
    """

    phase: np.ndarray
    moments: np.ndarray
    truncation: np.ndarray
    scaled_moments: np.ndarray
    max_degree: int
    spec: tuple
    phase_scaled: np.ndarray = None
    phase_unscaled: np.ndarray = None
    narrow: np.ndarray = None

    def phase_at(self, cos_theta, species) -> np.ndarray:
        """The single scattering's two parts (:func:`split_phase_function`) of the given species at the scattering
        angles' cosines: (n, len(species), 6) float32, ``phase_scaled`` at 615/546/450 nm then
        ``phase_unscaled``."""
        theta = np.degrees(np.arccos(np.clip(np.asarray(cos_theta, float), -1.0, 1.0)))
        angles = _angles()
        out = np.empty(theta.shape + (len(species), 6), np.float32)
        for n, s in enumerate(species):
            for c in range(3):
                out[..., n, c] = np.interp(theta, angles, self.phase_scaled[s, :, c])
                out[..., n, 3 + c] = np.interp(theta, angles, self.phase_unscaled[s, :, c])
        return out


def cloud_optics(phase_function="physical", max_degree=2, effective_radius_m=None) -> CloudOptics:
    """The hydrometeors' phase functions, Legendre moments and delta-M truncation.

    Parameters
    ----------
    phase_function : str or mapping
        "physical" or per-species models (:func:`resolve_phase_spec`).
    max_degree : int
        L, the degree of the truncated phase function (the moments of the diffuse solution).
    effective_radius_m : mapping, optional
        Species -> effective radius [m] of its phase function (e.g. the scene's extinction-weighted mean); default
        :data:`swim.constants.DEFAULT_EFFECTIVE_RADIUS`.

    Returns
    -------
    CloudOptics
    """
    spec = resolve_phase_spec(phase_function)
    if not 1 <= int(max_degree) <= 4:
        raise SwimInputError(f"cloud_optics: max_degree must be in 1..4, got {max_degree}")
    radii = dict(DEFAULT_EFFECTIVE_RADIUS)
    radii.update({k: float(v) for k, v in (effective_radius_m or {}).items() if np.isfinite(v) and v > 0})
    phase = np.stack([_species_phase(spec[s], s, radii[s]) for s in SPECIES])
    moments = np.stack([legendre_moments(p, max_degree + 1) for p in phase])  # (5, L + 2, 3)
    f = np.clip(moments[:, max_degree + 1, 1], 0.0, 0.99)
    scaled = (moments[:, :max_degree + 1, :] - f[:, None, None]) / (1.0 - f[:, None, None])
    key = tuple((s, spec[s], round(radii[s] * 1e6, 3) if spec[s][0] != "hg" else None) for s in SPECIES)
    parts = [split_phase_function(phase[n], moments[n, :max_degree + 1], f[n]) for n in range(len(SPECIES))]
    return CloudOptics(phase=phase, moments=moments, truncation=f, scaled_moments=scaled,
                       max_degree=int(max_degree), spec=key, phase_scaled=np.stack([a for a, _, _ in parts]),
                       phase_unscaled=np.stack([b for _, b, _ in parts]),
                       narrow=np.array([c for _, _, c in parts]))


def _aureole_split(excess, p, inner, theta, mu, f):
    """Pi (n_angles,) of :func:`split_phase_function` for one channel: ``excess`` (the forward excess up to its first
    zero) times s beyond the aureole (``inner``: within it), P - c within it, c = P - s E at the aureole's edge, with
    s such that Pi's energy is f (a few fixed-point steps: c depends on s only through the excess at the edge); a
    peak holding more than f within the aureole is scaled as a whole."""
    def energy(values):
        return 0.5 * np.trapezoid(values[::-1], mu[::-1])

    e_outer = energy(np.where(inner, 0.0, excess))
    p_edge, e_edge = (np.interp(AUREOLE_HALF_ANGLE_RAD, theta, v) for v in (p, excess))
    if e_outer <= 0:
        return f * excess / max(energy(excess), 1e-30)
    s = 1.0
    for _ in range(20):
        inside = np.where(inner, np.clip(p - (p_edge - s * e_edge), 0.0, p), 0.0)
        e_inner = energy(inside)
        if e_inner > f:  # a peak holding more than f: scaled as a whole
            return f * excess / max(energy(excess), 1e-30)
        s_next = (f - e_inner) / e_outer
        if abs(s_next - s) < 1e-9:
            break
        s = s_next
    inside = np.where(inner, np.clip(p - (p_edge - s * e_edge), 0.0, p), 0.0)  # with the s returned
    return np.where(inner, inside, excess * s)


def split_phase_function(p, moments, f):
    """The single scattering's split of a phase function for the delta-M scaled march.

    Delta-M (Wiscombe 1977) replaces the share f = chi_{L+1} of P by a forward delta, P = (1 - f) P* + f delta, so
    that the diffuse solution and the attenuation take the scaled optical depth (1 - f) tau. Nakajima and Tanaka's
    (1988) TMS then scatters the scaled direct beam e^{-(1 - f) tau_s} with the whole of P; where P's forward part is
    wider than the angles the delta stands for, that counts the light scattered more than once through the forward
    part as if it had been scattered once (a glow 10-40 deg from the sun up to 3x too bright under HG g = 0.85,
    +12-38 % in the GHI of an all-sky image; docs/decisions/0001-cloud-diffuse-solution.md). Here P is split:

    * the forward excess E(theta) = P - (1 - f) P* up to its first zero (theta_c, 38-44 deg for droplets), beyond the
      aureole scaled by s, within it P less the value c = P - s E that P - Pi takes at the aureole's edge (so that
      P - Pi is continuous there and flat inside: no peak narrower than a pixel, and no hole about the sun where a
      thick cloud dims the aureole's own light), s such that the whole has the energy f (Pi): the light the delta
      stands for;
    * its part within the aureole (:data:`AUREOLE_HALF_ANGLE_RAD`, above its value there): the narrow peak, energy
      f_a, delivered as the circumsolar aureole (swim.pipeline);
    * the rest of Pi scatters the beam dimmed by all but the narrow peak, e^{-(1 - f_a) tau_s} (a sharp
      diffraction peak's light scatters again much as the beam does; a broad lobe's does not);
    * P - Pi scatters the scaled beam e^{-(1 - f) tau_s} as in the TMS (outside the forward cone it is P itself).

    Along the sun's direction the three add up to the scaled beam's energy, e^{-(1 - f) tau} - e^{-tau}: fluxes do
    not depend on how finely an image resolves the forward peak.

    Parameters
    ----------
    p : numpy.ndarray
        (n_angles, 3) on :func:`angles_deg`.
    moments : numpy.ndarray
        (L + 1, 3): chi_0..chi_L.
    f : float
        The truncation.

    Returns
    -------
    tuple
        (P - Pi (n_angles, 3), Pi outside the aureole's peak (n_angles, 3), f_a at 546 nm).
    """
    theta = np.radians(_angles())
    mu = np.cos(theta)
    n_l = moments.shape[0]
    scaled = (moments - f) / (1.0 - f)  # (L + 1, 3)
    legendre = np.stack([np.polynomial.legendre.legval(mu, np.eye(n_l)[l]) for l in range(n_l)])  # (L + 1, n)
    p_star = ((2 * np.arange(n_l) + 1)[:, None, None] * scaled[:, None, :] * legendre[:, :, None]).sum(axis=0)
    excess = p - (1.0 - f) * p_star
    scaled_beam = np.empty_like(p)
    unscaled = np.empty_like(p)
    narrow = np.zeros(3)
    inner = theta < AUREOLE_HALF_ANGLE_RAD
    for c in range(3):
        negative = np.flatnonzero(excess[:, c] <= 0)
        cone = negative[0] if negative.size else theta.size
        pi = np.where(np.arange(theta.size) < cone, np.maximum(excess[:, c], 0.0), 0.0)
        pi = _aureole_split(pi, p[:, c], inner, theta, mu, f)
        scaled_beam[:, c] = np.maximum(p[:, c] - pi, 0.0)
        edge = np.interp(AUREOLE_HALF_ANGLE_RAD, theta, pi)
        outside = np.where(theta < AUREOLE_HALF_ANGLE_RAD, np.minimum(pi, edge), pi)
        unscaled[:, c] = outside
        narrow[c] = 0.5 * np.trapezoid((pi - outside)[::-1], mu[::-1])
    return scaled_beam, unscaled, float(narrow[1])
