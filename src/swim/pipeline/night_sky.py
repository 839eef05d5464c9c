"""The night-sky stage: airglow, zodiacal light, the faint stars' light and the bright stars added to a render whose
sun is below the horizon (docs/rendering.md, "Night sky"; docs/decisions/0022-night-sky.md).

The stage (:func:`add_night_sky`) runs after the sun's disk is added and before the colour stage: it adds the night
sky's solar-relative radiance to the ``radiance`` plane (float32, calibrated values for the netCDF), so the automatic
exposure and the ``rgb`` codes see it; :func:`with_night_sky_record` then keeps it apart in the image as
``radiance_night_sky`` (so ``radiance`` stays the sum of its parts) and records what was added in the attributes
``night_sky_*``. By day (the sun's zenith angle at most 90 deg, and the light not the moon) it adds nothing: the
night sky's L' of ~2e-8 is below a millionth of a day sky's. Cameras above :data:`NIGHT_SKY_MAX_OBSERVER_M` (above
the airglow, looking down) get none either. Lines of sight that meet the ground (beyond the horizon's dip) get none.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import pandas as pd
import xarray as xr

from ..constants import EARTH_RADIUS_M
from ..geometry.planets import planet_sky
from ..geometry.stars import galactic_coordinates, star_catalogue, star_directions_enu
from ..optics.ozone import US_STANDARD_OZONE_DU
from ..rt.night_sky import (AIRGLOW, MILKY_WAY_ANTICENTRE_S10, MILKY_WAY_CENTRE_S10, MILKY_WAY_HALF_WIDTH_DEG,
                            MILKY_WAY_POLE_S10, STARLIGHT_BACKGROUND_S10, ZODIACAL_LIGHT_S10, background_radiance,
                            integrated_starlight_s10, kasten_young_airmass, solar_relative, star_irradiance,
                            vertical_optical_depth)

log = logging.getLogger(__name__)

#: Faintest star [V mag] drawn from the catalogue; fainter stars are in the smooth background
#: (:data:`swim.rt.night_sky.STARLIGHT_BACKGROUND_S10`).
STAR_LIMIT_V = 6.5
#: Highest observer [m above sea level] that gets a night sky (the airglow layers lie at 87-250 km; a camera in
#: orbit looks down on them, which is not modelled).
NIGHT_SKY_MAX_OBSERVER_M = 80_000.0



def _below_horizon(view_zenith_deg, height_above_ground_m):
    """Pixels whose line of sight meets the ground: zenith angles beyond 90 deg plus the dip of the horizon seen
    from the observer's height above the ground (a sphere of the earth's radius)."""
    dip = np.degrees(np.arccos(EARTH_RADIUS_M / (EARTH_RADIUS_M + max(float(height_above_ground_m), 0.0))))
    return ~(view_zenith_deg <= 90.0 + dip)  # NaN (outside the camera's field) counts as hidden



#: Asymmetry parameter of the cloud's scattering in :func:`cloud_diffuse_transmittance` (water cloud, visible).
CLOUD_ASYMMETRY = 0.85



def cloud_diffuse_transmittance(tau):
    """Diffuse transmittance [-] of a conservatively scattering cloud of optical depth ``tau`` [-] lit by a diffuse
    sky, in the Eddington two-stream approximation: 1 / (1 + 3/4 (1 - g) tau), g = :data:`CLOUD_ASYMMETRY`
    (Bohren 1987, Am. J. Phys. 55, 524-533, doi:10.1119/1.15109; 0.15 at tau = 50)."""
    return 1.0 / (1.0 + 0.75 * (1.0 - CLOUD_ASYMMETRY) * np.maximum(np.asarray(tau, dtype=float), 0.0))



def _difference(dirs, r, c, dr, dc):
    """Direction differences (k, 3) per pixel step across (dr, dc) at pixels (r, c): central where both neighbours
    are imaged, else one-sided; NaN where neither is."""
    ny, nx = dirs.shape[:2]
    r1, c1 = np.minimum(r + dr, ny - 1), np.minimum(c + dc, nx - 1)
    r0, c0 = np.maximum(r - dr, 0), np.maximum(c - dc, 0)
    bad1 = ~np.isfinite(dirs[r1, c1, 0])
    bad0 = ~np.isfinite(dirs[r0, c0, 0])
    r1, c1 = np.where(bad1, r, r1), np.where(bad1, c, c1)
    r0, c0 = np.where(bad0, r, r0), np.where(bad0, c, c0)
    steps = (r1 - r0) * dr + (c1 - c0) * dc
    with np.errstate(invalid="ignore", divide="ignore"):
        return (dirs[r1, c1] - dirs[r0, c0]) / np.where(steps > 0, steps, np.nan)[:, None]



def pixel_solid_angle_at(dirs, r, c):
    """Solid angle [sr] (k,) of the pixels (r, c) (each (k,)) of an image whose pixel centres look along ``dirs``
    (ny, nx, 3) (unit vectors, NaN outside the field of view): |d_col x d_row|, the cross product of the direction
    differences per pixel along a row and along a column (second-order accurate; a camera's exact
    ``pixel_solid_angles`` of a whole 1024^2 all-sky image takes ~30 s). NaN where a pixel has no imaged neighbour."""
    r, c = np.asarray(r, dtype=np.int64), np.asarray(c, dtype=np.int64)
    return np.linalg.norm(np.cross(_difference(dirs, r, c, 0, 1), _difference(dirs, r, c, 1, 0)), axis=-1)



def star_radiance(camera, shape, time, observer, tau_vertical, tau_hydrometeor, hidden, earth_sun_distance_au=1.0,
                  catalogue=None):
    """The bright stars as point sources: solar-relative radiance (3, ny, nx) [-] and the number of stars drawn.

    Each star with V <= :data:`STAR_LIMIT_V` at its apparent, refracted place
    (:func:`swim.geometry.stars.star_directions_enu`) puts its spectral irradiance
    (:func:`swim.rt.night_sky.star_irradiance`), attenuated by exp(-tau_v X(z)) and the hydrometeor optical depth
    of its pixel's line of sight, into the pixel that the camera images it in, as radiance E / Omega_pixel
    (:func:`point_source_radiance`).

    Parameters
    ----------
    camera : swim.geometry.cameras.Camera
    shape : tuple of int
        (ny, nx) of the image.
    time : str or pandas.Timestamp
        UTC time.
    observer : tuple of float
        (lat [deg], lon [deg], height above sea level [m]).
    tau_vertical : array_like
        Shape (3,): the clear atmosphere's vertical optical depth above the observer [-].
    tau_hydrometeor, hidden : numpy.ndarray
        Shape (ny, nx): the line of sight's hydrometeor optical depth [-] and the pixels that see the ground.
    earth_sun_distance_au : float
    catalogue : swim.geometry.stars.StarCatalogue, optional
        Default: :func:`swim.geometry.stars.star_catalogue` (None: no stars drawn).
    """
    catalogue = star_catalogue() if catalogue is None else catalogue
    if catalogue is None:
        return np.zeros((3,) + tuple(shape)), 0
    stars = catalogue.brighter_than(STAR_LIMIT_V)
    lat, lon, height_asl = observer
    dirs, altitude = star_directions_enu(stars, time, lat, lon, height_asl)
    return point_source_radiance(camera, shape, dirs, altitude, stars.v_mag, stars.b_minus_v, tau_vertical,
                                 tau_hydrometeor, hidden, earth_sun_distance_au)



def planet_radiance(camera, shape, time, observer, tau_vertical, tau_hydrometeor, hidden,
                    earth_sun_distance_au=1.0):
    """Mercury, Venus, Mars, Jupiter and Saturn as point sources (:func:`swim.geometry.planets.planet_sky`: DE421
    places, Mallama & Hilton 2018 magnitudes, Harris 1961 colours), drawn as the stars are
    (:func:`point_source_radiance`): solar-relative radiance (3, ny, nx) [-] and the names of those drawn.
    Arguments as :func:`star_radiance`."""
    lat, lon, height_asl = observer
    planets = planet_sky(time, lat, lon, height_asl)
    out, n, drawn = point_source_radiance(camera, shape, planets.directions, planets.altitude_deg, planets.v_mag,
                                          planets.b_minus_v, tau_vertical, tau_hydrometeor, hidden,
                                          earth_sun_distance_au, return_index=True)
    return out, tuple(planets.names[i] for i in drawn)



def point_source_radiance(camera, shape, dirs, altitude_deg, v_mag, b_minus_v, tau_vertical, tau_hydrometeor, hidden,
                          earth_sun_distance_au=1.0, return_index=False):
    """Point sources (stars, planets) put into the pixels that image them: solar-relative radiance (3, ny, nx) [-]
    and the number drawn (with ``return_index`` also the indices (k,) of those drawn).

    Each source's spectral irradiance above the atmosphere (:func:`swim.rt.night_sky.star_irradiance` of V and
    B-V), attenuated by exp(-tau_v X(z)) (X: :func:`swim.rt.night_sky.kasten_young_airmass` at its apparent
    altitude) and by the hydrometeor optical depth of its pixel's line of sight, is spread over its pixel as the
    radiance E / Omega_pixel (:func:`pixel_solid_angle_at`). ``dirs`` (n, 3) ENU unit vectors, ``altitude_deg``,
    ``v_mag``, ``b_minus_v`` (n,); the other arguments as :func:`star_radiance`.
    """
    out = np.zeros((3,) + tuple(shape))
    row, col = camera.pixel_of_direction(dirs)
    seen = np.isfinite(row) & np.isfinite(col)
    r = np.rint(np.where(seen, row, 0)).astype(np.int64)
    c = np.rint(np.where(seen, col, 0)).astype(np.int64)
    seen &= (r >= 0) & (r < shape[0]) & (c >= 0) & (c < shape[1])
    r, c = r[seen], c[seen]
    visible = ~hidden[r, c]
    r, c = r[visible], c[visible]
    index = np.flatnonzero(seen)[visible]
    omega = pixel_solid_angle_at(camera.cached_directions()[0], r, c)
    ok = np.isfinite(omega) & (omega > 0)
    r, c, index, omega = r[ok], c[ok], index[ok], omega[ok]
    tau_h = np.nan_to_num(np.asarray(tau_hydrometeor, dtype=float)[r, c], nan=0.0)
    airmass = kasten_young_airmass(90.0 - np.asarray(altitude_deg, dtype=float)[index])
    e = star_irradiance(np.asarray(v_mag, dtype=float)[index], np.asarray(b_minus_v, dtype=float)[index])  # (k, 3)
    e = e * np.exp(-np.asarray(tau_vertical)[None, :] * airmass[:, None] - tau_h[:, None])
    l_prime = solar_relative(e.T / omega[None, :], earth_sun_distance_au)  # (3, k)
    flat = out.reshape(3, -1)
    pixels = r * shape[1] + c
    for ch in range(3):
        np.add.at(flat[ch], pixels, l_prime[ch])
    return (out, int(index.size), index) if return_index else (out, int(index.size))



def milky_way_s10(camera, time, observer):
    """The Milky Way's integrated starlight [S10] (ny, nx) towards each pixel
    (:func:`swim.rt.night_sky.integrated_starlight_s10` at the pixel's galactic coordinates,
    :func:`swim.geometry.stars.galactic_coordinates`); NaN outside the field of view.
    ``observer``: (lat [deg], lon [deg], height above sea level [m])."""
    lat, lon, height_asl = observer
    dirs = camera.cached_directions()[0]
    b, lon_gal = galactic_coordinates(dirs, time, lat, lon, height_asl)
    return np.where(np.isfinite(b), integrated_starlight_s10(b, lon_gal), np.nan)



@dataclass(frozen=True)
class NightSky:
    """What :func:`add_night_sky` added: ``radiance`` (3, ny, nx) float32 [-] and the image's ``attrs``."""

    radiance: np.ndarray
    attrs: dict



