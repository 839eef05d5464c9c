"""The march's settings (:class:`MarchSettings`) and the fixed constants that all of its kernels share.

The constants are the march's sampling rules (probes, step weights, refinement) and the floors of its cloud
composition; the JAX kernel (:mod:`swim.rt.march_jax`), the numba kernel (:mod:`swim.rt.march_cpu`) and the
Pallas kernel (:mod:`swim.rt.march_pallas`) read them from here, so they cannot drift apart.
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass, fields, replace

import numpy as np

from ..errors import SwimInputError
from ..surface.lighting import SURFACE_MODELS


#: Scalar irradiance of isotropic diffuse light from the upper hemisphere per unit horizontal irradiance
#: (2 pi L against pi L).
SKYLIGHT_SCALAR_FACTOR = 2.0
#: Range of the downward view cosine over which rays switch from the "seen from below" (Eq. 13) to the
#: "seen from above" (Eq. 26) treatment of clouds.
FROM_ABOVE_BLEND = 0.1
#: Floors of the cloud-top reflection seen from above (Eqs. 24-26, docs/rendering.md, "Overcast accuracy"): the sun's
#: cosine [-] in the slant optical depths and the delta-Eddington T of the top layer, the self-transmittance T_self
#: [-] that divides the irradiance, and the sun's cosine [-] in the reflectance factor.
TOP_MIN_MU0 = 0.05
TOP_MIN_SELF_TRANSMITTANCE = 0.05
TOP_REFLECTANCE_MIN_MU0 = 1e-3


#: Smallest non-zero :attr:`MarchSettings.probe_spacing` [cells]: finer probes than a tenth of a cell see
#: nothing new (the occupancy is per cell), and they are capped at :data:`MAX_PROBES` anyway.
MIN_PROBE_SPACING = 0.1


#: Kernels of the step loop (:attr:`ExecutionSettings.backend`).
BACKENDS = ("auto", "jax", "numba")
#: Marches of the grid segment in the JAX kernel (:attr:`ExecutionSettings.grid_kernel`).
GRID_KERNELS = ("auto", "lockstep", "fused", "fused-march")


def _integer(least, optional=False):
    """A rule: an integer >= ``least`` (None too where ``optional``)."""
    def check(value):
        if optional and value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
            return f"an integer >= {least}"
        return None
    return check


def _zero_or_at_least(least, what):
    """A rule: 0 or a finite number >= ``least``, described as ``what``."""
    def check(value):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                or not np.isfinite(value) or value < 0 or 0 < value < least:
            return what
        return None
    return check


def _one_of(choices):
    """A rule: one of ``choices``."""
    return lambda value: None if value in choices else f"one of {choices}"


def _switch(optional=True):
    """A rule: True or False (or None where ``optional``)."""
    def check(value):
        if optional and value is None:
            return None
        if not isinstance(value, (bool, np.bool_)):
            return "True, False or None" if optional else "True or False"
        return None
    return check


def _registers(value):
    """The rule of :attr:`ExecutionSettings.fused_max_registers`: ptxas's bounds, kept in :mod:`swim.rt.ptx_edits`."""
    from .ptx_edits import MAX_REGISTERS, MIN_REGISTERS

    if value is not None and (isinstance(value, bool) or not isinstance(value, (int, np.integer))
                              or not MIN_REGISTERS <= value <= MAX_REGISTERS):
        return f"None or an integer in [{MIN_REGISTERS}, {MAX_REGISTERS}] (registers per thread)"
    return None


def _check_fields(settings, rules):
    """Raise :class:`SwimInputError` for the first field of ``settings`` that breaks its rule in ``rules``."""
    for name, rule in rules.items():
        value = getattr(settings, name)
        expected = rule(value)
        if expected is not None:
            raise SwimInputError(f"{type(settings).__name__}.{name} must be {expected}, got {value!r}")


