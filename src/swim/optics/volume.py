"""Scene -> optical volume: extinction per species on a regular height grid (the optics stage).

The canonical scene (docs/scene-format.md) has terrain-following levels on a map-projected grid. The ray
tracer wants a volume it can index in O(1): this stage

1. computes the extinction coefficient of each hydrometeor species on the native grid with Eq. 7 of the
   paper (Albers et al. 2020) and the effective radius of each species
   (:func:`swim.optics.hydrometeors.effective_radius`), at the cells with content (elsewhere it is 0),
2. resamples extinction (not content: Eq. 7 is non-linear in the radius) linearly in height onto regular
   levels ``z = z_bottom + k dz`` per column; below the lowest model level down to the terrain the lowest
   value is kept (fog reaches the ground), below the terrain and above the top it is zero, and so is a
   regular level between model levels that are zero throughout a block of columns (not interpolated),
3. fits the affine map between grid indices (i, j) and grid horizontal coordinates (x, y) (the
   orthographic projection about the scene's reference point, :func:`swim.frames.orthographic_xy`; the scene's
   own 1-D ``x``, ``y`` coordinates where its grid reaches beyond the limb), and records how far the real column
   positions deviate from it.

The result is an :class:`xarray.Dataset`; see :func:`build_optical_volume`.
"""

from __future__ import annotations

import logging

import numpy as np
import xarray as xr

from ..constants import EARTH_RADIUS_M, HYDROMETEOR_DENSITY, SPECIES, WAVELENGTHS_NM
from ..errors import SwimInputError
from ..frames import orthographic_xy
from ..io.scene import DEFAULT_WIND_SPEED_M_S
from ..workers import in_blocks, parallel_map, threads
from .hydrometeors import effective_radius, extinction_coefficient_stephens1978
from .model_aerosol import smoke_extinction

log = logging.getLogger(__name__)

#: Default surface albedo at 615/546/450 nm over land (mixed vegetation and soil) and water.
DEFAULT_LAND_ALBEDO = (0.17, 0.13, 0.08)
DEFAULT_WATER_ALBEDO = (0.04, 0.05, 0.07)


def terrain_slope(terrain, grid_x, grid_y):
    """Gradient of the terrain height with respect to the grid's horizontal coordinates.

    Parameters
    ----------
    terrain : numpy.ndarray
        Shape (ny, nx): terrain height [m].
    grid_x, grid_y : numpy.ndarray
        Shape (ny, nx): horizontal coordinates of the columns [m] (any smooth, non-degenerate grid).

    Returns
    -------
    numpy.ndarray
        Shape (2, ny, nx): dh/dx and dh/dy [-] (central differences in index space, converted to metres with
        the local Jacobian of the grid, one-sided at the edges).
    """
    h = np.asarray(terrain, dtype=float)
    dh_dj, dh_di = np.gradient(h)
    dx_dj, dx_di = np.gradient(np.asarray(grid_x, dtype=float))
    dy_dj, dy_di = np.gradient(np.asarray(grid_y, dtype=float))
    det = dx_di * dy_dj - dx_dj * dy_di
    det = np.where(np.abs(det) > 0, det, np.inf)
    # [dh/dx, dh/dy] = J^-T [dh/di, dh/dj] with J = [[dx/di, dx/dj], [dy/di, dy/dj]]
    dh_dx = (dy_dj * dh_di - dy_di * dh_dj) / det
    dh_dy = (-dx_dj * dh_di + dx_di * dh_dj) / det
    return np.stack([dh_dx, dh_dy])


def fit_grid_affine(x, y):
    """Least-squares affine map between grid indices and horizontal coordinates.

    Parameters
    ----------
    x, y : numpy.ndarray
        Shape (ny, nx): horizontal coordinates [m] of the grid columns.

    Returns
    -------
    origin : numpy.ndarray
        Shape (2,): (x, y) [m] of index (i=0, j=0).
    matrix : numpy.ndarray
        Shape (2, 2): columns are d(x, y)/di and d(x, y)/dj [m per index].
    max_residual : float
        Largest distance [m] between a column and its affine position.
    """
    ny, nx = x.shape
    jj, ii = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    design = np.stack([np.ones(ii.size), ii.ravel(), jj.ravel()], axis=1)
    coef, *_ = np.linalg.lstsq(design, np.stack([x.ravel(), y.ravel()], axis=1), rcond=None)
    fitted = design @ coef
    residual = np.hypot(*(fitted - np.stack([x.ravel(), y.ravel()], axis=1)).T)
    return coef[0], coef[1:].T.copy(), float(residual.max())


