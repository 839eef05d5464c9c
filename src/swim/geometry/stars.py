"""The bright stars: the Yale Bright Star Catalogue (BSC5) and the stars' apparent, refracted places in the sky.

A star's catalogue place (J2000 right ascension and declination, ICRS to the catalogue's accuracy) is turned into
its apparent topocentric altitude and azimuth for a time and place by skyfield (Rhodes 2019): precession, nutation,
annual aberration, light deflection and the observer's diurnal aberration, with the JPL ephemeris DE421 for the
earth's motion and skyfield's built-in Delta T and leap seconds. Proper motion is neglected (the BSC5's largest,
a few arcsec yr-1, moves a star by less than 3 arcmin in 30 years, a quarter of a pixel of a 1024^2 all-sky image).
Astronomical refraction then lifts it by Saemundsson's formula (Saemundsson 1986) scaled to the air's pressure and
temperature at the observer (Meeus 1998, Ch. 16).

The catalogue is the BSC5's fixed-width ``catalog`` file (CDS/ADC V/50, Hoffleit & Warren 1991: 9096 stars to
V = 7.96 with J2000 position, V and B-V), read from the path given or from the environment variable
:data:`CATALOGUE_ENV`, parsed once per path; without either, the same stars packaged with swim
(``swim/data/bsc5_stars.npz``, :func:`packaged_catalogue`).

References
----------
Hoffleit, D. & Warren, W. H. Jr. (1991), The Bright Star Catalogue, 5th Revised Ed., NASA/ADC (CDS V/50).
Rhodes, B. (2019), Skyfield: high precision research-grade positions for planets and Earth satellites generator,
Astrophysics Source Code Library, ascl:1907.024.
Saemundsson, T. (1986), Astronomical refraction, Sky and Telescope 72, 70.
Meeus, J. (1998), Astronomical Algorithms, 2nd ed., Willmann-Bell, Ch. 16 (Eq. 16.4 and the pressure and
temperature factor).
"""

from __future__ import annotations

import functools
import logging
import os
import warnings
from dataclasses import dataclass
from importlib import resources
from importlib.util import find_spec
from pathlib import Path

import numpy as np

from ..errors import SwimInputError
from ..optics.atmosphere import us_standard_atmosphere_1976
from .sun import parse_time_utc

log = logging.getLogger(__name__)

#: Environment variable naming the BSC5 ``catalog`` file (e.g. ``.../stars/bsc5.dat``).
CATALOGUE_ENV = "SWIM_STAR_CATALOGUE"

#: The packaged star table (``swim/data``).
PACKAGED_TABLE = "bsc5_stars.npz"
#: Number of records in the BSC5 without its 14 non-stellar entries.
BSC5_STARS = 9096



@dataclass(frozen=True)
class StarCatalogue:
    """Stars of a catalogue, each array of shape (n,).

    Attributes
    ----------
    hr : numpy.ndarray
        Bright Star (Harvard Revised) number.
    ra_deg, dec_deg : numpy.ndarray
        J2000 right ascension and declination [deg].
    v_mag : numpy.ndarray
        Johnson V magnitude [mag].
    b_minus_v : numpy.ndarray
        Johnson B-V colour index [mag]; NaN where the catalogue has none.
    """

    hr: np.ndarray
    ra_deg: np.ndarray
    dec_deg: np.ndarray
    v_mag: np.ndarray
    b_minus_v: np.ndarray

    def __len__(self) -> int:
        return int(self.hr.size)

    def brighter_than(self, v_limit: float) -> "StarCatalogue":
        """The stars with V <= ``v_limit`` [mag]."""
        keep = self.v_mag <= v_limit
        return StarCatalogue(*(getattr(self, f)[keep] for f in ("hr", "ra_deg", "dec_deg", "v_mag", "b_minus_v")))



def _field(line: str, start: int, stop: int) -> str:
    """1-based inclusive byte columns ``start``-``stop`` of a fixed-width record (blank where it is short)."""
    return line[start - 1:stop].strip()



