"""Moonlight: a render lit by the moon instead of the sun (:func:`swim.render`'s ``light="moon"``).

The moon takes the sun's place in every stage (docs/rendering.md, "Moonlight"): its direction lights Step 1a, the
clear-sky tables, the 3-D diffuse field, the ground and the march, exactly as the sun's would. That render, in the
units of a light of the sun's spectrum and irradiance, is then scaled per wavelength by the moon's top-of-atmosphere
irradiance relative to the sun's (:func:`swim.geometry.moon.lunar_irradiance_ratio`, about 2.5e-6 at full moon), so
the image's radiance stays the solar-relative L' = 4 pi L / E_TOA of Albers et al. (2020), Eq. 2, of the moonlit sky.
The moon's disk is drawn with its phase (:func:`moon_disk`) where the image resolves it; the lunar aureole is the
scattering's own (the aerosol's and the clouds' forward peaks), as the sun's is.

``light="sun+moon"`` lights the scene by both (:func:`resolve_lights`): the sun's render (day or twilight, its disk)
and the moon's (scaled, its disk) are marched one after the other and summed as radiance (:func:`sum_lit`) before the
one colour stage; the night sky is added once, where the sun is below the horizon. A light is marched only where it
can show: the sun above :data:`SUN_MARCH_MIN_ELEVATION_DEG`, the moon above :data:`MOON_MARCH_MIN_ELEVATION_DEG`; the
image's ``lights`` attribute names those marched. One setting so serves a time series from day into night.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from ..errors import SwimInputError
from ..frames import enu_to_scene_rotation
from ..geometry.moon import (MEAN_EARTH_MOON_DISTANCE_M, MoonPosition, lunar_irradiance, lunar_irradiance_ratio,
                             moon_position, solar_irradiance_at_channels)
from ..geometry.sun import sun_position
from ..optics.cloud_phase import AUREOLE_HALF_ANGLE_RAD
from .arguments import fixed_white_level, resolve_sun
from .sun_disk import sun_disk, with_the_sun

log = logging.getLogger(__name__)

#: The lights a render can be lit by (:func:`swim.render`'s ``light``; a :class:`MoonPosition` is a moon too).
LIGHTS = ("sun", "moon", "sun+moon")

#: The disk is drawn with its phase where its angular radius spans at least this many pixels; a smaller disk is a
#: few pixels of its mean radiance, as the sun's is.
RESOLVED_DISK_PIXELS = 1.5

#: Sun elevations [deg] above which a moonlit render logs that the twilight (or daylight) it leaves out is there:
#: the end of astronomical twilight.
TWILIGHT_ELEVATION_DEG = -18.0

#: Sun elevation [deg] at or below which a ``light="sun+moon"`` render does not march the sun: the end of
#: astronomical twilight. The sun's twilight render is already zero from -16 deg (the default scene, an all-sky
#: camera at 2 m: the brightest pixel's L' at 546 nm is 2e-7 at -12 deg, ten times the night sky's 2e-8, and 0 at
#: -16, -18 and -20 deg).
SUN_MARCH_MIN_ELEVATION_DEG = TWILIGHT_ELEVATION_DEG

#: Moon elevation [deg] at or below which a ``light="sun+moon"`` render does not march the moon: below the horizon by
#: this margin, its light on the upper air (lunar twilight) is under 1 % of the night sky's in every pixel, even at
#: full moon (the sun's twilight render of the default scene scaled by the full moon's ratio, 2.4e-6: the brightest
#: pixel's L' at 546 nm 1.7e-10 at -8 deg, 1.9e-9 at -6 deg, against the night sky's 2e-8; its median is the night
#: sky's at -2 deg).
MOON_MARCH_MIN_ELEVATION_DEG = -8.0


def check_light(light):
    """``light`` checked: "sun", "moon", "sun+moon" or a :class:`swim.geometry.moon.MoonPosition` (returned as
    given).

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
    :class:`MoonPosition` (used as it is); for "sun+moon" the sun (both: :func:`resolve_lights`). ``request``: a
    :class:`swim.pipeline.chain.RenderRequest`.

    Raises
    ------
    SwimInputError
        A bad ``light``; sun angles with the moon; no time for the moon.
    """
    light = check_light(getattr(request, "light", "sun"))
    if light == "sun+moon":
        _no_sun_angles(request, light)
        return resolve_sun(_light_time(request, scene, light), scene)
    if not is_moon(light):
        return resolve_sun(request.time, scene, request.sun_zenith, request.sun_azimuth)
    _no_sun_angles(request, "moon")
    lat0, lon0 = float(scene.attrs["reference_lat"]), float(scene.attrs["reference_lon"])
    moon = light if isinstance(light, MoonPosition) else moon_position(_light_time(request, scene, light), lat0, lon0)
    if moon.zenith_deg > 90:
        log.warning("moon is %.1f deg below the horizon: a dark sky (the night sky alone)", moon.zenith_deg - 90)
    if moon.time is not None:
        sun = sun_position(moon.time, lat0, lon0)
        if sun.elevation_deg > TWILIGHT_ELEVATION_DEG:
            log.warning("sun elevation %.1f deg: its light (twilight or day) is left out; only the moon lights this "
                        "render (light='sun+moon' for both)", sun.elevation_deg)
    log.info("lit by the moon: zenith %.2f deg, azimuth %.2f deg, phase angle %.1f deg (%.0f %% lit), %.0f km",
             moon.zenith_deg, moon.azimuth_deg, moon.phase_angle_deg, 100 * moon.illuminated_fraction,
             moon.distance_m / 1e3)
    return moon


def _no_sun_angles(request, light):
    """Raise :class:`SwimInputError` where ``request`` sets the sun's angles: with ``light`` "moon" or "sun+moon"
    the lights' places come from the time."""
    if request.sun_zenith is not None or request.sun_azimuth is not None:
        raise SwimInputError(f"sun_zenith/sun_azimuth set the sun; with light='{light}' the places of the sun and the "
                             "moon come from the time (or pass light=swim.geometry.moon.moon_from_angles(...))")


