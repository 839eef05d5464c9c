"""Steps 1b, 2 and 3: rays from the observer through the atmosphere, the model grid and onto the ground.

Each pixel's ray is marched once, from where it enters the atmosphere (or the observer) to where it
leaves the atmosphere (100 km) or meets the ground, in three segments with fixed step counts: clear air
before the model grid, the grid (its steps concentrated where there are hydrometeors, raised terrain or
aerosol gradients, and few where there is nothing: :func:`grid_step_edges`), and clear air after it (the clear
air's steps dense where the air is: :func:`clear_step_edges`). Along the way the kernel accumulates

* the clear-sky radiance of the gas and the aerosol: single scattering (Step 2, Eq. 3), lit by the sun
  through the spherical atmosphere (tabulated, :mod:`swim.rt.gas`) and through the clouds (T of Step 1a,
  so cloud shadows fall on the air as well), plus the higher orders from the precomputed directional
  diffuse source (:mod:`swim.rt.multiple_scattering`), attenuated towards the observer by gas, aerosol
  *and* hydrometeors;
* for the hydrometeors (Step 1b): the optical depth tau_o per species and the integral of Eq. 12,
  ``int_0^l (E/E_TOA) e^{-tau_o} dtau_o`` with l = min(2, tau_o), both with and without the gas
  attenuation between the observer and the cloud;
* the first intersection with the terrain (bilinear height field, refined linearly between steps; beyond
  the grid the terrain continues at its edge heights) or the sea-level sphere.

After the march the cloud radiance follows Eq. 12 with the effective phase function of Eq. 13
(:func:`swim.optics.phase.effective_phase_function`), blended with the cloud-top reflection of Eqs. 24-26
for rays that look down on clouds; the ground reflects direct and diffuse light on its tilted terrain facet
(Eq. 35; BRDFs, sun glint and slopes in :mod:`swim.surface.lighting`). Step 3 (Eqs. 32-34) is realised by the compositing itself: gas in front of a cloud adds
unattenuated, the cloud is seen through the gas in front of it (the e^{-tau_1} of Eq. 33), and the sky
and ground behind it are attenuated by its optical depth. docs/rendering.md states the interpretation.

The kernels are JAX (float32, jit-compiled once per batch size, chunked over pixels). On a CPU the step
loop runs by default in :mod:`swim.rt.march_cpu` instead (numba, one loop per ray, ~5x faster there), with its
per-ray set-up (:func:`swim.rt.march_cpu.prepare_rays`) and the clouds' composition (:mod:`swim.rt.compose_cpu`)
and the ground's (:mod:`swim.rt.ground_cpu`) in numba too (:attr:`MarchSettings.backend`;
docs/decisions/0002-per-ray-cpu-kernel.md and docs/decisions/0009-work-around-the-march.md).
"""

from __future__ import annotations

import collections
import functools
import logging
import weakref
from dataclasses import dataclass, replace

import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr

from ..constants import AFTER_MIN_STEPS, BACKSCATTER_FRACTION, CELL_PROBES, EARTH_RADIUS_M, GAS_COLUMN_ROW, SPECIES
from ..frames import ray_sphere_intersections
from ..optics.volume import grid_indices
from ..optics.phase import (
    G_LIQUID,
    anisotropic_reflectance_factor_kokhanovsky2004,
    blend_coefficient,
    delta_scaled_path_factor,
    diffuse_transmission_factor,
    effective_phase_function,
    forward_peak_mixture,
    phase_thin_mixture,
)
from ..errors import SwimInputError
from ..surface.lighting import SURFACE_MODELS, surface_radiance
from ..workers import (in_blocks, in_worker_thread, parallel_map, threads,  # threads: also swim.rt.march.threads
                       worker_pool)
from .clouds_device import CLOUD_HOST_KEYS, CLOUD_KERNEL_KEYS, cloud_sources, ratio_above_grid, three_d
from .export_cache import exported_jit
from .gas import GasTables
from .solar import transmittance_delta_eddington

log = logging.getLogger(__name__)



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


