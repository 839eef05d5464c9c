"""Moonlight: a render lit by the moon instead of the sun (:func:`swim.render`'s ``light="moon"``).

The moon takes the sun's place in every stage (docs/rendering.md, "Moonlight"): its direction lights Step 1a, the
clear-sky tables, the 3-D diffuse field, the ground and the march, exactly as the sun's would. That render, in the
units of a light of the sun's spectrum and irradiance, is then scaled per wavelength by the moon's top-of-atmosphere
irradiance relative to the sun's (:func:`swim.geometry.moon.lunar_irradiance_ratio`, about 2.5e-6 at full moon), so
the image's radiance stays the solar-relative L' = 4 pi L / E_TOA of Albers et al. (2020), Eq. 2, of the moonlit sky.
The moon's disk is drawn with its phase (:func:`moon_disk`) where the image resolves it; the lunar aureole is the
scattering's own (the aerosol's and the clouds' forward peaks), as the sun's is.
"""

from __future__ import annotations

import logging

import numpy as np

from ..errors import SwimInputError
from ..geometry.moon import (MoonPosition, lunar_irradiance, lunar_irradiance_ratio, moon_position,
                             solar_irradiance_at_channels)
from ..geometry.sun import sun_position
from ..optics.cloud_phase import AUREOLE_HALF_ANGLE_RAD
from .arguments import fixed_white_level, resolve_sun
from .sun_disk import sun_disk, with_the_sun

log = logging.getLogger(__name__)

#: The lights a render can be lit by (:func:`swim.render`'s ``light``; a :class:`MoonPosition` is a moon too).
LIGHTS = ("sun", "moon")

#: The disk is drawn with its phase where its angular radius spans at least this many pixels; a smaller disk is a
#: few pixels of its mean radiance, as the sun's is.
RESOLVED_DISK_PIXELS = 1.5

#: Sun elevations [deg] above which a moonlit render logs that the twilight (or daylight) it leaves out is there:
#: the end of astronomical twilight.
TWILIGHT_ELEVATION_DEG = -18.0


def check_light(light):
    """``light`` checked: "sun", "moon" or a :class:`swim.geometry.moon.MoonPosition` (returned as given).

    Raises
    ------
    SwimInputError
        For anything else.
    """
    if isinstance(light, MoonPosition) or (isinstance(light, str) and light in LIGHTS):
        return light
    raise SwimInputError(f"light must be one of {LIGHTS} or a swim.geometry.moon.MoonPosition; got {light!r}")


def is_moon(light) -> bool:
    """Whether ``light`` (checked by :func:`check_light`) is the moon."""
    return isinstance(light, MoonPosition) or light == "moon"


def resolve_light(request, scene):
    """The render's light at the scene's reference point: the sun (:func:`swim.pipeline.arguments.resolve_sun`), or
    the moon for ``request.light`` "moon" (:func:`swim.geometry.moon.moon_position` at the time) or a
    :class:`MoonPosition` (used as it is). ``request``: a :class:`swim.pipeline.chain.RenderRequest`.

    Raises
    ------
    SwimInputError
        A bad ``light``; sun angles with the moon; no time for the moon.
    """
    light = check_light(getattr(request, "light", "sun"))
    if not is_moon(light):
        return resolve_sun(request.time, scene, request.sun_zenith, request.sun_azimuth)
    if request.sun_zenith is not None or request.sun_azimuth is not None:
        raise SwimInputError("sun_zenith/sun_azimuth set the sun; with light='moon' the moon's place comes from the "
                             "time (or pass light=swim.geometry.moon.moon_from_angles(...))")
    lat0, lon0 = float(scene.attrs["reference_lat"]), float(scene.attrs["reference_lon"])
    moon = light
    if not isinstance(light, MoonPosition):
        time = request.time
        if time is None:
            if "time" not in scene.coords:
                raise SwimInputError("light='moon' needs the time: pass time (ISO 8601, UTC); the scene has no 'time'")
            time = scene["time"].values
        moon = moon_position(time, lat0, lon0)
    if moon.zenith_deg > 90:
        log.warning("moon is %.1f deg below the horizon: a dark sky (the night sky alone)", moon.zenith_deg - 90)
    if moon.time is not None:
        sun = sun_position(moon.time, lat0, lon0)
        if sun.elevation_deg > TWILIGHT_ELEVATION_DEG:
            log.warning("sun elevation %.1f deg: its light (twilight or day) is left out; only the moon lights this "
                        "render", sun.elevation_deg)
    log.info("lit by the moon: zenith %.2f deg, azimuth %.2f deg, phase angle %.1f deg (%.0f %% lit), %.0f km",
             moon.zenith_deg, moon.azimuth_deg, moon.phase_angle_deg, 100 * moon.illuminated_fraction,
             moon.distance_m / 1e3)
    return moon