def _light_time(request, scene, light):
    """The time of the moon's place: ``request.time``, else the scene's ``time``.

    Raises
    ------
    SwimInputError
        If neither is there.
    """
    if request.time is not None:
        return request.time
    if "time" not in scene.coords:
        raise SwimInputError(f"light='{light}' needs the time: pass time (ISO 8601, UTC); the scene has no 'time'")
    return scene["time"].values


@dataclasses.dataclass(frozen=True, eq=False)
class Lights:
    """What lights a render (:func:`resolve_lights`).

    Attributes
    ----------
    sun : swim.geometry.sun.SunPosition or MoonPosition
        The light that places the view (its direction is the view's ``sun_enu``) and whose angles are the image's
        ``sun_*`` attributes: the sun, or the moon of a moonlit render.
    moon : MoonPosition or None
        The moon of a ``light="sun+moon"`` render; else None.
    marched : tuple
        The lights marched, in order (the sun first).
    """

    sun: object
    moon: object = None
    marched: tuple = ()

    @property
    def names(self) -> str:
        """The lights marched, by name ("sun", "moon", "sun moon")."""
        return " ".join("moon" if isinstance(light, MoonPosition) else "sun" for light in self.marched)

    @property
    def sun_alone(self) -> bool:
        """Whether the one light marched is the sun (a render the march may colour)."""
        return len(self.marched) == 1 and self.marched[0] is self.sun and not isinstance(self.sun, MoonPosition)

    @property
    def exposed_for_moon(self) -> bool:
        """Whether a fixed exposure's default is the full moon's: a moonlit render, or a sun-and-moon one whose sun
        is not marched (:func:`display_white_level`)."""
        return isinstance(self.sun, MoonPosition) or not any(light is self.sun for light in self.marched)


