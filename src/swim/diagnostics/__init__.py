"""Forward-operator diagnostics computed from rendered images (issue 5): irradiance from all-sky images."""

from .irradiance import allsky_camera_of, irradiance_w_m2, sky_irradiance

__all__ = ["allsky_camera_of", "irradiance_w_m2", "sky_irradiance"]
