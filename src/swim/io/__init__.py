"""swim.io: scene input.

The canonical scene format (``docs/scene-format.md``), its validation, readers for WRF output (raw or through
xwrf), WPS ``geo_em``/``met_em`` files (clear-sky scenes), NCEP GFS, HRRR and RAP GRIB output, ECMWF ERA5/IFS
output on pressure and model levels, ICON and MPAS output (regridded from their meshes) and SHDOM-style LES text
files, SURFRAD/BSRN/MIDC radiation observations, a numpy-array helper and the built-in default scene.
"""

from .default_scene import default_scene
from .ecmwf import read_ecmwf, read_era5_pressure_levels, read_ifs_model_levels
from .globe import hemisphere_scene, l1_view, read_gfs_global_columns, sub_solar_point
from .grib import grib_reader_for, read_gfs_grib
from .grib_ncep import read_ncep_grib
from .icon import read_icon
from .les import read_shdom_les
from .observations import read_observations
from .scene import as_scene, layer_thickness, open_scene, scene_from_arrays, validate_scene
from .surfrad import read_surfrad
from .unstructured import read_mpas
from .wps import read_wps_geogrid
from .wrf import read_wrf

__all__ = [
    "as_scene",
    "default_scene",
    "read_ecmwf",
    "read_era5_pressure_levels",
    "read_ifs_model_levels",
    "grib_reader_for",
    "hemisphere_scene",
    "l1_view",
    "read_gfs_global_columns",
    "sub_solar_point",
    "read_gfs_grib",
    "read_ncep_grib",
    "read_icon",
    "read_mpas",
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