def resolve_lights(request, scene) -> Lights:
    """The render's lights (:class:`Lights`): for ``request.light`` "sun+moon" the sun
    (:func:`swim.pipeline.arguments.resolve_sun`) and the moon (:func:`swim.geometry.moon.moon_position`) at the
    time, at the scene's reference point, each marched where it can show: the sun above
    :data:`SUN_MARCH_MIN_ELEVATION_DEG`, the moon above :data:`MOON_MARCH_MIN_ELEVATION_DEG`. Where neither is, the
    moon is marched all the same: the night sky needs the clouds on the lines of sight (``tau_hydrometeor``), and its
    light is part of the night's. Otherwise the one light of :func:`resolve_light`.

    Raises
    ------
    SwimInputError
        As :func:`resolve_light`; sun angles with "sun+moon".
    """
    light = check_light(getattr(request, "light", "sun"))
    if light != "sun+moon":
        one = resolve_light(request, scene)
        return Lights(one, None, (one,))
    _no_sun_angles(request, light)
    time = _light_time(request, scene, light)
    lat0, lon0 = float(scene.attrs["reference_lat"]), float(scene.attrs["reference_lon"])
    sun = resolve_sun(time, scene)
    moon = moon_position(time, lat0, lon0)
    marched = tuple(body for body, lowest in ((sun, SUN_MARCH_MIN_ELEVATION_DEG), (moon, MOON_MARCH_MIN_ELEVATION_DEG))
                    if 90.0 - body.zenith_deg > lowest) or (moon,)
    log.info("lit by the sun (elevation %.1f deg) and the moon (elevation %.1f deg, %.0f %% lit): marching the %s",
             90.0 - sun.zenith_deg, 90.0 - moon.zenith_deg, 100 * moon.illuminated_fraction,
             " and the ".join(Lights(sun, moon, marched).names.split()))
    return Lights(sun, moon, marched)


def crop_light_direction(request, scene):
    """The direction (3,) in the scene frame that the crop of a big grid widens towards for the shadows
    (:func:`swim.geometry.reach.crop_scene_to_view`'s ``sun_direction``): the one light marched; None (a margin on
    every side) where two are."""
    lights = resolve_lights(request, scene)
    return lights.marched[0].direction_enu if len(lights.marched) == 1 else None


def light_direction_at_observer(light, lights, view):
    """The unit direction (3,) of ``light`` (one of ``lights.marched``) in the observer's ENU frame: the view's
    ``sun_enu`` for the light that placed it (``lights.sun``), else the light's scene-frame direction turned as
    :func:`swim.pipeline.scene_stage.camera_view` turns the sun's. ``view``: a
    :class:`swim.pipeline.scene_stage.View`."""
    if light is lights.sun:
        return view.sun_enu
    rotation = enu_to_scene_rotation(view.lat, view.lon, *view.reference)
    return np.asarray(light.direction_enu, dtype=float) @ rotation.T


def progress_of(progress, index, count):
    """``progress`` (called with rays done, rays total) for the ``index``-th (from 0) of a render's ``count``
    marches: the rays of the marches before it counted as done, the total as ``count`` times this march's."""
    if progress is None or count == 1:
        return progress

    def report(done, total):
        progress(index * total + done, count * total)

    return report


def full_moon_ratio() -> float:
    """The full moon's irradiance at 546 nm relative to the sun's [-], both at their mean distances."""
    return float(lunar_irradiance(0.0)[1] / solar_irradiance_at_channels()[1])


def display_white_level(request, height_asl, lights=None) -> float:
    """The fixed exposure's white level [-] (solar-relative L'): :func:`swim.pipeline.arguments.fixed_white_level`;
    by default, for the moon, the sun's default scaled by :func:`full_moon_ratio` (a camera exposed for the full
    moon as the default one is for the sun: a moonlit sky's image looks like the sunlit one's, darker away from full
    moon). ``height_asl``: the observer's height [m above sea level]. ``lights`` (:class:`Lights`): with "sun+moon"
    the full moon's default where the sun is not marched (a night), the sun's where it is (day and twilight, as a
    sunlit render's); None: from ``request.light``."""
    white = fixed_white_level(request.white_level, request.exposure, height_asl)
    moonlit = is_moon(getattr(request, "light", "sun")) if lights is None else lights.exposed_for_moon
    if moonlit and request.white_level is None:
        white *= full_moon_ratio()
    return white


