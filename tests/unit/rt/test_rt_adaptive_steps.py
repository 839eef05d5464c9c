"""Empty-space skipping: the occupancy grid and the adaptive step edges of the grid segment."""

import numpy as np
import jax.numpy as jnp
import pytest

from swim.compilation import numba_jit
from swim.constants import EARTH_RADIUS_M
from swim.io.scene import scene_from_arrays
from swim.optics.volume import build_optical_volume
from swim.rt.gas import AerosolBackground, build_gas_tables
from swim.rt.march import ray_segments
from swim.rt.march_inputs import grid_geometry, kernel_constants, occupancy_grid, step_classes
from swim.rt.march_jax import adaptive_step_edges, grid_step_edges, probe_counts_and_cells
from swim.rt.march_settings import (EMPTY_CELLS_PER_STEP, EMPTY_STEP_WEIGHT, SUNLIT_CELLS_PER_STEP, SUNLIT_CLEAR,
                                    MarchSettings)
from swim.rt.solar import solar_transmittance


def _scene(terrain_peak=0.0, aerosol=False, cloud=True):
    n, spacing = 16, 500.0
    x = (np.arange(n) - n / 2 + 0.5) * spacing
    z = np.arange(0.0, 8000.0, 250.0) + 125.0
    zz, yy, xx = np.meshgrid(z, x, x, indexing="ij")
    # one cloud slab between 3 and 4 km over the whole domain
    liquid = np.where((zz > 3000) & (zz < 4000) & cloud, 3e-4, 0.0)
    terrain = terrain_peak * np.exp(-((xx[0] / 1500) ** 2 + (yy[0] / 1500) ** 2))
    aer = 2e-4 * (xx > 0) * np.exp(-zz / 1500.0) if aerosol else None
    return scene_from_arrays(x=x, y=x, z=z, reference_lat=40.0, reference_lon=-100.0, terrain_height=terrain,
                             cloud_liquid_content=liquid, land_mask=1.0, aerosol_extinction=aer)


@pytest.mark.parametrize("numba", [True, False], ids=["compiled", "numpy"])
@pytest.mark.parametrize("shape", [(1,), (7,), (1, 1, 1), (2, 3, 1), (1, 1, 4), (3, 2, 2), (5, 1, 9), (6, 7, 8),
                                   (40, 33, 17), (3, 4, 5, 2), (3, 4, 0), (0, 5, 5), (3, 0, 4)])
def test_dilation_by_one_cell_is_scipys_maximum_filter(shape, numba, monkeypatch):
    """Both ways (a grid's compiled passes, swim.rt.occupancy_cpu.dilate_cells, and NumPy's shifted ors) give scipy's
    3 x 3 x ... maximum filter, at the grid's edges and along axes of one or two cells too."""
    from scipy.ndimage import maximum_filter

    import swim.rt.march_inputs as march_inputs
    from swim.rt.march_inputs import dilated_by_one_cell

    if not numba:
        monkeypatch.setattr(march_inputs, "_numba_available", lambda: False)
    rng = np.random.default_rng(len(shape) * 10 + shape[0])
    for density in (0.0, 0.03, 0.3, 1.0):
        mask = rng.random(shape) < density
        if mask.ndim == 3 and mask.shape[1] > 1:  # a view that is not contiguous, as a crop's
            mask = np.asfortranarray(mask)
        got = dilated_by_one_cell(mask)
        assert got.dtype == bool and got.shape == mask.shape
        np.testing.assert_array_equal(got, maximum_filter(mask.astype(np.int8), size=3).astype(bool))
        assert not np.shares_memory(got, mask)


