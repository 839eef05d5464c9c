"""Regenerate the golden images of the regression tests (tests/regression/test_golden_images.py).

Small renders of the built-in scene on the CPU's numba kernel, one per view in :data:`VIEWS`, stored as their
546 nm radiance (float32) and sRGB bytes in ``tests/data/golden/<view>.npz``. The golden images guard behaviour:
a change that moves them was either meant (regenerate them with this script and say why in the commit) or is a
regression. They are not a physics test; the physics is held to DISORT, Mitsuba and analytic limits elsewhere.

Usage::

    python scripts/make_golden_images.py [--views NAME ...]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
GOLDEN_DIR = ROOT / "tests" / "data" / "golden"
sys.path.insert(0, str(ROOT / "tests" / "regression"))

from golden_views import VIEWS, render_view  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", nargs="*", default=None, help=f"views to regenerate (default: all of {list(VIEWS)})")
    args = ap.parse_args(argv)
    GOLDEN_DIR.mkdir(parents=True, exist_ok=True)
    for name in args.views or VIEWS:
        image = render_view(name)
        path = GOLDEN_DIR / f"{name}.npz"
        np.savez_compressed(path, radiance_546=image["radiance"].sel(wavelength=546).values.astype(np.float32),
                            rgb=image["rgb"].values.astype(np.uint8))
        print(f"wrote {path.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
