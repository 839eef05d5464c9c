"""Scenes of the benchmark suite: the real data sets and two procedural ones (deterministic, seeded).

``synthetic_scene`` is an eager 400 x 400 x 60 scene with all five hydrometeor species and terrain;
``conus_scene`` is a HRRR-sized 1799 x 1059 x 50 scene whose 3-D fields are lazy dask arrays, generated
chunk by chunk and never held in full. Both evaluate the same procedural field function at any (x, y), so
a dask chunk is bit-identical to the same window of an eager grid.

The clouds are built from sums of random plane waves (unit-variance Gaussian-like noise):

* terrain: red-spectrum noise, 20-200 km wavelengths, smooth hills up to ``terrain_max_m``; the lowest
  quarter of the noise range is sea (``land_mask`` 0, terrain 0);
* boundary-layer cumulus: 4-16 km noise plus a 80-400 km mesoscale envelope, thresholded to a strength
  s in [0, 1] (cloud fraction ~13 %); base 900 m above the ground, top rising with s; s > 0.85 makes deep
  cores up to ~12 km;
* cloud liquid: adiabatic-like growth above the base, <= 1 g m-3, below 7 km;
* rain: shafts from the ground into the lower cloud where s > 0.5, <= 0.5 g m-3;
* graupel: in the deep cores between 4.5 km and 1 km below the top, <= 0.5 g m-3;
* cloud ice: an anvil layer 8-11.5 km (30-200 km noise), <= 0.1 g m-3, and 0.05 g m-3 in the deep-core tops;
* snow: under the thicker anvil (5.5-9 km) and in the deep cores above 5 km, <= 0.3 g m-3.

Contents are in kg m-3 as docs/scene-format.md requires; effective radii are left to the defaults.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

#: Reference points and valid times of the procedural scenes (sun high over the central US in July).
SYNTHETIC_REFERENCE = (35.0, -100.0, "2024-07-01T18:00")
CONUS_REFERENCE = (38.0, -97.0, "2024-07-01T18:00")

_FIELD_NAMES = ("cloud_liquid_content", "cloud_ice_content", "rain_content", "snow_content", "graupel_content")


# ---------------------------------------------------------------------------------------------------------
# procedural fields


def _waves(rng, n, lam_min, lam_max, spectral_slope):
    """n random plane waves: wavenumber vectors (n, 2) [rad m-1], phases (n,), amplitudes (n,) with unit total
    variance; amplitude ~ wavelength**spectral_slope (1 = red: smooth, 0 = white)."""
    lam = np.exp(rng.uniform(np.log(lam_min), np.log(lam_max), n))
    theta = rng.uniform(0.0, 2 * np.pi, n)
    k = (2 * np.pi / lam)[:, None] * np.stack([np.cos(theta), np.sin(theta)], axis=1)
    amp = lam**spectral_slope
    amp /= np.sqrt(0.5 * np.sum(amp**2))
    return k, rng.uniform(0.0, 2 * np.pi, n), amp


def make_params(seed=0, terrain_max_m=1500.0, top_m=16000.0):
    """The random constants of one procedural world (wave sets, heights); pure data, so picklable."""
    rng = np.random.default_rng(seed)
    return {
        "terrain": _waves(rng, 24, 20e3, 200e3, 1.0),
        "meso": _waves(rng, 16, 80e3, 400e3, 1.0),
        "cumulus": _waves(rng, 48, 4e3, 16e3, 0.5),
        "anvil": _waves(rng, 24, 30e3, 200e3, 1.0),
        "terrain_max_m": float(terrain_max_m),
        "top_m": float(top_m),
    }


def _noise(x, y, waves, shift=(0.0, 0.0)):
    """Sum of plane waves on the grid (y, x) [m]; ``shift`` [m] moves the pattern (advection)."""
    k, phase, amp = waves
    xs, ys = np.asarray(x, float) - shift[0], np.asarray(y, float) - shift[1]
    out = np.zeros((ys.size, xs.size))
    for (kx, ky), p, a in zip(k, phase, amp):
        # cos(a + b) = cos a cos b - sin a sin b keeps the work O(nx + ny) per wave plus one outer product
        ax, ay = kx * xs + p, ky * ys
        out += a * (np.cos(ay)[:, None] * np.cos(ax)[None, :] - np.sin(ay)[:, None] * np.sin(ax)[None, :])
    return out


def _columns(x, y, params, shift):
    """2-D fields of a window: terrain [m], land mask, cumulus strength s, anvil strength a."""
    t = _noise(x, y, params["terrain"])
    land = t > -0.6
    terrain = np.where(land, params["terrain_max_m"] * np.clip((t + 0.6) / 3.0, 0.0, 1.0) ** 1.5, 0.0)
    meso = _noise(x, y, params["meso"], shift)
    s = np.clip((_noise(x, y, params["cumulus"], shift) + 0.6 * meso - 1.3) / 1.2, 0.0, 1.0)
    anvil = _noise(x, y, params["anvil"], shift) + 0.5 * meso
    return terrain, land, s, anvil


def level_fractions(nz):
    """Terrain-following level positions in (0, 1): stretched (thin near the ground, as in WRF/HRRR)."""
    return ((np.arange(nz) + 0.5) / nz) ** 1.4


def _profile(z, lo, hi):
    """0 outside [lo, hi], a smooth bump (sin) inside; broadcasting (nz, ny, nx)."""
    f = np.clip((z - lo) / np.maximum(hi - lo, 1.0), 0.0, 1.0)
    return np.sin(np.pi * f)


def fields_3d(x, y, nz, params, names, shift=(0.0, 0.0)):
    """The 3-D fields ``names`` (from "height" and the five ``*_content``) on the window (nz, y, x)."""
    terrain, _, s, anvil = _columns(x, y, params, shift)
    z = terrain + (params["top_m"] - terrain) * level_fractions(nz)[:, None, None]
    base = terrain + 900.0
    deep = np.clip((s - 0.85) / 0.15, 0.0, 1.0)
    top = np.where(s > 0, base + 300.0 + 2700.0 * s + 8000.0 * deep, base)
    inside = (z >= base) & (z <= top) & (s > 0)
    frac = np.clip((z - base) / np.maximum(top - base, 1.0), 0.0, 1.0)
    out = {}
    for name in names:
        if name == "height":
            v = z
        elif name == "cloud_liquid_content":
            adiabatic = np.minimum(np.sqrt(s) * (z - base) / 2000.0, 1.0)
            v = 1e-3 * adiabatic * (1.0 - frac**4) * (inside & (z < 7000.0))
        elif name == "rain_content":
            shaft = np.clip((s - 0.5) / 0.5, 0.0, 1.0)
            v = 0.5e-3 * shaft * (z >= terrain) * (z <= base + 0.4 * (top - base)) * (0.6 + 0.4 * np.exp(-(z - terrain) / 2000.0))
        elif name == "graupel_content":
            v = 0.5e-3 * deep * _profile(z, 4500.0, top - 1000.0)
        elif name == "cloud_ice_content":
            a = np.clip((anvil - 0.8) / 1.0, 0.0, 1.0)
            v = 0.1e-3 * a * _profile(z, 8000.0, 11500.0) + 0.05e-3 * deep * inside * (z > 7000.0)
        elif name == "snow_content":
            a = np.clip((anvil - 1.2) / 1.0, 0.0, 1.0)
            v = 0.2e-3 * a * _profile(z, 5500.0, 9000.0) + 0.3e-3 * deep * _profile(z, 5000.0, top)
        else:
            raise KeyError(name)
        out[name] = np.asarray(v, dtype=float)
    return out


def _axes(nx, ny, spacing):
    """Regular grid coordinates [m] centred on the reference point."""
    return (np.arange(nx) - 0.5 * (nx - 1)) * spacing, (np.arange(ny) - 0.5 * (ny - 1)) * spacing


# ---------------------------------------------------------------------------------------------------------
# scenes


def synthetic_scene(nx=400, ny=400, nz=60, spacing=1000.0, seed=0, shift=(0.0, 0.0), time=None):
    """Eager procedural scene with all five species and terrain (validated by ``scene_from_arrays``).

    Parameters
    ----------
    nx, ny, nz : int
        Grid size.
    spacing : float
        Horizontal grid spacing [m].
    seed : int
        Seed of the procedural world: the same seed gives the same scene at any grid size.
    shift : (float, float)
        Displacement [m] (east, north) of the clouds, e.g. wind x time for an advected time series.
    time : str, optional
        Valid time (UTC); default :data:`SYNTHETIC_REFERENCE`.
    """
    from swim import scene_from_arrays

    lat0, lon0, t0 = SYNTHETIC_REFERENCE
    params = make_params(seed)
    x, y = _axes(nx, ny, spacing)
    terrain, land, _, _ = _columns(x, y, params, shift)
    f = fields_3d(x, y, nz, params, ("height",) + _FIELD_NAMES, shift)
    return scene_from_arrays(x=x, y=y, z=f.pop("height"), reference_lat=lat0, reference_lon=lon0,
                             terrain_height=terrain, land_mask=land.astype(np.int8), time=time or t0,
                             title=f"swim benchmark synthetic scene {nx}x{ny}x{nz} seed {seed}",
                             source="benchmarks/scenes.py synthetic_scene", **f)


def _dask_block(name, x, y, nz, params, block_info=None):
    loc = block_info[None]["array-location"]
    return fields_3d(x[slice(*loc[2])], y[slice(*loc[1])], nz, params, (name,))[name]


def conus_scene(nx=1799, ny=1059, nz=50, spacing=3000.0, seed=0, chunk=256, terrain_max_m=3000.0):
    """HRRR-sized lazy scene: 3-D fields are dask arrays computed per (nz, chunk, chunk) block on demand.

    The grid is regular in swim's scene frame (orthographic about 38N 97W, close to HRRR's Lambert grid
    over CONUS) so that the ``x``/``y`` coordinates agree with lat/lon as the canonical format requires.
    The 2-D fields (lat, lon, terrain, land mask: ~15 MB each) are eager numpy; the six 3-D fields (~760 MB
    each in float64) are lazy. The dataset is built directly, not through ``validate_scene``, which would
    load every field; it holds what ``validate_scene`` returns for valid input.
    """
    import dask.array as da

    from swim.constants import EARTH_RADIUS_M
    from swim.frames import scene_to_geodetic
    from swim.io.scene import _LONG_NAMES, _UNITS

    lat0, lon0, t0 = CONUS_REFERENCE
    params = make_params(seed, terrain_max_m=terrain_max_m, top_m=20000.0)
    x, y = _axes(nx, ny, spacing)
    terrain, land, _, _ = _columns(x, y, params, (0.0, 0.0))
    gx, gy = np.meshgrid(x, y)
    # lat/lon of each column's sea-level point, exactly as scene_from_arrays computes them
    sea_level = np.stack([gx, gy, np.sqrt(EARTH_RADIUS_M**2 - gx**2 - gy**2)], axis=-1)
    lat, lon, _ = scene_to_geodetic(sea_level, lat0, lon0)

    def var(values, dims, name):
        return xr.DataArray(values, dims=dims, attrs={"units": _UNITS[name], "long_name": _LONG_NAMES[name]})

    chunks = ((nz,), tuple(np.diff(np.r_[0:ny:chunk, ny])), tuple(np.diff(np.r_[0:nx:chunk, nx])))
    data = {"lat": var(lat, ("y", "x"), "lat"), "lon": var(lon, ("y", "x"), "lon"),
            "terrain_height": var(terrain, ("y", "x"), "terrain_height"),
            "land_mask": var(land.astype(np.int8), ("y", "x"), "land_mask")}
    for name in ("height",) + _FIELD_NAMES:
        lazy = da.map_blocks(_dask_block, name, x, y, nz, params, chunks=chunks, dtype=np.float64,
                             meta=np.empty((0, 0, 0)), name=f"conus-{name}-{seed}-{nx}x{ny}x{nz}")
        data[name] = var(lazy, ("z", "y", "x"), name)
    coords = {"x": var(x, ("x",), "x"), "y": var(y, ("y",), "y"), "time": np.datetime64(t0, "ns")}
    attrs = {"reference_lat": lat0, "reference_lon": lon0, "title": f"swim benchmark CONUS scene {nx}x{ny}x{nz} (lazy)",
             "source": "benchmarks/scenes.py conus_scene"}
    return xr.Dataset(data, coords=coords, attrs=attrs)


def katrina_scene(data_dir):
    """Hurricane Katrina WRF output at 2005-08-28 18 UTC (the CI test file)."""
    import swim

    return swim.open_scene(Path(data_dir) / "wrf_katrina" / "ci_test_file.nc", time="2005-08-28T18:00")


def rico_scene(data_dir):
    """The RICO shallow-cumulus LES of the Monte Carlo validation (swim.validation.mitsuba.RICO_CASES)."""
    import swim
    from swim.validation.mitsuba import RICO_CASES

    return swim.open_scene(Path(data_dir) / "les" / RICO_CASES["rico_ground_sza30"]["les"])
