"""The 3-D cloud scattering against Mitsuba 3 Monte Carlo on real cloud fields, with the same phase functions.

Two fields with references (:func:`case_scene`): the RICO shallow cumulus LES (20 m columns) and the
stratocumulus LES of the SHDOM distribution (55 m columns). A third field, deep convection (Hurricane Katrina's
eyewall: WRF, 6 x 6 columns of 10 km refined bilinearly to 500 m, cloud water only, vertical optical depths
up to 480, median 150), is rendered (``case_scene("eyewall")``) but has no reference: Monte Carlo needs thousands of
scattering events per path there, and even on the eyewall's thinner outer flank (optical depths 0-75) 8 paths
per pixel took 122-130 s on 2 cores for block standard errors of 12-17 %, i.e. 35-65 min per case for 3 %.
Three views of each (:func:`render_case`): an all-sky image from the ground at the domain's centre, a nadir view
from 700 km and an oblique view from 700 km at a view zenith of 45 deg, towards the sun's azimuth; sun zenith 30 and
60 deg, a Rayleigh atmosphere, the sea (albedo 0.04/0.05/0.07).

Both codes use the same phase function: Henyey-Greenstein with g = 0.85 for the droplets (the I3RC convention,
``cloud_phase_function={"liquid": ("hg", 0.85)}`` in swim, Mitsuba's ``hg``). Mie droplets were tried first: with a
directional sun, Mitsuba's next-event estimate of a path that happens to head within a degree of the sun takes the
diffraction peak's value (~7 000), rare samples that the per-pixel variance misses, so that 8 x 8 blocks of cloud at
128 paths per pixel scattered by a factor 0.25-1.3 around swim while their standard errors read 3 %; the Mie physics
is held to DISORT instead (tests/validation/test_clouds_disort.py). Images of 96 x 96 pixels are compared as
8 x 8-pixel block means (blocks with at least half their pixels in the compared region), whose Monte Carlo standard
error is reported; the references are cached as those block means (and the 546 nm image at half precision, for the
figures) in ``tests/data/validation/clouds3d`` by ``scripts/make_mitsuba_reference.py --clouds3d``.

References
----------
Jakob, W. et al. (2022): Mitsuba 3 renderer, https://mitsuba-renderer.org (volumetric path tracing).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from ..errors import SwimInputError
from ..rt.gas import AerosolBackground

log = logging.getLogger(__name__)

__all__ = [
    "BLOCK",
    "CASES",
    "REFERENCE_DIR",
    "block_means",
    "case_rows",
    "case_scene",
    "load_case_reference",
    "make_case_reference",
    "merge_case_references",
    "render_case",
]

#: Side of the compared blocks [pixels].
BLOCK = 8
#: Image size [pixels].
SIZE = 96
#: The droplets' phase function in both codes.
PHASE = {"liquid": ("hg", 0.85)}
#: Where the references are cached.
REFERENCE_DIR = Path(__file__).resolve().parents[3] / "tests" / "data" / "validation" / "clouds3d"
#: The fields with Monte Carlo references.
FIELDS = ("rico", "stcu")
#: Every field :func:`case_scene` builds: those with references and the eyewall.
SCENE_FIELDS = (*FIELDS, "eyewall")
VIEWS = ("ground", "nadir", "oblique")
SUN_ZENITHS = (30.0, 60.0)
#: The cases: "<field>_<view>_sza<sun zenith>".
CASES = {f"{f}_{v}_sza{int(s)}": {"field": f, "view": v, "sun_zenith": s}
         for f in FIELDS for v in VIEWS for s in SUN_ZENITHS}
SUN_AZIMUTH = 135.0
SPACE_HEIGHT_M = 700.0e3
#: Paths per pixel of the references by view: block means of 64 pixels whose standard error stays within ~2 % (a
#: view from space has less noise per path: fewer paths end in a dark sky or the sea).
SPP = {"ground": 256, "nadir": 128, "oblique": 128}
#: Cases that need more paths for a median block standard error of <= 3 % at every wavelength: the
#: stratocumulus's thick cells scatter paths more (at the views' paths above its medians were 3.3-5.3 %). Their
#: cached references are two runs (seeds 1 and 2) merged by :func:`merge_case_references`.
CASE_SPP = {"stcu_ground_sza60": 640, "stcu_nadir_sza30": 384, "stcu_nadir_sza60": 512, "stcu_oblique_sza30": 384,
            "stcu_oblique_sza60": 384}
SEA_ALBEDO = (0.04, 0.05, 0.07)


def case_scene(field, shared_data):
    """The canonical scene of a field (one of :data:`SCENE_FIELDS`), from ``shared_data`` (../shared/data).

    Raises
    ------
    SwimInputError
        For another field.
    """
    from ..io.les import read_shdom_les

    shared = Path(shared_data)
    if field == "rico":
        return read_shdom_les(shared / "les" / "rico122x106x39.txt", reference_lat=0.0, reference_lon=0.0)
    if field == "stcu":
        return read_shdom_les(shared / "les" / "les_stcu.txt", reference_lat=0.0, reference_lon=0.0)
    if field == "eyewall":
        return _eyewall_scene(shared / "wrf_katrina" / "ci_test_file.nc")
    raise SwimInputError(f"field must be one of {SCENE_FIELDS}, got {field!r}")


def _eyewall_scene(path, rows=slice(42, 48), cols=slice(35, 41), dx_m=500.0):
    """Katrina's eyewall (the domain's north-east corner at 18 UTC): 6 x 6 WRF columns refined to ``dx_m``, on the
    WRF heights of the window's mean column, cloud water only."""
    from scipy.interpolate import RegularGridInterpolator

    from ..io.scene import open_scene, scene_from_arrays

    src = open_scene(path, time="2005-08-28T18:00")
    content = src["cloud_liquid_content"].values[:, rows, cols]
    height = src["height"].values[:, rows, cols].mean(axis=(1, 2))
    ny, nx = content.shape[1:]
    wrf_dx = float(src.attrs.get("wrf_dx", 10_000.0))
    y0 = (np.arange(ny) - (ny - 1) / 2) * wrf_dx
    x0 = (np.arange(nx) - (nx - 1) / 2) * wrf_dx
    x = np.arange(x0[0], x0[-1] + 1.0, dx_m)
    y = np.arange(y0[0], y0[-1] + 1.0, dx_m)
    yy, xx = np.meshgrid(y, x, indexing="ij")
    fine = np.empty((height.size, y.size, x.size))
    for k in range(height.size):
        f = RegularGridInterpolator((y0, x0), content[k])
        fine[k] = f(np.stack([yy, xx], axis=-1))
    lat = float(src["lat"].values[rows, cols].mean())
    lon = float(src["lon"].values[rows, cols].mean())
    return scene_from_arrays(x=x, y=y, z=height, reference_lat=lat, reference_lon=lon, cloud_liquid_content=fine,
                             surface_albedo=np.array(SEA_ALBEDO), land_mask=0.0,
                             title="Katrina's eyewall, 6 x 6 WRF columns refined to 500 m (cloud water)")


