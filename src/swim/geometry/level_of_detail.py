"""A distant view's scene at the resolution its pixels can resolve: one column per block of the grid's columns.

A satellite's view of a whole HRRR-size grid (1799 x 1059 x 50 columns of 3 km) from geostationary orbit sees ~20
km per pixel in a 256^2 image, yet the render would build the optical volume of every 3 km column: 14.3 GB and 64-82 s
on this project's 2-core machine (docs/performance.md, "Distant views of big grids"). Where each pixel covers several
columns, :func:`coarsen_scene` makes one column of each block of ``factor`` x ``factor`` columns before anything is read
in full (lazy arrays stay lazy), so that the volume, Step 1a and the march hold ``factor``^2 times fewer columns.
:func:`coarsening_factor` chooses the largest blocks no wider than the smallest pixel footprint on the grid.

:data:`METHODS`, how a block's columns become one:

* ``"sample"`` (the default): the block's middle column, as it is. A render traces one ray per pixel, a point sample
  of the grid inside the pixel's footprint; one column kept per block no wider than that footprint keeps the
  columns' statistics (the fraction of cloudy columns, the spread of their optical depths) and reads ``factor``^2
  times less of a file.
* ``"effective_thickness"``: the blocks' means, with each block's hydrometeor contents scaled by one factor
  chi <= 1, chosen so that the two-stream transmittance of a conservatively scattering layer,
  ``1 / (1 + 0.75 (1 - g) tau)``, of the block's mean column equals the mean of its columns' (the effective thickness
  approximation: Cahalan et al. 1994, doi:10.1175/1520-0469(1994)051<2434:TAOFC>2.0.CO;2; Szczap et al. 2000,
  doi:10.1029/2000JD900046). A column's ``(1 - g) tau`` is Step 1a's ``(7/3) sum_s b_s tau_s`` over the species
  (Albers et al. 2020, doi:10.5194/amt-13-3235-2020, Eqs. 4-8), tau_s its vertical optical depth from Eq. 7. The
  block's water path is not kept.
* ``"mean"``: the blocks' means. A block's water path and mean optical depth are kept, but a uniform cloud of the
  mean optical depth reflects more than the average of the block's columns (transmittance is convex in optical
  depth: the plane-parallel albedo bias, Cahalan et al. 1994).

On the synthetic CONUS grid seen from geostationary orbit at 256^2 (blocks of 7 x 7 columns), against the render
of the whole grid, the grid's pixels came out on average 6 % darker with ``"sample"``, 19 % darker with
``"effective_thickness"`` and 43 % brighter with ``"mean"`` (docs/performance.md, "Distant views of big grids").

With the means, over a block:

* ``aerosol_extinction`` [m-1], ``height`` and ``terrain_height`` [m], ``surface_albedo``, ``snow_cover`` and
  ``wind_speed_10m``: the mean;
* ``<species>_effective_radius`` [m]: ``1.5 mean(content) / (rho mean(beta))``, beta the cells' extinction of Eq. 7
  with the radius that the optical volume would give them (the scene's, else the default:
  :func:`swim.optics.hydrometeors.effective_radius`), so that the block's extinction per content is kept; added for
  species that had none (cloud liquid's default radius grows with its content); NaN where the block has no content
  (as validation allows);
* ``lat``, ``lon``: the direction of the mean of the columns' unit vectors from the Earth's centre (no wrap at the
  antimeridian); ``x``, ``y``: the mean;
* ``land_mask``: land where at least half the block is land.

The grid's last rows and columns that do not fill a block are dropped (at most ``factor - 1`` of each).
"""

from __future__ import annotations

import logging
import math

import numpy as np
import xarray as xr

from ..constants import BACKSCATTER_FRACTION, HYDROMETEOR_DENSITY, SPECIES
from ..errors import SwimInputError
from ..frames import geodetic_to_scene

log = logging.getLogger(__name__)

__all__ = ["coarsen_scene", "coarsening_factor", "check_coarsening", "resolve_coarsening", "METHODS"]

