"""The differentiable forward operator: hydrometeors and aerosol -> the observers' radiance images.

:class:`ForwardOperator` (``swim.forward_operator``) maps a state, the cloud liquid water content on the scene's grid
[kg m-3] or any of the hydrometeors' contents and effective radii and the 3-D aerosol's extinction
(:mod:`swim.assimilation.state`), to the images of radiance that the observers' cameras see, through the whole chain
(docs/assimilation.md): Eq. 7's extinction, the resampling onto the optical volume's levels, Step 1a's transmittance
T (the clouds' shadows on the air, the clouds and the ground), the march's single-scattering and diffuse sources and
the composition of Eqs. 12-26 and the ground's Eq. 35. Its tangent-linear and adjoint operators are JAX's ``jax.jvp``
and ``jax.vjp`` of that chain, taken chunk by chunk of rays so that memory stays bounded. What is held fixed at the
reference state (the step placement, the scattering tables, the geometry) is built once by
:func:`swim.assimilation.setup.build_setup`.

References
----------
Albers et al. (2020), doi:10.5194/amt-13-3235-2020 (the forward model); Errico (1997), What is an adjoint model?,
Bull. Amer. Meteor. Soc. 78, 2577-2591, doi:10.1175/1520-0477(1997)078<2577:WIAAM>2.0.CO;2 (the tangent-linear and
adjoint operators and their tests).
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr

from ..errors import SwimInputError
from ..rt.march_settings import MarchSettings
from .march import chunk_radiance
from .setup import DEFAULT_CHUNK, DEFAULT_VARIABLES, Observer, Setup, build_setup, ray_images
from .state import RADIUS_VARIABLES, STATE_UNITS, march_inputs

log = logging.getLogger(__name__)


@functools.partial(jax.jit, static_argnames=("settings",))
def _chunk_jvp(inputs, d_inputs, consts, chunk, settings):
    """The radiance (n, 3) of a chunk of rays and its directional derivative along ``d_inputs`` (the march's
    differentiable inputs: :func:`swim.assimilation.state.march_inputs`)."""
    return jax.jvp(lambda a: chunk_radiance(a, consts, chunk, settings), (inputs,), (d_inputs,))


@functools.partial(jax.jit, static_argnames=("settings",))
def _chunk_vjp(inputs, consts, chunk, cotangent, settings):
    """The adjoint of a chunk's radiance: the cotangent (n, 3) pulled back onto the march's differentiable inputs."""
    _, pull = jax.vjp(lambda a: chunk_radiance(a, consts, chunk, settings), inputs)
    return pull(cotangent)[0]


class ForwardOperator:
    """The observers' radiance images as a differentiable function of the state: the hydrometeors' contents and
    effective radii and the 3-D aerosol's extinction on the scene's grid.

    Parameters
    ----------
    scene : xarray.Dataset
        Canonical scene (docs/scene-format.md): its values of the state's variables are the reference state (the
        step placement and the other fixed set-up are taken from it); what the state does not hold is held fixed.
    observers : sequence of Observer
        The cameras (:class:`swim.assimilation.setup.Observer`).
    sun_zenith, sun_azimuth : float
        The sun's zenith angle and azimuth [deg] at the scene's reference point, fixed.
    state_variables : sequence of str
        The state's variables (:data:`swim.assimilation.state.STATE_VARIABLES`): ``<species>_content`` [kg m-3] and
        ``<species>_effective_radius`` [m] of the species of :data:`swim.constants.SPECIES`, ``aerosol_extinction``
        [m-1] (550 nm). Default: the cloud liquid water content alone.
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
    state_variables : tuple of str
        The state's variables.
    reference_state : dict or numpy.ndarray
        The scene's values of the state's variables, (z, y, x) each (a state's radii as Eq. 7 takes them).
    masks : list of numpy.ndarray
        (ny, nx) bool per observer: the pixels that have a ray (the others are 0 in every image).

    Raises
    ------
    SwimInputError
        If the state's variables are unknown or the scene does not give their reference (a varied species' content;
        for ``aerosol_extinction`` a 3-D aerosol not zero everywhere), the observers are not a non-empty list of
        ``Observer`` or their cameras have no pixels; a state that lacks a variable, has one of the wrong shape,
        values that are not finite, or radii that are not positive.

    Notes
    -----
    A state is an xarray.Dataset or a dict of (z, y, x) arrays by variable name, or for a one-variable state also a
    bare (z, y, x) array; :meth:`adjoint` and :meth:`value_and_grad` return the gradient in the state's own kind.
    The state is taken as it is: negative contents give a negative extinction (the linear continuation of Eq. 7
    below the Martin et al. radius's floor), which keeps the operator smooth for finite-difference and line-search
    steps; a minimiser keeps its iterates non-negative (e.g. through a change of variables).
    """

    def __init__(self, scene, observers, *, sun_zenith, sun_azimuth, state_variables=DEFAULT_VARIABLES,
                 aerosol=None, settings: MarchSettings = None, chunk=DEFAULT_CHUNK, dtype=jnp.float32):
        self.setup: Setup = build_setup(scene, observers, sun_zenith, sun_azimuth, aerosol, settings, chunk, dtype,
                                        state_variables)
        self.dtype = dtype
        layout = self.setup.layout
        self._inputs = jax.jit(lambda state, state_map: march_inputs(state, state_map, layout))

    @property
    def state_variables(self) -> tuple:
        """The state's variables (names of :data:`swim.assimilation.state.STATE_VARIABLES`)."""
        return self.setup.layout.variables

    @property
    def reference_state(self):
        """The scene's values of the state's variables: the state the fixed set-up was built from, a dict of (z, y, x)
        arrays (for a one-variable state its array)."""
        reference = self.setup.reference_state
        return next(iter(reference.values())) if len(reference) == 1 else dict(reference)

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

    def _checked(self, name, state, radii=True):
        """``state`` as a dict of (z, y, x) arrays in the operator's dtype, and its kind (:func:`state_parts`)."""
        parts, kind = state_parts(state, self.state_variables, name)
        shape = tuple(self.setup.state_shape)
        out = {}
        for variable, value in parts.items():
            units = STATE_UNITS[variable]
            if tuple(np.shape(value)) != shape:
                raise SwimInputError(f"forward_operator: {name}'s {variable} must have the scene's shape (z, y, x) = "
                                     f"{shape} [{units}], got {np.shape(value)}")
            value = jnp.asarray(value, self.dtype)
            if not isinstance(value, jax.core.Tracer):
                if not bool(jnp.all(jnp.isfinite(value))):
                    raise SwimInputError(f"forward_operator: {name}'s {variable} must be finite [{units}]")
                if radii and variable in RADIUS_VARIABLES and not bool(jnp.all(value > 0)):
                    raise SwimInputError(f"forward_operator: {name}'s {variable} must be > 0 in every cell [m] (Eq. 7 "
                                         f"divides by it; give any positive radius where there is no content)")
            out[variable] = value
        return out, kind

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
        """The march's differentiable inputs of a state (:func:`swim.assimilation.state.march_inputs`): a dict with the
        packed volume ``volume`` (level, y, x, channel), the ground's fields ``surface`` (channel, y', x') and, with a
        varied 3-D aerosol, its column optical depth ``aerosol_column`` (1, y, x)."""
        return self._inputs(self._checked("state", state)[0], self.setup.state_map)

    def __call__(self, state):
        """The observers' radiance images: a list of (3, ny, nx) arrays [-] (solar-relative L' at 615/546/450 nm,
        Eq. 2) of a state (:class:`ForwardOperator`'s Notes)."""
        inputs = self.march_inputs(state)
        s = self.setup
        rows = [chunk_radiance(inputs, s.consts, chunk, s.settings) for chunk in s.chunks]
        return self._images(self._radiance(rows))

    def tangent_linear(self, state, dstate):
        """The images' directional derivatives (a list of (3, ny, nx)) at ``state`` along ``dstate`` (a state of the
        same variables, in their units)."""
        state, dstate = self._checked("state", state)[0], self._checked("dstate", dstate, radii=False)[0]
        inputs, d_inputs = jax.jvp(lambda x: self._inputs(x, self.setup.state_map), (state,), (dstate,))
        s = self.setup
        rows = [_chunk_jvp(inputs, d_inputs, s.consts, chunk, s.settings)[1] for chunk in s.chunks]
        return self._images(self._radiance(rows))

    def adjoint(self, state, dimages):
        """The adjoint: the images' cotangents ``dimages`` (a list of (3, ny, nx), one per observer) pulled back to
        the state: the gradient, in the kind of ``state`` (a Dataset, a dict or the one array; per unit of each
        variable)."""
        given = state
        state, kind = self._checked("state", state)
        inputs, pull = jax.vjp(lambda x: self._inputs(x, self.setup.state_map), state)
        s = self.setup
        d_inputs = jax.tree_util.tree_map(jnp.zeros_like, inputs)
        for chunk, cotangent in zip(s.chunks, self._chunk_rows(self._ray_cotangent(dimages))):
            d_chunk = _chunk_vjp(inputs, s.consts, chunk, cotangent, s.settings)
            d_inputs = jax.tree_util.tree_map(jnp.add, d_inputs, d_chunk)
        return state_like(pull(d_inputs)[0], kind, given)

    def value_and_grad(self, loss, state):
        """``loss(images)`` (a JAX-differentiable scalar function of the list of images) and its gradient with
        respect to the state (of the state's kind: :meth:`adjoint`)."""
        images = self(state)
        value, pull = jax.vjp(loss, images)
        return value, self.adjoint(state, pull(jnp.ones_like(value))[0])


def state_parts(state, variables, name="state"):
    """A state as a dict of its variables' arrays, and its kind: ``"dataset"`` (an xarray.Dataset, its variables
    taken as (z, y, x)), ``"dict"`` (a mapping) or ``"array"`` (a bare (z, y, x) array, which stands for the one
    variable of a one-variable state).

    Raises
    ------
    SwimInputError
        If a bare array is given for a state of several variables, or a mapping lacks one of ``variables`` or holds
        others.
    """
    if isinstance(state, xr.Dataset):
        parts, kind = {v: state[v].transpose("z", "y", "x").data for v in variables if v in state}, "dataset"
        extra = set()
    elif isinstance(state, Mapping):
        parts, kind = dict(state), "dict"
        extra = set(parts) - set(variables)
    else:
        if len(variables) != 1:
            raise SwimInputError(f"forward_operator: {name} must be a dict or an xarray.Dataset of {variables} (an "
                                 f"array stands for a one-variable state only)")
        return {variables[0]: state}, "array"
    missing = [v for v in variables if v not in parts]
    if missing or extra:
        raise SwimInputError(f"forward_operator: {name} must hold exactly the variables {variables}; missing "
                             f"{missing}, not of the state {sorted(extra)}")
    return {v: parts[v] for v in variables}, kind


def state_like(parts, kind, given):
    """``parts`` (a dict of (z, y, x) arrays) in the kind of the state ``given`` (:func:`state_parts`): its one array,
    a dict, or an xarray.Dataset with ``given``'s coordinates."""
    if kind == "array":
        return next(iter(parts.values()))
    if kind == "dataset":
        return xr.Dataset({v: given[v].transpose("z", "y", "x").copy(data=np.asarray(a)) for v, a in parts.items()})
    return parts


def forward_operator(scene, observers, **options) -> ForwardOperator:
    """The differentiable forward operator of a scene seen by ``observers``: :class:`ForwardOperator` (its options
    described there)."""
    return ForwardOperator(scene, observers, **options)


__all__ = ["ForwardOperator", "Observer", "forward_operator"]
