"""A scene's smoke mass becomes 3-D aerosol extinction in the optical volume, through the smoke's mass extinction
efficiency (Reid et al. 2005: 4.5 m2 g-1 at 550 nm), and is refused in wrong units."""

from __future__ import annotations

import numpy as np
import pytest

from swim.errors import SwimInputError
from swim.io import scene_from_arrays, validate_scene
from swim.optics.model_aerosol import SMOKE_MASS_EXTINCTION_EFFICIENCY
from swim.optics.volume import build_optical_volume


def _scene(smoke):
    z = np.arange(250.0, 4000.0, 500.0)
    x = y = np.arange(-2000.0, 2001.0, 1000.0)
    return scene_from_arrays(x=x, y=y, z=z, reference_lat=39.0, reference_lon=-105.0,
                             smoke_mass_content=np.broadcast_to(smoke, (z.size, y.size, x.size)).copy())


def test_smoke_column_optical_depth():
    smoke = 100e-9  # 100 ug m-3 in every level up to 4 km
    volume = build_optical_volume(_scene(smoke))
    beta = volume["aerosol_extinction"].values  # (level, y, x) [m-1]
    np.testing.assert_allclose(beta[2:-2, 2, 2], SMOKE_MASS_EXTINCTION_EFFICIENCY * smoke, rtol=1e-5)
    assert 4.4e-4 < SMOKE_MASS_EXTINCTION_EFFICIENCY * smoke < 4.6e-4  # 4.5 m2 g-1 x 100 ug m-3 = 0.45 km-1


def test_smoke_in_micrograms_is_refused():
    with pytest.raises(SwimInputError, match="smoke_mass_content.*kg m-3"):
        validate_scene(_scene(50.0).assign(smoke_mass_content=lambda d: d.smoke_mass_content * 1e3))
