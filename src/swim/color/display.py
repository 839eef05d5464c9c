"""From CIE XYZ to display RGB and 8-bit sRGB (paper, Sect. 3.8, steps 2 and 3).

Chain (per pixel):

1. ``XYZ`` from :func:`swim.color.spectrum.solar_relative_to_XYZ` (``Y = 1`` for a spectrally flat
   ``L' = 1``, i.e. sunlight).
2. Sun-white display RGB: von Kries chromatic adaptation (Bradford) from the sun's white point
   (the XYZ of a flat ``L'``) to D65, then the IEC 61966-2-1 sRGB matrix, then division by the
   exposure ``white_level``. A spectrally flat ``L' = white_level`` maps to ``RGB = (1, 1, 1)``
   exactly (a per-channel renormalisation of at most 1.6e-4 absorbs the 4-digit rounding of the sRGB
   matrix). This replaces the paper's Eq. 36 matrix (see :data:`PAPER_EQ36_MATRIX`).
3. Tone and gamut mapping into [0, 1]^3 (default ``"filmic"``, see :func:`XYZ_to_display_rgb`): linear up to
   :data:`FILMIC_KNEE` of white, then a shoulder that rolls the luminance off towards white and the colour towards
   neutral, as film and camera view transforms do, so that over-exposed light turns white instead of keeping its
   hue; out-of-gamut colours lose chroma at constant luminance.
4. sRGB opto-electronic transfer function (the paper's "gamma 2.2", step 3) and 8-bit quantisation.

The exposure is ``white_level`` (a fixed solar-relative radiance, the default), optionally shifted by an exposure
value in stops (:func:`exposure_white_level`), or set from the image's luminance (:func:`auto_white_level`).
"""

from __future__ import annotations

import functools

import numpy as np

from swim.color._tables import colour_science_data, unknown_transform
from swim.color.spectrum import (
    _DEFAULT_WAVELENGTHS,
    _check_wavelengths,
    _linear_matrix,
    _monomial_solve,
    solar_relative_to_XYZ,
)
from swim.errors import SwimInputError

__all__ = [
    "DEFAULT_WHITE_LEVEL",
    "CHROMATIC_ADAPTATION_TRANSFORM",
    "PAPER_EQ36_MATRIX",
    "GAMUT_MAPPINGS",
    "FILMIC_KNEE",
    "AUTO_EXPOSURE_KEY",
    "auto_white_level",
    "exposure_white_level",
    "sun_white_XYZ",
    "display_matrix",
    "XYZ_to_display_rgb",
    "oetf_srgb",
    "encode_srgb8",
    "solar_relative_to_srgb8",
]

#: Exposure: the solar-relative radiance ``L'`` [-] of a spectrally flat (sun-coloured) scene that maps to
#: display white ``RGB = (1, 1, 1)`` before the tone mapping. Displayed linear brightness is
#: ``L' / DEFAULT_WHITE_LEVEL`` up to the ``"filmic"`` mapping's knee (paper Sect. 3.8: displayed brightness
#: proportional to scene brightness). 1.5 puts sunlit cloud tops (L' ~ 2-4) in the shoulder near white, cloud
#: bases (L' ~ 0.5-1.5) in mid to light greys and the clear sky (L' ~ 0.07-0.25) in darker blues. A white
#: Lambertian surface facing the sun has L' = 4 (Eq. 2).
DEFAULT_WHITE_LEVEL = 1.5
#: White level for views from space (observer above 100 km): L' of a white Lambertian surface facing the
#: sun (Eq. 2), so that reflectance 1 is display white as in satellite imagery.
SPACE_WHITE_LEVEL = 4.0

#: Chromatic adaptation transform (colour-science name) from the sun's white point to D65.
CHROMATIC_ADAPTATION_TRANSFORM = "Bradford"

#: The paper's Eq. 36 XYZ -> monitor RGB matrix (kept for comparison only; not used). Its primaries
#: are within 0.01 in xy of the sRGB/Rec. 709 primaries, and RGB = (1, 1, 1) corresponds to
#: xy = (0.3292, 0.3449), CCT ~ 5640 K (see docs/colour.md).
PAPER_EQ36_MATRIX = np.array(
    [
        [3.1894, -1.5755, -0.4948],
        [-0.9735, 1.8951, 0.0376],
        [0.0635, -0.2160, 1.2244],
    ]
)
PAPER_EQ36_MATRIX.flags.writeable = False

