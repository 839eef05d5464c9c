"""Command-line interface: a thin layer over :func:`swim.render` (``swim render --help``)."""

from __future__ import annotations

import gc
import logging
from enum import Enum
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.logging import RichHandler
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from ..errors import SwimInputError

# rich_markup_mode=None: help texts are plain (units in brackets such as "[deg]" must not be read as markup).
app = typer.Typer(add_completion=False, no_args_is_help=True, rich_markup_mode=None,
                  help="SWIm: render what a camera sees in NWP output (Albers et al. 2020).")
console = Console(stderr=True)


class CameraKind(str, Enum):
    allsky = "allsky"
    panorama = "panorama"
    perspective = "perspective"


#: Whether :func:`run` paused the cyclic garbage collector for the command's imports (see :func:`run`).
_GC_PAUSED = False


def run() -> None:
    """The ``swim`` console command: :data:`app` in a process of its own (``[project.scripts]``).

    A command loads JAX, numba, xarray, pandas and colour-science, millions of long-lived objects, and Python's
    cyclic garbage collector traverses them again and again while they load and once more, all of them, as the
    interpreter exits (~0.7 s after the README's render had written its picture). The collector is therefore
    paused until the command's modules are loaded (:func:`modules_loaded`), which then freezes them (the
    collector no longer visits them; they live as long as the process anyway), and everything is frozen before
    the interpreter exits. Together 1.2-1.5 s of the README's render (docs/decisions/0008-cold-start.md). Tests call
    :data:`app` in their own process and keep the collector as it is.
    """
    global _GC_PAUSED
    _GC_PAUSED = gc.isenabled()
    gc.disable()
    try:
        app()
    finally:
        gc.freeze()


def modules_loaded() -> None:
    """Freeze what the command's imports created and let the collector run again (when :func:`run` paused it)."""
    global _GC_PAUSED
    if _GC_PAUSED:
        _GC_PAUSED = False
        gc.freeze()
        gc.enable()


def _print_version(value: bool):
    if value:
        from .. import __version__

        console.print(f"swim {__version__}")
        raise typer.Exit()


#: ``-q``: no progress bars and no report of the files written (errors and warnings still).
QUIET = {"on": False}


def _report(text):
    if not QUIET["on"]:
        console.print(text)


@app.callback()
def main(verbose: bool = typer.Option(False, "--verbose", "-v", help="Log the stages."),
         quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bars and no report of the files "
                                    "written (errors and warnings still)."),
         version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True,
                                      help="Print the version and exit.")):
    """SWIm command-line interface."""
    QUIET["on"] = quiet
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, format="%(message)s",
                        handlers=[RichHandler(console=console, show_path=False)])
    # JAX's search for accelerators it was not built for ("Unable to initialize backend 'tpu'") is not a stage
    logging.getLogger("jax._src.xla_bridge").setLevel(logging.WARNING)


def _site_scene(scene, lat, lon, elevation, albedo, time, sun_zenith):
    """--site: the clear site scene of ``swim ghi`` (:func:`swim.diagnostics.ghi.clear_site_scene`)."""
    from ..diagnostics.ghi import clear_site_scene

    if scene is not None:
        raise SwimInputError("--site renders a cloud-free site instead of a scene file: give one or the other")
    if lat is None or lon is None:
        raise SwimInputError("--site needs --lat and --lon (the site [deg])")
    if time is None and sun_zenith is None:
        raise SwimInputError("--site needs --time (UTC) or --sun-zenith/--sun-azimuth: a site has no model time")
    if not 0.0 <= albedo <= 1.0:
        raise SwimInputError(f"--site-albedo must be within [0, 1], got {albedo}")
    return clear_site_scene(lat, lon, elevation, surface_albedo=albedo, time=time)


def _numbers(text, option):
    """'0.9' or '0.9,0.92,0.95' as a float or a list of floats."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise SwimInputError(f"{option} must be one number or three separated by commas, got {text!r}") from None
    if len(values) not in (1, 3):
        raise SwimInputError(f"{option} must be one number or three separated by commas, got {text!r}")
    return values[0] if len(values) == 1 else values


def _aerosol_optics(type_name, ssa, g, angstrom, phase, scale_height_km):
    """AerosolBackground arguments for the aerosol's own optics and scale height (none where none is given)."""
    from ..optics.aerosol_types import custom_aerosol_type, read_phase_function_table

    out = {}
    if scale_height_km is not None:
        out["scale_height_m"] = float(scale_height_km) * 1e3
    if ssa is None and g is None and angstrom is None and phase is None:
        return out
    if type_name.strip().lower() == "none":
        raise SwimInputError("--aerosol none has no optics to change")
    out["optics"] = custom_aerosol_type(
        type_name, ssa=None if ssa is None else _numbers(ssa, "--aerosol-ssa"),
        g=None if g is None else _numbers(g, "--aerosol-g"), angstrom_exponent=angstrom,
        phase_function=None if phase is None else read_phase_function_table(phase))
    return out


def _white_level(text):
    """--white-level: a number, 'auto' or unset."""
    if text is None or text.strip().lower() == "auto":
        return None if text is None else "auto"
    try:
        return float(text)
    except ValueError:
        raise SwimInputError(f"--white-level must be a positive number (L') or 'auto', got {text!r}") from None


def _cloud_scattering(method, phase):
    """The :class:`swim.rt.clouds.CloudScattering` of ``--cloud-scattering`` and ``--cloud-phase``."""
    from ..rt.clouds import CloudScattering

    if phase is None or phase.strip() == "physical":
        return CloudScattering(method=method)
    spec = {}
    for part in phase.split(","):
        name, sep, value = part.partition("=")
        try:
            spec[name.strip()] = ("hg", float(value))
        except ValueError:
            raise SwimInputError(f"--cloud-phase must be 'physical' or 'name=g,...' (name liquid, ice or a species, "
                                 f"g a Henyey-Greenstein asymmetry parameter), got {phase!r}") from None
        if not sep:
            raise SwimInputError(f"--cloud-phase must be 'physical' or 'name=g,...', got {phase!r}")
    return CloudScattering(method=method, phase_function=spec)


