"""The step's arithmetic per wavelength in the CPU march kernel (:mod:`swim.rt.march_cpu`, numba): the sky table as
lanes, the step's mean transmittance and accumulators, and the hydrometeors' sources
(docs/decisions/0003-cpu-kernel-code.md).

Each function mirrors its JAX counterpart in :mod:`swim.rt.march_jax` (named in its docstring) and follows the same
equations (Albers et al. 2020, doi:10.5194/amt-13-3235-2020: Eq. 3 for the clear-sky source, Eq. 12 for the
hydrometeor integral).
"""

from __future__ import annotations

import math

import numpy as np

from ..compilation.numba_jit import helper_jit
from .march_geometry_cpu import _clip

#: Lanes of the step's wavelength arithmetic: the three wavelengths and one lane of padding, whose values are
#: computed and never read. Four lanes of float64 fill a 256-bit vector register
#: (docs/decisions/0003-cpu-kernel-code.md).
LANES = 4
#: Columns of :func:`sky_lanes`' rows: the direct-sun lanes, then the skylight lanes.
SKY_LANE_COLUMNS = 2 * LANES


def sky_lanes(sky):
    """The sky table (6, nu, nmu) of :func:`swim.rt.march_inputs.atmosphere_constants` (the sun's transmittance at 3
    wavelengths, then the diffuse irradiance at 3) as the step loop reads it: (nu, nmu, 8) float64, the wavelengths
    innermost, each group of three padded with a zero lane, so that one corner's lanes are one contiguous load.

    Parameters
    ----------
    sky : array_like
        Shape (6, nu, nmu) [-].

    Returns
    -------
    numpy.ndarray
        Shape (nu, nmu, 8) float64 [-], C-contiguous: ``[..., c]`` the sun's transmittance and ``[..., 4 + c]`` the
        diffuse irradiance at wavelength c; columns 3 and 7 are 0.

    Raises
    ------
    ValueError
        If ``sky`` does not have 6 channels.
    """
    sky = np.asarray(sky)
    if sky.ndim != 3 or sky.shape[0] != 6:
        raise ValueError(f"sky table: expected shape (6, nu, nmu), got {sky.shape}")
    lanes = np.zeros(sky.shape[1:] + (SKY_LANE_COLUMNS,))
    lanes[..., 0:3] = np.moveaxis(sky[0:3], 0, -1)
    lanes[..., LANES:LANES + 3] = np.moveaxis(sky[3:6], 0, -1)
    return lanes


@helper_jit(inline="always")
def _corner_lane(lanes, u0, v0, u1, v1, o, a, b):
    """Lane o of a bilinear lookup between the four corner rows (u0, v0) ... (u1, v1) of a lane table
    (:func:`sky_lanes`): ``(r00 (1 - b) + r01 b) (1 - a) + (r10 (1 - b) + r11 b) a``, as :func:`_bilinear_at`."""
    return ((lanes[u0, v0, o] * (1 - b) + lanes[u0, v1, o] * b) * (1 - a)
            + (lanes[u1, v0, o] * (1 - b) + lanes[u1, v1, o] * b) * a)


@helper_jit(inline="always")
def _corner_lanes(lanes, u0, v0, u1, v1, o, a, b):
    """Lanes o ... o + 3 of :func:`_corner_lane`. The table is indexed element by element: a row taken as a view
    (``lanes[u0, v0]``) is a new array whose reference count numba raises and lowers with atomic instructions,
    which took ~1/4 of the march's cycles over all its views (docs/decisions/0003-cpu-kernel-code.md)."""
    return (_corner_lane(lanes, u0, v0, u1, v1, o, a, b), _corner_lane(lanes, u0, v0, u1, v1, o + 1, a, b),
            _corner_lane(lanes, u0, v0, u1, v1, o + 2, a, b), _corner_lane(lanes, u0, v0, u1, v1, o + 3, a, b))


@helper_jit(inline="always")
def _profile_lanes(lanes, u0, u1, o, w):
    """Lanes o ... o + 3 of the multiple-scattering profiles between two heights (rows u0, u1 of the ray's
    ``ms_lanes``): ``m0 (1 - w) + m1 w``, element by element (no row views: :func:`_corner_lanes`)."""
    return (lanes[u0, o] * (1 - w) + lanes[u1, o] * w, lanes[u0, o + 1] * (1 - w) + lanes[u1, o + 1] * w,
            lanes[u0, o + 2] * (1 - w) + lanes[u1, o + 2] * w, lanes[u0, o + 3] * (1 - w) + lanes[u1, o + 3] * w)


