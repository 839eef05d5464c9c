"""Irradiance at the observer from a rendered all-sky image (paper Sect. 3.1).

With the solar-relative radiance of the paper's Eq. 2, ``L' = 4 pi L / E_TOA``, the irradiance on a horizontal
surface relative to the TOA solar irradiance at normal incidence is

    E / E_TOA = (1 / 4 pi) int_{upper hemisphere} L' cos(zenith) dOmega.

:func:`sky_irradiance` evaluates this integral over an image rendered with ``swim.render(...,
camera="allsky")``, pixel by pixel with the exact projected solid angle of each pixel
(:meth:`swim.geometry.cameras.AllSkyCamera.pixel_solid_angles`), for the **diffuse** sky only (the sun's disk
is not a pixel quantity: a pixel is far larger than the disk), and adds the direct beam explicitly from the
transmittance of the ray towards the sun that :func:`swim.render` traces (attribute
``direct_transmittance``):

* DNI / E_TOA = T_direct (direct normal irradiance),
* DHI / E_TOA = (1 / 4 pi) sum_pixels L'_sky cos(zenith) dOmega (diffuse horizontal irradiance),
* GHI / E_TOA = DHI / E_TOA + mu0 T_direct (global horizontal irradiance), mu0 = cos(sun zenith).

All three per wavelength (615, 546, 450 nm). An isotropic sky L' = const gives DHI / E_TOA = L' / 4.

Conversion to W m-2 (:func:`irradiance_w_m2`) is the paper's monochromatic proxy (Sect. 3.1): the broadband
irradiance is taken proportional to the relative irradiance at 546 nm, E = (E / E_TOA)_546 x S / r^2 with
the solar constant S = 1362 W m-2 and the sun-earth distance r [AU]. The spectrally corrected conversion, with
the gaseous absorption swim lacks, is :func:`swim.diagnostics.broadband.broadband_irradiance`.
"""

from __future__ import annotations

import logging

import numpy as np
import xarray as xr

from ..constants import SOLAR_CONSTANT_W_M2, SUN_ANGULAR_RADIUS_RAD, WAVELENGTHS_NM
from ..errors import SwimInputError
from ..geometry.cameras import AllSkyCamera

log = logging.getLogger(__name__)

__all__ = ["allsky_camera_of", "sky_irradiance", "irradiance_w_m2"]

#: Index of the 546 nm channel, the paper's reference for broadband irradiance (Sect. 3.1).
GREEN_INDEX = int(np.argmin(np.abs(WAVELENGTHS_NM - 546.0)))


def allsky_camera_of(image: xr.Dataset) -> AllSkyCamera:
    """The :class:`~swim.geometry.cameras.AllSkyCamera` that rendered ``image`` (from its attributes).

    Raises
    ------
    SwimInputError
        If the image was not rendered with an all-sky camera.
    """
    kind = image.attrs.get("camera_kind", image.attrs.get("camera"))
    if kind != "allsky":
        raise SwimInputError(f"sky irradiance needs an all-sky image (camera='allsky'); this one is {kind!r}")
    size = int(image.attrs.get("camera_size", image.sizes["x"]))
    max_zenith = float(image.attrs.get("camera_max_zenith_deg", 90.0))
    return AllSkyCamera(size=size, max_zenith_deg=max_zenith)


_COMPONENTS = ("radiance_clear", "radiance_cloud", "radiance_surface")


def radiance_without_sun_disk(image: xr.Dataset) -> np.ndarray:
    """Radiance L' of a :func:`swim.render` image without the sun's disk, shape (3, ny, nx) [-], NaN -> 0.

    The sum of the clear-sky, cloud and surface components, which carry no sun disk (:func:`swim.render`
    adds the disk to ``radiance`` only).

    Raises
    ------
    KeyError
        If the image lacks one of the components.
    """
    total = 0
    for key in _COMPONENTS:  # on the numpy arrays: xarray's fillna and sums took ~2.5 ms of a 41 x 41 render's 30
        values = image.variables[key].values  # the Variable: a DataArray is made in ~40 us
        total = total + np.where(np.isnan(values), values.dtype.type(0), values)
    return np.asarray(total, dtype=float)


