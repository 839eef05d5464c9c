"""Reproduce the GHI validation of docs/irradiance.md: figure, tables and numbers.

Usage (from the repository root; needs ../shared/data/obs and matplotlib; ~6 min on 2 cores)::

    python scripts/make_ghi_validation.py [--out docs/irradiance] [--step 15min] [--table]

Writes ``surfrad_alamosa_2016-01-01.png`` (simulated vs observed GHI/DNI/DHI over the day), ``validation.json``
(every number quoted in docs/irradiance.md; with ``--table`` also the simulated day as CSV) and prints the
markdown tables. Deterministic: the renders,
pvlib's models and the SURFRAD file fix every number (no random sampling anywhere).
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
SHARED = (ROOT / ".." / "shared" / "data" / "obs").resolve()
AOD_550 = 0.03
OZONE = 0.30
ZENITHS = [0.0, 20.0, 40.0, 60.0, 70.0, 80.0, 85.0]


def closure_table():
    """Residual error of the conversion fed SPCTRL2's own three channels (as the unit test)."""
    import pvlib
    from pvlib.spectrum import spectrl2

    from swim.diagnostics.broadband import ReferenceSpectrum, broadband_irradiance, spectrl2_wavelengths

    wl = spectrl2_wavelengths()
    w = np.zeros_like(wl)
    w[:-1] += np.diff(wl) / 2
    w[1:] += np.diff(wl) / 2
    ch = np.array([615.0, 546.0, 450.0])
    out = {}
    for label, truth in (("same aerosol", {}), ("other aerosol (g 0.75, ssa 0.90 flat)",
                                                dict(aerosol_asymmetry_factor=0.75, scattering_albedo_400nm=0.90,
                                                     wavelength_variation_factor=0.0))):
        rows = []
        for z, p, pw, aod, alpha, alb in itertools.product((0.0, 30.0, 60.0, 75.0, 85.0), (101_325.0, 77_000.0),
                                                           (0.3, 1.5, 4.0), (0.02, 0.1, 0.3), (1.4, 0.5), (0.2, 0.8)):
            am = pvlib.atmosphere.get_relative_airmass(z, "kastenyoung1989")
            common = dict(apparent_zenith=z, aoi=z, surface_tilt=0.0, ground_albedo=alb, surface_pressure=p,
                          relative_airmass=am, aerosol_turbidity_500nm=aod, dayofyear=172, alpha=alpha, **truth)
            free = spectrl2(precipitable_water=0.0, ozone=0.0, **common)
            gas = spectrl2(precipitable_water=pw, ozone=0.3, **common)
            ex = free["dni_extra"][:, 0]
            spec = ReferenceSpectrum(wl, w, ex, 1.0, "spectrl2")
            at = lambda x: np.exp(np.interp(ch, wl, np.log(x)))  # noqa: E731
            res = broadband_irradiance(at(free["dni"][:, 0] / ex), at(free["dhi"][:, 0] / ex), z, pressure_pa=p,
                                       precipitable_water_cm=pw, ozone_atm_cm=0.3, surface_albedo=alb, spectrum=spec,
                                       solar_constant_w_m2=1.0)
            dni, dhi = np.sum(w * gas["dni"][:, 0]), np.sum(w * gas["dhi"][:, 0])
            ghi = dhi + np.cos(np.radians(z)) * dni
            rows.append((z, aod, 100 * (res["dni"] / dni - 1), 100 * (res["dhi"] / dhi - 1), 100 * (res["ghi"] / ghi - 1)))
        r = np.array(rows)
        sel = {"all": np.ones(len(r), bool), "zenith<=75": r[:, 0] <= 75,
               "zenith<=75, AOD500<=0.1": (r[:, 0] <= 75) & (r[:, 1] <= 0.1)}
        out[label] = {k: {"max_abs_dni_pct": float(np.abs(r[m, 2]).max()), "max_abs_dhi_pct": float(np.abs(r[m, 3]).max()),
                          "max_abs_ghi_pct": float(np.abs(r[m, 4]).max()), "mean_ghi_pct": float(r[m, 4].mean())}
                      for k, m in sel.items()}
    return out


