"""Physical constants and the SWIm reference parameters, in SI units.

Sources: Albers et al. (2020), Atmos. Meas. Tech. 13, 3235-3261, doi:10.5194/amt-13-3235-2020
(referred to as "the paper"); Bodhaine et al. (1999), J. Atmos. Oceanic Technol. 16, 1854-1861.
"""

from __future__ import annotations

import numpy as np

#: The three SWIm reference wavelengths (red, green, blue) [nm] (paper, Sect. 3).
WAVELENGTHS_NM = np.array([615.0, 546.0, 450.0])
#: Same in metres.
WAVELENGTHS_M = WAVELENGTHS_NM * 1e-9

#: Mean earth radius of the spherical earth used everywhere [m].
EARTH_RADIUS_M = 6_371_000.0
#: Top of the model atmosphere for the clear-sky step (Step 2) [m] (paper, Sect. 3.3).
ATMOSPHERE_TOP_M = 100_000.0
#: Row of the kernels' clear-air height table (``beta_gas``: the Rayleigh, background and stratospheric aerosol
#: profiles in rows 0-2) that holds ozone's absorption profile (a pure absorber: extinction, no scattering;
#: :mod:`swim.optics.ozone`).
GAS_OZONE_ROW = 3
#: Row of the kernels' clear-air height table (after its :data:`GAS_OZONE_ROW` + 1 extinction profiles) that holds
#: the fraction of the vertical optical depth at 546 nm of the scattering components (rows 0-2) above each height
#: (:func:`swim.rt.march_inputs.gas_column_above`).
GAS_COLUMN_ROW = 4
#: First node of the sun axis of the clear-sky diffuse-source tables (:mod:`swim.rt.multiple_scattering`), in the
#: coordinate t = sign(mu_s) sqrt(|mu_s|) [-]: -7/11, the sun 23.9 deg below the horizon, past the end of astronomical
#: twilight (18 deg). With the default 19 nodes up to t = 1 the spacing is 1/11 and one node lies on the horizon.
DIFFUSE_SUN_T_MIN = -7.0 / 11.0
#: Least clear-air steps after the grid of a ray that rises out of it (:func:`swim.rt.march_jax.after_step_counts`).
AFTER_MIN_STEPS = 4
#: Points per ray [-] at which a grid segment's length in cells is measured (:func:`swim.rt.march_jax.segment_cells`):
#: the middles of equal intervals. A straight path in grid indices measures the same from any two; the horizon's
#: rays, whose height index bends over the Earth's curvature, measure a little less from fewer: from 16 rather than
#: 64 at most 0.3 % less on the synthetic 400 x 400 x 60 all-sky (0.5 % of its rays one probe fewer) and 1 % on
#: Katrina's (docs/decisions/0003-cpu-kernel-code.md). At most ``swim.rt.march_cpu.PROBE_BLOCK`` (one block of probes).
CELL_PROBES = 16
#: Total solar irradiance at 1 AU [W m-2] (paper, Sect. 3.1).
SOLAR_CONSTANT_W_M2 = 1362.0
#: Extraterrestrial solar spectral irradiance E_TOA [W m-2 nm-1] at 1 AU at :data:`WAVELENGTHS_NM` (615, 546, 450 nm):
#: the ASTM G173-03 spectrum scaled to :data:`SOLAR_CONSTANT_W_M2`
#: (:func:`swim.diagnostics.broadband.channel_solar_irradiance`, which a test holds these to). Absolute radiance
#: L = L' E_TOA / (4 pi r^2) [W m-2 sr-1 nm-1], r the earth-sun distance [AU].
SOLAR_SPECTRAL_IRRADIANCE_W_M2_NM = np.array([1.6995, 1.8518, 1.9846])
#: Angular radius of the solar disk seen from 1 AU [rad].
SUN_ANGULAR_RADIUS_RAD = np.deg2rad(0.2665)
#: Standard gravity [m s-2].
STANDARD_GRAVITY = 9.80665
#: Specific gas constant of dry air [J kg-1 K-1].
R_DRY_AIR = 287.05
#: Ratio of the gas constants of dry air and water vapour (R_d / R_v) [-].
EPSILON_WATER_VAPOUR = 0.622
#: Reference pressure of the potential temperature [Pa].
P0_POTENTIAL_TEMPERATURE = 100_000.0
#: Poisson exponent R_d / c_p for dry air [-].
KAPPA_DRY_AIR = 0.2857

#: Hydrometeor species of the canonical scene, in the order used by the ray-tracing kernels.
SPECIES = ("cloud_liquid", "cloud_ice", "rain", "snow", "graupel")

#: Backscatter fraction b per species for Eqs. 4-6 and 24 (paper, Sect. 3.4 and 3.4.3; graupel 0.30
#: "anticipated" in Sect. 3.4.3; aerosol 0.125 in Sect. 3.4).
BACKSCATTER_FRACTION = {
    "cloud_liquid": 0.063,
    "cloud_ice": 0.14,
    "rain": 0.063,
    "snow": 0.14,
    "graupel": 0.30,
    "aerosol": 0.125,
}

#: Bulk density of the hydrometeor material r_h in Eq. 7 [kg m-3]. Snow and graupel are low-density
#: aggregates / rimed particles; the values are those commonly assumed by bulk microphysics schemes
#: (e.g. Thompson et al. 2008: snow 100, graupel 500 kg m-3).
HYDROMETEOR_DENSITY = {
    "cloud_liquid": 1000.0,
    "cloud_ice": 917.0,
    "rain": 1000.0,
    "snow": 100.0,
    "graupel": 500.0,
}

#: Default effective radii [m] where the scene gives none (cloud liquid rises with content,
#: see :func:`swim.optics.hydrometeors.effective_radius_liquid_martin1994`).
DEFAULT_EFFECTIVE_RADIUS = {
    "cloud_liquid": 10e-6,
    "cloud_ice": 34e-6,
    "rain": 750e-6,
    "snow": 4e-3,
    "graupel": 10e-3,
}

#: Default background aerosol: optical depth at 550 nm, scale height [m] and type
#: (docs/aerosols.md).
DEFAULT_AEROSOL = {
    "aod_550": 0.05,
    "scale_height_m": 1500.0,
    "type": "continental",
}
