"""The built-in default scene: fair-weather cumulus and a patchy cirrus deck over a hill and a lake.

It needs no external file and is generated deterministically (fixed seed) from the recipe below, which
``docs/scene-format.md`` repeats. All heights are above sea level.

Recipe
------
* **Grid.** 80 x 80 columns at 500 m (a 40 km x 40 km domain centred on the reference point 40.0 N,
  105.3 W, Boulder-like); ``x = (i - 39.5) * 500 m``, likewise ``y``. 40 terrain-following levels: layer
  interfaces ``zeta_k = dz0 (r^k - 1) / (r - 1)``, k = 0..40, with a first layer dz0 = 100 m and the ratio r
  (about 1.05) that puts the top interface at Z_TOP = 12 km; mass points midway between interfaces (50 m to
  about 11.7 km); ``height = zeta + h_s (1 - zeta / Z_TOP)`` (Gal-Chen & Somerville 1975) over terrain h_s.
* **Terrain.** Sea-level plain with a Gaussian hill of 800 m height and 5 km e-folding half-width
  (``800 exp(-d^2 / (2 * (5 km)^2))``) centred at (x, y) = (8, 6) km; a round lake of radius 3 km
  centred at (-12, -10) km (terrain 0, ``land_mask`` 0; land elsewhere).
* **Surface albedo** at (615, 546, 450) nm: grass/crops (0.09, 0.12, 0.05) on the plain, blending linearly to
  forest (0.04, 0.06, 0.03) between 0 and 600 m terrain height; water (0.04, 0.05, 0.06) in the lake.
* **Cumulus field** (seed 20230621, ``numpy.random.default_rng``): 24 clouds, centres uniform in
  [-18, 18] km in x and y, radius R uniform in [0.8, 2.0] km, base ``z_b = 1500 m + N(0, 50 m)``, top
  ``z_t`` uniform in [2500, 4000] m. Inside a cloud, with ``zeta = (z - z_b) / (z_t - z_b)`` in [0, 1],
  ``LWC = Gamma_ad (z - z_b) * 0.35 (1 - zeta^4)`` with the adiabatic LWC gradient Gamma_ad = 2e-6 kg m-3
  per m (sub-adiabatic, diluted towards the top; peak about 0.9 g m-3 in the deepest clouds), times a
  flat-topped horizontal profile ``exp(-(d / R(zeta))^4)`` with a dome ``R(zeta) = R sqrt(1 - zeta^3)``.
  Overlapping clouds take the maximum; LWC below 1e-5 kg m-3 (0.01 g m-3) is set to 0 (sharp edges).
  Effective radius after Martin et al. (1994): ``r_e = (3 LWC / (4 pi rho_w k N))^(1/3)`` with continental
  ``k = 0.67`` and droplet number ``N = 200 cm-3`` (about 3 to 12 um).
* **Cirrus deck**: a 2-D field of white noise (same generator) smoothed with a periodic Gaussian filter of
  sigma 2 km and scaled to unit standard deviation; ``patch = clip(noise / 1.5, 0, 1)`` (about half the
  domain covered). Ice content ``(1e-5 + 4e-5 patch) kg m-3`` where patch > 0, times a vertical trapezoid
  that is 1 between 9.0 and 10.0 km and falls linearly to 0 at 8.6 and 10.4 km; values below 1e-6 kg m-3 set
  to 0. No ice effective radius (the default 34 um applies).
* No rain, snow, graupel or aerosol variables (the renderer's default background aerosol applies).
* Time 2023-06-21T18:00Z (scalar coordinate ``time``).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter
from scipy.optimize import brentq

from .scene import scene_from_arrays

__all__ = ["default_scene", "DEFAULT_SCENE_SEED"]

#: Seed of the random generator of the default scene.
DEFAULT_SCENE_SEED = 20230621

_NX = _NY = 80
_DX = 500.0
_NZ = 40
_Z_TOP = 12_000.0
_DZ0 = 100.0
_REFERENCE = (40.0, -105.3)
_TIME = "2023-06-21T18:00:00Z"

_GAMMA_AD = 2e-6  # adiabatic LWC gradient [kg m-3 per m]
_N_DROPLETS = 200e6  # [m-3]
_K_MARTIN = 0.67  # continental, Martin et al. (1994)
_RHO_WATER = 1000.0


def _levels():
    ratio = brentq(lambda r: _DZ0 * (r**_NZ - 1.0) / (r - 1.0) - _Z_TOP, 1.0001, 1.5)
    interfaces = _DZ0 * (ratio ** np.arange(_NZ + 1) - 1.0) / (ratio - 1.0)
    return 0.5 * (interfaces[1:] + interfaces[:-1])


def default_scene():
    """The built-in default scene (recipe in the module docstring and ``docs/scene-format.md``).

    Returns
    -------
    xarray.Dataset
        Validated canonical scene with dims (z, y, x) = (40, 80, 80): terrain-following ``height`` [m],
        ``lat``/``lon`` [deg], ``terrain_height`` [m], ``cloud_liquid_content`` and ``cloud_ice_content``
        [kg m-3], ``cloud_liquid_effective_radius`` [m], ``surface_albedo`` (wavelength, y, x) [-],
        ``land_mask``, coordinates ``x``, ``y`` [m], ``wavelength`` [nm] and ``time`` (2023-06-21T18:00 UTC),
        attrs ``reference_lat`` = 40.0, ``reference_lon`` = -105.3. Identical on every call.
    """
    rng = np.random.default_rng(DEFAULT_SCENE_SEED)
    x = (np.arange(_NX) - 0.5 * (_NX - 1)) * _DX
    y = (np.arange(_NY) - 0.5 * (_NY - 1)) * _DX
    gx, gy = np.meshgrid(x, y)

    # terrain, lake, albedo
    terrain = 800.0 * np.exp(-((gx - 8000.0) ** 2 + (gy - 6000.0) ** 2) / (2.0 * 5000.0**2))
    lake = (gx + 12000.0) ** 2 + (gy + 10000.0) ** 2 < 3000.0**2
    terrain = np.where(lake, 0.0, terrain)
    land_mask = np.where(lake, 0, 1)
    grass = np.array([0.09, 0.12, 0.05])[:, None, None]
    forest = np.array([0.04, 0.06, 0.03])[:, None, None]
    water = np.array([0.04, 0.05, 0.06])[:, None, None]
    f = np.clip(terrain / 600.0, 0.0, 1.0)[None]
    albedo = np.where(lake[None], water, (1.0 - f) * grass + f * forest)

    # terrain-following heights
    zeta = _levels()[:, None, None]
    height = zeta + terrain[None] * (1.0 - zeta / _Z_TOP)

    # cumulus field
    n_clouds = 24
    cx = rng.uniform(-18000.0, 18000.0, n_clouds)
    cy = rng.uniform(-18000.0, 18000.0, n_clouds)
    radius = rng.uniform(800.0, 2000.0, n_clouds)
    base = 1500.0 + rng.normal(0.0, 50.0, n_clouds)
    top = rng.uniform(2500.0, 4000.0, n_clouds)
    lwc = np.zeros_like(height)
    for i in range(n_clouds):
        # exp(-(d/R)^4) < 1e-27 beyond 2.5 R: work on the bounding box only
        ix = np.flatnonzero(np.abs(x - cx[i]) <= 2.5 * radius[i])
        iy = np.flatnonzero(np.abs(y - cy[i]) <= 2.5 * radius[i])
        if ix.size == 0 or iy.size == 0:
            continue
        box = (slice(None), slice(iy[0], iy[-1] + 1), slice(ix[0], ix[-1] + 1))
        h = height[box]
        s = np.clip((h - base[i]) / (top[i] - base[i]), 0.0, 1.0)
        inside = (h >= base[i]) & (h <= top[i])
        vertical = _GAMMA_AD * (h - base[i]) * 0.35 * (1.0 - s**4)
        r_of_z = radius[i] * np.sqrt(np.clip(1.0 - s**3, 0.0, None))
        d = np.hypot(gx[box[1:]] - cx[i], gy[box[1:]] - cy[i])[None]
        horizontal = np.where(r_of_z > 0, np.exp(-((d / np.where(r_of_z > 0, r_of_z, 1.0)) ** 4)), 0.0)
        lwc[box] = np.maximum(lwc[box], np.where(inside, vertical * horizontal, 0.0))
    lwc = np.where(lwc >= 1e-5, lwc, 0.0)
    reff = np.cbrt(3.0 * lwc / (4.0 * np.pi * _RHO_WATER * _K_MARTIN * _N_DROPLETS))

    # cirrus deck
    noise = gaussian_filter(rng.standard_normal((_NY, _NX)), sigma=2000.0 / _DX, mode="wrap")
    noise /= noise.std()
    patch = np.clip(noise / 1.5, 0.0, 1.0)
    column_ice = np.where(patch > 0, 1e-5 + 4e-5 * patch, 0.0)
    vertical = np.clip(np.minimum((height - 8600.0) / 400.0, (10400.0 - height) / 400.0), 0.0, 1.0)
    ice = column_ice[None] * vertical
    ice = np.where(ice >= 1e-6, ice, 0.0)

    return scene_from_arrays(
        x=x,
        y=y,
        z=height,
        reference_lat=_REFERENCE[0],
        reference_lon=_REFERENCE[1],
        terrain_height=terrain,
        cloud_liquid_content=lwc,
        cloud_ice_content=ice,
        cloud_liquid_effective_radius=reff,
        surface_albedo=albedo,
        land_mask=land_mask,
        time=_TIME,
        title="swim default scene: fair-weather cumulus and patchy cirrus over a hill and a lake",
        source=f"swim.io.default_scene.default_scene (built-in recipe, seed {DEFAULT_SCENE_SEED})",
    )
