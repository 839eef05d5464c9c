"""GHI forward operator: broadband irradiance time series from rendered all-sky images.

For each instant :func:`ghi_time_series` renders a small all-sky image with :func:`swim.render`, integrates it
over the hemisphere with exact pixel solid angles and the direct beam handled explicitly
(:func:`swim.diagnostics.sky_irradiance`, paper Sect. 3.1), and converts the three-wavelength result to
broadband DNI, DHI and GHI [W m-2] with the gaseous absorption swim lacks
(:func:`swim.diagnostics.broadband.broadband_irradiance`). :func:`pvlib_clear_sky` gives pvlib's clear-sky
models (Bird, Ineichen-Perez, simplified Solis) for the same aerosol, water vapour, ozone and pressure, and
:func:`plot_ghi` draws simulated against observed GHI (matplotlib, optional).

Image size: the hemispheric integral of an all-sky image converges fast with its size (the pixels' solid
angles are exact and the direct beam is not a pixel quantity): for the clear sky at Alamosa (zenith 61 deg)
GHI from 33, 65, 129 and 257 px differs by < 0.05 %, so :data:`DEFAULT_SIZE` = 65 px is ample for clear or
smoothly cloudy skies; broken clouds need more (tests/system/test_ghi_surfrad.py checks 65 vs 129 px).

Aerosol and elevation: swim's background aerosol (:class:`swim.rt.gas.AerosolBackground`) is an exponential
profile anchored at sea level, so a site at elevation z sees ``aod_550 exp(-z / H)`` above it;
:func:`aerosol_for_site` builds the background whose column *above the site* is a given AOD, the quantity
that sun photometers and pvlib's clear-sky models use, and :func:`site_aod_550` inverts it.

References
----------
Albers, S. et al. (2020), AMT 13, 3235-3261, doi:10.5194/amt-13-3235-2020 (Sect. 3.1, Table 4).
Bird, R. E. and Hulstrom, R. L. (1981), A simplified clear sky model for direct and diffuse insolation on
horizontal surfaces, SERI/TR-642-761, doi:10.2172/6510849.
Ineichen, P. and Perez, R. (2002), Sol. Energy 73, 151-157, doi:10.1016/S0038-092X(02)00045-2.
Ineichen, P. (2008), Sol. Energy 82, 758-762, doi:10.1016/j.solener.2008.02.009 (simplified Solis).
Kasten, F. (1996), Sol. Energy 56, 239-244, doi:10.1016/0038-092X(95)00114-7 (Linke turbidity from AOD
and water vapour).
Holmgren, W. F., Hansen, C. W. and Mikofski, M. A. (2018), JOSS 3, 884, doi:10.21105/joss.00884 (pvlib).
"""

from __future__ import annotations

import dataclasses

import logging
import math

import numpy as np
import pandas as pd

from ..constants import DEFAULT_AEROSOL, SOLAR_CONSTANT_W_M2, WAVELENGTHS_NM
from ..errors import SwimInputError
from ..io.atomic import atomic_write
from .broadband import broadband_irradiance

log = logging.getLogger(__name__)

__all__ = [
    "DEFAULT_SIZE",
    "DEFAULT_OZONE_ATM_CM",
    "DEFAULT_PRECIPITABLE_WATER_CM",
    "MAX_STEPS",
    "clear_site_scene",
    "aerosol_for_site",
    "site_aod_550",
    "time_range",
    "ghi_time_series",
    "ghi_at_sun_zeniths",
    "pvlib_clear_sky",
    "error_statistics",
    "attach_observations",
    "write_csv",
    "matplotlib_pyplot",
    "plot_ghi",
]

#: Default all-sky image size [px] for irradiance (module docstring: converged to < 0.05 % for clear skies).
DEFAULT_SIZE = 65
#: Default total ozone [atm-cm] (300 DU, mid-latitude mean).
DEFAULT_OZONE_ATM_CM = 0.3
#: Default precipitable water [cm] (mid-latitude mean; pass the real value where known).
DEFAULT_PRECIPITABLE_WATER_CM = 1.0
#: Most instants one call renders (a guard against a mistyped step).
MAX_STEPS = 5000
_GREEN = int(np.argmin(np.abs(WAVELENGTHS_NM - 546.0)))


