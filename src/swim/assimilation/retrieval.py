"""A variational retrieval of the cloud liquid water content from images: the forward operator's misfit minimised.

:func:`retrieve_liquid_water` minimises the images' misfit, weighted by the observations' noise, and optionally 3D-Var's
background term J_b,

    J(x) = [1/2 sum_p w_p sum_c ((F_c,p(x) - y_c,p) / sigma_c,p)^2
            + 1/2 sum_k ((x_k - x_b,k) / sigma_b,k)^2] / sum_p w_p,

over the liquid water content x >= :data:`CONTENT_FLOOR` (z, y, x) [kg m-3] by L-BFGS-B (scipy), with the gradient of
:meth:`ForwardOperator.value_and_grad`; sigma_c,p = sqrt((relative_noise y)^2 + absolute_noise^2) and w the pixels'
masks; the second sum (a diagonal background-error covariance with standard deviations sigma_b) is there only where a
background x_b is given. The step placement that the operator holds fixed is renewed in outer loops (as incremental
4D-Var renews its linearisation): each outer loop builds a new operator whose steps are placed for the current state
and for a thin cloud layer around it (:func:`placement_scene`), so that cloud can grow where the first guess had none.

References
----------
Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Sects. 4.2.3 (r, Eq. 37) and 4.3 (variational assimilation of
camera images); Levis et al. (2015), Airborne three-dimensional cloud tomography, ICCV, doi:10.1109/ICCV.2015.373
(tomographic retrieval of liquid water from multi-view images); Lorenc (1986), Analysis methods for numerical
weather prediction, Q. J. R. Meteorol. Soc. 112, 1177-1194, doi:10.1002/qj.49711247414 (the background term);
Byrd et al. (1995), A limited memory algorithm for bound constrained optimization, SIAM J. Sci. Comput. 16,
1190-1208, doi:10.1137/0916069 (L-BFGS-B).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import jax.numpy as jnp
import numpy as np
from scipy import optimize

from ..errors import SwimInputError
from .colour_ratio import check_observed
from .misfit import one_minus_r
from .operator import ForwardOperator

log = logging.getLogger(__name__)

#: Liquid water content [kg m-3] in the cloud layer's empty cells of the placement scene: an extinction of 7.5e-4 m-1
#: (r_e 4 um), above the occupancy's threshold (1e-6 m-1), so that the steps are placed there too. It only places the
#: steps: the operator's liquid water is the state's.
PLACEMENT_CONTENT = 2e-6
#: Least liquid water content [kg m-3] of the retrieval's state: a line of sight meets an optical depth of ~4e-4 per km
#: of grid it crosses (r_e 4 um), which changes an image by about as much (0.04 % per km), but keeps Eq. 12's means over
#: the cloud defined on every line of sight, so that the derivative of cloud grown where there was none is the
#: derivative of the images (at exactly 0 the composition switches the cloud radiance off, and its derivative is 0;
#: checked against finite differences in float64).
CONTENT_FLOOR = 1e-9
#: Scale [kg m-3] of the minimiser's variable (x / X_SCALE ~ 1 in cloud).
X_SCALE = 1e-3


@dataclass
class RetrievalResult:
    """What :func:`retrieve_liquid_water` returns: the analysis ``state`` (z, y, x) [kg m-3], the last outer loop's
    operator, and ``history``: one dict per outer loop (``outer``, ``cost_before``, ``cost_after``, ``r_before``,
    ``r_after`` (per observer), ``iterations``, ``evaluations``, ``seconds``, ``message``)."""

    state: np.ndarray
    operator: ForwardOperator
    history: list = field(default_factory=list)


def placement_scene(scene, state, layer_margin=2):
    """The scene whose liquid water places the operator's steps: ``state`` where it is larger, and
    :data:`PLACEMENT_CONTENT` in every cell of the cloud layer (the levels with cloud, > 1e-5 kg m-3, and
    ``layer_margin`` levels below and above), so that the retrieval can grow cloud anywhere in that layer. The scene's
    cloud-liquid effective radius is left out: the droplets' r_e follows the retrieved content (Martin et al. 1994,
    :func:`swim.assimilation.state.effective_radius_liquid`), not the places of the scene's own clouds.

    Parameters
    ----------
    scene : xarray.Dataset
        Canonical scene.
    state : array_like
        (z, y, x) liquid water content [kg m-3].
    layer_margin : int
        Levels added below and above the levels with cloud.

    Returns
    -------
    xarray.Dataset
        A copy of ``scene`` with that ``cloud_liquid_content`` and without ``cloud_liquid_effective_radius``.

    Raises
    ------
    SwimInputError
        If ``state`` has no cloud.
    """
    state = np.asarray(state, float)
    levels = np.flatnonzero((state > 1e-5).any(axis=(1, 2)))
    if levels.size == 0:
        raise SwimInputError("retrieve_liquid_water: the first guess has no cloud (> 1e-5 kg m-3) to place the "
                             "march's steps; give one (e.g. from colour_ratio_update)")
    layer = np.zeros(state.shape, bool)
    layer[max(levels[0] - layer_margin, 0):levels[-1] + layer_margin + 1] = True
    out = scene.drop_vars("cloud_liquid_effective_radius", errors="ignore")
    out["cloud_liquid_content"] = (("z", "y", "x"), np.maximum(state, np.where(layer, PLACEMENT_CONTENT, 0.0)))
    return out


def image_cost(observed, masks, relative_noise=0.01, absolute_noise=1e-3):
    """The images' misfit J_o (module docstring) as a JAX function of the list of images (3, ny, nx).

    Parameters
    ----------
    observed : list of array_like
        One observed image (3, ny, nx) [-] per observer.
    masks : list of array_like
        One (ny, nx) weight per observer (e.g. :meth:`ForwardOperator.masks_without_sun`).
    relative_noise, absolute_noise : float
        The observations' noise [-] (:func:`swim.assimilation.observe.synthetic_observations`), >= 0, not both 0.

    Returns
    -------
    callable
        ``cost(images)`` -> scalar [-]: 0.5 per pixel and channel where the images differ from the observations by
        their noise.

    Raises
    ------
    SwimInputError
        If the noise levels are negative, not finite or both 0, or the masks leave no pixel.
    """
    if not (np.isfinite(relative_noise) and np.isfinite(absolute_noise) and relative_noise >= 0
            and absolute_noise >= 0 and relative_noise + absolute_noise > 0):
        raise SwimInputError(f"image_cost: relative_noise and absolute_noise must be finite standard "
                             f"deviations >= 0 [-], not both 0; got {relative_noise!r} and {absolute_noise!r}")
    total = float(sum(np.sum(np.asarray(w)) for w in masks))
    if not total > 0:
        raise SwimInputError("image_cost: the masks leave no pixel")
    ys = [jnp.asarray(y, jnp.float32) for y in observed]
    ws = [jnp.asarray(w, jnp.float32) for w in masks]
    # the masked pixels (no ray: L' = 0) get no weight, not 0 x 1 / 0
    inv_var = [jnp.where(w > 0, 1.0 / jnp.maximum((relative_noise * y) ** 2 + absolute_noise ** 2, 1e-30), 0.0)
               for y, w in zip(ys, ws)]

    def cost(images):
        return 0.5 * sum(jnp.sum(w * iv * (x - y) ** 2) for x, y, w, iv in zip(images, ys, ws, inv_var)) / total

    return cost


def background_cost(background, background_error, total):
    """3D-Var's background term J_b (module docstring) with a diagonal covariance, on the scale of
    :func:`image_cost` (divided by the masks' total weight ``total``): a function of the state (z, y, x) [kg m-3]
    that returns J_b [-] and its gradient (numpy).

    Parameters
    ----------
    background : array_like
        (z, y, x) the background state x_b [kg m-3].
    background_error : float or array_like
        The background's error standard deviations sigma_b [kg m-3], > 0: a number or (z, y, x).
    total : float
        The masks' total weight (the images' misfit's divisor), > 0.

    Raises
    ------
    SwimInputError
        If the background is not finite, or the errors are not finite and > 0 or do not broadcast to its shape.
    """
    xb = np.asarray(background, float)
    if not np.all(np.isfinite(xb)):
        raise SwimInputError("retrieve_liquid_water: background must be finite [kg m-3]")
    try:
        sigma = np.broadcast_to(np.asarray(background_error, float), xb.shape)
    except ValueError:
        raise SwimInputError(f"retrieve_liquid_water: background_error must be a number or have the background's shape "
                             f"{xb.shape} [kg m-3], got shape {np.shape(background_error)}") from None
    if not (np.all(np.isfinite(sigma)) and np.all(sigma > 0)):
        raise SwimInputError("retrieve_liquid_water: background_error must be finite standard deviations > 0 [kg m-3]")
    weight = 1.0 / (sigma ** 2 * float(total))

    def cost(x):
        d = np.asarray(x, float) - xb
        return 0.5 * float(np.sum(weight * d * d)), weight * d

    return cost


def mean_r(images, observed, masks):
    """r-bar (Eq. 37, averaged over the channels) of each observer's image (3, ny, nx) against its observation, with
    its mask (ny, nx): a list of floats [-], one per observer."""
    return [1.0 - float(one_minus_r(jnp.asarray(x), jnp.asarray(y, jnp.float32), w))
            for x, y, w in zip(images, observed, masks)]


def retrieve_liquid_water(scene, observers, observed, *, sun_zenith, sun_azimuth, first_guess, sun_radius_deg=5.0,
                          relative_noise=0.01, absolute_noise=1e-3, outer_loops=2, iterations=30,
                          layer_margin=2, background=None, background_error=None, settings=None,
                          chunk=4096) -> RetrievalResult:
    """The liquid water content (z, y, x) [kg m-3] that minimises the images' misfit (module docstring).

    Parameters
    ----------
    scene : xarray.Dataset
        Canonical scene: the grid, the other species, the ground and the aerosol (its liquid water is replaced).
    observers : sequence of Observer
        The cameras (:class:`swim.assimilation.Observer`).
    observed : list of array_like
        One observed radiance image (3, ny, nx) [-] per observer (L' at 615/546/450 nm).
    sun_zenith, sun_azimuth : float
        The sun's zenith angle and azimuth [deg].
    first_guess : array_like
        (z, y, x) [kg m-3], >= 0, with some cloud.
    sun_radius_deg : float
        Pixels within this angle [deg] of the sun do not count (the paper's 5 deg).
    relative_noise, absolute_noise : float
        The observations' noise [-] that weights the misfit.
    outer_loops, iterations : int
        Outer loops (new step placements) and L-BFGS-B iterations in each.
    layer_margin : int
        Levels below and above the current cloud in which cloud may grow in an outer loop.
    background, background_error : array_like, optional
        The background state x_b (z, y, x) [kg m-3] and its error standard deviations sigma_b [kg m-3] (a number or
        (z, y, x), > 0) of the background term J_b; None: no background term.
    settings, chunk
        The operator's (:class:`ForwardOperator`).

    Returns
    -------
    RetrievalResult

    Raises
    ------
    SwimInputError
        If the first guess has the wrong shape, negative or non-finite values or no cloud, the observed images do not
        match the observers, a count is below 1, the noise levels are out of range, or a background is given
        without its errors or with the wrong shape (:func:`background_cost`).
    """
    x = np.asarray(first_guess, float)
    shape = tuple(scene.sizes[d] for d in ("z", "y", "x"))
    if x.shape != shape:
        raise SwimInputError(f"retrieve_liquid_water: first_guess must have the scene's shape (z, y, x) = {shape}, "
                             f"got {x.shape}")
    if not (np.all(np.isfinite(x)) and x.min() >= 0):
        raise SwimInputError("retrieve_liquid_water: first_guess must be finite and >= 0 [kg m-3]")
    if not (outer_loops >= 1 and iterations >= 1):
        raise SwimInputError(f"retrieve_liquid_water: outer_loops and iterations must be >= 1, got {outer_loops} "
                             f"and {iterations}")
    if (background is None) != (background_error is None) or (background is not None
                                                                and np.shape(background) != shape):
        raise SwimInputError(f"retrieve_liquid_water: background (the scene's shape {shape}) and background_error "
                             f"[kg m-3] go together")
    x = np.maximum(x, CONTENT_FLOOR)
    result = RetrievalResult(x, None)
    for outer in range(int(outer_loops)):
        op = ForwardOperator(placement_scene(scene, x, layer_margin), observers, sun_zenith=sun_zenith,
                             sun_azimuth=sun_azimuth, settings=settings, chunk=chunk)
        check_observed(observed, op.setup.shapes, "retrieve_liquid_water")
        masks = op.masks_without_sun(sun_radius_deg)
        cost = image_cost(observed, masks, relative_noise, absolute_noise)
        prior = None if background is None else background_cost(background, background_error,
                                                                 sum(float(np.sum(w)) for w in masks))
        record = {"outer": outer, "r_before": mean_r(op(x), observed, masks)}
        x, record = _minimise(op, cost, x, int(iterations), record, prior)
        record["r_after"] = mean_r(op(x), observed, masks)
        log.info("retrieval, outer loop %d: cost %.4g -> %.4g, r-bar %s -> %s (%d iterations, %.0f s)", outer,
                 record["cost_before"], record["cost_after"], np.round(record["r_before"], 3),
                 np.round(record["r_after"], 3), record["iterations"], record["seconds"])
        result.state, result.operator = x, op
        result.history.append(record)
    return result


def _minimise(op, cost, x, iterations, record, prior=None):
    """L-BFGS-B on x / :data:`X_SCALE` >= :data:`CONTENT_FLOOR` / :data:`X_SCALE` from ``x``, of the images' misfit
    ``cost`` plus the background term ``prior`` (:func:`background_cost`, or None): the new state and ``record`` with
    the cost and counts."""
    shape, n_cells = x.shape, x.size
    evaluations = [0]

    def fun(u):
        state = u.reshape(shape) * X_SCALE
        value, grad = op.value_and_grad(cost, jnp.asarray(state, op.dtype))
        value, grad = float(value), np.asarray(grad, float)
        if prior is not None:
            value_b, grad_b = prior(state)
            value, grad = value + value_b, grad + grad_b
        evaluations[0] += 1
        return value, grad.ravel() * X_SCALE

    start = time.perf_counter()
    record["cost_before"] = fun(x.ravel() / X_SCALE)[0]
    # ftol: the cost is summed in float32 (relative rounding ~1e-7); scipy's default 2e-9 ends in failed line searches
    res = optimize.minimize(fun, x.ravel() / X_SCALE, jac=True, method="L-BFGS-B",
                            bounds=optimize.Bounds(np.full(n_cells, CONTENT_FLOOR / X_SCALE), np.inf),
                            options={"maxiter": iterations, "ftol": 1e-7})
    record.update(cost_after=float(res.fun), iterations=int(res.nit), evaluations=evaluations[0] - 1,
                  seconds=time.perf_counter() - start, message=str(res.message))
    return res.x.reshape(shape) * X_SCALE, record