def polynomial_features(u, v, xp=np):
    """The 10 monomials of a cubic in (u, v) [-]: shape ``broadcast(u, v).shape + (10,)``.

    ``xp`` is numpy or jax.numpy, so the same map serves the host and the kernels.
    """
    return xp.stack([xp.ones_like(u), u, v, u * u, u * v, v * v, u * u * u, u * u * v, u * v * v, v * v * v], axis=-1)


def fit_grid_index_map(x, y):
    """Least-squares cubic map from horizontal coordinates (x, y) [m] to fractional grid indices (i, j).

    Map-projected grids (Mercator, Lambert, polar stereographic) are not affine in the orthographic
    coordinates of :mod:`swim.frames`; a cubic in normalised coordinates follows them closely (it is exact
    for regular grids).

    Parameters
    ----------
    x, y : numpy.ndarray
        Shape (ny, nx): horizontal coordinates [m] of the grid columns.

    Returns
    -------
    centre : numpy.ndarray
        Shape (2,) [m]; ``scale`` : float [m]; the map takes ``u = (x - centre_x) / scale``, likewise v.
    coefficients : numpy.ndarray
        Shape (2, 10): i and j as cubics in (u, v) (:func:`polynomial_features`).
    max_residual : float
        Largest index error of the fit [grid cells].
    """
    ny, nx = x.shape
    jj, ii = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    centre = np.array([x.mean(), y.mean()])
    scale = float(max(np.ptp(x), np.ptp(y), 1.0) / 2)
    features = polynomial_features((x.ravel() - centre[0]) / scale, (y.ravel() - centre[1]) / scale)
    target = np.stack([ii.ravel(), jj.ravel()], axis=1).astype(float)
    coef, *_ = np.linalg.lstsq(features, target, rcond=None)
    residual = np.abs(features @ coef - target).max()
    return centre, scale, coef.T.copy(), float(residual)


def grid_indices(attrs, x, y, xp=np):
    """Fractional grid indices (i, j) of horizontal coordinates (x, y) [m] with the map stored in ``attrs``.

    Inside the bounding box of the grid's columns (``index_map_bounds``, normalised coordinates) the cubic of
    :func:`fit_grid_index_map`; beyond it the cubic's tangent plane at the nearest point of the box, because a
    cubic extrapolated far outside the grid runs away (a point 26 km north of a 2.5 km grid came out 14 cells
    off), and the terrain and surface beyond the grid are looked up by these indices.
    """
    cx, cy = attrs["index_map_centre"]
    scale = attrs["index_map_scale"]
    coef = xp.asarray(attrs["index_map_coefficients"]).reshape(2, 10)
    u = (x - cx) / scale
    v = (y - cy) / scale
    bounds = attrs.get("index_map_bounds") if hasattr(attrs, "get") else None
    if bounds is None:
        return _cubic(u, v, coef[0]), _cubic(u, v, coef[1])
    uc = xp.clip(u, bounds[0], bounds[1])
    vc = xp.clip(v, bounds[2], bounds[3])
    du, dv = u - uc, v - vc
    return tuple(_cubic(uc, vc, c) + _cubic_du(uc, vc, c) * du + _cubic_dv(uc, vc, c) * dv for c in coef)


# The cubic of polynomial_features and its derivatives written out (Horner-like): elementwise arithmetic that
# the JAX kernels fuse, where stacking the monomials and a matrix product would be separate operations.
def _cubic(u, v, c):
    return c[0] + u * (c[1] + u * (c[3] + u * c[6]) + v * (c[4] + v * c[8])) + v * (c[2] + v * (c[5] + v * c[9])) + u * u * v * c[7]


def _cubic_du(u, v, c):
    return c[1] + u * (2 * c[3] + 3 * c[6] * u + 2 * c[7] * v) + v * (c[4] + c[8] * v)


def _cubic_dv(u, v, c):
    return c[2] + v * (2 * c[5] + 3 * c[9] * v + 2 * c[8] * u) + u * (c[4] + c[7] * u)


