"""Sun position: zenith, azimuth and earth-sun distance for a time and place, or given directly.

Conventions (:mod:`swim.frames`, ``docs/frames.md``): azimuth [deg] clockwise from north (N 0, E 90, S 180,
W 270, as pvlib), zenith angle [deg] from the local vertical, and the sun direction is the unit vector in the
observer's local ENU frame pointing *towards* the sun.

The top-of-atmosphere solar irradiance scales with the inverse square of the earth-sun distance ``r`` [AU]:
``E_TOA = S0 / r**2`` with ``S0`` = :data:`swim.constants.SOLAR_CONSTANT_W_M2` (Albers et al. 2020, AMT 13,
3235-3261, Sect. 3.1); :attr:`SunPosition.irradiance_factor` is ``1 / r**2``.

Sources: Reda, I. and Andreas, A. (2004): Solar position algorithm for solar radiation applications, Solar
Energy 76, 577-589, doi:10.1016/j.solener.2003.12.003 (corrigendum: Solar Energy 81, 838, 2007), as
implemented by ``pvlib.solarposition.get_solarposition(method="nrel_numpy")`` and
``pvlib.solarposition.nrel_earthsun_distance`` (Holmgren et al. 2018, JOSS 3, 884).
"""

from __future__ import annotations

import functools
import logging
import math
import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from .. import frames
from ..errors import SwimInputError

__all__ = ["SunPosition", "SUN_SOURCES", "DELTA_T_S", "sun_position", "sun_from_angles", "parse_time_utc"]

logger = logging.getLogger(__name__)

#: Allowed values of :attr:`SunPosition.source`.
SUN_SOURCES = ("pvlib-spa", "override")

#: Difference TT - UT1 [s] passed to the SPA (pvlib's default). The true value was 64-69 s in 2000-2025; an
#: error of a few seconds shifts the sun by ~0.004 deg per second of time, far below the solar radius
#: (0.27 deg).
DELTA_T_S = 67.0

_TIME_FORMAT_HINT = "an ISO 8601 date-time such as '2024-06-21T12:00:00Z' (naive times are taken as UTC)"


def parse_time_utc(time: Any, name: str = "time") -> pd.Timestamp:
    """A single instant as a timezone-aware UTC :class:`pandas.Timestamp`.

    Parameters
    ----------
    time : str, datetime.datetime, datetime.date, numpy.datetime64 or pandas.Timestamp
        The instant. Strings are ISO 8601 (e.g. ``"2024-06-21T12:00:00Z"``, ``"2024-06-21 14:00+02:00"``).
        Naive times (no UTC offset) are taken as UTC; aware ones are converted to UTC.
    name : str, default "time"
        Parameter name used in error messages.

    Returns
    -------
    pandas.Timestamp
        Timezone-aware, UTC.

    Raises
    ------
    SwimInputError
        If ``time`` is missing (None, NaT), not a single instant, or cannot be parsed.
    """
    if time is None or isinstance(time, (bool, numbers.Number)) or (
        isinstance(time, np.ndarray) and time.ndim != 0
    ) or isinstance(time, (list, tuple, pd.Index, pd.Series)):
        raise SwimInputError(f"{name} must be a single instant, {_TIME_FORMAT_HINT}; got {time!r}")
    try:
        ts = pd.Timestamp(time)
    except (ValueError, TypeError, OverflowError) as exc:
        raise SwimInputError(
            f"{name} could not be parsed ({exc}); expected {_TIME_FORMAT_HINT}; got {time!r}"
        ) from None
    if ts is pd.NaT or pd.isna(ts):
        raise SwimInputError(f"{name} is missing (NaT); expected {_TIME_FORMAT_HINT}; got {time!r}")
    if ts.tzinfo is None:
        ts = ts.tz_localize("UTC")
    else:
        ts = ts.tz_convert("UTC")
    return ts