@helper_jit(inline="always")
def _mean_transmittance(x):
    """The step's mean transmittance (1 - e^-x) / x and e^-x - 1 (which carries e^-tau to the observer to the next
    step), per lane of optical depths x: for |x| < 0.1 in every lane (a step in clear air has x ~ 1e-3; x < 0 for the
    terminal step back over the ground) one Taylor polynomial (relative error < 1e-11) without a division, else one
    expm1 per lane. One test for all lanes keeps the lanes' arithmetic in one block, where LLVM vectorises it."""
    x0, x1, x2, x3 = x
    if max(max(abs(x0), abs(x1)), max(abs(x2), abs(x3))) < 0.1:
        m0 = 1.0 - x0 * (0.5 - x0 * (1.0 / 6 - x0 * (1.0 / 24 - x0 * (1.0 / 120 - x0 * (1.0 / 720 - x0 / 5040)))))
        m1 = 1.0 - x1 * (0.5 - x1 * (1.0 / 6 - x1 * (1.0 / 24 - x1 * (1.0 / 120 - x1 * (1.0 / 720 - x1 / 5040)))))
        m2 = 1.0 - x2 * (0.5 - x2 * (1.0 / 6 - x2 * (1.0 / 24 - x2 * (1.0 / 120 - x2 * (1.0 / 720 - x2 / 5040)))))
        m3 = 1.0 - x3 * (0.5 - x3 * (1.0 / 6 - x3 * (1.0 / 24 - x3 * (1.0 / 120 - x3 * (1.0 / 720 - x3 / 5040)))))
        return (m0, m1, m2, m3), (-x0 * m0, -x1 * m1, -x2 * m2, -x3 * m3)
    e0, e1, e2, e3 = math.expm1(-x0), math.expm1(-x1), math.expm1(-x2), math.expm1(-x3)
    return ((-e0 / x0 if x0 != 0.0 else 1.0, -e1 / x1 if x1 != 0.0 else 1.0, -e2 / x2 if x2 != 0.0 else 1.0,
             -e3 / x3 if x3 != 0.0 else 1.0), (e0, e1, e2, e3))


@helper_jit(inline="always")  # numba-level inlining, so that the accumulators stay scalars in registers
def _accumulate_lanes(tau_clear, t_obs, l_clear, i_nogas, i_gas, beta_clear, source, irradiance_h, beta_h, ds_eff,
                      weight, gas_ratio):
    """Each lane's (wavelength's) accumulators after a step of length ``ds_eff`` [m]: the clear-sky optical depth,
    the transmittance to the observer, the clear-sky radiance (Eq. 3: the source times the step's mean transmittance)
    and the Eq. 12 integrals with and without the gas (``weight``: the step's e^-min(t0, 2) - e^-min(t1, 2);
    ``gas_ratio``: e^t0, so that ``t_obs * gas_ratio`` is the clear sky's e^-tau_clear without an exp: t_obs =
    e^-(tau_clear + t0), and t0 < 2 wherever the weight is > 0). A negative weight is a terminal step back
    (:func:`swim.rt.march_jax._terminal_step`), where t0 may exceed 2: it takes e^-tau_clear itself. Every argument but
    the last four is a tuple of :data:`LANES` scalars, and so is each result."""
    tc0, tc1, tc2, tc3 = tau_clear
    to0, to1, to2, to3 = t_obs
    lc0, lc1, lc2, lc3 = l_clear
    in0, in1, in2, in3 = i_nogas
    ig0, ig1, ig2, ig3 = i_gas
    b0, b1, b2, b3 = beta_clear
    s0, s1, s2, s3 = source
    e0, e1, e2, e3 = irradiance_h
    (m0, m1, m2, m3), (x0, x1, x2, x3) = _mean_transmittance(((b0 + beta_h) * ds_eff, (b1 + beta_h) * ds_eff,
                                                               (b2 + beta_h) * ds_eff, (b3 + beta_h) * ds_eff))
    if weight > 0.0:
        in0, in1, in2, in3 = in0 + e0 * weight, in1 + e1 * weight, in2 + e2 * weight, in3 + e3 * weight
        g = gas_ratio * weight
        ig0, ig1, ig2, ig3 = ig0 + e0 * to0 * g, ig1 + e1 * to1 * g, ig2 + e2 * to2 * g, ig3 + e3 * to3 * g
    elif weight < 0.0:
        in0, in1, in2, in3 = in0 + e0 * weight, in1 + e1 * weight, in2 + e2 * weight, in3 + e3 * weight
        ig0 += e0 * math.exp(-tc0) * weight
        ig1 += e1 * math.exp(-tc1) * weight
        ig2 += e2 * math.exp(-tc2) * weight
        ig3 += e3 * math.exp(-tc3) * weight
    return ((tc0 + b0 * ds_eff, tc1 + b1 * ds_eff, tc2 + b2 * ds_eff, tc3 + b3 * ds_eff),
            (to0 * (1.0 + x0), to1 * (1.0 + x1), to2 * (1.0 + x2), to3 * (1.0 + x3)),
            (lc0 + to0 * s0 * (ds_eff * m0), lc1 + to1 * s1 * (ds_eff * m1), lc2 + to2 * s2 * (ds_eff * m2),
             lc3 + to3 * s3 * (ds_eff * m3)),
            (in0, in1, in2, in3), (ig0, ig1, ig2, ig3))