def clear_site_scene(lat, lon, elevation_m=0.0, *, surface_albedo=0.2, half_width_m=2000.0, time=None):
    """A small cloud-free land scene with flat terrain at a site's elevation (for clear-sky GHI).

    Parameters
    ----------
    lat, lon : float
        Site [deg].
    elevation_m : float
        Terrain height [m above sea level], -400 ... 8000.
    surface_albedo : float or array_like
        Ground albedo [-], scalar or (3,) at 615/546/450 nm.
    half_width_m : float
        Half width of the 5 x 5-column domain [m]; beyond it the renderer's clear atmosphere continues.
    time : optional
        Valid time (UTC) stored in the scene.

    Returns
    -------
    xarray.Dataset
        Canonical scene (:func:`swim.scene_from_arrays`) with zero cloud content and levels 50 m to 2 km
        above the terrain.

    Raises
    ------
    SwimInputError
        Coordinates or elevation out of range.
    """
    from ..io.scene import scene_from_arrays

    for name, value, lo, hi in (("lat", lat, -90.0, 90.0), ("lon", lon, -360.0, 360.0),
                                ("elevation_m", elevation_m, -400.0, 8000.0), ("half_width_m", half_width_m, 100.0, 1e6)):
        if not (isinstance(value, (int, float, np.floating, np.integer)) and math.isfinite(value) and lo <= value <= hi):
            raise SwimInputError(f"{name} must be a number within [{lo}, {hi}]; got {value!r}")
    x = np.linspace(-half_width_m, half_width_m, 5)
    z = float(elevation_m) + np.array([50.0, 250.0, 500.0, 1000.0, 2000.0])
    zero = np.zeros((z.size, x.size, x.size))
    return scene_from_arrays(x=x, y=x, z=z, reference_lat=float(lat), reference_lon=float(lon),
                             terrain_height=float(elevation_m), cloud_liquid_content=zero,
                             surface_albedo=surface_albedo, land_mask=1.0, time=time,
                             title=f"clear site {lat:.3f}, {lon:.3f}, {elevation_m:.0f} m",
                             source="swim.diagnostics.ghi.clear_site_scene")


def aerosol_for_site(aod_550, elevation_m, type_name=DEFAULT_AEROSOL["type"], scale_height_m=DEFAULT_AEROSOL["scale_height_m"]):
    """Background aerosol whose column above a site at ``elevation_m`` has optical depth ``aod_550``.

    Parameters
    ----------
    aod_550 : float
        Aerosol optical depth at 550 nm above the site [-], >= 0.
    elevation_m : float
        Site elevation [m above sea level].
    type_name : str
        Aerosol type (docs/aerosols.md).
    scale_height_m : float
        Exponential scale height H [m].

    Returns
    -------
    swim.rt.gas.AerosolBackground
        With sea-level-anchored ``aod_550 = aod_550 exp(elevation / H)``.
    """
    from ..rt.gas import AerosolBackground

    if not (np.isfinite(aod_550) and aod_550 >= 0):
        raise SwimInputError(f"aod_550 must be >= 0 [-]; got {aod_550!r}")
    return AerosolBackground(aod_550=float(aod_550) * math.exp(float(elevation_m) / float(scale_height_m)),
                             scale_height_m=float(scale_height_m), type_name=type_name)


def site_aod_550(aerosol, elevation_m) -> float:
    """Aerosol optical depth at 550 nm above a site [-] of a :class:`~swim.rt.gas.AerosolBackground`.

    The exponential background above ``elevation_m`` plus the whole stratospheric layer.
    """
    return float(aerosol.aod_550 * math.exp(-float(elevation_m) / aerosol.scale_height_m) + aerosol.stratospheric_aod_550)


def time_range(start, end, step) -> pd.DatetimeIndex:
    """Instants from ``start`` to ``end`` (inclusive) every ``step`` (UTC).

    Parameters
    ----------
    start, end : str or datetime
        ISO 8601; naive times are UTC.
    step : str or pandas.Timedelta
        E.g. ``"30min"``, ``"1h"``, > 0.

    Returns
    -------
    pandas.DatetimeIndex
        tz-aware UTC.

    Raises
    ------
    SwimInputError
        Unparseable values, end before start, step <= 0 or more than :data:`MAX_STEPS` instants.
    """
    from ..geometry.sun import parse_time_utc

    t0, t1 = parse_time_utc(start, "start"), parse_time_utc(end, "end")
    try:
        dt = pd.Timedelta(step)
    except (ValueError, TypeError):
        raise SwimInputError(f"step must be a duration such as '30min' or '1h'; got {step!r}") from None
    if dt <= pd.Timedelta(0):
        raise SwimInputError(f"step must be > 0; got {step!r}")
    if t1 < t0:
        raise SwimInputError(f"end ({t1}) is before start ({t0})")
    count = int((t1 - t0) / dt) + 1
    if count > MAX_STEPS:
        raise SwimInputError(f"{count} instants from {t0} to {t1} every {dt}: more than {MAX_STEPS}; use a longer step")
    return pd.date_range(t0, t1, freq=dt)


def _aerosol_shape_parameters(aerosol):
    """(ssa near 400 nm, asymmetry at 546 nm) of an aerosol type for the SPCTRL2 diffuse shape."""
    t = aerosol.type
    g = np.asarray(t.asymmetry_parameter(), dtype=float)
    return float(np.clip(t.ssa[2], 0.3, 1.0)), float(np.clip(g[_GREEN], 0.0, 0.95))