@dataclass(frozen=True)
class MarchSettings:
    """Step counts of the three ray segments (static for the compiled kernel).

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
    chunk : int or None
        Rays per kernel call; None (the default): :data:`CPU_CHUNK` on a CPU, :data:`GPU_CHUNK` when the JAX
        kernel runs on a GPU (:meth:`resolved_chunk`). Small chunks keep the kernel's working set in the CPU
        caches: on a 2-core machine a 255 x 255 all-sky renders in 7.1 s with 65536-ray chunks, 4.1 s with 4096
        or 8192, 4.2 s with 2048 and 6.1 s with 1024 (benchmarks/, docs/rendering.md). A GPU needs big ones to
        fill it: on an H100 the JAX kernel marches 1.9 million rays/s in chunks of 32768 and 4.0 million in
        chunks of 262144 (docs/performance.md, "The GPU kernels").
    multiple_scattering : bool
        Add the directional source of the higher scattering orders (:mod:`swim.rt.multiple_scattering`)
        to the clear-sky source (docs/rendering.md); False gives pure single scattering (Eq. 3).
    surface : {"brdf", "lambertian"}
        Reflectance of the ground (:func:`swim.surface.lighting.surface_radiance`): land, snow and water
        BRDFs with sun glint, or Lambertian (what plane-parallel reference solvers assume).
    backend : {"auto", "jax", "numba", "cuda"}
        Kernel of the step loop: "jax" marches a chunk of rays in lockstep (GPUs, gradients); "numba" runs
        the same steps one ray at a time on the CPU's cores (:mod:`swim.rt.march_cpu`, ~5x faster on a
        CPU: the default scene's 255^2 all-sky in 1.0 s against 4.6-5.1 s; docs/decisions/0002-per-ray-cpu-kernel.md and
        docs/decisions/0006-gpu-kernels.md); "cuda" compiles that same per-ray code for an NVIDIA GPU, one thread per
        ray (:mod:`swim.rt.march_cuda`, numba-cuda; opt-in: on an H100 its images match numba's, but it renders no
        faster than the JAX kernel, docs/decisions/0006-gpu-kernels.md); "auto" takes numba when JAX's default device is
        the CPU, else jax.
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
        numba and CUDA backends ignore it.
    ray_table : bool or None
        Keep the camera's rays on the device between frames (:mod:`swim.rt.ray_table`, the JAX kernel only): the
        rays' segments, starts, directions and occupancy probes are computed once per camera, observer and grid, and
        a batch of pixels sends only its rows' indices; the phase functions are computed on the device. The same
        kernel and results to float32 rounding of the scattering angle's cosine. None (the default): on where the
        JAX kernel runs on a GPU (:meth:`resolved_ray_table`; on an H100 a warm 1024^2 all-sky with every pixel
        traced renders in 0.151 s with it against 0.324 s without, adaptive 0.161 against 0.227 s, a new sun every
        frame 0.659 against 0.834 s; docs/decisions/0006-gpu-kernels.md), off on a CPU, where the march dominates and
        the table only holds memory. The numba and CUDA backends ignore it.
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
    cloud_scattering : str or CloudScattering
        How clouds scatter light (:mod:`swim.rt.clouds`): "discrete_ordinates" (the 3-D diffuse solution, the
        default; the numba and JAX kernels, not "cuda"; a sun below 0.6 deg of elevation falls back to
        "albers2020") or "albers2020" (the paper's Eqs. 12-26), or a :class:`swim.rt.clouds.CloudScattering` with
        its phase functions and accuracy settings; kept as the latter.
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

    n_before: int = 12
    n_grid: int = 128
    n_after: int = 28
    empty_steps: int | None = None
    sunlit_steps: int = 4
    n_probe: int = 64
    probe_spacing: float = 2.0
    tau_refine: float = 0.25
    stop_tau: float = 50.0
    chunk: int | None = None
    multiple_scattering: bool = True
    surface: str = "brdf"
    backend: str = "auto"
    grid_kernel: str = "auto"
    ray_table: bool | None = None
    step1a_on_device: bool | None = None
    device_sampling: bool | None = None
    device_image: bool | None = None
    fused_max_registers: int | None = None
    fused_vector_loads: bool = True
    fused_fma: bool = False
    cloud_scattering: object = "discrete_ordinates"

    def __post_init__(self):
        from .clouds import as_cloud_scattering

        object.__setattr__(self, "cloud_scattering", as_cloud_scattering(self.cloud_scattering))
        for name in ("n_before", "n_grid", "n_after", "empty_steps", "sunlit_steps", "n_probe", "chunk"):
            value, least = getattr(self, name), 1 if name in ("chunk", "n_probe") else 0
            if name in ("chunk", "empty_steps") and value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
                raise SwimInputError(f"MarchSettings.{name} must be an integer >= {least}, got {value!r}")
        # each 0 or a finite number >= its least value
        for name, what, least in (("probe_spacing", f"0 or a finite number of cells >= {MIN_PROBE_SPACING}",
                                    MIN_PROBE_SPACING), ("tau_refine", "a finite optical depth >= 0", 0.0),
                                  ("stop_tau", f"0 (off) or a finite optical depth >= {STOP_TAU_MIN:g} [-]",
                                   STOP_TAU_MIN)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                    or not np.isfinite(value) or value < 0 or 0 < value < least:
                raise SwimInputError(f"MarchSettings.{name} must be {what}, got {value!r}")
        if self.surface not in SURFACE_MODELS:
            raise SwimInputError(f"MarchSettings.surface must be one of {SURFACE_MODELS}, got {self.surface!r}")
        if self.backend not in BACKENDS:
            raise SwimInputError(f"MarchSettings.backend must be one of {BACKENDS}, got {self.backend!r}")
        if self.grid_kernel not in GRID_KERNELS:
            raise SwimInputError(f"MarchSettings.grid_kernel must be one of {GRID_KERNELS}, got {self.grid_kernel!r}")
        for name in ("ray_table", "step1a_on_device", "device_sampling", "device_image"):
            value = getattr(self, name)
            if value is not None and not isinstance(value, (bool, np.bool_)):
                raise SwimInputError(f"MarchSettings.{name} must be True, False or None, got {value!r}")
        from .ptx_edits import MAX_REGISTERS, MIN_REGISTERS  # ptxas's bounds, kept in one place

        registers = self.fused_max_registers
        if registers is not None and (isinstance(registers, bool) or not isinstance(registers, (int, np.integer))
                                      or not MIN_REGISTERS <= registers <= MAX_REGISTERS):
            raise SwimInputError(f"MarchSettings.fused_max_registers must be None or an integer in "
                                 f"[{MIN_REGISTERS}, {MAX_REGISTERS}] (registers per thread), got {registers!r}")
        for name in ("fused_vector_loads", "fused_fma"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise SwimInputError(f"MarchSettings.{name} must be True or False, got {getattr(self, name)!r}")

    def resolved_backend(self) -> str:
        """The kernel that runs: ``backend``, with "auto" resolved to "numba" when JAX's default device is the
        CPU and numba is installed, else "jax".

        Raises
        ------
        SwimInputError
            If ``backend`` is "numba" and numba is not installed, or "cuda" and numba-cuda finds no GPU.
        """
        if self.backend in ("numba", "cuda") and not _numba_available():
            raise SwimInputError(f"MarchSettings.backend={self.backend!r} needs the numba package (pip install numba)")
        if self.backend == "cuda":
            from .march_cuda import require_cuda

            require_cuda()
        if self.backend != "auto":
            return self.backend
        return "numba" if jax.default_backend() == "cpu" and _numba_available() else "jax"

    def resolved_grid_kernel(self) -> str:
        """The JAX kernel's march of the grid segment (:attr:`grid_kernel`): "auto" resolved to "fused" where JAX's
        default device is a GPU and Pallas can lower to Triton there, else "lockstep"; always "lockstep" with the 3-D
        cloud scattering, whose sources the fused kernel does not carry."""
        if self.cloud_scattering.three_d:
            return "lockstep"
        if self.grid_kernel != "auto":
            return self.grid_kernel
        from .march_pallas import pallas_triton_available

        return "fused" if pallas_triton_available() else "lockstep"

    def kernel_settings(self) -> MarchSettings:
        """These settings with those that the march's kernels do not read (:attr:`ray_table`,
        :attr:`step1a_on_device`, :attr:`device_sampling`, :attr:`device_image`) pinned to False, so that a compiled
        kernel (keyed by its settings, also on disk: :mod:`swim.rt.export_cache`) serves whatever they are: a
        recompilation of the JAX kernel takes tens of seconds on a GPU."""
        return replace(self, ray_table=False, step1a_on_device=False, device_sampling=False, device_image=False)

    def resolved_ray_table(self) -> bool:
        """Whether the camera's rays are kept on the device (:attr:`ray_table`): None resolved to True where the
        JAX kernel runs on a GPU (or another accelerator), else False; always False for the numba and CUDA
        kernels, which do not use it."""
        return self._jax_device_switch(self.ray_table)

    def resolved_step1a_on_device(self) -> bool:
        """Whether a new sun's Step 1a runs on the device's copy of the packed volume (:attr:`step1a_on_device`): None
        resolved to True where the JAX kernel runs on a GPU (or another accelerator), else False; always False for
        the numba and CUDA kernels, which keep no such copy."""
        return self._jax_device_switch(self.step1a_on_device)

    def _jax_device_switch(self, value) -> bool:
        """A switch of the JAX kernel's device copies (``value``: True, False or None): False for the other kernels
        and with the 3-D cloud scattering (its per-ray inputs and scaled Step 1a are the host's), else ``value``,
        None resolved to whether the march runs on an accelerator."""
        if self.resolved_backend() != "jax" or self.cloud_scattering.three_d:
            return False
        return self.on_accelerator() if value is None else bool(value)

    def resolved_device_sampling(self) -> bool:
        """Whether adaptive sampling keeps its image on the device (:attr:`device_sampling`): only with the camera's
        rays there (:meth:`resolved_ray_table`), and then None resolved to True."""
        if not self.resolved_ray_table():
            return False
        return True if self.device_sampling is None else bool(self.device_sampling)

    def resolved_device_image(self) -> bool:
        """Whether the image is finished on the device (:attr:`device_image`): only with the camera's rays there
        (:meth:`resolved_ray_table`), and then None resolved to whether the march runs on an accelerator."""
        return self.resolved_ray_table() and self._jax_device_switch(self.device_image)

    def resolved_empty_steps(self) -> int:
        """Most grid steps in a ray's empty space (:attr:`empty_steps`, None resolved to ``n_grid // 4``); 0: no
        limit, every ray takes ``n_grid`` grid steps."""
        return self.n_grid // 4 if self.empty_steps is None else int(self.empty_steps)

    def resolved_chunk(self) -> int:
        """Rays per kernel call: ``chunk``, or for None :data:`GPU_CHUNK` where the JAX kernel runs on a GPU (or
        another accelerator) and :data:`CPU_CHUNK` elsewhere."""
        if self.chunk is not None:
            return int(self.chunk)
        return GPU_CHUNK if self.on_accelerator() else CPU_CHUNK

    def on_accelerator(self) -> bool:
        """Whether the march runs on a GPU (or another accelerator): the CUDA kernel, or the JAX kernel where JAX's
        default device is not the CPU."""
        backend = self.resolved_backend()
        return backend == "cuda" or (backend == "jax" and jax.default_backend() != "cpu")


#: Rays per kernel call on a CPU (:meth:`MarchSettings.resolved_chunk`): small enough for its caches.
CPU_CHUNK = 4096
#: Rays per kernel call of the JAX kernel on a GPU: on an H100 1.9 million rays/s in chunks of 32768, 4.0 million
#: in chunks of 262144 and 4.4 million in one chunk of 1048576 (a 1024 x 1024 all-sky's 823 593 rays then pad to
#: 1048576: no faster); 1.6 GB of device memory at the peak (docs/performance.md, "The GPU kernels").
GPU_CHUNK = 262144

#: Kernels of the step loop (:attr:`MarchSettings.backend`).
BACKENDS = ("auto", "jax", "numba", "cuda")
#: Marches of the grid segment in the JAX kernel (:attr:`MarchSettings.grid_kernel`).
GRID_KERNELS = ("auto", "lockstep", "fused", "fused-march")


@functools.lru_cache(maxsize=None)
def _numba_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("numba") is not None


@dataclass(frozen=True)
class GridGeometry:
    """Geometry of the optical volume needed by the kernels (see :func:`grid_geometry`)."""

    origin: np.ndarray  # (2,) [m]
    matrix: np.ndarray  # (2, 2) [m / index]
    inverse: np.ndarray  # (2, 2) [index / m]
    z_bottom: float
    dz: float
    shape: tuple  # (nk, ny, nx)
    top: float
    affine_residual_cells: float = 0.0

    @property
    def spacing(self) -> float:
        """Horizontal grid spacing [m]: the square root of a cell's area."""
        return float(np.sqrt(abs(np.linalg.det(self.matrix))))


def grid_geometry(volume) -> GridGeometry:
    """:class:`GridGeometry` of an optical volume (:func:`swim.optics.volume.build_optical_volume`)."""
    matrix = np.asarray(volume.attrs["affine_matrix"], dtype=float).reshape(2, 2)
    nk, ny, nx = volume.variables["aerosol_extinction"].shape  # a Variable: no DataArray is made
    z_bottom = float(volume.attrs["z_bottom"])
    dz = float(volume.attrs["dz"])
    spacing = float(np.sqrt(abs(np.linalg.det(matrix))))
    return GridGeometry(np.asarray(volume.attrs["affine_origin"], dtype=float), matrix, np.linalg.inv(matrix),
                        z_bottom, dz, (nk, ny, nx), z_bottom + dz * (nk - 1),
                        float(volume.attrs.get("affine_max_residual_m", 0.0)) / spacing)


def ray_segments(origins, directions, geometry: GridGeometry, top=100_000.0, radius=EARTH_RADIUS_M):
    """Clip rays to the atmosphere, the sea-level sphere and the model grid (host side, float64), with NumPy: the
    reference of :func:`ray_segments_compiled`, which :func:`trace_rays` calls.

    Parameters
    ----------
    origins, directions : numpy.ndarray
        Shape (n, 3): ray origins [m] and unit directions in the scene frame.
    geometry : GridGeometry
    top : float
        Top of the atmosphere [m].

    Returns
    -------
    dict
        ``start`` (n, 3) [m]: rebased origins (first point inside the atmosphere) relative to the
        reference sea-level point (0, 0, R); ``bounds`` (n, 3) [m]: distances from ``start`` to the grid
        entry, grid exit and end of the ray; ``ends_on_ground`` (n,) bool; ``valid`` (n,) bool (False
        where the ray misses the atmosphere).
    """
    o = np.asarray(origins, dtype=float)
    d = np.asarray(directions, dtype=float)
    t1, t2 = ray_sphere_intersections(o, d, radius + top)
    valid = np.isfinite(t2) & (t2 > 0)
    s_start = np.where(valid, np.maximum(np.nan_to_num(t1), 0.0), 0.0)
    s_end = np.where(valid, t2, 0.0)
    g1, _ = ray_sphere_intersections(o, d, radius)
    hits_sea = np.isfinite(g1) & (g1 > 0) & (g1 < s_end)
    s_end = np.where(hits_sea, g1, s_end)

    # Model grid: below its top shell and inside its (slightly widened) lateral index bounds.
    k1, k2 = ray_sphere_intersections(o, d, radius + geometry.top)
    shell_in = np.where(np.isfinite(k1), np.maximum(k1, 0.0), np.inf)
    shell_out = np.where(np.isfinite(k2), k2, -np.inf)
    _, ny, nx = geometry.shape
    margin = _lateral_margin(geometry, radius)
    rel_x, rel_y = o[:, 0] - geometry.origin[0], o[:, 1] - geometry.origin[1]
    lo = np.full(len(o), -np.inf)
    hi = np.full(len(o), np.inf)
    for axis, n in ((0, nx), (1, ny)):
        a, b = -margin, n - 1 + margin
        # the inverse affine map element by element, not a matrix product: BLAS's fused multiply-adds differ from
        # one CPU to another, and the compiled twin (swim.rt.segments_cpu) takes these operations in this order
        row = geometry.inverse[axis]
        at = rel_x * row[0] + rel_y * row[1]
        rate = d[:, 0] * row[0] + d[:, 1] * row[1]
        with np.errstate(divide="ignore", invalid="ignore"):
            e1 = (a - at) / rate
            e2 = (b - at) / rate
        still = np.abs(rate) < 1e-12
        inside = (at >= a) & (at <= b)
        e_lo = np.where(still, np.where(inside, -np.inf, np.inf), np.minimum(e1, e2))
        e_hi = np.where(still, np.where(inside, np.inf, -np.inf), np.maximum(e1, e2))
        lo = np.maximum(lo, e_lo)
        hi = np.minimum(hi, e_hi)
    s_a = np.maximum.reduce([s_start, shell_in, lo])
    s_b = np.minimum.reduce([s_end, shell_out, hi])
    empty = ~(s_b > s_a)
    s_a = np.where(empty, s_start, s_a)
    s_b = np.where(empty, s_start, s_b)

    start = o + s_start[:, None] * d
    start[:, 2] -= radius
    bounds = np.stack([s_a - s_start, s_b - s_start, s_end - s_start], axis=1)
    bounds = np.where(valid[:, None], bounds, 0.0)
    return {"start": start, "bounds": bounds, "ends_on_ground": hits_sea & valid, "valid": valid}


def _lateral_margin(geometry: GridGeometry, radius):
    """Cells [-] by which :func:`ray_segments` widens the grid's lateral index bounds: the affine fit's error and
    the height-dependent scale of (x, y)."""
    _, ny, nx = geometry.shape
    return 1.0 + geometry.top / radius * max(nx, ny) + geometry.affine_residual_cells


def ray_segments_compiled(origins, directions, geometry: GridGeometry, top=100_000.0, radius=EARTH_RADIUS_M):
    """:func:`ray_segments` one ray at a time in compiled code (:mod:`swim.rt.segments_cpu`): the same arguments
    and dict, ~10x faster on a CPU (no float64 temporaries: 47 -> 4.7 ms for 200 000 rays on one thread here);
    what :func:`trace_rays` calls. The same operations in the same order, so the same results where NumPy's
    ``einsum`` sums three terms as this machine's does, else within float64 round-off
    (docs/decisions/0009-work-around-the-march.md)."""
    from .segments_cpu import ray_segments_into

    o = np.ascontiguousarray(origins, dtype=np.float64)
    d = np.ascontiguousarray(directions, dtype=np.float64)
    n = len(o)
    out = {"start": np.empty((n, 3)), "bounds": np.empty((n, 3)), "ends_on_ground": np.empty(n, np.bool_),
           "valid": np.empty(n, np.bool_)}
    _, ny, nx = geometry.shape
    ray_segments_into(o, d, np.ascontiguousarray(geometry.origin, dtype=np.float64),
                      np.ascontiguousarray(geometry.inverse, dtype=np.float64), (ny, nx),
                      float(_lateral_margin(geometry, radius)), float(radius), float(top), float(geometry.top),
                      out["start"], out["bounds"], out["ends_on_ground"], out["valid"])
    return out


def check_rays(caller, origins, directions):
    """Raise :class:`SwimInputError` naming ``caller`` unless ``origins`` and ``directions`` are finite (n, 3) arrays
    [m, unit vectors] with n >= 1 (what :func:`trace_rays` and :func:`swim.rt.ray_table.build_ray_table` take)."""
    for name, value in (("origins", origins), ("directions", directions)):
        value = np.asarray(value, dtype=float)
        if value.ndim != 2 or value.shape[-1] != 3 or not np.all(np.isfinite(value)):
            raise SwimInputError(f"{caller}: {name} must be a finite (n, 3) array [m for origins, unit vectors "
                                 f"for directions], got shape {value.shape} with non-finite values or the wrong shape")
    if len(origins) == 0:
        raise SwimInputError(f"{caller} needs at least one ray, got none")


def without_empty_segments(settings: MarchSettings, has) -> MarchSettings:
    """``settings`` with no steps for the segments (before, in, after the grid) that ``has`` (3 bools) says no ray
    of a batch has: a batch of observers inside the grid marches nothing before it."""
    return replace(settings, **{name: 0 for name, there in zip(("n_before", "n_grid", "n_after"), has) if not there})


def ray_segments_parallel(origins, directions, geometry: GridGeometry, top=100_000.0):
    """:func:`ray_segments_compiled` in blocks on up to 8 cores (the kernel runs without the GIL), a block per thread
    at least where there are :data:`SEGMENT_MIN_BLOCK` rays per thread: what :func:`trace_rays` and
    :func:`swim.rt.ray_table.build_ray_table` call. Compiled, ~45 -> ~7 ms of a warm 1024^2 adaptive all-sky
    (docs/decisions/0009-work-around-the-march.md); an adaptive render's batches of 20 000-70 000 rays were one block,
    on one thread while the others waited. The same arguments and dict as :func:`ray_segments`."""
    workers = min(threads(), 8)
    block = min(SEGMENT_BLOCK, max(SEGMENT_MIN_BLOCK, -(-len(origins) // workers)))

    def segments(lo):
        return ray_segments_compiled(origins[lo:lo + block], directions[lo:lo + block], geometry, top=top)

    blocks = parallel_map(segments, range(0, len(origins), block), workers)
    return {key: np.concatenate([b[key] for b in blocks]) for key in blocks[0]} if len(blocks) > 1 else blocks[0]


# ----------------------------------------------------------------------------------------------------
# JAX kernels
# ----------------------------------------------------------------------------------------------------

# The tables are stored channel-major, (C, ...), and sampled by one scalar gather per channel and corner from their
# flattened form: XLA on CPU fuses scalar gathers into the surrounding arithmetic, while a gather of (C,)-rows was
# a separate, several times slower operation (a 6-channel bilinear lookup took 35 ns per sample against 209 ns;
# docs/decisions/0006-gpu-kernels.md). The volume's trilinear sample is the exception since JAX 0.10: see trilinear.

def _materialise(x):
    """Compute x once: without the barrier XLA on a CPU may fuse the gathers into each of x's consumers and repeat
    them (the kernel ~9 % slower). On a GPU the barriers cost more than they save: each ends a fusion, so its
    values go through device memory; without them the kernel is 18 % faster on an H100
    (docs/decisions/0006-gpu-kernels.md), so there x passes unchanged."""
    if jax.default_backend() != "cpu":
        return x
    return jax.lax.optimization_barrier(x)


def lerp_gathers(flat, n_channels, n, f, row=0, stride=None):
    """Linear interpolation of a flattened channel-major table along rows of n values, at fractional indices f,
    clamped: a list of ``n_channels`` arrays shaped like f. Channel c's row starts at ``c * stride + row`` (``stride``
    None: n; ``row`` may be per point, as each ray's own profile in :func:`_profile_at`). ``flat`` is an array or a
    Pallas ref (:mod:`swim.rt.march_pallas`: the same indexing reads it)."""
    stride = n if stride is None else stride
    f = jnp.clip(f, 0.0, n - 1.001)
    i0 = jnp.floor(f).astype(jnp.int32)
    w = f - i0
    at = row + i0
    return [flat[c * stride + at] * (1 - w) + flat[c * stride + at + 1] * w for c in range(n_channels)]


def _lerp_table(table, f):
    """Linear interpolation of a channel-major (C, n) table at fractional indices f (n_pts,), clamped: (n_pts, C)."""
    return _materialise(jnp.stack(lerp_gathers(table.reshape(-1), *table.shape, f), axis=-1))


def bilinear_gathers(flat, shape, fu, fv, prepare=None):
    """Bilinear interpolation of a flattened channel-major (C, nu, nv) table at fractional indices fu, fv, clamped: a
    list of C arrays shaped like fu. ``flat`` is an array or a Pallas ref (:mod:`swim.rt.march_pallas`: the same
    indexing reads it); ``prepare`` is applied to the cell's offset and the weights before the gathers
    (:func:`_materialise` in :func:`_bilinear_table`)."""
    n_c, nu, nv = shape
    fu = jnp.clip(fu, 0.0, nu - 1.001)
    fv = jnp.clip(fv, 0.0, nv - 1.001)
    u0 = jnp.floor(fu).astype(jnp.int32)
    v0 = jnp.floor(fv).astype(jnp.int32)
    a = fu - u0
    b = fv - v0
    r = u0 * nv + v0
    if prepare is not None:
        r, a, b = prepare((r, a, b))
    out = []
    for c in range(n_c):
        t = c * nu * nv + r
        out.append((flat[t] * (1 - b) + flat[t + 1] * b) * (1 - a) + (flat[t + nv] * (1 - b) + flat[t + nv + 1] * b) * a)
    return out


def _bilinear_table(table, fu, fv):
    """Bilinear interpolation of a channel-major (C, nu, nv) table at fractional indices, clamped: (n_pts, C)."""
    return _materialise(jnp.stack(bilinear_gathers(table.reshape(-1), table.shape, fu, fv, _materialise), axis=-1))


def _cell_weights(shape, k, j, i):
    """The lower corner (k0, j0, i0) of the cell around fractional indices k, j, i of a (nk, ny, nx, ...) volume,
    clamped to the volume, the weights (fk, fj, fi) of its far corners and whether the point lies inside."""
    nk, ny, nx = shape[:3]
    inside = (k >= 0) & (k <= nk - 1) & (j >= 0) & (j <= ny - 1) & (i >= 0) & (i <= nx - 1)
    k0 = jnp.clip(jnp.floor(k), 0, nk - 2).astype(jnp.int32)
    j0 = jnp.clip(jnp.floor(j), 0, ny - 2).astype(jnp.int32)
    i0 = jnp.clip(jnp.floor(i), 0, nx - 2).astype(jnp.int32)
    fk = jnp.clip(k - k0, 0.0, 1.0)
    fj = jnp.clip(j - j0, 0.0, 1.0)
    fi = jnp.clip(i - i0, 0.0, 1.0)
    return inside, k0, j0, i0, fk, fj, fi


def trilinear_gathers(flat, shape, k, j, i, outside, prepare=None):
    """Trilinear sample of a flattened (nk, ny, nx, C) volume at fractional indices, one scalar gather per channel and
    corner: a list of C arrays shaped like k, each ``outside[c]`` beyond the volume. ``flat`` is an array or a Pallas
    ref (:mod:`swim.rt.march_pallas`: the same indexing reads it); ``prepare`` is applied to the corner's offset and
    the weights before the gathers (:func:`_materialise` in :func:`trilinear`)."""
    ny, nx, n_c = shape[1:]
    inside, k0, j0, i0, fk, fj, fi = _cell_weights(shape, k, j, i)
    base = ((k0 * ny + j0) * nx + i0) * n_c
    if prepare is not None:
        base, fk, fj, fi, inside = prepare((base, fk, fj, fi, inside))
    row_step, plane_step = nx * n_c, ny * nx * n_c
    channels = []
    for c in range(n_c):
        def row(b):
            return flat[b + c] * (1 - fi) + flat[b + c + n_c] * fi

        def plane(b):
            return row(b) * (1 - fj) + row(b + row_step) * fj

        channels.append(jnp.where(inside, plane(base) * (1 - fk) + plane(base + plane_step) * fk, outside[c]))
    return channels


def trilinear(volume, k, j, i, outside):
    """Trilinear sample of a (nk, ny, nx, C) volume at fractional indices: (n_pts, C); ``outside`` (C,) beyond it.

    The channels of a cell stay adjacent in memory (one cache line for all of them). On a CPU each of the 8
    corners is read as one row of C channels: with JAX 0.10 the kernel marches 1.9x faster so than with one scalar
    gather per channel and corner, the reverse of what an older XLA did (see the note above :func:`_lerp_table`;
    docs/decisions/0006-gpu-kernels.md). On a GPU the scalar gathers from the flattened volume stay
    (:func:`trilinear_gathers`): rows were 6 % slower on an H100."""
    if jax.default_backend() != "cpu":
        return _materialise(jnp.stack(trilinear_gathers(volume.reshape(-1), volume.shape, k, j, i, outside,
                                                        _materialise), axis=-1))
    nk, ny, nx, n_c = volume.shape
    inside, k0, j0, i0, fk, fj, fi = _cell_weights(volume.shape, k, j, i)
    cells = volume.reshape(-1, n_c)
    cell = (k0 * ny + j0) * nx + i0
    fk, fj, fi = fk[:, None], fj[:, None], fi[:, None]

    def corner(dk, dj, di):
        return cells[cell + (dk * ny + dj) * nx + di]

    def plane(dk):
        return ((corner(dk, 0, 0) * (1 - fi) + corner(dk, 0, 1) * fi) * (1 - fj)
                + (corner(dk, 1, 0) * (1 - fi) + corner(dk, 1, 1) * fi) * fj)

    return jnp.where(inside[:, None], plane(0) * (1 - fk) + plane(1) * fk, outside[None, :])


def bilinear_clamped(field, j, i):
    """Bilinear sample of a channel-major (C, ny, nx) field, clamped to its edges: (n_pts, C)."""
    ny, nx = field.shape[1:]
    return _bilinear_table(field, jnp.clip(j, 0, ny - 1), jnp.clip(i, 0, nx - 1))


def _point_geometry(q, consts):
    """Height, grid indices and local solar-zenith cosine of points q (n, 3) relative to (0, 0, R)."""
    radius = consts["radius"]
    pz = q[:, 2] + radius
    r = jnp.sqrt(q[:, 0] ** 2 + q[:, 1] ** 2 + pz**2)
    # Stable form of |p| - R for points near the sea-level sphere.
    h = (q[:, 0] ** 2 + q[:, 1] ** 2 + q[:, 2] ** 2 + 2 * radius * q[:, 2]) / (r + radius)
    sun = consts["sun"]
    mu_s = (q[:, 0] * sun[0] + q[:, 1] * sun[1] + pz * sun[2]) / r
    i, j = grid_indices(consts["index_map"], radius * q[:, 0] / r, radius * q[:, 1] / r, jnp)
    k = (h - consts["z_bottom"]) / consts["dz"]
    return _materialise((h, mu_s, k, j, i))


def _gas_at(h, mu_s, consts):
    """Clear-atmosphere quantities at heights h [m] and local solar-zenith cosines mu_s.

    Returns the Rayleigh, background-aerosol and stratospheric-aerosol extinction (n, 3) [m-1] (one
    lookup in a joint height table of their profiles, times their spectral factors: each is a height profile
    times a spectrum), and the sun transmittance and horizontal diffuse irradiance / E_TOA (n, 3) each (one
    bilinear lookup in the joint (height, mu_s) table).
    """
    profile = _lerp_table(consts["beta_gas"][:GAS_COLUMN_ROW], h / consts["dh"])
    spectra = consts["beta_gas_spectra"]  # (3 components, 3 wavelengths)
    beta = jnp.concatenate([profile[:, c : c + 1] * spectra[c][None, :] for c in range(3)], axis=-1)
    nu, nmu = consts["sky"].shape[1:]
    fu = jnp.sqrt(jnp.clip(h / consts["top"], 0.0, 1.0)) * (nu - 1)
    fm = (mu_s + 1.0) * 0.5 * (nmu - 1)
    sky = _bilinear_table(consts["sky"], fu, fm)
    return beta[:, :3], beta[:, 3:6], beta[:, 6:], sky[:, :3], sky[:, 3:]


def lowest_point(start, direction, bounds, consts, end=None):
    """The point of each ray closest to the earth's centre, clipped to the traced segment (n, 3).

    Rebased like ``start`` (scene frame minus (0, 0, R)): the observer for upward views, the ground for
    downward ones, the tangent point for limb views. Inputs: the chunk's rebased ``start`` (n, 3) [m], unit
    ``direction`` (n, 3) and ``bounds`` (n, 3) [m] of :func:`ray_segments`; ``end`` (n,) [m]: the lowest point up
    to there instead of the segment's end ``bounds[:, 2]``.
    """
    radius = consts["radius"]
    pz = start[:, 2] + radius
    s_low = jnp.clip(-(start[:, 0] * direction[:, 0] + start[:, 1] * direction[:, 1] + pz * direction[:, 2]),
                     0.0, bounds[:, 2] if end is None else end)
    return start + s_low[:, None] * direction


def aerosol_class_weights(point, consts):
    """Class of the 3-D aerosol column at rebased points (n, 3): lower class index (n,) and weight (n, 1).

    Linear in the column optical depth between the classes of :func:`swim.rt.gas.aerosol_column_classes`
    (clamped at both ends); index 0 and weight 0 when the tables have a single class.
    """
    class_aod = consts["class_aod"]
    n_class = class_aod.shape[0]
    if n_class == 1:
        return jnp.zeros(point.shape[0], jnp.int32), jnp.zeros((point.shape[0], 1), jnp.float32)
    _, _, _, j, i = _point_geometry(point, consts)
    column = bilinear_clamped(consts["aerosol_column"], j, i)[:, 0]
    f = jnp.clip(jnp.interp(column, class_aod, jnp.arange(n_class, dtype=jnp.float32)), 0.0, n_class - 1.001)
    c0 = jnp.floor(f).astype(jnp.int32)
    return c0, (f - c0)[:, None]


def diffuse_at(h, mu_s, aerosol_class, consts):
    """Downward diffuse irradiance on a horizontal surface / E_TOA (n, 3) of the ray's aerosol class."""
    table = consts["diffuse_classes"]  # (3, n_class * nu, nmu): the classes stacked along the height axis
    n_class = consts["class_aod"].shape[0]
    nu, nmu = table.shape[1] // n_class, table.shape[2]
    fu = jnp.sqrt(jnp.clip(h / consts["top"], 0.0, 1.0)) * (nu - 1)
    fm = (mu_s + 1.0) * 0.5 * (nmu - 1)
    if n_class == 1:
        return _bilinear_table(table, fu, fm)
    # Rows c nu ... c nu + nu - 1 hold class c; with fu clamped inside a class, the bilinear lookup never mixes
    # two classes.
    c0, wc = aerosol_class
    fu = jnp.clip(fu, 0.0, nu - 1.001)
    lower = _bilinear_table(table, c0 * nu + fu, fm)
    upper = _bilinear_table(table, (c0 + 1) * nu + fu, fm)
    return lower * (1 - wc) + upper * wc


def diffuse_source_profiles(point, direction, aerosol_class, consts):
    """Per-ray height profiles of the diffuse (multiple-scattering) source, (9, n, n_u).

    The table of :mod:`swim.rt.multiple_scattering` depends on the local sun and view cosines and the
    relative azimuth, which change along a ray only through the curvature of the earth. Each ray takes them
    at its lowest point in the atmosphere (:func:`lowest_point`: the observer for upward views, the ground
    for downward ones, the tangent point for limb views), where most of its scattering happens, and keeps
    the height dependence; with a 3-D aerosol field it takes the table of the aerosol column there
    (:func:`aerosol_class_weights`, the project's form of Eqs. 30-31).

    Inputs are the rebased ``point`` (n, 3) [m] of :func:`lowest_point`, the unit ``direction`` (n, 3) and
    the class of :func:`aerosol_class_weights`; the result, channel-major (9, n, n_u), holds J of molecules, aerosol and stratospheric
    aerosol at 615/546/450 nm [-] (solar-relative radiance per unit scattering optical depth) on the table's
    heights.
    """
    q = point + jnp.array([0.0, 0.0, 1.0], jnp.float32) * consts["radius"]
    up = q / jnp.linalg.norm(q, axis=1, keepdims=True)
    sun = consts["sun"]
    mu_v = jnp.sum(up * direction, axis=1)
    mu_s = up @ sun
    cos_phi = (direction @ sun - mu_v * mu_s) / jnp.sqrt(jnp.maximum((1 - mu_v**2) * (1 - mu_s**2), 1e-12))
    table = consts["ms_source"]  # (n_class, n_s, n_v, n_phi, n_u, 9)
    n_s, n_v, n_phi = table.shape[1:4]
    fs = jnp.clip(jnp.sqrt(jnp.clip(mu_s, 0.0, 1.0)) * (n_s - 1), 0.0, n_s - 1.001)
    fv = jnp.clip((mu_v + 1.0) * 0.5 * (n_v - 1), 0.0, n_v - 1.001)
    fp = jnp.clip(jnp.arccos(jnp.clip(cos_phi, -1.0, 1.0)) / jnp.pi * (n_phi - 1), 0.0, n_phi - 1.001)
    s0, v0, p0 = (jnp.floor(f).astype(jnp.int32) for f in (fs, fv, fp))
    ws, wv, wp = ((f - jnp.floor(f))[:, None, None] for f in (fs, fv, fp))
    c0, wc = aerosol_class
    classes = ((0, 1.0),) if table.shape[0] == 1 else ((0, 1 - wc[:, :, None]), (1, wc[:, :, None]))
    profile = 0.0
    for dc, w in classes:
        for ds, a in ((0, 1 - ws), (1, ws)):
            for dv, b in ((0, 1 - wv), (1, wv)):
                for dp, c in ((0, 1 - wp), (1, wp)):
                    profile = profile + table[c0 + dc, s0 + ds, v0 + dv, p0 + dp] * (a * b * c * w)
    return jnp.moveaxis(profile, -1, 0)


def _profile_at(profile, h, consts):
    """Linear interpolation of channel-major per-ray profiles (C, n, n_u) on u = sqrt(h / H_top) at the rays'
    heights h (n,): (n, C)."""
    n_c, n, n_u = profile.shape
    u = jnp.sqrt(jnp.clip(h / consts["top"], 0.0, 1.0)) * (n_u - 1)
    return _materialise(jnp.stack(lerp_gathers(profile.reshape(-1), n_c, n_u, u, row=jnp.arange(n) * n_u,
                                               stride=n * n_u), axis=-1))


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


def _probe_indices(start, direction, s0, length, consts, n_probe, count=None):
    """Grid indices (k, j, i), each (n_probe, n), of the probes at the middles of equal intervals of each ray's
    grid segment: ``n_probe`` of them, or the first ``count`` (n,) <= n_probe of each ray's own count (the others
    then repeat the last)."""
    m = jnp.arange(n_probe, dtype=jnp.float32)[:, None]
    count = jnp.float32(n_probe) if count is None else count.astype(jnp.float32)[None, :]
    f = (jnp.minimum(m, count - 1) + 0.5) / count
    s = s0[None, :] + f * length[None, :]
    q = (start[None] + s[..., None] * direction[None]).reshape(-1, 3)
    _, _, k, j, i = _point_geometry(q, consts)
    return tuple(x.reshape(n_probe, -1) for x in (k, j, i))


def probe_counts(start, direction, s0, length, consts, n_probe=N_OCCUPANCY_PROBES,
                 probe_spacing=MarchSettings.probe_spacing):
    """Occupancy probes per ray (n,) int32 for :func:`adaptive_step_edges`: ``n_probe``, or for a ray whose grid
    segment crosses more than ``n_probe * probe_spacing`` cells one per ``probe_spacing`` cells, at most
    :data:`MAX_PROBES`.

    A segment's length in cells is the Chebyshev length of its path in grid indices (:func:`segment_cells`): the
    number of cells the ray passes along its dominant axis. ``probe_spacing`` 0 gives ``n_probe`` for every ray.
    """
    if not probe_spacing:
        return jnp.full(start.shape[:1], n_probe, jnp.int32)
    return probe_counts_and_cells(start, direction, s0, length, consts, n_probe, probe_spacing)[0]


def probe_counts_and_cells(start, direction, s0, length, consts, n_probe=N_OCCUPANCY_PROBES,
                           probe_spacing=MarchSettings.probe_spacing):
    """:func:`probe_counts` (n,) int32 and the grid segments' lengths in cells (n,) [-] that they come from
    (:func:`segment_cells`; ``probe_spacing`` 0 gives ``n_probe`` probes for every ray)."""
    cells = segment_cells(start, direction, s0, length, consts)
    if not probe_spacing:
        return jnp.full(start.shape[:1], n_probe, jnp.int32), cells
    # CELL_SLACK: a ray along a grid axis crosses a whole number of cells, which must not round up in float32
    # here and not in float64 in the numba kernel (or the other way round)
    need = jnp.ceil(cells / probe_spacing - CELL_SLACK)
    return jnp.clip(need, n_probe, max(MAX_PROBES, n_probe)).astype(jnp.int32), cells


def segment_cells(start, direction, s0, length, consts):
    """Length in cells (n,) [-] of each ray's grid segment [s0, s0 + length] [m]: the Chebyshev length of its path
    in grid indices, measured at :data:`CELL_PROBES` points (the middles of equal intervals; the largest index change
    between neighbouring points, summed and extended by the half intervals at the ends), the cells the ray passes
    along its dominant axis.

    Measured apart from the occupancy probes, at fewer points: the march probed every ray's occupancy at ``n_probe``
    points for its length alone before probing it again at the count that length asks for (every ray of a 1024^2
    all-sky of the 400 x 400 x 60 scene, whose 160 levels make even the zenith's ray cross more than ``n_probe``
    times ``probe_spacing`` cells): 64 of a ray's ~147 probes there (docs/decisions/0003-cpu-kernel-code.md)."""
    k, j, i = _probe_indices(start, direction, s0, length, consts, CELL_PROBES)
    return _segment_cells(k, j, i, CELL_PROBES)


def _segment_cells(k, j, i, n_probe):
    """Length in cells (n,) of each ray's grid segment from the grid indices (n_probe, n) of its equally spaced
    probes: the largest index change between neighbouring probes, summed and extended by the half intervals at
    the segment's ends."""
    step = jnp.maximum(jnp.maximum(jnp.abs(jnp.diff(k, axis=0)), jnp.abs(jnp.diff(j, axis=0))), jnp.abs(jnp.diff(i, axis=0)))
    return jnp.sum(step, axis=0) * (n_probe / max(n_probe - 1, 1))


def adaptive_step_edges(start, direction, s0, length, n_steps, consts, n_probe=N_OCCUPANCY_PROBES,
                        empty_weight=EMPTY_STEP_WEIGHT, probes=None):
    """Edges (n_steps + 1, n) [m] of n_steps steps through the grid, concentrated where something happens
    (:func:`grid_step_edges` without a limit on the steps in empty space: every ray takes n_steps).

    Empty-space skipping for rays marched in lockstep: each ray probes the (dilated) occupancy grid of
    :func:`occupancy_grid` (hydrometeors, the terrain, gradients of the 3-D aerosol) at ``n_probe`` equal
    intervals of its grid segment (or at its own count ``probes`` (n,) <= n_probe, from :func:`probe_counts`)
    and spreads its steps with density 1 in occupied and ``empty_weight`` in empty intervals (inverse of the
    piecewise-linear cumulative density). Every ray takes the same number of steps, so no ray waits for
    another, and clear air still gets steps (a cloud missed by the probes is sampled as by a uniform march of
    n_steps empty_weight / (occupied + empty_weight (n_probe - occupied)) steps per interval).
    """
    return grid_step_edges(start, direction, s0, length, n_steps, consts, n_probe, empty_weight, probes)[0]


def grid_step_edges(start, direction, s0, length, n_steps, consts, n_probe=N_OCCUPANCY_PROBES,
                    empty_weight=EMPTY_STEP_WEIGHT, probes=None, cells=None, empty_steps=0, sunlit_steps=0):
    """Edges (n_steps + 1, n) [m] and counts (n,) int32 of each ray's steps through the grid: dense where something
    happens, few where nothing does.

    The steps of :func:`adaptive_step_edges` (density 1 in occupied and ``empty_weight`` in empty probe intervals),
    with the steps in empty space limited (empty-space skipping; docs/decisions/0004-step-placement.md): where the
    empty intervals would get more than ``max(empty_steps, empty cells / EMPTY_CELLS_PER_STEP)`` steps (the empty
    cells are the segment's ``cells`` (n,) times its share of empty probes), they get that many, and the ray
    takes fewer steps in all, ``ceil(occupied steps + that)``, so that its occupied intervals keep their step
    density. A ray through clear air alone takes ``empty_steps`` equal steps instead of n_steps. A ray's edges
    beyond its count repeat the segment's end; its march stops there. ``empty_steps`` 0: every ray takes
    n_steps, as in :func:`adaptive_step_edges`.

    Where ``consts["occupancy"]`` holds the step classes of :func:`step_classes` and ``sunlit_steps`` > 0, the
    sunlit clear intervals (code :data:`SUNLIT_CLEAR`) are limited in the same way on their own, to
    ``max(sunlit_steps, sunlit cells / SUNLIT_CELLS_PER_STEP)`` steps, and the weight left to the unoccupied
    intervals is shared in proportion to the two kinds' limited steps (docs/decisions/0004-step-placement.md); with
    ``sunlit_steps`` 0 they count as empty.

    ``probes`` (n,): each ray's probe count (:func:`probe_counts`, at most ``n_probe``), or None for ``n_probe``
    each; ``cells``: the segments' lengths in cells of :func:`segment_cells` (needed with ``probes`` and
    ``empty_steps``; without ``probes`` they are measured here).
    """
    n = start.shape[0]
    count = jnp.full((n,), n_probe, jnp.int32) if probes is None else jnp.minimum(probes.astype(jnp.int32), n_probe)
    k, j, i = _probe_indices(start, direction, s0, length, consts, n_probe, None if probes is None else count)
    occupancy = jnp.asarray(consts["occupancy"])
    nk, ny, nx = occupancy.shape
    kk, jj, ii = (jnp.clip(jnp.round(x), 0, size - 1).astype(jnp.int32) for x, size in ((k, nk), (j, ny), (i, nx)))
    kind = occupancy.reshape(-1)[(kk * ny + jj) * nx + ii].reshape(n_probe, n)
    occupied = kind > 0
    own = jnp.arange(n_probe)[:, None] < count[None, :]  # a ray's own probes only
    sunlit = (kind < 0) & own if sunlit_steps else jnp.zeros_like(own)
    steps = jnp.full((n,), n_steps, jnp.int32)
    weight_empty = weight_sunlit = jnp.float32(empty_weight)
    if empty_steps:
        if cells is None:
            if probes is not None:
                raise ValueError("grid_step_edges: cells are needed with probes (probe_counts_and_cells)")
            cells = segment_cells(start, direction, s0, length, consts)
        n_occupied = jnp.sum(occupied & own, axis=0).astype(jnp.float32)
        n_sunlit = jnp.sum(sunlit, axis=0).astype(jnp.float32)
        n_empty = count.astype(jnp.float32) - n_occupied - n_sunlit
        total = n_occupied + empty_weight * (n_empty + n_sunlit)
        # CELL_SLACK: a ray along a grid axis crosses a whole number of cells, which must not round the step count
        # up in float32 here and not in float64 in the numba kernel (as in probe_counts_and_cells)
        steps_empty = n_steps * empty_weight * n_empty / total
        budget = jnp.maximum(jnp.float32(empty_steps),
                             cells * n_empty / (count.astype(jnp.float32) * EMPTY_CELLS_PER_STEP) - CELL_SLACK)
        capped = (n_empty > 0) & (steps_empty > budget)
        steps_empty = jnp.where(capped, budget, steps_empty)
        steps_sunlit = n_steps * empty_weight * n_sunlit / total
        if sunlit_steps:
            budget = jnp.maximum(jnp.float32(sunlit_steps),
                                 cells * n_sunlit / (count.astype(jnp.float32) * SUNLIT_CELLS_PER_STEP) - CELL_SLACK)
            capped_sunlit = (n_sunlit > 0) & (steps_sunlit > budget)
            steps_sunlit = jnp.where(capped_sunlit, budget, steps_sunlit)
            capped = capped | capped_sunlit
        fewer = jnp.minimum(jnp.ceil(n_steps * n_occupied / total + steps_empty + steps_sunlit), n_steps)
        # the weight left to the unoccupied intervals at the occupied ones' steps per unit weight, n_steps / total,
        # shared in proportion to their capped steps
        rest = fewer * total / n_steps - n_occupied
        share = steps_empty / jnp.maximum(steps_empty + steps_sunlit, jnp.float32(1e-30))
        weight_empty = jnp.where(capped, rest / jnp.maximum(n_empty, 1.0) * share, weight_empty)[None, :]
        weight_sunlit = jnp.where(capped, rest / jnp.maximum(n_sunlit, 1.0) * (1.0 - share), weight_sunlit)[None, :]
        steps = jnp.where(capped, fewer, n_steps).astype(jnp.int32)
    weight = jnp.where(own, jnp.where(occupied, 1.0, jnp.where(sunlit, weight_sunlit, weight_empty)), 0.0)
    return _edges_from_density(weight, count, s0, length, n_steps, steps), steps


def _edges_from_density(weight, count, s0, length, n_steps, steps=None):
    """Edges (n_steps + 1, n) [m] that cut the piecewise-constant step density ``weight`` (n_probe, n) over each
    ray's ``count`` (n,) equal probe intervals of [s0, s0 + length] into n_steps equal parts (the inverse of the
    piecewise-linear cumulative density), or into ``steps`` (n,) <= n_steps parts each (the edges beyond them
    repeating the end)."""
    n = weight.shape[1]
    cdf = jnp.concatenate([jnp.zeros((1, n), jnp.float32), jnp.cumsum(weight, axis=0)], axis=0)
    cdf = cdf / cdf[-1:]
    m = jnp.arange(n_steps + 1, dtype=jnp.float32)
    if steps is None:
        targets = jnp.broadcast_to((m / n_steps)[:, None], (n_steps + 1, n))
    else:
        parts = steps.astype(jnp.float32)[None, :]
        targets = jnp.minimum(m[:, None], parts) / parts
    idx = jnp.clip(jax.vmap(lambda c, t: jnp.searchsorted(c, t, side="right") - 1, in_axes=1, out_axes=1)(cdf, targets),
                   0, count[None, :] - 1)
    c0 = jnp.take_along_axis(cdf, idx, axis=0)
    c1 = jnp.take_along_axis(cdf, idx + 1, axis=0)
    frac = jnp.clip((idx + (targets - c0) / jnp.maximum(c1 - c0, 1e-12)) / count[None, :].astype(jnp.float32),
                    0.0, 1.0)
    return s0[None, :] + frac * length[None, :]


def clear_step_edges(start, direction, s0, length, n_steps, consts, n_probe=CLEAR_PROBES, steps=None):
    """Edges (n_steps + 1, n) [m] of n_steps steps through the clear air before or after the grid, dense where
    the air is.

    The steps integrate the clear-sky source of Step 2 (single scattering and the diffuse source, Albers et al.
    2020, Eq. 3, doi:10.5194/amt-13-3235-2020) by the midpoint rule, whose error over a step of length ds is
    ~ f'' ds^3 / 24; for an integrand that falls exponentially with height (f'' ~ f / H^2) the error is spread
    evenly by a step density ~ f^(1/3) (the placement is ours, not the paper's: it marches Step 2 separately,
    Sect. 3.3). Each ray
    probes the extinction at 546 nm (Rayleigh, background and stratospheric aerosol: the clear-sky source's
    coefficients) at ``n_probe`` equal intervals and spreads its steps with density extinction^(1/3) plus
    :data:`CLEAR_STEP_FLOOR` times its largest value (so that the thin air far up still gets steps). Against a
    march of 384 + 256 equal steps, the default 24 steps after and 12 before the grid so placed are as accurate
    as the 48 and 32 equal steps they replace, or more (median error of ground views 0.013 % against 0.022 %, of
    a view from 800 km 0.25 % against 0.26 %; docs/decisions/0004-step-placement.md). A ray that rises out of
    the grid takes fewer steps after it where little of its air lies there (:func:`after_step_counts`,
    docs/decisions/0004-step-placement.md).

    Inputs per ray (n = rays): rebased ``start`` (n, 3) [m], unit ``direction`` (n, 3), the segment's start ``s0``
    and ``length`` (n,) [m]; ``steps`` (n,) <= n_steps: each ray's own step count (:func:`after_step_counts`), the
    edges beyond it repeating the segment's end (None: n_steps each).
    """
    n = start.shape[0]
    f = (jnp.arange(n_probe, dtype=jnp.float32)[:, None] + 0.5) / n_probe
    s = s0[None, :] + f * length[None, :]
    q = (start[None] + s[..., None] * direction[None]).reshape(-1, 3)
    h, mu_s, *_ = _point_geometry(q, consts)
    beta_r, beta_a, beta_s, _, _ = _gas_at(h, mu_s, consts)  # (the sky lookup unused: XLA drops it)
    beta = beta_r[:, 1] + beta_a[:, 1] + beta_s[:, 1]
    density = jnp.maximum(beta, 0.0).reshape(n_probe, n) ** CLEAR_STEP_POWER
    density = density + CLEAR_STEP_FLOOR * jnp.max(density, axis=0, keepdims=True) + 1e-30
    return _edges_from_density(density, jnp.full((n,), n_probe, jnp.int32), s0, length, n_steps, steps)


def gas_column_above(profiles, spectra, dh):
    """Fraction [-] of the clear air's vertical optical depth at 546 nm that lies above each height of the gas
    tables' height grid (trapezoidal rule; 1 at the grid's first height, 0 at its top; 1 everywhere for an empty
    atmosphere).

    Parameters
    ----------
    profiles : array_like, shape (3, n_gas)
        Extinction [m-1] of molecules (Rayleigh), background and stratospheric aerosol at the first wavelength, at
        heights ``dh * arange(n_gas)`` [m].
    spectra : array_like, shape (3, 3)
        Each component's extinction at the three wavelengths relative to the first.
    dh : float
        Height step [m] of the grid.

    Returns
    -------
    numpy.ndarray, shape (n_gas,)
        The column above each height over the whole column [-], non-increasing.
    """
    beta = (np.asarray(profiles, dtype=float) * np.asarray(spectra, dtype=float)[:, 1:2]).sum(axis=0)
    layers = 0.5 * (beta[1:] + beta[:-1]) * float(dh)
    above = np.concatenate([np.cumsum(layers[::-1])[::-1], [0.0]])
    return above / above[0] if above[0] > 0 else np.ones_like(above)


def after_step_counts(start, direction, bounds, n_after, consts):
    """Clear-air steps (n,) of each ray's segment after the grid: ``n_after`` times the square root of the fraction
    q of the vertical optical depth above the ray's lowest point (up to its grid exit) that lies above its exit, at
    least :data:`swim.constants.AFTER_MIN_STEPS`; ``n_after`` for a ray that descends where it leaves the grid (its
    segment may end on the ground beyond the domain).

    Why: the midpoint rule's error over a segment placed by :func:`clear_step_edges` falls as 1 / n² of the segment's
    own clear-sky radiance, roughly q times the ray's (the air above a 20 km grid top holds ~4 % of the vertical optical
    depth at 546 nm, above a 2 km LES top ~60 %). With n ∝ √q the error relative to the ray's
    clear sky is the same for every ray: that of ``n_after`` steps through the whole column
    (docs/decisions/0004-step-placement.md; our choice, not the paper's, which marches Step 2 separately).

    Inputs per ray (n = rays): rebased ``start`` (n, 3) [m], unit ``direction`` (n, 3) and ``bounds`` (n, 3) [m] of
    :func:`ray_segments`; ``consts`` with the column row :data:`swim.constants.GAS_COLUMN_ROW` of ``beta_gas``
    (:func:`gas_column_above`). :func:`swim.rt.march_cpu._after_steps` is the same per ray.
    """
    radius = consts["radius"]
    s_exit = bounds[:, 1]
    exit_point = start + s_exit[:, None] * direction
    rising = (exit_point[:, 0] * direction[:, 0] + exit_point[:, 1] * direction[:, 1]
              + (exit_point[:, 2] + radius) * direction[:, 2]) >= 0
    low_point = lowest_point(start, direction, bounds, consts, end=s_exit)  # the height is convex along a ray
    column = consts["beta_gas"][GAS_COLUMN_ROW:GAS_COLUMN_ROW + 1]
    above_exit = _lerp_table(column, _point_geometry(exit_point, consts)[0] / consts["dh"])[:, 0]
    above_low = _lerp_table(column, _point_geometry(low_point, consts)[0] / consts["dh"])[:, 0]
    q = jnp.clip(above_exit / jnp.maximum(above_low, 1e-30), 0.0, 1.0)
    steps = jnp.clip(jnp.ceil(n_after * jnp.sqrt(q)), min(AFTER_MIN_STEPS, n_after), n_after).astype(jnp.int32)
    return jnp.where(rising, steps, n_after)


def _march_segment(state, start, direction, edges, n_steps, in_grid, rays, consts, ms_profile, aerosol_class,
                   tau_refine=0.0, steps=None, terminal=False, stop_tau=0.0):
    """Accumulate one ray segment with n_steps midpoint steps between ``edges`` (n_steps + 1, n) [m] (see the
    module docstring), or each ray its own ``steps`` (n,) <= n_steps of them (:func:`grid_step_edges`); in the
    grid, thick steps and cloud faces are refined down to ``tau_refine`` (:func:`_march_grid_refined`), and a ray
    that does not look down stops where its hydrometeor optical depth passes ``stop_tau`` (> 0; 0: never), once
    past :data:`REFINE_VISIBLE_TAU` before the step (:attr:`MarchSettings.stop_tau`).

    ``ms_profile`` is :func:`diffuse_source_profiles` of the rays, or None for single scattering only;
    ``aerosol_class`` that of :func:`aerosol_class_weights` (the skylight of the hydrometeors).
    """
    multiple_scattering = ms_profile is not None
    clouds_3d = three_d(consts)  # cloud_scattering="discrete_ordinates" (swim.rt.clouds_device)
    n_c = consts["volume"].shape[-1]
    n_sp = consts["species_matrix"].shape[0]  # the packed species (packed_species)
    aerosol_3d = packed_aerosol_3d(n_c, n_sp)  # packed only where it is not zero
    outside = jnp.concatenate([jnp.zeros(n_c - 2), jnp.ones(2)]).astype(jnp.float32)

    def sample(st, s_lo, ds):
        """The state after a step of length ``ds`` from ``s_lo`` [m], and the step's hydrometeor extinction."""
        s = s_lo + 0.5 * ds
        if terminal:  # the step back takes back what the step before added: at that step's sample
            s = jnp.where(ds < 0, st["hit_lo"], s)
        q = start + s[:, None] * direction
        h, mu_s, k, j, i = _point_geometry(q, consts)
        beta_r, beta_a, beta_s, t_sun, diffuse = _gas_at(h, mu_s, consts)
        if in_grid:
            v = trilinear(consts["volume"], k, j, i, outside)
            beta_sp = v[:, :n_sp]
            t_cloud = v[:, -2]
            shadow = v[:, -1]
            if aerosol_3d:
                beta_a3 = v[:, n_sp : n_sp + 1] * consts["angstrom"][None, :]
                # Direct beam through the 3-D aerosol towards the sun (Angstrom-scaled from 550 nm).
                t_aerosol = jnp.exp(-v[:, n_sp + 1 : n_sp + 2] * consts["angstrom"][None, :])
            else:
                beta_a3 = jnp.zeros((q.shape[0], 3), jnp.float32)
                t_aerosol = jnp.ones((q.shape[0], 3), jnp.float32)
            gap = h - bilinear_clamped(consts["terrain"], j, i)[:, 0]
            hit_now = st["alive"] & (gap < 0) & (not terminal)
            frac = jnp.where(hit_now, jnp.clip(st["gap"] / jnp.maximum(st["gap"] - gap, 1e-6), 0.0, 1.0), 1.0)
        else:
            beta_sp = jnp.zeros((q.shape[0], n_sp), jnp.float32)
            beta_a3 = jnp.zeros((q.shape[0], 3), jnp.float32)
            t_cloud = jnp.ones(q.shape[0], jnp.float32)
            shadow = jnp.ones(q.shape[0], jnp.float32)
            t_aerosol = jnp.ones((q.shape[0], 3), jnp.float32)
            # Beyond the grid the terrain continues at its edge heights (clamped), so that mountains at the
            # domain's edge do not end in a cliff down to the sea-level sphere and a plateau's horizon is flat.
            gap = h - bilinear_clamped(consts["terrain"], j, i)[:, 0]
            hit_now = st["alive"] & (gap < 0)
            frac = jnp.where(hit_now, jnp.clip(st["gap"] / jnp.maximum(st["gap"] - gap, 1e-6), 0.0, 1.0), 1.0)
        # the step in which the ray meets the ground adds nothing here: its sample may lie deep inside the
        # terrain; the terminal step (_terminal_step) covers it up to the refined crossing
        ds_eff = jnp.where(st["alive"] & ~hit_now, ds, 0.0)
        # direct beam / E_TOA, lights the gas and aerosol (Eq. 3): gas, hydrometeors (T), 3-D aerosol
        irradiance = t_sun * (t_cloud * shadow)[:, None] * t_aerosol
        if in_grid:
            # Clear-sky diffuse scalar irradiance / E_TOA, through the clouds above (T of Step 1a); with
            # aerosol column classes, that of the ray's class.
            if consts["class_aod"].shape[0] > 1:
                diffuse = diffuse_at(h, mu_s, aerosol_class, consts)
            skylight = SKYLIGHT_SCALAR_FACTOR * diffuse * t_cloud[:, None]
        # Scalar irradiance of Eq. 8 ("direct + scattered") lighting the hydrometeors.
        irradiance_h = irradiance + skylight if in_grid else irradiance
        beta_clear = beta_r + beta_a + beta_a3 + beta_s
        beta_h = beta_sp.sum(axis=1)
        # the extinction that dims the light on its way to the observer: with the 3-D cloud scattering the
        # hydrometeors' delta-M scaled one (the forward peak's light stays in the view), whose sources are
        # integrated along the ray; the diffuse solution's ratio to the clear sky dims the air's diffuse source
        beta_view, dims_diffuse = beta_h, t_cloud[:, None]
        if clouds_3d and in_grid:
            dims_diffuse, cloud_source, beta_view = cloud_sources(beta_sp, k, j, i, t_cloud, irradiance, rays, consts)
        elif clouds_3d:
            dims_diffuse = ratio_above_grid(h, k, j, i, consts, consts["volume"].shape[:3])
        x = (beta_clear + beta_view[:, None]) * ds_eff[:, None]
        # (1 - e^-x) / x, also for the terminal step's negative x (a step back)
        big = jnp.abs(x) > 1e-4
        step_mean = jnp.where(big, -jnp.expm1(-x) / jnp.where(big, x, 1.0), 1.0 - 0.5 * x)
        t_obs = jnp.exp(-(st["tau_clear"] + (st["tau_view"] if clouds_3d else st["tau_h"])[:, None]))
        scat_a = (beta_a + beta_a3) * consts["aerosol_ssa"]
        scat_s = beta_s * consts["stratospheric_ssa"]
        source = (beta_r * rays["p_rayleigh"][:, None] + scat_a * rays["p_aerosol"]
                  + scat_s * rays["p_stratospheric"]) * irradiance
        if multiple_scattering:
            # Orders >= 2: the diffuse source of the successive-orders table (molecules, aerosol,
            # stratospheric aerosol), dimmed under clouds by their transmittance like the skylight.
            j = _profile_at(ms_profile, h, consts)
            source = source + (beta_r * j[:, :3] + scat_a * j[:, 3:6] + scat_s * j[:, 6:]) * dims_diffuse
        l_clear = st["l_clear"] + t_obs * source * (ds_eff[:, None] * step_mean)
        # Eq. 12 integrand over the first two optical depths of hydrometeors.
        t0 = st["tau_h"]
        t1 = t0 + beta_h * ds_eff
        if clouds_3d:  # the clouds' light is integrated along the ray (swim.rt.clouds), not composed by Eq. 12
            i_nogas, i_gas, i_cloud_t = st["i_nogas"], st["i_gas"], st["i_cloud_t"]
            extra = {"tau_view": st["tau_view"] + beta_view * ds_eff, "l_cloud": st["l_cloud"]}
            if in_grid:
                extra["l_cloud"] = st["l_cloud"] + t_obs * cloud_source * (ds_eff[:, None] * step_mean)
        else:
            weight = jnp.exp(-jnp.minimum(t0, 2.0)) - jnp.exp(-jnp.minimum(t1, 2.0))
            weight = jnp.where(t1 >= t0, jnp.maximum(weight, 0.0), weight)  # negative for a step back
            i_nogas = st["i_nogas"] + irradiance_h * weight[:, None]
            i_gas = st["i_gas"] + irradiance_h * jnp.exp(-st["tau_clear"]) * weight[:, None]
            i_cloud_t = st["i_cloud_t"] + t_cloud * shadow * weight
            extra = {}
        hit_s = jnp.where(hit_now, s - 0.5 * ds + frac * ds, st["hit_s"])
        # bracket of the crossing for the bisection after the march: the previous sample (above) and this one
        hit_lo = jnp.where(hit_now, st["s_last"], st["hit_lo"])
        hit_hi = jnp.where(hit_now, s, st["hit_hi"])
        hit_from = jnp.where(hit_now, s_lo, st["hit_from"])
        tau_species = st["tau_species"] + beta_sp * ds_eff[:, None]
        alive = st["alive"] & ~hit_now
        if in_grid and stop_tau > 0:
            # opaque (MarchSettings.stop_tau): the ray stops at stop_tau, its species in the proportions they had
            # there; past REFINE_VISIBLE_TAU before the step, so that no roll-back can undo it
            stopped = alive & (t1 > stop_tau) & (t0 >= REFINE_VISIBLE_TAU) & (direction[:, 2] >= 0)
            tau_species = jnp.where(stopped[:, None], tau_species * (stop_tau / jnp.maximum(t1, stop_tau))[:, None],
                                    tau_species)
            t1 = jnp.where(stopped, jnp.asarray(stop_tau, t1.dtype), t1)
            alive = alive & ~stopped
        return {
            "tau_clear": st["tau_clear"] + beta_clear * ds_eff[:, None],
            "tau_h": t1,
            "tau_species": tau_species,
            "l_clear": l_clear,
            "i_nogas": i_nogas,
            "i_gas": i_gas,
            "i_cloud_t": i_cloud_t,
            "alive": alive,
            "hit": st["hit"] | hit_now,
            "hit_s": hit_s,
            "hit_lo": hit_lo,
            "hit_hi": hit_hi,
            "hit_from": hit_from,
            "gap": gap,
            "s_last": s,
            **extra,
        }, beta_h

    def body(m, st):
        s_lo = jax.lax.dynamic_index_in_dim(edges, m, keepdims=False)
        ds = jax.lax.dynamic_index_in_dim(edges, m + 1, keepdims=False) - s_lo
        new = sample(st, s_lo, ds)[0]
        if steps is None:
            return new
        taken = m < steps  # a ray's steps beyond its own count leave it as it is
        return {key: jnp.where(taken.reshape((-1,) + (1,) * (value.ndim - 1)), value, st[key])
                for key, value in new.items()}

    if in_grid and tau_refine > 0:
        return _march_grid_refined(state, sample, edges, n_steps, tau_refine, steps)
    return jax.lax.fori_loop(0, n_steps, body, state)


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


def grid_loop_unroll() -> int:
    """Iterations of the lockstep grid loop per test of its condition (:func:`_march_grid_refined`):
    :data:`GRID_LOOP_UNROLL_ACCELERATOR` where JAX's default device is a GPU (or another accelerator), 1 on a CPU."""
    return 1 if jax.default_backend() == "cpu" else GRID_LOOP_UNROLL_ACCELERATOR


def _predicted_halving(adjacent, prev_beta, ds, depth, tau_h, pending, slots, tau_refine):
    """Whether a ray's next interval (length ``ds`` [m], refinement ``depth``) is halved before it is sampled, its
    second half left pending (:func:`_march_grid_refined`): the accumulated interval just before it (``adjacent``) had
    an extinction ``prev_beta`` [1/m] that makes this one thicker than ``tau_refine`` in hydrometeor optical depth, so
    its midpoint's sample would most likely find it too thick and be discarded for its halves. Only where that
    refinement could happen (``depth`` < :data:`REFINE_DEPTH`, the ray's optical depth ``tau_h`` <
    :data:`REFINE_VISIBLE_TAU`, two of ``slots`` free above ``pending``); the caller checks the ray's budget. One level
    each time an interval is taken: the first half is sampled even if the prediction would halve it again (its own
    sample finds it too thick then); the pending second half is predicted anew when it is taken, from the interval
    accumulated just before it. Elementwise: JAX arrays of one shape, or scalars (:mod:`swim.rt.march_pallas`;
    :func:`swim.rt.march_cpu._predicted_halving` is the numba kernel's)."""
    return (adjacent & (depth < REFINE_DEPTH) & (tau_h < REFINE_VISIBLE_TAU) & (pending + 2 <= slots)
            & (prev_beta * ds > tau_refine))


def _march_grid_refined(state, sample, edges, n_steps, tau_refine, steps=None, unroll=None):
    """The grid segment of :func:`_march_segment` with steps refined where a cloud face may lie, while the ray's
    own hydrometeor optical depth is below :data:`REFINE_VISIBLE_TAU` (at most :data:`REFINE_DEPTH` levels of
    halving and :data:`REFINE_BUDGET` refinements per ray):

    * a step whose hydrometeor optical depth ``beta_h ds`` exceeds ``tau_refine`` is replaced by its two halves,
      first half first, recursively (a face inside the step, or a thick step whose midpoint sunlight stands for
      all of it);
    * so is a step whose extinction differs from that of the interval before it by more than ``tau_refine / ds``
      (the face where a cloud ends lies in its first half, or the cloud goes on unseen by its midpoint);
    * where that difference over the previous interval's length exceeds ``tau_refine``, the previous interval
      held the face where a cloud begins, but its midpoint lay in clear air: the ray goes back to its state
      before that interval and takes its two halves, then this interval again;
    * an interval whose length times the extinction of the accumulated interval just before it exceeds
      ``tau_refine`` is halved before it is sampled (:func:`_predicted_halving`, one level): inside a cloud its
      own sample would find it too thick and be discarded for its halves. On the synthetic 400 x 400 x 60 all-sky
      that saves ~5 % of the samples, at a slightly smaller error (docs/decisions/0004-step-placement.md).

    So a cloud face is resolved where the light comes from, and neighbouring pixels whose step midpoints fall on
    either side of the face agree (the stripes of docs/decisions/0004-step-placement.md).

    Rays in lockstep, each with its own pending intervals (:data:`REFINE_SLOTS`, a refinement only where they
    fit): every iteration each ray takes its next interval (the last pending one, or its next step; its first half,
    the second pending, where the halving is predicted), samples it and either accumulates it, pushes its halves, or
    rolls back, until it has taken its n_steps (or its own ``steps`` (n,)) steps or has stopped (``alive`` False: the
    ground, or opaque cloud; its later samples would add nothing). :mod:`swim.rt.march_cpu` does the same per ray.

    ``unroll``: iterations per test of the loop's condition (None: :func:`grid_loop_unroll`); an iteration leaves
    a finished ray unchanged, so any value gives the same state.
    """
    n = edges.shape[1]
    slots = REFINE_SLOTS
    col = jnp.arange(slots)[None, :]
    last = jnp.full((n,), n_steps, jnp.int32) if steps is None else steps

    def finished(carry):
        # a ray that has stopped (the ground, opaque cloud) is finished: its later samples would add nothing (their
        # length counts as 0 in every sum), so its steps and pending intervals are left
        # (docs/decisions/0006-gpu-kernels.md)
        st, m, pending, *_ = carry
        return ((pending == 0) & (m >= last)) | ~st["alive"]

    def rows(mask, value):
        return mask.reshape((n,) + (1,) * (value.ndim - 1))

    def body(carry):
        st, m, pending, stack_lo, stack_hi, stack_depth, budget, saved, prev = carry
        stacked = pending > 0
        top = jnp.maximum(pending - 1, 0)[:, None]
        next_step = jnp.minimum(m, last - 1)[None, :]
        done = (~stacked & (m >= last)) | ~st["alive"]
        lo = jnp.where(stacked, jnp.take_along_axis(stack_lo, top, 1)[:, 0], jnp.take_along_axis(edges, next_step, 0)[0])
        hi = jnp.where(stacked, jnp.take_along_axis(stack_hi, top, 1)[:, 0], jnp.take_along_axis(edges, next_step + 1, 0)[0])
        depth = jnp.where(stacked, jnp.take_along_axis(stack_depth, top, 1)[:, 0], 0)
        ds = jnp.where(done, 0.0, hi - lo)
        base = pending - stacked
        adjacent = prev["valid"] & (prev["hi"] == lo)
        # an interval that the one before it predicts too thick: its second half pending, its first half sampled
        halve = (~done & (budget > 0) & st["alive"]
                 & _predicted_halving(adjacent, prev["beta_h"], ds, depth, st["tau_h"], base, slots, tau_refine))
        half = lo + 0.5 * ds
        at = halve[:, None] & (col == base[:, None])
        stack_lo = jnp.where(at, half[:, None], stack_lo)
        stack_hi = jnp.where(at, hi[:, None], stack_hi)
        stack_depth = jnp.where(at, depth[:, None] + 1, stack_depth)
        hi = jnp.where(halve, half, hi)
        depth = depth + halve
        ds = jnp.where(halve, hi - lo, ds)
        base = base + halve
        budget = budget - halve
        new, beta_h = sample(st, lo, ds)
        live = ~done & (budget > 0) & st["alive"]
        change = jnp.where(adjacent, jnp.abs(beta_h - prev["beta_h"]), 0.0)
        rollback = (live & adjacent & (prev["depth"] < REFINE_DEPTH) & (change * (prev["hi"] - prev["lo"]) > tau_refine)
                    & (base + 3 <= slots) & (saved["tau_h"] < REFINE_VISIBLE_TAU))
        refine = (live & ~rollback & (depth < REFINE_DEPTH) & (st["tau_h"] < REFINE_VISIBLE_TAU) & (base + 2 <= slots)
                  & (jnp.maximum(beta_h, change) * ds > tau_refine))
        keep = ~done & ~refine & ~rollback
        save = keep & live
        saved = {key: jnp.where(rows(save, value), st[key], value) for key, value in saved.items()}
        # a rolled-back ray's snapshot is not overwritten above (save needs keep)
        st = {key: jnp.where(rows(keep, value), value, jnp.where(rows(rollback, value), saved[key], st[key]))
              for key, value in new.items()}
        mid = (lo + 0.5 * ds)[:, None]
        prev_mid = (prev["lo"] + 0.5 * (prev["hi"] - prev["lo"]))[:, None]
        b = base[:, None]
        # split: the second half below the first, which is taken next; rollback: this interval, then the
        # previous one's second half, then its first half on top
        first, second = refine[:, None] & (col == b), refine[:, None] & (col == b + 1)
        again, p_second, p_first = (rollback[:, None] & (col == b + i) for i in range(3))
        stack_lo = jnp.where(first | p_second, jnp.where(first, mid, prev_mid),
                             jnp.where(second | again, lo[:, None], jnp.where(p_first, prev["lo"][:, None], stack_lo)))
        stack_hi = jnp.where(first | again, hi[:, None],
                             jnp.where(second, mid, jnp.where(p_second, prev["hi"][:, None],
                                                              jnp.where(p_first, prev_mid, stack_hi))))
        stack_depth = jnp.where(first | second, depth[:, None] + 1,
                                jnp.where(again, depth[:, None],
                                          jnp.where(p_second | p_first, prev["depth"][:, None] + 1, stack_depth)))
        prev = {"valid": jnp.where(save, True, prev["valid"] & ~rollback), "lo": jnp.where(save, lo, prev["lo"]),
                "hi": jnp.where(save, hi, prev["hi"]), "beta_h": jnp.where(save, beta_h, prev["beta_h"]),
                "depth": jnp.where(save, depth, prev["depth"])}
        pending = base + 2 * refine + 3 * rollback
        return (st, m + (~stacked & ~done), pending, stack_lo, stack_hi, stack_depth, budget - refine - rollback,
                saved, prev)

    zero = jnp.zeros(n, jnp.float32)
    prev = {"valid": jnp.zeros(n, bool), "lo": zero, "hi": zero, "beta_h": zero, "depth": jnp.zeros(n, jnp.int32)}
    carry = (state, jnp.zeros(n, jnp.int32), jnp.zeros(n, jnp.int32), jnp.zeros((n, slots), jnp.float32),
             jnp.zeros((n, slots), jnp.float32), jnp.zeros((n, slots), jnp.int32), jnp.full(n, REFINE_BUDGET, jnp.int32),
             dict(state), prev)
    unroll = grid_loop_unroll() if unroll is None else int(unroll)

    def bodies(c):  # a finished ray's iteration leaves it as it is, so the loop may run past its last one
        for _ in range(unroll):
            c = body(c)
        return c

    return jax.lax.while_loop(lambda c: ~jnp.all(finished(c)), bodies, carry)[0]


#: Bisection steps that refine a terrain crossing found between two samples of the march (2^-10 of a step:
#: a few metres even for the ~10 km steps beyond the grid).
TERRAIN_BISECTIONS = 10


def refine_terrain_hit(start, direction, state, consts):
    """Distance [m] to the terrain crossing of each ray, by bisection between the samples that bracket it.

    The march finds the crossing between a sample above and one below the (clamped bilinear) terrain and
    interpolates the gap linearly, which is exact for a flat surface but, with the long steps beyond the grid
    or along grazing rays, can put the hit kilometres off over curved terrain; bisection on the same gap
    function fixes that. Rays without a terrain hit keep ``state["hit_s"]``.
    """
    def gap(s):
        h, _, _, j, i = _point_geometry(start + s[:, None] * direction, consts)
        return h - bilinear_clamped(consts["terrain"], j, i)[:, 0]

    def step(_, bracket):
        lo, hi = bracket
        mid = 0.5 * (lo + hi)
        below = gap(mid) < 0
        return jnp.where(below, lo, mid), jnp.where(below, mid, hi)

    lo, hi = state["hit_lo"], state["hit_hi"]
    valid = (gap(lo) >= 0) & (gap(hi) < 0)
    lo, hi = jax.lax.fori_loop(0, TERRAIN_BISECTIONS, step, (lo, hi))
    return jnp.where(valid, 0.5 * (lo + hi), state["hit_s"])


def _terminal_step(state, start, direction, rays, consts, ms_profile, aerosol_class):
    """The last step of each ray that met the ground: from the start of the step in which it did (``hit_from``) to
    the refined crossing ``s_hit`` [m] (:func:`refine_terrain_hit`), one sample at its middle; rays that did not
    meet the ground are left as they are.

    The march finds the ground by a sample below it, in the middle of a step that may be kilometres long (the
    empty space of a ray grazing a big grid); that sample's light and extinction come from inside the terrain,
    and the step adds nothing. Where the crossing lies before ``hit_from``, in the far half of the step before
    (which was taken whole; its sample ``hit_lo`` is its middle, so it began at 2 ``hit_lo`` - ``hit_from``), that
    step is taken back (a step of negative length at its own sample, which undoes it) and taken again up to the
    crossing. The step back inverts Eq. 3's exponential step exactly ((T, L) -> (T e^-x, L + T S (1 - e^-x) / x)
    with -x) and Eq. 12's weight e^-min(tau0, 2) - e^-min(tau1, 2) changes sign (Albers et al. 2020,
    doi:10.5194/amt-13-3235-2020). So the light of the air in front of the ground no longer depends on the step
    count (docs/decisions/0004-step-placement.md). :mod:`swim.rt.march_cpu` takes the same steps.

    ``state``: the march's per-ray arrays (n,) or (n, 3) of :func:`_march_rays` with ``s_hit`` (n,) [m]; ``start``
    (n, 3) [m], unit ``direction`` (n, 3); the rest as :func:`_march_segment` takes them. Returns the state
    after the terminal steps, ``alive`` and ``s_hit`` as they were."""
    state = dict(state)
    s_hit, alive = state.pop("s_hit"), state["alive"]
    hit_from = state["hit_from"]
    back_to = 2.0 * state["hit_lo"] - hit_from  # < 0 where no step came before
    back = state["hit"] & (s_hit < hit_from) & (back_to >= 0)
    # two steps: back to where the step before began (zero length unless ``back``), then on to the crossing (zero
    # length where it lies before the ray's first step)
    mid = jnp.where(back, back_to, hit_from)
    end = jnp.where(back | (s_hit > hit_from), s_hit, hit_from)
    state["alive"] = state["hit"]
    state = _march_segment(state, start, direction, jnp.stack([hit_from, mid, end]), 2, True, rays, consts,
                           ms_profile, aerosol_class, terminal=True)
    return dict(state, alive=alive, s_hit=s_hit)


def fused_fits(n) -> bool:
    """Whether a batch of n rays fills whole blocks of the fused grid kernel (:data:`swim.rt.march_pallas.BLOCK_RAYS`);
    the batches of :func:`padded_batch_size` do (powers of two of at least :data:`MIN_BATCH`, or the chunk)."""
    from .march_pallas import BLOCK_RAYS

    return n % BLOCK_RAYS == 0


def _prepare_rays(start, direction, bounds, consts, settings: MarchSettings):
    """Per-ray set-up before the march: the aerosol column class and the diffuse-source height profiles (or
    None) at each ray's lowest point."""
    low = lowest_point(start, direction, bounds, consts)
    aerosol_class = aerosol_class_weights(low, consts)
    ms = diffuse_source_profiles(low, direction, aerosol_class, consts) if settings.multiple_scattering else None
    return aerosol_class, ms


def _march_rays(start, direction, bounds, valid, rays, consts, settings: MarchSettings, aerosol_class, ms, probes=None):
    """The lockstep march of the three segments; the state of :func:`_march_segment` plus ``s_hit`` (n,) [m],
    the refined terrain crossing or the end of the ray (:mod:`swim.rt.march_cpu` computes the same per ray).
    ``probes``: each ray's occupancy probes (n,) (:func:`probe_counts`, at most ``settings.n_probe``) and its grid
    segment's length in cells (n,), from :func:`probe_counts_and_cells`."""
    n = start.shape[0]
    zeros3 = jnp.zeros((n, 3), jnp.float32)
    state = {
        "tau_clear": zeros3, "tau_h": jnp.zeros(n, jnp.float32),
        "tau_species": jnp.zeros((n, consts["species_matrix"].shape[0]), jnp.float32),  # the packed species'
        "l_clear": zeros3, "i_nogas": zeros3, "i_gas": zeros3, "i_cloud_t": jnp.zeros(n, jnp.float32),
        "alive": valid, "hit": jnp.zeros(n, bool), "hit_s": jnp.zeros(n, jnp.float32),
        "hit_lo": jnp.zeros(n, jnp.float32), "hit_hi": jnp.zeros(n, jnp.float32),
        "hit_from": jnp.zeros(n, jnp.float32),
        "gap": jnp.full(n, 1e9, jnp.float32), "s_last": jnp.zeros(n, jnp.float32),
    }
    if three_d(consts):  # the hydrometeors' scaled optical depth to the observer and their radiance
        state.update(tau_view=jnp.zeros(n, jnp.float32), l_cloud=zeros3)
    from .march_pallas import Segment, march_grid_fused, march_segments_fused

    zero = jnp.zeros(n, jnp.float32)
    args = (rays, consts, ms, aerosol_class)
    tau_refine, stop_tau = float(settings.tau_refine), float(settings.stop_tau)
    segments = []  # the ray's segments in order, each's step edges placed from the geometry alone
    if settings.n_before:
        segments.append(Segment(clear_step_edges(start, direction, zero, bounds[:, 0], settings.n_before, consts),
                                settings.n_before))
    if settings.n_grid:
        count, cells = (None, None) if probes is None else probes
        empty_steps = settings.resolved_empty_steps()
        edges, steps = grid_step_edges(start, direction, bounds[:, 0], bounds[:, 1] - bounds[:, 0], settings.n_grid,
                                       consts, n_probe=settings.n_probe, probes=count, cells=cells,
                                       empty_steps=empty_steps, sunlit_steps=settings.sunlit_steps)
        segments.append(Segment(edges, settings.n_grid, steps if empty_steps else None, in_grid=True,
                                refined=tau_refine > 0))
    if settings.n_after:
        steps = after_step_counts(start, direction, bounds, settings.n_after, consts)
        segments.append(Segment(clear_step_edges(start, direction, bounds[:, 1], bounds[:, 2] - bounds[:, 1],
                                                 settings.n_after, consts, steps=steps), settings.n_after, steps))
    # one more step, of zero length at each ray's end: where that end lies on the sea-level sphere, below the terrain
    # (which beyond the grid keeps its edge's heights), its sample detects a crossing in the far half of the ray's
    # last step, which no later step would (docs/decisions/0004-step-placement.md); elsewhere it adds nothing
    segments.append(Segment(jnp.stack([bounds[:, 2], bounds[:, 2]]), 1))
    # the fused kernel marches whole blocks of rays: a batch of another size (a chunk set by hand) is marched by the
    # lockstep loops
    kernel = settings.resolved_grid_kernel()
    fused = kernel in ("fused", "fused-march") and fused_fits(n)
    interpret = jax.default_backend() == "cpu"
    # the fused kernel's register cap, loads and fused multiply-adds: settings, so that programs built with other
    # ones are kept apart
    fused_options = {"max_registers": settings.fused_max_registers, "vector_loads": settings.fused_vector_loads,
                     "fma": settings.fused_fma}
    if fused and kernel == "fused-march":
        state = march_segments_fused(state, start, direction, tuple(segments), rays, consts, ms, aerosol_class,
                                     tau_refine, stop_tau, interpret=interpret, **fused_options)
    else:
        for seg in segments:
            if fused and seg.refined:
                state = march_grid_fused(state, start, direction, seg.edges, seg.n_steps, rays, consts, ms,
                                         aerosol_class, tau_refine, steps=seg.steps, stop_tau=stop_tau,
                                         interpret=interpret, **fused_options)
            else:
                state = _march_segment(state, start, direction, seg.edges, seg.n_steps, seg.in_grid, *args,
                                       tau_refine=tau_refine if seg.refined else 0.0, steps=seg.steps,
                                       stop_tau=stop_tau if seg.in_grid else 0.0)
    state["s_hit"] = jnp.where(state["hit"], refine_terrain_hit(start, direction, state, consts), bounds[:, 2])
    state = _terminal_step(state, start, direction, *args)
    state["tau_species"] = state["tau_species"] @ consts["species_matrix"]  # all of SPECIES, 0 where not packed
    return state


def _compose(start, direction, bounds, ends_on_ground, valid, rays, consts, settings: MarchSettings, state,
             aerosol_class, ground=True):
    """The pixel radiance from the march's state: ground (Eq. 35), clouds (Eqs. 12-26), clear sky.

    ``ground`` (static): False where no ray of the batch ends on the ground, whose term is then 0 without being
    evaluated (as it is for such rays anyway). The chunks of an all-sky camera on the ground and the upper rows of a
    panorama see no ground, and the ground's BRDF is about half of the composition's cost
    (docs/decisions/0009-work-around-the-march.md)."""
    surface = _ends_on_surface(state, ends_on_ground)
    s_hit = state["s_hit"]
    if ground:
        l_surface = _ground_radiance(start, direction, rays, consts, settings, state, aerosol_class, surface, s_hit)
    else:
        l_surface = jnp.zeros_like(state["l_clear"])
    if three_d(consts):
        return _compose_three_d(consts, state, valid, surface, s_hit, l_surface)
    return _compose_clouds(rays, consts, state, valid, surface, s_hit, l_surface)


def _ends_on_surface(state, ends_on_ground):
    """Which rays end on the ground (n,) bool: a terrain hit, or a ray still alive at the end of a segment that ends
    on the sea-level sphere (JAX or numpy arrays)."""
    return state["hit"] | (ends_on_ground & state["alive"])


def _ground_radiance(start, direction, rays, consts, settings, state, aerosol_class, surface, s_hit):
    """The ground's part of the pixel radiance (n, 3), 0 where a ray does not end on the ground (``surface``):
    Eq. 35 on the terrain facet at ``s_hit`` [m], direct (BRDF) + diffuse (ARF = 1), seen through the clear sky and
    the hydrometeors on the way. The numba kernel's twin: :func:`swim.rt.ground_cpu.ground_radiance`."""
    q = start + s_hit[:, None] * direction
    h, mu_s, k, j, i = _point_geometry(q, consts)
    _, _, _, t_sun, diffuse = _gas_at(h, mu_s, consts)
    if consts["class_aod"].shape[0] > 1:
        diffuse = diffuse_at(h, mu_s, aerosol_class, consts)
    # albedo (3), land, snow, wind, slope (2), and Step 1a at the ground: cloud T, terrain shadow, 3-D aerosol
    # tau to the sun (2-D fields, so a steep slope does not sample its neighbours' underground values);
    # beyond the grid they fade from the nearest edge cell's to the edge's mean of a flat, unshaded ground
    fields = surface_beyond_edge(bilinear_clamped(consts["surface"], j, i), consts["surface_outside"],
                                 *consts["terrain"].shape[1:], j, i)
    slope = fields[:, 6:8]
    t_cloud = fields[:, 8]
    shadow = fields[:, 9]
    t_aerosol = jnp.exp(-fields[:, 10:11] * consts["angstrom"][None, :])
    # with the 3-D cloud scattering the diffuse light at the ground is the diffuse solution's (its ratio to the
    # clear sky's, channels 11-13), which includes the light between the ground and the cloud base
    clouds_3d = three_d(consts)
    diffuse = diffuse * (fields[:, 11:14] if clouds_3d else t_cloud[:, None])
    up = q + jnp.array([0.0, 0.0, 1.0], jnp.float32) * consts["radius"]
    up = up / jnp.linalg.norm(up, axis=1, keepdims=True)
    l_ground = surface_radiance(up, -direction, consts["sun"], slope, fields[:, :3], fields[:, 3], fields[:, 4],
                                fields[:, 5], t_sun * t_aerosol * (t_cloud * shadow)[:, None], diffuse,
                                model=settings.surface)
    if clouds_3d:  # seen through the delta-M scaled optical depth: the forward peak's light stays in the view
        t_hydro = jnp.exp(-(state["tau_species"] @ consts["backscatter_scaled"]))
        return jnp.where(surface[:, None], l_ground * (jnp.exp(-state["tau_clear"]) * t_hydro[:, None]), 0.0)
    # Seen from above, the ground under a cloud layer shines through the layer's total (direct + diffuse)
    # transmittance at the view angle (reciprocity), the same delta-Eddington T as in Step 1a; rays that do
    # not look down (blend as for the clouds) keep the direct e^{-tau} (docs/rendering.md, "Overcast accuracy").
    mu_down_ground = -rays["cos_view_zenith"]
    w_above_ground = jnp.clip(mu_down_ground / FROM_ABOVE_BLEND, 0.0, 1.0)
    tau_hydro = state["tau_h"]
    t_hydro = (1 - w_above_ground) * jnp.exp(-tau_hydro) + w_above_ground * transmittance_delta_eddington(
        tau_hydro, state["tau_species"] @ consts["backscatter"], jnp.maximum(mu_down_ground, FROM_ABOVE_BLEND))
    transmit = jnp.exp(-state["tau_clear"]) * t_hydro[:, None]
    return jnp.where(surface[:, None], l_ground * transmit, 0.0)


def _compose_three_d(consts, state, valid, surface, s_hit, l_surface):
    """The outputs of :func:`_compose` with the 3-D cloud scattering, whose hydrometeors' radiance was integrated
    along the rays (:mod:`swim.rt.clouds_device`), given the ground's part ``l_surface`` (n, 3); ``tau_narrow``
    (n,) is the optical depth that dims the beam but for the forward peak's narrow part (the circumsolar aureole,
    :func:`swim.optics.cloud_phase.split_phase_function`). The numba kernel's twin: :func:`_compose_numba`."""
    aureole = consts["species_matrix"].T @ consts["hydro_aureole"].astype(jnp.float32)  # (SPECIES,)
    radiance = jnp.where(valid[:, None], state["l_clear"] + state["l_cloud"] + l_surface, 0.0)
    return {
        "radiance": radiance,
        "radiance_clear": state["l_clear"],
        "radiance_cloud": state["l_cloud"],
        "radiance_surface": l_surface,
        "tau_hydrometeor": state["tau_h"],
        "tau_clear": state["tau_clear"],
        "surface": surface,
        "distance": jnp.where(surface, s_hit, jnp.nan),
        "tau_narrow": state["tau_species"] @ aureole,
    }


def _compose_clouds(rays, consts, state, valid, surface, s_hit, l_surface):
    """The clouds' part of the pixel radiance (Eq. 12 with the effective phase function of Eq. 13, seen from below,
    blended with the cloud-top reflection of Eqs. 24-26 seen from above; Albers et al. 2020,
    doi:10.5194/amt-13-3235-2020) and the outputs of :func:`_compose`, given the ground's part ``l_surface``
    (n, 3)."""
    # ---- clouds: Eq. 12 with the effective phase function of Eq. 13, blended with Eqs. 24-26 ----
    tau = state["tau_h"]
    norm = -jnp.expm1(-jnp.minimum(tau, 2.0))
    safe = jnp.maximum(norm, 1e-12)
    e_mean = state["i_nogas"] / safe[:, None]
    # How directly the visible cloud is lit, for c1 and c3 (Eqs. 14, 22): the cloud transmittance T of
    # Step 1a, not E/E_TOA with the gas extinction (docs/rendering.md).
    t_mean = jnp.clip(state["i_cloud_t"] / safe, 0.0, 1.0)
    weights = state["tau_species"] / jnp.maximum(tau, 1e-12)[:, None]
    cos_theta = rays["cos_theta"]
    cos_view_zenith = rays["cos_view_zenith"]
    mu_view_down = -cos_view_zenith
    mu0 = consts["mu0"]
    w_above = jnp.clip(mu_view_down / FROM_ABOVE_BLEND, 0.0, 1.0)[:, None]
    # Seen from below, the indirectly lit (c4) term of Eq. 21 is the diffusely transmitted light: 4 x the
    # transmitted flux mu0 T x the escape function, i.e. the factor (9/7) mu0 (docs/rendering.md, "Overcast
    # accuracy"); rays looking down keep Eq. 21 as printed.
    low_factor = (1 - w_above) * diffuse_transmission_factor(mu0) + w_above
    phase = effective_phase_function(cos_theta[:, None], cos_view_zenith[:, None], tau[:, None], t_mean[:, None],
                                     weights[:, None, :], consts["g_liquid"][None, :], low_factor)
    eq12 = (-jnp.expm1(-tau) / safe)[:, None] * state["i_gas"]
    # Thin-cloud term (c1 P_thin) with the forward (diffraction) peak kept in the beam: Eq. 12's 1 - e^{-tau}
    # delta-scaled to (1 - e^{-(1 - f) tau}) / (1 - f) (docs/rendering.md, "Overcast accuracy").
    eq12_thin = (delta_scaled_path_factor(tau) / safe)[:, None] * state["i_gas"]
    c1 = blend_coefficient(tau, t_mean)
    p_thin = phase_thin_mixture(cos_theta[:, None], tau[:, None], weights[:, None, :], consts["g_liquid"][None, :])
    p_rest = p_thin - forward_peak_mixture(cos_theta[:, None], tau[:, None], weights[:, None, :], consts["g_liquid"][None, :])
    l_12 = phase * eq12 + c1[:, None] * p_rest * (eq12_thin - eq12)
    # Seen from above (docs/rendering.md, "Overcast accuracy"): the thin part of Eq. 13 (c1 P_thin, Eq. 12)
    # plus, in place of its thick part (Eqs. 19-21, cloud sides and bases), the cloud-top reflection of
    # Eqs. 24-26, (1 - c1) a 4 mu0 ARF E_top: the albedo a = 1 - T of the layer seen (delta-Eddington, as in
    # Step 1a, along the sun path tau_s = tau mu_view / mu0) and the irradiance incident on the cloud top,
    # E_top = E / T_self (Eq. 12's mean E over the top two optical depths already carries the cloud's own
    # extinction, which the reflection function ARF includes).
    b_eff = weights @ consts["backscatter"]
    mu_down = jnp.maximum(mu_view_down, FROM_ABOVE_BLEND)
    mu0_top = jnp.maximum(mu0, TOP_MIN_MU0)
    tau_s = tau * mu_down / mu0_top
    albedo_cloud = 1.0 - transmittance_delta_eddington(tau_s, b_eff * tau_s, mu0_top)
    lim = jnp.minimum(tau, 2.0)
    depth = (1.0 - (1.0 + lim) * jnp.exp(-lim)) / safe  # Eq. 12's e^{-tau_o}-weighted mean tau_o
    depth_s = depth * mu_down / mu0_top
    t_self = jnp.maximum(transmittance_delta_eddington(depth_s, b_eff * depth_s, mu0_top), TOP_MIN_SELF_TRANSMITTANCE)
    arf = anisotropic_reflectance_factor_kokhanovsky2004(mu_down, jnp.maximum(mu0, TOP_REFLECTANCE_MIN_MU0), cos_theta)
    gas_to_cloud = state["i_gas"] / jnp.maximum(state["i_nogas"], 1e-30)
    l_top = 4.0 * jnp.maximum(mu0, 0.0) * arf[:, None] * (e_mean / t_self[:, None]) * gas_to_cloud
    l_above = c1[:, None] * p_thin * eq12 + ((1 - c1) * albedo_cloud)[:, None] * l_top
    l_cloud = jnp.where(tau[:, None] > 1e-6, (1 - w_above) * l_12 + w_above * l_above, 0.0)

    radiance = state["l_clear"] + l_cloud + l_surface
    radiance = jnp.where(valid[:, None], radiance, 0.0)
    return {
        "radiance": radiance,
        "radiance_clear": state["l_clear"],
        "radiance_cloud": l_cloud,
        "radiance_surface": l_surface,
        "tau_hydrometeor": tau,
        "tau_clear": state["tau_clear"],
        "surface": surface,
        "distance": jnp.where(surface, s_hit, jnp.nan),
    }


@exported_jit(static_argnames=("settings",))  # a new process reads the traced program (~1.1 s on a CPU)
def _trace_chunk(start, direction, bounds, ends_on_ground, valid, rays, consts, settings: MarchSettings, probes=None):
    """One chunk of rays through the JAX kernel: set-up, lockstep march and composition in one program
    (``probes``: see :func:`_march_rays`)."""
    aerosol_class, ms = _prepare_rays(start, direction, bounds, consts, settings)
    state = _march_rays(start, direction, bounds, valid, rays, consts, settings, aerosol_class, ms, probes)
    return _compose(start, direction, bounds, ends_on_ground, valid, rays, consts, settings, state, aerosol_class)


_prepare_chunk = exported_jit(_prepare_rays, static_argnames=("settings",))


@exported_jit(static_argnames=("n_probe", "probe_spacing"))
def _probe_counts_chunk(start, direction, bounds, consts, n_probe, probe_spacing):
    return probe_counts_and_cells(start, direction, bounds[:, 0], bounds[:, 1] - bounds[:, 0], consts, n_probe,
                                  probe_spacing)


def _chunk_probes(start, direction, bounds, consts, settings: MarchSettings):
    """Settings and per-ray probes for one chunk of the lockstep kernel: each ray's count of :func:`probe_counts`
    and its grid segment's length in cells (:func:`probe_counts_and_cells`), and ``n_probe`` raised to the next
    power of two above the chunk's largest count (so that a few compiled versions serve every chunk)."""
    if not settings.probe_spacing or not settings.n_grid:
        return settings, None
    probes, cells = _probe_counts_chunk(start, direction, bounds, consts, settings.n_probe,
                                        float(settings.probe_spacing))
    return with_probes_for(settings, int(jnp.max(probes))), (probes, cells)


def with_probes_for(settings: MarchSettings, most: int) -> MarchSettings:
    """``settings`` whose ``n_probe`` holds a chunk whose rays take at most ``most`` probes: raised to the next power
    of two above it (at most :data:`MAX_PROBES`), so that a few compiled versions serve every chunk."""
    if most > settings.n_probe:
        settings = replace(settings, n_probe=int(min(MAX_PROBES, 1 << int(np.ceil(np.log2(most))))))
    return settings


_compose_chunk = exported_jit(_compose, static_argnames=("settings", "ground"))


def surface_fields(volume, transmittance):
    """The ground's fields packed for one bilinear lookup, (ny, nx, 11): spectral albedo (3) [-], land fraction
    [-], snow cover [-], wind speed at 10 m [m s-1], terrain gradient dh/dx, dh/dy [-], and Step 1a at the
    ground (the first level at or above the terrain): cloud transmittance T [-], terrain shadow [-] and the
    3-D aerosol's optical depth towards the sun at 550 nm [-]."""
    levels = volume["level"].values
    terrain = volume["terrain_height"].values
    k = np.clip(np.searchsorted(levels, terrain - 1e-6 * float(volume.attrs["dz"])), 0, levels.size - 1)
    jj, ii = np.indices(terrain.shape)

    def at_ground(name):
        return transmittance[name].values[k, jj, ii][..., None]

    return np.concatenate([
        volume["surface_albedo"].transpose("y", "x", "wavelength").values,
        volume["land_fraction"].values[..., None], volume["snow_cover"].values[..., None],
        volume["wind_speed_10m"].values[..., None], volume["terrain_slope"].transpose("y", "x", "component").values,
        at_ground("cloud_transmittance"), at_ground("terrain_shadow"), at_ground("aerosol_tau_sun"),
    ], axis=-1)


#: e-folding distances [grid cells] over which the ground's fields fade beyond the grid's edge from the nearest
#: edge cell's values to :func:`surface_fields_outside` (:func:`surface_beyond_edge`): the surface's properties
#: (albedo, land, snow, wind, slope) over 2 cells, its lighting by Step 1a (cloud T, terrain shadow, 3-D aerosol
#: towards the sun) over one, since no cloud beyond the grid casts a shadow. A longer fade carries an edge's
#: features far out: over 6 cells a hurricane's edge winds show as streaks of glint tens of cells beyond the grid.
SURFACE_EDGE_FADE_CELLS = 2.0
LIGHTING_EDGE_FADE_CELLS = 1.0


def surface_beyond_edge(clamped, outside, ny, nx, j, i):
    """The ground's fields at grid indices (j, i) (n,), anywhere: inside the grid ``clamped`` (n, C), its bilinear
    lookup; beyond it a fade, with the distance d [cells] from the grid, from the nearest edge cell's values
    (``clamped``, the lookup at the clamped indices) to ``outside`` (C,) (:func:`surface_fields_outside`), weight
    e^(-d / L) with L of :func:`surface_fade_cells`.

    A ground that is ``outside`` at once beyond the grid shows the domain's outline from space wherever
    the edge cells differ from their mean (a hurricane's wind, a coast), 19-30 % in the surface radiance of the
    Katrina scene; clamping every field to its edge value instead draws streaks of edge values across the whole
    view. The fade keeps the ground continuous at the edge and the mean some cells beyond it."""
    dj = jnp.maximum(jnp.maximum(-j, j - (ny - 1)), 0.0)
    di = jnp.maximum(jnp.maximum(-i, i - (nx - 1)), 0.0)
    w = jnp.exp(-jnp.sqrt(dj * dj + di * di)[:, None] / surface_fade_cells(clamped.shape[-1])[None, :])
    return outside[None, :] + (clamped - outside[None, :]) * w


def surface_fade_cells(n_fields=11):
    """The e-folding distance [cells] of each of the 11 fields of :func:`surface_fields` beyond the grid (11,), or
    with ``n_fields`` 14 also of the 3-D cloud scattering's diffuse ratios at the ground (lighting, like T)
    (:func:`swim.rt.clouds.cloud_constants`)."""
    return np.array([SURFACE_EDGE_FADE_CELLS] * 8 + [LIGHTING_EDGE_FADE_CELLS] * (n_fields - 8), np.float32)


def surface_fields_outside(fields):
    """The ground far beyond the grid (11,): the packed :func:`surface_fields` (ny, nx, 11) averaged over the grid's
    edge cells, flat, lit by the unobstructed sun (T = 1, no shadow, no 3-D aerosol); near the grid it fades
    into the edge cells' own values (:func:`surface_beyond_edge`)."""
    ring = np.concatenate([fields[0], fields[-1], fields[1:-1, 0], fields[1:-1, -1]])
    out = ring.mean(axis=0)
    out[6:8] = 0.0
    out[8:11] = (1.0, 1.0, 0.0)
    return out


#: Hydrometeor extinction [m-1] above which a cell counts as occupied (0.001 optical depth per km).
OCCUPIED_EXTINCTION = 1e-6
#: Change of the 3-D aerosol's optical depth across a cell above which the cell counts as occupied [-].
OCCUPIED_AEROSOL_CHANGE = 1e-3


def occupancy_grid(volume):
    """Where rays need fine steps, (level, y, x) int8: 1 in cells with hydrometeors, next to the terrain, or with
    a 3-D aerosol that changes by more than :data:`OCCUPIED_AEROSOL_CHANGE` in optical depth across the cell,
    dilated by one cell in every direction so that a probe between two cells still sees them
    (:func:`adaptive_step_edges`). Read-only: renders share it across suns (it depends on the volume alone)."""
    from scipy.ndimage import maximum_filter, minimum_filter

    from .occupancy_cpu import occupied_cells

    dz = float(volume.attrs["dz"])
    spacing = grid_geometry(volume).spacing
    extinction = volume["extinction"].values
    levels = np.ascontiguousarray(volume["level"].values, dtype=np.float64)
    # Only raised terrain needs the march to find it: the sea-level sphere is met analytically.
    terrain = np.asarray(volume["terrain_height"].values, dtype=np.float64)
    top = maximum_filter(terrain, size=3) if np.any(terrain > 1.0) else np.zeros_like(terrain)
    occupied = np.empty(extinction.shape[1:], bool)
    # the cloud and the terrain in one compiled pass, blocks of levels on every core (a float32 matrix-vector
    # product per cell on one thread, then two passes: 0.22 s for 400 x 400 x 60, docs/decisions/0007-scene-set-up.md)
    in_blocks(lambda k0, k1: occupied_cells(extinction, np.float32(OCCUPIED_EXTINCTION), levels, top, dz, k0, k1,
                                            occupied), occupied.shape[0])
    aerosol = volume["aerosol_extinction"].values
    if np.any(aerosol > 0):
        change = (maximum_filter(aerosol, size=3) - minimum_filter(aerosol, size=3)) * max(dz, spacing)
        occupied |= change > OCCUPIED_AEROSOL_CHANGE
    occupancy = dilated_by_one_cell(occupied).view(np.int8)
    occupancy.flags.writeable = False
    return occupancy


def step_classes(occupancy, fields, out=None):
    """The cells' classes for the step placement of one sun (:func:`grid_step_edges`), (level, y, x) int8: 1 where
    ``occupancy`` (:func:`occupancy_grid`) is occupied, :data:`SUNLIT_CLEAR` (-1) in sunlit clear air, 0 in the other
    empty cells.

    A cell is sunlit clear air where it is not occupied and the direct sun reaches it and every cell next to it (the
    3 x 3 x 3 cube around it) with a transmittance of at least :data:`SUNLIT_TRANSMITTANCE`: Step 1a's cloud
    transmittance times the terrain's shadow times, with a 3-D aerosol, e^-(its sun-ward optical depth). There the
    clear sky's source (Eq. 3, Albers et al. 2020, doi:10.5194/amt-13-3235-2020) varies with height alone, through
    the smooth profiles of the gas and the background aerosol, and Eq. 12's cloud term is zero, so a ray needs few
    steps (:attr:`MarchSettings.sunlit_steps`); in the empty cells of a cloud's or the terrain's shadow the source
    changes across the shadow's edge, and they keep the empty cells' steps.

    Parameters
    ----------
    occupancy : numpy.ndarray
        Shape (level, y, x) int8: :func:`occupancy_grid` (> 0: occupied).
    fields : mapping
        Step 1a's fields (level, y, x) [-] by name: ``cloud_transmittance`` and ``terrain_shadow``, and
        ``aerosol_tau_sun`` where the volume has a 3-D aerosol (absent: none).
    out : numpy.ndarray, optional
        Shape (level, y, x) int8, written in place (an earlier sun's classes; its device copies are dropped).

    Returns
    -------
    numpy.ndarray
        Shape (level, y, x) int8, read-only: ``out`` where given.

    Raises
    ------
    ValueError
        If a field's or ``out``'s shape is not ``occupancy``'s.
    """
    from .occupancy_cpu import classify_cells, unlit_nodes

    cloud, shadow = (np.asarray(fields[name]) for name in ("cloud_transmittance", "terrain_shadow"))
    aerosol = fields.get("aerosol_tau_sun")
    has_aerosol = aerosol is not None
    aerosol = np.asarray(aerosol) if has_aerosol else np.zeros((1, 1, 1), np.float32)
    arrays = [cloud, shadow] + ([aerosol] if has_aerosol else []) + ([out] if out is not None else [])
    if any(a.shape != occupancy.shape for a in arrays):
        raise ValueError(f"step_classes: fields and out must have the occupancy's shape {occupancy.shape}, got "
                         f"{[a.shape for a in arrays]}")
    unlit = np.empty(occupancy.shape, bool)
    in_blocks(lambda k0, k1: unlit_nodes(cloud, shadow, aerosol, has_aerosol, SUNLIT_TRANSMITTANCE, k0, k1, unlit),
              unlit.shape[0])
    unlit = dilated_by_one_cell(unlit)  # a cell is sunlit only where every cell next to it is
    if out is None:
        out = np.empty(occupancy.shape, np.int8)
    else:
        forget_device_copies_of(out)
        out.flags.writeable = True
    in_blocks(lambda k0, k1: classify_cells(occupancy, unlit, np.int8(SUNLIT_CLEAR), k0, k1, out), out.shape[0])
    out.flags.writeable = False
    return out


def dilated_by_one_cell(mask):
    """A boolean array with every cell next to a True cell (a 3 x 3 x ... cube around it) set: what
    ``scipy.ndimage.maximum_filter(mask, size=3)`` gives, by one shifted ``|=`` per side and axis (bytes, in
    place: 0.03 s against scipy's 0.18 s for 160 x 400 x 400; docs/decisions/0007-scene-set-up.md); a 3-D mask (a
    grid's) in two compiled passes on every core where numba is installed (:func:`swim.rt.occupancy_cpu.dilate_cells`,
    docs/decisions/0006-gpu-kernels.md).

    Parameters
    ----------
    mask : numpy.ndarray
        Bool, any shape.

    Returns
    -------
    numpy.ndarray
        Bool, the shape of ``mask`` (a new array).
    """
    if np.ndim(mask) == 3 and _numba_available():  # a grid's: compiled, on every core (swim.rt.occupancy_cpu)
        from .occupancy_cpu import dilate_cells

        return dilate_cells(mask)
    out = np.array(mask, dtype=bool, copy=True)
    for axis in range(out.ndim):
        if out.shape[axis] < 2:
            continue
        before = out.copy()
        lower = [slice(None)] * out.ndim
        upper = [slice(None)] * out.ndim
        lower[axis], upper[axis] = slice(None, -1), slice(1, None)
        out[tuple(upper)] |= before[tuple(lower)]
        out[tuple(lower)] |= before[tuple(upper)]
    return out


def aerosol_column_optical_depth(volume):
    """Column optical depth at 550 nm of the optical volume's 3-D aerosol (y, x) [-] (sum over its levels)."""
    aer = volume["aerosol_extinction"]
    column = aer.values.sum(axis=0) * float(volume.attrs["dz"])  # numpy: no NaN-skipping copy of the volume
    return xr.DataArray(column, coords={d: aer.coords[d] for d in ("y", "x") if d in aer.coords}, dims=("y", "x"),
                        name="aerosol_column_optical_depth")


#: The variables of :func:`swim.rt.solar.solar_transmittance` that :func:`volume_constants` reads.
KERNEL_STEP1A_VARIABLES = ("aerosol_tau_sun", "cloud_transmittance", "terrain_shadow")
#: Constants of :func:`kernel_constants` kept as numpy arrays: the packed volume (the biggest array of a render)
#: and the step classes of the sun (:func:`step_classes`, under the name "occupancy"), which only the step loop reads.
#: The numba kernel reads them in place; the JAX kernel gets one device copy (:func:`_device_constants`), so a CPU
#: render does not hold the volume twice.
HOST_CONSTANTS = ("volume", "occupancy")


def kernel_constants(volume, transmittance, gas: GasTables, sun_direction_scene, radius=EARTH_RADIUS_M):
    """Arrays and scalars shared by all chunks of a render: :func:`volume_constants` and
    :func:`atmosphere_constants` in one dict."""
    return {**volume_constants(volume, transmittance), **atmosphere_constants(gas, sun_direction_scene, radius)}


def packed_aerosol_3d(n_channels, n_species) -> bool:
    """Whether a packed volume of ``n_channels`` channels and ``n_species`` packed species holds the 3-D aerosol's
    two channels.

    The packed volume's layout (:func:`pack_volume`): the extinctions of the species that are not zero everywhere
    (:func:`packed_species`, in the order of :data:`swim.constants.SPECIES`), the 3-D aerosol's extinction and its
    optical depth towards the sun (550 nm), Step 1a's cloud transmittance T, the terrain shadow (last). The terrain
    shadow cuts the direct beam only; the skylight under a cloud is dimmed by T alone. Species that are zero
    everywhere and, without a 3-D aerosol, its two channels are left out: RICO's liquid-only cumulus packs 3
    channels instead of 7 (18.5 -> 7.9 MB), and a march through it is 6-16 % faster for it
    (docs/decisions/0007-scene-set-up.md)."""
    return n_channels == n_species + 4


def packed_species(volume) -> tuple[int, ...]:
    """The species of an optical volume whose extinction is not zero everywhere: the species channels of
    :func:`pack_volume`.

    Parameters
    ----------
    volume : xarray.Dataset
        Optical volume (:func:`swim.optics.volume.build_optical_volume`): ``extinction`` (species, level, y, x)
        [m-1] over a ``species`` coordinate of names of :data:`swim.constants.SPECIES`, in that order (after
        :func:`share_packed_channels`, only the packed ones).

    Returns
    -------
    tuple of int
        Indices into :data:`swim.constants.SPECIES`, increasing.

    Raises
    ------
    ValueError
        If the ``species`` coordinate names a species not in :data:`swim.constants.SPECIES` or is out of its order.
    """
    names = [str(name) for name in volume["species"].values]
    unknown = [name for name in names if name not in SPECIES]
    if unknown:
        raise ValueError(f"optical volume: unknown species {unknown}; expected names of {SPECIES}")
    index = [SPECIES.index(name) for name in names]
    if index != sorted(set(index)):
        raise ValueError(f"optical volume: species {names} are not in the order of {SPECIES}")
    extinction = volume["extinction"].values
    nk = extinction.shape[1]
    level_bytes = int(np.prod(extinction.shape[2:])) * extinction.itemsize  # (no species at all: a clear sky)
    step = max(1, (4 << 20) // max(level_bytes, 1))  # ~4 MB of levels at a time: a cloud ends the scan

    def any_nonzero(n):
        return any(np.any(extinction[n, k0:k0 + step]) for k0 in range(0, nk, step))

    return tuple(s for n, s in enumerate(index) if any_nonzero(n))


def species_matrix(species) -> np.ndarray:
    """(len(species), len(SPECIES)) float32 one-hot rows: the packed species' optical depths (n, p) times it are
    those of all :data:`swim.constants.SPECIES` (n, 5), 0 for the species not packed (exactly: x * 1 + 0)."""
    matrix = np.zeros((len(species), len(SPECIES)), np.float32)
    matrix[np.arange(len(species)), list(species)] = 1.0
    return matrix


def pack_volume(volume, species=None):
    """The packed volume of :func:`volume_constants`, (level, y, x, channel) float32, with the grid's own channels
    filled: the extinctions of ``species`` and, where the volume has a 3-D aerosol, its extinction. Step 1a's
    channels (one sun) are left for :func:`volume_constants` to fill (their values are undefined until then).

    A render packs the grid before Step 1a and then lets the optical volume share the packed channels
    (:func:`share_packed_channels`), so the volume's own extinctions are freed before Step 1a's fields are made
    (docs/performance.md, "Memory"). Channels: the extinctions of ``species`` (indices into
    :data:`swim.constants.SPECIES`; default :func:`packed_species`, those not zero everywhere: a march through
    fewer channels reads fewer cache lines), then with a 3-D aerosol its extinction and ``aerosol_tau_sun``, then
    ``cloud_transmittance`` and ``terrain_shadow`` (``len(species) + 4`` channels with the aerosol, two fewer
    without: its channels would be zeros)."""
    if species is None:
        species = packed_species(volume)
    names = [str(name) for name in volume["species"].values]
    extinction = volume["extinction"].values
    aerosol = volume["aerosol_extinction"].values
    grid = [extinction[names.index(SPECIES[s])] for s in species]
    with_aerosol = bool(np.any(aerosol))
    if with_aerosol:
        grid.append(aerosol)
    n_channels = len(species) + (4 if with_aerosol else 2)
    packed = np.empty(extinction.shape[1:] + (n_channels,), np.float32)

    _fill_channels(packed, dict(enumerate(grid)))
    return packed


def _fill_channels(packed, values):
    """``packed[..., c] = value`` for each channel c and its ``value`` (level, y, x) of the dict ``values``, on every
    core: level by level, each level's channels one after the other while its cache lines are in the caches (0.056 s
    for the 400 x 400 x 60 scene's grid, 0.136 s channel by channel; docs/decisions/0007-scene-set-up.md). A transpose
    and a concatenate would each copy the whole volume."""
    def fill(k0, k1):
        for k in range(k0, k1):
            for c, value in values.items():
                packed[k, ..., c] = value[k]

    in_blocks(fill, packed.shape[0])


def shared_packed_volume(volume, species):
    """The packed volume that an optical volume's extinctions are views of (:func:`share_packed_channels`), so that
    a new sun refills its Step 1a channels in place (:func:`volume_constants`) instead of packing the grid again.

    Parameters
    ----------
    volume : xarray.Dataset
        Optical volume (:func:`swim.optics.volume.build_optical_volume`).
    species : tuple of int
        The species packed (indices into :data:`swim.constants.SPECIES`, :func:`packed_species`).

    Returns
    -------
    numpy.ndarray or None
        Shape (level, y, x, channel) float32: the packed volume whose first ``len(species)`` channels (and, with a
        3-D aerosol, the next) the volume's ``extinction`` (and ``aerosol_extinction``) are views of; None where
        they are not (a volume not yet shared, or shared with another layout), and the caller packs it anew.

    A new sun's repacking copied the whole grid (0.7 GB for the 400 x 400 x 60 scene's 160 levels and 7 channels,
    0.25-1.5 s on this project's 2 cores) and held two packed volumes at once (docs/decisions/0006-gpu-kernels.md).
    """
    n = len(species)
    channels = volume["extinction"].values
    packed = _owner(channels)
    if not (isinstance(packed, np.ndarray) and packed.ndim == 4 and packed.dtype == np.float32
            and packed.shape[-1] in (n + 2, n + 4) and channels.shape == (n,) + packed.shape[:-1]):
        return None
    # each view and the packed channels it must be: the same memory, shape and strides
    views = [(channels, np.moveaxis(packed[..., :n], -1, 0))]
    if packed_aerosol_3d(packed.shape[-1], n):
        views.append((volume["aerosol_extinction"].values, packed[..., n]))
    if any(_buffer_identity(view) != _buffer_identity(expected) for view, expected in views):
        return None
    return packed


def step1a_channel_names(aerosol_3d) -> tuple:
    """The packed volume's Step 1a channels by name, in their order (the last channels): :data:`KERNEL_STEP1A_VARIABLES`,
    without ``aerosol_tau_sun`` where the volume has no 3-D aerosol (:func:`packed_aerosol_3d`)."""
    return KERNEL_STEP1A_VARIABLES if aerosol_3d else KERNEL_STEP1A_VARIABLES[1:]


def step1a_channel_views(packed, species):
    """The packed volume's Step 1a channels (:data:`KERNEL_STEP1A_VARIABLES`, the 3-D aerosol's only where it is
    packed) as writeable views (level, y, x) by variable name, for :func:`swim.rt.solar.solar_transmittance` to write
    a new sun's fields into (its ``out``); :func:`volume_constants` then finds them in place and copies nothing.

    Parameters
    ----------
    packed : numpy.ndarray
        Shape (level, y, x, channel) float32: a packed volume that this process owns (:func:`pack_volume`,
        :func:`shared_packed_volume`); its device copies are dropped (its values are about to change) and it is made
        writeable until :func:`volume_constants` has filled it.
    species : tuple of int
        The species packed (indices into :data:`swim.constants.SPECIES`, :func:`packed_species`).

    Returns
    -------
    dict of str to numpy.ndarray
        ``aerosol_tau_sun`` (with a 3-D aerosol), ``cloud_transmittance`` and ``terrain_shadow``.

    The fields were made whole (~100 MB each at 400 x 400 x 160, all held until the copy) and then copied into the
    channels: one compiled pass instead takes 0.04-0.08 s off a new sun's 0.63-0.68 s for the 400 x 400 x 60 scene
    (docs/decisions/0007-scene-set-up.md)."""
    aerosol_3d = packed_aerosol_3d(packed.shape[-1], len(species))
    names = step1a_channel_names(aerosol_3d)
    first = packed.shape[-1] - len(names)
    forget_device_copies_of(packed)
    packed.flags.writeable = True
    return {name: packed[..., first + c] for c, name in enumerate(names)}


def volume_constants(volume, transmittance, occupancy=None, packed=None, species=None, classes=None):
    """The kernel constants of the grid and Step 1a (one sun), the big ones: the packed volume (level, y, x,
    channel) and the sun's step classes (level, y, x; :func:`step_classes`) as read-only numpy arrays
    (:data:`HOST_CONSTANTS`), the terrain, the ground's fields and the grid's index map as device arrays.

    ``transmittance`` needs the :data:`KERNEL_STEP1A_VARIABLES` of :func:`swim.rt.solar.solar_transmittance`;
    it is not referenced by the result, so a caller that keeps only this frees Step 1a's fields. ``occupancy``:
    the volume's :func:`occupancy_grid` (read-only), which does not depend on the sun, where the caller keeps it
    from an earlier sun; default: computed here. ``packed``: the volume's :func:`pack_volume`, whose Step 1a
    channels are filled here (in place; also an earlier sun's, :func:`shared_packed_volume`, whose device copies
    are then dropped); default: packed here. Step 1a's fields that are already the packed channels (written there by
    :func:`swim.rt.solar.solar_transmittance` through :func:`step1a_channel_views`) are not copied. ``species``: the
    species packed (indices into :data:`swim.constants.SPECIES`; default :func:`packed_species`), which the result's
    ``species_matrix`` expands to all of them. ``classes``: an earlier sun's :func:`step_classes` of this grid, to
    be written in place; default: a new array. The result's ``"occupancy"`` is the step classes of this sun (the
    kernels read an occupancy grid's 1 and 0 alike)."""
    geometry = grid_geometry(volume)
    if species is None:
        species = packed_species(volume)
    if packed is None:
        packed = pack_volume(volume, species)
    aerosol_3d = packed_aerosol_3d(packed.shape[-1], len(species))
    if packed.shape[-1] != len(species) + 2 + 2 * aerosol_3d:
        raise ValueError(f"packed volume of {packed.shape[-1]} channels does not hold the species {species}")
    n_grid = packed.shape[-1] - 2 - aerosol_3d  # channels of the grid itself
    names = step1a_channel_names(aerosol_3d)
    values = [transmittance[name].values for name in names]
    if packed.shape[:-1] != values[0].shape:
        raise ValueError(f"packed volume of shape {packed.shape} does not match Step 1a's fields {values[0].shape}")

    # a packed volume filled before (an earlier sun's): its device copies hold the old channels
    forget_device_copies_of(packed)
    packed.flags.writeable = True  # read-only for the kernels and the views; owned, so this may be set again
    # the fields that are not in their channels already (step1a_channel_views)
    missing = {n_grid + c: value for c, value in enumerate(values)
               if _buffer_identity(value) != _buffer_identity(packed[..., n_grid + c])}
    if missing:
        _fill_channels(packed, missing)
    packed.flags.writeable = False
    if occupancy is None:
        occupancy = occupancy_grid(volume)
    classes = step_classes(occupancy, dict(zip(names, values)), out=classes)
    surface = surface_fields(volume, transmittance)
    f32 = lambda a: jnp.asarray(np.asarray(a, dtype=np.float32))  # noqa: E731
    return {
        # host arrays (HOST_CONSTANTS): the numba kernel reads them in place; the JAX kernel gets one device copy
        "volume": packed,
        "occupancy": classes,
        "terrain": f32(volume["terrain_height"].values[None]),
        "surface": f32(np.moveaxis(surface, -1, 0)),
        "surface_outside": f32(surface_fields_outside(surface)),
        "index_map": {key: f32(volume.attrs[key]) for key in ("index_map_centre", "index_map_scale", "index_map_coefficients",
                                                             "index_map_bounds") if key in volume.attrs},
        "z_bottom": f32(geometry.z_bottom),
        "dz": f32(geometry.dz),
        "aerosol_column": f32(aerosol_column_optical_depth(volume).values[None]),
        "species_matrix": f32(species_matrix(species)),
    }


def share_packed_channels(volume, packed, species=None):
    """Point the optical volume's ``extinction`` (species, level, y, x) and, where packed, ``aerosol_extinction``
    (level, y, x) at their channels of a packed volume (:func:`pack_volume`, or the ``"volume"`` of
    :func:`volume_constants`) as read-only views, freeing the volume's own copies: a render then holds the grid's
    extinctions once (docs/performance.md, "Memory").

    The values are unchanged (the packed channels are copies of them), but the ``species`` coordinate then names
    only the packed ones (``species``, indices into :data:`swim.constants.SPECIES`; default
    :func:`packed_species`): the others were zero everywhere. A later Step 1a (a new sun) reads the views, and the
    next :func:`pack_volume` copies them into its own packed volume, which may then be shared in turn. Modifies
    ``volume`` in place and returns it."""
    if species is None:
        species = packed_species(volume)
    n_species = len(species)
    channels = np.moveaxis(packed[..., :n_species], -1, 0).view()
    channels.flags.writeable = False
    extinction, coordinate = volume["extinction"], volume["species"]
    # the species dimension changes size: the variable and its coordinate go first (the same Dataset object)
    del volume["extinction"]
    del volume["species"]
    volume["extinction"] = xr.Variable(extinction.dims, channels, extinction.attrs)
    volume.coords["species"] = xr.Variable("species", np.array([SPECIES[s] for s in species], coordinate.dtype),
                                           coordinate.attrs)
    if packed_aerosol_3d(packed.shape[-1], n_species):
        aerosol = packed[..., n_species].view()
        aerosol.flags.writeable = False
        volume["aerosol_extinction"] = volume["aerosol_extinction"].copy(data=aerosol)
    return volume


def atmosphere_constants(gas: GasTables, sun_direction_scene, radius=EARTH_RADIUS_M):
    """The kernel constants of the clear atmosphere (:mod:`swim.rt.gas` tables), the sun and the hydrometeor
    optics: small device arrays and scalars. ``beta_gas`` (4, n_gas) is the clear air's height table: the
    extinction profiles [m-1] of molecules, background and stratospheric aerosol at the first wavelength (their
    spectra in ``beta_gas_spectra``), then the fraction of the vertical optical depth above each height
    (:func:`gas_column_above`, row :data:`swim.constants.GAS_COLUMN_ROW`)."""
    classes = np.asarray(gas.diffuse_horizontal_classes)  # (n_class, nu, nmu, 3)
    # Molecules, background and stratospheric aerosol: each a height profile times a spectrum, so the kernel
    # looks up 3 profiles instead of 9 columns; the spectra relative to the first wavelength.
    components = [np.asarray(b, dtype=float) for b in (gas.beta_rayleigh, gas.beta_aerosol, gas.beta_stratospheric)]
    spectra = np.ones((3, 3))
    for c, b in enumerate(components):
        if b[:, 0].sum() > 0:
            spectra[c] = b.sum(axis=0) / b[:, 0].sum()
            if not np.allclose(b, b[:, :1] * spectra[c][None, :], rtol=1e-5, atol=1e-30):
                raise ValueError("clear-atmosphere extinction must be a height profile times a spectrum")
    sun = np.asarray(sun_direction_scene, dtype=float)
    profiles = np.stack([b[:, 0] for b in components])
    # the rows of the height table: the three profiles, then the column above each height (GAS_COLUMN_ROW)
    height_table = np.concatenate([profiles, gas_column_above(profiles, spectra, gas.dh)[None]])
    f32 = lambda a: jnp.asarray(np.asarray(a, dtype=np.float32))  # noqa: E731
    return {
        "radius": f32(radius),
        "sun": f32(sun),
        "mu0": f32(sun[2]),
        "dh": f32(gas.dh),
        "top": f32(gas.top_m),
        "beta_gas": f32(height_table),
        "beta_gas_spectra": f32(spectra),
        "sky": f32(np.moveaxis(np.concatenate([gas.sun_transmittance, gas.diffuse_horizontal], axis=-1), -1, 0)),
        "ms_source": f32(np.stack([t.source for t in gas.diffuse_sources])),
        "diffuse_classes": f32(np.moveaxis(classes, -1, 0).reshape(3, -1, classes.shape[2])),
        "class_aod": f32(gas.aerosol_class_aod),
        "angstrom": f32(gas.angstrom_factor),
        "aerosol_ssa": f32(gas.aerosol.ssa),
        "stratospheric_ssa": f32(gas.aerosol.stratospheric.ssa),
        "g_liquid": f32(G_LIQUID),
        "backscatter": f32([BACKSCATTER_FRACTION[s] for s in SPECIES]),
    }


#: Rays per call of :func:`ray_segments_compiled` and of a ``ray_phase`` function in :func:`trace_rays` (bounds the
#: phase functions' temporaries).
SEGMENT_BLOCK = 65536
#: Fewest rays per block of :func:`ray_segments_compiled` in :func:`trace_rays` when a batch is split between threads:
#: a smaller block's hand-over to a thread costs more than its rays' segments (~0.02-0.03 us a ray).
SEGMENT_MIN_BLOCK = 8192
#: Smallest batch of rays the kernel is compiled for (:func:`padded_batch_size`).
MIN_BATCH = 256


def padded_batch_size(n, chunk):
    """Rays a kernel call of n rays marches: ``chunk``, or for a last, smaller batch the next power of two
    (at least :data:`MIN_BATCH`). The kernel is compiled once per batch size, so a few sizes serve any number
    of rays (renders of every image size, the batches of adaptive sampling) with at most half of a batch
    wasted on padding."""
    if n >= chunk:
        return chunk
    return int(min(chunk, max(MIN_BATCH, 1 << int(np.ceil(np.log2(max(n, 1)))))))


#: Fewest rays of a chunk before the last round of :func:`chunk_spans` (each chunk has fixed costs of its own: its
#: job's Python calls and arrays).
TAIL_CHUNK = 512


def chunk_spans(n, chunk, cores, least=TAIL_CHUNK):
    """The chunks [lo, hi) of a batch of n rays that ``cores`` workers march on the CPU, in order: each round of
    ``cores`` chunks takes half of the rays left, split evenly (at most ``chunk`` rays per chunk), until such chunks
    would be smaller than ``least``: the last round takes what is left, split evenly. Chunks thus shrink towards the
    batch's end.

    This is "factoring" (Hummel, Schonberg and Flynn 1992, "Factoring: a method for scheduling parallel loops",
    Commun. ACM 35(8), 90-101, doi:10.1145/135226.135232). A ray's cost varies ~10-fold across an image (the horizon's
    rays cross far more cells than the zenith's), so chunks of equal size left one core marching the batch's last
    chunk alone for 0.04-0.15 s of a 1024^2 all-sky's three batches while the other waited
    (docs/decisions/0002-per-ray-cpu-kernel.md); with chunks this small at the end, it waits for a small one. A small
    batch (a small image, a level of adaptive sampling) still runs on every core from the start.

    Parameters
    ----------
    n : int
        Rays in the batch, >= 0.
    chunk : int
        Most rays per chunk, >= 1.
    cores : int
        Workers, >= 1.
    least : int
        Fewest rays per chunk but in the last round (whose chunks are < 2 ``least``), >= 1.

    Returns
    -------
    list of tuple of int
        (lo, hi) per chunk: consecutive, covering range(n).
    """
    spans, lo = [], 0
    while lo < n:
        left = n - lo
        size = min(-(-left // (2 * cores)), chunk)
        if size < least and -(-left // cores) <= chunk:  # the last round: what is left, split evenly
            k = min(cores, left)
            ends = lo + np.cumsum([left // k + (q < left % k) for q in range(k)])  # the bigger chunks first
            return spans + [(int(a), int(b)) for a, b in zip([lo, *ends[:-1]], ends)]
        for _ in range(cores):
            if lo < n:
                spans.append((lo, min(lo + size, n)))
                lo = spans[-1][1]
    return spans


def trace_rays(origins, directions, consts, geometry: GridGeometry, ray_phase, settings: MarchSettings = MarchSettings(),
               progress=None):
    """March rays and return per-ray radiance components (numpy arrays).

    Parameters
    ----------
    origins, directions : numpy.ndarray
        Shape (n, 3): scene-frame origins [m] and unit directions.
    consts : dict
        From :func:`kernel_constants`.
    geometry : GridGeometry
    ray_phase : dict or callable
        Per-ray arrays (n,): ``cos_theta`` (cosine of the scattering angle), ``cos_view_zenith`` (view
        direction dotted with the local up at the reference point), ``p_rayleigh`` (phase function,
        mean 1 over the sphere); ``p_aerosol`` and ``p_stratospheric`` (n, 3), the phase functions of the
        background and the stratospheric aerosol per wavelength. Or a function that returns that dict for a
        (m, 3) block of ``directions``, called block by block (:data:`SEGMENT_BLOCK` rays) so that a big image
        never holds them all.
    settings : MarchSettings
    progress : callable, optional
        Called with (rays done, rays total) after each chunk.

    Returns
    -------
    dict of numpy.ndarray
        ``radiance`` (n, 3) [-] solar-relative L' (Eq. 2) at 615/546/450 nm and its components
        ``radiance_clear``, ``radiance_cloud``, ``radiance_surface``; ``tau_hydrometeor`` (n,);
        ``tau_clear`` (n, 3); ``surface`` (n,) bool; ``distance`` (n,) [m] to the ground or NaN; ``steps`` (n,)
        the volume samples each ray took: as marched by the per-ray kernels ("numba", "cuda": refined halves
        included, none after the ground, :func:`swim.rt.march_cpu.march_rays`), the lockstep count
        ``n_before + n_grid + n_after + 1`` for the JAX kernel, whose rays all take every step of their chunk.

    Raises
    ------
    SwimInputError
        If there are no rays, if ``origins`` or ``directions`` are not finite (n, 3) arrays, or if
        ``settings.backend`` is "numba" and numba is not installed.
    """
    # the numba kernel reads its tables unchecked: a NaN ray must not get that far
    check_rays("trace_rays", origins, directions)
    seg = ray_segments_parallel(origins, directions, geometry, top=float(consts["top"]))
    # Segments of zero length for every ray need no steps (e.g. observers inside the grid).
    bounds = seg["bounds"]
    settings = without_empty_segments(settings.kernel_settings(), [np.any(length > 0) for length in (
        bounds[:, 0], bounds[:, 1] - bounds[:, 0], bounds[:, 2] - bounds[:, 1])])
    n = len(origins)
    chunk = batch = settings.resolved_chunk()
    steps = settings.n_before + settings.n_grid + settings.n_after + 1  # the end step (_march_rays)
    backend = settings.resolved_backend()
    if backend == "numba":
        # chunks that shrink towards the batch's end, so that all cores finish together (chunk_spans)
        cores = threads()
        spans = chunk_spans(n, chunk, cores)
    else:
        spans = [(lo, min(lo + chunk, n)) for lo in range(0, n, chunk)]
    if backend in ("numba", "cuda"):
        tables = _numba_tables(consts, prepare=backend == "numba")
        if backend == "cuda":
            from .march_cuda import device_tables

            tables = device_tables(tables)
        # the JAX set-up and composition never read the host arrays (a jitted call would copy them every time)
        consts = {key: value for key, value in consts.items() if key not in HOST_CONSTANTS}
    else:
        from .march_pallas import with_vector_volume

        # the probes' program takes the constants as the ray table's build gives them (one compiled program for
        # both), the march those and the fused kernel's padded volume
        probe_consts = _device_constants(_jax_cloud_constants(consts))
        consts = with_vector_volume(probe_consts, settings)
    outputs = {}  # written chunk by chunk into arrays for all rays (a list and a concatenate would hold two)
    # [first ray, end, phase arrays of those rays]: all rays for a dict, blocks of SEGMENT_BLOCK for a function
    # (one call per chunk would pay the phase functions' JAX dispatch ~200 times for a 1024^2 image)
    phase_block = [] if callable(ray_phase) else [0, n, ray_phase]
    pool, pending = None, collections.deque()  # (collect the outputs, end of the chunk, cancel it or None)
    held = []  # the first chunks' jobs, one per worker, submitted together (below)
    if backend == "numba":
        # chunks marched at once, one per core (the numba kernel runs without the GIL)
        workers = min(cores, len(spans))
        pool = worker_pool(workers) if workers > 1 else None
    # the JAX kernel's chunks are marched one after the other, on one worker thread when there are several chunks
    jax_pool = worker_pool(1) if backend == "jax" and n > chunk and not in_worker_thread() else None

    def finished(out, hi):
        for key, value in out.items():
            if key not in outputs:
                outputs[key] = np.empty((n,) + value.shape[1:], value.dtype)
            outputs[key][hi - len(value):hi] = value
        if progress is not None:
            progress(hi, n)

    try:
        for lo, hi in spans:
            pad = padded_batch_size(hi - lo, batch) - (hi - lo)

            def take(a, dtype=np.float32, first=0):
                return _pad_rows(np.asarray(a[lo - first:hi - first]), pad).astype(dtype)

            if not phase_block or hi > phase_block[1]:
                block_hi = min(n, lo + max(SEGMENT_BLOCK, hi - lo))
                phase_block[:] = [lo, block_hi, ray_phase(np.asarray(directions[lo:block_hi]))]
            rays = {key: take(value, first=phase_block[0]) for key, value in phase_block[2].items()}
            args = [take(seg["start"]), take(directions), take(seg["bounds"]), take(seg["ends_on_ground"], bool),
                    take(seg["valid"], bool)]
            if backend == "jax":
                args = list(map(jnp.asarray, args))
                rays = {key: jnp.asarray(value) for key, value in rays.items()}
                job = functools.partial(_trace_chunk_jax, args, rays, consts,
                                        *_chunk_probes(*args[:3], probe_consts, settings), hi - lo)
                if jax_pool is None:
                    finished(job(), hi)
                    continue
                # On a GPU the call returns only when the march is done (XLA reads its while loop's condition on
                # the host every step): a worker thread waits for it while this one prepares the next chunk
                # (docs/decisions/0006-gpu-kernels.md); the one before is collected now (two chunks at most are held)
                future = jax_pool.submit(job)
                pending.append((future.result, hi, future.cancel))
                if len(pending) > 1:
                    collect, done_hi, _ = pending.popleft()
                    finished(collect(), done_hi)
                continue
            job = functools.partial(_trace_chunk_numba, *args, rays, consts, settings, tables,
                                    [take(a, float) for a in (seg["start"], directions, seg["bounds"])], hi - lo,
                                    kernel=backend)
            if pool is None:
                finished(job(), hi)
                continue
            held.append((job, hi))
            if not pending and len(held) < workers and hi < n:
                # the first round's jobs are made before any is submitted: a worker's Python calls (the kernels'
                # dispatch) do not compete for the GIL with the making of the next job, and the chunks of a small
                # image start together (the second chunk of the Monte Carlo case's 41^2 view started ~0.8 ms after
                # the first; the view -0.1 ms in median, docs/decisions/0005-adaptive-sampling.md)
                continue
            for ready, ready_hi in held:
                future = pool.submit(ready)
                pending.append((future.result, ready_hi, future.cancel))
            held.clear()
            if len(pending) >= 2 * workers:  # bound the chunks held in memory; collect in order
                collect, done_hi, _ = pending.popleft()
                finished(collect(), done_hi)
        while pending:
            collect, hi, _ = pending.popleft()
            finished(collect(), hi)
    finally:  # after an error (or an interrupt): the chunks not yet started are dropped
        for _, _, cancel in pending:
            if cancel is not None:
                cancel()
    if "steps" not in outputs:  # the lockstep kernel: every ray of a chunk takes every step
        outputs["steps"] = np.full(n, steps, np.int32)
    return outputs


#: Device copies of the last kernel constants' host arrays for the JAX kernel (:func:`_device_constants`,
#: :func:`device_copies`).
_DEVICE_COPIES = {}
#: Every cache that :func:`device_copies` has served (the JAX kernel's, the CUDA kernel's), for
#: :func:`forget_device_copies_of`.
_COPY_CACHES = [_DEVICE_COPIES]


def _jax_cloud_constants(consts):
    """``consts`` without the 3-D cloud scattering's host-only entries (:data:`swim.rt.clouds_device.CLOUD_HOST_KEYS`)
    and with its arrays on the device, once per render (a jitted call would copy a numpy array every time)."""
    if not three_d(consts):
        return consts
    out = {key: value for key, value in consts.items() if key not in CLOUD_HOST_KEYS}
    for key in (*CLOUD_KERNEL_KEYS, "ms_coarsen"):
        out[key] = jnp.asarray(np.asarray(out[key], np.float32))
    return out


def _device_constants(consts):
    """``consts`` with the arrays of :data:`HOST_CONSTANTS` as JAX device arrays, for the JAX kernel
    (:func:`device_copies`: on a GPU the volume's one transfer)."""
    return {**consts, **device_copies({key: consts[key] for key in HOST_CONSTANTS}, jnp.asarray, _DEVICE_COPIES)}


def kept_device_copies(hosts, cache=None):
    """The device copies that :func:`device_copies` keeps in ``cache`` (default: the JAX kernel's) for exactly the
    host arrays ``hosts`` (name -> numpy array; the same arrays owning the memory, the same views), or None where it
    keeps none of them."""
    entry = (_DEVICE_COPIES if cache is None else cache).get("entry")
    return dict(entry[1]) if _copies_of(entry, hosts) else None


def keep_device_copies(hosts, copies, cache=None):
    """Keep the device arrays ``copies`` (name -> array) as :func:`device_copies`'s copies of the host arrays ``hosts``
    (name -> numpy array, the same names and values) in ``cache`` (default: the JAX kernel's), replacing what it kept:
    for copies made on the device (a new sun's Step 1a there, :mod:`swim.rt.solar_device`) rather than sent."""
    _store_copies(_DEVICE_COPIES if cache is None else cache, hosts, copies)


def device_copies(hosts, transfer, cache):
    """Device copies ``transfer(array)`` of the host arrays ``hosts`` (name -> numpy array), made once and kept in
    ``cache`` while the arrays that own the hosts' memory live: a render's chunks, and the renders of one scene and
    sun, share them (a render may hand over new views of the same arrays). Only the last set is kept: the previous
    copies go before new ones are made, and they are dropped with their host arrays, so a new sun or a cleared
    stage cache never keeps an old volume on the device. Serves the JAX kernel (:func:`_device_constants`) and the
    CUDA one (:func:`swim.rt.march_cuda.device_tables`)."""
    entry = cache.get("entry")
    if not _copies_of(entry, hosts):
        cache.clear()  # the previous copies go before the new ones are made
        entry = _store_copies(cache, hosts, {key: transfer(a) for key, a in hosts.items()})
    return entry[1]


def _copies_of(entry, hosts):
    """Whether a cache's ``entry`` (:func:`device_copies`) holds the copies of exactly the host arrays ``hosts``: the
    same arrays owning their memory, and the same views of them."""
    return (entry is not None and entry[3] == [_buffer_identity(a) for a in hosts.values()]
            and all(ref() is _owner(a) for ref, a in zip(entry[0], hosts.values())))


def _store_copies(cache, hosts, copies):
    """Keep ``copies`` (name -> device array) in ``cache`` as the copies of the host arrays ``hosts``, replacing what
    it held; they are dropped with the first host array's owner. Returns the entry."""
    if not any(known is cache for known in _COPY_CACHES):
        _COPY_CACHES.append(cache)  # for forget_device_copies_of
    owners = [_owner(a) for a in hosts.values()]
    token = object()  # what the finalizer holds: not the copies, which must not outlive the entry
    entry = ([weakref.ref(owner) for owner in owners], dict(copies), token,
             [_buffer_identity(a) for a in hosts.values()])
    cache["entry"] = entry
    weakref.finalize(owners[0], _forget_device_copies, cache, token)
    return entry


def forget_device_copies_of(host):
    """Drop the device copies (:func:`device_copies`, every cache) of the host array ``host`` or of any view of the
    array that owns its memory: its values are about to change in place."""
    owner = _owner(host)
    for cache in _COPY_CACHES:
        entry = cache.get("entry")
        if entry is not None and any(ref() is owner for ref in entry[0]):
            cache.clear()


def _forget_device_copies(cache, token):
    entry = cache.get("entry")
    if entry is not None and entry[2] is token:
        cache.clear()


def _owner(a):
    """The array that owns ``a``'s memory (the end of its chain of bases)."""
    while isinstance(a, np.ndarray) and a.base is not None:
        a = a.base
    return a


def _buffer_identity(a):
    """A host array's memory, shape, type and strides: with its owner, what identifies the values of a view."""
    return a.__array_interface__["data"][0], a.shape, a.dtype.str, a.strides


def _host_rows(out, n):
    """The first n rows of a chunk's device outputs as host arrays (waits for the device)."""
    # one device_get starts every output's copy before waiting for any: on an H100 a warm 1024^2 adaptive frame took
    # 10-25 ms less than with one blocking copy per output (docs/decisions/0006-gpu-kernels.md)
    return {key: value[:n] for key, value in jax.device_get(out).items()}


def _trace_chunk_jax(args, rays, consts, settings, probes, n):
    """One chunk through the JAX kernel (:func:`_trace_chunk`), its first ``n`` rows' outputs as host arrays."""
    return _host_rows(_trace_chunk(*args, rays, consts, settings, probes), n)


def _pad_rows(a, pad):
    """``a`` with its last row repeated ``pad`` times: a batch filled up to a size the kernels are compiled for."""
    return np.concatenate([a, np.repeat(a[-1:], pad, axis=0)], axis=0) if pad else a


def _numba_tables(consts, prepare=True):
    """The kernel constants as the numpy arrays and packed scalars of :func:`swim.rt.march_cpu.march_rays`
    (views of the device arrays where JAX allows it, so the volume is not copied), and with ``prepare`` those of
    :func:`swim.rt.march_cpu.prepare_rays` (not for the CUDA kernel, whose set-up is JAX's: from a GPU they would be
    copies)."""
    from . import march_cpu

    p, coef = march_cpu.pack_parameters(consts)

    def arr(a):
        a = np.asarray(a).view()  # a view: marking it read-only leaves the caller's array as it was
        a.flags.writeable = False  # like JAX's host views, so that every render calls the same compiled kernel
        return a

    tables = {"p": p, "coef": coef, "beta_gas": arr(consts["beta_gas"]), "spectra": arr(consts["beta_gas_spectra"]),
              "sky": arr(consts["sky"]), "sky_lanes": _sky_lanes(consts["sky"]),
              "diffuse_classes": arr(consts["diffuse_classes"]),
              "n_class": int(consts["class_aod"].shape[0]), "volume": arr(consts["volume"]),
              "terrain": arr(consts["terrain"]), "occupancy": arr(consts["occupancy"]),
              "angstrom": arr(consts["angstrom"]), "aerosol_ssa": arr(consts["aerosol_ssa"]),
              "stratospheric_ssa": arr(consts["stratospheric_ssa"]), "species_matrix": arr(consts["species_matrix"]),
              "surface": arr(consts["surface"]), "surface_outside": arr(consts["surface_outside"]),
              "backscatter": arr(consts["backscatter"])}
    # each packed species' index into SPECIES, for the numba composition
    tables["species_index"] = np.argmax(tables["species_matrix"], axis=1).astype(np.int64)
    # the 3-D cloud scattering's tables (swim.rt.clouds.cloud_constants), or placeholders the kernel does not read
    tables["cloud_mode"] = "ms_field" in consts
    if tables["cloud_mode"]:
        tables.update({key: consts[key] for key in CLOUD_KERNEL_KEYS}, ms_coarsen=float(consts["ms_coarsen"]))
    else:
        tables.update(hydro_scale=arr(np.zeros(1)), hydro_narrow=arr(np.zeros(1)),
                      ms_field=arr(np.zeros((1, 1, 1, 4), np.float32)),
                      ms_above=arr(np.ones((2, 1, 1, 3), np.float32)), above_heights=arr(np.array([0.0, 1.0])),
                      ms_coarsen=1.0)
    if prepare:  # the source table with each corner's (n_u, 9) profiles as one row
        source = consts["ms_source"]
        tables.update(ms_source=arr(np.asarray(source).reshape(source.shape[:4] + (-1,))), n_u=int(source.shape[4]),
                      aerosol_column=arr(consts["aerosol_column"]), class_aod=arr(consts["class_aod"]))
    return tables


#: The last sky table's :func:`swim.rt.march_cpu.sky_lanes` (:func:`_sky_lanes`).
_SKY_LANES = {}


def _sky_lanes(sky):
    """:func:`swim.rt.march_cpu.sky_lanes` of the sky table ``sky`` (6, nu, nmu), read-only, made once per table
    and kept while the table lives: a render calls the kernels ~3 times (adaptive sampling's batches), a time series
    or the Monte Carlo case's repeated view many more, and the copy (3 MB for 96 x 512 entries) took ~1 ms. Kept by
    the table itself, a JAX array, not by :func:`device_copies`, which identifies the owner of a numpy array's memory:
    each host view of a JAX array has a new one."""
    from . import march_cpu

    entry = _SKY_LANES.get("entry")
    if entry is None or entry[0]() is not sky:
        _SKY_LANES.clear()
        lanes = march_cpu.sky_lanes(sky)
        lanes.flags.writeable = False
        _SKY_LANES["entry"] = entry = (weakref.ref(sky), lanes)
    return entry[1]


def _trace_chunk_numba(start, direction, bounds, ends_on_ground, valid, rays, consts, settings, tables, exact, n,
                       kernel="numba"):
    """One chunk of rays: the per-ray set-up (:func:`swim.rt.march_cpu.prepare_rays` for ``kernel`` "numba", JAX's
    :func:`_prepare_rays` for "cuda"), the step loop in :func:`swim.rt.march_cpu.march_rays` ("numba") or its CUDA
    twin :func:`swim.rt.march_cuda.march_rays` ("cuda"; ``exact``: start, direction and bounds in float64), and the
    composition (:func:`_compose_numba` for "numba", JAX's :func:`_compose` for "cuda"). Returns numpy arrays of the
    first ``n`` (real) rays.

    The chunk's arrays stay numpy arrays between the stages (the jitted stages take them as they are, and their
    outputs are fetched once): a JAX operation per slice or conversion cost ~30 dispatches per chunk, ~3 ms
    (docs/decisions/0009-work-around-the-march.md)."""
    from . import march_cpu, precompile

    if kernel == "numba":  # a helper process compiling the march on a cold cache: its result loaded, not redone;
        from . import ground_cpu

        precompile.wait(meanwhile=(ground_cpu.ground_tables,))  # the ground's tables built while it compiles
    march = march_cpu.march_rays
    if kernel == "cuda":
        from . import march_cuda

        march = march_cuda.march_rays  # its tables already on the device (march_cuda.device_tables)
    # The batch is padded (repeats of its last ray) to a size the JAX stages are compiled for; numba marches only
    # the real rays, and the padding rows of the state repeat the last one as the inputs do.
    padded = start.shape[0]
    # the set-up in numba too: no JAX call per chunk (docs/decisions/0009-work-around-the-march.md)
    if kernel == "numba":
        class_lower, class_weight = np.empty(padded, np.int32), np.empty(padded)
        ms = np.empty((9, n, tables["n_u"]) if settings.multiple_scattering else (9, 1, 2), np.float32)
        march_cpu.prepare_rays(*(a[:n] for a in exact), tables["p"], tables["coef"], tables["aerosol_column"],
                               tables["class_aod"], tables["ms_source"], settings.multiple_scattering,
                               class_lower[:n], class_weight[:n], ms)
        class_lower[n:], class_weight[n:] = class_lower[n - 1], class_weight[n - 1]
        aerosol_class = (class_lower, class_weight.astype(np.float32)[:, None])
        ms_profile = ms  # with settings.multiple_scattering off, a (9, 1, 2) placeholder that the march never reads
    else:
        aerosol_class, ms = _prepare_chunk(start, direction, bounds, consts, settings)
        aerosol_class = jax.device_get(aerosol_class)
        if ms is None:  # zeros that the march never reads
            ms_profile = np.zeros((9, n, 2), np.float32)
        elif hasattr(ms, "__cuda_array_interface__"):
            # on a GPU the kernel reads JAX's array in place: 9 x chunk x n_u float32 (~0.4 GB per 262 144 rays)
            # not fetched to the host and copied back (docs/decisions/0006-gpu-kernels.md); rows beyond n are not read
            ms_profile = ms.block_until_ready()
        else:  # JAX on the CPU (numba's CUDA simulator): a writable copy, the kernel's compiled types
            ms_profile = np.array(ms)
    # in the order of march_rays' outputs (its last arguments but the sample counts, which go to the caller alone)
    state = {"tau_clear": np.empty((padded, 3)), "tau_h": np.empty(padded),
             "tau_species": np.empty((padded, tables["species_matrix"].shape[0])), "l_clear": np.empty((padded, 3)),
             "i_nogas": np.empty((padded, 3)), "i_gas": np.empty((padded, 3)), "i_cloud_t": np.empty(padded),
             "alive": np.empty(padded, bool), "hit": np.empty(padded, bool), "s_hit": np.empty(padded)}
    # Per-chunk arrays are fresh (writable) copies and the tables read-only views of the device arrays, in
    # every call: numba compiles (and caches on disk) one version of the kernel per combination of types.
    phase = {key: rays[key][:n].astype(float) for key in ("p_rayleigh", "p_aerosol", "p_stratospheric")}
    if tables["cloud_mode"]:  # float32 as built (swim.rt.clouds.cloud_ray_inputs); the kernel sums in float64
        p_hydro = np.ascontiguousarray(rays["p_hydro"][:n], np.float32)
        ray_ms = np.ascontiguousarray(rays["ray_ms"][:n], np.float32)
    else:
        p_hydro, ray_ms = np.zeros((1, 1, 6), np.float32), np.zeros((1, 1, 3), np.float32)
    state["l_cloud"] = np.zeros((padded, 3))
    samples = np.empty(n, np.int64)
    ray_class = (np.array(aerosol_class[0][:n]), aerosol_class[1][:n, 0].astype(float))  # the march's and the ground's
    t, out = tables, [state[key][:n] for key in state if key != "l_cloud"] + [samples]
    march(
        *(a[:n] for a in exact), np.array(valid[:n]), phase["p_rayleigh"], phase["p_aerosol"], phase["p_stratospheric"],
        *ray_class, ms_profile, settings.multiple_scattering,
        settings.n_before, settings.n_grid, settings.n_after, t["p"], t["coef"], t["beta_gas"], t["spectra"],
        t["sky_lanes"], t["diffuse_classes"], t["n_class"], t["volume"], t["terrain"], t["occupancy"], t["angstrom"],
        t["aerosol_ssa"], t["stratospheric_ssa"], settings.n_probe, EMPTY_STEP_WEIGHT, float(settings.probe_spacing),
        MAX_PROBES, CELL_SLACK, settings.resolved_empty_steps(), EMPTY_CELLS_PER_STEP, settings.sunlit_steps,
        SUNLIT_CELLS_PER_STEP, CLEAR_PROBES, CLEAR_STEP_POWER,
        CLEAR_STEP_FLOOR, float(settings.tau_refine), REFINE_DEPTH, REFINE_BUDGET, REFINE_VISIBLE_TAU, REFINE_SLOTS,
        TERRAIN_BISECTIONS, float(settings.stop_tau), *out, bool(t["cloud_mode"]), p_hydro, ray_ms, t["hydro_scale"],
        t["hydro_narrow"], t["ms_field"], t["ms_coarsen"], t["ms_above"], t["above_heights"], state["l_cloud"][:n])
    # the clouds and the ground composed in numba too (docs/decisions/0009-work-around-the-march.md)
    if kernel == "numba":
        return {**_compose_numba(exact, ends_on_ground, valid, rays, settings, tables, state, ray_class, n),
                "steps": samples.astype(np.int32)}
    _pad_state(state, n, tables)
    # a chunk without a ray on the ground composes without the ground's term (a second compiled version)
    ground = bool(np.any(_ends_on_surface(state, ends_on_ground)[:n]))
    out = _compose_chunk(start, direction, bounds, ends_on_ground, valid, rays, consts, settings, state, aerosol_class,
                         ground=ground)
    return {**_host_rows(out, n), "steps": samples.astype(np.int32)}


def _pad_state(state, n, tables):
    """The per-ray kernels' state (float64, the first ``n`` of its rows written) as the JAX composition takes it, in
    place: the padding rows repeat the last ray (as the inputs do), float32, and the packed species' optical depths
    spread into all of SPECIES' (those not packed were zero everywhere), as in the JAX kernel (:func:`_march_rays`)."""
    for key, value in state.items():
        value[n:] = value[n - 1]
        if value.dtype != bool:
            state[key] = value.astype(np.float32)
    state["tau_species"] = state["tau_species"] @ tables["species_matrix"]


def _compose_numba(exact, ends_on_ground, valid, rays, settings, tables, state, ray_class, n):
    """The outputs of :func:`_compose` for the first ``n`` rays of a chunk marched by the numba kernel: the ground's
    term (Eq. 35) in :func:`swim.rt.ground_cpu.ground_radiance` for chunks that have rays on the ground, the clouds'
    part and the sum in :func:`swim.rt.compose_cpu.compose_clouds` (no JAX call, no GIL). ``exact`` holds the rays'
    float64 start, direction and bounds as the march took them, ``ray_class`` the real rays' aerosol column class and
    float64 weight as the march took them, ``state`` the kernel's float64 outputs (its packed species, padding rows not
    yet written); numpy arrays."""
    from . import compose_cpu

    st = {key: value[:n] for key, value in state.items()}  # the real rays' float64 rows (views)
    surface = _ends_on_surface(st, ends_on_ground[:n])
    l_surface = np.zeros((n, 3), np.float32)
    if np.any(surface):
        from . import ground_cpu

        g = ground_cpu.ground_tables()
        cloud_mode = bool(tables["cloud_mode"])
        ground_cpu.ground_radiance(
            exact[0][:n], exact[1][:n], st["s_hit"], surface, rays["cos_view_zenith"][:n], st["tau_h"],
            st["tau_clear"], st["tau_species"], tables["species_index"], *ray_class, tables["p"], tables["coef"],
            tables["sky"],
            tables["diffuse_classes"], tables["n_class"], tables["surface"], tables["surface_outside"],
            tables["angstrom"], tables["backscatter_scaled"] if cloud_mode else tables["backscatter"],
            settings.surface == "lambertian", compose_cpu.COEFFICIENTS,
            g["coefficients"], g["rpv_q"], g["snow_table"], g["snow_albedo"], g["subsurface"], g["fade_cells"],
            cloud_mode, l_surface)
    if tables["cloud_mode"]:  # the hydrometeors' radiance was integrated along the ray (swim.rt.clouds)
        l_cloud = st["l_cloud"].astype(np.float32)
        radiance = (st["l_clear"] + st["l_cloud"] + l_surface).astype(np.float32)
        radiance[~np.asarray(valid[:n], bool)] = 0.0
        # the optical depth that dims the beam but for the forward peak's narrow part (the circumsolar aureole)
        tau_narrow = st["tau_species"] @ np.asarray(tables["hydro_aureole"], float)
        return {"radiance": radiance, "radiance_clear": st["l_clear"].astype(np.float32), "radiance_cloud": l_cloud,
                "radiance_surface": l_surface, "tau_hydrometeor": st["tau_h"].astype(np.float32),
                "tau_clear": st["tau_clear"].astype(np.float32), "surface": surface,
                "distance": np.where(surface, st["s_hit"], np.nan).astype(np.float32),
                "tau_narrow": tau_narrow.astype(np.float32)}
    radiance, l_cloud = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)
    compose_cpu.compose_clouds(st["tau_h"], st["tau_species"], tables["species_index"], st["i_nogas"], st["i_gas"],
                               st["i_cloud_t"], st["l_clear"], l_surface, np.array(valid[:n]), rays["cos_theta"][:n],
                               rays["cos_view_zenith"][:n], tables["p"][compose_cpu.P_MU0], compose_cpu.G_LIQUID_ARRAY,
                               compose_cpu.BACKSCATTER_ARRAY, compose_cpu.COEFFICIENTS, compose_cpu.LOBES, radiance,
                               l_cloud)
    return {"radiance": radiance, "radiance_clear": st["l_clear"].astype(np.float32), "radiance_cloud": l_cloud,
            "radiance_surface": l_surface, "tau_hydrometeor": st["tau_h"].astype(np.float32),
            "tau_clear": st["tau_clear"].astype(np.float32), "surface": surface,
            "distance": np.where(surface, st["s_hit"], np.nan).astype(np.float32)}