def night_sky_radiance(camera, view_zenith_deg, tau_hydrometeor, observer, time, aerosol=(0.05, 1500.0, 1.3, 345.5),
                       earth_sun_distance_au=1.0, catalogue=None):
    """The night sky's solar-relative radiance (3, ny, nx) [-] seen by a camera, the number of stars drawn and the
    planets drawn. With a time the faint stars' light is the Milky Way's (:func:`milky_way_s10`) and the bright stars
    and the planets are drawn as points; without one it is the uniform
    :data:`swim.rt.night_sky.STARLIGHT_BACKGROUND_S10`.

    Parameters
    ----------
    camera : swim.geometry.cameras.Camera
    view_zenith_deg, tau_hydrometeor : array_like
        Shape (ny, nx): each pixel's view zenith angle [deg] (NaN outside the field of view) and the hydrometeor
        optical depth along its line of sight [-].
    observer : tuple of float
        (lat [deg], lon [deg], height above sea level [m], height above the ground [m]).
    time : str, pandas.Timestamp or None
        UTC time of the stars' places; None: no stars.
    aerosol : tuple of float
        The background aerosol's optical depth at 550 nm [-], scale height [m] and Angstrom exponent [-], and the
        ozone column [DU] (:func:`swim.rt.night_sky.vertical_optical_depth`).
    earth_sun_distance_au : float
        Earth-sun distance [AU] of the solar-relative units.
    catalogue : swim.geometry.stars.StarCatalogue, optional
        Default :func:`swim.geometry.stars.star_catalogue`.

    Returns
    -------
    radiance : numpy.ndarray
        Shape (3, ny, nx), float64; zero where the line of sight meets the ground or leaves the field of view.
    n_stars : int
    tau_vertical : numpy.ndarray
        Shape (3,): the clear atmosphere's vertical optical depth above the observer [-].
    planets : tuple of str
        The planets drawn (above the horizon and in the field of view).
    """
    lat, lon, height_asl, height_above_ground = observer
    tau_v = vertical_optical_depth(height_asl, *aerosol)
    zenith = np.asarray(view_zenith_deg, dtype=float)
    hidden = _below_horizon(zenith, height_above_ground)
    tau_h = np.nan_to_num(np.asarray(tau_hydrometeor, dtype=float), nan=0.0)
    starlight = STARLIGHT_BACKGROUND_S10
    if time is not None:
        starlight = np.nan_to_num(milky_way_s10(camera, pd.Timestamp(time), (lat, lon, height_asl)),
                                  nan=STARLIGHT_BACKGROUND_S10)
    background = background_radiance(np.where(hidden, 0.0, zenith), tau_v, height_asl, starlight_s10=starlight)
    direct = np.exp(-tau_h)
    # a cloud on the line of sight passes the background behind it (exp(-tau)) and transmits, diffusely, the light
    # that the whole night sky sheds on it: that of the cosine-weighted median zenith angle, 45 deg
    diffuse = np.maximum(cloud_diffuse_transmittance(tau_h) - direct, 0.0)
    hemisphere = background_radiance(np.array(45.0), tau_v, height_asl)
    night = solar_relative(background * direct[None] + hemisphere.reshape(3, 1, 1) * diffuse[None],
                           earth_sun_distance_au)
    night[:, hidden] = 0.0
    n_stars, planets = 0, ()
    if time is not None:
        stars, n_stars = star_radiance(camera, zenith.shape, pd.Timestamp(time), (lat, lon, height_asl), tau_v,
                                       tau_h, hidden, earth_sun_distance_au, catalogue)
        wanderers, planets = planet_radiance(camera, zenith.shape, pd.Timestamp(time), (lat, lon, height_asl),
                                             tau_v, tau_h, hidden, earth_sun_distance_au)
        night += stars + wanderers
    return night, n_stars, tau_v, planets



