"""Empty-space skipping: the occupancy grid and the adaptive step edges of the grid segment."""

import numpy as np
import jax.numpy as jnp

from swim.constants import EARTH_RADIUS_M
from swim.io.scene import scene_from_arrays
from swim.optics.volume import build_optical_volume
from swim.rt.gas import AerosolBackground, build_gas_tables
from swim.rt.march import (
    EMPTY_STEP_WEIGHT,
    adaptive_step_edges,
    grid_geometry,
    kernel_constants,
    occupancy_grid,
    ray_segments,
)
from swim.rt.solar import solar_transmittance


def _scene(terrain_peak=0.0, aerosol=False):
    n, spacing = 16, 500.0
    x = (np.arange(n) - n / 2 + 0.5) * spacing
    z = np.arange(0.0, 8000.0, 250.0) + 125.0
    zz, yy, xx = np.meshgrid(z, x, x, indexing="ij")
    # one cloud slab between 3 and 4 km over the whole domain
    liquid = np.where((zz > 3000) & (zz < 4000), 3e-4, 0.0)
    terrain = terrain_peak * np.exp(-((xx[0] / 1500) ** 2 + (yy[0] / 1500) ** 2))
    aer = 2e-4 * (xx > 0) * np.exp(-zz / 1500.0) if aerosol else None
    return scene_from_arrays(x=x, y=x, z=z, reference_lat=40.0, reference_lon=-100.0, terrain_height=terrain,
                             cloud_liquid_content=liquid, land_mask=1.0, aerosol_extinction=aer)


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