def render_case(scene, view, sun_zenith, settings=None):
    """swim's image of a case: ``image`` (3, SIZE, SIZE) L' without the sun's disk (NaN outside the compared pixels),
    ``mask``, ``directions`` (n, 3) of the compared pixels and ``observer`` (3,) [m] in the flat frame of the
    Monte Carlo scene (east, north, up at the domain's centre; the oblique observer on the line of sight through the
    domain's centre, the directions turned into that frame), ``dataset``."""
    from ..frames import enu_from_azimuth_zenith
    from ..pipeline import render
    from .disort import reference_settings

    x = np.asarray(scene["x"].values, float)
    half = 0.5 * float(np.ptp(x))
    aerosol = AerosolBackground(aod_550=0.0, ozone_du=0.0)
    if view == "ground":
        camera, options, height, look_at = "allsky", {"size": SIZE}, 2.0, None
    elif view == "nadir":
        fov = 2.0 * np.degrees(np.arctan(0.9 * half / SPACE_HEIGHT_M))
        camera, height, look_at = "perspective", SPACE_HEIGHT_M, None
        options = {"width": SIZE, "height": SIZE, "fov_deg": fov, "view_azimuth_deg": 0.0, "view_zenith_deg": 180.0}
    elif view == "oblique":
        # from 700 km along a line of sight 45 deg from the zenith at the domain's centre, on the side opposite
        # the sun (looking towards the sun's azimuth), the field of view spanning 0.9 of the domain
        lat0, lon0 = float(scene.attrs["reference_lat"]), float(scene.attrs["reference_lon"])
        from ..frames import scene_to_geodetic

        d = SPACE_HEIGHT_M / np.cos(np.radians(45.0))
        towards = enu_from_azimuth_zenith(SUN_AZIMUTH + 180.0, 45.0)
        lat, lon, height = scene_to_geodetic(np.array([0.0, 0.0, 6_371_000.0]) + d * towards, lat0, lon0)
        fov = 2.0 * np.degrees(np.arctan(0.9 * half * np.cos(np.radians(45.0)) / d))
        camera, look_at = "perspective", (lat0, lon0, 0.0)
        options = {"width": SIZE, "height": SIZE, "fov_deg": fov}
        ds = render(scene, lat=float(lat), lon=float(lon), height=float(height), camera=camera,
                    camera_options=options, look_at=look_at, sun_zenith=float(sun_zenith), sun_azimuth=SUN_AZIMUTH,
                    aerosol=aerosol, settings=reference_settings(settings))
        return _selected(ds, view, sun_zenith, observer=d * towards)
    else:
        raise SwimInputError(f"view must be one of {VIEWS}, got {view!r}")
    ds = render(scene, camera=camera, camera_options=options, sun_zenith=float(sun_zenith), sun_azimuth=SUN_AZIMUTH,
                aerosol=aerosol, height=height, look_at=look_at, settings=reference_settings(settings))
    return _selected(ds, view, sun_zenith)


