"""Adaptive image sampling (swim.rt.image_sampling) on analytic images: exact where interpolation is exact,
exact at sharp edges, never tracing invalid pixels, over several image shapes."""

import numpy as np
import pytest

from swim.errors import SwimInputError
from swim.rt.image_sampling import AdaptiveSampling, sample_image_adaptive, tile_order


def make_trace(function, shape, calls=None):
    """A trace callback that evaluates function(y, x) -> (radiance (n, 3), tau (n,), surface (n,)) per pixel."""
    ny, nx = shape

    def trace(flat):
        flat = np.asarray(flat)
        if calls is not None:
            calls.append(flat.copy())
        y, x = np.divmod(flat, nx)
        radiance, tau, surface = function(y.astype(float), x.astype(float))
        return {"radiance": radiance, "tau_hydrometeor": tau, "surface": surface,
                "distance": np.where(surface, 100.0 + x, np.nan), "steps": np.full(flat.size, 7, np.int32)}

    return trace


def bilinear_function(y, x):
    """Exactly bilinear in (y, x), so bilinear interpolation of any cell reproduces it."""
    radiance = np.stack([0.2 + 0.01 * x + 0.003 * y + 1e-4 * x * y, 0.5 + 0.002 * y, 0.1 + 0.0 * x], axis=1)
    return radiance, 0.5 + 0.01 * y, np.zeros(y.shape, bool)


def disk_function(y, x):
    """A bright ground disk of radius 9 px (a sharp edge) on a uniform sky."""
    inside = (y - 20.3) ** 2 + (x - 31.7) ** 2 < 9.0**2
    radiance = np.where(inside[:, None], [2.0, 1.8, 1.5], [0.3, 0.5, 0.9])
    return radiance, np.where(inside, 5.0, 0.0), inside


def exact(function, shape):
    y, x = np.indices(shape).reshape(2, -1).astype(float)
    return function(y, x)


def expected_first_pixels(shape, spacing, edge_test_size):
    """The pixels that the first batch traces, from the rule in the module's docstring: the lattice, the centre of
    each cell with a pixel between its corners, and the midpoints of the edges of cells at least ``edge_test_size``
    pixels high or wide."""
    rows, cols = (np.unique(np.append(np.arange(0, n, spacing), n - 1)) for n in shape)
    pixels = {(int(r), int(c)) for r in rows for c in cols}
    for y0, y1 in zip(rows[:-1], rows[1:]):
        for x0, x1 in zip(cols[:-1], cols[1:]):
            yc, xc = (y0 + y1) // 2, (x0 + x1) // 2
            if y1 - y0 > 1 or x1 - x0 > 1:
                pixels.add((int(yc), int(xc)))
            if edge_test_size and max(y1 - y0, x1 - x0) >= edge_test_size:
                pixels |= {(int(y0), int(xc)), (int(y1), int(xc)), (int(yc), int(x0)), (int(yc), int(x1))}
    return {y * shape[1] + x for y, x in pixels}


