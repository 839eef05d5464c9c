"""How the renderer scatters light in clouds: the settings and the render's constants of the method.

Two methods (``MarchSettings(cloud_scattering=...)``, CLI ``--cloud-scattering``):

* ``"discrete_ordinates"`` (the default): a 3-D solution of the diffuse radiance field for the scene and sun
  (:mod:`swim.rt.diffuse_field`), integrated along every camera ray as a source, with single scattering of the
  direct beam by the species' full phase functions (:mod:`swim.optics.cloud_phase`) and delta-M scaled
  attenuation (Nakajima and Tanaka 1988's TMS); cloud-ground interreflection included.
  docs/decisions/0001-cloud-diffuse-solution.md records why, and why it is the default.
* ``"albers2020"``: the paper's parameterisation (Eqs. 12-26: per-ray phase-function blends of thin and thick
  cloud, the cloud-top albedo seen from above), with the changes of docs/rendering.md ("Overcast accuracy"); also
  the method of a render whose sun is below :data:`MIN_SUN_COSINE`.

References
----------
Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Eqs. 12-26.
Nakajima, T. and Tanaka, M. (1988): Algorithms for radiative intensity calculations in moderately thick
atmospheres using a truncation approximation, J. Quant. Spectrosc. Radiat. Transfer 40, 51-69,
doi:10.1016/0022-4073(88)90031-3.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from ..errors import SwimInputError
from .diffuse_field import MIN_SUN_COSINE, DiffuseSettings
from .surface_margin import extend_beyond_grid

#: Entries of :func:`swim.rt.clouds.cloud_constants` that only the host reads (objects, tuples, the moments' degrees):
#: the JAX kernel's constants leave them out.
CLOUD_HOST_KEYS = ("cloud_optics", "diffuse_field", "cloud_rotation", "cloud_species", "degree")
#: Its arrays that the march kernels read (numba and JAX), besides ``ms_coarsen``.
CLOUD_KERNEL_KEYS = ("hydro_scale", "hydro_narrow", "hydro_aureole", "ms_field", "ms_above", "above_heights",
                     "backscatter_scaled")


def three_d(consts) -> bool:
    """Whether the kernel constants carry the 3-D cloud scattering's diffuse solution (static: a dict key)."""
    return "ms_field" in consts


__all__ = ["CloudScattering", "CLOUD_METHODS", "CLOUD_HOST_KEYS", "CLOUD_KERNEL_KEYS", "three_d", "MIN_SUN_COSINE", "cloud_constants", "cloud_ray_inputs",
           "scene_cloud_optics", "direct_weights", "as_cloud_scattering"]

#: The methods of cloud scattering.
CLOUD_METHODS = ("albers2020", "discrete_ordinates")


@dataclass(frozen=True)
class CloudScattering:
    """The method of cloud scattering and its options.

    Attributes
    ----------
    method : str
        One of :data:`CLOUD_METHODS`.
    phase_function : str or tuple
        The hydrometeors' phase functions of ``"discrete_ordinates"``: "physical" (Mie liquid and rain, roughened
        aggregates for ice, snow and graupel) or a mapping of species (or "liquid", "ice") to ("mie",),
        ("roughened_aggregate",) or ("hg", g), e.g. ``{"liquid": ("hg", 0.85), "ice": ("hg", 0.75)}`` (kept as a
        sorted tuple of pairs, so that the settings hash).
    diffuse : DiffuseSettings
        Accuracy settings of the 3-D diffuse solution.
    """

    method: str = "discrete_ordinates"
    phase_function: object = "physical"
    diffuse: DiffuseSettings = field(default_factory=DiffuseSettings)

    def __post_init__(self):
        if self.method not in CLOUD_METHODS:
            raise SwimInputError(f"cloud_scattering must be one of {CLOUD_METHODS}, got {self.method!r}")
        spec = self.phase_function
        if isinstance(spec, Mapping):
            spec = tuple(sorted((str(k), tuple(v) if isinstance(v, (list, tuple)) else (v,)) for k, v in spec.items()))
            object.__setattr__(self, "phase_function", spec)
        elif not (spec == "physical" or isinstance(spec, tuple)):
            raise SwimInputError(f"cloud_phase_function must be 'physical' or a mapping of species to models, got "
                                 f"{spec!r}")
        if not isinstance(self.diffuse, DiffuseSettings):
            raise SwimInputError(f"CloudScattering.diffuse must be a DiffuseSettings, got "
                                 f"{type(self.diffuse).__name__}")
        from ..optics.cloud_phase import resolve_phase_spec

        resolve_phase_spec(self.phase_mapping())  # checks the names and models now, not in the middle of a render

    def phase_mapping(self):
        """The phase functions as :func:`swim.optics.cloud_phase.cloud_optics` takes them."""
        return self.phase_function if isinstance(self.phase_function, str) else dict(self.phase_function)

    @property
    def three_d(self) -> bool:
        """The 3-D diffuse solution (``"discrete_ordinates"``)."""
        return self.method == "discrete_ordinates"