def _scene_albedo(scene):
    """Grey (mean of the 3 channels) scene-mean surface albedo [-], as the renderer's multiple-scattering table."""
    from ..optics.volume import build_optical_volume

    volume = build_optical_volume(scene)
    return float(np.clip(volume["surface_albedo"].mean().values, 0.0, 1.0))


def _simulate(scene, lat, lon, suns, *, height, size, aerosol, precipitable_water_cm, ozone_atm_cm, pressure_pa,
              surface_albedo, settings, progress, index, band_nm=None):
    """Render ``suns`` (dicts: ``render`` keywords, or ``skip`` for a night instant) and convert to broadband."""
    from ..io.scene import validate_scene
    from ..optics.atmosphere import us_standard_atmosphere_1976
    from ..pipeline import render
    from ..pipeline.arguments import background_aerosol
    from ..rt.march_settings import MarchSettings
    from .irradiance import sky_irradiance

    if not (isinstance(size, (int, np.integer)) and 9 <= size <= 2049):
        raise SwimInputError(f"size must be an integer number of pixels in [9, 2049]; got {size!r}")
    scene = validate_scene(scene)
    aerosol = background_aerosol(aerosol, set(scene.variables))  # as swim.render takes it
    settings = MarchSettings() if settings is None else settings
    albedo = _scene_albedo(scene) if surface_albedo is None else float(surface_albedo)
    ssa400, asym = _aerosol_shape_parameters(aerosol)
    n = len(suns)
    try:
        pw = np.broadcast_to(np.asarray(precipitable_water_cm, dtype=float), (n,))
        ozone = np.broadcast_to(np.asarray(ozone_atm_cm, dtype=float), (n,))
    except ValueError:
        raise SwimInputError(f"precipitable_water_cm and ozone_atm_cm must be scalars or one value per instant ({n})") from None
    rel = {k: np.zeros((n, 3)) for k in ("ghi", "dhi", "dni")}
    zen = np.full(n, np.nan)
    azi = np.full(n, np.nan)
    dist = np.ones(n)
    rendered = np.zeros(n, dtype=bool)
    height_asl = np.nan
    for k, sun in enumerate(suns):
        if progress is not None:
            progress(k, n)
        if sun.get("skip"):
            zen[k], azi[k], dist[k] = sun["zenith"], sun["azimuth"], sun["distance"]
            continue
        # the render's ozone is the conversion's: its light holds that ozone's absorption, which the conversion
        # divides out at the channels before its fits (rendered_ozone_atm_cm)
        image = render(scene, lat=lat, lon=lon, height=height, camera="allsky", camera_options={"size": int(size)},
                       aerosol=dataclasses.replace(aerosol, ozone_du=1000.0 * float(ozone[k])), settings=settings,
                       **sun["render"])
        sky = sky_irradiance(image)
        for key in rel:
            rel[key][k] = sky[key].values
        zen[k] = float(image.attrs["sun_zenith_deg"])
        azi[k] = float(image.attrs["sun_azimuth_deg"])
        dist[k] = sun.get("distance", float(image.attrs["earth_sun_distance_au"]))
        height_asl = float(image.attrs["observer_height_asl_m"])
        rendered[k] = True
        log.info("GHI instant %d/%d: sun zenith %.2f deg, GHI/E_TOA(546) %.4f", k + 1, n, zen[k], rel["ghi"][k, _GREEN])
    if progress is not None:
        progress(n, n)
    if not np.isfinite(height_asl):
        from ..pipeline import terrain_at
        from ..optics.volume import build_optical_volume

        height_asl = terrain_at(build_optical_volume(scene), lat, lon)[0] + float(height)
    if pressure_pa is None:
        pressure_pa = float(us_standard_atmosphere_1976(np.array([height_asl]))[1][0])
    aod_site = site_aod_550(aerosol, height_asl)
    bb = {k: np.zeros(n) for k in ("ghi", "dni", "dhi", "direct_horizontal", "aod_550", "angstrom_exponent")}
    if rendered.any():
        res = broadband_irradiance(rel["dni"][rendered], rel["dhi"][rendered], zen[rendered],
                                   pressure_pa=pressure_pa, precipitable_water_cm=pw[rendered],
                                   ozone_atm_cm=ozone[rendered], earth_sun_distance_au=dist[rendered],
                                   surface_albedo=albedo, aerosol_ssa_400nm=ssa400, aerosol_asymmetry=asym,
                                   clear_sky_aod_550=min(max(aod_site, 0.0), 5.0), latitude_deg=float(lat),
                                   elevation_m=height_asl, band_nm=band_nm, rendered_ozone_atm_cm=ozone[rendered])
        for key in bb:
            bb[key][rendered] = res[key]
    e_toa = SOLAR_CONSTANT_W_M2 / dist**2
    frame = pd.DataFrame({
        "ghi": bb["ghi"], "dni": bb["dni"], "dhi": bb["dhi"], "direct_horizontal": bb["direct_horizontal"],
        "ghi_rel_546": rel["ghi"][:, _GREEN], "dni_rel_546": rel["dni"][:, _GREEN], "dhi_rel_546": rel["dhi"][:, _GREEN],
        "ghi_546_proxy": rel["ghi"][:, _GREEN] * e_toa,
        "sun_zenith_deg": zen, "sun_azimuth_deg": azi, "earth_sun_distance_au": dist, "rendered": rendered,
        "aod_550_fit": np.where(rendered, bb["aod_550"], np.nan), "angstrom_fit": np.where(rendered, bb["angstrom_exponent"], np.nan),
    }, index=index)
    frame.attrs.update(
        units={"ghi": "W m-2", "dni": "W m-2", "dhi": "W m-2", "direct_horizontal": "W m-2", "ghi_546_proxy": "W m-2",
               "ghi_rel_546": "1", "dni_rel_546": "1", "dhi_rel_546": "1", "sun_zenith_deg": "degree",
               "sun_azimuth_deg": "degree", "earth_sun_distance_au": "AU", "aod_550_fit": "1", "angstrom_fit": "1"},
        lat=float(lat), lon=float(lon), height_m=float(height), observer_height_asl_m=float(height_asl), size=int(size),
        aerosol_type=aerosol.type_name, aerosol_aod_550_sea_level=float(aerosol.aod_550), aerosol_aod_550_site=aod_site,
        aerosol_scale_height_m=float(aerosol.scale_height_m), angstrom_exponent=float(aerosol.type.angstrom_exponent),
        precipitable_water_cm=float(np.median(pw)), ozone_atm_cm=float(np.median(ozone)),
        pressure_pa=float(pressure_pa), surface_albedo=albedo, solar_constant_w_m2=SOLAR_CONSTANT_W_M2,
        band_nm="280-4000" if band_nm is None else f"{band_nm[0]:g}-{band_nm[1]:g}",
        method="swim.render all-sky + sky_irradiance + broadband_irradiance (docs/irradiance.md)")
    return frame


