"""3-D Monte Carlo reference radiances with Mitsuba 3 (volumetric path tracing).

An independent, unbiased solution of the 3-D radiative transfer equation for the scenes swim renders:
the hydrometeor extinction of :func:`swim.optics.volume.build_optical_volume` (paper Eq. 7) on the model
grid, embedded in the clear atmosphere swim uses (Rayleigh and background-aerosol extinction profiles of
:func:`swim.rt.gas.build_gas_tables`), lit by a directional sun and bounded below by a Lambertian ground.
Mitsuba 3 (Jakob et al. 2022, https://mitsuba.readthedocs.io, PyPI ``mitsuba``) traces all orders of
scattering with delta (null-collision) tracking in heterogeneous media; swim's approximations (Steps 1-3
of Albers et al. 2020) are compared against it in ``tests/validation/test_mitsuba_3d.py`` and
``scripts/make_mitsuba_reference.py``.

Scene construction (:func:`build_mitsuba_scene`)
------------------------------------------------
* **World frame.** Plane-parallel: x east, y north, z up [m], the grid's horizontal coordinates
  (``grid_x``, ``grid_y`` of the optical volume) and the height above sea level. swim's atmosphere is
  spherical; the two differ near the horizon, so compare view zenith angles up to ~70-80° only.
* **Gas box.** A box of half-width ``atmosphere_half_width_m`` (default 2000 km) from below the ground to
  100 km, filled with a ``heterogeneous`` medium whose 1 x 1 x n_z grids hold the Rayleigh + aerosol
  extinction [m-1] (``sigma_t``), the single-scattering albedo, and the aerosol share of the scattering
  (the ``weight`` of a ``blendphase`` of the depolarised Rayleigh phase function and the aerosol type's
  Eq. 28 phase function, both as ``tabphase`` tables in cos(theta)). Sky views thus see a horizontally
  wide atmosphere, as swim's Step 2 does.
* **Cloud box.** Inside it, a box around the cells of the model grid that hold hydrometeors or 3-D aerosol
  (plus one empty cell around them, two on the +x side; a smaller box means fewer null collisions) whose
  medium holds gas + hydrometeors + 3-D aerosol on the optical volume's regular levels; its exterior
  medium is the gas. Grid values sit at the voxel centres (Mitsuba's ``gridvolume`` convention) and are
  interpolated trilinearly, as swim's kernels do in index space. The phase function is
  ``blendphase(w_cloud, gas phase, cloud phase)`` with ``w_cloud`` the hydrometeor share of the
  scattering, dilated by one voxel: Mitsuba interpolates the weight itself, not the coefficients it is
  the ratio of, and undilated the scattering in every cloud-edge cell would get a ~50 % Rayleigh phase
  function (a tau = 10 slab then transmitted 13 % too little; see ``test_cloud_slab_flux_matches_disort``).
* **Watertightness.** Mitsuba's triangle intersection can miss a face hit exactly on the diagonal shared
  by its two triangles, which camera rays through the centre of a symmetric scene do; the gas box and
  the ground are therefore centred ~140 km away from the model domain.
* **Hydrometeors.** Single-scattering albedo 1 (liquid water and ice absorb negligibly at 450-615 nm)
  and a Henyey-Greenstein phase function, g = 0.85 for liquid cloud by default (the asymmetry parameter
  of Mie scattering by 10-15 um droplets at visible wavelengths is 0.85-0.87; HG reproduces the multiple
  scattering of thick cloud through the similarity parameter 1 - g, but not the diffraction peak, the
  rainbow and the glory of the single-scattered light). Other species: :data:`HYDROMETEOR_ASYMMETRY`.
  Mixed species share one g, their extinction-weighted mean over the grid.
* **Sun.** A ``directional`` emitter of irradiance 1 normal to the beam (F0 = 1), travelling along
  ``-sun`` (``sun`` points towards the sun, docs/frames.md).
* **Ground.** A ``rectangle`` at z = 0 with a ``diffuse`` BSDF (Lambertian) of the scene's mean albedo.
  Flat terrain only.

Units and angles
----------------
Mitsuba's radiance for an emitter of unit irradiance is I [sr-1]; swim's solar-relative radiance is
L' = 4 pi I (paper Eq. 2), the same conversion as for DISORT (:mod:`swim.validation.disort`), verified
against DISORT on a Rayleigh sky (``tests/validation/test_mitsuba_3d.py``). View directions are unit
vectors pointing away from the observer (swim's convention); the ray is traced along them. The
integrator's estimate does not include the direct sun (a directional emitter cannot be hit), i.e. it is
swim's ``radiance`` without the sun's disk.

Spectral handling
-----------------
With the ``*_rgb`` variants the three channels carry the 615/546/450 nm coefficients. A ``blendphase``
weight is one number per point, so a single RGB pass is exact only if the phase-function mixture is the
same at the three wavelengths: true without aerosol (Rayleigh only; the cloud share of the scattering is
then taken at 546 nm, which differs from the other channels by < 1e-3 wherever cloud matters). With
aerosol (``spectral="auto"``) the scene is built and traced once per wavelength ("monochromatic" passes).

Variants
--------
``llvm_ad_rgb`` (vectorised, all cores) is used where an LLVM >= 17 library is found (``DRJIT_LIBLLVM_PATH``
or Debian's ``libllvm19``); Mitsuba's JIT aborts the process with older LLVM, so it is never tried blindly.
Otherwise ``scalar_rgb`` traces ray by ray from Python (about 3-10x slower). ``SWIM_MITSUBA_VARIANT``
overrides the choice. Russian roulette is disabled (``rr_depth`` very large): it leaves bright outliers.

References
----------
Jakob, W., Speierer, S., Roussel, N., Nimier-David, M., Vicini, D., Zeltner, T., Nicolet, B., Crespo, M.,
Leroy, V. and Zhang, Z. (2022), Mitsuba 3 renderer, version 3.x, https://mitsuba-renderer.org,
https://mitsuba.readthedocs.io.
Albers, S. C. et al. (2020), Atmos. Meas. Tech. 13, 3235-3261, doi:10.5194/amt-13-3235-2020.
Stamnes, K. et al. (1988), Appl. Opt. 27, 2502, doi:10.1364/AO.27.002502 (DISORT, the 1-D check).
"""

from __future__ import annotations

import functools
import glob
import logging
import os
import time as _time
from pathlib import Path

import numpy as np

from ..constants import ATMOSPHERE_TOP_M, SPECIES, WAVELENGTHS_NM
from ..diagnostics.irradiance import radiance_without_sun_disk
from ..errors import SwimInputError
from ..frames import enu_from_azimuth_zenith
from ..optics.rayleigh import rayleigh_phase_function
from ..rt.gas import AerosolBackground, build_gas_tables
from .disort import paper_method_settings, reference_settings

log = logging.getLogger(__name__)

__all__ = [
    "HYDROMETEOR_ASYMMETRY",
    "select_variant",
    "build_mitsuba_scene",
    "mitsuba_radiance",
    "directions_from_angles",
    "swim_view",
    "compare_images",
    "comparison_png",
    "make_rico_reference",
    "load_rico_reference",
    "rico_table_rows",
    "RICO_CASES",
    "RICO_SETTINGS",
]

