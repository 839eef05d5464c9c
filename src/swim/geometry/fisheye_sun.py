"""Sun detection in all-sky images and the fit of a fisheye camera's orientation to the sun's positions.

:func:`detect_sun` finds the sun's disc (a round blob of clipped pixels) in a clear image;
:func:`fit_orientation_from_sun` fits a :class:`swim.geometry.fisheye.FisheyeCameraModel`'s rotation (and
optionally its centre, scale and tilt) to the sun's detected pixels at known sun positions. Both are importable
from :mod:`swim.geometry.fisheye` too.

References
----------
Urquhart, B. et al. (2015), Development of a sky imaging system for short-term solar power forecasting, Atmos.
Meas. Tech. 8, 875-890, doi:10.5194/amt-8-875-2015 (orientation from the sun's position).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import frames
from ..errors import SwimInputError
from .cameras import _as_float

if TYPE_CHECKING:
    from .fisheye import FisheyeCameraModel

# the camera model's logger: these functions log as they did as part of swim.geometry.fisheye
log = logging.getLogger("swim.geometry.fisheye")

#: A blob is sun-like when its pixels fill at least this share of the circle about its centroid through its farthest
#: pixel (a disc 1, a square 0.64, the ragged edge of a saturated cloud far less).
SUN_MIN_ROUNDNESS = 0.4
#: A blob larger than this share of the image is not the sun (with its glare), but a saturated cloud or sky.
SUN_MAX_AREA_FRACTION = 0.03


def detect_sun(image, *, saturation: float = 0.98, valid=None, min_pixels: int = 9, model=None,
               sun_zenith_deg=None, radius_tolerance: float = 0.1) -> tuple[float, float]:
    """Centroid (row, col) [px] of the sun: the largest round blob of saturated pixels, where the sun can be.

    A pixel is saturated where its *smallest* channel reaches ``saturation`` times the full scale (255 for
    8-bit, 65535 for 16-bit integer images, 1.0 for floats), i.e. it is clipped white. Connected saturated
    pixels (8-connectivity) form blobs. A blob is a candidate when it is round (its pixels fill at least
    :data:`SUN_MIN_ROUNDNESS` of the circle about its centroid through its farthest pixel), no larger than
    :data:`SUN_MAX_AREA_FRACTION` of the image and, given the camera ``model`` and the sun's zenith angle, at the
    polar radius where the model puts that zenith angle (within ``radius_tolerance``); bright cloud edges and lens
    flare fail these tests. The largest candidate wins; a larger blob that is not one is logged.

    Parameters
    ----------
    image : array_like
        Shape (ny, nx) or (ny, nx, channels).
    saturation : float, default 0.98
        Fraction of full scale [-], in (0, 1].
    valid : array_like of bool, optional
        Shape (ny, nx): only these pixels are searched.
    min_pixels : int, default 9
        Smallest blob accepted [px] (speckles of saturated cloud are smaller than the sun's disc and glare).
    model : FisheyeCameraModel, optional
        The camera (its centre and projection; its rotation is not needed), with ``sun_zenith_deg``.
    sun_zenith_deg : float, optional
        The sun's zenith angle [deg] at the image's time.
    radius_tolerance : float, default 0.1
        Allowed relative difference of a candidate's distance from the image centre and the model's polar radius of
        the sun's zenith angle (plus 3 px) [-].

    Returns
    -------
    tuple of float
        ``(row, col)`` in continuous pixel coordinates.

    Raises
    ------
    SwimInputError
        For a bad shape or threshold, no saturated blob, or no blob that can be the sun (the message says what was
        found and why it was refused).
    """
    from scipy import ndimage

    img = np.asarray(image)
    if img.ndim not in (2, 3):
        raise SwimInputError(f"image must have shape (ny, nx) or (ny, nx, channels), got {img.shape}")
    sat = _as_float("saturation", saturation, 0.0, 1.0, lo_open=True, unit="fraction of full scale")
    full = float(np.iinfo(img.dtype).max) if np.issubdtype(img.dtype, np.integer) else 1.0
    low = img.min(axis=-1) if img.ndim == 3 else img
    hot = np.asarray(low, dtype=float) >= sat * full
    if valid is not None:
        valid = np.asarray(valid, dtype=bool)
        if valid.shape != hot.shape:
            raise SwimInputError(f"valid must have shape {hot.shape}, got {valid.shape}")
        hot &= valid
    labels, n = ndimage.label(hot, structure=np.ones((3, 3)))
    if n == 0:
        raise SwimInputError(f"no saturated pixels (smallest channel >= {sat} x full scale) found: the sun is not "
                             "visible in this image; give the sun's pixel explicitly")
    expected = _sun_radius_px(model, sun_zenith_deg)
    blobs = _blobs(labels, n)
    reasons = {}
    for b in blobs:
        reasons[b["label"]] = _refusal(b, min_pixels, hot.size, expected, radius_tolerance, model)
    candidates = [b for b in blobs if reasons[b["label"]] is None]
    largest = max(blobs, key=lambda b: b["area"])
    if not candidates:
        raise SwimInputError(f"no saturated blob can be the sun: the largest ({largest['area']} px at row "
                             f"{largest['row']:.0f}, col {largest['col']:.0f}) {reasons[largest['label']]}; give the "
                             "sun's pixel explicitly, a valid mask or another saturation")
    best = max(candidates, key=lambda b: b["area"])
    if best is not largest:
        log.warning("detect_sun: a larger saturated blob (%d px at row %.0f, col %.0f) %s; the sun taken at row %.0f, "
                    "col %.0f (%d px)", largest["area"], largest["row"], largest["col"], reasons[largest["label"]],
                    best["row"], best["col"], best["area"])
    return best["row"], best["col"]


def _blobs(labels, n):
    """Each blob's label, area [px], centroid and roundness."""
    from scipy import ndimage

    index = np.arange(1, n + 1)
    areas = ndimage.sum(np.ones_like(labels), labels, index=index)
    centres = ndimage.center_of_mass(labels > 0, labels, index)
    out = []
    for lab, area, (row, col), sl in zip(index, areas, centres, ndimage.find_objects(labels)):
        rr, cc = np.nonzero(labels[sl] == lab)
        r_max = float(np.sqrt(np.max((rr + sl[0].start - row) ** 2 + (cc + sl[1].start - col) ** 2))) + 0.5
        out.append({"label": int(lab), "area": int(area), "row": float(row), "col": float(col),
                    "roundness": float(area / (math.pi * r_max * r_max))})
    return out


def _refusal(blob, min_pixels, n_pixels, expected, tolerance, model):
    """Why a blob cannot be the sun, or None."""
    if blob["area"] < min_pixels:
        return f"has fewer than min_pixels={min_pixels} px"
    if blob["area"] > SUN_MAX_AREA_FRACTION * n_pixels:
        return f"covers more than {SUN_MAX_AREA_FRACTION:.0%} of the image (a saturated cloud or sky)"
    if blob["area"] >= 5 and blob["roundness"] < SUN_MIN_ROUNDNESS:
        return f"is not round (it fills {blob['roundness']:.2f} of its circle, the sun's disc and glare >= " \
               f"{SUN_MIN_ROUNDNESS})"
    if expected is not None:
        radius = math.hypot(blob["row"] - model.cy, blob["col"] - model.cx)
        if abs(radius - expected) > tolerance * expected + 3.0:
            return (f"lies {radius:.0f} px from the image centre, where the camera puts the sun's zenith angle at "
                    f"{expected:.0f} px")
    return None


def _sun_radius_px(model, sun_zenith_deg):
    """The polar radius [px] of the sun's zenith angle in an untilted ``model`` (None without both)."""
    from .fisheye import FisheyeCameraModel

    if model is None or sun_zenith_deg is None:
        return None
    if not isinstance(model, FisheyeCameraModel):
        raise SwimInputError(f"model must be a FisheyeCameraModel, got {type(model).__name__}")
    zen = _as_float("sun_zenith_deg", sun_zenith_deg, 0.0, 180.0, unit="deg")
    level = dataclasses.replace(model, tilt_deg=0.0)
    dirs = frames.enu_from_azimuth_zenith(np.arange(0.0, 360.0, 45.0), np.full(8, zen))
    row, col = level.pixel_of_direction(dirs)
    radius = np.hypot(np.asarray(row) - model.cy, np.asarray(col) - model.cx)
    if not np.any(np.isfinite(radius)):
        raise SwimInputError(f"the camera does not see the sun's zenith angle {zen:g} deg (max_zenith_deg "
                             f"{model.max_zenith_deg:g})")
    return float(np.nanmean(radius))


@dataclass(frozen=True)
class OrientationFit:
    """Result of :func:`fit_orientation_from_sun`.

    Attributes
    ----------
    model : FisheyeCameraModel
        The input model with the fitted parameters.
    parameters : dict
        Fitted values: ``azimuth_up_deg`` and, where fitted, ``cx``, ``cy`` [px], ``scale`` [-] (factor applied
        to the focal length or the polynomial coefficients), ``tilt_deg``, ``tilt_azimuth_deg``.
    residuals_px : numpy.ndarray
        Shape (n, 2): predicted minus detected (row, col) of the sun [px].
    rms_px : float
        Root-mean-square of the residual distances [px].
    sun_pixels : numpy.ndarray
        Shape (n, 2): the detected (or given) sun pixels (row, col).
    """

    model: FisheyeCameraModel
    parameters: dict
    residuals_px: np.ndarray
    rms_px: float
    sun_pixels: np.ndarray


def fit_orientation_from_sun(model: FisheyeCameraModel, sun_azimuth_deg, sun_zenith_deg, sun_pixels=None, *,
                             images=None, fit_centre: bool = False, fit_scale: bool = False,
                             fit_tilt: bool = False, saturation: float = 0.98) -> OrientationFit:
    """Fit the camera's rotation (and optionally centre, scale, tilt) to the sun's position in clear images.

    Minimises the squared distance [px] between the sun's detected pixel and the pixel the model predicts for
    the sun's direction (from an ephemeris, e.g. :func:`swim.geometry.sun.sun_position`), over all images,
    with :func:`scipy.optimize.least_squares`. The starting rotation is the circular mean of the rotations
    that map each sun exactly onto its detected polar angle; the other parameters start from ``model``. The
    image handedness (``mirror``) and the projection are taken from ``model`` and not fitted.

    Parameters
    ----------
    model : FisheyeCameraModel
        First guess (image size, projection, focal length, mirror, ...).
    sun_azimuth_deg, sun_zenith_deg : array_like
        Shape (n,): the sun's azimuth and zenith angle [deg] at the times of the images.
    sun_pixels : array_like, optional
        Shape (n, 2): detected sun positions (row, col) [px]; default: :func:`detect_sun` on ``images``.
    images : sequence of array_like, optional
        n clear-sky images (only used when ``sun_pixels`` is None).
    fit_centre, fit_scale, fit_tilt : bool
        Also fit (cx, cy), a scale factor of r(theta), or the tilt (2 parameters each for centre and tilt).
        Needs ``2 n >= number of parameters`` (e.g. 2 suns for rotation + centre, 3 with scale).
    saturation : float
        Passed to :func:`detect_sun`.

    Returns
    -------
    OrientationFit

    Raises
    ------
    SwimInputError
        For inconsistent lengths, too few suns for the parameters, suns outside the image circle, or no
        sun found in an image.
    """
    from scipy.optimize import least_squares

    az, zen, obs = _sun_observations(model, sun_azimuth_deg, sun_zenith_deg, sun_pixels, images, saturation)
    n_params = 1 + 2 * fit_centre + fit_scale + 2 * fit_tilt
    if 2 * az.size < n_params:
        raise SwimInputError(f"{n_params} parameters need at least {math.ceil(n_params / 2)} sun positions, got "
                             f"{az.size}")
    sun_dirs = frames.enu_from_azimuth_zenith(az, zen)
    x0 = _first_guess(model, obs, sun_dirs, fit_centre, fit_scale, fit_tilt)

    def build(x) -> tuple[FisheyeCameraModel, dict]:
        return _fitted_model(model, x, fit_centre, fit_scale, fit_tilt)

    big = 10.0 * max(model.width, model.height)

    def residuals(x):
        m, _ = build(x)
        row, col = m.pixel_of_direction(sun_dirs)
        res = np.stack([row - obs[:, 0], col - obs[:, 1]], axis=-1)
        return np.where(np.isfinite(res), res, big).ravel()

    sol = least_squares(residuals, np.asarray(x0, dtype=float), x_scale="jac", method="trf")
    fitted, params = build(sol.x)
    row, col = fitted.pixel_of_direction(sun_dirs)
    res = np.stack([row - obs[:, 0], col - obs[:, 1]], axis=-1)
    if not np.all(np.isfinite(res)):
        raise SwimInputError("a sun direction falls outside the fitted image circle: check sun_zenith_deg against "
                             "max_zenith_deg and the sun pixels")
    rms = float(np.sqrt(np.mean(np.sum(res**2, axis=-1))))
    log.info("orientation fit from %d sun positions: %s, rms %.2f px", az.size, params, rms)
    return OrientationFit(model=fitted, parameters=params, residuals_px=res, rms_px=rms, sun_pixels=obs)


def _sun_observations(model, sun_azimuth_deg, sun_zenith_deg, sun_pixels, images, saturation):
    """The suns' azimuths and zenith angles (n,) [deg] and pixels (n, 2) (row, col) [px], detected where not given.

    Raises
    ------
    SwimInputError
        For inconsistent lengths, non-finite values or no sun found in an image.
    """
    az = np.atleast_1d(np.asarray(sun_azimuth_deg, dtype=float))
    zen = np.atleast_1d(np.asarray(sun_zenith_deg, dtype=float))
    if az.shape != zen.shape or az.ndim != 1 or not np.all(np.isfinite(az)) or not np.all(np.isfinite(zen)):
        raise SwimInputError("sun_azimuth_deg and sun_zenith_deg must be 1-D sequences of equal length of finite "
                             "angles [deg]")
    if sun_pixels is None:
        if images is None or len(images) != az.size:
            raise SwimInputError(f"give sun_pixels (n, 2) [px] or n = {az.size} clear-sky images")
        sun_pixels = [detect_sun(img, saturation=saturation, model=model, sun_zenith_deg=z)
                      for img, z in zip(images, zen)]
    obs = np.asarray(sun_pixels, dtype=float).reshape(-1, 2) if np.size(sun_pixels) else np.zeros((0, 2))
    if obs.shape != (az.size, 2) or not np.all(np.isfinite(obs)):
        raise SwimInputError(f"sun_pixels must have shape ({az.size}, 2) (row, col) [px] of finite values, got "
                             f"{np.shape(sun_pixels)}")
    return az, zen, obs


def _first_guess(model, obs, sun_dirs, fit_centre, fit_scale, fit_tilt) -> list:
    """Starting parameters: the circular mean of the rotations that put each sun on its observed polar angle (tilt
    ignored), then the model's centre, log scale 0 and its tilt (east, north components) as fitted."""
    du = obs[:, 1] - model.cx
    dv = model.cy - obs[:, 0]
    psi_obs = np.arctan2(du, dv) if model.mirror else np.arctan2(-du, dv)
    level = sun_dirs @ model._rotation
    phi = np.arctan2(level[:, 0], level[:, 1])
    delta = phi - psi_obs
    az_up0 = math.degrees(math.atan2(np.mean(np.sin(delta)), np.mean(np.cos(delta))))
    t0 = math.radians(model.tilt_azimuth_deg)

    x0 = [az_up0]
    if fit_centre:
        x0 += [model.cx, model.cy]
    if fit_scale:
        x0 += [0.0]  # log scale
    if fit_tilt:
        x0 += [model.tilt_deg * math.sin(t0), model.tilt_deg * math.cos(t0)]
    return x0


def _fitted_model(model, x, fit_centre, fit_scale, fit_tilt) -> tuple[FisheyeCameraModel, dict]:
    """The model with the parameters ``x`` (as :func:`_first_guess` orders them), and their fitted values."""
    i = 1
    changes: dict[str, Any] = {"azimuth_up_deg": x[0]}
    params = {"azimuth_up_deg": float(x[0]) % 360.0}
    if fit_centre:
        changes.update(cx=x[i], cy=x[i + 1])
        params.update(cx=float(x[i]), cy=float(x[i + 1]))
        i += 2
    if fit_scale:
        s = math.exp(x[i])
        if model.projection == "polynomial":
            changes["coefficients"] = tuple(k * s for k in model.coefficients)
        else:
            changes["focal_length_px"] = model.focal_length_px * s
        params["scale"] = s
        i += 1
    if fit_tilt:
        tilt = min(math.hypot(x[i], x[i + 1]), 90.0)
        taz = math.degrees(math.atan2(x[i], x[i + 1])) % 360.0
        changes.update(tilt_deg=tilt, tilt_azimuth_deg=taz)
        params.update(tilt_deg=tilt, tilt_azimuth_deg=taz)
    return dataclasses.replace(model, **changes), params
