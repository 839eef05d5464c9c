"""The 3-D cloud scattering's terms in the JAX kernel (``cloud_scattering="discrete_ordinates"``, :mod:`swim.rt.clouds`).

The twins of the numba kernel's ``_cloud_sources`` and ``_ratio_above`` (:mod:`swim.rt.march_cpu`), for rays marched
in lockstep: at a step in the grid, the hydrometeors' single scattering of the direct beam with the split phase
functions (the TMS correction of Nakajima and Tanaka 1988) and the source of the diffuse solution's spherical-harmonic
moments (:mod:`swim.rt.diffuse_field`); above the grid, the diffuse radiance's ratio to the clear sky's. Differentiable
in the volume's extinction and the diffuse field (no integer state but the cells' indices).

References
----------
Nakajima, T. and Tanaka, M. (1988): Algorithms for radiative intensity calculations in moderately thick atmospheres
using a truncation approximation, JQSRT 40, 51-69, doi:10.1016/0022-4073(88)90031-3.
Evans, K. F. (1998): The spherical harmonics discrete ordinate method for three-dimensional atmospheric radiative
transfer, J. Atmos. Sci. 55, 429-446, doi:10.1175/1520-0469(1998)055<0429:TSHDOM>2.0.CO;2.
"""

from __future__ import annotations

import jax.numpy as jnp


__all__ = ["clamped_trilinear", "cloud_sources", "ratio_above_grid"]


def _corner_indices(f, n):
    """Lower corner (int32), upper corner and upper weight of fractional indices ``f`` clamped to [0, n - 1]."""
    f = jnp.clip(f, 0.0, n - 1.0)
    lo = jnp.minimum(f.astype(jnp.int32), max(n - 2, 0))
    return lo, jnp.minimum(lo + 1, n - 1), f - lo


def _columns(j, i, coarsen, nyc, nxc):
    """The coarsened columns' corners of the grid columns (j, i): ((j, i) + 1/2) / coarsen - 1/2, clamped."""
    inv = 1.0 / coarsen
    return _corner_indices((j + 0.5) * inv - 0.5, nyc), _corner_indices((i + 0.5) * inv - 0.5, nxc)


def _bilinear_levels(field, k0, k1, ak, columns):
    """``field`` (nk, ny, nx, C) between levels k0 and k1 (weight ``ak`` of k1) and the columns' corners: (n, C)."""
    (j0, j1, aj), (i0, i1, ai) = columns
    aj, ai, ak = aj[:, None], ai[:, None], ak[:, None]

    def level(k):
        return ((field[k, j0, i0] * (1 - ai) + field[k, j0, i1] * ai) * (1 - aj)
                + (field[k, j1, i0] * (1 - ai) + field[k, j1, i1] * ai) * aj)

    return level(k0) * (1 - ak) + level(k1) * ak


def clamped_trilinear(field, k, j, i, coarsen):
    """A diffuse-solution field (nk, ny_c, nx_c, C) at the grid's fractional level ``k`` and columns (``j``, ``i``)
    (n,), its columns coarsened by ``coarsen``, clamped to its edges: (n, C)."""
    nk, nyc, nxc = field.shape[:3]
    k0, k1, ak = _corner_indices(k, nk)
    return _bilinear_levels(field, k0, k1, ak, _columns(j, i, coarsen, nyc, nxc))


