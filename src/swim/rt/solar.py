"""Step 1a: optical depth towards the sun at every grid point and the scalar irradiance (Eqs. 4-8).

Instead of one ray per grid point, the optical depth is swept level by level from the top of the grid
down, along the sun direction (a semi-Lagrangian sweep): the optical depth at level k is the one at level
k + 1, bilinearly interpolated at the point where the sun ray through (k, j, i) crosses level k + 1, plus
the integral of the extinction over the slanted segment in between. The segment is split into sub-steps
no longer than one grid cell horizontally, so clouds are not skipped under a low sun. Outside the domain
the air is taken as free of clouds (only the gas, handled in Step 2, attenuates there).

Three fields are swept together: the total extinction (hydrometeors and 3-D aerosol), the extinction
weighted by each species' backscatter fraction b (so that ``b tau_s = sum_s b_s tau_s`` in Eqs. 4-5),
and an opaque terrain occupancy field, which makes mountains cast shadows.
"""

from __future__ import annotations

import functools
import logging

import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr

from ..constants import BACKSCATTER_FRACTION, SPECIES

log = logging.getLogger(__name__)

#: Optical depth of terrain per fully occupied cell height crossed [-] (makes terrain opaque).
TERRAIN_OPACITY_PER_CELL = 8.0
#: Lowest sine of the solar elevation used for the sweep direction (the sun below ~0.6 deg elevation is
#: treated as grazing; the gas tables of Step 2 put such points into the earth's shadow anyway).
MIN_SUN_ELEVATION_SINE = 0.01


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
    t1 = 1.0 / (1.0 + b_tau)
    t2 = 1.0 / (1.0 + b_tau * mu0)
    return jnp.maximum(t1, t2 * mu0)


def _bilinear_zero_outside(field, jj, ii):
    """Bilinear sample of (C, ny, nx) fields at fractional (jj, ii) of shape (ny, nx); zero outside."""
    ny, nx = field.shape[-2:]
    inside = (jj >= 0) & (jj <= ny - 1) & (ii >= 0) & (ii <= nx - 1)
    j0 = jnp.clip(jnp.floor(jj), 0, ny - 2).astype(jnp.int32)
    i0 = jnp.clip(jnp.floor(ii), 0, nx - 2).astype(jnp.int32)
    fj = jnp.clip(jj - j0, 0.0, 1.0)
    fi = jnp.clip(ii - i0, 0.0, 1.0)
    v = (field[..., j0, i0] * (1 - fj) * (1 - fi) + field[..., j0, i0 + 1] * (1 - fj) * fi
         + field[..., j0 + 1, i0] * fj * (1 - fi) + field[..., j0 + 1, i0 + 1] * fj * fi)
    return jnp.where(inside, v, 0.0)


#: Levels integrated directly before the optical depth of a higher level is reused (bounds the numerical
#: diffusion of the semi-Lagrangian sweep: one bilinear interpolation per block instead of per level).
DIRECT_LEVELS = 16


@functools.partial(jax.jit, static_argnames=("n_sub", "block"))
def _sweep(fields, di, dj, path_per_level, n_sub, block=DIRECT_LEVELS):
    """Sweep (C, nk, ny, nx) extinction fields along the sun; returns optical depths of the same shape.

    tau(k) = integral of the extinction from level k up to level min(k + block, top) along the sun ray
    (sampled directly, n_sub points per level) + tau of that level, bilinearly interpolated where the
    ray crosses it.
    """
    c, nk, ny, nx = fields.shape
    jj, ii = jnp.meshgrid(jnp.arange(ny, dtype=jnp.float32), jnp.arange(nx, dtype=jnp.float32), indexing="ij")
    ts = (jnp.arange(n_sub, dtype=jnp.float32) + 0.5) / n_sub

    def level(k, taus):
        def one_level(m, acc):
            lo = jnp.minimum(k + m, nk - 2)
            lower = jax.lax.dynamic_index_in_dim(fields, lo, axis=1, keepdims=False)
            upper = jax.lax.dynamic_index_in_dim(fields, lo + 1, axis=1, keepdims=False)
            active = (k + m + 1) <= (nk - 1)

            def sub(a, t):
                shift = m + t
                lo_v = _bilinear_zero_outside(lower, jj + shift * dj, ii + shift * di)
                up_v = _bilinear_zero_outside(upper, jj + shift * dj, ii + shift * di)
                return a + (1 - t) * lo_v + t * up_v, None

            seg, _ = jax.lax.scan(sub, jnp.zeros_like(acc), ts)
            return acc + jnp.where(active, seg, 0.0)

        direct = jax.lax.fori_loop(0, block, one_level, jnp.zeros((c, ny, nx), fields.dtype))
        top = jnp.minimum(k + block, nk - 1)
        above = jax.lax.dynamic_index_in_dim(taus, top, axis=0, keepdims=False)
        n_levels = (top - k).astype(jnp.float32)
        tau = _bilinear_zero_outside(above, jj + n_levels * dj, ii + n_levels * di) + direct * (path_per_level / n_sub)
        return jax.lax.dynamic_update_index_in_dim(taus, tau, k, axis=0)

    taus = jnp.zeros((nk, c, ny, nx), fields.dtype)
    taus = jax.lax.fori_loop(0, nk - 1, lambda n, t: level(nk - 2 - n, t), taus)
    return taus.transpose(1, 0, 2, 3)


