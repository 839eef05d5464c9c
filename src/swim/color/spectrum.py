"""From three solar-relative radiances to a visible spectrum and CIE 1931 XYZ (paper, Sect. 3.8).

SWIm computes the solar-relative spectral radiance ``L'`` (paper Eq. 2, ``L' = 4 pi L_lambda /
E_TOA,lambda``) at three wavelengths only (615, 546, 450 nm). Section 3.8 reconstructs a full visible
spectrum by polynomial interpolation and extrapolation of the three values, multiplies it by the
solar spectrum and integrates it against the CIE colour matching functions. Here:

1. ``p(lambda)`` is the polynomial of degree ``n - 1`` through the ``n`` points ``(lambda_i, L'_i)``
   (a quadratic for the three SWIm wavelengths), evaluated on 380-780 nm in 5 nm steps
   (:data:`SPECTRAL_GRID_NM`). Its values are a fixed linear combination of the ``L'_i`` (the
   Lagrange basis, from one ``n x n`` Vandermonde solve), so the evaluation is a matrix product.
2. ``p`` is clipped at 0 (a negative radiance is unphysical) and multiplied by the extraterrestrial
   solar spectrum ``E(lambda)`` (ASTM G173-03, 5 nm band means).
3. ``X, Y, Z = k sum_lambda max(p, 0) E x-bar, y-bar, z-bar``, with ``k`` chosen such that a
   spectrally flat ``L' = 1`` gives ``Y = 1``.

Because everything but the clip is linear in ``L'``, :func:`solar_relative_to_XYZ` uses a
precomputed 3x3 matrix for every pixel whose polynomial is non-negative on the whole grid and the
full spectral sum only for the others.
"""

from __future__ import annotations

import functools

import numpy as np

from swim.color._tables import (
    SPECTRAL_GRID_NM,
    SPECTRAL_STEP_NM,
    cie_1931_cmfs_on_grid,
    solar_irradiance_on_grid,
)
from swim.constants import WAVELENGTHS_NM
from swim.errors import SwimInputError

__all__ = [
    "SPECTRAL_GRID_NM",
    "SPECTRAL_STEP_NM",
    "solar_relative_to_spectrum",
    "solar_relative_to_XYZ",
    "interpolation_matrix",
]

#: Pixels per chunk in the spectral (clipped) path: bounds the temporary (chunk, 81) arrays to ~20 MB.
_CHUNK = 32768

_GRID_CENTRE_NM = 0.5 * (SPECTRAL_GRID_NM[0] + SPECTRAL_GRID_NM[-1])
_GRID_HALF_WIDTH_NM = 0.5 * (SPECTRAL_GRID_NM[-1] - SPECTRAL_GRID_NM[0])


def _to_t(wavelength_nm: np.ndarray) -> np.ndarray:
    """Map wavelengths [nm] to t in [-1, 1] over the grid (keeps the Vandermonde well conditioned)."""
    return (np.asarray(wavelength_nm, dtype=float) - _GRID_CENTRE_NM) / _GRID_HALF_WIDTH_NM


def _check_wavelengths(wavelengths_nm) -> tuple[float, ...]:
    if wavelengths_nm is None:  # the default, valid by construction (its checks cost ~30 us a call)
        return _DEFAULT_WAVELENGTHS
    wl = np.asarray(wavelengths_nm, dtype=float)
    if wl.ndim != 1 or wl.size < 1:
        raise SwimInputError(f"wavelengths_nm must be a 1-D sequence of wavelengths [nm]; got shape {wl.shape}")
    if not np.all(np.isfinite(wl)) or np.any(wl <= 0.0):
        raise SwimInputError(f"wavelengths_nm must be finite and positive [nm]; got {wl.tolist()}")
    if np.unique(wl).size != wl.size:
        raise SwimInputError(f"wavelengths_nm must be distinct [nm]; got {wl.tolist()}")
    return tuple(float(v) for v in wl)


_DEFAULT_WAVELENGTHS = tuple(float(v) for v in WAVELENGTHS_NM)


@functools.lru_cache(maxsize=16)
def _monomial_solve(wavelengths: tuple[float, ...]) -> np.ndarray:
    """Inverse Vandermonde ``V^-1`` (n, n): monomial coefficients in t (highest power first) = V^-1 @ L'."""
    v = np.vander(_to_t(np.array(wavelengths)), len(wavelengths))
    inv = np.linalg.inv(v)
    inv.flags.writeable = False
    return inv