def _selected(ds, view, sun_zenith, observer=None):
    from ..diagnostics.irradiance import radiance_without_sun_disk
    from ..frames import enu_from_azimuth_zenith, enu_to_scene_rotation
    from .mitsuba import directions_from_angles

    sky = radiance_without_sun_disk(ds)
    vz = ds.variables["view_zenith"].values.astype(float)
    va = ds.variables["view_azimuth"].values.astype(float)
    d = directions_from_angles(vz, va)  # at the observer
    sun = enu_from_azimuth_zenith(float(ds.attrs["sun_azimuth_deg"]), float(ds.attrs["sun_zenith_deg"]))
    scat = np.degrees(np.arccos(np.clip(np.nan_to_num(d) @ sun, -1.0, 1.0)))
    mask = np.isfinite(vz) & np.all(np.isfinite(sky), axis=0) & (scat > 5.0)
    if view == "ground":
        mask &= vz <= 75.0
    lat0, lon0 = float(ds.attrs["reference_lat"]), float(ds.attrs["reference_lon"])
    rotation = enu_to_scene_rotation(float(ds.attrs["observer_lat"]), float(ds.attrs["observer_lon"]), lat0, lon0)
    d_ref = np.nan_to_num(d) @ rotation  # the directions at the domain's centre (the flat frame's)
    if observer is None:  # above or at the domain's centre
        observer = np.array([0.0, 0.0, float(ds.attrs["observer_height_asl_m"])])
    return {"image": np.where(mask[None], sky, np.nan), "mask": mask, "directions": d_ref[mask],
            "observer": np.asarray(observer, float), "dataset": ds}


