"""A new sun's Step 1a made on the host and on the device, field by field, and the step classes each gives.

Usage::

    python benchmarks/step1a_paths.py                              # the suite's synthetic 400 x 400 x 60 scene
    python benchmarks/step1a_paths.py --grid 200 --sun 30.5 136 --sun 60 250

For each sun (zenith, azimuth [deg], azimuth clockwise from north) it makes Step 1a's fields (Albers et al. 2020,
doi:10.5194/amt-13-3235-2020, Sect. 3.4, Eqs. 4-8: T, the terrain's shadow and the 3-D aerosol's optical depth
towards the sun) twice from the same optical volume:

* on the host, as a render on a CPU does (:func:`swim.rt.solar.solar_transmittance`, numba's sweep by default);
* from the device's copy of the packed volume (:func:`swim.rt.solar_device.solar_transmittance_on_device`, JAX's
  sweep on JAX's default device), as a render on a GPU does (``ExecutionSettings.step1a_on_device``).

It prints, per field, the largest difference and how many cells differ, and how many cells change their step class
(:func:`swim.rt.march_inputs.step_classes`: sunlit clear air where the direct sun's transmittance is at least
``SUNLIT_TRANSMITTANCE`` around a cell). The two paths round in another order (float32), so T differs by ~1e-5 in
some cells; a class is a threshold on T, so a few cells near it may flip, and a ray that crosses one places its grid
steps otherwise (docs/decisions/0007-scene-set-up.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--grid", type=int, default=400, help="columns per axis of the synthetic scene (60 levels, 1 km)")
    ap.add_argument("--sun", type=float, nargs=2, action="append", metavar=("ZENITH", "AZIMUTH"),
                    help="a sun [deg] (repeatable; default four suns)")
    ap.add_argument("--host-backend", choices=("numba", "jax"), default="numba", help="the host's sweep")
    args = ap.parse_args(argv)

    import jax
    import jax.numpy as jnp
    import numpy as np

    from scenes import synthetic_scene
    from swim.frames import enu_from_azimuth_zenith
    from swim.io.scene import validate_scene
    from swim.optics.volume import build_optical_volume
    from swim.rt import solar_device
    from swim.rt.march_inputs import (KERNEL_STEP1A_VARIABLES, occupancy_grid, pack_volume, packed_species,
                                      share_packed_channels, step_classes)
    from swim.rt.solar import solar_transmittance, step1a_levels

    volume = build_optical_volume(validate_scene(synthetic_scene(nx=args.grid, ny=args.grid)))
    species = packed_species(volume)
    packed = pack_volume(volume, species)
    share_packed_channels(volume, packed, species)
    occupancy = occupancy_grid(volume)
    print(f"device {jax.devices()[0]}, host sweep {args.host_backend}, volume {packed.shape[:-1]}")
    print("| sun zenith, azimuth [deg] | field | largest difference | cells differing | step classes flipped |")
    print("|---|---|---|---|---|")
    for zenith, azimuth in args.sun or [(30.5, 136.0), (31.5, 138.0), (20.0, 100.0), (60.0, 250.0)]:
        sun = enu_from_azimuth_zenith(azimuth, zenith)
        host = solar_transmittance(volume, sun, variables=KERNEL_STEP1A_VARIABLES, backend=args.host_backend)
        host = {name: host[name].values.copy() for name in KERNEL_STEP1A_VARIABLES}
        device_copy = jnp.asarray(np.where(np.isfinite(packed), packed, 0.0))
        got, _ = solar_device.solar_transmittance_on_device(volume, sun, device_copy, packed, species,
                                                            step1a_levels(volume))
        got = {name: got[name].values.copy() for name in KERNEL_STEP1A_VARIABLES}
        flipped = int(np.count_nonzero(step_classes(occupancy, host) != step_classes(occupancy, got)))
        for name in KERNEL_STEP1A_VARIABLES:
            apart = np.abs(host[name].astype(np.float64) - got[name])
            print(f"| {zenith:g}, {azimuth:g} | {name} | {apart.max():.2e} | {np.count_nonzero(apart):,} of "
                  f"{apart.size:,} | {flipped} |", flush=True)


if __name__ == "__main__":
    main()