#: Accepted values of the ``gamut`` argument of :func:`XYZ_to_display_rgb` (the first is the default).
GAMUT_MAPPINGS = ("filmic", "preserve_hue", "clip", "none")

#: The ``"filmic"`` mapping's knee: the display luminance (a fraction of white) up to which the mapping is linear
#: (displayed brightness proportional to scene brightness, paper Sect. 3.8) and above which the shoulder rolls off.
FILMIC_KNEE = 0.6

#: Auto exposure's key: the display luminance that the image's log-average luminance is given (Reinhard et al. 2002,
#: the "middle grey" 0.18 of a camera's average metering).
AUTO_EXPOSURE_KEY = 0.18


def sun_white_XYZ() -> np.ndarray:
    """XYZ of a spectrally flat solar-relative radiance ``L' = 1``: the sun's white point.

    Returns
    -------
    numpy.ndarray, shape (3,)
        ``X, Y, Z`` with ``Y = 1``; chromaticity xy ~ (0.3234, 0.3327) for the ASTM G173-03
        extraterrestrial spectrum (CCT ~ 6090 K; the paper quotes 5780 K as the sun's approximate
        colour temperature).
    """
    return solar_relative_to_XYZ(np.ones(3))


@functools.lru_cache(maxsize=4)
def _display_matrix(transform: str) -> np.ndarray:
    data = colour_science_data(transform)  # raises SwimInputError for a transform colour-science does not know
    xyz_sun = sun_white_XYZ()
    xyz_d65 = data["srgb_whitepoint_XYZ"]  # Y = 1
    # von Kries adaptation in the transform's cone space, M^-1 diag(M XYZ_d65 / M XYZ_sun) M (what
    # colour.adaptation.matrix_chromatic_adaptation_VonKries gives; tests/unit/color/test_color.py holds the two
    # together)
    cone = data["cat"]
    cat = np.linalg.inv(cone) @ np.diag((cone @ xyz_d65) / (cone @ xyz_sun)) @ cone
    m = data["srgb_XYZ_to_RGB"] @ cat
    m = m / (m @ xyz_sun)[:, None]  # sun white -> exactly (1, 1, 1)
    m.flags.writeable = False
    return m


def display_matrix(transform: str = CHROMATIC_ADAPTATION_TRANSFORM) -> np.ndarray:
    """The 3x3 matrix from XYZ (``Y = 1`` for sunlight) to linear sRGB with the sun as white.

    ``M = diag(1 / (M0 @ XYZ_sun)) @ M0`` with ``M0 = M_XYZ->sRGB @ CAT(XYZ_sun -> D65)``.

    Parameters
    ----------
    transform : str, optional
        colour-science chromatic adaptation transform name ("Bradford", "CAT02", "Von Kries", ...).

    Returns
    -------
    numpy.ndarray, shape (3, 3)
        ``rgb = M @ XYZ``; ``M @ sun_white_XYZ() = (1, 1, 1)``.

    Raises
    ------
    SwimInputError
        If ``transform`` is not a colour-science chromatic adaptation transform.
    """
    try:
        return np.array(_display_matrix(transform))
    except TypeError:  # an unhashable name
        raise unknown_transform(transform) from None


@functools.lru_cache(maxsize=4)
def _luminance_row(transform: str) -> np.ndarray:
    """Row of the display matrix's inverse that gives luminance from display RGB (made once per transform)."""
    row = np.linalg.inv(_display_matrix(transform))[1]
    row.flags.writeable = False
    return row


def _check_white_level(white_level) -> float:
    if isinstance(white_level, (bool, np.bool_)):
        raise SwimInputError(f"white_level must be a positive number (solar-relative L' [-]); got {white_level!r}")
    try:
        w = float(white_level)
    except (TypeError, ValueError):
        raise SwimInputError(
            f"white_level must be a positive number (solar-relative L' [-]); got {white_level!r}"
        ) from None
    if not np.isfinite(w) or w <= 0.0:
        raise SwimInputError(
            f"white_level must be a positive finite solar-relative radiance L' [-]; got {white_level!r}"
        )
    return w


