"""The orchestrator: :func:`render` runs the stages as functions between xarray and dataclass values, scene -> optical
volume -> solar and diffuse fields (kernel tables) -> camera rays -> march -> image (docs/architecture.md)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
import xarray as xr

from ..color.display import auto_white_level, exposure_white_level
from ..io.scene import as_scene
from ..memory import release_compiled_programs, release_free_memory
from ..rt import precompile
from ..rt.backends import march
from ..optics.aerosol_types import AerosolType
from ..rt.gas import AerosolBackground
from ..rt.image_sampling import AdaptiveSampling
from ..rt.march_settings import ExecutionSettings, MarchSettings
from .arguments import background_aerosol, checked_arguments, settings_for_sun
from .caches import STATE, DigestGuess, StaleDigest
from .image import colour_stage, image_dataset
from .moonlight import (LitImage, check_light, display_white_level, is_moon, light_direction_at_observer,
                        lights_attributes, progress_of, resolve_lights, sum_lit, with_the_light)
from .city_lights import add_city_lights, city_light_emission, with_city_lights_record
from .night_sky import add_night_sky, with_night_sky_record
from .scene_stage import camera_view, optical_volume, prepared_scene, scene_fingerprint
from .tables import kernel_tables

log = logging.getLogger(__name__)

#: Shortest time between two of :func:`render`'s counts of the process's memory mappings [s]
#: (:func:`swim.memory.release_compiled_programs`; a count costs tens of ms near the limit).
COMPILED_PROGRAMS_CHECK_S = 30.0



#: Images of fewer pixels skip the C heap's trims after the march and at the end of :func:`render`: they free a few
#: MB, and each ``malloc_trim`` walks the whole heap (1-3 ms, a tenth of a 41 x 41 render; swim.memory). So do
#: renders whose march runs on a GPU.
TRIM_MIN_PIXELS = 1 << 16



def render(scene: xr.Dataset, *, time=None, lat=None, lon=None, height=2.0, camera="allsky",
           camera_options=None, sun_zenith=None, sun_azimuth=None, look_at=None,
           aerosol: AerosolBackground | AerosolType | str | None = None, settings: MarchSettings = MarchSettings(),
           white_level=None, exposure: float = 0.0, progress=None, crop: bool = True,
           sampling: AdaptiveSampling | None = None, coarsen=None, check_memory: bool = True,
           execution: ExecutionSettings | None = None, light="sun") -> xr.Dataset:
    """Render what a camera at a vantage point sees in a scene.

    Parameters
    ----------
    scene : xarray.Dataset
        Canonical scene (docs/scene-format.md), e.g. from :func:`swim.open_scene`; or WRF output as a dataset,
        raw or post-processed by xwrf, or WPS output, read at ``time`` (:func:`swim.io.scene.as_scene`). Values may
        be pint quantities (MetPy's or pint-xarray's ``quantify()``): they are converted to the canonical units.
    time : str, datetime or pandas.Timestamp, optional
        UTC time; default: the scene's ``time`` coordinate. Not needed with ``sun_zenith``/``sun_azimuth``.
    lat, lon : float, optional
        Observer position [deg]; default: the scene's reference point.
    height : float
        Observer height above the ground [m] (above the terrain or sea surface under it).
    camera : {"allsky", "panorama", "perspective"}
        Camera kind (docs/frames.md); ``camera_options`` are passed to its constructor (e.g. ``size``,
        ``width``, ``height``, ``fov_deg``, ``view_azimuth_deg``, ``view_zenith_deg``).
    sun_zenith, sun_azimuth : float, optional
        Override the ephemeris [deg].
    look_at : tuple of float, optional
        (lat [deg], lon [deg], height [m above sea level]) for a perspective camera. Without it (and
        without view angles) a camera above 100 km looks straight down and fits the domain in its field
        of view, and a lower one looks at the horizon towards the north.
    aerosol : AerosolBackground, AerosolType or str, optional
        Background 1-D aerosol and the type of all aerosol (a type name or an ``AerosolType`` alone keeps the default
        profile, or none where the scene has a 3-D ``aerosol_extinction``; docs/aerosols.md); ``"none"``: no
        background aerosol; default: type "continental", AOD 0.05 at 550 nm, or no background where the scene has
        a 3-D ``aerosol_extinction`` (which a scene's 3-D aerosol keeps).
    settings : MarchSettings
        What the march computes and how accurately: its step counts, the scattering and the ground.
    white_level : float or "auto", optional
        Exposure: the solar-relative radiance mapped to display white before the tone curve, whose shoulder
        rolls brighter light off to neutral white (docs/colour.md); default 1.5 for observers in the atmosphere
        (a camera's exposure) and 4.0 above 100 km (reflectance 1 is white, as in satellite imagery). ``"auto"``:
        from the image's luminance, its log-average shown at 0.18 of white (a camera's average metering,
        :func:`swim.color.auto_white_level`). The radiance planes do not depend on it.
    exposure : float
        Exposure shift [EV, stops] on top of ``white_level``: +1 shows the image twice as bright.
    progress : callable, optional
        Called with (rays done, rays total).
    crop : bool
        First crop the scene lazily to the columns the camera's rays can reach, widened towards the sun for
        the shadows (:func:`swim.geometry.reach.crop_scene_to_view`; docs/rendering.md, "Cropping big
        grids"), so a big (or dask-backed) grid is never loaded in full. Not done for a perspective camera
        without ``view_azimuth_deg``/``view_zenith_deg`` in ``camera_options`` (its view comes from the whole
        grid), nor when the rays reach more than 90 % of the columns. False renders the whole grid.
    sampling : AdaptiveSampling, optional
        Trace a coarse lattice of pixels and only refine where the image is not smooth, interpolating the
        rest (:func:`swim.rt.image_sampling.sample_image_adaptive`; docs/rendering.md, "Adaptive
        sampling"): 2-5x fewer rays on typical scenes, within the sampling's tolerance where it interpolates.
        Default: every valid pixel is traced.
    coarsen : None, "auto" or int
        Keep one column (the middle one) of each block of N x N of the grid's columns, before anything is read in
        full, for a distant view whose pixels each cover several columns
        (:func:`swim.geometry.level_of_detail.coarsen_scene`, method ``"sample"``; docs/rendering.md, "Distant views
        of big grids"): the volume, Step 1a and the march then hold N^2 times fewer columns. ``"auto"``: the largest
        N whose blocks are no wider than the smallest pixel footprint on the grid (perspective cameras only; 1 for
        the others). Default None: the grid as it is.
    check_memory : bool
        Refuse, before any work, an image whose render would need more memory than the system has available
        (:data:`swim.pipeline.arguments.RENDER_BYTES_PER_PIXEL` per pixel); False renders it anyway.
    execution : ExecutionSettings, optional
        How and where the march runs (the kernel, its chunks, the device's switches); default:
        ``settings.execution``. They change the speed, not the image (to float32 rounding).
    light : {"sun", "moon", "sun+moon"} or swim.geometry.moon.MoonPosition
        What lights the scene: the sun, or the moon at the time (its phase, distance and irradiance, with the night
        sky but no twilight; docs/rendering.md, "Moonlight"), or a moon given as a ``MoonPosition``
        (:func:`swim.geometry.moon.moon_from_angles`). The radiance stays solar-relative (L' = 4 pi L / E_TOA, about
        1e-6 in moonlight) and the image's attributes ``light``, ``moon_*`` say so; the default exposure is then the
        full moon's (``white_level='auto'`` meters each image). ``"sun+moon"``: both at the time, their radiances
        summed (the night sky added once, where the sun is below the horizon), each marched only where it shows
        (the sun above -18 deg, the moon above -8 deg; attribute ``lights``), so that one setting serves a time series
        from day into a moonlit night (with ``white_level='auto'``; the default fixed exposure is the sun's while it
        is marched, the full moon's after). Not with ``sun_zenith``/``sun_azimuth``.

    Returns
    -------
    xarray.Dataset
        ``radiance`` (wavelength, y, x) [1]: solar-relative spectral radiance L' (Eq. 2) at 615/546/450 nm;
        ``rgb`` (y, x, channel) uint8 sRGB; ``view_azimuth``, ``view_zenith`` (y, x) [deg] in the observer's
        frame; ``tau_hydrometeor`` (y, x) [1], the hydrometeor optical depth along the line of sight (``stop_tau``
        of :class:`MarchSettings`, 50, where a ray that does not look down stops in opaque cloud: a lower bound);
        ``radiance_clear``, ``radiance_cloud``, ``radiance_surface``;
        attributes with the sun, observer, time and camera, ``traced_pixels`` (pixels whose ray was
        marched), ``march_samples`` (the volume samples the march took: per ray as marched by the "numba"
        kernel, the lockstep count of every ray's steps for "jax"; :func:`swim.rt.march.trace_rays`) and
        ``march_backend`` (the kernel that marched them, :class:`MarchSettings`).

    Raises
    ------
    SwimInputError
        Bad scene, observer below the terrain or out of reach, bad camera options, time or ``coarsen``; a march kernel
        (``settings.execution.backend``) that cannot run here (numba missing); an image too big for the
        memory available (``check_memory``).

    Notes
    -----
    The renders of a process share the last scene's stages: the optical volume, the packed grid and Step 1a. A
    render of the same scene and sun reuses them; a new sun (a time series' frame) redoes Step 1a only, into the
    same packed grid where no other render is running, else into a new one. Renders may run on several threads
    at once (a dask worker's; docs/decisions/0006-gpu-kernels.md). Where the march runs on a GPU, a scene whose arrays
    were rendered before is recognised by them and hashed while the device marches; if their values were changed in
    place since, the render finds it before it returns and renders the scene again (a warning says so, and
    ``progress`` counts the rays twice; docs/decisions/0006-gpu-kernels.md).
    """
    scene = as_scene(scene, time, lat, lon)  # model datasets read here (swim.io.formats); pint quantities made plain
    request = RenderRequest(time=time, lat=lat, lon=lon, height=height, camera=camera, camera_options=camera_options,
                            sun_zenith=sun_zenith, sun_azimuth=sun_azimuth, look_at=look_at, aerosol=aerosol,
                            settings=settings if execution is None else replace(settings, execution=execution),
                            white_level=white_level, exposure=exposure, progress=progress, crop=crop,
                            sampling=sampling, coarsen=coarsen, check_memory=check_memory, light=check_light(light))
    with STATE.rendering():
        guess = DigestGuess()
        try:
            image = _render(scene, request, guess)
            if guess.held():
                return image
            del image
        except StaleDigest:
            pass
        except Exception:
            if guess.held():
                raise
        # the scene's values changed in place since its arrays were last rendered: the image (or the error) came
        # from the stages of their old values. Forget both, and render again from the values as they are
        log.warning("the scene's values changed in place since its last render: rendering it again")
        STATE.forget()
        # a new guess: with the record forgotten none is taken, the scene is hashed first and remembered for the next
        return _render(scene, request, DigestGuess())


@dataclass(frozen=True, eq=False)
class RenderRequest:
    """:func:`render`'s arguments but the scene (described there)."""

    time: object
    lat: float | None
    lon: float | None
    height: float
    camera: str
    camera_options: object
    sun_zenith: float | None
    sun_azimuth: float | None
    look_at: tuple | None
    aerosol: object
    settings: MarchSettings
    white_level: object
    exposure: float
    progress: object
    crop: bool
    sampling: AdaptiveSampling | None
    coarsen: object
    check_memory: bool
    light: object = "sun"


def _render(scene, request: RenderRequest, guess: DigestGuess | None) -> xr.Dataset:
    """:func:`render`'s stages. ``guess``: where the scene's digest may be taken by its arrays' identity
    (:func:`swim.pipeline.caches.fingerprint_by_identity`; None: hashed first)."""
    height, auto_exposure = checked_arguments(scene, request)
    scene, coarsened_by = prepared_scene(scene, request, height)
    city = city_light_emission(scene)  # the scene's 2-D emission, before the volume's stage drops its values
    precompile.start(request.settings.resolved_backend())  # on a cold numba cache the march compiles meanwhile
    fingerprint = scene_fingerprint(scene, request.settings, guess)
    volume, scene, scene_vars = optical_volume(scene, fingerprint, guess)
    lights = resolve_lights(request, scene)  # the sun, the moon in its place, or both (swim.pipeline.moonlight)
    sun = lights.sun
    if sun.zenith_deg > 90 and request.light == "sun":
        log.warning("sun is %.1f deg below the horizon: twilight/night sky with stars and airglow (light='moon' or "
                    "'sun+moon' for moonlight)", sun.zenith_deg - 90)
    view = camera_view(volume, scene, request, height, np.asarray(sun.direction_enu, dtype=float))
    aerosol = background_aerosol(request.aerosol, scene_vars)
    white_level = None if auto_exposure else display_white_level(request, view.height_asl, lights)
    # the march colours the image only where the sun alone lights it: moonlight is scaled, two lights summed, first
    lit = sum_lit([_march_light(light, lights, volume, fingerprint, aerosol, request, view,
                                white_level if lights.sun_alone else None,
                                progress_of(request.progress, index, len(lights.marched)))
                   for index, light in enumerate(lights.marched)])
    radiance, recoloured, night = add_night_sky(lit.radiance, lit.recoloured, lit.planes, view, sun, aerosol, scene,
                                                night=is_moon(request.light))
    radiance, recoloured, city = add_city_lights(radiance, recoloured, lit.planes, view, sun, aerosol, volume, city,
                                                 night=is_moon(request.light))
    if auto_exposure:
        white_level = exposure_white_level(auto_white_level(radiance), request.exposure)
    rgb = colour_stage(radiance, white_level, lit.rgb, recoloured)
    image = image_dataset(
        radiance, rgb, lit.planes, view.camera, camera=request.camera, settings=lit.settings,
        sampling=request.sampling, sun=sun, sun_enu_observer=view.sun_enu, scene=scene,
        observer=(view.lat, view.lon, view.height, view.height_asl), reference=view.reference,
        exposure=(white_level, auto_exposure, request.exposure), aerosol=aerosol,
        march=(lit.samples, int(np.count_nonzero(lit.traced)), coarsened_by),
        transmittances=lit.transmittances("moon" if is_moon(sun) else "sun"))
    image.attrs.update(lights_attributes(lights, lit))
    image = with_night_sky_record(image, night)
    image = with_city_lights_record(image, city)
    trim = _trims(view, lit.on_accelerator)
    del radiance, rgb, lit
    if trim:
        release_free_memory()  # what the image's assembly freed, so the next render starts from the live arrays
    # A long-lived process that renders many grids keeps every program JAX compiled; near the process's limit of
    # memory mappings XLA's next executable would fail to map and leave the process to crash (swim.memory).
    release_compiled_programs(min_interval_s=COMPILED_PROGRAMS_CHECK_S)
    return image


def _trims(view, on_accelerator) -> bool:
    """Whether the render trims the C heap after a march and at its end: images of at least
    :data:`TRIM_MIN_PIXELS` pixels, not where the march ran on a GPU, whose host has the memory to spare
    (docs/decisions/0006-gpu-kernels.md)."""
    ny, nx = view.rays.shape
    return ny * nx >= TRIM_MIN_PIXELS and not on_accelerator


def _march_light(light, lights, volume, fingerprint, aerosol, request, view, white_level, progress) -> LitImage:
    """One light's stages: its march settings (:func:`swim.pipeline.arguments.settings_for_sun`), kernel tables and
    march, and its disk, scaled for the moon (:func:`swim.pipeline.moonlight.with_the_light`). ``light``: one of
    ``lights.marched`` (:class:`swim.pipeline.moonlight.Lights`); ``white_level``: where the march may colour the
    image, else None. The tables are let go before the next light's are made, which refill the shared packed
    volume with that light's Step 1a (:func:`swim.pipeline.tables.grid_constants`)."""
    light_scene = np.asarray(light.direction_enu, dtype=float)
    settings = settings_for_sun(request.settings, light, light_scene, volume)
    resolved = settings.resolved()  # the hardware asked once
    tables = kernel_tables(volume, fingerprint, aerosol, resolved, light_scene)
    marched = march(view.rays, tables, resolved, progress=progress, white_level=white_level)
    aureole = tables.cloud_optics is not None
    del tables
    if _trims(view, resolved.on_accelerator()):
        release_free_memory()  # the march's freed chunks, before the image is assembled
    radiance, recoloured, t_direct, t_aureole = with_the_light(
        light, marched.planes, marched.sun, view.camera, view.directions_enu, view.rays.valid,
        light_direction_at_observer(light, lights, view), aureole=aureole)
    return LitImage(radiance, recoloured, marched.planes, {"moon" if is_moon(light) else "sun": (t_direct, t_aureole)},
                    settings, marched.samples + int(marched.sun["steps"]), marched.traced, marched.rgb,
                    resolved.on_accelerator())
