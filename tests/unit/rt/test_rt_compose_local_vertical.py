"""The clouds' composition at each ray's own vertical on grids whose columns take their own sun
(:func:`swim.rt.compose_cpu.local_view_geometry`, :func:`swim.rt.compose_cpu.compose_clouds` with one mu0 per ray,
:func:`swim.rt.march.grid_tilt_deg`, :func:`swim.pipeline.arguments.settings_for_sun`;
docs/decisions/0020-per-column-sun.md)."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
import xarray as xr

from swim.constants import EARTH_RADIUS_M
from swim.geometry.sun import sun_from_angles
from swim.pipeline.arguments import settings_for_sun
from swim.rt import compose_cpu
from swim.rt.clouds import CloudScattering
from swim.rt.march import grid_tilt_deg
from swim.rt.march_inputs import GridGeometry
from swim.rt.march_settings import ExecutionSettings, FROM_ABOVE_BLEND, MarchSettings
from swim.rt.solar import PER_COLUMN_SUN_TILT_DEG, column_tilt_deg

R = EARTH_RADIUS_M
#: Distance of the Sun-Earth L1 point from the Earth's centre [m] (about 1.5 million km).
L1_M = 1.5e9


def _states(rng, n, species):
    """Per-ray inputs of the composition, as the numba march gives them (float32 cosines): thin and thick clouds,
    clear rays, views from below and from above, rays outside the camera."""
    tau = np.exp(rng.uniform(np.log(1e-5), np.log(300.0), n))
    tau[rng.random(n) < 0.2] = 0.0
    norm = -np.expm1(-np.minimum(tau, 2.0))
    i_nogas = norm[:, None] * rng.uniform(0.01, 3.0, (n, 3))
    cos_view_zenith = rng.uniform(-1.0, 1.0, n).astype(np.float32)
    cos_view_zenith[:3] = (-FROM_ABOVE_BLEND, 0.0, -1.0)
    return {"tau_h": tau, "tau_packed": tau[:, None] * rng.dirichlet(np.ones(len(species)), n),
            "species": np.asarray(species, np.int64), "i_nogas": i_nogas,
            "i_gas": i_nogas * rng.uniform(0.2, 1.0, (n, 3)), "i_cloud_t": norm * rng.uniform(0.0, 1.2, n),
            "l_clear": rng.uniform(0.0, 0.5, (n, 3)), "l_surface": rng.uniform(0.0, 0.3, (n, 3)).astype(np.float32),
            "valid": rng.random(n) < 0.9, "cos_theta": rng.uniform(-1.0, 1.0, n).astype(np.float32),
            "cos_view_zenith": cos_view_zenith}


def _compose(st, mu0):
    n = st["tau_h"].size
    radiance, cloud = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)
    compose_cpu.compose_clouds(st["tau_h"], st["tau_packed"], st["species"], st["i_nogas"], st["i_gas"],
                               st["i_cloud_t"], st["l_clear"], st["l_surface"], st["valid"], st["cos_theta"],
                               st["cos_view_zenith"], mu0, compose_cpu.G_LIQUID_ARRAY, compose_cpu.BACKSCATTER_ARRAY,
                               compose_cpu.COEFFICIENTS, compose_cpu.LOBES, radiance, cloud)
    return radiance, cloud


@pytest.mark.parametrize("mu0", [0.97, 0.5, 0.03, 0.0, -0.05])
@pytest.mark.parametrize("species", [[0], [0, 1, 2, 3, 4], [1, 3]])
def test_one_mu0_per_ray_of_one_value_gives_the_reference_composition_bit_for_bit(species, mu0):
    st = _states(np.random.default_rng([len(species), int(100 * mu0) + 10]), 300, species)
    radiance, cloud = _compose(st, float(mu0))
    per_ray = _compose(st, np.full(st["tau_h"].size, float(mu0)))
    assert np.array_equal(per_ray[0], radiance) and np.array_equal(per_ray[1], cloud)
    if mu0 > 0:
        assert np.count_nonzero(cloud) > 100  # the comparison is not of zeros


def test_each_ray_takes_its_own_mu0():
    """Rays composed together with one mu0 each give what each gives alone with its mu0 as the scalar."""
    rng = np.random.default_rng(7)
    st = _states(rng, 64, [0, 1])
    mu0 = rng.uniform(-0.1, 1.0, 64)
    radiance, cloud = _compose(st, mu0)
    for r in range(64):
        alone = _compose({key: value[r:r + 1] for key, value in st.items() if key != "species"}
                         | {"species": st["species"]}, float(mu0[r]))
        assert np.array_equal(alone[0][0], radiance[r]) and np.array_equal(alone[1][0], cloud[r])
    # a thick cloud seen from above is brighter under a higher sun (the cloud-top reflection, paper Eqs. 24-26)
    thick = np.ones(2, bool)
    one = {key: np.repeat(value[:1], 2, axis=0) for key, value in st.items() if key != "species"}
    one.update(tau_h=np.full(2, 50.0), tau_packed=np.array([[50.0, 0.0]] * 2), valid=thick, species=st["species"],
               i_nogas=np.full((2, 3), 0.8), i_gas=np.full((2, 3), 0.6), i_cloud_t=np.full(2, 0.4),
               cos_view_zenith=np.full(2, -1.0, np.float32), cos_theta=np.full(2, -0.8, np.float32))
    low_high = _compose(one, np.array([0.2, 0.9]))[1]
    assert np.all(low_high[1] > 2.0 * low_high[0])


def _rotation_y(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rebased(points, rotation):
    """Points given about the Earth's centre, rotated, as the march's rebased start (scene z less R)."""
    out = points @ rotation.T
    out[:, 2] -= R
    return out


@pytest.mark.parametrize("tilt_deg", [40.0, 75.0])
def test_the_local_vertical_turns_with_the_globe(tilt_deg):
    """A cloud seen from L1 at the reference point, the sun 30 deg from its zenith, and the same scene turned about
    the Earth's centre by the tilt (its cloud now far from the reference point): the same cosines of the view and
    sun zenith angles at the ray's own vertical; at the reference point they are the direction's and the sun's z."""
    sun = np.array([math.sin(math.radians(30.0)), 0.0, math.cos(math.radians(30.0))])
    target = np.array([[0.0, 0.0, R + 4000.0], [50e3, -30e3, R + 4000.0]])
    observer = np.array([[1e5, 2e5, L1_M]] * 2)
    direction = (target - observer) / np.linalg.norm(target - observer, axis=1)[:, None]
    cos_view, mu0 = compose_cpu.local_view_geometry(_rebased(observer, np.eye(3)), direction, R, sun)
    assert cos_view.dtype == np.float32 and mu0.dtype == np.float64
    np.testing.assert_allclose(cos_view[0], direction[0, 2], rtol=1e-7)
    np.testing.assert_allclose(mu0[0], sun[2], rtol=1e-12)
    turn = _rotation_y(math.radians(tilt_deg))
    cos_turned, mu0_turned = compose_cpu.local_view_geometry(_rebased(observer, turn), direction @ turn.T, R,
                                                             turn @ sun)
    np.testing.assert_allclose(cos_turned, cos_view, rtol=1e-6)
    np.testing.assert_allclose(mu0_turned, mu0, rtol=1e-9, atol=1e-12)


