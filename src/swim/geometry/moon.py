"""The moon as a light source: its position, phase and top-of-atmosphere spectral irradiance for a time and place.

Conventions as for the sun (:mod:`swim.geometry.sun`, ``docs/frames.md``): azimuth [deg] clockwise from north, zenith
angle [deg] from the local vertical, *geometric* (unrefracted) angles, and directions as unit vectors in the
observer's local ENU frame.

Position. The topocentric apparent place (light time and aberration, no refraction) of the moon and of the sun from
the JPL DE421 ephemeris (Folkner et al. 2008) with Skyfield (Rhodes 2019), read from the copy that the
``skyfield-data`` package ships, and Skyfield's built-in Delta T: nothing is downloaded. The phase angle g is the
sun-moon-observer angle (0 at full moon, 180 deg at new moon); the illuminated fraction of the disk is
``k = (1 + cos g) / 2``.

Irradiance. The lunar spectral irradiance at the top of the atmosphere is the Miller and Turner (2009) model, tabulated
at 1 AU sun-moon distance and the mean earth-moon distance 384,400 km against the phase angle (NOAA ``moontran``'s
table, 300-750 nm, 1 nm, mW m-2 um-1). :data:`LUNAR_IRRADIANCE_TABLE` holds it averaged over 10 nm about each SWIm
wavelength (615, 546, 450 nm; the mean of the 11 table samples from lambda - 5 nm to lambda + 5 nm) at 45 phase angles
(every degree to 9 deg, where the opposition surge steepens it, every 5 deg beyond); between them it is interpolated
monotonically (PCHIP) in log E, within 0.4 % of the full 1-degree table (``tests/unit/geometry/test_moon.py``). It
is scaled to a date by ``(1 AU / r_sun-moon)^2 (384,400 km / d_observer-moon)^2``. Divided by the solar spectral
irradiance of swim's colour stage averaged over the same 10 nm (the ASTM G173-03 extraterrestrial spectrum scaled to
1362 W m-2, :func:`swim.color.astm_g173_extraterrestrial`) at the actual earth-sun distance, it gives
:func:`lunar_irradiance_ratio`, the factor that turns a render lit by a light of the sun's spectrum and irradiance into
one lit by the moon, still in the solar-relative units ``L' = 4 pi L / E_TOA`` (Albers et al. 2020, Eq. 2).

References
----------
Miller, S. D. and Turner, R. E. (2009): A dynamic lunar spectral irradiance data set for NPOESS/VIIRS day/night band
nighttime environmental applications, IEEE Trans. Geosci. Remote Sens. 47, 2316-2329, doi:10.1109/TGRS.2009.2012696.
Kieffer, H. H. and Stone, T. C. (2005): The spectral irradiance of the Moon, Astron. J. 129, 2887-2901,
doi:10.1086/430185 (ROLO; the tests' comparison).
Folkner, W. M., Williams, J. G. and Boggs, D. H. (2008): The planetary and lunar ephemeris DE 421, JPL IOM 343R-08-003.
Rhodes, B. (2019): Skyfield: high precision research-grade positions for planets and Earth satellites generator,
Astrophysics Source Code Library ascl:1907.024.
"""

from __future__ import annotations

import functools
import logging
import math
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from .. import frames
from ..constants import WAVELENGTHS_NM
from ..errors import SwimInputError
from .sun import _real, parse_time_utc

__all__ = ["MoonPosition", "MOON_RADIUS_M", "MEAN_EARTH_MOON_DISTANCE_M", "LUNAR_IRRADIANCE_TABLE", "moon_position",
           "moon_from_angles", "lunar_irradiance", "lunar_irradiance_ratio", "solar_irradiance_at_channels",
           "CHANNEL_HALF_WIDTH_NM"]

logger = logging.getLogger(__name__)