def test_occupancy_marks_cloud_dilated_by_one_level_and_nothing_else():
    volume = build_optical_volume(_scene())
    occupancy = occupancy_grid(volume)
    cloudy = volume["extinction"].sum("species").values > 0
    levels = volume["level"].values
    assert occupancy.shape == cloudy.shape and occupancy.dtype == np.int8
    assert np.all(occupancy[cloudy] == 1)
    occupied_levels = levels[occupancy.any(axis=(1, 2))]
    cloud_levels = levels[cloudy.any(axis=(1, 2))]
    dz = float(volume.attrs["dz"])
    # flat sea-level terrain and no 3-D aerosol: only the cloud, widened by one level up and down
    assert occupied_levels.min() == cloud_levels.min() - dz and occupied_levels.max() == cloud_levels.max() + dz


@pytest.mark.parametrize("shared", [False, True], ids=["own extinction", "packed channels"])
def test_occupancy_is_the_float32_species_sum_and_the_raised_terrain_dilated(shared):
    """The compiled occupancy (swim.rt.occupancy_cpu, level blocks on every core) marks what the NumPy formula
    marks: the species' sum above OCCUPIED_EXTINCTION, or a level at most dz above the highest terrain of
    the 3 x 3 columns around (where it is raised above 1 m), dilated by one cell; for a volume's own contiguous
    extinction and for its views of the packed volume's channels. Patchy cloud of two species, many cells within
    a factor of 2 of the threshold, so that a wrong sum or a wrong species is seen."""
    from scipy.ndimage import maximum_filter

    from swim.rt.march_inputs import (OCCUPIED_EXTINCTION, dilated_by_one_cell, pack_volume, packed_species,
                                      share_packed_channels)

    scene = _scene(terrain_peak=1200.0)
    rng = np.random.default_rng(5)
    shape = scene["cloud_liquid_content"].shape
    # contents whose extinction straddles the threshold (liquid ~1.5e-3 m-1 per 1e-6 kg m-3 at 10 um radius)
    for name in ("cloud_liquid_content", "snow_content"):
        scene[name] = (scene["cloud_liquid_content"].dims, np.where(rng.random(shape) < 0.3,
                                                                    10 ** rng.uniform(-10, -7, shape), 0.0))
    volume = build_optical_volume(scene)
    if shared:
        species = packed_species(volume)
        share_packed_channels(volume, pack_volume(volume, species), species)
    extinction = volume["extinction"].values
    assert volume["extinction"].shape[0] == (2 if shared else 5)
    total = extinction.astype(np.float64).sum(axis=0)  # (float32 round-off moves no cell of this scene)
    near = (total > OCCUPIED_EXTINCTION / 2) & (total < 2 * OCCUPIED_EXTINCTION)
    assert near.sum() > 100, "the test needs cells near the threshold"
    top = maximum_filter(volume["terrain_height"].values, size=3)
    terrain = (volume["level"].values[:, None, None] <= top[None] + float(volume.attrs["dz"])) & (top[None] > 1.0)
    assert terrain.any() and not terrain.all()
    expected = dilated_by_one_cell((total > OCCUPIED_EXTINCTION) | terrain)
    got = occupancy_grid(volume)
    assert got.dtype == np.int8 and not got.flags.writeable
    np.testing.assert_array_equal(got.view(bool), expected)


def test_occupancy_marks_raised_terrain_and_aerosol_edges():
    volume = build_optical_volume(_scene(terrain_peak=1000.0, aerosol=True))
    occupancy = occupancy_grid(volume)
    levels = volume["level"].values
    terrain = volume["terrain_height"].values
    jj, ii = np.unravel_index(np.argmax(terrain), terrain.shape)
    k_ground = np.searchsorted(levels, terrain[jj, ii])
    assert occupancy[k_ground, jj, ii] == 1, "cells at the peak's ground must be occupied"
    # at 2 km, well above the 1 km peak: the plume's edge at x = 0 is occupied, its smooth parts are not
    k_mid = np.searchsorted(levels, 2000.0)
    row = occupancy[k_mid, 0]
    assert row.max() == 1 and row.min() == 0


