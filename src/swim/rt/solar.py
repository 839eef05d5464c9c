"""Step 1a: optical depth towards the sun at every grid point and the cloud transmittance (Eqs. 4-8).

Instead of one ray per grid point, the optical depth is swept level by level from the top of the grid
down, along the sun direction (a semi-Lagrangian sweep): the optical depth at level k is the one at level
k + 1, bilinearly interpolated at the point where the sun ray through (k, j, i) crosses level k + 1, plus
the integral of the extinction over the slanted segment in between. The segment is split into sub-steps
no longer than one grid cell horizontally, so clouds are not skipped under a low sun. Outside the domain
the air is taken as free of clouds (only the gas, handled in Step 2, attenuates there).

On a grid that spans a noticeable part of the sphere (its columns' verticals tilt by more than
:data:`PER_COLUMN_SUN_TILT_DEG` from the reference point's) each column takes the sun in its own local frame: its
own shift per level, path per level and mu0 (:func:`column_sweep_geometry`, docs/decisions/0020-per-column-sun.md).

Four fields are swept together: the hydrometeor extinction, the extinction weighted by each species'
backscatter fraction b (so that ``b tau_s = sum_s b_s tau_s`` in Eqs. 4-5), an opaque terrain occupancy
field, which makes mountains cast shadows, and the 3-D aerosol extinction (its own optical depth towards the
sun: the aerosol dims the direct beam, its diffuse light is in Step 2's multiple-scattering table).

The transmittance T is the delta-Eddington flux transmittance of :func:`transmittance_delta_eddington`
(a function of tau_s, b tau_s and mu0), not Stephens' form of Eqs. 4-6 (:func:`transmittance_stephens1978`,
kept for reference), whose sun-angle dependence is wrong for thick layers (docs/rendering.md, "Overcast
accuracy").
"""

from __future__ import annotations

import logging

import numpy as np
import xarray as xr

from ..constants import BACKSCATTER_FRACTION
from ..errors import SwimInputError
from ..arrays import array_namespace

log = logging.getLogger(__name__)

#: Optical depth of terrain per fully occupied cell height crossed [-] (makes terrain opaque).
TERRAIN_OPACITY_PER_CELL = 8.0
#: Lowest sine of the solar elevation used for the sweep direction (the sun below ~0.6 deg elevation is
#: treated as grazing; the gas tables of Step 2 put such points into the earth's shadow anyway).
MIN_SUN_ELEVATION_SINE = 0.01
#: Variables of :func:`solar_transmittance`.
STEP1A_VARIABLES = ("tau_sun", "b_tau_sun", "terrain_shadow", "aerosol_tau_sun", "cloud_transmittance", "transmittance")
#: Variables of :func:`solar_transmittance` that it can write into the caller's arrays (``out``): those of a render.
OUT_VARIABLES = ("aerosol_tau_sun", "cloud_transmittance", "terrain_shadow")
#: 1 - g per unit backscatter fraction b in :func:`transmittance_delta_eddington` [-]: with 1 - g = (7/3) b
#: the delta-Eddington transmittance of a thick layer equals Eq. 4's (T1 -> mu0 / (b tau_v)) at z0 = 60 deg,
#: and the paper's b of cloud liquid (0.063) gives g = 0.853, the asymmetry parameter of stratus droplets
#: (0.85 ... 0.87 from Mie theory for r_e ~ 10 um).
ONE_MINUS_G_PER_BACKSCATTER = 7.0 / 3.0


def transmittance_stephens1978(b_tau, mu0):
    """Cloud transmittance of scalar irradiance T (Eqs. 4-6 of Albers et al. 2020).

    ``T1 = 1 - b tau / (1 + b tau)`` (Eq. 4), ``T2 = 1 - b tau mu0 / (1 + b tau mu0)`` (Eq. 5),
    ``T = max(T1, T2 mu0)`` (Eq. 6).

    Parameters
    ----------
    b_tau : array_like
        Backscatter-weighted optical depth towards the sun, sum_s b_s tau_s [-].
    mu0 : float or array_like
        Cosine of the solar zenith angle z0 [-], > 0.

    Returns
    -------
    array_like
        T [-], same shape as ``b_tau``; T = 1 for b_tau = 0.

    References
    ----------
    Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Eqs. 4-6, after Stephens (1978).
    """
    xp = array_namespace(b_tau, mu0)
    t1 = 1.0 / (1.0 + b_tau)
    t2 = 1.0 / (1.0 + b_tau * mu0)
    return xp.maximum(t1, t2 * mu0)


