"""The host's march: a camera's rays made on the host, marched in chunks by :func:`swim.rt.march.trace_rays` (the numba
kernel on the CPU's cores, or the JAX kernel without a ray table), and the image's planes scattered on the host.

Only the camera's valid pixels are traced (an all-sky image's corners are 21 % of its pixels), plus one extra ray
towards the sun for the direct-beam transmittance of the sun's disk, with the first batch.
"""

from __future__ import annotations

import logging

import numpy as np

from ...workers import parallel_map, threads
from ..image_sampling import sample_image_adaptive, tile_order
from ..kernel_tables import KernelTables
from ..march import trace_rays
from ..march_settings import MarchSettings
from . import IMAGE_OUTPUTS, CameraRays, MarchedImage

log = logging.getLogger(__name__)

#: Images of at least this many traced pixels are scattered into their planes on several threads (:func:`render`):
#: below it the pool's overhead (~0.02 ms a task) is not worth it.
PLANES_THREADED_PIXELS = 1 << 16


#: Rows per block of an adaptive render's planes, copied on several threads [-].
PLANE_BLOCK_ROWS = 64



class PixelTracer:
    """Traces batches of a camera's pixels in tile order (neighbouring pixels one after the other: they cross the same
    cells), the ray towards the sun with the first batch (:attr:`sun`: its outputs).

    ``table``: where the JAX kernel keeps the camera's rays on the device (:mod:`swim.rt.ray_table`), the camera's
    table, its pixels' rows and the phase functions' inputs, a batch sending only its rows' indices; None: the rays
    are made here and marched by :func:`swim.rt.march.trace_rays`."""

    def __init__(self, rays: CameraRays, tables: KernelTables, settings: MarchSettings, table=None):
        self.rays, self.tables, self.settings, self.table = rays, tables, settings, table
        self.sun = {}

    def trace(self, flat, progress_rays=None, tiled=False):
        """Trace the pixels ``flat``: the order in which they were traced (indices into ``flat``) and the rays'
        outputs in it. With ``tiled``, ``flat`` is already in tile order and traced as it is (the order: None)."""
        order = None if tiled else tile_order(flat, self.rays.shape)
        pixels = flat if tiled else flat[order]
        with_sun = not self.sun  # the sun's ray, last, with the first batch
        if self.table is not None:
            result = self._trace_table_rows(pixels, with_sun, progress_rays)
        else:
            dirs = np.empty((len(pixels) + with_sun, 3))
            np.take(self.rays.directions, pixels, axis=0, out=dirs[:len(pixels)])
            if with_sun:
                dirs[-1] = self.tables.sun_scene
            # the phase functions block by block (trace_rays), not held for every pixel of a big image at once
            result = trace_rays(np.broadcast_to(self.rays.observer, dirs.shape), dirs, self.tables.constants,
                                self.tables.geometry, self.tables.phase, self.settings, progress_rays)
        if with_sun:
            self.sun.update({key: value[-1] for key, value in result.items()})
            result = {key: value[:-1] for key, value in result.items()}
        return order, result

    def _trace_table_rows(self, pixels, with_sun, progress_rays):
        from ..ray_table import single_ray_table, trace_table_rows

        table, table_rows, phase_inputs = self.table
        # (the sun's ray is not the camera's, so not in its table: a one-row table of its own)
        extra = (single_ray_table(self.rays.observer, self.tables.sun_scene, self.tables.geometry,
                                  self.tables.constants, self.settings) if with_sun else None)
        return trace_table_rows(table, table_rows[pixels], self.tables.constants, phase_inputs, self.settings,
                                progress_rays, extra=extra)

    def for_sampler(self, flat, progress_rays=None):
        """The adaptive sampler's ``trace``: the outputs in tile order with that order (the sampler scatters each
        into its image once; put back into the order of ``flat`` first, each was copied twice: ~0.01 s of a 1024^2
        all-sky while the cores idled), only those that the image and the sampler's test read (the sampler keeps and
        interpolates every array it is given)."""
        order, result = self.trace(flat, progress_rays)
        kept = (*IMAGE_OUTPUTS, "surface", "steps")
        return order, {key: value for key, value in result.items() if key in kept}


def march(rays: CameraRays, tables: KernelTables, settings: MarchSettings, *, progress=None, white_level=None,
          table=None) -> MarchedImage:
    """:func:`swim.rt.backends.march` on the host: every valid pixel, or adaptively (``rays.sampling``).
    ``white_level`` is not used (the caller colours the image); ``table``: :class:`PixelTracer`'s."""
    tracer = PixelTracer(rays, tables, settings, table)
    if rays.sampling is None:
        return march_every_pixel(tracer, progress)
    return march_adaptively(tracer, progress)


