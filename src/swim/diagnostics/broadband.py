"""Spectral (615/546/450 nm) -> broadband solar irradiance, with the gaseous absorption swim lacks.

SWIm renders at three wavelengths only and has no gaseous absorption there (Rayleigh + aerosol + clouds).
The paper (Albers et al. 2020, Sect. 3.1) takes broadband irradiance proportional to the relative
irradiance at 546 nm, with a "preliminary correction based on water vapour". This module replaces that
proxy by a spectral reconstruction over 280-4000 nm, done separately for the direct and the diffuse light,
times the absorption by water vapour, ozone and the uniformly mixed gases.

Method (each step is documented in docs/irradiance.md, with its error budget)
------------------------------------------------------------------------------
Inputs per sample: the direct-beam transmittance T_c = DNI_c / E_TOA,c and the relative diffuse horizontal
irradiance D_c = DHI_c / E_TOA,c at the three channels c (from :func:`swim.diagnostics.sky_irradiance`), the
sun zenith angle, surface pressure, precipitable water, total ozone, the ground albedo and the earth-sun
distance.

1. **Spectral grid and solar spectrum.** The 122 wavelengths of the Bird & Riordan (1986) SPCTRL2 model
   (300-4000 nm, pvlib's table); each node stands for a cell between the midpoints to its neighbours
   (280 nm and 4000 nm at the ends). The extraterrestrial irradiance of a cell is the mean of the ASTM
   G173-03 extraterrestrial spectrum over it (package data ``swim/data/astm_g173_etr_spectrl2_bins.csv``),
   scaled from the 1366.1 W m-2 total of that spectrum to the paper's solar constant 1362 W m-2 and by
   1 / r^2. Sum over the grid = 1347.9 x 1362 / 1366.1 = 1343.9 W m-2: the 1.3 % of the solar constant
   outside 280-4000 nm is taken not to reach a pyranometer.
2. **Direct beam.** The slant optical depth tau_c = -ln T_c is split into Rayleigh scattering, known a
   priori (Bodhaine et al. 1999 cross-sections, the surface pressure, Kasten & Young 1989 relative air
   mass), and a remainder (aerosol and cloud) fitted by an Angstrom law beta (lambda / 550 nm)^-alpha
   through the three channels (alpha ~ 0 for cloud: grey). The modelled T(lambda) is multiplied by the ratio
   swim / model at the channels (within ~1 %; interpolated linearly in lambda between 450 and 615 nm and
   held constant outside), so the reconstruction reproduces swim's three values exactly.
3. **Diffuse light.** Its spectral *shape* is the Bird & Riordan (1986) SPCTRL2 clear-sky diffuse spectrum
   (pvlib's :func:`pvlib.spectrum.spectrl2`: Rayleigh, aerosol and ground-sky multiple-reflection terms,
   Eqs. 3-1 to 3-17) for the same sun, pressure, ground albedo and the aerosol fitted in step 2 (or
   ``clear_sky_aod_550`` where the sun is hidden). swim's D_c are fitted by non-negative least squares as
   a x SPCTRL2_c + g (a: scale of the clear-sky spectrum, g: a grey, cloud-like part), and the ratio of
   swim to that fit at the channels (exact reproduction) is interpolated as in step 2.
4. **Gaseous absorption.** Water vapour, ozone and uniformly mixed gases (O2, CO2, ...) with the SPCTRL2
   band transmittances (Bird & Riordan 1986, Eqs. 2-8 to 2-11, pvlib's implementation) at the relative air
   mass of the sun; the diffuse light gets the same transmittance as the direct beam, as in SPCTRL2 (its
   Eqs. 3-5, 3-6) -- the clear-sky diffuse of step 3 already carries them.
5. DNI = sum_lambda E0 T(lambda) T_gas(lambda) dlambda; DHI likewise; GHI = DHI + cos(zenith) DNI.

Residual error of the conversion itself (docs/irradiance.md, tests/unit/diagnostics/test_diagnostics_broadband.py):
fed SPCTRL2's own three-channel values (a gas-free SPCTRL2 run) it reproduces SPCTRL2's broadband GHI to
0.3 % (zenith 0-85 deg, AOD 0.02-0.3, precipitable water 0.3-4 cm, albedo 0.2-0.8), DNI to 1.2 % (0.3 % for
zenith <= 75 deg) and DHI to 1 %. The dominant uncertainty in real use is the near-infrared aerosol
single-scattering albedo and asymmetry, which three visible channels cannot tell (up to 4 % of GHI for AOD
0.3 at zenith 75 deg, < 1 % for AOD <= 0.1).

References
----------
Albers, S. et al. (2020), AMT 13, 3235-3261, doi:10.5194/amt-13-3235-2020 (Sect. 3.1).
Bird, R. E. and Riordan, C. (1986), J. Clim. Appl. Meteorol. 25, 87-97,
doi:10.1175/1520-0450(1986)025<0087:SSSMFD>2.0.CO;2 (SPCTRL2; NREL TR-215-2436, doi:10.2172/5986936).
Bodhaine, B. A. et al. (1999), J. Atmos. Oceanic Technol. 16, 1854-1861,
doi:10.1175/1520-0426(1999)016<1854:ORODC>2.0.CO;2.
Kasten, F. and Young, A. T. (1989), Appl. Opt. 28, 4735-4738, doi:10.1364/AO.28.004735.
ASTM G173-03 (2012), Standard Tables for Reference Solar Spectral Irradiances, ASTM International,
doi:10.1520/G0173-03R12; data as distributed by NREL (Gueymard, C. A. (2004), Sol. Energy 76, 423-453,
doi:10.1016/j.solener.2003.08.039, and SMARTS 2.9.2).
Holmgren, W. F., Hansen, C. W. and Mikofski, M. A. (2018), pvlib python, JOSS 3, 884,
doi:10.21105/joss.00884.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass
from importlib import resources

import numpy as np
import xarray as xr

from ..constants import SOLAR_CONSTANT_W_M2, WAVELENGTHS_NM
from ..errors import SwimInputError

log = logging.getLogger(__name__)

__all__ = [
    "ReferenceSpectrum",
    "ASTM_G173_TSI_W_M2",
    "spectrl2_wavelengths",
    "reference_spectrum",
    "channel_solar_irradiance",
    "bin_spectrum",
    "gas_transmittance",
    "rayleigh_optical_depth",
    "relative_airmass",
    "broadband_irradiance",
    "broadband_from_sky",
]

#: Total solar irradiance [W m-2] that the ASTM G173-03 extraterrestrial spectrum represents (Gueymard 2004):
#: 1347.9 W m-2 of it lie in 280-4000 nm.
ASTM_G173_TSI_W_M2 = 1366.1
#: Package-data file with the binned ASTM G173 extraterrestrial spectrum.
SPECTRUM_FILE = "astm_g173_etr_spectrl2_bins.csv"
#: Limits of the spectral integration [nm] (the ASTM G173 range).
BAND_NM = (280.0, 4000.0)
#: Above this non-Rayleigh slant optical depth at 550 nm the sun counts as hidden (T < 5 %): the clear-sky
#: shape of the diffuse light then uses ``clear_sky_aod_550`` instead of the fitted aerosol.
HIDDEN_SUN_TAU = 3.0
#: Largest sun zenith angle [deg] at which the SPCTRL2 shape and the air masses are evaluated.
MAX_SHAPE_ZENITH_DEG = 89.5
#: Bounds of the fitted Angstrom exponent [-].
ANGSTROM_RANGE = (-0.5, 3.0)


def spectrl2_wavelengths() -> np.ndarray:
    """The 122 wavelengths [nm] of the SPCTRL2 model (300-4000 nm), from pvlib's coefficient table.

    Returns
    -------
    numpy.ndarray
        Shape (122,) [nm].
    """
    from pvlib.spectrum.spectrl2 import _SPECTRL2_COEFFS

    return np.asarray(_SPECTRL2_COEFFS["wavelength"], dtype=float).copy()


@dataclass(frozen=True)
class ReferenceSpectrum:
    """An extraterrestrial solar spectrum on the SPCTRL2 wavelengths, with quadrature weights.

    Attributes
    ----------
    wavelength_nm : numpy.ndarray
        Shape (n,): the nodes [nm]; must be :func:`spectrl2_wavelengths`.
    weight_nm : numpy.ndarray
        Shape (n,): quadrature weights [nm]: integral f dlambda ~ sum(weight_nm * f(wavelength_nm)).
    irradiance : numpy.ndarray
        Shape (n,): extraterrestrial spectral irradiance at 1 AU [W m-2 nm-1] (for binned data, the cell
        mean).
    tsi_w_m2 : float
        Total solar irradiance [W m-2] the spectrum stands for (all wavelengths); the spectrum is scaled by
        ``solar_constant / tsi_w_m2`` in use.
    source : str
        Where the numbers come from.
    edges_nm : numpy.ndarray, optional
        Shape (n + 1,): cell edges [nm] of binned data (needed to integrate over a sub-band).
    """

    wavelength_nm: np.ndarray
    weight_nm: np.ndarray
    irradiance: np.ndarray
    tsi_w_m2: float
    source: str
    edges_nm: np.ndarray | None = None

    def __post_init__(self):
        wl = np.asarray(self.wavelength_nm, dtype=float)
        w = np.asarray(self.weight_nm, dtype=float)
        e = np.asarray(self.irradiance, dtype=float)
        if not (wl.shape == w.shape == e.shape) or wl.ndim != 1:
            raise SwimInputError("reference spectrum: wavelength_nm, weight_nm and irradiance must be 1-D of one length")
        if np.any(~np.isfinite(e)) or np.any(e < 0) or np.any(~np.isfinite(w)) or np.any(w < 0):
            raise SwimInputError("reference spectrum: irradiance [W m-2 nm-1] and weights [nm] must be finite and >= 0")
        if not (np.isfinite(self.tsi_w_m2) and self.tsi_w_m2 > 0):
            raise SwimInputError(f"reference spectrum: tsi_w_m2 must be > 0 [W m-2], got {self.tsi_w_m2}")
        for name, value in (("wavelength_nm", wl), ("weight_nm", w), ("irradiance", e)):
            object.__setattr__(self, name, value)
        if self.edges_nm is not None:
            edges = np.asarray(self.edges_nm, dtype=float)
            if edges.shape != (wl.size + 1,) or np.any(np.diff(edges) <= 0):
                raise SwimInputError("reference spectrum: edges_nm must be increasing with one more value than the nodes")
            object.__setattr__(self, "edges_nm", edges)

    def band_weights(self, band_nm=None) -> np.ndarray:
        """Quadrature weights (n,) [nm] restricted to ``band_nm`` = (lower, upper) [nm] (None: all).

        Raises
        ------
        SwimInputError
            A sub-band of a spectrum without cell edges, or a band that is empty or not increasing.
        """
        if band_nm is None:
            return self.weight_nm
        lo, hi = (float(b) for b in band_nm)
        if not hi > lo:
            raise SwimInputError(f"band_nm must be (lower, upper) with upper > lower [nm]; got {band_nm!r}")
        if self.edges_nm is None:
            raise SwimInputError("this reference spectrum has no cell edges: it cannot be limited to a band")
        overlap = np.minimum(self.edges_nm[1:], hi) - np.maximum(self.edges_nm[:-1], lo)
        if not np.any(overlap > 0):
            raise SwimInputError(f"band_nm {band_nm!r} does not overlap the spectrum")
        return np.clip(overlap, 0.0, None) * (self.weight_nm / np.diff(self.edges_nm))

    @property
    def band_total_w_m2(self) -> float:
        """sum(weight x irradiance) [W m-2]: the part of ``tsi_w_m2`` inside the grid's band."""
        return float(np.sum(self.weight_nm * self.irradiance))

    def scaled(self, solar_constant_w_m2=SOLAR_CONSTANT_W_M2, earth_sun_distance_au=1.0) -> np.ndarray:
        """Spectral irradiance E0 (n,) [W m-2 nm-1] for a solar constant and earth-sun distance(s).

        Parameters
        ----------
        solar_constant_w_m2 : float
            Total solar irradiance at 1 AU [W m-2].
        earth_sun_distance_au : float or array_like
            Shape () or (N,): r [AU].

        Returns
        -------
        numpy.ndarray
            Shape (n,) or (n, N) [W m-2 nm-1].
        """
        r = np.asarray(earth_sun_distance_au, dtype=float)
        e = self.irradiance * (float(solar_constant_w_m2) / self.tsi_w_m2)
        return e / r**2 if r.ndim == 0 else e[:, None] / r[None, :] ** 2


