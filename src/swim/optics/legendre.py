"""Legendre moments of phase functions (DISORT's normalisation): the expansion that the diffuse solutions and the
DISORT references take, P(mu) = sum_l (2 l + 1) chi_l P_l(mu).

References
----------
Stamnes, K., Tsay, S.-C., Wiscombe, W. and Jayaweera, K. (1988): Numerically stable algorithm for discrete-ordinate-
method radiative transfer in multiple scattering and emitting layered media, Appl. Opt. 27, 2502-2509,
doi:10.1364/AO.27.002502.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["phase_function_legendre_moments", "rayleigh_legendre_moments"]


def rayleigh_legendre_moments(depolarization, n_moments):
    """Legendre moments chi_l of the depolarised Rayleigh phase function (DISORT normalisation).

    P(mu) = 3 / (4 (1 + 2 gamma)) ((1 + 3 gamma) + (1 - gamma) mu^2) with gamma = rho / (2 - rho)
    (:func:`swim.optics.rayleigh.rayleigh_phase_function`). Writing mu^2 = (1 + 2 P_2(mu)) / 3 gives
    P = 1 + (1 - gamma) / (2 (1 + 2 gamma)) P_2, i.e. with P = sum (2l + 1) chi_l P_l:
    chi_0 = 1, chi_1 = 0, chi_2 = (1 - gamma) / (10 (1 + 2 gamma)) = (1 - rho) / (5 (2 + rho)), chi_l>2 = 0
    (0.1 for rho = 0, the classical value).

    Parameters
    ----------
    depolarization : float
        Depolarisation ratio rho [-].
    n_moments : int
        Highest moment index (the array has n_moments + 1 entries), >= 2.

    Returns
    -------
    numpy.ndarray
        Shape (n_moments + 1,).
    """
    rho = float(depolarization)
    chi = np.zeros(int(n_moments) + 1)
    chi[0] = 1.0
    chi[2] = (1.0 - rho) / (5.0 * (2.0 + rho))
    return chi


def phase_function_legendre_moments(phase_function, n_moments, n_quad=None):
    """Legendre moments chi_l = 1/2 int_{-1}^{1} P(mu) P_l(mu) dmu by Gauss-Legendre quadrature.

    Parameters
    ----------
    phase_function : callable
        cos(theta) array (n,) -> P, shape (n,) or (n, k), normalised to mean 1 over the sphere.
    n_moments : int
        Highest moment index.
    n_quad : int, optional
        Quadrature points; default max(4 n_moments, 2048).

    Returns
    -------
    numpy.ndarray
        Shape (n_moments + 1,) or (n_moments + 1, k); chi_0 is 1 for a normalised P.
    """
    n_quad = int(n_quad or max(4 * n_moments, 2048))
    x, w = _gauss_legendre(n_quad)
    p = np.asarray(phase_function(x), dtype=float)
    # Legendre polynomials by the three-term recurrence, P_l(x) for l = 0..n_moments
    pl = np.empty((n_moments + 1, n_quad))
    pl[0] = 1.0
    if n_moments >= 1:
        pl[1] = x
    for l in range(1, n_moments):
        pl[l + 1] = ((2 * l + 1) * x * pl[l] - l * pl[l - 1]) / (l + 1)
    wp = p * w[:, None] if p.ndim == 2 else p * w
    return 0.5 * (pl @ wp)


@functools.lru_cache(maxsize=4)
def _gauss_legendre(n):
    """Gauss-Legendre nodes and weights on [-1, 1] (SciPy's O(n) algorithm; numpy's leggauss is O(n^3))."""
    from scipy.special import roots_legendre

    x, w = roots_legendre(int(n))
    x.flags.writeable = False
    w.flags.writeable = False
    return x, w
