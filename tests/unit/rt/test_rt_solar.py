"""Step 1a (sun sweep) against analytic optical depths of simple clouds."""

import numpy as np
import pytest

from swim.constants import BACKSCATTER_FRACTION, HYDROMETEOR_DENSITY
from swim.errors import SwimInputError
from swim.frames import enu_from_azimuth_zenith
from swim.io.scene import scene_from_arrays
from swim.optics.volume import build_optical_volume
from swim.rt.solar import (ONE_MINUS_G_PER_BACKSCATTER, solar_transmittance, transmittance_delta_eddington,
                            transmittance_stephens1978)

RADIUS = 10e-6  # effective radius given explicitly so the extinction is known exactly (Eq. 7)


def _slab_scene(lwc=2e-4, base=1000.0, top=2000.0, n=41, spacing=500.0):
    x = (np.arange(n) - n // 2) * spacing
    z = np.arange(0.0, 4000.0, 100.0) + 50.0
    content = np.where((z >= base) & (z <= top), lwc, 0.0)[:, None, None] * np.ones((z.size, n, n))
    scene = scene_from_arrays(x=x, y=x, z=z, reference_lat=40.0, reference_lon=-105.0,
                              cloud_liquid_content=content, cloud_liquid_effective_radius=RADIUS)
    beta = 1.5 * lwc / (RADIUS * HYDROMETEOR_DENSITY["cloud_liquid"])
    return scene, beta


@pytest.mark.parametrize("backend", ["jax", "numba"])
@pytest.mark.parametrize("zenith, azimuth", [(0.0, 0.0), (30.0, 120.0), (60.0, 250.0), (75.0, 45.0)])
def test_slab_optical_depth_below_cloud_is_beta_times_path(zenith, azimuth, backend):
    scene, beta = _slab_scene()
    volume = build_optical_volume(scene, dz=100.0)
    sun = enu_from_azimuth_zenith(azimuth, zenith)
    result = solar_transmittance(volume, sun, backend=backend)
    mu0 = np.cos(np.deg2rad(zenith))
    # The cloud holds 1000 m of constant extinction between the layer mid-points' linear ramps: the
    # resampled profile has the same column integral, so tau below it is beta * 1000 m / mu0.
    column = float(volume["extinction"].sel(species="cloud_liquid").isel(y=20, x=20).sum() * volume.attrs["dz"])
    expected = column / mu0
    tau_ground = float(result["tau_sun"].isel(level=2, y=20, x=20))
    assert column == pytest.approx(beta * 1000.0, rel=0.02)
    assert tau_ground == pytest.approx(expected, rel=0.01)
    # Above the cloud the sun is unobstructed.
    assert float(result["tau_sun"].isel(level=-1, y=20, x=20)) == 0.0
    # b-weighted sum for a pure liquid cloud.
    assert float(result["b_tau_sun"].isel(level=2, y=20, x=20)) == pytest.approx(
        BACKSCATTER_FRACTION["cloud_liquid"] * expected, rel=1e-4)


def test_transmittance_equations_4_to_6():
    b_tau = np.array([0.0, 1.0, 10.0])
    mu0 = 0.5
    t = np.asarray(transmittance_stephens1978(b_tau, mu0))
    t1 = 1 - b_tau / (1 + b_tau)
    t2 = 1 - b_tau * mu0 / (1 + b_tau * mu0)
    np.testing.assert_allclose(t, np.maximum(t1, t2 * mu0), rtol=1e-6)
    assert t[0] == 1.0


# DISORT (32 streams) total transmittance T = (direct + diffuse down) / mu0 of a conservative Henyey-Greenstein
# layer, g = 0.85, over a black surface: {(tau_vertical, mu0): T} (docs/rendering.md, "Overcast accuracy").
DISORT_HG085 = {(1.0, 1.0): 0.9577, (5.0, 1.0): 0.7621, (20.0, 1.0): 0.3828, (50.0, 1.0): 0.1899,
                (5.0, 0.866): 0.7113, (20.0, 0.866): 0.3513, (50.0, 0.866): 0.1742,
                (1.0, 0.5): 0.8351, (5.0, 0.5): 0.5387, (20.0, 0.5): 0.2616, (50.0, 0.5): 0.1297}


@pytest.mark.parametrize("tau_v,mu0", sorted(DISORT_HG085))
def test_delta_eddington_transmittance_against_disort(tau_v, mu0):
    tau_s = tau_v / mu0
    b = BACKSCATTER_FRACTION["cloud_liquid"]
    t = float(transmittance_delta_eddington(tau_s, b * tau_s, mu0))
    assert t == pytest.approx(DISORT_HG085[(tau_v, mu0)], rel=0.06)


def test_delta_eddington_transmittance_limits_and_sun_angle_dependence():
    b = BACKSCATTER_FRACTION["cloud_liquid"]
    tau_s = np.array([0.0, 0.01, 0.1, 1.0, 10.0, 100.0, 1000.0])
    for mu0 in (1.0, 0.866, 0.5, 0.2, 0.01):
        t = np.asarray(transmittance_delta_eddington(tau_s, b * tau_s, mu0))
        assert t[0] == 1.0
        assert np.all(t <= 1.0) and np.all(t > 0.0) and np.all(np.diff(t) < 0)
    # thick layer: T -> (1/2 + 3 mu0/4) / ((3/4)(1 - g) tau_v), with 1 - g = (7/3) b, i.e. Eq. 4's
    # mu0 / (b tau_v) at mu0 = 1/2 and (1/2 + 3 mu0/4) / (7 b tau_v / 4) elsewhere
    tau_v = 1e4
    for mu0 in (1.0, 0.5, 0.2):
        t = float(transmittance_delta_eddington(tau_v / mu0, b * tau_v / mu0, mu0))
        assert t == pytest.approx((0.5 + 0.75 * mu0) / (0.75 * ONE_MINUS_G_PER_BACKSCATTER * b * tau_v), rel=1e-3)
    t_eq4 = float(transmittance_stephens1978(b * tau_v / 0.5, 0.5))
    assert float(transmittance_delta_eddington(tau_v / 0.5, b * tau_v / 0.5, 0.5)) == pytest.approx(t_eq4, rel=1e-3)


def test_solar_transmittance_is_the_delta_eddington_t_of_the_swept_depths():
    scene, _ = _slab_scene()
    volume = build_optical_volume(scene, dz=100.0)
    zenith = 30.0
    result = solar_transmittance(volume, enu_from_azimuth_zenith(200.0, zenith))
    tau = result["tau_sun"].isel(level=2, y=20, x=20).values
    b_tau = result["b_tau_sun"].isel(level=2, y=20, x=20).values
    expected = float(transmittance_delta_eddington(tau, b_tau, np.cos(np.deg2rad(zenith))))
    assert float(result["transmittance"].isel(level=2, y=20, x=20)) == pytest.approx(expected, rel=1e-5)
    assert float(result["transmittance"].isel(level=-1, y=20, x=20)) == 1.0


@pytest.mark.parametrize("backend", ["jax", "numba"])
def test_isolated_cloud_shadow_falls_along_the_sun_direction(backend):
    n, spacing = 41, 250.0
    x = (np.arange(n) - n // 2) * spacing
    z = np.arange(0.0, 4000.0, 100.0) + 50.0
    content = np.zeros((z.size, n, n))
    # A 1 km cube of cloud centred at 2 km above the domain centre.
    cube = (np.abs(z - 2000) <= 500)[:, None, None] & (np.abs(x) <= 500)[None, None, :] & (np.abs(x) <= 500)[None, :, None]
    content[cube] = 5e-4
    scene = scene_from_arrays(x=x, y=x, z=z, reference_lat=10.0, reference_lon=20.0, cloud_liquid_content=content,
                              cloud_liquid_effective_radius=RADIUS)
    volume = build_optical_volume(scene, dz=100.0)
    # Sun in the east at 45 deg zenith: the shadow at the ground lies 2 km west of the cube's foot.
    result = solar_transmittance(volume, enu_from_azimuth_zenith(90.0, 45.0), backend=backend)
    tau = result["tau_sun"].isel(level=0).values
    j_centre = n // 2
    shadow_i = j_centre - int(round(2000 / spacing))
    assert tau[j_centre, shadow_i] > 10.0          # in the shadow
    assert tau[j_centre, j_centre] == 0.0          # under the cube but lit from the east
    assert tau[j_centre, j_centre + 8] == 0.0      # east of the cube
    assert tau[j_centre + 8, shadow_i] == 0.0      # 2 km north of the shadow


@pytest.mark.parametrize("backend", ["jax", "numba"])
def test_terrain_casts_a_shadow(backend):
    n, spacing = 41, 500.0
    x = (np.arange(n) - n // 2) * spacing
    z = np.arange(0.0, 5000.0, 100.0) + 50.0
    # A north-south ridge 1500 m high at x = 0; sun low in the west.
    terrain = np.broadcast_to(1500.0 * np.exp(-(x / 1000.0) ** 2)[None, :], (n, n)).copy()
    scene = scene_from_arrays(x=x, y=x, z=z, reference_lat=45.0, reference_lon=7.0, terrain_height=terrain)
    volume = build_optical_volume(scene, dz=100.0)
    result = solar_transmittance(volume, enu_from_azimuth_zenith(270.0, 70.0), backend=backend)
    shadow = result["terrain_shadow"].values
    level = 1  # 100 m above the bottom
    east_foot = n // 2 + 4   # 2 km east of the ridge: behind it, away from the sun
    west_foot = n // 2 - 4   # facing the sun
    assert shadow[level, n // 2, east_foot] < 0.05
    assert shadow[level, n // 2, west_foot] > 0.95


def _full_and_empty_scenes():
    """A scene with cloud, terrain (a shadow) and a 3-D aerosol, and one with nothing to sweep at all."""
    n, spacing = 21, 500.0
    x = (np.arange(n) - n // 2) * spacing
    z = np.arange(0.0, 4000.0, 100.0) + 50.0
    zz, yy, xx = np.meshgrid(z, x, x, indexing="ij")
    cloud = 4e-4 * (np.abs(zz - 2000) < 400) * (np.abs(xx) < 1500) * (np.abs(yy) < 1500)
    terrain = 900.0 * np.exp(-((x[None, :] + 2000) / 1200.0) ** 2 - (x[:, None] / 3000.0) ** 2)
    aerosol = 2e-4 * np.exp(-zz / 1500.0) * (xx > 0)
    full_scene = scene_from_arrays(x=x, y=x, z=z, reference_lat=45.0, reference_lon=7.0, terrain_height=terrain,
                                   cloud_liquid_content=cloud, cloud_liquid_effective_radius=RADIUS,
                                   aerosol_extinction=aerosol)
    empty_scene = scene_from_arrays(x=x, y=x, z=z, reference_lat=45.0, reference_lon=7.0)
    return full_scene, empty_scene


def test_selected_variables_match_the_full_result_and_unknown_names_are_rejected():
    """A render asks only for the Step 1a fields its kernel reads; they must be those of the full result, for a
    scene with cloud, terrain (a shadow) and a 3-D aerosol, and a scene with nothing to sweep at all."""
    full_scene, empty_scene = _full_and_empty_scenes()
    sun = enu_from_azimuth_zenith(250.0, 55.0)
    wanted = ("cloud_transmittance", "terrain_shadow", "aerosol_tau_sun")
    for scene in (full_scene, empty_scene):
        volume = build_optical_volume(scene, dz=100.0)
        full = solar_transmittance(volume, sun)
        part = solar_transmittance(volume, sun, variables=wanted)
        assert set(part.data_vars) == set(wanted)
        for name in wanted:
            np.testing.assert_array_equal(part[name].values, full[name].values, err_msg=name)
    assert float(full["cloud_transmittance"].min()) == 1.0 and float(full["terrain_shadow"].min()) == 1.0
    volume = build_optical_volume(full_scene, dz=100.0)
    result = solar_transmittance(volume, sun)
    assert float(result["cloud_transmittance"].min()) < 0.5, "the cloud must dim the sun somewhere"
    assert float(result["terrain_shadow"].min()) < 0.05, "the hill must cast a shadow"
    assert float(result["aerosol_tau_sun"].max()) > 0.05, "the aerosol must have an optical depth towards the sun"
    with pytest.raises(SwimInputError, match="unknown variables"):
        solar_transmittance(volume, sun, variables=("cloud_transmittance", "tau"))


@pytest.mark.parametrize("backend", ["jax", "numba"])
@pytest.mark.parametrize("layout", ["contiguous", "channels"])
def test_fields_written_into_given_arrays_are_those_made_anew(backend, layout):
    """``out``: the fields a render reads written into the caller's arrays (contiguous ones, or channels of one
    array as the packed volume's are) equal the ones solar_transmittance makes itself, for a scene with cloud,
    terrain and a 3-D aerosol and one with nothing to sweep (T, the shadow, 1 and the aerosol's depth 0 everywhere),
    T to float32 round-off, the others exactly; the result's variables are the given arrays."""
    full_scene, empty_scene = _full_and_empty_scenes()
    sun = enu_from_azimuth_zenith(250.0, 55.0)
    names = ("aerosol_tau_sun", "cloud_transmittance", "terrain_shadow")
    for scene in (full_scene, empty_scene):
        volume = build_optical_volume(scene, dz=100.0)
        shape = volume["extinction"].shape[1:]
        made = solar_transmittance(volume, sun, variables=names, backend=backend)
        if layout == "channels":
            packed = np.full(shape + (5,), np.nan, np.float32)
            out = {name: packed[..., 1 + c] for c, name in enumerate(names)}
        else:
            out = {name: np.full(shape, np.nan, np.float32) for name in names}
        written = solar_transmittance(volume, sun, variables=names, backend=backend, out=out)
        for name in names:
            assert written[name].values is out[name], name
            assert np.isfinite(out[name]).all(), name
        np.testing.assert_allclose(out["cloud_transmittance"], made["cloud_transmittance"].values, rtol=1e-6, atol=0)
        np.testing.assert_array_equal(out["aerosol_tau_sun"], made["aerosol_tau_sun"].values)
        np.testing.assert_allclose(out["terrain_shadow"], made["terrain_shadow"].values, rtol=1e-6, atol=1e-30)
        if layout == "channels":
            assert np.isnan(packed[..., [0, 4]]).all(), "nothing beyond the given channels"
    assert float(out["cloud_transmittance"].min()) == 1.0 and float(out["aerosol_tau_sun"].max()) == 0.0
    assert float(made["cloud_transmittance"].min()) == 1.0  # (the empty scene's, last)


def test_arrays_to_write_into_are_checked():
    volume = build_optical_volume(_slab_scene(n=9)[0], dz=100.0)
    sun = enu_from_azimuth_zenith(0.0, 30.0)
    shape = volume["extinction"].shape[1:]
    wanted = ("cloud_transmittance", "terrain_shadow")
    good = np.zeros(shape, np.float32)
    with pytest.raises(SwimInputError, match="out names 'tau_sun'"):
        solar_transmittance(volume, sun, variables=wanted + ("tau_sun",), out={"tau_sun": good})
    with pytest.raises(SwimInputError, match="out names 'aerosol_tau_sun'"):  # not asked for
        solar_transmittance(volume, sun, variables=wanted, out={"aerosol_tau_sun": good})
    read_only = np.zeros(shape, np.float32)
    read_only.flags.writeable = False
    for bad in (np.zeros(shape, np.float64), np.zeros(shape[1:], np.float32), read_only, good.tolist()):
        with pytest.raises(SwimInputError, match=r"out\['cloud_transmittance'\] must be a writeable float32 array"):
            solar_transmittance(volume, sun, variables=wanted, out={"cloud_transmittance": bad})


@pytest.mark.parametrize("zenith, azimuth", [(0.0, 0.0), (35.0, 200.0), (68.0, 75.0), (84.0, 310.0)])
def test_cpu_sweep_matches_the_jax_sweep(zenith, azimuth):
    """The numba sweep (swim.rt.solar_cpu) is the JAX sweep's sums in another order: all Step 1a fields must agree
    to float32 round-off, for a scene with broken cloud, terrain and a 3-D aerosol, a high sun, a low one (several
    points per level) and one near the horizon (rays that leave the grid sideways), with the grid not square."""
    rng = np.random.default_rng(7)
    ny, nx = 23, 31
    x, y = (np.arange(nx) - nx // 2) * 400.0, (np.arange(ny) - ny // 2) * 400.0
    z = np.arange(0.0, 6000.0, 150.0) + 75.0
    zz, yy, xx = np.meshgrid(z, y, x, indexing="ij")
    cloud = 5e-4 * rng.random(zz.shape) * (rng.random(zz.shape) > 0.6) * (np.abs(zz - 2500) < 1200)
    ice = 5e-5 * rng.random(zz.shape) * (np.abs(zz - 5000) < 500)
    terrain = 1200.0 * np.exp(-((xx[0] - 2000) / 1500.0) ** 2 - (yy[0] / 2500.0) ** 2)
    aerosol = 3e-4 * np.exp(-zz / 1500.0) * (xx > -1000)
    scene = scene_from_arrays(x=x, y=y, z=z, reference_lat=45.0, reference_lon=7.0, terrain_height=terrain,
                              cloud_liquid_content=cloud, cloud_ice_content=ice, cloud_liquid_effective_radius=RADIUS,
                              aerosol_extinction=aerosol)
    volume = build_optical_volume(scene, dz=150.0)
    sun = enu_from_azimuth_zenith(azimuth, zenith)
    out = {backend: solar_transmittance(volume, sun, backend=backend) for backend in ("jax", "numba")}
    assert float(out["jax"]["tau_sun"].max()) > 5.0 and float(out["jax"]["terrain_shadow"].min()) < 0.5
    for name in out["jax"].data_vars:
        a, b = out["jax"][name].values, out["numba"][name].values
        np.testing.assert_allclose(b, a, rtol=1e-4, atol=1e-5 * max(float(np.abs(a).max()), 1.0), err_msg=name)


def test_unknown_sweep_backend_is_rejected():
    scene, _ = _slab_scene(n=5)
    volume = build_optical_volume(scene, dz=100.0)
    with pytest.raises(SwimInputError, match="backend must be"):
        solar_transmittance(volume, enu_from_azimuth_zenith(0.0, 30.0), backend="opencl")


@pytest.mark.parametrize("packed", [False, True])
def test_species_sums_are_the_extinction_and_its_backscatter_weighted_sum(packed):
    """The sweep's first two fields in one pass (swim.rt.solar_cpu.species_sums): the sum over the species and the
    sum weighted by the backscatter fractions, against NumPy's float64 sums, for the species as separate fields and as
    adjacent channels of a packed volume (strided views, as a render gives them), levels k0:k1 written into strided
    views of the sweep's padded input."""
    from swim.rt.solar_cpu import species_sums

    rng = np.random.default_rng(3)
    n, nk, ny, nx = 5, 9, 6, 7
    values = (rng.random((n, nk, ny, nx)) * (rng.random((n, nk, ny, nx)) > 0.5)).astype(np.float32) * 1e-2
    extinction = np.moveaxis(np.ascontiguousarray(np.moveaxis(values, 0, -1)), -1, 0) if packed else values
    assert np.array_equal(extinction, values) and extinction.flags.c_contiguous != packed
    weights = np.array([BACKSCATTER_FRACTION[s] for s in ("cloud_liquid", "cloud_ice", "rain", "snow", "graupel")],
                       np.float32)
    padded = np.full((2, nk, ny + 1, nx + 1), np.nan, np.float32)
    k0, k1 = 2, 8
    species_sums(extinction, weights, k0, k1, padded[0, :k1 - k0, :ny, :nx], padded[1, :k1 - k0, :ny, :nx])
    expected = (values[:, k0:k1].astype(float).sum(axis=0),
                np.tensordot(weights.astype(float), values[:, k0:k1].astype(float), axes=1))
    for got, want in zip(padded[:, :k1 - k0, :ny, :nx], expected):
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=0)
    assert np.isnan(padded[:, k1 - k0:]).all() and np.isnan(padded[:, :, ny]).all()  # nothing beyond the views
