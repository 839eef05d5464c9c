"""Make the liquid-water Mie phase-function table shipped in ``src/swim/data/mie_liquid_phase.npz``.

Bulk phase functions of droplets with a gamma size distribution (Hansen and Travis 1974, doi:10.1007/BF00168069:
n(r) ~ r^((1 - 3 v_e) / v_e) exp(-r / (r_e v_e)), effective variance v_e = 0.1) for effective radii 2-40 um at
swim's wavelengths 615, 546 and 450 nm, from Mie theory (``miepython``; Wiscombe 1980's algorithm), with the
refractive index of water of Hale and Querry (1973), doi:10.1364/AO.12.000555 (real part; the imaginary part,
~1e-9 in the visible, makes the single-scattering albedo 1 - 1e-5 and is neglected).

Run once (a few minutes on 2 cores); the table is loaded by :mod:`swim.optics.cloud_phase`.

    python scripts/make_mie_tables.py
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

WAVELENGTHS_NM = (615.0, 546.0, 450.0)
REFRACTIVE_INDEX = {615.0: 1.332, 546.0: 1.334, 450.0: 1.337}
EFFECTIVE_RADII_UM = (2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 10.0, 12.0, 14.0, 17.0, 20.0, 25.0, 30.0, 40.0)
EFFECTIVE_VARIANCE = 0.1
OUT = Path(__file__).resolve().parents[1] / "src" / "swim" / "data" / "mie_liquid_phase.npz"


def angles_deg():
    """Scattering angles: fine in the diffraction peak, 0.25 deg elsewhere."""
    return np.unique(np.concatenate([np.arange(0.0, 2.0, 0.01), np.arange(2.0, 10.0, 0.05),
                                     np.arange(10.0, 180.0, 0.25), [180.0]]))


def main():
    import miepython

    theta = angles_deg()
    mu = np.cos(np.radians(theta))
    radii = np.geomspace(0.3, 160.0, 700)  # [um]
    table = np.zeros((len(EFFECTIVE_RADII_UM), len(WAVELENGTHS_NM), theta.size))
    q_ext = np.zeros((len(EFFECTIVE_RADII_UM), len(WAVELENGTHS_NM)))
    t0 = time.time()
    for c, wl in enumerate(WAVELENGTHS_NM):
        k = 2 * np.pi / (wl * 1e-3)  # [um-1]
        m = REFRACTIVE_INDEX[wl]
        intensity = np.empty((radii.size, theta.size))  # dsigma/dOmega [um2 sr-1] per droplet
        c_ext = np.empty(radii.size)
        for n, r in enumerate(radii):
            x = k * r
            s1, s2 = miepython.S1_S2(m, x, mu, norm="bohren")
            intensity[n] = 0.5 * (np.abs(s1) ** 2 + np.abs(s2) ** 2) / k**2
            qext, _, _, _ = miepython.efficiencies_mx(m, x)[:4]
            c_ext[n] = qext * np.pi * r**2
        for e, re in enumerate(EFFECTIVE_RADII_UM):
            v = EFFECTIVE_VARIANCE
            a = (1 - 3 * v) / v
            w = np.exp(a * np.log(radii) - radii / (re * v))
            w *= np.gradient(radii)
            bulk = w @ intensity
            # normalised to mean 1 over the sphere: (1/2) int P dmu = 1 (trapezoid in mu on the table's angles)
            norm = 0.5 * np.trapezoid(bulk[::-1], mu[::-1])
            table[e, c] = bulk / norm
            q_ext[e, c] = (w @ c_ext) / (w @ (np.pi * radii**2))
        print(f"{wl} nm done ({time.time() - t0:.0f} s)", flush=True)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(OUT, theta_deg=theta.astype(np.float64), effective_radius_um=np.array(EFFECTIVE_RADII_UM),
                        wavelength_nm=np.array(WAVELENGTHS_NM), phase=table.astype(np.float32),
                        q_ext=q_ext.astype(np.float32), effective_variance=np.float64(EFFECTIVE_VARIANCE))
    print(f"wrote {OUT} ({OUT.stat().st_size / 1e3:.0f} kB)")


if __name__ == "__main__":
    main()
