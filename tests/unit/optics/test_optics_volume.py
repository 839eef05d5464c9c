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


def _numpy_interp_per_column(values, height, terrain, levels):
    """The independent reference of the column resampling: numpy.interp on each column, zero below the terrain and
    above half a layer over the top model level; (levels, ny, nx)."""
    expected = np.zeros((levels.size,) + values.shape[1:])
    for j, i in np.ndindex(*values.shape[1:]):
        h = height[:, j, i]
        expected[:, j, i] = np.interp(levels, h, values[:, j, i])
        top = h[-1] + 0.5 * (h[-1] - h[-2])
        expected[(levels > top) | (levels < terrain[j, i]), j, i] = 0.0
    return expected


@pytest.mark.parametrize("shape", [(2, 1, 1), (7, 3, 5), (30, 11, 4)])
def test_resample_columns_matches_numpy_interp_per_column(shape):
    """Each column resampled as numpy.interp would (an independent per-column reference), on uneven heights
    that differ from column to column, with target levels between, on and beyond the model levels; zero below
    the terrain and above half a layer over the top level. A block of columns gives the same as the whole."""
    from swim.optics.volume import ColumnInterpolation

    rng = np.random.default_rng(sum(shape))
    nz, ny, nx = shape
    height = 50.0 + np.cumsum(rng.uniform(20.0, 400.0, shape), axis=0)
    terrain = rng.uniform(0.0, 120.0, (ny, nx))
    values = rng.uniform(0.0, 1e-3, shape)
    levels = np.concatenate([np.linspace(0.0, height.max() * 1.3, 37), height[::3, 0, 0]])
    levels.sort()
    out = resample_columns(values, height, terrain, levels)
    assert out.shape == (levels.size, ny, nx) and out.dtype == np.float32
    # float32 weights from float32 heights (~1 mm at 12 km): 1e-4 of the values' range
    np.testing.assert_allclose(out, _numpy_interp_per_column(values, height, terrain, levels), rtol=1e-5, atol=1e-7)
    interpolation = ColumnInterpolation(height, terrain, levels)
    c0, c1 = (ny * nx) // 3, ny * nx
    block = interpolation.columns(values.reshape(nz, -1)[:, c0:c1], c0, c1)
    np.testing.assert_array_equal(block, out.reshape(levels.size, -1)[:, c0:c1])
    with pytest.raises(ValueError, match="columns per level"):
        interpolation.columns(values, c0, c1) if c0 else interpolation.columns(values[:, :0], 0, 1)


