#!/usr/bin/env python
"""Run the Mitsuba 3 Monte Carlo references and cache them under tests/data/validation/.

* ``rico_<view>_sza<zz>.npz``: the RICO LES cumulus (``../shared/data/les/rico122x106x39.txt``) seen from the
  ground (41 x 41 all-sky image, view zenith <= 75°) and from space (32 x 28 perspective image from 700 km
  looking straight down, the field of view spanning the domain), sun zenith 30° and 60°, azimuth 135°, Rayleigh atmosphere (no aerosol), sea albedo
  (swim.render defaults otherwise), with the inputs recorded (:func:`swim.validation.mitsuba.make_rico_reference`).
* ``rayleigh_sza30.npz``: the adapter against DISORT on a Rayleigh sky (16 view directions).
* with ``--clouds3d``: ``clouds3d/<field>_<view>_sza<zz>.npz``, the 3-D cloud scattering's references
  (:mod:`swim.validation.clouds3d`: RICO and stratocumulus; all-sky, nadir and 45° views;
  Henyey-Greenstein g 0.85 in both codes; 8 x 8-pixel block means of 96 x 96 images), and docs/validation/clouds3d_*.png.

It also writes the comparison images docs/validation/<case>.png (swim | Mitsuba | relative difference) and
prints the table rows (:func:`swim.validation.mitsuba.rico_table_rows`).

Usage::

    pip install -e '.[validation]'
    python scripts/make_mitsuba_reference.py [--cases rico_ground_sza30 ...] [--spp N] [--skip-rayleigh]
    python scripts/make_mitsuba_reference.py --clouds3d [--cases rico_ground_sza30 ...] [--spp N]

Runtime (2 CPU cores, ``llvm_ad_rgb`` with LLVM 19): about 2-4 minutes per RICO case; ``scalar_rgb``
(no LLVM >= 17 found) is several times slower.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
LES_DIR = (ROOT / ".." / "shared" / "data" / "les").resolve()
OUT_DIR = ROOT / "tests" / "data" / "validation"
DOC_DIR = ROOT / "docs" / "validation"


def rayleigh_check(spp=100_000, sun_zenith=30.0, sun_azimuth=135.0):
    """Mitsuba against DISORT on a Rayleigh sky (ground observer); cached as rayleigh_sza30.npz."""
    from swim.rt.gas import AerosolBackground
    from swim.validation.disort import disort_clear_sky_radiance
    from swim.validation.mitsuba import directions_from_angles, mitsuba_radiance

    rayleigh = AerosolBackground(aod_550=0.0)
    vz = np.array([0.0, 20, 20, 40, 40, 40, 60, 60, 60, 60, 70, 70, 70, 45, 10, 30])
    va = np.array([0.0, 135, 315, 135, 45, 225, 135, 315, 45, 225, 135, 315, 0, 90, 200, 180])
    out = mitsuba_radiance(None, sun_zenith, sun_azimuth, [0.0, 0.0, 2.0], directions_from_angles(vz, va), spp=spp,
                           aerosol=rayleigh, surface_albedo=0.06, seed=3)
    ref = disort_clear_sky_radiance(sun_zenith, vz, va - sun_azimuth, aerosol=rayleigh, surface_albedo=0.06,
                                    observer="ground", n_streams=32)
    path = OUT_DIR / f"rayleigh_sza{sun_zenith:.0f}.npz"
    np.savez_compressed(path, view_zenith=vz, view_azimuth=va, sun_zenith=sun_zenith, sun_azimuth=sun_azimuth,
                        mitsuba=out["radiance"], stderr=out["stderr"], disort=ref, spp=spp, variant=out["variant"],
                        seconds=out["seconds"], surface_albedo=0.06)
    rel = out["radiance"] / ref - 1
    print(f"Rayleigh sky, sun zenith {sun_zenith:.0f}: {spp} paths per view, {out['seconds']:.0f} s ({out['variant']})")
    print("  Mitsuba/DISORT - 1 per channel: mean %s, max |.| %s, median rel. std. error %s" % (
        np.round(rel.mean(0), 4), np.round(np.abs(rel).max(0), 4), np.round(np.median(out["stderr"] / ref, 0), 4)))
    return path


def clouds3d(cases, spp, only_images):
    """The 3-D cloud scattering's references and their comparison images."""
    from swim.validation import clouds3d as C
    from swim.validation.mitsuba import comparison_png

    shared = LES_DIR.parent
    cases = cases or list(C.CASES)
    if not only_images:
        for case in cases:
            C.make_case_reference(case, shared, spp=spp)
    rows, images = C.case_rows(cases, shared)
    print("| case | λ [nm] | blocks | r | mean abs. error | bias | MC std. error |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['case']} | {r['wavelength_nm']:.0f} | {r['n_blocks']} | {r['pearson_r']:.3f} | "
              f"{r['mean_abs_error']:.3f} | {r['bias']:+.3f} | {r['mc_stderr']:.3f} |")
    for case, (ours, mask, ref546) in images.items():
        sel = [r for r in rows if r["case"] == case]
        title = (f"{case}: 8x8 blocks r = " + ", ".join(f"{x['pearson_r']:.2f}" for x in sel) + ", mean |err| = "
                 + ", ".join(f"{x['mean_abs_error']:.0%}" for x in sel))
        ref = np.repeat(ref546[None], 3, axis=0)
        white = 1.5 if C.CASES[case]["view"] == "ground" else 2.0
        grey = np.repeat(ours[1:2], 3, axis=0)  # the reference keeps 546 nm only: both shown grey
        comparison_png(grey, np.where(mask[None], ref, np.nan), DOC_DIR / f"clouds3d_{case}.png", title=title,
                       white_level=white)


