"""The optics stage: grid index maps for map-projected grids and the column resampling."""

import numpy as np
import pytest

from swim.constants import EARTH_RADIUS_M
from swim.frames import orthographic_xy
from swim.optics.volume import fit_grid_affine, fit_grid_index_map, grid_indices, resample_columns


def _mercator_grid(n=48, dx=10e3, lat0=24.5, lon0=-90.3):
    """Columns of a Mercator grid true at lat0 (as WRF MAP_PROJ=3), like the Katrina domain."""
    k = EARTH_RADIUS_M * np.cos(np.deg2rad(lat0))
    y0 = k * np.log(np.tan(np.pi / 4 + np.deg2rad(lat0) / 2))
    idx = np.arange(n) - (n - 1) / 2
    lon = lon0 + np.rad2deg(idx * dx / k)
    lat = np.rad2deg(2 * np.arctan(np.exp((y0 + idx * dx) / k)) - np.pi / 2)
    lon2, lat2 = np.meshgrid(lon, lat)
    return orthographic_xy(lat2, lon2, lat0, lon0)


def test_cubic_index_map_recovers_mercator_indices_where_affine_cannot():
    x, y = _mercator_grid()
    _, matrix, affine_residual = fit_grid_affine(x, y)
    spacing = np.sqrt(abs(np.linalg.det(matrix)))
    assert affine_residual > 0.2 * spacing  # the affine map misplaces columns by a fifth of a cell or more
    centre, scale, coefficients, residual = fit_grid_index_map(x, y)
    attrs = {"index_map_centre": centre, "index_map_scale": scale, "index_map_coefficients": coefficients.ravel()}
    i, j = grid_indices(attrs, x, y)
    jj, ii = np.meshgrid(np.arange(x.shape[0]), np.arange(x.shape[1]), indexing="ij")
    assert np.abs(i - ii).max() < 0.01 and np.abs(j - jj).max() < 0.01
    assert residual < 0.01
    # Mid-cell points land half-way between columns.
    xm, ym = 0.5 * (x[10, 10] + x[10, 11]), 0.5 * (y[10, 10] + y[10, 11])
    im, jm = grid_indices(attrs, xm, ym)
    assert im == pytest.approx(10.5, abs=0.01) and jm == pytest.approx(10.0, abs=0.01)


def test_resample_columns_is_linear_in_height_and_zero_below_terrain_and_above_top():
    height = np.array([100.0, 300.0, 700.0])[:, None, None] * np.ones((3, 2, 2))
    values = np.array([1.0, 3.0, 7.0])[:, None, None] * np.ones((3, 2, 2))
    terrain = np.array([[0.0, 150.0], [0.0, 0.0]])
    levels = np.array([0.0, 50.0, 200.0, 500.0, 800.0, 1000.0])
    out = resample_columns(values, height, terrain, levels)
    np.testing.assert_allclose(out[:, 0, 0], [1.0, 1.0, 2.0, 5.0, 7.0, 0.0])  # top + half a layer = 900 m
    assert out[1, 0, 1] == 0.0 and out[2, 0, 1] == pytest.approx(2.0)  # below the 150 m terrain: zero