#: Henyey-Greenstein asymmetry parameter [-] per hydrometeor species at visible wavelengths
#: (liquid: Mie, r_e 10-15 um, Hansen and Travis 1974; ice: hexagonal crystals, Macke et al. 1996 ~0.75;
#: rain: large drops ~0.88; snow and graupel: irregular ice ~0.75 and ~0.80).
HYDROMETEOR_ASYMMETRY = {
    "cloud_liquid": 0.85,
    "cloud_ice": 0.75,
    "rain": 0.88,
    "snow": 0.75,
    "graupel": 0.80,
}

#: Horizontal offset [m] of the centre of the gas box and the ground from the grid origin.
_GAS_BOX_OFFSET_M = (137.0e3, 41.0e3)

#: Rays per vectorised (llvm) wavefront.
_WAVEFRONT = 1 << 18

_LLVM_CANDIDATES = (
    "/usr/lib/x86_64-linux-gnu/libLLVM-{v}.so",
    "/usr/lib/llvm-{v}/lib/libLLVM.so",
    "/usr/lib/llvm-{v}/lib/libLLVM-{v}.so",
    "/usr/lib/aarch64-linux-gnu/libLLVM-{v}.so",
    "/opt/homebrew/opt/llvm@{v}/lib/libLLVM.dylib",
)


def _find_llvm():
    """Path of an LLVM >= 17 shared library usable by Dr.Jit, or None."""
    path = os.environ.get("DRJIT_LIBLLVM_PATH")
    if path:
        return path if Path(path).is_file() else None
    for v in (20, 19, 18, 17):
        for pattern in _LLVM_CANDIDATES:
            for p in glob.glob(pattern.format(v=v)):
                if Path(p).is_file():
                    return p
    return None


def select_variant(variant=None):
    """Import Mitsuba and set its variant; return the module.

    Parameters
    ----------
    variant : str, optional
        ``"llvm_ad_rgb"`` or ``"scalar_rgb"``; default ``$SWIM_MITSUBA_VARIANT``, else ``llvm_ad_rgb`` where
        an LLVM >= 17 library is found (``DRJIT_LIBLLVM_PATH`` is then set to it), else ``scalar_rgb``.

    Returns
    -------
    module
        ``mitsuba`` with the variant set.

    Raises
    ------
    ImportError
        Mitsuba is not installed (``pip install 'swim-imagery[validation]'``).
    """
    import mitsuba as mi

    variant = variant or os.environ.get("SWIM_MITSUBA_VARIANT")
    if variant is None:
        llvm = _find_llvm()
        if llvm is not None and "llvm_ad_rgb" in mi.variants():
            os.environ.setdefault("DRJIT_LIBLLVM_PATH", llvm)
            variant = "llvm_ad_rgb"
        else:
            variant = "scalar_rgb"
    if variant not in ("llvm_ad_rgb", "scalar_rgb"):
        raise SwimInputError(f"Mitsuba variant must be 'llvm_ad_rgb' or 'scalar_rgb'; got {variant!r}")
    if mi.variant() != variant:
        mi.set_variant(variant)
    return mi


# --------------------------------------------------------------------------------------------------------
# scene
# --------------------------------------------------------------------------------------------------------
def _grid_volume(mi, values, lo, hi, channels=None):
    """A ``gridvolume`` dict: values (nz, ny, nx[, c]) at voxel centres of the box [lo, hi] (x, y, z) [m]."""
    a = np.asarray(values, dtype=np.float32)
    if channels is None:
        a = a[..., None]
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    to_world = mi.ScalarTransform4f().translate(mi.ScalarPoint3f(*lo)) @ mi.ScalarTransform4f().scale(mi.ScalarPoint3f(*(hi - lo)))
    return {"type": "gridvolume", "data": mi.TensorXf(np.ascontiguousarray(a)), "to_world": to_world,
            "filter_type": "trilinear", "wrap_mode": "clamp", "raw": True}


#: Cosines of a tabulated cloud phase function in Mitsuba's ``tabphase`` (equally spaced in cos theta: 2e-5 apart,
#: a forward peak ~0.4 deg wide takes ~2 of them).
CLOUD_TABPHASE_POINTS = 100_001


def _tabphase(phase_function, n=4001):
    """A ``tabphase`` dict tabulating P(cos theta) on n points from -1 (backward) to +1 (forward)."""
    mu = np.linspace(-1.0, 1.0, int(n))
    p = np.asarray(phase_function(mu), dtype=float)
    if np.any(~np.isfinite(p)) or np.any(p < 0):
        raise SwimInputError("phase function must be finite and non-negative")
    return {"type": "tabphase", "values": ", ".join(f"{v:.8g}" for v in p)}


def _box_shape(mi, lo, hi, interior, exterior=None):
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    c, h = 0.5 * (lo + hi), 0.5 * (hi - lo)
    shape = {"type": "cube", "bsdf": {"type": "null"}, "interior": interior,
             "to_world": mi.ScalarTransform4f().translate(mi.ScalarPoint3f(*c)) @ mi.ScalarTransform4f().scale(mi.ScalarPoint3f(*h))}
    if exterior is not None:
        shape["exterior"] = exterior
    return shape


def _safe_ratio(num, den):
    den = np.asarray(den, dtype=float)
    return np.where(den > 0, np.asarray(num, dtype=float) / np.where(den > 0, den, 1.0), 0.0)


def _cloud_asymmetry(volume, asymmetry):
    """One HG g for all hydrometeors: their extinction-weighted mean over the grid."""
    ext = np.asarray(volume["extinction"].values, dtype=float)
    totals = ext.reshape(ext.shape[0], -1).sum(axis=1)
    if totals.sum() <= 0:
        return float(asymmetry["cloud_liquid"])
    g = float(np.sum(totals * np.array([asymmetry[s] for s in SPECIES])) / totals.sum())
    present = [s for s, t in zip(SPECIES, totals) if t > 0]
    if len(present) > 1:
        log.warning("hydrometeors %s share one HG phase function, g = %.3f (extinction-weighted mean)", present, g)
    return g


def _regular_axes(volume):
    """Grid x (nx,) and y (ny,) [m] of a regular, axis-aligned optical volume."""
    gx = np.asarray(volume["grid_x"].values, dtype=float)
    gy = np.asarray(volume["grid_y"].values, dtype=float)
    x, y = gx[0], gy[:, 0]
    if gx.shape[1] > 1 and gy.shape[0] > 1:
        dx, dy = np.diff(x), np.diff(y)
        tol = 1e-3 * max(abs(dx).max(), abs(dy).max())
        if (np.ptp(dx) > tol or np.ptp(dy) > tol or np.ptp(gx, axis=0).max() > tol or np.ptp(gy, axis=1).max() > tol):
            raise SwimInputError("the Mitsuba adapter needs a regular, axis-aligned grid (e.g. an LES grid)")
    return x, y