#: The ways :func:`coarsen_scene` makes a block's column (see the module's docstring).
METHODS = ("sample", "effective_thickness", "mean")
#: Variables averaged over a block as they are.
_MEANS = ("height", "terrain_height", "aerosol_extinction", "smoke_mass_content", "surface_albedo", "snow_cover",
          "wind_speed_10m")
#: Columns of the lat/lon grid read per axis to find the grid's spacing and its nearest point to a camera (every
#: n-th; the 2-D fields of a CONUS grid are 1.9 million columns).
_SAMPLE = 256


def _is_factor(value) -> bool:
    """Whether ``value`` is an integer >= 1 (a bool is not)."""
    return not isinstance(value, bool) and isinstance(value, (int, np.integer)) and value >= 1


def _block_mean(da: xr.DataArray, factor: int) -> xr.DataArray:
    dims = {d: factor for d in ("y", "x") if d in da.dims}
    return da.coarsen(dims, boundary="trim").mean() if dims else da


def coarsen_scene(scene: xr.Dataset, factor: int, method: str = "sample") -> xr.Dataset:
    """One column for each block of ``factor`` x ``factor`` of the scene's columns (see the module's docstring).

    Parameters
    ----------
    scene : xarray.Dataset
        A scene in the canonical format (docs/scene-format.md), validated or not, with dimensions ``y`` and ``x``;
        any backing (numpy, dask, lazy netCDF): lazy arrays stay lazy.
    factor : int
        Columns per block along each horizontal axis, >= 1 (1: the scene itself).
    method : str
        One of :data:`METHODS`: a block's middle column (``"sample"``), or its means with the hydrometeors scaled to
        its mean transmittance (``"effective_thickness"``) or not (``"mean"``).

    Returns
    -------
    xarray.Dataset
        The coarse scene, with the scene's attributes (its reference point kept, so that the scene frame does not
        move), ``coarsened_by`` = ``factor`` (times the scene's own ``coarsened_by``, where it was coarsened before)
        and ``coarsened_with`` = ``method``. With the means, variables that are
        not in the canonical format are dropped.

    Raises
    ------
    SwimInputError
        If ``factor`` is not an integer >= 1, ``method`` is unknown, the scene has no ``y``/``x`` dimensions, or a
        block would be larger than half the grid.

    References
    ----------
    Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Eq. 7 (extinction from content and effective radius) and
    Eqs. 4-8 (the backscatter fractions of Step 1a); Cahalan et al. (1994),
    doi:10.1175/1520-0469(1994)051<2434:TAOFC>2.0.CO;2, and Szczap et al. (2000), doi:10.1029/2000JD900046 (the
    effective thickness).
    """
    if not _is_factor(factor):
        raise SwimInputError(f"coarsen: the factor must be an integer >= 1 (columns per block), got {factor!r}")
    if method not in METHODS:
        raise SwimInputError(f"coarsen: method must be one of {METHODS}, got {method!r}")
    factor = int(factor)
    if factor == 1:
        return scene
    if not isinstance(scene, xr.Dataset) or not {"y", "x"} <= set(scene.dims):
        raise SwimInputError("coarsen: the scene must be an xarray.Dataset with dimensions 'y' and 'x'")
    if min(scene.sizes["y"], scene.sizes["x"]) < 2 * factor:
        raise SwimInputError(f"coarsen: blocks of {factor} x {factor} columns need a grid of at least {2 * factor} "
                             f"columns per axis, got {scene.sizes['y']} x {scene.sizes['x']}")
    if method == "sample":  # each block's middle column, as it is (the same blocks as the means': trimmed)
        rows, cols = (slice(factor // 2, scene.sizes[d] // factor * factor, factor) for d in ("y", "x"))
        return scene.isel(y=rows, x=cols).assign_attrs(coarsened_by=factor * int(scene.attrs.get("coarsened_by", 1)),
                                                       coarsened_with=method)
    if "time" in scene.dims and scene.sizes["time"] == 1:  # one time along a dimension (validation accepts it)
        scene = scene.squeeze("time")
    out = {}
    for name in _MEANS:
        if name in scene:
            out[name] = _block_mean(scene[name], factor).assign_attrs(scene[name].attrs)
    present = [species for species in SPECIES if f"{species}_content" in scene]
    # numerical noise below 0 (which validation clips) as 0
    contents = {species: xr.where(scene[f"{species}_content"] > 0, scene[f"{species}_content"], 0.0)
                for species in present}
    betas = {species: _extinction(scene, species, contents[species]) for species in present}
    chi = _effective_thickness_factor(scene, betas, factor) if method == "effective_thickness" and present else 1.0
    for species in present:
        name, radius = f"{species}_content", f"{species}_effective_radius"
        mean_c, mean_beta = _block_mean(contents[species], factor), _block_mean(betas[species], factor)
        out[name] = (mean_c * chi).assign_attrs(scene[name].attrs)
        # Eq. 7 inverted for the block's extinction per content (chi scales content and extinction alike)
        out[radius] = xr.where(mean_beta > 0, 1.5 * mean_c / (HYDROMETEOR_DENSITY[species] * mean_beta.where(
            mean_beta > 0)), np.nan).assign_attrs(scene[radius].attrs if radius in scene else {"units": "m"})
    if "land_mask" in scene:
        land = _block_mean(scene["land_mask"].astype(np.float32), factor)
        out["land_mask"] = (land >= 0.5).astype(np.int8).assign_attrs(scene["land_mask"].attrs)
    if "lat" in scene and "lon" in scene:
        lat, lon = np.deg2rad(scene["lat"]), np.deg2rad(scene["lon"])
        ex, ey, ez = (_block_mean(v, factor) for v in (np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon),
                                                      np.sin(lat)))
        out["lat"] = np.rad2deg(np.arctan2(ez, np.hypot(ex, ey))).assign_attrs(scene["lat"].attrs)
        out["lon"] = np.rad2deg(np.arctan2(ey, ex)).assign_attrs(scene["lon"].attrs)
    coarse = xr.Dataset(out, attrs={**scene.attrs, "coarsened_by": factor * int(scene.attrs.get("coarsened_by", 1)),
                                    "coarsened_with": method})
    for name in ("x", "y"):  # the mean of the block's coordinates (trimmed as the fields)
        if name in scene.coords:
            coarse = coarse.assign_coords({name: _block_mean(scene[name], factor).assign_attrs(scene[name].attrs)})
    for name, coord in scene.coords.items():  # time, wavelength: kept as they are
        if name not in coarse.coords and not {"y", "x"} & set(coord.dims):
            coarse = coarse.assign_coords({name: coord})
    return coarse


def _extinction(scene: xr.Dataset, species: str, content: xr.DataArray) -> xr.DataArray:
    """Eq. 7's extinction [m-1] of the cells, ``1.5 content / (radius rho)``, with the radius that the optical volume
    would use (the scene's where positive, else the default: :func:`swim.optics.hydrometeors.effective_radius`);
    lazy where ``content`` is."""
    from ..optics.hydrometeors import effective_radius, extinction_coefficient_stephens1978

    def beta(c, r=None):  # the radius is positive everywhere (the default where none is given), so 0 where c is 0
        return extinction_coefficient_stephens1978(c, effective_radius(species, c, r), HYDROMETEOR_DENSITY[species])

    given = scene.get(f"{species}_effective_radius")
    args = (content,) if given is None else (content, given)
    return xr.apply_ufunc(beta, *args, dask="parallelized", output_dtypes=[np.float64])


def _effective_thickness_factor(scene: xr.Dataset, betas: dict, factor: int) -> xr.DataArray:
    """Per block (y, x): chi = s_eff / mean(s), s = (1 - g) tau of each column (7/3 sum_s b_s tau_s, tau_s its
    vertical optical depth: Eq. 7's extinction times the layers' thickness) and ``1 / (1 + 0.75 s_eff)`` the mean of
    the columns' ``1 / (1 + 0.75 s)``; 1 where the block has no hydrometeors."""
    from ..io.scene import layer_thickness
    from ..rt.solar import ONE_MINUS_G_PER_BACKSCATTER

    height = scene["height"].transpose("z", "y", "x")
    if getattr(height.data, "chunks", None) is not None:
        height = height.chunk({"z": -1})  # a column's layers in one block

    def thickness(h, t):  # apply_ufunc puts z last; layer_thickness wants it first
        return np.moveaxis(layer_thickness(np.moveaxis(h, -1, 0), t), 0, -1)

    dz = xr.apply_ufunc(thickness, height, scene["terrain_height"], input_core_dims=[["z"], []],
                        output_core_dims=[["z"]], dask="parallelized", output_dtypes=[np.float64])
    s = ONE_MINUS_G_PER_BACKSCATTER * sum(BACKSCATTER_FRACTION[species] * (beta * dz).sum("z")
                                          for species, beta in betas.items())
    mean_s = _block_mean(s, factor)
    mean_t = _block_mean(1.0 / (1.0 + 0.75 * s), factor)
    s_eff = (1.0 / mean_t - 1.0) / 0.75
    return xr.where(mean_s > 0, s_eff / mean_s.where(mean_s > 0), 1.0).clip(0.0, 1.0)


def _grid_spacing_and_points(scene: xr.Dataset):
    """The grid's smallest column spacing [m] (of a sample of neighbouring columns), a sample of its columns'
    sea-level points (lat, lon) [deg] (~:data:`_SAMPLE` columns per axis), and the sample's largest spacing [m], from
    ``lat`` and ``lon`` (2-D: read, not the 3-D fields; a length-1 ``time`` dimension dropped, as the crop does).

    Raises
    ------
    SwimInputError
        If ``lat`` or ``lon`` is missing, not (y, x), or not finite.
    """
    from .reach import _finite, _horizontal_values

    if "lat" not in scene or "lon" not in scene:
        raise SwimInputError("coarsen: the scene needs 'lat' and 'lon' (y, x) [deg] to choose a factor")
    ny, nx = scene.sizes["y"], scene.sizes["x"]
    sy, sx = max(1, ny // _SAMPLE), max(1, nx // _SAMPLE)
    rows, cols = slice(None, None, sy), slice(None, None, sx)
    lat, lon = (_finite(name, _horizontal_values(scene, name, rows, cols)) for name in ("lat", "lon"))
    points = geodetic_to_scene(lat, lon, 0.0, float(lat.flat[0]), float(lon.flat[0]))
    # the sample's neighbours are sy and sx columns apart
    steps, sample_steps = [], [0.0]
    if points.shape[0] > 1:
        step = float(np.median(np.linalg.norm(np.diff(points, axis=0), axis=-1)))
        steps.append(step / sy)
        sample_steps.append(step)
    if points.shape[1] > 1:
        step = float(np.median(np.linalg.norm(np.diff(points, axis=1), axis=-1)))
        steps.append(step / sx)
        sample_steps.append(step)
    return (min(steps) if steps else math.inf), lat, lon, max(sample_steps)


def coarsening_factor(scene: xr.Dataset, camera: str, camera_options: dict, lat: float, lon: float,
                      height: float, look_at=None) -> int:
    """The largest block of columns (per axis) no wider than the smallest footprint of a pixel on the grid.

    The footprint is the angle of a pixel at the image's centre (``2 tan(fov / 2) / width`` for a perspective
    camera; the image's edges are narrower by cos^2(fov / 2), negligible from orbit) times the distance from the
    camera to the grid's nearest column at sea level: of a sample of ~256 columns per axis, or the camera's height
    where it is over the grid. Only perspective cameras are coarsened: an all-sky or panoramic camera sees the
    columns around it from close by.

    Parameters
    ----------
    scene : xarray.Dataset
        With ``lat``, ``lon`` (y, x) [deg] (read; the 3-D fields are not).
    camera : str
        Camera kind.
    camera_options : dict
        The camera's options: a perspective camera's ``width`` and ``fov_deg``. Without ``fov_deg``, a camera in
        space that looks at the grid's reference point (no ``look_at``) gets the field of view that
        :func:`swim.render` fits to the grid (:func:`swim.geometry.cameras.fov_to_fit` of the grid's half diagonal);
        otherwise 1 is returned.
    lat, lon : float
        The camera's position [deg].
    height : float
        The camera's height [m] above sea level (its height above the ground, for a distant camera).
    look_at : tuple of float, optional
        :func:`swim.render`'s ``look_at``.

    Returns
    -------
    int
        >= 1 (1: no coarsening).
    """
    from ..constants import ATMOSPHERE_TOP_M
    from .cameras import fov_to_fit

    if str(camera).strip().lower() != "perspective" or "width" not in camera_options:
        return 1
    spacing, glat, glon, sample_step = _grid_spacing_and_points(scene)
    if not (np.isfinite(spacing) and spacing > 0):
        return 1
    lat0, lon0 = float(glat.flat[0]), float(glon.flat[0])
    camera_at = geodetic_to_scene(float(lat), float(lon), float(height), lat0, lon0)
    columns = geodetic_to_scene(glat, glon, 0.0, lat0, lon0)
    below = geodetic_to_scene(float(lat), float(lon), 0.0, lat0, lon0)
    if "fov_deg" in camera_options:
        fov = float(camera_options["fov_deg"])
    elif look_at is None and float(height) > ATMOSPHERE_TOP_M and {"reference_lat", "reference_lon"} <= set(
            scene.attrs):
        # as swim.pipeline.scene_stage.default_perspective_view: the grid's half diagonal seen from the camera
        centre = geodetic_to_scene(float(scene.attrs["reference_lat"]), float(scene.attrs["reference_lon"]), 0.0,
                                   lat0, lon0)
        half_diagonal = 0.5 * float(np.linalg.norm(columns[-1, -1] - columns[0, 0]))
        fov = fov_to_fit(float(np.linalg.norm(camera_at - centre)), half_diagonal)
    else:
        return 1
    pixel = 2.0 * math.tan(math.radians(fov) / 2.0) / float(camera_options["width"])
    nearest = float(np.min(np.linalg.norm(columns - camera_at, axis=-1)))
    if float(np.min(np.linalg.norm(columns - below, axis=-1))) <= sample_step:
        # over the grid (or at its edge): a column may lie straight below, between the sampled ones
        nearest = min(nearest, max(float(height), 0.0))
    factor = int(nearest * pixel // spacing)
    # at least two blocks per axis
    return max(1, min(factor, scene.sizes["y"] // 2, scene.sizes["x"] // 2))


def check_coarsening(coarsen) -> None:
    """Raise SwimInputError unless ``coarsen`` is None, ``"auto"`` or an integer >= 1 (:func:`swim.render`'s
    argument), before any work."""
    if coarsen is None or (isinstance(coarsen, str) and coarsen.strip().lower() == "auto"):
        return
    if not _is_factor(coarsen):
        raise SwimInputError(f"coarsen must be None, 'auto' or an integer >= 1, got {coarsen!r}")


def resolve_coarsening(coarsen, scene, camera, camera_options, lat, lon, height, look_at=None) -> int:
    """:func:`swim.render`'s ``coarsen`` argument as a factor: None -> 1, ``"auto"`` -> :func:`coarsening_factor`,
    an integer >= 1 as it is.

    Raises
    ------
    SwimInputError
        For any other value.
    """
    check_coarsening(coarsen)
    if coarsen is None:
        return 1
    if isinstance(coarsen, str):
        lat0, lon0 = scene.attrs.get("reference_lat"), scene.attrs.get("reference_lon")
        factor = coarsening_factor(scene, camera, dict(camera_options or {}), lat0 if lat is None else lat,
                                   lon0 if lon is None else lon, height, look_at)
        log.info("coarsen: %d x %d columns per block for this view", factor, factor)
        return factor
    return int(coarsen)