@functools.lru_cache(maxsize=16)
def _basis(wavelengths: tuple[float, ...]) -> np.ndarray:
    """Lagrange basis on the grid, shape (81, n): ``p(grid) = basis @ L'``."""
    n = len(wavelengths)
    b = np.vander(_to_t(SPECTRAL_GRID_NM), n) @ _monomial_solve(wavelengths)
    b.flags.writeable = False
    return b


@functools.lru_cache(maxsize=1)
def _xyz_weights() -> np.ndarray:
    """Weights W (81, 3) with ``XYZ = max(p, 0) @ W``, normalised so that ``p = 1`` gives ``Y = 1``."""
    w = solar_irradiance_on_grid()[:, None] * cie_1931_cmfs_on_grid() * SPECTRAL_STEP_NM
    w = w / w[:, 1].sum()
    w.flags.writeable = False
    return w


@functools.lru_cache(maxsize=16)
def _linear_matrix(wavelengths: tuple[float, ...]) -> np.ndarray:
    """3 x n matrix M with ``XYZ = M @ L'`` wherever the interpolating polynomial is >= 0 on the grid."""
    m = _xyz_weights().T @ _basis(wavelengths)
    m.flags.writeable = False
    return m


def interpolation_matrix(wavelengths_nm=None) -> np.ndarray:
    """Linear map from the sampled ``L'`` to the interpolating polynomial on :data:`SPECTRAL_GRID_NM`.

    Parameters
    ----------
    wavelengths_nm : array_like, shape (n,), optional
        Distinct sample wavelengths [nm]; default :data:`swim.constants.WAVELENGTHS_NM`
        (615, 546, 450 nm).

    Returns
    -------
    numpy.ndarray, shape (81, n)
        ``B`` such that ``p(SPECTRAL_GRID_NM) = B @ L'`` for the polynomial ``p`` of degree ``n - 1``
        through ``(wavelengths_nm[i], L'[i])`` (before the clip at 0). Each row sums to 1.

    Raises
    ------
    SwimInputError
        If the wavelengths are not a 1-D sequence of distinct positive finite numbers.
    """
    return np.array(_basis(_check_wavelengths(wavelengths_nm)))


def _as_pixels(radiance, wavelengths: tuple[float, ...]) -> tuple[np.ndarray, tuple[int, ...]]:
    """Validate ``radiance`` (n, ...) and return it as (N, n) plus the trailing shape."""
    r = np.asarray(radiance, dtype=float)
    n = len(wavelengths)
    if r.ndim < 1 or r.shape[0] != n:
        raise SwimInputError(
            f"radiance must have the wavelength axis first with length {n} "
            f"(solar-relative L' at {list(wavelengths)} nm); got shape {r.shape}"
        )
    rest = r.shape[1:]
    return np.moveaxis(r, 0, -1).reshape(-1, n), rest


def solar_relative_to_spectrum(radiance, wavelengths_nm=None) -> np.ndarray:
    """Reconstruct the visible spectral radiance from the solar-relative radiance at a few wavelengths.

    The polynomial through the points ``(wavelengths_nm[i], radiance[i])`` (degree ``n - 1``: a
    quadratic for SWIm's three wavelengths), evaluated on :data:`SPECTRAL_GRID_NM` (380-780 nm,
    5 nm steps), is clipped at 0 and multiplied by the extraterrestrial solar spectral irradiance
    (ASTM G173-03, 5 nm band means, scaled to 1362 W m-2), then divided by 4 pi: this inverts
    paper Eq. 2, ``L_lambda = L'_lambda E_TOA,lambda / (4 pi)`` (paper, Sect. 3.8, first paragraph).

    Parameters
    ----------
    radiance : array_like, shape (n, ...)
        Solar-relative spectral radiance ``L'`` [-] (paper Eq. 2), wavelength axis first, in the
        order of ``wavelengths_nm``. Any trailing shape (pixels). NaN propagates to the output.
    wavelengths_nm : array_like, shape (n,), optional
        Wavelengths of ``radiance`` [nm]; default :data:`swim.constants.WAVELENGTHS_NM`
        (615, 546, 450 nm).

    Returns
    -------
    numpy.ndarray, shape (..., 81)
        Spectral radiance ``L_lambda`` [W m-2 sr-1 nm-1] at :data:`SPECTRAL_GRID_NM`, for the sun at
        1 AU (wavelength axis last). A spectrally flat ``L' = 1`` returns ``E_TOA,lambda / (4 pi)``.

    Raises
    ------
    SwimInputError
        If ``radiance.shape[0]`` differs from the number of wavelengths, or the wavelengths are
        invalid.

    Notes
    -----
    The paper uses the observed solar spectrum in 20 nm steps; the 5 nm step here is the CIE 015
    recommended interval. Extrapolation beyond the outer sample wavelengths (below 450 nm and
    above 615 nm) is what the paper prescribes; its effect on colour is small because the colour
    matching functions are small there.
    """
    wl = _check_wavelengths(wavelengths_nm)
    pix, rest = _as_pixels(radiance, wl)
    p = pix @ _basis(wl).T
    np.maximum(p, 0.0, out=p)  # NaN stays NaN
    p *= solar_irradiance_on_grid() / (4.0 * np.pi)
    return p.reshape(rest + (SPECTRAL_GRID_NM.size,))