def transmittance_delta_eddington(tau_s, b_tau_s, mu0):
    """Flux transmittance T of the hydrometeors above a point along the sun path (replaces Eqs. 4-6).

    The conservative (non-absorbing) delta-Eddington two-stream solution for a plane layer, as a function of
    the slant optical depth tau_s towards the sun (the Step 1a sweep) and mu0:

    ``T = [K(mu0) + (1 - K(mu0)) e^{-tau'_s}] / (1 + (3/4) (1 - g) mu0 tau_s)``,

    ``K(mu0) = 1/2 + 3 mu0 / 4``, ``tau'_s = (1 - g^2) tau_s`` (delta-scaled slant optical depth,
    f = g^2), ``1 - g = (7/3) b`` with the backscatter-weighted mean b = (b tau_s) / tau_s of the species
    along the path (:data:`ONE_MINUS_G_PER_BACKSCATTER`).

    T is the total (direct + diffuse) downward flux below the layer per unit incident flux mu0 E_TOA, i.e.
    it keeps the meaning of Stephens' T of Eqs. 4-6 (the horizontal flux below a cloud is mu0 T E_TOA).

    Parameters
    ----------
    tau_s : array_like
        Optical depth towards the sun (hydrometeors and 3-D aerosol) [-], >= 0.
    b_tau_s : array_like
        Its backscatter-weighted sum, sum_s b_s tau_s [-] (the b of Sect. 3.4: 0.063 liquid and rain,
        0.14 ice and snow, 0.125 aerosol), same shape as ``tau_s``.
    mu0 : float or array_like
        Cosine of the solar zenith angle [-], > 0.

    Returns
    -------
    array_like
        T [-] in (0, 1], same shape as ``tau_s``; T = 1 for tau_s = 0.

    Notes
    -----
    Why not Eqs. 4-6: for a plane layer T = T1 = mu0 / (mu0 + b tau_v) (tau_v = mu0 tau_s), which for a thick
    layer falls as mu0 / (b tau_v), whereas the diffusion (two-stream) limit is
    K(mu0) / ((3/4)(1 - g) tau_v), K = 1/2 + 3 mu0 / 4 (Eddington; the exact escape function is
    (3/7)(1 + 2 mu0)). Against DISORT for a conservative Henyey-Greenstein layer (g = 0.85, black surface)
    Eq. 4 is +16 % (tau_v = 20) and +24 % (50) too bright at z0 = 30 deg, +9 % and +6 % at 60 deg; this T is
    within +2.5 % at z0 <= 30 deg and +6 % at 60 deg for all tau_v, +15 % at z0 = 78 deg (the known
    delta-Eddington excess at low sun), docs/rendering.md, "Overcast accuracy". Delta scaling keeps
    R = 1 - T >= 0 for thin layers and a high sun (plain Eddington gives T > 1 there for g > 2/3).
    The mapping of b to 1 - g keeps the species dependence of the paper's b and Eq. 4's thick-layer value
    at z0 = 60 deg (T1 -> mu0 / (b tau_v) = K(1/2) / ((3/4)(1 - g) tau_v) for 1 - g = (7/3) b).

    References
    ----------
    Joseph, J. H., Wiscombe, W. J. and Weinman, J. A. (1976), The delta-Eddington approximation for
    radiative flux transfer, J. Atmos. Sci. 33, 2452-2459, doi:10.1175/1520-0469(1976)033<2452:TDEAFR>2.0.CO;2;
    Meador, W. E. and Weaver, W. R. (1980), Two-stream approximations to radiative transfer in planetary
    atmospheres, J. Atmos. Sci. 37, 630-643, doi:10.1175/1520-0469(1980)037<0630:TSATRT>2.0.CO;2
    (conservative case, Eddington coefficients gamma_1 = (3/4)(1 - g), gamma_3 = (2 - 3 g mu0) / 4);
    replaces Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Eqs. 4-6.
    """
    xp = array_namespace(tau_s, b_tau_s, mu0)
    tau_s = xp.asarray(tau_s)
    x = ONE_MINUS_G_PER_BACKSCATTER * xp.asarray(b_tau_s)  # (1 - g) tau_s
    # guarded on both branches: the same values, and a derivative that is finite at tau_s = 0 (that of
    # x / maximum(tau_s, 1e-30) is -x / 1e-60 there, 0 / 0 in float32;
    # docs/decisions/0025-differentiable-forward-operator.md)
    thick = tau_s > 1e-30
    one_minus_g = xp.clip(xp.where(thick, x / xp.where(thick, tau_s, 1.0), x / 1e-30), 0.0, 1.0)
    tau_prime = x * (2.0 - one_minus_g)  # (1 - g^2) tau_s = (1 - g)(1 + g) tau_s
    k = 0.5 + 0.75 * mu0
    return (k + (1.0 - k) * xp.exp(-tau_prime)) / (1.0 + 0.75 * mu0 * x)


#: Levels integrated directly before the optical depth of a higher level is reused (bounds the numerical
#: diffusion of the semi-Lagrangian sweep: one bilinear interpolation per block instead of per level).
DIRECT_LEVELS = 16
#: Levels per block of the transforms (T, the terrain shadow) of :func:`solar_transmittance`'s output.
TRANSFORM_LEVELS = 16