#: Mean radius of the moon [m] (IAU; Archinal et al. 2018).
MOON_RADIUS_M = 1_737_400.0
#: Mean earth-moon distance of the Miller and Turner (2009) table [m].
MEAN_EARTH_MOON_DISTANCE_M = 384_400_000.0
#: Astronomical unit [m] (IAU 2012).
AU_M = 149_597_870_700.0
#: Half width of the 10 nm band over which the lunar and the solar spectra are averaged about each SWIm wavelength
#: [nm]: wide enough that the solar lines (in both, from different solar spectra) do not alias; the ratio at 546 nm
#: changes by 0.1 % between 5 and 20 nm wide bands.
CHANNEL_HALF_WIDTH_NM = 5.0
#: Source recorded in :attr:`MoonPosition.source`.
MOON_SOURCES = ("skyfield-de421", "override")

#: Miller and Turner (2009) top-of-atmosphere lunar spectral irradiance at 1 AU and 384,400 km [mW m-2 um-1], the mean
#: over 10 nm about 615, 546 and 450 nm: rows (phase angle [deg], E_615, E_546, E_450).
LUNAR_IRRADIANCE_TABLE = np.array([
    (0, 4.5084, 4.509, 4.0417), (1, 4.4008, 4.4001, 3.9421), (2, 4.2958, 4.2935, 3.845), (3, 4.1936, 4.1897, 3.7503),
    (4, 4.0937, 4.0885, 3.6578), (5, 3.9959, 3.9897, 3.5678), (6, 3.8965, 3.8885, 3.4747),
    (7, 3.7995, 3.7897, 3.3845), (8, 3.7049, 3.6937, 3.2963), (9, 3.6127, 3.6, 3.2106), (10, 3.5229, 3.5086, 3.1271),
    (15, 3.1143, 3.0949, 2.7499), (20, 2.7531, 2.7302, 2.4186), (25, 2.4388, 2.4135, 2.132),
    (30, 2.1606, 2.1337, 1.8793), (35, 1.9104, 1.8825, 1.6532), (40, 1.6892, 1.661, 1.4542),
    (45, 1.5039, 1.4774, 1.2918), (50, 1.339, 1.3142, 1.1476), (55, 1.1907, 1.1682, 1.0196),
    (60, 1.059, 1.0386, 0.90605), (65, 0.93325, 0.91495, 0.79767), (70, 0.82245, 0.806, 0.70228),
    (75, 0.71487, 0.7003, 0.60989), (80, 0.62136, 0.60849, 0.52967), (85, 0.52891, 0.51756, 0.4501),
    (90, 0.45021, 0.44025, 0.38249), (95, 0.374, 0.36519, 0.31664), (100, 0.31066, 0.30291, 0.2621),
    (105, 0.25003, 0.24333, 0.20998), (110, 0.20123, 0.19545, 0.1682), (115, 0.15613, 0.15117, 0.12955),
    (120, 0.12115, 0.11694, 0.099797), (125, 0.089875, 0.086421, 0.07334), (130, 0.066681, 0.063864, 0.053899),
    (135, 0.048665, 0.046468, 0.039048), (140, 0.035516, 0.033805, 0.028287), (145, 0.024938, 0.023674, 0.019735),
    (150, 0.017512, 0.016578, 0.013768), (155, 0.012052, 0.011405, 0.0094641), (160, 0.0082964, 0.0078457, 0.0065057),
    (165, 0.0056825, 0.0053916, 0.0044913), (170, 0.0038917, 0.003705, 0.0031006),
    (175, 0.002702, 0.0025969, 0.0022023), (180, 0.0018757, 0.0018201, 0.0015642),
])
LUNAR_IRRADIANCE_TABLE.flags.writeable = False


