"""Render the docs/gallery images from the real scenes in ../shared/data (and the built-in scene).

Usage: ``python scripts/make_gallery.py [--data ../shared/data] [--out docs/gallery] [--only NAME ...]``

Writes one PNG per view and ``docs/gallery/README.md`` with the settings, sun angles and render times.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

import numpy as np

import swim

ROOT = Path(__file__).resolve().parents[1]

KATRINA_TIME = "2005-08-28T18:00"
RICO_LAT, RICO_LON, RICO_TIME = 17.6, -61.8, "2005-01-10T15:00"


def views(data: Path):
    katrina = data / "wrf_katrina" / "ci_test_file.nc"
    rico = data / "les" / "rico122x106x39.txt"
    return {
        "default_allsky": dict(scene=lambda: swim.default_scene(), camera="allsky", camera_options={"size": 511},
                               caption="Built-in default scene: all-sky view from the ground (cumulus, cirrus deck, hill)."),
        "katrina_allsky": dict(scene=lambda: swim.open_scene(katrina, time=KATRINA_TIME), time=KATRINA_TIME,
                               lat=24.7, lon=-88.6, height=2.0, camera="allsky", camera_options={"size": 511},
                               caption="Katrina (WRF, 2005-08-28 18 UTC): all-sky from the sea surface at 24.7 N, 88.6 W; "
                                       "north up, east left. A veil of stratiform snow at 4.5-5.6 km (WSM3 QRAIN below "
                                       "0 degC, vertical optical depth ~0.7) covers this spot: a milky sky with a bright "
                                       "aureole, and the hurricane's thick clouds on the north-eastern horizon."),
        "katrina_allsky_clear": dict(scene=lambda: swim.open_scene(katrina, time=KATRINA_TIME), time=KATRINA_TIME,
                                     lat=26.0, lon=-90.66, height=2.0, camera="allsky", camera_options={"size": 511},
                                     caption="Katrina: all-sky from a cloud-free spot north-west of the hurricane "
                                             "(26.0 N, 90.66 W); its thick clouds ~50 km to the east, low on the horizon (left)."),
        "katrina_panorama": dict(scene=lambda: swim.open_scene(katrina, time=KATRINA_TIME), time=KATRINA_TIME,
                                 lat=24.2, lon=-89.0, height=3000.0, camera="panorama",
                                 camera_options={"width": 1024, "height": 512},
                                 caption="Katrina: 360° panorama from 3 km at 24.2 N, 89.0 W (north at the left edge, "
                                         "azimuth increasing to the right; elevation -90..90)."),
        "katrina_space": dict(scene=lambda: swim.open_scene(katrina, time=KATRINA_TIME), time=KATRINA_TIME,
                              height=36_000e3, camera="perspective", camera_options={"width": 512, "height": 512},
                              caption="Katrina seen from 36 000 km above the domain centre (north up)."),
        "rico_below": dict(scene=lambda: swim.open_scene(rico, reference_lat=RICO_LAT, reference_lon=RICO_LON),
                           time=RICO_TIME, height=2.0, camera="allsky", camera_options={"size": 511},
                           caption="RICO trade-wind cumulus (LES, 20 m grid) from the sea surface at the domain centre."),
        "rico_above": dict(scene=lambda: swim.open_scene(rico, reference_lat=RICO_LAT, reference_lon=RICO_LON),
                           time=RICO_TIME, height=4000.0, camera="perspective",
                           camera_options={"width": 512, "height": 512, "fov_deg": 40.0,
                                           "view_azimuth_deg": 0.0, "view_zenith_deg": 180.0},
                           caption="RICO cumulus seen from above: nadir view from 4 km, 40° field of view (north up)."),
        "volcanic_twilight": dict(scene=lambda: swim.default_scene(), camera="panorama",
                                  camera_options={"width": 1024, "height": 512}, sun_zenith=86.0, sun_azimuth=270.0,
                                  aerosol=swim.AerosolBackground(stratospheric_aod_550=0.15),
                                  caption="Built-in scene at sunset (sun 4° above the western horizon) under a volcanic "
                                          "stratospheric sulfate layer of AOD 0.15 at 20 km (docs/aerosols.md, §7)."),
        "clear_sky_sunset": dict(scene=lambda: swim.default_scene(), camera="panorama",
                                 camera_options={"width": 1024, "height": 512}, sun_zenith=86.0, sun_azimuth=270.0,
                                 caption="The same sunset without the stratospheric layer, for comparison."),
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "gallery")
    parser.add_argument("--only", nargs="*")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name, view in views(args.data).items():
        if args.only and name not in args.only:
            continue
        kwargs = {k: v for k, v in view.items() if k not in ("scene", "caption")}
        scene = view["scene"]()
        start = time.perf_counter()
        image = swim.render(scene, **kwargs)
        elapsed = time.perf_counter() - start
        swim.write_png(image, args.out / f"{name}.png")
        radiance = image["radiance"].values
        rows.append((name, view["caption"], image.attrs, elapsed, np.nanmedian(radiance, axis=(1, 2))))
        logging.info("%s: %.1f s", name, elapsed)
    lines = ["# Gallery", "", "Made by `python scripts/make_gallery.py` from the real scenes in `../shared/data`.", ""]
    for name, caption, attrs, elapsed, median in rows:
        lines += [f"## {name}", "", f"![{name}]({name}.png)", "", caption, "",
                  f"- sun zenith {attrs['sun_zenith_deg']:.1f}°, azimuth {attrs['sun_azimuth_deg']:.1f}° "
                  f"(at the observer; {attrs['sun_source']})",
                  f"- observer {attrs['observer_lat']:.2f}°, {attrs['observer_lon']:.2f}°, "
                  f"{attrs['observer_height_above_ground_m']:.0f} m above ground; time {attrs['time'] or 'n/a'}",
                  f"- median L' (615/546/450 nm): {median[0]:.3f} / {median[1]:.3f} / {median[2]:.3f}; "
                  f"render time {elapsed:.1f} s (2-core CPU)", ""]
    if not args.only:
        (args.out / "README.md").write_text("\n".join(lines))


if __name__ == "__main__":
    main()
