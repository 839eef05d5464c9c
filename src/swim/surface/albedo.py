"""Spectral surface albedo at the SWIm wavelengths (615, 546, 450 nm) from model fields and images.

Builders (all numpy; the leading axis of a spectral albedo is the wavelength, in the order of
:data:`swim.constants.WAVELENGTHS_NM`):

* :func:`spectral_albedo_from_landuse`, :func:`spectral_albedo_from_landuse_fractions`: snow-free class
  albedos of the WRF/WPS land-use schemes (:mod:`swim.surface.landuse`), for a dominant class
  (``LU_INDEX``) or area-weighted over class fractions (``LANDUSEF``);
* :func:`spectral_albedo_from_broadband`: a model's broadband albedo with the spectral shape of a class;
* :func:`blend_snow`: the snow-covered fraction of a cell with a snow spectrum (what the renderer does);
  :func:`effective_snow_cover`, :func:`snow_cover_from_swe`, :func:`snow_ice_fraction_from_landuse`: the
  scene's ``snow_cover`` from model fields;
* :func:`surface_from_model_fields`: the readers' path from WRF/WPS fields to the scene's snow-free
  ``surface_albedo`` and ``snow_cover``;
* :func:`spectral_albedo_from_rgb`, :func:`regrid_image_to_scene`, :func:`spectral_albedo_from_image`: an
  RGB image (e.g. NASA Blue Marble) as MODIS band reflectances, following Albers et al. (2020), Sect. 3.7.

Units: albedos are fractions in [0, 1]; percent input is converted once, at the edge
(:func:`albedo_to_fraction`). See ``docs/surfaces.md`` for the sources and the conventions.

References
----------
Albers, S. C., et al. (2020): A fast visible-wavelength 3D radiative transfer procedure for NWP
visualization and forward modeling, Atmos. Meas. Tech. 13, 3235-3261, doi:10.5194/amt-13-3235-2020.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..constants import WAVELENGTHS_NM
from ..errors import SwimInputError
from .landuse import class_table, reference_shortwave_albedo, reference_spectral_albedo

logger = logging.getLogger(__name__)

__all__ = [
    "VISIBLE_WEIGHTS",
    "DEFAULT_SNOW_ALBEDO",
    "DEFAULT_SNOW_SHORTWAVE_ALBEDO",
    "FRESH_SNOW_ALBEDO",
    "WATER_SURFACE_DIFFUSE_ALBEDO",
    "MODIS_RGB_BANDS_NM",
    "NOAH_SNOW_DEPLETION_SWE_KG_M2",
    "NOAH_SNOW_DEPLETION_SHAPE",
    "albedo_to_fraction",
    "visible_mean",
    "spectral_albedo_from_landuse",
    "spectral_albedo_from_landuse_fractions",
    "shortwave_albedo_from_landuse",
    "shortwave_albedo_from_landuse_fractions",
    "spectral_albedo_from_broadband",
    "blend_snow",
    "snow_cover_from_swe",
    "snow_ice_fraction_from_landuse",
    "effective_snow_cover",
    "surface_from_model_fields",
    "srgb_to_linear",
    "spectral_albedo_from_rgb",
    "load_image",
    "regrid_image_to_scene",
    "spectral_albedo_from_image",
    "scene_with_albedo_from_image",
]

#: Weights of the albedos at (615, 546, 450) nm in the *visible* broadband mean (:func:`visible_mean`): the
#: ASTM G173-03 global (AM1.5) irradiance integrated over the three sub-bands 580.5-700, 498-580.5 and
#: 400-498 nm (band edges midway between the wavelengths), normalised to 1.
VISIBLE_WEIGHTS = np.array([0.391, 0.292, 0.317])

#: Default snow spectrum [-] at (615, 546, 450) nm: CERES/SARB "permanent snow" (:mod:`swim.surface.landuse`),
#: close to the spectral albedo of snow of ~0.1-0.5 mm grain radius (Wiscombe and Warren 1980).
DEFAULT_SNOW_ALBEDO = reference_spectral_albedo(15)
#: Shortwave broadband albedo of :data:`DEFAULT_SNOW_ALBEDO`'s full CERES/SARB spectrum [-].
DEFAULT_SNOW_SHORTWAVE_ALBEDO = reference_shortwave_albedo(15)
#: CERES/SARB "fresh snow" at (615, 546, 450) nm [-] (fine-grained new snow, Wiscombe and Warren 1980).
FRESH_SNOW_ALBEDO = reference_spectral_albedo(19)
#: Albedo of a flat water surface for isotropic (diffuse) light, Fresnel reflection with n = 1.34 [-]. The
#: water classes of :mod:`swim.surface.landuse` include it (plus the light scattered back from below the
#: surface); a renderer that models the surface reflection itself (glint) should subtract it there.
WATER_SURFACE_DIFFUSE_ALBEDO = 0.066
#: Centre wavelengths [nm] of MODIS bands 1, 4 and 3, the bands behind the red, green and blue channels of
#: the Blue Marble Next Generation (Stockli et al. 2005).
MODIS_RGB_BANDS_NM = np.array([645.0, 555.0, 469.0])
#: Noah LSM snow depletion: snow water equivalent at which the cover is complete (``SNUP`` of
#: VEGPARM.TBL, 0.02-0.08 m water; 0.04 m for grass and crops) [kg m-2].
NOAH_SNOW_DEPLETION_SWE_KG_M2 = 40.0
#: Noah LSM snow depletion shape parameter ``SALP`` [-].
NOAH_SNOW_DEPLETION_SHAPE = 2.6

_PERCENT_UNITS = {"%", "percent", "pct", "percentage"}
_FRACTION_UNITS = {"", "1", "-", "fraction", "dimensionless", "none", "0-1"}


# ---------------------------------------------------------------------------------------------------------------
# units and means


def albedo_to_fraction(values, units=None, name: str = "albedo") -> np.ndarray:
    """Convert an albedo given as a fraction or in percent to a fraction in [0, 1].

    Parameters
    ----------
    values : array_like
        Albedo values, any shape.
    units : str, optional
        ``"%"``/``"percent"`` (divided by 100) or a spelling of 1 (``""``, ``"1"``, ``"-"``, ``"fraction"``).
        None: a maximum above 1 means percent (logged), otherwise a fraction.
    name : str
        Variable name for messages.

    Returns
    -------
    numpy.ndarray
        float64, same shape, in [0, 1].

    Raises
    ------
    SwimInputError
        On non-finite values, unknown units, or values outside [0, 1] after the conversion.
    """
    a = np.array(values, dtype=float)
    if not np.all(np.isfinite(a)):
        raise SwimInputError(f"{name}: {int(np.sum(~np.isfinite(a)))} non-finite value(s); expected an albedo in [0, 1]")
    if units is not None:
        u = str(units).strip().lower()
        if u in _PERCENT_UNITS:
            a = a / 100.0
        elif u not in _FRACTION_UNITS:
            raise SwimInputError(f"{name} has units '{units}'; expected a fraction (1) or percent (%)")
    elif a.size and a.max() > 1.0:
        logger.info("%s: values up to %.3g without units: taken as percent", name, float(a.max()))
        a = a / 100.0
    if a.size and (a.min() < 0.0 or a.max() > 1.0):
        raise SwimInputError(
            f"{name}: range [{a.min():.4g}, {a.max():.4g}] is outside [0, 1] (a fraction; percent must be divided by 100)"
        )
    return a


def visible_mean(albedo) -> np.ndarray:
    """Visible broadband mean of a spectral albedo: ``sum_i w_i a_i`` with :data:`VISIBLE_WEIGHTS`.

    Parameters
    ----------
    albedo : array_like
        Shape (3, ...) at (615, 546, 450) nm [-].

    Returns
    -------
    numpy.ndarray
        Shape (...) [-].
    """
    a = np.asarray(albedo, dtype=float)
    if a.shape[:1] != (WAVELENGTHS_NM.size,):
        raise SwimInputError(f"albedo must have shape (3, ...) for {WAVELENGTHS_NM.tolist()} nm; got {a.shape}")
    return np.tensordot(VISIBLE_WEIGHTS, a, axes=(0, 0))


# ---------------------------------------------------------------------------------------------------------------
# land use


def _class_index(lu_index, n_classes: int, scheme: str) -> np.ndarray:
    lu = np.asarray(lu_index, dtype=float)
    if not np.all(np.isfinite(lu)):
        raise SwimInputError(f"LU_INDEX has {int(np.sum(~np.isfinite(lu)))} non-finite value(s); expected class numbers")
    idx = np.rint(lu).astype(int)
    if np.any(np.abs(lu - idx) > 1e-3):
        raise SwimInputError("LU_INDEX must hold integer class numbers")
    bad = (idx < 1) | (idx > n_classes)
    if bad.any():
        raise SwimInputError(
            f"LU_INDEX holds class(es) {sorted(set(idx[bad].tolist()))[:10]} outside 1-{n_classes} of the {scheme} scheme"
        )
    return idx


def spectral_albedo_from_landuse(lu_index, scheme) -> np.ndarray:
    """Snow-free spectral albedo of the dominant land-use class of each cell.

    Parameters
    ----------
    lu_index : array_like of int
        Shape (...): class numbers (WRF ``LU_INDEX``/``IVGTYP``), 1-based.
    scheme : str
        Land-use scheme, the ``MMINLU`` attribute (``"USGS"``, ``"MODIFIED_IGBP_MODIS_NOAH"``, aliases).

    Returns
    -------
    numpy.ndarray
        Shape (3, ...): albedo [-] at (615, 546, 450) nm (:mod:`swim.surface.landuse`).

    Raises
    ------
    SwimInputError
        For an unknown scheme, non-integer or out-of-range class numbers.
    """
    table, _, _ = class_table(scheme)
    idx = _class_index(lu_index, table.shape[0] - 1, str(scheme))
    return np.moveaxis(table[idx], -1, 0)


def shortwave_albedo_from_landuse(lu_index, scheme) -> np.ndarray:
    """Shortwave broadband albedo [-] of the dominant land-use class, shape of ``lu_index``.

    See :func:`spectral_albedo_from_landuse` for the arguments; the class values are
    :attr:`swim.surface.landuse.LandUseClass.shortwave_albedo`.
    """
    _, shortwave, _ = class_table(scheme)
    return shortwave[_class_index(lu_index, shortwave.size - 1, str(scheme))]


def snow_ice_fraction_from_landuse(scheme, lu_index=None, landusef=None, axis: int = 0) -> np.ndarray:
    """Area fraction [0-1] of the permanent snow/ice classes (kind ``snow_ice``) of a land-use scheme.

    Parameters
    ----------
    scheme : str
        ``MMINLU`` value or alias.
    lu_index : array_like, optional
        Shape (...): dominant class; the fraction is 1 where it is a snow/ice class, else 0.
    landusef : array_like, optional
        Shape (ncat, ...) (class along ``axis``): class fractions; used when given.
    axis : int
        Class axis of ``landusef``.

    Returns
    -------
    numpy.ndarray
        Shape (...) [0-1].
    """
    _, _, kind = class_table(scheme)
    is_ice = (kind == "snow_ice").astype(float)
    if landusef is not None:
        w = _fraction_weights(landusef, kind.size - 1, axis)
        return np.tensordot(is_ice[1 : w.shape[0] + 1], w, axes=(0, 0))
    if lu_index is None:
        raise SwimInputError("snow_ice_fraction_from_landuse needs lu_index or landusef")
    return is_ice[_class_index(lu_index, kind.size - 1, str(scheme))]


def _fraction_weights(landusef, n_classes: int, axis: int) -> np.ndarray:
    f = np.moveaxis(np.asarray(landusef, dtype=float), axis, 0)
    if not np.all(np.isfinite(f)):
        raise SwimInputError(f"LANDUSEF has {int(np.sum(~np.isfinite(f)))} non-finite value(s); expected fractions in [0, 1]")
    if f.min() < -1e-6 or f.max() > 1.0 + 1e-6:
        raise SwimInputError(f"LANDUSEF: range [{f.min():.4g}, {f.max():.4g}] is outside [0, 1] (class area fractions)")
    if f.shape[0] > n_classes:
        extra = f[n_classes:]
        if np.any(extra > 0):
            raise SwimInputError(f"LANDUSEF has {f.shape[0]} classes with non-zero fractions beyond the scheme's {n_classes}")
        f = f[:n_classes]
    total = f.sum(axis=0)
    if np.any(total <= 0):
        raise SwimInputError(f"LANDUSEF: {int(np.sum(total <= 0))} cell(s) with all class fractions 0")
    return np.clip(f, 0.0, None) / total


def spectral_albedo_from_landuse_fractions(landusef, scheme, axis: int = 0) -> np.ndarray:
    """Snow-free spectral albedo as the area-weighted mean over the land-use class fractions.

    ``a(lambda) = sum_c f_c a_c(lambda) / sum_c f_c``: the albedo of a cell whose sub-areas reflect
    independently (the fractions are renormalised to sum 1).

    Parameters
    ----------
    landusef : array_like
        Shape (ncat, ...) (class along ``axis``): area fractions [0-1] of classes 1..ncat (WPS ``LANDUSEF``).
    scheme : str
        ``MMINLU`` value or alias.
    axis : int
        Axis of ``landusef`` that runs over the classes.

    Returns
    -------
    numpy.ndarray
        Shape (3, ...) [-] at (615, 546, 450) nm.

    Raises
    ------
    SwimInputError
        For an unknown scheme, fractions outside [0, 1], non-zero fractions of classes the scheme lacks, or
        cells without any class.
    """
    table, _, _ = class_table(scheme)
    w = _fraction_weights(landusef, table.shape[0] - 1, axis)
    return np.tensordot(table[1 : w.shape[0] + 1].T, w, axes=(1, 0))


def shortwave_albedo_from_landuse_fractions(landusef, scheme, axis: int = 0) -> np.ndarray:
    """Area-weighted shortwave broadband albedo [-] over the class fractions, shape ``landusef`` less ``axis``.

    See :func:`spectral_albedo_from_landuse_fractions` for the arguments.
    """
    _, shortwave, _ = class_table(scheme)
    w = _fraction_weights(landusef, shortwave.size - 1, axis)
    return np.tensordot(shortwave[1 : w.shape[0] + 1], w, axes=(0, 0))


# ---------------------------------------------------------------------------------------------------------------
# broadband and snow


def spectral_albedo_from_broadband(albedo_broadband, class_albedo, class_broadband=None, units=None) -> np.ndarray:
    """Give a broadband albedo the spectral shape of a class: ``a(lambda) = a_c(lambda) A / A_c``.

    ``A`` is the model's broadband albedo and ``A_c`` the class's broadband albedo of the same kind:
    ``class_broadband`` when given (e.g. the class's *shortwave* albedo,
    :func:`shortwave_albedo_from_landuse`, for WRF's shortwave ``ALBEDO``), else the visible mean of
    ``class_albedo`` (:func:`visible_mean`), in which case the visible mean of the result equals ``A``
    (before clipping). The result is clipped to [0, 1] (logged). Where ``A_c`` is 0 the result is ``A`` at
    every wavelength.

    Parameters
    ----------
    albedo_broadband : array_like
        Shape (...): broadband albedo, fraction or percent (see ``units``).
    class_albedo : array_like
        Shape (3, ...) or (3,): snow-free spectral albedo of the class [-] at (615, 546, 450) nm.
    class_broadband : array_like, optional
        Shape (...) or scalar: broadband albedo [-] of the class that corresponds to ``albedo_broadband``.
    units : str, optional
        Units of ``albedo_broadband`` (:func:`albedo_to_fraction`; None: > 1 means percent).

    Returns
    -------
    numpy.ndarray
        Shape (3, ...) [-] in [0, 1].

    Raises
    ------
    SwimInputError
        On albedos outside [0, 1] (after the percent conversion) or shapes that do not broadcast.
    """
    big_a = albedo_to_fraction(albedo_broadband, units, "albedo_broadband")
    shape = np.asarray(class_albedo, dtype=float)
    if shape.shape[:1] != (WAVELENGTHS_NM.size,):
        raise SwimInputError(f"class_albedo must have shape (3, ...) for {WAVELENGTHS_NM.tolist()} nm; got {shape.shape}")
    if shape.ndim == 1:
        shape = shape.reshape((WAVELENGTHS_NM.size,) + (1,) * big_a.ndim)
    ref = visible_mean(shape) if class_broadband is None else albedo_to_fraction(class_broadband, "1", "class_broadband")
    try:
        grid = np.broadcast_shapes(big_a.shape, shape.shape[1:], np.shape(ref))
    except ValueError as exc:
        raise SwimInputError(
            f"albedo_broadband {big_a.shape}, class_albedo {np.shape(class_albedo)} and class_broadband "
            f"{np.shape(ref)} do not broadcast"
        ) from exc
    big_a = np.broadcast_to(big_a, grid)
    ref = np.broadcast_to(ref, grid)
    shape = np.broadcast_to(shape, (WAVELENGTHS_NM.size,) + grid)
    ratio = np.divide(big_a, ref, out=np.zeros(grid), where=ref > 0)
    out = np.where(ref > 0, shape * ratio, big_a)
    clipped = (out < 0.0) | (out > 1.0)
    if clipped.any():
        logger.info("spectral_albedo_from_broadband: clipped %d value(s) to [0, 1]", int(clipped.sum()))
    return np.clip(out, 0.0, 1.0)


def blend_snow(albedo, snow_cover, snow_albedo=None, snow_broadband=None, snow_broadband_units=None) -> np.ndarray:
    """Albedo of a partly snow-covered surface: ``(1 - f) a + f a_snow``.

    Parameters
    ----------
    albedo : array_like
        Shape (3, ...): snow-free spectral albedo [-] at (615, 546, 450) nm.
    snow_cover : array_like
        Shape (...) or scalar: snow-covered area fraction f [0-1].
    snow_albedo : array_like, optional
        Shape (3,) or (3, ...): spectral albedo of the snow-covered surface [-]; default
        :data:`DEFAULT_SNOW_ALBEDO`.
    snow_broadband : array_like, optional
        Shape (...) or scalar: shortwave broadband albedo of the snow-covered surface (WRF/WPS ``SNOALB``, the
        maximum albedo of deep snow on that cell's vegetation), fraction or percent. When given, ``snow_albedo``
        is rescaled to it with :func:`spectral_albedo_from_broadband` (the snow keeps its spectral shape); the
        broadband reference is :data:`DEFAULT_SNOW_SHORTWAVE_ALBEDO` for the default spectrum, else the visible
        mean of ``snow_albedo``.
    snow_broadband_units : str, optional
        Units of ``snow_broadband`` (None: > 1 means percent).

    Returns
    -------
    numpy.ndarray
        Shape (3, ...) [-] in [0, 1]; equals ``albedo`` where f = 0 and the snow albedo where f = 1.

    Raises
    ------
    SwimInputError
        If ``snow_cover`` is outside [0, 1] (e.g. percent) or an albedo is outside [0, 1].
    """
    a = np.asarray(albedo, dtype=float)
    if a.shape[:1] != (WAVELENGTHS_NM.size,):
        raise SwimInputError(f"albedo must have shape (3, ...) for {WAVELENGTHS_NM.tolist()} nm; got {a.shape}")
    f = np.asarray(snow_cover, dtype=float)
    if not np.all(np.isfinite(f)):
        raise SwimInputError(f"snow_cover has {int(np.sum(~np.isfinite(f)))} non-finite value(s); expected a fraction in [0, 1]")
    if f.size and (f.min() < 0.0 or f.max() > 1.0):
        raise SwimInputError(f"snow_cover: range [{f.min():.4g}, {f.max():.4g}] is outside [0, 1] (a fraction, not percent)")
    snow = DEFAULT_SNOW_ALBEDO if snow_albedo is None else np.asarray(snow_albedo, dtype=float)
    if snow.shape[:1] != (WAVELENGTHS_NM.size,):
        raise SwimInputError(f"snow_albedo must have shape (3,) or (3, ...); got {snow.shape}")
    if snow.min() < 0.0 or snow.max() > 1.0:
        raise SwimInputError("snow_albedo must lie in [0, 1]")
    if snow.ndim == 1:
        snow = snow.reshape((WAVELENGTHS_NM.size,) + (1,) * (a.ndim - 1))
    if snow_broadband is not None:
        reference = DEFAULT_SNOW_SHORTWAVE_ALBEDO if snow_albedo is None else visible_mean(snow)
        snow = spectral_albedo_from_broadband(snow_broadband, snow, reference, units=snow_broadband_units)
    return np.clip((1.0 - f) * a + f * snow, 0.0, 1.0)


def snow_cover_from_swe(swe, threshold=NOAH_SNOW_DEPLETION_SWE_KG_M2, shape=NOAH_SNOW_DEPLETION_SHAPE) -> np.ndarray:
    """Snow-covered fraction from the snow water equivalent, with the Noah LSM depletion curve.

    ``f = 1 - (exp(-s r) - r exp(-s))`` with ``r = SWE / threshold`` for SWE < threshold, else 1 (Noah's
    ``SNFRAC``, Ek et al. 2003; ``s`` = ``SALP`` = 2.6, ``threshold`` = ``SNUP``).

    Parameters
    ----------
    swe : array_like
        Snow water equivalent [kg m-2] (= mm of water; WRF/WPS ``SNOW``), >= 0.
    threshold : float or array_like
        SWE of complete cover [kg m-2] (``SNUP`` x 1000; default 40).
    shape : float
        Shape parameter ``SALP`` [-].

    Returns
    -------
    numpy.ndarray
        Snow cover fraction [0-1], shape of ``swe``.

    Raises
    ------
    SwimInputError
        On negative or non-finite SWE.

    References
    ----------
    Ek, M. B., et al. (2003): Implementation of Noah land surface model advances in the NCEP operational
    mesoscale Eta model, J. Geophys. Res. 108, 8851, doi:10.1029/2002JD003296.
    """
    w = np.asarray(swe, dtype=float)
    if not np.all(np.isfinite(w)) or (w.size and w.min() < 0):
        raise SwimInputError("SNOW (snow water equivalent) must be finite and >= 0 [kg m-2]")
    r = w / np.asarray(threshold, dtype=float)
    f = 1.0 - (np.exp(-shape * r) - r * np.exp(-shape))
    return np.clip(np.where(r < 1.0, f, 1.0), 0.0, 1.0)


def effective_snow_cover(snow_cover, snow_free_albedo, snow_broadband, snow_albedo=None, snow_units=None) -> np.ndarray:
    """Fraction of the surface that appears as (bright) snow, given the albedo of the snow-covered surface.

    Models give the albedo of a fully snow-covered cell (WRF/WPS ``SNOALB``: deep snow partly hidden by the
    canopy, e.g. 0.4 for a conifer forest against 0.8 for grass). The renderer blends the snow-free albedo
    ``a`` with a fixed snow spectrum ``a_s`` over ``snow_cover``; the fraction that reproduces the model's
    snow-covered albedo is ``f_eff = f (s V(a_s) - V(a)) / (V(a_s) - V(a))`` clipped to [0, f], where
    ``s = SNOALB / A_s`` rescales the snow spectrum to the model's snow albedo (``A_s`` its shortwave albedo)
    and ``V`` is :func:`visible_mean`. So ``(1 - f_eff) a + f_eff a_s`` has the visible mean of
    :func:`blend_snow` ``(a, f, snow_broadband=SNOALB)``.

    Parameters
    ----------
    snow_cover : array_like
        Shape (...): snow-covered area fraction f [0-1].
    snow_free_albedo : array_like
        Shape (3, ...): snow-free spectral albedo a [-].
    snow_broadband : array_like
        Shape (...): shortwave albedo of the snow-covered surface (``SNOALB``), fraction or percent.
    snow_albedo : array_like, optional
        Shape (3,): the renderer's snow spectrum a_s [-]; default :data:`DEFAULT_SNOW_ALBEDO` (whose shortwave
        albedo is :data:`DEFAULT_SNOW_SHORTWAVE_ALBEDO`; for another spectrum its visible mean is used).
    snow_units : str, optional
        Units of ``snow_broadband``.

    Returns
    -------
    numpy.ndarray
        Shape (...): effective snow cover in [0, f].

    Raises
    ------
    SwimInputError
        On fractions or albedos outside [0, 1].
    """
    f = np.asarray(snow_cover, dtype=float)
    if f.size and (not np.all(np.isfinite(f)) or f.min() < 0.0 or f.max() > 1.0):
        raise SwimInputError("snow_cover must be finite and in [0, 1] (a fraction, not percent)")
    big_s = albedo_to_fraction(snow_broadband, snow_units, "snow albedo (SNOALB)")
    a_s = DEFAULT_SNOW_ALBEDO if snow_albedo is None else np.asarray(snow_albedo, dtype=float)
    a_s_sw = DEFAULT_SNOW_SHORTWAVE_ALBEDO if snow_albedo is None else float(visible_mean(a_s))
    v_s = float(visible_mean(a_s))
    v_a = visible_mean(snow_free_albedo)
    scale = big_s / a_s_sw
    denominator = v_s - v_a
    ratio = np.divide(scale * v_s - v_a, denominator, out=np.ones(np.broadcast(denominator, scale).shape),
                      where=denominator > 1e-6)
    return np.clip(f * np.clip(ratio, 0.0, 1.0), 0.0, f)


def surface_from_model_fields(albedo_broadband=None, *, lu_index=None, landusef=None, scheme=None,
                              snow_cover=None, snow_broadband=None, includes_snow: bool = False,
                              band: str = "shortwave", units=None, snow_units=None):
    """Snow-free spectral albedo and snow cover of a model grid (the readers' common path).

    The canonical scene holds the **snow-free** albedo in ``surface_albedo`` and the snow separately in
    ``snow_cover``; the renderer blends them (the snow has its own BRDF). Steps:

    * Class spectrum: area-weighted over ``landusef`` when given, else of the dominant class ``lu_index``;
      none without ``scheme``.
    * Snow-free broadband albedo ``A_0``: ``albedo_broadband`` when it excludes the snow (WRF ``ALBBCK``, WPS
      ``ALBEDO12M``); when it includes it (WRF ``ALBEDO``), ``A_0 = (A - f A_snow) / (1 - f)`` (Noah's
      ``A = (1 - f) A_0 + f A_snow``, ``A_snow`` = ``snow_broadband`` or :data:`DEFAULT_SNOW_SHORTWAVE_ALBEDO`),
      clipped to [0, 1]; where f > 0.99 the class's own shortwave albedo (the background is hidden anyway).
    * Spectral albedo: ``A_0`` with the class's spectral shape (:func:`spectral_albedo_from_broadband`; its
      reference is the class's shortwave albedo for ``band="shortwave"``, the visible mean for
      ``band="visible"``); without land use ``A_0`` at all three wavelengths; without a broadband albedo the
      class spectrum; None without either.
    * Snow cover: ``snow_cover``, reduced by :func:`effective_snow_cover` when ``snow_broadband`` (``SNOALB``)
      and an albedo are known; at least the area fraction of permanent snow/ice classes
      (:func:`snow_ice_fraction_from_landuse`), so that glaciers get the snow reflectance.

    Parameters
    ----------
    albedo_broadband : array_like, optional
        Shape (ny, nx): broadband albedo, fraction or percent (``units``).
    lu_index : array_like, optional
        Shape (ny, nx): dominant land-use class.
    landusef : array_like, optional
        Shape (ncat, ny, nx): land-use class fractions.
    scheme : str, optional
        ``MMINLU``; None: land use is not used.
    snow_cover : array_like, optional
        Shape (ny, nx): snow-covered fraction [0-1].
    snow_broadband : array_like, optional
        Shape (ny, nx): shortwave albedo of the snow-covered surface (``SNOALB``), fraction or percent
        (``snow_units``).
    includes_snow : bool
        Whether ``albedo_broadband`` includes the snow.
    band : {"shortwave", "visible"}
        What ``albedo_broadband`` is the broadband mean over.
    units, snow_units : str, optional
        Units of ``albedo_broadband`` and ``snow_broadband`` (:func:`albedo_to_fraction`).

    Returns
    -------
    albedo : numpy.ndarray or None
        Shape (3, ny, nx): snow-free albedo [-] at (615, 546, 450) nm, in [0, 1].
    snow_cover : numpy.ndarray or None
        Shape (ny, nx): the fraction to render as snow [0-1]; None when ``snow_cover`` is None and there is no
        snow/ice class.

    Raises
    ------
    SwimInputError
        On an unknown ``band``, bad class numbers or fractions, or albedos/fractions out of range.
    """
    if band not in ("shortwave", "visible"):
        raise SwimInputError(f"albedo_band={band!r}: expected 'shortwave' (WRF/WPS albedos) or 'visible'")
    cls = cls_sw = None
    if scheme is not None and landusef is not None:
        cls = spectral_albedo_from_landuse_fractions(landusef, scheme)
        cls_sw = shortwave_albedo_from_landuse_fractions(landusef, scheme)
    elif scheme is not None and lu_index is not None:
        cls = spectral_albedo_from_landuse(lu_index, scheme)
        cls_sw = shortwave_albedo_from_landuse(lu_index, scheme)
    f = None
    if snow_cover is not None:
        f = np.asarray(snow_cover, dtype=float)
        if not np.all(np.isfinite(f)) or (f.size and (f.min() < 0.0 or f.max() > 1.0)):
            raise SwimInputError("snow cover must be finite and in [0, 1] (a fraction, not percent)")
    snow_sw = None
    if snow_broadband is not None:
        snow_sw = albedo_to_fraction(snow_broadband, snow_units, "snow albedo (SNOALB)")

    albedo = None
    if albedo_broadband is not None:
        big_a = albedo_to_fraction(albedo_broadband, units, "albedo")
        if includes_snow and f is not None and np.any(f > 0):
            a_snow = DEFAULT_SNOW_SHORTWAVE_ALBEDO if snow_sw is None else snow_sw
            covered = f > 0.99
            background = np.divide(big_a - f * a_snow, 1.0 - f, out=np.array(big_a, dtype=float), where=~covered)
            hidden = cls_sw if cls_sw is not None else big_a
            big_a = np.clip(np.where(covered, hidden, background), 0.0, 1.0)
        if cls is None:
            albedo = np.broadcast_to(big_a, (WAVELENGTHS_NM.size,) + np.shape(big_a)).copy()
        else:
            albedo = spectral_albedo_from_broadband(big_a, cls, cls_sw if band == "shortwave" else None)
    elif cls is not None:
        albedo = cls
    if f is not None and snow_sw is not None and albedo is not None:
        f = effective_snow_cover(f, albedo, snow_sw)
    if scheme is not None and (lu_index is not None or landusef is not None):
        ice = snow_ice_fraction_from_landuse(scheme, lu_index=lu_index, landusef=landusef)
        if np.any(ice > 0):
            f = ice if f is None else np.maximum(f, ice)
    return albedo, f


# ---------------------------------------------------------------------------------------------------------------
# RGB images (Blue Marble)


def srgb_to_linear(values) -> np.ndarray:
    """Decode sRGB-encoded values to linear light: the sRGB EOTF of IEC 61966-2-1:1999.

    ``v / 12.92`` for ``v <= 0.04045``, else ``((v + 0.055) / 1.055) ** 2.4``.

    Parameters
    ----------
    values : array_like
        Encoded values in [0, 1] (divide 8-bit values by 255 first).

    Returns
    -------
    numpy.ndarray
        Linear values in [0, 1], same shape.
    """
    v = np.clip(np.asarray(values, dtype=float), 0.0, 1.0)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def _image_unit_range(image) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim < 1 or img.shape[-1] not in (3, 4):
        raise SwimInputError(f"image must have shape (..., 3) (R, G, B) or (..., 4) (RGBA); got {img.shape}")
    img = img[..., :3]
    if img.dtype == np.uint8:
        return img.astype(float) / 255.0
    if img.dtype == np.uint16:
        return img.astype(float) / 65535.0
    v = img.astype(float)
    if not np.all(np.isfinite(v)):
        raise SwimInputError("image has non-finite values")
    if v.size and (v.min() < 0.0 or v.max() > 1.0):
        raise SwimInputError(
            f"image: float values in [{v.min():.4g}, {v.max():.4g}]; expected [0, 1] (or uint8 0-255, uint16 0-65535)"
        )
    return v


def spectral_albedo_from_rgb(image, scale=1.0, encoding: str = "srgb") -> np.ndarray:
    """Spectral albedo at (615, 546, 450) nm from an RGB image (the paper's Blue Marble -> MODIS idea).

    1. decode the channels to linear values ``L`` (the sRGB EOTF, :func:`srgb_to_linear`, or none);
    2. take R, G, B as reflectances of MODIS bands 1 (645 nm), 4 (555 nm) and 3 (469 nm):
       ``rho_b = scale_b L_b`` (:data:`MODIS_RGB_BANDS_NM`);
    3. interpolate linearly in wavelength: 615 nm between 555 and 645 nm (``G + (2/3)(R - G)``), 546 nm
       between 469 and 555 nm, 450 nm extrapolated from the 469-555 nm slope; clip to [0, 1].

    The Blue Marble Next Generation is made of MODIS surface reflectances in bands 1, 4, 3 (Stockli et al.
    2005) but stretched for display, so the linear ``scale`` is an assumption: the default 1 maps white to a
    perfect reflector; calibrate it (per channel if needed) against MODIS white-sky albedos (MCD43) of the
    region. For grey pixels (R = G = B) all three albedos equal ``scale L``.

    Parameters
    ----------
    image : array_like
        Shape (..., 3) (or (..., 4); alpha ignored): uint8 (0-255), uint16 (0-65535) or float in [0, 1].
    scale : float or array_like of 3
        Reflectance of a full-scale channel [-], one value or (R, G, B).
    encoding : {"srgb", "linear"}
        Transfer function of the image values.

    Returns
    -------
    numpy.ndarray
        Shape (3, ...) [-] at (615, 546, 450) nm, in [0, 1].

    Raises
    ------
    SwimInputError
        On a bad image shape or range, an unknown encoding, or a scale outside (0, 1.5].

    References
    ----------
    Stockli, R., Vermote, E., Saleous, N., Simmon, R., Herring, D. (2005): The Blue Marble Next Generation - a
    true color Earth dataset including seasonal dynamics from MODIS, NASA Earth Observatory.
    """
    v = _image_unit_range(image)
    if encoding == "srgb":
        lin = srgb_to_linear(v)
    elif encoding == "linear":
        lin = v
    else:
        raise SwimInputError(f"encoding={encoding!r}: expected 'srgb' or 'linear'")
    s = np.broadcast_to(np.asarray(scale, dtype=float), (3,))
    if not np.all((s > 0) & (s <= 1.5)):
        raise SwimInputError(f"scale={scale!r}: expected a reflectance of a full-scale channel in (0, 1.5]")
    rho = lin * s  # (..., 3): bands at 645, 555, 469 nm
    r, g, b = rho[..., 0], rho[..., 1], rho[..., 2]
    l_r, l_g, l_b = MODIS_RGB_BANDS_NM
    out = np.stack(
        [
            g + (WAVELENGTHS_NM[0] - l_g) / (l_r - l_g) * (r - g),
            b + (WAVELENGTHS_NM[1] - l_b) / (l_g - l_b) * (g - b),
            b + (WAVELENGTHS_NM[2] - l_b) / (l_g - l_b) * (g - b),
        ],
        axis=0,
    )
    return np.clip(out, 0.0, 1.0)


def load_image(path, max_pixels: int | None = 400_000_000) -> np.ndarray:
    """Read an RGB image file with Pillow.

    Parameters
    ----------
    path : str or os.PathLike
        Image file (PNG, JPEG, TIFF, ...).
    max_pixels : int or None
        Largest image accepted (Pillow's decompression-bomb limit for this call); None: no limit. The
        default admits the 21600 x 10800 Blue Marble.

    Returns
    -------
    numpy.ndarray
        Shape (rows, cols, 3), uint8 (16-bit images are reduced to 8 bit by Pillow's RGB conversion).

    Raises
    ------
    SwimInputError
        If the file is missing or cannot be read as an image.
    """
    from PIL import Image

    p = Path(path)
    if not p.is_file():
        raise SwimInputError(f"image file not found: {p}")
    old = Image.MAX_IMAGE_PIXELS
    Image.MAX_IMAGE_PIXELS = max_pixels
    try:
        with Image.open(p) as im:
            return np.asarray(im.convert("RGB"))
    except Exception as exc:  # noqa: BLE001 - any Pillow failure means "not a readable image"
        raise SwimInputError(f"image file {p.name} cannot be read: {exc}") from exc
    finally:
        Image.MAX_IMAGE_PIXELS = old


def regrid_image_to_scene(image, lat, lon, bounds=(-180.0, 180.0, -90.0, 90.0), geotransform=None,
                          method: str = "bilinear") -> np.ndarray:
    """Sample an equirectangular (lat/lon) image at the scene's columns.

    Row 0 of the image is its northern edge and column 0 its western edge; pixels are areas, their centres
    half a pixel inside the edges. A global image (360 deg wide) wraps around in longitude.

    Parameters
    ----------
    image : array_like
        Shape (rows, cols) or (rows, cols, channels).
    lat, lon : array_like
        Shape (...): latitudes and longitudes [deg] of the scene columns.
    bounds : tuple of 4 float
        ``(lon_west, lon_east, lat_south, lat_north)`` [deg] of the image edges; default the whole globe
        (-180..180, -90..90), e.g. the NASA Blue Marble.
    geotransform : tuple of 6 float, optional
        GDAL geotransform ``(lon_west, dlon, 0, lat_north, 0, dlat)`` [deg] (``dlat`` < 0); replaces
        ``bounds``.
    method : {"bilinear", "nearest"}
        Sampling.

    Returns
    -------
    numpy.ndarray
        Shape (..., channels) (or (...) for a 2-D image), float64.

    Raises
    ------
    SwimInputError
        On bad bounds or geotransform (rotation terms must be 0), an unknown method, or scene columns outside
        a non-global image (by more than half a pixel).
    """
    img = np.asarray(image)
    if img.ndim not in (2, 3) or img.shape[0] < 1 or img.shape[1] < 1:
        raise SwimInputError(f"image must have shape (rows, cols) or (rows, cols, channels); got {img.shape}")
    rows, cols = img.shape[:2]
    if geotransform is not None:
        gt = [float(g) for g in geotransform]
        if len(gt) != 6 or gt[2] != 0.0 or gt[4] != 0.0 or gt[1] <= 0 or gt[5] >= 0:
            raise SwimInputError(
                f"geotransform={geotransform!r}: expected (lon_west, dlon > 0, 0, lat_north, 0, dlat < 0) [deg]"
            )
        west, north = gt[0], gt[3]
        east, south = west + cols * gt[1], north + rows * gt[5]
    else:
        try:
            west, east, south, north = (float(b) for b in bounds)
        except (TypeError, ValueError) as exc:
            raise SwimInputError(f"bounds={bounds!r}: expected (lon_west, lon_east, lat_south, lat_north) [deg]") from exc
    if not (east > west and north > south and east - west <= 360.0 + 1e-9 and -90.0 <= south and north <= 90.0):
        raise SwimInputError(
            f"image bounds lon {west}..{east}, lat {south}..{north}: expected west < east (at most 360 deg apart) and "
            "-90 <= south < north <= 90"
        )
    if method not in ("bilinear", "nearest"):
        raise SwimInputError(f"method={method!r}: expected 'bilinear' or 'nearest'")
    la = np.asarray(lat, dtype=float)
    lo = np.asarray(lon, dtype=float)
    if la.shape != lo.shape:
        raise SwimInputError(f"lat {la.shape} and lon {lo.shape} must have the same shape")
    dlon = (east - west) / cols
    dlat = (north - south) / rows
    periodic = abs((east - west) - 360.0) < 1e-6
    lo = west + np.mod(lo - west, 360.0)  # into [west, west + 360)
    fx = (lo - west) / dlon - 0.5  # fractional column of the pixel centres
    fy = (north - la) / dlat - 0.5
    if not periodic:
        outside = (fx < -1.0) | (fx > cols) | (fy < -1.0) | (fy > rows)
        if np.any(outside):
            raise SwimInputError(
                f"{int(outside.sum())} scene column(s) lie outside the image (lon {west}..{east}, lat {south}..{north})"
            )
    if np.any((fy < -1.0) | (fy > rows)):
        raise SwimInputError(f"scene latitudes outside the image's {south}..{north} deg")
    values = img.astype(float)
    if method == "nearest":
        i = np.clip(np.floor(fy + 0.5).astype(int), 0, rows - 1)
        j = np.floor(fx + 0.5).astype(int)
        j = np.mod(j, cols) if periodic else np.clip(j, 0, cols - 1)
        return values[i, j]
    fy = np.clip(fy, 0.0, rows - 1.0)
    i0 = np.clip(np.floor(fy).astype(int), 0, max(rows - 2, 0))
    i1 = np.minimum(i0 + 1, rows - 1)
    wy = fy - i0
    if periodic:
        j0 = np.floor(fx).astype(int)
        wx = fx - j0
        j0, j1 = np.mod(j0, cols), np.mod(j0 + 1, cols)
    else:
        fx = np.clip(fx, 0.0, cols - 1.0)
        j0 = np.clip(np.floor(fx).astype(int), 0, max(cols - 2, 0))
        j1 = np.minimum(j0 + 1, cols - 1)
        wx = fx - j0
    if values.ndim == 3:
        wx, wy = wx[..., None], wy[..., None]
    top = (1.0 - wx) * values[i0, j0] + wx * values[i0, j1]
    bottom = (1.0 - wx) * values[i1, j0] + wx * values[i1, j1]
    return (1.0 - wy) * top + wy * bottom


def spectral_albedo_from_image(image, lat, lon, bounds=(-180.0, 180.0, -90.0, 90.0), geotransform=None,
                               method: str = "bilinear", scale=1.0, encoding: str = "srgb") -> np.ndarray:
    """Spectral albedo of the scene columns from an equirectangular RGB image (e.g. the Blue Marble).

    :func:`regrid_image_to_scene` (on the encoded values, in [0, 1]) followed by
    :func:`spectral_albedo_from_rgb`.

    Parameters
    ----------
    image : array_like or str or os.PathLike
        Shape (rows, cols, 3) array, or an image file (:func:`load_image`).
    lat, lon : array_like
        Shape (ny, nx) (or any shape (...)): scene column latitudes/longitudes [deg].
    bounds, geotransform, method
        See :func:`regrid_image_to_scene`.
    scale, encoding
        See :func:`spectral_albedo_from_rgb`.

    Returns
    -------
    numpy.ndarray
        Shape (3, ...) [-] at (615, 546, 450) nm; assign as ``scene["surface_albedo"]`` with dims
        ``("wavelength", "y", "x")``.

    Raises
    ------
    SwimInputError
        See the two functions.
    """
    if isinstance(image, (str, Path)):
        image = load_image(image)
    unit = _image_unit_range(image)
    sampled = regrid_image_to_scene(unit, lat, lon, bounds=bounds, geotransform=geotransform, method=method)
    return spectral_albedo_from_rgb(np.clip(sampled, 0.0, 1.0), scale=scale, encoding=encoding)


def scene_with_albedo_from_image(scene, image, bounds=(-180.0, 180.0, -90.0, 90.0), scale=1.0,
                                 method: str = "bilinear"):
    """A copy of a canonical scene whose ``surface_albedo`` comes from an equirectangular RGB image.

    The paper's Blue Marble route (Sect. 3.7; docs/surfaces.md §3): the image is sampled at the scene's column
    latitudes/longitudes and converted with :func:`spectral_albedo_from_rgb`. Over water the renderer uses its
    own water model, so only the land albedo matters.

    Parameters
    ----------
    scene : xarray.Dataset
        Canonical scene with ``lat``, ``lon`` (y, x) [deg].
    image : array_like or str or os.PathLike
        RGB image (rows, cols, 3) or a file (:func:`load_image`), north up.
    bounds : tuple of float
        (west, east, south, north) [deg] covered by the image (default: the whole globe).
    scale : float
        Albedo of a white (255) pixel [-] (:func:`spectral_albedo_from_rgb`).
    method : {"bilinear", "nearest"}
        Sampling (:func:`regrid_image_to_scene`).

    Returns
    -------
    xarray.Dataset
        A copy of the scene with ``surface_albedo`` (wavelength, y, x) [-] replaced, clipped to [0, 1] (the render
        validates the scene as a whole).

    Raises
    ------
    SwimInputError
        A missing or unreadable image, or scene points outside ``bounds``.
    """
    try:
        albedo = spectral_albedo_from_image(image, scene["lat"].values, scene["lon"].values, bounds=tuple(bounds),
                                            method=method, scale=scale)
    except SwimInputError as exc:
        raise SwimInputError(f"surface albedo from an RGB image: {exc}") from None
    out = scene.drop_vars("surface_albedo", errors="ignore").copy()
    out["surface_albedo"] = (("wavelength", "y", "x"), np.clip(albedo, 0.0, 1.0),
                             {"units": "1", "long_name": "surface spectral albedo", "source": "RGB image"})
    return out.assign_coords(wavelength=("wavelength", np.asarray(WAVELENGTHS_NM, dtype=float), {"units": "nm"}))
