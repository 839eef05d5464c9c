"""The JAX kernel's march (:mod:`swim.rt.march_jax`): where the camera's rays are kept on the device
(:attr:`swim.rt.march_settings.ExecutionSettings.ray_table`, :mod:`swim.rt.ray_table`), a batch of pixels sends only
its rows' indices, and with :attr:`~swim.rt.march_settings.ExecutionSettings.device_image` or
:attr:`~swim.rt.march_settings.ExecutionSettings.device_sampling` the image's planes (and colour) are made there,
then copied to the host at once. Without a ray table the rays are the host's (:mod:`swim.rt.backends.host`).
"""

from __future__ import annotations

import logging

import numpy as np

from ..kernel_tables import KernelTables
from ..march_settings import MarchSettings
from . import IMAGE_OUTPUTS, CameraRays, MarchedImage, host

log = logging.getLogger(__name__)

#: The outputs of the sun's ray and of the adaptive sampler's batches that the image needs besides its planes.
KEPT_OUTPUTS = (*IMAGE_OUTPUTS, "surface", "steps")


def march(rays: CameraRays, tables: KernelTables, settings: MarchSettings, *, progress=None,
          white_level=None) -> MarchedImage:
    """:func:`swim.rt.backends.march` with the JAX kernel. ``white_level``: the colour stage's, where it may run on
    the device (:attr:`~swim.rt.march_settings.ExecutionSettings.device_image`), or None."""
    if not settings.resolved_ray_table():
        return host.march(rays, tables, settings, progress=progress)
    from ..ray_table import PhaseInputs, camera_ray_table

    table, table_rows = camera_ray_table(rays.observer, rays.directions, rays.valid_pixels, tables.geometry,
                                         tables.constants, settings)
    phase_inputs = PhaseInputs(tuple(float(x) for x in tables.sun_scene), float(tables.gas.depolarization),
                               tables.aerosol.type, tables.aerosol.stratospheric)
    tracer = host.PixelTracer(rays, tables, settings, (table, table_rows, phase_inputs))
    # the colour on the device needs the white level before the image exists: not with auto exposure
    device_image = settings.resolved_device_image()
    colour = white_level if device_image else None
    if rays.sampling is None and device_image and rays.valid_pixels.size:
        return _every_pixel_on_device(tracer, progress, colour)
    if rays.sampling is None:
        return host.march_every_pixel(tracer, progress)
    if settings.resolved_device_sampling():
        return _adaptively_on_device(tracer, progress, colour)
    return host.march_adaptively(tracer, progress)


def planes_to_host(device_planes, *extra, white_level=None):
    """The planes (on the device), coloured there first where ``white_level`` is given, copied to the host at once
    with ``extra``: the planes as writable host arrays (a CPU device's may be read-only views), the codes and flags
    of the colour stage (None without ``white_level``) and ``extra``."""
    import jax

    codes = None
    if white_level is not None:
        from ...color.srgb_device import solar_relative_to_srgb8_device

        codes = solar_relative_to_srgb8_device(device_planes["radiance"], white_level)
    device_planes, codes, extra = jax.device_get((device_planes, codes, extra))
    return ({key: value if value.flags.writeable else value.copy() for key, value in device_planes.items()},
            codes, extra)


def _sun_table(tracer):
    """The sun's ray in a one-row table of its own (not the camera's ray, so not in its table)."""
    from ..ray_table import single_ray_table

    return single_ray_table(tracer.rays.observer, tracer.tables.sun_scene, tracer.tables.geometry,
                            tracer.tables.constants, tracer.settings)