def cloud_sources(beta_species, k, j, i, t_cloud, irradiance, rays, consts):
    """The hydrometeors' sources at the rays' steps in the grid.

    Parameters
    ----------
    beta_species : jax.Array
        (n, n_sp) the packed species' extinction coefficients [m-1].
    k, j, i : jax.Array
        (n,) fractional grid indices of the steps' samples.
    t_cloud : jax.Array
        (n,) the direct beam's delta-M scaled transmittance through the hydrometeors (Step 1a) [-].
    irradiance : jax.Array
        (n, 3) the direct beam / E_TOA at the sample (gas, scaled hydrometeors, terrain shadow, 3-D aerosol) [-].
    rays : dict
        ``p_hydro`` (n, n_sp, 6) split phase functions and ``ray_ms`` (n, n_sp, 3 nm) moment weights
        (:func:`swim.rt.clouds.cloud_ray_inputs`).
    consts : dict
        ``ms_field`` (nk, ny_c, nx_c, 3 + 3 nm), ``ms_coarsen``, ``hydro_scale`` (1 - f), ``hydro_narrow``
        (f - f_a) (:func:`swim.rt.clouds.cloud_constants`).

    Returns
    -------
    ratio : jax.Array
        (n, 3) the diffuse radiance's ratio to the clear sky's, which scales the air's diffuse source [-].
    source : jax.Array
        (n, 3) the hydrometeors' source J beta [m-1] (single scattering of the beam plus the diffuse solution's
        sum_s beta_s sum_lm (chi_s,l - f_s) Y_lm L'_lm); 0 without hydrometeors.
    beta_scaled : jax.Array
        (n,) the delta-M scaled extinction sum_s (1 - f_s) beta_s [m-1].
    """
    n, n_sp = beta_species.shape
    field = clamped_trilinear(consts["ms_field"], k, j, i, consts["ms_coarsen"])
    ratio = field[:, :3]
    if n_sp == 0:
        zero = jnp.zeros(n, beta_species.dtype)
        return ratio, jnp.zeros((n, 3), beta_species.dtype), zero
    beta_h = beta_species.sum(axis=1)
    beta_scaled = beta_species @ consts["hydro_scale"].astype(beta_species.dtype)
    gap = beta_species @ consts["hydro_narrow"].astype(beta_species.dtype)
    phase = rays["p_hydro"]
    scattered = jnp.einsum("ns,nsc->nc", beta_species, phase[..., :3])
    peak = jnp.einsum("ns,nsc->nc", beta_species, phase[..., 3:])
    # the beam without the broad part of the forward peak: t_cloud^(gap / beta_scaled) times t_cloud
    lit = (t_cloud > 0) & (beta_scaled > 0)
    extra = jnp.where(lit, jnp.exp(jnp.log(jnp.where(lit, t_cloud, 1.0)) * gap / jnp.where(lit, beta_scaled, 1.0)), 0.0)
    single = (scattered + peak * extra[:, None]) * irradiance
    nm = field.shape[1] // 3 - 1
    weights = rays["ray_ms"].reshape(n, n_sp, 3, nm)
    diffuse = jnp.einsum("ns,nscm,ncm->nc", beta_species, weights, field[:, 3:].reshape(n, 3, nm))
    source = jnp.where((beta_h > 0)[:, None], single + diffuse, 0.0)
    return ratio, source, jnp.where(beta_h > 0, beta_scaled, 0.0)


def ratio_above_grid(h, k, j, i, consts, grid_shape):
    """The diffuse radiance's ratio to the clear sky's (n, 3) in the clear air over the grid (``k`` above its top
    level, ``j`` and ``i`` within its columns): ``ms_above`` (n_a, ny_c, nx_c, 3) at ``above_heights`` (n_a,) [m],
    linear in the height ``h`` (n,) [m] and bilinear across the columns; 1 above the highest and elsewhere."""
    nk, ny, nx = grid_shape
    above, heights = consts["ms_above"], consts["above_heights"].astype(h.dtype)
    n_a, nyc, nxc = above.shape[:3]
    a = jnp.clip(jnp.searchsorted(heights[1:n_a - 1], h, side="left"), 0, n_a - 2)
    lo, hi = heights[a], heights[a + 1]
    w = jnp.clip((h - lo) / (hi - lo), 0.0, 1.0)
    ratio = _bilinear_levels(above, a, a + 1, w, _columns(j, i, consts["ms_coarsen"], nyc, nxc))
    over = (k > nk - 1) & (j >= 0) & (j <= ny - 1) & (i >= 0) & (i <= nx - 1) & (h < heights[n_a - 1])
    return jnp.where(over[:, None], ratio, 1.0)
