"""The ground beyond the model grid: the margin by which the kernels' ground fields extend the grid, and the fade
beyond it to the far ground (:func:`extend_beyond_grid`, :func:`surface_fade_cells`).

A limited-area model knows nothing of the ground beyond its domain, but a view from an aircraft or from space sees
it. Beyond the grid swim continues the ground's fields from the grid's edge, smoothed along the edge the further out
they are and fading to the mean of the edge (:func:`swim.rt.march_inputs.surface_fields_outside`), so that the
domain's edge shows neither an outline (the sea brighter inside than outside where the edge's winds differ from their
mean) nor streaks (an edge's features carried outwards).
"""

from __future__ import annotations

import math

import numpy as np


#: The ground beyond the grid: the kernels read the ground's fields from an array that extends the grid by a margin of
#: :func:`surface_margin_cells` cells on every side (:func:`extend_beyond_grid`), and beyond that margin they fade from
#: its edge to :func:`surface_fields_outside` with these e-folding distances [cells] (:func:`surface_fade_cells`):
#: the surface's properties (albedo, land, snow, wind, slope) over 2 cells, its lighting by Step 1a (cloud T, terrain
#: shadow, 3-D aerosol towards the sun) over one, since no cloud beyond the grid casts a shadow.
SURFACE_EDGE_FADE_CELLS = 2.0
LIGHTING_EDGE_FADE_CELLS = 1.0
#: The margin beyond the grid [cells] (:func:`surface_margin_cells`): this fraction of the grid's longer side, within
#: [:data:`SURFACE_MARGIN_MIN_CELLS`, :data:`SURFACE_MARGIN_MAX_CELLS`].
SURFACE_MARGIN_FRACTION = 0.5
SURFACE_MARGIN_MIN_CELLS = 8
SURFACE_MARGIN_MAX_CELLS = 64


def surface_fade_cells(n_fields=11):
    """The e-folding distance [cells] of each of the 11 fields of :func:`surface_fields` beyond the grid's margin
    (11,), or with ``n_fields`` 14 also of the 3-D cloud scattering's diffuse ratios at the ground (lighting, like T)
    (:func:`swim.rt.clouds.cloud_constants`)."""
    return np.array([SURFACE_EDGE_FADE_CELLS] * 8 + [LIGHTING_EDGE_FADE_CELLS] * (n_fields - 8), np.float32)


def surface_margin_cells(ny, nx) -> int:
    """The width [cells] of the margin by which :func:`extend_beyond_grid` extends a grid of (ny, nx) columns."""
    return int(min(SURFACE_MARGIN_MAX_CELLS, max(SURFACE_MARGIN_MIN_CELLS, math.ceil(SURFACE_MARGIN_FRACTION
                                                                                      * max(ny, nx)))))


def extend_beyond_grid(fields, outside, margin, fade_cells=None, smoothed=True):
    """The ground's fields continued beyond the grid by ``margin`` cells on every side.

    At a distance d [cells] beyond the grid each field is ``outside + (S_d - outside) w(d)``: S_d is the grid's field
    extended outwards from its nearest edge cells and smoothed along the edge over a width of about d (box filters of
    widths 1, 2, 4, ... cells of the extruded field, interpolated in log-width), so that features of the edge (a
    hurricane's winds, a coast) widen and fade instead of running on as streaks; w(d) tapers from 1 at the edge to 0
    at the margin's edge as a half cosine, 0.5 (1 + cos(pi d / margin)), so that the ground stays continuous at the
    edge and changes over the whole margin, not in a band along the edge; or, with ``fade_cells``, w(d) = e^(-d / L).
    Inside the grid the fields are unchanged.

    Parameters
    ----------
    fields : numpy.ndarray, shape (C, ny, nx)
        The fields on the grid (:func:`surface_fields`, channel-major).
    outside : array_like, shape (C,)
        The ground far beyond the grid (:func:`surface_fields_outside`).
    margin : int
        The margin's width [cells] (:func:`surface_margin_cells`).
    fade_cells : array_like, shape (C,), optional
        The e-folding distance L [cells] of each field, for an exponential fade instead of the taper.
    smoothed : bool
        Whether S_d is smoothed along the edge; False: the nearest edge cell's values (for fields that fade within a
        cell or two, where the smoothing would change nothing that shows).

    Returns
    -------
    numpy.ndarray, shape (C, ny + 2 margin, nx + 2 margin), float32
    """
    from scipy.ndimage import uniform_filter

    fields = np.asarray(fields, np.float32)
    c, ny, nx = fields.shape
    m = int(margin)
    extruded = np.pad(fields, ((0, 0), (m, m), (m, m)), mode="edge")
    jj, ii = np.indices(extruded.shape[1:], dtype=np.float32)
    dj = np.maximum(np.maximum(m - jj, jj - (ny - 1 + m)), 0.0)
    di = np.maximum(np.maximum(m - ii, ii - (nx - 1 + m)), 0.0)
    d = np.hypot(dj, di)
    beyond = d > 0
    distance = d[beyond]
    # box widths 1, 2, 4, ... up to the margin; a cell at distance d takes the width ~d (interpolated in log2)
    widths = [1]
    while smoothed and widths[-1] < m:
        widths.append(2 * widths[-1])
    if len(widths) > 1:
        level = np.clip(np.log2(np.maximum(distance, 1.0)), 0.0, len(widths) - 1.0)
        lower = np.minimum(level.astype(np.int64), len(widths) - 2)
        upper_weight = (level - lower).astype(np.float32)
        rows = np.arange(lower.size)
    outside = np.asarray(outside, np.float32)
    taper = 0.5 * (1.0 + np.cos(np.pi * np.minimum(distance / max(m, 1), 1.0))) if fade_cells is None else None
    out = extruded.copy()
    for channel in range(c):
        if len(widths) > 1:
            boxes = np.stack([uniform_filter(extruded[channel], size=w, mode="nearest")[beyond] for w in widths])
            continued = boxes[lower, rows] * (1.0 - upper_weight) + boxes[lower + 1, rows] * upper_weight
        else:
            continued = extruded[channel][beyond]
        weight = taper if taper is not None else np.exp(-distance / np.float32(np.asarray(fade_cells)[channel]))
        out[channel][beyond] = outside[channel] + (continued - outside[channel]) * weight
    return out