@pytest.mark.full  # the JAX kernel's step placement (its numba twin is held to it in the full tier too)
def test_adaptive_edges_span_the_segment_and_concentrate_in_the_cloud():
    scene = _scene()
    volume = build_optical_volume(scene)
    sun = np.array([0.0, 0.0, 1.0])
    gas = build_gas_tables(AerosolBackground())
    consts = kernel_constants(volume, solar_transmittance(volume, sun), gas, sun)
    origins = np.array([[0.0, 0.0, EARTH_RADIUS_M + 10.0]] * 2)
    dirs = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    seg = ray_segments(origins, dirs, grid_geometry(volume), top=float(consts["top"]))
    start = jnp.asarray(seg["start"], jnp.float32)
    bounds = jnp.asarray(seg["bounds"], jnp.float32)
    n_steps = 64
    edges = np.asarray(adaptive_step_edges(start, jnp.asarray(dirs, jnp.float32), bounds[:, 0],
                                           bounds[:, 1] - bounds[:, 0], n_steps, consts))
    assert edges.shape == (n_steps + 1, 2)
    np.testing.assert_allclose(edges[0], seg["bounds"][:, 0], atol=1e-3)
    np.testing.assert_allclose(edges[-1], seg["bounds"][:, 1], rtol=1e-6)
    assert np.all(np.diff(edges, axis=0) >= 0)
    # vertical ray: steps inside the cloud slab (3-4 km) are shorter than those in clear air by ~1/EMPTY_STEP_WEIGHT
    mid = 0.5 * (edges[1:, 0] + edges[:-1, 0])
    ds = np.diff(edges[:, 0])
    in_cloud = (mid > 3100) & (mid < 3900)
    clear = (mid < 2000) | (mid > 5500)
    uniform = n_steps * 800.0 / seg["bounds"][0, 1]  # steps a uniform march puts between 3.1 and 3.9 km
    assert in_cloud.sum() > 2.5 * uniform, "the cloud must get several times the steps of a uniform march"
    ratio = np.median(ds[clear]) / np.median(ds[in_cloud])
    assert 0.7 / EMPTY_STEP_WEIGHT < ratio < 1.3 / EMPTY_STEP_WEIGHT


def _rays(scene, dirs, heights=None):
    volume = build_optical_volume(scene)
    sun = np.array([0.0, 0.0, 1.0])
    consts = kernel_constants(volume, solar_transmittance(volume, sun), build_gas_tables(AerosolBackground()), sun)
    heights = np.full(len(dirs), 10.0) if heights is None else np.asarray(heights, float)
    origins = np.stack([np.zeros(len(dirs)), np.zeros(len(dirs)), EARTH_RADIUS_M + heights], axis=1)
    seg = ray_segments(origins, np.asarray(dirs, float), grid_geometry(volume), top=float(consts["top"]))
    start, direction = jnp.asarray(seg["start"], jnp.float32), jnp.asarray(dirs, jnp.float32)
    bounds = jnp.asarray(seg["bounds"], jnp.float32)
    return consts, (start, direction, bounds[:, 0], bounds[:, 1] - bounds[:, 0])


