"""The ground beyond the grid (swim.rt.surface_margin.extend_beyond_grid): unchanged inside, continuous at the edge,
the far ground at the margin's edge, and an edge's features smoothed out instead of carried outwards as streaks."""

import numpy as np
import pytest

from swim.rt.surface_margin import extend_beyond_grid, surface_margin_cells


def _extend(fields, outside, margin, fade=None, smoothed=True):
    return extend_beyond_grid(np.asarray(fields, np.float32), np.asarray(outside, np.float32), margin,
                              None if fade is None else np.asarray(fade, np.float32), smoothed=smoothed)


def _taper(d, margin):
    return 0.5 * (1.0 + np.cos(np.pi * min(d / margin, 1.0)))


@pytest.mark.parametrize("shape", [(1, 1), (3, 7), (20, 12)])
@pytest.mark.parametrize("smoothed", [True, False])
def test_the_grid_is_unchanged_and_the_margin_ends_on_the_far_ground(shape, smoothed):
    rng = np.random.default_rng(sum(shape))
    fields = rng.uniform(0.0, 10.0, (1,) + shape)
    margin = 12
    tapered = _extend(fields, (4.0,), margin, smoothed=smoothed)
    faded = _extend(fields, (-1.0,), margin, fade=(1.0,), smoothed=smoothed)
    for out in (tapered, faded):
        assert out.shape == (1, shape[0] + 2 * margin, shape[1] + 2 * margin) and out.dtype == np.float32
        np.testing.assert_array_equal(out[:, margin:-margin, margin:-margin], fields.astype(np.float32))
    # at the margin's edge (d >= margin) the taper has reached the far ground, and a fade of one cell e^-12 of it
    for out, far, left in ((tapered, 4.0, 0.0), (faded, -1.0, np.exp(-12.0) * 11.0)):
        ring = np.concatenate([out[0, 0], out[0, -1], out[0, :, 0], out[0, :, -1]])
        assert np.all(np.abs(ring - far) <= left + 1e-5)


def test_the_ground_is_continuous_at_the_grid_edge():
    """The first cell beyond the edge continues the edge cell but for the taper's first step, 1 - w(1): 0.4 % of the
    difference from the far ground for a margin of 24 cells (a ground that jumped to the far ground at the edge would
    show the domain's outline)."""
    y, x = np.mgrid[0:30, 0:40]
    fields = (5.0 + 0.1 * x + 0.05 * y)[None]
    far = fields.mean()
    out = _extend(fields, (far,), 24)
    inner, first = out[0, 24:-24, 24], out[0, 24:-24, 23]  # the west edge and the cell beyond it
    assert np.all(np.abs(first - inner) <= (1 - _taper(1, 24)) * np.abs(inner - far) + 1e-5)
    # and halfway across the margin, half of the difference is left: the change is spread over the margin
    half = out[0, 24:-24, 12]
    np.testing.assert_allclose(half - far, 0.5 * (inner - far), atol=0.02 * np.ptp(fields))


def test_an_edge_feature_is_not_carried_outwards_as_a_streak():
    """One edge cell far from its neighbours (a hurricane's wind on a calm edge): extruded, it would run on at its
    value times the taper; smoothed along the edge it falls off faster, as ~1/d on top of it."""
    fields = np.zeros((1, 40, 40))
    fields[0, 20, 0] = 30.0  # one cell of the west edge
    margin = 32
    smoothed = _extend(fields, (0.0,), margin)
    extruded = _extend(fields, (0.0,), margin, smoothed=False)
    row = margin + 20
    for d in (4, 8, 16):
        column = margin - d
        assert extruded[0, row, column] == pytest.approx(30.0 * _taper(d, margin), rel=1e-4)
        assert smoothed[0, row, column] < 0.5 * extruded[0, row, column]
    # and the feature spreads no further along the edge than about its distance from the grid
    assert np.all(smoothed[0, : row - 3 * 8, margin - 8] < 1e-6)


def test_the_margin_follows_the_grid_size():
    assert surface_margin_cells(10, 10) == 8
    assert surface_margin_cells(100, 40) == 50
    assert surface_margin_cells(2000, 1000) == 64