def ghi_time_series(scene, lat, lon, times, *, height=2.0, size=DEFAULT_SIZE, aerosol=None,
                    precipitable_water_cm=DEFAULT_PRECIPITABLE_WATER_CM, ozone_atm_cm=DEFAULT_OZONE_ATM_CM,
                    pressure_pa=None, surface_albedo=None, band_nm=None, settings=None,
                    progress=None) -> pd.DataFrame:
    """Broadband GHI, DNI and DHI [W m-2] at a site for a sequence of instants, from rendered all-sky images.

    Parameters
    ----------
    scene : xarray.Dataset
        Canonical scene (e.g. :func:`clear_site_scene` or :func:`swim.open_scene`); its clouds and 3-D
        aerosol stay fixed, only the sun moves.
    lat, lon : float
        Observer [deg].
    times : sequence of str/datetime or pandas.DatetimeIndex
        Instants (naive = UTC), e.g. :func:`time_range`. Instants with the sun at or below the horizon
        (zenith >= 90 deg) are not rendered: their irradiances are 0 (twilight < ~5 W m-2).
    height : float
        Observer height above the ground [m].
    size : int
        All-sky image size [px] (module docstring).
    aerosol : swim.rt.gas.AerosolBackground or str, optional
        Background aerosol (sea-level anchored: see :func:`aerosol_for_site`); default as :func:`swim.render`.
    precipitable_water_cm, ozone_atm_cm : float or array_like
        Column water vapour [cm] and ozone [atm-cm] for the broadband conversion; scalars or one per instant.
    pressure_pa : float, optional
        Surface pressure [Pa] for the conversion; default the US Standard Atmosphere 1976 at the observer's
        height, the atmosphere the renderer uses.
    surface_albedo : float, optional
        Broadband ground albedo [-] for the diffuse spectral shape; default the scene's mean albedo.
    band_nm : tuple of float, optional
        Spectral band of the broadband values [nm] (e.g. (285, 2800) for a PSP pyranometer); default
        280-4000 nm (:func:`swim.diagnostics.broadband.broadband_irradiance`).
    settings : swim.rt.march_settings.MarchSettings, optional
        Ray-marching settings.
    progress : callable, optional
        Called with (instants done, instants total).

    Returns
    -------
    pandas.DataFrame
        Index: the instants (UTC). Columns ``ghi``, ``dni``, ``dhi``, ``direct_horizontal`` [W m-2]
        (broadband 280-4000 nm, E_TOA = 1362 W m-2 / r^2 with the earth-sun distance r of each date);
        ``ghi_rel_546``, ``dni_rel_546``, ``dhi_rel_546`` [1] (relative to E_TOA at 546 nm);
        ``ghi_546_proxy`` [W m-2] (the paper's monochromatic proxy, for comparison);
        ``sun_zenith_deg``, ``sun_azimuth_deg`` [deg]; ``earth_sun_distance_au`` [AU]; ``rendered``;
        ``aod_550_fit``, ``angstrom_fit`` [-] (non-Rayleigh extinction seen in the direct beam).
        ``attrs`` hold the inputs (water vapour and ozone: their medians) and ``units``.

    Raises
    ------
    SwimInputError
        Bad scene, observer, times or options.
    """
    from ..geometry.sun import sun_position

    try:
        index = pd.DatetimeIndex(pd.to_datetime(times, utc=True), name="time")
    except (ValueError, TypeError) as exc:
        raise SwimInputError(f"times must be UTC instants (ISO 8601); {exc}") from None
    if len(index) == 0:
        raise SwimInputError("times is empty")
    if len(index) > MAX_STEPS:
        raise SwimInputError(f"{len(index)} instants: more than {MAX_STEPS}")
    lat0, lon0 = float(scene.attrs.get("reference_lat", lat)), float(scene.attrs.get("reference_lon", lon))
    suns = []
    for t in index:
        sun = sun_position(t, lat0, lon0)
        if sun.zenith_deg >= 90.0:
            suns.append({"skip": True, "zenith": sun.zenith_deg, "azimuth": sun.azimuth_deg,
                         "distance": sun.earth_sun_distance_au})
        else:
            suns.append({"render": {"time": t}, "distance": sun.earth_sun_distance_au})
    return _simulate(scene, lat, lon, suns, height=height, size=size, aerosol=aerosol,
                     precipitable_water_cm=precipitable_water_cm, ozone_atm_cm=ozone_atm_cm, pressure_pa=pressure_pa,
                     surface_albedo=surface_albedo, settings=settings, progress=progress, index=index,
                     band_nm=band_nm)


