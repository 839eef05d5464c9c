"""Colour-ratio cloud masks of sky images and categorical scores (paper Sect. 4.2.3).

The paper suggests deriving cloud masks from both a simulated and a camera image "using for example sky
color (e.g., red/blue intensity ratios)" and scoring their agreement with categorical skill scores
(Albers et al. 2020, Sect. 4.2.3).

Cloud masks
-----------
Clear sky is blue (Rayleigh scattering: B > R), clouds are white or grey (R ~ B). Two classic tests on the
display-encoded 8-bit values of the image (as stored by the camera; for swim its ``rgb``):

* ``method="ratio"`` (default): cloudy where ``R / B >= threshold``. Long et al. (2006) classify sky-imager
  pixels by a fixed red-to-blue ratio threshold tuned to each imager; the right value depends on the camera,
  its white balance and encoding, the aerosol load and the sun's position (the circumsolar sky and the
  hazy horizon are whiter). The default :data:`RB_RATIO_THRESHOLD` = 0.8 suits swim's sRGB images: in the
  built-in scene, 8-bit R/B is about 0.54-0.68 for cloud-free sky above 30 deg elevation and 0.85-1.06 for
  cloud of optical depth > 1.
* ``method="difference"``: cloudy where ``B - R < threshold`` (8-bit counts); Heinle et al. (2010) use the
  difference of the red and blue channels instead of their ratio, with a threshold of about 30 counts
  (:data:`BR_DIFFERENCE_THRESHOLD`).

Float images in [0, 1] are scaled to 8-bit counts for the difference test (the ratio is scale-free).
Pixels with R = B = 0 (black: no data) are never cloudy; the common valid mask (image circle, horizon,
sun exclusion) must be applied by the caller (``valid``), the same for both images.

Categorical scores
------------------
With the simulation as "forecast" and the camera as "observation", the 2 x 2 contingency table counts hits
a (both cloudy), false alarms b (simulated cloudy, observed clear), misses c (simulated clear, observed
cloudy) and correct negatives d (both clear), optionally weighted (e.g. by solid angle, giving sky
fractions in sr). The standard scores (Wilks 2011, Sect. 8.2; Jolliffe and Stephenson 2012, Ch. 3):

* probability of detection POD = a / (a + c)
* false alarm ratio FAR = b / (a + b)
* critical success index (threat score) CSI = a / (a + b + c)
* frequency bias B = (a + b) / (a + c)
* accuracy (proportion correct) ACC = (a + d) / (a + b + c + d)

A score whose denominator is 0 is NaN.

References
----------
Long, C. N., Sabburg, J. M., Calbo, J., and Pages, D. (2006): Retrieving cloud characteristics from
ground-based daytime color all-sky images, J. Atmos. Oceanic Technol. 23, 633-652, doi:10.1175/JTECH1875.1.
Heinle, A., Macke, A., and Srivastav, A. (2010): Automatic cloud classification of whole sky images,
Atmos. Meas. Tech. 3, 557-567, doi:10.5194/amt-3-557-2010.
Wilks, D. S. (2011): Statistical Methods in the Atmospheric Sciences, 3rd ed., Academic Press, Sect. 8.2.
Jolliffe, I. T. and Stephenson, D. B. (eds., 2012): Forecast Verification: A Practitioner's Guide in
Atmospheric Science, 2nd ed., Wiley, doi:10.1002/9781119960003.
Albers, S. et al. (2020), Atmos. Meas. Tech. 13, 3235-3261, doi:10.5194/amt-13-3235-2020, Sect. 4.2.3.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from ..errors import SwimInputError

__all__ = [
    "RB_RATIO_THRESHOLD",
    "BR_DIFFERENCE_THRESHOLD",
    "CLOUD_MASK_METHODS",
    "red_blue_ratio",
    "cloud_mask",
    "contingency_table",
    "categorical_scores",
    "compare_cloud_masks",
]

log = logging.getLogger(__name__)

#: Default red/blue ratio [-] at and above which a pixel is cloudy (method "ratio").
RB_RATIO_THRESHOLD = 0.8
#: Default blue-minus-red difference [8-bit counts] below which a pixel is cloudy (method "difference").
BR_DIFFERENCE_THRESHOLD = 30.0
#: Accepted ``method`` values of :func:`cloud_mask`.
CLOUD_MASK_METHODS = ("ratio", "difference")


def _rgb_counts(rgb) -> np.ndarray:
    """(..., 3) image -> float 8-bit counts (integer images scaled from their full range, floats x 255)."""
    a = np.asarray(rgb)
    if a.ndim < 1 or a.shape[-1] < 3:
        raise SwimInputError(f"rgb must have the R, G, B channels on the last axis (..., 3), got shape {a.shape}")
    a = a[..., :3]
    if np.issubdtype(a.dtype, np.integer):
        return a.astype(float) * (255.0 / float(np.iinfo(a.dtype).max))
    if np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.bool_):
        return a.astype(float) * 255.0
    raise SwimInputError(f"rgb must be a numeric image, got dtype {a.dtype}")


def red_blue_ratio(rgb) -> np.ndarray:
    """R / B of an RGB image (..., 3) [-]; inf where B = 0 < R, NaN where R = B = 0 or not finite."""
    c = _rgb_counts(rgb)
    r, b = c[..., 0], c[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(b > 0, r / np.where(b > 0, b, 1.0), np.where(r > 0, np.inf, np.nan))
    return np.where(np.isfinite(r) & np.isfinite(b), ratio, np.nan)


def cloud_mask(rgb, *, method: str = "ratio", threshold: float | None = None, valid=None) -> np.ndarray:
    """Cloudy pixels of a display-encoded sky image (module docstring).

    Parameters
    ----------
    rgb : array_like
        Image (..., 3): uint8 (or other integer) display-encoded values, or floats in [0, 1].
    method : {"ratio", "difference"}
        ``"ratio"``: cloudy where R / B >= threshold; ``"difference"``: cloudy where B - R < threshold
        [8-bit counts].
    threshold : float, optional
        Default :data:`RB_RATIO_THRESHOLD` (0.8) or :data:`BR_DIFFERENCE_THRESHOLD` (30 counts).
    valid : array_like of bool, optional
        Shape ``rgb.shape[:-1]``: pixels outside are never cloudy.

    Returns
    -------
    numpy.ndarray
        bool, shape ``rgb.shape[:-1]``.

    Raises
    ------
    SwimInputError
        For an unknown method, a non-finite (or, for the ratio, non-positive) threshold, or bad shapes.
    """
    if method not in CLOUD_MASK_METHODS:
        raise SwimInputError(f"method must be one of {CLOUD_MASK_METHODS}, got {method!r}")
    if threshold is None:
        threshold = RB_RATIO_THRESHOLD if method == "ratio" else BR_DIFFERENCE_THRESHOLD
    try:
        thr = float(threshold)
    except (TypeError, ValueError):
        raise SwimInputError(f"threshold must be a number, got {threshold!r}") from None
    if not math.isfinite(thr) or (method == "ratio" and thr <= 0):
        unit = "R/B ratio [-], > 0" if method == "ratio" else "B - R [8-bit counts]"
        raise SwimInputError(f"threshold must be a finite {unit}, got {threshold!r}")
    c = _rgb_counts(rgb)
    if method == "ratio":
        ratio = red_blue_ratio(rgb)
        cloudy = np.nan_to_num(ratio, nan=-1.0) >= thr
    else:
        dark = (c[..., 0] <= 0) & (c[..., 2] <= 0)
        cloudy = np.nan_to_num(c[..., 2] - c[..., 0], nan=np.inf) < thr
        cloudy &= ~dark
    if valid is not None:
        v = np.asarray(valid, dtype=bool)
        if v.shape != cloudy.shape:
            raise SwimInputError(f"valid must have shape {cloudy.shape}, got {v.shape}")
        cloudy &= v
    return cloudy


def contingency_table(forecast, observed, valid=None, weights=None) -> dict[str, float]:
    """2 x 2 contingency table of two binary masks.

    Parameters
    ----------
    forecast, observed : array_like of bool
        Same shape: e.g. the simulated and the camera cloud mask.
    valid : array_like of bool, optional
        Only these elements count.
    weights : array_like, optional
        Non-negative weight per element (e.g. solid angle [sr]); default 1 (counts).

    Returns
    -------
    dict
        ``hits`` (a), ``false_alarms`` (b), ``misses`` (c), ``correct_negatives`` (d), ``total`` (a + b + c + d);
        floats (counts or weighted sums).

    Raises
    ------
    SwimInputError
        For shape mismatches or negative weights.
    """
    f = np.asarray(forecast, dtype=bool)
    o = np.asarray(observed, dtype=bool)
    if f.shape != o.shape:
        raise SwimInputError(f"forecast and observed masks must have the same shape, got {f.shape} and {o.shape}")
    v = np.ones(f.shape, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    if v.shape != f.shape:
        raise SwimInputError(f"valid must have shape {f.shape}, got {v.shape}")
    w = np.ones(f.shape) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != f.shape:
        raise SwimInputError(f"weights must have shape {f.shape}, got {w.shape}")
    if np.any(w[v] < 0) or not np.all(np.isfinite(w[v])):
        raise SwimInputError("weights must be finite and >= 0")
    wv = np.where(v, w, 0.0)
    a = float(np.sum(wv[f & o]))
    b = float(np.sum(wv[f & ~o]))
    c = float(np.sum(wv[~f & o]))
    d = float(np.sum(wv[~f & ~o]))
    return {"hits": a, "false_alarms": b, "misses": c, "correct_negatives": d, "total": a + b + c + d}


def _ratio(num: float, den: float) -> float:
    return num / den if den > 0 else float("nan")


def categorical_scores(table: dict[str, float]) -> dict[str, float]:
    """POD, FAR, CSI, frequency bias and accuracy of a contingency table (module docstring).

    Parameters
    ----------
    table : dict
        With ``hits``, ``false_alarms``, ``misses``, ``correct_negatives`` (counts or weights, >= 0), e.g.
        from :func:`contingency_table`.

    Returns
    -------
    dict
        ``pod``, ``far``, ``csi``, ``frequency_bias``, ``accuracy`` (NaN where the denominator is 0).

    Raises
    ------
    SwimInputError
        If an entry is missing, negative or not finite.
    """
    try:
        a, b, c, d = (float(table[k]) for k in ("hits", "false_alarms", "misses", "correct_negatives"))
    except (KeyError, TypeError, ValueError):
        raise SwimInputError("table needs numeric hits, false_alarms, misses and correct_negatives") from None
    if not all(math.isfinite(x) and x >= 0 for x in (a, b, c, d)):
        raise SwimInputError(f"contingency table entries must be finite and >= 0, got {(a, b, c, d)}")
    return {
        "pod": _ratio(a, a + c),
        "far": _ratio(b, a + b),
        "csi": _ratio(a, a + b + c),
        "frequency_bias": _ratio(a + b, a + c),
        "accuracy": _ratio(a + d, a + b + c + d),
    }


def compare_cloud_masks(simulated_rgb, observed_rgb, valid=None, *, method: str = "ratio",
                        threshold: float | None = None, weights=None) -> dict[str, Any]:
    """Cloud masks of a simulated and an observed image on the same grid, and their categorical scores.

    Parameters
    ----------
    simulated_rgb, observed_rgb : array_like
        Display-encoded images (height, width, 3) on the same grid (e.g. the ``rgb`` of
        :func:`swim.diagnostics.compare.reproject` and the camera image).
    valid : array_like of bool, optional
        Common valid mask (height, width) (e.g. the ``mask`` of :func:`~swim.diagnostics.compare.compare_images`).
    method, threshold
        As :func:`cloud_mask`, the same for both images.
    weights : array_like, optional
        Per-pixel weights, e.g. solid angle [sr].

    Returns
    -------
    dict
        ``simulated_mask``, ``observed_mask`` (bool arrays), ``table`` (:func:`contingency_table`), ``scores``
        (:func:`categorical_scores`), ``simulated_cloud_fraction``, ``observed_cloud_fraction`` (weighted
        fractions of the valid pixels), ``method``, ``threshold``.

    Raises
    ------
    SwimInputError
        For shape mismatches or bad options.
    """
    sim = np.asarray(simulated_rgb)
    obs = np.asarray(observed_rgb)
    if sim.shape[:-1] != obs.shape[:-1]:
        raise SwimInputError(f"simulated and observed images must have the same size, got {sim.shape} and {obs.shape}")
    if threshold is None:
        threshold = RB_RATIO_THRESHOLD if method == "ratio" else BR_DIFFERENCE_THRESHOLD
    v = np.ones(sim.shape[:-1], dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    ms = cloud_mask(sim, method=method, threshold=threshold, valid=v)
    mo = cloud_mask(obs, method=method, threshold=threshold, valid=v)
    table = contingency_table(ms, mo, valid=v, weights=weights)
    scores = categorical_scores(table)
    total = table["total"]
    out = {
        "simulated_mask": ms,
        "observed_mask": mo,
        "table": table,
        "scores": scores,
        "simulated_cloud_fraction": _ratio(table["hits"] + table["false_alarms"], total),
        "observed_cloud_fraction": _ratio(table["hits"] + table["misses"], total),
        "method": method,
        "threshold": float(threshold),
    }
    log.info("cloud masks (%s >= %s): %s", method, threshold, scores)
    return out
