"""Land/snow reflectance and the surface dispatcher (swim.surface.brdf) against analytic invariants.

Directions: ``sun`` and ``view`` point from the surface towards the sun and the observer. Hemispherical
integrals use Gauss-Legendre quadrature in the view zenith angle times a uniform azimuth grid. The published
model formulas are re-implemented here in float64 from the papers, independently of the module.
"""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swim.surface import brdf as br
from swim.surface import water as wt

_STATIC = ("k", "theta_hg", "hot_spot")
jb = SimpleNamespace(
    rpv=jax.jit(br.reflectance_factor_rpv1993, static_argnames=_STATIC),
    snow=jax.jit(br.reflectance_factor_snow_kokhanovsky2004),
    surface=jax.jit(br.surface_reflectance_factor),
    diffuse=jax.jit(br.surface_diffuse_albedo),
    glint=jax.jit(wt.sun_glint_reflectance_factor_cox_munk1954),
    leaving=jax.jit(wt.water_leaving_reflectance),
)
RPV_OTHER = dict(k=0.6, theta_hg=-0.25, hot_spot=0.05)  # a second, more anisotropic parameter set


def vec(zenith_deg, azimuth_deg=0.0):
    """Unit vector (..., 3) from zenith and azimuth angles [deg] (azimuth from +x towards +y)."""
    z, a = np.radians(zenith_deg), np.radians(azimuth_deg)
    return np.stack(np.broadcast_arrays(np.sin(z) * np.cos(a), np.sin(z) * np.sin(a), np.cos(z)), axis=-1)


def dhr(fn, sun_zenith, n_theta=160, n_phi=360):
    """(1/pi) int R(sun, view) mu_v dOmega_v; R may carry trailing axes."""
    x, w = np.polynomial.legendre.leggauss(n_theta)
    th = 0.25 * np.pi * (x + 1.0)
    w_th = 0.25 * np.pi * w
    ph = np.arange(n_phi) * 2 * np.pi / n_phi
    t, p = np.meshgrid(th, ph, indexing="ij")
    view = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)
    r = np.asarray(fn(vec(sun_zenith), view), dtype=float)
    weight = (np.cos(t) * np.sin(t) * w_th[:, None]).reshape(t.shape + (1,) * (r.ndim - 2))
    return np.sum(r * weight, axis=(0, 1)) * (2 * np.pi / n_phi) / np.pi


def rpv_published(sun_zenith, view_zenith, rel_azimuth, k=br.RPV_K, theta=br.RPV_THETA_HG, rho_c=br.RPV_HOT_SPOT):
    """Rahman et al. (1993) Eqs. without rho_0; rel_azimuth = 0 when view and sun share the azimuth [deg]."""
    ti, tv, ph = np.radians(sun_zenith), np.radians(view_zenith), np.radians(rel_azimuth)
    mi, mv = np.cos(ti), np.cos(tv)
    cos_g = mi * mv + np.sin(ti) * np.sin(tv) * np.cos(ph)
    big_g = np.sqrt(np.tan(ti) ** 2 + np.tan(tv) ** 2 - 2 * np.tan(ti) * np.tan(tv) * np.cos(ph))
    return ((mi * mv * (mi + mv)) ** (k - 1) * (1 - theta**2) / (1 + theta**2 + 2 * theta * cos_g) ** 1.5
            * (1 + (1 - rho_c) / (1 + big_g)))


def snow_published(sun_zenith, view_zenith, rel_azimuth, albedo):
    """Kokhanovsky and Breon (2012): R0 a^(K0 K0 / R0); rel_azimuth = 0 when view and sun share the azimuth."""
    ti, tv, ph = np.radians(sun_zenith), np.radians(view_zenith), np.radians(rel_azimuth)
    mi, mv = np.cos(ti), np.cos(tv)
    scat = np.degrees(np.arccos(-(mi * mv + np.sin(ti) * np.sin(tv) * np.cos(ph))))  # 180 = backscatter
    p = 11.1 * np.exp(-0.087 * scat) + 1.1 * np.exp(-0.014 * scat)
    r0 = (1.247 + 1.186 * (mi + mv) + 5.157 * mi * mv + p) / (4 * (mi + mv))
    k0 = lambda mu: 3 / 7 * (1 + 2 * mu)  # noqa: E731
    return r0 * albedo ** (k0(mi) * k0(mv) / r0)


