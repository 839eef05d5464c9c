"""The retrieval demonstration of docs/assimilation.md: cloud liquid water recovered from three ground cameras and a
satellite, by the variational retrieval and by the paper's colour-ratio baseline.

Usage: ``python scripts/make_retrieval_demo.py [--data ../shared/data] [--out docs/validation] [--cases tuned held_out]
[--size 48] [--outer 3] [--iterations 30] [--align-outer 3] [--align-iterations 30] [--rows existing alignment]
[--truth-radius martin]``

The truth is a 1 x 1 km subvolume of the RICO LES (50 x 50 columns of 20 m, 18 levels of 40 m from 440 m) with two
cumulus clouds (and 18 fragments). Its images are "observed" by
:func:`swim.assimilation.observe.synthetic_observations` (the render's numba kernel with refinement, the stop in opaque
cloud and twice the steps: not the operator's march) with 1 % + 0.001 noise. The first guess perturbs the truth: one
of the two clouds removed, the other shifted by 100-170 m, all liquid water thinned to 60 % (the fragments stay in
place). Three all-sky cameras on the ground (48 x 48) and a satellite 700 km up looking down 25 deg off nadir (48 x 48
pixels over 0.085 deg) see it. Each case reports, per observer and on average, the image r-bar (Eq. 37,
pixels within 5 deg of the sun masked) and the relative L2 error of the 3-D liquid water content of the first guess,
the colour-ratio baseline (one iteration, Sect. 4.3) and the variational retrieval (from the first guess, and from the
baseline's result), and the field alignment's pipeline (``--rows alignment``): the first guess's clouds moved and
scaled as wholes (:func:`swim.assimilation.alignment.align_clouds`), then the baseline, then the variational retrieval
(``--align-outer`` outer loops of ``--align-iterations``); each state's images made by the observations' model without
noise. The truth's droplets follow the forward operator's relation of the effective radius to the content (Martin et
al. 1994, ``--truth-radius martin``, the default: the LES's own radius dropped), because images at visible wavelengths
measure the extinction, 1.5 LWC / (rho_w r_e), and not the liquid water apart from r_e; ``--truth-radius les`` keeps
the LES's radii (larger than Martin's), which biases every retrieved content low. Two
cases: ``tuned`` (the one the settings were chosen on: the smaller cloud removed, the larger moved 120 m north and
120 m east, the sun at 30 deg zenith in the south-east) and ``held_out`` (the larger removed, the smaller moved 100 m
south and 80 m east, the sun at 40 deg in the south-west), reported apart.

Writes ``<out>/retrieval_<case>.png`` (rows: observed, first guess, baseline, retrieved; columns: the cameras and the
satellite; and the liquid water path of each), ``<out>/retrieval.json`` (with the truth's figures:
:func:`truth_figures`) and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

import swim
from swim.assimilation import ForwardOperator, Observer
from swim.assimilation.alignment import align_clouds
from swim.assimilation.colour_ratio import colour_ratio_update
from swim.assimilation.observe import render_observer_images, synthetic_observations
from swim.assimilation.retrieval import image_cost, mean_r, placement_scene, retrieve_liquid_water
from swim.assimilation.state import effective_radius_liquid
from swim.geometry.cameras import look_at_angles
from swim.rt.march_settings import MarchSettings

ROOT = Path(__file__).resolve().parents[1]
#: The operator's march: fewer steps than the render's default (the clouds fill a 1 km grid).
SETTINGS = MarchSettings(n_before=8, n_grid=64, n_after=16)
CASES = {
    # removed cloud (by rank of mass), shift (cells, y and x), thinning, sun zenith and azimuth [deg]
    "tuned": dict(removed=1, shift=(6, 6), thinning=0.6, sun=(30.0, 120.0)),
    "held_out": dict(removed=0, shift=(-5, 4), thinning=0.6, sun=(40.0, 220.0)),
}
CAMERAS = ((15, 15), (35, 20), (25, 38))  # the ground cameras' columns (y, x) in the subvolume
SATELLITE = dict(height=700e3, off_nadir_deg=25.0, view_azimuth_deg=300.0, fov_deg=0.085)


def truth_scene(data: Path, radius="les"):
    """The RICO subvolume: 50 x 50 columns, the lowest 18 levels, its reference point at its centre; its droplets'
    effective radius the LES's (``radius="les"``) or, without it, Martin et al.'s of the content (``"martin"``: the
    forward operator's relation, :func:`swim.assimilation.state.effective_radius_liquid`)."""
    full = swim.read_shdom_les(data / "les" / "rico122x106x39.txt", reference_lat=17.5, reference_lon=-62.0)
    sub = full.isel(y=slice(40, 90), x=slice(8, 58), z=slice(0, 18))
    if radius == "martin":
        sub = sub.drop_vars("cloud_liquid_effective_radius")
    return sub.assign_attrs(reference_lat=float(sub.lat.mean()), reference_lon=float(sub.lon.mean()))


def first_guess(truth, removed, shift, thinning):
    """The truth with its ``removed``-th largest cloud taken out, its largest other cloud shifted by ``shift`` cells
    and everything thinned by ``thinning``."""
    q = truth["cloud_liquid_content"].values
    label, n = ndimage.label(q > 0)
    order = np.argsort(ndimage.sum(q, label, range(1, n + 1)))[::-1] + 1
    gone, moved = order[removed], order[1 - removed]
    guess = np.where((label == gone) | (label == moved), 0.0, q)
    guess += np.roll(np.where(label == moved, q, 0.0), shift, axis=(1, 2))
    return thinning * guess


def observers(truth, size):
    """Three all-sky cameras on the ground and the satellite, looking at the subvolume's centre."""
    lat, lon = truth["lat"].values, truth["lon"].values
    out = [Observer(float(lat[j, i]), float(lon[j, i]), height=2.0, camera="allsky", camera_options={"size": size})
           for j, i in CAMERAS]
    lat0, lon0 = truth.attrs["reference_lat"], truth.attrs["reference_lon"]
    d = SATELLITE["height"] * math.tan(math.radians(SATELLITE["off_nadir_deg"]))
    back = math.radians(SATELLITE["view_azimuth_deg"] + 180.0)
    slat = lat0 + math.degrees(d * math.cos(back) / 6.371e6)
    slon = lon0 + math.degrees(d * math.sin(back) / (6.371e6 * math.cos(math.radians(lat0))))
    azimuth, zenith = look_at_angles(slat, slon, SATELLITE["height"], lat0, lon0, 700.0)[:2]
    out.append(Observer(slat, slon, height=SATELLITE["height"], camera="perspective",
                        camera_options=dict(width=size, height=size, fov_deg=SATELLITE["fov_deg"],
                                            view_azimuth_deg=float(azimuth), view_zenith_deg=float(zenith))))
    return out


def truth_figures(truth):
    """What bounds the 3-D error: the truth's largest liquid water [g m-3], effective radii [um], largest vertical and
    horizontal optical depths, and the L2 error of its own cloud mask (> 1e-5 kg m-3) filled with each level's median
    content (and of that mask dilated by one cell)."""
    q = truth["cloud_liquid_content"].values
    r_e = (truth["cloud_liquid_effective_radius"].values if "cloud_liquid_effective_radius" in truth
           else np.asarray(effective_radius_liquid(q)))
    cloud = q > 1e-5
    beta = np.where(q > 0, 1.5 * q / (1000.0 * np.where(r_e > 0, r_e, 1.0)), 0.0)  # Eq. 7 [m-1]
    dz = float(np.median(np.diff(truth["height"].values[:, 0, 0])))
    dx = float(abs(truth["x"].values[1] - truth["x"].values[0]))
    level = np.array([np.median(a[c]) if c.any() else 0.0 for a, c in zip(q, cloud)])[:, None, None]
    dilated = ndimage.binary_dilation(cloud)
    return {"max_lwc_g_m3": 1e3 * float(q.max()),
            "r_e_um": [1e6 * float(r_e[q > 0].min()), 1e6 * float(r_e[q > 0].max())],
            "max_tau_vertical": float((beta * dz).sum(axis=0).max()),
            "max_tau_horizontal": float(max((beta * dx).sum(axis=1).max(), (beta * dx).sum(axis=2).max())),
            "l2_true_mask_level_median": l2(np.where(cloud, level, 0.0), q),
            "l2_dilated_mask_level_median": l2(np.where(dilated, level, 0.0), q),
            "cells": int(q.size), "clouds": int(ndimage.label(q > 0)[1])}


def l2(x, truth):
    return float(np.linalg.norm(x - truth) / np.linalg.norm(truth))


def run_case(name, truth, size, outer, iterations, out: Path, rows_wanted=("existing", "alignment"),
             align_outer=3, align_iterations=30):
    case = CASES[name]
    q = truth["cloud_liquid_content"].values
    guess = first_guess(truth, case["removed"], case["shift"], case["thinning"])
    obs = observers(truth, size)
    zenith, azimuth = case["sun"]
    observed, _ = synthetic_observations(truth, obs, sun_zenith=zenith, sun_azimuth=azimuth)
    op = ForwardOperator(placement_scene(truth, guess), obs, sun_zenith=zenith, sun_azimuth=azimuth,
                         settings=SETTINGS)
    masks = op.masks_without_sun(5.0)
    states, rows, seconds, extra = {"first guess": guess}, {}, {}, {}
    if "existing" in rows_wanted:
        start = time.perf_counter()
        states["colour-ratio baseline"] = colour_ratio_update(op, truth, guess, observed, masks).state
        seconds["colour-ratio baseline"] = time.perf_counter() - start
        for label, x0 in (("variational", guess), ("baseline + variational", states["colour-ratio baseline"])):
            start = time.perf_counter()
            result = retrieve_liquid_water(truth, obs, observed, sun_zenith=zenith, sun_azimuth=azimuth,
                                           first_guess=x0, outer_loops=outer, iterations=iterations,
                                           settings=SETTINGS)
            seconds[label] = time.perf_counter() - start
            states[label] = result.state
    if "alignment" in rows_wanted:
        alignment_rows(truth, obs, observed, op, masks, case, (align_outer, align_iterations), states, seconds,
                       extra)
    images = {}
    for label, x in states.items():
        # scored by the observations' model (the render's numba kernel, no noise): the same judge for every state,
        # whatever step placement its retrieval used
        sim = truth.copy()
        sim["cloud_liquid_content"] = (("z", "y", "x"), x)
        images[label] = render_observer_images(sim, obs, sun_zenith=zenith, sun_azimuth=azimuth)[0]
        r = mean_r(images[label], observed, masks)
        rows[label] = {"r_bar": r, "mean_r_bar": float(np.mean(r)), "l2": l2(x, q), "seconds": seconds.get(label),
                       **extra.get(label, {})}
    figure(name, observed, images, states, q, masks, out / f"retrieval_{name}.png")
    return rows


def alignment_rows(truth, obs, observed, op, masks, case, loops, states, seconds, extra):
    """The field alignment's rows: the first guess's clouds moved and scaled
    (:func:`swim.assimilation.alignment.align_clouds`), then the colour-ratio baseline on the aligned state (its
    steps placed for it), then the variational retrieval (``loops``: outer loops and iterations) from there; into
    ``states``, ``seconds`` and ``extra`` (the fitted displacements and amplitudes against the first guess's)."""
    zenith, azimuth = case["sun"]
    start = time.perf_counter()
    aligned = align_clouds(op, image_cost(observed, masks), states["first guess"])
    seconds["alignment"] = time.perf_counter() - start
    states["alignment"] = aligned.state
    extra["alignment"] = {"displacements_cells": aligned.displacements.round(3).tolist(),
                          "amplitudes": aligned.amplitudes.round(4).tolist(),
                          "rest_amplitude": round(aligned.rest_amplitude, 4),
                          "true_displacement_cells": [0.0] + [-float(v) for v in case["shift"]],
                          "true_amplitude": 1.0 / case["thinning"]}
    start = time.perf_counter()
    placed = ForwardOperator(placement_scene(truth, aligned.state), obs, sun_zenith=zenith, sun_azimuth=azimuth,
                             settings=SETTINGS)
    states["alignment + baseline"] = colour_ratio_update(placed, truth, aligned.state, observed, masks).state
    seconds["alignment + baseline"] = seconds["alignment"] + time.perf_counter() - start
    start = time.perf_counter()
    result = retrieve_liquid_water(truth, obs, observed, sun_zenith=zenith, sun_azimuth=azimuth,
                                   first_guess=states["alignment + baseline"], outer_loops=loops[0],
                                   iterations=loops[1], settings=SETTINGS)
    label = "alignment + baseline + variational"
    seconds[label] = seconds["alignment + baseline"] + time.perf_counter() - start
    states[label] = result.state


def figure(name, observed, images, states, truth, masks, path):
    """Rows: observed and each state's images (the cameras and the satellite, each exposed alike), then the liquid
    water paths (truth and each state) on one colour scale."""
    from PIL import Image, ImageDraw

    from swim.color.display import auto_white_level, solar_relative_to_srgb8

    whites = [auto_white_level(np.where(m > 0, o, np.nan)) for o, m in zip(observed, masks)]
    rows = [("observed", observed)] + list(images.items())
    tile = 144
    sheet = Image.new("RGB", (tile * (len(observed) + 1), tile * len(rows)), "black")
    lwp_max = 40.0 * truth.sum(axis=0).max()
    for r, (label, ims) in enumerate(rows):
        for c, (im, white) in enumerate(zip(ims, whites)):
            rgb = solar_relative_to_srgb8(np.where(masks[c] > 0, im, np.nan), white)
            sheet.paste(Image.fromarray(np.ascontiguousarray(rgb)).resize((tile, tile), Image.NEAREST),
                        (c * tile, r * tile))
        x = truth if label == "observed" else states[label]
        lwp = np.clip(40.0 * x.sum(axis=0) / lwp_max, 0.0, 1.0)[::-1]  # north up
        grey = (255 * lwp).astype(np.uint8)
        sheet.paste(Image.fromarray(np.stack([grey] * 3, axis=-1)).resize((tile, tile), Image.NEAREST),
                    (len(ims) * tile, r * tile))
        draw = ImageDraw.Draw(sheet)
        text = f"{label} (LWP: {'truth' if label == 'observed' else label})"
        draw.rectangle(draw.textbbox((4, r * tile + 2), text), fill=(0, 0, 0))
        draw.text((4, r * tile + 2), text, fill=(255, 255, 160))
    sheet.save(path)
    logging.getLogger(__name__).info("%s: %s", name, path)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "validation")
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--size", type=int, default=48)
    parser.add_argument("--outer", type=int, default=3)
    parser.add_argument("--iterations", type=int, default=30)
    parser.add_argument("--align-outer", type=int, default=3)
    parser.add_argument("--align-iterations", type=int, default=30)
    parser.add_argument("--rows", nargs="+", default=["existing", "alignment"], choices=["existing", "alignment"])
    parser.add_argument("--truth-radius", default="martin", choices=["les", "martin"])
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    args.out.mkdir(parents=True, exist_ok=True)
    truth = truth_scene(args.data, args.truth_radius)
    results = {name: run_case(name, truth, args.size, args.outer, args.iterations, args.out, args.rows,
                              args.align_outer, args.align_iterations) for name in args.cases}
    results["truth"] = truth_figures(truth)
    (args.out / "retrieval.json").write_text(json.dumps(results, indent=1) + "\n")
    print(json.dumps(results["truth"]))
    print("| case | state | r-bar (cameras 1-3, satellite) | mean r-bar | L2 error of LWC | time [s] |")
    print("|---|---|---|---|---|---|")
    for name in args.cases:
        for label, row in results[name].items():
            sec = "" if row["seconds"] is None else f"{row['seconds']:.0f}"
            print(f"| {name} | {label} | {', '.join(f'{v:.3f}' for v in row['r_bar'])} | {row['mean_r_bar']:.3f} | "
                  f"{row['l2']:.3f} | {sec} |")


if __name__ == "__main__":
    main()
