"""The paper's non-variational baseline: one iteration of cloud clearing and insertion from colour-ratio cloud masks.

Albers et al. (2020), Sect. 4.3: cloud masks are derived from the red/blue ratio of the simulated and the observed
images (Sect. 4.2.3); where the simulated image shows cloud and the observed one clear sky, the clouds along the line
of sight are cleared, and where the observed image shows cloud and the simulated one none, cloud is added; one such
iteration raised r from 0.407 to 0.705 in their Fig. 14. The paper does not give the algorithm's details; this one
(docs/assimilation.md, "The colour-ratio baseline"):

* cloudy pixels: L'(615 nm) / L'(450 nm) >= ``threshold`` in the images of radiance (the ratio of
  :func:`swim.diagnostics.red_blue_ratio` taken before display encoding);
* clearing: every cell that a line of sight crosses in the model grid is set to 0 where the simulated pixel is cloudy
  and the observed pixel clear;
* insertion: the cells that a line of sight crosses within the cloud layer (the heights of the state's clouds) where
  the observed pixel is cloudy and the simulated pixel clear get ``content`` (by default the state's median in-cloud
  liquid water at the cell's level), except the cells that any clear observed line of sight crosses: clear sky seen
  through a cell is stronger evidence than cloud seen along a line (the clouds of several cameras intersect, a space
  carving).

References
----------
Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Sects. 4.2.3 (colour-ratio cloud masks; r, Eq. 37) and 4.3
(the insertion and clearing of clouds, Fig. 14).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..constants import EARTH_RADIUS_M
from ..errors import SwimInputError

log = logging.getLogger(__name__)

#: L'(615 nm) / L'(450 nm) [-] at and above which a pixel is cloudy: clear sky's ratio of solar-relative radiance is
#: 0.3-0.5 (Rayleigh scattering), a cloud's ~0.9-1.0 (white); 0.8 of display-encoded values (gamma 2.2) is 0.6.
RADIANCE_RATIO_THRESHOLD = 0.6
#: Samples per cell [-] along a line of sight when finding the cells it crosses.
SAMPLES_PER_CELL = 4


@dataclass(frozen=True)
class ColourRatioUpdate:
    """The result of :func:`colour_ratio_update`: the new state (z, y, x) [kg m-3], the cells cleared and inserted
    ((z, y, x) bool), and per observer the cloud masks of the simulated and the observed image ((ny, nx) bool)."""

    state: np.ndarray
    cleared: np.ndarray
    inserted: np.ndarray
    simulated_cloudy: list
    observed_cloudy: list


def check_observed(observed, shapes, where):
    """Raise :class:`SwimInputError` unless ``observed`` holds one finite (3, ny, nx) image per observer's
    ``shapes`` (ny, nx)."""
    if len(observed) != len(shapes):
        raise SwimInputError(f"{where}: one observed image per observer is needed, {len(shapes)}; got "
                             f"{len(observed)}")
    for n, (image, shape) in enumerate(zip(observed, shapes)):
        if np.shape(image) != (3,) + tuple(shape) or not np.all(np.isfinite(image)):
            raise SwimInputError(f"{where}: observed image {n} must be finite radiance L' (3, ny, nx) = "
                                 f"{(3,) + tuple(shape)} [-], got shape {np.shape(image)}")


def cloudy_pixels(image, valid, threshold=RADIANCE_RATIO_THRESHOLD):
    """Cloudy pixels (ny, nx) bool of a radiance image (3, ny, nx) [-]: L'(615) / L'(450) >= ``threshold`` where
    ``valid`` (ny, nx)."""
    image = np.asarray(image, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(image[2] > 0, image[0] / np.where(image[2] > 0, image[2], 1.0), 0.0)
    return (ratio >= threshold) & np.asarray(valid, bool)


def _level_content(state, cloud):
    """The content (z, y, x) [kg m-3] of inserted cloud: at each level the median of the state's cloudy cells there
    (the vertical profile of the analysis's clouds, which in cumulus grows with height above the base), the median of
    all its cloudy cells at levels without cloud."""
    overall = np.median(state[cloud])
    level = np.array([np.median(s[c]) if c.any() else overall for s, c in zip(state, cloud)])
    return np.broadcast_to(level[:, None, None], state.shape)


def _rays_in_scene_frame(setup):
    """All rays' earth-centred origins (n, 3) [m], unit directions (n, 3) and grid bounds (n, 3) [m]
    (:func:`swim.rt.march.ray_segments`: the chunks' rebased starts are relative to the sea-level point (0, 0, R))."""
    n = setup.n_rays
    start, direction, bounds = (np.concatenate([np.asarray(chunk[key], float) for chunk in setup.chunks])[:n]
                                for key in ("start", "direction", "bounds"))
    return start + [0.0, 0.0, EARTH_RADIUS_M], direction, bounds


def _block_cells(start, direction, bounds, geometry, heights, terrain, step):
    """:func:`_ray_cells` for a block of rays: flat cell indices and the rays' indices within the block."""
    nz, ny, nx = heights.shape
    count = np.ceil(np.maximum(bounds[:, 1] - bounds[:, 0], 0.0) / step).astype(int)
    ray = np.repeat(np.arange(count.size), count)
    first = np.repeat(np.cumsum(count) - count, count)
    s = bounds[ray, 0] + (np.arange(ray.size) - first + 0.5) * step
    p = start[ray] + s[:, None] * direction[ray]
    rel = p[:, :2] - geometry.origin
    i = np.rint(rel @ geometry.inverse[0]).astype(int)
    j = np.rint(rel @ geometry.inverse[1]).astype(int)
    inside = (i >= 0) & (i < nx) & (j >= 0) & (j < ny)
    h = np.linalg.norm(p, axis=1) - EARTH_RADIUS_M
    # a line of sight ends where it meets the terrain: no sample after the first one below the ground
    below = inside & (h < terrain[np.clip(j, 0, ny - 1), np.clip(i, 0, nx - 1)])
    total = np.cumsum(below)
    ended = total - (total - below)[first] > 0
    keep = inside & ~ended
    ray, h, i, j = ray[keep], h[keep], i[keep], j[keep]
    # the level whose layer (between the midpoints to its neighbours, in its own column) holds the sample
    column = heights[:, j, i]  # (nz, n) [m above sea level]
    edges = 0.5 * (column[1:] + column[:-1])
    k = np.sum(h[None, :] >= edges, axis=0)
    if nz > 1:  # within half a level's spacing of the lowest and highest level
        near = (h >= 1.5 * column[0] - 0.5 * column[1]) & (h <= 1.5 * column[-1] - 0.5 * column[-2])
    else:
        near = np.ones(k.size, bool)
    return np.ravel_multi_index((k[near], j[near], i[near]), heights.shape), ray[near]


def _ray_cells(setup, heights, terrain, block=2048):
    """For every ray: the scene's cells (k, j, i) that its grid segment crosses before it meets the terrain, as flat
    indices into (z, y, x), and the ray each belongs to; sampled every 1 / :data:`SAMPLES_PER_CELL` of the smaller cell
    size, ``block`` rays at a time. The horizontal index is the grid's affine map of the scene frame's x and y (within
    a hundredth of a cell of the march's over a few km; the march projects onto the sea-level sphere first)."""
    g = setup.geometry
    step = min(g.dz, g.spacing) / SAMPLES_PER_CELL
    start, direction, bounds = _rays_in_scene_frame(setup)
    cells, rays = [], []
    for lo in range(0, start.shape[0], block):
        c, r = _block_cells(start[lo:lo + block], direction[lo:lo + block], bounds[lo:lo + block], g, heights,
                            terrain, step)
        cells.append(c)
        rays.append(r + lo)
    return np.concatenate(cells), np.concatenate(rays)


def _pixel_rays(setup, pixel_masks):
    """The rays (indices in the rays' order) of the pixels where ``pixel_masks`` (one (ny, nx) bool per observer)."""
    rays, first = [], 0
    for flat, mask in zip(setup.pixels, pixel_masks):
        rays.append(first + np.flatnonzero(np.asarray(mask).reshape(-1)[flat]))
        first += flat.size
    return np.concatenate(rays)


def colour_ratio_update(operator, scene, state, observed, masks=None, *, threshold=RADIANCE_RATIO_THRESHOLD,
                        content=None, layer=None) -> ColourRatioUpdate:
    """One iteration of the paper's cloud clearing and insertion from colour-ratio cloud masks (module docstring).

    Parameters
    ----------
    operator : ForwardOperator
        The observers' forward operator (:class:`swim.assimilation.ForwardOperator`) of ``scene``.
    scene : xarray.Dataset
        The canonical scene of the operator: its ``height`` (z, y, x) [m above sea level] places the cells.
    state : array_like
        (z, y, x) cloud liquid water content [kg m-3]: the analysis to improve.
    observed : list of array_like
        One observed radiance image (3, ny, nx) [-] per observer, as the operator's.
    masks : list of array_like, optional
        One (ny, nx) mask per observer: the pixels that count (default the operator's masks; e.g.
        :meth:`ForwardOperator.masks_without_sun`).
    threshold : float
        L'(615) / L'(450) [-] at and above which a pixel is cloudy (:data:`RADIANCE_RATIO_THRESHOLD`).
    content : float, optional
        Liquid water content [kg m-3] of inserted cloud (default at each level the median of the state's cloudy cells
        there, > 1e-5 kg m-3; levels without: the median of all).
    layer : (float, float), optional
        Heights [m above sea level] between which cloud is inserted (default the heights of the state's cells with
        cloud, > 1e-5 kg m-3).

    Returns
    -------
    ColourRatioUpdate

    Raises
    ------
    SwimInputError
        If the state has the wrong shape or is not finite, the observed images do not match the observers, or the
        state has no cloud and ``content`` or ``layer`` is not given, or they are not positive and ordered.
    """
    state = np.asarray(state, float)
    heights = np.asarray(scene["height"].transpose("z", "y", "x").values, float)
    if state.shape != heights.shape or not np.all(np.isfinite(state)):
        raise SwimInputError(f"colour_ratio_update: state must be finite with the scene's shape (z, y, x) = "
                             f"{heights.shape} [kg m-3], got {state.shape}")
    check_observed(observed, operator.setup.shapes, "colour_ratio_update")
    cloud = state > 1e-5
    if (content is None or layer is None) and not cloud.any():
        raise SwimInputError("colour_ratio_update: the state has no cloud (> 1e-5 kg m-3); give content [kg m-3] "
                             "and layer (bottom, top) [m above sea level]")
    content = _level_content(state, cloud) if content is None else np.full(state.shape, float(content))
    layer = (heights[cloud].min(), heights[cloud].max()) if layer is None else tuple(map(float, layer))
    if not (np.all(content > 0) and layer[0] <= layer[1]):
        raise SwimInputError(f"colour_ratio_update: content must be > 0 [kg m-3] and layer (bottom, top) ordered "
                             f"[m], got {content.min()!r} and {layer!r}")
    masks = operator.masks if masks is None else [np.asarray(m) > 0 for m in masks]
    simulated = [np.asarray(image) for image in operator(state)]
    sim_cloudy = [cloudy_pixels(image, m, threshold) for image, m in zip(simulated, masks)]
    obs_cloudy = [cloudy_pixels(image, m, threshold) for image, m in zip(observed, masks)]
    terrain = np.asarray(scene["terrain_height"].transpose("y", "x").values, float)
    cells, ray = _ray_cells(operator.setup, heights, terrain)

    def crossed(pixel_masks):
        out = np.zeros(state.size, bool)
        out[cells[np.isin(ray, _pixel_rays(operator.setup, pixel_masks))]] = True
        return out.reshape(state.shape)

    seen_clear = crossed([m & ~o for m, o in zip(masks, obs_cloudy)])
    cleared = crossed([s & ~o for s, o in zip(sim_cloudy, obs_cloudy)]) & cloud
    in_layer = (heights >= layer[0]) & (heights <= layer[1])
    inserted = crossed([o & ~s for s, o in zip(sim_cloudy, obs_cloudy)]) & in_layer & ~seen_clear & ~cloud
    new = np.where(cleared, 0.0, state)
    new = np.where(inserted, content, new)
    log.info("colour-ratio update: %d cells cleared, %d inserted (%.2g kg m-3 on average, between %.0f and %.0f m)",
             cleared.sum(), inserted.sum(), content[inserted].mean() if inserted.any() else 0.0, *layer)
    return ColourRatioUpdate(new, cleared, inserted, sim_cloudy, obs_cloudy)