def step1a_levels(volume: xr.Dataset) -> tuple[np.ndarray, np.ndarray]:
    """The levels of an optical volume that hold hydrometeors and 3-D aerosol: Step 1a sweeps each field only up
    to its highest such level (:func:`solar_transmittance`).

    They depend on the volume alone, so a render keeps them for a new sun (a time series' frame): the scan reads
    every species' extinction, ~0.2 s of a new sun's Step 1a for the 400 x 400 x 60 scene where the extinctions
    are views of the packed volume's channels, and ~0.09 s on a new scene's own contiguous arrays, where a render
    now scans them (docs/decisions/0006-gpu-kernels.md).

    Parameters
    ----------
    volume : xarray.Dataset
        Optical volume from :func:`swim.optics.volume.build_optical_volume`.

    Returns
    -------
    hydrometeor_levels, aerosol_levels : numpy.ndarray
        Shape (level,) bool each: a level with any non-zero hydrometeor extinction (any species) and with any
        non-zero 3-D aerosol extinction.
    """
    from ..workers import in_blocks

    beta = volume["extinction"].values
    aerosol = volume["aerosol_extinction"].values
    nk = volume["level"].size
    hydro_levels, aerosol_levels = np.zeros(nk, bool), np.zeros(nk, bool)

    def find(k0, k1):  # not reshape: the fields may be strided views (no copies)
        for n in range(beta.shape[0]):
            hydro_levels[k0:k1] |= beta[n, k0:k1].any(axis=(1, 2))
        aerosol_levels[k0:k1] = aerosol[k0:k1].any(axis=(1, 2))

    in_blocks(find, nk)  # on every core (NumPy's reductions release the GIL)
    return hydro_levels, aerosol_levels


#: The attributes of :func:`solar_transmittance`'s variables.
STEP1A_ATTRS = {"tau_sun": {"units": "1", "long_name": "optical depth towards the sun (Step 1a)"},
                "b_tau_sun": {"units": "1"},
                "terrain_shadow": {"units": "1"},
                "aerosol_tau_sun": {"units": "1",
                                    "long_name": "optical depth of the 3-D aerosol towards the sun at 550 nm"},
                "cloud_transmittance": {"units": "1", "long_name": "cloud transmittance T (Step 1a)"},
                "transmittance": {"units": "1", "long_name": "cloud transmittance T times terrain shadow"}}
#: :data:`OUT_VARIABLES` above the swept levels, where nothing casts a shadow: T and the terrain's shadow 1, the 3-D
#: aerosol's optical depth towards the sun 0.
ABOVE_SWEPT = {"aerosol_tau_sun": 0.0, "cloud_transmittance": 1.0, "terrain_shadow": 1.0}


def sweep_geometry(volume: xr.Dataset, sun, caller: str):
    """The sun's path through an optical volume's levels, as the sweep takes it.

    Parameters
    ----------
    volume : xarray.Dataset
        Optical volume: its attributes ``dz`` [m] and ``affine_matrix`` (2 x 2, [m per grid index]).
    sun : numpy.ndarray
        Shape (3,): unit vector towards the sun in the scene frame.
    caller : str
        Named in the error.

    Returns
    -------
    di, dj : float
        The sun ray's horizontal shift [grid indices] per level climbed (the elevation's sine at least
        :data:`MIN_SUN_ELEVATION_SINE`).
    n_sub : int
        Sub-steps per level: none longer than one grid cell horizontally (at most 256).
    path_per_level : float
        Path length [m] along the sun per level.
    mu0 : float
        The cosine of the solar zenith angle [-] that T takes, at least :data:`MIN_SUN_ELEVATION_SINE`.

    Raises
    ------
    SwimInputError
        If the shift is not finite (the sweeps index by it unchecked, the numba one without bounds tests).

    References
    ----------
    Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Sect. 3.4 (Step 1a's rays towards the sun).
    """
    sin_elev = max(sun[2], MIN_SUN_ELEVATION_SINE)
    dz = float(volume.attrs["dz"])
    matrix = np.asarray(volume.attrs["affine_matrix"]).reshape(2, 2)
    # Horizontal displacement [m] while climbing one level along the sun, in index units.
    di, dj = np.linalg.solve(matrix, sun[:2] / sin_elev * dz)
    if not (np.isfinite(di) and np.isfinite(dj)):
        raise SwimInputError(f"{caller}: the sun's shift per level ({di}, {dj}) grid cells is not finite; "
                             f"check the sun direction {sun.tolist()} and the volume's affine_matrix")
    n_sub = int(np.clip(np.ceil(max(abs(di), abs(dj), 1.0)), 1, 256))
    return float(di), float(dj), n_sub, dz / sin_elev, max(max(float(sun[2]), 0.0), MIN_SUN_ELEVATION_SINE)


#: Largest tilt [deg] between a column's vertical and the reference point's up to which Step 1a sweeps one sun
#: direction through the grid as if it were flat (:func:`sweep_geometry`); beyond it each column takes its own sun
#: (:func:`column_sweep_geometry`). Measured on a uniform layer (tau_v = 5), the flat sweep's slant optical depth at
#: the grid's rim errs by about tilt x tan(z0), its T by less: at 3 deg 2.5 % and 1.1 % (z0 = 30 deg), 7.3 % and
#: 3.2 % (60 deg); at 15 deg (a GFS region of +- 15 deg) 14 % and 6.7 %, 38 % and 20 %
#: (docs/decisions/0020-per-column-sun.md). The WRF Katrina grid tilts by 2.74 deg.
PER_COLUMN_SUN_TILT_DEG = 3.0