def _given(**options):
    """The options that were given on the command line (not None): the settings classes keep their own defaults
    for the others."""
    return {name: value for name, value in options.items() if value is not None}


#: The render command's GPU kernel options, hidden from its help page (they tune execution, not the image).
GPU_TUNING_OPTIONS = ("--grid-kernel", "--ray-table", "--step1a-on-device", "--device-sampling", "--device-image",
                      "--fused-max-registers", "--fused-vector-loads", "--fused-fma")


class _RenderOptions:
    """The argument and options of :func:`render`: each is the default of the parameter of the same name, where
    Typer reads it, and is declared here so that the command's signature stays short."""

    scene = typer.Argument(None, help="Scene file, recognised by its content: WRF wrfout, WPS geo_em/met_em, "
                           "canonical scene netCDF, SHDOM LES text; and, cut to the region around --lat/--lon: GRIB "
                           "(NCEP GFS, HRRR, RAP; ECMWF), ERA5/IFS netCDF, ICON and MPAS netCDF "
                           "(docs/scene-format.md); default: the built-in scene.")
    time = typer.Option(None, help="UTC time, ISO 8601 (default: the scene's time).")
    lat = typer.Option(None, help="Observer latitude [deg] (default: domain centre; a GRIB, ERA5/IFS, ICON or "
                       "MPAS scene's region is cut around --lat/--lon).")
    lon = typer.Option(None, help="Observer longitude [deg] (default: domain centre).")
    height = typer.Option(2.0, help="Observer height above the ground [m].")
    site = typer.Option(False, "--site", help="No scene file: a cloud-free site at --lat/--lon (flat ground at "
                        "--elevation, albedo --site-albedo) in the clear atmosphere of --aerosol/--aod.")
    elevation = typer.Option(0.0, help="--site: ground elevation [m above sea level].")
    site_albedo = typer.Option(0.2, "--site-albedo", help="--site: ground albedo [-].")
    camera = typer.Option(CameraKind.allsky, help="Camera kind.")
    size = typer.Option(511, help="All-sky image size [pixels].")
    width = typer.Option(1024, help="Panorama / perspective width [pixels].")
    image_height = typer.Option(512, "--image-height", help="Panorama / perspective height [pixels].")
    fov = typer.Option(None, help="Perspective horizontal field of view [deg].")
    view_azimuth = typer.Option(None, help="Perspective view azimuth [deg from north].")
    view_zenith = typer.Option(None, help="Perspective view zenith angle [deg].")
    look_at = typer.Option(None, help="Perspective target 'lat,lon,height_m_asl'.")
    sun_zenith = typer.Option(None, help="Override the sun zenith angle [deg].")
    sun_azimuth = typer.Option(None, help="Override the sun azimuth [deg].")
    aerosol = typer.Option(None, help="Aerosol type: colorado_dust, saudi_mixed, smoke, continental, "
                                      "sea_salt, stratospheric_sulfate (docs/aerosols.md); none: no background "
                                      "aerosol. Default: continental; smoke for a scene whose only aerosol is its "
                                      "smoke_mass_content; the mixture's own type with --aerosol-file.")
    aerosol_file = typer.Option(None, "--aerosol-file", help="CAMS aerosol mass mixing ratios (ADS netCDF on model "
                                "or pressure levels, or ecRad's layout) to put on the scene as its 3-D aerosol, "
                                "through --aerosol-table (docs/aerosols.md, CAMS).")
    aerosol_table = typer.Option(None, "--aerosol-table", help="The IFS aerosol optics table (ecRad's "
                                 "aerosol_ifs_*.nc) that --aerosol-file's species go through.")
    aod = typer.Option(None, help="Background aerosol optical depth at 550 nm (default 0.05; 0 "
                                  "where the scene has a 3-D aerosol field).")
    aerosol_ssa = typer.Option(None, "--aerosol-ssa", help="The aerosol's own single-scattering "
                               "albedo: one value or 'w615,w546,w450' (replaces the type's).")
    aerosol_g = typer.Option(None, "--aerosol-g", help="The aerosol's own asymmetry parameter "
                             "(Henyey-Greenstein): one value or three (615, 546, 450 nm).")
    aerosol_angstrom = typer.Option(None, "--aerosol-angstrom", help="The aerosol's own "
                                    "Angstrom exponent [-].")
    aerosol_phase = typer.Option(None, "--aerosol-phase", help="The aerosol's own phase function: a "
                                 "text table of scattering angle [deg] and P (or P at 615, 546, "
                                 "450 nm), 0-180 deg.")
    aerosol_scale_height = typer.Option(None, "--aerosol-scale-height", help="Scale height of the "
                                        "background aerosol [km] (default 1.5).")
    strat_aod = typer.Option(0.0, "--strat-aod", help="Optical depth at 550 nm of a stratospheric "
                                                      "(volcanic sulfate) aerosol layer at 20 km.")
    strat_height = typer.Option(20.0, "--strat-height", help="Peak height of the stratospheric layer [km].")
    ozone = typer.Option(None, "--ozone", help="Ozone column [DU] of the clear atmosphere (default 345.5, the US "
                         "standard profile's; 0: none): the Chappuis absorption that keeps a twilight zenith blue "
                         "(docs/rendering.md, 'Ozone and twilight').")
    white_level = typer.Option(None, help="Exposure: the L' mapped to display white before the "
                               "highlights roll off (default 1.5, 4 above 100 km), or 'auto' (from "
                               "the image's luminance).")
    exposure = typer.Option(0.0, help="Exposure shift in stops [EV] on top of --white-level: +1 is twice "
                                      "as bright.")
    albedo_image = typer.Option(None, "--albedo-image", help="Land albedo from an RGB image "
                                "(equirectangular, north up, e.g. Blue Marble; docs/surfaces.md).")
    albedo_image_bounds = typer.Option("-180,180,-90,90", "--albedo-image-bounds",
                                       help="'west,east,south,north' [deg] covered by --albedo-image.")
    albedo_image_scale = typer.Option(1.0, "--albedo-image-scale", help="Albedo of a white pixel of "
                                      "--albedo-image [-].")
    surface = typer.Option("brdf", help="Ground reflectance: brdf (land hot spot, snow, sun glint on water) "
                           "or lambertian (docs/surfaces.md).")
    cloud_scattering = typer.Option("discrete_ordinates", "--cloud-scattering",
                                    help="How clouds scatter light: discrete_ordinates (a 3-D solution of the "
                                    "diffuse light for the scene and sun, with Mie and ice phase functions and "
                                    "cloud-ground interreflection; numba and JAX kernels; seconds per new scene "
                                    "and sun; docs/rendering.md, '3-D cloud scattering') or albers2020 (the "
                                    "paper's Eqs. 12-26: a new sun at once, every kernel).")
    cloud_phase = typer.Option(None, "--cloud-phase",
                               help="Phase functions of --cloud-scattering discrete_ordinates: "
                               "physical (default: Mie droplets, roughened-aggregate ice) or "
                               "Henyey-Greenstein per phase, e.g. 'liquid=0.85,ice=0.75'.")
    scene_lat = typer.Option(None, help="Place an LES scene (no coordinates of its own): centre latitude [deg].")
    scene_lon = typer.Option(None, help="Place an LES scene: centre longitude [deg].")
    region_radius = typer.Option(None, "--region-radius", help="GRIB, ERA5/IFS, ICON and MPAS scenes: great-circle "
                                 "radius [deg] of the region cut around --lat/--lon (default: the reader's, 15 for "
                                 "GFS, 4 for HRRR/RAP; at most 30: swim.io.grib.DEFAULT_RADIUS_DEG, MAX_RADIUS_DEG).")
    out = typer.Option(None, help="Image output path, PNG, JPEG or TIFF by its suffix (default swim.png); with --end "
                       "a pattern such as "
                       "'frames/{time:%Y%m%dT%H%M}.png' (fields: index, time, lat, lon, height).")
    netcdf = typer.Option(None, help="Also write the radiance as CF netCDF here (a pattern with "
                          "--end).")
    end = typer.Option(None, help="Render a time series from --time (default: the scene's time) to "
                       "this UTC time, ISO 8601: each frame from the scene file's nearest model time "
                       "(within 90 min), the sun moving.")
    every = typer.Option(10.0, help="Time step of a series [min].")
    freeze_fields = typer.Option(False, "--freeze-fields", help="A series from a scene file: render every frame "
                                 "from the model time nearest to --time (frozen clouds, a moving sun) "
                                 "instead of each frame's nearest model time within 90 min.")
    workers = typer.Option(0, help="Render a series' frames on a local dask cluster of this many processes "
                           "(0: one after the other in this process; needs dask.distributed).")
    scheduler = typer.Option(None, help="Address of a running dask.distributed scheduler for a "
                             "series' frames (e.g. tcp://10.0.0.5:8786).")
    steps = typer.Option(None, help="Ray-marching steps through the model grid (default: "
                                     "MarchSettings().n_grid, 128 adaptive steps).")
    empty_steps = typer.Option(None, "--empty-steps",
                               help="Most grid steps a ray puts into empty grid cells, or one per 2 "
                                    "empty cells where it crosses more (default: a quarter of "
                                    "--steps, 32; 0: every ray takes --steps steps).")
    probes = typer.Option(None, help="Occupancy probes per ray, at least, that place the grid steps "
                                      "(default: MarchSettings().n_probe, 64; 256 with --steps 256 for "
                                      "views that graze a big grid near the horizon).")
    probe_spacing = typer.Option(None, "--probe-spacing",
                                 help="Most grid cells between a ray's occupancy probes: rays that "
                                      "cross more cells take more probes (default: "
                                      "MarchSettings().probe_spacing, 2; 0 for --probes on every "
                                      "ray).")
    tau_refine = typer.Option(None, "--tau-refine",
                              help="Largest hydrometeor optical depth of a grid step, and "
                                   "change of it at a cloud face, near the observer: thicker "
                                   "steps and faces are halved (default: "
                                   "MarchSettings().tau_refine, 0.25; 0 turns it off).")
    stop_tau = typer.Option(None, "--stop-tau",
                            help="Hydrometeor optical depth at which rays that do not look down "
                                 "stop: opaque, the radiance unchanged (default: "
                                 "MarchSettings().stop_tau, 50; 0 marches every ray to its end).")
    globe = typer.Option(False, "--globe", help="Whole-earth view of a global GRIB file (NCEP GFS): its columns on "
                         "an orthographic grid about --lat/--lon (default: the sub-solar point at the file's time), "
                         "seen from the sun-earth L1 point (1.5 million km; --height above 100 km sets another) "
                         "with a perspective camera of --size pixels that fits the disc (docs/decisions/"
                         "0019-whole-earth-views.md).")
    globe_grid = typer.Option(256, "--globe-grid", help="--globe: columns per side of the orthographic grid.")
    lazy = typer.Option(False, "--lazy", help="Open a canonical scene file lazily (dask) and read only the "
                                              "columns the camera can see (big grids; docs/rendering.md).")
    coarsen = typer.Option(None, help="Keep one column of each block of N x N of the grid's columns, "
                           "for a distant view of a big grid: an integer N, or 'auto' (the largest "
                           "blocks no wider than a pixel's footprint on the grid; perspective cameras "
                           "only). docs/rendering.md, 'Distant views of big grids'.")
    adaptive = typer.Option(False, "--adaptive", help="Trace a coarse lattice of pixels and refine only where "
                            "the image is not smooth, interpolating the rest (big images 3-6x faster; "
                            "docs/rendering.md).")
    tolerance = typer.Option(None, help="Relative radiance error allowed where --adaptive "
                             "interpolates [-] (default: AdaptiveSampling().tolerance, 0.0085).")
    tau_tolerance = typer.Option(None, "--tau-tolerance",
                                 help="Relative error of the line-of-sight hydrometeor optical depth "
                                      "allowed where --adaptive interpolates [-] (default: "
                                      "AdaptiveSampling().tau_tolerance, 0.05).")
    clear_tolerance = typer.Option(None, "--clear-tolerance",
                                   help="Relative error of the radiance of the air in front of the "
                                        "clouds allowed where --adaptive interpolates [-] (default: "
                                        "AdaptiveSampling().clear_tolerance, 0.05; 0: not tested).")
    memory_check = typer.Option(True, "--memory-check/--no-memory-check",
                                help="Refuse an image too big for the memory available (before any work).")
    town = typer.Option(None, "--town", help="City lights: a town of POPULATION at LAT,LON as 'LAT,LON,POPULATION' "
                        "(repeatable), its lamps' light sent up by Garstang's law (docs/rendering.md, 'City lights').")
    lamps = typer.Option(None, "--lamps", help="The city lights' lamp spectrum: sodium (high-pressure sodium, orange; "
                         "the default) or led (4000 K white), for --town and a scene's upward_light_emission.")
    light = typer.Option("sun", help="What lights the scene: sun, moon (its place, phase and irradiance at --time; "
                         "docs/rendering.md, 'Moonlight'), or sun+moon (both, each where it shows: one setting "
                         "for a series from day into a moonlit night, with --white-level auto).")
    backend = typer.Option("auto", help="Ray-march kernel: auto (numba on a CPU, JAX on a GPU), jax or numba "
                           "(docs/performance.md).")
    grid_kernel = typer.Option("auto", "--grid-kernel", hidden=True, help="The JAX kernel's march of the grid: auto "
                               "(fused on "
                               "a GPU, else lockstep), lockstep (XLA's loops; gradients), fused (one Pallas "
                               "kernel), or fused-march (the clear air in it too: ~15 % faster per frame, ~40 s "
                               "more compilation, for long series; docs/performance.md).")
    ray_table = typer.Option(None, "--ray-table/--no-ray-table", hidden=True, help="Keep the camera's rays on "
                             "the device between the frames of a series (the JAX kernel: "
                             "ExecutionSettings.ray_table; default: on a GPU, docs/performance.md).")
    step1a_on_device = typer.Option(None, "--step1a-on-device/--no-step1a-on-device", hidden=True, help="A "
                                    "series' new suns: Step 1a on the device's copy of the packed "
                                    "volume (the JAX kernel: ExecutionSettings.step1a_on_device; "
                                    "default: on a GPU, docs/performance.md).")
    device_sampling = typer.Option(None, "--device-sampling/--no-device-sampling", hidden=True, help="With "
                                   "--adaptive and the camera's rays on the device (--ray-table): the "
                                   "sampler's image, tests and interpolation on the device "
                                   "(ExecutionSettings.device_sampling; default: wherever the ray table "
                                   "is, docs/performance.md).")
    device_image = typer.Option(None, "--device-image/--no-device-image", hidden=True, help="With the camera's "
                                "rays on the device (--ray-table): the image's planes and its colour "
                                "made on the device, then copied to the host at once "
                                "(ExecutionSettings.device_image; default: on a GPU, "
                                "docs/performance.md).")
    fused_max_registers = typer.Option(None, "--fused-max-registers", hidden=True, help="Registers per thread "
                                       "that the fused GPU kernel may take, 16-255 (PTX's .maxnreg; "
                                       "ExecutionSettings.fused_max_registers; default: ptxas's choice, "
                                       "docs/performance.md).")
    fused_vector_loads = typer.Option(True, "--fused-vector-loads/--no-fused-vector-loads", hidden=True,
                                      help="The fused GPU kernel reads its tables' channels up to four a load "
                                      "(default) or "
                                      "one scalar gather each (ExecutionSettings.fused_vector_loads; "
                                      "docs/performance.md).")
    fused_fma = typer.Option(False, "--fused-fma/--no-fused-fma", hidden=True, help="Let ptxas contract the fused GPU "
                             "kernel's float32 multiplies and adds into fused multiply-adds (NVIDIA GPUs, "
                             "jaxlib > 0.10.2; ExecutionSettings.fused_fma; docs/performance.md).")


