"""The differentiable forward operator: cloud liquid water content -> the observers' radiance images.

:class:`ForwardOperator` (``swim.forward_operator``) maps a state, the cloud liquid water content on the scene's grid
[kg m-3], to the images of radiance that the observers' cameras see, through the whole chain (docs/assimilation.md):
Eq. 7's extinction, the resampling onto the optical volume's levels, Step 1a's transmittance T (the clouds' shadows
on the air, the clouds and the ground), the march's single-scattering and diffuse sources and the composition of
Eqs. 12-26 and the ground's Eq. 35. Its tangent-linear and adjoint operators are JAX's ``jax.jvp`` and ``jax.vjp``
of that chain, taken chunk by chunk of rays so that memory stays bounded. What is held fixed at the reference state
(the step placement, the scattering tables, the geometry) is built once by :func:`swim.assimilation.setup.build_setup`.

References
----------
Albers et al. (2020), doi:10.5194/amt-13-3235-2020 (the forward model); Errico (1997), What is an adjoint model?,
Bull. Amer. Meteor. Soc. 78, 2577-2591, doi:10.1175/1520-0477(1997)078<2577:WIAAM>2.0.CO;2 (the tangent-linear and
adjoint operators and their tests).
"""

from __future__ import annotations

import functools
import logging

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import SwimInputError
from ..rt.march_settings import MarchSettings
from .march import chunk_radiance
from .setup import DEFAULT_CHUNK, Observer, Setup, build_setup, ray_images
from .state import march_inputs

log = logging.getLogger(__name__)


@functools.partial(jax.jit, static_argnames=("settings",))
def _chunk_jvp(volume, surface, d_volume, d_surface, consts, chunk, settings):
    """The radiance (n, 3) of a chunk of rays and its directional derivative along (d_volume, d_surface)."""
    return jax.jvp(lambda v, s: chunk_radiance(v, s, consts, chunk, settings), (volume, surface),
                   (d_volume, d_surface))


@functools.partial(jax.jit, static_argnames=("settings",))
def _chunk_vjp(volume, surface, consts, chunk, cotangent, settings):
    """The adjoint of a chunk's radiance: the cotangent (n, 3) pulled back onto the packed volume and the ground's
    fields."""
    _, pull = jax.vjp(lambda v, s: chunk_radiance(v, s, consts, chunk, settings), volume, surface)
    return pull(cotangent)