@dataclass(frozen=True)
class ExecutionSettings:
    """How and where the march runs: the kernel, its chunks and the device's switches. They change the speed and
    the memory of a render, not its physics: every choice gives the same radiance to float32 rounding (the tests in
    tests/unit/rt hold the kernels to one another and to a float64 reference). What to compute, and how accurately,
    is :class:`MarchSettings`.

    "auto" and None are resolved for the hardware once per render (:meth:`MarchSettings.resolved`).

    Attributes
    ----------
    chunk : int or None
        Rays per kernel call; None (the default): :data:`CPU_CHUNK` on a CPU, :data:`GPU_CHUNK` when the JAX
        kernel runs on a GPU (:meth:`resolved_chunk`). Small chunks keep the kernel's working set in the CPU
        caches: on a 2-core machine a 255 x 255 all-sky renders in 7.1 s with 65536-ray chunks, 4.1 s with 4096
        or 8192, 4.2 s with 2048 and 6.1 s with 1024 (benchmarks/, docs/rendering.md). A GPU needs big ones to
        fill it: on an H100 the JAX kernel marches 1.9 million rays/s in chunks of 32768 and 4.0 million in
        chunks of 262144 (docs/performance.md, "The GPU kernels").
    backend : {"auto", "jax", "numba"}
        Kernel of the step loop: "jax" marches a chunk of rays in lockstep (:mod:`swim.rt.march_jax`; GPUs,
        gradients); "numba" runs the same steps one ray at a time on the CPU's cores (:mod:`swim.rt.march_cpu`, ~5x
        faster on a CPU: the default scene's 255^2 all-sky in 1.0 s against 4.6-5.1 s;
        docs/decisions/0002-per-ray-cpu-kernel.md and docs/decisions/0006-gpu-kernels.md); "auto" takes numba when
        JAX's default device is the CPU, else jax. A numba render never imports JAX
        (docs/decisions/0011-jax-only-where-it-runs.md).
    grid_kernel : {"auto", "lockstep", "fused", "fused-march"}
        How the JAX kernel marches the grid segment with refinement (``tau_refine`` > 0): "lockstep", one XLA
        program per iteration of every ray's march (:func:`_march_grid_refined`); "fused", one Pallas kernel whose
        Triton programs keep a block of rays' state in registers for the whole segment
        (:func:`swim.rt.march_pallas.march_grid_fused`; same equations, same results to float32 rounding; on a
        CPU it runs in Pallas's interpreter, slowly: for checks only); "fused-march", the clear air before and after
        the grid and the zero-length step at each ray's end in the same kernel too
        (:func:`swim.rt.march_pallas.march_segments_fused`; on an H100 a 262 144-ray chunk in 22.6 ms against 26.5 ms
        for "fused", but its first compilation takes ~40 s longer: for long series). "auto" takes "fused" where JAX's
        default device is a GPU that Pallas can compile for, else "lockstep" (docs/decisions/0006-gpu-kernels.md). The
        numba backend ignores it.
    ray_table : bool or None
        Keep the camera's rays on the device between frames (:mod:`swim.rt.ray_table`, the JAX kernel only): the
        rays' segments, starts, directions and occupancy probes are computed once per camera, observer and grid, and
        a batch of pixels sends only its rows' indices; the phase functions are computed on the device. The same
        kernel and results to float32 rounding of the scattering angle's cosine. None (the default): on where the
        JAX kernel runs on a GPU (:meth:`resolved_ray_table`; on an H100 a warm 1024^2 all-sky with every pixel
        traced renders in 0.151 s with it against 0.324 s without, adaptive 0.161 against 0.227 s, a new sun every
        frame 0.659 against 0.834 s; docs/decisions/0006-gpu-kernels.md), off on a CPU, where the march dominates and
        the table only holds memory. The numba backend ignores it.
    step1a_on_device : bool or None
        A new sun's Step 1a where the JAX kernel marches (:mod:`swim.rt.solar_device`): the previous sun's device copy
        of the packed volume is refilled there, instead of sweeping from the host's sums and copying the whole packed
        volume to the device again (~1.3 GB of transfers for the 400 x 400 x 60 scene). The same equations and sweep;
        the channels agree to float32 round-off. None (the default): on where the JAX kernel runs on a GPU
        (:meth:`resolved_step1a_on_device`; on an H200 a 1024^2 all-sky with a new sun every frame renders in 0.392 s
        with it against 0.614 s without, docs/decisions/0006-gpu-kernels.md), off on a CPU, where numba's sweep on the
        host is faster than JAX's. Used only by the JAX kernel, for a scene rendered before with another sun in the
        same process.
    device_sampling : bool or None
        Adaptive sampling with the image on the device (:mod:`swim.rt.image_sampling_device`), where the camera's
        rays are kept there (:meth:`resolved_ray_table`): the march's outputs are scattered, the cells tested and the
        smooth ones interpolated on the device, and only each batch's mask of wanted pixels and the finished image
        come to the host. The same traced pixels and image as the host's sampler (to float32 rounding). None (the
        default): on wherever the ray table is (:meth:`resolved_device_sampling`; on an H200 an adaptive 1024^2
        all-sky in 0.136 s with it against 0.152 s without, docs/decisions/0006-gpu-kernels.md). Ignored without a ray
        table or without adaptive sampling.
    fused_max_registers : int or None
        Registers per thread that the fused GPU kernel ("fused", "fused-march") may take on NVIDIA GPUs, in [16, 255]
        (PTX's ``.maxnreg``, :mod:`swim.rt.ptx_edits`; it needs jaxlib > 0.10.2, else it is logged and ignored).
        None (the default): ptxas's choice, 255 at 128 rays a program, which fits two programs per Hopper
        multiprocessor (12.5 % occupancy); 168 fits three and 128 four, at the price of spills
        (docs/decisions/0006-gpu-kernels.md: which is fastest is to be timed). The other kernels ignore it.
    fused_vector_loads : bool
        Whether the fused GPU kernel reads its tables (the volume, gas, sky, diffuse and multiple-scattering tables)
        with their channels last, up to four channels a load (:func:`swim.rt.march_pallas._load_groups`): on sm_90a
        its grid loop then issues 48 global loads an iteration instead of 110 and 1 617 instructions instead of
        1 893 (docs/decisions/0006-gpu-kernels.md). False: a scalar gather per channel and corner. The same results
        to float32 rounding; the other kernels ignore it.
    fused_fma : bool
        Whether ptxas may contract the fused GPU kernel's float32 multiplies and adds into fused multiply-adds on
        NVIDIA GPUs (:mod:`swim.rt.ptx_edits`: Triton writes them with an explicit rounding mode, which forbids it;
        it needs jaxlib > 0.10.2, else it is logged and ignored). On sm_90a the grid loop then issues 1 440
        instructions an iteration instead of 1 617 at the same registers (docs/decisions/0006-gpu-kernels.md). A
        contracted pair rounds once instead of twice, so the results move by float32 rounding. False (the default)
        until timed on a GPU; the other kernels, and the fused kernel in Pallas's interpreter, ignore it.
    device_image : bool or None
        The image finished on the device, where the camera's rays are kept there (:meth:`resolved_ray_table`): with
        every pixel traced, the chunks' outputs stay on the device and are scattered into the image's planes there
        (:mod:`swim.rt.image_device`), and the colour stage runs there too (:mod:`swim.color.srgb_device`, with every
        pixel and, where :meth:`resolved_device_sampling`, adaptively), so that a frame's planes and RGB come to the
        host in one copy. The same planes, and the same 8-bit codes but where the device rounds a fused
        multiply-add once (a code apart at most, at a value within ~1e-16 of a code's step); the rare pixels whose
        spectrum needs clipping, and the sun's disk, are coloured on the host. None (the default): on where the JAX
        kernel runs on a GPU (:meth:`resolved_device_image`; docs/decisions/0006-gpu-kernels.md), off elsewhere, where
        the host's cores are the device's and its compiled colour stage is faster than XLA's.
    """

    backend: str = "auto"
    grid_kernel: str = "auto"
    chunk: int | None = None
    ray_table: bool | None = None
    step1a_on_device: bool | None = None
    device_sampling: bool | None = None
    device_image: bool | None = None
    fused_max_registers: int | None = None
    fused_vector_loads: bool = True
    fused_fma: bool = False

    def __post_init__(self):
        _check_fields(self, _EXECUTION_RULES)