def block_means(image, mask, stderr=None, block=BLOCK, min_fraction=0.5):
    """Means of ``image`` (3, ny, nx) over ``block`` x ``block`` pixels of ``mask`` (blocks with at least
    ``min_fraction`` of their pixels in it): (3, n_blocks), and with ``stderr`` their standard errors (3, n_blocks)."""
    img = np.asarray(image, float)
    m = np.asarray(mask, bool)
    ny, nx = m.shape
    by, bx = ny // block, nx // block
    img = img[:, :by * block, :bx * block].reshape(3, by, block, bx, block)
    mm = m[:by * block, :bx * block].reshape(by, block, bx, block)
    count = mm.sum(axis=(1, 3))
    keep = count >= min_fraction * block * block
    vals = np.where(mm[None], np.nan_to_num(img), 0.0).sum(axis=(2, 4)) / np.maximum(count, 1)
    out = vals[:, keep]
    if stderr is None:
        return out
    se = np.asarray(stderr, float)[:, :by * block, :bx * block].reshape(3, by, block, bx, block)
    var = np.where(mm[None], np.nan_to_num(se) ** 2, 0.0).sum(axis=(2, 4)) / np.maximum(count, 1) ** 2
    return out, np.sqrt(var[:, keep])


def settings_3d():
    """swim's settings of the comparison: the 3-D cloud scattering with the references' phase function."""
    from ..rt.clouds import CloudScattering
    from ..rt.march_settings import MarchSettings

    return MarchSettings(cloud_scattering=CloudScattering("discrete_ordinates", PHASE))


def make_case_reference(case, shared_data, spp=None, seed=1, out_dir=None, variant=None):
    """Run the Mitsuba reference of ``case`` and cache its block means; returns the .npz path."""
    from datetime import UTC, datetime

    import mitsuba

    from .. import __version__
    from ..optics.volume import build_optical_volume
    from .mitsuba import mitsuba_radiance

    spec = CASES[case]
    spp = int(spp or CASE_SPP.get(case, SPP[spec["view"]]))
    scene = case_scene(spec["field"], shared_data)
    volume = build_optical_volume(scene)
    sv = render_case(scene, spec["view"], spec["sun_zenith"], settings_3d())
    from .mitsuba import HYDROMETEOR_ASYMMETRY

    g = dict(HYDROMETEOR_ASYMMETRY, cloud_liquid=float(PHASE["liquid"][1]), rain=float(PHASE["liquid"][1]))
    out = mitsuba_radiance(volume, spec["sun_zenith"], SUN_AZIMUTH, sv["observer"], sv["directions"], spp=int(spp),
                           aerosol=AerosolBackground(aod_550=0.0, ozone_du=0.0), surface_albedo=SEA_ALBEDO, seed=seed,
                           variant=variant, asymmetry=g)
    ref = np.full(sv["image"].shape, np.nan)
    err = np.full(sv["image"].shape, np.nan)
    ref[:, sv["mask"]] = out["radiance"].T
    err[:, sv["mask"]] = out["stderr"].T
    means, se = block_means(ref, sv["mask"], err)
    out_dir = Path(out_dir or REFERENCE_DIR)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{case}.npz"
    np.savez_compressed(
        path, blocks=means.astype(np.float32), block_stderr=se.astype(np.float32), mask=sv["mask"],
        image_546=ref[1].astype(np.float16), case=case, field=spec["field"], view=spec["view"],
        sun_zenith=float(spec["sun_zenith"]), phase=json.dumps(PHASE), spp=int(spp), seed=int(seed),
        variant=out["variant"], mitsuba_version=mitsuba.__version__, seconds=float(out["seconds"]),
        swim_version=__version__, created=datetime.now(UTC).isoformat(timespec="seconds"),
        settings=json.dumps({"size": SIZE, "block": BLOCK, "sun_azimuth": SUN_AZIMUTH, "sea_albedo": SEA_ALBEDO}))
    log.info("%s: %d pixels x %d spp in %.0f s -> %s", case, int(sv["mask"].sum()), spp, out["seconds"], path)
    return path