@helper_jit()
def _cloud_sources(row, k, j, i, nk, vol, n_species, p_hydro, ray_ms, hydro_scale, hydro_narrow, ms_field, ms_coarsen,
                   beta_h, t_cloud, e0, e1, e2):
    """The hydrometeors' sources at a step of ``cloud_scattering="discrete_ordinates"``, per wavelength [m-1]:

    * single scattering of the direct beam with the species' phase functions split in two
      (:func:`swim.optics.cloud_phase.split_phase_function`), ``p_hydro[row]`` (n_sp, 6): the first three
      columns scatter the beam with its delta-M scaled transmittance ``t_cloud`` (in ``e0..e2``, Nakajima and Tanaka
      1988's TMS), the last three the beam dimmed by all but the narrow forward peak, t_cloud^x with
      x = sum_s beta_s (f_s - f_a,s) / sum_s beta_s (1 - f_s) (``hydro_narrow``: f - f_a; exact for one species);
    * the diffuse solution's source sum_s beta_s sum_lm (chi_s,l - f_s) Y_lm(-d) L'_lm(x): the ray's weights
      ``ray_ms[row]`` (n_sp, 3 nm), (chi_s,l - f_s) Y_lm(-d) per wavelength and moment, on the moments ``ms_field``
      (nk, ny_c, nx_c, 3 + 3 nm) interpolated trilinearly at the step's level ``k`` and columns
      ((j, i) + 1/2) / ``ms_coarsen`` - 1/2 (the species' weights summed first, then one interpolation per moment);

    and the ratio of the diffuse radiance to the clear sky's (channels 0-2), which scales the air's diffuse source,
    and the hydrometeors' scaled extinction sum_s (1 - f_s) beta_s (``hydro_scale``: 1 - f)."""
    nyc, nxc = ms_field.shape[1], ms_field.shape[2]
    nm3 = ray_ms.shape[2]
    nm = nm3 // 3
    inv = 1.0 / ms_coarsen
    fk = _clip(k, 0.0, nk - 1.0)
    fj = _clip((j + 0.5) * inv - 0.5, 0.0, nyc - 1.0)
    fi = _clip((i + 0.5) * inv - 0.5, 0.0, nxc - 1.0)
    k0 = min(int(fk), nk - 2) if nk > 1 else 0
    j0 = min(int(fj), nyc - 2) if nyc > 1 else 0
    i0 = min(int(fi), nxc - 2) if nxc > 1 else 0
    k1, j1, i1 = min(k0 + 1, nk - 1), min(j0 + 1, nyc - 1), min(i0 + 1, nxc - 1)
    ak, aj, ai = fk - k0, fj - j0, fi - i0
    d0 = _field_at(ms_field, 0, k0, k1, j0, j1, i0, i1, ak, aj, ai)
    d1 = _field_at(ms_field, 1, k0, k1, j0, j1, i0, i1, ak, aj, ai)
    d2 = _field_at(ms_field, 2, k0, k1, j0, j1, i0, i1, ak, aj, ai)
    if beta_h <= 0.0:
        return d0, d1, d2, 0.0, 0.0, 0.0, 0.0
    beta_eff = 0.0
    gap = 0.0
    ss0 = ss1 = ss2 = 0.0
    su0 = su1 = su2 = 0.0
    for s in range(n_species):
        b = vol[s]
        beta_eff += hydro_scale[s] * b
        gap += hydro_narrow[s] * b
        ss0 += b * p_hydro[row, s, 0]
        ss1 += b * p_hydro[row, s, 1]
        ss2 += b * p_hydro[row, s, 2]
        su0 += b * p_hydro[row, s, 3]
        su1 += b * p_hydro[row, s, 4]
        su2 += b * p_hydro[row, s, 5]
    # the beam without the broad part of the forward peak: t_cloud^(gap / beta_eff) times t_cloud's e0..e2
    extra = math.exp(math.log(t_cloud) * (gap / beta_eff)) if t_cloud > 0.0 and beta_eff > 0.0 else 0.0
    ss0 += su0 * extra
    ss1 += su1 * extra
    ss2 += su2 * extra
    # sum_s beta_s sum_m w_s,m F_m(x) as sum_m (sum_s beta_s w_s,m) F_m(x): the species' weights combined before the
    # trilinear interpolation, which is then done once per moment (most cloudy cells hold two species or more)
    ms0 = ms1 = ms2 = 0.0
    for m in range(3 * nm):
        r = 0.0
        for s in range(n_species):
            r += vol[s] * ray_ms[row, s, m]
        if r == 0.0:
            continue
        f = _field_at(ms_field, 3 + m, k0, k1, j0, j1, i0, i1, ak, aj, ai)
        if m < nm:
            ms0 += r * f
        elif m < 2 * nm:
            ms1 += r * f
        else:
            ms2 += r * f
    return d0, d1, d2, ss0 * e0 + ms0, ss1 * e1 + ms1, ss2 * e2 + ms2, beta_eff