@dataclass(frozen=True)
class MoonPosition:
    """The moon seen from an observer, as a light source.

    It has the attributes of a :class:`swim.geometry.sun.SunPosition` that a render reads (``zenith_deg``,
    ``azimuth_deg``, ``earth_sun_distance_au``, ``time``, ``source``, ``direction_enu``), so the render's stages take
    it in the sun's place.

    Parameters
    ----------
    zenith_deg, azimuth_deg : float
        Geometric (unrefracted) topocentric zenith angle [deg], in [0, 180], and azimuth [deg] clockwise from north
        (stored wrapped into [0, 360)).
    distance_m : float
        Observer-moon distance [m], > 0 (356,000-407,000 km).
    phase_angle_deg : float
        Sun-moon-observer angle g [deg], in [0, 180]: 0 at full moon.
    bright_limb_angle_deg : float
        Direction of the bright limb's middle on the disk [deg], clockwise from the local upward vertical as seen by
        an observer facing the moon (90: the right, the evening crescent of the northern hemisphere's spring).
    sun_moon_distance_au, earth_sun_distance_au : float
        Sun-moon and earth-sun distances [AU], > 0.
    time : pandas.Timestamp or None
        The instant (UTC), or None for an override.
    source : str
        ``"skyfield-de421"`` (:func:`moon_position`) or ``"override"`` (:func:`moon_from_angles`).

    Raises
    ------
    SwimInputError
        For values outside the ranges above.
    """

    zenith_deg: float
    azimuth_deg: float
    distance_m: float
    phase_angle_deg: float
    bright_limb_angle_deg: float
    sun_moon_distance_au: float
    earth_sun_distance_au: float
    time: pd.Timestamp | None
    source: str

    def __post_init__(self) -> None:
        object.__setattr__(self, "zenith_deg", _real("zenith_deg", self.zenith_deg, 0.0, 180.0))
        object.__setattr__(self, "azimuth_deg", _real("azimuth_deg", self.azimuth_deg) % 360.0)
        object.__setattr__(self, "phase_angle_deg", _real("phase_angle_deg", self.phase_angle_deg, 0.0, 180.0))
        object.__setattr__(self, "bright_limb_angle_deg", _real("bright_limb_angle_deg", self.bright_limb_angle_deg)
                           % 360.0)
        for name, lo, hi, unit in (("distance_m", 3.0e8, 4.2e8, "m"), ("sun_moon_distance_au", 0.9, 1.1, "AU"),
                                   ("earth_sun_distance_au", 0.9, 1.1, "AU")):
            object.__setattr__(self, name, _real(name, getattr(self, name), lo, hi, unit=unit))
        if self.time is not None:
            object.__setattr__(self, "time", parse_time_utc(self.time))
        if self.source not in MOON_SOURCES:
            raise SwimInputError(f"source must be one of {MOON_SOURCES}, got {self.source!r}")

    @property
    def elevation_deg(self) -> float:
        """Geometric elevation ``90 - zenith_deg`` [deg]."""
        return 90.0 - self.zenith_deg

    @property
    def direction_enu(self) -> np.ndarray:
        """Unit vector (east, north, up) [-] towards the moon in the observer's ENU frame, shape ``(3,)``."""
        return frames.enu_from_azimuth_zenith(self.azimuth_deg, self.zenith_deg)

    @property
    def illuminated_fraction(self) -> float:
        """Illuminated fraction of the disk ``(1 + cos g) / 2`` [-]."""
        return 0.5 * (1.0 + math.cos(math.radians(self.phase_angle_deg)))

    @property
    def angular_radius_rad(self) -> float:
        """Angular radius of the disk, ``asin(R_moon / d)`` [rad] (about 0.0045)."""
        return math.asin(MOON_RADIUS_M / self.distance_m)

    def sun_from_moon_enu(self, direction_enu=None) -> np.ndarray:
        """Unit vector (3,) [-] from the moon towards the sun in an ENU frame: at the phase angle from the direction
        back to the observer, towards the bright limb. ``direction_enu``: the moon's direction in that frame (3,);
        default :attr:`direction_enu` (an observer elsewhere in a scene sees the moon in a slightly turned frame)."""
        m = self.direction_enu if direction_enu is None else np.asarray(direction_enu, dtype=float)
        up, right = _disk_axes(m)
        chi = math.radians(self.bright_limb_angle_deg)
        limb = math.cos(chi) * up + math.sin(chi) * right
        g = math.radians(self.phase_angle_deg)
        return -math.cos(g) * m + math.sin(g) * limb

    def to_attrs(self) -> dict[str, Any]:
        """Plain scalars and strings describing the moon (netCDF attributes); keys start with ``moon_``."""
        return {
            "moon_zenith_deg": float(self.zenith_deg),
            "moon_azimuth_deg": float(self.azimuth_deg),
            "moon_distance_km": float(self.distance_m / 1000.0),
            "moon_phase_angle_deg": float(self.phase_angle_deg),
            "moon_illuminated_fraction": float(self.illuminated_fraction),
            "moon_bright_limb_angle_deg": float(self.bright_limb_angle_deg),
            "moon_sun_moon_distance_au": float(self.sun_moon_distance_au),
            "moon_time_utc": "" if self.time is None else self.time.strftime("%Y-%m-%dT%H:%M:%S.%fZ"),
            "moon_source": self.source,
            "moon_angles": "geometric (no refraction); azimuth clockwise from north; bright limb clockwise from the "
                           "upward vertical, facing the moon",
        }