def build_mitsuba_scene(volume, sun_zenith_deg, sun_azimuth_deg, aerosol: AerosolBackground = AerosolBackground(),
                        surface_albedo=None, channel=None, asymmetry=None, atmosphere_half_width_m=2.0e6,
                        variant=None, cloud_phase=None):
    """Build the Mitsuba scene of a swim optical volume (or of a cloud-free atmosphere).

    Parameters
    ----------
    volume : xarray.Dataset or None
        Optical volume of :func:`swim.optics.volume.build_optical_volume` (regular, axis-aligned grid, flat
        terrain); ``None`` for a cloud-free, horizontally uniform atmosphere.
    sun_zenith_deg, sun_azimuth_deg : float
        Sun zenith angle [deg] (< 90) and azimuth [deg] clockwise from north, swim's conventions.
    aerosol : AerosolBackground
        Background 1-D aerosol (``aod_550=0`` for none) and the type of the volume's 3-D aerosol.
    surface_albedo : float or array_like, optional
        Lambertian ground albedo, scalar or (3,) at 615/546/450 nm; default: the volume's mean albedo
        (0.06 without a volume).
    channel : int, optional
        Build a monochromatic scene of wavelength index ``channel`` (all three RGB channels equal); default:
        the three wavelengths in the RGB channels (exact only without aerosol, see the module docstring).
    asymmetry : dict, optional
        HG asymmetry parameter per species; default :data:`HYDROMETEOR_ASYMMETRY`.
    atmosphere_half_width_m : float
        Half-width of the plane-parallel gas box [m].
    variant : str, optional
        Mitsuba variant (:func:`select_variant`).
    cloud_phase : callable, optional
        cos(theta) (n,) -> P (n,), normalised to mean 1 over the sphere: one tabulated phase function of every
        hydrometeor (``tabphase`` on :data:`CLOUD_TABPHASE_POINTS` cosines, which resolve a diffraction peak of
        ~0.4 deg) in place of the Henyey-Greenstein ``asymmetry``.

    Returns
    -------
    dict
        ``scene`` (mitsuba.Scene), ``media`` (dict name -> Medium), ``cloud_box`` ((lo, hi) [m] or None),
        ``gas_box`` (lo, hi) [m], ``cloud_g``, ``channel``.
    """
    mi = select_variant(variant)
    mu0 = float(np.cos(np.radians(sun_zenith_deg)))
    if not (0.0 < mu0 <= 1.0):
        raise SwimInputError(f"sun_zenith_deg must be in [0, 90); got {sun_zenith_deg}")
    gas = build_gas_tables(aerosol)
    asymmetry = dict(HYDROMETEOR_ASYMMETRY if asymmetry is None else asymmetry)
    sel = (lambda a: np.repeat(np.asarray(a)[..., channel:channel + 1], 3, axis=-1)) if channel is not None else (lambda a: np.asarray(a))
    ssa_a = np.asarray(aerosol.ssa, dtype=float)
    albedo = _ground_albedo(volume, surface_albedo, sel)

    w = float(atmosphere_half_width_m)
    off, gas_lo, gas_hi = _gas_box(gas, w)
    wc = 1 if channel is None else channel
    has_aerosol = bool(np.any(np.asarray(gas.beta_aerosol, dtype=float) > 0)
                       or (volume is not None and np.any(volume["aerosol_extinction"].values > 0)))
    if has_aerosol and channel is None:
        log.warning("aerosol with an RGB pass: the aerosol/Rayleigh phase mixture is taken at 546 nm for all channels")
    p_rayleigh = _tabphase(lambda m: np.asarray(rayleigh_phase_function(m, gas.depolarization), dtype=float), n=401)
    # the aerosol type's phase function is per wavelength (n, 3): the channel rendered, or 546 nm for an RGB pass
    p_aerosol = (_tabphase(lambda m: np.asarray(aerosol.type.phase_function(m), dtype=float)[:, wc])
                 if has_aerosol else None)
    gas_phase = functools.partial(_gas_phase, p_rayleigh, p_aerosol)
    gas_medium = _gas_medium(mi, gas, ssa_a, sel, wc, gas_lo, gas_hi, gas_phase)
    scene_dict = _scene_dict(mi, sun_zenith_deg, sun_azimuth_deg, albedo, off, w)
    cloud_box, cloud_g = None, None
    if volume is None:
        scene_dict["gas"] = _box_shape(mi, gas_lo, gas_hi, gas_medium)
    else:
        gas_ref = {"type": "ref", "id": "gas_medium"}
        scene_dict["gas_medium"] = gas_medium
        scene_dict["gas"] = _box_shape(mi, gas_lo, gas_hi, gas_ref)
        lo, hi, cloud_medium, cloud_g = _cloud_medium(mi, volume, gas, ssa_a, sel, wc, asymmetry, cloud_phase,
                                                      gas_phase)
        scene_dict["cloud_medium"] = cloud_medium
        scene_dict["cloud"] = _box_shape(mi, lo, hi, {"type": "ref", "id": "cloud_medium"}, gas_ref)
        cloud_box = (lo, hi)
    scene = mi.load_dict(scene_dict)
    return {"scene": scene, "media": _media_of(scene), "cloud_box": cloud_box, "gas_box": (gas_lo, gas_hi),
            "cloud_g": cloud_g, "channel": channel, "variant": mi.variant()}


def _ground_albedo(volume, surface_albedo, sel):
    """The Lambertian ground's albedo (3,): ``surface_albedo``, or the volume's mean (0.06 without a volume)."""
    if surface_albedo is None:
        surface_albedo = (np.asarray(volume["surface_albedo"].values, dtype=float).reshape(3, -1).mean(axis=1)
                          if volume is not None else 0.06)
    albedo = sel(np.broadcast_to(np.asarray(surface_albedo, dtype=float), (3,)).copy())
    if np.any(~np.isfinite(albedo)) or np.any((albedo < 0) | (albedo > 1)):
        raise SwimInputError(f"surface_albedo must be in [0, 1]; got {surface_albedo!r}")
    return albedo


def _gas_heights(gas):
    """Heights (nh,) [m] of the gas tables' levels."""
    return np.arange(np.asarray(gas.beta_rayleigh, dtype=float).shape[0]) * gas.dh


def _gas_box(gas, w):
    """The offset (3,) [m] of the gas box and the ground from the model domain, and the gas box (lo, hi) [m]:
    ``w`` to either side, 1 x 1 x nh voxels centred on the gas tables' heights."""
    h = _gas_heights(gas)
    dh = float(gas.dh)
    # Mitsuba's triangle intersection is not watertight: a ray that meets a face exactly on the diagonal
    # of its two triangles can miss it (measured: a view whose entry point into the gas box lay on the top
    # face's diagonal saw no Rayleigh sky). Camera rays through the centre of a symmetric scene do exactly
    # that, so the gas box and the ground are centred away from the model domain (their diagonals then
    # pass ~100 km from it), and the cloud box gets one extra empty column on its +x side.
    off = np.array([_GAS_BOX_OFFSET_M[0], _GAS_BOX_OFFSET_M[1], 0.0])
    gas_lo = np.array([-w, -w, -0.5 * dh]) + off
    gas_hi = np.array([w, w, h[-1] + 0.5 * dh]) + off
    return off, gas_lo, gas_hi


def _gas_phase(p_rayleigh, p_aerosol, weight_volume):
    """The gas's phase function: Rayleigh, blended with the aerosol's by ``weight_volume`` where there is aerosol."""
    if p_aerosol is None:
        return dict(p_rayleigh)
    return {"type": "blendphase", "weight": weight_volume, "phase1": dict(p_rayleigh), "phase2": dict(p_aerosol)}


