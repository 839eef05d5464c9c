"""The march's one entry point, :func:`march`: a camera's rays and the kernel tables in, the image's planes out.

Each backend is a module with a function ``march(rays, tables, settings, *, progress, white_level)``, chosen by the
resolved :attr:`swim.rt.march_settings.ExecutionSettings.backend`:

========== ================================ =====================================================================
backend    module                           how
========== ================================ =====================================================================
"numba"    :mod:`swim.rt.backends.host`     rays made on the host, marched by the numba kernel on the CPU's cores
                                            (:mod:`swim.rt.march_cpu`) in chunks (:func:`swim.rt.march.trace_rays`)
"jax"      :mod:`swim.rt.backends.device`   the JAX kernel (:mod:`swim.rt.march_jax`, :mod:`swim.rt.march_pallas`);
                                            where the camera's rays are kept on the device
                                            (:attr:`~swim.rt.march_settings.ExecutionSettings.ray_table`) the
                                            image's planes and colour are made there too, else as "numba"'s
========== ================================ =====================================================================

A backend's module is imported when it is first used: a numba render never imports JAX
(docs/decisions/0011-jax-only-where-it-runs.md). The float64 reference (:mod:`swim.rt.reference`) and the JAX
lockstep kernel are the oracles the tests hold the others to.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field

import numpy as np

from ..kernel_tables import KernelTables
from ..march_settings import MarchSettings

#: The backends' modules by :attr:`swim.rt.march_settings.ExecutionSettings.backend` (resolved).
BACKEND_MODULES = {"numba": "swim.rt.backends.host", "jax": "swim.rt.backends.device"}
#: The outputs of the march that become the image's planes.
IMAGE_OUTPUTS = ("radiance", "radiance_clear", "radiance_cloud", "radiance_surface", "tau_hydrometeor")


@dataclass(frozen=True, eq=False)
class CameraRays:
    """A camera's rays in the scene frame, and how its image is sampled.

    Attributes
    ----------
    observer : numpy.ndarray
        Shape (3,): where every ray starts, in the scene frame [m].
    directions : numpy.ndarray
        Shape (ny * nx, 3): the pixels' unit view directions in the scene frame (zeros where not valid).
    valid_pixels : numpy.ndarray
        Shape (n,) int: the flat indices of the pixels that have a ray, in tile order
        (:func:`swim.rt.image_sampling.tile_order`).
    valid : numpy.ndarray
        Shape (ny, nx) bool: the pixels that have a ray.
    sampling : swim.rt.image_sampling.AdaptiveSampling or None
        Adaptive sampling (:func:`swim.rt.image_sampling.sample_image_adaptive`), or None: every valid pixel.
    description : str
        The camera, for the log (e.g. "allsky camera (255, 255)").
    """

    observer: np.ndarray
    directions: np.ndarray
    valid_pixels: np.ndarray
    valid: np.ndarray
    sampling: object = None
    description: str = "camera"

    @property
    def shape(self) -> tuple:
        """The image's (ny, nx) [pixels]."""
        return self.valid.shape


@dataclass
class MarchedImage:
    """What :func:`march` returns.

    Attributes
    ----------
    planes : dict of numpy.ndarray
        The image's planes (C, ny, nx) of :data:`IMAGE_OUTPUTS` (C = 3 wavelengths, or 1), NaN at pixels without a ray.
    sun : dict
        The outputs of one extra ray from the observer towards the sun (``tau_clear`` (3,), ``tau_hydrometeor``,
        ``tau_narrow`` with the 3-D cloud scattering, ``surface``, ``steps``): the sun's disk's transmittance.
    traced : numpy.ndarray
        Shape (ny * nx,) bool: the pixels whose ray was marched.
    samples : int
        The volume samples the march took for the camera's rays (:func:`swim.rt.march.trace_rays`' ``steps``).
    rgb : tuple or None
        Where the colour stage ran on the device: its 8-bit codes (ny, nx, 3) and the pixels it left to the host
        (ny, nx) bool; else None.
    """

    planes: dict
    sun: dict
    traced: np.ndarray
    samples: int
    rgb: tuple | None = field(default=None)


def march(rays: CameraRays, tables: KernelTables, settings: MarchSettings, *, progress=None,
          white_level=None) -> MarchedImage:
    """March a camera's rays through the kernel tables with the backend of ``settings``.

    Parameters
    ----------
    rays : CameraRays
        The camera's rays and its sampling.
    tables : KernelTables
        The scene's, sun's and atmosphere's tables.
    settings : MarchSettings
        The march's settings; its :attr:`~MarchSettings.execution` chooses the backend ("auto" resolved here if it
        was not before, :meth:`MarchSettings.resolved`).
    progress : callable, optional
        Called with (rays done, rays total).
    white_level : float, optional
        The display's white level [-] where the colour stage may run where the march ran (the JAX kernel's
        :attr:`~swim.rt.march_settings.ExecutionSettings.device_image`); None: the caller colours the image.

    Returns
    -------
    MarchedImage

    Raises
    ------
    SwimInputError
        If the backend cannot run here (numba not installed).
    """
    module = importlib.import_module(BACKEND_MODULES[settings.resolved_backend()])
    return module.march(rays, tables, settings, progress=progress, white_level=white_level)