def _may_clip_quadratic(coef: np.ndarray) -> np.ndarray:
    """True where ``a t^2 + b t + c`` (rows of ``coef``) may be negative somewhere on t in [-1, 1].

    Exact minimum over the continuous interval (end points and interior vertex); this is a superset
    of the pixels whose 5 nm samples go negative, which is all that is needed to route them to the
    exact spectral sum.
    """
    a, b, c = coef[:, 0], coef[:, 1], coef[:, 2]
    lo = np.minimum(a - b + c, a + b + c)
    with np.errstate(divide="ignore", invalid="ignore"):
        tv = -b / (2.0 * a)
        inside = (a > 0.0) & (np.abs(tv) < 1.0)
        vertex = np.where(inside, c - b * b / (4.0 * a), np.inf)
    return np.minimum(lo, vertex) < 0.0


def solar_relative_to_XYZ(radiance, wavelengths_nm=None) -> np.ndarray:
    """CIE 1931 2-degree tristimulus values of the reconstructed spectrum (paper, Sect. 3.8, step 1).

    ``XYZ = k sum_lambda max(p(lambda), 0) E(lambda) {x-bar, y-bar, z-bar}(lambda) d_lambda`` over
    :data:`SPECTRAL_GRID_NM`, with ``p`` the interpolating polynomial of
    :func:`solar_relative_to_spectrum` and ``k`` such that a spectrally flat ``L' = 1`` (the colour
    of the sun) gives ``Y = 1``. ``Y`` is therefore luminance relative to that of a flat ``L' = 1``
    scene (a white Lambertian surface facing the sun has ``L' = 4``, paper Eq. 2, so ``Y = 4``).

    Parameters
    ----------
    radiance : array_like, shape (n, ...)
        Solar-relative spectral radiance ``L'`` [-], wavelength axis first (default order
        615, 546, 450 nm).
    wavelengths_nm : array_like, shape (n,), optional
        Wavelengths of ``radiance`` [nm]; default :data:`swim.constants.WAVELENGTHS_NM`.

    Returns
    -------
    numpy.ndarray, shape (..., 3)
        ``X, Y, Z`` [-] (colour-science convention: components on the last axis). A pixel with a
        NaN input is NaN.

    Raises
    ------
    SwimInputError
        If ``radiance.shape[0]`` differs from the number of wavelengths, or the wavelengths are
        invalid.

    Notes
    -----
    For pixels whose interpolating polynomial is non-negative over 380-780 nm (nearly all
    natural scenes, including the clear sky and Rayleigh ``lambda^-4`` spectra) the result is the
    exact matrix product ``XYZ = M @ L'`` with ``M = W^T B`` (``B`` the Lagrange basis,
    :func:`interpolation_matrix`; ``W`` the solar-weighted CMFs). The remaining pixels go through the
    explicit clipped spectral sum, in chunks, with identical numerics.
    """
    wl = _check_wavelengths(wavelengths_nm)
    pix, rest = _as_pixels(radiance, wl)
    xyz = pix @ _linear_matrix(wl).T
    if len(wl) == 3:
        need = _may_clip_quadratic(pix @ _monomial_solve(wl).T)
        idx = np.flatnonzero(need)
    else:
        idx = np.arange(pix.shape[0])
    if idx.size:
        basis_t = _basis(wl).T
        weights = _xyz_weights()
        for start in range(0, idx.size, _CHUNK):
            sel = idx[start : start + _CHUNK]
            p = pix[sel] @ basis_t
            np.maximum(p, 0.0, out=p)
            xyz[sel] = p @ weights
    return xyz.reshape(rest + (3,))
