"""The naked-eye planets: Mercury, Venus, Mars, Jupiter and Saturn as point sources, with their apparent, refracted
places in the sky, their V magnitudes and colours for a time and place.

Places. The topocentric apparent place (light time, aberration, light deflection, precession and nutation) of each
planet from the JPL ephemeris DE421 (Folkner et al. 2008) through Skyfield (Rhodes 2019), read from the copy that
``skyfield-data`` ships (nothing is downloaded). DE421 there holds the bodies Mercury (199), Venus (299) and Mars
(499) and the barycentres of the Jupiter and Saturn systems (5, 6), which stand for the planets: the barycentre lies
within a few thousand km of the planet's centre (Jupiter: Galilean moons' mass 2e-4 of Jupiter's), under 0.01 arcsec
seen from the earth. Astronomical refraction then lifts each planet as it lifts the stars
(:func:`swim.geometry.stars.refracted_directions`).

Magnitudes. The apparent V magnitude from the planet's heliocentric distance r, its distance from the observer and
its phase angle by the formulae of Mallama & Hilton (2018) that the Astronomical Almanac uses, as Skyfield implements
them (:func:`skyfield.magnitudelib.planetary_magnitude`; Saturn's includes its rings, with the ring tilts towards the
sun and the observer). Skyfield places the sun at the solar-system barycentre there, which changes r by at most
0.01 AU: 0.03 mag for Venus, less for the others. A planet whose formula has no value (Saturn's beyond a phase angle
of 6.5 deg, which an observer on the earth never sees) is left out, logged.

Colours. The planets' Johnson B-V (Harris 1961, as tabulated in Allen's Astrophysical Quantities): Mercury 0.93,
Venus 0.82, Mars 1.36, Jupiter 0.83, Saturn 1.04; the renderer turns B-V and V into spectral irradiance as for a
star (:func:`swim.rt.night_sky.star_irradiance`).

References
----------
Folkner, W. M., Williams, J. G. & Boggs, D. H. (2008), The planetary and lunar ephemeris DE 421, JPL IOM 343R-08-003.
Rhodes, B. (2019), Skyfield, Astrophysics Source Code Library, ascl:1907.024.
Mallama, A. & Hilton, J. L. (2018), Computing apparent planetary magnitudes for The Astronomical Almanac, Astronomy
and Computing 25, 10-24, doi:10.1016/j.ascom.2018.08.002.
Harris, D. L. (1961), Photometry and colorimetry of planets and satellites, in Planets and Satellites (G. P. Kuiper &
B. M. Middlehurst, eds.), University of Chicago Press, 272-342; Cox, A. N. (ed.) (2000), Allen's Astrophysical
Quantities, 4th ed., Springer (the planets' B-V).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..errors import SwimInputError
from .stars import _skyfield, refracted_directions
from .sun import parse_time_utc

log = logging.getLogger(__name__)

#: The naked-eye planets: (name, DE421 target in skyfield-data's kernel, Johnson B-V [mag] (Harris 1961)).
PLANETS = (
    ("Mercury", "mercury", 0.93),
    ("Venus", "venus", 0.82),
    ("Mars", "mars", 1.36),
    ("Jupiter", "jupiter barycenter", 0.83),
    ("Saturn", "saturn barycenter", 1.04),
)



@dataclass(frozen=True)
class PlanetSky:
    """The planets seen from a place at a time, each array of shape (n,).

    Attributes
    ----------
    names : tuple of str
    directions : numpy.ndarray
        Shape (n, 3): unit vectors (east, north, up) towards the apparent, refracted places.
    altitude_deg : numpy.ndarray
        Apparent (refracted) altitude [deg].
    azimuth_deg : numpy.ndarray
        Azimuth clockwise from north [deg].
    v_mag : numpy.ndarray
        Apparent V magnitude above the atmosphere [mag] (Mallama & Hilton 2018).
    b_minus_v : numpy.ndarray
        Johnson B-V [mag] (Harris 1961).
    phase_angle_deg : numpy.ndarray
        Sun-planet-observer angle [deg].
    """

    names: tuple
    directions: np.ndarray
    altitude_deg: np.ndarray
    azimuth_deg: np.ndarray
    v_mag: np.ndarray
    b_minus_v: np.ndarray
    phase_angle_deg: np.ndarray

    def __len__(self) -> int:
        return len(self.names)



def planet_sky(time, lat, lon, height_m=0.0, temperature_c=None) -> PlanetSky:
    """Mercury, Venus, Mars, Jupiter and Saturn at their apparent, refracted places, with V and B-V.

    Parameters
    ----------
    time : str, datetime, numpy.datetime64 or pandas.Timestamp
        UTC time, within DE421 (1900-2049).
    lat, lon : float
        Observer's geodetic latitude and longitude [deg] (WGS84).
    height_m : float
        Observer's height above sea level [m].
    temperature_c : float, optional
        Air temperature at the observer [degC] for the refraction; default the US Standard Atmosphere's.

    Returns
    -------
    PlanetSky
        All five planets, above the horizon or not (a planet without a magnitude is left out).

    Raises
    ------
    SwimInputError
        Bad time or a time outside DE421, an observer outside [-90, 90] deg latitude, or skyfield missing.

    References
    ----------
    Folkner et al. (2008) (DE421); Mallama & Hilton (2018), doi:10.1016/j.ascom.2018.08.002; Harris (1961).
    """
    from skyfield.api import wgs84
    from skyfield.magnitudelib import planetary_magnitude

    if not (np.isfinite(lat) and -90.0 <= lat <= 90.0 and np.isfinite(lon)):
        raise SwimInputError(f"observer lat/lon must be finite, lat in [-90, 90] deg; got {lat}, {lon}")
    when = parse_time_utc(time)
    if not 1900 <= when.year < 2050:
        raise SwimInputError(f"time must lie in 1900-2049 (the DE421 ephemeris), got {when.isoformat()}")
    ts, earth, kernel = _skyfield(with_kernel=True)
    t = ts.from_datetime(when.to_pydatetime())
    here = (earth + wgs84.latlon(float(lat), float(lon), elevation_m=float(height_m))).at(t)
    sun = kernel["sun"].at(t).position.au
    rows = []
    for name, target, b_minus_v in PLANETS:
        astrometric = here.observe(kernel[target])
        v = float(planetary_magnitude(astrometric))
        if not np.isfinite(v):
            log.info("%s left out: its magnitude formula has no value at this phase angle", name)
            continue
        alt, az, _ = astrometric.apparent().altaz()
        to_planet = astrometric.position.au
        from_sun = here.position.au + to_planet - sun
        cos_phase = np.dot(from_sun, to_planet) / (np.linalg.norm(from_sun) * np.linalg.norm(to_planet))
        rows.append((name, float(alt.degrees), float(az.degrees), v, b_minus_v,
                     float(np.degrees(np.arccos(np.clip(cos_phase, -1.0, 1.0))))))
    names = tuple(r[0] for r in rows)
    alt, az, v, bv, phase = (np.array([r[k] for r in rows], dtype=float).reshape(-1) for k in range(1, 6))
    directions, alt = refracted_directions(alt, az, height_m, temperature_c)
    log.debug("planets at %s: %s", when.isoformat(),
              ", ".join(f"{n} alt {a:.2f} V {m:.2f}" for n, a, m in zip(names, alt, v)))
    return PlanetSky(names, directions, alt, az, v, bv, phase)