@app.command(epilog="GPU kernel tuning, not shown above: " + ", ".join(GPU_TUNING_OPTIONS)
             + " (MarchSettings; docs/performance.md).")
def render(
    scene: Optional[Path] = _RenderOptions.scene, time: Optional[str] = _RenderOptions.time,
    lat: Optional[float] = _RenderOptions.lat, lon: Optional[float] = _RenderOptions.lon,
    height: float = _RenderOptions.height, site: bool = _RenderOptions.site,
    elevation: float = _RenderOptions.elevation, site_albedo: float = _RenderOptions.site_albedo,
    camera: CameraKind = _RenderOptions.camera, size: int = _RenderOptions.size, width: int = _RenderOptions.width,
    image_height: int = _RenderOptions.image_height, fov: Optional[float] = _RenderOptions.fov,
    view_azimuth: Optional[float] = _RenderOptions.view_azimuth,
    view_zenith: Optional[float] = _RenderOptions.view_zenith, look_at: Optional[str] = _RenderOptions.look_at,
    sun_zenith: Optional[float] = _RenderOptions.sun_zenith, sun_azimuth: Optional[float] = _RenderOptions.sun_azimuth,
    aerosol: Optional[str] = _RenderOptions.aerosol, aod: Optional[float] = _RenderOptions.aod,
    aerosol_file: Optional[Path] = _RenderOptions.aerosol_file,
    aerosol_table: Optional[Path] = _RenderOptions.aerosol_table,
    aerosol_ssa: Optional[str] = _RenderOptions.aerosol_ssa, aerosol_g: Optional[str] = _RenderOptions.aerosol_g,
    aerosol_angstrom: Optional[float] = _RenderOptions.aerosol_angstrom,
    aerosol_phase: Optional[Path] = _RenderOptions.aerosol_phase,
    aerosol_scale_height: Optional[float] = _RenderOptions.aerosol_scale_height,
    strat_aod: float = _RenderOptions.strat_aod, strat_height: float = _RenderOptions.strat_height,
    ozone: Optional[float] = _RenderOptions.ozone,
    white_level: Optional[str] = _RenderOptions.white_level, exposure: float = _RenderOptions.exposure,
    albedo_image: Optional[Path] = _RenderOptions.albedo_image,
    albedo_image_bounds: str = _RenderOptions.albedo_image_bounds,
    albedo_image_scale: float = _RenderOptions.albedo_image_scale, surface: str = _RenderOptions.surface,
    cloud_scattering: str = _RenderOptions.cloud_scattering, cloud_phase: Optional[str] = _RenderOptions.cloud_phase,
    scene_lat: Optional[float] = _RenderOptions.scene_lat, scene_lon: Optional[float] = _RenderOptions.scene_lon,
    region_radius: Optional[float] = _RenderOptions.region_radius,
    out: Optional[Path] = _RenderOptions.out, netcdf: Optional[Path] = _RenderOptions.netcdf,
    end: Optional[str] = _RenderOptions.end, every: float = _RenderOptions.every,
    freeze_fields: bool = _RenderOptions.freeze_fields, workers: int = _RenderOptions.workers,
    scheduler: Optional[str] = _RenderOptions.scheduler, steps: Optional[int] = _RenderOptions.steps,
    empty_steps: Optional[int] = _RenderOptions.empty_steps, probes: Optional[int] = _RenderOptions.probes,
    probe_spacing: Optional[float] = _RenderOptions.probe_spacing,
    tau_refine: Optional[float] = _RenderOptions.tau_refine, stop_tau: Optional[float] = _RenderOptions.stop_tau,
    globe: bool = _RenderOptions.globe, globe_grid: int = _RenderOptions.globe_grid,
    lazy: bool = _RenderOptions.lazy, coarsen: Optional[str] = _RenderOptions.coarsen,
    adaptive: bool = _RenderOptions.adaptive, tolerance: Optional[float] = _RenderOptions.tolerance,
    tau_tolerance: Optional[float] = _RenderOptions.tau_tolerance,
    clear_tolerance: Optional[float] = _RenderOptions.clear_tolerance, memory_check: bool = _RenderOptions.memory_check,
    light: str = _RenderOptions.light, town: Optional[list[str]] = _RenderOptions.town,
    lamps: Optional[str] = _RenderOptions.lamps, backend: str = _RenderOptions.backend,
    grid_kernel: str = _RenderOptions.grid_kernel,
    ray_table: Optional[bool] = _RenderOptions.ray_table,
    step1a_on_device: Optional[bool] = _RenderOptions.step1a_on_device,
    device_sampling: Optional[bool] = _RenderOptions.device_sampling,
    device_image: Optional[bool] = _RenderOptions.device_image,
    fused_max_registers: Optional[int] = _RenderOptions.fused_max_registers,
    fused_vector_loads: bool = _RenderOptions.fused_vector_loads, fused_fma: bool = _RenderOptions.fused_fma,
):
    """Render an all-sky, panorama or perspective image of a scene, or a time series of them (--end)."""
    from ..rt import precompile

    precompile.start_early(backend)  # on a cold numba cache: the march compiles in a helper while the rest loads
    _load_render_modules()
    try:
        if end is None and not workers and not scheduler:  # a series checks each frame's files (render_series)
            _check_outputs(out, netcdf)
        place = {} if globe else {**_les_placement(scene, scene_lat, scene_lon),
                                  **_grib_region(scene, lat, lon, region_radius)}
        if lazy and scene is None:
            raise SwimInputError("--lazy needs a scene file (a canonical scene netCDF file)")
        level_of_detail = _level_of_detail(coarsen)  # checked before the scene is opened
        if site:
            ds = _site_scene(scene, lat, lon, elevation, site_albedo, time, sun_zenith)
        elif globe:
            ds, lat, lon, height = _globe_scene(scene, lat, lon, time, height, globe_grid)
            camera, width, image_height = CameraKind.perspective, size, size
            if fov is None and view_azimuth is None and look_at is None:
                fov, view_azimuth, view_zenith = _globe_camera(lat, lon, height)
        else:
            ds = _scene_file(scene, lazy, time, place)
        ds = _with_towns(_with_albedo_image(ds, albedo_image, albedo_image_bounds, albedo_image_scale), town, lamps)
        options = _camera_options(camera, size, width, image_height, fov, view_azimuth, view_zenith, look_at)
        ds, aerosol = _model_aerosol(ds, aerosol, aerosol_file, aerosol_table, time)
        background = _aerosol_background(ds, aerosol, aod, strat_aod, strat_height, aerosol_ssa, aerosol_g,
                                         aerosol_angstrom, aerosol_phase, aerosol_scale_height, ozone)
        sampling = _adaptive_sampling(tolerance, tau_tolerance, clear_tolerance) if adaptive else None
        target = None if look_at is None else _look_at_target(look_at)
        settings = _march_settings(surface, cloud_scattering, cloud_phase, backend, grid_kernel, ray_table,
                                   step1a_on_device, device_sampling, device_image, fused_max_registers,
                                   fused_vector_loads, fused_fma, steps, probes, empty_steps, probe_spacing,
                                   tau_refine, stop_tau)
        common = dict(lat=lat, lon=lon, height=height, camera=camera.value, camera_options=options,
                      sun_zenith=sun_zenith, sun_azimuth=sun_azimuth, look_at=target, aerosol=background,
                      settings=settings, white_level=_white_level(white_level), exposure=exposure,
                      sampling=sampling, coarsen=level_of_detail,
                      check_memory=memory_check, **({} if light == "sun" else {"light": light}))
        if end is not None or workers or scheduler:
            if sun_zenith is not None or sun_azimuth is not None:
                raise SwimInputError("--sun-zenith/--sun-azimuth fix the sun: every frame of a series from --time to "
                                     "--end would be the same")
            # a cluster's workers open a plain scene file themselves (no scene sent through the scheduler)
            source = None if scene is None or globe or albedo_image is not None or aerosol_file is not None else (
                scene, {**_given(time=time), **place}, lazy)
            _render_series(ds, source, time, end, every, workers, scheduler, out, netcdf, common, freeze_fields)
            return
        out = Path("swim.png") if out is None else out
        image = _render_image(ds, time, out, netcdf, common)
    except SwimInputError as exc:
        console.print(f"[red]error:[/red] {escape(str(exc))}", soft_wrap=True)  # one line, however long
        raise typer.Exit(code=2) from None
    _report(_wrote(out, netcdf, image))