def column_tilt_deg(volume: xr.Dataset) -> float:
    """The largest angle [deg] between a column's vertical and the vertical at the scene's reference point.

    Parameters
    ----------
    volume : xarray.Dataset
        Optical volume with ``grid_x``, ``grid_y`` (y, x) [m] (orthographic coordinates about the reference point,
        :func:`swim.frames.orthographic_xy`; a volume without them is taken as flat: 0).

    Returns
    -------
    float
        arcsin(max_columns sqrt(x^2 + y^2) / R) [deg], R = :data:`swim.constants.EARTH_RADIUS_M`.
    """
    from ..constants import EARTH_RADIUS_M

    if "grid_x" not in volume or "grid_y" not in volume:
        return 0.0
    rho = float(np.sqrt(np.max(volume["grid_x"].values ** 2 + volume["grid_y"].values ** 2))) / EARTH_RADIUS_M
    return float(np.degrees(np.arcsin(min(rho, 1.0))))


def per_column_sun(volume: xr.Dataset) -> bool:
    """Whether Step 1a takes each column's own sun (:func:`column_sweep_geometry`): the grid's
    :func:`column_tilt_deg` is above :data:`PER_COLUMN_SUN_TILT_DEG`."""
    return column_tilt_deg(volume) > PER_COLUMN_SUN_TILT_DEG


def column_sweep_geometry(volume: xr.Dataset, sun, caller: str):
    """The sun's path through an optical volume's levels column by column: :func:`sweep_geometry` with each column's
    own sun, for a grid that spans a noticeable part of the sphere.

    A column at orthographic coordinates (x, y) stands on the sphere's point p = (x, y, sqrt(R^2 - x^2 - y^2)) of the
    scene frame (docs/frames.md), its vertical u = p / R. The sun (a direction, the same for all columns) is at
    mu0 = s . u there; climbing one level dz along the sun moves the ray by (s - mu0 u) dz / mu0 in the column's
    tangent plane, whose scene x and y are the grid coordinates' change (a radial step leaves them as they are). The
    grid's local Jacobian d(x, y) / d(i, j) (centred differences of ``grid_x``, ``grid_y``) turns it into grid
    indices, so a latitude-longitude grid's varying spacing is followed too. At the reference point this is
    :func:`sweep_geometry`'s shift.

    Where the local sun is below :data:`MIN_SUN_ELEVATION_SINE` the column is treated as the flat sweep treats a
    grazing sun (the elevation's sine taken as that limit); where it is at or below the horizon (mu0 <= 0) the column
    gets no direct sun (``lit`` False: :func:`solar_transmittance` sets its terrain shadow, which cuts the direct beam,
    to 0). Twilight through the limb (the sun seen over the horizon through the atmosphere) is not modelled.

    Parameters
    ----------
    volume : xarray.Dataset
        Optical volume: ``grid_x``, ``grid_y`` (y, x) [m] and the attribute ``dz`` [m].
    sun : numpy.ndarray
        Shape (3,): unit vector towards the sun in the scene frame.
    caller : str
        Named in the error.

    Returns
    -------
    di, dj : numpy.ndarray
        Shape (y, x) float64: each column's sun-ray shift [grid indices] per level climbed.
    n_sub : int
        Sub-steps per level: none longer than one grid cell horizontally in any column (at most 256).
    path_per_level : numpy.ndarray
        Shape (y, x) float64: path length [m] along the sun per level.
    mu0 : numpy.ndarray
        Shape (y, x) float32: the cosine of the local solar zenith angle [-] that T takes, at least
        :data:`MIN_SUN_ELEVATION_SINE`.
    lit : numpy.ndarray
        Shape (y, x) bool: the local sun is above the horizon.

    Raises
    ------
    SwimInputError
        If a shift is not finite (a degenerate grid: two columns at one place).

    References
    ----------
    Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Sect. 3.4 (Step 1a's rays towards the sun);
    docs/decisions/0020-per-column-sun.md.
    """
    from ..constants import EARTH_RADIUS_M

    sun = np.asarray(sun, dtype=float)
    dz = float(volume.attrs["dz"])
    gx, gy = (np.asarray(volume[name].values, dtype=float) for name in ("grid_x", "grid_y"))
    ux, uy = gx / EARTH_RADIUS_M, gy / EARTH_RADIUS_M
    uz = np.sqrt(np.clip(1.0 - ux * ux - uy * uy, 0.0, 1.0))
    mu = sun[0] * ux + sun[1] * uy + sun[2] * uz
    sin_elev = np.maximum(mu, MIN_SUN_ELEVATION_SINE)
    step_x = (sun[0] - mu * ux) / sin_elev * dz  # [m] per level, grid x and y
    step_y = (sun[1] - mu * uy) / sin_elev * dz
    # the local Jacobian: columns of d(x, y)/di and d(x, y)/dj (y, x, 2, 2), inverted per column
    x_j, x_i = np.gradient(gx)
    y_j, y_i = np.gradient(gy)
    det = x_i * y_j - x_j * y_i
    with np.errstate(divide="ignore", invalid="ignore"):
        di = (y_j * step_x - x_j * step_y) / det
        dj = (x_i * step_y - y_i * step_x) / det
    if not (np.all(np.isfinite(di)) and np.all(np.isfinite(dj))):
        raise SwimInputError(f"{caller}: the sun's shift per level is not finite in some columns; check the sun "
                             f"direction {sun.tolist()} and the volume's grid_x, grid_y (two columns at one place?)")
    n_sub = int(np.clip(np.ceil(max(float(np.abs(di).max()), float(np.abs(dj).max()), 1.0)), 1, 256))
    return di, dj, n_sub, dz / sin_elev, sin_elev.astype(np.float32), mu > 0.0