def _gas_medium(mi, gas, ssa_a, sel, wc, gas_lo, gas_hi, gas_phase):
    """The gas box's heterogeneous medium: Rayleigh and background aerosol profiles, the phase weight at ``wc``."""
    beta_r = np.asarray(gas.beta_rayleigh, dtype=float)
    beta_a = np.asarray(gas.beta_aerosol, dtype=float)
    # ozone absorbs only (swim.optics.ozone): extinction without scattering
    sig_t = beta_r + beta_a + np.asarray(gas.ozone_extinction, dtype=float)
    sca_r, sca_a = beta_r, beta_a * ssa_a
    gas_ssa = np.clip(_safe_ratio(sca_r + sca_a, sig_t), 0.0, 1.0)
    gas_waer = _safe_ratio(sca_a, sca_r + sca_a)  # (nh, 3)
    return {
        "type": "heterogeneous",
        "sigma_t": _grid_volume(mi, sel(sig_t)[:, None, None, :], gas_lo, gas_hi, channels=3),
        "albedo": _grid_volume(mi, sel(gas_ssa)[:, None, None, :], gas_lo, gas_hi, channels=3),
        "scale": 1.0,
        "phase": gas_phase(_grid_volume(mi, gas_waer[:, wc][:, None, None], gas_lo, gas_hi)),
    }


def _scene_dict(mi, sun_zenith_deg, sun_azimuth_deg, albedo, off, w):
    """The scene's integrator, sun and ground (a square of half-width ``w`` [m] centred at ``off``)."""
    return {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": -1, "rr_depth": 1 << 30},
        "sun": {"type": "directional", "direction": mi.ScalarVector3f(*(-enu_from_azimuth_zenith(sun_azimuth_deg, sun_zenith_deg))),
                "irradiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},
        "ground": {"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": albedo.tolist()}},
                   "to_world": mi.ScalarTransform4f().translate(mi.ScalarPoint3f(*off)) @ mi.ScalarTransform4f().scale(mi.ScalarPoint3f(w, w, 1.0))},
    }


def _cloud_medium(mi, volume, gas, ssa_a, sel, wc, asymmetry, cloud_phase, gas_phase):
    """The cloud box's medium: hydrometeors, 3-D aerosol and the gas on the cells that hold any.

    Returns the box (lo, hi) [m], the medium dict and the hydrometeors' HG asymmetry parameter.
    """
    x, y = _regular_axes(volume)
    if np.any(np.asarray(volume["terrain_height"].values) > 1.0):
        log.warning("the Mitsuba scene has a flat ground at 0 m; the volume's terrain is ignored")
    levels = np.asarray(volume["level"].values, dtype=float)
    dz = float(volume.attrs["dz"])
    dx = float(x[1] - x[0]) if x.size > 1 else 1.0
    dy = float(y[1] - y[0]) if y.size > 1 else 1.0
    s_c_p, aer_p, lev_p, (i0, j0) = _active_cells(volume, gas, levels, dz)
    e_t_p, ssa, w_cloud, w_aer = _cloud_optics(gas, ssa_a, s_c_p, aer_p, lev_p, wc)
    nz, ny, nx = e_t_p.shape[:3]
    lo = np.array([x[0] + (i0 - 1.5) * dx, y[0] + (j0 - 1.5) * dy, lev_p[0] - 0.5 * dz])
    hi = lo + np.array([nx * dx, ny * dy, nz * dz])
    if levels[0] > 0.5 * dz:
        raise SwimInputError("the optical volume must start at the ground (flat terrain at 0 m)")
    cloud_g = _cloud_asymmetry(volume, asymmetry)
    cloud_medium = {
        "type": "heterogeneous",
        "sigma_t": _grid_volume(mi, sel(e_t_p), lo, hi, channels=3),
        "albedo": _grid_volume(mi, sel(ssa), lo, hi, channels=3),
        "scale": 1.0,
        "phase": {"type": "blendphase", "weight": _grid_volume(mi, w_cloud, lo, hi),
                  "phase1": gas_phase(_grid_volume(mi, w_aer, lo, hi)),
                  "phase2": ({"type": "hg", "g": float(cloud_g)} if cloud_phase is None
                             else _tabphase(cloud_phase, n=CLOUD_TABPHASE_POINTS))},
    }
    return lo, hi, cloud_medium, cloud_g


def _active_cells(volume, gas, levels, dz):
    """The hydrometeor (nz, ny, nx, 3) and 3-D aerosol extinction [m-1] on the cells that hold any, with one empty
    cell around them; their levels (nz,) [m]; and the first kept cell's (i, j) on the padded grid."""
    ext = np.asarray(volume["extinction"].values, dtype=float)  # (species, nz, ny, nx)
    beta_c = ext.sum(axis=0)
    aer3 = np.asarray(volume["aerosol_extinction"].values, dtype=float)[..., None] * np.asarray(gas.angstrom_factor, dtype=float)
    def pad(a):
        # one empty cell on the x and y sides and on top; the bottom level lies half a cell below ground
        # (two on the +x side: see the note on watertightness in _gas_box)
        return np.pad(a, [(0, 1), (1, 1), (1, 2)] + [(0, 0)] * (a.ndim - 3), mode="constant")

    # Zero-pad cloud and 3-D aerosol (one cell on the sides and on top), then keep only the cells that
    # hold any (plus one empty cell around them): a smaller box has fewer null collisions. The gas is
    # recomputed on the kept levels; the bottom level lies half a cell below the ground.
    s_c_p = pad(np.broadcast_to(beta_c[..., None], aer3.shape))
    aer_p = pad(aer3)
    active = np.any((s_c_p > 0) | (aer_p > 0), axis=-1)
    if not active.any():
        active[0, 1:-1, 1:-1] = True
    ks, js, is_ = (np.nonzero(active.any(axis=axes))[0] for axes in ((1, 2), (0, 2), (0, 1)))
    k0, k1 = max(ks[0] - 1, 0), ks[-1] + 1
    j0, j1 = js[0] - 1, js[-1] + 1
    i0, i1 = is_[0] - 1, is_[-1] + 2
    s_c_p = s_c_p[k0:k1 + 1, j0:j1 + 1, i0:i1 + 1]
    aer_p = aer_p[k0:k1 + 1, j0:j1 + 1, i0:i1 + 1]
    lev_p = np.append(levels, levels[-1] + dz)[k0:k1 + 1]
    return s_c_p, aer_p, lev_p, (i0, j0)