def _disk_axes(m):
    """Unit vectors (up, right) across the line of sight ``m`` (3,): towards the zenith (towards north where ``m`` is
    vertical) and to the right of an observer facing along ``m``."""
    m = np.asarray(m, dtype=float)
    zenith = np.array([0.0, 0.0, 1.0]) if abs(m[2]) < 1.0 - 1e-9 else np.array([0.0, 1.0, 0.0])
    up = zenith - np.dot(zenith, m) * m
    up /= np.linalg.norm(up)
    return up, np.cross(m, up)


def _bright_limb_angle(m, s):
    """Clockwise angle [deg] from the upward vertical to the projection of the moon-to-sun unit vector ``s`` on the
    disk of the moon seen along ``m`` (unit, ENU)."""
    up, right = _disk_axes(m)
    return math.degrees(math.atan2(float(np.dot(s, right)), float(np.dot(s, up)))) % 360.0


@functools.lru_cache(maxsize=1)
def _ephemeris():
    """Skyfield's timescale (built-in Delta T) and the DE421 ephemeris shipped by ``skyfield-data``."""
    from skyfield.api import Loader

    with warnings.catch_warnings():  # skyfield-data warns that its Earth-orientation file aged; it is not used here
        warnings.simplefilter("ignore")
        from skyfield_data import get_skyfield_data_path

        path = get_skyfield_data_path()
    load = Loader(path, verbose=False)
    return load.timescale(builtin=True), load("de421.bsp")


def moon_position(time, lat, lon, altitude_m=0.0) -> MoonPosition:
    """The moon's topocentric position, distance and phase at an instant and place (DE421 via Skyfield).

    Parameters
    ----------
    time : str, datetime.datetime, numpy.datetime64 or pandas.Timestamp
        The instant, one value (ISO 8601 strings; naive times are UTC).
    lat : float
        Observer latitude [deg], in [-90, 90].
    lon : float
        Observer longitude [deg], east positive; any finite value.
    altitude_m : float, default 0.0
        Observer height above the WGS84 ellipsoid [m], in [-1000, 100000] (topocentric parallax: up to 1 deg).

    Returns
    -------
    MoonPosition
        With ``source="skyfield-de421"``.

    Raises
    ------
    SwimInputError
        If ``time`` cannot be parsed or lies outside DE421 (1900-2050), or a coordinate is out of range.

    References
    ----------
    Folkner et al. (2008), JPL IOM 343R-08-003 (DE421); Rhodes (2019), ascl:1907.024 (Skyfield).
    """
    ts = parse_time_utc(time, "time")
    if not 1900 <= ts.year < 2050:
        raise SwimInputError(f"time must lie in 1900-2049 (the DE421 ephemeris), got {ts.isoformat()}")
    lat_v = _real("lat", lat, -90.0, 90.0)
    lon_v = (_real("lon", lon) + 180.0) % 360.0 - 180.0
    alt = _real("altitude_m", altitude_m, -1000.0, 100000.0, unit="m")
    return _moon(ts, lat_v, lon_v, alt)