@pytest.mark.parametrize("shape", [(6, 1, 1), (9, 3, 5), (30, 11, 4)])
def test_resample_columns_of_a_sparse_field_matches_numpy_interp_per_column(shape):
    """A cloud fills few model levels: target levels whose model levels are zero in every column of a block are
    left zero without interpolating. Against numpy.interp per column, for a field that is zero on most levels,
    non-zero on one level in a single column, and zero everywhere; over the whole grid and in blocks of columns
    that split the cloudy levels' columns; and given by its non-zero cells alone (``ColumnInterpolation.cells``, which
    build_optical_volume uses), the same bits."""
    from swim.optics.volume import ColumnInterpolation

    rng = np.random.default_rng(sum(shape) + 1)
    nz, ny, nx = shape
    height = 50.0 + np.cumsum(rng.uniform(20.0, 400.0, shape), axis=0)
    terrain = rng.uniform(0.0, 120.0, (ny, nx))
    levels = np.linspace(0.0, height.max() * 1.2, 53)
    layer = np.zeros(shape)
    layer[nz // 2] = rng.uniform(1e-4, 1e-3, (ny, nx))  # one cloudy model level
    layer[nz // 2 + 1, ny - 1, nx - 1] = 7e-4  # and one cloudy cell above it, in the last column only
    fields = {"one level and one cell": layer, "zero": np.zeros(shape)}
    interpolation = ColumnInterpolation(height, terrain, levels)
    for name, values in fields.items():
        out = interpolation(values)
        np.testing.assert_allclose(out, _numpy_interp_per_column(values, height, terrain, levels), rtol=1e-5,
                                   atol=1e-9, err_msg=name)
        flat = values.reshape(nz, -1)
        cut = max(1, flat.shape[1] - 2)  # the last block holds the single cloudy column
        parts = [interpolation.columns(flat[:, c0:c1], c0, c1) for c0, c1 in ((0, cut), (cut, flat.shape[1]))
                 if c1 > c0]
        np.testing.assert_array_equal(np.concatenate(parts, axis=1), out.reshape(levels.size, -1), err_msg=name)
        # the compiled path of build_optical_volume: the same field given by its non-zero cells, the same bits
        for c0, c1 in ((0, cut), (cut, flat.shape[1]), (0, flat.shape[1])):
            block = np.ascontiguousarray(flat[:, c0:c1], dtype=np.float32)
            where = np.flatnonzero(block)
            sparse = interpolation.cells(where, block.ravel()[where], nz, c0, c1)
            np.testing.assert_array_equal(sparse, out.reshape(levels.size, -1)[:, c0:c1], err_msg=name)
    assert interpolation(layer).any() and not interpolation(fields["zero"]).any()


def test_optical_volume_refuses_bad_content_by_name():
    """Eq. 7 runs on the cells with content only, so a content that is not finite and >= 0 (a scene that was not
    validated) is refused with the variable's name and units, not skipped or turned into NaN extinction."""
    from swim.errors import SwimInputError
    from swim.io.scene import scene_from_arrays, validate_scene
    from swim.optics.volume import build_optical_volume

    nz, ny, nx = 6, 4, 5
    scene = validate_scene(scene_from_arrays(x=np.arange(nx) * 1000.0, y=np.arange(ny) * 1000.0,
                                             z=300.0 * (1 + np.arange(nz)), reference_lat=40.0, reference_lon=-100.0,
                                             terrain_height=np.zeros((ny, nx)),
                                             snow_content=np.full((nz, ny, nx), 1e-4)))
    for bad in (-1e-3, np.nan, np.inf):
        for background in (1e-4, 0.0):  # also where the field has no content at all besides the bad value
            broken = scene.copy(deep=True)
            broken["snow_content"].values[...] = background
            broken["snow_content"].values[2, 1, 3] = bad
            with pytest.raises(SwimInputError, match=r"snow_content must be finite and >= 0 \[kg m-3\]"):
                build_optical_volume(broken)


def test_optical_volume_in_blocks_of_rows_is_eq7_resampled(monkeypatch):
    """build_optical_volume computes Eq. 7 and resamples it in blocks of rows (memory): any block size gives
    beta = 1.5 CWC / (r_e rho) of the whole field, resampled, with r_e from Martin et al. (1994) for cloud
    liquid (computed here from its formula) and the scene's own radii for snow. Both fields are patchy (Eq. 7 is
    evaluated where there is content only), and one row of snow is clear (a block of one row is then empty)."""
    import swim.optics.volume as volume_module
    from swim.constants import HYDROMETEOR_DENSITY, SPECIES
    from swim.io.scene import scene_from_arrays, validate_scene

    rng = np.random.default_rng(7)
    nz, ny, nx = 12, 9, 7
    x = np.arange(nx) * 1000.0
    y = np.arange(ny) * 1000.0
    z = 200.0 + 400.0 * np.arange(nz)
    liquid = 5e-4 * rng.random((nz, ny, nx)) * (rng.random((nz, ny, nx)) > 0.4)
    snow = 2e-4 * rng.random((nz, ny, nx)) * (rng.random((nz, ny, nx)) > 0.5)
    snow[:, 3] = 0.0
    snow_radius = rng.uniform(50e-6, 500e-6, (nz, ny, nx))
    terrain = 300.0 * rng.random((ny, nx))
    scene = validate_scene(scene_from_arrays(x=x, y=y, z=z, reference_lat=40.0, reference_lon=-100.0,
                                             terrain_height=terrain, cloud_liquid_content=liquid, snow_content=snow,
                                             snow_effective_radius=snow_radius))
    volumes = {}
    for rows in (1, 4, ny):
        monkeypatch.setattr(volume_module, "_BLOCK_BYTES", 8 * nz * nx * rows)
        volumes[rows] = volume_module.build_optical_volume(scene)
    levels = volumes[ny]["level"].values
    height = scene["height"].values
    q = scene["cloud_liquid_content"].values
    r_liquid = np.clip(np.cbrt(3 * q / (4 * np.pi * 1000.0 * 0.8 * 1e8)), 4e-6, 20e-6)  # Martin et al. (1994)
    beta = {"cloud_liquid": 1.5 * q / (r_liquid * HYDROMETEOR_DENSITY["cloud_liquid"]),
            "snow": 1.5 * snow / (snow_radius * HYDROMETEOR_DENSITY["snow"])}
    for rows, volume in volumes.items():
        for species, value in beta.items():
            expected = resample_columns(value, height, scene["terrain_height"].values, levels)
            np.testing.assert_allclose(volume["extinction"].sel(species=species).values, expected, rtol=2e-6,
                                       atol=1e-12, err_msg=f"{species}, {rows} rows per block")
        others = [s for s in SPECIES if s not in beta]
        assert not volume["extinction"].sel(species=others).values.any()
        # no 3-D aerosol in the scene: a read-only zero that takes no memory
        aerosol = volume["aerosol_extinction"].values
        assert aerosol.shape == (levels.size, ny, nx) and not aerosol.any()
        assert not aerosol.flags.writeable and aerosol.strides == (0, 0, 0)