def as_cloud_scattering(value) -> CloudScattering:
    """A :class:`CloudScattering` from a method's name or an instance."""
    if isinstance(value, CloudScattering):
        return value
    if isinstance(value, str):
        return CloudScattering(method=value)
    raise SwimInputError(f"cloud_scattering must be one of {CLOUD_METHODS} or a CloudScattering, got {value!r}")


def mean_effective_radii(volume) -> dict:
    """The extinction-weighted mean effective radius [m] of each species the volume records
    (``mean_effective_radius_m`` attribute of :func:`swim.optics.volume.build_optical_volume`)."""
    from ..constants import SPECIES

    radii = np.asarray(volume.attrs.get("mean_effective_radius_m", [np.nan] * len(SPECIES)), float)
    return {s: float(r) for s, r in zip(SPECIES, radii) if np.isfinite(r) and r > 0}


def cloud_constants(packed, species, sun_scene, optics, solved) -> dict:
    """The constants of the 3-D cloud scattering for the march and the ground: the diffuse field scaled to the
    render's sun and the hydrometeors' optics.

    Parameters
    ----------
    packed : dict
        The render's grid constants (:func:`swim.rt.march_inputs.volume_constants`): ``volume`` (the packed channels,
        whose Step 1a channels hold the scaled direct transmittance), ``surface``, ``surface_outside``.
    species : tuple of int
        The packed species.
    sun_scene : array_like
        (3,) towards the sun, scene frame.
    optics : swim.optics.cloud_phase.CloudOptics
        The hydrometeors' optics (:func:`scene_cloud_optics`), whose truncation Step 1a's scaled transmittance used.
    solved : swim.rt.diffuse_field.DiffuseField
        The diffuse solution (:func:`swim.rt.diffuse_field.diffuse_field`), solved for the node of
        :func:`swim.rt.diffuse_field.solve_sun` nearest ``sun_scene`` and scaled to it here
        (:meth:`~swim.rt.diffuse_field.DiffuseField.for_sun`).

    Returns
    -------
    dict
        ``cloud_optics`` (:class:`swim.optics.cloud_phase.CloudOptics`), ``diffuse_field``
        (:class:`swim.rt.diffuse_field.DiffuseField`), ``hydro_scale`` (n_sp,) 1 - f, ``hydro_chi``
        (n_sp, 3, L + 1) chi_l - f, ``degree`` (nm,), ``ms_field``, ``ms_coarsen``, ``surface`` (14, ny, nx) and
        ``surface_outside`` (14,) with the ground's diffuse ratios, ``backscatter_scaled`` (5,) 1 - f per species.
    """
    from .ordinates import harmonic_degrees

    n_sp = len(species)
    field_ = solved.for_sun(sun_scene)
    idx = list(species)
    f = optics.truncation
    hydro_chi = (optics.moments[idx, :optics.max_degree + 1, :] - f[idx, None, None]).transpose(0, 2, 1)
    surface = np.asarray(packed["surface"])  # with its margin beyond the grid (swim.rt.march_inputs.extended_surface)
    margin = int(np.asarray(packed["surface_margin"]))
    ny, nx = surface.shape[1] - 2 * margin, surface.shape[2] - 2 * margin
    # the ground's diffuse ratios, lighting like T: beyond the grid they fade to 1 within a cell or two
    ratio = extend_beyond_grid(_upsample(field_.ground, field_.coarsen, ny, nx), np.ones(3), margin, np.ones(3),
                               smoothed=False)  # (3, ny + 2 margin, nx + 2 margin)
    readonly = lambda a: _readonly(np.ascontiguousarray(a))  # noqa: E731
    return {
        "cloud_optics": optics, "diffuse_field": field_,
        "hydro_scale": readonly(np.asarray(1.0 - f[idx], np.float64)),
        "hydro_chi": readonly(np.asarray(hydro_chi, np.float64) if n_sp else np.zeros((1, 3, 1))),
        # f - f_a: the forward peak's share outside the aureole (swim.optics.cloud_phase.split_phase_function)
        "hydro_narrow": readonly(np.asarray(f[idx] - optics.narrow[idx], np.float64)),
        # 1 - f_a: the species' weights of the optical depth that dims the beam but for the aureole
        "hydro_aureole": readonly(np.asarray(1.0 - optics.narrow[idx], np.float64)),
        "degree": readonly(harmonic_degrees(optics.max_degree).astype(np.int64)),
        "ms_field": readonly(field_.field), "ms_coarsen": float(field_.coarsen),
        "ms_above": readonly(field_.above), "above_heights": readonly(np.asarray(field_.above_heights, np.float64)),
        "surface": readonly(np.concatenate([surface, ratio.astype(np.float32)])),
        "surface_outside": readonly(np.concatenate([np.asarray(packed["surface_outside"]),
                                                    np.ones(3, np.float32)]).astype(np.float32)),
        "backscatter_scaled": readonly((1.0 - f).astype(np.float32)),
        "cloud_rotation": field_.rotation, "cloud_species": tuple(species),
    }