@functools.lru_cache(maxsize=64)
def _moon(ts, lat_v, lon_v, alt) -> MoonPosition:
    """:func:`moon_position` of validated arguments, remembered (a render asks twice)."""
    from skyfield.api import wgs84

    timescale, eph = _ephemeris()
    t = timescale.from_datetime(ts.to_pydatetime())
    here = (eph["earth"] + wgs84.latlon(lat_v, lon_v, elevation_m=alt)).at(t)
    vectors = {}
    for body in ("moon", "sun"):
        alt_deg, az_deg, dist = here.observe(eph[body]).apparent().altaz()
        vectors[body] = dist.m * frames.enu_from_azimuth_zenith(az_deg.degrees, 90.0 - alt_deg.degrees)
    r_moon, r_sun = vectors["moon"], vectors["sun"]
    d_moon = float(np.linalg.norm(r_moon))
    m = r_moon / d_moon
    to_sun = r_sun - r_moon
    s = to_sun / np.linalg.norm(to_sun)
    zen, az = frames.azimuth_zenith_from_enu(m)[::-1]
    moon = MoonPosition(
        zenith_deg=float(np.clip(zen, 0.0, 180.0)), azimuth_deg=float(az), distance_m=d_moon,
        phase_angle_deg=math.degrees(math.acos(float(np.clip(np.dot(s, -m), -1.0, 1.0)))),
        bright_limb_angle_deg=_bright_limb_angle(m, s),
        sun_moon_distance_au=float(np.linalg.norm(to_sun)) / AU_M,
        earth_sun_distance_au=float(np.linalg.norm(r_sun)) / AU_M, time=ts, source="skyfield-de421")
    logger.debug("moon at %s, lat %.4f lon %.4f alt %.0f m: zenith %.4f deg, azimuth %.4f deg, %.0f km, phase angle "
                 "%.2f deg", ts.isoformat(), lat_v, lon_v, alt, moon.zenith_deg, moon.azimuth_deg, d_moon / 1e3,
                 moon.phase_angle_deg)
    return moon


def moon_from_angles(zenith_deg, azimuth_deg, phase_angle_deg, bright_limb_angle_deg=90.0,
                     distance_m=MEAN_EARTH_MOON_DISTANCE_M, sun_moon_distance_au=1.0,
                     earth_sun_distance_au=1.0) -> MoonPosition:
    """A moon given directly (an override of :func:`moon_position`), e.g. a chosen geometry for a check.

    Parameters
    ----------
    zenith_deg, azimuth_deg : float
        Zenith angle [deg], in [0, 180], and azimuth [deg] clockwise from north.
    phase_angle_deg : float
        Phase angle [deg], in [0, 180] (0: full moon).
    bright_limb_angle_deg : float, default 90
        Bright limb's direction [deg] clockwise from the upward vertical, facing the moon.
    distance_m : float, default 384,400 km
        Observer-moon distance [m].
    sun_moon_distance_au, earth_sun_distance_au : float, default 1
        Distances [AU].

    Returns
    -------
    MoonPosition
        With ``source="override"`` and ``time=None``.

    Raises
    ------
    SwimInputError
        For values outside the ranges of :class:`MoonPosition`.
    """
    return MoonPosition(zenith_deg=zenith_deg, azimuth_deg=azimuth_deg, distance_m=distance_m,
                        phase_angle_deg=phase_angle_deg, bright_limb_angle_deg=bright_limb_angle_deg,
                        sun_moon_distance_au=sun_moon_distance_au, earth_sun_distance_au=earth_sun_distance_au,
                        time=None, source="override")


@functools.lru_cache(maxsize=1)
def _log_irradiance_interpolant():
    from scipy.interpolate import PchipInterpolator

    return PchipInterpolator(LUNAR_IRRADIANCE_TABLE[:, 0], np.log(LUNAR_IRRADIANCE_TABLE[:, 1:] * 1e-6))


