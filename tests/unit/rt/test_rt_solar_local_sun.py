"""Step 1a with each column's own sun (swim.rt.solar.column_sweep_geometry) on grids that span a noticeable part of
the sphere: a horizontally uniform cloud layer against Beer's law and the delta-Eddington T with the local sun (the
plane-parallel answer), the night side without direct sun, the numba, JAX and device sweeps against each other, and
ordinary grids left on the flat sweep."""

import math

import numpy as np
import pytest
import xarray as xr

from swim.constants import BACKSCATTER_FRACTION, EARTH_RADIUS_M, SPECIES
from swim.rt import solar
from swim.rt.solar import (PER_COLUMN_SUN_TILT_DEG, column_sweep_geometry, column_tilt_deg, per_column_sun,
                           solar_transmittance, sweep_geometry, transmittance_delta_eddington)

DZ = 250.0
BETA = 4e-3  # m-1 of cloud liquid between 2 and 3 km


def _layer_volume(half_width_m, n=41, nk=24, terrain=None):
    """An orthographic grid of n x n columns over +- half_width_m about the reference point with one horizontally
    uniform cloud-liquid layer (levels 2000-3000 m, extinction BETA); its vertical optical depth is the sweep's
    trapezoid sum, BETA x 5 levels x DZ = 5.0."""
    x = np.linspace(-half_width_m, half_width_m, n)
    gx, gy = np.meshgrid(x, x)
    levels = DZ * np.arange(nk)
    extinction = np.zeros((len(SPECIES), nk, n, n), np.float32)
    extinction[0, (levels >= 2000.0) & (levels <= 3000.0)] = BETA
    spacing = x[1] - x[0]
    return xr.Dataset(
        {"extinction": (("species", "level", "y", "x"), extinction),
         "aerosol_extinction": (("level", "y", "x"), np.zeros((nk, n, n), np.float32)),
         "terrain_height": (("y", "x"), np.zeros((n, n)) if terrain is None else terrain),
         "grid_x": (("y", "x"), gx), "grid_y": (("y", "x"), gy)},
        coords={"species": list(SPECIES), "level": levels},
        attrs={"dz": DZ, "affine_matrix": np.array([spacing, 0.0, 0.0, spacing]),
               "affine_origin": np.array([-half_width_m, -half_width_m])})


def _sun(zenith_deg, azimuth_deg):
    z, a = math.radians(zenith_deg), math.radians(azimuth_deg)
    return np.array([math.sin(z) * math.sin(a), math.sin(z) * math.cos(a), math.cos(z)])


def _local_mu0(volume, sun):
    """cos(local solar zenith angle) of each column, from its latitude and longitude's ENU frame (swim.frames)."""
    from swim.frames import enu_basis_ecef, scene_to_geodetic

    gx, gy = volume["grid_x"].values, volume["grid_y"].values
    p = np.stack([gx, gy, np.sqrt(EARTH_RADIUS_M ** 2 - gx ** 2 - gy ** 2)], axis=-1)
    lat, lon, _ = scene_to_geodetic(p, 0.0, 0.0)
    up_ecef = enu_basis_ecef(lat, lon)[..., 2, :]
    sun_ecef = sun @ enu_basis_ecef(0.0, 0.0)  # the scene frame at (0, 0): rows east, north, up
    return up_ecef @ sun_ecef