def swept_levels(top) -> int:
    """Levels [-] a field is swept on: up to its highest level ``top`` (level,) bool marks (which must mark one), and
    the clear level above it, at least 2 and at most all; above them its optical depth towards the sun is 0."""
    return max(min(int(np.flatnonzero(top).max()) + 2, top.size), 2)


def backscatter_weights(volume: xr.Dataset) -> np.ndarray:
    """The backscatter fraction b [-] (species,) float32 of each species of an optical volume's ``species``
    coordinate (after :func:`swim.rt.march_inputs.share_packed_channels` it names only the packed species): the
    weights of the swept ``b tau_s`` (Sect. 3.4 of Albers et al. 2020, doi:10.5194/amt-13-3235-2020)."""
    return np.array([BACKSCATTER_FRACTION[str(name)] for name in volume["species"].values], np.float32)


def solar_transmittance(volume: xr.Dataset, sun_direction_scene, variables=None, backend="auto",
                        nonzero_levels=None, out=None, direct_weights=None) -> xr.Dataset:
    """Step 1a: optical depth towards the sun and cloud transmittance T at every grid point.

    Parameters
    ----------
    volume : xarray.Dataset
        Optical volume from :func:`swim.optics.volume.build_optical_volume`.
    sun_direction_scene : array_like
        Shape (3,): unit vector towards the sun in the scene frame (ENU at the reference point). On a grid whose
        columns' verticals tilt by more than :data:`PER_COLUMN_SUN_TILT_DEG` from the reference point's
        (:func:`per_column_sun`), each column takes this sun in its own local frame (:func:`column_sweep_geometry`:
        its own mu0, shifts and path; no direct sun, a terrain shadow of 0, where the sun is below its horizon).
    variables : sequence of str, optional
        Only these of the variables below (a render needs ``cloud_transmittance``, ``terrain_shadow`` and
        ``aerosol_tau_sun``; each is a float32 field of the volume's size); default: all of them.
    backend : {"auto", "jax", "numba"}
        The sweep's code: JAX (:func:`swim.rt.solar_device._sweep`, any device) or numba
        (:func:`swim.rt.solar_cpu.sweep`: the sweep ~5x, Step 1a as a whole ~3x faster on a CPU); "auto" takes numba
        when JAX's default device is the CPU and numba is installed, as
        :meth:`swim.rt.march_settings.MarchSettings.resolved_backend` does. Both give the same optical depths to
        float32 round-off.
    nonzero_levels : tuple of numpy.ndarray, optional
        The volume's :func:`step1a_levels`, if the caller kept them from an earlier sun; default: scanned here.
    out : dict of str to numpy.ndarray, optional
        Arrays to write some of :data:`OUT_VARIABLES` into instead of new ones (e.g. the packed volume's channels,
        :func:`swim.rt.march_inputs.step1a_channel_views`): each (level, y, x) float32, writeable, of any strides; the
        result's variables are these arrays. They are written in one compiled pass
        (:func:`swim.rt.solar_cpu.step1a_channels`), T in float32 as :func:`transmittance_delta_eddington` computes
        it (the same values within float32 round-off). Default: new arrays.
    direct_weights : array_like, optional
        (species,) weights [-] of the species of the volume's ``species`` coordinate: with them ``b_tau_sun`` is the
        weighted sum of the optical depths (for ``cloud_scattering="discrete_ordinates"`` the delta-M scaled one,
        weights 1 - f) and ``cloud_transmittance`` is the direct beam's e^{-b_tau_sun} instead of T. Default: the
        backscatter fractions and T.

    Returns
    -------
    xarray.Dataset
        ``tau_sun`` (level, y, x) [-]: optical depth of the hydrometeors towards the sun;
        ``b_tau_sun`` (level, y, x) [-]: its backscatter-weighted sum; ``aerosol_tau_sun`` (level, y, x)
        [-]: optical depth of the 3-D aerosol towards the sun at 550 nm (it dims the direct beam,
        e^{-tau}, and is not part of T); ``terrain_shadow`` (level, y, x)
        [-]: transmittance of the terrain (0 in a mountain's shadow); ``cloud_transmittance`` (level, y, x)
        [-]: T alone (it dims the skylight; the terrain shadow cuts only the direct beam);
        ``transmittance`` (level, y, x) [-]: T (:func:`transmittance_delta_eddington`, in place of Eq. 6) times the
        terrain shadow, i.e. E / (e^{-tau_R} E_TOA) of Eq. 8. All are float32; a field that nothing makes (no cloud,
        terrain or 3-D aerosol) is a read-only broadcast of its constant value.

    Raises
    ------
    SwimInputError
        If ``variables`` names a variable that is not one of these, or ``backend`` is not one of
        :data:`swim.rt.march_settings.BACKENDS` (or is "numba" without numba installed), or ``nonzero_levels``
        are not two arrays of the volume's levels, or ``out`` names a variable that is not both requested and one of
        :data:`OUT_VARIABLES`, or one of its arrays is not a writeable float32 array of the volume's shape.

    References
    ----------
    Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Sect. 3.4, Eqs. 4-8; Joseph et al. (1976),
    doi:10.1175/1520-0469(1976)033<2452:TDEAFR>2.0.CO;2 (T).
    """
    from .march_settings import ExecutionSettings, MarchSettings

    names, out = _checked_request(volume, variables, backend, out)
    # "numba" without numba raises there
    backend = MarchSettings(execution=ExecutionSettings(backend=backend)).resolved_backend()
    sun = np.asarray(sun_direction_scene, dtype=float)
    lit = None
    if per_column_sun(volume):  # a grid over a noticeable part of the sphere: each column's own sun
        di, dj, n_sub, path_per_level, mu0, lit = column_sweep_geometry(volume, sun, "solar_transmittance")
        log.info("Step 1a: each column's own sun (the grid's verticals tilt up to %.1f deg; local sun cosine %.3f to "
                 "%.3f, %d columns without direct sun)", column_tilt_deg(volume), float(mu0.min()),
                 float(mu0.max()), int(lit.size - lit.sum()))
    else:
        di, dj, n_sub, path_per_level, mu0 = sweep_geometry(volume, sun, "solar_transmittance")
    dz = float(volume.attrs["dz"])

    beta = volume["extinction"].values
    aerosol = volume["aerosol_extinction"].values
    levels = volume["level"].values
    terrain = volume["terrain_height"].values
    nk = levels.size
    b = _species_weights(volume, direct_weights)
    direct_beam = direct_weights is not None
    # The swept fields: 0 hydrometeor extinction, 1 its backscatter-weighted sum, 2 the terrain (zero at and
    # above the surface, so a sunlit slope does not shade itself; opaque a full level below it), 3 the 3-D
    # aerosol. The hydrometeors make T (a flux transmittance, forward-scattered light included); the 3-D
    # aerosol is swept apart: its diffuse light is in the multiple-scattering table of Step 2, so it dims the
    # direct beam only (docs/rendering.md).
    # Only fields that are not zero everywhere, and only up to their highest non-zero level (plus the clear
    # level above it), are swept: above it the optical depth towards the sun is 0. This is what makes a flat
    # sea or a scene without 3-D aerosol, and the clear air above the highest cloud, cost nothing; and only
    # those levels are ever held as sweep input and output (memory: docs/performance.md).
    hydro_levels, aerosol_levels = (step1a_levels(volume) if nonzero_levels is None
                                    else (np.asarray(a, bool) for a in nonzero_levels))
    if hydro_levels.shape != (nk,) or aerosol_levels.shape != (nk,):
        raise SwimInputError(f"solar_transmittance: nonzero_levels must be two boolean arrays of shape ({nk},) (the "
                             f"volume's step1a_levels), got shapes {hydro_levels.shape} and {aerosol_levels.shape}")
    tops = {0: hydro_levels, 1: hydro_levels, 2: levels < terrain.max(), 3: aerosol_levels}
    taus = _swept_depths((beta, aerosol, levels, terrain, dz), tops, b, backend, (di, dj, n_sub, path_per_level))
    log.info("Step 1a sweep (%s): %d sub-steps per level, max tau_sun %.1f", backend, n_sub,
             float(taus[0].max()) if 0 in taus else 0.0)
    return _step1a_dataset(volume, names, out, taus, mu0, direct_beam, lit)


