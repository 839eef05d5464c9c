"""The cloud-scattering settings (swim.rt.clouds) and the 3-D diffuse field of a render (swim.rt.diffuse_field)."""

import dataclasses
import math

import numpy as np
import pytest

from swim.errors import SwimInputError
from swim.rt.clouds import CLOUD_METHODS, CloudScattering, as_cloud_scattering
from swim.rt.diffuse_field import DiffuseSettings, solver_levels
from swim.rt.march import MarchSettings


def test_settings_take_a_method_name_and_hash():
    s = MarchSettings(cloud_scattering="discrete_ordinates")
    assert isinstance(s.cloud_scattering, CloudScattering) and s.cloud_scattering.three_d
    assert MarchSettings().cloud_scattering.method == "albers2020"
    assert not MarchSettings().cloud_scattering.three_d
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
