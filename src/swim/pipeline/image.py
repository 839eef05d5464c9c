"""A render's image: the colour stage and the image's dataset, its variables and attributes (CF-1.8)."""

from __future__ import annotations

import dataclasses
import functools
from datetime import datetime, timezone

import numpy as np
import pandas as pd
import xarray as xr

from .. import __version__
from ..color import solar_relative_to_srgb8
from ..constants import SOLAR_SPECTRAL_IRRADIANCE_W_M2_NM, WAVELENGTHS_NM
from ..frames import azimuth_zenith_from_enu
from ..io.scene import to_utc_datetime64
from ..rt.march_settings import EXECUTION_FIELDS, MarchSettings
from ..workers import parallel_map, threads


#: Image rows per call of the colour stage in :func:`render` (bounds its float64 temporaries).
COLOUR_BLOCK_ROWS = 128



def settings_attributes(settings: MarchSettings) -> dict:
    """The march settings as netCDF attributes ``settings_<field>``, the fields of its
    :class:`~swim.rt.march_settings.ExecutionSettings` among them: numbers as they are, booleans as 0 or 1, the rest
    (None, methods, nested settings) as text."""
    values = {field.name: getattr(settings, field.name) for field in dataclasses.fields(settings)
              if field.name != "execution"}
    values.update({name: getattr(settings.execution, name) for name in EXECUTION_FIELDS})
    out = {}
    for name, value in values.items():
        if isinstance(value, (bool, np.bool_)):
            value = int(value)
        elif not isinstance(value, (int, float, np.integer, np.floating)):
            value = str(value)
        out[f"settings_{name}"] = value
    return out


def colour_stage(radiance, white_level, device_rgb=None, recoloured=()):
    """The image's 8-bit sRGB codes (ny, nx, 3) of its ``radiance`` (3, ny, nx) [-] at ``white_level``
    (:func:`swim.color.solar_relative_to_srgb8`). Per pixel, in blocks of rows (float64 copies of a block) on up to
    8 cores, its compiled pass without the GIL (:mod:`swim.color.srgb_cpu`: ~0.05 s for a 1024^2 image on one core,
    0.26-0.39 s in NumPy). ``device_rgb``: the codes made where the march ran and the pixels it left to the host (the
    spectra that need clipping), which are coloured here with the pixels ``recoloured`` (flat indices: the sun's disk
    and aureole, added since)."""
    if device_rgb is not None:
        codes, need = device_rgb
        rgb = codes if codes.flags.writeable else codes.copy()
        redo = np.union1d(np.flatnonzero(need), recoloured)
        if redo.size:
            rgb.reshape(-1, 3)[redo] = solar_relative_to_srgb8(radiance.reshape(3, -1)[:, redo],
                                                               white_level=white_level)
        return rgb
    ny = radiance.shape[1]

    def colour(r0):
        return solar_relative_to_srgb8(radiance[:, r0:r0 + COLOUR_BLOCK_ROWS], white_level=white_level)

    return np.concatenate(parallel_map(colour, range(0, ny, COLOUR_BLOCK_ROWS), min(threads(), 8)), axis=0)