def ghi_at_sun_zeniths(scene, lat, lon, sun_zenith_deg, *, sun_azimuth_deg=180.0, earth_sun_distance_au=1.0,
                       height=2.0, size=DEFAULT_SIZE, aerosol=None, precipitable_water_cm=DEFAULT_PRECIPITABLE_WATER_CM,
                       ozone_atm_cm=DEFAULT_OZONE_ATM_CM, pressure_pa=None, surface_albedo=None, band_nm=None,
                       settings=None, progress=None) -> pd.DataFrame:
    """As :func:`ghi_time_series` for given sun zenith angles instead of instants (clear-sky model checks).

    Parameters
    ----------
    sun_zenith_deg : sequence of float
        Sun zenith angles [deg], each in [0, 90).
    sun_azimuth_deg : float
        Sun azimuth [deg] for all of them.
    earth_sun_distance_au : float
        r [AU] for E_TOA.
    Other parameters
        As :func:`ghi_time_series`.

    Returns
    -------
    pandas.DataFrame
        Index ``sun_zenith_deg``; columns as :func:`ghi_time_series`.
    """
    zen = np.atleast_1d(np.asarray(sun_zenith_deg, dtype=float))
    if zen.ndim != 1 or np.any(~np.isfinite(zen)) or np.any(zen < 0) or np.any(zen >= 90):
        raise SwimInputError(f"sun_zenith_deg must be angles in [0, 90) deg; got {sun_zenith_deg!r}")
    suns = [{"render": {"sun_zenith": float(z), "sun_azimuth": float(sun_azimuth_deg)},
             "distance": float(earth_sun_distance_au)} for z in zen]
    frame = _simulate(scene, lat, lon, suns, height=height, size=size, aerosol=aerosol,
                      precipitable_water_cm=precipitable_water_cm, ozone_atm_cm=ozone_atm_cm, pressure_pa=pressure_pa,
                      surface_albedo=surface_albedo, settings=settings, progress=progress,
                      index=pd.Index(zen, name="sun_zenith_deg"), band_nm=band_nm)
    return frame