def _wrote(out, netcdf, image):
    """The closing line of a render: the files written and where the light stood."""
    light = image.attrs.get("light", "sun")
    lights = f"; lights marched: {image.attrs.get('lights') or 'none'}" if light == "sun+moon" else ""
    name = "sun" if light == "sun+moon" else light
    return (f"wrote {out}" + (f" and {netcdf}" if netcdf else "") + f" ({name} zenith "
            f"{image.attrs['sun_zenith_deg']:.1f} deg, azimuth {image.attrs['sun_azimuth_deg']:.1f} deg{lights})")


def _load_render_modules():
    """Import the modules a render runs, then :func:`modules_loaded`, which freezes what these imports created too."""
    # the helpers import these names again where they use them; here they load before the freeze
    from .. import default_scene, open_scene  # noqa: F401
    from ..geometry.level_of_detail import check_coarsening  # noqa: F401
    from ..io.atomic import check_output_path  # noqa: F401
    from ..pipeline import image_format, render as render_image, write_outputs  # noqa: F401
    from ..rt.gas import AerosolBackground  # noqa: F401
    from ..rt.image_sampling import AdaptiveSampling  # noqa: F401
    from ..rt.march_settings import MarchSettings  # noqa: F401

    modules_loaded()


def _check_outputs(out, netcdf):
    """--out and --netcdf before any work: a render that cannot be written is not started."""
    from ..io.atomic import check_output_path
    from ..pipeline import image_format

    image_format(Path("swim.png") if out is None else out, "--out")
    check_output_path(Path("swim.png") if out is None else out, "--out")
    if netcdf is not None:
        check_output_path(netcdf, "--netcdf")


