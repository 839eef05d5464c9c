"""A rendered image written to files: PNG, JPEG or TIFF (8-bit sRGB, :func:`write_image`) and CF netCDF
(:func:`write_netcdf`), each atomically (:mod:`swim.io.atomic`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from ..errors import SwimInputError
from .atomic import atomic_write


#: Image files by suffix: Pillow's format name and its options.
IMAGE_FORMATS = {".png": ("PNG", {}), ".jpg": ("JPEG", {"quality": 95}), ".jpeg": ("JPEG", {"quality": 95}),
                 ".tif": ("TIFF", {"compression": "tiff_deflate"}), ".tiff": ("TIFF", {"compression": "tiff_deflate"})}



def image_format(path, what="image file"):
    """Pillow's format name and options for an image file ``path`` by its suffix (:data:`IMAGE_FORMATS`).

    Raises
    ------
    SwimInputError
        If the suffix is not that of a format swim writes.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in IMAGE_FORMATS:
        raise SwimInputError(f"{what} {path}: unknown image format {suffix or '(no suffix)'!r}; use "
                             f"{', '.join(sorted(IMAGE_FORMATS))}")
    return IMAGE_FORMATS[suffix]



def _image_text(image: xr.Dataset) -> dict:
    """What an image file says about itself: software, time, place, camera and sun (PNG text chunks)."""
    a = image.attrs
    where = (f"observer {a.get('observer_lat', float('nan')):.4f} N {a.get('observer_lon', float('nan')):.4f} E, "
             f"{a.get('observer_height_above_ground_m', float('nan')):g} m above ground")
    text = {"Software": str(a.get("source", "swim")), "Title": str(a.get("title", "SWIm image")),
            "Description": f"{a.get('camera', '')} camera; {where}; sun zenith {a.get('sun_zenith_deg', float('nan')):.2f} "
                           f"deg, azimuth {a.get('sun_azimuth_deg', float('nan')):.2f} deg; cloud scattering "
                           f"{a.get('cloud_scattering', '')}; scene: {a.get('scene_title', '')}",
            "Source": str(a.get("scene_source", "")), "Comment": str(a.get("references", ""))}
    if a.get("time"):
        text["Creation Time"] = str(a["time"])
    return text



def _rgb(image, caller):
    rgb = image.get("rgb") if isinstance(image, xr.Dataset) else None
    if rgb is None or rgb.ndim != 3 or rgb.shape[-1] != 3 or rgb.dtype != np.uint8:
        raise SwimInputError(f"{caller}: image must be a rendered image (swim.render) with an 'rgb' variable of "
                             "(rows, columns, 3) 8-bit sRGB values")
    return np.asarray(rgb.values, dtype=np.uint8)



def write_image(image: xr.Dataset, path) -> Path:
    """Write the ``rgb`` of a rendered image as an 8-bit sRGB image file (atomically), in the format of the path's
    suffix: PNG (with text chunks: software, time, place, camera, sun), JPEG (quality 95) or TIFF (deflate).

    Raises
    ------
    SwimInputError
        If ``image`` is not a rendered image (no ``rgb`` of (rows, columns, 3) 8-bit values), the suffix is not one
        of :data:`IMAGE_FORMATS`, or the file cannot be written there (:func:`swim.io.atomic.check_output_path`).
    """
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    rgb = _rgb(image, "write_image")
    kind, options = image_format(path)
    options = dict(options)
    if kind == "PNG":
        info = PngInfo()
        for key, value in _image_text(image).items():
            info.add_itxt(key, value)
        options["pnginfo"] = info
    atomic_write(Path(path), lambda tmp: Image.fromarray(rgb, "RGB").save(tmp, format=kind, **options))
    return Path(path)



def write_png(image: xr.Dataset, path) -> Path:
    """Write the ``rgb`` of a rendered image as an 8-bit sRGB PNG (atomically; :func:`write_image`).

    Raises
    ------
    SwimInputError
        If ``image`` is not a rendered image (no ``rgb`` of (rows, columns, 3) 8-bit values), or ``path`` names
        another format than PNG (:func:`write_image` writes JPEG and TIFF).
    """
    _rgb(image, "write_png")
    if Path(path).suffix.lower() != ".png":
        raise SwimInputError(f"write_png: {path} is not a .png file (write_image writes JPEG and TIFF by suffix)")
    return write_image(image, path)



def write_netcdf(image: xr.Dataset, path) -> Path:
    """Write a rendered image as CF-style netCDF-4 (atomically); radiance is compressed float32."""
    atomic_write(Path(path), lambda tmp: _netcdf_to(image, tmp))
    return Path(path)



def with_absolute_radiance(image: xr.Dataset) -> xr.Dataset:
    """The image with ``radiance_absolute`` [W m-2 sr-1 nm-1] = L' E / (4 pi), E its ``toa_spectral_irradiance``
    attribute (the light's spectral irradiance at the top of the atmosphere [W m-2 nm-1] at each wavelength); the
    image as it is where it has no such attribute or already has the variable."""
    e = image.attrs.get("toa_spectral_irradiance")
    if e is None or "radiance_absolute" in image or "radiance" not in image:
        return image
    e = xr.DataArray(np.asarray(e, dtype=np.float64).reshape(-1), dims="wavelength")
    absolute = (image["radiance"] * (e / (4.0 * np.pi))).astype(np.float32)
    absolute.attrs = {"units": "W m-2 sr-1 nm-1", "long_name": "spectral radiance L = L' E_TOA / (4 pi)",
                      "comment": "E_TOA: the toa_spectral_irradiance attribute (W m-2 nm-1 at each wavelength)"}
    return image.assign(radiance_absolute=absolute)


def cf_dataset(image: xr.Dataset) -> xr.Dataset:
    """A rendered image as written to netCDF (CF-1.8): the ``channel`` labels as a character variable
    ``channel_name`` (CF 6.1.1 labels; CF 2.2 allows no variable-length strings) instead of a string coordinate."""
    if "channel" in image.coords and image["channel"].dtype.kind in "OUS":
        names = np.asarray(image["channel"].values).astype("S1")
        image = image.drop_vars("channel").assign_coords(
            channel_name=xr.Variable("channel", names, {"long_name": "colour channel of rgb (R, G, B)"}))
    return image



def _netcdf_to(image, tmp):
    image = cf_dataset(with_absolute_radiance(image))
    encoding = {name: {"zlib": True, "complevel": 4} for name in image.data_vars}
    if "channel_name" in image.coords:
        encoding["channel_name"] = {"dtype": "S1"}
    image.to_netcdf(tmp, format="NETCDF4", encoding=encoding)



def write_outputs(image: xr.Dataset, image_path=None, netcdf_path=None):
    """Write a rendered image's image file (:func:`write_image`) and netCDF file (:func:`write_netcdf`), each where
    given, both or neither: the netCDF file is written to a temporary file, the image put in place, and only then
    the netCDF file, so that an error leaves neither new file (and an image is never left without its netCDF)."""
    if netcdf_path is None:
        if image_path is not None:
            write_image(image, image_path)
        return
    if image_path is not None:
        image_format(image_path)

    def both(tmp):
        _netcdf_to(image, tmp)
        if image_path is not None:
            write_image(image, image_path)

    atomic_write(Path(netcdf_path), both)

