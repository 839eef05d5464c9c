"""The 3-D cloud scattering's costs (``cloud_scattering="discrete_ordinates"``).

* the diffuse solution of a new scene and sun on the synthetic 400 x 400 x 60 grid (its cells, sweeps and the median
  seconds of ``--repeats`` solves),
  for the default settings and a trade-off grid of ``max_cells`` x ``max_cell_tau``, each with its accuracy on two
  references: the RICO all-sky view against Mitsuba (8 x 8 block means, swim.validation.clouds3d) and a tau 20
  deck at sun zenith 60 deg against DISORT (GHI, zenith radiance);
* a warm adaptive 1024^2 all-sky render of the synthetic scene with ``"albers2020"`` and ``"discrete_ordinates"``,
  taking turns (the suite's ``synthetic_allsky_adaptive`` view).

Usage::

    python benchmarks/bench_clouds3d.py [--quick] [--no-tradeoff] [--repeats 3]

Writes ``benchmarks/results/clouds3d-latest.json`` and prints Markdown tables.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
ROOT = HERE.parent
SHARED = ROOT.parent / "shared" / "data"


def solve_case(volume, gas, sun, settings):
    from swim.optics.cloud_phase import cloud_optics
    from swim.rt.clouds import mean_effective_radii
    from swim.rt.diffuse_field import diffuse_field
    from swim.rt.march_inputs import packed_species

    optics = cloud_optics("physical", settings.max_degree, mean_effective_radii(volume))
    species = tuple(packed_species(volume))
    t0 = time.perf_counter()
    field = diffuse_field(volume, species, gas, sun, optics, settings)
    return time.perf_counter() - t0, field


def median_solve(volume, gas, sun, settings, repeats):
    """The median time of ``repeats`` solves (this machine's times vary by tens of per cent) and the last field."""
    times = []
    for _ in range(repeats):
        t, field = solve_case(volume, gas, sun, settings)
        times.append(t)
    return float(np.median(times)), field


def accuracy(settings):
    """(RICO block mean |error| at 546 nm, deck GHI error, deck zenith error) with these diffuse settings."""
    from swim.optics.cloud_phase import legendre_moments, mie_liquid_phase
    from swim.rt.clouds import CloudScattering
    from swim.rt.march_settings import MarchSettings
    from swim.validation import clouds3d as C
    from swim.validation.stratus import compare_stratus

    rows, _ = C.case_rows(["rico_ground_sza30"], SHARED, settings=MarchSettings(
        cloud_scattering=CloudScattering("discrete_ordinates", C.PHASE, settings)))
    ms = MarchSettings(cloud_scattering=CloudScattering("discrete_ordinates", diffuse=settings))
    deck = compare_stratus(20.0, 60.0, camera_size=41, settings=ms, n_streams=32,
                           g=legendre_moments(mie_liquid_phase(10e-6), 512), space_views=())
    return rows[1]["mean_abs_error"], float(deck["ghi_err"][1]), float(deck["zenith_err"][1])


def render_turns(scene, repeats, size):
    import swim
    from swim.rt.image_sampling import AdaptiveSampling
    from swim.rt.march_settings import MarchSettings

    kw = {"camera": "allsky", "camera_options": {"size": size}, "height": 2.0,
          "sampling": AdaptiveSampling(tolerance=0.0085, coarse_spacing=8, edge_test_size=8)}
    methods = {"albers2020": MarchSettings(cloud_scattering="albers2020"),
               "discrete_ordinates": MarchSettings(cloud_scattering="discrete_ordinates")}
    cold = {}
    for name, s in methods.items():  # cold: compile and (3-D) the diffuse solve of this sun
        t0 = time.perf_counter()
        swim.render(scene, settings=s, **kw)
        cold[name] = time.perf_counter() - t0
    times = {name: [] for name in methods}
    for _ in range(repeats):
        for name, s in methods.items():
            swim.render(scene, settings=s, **kw)  # the stage cache holds one method's constants at a time
            t0 = time.perf_counter()
            swim.render(scene, settings=s, **kw)
            times[name].append(time.perf_counter() - t0)
    return cold, times


def main():
    import scenes

    from swim.io.scene import validate_scene
    from swim.optics.volume import build_optical_volume
    from swim.rt.diffuse_field import DiffuseSettings
    from swim.rt.gas import AerosolBackground, build_gas_tables

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a 100 x 100 x 60 grid and a 256^2 image")
    ap.add_argument("--no-tradeoff", action="store_true")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    n = 100 if args.quick else 400
    size = 256 if args.quick else 1024
    scene = scenes.synthetic_scene(nx=n, ny=n)
    volume = build_optical_volume(validate_scene(scene))
    gas = build_gas_tables(AerosolBackground(), surface_albedo=0.15)
    sz, sa = np.radians(40.0), np.radians(150.0)
    sun = np.array([np.sin(sz) * np.sin(sa), np.sin(sz) * np.cos(sa), np.cos(sz)])
    out = {"created": datetime.now(UTC).isoformat(timespec="seconds"), "grid": [n, n, 60],
           "machine": {"cpus": os.cpu_count(), "platform": platform.platform()}}

    first, _ = solve_case(volume, gas, sun, DiffuseSettings())  # compiles the sweeps
    repeats = args.repeats
    seconds, field = median_solve(volume, gas, sun, DiffuseSettings(), repeats)
    out["solve_default"] = {"first_s": first, "s": seconds, "repeats": repeats, "cells": field.cells,
                            "coarsen": field.coarsen, "sweeps": field.sweeps, "parts_s": field.seconds}
    print(f"diffuse solution, {n} x {n} x 60 grid: {seconds:.2f} s warm (median of {repeats}; {first:.2f} s with "
          f"compilation), {field.cells} cells (columns coarsened {field.coarsen} x), {field.sweeps} sweeps", flush=True)

    if not args.no_tradeoff:
        rows = []
        # coarser grids than the default (faster, fewer columns), then finer ones and thinner cells
        points = [(20_000, 0.25), (37_500, 0.25)] + [(c, t) for c in (75_000, 150_000, 300_000) for t in (0.25, 0.5)]
        for max_cells, max_tau in points:
            s = DiffuseSettings(max_cells=max_cells, max_cell_tau=max_tau)
            t, f = median_solve(volume, gas, sun, s, repeats)
            rico, ghi, zen = accuracy(s)
            rows.append({"max_cells": max_cells, "max_cell_tau": max_tau, "s": t, "cells": f.cells,
                         "coarsen": f.coarsen, "sweeps": f.sweeps, "rico_block_mean_abs_error": rico,
                         "deck_ghi_error": ghi, "deck_zenith_error": zen})
            print(f"max_cells {max_cells}, max_cell_tau {max_tau}: {t:.2f} s ({f.cells} cells, coarsened "
                  f"{f.coarsen} x, {f.sweeps} sweeps); RICO blocks {100 * rico:.1f} %, deck GHI "
                  f"{100 * ghi:+.1f} %, zenith {100 * zen:+.1f} %", flush=True)
        out["tradeoff"] = rows

    cold, times = render_turns(scene, args.repeats, size)
    med = {k: float(np.median(v)) for k, v in times.items()}
    out["render"] = {"image": size, "cold_s": cold, "warm_runs_s": times, "warm_median_s": med,
                     "ratio": med["discrete_ordinates"] / med["albers2020"]}
    print(f"adaptive {size}^2 all-sky, warm: albers2020 {med['albers2020']:.2f} s, discrete_ordinates "
          f"{med['discrete_ordinates']:.2f} s ({out['render']['ratio']:.2f}x); cold {cold}", flush=True)
    path = HERE / "results" / ("clouds3d-quick.json" if args.quick else "clouds3d-latest.json")
    path.write_text(json.dumps(out, indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
