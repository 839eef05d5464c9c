"""swim.geometry: cameras (pixel <-> view direction), the sun position, and the level of detail of distant views.

Conventions: :mod:`swim.frames` and ``docs/frames.md``.
"""

from .cameras import (
    CAMERA_KINDS,
    AllSkyCamera,
    Camera,
    PanoramaCamera,
    PerspectiveCamera,
    fov_to_fit,
    look_at_angles,
    check_camera_options,
    make_camera,
)
from .fisheye import FISHEYE_PROJECTIONS, FisheyeCameraModel, OrientationFit, detect_sun, fit_orientation_from_sun
from .level_of_detail import METHODS as COARSEN_METHODS
from .level_of_detail import coarsen_scene, coarsening_factor
from .sun import SunPosition, parse_time_utc, sun_from_angles, sun_position

__all__ = [
    "CAMERA_KINDS",
    "FISHEYE_PROJECTIONS",
    "FisheyeCameraModel",
    "OrientationFit",
    "detect_sun",
    "fit_orientation_from_sun",
    "AllSkyCamera",
    "Camera",
    "PanoramaCamera",
    "PerspectiveCamera",
    "fov_to_fit",
    "look_at_angles",
    "make_camera",
    "check_camera_options",
    "COARSEN_METHODS",
    "coarsen_scene",
    "coarsening_factor",
    "SunPosition",
    "parse_time_utc",
    "sun_from_angles",
    "sun_position",
]