def image_dataset(radiance, rgb, planes, cam, *, camera, settings, sampling, sun, sun_enu_observer, scene, observer,
                   reference, exposure, aerosol, march, transmittances) -> xr.Dataset:
    """:func:`render`'s image: the radiance planes (``radiance`` (3, ny, nx) and the other ``planes``), the sRGB codes
    ``rgb`` (ny, nx, 3) and the view angles of the camera ``cam`` (kind ``camera``) as CF variables, with the render's
    attributes: the sun (``sun``, and ``sun_enu_observer`` its direction at the observer), the ``scene``'s title,
    source and time, the ``observer`` (lat, lon [deg], height above the ground and above sea level [m]), the scene's
    ``reference`` point (lat, lon [deg]), the ``exposure`` (white level, whether automatic, shift [EV]), the
    ``aerosol``, the ``march`` (samples, traced pixels, the scene's coarsening), the sun's direct and circumsolar
    ``transmittances`` (3,) and the ``settings`` and ``sampling``; and the time as a scalar coordinate (CF 4.4)."""
    lat, lon, height, height_asl = observer
    lat0, lon0 = reference
    white_level, auto_exposure, exposure = exposure
    march_samples, traced_pixels, coarsened_by = march
    t_direct, t_aureole = transmittances
    # float32 copies (the output is the caller's; the cached angles are read-only): no second copy below
    view_az, view_zen = (np.array(a, dtype=np.float32) for a in cam.cached_view_angles())
    sun_az_obs, sun_zen_obs = azimuth_zenith_from_enu(sun_enu_observer)

    dims3 = ("wavelength", "y", "x")
    data = {
        "radiance": (dims3, radiance.astype(np.float32, copy=False), {
            "units": "1", "long_name": "solar-relative spectral radiance L' = 4 pi L / E_TOA (Albers et al. 2020, Eq. 2)"}),
        "radiance_clear": (dims3, planes.pop("radiance_clear").astype(np.float32, copy=False), {"units": "1", "long_name": "gas and aerosol part of L'"}),
        "radiance_cloud": (dims3, planes.pop("radiance_cloud").astype(np.float32, copy=False), {"units": "1", "long_name": "hydrometeor part of L'"}),
        "radiance_surface": (dims3, planes.pop("radiance_surface").astype(np.float32, copy=False), {"units": "1", "long_name": "ground part of L'"}),
        "tau_hydrometeor": (("y", "x"), planes.pop("tau_hydrometeor")[0].astype(np.float32, copy=False), {
            "units": "1", "long_name": "hydrometeor optical depth along the line of sight",
            "comment": (f"rays that do not look down stop where it passes {settings.stop_tau:g} (opaque): there it "
                        f"is {settings.stop_tau:g}, a lower bound") if settings.stop_tau
                       else "the whole line of sight"}),
        "rgb": (("y", "x", "channel"), rgb, {"units": "1", "long_name": "true-colour image, 8-bit sRGB codes",
                                             "comment": "display transform: see the display_transform, white_level "
                                                        "and exposure attributes; the radiance does not depend on it"}),
        "view_azimuth": (("y", "x"), view_az, {"units": "degree", "standard_name": "sensor_azimuth_angle",
                                               "long_name": "view azimuth, clockwise from north"}),
        "view_zenith": (("y", "x"), view_zen, {"units": "degree", "standard_name": "sensor_zenith_angle",
                                              "long_name": "view zenith angle"}),
    }
    attrs = {
        "title": f"SWIm {camera} image",
        "institution": "swim-imagery",
        "source": f"swim {__version__}",
        "references": "Albers et al. (2020), Atmos. Meas. Tech. 13, 3235-3261, doi:10.5194/amt-13-3235-2020",
        "history": f"{datetime.now(timezone.utc).isoformat(timespec='seconds')} rendered by swim {__version__}",
        "scene_title": str(scene.attrs.get("title", "")),
        "scene_source": str(scene.attrs.get("source", "")),
        # the model time whose fields were rendered (a series' frame may lie up to 90 min from it)
        "scene_time": pd.Timestamp(scene["time"].values).isoformat() if "time" in scene.coords else "",
        "time": "" if sun.time is None else pd.Timestamp(sun.time).isoformat(),
        "sun_zenith_deg": float(sun_zen_obs),
        "sun_azimuth_deg": float(sun_az_obs),
        "sun_zenith_reference_deg": float(sun.zenith_deg),
        "sun_azimuth_reference_deg": float(sun.azimuth_deg),
        "sun_source": sun.source,
        "earth_sun_distance_au": float(sun.earth_sun_distance_au),
        # E_TOA [W m-2 nm-1] at the three wavelengths: absolute radiance L = L' E_TOA / (4 pi) (write_netcdf writes it)
        "toa_spectral_irradiance": SOLAR_SPECTRAL_IRRADIANCE_W_M2_NM / float(sun.earth_sun_distance_au) ** 2,
        "direct_transmittance": np.asarray(t_direct, dtype=float),
        "circumsolar_transmittance": np.asarray(t_aureole, dtype=float),
        "cloud_scattering": settings.cloud_scattering.method,
        "observer_lat": lat,
        "observer_lon": lon,
        "observer_height_above_ground_m": float(height),
        "observer_height_asl_m": float(height_asl),
        "reference_lat": lat0,
        "reference_lon": lon0,
        "white_level": float(white_level),
        "exposure": "auto" if auto_exposure else "fixed",
        "exposure_ev": float(exposure),
        "display_transform": "filmic",
        "aerosol_type": aerosol.type_name,
        "aerosol_optical_depth_550": float(aerosol.aod_550),
        "aerosol_scale_height_m": float(aerosol.scale_height_m),
        "aerosol_single_scattering_albedo": np.asarray(aerosol.type.ssa, dtype=float),
        "aerosol_asymmetry_parameter": np.asarray(aerosol.type.asymmetry_parameter(), dtype=float),
        "aerosol_angstrom_exponent": float(aerosol.type.angstrom_exponent),
        "ozone_column_du": float(aerosol.ozone_du),
        "camera": camera,
        "march_samples": march_samples,
        "traced_pixels": traced_pixels,
        "march_backend": settings.resolved_backend(),
        "scene_coarsened_by": coarsened_by,
        "sampling": "every pixel" if sampling is None else (
            f"adaptive (tolerance {sampling.tolerance:g}, coarse spacing {sampling.coarse_spacing}, "
            f"radiance floor {sampling.radiance_floor:g}, tau tolerance {sampling.tau_tolerance:g}, "
            f"tau floor {sampling.tau_floor:g}, clear tolerance {sampling.clear_tolerance:g}, "
            f"edge tests in cells of {sampling.edge_test_size} pixels)"),
        "Conventions": "CF-1.8",
    }
    attrs.update(cam.to_attrs())  # keys start with "camera_"
    attrs.update(settings_attributes(settings))  # keys start with "settings_"
    image = xr.Dataset(data, coords=image_coordinates(), attrs=attrs)
    when = sun.time if sun.time is not None else (scene["time"].values if "time" in scene.coords else None)
    if when is not None:  # a scalar time coordinate (CF 4.4): the sun's time, else the scene's
        image = image.assign_coords(time=xr.Variable((), to_utc_datetime64(when),
                                                     {"standard_name": "time", "long_name": "time of the image (UTC)"}))
    return image



@functools.lru_cache(maxsize=1)
def image_coordinates() -> xr.Coordinates:
    """The coordinates of every image of :func:`render` (wavelength [nm], channel), with their indexes made once:
    making them took half of the output Dataset's ~0.3 ms. A Dataset copies the variables' attributes, and the
    indexes' values are read-only, so images that share them cannot change one another's."""
    return xr.Coordinates({"wavelength": xr.Variable("wavelength", np.asarray(WAVELENGTHS_NM, dtype=float),
                                                     {"units": "nm", "standard_name": "radiation_wavelength",
                                                      "long_name": "wavelength"}),
                           "channel": ["R", "G", "B"]})

