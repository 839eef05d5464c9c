"""City lights' sky glow against Walker's law (Walker 1977, PASP 89, 405-409, doi:10.1086/130142).

Walker measured the sky brightness at 45 deg elevation towards towns in California and found its increase over the
natural sky to fall with the distance d as d^-2.5, I / I_natural = 0.01 P d^-2.5 (P the population, d in km).
Garstang's (1986, PASP 98, 364-375, doi:10.1086/131768) single-scattering model of the same geometry reproduced it.
swim's model (swim.rt.city_lights: Garstang's emission law, 1000 lm per person, F = 0.1, G = 0.15, the renderer's
clear air) must give

* the ratio of the glow at 10 and 40 km within a factor 2 of Walker's 4^2.5 = 32, i.e. in [16, 64];
* the glow's luminance within a factor 4 of Walker's absolute level, the natural sky at 45 deg elevation taken as
  21.6 V mag arcsec-2 (2.5e-4 cd m-2; a dark site's zenith of about 22.0, Benn & Ellison 1998, brightened by the air
  mass), with V = 0 mag arcsec-2 = 1.08e5 cd m-2.
"""

from __future__ import annotations

import numpy as np
import pytest

from swim.constants import EARTH_RADIUS_M
from swim.rt.city_lights import LightSources, clear_air, luminance, path_distances, sky_glow
from swim.surface.city_lights import town_light_emission, upward_fraction

pytestmark = pytest.mark.validation

#: Population of the town [persons].
POPULATION = 1e5
#: The natural sky's luminance at 45 deg elevation [cd m-2]: 21.6 V mag arcsec-2 (module docstring).
NATURAL_SKY_45_CD_M2 = 1.08e5 * 10 ** (-0.4 * 21.6)


def _glow_at_45_deg(distance_km, lamp="sodium", aod_550=0.05):
    """The glow's spectral radiance (3,) [W m-2 sr-1 nm-1] at 45 deg elevation towards a town of
    :data:`POPULATION` (radius of 2000 persons km-2) seen from ``distance_km`` away, 2 m above the ground."""
    r = EARTH_RADIUS_M
    radius_m = np.sqrt(POPULATION / (np.pi * 2000.0)) * 1e3
    town = LightSources([[0.0, 0.0, r]], [POPULATION * 1000.0 * upward_fraction()], [radius_m], lamp)
    a = distance_km * 1e3 / r
    observer = np.array([0.0, -np.sin(a), np.cos(a)]) * (r + 2.0)
    up = observer / np.linalg.norm(observer)
    towards = np.array([0.0, np.cos(a), np.sin(a)])  # horizontal, towards the town
    view = (towards + up) / np.sqrt(2.0)
    return sky_glow(observer, view[None], town, clear_air(aod_550), path_distances(200, 5.0, 200_000.0))[0]


@pytest.mark.parametrize("aod_550", [0.05, 0.1])
@pytest.mark.parametrize("lamp", ["sodium", "led"])
def test_glow_falls_as_walkers_d_to_the_minus_2_5(lamp, aod_550):
    ratio = luminance(_glow_at_45_deg(10.0, lamp, aod_550)) / luminance(_glow_at_45_deg(40.0, lamp, aod_550))
    assert 16.0 <= ratio <= 64.0, ratio


@pytest.mark.parametrize("distance_km", [10.0, 40.0])
def test_glow_level_near_walkers(distance_km):
    walker = 0.01 * POPULATION * distance_km**-2.5 * NATURAL_SKY_45_CD_M2
    model = float(luminance(_glow_at_45_deg(distance_km)))
    assert walker / 4.0 <= model <= walker * 4.0, model / walker


def test_town_emission_field_holds_garstangs_lumens_per_person():
    lat, lon = np.meshgrid(np.linspace(-0.2, 0.2, 41), np.linspace(-0.2, 0.2, 41), indexing="ij")
    m = town_light_emission(lat, lon, 0.0, 0.0, POPULATION)
    from swim.surface.city_lights import cell_areas

    # 1000 lm per person (Garstang 1986), of which F + G (1 - F) = 0.235 goes up
    assert float((m * cell_areas(lat, lon)).sum()) == pytest.approx(POPULATION * 1000.0 * 0.235, rel=1e-9)
