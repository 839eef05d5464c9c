"""Frames and angle conventions: the one place where they are defined (see docs/frames.md).

Conventions
-----------
* **Azimuth** ``azimuth`` [deg]: clockwise from geographic north seen from above: N = 0, E = 90, S = 180,
  W = 270 (as pvlib).
* **Zenith angle** ``zenith`` [deg] from the local vertical; **elevation** = 90 - zenith.
* **Directions** are unit vectors pointing *away from the observer*: a view direction points from the
  observer to what it sees; the sun direction points from the observer *towards* the sun.
* **Scattering angle** theta between the incident sunlight (propagating along ``-sun``) and the light
  scattered towards the observer (propagating along ``-view``): ``cos(theta) = dot(sun, view)``;
  theta = 0 is forward scattering (looking at the sun), 180 deg is backscatter (the antisolar point).
* **Local ENU frame** at a point: x east, y north, z up.
* **Scene frame**: an earth-centred Cartesian frame [m] whose axes are the ENU axes at the scene's
  reference point (lat0, lon0), usually the centre of the model domain. The reference point at height h
  is ``(0, 0, R + h)``. The earth is a sphere of radius R = :data:`swim.constants.EARTH_RADIUS_M`.
* **Grid horizontal coordinates** (x, y) [m] of a point p: the scene X and Y of the point where the
  radius through p meets the sea-level sphere, ``(x, y) = R (p_x, p_y) / |p|``; its height is
  ``h = |p| - R``. For the columns of a model grid these equal the orthographic projection about
  (lat0, lon0) (:func:`orthographic_xy`).
"""

from __future__ import annotations

import functools

import numpy as np

from .constants import EARTH_RADIUS_M


def enu_from_azimuth_zenith(azimuth, zenith):
    """Unit vector in a local ENU frame from azimuth and zenith angle.

    Parameters
    ----------
    azimuth : array_like
        Azimuth [deg], clockwise from north.
    zenith : array_like
        Zenith angle [deg].

    Returns
    -------
    numpy.ndarray
        Shape ``broadcast(azimuth, zenith).shape + (3,)``: (east, north, up) components [-].
    """
    az = np.deg2rad(np.asarray(azimuth, dtype=float))
    ze = np.deg2rad(np.asarray(zenith, dtype=float))
    s = np.sin(ze)
    return np.stack(np.broadcast_arrays(s * np.sin(az), s * np.cos(az), np.cos(ze)), axis=-1)


def azimuth_zenith_from_enu(vector):
    """Azimuth and zenith angle [deg] of ENU vectors of shape ``(..., 3)`` (need not be unit length).

    Returns
    -------
    tuple of numpy.ndarray
        ``(azimuth, zenith)``, each of shape ``vector.shape[:-1]``; azimuth in [0, 360).
    """
    v = np.asarray(vector, dtype=float)
    norm = np.linalg.norm(v, axis=-1)
    azimuth = np.rad2deg(np.arctan2(v[..., 0], v[..., 1])) % 360.0
    zenith = np.rad2deg(np.arccos(np.clip(v[..., 2] / norm, -1.0, 1.0)))
    return azimuth, zenith


def _unit_earth_centred(lat, lon):
    """Earth-centred earth-fixed unit vector(s) (spherical earth), shape ``(..., 3)``."""
    la = np.deg2rad(np.asarray(lat, dtype=float))
    lo = np.deg2rad(np.asarray(lon, dtype=float))
    return np.stack(np.broadcast_arrays(np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)), axis=-1)


def enu_basis_ecef(lat, lon):
    """Rows east, north, up of the local ENU frame at (lat, lon) [deg] in earth-centred coordinates.

    Returns
    -------
    numpy.ndarray
        Shape ``(..., 3, 3)``; ``[..., 0, :]`` is east, ``[..., 1, :]`` north, ``[..., 2, :]`` up.
    """
    if np.ndim(lat) == 0 and np.ndim(lon) == 0:
        return _enu_basis_ecef_at(float(lat), float(lon)).copy()
    return _enu_basis_ecef(lat, lon)