def random_pairs(seed, n, tilt=True):
    rng = np.random.default_rng(seed)
    normal = np.tile([0.0, 0.0, 1.0], (n, 1))
    if tilt:
        normal = normal + 0.4 * rng.normal(size=(n, 3))
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    out = []
    for _ in range(2):
        v = rng.normal(size=(n, 3))
        v /= np.linalg.norm(v, axis=-1, keepdims=True)
        v *= np.sign(np.sum(v * normal, -1))[:, None]  # above the local surface
        out.append(v)
    return out[0], out[1], normal, rng


# ------------------------------------------------------------------------------------------------ Lambertian
def test_lambertian():
    a = np.array([[0.1, 0.2, 0.3], [0.5, 0.6, 0.7]])
    np.testing.assert_array_equal(np.asarray(br.reflectance_factor_lambertian(a)), a)
    f = lambda s, v: np.broadcast_to(br.reflectance_factor_lambertian(0.37), v.shape[:-1])  # noqa: E731
    assert dhr(f, 30.0) == pytest.approx(0.37, rel=1e-6)


# ------------------------------------------------------------------------------------------- energy (DHR)
@pytest.mark.parametrize("sun_zenith", [0.0, 30.0, 60.0, 75.0, 85.0])
def test_rpv_dhr_equals_albedo(sun_zenith):
    albedo = np.array([0.05, 0.3, 0.8])
    f = lambda s, v: jb.rpv(s[..., None, :], v[..., None, :], None, albedo)  # noqa: E731
    np.testing.assert_allclose(dhr(f, sun_zenith), albedo, rtol=0.01)
    g = lambda s, v: jb.rpv(s, v, None, 1.0, **RPV_OTHER)  # noqa: E731
    assert dhr(g, sun_zenith) == pytest.approx(1.0, rel=0.01)


@pytest.mark.parametrize("sun_zenith", [0.0, 30.0, 60.0, 75.0, 85.0])
def test_snow_dhr_equals_albedo(sun_zenith):
    albedo = np.array([0.3, 0.62, 0.8, 0.93, 0.99, 1.0])  # below, between and on the table's albedo nodes
    f = lambda s, v: jb.snow(s[..., None, :], v[..., None, :], None, albedo)  # noqa: E731
    np.testing.assert_allclose(dhr(f, sun_zenith), albedo, rtol=0.01)


@pytest.mark.parametrize("sun_zenith", [0.0, 45.0, 80.0, 89.0])
def test_dhr_at_most_one(sun_zenith):
    for f in (lambda s, v: jb.rpv(s, v, None, 0.99), lambda s, v: jb.rpv(s, v, None, 0.99, **RPV_OTHER),
              lambda s, v: jb.snow(s, v, None, 0.99)):
        assert 0.9 < dhr(f, sun_zenith) <= 1.0


def test_normalisation_changes_the_published_models():
    """The normalisation is not a no-op: the published RPV and snow shapes do not conserve the albedo."""
    def published_dhr(fn, sun_zenith):
        x, w = np.polynomial.legendre.leggauss(160)
        tv = 45 * (x + 1.0)
        ph = np.arange(360) + 0.5
        t, p = np.meshgrid(tv, ph, indexing="ij")
        r = fn(sun_zenith, t, p)
        weight = np.cos(np.radians(t)) * np.sin(np.radians(t)) * (np.pi / 4 * w)[:, None]
        return np.sum(r * weight) * np.radians(1) / np.pi

    rpv = [published_dhr(rpv_published, z) for z in (0.0, 60.0, 85.0)]
    assert rpv[2] / rpv[0] > 1.25  # the k < 1 bowl: +34 % from sun at zenith to 85 deg
    snow = [published_dhr(lambda a, b, c: snow_published(a, b, c, 0.9), z) for z in (0.0, 60.0, 85.0)]
    assert abs(snow[0] - 0.9) > 0.01 and abs(snow[2] - 0.9) > 0.1


# ------------------------------------------------------------------------------------------- reciprocity
def test_reciprocity():
    s, v, n, rng = random_pairs(5, 3000)
    a = rng.uniform(0.0, 1.0, 3000)
    for f in (lambda x, y: jb.rpv(x, y, n, a), lambda x, y: jb.rpv(x, y, n, a, **RPV_OTHER),
              lambda x, y: jb.snow(x, y, n, a), lambda x, y: jb.snow(x, y, n, 0.97)):
        r1, r2 = np.asarray(f(s, v)), np.asarray(f(v, s))
        np.testing.assert_allclose(r1, r2, rtol=2e-5)
        assert np.all(r1 > 0)


