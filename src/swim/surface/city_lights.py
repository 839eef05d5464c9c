"""The city lights' emission field: the upward luminous exitance of the artificial light on the ground.

The canonical scene may carry ``upward_light_emission`` (y, x) [lm m-2] (docs/scene-format.md): the luminous flux
per unit ground area that leaves the ground upwards, the lamps' light sent directly up plus the part of their
downward light that the ground reflects. Where a scene has none, it can be made from land use or from towns:

* :func:`urban_light_emission`: a proxy from the urban land-use classes of WRF/WPS (``LU_INDEX`` or the class
  fractions ``LANDUSEF`` of the USGS or MODIS schemes, :mod:`swim.surface.landuse`): each urban cell a population
  density :data:`URBAN_POPULATION_DENSITY_KM2` whose lamps give :data:`LUMENS_PER_PERSON` each, of which the part
  F + G (1 - F) goes up (:func:`upward_fraction`; Garstang 1986).
* :func:`town_light_emission`: a town of a given population as a disc on the grid.

The emission is monochrome here; its spectrum (a lamp kind, :data:`swim.rt.city_lights.LAMP_SPECTRA`) is the
scene's attribute ``lamp_spectrum`` (default high-pressure sodium).

References
----------
Garstang, R. H. (1986), Model for artificial night-sky illumination, PASP 98, 364-375, doi:10.1086/131768
(the per-capita light output, of order 500-1000 lm per person, and the fractions F = 0.1 and G = 0.15).
Walker, M. F. (1977), PASP 89, 405-409, doi:10.1086/130142. U.S. Census Bureau (2012), 2010 Census Urban Area
list: urbanized areas average about 1000 persons km-2, their cores several thousand.
"""

from __future__ import annotations

import numpy as np

from ..constants import EARTH_RADIUS_M
from ..errors import SwimInputError
from .landuse import landuse_classes

#: Light output of the lamps per person [lm] (Garstang 1986's order, 500-1000 lm per person; the larger value).
LUMENS_PER_PERSON = 1000.0
#: Fraction of the lamps' light sent directly upwards, F [-], and the reflectance of the ground, G [-]
#: (Garstang 1986, Sect. 2).
DIRECT_UPWARD_FRACTION, GROUND_REFLECTANCE = 0.10, 0.15
#: Population density of the land-use proxy's urban (built-up) land [persons km-2]: that of a built-up cell, between
#: an urbanized area's mean (about 1000 km-2) and its core (several thousand).
URBAN_POPULATION_DENSITY_KM2 = 2000.0
#: Largest plausible upward luminous exitance [lm m-2] (a floodlit stadium's; larger means wrong units).
MAX_EMISSION_LM_M2 = 1000.0



def upward_fraction(direct_fraction=DIRECT_UPWARD_FRACTION, ground_reflectance=GROUND_REFLECTANCE) -> float:
    """Part of the lamps' light that leaves the ground upwards [-]: F + G (1 - F) (Garstang 1986; 0.235 for the
    defaults).

    Raises
    ------
    SwimInputError
        If F or G lies outside [0, 1].
    """
    f, g = float(direct_fraction), float(ground_reflectance)
    if not (0.0 <= f <= 1.0 and 0.0 <= g <= 1.0):
        raise SwimInputError(f"direct_fraction F and ground_reflectance G must lie in [0, 1]; got {f}, {g}")
    return f + g * (1.0 - f)



def _check_positive(name, value, units):
    """``value`` as a float, checked finite and >= 0 [``units``]; else :class:`SwimInputError` naming ``name``."""
    v = float(value)
    if not (np.isfinite(v) and v >= 0.0):
        raise SwimInputError(f"{name} must be a finite value >= 0 [{units}]; got {value!r}")
    return v



def urban_light_emission(scheme, lu_index=None, landusef=None, population_density_km2=URBAN_POPULATION_DENSITY_KM2,
                         lumens_per_person=LUMENS_PER_PERSON, direct_fraction=DIRECT_UPWARD_FRACTION,
                         ground_reflectance=GROUND_REFLECTANCE) -> np.ndarray:
    """Upward luminous exitance [lm m-2] (y, x) of the urban land of a WRF/WPS land-use field.

    Parameters
    ----------
    scheme : str
        The land-use scheme (``MMINLU``: USGS or MODIFIED_IGBP_MODIS_NOAH and their aliases).
    lu_index : array_like, optional
        Shape (y, x): the dominant class (``LU_INDEX``).
    landusef : array_like, optional
        Shape (class, y, x): the class fractions [-] (``LANDUSEF``; class k at index k - 1); preferred to
        ``lu_index``.
    population_density_km2 : float
        Persons per km2 of urban land.
    lumens_per_person : float
        The lamps' light per person [lm].
    direct_fraction, ground_reflectance : float
        Garstang's F and G [-] (:func:`upward_fraction`).

    Returns
    -------
    numpy.ndarray
        Shape (y, x): urban fraction x density x lumens per person x (F + G (1 - F)) [lm m-2].

    Raises
    ------
    SwimInputError
        Neither field given, an unknown scheme, a density or lumens below 0, fractions outside [0, 1].
    """
    density = _check_positive("population_density_km2", population_density_km2, "km-2") * 1e-6
    lumens = _check_positive("lumens_per_person", lumens_per_person, "lm")
    classes = landuse_classes(scheme)
    urban = sorted(i for i, c in classes.items() if c.kind == "urban")
    if landusef is not None:
        f = np.asarray(landusef, dtype=float)
        if f.ndim != 3 or not np.all(np.isfinite(f)) or f.min() < 0.0 or f.max() > 1.0 + 1e-6:
            raise SwimInputError("landusef must be (class, y, x) finite fractions in [0, 1]")
        fraction = sum(f[i - 1] for i in urban if i - 1 < f.shape[0])
    elif lu_index is not None:
        lu = np.asarray(lu_index)
        fraction = np.isin(np.rint(lu).astype(np.int64), urban).astype(float)
    else:
        raise SwimInputError("urban_light_emission needs lu_index (y, x) or landusef (class, y, x)")
    return np.asarray(fraction, dtype=float) * density * lumens * upward_fraction(direct_fraction, ground_reflectance)