@functools.lru_cache(maxsize=4)
def read_bsc5(path) -> StarCatalogue:
    """Parse the BSC5 ``catalog`` file (CDS/ADC V/50 byte layout) once per path.

    Parameters
    ----------
    path : str or pathlib.Path
        The fixed-width catalogue (``bsc5.dat``).

    Returns
    -------
    StarCatalogue
        Every record with a J2000 position and V (the non-stellar entries, which have none, are skipped).

    Raises
    ------
    SwimInputError
        If the file does not exist or holds no star.
    """
    path = Path(path)
    if not path.is_file():
        raise SwimInputError(f"star catalogue (BSC5 'catalog' file) not found: {path}")
    rows = []
    with open(path, encoding="latin-1") as f:
        for line in f:
            ra_h, v = _field(line, 76, 77), _field(line, 103, 107)
            if not ra_h or not v:
                continue
            ra = 15.0 * (float(ra_h) + float(_field(line, 78, 79)) / 60 + float(_field(line, 80, 83)) / 3600)
            sign = -1.0 if line[83] == "-" else 1.0
            dec = sign * (float(_field(line, 85, 86)) + float(_field(line, 87, 88)) / 60
                          + float(_field(line, 89, 90)) / 3600)
            bv = _field(line, 110, 114)
            rows.append((int(_field(line, 1, 4)), ra, dec, float(v), float(bv) if bv else np.nan))
    if not rows:
        raise SwimInputError(f"star catalogue {path} holds no star with a J2000 position and V (BSC5 layout expected)")
    hr, ra, dec, v, bv = (np.asarray(c) for c in zip(*rows))
    arrays = (hr.astype(np.int32), ra.astype(float), dec.astype(float), v.astype(float), bv.astype(float))
    for a in arrays:
        a.setflags(write=False)
    log.debug("read %d stars from %s", len(rows), path)
    return StarCatalogue(*arrays)



def star_catalogue(path=None) -> StarCatalogue | None:
    """The bright-star catalogue: ``path``, else the file named by :data:`CATALOGUE_ENV`, else the packaged table
    (:func:`packaged_catalogue`: the BSC5's 9096 stars); None (logged once) where skyfield, which places the stars,
    is not installed. Raises :class:`SwimInputError` for a path that does not exist."""
    if find_spec("skyfield") is None or find_spec("skyfield_data") is None:
        _warn_once("the stars need skyfield and skyfield-data (pip install skyfield skyfield-data): left out")
        return None
    path = path or os.environ.get(CATALOGUE_ENV, "").strip()
    return read_bsc5(str(path)) if path else packaged_catalogue()


@functools.lru_cache(maxsize=1)
def packaged_catalogue() -> StarCatalogue:
    """The stars of the BSC5 packaged with swim (``swim/data/bsc5_stars.npz``, written from the catalogue file by
    ``scripts/make_star_table.py``): the same values as :func:`read_bsc5` of the catalogue (V and B-V as float32).

    Raises
    ------
    SwimInputError
        If the package data file is missing (a broken installation).
    """
    try:
        with resources.files("swim").joinpath("data", PACKAGED_TABLE).open("rb") as f, np.load(f) as table:
            arrays = (table["hr"].astype(np.int32), table["ra_deg"].astype(float), table["dec_deg"].astype(float),
                      table["v_mag"].astype(float), table["b_minus_v"].astype(float))
    except (FileNotFoundError, OSError, KeyError) as exc:
        raise SwimInputError(f"package data swim/data/{PACKAGED_TABLE} is missing or broken: reinstall swim-imagery "
                             f"({exc})") from None
    for a in arrays:
        a.setflags(write=False)
    return StarCatalogue(*arrays)



@functools.lru_cache(maxsize=4)
def _warn_once(message):
    log.warning(message)



