"""The light of the night sky: airglow, zodiacal light, integrated starlight and the bright stars, as spectral
radiance at the ground in the renderer's three channels (615, 546, 450 nm) and in its solar-relative units.

Every component is emitted or lit above the atmosphere (the airglow at 87-250 km) and is attenuated on its way down
by the clear atmosphere's vertical optical depth above the observer, tau_v (Rayleigh, Bodhaine et al. 1999, scaled
with the pressure; the background aerosol; ozone's Chappuis band, swim.optics.ozone), times an air mass: Kasten &
Young's (1989) for a star, the van Rhijn factor for the diffuse light (:func:`background_radiance`); and by the
hydrometeors on the line of sight (swim.pipeline.night_sky). Light scattered into the line of sight enters only
through the diffuse light's air mass; the clouds' own glow is the diffuse transmittance of swim.pipeline.night_sky.

Channels. The renderer's three values stand for the red, green and blue parts of the visible spectrum; a line
emission of I rayleigh at wavelength lambda is put into the channel whose band (:data:`CHANNEL_BANDS_NM`, split
half-way between the channel wavelengths, 400-700 nm) holds it, as the band-mean spectral radiance

    L = I 1e10 / (4 pi) [photons s-1 m-2 sr-1] x h c / lambda [J] / (band width) [nm],

and an emission spread over a band (a pseudo-continuum, the OH Meinel bands) contributes the part of it that
overlaps each channel's band. The solar-relative radiance of Albers et al. (2020), Eq. 2, is L' = 4 pi L / E_TOA
with the extraterrestrial solar spectrum of :func:`swim.color.solar_irradiance_on_grid` (ASTM G173, scaled to
1362 W m-2) at the channel wavelengths, divided by the square of the earth-sun distance.

Magnitudes. Johnson V = 0 is 3.63e-11 W m-2 nm-1 at 550 nm (Bessell et al. 1998, Table A2); a surface brightness
of mu V mag arcsec-2 is L = 3.63e-11 10^(-0.4 mu) / (1 arcsec^2 in sr) [W m-2 sr-1 nm-1], read at 546 nm.

References
----------
Leinert, Ch. et al. (1998), The 1997 reference of diffuse night sky brightness, A&AS 127, 1-99,
doi:10.1051/aas:1998105. Noll, S. et al. (2012), An atmospheric radiation model for Cerro Paranal, A&A 543, A92,
doi:10.1051/0004-6361/201219040. van Rhijn, P. J. (1921), Publ. Astron. Lab. Groningen 31. Benn, C. R. & Ellison,
S. L. (1998), Brightness of the night sky over La Palma, New Astron. Rev. 42, 503-507. Bessell, M. S., Castelli, F.
& Plez, B. (1998), A&A 333, 231-250. Ballesteros, F. J. (2012), New insights into black bodies, EPL 97, 34008,
doi:10.1209/0295-5075/97/34008. Kasten, F. & Young, A. T. (1989), Appl. Opt. 28, 4735-4738,
doi:10.1364/AO.28.004735. Krisciunas, K. & Schaefer, B. E. (1991), A model of the brightness of moonlight, PASP 103,
1033-1039, doi:10.1086/132921. Garstang, R. H. (1989), Night-sky brightness at observatories and sites, PASP 101,
306-329, doi:10.1086/132436. Serdyuchenko, A. et al. (2014), Atmos. Meas. Tech. 7, 625-636, doi:10.5194/amt-7-625-2014.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..color._tables import SPECTRAL_GRID_NM, solar_irradiance_on_grid
from ..constants import EARTH_RADIUS_M, WAVELENGTHS_NM
from ..errors import SwimInputError
from ..optics.atmosphere import us_standard_atmosphere_1976
from ..optics.ozone import (DOBSON_UNIT_M2, US_STANDARD_OZONE_DU, ozone_column_du, ozone_cross_section,
                           ozone_number_density)
from ..optics.rayleigh import rayleigh_optical_depth_bodhaine1999

#: Spectral irradiance of a V = 0 star at 550 nm [W m-2 nm-1] (Bessell et al. 1998, Table A2: 3.63e-9 erg
#: cm-2 s-1 A-1).
V_ZERO_POINT_W_M2_NM = 3.63e-11
#: Wavelength at which the V magnitude fixes a star's spectrum [nm] (the V band's effective wavelength).
V_WAVELENGTH_NM = 550.0
#: One square arcsecond [sr].
ARCSEC2_SR = (np.pi / (180.0 * 3600.0)) ** 2
#: Photon radiance of one rayleigh [photons s-1 m-2 sr-1]: 10^10 / (4 pi) (Hunten et al. 1956).
RAYLEIGH_PHOTON_RADIANCE = 1e10 / (4.0 * np.pi)
#: Planck's constant [J s], the speed of light [m s-1] and Boltzmann's constant [J K-1].
PLANCK_H, LIGHT_C, BOLTZMANN_K = 6.62607015e-34, 2.99792458e8, 1.380649e-23
#: The spectral band [nm] each channel (615, 546, 450 nm) stands for: the visible 400-700 nm split half-way between
#: the channel wavelengths.
CHANNEL_BANDS_NM = ((580.5, 700.0), (498.0, 580.5), (400.0, 498.0))
#: Radiance of one S10 unit (one V = 10 solar-type star per square degree) at 550 nm [W m-2 sr-1 nm-1].
S10_RADIANCE = V_ZERO_POINT_W_M2_NM * 1e-4 / np.radians(1.0) ** 2
#: Zodiacal light [S10] at the middle ecliptic latitudes (about 45 deg) away from the sun and the gegenschein,
#: where a midnight zenith of the middle latitudes mostly looks (Leinert et al. 1998, Table 17: 60 S10 at the
#: ecliptic pole, 90-150 at latitudes 30-60 deg); with the solar spectrum.
ZODIACAL_LIGHT_S10 = 100.0
#: Integrated light of the stars fainter than the bright-star catalogue's (V > 6.5) and the diffuse galactic light
#: [S10], a mean away from the Milky Way (Leinert et al. 1998, Sect. 6, Tables 35-36: 20-60 S10 at galactic
#: latitudes above 30 deg, the stars brighter than V = 6 a small part); with the solar spectrum.
STARLIGHT_BACKGROUND_S10 = 30.0
#: The Milky Way (:func:`integrated_starlight_s10`): the light of the stars fainter than the drawn ones and the
#: diffuse galactic light [S10] at the galactic poles, in the galactic plane towards the centre (the Sagittarius star
#: clouds) and towards the anticentre, and the band's Gaussian 1/e half-width in galactic latitude [deg]. A schematic
#: model, not a table: its high latitudes keep the 20-60 S10 above |b| = 30 deg of Leinert et al. (1998), Sect. 10;
#: its plane (V = 20.6 mag arcsec-2 towards the centre, 22.4 towards the anticentre) is a chosen round figure for
#: the band seen by eye at a dark site (docs/decisions/0022-night-sky.md).
MILKY_WAY_POLE_S10 = 25.0
MILKY_WAY_CENTRE_S10 = 700.0
MILKY_WAY_ANTICENTRE_S10 = 120.0
MILKY_WAY_HALF_WIDTH_DEG = 15.0
#: Height [m] of the layer whose van Rhijn factor is the air mass of the zodiacal light and starlight
#: (:func:`background_radiance`): Krisciunas & Schaefer's (1991) X = (1 - 0.96 sin^2 z)^-1/2.
DIFFUSE_AIRMASS_HEIGHT_M = 131_000.0
#: B-V of a star whose catalogue has none (a G star's, about the sun's 0.65).
DEFAULT_B_MINUS_V = 0.65



@dataclass(frozen=True)
class AirglowEmission:
    """An airglow emission: a line (``band_nm`` = (lambda, lambda)) or an emission spread evenly over a band.

    Attributes
    ----------
    name : str
    band_nm : tuple of float
        (lower, upper) wavelength [nm]; equal for a line.
    zenith_rayleigh : float
        Zenith intensity above the atmosphere [R] (for a band: the whole band's).
    height_m : float
        Height of the thin emitting layer [m] (the van Rhijn factor's).
    """

    name: str
    band_nm: tuple
    zenith_rayleigh: float
    height_m: float



#: Typical zenith airglow of the middle latitudes at moderate solar activity. OI 557.7 nm 250 R at 97 km and the
#: F-region's OI 630.0 nm 60 R at 250 km (Leinert et al. 1998, Table 16 and Sect. 4.2); Na D 50 R at 92 km (20-150
#: R with the season, Leinert Table 16); the OH Meinel bands' part in the red channel's band, 600 R at 87 km (the
#: bands (5-0) to (9-3) of Noll et al. 2012, Sect. 4 and Fig. 1; chosen so that the zenith's red channel meets the
#: dark-site R = 20.9-21.0 mag arcsec-2 of Benn & Ellison 1998); the visible pseudo-continuum (NO2, FeO), 3 R nm-1
#: (0.3 R per angstrom) at 90 km over 400-700 nm (Leinert et al. 1998, Sect. 4.3; Noll et al. 2012, Sect. 4.3).
AIRGLOW = (
    AirglowEmission("OI 557.7 nm", (557.7, 557.7), 250.0, 97_000.0),
    AirglowEmission("Na D 589.3 nm", (589.3, 589.3), 50.0, 92_000.0),
    AirglowEmission("OI 630.0 nm", (630.0, 630.0), 60.0, 250_000.0),
    AirglowEmission("OH Meinel bands", CHANNEL_BANDS_NM[0], 600.0, 87_000.0),
    AirglowEmission("pseudo-continuum", (400.0, 700.0), 900.0, 90_000.0),
)



@functools.lru_cache(maxsize=1)
def solar_irradiance_channels() -> np.ndarray:
    """Extraterrestrial solar spectral irradiance at 1 AU at the channel wavelengths (3,) [W m-2 nm-1]
    (:func:`swim.color.solar_irradiance_on_grid`, 5 nm bins, interpolated)."""
    e = np.interp(WAVELENGTHS_NM, SPECTRAL_GRID_NM, solar_irradiance_on_grid())
    e.setflags(write=False)
    return e



def solar_relative(radiance, earth_sun_distance_au=1.0):
    """Spectral radiance (3, ...) [W m-2 sr-1 nm-1] in the renderer's units L' = 4 pi L / E_TOA [-] (Albers et al.
    2020, Eq. 2), E_TOA the solar spectral irradiance at the channel wavelengths and earth-sun distance [AU]."""
    e_toa = solar_irradiance_channels() / float(earth_sun_distance_au) ** 2
    radiance = np.asarray(radiance, dtype=float)
    return 4.0 * np.pi * radiance / e_toa.reshape((3,) + (1,) * (radiance.ndim - 1))



def v_surface_brightness(radiance_546):
    """Surface brightness [V mag arcsec-2] of a spectral radiance at 546 nm [W m-2 sr-1 nm-1] (module docstring)."""
    return -2.5 * np.log10(np.asarray(radiance_546, dtype=float) * ARCSEC2_SR / V_ZERO_POINT_W_M2_NM)



def bv_temperature(b_minus_v):
    """Effective temperature [K] of a star of colour index B-V [mag] (Ballesteros 2012, Eq. 14):
    T = 4600 K (1 / (0.92 (B-V) + 1.7) + 1 / (0.92 (B-V) + 0.62)); B-V is clipped to [-0.4, 2.0]."""
    bv = np.clip(np.asarray(b_minus_v, dtype=float), -0.4, 2.0)
    return 4600.0 * (1.0 / (0.92 * bv + 1.7) + 1.0 / (0.92 * bv + 0.62))



def planck_radiance(wavelength_nm, temperature_k):
    """Black-body spectral radiance B_lambda(T) [W m-2 sr-1 nm-1]; broadcasts its arguments."""
    lam = np.asarray(wavelength_nm, dtype=float) * 1e-9
    t = np.asarray(temperature_k, dtype=float)
    return 2 * PLANCK_H * LIGHT_C**2 / lam**5 / np.expm1(PLANCK_H * LIGHT_C / (lam * BOLTZMANN_K * t)) * 1e-9



def star_irradiance(v_mag, b_minus_v):
    """Spectral irradiance above the atmosphere (n, 3) [W m-2 nm-1] of stars at the channel wavelengths.

    A black body at the star's B-V temperature (:func:`bv_temperature`; :data:`DEFAULT_B_MINUS_V` where B-V is NaN)
    scaled to V at 550 nm: E(lambda) = 3.63e-11 10^(-0.4 V) B(lambda, T) / B(550 nm, T).

    Raises
    ------
    SwimInputError
        If a V magnitude is not finite.
    """
    v = np.atleast_1d(np.asarray(v_mag, dtype=float))
    if not np.all(np.isfinite(v)):
        raise SwimInputError("star V magnitudes must be finite [mag]")
    bv = np.atleast_1d(np.asarray(b_minus_v, dtype=float))
    t = bv_temperature(np.where(np.isfinite(bv), bv, DEFAULT_B_MINUS_V))[:, None]
    shape = planck_radiance(WAVELENGTHS_NM[None, :], t) / planck_radiance(V_WAVELENGTH_NM, t)
    return V_ZERO_POINT_W_M2_NM * 10.0 ** (-0.4 * v)[:, None] * shape



def kasten_young_airmass(zenith_deg):
    """Relative optical air mass (Kasten & Young 1989): 1 / (cos z + 0.50572 (96.07995 - z)^-1.6364), z the
    zenith angle [deg] clipped to [0, 90] (38.1 at the horizon)."""
    z = np.clip(np.asarray(zenith_deg, dtype=float), 0.0, 90.0)
    return 1.0 / (np.cos(np.radians(z)) + 0.50572 * (96.07995 - z) ** -1.6364)



def vertical_optical_depth(height_asl_m, aod_550=0.05, aerosol_scale_height_m=1500.0, angstrom_exponent=1.3,
                           ozone_du=US_STANDARD_OZONE_DU):
    """The clear atmosphere's vertical optical depth above an observer (3,) [-] at 615, 546, 450 nm.

    Rayleigh (Bodhaine et al. 1999) at the US Standard Atmosphere 1976's pressure at that height; the exponential
    background aerosol above it, aod_550 exp(-h / H) (lambda / 550 nm)^-alpha, as the renderer's
    (:class:`swim.rt.gas.AerosolBackground`); ozone's Chappuis band (:mod:`swim.optics.ozone`: the Bremen cross
    sections on the US standard profile scaled to ``ozone_du``), the part of its column above the observer.

    Raises
    ------
    SwimInputError
        A negative AOD or ozone column, or a non-positive scale height.
    """
    if not (np.isfinite(aod_550) and aod_550 >= 0 and np.isfinite(aerosol_scale_height_m)
            and aerosol_scale_height_m > 0 and np.isfinite(ozone_du) and ozone_du >= 0):
        raise SwimInputError(f"aerosol optical depth at 550 nm and ozone column [DU] must be >= 0 and the aerosol "
                             f"scale height > 0 m; got {aod_550}, {ozone_du}, {aerosol_scale_height_m}")
    h = float(np.clip(height_asl_m, -5_000.0, 100_000.0))
    _, pressure, _ = us_standard_atmosphere_1976(np.array([h]))
    tau_r = np.asarray(rayleigh_optical_depth_bodhaine1999(WAVELENGTHS_NM, pressure_pa=float(pressure[0])))
    tau_a = aod_550 * np.exp(-max(h, 0.0) / aerosol_scale_height_m) * (WAVELENGTHS_NM / 550.0) ** -angstrom_exponent
    heights = np.linspace(max(h, 0.0), 100_000.0, 2001)
    above_du = ozone_column_du(heights, ozone_number_density(heights, ozone_du)) if ozone_du > 0 else 0.0
    tau_o3 = ozone_cross_section(WAVELENGTHS_NM) * above_du * DOBSON_UNIT_M2
    return tau_r + tau_a + tau_o3



def van_rhijn(zenith_deg, layer_height_m, observer_height_m=0.0):
    """Brightening of a thin emitting layer seen at zenith angle z [deg] (van Rhijn 1921):
    1 / sqrt(1 - ((R + h0) / (R + h))^2 sin^2 z), R the earth's radius, h the layer's and h0 the observer's
    height [m]. Zero for an observer at or above the layer."""
    if observer_height_m >= layer_height_m:
        return np.zeros_like(np.asarray(zenith_deg, dtype=float))
    ratio = (EARTH_RADIUS_M + observer_height_m) / (EARTH_RADIUS_M + layer_height_m)
    s = np.sin(np.radians(np.asarray(zenith_deg, dtype=float)))
    return 1.0 / np.sqrt(1.0 - (ratio * s) ** 2)



def emission_channel_radiance(emission: AirglowEmission) -> np.ndarray:
    """Band-mean spectral radiance (3,) [W m-2 sr-1 nm-1] in the channels of an emission's zenith intensity
    (module docstring, "Channels")."""
    lo, hi = emission.band_nm
    out = np.zeros(3)
    for c, (b0, b1) in enumerate(CHANNEL_BANDS_NM):
        if hi == lo:
            share = 1.0 if b0 <= lo < b1 else 0.0
            wavelength = lo
        else:
            share = max(0.0, min(hi, b1) - max(lo, b0)) / (hi - lo)
            wavelength = 0.5 * (max(lo, b0) + min(hi, b1))
        energy = PLANCK_H * LIGHT_C / (wavelength * 1e-9)
        out[c] = emission.zenith_rayleigh * share * RAYLEIGH_PHOTON_RADIANCE * energy / (b1 - b0)
    return out



def integrated_starlight_s10(galactic_latitude_deg, galactic_longitude_deg):
    """The Milky Way: the integrated light of the faint stars and the diffuse galactic light [S10] towards galactic
    latitude b and longitude l [deg] (any shapes that broadcast; NaN gives :data:`STARLIGHT_BACKGROUND_S10`).

    S(l, b) = S_pole + S_plane(l) exp(-(b / w)^2), S_plane(l) = S_anti + (S_centre - S_anti) ((1 + cos l) / 2)^2,
    with S_pole, S_centre, S_anti and w the constants :data:`MILKY_WAY_POLE_S10`, :data:`MILKY_WAY_CENTRE_S10`,
    :data:`MILKY_WAY_ANTICENTRE_S10` and :data:`MILKY_WAY_HALF_WIDTH_DEG`: the band brightest towards the galactic
    centre (l = 0) and faintest towards the anticentre (l = 180 deg), 25-30 S10 at high galactic latitudes.

    References
    ----------
    Leinert, Ch. et al. (1998), A&AS 127, 1-99, Sect. 10, doi:10.1051/aas:1998105 (the high latitudes).
    """
    b = np.radians(np.asarray(galactic_latitude_deg, dtype=float))
    lon = np.radians(np.asarray(galactic_longitude_deg, dtype=float))
    towards_centre = (0.5 * (1.0 + np.cos(lon))) ** 2
    plane = MILKY_WAY_ANTICENTRE_S10 + (MILKY_WAY_CENTRE_S10 - MILKY_WAY_ANTICENTRE_S10) * towards_centre
    s10 = MILKY_WAY_POLE_S10 + plane * np.exp(-(b / np.radians(MILKY_WAY_HALF_WIDTH_DEG)) ** 2)
    return np.where(np.isfinite(s10), s10, STARLIGHT_BACKGROUND_S10)



def background_radiance(zenith_deg, tau_vertical, observer_height_m=0.0, emissions=AIRGLOW,
                        zodiacal_s10=ZODIACAL_LIGHT_S10, starlight_s10=STARLIGHT_BACKGROUND_S10):
    """The night sky's smooth background at the ground (3, ...) [W m-2 sr-1 nm-1]: airglow (each layer brightened by
    its :func:`van_rhijn` factor V) plus zodiacal light and the faint stars' light.

    A diffuse source is attenuated as exp(-tau_v V), its van Rhijn factor taken for the air mass (for zodiacal light
    and starlight that of a layer at :data:`DIFFUSE_AIRMASS_HEIGHT_M`), as in Krisciunas & Schaefer (1991), Eq. 2:
    light scattered into the line of sight from the neighbouring sky makes up part of what is scattered out of it
    (Garstang 1989), so the sky keeps brightening to the horizon (2.6 times the zenith at 85 deg), where a point
    source's air mass (:func:`kasten_young_airmass`, 38 at the horizon) would black it out.

    Parameters
    ----------
    zenith_deg : array_like
        View zenith angles [deg], any shape.
    tau_vertical : array_like
        Shape (3,): the clear atmosphere's vertical optical depth above the observer [-]
        (:func:`vertical_optical_depth`).
    observer_height_m : float
        Observer's height above sea level [m].
    emissions : sequence of AirglowEmission
    zodiacal_s10, starlight_s10 : float or array_like
        Zodiacal light and the faint stars' light [S10], with the solar spectrum; arrays broadcast to
        ``zenith_deg``'s shape (the Milky Way of :func:`integrated_starlight_s10`).

    Returns
    -------
    numpy.ndarray
        Shape (3,) + ``zenith_deg``'s shape.
    """
    z = np.asarray(zenith_deg, dtype=float)
    tau = np.asarray(tau_vertical, dtype=float).reshape((3,) + (1,) * z.ndim)
    sun = solar_irradiance_channels()
    solar_shape = sun / np.interp(V_WAVELENGTH_NM, SPECTRAL_GRID_NM, solar_irradiance_on_grid())
    x = van_rhijn(z, DIFFUSE_AIRMASS_HEIGHT_M, min(observer_height_m, DIFFUSE_AIRMASS_HEIGHT_M - 1.0))
    s10 = np.broadcast_to(np.asarray(zodiacal_s10, dtype=float) + np.asarray(starlight_s10, dtype=float), z.shape)
    total = (S10_RADIANCE * solar_shape).reshape(tau.shape) * s10[None] * np.exp(-tau * x)
    for emission in emissions:
        x = van_rhijn(z, emission.height_m, observer_height_m)
        total = total + emission_channel_radiance(emission).reshape(tau.shape) * x * np.exp(-tau * x)
    return total