def march_every_pixel(tracer: PixelTracer, progress=None) -> MarchedImage:
    """Every valid pixel of ``tracer``'s camera traced, in tile order, and scattered into the image's planes."""
    rays = tracer.rays
    log.info("tracing %d rays (%s)", int(rays.valid.sum()) + 1, rays.description)
    _, outputs = tracer.trace(rays.valid_pixels, progress, tiled=True)
    planes = scattered_planes({key: outputs.pop(key) for key in IMAGE_OUTPUTS}, rays.valid_pixels, *rays.shape)
    return MarchedImage(planes, tracer.sun, rays.valid.reshape(-1), int(outputs["steps"].sum()))


def log_adaptive(rays: CameraRays):
    """Log an adaptive render's sampling."""
    sampling = rays.sampling
    log.info("tracing adaptively (%s, %d valid pixels, tolerance %g, tau tolerance %g, clear tolerance %g, coarse "
             "spacing %d, edge tests in cells of %d pixels)", rays.description, int(rays.valid.sum()),
             sampling.tolerance, sampling.tau_tolerance, sampling.clear_tolerance, sampling.coarse_spacing,
             sampling.edge_test_size)


def log_traced(traced, valid):
    """Log how many of the valid pixels an adaptive render traced."""
    log.info("traced %d of %d valid pixels (%.1f %%)", int(traced.sum()), int(valid.sum()),
             100.0 * traced.sum() / max(int(valid.sum()), 1))


def march_adaptively(tracer: PixelTracer, progress=None) -> MarchedImage:
    """The image of ``tracer``'s camera sampled adaptively on the host
    (:func:`swim.rt.image_sampling.sample_image_adaptive`): NaN outside the camera's pixels from the start, so that
    the planes are copies in channel order, not masked (np.where over a transposed view took ~30 ms of a 1024^2
    image while the cores idled)."""
    rays = tracer.rays
    log_adaptive(rays)
    out, traced = sample_image_adaptive(tracer.for_sampler, rays.valid, rays.sampling, progress,
                                        max_threads=min(threads(), 8), outside=np.nan)
    log_traced(traced, rays.valid)
    planes = planes_of_samples(out, *rays.shape)
    return MarchedImage(planes, tracer.sun, traced, int(out["steps"].sum()))


def scattered_planes(outputs, pixels, ny, nx):
    """The image's planes (C, ny, nx) of the traced rays' ``outputs`` (name -> (n,) or (n, C)): NaN, then each ray's
    value at its flat pixel index ``pixels`` (n,). Every channel at once on the pools' threads (NumPy's scatter
    without the GIL): the 13 channels' scatters of a 1024^2 all-sky took 77 ms one after the other on a GPU machine's
    host while the device idled (docs/decisions/0006-gpu-kernels.md). Empties ``outputs``."""
    planes = {key: np.empty((value.shape[1] if value.ndim == 2 else 1, ny * nx), value.dtype)
              for key, value in outputs.items()}

    def scatter(row):  # one channel of one output
        key, channel = row
        value, plane = outputs[key], planes[key][channel]
        np.copyto(plane, np.nan)
        plane[pixels] = value[:, channel] if value.ndim == 2 else value

    parallel_map(scatter, [(key, c) for key, plane in planes.items() for c in range(plane.shape[0])],
                 min(threads(), 8) if pixels.size >= PLANES_THREADED_PIXELS else 1)
    outputs.clear()
    return {key: plane.reshape(-1, ny, nx) for key, plane in planes.items()}



def planes_of_samples(out, ny, nx):
    """The image's planes (C, ny, nx) of the adaptive sampler's image ``out`` (name -> (ny * nx,) or (ny * nx, C)),
    taking the outputs of :data:`IMAGE_OUTPUTS` out of it. One output at a time, its rows in blocks on several threads
    (NumPy's copy without the GIL), each output dropped once copied: with all of them copied at once, every output and
    its copy were alive together, the render's peak for big images (docs/decisions/0010-memory.md). The arrays travel
    in the blocks' items, so that no function outlives the loop holding the last output."""
    planes = {}

    def copy_rows(block):
        source, target, r0 = block
        np.copyto(target[:, r0:r0 + PLANE_BLOCK_ROWS], source[:, r0:r0 + PLANE_BLOCK_ROWS])

    for key in IMAGE_OUTPUTS:
        a = out.pop(key)
        if a.ndim == 1:
            planes[key] = a.reshape(1, ny, nx)
            continue
        source = a.reshape(ny, nx, -1).transpose(2, 0, 1)
        planes[key] = target = np.empty(source.shape, a.dtype)
        del a
        parallel_map(copy_rows, [(source, target, r0) for r0 in range(0, ny, PLANE_BLOCK_ROWS)],
                     min(threads(), 8) if ny * nx >= PLANES_THREADED_PIXELS else 1)
        del source, target
    return planes