def pvlib_clear_sky(sun_zenith_deg, *, elevation_m, aod_550, angstrom_exponent, precipitable_water_cm,
                    ozone_atm_cm=DEFAULT_OZONE_ATM_CM, pressure_pa=None, earth_sun_distance_au=1.0, surface_albedo=0.2,
                    solar_constant_w_m2=SOLAR_CONSTANT_W_M2, bird_asymmetry=0.85) -> pd.DataFrame:
    """pvlib's clear-sky models for the same atmosphere as a swim run (Bird, Ineichen-Perez, simplified Solis).

    Each gets the aerosol as it needs it, from the AOD at 550 nm above the site and the Angstrom exponent
    (AOD(lambda) = aod_550 (lambda / 550 nm)^-alpha):

    * Bird & Hulstrom (1981): AOD at 380 and 500 nm, precipitable water, ozone, pressure, the ground albedo
      (pvlib ``clearsky.bird``; Kasten & Young relative air mass);
    * Ineichen & Perez (2002): Linke turbidity from the broadband AOD (Bird & Hulstrom 1980) and the water
      vapour by Kasten (1996) (pvlib ``atmosphere.kasten96_lt``), at the site's altitude;
    * simplified Solis (Ineichen 2008): AOD at 700 nm, precipitable water, pressure;
    * SPCTRL2 (Bird & Riordan 1986): AOD at 500 nm and the Angstrom exponent, water vapour, ozone, pressure,
      albedo (the spectral model whose absorption swim's broadband conversion borrows).

    These are the functions ``pvlib.location.Location.get_clearsky(model="ineichen"|"simplified_solis")``
    calls, here with the geometric sun zenith of the swim run instead of pvlib's refracted one. All three get
    the same extraterrestrial irradiance as swim, ``solar_constant / r^2``.

    Parameters
    ----------
    sun_zenith_deg : float, array_like or pandas.Series
        Geometric sun zenith [deg] (a Series keeps its index).
    elevation_m : float
        Site elevation [m].
    aod_550, angstrom_exponent : float
        Aerosol optical depth at 550 nm above the site [-] and Angstrom exponent [-].
    precipitable_water_cm, ozone_atm_cm : float
        Water vapour [cm] and ozone [atm-cm].
    pressure_pa : float, optional
        Surface pressure [Pa]; default the US Standard Atmosphere 1976 at ``elevation_m``.
    earth_sun_distance_au : float or array_like
        r [AU].
    surface_albedo : float
        Ground albedo for Bird [-].
    solar_constant_w_m2 : float
        [W m-2].
    bird_asymmetry : float
        Bird's forward-scattering ratio of the aerosol (0.85 recommended by Bird & Hulstrom).

    Returns
    -------
    pandas.DataFrame
        Columns ``<model>_ghi``, ``<model>_dni``, ``<model>_dhi`` [W m-2] for model in bird, ineichen,
        solis and spectrl2 (Bird & Riordan 1986, pvlib ``spectrum.spectrl2``, integrated over its 300-4000 nm
        grid with swim's ASTM G173 extraterrestrial spectrum); zero where the sun is down.
    """
    import pvlib

    from ..optics.atmosphere import us_standard_atmosphere_1976

    index = sun_zenith_deg.index if isinstance(sun_zenith_deg, pd.Series) else None
    zen = np.atleast_1d(np.asarray(sun_zenith_deg, dtype=float))
    if index is None:
        index = pd.RangeIndex(zen.size)
    if pressure_pa is None:
        pressure_pa = float(us_standard_atmosphere_1976(np.array([float(elevation_m)]))[1][0])
    r = np.broadcast_to(np.asarray(earth_sun_distance_au, dtype=float), zen.shape)
    dni_extra = solar_constant_w_m2 / r**2
    up = zen < 90.0
    zc = np.where(up, zen, 89.9)
    am_rel = np.asarray(pvlib.atmosphere.get_relative_airmass(zc, model="kastenyoung1989"), dtype=float)
    am_abs = np.asarray(pvlib.atmosphere.get_absolute_airmass(am_rel, pressure_pa), dtype=float)
    aod = {lam: aod_550 * (lam / 550.0) ** (-angstrom_exponent) for lam in (380.0, 500.0, 700.0)}
    out = {}
    bird = pvlib.clearsky.bird(zc, am_rel, aod[380.0], aod[500.0], precipitable_water_cm, ozone=ozone_atm_cm,
                               pressure=pressure_pa, dni_extra=dni_extra, asymmetry=bird_asymmetry, albedo=surface_albedo)
    aod_bb = pvlib.atmosphere.bird_hulstrom80_aod_bb(aod[380.0], aod[500.0])
    linke = pvlib.atmosphere.kasten96_lt(am_abs, precipitable_water_cm, aod_bb)
    ineichen = pvlib.clearsky.ineichen(zc, am_abs, linke, altitude=elevation_m, dni_extra=dni_extra)
    solis = pvlib.clearsky.simplified_solis(90.0 - zc, aod700=aod[700.0], precipitable_water=precipitable_water_cm,
                                            pressure=pressure_pa, dni_extra=dni_extra)
    spectral = _spectrl2_broadband(zc, am_rel, aod[500.0],
                                   angstrom_exponent, precipitable_water_cm, ozone_atm_cm, pressure_pa, surface_albedo,
                                   r, solar_constant_w_m2)
    for name, res in (("bird", bird), ("ineichen", ineichen), ("solis", solis), ("spectrl2", spectral)):
        for comp in ("ghi", "dni", "dhi"):
            out[f"{name}_{comp}"] = np.where(up, np.nan_to_num(np.asarray(res[comp], dtype=float)), 0.0)
    frame = pd.DataFrame(out, index=index)
    frame.attrs.update(aod_550=float(aod_550), angstrom_exponent=float(angstrom_exponent),
                       precipitable_water_cm=float(precipitable_water_cm), ozone_atm_cm=float(ozone_atm_cm),
                       pressure_pa=float(pressure_pa), surface_albedo=float(surface_albedo))
    return frame