def _diffuse_sky(image: xr.Dataset, sun_exclusion_deg):
    """Sky radiance without the sun's disk (3, ny, nx), NaN -> 0."""
    if all(k in image for k in _COMPONENTS):
        return radiance_without_sun_disk(image)
    # Only the total: replace the pixels of the disk by the median of a ring around it.
    sky = np.nan_to_num(np.asarray(image["radiance"].values, dtype=float))
    sz, sa = np.radians(float(image.attrs["sun_zenith_deg"])), np.radians(float(image.attrs["sun_azimuth_deg"]))
    vz, va = np.radians(image["view_zenith"].values.astype(float)), np.radians(image["view_azimuth"].values.astype(float))
    cos_angle = np.cos(vz) * np.cos(sz) + np.sin(vz) * np.sin(sz) * np.cos(va - sa)
    angle = np.degrees(np.arccos(np.clip(np.nan_to_num(cos_angle, nan=-1.0), -1, 1)))
    radius = sun_exclusion_deg
    if radius is None:
        pitch = np.degrees(allsky_camera_of(image).radians_per_pixel)
        radius = 1.5 * max(np.degrees(SUN_ANGULAR_RADIUS_RAD), 0.75 * pitch)
    disk = angle <= radius
    ring = (angle > radius) & (angle <= 2 * radius)
    if disk.any():
        fill = np.median(sky[:, ring], axis=1) if ring.any() else np.zeros(sky.shape[0])
        sky[:, disk] = fill[:, None]
    return sky


def sky_irradiance(image: xr.Dataset, sun_exclusion_deg=None) -> xr.Dataset:
    """GHI, DHI and DNI relative to E_TOA from an all-sky image rendered by :func:`swim.render`.

    Parameters
    ----------
    image : xarray.Dataset
        Output of ``swim.render(..., camera="allsky")`` for an observer in the atmosphere: ``radiance``
        (wavelength, y, x) [1] (and, where present, its diffuse components ``radiance_clear``,
        ``radiance_cloud``, ``radiance_surface``, which carry no sun disk), ``view_zenith`` [deg], and the
        attributes ``direct_transmittance`` (3,) [1], ``sun_zenith_deg`` [deg] and the camera's.
    sun_exclusion_deg : float, optional
        Only used when the image has no components: radius [deg] about the sun whose pixels are replaced by
        the median of the ring out to twice the radius before the diffuse sum; default 1.5 x the disk radius
        that :func:`swim.render` paints (max(0.2665 deg, 0.75 pixel)).

    Returns
    -------
    xarray.Dataset
        Per ``wavelength`` [nm]: ``ghi``, ``dhi``, ``dni``, ``direct_horizontal`` (= mu0 DNI), all relative
        to the TOA solar irradiance at normal incidence [1]; attribute ``sun_zenith_deg``.

    Raises
    ------
    SwimInputError
        If the image is not an all-sky image covering the whole upper hemisphere, or lacks the attributes.
    """
    cam = allsky_camera_of(image)
    if cam.max_zenith_deg < 90.0 - 1e-9:
        raise SwimInputError(f"the all-sky image must reach the horizon (max_zenith_deg >= 90), got {cam.max_zenith_deg}")
    try:
        sun_zenith = float(image.attrs["sun_zenith_deg"])
        t_direct = np.broadcast_to(np.asarray(image.attrs["direct_transmittance"], dtype=float), (3,))
        # a moonlit image's radiance is relative to the sun's E_TOA: so is its direct beam, the moon's irradiance
        t_direct = t_direct * np.asarray(image.attrs.get("moon_irradiance_ratio", 1.0), dtype=float)
    except KeyError as err:
        raise SwimInputError(f"image lacks the attribute {err.args[0]!r} (render it with swim.render)") from None
    projected = cam.pixel_solid_angles(cosine_weighted=True)  # int cos(zenith) dOmega per pixel [sr]
    sky = _diffuse_sky(image, sun_exclusion_deg)
    # Rim pixels whose centre lies outside the image circle are not rendered (NaN) but part of them is sky:
    # they take the radiance of the nearest rendered pixel.
    rendered = np.isfinite(np.asarray(image["view_zenith"].values, dtype=float))
    if np.any(~rendered & (projected > 0)) and rendered.any():
        from scipy.ndimage import distance_transform_edt

        _, (ri, ci) = distance_transform_edt(~rendered, return_indices=True)
        sky = sky[:, ri, ci]
    dhi = np.einsum("cyx,yx->c", sky, projected) / (4.0 * np.pi)
    mu0 = max(np.cos(np.radians(sun_zenith)), 0.0)
    direct_h = mu0 * t_direct
    wl = image["wavelength"].values if "wavelength" in image.coords else WAVELENGTHS_NM
    coords = {"wavelength": ("wavelength", wl, {"units": "nm"})}
    unit = {"units": "1"}
    return xr.Dataset(
        {
            "ghi": ("wavelength", dhi + direct_h, {**unit, "long_name": "global horizontal irradiance / E_TOA"}),
            "dhi": ("wavelength", dhi, {**unit, "long_name": "diffuse horizontal irradiance / E_TOA"}),
            "dni": ("wavelength", t_direct.copy(), {**unit, "long_name": "direct normal irradiance / E_TOA"}),
            "direct_horizontal": ("wavelength", direct_h, {**unit, "long_name": "direct horizontal irradiance / E_TOA"}),
        },
        coords=coords,
        attrs={"sun_zenith_deg": sun_zenith,
               "earth_sun_distance_au": float(image.attrs.get("earth_sun_distance_au", 1.0)),
               # the render's ozone column, whose absorption its direct beam holds (0 for images without it)
               "ozone_column_du": float(image.attrs.get("ozone_column_du", 0.0))},
    )