def _les_placement(scene, scene_lat, scene_lon):
    """The reader options of --scene-lat/--scene-lon, which place an LES text scene (none where not given)."""
    if scene_lat is None and scene_lon is None:
        return {}
    if scene is None or scene.suffix.lower() not in (".txt", ".lwc", ".dat"):
        raise SwimInputError("--scene-lat/--scene-lon place LES text scenes only; other scenes carry coordinates")
    return {"reference_lat": scene_lat or 0.0, "reference_lon": scene_lon or 0.0}


def _grib_region(scene, lat, lon, region_radius):
    """The reader options of a scene cut around the camera (GRIB, ERA5/IFS, ICON, MPAS: a reader that takes ``lat``,
    ``lon`` and ``radius_deg``): its region is cut around --lat/--lon, of radius --region-radius."""
    import inspect

    from ..io.scene import scene_reader

    reader = None
    if scene is not None and scene.is_file():
        try:
            reader, _, dataset = scene_reader(scene)
        except SwimInputError:
            reader, dataset = None, None  # open_scene says why
        if dataset is not None:
            dataset.close()
    takes = set(inspect.signature(reader).parameters) if reader is not None else set()
    if not {"lat", "lon", "radius_deg"} <= takes:
        if region_radius is not None:
            raise SwimInputError("--region-radius cuts the region of a GRIB, ERA5/IFS, ICON or MPAS scene only")
        return {}
    return {"lat": lat, "lon": lon, **_given(radius_deg=region_radius)}