def _cloud_optics(gas, ssa_a, s_c_p, aer_p, lev_p, wc):
    """The cloud box's extinction and single-scattering albedo (nz, ny, nx, 3), and its phase weights (nz, ny, nx)
    at channel ``wc``: of the hydrometeors against the rest, and of the aerosol against the gas."""
    h = _gas_heights(gas)
    beta_r = np.asarray(gas.beta_rayleigh, dtype=float)
    beta_a = np.asarray(gas.beta_aerosol, dtype=float)
    br_p = np.stack([np.interp(lev_p, h, beta_r[:, c]) for c in range(3)], axis=-1)[:, None, None, :]
    ba_p = np.stack([np.interp(lev_p, h, beta_a[:, c]) for c in range(3)], axis=-1)[:, None, None, :]
    s_r_p = np.broadcast_to(br_p, s_c_p.shape)
    s_a_p = (ba_p + aer_p) * ssa_a
    e_t_p = s_r_p + ba_p + aer_p + s_c_p
    ssa = np.clip(_safe_ratio(s_r_p + s_a_p + s_c_p, e_t_p), 0.0, 1.0)
    # The blend weight is interpolated trilinearly, but the true weight is the ratio of the interpolated
    # coefficients: across a cloud edge (cloud voxel next to a clear one) interpolating the ratio would
    # give the cloud's own scattering a ~50 % Rayleigh phase function (measured: -13 % transmission and
    # +13 % reflection of a tau = 10 slab whose base and top ramp over one level). The weight is
    # therefore dilated by one voxel: exact wherever cloud scattering dominates, and it only gives the
    # (negligible, tau ~ 1e-4 per cell) gas scattering next to cloud the cloud's phase function.
    from scipy.ndimage import maximum_filter

    w_cloud = maximum_filter(_safe_ratio(s_c_p, s_r_p + s_a_p + s_c_p)[..., wc], size=3, mode="nearest")
    w_aer = _safe_ratio(s_a_p, s_r_p + s_a_p)[..., wc]
    return e_t_p, ssa, w_cloud, w_aer


def _media_of(scene):
    """The scene's media by name: ``gas`` (the box that reaches the top of the atmosphere) and ``cloud``."""
    media = {}
    for shape in scene.shapes():
        if shape.is_medium_transition():
            bbox = shape.bbox()
            key = "gas" if float(bbox.max[2]) > 0.5 * ATMOSPHERE_TOP_M else "cloud"
            media[key] = shape.interior_medium()
    return media


def directions_from_angles(view_zenith_deg, view_azimuth_deg):
    """Unit view directions (n, 3) (east, north, up) from zenith and azimuth [deg] (docs/frames.md)."""
    return enu_from_azimuth_zenith(view_azimuth_deg, view_zenith_deg)


# --------------------------------------------------------------------------------------------------------
# tracing
# --------------------------------------------------------------------------------------------------------
def _inside(p, box):
    lo, hi = box
    return bool(np.all(p > lo) and np.all(p < hi))


def wavefront_seed(seed, k):
    """Sampler seed of wavefront k of a run with seed ``seed``: seed 1000003 + k, wrapped to Mitsuba's 32-bit
    seeds (unchanged below 2^32, so references made with small seeds stay reproducible)."""
    return (int(seed) * 1000003 + int(k)) % 2**32


def _trace(built, origin, dirs, spp, seed):
    """Per-ray mean and standard error (n, 3) of Mitsuba's radiance I [sr-1] for unit irradiance."""
    mi = select_variant(built["variant"])
    scene, media = built["scene"], built["media"]
    origin = np.asarray(origin, dtype=float)
    dirs = np.asarray(dirs, dtype=float)
    n = dirs.shape[0]
    gas_lo, gas_hi = built["gas_box"]
    top = float(gas_hi[2])
    if origin[2] >= top:
        # start the rays just above the atmosphere (float32 positions stay accurate)
        if np.any(dirs[:, 2] >= 0):
            raise SwimInputError("an observer above the atmosphere must look down")
        t = (origin[2] - (top + 10.0)) / -dirs[:, 2]
        origins = origin[None, :] + t[:, None] * dirs
        medium = None
    else:
        origins = np.broadcast_to(origin, dirs.shape)
        if built["cloud_box"] is not None and _inside(origin, built["cloud_box"]):
            medium = media["cloud"]
        elif _inside(origin, built["gas_box"]):
            medium = media["gas"]
        else:
            raise SwimInputError("the observer must be inside the atmosphere or above it")
    integrator = scene.integrator()
    sums = np.zeros((n, 3))
    sums2 = np.zeros((n, 3))
    if mi.variant().startswith("llvm"):
        import drjit as dr

        total = n * spp
        o_rep = np.repeat(origins, spp, axis=0)
        d_rep = np.repeat(dirs, spp, axis=0)
        idx = np.repeat(np.arange(n), spp)
        for k, start in enumerate(range(0, total, _WAVEFRONT)):
            stop = min(total, start + _WAVEFRONT)
            m = stop - start
            sampler = mi.load_dict({"type": "independent"})
            sampler.seed(wavefront_seed(seed, k), m)
            o = mi.Point3f(*(np.ascontiguousarray(o_rep[start:stop, i], dtype=np.float32) for i in range(3)))
            d = mi.Vector3f(*(np.ascontiguousarray(d_rep[start:stop, i], dtype=np.float32) for i in range(3)))
            ray = mi.RayDifferential3f(mi.Ray3f(o, d))
            spec, _, _ = integrator.sample(scene, sampler, ray, medium, True)
            dr.eval(spec)
            val = np.stack([np.asarray(spec[i]) for i in range(3)], axis=-1).astype(float)
            if val.shape[0] != m:
                val = np.broadcast_to(val, (m, 3))
            val = np.nan_to_num(val)
            np.add.at(sums, idx[start:stop], val)
            np.add.at(sums2, idx[start:stop], val**2)
    else:
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(int(seed) % 2**32, 1)
        for i in range(n):
            ray = mi.RayDifferential3f(mi.Ray3f(mi.Point3f(*origins[i]), mi.Vector3f(*dirs[i])))
            for _ in range(spp):
                spec, _, _ = integrator.sample(scene, sampler, ray, medium, True)
                v = np.array([spec[0], spec[1], spec[2]], dtype=float)
                if np.all(np.isfinite(v)):
                    sums[i] += v
                    sums2[i] += v * v
    mean = sums / spp
    var = np.maximum(sums2 / spp - mean**2, 0.0)
    return mean, np.sqrt(var / max(spp - 1, 1))