#: The earth's apparent albedo [-] seen in the earthshine (Qiu et al. 2003, JGR 108, 4709, doi:10.1029/2003JD003610:
#: 0.297 +- 0.005, the 1999-2001 mean of the Big Bear earthshine): the Bond albedo of a Lambert sphere that sheds the
#: observed earthshine, whose geometric albedo is 2/3 of it.
EARTH_APPARENT_ALBEDO = 0.297
#: Mean radius of the earth [m] (IUGG).
EARTH_MEAN_RADIUS_M = 6_371_000.0
#: Phase angle [deg] at which the moon's dark side reflects the earthshine back to the earth: the earth's sunlit
#: photocentre seen from the moon lies within a degree or two of the observer, near the opposition peak.
EARTHSHINE_PHASE_ANGLE_DEG = 1.0


def lambert_phase_function(phase_angle_deg):
    """Phase function of a Lambert sphere [-], 1 at full phase: (sin a + (pi - a) cos a) / pi, a the phase angle
    [deg] (Russell 1916, ApJ 43, 173; the f_e of Qiu et al. 2003)."""
    a = np.radians(np.clip(np.asarray(phase_angle_deg, dtype=float), 0.0, 180.0))
    return (np.sin(a) + (np.pi - a) * np.cos(a)) / np.pi


def earth_irradiance_at_moon(phase_angle_deg, moon_distance_m=MEAN_EARTH_MOON_DISTANCE_M,
                             apparent_albedo=EARTH_APPARENT_ALBEDO):
    """The earth's irradiance at the moon relative to the sun's there [-]: (2/3) p* f_e(180 deg - g) (R_E / d)^2, the
    earth a Lambert sphere of apparent albedo p* seen from the moon at phase angle 180 deg - g, g the moon's phase
    angle [deg] seen from the earth, d the earth-moon distance [m] (Qiu et al. 2003). 5.4e-5 at new moon.

    Raises
    ------
    SwimInputError
        An albedo outside [0, 1] or a distance that is not positive.
    """
    if not (0.0 <= apparent_albedo <= 1.0 and np.isfinite(moon_distance_m) and moon_distance_m > 0):
        raise SwimInputError(f"apparent_albedo must lie in [0, 1] and moon_distance_m be > 0 m; got "
                             f"{apparent_albedo}, {moon_distance_m}")
    earth_phase = 180.0 - np.asarray(phase_angle_deg, dtype=float)
    return 2.0 / 3.0 * apparent_albedo * lambert_phase_function(earth_phase) * (EARTH_MEAN_RADIUS_M
                                                                               / moon_distance_m) ** 2


def earthshine_ratio(phase_angle_deg, moon_distance_m=MEAN_EARTH_MOON_DISTANCE_M, lit_fraction=None,
                     apparent_albedo=EARTH_APPARENT_ALBEDO):
    """Radiance of the moon's dark part, lit by the earth, relative to the mean radiance of its sunlit part (3,) [-].

    The dark part is the lunar surface lit by the earth's irradiance (:func:`earth_irradiance_at_moon`) and seen
    near opposition (:data:`EARTHSHINE_PHASE_ANGLE_DEG`), so its radiance is the mean radiance of a full moon
    (Miller & Turner 2009, :func:`swim.geometry.moon.lunar_irradiance`) scaled by that irradiance; the sunlit part's
    is the moon's irradiance at phase angle g spread over the lit fraction k of the disk:

        L_dark / L_lit = (E_earth / E_sun) E_moon(1 deg) / E_moon(g) k,

    k = (1 + cos g) / 2 unless ``lit_fraction`` (e.g. the lit share of a drawn disk's pixels) is given: Qiu et
    al.'s (2003) apparent-albedo equation solved for the intensity ratio, with the Miller & Turner lunar phase curve
    for theirs. About 9e-5 at g = 90 deg, 3e-4 at 120 deg, 8e-4 at 150 deg.

    References
    ----------
    Qiu, J. et al. (2003), Earthshine and the Earth's albedo: 1, J. Geophys. Res. 108, 4709, doi:10.1029/2003JD003610.
    Miller, S. D. & Turner, R. E. (2009), IEEE TGRS 47, 2316-2329, doi:10.1109/TGRS.2009.2012696.
    """
    g = float(phase_angle_deg)
    k = 0.5 * (1.0 + np.cos(np.radians(g))) if lit_fraction is None else float(lit_fraction)
    e_ratio = earth_irradiance_at_moon(g, moon_distance_m, apparent_albedo)
    return e_ratio * lunar_irradiance(EARTHSHINE_PHASE_ANGLE_DEG) / lunar_irradiance(g) * k