def test_normalisation_is_separable():
    """R / published shape = N(mu_i) N(mu_v): the reciprocal (symmetric) normalisation."""
    z = np.array([5.0, 35.0, 60.0, 80.0])
    zi, zv = np.meshgrid(z, z, indexing="ij")
    for model, published in ((lambda s, v: jb.rpv(s, v), rpv_published),
                             (lambda s, v: jb.snow(s, v, None, 0.9), lambda a, b, c: snow_published(a, b, c, 0.9))):
        ratio = np.asarray(model(vec(zi), vec(zv, 90.0)), float) / published(zi, zv, 90.0)
        np.testing.assert_allclose(ratio, ratio.T, rtol=2e-5)
        np.testing.assert_allclose(ratio**2, np.outer(np.diag(ratio), np.diag(ratio)), rtol=5e-5)


# ------------------------------------------------------------------------------------------ angular shape
@pytest.mark.parametrize("sun_zenith, view_zenith", [(0.0, 40.0), (30.0, 30.0), (50.0, 20.0), (70.0, 75.0)])
def test_rpv_azimuthal_shape_matches_published(sun_zenith, view_zenith):
    az = np.linspace(0.0, 180.0, 37)
    for pars in ({}, RPV_OTHER):
        r = np.asarray(jb.rpv(vec(sun_zenith), vec(view_zenith, az), None, 1.0, **pars), float)
        ref = rpv_published(sun_zenith, view_zenith, az, *(pars[p] for p in _STATIC) if pars else ())
        np.testing.assert_allclose(r / r[-1], ref / ref[-1], rtol=2e-5)


@pytest.mark.parametrize("sun_zenith, view_zenith", [(30.0, 30.0), (60.0, 45.0), (75.0, 80.0)])
def test_snow_azimuthal_shape_matches_published(sun_zenith, view_zenith):
    az = np.linspace(0.0, 180.0, 37)
    for a in (0.8, 0.97):
        r = np.asarray(jb.snow(vec(sun_zenith), vec(view_zenith, az), None, a), float)
        ref = snow_published(sun_zenith, view_zenith, az, a)
        np.testing.assert_allclose(r / r[0], ref / ref[0], rtol=5e-5)


@pytest.mark.parametrize("sun_zenith", [20.0, 40.0, 60.0])
def test_rpv_maximum_at_hot_spot(sun_zenith):
    sun = vec(sun_zenith, 30.0)
    for pars in ({}, RPV_OTHER):
        r_hot = float(jb.rpv(sun, sun, None, 1.0, **pars))
        r_spec = float(jb.rpv(sun, wt.specular_direction(sun), None, 1.0, **pars))
        assert r_hot > 1.3 * r_spec
        zen, az = np.meshgrid(np.linspace(0, 75, 151), np.linspace(0, 359, 360), indexing="ij")
        r = np.asarray(jb.rpv(sun, vec(zen, az), None, 1.0, **pars))
        i = np.unravel_index(np.argmax(r), r.shape)
        assert (zen[i], az[i]) == (pytest.approx(sun_zenith, abs=0.5), pytest.approx(30.0, abs=1.0))
        assert r.max() <= r_hot * (1 + 1e-6)
    # the hot-spot factor: at view = sun, G = 0 and 1 + (1 - rho_c)/(1 + G) = 2 - rho_c
    hot = rpv_published(sun_zenith, sun_zenith, 0.0) / rpv_published(sun_zenith, sun_zenith, 0.0, rho_c=1.0)
    assert hot == pytest.approx(2 - br.RPV_HOT_SPOT)


@pytest.mark.parametrize("sun_zenith", [30.0, 50.0, 70.0, 80.0])
def test_snow_maximum_forward(sun_zenith):
    sun = vec(sun_zenith)  # azimuth 0: the forward half has views with azimuth 90..270
    zen, az = np.meshgrid(np.linspace(0, 89.5, 180), np.linspace(0, 358, 180), indexing="ij")
    for a in (0.7, 0.95):
        r = np.asarray(jb.snow(sun, vec(zen, az), None, a))
        i = np.unravel_index(np.argmax(r), r.shape)
        assert 90.0 < az[i] < 270.0
        if sun_zenith >= 50.0:  # forward peak near the specular azimuth and at grazing view
            assert az[i] == pytest.approx(180.0, abs=10.0) and zen[i] > 75.0
            assert r.max() > float(jb.snow(sun, sun, None, a))  # brighter than the backscatter direction