@helper_jit(inline="always")
def _field_at(field, c, k0, k1, j0, j1, i0, i1, ak, aj, ai):
    """Channel ``c`` of ``field`` (nk, ny, nx, C) interpolated trilinearly between the corners (k0|k1, j0|j1,
    i0|i1) with the upper corners' weights ``ak``, ``aj``, ``ai``."""
    lo = ((1 - aj) * ((1 - ai) * field[k0, j0, i0, c] + ai * field[k0, j0, i1, c])
          + aj * ((1 - ai) * field[k0, j1, i0, c] + ai * field[k0, j1, i1, c]))
    hi = ((1 - aj) * ((1 - ai) * field[k1, j0, i0, c] + ai * field[k1, j0, i1, c])
          + aj * ((1 - ai) * field[k1, j1, i0, c] + ai * field[k1, j1, i1, c]))
    return (1 - ak) * lo + ak * hi


@helper_jit()
def _ratio_above(h, j, i, above, heights, coarsen):
    """The diffuse radiance's ratio to the clear sky's (3 wavelengths) at height ``h`` [m] over the grid's column
    (``j``, ``i``): ``above`` (n, ny_c, nx_c, 3) at ``heights`` (n,) [m], the grid's top level first, linear in
    height, bilinear across the coarsened columns (:class:`swim.rt.diffuse_field.DiffuseField`); 1 above the
    highest."""
    n, nyc, nxc = above.shape[0], above.shape[1], above.shape[2]
    if h >= heights[n - 1]:
        return 1.0, 1.0, 1.0
    a = 0
    while a < n - 2 and h > heights[a + 1]:
        a += 1
    w = _clip((h - heights[a]) / (heights[a + 1] - heights[a]), 0.0, 1.0)
    inv = 1.0 / coarsen
    fj = _clip((j + 0.5) * inv - 0.5, 0.0, nyc - 1.0)
    fi = _clip((i + 0.5) * inv - 0.5, 0.0, nxc - 1.0)
    j0 = min(int(fj), nyc - 2) if nyc > 1 else 0
    i0 = min(int(fi), nxc - 2) if nxc > 1 else 0
    j1, i1 = min(j0 + 1, nyc - 1), min(i0 + 1, nxc - 1)
    return (_field_at(above, 0, a, a + 1, j0, j1, i0, i1, w, fj - j0, fi - i0),
            _field_at(above, 1, a, a + 1, j0, j1, i0, i1, w, fj - j0, fi - i0),
            _field_at(above, 2, a, a + 1, j0, j1, i0, i1, w, fj - j0, fi - i0))


@helper_jit(inline="always")
def _accumulate_cloud(l_cloud, t_obs, source, beta_clear, beta_h, ds_eff):
    """The hydrometeors' radiance lanes after a step: ``source`` (3 lanes) times the step's mean transmittance
    (its extinction: the clear air's ``beta_clear`` lanes and the scaled hydrometeors' ``beta_h``) and the
    transmittance ``t_obs`` to the observer at its start."""
    l0, l1, l2, l3 = l_cloud
    s0, s1, s2 = source
    b0, b1, b2 = beta_clear
    (m0, m1, m2, _), _ = _mean_transmittance(((b0 + beta_h) * ds_eff, (b1 + beta_h) * ds_eff,
                                              (b2 + beta_h) * ds_eff, 0.0))
    return (l0 + t_obs[0] * s0 * (ds_eff * m0), l1 + t_obs[1] * s1 * (ds_eff * m1),
            l2 + t_obs[2] * s2 * (ds_eff * m2), l3)


