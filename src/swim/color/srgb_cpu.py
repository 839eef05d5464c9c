"""The colour stage of :func:`swim.color.solar_relative_to_srgb8` one pixel at a time on the CPU (numba).

:func:`~swim.color.solar_relative_to_srgb8` in NumPy makes ~20 passes over an image, in float64, with a temporary per
pass: 0.26-0.39 s for a 1024 x 1024 image on one core of the 2-core benchmark machine, 0.22 s of a warm 1024^2 render
on both (its last stage, while the march's threads are idle). This kernel does the same arithmetic for each pixel in
one pass: ~0.05 s on one core. JAX's fused version of it took 0.11 s (and 0.7 s to compile), so numba
(docs/decisions/0009-work-around-the-march.md).

The arithmetic is that of the NumPy functions, step by step and in their order (paper, Sect. 3.8):

1. ``XYZ = M @ L'`` (:func:`swim.color.spectrum.solar_relative_to_XYZ`'s exact matrix, valid where the interpolating
   quadratic of the three wavelengths is >= 0 between 380 and 780 nm). A pixel whose quadratic may be negative there
   (:func:`swim.color.spectrum._may_clip_quadratic`; rare in rendered skies) is only flagged: the caller computes it
   with the clipped spectral sum in NumPy.
2. ``rgb = (display_matrix / white_level) @ XYZ`` and the tone and gamut mapping of
   :func:`swim.color.display.XYZ_to_display_rgb` ("filmic", "preserve_hue" or "clip").
3. :func:`swim.color.display.encode_srgb8`: clipped to [0, 1], the sRGB transfer function, rounded to 0-255. The
   kernel finds each code among the 255 linear values at which the code steps up (:func:`code_tables`, found once
   with the transfer function itself) instead of computing a ``pow`` per channel: three ``pow`` were half of a
   pixel's ~57 ns (docs/decisions/0009-work-around-the-march.md).

``tests/unit/color/test_color.py`` holds it to the NumPy chain.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit

# no fast-math: the same IEEE arithmetic as the NumPy chain, so that the codes agree (a pixel near a code's edge
# may still round the other way where NumPy's matrix products sum in another order)
from ..compilation.numba_jit import JIT_EXACT as _JIT


@njit(**_JIT)
def _encode(v):
    """:func:`swim.color.display.encode_srgb8` of one linear value [-]: clipped to [0, 1], the sRGB transfer
    function (IEC 61966-2-1), rounded half to even to 0-255."""
    v = min(max(v, 0.0), 1.0)
    e = 12.92 * v if v <= 0.0031308 else 1.055 * v ** (1 / 2.4) - 0.055
    return np.uint8(np.rint(e * 255.0))


#: Bins of [0, 1] in whose first value the table's search for a code starts (:func:`code_tables`): the transfer
#: function rises by at most 12.92 * 255 ~ 3295 codes per unit of its linear value, so a bin holds at most one step.
CODE_BINS = 4096


@functools.lru_cache(maxsize=1)
def code_tables():
    """The linear values at which :func:`_encode`'s code steps up, and the code at the start of each bin of [0, 1].

    Each step is found with ``_encode`` itself (its Python function, with the same libm ``pow`` as the compiled
    one): from the sRGB transfer function's inverse at the code's lower edge, walked float by float to the first
    value that ``_encode`` gives the higher code. A value's code is then the number of steps at or below it, for any
    value at which ``_encode`` does not decrease (it rises with its argument, as the transfer function does).

    Returns
    -------
    steps : numpy.ndarray
        Shape (257,) float64, read-only: -inf, then for k = 0..254 the smallest float64 v in [0, 1] with
        ``_encode(v) >= k + 1``, then +inf.
    start : numpy.ndarray
        Shape (CODE_BINS + 1,) int64, read-only: the code of ``b / CODE_BINS``.
    """
    encode = _encode.py_func
    steps = np.empty(257)
    steps[0], steps[256] = -np.inf, np.inf
    for k in range(255):
        edge = (k + 0.5) / 255.0  # the encoded value at which rounding reaches k + 1
        v = edge / 12.92 if edge <= 12.92 * 0.0031308 else ((edge + 0.055) / 1.055) ** 2.4
        v = min(max(v, 0.0), 1.0)
        while v > 0.0 and encode(math.nextafter(v, 0.0)) >= k + 1:
            v = math.nextafter(v, 0.0)
        while encode(v) < k + 1:
            v = math.nextafter(v, 2.0)
        steps[k + 1] = v
    start = np.searchsorted(steps[1:256], np.arange(CODE_BINS + 1) / CODE_BINS, side="right").astype(np.int64)
    steps.flags.writeable = False
    start.flags.writeable = False
    return steps, start


@njit(**_JIT)
def _encode_by_table(v, steps, start):
    """:func:`_encode` of one linear value [-] from :func:`code_tables`: the code at the start of its bin, corrected
    by the one step that may lie between that start and the value (either side: ``v * CODE_BINS`` is rounded), with
    comparisons and no branch (3.3 ns a value here, against 11.5 for the ``pow``; loops that walk across the steps
    took 31 ns, their branches mispredicted)."""
    v = v if v > 0.0 else 0.0  # NaN too
    v = v if v < 1.0 else 1.0
    code = start[int(v * CODE_BINS)]
    return np.uint8(code + (v >= steps[code + 1]) - (v < steps[code]))


@njit(**_JIT)
def _filmic(r, g, bl, luminance, knee):
    """:func:`swim.color.display._filmic` of one pixel's linear display RGB: the tone curve of its luminance
    (:func:`swim.color.display.filmic_tone`), its chroma scaled by the curve's share, then reduced at constant
    luminance until every channel fits in [0, 1]."""
    y = r * luminance[0] + g * luminance[1] + bl * luminance[2]
    if not y > 0.0:
        return 0.0, 0.0, 0.0
    over = max(y - knee, 0.0) / (1.0 - knee)
    fall = math.exp(-over)
    tone = knee + (1.0 - knee) * (1.0 - fall) if y > knee else y
    share = math.sqrt(fall)
    f = tone / y
    c0, c1, c2 = (r * f - tone) * share, (g * f - tone) * share, (bl * f - tone) * share
    s = 1.0
    for c in (c0, c1, c2):
        if c < 0.0:
            s = min(s, tone / -c)
        elif c > 0.0:
            s = min(s, (1.0 - tone) / c)
    return tone + s * c0, tone + s * c1, tone + s * c2


@njit(**_JIT)
def srgb8_pixels(radiance, to_xyz, monomial, to_rgb, luminance, mode, knee, steps, start, out, need):
    """8-bit sRGB of pixels whose three-wavelength spectrum needs no clipping.

    Parameters
    ----------
    radiance : numpy.ndarray
        Shape (3, n) float64: solar-relative radiance L' [-] (paper Eq. 2) at the three wavelengths; a pixel with a NaN
        channel is black.
    to_xyz : numpy.ndarray
        Shape (3, 3) float64: XYZ from L' (:func:`swim.color.spectrum._linear_matrix`).
    monomial : numpy.ndarray
        Shape (3, 3) float64: the quadratic's coefficients (a, b, c) in t from L'
        (:func:`swim.color.spectrum._monomial_solve`).
    to_rgb : numpy.ndarray
        Shape (3, 3) float64: linear display RGB from XYZ, the exposure included (``display_matrix / white_level``).
    luminance : numpy.ndarray
        Shape (3,) float64: luminance from display RGB (:func:`swim.color.display._luminance_row`).
    mode : int
        The gamut mapping (:func:`swim.color.display.gamut_mode`): 0 "clip", 1 "preserve_hue", 2 "filmic".
    knee : float
        The "filmic" tone curve's knee (:data:`swim.color.display.FILMIC_KNEE`).
    steps, start : numpy.ndarray
        Shapes (257,) float64 and (CODE_BINS + 1,) int64: :func:`code_tables`.
    out : numpy.ndarray
        Shape (n, 3) uint8, written: the sRGB codes (R, G, B); left as it is where ``need``.
    need : numpy.ndarray
        Shape (n,) bool, written: True where the quadratic may be negative (the caller's clipped spectral sum).
    """
    for p in range(radiance.shape[1]):
        l0, l1, l2 = radiance[0, p], radiance[1, p], radiance[2, p]
        need[p] = False
        if l0 != l0 or l1 != l1 or l2 != l2:
            out[p, 0] = out[p, 1] = out[p, 2] = 0
            continue
        # swim.color.spectrum._may_clip_quadratic: the minimum of a t^2 + b t + c over t in [-1, 1]
        a = monomial[0, 0] * l0 + monomial[0, 1] * l1 + monomial[0, 2] * l2
        b = monomial[1, 0] * l0 + monomial[1, 1] * l1 + monomial[1, 2] * l2
        c = monomial[2, 0] * l0 + monomial[2, 1] * l1 + monomial[2, 2] * l2
        lo = min(a - b + c, a + b + c)
        if a > 0.0 and abs(-b / (2.0 * a)) < 1.0:
            lo = min(lo, c - b * b / (4.0 * a))
        if lo < 0.0:
            need[p] = True
            continue
        x = to_xyz[0, 0] * l0 + to_xyz[0, 1] * l1 + to_xyz[0, 2] * l2
        y = to_xyz[1, 0] * l0 + to_xyz[1, 1] * l1 + to_xyz[1, 2] * l2
        z = to_xyz[2, 0] * l0 + to_xyz[2, 1] * l1 + to_xyz[2, 2] * l2
        r = to_rgb[0, 0] * x + to_rgb[0, 1] * y + to_rgb[0, 2] * z
        g = to_rgb[1, 0] * x + to_rgb[1, 1] * y + to_rgb[1, 2] * z
        bl = to_rgb[2, 0] * x + to_rgb[2, 1] * y + to_rgb[2, 2] * z
        if mode == 2:
            r, g, bl = _filmic(r, g, bl, luminance, knee)
        elif mode == 1:
            smallest = min(min(r, g), bl)
            if smallest < 0.0:  # towards the grey of the same luminance until the smallest channel is 0
                lum = r * luminance[0] + g * luminance[1] + bl * luminance[2]
                if lum > 0.0:
                    f = lum / (lum - smallest)
                    r, g, bl = (max(lum + f * (r - lum), 0.0), max(lum + f * (g - lum), 0.0),
                                max(lum + f * (bl - lum), 0.0))
                else:
                    r = g = bl = 0.0
            largest = max(max(r, g), bl)
            if largest > 1.0:  # brightness saturates, chromaticity kept
                r, g, bl = r / largest, g / largest, bl / largest
        out[p, 0] = _encode_by_table(r, steps, start)
        out[p, 1] = _encode_by_table(g, steps, start)
        out[p, 2] = _encode_by_table(bl, steps, start)
