"""The colour stage of :func:`swim.color.solar_relative_to_srgb8` on the device (JAX), for an image that is already
there.

Where the JAX kernel marches on a GPU, the image's radiance is made on the device (the march's outputs scattered into
planes there, :mod:`swim.rt.image_device`). The host's colour stage (:mod:`swim.color.srgb_cpu`, ~57 ns a pixel on a
core) then waits for the planes' copy and runs on the host's cores while the device idles. This module computes the
same 8-bit codes on the device, so that a frame's planes and its RGB come back in one copy.

The arithmetic is :func:`swim.color.srgb_cpu.srgb8_pixels`'s, step by step, in float64 (JAX's 64-bit types on for
this program alone) and in the same order (paper, Sect. 3.8, Eqs. 33-35; docs/colour.md):

1. ``XYZ = M @ L'`` where the interpolating quadratic of the three wavelengths is >= 0 between 380 and 780 nm; a pixel
   whose quadratic may be negative there is only flagged (``need``): the caller computes it with the clipped spectral
   sum on the host (:func:`swim.color.solar_relative_to_srgb8`). It is rare in rendered skies.
2. ``rgb = (display_matrix / white_level) @ XYZ`` and the tone and gamut mapping ("filmic", "preserve_hue" or
   "clip").
3. The sRGB encoding by :func:`swim.color.srgb_cpu.code_tables`' steps (the linear values where a code steps up).

A device may fuse a product and a sum (one rounding instead of two): a value then moves by ~1e-16 relative, which
changes a code only where the value lies that close to a code's step. ``tests/unit/color/test_color_device.py`` holds
the codes to the host's.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import SwimInputError
from ..compilation.jax_export import exported_jit
from .display import (
    CHROMATIC_ADAPTATION_TRANSFORM,
    FILMIC_KNEE,
    GAMUT_MAPPINGS,
    _check_white_level,
    _luminance_row,
    display_matrix,
    gamut_mode,
)
from .spectrum import _DEFAULT_WAVELENGTHS, _linear_matrix, _monomial_solve
from .srgb_cpu import CODE_BINS, code_tables


def _dot3(m, row, v0, v1, v2):
    # ((m0 v0 + m1 v1) + m2 v2), the host kernel's order
    return m[row, 0] * v0 + m[row, 1] * v1 + m[row, 2] * v2


def _encode_by_table(v, steps, start):
    """:func:`swim.color.srgb_cpu._encode_by_table` on arrays: clipped to [0, 1] (NaN to 0), the code at the start of
    its bin, corrected by the one step that may lie between that start and the value."""
    v = jnp.where(v > 0.0, v, 0.0)
    v = jnp.where(v < 1.0, v, 1.0)
    code = start[(v * CODE_BINS).astype(jnp.int32)]
    return (code + (v >= steps[code + 1]).astype(code.dtype) - (v < steps[code]).astype(code.dtype)).astype(jnp.uint8)


def _filmic(r, g, bl, luminance, knee):
    """:func:`swim.color.srgb_cpu._filmic` on arrays."""
    y = r * luminance[0] + g * luminance[1] + bl * luminance[2]
    lit = y > 0.0
    safe_y = jnp.where(lit, y, 1.0)
    fall = jnp.exp(-(jnp.maximum(y - knee, 0.0) / (1.0 - knee)))
    tone = jnp.where(y > knee, knee + (1.0 - knee) * (1.0 - fall), y)
    share = jnp.sqrt(fall)
    f = tone / safe_y
    chroma = [(ch * f - tone) * share for ch in (r, g, bl)]
    s = jnp.ones_like(y)
    for c in chroma:
        neg, pos = c < 0.0, c > 0.0
        safe_c = jnp.where(neg | pos, c, 1.0)
        s = jnp.where(neg, jnp.minimum(s, tone / -safe_c), s)
        s = jnp.where(pos, jnp.minimum(s, (1.0 - tone) / safe_c), s)
    return tuple(jnp.where(lit, tone + s * c, 0.0) for c in chroma)


@exported_jit(static_argnames=("mode",))
def _srgb8_planes(radiance, to_xyz, monomial, to_rgb, luminance, knee, steps, start, *, mode):
    """Codes (..., 3) uint8 and ``need`` (...) bool of ``radiance`` (3, ...), as :func:`swim.color.srgb_cpu.
    srgb8_pixels` gives them per pixel (a pixel with a NaN channel: 0, 0, 0; a flagged pixel: 0, 0, 0 too)."""
    l0, l1, l2 = (radiance[c].astype(jnp.float64) for c in range(3))
    invalid = jnp.isnan(l0) | jnp.isnan(l1) | jnp.isnan(l2)
    # swim.color.spectrum._may_clip_quadratic: the minimum of a t^2 + b t + c over t in [-1, 1]
    a, b, c = (_dot3(monomial, k, l0, l1, l2) for k in range(3))
    lo = jnp.minimum(a - b + c, a + b + c)
    safe_a = jnp.where(a > 0.0, a, 1.0)  # the vertex only where a > 0 (no division by 0 elsewhere)
    vertex = (a > 0.0) & (jnp.abs(-b / (2.0 * safe_a)) < 1.0)
    lo = jnp.where(vertex, jnp.minimum(lo, c - b * b / (4.0 * safe_a)), lo)
    need = ~invalid & (lo < 0.0)
    x, y, z = (_dot3(to_xyz, k, l0, l1, l2) for k in range(3))
    r, g, bl = (_dot3(to_rgb, k, x, y, z) for k in range(3))
    if mode == 2:
        r, g, bl = _filmic(r, g, bl, luminance, knee)
    elif mode == 1:
        smallest = jnp.minimum(jnp.minimum(r, g), bl)
        lum = r * luminance[0] + g * luminance[1] + bl * luminance[2]
        shift = (smallest < 0.0) & (lum > 0.0)  # towards the grey of the same luminance until the smallest is 0
        f = lum / jnp.where(shift, lum - smallest, 1.0)
        dark = (smallest < 0.0) & ~(lum > 0.0)
        r, g, bl = (jnp.where(shift, jnp.maximum(lum + f * (ch - lum), 0.0), jnp.where(dark, 0.0, ch))
                    for ch in (r, g, bl))
        largest = jnp.maximum(jnp.maximum(r, g), bl)
        over = largest > 1.0  # brightness saturates, chromaticity kept
        scale = jnp.where(over, largest, 1.0)
        r, g, bl = (jnp.where(over, ch / scale, ch) for ch in (r, g, bl))
    codes = jnp.stack([_encode_by_table(ch, steps, start) for ch in (r, g, bl)], axis=-1)
    codes = jnp.where((invalid | need)[..., None], jnp.uint8(0), codes)
    return codes, need


def solar_relative_to_srgb8_device(radiance, white_level, *, gamut: str = "filmic"):
    """8-bit sRGB codes of a device array of solar-relative radiance, on the device, and the pixels left to the host.

    Parameters
    ----------
    radiance : jax.Array
        Shape (3, ...) float32 or float64: solar-relative spectral radiance ``L'`` [-] (paper Eq. 2) at the default
        wavelengths (615, 546, 450 nm), the wavelength axis first; NaN in any channel marks a pixel without a ray
        (rendered black).
    white_level : float
        Exposure: the flat ``L'`` shown as white [-] (:func:`swim.color.solar_relative_to_srgb8`).
    gamut : {"filmic", "preserve_hue", "clip", "none"}
        As for :func:`swim.color.solar_relative_to_srgb8` ("none" behaves as "clip").

    Returns
    -------
    codes : jax.Array
        Shape (..., 3) uint8, on the device: the sRGB codes (R, G, B) of :func:`swim.color.solar_relative_to_srgb8`,
        except at ``need``, where they are 0.
    need : jax.Array
        Shape (...) bool, on the device: pixels whose three-wavelength spectrum may need clipping (its quadratic
        negative somewhere between 380 and 780 nm), whose codes the caller takes from
        :func:`swim.color.solar_relative_to_srgb8` on the host.

    Raises
    ------
    SwimInputError
        If ``white_level`` is not a positive finite number or ``gamut`` is not one of
        :data:`swim.color.GAMUT_MAPPINGS`.
    ValueError
        If ``radiance``'s first axis is not of length 3.

    Notes
    -----
    Infinite radiance is not checked here (the march gives none); the host's function raises for it.

    References
    ----------
    Albers et al. (2020), Sect. 3.8, doi:10.5194/amt-13-3235-2020; :mod:`swim.color.srgb_cpu` (the same arithmetic on
    the host).
    """
    w = _check_white_level(white_level)
    if gamut not in GAMUT_MAPPINGS:
        raise SwimInputError(f"gamut must be one of {GAMUT_MAPPINGS}, got {gamut!r}")
    if radiance.ndim < 1 or radiance.shape[0] != 3:
        raise ValueError(f"radiance must have 3 wavelengths on its first axis, got shape {radiance.shape}")
    wl = _DEFAULT_WAVELENGTHS
    transform = CHROMATIC_ADAPTATION_TRANSFORM
    steps, start = code_tables()
    with jax.enable_x64(True):  # the host kernel's float64 arithmetic
        tables = [jnp.asarray(np.asarray(a, np.float64)) for a in (
            _linear_matrix(wl), _monomial_solve(wl), display_matrix(transform) / w, _luminance_row(transform))]
        knee = jnp.asarray(np.float64(FILMIC_KNEE))
        return _srgb8_planes(radiance, *tables, knee, jnp.asarray(np.asarray(steps, np.float64)), jnp.asarray(start),
                             mode=gamut_mode(gamut))
