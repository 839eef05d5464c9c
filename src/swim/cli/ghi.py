"""``swim ghi``: broadband GHI/DNI/DHI time series from small all-sky renders (a thin layer over
:func:`swim.diagnostics.ghi.ghi_time_series`; docs/irradiance.md).

Register it on the main app with ``app.command()(ghi)`` (``swim/cli/main.py``).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.markup import escape

from ..errors import SwimInputError

console = Console(stderr=True)
log = logging.getLogger(__name__)


def _parse_band(text):
    if text is None:
        return None
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise SwimInputError(f"--band must be 'lower,upper' in nm, e.g. '285,2800'; got {text!r}") from None
    return lo, hi


def ghi(
    scene: Optional[Path] = typer.Argument(None, help="Scene file (as for 'swim render'); default: a cloud-free site "
                                           "scene at --lat/--lon/--elevation."),
    lat: Optional[float] = typer.Option(None, help="Observer latitude [deg] (default: --observed station, else the "
                                        "scene centre; overrides the --observed file's; required with an MIDC "
                                        "file)."),
    lon: Optional[float] = typer.Option(None, help="Observer longitude [deg, east +] (as --lat)."),
    elevation: Optional[float] = typer.Option(None, help="Site elevation [m] for the clear site scene (default: "
                                              "--observed station, else 0; as --lat)."),
    start: str = typer.Option(..., help="First instant, ISO 8601 UTC (e.g. 2016-01-01T14:00Z)."),
    end: str = typer.Option(..., help="Last instant, ISO 8601 UTC."),
    step: str = typer.Option("30min", help="Step between instants (e.g. 10min, 1h)."),
    size: int = typer.Option(65, help="All-sky image size [px] (65 converges to < 0.1 % for clear skies)."),
    height: float = typer.Option(2.0, help="Observer height above the ground [m]."),
    aod: float = typer.Option(0.05, help="Aerosol optical depth at 550 nm above the site."),
    aerosol: str = typer.Option("continental", help="Aerosol type (docs/aerosols.md)."),
    pw: Optional[float] = typer.Option(None, help="Precipitable water [cm] (default: from --observed temperature and "
                                       "humidity (Gueymard 1994), else 1.0)."),
    ozone: float = typer.Option(0.3, help="Total ozone [atm-cm]."),
    albedo: Optional[float] = typer.Option(None, help="Ground albedo [-] (default: --observed up/down ratio, else 0.2 "
                                           "for the site scene or the scene's own)."),
    band: Optional[str] = typer.Option(None, help="Integrate over 'lower,upper' nm only (e.g. 285,2800 for a PSP "
                                       "pyranometer); default 280-4000."),
    out: Path = typer.Option(Path("ghi.csv"), help="CSV output (written atomically)."),
    plot: Optional[Path] = typer.Option(None, help="Also write a PNG of simulated (vs observed) irradiance "
                                        "(needs matplotlib)."),
    observed: Optional[Path] = typer.Option(None, help="Radiation observations to compare with: a SURFRAD daily "
                                            "file, a BSRN station-to-archive file (plain or .gz) or an NREL MIDC "
                                            "CSV (with --lat/--lon/--elevation), recognised by content; adds *_obs "
                                            "columns, clear flags and MBE/RMSE."),
):
    """Broadband GHI, DNI and DHI [W m-2] over a period from small all-sky renders (docs/irradiance.md)."""
    from ..rt import precompile

    precompile.start_early("auto")  # on a cold numba cache: the march compiles in a helper while the rest loads
    import numpy as np

    from ..diagnostics.ghi import plot_ghi, time_range, write_csv
    from .main import modules_loaded

    modules_loaded()
    try:
        if plot is not None:
            _check_plotting()
        times = time_range(start, end, step)
        obs = clear = None
        if observed is not None:
            obs, clear, (lat, lon, elevation), pw, albedo = _observations(observed, lat, lon, elevation, pw, albedo)
        pw = 1.0 if pw is None else pw
        ds, lat, lon = _scene_at_site(scene, lat, lon, elevation, albedo)
        sim, background = _simulate(ds, lat, lon, times, height, size, aod, aerosol, pw, ozone, albedo, band)
        ref = _clear_sky_models(sim, background, pw, ozone)
        table = sim.join(ref[["bird_ghi", "ineichen_ghi", "solis_ghi"]])
        if obs is not None:
            table = _with_observations(table, obs, sim.index, clear)
        write_csv(table, out)
        if plot is not None:
            plot_ghi(table, obs, plot, clear=clear, reference=ref,
                     title=f"swim GHI at {lat:.2f}, {lon:.2f} (AOD550 {aod:g} {aerosol}, pw {pw:.2f} cm, {size} px)")
    except SwimInputError as exc:
        console.print(f"[red]error:[/red] {escape(str(exc))}", soft_wrap=True)  # one line, however long
        raise typer.Exit(code=2) from None
    day = table["rendered"]
    _report(f"wrote {out}" + (f" and {plot}" if plot else "")
            + f" ({int(day.sum())} daylight instants, max GHI {float(np.nanmax(table['ghi'])):.0f} W m-2)")


def _report(text):
    """Print what is done, unless -q (which keeps the scores and errors)."""
    from .main import QUIET

    if not QUIET["on"]:
        console.print(text)


def _check_plotting():
    """--plot needs matplotlib: checked before any work."""
    from ..diagnostics.ghi import matplotlib_pyplot

    try:
        matplotlib_pyplot()
    except ImportError as exc:
        raise SwimInputError(f"--plot: {exc}") from None


def _observations(observed, lat, lon, elevation, pw, albedo):
    """The --observed file: the observations, their clear periods, the station's (lat, lon, elevation), and the
    precipitable water and albedo they give where the options do not."""
    from ..io.observations import clear_periods, observed_albedo, observed_precipitable_water, read_observations

    obs = read_observations(observed, latitude=lat, longitude=lon, elevation_m=elevation)
    station = obs.attrs["latitude"], obs.attrs["longitude"], obs.attrs["elevation_m"]
    pw = observed_precipitable_water(obs) if pw is None else pw
    albedo = observed_albedo(obs) if albedo is None else albedo
    clear = clear_periods(obs)
    _report(f"observed: {obs.attrs['format'].upper()} {escape(str(obs.attrs['station']))}, "
            f"{len(obs)} rows {obs.index[0]:%Y-%m-%d %H:%M} to {obs.index[-1]:%Y-%m-%d %H:%M} UTC; "
            f"pw {'default' if pw is None else f'{pw:.2f} cm'}, albedo "
            f"{'default' if albedo is None else f'{albedo:.2f}'}")
    return obs, clear, station, pw, albedo


def _scene_at_site(scene, lat, lon, elevation, albedo):
    """The scene and the site (ds, lat, lon): the SCENE file (its centre by default) or a clear site scene."""
    if scene is None:
        from ..diagnostics.ghi import clear_site_scene

        if lat is None or lon is None:
            raise SwimInputError("without a SCENE give --lat and --lon (or --observed) for the clear site scene")
        elevation = 0.0 if elevation is None else elevation
        return clear_site_scene(lat, lon, elevation, surface_albedo=0.2 if albedo is None else albedo), lat, lon
    from .. import open_scene

    ds = open_scene(scene)
    lat = float(ds.attrs["reference_lat"]) if lat is None else lat
    lon = float(ds.attrs["reference_lon"]) if lon is None else lon
    return ds, lat, lon


def _simulate(ds, lat, lon, times, height, size, aod, aerosol, pw, ozone, albedo, band):
    """The rendered irradiance at ``times``, with a progress bar, and the site's aerosol background."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from ..diagnostics.ghi import aerosol_for_site, ghi_time_series
    from ..optics.volume import build_optical_volume
    from ..pipeline import terrain_at
    from .main import QUIET

    ground = terrain_at(build_optical_volume(ds), lat, lon)[0]
    background = aerosol_for_site(aod, ground + height, aerosol)
    _report(f"rendering {len(times)} instants ({size} px) at {lat:.3f}, {lon:.3f}, ground {ground:.0f} m")
    with Progress(TextColumn("[bold]ghi"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                  TimeRemainingColumn(), console=console, transient=True, disable=QUIET["on"]) as bar:
        task = bar.add_task("ghi", total=len(times))
        sim = ghi_time_series(ds, lat, lon, times, height=height, size=size, aerosol=background,
                              precipitable_water_cm=pw, ozone_atm_cm=ozone, surface_albedo=albedo,
                              band_nm=_parse_band(band),
                              progress=lambda done, total: bar.update(task, completed=done))
    return sim, background


def _clear_sky_models(sim, background, pw, ozone):
    """pvlib's clear-sky GHI models (Bird, Ineichen, SOLIS) at the rendered instants, in the same atmosphere."""
    from ..diagnostics.ghi import pvlib_clear_sky, site_aod_550

    return pvlib_clear_sky(sim["sun_zenith_deg"], elevation_m=sim.attrs["observer_height_asl_m"],
                           aod_550=site_aod_550(background, sim.attrs["observer_height_asl_m"]),
                           angstrom_exponent=background.type.angstrom_exponent, precipitable_water_cm=pw,
                           ozone_atm_cm=ozone, pressure_pa=sim.attrs["pressure_pa"],
                           earth_sun_distance_au=sim["earth_sun_distance_au"],
                           surface_albedo=sim.attrs["surface_albedo"])


def _with_observations(table, obs, index, clear):
    """The table with the observations at its instants; prints MBE and RMSE over the clear daylight instants."""
    from ..diagnostics.ghi import attach_observations, error_statistics
    from ..io.observations import observations_at

    table = attach_observations(table, observations_at(obs, index, clear=clear))
    mask = table["clear"].values & table["rendered"].values
    for comp in ("ghi", "dni", "dhi"):
        s = error_statistics(table[comp], table[f"{comp}_obs"], mask)
        console.print(f"{comp.upper()} vs observed, {s['n']} clear instants: MBE {s['mbe']:+.1f} W m-2 "
                      f"({s['mbe_pct']:+.1f} %), RMSE {s['rmse']:.1f} W m-2 ({s['rmse_pct']:.1f} %)")
    return table
