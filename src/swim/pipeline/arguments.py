"""Checks of :func:`swim.render`'s arguments before any work, and the choices made from them: the sun, the background
aerosol, the cloud scattering for the sun."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping

import numpy as np
import pandas as pd
import xarray as xr

from ..color import DEFAULT_WHITE_LEVEL, SPACE_WHITE_LEVEL
from ..color.display import exposure_white_level
from ..constants import ATMOSPHERE_TOP_M
from ..errors import SwimInputError
from ..geometry.cameras import check_camera_options
from ..geometry.level_of_detail import check_coarsening
from ..geometry.sun import SunPosition, sun_from_angles, sun_position
from ..rt.clouds import MIN_SUN_COSINE
from ..optics.aerosol_types import AerosolType
from ..rt.gas import AerosolBackground
from ..rt.march_settings import MarchSettings
from ..rt.solar import PER_COLUMN_SUN_TILT_DEG, column_tilt_deg, per_column_sun

log = logging.getLogger(__name__)

#: Above this height [m] a perspective camera without a look-at point looks straight down.
SPACE_VIEW_HEIGHT_M = ATMOSPHERE_TOP_M



#: Peak memory of a render per image pixel [bytes]: ~216 measured for all-sky images of the built-in scene between
#: 512^2 and 1024^2 pixels (its planes, the rays' outputs and the colour stage), with a margin; the scene's volume
#: comes on top.
RENDER_BYTES_PER_PIXEL = 250



def check_render_memory(n_pixels: int) -> None:
    """Refuse an image of ``n_pixels`` whose render would need more memory than the system has available.

    Raises
    ------
    SwimInputError
        If ``n_pixels`` x :data:`RENDER_BYTES_PER_PIXEL` exceeds :func:`swim.memory.available_memory_bytes`.
    """
    from ..memory import available_memory_bytes

    need, have = n_pixels * RENDER_BYTES_PER_PIXEL, available_memory_bytes()
    if have is not None and need > have:
        raise SwimInputError(f"an image of {n_pixels:,} pixels needs about {need / 2**30:.1f} GiB to render, more than "
                             f"the {have / 2**30:.1f} GiB available: a smaller image, or check_memory=False "
                             f"(CLI --no-memory-check) to try anyway")



def check_exposure(white_level, exposure) -> bool:
    """Check ``render``'s exposure arguments before any work; True for auto exposure."""
    exposure_white_level(1.0, exposure)  # raises SwimInputError for a bad shift
    if isinstance(white_level, str):
        if white_level != "auto":
            raise SwimInputError(f"white_level must be a positive number (solar-relative L' [-]) or 'auto'; got "
                                 f"{white_level!r}")
        return True
    if white_level is not None:
        exposure_white_level(white_level)
    return False



def checked_arguments(scene, request):
    """:func:`render`'s arguments (``request``, a :class:`swim.pipeline.chain.RenderRequest`) checked before the
    scene is read (a whole CONUS grid: ~40 s and ~11 GB): the scene's type, the exposure, the camera's kind and
    options (a perspective camera's view is filled in from the grid later,
    :func:`swim.pipeline.scene_stage.default_perspective_view`), the image's memory, the observer and the
    coarsening. Returns the observer's height [m above the ground] as a float and whether the exposure is automatic.

    Raises
    ------
    SwimInputError
        Naming the argument and what it should be.
    """
    camera, camera_options, height, look_at = request.camera, request.camera_options, request.height, request.look_at
    aerosol, lat, white_level, exposure = request.aerosol, request.lat, request.white_level, request.exposure
    coarsen, check_memory = request.coarsen, request.check_memory
    if not isinstance(scene, xr.Dataset):
        raise SwimInputError(f"scene must be an xarray.Dataset; got {type(scene).__name__}")
    auto_exposure = check_exposure(white_level, exposure)
    if camera_options is not None and not isinstance(camera_options, Mapping):
        raise SwimInputError(f"camera_options must be a mapping of option names to values, got "
                             f"{type(camera_options).__name__}")
    # a number, not text or a flag that float() would take: a misread "2" or True is a mistake, not a height
    height_m = None
    if isinstance(height, (int, float, np.integer, np.floating)) and not isinstance(height, (bool, np.bool_)):
        height_m = float(height)
    if not (aerosol is None or isinstance(aerosol, (str, AerosolBackground, AerosolType))):
        raise SwimInputError(f"aerosol must be None (the default background), an aerosol type name, an AerosolType "
                             f"or an AerosolBackground; got {aerosol!r} ({type(aerosol).__name__})")
    filled_later = ()
    if "view_azimuth_deg" not in (camera_options or {}):  # default_perspective_view: the view, and from space its
        # field of view where no look_at is given (the ground's height, at most 9 km, not yet known)
        space = height_m is not None and height_m + 9000.0 > SPACE_VIEW_HEIGHT_M
        filled_later = ("view_azimuth_deg", "view_zenith_deg") + (("fov_deg",) if space and look_at is None else ())
    preview = check_camera_options(camera, dict(camera_options or {}), filled_later=filled_later)
    if check_memory:
        check_render_memory(int(np.prod(preview.shape)))
    if lat is not None and not (-90 <= float(lat) <= 90):
        raise SwimInputError(f"observer lat must be in [-90, 90] deg, got {lat}")
    if height_m is None or not np.isfinite(height_m) or height_m < 0:
        raise SwimInputError(f"observer height must be a number >= 0 [m above the ground], got {height!r}")
    check_coarsening(coarsen)
    return height_m, auto_exposure



