"""Field alignment: the position and amplitude errors of a first guess's clouds corrected from the images.

A first guess whose clouds are in the wrong place cannot be corrected cell by cell: the images' misfit is not convex
in a displacement larger than a cloud, and a cell-wise retrieval grows new cloud and thins the old instead of moving
it. :func:`align_clouds` moves each cloud object of the state as a whole instead. The state is cut into objects
(:func:`cloud_objects`: the connected components of the cells with cloud) and a rest (the small fragments and
whatever is left), and the aligned state is

    x(p) = sum_k exp(a_k) f_k(p - d_k) + exp(a_0) r(p),

f_k the k-th object's content, d_k = (dz, dy, dx) its displacement [cells] and a_k its log amplitude, r the rest
held in place with its own log amplitude a_0. The objects are sampled at the displaced positions by trilinear
interpolation (:func:`warp_state`, ``jax.scipy.ndimage.map_coordinates`` of order 1), so that the state and the
images are differentiable in the parameters: the gradient of the images' misfit is the forward operator's adjoint
pulled back through the warp (``jax.vjp``). A coarse search over displacements on a grid (forward runs only, object
by object) finds the basin of the misfit, then L-BFGS-B refines all the parameters together.

References
----------
Ravela, Emanuel and McLaughlin (2007), Data assimilation by field alignment, Physica D 230, 127-145,
doi:10.1016/j.physd.2006.09.035 (the two-step correction of position, then amplitude errors); Nehrkorn et al. (2014),
Correcting for position errors in variational data assimilation, Mon. Wea. Rev. 142, 1756-1777,
doi:10.1175/MWR-D-13-00164.1 (the displacement as a control variable of the variational problem); Albers et al. (2020),
doi:10.5194/amt-13-3235-2020, Sects. 4.2.3 (r, Eq. 37) and 4.3 (the assimilation of camera images).
"""

from __future__ import annotations

import itertools
import logging
import time
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage, optimize

from ..errors import SwimInputError
from .retrieval import CONTENT_FLOOR

log = logging.getLogger(__name__)

#: Liquid water content [kg m-3] above which a cell belongs to a cloud object (the demonstration's cloud mask).
OBJECT_THRESHOLD = 1e-5
#: Least number of cells of a cloud object that moves on its own; smaller components stay in the rest.
MIN_OBJECT_CELLS = 50
#: Bounds of the log amplitudes [-]: the amplitude factors stay within 0.2-5.
LOG_AMPLITUDE_BOUND = float(np.log(5.0))


@dataclass
class AlignmentResult:
    """What :func:`align_clouds` returns.

    Attributes
    ----------
    state : numpy.ndarray
        (z, y, x) the aligned state [kg m-3].
    displacements : numpy.ndarray
        (n_objects, 3) each object's displacement (dz, dy, dx) [cells], largest object first.
    amplitudes : numpy.ndarray
        (n_objects,) each object's amplitude factor [-].
    rest_amplitude : float
        The amplitude factor [-] of the rest (the cells in no object).
    labels : numpy.ndarray
        (z, y, x) int: the first guess's objects (1 ... n_objects, in the order of the parameters), 0 the rest.
    history : dict
        ``cost_before``, ``cost_search`` (after the coarse search), ``cost_after``, ``search`` (per object the grid's
        displacements (n, 3) and costs (n,)), ``iterations``, ``evaluations``, ``seconds``, ``message``.
    """

    state: np.ndarray
    displacements: np.ndarray
    amplitudes: np.ndarray
    rest_amplitude: float
    labels: np.ndarray
    history: dict = field(default_factory=dict)


