"""The city-lights stage: the sky glow of the towns' upward light and the cloud bases it lights from below, added to
a night render (docs/rendering.md, "City lights"; docs/decisions/0024-city-lights.md).

The emission is the scene's ``upward_light_emission`` (y, x) [lm m-2] (docs/scene-format.md; made from land use or
towns by :mod:`swim.surface.city_lights`), read by :func:`city_light_emission` from the prepared scene (before the
optical volume's stage drops the values) and coarse-grained into at most :data:`MAX_SOURCES` sources. The stage
(:func:`add_city_lights`) runs after the night sky's and before the colour stage, where the sun is below the
observer's horizon (or the light is the moon): it adds the solar-relative radiance to ``radiance`` (float32), and
:func:`with_city_lights_record` keeps it apart in the image as ``radiance_city_lights`` and records what was added in
the attributes ``city_lights_*``. By day, without emission, or for a camera above
:data:`swim.pipeline.night_sky.NIGHT_SKY_MAX_OBSERVER_M` it adds nothing.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np
import xarray as xr

from ..errors import SwimInputError
from ..frames import enu_to_scene_rotation
from ..rt.city_lights import (DEFAULT_LAMP, CloudVolume, city_lights_image, clear_air, luminous_efficacy,
                              sources_from_emission)
from ..rt.night_sky import solar_relative
from .night_sky import NIGHT_SKY_MAX_OBSERVER_M

log = logging.getLogger(__name__)

#: Most sources the emission field is coarse-grained into (:func:`swim.rt.city_lights.sources_from_emission`).
MAX_SOURCES = 128
#: The scene's variable of the upward luminous exitance [lm m-2] and its attribute naming the lamps' spectrum.
EMISSION_VARIABLE, LAMP_ATTRIBUTE = "upward_light_emission", "lamp_spectrum"



@dataclass(frozen=True)
class CityEmission:
    """The scene's emission field, perhaps lazy: ``lat``, ``lon`` [deg], ``terrain_height`` [m] and ``emission``
    [lm m-2], each a (y, x) DataArray read only where the stage adds the city lights, and the ``lamp`` spectrum's
    name."""

    lat: xr.DataArray
    lon: xr.DataArray
    terrain_height: xr.DataArray
    emission: xr.DataArray
    lamp: str = DEFAULT_LAMP

    def values(self):
        """``lat``, ``lon``, ``terrain_height`` and ``emission`` as float64 (y, x) numpy arrays."""
        return tuple(np.asarray(a.transpose("y", "x").values, dtype=float)
                     for a in (self.lat, self.lon, self.terrain_height, self.emission))



def city_light_emission(scene: xr.Dataset) -> CityEmission | None:
    """The scene's ``upward_light_emission`` with its columns' places, from a prepared (perhaps lazy, cropped)
    canonical scene, not read yet; None where the scene has none.

    Raises
    ------
    SwimInputError
        If the variable is not (y, x).
    """
    if EMISSION_VARIABLE not in scene.variables:
        return None
    da = scene[EMISSION_VARIABLE]
    if set(da.dims) != {"y", "x"}:
        raise SwimInputError(f"{EMISSION_VARIABLE} has dims {da.dims}; expected (y, x) [lm m-2]")
    lamp = str(da.attrs.get(LAMP_ATTRIBUTE, scene.attrs.get(LAMP_ATTRIBUTE, DEFAULT_LAMP)))
    return CityEmission(scene["lat"], scene["lon"], scene["terrain_height"], da, lamp)



@dataclass(frozen=True)
class CityLights:
    """What :func:`add_city_lights` added: ``radiance`` (3, ny, nx) float32 [-] and the image's ``attrs``."""

    radiance: np.ndarray
    attrs: dict