def _real(name: str, value: Any, lo: float | None = None, hi: float | None = None, unit: str = "deg") -> float:
    """Finite float in the closed range [lo, hi] or :class:`SwimInputError`."""
    if isinstance(value, bool):
        raise SwimInputError(f"{name} must be a real number [{unit}], got {value!r}")
    try:
        v = float(np.asarray(value, dtype=float).item())
    except (TypeError, ValueError):
        raise SwimInputError(f"{name} must be a single real number [{unit}], got {value!r}") from None
    rng = f"[{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]"
    if not math.isfinite(v) or (lo is not None and v < lo) or (hi is not None and v > hi):
        raise SwimInputError(f"{name} must be finite and in {rng} [{unit}], got {v}")
    return v


@dataclass(frozen=True)
class SunPosition:
    """Position of the sun seen from an observer.

    Parameters
    ----------
    zenith_deg : float
        Geometric (unrefracted) solar zenith angle [deg], in [0, 180].
    azimuth_deg : float
        Solar azimuth [deg], clockwise from north; any finite value, stored wrapped into [0, 360).
    earth_sun_distance_au : float
        Earth-sun distance [AU], > 0.
    time : pandas.Timestamp or None
        The instant (UTC), or None for an override.
    source : str
        ``"pvlib-spa"`` (computed by :func:`sun_position`) or ``"override"`` (:func:`sun_from_angles`).

    Raises
    ------
    SwimInputError
        For values outside the ranges above.
    """

    zenith_deg: float
    azimuth_deg: float
    earth_sun_distance_au: float
    time: pd.Timestamp | None
    source: str

    def __post_init__(self) -> None:
        object.__setattr__(self, "zenith_deg", _real("zenith_deg", self.zenith_deg, 0.0, 180.0))
        object.__setattr__(self, "azimuth_deg", _real("azimuth_deg", self.azimuth_deg) % 360.0)
        dist = _real("earth_sun_distance_au", self.earth_sun_distance_au, unit="AU")
        if not dist > 0.0:
            raise SwimInputError(f"earth_sun_distance_au must be > 0 [AU] (about 0.983-1.017), got {dist}")
        object.__setattr__(self, "earth_sun_distance_au", dist)
        if self.time is not None:
            object.__setattr__(self, "time", parse_time_utc(self.time))
        if self.source not in SUN_SOURCES:
            raise SwimInputError(f"source must be one of {SUN_SOURCES}, got {self.source!r}")

    @property
    def elevation_deg(self) -> float:
        """Geometric solar elevation ``90 - zenith_deg`` [deg]."""
        return 90.0 - self.zenith_deg

    @property
    def direction_enu(self) -> np.ndarray:
        """Unit vector (east, north, up) [-] towards the sun in the observer's ENU frame, shape ``(3,)``."""
        return frames.enu_from_azimuth_zenith(self.azimuth_deg, self.zenith_deg)

    @property
    def irradiance_factor(self) -> float:
        """``1 / r**2`` [-]: scaling of the 1-AU top-of-atmosphere irradiance (paper, Sect. 3.1)."""
        return 1.0 / self.earth_sun_distance_au**2

    def to_attrs(self) -> dict[str, Any]:
        """Plain scalars and strings describing the sun (for netCDF attributes); keys start with ``sun_``."""
        return {
            "sun_zenith_deg": float(self.zenith_deg),
            "sun_azimuth_deg": float(self.azimuth_deg),
            "sun_earth_sun_distance_au": float(self.earth_sun_distance_au),
            "sun_time_utc": "" if self.time is None else self.time.strftime("%Y-%m-%dT%H:%M:%S.%fZ"),
            "sun_source": self.source,
            "sun_angles": "geometric (no refraction); azimuth clockwise from north",
        }


