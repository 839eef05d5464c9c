"""Discrete ordinates and real spherical harmonics of the 3-D diffuse solution (:mod:`swim.rt.diffuse_field`).

The directions are a product quadrature: ``n_polar`` Gauss-Legendre cosines on each hemisphere (the "double
Gauss" set, which integrates polynomials of the cosine of degree ``2 n_polar - 1`` exactly on each hemisphere:
Sykes 1951; the polar set of a 4-stream discrete-ordinates code for ``n_polar`` = 2) times ``n_azimuth`` equally
spaced azimuths, offset by half a step so that no direction runs along a grid axis. The weights sum to 4 pi.

The angular moments of the radiance are taken on real, orthonormal spherical harmonics Y_lm (l <= L), so that by
the addition theorem the scattering source of a phase function with Legendre moments chi_l (P = sum_l (2l + 1)
chi_l P_l, mean 1 over the sphere) is

    (1 / 4 pi) int P(Omega . Omega') I(Omega') dOmega' = sum_l chi_l sum_m Y_lm(Omega) I_lm,
    I_lm = int I(Omega) Y_lm(Omega) dOmega.

The frame is the solver's: x along the grid's i axis, y along its j axis, z up; directions are directions of
propagation.

References
----------
Chandrasekhar, S. (1960): Radiative Transfer, Dover (discrete ordinates, Ch. II).
Evans, K. F. (1998): The spherical harmonics discrete ordinate method for three-dimensional atmospheric radiative
transfer, J. Atmos. Sci. 55, 429-446, doi:10.1175/1520-0469(1998)055<0429:TSHDOM>2.0.CO;2 (spherical harmonics for
the source, discrete ordinates for the transport).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import lpmv

from ..errors import SwimInputError

__all__ = ["Quadrature", "make_quadrature", "real_spherical_harmonics", "harmonic_degrees"]


def harmonic_degrees(max_degree: int) -> np.ndarray:
    """The degree l of each of the (L + 1)^2 real harmonics in the order of :func:`real_spherical_harmonics`
    (l = 0; l = 1 with m = -1, 0, 1; ...), int (n_moments,)."""
    return np.repeat(np.arange(max_degree + 1), 2 * np.arange(max_degree + 1) + 1)


def real_spherical_harmonics(directions, max_degree: int) -> np.ndarray:
    """Real orthonormal spherical harmonics Y_lm of unit vectors, l <= ``max_degree``.

    Parameters
    ----------
    directions : array_like
        Shape (..., 3): unit vectors (x, y, z); the polar angle is measured from +z.
    max_degree : int
        Largest degree L >= 0.

    Returns
    -------
    numpy.ndarray
        Shape (..., (L + 1)^2), float64, in the order l = 0..L, m = -l..l: Y_l0 = N_l0 P_l(cos theta),
        Y_lm = sqrt(2) N_lm P_l^m(cos theta) cos(m phi), Y_l,-m = sqrt(2) N_lm P_l^m(cos theta) sin(m phi) (m > 0),
        N_lm = sqrt((2l + 1) / (4 pi) (l - m)! / (l + m)!). Their integral products over the sphere are the identity.
    """
    d = np.asarray(directions, dtype=float)
    if d.shape[-1] != 3:
        raise SwimInputError(f"real_spherical_harmonics: directions must end in an axis of 3, got {d.shape}")
    mu = np.clip(d[..., 2], -1.0, 1.0)
    phi = np.arctan2(d[..., 1], d[..., 0])
    out = np.empty(d.shape[:-1] + ((max_degree + 1) ** 2,))
    n = 0
    for l in range(max_degree + 1):
        for m in range(-l, l + 1):
            am = abs(m)
            norm = math.sqrt((2 * l + 1) / (4 * math.pi) * math.factorial(l - am) / math.factorial(l + am))
            p = lpmv(am, l, mu)
            if m == 0:
                out[..., n] = norm * p
            elif m > 0:
                out[..., n] = math.sqrt(2.0) * norm * p * np.cos(am * phi)
            else:
                out[..., n] = math.sqrt(2.0) * norm * p * np.sin(am * phi)
            n += 1
    return out


@dataclass(frozen=True)
class Quadrature:
    """A product quadrature of directions, grouped by octant (see the module docstring).

    Attributes
    ----------
    directions : numpy.ndarray
        (n_dir, 3) unit propagation directions, octant by octant.
    weights : numpy.ndarray
        (n_dir,) solid angles [sr], summing to 4 pi.
    octants : numpy.ndarray
        (8, 3) int: the signs (+1, -1) of x, y and z of each octant's directions; octants 0-3 go down (z < 0).
    per_octant : int
        Directions in each octant (directions[o * per_octant:(o + 1) * per_octant] belong to octant o).
    harmonics : numpy.ndarray
        (n_dir, (L + 1)^2) Y_lm of the directions.
    max_degree : int
        L.
    """

    directions: np.ndarray
    weights: np.ndarray
    octants: np.ndarray
    per_octant: int
    harmonics: np.ndarray
    max_degree: int

    @property
    def n_directions(self) -> int:
        return self.directions.shape[0]


def make_quadrature(n_polar: int = 2, n_azimuth: int = 8, max_degree: int = 2) -> Quadrature:
    """The product quadrature of ``n_polar`` double-Gauss cosines per hemisphere and ``n_azimuth`` azimuths.

    Parameters
    ----------
    n_polar : int
        Gauss points per hemisphere, >= 1.
    n_azimuth : int
        Azimuths, a multiple of 4 (so that every octant holds the same directions, mirrored), >= 4.
    max_degree : int
        Largest spherical-harmonic degree L of the moments, 0 <= L < 2 n_polar + 1 ... L <= 4.

    Returns
    -------
    Quadrature

    Raises
    ------
    SwimInputError
        If the counts are out of range.
    """
    if not (int(n_polar) >= 1 and int(n_azimuth) >= 4 and int(n_azimuth) % 4 == 0 and 0 <= int(max_degree) <= 4):
        raise SwimInputError(f"make_quadrature: need n_polar >= 1, n_azimuth a multiple of 4 (>= 4) and "
                             f"0 <= max_degree <= 4; got {n_polar}, {n_azimuth}, {max_degree}")
    x, w = np.polynomial.legendre.leggauss(int(n_polar))
    mu = 0.5 * (x + 1.0)
    w_mu = 0.5 * w * (2.0 * math.pi / n_azimuth)
    quarter = n_azimuth // 4
    phi = (np.arange(quarter) + 0.5) * (2.0 * math.pi / n_azimuth)  # the first quadrant's azimuths
    octants = np.array([(sx, sy, sz) for sz in (-1, 1) for sy in (1, -1) for sx in (1, -1)])
    dirs, weights = [], []
    for sx, sy, sz in octants:
        for m, wm in zip(mu, w_mu):
            s = math.sqrt(max(1.0 - m * m, 0.0))
            for p in phi:
                dirs.append((sx * s * math.cos(p), sy * s * math.sin(p), sz * m))
                weights.append(wm)
    dirs = np.array(dirs)
    return Quadrature(directions=dirs, weights=np.array(weights), octants=octants,
                      per_octant=len(mu) * quarter, harmonics=real_spherical_harmonics(dirs, int(max_degree)),
                      max_degree=int(max_degree))