@pytest.mark.parametrize("shape", [(1, 7), (2, 2), (3, 3), (5, 17), (33, 33), (40, 61), (64, 64)])
@pytest.mark.parametrize("spacing, edge_test_size", [(2, 0), (4, 0), (8, 0), (4, 4), (8, 8), (16, 8)])
def test_bilinear_image_is_reproduced_exactly_over_shapes(shape, spacing, edge_test_size):
    sampling = AdaptiveSampling(coarse_spacing=spacing, edge_test_size=edge_test_size)
    values, traced = sample_image_adaptive(make_trace(bilinear_function, shape), np.ones(shape, bool), sampling)
    radiance, tau, _ = exact(bilinear_function, shape)
    np.testing.assert_allclose(values["radiance"], radiance, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(values["tau_hydrometeor"], tau, rtol=1e-12, atol=1e-12)
    assert traced.shape == shape
    # integer outputs (march steps) count the traced pixels only
    assert np.array_equal(values["steps"] > 0, traced.reshape(-1))
    if min(shape) > spacing:
        # every cell is smooth: the lattice and each cell's tested pixels are traced, and nothing else
        assert set(np.flatnonzero(traced)) == expected_first_pixels(shape, spacing, edge_test_size)
    if min(shape) >= 4 * spacing:
        assert traced.sum() < 1.5 * (4 if edge_test_size else 2) / spacing**2 * traced.size


@pytest.mark.parametrize("shape", [(65, 65), (64, 97)])
def test_a_smooth_image_is_traced_on_the_lattice_of_half_the_spacing_with_edge_tests(shape):
    """With edge tests in the coarse cells, a smooth image's traced pixels are the lattice of every 4th row and
    column (the coarse lattice of 8, its cells' centres and their edges' midpoints) over the whole cells of 8: 1/16
    of the pixels, where centre tests alone at a spacing of 4 trace 1/8."""
    values, traced = sample_image_adaptive(make_trace(bilinear_function, shape), np.ones(shape, bool),
                                           AdaptiveSampling(coarse_spacing=8, edge_test_size=8))
    on_lattice = np.zeros(shape, bool)
    on_lattice[::4, ::4] = True
    full = (slice(0, (shape[0] - 1) // 8 * 8 + 1), slice(0, (shape[1] - 1) // 8 * 8 + 1))  # the whole cells of 8
    assert np.array_equal(traced[full], on_lattice[full])
    assert traced.sum() < 1.3 / 16 * traced.size
    old = sample_image_adaptive(make_trace(bilinear_function, shape), np.ones(shape, bool),
                                AdaptiveSampling(coarse_spacing=4, edge_test_size=0))[1]
    assert traced.sum() < 0.6 * old.sum()
    np.testing.assert_allclose(values["radiance"], exact(bilinear_function, shape)[0], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("spot", [(0, 4), (8, 4), (4, 0), (4, 8)])
def test_a_feature_at_an_edge_midpoint_is_found_by_the_edge_test_and_missed_without(spot):
    """A one-pixel spot at the midpoint of an edge of the first 8-pixel cell touches neither the cell's corners nor
    its centre: centre tests alone interpolate it away, edge tests find it and trace it."""
    def spot_image(y, x):
        on = (y == spot[0]) & (x == spot[1])
        radiance = np.where(on[:, None], 1.0, 0.2) * np.ones((1, 3))
        return radiance, np.zeros(y.shape), np.zeros(y.shape, bool)

    shape = (17, 17)
    radiance, _, _ = exact(spot_image, shape)
    at = spot[0] * shape[1] + spot[1]
    found, traced = sample_image_adaptive(make_trace(spot_image, shape), np.ones(shape, bool),
                                          AdaptiveSampling(coarse_spacing=8, edge_test_size=8))
    np.testing.assert_allclose(found["radiance"], radiance, rtol=1e-12, atol=0)
    assert traced.reshape(-1)[at]
    missed, traced = sample_image_adaptive(make_trace(spot_image, shape), np.ones(shape, bool),
                                           AdaptiveSampling(coarse_spacing=8, edge_test_size=0))
    assert not traced.reshape(-1)[at] and np.allclose(missed["radiance"][at], 0.2)


def test_the_clear_air_test_finds_a_jump_of_the_air_in_front_of_opaque_cloud_that_the_others_miss():
    """Opaque cloud whose visible face jumps from a near cloud to a far one along a line: the total radiance and the
    capped line-of-sight optical depth are the same on both sides, the air in front of the cloud (radiance_clear) is
    brighter beyond. The clear-air test traces the line's pixels; without it (clear_tolerance 0), or with a trace
    that does not return radiance_clear, the cells are interpolated over it."""
    def faces(y, x):
        far = x >= 11
        clear = np.where(far[:, None], 0.30, 0.10) * np.ones((1, 3))
        return np.full((y.size, 3), 0.8), np.full(y.shape, 50.0), np.zeros(y.shape, bool), clear

    shape = (17, 33)
    y, x = np.indices(shape).reshape(2, -1)

    def trace(flat, with_clear=True):
        radiance, tau, surface, clear = faces(y[flat], x[flat])
        out = {"radiance": radiance, "tau_hydrometeor": tau, "surface": surface}
        return {**out, "radiance_clear": clear} if with_clear else out

    valid = np.ones(shape, bool)
    found, traced = sample_image_adaptive(trace, valid, AdaptiveSampling())
    assert traced.reshape(-1)[(x == 10) | (x == 11)].all()  # both sides of the jump, in every row
    np.testing.assert_allclose(found["radiance_clear"], faces(y, x)[3], rtol=1e-12, atol=0)
    for sampling, tracer in ((AdaptiveSampling(clear_tolerance=0.0), trace),
                             (AdaptiveSampling(), lambda flat: trace(flat, with_clear=False))):
        _, traced = sample_image_adaptive(tracer, valid, sampling)
        assert not traced.reshape(-1)[(x == 10) | (x == 11)].any()


@pytest.mark.parametrize("spacing", [4, 8])
def test_sharp_edge_is_refined_to_single_pixels(spacing):
    shape = (45, 70)
    values, traced = sample_image_adaptive(make_trace(disk_function, shape), np.ones(shape, bool),
                                           AdaptiveSampling(coarse_spacing=spacing))
    radiance, tau, surface = exact(disk_function, shape)
    # a disk much larger than a cell: every cell its edge crosses separates some of its corners and centre
    np.testing.assert_allclose(values["radiance"], radiance, rtol=1e-12, atol=0)
    np.testing.assert_allclose(values["tau_hydrometeor"], tau, rtol=1e-12, atol=0)
    np.testing.assert_array_equal(values["surface"], surface)
    np.testing.assert_array_equal(np.isnan(values["distance"]), ~surface)
    assert traced.sum() < 0.6 * traced.size


def test_feature_at_a_cell_centre_is_found():
    def spot_at_centre(y, x):
        on = (y == 8) & (x == 8)  # the centre of the first 16-pixel cell
        radiance = np.where(on[:, None], 1.0, 0.2) * np.ones((1, 3))
        return radiance, np.zeros(y.shape), np.zeros(y.shape, bool)

    shape = (33, 33)
    values, _ = sample_image_adaptive(make_trace(spot_at_centre, shape), np.ones(shape, bool),
                                      AdaptiveSampling(coarse_spacing=16))
    radiance, _, _ = exact(spot_at_centre, shape)
    np.testing.assert_allclose(values["radiance"], radiance, rtol=1e-12, atol=0)


@pytest.mark.parametrize("outside", [0.0, np.nan])
def test_invalid_pixels_are_never_traced_and_keep_the_outside_value(outside):
    shape = (48, 48)
    yy, xx = np.indices(shape)
    valid = (yy - 23.5) ** 2 + (xx - 23.5) ** 2 <= 24.0**2  # an all-sky camera's circle
    calls = []
    values, traced = sample_image_adaptive(make_trace(bilinear_function, shape, calls), valid, AdaptiveSampling(),
                                           outside=outside)
    asked = np.concatenate(calls)
    assert valid.reshape(-1)[asked].all()
    assert np.unique(asked).size == asked.size  # no pixel traced twice
    assert not traced[~valid].any()
    radiance, _, _ = exact(bilinear_function, shape)
    flat_valid = valid.reshape(-1)
    np.testing.assert_allclose(values["radiance"][flat_valid], radiance[flat_valid], rtol=1e-12, atol=1e-12)
    # float outputs take the outside value there (all of them, and no valid pixel does), the others 0
    for key in ("radiance", "tau_hydrometeor"):
        np.testing.assert_array_equal(values[key][~flat_valid], outside)
        assert np.all(np.isfinite(values[key][flat_valid]))
    assert not values["surface"][~flat_valid].any() and np.all(values["steps"][~flat_valid] == 0)


def test_tolerance_bounds_the_error_of_a_smooth_curved_image():
    def curved(y, x):
        r = 0.3 + 0.5 * np.exp(-((y - 30) ** 2 + (x - 50) ** 2) / 400.0)
        return np.stack([r, 0.8 * r, 1.2 * r], axis=1), np.zeros(y.shape), np.zeros(y.shape, bool)

    shape = (64, 96)
    for tolerance in (0.01, 0.002):
        values, traced = sample_image_adaptive(make_trace(curved, shape), np.ones(shape, bool),
                                               AdaptiveSampling(tolerance=tolerance))
        radiance, _, _ = exact(curved, shape)
        rel = np.abs(values["radiance"] - radiance) / radiance
        # the centre test bounds the error where it looks; elsewhere the curvature is of the same order
        assert rel.max() < 2 * tolerance
        assert traced.sum() < 0.7 * traced.size


def test_tau_tolerance_bounds_the_error_of_a_smooth_optical_depth_image_on_its_own():
    """A uniform radiance over a smooth optical-depth bump: only the optical-depth test can refine, and its own
    tolerance (not the radiance's) bounds the interpolated optical depth's error."""
    def bump(y, x):
        tau = 2.0 + 6.0 * np.exp(-((y - 30) ** 2 + (x - 50) ** 2) / 400.0)
        return np.tile([0.3, 0.5, 0.9], (y.size, 1)), tau, np.zeros(y.shape, bool)

    shape = (64, 96)
    _, tau, _ = exact(bump, shape)
    errors, traced_counts = [], []
    for tau_tolerance in (0.05, 0.01):
        values, traced = sample_image_adaptive(make_trace(bump, shape), np.ones(shape, bool),
                                               AdaptiveSampling(tolerance=0.001, tau_tolerance=tau_tolerance))
        errors.append(np.max(np.abs(values["tau_hydrometeor"] - tau) / tau))
        traced_counts.append(int(traced.sum()))
        # the centre test bounds the error where it looks; elsewhere the curvature is of the same order
        assert errors[-1] < 2 * tau_tolerance
    assert errors[0] > 2 * 0.001  # the radiance's tolerance does not hold the optical depth
    assert traced_counts[0] < traced_counts[1]  # the looser test interpolates more of the bump


def mixed_function(y, x):
    """Smooth gradients with sharp-edged blobs of several sizes: smooth cells and splits at every level."""
    blobs = ((y - 12.0) ** 2 + (x - 40.0) ** 2 < 30.0) | ((np.abs(y - 45.0) < 3) & (np.abs(x - 20.0) < 11))
    r = 0.3 + 0.004 * x + 0.002 * y + np.where(blobs, 0.9, 0.0) + 0.05 * np.sin(x / 7.0) * np.cos(y / 9.0)
    return np.stack([r, 0.7 * r, 1.1 * r], axis=1), np.where(blobs, 3.0, 0.01 * y), blobs


@pytest.mark.parametrize("shape", [(64, 96), (61, 77)])
def test_traced_pixels_keep_their_values_and_threads_do_not_change_the_image(shape):
    valid = np.ones(shape, bool)
    valid[:, :3] = False  # invalid pixels on the lattice's first column
    results = [sample_image_adaptive(make_trace(mixed_function, shape), valid, AdaptiveSampling(), max_threads=n)
               for n in (1, 3)]
    (values, traced), (values_threads, traced_threads) = results
    assert np.array_equal(traced, traced_threads)
    for key in values:
        np.testing.assert_array_equal(values[key], values_threads[key])
    radiance, tau, surface = exact(mixed_function, shape)
    t = traced.reshape(-1)
    # interpolation happens after the last level: no traced pixel is overwritten by a coarser cell's interpolation
    np.testing.assert_array_equal(values["radiance"][t], radiance[t])
    np.testing.assert_array_equal(values["tau_hydrometeor"][t], tau[t])
    np.testing.assert_array_equal(values["surface"][t], surface[t])
    interpolated = valid.reshape(-1) & ~t
    assert interpolated.sum() > 0.3 * valid.sum() and t.sum() > 0.1 * valid.sum()
    # an interpolated pixel is a convex combination of traced ones, and a smooth cell is accurate to ~ tolerance
    assert values["radiance"][interpolated].min() >= radiance[t].min() - 1e-12
    assert values["radiance"][interpolated].max() <= radiance[t].max() + 1e-12
    rel = np.abs(values["radiance"][interpolated] - radiance[interpolated]) / radiance[interpolated]
    assert np.median(rel) < 0.01
    assert np.all(values["radiance"][~valid.reshape(-1)] == 0)


@pytest.mark.parametrize("pattern", ["none", "diagonal", "one"])
def test_masks_without_valid_lattice_pixels(pattern):
    shape = (33, 40)
    valid = np.zeros(shape, bool)
    if pattern == "diagonal":
        valid[np.arange(33), np.arange(33) + 3] = True  # off the lattice's first columns
    elif pattern == "one":
        valid[13, 17] = True
    values, traced = sample_image_adaptive(make_trace(bilinear_function, shape), valid, AdaptiveSampling())
    radiance, _, _ = exact(bilinear_function, shape)
    assert np.array_equal(traced, valid)  # no cell of valid pixels is smooth: each is traced
    flat = valid.reshape(-1)
    np.testing.assert_array_equal(values["radiance"][flat], radiance[flat])
    assert np.all(values["radiance"][~flat] == 0)


def test_each_cells_centre_is_traced_with_the_batch_before_its_test():
    # the lattice with its cells' centres, then each level's edge midpoints with the children's centres: three
    # batches for a spacing of 4 (the levels 4 and 2), and no pixel asked for twice
    # (for a spacing of 8 with edge tests: the levels 8, 4 and 2)
    shape = (40, 61)
    for spacing, edge_test_size, batches in ((4, 0, 3), (8, 8, 4)):
        calls = []
        values, traced = sample_image_adaptive(make_trace(disk_function, shape, calls), np.ones(shape, bool),
                                               AdaptiveSampling(coarse_spacing=spacing, edge_test_size=edge_test_size))
        assert len(calls) == batches
        asked = np.concatenate(calls)
        assert np.unique(asked).size == asked.size and np.array_equal(np.sort(asked), np.flatnonzero(traced))
        assert set(calls[0]) == expected_first_pixels(shape, spacing, edge_test_size)


def test_progress_reaches_all_valid_pixels():
    shape = (30, 40)
    seen = []
    sample_image_adaptive(make_trace(disk_function, shape), np.ones(shape, bool), AdaptiveSampling(),
                          progress=lambda done, total: seen.append((done, total)))
    assert seen[-1] == (30 * 40, 30 * 40)
    assert all(a <= b for (a, _), (b, _) in zip(seen, seen[1:]))


@pytest.mark.parametrize("kwargs", [{"tolerance": 0.0}, {"tolerance": -0.1}, {"tolerance": float("nan")},
                                    {"coarse_spacing": 1}, {"coarse_spacing": 2.5}, {"radiance_floor": -1.0},
                                    {"tau_floor": float("inf")}, {"tau_tolerance": 0.0}, {"tau_tolerance": -1.0},
                                    {"edge_test_size": -1}, {"edge_test_size": 8.0}, {"clear_tolerance": -0.01},
                                    {"clear_tolerance": float("inf")}, {"clear_tolerance": "0.05"}])
def test_bad_settings_raise_naming_the_field(kwargs):
    with pytest.raises(SwimInputError, match=f"AdaptiveSampling.{next(iter(kwargs))}"):
        AdaptiveSampling(**kwargs)


def test_bad_mask_raises():
    with pytest.raises(SwimInputError, match="valid"):
        sample_image_adaptive(make_trace(bilinear_function, (4, 4)), np.ones((4, 4)), AdaptiveSampling())


@pytest.mark.parametrize("shape, tile", [((16, 16), 8), ((19, 37), 8), ((5, 3), 4), ((7, 11), 1), ((1, 9), 8)])
@pytest.mark.parametrize("subset", ["all", "scattered"])
def test_tile_order_is_a_permutation_that_visits_tiles_one_after_the_other(shape, tile, subset):
    rng = np.random.default_rng(3)
    flat = np.arange(shape[0] * shape[1])
    if subset == "scattered":
        flat = np.sort(rng.choice(flat, size=max(1, flat.size // 3), replace=False))
    order = tile_order(flat, shape, tile)
    assert sorted(order.tolist()) == list(range(flat.size))
    y, x = np.divmod(flat[order], shape[1])
    tile_id = (y // tile) * -(-shape[1] // tile) + x // tile
    # each tile's pixels form one run, tiles in row-major order, pixels of a tile in row-major order
    assert np.all(np.diff(tile_id) >= 0)
    same = np.diff(tile_id) == 0
    assert np.all(np.diff(flat[order])[same] > 0)
    if tile == 1:
        assert np.array_equal(flat[order], flat)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_the_compiled_fill_interpolates_each_cell_in_the_values_precision_finer_cells_last(dtype):
    """swim.rt.fill_cpu against a per-cell NumPy reference: every untraced valid pixel of a cell is the bilinear
    interpolation of its corners, with the four weights computed in float64 and rounded once to the values'
    precision and the products summed corner by corner, bit for bit, in every array of the pass; a pixel shared
    with a later (finer) cell takes that cell's value, also when bands of rows are filled apart; traced and invalid
    pixels are left alone; booleans copy the first corner, counts are 0."""
    from swim.rt.fill_cpu import fill_cells, fill_cells_from_corner

    ny, nx = 17, 26
    rng = np.random.default_rng(5)
    values = rng.uniform(0.1, 3.0, (ny * nx, 3)).astype(dtype)
    flags = rng.random(ny * nx) < 0.5
    counts = rng.integers(1, 50, ny * nx).astype(np.int32)
    coarse = np.array([[0, 8, 0, 8], [0, 8, 8, 16], [8, 16, 16, 25]])
    fine = np.array([[8, 12, 0, 4], [12, 16, 4, 8], [0, 4, 16, 20], [8, 9, 0, 3]])  # one cell a single row high
    cells = np.concatenate([coarse, fine])
    traced = np.zeros(ny * nx, bool)
    for y0, y1, x0, x1 in cells:
        traced[[y0 * nx + x0, y0 * nx + x1, y1 * nx + x0, y1 * nx + x1]] = True
    traced[3 * nx + 5] = True  # a traced pixel inside a cell keeps its value
    valid = np.ones(ny * nx, bool)
    valid[10 * nx + 1] = False

    original = values.copy()
    expected, expected_flags, expected_counts = values.copy(), flags.copy(), counts.copy()
    for y0, y1, x0, x1 in cells:
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                pix = y * nx + x
                if traced[pix] or not valid[pix]:
                    continue
                wy, wx = (y - y0) / (y1 - y0), (x - x0) / (x1 - x0)
                w = np.array([(1 - wx) * (1 - wy), wx * (1 - wy), (1 - wx) * wy, wx * wy]).astype(dtype)
                corners = [y0 * nx + x0, y0 * nx + x1, y1 * nx + x0, y1 * nx + x1]
                acc = values[corners[0]] * w[0]
                for c, wc in zip(corners[1:], w[1:]):
                    acc = acc + values[c] * wc
                expected[pix] = acc
                expected_flags[pix] = flags[corners[0]]
                expected_counts[pix] = 0
    # with a second array of one channel (its expected values: the first channel's), in bands of rows that split
    # cells (rows 0-6 and 7-16: the pixel (8, 2) and its cells in the second), as threads run it
    single = np.ascontiguousarray(original[:, :1])
    for y_lo, y_hi in ((0, 7), (7, ny)):
        fill_cells((values, single), cells, traced, valid, nx, y_lo, y_hi)
    fill_cells_from_corner(flags, cells, traced, valid, nx, False)
    fill_cells_from_corner(counts, cells, traced, valid, nx, True)
    assert values.tobytes() == expected.tobytes()
    assert single.tobytes() == np.ascontiguousarray(expected[:, :1]).tobytes()
    # a band writes its rows alone
    banded = original.copy()
    fill_cells((banded,), cells, traced, valid, nx, 7, 9)
    rows = np.arange(ny * nx) // nx
    assert banded[(rows >= 7) & (rows < 9)].tobytes() == expected[(rows >= 7) & (rows < 9)].tobytes()
    assert banded[(rows < 7) | (rows >= 9)].tobytes() == original[(rows < 7) | (rows >= 9)].tobytes()
    np.testing.assert_array_equal(flags, expected_flags)
    np.testing.assert_array_equal(counts, expected_counts)
    # the cases that the comparison covers: the pixel (8, 2) on the common edge of a coarse and a fine cell, whose
    # value along the coarse cell's edge differs; a traced and an invalid pixel inside cells, unchanged
    along_coarse_edge = original[8 * nx] * dtype(1 - 2 / 8) + original[8 * nx + 8] * dtype(2 / 8)
    assert np.abs(values[8 * nx + 2] - along_coarse_edge).max() > 1e-3
    np.testing.assert_array_equal(values[[3 * nx + 5, 10 * nx + 1]], original[[3 * nx + 5, 10 * nx + 1]])


def _smooth_cells_numpy(values, valid_flat, traced, cells, nx, sampling):
    """The cells' test as NumPy gathers over all cells at once (a vectorised equivalent): the reference
    that swim.rt.smooth_cpu's per-cell kernels must reproduce."""
    y0, y1, x0, x1 = cells.T
    yc, xc = (y0 + y1) // 2, (x0 + x1) // 2
    corners = [y0 * nx + x0, y0 * nx + x1, y1 * nx + x0, y1 * nx + x1]
    wy = (yc - y0) / np.maximum(y1 - y0, 1)
    wx = (xc - x0) / np.maximum(x1 - x0, 1)
    tests = [(yc * nx + xc, ((1 - wx) * (1 - wy), wx * (1 - wy), (1 - wx) * wy, wx * wy))]
    size = sampling.edge_test_size
    edged = (np.maximum(y1 - y0, x1 - x0) >= size) if size > 0 else np.zeros(len(cells), bool)
    zero = np.zeros(len(cells))
    midpoints = (y0 * nx + xc, y1 * nx + xc, yc * nx + x0, yc * nx + x1)
    edge_weights = ((1 - wx, wx, zero, zero), (zero, zero, 1 - wx, wx), (1 - wy, zero, wy, zero),
                    (zero, 1 - wy, zero, wy))
    centre, centre_weights = tests[0]
    tests += [(np.where(edged, pixel, centre), tuple(np.where(edged, w, wc) for w, wc in zip(weights, centre_weights)))
              for pixel, weights in zip(midpoints, edge_weights)]
    ok = np.ones(len(cells), bool)
    for p in corners + [pixel for pixel, _ in tests]:
        ok &= valid_flat[p] & traced[p]
    for p in corners + [pixel for pixel, _ in tests[1:]]:
        ok &= values["surface"][p] == values["surface"][centre]
    checks = [("radiance", sampling.tolerance, sampling.radiance_floor),
              ("tau_hydrometeor", sampling.tau_tolerance, sampling.tau_floor)]
    if sampling.clear_tolerance > 0:
        checks.append(("radiance_clear", sampling.clear_tolerance, sampling.radiance_floor))
    for key, tolerance, floor in checks:
        v = values[key].reshape(values[key].shape[0], -1)
        c = [v[p] for p in corners]
        for pixel, weights in tests:
            with np.errstate(invalid="ignore"):  # 0 * inf
                predicted = sum(w[:, None] * ci for w, ci in zip(weights, c))
                actual = v[pixel]
                scale = np.maximum(np.abs(actual), np.abs(predicted))
                ok &= np.all(np.abs(actual - predicted) <= tolerance * scale + floor, axis=1)
    return ok


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("edge_test_size", [0, 5, 8])
@pytest.mark.parametrize("clear_tolerance", [0.0, 0.05])
def test_the_compiled_cell_test_decides_as_the_numpy_gathers(dtype, edge_test_size, clear_tolerance, monkeypatch):
    """swim.rt.smooth_cpu (through image_sampling._smooth_cells) against the NumPy test it replaced, cell for cell,
    on images that make every part of the test decide: values that are exactly bilinear (pass), noise at the
    tolerance's edge (both ways), NaN and inf values, pixels without a ray or not traced, the ground beside the
    sky, and cells of every size from 1 x 2 pixels to 16 x 16, with and without edge tests; on one thread and on
    three, each testing a block of the cells."""
    from swim.rt import image_sampling
    from swim.rt.image_sampling import _smooth_cells

    ny, nx = 64, 70
    rng = np.random.default_rng(47 + edge_test_size)
    y, x = np.mgrid[0:ny, 0:nx]
    planar = (0.3 + 0.01 * y + 0.02 * x + 1e-4 * x * y).reshape(-1)
    sampling = AdaptiveSampling(tolerance=0.02, tau_tolerance=0.05, clear_tolerance=clear_tolerance,
                                edge_test_size=edge_test_size)
    # relative noise spread around the tolerances: about half the tested pixels pass
    noise = lambda k: 1 + rng.uniform(-0.06, 0.06, (ny * nx, k)) * (rng.random((ny * nx, 1)) < 0.5)
    values = {"radiance": (planar[:, None] * [1.0, 0.8, 0.6] * noise(3)).astype(dtype),
              "tau_hydrometeor": (10 * planar * noise(1)[:, 0]).astype(dtype),
              "radiance_clear": (0.1 * planar[:, None] * [1.0, 0.9, 0.7] * noise(3)).astype(dtype),
              "surface": rng.random(ny * nx) < 0.05}
    values["radiance"][rng.random(ny * nx) < 0.01, 1] = np.nan
    values["radiance_clear"][rng.random(ny * nx) < 0.005, 2] = np.inf
    valid = rng.random(ny * nx) > 0.03
    traced = rng.random(ny * nx) > 0.03
    cells = []
    for size in (1, 2, 3, 4, 5, 8, 16):
        for y0 in range(0, ny - size, max(size, 2) + 1):
            for x0 in range(0, nx - 2 * size, 2 * size + 1):
                cells.append((y0, y0 + size, x0, x0 + 2 * size if size < 3 else x0 + size))
    cells = np.array(cells, np.int64)
    got = _smooth_cells(values, valid, traced, cells, nx, sampling)
    expected = _smooth_cells_numpy(values, valid, traced, cells, nx, sampling)
    np.testing.assert_array_equal(got, expected)
    monkeypatch.setattr(image_sampling, "SMOOTH_BLOCK_CELLS", len(cells) // 4)  # three uneven blocks
    np.testing.assert_array_equal(_smooth_cells(values, valid, traced, cells, nx, sampling, max_threads=3), expected)
    # every way of deciding occurs: some cells pass, and more fail than the rays and surfaces alone would fail
    assert 0.1 < expected.mean() < 0.9
    bare = AdaptiveSampling(tolerance=1e9, tau_tolerance=1e9, clear_tolerance=1e9 if clear_tolerance else 0.0,
                            edge_test_size=edge_test_size)
    only_rays = _smooth_cells_numpy(values, valid, traced, cells, nx, bare)
    assert np.any(only_rays & ~expected) and not np.all(only_rays)
    # exactly bilinear values pass wherever the rays and surfaces allow (float64 rounding within the tolerance)
    exact = {**values, "radiance": np.repeat(planar[:, None], 3, 1).astype(dtype),
             "tau_hydrometeor": planar.astype(dtype), "radiance_clear": np.repeat(planar[:, None], 3, 1).astype(dtype)}
    exact["surface"] = np.zeros(ny * nx, bool)
    passed = _smooth_cells(exact, valid, traced, cells, nx, AdaptiveSampling(tolerance=1e-3, tau_tolerance=1e-3,
                                                                              edge_test_size=edge_test_size))
    np.testing.assert_array_equal(passed, _smooth_cells_numpy(exact, valid, traced, cells, nx, bare))


@pytest.mark.parametrize("shape", [(5, 17), (40, 61)])
def test_a_tracer_may_return_its_rows_in_its_own_order(shape):
    """trace(pixels) -> (order, arrays), the rows those of pixels[order] (the pipeline's tile order): the same image
    and the same traced pixels as a tracer that returns them in the order asked for. A tracer whose order were
    ignored would put each pixel's values at another pixel."""
    plain = make_trace(disk_function, shape)
    rng = np.random.default_rng(3)

    def shuffled(flat):
        order = rng.permutation(len(flat))
        return order, plain(np.asarray(flat)[order])

    valid = np.ones(shape, bool)
    valid[0, :3] = False
    expected, traced_expected = sample_image_adaptive(plain, valid, AdaptiveSampling(coarse_spacing=4))
    values, traced = sample_image_adaptive(shuffled, valid, AdaptiveSampling(coarse_spacing=4))
    np.testing.assert_array_equal(traced, traced_expected)
    assert set(values) == set(expected)
    for key in expected:
        np.testing.assert_array_equal(values[key], expected[key])


def _split_cells_numpy(cells, smooth, nx, ny, edge_size):
    """The next level in NumPy (a vectorised equivalent): the reference for swim.rt.smooth_cpu's
    split_cells. Returns the children (k, 4) and the mask of the pixels to trace."""
    split = cells[~smooth]
    y0, y1, x0, x1 = split.T
    yc, xc = (y0 + y1) // 2, (x0 + x1) // 2
    children = np.concatenate([
        np.stack([y0, yc, x0, xc], axis=1), np.stack([y0, yc, xc, x1], axis=1),
        np.stack([yc, y1, x0, xc], axis=1), np.stack([yc, y1, xc, x1], axis=1)])
    children = children[(children[:, 1] > children[:, 0]) & (children[:, 3] > children[:, 2])]
    children = children[(children[:, 1] - children[:, 0] > 1) | (children[:, 3] - children[:, 2] > 1)]
    wanted = np.zeros(ny * nx, bool)
    wanted[np.concatenate([y0 * nx + xc, y1 * nx + xc, yc * nx + x0, yc * nx + x1])] = True
    wanted[_tested_numpy(children, nx, edge_size)] = True
    return children, wanted


def _tested_numpy(cells, nx, edge_size):
    y0, y1, x0, x1 = cells.T
    yc, xc = (y0 + y1) // 2, (x0 + x1) // 2
    edged = (np.maximum(y1 - y0, x1 - x0) >= edge_size) if edge_size > 0 else np.zeros(len(cells), bool)
    return np.concatenate([yc * nx + xc, *(p[edged] for p in (y0 * nx + xc, y1 * nx + xc, yc * nx + x0,
                                                              yc * nx + x1))])


@pytest.mark.parametrize("edge_size", [0, 3, 8])
def test_the_compiled_split_gives_the_numpy_children_and_pixels(edge_size):
    """swim.rt.smooth_cpu.split_cells and mark_tested against the NumPy they replaced: the same children in the
    same order (the fill's order) and the same pixels to trace, for cells of every shape from 1 x 2 pixels (which
    split only across, or not at all) to 16 x 9, half of them smooth."""
    from swim.rt.smooth_cpu import mark_tested, split_cells

    ny, nx = 80, 90
    rng = np.random.default_rng(50 + edge_size)
    cells = []
    for h, w in ((1, 2), (2, 1), (2, 2), (2, 3), (3, 3), (4, 4), (5, 8), (8, 8), (16, 9)):
        for _ in range(12):
            y0, x0 = rng.integers(0, ny - h), rng.integers(0, nx - w)
            cells.append((y0, y0 + h, x0, x0 + w))
    cells = np.array(cells, np.int64)
    smooth = rng.random(len(cells)) < 0.5
    expected_children, expected_wanted = _split_cells_numpy(cells, smooth, nx, ny, edge_size)
    wanted = np.zeros(ny * nx, bool)
    children = split_cells(cells, smooth, nx, edge_size, wanted)
    np.testing.assert_array_equal(children, expected_children)
    np.testing.assert_array_equal(wanted, expected_wanted)
    # the cases occur: cells that split into fewer than four children, and children with edge tests
    assert len(children) < 4 * np.count_nonzero(~smooth)
    tested = np.zeros(ny * nx, bool)
    mark_tested(cells, nx, edge_size, tested)
    reference = np.zeros(ny * nx, bool)
    reference[_tested_numpy(cells, nx, edge_size)] = True
    np.testing.assert_array_equal(tested, reference)
    if edge_size:
        assert tested.sum() > len({(y0 + y1) // 2 * nx + (x0 + x1) // 2 for y0, y1, x0, x1 in cells})


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int32, bool])
@pytest.mark.parametrize("channels", [1, 3])
def test_the_compiled_scatter_writes_what_numpy_fancy_assignment_writes(dtype, channels):
    """swim.rt.fill_cpu.scatter_rows against ``image[pixels] = rows``: pixels in any order, the others untouched."""
    from swim.rt.fill_cpu import scatter_rows

    rng = np.random.default_rng(channels)
    image = rng.integers(0, 2, (500, channels)).astype(dtype)
    pixels = rng.choice(500, 137, replace=False).astype(np.int64)
    rows = rng.integers(0, 9, (137, channels)).astype(dtype)
    expected = image.copy()
    expected[pixels] = rows
    scatter_rows(image, pixels, rows)
    np.testing.assert_array_equal(image, expected)


def tent_function(y, x, spacing=8, amplitude=0.004):
    """1 + amplitude * T(y) * T(x), T a tent that is 0 on the lattice's rows (columns) and 1 half way between them:
    bilinear on each quarter of each lattice cell, not on the whole cell. Its centres rise ``amplitude`` above the
    corners' bilinear interpolation, within the default tolerance; its edges' midpoints do not rise at all."""
    def tent(t):
        return 1.0 - np.abs(np.mod(t, spacing) - spacing / 2) / (spacing / 2)

    value = 1.0 + amplitude * tent(y) * tent(x)
    radiance = np.stack([value, 0.8 * value, 0.6 * value], axis=1)
    return radiance, 3.0 * value, np.zeros(y.shape, bool)


@pytest.mark.parametrize("shape", [(33, 33), (41, 57)])
def test_a_cell_that_tested_its_edges_is_interpolated_from_its_traced_centre_and_midpoints(shape):
    """The five pixels that a smooth cell's test traced (centre, edge midpoints) enter its interpolation: each quarter
    is bilinear from its four traced corners, which reproduces a field that is bilinear on each quarter exactly (the
    cell's corners alone are off by ~3/4 of the centre's rise at its neighbours)."""
    sampling = AdaptiveSampling(coarse_spacing=8, edge_test_size=8)
    values, traced = sample_image_adaptive(make_trace(tent_function, shape), np.ones(shape, bool), sampling)
    radiance, tau, _ = exact(tent_function, shape)
    full_cells = (shape[0] - 1) // 8 * 8 + 1, (shape[1] - 1) // 8 * 8 + 1  # the whole 8 x 8 cells
    got = values["radiance"].reshape(*shape, 3)[:full_cells[0], :full_cells[1]]
    np.testing.assert_allclose(got, radiance.reshape(*shape, 3)[:full_cells[0], :full_cells[1]], rtol=1e-13)
    np.testing.assert_allclose(values["tau_hydrometeor"].reshape(shape)[:full_cells[0], :full_cells[1]],
                               tau.reshape(shape)[:full_cells[0], :full_cells[1]], rtol=1e-13)
    # the cells were smooth: only the lattice and the tested pixels traced
    assert set(np.flatnonzero(traced)) == expected_first_pixels(shape, 8, 8)
    # and the corners alone would not do: next to a centre, their bilinear value is off by 0.75 * 0.004
    y, x = np.array([3.0]), np.array([4.0])
    assert abs(tent_function(y, x)[0][0, 0] - 1.0) > 2.9e-3


def test_quarters_of_edged_cells_split_only_the_cells_that_test_their_edges():
    from swim.rt.image_sampling import quarters_of_edged_cells

    cells = np.array([[0, 8, 0, 8],      # tests its edges: four quarters
                      [8, 12, 0, 4],     # smaller than 8: kept
                      [0, 1, 8, 16],     # one pixel high, 8 wide: tests its edges; its quarters 1 x 4 (top ones empty)
                      [16, 24, 8, 10]])  # 8 high, 2 wide: quarters 4 x 1
    out = quarters_of_edged_cells(cells, 8)
    assert {tuple(c) for c in out} == {
        (8, 12, 0, 4),
        (0, 4, 0, 4), (0, 4, 4, 8), (4, 8, 0, 4), (4, 8, 4, 8),
        (0, 1, 8, 12), (0, 1, 12, 16),
        (16, 20, 8, 9), (16, 20, 9, 10), (20, 24, 8, 9), (20, 24, 9, 10)}
    assert out.dtype == np.int64 and out.flags.c_contiguous
    np.testing.assert_array_equal(quarters_of_edged_cells(cells, 0), cells)  # no edge tests: unchanged
    assert quarters_of_edged_cells(np.zeros((0, 4), np.int64), 8).shape == (0, 4)


@pytest.mark.parametrize("shape", [(33, 33), (29, 45)])
def test_a_cell_that_tested_its_centre_alone_is_interpolated_through_it(shape):
    """A smooth cell without edge tests is interpolated from its corners plus a bump through its traced centre (1 at
    the centre, 0 on the edges, bilinear on the quarters the centre makes): a field that rises at the cells' centres
    and is linear along their edges comes out exact; the corners alone miss its rise."""
    def tent_centres(y, x):
        return tent_function(y, x, spacing=4, amplitude=0.004)

    sampling = AdaptiveSampling(coarse_spacing=4, edge_test_size=0)
    values, traced = sample_image_adaptive(make_trace(tent_centres, shape), np.ones(shape, bool), sampling)
    radiance, tau, _ = exact(tent_centres, shape)
    whole = (shape[0] - 1) // 4 * 4 + 1, (shape[1] - 1) // 4 * 4 + 1  # the whole 4 x 4 cells
    np.testing.assert_allclose(values["radiance"].reshape(*shape, 3)[:whole[0], :whole[1]],
                               radiance.reshape(*shape, 3)[:whole[0], :whole[1]], rtol=1e-13)
    np.testing.assert_allclose(values["tau_hydrometeor"].reshape(shape)[:whole[0], :whole[1]],
                               tau.reshape(shape)[:whole[0], :whole[1]], rtol=1e-13)
    assert set(np.flatnonzero(traced)) == expected_first_pixels(shape, 4, 0)  # every cell smooth
    assert abs(tent_centres(np.array([1.0]), np.array([2.0]))[0][0, 0] - 1.0) > 1.9e-3  # off the corners' plane


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_the_compiled_fill_adds_the_bump_through_a_traced_centre(dtype):
    """swim.rt.fill_cpu.fill_cells in a cell whose centre is traced and strictly inside it: the corners' bilinear value
    plus the centre's residual (its value less the corners' value there, both in the values' precision) times the
    bump (ty * tx in float64, rounded once), bit for bit; not in a cell one pixel high, nor where the residual is not
    finite, nor in a cell whose centre is not traced."""
    from swim.rt.fill_cpu import fill_cells

    ny, nx = 14, 20
    rng = np.random.default_rng(11)
    values = rng.uniform(0.1, 3.0, (ny * nx, 2)).astype(dtype)
    cells = np.array([[0, 5, 0, 3],      # 5 x 3: its centre (2, 1)
                      [0, 4, 4, 8],      # 4 x 4: its centre (2, 6)
                      [6, 7, 0, 6],      # one pixel high: its centre (6, 3) on its edge, no bump
                      [6, 10, 8, 12],    # its centre (8, 10) not traced: no bump
                      [10, 13, 12, 19]])  # its centre (11, 15) NaN in the second channel
    traced = np.zeros(ny * nx, bool)
    for y0, y1, x0, x1 in cells:
        traced[[y0 * nx + x0, y0 * nx + x1, y1 * nx + x0, y1 * nx + x1]] = True
    for y, x in ((2, 1), (2, 6), (6, 3), (11, 15)):
        traced[y * nx + x] = True
    values[11 * nx + 15, 1] = np.nan
    valid = np.ones(ny * nx, bool)
    expected = values.copy()
    for y0, y1, x0, x1 in cells:
        h, w = y1 - y0, x1 - x0
        yc, xc = y0 + h // 2, x0 + w // 2
        corners = [y0 * nx + x0, y0 * nx + x1, y1 * nx + x0, y1 * nx + x1]

        def bilinear(wy, wx):
            weights = np.array([(1 - wx) * (1 - wy), wx * (1 - wy), (1 - wx) * wy, wx * wy]).astype(dtype)
            acc = values[corners[0]] * weights[0]
            for c, wc in zip(corners[1:], weights[1:]):
                acc = acc + values[c] * wc
            return acc

        residual = values[yc * nx + xc] - bilinear((yc - y0) / h, (xc - x0) / w)
        centred = h >= 2 and w >= 2 and traced[yc * nx + xc]
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                pix = y * nx + x
                if traced[pix]:
                    continue
                acc = bilinear((y - y0) / h, (x - x0) / w)
                if centred and y0 < y < y1 and x0 < x < x1:
                    ty = (y - y0) / (yc - y0) if y <= yc else (y1 - y) / (y1 - yc)
                    tx = (x - x0) / (xc - x0) if x <= xc else (x1 - x) / (x1 - xc)
                    bump = dtype(ty * tx)
                    acc = np.where(np.isfinite(residual), acc + residual * bump, acc)
                expected[pix] = acc
    before = values.copy()
    fill_cells((values,), cells, traced, valid, nx, 0, ny)
    assert values.tobytes() == expected.tobytes()
    # the comparison covers a bump: inside the 4 x 4 cell the values left the corners' plane
    assert abs(values[1 * nx + 5, 0] - bilinear_at(before, nx, (0, 4, 4, 8), 1, 5, dtype)) > 1e-6


def bilinear_at(values, nx, cell, y, x, dtype):
    """The bilinear interpolation of a cell's corners at pixel (y, x), first channel."""
    y0, y1, x0, x1 = cell
    wy, wx = (y - y0) / (y1 - y0), (x - x0) / (x1 - x0)
    return (values[y0 * nx + x0, 0] * dtype((1 - wx) * (1 - wy)) + values[y0 * nx + x1, 0] * dtype(wx * (1 - wy))
            + values[y1 * nx + x0, 0] * dtype((1 - wx) * wy) + values[y1 * nx + x1, 0] * dtype(wx * wy))
