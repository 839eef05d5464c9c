"""The ground's radiance (swim.surface.lighting): Eq. 35 limits, slopes, sky view and the water mirror."""

import numpy as np
import pytest

from swim.frames import enu_from_azimuth_zenith
from swim.surface.lighting import facet_normal, surface_radiance
from swim.surface.water import fresnel_reflectance, water_diffuse_albedo


def _one(n, **kw):
    args = dict(up=np.tile([0.0, 0.0, 1.0], (n, 1)), view=np.tile([0.0, 0.0, 1.0], (n, 1)),
                sun=enu_from_azimuth_zenith(180.0, 40.0), slope=np.zeros((n, 2)), albedo=np.full((n, 3), 0.2),
                land_fraction=np.ones(n), snow_cover=np.zeros(n), wind_speed=np.full(n, 5.0),
                direct=np.full((n, 3), 0.8), diffuse=np.full((n, 3), 0.1), model="lambertian")
    args.update(kw)
    return np.asarray(surface_radiance(**args), dtype=float)


@pytest.mark.parametrize("n", [1, 7])
def test_flat_lambertian_ground_is_eq_35(n):
    """L' = 4 a E_H / E_TOA with E_H = mu0 E_dir + E_diff (paper Eq. 35, ARF = 1)."""
    mu0 = np.cos(np.radians(40.0))
    np.testing.assert_allclose(_one(n), 4 * 0.2 * (mu0 * 0.8 + 0.1), rtol=1e-6)


def test_slopes_facing_and_away_from_the_sun():
    """A 30 deg slope facing the sun (south) gets cos(10 deg) of the direct beam, one facing north at 40 + 30 deg
    cos(70 deg); a slope steeper than the sun's elevation and facing away is in its own shadow; the sky-view
    factor (1 + cos 30)/2 scales the diffuse light and the rest comes from the ground around."""
    s = np.tan(np.radians(30.0))
    # gradient dh/dy > 0 (rising northwards) tilts the normal to the south, towards the sun
    slopes = np.array([[0.0, s], [0.0, -s], [0.0, -np.tan(np.radians(60.0))]])
    out = _one(3, slope=slopes, diffuse=np.zeros((3, 3)))
    cos_i = np.array([np.cos(np.radians(10)), np.cos(np.radians(70)), 0.0])
    # plus the light of the sunlit ground around, a E_H through 1 - sky-view factor
    ground = (1 - 0.5 * (1 + np.cos(np.radians([30.0, 30.0, 60.0])))) * 0.2 * np.cos(np.radians(40.0))
    np.testing.assert_allclose(out[:, 0], 4 * 0.2 * 0.8 * (cos_i + ground), rtol=1e-5, atol=1e-7)
    only_diffuse = _one(1, slope=slopes[:1], direct=np.zeros((1, 3)))[0, 0]
    v = 0.5 * (1 + np.cos(np.radians(30.0)))
    assert only_diffuse == pytest.approx(4 * 0.2 * (v * 0.1 + (1 - v) * 0.2 * 0.1), rel=1e-5)


def test_facet_normal_is_unit_and_perpendicular_to_the_slope():
    up = np.tile([0.0, 0.0, 1.0], (2, 1))
    n = np.asarray(facet_normal(up, np.array([[0.5, 0.0], [0.0, 0.0]])))
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, rtol=1e-6)
    np.testing.assert_allclose(n[0] @ np.array([1.0, 0.0, 0.5]), 0.0, atol=1e-6)  # along the surface
    np.testing.assert_allclose(n[1], [0.0, 0.0, 1.0], atol=1e-7)


def test_water_mirrors_the_sky_with_fresnel_and_stays_flat():
    """Sky light on water: L' = 4 rho_F(mu_v) E_diff (+ water-leaving); its cosine-weighted hemispheric mean is
    the bihemispherical 0.067, brighter near the horizon than looking down; coastal slopes are ignored."""
    mus = np.array([1.0, 0.5, 0.15])
    views = np.stack([np.sqrt(1 - mus**2), np.zeros(3), mus], axis=1)
    kw = dict(view=views, land_fraction=np.zeros(3), direct=np.zeros((3, 3)), model="brdf")
    water = _one(3, **kw)
    assert np.all(np.diff(water[:, 1]) > 0)  # brighter towards the horizon
    leaving = water[0, 1] / 0.4 - float(fresnel_reflectance(1.0))
    np.testing.assert_allclose(water[:, 1] / 0.4 - leaving, np.asarray(fresnel_reflectance(mus)), rtol=1e-4)
    x, w = np.polynomial.legendre.leggauss(64)
    mu = 0.5 * (x + 1)
    mean = np.sum(np.asarray(fresnel_reflectance(np.clip(mu, 0.1, 1.0))) * mu * w)  # 2 int rho mu dmu
    assert mean == pytest.approx(water_diffuse_albedo(), rel=0.08)
    tilted = _one(3, slope=np.full((3, 2), 0.3), **kw)
    np.testing.assert_allclose(tilted, water, rtol=1e-6)
