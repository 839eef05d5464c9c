"""Step 1a (sun sweep) against analytic optical depths of simple clouds."""

import numpy as np
import pytest

from swim.constants import BACKSCATTER_FRACTION, HYDROMETEOR_DENSITY
from swim.frames import enu_from_azimuth_zenith
from swim.io.scene import scene_from_arrays
from swim.optics.volume import build_optical_volume
from swim.rt.solar import solar_transmittance, transmittance_stephens1978

RADIUS = 10e-6  # effective radius given explicitly so the extinction is known exactly (Eq. 7)


def _slab_scene(lwc=2e-4, base=1000.0, top=2000.0, n=41, spacing=500.0):
    x = (np.arange(n) - n // 2) * spacing
    z = np.arange(0.0, 4000.0, 100.0) + 50.0
    content = np.where((z >= base) & (z <= top), lwc, 0.0)[:, None, None] * np.ones((z.size, n, n))
    scene = scene_from_arrays(x=x, y=x, z=z, reference_lat=40.0, reference_lon=-105.0,
                              cloud_liquid_content=content, cloud_liquid_effective_radius=RADIUS)
    beta = 1.5 * lwc / (RADIUS * HYDROMETEOR_DENSITY["cloud_liquid"])
    return scene, beta


@pytest.mark.parametrize("zenith, azimuth", [(0.0, 0.0), (30.0, 120.0), (60.0, 250.0), (75.0, 45.0)])
def test_slab_optical_depth_below_cloud_is_beta_times_path(zenith, azimuth):
    scene, beta = _slab_scene()
    volume = build_optical_volume(scene, dz=100.0)
    sun = enu_from_azimuth_zenith(azimuth, zenith)
    result = solar_transmittance(volume, sun)
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


def test_isolated_cloud_shadow_falls_along_the_sun_direction():
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
    result = solar_transmittance(volume, enu_from_azimuth_zenith(90.0, 45.0))
    tau = result["tau_sun"].isel(level=0).values
    j_centre = n // 2
    shadow_i = j_centre - int(round(2000 / spacing))
    assert tau[j_centre, shadow_i] > 10.0          # in the shadow
    assert tau[j_centre, j_centre] == 0.0          # under the cube but lit from the east
    assert tau[j_centre, j_centre + 8] == 0.0      # east of the cube
    assert tau[j_centre + 8, shadow_i] == 0.0      # 2 km north of the shadow


def test_terrain_casts_a_shadow():
    n, spacing = 41, 500.0
    x = (np.arange(n) - n // 2) * spacing
    z = np.arange(0.0, 5000.0, 100.0) + 50.0
    # A north-south ridge 1500 m high at x = 0; sun low in the west.
    terrain = np.broadcast_to(1500.0 * np.exp(-(x / 1000.0) ** 2)[None, :], (n, n)).copy()
    scene = scene_from_arrays(x=x, y=x, z=z, reference_lat=45.0, reference_lon=7.0, terrain_height=terrain)
    volume = build_optical_volume(scene, dz=100.0)
    result = solar_transmittance(volume, enu_from_azimuth_zenith(270.0, 70.0))
    shadow = result["terrain_shadow"].values
    level = 1  # 100 m above the bottom
    east_foot = n // 2 + 4   # 2 km east of the ridge: behind it, away from the sun
    west_foot = n // 2 - 4   # facing the sun
    assert shadow[level, n // 2, east_foot] < 0.05
    assert shadow[level, n // 2, west_foot] > 0.95
