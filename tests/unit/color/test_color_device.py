"""The colour stage on the device (:mod:`swim.color.srgb_device`) against the host's NumPy chain and compiled kernel."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import swim.color as sc
from swim.color.display import _srgb8_compiled
from swim.color.spectrum import _DEFAULT_WAVELENGTHS, _linear_matrix, _may_clip_quadratic, _monomial_solve
from swim.color.srgb_device import solar_relative_to_srgb8_device
from swim.errors import SwimInputError


def sky_like(shape, seed=0):
    """Radiances (3, *shape) of skies, clouds and odd spectra: lognormal levels, a bluish tilt, a few pixels with one
    channel far off (spectra that need clipping, or fall outside the display's gamut), NaN pixels and exact zeros."""
    rng = np.random.default_rng(seed)
    level = rng.lognormal(-1.0, 1.2, size=shape)
    tilt = rng.uniform(0.6, 1.4, size=(3,) + shape)
    r = (level * tilt * np.array([0.7, 0.85, 1.0]).reshape((3,) + (1,) * len(shape))).astype(np.float32)
    flat = r.reshape(3, -1)
    n = flat.shape[1]
    odd = rng.choice(n, size=max(n // 20, 1), replace=False)
    flat[rng.integers(0, 3, size=odd.size), odd] *= rng.choice([0.01, 8.0], size=odd.size)
    flat[:, rng.choice(n, size=max(n // 50, 1), replace=False)] = np.nan
    flat[:, :1] = 0.0
    return r


def numpy_chain(radiance, white_level, gamut):
    """The NumPy functions' codes (spectral sum, display matrix, gamut mapping, sRGB encoding), NaN pixels black."""
    r = np.asarray(radiance, dtype=float)
    invalid = np.isnan(r).any(axis=0)
    out = sc.encode_srgb8(sc.XYZ_to_display_rgb(sc.solar_relative_to_XYZ(np.where(invalid, 0.0, r)), white_level,
                                                gamut=gamut))
    out[invalid] = 0
    return out


@pytest.mark.parametrize("shape", [(), (7,), (40, 50), (3, 16, 16)], ids=["pixel", "row", "image", "3-d"])
@pytest.mark.parametrize("gamut", ["filmic", "preserve_hue", "clip"])
@pytest.mark.parametrize("white_level", [1.5, 0.3])
def test_device_codes_are_the_numpy_chains(shape, gamut, white_level):
    r = sky_like(shape, seed=len(shape))
    codes, need = solar_relative_to_srgb8_device(jnp.asarray(r), white_level, gamut=gamut)
    codes, need = np.asarray(codes), np.asarray(need)
    assert codes.shape == shape + (3,) and codes.dtype == np.uint8 and need.shape == shape
    reference = numpy_chain(r, white_level, gamut)
    # the flagged pixels are those whose quadratic may be negative (the spectral sum clips them), no others
    valid = ~np.isnan(r).any(axis=0)
    coef = _monomial_solve(_DEFAULT_WAVELENGTHS) @ np.where(valid, r, 0.0).astype(float).reshape(3, -1)
    np.testing.assert_array_equal(need, valid & _may_clip_quadratic(coef.T).reshape(shape))
    np.testing.assert_array_equal(codes[~need], reference[~need])
    assert (codes[need] == 0).all()
    assert (codes[~valid] == 0).all()


def test_device_codes_are_the_host_kernels_on_a_big_image():
    """Every code of a 512 x 512 image as the host's compiled colour stage gives it, the flagged pixels aside; some
    pixels of it are flagged."""
    r = sky_like((512, 512), seed=3)
    codes, need = (np.asarray(a) for a in solar_relative_to_srgb8_device(jnp.asarray(r), 1.5))
    host = _srgb8_compiled(r.astype(float), 1.5, "filmic")
    assert 0 < need.sum() < need.size
    np.testing.assert_array_equal(codes[~need], host[~need])


def test_exposure_and_flat_white():
    """A flat L' equal to the white level is display white (255, 255, 255) without the tone curve and the neutral
    grey of its shoulder with it, half of it a neutral grey; black for 0 (paper Sect. 3.8: the sun's spectrum is
    white)."""
    r = np.array([[1.5, 0.75, 0.0]] * 3, np.float32)
    codes, need = solar_relative_to_srgb8_device(jnp.asarray(r), 1.5, gamut="preserve_hue")
    codes = np.asarray(codes)
    assert not np.asarray(need).any()
    np.testing.assert_array_equal(codes[0], [255, 255, 255])
    filmic = np.asarray(solar_relative_to_srgb8_device(jnp.asarray(r), 1.5)[0])
    np.testing.assert_array_equal(filmic[0], [sc.encode_srgb8(np.array(0.6 + 0.4 * (1 - np.exp(-1.0))))] * 3)
    assert codes[1, 0] == codes[1, 1] == codes[1, 2] == sc.encode_srgb8(np.array(0.5))
    np.testing.assert_array_equal(codes[2], [0, 0, 0])


def test_bad_arguments_are_named():
    r = jnp.ones((3, 4), jnp.float32)
    with pytest.raises(SwimInputError, match="white_level"):
        solar_relative_to_srgb8_device(r, 0.0)
    with pytest.raises(SwimInputError, match="gamut"):
        solar_relative_to_srgb8_device(r, 1.5, gamut="vivid")
    with pytest.raises(ValueError, match="3 wavelengths"):
        solar_relative_to_srgb8_device(jnp.ones((4, 4)), 1.5)


def test_the_linear_matrix_is_the_hosts():
    """The device takes the host's XYZ matrix (not a copy of its numbers): XYZ = M L' of a flat L' is the sun's."""
    np.testing.assert_allclose(_linear_matrix(_DEFAULT_WAVELENGTHS) @ np.ones(3), sc.sun_white_XYZ(), rtol=1e-12)