def exposure_white_level(white_level, exposure_ev=0.0) -> float:
    """The white level after an exposure change of ``exposure_ev`` stops: ``white_level * 2^-exposure_ev``.

    Parameters
    ----------
    white_level : float
        Solar-relative radiance ``L'`` [-] shown as white at exposure 0, > 0.
    exposure_ev : float
        Exposure value [EV, stops]; +1 doubles the displayed brightness.

    Returns
    -------
    float
        The white level [-].

    Raises
    ------
    SwimInputError
        If ``white_level`` is not a positive finite number or ``exposure_ev`` is not a finite number within
        +-20 EV.
    """
    w = _check_white_level(white_level)
    try:
        ev = float(exposure_ev)
    except (TypeError, ValueError):
        raise SwimInputError(f"exposure must be a number of stops [EV]; got {exposure_ev!r}") from None
    if not np.isfinite(ev) or abs(ev) > 20.0:
        raise SwimInputError(f"exposure must be a finite number of stops within +-20 [EV]; got {exposure_ev!r}")
    return w * 2.0 ** -ev


def auto_white_level(radiance, key=AUTO_EXPOSURE_KEY, *, wavelengths_nm=None) -> float:
    """Auto exposure: the white level that shows the image's log-average luminance at ``key`` of white.

    A camera's average metering (Reinhard et al. 2002, Eq. 1): ``white = exp(mean(log Y)) / key``, with ``Y`` the
    luminance of each valid pixel relative to a flat ``L' = 1`` (:func:`swim.color.solar_relative_to_XYZ`'s Y).
    The log-average lets a few very bright pixels (the sun's disc) barely move it.

    Parameters
    ----------
    radiance : array_like, shape (n, ...)
        Solar-relative spectral radiance ``L'`` [-], wavelength axis first; NaN marks pixels without a ray.
    key : float
        Display luminance of the log-average [-], in (0, 1).
    wavelengths_nm : array_like, shape (n,), optional
        Wavelengths of ``radiance`` [nm]; default 615, 546, 450.

    Returns
    -------
    float
        The white level [-] (solar-relative radiance shown as white).

    Raises
    ------
    SwimInputError
        If ``key`` is not in (0, 1), or no pixel has a positive luminance.

    References
    ----------
    Reinhard, E., Stark, M., Shirley, P. and Ferwerda, J. (2002): Photographic tone reproduction for digital images,
    ACM Trans. Graph. 21, 267-276, doi:10.1145/566654.566575.
    """
    k = float(key)
    if not 0.0 < k < 1.0:
        raise SwimInputError(f"auto exposure key must be in (0, 1); got {key!r}")
    r = np.asarray(radiance, dtype=float)
    wl = _DEFAULT_WAVELENGTHS if wavelengths_nm is None else _check_wavelengths(wavelengths_nm)
    y = np.tensordot(_linear_matrix(wl)[1], r.reshape(r.shape[0], -1), axes=1)
    y = y[np.isfinite(y) & (y > 0.0)]
    if y.size == 0:
        raise SwimInputError("auto exposure needs at least one pixel with a positive luminance; the image has none")
    return float(np.exp(np.mean(np.log(y))) / k)