def mitsuba_radiance(volume, sun_zenith_deg, sun_azimuth_deg, observer, view_directions, spp=256,
                     aerosol: AerosolBackground = AerosolBackground(), surface_albedo=None, spectral="auto",
                     asymmetry=None, seed=0, variant=None, atmosphere_half_width_m=2.0e6, cloud_phase=None):
    """Monte Carlo radiance L' (paper Eq. 2) seen from an observer along given view directions.

    Parameters
    ----------
    volume : xarray.Dataset or None
        Optical volume (:func:`swim.optics.volume.build_optical_volume`) or ``None`` (clear sky).
    sun_zenith_deg, sun_azimuth_deg : float
        Sun zenith [deg] and azimuth [deg, clockwise from north].
    observer : array_like
        (x east, y north, z height above sea level) [m] in the grid's horizontal coordinates; above
        100 km the rays start at the top of the atmosphere.
    view_directions : array_like
        Shape (n, 3): unit look directions (east, north, up), pointing away from the observer.
    spp : int
        Paths per view direction.
    aerosol : AerosolBackground
        Background aerosol (``aod_550=0`` for a Rayleigh atmosphere).
    surface_albedo : float or array_like, optional
        Lambertian ground albedo [-]; default: the volume's mean (0.06 without a volume).
    spectral : {"auto", "rgb", "mono"}
        One RGB pass or three monochromatic passes; ``auto``: RGB without aerosol, mono with.
    asymmetry : dict, optional
        HG g per species (:data:`HYDROMETEOR_ASYMMETRY`).
    seed : int
        Random seed.
    variant : str, optional
        Mitsuba variant (:func:`select_variant`).
    atmosphere_half_width_m : float
        Half-width of the plane-parallel atmosphere [m].
    cloud_phase : callable, optional
        The hydrometeors' tabulated phase function (:func:`build_mitsuba_scene`).

    Returns
    -------
    dict
        ``radiance`` (n, 3) L' = 4 pi I at 615/546/450 nm (no direct sun); ``stderr`` (n, 3) its Monte Carlo
        standard error; ``spp``; ``seconds``; ``variant``; ``cloud_g``; ``spectral``.
    """
    dirs = np.asarray(view_directions, dtype=float).reshape(-1, 3)
    dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    if spectral == "auto":
        spectral = "mono" if (aerosol.aod_550 > 0 or (volume is not None and np.any(volume["aerosol_extinction"].values > 0))) else "rgb"
    if spectral not in ("rgb", "mono"):
        raise SwimInputError(f"spectral must be 'auto', 'rgb' or 'mono'; got {spectral!r}")
    t0 = _time.perf_counter()
    radiance, stderr = np.zeros((dirs.shape[0], 3)), np.zeros((dirs.shape[0], 3))
    channels = [None] if spectral == "rgb" else [0, 1, 2]
    built = None
    for c in channels:
        built = build_mitsuba_scene(volume, sun_zenith_deg, sun_azimuth_deg, aerosol=aerosol, surface_albedo=surface_albedo,
                                    channel=c, asymmetry=asymmetry, atmosphere_half_width_m=atmosphere_half_width_m,
                                    variant=variant, cloud_phase=cloud_phase)
        mean, err = _trace(built, observer, dirs, int(spp), seed + (0 if c is None else 7919 * (c + 1)))
        if c is None:
            radiance, stderr = mean, err
        else:
            radiance[:, c], stderr[:, c] = mean[:, c], err[:, c]
    seconds = _time.perf_counter() - t0
    log.info("Mitsuba (%s, %s): %d views x %d spp in %.1f s", built["variant"], spectral, dirs.shape[0], spp, seconds)
    return {"radiance": 4 * np.pi * radiance, "stderr": 4 * np.pi * stderr, "spp": int(spp), "seconds": seconds,
            "variant": built["variant"], "cloud_g": built["cloud_g"], "spectral": spectral}


# --------------------------------------------------------------------------------------------------------
# swim against Mitsuba: image pairs and metrics
# --------------------------------------------------------------------------------------------------------
#: The RICO comparison cases: LES file, view, sun zenith [deg], camera, camera options, observer height [m].
RICO_CASES = {
    "rico_ground_sza30": {"les": "rico122x106x39.txt", "view": "ground", "sun_zenith": 30.0},
    "rico_ground_sza60": {"les": "rico122x106x39.txt", "view": "ground", "sun_zenith": 60.0},
    "rico_space_sza30": {"les": "rico122x106x39.txt", "view": "space", "sun_zenith": 30.0},
    "rico_space_sza60": {"les": "rico122x106x39.txt", "view": "space", "sun_zenith": 60.0},
}
#: Shared settings of the RICO cases: sun azimuth [deg], the all-sky size and maximum view zenith [deg],
#: the satellite image size and height [m], the atmosphere (Rayleigh only) and the sun exclusion [deg].
RICO_SETTINGS = {
    "sun_azimuth": 135.0,
    "allsky_size": 41,
    "ground_height_m": 2.0,
    "max_view_zenith_deg": 75.0,
    "space_width": 32,
    "space_height": 28,
    "space_height_m": 700.0e3,
    "space_half_width_m": 1200.0,
    "aod_550": 0.0,
    # the cached Mitsuba references hold no ozone: both sides of the comparison leave it out (ozone's absorption
    # is validated against DISORT; regenerate the references with ozone_du to compare with it)
    "ozone_du": 0.0,
    "sun_exclusion_deg": 5.0,
}


def swim_view(scene, view, sun_zenith_deg, settings=None, march_settings=None):
    """Render a RICO-style case with swim and select the pixels to compare.

    Parameters
    ----------
    scene : xarray.Dataset
        Canonical scene (e.g. :func:`swim.read_shdom_les`).
    view : {"ground", "space"}
        All-sky camera at ``ground_height_m`` above the reference point, or a perspective camera at
        ``space_height_m`` looking straight down (swim's default satellite view).
    sun_zenith_deg : float
        Sun zenith angle [deg].
    settings : dict, optional
        Overrides of :data:`RICO_SETTINGS`.
    march_settings : swim.rt.march_settings.MarchSettings, optional
        Renderer settings (default: the renderer's with ``cloud_scattering="albers2020"``, the paper's method, whose
        own phase functions these references compare; the 3-D method against references with its phase
        function: :mod:`swim.validation.clouds3d`).

    Returns
    -------
    dict
        ``image`` (3, ny, nx) swim L' without the sun's disk (NaN where not compared); ``mask`` (ny, nx) the
        compared pixels; ``directions`` (n, 3) their view directions (east, north, up); ``observer`` (3,) [m]
        in the grid frame (x, y, height above sea level); ``tau`` (ny, nx) swim's hydrometeor optical depth
        along the line of sight; ``dataset`` the rendered :class:`xarray.Dataset`.
    """
    from ..pipeline import render


    cfg = dict(RICO_SETTINGS, **(settings or {}))
    aerosol = AerosolBackground(aod_550=float(cfg["aod_550"]), ozone_du=float(cfg.get("ozone_du", 0.0)))
    if view == "ground":
        camera, options, height = "allsky", {"size": int(cfg["allsky_size"])}, float(cfg["ground_height_m"])
    elif view == "space":
        # looking straight down, the field of view spanning the domain's x extent at the ground, so that
        # every pixel sees the model domain (outside it swim has no clouds and no cloud shadows)
        height = float(cfg["space_height_m"])
        x = np.asarray(scene["x"].values, dtype=float) if "x" in scene.coords else np.array([-1.0, 1.0]) * float(cfg["space_half_width_m"])
        fov = 2.0 * np.degrees(np.arctan(0.5 * float(np.ptp(x)) / height))
        camera = "perspective"
        options = {"width": int(cfg["space_width"]), "height": int(cfg["space_height"]), "fov_deg": fov,
                   "view_azimuth_deg": 0.0, "view_zenith_deg": 180.0}
    else:
        raise SwimInputError(f"view must be 'ground' or 'space'; got {view!r}")
    ds = render(scene, camera=camera, camera_options=options, sun_zenith=float(sun_zenith_deg),
                sun_azimuth=float(cfg["sun_azimuth"]), aerosol=aerosol, height=height,
                settings=reference_settings(paper_method_settings() if march_settings is None else march_settings))
    sky = radiance_without_sun_disk(ds)
    vz = ds.variables["view_zenith"].values.astype(float)  # Variables: a DataArray is made in ~30 us
    va = ds.variables["view_azimuth"].values.astype(float)
    d = directions_from_angles(vz, va)
    sun = enu_from_azimuth_zenith(float(ds.attrs["sun_azimuth_deg"]), float(ds.attrs["sun_zenith_deg"]))
    scat = np.degrees(np.arccos(np.clip(np.nan_to_num(d) @ sun, -1.0, 1.0)))
    mask = np.isfinite(vz) & np.all(np.isfinite(sky), axis=0) & (scat > float(cfg["sun_exclusion_deg"]))
    if view == "ground":
        mask &= vz <= float(cfg["max_view_zenith_deg"])
    image = np.where(mask[None], sky, np.nan)
    observer = np.array([0.0, 0.0, float(ds.attrs["observer_height_asl_m"])])
    tau = ds.variables["tau_hydrometeor"].values.astype(float)
    return {"image": image, "mask": mask, "directions": d[mask], "observer": observer, "dataset": ds,
            "aerosol": aerosol, "tau": tau}


