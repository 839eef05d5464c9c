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
from swim.io import globe
from swim.series import series_times

ROOT = Path(__file__).resolve().parents[1]

KATRINA_TIME = "2005-08-28T18:00"
RICO_LAT, RICO_LON, RICO_TIME = 17.6, -61.8, "2005-01-10T15:00"
# Highest point of the met_em terrain (3267 m, on the grid's west edge), moved 0.05 cells into the grid: on the
# edge itself the observer would be placed at sea level (see tests/system/test_surfaces_realdata.py).
COLORADO_PEAK_LAT, COLORADO_PEAK_LON = 39.7045, -107.3050
# Katrina's domain centre (the scene's reference point) and an observer 800 km up from which the sea mirrors the
# 18 UTC sun ~90 km south of the centre (the specular point, found by root finding on the sphere).
KATRINA_CENTRE = (24.49, -90.35, 0.0)
KATRINA_GLINT_OBSERVER = (25.29, -90.26, 800e3)
# The valid time of the GFS file of the whole-earth views (12 UTC run + 120 h).
GFS_GLOBE_TIME = "2011-01-15T12:00"
# The time series through twilight: Katrina's 12 UTC fields from night to sunrise (every frame within the reader's
# 90 min of 12 UTC), and the built-in scene's fields frozen through sunset at its site (40 N, 105.3 W).
KATRINA_DAWN = ("2005-08-28T10:30", "2005-08-28T13:00", 15)
DEFAULT_DUSK = ("2023-06-22T02:00", "2023-06-22T04:30", 15)


def globe_view(gfs: Path, lat: float, lon: float, caption: str) -> dict:
    """A whole-earth view (docs/decisions/0019-whole-earth-views.md): the GFS globe from L1 above (lat, lon), 512 x 512
    pixels, the model's columns on a 256 x 256 orthographic grid holding the disc of 87 deg about (lat, lon)."""
    view = globe.l1_view(lat, lon)
    view["camera_options"].update(width=512, height=512)
    return dict(scene=lambda: globe.hemisphere_scene(globe.read_gfs_global_columns(gfs, GFS_GLOBE_TIME), lat, lon,
                                                     size=256),
                time=GFS_GLOBE_TIME, caption=caption, **view)


def twilight_series(scene, times, caption, columns=4, size=255, **kwargs) -> dict:
    """A time series through twilight: all-sky frames from ``times`` (start, end, every minutes) lit by the sun and the
    moon together, each with its own automatic exposure (a camera at night), tiled into one image with their times."""
    frames = list(series_times(*times))
    return dict(scene=scene, frames=frames, columns=columns, caption=caption, camera="allsky",
                camera_options={"size": size}, light="sun+moon", white_level="auto", **kwargs)