def filmic_tone(y):
    """The ``"filmic"`` mapping's tone curve and its colour's share, of display luminance ``y`` (white 1) [-].

    Linear up to :data:`FILMIC_KNEE` (k); above it an exponential shoulder that meets the line with equal slope and
    approaches white, ``T = k + (1 - k) (1 - exp(-(y - k) / (1 - k)))``: the old white (y = 1) shows at 0.85, twice
    it at 0.99. The colour's share, ``sqrt((1 - T) / (1 - k))``, falls from 1 at the knee to 0 at white, so that
    highlights turn neutral as on film.

    Parameters
    ----------
    y : array_like
        Display luminance [-] (1: the exposure's white), any shape.

    Returns
    -------
    tone, share : numpy.ndarray
        Same shape as ``y``: the displayed luminance [-], in [0, 1) and the share of the chroma kept [-], in (0, 1].

    Notes
    -----
    The curve is this project's (docs/colour.md, "Tone and gamut mapping"), after the highlight roll-off of film
    and of camera view transforms (ACES, AgX), not a published formula: linear below the knee so that the paper's
    rule of displayed brightness proportional to scene brightness (Albers et al. 2020, Sect. 3.8,
    doi:10.5194/amt-13-3235-2020) holds for everything but highlights.
    """
    y = np.asarray(y, dtype=float)
    k = FILMIC_KNEE
    over = np.maximum(y - k, 0.0) / (1.0 - k)
    fall = np.exp(-over)
    tone = np.where(y > k, k + (1.0 - k) * (1.0 - fall), y)
    return tone, np.sqrt(fall)


def _filmic(flat, lum):
    """The ``"filmic"`` mapping of linear display RGB rows (n, 3) in place (see :func:`XYZ_to_display_rgb`)."""
    y = flat @ lum
    tone, share = filmic_tone(y)
    with np.errstate(divide="ignore", invalid="ignore"):
        chroma = (flat * (tone / y)[:, None] - tone[:, None]) * share[:, None]
        # the largest share of the chroma that keeps every channel within [0, 1] at this luminance
        room = np.where(chroma < 0.0, tone[:, None] / -chroma, np.where(chroma > 0.0, (1.0 - tone[:, None]) / chroma,
                                                                        np.inf))
    s = np.minimum(room.min(axis=1), 1.0)[:, None]
    # (clipped for the rounding of a channel that the chroma's room puts at 0 or 1; the encoders clip the same)
    flat[...] = np.clip(np.where(y[:, None] > 0.0, tone[:, None] + s * chroma, 0.0), 0.0, 1.0)
    return flat


