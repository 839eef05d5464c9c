"""What the march reads for one scene, sun and atmosphere (:class:`KernelTables`), and the rays' phase functions.

The pipeline builds the tables once per scene and sun (:mod:`swim.pipeline.tables`) and hands them to
:func:`swim.rt.backends.march` with the camera's rays; every backend reads the same tables.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .clouds import cloud_ray_inputs
from .gas import AerosolBackground, phase_functions
from .march_inputs import GridGeometry


def ray_phase_functions(cos_theta, depolarization, aerosol_type, stratospheric_type):
    """Rayleigh (n,), aerosol and stratospheric aerosol (n, 3) phase functions [-] (mean 1 over the sphere;
    :func:`swim.rt.gas.phase_functions`) at the scattering-angle cosines ``cos_theta`` (n,), float32 numpy arrays."""
    return phase_functions(np.asarray(cos_theta, np.float32), np.float32(depolarization), aerosol_type,
                           stratospheric_type)


@dataclass(frozen=True, eq=False)
class KernelTables:
    """The kernels' inputs for one scene, sun and atmosphere.

    Attributes
    ----------
    constants : dict
        The kernels' arrays and scalars (:func:`swim.rt.march_inputs.volume_constants` and
        :func:`swim.rt.march_inputs.atmosphere_constants`, with the 3-D cloud scattering's
        :func:`swim.rt.clouds.cloud_constants`): the packed volume, Step 1a, the step classes, the ground, the clear
        air's tables.
    geometry : GridGeometry
        The grid's frame and spacing (:func:`swim.rt.march_inputs.grid_geometry`).
    gas : swim.rt.gas.GasTables
        The clear air's tables (:func:`swim.rt.gas.build_gas_tables`).
    aerosol : AerosolBackground
        The background aerosol, whose types give the rays' aerosol phase functions.
    sun_scene : numpy.ndarray
        Shape (3,): the unit direction towards the sun in the scene frame.
    cloud_optics : swim.optics.cloud_phase.CloudOptics or None
        The 3-D cloud scattering's optics (:func:`swim.rt.clouds.scene_cloud_optics`), or None for the paper's
        method (Eqs. 12-26).
    """

    constants: dict
    geometry: GridGeometry
    gas: object
    aerosol: AerosolBackground
    sun_scene: np.ndarray
    cloud_optics: object = None

    def phase(self, directions) -> dict:
        """The per-ray inputs of the kernels that depend on the rays' directions (n, 3) in the scene frame: the
        scattering angle's cosine ``cos_theta``, ``cos_view_zenith``, the phase functions ``p_rayleigh`` (n,),
        ``p_aerosol`` and ``p_stratospheric`` (n, 3), and with the 3-D cloud scattering its per-ray inputs
        (:func:`swim.rt.clouds.cloud_ray_inputs`). The ``ray_phase`` of :func:`swim.rt.march.trace_rays`."""
        cos_theta = directions @ self.sun_scene
        p_rayleigh, p_aerosol, p_stratospheric = ray_phase_functions(
            cos_theta, self.gas.depolarization, self.aerosol.type, self.aerosol.stratospheric)
        out = {"cos_theta": cos_theta, "cos_view_zenith": directions[:, 2], "p_rayleigh": p_rayleigh,
               "p_aerosol": p_aerosol, "p_stratospheric": p_stratospheric}
        if self.cloud_optics is not None:
            out.update(cloud_ray_inputs(directions, self.sun_scene, self.constants["cloud_species"], self.constants))
        return out