def _level_of_detail(coarsen):
    """--coarsen as :func:`swim.geometry.level_of_detail.check_coarsening` takes it: None, 'auto' or a block size."""
    from ..geometry.level_of_detail import check_coarsening

    level_of_detail = None if coarsen is None else coarsen.strip().lower()
    if level_of_detail not in (None, "auto"):
        try:
            level_of_detail = int(level_of_detail)
        except ValueError:
            raise SwimInputError(f"--coarsen must be 'auto' or an integer >= 1, got {coarsen!r}") from None
    check_coarsening(level_of_detail)
    return level_of_detail


def _globe_scene(scene, lat, lon, time, height, grid):
    """--globe: the scene (a global GRIB file's columns on an orthographic grid about --lat/--lon, by default the
    sub-solar point at the file's time), the sub-observer point and the observer's height (L1's, unless --height
    is above 100 km)."""
    from ..constants import EARTH_RADIUS_M
    from ..io.globe import L1_DISTANCE_M, hemisphere_scene, read_gfs_global_columns, sub_solar_point

    if scene is None:
        raise SwimInputError("--globe needs a global GRIB file (NCEP GFS) as the scene")
    if (lat is None) != (lon is None):
        raise SwimInputError("--globe: give both --lat and --lon (the sub-observer point), or neither (the sub-solar "
                             "point)")
    columns = read_gfs_global_columns(scene, time)
    if lat is None:
        if time is None and "time" not in columns.coords:
            raise SwimInputError("--globe: the file has no time; give --time or --lat/--lon")
        lat, lon = sub_solar_point(time if time is not None else columns["time"].values)
    if height < 1e5:
        height = L1_DISTANCE_M - EARTH_RADIUS_M
    return hemisphere_scene(columns, lat, lon, size=grid), lat, lon, height


def _globe_camera(lat, lon, height):
    """--globe's perspective camera without --fov/--view-*: straight down at the earth's centre, the disc fitted."""
    from ..constants import EARTH_RADIUS_M
    from ..io.globe import l1_view

    options = l1_view(lat, lon, distance_m=height + EARTH_RADIUS_M)["camera_options"]
    return options["fov_deg"], options["view_azimuth_deg"], options["view_zenith_deg"]


def _scene_file(scene, lazy, time, place):
    """The scene of the SCENE argument, or the built-in scene where none is given."""
    from .. import default_scene, open_scene

    if scene is None:
        return default_scene()
    return open_scene(scene, lazy=lazy, time=time, **place)