def compare_images(test, reference, mask=None):
    """Per-channel agreement of two radiance images (paper Eq. 37 and relative errors).

    Parameters
    ----------
    test, reference : array_like
        Shape (3, ny, nx) or (3, n): L' of swim and of the reference; NaN pixels are ignored.
    mask : array_like of bool, optional
        Pixels to compare (default: finite in both).

    Returns
    -------
    dict
        Per channel (3,): ``pearson_r`` (Eq. 37), ``mean_abs_rel``, ``median_abs_rel``, ``p90_abs_rel``,
        ``bias`` (median of test / reference - 1); ``n_pixels``.
    """
    a = np.asarray(test, dtype=float).reshape(3, -1)
    b = np.asarray(reference, dtype=float).reshape(3, -1)
    ok = np.all(np.isfinite(a), axis=0) & np.all(np.isfinite(b), axis=0) & np.all(b > 0, axis=0)
    if mask is not None:
        ok &= np.asarray(mask, dtype=bool).reshape(-1)
    a, b = a[:, ok], b[:, ok]
    rel = a / b - 1.0
    return {
        "pearson_r": np.array([np.corrcoef(a[c], b[c])[0, 1] for c in range(3)]),
        "mean_abs_rel": np.mean(np.abs(rel), axis=1),
        "median_abs_rel": np.median(np.abs(rel), axis=1),
        "p90_abs_rel": np.percentile(np.abs(rel), 90, axis=1),
        "bias": np.median(rel, axis=1),
        "n_pixels": int(ok.sum()),
    }


def _diverging(rel, limit):
    """RGB uint8 (ny, nx, 3) of relative differences: blue (negative) - white - red (positive), black = NaN."""
    t = np.clip(np.nan_to_num(rel) / limit, -1.0, 1.0)
    r = np.where(t < 0, 1.0 + t, 1.0)
    g = 1.0 - np.abs(t)
    b = np.where(t > 0, 1.0 - t, 1.0)
    rgb = np.stack([r, g, b], axis=-1)
    rgb = np.where(np.isfinite(rel)[..., None], rgb, 0.0)
    return (255 * rgb + 0.5).astype(np.uint8)


def comparison_png(swim_image, reference_image, path, title="", white_level=None, scale=None, limit=0.5):
    """Write a PNG: swim | Mitsuba | relative difference (546 nm), with a caption.

    Parameters
    ----------
    swim_image, reference_image : array_like
        Shape (3, ny, nx): L' at 615/546/450 nm; NaN pixels (not compared) are drawn black.
    path : str or os.PathLike
        Output file.
    title : str
        Caption line.
    white_level : float, optional
        L' shown as white (default: 99th percentile of the reference, at least 0.5).
    scale : int, optional
        Integer up-scaling of the small images (default: to ~240 pixels wide).
    limit : float
        Relative difference shown at full colour [-] (swim / Mitsuba - 1 = +-limit).

    Returns
    -------
    pathlib.Path
    """
    from PIL import Image, ImageDraw

    from ..color import solar_relative_to_srgb8

    a = np.asarray(swim_image, dtype=float)
    b = np.asarray(reference_image, dtype=float)
    ny, nx = a.shape[1:]
    if white_level is None:
        white_level = max(float(np.nanpercentile(b[1], 99)), 0.5)
    scale = scale or max(1, int(round(240 / nx)))
    rel = a[1] / b[1] - 1.0
    panels = [solar_relative_to_srgb8(np.where(np.isfinite(a), a, np.nan), white_level=white_level),
              solar_relative_to_srgb8(np.where(np.isfinite(b), b, np.nan), white_level=white_level),
              _diverging(rel, limit)]
    panels = [Image.fromarray(np.asarray(p, dtype=np.uint8)).resize((nx * scale, ny * scale), Image.NEAREST) for p in panels]
    gap, top, bottom = 8, 16, 34
    w = sum(p.size[0] for p in panels) + gap * 4
    out = Image.new("RGB", (w, ny * scale + top + bottom), (255, 255, 255))
    draw = ImageDraw.Draw(out)
    x = gap
    labels = ["swim", "Mitsuba 3 (Monte Carlo)", f"swim/Mitsuba - 1 at 546 nm (+-{limit:.0%})"]
    for p, label in zip(panels, labels):
        out.paste(p, (x, top))
        draw.text((x, 2), label, fill=(0, 0, 0))
        x += p.size[0] + gap
    # colour bar under the difference panel
    x0 = w - gap - panels[2].size[0]
    bar = _diverging(np.linspace(-limit, limit, panels[2].size[0])[None, :].repeat(6, axis=0), limit)
    out.paste(Image.fromarray(bar), (x0, top + ny * scale + 4))
    draw.text((x0, top + ny * scale + 11), f"-{limit:.0%}", fill=(0, 0, 0))
    draw.text((x0 + panels[2].size[0] - 28, top + ny * scale + 11), f"+{limit:.0%}", fill=(0, 0, 0))
    draw.text((gap, top + ny * scale + 11), f"{title}  (white = L' {white_level:.2f})", fill=(0, 0, 0))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    out.save(path, format="PNG")
    return path


# --------------------------------------------------------------------------------------------------------
# cached RICO references
# --------------------------------------------------------------------------------------------------------
#: Default folder of the cached references (tests/data/validation of the source tree).
REFERENCE_DIR = Path(__file__).resolve().parents[3] / "tests" / "data" / "validation"
#: Line-of-sight hydrometeor optical depth [-] above which a pixel counts as cloudy in the table rows.
CLOUDY_TAU = 1.0
#: Paths per pixel of the cached RICO references, per view.
RICO_SPP = {"ground": 2048, "space": 1024}


