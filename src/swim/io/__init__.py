"""swim.io: scene input.

The canonical scene format (``docs/scene-format.md``), its validation, readers for WRF output, WPS
``geo_em``/``met_em`` files (clear-sky scenes), NCEP GFS GRIB output and SHDOM-style LES text files,
SURFRAD/BSRN/MIDC radiation observations, a numpy-array helper and the built-in default scene.
"""

from .default_scene import default_scene
from .grib import read_gfs_grib
from .les import read_shdom_les
from .observations import read_observations
from .scene import layer_thickness, open_scene, scene_from_arrays, validate_scene
from .surfrad import read_surfrad
from .wps import read_wps_geogrid
from .wrf import read_wrf

__all__ = [
    "default_scene",
    "read_gfs_grib",
    "layer_thickness",
    "open_scene",
    "read_observations",
    "read_shdom_les",
    "read_surfrad",
    "read_wps_geogrid",
    "read_wrf",
    "scene_from_arrays",
    "validate_scene",
]