def render_montage(scene, view, path: Path):
    """Render a :func:`twilight_series` view's frames and tile them, each labelled with its UTC time, the sun's
    elevation and the exposure (log2 of the white level: EV below daylight's 1.5); returns the last frame's image."""
    from PIL import Image, ImageDraw

    kwargs = {k: v for k, v in view.items() if k not in ("scene", "caption", "frames", "columns")}
    tiles, image = [], None
    for t in view["frames"]:
        image = swim.render(scene, time=t.isoformat(), **kwargs)
        tile = Image.fromarray(np.ascontiguousarray(image["rgb"].values))
        ev = np.log2(float(image.attrs["white_level"]) / 1.5)
        draw = ImageDraw.Draw(tile)
        label = f"{t:%H:%M} UTC  sun {90 - image.attrs['sun_zenith_deg']:+.1f}°  {ev:+.1f} EV"
        draw.rectangle(draw.textbbox((4, 2), label), fill=(0, 0, 0))  # legible on a white sky too
        draw.text((4, 2), label, fill=(255, 255, 160))
        tiles.append(tile)
    cols = view["columns"]
    w, h = tiles[0].size
    sheet = Image.new("RGB", (w * cols, h * -(-len(tiles) // cols)))
    for i, tile in enumerate(tiles):
        sheet.paste(tile, ((i % cols) * w, (i // cols) * h))
    sheet.save(path)
    return image


def views(data: Path):
    katrina = data / "wrf_katrina" / "ci_test_file.nc"
    rico = data / "les" / "rico122x106x39.txt"
    met_em = data / "wrf_geo" / "met_em.d01.2005-08-28_12_00_00.nc"
    stcu = data / "les" / "les_stcu.txt"
    paper = swim.MarchSettings(cloud_scattering="albers2020")
    gfs = data / "gfs" / "gfs.t12z.pgrbf120.2p5deg.grib2"
    sun_lat, sun_lon = globe.sub_solar_point(GFS_GLOBE_TIME)
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
                                         "azimuth increasing to the right; elevation -90..90). The white arc across "
                                         "the cloud below is the cloudbow, at scattering angles of 138–142° (~40° from "
                                         "the anti-solar point): the Mie droplets of the 3-D cloud scattering; the "
                                         "paper's phase functions have none."),
        "katrina_space": dict(scene=lambda: swim.open_scene(katrina, time=KATRINA_TIME), time=KATRINA_TIME,
                              height=36_000e3, camera="perspective", camera_options={"width": 512, "height": 512},
                              caption="Katrina seen from 36 000 km above the domain centre (north up)."),
        "rico_below": dict(scene=lambda: swim.open_scene(rico, reference_lat=RICO_LAT, reference_lon=RICO_LON),
                           time=RICO_TIME, height=2.0, camera="allsky", camera_options={"size": 511},
                           caption="RICO trade-wind cumulus (LES, 20 m grid) from the sea surface at the domain "
                                   "centre, with the 3-D cloud scattering (the default: Mie droplets, the diffuse "
                                   "light solved in 3-D): grey bases, sunlit sides and the forward glow towards the "
                                   "sun."),
        "rico_above": dict(scene=lambda: swim.open_scene(rico, reference_lat=RICO_LAT, reference_lon=RICO_LON),
                           time=RICO_TIME, height=4000.0, camera="perspective",
                           camera_options={"width": 512, "height": 512, "fov_deg": 40.0,
                                           "view_azimuth_deg": 0.0, "view_zenith_deg": 180.0},
                           caption="RICO cumulus seen from above: nadir view from 4 km, 40° field of view (north up); "
                                   "shaded flanks and soft shadows on the sea."),
        "rico_below_albers2020": dict(scene=lambda: swim.open_scene(rico, reference_lat=RICO_LAT,
                                                                     reference_lon=RICO_LON),
                                     time=RICO_TIME, height=2.0, camera="allsky", camera_options={"size": 511},
                                     settings=paper,
                                     caption="The same view with the paper's cloud scattering (`--cloud-scattering "
                                             "albers2020`, Eqs. 12-26), for comparison."),
        "rico_above_albers2020": dict(scene=lambda: swim.open_scene(rico, reference_lat=RICO_LAT,
                                                                     reference_lon=RICO_LON),
                                     time=RICO_TIME, height=4000.0, camera="perspective",
                                     camera_options={"width": 512, "height": 512, "fov_deg": 40.0,
                                                     "view_azimuth_deg": 0.0, "view_zenith_deg": 180.0},
                                     settings=paper,
                                     caption="RICO from above with the paper's cloud scattering, for comparison."),
        "stcu_below": dict(scene=lambda: swim.open_scene(stcu, reference_lat=RICO_LAT, reference_lon=RICO_LON),
                           time=RICO_TIME, height=2.0, camera="allsky", camera_options={"size": 511},
                           caption="Stratocumulus (SHDOM's LES, 55 m grid, 3.5 km across) from the sea surface: "
                                   "a deck of grey cells, brighter where it is thin."),
        "volcanic_twilight": dict(scene=lambda: swim.default_scene(), camera="panorama",
                                  camera_options={"width": 1024, "height": 512}, sun_zenith=86.0, sun_azimuth=270.0,
                                  aerosol=swim.AerosolBackground(stratospheric_aod_550=0.15),
                                  caption="Built-in scene at sunset (sun 4° above the western horizon) under a volcanic "
                                          "stratospheric sulfate layer of AOD 0.15 at 20 km (docs/aerosols.md, §7)."),
        "clear_sky_sunset": dict(scene=lambda: swim.default_scene(), camera="panorama",
                                 camera_options={"width": 1024, "height": 512}, sun_zenith=86.0, sun_azimuth=270.0,
                                 caption="The same sunset without the stratospheric layer, for comparison."),
        "katrina_dawn_series": twilight_series(
            lambda: swim.open_scene(katrina, time="2005-08-28T12:00"), KATRINA_DAWN, lat=26.0, lon=-90.66, height=2.0,
            caption="Katrina (WRF 12 UTC fields) from the sea surface at the cloud-free spot north-west of the "
                    "hurricane (26.0 N, 90.66 W), from night to sunrise (10:30-13:00 UTC, every 15 min), lit by the "
                    "sun and the waning moon together, each frame with its own automatic exposure; north up, east "
                    "left. Each label gives the time, the sun's elevation and the exposure in EV against the "
                    "daylight default. Stars, the Milky Way and the moon's hazy glow at night; the dawn glow low "
                    "in the east with the hurricane's clouds in silhouette on that horizon; a deep blue sky "
                    "through nautical and civil twilight; the sun rising into a hazy eastern sky."),
        "default_dusk_series": twilight_series(
            lambda: swim.default_scene(), DEFAULT_DUSK,
            caption="The built-in scene's clouds frozen from sunset into the night at its site (40 N, 105.3 W; "
                    "2023-06-22 02:00-04:30 UTC, every 15 min), lit by the sun and the young moon together, each "
                    "frame with its own automatic exposure; north up, east left. The cirrus turns gold and pink at "
                    "sunset while the cumulus below it is in shadow; the zenith stays blue through civil twilight "
                    "and the stars come out; past nautical twilight the night sky's airglow, exposed up by ~23 EV, "
                    "gives the brownish cast of a long exposure. The twilight fades by the sun ~13 deg below the "
                    "horizon (docs/rendering.md, 'Ozone and twilight')."),
        "colorado_peak_panorama": dict(
            scene=lambda: swim.open_scene(met_em), time="2005-08-28T15:00",
            lat=COLORADO_PEAK_LAT, lon=COLORADO_PEAK_LON, height=5.0, camera="panorama",
            camera_options={"width": 1024, "height": 256, "elevation_min_deg": -10.0, "elevation_max_deg": 6.0},
            caption="WPS met_em terrain in Colorado (60 m grid, 2.5 km across): 360° panorama from 5 m above its "
                    "highest point (3267 m, on the grid's west edge) at 8 am local time, the sun 27° high in the "
                    "east (above the frame, its glow at azimuth 100°). North at the left edge, azimuth increasing "
                    "to the right; elevation -10° to +6°, so the vertical scale is stretched 5.6 times. The ridge "
                    "runs east from the peak (the dark cone at azimuth 90°); its north flank (left) faces away "
                    "from the sun and is darker than the south-facing ground (right). The flat band just below "
                    "the skyline is the terrain beyond the tiny grid, which continues at the grid's edge "
                    "heights: its steps near azimuths 90° and 170° are where those extruded edges meet. (The "
                    "faint horizontal line at -1.8° across the western half is a ray-marching artefact.)"),
        "katrina_glint_space": dict(
            scene=lambda: swim.open_scene(katrina, time=KATRINA_TIME).drop_vars("wind_speed_10m"),
            time=KATRINA_TIME, lat=KATRINA_GLINT_OBSERVER[0], lon=KATRINA_GLINT_OBSERVER[1],
            height=KATRINA_GLINT_OBSERVER[2], camera="perspective", look_at=KATRINA_CENTRE,
            camera_options={"width": 512, "height": 512, "fov_deg": 42.0, "roll_deg": 180.0},
            caption="Katrina (18 UTC) from 800 km above 25.29 N, 90.26 W, looking back south at the domain "
                    "centre; the camera is rolled 180° so that north is up and east right. The sun, 16° from the "
                    "zenith in the south, is mirrored by the sea ~90 km south of the centre: the "
                    "soft sun glint (Cox-Munk) below the image centre. The scene's 10 m wind is replaced by the "
                    "renderer's default 5 m/s: with the hurricane's 8-43 m/s winds the glint spreads into a "
                    "faint haze. The hurricane's clouds (top right) end at the domain's north and east edges."),
        "gfs_globe_l1": globe_view(
            gfs, sun_lat, sun_lon,
            "The whole earth from the sun-earth L1 point (1.5 million km), as DSCOVR EPIC sees it: GFS 2.5 deg "
            "(valid 2011-01-15 12 UTC) on a 256 x 256 orthographic grid about the sub-solar point (21.1 S, 2.3 E) "
            "that holds the disc to 87 deg from it (`swim.io.globe`, docs/decisions/0019-whole-earth-views.md). "
            "Africa and Madagascar upper right, the east coast of South America under cloud at the left limb, "
            "Antarctica at the bottom; the clouds reach the limb. Each 2.5 deg cloudy cell shows as a soft "
            "square."),
        "gfs_globe_terminator": globe_view(
            gfs, 0.0, sun_lon - 90.0,
            "The same GFS globe from L1 above (0 N, 87.7 W), 90 deg west of the sub-solar point: the terminator "
            "runs down the middle of the disc (its place checked against the solar ephemeris in "
            "tests/system/test_whole_earth.py), South America on the lit side. Each column takes its own sun and "
            "each ray's clouds are lit at its own vertical (docs/decisions/0020-per-column-sun.md): white towards "
            "the sunlit limb, fading and reddening towards the terminator."),
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
        if "frames" in view:
            image = render_montage(scene, view, args.out / f"{name}.png")
        else:
            image = swim.render(scene, **kwargs)
            swim.write_png(image, args.out / f"{name}.png")
        elapsed = time.perf_counter() - start
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
    readme = args.out / "README.md"
    if args.only and readme.is_file():  # the views rendered replace their own sections, the others are kept
        text = readme.read_text()
        head, *sections = text.split("\n## ")
        kept = {part.split("\n", 1)[0]: part for part in sections}
        new = "\n".join(lines).split("\n## ")[1:]
        for part in new:
            kept[part.split("\n", 1)[0]] = part
        order = [name for name in views(args.data) if name in kept]
        text = head + "".join("\n## " + kept[name].rstrip("\n") + "\n" for name in order)
        readme.write_text(text)
    else:
        readme.write_text("\n".join(lines))


if __name__ == "__main__":
    main()