@pytest.mark.full  # the JAX kernel's step placement (its numba twin is held to it in the full tier too)
def test_empty_steps_thin_out_the_steps_in_empty_space():
    """grid_step_edges: a ray through an empty grid takes max(empty_steps, cells / EMPTY_CELLS_PER_STEP) equal steps;
    a ray through the cloud slab keeps the step length of adaptive_step_edges inside the cloud and takes that
    many steps in empty space, fewer in all."""
    n_steps = 64
    dirs = [[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]]
    consts, args = _rays(_scene(cloud=False), dirs)
    cells = np.asarray(probe_counts_and_cells(*args, consts)[1])
    assert 28 < cells[0] < 33, "a vertical ray from 10 m crosses the grid's 32 levels"
    for empty_steps in (4, 24):
        edges, steps = (np.asarray(a) for a in grid_step_edges(*args, n_steps, consts, empty_steps=empty_steps))
        expected = np.ceil(np.maximum(empty_steps, cells / EMPTY_CELLS_PER_STEP))
        np.testing.assert_array_equal(steps, expected)
        for r, count in enumerate(steps):
            ds = np.diff(edges[: count + 1, r])
            np.testing.assert_allclose(ds, ds.mean(), rtol=1e-3)  # equal steps: nothing to concentrate them on
            np.testing.assert_allclose(edges[count:, r], float(args[2][r] + args[3][r]), rtol=1e-6)

    consts, args = _rays(_scene(), dirs)
    full = np.asarray(adaptive_step_edges(*args, n_steps, consts))
    edges, steps = (np.asarray(a) for a in grid_step_edges(*args, n_steps, consts, empty_steps=8))
    assert np.all(steps < n_steps)
    for r, count in enumerate(steps):
        ray = edges[: count + 1, r]
        assert np.all(np.diff(ray) > 0)
        np.testing.assert_allclose([ray[0], ray[-1]], [full[0, r], full[-1, r]], rtol=1e-6, atol=1e-3)
        mid, ds = 0.5 * (ray[1:] + ray[:-1]) * dirs[r][2], np.diff(ray)
        mid_full, ds_full = 0.5 * (full[1:, r] + full[:-1, r]) * dirs[r][2], np.diff(full[:, r])
        in_cloud, in_cloud_full = (mid > 3100) & (mid < 3900), (mid_full > 3100) & (mid_full < 3900)
        np.testing.assert_allclose(np.median(ds[in_cloud]), np.median(ds_full[in_cloud_full]), rtol=1e-3)
        # in clear air: fewer, longer steps (the empty intervals get max(8, ~13 empty cells / 2) steps, not ~22)
        clear, clear_full = (mid < 2000) | (mid > 5500), (mid_full < 2000) | (mid_full > 5500)
        assert clear.sum() < 0.75 * clear_full.sum()
        assert np.median(ds[clear]) > 1.4 * np.median(ds_full[clear_full])


def test_empty_steps_setting():
    assert MarchSettings().resolved_empty_steps() == MarchSettings().n_grid // 4
    assert MarchSettings(n_grid=512).resolved_empty_steps() == 128
    assert MarchSettings(empty_steps=0).resolved_empty_steps() == 0
    assert MarchSettings(empty_steps=7).resolved_empty_steps() == 7


@pytest.mark.full  # the JAX kernel's programs compile for tens of seconds on an empty cache: the full tier
def test_numba_kernel_places_the_same_steps_as_grid_step_edges():
    """swim.rt.march_cpu._adaptive_edges (the per-ray kernel's, also the CUDA kernel's) against grid_step_edges:
    the same step counts and edges, with and without a limit on the empty steps, through clear and cloudy grids,
    with probes per cell crossed (re-probed rays, their lengths in cells from probe_counts_and_cells), for rays
    straight down through whole levels (a whole number of cells, where rounding up must not tip either way), and with
    and without a limit of their own on the steps in sunlit clear air (the step classes of kernel_constants: the
    clear grid is all sunlit, the cloudy one sunlit above the slab and in its shadow below)."""
    from swim.rt import march_cpu
    from swim.rt.march_settings import CELL_SLACK, MAX_PROBES

    dirs = [[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.8, 0.3, 0.52], [0.0, 0.0, -1.0], [0.1, 0.0, -0.995]]
    heights = [10.0, 10.0, 10.0, 9000.0, 9000.0]
    adaptive_edges = numba_jit.callable_from_python(march_cpu._adaptive_edges)
    for cloud in (False, True):
        consts, args = _rays(_scene(cloud=cloud), dirs, heights)
        start, direction, s0, length = (np.asarray(a, float) for a in args)
        p, coef = march_cpu.pack_parameters(consts)
        occupancy = np.asarray(consts["occupancy"])
        assert np.any(occupancy == SUNLIT_CLEAR) and (not cloud or np.any(occupancy == 0))
        for n_probe, spacing in ((64, 0.0), (8, 1.0)):
            count, cells = probe_counts_and_cells(*args, consts, n_probe, spacing)
            assert spacing == 0 or np.asarray(count).max() > n_probe, "some rays must be probed again"
            for empty_steps, sunlit_steps in ((0, 0), (0, 4), (4, 0), (16, 0), (4, 2), (16, 4)):
                edges, steps = (np.asarray(a) for a in grid_step_edges(
                    *args, 64, consts, n_probe=int(np.asarray(count).max()), probes=count, cells=cells,
                    empty_steps=empty_steps, sunlit_steps=sunlit_steps))
                for r in range(len(dirs)):
                    if cloud and r == 3:
                        # straight down through the slab the probes fall on exact halves of levels, which the two
                        # kernels' precisions may round to different cells (a tie older than the limit)
                        continue
                    out, cdf = np.empty(65), np.empty(MAX_PROBES + 1)
                    probe_at = np.empty((6, march_cpu.PROBE_BLOCK))  # a block of probes' indices (_probe_indices)
                    n = adaptive_edges(*start[r], *direction[r], s0[r], length[r], 64, p, coef, occupancy,
                                       n_probe, EMPTY_STEP_WEIGHT, spacing, CELL_SLACK, empty_steps,
                                       EMPTY_CELLS_PER_STEP, sunlit_steps, SUNLIT_CELLS_PER_STEP, cdf, out, probe_at)
                    assert n == steps[r], (cloud, n_probe, empty_steps, sunlit_steps, r)
                    np.testing.assert_allclose(out[: n + 1], edges[: n + 1, r], rtol=0,
                                               atol=1e-4 * max(length[r], 1.0))
                if empty_steps == 4:
                    assert np.all(steps < 64), "rays through the grid must take fewer steps"


