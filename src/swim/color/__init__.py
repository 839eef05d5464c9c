"""swim.color: translation of solar-relative radiance into a displayable colour image (paper, Sect. 3.8).

Chain: three solar-relative radiances ``L'`` (615, 546, 450 nm) -> quadratic spectrum x solar spectrum
(:func:`solar_relative_to_spectrum`) -> CIE 1931 XYZ (:func:`solar_relative_to_XYZ`) -> linear sRGB
with the sun as white, an exposure ``white_level`` and a tone curve whose highlights roll off to white
(:func:`XYZ_to_display_rgb`) -> 8-bit sRGB
(:func:`encode_srgb8`); all at once: :func:`solar_relative_to_srgb8`. See docs/colour.md.
"""

from swim.color._tables import (
    SPECTRAL_GRID_NM,
    SPECTRAL_STEP_NM,
    astm_g173_extraterrestrial,
    cie_1931_cmfs,
    cie_1931_cmfs_on_grid,
    solar_irradiance_on_grid,
)
from swim.color.display import (
    AUTO_EXPOSURE_KEY,
    CHROMATIC_ADAPTATION_TRANSFORM,
    DEFAULT_WHITE_LEVEL,
    FILMIC_KNEE,
    SPACE_WHITE_LEVEL,
    GAMUT_MAPPINGS,
    PAPER_EQ36_MATRIX,
    XYZ_to_display_rgb,
    auto_white_level,
    display_matrix,
    encode_srgb8,
    exposure_white_level,
    filmic_tone,
    oetf_srgb,
    solar_relative_to_srgb8,
    sun_white_XYZ,
)
from swim.color.rayleigh import RAYLEIGH_METHODS, rayleigh_sky_chromaticity
from swim.color.spectrum import interpolation_matrix, solar_relative_to_spectrum, solar_relative_to_XYZ

__all__ = [
    "SPECTRAL_GRID_NM",
    "SPECTRAL_STEP_NM",
    "astm_g173_extraterrestrial",
    "cie_1931_cmfs",
    "cie_1931_cmfs_on_grid",
    "solar_irradiance_on_grid",
    "AUTO_EXPOSURE_KEY",
    "CHROMATIC_ADAPTATION_TRANSFORM",
    "DEFAULT_WHITE_LEVEL",
    "FILMIC_KNEE",
    "SPACE_WHITE_LEVEL",
    "GAMUT_MAPPINGS",
    "PAPER_EQ36_MATRIX",
    "XYZ_to_display_rgb",
    "auto_white_level",
    "display_matrix",
    "encode_srgb8",
    "exposure_white_level",
    "filmic_tone",
    "oetf_srgb",
    "solar_relative_to_srgb8",
    "sun_white_XYZ",
    "RAYLEIGH_METHODS",
    "rayleigh_sky_chromaticity",
    "interpolation_matrix",
    "solar_relative_to_spectrum",
    "solar_relative_to_XYZ",
]