def XYZ_to_display_rgb(
    XYZ,
    white_level=DEFAULT_WHITE_LEVEL,
    *,
    gamut: str = "filmic",
    transform: str = CHROMATIC_ADAPTATION_TRANSFORM,
) -> np.ndarray:
    """Linear display RGB in sRGB primaries with the sun as white (paper, Sect. 3.8, step 2).

    ``rgb = display_matrix() @ XYZ / white_level``, followed by gamut mapping.

    Parameters
    ----------
    XYZ : array_like, shape (..., 3)
        CIE 1931 tristimulus values normalised as in :func:`swim.color.solar_relative_to_XYZ`
        (``Y = 1`` for a spectrally flat ``L' = 1``).
    white_level : float, optional
        Exposure: the flat ``L'`` [-] mapped to ``RGB = (1, 1, 1)`` before the tone mapping; default
        :data:`DEFAULT_WHITE_LEVEL` (1.5).
    gamut : {"filmic", "preserve_hue", "clip", "none"}, optional
        Mapping of out-of-range values into [0, 1]:

        - ``"filmic"`` (default): the luminance ``y`` is kept up to :data:`FILMIC_KNEE` and rolled off towards
          white above it (:func:`filmic_tone`), the colour's chroma scaled by the tone curve's share so that
          highlights become neutral white, then, where a channel would still leave [0, 1], the chroma reduced at
          constant luminance until it fits (hue kept). Pixels with luminance <= 0 become black.
        - ``"preserve_hue"``: a pixel with a negative channel (chromaticity outside the
          sRGB triangle) is desaturated towards the neutral grey of the same luminance until its
          smallest channel is 0 (hue and luminance kept); then a pixel whose largest channel
          exceeds 1 is scaled down by that channel (chromaticity kept, brightness saturates).
          Pixels with luminance <= 0 become black.
        - ``"clip"``: each channel clipped to [0, 1] independently (over-exposed colours shift
          towards white/yellow as on a camera sensor).
        - ``"none"``: no mapping; values may be negative or exceed 1.
    transform : str, optional
        Chromatic adaptation transform (colour-science name); default "Bradford".

    Returns
    -------
    numpy.ndarray, shape (..., 3)
        Linear R, G, B [-] in [0, 1] (unless ``gamut="none"``). NaN input gives NaN.

    Raises
    ------
    SwimInputError
        If ``XYZ`` has no trailing axis of length 3, ``white_level`` is not a positive finite
        number, or ``gamut`` / ``transform`` are unknown.
    """
    w = _check_white_level(white_level)
    if gamut not in GAMUT_MAPPINGS:
        raise SwimInputError(f"gamut must be one of {GAMUT_MAPPINGS}; got {gamut!r}")
    xyz = np.asarray(XYZ, dtype=float)
    if xyz.ndim < 1 or xyz.shape[-1] != 3:
        raise SwimInputError(f"XYZ must have the X, Y, Z components on the last axis (..., 3); got shape {xyz.shape}")
    m = display_matrix(transform)
    rgb = xyz @ (m.T / w)
    if gamut == "none":
        return rgb
    if gamut == "clip":
        return np.clip(rgb, 0.0, 1.0)
    if gamut == "filmic":
        return _filmic(rgb.reshape(-1, 3), _luminance_row(transform)).reshape(rgb.shape)
    # preserve_hue: work on the (few) offending pixels only
    flat = rgb.reshape(-1, 3)
    lum = _luminance_row(transform)  # luminance Y / Y_white from rgb; the coefficients sum to 1
    # the smallest and largest channels as two element-wise operations: a reduction over an axis of 3 took ~70 us
    # for a 41 x 41 image
    neg = np.flatnonzero(np.minimum(np.minimum(flat[:, 0], flat[:, 1]), flat[:, 2]) < 0.0)
    if neg.size:
        sub = flat[neg]
        y = (sub @ lum)[:, None]
        lo = sub.min(axis=1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            mixed = y + (y / (y - lo)) * (sub - y)  # smallest channel -> 0, luminance kept
        flat[neg] = np.where(y > 0.0, np.maximum(mixed, 0.0), 0.0)
    over = np.flatnonzero(np.maximum(np.maximum(flat[:, 0], flat[:, 1]), flat[:, 2]) > 1.0)
    if over.size:
        flat[over] /= flat[over].max(axis=1, keepdims=True)
    rgb = flat.reshape(rgb.shape)
    return rgb


def oetf_srgb(rgb_linear) -> np.ndarray:
    """sRGB opto-electronic transfer function (IEC 61966-2-1), the paper's "gamma 2.2" (step 3).

    ``V = 12.92 L`` for ``L <= 0.0031308``, else ``V = 1.055 L^(1/2.4) - 0.055`` (colour-science
    :func:`colour.models.eotf_inverse_sRGB`).

    Parameters
    ----------
    rgb_linear : array_like, any shape
        Linear values [-], nominally in [0, 1].

    Returns
    -------
    numpy.ndarray, same shape
        Encoded values [-]; [0, 1] maps onto [0, 1].
    """
    linear = np.asarray(rgb_linear, dtype=float)
    # as colour.models.eotf_inverse_sRGB (tests/unit/color/test_color.py holds the two together), without importing
    # colour-science in a render
    with np.errstate(invalid="ignore"):
        return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.abs(linear) ** (1 / 2.4) - 0.055)


def encode_srgb8(rgb_linear) -> np.ndarray:
    """Encode linear RGB as 8-bit sRGB.

    Values are clipped to [0, 1] (NaN -> 0), passed through :func:`oetf_srgb` and rounded to the
    nearest of 0..255.

    Parameters
    ----------
    rgb_linear : array_like, any shape (typically (..., 3))
        Linear display values [-].

    Returns
    -------
    numpy.ndarray of uint8, same shape
        sRGB code values.
    """
    v = np.nan_to_num(np.asarray(rgb_linear, dtype=float), nan=0.0, posinf=1.0, neginf=0.0)
    v = oetf_srgb(np.clip(v, 0.0, 1.0))
    return np.rint(v * 255.0).astype(np.uint8)