def _regular_levels(height, terrain, dz=None, max_levels=160):
    """Bottom, spacing and count of the regular levels that cover the model column heights."""
    bottom = float(min(np.min(terrain), np.min(height[0])))
    thickness = np.diff(height, axis=0)
    top = float(np.max(height[-1]) + 0.5 * np.max(thickness[-1]))
    if dz is None:
        # The finest typical layer of the model, but no more than max_levels levels.
        dz = float(np.min(np.median(thickness.reshape(thickness.shape[0], -1), axis=1)))
        dz = max(dz, (top - bottom) / (max_levels - 1))
    n = int(np.ceil((top - bottom) / dz)) + 1
    return bottom, float(dz), n


#: Bytes of one float64 temporary of :func:`build_optical_volume`'s blocks of rows.
_BLOCK_BYTES = 16 * 2**20


class ColumnInterpolation:
    """Weights of :func:`resample_columns` from model levels to regular levels, computed once per grid.

    ``k0`` (nk, ncol) int32: the model level at or below each target level (clipped to [0, nz - 2]); ``w``
    (nk, ncol) float32: the weight of level k0 + 1; ``zero`` (nk, ncol) bool: target levels below the terrain
    or above half a layer over the top model level. The heights must increase along the first axis in every column
    (as :func:`swim.io.scene.validate_scene` ensures) and the levels must increase.
    """

    def __init__(self, height, terrain, levels):
        height = np.asarray(height, dtype=float)
        nz = height.shape[0]
        h = height.reshape(nz, -1)
        ncol = h.shape[1]
        levels = np.asarray(levels, dtype=float)
        nk = levels.size
        # int32 and float32 keep the (nk, ncol) work arrays small (heights to a millimetre at 20 km).
        self.k0 = np.empty((nk, ncol), dtype=np.int32)
        self.w = np.empty((nk, ncol), dtype=np.float32)
        self.zero = np.empty((nk, ncol), dtype=bool)  # below the terrain or above half a layer over the top level
        top = h[-1] + 0.5 * (h[-1] - h[-2])
        ground = np.asarray(terrain, dtype=float).reshape(-1)
        from .columns_cpu import column_weights

        # one compiled pass per block of columns (a merge of each column's model levels with the regular ones), on
        # every core: NumPy's searchsorted per model level, running counts and takes per level, 0.3 s for 400 x 400
        # x 60 (docs/decisions/0007-scene-set-up.md), gave the same values
        in_blocks(lambda c0, c1: column_weights(h[:, c0:c1], levels, top[c0:c1], ground[c0:c1], self.k0[:, c0:c1],
                                                self.w[:, c0:c1], self.zero[:, c0:c1]), ncol)
        self.shape = (levels.size,) + height.shape[1:]
        self._spans = {}  # (c0, c1) -> the lowest and highest model level each target level reads there

    def __call__(self, values):
        """The field (nz, ny, nx) on the regular levels, (nk, ny, nx) float32."""
        out = self.columns(values, 0, int(np.prod(self.shape[1:])))
        return out.reshape(self.shape)

    def columns(self, values, c0, c1):
        """Columns ``c0:c1`` (of the flattened (y, x)) of a field on the regular levels, (nk, c1 - c0) float32.

        ``values`` (nz, ...) holds those columns only (any shape whose trailing axes flatten to c1 - c0), so a
        big grid can be resampled in blocks of rows, each with small temporaries. A target level whose model
        levels either side are zero in every one of these columns is zero, without interpolating: a cloud
        species fills a few of a model's levels (docs/decisions/0007-scene-set-up.md)."""
        n = c1 - c0
        v = np.ascontiguousarray(values, dtype=np.float32).reshape(-1)
        nz = values.shape[0]
        if v.size != nz * n:
            raise ValueError(f"values hold {v.size // max(nz, 1)} columns per level, not c1 - c0 = {n}")
        cols = np.arange(n)
        out = np.zeros((self.k0.shape[0], n), dtype=np.float32)
        for k in np.flatnonzero(self._reads_values(v.reshape(nz, n), c0, c1)):
            row = out[k]  # one flat take per target level
            below = self.k0[k, c0:c1] * np.intp(n) + cols
            lower = v.take(below)
            v.take(below + n, out=row)
            row -= lower
            row *= self.w[k, c0:c1]
            row += lower
            row[self.zero[k, c0:c1]] = 0.0
        return out

    def cells(self, where, values, nz, c0, c1, out=None):
        """Columns ``c0:c1`` of a sparse field on the regular levels, (nk, c1 - c0) float32: the same values as
        :meth:`columns` of the dense field, which is zero but at the flat positions ``where`` (int64, increasing, C
        order of its shape (nz, c1 - c0)), where it holds ``values`` (float32). One compiled pass over the target
        levels that may read those cells (:func:`swim.optics.columns_cpu.resample_cells`), written into ``out``
        ((nk, c1 - c0) float32 of zeros, e.g. a view of the volume; a new array if None)."""
        n = c1 - c0
        if out is None:
            out = np.zeros((self.k0.shape[0], n), dtype=np.float32)
        if where.size == 0:
            return out
        span_lo, span_hi = self._span(c0, c1)
        # the target levels whose model levels meet those with values: a range, since both bounds grow with the level
        meets = np.flatnonzero((span_hi >= where[0] // n) & (span_lo <= where[-1] // n))
        if meets.size:
            from .columns_cpu import resample_cells

            resample_cells(where, values, nz, self.k0[:, c0:c1], self.w[:, c0:c1], self.zero[:, c0:c1],
                           int(meets[0]), int(meets[-1]) + 1, out)
        return out

    def _span(self, c0, c1):
        """The lowest and the highest model level (nk,) that each target level reads in columns ``c0:c1`` (all fields
        share them)."""
        key = (c0, c1)
        span = self._spans.get(key)
        if span is None:
            k0 = self.k0[:, c0:c1]
            span = self._spans[key] = (k0.min(axis=1), k0.max(axis=1) + 1)
        return span

    def _reads_values(self, values, c0, c1):
        """(nk,) bool: whether target level k reads a model level that is not zero in every column of ``values``
        (nz, c1 - c0), i.e. whether some column's levels k0 or k0 + 1 there hold a value."""
        lowest, highest = self._span(c0, c1)
        # nonzero model levels counted from the bottom: any in [lowest, highest] is a difference of two counts
        count = np.concatenate(([0], np.cumsum(np.any(values != 0, axis=1))))
        return count[highest + 1] > count[lowest]


def resample_columns(values, height, terrain, levels, interpolation: ColumnInterpolation | None = None):
    """Linear interpolation of column profiles onto common regular levels.

    Parameters
    ----------
    values : numpy.ndarray
        Shape (nz, ny, nx) on the model levels.
    height : numpy.ndarray
        Shape (nz, ny, nx): height [m] of the model levels, increasing with the first index.
    terrain : numpy.ndarray
        Shape (ny, nx): terrain height [m]; output is zero below it.
    levels : numpy.ndarray
        Shape (nk,): regular target heights [m].
    interpolation : ColumnInterpolation, optional
        The weights for these heights and levels, when several fields share them.

    Returns
    -------
    numpy.ndarray
        Shape (nk, ny, nx). Between the terrain and the lowest model level the lowest value is kept; above
        half a layer over the top model level the result is zero.
    """
    if interpolation is None:
        interpolation = ColumnInterpolation(height, terrain, levels)
    return interpolation(values)


def default_surface_albedo(land_mask):
    """Spectral albedo (3, ny, nx) [-] at 615/546/450 nm from a land mask (1 land, 0 water)."""
    land = np.asarray(land_mask, dtype=float)[None]
    return land * np.array(DEFAULT_LAND_ALBEDO)[:, None, None] + (1 - land) * np.array(DEFAULT_WATER_ALBEDO)[:, None, None]


def _column_xy(scene: xr.Dataset, lat0, lon0):
    """The columns' orthographic (x, y) [m], each (y, x): ``orthographic_xy(lat, lon)``; of a grid with 1-D ``x`` and
    ``y`` coordinates that reaches beyond the limb (some column with ``x^2 + y^2 >= R^2``, whose lat/lon cannot give
    its place: ``swim.io.globe.hemisphere_scene``) ``np.meshgrid(x, y)``, which places a regular grid exactly however
    far it reaches. (Inside the limb the two agree to ~1e-9 m, and an index map fitted to either is the same to
    1e-14 of a cell; the columns' lat/lon keep the renders of such grids as they were, bit for bit.)"""
    if all(axis in scene.coords and scene[axis].dims == (axis,) for axis in ("x", "y")):
        gx, gy = np.meshgrid(np.asarray(scene["x"].values, dtype=float), np.asarray(scene["y"].values, dtype=float))
        if np.any(gx**2 + gy**2 >= EARTH_RADIUS_M**2):
            return gx, gy
    return orthographic_xy(scene["lat"].values, scene["lon"].values, lat0, lon0)


def _grid_maps(scene: xr.Dataset, lat0, lon0):
    """The columns' orthographic (x, y) [m] (y, x) (:func:`_column_xy`) and the attributes of their affine fit and
    cubic index map."""
    gx, gy = _column_xy(scene, lat0, lon0)
    origin, matrix, residual = fit_grid_affine(gx, gy)
    spacing = float(np.sqrt(abs(np.linalg.det(matrix))))
    centre, scale, coefficients, index_residual = fit_grid_index_map(gx, gy)
    index_bounds = np.array([(gx.min() - centre[0]) / scale, (gx.max() - centre[0]) / scale,
                             (gy.min() - centre[1]) / scale, (gy.max() - centre[1]) / scale])
    log.info("grid: affine fit within %.0f m, cubic index map within %.3f cells (spacing %.0f m)",
             residual, index_residual, spacing)
    if index_residual > 0.25:
        log.warning("grid columns deviate up to %.2f cells from a smooth map; cloud positions are approximate",
                    index_residual)
    return gx, gy, {
        "affine_origin": origin,
        "affine_matrix": matrix.ravel(),
        "affine_max_residual_m": residual,
        "index_map_centre": centre,
        "index_map_scale": scale,
        "index_map_coefficients": coefficients.ravel(),
        "index_map_bounds": index_bounds,
        "index_map_max_residual_cells": index_residual,
    }


def _resampled_extinction(scene: xr.Dataset, height, terrain, levels):
    """Hydrometeor (species, level, y, x) and 3-D aerosol (level, y, x) extinction [m-1] on the regular levels.

    Also returns, per species, the (sum of beta r_eff, sum of beta) of each block of rows, for the
    extinction-weighted mean effective radius.

    Raises
    ------
    SwimInputError
        If a ``<species>_content`` is negative or not finite.
    """
    nz, ny, nx = height.shape
    nk = levels.size
    extinction = np.zeros((len(SPECIES), nk, ny, nx), dtype=np.float32)
    interpolation = ColumnInterpolation(height, terrain, levels)
    # Eq. 7 and the resampling in blocks of rows: the float64 temporaries of a species (content, radius,
    # extinction, masks) then take ~16 MB each instead of a whole field each (~77 MB each for 400 x 400 x 60),
    # which set the peak memory of a render of a big grid (docs/performance.md, "Memory"). The blocks run on every
    # core (NumPy releases the GIL), each thread's blocks that much smaller, so the temporaries stay ~16 MB each.
    workers = threads()
    rows = max(1, min(ny, _BLOCK_BYTES // (8 * nz * nx * workers)))
    flat = extinction.reshape(len(SPECIES), nk, ny * nx)
    blocks = [(j0, min(j0 + rows, ny)) for j0 in range(0, ny, rows)]
    # the extinction-weighted mean effective radius of each species [m] (its phase function's, in the 3-D cloud
    # scattering: swim.optics.cloud_phase), from sums per block of rows
    radius_sums = {species: [] for species in SPECIES}
    for n, species in enumerate(SPECIES):
        if f"{species}_content" in scene:
            _species_extinction(scene, n, species, interpolation, flat[n], blocks, workers, radius_sums[species])

    if "aerosol_extinction" in scene or "smoke_mass_content" in scene:
        aerosol = np.empty((nk, ny * nx), np.float32)
        values = _aerosol_extinction_550(scene)

        def aerosol_block(block):
            j0, j1 = block
            aerosol[:, j0 * nx:j1 * nx] = interpolation.columns(values[:, j0:j1], j0 * nx, j1 * nx)

        parallel_map(aerosol_block, blocks, workers)
        aerosol = aerosol.reshape(nk, ny, nx)
    else:
        # no 3-D aerosol: a read-only broadcast of zero, which takes no memory (100 MB at 400 x 400 x 160)
        aerosol = np.broadcast_to(np.float32(0.0), (nk, ny, nx))
    return extinction, aerosol, radius_sums


def _aerosol_extinction_550(scene: xr.Dataset) -> np.ndarray:
    """The scene's 3-D aerosol extinction at 550 nm [m-1] (z, y, x): ``aerosol_extinction`` plus the extinction of
    ``smoke_mass_content`` [kg m-3] through the smoke's mass extinction efficiency
    (:func:`swim.optics.model_aerosol.smoke_extinction`)."""
    values = scene["aerosol_extinction"].values if "aerosol_extinction" in scene else 0.0
    if "smoke_mass_content" in scene:
        values = values + smoke_extinction(scene["smoke_mass_content"].values)
    return values


def _species_extinction(scene: xr.Dataset, n, species, interpolation: ColumnInterpolation, flat, blocks, workers,
                        radius_sums):
    """Eq. 7 for one species, block of rows by block, resampled in place into ``flat`` (level, y * x).

    Appends each block's (sum of beta r_eff, sum of beta) to ``radius_sums``.

    Raises
    ------
    SwimInputError
        If the species' content is negative or not finite.
    """
    nz, _, nx = scene["height"].shape
    name = f"{species}_content"
    content_all = scene[name].values  # each block checks its content and skips itself where it has none
    radius_name = f"{species}_effective_radius"
    radius_all = scene[radius_name].values if radius_name in scene else None

    def eq7_block(block):
        from .columns_cpu import gather_cells, scan_content

        j0, j1 = block
        content = content_all[:, j0:j1]  # a view: the compiled scan reads it in place
        cells = nz * (j1 - j0) * nx
        where, values = np.empty(cells, np.int64), np.empty(cells, np.float64)
        # one pass: the check of the values and the cloudy cells (1-10 % of a model's cells), where Eq. 7 is
        # computed: elsewhere beta is 0 (docs/decisions/0007-scene-set-up.md)
        bad, present = scan_content(content, where, values)
        if bad:
            content = np.asarray(content, dtype=float)
            wrong = ~np.isfinite(content) | (content < 0)
            raise SwimInputError(f"{name} must be finite and >= 0 [kg m-3]; got {int(wrong.sum())} values such as "
                                 f"{content[wrong].flat[0]!r}")
        if present == 0:
            return  # the block's extinction stays 0
        where, values = where[:present], values[:present]
        given = None
        if radius_all is not None:
            given = np.empty(present, np.float64)
            gather_cells(radius_all[:, j0:j1], where, given)
        radius = effective_radius(species, values, given)
        beta = extinction_coefficient_stephens1978(values, radius, HYDROMETEOR_DENSITY[species]).astype(np.float32)
        radius_sums.append((float(np.dot(beta, radius)), float(beta.sum(dtype=np.float64))))
        interpolation.cells(where, beta, nz, j0 * nx, j1 * nx, out=flat[:, j0 * nx:j1 * nx])  # in place

    parallel_map(eq7_block, blocks, workers)  # an error in a block (bad values) is raised here


def _surface_fields(scene: xr.Dataset, terrain):
    """Land fraction, surface albedo (wavelength, y, x), snow cover and 10 m wind speed [m s-1] of the scene."""
    ny, nx = terrain.shape
    land = scene["land_mask"].values.astype(float) if "land_mask" in scene else (terrain > 0.5).astype(float)
    if "surface_albedo" in scene:
        albedo = scene["surface_albedo"].transpose("wavelength", "y", "x").values.astype(float)
    else:
        albedo = default_surface_albedo(land)
    snow = scene["snow_cover"].values.astype(float) if "snow_cover" in scene else np.zeros((ny, nx))
    wind = (scene["wind_speed_10m"].values.astype(float) if "wind_speed_10m" in scene
            else np.full((ny, nx), DEFAULT_WIND_SPEED_M_S))
    return land, albedo, snow, wind


def build_optical_volume(scene: xr.Dataset, dz: float | None = None, max_levels: int = 160) -> xr.Dataset:
    """Optical properties of a canonical scene on a regular height grid.

    Parameters
    ----------
    scene : xarray.Dataset
        Canonical scene (validated; docs/scene-format.md), dims (z, y, x).
    dz : float, optional
        Spacing of the regular levels [m]; default: the finest median model layer, with at most
        ``max_levels`` levels.
    max_levels : int
        Upper bound on the number of regular levels.

    Returns
    -------
    xarray.Dataset
        ``extinction`` (species, level, y, x) [m-1] for the hydrometeor species of
        :data:`swim.constants.SPECIES`; ``aerosol_extinction`` (level, y, x) [m-1 at 550 nm];
        ``terrain_height`` (y, x) [m]; ``surface_albedo`` (wavelength, y, x) [-]; ``land_fraction`` (y, x)
        [-] (the scene's ``land_mask``, else terrain > 0.5 m); ``snow_cover`` (y, x) [-] (default 0);
        ``wind_speed_10m`` (y, x) [m s-1] (default :data:`swim.io.scene.DEFAULT_WIND_SPEED_M_S`); ``terrain_slope``
        (component, y, x) [-] (:func:`terrain_slope`); ``grid_x``, ``grid_y`` (y, x) [m]; coordinate ``level`` [m above sea level]. Attributes: ``reference_lat``,
        ``reference_lon`` [deg], ``z_bottom``, ``dz`` [m], ``affine_origin`` (2,) [m], ``affine_matrix``
        (4,) [m] (row-major 2x2, columns d/di and d/dj), ``affine_max_residual_m``; the cubic index map ``index_map_centre``, ``index_map_scale``,
        ``index_map_coefficients`` (20,), ``index_map_bounds`` (4,) and ``index_map_max_residual_cells``
        (:func:`grid_indices`).

    Raises
    ------
    SwimInputError
        If the grid is degenerate (fewer than 2 columns in x or y or 2 levels), or a ``<species>_content`` is
        negative or not finite (the message names it; :func:`swim.io.scene.validate_scene` refuses such scenes
        first).

    References
    ----------
    Albers et al. (2020), Eq. 7, doi:10.5194/amt-13-3235-2020.
    """
    nz, ny, nx = scene["height"].shape
    if nz < 2 or ny < 2 or nx < 2:
        raise SwimInputError(f"scene grid must have at least 2 points along z, y and x; got (z, y, x) = {(nz, ny, nx)}")
    lat0 = float(scene.attrs["reference_lat"])
    lon0 = float(scene.attrs["reference_lon"])
    height = np.asarray(scene["height"].values, dtype=float)  # no copy of a validated scene's float64
    terrain = np.asarray(scene["terrain_height"].values, dtype=float)

    gx, gy, grid_attrs = _grid_maps(scene, lat0, lon0)

    bottom, dz, nk = _regular_levels(height, terrain, dz, max_levels)
    levels = bottom + dz * np.arange(nk)
    log.info("optical volume: %d x %d columns, %d regular levels of %.1f m from %.0f m", nx, ny, nk, dz, bottom)

    extinction, aerosol, radius_sums = _resampled_extinction(scene, height, terrain, levels)
    land, albedo, snow, wind = _surface_fields(scene, terrain)

    return xr.Dataset(
        {
            "extinction": (("species", "level", "y", "x"), extinction, {"units": "m-1", "long_name": "extinction coefficient (Eq. 7)"}),
            "aerosol_extinction": (("level", "y", "x"), aerosol, {"units": "m-1", "long_name": "aerosol extinction coefficient at 550 nm"}),
            "terrain_height": (("y", "x"), terrain, {"units": "m"}),
            "surface_albedo": (("wavelength", "y", "x"), albedo, {"units": "1"}),
            "land_fraction": (("y", "x"), land, {"units": "1", "long_name": "land fraction (1 land, 0 water)"}),
            "snow_cover": (("y", "x"), snow, {"units": "1", "long_name": "snow-covered fraction of the land"}),
            "wind_speed_10m": (("y", "x"), wind, {"units": "m s-1", "long_name": "wind speed at 10 m (sun glint)"}),
            "terrain_slope": (("component", "y", "x"), terrain_slope(terrain, gx, gy),
                              {"units": "1", "long_name": "terrain gradient dh/dx, dh/dy"}),
            "grid_x": (("y", "x"), gx, {"units": "m"}),
            "grid_y": (("y", "x"), gy, {"units": "m"}),
        },
        coords={"species": list(SPECIES), "level": ("level", levels, {"units": "m"}), "wavelength": ("wavelength", WAVELENGTHS_NM, {"units": "nm"})},
        attrs={
            "reference_lat": lat0,
            "reference_lon": lon0,
            "z_bottom": bottom,
            "dz": dz,
            **grid_attrs,
            "mean_effective_radius_m": np.array([
                sum(a for a, _ in radius_sums[sp]) / max(sum(b for _, b in radius_sums[sp]), 1e-30)
                if radius_sums[sp] else np.nan for sp in SPECIES]),
        },
    )