def _spectrl2_broadband(zenith, airmass, aod500, alpha, pw, ozone, pressure, albedo, distance, solar_constant):
    """SPCTRL2 GHI/DNI/DHI [W m-2] integrated with the ASTM G173 spectrum on its own grid (1-D inputs)."""
    from pvlib.spectrum import spectrl2

    from .broadband import reference_spectrum

    n = zenith.size
    full = lambda v: np.broadcast_to(np.asarray(v, dtype=float), (n,)).copy()  # noqa: E731
    with np.errstate(invalid="ignore", divide="ignore"):
        res = spectrl2(zenith, zenith, np.zeros(n), full(albedo), full(pressure), airmass, full(pw), full(ozone),
                       full(aod500), dayofyear=np.ones(n), alpha=full(alpha))
    spec = reference_spectrum()
    e0 = spec.scaled(solar_constant, distance)
    w = spec.weight_nm[:, None]
    extra = np.asarray(res["dni_extra"])
    dni = np.sum(w * e0 * np.nan_to_num(np.asarray(res["dni"]) / extra), axis=0)
    dhi = np.sum(w * e0 * np.nan_to_num(np.asarray(res["dhi"]) / extra), axis=0)
    return {"dni": dni, "dhi": dhi, "ghi": dhi + np.cos(np.radians(zenith)) * dni}


def error_statistics(simulated, observed, mask=None) -> dict:
    """Mean bias and root-mean-square error of simulated against observed irradiance.

    Parameters
    ----------
    simulated, observed : array_like or pandas.Series
        Same shape [W m-2]; NaN pairs are ignored.
    mask : array_like of bool, optional
        Use only these.

    Returns
    -------
    dict
        ``n``; ``mbe``, ``rmse``, ``mae`` [W m-2]; ``mbe_pct``, ``rmse_pct``, ``mae_pct`` [%] relative to the
        mean observation; ``mean_observed`` [W m-2].
    """
    s = np.asarray(simulated, dtype=float).ravel()
    o = np.asarray(observed, dtype=float).ravel()
    if s.shape != o.shape:
        raise SwimInputError(f"simulated and observed must have the same shape; got {s.shape} and {o.shape}")
    ok = np.isfinite(s) & np.isfinite(o)
    if mask is not None:
        ok &= np.asarray(mask, dtype=bool).ravel()
    if not ok.any():
        return {"n": 0, "mbe": np.nan, "rmse": np.nan, "mae": np.nan, "mbe_pct": np.nan, "rmse_pct": np.nan,
                "mae_pct": np.nan, "mean_observed": np.nan}
    d = s[ok] - o[ok]
    mean_obs = float(np.mean(o[ok]))
    stats = {"n": int(ok.sum()), "mbe": float(np.mean(d)), "rmse": float(np.sqrt(np.mean(d**2))),
             "mae": float(np.mean(np.abs(d))), "mean_observed": mean_obs}
    for key in ("mbe", "rmse", "mae"):
        stats[f"{key}_pct"] = 100.0 * stats[key] / mean_obs if mean_obs != 0 else np.nan
    return stats


def write_csv(frame: pd.DataFrame, path):
    """Write a :func:`ghi_time_series` table as CSV atomically (ISO 8601 UTC times, 4 decimals).

    Returns
    -------
    pathlib.Path
    """
    return atomic_write(path, lambda tmp: frame.to_csv(tmp, index=True, float_format="%.4f",
                                                        date_format="%Y-%m-%dT%H:%M:%SZ"))


def matplotlib_pyplot():
    """``matplotlib.pyplot`` with the Agg backend, or ImportError if matplotlib is not really installed.

    colour-science (when imported, e.g. to build swim's colour cache entry) puts ``unittest.mock.MagicMock``
    objects into ``sys.modules["matplotlib"]`` etc. when matplotlib is missing, so a bare ``import matplotlib``
    succeeds and every drawing call silently does nothing; this checks for the real package.

    Raises
    ------
    ImportError
        With the install hint.
    """
    import sys
    import types

    hint = "plotting needs matplotlib: pip install matplotlib"
    module = sys.modules.get("matplotlib")
    if module is not None and not (isinstance(module, types.ModuleType) and getattr(module, "__file__", None)):
        raise ImportError(hint + " (only colour-science's stand-in is loaded)")
    try:
        import matplotlib

        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise ImportError(hint) from exc
    if not (isinstance(matplotlib, types.ModuleType) and getattr(matplotlib, "__file__", None)):
        raise ImportError(hint + " (only colour-science's stand-in is loaded)")
    return plt