def scene_cloud_optics(volume, clouds: CloudScattering):
    """The hydrometeors' optics of a scene (:func:`swim.optics.cloud_phase.cloud_optics` at its species'
    extinction-weighted mean effective radii)."""
    from ..optics.cloud_phase import cloud_optics

    return cloud_optics(clouds.phase_mapping(), clouds.diffuse.max_degree, mean_effective_radii(volume))


def direct_weights(volume, optics):
    """Step 1a's weights of the species of the volume's ``species`` coordinate for the scaled direct beam: 1 - f."""
    from ..constants import SPECIES

    return np.array([1.0 - optics.truncation[SPECIES.index(str(s))] for s in volume["species"].values], np.float32)


def cloud_ray_inputs(directions, sun_scene, species, constants) -> dict:
    """Per-ray inputs of the 3-D cloud scattering: ``p_hydro`` (n, n_sp, 6) the packed species' split phase
    functions at the rays' scattering angles (:meth:`swim.optics.cloud_phase.CloudOptics.phase_at`) and ``ray_ms``
    (n, n_sp, 3 nm) the weights of the diffuse solution's moments in each species' source, (chi_l - f) Y_lm of the
    light's propagation direction (towards the observer) in the solution's frame, per wavelength."""
    from .ordinates import real_spherical_harmonics

    d = np.asarray(directions, float)
    optics = constants["cloud_optics"]
    cos_theta = d @ np.asarray(sun_scene, float)
    if len(species):
        p_hydro = optics.phase_at(cos_theta, list(species)).astype(np.float32)
    else:
        p_hydro = np.zeros((d.shape[0], 1, 6), np.float32)
    rot = constants["cloud_rotation"]
    prop = -d
    prop_solver = np.concatenate([prop[:, :2] @ rot.T, prop[:, 2:3]], axis=1)
    y_view = real_spherical_harmonics(prop_solver, optics.max_degree)  # (n, nm)
    degree = np.asarray(constants["degree"])
    if not len(species):  # a cloudless scene: weights the march does not read
        return {"p_hydro": p_hydro, "ray_ms": np.zeros((d.shape[0], 1, 3 * degree.size), np.float32)}
    chi = np.asarray(constants["hydro_chi"], float)  # (n_sp, 3, L + 1): chi_l - f
    ray_ms = np.empty((d.shape[0], chi.shape[0], 3, degree.size), np.float32)  # one pass, in the kernel's precision
    np.multiply(y_view.astype(np.float32)[:, None, None, :], chi[:, :, degree].astype(np.float32)[None], out=ray_ms)
    return {"p_hydro": p_hydro, "ray_ms": ray_ms.reshape(d.shape[0], chi.shape[0], -1)}


def _readonly(a):
    a = a.view()
    a.flags.writeable = False
    return a


def _upsample(coarse, c, ny, nx):
    """A coarse (nyc, nxc, 3) field on the full grid's columns (3, ny, nx), bilinear between block centres."""
    coarse = np.asarray(coarse, float)
    if c == 1:
        return np.moveaxis(coarse, -1, 0)
    nyc, nxc = coarse.shape[:2]
    fj = np.clip((np.arange(ny) + 0.5) / c - 0.5, 0, nyc - 1)
    fi = np.clip((np.arange(nx) + 0.5) / c - 0.5, 0, nxc - 1)
    j0 = np.minimum(fj.astype(int), max(nyc - 2, 0))
    i0 = np.minimum(fi.astype(int), max(nxc - 2, 0))
    j1, i1 = np.minimum(j0 + 1, nyc - 1), np.minimum(i0 + 1, nxc - 1)
    a, b = (fj - j0)[:, None, None], (fi - i0)[None, :, None]
    out = ((1 - a) * ((1 - b) * coarse[j0][:, i0] + b * coarse[j0][:, i1])
           + a * ((1 - b) * coarse[j1][:, i0] + b * coarse[j1][:, i1]))
    return np.moveaxis(out, -1, 0)