def _classes(scene, sun):
    volume = build_optical_volume(scene)
    sun = np.asarray(sun, float) / np.linalg.norm(sun)
    fields = solar_transmittance(volume, sun)
    names = ["cloud_transmittance", "terrain_shadow"] + (["aerosol_tau_sun"] if scene_has_aerosol(volume) else [])
    return volume, fields, step_classes(occupancy_grid(volume), {n: fields[n].values for n in names})


def scene_has_aerosol(volume):
    return bool(np.any(volume["aerosol_extinction"].values > 0))


def test_step_classes_mark_the_sunlit_clear_air_only():
    """step_classes: occupied cells 1 (the cloud slab, dilated); above the slab, where the sun comes from, sunlit clear
    air (-1); below it, in its shadow, 0; a cell is sunlit only where every cell next to it is, so the level next to
    the shadow's edge is 0 too; a terrain's shadow and a 3-D aerosol's sun-ward optical depth take cells out too."""
    volume, fields, classes = _classes(_scene(), [0.0, 0.0, 1.0])
    z = volume["level"].values
    assert classes.dtype == np.int8 and not classes.flags.writeable
    np.testing.assert_array_equal(classes > 0, occupancy_grid(volume) > 0)
    assert np.all(classes[(z > 4600) & (z < 7500)] == SUNLIT_CLEAR), "clear air above the slab is sunlit"
    assert np.all(classes[z < 2700] == 0), "clear air in the slab's shadow is not"
    lit = (fields["cloud_transmittance"].values * fields["terrain_shadow"].values >= 0.999)
    # every sunlit cell has sunlit nodes all around it
    k, j, i = np.nonzero(classes == SUNLIT_CLEAR)
    assert len(k) and lit[k, j, i].all()
    for dk in (-1, 1):
        kk = np.clip(k + dk, 0, lit.shape[0] - 1)
        assert lit[kk, j, i].all()

    # no cloud, a low sun behind a hill: the hill's shadow is not sunlit, the air far above it is
    _, fields, classes = _classes(_scene(terrain_peak=1500.0, cloud=False), [1.0, 0.0, 0.15])
    shadow = fields["terrain_shadow"].values < 0.5
    assert shadow.any() and np.all(classes[shadow] >= 0)
    assert np.mean(classes == SUNLIT_CLEAR) > 0.5

    # a 3-D aerosol (over x > 0): its sun-ward optical depth takes its air out
    volume, fields, classes = _classes(_scene(aerosol=True, cloud=False), [0.0, 0.0, 1.0])
    hazy = fields["aerosol_tau_sun"].values > 2e-3
    assert hazy.any() and np.all(classes[hazy] >= 0)
    assert np.any(classes == SUNLIT_CLEAR)