def refraction_saemundsson_deg(true_altitude_deg, pressure_hpa=1010.0, temperature_c=10.0):
    """Astronomical refraction [deg] of a star at true (airless) altitude ``true_altitude_deg`` [deg].

    R = 1.02' / tan(h + 10.3 / (h + 5.11)) (h in degrees, R in arcmin) at 1010 hPa and 10 degC, scaled by
    (P / 1010 hPa) (283 K / (273 K + T)): within 0.1' of Bennett's inverse formula, 34' at the horizon. Zero
    below an altitude of -2 deg (stars there are not seen).

    Parameters
    ----------
    true_altitude_deg : array_like
        Geometric altitude [deg], any shape.
    pressure_hpa, temperature_c : float
        Air pressure [hPa] and temperature [degC] at the observer.

    Returns
    -------
    numpy.ndarray
        Refraction [deg] (apparent minus true altitude), the shape of ``true_altitude_deg``.

    References
    ----------
    Saemundsson, T. (1986), Sky and Telescope 72, 70; Meeus (1998), Astronomical Algorithms, Eq. 16.4.
    """
    h = np.asarray(true_altitude_deg, dtype=float)
    hh = np.maximum(h, -2.0)
    r_arcmin = 1.02 / np.tan(np.radians(hh + 10.3 / (hh + 5.11)))
    r_arcmin *= (pressure_hpa / 1010.0) * (283.0 / (273.0 + temperature_c))
    return np.where(h >= -2.0, r_arcmin / 60.0, 0.0)



def _skyfield(with_kernel=False):
    """skyfield's timescale (built-in Delta T and leap seconds) and the DE421 earth, loaded once from
    skyfield-data's files (no download); with ``with_kernel`` also the DE421 kernel (the sun and planets)."""
    ts, kernel = _de421()
    return (ts, kernel["earth"], kernel) if with_kernel else (ts, kernel["earth"])


@functools.lru_cache(maxsize=1)
def _de421():
    """skyfield's built-in timescale and skyfield-data's DE421 kernel, loaded once."""
    try:
        from skyfield.api import Loader
        from skyfield_data import get_skyfield_data_path
    except ImportError as err:  # pragma: no cover - an optional dependency
        raise SwimInputError("star positions need skyfield and skyfield-data (pip install skyfield skyfield-data)") \
            from err
    with warnings.catch_warnings():  # skyfield-data's IERS table may be past its date: the built-in one is used
        warnings.simplefilter("ignore", RuntimeWarning)
        load = Loader(get_skyfield_data_path(), verbose=False, expire=False)
        ts = load.timescale(builtin=True)
        kernel = load("de421.bsp")
    return ts, kernel



def apparent_altaz(ra_deg, dec_deg, time, lat, lon, height_m=0.0):
    """Apparent topocentric altitude and azimuth of stars, without refraction.

    Parameters
    ----------
    ra_deg, dec_deg : array_like
        J2000 (ICRS) right ascension and declination [deg], shape (n,).
    time : str, datetime, numpy.datetime64 or pandas.Timestamp
        UTC time.
    lat, lon : float
        Observer's geodetic latitude and longitude [deg] (WGS84).
    height_m : float
        Observer's height above sea level [m].

    Returns
    -------
    altitude_deg, azimuth_deg : numpy.ndarray
        Shape (n,): true (airless) altitude [deg] and azimuth clockwise from north [deg].

    Raises
    ------
    SwimInputError
        Bad time or an observer outside [-90, 90] deg latitude; skyfield missing.
    """
    from skyfield.api import Star, wgs84

    if not (np.isfinite(lat) and -90.0 <= lat <= 90.0 and np.isfinite(lon)):
        raise SwimInputError(f"observer lat/lon must be finite, lat in [-90, 90] deg; got {lat}, {lon}")
    ts, earth = _skyfield()
    t = ts.from_datetime(parse_time_utc(time).to_pydatetime())
    stars = Star(ra_hours=np.asarray(ra_deg, float) / 15.0, dec_degrees=np.asarray(dec_deg, float))
    observer = earth + wgs84.latlon(float(lat), float(lon), elevation_m=float(height_m))
    alt, az, _ = observer.at(t).observe(stars).apparent().altaz()
    return np.atleast_1d(alt.degrees), np.atleast_1d(az.degrees)



def star_directions_enu(catalogue: StarCatalogue, time, lat, lon, height_m=0.0, temperature_c=None):
    """Unit vectors (n, 3) in the observer's ENU frame towards the stars' apparent, refracted places.

    The airless places of :func:`apparent_altaz` lifted by :func:`refracted_directions`: the refraction of the air
    at the observer's height in the US Standard Atmosphere 1976 (its pressure and, unless ``temperature_c`` [degC]
    is given, its temperature); above 85 km (no air) none.

    Returns
    -------
    directions : numpy.ndarray
        Shape (n, 3): east, north, up.
    altitude_deg : numpy.ndarray
        Shape (n,): the apparent (refracted) altitude [deg].
    """
    alt, az = apparent_altaz(catalogue.ra_deg, catalogue.dec_deg, time, lat, lon, height_m)
    return refracted_directions(alt, az, height_m, temperature_c)



