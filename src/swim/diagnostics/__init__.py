"""Forward-operator diagnostics computed from rendered images.

Irradiance from all-sky images (:mod:`.irradiance`) and its broadband conversion and time series
(:mod:`.broadband`, :mod:`.ghi`), comparison with camera images (:mod:`.compare`, Eq. 37),
cloud masks and categorical scores (:mod:`.cloud_mask`), reflectance factors of views from space
(:mod:`.satellite`).
"""

from .broadband import broadband_irradiance
from .cloud_mask import categorical_scores, cloud_mask, compare_cloud_masks, contingency_table
from .compare import compare_images, pearson_r, reproject, scores_dict, write_difference_png
from .ghi import ghi_time_series
from .irradiance import allsky_camera_of, irradiance_w_m2, sky_irradiance
from .satellite import geostationary_view, nadir_view, reflectance_factor

__all__ = [
    "allsky_camera_of",
    "broadband_irradiance",
    "categorical_scores",
    "cloud_mask",
    "compare_cloud_masks",
    "compare_images",
    "contingency_table",
    "geostationary_view",
    "ghi_time_series",
    "irradiance_w_m2",
    "nadir_view",
    "pearson_r",
    "reflectance_factor",
    "reproject",
    "scores_dict",
    "sky_irradiance",
    "write_difference_png",
]