def _with_albedo_image(ds, albedo_image, bounds_text, scale):
    """The scene with the land albedo of --albedo-image over --albedo-image-bounds (unchanged without one)."""
    from ..surface.albedo import scene_with_albedo_from_image

    if albedo_image is None:
        return ds
    try:
        bounds = tuple(float(v) for v in bounds_text.split(","))
        assert len(bounds) == 4
    except (ValueError, AssertionError):
        raise SwimInputError("--albedo-image-bounds must be 'west,east,south,north' [deg], got "
                             f"{bounds_text!r}") from None
    return scene_with_albedo_from_image(ds, albedo_image, bounds=bounds, scale=scale)


def _with_towns(ds, towns, lamps):
    """The scene with the city lights of each --town 'LAT,LON,POPULATION' added to its ``upward_light_emission``
    (:func:`swim.surface.city_lights.town_light_emission`), and the lamps of --lamps (default: the scene's, else
    sodium); unchanged without towns or lamps."""
    from ..rt.city_lights import DEFAULT_LAMP, LAMP_SPECTRA
    from ..surface.city_lights import town_light_emission

    if lamps is not None and lamps not in LAMP_SPECTRA:
        raise SwimInputError(f"--lamps must be one of {sorted(LAMP_SPECTRA)}, got {lamps!r}")
    has = "upward_light_emission" in ds
    if not towns:
        if lamps is None or not has:
            return ds
        out = ds.copy()
        out["upward_light_emission"] = out["upward_light_emission"].copy()
        out["upward_light_emission"].attrs["lamp_spectrum"] = lamps
        return out
    lamps = lamps or (ds["upward_light_emission"].attrs.get("lamp_spectrum", DEFAULT_LAMP) if has else DEFAULT_LAMP)
    emission = ds["upward_light_emission"].values if has else 0.0
    for text in towns:
        if len(text.split(",")) != 3:
            raise SwimInputError(f"--town must be 'LAT,LON,POPULATION', got {text!r}")
        lat, lon, population = _numbers(text, "--town")
        emission = emission + town_light_emission(ds["lat"].values, ds["lon"].values, lat, lon, population)
    out = ds.assign(upward_light_emission=(("y", "x"), emission, {"units": "lm m-2"}))
    out["upward_light_emission"].attrs["lamp_spectrum"] = lamps
    return out


def _camera_options(camera, size, width, image_height, fov, view_azimuth, view_zenith, look_at):
    """The camera's options of :func:`swim.render`: its image size and, for a perspective camera, its view."""
    options = {"allsky": {"size": size},
               "panorama": {"width": width, "height": image_height},
               "perspective": {"width": width, "height": image_height}}[camera.value]
    if view_zenith is not None and view_azimuth is None:
        raise SwimInputError("--view-zenith needs --view-azimuth (the view's direction is both angles)")
    if camera is CameraKind.perspective:
        if fov is not None:
            options["fov_deg"] = fov
        elif view_azimuth is not None or look_at is not None:
            options["fov_deg"] = 60.0
        if view_azimuth is not None:
            options.update(view_azimuth_deg=view_azimuth, view_zenith_deg=90.0 if view_zenith is None else view_zenith)
    return options


def _model_aerosol(ds, aerosol, aerosol_file, aerosol_table, time):
    """The scene with --aerosol-file's CAMS aerosol through --aerosol-table (swim.optics.model_aerosol_fields), and
    the aerosol type: --aerosol, else the mixture's effective type (an AerosolType), else the default."""
    if aerosol_file is None:
        if aerosol_table is not None:
            raise SwimInputError("--aerosol-table is the optics table of --aerosol-file, which is not given")
        return ds, aerosol
    if aerosol_table is None:
        raise SwimInputError("--aerosol-file needs --aerosol-table, the IFS aerosol optics table (ecRad's "
                             "aerosol_ifs_*.nc) its species go through")
    from ..io.files import open_netcdf
    from ..optics.model_aerosol_fields import add_cams_aerosol

    with open_netcdf(aerosol_file, "aerosol file") as cams:
        ds, mixture = add_cams_aerosol(ds, cams.load(), aerosol_table, time=time)
    return ds, mixture if aerosol is None else aerosol


def _aerosol_background(ds, aerosol, aod, strat_aod, strat_height, ssa, g, angstrom, phase, scale_height_km,
                        ozone=None):
    """The :class:`swim.rt.gas.AerosolBackground` of the --aerosol, --aod and --strat-* options. ``aerosol``: a type
    name, an AerosolType (--aerosol-file's mixture) or None (continental; smoke for a scene of smoke alone)."""
    from ..optics.aerosol_types import AerosolType
    from ..rt.gas import AerosolBackground

    if isinstance(aerosol, AerosolType):
        if any(v is not None for v in (ssa, g, angstrom, phase)):
            raise SwimInputError("--aerosol-ssa/-g/-angstrom/-phase change a named type; --aerosol-file's mixture "
                                 "has its own (give --aerosol to use a named type instead)")
        strat = {"stratospheric_aod_550": strat_aod, "stratospheric_height_m": 1000.0 * strat_height,
                 **_aerosol_optics("continental", None, None, None, None, scale_height_km), "optics": aerosol,
                 **_given(ozone_du=ozone)}
        return AerosolBackground(aod_550=0.0 if aod is None else aod, **strat)
    if aerosol is None:
        smoke_only = "smoke_mass_content" in ds and "aerosol_extinction" not in ds
        aerosol = "smoke" if smoke_only else "continental"
    strat = {"stratospheric_aod_550": strat_aod, "stratospheric_height_m": 1000.0 * strat_height,
             **_aerosol_optics(aerosol, ssa, g, angstrom, phase, scale_height_km), **_given(ozone_du=ozone)}
    if aerosol.strip().lower() == "none":  # no background aerosol (a scene's 3-D aerosol field stays)
        if aod is not None and aod != 0:
            raise SwimInputError(f"--aerosol none has no optical depth; got --aod {aod}")
        aerosol, aod = "continental", 0.0
    if aod is not None:
        return AerosolBackground(aod_550=aod, type_name=aerosol, **strat)
    if "aerosol_extinction" in ds or "smoke_mass_content" in ds:
        return AerosolBackground(aod_550=0.0, type_name=aerosol, **strat)
    return AerosolBackground(type_name=aerosol, **strat)