@pytest.mark.parametrize("zenith, azimuth", [(0.0, 0.0), (30.0, 90.0), (60.0, 200.0), (80.0, 45.0)])
def test_a_uniform_layer_on_a_continental_grid_follows_beers_law_with_the_local_sun(zenith, azimuth):
    """Each column's optical depth towards the sun is tau_v / mu0_local (the plane-parallel slant path), its direct
    beam e^{-tau_v / mu0_local} and its T the delta-Eddington T of mu0_local, within 1 %: the verticals of a 8000 km
    wide grid tilt by up to 63 deg, so the reference sun alone would be wrong by up to a factor 2 and more."""
    volume = _layer_volume(4000e3)
    sun = _sun(zenith, azimuth)
    assert per_column_sun(volume)
    mu = np.maximum(_local_mu0(volume, sun), 1e-3)  # (the night side is not compared)
    result = solar_transmittance(volume, sun, backend="numba")
    direct = solar_transmittance(volume, sun, variables=["cloud_transmittance"], backend="numba",
                                 direct_weights=np.ones(len(SPECIES)))
    tau_v = BETA * 5 * DZ
    # columns with the sun at least 3 deg up, the sweep's rays (< 60 km long in the layer) inside the grid
    inner = (mu > 0.05) & (np.abs(volume["grid_x"].values) < 3800e3) & (np.abs(volume["grid_y"].values) < 3800e3)
    assert inner.sum() > 200
    np.testing.assert_allclose(result["tau_sun"].values[0][inner], (tau_v / mu)[inner], rtol=0.01)
    np.testing.assert_allclose(direct["cloud_transmittance"].values[0][inner], np.exp(-tau_v / mu)[inner],
                               rtol=0.01, atol=1e-30)
    expected_t = transmittance_delta_eddington(tau_v / mu, BACKSCATTER_FRACTION["cloud_liquid"] * tau_v / mu, mu)
    np.testing.assert_allclose(result["cloud_transmittance"].values[0][inner], expected_t[inner], rtol=0.01)
    # above the layer nothing dims the sun
    assert np.all(result["cloud_transmittance"].values[-1] == 1.0)
    # the reference sun's slant path would miss by more than 10 % in many of these columns
    flat = tau_v / max(sun[2], solar.MIN_SUN_ELEVATION_SINE)
    assert np.mean(np.abs(flat / (tau_v / mu[inner]) - 1.0) > 0.1) > 0.3


def test_columns_whose_sun_is_below_the_horizon_get_no_direct_sun():
    """With the sun 70 deg from the reference point's zenith, the columns over 20 deg beyond it towards the anti-sun
    side see it set: their terrain shadow (which cuts the direct beam) is 0 on every level, also written into a
    render's arrays; the sunlit ones keep 1."""
    volume = _layer_volume(4000e3)
    sun = _sun(70.0, 90.0)
    mu = _local_mu0(volume, sun)
    night, day = mu <= 0.0, mu > 0.05
    assert night.sum() > 20 and day.sum() > 200
    result = solar_transmittance(volume, sun, backend="numba")
    shadow = result["terrain_shadow"].values
    assert np.all(shadow[:, night] == 0.0) and np.all(shadow[:, day] == 1.0)
    assert np.all(result["transmittance"].values[:, night] == 0.0)
    shape = volume["extinction"].shape[1:]
    out = {name: np.full(shape, np.nan, np.float32) for name in solar.OUT_VARIABLES}
    solar_transmittance(volume, sun, variables=solar.OUT_VARIABLES, backend="numba", out=out)
    np.testing.assert_array_equal(out["terrain_shadow"], shadow)
    np.testing.assert_allclose(out["cloud_transmittance"], result["cloud_transmittance"].values, rtol=2e-6)
    assert np.all(out["aerosol_tau_sun"] == 0.0)


def test_the_numba_and_jax_sweeps_agree_with_each_columns_sun():
    """Both sweeps take the per-column shifts (numba: solar_cpu._direct_columns; JAX: the shifts broadcast), over a
    cloud field that varies from column to column and terrain that casts shadows."""
    rng = np.random.default_rng(5)
    terrain = rng.uniform(0.0, 1500.0, (41, 41))
    volume = _layer_volume(3000e3, terrain=terrain)
    volume["extinction"].values[0] *= rng.uniform(0.0, 2.0, volume["extinction"].shape[1:]).astype(np.float32)
    sun = _sun(55.0, 300.0)
    numba_result = solar_transmittance(volume, sun, backend="numba")
    jax_result = solar_transmittance(volume, sun, backend="jax")
    for name in ("tau_sun", "b_tau_sun", "terrain_shadow", "cloud_transmittance"):
        # (JAX takes the shifted positions in float32, numba in float64)
        np.testing.assert_allclose(numba_result[name].values, jax_result[name].values, rtol=1e-3, atol=1e-4,
                                   err_msg=name)
    assert numba_result["tau_sun"].values.max() > 5.0 and numba_result["terrain_shadow"].values.min() < 0.5