def irradiance_w_m2(relative, earth_sun_distance_au=1.0, solar_constant_w_m2=SOLAR_CONSTANT_W_M2):
    """Monochromatic proxy of broadband irradiance [W m-2] from irradiance relative to E_TOA (paper Sect. 3.1).

    E = (E / E_TOA)_546 nm x S / r^2: the paper's assumption that broadband irradiance is proportional to the
    irradiance at 546 nm. Neglects the spectral difference between direct and diffuse light (the paper
    estimates -11 % of the diffuse part for a pure Rayleigh sky) and water-vapour absorption.

    Parameters
    ----------
    relative : xarray.Dataset, xarray.DataArray or array_like
        Relative irradiance [1]: a Dataset from :func:`sky_irradiance` (its 546 nm values are used, and its
        ``earth_sun_distance_au`` attribute), a DataArray with a ``wavelength`` dimension, or plain numbers
        taken to be at 546 nm.
    earth_sun_distance_au : float
        Sun-earth distance r [AU] (ignored for a Dataset that carries it).
    solar_constant_w_m2 : float
        S [W m-2] (paper: 1362).

    Returns
    -------
    Same kind as ``relative`` (without the wavelength dimension) [W m-2].
    """
    if isinstance(relative, xr.Dataset):
        r = float(relative.attrs.get("earth_sun_distance_au", earth_sun_distance_au))
        out = relative.isel(wavelength=GREEN_INDEX, drop=True) * (solar_constant_w_m2 / r**2)
        for name in out.data_vars:
            out[name].attrs = {"units": "W m-2", "long_name": relative[name].attrs.get("long_name", name).replace(
                " / E_TOA", "") + " (546 nm proxy)"}
        return out
    if isinstance(relative, xr.DataArray) and "wavelength" in relative.dims:
        relative = relative.isel(wavelength=GREEN_INDEX, drop=True)
    return relative * (solar_constant_w_m2 / float(earth_sun_distance_au) ** 2)