def make_rico_reference(case, les_dir, spp=None, seed=1, out_dir=None, variant=None):
    """Run the Mitsuba reference of one RICO case and cache it as ``<out_dir>/<case>.npz``.

    Parameters
    ----------
    case : str
        Key of :data:`RICO_CASES`.
    les_dir : str or os.PathLike
        Folder holding the LES files (``../shared/data/les``).
    spp : int, optional
        Paths per pixel (default :data:`RICO_SPP` of the view).
    seed : int
        Random seed.
    out_dir : str or os.PathLike, optional
        Output folder (default :data:`REFERENCE_DIR`).
    variant : str, optional
        Mitsuba variant (:func:`select_variant`).

    Returns
    -------
    pathlib.Path
        The .npz file: ``mitsuba``, ``stderr`` (3, ny, nx) float32 L' (NaN outside the compared pixels),
        ``swim`` (3, ny, nx) swim's image at generation time, ``tau`` its line-of-sight hydrometeor optical
        depth, ``mask``; and the inputs (``case``, ``les``,
        ``view``, ``sun_zenith``, ``settings`` as JSON, ``spp``, ``seed``, ``variant``, ``mitsuba_version``,
        ``cloud_g``, ``seconds``, ``swim_version``, ``created``).
    """
    import json
    from datetime import datetime, timezone

    import mitsuba

    from .. import __version__
    from ..io.les import read_shdom_les
    from ..optics.volume import build_optical_volume

    spec = RICO_CASES[case]
    spp = int(spp or RICO_SPP[spec["view"]])
    scene = read_shdom_les(Path(les_dir) / spec["les"], reference_lat=0.0, reference_lon=0.0)
    sv = swim_view(scene, spec["view"], spec["sun_zenith"])
    volume = build_optical_volume(scene)
    out = mitsuba_radiance(volume, spec["sun_zenith"], RICO_SETTINGS["sun_azimuth"], sv["observer"], sv["directions"],
                           spp=spp, aerosol=sv["aerosol"], seed=seed, variant=variant)
    ref = np.full(sv["image"].shape, np.nan, dtype=np.float32)
    err = np.full(sv["image"].shape, np.nan, dtype=np.float32)
    ref[:, sv["mask"]] = out["radiance"].T
    err[:, sv["mask"]] = out["stderr"].T
    out_dir = Path(out_dir or REFERENCE_DIR)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{case}.npz"
    np.savez_compressed(
        path, mitsuba=ref, stderr=err, swim=sv["image"].astype(np.float32), mask=sv["mask"], case=case,
        tau=np.where(sv["mask"], sv["tau"], np.nan).astype(np.float32),
        les=spec["les"], view=spec["view"], sun_zenith=float(spec["sun_zenith"]),
        settings=json.dumps(RICO_SETTINGS), spp=spp, seed=int(seed), variant=out["variant"],
        mitsuba_version=mitsuba.__version__, cloud_g=float(out["cloud_g"]), seconds=float(out["seconds"]),
        swim_version=__version__, created=datetime.now(timezone.utc).isoformat(timespec="seconds"),
    )
    log.info("%s: %d pixels x %d spp in %.0f s -> %s", case, int(sv["mask"].sum()), spp, out["seconds"], path)
    return path


def load_rico_reference(case, ref_dir=None):
    """Load a cached RICO reference (:func:`make_rico_reference`) as a dict of numpy values."""
    path = Path(ref_dir or REFERENCE_DIR) / f"{case}.npz"
    with np.load(path, allow_pickle=False) as z:
        return {k: (z[k] if z[k].ndim else z[k].item()) for k in z.files}


def rico_table_rows(les_dir=None, ref_dir=None, cases=None, render=True, march_settings=None, images=True):
    """Rows of the RICO comparison table: swim against the cached Mitsuba references.

    Parameters
    ----------
    les_dir : str or os.PathLike, optional
        Folder of the LES files; needed when ``render`` (swim renders the case now).
    ref_dir : str or os.PathLike, optional
        Folder of the cached references (default :data:`REFERENCE_DIR`).
    cases : iterable of str, optional
        Keys of :data:`RICO_CASES` (default: all whose reference file exists).
    render : bool
        Render swim now (default); otherwise use the swim image stored with the reference.
    march_settings : swim.rt.march_settings.MarchSettings, optional
        Renderer settings (default: those of :func:`swim_view`).
    images : bool
        Include the image pair (``swim``, ``mitsuba`` (3, ny, nx)) in each row.

    Returns
    -------
    list of dict
        One row per case and wavelength: ``case``, ``view``, ``sun_zenith`` [deg], ``wavelength_nm``,
        ``n_pixels``, ``median_abs_rel``, ``p90_abs_rel``, ``mean_abs_rel``, ``bias`` [-], ``pearson_r``,
        ``mc_noise`` (median relative standard error of the reference) [-], ``spp``; the same statistics over
        the cloudy pixels (swim's line-of-sight hydrometeor optical depth > :data:`CLOUDY_TAU`):
        ``n_cloudy``, ``cloudy_mean_abs_rel``, ``cloudy_median_abs_rel``, ``cloudy_bias``,
        ``cloudy_pearson_r``; with ``images`` also ``swim`` and ``mitsuba``.
    """
    from ..io.les import read_shdom_les

    ref_dir = Path(ref_dir or REFERENCE_DIR)
    cases = [c for c in (cases or RICO_CASES) if (ref_dir / f"{c}.npz").is_file()]
    rows, scenes = [], {}
    for case in cases:
        ref = load_rico_reference(case, ref_dir)
        if render:
            if les_dir is None:
                raise SwimInputError("rico_table_rows(render=True) needs les_dir")
            if ref["les"] not in scenes:
                scenes[ref["les"]] = read_shdom_les(Path(les_dir) / ref["les"], reference_lat=0.0, reference_lon=0.0)
            sv = swim_view(scenes[ref["les"]], ref["view"], ref["sun_zenith"], march_settings=march_settings)
            if sv["mask"].shape != ref["mask"].shape or np.any(sv["mask"] != ref["mask"]):
                raise SwimInputError(f"{case}: the rendered pixels differ from the cached reference's; regenerate it")
            image, tau = sv["image"], sv["tau"]
        else:
            image, tau = ref["swim"].astype(float), ref["tau"].astype(float)
        m = compare_images(image, ref["mitsuba"], ref["mask"])
        cloudy = ref["mask"] & (np.nan_to_num(tau) > CLOUDY_TAU)
        mc = compare_images(image, ref["mitsuba"], cloudy)
        noise = np.nanmedian((ref["stderr"] / ref["mitsuba"]).reshape(3, -1), axis=1)
        for c, wl in enumerate(WAVELENGTHS_NM):
            row = {"case": case, "view": ref["view"], "sun_zenith": float(ref["sun_zenith"]), "wavelength_nm": float(wl),
                   "n_pixels": m["n_pixels"], "median_abs_rel": float(m["median_abs_rel"][c]),
                   "p90_abs_rel": float(m["p90_abs_rel"][c]), "mean_abs_rel": float(m["mean_abs_rel"][c]),
                   "bias": float(m["bias"][c]), "pearson_r": float(m["pearson_r"][c]), "mc_noise": float(noise[c]),
                   "spp": int(ref["spp"]), "n_cloudy": mc["n_pixels"],
                   "cloudy_mean_abs_rel": float(mc["mean_abs_rel"][c]), "cloudy_median_abs_rel": float(mc["median_abs_rel"][c]),
                   "cloudy_bias": float(mc["bias"][c]), "cloudy_pearson_r": float(mc["pearson_r"][c])}
            if images:
                row["swim"], row["mitsuba"] = image, ref["mitsuba"].astype(float)
            rows.append(row)
    return rows
