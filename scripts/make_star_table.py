#!/usr/bin/env python
"""Write the packaged star table swim/data/bsc5_stars.npz from the Yale Bright Star Catalogue, 5th revised
edition (Hoffleit & Warren 1991, NASA/ADC; public domain): HR number, J2000 RA and Dec [deg], V and B-V [mag] of the
9096 stars with a position and V.

Usage::

    python scripts/make_star_table.py ../shared/data/stars/bsc5.dat
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from swim.geometry.stars import read_bsc5

OUT = Path(__file__).resolve().parents[1] / "src" / "swim" / "data" / "bsc5_stars.npz"


def main(path: str) -> None:
    stars = read_bsc5(path)
    np.savez_compressed(OUT, hr=stars.hr.astype(np.int16), ra_deg=stars.ra_deg.astype(np.float64),
                        dec_deg=stars.dec_deg.astype(np.float64), v_mag=stars.v_mag.astype(np.float32),
                        b_minus_v=stars.b_minus_v.astype(np.float32),
                        source=np.array("Yale Bright Star Catalogue, 5th revised ed. (Hoffleit & Warren 1991, "
                                        "NASA/ADC V/50), public domain"))
    print(f"wrote {OUT} ({len(stars)} stars, {OUT.stat().st_size} bytes)")


if __name__ == "__main__":
    main(sys.argv[1])