def test_rays_that_miss_the_cloud_sphere_or_start_inside_it():
    """A ray that passes above the sphere R + 4 km takes the vertical at its closest approach (there it runs
    horizontally: cosine 0), one that starts below it the vertical where it leaves it."""
    sun = np.array([0.0, 0.0, 1.0])
    start = np.array([[-3e6, 0.0, R + 20e3], [0.0, 0.0, R + 100.0]])
    direction = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 1.0]]) / np.array([[1.0], [math.sqrt(2.0)]])
    cos_view, mu0 = compose_cpu.local_view_geometry(_rebased(start, np.eye(3)), direction, R, sun)
    assert abs(cos_view[0]) < 1e-6 and mu0[0] == pytest.approx(1.0, abs=1e-12)
    # leaving R + 4 km from (0, 0, R + 100 m) at 45 deg: s = -b + sqrt(b^2 - c)
    b, c = (R + 100.0) / math.sqrt(2.0), (R + 100.0) ** 2 - (R + 4000.0) ** 2
    s = -b + math.sqrt(b * b - c)
    up = (start[1] + s * direction[1]) / (R + 4000.0)
    assert cos_view[1] == pytest.approx(up @ direction[1], rel=1e-6)
    assert mu0[1] == pytest.approx(up[2], rel=1e-12)


