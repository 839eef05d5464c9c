"""Synthetic observations for retrieval experiments: the observers' images of a "true" scene made by a different
forward model than the operator's, with noise.

:func:`synthetic_observations` renders the truth with the render's numba kernel (:func:`swim.rt.march.trace_rays`) at
finer settings than the operator's: the refined march (steps halved at cloud faces and in thick steps, ``tau_refine``),
the stop in opaque cloud, twice the grid steps, and its own step placement from the truth. The operator
(:class:`swim.assimilation.ForwardOperator`) runs the JAX march with a placement held fixed from another state and
neither refinement nor stop. Both compose clouds by the paper's Eqs. 12-26 (``cloud_scattering="albers2020"``), the
operator's physics. Gaussian noise, relative and absolute, stands in for a calibrated camera's.

References
----------
Albers et al. (2020), doi:10.5194/amt-13-3235-2020 (the forward model: Eqs. 2-26, 35).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import SwimInputError
from ..rt.march import trace_rays
from ..rt.march_settings import MarchSettings
from .setup import build_setup, ray_images

#: The observations' march: twice the default grid steps, refinement and the stop in opaque cloud as the render has
#: them, the paper's cloud composition (the operator's).
OBSERVATION_SETTINGS = MarchSettings(n_before=16, n_grid=256, n_after=40, cloud_scattering="albers2020")


def _host(value):
    """A kernel constant back on the host (numpy; dicts entry by entry)."""
    if isinstance(value, dict):
        return {key: np.asarray(v) for key, v in value.items()}
    return np.asarray(value)


def render_observer_images(scene, observers, *, sun_zenith, sun_azimuth, aerosol=None, settings=None):
    """The observers' radiance images of ``scene`` by the render's numba kernel at ``settings``.

    Parameters
    ----------
    scene : xarray.Dataset
        Canonical scene with ``cloud_liquid_content`` [kg m-3].
    observers : sequence of Observer
        The cameras (:class:`swim.assimilation.Observer`).
    sun_zenith, sun_azimuth : float
        The sun's zenith angle and azimuth [deg] at the scene's reference point.
    aerosol : AerosolBackground, optional
        The background aerosol.
    settings : MarchSettings, optional
        The march (default :data:`OBSERVATION_SETTINGS`); its cloud composition is set to "albers2020".

    Returns
    -------
    images : list of numpy.ndarray
        One (3, ny, nx) image per observer: L' (Eq. 2) at 615/546/450 nm [-], 0 at pixels without a ray.
    masks : list of numpy.ndarray
        One (ny, nx) bool array per observer: the pixels with a ray.
    """
    settings = replace(OBSERVATION_SETTINGS if settings is None else settings, cloud_scattering="albers2020")
    setup = build_setup(scene, observers, sun_zenith, sun_azimuth, aerosol)
    consts = {key: _host(value) for key, value in setup.consts.items()}
    geometry = setup.geometry
    radiance, left = [], setup.n_rays
    for chunk in setup.chunks:
        n = min(left, chunk["valid"].shape[0])
        left -= n
        # the chunk's rebased origins are relative to the ground under the reference point; the kernel's to the
        # earth's centre (swim.rt.march.ray_segments)
        origins = np.asarray(chunk["start"][:n], float) + [0.0, 0.0, float(consts["radius"])]
        rays = {key: np.asarray(value[:n]) for key, value in chunk["rays"].items()}
        out = trace_rays(origins, np.asarray(chunk["direction"][:n], float), consts, geometry, rays,
                         settings.with_execution(backend="numba"))
        radiance.append(np.asarray(out["radiance"], float))
    images = ray_images(setup, np.concatenate(radiance), 0.0)
    return images, [np.asarray(m, bool) for m in setup.masks]


def synthetic_observations(scene, observers, *, sun_zenith, sun_azimuth, relative_noise=0.01, absolute_noise=1e-3,
                           seed=0, aerosol=None, settings=None):
    """Observed images of a true scene: :func:`render_observer_images` plus Gaussian noise.

    Each pixel and channel's observation is L' (1 + relative_noise e1) + absolute_noise e2, e1 and e2 independent
    standard normal deviates (a calibrated camera's shot and read noise, in the units of L').

    Parameters
    ----------
    scene, observers, sun_zenith, sun_azimuth, aerosol, settings
        As :func:`render_observer_images`.
    relative_noise, absolute_noise : float
        Standard deviations [-] of the noise, >= 0.
    seed : int
        Seed of the noise's generator (numpy's default).

    Returns
    -------
    images : list of numpy.ndarray
        One (3, ny, nx) noisy image per observer [-], 0 at pixels without a ray.
    masks : list of numpy.ndarray
        One (ny, nx) bool array per observer: the pixels with a ray.

    Raises
    ------
    SwimInputError
        If a noise level is negative or not finite.
    """
    for name, value in (("relative_noise", relative_noise), ("absolute_noise", absolute_noise)):
        if not (np.isfinite(value) and value >= 0):
            raise SwimInputError(f"synthetic_observations: {name} must be a finite standard deviation >= 0 [-], "
                                 f"got {value!r}")
    images, masks = render_observer_images(scene, observers, sun_zenith=sun_zenith, sun_azimuth=sun_azimuth,
                                           aerosol=aerosol, settings=settings)
    rng = np.random.default_rng(seed)
    noisy = []
    for image, mask in zip(images, masks):
        e = rng.standard_normal((2,) + image.shape)
        noisy.append(np.where(mask, image * (1.0 + relative_noise * e[0]) + absolute_noise * e[1], 0.0))
    return noisy, masks
