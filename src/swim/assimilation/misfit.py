"""Image misfits for the forward operator: the root-mean-square difference and 1 - r (Pearson's r, Eq. 37 of Albers et
al. 2020), both with pixel masks, both differentiable (JAX).

Both take images of shape (channel, ny, nx) (the operator's radiance: 615/546/450 nm) or lists of them (several
observers), the reference images alike, and optional masks (ny, nx) per image: a pixel counts with its mask's
weight (bool or in [0, 1]: e.g. 0 within 5 deg of the sun, where camera glare dominates, as the paper masks it, and
outside the camera's circle). Pixels are pooled over all images; channels are pooled by the RMSE and averaged as
r-bar by 1 - r.

References
----------
Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Eq. 37 and Sect. 5 (r, r-bar over the R, G and B channels, the
masked circle around the sun).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..errors import SwimInputError


def _pooled(images, reference, masks):
    """Images, reference and weights as (channel, pixels) arrays pooled over all images.

    Raises
    ------
    SwimInputError
        If the images, reference and masks do not match in number and shape, or no pixel has weight.
    """
    if not isinstance(images, (list, tuple)):
        images, reference = [images], [reference]
        masks = None if masks is None else [masks]
    if len(reference) != len(images) or (masks is not None and len(masks) != len(images)):
        raise SwimInputError(f"misfit: {len(images)} images need as many reference images and masks, got "
                             f"{len(reference)} and {None if masks is None else len(masks)}")
    xs, ys, ws = [], [], []
    for n, (x, y) in enumerate(zip(images, reference)):
        x, y = jnp.asarray(x), jnp.asarray(y)
        if x.ndim != 3 or x.shape != y.shape:
            raise SwimInputError(f"misfit: image {n} must be (channel, ny, nx) and match its reference, got "
                                 f"{x.shape} and {y.shape}")
        w = jnp.ones(x.shape[1:], x.dtype) if masks is None else jnp.asarray(masks[n], x.dtype)
        if w.shape != x.shape[1:]:
            raise SwimInputError(f"misfit: mask {n} must be (ny, nx) = {x.shape[1:]}, got {w.shape}")
        xs.append(x.reshape(x.shape[0], -1))
        ys.append(y.reshape(y.shape[0], -1))
        ws.append(w.reshape(-1))
    w = jnp.concatenate(ws)
    if _concrete(w):
        values = np.asarray(w)
        if not (np.all(np.isfinite(values)) and values.min() >= 0 and values.sum() > 0):
            raise SwimInputError("misfit: the masks leave no pixel, or have weights that are not finite and >= 0")
    return jnp.concatenate(xs, axis=1), jnp.concatenate(ys, axis=1), w


def _concrete(a) -> bool:
    """Whether ``a`` holds values (not a tracer inside a JAX transformation)."""
    try:
        np.asarray(a)
    except Exception:  # noqa: BLE001  (a tracer cannot be converted)
        return False
    return True


def rmse(images, reference, masks=None):
    """Root-mean-square difference of images and reference images over the masked pixels and all channels.

    Parameters
    ----------
    images, reference : array or list of arrays
        (channel, ny, nx) each [any units, e.g. the solar-relative radiance L'].
    masks : array or list of arrays, optional
        (ny, nx) weights per image (bool, or >= 0): a pixel's squared differences count with its weight.

    Returns
    -------
    jax.Array
        Scalar sqrt(sum_w (x - y)^2 / (C sum_w)) [units of the images].

    Raises
    ------
    SwimInputError
        If shapes do not match or no pixel has weight.
    """
    x, y, w = _pooled(images, reference, masks)
    return jnp.sqrt(jnp.sum(w[None, :] * (x - y) ** 2) / (x.shape[0] * jnp.sum(w)))


def one_minus_r(images, reference, masks=None):
    """1 - r-bar: one minus the mean over channels of Pearson's correlation r (Eq. 37) of the masked pixels.

    Parameters
    ----------
    images, reference : array or list of arrays
        (channel, ny, nx) each.
    masks : array or list of arrays, optional
        (ny, nx) weights per image (bool, or >= 0): Eq. 37's sums taken with these weights (N = sum of weights).

    Returns
    -------
    jax.Array
        Scalar 1 - (1/C) sum_c r_c in [0, 2]; 0 for images that are an increasing linear function of the reference
        in every channel.

    Raises
    ------
    SwimInputError
        If shapes do not match or no pixel has weight.

    Notes
    -----
    Eq. 37 in its centred form, r = sum w (x - x_mean)(y - y_mean) / sqrt(sum w (x - x_mean)^2 sum w (y -
    y_mean)^2), which equals it and does not lose digits to cancellation; a channel constant over the masked pixels
    has no r (NaN).

    References
    ----------
    Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Eq. 37 (r), Sect. 5 (r-bar, the mean of the channels' r).
    """
    x, y, w = _pooled(images, reference, masks)
    total = jnp.sum(w)
    dx = x - jnp.sum(w[None, :] * x, axis=1, keepdims=True) / total
    dy = y - jnp.sum(w[None, :] * y, axis=1, keepdims=True) / total
    r = jnp.sum(w * dx * dy, axis=1) / jnp.sqrt(jnp.sum(w * dx * dx, axis=1) * jnp.sum(w * dy * dy, axis=1))
    return 1.0 - jnp.mean(r)