def solar_transmittance(volume: xr.Dataset, sun_direction_scene) -> xr.Dataset:
    """Step 1a: optical depth towards the sun and cloud transmittance T at every grid point.

    Parameters
    ----------
    volume : xarray.Dataset
        Optical volume from :func:`swim.optics.volume.build_optical_volume`.
    sun_direction_scene : array_like
        Shape (3,): unit vector towards the sun in the scene frame (ENU at the reference point).

    Returns
    -------
    xarray.Dataset
        ``tau_sun`` (level, y, x) [-]: optical depth of hydrometeors and 3-D aerosol towards the sun;
        ``b_tau_sun`` (level, y, x) [-]: its backscatter-weighted sum; ``terrain_shadow`` (level, y, x)
        [-]: transmittance of the terrain (0 in a mountain's shadow); ``transmittance`` (level, y, x)
        [-]: T of Eq. 6 times the terrain shadow, i.e. E / (e^{-tau_R} E_TOA) of Eq. 8.

    References
    ----------
    Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Sect. 3.4, Eqs. 4-8.
    """
    sun = np.asarray(sun_direction_scene, dtype=float)
    sin_elev = max(sun[2], MIN_SUN_ELEVATION_SINE)
    dz = float(volume.attrs["dz"])
    matrix = np.asarray(volume.attrs["affine_matrix"]).reshape(2, 2)
    # Horizontal displacement [m] while climbing one level along the sun, in index units.
    horiz = sun[:2] / sin_elev * dz
    di, dj = np.linalg.solve(matrix, horiz)
    n_sub = int(np.clip(np.ceil(max(abs(di), abs(dj), 1.0)), 1, 256))
    path_per_level = dz / sin_elev  # path length [m] along the (unit) sun vector per level

    beta = volume["extinction"].values
    aerosol = volume["aerosol_extinction"].values
    b = np.array([BACKSCATTER_FRACTION[s] for s in SPECIES])[:, None, None, None]
    total = beta.sum(axis=0) + aerosol
    b_weighted = (b * beta).sum(axis=0) + BACKSCATTER_FRACTION["aerosol"] * aerosol
    levels = volume["level"].values
    terrain = volume["terrain_height"].values
    # Zero at and above the surface (a sunlit slope does not shade itself), 1 a full level below it.
    occupancy = np.clip((terrain[None] - levels[:, None, None]) / dz, 0.0, 1.0) * (TERRAIN_OPACITY_PER_CELL / dz)
    fields = jnp.asarray(np.stack([total, b_weighted, occupancy]).astype(np.float32))

    taus = np.asarray(_sweep(fields, float(di), float(dj), float(path_per_level), n_sub))
    log.info("Step 1a sweep: %d sub-steps per level, max tau_sun %.1f", n_sub, float(taus[0].max()))
    mu0 = max(float(sun[2]), 0.0)
    cloud_t = np.asarray(transmittance_stephens1978(jnp.asarray(taus[1]), max(mu0, MIN_SUN_ELEVATION_SINE)))
    shadow = np.exp(-taus[2])
    dims = ("level", "y", "x")
    return xr.Dataset(
        {
            "tau_sun": (dims, taus[0], {"units": "1", "long_name": "optical depth towards the sun (Step 1a)"}),
            "b_tau_sun": (dims, taus[1], {"units": "1"}),
            "terrain_shadow": (dims, shadow, {"units": "1"}),
            "transmittance": (dims, cloud_t * shadow, {"units": "1", "long_name": "T of Eq. 6 times terrain shadow"}),
        },
        coords={"level": volume["level"]},
    )
