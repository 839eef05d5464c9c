"""swim.geometry: cameras (pixel <-> view direction) and the sun position.

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
    make_camera,
)
from .fisheye import FISHEYE_PROJECTIONS, FisheyeCameraModel, OrientationFit, detect_sun, fit_orientation_from_sun
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
    "SunPosition",
    "parse_time_utc",
    "sun_from_angles",
    "sun_position",
]