def moon_disk(camera, dirs_enu, valid, moon_enu, sun_from_moon, transmittance, radius, earthshine=None):
    """The moon's disk: the flat indices (k,) of its pixels and their radiance in units of the light's (the moon's)
    irradiance, ``4 pi T_direct`` spread over the lit ones.

    Where the disk spans at least :data:`RESOLVED_DISK_PIXELS` pixels of angular radius, a pixel is lit where the
    point of the sphere it sees faces the sun (``sun_from_moon``, unit (3,), ENU): the phase's shape and the bright
    limb's side follow; each lit pixel has the same radiance (irradiance / lit solid angle). A smaller disk is the
    pixels of :func:`swim.pipeline.sun_disk.sun_disk`. ``radius``: the disk's angular radius [rad].

    Without ``earthshine`` the pixels are the lit ones and the radiance is (3,), one value for them all. With
    ``earthshine`` (a :class:`swim.geometry.moon.MoonPosition`: its phase angle and distance) a resolved disk's dark
    pixels are drawn too, at :func:`earthshine_ratio` of the lit ones' radiance, and the radiance is (3, k), a column
    per pixel (``radiance.reshape(3, -1)`` serves both)."""
    pixels, unit = sun_disk(camera, dirs_enu, valid, moon_enu, np.ones(3), radius=radius)
    t = np.asarray(transmittance, dtype=float)
    if pixels.size == 0:
        return pixels, (np.zeros((3, 0)) if earthshine is not None else np.zeros(3))
    pixel_solid_angle = 4 * np.pi / (pixels.size * unit[0])
    if radius < RESOLVED_DISK_PIXELS * np.sqrt(pixel_solid_angle):
        radiance = t * unit
        return pixels, (np.repeat(radiance[:, None], pixels.size, axis=1) if earthshine is not None else radiance)
    inside, lit = _disk_phase(dirs_enu.reshape(-1, 3)[pixels], moon_enu, sun_from_moon, radius)
    lit_pixels = pixels[lit]
    bright = 4 * np.pi * t / (lit_pixels.size * pixel_solid_angle)
    if earthshine is None:
        return lit_pixels, bright
    dark = inside & ~lit
    ratio = earthshine_ratio(earthshine.phase_angle_deg, earthshine.distance_m, lit.sum() / max(inside.sum(), 1))
    keep = lit | dark
    radiance = np.where(lit[keep][None, :], bright[:, None], (bright * ratio)[:, None])
    return pixels[keep], radiance


def _disk_phase(d, moon_enu, sun_from_moon, radius):
    """Which of the directions ``d`` (k, 3) fall on the disk of angular radius ``radius`` [rad] about ``moon_enu``
    (``inside``, (k,)) and which of those see its sunlit part (``lit``): the sphere's outward normal at the point
    seen faces the sun (``sun_from_moon``); a crescent thinner than a pixel is its brightest pixel."""
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
    return inside, lit


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
                                           t_direct, light.angular_radius_rad, earthshine=light)
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
    flat[:, disk_pixels] += disk_radiance.reshape(3, -1)  # lit and earthshine-lit pixels alike
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