def _checked_request(volume: xr.Dataset, variables, backend, out):
    """The variables asked of :func:`solar_transmittance` and its ``out`` arrays (a dict), checked.

    Raises
    ------
    SwimInputError
        As :func:`solar_transmittance` for ``variables``, ``backend`` and ``out``.
    """
    from .march_settings import BACKENDS

    names = STEP1A_VARIABLES if variables is None else tuple(variables)
    unknown = sorted(set(names) - set(STEP1A_VARIABLES))
    if unknown:
        raise SwimInputError(f"solar_transmittance: unknown variables {unknown}; expected some of {STEP1A_VARIABLES}")
    if backend not in BACKENDS:
        raise SwimInputError(f"solar_transmittance: backend must be one of {BACKENDS}, got {backend!r}")
    out = dict(out or {})
    expected = tuple(volume["extinction"].shape[1:])
    for name, array in out.items():
        if name not in OUT_VARIABLES or name not in names:
            raise SwimInputError(f"solar_transmittance: out names {name!r}; expected requested variables among "
                                 f"{OUT_VARIABLES}")
        if not (isinstance(array, np.ndarray) and array.dtype == np.float32 and array.shape == expected
                and array.flags.writeable):
            raise SwimInputError(f"solar_transmittance: out[{name!r}] must be a writeable float32 array of shape "
                                 f"{expected} (level, y, x), got {type(array).__name__} "
                                 f"{getattr(array, 'dtype', '')} {getattr(array, 'shape', '')}")
    return names, out