def test_step_classes_write_in_place_and_check_shapes():
    volume = build_optical_volume(_scene())
    occupancy = occupancy_grid(volume)
    fields = solar_transmittance(volume, np.array([0.0, 0.0, 1.0]))
    named = {n: fields[n].values for n in ("cloud_transmittance", "terrain_shadow")}
    out = np.zeros(occupancy.shape, np.int8)
    got = step_classes(occupancy, named, out=out)
    assert got is out and np.any(out == SUNLIT_CLEAR)
    np.testing.assert_array_equal(step_classes(occupancy, named), out)
    with pytest.raises(ValueError, match="occupancy's shape"):
        step_classes(occupancy, {**named, "terrain_shadow": named["terrain_shadow"][1:]})


@pytest.mark.full  # the JAX kernel's step placement (its numba twin is held to it in the full tier too)
def test_sunlit_steps_thin_out_the_steps_in_sunlit_clear_air():
    """grid_step_edges: a ray through a clear, sunlit grid takes max(sunlit_steps, cells / SUNLIT_CELLS_PER_STEP)
    equal steps (fewer than the empty cells' limit gives it); through the cloud slab it keeps its steps in the cloud
    and at least as many in the cloud's shadow below it (whose empty cells keep their own limit), and takes fewer above
    it."""
    dirs = [[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]]
    consts, args = _rays(_scene(cloud=False), dirs)
    cells = np.asarray(probe_counts_and_cells(*args, consts)[1])
    for sunlit_steps in (2, 5):
        edges, steps = (np.asarray(a) for a in grid_step_edges(*args, 64, consts, empty_steps=16,
                                                               sunlit_steps=sunlit_steps))
        np.testing.assert_array_equal(steps, np.ceil(np.maximum(sunlit_steps, cells / SUNLIT_CELLS_PER_STEP)))
        for r, count in enumerate(steps):
            ds = np.diff(edges[: count + 1, r])
            np.testing.assert_allclose(ds, ds.mean(), rtol=1e-3)

    consts, args = _rays(_scene(), dirs)
    before, steps_before = (np.asarray(a) for a in grid_step_edges(*args, 64, consts, empty_steps=16))
    after, steps_after = (np.asarray(a) for a in grid_step_edges(*args, 64, consts, empty_steps=16, sunlit_steps=2))
    assert np.all(steps_after < steps_before)
    for r in range(len(dirs)):
        def heights(edges, count):
            return 0.5 * (edges[1:count + 1, r] + edges[:count, r]) * dirs[r][2]
        h0, h1 = heights(before, steps_before[r]), heights(after, steps_after[r])
        ds0, ds1 = np.diff(before[: steps_before[r] + 1, r]), np.diff(after[: steps_after[r] + 1, r])
        cloud0, cloud1 = (h0 > 3100) & (h0 < 3900), (h1 > 3100) & (h1 < 3900)
        np.testing.assert_allclose(np.median(ds1[cloud1]), np.median(ds0[cloud0]), rtol=0.02)  # the cloud
        assert np.sum(h1 < 2700) >= np.sum(h0 < 2700), r  # the shadow
        assert np.sum(h1 > 4600) < np.sum(h0 > 4600), r  # the sunlit clear air


def test_sunlit_steps_setting():
    assert MarchSettings().sunlit_steps == 4
    assert MarchSettings(sunlit_steps=0).sunlit_steps == 0
    with pytest.raises(Exception, match="sunlit_steps"):
        MarchSettings(sunlit_steps=-1)
    with pytest.raises(Exception, match="sunlit_steps"):
        MarchSettings(sunlit_steps=2.5)