def smarts_check():
    """Conversion of the ASTM G173 reference atmosphere's direct beam against its SMARTS direct spectrum."""
    from swim.diagnostics.broadband import (ASTM_G173_TSI_W_M2, broadband_irradiance, rayleigh_optical_depth,
                                            relative_airmass)

    ch = np.array([615.0, 546.0, 450.0])
    z = 48.236
    aod = np.where(ch < 500, 0.084 * (ch / 500) ** -0.9329, 0.084 * (ch / 500) ** -1.3853)
    t = np.exp(-relative_airmass(z) * (rayleigh_optical_depth(ch, 101_325.0) + aod))
    res = broadband_irradiance(t, np.full(3, 0.05), z, pressure_pa=101_325.0, precipitable_water_cm=1.4164,
                               ozone_atm_cm=0.3438, solar_constant_w_m2=ASTM_G173_TSI_W_M2)
    table = pd.read_csv(SHARED / "ASTMG173.csv", skiprows=1)
    smarts = float(np.trapezoid(table["direct"], table["wavelength"]))
    return {"swim_dni": float(res["dni"]), "smarts_direct_circumsolar": smarts,
            "difference_pct": 100 * (float(res["dni"]) / smarts - 1)}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "irradiance")
    parser.add_argument("--step", default="15min")
    parser.add_argument("--table", action="store_true", help="also write the simulated day as CSV")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    from swim.diagnostics.ghi import matplotlib_pyplot

    try:
        matplotlib_pyplot()
    except ImportError as exc:
        sys.exit(f"make_ghi_validation.py: {exc}")
    from swim.diagnostics.ghi import (aerosol_for_site, attach_observations, clear_site_scene, error_statistics,
                                      ghi_at_sun_zeniths, ghi_time_series, plot_ghi, pvlib_clear_sky, site_aod_550,
                                      time_range, write_csv)
    from swim.io.observations import clear_periods, observations_at, observed_albedo, observed_precipitable_water
    from swim.io.surfrad import read_surfrad

    t0 = time.time()
    obs = read_surfrad(SHARED / "surfrad-slv16001.dat")
    lat, lon, elev = obs.attrs["latitude"], obs.attrs["longitude"], obs.attrs["elevation_m"]
    pw, albedo = observed_precipitable_water(obs), observed_albedo(obs)
    clear = clear_periods(obs)
    scene = clear_site_scene(lat, lon, elev, surface_albedo=albedo)
    numbers = {"site": {"lat": lat, "lon": lon, "elevation_m": elev, "precipitable_water_cm": pw, "albedo": albedo,
                        "ozone_atm_cm": OZONE, "aod_550_site": AOD_550, "aerosol_type": "continental",
                        "clear_minutes_zenith_lt_85": int(clear.sum())}}

    def day_run(aod, step, band=None):
        aer = aerosol_for_site(aod, elev + 2.0, "continental")
        sim = ghi_time_series(scene, lat, lon, time_range("2016-01-01T14:30Z", "2016-01-02T00:00Z", step), aerosol=aer,
                              precipitable_water_cm=pw, ozone_atm_cm=OZONE, band_nm=band)
        sim = attach_observations(sim, observations_at(obs, sim.index, clear=clear))
        ref = pvlib_clear_sky(sim["sun_zenith_deg"], elevation_m=sim.attrs["observer_height_asl_m"],
                              aod_550=site_aod_550(aer, sim.attrs["observer_height_asl_m"]),
                              angstrom_exponent=aer.type.angstrom_exponent, precipitable_water_cm=pw, ozone_atm_cm=OZONE,
                              pressure_pa=sim.attrs["pressure_pa"], earth_sun_distance_au=sim["earth_sun_distance_au"],
                              surface_albedo=albedo)
        mask = sim["clear"].values & sim["rendered"].values
        stats = {c: error_statistics(sim[c], sim[f"{c}_obs"], mask) for c in ("ghi", "dni", "dhi")}
        stats["ghi_546_proxy"] = error_statistics(sim["ghi_546_proxy"], sim["ghi_obs"], mask)
        for model in ("bird", "ineichen", "solis", "spectrl2"):
            stats[f"{model}_ghi_vs_obs"] = error_statistics(ref[f"{model}_ghi"], sim["ghi_obs"], mask)
        # DNI ratio observed / swim against air mass: flat means a multiplicative (calibration-like) offset
        m = 1.0 / np.cos(np.radians(sim["sun_zenith_deg"].values[mask]))
        ratio = sim["dni_obs"].values[mask] / sim["dni"].values[mask]
        slope, intercept = np.polyfit(m, np.log(ratio), 1)
        stats["dni_obs_over_swim"] = {"at_airmass_0": float(np.exp(intercept)), "dlog_per_airmass": float(slope),
                                      "min": float(ratio.min()), "max": float(ratio.max())}
        return sim, ref, stats

    sim, ref, stats = day_run(AOD_550, args.step)
    numbers["surfrad"] = {f"aod_{AOD_550}": stats}
    args.out.mkdir(parents=True, exist_ok=True)
    plot_ghi(sim, obs.loc["2016-01-01T14:00Z":"2016-01-02T00:10Z"], args.out / "surfrad_alamosa_2016-01-01.png",
             clear=clear.loc["2016-01-01T14:00Z":"2016-01-02T00:10Z"], reference=ref,
             title=f"SURFRAD Alamosa (2317 m), 2016-01-01: swim ({sim.attrs['size']} px all-sky, AOD$_{{550}}$ {AOD_550} "
                   f"continental, pw {pw:.2f} cm, O$_3$ {OZONE} atm-cm) vs observed\nclear instants: GHI MBE "
                   f"{stats['ghi']['mbe']:+.1f} W m$^{{-2}}$ ({stats['ghi']['mbe_pct']:+.1f} %), RMSE "
                   f"{stats['ghi']['rmse']:.1f} W m$^{{-2}}$ ({stats['ghi']['rmse_pct']:.1f} %)")
    if args.table:
        write_csv(sim, args.out / "surfrad_alamosa_2016-01-01.csv")
    for aod in (0.01, 0.05):
        numbers["surfrad"][f"aod_{aod}"] = day_run(aod, "30min")[2]
    numbers["surfrad"]["aod_0.03_band_285_2800"] = day_run(AOD_550, "30min", band=(285.0, 2800.0))[2]

    zen_tables = {}
    for aod in (0.03, 0.1):
        aer = aerosol_for_site(aod, elev + 2.0, "continental")
        z = ghi_at_sun_zeniths(scene, lat, lon, ZENITHS, aerosol=aer, precipitable_water_cm=pw, ozone_atm_cm=OZONE)
        r = pvlib_clear_sky(z["sun_zenith_deg"], elevation_m=z.attrs["observer_height_asl_m"], aod_550=aod,
                            angstrom_exponent=aer.type.angstrom_exponent, precipitable_water_cm=pw, ozone_atm_cm=OZONE,
                            pressure_pa=z.attrs["pressure_pa"], surface_albedo=albedo)
        rows = {}
        for zen in ZENITHS:
            row = {"swim_ghi": float(z.loc[zen, "ghi"]), "swim_dni": float(z.loc[zen, "dni"]), "swim_dhi": float(z.loc[zen, "dhi"])}
            for model in ("bird", "ineichen", "solis", "spectrl2"):
                row[f"{model}_ghi"] = float(r.loc[zen, f"{model}_ghi"])
                row[f"vs_{model}_pct"] = 100 * (row["swim_ghi"] / row[f"{model}_ghi"] - 1)
            rows[str(zen)] = row
        zen_tables[f"aod_{aod}"] = rows
    numbers["clear_sky_vs_models"] = zen_tables
    numbers["conversion_closure_spectrl2"] = closure_table()
    numbers["conversion_vs_smarts_g173"] = smarts_check()
    numbers["runtime_s"] = time.time() - t0
    (args.out / "validation.json").write_text(json.dumps(numbers, indent=1, default=float))

    print("| zenith | swim GHI | Bird | Ineichen | Solis | SPCTRL2 |")
    print("|---|---|---|---|---|---|")
    for key, rows in zen_tables.items():
        print(f"| {key} | | | | | |")
        for zen, row in rows.items():
            print(f"| {float(zen):.0f} | {row['swim_ghi']:.1f} | {row['vs_bird_pct']:+.1f} % | {row['vs_ineichen_pct']:+.1f} % | "
                  f"{row['vs_solis_pct']:+.1f} % | {row['vs_spectrl2_pct']:+.1f} % |")
    print()
    print("| run | n | GHI MBE | GHI RMSE | DNI MBE | DHI MBE | 546 nm proxy MBE |")
    print("|---|---|---|---|---|---|---|")
    for key, s in numbers["surfrad"].items():
        print(f"| {key} | {s['ghi']['n']} | {s['ghi']['mbe']:+.1f} W m-2 ({s['ghi']['mbe_pct']:+.1f} %) | "
              f"{s['ghi']['rmse']:.1f} W m-2 ({s['ghi']['rmse_pct']:.1f} %) | {s['dni']['mbe_pct']:+.1f} % | "
              f"{s['dhi']['mbe_pct']:+.1f} % | {s['ghi_546_proxy']['mbe_pct']:+.1f} % |")
    print(json.dumps({k: numbers[k] for k in ("conversion_closure_spectrl2", "conversion_vs_smarts_g173")}, indent=1))
    print(f"done in {numbers['runtime_s']:.0f} s")


if __name__ == "__main__":
    main()