def resolve_sun(time, scene, sun_zenith=None, sun_azimuth=None) -> SunPosition:
    """Sun position at the scene's reference point from the time or from explicit angles [deg]."""
    if (sun_zenith is None) != (sun_azimuth is None):
        raise SwimInputError("give both sun_zenith and sun_azimuth [deg] to override the sun, or neither")
    lat0, lon0 = float(scene.attrs["reference_lat"]), float(scene.attrs["reference_lon"])
    if sun_zenith is not None:
        return sun_from_angles(sun_zenith, sun_azimuth)
    if time is None:
        if "time" not in scene.coords:
            raise SwimInputError("no time given and the scene has no 'time' coordinate: pass time (ISO 8601, UTC)")
        time = pd.Timestamp(scene["time"].values)
    return sun_position(time, lat0, lon0)



def background_aerosol(aerosol, scene_vars) -> AerosolBackground:
    """The render's background aerosol (:func:`render`'s ``aerosol``): None gives the default background, or none
    where the scene has a 3-D ``aerosol_extinction`` or ``smoke_mass_content`` (of type ``smoke`` where it has only
    smoke) (``scene_vars``: the scene's variable names); ``"none"`` no
    background (a scene's 3-D aerosol stays); a type name, or an :class:`~swim.optics.aerosol_types.AerosolType`
    (e.g. a model aerosol's effective type, :mod:`swim.optics.model_aerosol`), that type with the default profile,
    or for the scene's 3-D aerosol alone where it has one."""
    scene_aerosol = "aerosol_extinction" in scene_vars or "smoke_mass_content" in scene_vars
    if aerosol is None and "aerosol_extinction" not in scene_vars and "smoke_mass_content" in scene_vars:
        return AerosolBackground(aod_550=0.0, type_name="smoke")  # the scene's aerosol is all smoke
    if aerosol is None:
        return AerosolBackground(aod_550=0.0) if scene_aerosol else AerosolBackground()
    if isinstance(aerosol, str) and aerosol.strip().lower() == "none":
        return AerosolBackground(aod_550=0.0)
    if isinstance(aerosol, str):
        return AerosolBackground(type_name=aerosol)
    if isinstance(aerosol, AerosolType):
        return AerosolBackground(aod_550=0.0, optics=aerosol) if scene_aerosol else AerosolBackground(optics=aerosol)
    return aerosol



#: Tilt [deg] between the verticals of a grid's columns (:func:`swim.rt.solar.column_tilt_deg`) above which the
#: clouds are scattered by the paper's method, composed at each ray's own vertical, instead of the 3-D diffuse
#: solution: whole-earth and hemispheric grids. Regional grids below it (a GFS region of 15 deg: 21.7 deg) keep the
#: 3-D solution, right near the reference point where a ground camera looks, and Step 1a's per-column sun
#: (docs/decisions/0020-per-column-sun.md).
WHOLE_EARTH_TILT_DEG = 30.0


def settings_for_sun(settings: MarchSettings, sun: SunPosition, sun_scene, volume: xr.Dataset | None = None
                     ) -> MarchSettings:
    """``settings``, with the 3-D cloud scattering replaced by the paper's method (the image's ``cloud_scattering``
    attribute says which ran) where the sun (``sun_scene``, its unit direction in the scene frame) is too low for the
    3-D diffuse solution (twilight and night skies, lit by the clear sky's tables), and on a grid whose columns tilt
    by more than :data:`WHOLE_EARTH_TILT_DEG` (``volume``, the optical volume: a whole-earth view), which the 3-D
    diffuse solution, solved for one sun in a flat frame, cannot light: there the paper's method composes each ray's
    clouds at its own vertical (docs/decisions/0020-per-column-sun.md). On such a grid the JAX kernel's
    composition keeps the reference point's vertical: a warning says that its cloud lighting far from the reference
    point is approximate."""
    clouds = settings.cloud_scattering
    per_column = volume is not None and per_column_sun(volume)
    whole_earth = per_column and column_tilt_deg(volume) > WHOLE_EARTH_TILT_DEG
    if per_column and settings.resolved_backend() == "jax":
        log.warning("the JAX kernel composes the clouds at the reference point's vertical: on this grid (its columns "
                    "tilt above %.0f deg) cloud lighting far from the reference point is approximate (backend "
                    "'numba' takes each ray's own vertical)", PER_COLUMN_SUN_TILT_DEG)
    if whole_earth and clouds.three_d:
        log.info("clouds scattered by the albers2020 method: the grid's columns tilt by more than %.0f deg, their suns "
                 "too far apart for the 3-D diffuse solution (one sun, a flat frame)", WHOLE_EARTH_TILT_DEG)
        return dataclasses.replace(settings, cloud_scattering=dataclasses.replace(clouds, method="albers2020"))
    if not (clouds.three_d and sun_scene[2] <= MIN_SUN_COSINE):
        return settings
    log.info("sun elevation %.2f deg: clouds scattered by the albers2020 method (the 3-D diffuse solution needs "
             "the sun above %.1f deg)", 90.0 - sun.zenith_deg, np.degrees(np.arcsin(MIN_SUN_COSINE)))
    return dataclasses.replace(settings, cloud_scattering=dataclasses.replace(clouds, method="albers2020"))



def fixed_white_level(white_level, exposure, height_asl) -> float:
    """The display's white level [-] of a fixed exposure: ``white_level``, or by default a camera's in the atmosphere
    and a satellite's above :data:`SPACE_VIEW_HEIGHT_M` (``height_asl`` [m]: the observer's), shifted by
    ``exposure`` [EV]."""
    if white_level is None:
        white_level = SPACE_WHITE_LEVEL if height_asl > SPACE_VIEW_HEIGHT_M else DEFAULT_WHITE_LEVEL
    return exposure_white_level(white_level, exposure)