def _geometry(half_width, n=9):
    spacing = 2.0 * half_width / (n - 1)
    matrix = np.diag([spacing, spacing])
    return GridGeometry(np.array([-half_width, -half_width]), matrix, np.linalg.inv(matrix), 0.0, 500.0, (20, n, n),
                        9500.0)


@pytest.mark.parametrize("half_width", [100e3, 220e3, 800e3, 6e6])
def test_grid_tilt_of_the_affine_frame_is_the_columns_tilt(half_width):
    """On a grid regular in orthographic (x, y) the affine frame's corner columns are the grid's: the same tilt as
    Step 1a's :func:`swim.rt.solar.column_tilt_deg`, and the same choice of the per-column treatment."""
    n = 9
    x = np.linspace(-half_width, half_width, n)
    gx, gy = np.meshgrid(x, x)
    volume = xr.Dataset({"grid_x": (("y", "x"), gx), "grid_y": (("y", "x"), gy)})
    tilt = grid_tilt_deg(_geometry(half_width, n))
    assert tilt == pytest.approx(column_tilt_deg(volume), abs=1e-9)
    assert tilt == pytest.approx(math.degrees(math.asin(min(half_width * math.sqrt(2.0) / R, 1.0))), abs=1e-9)
    assert (tilt > PER_COLUMN_SUN_TILT_DEG) == (half_width > 220e3)


def _volume(half_width):
    x = np.linspace(-half_width, half_width, 5)
    gx, gy = np.meshgrid(x, x)
    return xr.Dataset({"grid_x": (("y", "x"), gx), "grid_y": (("y", "x"), gy)})


def test_settings_for_sun_takes_albers2020_on_a_grid_of_per_column_suns(caplog):
    three_d = MarchSettings(cloud_scattering=CloudScattering(method="discrete_ordinates"),
                            execution=ExecutionSettings(backend="numba"))
    sun = sun_from_angles(30.0, 120.0)
    sun_scene = np.asarray(sun.direction_enu, dtype=float)
    with caplog.at_level(logging.INFO, logger="swim.pipeline.arguments"):
        flat = settings_for_sun(three_d, sun, sun_scene, _volume(100e3))
        assert flat is three_d and not caplog.records
        # a regional grid whose columns take their own sun in Step 1a (tilt ~13 deg) keeps the 3-D solution
        assert settings_for_sun(three_d, sun, sun_scene, _volume(1e6)) is three_d and not caplog.records
        wide = settings_for_sun(three_d, sun, sun_scene, _volume(3e6))
    assert wide.cloud_scattering.method == "albers2020"
    assert [r.levelno for r in caplog.records] == [logging.INFO] and "tilt by more than" in caplog.text
    assert settings_for_sun(three_d, sun, sun_scene) is three_d  # no volume: as before


def test_settings_for_sun_warns_that_the_jax_composition_keeps_the_reference_vertical(caplog):
    jax_albers = MarchSettings(cloud_scattering=CloudScattering(method="albers2020"),
                               execution=ExecutionSettings(backend="jax"))
    sun = sun_from_angles(30.0, 120.0)
    with caplog.at_level(logging.INFO, logger="swim.pipeline.arguments"):
        assert settings_for_sun(jax_albers, sun, np.asarray(sun.direction_enu), _volume(100e3)) is jax_albers
        assert not caplog.records
        assert settings_for_sun(jax_albers, sun, np.asarray(sun.direction_enu), _volume(3e6)) is jax_albers
    assert [r.levelno for r in caplog.records] == [logging.WARNING] and "approximate" in caplog.text