class ForwardOperator:
    """The observers' radiance images as a differentiable function of the cloud liquid water content.

    Parameters
    ----------
    scene : xarray.Dataset
        Canonical scene (docs/scene-format.md) with ``cloud_liquid_content`` [kg m-3], the reference state: the step
        placement and the other fixed set-up are taken from it.
    observers : sequence of Observer
        The cameras (:class:`swim.assimilation.setup.Observer`).
    sun_zenith, sun_azimuth : float
        The sun's zenith angle and azimuth [deg] at the scene's reference point, fixed.
    aerosol : AerosolBackground, optional
        The background aerosol (default :class:`swim.rt.gas.AerosolBackground`).
    settings : MarchSettings, optional
        The march's step counts; refinement, the stop in opaque cloud and the 3-D cloud scattering are turned off
        (:data:`swim.assimilation.setup.DIFFERENTIABLE`).
    chunk : int
        Rays per chunk of the march (memory: each chunk's reverse pass holds its rays' states at every step).
    dtype : jax.numpy dtype
        float32 (the kernel's), or float64 (with ``jax_enable_x64``) for derivative checks.

    Attributes
    ----------
    reference_state : numpy.ndarray
        (z, y, x) the scene's ``cloud_liquid_content`` [kg m-3].
    masks : list of numpy.ndarray
        (ny, nx) bool per observer: the pixels that have a ray (the others are 0 in every image).

    Raises
    ------
    SwimInputError
        If the scene has no ``cloud_liquid_content``, the observers are not a non-empty list of ``Observer`` or their
        cameras have no pixels; a state of the wrong shape or with values that are not finite.

    Notes
    -----
    The state is taken as it is: negative contents give a negative extinction (the linear continuation of Eq. 7
    below the Martin et al. radius's floor), which keeps the operator smooth for finite-difference and line-search
    steps; a minimiser keeps its iterates non-negative (e.g. through a change of variables).
    """

    def __init__(self, scene, observers, *, sun_zenith, sun_azimuth, aerosol=None, settings: MarchSettings = None,
                 chunk=DEFAULT_CHUNK, dtype=jnp.float32):
        self.setup: Setup = build_setup(scene, observers, sun_zenith, sun_azimuth, aerosol, settings, chunk, dtype)
        self.dtype = dtype
        layout = self.setup.layout
        self._inputs = jax.jit(lambda lwc, state_map: march_inputs(lwc, state_map, layout))

    @property
    def reference_state(self) -> np.ndarray:
        """The scene's cloud liquid water content (z, y, x) [kg m-3]: the state the fixed set-up was built from."""
        return self.setup.reference_state

    @property
    def masks(self) -> list:
        """One (ny, nx) bool array per observer: the pixels that have a ray."""
        return self.setup.masks

    def sun_angles(self) -> list:
        """One (ny, nx) array per observer: the angle [deg] between each pixel's line of sight and the direction to
        the sun (NaN at pixels without a ray)."""
        cos = np.concatenate([np.asarray(chunk["rays"]["cos_theta"], float) for chunk in self.setup.chunks])
        return ray_images(self.setup, np.degrees(np.arccos(np.clip(cos[:self.setup.n_rays], -1.0, 1.0))), np.nan)

    def masks_without_sun(self, radius_deg=5.0) -> list:
        """One (ny, nx) float mask per observer for the misfits: 1 at the pixels with a ray farther than
        ``radius_deg`` [deg] from the sun, 0 elsewhere (the paper's exclusion of the sun's glare, Albers et al.
        2020, Sect. 4.2.3).

        Raises
        ------
        SwimInputError
            If ``radius_deg`` is not a finite number in [0, 180).
        """
        try:
            radius = float(radius_deg)
        except (TypeError, ValueError):
            radius = np.nan
        if not 0.0 <= radius < 180.0:
            raise SwimInputError(f"ForwardOperator.masks_without_sun: radius_deg must be in [0, 180) [deg], got "
                                 f"{radius_deg!r}")
        return [np.where(np.nan_to_num(angle, nan=-1.0) > radius, 1.0, 0.0) for angle in self.sun_angles()]

    def _checked(self, name, state):
        shape = self.setup.state_shape
        if tuple(np.shape(state)) != tuple(shape):
            raise SwimInputError(f"forward_operator: {name} must have the scene's shape (z, y, x) = {shape} "
                                 f"[kg m-3], got {np.shape(state)}")
        if not isinstance(state, jax.core.Tracer) and not bool(jnp.all(jnp.isfinite(jnp.asarray(state)))):
            raise SwimInputError(f"forward_operator: {name} must be finite [kg m-3]")
        return jnp.asarray(state, self.dtype)

    def _images(self, radiance):
        """The observers' images (3, ny, nx) from the rays' radiance (n_rays, 3), 0 where a pixel has no ray."""
        images, first = [], 0
        for shape, flat in zip(self.setup.shapes, self.setup.pixels):
            rows = radiance[first:first + flat.size]
            first += flat.size
            image = jnp.zeros((3, shape[0] * shape[1]), radiance.dtype).at[:, flat].set(rows.T)
            images.append(image.reshape(3, *shape))
        return images

    def _ray_cotangent(self, dimages):
        """The rays' cotangent (n_rays, 3) of the images' (the adjoint of :meth:`_images`)."""
        if len(dimages) != len(self.setup.shapes):
            raise SwimInputError(f"forward_operator: one cotangent image per observer is needed, "
                                 f"{len(self.setup.shapes)}; got {len(dimages)}")
        rows = []
        for shape, flat, image in zip(self.setup.shapes, self.setup.pixels, dimages):
            image = jnp.asarray(image, self.dtype)
            if image.shape != (3,) + tuple(shape):
                raise SwimInputError(f"forward_operator: an image's cotangent must have the shape (3, ny, nx) = "
                                     f"{(3,) + tuple(shape)}, got {image.shape}")
            rows.append(image.reshape(3, -1)[:, flat].T)
        return jnp.concatenate(rows)

    def _chunk_rows(self, values):
        """``values`` (n_rays, ...) cut into the chunks' rows, the last padded with zeros."""
        out, first = [], 0
        for chunk in self.setup.chunks:
            n = chunk["valid"].shape[0]
            rows = values[first:first + n]
            first += n
            if rows.shape[0] < n:
                rows = jnp.concatenate([rows, jnp.zeros((n - rows.shape[0],) + rows.shape[1:], rows.dtype)])
            out.append(rows)
        return out

    def _radiance(self, rows):
        """The rays' radiance (n_rays, 3) from the chunks' rows."""
        return jnp.concatenate(rows)[:self.setup.n_rays]

    def march_inputs(self, state):
        """The packed volume (level, y, x, channel) and the ground's fields (channel, y', x') of a state."""
        return self._inputs(self._checked("state", state), self.setup.state_map)

    def __call__(self, state):
        """The observers' radiance images: a list of (3, ny, nx) arrays [-] (solar-relative L' at 615/546/450 nm,
        Eq. 2) of a state (z, y, x) [kg m-3]."""
        volume, surface = self.march_inputs(state)
        s = self.setup
        rows = [chunk_radiance(volume, surface, s.consts, chunk, s.settings) for chunk in s.chunks]
        return self._images(self._radiance(rows))

    def tangent_linear(self, state, dstate):
        """The images' directional derivatives (a list of (3, ny, nx)) at ``state`` along ``dstate`` (z, y, x)."""
        state, dstate = self._checked("state", state), self._checked("dstate", dstate)
        (volume, surface), (d_volume, d_surface) = jax.jvp(lambda x: self._inputs(x, self.setup.state_map),
                                                           (state,), (dstate,))
        s = self.setup
        rows = [_chunk_jvp(volume, surface, d_volume, d_surface, s.consts, chunk, s.settings)[1]
                for chunk in s.chunks]
        return self._images(self._radiance(rows))

    def adjoint(self, state, dimages):
        """The adjoint: the images' cotangents ``dimages`` (a list of (3, ny, nx), one per observer) pulled back to
        the state, (z, y, x) [per kg m-3 of the images' units]."""
        state = self._checked("state", state)
        (volume, surface), pull = jax.vjp(lambda x: self._inputs(x, self.setup.state_map), state)
        s = self.setup
        d_volume, d_surface = jnp.zeros_like(volume), jnp.zeros_like(surface)
        for chunk, cotangent in zip(s.chunks, self._chunk_rows(self._ray_cotangent(dimages))):
            dv, ds = _chunk_vjp(volume, surface, s.consts, chunk, cotangent, s.settings)
            d_volume, d_surface = d_volume + dv, d_surface + ds
        return pull((d_volume, d_surface))[0]

    def value_and_grad(self, loss, state):
        """``loss(images)`` (a JAX-differentiable scalar function of the list of images) and its gradient with
        respect to the state (z, y, x), through :meth:`adjoint`."""
        images = self(state)
        value, pull = jax.vjp(loss, images)
        return value, self.adjoint(state, pull(jnp.ones_like(value))[0])


def forward_operator(scene, observers, **options) -> ForwardOperator:
    """The differentiable forward operator of a scene seen by ``observers``: :class:`ForwardOperator` (its options
    described there)."""
    return ForwardOperator(scene, observers, **options)


__all__ = ["ForwardOperator", "Observer", "forward_operator"]