def cell_areas(lat, lon) -> np.ndarray:
    """Area [m2] (y, x) of the cells of a grid of columns at ``lat``, ``lon`` (y, x) [deg]: the cross product of the
    local grid steps on the sphere (central differences; one-sided at the edges)."""
    lat_r, lon_r = np.radians(np.asarray(lat, dtype=float)), np.radians(np.asarray(lon, dtype=float))
    if lat_r.ndim != 2 or lat_r.shape[0] < 2 or lat_r.shape[1] < 2:
        raise SwimInputError(f"lat, lon must be (y, x) grids of at least 2 x 2 [deg]; got shape {lat_r.shape}")
    xyz = np.stack([np.cos(lat_r) * np.cos(lon_r), np.cos(lat_r) * np.sin(lon_r), np.sin(lat_r)], axis=-1)
    dy, dx = np.gradient(xyz * EARTH_RADIUS_M, axis=(0, 1))
    return np.linalg.norm(np.cross(dx, dy), axis=-1)



def town_light_emission(lat, lon, town_lat, town_lon, population, radius_m=None,
                        population_density_km2=URBAN_POPULATION_DENSITY_KM2, lumens_per_person=LUMENS_PER_PERSON,
                        direct_fraction=DIRECT_UPWARD_FRACTION, ground_reflectance=GROUND_REFLECTANCE) -> np.ndarray:
    """Upward luminous exitance [lm m-2] (y, x) of a town of ``population`` on a grid of columns ``lat``, ``lon``
    (y, x) [deg]: a uniform disc about (``town_lat``, ``town_lon``) [deg] of ``radius_m`` [m] (default: the radius of
    the population at ``population_density_km2``), its upward flux population x lumens per person x (F + G (1 - F))
    [lm] shared by the cells whose centres lie in it (all in the nearest cell where none does).

    Raises
    ------
    SwimInputError
        A population that is not > 0, a negative density or lumens, a non-positive radius, a town's latitude or
        longitude that is not finite or out of range, a town farther from the grid than its radius and a cell.
    """
    p = _check_positive("population", population, "persons")
    if p <= 0:
        raise SwimInputError(f"population must be > 0 [persons]; got {population!r}")
    t_lat, t_lon = float(town_lat), float(town_lon)
    if not (np.isfinite(t_lat) and np.isfinite(t_lon) and abs(t_lat) <= 90.0 and abs(t_lon) <= 360.0):
        raise SwimInputError(f"a town's latitude must be in [-90, 90] and its longitude in [-360, 360] [deg]; got "
                             f"({town_lat!r}, {town_lon!r})")
    density = _check_positive("population_density_km2", population_density_km2, "km-2")
    if radius_m is None:
        radius_m = np.sqrt(p / (np.pi * max(density, 1e-9))) * 1e3
    if not (np.isfinite(radius_m) and radius_m > 0.0):
        raise SwimInputError(f"radius_m must be > 0 [m]; got {radius_m!r}")
    flux = p * _check_positive("lumens_per_person", lumens_per_person, "lm") * upward_fraction(
        direct_fraction, ground_reflectance)
    area = cell_areas(lat, lon)
    la, lo = np.radians(np.asarray(lat, dtype=float)), np.radians(np.asarray(lon, dtype=float))
    t_la, t_lo = np.radians(t_lat), np.radians(t_lon)
    cos_c = np.sin(la) * np.sin(t_la) + np.cos(la) * np.cos(t_la) * np.cos(lo - t_lo)
    distance = EARTH_RADIUS_M * np.arccos(np.clip(cos_c, -1.0, 1.0))
    inside = distance <= radius_m
    if not inside.any():
        cell = float(np.sqrt(np.median(area)))
        if distance.min() > radius_m + 2.0 * cell:
            raise SwimInputError(f"the town at ({t_lat:g}, {t_lon:g}) lies {distance.min() / 1e3:.1f} km from the "
                                 "nearest column of the scene: outside its grid")
        inside = distance == distance.min()
    out = np.zeros(area.shape)
    out[inside] = flux / area[inside].sum()
    return out



def check_emission(values, name="upward_light_emission") -> np.ndarray:
    """``values`` as float64, checked: finite, >= 0 and at most :data:`MAX_EMISSION_LM_M2` [lm m-2].

    Raises
    ------
    SwimInputError
        Naming ``name``, the units and the range.
    """
    v = np.asarray(values, dtype=float)
    if not np.all(np.isfinite(v)):
        raise SwimInputError(f"{name}: non-finite values; expected an upward luminous exitance >= 0 lm m-2")
    if v.size and (v.min() < 0.0 or v.max() > MAX_EMISSION_LM_M2):
        raise SwimInputError(f"{name}: range [{v.min():.4g}, {v.max():.4g}] is outside [0, {MAX_EMISSION_LM_M2:g}] "
                             "lm m-2 (the upward luminous exitance of the artificial light)")
    return v
