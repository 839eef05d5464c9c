"""A distant view's scene averaged in blocks of columns (swim.geometry.level_of_detail) and the factor a view needs."""

import math

import numpy as np
import pytest

import swim
from swim.errors import SwimInputError
from swim.frames import orthographic_xy
from swim.geometry.level_of_detail import coarsen_scene, coarsening_factor, resolve_coarsening
from swim.io.scene import scene_from_arrays, validate_scene

NY, NX, NZ = 22, 31, 6


def _scene(spacing=3000.0, lat0=38.0, lon0=-97.0, seed=0, terrain_m=150.0):
    """A random scene with every kind of variable: contents with holes (zero cells), radii with NaN where there is
    no content, a land mask, a 3-wavelength albedo."""
    rng = np.random.default_rng(seed)
    x = (np.arange(NX) - NX // 2) * spacing
    y = (np.arange(NY) - NY // 2) * spacing
    z = np.linspace(200.0, 9000.0, NZ)
    shape = (NZ, NY, NX)

    def content():
        return np.where(rng.random(shape) < 0.4, rng.uniform(1e-6, 1e-3, shape), 0.0)

    liquid, ice = content(), content()
    radius = lambda c, lo, hi: np.where(c > 0, rng.uniform(lo, hi, shape), np.nan)  # noqa: E731
    return scene_from_arrays(
        x=x, y=y, z=z, reference_lat=lat0, reference_lon=lon0, terrain_height=rng.uniform(0.0, terrain_m, (NY, NX)),
        cloud_liquid_content=liquid, cloud_liquid_effective_radius=radius(liquid, 4e-6, 20e-6),
        cloud_ice_content=ice, cloud_ice_effective_radius=radius(ice, 20e-6, 80e-6),
        aerosol_extinction=rng.uniform(0.0, 1e-4, shape), land_mask=(rng.random((NY, NX)) < 0.5).astype(np.int8),
        surface_albedo=rng.uniform(0.0, 0.4, (NY, NX)), snow_cover=rng.uniform(0.0, 1.0, (NY, NX)),
        wind_speed_10m=rng.uniform(0.0, 20.0, (NY, NX)), time="2024-07-01T18:00")


def _blocks(a, f):
    """(..., ny, nx) -> (..., ny // f, nx // f, f * f): each block's values (the last rows and columns trimmed)."""
    ny, nx = a.shape[-2] // f * f, a.shape[-1] // f * f
    a = a[..., :ny, :nx].reshape(a.shape[:-2] + (ny // f, f, nx // f, f))
    return np.moveaxis(a, -3, -2).reshape(a.shape[:-4] + (ny // f, nx // f, f * f))


@pytest.mark.parametrize("factor", [2, 3, 5])
def test_coarse_scene_keeps_each_block_s_water_and_mean_extinction_and_validates(factor):
    """With plain means: contents and the aerosol's extinction are the blocks' means (water paths kept); a radius keeps
    the block's mean content / radius (the extinction of Eq. 7, Albers et al. 2020, is proportional to it), NaN where
    the block has no content; the land mask is the majority; the coarse scene validates, its x/y agreeing with its
    lat/lon."""
    scene = _scene()
    coarse = coarsen_scene(scene, factor, method="mean")
    assert dict(coarse.sizes) == {"z": NZ, "y": NY // factor, "x": NX // factor, "wavelength": 3}
    assert coarse.attrs["coarsened_by"] == factor
    for name in ("cloud_liquid_content", "cloud_ice_content", "aerosol_extinction", "height"):
        np.testing.assert_allclose(coarse[name].values, _blocks(scene[name].values, factor).mean(-1), rtol=1e-12,
                                   err_msg=name)
    for species in ("cloud_liquid", "cloud_ice"):
        c, r = scene[f"{species}_content"].values, scene[f"{species}_effective_radius"].values
        per_radius = np.where(c > 0, c / np.where(c > 0, r, 1.0), 0.0)  # extinction / constant, per cell
        coarse_c, coarse_r = coarse[f"{species}_content"].values, coarse[f"{species}_effective_radius"].values
        cloudy = coarse_c > 0
        np.testing.assert_allclose((coarse_c / np.where(cloudy, coarse_r, 1.0))[cloudy],
                                   _blocks(per_radius, factor).mean(-1)[cloudy], rtol=1e-12)
        assert np.all(np.isnan(coarse_r[~cloudy]))
        assert cloudy.any()
    land = _blocks(scene["land_mask"].values.astype(float), factor).mean(-1) >= 0.5
    np.testing.assert_array_equal(coarse["land_mask"].values, land.astype(np.int8))
    valid = validate_scene(coarse)  # x/y against lat/lon within 1 % of the (coarse) spacing, among the rest
    x, y = orthographic_xy(valid["lat"].values, valid["lon"].values, 38.0, -97.0)
    assert np.abs(x - valid["x"].values[None, :]).max() < 0.01 * 3000.0
    assert np.abs(y - valid["y"].values[:, None]).max() < 0.01 * 3000.0


def _two_stream_transmittance(scene):
    """Per column (y, x): 1 / (1 + 0.75 (1 - g) tau), (1 - g) tau = 7/3 sum_s b_s tau_s (Albers et al. 2020, Eqs. 4-8
    and their backscatter fractions), tau_s = sum_k 1.5 c / (r rho) dz_k (Eq. 7) with flat layers: interfaces midway
    between the levels, the lowest on the ground at sea level (the test's flat terrain)."""
    from swim.constants import BACKSCATTER_FRACTION, HYDROMETEOR_DENSITY

    assert np.all(scene["terrain_height"].values == 0.0)
    h = scene["height"].values[:, 0, 0]
    edges = np.concatenate([[0.0], 0.5 * (h[1:] + h[:-1]), [h[-1] + 0.5 * (h[-1] - h[-2])]])
    dz = np.diff(edges)[:, None, None]
    s = 0.0
    for species in ("cloud_liquid", "cloud_ice"):
        c, r = scene[f"{species}_content"].values, scene[f"{species}_effective_radius"].values
        beta = np.where(c > 0, 1.5 * c / (np.where(c > 0, r, 1.0) * HYDROMETEOR_DENSITY[species]), 0.0)
        s = s + BACKSCATTER_FRACTION[species] * (beta * dz).sum(axis=0)
    return 1.0 / (1.0 + 0.75 * (7.0 / 3.0) * s)


@pytest.mark.parametrize("factor", [2, 4])
def test_effective_thickness_keeps_each_block_s_mean_two_stream_transmittance(factor):
    """"effective_thickness" scales each block's mean contents so that the two-stream transmittance of its column is
    the mean of its columns' (Cahalan et al. 1994; Szczap et al. 2000); plain means give a lower one (transmittance is
    convex in optical depth), and a horizontally uniform block is left as the means."""
    scene = _scene(terrain_m=0.0)
    fine_t = _blocks(_two_stream_transmittance(scene), factor).mean(-1)
    coarse = validate_scene(coarsen_scene(scene, factor, method="effective_thickness"))
    np.testing.assert_allclose(_two_stream_transmittance(coarse), fine_t, rtol=1e-9)
    plain = validate_scene(coarsen_scene(scene, factor, method="mean"))
    assert np.all(_two_stream_transmittance(plain) < fine_t - 1e-6)
    ratio = coarse["cloud_liquid_content"].values / np.where(plain["cloud_liquid_content"].values > 0,
                                                            plain["cloud_liquid_content"].values, np.nan)
    assert np.nanmax(ratio) <= 1.0 and np.nanmin(ratio) < 0.9  # the contents scaled down, never up
    uniform = scene.copy()
    for name in ("cloud_liquid_content", "cloud_ice_content"):
        uniform[name] = uniform[name].copy(data=np.broadcast_to(scene[name].values[:, :1, :1], scene[name].shape))
    for name in ("cloud_liquid_effective_radius", "cloud_ice_effective_radius"):
        uniform[name] = uniform[name].copy(data=np.broadcast_to(scene[name].values[:, :1, :1], scene[name].shape))
    a, b = coarsen_scene(uniform, factor, "effective_thickness"), coarsen_scene(uniform, factor, method="mean")
    np.testing.assert_allclose(a["cloud_liquid_content"].values, b["cloud_liquid_content"].values, rtol=1e-12)


@pytest.mark.parametrize("factor", [2, 3, 5])
def test_sampling_keeps_each_block_s_middle_column(factor):
    """The default method keeps the middle column of each block (the same blocks as the means', trimmed), every
    variable as it is; the coarse scene validates."""
    scene = _scene()
    coarse = coarsen_scene(scene, factor)
    assert coarse.attrs["coarsened_with"] == "sample" and coarse.attrs["coarsened_by"] == factor
    rows = np.arange(NY // factor) * factor + factor // 2
    cols = np.arange(NX // factor) * factor + factor // 2
    for name in scene.data_vars:
        np.testing.assert_array_equal(coarse[name].values, scene[name].isel(y=rows, x=cols).values, err_msg=name)
    np.testing.assert_array_equal(coarse["x"].values, scene["x"].values[cols])
    validate_scene(coarse)


@pytest.mark.parametrize("method", ["sample", "effective_thickness", "mean"])
def test_a_lazy_scene_stays_lazy_and_gives_the_eager_scene_s_values(method):
    """Nothing of a lazy scene is computed while it is coarsened (dask's scheduler made to fail), and its values are
    then the eager scene's."""
    dask = pytest.importorskip("dask")  # the scale extra
    da = pytest.importorskip("dask.array")

    scene = _scene()
    lazy = scene.copy()
    for name in ("cloud_liquid_content", "cloud_liquid_effective_radius", "height", "aerosol_extinction"):
        lazy[name] = lazy[name].copy(data=da.from_array(scene[name].values, chunks=(NZ, 8, 8)))

    def no_compute(*args, **kwargs):
        raise AssertionError("a lazy field was computed")

    with dask.config.set(scheduler=no_compute):
        coarse_lazy = coarsen_scene(lazy, 4, method)
    coarse = coarsen_scene(scene, 4, method)
    for name in ("cloud_liquid_content", "cloud_liquid_effective_radius", "height", "aerosol_extinction"):
        assert isinstance(coarse_lazy[name].data, da.Array), name
        np.testing.assert_allclose(coarse_lazy[name].values, coarse[name].values, rtol=1e-12, err_msg=name)


def test_columns_across_the_antimeridian_average_to_it():
    """Blocks of columns on both sides of 180 deg: their longitude is near +-180, not the mean of +179 and -179."""
    coarse = coarsen_scene(_scene(spacing=20000.0, lat0=-10.0, lon0=179.95), 3, "mean")  # a block on both sides
    lon = coarse["lon"].values
    assert np.all(np.abs(np.abs(lon) - 180.0) < 3.0), lon
    validate_scene(coarse)


def test_factors_that_are_not_blocks_are_rejected():
    scene = _scene()
    assert coarsen_scene(scene, 1) is scene
    for bad in (0, -2, 2.5, "2", True):
        with pytest.raises(SwimInputError, match="integer >= 1"):
            coarsen_scene(scene, bad)
    with pytest.raises(SwimInputError, match="method must be one of"):
        coarsen_scene(scene, 2, "median")
    with pytest.raises(SwimInputError, match="at least"):
        coarsen_scene(scene, 12)  # 22 rows: not two blocks
    for bad in ("fine", 0, 1.5):
        with pytest.raises(SwimInputError, match="coarsen must be"):
            resolve_coarsening(bad, scene, "perspective", {"width": 8, "height": 8, "fov_deg": 10.0}, 38.0, -97.0,
                               700e3)
    assert resolve_coarsening(None, scene, "perspective", {}, None, None, 2.0) == 1
    assert resolve_coarsening(3, scene, "allsky", {}, None, None, 2.0) == 3


@pytest.mark.parametrize("height_m, fov_deg, width, spacing, expected", [
    (700e3, 30.0, 64, 1000.0, 5),  # 5.86 km pixels over 1 km columns
    (35786e3, 9.0, 256, 3000.0, 7),  # 22.0 km over 3 km
    (35786e3, 9.0, 2048, 3000.0, 1),  # 2.75 km over 3 km: no block
    (35786e3, 9.0, 64, 3000.0, 11),  # 88 km over 3 km: at most half the grid's 22 rows
])
def test_the_factor_is_the_pixel_footprint_straight_below_over_the_spacing(height_m, fov_deg, width, spacing,
                                                                           expected):
    """A camera straight above the grid's reference column: its nearest column is height_m away, so the blocks are
    floor(height_m x 2 tan(fov / 2) / width / spacing) columns wide (at least 1, at most half the grid)."""
    scene = _scene(spacing=spacing)
    footprint = height_m * 2.0 * math.tan(math.radians(fov_deg) / 2.0) / width
    assert expected == max(1, min(int(footprint // spacing), NY // 2, NX // 2))  # the cases' arithmetic
    got = coarsening_factor(scene, "perspective", {"width": width, "height": width, "fov_deg": fov_deg},
                            38.0, -97.0, height_m)
    assert got == expected
    assert coarsening_factor(scene, "allsky", {"size": 65}, 38.0, -97.0, height_m) == 1
    assert coarsening_factor(scene, "panorama", {"width": 64, "height": 32}, 38.0, -97.0, height_m) == 1


def test_the_factor_of_a_space_view_without_a_field_of_view_uses_the_fitted_one():
    """From space without fov_deg or look_at, render fits the field of view to the grid: the factor follows it (a
    wider grid, a wider view, bigger pixels); with look_at and no fov_deg nothing is known: 1."""
    scene = _scene(spacing=3000.0)
    small = coarsening_factor(scene, "perspective", {"width": 16, "height": 16}, 38.0, -97.0, 35786e3)
    assert small >= 2
    assert coarsening_factor(scene, "perspective", {"width": 16, "height": 16}, 38.0, -97.0, 35786e3,
                             look_at=(38.0, -97.0, 0.0)) == 1


def test_render_coarsens_the_scene_it_is_given():
    """render(coarsen=N) is the render of coarsen_scene(scene, N), and says so; "auto" renders with the factor that
    coarsening_factor chooses (here 4: 2 km pixels over 0.5 km columns); a camera height given as a NumPy scalar is a
    height."""
    scene = swim.default_scene()
    # the paper's cloud scattering: each coarsened grid would otherwise cost a 3-D solve
    view = dict(height=700e3, camera="perspective", camera_options={"width": 24, "height": 24, "fov_deg": 4.0},
                sun_zenith=40.0, sun_azimuth=150.0, settings=swim.MarchSettings(cloud_scattering="albers2020"))
    coarse = swim.render(scene, coarsen=2, **view)
    by_hand = swim.render(coarsen_scene(scene, 2), **view)
    np.testing.assert_array_equal(coarse["radiance"].values, by_hand["radiance"].values)
    assert coarse.attrs["scene_coarsened_by"] == 2 and by_hand.attrs["scene_coarsened_by"] == 2
    full = swim.render(scene, **view)
    assert not np.array_equal(full["radiance"].values, coarse["radiance"].values)
    assert full.attrs["scene_coarsened_by"] == 1
    lat0, lon0 = scene.attrs["reference_lat"], scene.attrs["reference_lon"]
    factor = coarsening_factor(scene, "perspective", view["camera_options"], lat0, lon0, 700e3)
    assert factor == 4
    auto = swim.render(scene, coarsen="auto", **{**view, "height": np.float32(700e3)})
    assert auto.attrs["scene_coarsened_by"] == factor
    np.testing.assert_array_equal(auto["radiance"].values, swim.render(scene, coarsen=factor, **view)["radiance"].values)
    with pytest.raises(SwimInputError, match="coarsen must be"):
        swim.render(scene, coarsen="fine", **view)


def test_the_whole_grid_is_coarsened_before_the_crop(monkeypatch):
    """render coarsens the whole grid, then crops: the crop gets the whole grid's blocks (their middle columns), so the
    columns kept do not depend on the window that the crop takes for a camera or a sun (blocks of 3, which the crop's
    power-of-two windows would not line up with)."""
    from swim import pipeline

    scene = _scene(spacing=20000.0)
    seen = []

    class Stop(Exception):
        pass

    def crop(scene, *args, **kwargs):
        seen.append(scene)
        raise Stop

    monkeypatch.setattr(pipeline.scene_stage, "crop_scene_to_view", crop)
    view = dict(lat=38.0, lon=-97.0, height=2.0, camera="perspective",
                camera_options={"width": 12, "height": 8, "fov_deg": 20.0, "view_azimuth_deg": 60.0,
                                "view_zenith_deg": 80.0})
    for sun in (dict(sun_zenith=40.0, sun_azimuth=150.0), dict(sun_zenith=70.0, sun_azimuth=250.0)):
        with pytest.raises(Stop):
            swim.render(scene, coarsen=3, crop=True, **view, **sun)
    cols, rows = np.arange(NX // 3) * 3 + 1, np.arange(NY // 3) * 3 + 1
    for got in seen:
        np.testing.assert_array_equal(got["x"].values, scene["x"].values[cols])
        np.testing.assert_array_equal(got["y"].values, scene["y"].values[rows])


def test_auto_over_the_grid_and_with_a_time_dimension():
    """A camera over the grid is as far from it as its height, even between the sampled columns; a scene whose lat
    and lon carry a length-1 time dimension (as a lazily opened file may) gets its factor too."""
    scene = _scene(spacing=3000.0)
    wide = {"width": 16, "height": 16, "fov_deg": 170.0}
    assert coarsening_factor(scene, "perspective", wide, 38.0, -97.0, 2.0) == 1
    timed = scene.copy()
    for name in ("lat", "lon"):
        timed[name] = scene[name].expand_dims(time=[np.datetime64("2024-07-01T18:00", "ns")])
    timed = timed.drop_vars("time") if "time" in timed.coords and timed["time"].ndim == 0 else timed
    options = {"width": 64, "height": 64, "fov_deg": 30.0}
    assert coarsening_factor(timed, "perspective", options, 38.0, -97.0, 700e3) == \
        coarsening_factor(scene, "perspective", options, 38.0, -97.0, 700e3) == 1