def add_night_sky(radiance, recoloured, planes, view, sun, aerosol, scene, night=False, catalogue=None):
    """The render's stage (:func:`swim.pipeline.chain.render`): the night sky added to ``radiance`` where the sun is
    below the horizon, before the colour stage.

    Parameters
    ----------
    radiance : numpy.ndarray
        Shape (3, ny, nx): the render's solar-relative radiance [-], the sun's disk added.
    recoloured : numpy.ndarray
        Flat indices of the pixels changed since the march coloured them.
    planes : dict
        The march's planes (its ``tau_hydrometeor``, (1, ny, nx)).
    view : swim.pipeline.scene_stage.View
        The observer (``lat``, ``lon``, ``height``, ``height_asl``, ``sun_enu``) and its ``camera``.
    sun : swim.geometry.sun.SunPosition or swim.geometry.moon.MoonPosition
        The render's light: its ``time`` (else the scene's) places the stars; its ``earth_sun_distance_au`` sets the
        units. The night sky is added where the sun is below the observer's horizon (``view.sun_enu``), or always
        with ``night``.
    night : bool
        The light is the moon (a night render, :mod:`swim.pipeline.moonlight`): ``view.sun_enu`` is the moon's.
    aerosol : swim.rt.gas.AerosolBackground
        The render's background aerosol and ozone column (the clear atmosphere's extinction).
    scene : xarray.Dataset
        The scene (its ``time`` coordinate where the sun has none).
    catalogue : swim.geometry.stars.StarCatalogue, optional

    Returns
    -------
    radiance : numpy.ndarray
        Float32, the night sky added (the input itself by day).
    recoloured : numpy.ndarray
        Every pixel's flat index where the night sky was added, else the input.
    night : NightSky or None
        None by day or for an observer above :data:`NIGHT_SKY_MAX_OBSERVER_M`.
    """
    sun_zenith = float(np.degrees(np.arccos(np.clip(np.asarray(view.sun_enu, dtype=float)[2], -1.0, 1.0))))
    if (sun_zenith <= 90.0 and not night) or view.height_asl > NIGHT_SKY_MAX_OBSERVER_M:
        return radiance, recoloured, None
    time = sun.time if sun.time is not None else (scene["time"].values if "time" in scene.coords else None)
    if time is None:
        log.info("night sky without stars: neither the sun nor the scene has a time")
    zenith = view.camera.cached_view_angles()[1]
    night_radiance, n_stars, tau_v, planets = night_sky_radiance(
        view.camera, zenith, planes["tau_hydrometeor"][0], (view.lat, view.lon, view.height_asl, view.height), time,
        (float(aerosol.aod_550), float(aerosol.scale_height_m), float(aerosol.type.angstrom_exponent),
         float(getattr(aerosol, "ozone_du", US_STANDARD_OZONE_DU))),
        float(sun.earth_sun_distance_au), catalogue)
    night_radiance = night_radiance.astype(np.float32)
    radiance = (radiance + night_radiance).astype(np.float32, copy=False)
    attrs = {
        "night_sky_components": "airglow (van Rhijn layers), zodiacal light, "
                                + ("the Milky Way (faint starlight by galactic latitude and longitude)"
                                   if time is not None else "faint starlight")
                                + (", bright stars (BSC5)" if n_stars else "")
                                + (", planets (DE421)" if planets else ""),
        "night_sky_stars": n_stars,
        "night_sky_planets": ", ".join(planets),
        "night_sky_star_limit_v": STAR_LIMIT_V,
        "night_sky_zodiacal_s10": ZODIACAL_LIGHT_S10,
        "night_sky_starlight_s10": STARLIGHT_BACKGROUND_S10,
        "night_sky_airglow": "; ".join(f"{e.name} {e.zenith_rayleigh:g} R at {e.height_m / 1e3:g} km" for e in AIRGLOW),
        "night_sky_vertical_optical_depth": np.asarray(tau_v, dtype=float),
    }
    if time is not None:
        attrs["night_sky_milky_way_s10"] = np.array([MILKY_WAY_POLE_S10, MILKY_WAY_CENTRE_S10, MILKY_WAY_ANTICENTRE_S10,
                                                     MILKY_WAY_HALF_WIDTH_DEG])
    log.info("night sky added: %d stars, planets (%s), airglow, zodiacal light and the faint stars' light", n_stars,
             ", ".join(planets) or "none")
    return radiance, np.arange(radiance[0].size), NightSky(night_radiance, attrs)



def with_night_sky_record(image: xr.Dataset, night: NightSky | None) -> xr.Dataset:
    """The image with :func:`add_night_sky`'s record: the plane ``radiance_night_sky`` (wavelength, y, x) [1] (so
    that ``radiance`` stays the sum of its parts) and the attributes ``night_sky_components``, ``night_sky_stars``
    (the number drawn), ``night_sky_planets`` (those drawn), ``night_sky_star_limit_v``, ``night_sky_zodiacal_s10``,
    ``night_sky_starlight_s10`` (the uniform faint starlight without a time), ``night_sky_milky_way_s10`` (the Milky
    Way's pole, centre and anticentre [S10] and half-width [deg]; absent without a time),
    ``night_sky_airglow`` (the layers' zenith intensities and heights) and ``night_sky_vertical_optical_depth``
    (3,); unchanged where ``night`` is None."""
    if night is None:
        return image
    image["radiance_night_sky"] = (("wavelength", "y", "x"), night.radiance, {
        "units": "1",
        "long_name": "night sky's part of L': airglow, zodiacal light, the Milky Way, stars and planets as points"})
    image.attrs.update(night.attrs)
    return image
