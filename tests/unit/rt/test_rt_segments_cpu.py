"""The compiled ray segments (swim.rt.segments_cpu) against the NumPy function they replace in trace_rays."""

import numpy as np
import pytest

from swim.constants import EARTH_RADIUS_M
from swim.rt.march import ray_segments, ray_segments_compiled
from swim.rt.march_inputs import GridGeometry

R = EARTH_RADIUS_M


def _geometry(angle_deg=30.0, spacing=2000.0, shape=(40, 80, 100), top=20_000.0, residual=0.3):
    """A grid whose (i, j) axes are rotated by ``angle_deg`` from east and north, so that both rows of the inverse
    affine map mix x and y."""
    a = np.deg2rad(angle_deg)
    matrix = spacing * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return GridGeometry(np.array([-90_000.0, -70_000.0]), matrix, np.linalg.inv(matrix), 0.0, top / (shape[0] - 1),
                        shape, top, residual)


def _rays(n, seed):
    """Rays from the ground, from aircraft, from orbit and from below sea level, inside and outside the grid's
    columns, in random directions, plus rays along the grid's axes (a zero rate of one index) and level rays."""
    rng = np.random.default_rng(seed)
    quarter = n // 4
    heights = np.concatenate([np.full(quarter, 2.0), rng.uniform(0.0, 15_000.0, quarter), np.full(quarter, 700e3),
                              rng.uniform(-3_000.0, 40_000.0, n - 3 * quarter)])
    xy = rng.uniform(-300e3, 300e3, (n, 2))
    origins = np.column_stack([xy, R + heights])
    directions = rng.normal(size=(n, 3))
    directions[: n // 10, 2] = 0.0  # level
    a = np.deg2rad(30.0)
    directions[n // 10: n // 5] = [np.cos(a), np.sin(a), 0.0]  # along the grid's i axis: j's rate is zero
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    return origins, directions


@pytest.mark.parametrize("top", [100_000.0, 60_000.0])
def test_compiled_segments_match_numpy_on_every_kind_of_ray(top):
    geometry = _geometry()
    origins, directions = _rays(20_000, seed=7)
    expected = ray_segments(origins, directions, geometry, top=top)
    got = ray_segments_compiled(origins, directions, geometry, top=top)
    assert set(got) == set(expected)
    for key in ("valid", "ends_on_ground"):
        assert got[key].dtype == np.bool_
        np.testing.assert_array_equal(got[key], expected[key], err_msg=key)
    # the same operations in the same order: equal where NumPy's einsum sums three terms as the kernel does; within
    # round-off near a sphere's tangent otherwise (a few cm of a ray's 1e5-1e6 m)
    for key in ("start", "bounds"):
        np.testing.assert_allclose(got[key], expected[key], rtol=1e-12, atol=0.05, err_msg=key)
    # the cases are all there: rays that miss the atmosphere, end on the sea, cross the grid and miss it
    assert (~got["valid"]).any() and got["ends_on_ground"].any()
    in_grid = got["bounds"][:, 1] > got["bounds"][:, 0]
    assert in_grid.any() and (got["valid"] & ~in_grid).any()


def test_compiled_segments_of_a_ray_straight_up_and_down_through_the_grid():
    geometry = _geometry(angle_deg=0.0, top=10_000.0)
    # above the scene frame's reference point (0, 0, R), where "up" is the frame's z: cell (i, j) = (45, 35)
    np.testing.assert_allclose(geometry.inverse @ -geometry.origin, [45.0, 35.0])
    centre = np.zeros(2)
    origins = np.array([[*centre, R + 2.0], [*centre, R + 800e3]])
    seg = ray_segments_compiled(origins, np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]), geometry)
    np.testing.assert_allclose(seg["bounds"][0], [0.0, 10_000.0 - 2.0, 100e3 - 2.0], atol=1e-6)
    np.testing.assert_allclose(seg["bounds"][1], [100e3 - 10_000.0, 100e3, 100e3], atol=1e-6)
    np.testing.assert_allclose(seg["start"][1], [*centre, 100e3], atol=1e-6)
    assert seg["valid"].all()
    np.testing.assert_array_equal(seg["ends_on_ground"], [False, True])


def test_compiled_segments_take_any_array_layout():
    geometry = _geometry()
    origins, directions = _rays(1000, seed=3)
    expected = ray_segments_compiled(origins, directions, geometry)
    # Fortran-ordered arrays are copied to C order: the results do not depend on the layout
    got = ray_segments_compiled(np.asfortranarray(origins), np.asfortranarray(directions), geometry)
    for key in expected:
        np.testing.assert_array_equal(got[key], expected[key])


def test_segments_in_blocks_on_threads_are_the_segments_of_all_rays(monkeypatch):
    """ray_segments_parallel (trace_rays's and the ray table's): blocks of rays on the pools' threads, put back in
    order, give what one call over all the rays gives, bit for bit."""
    from swim.rt import march

    monkeypatch.setattr(march, "SEGMENT_MIN_BLOCK", 1000)  # 20 000 rays: several blocks on every thread
    monkeypatch.setenv("SWIM_NUM_THREADS", "3")
    geometry = _geometry()
    origins, directions = _rays(20_000, seed=11)
    expected = ray_segments_compiled(origins, directions, geometry, top=80_000.0)
    got = march.ray_segments_parallel(origins, directions, geometry, top=80_000.0)
    assert set(got) == set(expected)
    for key, value in expected.items():
        np.testing.assert_array_equal(got[key], value, err_msg=key)
