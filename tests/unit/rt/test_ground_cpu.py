"""The numba ground term (:mod:`swim.rt.ground_cpu`) against the JAX one (:func:`swim.surface.lighting.surface_radiance`
and :func:`swim.rt.march_jax._ground_radiance`), which the surface tests hold to the BRDFs' published forms and to
normalisation and reciprocity.

The point function is compared in float64 (JAX with ``jax.enable_x64``) on random geometries that cover every branch:
land, water, coasts and snow, slopes facing towards and away from the sun and the observer (the facet seen edge-on
falls back to the horizontal), a sun below the facet's horizon, the sun glint and the hot spot, and the Lambertian
model. The ray function is compared through the renderer: the numba kernel's pixels against the JAX kernel's."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from swim.compilation import numba_jit
from swim.constants import EARTH_RADIUS_M, SPECIES
from swim.frames import enu_from_azimuth_zenith
from swim.io.scene import scene_from_arrays
from swim.optics.volume import build_optical_volume
from swim.rt import compose_cpu, ground_cpu
from swim.rt.gas import AerosolBackground, aerosol_column_classes, build_gas_tables
from swim.rt.march import _numba_tables
from swim.rt.march_inputs import aerosol_column_optical_depth, kernel_constants
from swim.rt.march_jax import _ground_radiance
from swim.rt.march_settings import ExecutionSettings, MarchSettings
from swim.rt.solar import solar_transmittance
from swim.surface.lighting import MIN_VIEW_COSINE, facet_normal, surface_radiance

from test_rt_march import _trace


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def random_points(rng, n):
    """Inputs of surface_radiance for n ground points: local verticals tilted by the earth's curvature, views and
    suns anywhere above and some below the horizon, slopes up to 45 degrees, every kind of surface."""
    up = _unit(np.column_stack([rng.normal(0, 0.02, n), rng.normal(0, 0.02, n), np.ones(n)]))
    view = _unit(rng.normal(size=(n, 3)) + np.array([0.0, 0.0, 0.6]))
    sun = _unit(rng.normal(size=(n, 3)) + np.array([0.0, 0.0, 0.8]))
    # some views exactly at the sun's mirror image (the glint) and at the sun itself (the hot spot)
    glint = slice(0, n // 10)
    view[glint] = 2 * np.sum(sun[glint] * up[glint], axis=1, keepdims=True) * up[glint] - sun[glint]
    hot = slice(n // 10, n // 5)
    view[hot] = sun[hot]
    slope = rng.uniform(-1.0, 1.0, (n, 2)) * (rng.random((n, 1)) < 0.7)
    land = rng.choice([0.0, 0.0, 0.35, 0.5, 1.0, 1.0, 1.0], n)
    coast = rng.random(n) < 0.1
    land[coast] = rng.uniform(0.0, 1.0, coast.sum())
    snow = rng.choice([0.0, 0.0, 0.4, 1.0], n)
    wind = rng.choice([0.0, 2.0, 7.0, 20.0], n)
    albedo = rng.uniform(0.02, 0.6, (n, 3))
    direct = rng.uniform(0.0, 1.0, (n, 3))
    diffuse = rng.uniform(0.0, 0.3, (n, 3))
    return dict(up=up, view=view, sun=sun, slope=slope, albedo=albedo, land_fraction=land, snow_cover=snow,
                wind_speed=wind, direct=direct, diffuse=diffuse)


def numba_radiance(pts, model):
    g = ground_cpu.ground_tables()
    n = len(pts["up"])
    out = np.empty((n, 3))
    surface_radiance = numba_jit.callable_from_python(ground_cpu.surface_radiance)
    for r in range(n):
        surface_radiance(
            pts["up"][r], pts["view"][r], pts["sun"][r], pts["slope"][r, 0], pts["slope"][r, 1], pts["albedo"][r],
            pts["land_fraction"][r], pts["snow_cover"][r], pts["wind_speed"][r], pts["direct"][r], pts["diffuse"][r],
            model == "lambertian", g["coefficients"], g["rpv_q"], g["snow_table"], g["snow_albedo"], g["subsurface"],
            out[r])
    return out


@pytest.mark.parametrize("model", [pytest.param("brdf", marks=pytest.mark.full), "lambertian"])
def test_the_numba_surface_radiance_is_the_jax_one(model):
    rng = np.random.default_rng(7)
    pts = random_points(rng, 4000)
    with jax.enable_x64(True):
        expected = np.asarray(surface_radiance(**pts, model=model))
    got = numba_radiance(pts, model)
    normal = np.asarray(facet_normal(pts["up"], np.where(pts["land_fraction"][:, None] >= 0.5, pts["slope"], 0.0)))
    facing = np.sum(normal * pts["view"], axis=1)
    # the branches the comparison covers: water and snow, facets seen edge-on and the sun behind the facet
    assert (pts["land_fraction"] == 0).sum() > 500 and (pts["snow_cover"] == 1).sum() > 500
    assert (facing <= MIN_VIEW_COSINE).sum() > 100 and (np.sum(normal * pts["sun"], axis=1) < 0).sum() > 100
    assert np.all(np.isfinite(got)) and got.max() > 1.0  # the glint points are bright
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12)


def _surface_scene(aerosol_plume):
    """A coast: sea in the west (the ground's fields blend the two across the coast's cell), land with a
    snow-capped ridge in the east, a wind field, a cloud of liquid and one of ice (two packed species, whose
    backscatter fractions differ); with a smoke plume, several aerosol column classes."""
    n, spacing = 12, 400.0
    x = (np.arange(n) - n / 2 + 0.5) * spacing
    z = np.arange(0.0, 5000.0, 250.0) + 125.0
    zz, yy, xx = np.meshgrid(z, x, x, indexing="ij")
    liquid = 6e-4 * np.exp(-(((xx - 300) / 900) ** 2 + ((yy + 200) / 700) ** 2 + ((zz - 2500) / 600) ** 2))
    snowfall = 2e-4 * np.exp(-(((xx + 1200) / 700) ** 2 + ((yy - 600) / 700) ** 2 + ((zz - 1200) / 500) ** 2))
    land = (xx[0] > -500.0).astype(float)
    terrain = 900.0 * np.exp(-(((xx[0] - 1500) / 700) ** 2)) * land
    snow = np.clip((terrain - 300.0) / 400.0, 0.0, 1.0)
    wind = 2.0 + 8.0 * (yy[0] - x[0]) / (x[-1] - x[0])
    aerosol = 6e-4 * np.exp(-zz / 1500.0) * np.clip((600.0 - xx) / 1200.0, 0.0, 1.0) if aerosol_plume else None
    return scene_from_arrays(x=x, y=x, z=z, reference_lat=30.0, reference_lon=10.0, terrain_height=terrain,
                             cloud_liquid_content=liquid, snow_content=snowfall, land_mask=land, snow_cover=snow, wind_speed_10m=wind,
                             aerosol_extinction=aerosol)


@pytest.mark.parametrize("surface,plume", [pytest.param("brdf", False, marks=pytest.mark.full),
                                           pytest.param("brdf", True, marks=pytest.mark.full),
                                           pytest.param("lambertian", False, marks=pytest.mark.full)],
                         ids=["brdf", "brdf, five aerosol classes", "lambertian"])  # the JAX programs' compilation: the full tier
def test_the_numba_kernels_ground_is_the_jax_kernels(monkeypatch, surface, plume):
    """Views down from 3 km onto sea, coast, land and snow, from within the grid and beyond its edge (where the
    ground's fields fade to their edge mean), under a cloud and beside it, towards and away from the sun's glint:
    the numba kernel's ground term must give the JAX kernel's pixels to float32 round-off."""
    monkeypatch.setenv("SWIM_NUM_THREADS", "1")
    rng = np.random.default_rng(5)
    n = 700
    dirs = np.array([enu_from_azimuth_zenith(a, z) for a, z in zip(rng.uniform(0, 360, n), rng.uniform(95, 180, n))])
    origins = np.repeat(np.array([[0.0, 0.0, EARTH_RADIUS_M + 3000.0]]), n, axis=0)
    sun = enu_from_azimuth_zenith(250.0, 50.0)
    out = {backend: _trace(_surface_scene(plume), origins, dirs, sun,
                           settings=MarchSettings(surface=surface, execution=ExecutionSettings(backend=backend)))[0]
           for backend in ("jax", "numba")}
    on_ground = out["numba"]["surface"]
    np.testing.assert_array_equal(on_ground, out["jax"]["surface"])
    assert on_ground.sum() > 0.95 * n
    # the views reach beyond the 4.8 km grid and see water, glint and snow
    assert np.nanmax(out["numba"]["distance"]) > 10_000.0
    assert out["numba"]["radiance_surface"].max() > 2 * np.median(out["numba"]["radiance_surface"])
    for key in ("radiance", "radiance_surface"):
        np.testing.assert_allclose(out["numba"][key], out["jax"][key], rtol=2e-4, atol=1e-6, err_msg=key)


def _surface_constants(plume, sun):
    volume = build_optical_volume(_surface_scene(plume))
    profile, classes = None, None
    if plume:
        aer3d = volume["aerosol_extinction"].mean(dim=("y", "x")).values.astype(float)
        profile = (float(volume.attrs["z_bottom"]) + float(volume.attrs["dz"]) * np.arange(aer3d.size), aer3d)
        classes = aerosol_column_classes(aerosol_column_optical_depth(volume).values)
    gas = build_gas_tables(AerosolBackground(), scene_aerosol_profile=profile, aerosol_class_aod=classes)
    return kernel_constants(volume, solar_transmittance(volume, sun), gas, sun)


@pytest.mark.full  # the JAX kernel's programs compile for tens of seconds on an empty cache: the full tier
@pytest.mark.parametrize("surface,plume", [("brdf", True), ("lambertian", False)],
                         ids=["brdf, five aerosol classes", "lambertian"])
def test_the_numba_ground_term_of_rays_is_the_jax_one(surface, plume):
    """ground_radiance against march._ground_radiance in float64 on random ray states: ground points within the grid
    and up to 25 km beyond its edge, views from below, along and across the from-above blend, every species packed in
    a shuffled order (each with its own backscatter fraction), mixed aerosol classes, rays that do not end on the
    ground."""
    rng = np.random.default_rng(9)
    sun = enu_from_azimuth_zenith(250.0, 50.0)
    consts = _surface_constants(plume, sun)
    tables = _numba_tables(consts, prepare=False)
    n = 3000
    start = np.column_stack([rng.uniform(-30e3, 30e3, n), rng.uniform(-30e3, 30e3, n), rng.uniform(0.0, 6000.0, n)])
    direction = _unit(rng.normal(size=(n, 3)) * np.array([1.0, 1.0, 2.0]))
    s_hit = rng.uniform(0.0, 20e3, n)
    surface_mask = rng.random(n) < 0.9
    cos_view_zenith = direction[:, 2].copy()
    cos_view_zenith[:40] = 0.0
    cos_view_zenith[40:80] = -0.1
    cos_view_zenith[80:120] = -0.05
    tau_h = rng.exponential(2.0, n) * (rng.random(n) < 0.7)
    species = rng.permutation(len(SPECIES)).astype(np.int64)
    tau_packed = rng.dirichlet(np.ones(len(SPECIES)), n) * tau_h[:, None]
    tau_species = np.zeros_like(tau_packed)
    tau_species[:, species] = tau_packed
    tau_clear = rng.uniform(0.0, 1.0, (n, 3))
    n_class = tables["n_class"]
    assert n_class == (5 if plume else 1)
    class_lower = rng.integers(0, max(n_class - 1, 1), n).astype(np.int32)
    class_weight = rng.random(n) if n_class > 1 else np.zeros(n)
    with jax.enable_x64(True):
        expected = np.asarray(_ground_radiance(
            start, direction, {"cos_view_zenith": cos_view_zenith}, consts, MarchSettings(surface=surface),
            {"tau_h": tau_h, "tau_clear": tau_clear, "tau_species": tau_species}, (class_lower, class_weight[:, None]),
            surface_mask, s_hit))
    g = ground_cpu.ground_tables()
    got = np.empty((n, 3))
    ground_cpu.ground_radiance(
        start, direction, s_hit, surface_mask, cos_view_zenith, tau_h, tau_clear, tau_packed, species, class_lower,
        class_weight, tables["p"], tables["coef"], tables["sky"], tables["diffuse_classes"], n_class,
        tables["surface"], tables["surface_outside"], tables["angstrom"], tables["backscatter"], surface == "lambertian",
        compose_cpu.COEFFICIENTS, g["coefficients"], g["rpv_q"], g["snow_table"], g["snow_albedo"], g["subsurface"],
        g["fade_cells"], False, got)
    assert np.all(got[~surface_mask] == 0) and np.all(got[surface_mask] > 0)
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-14)