def add_city_lights(radiance, recoloured, planes, view, sun, aerosol, volume, emission: CityEmission | None,
                    night=False, max_sources=MAX_SOURCES):
    """The render's stage (:func:`swim.pipeline.chain.render`): the city lights added to ``radiance`` where the sun is
    below the horizon, after the night sky and before the colour stage.

    Parameters
    ----------
    radiance : numpy.ndarray
        Shape (3, ny, nx): the render's solar-relative radiance [-].
    recoloured : numpy.ndarray
        Flat indices of the pixels changed since the march coloured them.
    planes : dict
        The march's planes (its ``tau_hydrometeor``, (1, ny, nx)).
    view : swim.pipeline.scene_stage.View
        The observer, its camera and rays.
    sun : swim.geometry.sun.SunPosition or swim.geometry.moon.MoonPosition
        The render's light (its ``earth_sun_distance_au`` sets the units).
    aerosol : swim.rt.gas.AerosolBackground
        The background aerosol (the clear air's extinction and phase function).
    volume : xarray.Dataset
        The optical volume (where the lines of sight meet cloud).
    emission : CityEmission or None
        :func:`city_light_emission` of the scene.
    night : bool
        The light is the moon: the city lights are added whatever ``view.sun_enu`` says.
    max_sources : int

    Returns
    -------
    radiance : numpy.ndarray
        Float32, the city lights added (the input itself where none are).
    recoloured : numpy.ndarray
        Every pixel's flat index where they were added, else the input.
    lights : CityLights or None
    """
    sun_zenith = float(np.degrees(np.arccos(np.clip(np.asarray(view.sun_enu, dtype=float)[2], -1.0, 1.0))))
    if emission is None or (sun_zenith <= 90.0 and not night) or view.height_asl > NIGHT_SKY_MAX_OBSERVER_M:
        return radiance, recoloured, None
    start = time.perf_counter()
    lat, lon, terrain, field = emission.values()
    if not np.any(field > 0):
        return radiance, recoloured, None
    lat0, lon0 = view.reference
    sources = sources_from_emission(lat, lon, terrain, field, lat0, lon0, max_sources, emission.lamp)
    kind = aerosol.type
    air = clear_air(float(aerosol.aod_550), float(aerosol.scale_height_m), float(kind.angstrom_exponent),
                    kind.ssa, kind.phase_function)
    tau_h = np.asarray(planes["tau_hydrometeor"][0], dtype=float)
    cloud = None
    if np.nanmax(tau_h, initial=0.0) > 0.01:
        cloud = CloudVolume(np.asarray(volume.variables["extinction"].values, dtype=float).sum(axis=0),
                            dict(volume.attrs))
    azimuth, zenith = view.camera.cached_view_angles()
    spectral, n_cloudy = city_lights_image(
        view.rays.observer, enu_to_scene_rotation(view.lat, view.lon, lat0, lon0), azimuth, zenith,
        view.rays.directions, tau_h, sources, air, cloud, ground_height_m=view.height_asl - view.height)
    added = solar_relative(spectral, float(sun.earth_sun_distance_au)).astype(np.float32)
    radiance = (radiance + added).astype(np.float32, copy=False)
    seconds = time.perf_counter() - start
    attrs = {
        "city_lights_sources": int(sources.flux_lm.size),
        "city_lights_flux_lm": float(sources.flux_lm.sum()),
        "city_lights_lamp": sources.lamp,
        "city_lights_luminous_efficacy_lm_per_w": luminous_efficacy(sources.lamp),
        "city_lights_emission_law": f"Garstang 1986, F = {sources.direct_fraction:g}, G = "
                                    f"{sources.ground_reflectance:g}",
        "city_lights_cloudy_pixels": n_cloudy,
        "city_lights_seconds": seconds,
    }
    log.info("city lights added: %d sources, %.3g lm upward (%s lamps), %d cloudy pixels, %.2f s",
             sources.flux_lm.size, sources.flux_lm.sum(), sources.lamp, n_cloudy, seconds)
    return radiance, np.arange(radiance[0].size), CityLights(added, attrs)



def with_city_lights_record(image: xr.Dataset, lights: CityLights | None) -> xr.Dataset:
    """The image with :func:`add_city_lights`'s record: the plane ``radiance_city_lights`` (wavelength, y, x) [1] and
    the attributes ``city_lights_sources``, ``city_lights_flux_lm``, ``city_lights_lamp``,
    ``city_lights_luminous_efficacy_lm_per_w``, ``city_lights_emission_law``, ``city_lights_cloudy_pixels`` and
    ``city_lights_seconds``; unchanged where ``lights`` is None."""
    if lights is None:
        return image
    image["radiance_city_lights"] = (("wavelength", "y", "x"), lights.radiance, {
        "units": "1", "long_name": "city lights' part of L': the sky glow and the cloud bases lit from below"})
    image.attrs.update(lights.attrs)
    return image