def _adaptive_sampling(tolerance, tau_tolerance, clear_tolerance):
    """The :class:`swim.rt.image_sampling.AdaptiveSampling` of --adaptive and its tolerances."""
    from ..rt.image_sampling import AdaptiveSampling

    return AdaptiveSampling(**_given(tolerance=tolerance, tau_tolerance=tau_tolerance,
                                     clear_tolerance=clear_tolerance))


def _look_at_target(look_at):
    """--look-at as (lat, lon, height_m_asl)."""
    try:
        target = tuple(float(v) for v in look_at.split(","))
        assert len(target) == 3
    except (ValueError, AssertionError):
        raise SwimInputError(f"--look-at must be 'lat,lon,height_m_asl', got {look_at!r}") from None
    return target


def _march_settings(surface, cloud_scattering, cloud_phase, backend, grid_kernel, ray_table, step1a_on_device,
                    device_sampling, device_image, fused_max_registers, fused_vector_loads, fused_fma, steps, probes,
                    empty_steps, probe_spacing, tau_refine, stop_tau):
    """The :class:`swim.rt.march_settings.MarchSettings` of the render's options, with their
    :class:`swim.rt.march_settings.ExecutionSettings`."""
    from ..rt.march_settings import ExecutionSettings, MarchSettings

    execution = ExecutionSettings(backend=backend, grid_kernel=grid_kernel, ray_table=ray_table,
                                  step1a_on_device=step1a_on_device, device_sampling=device_sampling,
                                  device_image=device_image, fused_max_registers=fused_max_registers,
                                  fused_vector_loads=fused_vector_loads, fused_fma=fused_fma)
    return MarchSettings(surface=surface, cloud_scattering=_cloud_scattering(cloud_scattering, cloud_phase),
                         execution=execution,
                         **_given(n_grid=steps, n_probe=probes, empty_steps=empty_steps,
                                  probe_spacing=probe_spacing, tau_refine=tau_refine, stop_tau=stop_tau))


def _render_image(ds, time, out, netcdf, common):
    """One image, with a progress bar, written to ``out`` (and ``netcdf``); returns the image."""
    from ..pipeline import render as render_image, write_outputs

    with Progress(TextColumn("[bold]rendering"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                  TimeElapsedColumn(), TimeRemainingColumn(), console=console, transient=True,
                  disable=QUIET["on"]) as bar:
        task = bar.add_task("render", total=1.0)
        image = render_image(ds, time=time, progress=lambda done, total: bar.update(task, completed=done / total),
                             **common)
    write_outputs(image, out, netcdf)
    return image


def _render_series(scene, source, start, end, every, workers, scheduler, out, netcdf, common, freeze_fields=False):
    """``swim render --end``: the frames from ``start`` to ``end`` (:func:`swim.series.render_series`). ``scene`` is the
    opened scene; ``source`` (path, reader options, lazy) the file it came from, which the workers of a cluster open
    themselves, or None."""
    import pandas as pd

    from ..series import model_time_frames, render_series, series_times

    if end is None:
        raise SwimInputError("--workers and --scheduler render a series: give its last time with --end")
    if workers < 0:
        raise SwimInputError(f"--workers must be >= 0, got {workers}")
    if start is None:
        if "time" not in scene.coords:
            raise SwimInputError("a series needs --time: the scene has no time of its own")
        start = pd.Timestamp(scene["time"].values)
    times = series_times(start, end, every)
    if out is None and netcdf is None:
        raise SwimInputError("a series needs --out (or --netcdf) as a pattern, e.g. 'frames/{time:%Y%m%dT%H%M}.png'")
    if (workers or scheduler) and logging.getLogger().level > logging.INFO:
        try:  # dask.distributed sets its own logger to INFO as it is imported; -v shows its scheduler's life
            import distributed  # noqa: F401

            logging.getLogger("distributed").setLevel(logging.WARNING)
        except ImportError:
            pass  # render_series names the missing package
    client = None
    if scheduler is not None:
        try:
            from dask.distributed import Client
        except ImportError:
            raise SwimInputError('--scheduler needs dask.distributed: pip install "swim-imagery[scale]"') from None
        try:
            client = Client(scheduler, timeout=30, set_as_default=False)  # used through render_series only
        except (OSError, TimeoutError, ValueError) as err:
            raise SwimInputError(f"--scheduler {scheduler}: no dask scheduler answered ({err})") from None
    try:
        with Progress(TextColumn("[bold]frames"), BarColumn(), TextColumn("{task.completed:.0f}/{task.total:.0f}"),
                      TimeElapsedColumn(), TimeRemainingColumn(), console=console, transient=True,
                      disable=QUIET["on"]) as bar:
            task = bar.add_task("frames", total=len(times))
            given, frames, opening = scene, times, {}
            if source is not None:  # a scene file: each frame from its nearest model time (model_time_frames)
                path, options, lazy = source
                given, opening = None, {"lazy": lazy}
                frames = model_time_frames(path, times, options, freeze_fields=freeze_fields)
            table = render_series(given, frames, out=out, netcdf=netcdf, client=client, workers=workers or None,
                                  progress=lambda done, total: bar.update(task, completed=done), **opening, **common)
    finally:
        if client is not None:
            client.close()
    files = table["png"] if out is not None else table["netcdf"]
    _report(f"wrote {len(table)} frames, {escape(str(files.iloc[0]))} ... {escape(str(files.iloc[-1]))} "
                  f"({table['seconds'].median():.2f} s per frame in median)")


def _register_diagnostics():
    """The forward-operator commands live in their own modules, and so does ``swim cache``."""
    from .cache import cache
    from .compare import compare
    from .ghi import ghi

    app.command(name="ghi")(ghi)
    app.command(name="compare")(compare)
    app.command(name="cache")(cache)


_register_diagnostics()


if __name__ == "__main__":  # pragma: no cover
    # the package's module, not this __main__ copy: the commands' modules_loaded() reads its _GC_PAUSED
    from swim.cli.main import run as _run

    _run()