def bin_spectrum(wavelength_nm, irradiance, nodes_nm, band_nm=BAND_NM):
    """Mean of a tabulated spectrum over the cells around given nodes (exact for a piecewise-linear table).

    Parameters
    ----------
    wavelength_nm : array_like
        Shape (m,): increasing wavelengths of the table [nm].
    irradiance : array_like
        Shape (m,): spectral irradiance [W m-2 nm-1] (linear between the table's wavelengths).
    nodes_nm : array_like
        Shape (n,): increasing nodes [nm]; cell edges are the midpoints between nodes, and ``band_nm`` at
        the ends.
    band_nm : tuple of float
        (lower, upper) edge of the first and last cell [nm].

    Returns
    -------
    edges : numpy.ndarray
        Shape (n + 1,) [nm].
    mean : numpy.ndarray
        Shape (n,): mean spectral irradiance over each cell [W m-2 nm-1]; sum(diff(edges) * mean) equals
        the trapezoidal integral of the table over ``band_nm``.

    Raises
    ------
    SwimInputError
        Non-increasing inputs or nodes outside the band.
    """
    w = np.asarray(wavelength_nm, dtype=float)
    e = np.asarray(irradiance, dtype=float)
    nodes = np.asarray(nodes_nm, dtype=float)
    if w.ndim != 1 or w.shape != e.shape or np.any(np.diff(w) <= 0) or np.any(np.diff(nodes) <= 0):
        raise SwimInputError("bin_spectrum: wavelengths and nodes must be increasing 1-D arrays [nm]")
    lo, hi = (float(b) for b in band_nm)
    if not (lo <= nodes[0] and nodes[-1] <= hi and w[0] <= lo and hi <= w[-1]):
        raise SwimInputError(f"bin_spectrum: the table ({w[0]}-{w[-1]} nm) must cover the band {band_nm} and the nodes")
    edges = np.concatenate([[lo], 0.5 * (nodes[1:] + nodes[:-1]), [hi]])
    fine = np.union1d(w, edges)
    ef = np.interp(fine, w, e)
    cumulative = np.concatenate([[0.0], np.cumsum(np.diff(fine) * 0.5 * (ef[1:] + ef[:-1]))])
    return edges, np.diff(np.interp(edges, fine, cumulative)) / np.diff(edges)


