"""Golden-image regression tests of the CPU backend: small renders of the built-in scene against stored images.

They guard behaviour, not physics: an intended change regenerates the images (scripts/make_golden_images.py) and
says why in its commit. The tolerance admits float rounding between CPUs and compilers (the march runs in float32
and float64 with fused multiply-adds where LLVM chooses them) but not a change of the method.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from golden_views import VIEWS, render_view

GOLDEN_DIR = Path(__file__).resolve().parents[1] / "data" / "golden"


@pytest.mark.parametrize("name", list(VIEWS))
def test_render_matches_its_golden_image(name):
    golden = np.load(GOLDEN_DIR / f"{name}.npz")
    image = render_view(name)
    radiance = image["radiance"].sel(wavelength=546).values
    expected = golden["radiance_546"].astype(float)
    np.testing.assert_array_equal(np.isfinite(radiance), np.isfinite(expected))
    valid = np.isfinite(expected)
    rel = np.abs(radiance[valid] - expected[valid]) / np.maximum(np.abs(expected[valid]), 1e-3)
    assert np.percentile(rel, 99) < 1e-3 and rel.max() < 2e-2, (np.percentile(rel, 99), rel.max())
    codes = np.abs(image["rgb"].values.astype(int) - golden["rgb"].astype(int))
    assert codes.max() <= 2 and np.mean(codes > 0) < 0.01, (codes.max(), np.mean(codes > 0))
