"""SWIm: Simulated Weather Imagery, a fast visible-light 3D radiative transfer renderer for NWP output.

Physics after Albers et al. (2020), Atmos. Meas. Tech. 13, 3235-3261, doi:10.5194/amt-13-3235-2020.

Public API: :func:`open_scene`, :func:`default_scene`, :func:`scene_from_arrays`, :func:`render`,
:func:`write_image`, :func:`write_png`, :func:`write_netcdf`, :class:`AerosolBackground` (1-D and stratospheric aerosol),
:class:`MarchSettings` with its :class:`ExecutionSettings`, :func:`sky_irradiance` (GHI/DHI/DNI from an all-sky image),
:func:`forward_operator` (differentiable images of the hydrometeors and aerosol: tangent-linear, adjoint, gradients).
"""

import logging
from importlib.util import find_spec

if find_spec("pyproj") is not None:
    # PROJ's bundled libraries must load before ecCodes' (eccodeslib wheels), which xarray loads whenever it guesses
    # a file's engine (cfgrib's backend): the other way round pyproj finds no database and the process aborts at exit.
    # xwrf imports pyproj, so a WRF dataset post-processed by xwrf after any file was opened would crash (~80 ms).
    import pyproj  # noqa: F401

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())

_API = {
    "open_scene": "swim.io.scene",
    "scene_from_arrays": "swim.io.scene",
    "validate_scene": "swim.io.scene",
    "default_scene": "swim.io.default_scene",
    "read_wrf": "swim.io.wrf",
    "as_scene": "swim.io.scene",
    "read_ecmwf": "swim.io.ecmwf",
    "read_ncep_grib": "swim.io.grib_ncep",
    "read_icon": "swim.io.icon",
    "read_mpas": "swim.io.unstructured",
    "read_shdom_les": "swim.io.les",
    "render": "swim.pipeline",
    "write_image": "swim.io.outputs",
    "write_png": "swim.io.outputs",
    "write_netcdf": "swim.io.outputs",
    "render_series": "swim.series",
    "series_times": "swim.series",
    "AerosolBackground": "swim.rt.gas",
    "MarchSettings": "swim.rt.march_settings",
    "ExecutionSettings": "swim.rt.march_settings",
    "sky_irradiance": "swim.diagnostics.irradiance",
    "compare_images": "swim.diagnostics.compare",
    "reflectance_factor": "swim.diagnostics.satellite",
    "FisheyeCameraModel": "swim.geometry.fisheye",
    "forward_operator": "swim.assimilation",
    "ForwardOperator": "swim.assimilation",
    "Observer": "swim.assimilation",
}

__all__ = sorted(_API) + ["__version__"]


def __getattr__(name):
    # Lazy imports keep `import swim` light (JAX is loaded only when rendering).
    if name in _API:
        import importlib

        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module 'swim' has no attribute {name!r}")