_EXECUTION_RULES = {
    "backend": _one_of(BACKENDS), "grid_kernel": _one_of(GRID_KERNELS),
    "chunk": _integer(1, optional=True), "ray_table": _switch(), "step1a_on_device": _switch(),
    "device_sampling": _switch(), "device_image": _switch(), "fused_max_registers": _registers,
    "fused_vector_loads": _switch(optional=False), "fused_fma": _switch(optional=False)}
#: The fields of :class:`ExecutionSettings`, which :class:`MarchSettings` also takes as deprecated keywords.
EXECUTION_FIELDS = tuple(f.name for f in fields(ExecutionSettings))


@dataclass(frozen=True)
class MarchSettings:
    """What the march computes and how accurately: the step counts of the three ray segments, the scattering and the
    ground (static for the compiled kernel); how and where it runs is :attr:`execution`.

    Attributes
    ----------
    n_before : int
        Steps through clear air before the model grid (e.g. from space down to the grid top), placed by the
        extinction along the ray (:func:`clear_step_edges`).
    n_grid : int
        Steps through the model grid, concentrated where there are hydrometeors, raised terrain or aerosol
        gradients (:func:`adaptive_step_edges`): 128 adaptive steps are about as accurate as 256 equal ones were
        (docs/performance.md).
    n_after : int
        Steps through clear air after the grid (to the top of the atmosphere or the ground), placed like
        ``n_before``'s. A ray that rises out of the grid takes fewer where little of its air lies beyond it:
        ``n_after`` times the square root of the fraction of the vertical optical depth above its lowest point that
        lies above its exit, at least :data:`swim.constants.AFTER_MIN_STEPS` (:func:`after_step_counts`; the midpoint
        rule's error of the segment, relative to the ray's clear sky, then stays the same). Default 28: the rays of a
        ground view of the RICO LES (grid top 2 km, 2.4 km wide) take 22-28, 2 % more samples than 24 each and
        12 % less error; those leaving a 20 km grid top 6 (docs/decisions/0004-step-placement.md).
    empty_steps : int or None
        Most grid steps [-] that a ray puts into the empty (unoccupied) part of its grid segment, unless that part
        is longer than 2 ``empty_steps`` cells (then one step per :data:`EMPTY_CELLS_PER_STEP` empty cells);
        its occupied part keeps the step density that ``n_grid`` gives it, so a ray that crosses clear air only
        takes ``empty_steps`` steps instead of ``n_grid`` (:func:`grid_step_edges`). None (the default):
        ``n_grid // 4``; 0: every ray takes ``n_grid`` steps. The RICO cumulus all-sky renders 1.5x faster, views
        of overcast or terrain-filled grids do not change (docs/decisions/0004-step-placement.md).
    sunlit_steps : int
        Most grid steps [-] that a ray puts into the sunlit clear air of its grid segment (:func:`step_classes`:
        empty cells whose every neighbour the sun reaches through no cloud, terrain or 3-D aerosol, transmittance
        >= :data:`SUNLIT_TRANSMITTANCE`, where the clear sky's source varies with height alone), unless that part
        is longer than ``sunlit_steps`` x :data:`SUNLIT_CELLS_PER_STEP` cells (then one step per
        :data:`SUNLIT_CELLS_PER_STEP` such cells); the other empty cells keep ``empty_steps``' limit
        (:func:`grid_step_edges`). Default 4: the 400 x 400 x 60 synthetic scene's rays take 13 % fewer samples
        with the error against a converged reference unchanged (docs/decisions/0004-step-placement.md). 0: sunlit clear
        air counts as empty air. Ignored where ``empty_steps`` is 0.
    n_probe : int
        Occupancy probes per ray along its grid segment, at least, which place the ``n_grid`` steps
        (:func:`grid_step_edges`).
    probe_spacing : float
        Most cells [-] between a ray's probes: a ray that crosses more than ``n_probe * probe_spacing`` cells
        (a ray grazing a big grid crosses hundreds) takes one probe per ``probe_spacing`` cells instead, up to
        :data:`MAX_PROBES` (:func:`probe_counts`). With 2, no ray passes through the central half of an
        occupied cell unseen (the occupancy is dilated by one cell); the 99th percentile of the error of a
        view 6° above the horizon of a 400 km grid falls from 20 % to 10 %, and other views do not change
        (docs/decisions/0004-step-placement.md). 0 probes every ray ``n_probe`` times.
    tau_refine : float
        Largest hydrometeor optical depth [-] of a grid step, and largest change of it between neighbouring
        steps, while the ray's own is below 8: a thicker step is replaced by its halves, and so is a step at a
        cloud face, recursively (:func:`_march_grid_refined`), so that the face is sampled where its light comes
        from. 0 turns this off. Default 0.25: against 0.5 the 99th percentile of a 1024² all-sky's error falls
        from 2.3 to 1.8 % for ~1-3 % more samples (docs/decisions/0004-step-placement.md).
    stop_tau : float
        Hydrometeor optical depth [-] along a ray at which a ray that does not look down (view zenith <= 90 deg)
        stops: beyond it nothing reaches the observer (e^-50 ~ 2e-22) and the cloud radiance of Eqs. 12-23 seen
        from below no longer depends on the optical depth (Eq. 14's c1 = e^-(tau/10)^2 < 1e-10 at 50), so the
        radiance is the same as if the ray went on. Such a ray's ``tau_hydrometeor`` is ``stop_tau`` (a lower bound
        of the line of sight's: "opaque"), and it does not see the ground behind. Rays that look down keep going
        (the cloud-top reflection of Eqs. 24-26 depends on the whole optical depth). 0 turns it off; otherwise at
        least :data:`STOP_TAU_MIN`. Default 50 (docs/rendering.md, "Opaque rays";
        docs/decisions/0004-step-placement.md).
    multiple_scattering : bool
        Add the directional source of the higher scattering orders (:mod:`swim.rt.multiple_scattering`)
        to the clear-sky source (docs/rendering.md); False gives pure single scattering (Eq. 3).
    surface : {"brdf", "lambertian"}
        Reflectance of the ground (:func:`swim.surface.lighting.surface_radiance`): land, snow and water
        BRDFs with sun glint, or Lambertian (what plane-parallel reference solvers assume).
    cloud_scattering : str or CloudScattering
        How clouds scatter light (:mod:`swim.rt.clouds`): "discrete_ordinates" (the 3-D diffuse solution, the
        default; a sun below 0.6 deg of elevation falls back to
        "albers2020") or "albers2020" (the paper's Eqs. 12-26), or a :class:`swim.rt.clouds.CloudScattering` with
        its phase functions and accuracy settings; kept as the latter.
    execution : ExecutionSettings
        The kernel, its chunks and the device's switches (:class:`ExecutionSettings`). Its fields were
        :class:`MarchSettings`'s and are still taken as keywords (``MarchSettings(backend="jax")``) and read as
        attributes (``settings.backend``), with a :class:`DeprecationWarning`.
    """

    n_before: int = 12
    n_grid: int = 128
    n_after: int = 28
    empty_steps: int | None = None
    sunlit_steps: int = 4
    n_probe: int = 64
    probe_spacing: float = 2.0
    tau_refine: float = 0.25
    stop_tau: float = 50.0
    multiple_scattering: bool = True
    surface: str = "brdf"
    cloud_scattering: object = "discrete_ordinates"
    execution: ExecutionSettings = ExecutionSettings()

    def __post_init__(self):
        from .clouds import as_cloud_scattering

        object.__setattr__(self, "cloud_scattering", as_cloud_scattering(self.cloud_scattering))
        _check_fields(self, _PHYSICS_RULES)
        if not isinstance(self.execution, ExecutionSettings):
            raise SwimInputError(f"MarchSettings.execution must be an ExecutionSettings, got {self.execution!r}")

    def __getattr__(self, name):
        # only for names that are not attributes: the execution fields' old home
        if name in EXECUTION_FIELDS and "execution" in self.__dict__:
            warnings.warn(f"MarchSettings.{name} is deprecated: read MarchSettings.execution.{name}",
                          DeprecationWarning, stacklevel=2)
            return getattr(self.execution, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def with_execution(self, **changes) -> MarchSettings:
        """These settings with the :class:`ExecutionSettings` fields in ``changes`` changed."""
        return replace(self, execution=replace(self.execution, **changes))

    def resolved(self) -> MarchSettings:
        """These settings with :attr:`execution` resolved for this machine: the backend, the grid kernel, the chunk
        and the device's switches as they will run ("auto" and None replaced), so that a render asks the hardware
        once. Resolving resolved settings changes nothing.

        Raises
        ------
        SwimInputError
            If ``execution.backend`` is "numba" and numba is not installed.
        """
        backend = self.resolved_backend()
        ray_table = self.resolved_ray_table()
        execution = replace(self.execution, backend=backend, grid_kernel=self.resolved_grid_kernel()
                            if backend == "jax" else self.execution.grid_kernel, chunk=self.resolved_chunk(),
                            ray_table=ray_table, step1a_on_device=self.resolved_step1a_on_device(),
                            device_sampling=self.resolved_device_sampling(),
                            device_image=self.resolved_device_image())
        return replace(self, execution=execution)

    def resolved_backend(self) -> str:
        """The kernel that runs: ``execution.backend``, with "auto" resolved to "numba" when JAX's default device is
        the CPU and numba is installed, else "jax". JAX is asked only where it may see an accelerator (a GPU platform
        in ``JAX_PLATFORMS`` or a JAX plugin installed, :func:`swim.rt.precompile.jax_may_see_a_gpu`): elsewhere its
        default device is the CPU, and "auto" resolves without importing it.

        Raises
        ------
        SwimInputError
            If ``execution.backend`` is "numba" and numba is not installed.
        """
        backend = self.execution.backend
        if backend == "numba" and not _numba_available():
            raise SwimInputError(f"MarchSettings.backend={backend!r} needs the numba package (pip install numba)")
        if backend != "auto":
            return backend
        return "numba" if _numba_available() and not _jax_on_accelerator() else "jax"

    def resolved_grid_kernel(self) -> str:
        """The JAX kernel's march of the grid segment (:attr:`ExecutionSettings.grid_kernel`): "auto" resolved to
        "fused" where JAX's default device is a GPU and Pallas can lower to Triton there, else "lockstep"; always
        "lockstep" with the 3-D cloud scattering, whose sources the fused kernel does not carry."""
        if self.cloud_scattering.three_d:
            return "lockstep"
        if self.execution.grid_kernel != "auto":
            return self.execution.grid_kernel
        from .march_pallas import pallas_triton_available

        return "fused" if pallas_triton_available() else "lockstep"

    def kernel_settings(self) -> MarchSettings:
        """These settings with those that the march's kernels do not read (:attr:`ExecutionSettings.ray_table`,
        ``step1a_on_device``, ``device_sampling``, ``device_image``) pinned to False, so that a compiled kernel (keyed
        by its settings, also on disk: :mod:`swim.compilation.jax_export`) serves whatever they are: a recompilation
        of the JAX kernel takes tens of seconds on a GPU."""
        return self.with_execution(ray_table=False, step1a_on_device=False, device_sampling=False,
                                   device_image=False)

    def resolved_ray_table(self) -> bool:
        """Whether the camera's rays are kept on the device (:attr:`ExecutionSettings.ray_table`): None resolved to
        True where the JAX kernel runs on a GPU (or another accelerator), else False; always False for the numba
        kernel, which does not use it."""
        return self._jax_device_switch(self.execution.ray_table)

    def resolved_step1a_on_device(self) -> bool:
        """Whether a new sun's Step 1a runs on the device's copy of the packed volume
        (:attr:`ExecutionSettings.step1a_on_device`): None resolved to True where the JAX kernel runs on a GPU (or
        another accelerator), else False; always False for the numba kernel, which keeps no such copy."""
        return self._jax_device_switch(self.execution.step1a_on_device)

    def _jax_device_switch(self, value) -> bool:
        """A switch of the JAX kernel's device copies (``value``: True, False or None): False for the other kernels
        and with the 3-D cloud scattering (its per-ray inputs and scaled Step 1a are the host's), else ``value``,
        None resolved to whether the march runs on an accelerator."""
        if self.resolved_backend() != "jax" or self.cloud_scattering.three_d:
            return False
        return self.on_accelerator() if value is None else bool(value)

    def resolved_device_sampling(self) -> bool:
        """Whether adaptive sampling keeps its image on the device (:attr:`ExecutionSettings.device_sampling`): only
        with the camera's rays there (:meth:`resolved_ray_table`), and then None resolved to True."""
        if not self.resolved_ray_table():
            return False
        return True if self.execution.device_sampling is None else bool(self.execution.device_sampling)

    def resolved_device_image(self) -> bool:
        """Whether the image is finished on the device (:attr:`ExecutionSettings.device_image`): only with the
        camera's rays there (:meth:`resolved_ray_table`), and then None resolved to whether the march runs on an
        accelerator."""
        return self.resolved_ray_table() and self._jax_device_switch(self.execution.device_image)

    def resolved_empty_steps(self) -> int:
        """Most grid steps in a ray's empty space (:attr:`empty_steps`, None resolved to ``n_grid // 4``); 0: no
        limit, every ray takes ``n_grid`` grid steps."""
        return self.n_grid // 4 if self.empty_steps is None else int(self.empty_steps)

    def resolved_chunk(self) -> int:
        """Rays per kernel call: :attr:`ExecutionSettings.chunk`, or for None :data:`GPU_CHUNK` where the JAX kernel
        runs on a GPU (or another accelerator) and :data:`CPU_CHUNK` elsewhere."""
        if self.execution.chunk is not None:
            return int(self.execution.chunk)
        return GPU_CHUNK if self.on_accelerator() else CPU_CHUNK

    def on_accelerator(self) -> bool:
        """Whether the march runs on a GPU (or another accelerator): the JAX kernel where JAX's default device is not
        the CPU."""
        return self.resolved_backend() == "jax" and _jax_on_accelerator()


_PHYSICS_RULES = {
    **{name: _integer(0) for name in ("n_before", "n_grid", "n_after", "sunlit_steps")},
    "empty_steps": _integer(0, optional=True), "n_probe": _integer(1),
    "probe_spacing": _zero_or_at_least(MIN_PROBE_SPACING, f"0 or a finite number of cells >= {MIN_PROBE_SPACING}"),
    "tau_refine": _zero_or_at_least(0.0, "a finite optical depth >= 0"),
    "stop_tau": lambda value: _zero_or_at_least(STOP_TAU_MIN, f"0 (off) or a finite optical depth >= "
                                                              f"{STOP_TAU_MIN:g} [-]")(value),
    "surface": _one_of(SURFACE_MODELS)}


def _march_settings_init(init):
    """``MarchSettings``'s dataclass ``__init__`` that also takes :class:`ExecutionSettings`' fields as deprecated
    keywords, moved into ``execution``."""
    @functools.wraps(init)
    def __init__(self, *args, **kwargs):
        moved = {name: kwargs.pop(name) for name in EXECUTION_FIELDS if name in kwargs}
        if moved:
            warnings.warn(f"MarchSettings({', '.join(f'{name}=' for name in moved)}) is deprecated: these are "
                          f"ExecutionSettings' fields, given as MarchSettings(execution=ExecutionSettings(...))",
                          DeprecationWarning, stacklevel=2)
            kwargs["execution"] = replace(kwargs.get("execution", ExecutionSettings()), **moved)
        init(self, *args, **kwargs)
    return __init__


MarchSettings.__init__ = _march_settings_init(MarchSettings.__init__)


#: Rays per kernel call on a CPU (:meth:`MarchSettings.resolved_chunk`): small enough for its caches.
CPU_CHUNK = 4096
#: Rays per kernel call of the JAX kernel on a GPU: on an H100 1.9 million rays/s in chunks of 32768, 4.0 million
#: in chunks of 262144 and 4.4 million in one chunk of 1048576 (a 1024 x 1024 all-sky's 823 593 rays then pad to
#: 1048576: no faster); 1.6 GB of device memory at the peak (docs/performance.md, "The GPU kernels").
GPU_CHUNK = 262144



def _jax_on_accelerator() -> bool:
    """Whether JAX's default device is a GPU (or another accelerator); imports JAX only where it may see one."""
    from .precompile import jax_may_see_a_gpu

    if not jax_may_see_a_gpu():
        return False
    import jax

    return jax.default_backend() != "cpu"


@functools.lru_cache(maxsize=None)
def _numba_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("numba") is not None


#: Default occupancy probes per ray along the grid segment (:func:`adaptive_step_edges`, :attr:`MarchSettings.n_probe`).
N_OCCUPANCY_PROBES = MarchSettings.n_probe
#: Most occupancy probes per ray (:func:`probe_counts`): one per 2 cells of a ray across 2048 cells.
MAX_PROBES = 1024
#: Probe intervals [-] (of ``probe_spacing`` cells) by which a ray's length may exceed a whole number of them
#: without another probe (:func:`probe_counts`).
CELL_SLACK = 1e-3
#: Step density in empty space relative to occupied space (:func:`adaptive_step_edges`).
EMPTY_STEP_WEIGHT = 0.125
#: Empty cells [-] per grid step beyond :attr:`MarchSettings.empty_steps` (:func:`grid_step_edges`): a ray that
#: grazes a big grid through hundreds of empty cells still samples their cloud shadows and aerosol once per 2
#: cells (with one step per 4, a view 6 deg above the horizon of the 400 km synthetic grid had its 99th
#: percentile error raised from 1.0 to 1.2 % and its largest from 7 to 13 %; docs/decisions/0004-step-placement.md).
EMPTY_CELLS_PER_STEP = 2.0
#: Sunlit clear cells [-] per grid step beyond :attr:`MarchSettings.sunlit_steps` (:func:`grid_step_edges`): there the
#: clear sky's source follows the smooth height profiles of the gas and the background aerosol alone (the steps
#: after the grid cross all the air above it in 4-28; with one step per 16 or 32 such cells the sky's error grew,
#: docs/decisions/0004-step-placement.md).
SUNLIT_CELLS_PER_STEP = 8.0
#: Least transmittance [-] of the direct sun (cloud, terrain shadow and 3-D aerosol together, Step 1a) at a grid
#: node and all its neighbours for a cell without hydrometeors to count as sunlit clear air (:func:`step_classes`).
SUNLIT_TRANSMITTANCE = 0.999
#: The step classes' codes (:func:`step_classes`): occupied cells are 1, empty ones 0 (as in :func:`occupancy_grid`).
SUNLIT_CLEAR = -1
#: Extinction probes per ray along a clear-air segment (:func:`clear_step_edges`).
CLEAR_PROBES = 16
#: Exponent of the extinction in the clear-air step density (:func:`clear_step_edges`).
CLEAR_STEP_POWER = 1.0 / 3.0
#: Least clear-air step density, relative to a ray's largest (:func:`clear_step_edges`).
CLEAR_STEP_FLOOR = 0.02


#: Binary refinement of grid steps where a cloud face may lie (:func:`_march_grid_refined`): levels of halving (a
#: step down to 1/64), refinements per ray (splits and roll-backs), the hydrometeor optical depth [-] to the
#: observer beyond which no step is refined (e^-8: what lies deeper adds < 0.04 % of the light), and the pending
#: intervals a ray can hold (a split adds one, a roll-back two; a refinement that does not fit is not made).
REFINE_DEPTH = 6
REFINE_BUDGET = 16
REFINE_VISIBLE_TAU = 8.0
REFINE_SLOTS = REFINE_DEPTH + 4
#: Least :attr:`MarchSettings.stop_tau` [-] (but 0): at 40 the cloud radiance seen from below is still within 1e-7 of
#: its value for an infinite optical depth (Eq. 14's c1 = e^-16) and e^-40 of what lies behind reaches the observer.
STOP_TAU_MIN = 40.0


#: Iterations of the lockstep grid loop per test of its condition on an accelerator. On a GPU XLA copies the while
#: loop's condition to the host after every iteration and launches the next from there. An H100 marched a 262 144-ray
#: chunk of the synthetic scene in 58.1-58.8 ms with one iteration per test, 48.7-50.6 ms with two and 46.4-47.8 ms
#: with four (Katrina: 53.6-53.7, 44.5-46.2 and 42.0-44.3 ms), the same bits (docs/decisions/0006-gpu-kernels.md). The
#: loop's body is compiled that many times: a fresh H100 machine's first 1024^2 render compiled for 52-55 s with four
#: against 39-43 s with two. On a CPU there is no such round trip (1).
GRID_LOOP_UNROLL_ACCELERATOR = 4


#: Bisection steps that refine a terrain crossing found between two samples of the march (2^-10 of a step:
#: a few metres even for the ~10 km steps beyond the grid).
TERRAIN_BISECTIONS = 10
