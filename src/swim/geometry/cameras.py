"""Camera models: the map between image pixels and view directions in the observer's local ENU frame.

All conventions are those of :mod:`swim.frames` and ``docs/frames.md``:

* view directions are unit vectors in the **observer's local ENU frame** (x east, y north, z up), pointing
  *away from the observer* towards what the pixel sees;
* azimuth [deg] is clockwise from north, zenith [deg] from the local vertical;
* images are arrays of shape ``(ny, nx)``; row 0 is the **top** of the image, column 0 its **left** edge;
* **pixel-centre convention**: continuous pixel coordinates ``(row, col)`` are chosen such that the centre
  of pixel ``(i, j)`` is exactly ``(i, j)``; pixel ``(i, j)`` covers ``[i - 0.5, i + 0.5) x
  [j - 0.5, j + 0.5)``, so the image spans ``row`` in ``[-0.5, ny - 0.5]`` and ``col`` in
  ``[-0.5, nx - 0.5]``; the nearest pixel of a continuous coordinate is ``round(row), round(col)``.

Every camera offers the same interface (:class:`Camera`): ``shape``, ``kind``, ``directions()``,
``pixel_of_direction(dirs_enu)`` and ``to_attrs()``. The three cameras are

* :class:`AllSkyCamera` - polar equidistant fisheye looking straight up: zenith at the image centre, north
  up, east **left** (the sky seen from below), west right;
* :class:`PanoramaCamera` - cylindrical equirectangular: azimuth linear in the column, elevation linear in
  the row;
* :class:`PerspectiveCamera` - pinhole (rectilinear) camera with a horizontal field of view, a view
  direction and a roll angle.

The map between pixels and directions is purely geometric: it knows nothing about where the observer is.
:func:`look_at_angles` and :func:`fov_to_fit` help to point a :class:`PerspectiveCamera` at a target.

Sources: the equidistant fisheye ("f-theta") and equirectangular projections, e.g. Snyder (1987), Map
Projections - A Working Manual, USGS Prof. Paper 1395; the all-sky orientation follows the SWIm all-sky
imagery (Albers et al. 2020, AMT 13, 3235-3261, Sect. 2 and Fig. 1: north up, east left).
"""

from __future__ import annotations

import functools
import logging
import math
import numbers
from abc import ABC, abstractmethod
from dataclasses import MISSING, dataclass, fields
from typing import Any, ClassVar

import numpy as np

from .. import frames
from ..constants import EARTH_RADIUS_M
from ..errors import SwimInputError

__all__ = [
    "Camera",
    "AllSkyCamera",
    "PanoramaCamera",
    "PerspectiveCamera",
    "CAMERA_KINDS",
    "make_camera",
    "check_camera_options",
    "look_at_angles",
    "fov_to_fit",
]

logger = logging.getLogger(__name__)

#: Below this horizontal component [-] of the unit view axis a perspective camera counts as looking straight
#: up or down, and its image up is north instead of the (undefined) projection of the local up.
VERTICAL_VIEW_TOLERANCE = 1e-6

_PIXEL_CONVENTION = "pixel (i, j) centre at (row, col) = (i, j); row 0 = top; col 0 = left"


# --------------------------------------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------------------------------------
def _as_int(name: str, value: Any, minimum: int = 1) -> int:
    """Integer >= minimum or :class:`SwimInputError`."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        if isinstance(value, numbers.Real) and not isinstance(value, bool) and float(value).is_integer():
            value = int(value)
        else:
            raise SwimInputError(f"{name} must be an integer >= {minimum} [pixels], got {value!r}")
    value = int(value)
    if value < minimum:
        raise SwimInputError(f"{name} must be an integer >= {minimum} [pixels], got {value}")
    return value


def _as_float(name: str, value: Any, lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
              hi_open: bool = False, unit: str = "deg") -> float:
    """Finite float within [lo, hi] (ends optionally open) or :class:`SwimInputError`."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        try:
            value = float(np.asarray(value, dtype=float).item())
        except (TypeError, ValueError):
            raise SwimInputError(f"{name} must be a real number [{unit}], got {value!r}") from None
    value = float(value)
    lo_s = "(" if lo_open else "["
    hi_s = ")" if hi_open else "]"
    rng = f"{lo_s}{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}{hi_s}"
    if not math.isfinite(value):
        raise SwimInputError(f"{name} must be finite, in {rng} [{unit}], got {value}")
    if lo is not None and (value < lo or (lo_open and value == lo)):
        raise SwimInputError(f"{name} must be in {rng} [{unit}], got {value}")
    if hi is not None and (value > hi or (hi_open and value == hi)):
        raise SwimInputError(f"{name} must be in {rng} [{unit}], got {value}")
    return value


def _as_directions(dirs_enu: Any) -> tuple[np.ndarray, np.ndarray]:
    """Normalised float64 copy of ``(..., 3)`` directions and a mask of the usable (finite, non-zero) ones."""
    d = np.asarray(dirs_enu, dtype=float)
    if d.ndim == 0 or d.shape[-1] != 3:
        raise SwimInputError(f"dirs_enu must have shape (..., 3) (east, north, up), got shape {d.shape}")
    norm = np.linalg.norm(d, axis=-1)
    ok = np.isfinite(norm) & (norm > 0.0)
    d = d / np.where(ok, norm, 1.0)[..., None]
    return d, ok