def full_moon_ratio() -> float:
    """The full moon's irradiance at 546 nm relative to the sun's [-], both at their mean distances."""
    return float(lunar_irradiance(0.0)[1] / solar_irradiance_at_channels()[1])


def display_white_level(request, height_asl) -> float:
    """The fixed exposure's white level [-] (solar-relative L'): :func:`swim.pipeline.arguments.fixed_white_level`;
    by default, for the moon, the sun's default scaled by :func:`full_moon_ratio` (a camera exposed for the full
    moon as the default one is for the sun: a moonlit sky's image looks like the sunlit one's, darker away from full
    moon). ``height_asl``: the observer's height [m above sea level]."""
    white = fixed_white_level(request.white_level, request.exposure, height_asl)
    if is_moon(getattr(request, "light", "sun")) and request.white_level is None:
        white *= full_moon_ratio()
    return white


def moon_disk(camera, dirs_enu, valid, moon_enu, sun_from_moon, transmittance, radius):
    """The moon's disk: the flat indices (k,) of its lit pixels and their radiance (3,) [-] in units of the light's
    (the moon's) irradiance, ``4 pi T_direct`` spread over them.

    Where the disk spans at least :data:`RESOLVED_DISK_PIXELS` pixels of angular radius, a pixel is lit where the
    point of the sphere it sees faces the sun (``sun_from_moon``, unit (3,), ENU): the phase's shape and the bright
    limb's side follow; each lit pixel has the same radiance (irradiance / lit solid angle). A smaller disk is the
    pixels of :func:`swim.pipeline.sun_disk.sun_disk`. ``radius``: the disk's angular radius [rad]."""
    pixels, unit = sun_disk(camera, dirs_enu, valid, moon_enu, np.ones(3), radius=radius)
    t = np.asarray(transmittance, dtype=float)
    if pixels.size == 0:
        return pixels, np.zeros(3)
    pixel_solid_angle = 4 * np.pi / (pixels.size * unit[0])
    if radius < RESOLVED_DISK_PIXELS * np.sqrt(pixel_solid_angle):
        return pixels, t * unit
    d = dirs_enu.reshape(-1, 3)[pixels]
    m = np.asarray(moon_enu, dtype=float)
    across = d - (d @ m)[:, None] * m  # the offset from the disk's centre [rad], across the line of sight
    rho = np.linalg.norm(across, axis=1) / radius
    inside = rho <= 1.0
    # the sphere's outward normal at the point seen: across the line of sight, and back towards the observer
    normal = across / radius - np.sqrt(np.clip(1.0 - rho**2, 0.0, 1.0))[:, None] * m
    facing = normal @ np.asarray(sun_from_moon, dtype=float)
    lit = inside & (facing > 0.0)
    if not lit.any():  # a crescent thinner than a pixel: its brightest pixel
        lit = np.zeros_like(inside)
        lit[int(np.argmax(np.where(inside, facing, -np.inf)))] = True
    lit_pixels = pixels[lit]
    return lit_pixels, 4 * np.pi * t / (lit_pixels.size * pixel_solid_angle)


