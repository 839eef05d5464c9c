"""Camera model of a real all-sky (fisheye) camera: pixel <-> view direction, masks, TOML files, sun-based fit.

:class:`FisheyeCameraModel` describes the geometry of an image taken by a real upward-looking fisheye camera
so that a :func:`swim.render` simulation can be reprojected into it (:mod:`swim.diagnostics.compare`). All
conventions are those of :mod:`swim.frames` and :mod:`swim.geometry.cameras`:

* view directions are unit vectors in the **observer's local ENU frame** (x east, y north, z up) pointing
  away from the observer; azimuth [deg] clockwise from north, zenith angle [deg] from the local vertical;
* images are arrays of shape ``(height, width)`` (rows, columns); row 0 is the top, column 0 the left edge;
  the centre of pixel ``(i, j)`` has the continuous coordinates ``(row, col) = (i, j)``.

Projection
----------
The distance ``r`` [px] of an image point from the optical centre ``(cx, cy)`` (column, row [px]) is a
function of the angle ``theta`` [rad] between its view direction and the optical axis:

==================  ====================================  =====================================
``projection``      ``r(theta)``                           ``theta`` range
==================  ====================================  =====================================
``equidistant``     ``f theta``                            [0, 180 deg]
``equisolid``       ``2 f sin(theta / 2)``                 [0, 180 deg]
``stereographic``   ``2 f tan(theta / 2)``                 [0, 180 deg)
``orthographic``    ``f sin(theta)``                       [0, 90 deg]
``polynomial``      ``k1 theta + k2 theta^2 + ...``        [0, ``max_zenith_deg``], monotonic
==================  ====================================  =====================================

``f`` is the focal length [px] (``focal_length_px``); the polynomial coefficients ``k_i`` [px rad^-i] are
``coefficients = (k1, k2, ...)`` (no constant term: the axis is imaged at the centre; ``k1 > 0``). A model
can also be given by the radius [px] of the circle on which a zenith angle ``radius_zenith_deg`` (default
90: the horizon) is imaged (:meth:`FisheyeCameraModel.from_radius`); ``f`` (or the scale of the
coefficients) follows from it. Only directions up to ``max_zenith_deg`` from the axis are imaged (the
image circle); pixels outside it are invalid.

Orientation
-----------
* ``azimuth_up_deg``: azimuth [deg] of the sky imaged straight **above** the centre (towards row 0). 0: north
  up.
* ``mirror``: the handedness of the image. ``False`` (default): the sky as seen **from below**, as an
  upward-looking camera records it: azimuth increases **counter-clockwise** in the image, so with north up
  east is on the **left** and west on the right (the convention of
  :class:`~swim.geometry.cameras.AllSkyCamera`). ``True``: a mirrored image (some camera software flips
  images, or the camera looks at a convex mirror as a TSI does): azimuth increases **clockwise**, north up
  puts east on the **right** (like a map).
* ``tilt_deg``, ``tilt_azimuth_deg``: the optical axis points at zenith angle ``tilt_deg`` towards azimuth
  ``tilt_azimuth_deg`` (a levelled camera has ``tilt_deg = 0``). The image is first formed in the camera's
  own frame (the ENU frame rotated so that its up is the optical axis, by the smallest rotation about a
  horizontal axis); ``azimuth_up_deg`` and ``mirror`` refer to that frame.

Pixel ``(row, col)`` with ``u = col - cx``, ``v = cy - row`` (v points up), ``r = hypot(u, v)``, looks at
``theta = r^-1(r)`` from the axis, at camera-frame azimuth ``phi = azimuth_up + atan2(-u, v)`` (``mirror``:
``atan2(u, v)``); inversely ``col = cx - r(theta) sin(phi - azimuth_up)`` (``mirror``: ``+``),
``row = cy - r(theta) cos(phi - azimuth_up)``.

Masks
-----
Pixels can be excluded by a **horizon profile** (``horizon_azimuth_deg``, ``horizon_elevation_deg``: the
elevation [deg] of obstacles, linearly interpolated, periodic in azimuth; a pixel is sky where its elevation
exceeds the profile) and by a **mask image** (``mask_path``: an image of the camera's size, grey value >= 128
= usable sky, darker = masked, e.g. a hand-drawn mask of buildings and the camera mount).

File format (TOML, :meth:`FisheyeCameraModel.to_toml`, :meth:`FisheyeCameraModel.from_toml`)::

    [camera]
    width = 1024
    height = 768
    cx = 511.5               # optical centre, column [px] (default (width - 1) / 2)
    cy = 383.5               # optical centre, row [px] (default (height - 1) / 2)
    projection = "equisolid" # equidistant | equisolid | stereographic | orthographic | polynomial
    focal_length_px = 260.0  # or radius_px = 367.7 with radius_zenith_deg = 90.0
    # coefficients = [250.0, 0.0, -8.0]   # polynomial only [px rad^-i]
    max_zenith_deg = 90.0
    azimuth_up_deg = 12.5
    mirror = false
    tilt_deg = 0.0
    tilt_azimuth_deg = 0.0

    [horizon]
    azimuth_deg = [0.0, 90.0, 180.0, 270.0]
    elevation_deg = [3.0, 8.0, 5.0, 2.0]
    mask_image = "mask.png"  # relative to the TOML file

References
----------
Miyamoto, K. (1964): Fish eye lens, J. Opt. Soc. Am. 54, 1060-1061, doi:10.1364/JOSA.54.001060
(equidistant, equisolid, stereographic and orthographic fisheye projections). Kannala, J. and Brandt, S. S.
(2006): A generic camera model and calibration method for conventional, wide-angle, and fish-eye lenses,
IEEE Trans. Pattern Anal. Mach. Intell. 28, 1335-1340, doi:10.1109/TPAMI.2006.153 (polynomial r(theta)).
Orientation from the sun's position: e.g. Urquhart, B. et al. (2015), Development of a sky imaging system
for short-term solar power forecasting, Atmos. Meas. Tech. 8, 875-890, doi:10.5194/amt-8-875-2015.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from .. import frames
from ..errors import SwimInputError
from .cameras import _as_directions, _as_float, _as_int, _pixel_centres, stokes_pixel_solid_angles
# the sun detection and orientation fit, importable from here too (the constants re-exported explicitly)
from .fisheye_sun import SUN_MAX_AREA_FRACTION as SUN_MAX_AREA_FRACTION
from .fisheye_sun import SUN_MIN_ROUNDNESS as SUN_MIN_ROUNDNESS
from .fisheye_sun import OrientationFit, detect_sun, fit_orientation_from_sun

__all__ = [
    "FISHEYE_PROJECTIONS",
    "FisheyeCameraModel",
    "OrientationFit",
    "reduce_blocks",
    "detect_sun",
    "fit_orientation_from_sun",
]

log = logging.getLogger(__name__)

#: Projection names accepted by :class:`FisheyeCameraModel`.
FISHEYE_PROJECTIONS = ("equidistant", "equisolid", "stereographic", "orthographic", "polynomial")

#: Largest angle from the optical axis [deg] each projection can image.
_DOMAIN_DEG = {"equidistant": 180.0, "equisolid": 180.0, "stereographic": 180.0, "orthographic": 90.0,
               "polynomial": 180.0}

_CAMERA_KEYS = ("width", "height", "cx", "cy", "projection", "focal_length_px", "radius_px", "radius_zenith_deg",
                "coefficients", "max_zenith_deg", "azimuth_up_deg", "mirror", "tilt_deg", "tilt_azimuth_deg")
_HORIZON_KEYS = ("azimuth_deg", "elevation_deg", "mask_image")


def _float_tuple(name: str, values: Any, unit: str) -> tuple[float, ...]:
    """Tuple of finite floats or :class:`SwimInputError`."""
    if values is None:
        return ()
    try:
        arr = np.atleast_1d(np.asarray(values, dtype=float))
    except (TypeError, ValueError):
        raise SwimInputError(f"{name} must be a sequence of numbers [{unit}], got {values!r}") from None
    if arr.ndim != 1 or not np.all(np.isfinite(arr)):
        raise SwimInputError(f"{name} must be a 1-D sequence of finite numbers [{unit}], got {values!r}")
    return tuple(float(v) for v in arr)


def _radial(projection: str, theta, f: float, coefficients: tuple[float, ...]):
    """r(theta) [px] for angles theta [rad] (array)."""
    t = np.asarray(theta, dtype=float)
    if projection == "equidistant":
        return f * t
    if projection == "equisolid":
        return 2.0 * f * np.sin(0.5 * t)
    if projection == "stereographic":
        return 2.0 * f * np.tan(0.5 * t)
    if projection == "orthographic":
        return f * np.sin(t)
    return np.polynomial.polynomial.polyval(t, (0.0,) + tuple(coefficients))


def _radial_derivative(projection: str, theta, f: float, coefficients: tuple[float, ...]):
    """dr/dtheta [px rad-1]."""
    t = np.asarray(theta, dtype=float)
    if projection == "equidistant":
        return np.full_like(t, f)
    if projection == "equisolid":
        return f * np.cos(0.5 * t)
    if projection == "stereographic":
        return f / np.cos(0.5 * t) ** 2
    if projection == "orthographic":
        return f * np.cos(t)
    return np.polynomial.polynomial.polyval(t, tuple(k * (i + 1) for i, k in enumerate(coefficients)))


def reduce_blocks(a, factor: int, reduce) -> np.ndarray:
    """``a`` (..., ny, nx) over blocks of ``factor`` x ``factor`` pixels from the top left (a remainder of rows and
    columns left out), each block reduced by ``reduce`` (``np.mean``, ``np.all``, ``np.any``): (..., ny // factor,
    nx // factor), the grid of :meth:`FisheyeCameraModel.downsampled`."""
    a = np.asarray(a)
    if factor == 1:
        return a
    *lead, ny, nx = a.shape
    h, w = ny // factor, nx // factor
    return reduce(a[..., :h * factor, :w * factor].reshape(*lead, h, factor, w, factor), axis=(-3, -1))


@dataclass(frozen=True)
class FisheyeCameraModel:
    """Geometry of a real upward-looking fisheye camera (see the module docstring for all conventions).

    Parameters
    ----------
    width, height : int
        Image size [px], >= 1.
    focal_length_px : float, optional
        Focal length f [px], > 0, for the parametric projections (give :meth:`from_radius` a radius
        instead); must be omitted for ``projection="polynomial"``.
    projection : {"equidistant", "equisolid", "stereographic", "orthographic", "polynomial"}
        Radial mapping r(theta) (module docstring).
    cx, cy : float, optional
        Optical centre: column and row [px] (continuous pixel coordinates, the centre of pixel (i, j) is
        (row, col) = (i, j)); default the image centre ``((width - 1) / 2, (height - 1) / 2)``.
    coefficients : tuple of float
        Polynomial coefficients ``(k1, k2, ...)`` [px rad^-i] of ``r = k1 theta + k2 theta^2 + ...``;
        required for (and only for) ``projection="polynomial"``; ``k1 > 0`` and r increasing on
        [0, max_zenith_deg].
    max_zenith_deg : float, default 90
        Largest angle from the optical axis that is imaged [deg], in (0, 180] within the projection's range
        (orthographic <= 90, stereographic < 180). Defines the image circle.
    azimuth_up_deg : float, default 0
        Azimuth [deg] imaged straight above the optical centre (wrapped into [0, 360)).
    mirror : bool, default False
        False: sky as seen from below (north up -> east left); True: mirrored (north up -> east right).
    tilt_deg : float, default 0
        Zenith angle of the optical axis [deg], in [0, 90].
    tilt_azimuth_deg : float, default 0
        Azimuth towards which the optical axis is tilted [deg] (wrapped into [0, 360)).
    horizon_azimuth_deg, horizon_elevation_deg : tuple of float
        Horizon profile: azimuths [deg] and the elevation [deg] in [-90, 90] of obstacles there (same length;
        empty: no profile). Interpolated linearly, periodic in azimuth.
    mask_path : str, optional
        Path of a mask image of size (height, width): grey >= 128 usable, darker masked.
    mask_block : int, default 1
        The mask image is ``mask_block`` times the camera's size (a :meth:`downsampled` camera): a pixel is usable
        where every pixel of its block is.

    Raises
    ------
    SwimInputError
        For any value outside the ranges above, an unknown projection, a missing or superfluous focal length
        or coefficients, or a non-monotonic polynomial.
    """

    width: int
    height: int
    focal_length_px: float | None = None
    projection: str = "equidistant"
    cx: float | None = None
    cy: float | None = None
    coefficients: tuple[float, ...] = ()
    max_zenith_deg: float = 90.0
    azimuth_up_deg: float = 0.0
    mirror: bool = False
    tilt_deg: float = 0.0
    tilt_azimuth_deg: float = 0.0
    horizon_azimuth_deg: tuple[float, ...] = ()
    horizon_elevation_deg: tuple[float, ...] = ()
    mask_path: str | None = None
    mask_block: int = 1
    _rotation: np.ndarray = field(init=False, repr=False, compare=False)

    kind: ClassVar[str] = "fisheye"

    # ------------------------------------------------------------------ validation
    def __post_init__(self) -> None:
        set_ = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731
        set_("width", _as_int("width", self.width))
        set_("height", _as_int("height", self.height))
        if not isinstance(self.projection, str) or self.projection.strip().lower() not in FISHEYE_PROJECTIONS:
            raise SwimInputError(f"projection must be one of {FISHEYE_PROJECTIONS}, got {self.projection!r}")
        proj = self.projection.strip().lower()
        set_("projection", proj)
        cx = (self.width - 1) / 2.0 if self.cx is None else _as_float("cx", self.cx, unit="px")
        cy = (self.height - 1) / 2.0 if self.cy is None else _as_float("cy", self.cy, unit="px")
        set_("cx", cx)
        set_("cy", cy)
        domain = _DOMAIN_DEG[proj]
        set_("max_zenith_deg", _as_float("max_zenith_deg", self.max_zenith_deg, 0.0, domain, lo_open=True,
                                         hi_open=proj == "stereographic"))
        coeffs = _float_tuple("coefficients", self.coefficients, "px rad^-i")
        set_("coefficients", coeffs)
        if proj == "polynomial":
            if self.focal_length_px is not None:
                raise SwimInputError("focal_length_px must be omitted for projection='polynomial' (give "
                                     "coefficients [px rad^-i])")
            if not coeffs or coeffs[0] <= 0.0:
                raise SwimInputError(f"coefficients (k1, k2, ...) [px rad^-i] with k1 > 0 are required for "
                                     f"projection='polynomial', got {coeffs}")
            t = np.linspace(0.0, math.radians(self.max_zenith_deg), 2001)
            if np.any(_radial_derivative(proj, t, 0.0, coeffs) <= 0.0):
                raise SwimInputError(f"polynomial r(theta) with coefficients {coeffs} [px rad^-i] must increase "
                                     f"on [0, max_zenith_deg={self.max_zenith_deg}] deg")
        else:
            if coeffs:
                raise SwimInputError(f"coefficients are only used with projection='polynomial', not {proj!r}")
            if self.focal_length_px is None:
                raise SwimInputError(f"focal_length_px [px] (or a radius, see FisheyeCameraModel.from_radius) "
                                     f"is required for projection={proj!r}")
            set_("focal_length_px", _as_float("focal_length_px", self.focal_length_px, 0.0, None, lo_open=True,
                                              unit="px"))
        set_("azimuth_up_deg", _as_float("azimuth_up_deg", self.azimuth_up_deg) % 360.0)
        if not isinstance(self.mirror, (bool, np.bool_)):
            raise SwimInputError(f"mirror must be true or false, got {self.mirror!r}")
        set_("mirror", bool(self.mirror))
        set_("tilt_deg", _as_float("tilt_deg", self.tilt_deg, 0.0, 90.0))
        set_("tilt_azimuth_deg", _as_float("tilt_azimuth_deg", self.tilt_azimuth_deg) % 360.0)
        haz = _float_tuple("horizon_azimuth_deg", self.horizon_azimuth_deg, "deg")
        hel = _float_tuple("horizon_elevation_deg", self.horizon_elevation_deg, "deg")
        if len(haz) != len(hel):
            raise SwimInputError(f"horizon_azimuth_deg and horizon_elevation_deg must have the same length, got "
                                 f"{len(haz)} and {len(hel)}")
        if any(abs(e) > 90.0 for e in hel):
            raise SwimInputError(f"horizon_elevation_deg must be in [-90, 90] deg, got {hel}")
        set_("horizon_azimuth_deg", haz)
        set_("horizon_elevation_deg", hel)
        if self.mask_path is not None:
            if not isinstance(self.mask_path, (str, Path)) or str(self.mask_path) == "":
                raise SwimInputError(f"mask_path must be a file path, got {self.mask_path!r}")
            set_("mask_path", str(self.mask_path))
        set_("mask_block", _as_int("mask_block", self.mask_block))
        set_("_rotation", self._tilt_rotation())

    def downsampled(self, factor: int) -> FisheyeCameraModel:
        """The camera with pixels ``factor`` times larger: ``width // factor`` x ``height // factor`` pixels, each the
        block of ``factor`` x ``factor`` of this camera's pixels from the top left (a remainder of rows and columns
        is left out); the same sky on them.

        Raises
        ------
        SwimInputError
            If ``factor`` is not an integer >= 1 or leaves fewer than 8 pixels across.
        """
        f = _as_int("factor", factor)
        if f == 1:
            return self
        if self.width // f < 8 or self.height // f < 8:
            raise SwimInputError(f"downsampling by {f} leaves fewer than 8 pixels across a {self.width} x "
                                 f"{self.height} image")
        shift = 0.5 * (f - 1)  # a block's centre in this camera's pixel coordinates, from its first pixel
        changes = {"width": self.width // f, "height": self.height // f, "cx": (self.cx - shift) / f,
                   "cy": (self.cy - shift) / f, "mask_block": self.mask_block * f}
        if self.projection == "polynomial":
            changes["coefficients"] = tuple(k / f for k in self.coefficients)
        else:
            changes["focal_length_px"] = self.focal_length_px / f
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_radius(cls, width: int, height: int, radius_px: float, *, radius_zenith_deg: float = 90.0,
                    projection: str = "equidistant", coefficients=(), **options: Any) -> "FisheyeCameraModel":
        """Model whose zenith angle ``radius_zenith_deg`` is imaged on a circle of ``radius_px`` [px].

        For the parametric projections the focal length is ``f = radius_px / g(radius_zenith)`` with ``g`` the
        projection's ``r(theta) / f``; for ``"polynomial"`` the given ``coefficients`` (the shape of r(theta))
        are scaled so that ``r(radius_zenith) = radius_px``.

        Parameters
        ----------
        width, height : int
            Image size [px].
        radius_px : float
            Radius [px], > 0.
        radius_zenith_deg : float, default 90
            Angle from the optical axis [deg] imaged at ``radius_px``, in (0, 180].
        projection : str
            See :class:`FisheyeCameraModel`.
        coefficients : sequence of float
            Polynomial shape (``projection="polynomial"`` only).
        **options
            Other fields of :class:`FisheyeCameraModel` (cx, cy, max_zenith_deg, azimuth_up_deg, ...).

        Raises
        ------
        SwimInputError
            For invalid values (as the constructor) or a radius the projection cannot reach.
        """
        radius = _as_float("radius_px", radius_px, 0.0, None, lo_open=True, unit="px")
        theta_r = math.radians(_as_float("radius_zenith_deg", radius_zenith_deg, 0.0, 180.0, lo_open=True))
        proj = str(projection).strip().lower()
        if proj == "polynomial":
            coeffs = _float_tuple("coefficients", coefficients, "px rad^-i")
            shape = float(_radial(proj, theta_r, 0.0, coeffs)) if coeffs else 0.0
            if not shape > 0.0:
                raise SwimInputError(f"polynomial coefficients {coeffs} give r <= 0 at radius_zenith_deg")
            return cls(width, height, projection=proj, coefficients=tuple(k * radius / shape for k in coeffs),
                       **options)
        if proj not in FISHEYE_PROJECTIONS:
            raise SwimInputError(f"projection must be one of {FISHEYE_PROJECTIONS}, got {projection!r}")
        if theta_r > math.radians(_DOMAIN_DEG[proj]) or (proj == "stereographic" and theta_r >= math.pi):
            raise SwimInputError(f"radius_zenith_deg={math.degrees(theta_r)} is beyond the range of the {proj} "
                                 "projection")
        g = float(_radial(proj, theta_r, 1.0, ()))
        return cls(width, height, focal_length_px=radius / g, projection=proj, **options)

    # ------------------------------------------------------------------ radial mapping
    @property
    def shape(self) -> tuple[int, int]:
        """``(height, width)``."""
        return (self.height, self.width)

    def radius_of_angle(self, theta_deg) -> np.ndarray:
        """Image radius r [px] of angles from the optical axis ``theta_deg`` [deg] (array_like)."""
        return _radial(self.projection, np.radians(np.asarray(theta_deg, dtype=float)), self.focal_length_px or 0.0,
                       self.coefficients)

    def angle_of_radius(self, radius_px) -> np.ndarray:
        """Angle from the optical axis [deg] imaged at radius ``radius_px`` [px]; NaN beyond the projection's
        range (for ``"polynomial"``: beyond ``max_zenith_deg``)."""
        return np.degrees(self._theta_of_r(np.asarray(radius_px, dtype=float)))

    @property
    def rim_radius_px(self) -> float:
        """Radius [px] of the image circle (the angle ``max_zenith_deg`` from the axis)."""
        return float(self.radius_of_angle(self.max_zenith_deg))

    def _theta_of_r(self, r: np.ndarray) -> np.ndarray:
        """theta [rad] of radii r [px]; NaN for negative r or r beyond the range."""
        f = self.focal_length_px
        r = np.asarray(r, dtype=float)
        bad = ~(r >= 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            if self.projection == "equidistant":
                t = r / f
            elif self.projection == "equisolid":
                t = 2.0 * np.arcsin(np.where(r <= 2.0 * f, r / (2.0 * f), np.nan))
            elif self.projection == "stereographic":
                t = 2.0 * np.arctan(r / (2.0 * f))
            elif self.projection == "orthographic":
                t = np.arcsin(np.where(r <= f, r / f, np.nan))
            else:
                tmax = math.radians(self.max_zenith_deg)
                grid = np.linspace(0.0, tmax, 4097)
                rg = _radial("polynomial", grid, 0.0, self.coefficients)
                t = np.interp(r, rg, grid)
                for _ in range(3):  # Newton refinement on the smooth monotonic polynomial
                    t = t - (_radial("polynomial", t, 0.0, self.coefficients) - r) / _radial_derivative(
                        "polynomial", t, 0.0, self.coefficients)
                    t = np.clip(t, 0.0, tmax)
                t = np.where(r <= rg[-1] * (1.0 + 1e-12), t, np.nan)
        return np.where(bad, np.nan, t)

    # ------------------------------------------------------------------ orientation
    def _tilt_rotation(self) -> np.ndarray:
        """R (3, 3) with v_enu = R @ v_camera (the smallest rotation taking up to the optical axis)."""
        tilt = math.radians(self.tilt_deg)
        if tilt == 0.0:
            return np.eye(3)
        az = math.radians(self.tilt_azimuth_deg)
        k = np.array([-math.cos(az), math.sin(az), 0.0])  # up x axis, normalised (horizontal)
        kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        return np.eye(3) * math.cos(tilt) + math.sin(tilt) * kx + (1.0 - math.cos(tilt)) * np.outer(k, k)

    @property
    def optical_axis(self) -> np.ndarray:
        """Unit ENU vector (3,) of the optical axis."""
        return self._rotation[:, 2].copy()

    # ------------------------------------------------------------------ pixels <-> directions
    def directions(self, apply_masks: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """View directions of all pixel centres.

        Parameters
        ----------
        apply_masks : bool, default True
            Also mark pixels hidden by the horizon profile or the mask image as invalid (their directions
            stay defined); False: ``valid`` is the image circle only.

        Returns
        -------
        dirs : numpy.ndarray
            float64, shape ``(height, width, 3)``: unit ENU view directions; NaN outside the image circle.
        valid : numpy.ndarray
            bool, shape ``(height, width)``: pixel centre inside the image circle (and not masked).

        Raises
        ------
        SwimInputError
            If the mask image cannot be read or has the wrong size.
        """
        rows, cols = _pixel_centres(*self.shape)
        u = cols - self.cx
        v = self.cy - rows
        r = np.hypot(u, v)
        inside = r <= self.rim_radius_px * (1.0 + 1e-12)
        theta = self._theta_of_r(np.where(inside, r, 0.0))
        phi = math.radians(self.azimuth_up_deg) + (np.arctan2(u, v) if self.mirror else np.arctan2(-u, v))
        s = np.sin(theta)
        level = np.stack([s * np.sin(phi), s * np.cos(phi), np.cos(theta)], axis=-1)
        dirs = level @ self._rotation.T
        valid = inside & np.all(np.isfinite(dirs), axis=-1)
        dirs[~valid] = np.nan
        if apply_masks:
            valid &= self.sky_mask(dirs)
        return dirs, valid

    def pixel_of_direction(self, dirs_enu) -> tuple[np.ndarray, np.ndarray]:
        """Continuous pixel coordinates of view directions (inverse of :meth:`directions`; masks not applied).

        Parameters
        ----------
        dirs_enu : array_like
            Shape ``(..., 3)``: ENU directions pointing away from the observer; need not be unit length.

        Returns
        -------
        row, col : numpy.ndarray
            float64, shape ``dirs_enu.shape[:-1]``; NaN beyond ``max_zenith_deg`` from the optical axis, outside
            the image rectangle, or for zero / non-finite directions.

        Raises
        ------
        SwimInputError
            If ``dirs_enu`` does not have a last axis of length 3.
        """
        d, ok = _as_directions(dirs_enu)
        level = d @ self._rotation  # v_camera = R^T v_enu
        h = np.hypot(level[..., 0], level[..., 1])
        theta = np.arctan2(h, level[..., 2])
        ok &= theta <= math.radians(self.max_zenith_deg) * (1.0 + 1e-12)
        phi = np.arctan2(level[..., 0], level[..., 1])
        r = _radial(self.projection, np.where(ok, theta, 0.0), self.focal_length_px or 0.0, self.coefficients)
        psi = phi - math.radians(self.azimuth_up_deg)
        sign = 1.0 if self.mirror else -1.0
        col = self.cx + sign * r * np.sin(psi)
        row = self.cy - r * np.cos(psi)
        eps = 1e-9
        ok &= (row >= -0.5 - eps) & (row <= self.height - 0.5 + eps)
        ok &= (col >= -0.5 - eps) & (col <= self.width - 0.5 + eps)
        return np.where(ok, row, np.nan), np.where(ok, col, np.nan)

    # ------------------------------------------------------------------ masks
    def horizon_elevation(self, azimuth_deg) -> np.ndarray:
        """Obstacle elevation [deg] of the horizon profile at ``azimuth_deg`` [deg]; -90 without a profile."""
        az = np.asarray(azimuth_deg, dtype=float)
        if not self.horizon_azimuth_deg:
            return np.full(az.shape, -90.0)
        xp = np.asarray(self.horizon_azimuth_deg) % 360.0
        order = np.argsort(xp)
        return np.interp(az % 360.0, xp[order], np.asarray(self.horizon_elevation_deg)[order], period=360.0)

    def mask_image(self) -> np.ndarray | None:
        """Usable-pixel mask (height, width) read from ``mask_path`` (grey >= 128 usable), or None.

        Raises
        ------
        SwimInputError
            If the file cannot be read or its size differs from (height, width).
        """
        if self.mask_path is None:
            return None
        from PIL import Image, UnidentifiedImageError

        try:
            with Image.open(self.mask_path) as im:
                grey = np.asarray(im.convert("L"))
        except (OSError, UnidentifiedImageError) as err:
            raise SwimInputError(f"mask_path {self.mask_path!r} cannot be read as an image: {err}") from None
        b = self.mask_block
        expected = (self.height * b, self.width * b)
        if b > 1 and grey.shape[0] >= expected[0] and grey.shape[1] >= expected[1]:
            return reduce_blocks(grey >= 128, b, np.all)[:self.height, :self.width]
        if grey.shape != self.shape:
            raise SwimInputError(f"mask image {self.mask_path!r} has size (height, width) = {grey.shape}, expected "
                                 f"{expected} [px]")
        return grey >= 128

    def sky_mask(self, dirs: np.ndarray | None = None) -> np.ndarray:
        """Pixels (height, width) not hidden by the horizon profile or the mask image (bool)."""
        if dirs is None:
            dirs, _ = self.directions(apply_masks=False)
        ok = np.ones(self.shape, dtype=bool)
        if self.horizon_azimuth_deg:
            finite = np.all(np.isfinite(dirs), axis=-1, keepdims=True)
            az, zen = frames.azimuth_zenith_from_enu(np.where(finite, dirs, np.array([0.0, 0.0, 1.0])))
            ok &= (90.0 - zen) > self.horizon_elevation(az)
        image = self.mask_image()
        if image is not None:
            ok &= image
        return ok

    # ------------------------------------------------------------------ solid angles
    def pixel_solid_angles(self) -> np.ndarray:
        """Solid angle [sr] of every pixel: the part of the pixel square inside the image circle.

        The projection is radially symmetric about the optical centre (rotation, mirroring and tilt are
        rotations of the sphere and keep solid angles), with the density
        ``dOmega / dA = sin(theta) / (r dr/dtheta)`` in the image plane: the Jacobian of the mapping. This is the
        exterior derivative of the 1-form ``(1 - cos(theta(r))) dpsi`` (``psi`` the polar angle in the image), so
        by Stokes' theorem a pixel's solid angle is the line integral of ``(1 - cos(theta(min(r, r_rim))))
        dpsi`` round its edges; each edge is integrated with 16-point Gauss-Legendre quadrature, split where it
        crosses the rim, as in :meth:`swim.geometry.cameras.AllSkyCamera.pixel_solid_angles`. Neighbouring
        pixels share edges, so an image containing the whole image circle sums to ``2 pi (1 - cos
        max_zenith)`` (2 pi for a hemisphere) to rounding.

        Returns
        -------
        numpy.ndarray
            float64, shape (height, width) [sr]; masks are not applied (multiply by ``directions()[1]``).
        """
        rim = self.rim_radius_px
        k1 = float(_radial_derivative(self.projection, 0.0, self.focal_length_px or 0.0, self.coefficients))

        def g_over_r2(r):  # (1 - cos theta) / r^2 = 2 sin^2(theta / 2) / r^2, finite at r = 0
            rr = np.minimum(r, rim)
            t = self._theta_of_r(rr)
            safe = np.where(r > 0, r, 1.0)
            return np.where(r > 0, 2.0 * np.sin(0.5 * t) ** 2 / safe**2, 0.5 / k1**2)

        u_lines = np.arange(self.width + 1, dtype=float) - 0.5 - self.cx  # column edges
        v_lines = np.arange(self.height + 1, dtype=float) - 0.5 - self.cy  # row edges (v downwards here)
        return np.abs(stokes_pixel_solid_angles(g_over_r2, rim, u_lines, v_lines))

    # ------------------------------------------------------------------ attributes and files
    def to_attrs(self) -> dict[str, Any]:
        """Plain scalars and strings for netCDF attributes (keys start with ``fisheye_``)."""
        attrs: dict[str, Any] = {
            "fisheye_width": int(self.width), "fisheye_height": int(self.height),
            "fisheye_cx": float(self.cx), "fisheye_cy": float(self.cy),
            "fisheye_projection": self.projection,
            "fisheye_max_zenith_deg": float(self.max_zenith_deg),
            "fisheye_azimuth_up_deg": float(self.azimuth_up_deg),
            "fisheye_mirror": int(self.mirror),
            "fisheye_tilt_deg": float(self.tilt_deg), "fisheye_tilt_azimuth_deg": float(self.tilt_azimuth_deg),
        }
        if self.projection == "polynomial":
            attrs["fisheye_coefficients"] = np.asarray(self.coefficients, dtype=float)
        else:
            attrs["fisheye_focal_length_px"] = float(self.focal_length_px)
        return attrs

    def to_toml(self, path=None) -> str:
        """TOML text of the model (module docstring); also written to ``path`` if given.

        Floats are written with ``repr`` (exact round trip). ``mask_image`` is written as stored.
        """
        def num(x):
            return repr(float(x))

        lines = ["# swim fisheye camera model (docs/comparison.md)", "[camera]",
                 f"width = {self.width}", f"height = {self.height}",
                 f"cx = {num(self.cx)}", f"cy = {num(self.cy)}", f'projection = "{self.projection}"']
        if self.projection == "polynomial":
            lines.append("coefficients = [" + ", ".join(num(k) for k in self.coefficients) + "]")
        else:
            lines.append(f"focal_length_px = {num(self.focal_length_px)}")
        lines += [f"max_zenith_deg = {num(self.max_zenith_deg)}", f"azimuth_up_deg = {num(self.azimuth_up_deg)}",
                  f"mirror = {'true' if self.mirror else 'false'}", f"tilt_deg = {num(self.tilt_deg)}",
                  f"tilt_azimuth_deg = {num(self.tilt_azimuth_deg)}"]
        if self.horizon_azimuth_deg or self.mask_path is not None:
            lines += ["", "[horizon]"]
            if self.horizon_azimuth_deg:
                lines.append("azimuth_deg = [" + ", ".join(num(a) for a in self.horizon_azimuth_deg) + "]")
                lines.append("elevation_deg = [" + ", ".join(num(e) for e in self.horizon_elevation_deg) + "]")
            if self.mask_path is not None:
                escaped = self.mask_path.replace("\\", "\\\\").replace('"', '\\"')
                lines.append(f'mask_image = "{escaped}"')
        text = "\n".join(lines) + "\n"
        if path is not None:
            _write_text_atomic(Path(path), text)
        return text

    @classmethod
    def from_toml(cls, source) -> "FisheyeCameraModel":
        """Read a model from a TOML file path, or from TOML text (a ``str`` containing a newline or ``[``).

        ``[camera]`` takes the constructor's fields; ``radius_px`` (with optional ``radius_zenith_deg``)
        replaces ``focal_length_px`` (:meth:`from_radius`). ``[horizon]`` takes ``azimuth_deg``,
        ``elevation_deg`` and ``mask_image`` (a path relative to the TOML file's folder).

        Raises
        ------
        SwimInputError
            If the file is missing or not valid TOML, has unknown keys, or holds invalid values.
        """
        base = None
        if isinstance(source, Path) or (isinstance(source, str) and "\n" not in source and "[" not in source):
            path = Path(source)
            try:
                text = path.read_text(encoding="utf-8")
            except OSError as err:
                raise SwimInputError(f"camera model file {str(path)!r} cannot be read: {err}") from None
            base = path.resolve().parent
        elif isinstance(source, str):
            text = source
        else:
            raise SwimInputError(f"camera model source must be a TOML path or text, got {type(source).__name__}")
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as err:
            raise SwimInputError(f"camera model is not valid TOML: {err}") from None
        unknown = sorted(set(data) - {"camera", "horizon"})
        if unknown or "camera" not in data:
            raise SwimInputError(f"camera model TOML needs a [camera] table (and optionally [horizon]); unknown "
                                 f"tables: {unknown}")
        cam = dict(data["camera"])
        hor = dict(data.get("horizon", {}))
        for table, got, known in (("camera", cam, _CAMERA_KEYS), ("horizon", hor, _HORIZON_KEYS)):
            bad = sorted(set(got) - set(known))
            if bad:
                raise SwimInputError(f"unknown key(s) {bad} in [{table}] of the camera model; valid: {list(known)}")
        options: dict[str, Any] = {}
        if "azimuth_deg" in hor or "elevation_deg" in hor:
            options["horizon_azimuth_deg"] = hor.get("azimuth_deg", ())
            options["horizon_elevation_deg"] = hor.get("elevation_deg", ())
        if "mask_image" in hor:
            mask = Path(str(hor["mask_image"]))
            if not mask.is_absolute() and base is not None:
                mask = base / mask
            options["mask_path"] = str(mask)
        for key in ("width", "height"):
            if key not in cam:
                raise SwimInputError(f"[camera] {key} [px] is required in the camera model")
        width, height = cam.pop("width"), cam.pop("height")
        if "radius_px" in cam:
            if "focal_length_px" in cam:
                raise SwimInputError("give either focal_length_px or radius_px [px] in [camera], not both")
            radius = cam.pop("radius_px")
            rz = cam.pop("radius_zenith_deg", 90.0)
            return cls.from_radius(width, height, radius, radius_zenith_deg=rz, **cam, **options)
        if "radius_zenith_deg" in cam:
            raise SwimInputError("radius_zenith_deg needs radius_px in [camera]")
        if "coefficients" in cam:
            cam["coefficients"] = tuple(cam["coefficients"])
        return cls(width, height, **cam, **options)


def _write_text_atomic(path: Path, text: str) -> None:
    """Write text through a temporary file in the same folder and rename it into place."""
    import os
    import tempfile

    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
