"""Discrete ordinates and real spherical harmonics of the 3-D diffuse solution (swim.rt.ordinates)."""

import math

import numpy as np
import pytest

from swim.errors import SwimInputError
from swim.rt.ordinates import harmonic_degrees, make_quadrature, real_spherical_harmonics


def _sphere_grid(n=400):
    """A fine product grid on the sphere: directions (m, 3) and solid angles (m,)."""
    x, w = np.polynomial.legendre.leggauss(n // 2)
    phi = (np.arange(n) + 0.5) * 2 * math.pi / n
    mu, ph = np.meshgrid(x, phi, indexing="ij")
    s = np.sqrt(1 - mu**2)
    d = np.stack([s * np.cos(ph), s * np.sin(ph), mu], axis=-1).reshape(-1, 3)
    return d, np.repeat(w, n) * (2 * math.pi / n)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_real_harmonics_are_orthonormal(degree):
    d, w = _sphere_grid()
    y = real_spherical_harmonics(d, degree)
    assert y.shape == (d.shape[0], (degree + 1) ** 2)
    np.testing.assert_allclose((y * w[:, None]).T @ y, np.eye(y.shape[1]), atol=1e-10)


def test_addition_theorem_gives_the_legendre_polynomials():
    """sum_m Y_lm(a) Y_lm(b) = (2l + 1) / (4 pi) P_l(a . b), the identity the scattering source rests on."""
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(2, 50, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    ya, yb = real_spherical_harmonics(a, 3), real_spherical_harmonics(b, 3)
    cos = np.sum(a * b, axis=1)
    degree = harmonic_degrees(3)
    for l in range(4):
        got = np.sum(ya[:, degree == l] * yb[:, degree == l], axis=1)
        p_l = np.polynomial.legendre.legval(cos, np.eye(4)[l])
        np.testing.assert_allclose(got, (2 * l + 1) / (4 * math.pi) * p_l, atol=1e-12)


@pytest.mark.parametrize("n_polar, n_azimuth", [(1, 4), (2, 8), (3, 12)])
def test_quadrature_weights_directions_and_octants(n_polar, n_azimuth):
    q = make_quadrature(n_polar, n_azimuth, 2)
    assert q.n_directions == 2 * n_polar * n_azimuth == 8 * q.per_octant
    np.testing.assert_allclose(q.weights.sum(), 4 * math.pi, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(q.directions, axis=1), 1.0, rtol=1e-12)
    for o, signs in enumerate(q.octants):
        block = q.directions[o * q.per_octant:(o + 1) * q.per_octant]
        assert np.all(np.sign(block) == signs)
    assert np.all(q.octants[:4, 2] == -1) and np.all(q.octants[4:, 2] == 1)
    # the first moments of a uniform radiance: 4 pi for the mean, 0 for the flux
    np.testing.assert_allclose(q.weights @ q.directions, 0.0, atol=1e-12)


def test_quadrature_integrates_the_harmonics_products_of_degree_one_exactly():
    """A double-Gauss set of 2 cosines per hemisphere is exact for polynomials of degree 3 on each hemisphere, and 8
    azimuths for cos(m phi) with m < 8: the products of harmonics of degree <= 1 are integrated exactly."""
    q = make_quadrature(2, 8, 1)
    y = q.harmonics
    np.testing.assert_allclose((y * q.weights[:, None]).T @ y, np.eye(4), atol=1e-12)


def test_bad_quadratures_are_refused():
    for args in ((0, 8, 2), (2, 6, 2), (2, 8, 5)):
        with pytest.raises(SwimInputError):
            make_quadrature(*args)
    with pytest.raises(SwimInputError):
        real_spherical_harmonics(np.zeros((3, 2)), 1)