def main():
    from swim.validation import mitsuba as M

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="*", default=None)
    parser.add_argument("--clouds3d", action="store_true", help="the 3-D cloud scattering's references")
    parser.add_argument("--spp", type=int, default=None, help="paths per pixel (default: swim.validation.mitsuba.RICO_SPP)")
    parser.add_argument("--skip-rayleigh", action="store_true")
    parser.add_argument("--only-images", action="store_true", help="no Mitsuba runs: table and images from the cache")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    for name in ("jax", "absl", "swim.rt", "swim.optics", "swim.pipeline", "swim.io"):
        logging.getLogger(name).setLevel(logging.WARNING)
    OUT_DIR.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    if args.clouds3d:
        clouds3d(args.cases, args.spp, args.only_images)
        print(f"done in {time.perf_counter() - t0:.0f} s")
        return
    args.cases = args.cases or list(M.RICO_CASES)
    if not args.only_images:
        if not args.skip_rayleigh:
            rayleigh_check()
        for case in args.cases:
            M.make_rico_reference(case, LES_DIR, spp=args.spp, out_dir=OUT_DIR)
    rows = M.rico_table_rows(LES_DIR, OUT_DIR, cases=args.cases)
    print("| case | view | sun zenith | λ [nm] | pixels | median abs. rel. error | p90 | mean | bias | r | MC noise | spp "
          "| cloudy pixels | cloudy: mean | cloudy: bias | cloudy: r |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['case']} | {r['view']} | {r['sun_zenith']:.0f} | {r['wavelength_nm']:.0f} | {r['n_pixels']} | "
              f"{r['median_abs_rel']:.3f} | {r['p90_abs_rel']:.3f} | {r['mean_abs_rel']:.3f} | {r['bias']:+.3f} | "
              f"{r['pearson_r']:.3f} | {r['mc_noise']:.3f} | {r['spp']} | {r['n_cloudy']} | "
              f"{r['cloudy_mean_abs_rel']:.3f} | {r['cloudy_bias']:+.3f} | {r['cloudy_pearson_r']:.3f} |")
    for case in args.cases:
        sel = [r for r in rows if r["case"] == case]
        if not sel:
            continue
        r = sel[1]
        r_text = ", ".join(f"{x['pearson_r']:.2f}" for x in sel)
        e_text = ", ".join(f"{x['mean_abs_rel']:.0%}" for x in sel)
        title = f"{case}: r = {r_text}, mean |rel. err.| = {e_text} (615/546/450 nm)"
        white = 1.5 if r["view"] == "ground" else 2.0
        M.comparison_png(r["swim"], r["mitsuba"], DOC_DIR / f"{case}.png", title=title, white_level=white)
    print(f"done in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