def plot_ghi(sim: pd.DataFrame, obs: pd.DataFrame | None, path, *, clear=None, reference: pd.DataFrame | None = None,
             title=None, components=("ghi", "dni", "dhi")):
    """Plot simulated (and observed) irradiance over time, with the differences, to a PNG (atomically).

    Parameters
    ----------
    sim : pandas.DataFrame
        From :func:`ghi_time_series` (index UTC).
    obs : pandas.DataFrame, optional
        Observations with columns ``ghi``/``dni``/``dhi`` [W m-2] and a UTC index (e.g. a SURFRAD day from
        :func:`swim.io.observations.read_observations`), drawn as lines.
    path : str or pathlib.Path
        Output PNG.
    clear : pandas.Series, optional
        Boolean clear-period flags of ``obs`` (shaded where not clear).
    reference : pandas.DataFrame, optional
        :func:`pvlib_clear_sky` output with the index of ``sim`` (Bird GHI drawn dashed).
    title : str, optional
        Figure title.
    components : sequence of str
        Which of ghi, dni, dhi to draw.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ImportError
        If matplotlib is not installed (``pip install matplotlib``).
    """
    from pathlib import Path

    plt = matplotlib_pyplot()
    colours = {"ghi": "tab:red", "dni": "tab:orange", "dhi": "tab:blue"}

    def naive(index):
        return index.tz_convert("UTC").tz_localize(None) if getattr(index, "tz", None) is not None else index

    fig, (ax, axd) = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True, gridspec_kw={"height_ratios": [3, 1.3]})
    x_sim = naive(sim.index)
    for comp in components:
        ax.plot(x_sim, sim[comp], "o", color=colours[comp], ms=4, label=f"swim {comp.upper()}")
        if obs is not None and comp in obs:
            ax.plot(naive(obs.index), obs[comp], "-", color=colours[comp], lw=1, alpha=0.7, label=f"observed {comp.upper()}")
    if reference is not None and "bird_ghi" in reference:
        ax.plot(x_sim, reference["bird_ghi"], "--", color="k", lw=1, label="Bird (pvlib) GHI")
    if obs is not None and clear is not None:
        daylight = np.asarray(obs["zenith"] < 90) if "zenith" in obs else np.ones(len(obs), bool)
        cloudy = ~np.asarray(clear, dtype=bool) & daylight
        if cloudy.any():
            ax.fill_between(naive(obs.index), 0, 1, where=cloudy, color="0.88", transform=ax.get_xaxis_transform(),
                            lw=0, label="not clear or zenith > 85°")
    ax.set_ylabel("irradiance [W m$^{-2}$]")
    ax.legend(fontsize=8, ncol=2, loc="upper left")
    ax.grid(alpha=0.3)
    if "ghi_obs" in sim:
        use = np.asarray(sim["clear"], dtype=bool) if "clear" in sim else np.ones(len(sim), bool)
        axd.axhline(0, color="k", lw=0.8)
        for comp in components:
            if f"{comp}_obs" in sim:
                diff = (sim[comp] - sim[f"{comp}_obs"]).values
                axd.plot(x_sim[use], diff[use], "o", color=colours[comp], ms=3, label=comp.upper())
        axd.set_ylabel("swim − observed\n[W m$^{-2}$]" + ("\n(clear instants)" if "clear" in sim else ""))
        axd.legend(fontsize=8, ncol=3)
    else:
        axd.plot(x_sim, sim["sun_zenith_deg"], "k-")
        axd.set_ylabel("sun zenith [deg]")
    axd.grid(alpha=0.3)
    axd.set_xlabel("time (UTC)")
    if isinstance(x_sim, pd.DatetimeIndex):
        import matplotlib.dates as mdates

        axd.xaxis.set_major_formatter(mdates.DateFormatter("%H:%M"))
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path = Path(path)
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    plt.close(fig)
    return path


def attach_observations(sim: pd.DataFrame, observed: pd.DataFrame, columns=("ghi", "dni", "dhi")) -> pd.DataFrame:
    """Copy of ``sim`` with observed columns ``<name>_obs`` (and ``clear``) at its instants.

    Parameters
    ----------
    sim : pandas.DataFrame
        From :func:`ghi_time_series`.
    observed : pandas.DataFrame
        Observations at the instants of ``sim`` (same index), e.g. from
        :func:`swim.io.observations.observations_at`; an optional boolean ``clear`` column is copied as is.
    columns : sequence of str
        Columns to copy [W m-2].

    Returns
    -------
    pandas.DataFrame
    """
    if not sim.index.equals(observed.index):
        raise SwimInputError("observed must have the same index (instants) as the simulation")
    out = sim.copy()
    for name in columns:
        if name in observed:
            out[f"{name}_obs"] = observed[name].values
    if "clear" in observed:
        out["clear"] = observed["clear"].values.astype(bool)
    out.attrs = dict(sim.attrs)
    return out