def solar_relative_to_srgb8(
    radiance,
    white_level=DEFAULT_WHITE_LEVEL,
    *,
    gamut: str = "filmic",
    wavelengths_nm=None,
) -> np.ndarray:
    """The whole colour stage: solar-relative radiance to 8-bit sRGB (paper, Sect. 3.8).

    :func:`~swim.color.spectrum.solar_relative_to_XYZ` -> :func:`XYZ_to_display_rgb` ->
    :func:`encode_srgb8`.

    Parameters
    ----------
    radiance : array_like, shape (n, ...)
        Solar-relative spectral radiance ``L'`` [-] (paper Eq. 2), wavelength axis first (default
        615, 546, 450 nm). A pixel with NaN in any channel (e.g. outside the fisheye circle) is
        rendered black.
    white_level : float, optional
        Exposure: the flat ``L'`` shown as white; default :data:`DEFAULT_WHITE_LEVEL`.
    gamut : {"filmic", "preserve_hue", "clip", "none"}, optional
        See :func:`XYZ_to_display_rgb` (``"none"`` behaves as ``"clip"`` here, via the encoder).
    wavelengths_nm : array_like, shape (n,), optional
        Wavelengths of ``radiance`` [nm]; default :data:`swim.constants.WAVELENGTHS_NM`.

    Returns
    -------
    numpy.ndarray of uint8, shape (..., 3)
        sRGB code values (R, G, B on the last axis).

    Raises
    ------
    SwimInputError
        If the radiance shape does not match the wavelengths, it contains +-inf, or
        ``white_level`` / ``gamut`` are invalid.

    Notes
    -----
    At the default wavelengths the chain runs in one compiled pass per pixel
    (:func:`swim.color.srgb_cpu.srgb8_pixels`), with the NumPy functions' arithmetic and codes; a pixel
    whose spectrum needs clipping goes through them (docs/colour.md, "Performance").
    """
    w = _check_white_level(white_level)
    r = np.asarray(radiance, dtype=float)
    if np.isinf(r).any():
        raise SwimInputError("radiance (solar-relative L') contains infinite values; use NaN to mark invalid pixels")
    if (gamut in GAMUT_MAPPINGS and r.ndim >= 1 and r.shape[0] == 3
            and (wavelengths_nm is None or _check_wavelengths(wavelengths_nm) == _DEFAULT_WAVELENGTHS)):
        return _srgb8_compiled(r, w, gamut)
    invalid = np.isnan(r).any(axis=0) if r.ndim >= 1 else np.isnan(r)
    if invalid.any():
        r = np.where(invalid, 0.0, r)
    rgb = XYZ_to_display_rgb(solar_relative_to_XYZ(r, wavelengths_nm), w, gamut=gamut)
    out = encode_srgb8(rgb)
    out[invalid] = 0
    return out


def gamut_mode(gamut: str) -> int:
    """The compiled kernels' code of a gamut mapping: 0 "clip" (and "none", clipped by the encoder), 1
    "preserve_hue", 2 "filmic"."""
    return {"preserve_hue": 1, "filmic": 2}.get(gamut, 0)


def _srgb8_compiled(radiance, white_level, gamut):
    """:func:`solar_relative_to_srgb8` at the default wavelengths in one compiled pass per pixel
    (:func:`swim.color.srgb_cpu.srgb8_pixels`, ~6x faster than the NumPy chain); the pixels whose spectrum needs
    clipping (rare) through the NumPy chain. ``radiance`` (3, ...) float64 without infinities."""
    from swim.color.srgb_cpu import code_tables, srgb8_pixels

    wl = _DEFAULT_WAVELENGTHS
    flat = np.ascontiguousarray(radiance.reshape(3, -1))
    out = np.empty((flat.shape[1], 3), np.uint8)
    need = np.empty(flat.shape[1], bool)
    transform = CHROMATIC_ADAPTATION_TRANSFORM
    srgb8_pixels(flat, _linear_matrix(wl), _monomial_solve(wl), display_matrix(transform) / white_level,
                 _luminance_row(transform), gamut_mode(gamut), FILMIC_KNEE, *code_tables(), out, need)
    if need.any():
        out[need] = encode_srgb8(XYZ_to_display_rgb(solar_relative_to_XYZ(flat[:, need]), white_level, gamut=gamut))
    return out.reshape(radiance.shape[1:] + (3,))
