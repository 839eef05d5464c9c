"""Satellite views: reflectance factor images and render settings for nadir / geostationary views.

Reflectance factor
------------------
The bidirectional reflectance factor of a space view (as in satellite level-1 "reflectance" products, e.g.
the paper's comparison with DSCOVR EPIC red-band reflectance, Sect. 4.2.2 and Table 4) is

    R = pi L / (mu0 E_TOA),

with L the radiance leaving the top of the atmosphere towards the sensor, E_TOA the solar irradiance at
normal incidence at the top of the atmosphere and mu0 the cosine of the **local** solar zenith angle at the
ground point seen. swim's images hold the solar-relative radiance L' = 4 pi L / E_TOA (paper Eq. 2), so

    R = L' / (4 mu0).

A white Lambertian surface lit at mu0 without atmosphere has L' = 4 mu0 and therefore R = 1 (albedo a:
R = a). mu0 is computed per pixel (:func:`ground_points`): the pixel's view ray (from the image's observer
position and view directions; spherical earth of radius :data:`swim.constants.EARTH_RADIUS_M`) is
intersected with the sphere at ``surface_height_m`` (default sea level; terrain is ignored) and mu0 is the
dot product of the sun direction with the local vertical there. Pixels whose ray misses the earth (space
beyond the limb) or whose ground point is in darkness (mu0 <= ``min_mu0``) are NaN. The sun direction is
the image's ``sun_azimuth_deg``/``sun_zenith_deg`` in the observer's ENU frame (:func:`swim.render`
attributes); the sun is at infinity, so the direction is the same everywhere.

Viewing geometry
----------------
:func:`geostationary_view` and :func:`nadir_view` return keyword arguments for :func:`swim.render`: a
:class:`~swim.geometry.cameras.PerspectiveCamera` at the satellite's position pointing at a target (by
default the scene's reference point) with a field of view that covers the scene
(:func:`~swim.geometry.cameras.fov_to_fit` of the largest distance of a scene column from the target). The
geostationary radius is 42 164 km from the earth's centre: a height of 35 786 km above the equator.

References
----------
Albers, S. et al. (2020), Atmos. Meas. Tech. 13, 3235-3261, doi:10.5194/amt-13-3235-2020 (Eq. 2; Sect. 4.2.2).
Schaepman-Strub, G. et al. (2006): Reflectance quantities in optical remote sensing - definitions and case
studies, Remote Sens. Environ. 103, 27-42, doi:10.1016/j.rse.2006.03.002.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import xarray as xr

from .. import frames
from ..constants import EARTH_RADIUS_M
from ..errors import SwimInputError
from ..geometry.cameras import _as_float, _as_int, fov_to_fit, look_at_angles

__all__ = [
    "GEOSTATIONARY_HEIGHT_M",
    "reflectance_from_radiance",
    "ground_points",
    "reflectance_factor",
    "geostationary_view",
    "nadir_view",
]

log = logging.getLogger(__name__)

#: Height [m] of the geostationary orbit above the equator (radius 42 164 km).
GEOSTATIONARY_HEIGHT_M = 35_786_000.0


def reflectance_from_radiance(radiance, mu0, min_mu0: float = 0.0) -> np.ndarray:
    """Reflectance factor R = L' / (4 mu0) [-] from solar-relative radiance L' [-] (module docstring).

    Parameters
    ----------
    radiance : array_like
        L' = 4 pi L / E_TOA [-], any shape broadcastable with ``mu0`` (e.g. (wavelength, y, x)).
    mu0 : array_like
        Cosine of the local solar zenith angle at the ground point seen [-].
    min_mu0 : float, default 0
        R is NaN where mu0 <= min_mu0 (night, or grazing sun where R diverges), in [0, 1).

    Returns
    -------
    numpy.ndarray
        R [-], broadcast shape.

    Raises
    ------
    SwimInputError
        If ``min_mu0`` is outside [0, 1).
    """
    m = _as_float("min_mu0", min_mu0, 0.0, 1.0, hi_open=True, unit="-")
    L = np.asarray(radiance, dtype=float)
    mu = np.asarray(mu0, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(mu > m, L / (4.0 * np.where(mu > m, mu, 1.0)), np.nan)


def _view_directions(image: xr.Dataset) -> np.ndarray:
    """ENU view directions (y, x, 3) of an image: exact from its camera attributes, else from its view angles."""
    from .compare import swim_camera_of

    try:
        dirs, valid = swim_camera_of(image).directions()
        return np.where(valid[..., None], dirs, np.nan)
    except SwimInputError:
        if "view_azimuth" not in image or "view_zenith" not in image:
            raise SwimInputError("image needs view_azimuth/view_zenith [deg] or camera attributes") from None
        return frames.enu_from_azimuth_zenith(np.asarray(image["view_azimuth"].values, dtype=float),
                                              np.asarray(image["view_zenith"].values, dtype=float))


def ground_points(image: xr.Dataset, surface_height_m: float = 0.0) -> xr.Dataset:
    """Ground point seen by each pixel of a :func:`swim.render` image and the local sun there.

    Parameters
    ----------
    image : xarray.Dataset
        With the attributes ``observer_lat``, ``observer_lon`` [deg], ``observer_height_asl_m`` [m],
        ``sun_azimuth_deg``, ``sun_zenith_deg`` [deg] (observer frame) and camera attributes or
        ``view_azimuth``, ``view_zenith`` (y, x) [deg].
    surface_height_m : float, default 0
        Height of the spherical surface intersected [m above sea level], below the observer.

    Returns
    -------
    xarray.Dataset
        (y, x): ``mu0`` (cosine of the local solar zenith angle [-]), ``ground_lat``, ``ground_lon`` [deg],
        ``distance`` [m] from the observer; NaN where the ray misses the surface.

    Raises
    ------
    SwimInputError
        If attributes are missing or the observer is not above the surface.
    """
    try:
        lat = float(image.attrs["observer_lat"])
        lon = float(image.attrs["observer_lon"])
        h = float(image.attrs["observer_height_asl_m"])
        sun_az = float(image.attrs["sun_azimuth_deg"])
        sun_zen = float(image.attrs["sun_zenith_deg"])
    except KeyError as err:
        raise SwimInputError(f"image lacks the attribute {err.args[0]!r} (render it with swim.render)") from None
    hs = _as_float("surface_height_m", surface_height_m, -EARTH_RADIUS_M, None, lo_open=True, unit="m")
    if not h > hs:
        raise SwimInputError(f"observer height {h} m must be above surface_height_m={hs} m")
    dirs = _view_directions(image)
    # scene frame with the observer as reference: its ENU frame is the observer's, its position (0, 0, R + h)
    origin = np.array([0.0, 0.0, EARTH_RADIUS_M + h])
    near, _ = frames.ray_sphere_intersections(origin, dirs, EARTH_RADIUS_M + hs)
    hit = np.isfinite(near) & (near > 0)
    s = np.where(hit, near, np.nan)
    p = origin + s[..., None] * dirs
    up = p / np.linalg.norm(p, axis=-1, keepdims=True)
    sun = frames.enu_from_azimuth_zenith(sun_az, sun_zen)
    mu0 = up @ sun
    glat, glon, _ = frames.scene_to_geodetic(np.where(hit[..., None], p, origin), lat, lon)
    dims = ("y", "x")
    return xr.Dataset(
        {
            "mu0": (dims, np.where(hit, mu0, np.nan), {"units": "1", "long_name": "cosine of the local solar zenith"}),
            "ground_lat": (dims, np.where(hit, glat, np.nan), {"units": "degree_north"}),
            "ground_lon": (dims, np.where(hit, glon, np.nan), {"units": "degree_east"}),
            "distance": (dims, s, {"units": "m", "long_name": "distance from the observer to the ground point"}),
        },
        attrs={"surface_height_m": hs},
    )


def reflectance_factor(image: xr.Dataset, *, surface_height_m: float = 0.0, min_mu0: float = 0.01,
                       variable: str = "radiance") -> xr.Dataset:
    """Reflectance factor images R = L' / (4 mu0) per wavelength of a space view (module docstring).

    Parameters
    ----------
    image : xarray.Dataset
        :func:`swim.render` output (``radiance`` (wavelength, y, x) [1] and its attributes).
    surface_height_m : float, default 0
        Height of the surface on which mu0 is evaluated [m above sea level].
    min_mu0 : float, default 0.01
        R is NaN where mu0 <= min_mu0 [-].
    variable : str, default "radiance"
        Radiance variable to convert (e.g. ``"radiance_surface"``).

    Returns
    -------
    xarray.Dataset
        ``reflectance_factor`` (wavelength, y, x) [1] and the fields of :func:`ground_points`.

    Raises
    ------
    SwimInputError
        If the variable or the geometry attributes are missing.
    """
    if variable not in image:
        raise SwimInputError(f"image has no variable {variable!r} (solar-relative radiance L' [1])")
    ground = ground_points(image, surface_height_m)
    radiance = image[variable].transpose(..., "y", "x")
    refl = reflectance_from_radiance(radiance.values, ground["mu0"].values, min_mu0)
    out = ground.copy()
    out["reflectance_factor"] = (radiance.dims, refl, {
        "units": "1", "long_name": "reflectance factor pi L / (mu0 E_TOA) = L' / (4 mu0)"})
    if "wavelength" in image.coords:
        out = out.assign_coords(wavelength=image["wavelength"])
    out.attrs.update(min_mu0=float(min_mu0), source_variable=variable)
    return out


def _scene_target(scene: xr.Dataset | None, target_lat, target_lon):
    """Target lat/lon [deg] (default the scene's reference point)."""
    if target_lat is None or target_lon is None:
        if scene is None:
            raise SwimInputError("give target_lat and target_lon [deg] or a scene (its reference point is the target)")
        target_lat = scene.attrs["reference_lat"] if target_lat is None else target_lat
        target_lon = scene.attrs["reference_lon"] if target_lon is None else target_lon
    return (_as_float("target_lat", target_lat, -90.0, 90.0), _as_float("target_lon", target_lon))


def _half_extent(scene: xr.Dataset | None, half_extent_m, tlat: float, tlon: float) -> float:
    """Largest distance [m] of a scene column from the target (or the given half extent)."""
    if half_extent_m is not None:
        return _as_float("half_extent_m", half_extent_m, 0.0, None, lo_open=True, unit="m")
    if scene is None or "lat" not in scene or "lon" not in scene:
        raise SwimInputError("give half_extent_m [m] or a scene with lat/lon columns")
    lat = np.asarray(scene["lat"].values, dtype=float)
    lon = np.asarray(scene["lon"].values, dtype=float)
    p = frames.geodetic_to_scene(lat, lon, 0.0, tlat, tlon)
    return float(max(np.max(np.hypot(p[..., 0], p[..., 1])), 1.0))


def _view_kwargs(sat_lat: float, sat_lon: float, sat_height: float, tlat: float, tlon: float, target_height: float,
                 half_extent: float, size: int, margin: float) -> dict[str, Any]:
    az, zen = look_at_angles(sat_lat, sat_lon, sat_height, tlat, tlon, target_height)
    p_sat = frames.geodetic_to_scene(sat_lat, sat_lon, sat_height, sat_lat, sat_lon)
    p_tgt = frames.geodetic_to_scene(tlat, tlon, target_height, sat_lat, sat_lon)
    distance = float(np.linalg.norm(p_tgt - p_sat))
    # the target must be the first point of the earth on the line of sight (not behind the limb)
    d = (p_tgt - p_sat) / distance
    near, _ = frames.ray_sphere_intersections(p_sat, d, EARTH_RADIUS_M + min(target_height, 0.0))
    if np.isfinite(near) and near < distance - max(1.0, 1e-6 * distance):
        raise SwimInputError(f"the target ({tlat}, {tlon}) is beyond the earth's limb seen from the satellite at "
                             f"({sat_lat}, {sat_lon}, {sat_height} m)")
    if zen < 90.0:
        raise SwimInputError("the target is above the satellite: nothing to look down at")
    fov = fov_to_fit(distance, half_extent, margin)
    return {
        "lat": float(sat_lat),
        "lon": float(sat_lon),
        "height": float(sat_height),
        "camera": "perspective",
        "camera_options": {"width": size, "height": size, "fov_deg": fov, "view_azimuth_deg": az,
                           "view_zenith_deg": zen},
    }


def geostationary_view(sub_satellite_lon: float, scene: xr.Dataset | None = None, *, target_lat=None,
                       target_lon=None, target_height_m: float = 0.0, size: int = 256, half_extent_m=None,
                       margin: float = 1.2, satellite_height_m: float = GEOSTATIONARY_HEIGHT_M) -> dict[str, Any]:
    """Keyword arguments of :func:`swim.render` for a geostationary satellite's view of a scene.

    The observer is at latitude 0, longitude ``sub_satellite_lon``, ``satellite_height_m`` above sea level
    (render's ``height`` is above the ground; the sub-satellite point is far outside any model domain,
    where swim takes the ground at sea level). The perspective camera (square, ``size`` pixels) points at the
    target with :func:`~swim.geometry.cameras.look_at_angles`, with a field of view that shows the scene
    (``fov_to_fit(distance, half_extent_m, margin)``; the oblique view foreshortens the scene, so this is
    generous across the line of sight). For an odd ``size`` the centre pixel looks exactly at the target.

    Parameters
    ----------
    sub_satellite_lon : float
        Longitude of the sub-satellite point [deg], e.g. -75.2 (GOES-East), -137.2 (GOES-West), 0 (Meteosat).
    scene : xarray.Dataset, optional
        Scene whose reference point is the default target and whose columns set the default half extent.
    target_lat, target_lon : float, optional
        Target [deg]; default the scene's reference point.
    target_height_m : float, default 0
        Target height [m above sea level].
    size : int, default 256
        Image width and height [px].
    half_extent_m : float, optional
        Half the extent to fit in the view [m]; default the largest distance of a scene column from the target.
    margin : float, default 1.2
        Factor on the half extent [-].
    satellite_height_m : float
        Orbit height above sea level [m], > 100 km.

    Returns
    -------
    dict
        ``lat``, ``lon``, ``height``, ``camera="perspective"``, ``camera_options`` (``width``, ``height``,
        ``fov_deg``, ``view_azimuth_deg``, ``view_zenith_deg``): ``swim.render(scene, **kwargs)``.

    Raises
    ------
    SwimInputError
        For out-of-range values, a target beyond the limb, or no way to set the target or extent.
    """
    lon = _as_float("sub_satellite_lon", sub_satellite_lon)
    h = _as_float("satellite_height_m", satellite_height_m, 100e3, None, lo_open=True, unit="m")
    tlat, tlon = _scene_target(scene, target_lat, target_lon)
    th = _as_float("target_height_m", target_height_m, -1e4, 1e5, unit="m")
    n = _as_int("size", size)
    half = _half_extent(scene, half_extent_m, tlat, tlon)
    kwargs = _view_kwargs(0.0, lon, h, tlat, tlon, th, half, n, margin)
    log.info("geostationary view from %.2f E: %s", lon, kwargs["camera_options"])
    return kwargs


def nadir_view(scene: xr.Dataset | None = None, *, lat=None, lon=None, height_m: float = 705_000.0, size: int = 256,
               half_extent_m=None, margin: float = 1.2) -> dict[str, Any]:
    """Keyword arguments of :func:`swim.render` for a view straight down from ``height_m`` above (lat, lon).

    The camera looks at the point below it (view zenith 180 deg; image up is north, east right, as a map);
    default position: the scene's reference point; default height 705 km (a polar orbiter such as
    Aqua/Terra). The field of view fits the scene as in :func:`geostationary_view`.

    Parameters
    ----------
    scene : xarray.Dataset, optional
        Scene (reference point and extent).
    lat, lon : float, optional
        Sub-satellite point [deg].
    height_m : float, default 705 000
        Height above sea level [m], > 100 km.
    size : int, default 256
        Image width and height [px].
    half_extent_m : float, optional
        Half the extent to show [m].
    margin : float, default 1.2
        Factor on the half extent [-].

    Returns
    -------
    dict
        As :func:`geostationary_view`.

    Raises
    ------
    SwimInputError
        For out-of-range values or missing position/extent.
    """
    h = _as_float("height_m", height_m, 100e3, None, lo_open=True, unit="m")
    tlat, tlon = _scene_target(scene, lat, lon)
    n = _as_int("size", size)
    half = _half_extent(scene, half_extent_m, tlat, tlon)
    fov = fov_to_fit(h, half, margin)
    return {
        "lat": tlat, "lon": tlon, "height": h, "camera": "perspective",
        "camera_options": {"width": n, "height": n, "fov_deg": fov, "view_azimuth_deg": 0.0,
                           "view_zenith_deg": 180.0},
    }