def _species_weights(volume: xr.Dataset, direct_weights):
    """The weights (species,) float32 of the swept ``b_tau_sun``: ``direct_weights`` if given, else the backscatter
    fractions of the volume's species.

    Raises
    ------
    SwimInputError
        If ``direct_weights`` are not one finite weight >= 0 per species.
    """
    # by the volume's own species coordinate: after share_packed_channels it names only the packed species
    b = backscatter_weights(volume)
    if direct_weights is not None:
        b = np.asarray(direct_weights, np.float32).reshape(-1)
        if b.shape != (volume["extinction"].shape[0],) or not np.all(np.isfinite(b)) or np.any(b < 0):
            raise SwimInputError(f"solar_transmittance: direct_weights must be {volume['extinction'].shape[0]} "
                                 f"finite weights >= 0 (one per species), got {direct_weights!r}")
    return b


def _swept_depths(arrays, tops, b, backend, geometry):
    """Optical depths towards the sun (swept levels, y, x) float32 of each swept field, by field (0-3).

    ``arrays``: the volume's extinction (species, level, y, x) and aerosol extinction (level, y, x) [m-1], levels
    and terrain height [m] and dz [m]; ``tops`` (level,) bool per field marks its non-zero levels (a field with none
    is not swept); ``b`` (species,) the weights of field 1; ``geometry``: :func:`sweep_geometry`'s (di, dj, n_sub,
    path_per_level), or :func:`column_sweep_geometry`'s with (y, x) arrays of di, dj and path_per_level.
    """
    from ..workers import in_blocks
    from .solar_cpu import species_sums

    beta, aerosol, levels, terrain, dz = arrays
    di, dj, n_sub, path_per_level = geometry
    shape = beta.shape[2:]  # (ny, nx)
    swept = [c for c in range(4) if tops[c].any()]
    taus = {}
    # Each field is swept up to its own top: the terrain's few levels apart from the clouds' many, so neither the
    # sweep's input nor its output holds zeros above the terrain up to the cloud top (memory). The JAX sweep
    # takes all fields in one call (one compiled shape).
    levels_of = {c: swept_levels(tops[c]) for c in swept}
    groups = {}
    for c in swept:
        groups.setdefault(levels_of[c] if backend == "numba" else max(levels_of.values()), []).append(c)
    for n_levels, group in sorted(groups.items()):  # the smallest first: the biggest sweep's memory comes last
        if backend == "numba":  # with a zero last row and column, which it reads beside the grid's far edge
            padded = np.zeros((len(group), n_levels, shape[0] + 1, shape[1] + 1), np.float32)
            fields = padded[:, :, :shape[0], :shape[1]]
        else:  # JAX's input contiguous as filled: no copy before its transfer (~0.4 GB at 400 x 400 x 160)
            padded = fields = np.empty((len(group), n_levels) + shape, np.float32)

        def fill(k0, k1):  # levels k0..k1 of every swept field of the group
            if 0 in group:  # fields 0 and 1 share their levels, so their group: one pass over the species for both
                species_sums(beta, b, k0, k1, fields[group.index(0), k0:k1], fields[group.index(1), k0:k1])
            for row, c in enumerate(group):
                if c == 2:
                    fields[row, k0:k1] = np.clip((terrain[None] - levels[k0:k1, None, None]) / dz, 0.0, 1.0) * (
                        TERRAIN_OPACITY_PER_CELL / dz)
                elif c == 3:
                    fields[row, k0:k1] = aerosol[k0:k1]

        in_blocks(fill, n_levels)  # on every core (NumPy's loops release the GIL)
        if backend == "numba":
            from .solar_cpu import sweep

            depths = sweep(padded, di, dj, path_per_level, n_sub,
                           DIRECT_LEVELS)[:, :, :shape[0], :shape[1]]
            del padded, fields
        else:
            import jax.numpy as jnp

            from .solar_device import _sweep

            device = jnp.asarray(fields)
            del padded, fields  # the host copy goes before the sweep's output is made
            if np.ndim(di):  # each column's own sun: (ny, nx) shifts and paths, which the sweep broadcasts
                di, dj, path_per_level = (jnp.asarray(a, jnp.float32) for a in (di, dj, path_per_level))
            depths = np.asarray(_sweep(device, di, dj, path_per_level, n_sub))
            del device
        taus.update({c: depths[:, row] for row, c in enumerate(group)})
        del depths
    return taus


def _full_field(taus, nk, shape, c, transform=None, above=0.0):
    """Swept field c on all levels (the swept levels, then ``above``), through ``transform``. A field that was not
    swept (zero everywhere) is a read-only broadcast of ``above``: it takes no memory."""
    if c not in taus:
        return np.broadcast_to(np.float32(above), (nk,) + shape)
    swept_levels = taus[c].shape[0]
    a = np.empty((nk,) + shape, np.float32)
    a[swept_levels:] = above  # each level written once: the swept ones below
    # in blocks of levels, so the transform's temporaries stay small (a whole field of each took ~0.5 GB
    # of a render's peak memory at 400 x 400 x 160: docs/performance.md, "Memory")
    for k0 in range(0, swept_levels, TRANSFORM_LEVELS):
        k1 = min(k0 + TRANSFORM_LEVELS, swept_levels)
        a[k0:k1] = taus[c][k0:k1] if transform is None else transform(k0, k1)
    return a


