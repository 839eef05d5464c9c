"""Frames: analytic invariants of the ray-sphere intersections and the local ENU basis (swim.frames)."""

import numpy as np
import pytest

from swim.frames import enu_basis_ecef, geodetic_to_scene, ray_sphere_intersections

R = 6_371_000.0


@pytest.mark.parametrize("shape", [(), (5,), (2, 3)])
def test_ray_sphere_intersections_from_inside_are_the_chord_ends(shape):
    # from a point at height h above the centre straight up / down, a sphere of radius r is met at r - h ahead and
    # r + h behind (up), or the reverse (down), over several array shapes
    h, r = 1_000.0, R + 100_000.0
    origin = np.broadcast_to([0.0, 0.0, R + h], shape + (3,))
    for sign in (1.0, -1.0):
        direction = np.broadcast_to([0.0, 0.0, sign], shape + (3,))
        near, far = ray_sphere_intersections(origin, direction, r)
        assert near.shape == far.shape == shape
        np.testing.assert_allclose(far, r - sign * (R + h), rtol=1e-12)
        np.testing.assert_allclose(near, -r - sign * (R + h), rtol=1e-12)


def test_ray_sphere_intersections_broadcast_origin_and_misses():
    # one origin for many directions (a camera's rays); a horizontal ray from above the sphere misses it (NaN)
    origin = np.array([0.0, 0.0, R + 10_000.0])
    directions = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    near, far = ray_sphere_intersections(origin, directions, R)
    assert np.isnan(near[1]) and np.isnan(far[1])
    np.testing.assert_allclose(near[2], 10_000.0, rtol=1e-9)  # straight down: the ground 10 km ahead
    np.testing.assert_allclose(far[0], -10_000.0, rtol=1e-9)  # straight up: the sphere is behind
    # a horizontal ray from the ground leaves a shell of height h after sqrt(2 R h + h^2) (the horizon distance)
    h = 10_000.0
    far_horizon = ray_sphere_intersections(np.array([0.0, 0.0, R]), np.array([1.0, 0.0, 0.0]), R + h)[1]
    np.testing.assert_allclose(far_horizon, np.sqrt(2 * R * h + h * h), rtol=1e-9)


@pytest.mark.parametrize("lat, lon", [(0.0, 0.0), (52.5, 13.4), (-33.9, -151.2), (89.0, 170.0)])
def test_enu_basis_of_a_point_is_orthonormal_and_matches_the_array_form(lat, lon):
    basis = enu_basis_ecef(lat, lon)
    np.testing.assert_allclose(basis @ basis.T, np.eye(3), atol=1e-15)
    la, lo = np.deg2rad(lat), np.deg2rad(lon)
    np.testing.assert_allclose(basis[2], [np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)], atol=1e-15)
    assert np.cross(basis[0], basis[1]) @ basis[2] == pytest.approx(1.0)  # right-handed: east x north = up
    # the scalar form (remembered per point) equals a row of the array form
    many = enu_basis_ecef(np.array([lat, 10.0]), np.array([lon, 20.0]))
    np.testing.assert_array_equal(basis, many[0])


def test_enu_basis_of_a_point_is_a_fresh_copy():
    # the remembered basis must not be changed through an array handed to a caller
    first = enu_basis_ecef(12.0, -60.0)
    first[:] = 0.0
    second = enu_basis_ecef(12.0, -60.0)
    assert second.flags.writeable
    np.testing.assert_allclose(second @ second.T, np.eye(3), atol=1e-15)


def test_geodetic_to_scene_of_the_reference_point_is_straight_above_the_origin():
    p = geodetic_to_scene(30.0, -90.0, 2_000.0, 30.0, -90.0)
    np.testing.assert_allclose(p, [0.0, 0.0, R + 2_000.0], atol=1e-6)