def test_rotation_invariance_with_tilted_normal():
    """Rotating sun, view and normal together leaves R unchanged (the vector interface has no frame)."""
    s, v, _, _ = random_pairs(6, 500, tilt=False)
    c, si = np.cos(0.5), np.sin(0.5)
    rot = np.array([[1, 0, 0], [0, c, -si], [0, si, c]]) @ np.array([[c, 0, si], [0, 1, 0], [-si, 0, c]])
    n = np.array([0.0, 0.0, 1.0])
    for f in (lambda x, y, m: jb.rpv(x, y, m, 0.4), lambda x, y, m: jb.snow(x, y, m, 0.9),
              lambda x, y, m: jb.glint(x, y, m, 4.0)):
        np.testing.assert_allclose(np.asarray(f(s @ rot.T, v @ rot.T, n @ rot.T)), np.asarray(f(s, v, None)),
                                   rtol=2e-4, atol=1e-7)


# ------------------------------------------------------------------------------------- robustness, shapes
def test_float32_jit_random_directions():
    rng = np.random.default_rng(7)
    n = 20_000
    s = rng.normal(size=(n, 3)).astype(np.float32)
    v = rng.normal(size=(n, 3)).astype(np.float32)
    s /= np.linalg.norm(s, axis=-1, keepdims=True)
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    normal = rng.normal(size=(n, 3)) * 0.3 + [0, 0, 1]
    normal = (normal / np.linalg.norm(normal, axis=-1, keepdims=True)).astype(np.float32)
    s[:6] = [[1, 0, 0], [0, 0, 1], [0.6, 0, 0.8], [0.6, 0, 0.8], [1, 0, 0], [0, 0, 1]]
    v[:6] = [[-1, 0, 0], [0, 0, 1], [-0.6, 0, -0.8], [0.6, 0, 0.8], [1, 0, 0], [1, 0, 0]]
    normal[:6] = [0, 0, 1]
    albedo = rng.uniform(0, 1, (n, 3)).astype(np.float32)
    snow = rng.uniform(-0.1, 1.1, n).astype(np.float32)
    land = rng.integers(0, 2, n)
    wind = rng.uniform(0, 20, n).astype(np.float32)
    below = (np.sum(s * normal, -1) <= 0) | (np.sum(v * normal, -1) <= 0)
    outputs = [jb.rpv(s, v, normal, albedo[:, 0]), jb.rpv(s, v, normal, 1.0, **RPV_OTHER),
               jb.snow(s, v, normal, albedo[:, 1]), jb.surface(s, v, normal, albedo, snow, land, wind)]
    for r in outputs:
        r = np.asarray(r)
        assert r.dtype == np.float32
        assert np.all(np.isfinite(r)) and np.all(r >= 0)
        assert np.all(r[below] == 0) and np.any(r[~below] > 0)
    # grazing but visible geometry stays bounded
    grazing = np.asarray(jb.rpv(vec(89.99), vec(89.99, 180.0), None, 1.0))
    assert np.isfinite(grazing) and grazing < 10


# each shape compiles its own JAX programs: the larger ones in the full tier
@pytest.mark.parametrize("shape", [(), pytest.param((7,), marks=pytest.mark.full),
                                   pytest.param((4, 5), marks=pytest.mark.full)])
def test_shapes(shape):
    rng = np.random.default_rng(8)
    sun = np.broadcast_to(vec(40.0), shape + (3,))
    view = vec(rng.uniform(0, 80, shape), rng.uniform(0, 360, shape))
    albedo = rng.uniform(0.05, 0.5, shape + (3,))
    assert jb.rpv(sun, view).shape == shape
    assert jb.rpv(sun, view, None, albedo[..., 0]).shape == shape
    assert jb.snow(sun, view, None, 0.9).shape == shape
    assert jb.rpv(sun[..., None, :], view[..., None, :], None, albedo).shape == shape + (3,)
    fields = np.zeros(shape), np.ones(shape), np.full(shape, 5.0)
    assert jb.surface(sun, view, None, albedo, *fields).shape == shape + (3,)
    assert jb.surface(vec(40.0), view, None, albedo).shape == shape + (3,)  # scalar sun, defaults
    assert jb.diffuse(albedo, 0.5, np.zeros(shape)).shape == shape + (3,)
    assert br.reflectance_factor_rpv1993(jnp.asarray(vec(40.0)), view).shape == shape  # eager, jax input