def sun_position(time, lat, lon, altitude_m=0.0) -> SunPosition:
    """Solar position at an instant and place with the NREL SPA (via pvlib).

    The zenith angle is the *geometric* (topocentric, unrefracted) one, pvlib's ``zenith`` column, not the
    refraction-corrected ``apparent_zenith``: the radiative transfer traces straight rays through the
    atmosphere, so the direction of the incident sunlight must be the unrefracted one (refraction lifts the
    sun by ~0.5 deg at the horizon and ~0.02 deg at 40 deg elevation). Hence pressure and temperature, which
    only enter the refraction correction, do not matter here. ``delta_t`` = :data:`DELTA_T_S`.

    Parameters
    ----------
    time : str, datetime.datetime, numpy.datetime64 or pandas.Timestamp
        The instant, one value. Strings are ISO 8601 (e.g. ``"2024-06-21T12:00:00Z"``); naive times are UTC.
    lat : float
        Observer latitude [deg], in [-90, 90].
    lon : float
        Observer longitude [deg], east positive; any finite value (wrapped into [-180, 180)).
    altitude_m : float, default 0.0
        Observer height above sea level [m], in [-1000, 100000] (enters the topocentric parallax only).

    Returns
    -------
    SunPosition
        With ``source="pvlib-spa"`` and ``time`` the UTC instant.

    Raises
    ------
    SwimInputError
        If ``time`` cannot be parsed (expected ISO 8601) or a coordinate is out of range.

    References
    ----------
    Reda and Andreas (2004), Solar Energy 76, 577-589; pvlib ``get_solarposition`` and
    ``nrel_earthsun_distance``.
    """
    ts = parse_time_utc(time, "time")
    lat_v = _real("lat", lat, -90.0, 90.0)
    lon_v = (_real("lon", lon) + 180.0) % 360.0 - 180.0
    alt = _real("altitude_m", altitude_m, -1000.0, 100000.0, unit="m")
    return _spa(ts, lat_v, lon_v, alt)


@functools.lru_cache(maxsize=64)
def _spa(ts, lat_v, lon_v, alt) -> SunPosition:
    """:func:`sun_position` of validated arguments, remembered: a render asks for the same sun twice (the crop's and
    its own) and a series of frames often for the same instant, and pvlib's SPA takes ~8 ms a call
    (:class:`SunPosition` is immutable)."""
    import pvlib.solarposition as solpos  # lazy: pvlib pulls in scipy/pandas machinery

    index = pd.DatetimeIndex([ts])
    df = solpos.get_solarposition(index, lat_v, lon_v, altitude=alt, method="nrel_numpy", delta_t=DELTA_T_S)
    dist = solpos.nrel_earthsun_distance(index, delta_t=DELTA_T_S)
    zen = float(np.clip(df["zenith"].iloc[0], 0.0, 180.0))
    sun = SunPosition(
        zenith_deg=zen,
        azimuth_deg=float(df["azimuth"].iloc[0]),
        earth_sun_distance_au=float(np.asarray(dist)[0]),
        time=ts,
        source="pvlib-spa",
    )
    logger.debug(
        "sun at %s, lat %.4f lon %.4f alt %.0f m: zenith %.4f deg, azimuth %.4f deg, r %.6f AU",
        ts.isoformat(), lat_v, lon_v, alt, sun.zenith_deg, sun.azimuth_deg, sun.earth_sun_distance_au,
    )
    return sun


def sun_from_angles(zenith_deg, azimuth_deg, earth_sun_distance_au=1.0) -> SunPosition:
    """Sun position given directly (override of :func:`sun_position`).

    Parameters
    ----------
    zenith_deg : float
        Solar zenith angle [deg], in [0, 180].
    azimuth_deg : float
        Solar azimuth [deg] clockwise from north, any finite value (wrapped into [0, 360)).
    earth_sun_distance_au : float, default 1.0
        Earth-sun distance [AU], > 0.

    Returns
    -------
    SunPosition
        With ``source="override"`` and ``time=None``.

    Raises
    ------
    SwimInputError
        For values outside the ranges above.
    """
    return SunPosition(
        zenith_deg=zenith_deg,
        azimuth_deg=azimuth_deg,
        earth_sun_distance_au=earth_sun_distance_au,
        time=None,
        source="override",
    )