def cloud_objects(state, threshold=OBJECT_THRESHOLD, min_cells=MIN_OBJECT_CELLS):
    """The cloud objects of a state: its connected components (faces touching) of cells above ``threshold``, each
    with the fainter cells next to it, largest (by mass) first.

    Parameters
    ----------
    state : array_like
        (z, y, x) liquid water content [kg m-3], finite and >= 0.
    threshold : float
        Content [kg m-3] above which a cell is cloud, > 0.
    min_cells : int
        Least number of cells of an object; smaller components are left in the rest.

    Returns
    -------
    labels : numpy.ndarray
        (z, y, x) int: 1 ... n for the objects (by decreasing mass), 0 for the rest.
    n : int
        The number of objects.

    Raises
    ------
    SwimInputError
        If the state is not a finite, non-negative 3-D array or ``threshold`` is not positive.
    """
    state = np.asarray(state, float)
    if state.ndim != 3 or not (np.all(np.isfinite(state)) and state.min() >= 0):
        raise SwimInputError(f"cloud_objects: state must be a finite (z, y, x) array >= 0 [kg m-3], got shape "
                             f"{state.shape}")
    if not threshold > 0:
        raise SwimInputError(f"cloud_objects: threshold must be > 0 [kg m-3], got {threshold!r}")
    label, n = ndimage.label(state > threshold)
    if n == 0:
        return np.zeros(state.shape, int), 0
    index = np.arange(1, n + 1)
    cells = ndimage.sum(np.ones_like(state), label, index)
    mass = ndimage.sum(state, label, index)
    keep = [k for k in index[np.argsort(mass)[::-1]] if cells[k - 1] >= min_cells]
    labels = np.zeros(state.shape, int)
    for new, old in enumerate(keep, start=1):
        labels[label == old] = new
    # the faint cells (0 < content <= threshold) within one cell of an object go with it
    faint = (state > 0) & (state <= threshold)
    grown = ndimage.grey_dilation(labels, size=(3, 3, 3))
    labels = np.where(faint & (labels == 0), grown, labels)
    return labels, len(keep)


def warp_state(objects, rest, params):
    """The aligned state x(p) = sum_k exp(a_k) f_k(p - d_k) + exp(a_0) r(p) (module docstring), differentiable.

    Parameters
    ----------
    objects : jax.Array
        (n, z, y, x) each object's content [kg m-3] (0 outside it).
    rest : jax.Array
        (z, y, x) the content [kg m-3] in no object, held in place.
    params : jax.Array
        (4 n + 1,): per object (dz, dy, dx) [cells] and its log amplitude a_k [-], then the rest's a_0.

    Returns
    -------
    jax.Array
        (z, y, x) [kg m-3]. An object sampled beyond the grid's edges is 0 there.
    """
    n, shape = objects.shape[0], objects.shape[1:]
    p = params[:4 * n].reshape(n, 4)
    grid = jnp.stack(jnp.meshgrid(*(jnp.arange(s, dtype=objects.dtype) for s in shape), indexing="ij"))

    def one(f, q):
        coords = grid - q[:3, None, None, None].astype(objects.dtype)
        moved = jax.scipy.ndimage.map_coordinates(f, list(coords), order=1, mode="constant", cval=0.0)
        return jnp.exp(q[3]).astype(objects.dtype) * moved

    total = jnp.exp(params[4 * n]).astype(objects.dtype) * rest
    if n:
        total = total + jnp.sum(jax.vmap(one)(objects, p), axis=0)
    return total


def split_objects(state, labels, n):
    """The objects' fields (n, z, y, x) and the rest (z, y, x) of ``state`` [kg m-3] by its ``labels``
    (:func:`cloud_objects`)."""
    state = np.asarray(state, float)
    objects = np.stack([np.where(labels == k, state, 0.0) for k in range(1, n + 1)]) if n else \
        np.zeros((0,) + state.shape)
    return objects, np.where(labels == 0, state, 0.0)


def _search(fun_value, params, n, radius, step, vertical):
    """The coarse search: object by object (largest first), the displacement on a grid of ``step`` cells within
    ``radius`` (dz within one ``step`` if ``vertical``) with the least cost, the others held; returns the parameters
    and per object the grid (m, 3) and its costs (m,)."""
    offsets = np.arange(-radius, radius + 1e-9, step)
    vertical_offsets = np.array([-step, 0.0, step]) if vertical else np.array([0.0])
    grids = []
    for k in range(n):
        trial = np.array(list(itertools.product(vertical_offsets, offsets, offsets)), float)
        costs = np.empty(len(trial))
        for m, d in enumerate(trial):
            candidate = params.copy()
            candidate[4 * k:4 * k + 3] = d
            costs[m] = fun_value(candidate)
        params[4 * k:4 * k + 3] = trial[int(np.argmin(costs))]
        log.info("alignment search, object %d: displacement (dz, dy, dx) %s cells, cost %.4g (at 0: %.4g)", k + 1,
                 params[4 * k:4 * k + 3], costs.min(), costs[np.argmin(np.abs(trial).sum(axis=1))])
        grids.append({"displacements": trial, "costs": costs})
    return params, grids