def _every_pixel_on_device(tracer, progress, white_level) -> MarchedImage:
    """Every valid pixel marched and its planes made on the device (in tile order: the table's rows in order, it was
    built from the valid pixels), then the sun's ray; one copy of the planes and the sun's row to the host."""
    from ..image_device import planes_on_device
    from ..ray_table import trace_table_rows

    rays, tables = tracer.rays, tracer.tables
    table = tracer.table[0]
    log.info("tracing %d rays (%s), the image made on the device", int(rays.valid.sum()) + 1, rays.description)
    result = trace_table_rows(table, range(table.size), tables.constants, tracer.table[2], tracer.settings,
                              progress, extra=_sun_table(tracer), on_device=True)
    device_planes, sun_row, first_steps = planes_on_device(
        result, rays.valid_pixels, rays.shape, IMAGE_OUTPUTS,
        sun_keys=("tau_clear", "tau_hydrometeor", "surface", "steps"))
    del result
    planes, rgb, (sun_row, first_steps) = planes_to_host(device_planes, sun_row, first_steps,
                                                         white_level=white_level)
    # the lockstep's steps, the same for every ray
    return MarchedImage(planes, dict(sun_row), rays.valid.reshape(-1), int(rays.valid_pixels.size) * int(first_steps),
                        rgb)


def _adaptively_on_device(tracer, progress, white_level) -> MarchedImage:
    """Adaptive sampling with the sampler's image on the device, beside the camera's ray table
    (:func:`swim.rt.image_sampling_device.sample_image_adaptive_device`); one copy of all the arrays to the host."""
    from ..image_device import device_plane
    from ..image_sampling_device import sample_image_adaptive_device

    rays = tracer.rays
    host.log_adaptive(rays)
    sun_rows = {}
    out, traced = sample_image_adaptive_device(lambda pixels: _trace_on_device(tracer, pixels, sun_rows), rays.valid,
                                               rays.sampling, progress, outside=np.nan,
                                               chunk=tracer.settings.resolved_chunk())
    # the image's planes (C, ny, nx) made on the device, then one copy of all the arrays to the host with the sun's
    # row; with device_image coloured there first
    ny, nx = rays.shape
    device_planes = {key: device_plane(out.pop(key), ny, nx) for key in IMAGE_OUTPUTS}
    planes, rgb, (out, traced, sun_padded) = planes_to_host(device_planes, out, traced, sun_rows,
                                                            white_level=white_level)
    traced = np.asarray(traced)
    host.log_traced(traced, rays.valid)
    sun = {key: value[0] for key, value in sun_padded.items()}  # the rest is the chunk's padding
    return MarchedImage(planes, sun, traced, int(out["steps"].sum()), rgb)


def _trace_on_device(tracer, pixels, sun_rows):
    """A bucketed batch of the device's sampler (its last pixel repeated), its outputs left on the device. The sampler
    asks for one batch at least (an empty one where nothing is traced), so the sun's ray is always marched here, first,
    into ``sun_rows``."""
    from ..ray_table import trace_table_rows

    table, table_rows, phase_inputs = tracer.table
    constants = tracer.tables.constants
    if not sun_rows:
        # the sun's ray in a one-row batch of its own (with a full bucket's rows it would double the batch's padded
        # size; so the samples count no step that only the sun's ray needs), its outputs left on the device: queued
        # without a wait, its row copied with the image's planes
        sun_rows.update(trace_table_rows(_sun_table(tracer), np.zeros(1, np.int64), constants, phase_inputs,
                                         tracer.settings, on_device=True))
    if len(pixels) == 0:  # no valid pixel in the image: its outputs' keys and types, without rows
        return {key: value[:0] for key, value in sun_rows.items() if key in KEPT_OUTPUTS}
    # the batch's own pixels, then its last one repeated up to its bucket: the repeats marched as padding (rays that
    # start stopped, sample_image_adaptive_device drops their rows)
    own = int(np.argmax(pixels == pixels[-1])) + 1
    result = trace_table_rows(table, table_rows[pixels], constants, phase_inputs, tracer.settings, on_device=True,
                              padding_from=own)
    return {key: value for key, value in result.items() if key in KEPT_OUTPUTS}
