"""Validation against independent reference solvers: DISORT plane-parallel clear sky and stratus."""

from .disort import (
    clear_sky_layers,
    cloud_layer_layers,
    disort_clear_sky_irradiance,
    disort_cloud_layer_irradiance,
    disort_cloud_layer_radiance,
    disort_clear_sky_radiance,
)

__all__ = [
    "clear_sky_layers",
    "cloud_layer_layers",
    "disort_cloud_layer_irradiance",
    "disort_cloud_layer_radiance",
    "disort_clear_sky_irradiance",
    "disort_clear_sky_radiance",
]