@functools.lru_cache(maxsize=1)
def reference_spectrum() -> ReferenceSpectrum:
    """The packaged ASTM G173-03 extraterrestrial spectrum, binned on the SPCTRL2 wavelengths.

    Returns
    -------
    ReferenceSpectrum
        Cell means [W m-2 nm-1] at 1 AU over 280-4000 nm (integral 1347.9 W m-2), ``tsi_w_m2`` 1366.1.

    Raises
    ------
    SwimInputError
        If the package data file is missing or malformed (a broken installation).
    """
    try:
        text = resources.files("swim").joinpath("data", SPECTRUM_FILE).read_text(encoding="utf-8")
    except (FileNotFoundError, OSError) as exc:
        raise SwimInputError(f"package data swim/data/{SPECTRUM_FILE} is missing: reinstall swim-imagery ({exc})") from None
    rows = [line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    try:
        table = np.array([[float(v) for v in line.split(",")] for line in rows[1:]], dtype=float)
    except ValueError as exc:
        raise SwimInputError(f"package data swim/data/{SPECTRUM_FILE} is malformed: {exc}") from None
    if table.ndim != 2 or table.shape[1] != 4:
        raise SwimInputError(f"package data swim/data/{SPECTRUM_FILE} must have 4 columns")
    nodes = spectrl2_wavelengths()
    if table.shape[0] != nodes.size or np.max(np.abs(table[:, 0] - nodes)) > 1e-6:
        raise SwimInputError(f"package data swim/data/{SPECTRUM_FILE} is not on the SPCTRL2 wavelengths")
    return ReferenceSpectrum(wavelength_nm=table[:, 0], weight_nm=table[:, 2] - table[:, 1], irradiance=table[:, 3],
                             tsi_w_m2=ASTM_G173_TSI_W_M2,
                             source="ASTM G173-03 extraterrestrial spectrum (NREL), cell means on the SPCTRL2 grid",
                             edges_nm=np.concatenate([table[:, 1], table[-1:, 2]]))


def channel_solar_irradiance(wavelengths_nm=WAVELENGTHS_NM, earth_sun_distance_au=1.0,
                             solar_constant_w_m2=SOLAR_CONSTANT_W_M2) -> np.ndarray:
    """Extraterrestrial solar spectral irradiance E_TOA at the channels' wavelengths: what converts the
    solar-relative radiance L' = 4 pi L / E_TOA (Albers et al. 2020, Eq. 2) to absolute radiance, L = L' E_TOA / 4 pi.

    Parameters
    ----------
    wavelengths_nm : array_like
        Shape (C,) [nm], in 280-4000 nm; default the renderer's 615, 546, 450 nm.
    earth_sun_distance_au : float
        Earth-sun distance [AU], > 0 (``E ~ 1 / r^2``).
    solar_constant_w_m2 : float
        Total solar irradiance at 1 AU [W m-2] the spectrum is scaled to (default the paper's 1362).

    Returns
    -------
    numpy.ndarray
        Shape (C,) [W m-2 nm-1]: the ASTM G173-03 extraterrestrial spectrum's cell means on the SPCTRL2 grid,
        log-linearly interpolated at the wavelengths (1.70, 1.85, 1.98 W m-2 nm-1 at 615, 546, 450 nm and 1 AU).

    Raises
    ------
    SwimInputError
        For wavelengths outside 280-4000 nm or a distance that is not positive.

    References
    ----------
    ASTM G173-03 (2012), Standard Tables for Reference Solar Spectral Irradiances; Gueymard, C. A. (2004), Solar
    Energy 76, 423-453, doi:10.1016/j.solener.2003.08.039.
    """
    wl = np.atleast_1d(np.asarray(wavelengths_nm, dtype=float))
    if not np.all((wl >= BAND_NM[0]) & (wl <= BAND_NM[1])):
        raise SwimInputError(f"wavelengths_nm must lie in {BAND_NM[0]:g}-{BAND_NM[1]:g} nm; got {wl}")
    if not (np.isfinite(earth_sun_distance_au) and earth_sun_distance_au > 0):
        raise SwimInputError(f"earth_sun_distance_au must be > 0 [AU]; got {earth_sun_distance_au!r}")
    spec = reference_spectrum()
    e0 = spec.scaled(solar_constant_w_m2, earth_sun_distance_au).reshape(-1, 1)
    return _channel_values(e0, spec.wavelength_nm, wl)[:, 0]


def relative_airmass(sun_zenith_deg):
    """Kasten & Young (1989) relative optical air mass [-], zenith clipped to :data:`MAX_SHAPE_ZENITH_DEG`.

    Parameters
    ----------
    sun_zenith_deg : array_like
        Sun zenith angle [deg], any shape.

    Returns
    -------
    numpy.ndarray
        Same shape [-] (1 at zenith, 26.6 at 89.5 deg).
    """
    import pvlib

    z = np.minimum(np.asarray(sun_zenith_deg, dtype=float), MAX_SHAPE_ZENITH_DEG)
    return np.asarray(pvlib.atmosphere.get_relative_airmass(z, model="kastenyoung1989"), dtype=float)


def rayleigh_optical_depth(wavelength_nm, pressure_pa, latitude_deg=45.0, elevation_m=0.0):
    """Vertical Rayleigh optical depth above a site (Bodhaine et al. 1999), any wavelength of the band.

    Parameters
    ----------
    wavelength_nm : array_like
        Shape (n,) [nm]; outside 230-1690 nm (the range of the Bodhaine fit) the cross-section at the nearest
        end is scaled by lambda^-4.
    pressure_pa : array_like
        Shape () or (N,): surface pressure [Pa].
    latitude_deg, elevation_m : float
        Site latitude [deg] and elevation [m] (effective gravity).

    Returns
    -------
    numpy.ndarray
        Shape (n,) or (n, N) [-].
    """
    from ..optics.rayleigh import rayleigh_optical_depth_bodhaine1999

    wl = np.asarray(wavelength_nm, dtype=float)
    clipped = np.clip(wl, 230.0, 1690.0)
    p = np.asarray(pressure_pa, dtype=float)
    tau1 = rayleigh_optical_depth_bodhaine1999(clipped, 101_325.0, latitude_deg, elevation_m) * (clipped / wl) ** 4
    return tau1 * (p / 101_325.0) if p.ndim == 0 else tau1[:, None] * (p[None, :] / 101_325.0)


def gas_transmittance(sun_zenith_deg, pressure_pa, precipitable_water_cm, ozone_atm_cm):
    """Transmittance of water vapour, ozone and the mixed gases on the SPCTRL2 wavelengths (direct beam).

    Bird & Riordan (1986), Eqs. 2-8 (water vapour), 2-9/2-10 (ozone, with its own air mass for a layer at
    22 km) and 2-11 (uniformly mixed gases, pressure-corrected air mass), as implemented by pvlib
    (``pvlib.spectrum.spectrl2``) with the Kasten & Young (1989) relative air mass.

    Parameters
    ----------
    sun_zenith_deg, pressure_pa, precipitable_water_cm, ozone_atm_cm : array_like
        Shape () or (N,): sun zenith [deg], surface pressure [Pa], precipitable water [cm], total ozone
        [atm-cm].

    Returns
    -------
    numpy.ndarray
        Shape (122, N): T_water x T_ozone x T_mixed [-] (N = 1 for scalar input).
    """
    from pvlib.spectrum.spectrl2 import _spectrl2_transmittances

    z, p, w, o = np.broadcast_arrays(*(np.atleast_1d(np.asarray(a, dtype=float)) for a in
                                       (sun_zenith_deg, pressure_pa, precipitable_water_cm, ozone_atm_cm)))
    z = np.minimum(z, MAX_SHAPE_ZENITH_DEG)
    n = spectrl2_wavelengths().size
    out = _spectrl2_transmittances(z, relative_airmass(z), p, w, o, np.zeros((n, 1)), np.ones((n, 1)),
                                   np.ones_like(z))
    t_water, t_ozone, t_mixed = out[3], out[4], out[5]
    return np.asarray(t_water * t_ozone * t_mixed, dtype=float)


def _channel_values(spectrum, wl_grid, channels):
    """Log-linear interpolation of spectra (n, N) at the channel wavelengths -> (C, N)."""
    logs = np.log(np.maximum(spectrum, 1e-300))
    out = np.empty((channels.size, spectrum.shape[1]))
    for k in range(spectrum.shape[1]):
        out[:, k] = np.exp(np.interp(channels, wl_grid, logs[:, k]))
    return out


def _channel_ratio_on_grid(ratio, channels, wl_grid):
    """Ratios at the channels (C,) -> linear in lambda between them, constant outside, on the grid (n,)."""
    order = np.argsort(channels)
    return np.interp(wl_grid, channels[order], ratio[order])


def _fit_angstrom(tau_rest, channels):
    """(beta at 550 nm, alpha) of tau = beta (lambda / 550)^-alpha through the channels' non-Rayleigh depth."""
    if not np.all(np.isfinite(tau_rest)):
        return np.inf, 0.0
    if np.max(tau_rest) <= 1e-6:
        return 0.0, 0.0
    if np.all(tau_rest > 0):
        x = -np.log(channels / 550.0)
        design = np.vstack([np.ones_like(x), x]).T
        (_, alpha), *_ = np.linalg.lstsq(design, np.log(tau_rest), rcond=None)
        alpha = float(np.clip(alpha, *ANGSTROM_RANGE))
        beta = float(np.exp(np.mean(np.log(tau_rest) - alpha * x)))
        return beta, alpha
    # Some channel has no aerosol left after the Rayleigh part (e.g. a pure Rayleigh sky): grey remainder.
    return max(float(np.mean(tau_rest)), 0.0), 0.0


def broadband_irradiance(dni_relative, dhi_relative, sun_zenith_deg, *, wavelengths_nm=WAVELENGTHS_NM,
                         pressure_pa=101_325.0, precipitable_water_cm=1.0, ozone_atm_cm=0.3,
                         earth_sun_distance_au=1.0, surface_albedo=0.2, aerosol_ssa_400nm=0.945,
                         aerosol_asymmetry=0.65, clear_sky_aod_550=0.05, latitude_deg=45.0, elevation_m=0.0,
                         solar_constant_w_m2=SOLAR_CONSTANT_W_M2, spectrum: ReferenceSpectrum | None = None,
                         band_nm=None, return_spectra=False, rendered_ozone_atm_cm=None) -> dict:
    """Broadband DNI, DHI and GHI [W m-2] from swim's three-wavelength irradiances (module docstring).

    Parameters
    ----------
    dni_relative : array_like
        Shape (C,) or (N, C): direct-beam transmittance DNI / E_TOA at ``wavelengths_nm`` [-], in [0, 1].
    dhi_relative : array_like
        Shape (C,) or (N, C): diffuse horizontal irradiance / E_TOA (normal incidence) [-], >= 0.
    sun_zenith_deg : array_like
        Shape () or (N,): sun zenith angle [deg].
    wavelengths_nm : array_like
        Shape (C,), C >= 2 (swim: 615, 546, 450) [nm], within 300-1000 nm.
    pressure_pa : array_like
        Shape () or (N,): surface pressure [Pa], 0-110 000 (Rayleigh a priori and mixed gases; 0: no
        molecular atmosphere); for swim's renders the US Standard Atmosphere 1976 at the observer's height
        is what the renderer used.
    precipitable_water_cm : array_like
        Shape () or (N,): precipitable water [cm], 0-10.
    ozone_atm_cm : array_like
        Shape () or (N,): total ozone [atm-cm] (0.3 = 300 DU), 0-1.
    rendered_ozone_atm_cm : array_like, optional
        Shape () or (N,): the ozone column [atm-cm] whose absorption ``dni_relative`` and ``dhi_relative`` already
        hold (swim's renders: :func:`broadband_from_sky` takes it from the render's ``ozone_column_du``); None: they
        hold none. Its transmittance at the channels (the renderer's cross sections) is divided out of the direct
        and the diffuse light before the fits, and SPCTRL2's gas transmittance of ``ozone_atm_cm`` then applies over
        the whole band, so the ozone is neither taken for aerosol nor counted twice.
    earth_sun_distance_au : array_like
        Shape () or (N,): r [AU]; E0 scales with 1 / r^2.
    surface_albedo : array_like
        Shape () or (N,): broadband ground albedo [-] for the SPCTRL2 diffuse shape.
    aerosol_ssa_400nm, aerosol_asymmetry : float
        Aerosol single-scattering albedo at 400 nm and asymmetry parameter [-] for the SPCTRL2 diffuse
        shape (SPCTRL2's rural defaults 0.945, 0.65); they set the spectral slope of the aerosol diffuse in
        the near infrared, which three visible channels cannot constrain.
    clear_sky_aod_550 : float
        Vertical aerosol optical depth at 550 nm [-] used for the clear-sky diffuse shape where the sun is
        hidden (non-Rayleigh slant optical depth > :data:`HIDDEN_SUN_TAU`).
    latitude_deg, elevation_m : float
        Site latitude [deg] and elevation [m] (Rayleigh optical depth, Bodhaine et al. 1999).
    solar_constant_w_m2 : float
        Total solar irradiance at 1 AU [W m-2] (paper: 1362).
    spectrum : ReferenceSpectrum, optional
        Extraterrestrial spectrum on the SPCTRL2 grid; default :func:`reference_spectrum` (ASTM G173-03).
    band_nm : tuple of float, optional
        (lower, upper) [nm]: integrate over this band only, e.g. (285, 2800) for the glass dome of a
        thermopile pyranometer (Eppley PSP) or (300, 3000) for Bird's broadband model; default the whole
        280-4000 nm.
    return_spectra : bool
        Also return the spectra (keys ``wavelength_nm`` (n,), ``dni_spectral``, ``dhi_spectral`` (n, N)
        [W m-2 nm-1]).

    Returns
    -------
    dict of numpy.ndarray
        Each of shape () (scalar input) or (N,): ``ghi``, ``dni``, ``dhi``, ``direct_horizontal``
        [W m-2]; ``aod_550`` (fitted vertical non-Rayleigh optical depth at 550 nm) [-],
        ``angstrom_exponent`` [-], ``diffuse_scale`` (a) and ``diffuse_grey`` (g) of the diffuse fit [-].

    Raises
    ------
    SwimInputError
        Shapes that do not match, values outside their ranges, a spectrum on another grid.

    Notes
    -----
    A sample with the sun below the horizon (zenith >= 90 deg) has DNI = direct_horizontal = 0; its diffuse
    light is converted with the shape at zenith 89.5 deg (twilight; a few W m-2 at most).
    """
    channels = _checked_channels(wavelengths_nm)
    scalar = np.ndim(dni_relative) == 1 and np.ndim(sun_zenith_deg) == 0
    t_dir, d_rel = _relative_arrays(dni_relative, dhi_relative, channels)
    n = t_dir.shape[0]
    zen, p, pw, o3, r, albedo = _sample_parameters(n, sun_zenith_deg, pressure_pa, precipitable_water_cm,
                                                   ozone_atm_cm, earth_sun_distance_au, surface_albedo)
    _check_ranges(t_dir, d_rel, aerosol_ssa_400nm, aerosol_asymmetry, clear_sky_aod_550)
    wl, e0, weight = _extraterrestrial(spectrum, solar_constant_w_m2, r, band_nm)
    zs, am, tau_r_grid, tau_r_chan, t_gas = _a_priori_atmosphere(zen, p, pw, o3, wl, channels, latitude_deg,
                                                                 elevation_m)

    # Step 2: direct beam.
    if rendered_ozone_atm_cm is not None:  # SPCTRL2 applies its gas transmittance to the diffuse light too
        rendered = np.broadcast_to(np.asarray(rendered_ozone_atm_cm, dtype=float), (n,))
        t_o3 = _channel_ozone_transmittance(zs, rendered, channels)
        t_dir, d_rel = t_dir / t_o3, d_rel / t_o3
    t_model, beta, alpha, hidden = _direct_beam(t_dir, zen, channels, wl, tau_r_grid, tau_r_chan)
    dni_spectral = e0 * t_model * t_gas

    # Step 3: diffuse light, shaped by SPCTRL2 for the fitted (or fallback) aerosol.
    shape_free, shape_gas = _diffuse_shapes(zs, am, p, pw, o3, albedo, beta, alpha, hidden, clear_sky_aod_550,
                                            aerosol_ssa_400nm, aerosol_asymmetry)
    scale, grey, dhi_rel_grid = _fit_diffuse(d_rel, _channel_values(shape_free, wl, channels), shape_gas, t_gas,
                                             channels, wl)
    dhi_spectral = e0 * dhi_rel_grid

    out = _integrated(weight, dni_spectral, dhi_spectral, zen, am, beta, alpha, hidden, scale, grey)
    if scalar:
        out = {k: v[0] for k, v in out.items()}
    if return_spectra:
        out.update(wavelength_nm=wl, dni_spectral=dni_spectral, dhi_spectral=dhi_spectral)
    return out


def _checked_channels(wavelengths_nm):
    """The channels' wavelengths (C,) [nm]: at least two, distinct, within 300-1000 nm."""
    channels = np.asarray(wavelengths_nm, dtype=float).ravel()
    if channels.size < 2 or np.any(~np.isfinite(channels)) or np.any(channels < 300) or np.any(channels > 1000):
        raise SwimInputError(f"wavelengths_nm must hold >= 2 wavelengths within 300-1000 nm, got {wavelengths_nm!r}")
    if np.unique(channels).size != channels.size:
        raise SwimInputError(f"wavelengths_nm must be distinct, got {wavelengths_nm!r}")
    return channels


def _relative_arrays(dni_relative, dhi_relative, channels):
    """The relative direct and diffuse irradiances as arrays (N, C); raises where their shapes differ."""
    t_dir = np.atleast_2d(np.asarray(dni_relative, dtype=float))
    d_rel = np.atleast_2d(np.asarray(dhi_relative, dtype=float))
    if t_dir.shape != d_rel.shape or t_dir.shape[1] != channels.size:
        raise SwimInputError(f"dni_relative and dhi_relative must both have shape (N, {channels.size}); got "
                             f"{np.shape(dni_relative)} and {np.shape(dhi_relative)}")
    return t_dir, d_rel


def _per_sample(name, value, lo, hi, unit, n):
    """A scalar or (n,) parameter as an array (n,), checked to be finite and within [lo, hi]."""
    a = np.asarray(value, dtype=float)
    if a.ndim > 1 or (a.ndim == 1 and a.size != n):
        raise SwimInputError(f"{name} must be a scalar or have shape ({n},); got {a.shape}")
    a = np.broadcast_to(a, (n,)).astype(float)
    if np.any(~np.isfinite(a)) or np.any(a < lo) or np.any(a > hi):
        raise SwimInputError(f"{name} must be finite and within [{lo}, {hi}] [{unit}]; got {value!r}")
    return a


def _sample_parameters(n, sun_zenith_deg, pressure_pa, precipitable_water_cm, ozone_atm_cm, earth_sun_distance_au,
                       surface_albedo):
    """The per-sample parameters as arrays (n,), each checked (:func:`_per_sample`)."""
    return (_per_sample("sun_zenith_deg", sun_zenith_deg, 0.0, 180.0, "deg", n),
            _per_sample("pressure_pa", pressure_pa, 0.0, 110_000.0, "Pa", n),
            _per_sample("precipitable_water_cm", precipitable_water_cm, 0.0, 10.0, "cm", n),
            _per_sample("ozone_atm_cm", ozone_atm_cm, 0.0, 1.0, "atm-cm", n),
            _per_sample("earth_sun_distance_au", earth_sun_distance_au, 0.9, 1.1, "AU", n),
            _per_sample("surface_albedo", surface_albedo, 0.0, 1.0, "1", n))


def _check_ranges(t_dir, d_rel, aerosol_ssa_400nm, aerosol_asymmetry, clear_sky_aod_550):
    """Raise where the aerosol's shape parameters or the relative irradiances are out of range."""
    for name, value, lo, hi in (("aerosol_ssa_400nm", aerosol_ssa_400nm, 0.3, 1.0),
                                ("aerosol_asymmetry", aerosol_asymmetry, 0.0, 0.95),
                                ("clear_sky_aod_550", clear_sky_aod_550, 0.0, 5.0)):
        if not (np.isfinite(value) and lo <= value <= hi):
            raise SwimInputError(f"{name} must be within [{lo}, {hi}] [-]; got {value!r}")
    if np.any(~np.isfinite(t_dir)) or np.any(t_dir < 0) or np.any(t_dir > 1.0 + 1e-6):
        raise SwimInputError("dni_relative (direct transmittance) must be within [0, 1]")
    if np.any(~np.isfinite(d_rel)) or np.any(d_rel < 0):
        raise SwimInputError("dhi_relative must be finite and >= 0")


def _extraterrestrial(spectrum, solar_constant_w_m2, earth_sun_distance_au, band_nm):
    """Step 1: the SPCTRL2 grid (n_wl,) [nm], E0 on it (n_wl, N) [W m-2 nm-1] and the band's weights (n_wl, 1)."""
    spec = reference_spectrum() if spectrum is None else spectrum
    wl = spectrl2_wavelengths()
    if spec.wavelength_nm.shape != wl.shape or np.max(np.abs(spec.wavelength_nm - wl)) > 1e-6:
        raise SwimInputError("the reference spectrum must be on the SPCTRL2 wavelengths (spectrl2_wavelengths())")
    e0 = spec.scaled(solar_constant_w_m2, earth_sun_distance_au)  # (n_wl, N)
    weight = spec.band_weights(band_nm)[:, None]
    return wl, e0, weight


def _a_priori_atmosphere(zen, p, pw, o3, wl, channels, latitude_deg, elevation_m):
    """What is known without the renders: the zenith of the spectral shapes (N,) [deg], the relative air mass (N,),
    the slant Rayleigh optical depths on the grid (n_wl, N) and at the channels (C, N), and the gases'
    transmittance (n_wl, N)."""
    zs = np.minimum(zen, MAX_SHAPE_ZENITH_DEG)
    am = relative_airmass(zs)
    tau_r_grid = rayleigh_optical_depth(wl, p, latitude_deg, elevation_m) * am[None, :]  # slant (n_wl, N)
    tau_r_chan = rayleigh_optical_depth(channels, p, latitude_deg, elevation_m) * am[None, :]  # (C, N)
    t_gas = gas_transmittance(zs, p, pw, o3)  # (n_wl, N)
    return zs, am, tau_r_grid, tau_r_chan, t_gas


def _channel_ozone_transmittance(zs, o3, channels):
    """The renderer's ozone transmittance of the direct beam at the channels (N, C) [-]: its cross sections
    (:func:`swim.optics.ozone.ozone_cross_section`) times the column ``o3`` [atm-cm] along the ozone layer's air
    mass (a layer at 22 km, Bird & Riordan 1986, Eq. 2-10), so that dividing it out leaves the render's direct and
    diffuse light free of ozone."""
    from ..optics.ozone import DOBSON_UNIT_M2, ozone_cross_section

    zr = np.radians(np.minimum(np.asarray(zs, dtype=float), MAX_SHAPE_ZENITH_DEG))
    airmass = (1.0 + 22.0 / 6370.0) / np.sqrt(np.cos(zr) ** 2 + 2.0 * 22.0 / 6370.0)
    tau = 1000.0 * np.asarray(o3, dtype=float)[:, None] * DOBSON_UNIT_M2 * ozone_cross_section(channels)[None, :]
    return np.exp(-tau * airmass[:, None])


def _direct_beam(t_dir, zen, channels, wl, tau_r_grid, tau_r_chan):
    """Step 2: the direct beam's transmittance on the grid (n_wl, N), the Angstrom fit (beta, alpha) (N,) and
    whether the sun is hidden (N,)."""
    n = t_dir.shape[0]
    t_model = np.zeros((wl.size, n))
    beta = np.zeros(n)
    alpha = np.zeros(n)
    hidden = np.zeros(n, dtype=bool)
    for k in range(n):
        if zen[k] >= 90.0 or np.any(t_dir[k] <= 1e-12):
            hidden[k] = True
            beta[k], alpha[k] = np.inf, 0.0
            continue
        tau_rest = -np.log(t_dir[k]) - tau_r_chan[:, k]
        beta[k], alpha[k] = _fit_angstrom(tau_rest, channels)
        hidden[k] = beta[k] > HIDDEN_SUN_TAU
        tau_rest_grid = beta[k] * (wl / 550.0) ** (-alpha[k])
        fitted = np.exp(-tau_r_chan[:, k] - beta[k] * (channels / 550.0) ** (-alpha[k]))
        ratio = np.where(fitted > 0, t_dir[k] / np.maximum(fitted, 1e-300), 1.0)
        t_model[:, k] = np.exp(-tau_r_grid[:, k] - tau_rest_grid) * _channel_ratio_on_grid(ratio, channels, wl)
    return t_model, beta, alpha, hidden


def _diffuse_shapes(zs, am, p, pw, o3, albedo, beta, alpha, hidden, clear_sky_aod_550, aerosol_ssa_400nm,
                    aerosol_asymmetry):
    """Step 3: SPCTRL2's clear-sky diffuse / E0 on the grid (n_wl, N) [-], without gases and with them, for the
    fitted aerosol (``clear_sky_aod_550`` where the sun is hidden)."""
    from pvlib.spectrum import spectrl2

    n = zs.shape[0]
    aod500 = np.where(hidden, clear_sky_aod_550 * (500.0 / 550.0) ** -1.3,
                      np.where(np.isfinite(beta), beta, 0.0) * (500.0 / 550.0) ** (-alpha) / am)
    alpha_shape = np.where(hidden, 1.3, alpha)
    common = dict(apparent_zenith=zs, aoi=zs, surface_tilt=np.zeros(n), ground_albedo=albedo,
                  surface_pressure=p, relative_airmass=am, aerosol_turbidity_500nm=aod500,
                  dayofyear=np.ones(n), scattering_albedo_400nm=np.full(n, float(aerosol_ssa_400nm)),
                  alpha=alpha_shape, aerosol_asymmetry_factor=np.full(n, float(aerosol_asymmetry)))
    with np.errstate(invalid="ignore", divide="ignore"):
        free = spectrl2(precipitable_water=np.zeros(n), ozone=np.zeros(n), **common)
        gassy = spectrl2(precipitable_water=pw, ozone=o3, **common)
    shape_free = np.nan_to_num(np.asarray(free["dhi"]) / np.asarray(free["dni_extra"]))  # (n_wl, N) [-]
    shape_gas = np.nan_to_num(np.asarray(gassy["dhi"]) / np.asarray(gassy["dni_extra"]))
    return shape_free, shape_gas


def _fit_diffuse(d_rel, shape_chan, shape_gas, t_gas, channels, wl):
    """Step 3: swim's diffuse light fitted as a x SPCTRL2 + g at the channels, and its reconstruction on the grid.

    Returns the scale a (N,), the grey part g (N,) and the relative diffuse on the grid (n_wl, N) [-].
    """
    from scipy.optimize import nnls

    n = d_rel.shape[0]
    scale = np.zeros(n)
    grey = np.zeros(n)
    dhi_rel_grid = np.zeros((wl.size, n))
    for k in range(n):
        target = d_rel[k]
        if not np.any(target > 0):
            continue
        w_rows = 1.0 / np.maximum(target, 1e-12 * target.max())  # fit in relative terms
        design = np.vstack([shape_chan[:, k], np.ones(channels.size)]).T * w_rows[:, None]
        (scale[k], grey[k]), _ = nnls(design, target * w_rows)
        fitted = scale[k] * shape_chan[:, k] + grey[k]
        ratio = np.where(fitted > 0, target / np.maximum(fitted, 1e-300), 1.0)
        dhi_rel_grid[:, k] = ((scale[k] * shape_gas[:, k] + grey[k] * t_gas[:, k])
                              * _channel_ratio_on_grid(ratio, channels, wl))
    return scale, grey, dhi_rel_grid


def _integrated(weight, dni_spectral, dhi_spectral, zen, am, beta, alpha, hidden, scale, grey):
    """Step 5: the band's DNI, DHI and GHI [W m-2] (N,) and the fits' diagnostics (N,)."""
    mu0 = np.maximum(np.cos(np.radians(zen)), 0.0)
    dni = np.sum(weight * dni_spectral, axis=0)
    dhi = np.sum(weight * dhi_spectral, axis=0)
    return {
        "ghi": dhi + mu0 * dni,
        "dni": dni,
        "dhi": dhi,
        "direct_horizontal": mu0 * dni,
        "aod_550": np.where(hidden, np.inf, np.where(np.isfinite(beta), beta, np.inf) / am),
        "angstrom_exponent": alpha,
        "diffuse_scale": scale,
        "diffuse_grey": grey,
    }


def broadband_from_sky(relative: xr.Dataset, **kwargs) -> xr.Dataset:
    """Broadband irradiance [W m-2] from the output of :func:`swim.diagnostics.sky_irradiance`.

    Parameters
    ----------
    relative : xarray.Dataset
        ``dni`` and ``dhi`` (wavelength) relative to E_TOA [-], attributes ``sun_zenith_deg`` [deg] and
        ``earth_sun_distance_au`` [AU].
    **kwargs
        Passed to :func:`broadband_irradiance` (pressure_pa, precipitable_water_cm, ozone_atm_cm,
        surface_albedo, ...).

    Returns
    -------
    xarray.Dataset
        Scalars ``ghi``, ``dni``, ``dhi``, ``direct_horizontal`` [W m-2] and the fit diagnostics.

    Raises
    ------
    SwimInputError
        If ``relative`` lacks ``dni``/``dhi`` or the sun's attributes.
    """
    try:
        wl = np.asarray(relative["wavelength"].values, dtype=float)
        dni_rel = np.asarray(relative["dni"].values, dtype=float)
        dhi_rel = np.asarray(relative["dhi"].values, dtype=float)
        zen = float(relative.attrs["sun_zenith_deg"])
    except KeyError as err:
        raise SwimInputError(f"relative irradiance lacks {err.args[0]!r} (use swim.diagnostics.sky_irradiance)") from None
    kwargs.setdefault("earth_sun_distance_au", float(relative.attrs.get("earth_sun_distance_au", 1.0)))
    if float(relative.attrs.get("ozone_column_du", 0.0)) > 0:  # the render's ozone, which its light holds
        rendered = float(relative.attrs["ozone_column_du"]) / 1000.0
        kwargs.setdefault("rendered_ozone_atm_cm", rendered)
        kwargs.setdefault("ozone_atm_cm", rendered)
    res = broadband_irradiance(dni_rel, dhi_rel, zen, wavelengths_nm=wl, **kwargs)
    names = {"ghi": "global horizontal irradiance", "dni": "direct normal irradiance",
             "dhi": "diffuse horizontal irradiance", "direct_horizontal": "direct horizontal irradiance"}
    data = {k: ((), float(res[k]), {"units": "W m-2", "long_name": f"{v} (broadband 280-4000 nm)"}) for k, v in names.items()}
    data.update({k: ((), float(res[k]), {"units": "1"}) for k in ("aod_550", "angstrom_exponent", "diffuse_scale", "diffuse_grey")})
    return xr.Dataset(data, attrs={"sun_zenith_deg": zen, "method": "swim.diagnostics.broadband (docs/irradiance.md)"})