# ------------------------------------------------------------------------------------------- dispatcher
def test_surface_dispatcher_components():
    s, v, n, rng = random_pairs(9, 200)
    albedo = rng.uniform(0.02, 0.4, (200, 3))
    snow_a = np.array(br.SNOW_ALBEDO)
    rpv = np.asarray(jb.rpv(s[:, None], v[:, None], n[:, None], albedo))
    snow = np.asarray(jb.snow(s[:, None], v[:, None], n[:, None], snow_a))
    glint = np.asarray(jb.glint(s, v, n, 7.0))
    leaving = np.asarray(jb.leaving(s, v, n))
    for cover in (0.0, 0.3, 1.0):
        r = np.asarray(jb.surface(s, v, n, albedo, cover, 1, 7.0))
        np.testing.assert_allclose(r, (1 - cover) * rpv + cover * snow, rtol=1e-5, atol=1e-8)
    r = np.asarray(jb.surface(s, v, n, albedo, 0.8, 0, 7.0))
    np.testing.assert_allclose(r, glint[:, None] + leaving, rtol=1e-5, atol=1e-8)
    mask = np.arange(200) % 2
    r = np.asarray(jb.surface(s, v, n, albedo, 0.0, mask, 7.0))
    np.testing.assert_allclose(r[mask == 1], rpv[mask == 1], rtol=1e-5)
    np.testing.assert_allclose(r[mask == 0], (glint[:, None] + leaving)[mask == 0], rtol=1e-5, atol=1e-8)
    # a fractional land fraction (coasts) blends land and water linearly
    r = np.asarray(jb.surface(s, v, n, albedo, 0.5, 0.25, 7.0))
    np.testing.assert_allclose(r, 0.25 * (0.5 * rpv + 0.5 * snow) + 0.75 * (glint[:, None] + leaving), rtol=1e-5,
                               atol=1e-8)


def test_per_pixel_fields_accept_trailing_channel_axis():
    """snow_cover, land_mask and wind_speed of shape (n,) and (n, 1) give the same result."""
    s, v, n, rng = random_pairs(10, 50)
    albedo = rng.uniform(0.02, 0.4, (50, 3))
    cover, land, wind = rng.uniform(0, 1, 50), rng.uniform(0, 1, 50), rng.uniform(0, 15, 50)
    r1 = np.asarray(jb.surface(s, v, n, albedo, cover, land, wind))
    r2 = np.asarray(jb.surface(s, v, n, albedo, cover[:, None], land[:, None], wind[:, None]))
    assert r1.shape == r2.shape == (50, 3)
    np.testing.assert_allclose(r1, r2, rtol=1e-6)
    d1 = np.asarray(jb.diffuse(albedo, cover, land))
    np.testing.assert_allclose(np.asarray(jb.diffuse(albedo, cover[:, None], land[:, None])), d1, rtol=1e-6)
    assert d1.shape == (50, 3)


@pytest.mark.parametrize("sun_zenith", [10.0, 60.0])
def test_dispatcher_dhr_matches_diffuse_albedo(sun_zenith):
    """Over land the direct-beam R and the diffuse (ARF = 1) albedo carry the same energy."""
    albedo = np.array([0.12, 0.09, 0.05])
    for cover in (0.0, 0.5, 1.0):
        f = lambda s, v: jb.surface(s, v, None, albedo, cover, 1)  # noqa: E731
        np.testing.assert_allclose(dhr(f, sun_zenith), np.asarray(jb.diffuse(albedo, cover, 1)), rtol=0.01)


def test_surface_diffuse_albedo_values():
    albedo = np.array([0.1, 0.2, 0.3])
    np.testing.assert_allclose(np.asarray(jb.diffuse(albedo, 0.25, 1)),
                               0.75 * albedo + 0.25 * np.array(br.SNOW_ALBEDO), rtol=1e-6)
    water = np.asarray(jb.diffuse(albedo, 0.0, 0))
    r_sub = np.array(wt.WATER_SUBSURFACE_REFLECTANCE)
    assert np.all(water > wt.water_diffuse_albedo()) and np.all(water < wt.water_diffuse_albedo() + 0.6 * r_sub)
    assert water[2] > water[1] > water[0]


def test_model_parameters_are_static():
    with pytest.raises(TypeError, match="static"):
        jax.jit(lambda s, v, kk: br.reflectance_factor_rpv1993(s, v, k=kk))(vec(10.0), vec(20.0), 0.7)
    r1 = float(jb.rpv(vec(30.0), vec(30.0), None, 1.0, k=0.7))
    r2 = float(jb.rpv(vec(30.0), vec(30.0), None, 1.0, k=0.9))
    assert r1 != r2