def lights_attributes(lights: Lights, lit) -> dict:
    """The image's attributes that say what lit it (:func:`light_attributes` for one light). For "sun+moon":
    ``light = "sun+moon"``, ``lights`` (those marched, e.g. "sun moon"), the moon's attributes, irradiance and ratio
    as a moonlit render's, ``moon_direct_transmittance`` (3,) [-] (zero where the moon was not marched) and a note
    that the ``sun_*`` and transmittance attributes are the sun's. ``lit``: the render's :class:`LitImage`
    (:func:`sum_lit`)."""
    if lights.moon is None:
        return light_attributes(lights.sun)
    moon = lights.moon
    attrs = {key: value for key, value in light_attributes(moon).items() if key != "light_comment"}
    attrs.update({"light": "sun+moon", "lights": lights.names})
    attrs["moon_direct_transmittance"] = np.asarray(lit.transmittances_by_light.get("moon", (np.zeros(3),))[0],
                                                    dtype=float)
    attrs["light_comment"] = (
        "lit by the sun and the moon: radiance is the sum of the sunlit scene's and the moonlit scene's (Miller and "
        "Turner 2009 irradiance, DE421 position; scaled by moon_irradiance_ratio, E_moon / E_TOA per wavelength), "
        "the solar-relative L' = 4 pi L / E_TOA, E_TOA the sun's at earth_sun_distance_au; lights names the lights "
        f"marched (the sun above {SUN_MARCH_MIN_ELEVATION_DEG:g} deg, the moon above {MOON_MARCH_MIN_ELEVATION_DEG:g} "
        "deg); the sun_* angles, direct_transmittance and circumsolar_transmittance are the sun's, "
        "moon_direct_transmittance the moon's")
    return attrs


@dataclasses.dataclass(eq=False)
class LitImage:
    """One light's march with its disk (:func:`swim.pipeline.chain.render`'s stage), or the sum of a render's lights
    (:func:`sum_lit`).

    Attributes
    ----------
    radiance : numpy.ndarray
        Shape (3, ny, nx), float32: the solar-relative radiance L' [-], the light's disk added (the moon's scaled).
    recoloured : numpy.ndarray
        Flat indices of the pixels changed since the march coloured them.
    planes : dict
        The march's other planes: ``radiance_clear``, ``radiance_cloud``, ``radiance_surface`` (3, ny, nx) [-] and
        ``tau_hydrometeor`` (1, ny, nx) [-].
    transmittances_by_light : dict
        ``"sun"`` and/or ``"moon"``: the direct and circumsolar transmittances (3,) [-] towards each light marched.
    settings : swim.rt.march_settings.MarchSettings
        The settings the (first) light was marched with (:func:`swim.pipeline.arguments.settings_for_sun`).
    samples : int
        Volume samples of the marches, the rays towards the lights included.
    traced : numpy.ndarray
        Shape (ny * nx,) bool: the pixels whose ray was marched (by any light).
    rgb : tuple or None
        The march's colour codes (:class:`swim.rt.backends.MarchedImage`), or None.
    on_accelerator : bool
        Whether the march ran on a GPU.
    """

    radiance: np.ndarray
    recoloured: np.ndarray
    planes: dict
    transmittances_by_light: dict
    settings: object
    samples: int
    traced: np.ndarray
    rgb: tuple | None = None
    on_accelerator: bool = False

    def transmittances(self, name="sun"):
        """The direct and circumsolar transmittances (3,) [-] towards the light ``name``; zeros where it was not
        marched."""
        return self.transmittances_by_light.get(name, (np.zeros(3), np.zeros(3)))


def sum_lit(lit) -> LitImage:
    """The render's light: the one :class:`LitImage` of ``lit`` (a list), or their sum: the radiance planes added
    (float32, the line of sight's ``tau_hydrometeor`` the first's), the pixels traced by any, their samples added;
    no march colour (the sum is coloured after)."""
    if len(lit) == 1:
        return lit[0]
    first = lit[0]
    radiance = first.radiance.astype(np.float32, copy=True)
    planes = dict(first.planes)
    for other in lit[1:]:
        radiance += other.radiance
        for name in ("radiance_clear", "radiance_cloud", "radiance_surface"):
            planes[name] = (planes[name] + other.planes[name]).astype(np.float32, copy=False)
    return LitImage(radiance, np.arange(radiance[0].size),
                    planes, {key: value for one in lit for key, value in one.transmittances_by_light.items()},
                    first.settings, sum(one.samples for one in lit), np.logical_or.reduce([one.traced for one in lit]),
                    None, any(one.on_accelerator for one in lit))