def _step1a_dataset(volume: xr.Dataset, names, out, taus, mu0, direct_beam, lit=None):
    """:func:`solar_transmittance`'s variables ``names`` from the swept optical depths ``taus`` (by field). ``mu0``:
    one, or each column's (y, x) with ``lit`` (y, x) bool, False where the column gets no direct sun (its terrain
    shadow 0: :func:`column_sweep_geometry`)."""
    nk = volume["level"].size
    shape = tuple(volume["extinction"].shape[2:])  # (ny, nx)
    dark = None if lit is None or lit.all() else ~np.asarray(lit, bool)

    def cloud_t(k0, k1):
        if direct_beam:
            return np.exp(-taus[1][k0:k1])
        return transmittance_delta_eddington(taus[0][k0:k1], taus[1][k0:k1], np.float32(mu0))

    dims = ("level", "y", "x")
    attrs = STEP1A_ATTRS

    def shadow(k0, k1):
        return np.exp(-taus[2][k0:k1])

    # field: (swept field, transform, value above the swept levels)
    recipes = {"tau_sun": (0, None, 0.0), "b_tau_sun": (1, None, 0.0),
               "terrain_shadow": (2, shadow, ABOVE_SWEPT["terrain_shadow"]),
               "aerosol_tau_sun": (3, None, ABOVE_SWEPT["aerosol_tau_sun"]),
               "cloud_transmittance": (0, cloud_t, ABOVE_SWEPT["cloud_transmittance"])}
    data = {}
    if out:
        _write_step1a_channels(out, taus, mu0, shape, direct_beam, dark)
        data = {name: (dims, out[name], attrs[name]) for name in out}

    def made(name):  # a column without direct sun: no terrain shadow's light either
        value = _full_field(taus, nk, shape, *recipes[name])
        return value if dark is None or name != "terrain_shadow" else np.where(dark, np.float32(0.0), value)

    for name in names:  # one field at a time, so only the requested ones are ever held
        if name in data:
            continue
        if name == "transmittance":  # T times the terrain shadow, each made once if it is asked for too
            parts = [data[part][1] if part in data else made(part) for part in ("cloud_transmittance",
                                                                                "terrain_shadow")]
            value = parts[0] * parts[1]
        else:
            value = made(name)
        data[name] = (dims, value, attrs[name])
    return xr.Dataset({name: data[name] for name in names}, coords={"level": volume["level"]})


def _write_step1a_channels(out, taus, mu0, shape, direct_beam=False, dark=None):
    """:data:`OUT_VARIABLES` of :func:`solar_transmittance` into the arrays ``out`` from the swept optical depths
    ``taus`` (by swept field), level blocks on every core (:func:`swim.rt.solar_cpu.step1a_channels`). With each
    column's own ``mu0`` (y, x), T is written by :func:`transmittance_delta_eddington` here, and the terrain shadow
    is 0 in the columns ``dark`` (y, x) bool (or None)."""
    from ..workers import in_blocks
    from .solar_cpu import step1a_channels

    # a field that was not swept: a stand-in of one level (and strided, as the swept fields and the packed channels
    # are, so that one compiled version of the kernel serves: numba compiles one per memory layout)
    stand_in = np.zeros((1,) + shape[:-1] + (shape[-1] + 1,), np.float32)[..., :shape[-1]]
    swept = [(taus[c].shape[0], taus[c]) if c in taus else (0, stand_in) for c in range(4)]
    targets = [(name in out, out.get(name, stand_in)) for name in ("cloud_transmittance", "terrain_shadow",
                                                                   "aerosol_tau_sun")]
    nk = next(iter(out.values())).shape[0]

    columns = np.ndim(mu0) > 0
    # one sun: T in the compiled pass; each column's own: T with its mu0 below
    scalar_mu0 = np.float32(MIN_SUN_ELEVATION_SINE) if columns else np.float32(mu0)
    write_cloud = targets[0][0] and not (columns and not direct_beam)

    def write(k0, k1):
        step1a_channels(k0, k1, scalar_mu0, swept[0][0], swept[0][1], swept[1][1], swept[2][0], swept[2][1],
                        swept[3][0], swept[3][1], targets[0][1], targets[1][1], targets[2][1], write_cloud,
                        targets[1][0], targets[2][0], direct_beam)
        if targets[0][0] and not write_cloud:
            n_hydro, tau, b_tau = swept[0][0], swept[0][1], swept[1][1]
            swept_to = min(k1, n_hydro)
            if swept_to > k0:
                targets[0][1][k0:swept_to] = transmittance_delta_eddington(tau[k0:swept_to], b_tau[k0:swept_to], mu0)
            if k1 > max(k0, n_hydro):
                targets[0][1][max(k0, n_hydro):k1] = ABOVE_SWEPT["cloud_transmittance"]
        if targets[1][0] and dark is not None:
            targets[1][1][k0:k1, dark] = 0.0

    in_blocks(write, nk)
