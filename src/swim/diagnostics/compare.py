"""Compare a simulated image with a real camera image (paper Sect. 4.2.3, Eq. 37).

Workflow
--------
1. Describe the real camera with a :class:`~swim.geometry.fisheye.FisheyeCameraModel` (projection, centre,
   radius, rotation, mirror, horizon mask; TOML file; orientation fitted from the sun with
   :func:`~swim.geometry.fisheye.fit_orientation_from_sun`).
2. :func:`reproject` the :func:`swim.render` output into the camera's pixels: each camera pixel's view
   direction is looked up in the simulated image (through the exact inverse of the simulating camera, rebuilt
   from the image's ``camera_*`` attributes) and the simulated image is sampled there bilinearly.
3. :func:`compare_images` computes, per channel R, G, B, the Pearson correlation coefficient r (paper
   Eq. 37) and its mean r-bar over the three channels (the paper: "The mean value of r, calculated
   individually for the set of simulated vs. observed pixel intensities in each of the image channels (R,
   G, and B), is denoted as r-bar"), the RMSE and bias after an optional linear brightness fit, and a
   difference image, over the common valid pixels: inside the camera's image circle and masks, simulated and
   observed finite, above ``min_elevation_deg`` and farther than ``sun_exclusion_deg`` from the sun (default
   5 deg as the paper's Sect. 4.2.3; Table 4 used 12 deg against camera glare).

Weighting
---------
Eq. 37 gives every pixel pair the same weight. Fisheye pixels do not subtend equal solid angles (an
equidistant pixel at the horizon subtends 2 / pi of one at the zenith, an equisolid one the same), so r
depends on the camera's projection. ``weighting="solid_angle"`` (default) weights each pixel pair by its
solid angle w_i (:meth:`~swim.geometry.fisheye.FisheyeCameraModel.pixel_solid_angles`): the weighted
Pearson coefficient ``r = sum w (x - xm)(y - ym) / sqrt(sum w (x - xm)^2 sum w (y - ym)^2)`` with weighted
means xm, ym, an estimate of the correlation over the sky dome independent of the projection.
``weighting="pixel"`` (w = 1) is Eq. 37 exactly.

Compared quantities (``quantity``)
----------------------------------
Real cameras store display-encoded (sRGB-like, "gamma") 8-bit values and are not radiometrically calibrated
(paper Sect. 4.2.3). swim's ``rgb`` is 8-bit sRGB with the exposure ``white_level`` (docs/colour.md).

* ``"linear_rgb"`` (default): both images' 8-bit values are linearised with the sRGB EOTF (IEC 61966-2-1:
  ``V / 12.92`` for ``V <= 0.04045``, else ``((V + 0.055) / 1.055)^2.4``, V = value / 255), so that both
  are proportional to scene radiance (for the simulation up to the clipping at its white level; for the
  camera if its response is sRGB-like). Reprojection interpolates in linear units.
* ``"srgb"``: the display-encoded values / 255 as stored (r on the "RGB images" as the paper did).
* ``"radiance"``: the simulated solar-relative radiance L' at 615, 546, 450 nm against the camera's
  linearised R, G, B (channel by channel). The camera is uncalibrated, so use ``fit="gain"`` or
  ``"gain_offset"`` for RMSE and bias (r is invariant under the fit).

Brightness fit (``fit``)
------------------------
Per channel c the simulation x is mapped onto the observation y by weighted least squares:
``"none"``: y ~ x; ``"gain"``: y ~ a x; ``"gain_offset"``: y ~ a x + b. RMSE and bias are those of the fitted
simulation minus the observation, ``d = a x + b - y``: ``bias = sum w d / sum w``, ``RMSE = sqrt(sum w d^2 /
sum w)``, in the units of the observation (``rmse_raw``, ``bias_raw``: without fit). The difference image
is d (NaN outside the mask). Pearson r is invariant under the fit.

References
----------
Albers, S. et al. (2020): A fast visible-wavelength 3D radiative transfer procedure for NWP visualization
and forward modeling, Atmos. Meas. Tech. 13, 3235-3261, doi:10.5194/amt-13-3235-2020 (Sect. 4.2.3, Eq. 37,
Table 4). IEC 61966-2-1:1999 (sRGB).
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from .. import frames
from ..errors import SwimInputError
from ..geometry.cameras import CAMERA_KINDS, Camera, make_camera
from ..geometry.fisheye import FisheyeCameraModel, reduce_blocks
from ..io.atomic import atomic_write

__all__ = [
    "QUANTITIES",
    "FITS",
    "WEIGHTINGS",
    "srgb_to_linear",
    "linear_to_srgb",
    "swim_camera_of",
    "read_camera_image",
    "reproject",
    "pearson_r",
    "linear_fit",
    "sun_angle_deg",
    "compare_images",
    "scores_dict",
    "difference_rgb8",
    "write_difference_png",
    "write_json",
]

log = logging.getLogger(__name__)

#: Accepted ``quantity`` values of :func:`compare_images`.
QUANTITIES = ("linear_rgb", "srgb", "radiance")
#: Accepted ``fit`` values of :func:`compare_images`.
FITS = ("none", "gain", "gain_offset")
#: Accepted ``weighting`` values of :func:`compare_images`.
WEIGHTINGS = ("solid_angle", "pixel")

_CHANNELS = ["R", "G", "B"]
_REFERENCE = "Albers et al. (2020), Atmos. Meas. Tech. 13, 3235-3261, doi:10.5194/amt-13-3235-2020, Sect. 4.2.3, Eq. 37"


# --------------------------------------------------------------------------------------------------------
# encoding
# --------------------------------------------------------------------------------------------------------
def srgb_to_linear(values) -> np.ndarray:
    """sRGB EOTF (IEC 61966-2-1): display-encoded V in [0, 1] -> linear [0, 1]; NaN stays NaN."""
    v = np.asarray(values, dtype=float)
    return np.where(v <= 0.04045, v / 12.92, ((np.maximum(v, 0.04045) + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(values) -> np.ndarray:
    """sRGB OETF (IEC 61966-2-1): linear [0, 1] -> display-encoded [0, 1] (clipped to [0, 1]); NaN stays NaN."""
    v = np.clip(np.asarray(values, dtype=float), 0.0, 1.0)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.maximum(v, 0.0031308) ** (1.0 / 2.4) - 0.055)


def _full_scale(a: np.ndarray) -> float:
    return float(np.iinfo(a.dtype).max) if np.issubdtype(a.dtype, np.integer) else 1.0


# --------------------------------------------------------------------------------------------------------
# simulated image geometry
# --------------------------------------------------------------------------------------------------------
def swim_camera_of(image: xr.Dataset) -> Camera:
    """The swim camera (:mod:`swim.geometry.cameras`) that rendered ``image``, rebuilt from its attributes.

    Reads ``camera_<name>`` or ``camera_camera_<name>`` attributes (both prefixes occur) and checks that the
    rebuilt camera's view directions match the image's ``view_azimuth``/``view_zenith`` where present.

    Raises
    ------
    SwimInputError
        If the attributes are missing or inconsistent with the image.
    """
    attrs = image.attrs

    def get(name, default=None):
        for key in (f"camera_camera_{name}", f"camera_{name}"):
            if key in attrs:
                return attrs[key]
        return default

    kind = get("kind", attrs.get("camera"))
    if kind not in CAMERA_KINDS:
        raise SwimInputError(f"simulated image has no known camera kind in its attributes (camera_kind={kind!r})")
    try:
        if kind == "allsky":
            cam = make_camera(kind, size=int(get("size", image.sizes.get("x"))),
                              max_zenith_deg=float(get("max_zenith_deg", 90.0)))
        elif kind == "panorama":
            cam = make_camera(kind, width=int(get("nx")), height=int(get("ny")),
                              azimuth_start_deg=float(get("azimuth_start_deg")),
                              azimuth_span_deg=float(get("azimuth_span_deg")),
                              elevation_min_deg=float(get("elevation_min_deg")),
                              elevation_max_deg=float(get("elevation_max_deg")))
        else:
            cam = make_camera(kind, width=int(get("nx")), height=int(get("ny")), fov_deg=float(get("fov_deg")),
                              view_azimuth_deg=float(get("view_azimuth_deg")),
                              view_zenith_deg=float(get("view_zenith_deg")), roll_deg=float(get("roll_deg", 0.0)))
    except (TypeError, ValueError) as err:
        raise SwimInputError(f"simulated image's {kind} camera attributes are incomplete: {err}") from None
    if "y" in image.sizes and cam.shape != (image.sizes["y"], image.sizes["x"]):
        raise SwimInputError(f"camera attributes give shape {cam.shape} but the image is "
                             f"{(image.sizes['y'], image.sizes['x'])}")
    if "view_zenith" in image and "view_azimuth" in image:
        dirs, valid = cam.directions()
        ref = frames.enu_from_azimuth_zenith(np.asarray(image["view_azimuth"].values, dtype=float),
                                             np.asarray(image["view_zenith"].values, dtype=float))
        ok = valid & np.all(np.isfinite(ref), axis=-1)
        if ok.any():
            cos = np.clip(np.sum(dirs[ok] * ref[ok], axis=-1), -1.0, 1.0)
            worst = float(np.degrees(np.arccos(cos.min())))
            if worst > 0.05:
                raise SwimInputError(f"camera attributes disagree with view_azimuth/view_zenith by {worst:.3f} deg")
    return cam


def _finite_dirs(dirs: np.ndarray) -> np.ndarray:
    """Directions (..., 3) with non-finite vectors replaced by the zenith (0, 0, 1) (for angle computations
    whose results are masked anyway)."""
    ok = np.all(np.isfinite(dirs), axis=-1, keepdims=True)
    return np.where(ok, dirs, np.array([0.0, 0.0, 1.0]))


def _bilinear(stack: np.ndarray, row: np.ndarray, col: np.ndarray, wrap_cols: bool = False) -> np.ndarray:
    """Sample (C, ny, nx) at continuous (row, col) (any shape); NaN-aware (weights renormalised over the
    finite neighbours; NaN where none or where row/col is NaN)."""
    c, ny, nx = stack.shape
    ok = np.isfinite(row) & np.isfinite(col)
    r = np.where(ok, row, 0.0)
    q = np.where(ok, col, 0.0)
    r0 = np.floor(r)
    q0 = np.floor(q)
    fr = r - r0
    fq = q - q0
    out = np.zeros((c,) + row.shape)
    wsum = np.zeros(row.shape)
    for dr, wr in ((0, 1.0 - fr), (1, fr)):
        for dq, wq in ((0, 1.0 - fq), (1, fq)):
            ri = np.clip(r0 + dr, 0, ny - 1).astype(int)
            qi = (q0 + dq).astype(int)
            qi = qi % nx if wrap_cols else np.clip(qi, 0, nx - 1)
            vals = stack[:, ri, qi]
            w = wr * wq
            good = np.all(np.isfinite(vals), axis=0) & (w > 0)
            out += np.where(good, w, 0.0) * np.nan_to_num(vals)
            wsum += np.where(good, w, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        res = out / wsum
    return np.where(ok & (wsum > 1e-9), res, np.nan)


def _sample_by_directions(image: xr.Dataset, stack: np.ndarray, dirs: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Fallback without camera attributes: inverse-distance weights of the 4 nearest simulated view directions."""
    from scipy.spatial import cKDTree

    sim_dirs = frames.enu_from_azimuth_zenith(np.asarray(image["view_azimuth"].values, dtype=float),
                                              np.asarray(image["view_zenith"].values, dtype=float))
    good = np.all(np.isfinite(sim_dirs), axis=-1) & np.all(np.isfinite(stack), axis=0)
    if good.sum() < 4:
        raise SwimInputError("the simulated image has fewer than 4 pixels with finite view directions and values")
    tree = cKDTree(sim_dirs[good])
    values = stack[:, good]
    # pitch of the simulated image: median nearest-neighbour distance
    d_nn, _ = tree.query(sim_dirs[good][:: max(1, good.sum() // 500)], k=2)
    pitch = float(np.median(d_nn[:, 1]))
    out = np.full((stack.shape[0],) + valid.shape, np.nan)
    q = dirs[valid]
    dist, idx = tree.query(q, k=4)
    w = 1.0 / np.maximum(dist, 1e-9 * pitch)
    res = np.sum(values[:, idx] * w, axis=-1) / np.sum(w, axis=-1)  # (C, n)
    res[:, dist[:, 0] > 2.0 * pitch] = np.nan  # outside the simulated field of view
    out[:, valid] = res
    return out


def reproject(simulated: xr.Dataset, camera: FisheyeCameraModel) -> xr.Dataset:
    """Resample a :func:`swim.render` image into the pixels of a real camera.

    For each camera pixel (:meth:`FisheyeCameraModel.directions`, masks applied) the simulated image is
    sampled bilinearly at the continuous pixel coordinates of the same view direction in the simulating
    camera (rebuilt by :func:`swim_camera_of`; the observer's ENU frame is shared). Without usable camera
    attributes the four nearest simulated view directions (``view_azimuth``, ``view_zenith``) are averaged
    with inverse-distance weights instead. Interpolation ignores NaN neighbours (weights renormalised).

    Parameters
    ----------
    simulated : xarray.Dataset
        Output of :func:`swim.render` (or read back from its netCDF): ``radiance`` (wavelength, y, x) [1],
        ``rgb`` (y, x, channel) uint8 sRGB, ``view_azimuth``, ``view_zenith`` (y, x) [deg], attributes.
    camera : FisheyeCameraModel
        The real camera.

    Returns
    -------
    xarray.Dataset
        On the camera grid (y, x) = (height, width): every simulated variable with dims (y, x) or
        (wavelength, y, x) (float64, NaN where not imaged); ``rgb_linear`` (y, x, channel) [0, 1]: the
        simulated ``rgb`` linearised with the sRGB EOTF, then interpolated; ``rgb`` (y, x, channel) uint8:
        ``rgb_linear`` re-encoded (0 where NaN); ``view_azimuth``, ``view_zenith`` [deg] of the camera pixels;
        ``valid`` (y, x) bool: camera pixel valid and all simulated channels finite; ``solid_angle`` (y, x)
        [sr]. Attributes: the simulated image's sun, observer and time attributes, the camera model's
        ``fisheye_*`` attributes and ``swim_reprojected = "fisheye"``.

    Raises
    ------
    SwimInputError
        If ``simulated`` lacks ``radiance`` or ``rgb`` and the geometry cannot be determined.
    """
    if not isinstance(camera, FisheyeCameraModel):
        raise SwimInputError(f"camera must be a FisheyeCameraModel, got {type(camera).__name__}")
    if not isinstance(simulated, xr.Dataset) or "y" not in simulated.dims or "x" not in simulated.dims:
        raise SwimInputError("simulated must be an xarray.Dataset from swim.render with dims (y, x)")
    dirs, valid = camera.directions()
    names = [n for n, v in simulated.data_vars.items()
             if n not in ("rgb", "view_azimuth", "view_zenith") and v.dims[-2:] == ("y", "x") and v.ndim in (2, 3)
             and np.issubdtype(v.dtype, np.number)]
    layers = []
    for n in names:
        a = np.asarray(simulated[n].values, dtype=float)
        layers.append(a[None] if a.ndim == 2 else a)
    if "rgb" in simulated:
        rgb = np.asarray(simulated["rgb"].transpose("y", "x", ...).values)
        layers.append(np.moveaxis(srgb_to_linear(rgb / _full_scale(rgb)), -1, 0))
    if not layers:
        raise SwimInputError("simulated image has no variables with dims (y, x) to reproject")
    stack = np.concatenate(layers, axis=0)
    try:
        cam = swim_camera_of(simulated)
    except SwimInputError as err:
        if "view_azimuth" not in simulated or "view_zenith" not in simulated:
            raise SwimInputError(f"cannot reproject: {err}; and no view_azimuth/view_zenith") from None
        log.warning("reprojecting by nearest view directions (%s)", err)
        sampled = _sample_by_directions(simulated, stack, dirs, valid)
    else:
        row, col = cam.pixel_of_direction(np.where(valid[..., None], dirs, np.nan))
        wrap = getattr(cam, "kind", "") == "panorama" and getattr(cam, "azimuth_span_deg", 0.0) >= 360.0
        sampled = _bilinear(stack, row, col, wrap_cols=wrap)
    sampled[:, ~valid] = np.nan

    data: dict[str, Any] = {}
    i = 0
    for n, layer in zip(names, layers):
        k = layer.shape[0]
        src = simulated[n]
        block = sampled[i:i + k]
        data[n] = (src.dims, block if src.ndim == 3 else block[0], dict(src.attrs))
        i += k
    coords: dict[str, Any] = {}
    if "wavelength" in simulated.coords:
        coords["wavelength"] = simulated["wavelength"]
    if "rgb" in simulated:
        lin = np.moveaxis(sampled[i:i + 3], 0, -1)
        data["rgb_linear"] = (("y", "x", "channel"), lin, {"units": "1", "long_name":
                              "simulated display RGB, linearised with the sRGB EOTF, reprojected"})
        enc = np.rint(linear_to_srgb(np.nan_to_num(lin)) * 255.0).astype(np.uint8)
        data["rgb"] = (("y", "x", "channel"), enc, {"long_name": "simulated 8-bit sRGB, reprojected"})
        coords["channel"] = _CHANNELS
    az, zen = frames.azimuth_zenith_from_enu(_finite_dirs(dirs))
    data["view_azimuth"] = (("y", "x"), np.where(valid, az, np.nan), {"units": "degree"})
    data["view_zenith"] = (("y", "x"), np.where(valid, zen, np.nan), {"units": "degree"})
    finite = np.all(np.isfinite(sampled), axis=0)
    data["valid"] = (("y", "x"), valid & finite, {"long_name": "camera pixel valid and simulation finite"})
    data["solid_angle"] = (("y", "x"), camera.pixel_solid_angles(), {"units": "sr"})
    attrs = {k: v for k, v in simulated.attrs.items() if not k.startswith("camera")}
    attrs.update(camera.to_attrs())
    attrs["swim_reprojected"] = "fisheye"
    return xr.Dataset(data, coords=coords, attrs=attrs)


# --------------------------------------------------------------------------------------------------------
# statistics
# --------------------------------------------------------------------------------------------------------
def _paired(a, b, weights):
    x = np.asarray(a, dtype=float)
    y = np.asarray(b, dtype=float)
    if x.shape != y.shape:
        raise SwimInputError(f"the two images must have the same shape, got {x.shape} and {y.shape}")
    w = np.ones(x.shape) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != x.shape:
        try:
            w = np.broadcast_to(w, x.shape)
        except ValueError:
            raise SwimInputError(f"weights must have shape {x.shape}, got {w.shape}") from None
    if np.any(w[np.isfinite(w)] < 0):
        raise SwimInputError("weights must be >= 0")
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(w) & (w > 0)
    return x[ok], y[ok], w[ok]


def pearson_r(a, b, weights=None) -> float:
    """(Weighted) Pearson correlation coefficient of paired values (paper Eq. 37).

    ``r = sum w (x - xm)(y - ym) / sqrt(sum w (x - xm)^2 sum w (y - ym)^2)`` with weighted means ``xm``,
    ``ym``; with equal weights this is Eq. 37, ``(N sum xy - sum x sum y) / sqrt([N sum x^2 - (sum x)^2]
    [N sum y^2 - (sum y)^2])``. Pairs with a non-finite value or weight, or zero weight, are ignored.

    Parameters
    ----------
    a, b : array_like
        Same shape.
    weights : array_like, optional
        Non-negative, broadcastable to the shape of ``a``; default equal weights.

    Returns
    -------
    float
        r in [-1, 1]; NaN with fewer than 2 pairs or when either image is constant.

    Raises
    ------
    SwimInputError
        For different shapes or negative weights.
    """
    x, y, w = _paired(a, b, weights)
    if x.size < 2:
        return float("nan")
    sw = w.sum()
    dx = x - np.sum(w * x) / sw
    dy = y - np.sum(w * y) / sw
    sxx = np.sum(w * dx * dx)
    syy = np.sum(w * dy * dy)
    if not (sxx > 0 and syy > 0):
        return float("nan")
    return float(np.clip(np.sum(w * dx * dy) / math.sqrt(sxx * syy), -1.0, 1.0))


def linear_fit(x, y, weights=None, fit: str = "gain_offset") -> tuple[float, float]:
    """Weighted least-squares coefficients (gain a, offset b) of ``y ~ a x + b``.

    Parameters
    ----------
    x, y : array_like
        Simulated and observed values (same shape).
    weights : array_like, optional
        Non-negative weights.
    fit : {"none", "gain", "gain_offset"}
        ``"none"``: (1, 0); ``"gain"``: b = 0, ``a = sum w x y / sum w x^2``; ``"gain_offset"``: both.

    Returns
    -------
    tuple of float
        ``(a, b)``; NaN where undetermined (no pairs, or constant x for ``gain_offset``).

    Raises
    ------
    SwimInputError
        For an unknown ``fit``, different shapes or negative weights.
    """
    if fit not in FITS:
        raise SwimInputError(f"fit must be one of {FITS}, got {fit!r}")
    if fit == "none":
        return 1.0, 0.0
    xs, ys, w = _paired(x, y, weights)
    if xs.size == 0:
        return float("nan"), float("nan")
    if fit == "gain":
        sxx = np.sum(w * xs * xs)
        return (float(np.sum(w * xs * ys) / sxx) if sxx > 0 else float("nan")), 0.0
    sw = w.sum()
    xm = np.sum(w * xs) / sw
    ym = np.sum(w * ys) / sw
    sxx = np.sum(w * (xs - xm) ** 2)
    if not sxx > 0:
        return float("nan"), float("nan")
    a = float(np.sum(w * (xs - xm) * (ys - ym)) / sxx)
    return a, float(ym - a * xm)


def sun_angle_deg(dirs: np.ndarray, sun_azimuth_deg: float, sun_zenith_deg: float) -> np.ndarray:
    """Angle [deg] between view directions (..., 3) (ENU) and the sun at (azimuth, zenith) [deg]; NaN for NaN."""
    sun = frames.enu_from_azimuth_zenith(float(sun_azimuth_deg), float(sun_zenith_deg))
    d = np.asarray(dirs, dtype=float)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    cos = np.clip(d @ sun, -1.0, 1.0)
    # atan2 of |d x s| and d.s: accurate for small angles
    sin = np.linalg.norm(np.cross(d, sun), axis=-1)
    return np.degrees(np.arctan2(sin, cos))


# --------------------------------------------------------------------------------------------------------
# image comparison
# --------------------------------------------------------------------------------------------------------
def read_camera_image(path, camera: FisheyeCameraModel | None = None) -> np.ndarray:
    """Read a camera JPEG/PNG (any format Pillow reads) as an 8-bit RGB array (height, width, 3).

    Raises
    ------
    SwimInputError
        If the file cannot be read, or its size differs from the camera model's (height, width).
    """
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            rgb = np.asarray(im.convert("RGB"), dtype=np.uint8)
    except (OSError, UnidentifiedImageError) as err:
        raise SwimInputError(f"camera image {str(path)!r} cannot be read: {err}") from None
    if camera is not None and rgb.shape[:2] != camera.shape:
        raise SwimInputError(f"camera image {str(path)!r} has (height, width) = {rgb.shape[:2]} px but the camera "
                             f"model expects {camera.shape} px")
    return rgb


def _observed_channels(observed, quantity: str, shape) -> np.ndarray:
    """Observed image -> (3, ny, nx) float in the compared units."""
    obs = read_camera_image(observed) if isinstance(observed, (str, Path)) else np.asarray(observed)
    if obs.ndim != 3 or obs.shape[:2] != tuple(shape) or obs.shape[2] < 3:
        raise SwimInputError(f"observed image must have shape {tuple(shape) + (3,)} (height, width, RGB), got "
                             f"{obs.shape}")
    obs = obs[..., :3]
    if np.issubdtype(obs.dtype, np.integer):
        enc = obs.astype(float) / _full_scale(obs)
        vals = enc if quantity == "srgb" else srgb_to_linear(enc)
    else:
        vals = obs.astype(float)  # floats: already in the compared units
    return np.moveaxis(vals, -1, 0)


def _simulated_channels(sim: xr.Dataset, quantity: str) -> np.ndarray:
    """Reprojected simulation -> (3, ny, nx) float in the compared units."""
    if quantity == "radiance":
        if "radiance" not in sim:
            raise SwimInputError("quantity='radiance' needs the simulated variable 'radiance'")
        return np.asarray(sim["radiance"].transpose("wavelength", "y", "x").values, dtype=float)[:3]
    if "rgb_linear" not in sim:
        raise SwimInputError(f"quantity={quantity!r} needs the simulated 'rgb' image")
    lin = np.moveaxis(np.asarray(sim["rgb_linear"].transpose("y", "x", "channel").values, dtype=float), -1, 0)
    return linear_to_srgb(lin) if quantity == "srgb" else lin


def _downsample_factor(value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise SwimInputError(f"downsample must be an integer >= 1, got {value!r}")
    return int(value)


def block_mean_codes(image, factor: int) -> np.ndarray:
    """An image (ny, nx, c) of display codes averaged over blocks of ``factor`` x ``factor`` pixels, rounded to its
    dtype (the grid of :meth:`FisheyeCameraModel.downsampled`)."""
    img = np.asarray(image)
    factor = _downsample_factor(factor)
    if factor == 1:
        return img
    mean = np.moveaxis(reduce_blocks(np.moveaxis(img.astype(float), -1, 0), factor, np.mean), 0, -1)
    return np.rint(mean).astype(img.dtype) if np.issubdtype(img.dtype, np.integer) else mean


def compare_images(simulated, observed, camera: FisheyeCameraModel, *, sun_azimuth_deg=None, sun_zenith_deg=None,
                   sun_exclusion_deg: float = 5.0, fit: str = "none", min_elevation_deg: float = 0.0,
                   quantity: str = "linear_rgb", weighting: str = "solid_angle",
                   exclude_saturated: bool = False, downsample: int = 1) -> xr.Dataset:
    """Pearson r per channel and r-bar (paper Eq. 37), RMSE, bias and a difference image of two sky images.

    Parameters
    ----------
    simulated : xarray.Dataset or array_like
        A :func:`swim.render` image (reprojected here with :func:`reproject`), an already reprojected one
        (attribute ``swim_reprojected``), or an array (height, width, 3) on the camera grid, already in the
        compared units.
    observed : str, Path or array_like
        Camera image file, or array (height, width, 3): integer arrays are display-encoded (linearised for
        ``"linear_rgb"``/``"radiance"``), float arrays are taken as already in the compared units.
    camera : FisheyeCameraModel
        Geometry of ``observed``.
    sun_azimuth_deg, sun_zenith_deg : float, optional
        Sun position [deg] in the observer's frame; default the simulated image's ``sun_azimuth_deg``,
        ``sun_zenith_deg`` attributes. Needed when ``sun_exclusion_deg > 0``.
    sun_exclusion_deg : float, default 5
        Pixels within this angle [deg] of the sun's centre are excluded (paper Sect. 4.2.3: 5 deg; Table 4:
        12 deg), in [0, 180].
    fit : {"none", "gain", "gain_offset"}
        Brightness fit of the simulation onto the observation per channel (module docstring).
    min_elevation_deg : float, default 0
        Pixels below this elevation [deg] are excluded, in [-90, 90].
    quantity : {"linear_rgb", "srgb", "radiance"}
        What is compared (module docstring).
    weighting : {"solid_angle", "pixel"}
        Pixel weights: solid angle [sr] or 1 (Eq. 37 literally).
    exclude_saturated : bool, default False
        Also exclude camera pixels with any 8-bit channel at full scale (only for integer observed images).
    downsample : int, default 1
        Compare on pixels ``downsample`` times larger (:meth:`FisheyeCameraModel.downsampled`): the camera image
        averaged over blocks of ``downsample`` x ``downsample`` pixels in the compared units, the simulation
        reprojected onto the coarser grid, a block saturated where any of its pixels is; a 2048^2 image by 4 costs
        a sixteenth.

    Returns
    -------
    xarray.Dataset
        Per ``channel`` (R, G, B): ``r``, ``gain``, ``offset``, ``rmse``, ``bias`` (after the fit),
        ``rmse_raw``, ``bias_raw`` (without); scalars ``r_mean`` (r-bar, the mean of the three r), ``n_pixels``,
        ``solid_angle_sr`` (total solid angle compared); images (y, x, channel): ``simulated`` (after the fit),
        ``observed``, ``difference`` (simulated after fit minus observed; NaN outside the mask); ``mask``
        (y, x). Attributes: the options, the sun position and the reference.

    Raises
    ------
    SwimInputError
        For unknown options, out-of-range angles, shape mismatches, a missing sun position, or no valid
        pixels.
    """
    sun_excl, min_el = _checked_options(camera, quantity, fit, weighting, sun_exclusion_deg, min_elevation_deg)
    full_camera, factor = camera, _downsample_factor(downsample)
    camera = camera.downsampled(factor)
    dirs, valid = camera.directions()
    sim, attrs_src = _simulated_on_grid(simulated, camera, quantity)
    obs = reduce_blocks(_observed_channels(observed, quantity, full_camera.shape), factor, np.mean)

    if sun_azimuth_deg is None and sun_zenith_deg is None and attrs_src:
        sun_azimuth_deg = attrs_src.get("sun_azimuth_deg")
        sun_zenith_deg = attrs_src.get("sun_zenith_deg")
    mask = _compared_pixels(valid, dirs, sim, obs, min_el, sun_excl, sun_azimuth_deg, sun_zenith_deg,
                            observed if exclude_saturated else None, factor)
    n = int(mask.sum())
    if n < 2:
        raise SwimInputError(f"only {n} pixels remain after masking (image circle, horizon, min_elevation_deg="
                             f"{min_el}, sun_exclusion_deg={sun_excl}): nothing to compare")
    omega = camera.pixel_solid_angles()
    weights = omega if weighting == "solid_angle" else np.ones(camera.shape)
    scores = _channel_scores(sim, obs, mask, np.where(mask, weights, 0.0), fit)
    r_mean = float(np.mean(scores["r"]))
    log.info("compare: r = %s, r_mean = %.4f over %d px (%s, fit %s)", np.round(scores["r"], 4), r_mean, n, quantity,
             fit)

    attrs = {
        "quantity": quantity, "fit": fit, "weighting": weighting, "sun_exclusion_deg": sun_excl,
        "min_elevation_deg": min_el, "exclude_saturated": int(bool(exclude_saturated)), "downsample": factor,
        "sun_azimuth_deg": float("nan") if sun_azimuth_deg is None else float(sun_azimuth_deg),
        "sun_zenith_deg": float("nan") if sun_zenith_deg is None else float(sun_zenith_deg),
        "references": _REFERENCE,
    }
    return _comparison_dataset(scores, r_mean, n, float(omega[mask].sum()), obs, mask, quantity, attrs)


def _checked_options(camera, quantity, fit, weighting, sun_exclusion_deg, min_elevation_deg):
    """Raise for an unknown option or an angle out of range; returns (sun exclusion, min elevation) [deg]."""
    if not isinstance(camera, FisheyeCameraModel):
        raise SwimInputError(f"camera must be a FisheyeCameraModel, got {type(camera).__name__}")
    if quantity not in QUANTITIES:
        raise SwimInputError(f"quantity must be one of {QUANTITIES}, got {quantity!r}")
    if fit not in FITS:
        raise SwimInputError(f"fit must be one of {FITS}, got {fit!r}")
    if weighting not in WEIGHTINGS:
        raise SwimInputError(f"weighting must be one of {WEIGHTINGS}, got {weighting!r}")
    try:
        sun_excl = float(sun_exclusion_deg)
        min_el = float(min_elevation_deg)
    except (TypeError, ValueError):
        raise SwimInputError("sun_exclusion_deg and min_elevation_deg must be numbers [deg]") from None
    if not 0.0 <= sun_excl <= 180.0:
        raise SwimInputError(f"sun_exclusion_deg must be in [0, 180] deg, got {sun_exclusion_deg}")
    if not -90.0 <= min_el <= 90.0:
        raise SwimInputError(f"min_elevation_deg must be in [-90, 90] deg, got {min_elevation_deg}")
    return sun_excl, min_el


def _simulated_on_grid(simulated, camera: FisheyeCameraModel, quantity: str):
    """The simulation on the camera's grid, (3, ny, nx) in the compared units, and its attributes (a dict; empty
    for an array)."""
    if not isinstance(simulated, xr.Dataset):
        arr = np.asarray(simulated, dtype=float)
        if arr.shape != camera.shape + (3,):
            raise SwimInputError(f"simulated array must have shape {camera.shape + (3,)}, got {arr.shape}")
        return np.moveaxis(arr, -1, 0), {}
    sim_ds = simulated if simulated.attrs.get("swim_reprojected") == "fisheye" else reproject(simulated, camera)
    if (sim_ds.sizes["y"], sim_ds.sizes["x"]) != camera.shape:
        raise SwimInputError(f"reprojected simulation has shape {(sim_ds.sizes['y'], sim_ds.sizes['x'])}, the "
                             f"camera {camera.shape}")
    return _simulated_channels(sim_ds, quantity), dict(simulated.attrs)


def _compared_pixels(valid, dirs, sim, obs, min_el, sun_excl, sun_azimuth_deg, sun_zenith_deg, saturated_from,
                     factor) -> np.ndarray:
    """The mask (ny, nx) of the pixels compared: in the image circle, finite in both images, above ``min_el``, away
    from the sun, and (where ``saturated_from``, the observed image, is given) not saturated."""
    mask = valid & np.all(np.isfinite(sim), axis=0) & np.all(np.isfinite(obs), axis=0)
    _, zen = frames.azimuth_zenith_from_enu(_finite_dirs(dirs))
    mask &= (90.0 - zen) >= min_el
    if sun_excl > 0.0:
        if sun_azimuth_deg is None or sun_zenith_deg is None:
            raise SwimInputError("sun_azimuth_deg and sun_zenith_deg [deg] are needed for the sun exclusion "
                                 "(or set sun_exclusion_deg=0)")
        angle = sun_angle_deg(_finite_dirs(dirs), sun_azimuth_deg, sun_zenith_deg)
        mask &= angle > sun_excl
    if saturated_from is not None:
        from_file = isinstance(saturated_from, (str, Path))
        raw = read_camera_image(saturated_from) if from_file else np.asarray(saturated_from)
        if np.issubdtype(raw.dtype, np.integer):
            mask &= ~reduce_blocks(np.any(raw[..., :3] >= _full_scale(raw), axis=-1), factor, np.any)
    return mask


def _channel_scores(sim, obs, mask, w, fit: str) -> dict[str, np.ndarray]:
    """Per channel (3,): r, the fit's gain and offset, RMSE and bias after the fit and without it; and the images
    (3, ny, nx) after the fit (``fitted``) and their difference (``diff``), NaN outside the mask."""
    out = {name: np.empty(3) for name in ("r", "gain", "offset", "rmse", "bias", "rmse_raw", "bias_raw")}
    r, gain, offset, rmse, bias, rmse_raw, bias_raw = out.values()
    fitted = np.full_like(sim, np.nan)
    diff = np.full_like(sim, np.nan)
    sw = w[mask].sum()
    for c in range(3):
        x = sim[c][mask]
        y = obs[c][mask]
        wc = w[mask]
        r[c] = pearson_r(x, y, wc)
        gain[c], offset[c] = linear_fit(x, y, wc, fit)
        d = gain[c] * x + offset[c] - y
        d0 = x - y
        bias[c] = np.sum(wc * d) / sw
        rmse[c] = math.sqrt(np.sum(wc * d * d) / sw)
        bias_raw[c] = np.sum(wc * d0) / sw
        rmse_raw[c] = math.sqrt(np.sum(wc * d0 * d0) / sw)
        fitted[c][mask] = gain[c] * x + offset[c]
        diff[c][mask] = d
    return {**out, "fitted": fitted, "diff": diff}


def _comparison_dataset(s, r_mean, n, solid_angle_sr, obs, mask, quantity, attrs) -> xr.Dataset:
    """The result of :func:`compare_images` from the channels' scores ``s`` (:func:`_channel_scores`)."""
    unit = {"quantity": quantity}
    chan = ("channel",)
    img = ("y", "x", "channel")
    return xr.Dataset(
        {
            "r": (chan, s["r"], {"long_name": "Pearson correlation coefficient (Eq. 37)", "units": "1"}),
            "r_mean": ((), r_mean, {"long_name": "mean of r over R, G, B (r-bar)", "units": "1"}),
            "gain": (chan, s["gain"], {"long_name": "fitted gain a of observed ~ a simulated + b", "units": "1"}),
            "offset": (chan, s["offset"], {"long_name": "fitted offset b", **unit}),
            "rmse": (chan, s["rmse"], {"long_name": "RMSE of a simulated + b - observed", **unit}),
            "bias": (chan, s["bias"], {"long_name": "mean of a simulated + b - observed", **unit}),
            "rmse_raw": (chan, s["rmse_raw"], {"long_name": "RMSE of simulated - observed (no fit)", **unit}),
            "bias_raw": (chan, s["bias_raw"], {"long_name": "mean of simulated - observed (no fit)", **unit}),
            "n_pixels": ((), n, {"long_name": "number of compared pixel pairs"}),
            "solid_angle_sr": ((), solid_angle_sr, {"units": "sr", "long_name": "solid angle compared"}),
            "simulated": (img, np.moveaxis(s["fitted"], 0, -1), {"long_name": "simulated after the fit", **unit}),
            "observed": (img, np.moveaxis(np.where(mask, obs, np.nan), 0, -1), {"long_name": "observed", **unit}),
            "difference": (img, np.moveaxis(s["diff"], 0, -1), {"long_name": "simulated after fit - observed", **unit}),
            "mask": (("y", "x"), mask, {"long_name": "compared pixels"}),
        },
        coords={"channel": _CHANNELS},
        attrs=attrs,
    )


def scores_dict(result: xr.Dataset) -> dict[str, Any]:
    """JSON-ready summary of :func:`compare_images` (scalars and per-channel lists; no images); NaN -> None."""
    def clean(v):
        v = float(v)
        return None if not math.isfinite(v) else v

    out: dict[str, Any] = {"channels": [str(c) for c in result["channel"].values]}
    for name in ("r", "gain", "offset", "rmse", "bias", "rmse_raw", "bias_raw"):
        out[name] = [clean(v) for v in result[name].values]
    out["r_mean"] = clean(result["r_mean"].values)
    out["n_pixels"] = int(result["n_pixels"].values)
    out["solid_angle_sr"] = clean(result["solid_angle_sr"].values)
    for k, v in result.attrs.items():
        out[k] = v.item() if isinstance(v, np.generic) else v
    for k in ("sun_azimuth_deg", "sun_zenith_deg"):
        out[k] = clean(out[k])
    return out


def difference_rgb8(result: xr.Dataset, scale: float | None = None) -> np.ndarray:
    """Colour-coded difference image (height, width, 3) uint8 of a :func:`compare_images` result.

    The channel mean of the difference ``d`` (simulated after fit minus observed) is mapped to a diverging
    scale: white at 0, saturating to red for ``d >= +scale`` (simulation too bright) and to blue for
    ``d <= -scale`` (too dark); pixels outside the comparison mask are black.

    Parameters
    ----------
    result : xarray.Dataset
        Output of :func:`compare_images`.
    scale : float, optional
        Difference shown at full colour, > 0 [compared units]; default the 99th percentile of |d| (1e-12 if 0).

    Raises
    ------
    SwimInputError
        For a non-positive scale.
    """
    d = np.mean(np.asarray(result["difference"].transpose("y", "x", "channel").values, dtype=float), axis=-1)
    mask = np.asarray(result["mask"].values, dtype=bool) & np.isfinite(d)
    if scale is None:
        scale = float(np.percentile(np.abs(d[mask]), 99)) if mask.any() else 1.0
        scale = scale if scale > 0 else 1e-12
    elif not (np.isfinite(scale) and scale > 0):
        raise SwimInputError(f"scale must be a positive number [compared units], got {scale}")
    t = np.clip(np.nan_to_num(d) / scale, -1.0, 1.0)
    out = np.ones(d.shape + (3,))
    pos = t > 0
    out[pos, 1] -= t[pos]
    out[pos, 2] -= t[pos]
    neg = t < 0
    out[neg, 0] += t[neg]
    out[neg, 1] += t[neg]
    out[~mask] = 0.0
    return np.rint(out * 255.0).astype(np.uint8)


def write_difference_png(result: xr.Dataset, path, scale: float | None = None) -> Path:
    """Write :func:`difference_rgb8` as a PNG (atomically); returns the path."""
    from PIL import Image

    rgb = difference_rgb8(result, scale)
    return atomic_write(Path(path), lambda tmp: Image.fromarray(rgb, "RGB").save(tmp, format="PNG"))


def write_json(data: dict, path) -> Path:
    """Write a JSON document (atomically, UTF-8, indented); returns the path."""
    text = json.dumps(data, indent=2, sort_keys=False)

    def writer(tmp):
        Path(tmp).write_text(text + "\n", encoding="utf-8")

    return atomic_write(Path(path), writer)