def _pixel_centres(ny: int, nx: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of all pixel centres, each of shape ``(ny, nx)`` (float64)."""
    rows, cols = np.meshgrid(np.arange(ny, dtype=float), np.arange(nx, dtype=float), indexing="ij")
    return rows, cols


#: Pixels per block of :func:`_view_angles` [-]: its float64 temporaries (~70 bytes a pixel) for a block at a time
#: rather than the whole image, whose first render computes them after the march, with the image's planes alive
#: (at 2048^2 the render's peak was there: docs/decisions/0010-memory.md).
VIEW_ANGLE_BLOCK = 1 << 16


def _view_angles(camera, block=VIEW_ANGLE_BLOCK):
    """View azimuth and zenith [deg] (float32, NaN where not valid) of every pixel, in blocks of ``block`` pixels."""
    dirs, valid = camera.cached_directions()
    flat_dirs, flat_valid = dirs.reshape(-1, 3), valid.reshape(-1)
    azimuth = np.empty(flat_valid.size, np.float32)
    zenith = np.empty(flat_valid.size, np.float32)
    for start in range(0, flat_valid.size, block):
        part = slice(start, start + block)
        azimuth[part], zenith[part] = frames.azimuth_zenith_from_enu(
            np.where(flat_valid[part, None], flat_dirs[part], np.nan))
    return azimuth.reshape(valid.shape), zenith.reshape(valid.shape)


@functools.lru_cache(maxsize=2)
def _view_angles_of(camera):
    angles = _view_angles(camera)
    for a in angles:
        a.flags.writeable = False
    return angles


@functools.lru_cache(maxsize=2)
def _directions_of(camera):
    dirs, valid = camera.directions()
    dirs.flags.writeable = False
    valid.flags.writeable = False
    return dirs, valid


# --------------------------------------------------------------------------------------------------------
# common interface
# --------------------------------------------------------------------------------------------------------
class Camera(ABC):
    """Common interface of the SWIm cameras.

    Attributes
    ----------
    kind : str
        ``"allsky"``, ``"panorama"`` or ``"perspective"`` (class attribute).
    shape : tuple of int
        ``(ny, nx)``: number of image rows and columns.
    """

    kind: ClassVar[str] = ""

    @property
    @abstractmethod
    def shape(self) -> tuple[int, int]:
        """``(ny, nx)``: number of image rows and columns."""

    @abstractmethod
    def directions(self) -> tuple[np.ndarray, np.ndarray]:
        """View directions of all pixel centres.

        Returns
        -------
        dirs : numpy.ndarray
            float64, shape ``(ny, nx, 3)``: unit view directions (east, north, up) [-] in the observer's local
            ENU frame, pointing away from the observer; NaN where ``valid`` is False.
        valid : numpy.ndarray
            bool, shape ``(ny, nx)``: True where the pixel centre images a direction.
        """

    def cached_directions(self) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`directions`, computed once for the last two cameras (equal cameras share them) and read-only:
        a render asks for them twice (the crop and the rays) and the renders of a series once more each."""
        try:
            return _directions_of(self)
        except TypeError:  # a camera with unhashable options is computed every time
            return self.directions()

    def cached_view_angles(self) -> tuple[np.ndarray, np.ndarray]:
        """View azimuth and zenith angle [deg] of every pixel (float32, NaN where not ``valid``; azimuth clockwise
        from north, :func:`swim.frames.azimuth_zenith_from_enu`), computed once for the last two cameras and
        read-only, like :meth:`cached_directions`."""
        try:
            return _view_angles_of(self)
        except TypeError:  # a camera with unhashable options is computed every time
            return _view_angles(self)

    @abstractmethod
    def pixel_of_direction(self, dirs_enu) -> tuple[np.ndarray, np.ndarray]:
        """Continuous pixel coordinates of view directions (inverse of :meth:`directions`).

        Parameters
        ----------
        dirs_enu : array_like
            Shape ``(..., 3)``: directions (east, north, up) in the observer's local ENU frame, pointing away
            from the observer; need not be unit length.

        Returns
        -------
        row, col : numpy.ndarray
            float64, each of shape ``dirs_enu.shape[:-1]``; the centre of pixel ``(i, j)`` is ``(i, j)``.
            NaN where the direction is not imaged (outside the field of view, zero or non-finite).

        Raises
        ------
        SwimInputError
            If ``dirs_enu`` does not have a last axis of length 3.
        """

    @abstractmethod
    def to_attrs(self) -> dict[str, Any]:
        """Plain scalars and strings describing the camera (for netCDF attributes); keys start with ``camera_``."""

    def _base_attrs(self) -> dict[str, Any]:
        ny, nx = self.shape
        return {
            "camera_kind": self.kind,
            "camera_ny": int(ny),
            "camera_nx": int(nx),
            "camera_frame": "observer local ENU (x east, y north, z up); view directions point away from the observer",
            "camera_pixel_convention": _PIXEL_CONVENTION,
        }


def stokes_pixel_solid_angles(g_over_r2, rim, u_lines, v_lines):
    """Solid angles of the pixels of a radially symmetric image-plane projection, by Stokes' theorem.

    A projection whose solid-angle density in the image plane is the exterior derivative of the 1-form
    ``g(r) dpsi`` (``psi`` the polar angle about the optical centre) gives each pixel square the line integral of
    ``g dpsi = g (u dv - v du) / r^2`` round its edges. Every edge is integrated with 16-point Gauss-Legendre
    quadrature, split where it crosses the rim (``|u| = sqrt(rim^2 - v^2)``, a kink of ``g(min(r, rim))``), so
    the result is exact to rounding and neighbouring pixels, which share edges, add up exactly.

    Parameters
    ----------
    g_over_r2 : callable
        r [px] (any shape) -> g(min(r, rim)) / r^2, finite at r = 0.
    rim : float
        Radius of the image circle [px].
    u_lines, v_lines : numpy.ndarray
        Shapes (nx + 1,) and (ny + 1,): pixel edge coordinates from the optical centre [px], columns and rows.

    Returns
    -------
    numpy.ndarray
        Shape (ny, nx): the counter-clockwise line integral per pixel (the signed solid angle [sr] for the
        1-form ``(1 - cos theta) dpsi``, the projected solid angle for ``sin^2(theta) / 2 dpsi``).
    """
    nodes, weights = np.polynomial.legendre.leggauss(16)

    def edge_integrals(lines, lo, hi):
        """H[m, j] = int_{lo_j}^{hi_j} g(r) v_m / r^2 du along the lines v = v_m."""
        v = lines[:, None]
        a = np.broadcast_to(lo[None, :], (v.shape[0], lo.size))
        b = np.broadcast_to(hi[None, :], (v.shape[0], hi.size))
        s = np.sqrt(np.maximum(rim * rim - v * v, 0.0))
        cuts = [a, np.clip(-s, a, b), np.clip(s, a, b), b]
        total = np.zeros(a.shape)
        for p, q in zip(cuts[:-1], cuts[1:]):
            half = 0.5 * (q - p)
            mid = 0.5 * (q + p)
            u = mid[..., None] + half[..., None] * nodes
            r = np.hypot(u, v[..., None])
            total += half * np.sum(weights * g_over_r2(r) * v[..., None], axis=-1)
        return total

    h_rows = edge_integrals(v_lines, u_lines[:-1], u_lines[1:])  # (ny + 1, nx): horizontal edges
    h_cols = edge_integrals(u_lines, v_lines[:-1], v_lines[1:])  # (nx + 1, ny): vertical edges
    # Horizontal edge v = const from u = a to b contributes -int g v / r^2 du; vertical edge u = const from
    # v = a to b contributes +int g u / r^2 dv, the same integral with u and v exchanged (h_cols.T).
    return (h_rows[1:, :] - h_rows[:-1, :]) + (h_cols.T[:, 1:] - h_cols.T[:, :-1])


# --------------------------------------------------------------------------------------------------------
# all-sky fisheye
# --------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class AllSkyCamera(Camera):
    """Polar equidistant ("f-theta") fisheye looking straight up, as seen from below (an all-sky imager).

    The zenith is at the image centre ``c = ((size - 1) / 2, (size - 1) / 2)``; the radial distance from the
    centre is proportional to the zenith angle, ``r = zenith * (size / 2) / max_zenith_deg`` [pixels], so
    that ``max_zenith_deg`` (default 90: the horizon) lies on the rim of the inscribed circle of radius
    ``size / 2``. North is up, **east left**, south down, west right (the sky seen looking up)::

                     N (row 0)
                 .-----------.
               /       |       \\
         E    |  ---- zenith ---- |    W
        (col 0)\\       |       /  (col size-1)
                 '-----------'
                     S

    A direction of azimuth ``az`` and zenith angle ``z`` is imaged at
    ``row = c - r cos(az)``, ``col = c - r sin(az)``. For an odd ``size`` the centre pixel looks exactly at
    the zenith.

    Parameters
    ----------
    size : int, default 511
        Image width and height [pixels], >= 1.
    max_zenith_deg : float, default 90.0
        Zenith angle on the rim of the image circle [deg], in (0, 180]. Values above 90 also image part of the
        sky below the horizon (e.g. for an elevated observer).

    Raises
    ------
    SwimInputError
        If ``size`` is not an integer >= 1 or ``max_zenith_deg`` is outside (0, 180].
    """

    size: int = 511
    max_zenith_deg: float = 90.0

    kind: ClassVar[str] = "allsky"

    def __post_init__(self) -> None:
        object.__setattr__(self, "size", _as_int("size", self.size))
        object.__setattr__(
            self, "max_zenith_deg", _as_float("max_zenith_deg", self.max_zenith_deg, 0.0, 180.0, lo_open=True)
        )

    @property
    def shape(self) -> tuple[int, int]:
        """``(size, size)``."""
        return (self.size, self.size)

    @property
    def centre(self) -> float:
        """Row (= column) of the image centre, ``(size - 1) / 2`` [pixels]."""
        return (self.size - 1) / 2.0

    @property
    def radians_per_pixel(self) -> float:
        """Zenith angle per pixel of radial distance [rad pixel-1]."""
        return math.radians(self.max_zenith_deg) / (self.size / 2.0)

    def directions(self) -> tuple[np.ndarray, np.ndarray]:
        """See :meth:`Camera.directions`; ``valid`` is the disc of radius ``size / 2`` about the centre."""
        rows, cols = _pixel_centres(*self.shape)
        c = self.centre
        k = self.radians_per_pixel
        dx = c - cols  # towards the east (left)
        dy = c - rows  # towards the north (up)
        r = np.hypot(dx, dy)
        valid = r <= self.size / 2.0
        zen = k * r
        # sin(z) / r = k * sinc(z / pi): no singularity at the zenith
        s_over_r = k * np.sinc(zen / np.pi)
        dirs = np.stack([dx * s_over_r, dy * s_over_r, np.cos(zen)], axis=-1)
        dirs[~valid] = np.nan
        return dirs, valid

    def pixel_of_direction(self, dirs_enu) -> tuple[np.ndarray, np.ndarray]:
        """See :meth:`Camera.pixel_of_direction`; NaN for zenith angles above ``max_zenith_deg``."""
        d, ok = _as_directions(dirs_enu)
        h = np.hypot(d[..., 0], d[..., 1])
        zen = np.arctan2(h, d[..., 2])  # accurate near the zenith, unlike arccos
        ok &= zen <= math.radians(self.max_zenith_deg) * (1.0 + 1e-12)
        ok &= ~((h == 0.0) & (d[..., 2] < 0.0))  # the nadir has no azimuth
        # r / h = (zen / k) / h, with the limit 1 / k at the zenith
        r_over_h = np.where(h > 0.0, zen / np.where(h > 0.0, h, 1.0), 1.0) / self.radians_per_pixel
        c = self.centre
        row = np.where(ok, c - r_over_h * d[..., 1], np.nan)
        col = np.where(ok, c - r_over_h * d[..., 0], np.nan)
        return row, col

    def pixel_solid_angles(self, cosine_weighted: bool = False, upper_hemisphere: bool = False) -> np.ndarray:
        """Exact solid angle of every pixel (the part of the pixel square inside the image circle).

        In the image plane the equidistant projection has the solid-angle density
        ``dOmega = k sin(k r) / r du dv`` (``k`` = :attr:`radians_per_pixel`, ``r`` the distance from the centre
        in pixels), which is the exterior derivative of the 1-form ``(1 - cos(k r)) dphi``. By Stokes' theorem
        the solid angle of a pixel square is the line integral of ``(1 - cos(k min(r, R))) dphi`` round its
        edges (``R = size / 2``: the rim); the integral along every pixel edge is evaluated with Gauss-Legendre
        quadrature, split where the edge crosses the rim (where the integrand has a kink), so the result is
        exact to rounding, and because neighbouring pixels share edges the image sums to the solid angle of
        the whole disc, ``2 pi (1 - cos(max_zenith))``. With ``cosine_weighted`` the 1-form is
        ``sin^2(k min(r, R)) / 2 dphi`` and the result is the projected solid angle ``int cos(zenith) dOmega``
        (the image sums to ``pi sin^2(max_zenith)``).

        Parameters
        ----------
        cosine_weighted : bool, default False
            Return ``int_pixel cos(zenith) dOmega`` [sr] instead of ``int_pixel dOmega`` [sr].
        upper_hemisphere : bool, default False
            Count only the part of each pixel above the horizon (zenith <= 90 deg); matters only for
            ``max_zenith_deg > 90``.

        Returns
        -------
        numpy.ndarray
            float64, shape ``(size, size)`` [sr]; 0 for pixels wholly outside the image circle (or below the
            horizon with ``upper_hemisphere``). Sums to 2 pi for the default camera (the upper hemisphere) and
            to pi with ``cosine_weighted``.
        """
        k = self.radians_per_pixel
        rim = self.size / 2.0
        if upper_hemisphere or cosine_weighted:
            # cos(zenith) dOmega is not a density below the horizon: the projected solid angle stops there.
            rim = min(rim, (math.pi / 2.0) / k)

        if cosine_weighted:
            def g_over_r2(r):  # sin^2(k min(r, rim)) / 2 / r^2, finite at r = 0
                rr = np.minimum(r, rim)
                return 0.5 * np.where(r > 0, np.sin(k * rr) ** 2 / np.where(r > 0, r, 1.0) ** 2, k * k)
        else:
            def g_over_r2(r):  # (1 - cos(k min(r, rim))) / r^2 = 2 sin^2(k min(r, rim) / 2) / r^2
                rr = np.minimum(r, rim)
                return np.where(r > 0, 2.0 * np.sin(0.5 * k * rr) ** 2 / np.where(r > 0, r, 1.0) ** 2, 0.5 * k * k)

        lines = np.arange(self.size + 1, dtype=float) - 0.5 - self.centre  # edge coordinates from the centre
        return np.maximum(stokes_pixel_solid_angles(g_over_r2, rim, lines, lines), 0.0)

    def to_attrs(self) -> dict[str, Any]:
        """See :meth:`Camera.to_attrs`."""
        attrs = self._base_attrs()
        attrs.update(
            camera_projection="polar equidistant fisheye (radius proportional to zenith angle)",
            camera_orientation="zenith at centre, north up, east left, west right (sky seen from below)",
            camera_size=int(self.size),
            camera_max_zenith_deg=float(self.max_zenith_deg),
        )
        return attrs


# --------------------------------------------------------------------------------------------------------
# panorama
# --------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PanoramaCamera(Camera):
    """Cylindrical equirectangular panorama: azimuth linear in the column, elevation linear in the row.

    The left image edge (``col = -0.5``) is at ``azimuth_start_deg``; azimuth increases to the right over
    ``azimuth_span_deg`` (default a full turn). The top image edge (``row = -0.5``) is at
    ``elevation_max_deg``, the bottom edge (``row = height - 0.5``) at ``elevation_min_deg``::

        elevation_max  +---------------------------------------------+
                       |                  sky                        |
        horizon (0)    |- - - - - - - - - - - - - - - - - - - - - - -|
                       |                 ground                      |
        elevation_min  +---------------------------------------------+
                   az_start   az_start+90   az_start+180   ...   az_start+span

    So pixel ``(i, j)`` looks at azimuth ``azimuth_start + (j + 0.5) * span / width`` and elevation
    ``elevation_max - (i + 0.5) * (elevation_max - elevation_min) / height``. With ``azimuth_start_deg = 0``
    the boundary between columns ``width/4 - 1`` and ``width/4`` (continuous ``col = width/4 - 0.5``) looks
    east.

    Parameters
    ----------
    width : int, default 1024
        Number of columns [pixels], >= 1.
    height : int, default 512
        Number of rows [pixels], >= 1.
    azimuth_start_deg : float, default 0.0
        Azimuth of the left image edge [deg], any finite value (wrapped into [0, 360)).
    elevation_min_deg : float, default -90.0
        Elevation of the bottom image edge [deg], in [-90, 90).
    elevation_max_deg : float, default 90.0
        Elevation of the top image edge [deg], in (elevation_min_deg, 90].
    azimuth_span_deg : float, default 360.0
        Azimuth range across the image [deg], in (0, 360].

    Raises
    ------
    SwimInputError
        For sizes that are not integers >= 1 or angles outside the ranges above.
    """

    width: int = 1024
    height: int = 512
    azimuth_start_deg: float = 0.0
    elevation_min_deg: float = -90.0
    elevation_max_deg: float = 90.0
    azimuth_span_deg: float = 360.0

    kind: ClassVar[str] = "panorama"

    def __post_init__(self) -> None:
        object.__setattr__(self, "width", _as_int("width", self.width))
        object.__setattr__(self, "height", _as_int("height", self.height))
        az0 = _as_float("azimuth_start_deg", self.azimuth_start_deg) % 360.0
        object.__setattr__(self, "azimuth_start_deg", az0)
        emin = _as_float("elevation_min_deg", self.elevation_min_deg, -90.0, 90.0, hi_open=True)
        object.__setattr__(self, "elevation_min_deg", emin)
        emax = _as_float("elevation_max_deg", self.elevation_max_deg, emin, 90.0, lo_open=True)
        object.__setattr__(self, "elevation_max_deg", emax)
        span = _as_float("azimuth_span_deg", self.azimuth_span_deg, 0.0, 360.0, lo_open=True)
        object.__setattr__(self, "azimuth_span_deg", span)

    @property
    def shape(self) -> tuple[int, int]:
        """``(height, width)``."""
        return (self.height, self.width)

    @property
    def _deg_per_row(self) -> float:
        return (self.elevation_max_deg - self.elevation_min_deg) / self.height

    @property
    def _deg_per_col(self) -> float:
        return self.azimuth_span_deg / self.width

    def directions(self) -> tuple[np.ndarray, np.ndarray]:
        """See :meth:`Camera.directions`; every pixel is valid."""
        rows, cols = _pixel_centres(*self.shape)
        az = self.azimuth_start_deg + (cols + 0.5) * self._deg_per_col
        el = self.elevation_max_deg - (rows + 0.5) * self._deg_per_row
        dirs = frames.enu_from_azimuth_zenith(az, 90.0 - el)
        return dirs, np.ones(self.shape, dtype=bool)

    def pixel_of_direction(self, dirs_enu) -> tuple[np.ndarray, np.ndarray]:
        """See :meth:`Camera.pixel_of_direction`; NaN outside the elevation and azimuth ranges.

        Straight up or down (where the azimuth is undefined) the column is that of azimuth 0 (if imaged).
        """
        d, ok = _as_directions(dirs_enu)
        h = np.hypot(d[..., 0], d[..., 1])
        el = np.degrees(np.arctan2(d[..., 2], h))
        az = np.degrees(np.arctan2(d[..., 0], d[..., 1]))
        daz = (az - self.azimuth_start_deg) % 360.0
        row = (self.elevation_max_deg - el) / self._deg_per_row - 0.5
        col = daz / self._deg_per_col - 0.5
        eps = 1e-9
        ok &= (row >= -0.5 - eps) & (row <= self.height - 0.5 + eps)
        if self.azimuth_span_deg < 360.0:
            ok &= col <= self.width - 0.5 + eps
        return np.where(ok, row, np.nan), np.where(ok, col, np.nan)

    def pixel_solid_angles(self, cosine_weighted: bool = False, upper_hemisphere: bool = False) -> np.ndarray:
        """Exact solid angle of every pixel: ``dAz (sin el_top - sin el_bottom)`` [sr].

        Parameters
        ----------
        cosine_weighted : bool, default False
            Return the projected solid angle ``int_pixel cos(zenith) dOmega = dAz (sin^2 el_top -
            sin^2 el_bottom) / 2`` [sr], counted above the horizon only.
        upper_hemisphere : bool, default False
            Count only the part of each pixel above the horizon (elevation >= 0).

        Returns
        -------
        numpy.ndarray
            float64, shape ``(height, width)`` [sr]; a full panorama sums to 4 pi (2 pi above the horizon, pi
            cosine-weighted).
        """
        rows = np.arange(self.height + 1, dtype=float)
        el = np.radians(self.elevation_max_deg - rows * self._deg_per_row)  # row edges, top to bottom
        if upper_hemisphere or cosine_weighted:
            el = np.maximum(el, 0.0)
        if cosine_weighted:
            band = 0.5 * (np.sin(el[:-1]) ** 2 - np.sin(el[1:]) ** 2)
        else:
            band = np.sin(el[:-1]) - np.sin(el[1:])
        return np.repeat((band * math.radians(self._deg_per_col))[:, None], self.width, axis=1)

    def to_attrs(self) -> dict[str, Any]:
        """See :meth:`Camera.to_attrs`."""
        attrs = self._base_attrs()
        attrs.update(
            camera_projection="cylindrical equirectangular (azimuth linear in column, elevation linear in row)",
            camera_orientation="azimuth increasing left to right from the left edge; elevation max at the top edge",
            camera_azimuth_start_deg=float(self.azimuth_start_deg),
            camera_azimuth_span_deg=float(self.azimuth_span_deg),
            camera_elevation_min_deg=float(self.elevation_min_deg),
            camera_elevation_max_deg=float(self.elevation_max_deg),
        )
        return attrs


# --------------------------------------------------------------------------------------------------------
# perspective
# --------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PerspectiveCamera(Camera):
    """Pinhole (rectilinear) camera.

    The optical axis ``f`` points at ``(view_azimuth_deg, view_zenith_deg)``. Image up ``u`` is the local up
    ``(0, 0, 1)`` projected onto the image plane (so the horizon is level), or north when the axis is within
    :data:`VERTICAL_VIEW_TOLERANCE` of the vertical; image right is ``r = f x u``. Looking straight down
    with north up therefore gives east to the right (a map); looking straight up gives east to the left
    (like :class:`AllSkyCamera`). ``roll_deg`` then rotates the camera about its axis, clockwise as seen from
    behind the camera, so that the scene turns counter-clockwise in the image:
    ``u' = cos(roll) u + sin(roll) r``, ``r' = cos(roll) r - sin(roll) u``::

                 u (image up)
                 ^
                 |    r (image right)
        row 0 -> +----->----------+
                 |                |
                 |      (f)       |  f points into the page, through the image centre
                 |                |
                 +----------------+

    The focal length in pixels is ``F = (width / 2) / tan(fov_deg / 2)`` (square pixels); pixel ``(i, j)``
    looks along ``F f + (j - (width - 1) / 2) r' - (i - (height - 1) / 2) u'``. The left and right image edges
    are at ``fov_deg / 2`` from the axis; the vertical field of view is ``2 atan((height / 2) / F)``.

    Parameters
    ----------
    width, height : int
        Image size [pixels], >= 1.
    fov_deg : float
        Horizontal field of view [deg], in (0, 180).
    view_azimuth_deg : float
        Azimuth of the optical axis [deg], any finite value (wrapped into [0, 360)).
    view_zenith_deg : float
        Zenith angle of the optical axis [deg], in [0, 180] (90: horizontal, 180: straight down).
    roll_deg : float, default 0.0
        Roll about the optical axis [deg], any finite value (wrapped into [-180, 180)).

    Raises
    ------
    SwimInputError
        For sizes that are not integers >= 1 or angles outside the ranges above.
    """

    width: int
    height: int
    fov_deg: float
    view_azimuth_deg: float
    view_zenith_deg: float
    roll_deg: float = 0.0

    kind: ClassVar[str] = "perspective"

    def __post_init__(self) -> None:
        object.__setattr__(self, "width", _as_int("width", self.width))
        object.__setattr__(self, "height", _as_int("height", self.height))
        fov = _as_float("fov_deg", self.fov_deg, 0.0, 180.0, lo_open=True, hi_open=True)
        object.__setattr__(self, "fov_deg", fov)
        object.__setattr__(self, "view_azimuth_deg", _as_float("view_azimuth_deg", self.view_azimuth_deg) % 360.0)
        object.__setattr__(self, "view_zenith_deg", _as_float("view_zenith_deg", self.view_zenith_deg, 0.0, 180.0))
        roll = (_as_float("roll_deg", self.roll_deg) + 180.0) % 360.0 - 180.0
        object.__setattr__(self, "roll_deg", roll)

    @property
    def shape(self) -> tuple[int, int]:
        """``(height, width)``."""
        return (self.height, self.width)

    @property
    def focal_length_px(self) -> float:
        """Focal length [pixels]: ``(width / 2) / tan(fov_deg / 2)``."""
        return (self.width / 2.0) / math.tan(math.radians(self.fov_deg) / 2.0)

    @property
    def vertical_fov_deg(self) -> float:
        """Vertical field of view [deg] between the top and bottom image edges."""
        return math.degrees(2.0 * math.atan((self.height / 2.0) / self.focal_length_px))

    def basis(self) -> np.ndarray:
        """Camera axes in the observer's ENU frame.

        Returns
        -------
        numpy.ndarray
            Shape ``(3, 3)``: rows ``right``, ``up`` (image right and up after roll) and ``forward`` (the
            optical axis), orthonormal, with ``forward = up x right`` (and ``right = forward x up``).
        """
        f = frames.enu_from_azimuth_zenith(self.view_azimuth_deg, self.view_zenith_deg)
        if math.hypot(f[0], f[1]) < VERTICAL_VIEW_TOLERANCE:
            ref = np.array([0.0, 1.0, 0.0])  # north
        else:
            ref = np.array([0.0, 0.0, 1.0])  # local up
        u = ref - np.dot(ref, f) * f
        u /= np.linalg.norm(u)
        r = np.cross(f, u)
        rho = math.radians(self.roll_deg)
        u2 = math.cos(rho) * u + math.sin(rho) * r
        r2 = math.cos(rho) * r - math.sin(rho) * u
        return np.stack([r2, u2, f])

    def directions(self) -> tuple[np.ndarray, np.ndarray]:
        """See :meth:`Camera.directions`; every pixel is valid."""
        rows, cols = _pixel_centres(*self.shape)
        right, up, fwd = self.basis()
        x = cols - (self.width - 1) / 2.0
        y = (self.height - 1) / 2.0 - rows
        d = self.focal_length_px * fwd + x[..., None] * right + y[..., None] * up
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        return d, np.ones(self.shape, dtype=bool)

    def pixel_of_direction(self, dirs_enu) -> tuple[np.ndarray, np.ndarray]:
        """See :meth:`Camera.pixel_of_direction`; NaN behind the camera or outside the image rectangle."""
        d, ok = _as_directions(dirs_enu)
        right, up, fwd = self.basis()
        a = d @ fwd
        ok &= a > 0.0
        a = np.where(ok, a, 1.0)
        fpx = self.focal_length_px
        col = (self.width - 1) / 2.0 + fpx * (d @ right) / a
        row = (self.height - 1) / 2.0 - fpx * (d @ up) / a
        eps = 1e-9
        ok &= (row >= -0.5 - eps) & (row <= self.height - 0.5 + eps)
        ok &= (col >= -0.5 - eps) & (col <= self.width - 0.5 + eps)
        return np.where(ok, row, np.nan), np.where(ok, col, np.nan)

    def pixel_solid_angles(self) -> np.ndarray:
        """Exact solid angle of every pixel [sr].

        A rectangle ``[x0, x1] x [y0, y1]`` on the image plane at focal distance ``F`` (pixels) subtends
        ``S(x1, y1) - S(x0, y1) - S(x1, y0) + S(x0, y0)`` with ``S(x, y) = atan(x y / (F sqrt(F^2 + x^2 + y^2)))``
        (the solid angle of a rectangle with a corner on the axis).

        Returns
        -------
        numpy.ndarray
            float64, shape ``(height, width)`` [sr].
        """
        fpx = self.focal_length_px
        x = np.arange(self.width + 1, dtype=float) - 0.5 - (self.width - 1) / 2.0
        y = np.arange(self.height + 1, dtype=float) - 0.5 - (self.height - 1) / 2.0
        yy, xx = np.meshgrid(y, x, indexing="ij")
        s = np.arctan(xx * yy / (fpx * np.sqrt(fpx * fpx + xx * xx + yy * yy)))
        return np.abs(s[1:, 1:] - s[1:, :-1] - s[:-1, 1:] + s[:-1, :-1])

    def to_attrs(self) -> dict[str, Any]:
        """See :meth:`Camera.to_attrs`."""
        attrs = self._base_attrs()
        attrs.update(
            camera_projection="pinhole (rectilinear)",
            camera_orientation=(
                "image up = local up projected on the image plane (north when looking straight up or down), "
                "then rolled clockwise (seen from behind the camera) by roll_deg"
            ),
            camera_fov_deg=float(self.fov_deg),
            camera_vertical_fov_deg=float(self.vertical_fov_deg),
            camera_view_azimuth_deg=float(self.view_azimuth_deg),
            camera_view_zenith_deg=float(self.view_zenith_deg),
            camera_roll_deg=float(self.roll_deg),
        )
        return attrs


# --------------------------------------------------------------------------------------------------------
# factory and pointing helpers
# --------------------------------------------------------------------------------------------------------
#: Camera classes by ``kind``.
CAMERA_KINDS: dict[str, type[Camera]] = {
    "allsky": AllSkyCamera,
    "panorama": PanoramaCamera,
    "perspective": PerspectiveCamera,
}

_KIND_ALIASES = {"all-sky": "allsky", "all_sky": "allsky", "fisheye": "allsky"}


def make_camera(kind: str, **options: Any) -> Camera:
    """Build a camera by name.

    Parameters
    ----------
    kind : str
        ``"allsky"`` (aliases ``"all-sky"``, ``"all_sky"``, ``"fisheye"``), ``"panorama"`` or
        ``"perspective"``; case-insensitive.
    **options
        Keyword arguments of the camera class (:class:`AllSkyCamera`, :class:`PanoramaCamera`,
        :class:`PerspectiveCamera`).

    Returns
    -------
    Camera

    Raises
    ------
    SwimInputError
        For an unknown ``kind``, an unknown option, a missing required option or an invalid value.
    """
    cls, key = _camera_class(kind, options)
    required = [
        f.name for f in fields(cls) if f.default is MISSING and f.default_factory is MISSING and f.name not in options
    ]
    if required:
        raise SwimInputError(f"camera kind {key!r} needs option(s) {required}")
    return cls(**options)


def _camera_class(kind, options):
    """The camera class of ``kind`` (an alias allowed) and its canonical name; SwimInputError for an unknown kind or
    an option that the class does not have."""
    if not isinstance(kind, str):
        raise SwimInputError(f"camera kind must be one of {sorted(CAMERA_KINDS)}, got {kind!r}")
    key = kind.strip().lower()
    key = _KIND_ALIASES.get(key, key)
    if key not in CAMERA_KINDS:
        raise SwimInputError(f"camera kind must be one of {sorted(CAMERA_KINDS)}, got {kind!r}")
    cls = CAMERA_KINDS[key]
    names = [f.name for f in fields(cls)]
    unknown = sorted(set(options) - set(names))
    if unknown:
        raise SwimInputError(f"unknown option(s) {unknown} for camera kind {key!r}; valid options: {names}")
    return cls, key


#: Stand-ins for the options that :func:`check_camera_options` is told come later (valid for any camera): a
#: horizontal view to the north with a 60 deg field of view.
_STAND_IN_OPTIONS = {"view_azimuth_deg": 0.0, "view_zenith_deg": 90.0, "fov_deg": 60.0}


def check_camera_options(kind: str, options: dict, filled_later=()) -> Camera:
    """Check a camera's kind and options before any work that the camera does not need (a scene's loading), as
    :func:`make_camera` will check them.

    Parameters
    ----------
    kind : str
        As :func:`make_camera`.
    options : dict
        The options given.
    filled_later : iterable of str
        Options that the caller fills in later where they are not given (``view_azimuth_deg``, ``view_zenith_deg``,
        ``fov_deg``: :func:`swim.render`'s default view of a perspective camera); not required here.

    Returns
    -------
    Camera
        The camera, with stand-ins for the options filled later: its ``shape`` is the image's.

    Raises
    ------
    SwimInputError
        For an unknown ``kind``, an unknown option, a missing required option that is not in ``filled_later``, or
        an invalid value of a given option.
    """
    cls, key = _camera_class(kind, options)
    names = {f.name for f in fields(cls)}
    stand_ins = {name: _STAND_IN_OPTIONS[name] for name in filled_later
                 if name not in options and name in names and name in _STAND_IN_OPTIONS}
    return make_camera(key, **options, **stand_ins)


def look_at_angles(observer_lat, observer_lon, observer_height, target_lat, target_lon, target_height):
    """Azimuth and zenith angle of the straight line from an observer to a target, in the observer's ENU frame.

    Both points are placed in the scene frame whose reference point is the observer
    (:func:`swim.frames.geodetic_to_scene`, spherical earth of radius
    :data:`swim.constants.EARTH_RADIUS_M`); the difference vector is rotated into the observer's ENU frame
    with :func:`swim.frames.enu_to_scene_rotation` (the identity for this choice of reference, kept so the
    code reads the same for any scene frame). Refraction is ignored (straight rays, as in the renderer). For
    a target at the observer's height and great-circle angle ``phi`` away, the zenith angle is
    ``90 + phi / 2`` deg (the target lies below the observer's horizontal).

    Parameters
    ----------
    observer_lat, observer_lon : float
        Observer latitude [deg] in [-90, 90] and longitude [deg] (any finite value).
    observer_height : float
        Observer height above the sea-level sphere [m], > -R.
    target_lat, target_lon, target_height : float
        The same for the target.

    Returns
    -------
    azimuth_deg, zenith_deg : float
        Azimuth [deg] in [0, 360) clockwise from north and zenith angle [deg] in [0, 180] of the direction from
        the observer to the target.

    Raises
    ------
    SwimInputError
        For latitudes outside [-90, 90], non-finite values, heights <= -R, or coincident points.
    """
    olat = _as_float("observer_lat", observer_lat, -90.0, 90.0)
    olon = _as_float("observer_lon", observer_lon)
    oh = _as_float("observer_height", observer_height, -EARTH_RADIUS_M, None, lo_open=True, unit="m")
    tlat = _as_float("target_lat", target_lat, -90.0, 90.0)
    tlon = _as_float("target_lon", target_lon)
    th = _as_float("target_height", target_height, -EARTH_RADIUS_M, None, lo_open=True, unit="m")
    p_obs = frames.geodetic_to_scene(olat, olon, oh, olat, olon)
    p_tgt = frames.geodetic_to_scene(tlat, tlon, th, olat, olon)
    v_scene = p_tgt - p_obs
    if not np.linalg.norm(v_scene) > 1e-6:
        raise SwimInputError("observer and target coincide: the look direction is undefined")
    rot = frames.enu_to_scene_rotation(olat, olon, olat, olon)  # v_scene = v_enu @ rot
    v_enu = v_scene @ rot.T
    az, zen = frames.azimuth_zenith_from_enu(v_enu)
    return float(az), float(zen)


def fov_to_fit(distance_m, half_extent_m, margin=1.2):
    """Full field of view [deg] that shows an object of half-size ``half_extent_m`` at ``distance_m``.

    ``fov = 2 atan(margin * half_extent_m / distance_m)``, for an object centred on the optical axis and
    perpendicular to it.

    Parameters
    ----------
    distance_m : float
        Distance from the camera to the object [m], > 0.
    half_extent_m : float
        Half the object's extent across the view [m], > 0.
    margin : float, default 1.2
        Factor applied to ``half_extent_m`` [-], > 0 (1.2: 20 % margin).

    Returns
    -------
    float
        Field of view [deg], in (0, 180).

    Raises
    ------
    SwimInputError
        If an argument is not a finite positive number.
    """
    dist = _as_float("distance_m", distance_m, 0.0, None, lo_open=True, unit="m")
    half = _as_float("half_extent_m", half_extent_m, 0.0, None, lo_open=True, unit="m")
    m = _as_float("margin", margin, 0.0, None, lo_open=True, unit="-")
    fov = math.degrees(2.0 * math.atan2(m * half, dist))
    if not 0.0 < fov < 180.0:  # only reachable through extreme ratios
        raise SwimInputError(
            f"distance_m={dist} and half_extent_m={half} (margin={m}) give a field of view outside (0, 180) deg"
        )
    return fov