def align_clouds(operator, cost, state, *, radius=8.0, step=2.0, vertical=False, iterations=30, amplitude=True,
                 threshold=OBJECT_THRESHOLD, min_cells=MIN_OBJECT_CELLS) -> AlignmentResult:
    """The state's cloud objects moved and scaled to fit the images (module docstring): a coarse search of the
    displacements, then L-BFGS-B on all displacements and log amplitudes.

    Parameters
    ----------
    operator : ForwardOperator
        The observers' forward operator (:class:`swim.assimilation.ForwardOperator`); its step placement must cover
        where the clouds may move (e.g. :func:`swim.assimilation.retrieval.placement_scene`'s cloud layer).
    cost : callable
        ``cost(images)``: a JAX-differentiable scalar misfit of the list of images (3, ny, nx) (e.g.
        :func:`swim.assimilation.retrieval.image_cost`).
    state : array_like
        (z, y, x) the first guess's liquid water content [kg m-3], finite, >= 0, with at least one object.
    radius, step : float
        The coarse search's largest horizontal displacement and its grid's spacing [cells]; ``radius`` 0 skips it.
    vertical : bool
        Whether the objects move vertically too (dz); otherwise dz stays 0.
    iterations : int
        L-BFGS-B iterations (0: the coarse search only).
    amplitude : bool
        Whether the amplitudes are fitted too; otherwise they stay 1.
    threshold, min_cells
        The objects' definition (:func:`cloud_objects`).

    Returns
    -------
    AlignmentResult

    Raises
    ------
    SwimInputError
        If the state does not match the operator, has no object, or a setting is out of range.
    """
    state = np.asarray(state, float)
    if tuple(state.shape) != tuple(operator.setup.state_shape):
        raise SwimInputError(f"align_clouds: state must have the operator's shape (z, y, x) = "
                             f"{tuple(operator.setup.state_shape)} [kg m-3], got {state.shape}")
    if not (radius >= 0 and step > 0 and iterations >= 0):
        raise SwimInputError(f"align_clouds: radius [cells] must be >= 0, step [cells] > 0 and iterations >= 0, got "
                             f"{radius!r}, {step!r} and {iterations!r}")
    labels, n = cloud_objects(state, threshold, min_cells)
    if n == 0:
        raise SwimInputError(f"align_clouds: the state has no cloud object (>= {min_cells} connected cells above "
                             f"{threshold} kg m-3) to move")
    objects, rest = (jnp.asarray(a, operator.dtype) for a in split_objects(state, labels, n))
    # the operator's derivative is that of the images only above the content floor (retrieval.CONTENT_FLOOR)
    warp = jax.jit(lambda p: jnp.maximum(warp_state(objects, rest, p), CONTENT_FLOOR))
    free = np.ones(4 * n + 1, bool)
    if not vertical:
        free[0:4 * n:4] = False
    if not amplitude:
        free[3:4 * n:4] = False
        free[-1] = False
    evaluations = [0]

    def value(p):
        return float(cost(operator(warp(jnp.asarray(p, operator.dtype)))))

    def value_and_grad(u):
        p = params.copy()
        p[free] = u
        x, pull = jax.vjp(warp, jnp.asarray(p, operator.dtype))
        v, g = operator.value_and_grad(cost, x)
        evaluations[0] += 1
        return float(v), np.asarray(pull(g)[0], float)[free]

    start = time.perf_counter()
    params = np.zeros(4 * n + 1)
    history = {"cost_before": value(params)}
    grids = []
    if radius > 0:
        params, grids = _search(value, params, n, float(radius), float(step), vertical)
    history.update(cost_search=value(params), search=grids)
    if iterations > 0:
        bounds = np.tile([radius + step] * 3 + [LOG_AMPLITUDE_BOUND], n).tolist() + [LOG_AMPLITUDE_BOUND]
        bounds = [(-b, b) for b, f in zip(bounds, free) if f]
        res = optimize.minimize(value_and_grad, params[free], jac=True, method="L-BFGS-B", bounds=bounds,
                                options={"maxiter": int(iterations), "ftol": 1e-7})
        params[free] = res.x
        history.update(iterations=int(res.nit), message=str(res.message))
    history.update(cost_after=value(params), evaluations=evaluations[0], seconds=time.perf_counter() - start)
    p = params[:4 * n].reshape(n, 4)
    aligned = np.maximum(np.asarray(warp_state(objects, rest, jnp.asarray(params, operator.dtype)), float), 0.0)
    result = AlignmentResult(aligned,
                             p[:, :3].copy(), np.exp(p[:, 3]), float(np.exp(params[-1])), labels, history)
    log.info("alignment: cost %.4g -> %.4g (search) -> %.4g; displacements %s cells, amplitudes %s, rest %.3g "
             "(%.0f s)", history["cost_before"], history["cost_search"], history["cost_after"],
             np.round(result.displacements, 2).tolist(), np.round(result.amplitudes, 3).tolist(),
             result.rest_amplitude, history["seconds"])
    return result
