"""Make the colorimetric tables shipped in ``src/swim/data/colour_tables.npz`` from colour-science.

The colour stage (:mod:`swim.color`) needs the CIE 1931 2-degree colour matching functions, the sRGB colourspace's
XYZ-to-RGB matrix and D65 white, and the cone-response matrices of the chromatic adaptation transforms. They are
taken from colour-science (``colour.MSDS_CMFS``, ``colour.RGB_COLOURSPACES["sRGB"]``,
``colour.CHROMATIC_ADAPTATION_TRANSFORMS``) once, here, so that swim does not need colour-science at run time;
``tests/unit/color/test_color.py`` holds the shipped tables to colour-science's.

    python scripts/make_colour_tables.py
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parents[1] / "src" / "swim" / "data" / "colour_tables.npz"
CMFS_NAME = "CIE 1931 2 Degree Standard Observer"


def main():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import colour

    cmfs = colour.MSDS_CMFS[CMFS_NAME]
    srgb = colour.RGB_COLOURSPACES["sRGB"]
    names = sorted(colour.CHROMATIC_ADAPTATION_TRANSFORMS)
    np.savez_compressed(
        OUT, cmfs_wavelength_nm=np.array(cmfs.wavelengths, dtype=float), cmfs=np.array(cmfs.values, dtype=float),
        srgb_XYZ_to_RGB=np.array(srgb.matrix_XYZ_to_RGB, dtype=float),
        srgb_whitepoint_XYZ=np.array(colour.xy_to_XYZ(srgb.whitepoint), dtype=float),
        cat_names=np.array(names), cat_matrices=np.array([colour.CHROMATIC_ADAPTATION_TRANSFORMS[n] for n in names],
                                                         dtype=float),
        colour_science_version=np.array(colour.__version__))
    print(f"wrote {OUT} (colour-science {colour.__version__}, {len(names)} adaptation transforms)")


if __name__ == "__main__":
    main()