@functools.lru_cache(maxsize=64)
def _enu_basis_ecef_at(lat, lon):
    """:func:`enu_basis_ecef` of one point, remembered: a render asks for the same few points (observer, scene
    reference) several times, ~25 us each with NumPy on scalars (docs/decisions/0009-work-around-the-march.md)."""
    return _enu_basis_ecef(lat, lon)


def _enu_basis_ecef(lat, lon):
    la = np.deg2rad(np.asarray(lat, dtype=float))
    lo = np.deg2rad(np.asarray(lon, dtype=float))
    la, lo = np.broadcast_arrays(la, lo)
    east = np.stack([-np.sin(lo), np.cos(lo), np.zeros_like(lo)], axis=-1)
    north = np.stack([-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)], axis=-1)
    up = np.stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)], axis=-1)  # la, lo in rad
    return np.stack([east, north, up], axis=-2)


def geodetic_to_scene(lat, lon, height, lat0, lon0, radius=EARTH_RADIUS_M):
    """Scene-frame position [m] of points given by latitude, longitude [deg] and height [m] above sea level.

    Parameters
    ----------
    lat, lon, height : array_like
        Broadcastable arrays: latitude [deg], longitude [deg], height above the sea-level sphere [m].
    lat0, lon0 : float
        Reference point of the scene frame [deg].

    Returns
    -------
    numpy.ndarray
        Shape ``broadcast.shape + (3,)`` [m].
    """
    ecef = _unit_earth_centred(lat, lon) * (radius + np.asarray(height, dtype=float))[..., None]
    return ecef @ enu_basis_ecef(lat0, lon0).T


def scene_to_geodetic(position, lat0, lon0, radius=EARTH_RADIUS_M):
    """Inverse of :func:`geodetic_to_scene`: ``(lat [deg], lon [deg], height [m])`` of ``(..., 3)`` points."""
    p = np.asarray(position, dtype=float)
    ecef = p @ enu_basis_ecef(lat0, lon0)
    r = np.linalg.norm(ecef, axis=-1)
    lat = np.rad2deg(np.arcsin(np.clip(ecef[..., 2] / r, -1.0, 1.0)))
    lon = np.rad2deg(np.arctan2(ecef[..., 1], ecef[..., 0]))
    lon = (lon + 180.0) % 360.0 - 180.0
    return lat, lon, r - radius


def enu_to_scene_rotation(lat, lon, lat0, lon0):
    """Matrix M of shape (3, 3) with ``v_scene = v_enu @ M`` for directions at (lat, lon) [deg]."""
    return enu_basis_ecef(lat, lon) @ enu_basis_ecef(lat0, lon0).T


def orthographic_xy(lat, lon, lat0, lon0, radius=EARTH_RADIUS_M):
    """Grid horizontal coordinates (x east, y north) [m] of sea-level points: orthographic projection about (lat0, lon0).

    Returns
    -------
    tuple of numpy.ndarray
        ``(x, y)`` with the broadcast shape of ``lat`` and ``lon``.
    """
    p = geodetic_to_scene(lat, lon, 0.0, lat0, lon0, radius)
    return p[..., 0], p[..., 1]


def scattering_angle_cosine(sun_direction, view_direction):
    """cos(theta) of the scattering angle (see module conventions): ``dot(sun, view)`` over the last axis."""
    return np.sum(np.asarray(sun_direction) * np.asarray(view_direction), axis=-1)


def ray_sphere_intersections(origin, direction, radius):
    """Distances [m] along rays ``origin + s * direction`` to a sphere of ``radius`` centred on the origin of the frame.

    Parameters
    ----------
    origin, direction : numpy.ndarray
        Shape ``(..., 3)``; ``direction`` must be unit length.
    radius : float or numpy.ndarray
        Sphere radius [m].

    Returns
    -------
    tuple of numpy.ndarray
        ``(s_near, s_far)``; NaN where the ray's line misses the sphere.
    """
    origin, direction = np.asarray(origin, dtype=float), np.asarray(direction, dtype=float)
    # einsum, not np.sum over the axis of 3: ~4x faster on (n, 3) arrays (a render's ray segments)
    b = np.einsum("...i,...i->...", origin, direction)
    c = np.einsum("...i,...i->...", origin, origin) - radius**2
    disc = b * b - c
    root = np.sqrt(np.where(disc >= 0, disc, np.nan))
    return -b - root, -b + root
