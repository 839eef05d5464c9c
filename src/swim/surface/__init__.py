"""swim.surface: the ground (paper Sect. 3.7, Eq. 35).

* :mod:`~swim.surface.landuse` and :mod:`~swim.surface.albedo`: spectral albedo at 615/546/450 nm from WRF/WPS
  land-use classes, model broadband albedos, snow and user RGB images (docs/surfaces.md);
* :mod:`~swim.surface.brdf` and :mod:`~swim.surface.water`: reflectance factors of land (RPV, hot spot),
  snow (forward peak) and water (Fresnel, Cox-Munk sun glint, water-leaving light) (docs/surface-reflectance.md);
* :mod:`~swim.surface.lighting`: the radiance leaving a tilted terrain facet, as the ray march uses it.
"""

from .albedo import (
    blend_snow,
    scene_with_albedo_from_image,
    spectral_albedo_from_broadband,
    spectral_albedo_from_image,
    spectral_albedo_from_landuse,
    spectral_albedo_from_landuse_fractions,
    spectral_albedo_from_rgb,
)
from .brdf import (
    reflectance_factor_lambertian,
    reflectance_factor_rpv1993,
    reflectance_factor_snow_kokhanovsky2004,
    surface_diffuse_albedo,
    surface_reflectance_factor,
)
from .landuse import landuse_classes, landuse_scheme
from .lighting import SURFACE_MODELS, surface_radiance
from .water import (
    fresnel_reflectance,
    slope_variance_cox_munk1954,
    specular_direction,
    sun_glint_reflectance_factor_cox_munk1954,
    water_diffuse_albedo,
)

__all__ = [
    "SURFACE_MODELS",
    "blend_snow",
    "fresnel_reflectance",
    "landuse_classes",
    "landuse_scheme",
    "reflectance_factor_lambertian",
    "reflectance_factor_rpv1993",
    "reflectance_factor_snow_kokhanovsky2004",
    "scene_with_albedo_from_image",
    "slope_variance_cox_munk1954",
    "specular_direction",
    "spectral_albedo_from_broadband",
    "spectral_albedo_from_image",
    "spectral_albedo_from_landuse",
    "spectral_albedo_from_landuse_fractions",
    "spectral_albedo_from_rgb",
    "sun_glint_reflectance_factor_cox_munk1954",
    "surface_diffuse_albedo",
    "surface_radiance",
    "surface_reflectance_factor",
    "water_diffuse_albedo",
]