def test_the_device_refill_takes_each_columns_sun_as_the_host_does():
    """swim.rt.solar_device.refill_step1a_channels (here on JAX's CPU device) gives the host's Step 1a channels on a
    grid with per-column suns, the night side's shadow 0 included."""
    from swim.rt.march_inputs import packed_species, step1a_channel_names
    from swim.rt.solar_device import refill_step1a_channels
    import jax.numpy as jnp

    volume = _layer_volume(4000e3)
    sun = _sun(70.0, 90.0)
    species = packed_species(volume)
    n_species = len(species)
    nk, ny, nx = volume["extinction"].shape[1:]
    device = jnp.zeros((nk, ny, nx, n_species + 2), jnp.float32)
    device = device.at[..., :n_species].set(np.moveaxis(volume["extinction"].values[list(species)], 0, -1))
    sub = volume.isel(species=list(species))
    levels = solar.step1a_levels(sub)
    new, swept, n_levels = refill_step1a_channels(device, sub, sun, n_species, False, levels)
    host = solar_transmittance(sub, sun, variables=["cloud_transmittance", "terrain_shadow"], backend="numba")
    names = step1a_channel_names(False)
    values = np.asarray(new)[..., n_species:]
    for c, name in enumerate(names):
        np.testing.assert_allclose(values[..., c], host[name].values, rtol=2e-5, atol=2e-6, err_msg=name)


def test_ordinary_grids_keep_the_flat_sweep():
    """A grid of 400 km (the WRF Katrina grid's size, whose verticals tilt by 2.74 deg) stays below the tilt threshold,
    so Step 1a is the flat sweep, bit for bit; at its reference column the per-column geometry is the flat one."""
    small = _layer_volume(200e3)
    assert column_tilt_deg(small) == pytest.approx(math.degrees(math.asin(200e3 * math.sqrt(2) / EARTH_RADIUS_M)))
    assert not per_column_sun(small)
    assert per_column_sun(_layer_volume(600e3))  # 7.7 deg at the corners
    assert 2.74 < PER_COLUMN_SUN_TILT_DEG < 7.0
    sun = _sun(40.0, 120.0)
    di, dj, n_sub, path, mu0 = sweep_geometry(small, sun, "test")
    cdi, cdj, c_sub, cpath, cmu0, lit = column_sweep_geometry(small, sun, "test")
    assert lit.all() and c_sub >= n_sub
    np.testing.assert_allclose([cdi[20, 20], cdj[20, 20], cpath[20, 20], cmu0[20, 20]], [di, dj, path, mu0],
                               rtol=1e-6)


def test_the_per_column_kernels_take_no_array_views_in_their_loops():
    """The per-column sweep's kernels read scalars only: no reference count is raised or lowered inside a loop of
    their compiled code (a view's count is an atomic operation shared by the threads,
    docs/decisions/0003-cpu-kernel-code.md); only the accumulator made once per call, before the loops."""
    import re

    import numba
    from test_rt_march_cpu_step import _blocks_in_loops

    from swim.compilation import numba_jit
    from swim.rt import solar_cpu

    f4 = np.zeros((1, 3, 5, 5), np.float32)
    f8 = np.zeros((4, 4))
    counted = re.compile(r"call void @NRT_(?:incref|decref)\(")
    for kernel, args in ((solar_cpu._direct_columns, (f4, np.zeros((3, 1, 5, 5), np.float32), 4, 4, f8, f8, f8, 2,
                                                      16, False, 0, 4)),
                         (solar_cpu._add_above_columns, (np.zeros((3, 1, 5, 5), np.float32), 4, 4, f8, f8, 16, 0, 1))):
        fresh = numba.njit(**{**numba_jit.JIT_KERNEL, "cache": False}, nogil=True)(kernel.py_func)
        fresh(*args)
        ir = fresh.inspect_llvm(fresh.signatures[0])
        name = kernel.py_func.__name__
        body = re.search(r"^define [^\n]*" + name + r"[^\n]*\n(.*?)^}", ir, re.S | re.M)
        assert body is not None
        looped = _blocks_in_loops(body.group(1))
        assert len(looped) > 5, name  # the loops over levels, rows, columns, fields
        assert not [block for block, text in looped.items() if counted.search(text)], name
