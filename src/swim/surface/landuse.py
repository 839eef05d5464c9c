"""Land-use classes of the WRF/WPS schemes and their snow-free spectral albedo at 615, 546 and 450 nm.

Source of the numbers (details and the full tables in ``docs/surfaces.md``):

* **Spectral albedo of 20 reference surface types** (the 17 IGBP classes plus tundra, fresh snow and sea
  ice): the CERES/SARB Surface Properties database (NASA Langley, May 2006 release), 15 bands from 200 to
  3750 nm, as tabulated in ``SPECTRAL_ALBEDO`` of the US EPA CMAQ in-line photolysis preprocessor,
  ``BLD/ALBEDO_REFER_DATA.F`` of github.com/USEPA/CMAQ (commit 68342e871f8db1bc880ac3c9e4147f02d7661a7f;
  J. Streicher 2010, B. Hutzell 2013). The values are used as tabulated, without CMAQ's solar-zenith,
  season, "MODIS2SPECTRAL" and snow factors. CMAQ's zenith factor (Briegleb et al. 1986) is 1 at a 60 deg
  solar zenith angle, so the tabulated values are the albedo at 60 deg, which for these surfaces lies within
  about 10 % of the white-sky (diffuse) albedo.
* **Class mapping**: ``ALBMAP_REF2USGS``/``ALBFAC_REF2USGS`` (USGS 24 classes) and ``ALBMAP_REF2MODIS``
  (MODIS/IGBP classes; the three tundra classes share the reference "tundra") of the same CMAQ file. USGS
  classes 25-28 (Playa, Lava, White Sand, Lakes) are not in CMAQ; here Playa, Lava and White Sand take the
  barren/desert spectrum and Lakes the water spectrum (an approximation for the *shape*; readers that have
  the model's broadband albedo rescale it, :func:`swim.surface.albedo.spectral_albedo_from_broadband`).
* **Interpolation to the SWIm wavelengths**: linear in wavelength between the CERES/SARB band centres
  397.5, 467.5, 546.25 and 642.3 nm (450 nm between 397.5 and 467.5 nm; 546 nm at 546.25 nm; 615 nm between
  546.25 and 642.3 nm).
* **Shortwave broadband albedo of a class**: the 15 band albedos weighted with the ASTM G173-03 global
  (AM1.5, 37 deg tilt) solar spectrum integrated over each band (band edges midway between the band
  centres; the spectrum starts at 280 nm): :data:`CERES_SARB_BAND_WEIGHTS`. WRF's ``ALBEDO``/``ALBBCK``/
  ``ALBEDO12M``/``SNOALB`` are shortwave broadband albedos, so this is the quantity to compare them with.

The WRF/WPS land-use scheme is named by the ``MMINLU`` global attribute of ``geo_em``/``met_em``/``wrfout``
files: ``"USGS"`` (24 classes; 28 with Playa, Lava, White Sand and Lakes) and
``"MODIFIED_IGBP_MODIS_NOAH"`` (20 classes; 21 with Lakes). ``"USGS-RUC"`` and ``"MODI-RUC"`` (the same
class lists with the RUC land-surface model's parameter tables) are accepted as aliases. Class numbers and
names are those of WRF's ``LANDUSE.TBL``.

References
----------
Briegleb, B. P., Minnis, P., Ramanathan, V., Harrison, E. (1986): Comparison of regional clear-sky albedos
inferred from satellite observations and model computations, J. Clim. Appl. Meteor. 25, 214-226.
Rutan, D., Rose, F., Roman, M., Manalo-Smith, N., Schaaf, C., Charlock, T. (2009): Development and assessment
of broadband surface albedo from Clouds and the Earth's Radiant Energy System Clouds and Radiation Swath data
product, J. Geophys. Res. 114, D08125, doi:10.1029/2008JD010669.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..constants import WAVELENGTHS_NM
from ..errors import SwimInputError

logger = logging.getLogger(__name__)

__all__ = [
    "CERES_SARB_WAVELENGTHS_NM",
    "CERES_SARB_BAND_WEIGHTS",
    "CERES_SARB_TYPES",
    "CERES_SARB_SPECTRAL_ALBEDO",
    "SURFACE_KINDS",
    "LandUseClass",
    "LANDUSE_SCHEMES",
    "SCHEME_ALIASES",
    "reference_spectral_albedo",
    "reference_shortwave_albedo",
    "landuse_scheme",
    "landuse_classes",
    "scheme_from_attrs",
    "class_table",
]

#: Centres of the 15 CERES/SARB surface-albedo bands [nm] (CMAQ ``WVBAND``).
CERES_SARB_WAVELENGTHS_NM = np.array(
    [200.05, 234.3, 264.8, 292.1, 310.5, 340.0, 397.5, 467.5, 546.25, 642.3, 1000.0, 1550.0, 2150.0, 3000.0, 3750.0]
)

#: Weight of each CERES/SARB band in the shortwave broadband albedo [-]: the ASTM G173-03 global (AM1.5)
#: irradiance integrated between the midpoints of adjacent band centres (280-4000 nm), normalised to 1.
CERES_SARB_BAND_WEIGHTS = np.array(
    [0.0, 0.0, 0.0, 0.0, 0.0028, 0.0217, 0.0595, 0.1121, 0.1320, 0.2818, 0.2586, 0.0914, 0.0323, 0.0020, 0.0057]
)
CERES_SARB_BAND_WEIGHTS = CERES_SARB_BAND_WEIGHTS / CERES_SARB_BAND_WEIGHTS.sum()

#: The 20 CERES/SARB reference surface types (1-based, as in CMAQ ``LANDUSE``).
CERES_SARB_TYPES = {
    1: "evergreen needleleaf forest",
    2: "evergreen broadleaf forest",
    3: "deciduous needleleaf forest",
    4: "deciduous broadleaf forest",
    5: "mixed forest",
    6: "closed shrubs",
    7: "open shrubs",
    8: "woody savanna",
    9: "savanna",
    10: "grassland",
    11: "permanent wetlands",
    12: "cropland",
    13: "urban",
    14: "crop mosaic",
    15: "permanent snow",
    16: "barren / desert",
    17: "ocean water",
    18: "tundra",
    19: "fresh snow",
    20: "sea ice",
}

#: Spectral albedo [-] of the 20 reference types in the 15 bands of :data:`CERES_SARB_WAVELENGTHS_NM`
#: (CMAQ ``SPECTRAL_ALBEDO``, CERES/SARB Surface Properties database, May 2006), shape (20, 15); row
#: ``t - 1`` is type ``t``.
CERES_SARB_SPECTRAL_ALBEDO = np.array(
    [
        [0.032, 0.032, 0.032, 0.032, 0.032, 0.032, 0.032, 0.032, 0.046, 0.046, 0.235, 0.096, 0.038, 0.038, 0.038],
        [0.044, 0.044, 0.044, 0.044, 0.044, 0.044, 0.044, 0.044, 0.044, 0.044, 0.234, 0.193, 0.112, 0.112, 0.112],
        [0.032, 0.032, 0.032, 0.032, 0.032, 0.032, 0.032, 0.032, 0.046, 0.046, 0.235, 0.096, 0.038, 0.038, 0.038],
        [0.034, 0.034, 0.034, 0.034, 0.034, 0.034, 0.034, 0.034, 0.066, 0.067, 0.312, 0.276, 0.160, 0.160, 0.160],
        [0.033, 0.033, 0.033, 0.033, 0.033, 0.033, 0.033, 0.033, 0.056, 0.057, 0.274, 0.186, 0.099, 0.099, 0.099],
        [0.010, 0.010, 0.010, 0.015, 0.017, 0.020, 0.036, 0.045, 0.055, 0.156, 0.350, 0.239, 0.101, 0.101, 0.101],
        [0.095, 0.095, 0.095, 0.095, 0.095, 0.095, 0.098, 0.104, 0.122, 0.157, 0.231, 0.330, 0.311, 0.150, 0.150],
        [0.020, 0.020, 0.020, 0.023, 0.024, 0.026, 0.035, 0.041, 0.102, 0.104, 0.366, 0.291, 0.151, 0.107, 0.107],
        [0.010, 0.010, 0.010, 0.015, 0.017, 0.020, 0.036, 0.045, 0.126, 0.129, 0.402, 0.301, 0.145, 0.071, 0.071],
        [0.010, 0.010, 0.010, 0.015, 0.017, 0.020, 0.036, 0.045, 0.126, 0.129, 0.402, 0.301, 0.145, 0.071, 0.071],
        [0.039, 0.039, 0.039, 0.039, 0.039, 0.039, 0.039, 0.039, 0.051, 0.071, 0.164, 0.100, 0.056, 0.056, 0.056],
        [0.010, 0.010, 0.010, 0.015, 0.017, 0.020, 0.036, 0.045, 0.115, 0.099, 0.442, 0.271, 0.122, 0.059, 0.059],
        [0.052, 0.052, 0.052, 0.052, 0.052, 0.052, 0.052, 0.066, 0.104, 0.114, 0.304, 0.258, 0.258, 0.258, 0.258],
        [0.010, 0.010, 0.010, 0.015, 0.017, 0.020, 0.036, 0.045, 0.090, 0.083, 0.377, 0.273, 0.141, 0.110, 0.110],
        [0.910, 0.910, 0.910, 0.916, 0.921, 0.931, 0.947, 0.964, 0.953, 0.920, 0.635, 0.013, 0.006, 0.009, 0.014],
        [0.144, 0.144, 0.144, 0.144, 0.144, 0.144, 0.144, 0.179, 0.263, 0.331, 0.405, 0.390, 0.390, 0.390, 0.390],
        [0.066, 0.066, 0.066, 0.070, 0.073, 0.082, 0.094, 0.091, 0.078, 0.072, 0.066, 0.062, 0.055, 0.044, 0.069],
        [0.180, 0.180, 0.180, 0.180, 0.180, 0.180, 0.180, 0.180, 0.180, 0.180, 0.247, 0.265, 0.265, 0.265, 0.265],
        [0.979, 0.979, 0.979, 0.980, 0.982, 0.984, 0.988, 0.992, 0.989, 0.982, 0.902, 0.143, 0.168, 0.019, 0.015],
        [0.778, 0.778, 0.778, 0.778, 0.778, 0.778, 0.778, 0.778, 0.778, 0.752, 0.393, 0.055, 0.054, 0.036, 0.036],
    ]
)

#: Surface kinds of a land-use class: ``land`` (vegetation, soil, rock), ``urban``, ``water`` (a glint model
#: applies; the tabulated albedo is the diffuse albedo) and ``snow_ice`` (permanent snow or ice).
SURFACE_KINDS = ("land", "urban", "water", "snow_ice")


def reference_spectral_albedo(reference_type: int, wavelengths_nm=None) -> np.ndarray:
    """Spectral albedo of a CERES/SARB reference type, linearly interpolated in wavelength.

    Parameters
    ----------
    reference_type : int
        1-20 (:data:`CERES_SARB_TYPES`).
    wavelengths_nm : array_like, optional
        Wavelengths [nm] in [200.05, 3750]; default :data:`swim.constants.WAVELENGTHS_NM` (615, 546, 450).

    Returns
    -------
    numpy.ndarray
        Albedo [-] at ``wavelengths_nm``, same shape.

    Raises
    ------
    SwimInputError
        For an unknown type or wavelengths outside the tabulated range.
    """
    if reference_type not in CERES_SARB_TYPES:
        raise SwimInputError(f"reference_type={reference_type!r}: expected a CERES/SARB surface type 1-20")
    wl = WAVELENGTHS_NM if wavelengths_nm is None else np.asarray(wavelengths_nm, dtype=float)
    if np.any(wl < CERES_SARB_WAVELENGTHS_NM[0]) or np.any(wl > CERES_SARB_WAVELENGTHS_NM[-1]):
        raise SwimInputError(
            f"wavelengths_nm must lie in [{CERES_SARB_WAVELENGTHS_NM[0]}, {CERES_SARB_WAVELENGTHS_NM[-1]}] nm"
        )
    return np.interp(wl, CERES_SARB_WAVELENGTHS_NM, CERES_SARB_SPECTRAL_ALBEDO[reference_type - 1])


def reference_shortwave_albedo(reference_type: int) -> float:
    """Shortwave (280-4000 nm) broadband albedo [-] of a CERES/SARB reference type.

    The band albedos weighted with :data:`CERES_SARB_BAND_WEIGHTS` (ASTM G173-03 global spectrum).
    """
    if reference_type not in CERES_SARB_TYPES:
        raise SwimInputError(f"reference_type={reference_type!r}: expected a CERES/SARB surface type 1-20")
    return float(np.dot(CERES_SARB_BAND_WEIGHTS, CERES_SARB_SPECTRAL_ALBEDO[reference_type - 1]))


@dataclass(frozen=True)
class LandUseClass:
    """One class of a land-use scheme.

    Attributes
    ----------
    index : int
        Class number in the scheme (``LU_INDEX`` value, 1-based).
    name : str
        Class name as in WRF's ``LANDUSE.TBL``.
    kind : str
        One of :data:`SURFACE_KINDS`.
    reference_type : int
        CERES/SARB reference type whose spectrum the class takes.
    factor : float
        Factor on the reference spectrum (CMAQ ``ALBFAC_*``; 1 for most classes).
    albedo : tuple of float
        Snow-free spectral albedo [-] at (615, 546, 450) nm: ``factor`` x the interpolated reference spectrum,
        clipped to [0, 1].
    shortwave_albedo : float
        Shortwave broadband albedo [-] of the class (``factor`` x :func:`reference_shortwave_albedo`).
    """

    index: int
    name: str
    kind: str
    reference_type: int
    factor: float
    albedo: tuple
    shortwave_albedo: float


def _make(entries: dict[int, tuple[str, str, int, float]]) -> dict[int, LandUseClass]:
    out = {}
    for index, (name, kind, ref, factor) in entries.items():
        albedo = np.clip(factor * reference_spectral_albedo(ref), 0.0, 1.0)
        out[index] = LandUseClass(
            index=index,
            name=name,
            kind=kind,
            reference_type=ref,
            factor=factor,
            albedo=tuple(float(a) for a in albedo),
            shortwave_albedo=float(min(1.0, factor * reference_shortwave_albedo(ref))),
        )
    return out


# (name, kind, CERES/SARB reference type, factor); reference types and factors of classes 1-24 from CMAQ
# ALBMAP_REF2USGS / ALBFAC_REF2USGS (2013 version: Shrubland -> open shrubs).
_USGS = {
    1: ("Urban and Built-Up Land", "urban", 13, 1.0),
    2: ("Dryland Cropland and Pasture", "land", 12, 1.0),
    3: ("Irrigated Cropland and Pasture", "land", 12, 1.0588),
    4: ("Mixed Dryland/Irrigated Cropland and Pasture", "land", 12, 1.0588),
    5: ("Cropland/Grassland Mosaic", "land", 14, 1.0),
    6: ("Cropland/Woodland Mosaic", "land", 14, 0.8889),
    7: ("Grassland", "land", 10, 1.0),
    8: ("Shrubland", "land", 7, 1.0),
    9: ("Mixed Shrubland/Grassland", "land", 7, 1.0),
    10: ("Savanna", "land", 9, 1.0),
    11: ("Deciduous Broadleaf Forest", "land", 4, 1.0),
    12: ("Deciduous Needleleaf Forest", "land", 3, 1.0),
    13: ("Evergreen Broadleaf Forest", "land", 2, 1.0),
    14: ("Evergreen Needleleaf Forest", "land", 1, 1.0),
    15: ("Mixed Forest", "land", 5, 1.0),
    16: ("Water Bodies", "water", 17, 1.0),
    17: ("Herbaceous Wetland", "land", 11, 1.0),
    18: ("Wooded Wetland", "land", 11, 1.0),
    19: ("Barren or Sparsely Vegetated", "land", 16, 1.0),
    20: ("Herbaceous Tundra", "land", 18, 1.0),
    21: ("Wooded Tundra", "land", 18, 1.0),
    22: ("Mixed Tundra", "land", 18, 1.0),
    23: ("Bare Ground Tundra", "land", 18, 1.0),
    24: ("Snow or Ice", "snow_ice", 15, 1.0),
    # not in CMAQ: approximations (see the module docstring)
    25: ("Playa", "land", 16, 1.0),
    26: ("Lava", "land", 16, 1.0),
    27: ("White Sand", "land", 16, 1.0),
    28: ("Lakes", "water", 17, 1.0),
}

# CMAQ ALBMAP_REF2MODIS: classes 1-17 are the reference types 1-17, the tundra classes 18-20 take "tundra".
_IGBP = {
    1: ("Evergreen Needleleaf Forest", "land", 1, 1.0),
    2: ("Evergreen Broadleaf Forest", "land", 2, 1.0),
    3: ("Deciduous Needleleaf Forest", "land", 3, 1.0),
    4: ("Deciduous Broadleaf Forest", "land", 4, 1.0),
    5: ("Mixed Forests", "land", 5, 1.0),
    6: ("Closed Shrublands", "land", 6, 1.0),
    7: ("Open Shrublands", "land", 7, 1.0),
    8: ("Woody Savannas", "land", 8, 1.0),
    9: ("Savannas", "land", 9, 1.0),
    10: ("Grasslands", "land", 10, 1.0),
    11: ("Permanent Wetlands", "land", 11, 1.0),
    12: ("Croplands", "land", 12, 1.0),
    13: ("Urban and Built-Up", "urban", 13, 1.0),
    14: ("Cropland/Natural Vegetation Mosaic", "land", 14, 1.0),
    15: ("Snow and Ice", "snow_ice", 15, 1.0),
    16: ("Barren or Sparsely Vegetated", "land", 16, 1.0),
    17: ("Water", "water", 17, 1.0),
    18: ("Wooded Tundra", "land", 18, 1.0),
    19: ("Mixed Tundra", "land", 18, 1.0),
    20: ("Barren Tundra", "land", 18, 1.0),
    21: ("Lakes", "water", 17, 1.0),
}

#: Land-use schemes by ``MMINLU``: class number -> :class:`LandUseClass`.
LANDUSE_SCHEMES: dict[str, dict[int, LandUseClass]] = {
    "USGS": _make(_USGS),
    "MODIFIED_IGBP_MODIS_NOAH": _make(_IGBP),
}
#: Other ``MMINLU`` spellings with the same class lists.
SCHEME_ALIASES = {"USGS-RUC": "USGS", "MODI-RUC": "MODIFIED_IGBP_MODIS_NOAH", "MODIS": "MODIFIED_IGBP_MODIS_NOAH"}
#: Number of classes each scheme comes with (``NUM_LAND_CAT``).
_NUM_LAND_CAT = {"USGS": (24, 27, 28), "MODIFIED_IGBP_MODIS_NOAH": (20, 21)}


def landuse_scheme(mminlu) -> str:
    """Canonical scheme name for an ``MMINLU`` value.

    Parameters
    ----------
    mminlu : str or bytes
        The ``MMINLU`` attribute of a WRF/WPS file (case and surrounding blanks are ignored).

    Returns
    -------
    str
        ``"USGS"`` or ``"MODIFIED_IGBP_MODIS_NOAH"``.

    Raises
    ------
    SwimInputError
        For a scheme without a table (e.g. ``NLCD40``).
    """
    if isinstance(mminlu, bytes):
        mminlu = mminlu.decode("ascii", "replace")
    key = str(mminlu).strip().upper()
    key = SCHEME_ALIASES.get(key, key)
    if key not in LANDUSE_SCHEMES:
        raise SwimInputError(
            f"land-use scheme MMINLU={mminlu!r} has no albedo table; supported: {sorted(LANDUSE_SCHEMES)} "
            f"(aliases {sorted(SCHEME_ALIASES)})"
        )
    return key


def landuse_classes(scheme) -> dict[int, LandUseClass]:
    """The classes of a scheme (``MMINLU`` value or alias): class number -> :class:`LandUseClass`."""
    return LANDUSE_SCHEMES[landuse_scheme(scheme)]


def scheme_from_attrs(attrs: dict, label: str = "file") -> str | None:
    """Scheme of a WRF/WPS file from its global attributes, checked against ``ISWATER``/``ISICE``/``ISLAKE``.

    Parameters
    ----------
    attrs : dict
        Global attributes (``MMINLU``, optionally ``NUM_LAND_CAT``, ``ISWATER``, ``ISLAKE``, ``ISICE``,
        ``ISURBAN``).
    label : str
        Used in log messages.

    Returns
    -------
    str or None
        The canonical scheme name; None (logged) when ``MMINLU`` is absent or has no table.
    """
    if "MMINLU" not in attrs:
        logger.info("%s has no MMINLU attribute: land use not used for the albedo", label)
        return None
    try:
        scheme = landuse_scheme(attrs["MMINLU"])
    except SwimInputError as exc:
        logger.warning("%s: %s; land use not used for the albedo", label, exc)
        return None
    classes = LANDUSE_SCHEMES[scheme]
    n = attrs.get("NUM_LAND_CAT")
    if n is not None and int(n) not in _NUM_LAND_CAT[scheme]:
        logger.warning("%s: NUM_LAND_CAT=%s is unusual for %s (expected one of %s)", label, n, scheme, _NUM_LAND_CAT[scheme])
    for key, kinds in (("ISWATER", ("water",)), ("ISLAKE", ("water",)), ("ISICE", ("snow_ice",)), ("ISURBAN", ("urban",))):
        value = attrs.get(key)
        if value is None or int(value) < 1:
            continue
        cls = classes.get(int(value))
        if cls is None or cls.kind not in kinds:
            logger.warning(
                "%s: %s=%s but class %s of %s is %s in swim's table", label, key, value, value, scheme,
                "absent" if cls is None else f"'{cls.name}' ({cls.kind})",
            )
    return scheme


def class_table(scheme) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Arrays for vectorised look-up of a scheme's classes, indexed by class number.

    Parameters
    ----------
    scheme : str
        ``MMINLU`` value or alias.

    Returns
    -------
    albedo : numpy.ndarray
        Shape (ncat + 1, 3): spectral albedo [-] at (615, 546, 450) nm; row 0 (no class) is NaN.
    shortwave : numpy.ndarray
        Shape (ncat + 1,): shortwave broadband albedo [-]; entry 0 is NaN.
    kind : numpy.ndarray
        Shape (ncat + 1,), dtype object: the :data:`SURFACE_KINDS` entry of each class; entry 0 is "".
    """
    classes = landuse_classes(scheme)
    n = max(classes)
    albedo = np.full((n + 1, WAVELENGTHS_NM.size), np.nan)
    shortwave = np.full(n + 1, np.nan)
    kind = np.full(n + 1, "", dtype=object)
    for i, c in classes.items():
        albedo[i] = c.albedo
        shortwave[i] = c.shortwave_albedo
        kind[i] = c.kind
    return albedo, shortwave, kind