def lunar_irradiance(phase_angle_deg, sun_moon_distance_au=1.0, moon_distance_m=MEAN_EARTH_MOON_DISTANCE_M):
    """Top-of-atmosphere lunar spectral irradiance at the SWIm wavelengths (Miller and Turner 2009).

    Parameters
    ----------
    phase_angle_deg : float or array_like, shape (n,)
        Phase angle [deg], in [0, 180].
    sun_moon_distance_au : float
        Sun-moon distance [AU], > 0.
    moon_distance_m : float
        Observer-moon distance [m], > 0.

    Returns
    -------
    numpy.ndarray, shape (3,) or (n, 3)
        Spectral irradiance normal to the beam [W m-2 nm-1] at 615, 546, 450 nm (10 nm means).

    Raises
    ------
    SwimInputError
        For a phase angle outside [0, 180] deg or a non-positive distance.

    References
    ----------
    Miller and Turner (2009), IEEE TGRS 47, 2316-2329, doi:10.1109/TGRS.2009.2012696.
    """
    g = np.asarray(phase_angle_deg, dtype=float)
    if not (np.all(np.isfinite(g)) and np.all((g >= 0.0) & (g <= 180.0))):
        raise SwimInputError(f"phase_angle_deg must be in [0, 180] [deg], got {phase_angle_deg!r}")
    r = _real("sun_moon_distance_au", sun_moon_distance_au, 0.0, unit="AU")
    d = _real("moon_distance_m", moon_distance_m, 0.0, unit="m")
    if r <= 0.0 or d <= 0.0:
        raise SwimInputError(f"distances must be > 0; got sun_moon_distance_au={r}, moon_distance_m={d}")
    return np.exp(_log_irradiance_interpolant()(g)) / r**2 * (MEAN_EARTH_MOON_DISTANCE_M / d) ** 2


@functools.lru_cache(maxsize=1)
def solar_irradiance_at_channels() -> np.ndarray:
    """Extraterrestrial solar spectral irradiance at 1 AU averaged over 10 nm about 615, 546, 450 nm.

    Returns
    -------
    numpy.ndarray, shape (3,)
        [W m-2 nm-1]: ASTM G173-03 (:func:`swim.color.astm_g173_extraterrestrial`) scaled to
        :data:`swim.constants.SOLAR_CONSTANT_W_M2`, the same spectrum as the colour stage's (docs/colour.md).
    """
    from ..color import astm_g173_extraterrestrial
    from ..color._tables import ASTM_G173_TSI_W_M2
    from ..constants import SOLAR_CONSTANT_W_M2

    wl, e = astm_g173_extraterrestrial()
    out = []
    for lam in WAVELENGTHS_NM:
        fine = np.arange(lam - CHANNEL_HALF_WIDTH_NM, lam + CHANNEL_HALF_WIDTH_NM + 0.25, 0.5)
        out.append(np.interp(fine, wl, e).mean())
    out = np.array(out) * (SOLAR_CONSTANT_W_M2 / ASTM_G173_TSI_W_M2)
    out.flags.writeable = False
    return out


def lunar_irradiance_ratio(moon: MoonPosition) -> np.ndarray:
    """The moon's top-of-atmosphere spectral irradiance relative to the sun's, at the SWIm wavelengths.

    Parameters
    ----------
    moon : MoonPosition
        Phase angle and distances.

    Returns
    -------
    numpy.ndarray, shape (3,)
        ``E_moon / E_TOA`` [-] at 615, 546, 450 nm, the sun at ``moon.earth_sun_distance_au``: about 2.5e-6 at full
        moon. A render lit from the moon's direction by a light of the sun's irradiance, times this, is the moonlit
        render in the solar-relative radiance L' = 4 pi L / E_TOA (Albers et al. 2020, Eq. 2).
    """
    e_moon = lunar_irradiance(moon.phase_angle_deg, moon.sun_moon_distance_au, moon.distance_m)
    return e_moon / (solar_irradiance_at_channels() / moon.earth_sun_distance_au**2)
