"""The kernel tables of a scene, sun and atmosphere (:class:`swim.rt.kernel_tables.KernelTables`), built through the
stage cache (:data:`swim.pipeline.caches.STATE`): the packed volume with Step 1a, the step classes, the ground's
fields, the clear air's tables and the 3-D cloud scattering's diffuse solution."""

from __future__ import annotations

import logging

import numpy as np

from ..memory import release_free_memory
from ..rt.clouds import cloud_constants, direct_weights, scene_cloud_optics
from ..rt.device_copies import keep_device_copies, kept_device_copies
from ..rt.diffuse_field import diffuse_field, solve_sun
from ..rt.gas import aerosol_column_classes, build_gas_tables
from ..rt.kernel_tables import KernelTables
from ..rt.march_inputs import (KERNEL_STEP1A_VARIABLES, aerosol_column_optical_depth, atmosphere_constants,
                               grid_geometry, occupancy_grid, pack_volume, packed_species, share_packed_channels,
                               shared_packed_volume, step1a_channel_views, volume_constants)
from ..rt.march_settings import MarchSettings
from ..rt.solar import solar_transmittance, step1a_levels
from .caches import STATE

log = logging.getLogger(__name__)


def atmosphere_inputs(volume):
    """What the clear-atmosphere tables take from the optical volume (:func:`swim.rt.gas.build_gas_tables`): the
    scene-mean surface albedo (3,), which reflects light back into the sky in the multiple-scattering table; the
    mean column of a 3-D aerosol field, (heights [m], extinction [1/m]) or None, which joins the background aerosol
    there; and for a non-uniform field the classes of its column optical depth, one table each (Eqs. 30-31,
    docs/aerosols.md §8), or None. Kept with the volume in the stage cache: a warm render of a small image spent
    ~0.5 ms on these means."""
    albedo = volume["surface_albedo"]
    mean_albedo = np.asarray(albedo.mean(dim=[d for d in albedo.dims if d != "wavelength"]).values, dtype=float)
    aer3d = volume["aerosol_extinction"].values.mean(axis=(1, 2), dtype=float)
    if not np.any(aer3d > 0):
        return mean_albedo, None, None
    levels = float(volume.attrs["z_bottom"]) + float(volume.attrs["dz"]) * np.arange(aer3d.size)
    return mean_albedo, (levels, aer3d), aerosol_column_classes(aerosol_column_optical_depth(volume).values)



def grid_constants(volume, fingerprint, settings: MarchSettings, sun_scene, cloud_optics) -> dict:
    """The kernel constants of the scene's grid for one sun (:func:`swim.rt.march_inputs.volume_constants`): the
    packed volume with Step 1a's channels for the sun ``sun_scene`` (3,), the step classes, the ground's fields. The
    packing, the species packed, Step 1a's levels and the occupancy depend on the volume alone and are kept in the
    stage cache under ``fingerprint``; a new sun refills the packed volume in place where this render is the only one
    (on the device's copy with ``ExecutionSettings.step1a_on_device``). ``cloud_optics``: the 3-D cloud scattering's, or
    None."""
    # The grid is packed first and the volume's extinctions become views of the packed channels, so the
    # grid is held once before Step 1a's fields are made (docs/performance.md, "Memory"); species that are zero
    # everywhere are not packed (a march through fewer channels reads fewer cache lines,
    # docs/decisions/0007-scene-set-up.md) the species packed and Step 1a's levels with extinction depend on the
    # volume alone: a new sun (a time series' frame) reuses them (their scans read every species' extinction: ~0.1
    # and ~0.2 s for the 400 x 400 x 60 scene on this project's 2 cores, docs/decisions/0006-gpu-kernels.md)
    species = STATE.stages.get(("packed species", fingerprint), lambda: packed_species(volume))
    # before the packing, which makes the extinctions strided views: the scan of a new scene's contiguous
    # arrays took 84-90 ms against 440-490 ms through the views (400 x 400 x 60, docs/decisions/0006-gpu-kernels.md)
    nonzero_levels = STATE.stages.get(("step 1a levels", fingerprint), lambda: step1a_levels(volume))
    # A new sun refills the packed volume's Step 1a channels in place (the grid's channels are the same), where
    # this render is the only one in the process: beside others (a dask worker's threads) one of them may still
    # march through that volume with its own sun, and this one packs the grid anew
    packed = shared_packed_volume(volume, species) if STATE.rendering_alone() else None
    # the step classes (march.step_classes) of a new sun are written over the last sun's where the packed volume
    # is refilled in place too (the same arrays then keep their device copies' places)
    classes = None
    if packed is None:
        packed = pack_volume(volume, species)
        share_packed_channels(volume, packed, species)
    else:
        classes = STATE.stages.peek(("step classes", fingerprint))
    # the occupancy grid depends on the volume alone: a new sun (a time series' frame) reuses it
    occupancy = STATE.stages.get(("occupancy", fingerprint), lambda: occupancy_grid(volume))
    if classes is None:
        # kept also beside other renders: the next render alone reuses this render's packed volume, and with its
        # classes it finds the device copies that this render made (only a render alone writes them in place)
        classes = STATE.stages.put(("step classes", fingerprint), np.zeros(occupancy.shape, np.int8))
    # ExecutionSettings.step1a_on_device: a new sun on the device's copy of this packed volume, which an earlier
    # sun's render of the JAX kernel left there (swim.rt.solar_device): no sums, sweep input or volume sent
    kept = (kept_device_copies({"volume": packed, "occupancy": classes})
            if settings.resolved_step1a_on_device() else None)
    if kept is not None:
        from ..rt.solar_device import solar_transmittance_on_device

        transmittance, device_packed = solar_transmittance_on_device(volume, sun_scene, kept["volume"], packed,
                                                                     species, nonzero_levels)
        del kept["volume"]  # (donated to the new copy on a GPU)
    else:
        # Step 1a, only the fields that the kernel constants read, written straight into the packed volume's
        # channels: no field of its own (~100 MB each at 400 x 400 x 160) and no copy
        # (docs/decisions/0007-scene-set-up.md) (the 3-D cloud scattering: the direct beam's delta-M scaled
        # transmittance in place of T)
        transmittance = solar_transmittance(volume, sun_scene, variables=KERNEL_STEP1A_VARIABLES,
                                            backend=settings.execution.backend, nonzero_levels=nonzero_levels,
                                            out=step1a_channel_views(packed, species),
                                            direct_weights=(None if cloud_optics is None
                                                            else direct_weights(volume, cloud_optics)))
    constants = volume_constants(volume, transmittance, occupancy=occupancy, packed=packed, species=species,
                                 classes=classes)
    if kept is not None:  # the device's new copy is the one the JAX kernel takes (swim.rt.device_copies.device_copies);
        # the step classes of this sun are sent (25.6 MB for 400 x 400 x 160)
        import jax

        keep_device_copies({"volume": constants["volume"], "occupancy": constants["occupancy"]},
                           {"volume": device_packed, "occupancy": jax.device_put(constants["occupancy"])})
        del device_packed
    del transmittance
    if not settings.on_accelerator():
        # Step 1a's freed levels, before the ray march; not where the march runs on a GPU, whose host has the
        # memory to spare: there the trim took 0.06 s of a new sun's 0.58 s frame on an H100 machine's 16
        # cores (docs/decisions/0006-gpu-kernels.md)
        release_free_memory()
    return constants