def with_the_light(light, planes, sun_out, cam, dirs_enu, valid, light_enu_observer, aureole):
    """The image's radiance (3, ny, nx) with the light's disk: :func:`swim.pipeline.sun_disk.with_the_sun` for the
    sun; for the moon (``light``, a :class:`MoonPosition`) its disk with its phase (:func:`moon_disk`) and the clouds'
    aureole (with ``aureole``), then every radiance plane (the returned one and ``planes``' ``radiance_clear``,
    ``radiance_cloud``, ``radiance_surface``, in place) scaled by the moon's irradiance relative to the sun's. Returns
    the radiance, the flat indices of the pixels that changed, and the direct and circumsolar transmittances (3,)
    [-] towards the light."""
    if not isinstance(light, MoonPosition):
        return with_the_sun(planes, sun_out, cam, dirs_enu, valid, light_enu_observer, aureole)
    t_direct = np.zeros(3) if sun_out["surface"] else np.exp(-(sun_out["tau_clear"] + sun_out["tau_hydrometeor"]))
    moon_enu = np.asarray(light_enu_observer, dtype=float)
    disk_pixels, disk_radiance = moon_disk(cam, dirs_enu, valid, moon_enu, light.sun_from_moon_enu(moon_enu),
                                           t_direct, light.angular_radius_rad)
    radiance = planes.pop("radiance")
    t_aureole = np.zeros(3)
    changed = [disk_pixels]
    if aureole and not sun_out["surface"]:
        t_aureole = np.maximum(np.exp(-(sun_out["tau_clear"] + sun_out["tau_narrow"])) - t_direct, 0.0)
        aureole_pixels, aureole_radiance = sun_disk(cam, dirs_enu, valid, moon_enu, t_aureole,
                                                     radius=AUREOLE_HALF_ANGLE_RAD)
        for plane in (radiance, planes["radiance_cloud"]):
            flat = plane.reshape(3, -1)
            flat[:, aureole_pixels] += aureole_radiance[:, None].astype(flat.dtype)
        changed.append(aureole_pixels)
    ratio = lunar_irradiance_ratio(light)
    flat = radiance.reshape(3, -1).astype(np.float64)
    flat[:, disk_pixels] += disk_radiance[:, None]
    radiance = (flat * ratio[:, None]).astype(np.float32).reshape(radiance.shape)
    for name in ("radiance_clear", "radiance_cloud", "radiance_surface"):
        if name in planes:
            planes[name] = (planes[name] * ratio[:, None, None]).astype(planes[name].dtype, copy=False)
    return radiance, np.union1d(*changed) if len(changed) > 1 else changed[0], t_direct, t_aureole


def light_attributes(light) -> dict:
    """The image's attributes that say what lit it: none for the sun; for the moon ``light="moon"``, the moon's
    (:meth:`MoonPosition.to_attrs`), its irradiance and the ratio the radiance was scaled by, and a note that the
    ``sun_*`` and transmittance attributes describe the light, the moon."""
    if not isinstance(light, MoonPosition):
        return {}
    attrs = {"light": "moon"}
    attrs.update(light.to_attrs())
    attrs["moon_irradiance_w_m2_nm"] = np.asarray(
        lunar_irradiance(light.phase_angle_deg, light.sun_moon_distance_au, light.distance_m), dtype=float)
    attrs["moon_irradiance_ratio"] = np.asarray(lunar_irradiance_ratio(light), dtype=float)
    attrs["light_comment"] = (
        "lit by the moon (Miller and Turner 2009 irradiance, DE421 position): radiance is the solar-relative "
        "L' = 4 pi L / E_TOA of the moonlit scene, E_TOA the sun's at earth_sun_distance_au; moon_irradiance_ratio "
        "is E_moon / E_TOA per wavelength; the sun_* angles, direct_transmittance and circumsolar_transmittance are "
        "the moon's")
    return attrs
