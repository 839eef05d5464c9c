"""The views of the golden-image regression tests: small renders of the built-in scene on the CPU's numba kernel.

Shared by tests/regression/test_golden_images.py and scripts/make_golden_images.py, which regenerates the stored
images.
"""

from __future__ import annotations

import swim
from swim.rt.march_settings import ExecutionSettings, MarchSettings

#: name -> (render keywords, march settings keywords). The sun is set by angles so that no ephemeris or clock enters.
#: One view of the default 3-D cloud scattering (its diffuse solution costs seconds), the others the paper's method.
VIEWS = {
    "allsky_3d": ({"camera": "allsky", "camera_options": {"size": 48}, "sun_zenith": 40.0, "sun_azimuth": 150.0},
                  {}),
    "allsky_albers2020": ({"camera": "allsky", "camera_options": {"size": 48}, "sun_zenith": 40.0,
                           "sun_azimuth": 150.0}, {"cloud_scattering": "albers2020"}),
    "perspective_towards_the_sun": ({"camera": "perspective",
                                     "camera_options": {"width": 64, "height": 32, "fov_deg": 90.0,
                                                        "view_azimuth_deg": 150.0, "view_zenith_deg": 70.0},
                                     "sun_zenith": 40.0, "sun_azimuth": 150.0}, {"cloud_scattering": "albers2020"}),
}


def render_view(name):
    """The rendered dataset of the view ``name`` of :data:`VIEWS` (numba backend)."""
    from swim.io.default_scene import default_scene

    kwargs, settings = VIEWS[name]
    return swim.render(default_scene(), settings=MarchSettings(**settings,
                                                               execution=ExecutionSettings(backend="numba")), **kwargs)
