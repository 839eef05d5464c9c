"""The cloud-scattering settings (swim.rt.clouds) and the 3-D diffuse field of a render (swim.rt.diffuse_field)."""

import dataclasses
import math

import numpy as np
import pytest

from swim.errors import SwimInputError
from swim.rt.clouds import CLOUD_METHODS, CloudScattering, as_cloud_scattering
from swim.rt.diffuse_field import MAX_NODE_COSINE_CHANGE, DiffuseField, DiffuseSettings, solve_sun, solver_levels
from swim.rt.march_settings import MarchSettings


def test_settings_take_a_method_name_and_hash():
    s = MarchSettings(cloud_scattering="discrete_ordinates")
    assert isinstance(s.cloud_scattering, CloudScattering) and s.cloud_scattering.three_d
    assert MarchSettings().cloud_scattering == s.cloud_scattering  # the default
    assert not MarchSettings(cloud_scattering="albers2020").cloud_scattering.three_d
    a = CloudScattering("discrete_ordinates", {"liquid": ("hg", 0.85)})
    b = CloudScattering("discrete_ordinates", {"liquid": ["hg", 0.85]})
    assert a == b and hash(a) == hash(b)
    assert as_cloud_scattering(a) is a
    assert hash(dataclasses.replace(s, n_grid=64)) != hash(s)  # the settings hash (the kernels are keyed by them)


@pytest.mark.parametrize("bad", ["monte_carlo", 3, CloudScattering])
def test_unknown_methods_are_refused(bad):
    with pytest.raises(SwimInputError):
        MarchSettings(cloud_scattering=bad)


def test_bad_phase_functions_are_refused_when_made():
    with pytest.raises(SwimInputError):
        CloudScattering("discrete_ordinates", {"liquid": ("hg", 2.0)})
    with pytest.raises(SwimInputError):
        CloudScattering("discrete_ordinates", "mie")


def test_diffuse_settings_are_checked():
    for bad in ({"n_azimuth": 6}, {"max_cell_tau": 0.0}, {"tolerance": 2.0}, {"max_degree": 5}):
        with pytest.raises(SwimInputError):
            DiffuseSettings(**bad)
    assert CLOUD_METHODS == ("albers2020", "discrete_ordinates")


def test_solver_levels_split_thick_intervals_and_reach_the_top():
    levels = np.array([0.0, 100.0, 200.0, 300.0])
    edges, first, n_split = solver_levels(levels, np.array([0.1, 1.0, 0.0]), DiffuseSettings(max_cell_tau=0.25),
                                          100e3)
    assert list(n_split) == [1, 4, 1]
    assert list(first) == [0, 1, 5]
    np.testing.assert_allclose(edges[:7], [0, 100, 125, 150, 175, 200, 300])
    assert edges[-1] == pytest.approx(100e3) and np.all(np.diff(edges) > 0)
    assert math.isclose(edges[6], 300.0)


def test_solver_levels_keep_to_their_budget():
    """A convective scene's thick intervals split into thicker cells than max_cell_tau rather than into more levels
    than max_level_factor times the volume's intervals."""
    levels = np.array([0.0, 100.0, 200.0, 300.0])
    _, _, n_split = solver_levels(levels, np.array([10.0, 10.0, 10.0]), DiffuseSettings(max_cell_tau=0.25), 100e3)
    assert n_split.sum() <= 9 and list(n_split) == [3, 3, 3]


def _sun(zenith_deg, azimuth_deg):
    z, a = np.radians(zenith_deg), np.radians(azimuth_deg)
    return np.array([np.sin(z) * np.sin(a), np.sin(z) * np.cos(a), np.cos(z)])


@pytest.mark.parametrize("step", [0.5, 1.0, 2.0])
def test_the_solved_sun_is_the_nearest_node_within_a_step(step):
    rng = np.random.default_rng(3)
    for zenith, azimuth in zip(rng.uniform(0, 75, 400), rng.uniform(-180, 180, 400)):
        sun = _sun(zenith, azimuth)
        node = solve_sun(sun, step)
        assert np.linalg.norm(node) == pytest.approx(1.0)
        assert np.degrees(np.arccos(min(1.0, node @ sun))) <= 0.75 * step  # half a step in zenith and in arc
        assert abs(node[2] / sun[2] - 1) <= MAX_NODE_COSINE_CHANGE
        # a node is its own node, and suns near each other share it: what a series reuses
        np.testing.assert_allclose(solve_sun(node, step), node, atol=1e-12)
    assert np.array_equal(solve_sun(_sun(30.2, 10.0), 1.0), solve_sun(_sun(29.9, 10.3), 1.0))


def test_a_low_sun_and_a_zero_step_are_solved_for_exactly():
    for sun in (_sun(89.5, 10.0), _sun(84.6, 200.0), _sun(90.0, 0.0), _sun(120.0, 0.0)):
        np.testing.assert_array_equal(solve_sun(sun, 1.0), sun)
    sun = _sun(30.3, 135.0)
    np.testing.assert_array_equal(solve_sun(sun, 0.0), sun)
    with pytest.raises(SwimInputError):
        DiffuseSettings(sun_step_deg=-1.0)


def test_a_solution_is_scaled_to_the_render_s_sun_cosine():
    """The moments and the ground's diffuse irradiance scale with the sun's cosine; the ratios to the clear column
    (channels 0-2, the ground's and the air's above) are kept."""
    field = np.arange(2 * 3 * 4 * 30, dtype=np.float32).reshape(2, 3, 4, 30)
    solved = DiffuseField(field=field, ground=np.ones((3, 4, 3), np.float32), coarsen=1, rotation=np.eye(2),
                          max_degree=2, ground_diffuse=np.full((3, 4, 3), 0.2, np.float32), sun=_sun(30.0, 0.0))
    assert solved.for_sun(_sun(30.0, 40.0)) is solved  # the same cosine: nothing to scale
    scaled = solved.for_sun(_sun(30.5, 0.0))
    ratio = np.cos(np.radians(30.5)) / np.cos(np.radians(30.0))
    np.testing.assert_allclose(scaled.field[..., 3:], field[..., 3:] * ratio, rtol=1e-6)
    np.testing.assert_array_equal(scaled.field[..., :3], field[..., :3])
    np.testing.assert_allclose(scaled.ground_diffuse, 0.2 * ratio, rtol=1e-6)
    np.testing.assert_array_equal(scaled.ground, solved.ground)
    np.testing.assert_array_equal(solved.field, field)  # the kept solution is not changed