def refracted_directions(altitude_deg, azimuth_deg, height_m=0.0, temperature_c=None):
    """Unit vectors (n, 3) in the ENU frame towards true (airless) altitudes and azimuths [deg] (n,) lifted by the
    refraction (:func:`refraction_saemundsson_deg`) of the air at the observer's height [m] in the US Standard
    Atmosphere 1976 (its pressure and, unless ``temperature_c`` [degC] is given, its temperature; above 85 km none).

    Returns
    -------
    directions : numpy.ndarray
        Shape (n, 3): east, north, up.
    altitude_deg : numpy.ndarray
        Shape (n,): the apparent (refracted) altitude [deg].
    """
    alt, az = np.asarray(altitude_deg, dtype=float), np.asarray(azimuth_deg, dtype=float)
    h = float(np.clip(height_m, -5_000.0, 85_000.0))
    temperature, pressure, _ = us_standard_atmosphere_1976(np.array([h]))
    t_c = float(temperature[0]) - 273.15 if temperature_c is None else float(temperature_c)
    p_hpa = float(pressure[0]) / 100.0 if height_m < 85_000.0 else 0.0
    alt = alt + refraction_saemundsson_deg(alt, p_hpa, t_c)
    a, z = np.radians(alt), np.radians(az)
    dirs = np.stack([np.cos(a) * np.sin(z), np.cos(a) * np.cos(z), np.sin(a)], axis=-1)
    return dirs, alt



#: ICRS right ascension and declination [deg] of the north galactic pole and of the galactic centre (l = 0, b = 0)
#: of the IAU 1958 galactic coordinates as the Hipparcos catalogue defines them in the ICRS (ESA 1997, Vol. 1,
#: Sect. 1.5.3: alpha_G = 192.85948 deg, delta_G = 27.12825 deg, l_Omega = 32.93192 deg).
GALACTIC_POLE_RA_DEC_DEG = (192.85948, 27.12825)
GALACTIC_CENTRE_RA_DEC_DEG = (266.40500, -28.93617)



def galactic_coordinates(directions_enu, time, lat, lon, height_m=0.0):
    """Galactic latitude and longitude [deg] of directions in an observer's ENU frame.

    The north galactic pole and the galactic centre (:data:`GALACTIC_POLE_RA_DEC_DEG`,
    :data:`GALACTIC_CENTRE_RA_DEC_DEG`) are placed in the sky like stars (:func:`apparent_altaz`, no refraction);
    b = asin(d . p), l = atan2(d . (p x c), d . c) for each direction d, pole p and centre c (c made orthogonal to
    p). Precise to the apparent places' aberration (20 arcsec), far below the scale of the Milky Way's light.

    Parameters
    ----------
    directions_enu : array_like
        Shape (..., 3): unit vectors (east, north, up); NaN rows give NaN.
    time, lat, lon, height_m
        As :func:`apparent_altaz`.

    Returns
    -------
    galactic_latitude_deg, galactic_longitude_deg : numpy.ndarray
        Shape (...): b in [-90, 90] deg and l in [0, 360) deg.
    """
    ra = np.array([GALACTIC_POLE_RA_DEC_DEG[0], GALACTIC_CENTRE_RA_DEC_DEG[0]])
    dec = np.array([GALACTIC_POLE_RA_DEC_DEG[1], GALACTIC_CENTRE_RA_DEC_DEG[1]])
    alt, az = np.radians(apparent_altaz(ra, dec, time, lat, lon, height_m))
    axes = np.stack([np.cos(alt) * np.sin(az), np.cos(alt) * np.cos(az), np.sin(alt)], axis=-1)
    pole, centre = axes[0], axes[1] - np.dot(axes[1], axes[0]) * axes[0]
    centre /= np.linalg.norm(centre)
    d = np.asarray(directions_enu, dtype=float)
    b = np.degrees(np.arcsin(np.clip(d @ pole, -1.0, 1.0)))
    lon_gal = np.degrees(np.arctan2(d @ np.cross(pole, centre), d @ centre)) % 360.0
    return b, lon_gal
