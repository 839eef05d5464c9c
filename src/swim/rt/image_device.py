"""An image's planes made on the device from the march's outputs, where the camera's rays are kept there
(:mod:`swim.rt.ray_table`; ``ExecutionSettings.device_image``).

With every pixel traced, copying each chunk's outputs back to the host and scattering each output's channels into the
image's planes (C, ny, nx) on its cores takes ~53 MB of rows and 13 channel scatters for a 1024^2 all-sky while the
device idles. Here the chunks' outputs stay on the device, one program scatters them into the planes, and the frame's
planes (and its colour, :mod:`swim.color.srgb_device`) come back in one copy (docs/decisions/0006-gpu-kernels.md).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..compilation.jax_export import exported_jit


@functools.partial(jax.jit, static_argnames=("ny", "nx"))
def device_plane(values, ny, nx):
    """An image's output as rows of its pixels, (ny * nx, C) or (ny * nx,), as its plane (C, ny, nx), on the device:
    its copy to the host is then the plane itself (the host's transposes of a 1024^2 image's ~40 MB took the threads
    of :func:`swim.workers.parallel_map`). For the device's adaptive sampler's images and :func:`planes_on_device`."""
    return values.reshape(ny, nx, -1).transpose(2, 0, 1)


@exported_jit(static_argnames=("keys", "n_pixels", "ny", "nx", "sun_keys"))
def _planes(outputs, pixels, *, keys, n_pixels, ny, nx, sun_keys):
    """The planes (C, ny, nx) of ``outputs``' ``keys`` (NaN where no pixel), the row after the pixels' (the sun's
    ray) of ``sun_keys`` and the first ray's ``steps``."""
    n = ny * nx
    planes = {}
    for key in keys:
        value = outputs[key][:n_pixels]
        rows = value.reshape(n_pixels, -1)
        planes[key] = device_plane(jnp.full((n, rows.shape[1]), jnp.nan, rows.dtype).at[pixels].set(rows), ny, nx)
    sun = {key: outputs[key][n_pixels] for key in sun_keys}
    return planes, sun, outputs["steps"][0]


def planes_on_device(outputs, pixels, shape, keys, sun_keys=()):
    """The image's planes of the march's outputs for ``pixels``, on the device.

    Parameters
    ----------
    outputs : dict of jax.Array
        The march's outputs on the device (:func:`swim.rt.ray_table.trace_table_rows` with ``on_device``), each
        (m + k, ...) with m >= len(pixels): the pixels' rays first, in the order of ``pixels``, then, where
        ``sun_keys`` are given, the sun's ray, then padding rows; ``steps`` among them.
    pixels : numpy.ndarray
        Shape (p,) int: the flat pixel indices (row-major in the (ny, nx) image) of the first p rows, p >= 1.
    shape : tuple of int
        (ny, nx): the image's size [pixels].
    keys : sequence of str
        Outputs that become planes: float arrays (m + k,) or (m + k, C).
    sun_keys : sequence of str
        Outputs whose row p (the sun's ray, after the pixels') is returned too.

    Returns
    -------
    planes : dict of jax.Array
        Shape (C, ny, nx) per key (C = 1 for a 1-D output), NaN at the pixels not in ``pixels``.
    sun : dict of jax.Array
        Row p of each of ``sun_keys``.
    steps : jax.Array
        Scalar int: the first ray's ``steps``. The JAX kernel marches every ray of a batch in lockstep and counts the
        same steps for each (:func:`swim.rt.ray_table.trace_table_rows`), so the pixels' rays took p times as many
        samples (a sum on the device would overflow int32 for images of more than ~12 million pixels).

    Raises
    ------
    ValueError
        If ``pixels`` is empty, or ``outputs`` have fewer rows than the pixels (plus the sun's where asked for).
    """
    pixels = np.asarray(pixels)
    p = int(pixels.size)
    rows = int(outputs["steps"].shape[0])
    if p == 0 or rows < p + (1 if sun_keys else 0):
        raise ValueError(f"planes_on_device: {rows} rows of outputs for {p} pixels"
                         f"{' and the sun' if sun_keys else ''}")
    ny, nx = (int(s) for s in shape)
    return _planes({key: outputs[key] for key in {*keys, *sun_keys, "steps"}}, jnp.asarray(pixels.astype(np.int32)),
                   keys=tuple(keys), n_pixels=p, ny=ny, nx=nx, sun_keys=tuple(sun_keys))
