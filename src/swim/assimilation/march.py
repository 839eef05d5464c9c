"""The JAX march with the step placement held fixed, differentiable in reverse mode with bounded memory.

The same samples, sources and composition as the JAX kernel's lockstep march (:mod:`swim.rt.march_jax`:
``_sample_step``, ``_terminal_step``, ``_compose``), driven by a loop that reverse-mode differentiation can take:

* the steps' edges of every ray are placed once, at set-up, from the reference state's step classes
  (:func:`step_segments`: :func:`swim.rt.march_jax.clear_step_edges`, :func:`swim.rt.march_jax.grid_step_edges`,
  :func:`swim.rt.march_jax.after_step_counts`), and passed to the march as constants, so the radiance is a smooth
  function of the volume for a fixed placement;
* there is no refinement of thick steps and cloud faces (``tau_refine`` 0): the kernel's refined grid loop is a
  ``lax.while_loop`` with a data-dependent trip count, which JAX cannot differentiate in reverse mode;
* rays do not stop in opaque cloud (``stop_tau`` 0): the stop is a switch on the optical depth;
* all steps are one ``lax.scan`` whose body is wrapped in ``jax.checkpoint``: the reverse pass keeps only
  the march's state (about 25 numbers per ray) at each step and recomputes a step's samples (the gathers of the
  volume and the tables) when it needs them, instead of storing them all.

The composition is the paper's (Eqs. 12-26, ``cloud_scattering="albers2020"``); the 3-D cloud scattering's diffuse
solution is solved on the host (:mod:`swim.rt.diffuse_solver`) and is not part of this march.

References
----------
Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Eqs. 3, 12-26 (the march and its composition); Griewank and
Walther (2008), Evaluating Derivatives, 2nd ed., SIAM, doi:10.1137/1.9780898717761, Ch. 12 (checkpointing).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..rt.clouds import three_d
from ..rt.march_jax import (_SegmentInputs, _compose, _prepare_rays, _sample_step, _terminal_step,
                            after_step_counts, clear_step_edges, grid_step_edges, refine_terrain_hit)
from ..rt.march_settings import MarchSettings


class FixedSegment(NamedTuple):
    """One segment of a chunk's rays with its steps placed: ``edges`` (n_steps + 1, n) [m] from each ray's rebased
    start, each ray's own step count ``steps`` (n,) int32 or None (all ``n_steps``), and whether it lies in the grid
    (``in_grid``: the volume is sampled)."""

    edges: object
    steps: object
    in_grid: bool


def step_segments(start, direction, bounds, consts, settings: MarchSettings, probes=None):
    """The step placement of a chunk of rays, as :func:`swim.rt.march_jax._march_rays` places it: the clear air
    before the grid, the grid (dense where the step classes ``consts["occupancy"]`` say something is, few steps in
    empty space), the clear air after it and the zero-length end step.

    Parameters
    ----------
    start, direction, bounds : jax.Array
        Shape (n, 3) each: rebased starts [m], unit directions and segment bounds [m] of
        :func:`swim.rt.march.ray_segments`.
    consts : dict
        Kernel constants (:func:`swim.rt.march_inputs.kernel_constants`) as JAX arrays.
    settings : MarchSettings
        Step counts (``n_before``, ``n_grid``, ``n_after``, ``n_probe``, ``empty_steps``, ``sunlit_steps``).
    probes : tuple, optional
        Each ray's probe count and cells crossed (:func:`swim.rt.march_jax.probe_counts_and_cells`).

    Returns
    -------
    tuple of FixedSegment
    """
    zero = jnp.zeros(start.shape[0], start.dtype)
    segments = []
    if settings.n_before:
        edges = clear_step_edges(start, direction, zero, bounds[:, 0], settings.n_before, consts)
        segments.append(FixedSegment(edges, None, False))
    if settings.n_grid:
        count, cells = (None, None) if probes is None else probes
        empty_steps = settings.resolved_empty_steps()
        edges, steps = grid_step_edges(start, direction, bounds[:, 0], bounds[:, 1] - bounds[:, 0], settings.n_grid,
                                       consts, n_probe=settings.n_probe, probes=count, cells=cells,
                                       empty_steps=empty_steps, sunlit_steps=settings.sunlit_steps)
        segments.append(FixedSegment(edges, steps if empty_steps else None, True))
    if settings.n_after:
        steps = after_step_counts(start, direction, bounds, settings.n_after, consts)
        edges = clear_step_edges(start, direction, bounds[:, 1], bounds[:, 2] - bounds[:, 1], settings.n_after,
                                 consts, steps=steps)
        segments.append(FixedSegment(edges, steps, False))
    segments.append(FixedSegment(jnp.stack([bounds[:, 2], bounds[:, 2]]), None, False))
    return tuple(segments)


def placed_steps(segments):
    """The steps of a chunk's segments (:func:`step_segments`) in marching order, as three (steps, n) arrays: each
    step's start ``lo`` [m], length ``ds`` [m] and whether the ray takes it (``taken``: a ray's steps beyond its own
    count in a segment are not taken)."""
    lo, ds, taken = [], [], []
    for seg in segments:
        n_steps = seg.edges.shape[0] - 1
        lo.append(seg.edges[:-1])
        ds.append(seg.edges[1:] - seg.edges[:-1])
        m = jnp.arange(n_steps)[:, None]
        taken.append(jnp.broadcast_to(m < (n_steps if seg.steps is None else seg.steps[None, :]), seg.edges[1:].shape))
    return jnp.concatenate(lo), jnp.concatenate(ds), jnp.concatenate(taken)


def _scan_steps(state, seg: _SegmentInputs, steps):
    """The state after the placed ``steps`` (lo, ds, taken; :func:`placed_steps`), one ``lax.scan`` whose body
    (:func:`swim.rt.march_jax._sample_step`) is checkpointed; a step that a ray does not take leaves it as it is.

    Every step samples the volume (``seg.in_grid``): beyond the grid its lookup gives the channels' ``outside``
    values (no hydrometeors, T and the terrain's shadow 1), which is what a step in the clear air takes, and the
    hydrometeors' integrands add exactly 0 there (their weight is e^-min(tau, 2) - e^-min(tau, 2)). One loop body for
    all segments: one program to compile, and to differentiate."""

    @jax.checkpoint
    def body(st, step):
        s_lo, ds, taken = step
        new = _sample_step(seg, st, s_lo, ds)[0]
        return {key: jnp.where(taken.reshape((-1,) + (1,) * (value.ndim - 1)), value, st[key])
                for key, value in new.items()}, None

    return jax.lax.scan(body, state, steps)[0]


def initial_state(n, n_species, dtype, clouds_3d=False):
    """The march's state before the first step (as :func:`swim.rt.march_jax._march_rays` starts it), in ``dtype``
    (float32, or float64 for derivative checks)."""
    zeros3 = jnp.zeros((n, 3), dtype)
    zero = jnp.zeros(n, dtype)
    state = {"tau_clear": zeros3, "tau_h": zero, "tau_species": jnp.zeros((n, n_species), dtype), "l_clear": zeros3,
             "i_nogas": zeros3, "i_gas": zeros3, "i_cloud_t": zero, "alive": None, "hit": jnp.zeros(n, bool),
             "hit_s": zero, "hit_lo": zero, "hit_hi": zero, "hit_from": zero, "gap": jnp.full(n, 1e9, dtype),
             "s_last": zero}
    if clouds_3d:
        state.update(tau_view=zero, l_cloud=zeros3)
    return state


def march_fixed(rays_in, steps, rays, consts, settings: MarchSettings):
    """The march's state after a chunk's rays' placed steps (:func:`placed_steps`),
    the terrain crossing refined and the terminal step taken, as :func:`swim.rt.march_jax._march_rays` gives it
    (without refinement and without the stop in opaque cloud).

    ``rays_in``: (start, direction, bounds, valid) of the chunk; ``rays``: the per-ray phase arrays."""
    start, direction, bounds, valid = rays_in
    dtype = consts["volume"].dtype
    aerosol_class, ms = _prepare_rays(start, direction, bounds, consts, settings)
    state = initial_state(start.shape[0], consts["species_matrix"].shape[0], dtype, three_d(consts))
    state["alive"] = valid
    n_c = consts["volume"].shape[-1]
    outside = jnp.concatenate([jnp.zeros(n_c - 2), jnp.ones(2)]).astype(dtype)
    seg = _SegmentInputs(start, direction, rays, consts, ms, aerosol_class, True, False, 0.0, outside)
    state = _scan_steps(state, seg, steps)
    state["s_hit"] = jnp.where(state["hit"], refine_terrain_hit(start, direction, state, consts), bounds[:, 2])
    state = _terminal_step(state, start, direction, rays, consts, ms, aerosol_class)
    state["tau_species"] = state["tau_species"] @ consts["species_matrix"]
    return state, aerosol_class


@functools.partial(jax.jit, static_argnames=("settings",))
def chunk_radiance(inputs, fixed_consts, chunk, settings: MarchSettings):
    """Radiance (n, 3) [-] (solar-relative L' at 615/546/450 nm, Eq. 2; 0 for rays that are not ``valid``) of one
    chunk of rays through the differentiable kernel constants ``inputs`` (a dict: the packed ``volume`` (level, y, x,
    channel), the ground's extended ``surface`` fields (channel, y, x) and, with a varied 3-D aerosol,
    ``aerosol_column`` (1, y, x); :func:`swim.assimilation.state.march_inputs`); the other kernel constants
    ``fixed_consts`` (:func:`swim.rt.march_inputs.volume_constants`) and the chunk's rays and placed steps ``chunk`` (a
    dict of arrays: :func:`swim.assimilation.setup.build_setup`) are held fixed."""
    consts = {**fixed_consts, **inputs}
    rays_in = (chunk["start"], chunk["direction"], chunk["bounds"], chunk["valid"])
    steps = (chunk["lo"], chunk["ds"], chunk["taken"])
    state, aerosol_class = march_fixed(rays_in, steps, chunk["rays"], consts, settings)
    out = _compose(chunk["start"], chunk["direction"], chunk["bounds"], chunk["ends_on_ground"], chunk["valid"],
                   chunk["rays"], consts, settings, state, aerosol_class)
    return out["radiance"]