def kernel_tables(volume, fingerprint, aerosol, settings: MarchSettings, sun_scene) -> KernelTables:
    """The kernel tables of the scene's optical ``volume`` (digest ``fingerprint``) for the sun ``sun_scene`` (3,),
    the background ``aerosol`` and ``settings``' cloud scattering, through the stage cache: a new sun (a time
    series' frame) redoes Step 1a and the diffuse solution, a new aerosol only the clear air's tables."""
    mean_albedo, aerosol_profile, classes = STATE.stages.get(("atmosphere inputs", fingerprint),
                                                             lambda: atmosphere_inputs(volume))
    gas = build_gas_tables(aerosol, surface_albedo=mean_albedo, scene_aerosol_profile=aerosol_profile,
                           aerosol_class_aod=classes)
    clouds = settings.cloud_scattering
    cloud_optics = (STATE.stages.get(("cloud optics", fingerprint, clouds), lambda: scene_cloud_optics(volume, clouds))
                    if clouds.three_d else None)
    cloud_key = clouds if clouds.three_d else None
    sun_key = tuple(np.round(sun_scene, 12))

    def build():
        grid = STATE.stages.get(("grid constants", fingerprint, sun_key, cloud_key),
                                lambda: grid_constants(volume, fingerprint, settings, sun_scene, cloud_optics))
        clouds_3d = (_cloud_constants(volume, fingerprint, grid, gas, sun_scene, cloud_optics, clouds)
                     if cloud_optics is not None else {})
        return {**grid, **atmosphere_constants(gas, sun_scene), **clouds_3d}, gas

    # The entry holds the gas tables, so their id cannot be reused by other tables while it lives. The grid's
    # constants are looked up inside its build, after the old entry has gone: a new sun never holds two volumes.
    with STATE.grid_tables_lock:
        constants, _ = STATE.stages.get(("constants", fingerprint, sun_key, id(gas), cloud_key), build)
    return KernelTables(constants, grid_geometry(volume), gas, aerosol, sun_scene, cloud_optics)


def _cloud_constants(volume, fingerprint, grid, gas, sun_scene, cloud_optics, clouds) -> dict:
    """The 3-D cloud scattering's tables (:func:`swim.rt.clouds.cloud_constants`) with its diffuse solution, solved
    for the node of the grid of suns nearest this sun and kept while the sun stays near it: the frames of a series
    share it (:func:`swim.rt.diffuse_field.solve_sun`)."""
    species = tuple(STATE.stages.peek(("packed species", fingerprint)))
    node = solve_sun(sun_scene, clouds.diffuse.sun_step_deg)
    key = ("diffuse field", fingerprint, tuple(np.round(node, 12)), id(gas), clouds)
    solved = STATE.stages.get_small(key, lambda: diffuse_field(volume, species, gas, node, cloud_optics,
                                                               clouds.diffuse), named=gas)
    return cloud_constants(grid, species, sun_scene, cloud_optics, solved)