def merge_case_references(paths, out_path):
    """Merge references of one case made with different seeds (:func:`make_case_reference`) into one with all their
    paths: the block means and the 546 nm image weighted by paths per pixel, the blocks' standard errors combined
    (se^2 = sum_i n_i^2 se_i^2 / (sum_i n_i)^2), the seeds listed in ``seeds``. Returns ``out_path``.

    Raises
    ------
    SwimInputError
        If the references are of different cases, pixels or settings, or share a seed.
    """
    refs = [load_case_reference(Path(p).stem, Path(p).parent) | {"_path": str(p)} for p in paths]
    first = refs[0]
    seeds = [int(s) for r in refs for s in json.loads(str(r.get("seeds", f"[{r['seed']}]")))]
    for r in refs[1:]:
        for key in ("case", "phase", "settings", "variant"):
            if r[key] != first[key]:
                raise SwimInputError(f"merge_case_references: {r['_path']} differs in {key!r} from {first['_path']}")
        if not np.array_equal(r["mask"], first["mask"]):
            raise SwimInputError(f"merge_case_references: {r['_path']} compares other pixels than {first['_path']}")
    if len(set(seeds)) != len(seeds):
        raise SwimInputError(f"merge_case_references: the references share a seed ({seeds}): their paths are not "
                             f"independent")
    n = np.array([float(r["spp"]) for r in refs])
    w = n / n.sum()
    blocks = sum(wi * r["blocks"].astype(float) for wi, r in zip(w, refs))
    stderr = np.sqrt(sum((wi * r["block_stderr"].astype(float)) ** 2 for wi, r in zip(w, refs)))
    image = sum(wi * r["image_546"].astype(float) for wi, r in zip(w, refs))
    out = {key: value for key, value in first.items() if key != "_path"}
    out.update(blocks=blocks.astype(np.float32), block_stderr=stderr.astype(np.float32),
               image_546=image.astype(np.float16), spp=int(n.sum()), seed=int(seeds[0]), seeds=json.dumps(seeds),
               seconds=float(sum(float(r["seconds"]) for r in refs)))
    np.savez_compressed(out_path, **out)
    return Path(out_path)


def load_case_reference(case, ref_dir=None):
    """A cached reference of :func:`make_case_reference` as a dict."""
    path = Path(ref_dir or REFERENCE_DIR) / f"{case}.npz"
    with np.load(path, allow_pickle=False) as z:
        return {k: (z[k] if z[k].ndim else z[k].item()) for k in z.files}


def case_rows(cases, shared_data, settings=None, ref_dir=None):
    """swim against the cached references, one row per case and wavelength: block-mean ``pearson_r``,
    ``mean_abs_error`` and ``bias`` (median of swim / Monte Carlo - 1), the blocks' median Monte Carlo relative
    standard error ``mc_stderr``, ``n_blocks``; and the swim images (``images``: case -> (swim, mask))."""
    from ..constants import WAVELENGTHS_NM

    settings = settings or settings_3d()
    rows, images, scenes = [], {}, {}
    for case in cases:
        spec = CASES[case]
        ref = load_case_reference(case, ref_dir)
        if spec["field"] not in scenes:
            scenes[spec["field"]] = case_scene(spec["field"], shared_data)
        sv = render_case(scenes[spec["field"]], spec["view"], spec["sun_zenith"], settings)
        if not np.array_equal(sv["mask"], ref["mask"]):
            raise SwimInputError(f"{case}: swim's compared pixels differ from the reference's (regenerate it)")
        ours = block_means(sv["image"], sv["mask"])
        theirs, se = ref["blocks"].astype(float), ref["block_stderr"].astype(float)
        images[case] = (sv["image"], sv["mask"], ref["image_546"].astype(float))
        for c, wl in enumerate(WAVELENGTHS_NM):
            rel = ours[c] / theirs[c] - 1.0
            rows.append({"case": case, "field": spec["field"], "view": spec["view"],
                         "sun_zenith_deg": spec["sun_zenith"], "wavelength_nm": float(wl),
                         "n_blocks": int(rel.size), "pearson_r": float(np.corrcoef(ours[c], theirs[c])[0, 1]),
                         "mean_abs_error": float(np.mean(np.abs(rel))), "bias": float(np.median(rel)),
                         "mc_stderr": float(np.median(se[c] / theirs[c]))})
    return rows, images
