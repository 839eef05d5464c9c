"""Multiple scattering of the clear atmosphere: a precomputed diffuse-source table.

Single scattering of the direct beam (paper Eq. 3) leaves the blue sky 15-30 % too dark against DISORT
(docs/validation.md). In the spirit of Bruneton and Neyret (2008) and Hillaire (2020) the higher orders
are precomputed once per atmosphere and looked up by the ray march, but instead of assuming an isotropic
multiple-scattering phase function the table holds the full directional *diffuse source*

    J_x(h, mu_s, mu_v, phi) = (1 / 4 pi) ∫ P_x(Ω_v, Ω') L'_d(h, Ω') dΩ'    (x = Rayleigh, aerosol)

of a plane-parallel atmosphere with the same extinction profiles, where L'_d is the diffuse radiance (all
orders >= 1 of scattering, including light reflected by a Lambertian ground) in the paper's solar-relative
units (Eq. 2, L' = 4 pi I for a unit beam flux). The renderer adds ``beta_R J_R + omega_A beta_A J_A`` to
the single-scattering source of Eq. 3 at every step, which then contains all orders >= 2.

The diffuse field is computed by successive orders of scattering (SOS; e.g. Lenoble et al. 2007, JQSRT
106, 243, doi:10.1016/j.jqsrt.2007.01.005) on a discrete direction grid:

* heights: layer edges ``h = H_top u^2`` with u uniform (the table axis of :mod:`swim.rt.gas`), so the
  layers are ~40 m thick at the ground and the sources are constant within a layer;
* directions: Gauss-Legendre cosines on each hemisphere times uniform azimuths over [0, pi]; the field is
  symmetric about the solar principal plane, so each azimuth node stands for itself and its mirror image;
* the scattering kernels are the phase functions evaluated between grid directions, balanced (Sinkhorn)
  so that every row and column sums to one, which conserves energy exactly even for the forward-peaked
  aerosol phase functions the coarse grid cannot resolve; the direct-beam column is normalised likewise;
* orders are summed until the newest adds < 1e-5 of the total, the remainder taken as a geometric series.

Conventions: ``mu_v`` is the cosine of the *view* zenith angle (positive looking up) and ``phi`` the view
azimuth minus the sun azimuth (0 = looking towards the sun's azimuth), as in :mod:`swim.frames`; the
radiance seen travels the opposite way.

The sun below the horizon (twilight). The table's sun axis runs from 23.9 deg below the horizon to the zenith
(:data:`swim.constants.DIFFUSE_SUN_T_MIN`). Its direct beam is pseudo-spherical: each level is lit by the
sun's transmittance along the slant path through the spherical shell (``beam_transmittance``; zero in the
earth's shadow), travelling in the level's local sun direction, upwards for a sun below the horizon, while
the diffuse light is spread through plane-parallel layers (Dahlback and Stamnes 1991, Planet. Space Sci. 39,
671, doi:10.1016/0032-0633(91)90061-E, for the sun above the horizon; the same construction with the beam of
the shell's sunlit upper levels below it). At twilight that is the light of the sunlit upper air scattered
once more into the shadowed air below, which fills the earth's shadow and adds ~20 % to the twilight zenith
(docs/decisions/0023-ozone-and-twilight.md). Without ``beam_transmittance`` the beam is plane-parallel and
rows of a sun at or below the horizon hold zero.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..constants import DIFFUSE_SUN_T_MIN

log = logging.getLogger(__name__)

__all__ = ["DiffuseSourceTable", "aerosol_layer_albedo", "diffuse_source_table", "successive_orders_plane_parallel"]


@dataclass(frozen=True)
class DiffuseSourceTable:
    """Diffuse-light source and irradiance of a plane-parallel clear atmosphere (see module docstring).

    Attributes
    ----------
    u : numpy.ndarray
        Shape (n_u,): height coordinate u = sqrt(h / H_top) [-] of the levels.
    t_s : numpy.ndarray
        Shape (n_s,): sun coordinate t = sign(mu_s) sqrt(|mu_s|) [-], uniform from
        :data:`swim.constants.DIFFUSE_SUN_T_MIN` (a sun 23.9 deg below the horizon) to 1.
    mu_v : numpy.ndarray
        Shape (n_v,): cosine of the view zenith angle [-], uniform in [-1, 1].
    phi_deg : numpy.ndarray
        Shape (n_phi,): relative azimuth view - sun [deg], uniform in [0, 180].
    source : numpy.ndarray
        Shape (n_s, n_v, n_phi, n_u, K C), float32: J of each of the K scattering components (molecules,
        aerosol, stratospheric aerosol), C = 3 wavelengths each [-] (solar-relative radiance per unit
        optical depth of scattering, phase functions of mean 1).
    diffuse_down : numpy.ndarray
        Shape (n_u, n_s, 3): downward diffuse irradiance on a horizontal surface / E_TOA [-].
    scalar_diffuse : numpy.ndarray
        Shape (n_u, n_s, 3): diffuse scalar irradiance (all directions) / E_TOA [-].
    orders : int
        Scattering orders summed explicitly.
    """

    u: np.ndarray
    t_s: np.ndarray
    mu_v: np.ndarray
    phi_deg: np.ndarray
    source: np.ndarray
    diffuse_down: np.ndarray
    scalar_diffuse: np.ndarray
    orders: int


def _direction_grid(n_half, n_phi):
    """Propagation directions (mu positive up, phi in (0, pi)) and quadrature weights summing to 4 pi."""
    x, w = np.polynomial.legendre.leggauss(n_half)
    mu_half = 0.5 * (x + 1.0)
    w_half = 0.5 * w
    mu = np.concatenate([-mu_half[::-1], mu_half])
    w_mu = np.concatenate([w_half[::-1], w_half])
    dphi = np.pi / n_phi
    phi = (np.arange(n_phi) + 0.5) * dphi
    M, P = np.meshgrid(mu, phi, indexing="ij")
    W = np.outer(w_mu, np.full(n_phi, 2.0 * dphi))
    return M.ravel(), P.ravel(), W.ravel()


def _cos_between(mu_a, phi_a, mu_b, phi_b):
    """cos of the angle between directions (mu, phi) [broadcasting]."""
    sa = np.sqrt(np.clip(1.0 - mu_a**2, 0.0, None))
    sb = np.sqrt(np.clip(1.0 - mu_b**2, 0.0, None))
    return np.clip(mu_a * mu_b + sa * sb * np.cos(phi_a - phi_b), -1.0, 1.0)


def tabulated_phase_function(phase_function, n_theta=4097):
    """Wrap a (jax) phase function in linear interpolation on a fixed grid of scattering angles.

    Evaluating the jit-compiled phase functions on the many array shapes of the SOS solution would compile
    each shape anew; one fixed-size table (0.044° steps) compiles once and interpolates to < 1e-4.
    """
    theta = np.linspace(0.0, np.pi, n_theta)
    values = np.asarray(phase_function(np.cos(theta)), float)

    def interpolated(cos_theta):
        t = np.arccos(np.clip(np.asarray(cos_theta, float), -1.0, 1.0)) * ((n_theta - 1) / np.pi)
        i0 = np.clip(np.floor(t).astype(int), 0, n_theta - 2)
        w = t - i0
        if values.ndim == 2:
            w = w[..., None]
        return values[i0] * (1 - w) + values[i0 + 1] * w

    return interpolated


def _kernel(phase_function, mu_out, phi_out, mu_q, phi_q, w_q, symmetric=False):
    """Scattering kernel K (..., n_out, n_q) with J_out = K @ L_q (mirror azimuth nodes folded in).

    Rows sum to one (each output direction sees a mean-1 phase function). With ``symmetric`` (output
    directions = quadrature directions) the folded phase matrix, which is symmetric, is first rescaled as
    a_i a_j P_ij (Sinkhorn balancing) so that the columns conserve energy as well: the light scattered out
    of each direction then equals its extinction times omega, which a forward peak narrower than the grid
    would otherwise violate by ~1 %.
    """
    c1 = _cos_between(mu_out[:, None], phi_out[:, None], mu_q[None, :], phi_q[None, :])
    c2 = _cos_between(mu_out[:, None], phi_out[:, None], mu_q[None, :], -phi_q[None, :])
    p = 0.5 * (np.asarray(phase_function(c1), float) + np.asarray(phase_function(c2), float))
    # p has shape (n_out, n_q) or (n_out, n_q, C): move channels first.
    if p.ndim == 3:
        p = np.moveaxis(p, -1, 0)
    if symmetric:
        a = np.ones(p.shape[:-1])
        for _ in range(500):
            row = np.sum(p * a[..., None, :] * w_q, axis=-1) * a / (4 * np.pi)
            a = a / np.sqrt(row)
            if np.max(np.abs(row - 1.0)) < 1e-10:
                break
        p = p * a[..., :, None] * a[..., None, :]
    k = p * w_q
    return k / k.sum(axis=-1, keepdims=True)


def _channel_kernels(phase_function, mu_out, phi_out, mu_q, phi_q, w_q, n_c, symmetric=False):
    """:func:`_kernel` with a leading channel axis (C, n_out, n_q) (a grey phase function is broadcast)."""
    k = _kernel(phase_function, mu_out, phi_out, mu_q, phi_q, w_q, symmetric=symmetric)
    return np.broadcast_to(k, (n_c,) + k.shape[-2:]) if k.ndim == 2 else k


def _log_mean(a, b):
    """Layer mean of a beam falling exponentially from ``a`` to ``b`` across the layer, (a - b) / ln(a / b): the exact
    mean of exp(-tau / mu0) in a homogeneous layer; the linear mean where an edge is dark (the shadow's edge)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        la, lb = np.log(a), np.log(b)
        mean = np.where(np.abs(la - lb) > 1e-9, (a - b) / (la - lb), 0.5 * (a + b))
    return np.where((a > 0) & (b > 0), mean, 0.5 * (a + b))


def _single_scattering_source(d_tau, ssa, fractions, mu0, phase_functions, mu_q, phi_q, w_q, beam_edges=None):
    """Direct beam at the layer edges (n_l + 1, n_s, C) and the first order's source (n_l, n_q, n_s, C).

    The beam propagates with mu = -mu0 at azimuth 0 (upward for a sun below the horizon, mu0 < 0); its
    single-scattering phase is column-normalised over the quadrature. ``beam_edges`` (n_l + 1, n_s, C), when
    given, is the beam at the edges (the pseudo-spherical transmittance); else exp(-tau / mu0).
    """
    n_c = d_tau.shape[1]
    cos_sun = _cos_between(mu_q[:, None], phi_q[:, None], -mu0[None, :], 0.0)  # (n_q, n_s)
    beam_phase = 0.0
    for frac, phase in zip(fractions, phase_functions):
        p = np.asarray(phase(cos_sun), float)
        p = p[..., None] if p.ndim == 2 else p  # (n_q, n_s, C or 1)
        p = p / ((w_q[:, None, None] * p).sum(axis=0) / (4 * np.pi))
        beam_phase = beam_phase + frac[:, None, None, :] * p[None]
    w_ssa = ssa[:, None, None, :]
    if beam_edges is not None:
        e_edges = np.asarray(beam_edges, float)
        return e_edges, w_ssa * beam_phase * _log_mean(e_edges[:-1], e_edges[1:])[:, None, :, :]
    tau_edges = np.concatenate([np.zeros((1, n_c)), np.cumsum(d_tau, axis=0)])  # (n_l + 1, C)
    e_edges = np.exp(-tau_edges[:, None, :] / mu0[None, :, None])  # (n_l + 1, n_s, C)
    safe = np.maximum(d_tau, 1e-12)[:, None, :]
    e_mean = np.where(d_tau[:, None, :] > 1e-9, mu0[None, :, None] * (e_edges[:-1] - e_edges[1:]) / safe, e_edges[:-1])
    return e_edges, w_ssa * beam_phase * e_mean[:, None, :, :]


def _sweep_order(source, att, mean_fac, flux_w, direct_ground, albedo, n_s):
    """One order of scattering: radiance at the layer edges (n_l + 1, n_q, n_s, C) and its layer means (n_l, ...).

    The sweep goes down from the top (no diffuse light enters from space), then up from a Lambertian ground,
    L'_up = 4 a E (E / E_TOA the horizontal irradiance, ``direct_ground`` the direct beam's share of it). The
    grid lists the downward directions first: slices avoid copies in the sweeps.
    """
    n_l, n_q, _, n_c = att.shape
    down = slice(0, n_q // 2)
    up = slice(n_q // 2, n_q)
    edges = np.zeros((n_l + 1, n_q, n_s, n_c))
    mean = np.zeros((n_l, n_q, n_s, n_c))
    i_d = np.zeros((n_q // 2, n_s, n_c))
    for layer in range(n_l):
        s = source[layer, down]
        a = att[layer, down]
        mean[layer, down] = s + (i_d - s) * mean_fac[layer, down]
        i_d = i_d * a + s * (1 - a)
        edges[layer + 1, down] = i_d
    e_ground = np.einsum("q,qsc->sc", flux_w, i_d) + direct_ground
    i_u = np.broadcast_to(4.0 * albedo * e_ground, (n_q - n_q // 2, n_s, n_c)).copy()
    edges[n_l, up] = i_u
    for layer in range(n_l - 1, -1, -1):
        s = source[layer, up]
        a = att[layer, up]
        mean[layer, up] = s + (i_u - s) * mean_fac[layer, up]
        i_u = i_u * a + s * (1 - a)
        edges[layer, up] = i_u
    return edges, mean


def _scattered(fractions, kernels, mean):
    """Light scattered out of the layer-mean radiance ``mean`` (n_l, n_q, n_s, C), before the albedo."""
    n_c = mean.shape[-1]
    scattered = 0.0
    for frac, kern in zip(fractions, kernels):
        j = np.stack([np.einsum("pq,lqs->lps", kern[c], mean[..., c], optimize=True) for c in range(n_c)], axis=-1)
        scattered = scattered + frac[:, None, None, :] * j
    return scattered


def successive_orders_plane_parallel(d_tau, ssa, scattering_fractions, mu0, surface_albedo, phase_functions,
                                     n_half=10, n_phi=12, tolerance=1e-5, max_orders=60, beam_edges=None):
    """Diffuse radiance field of a plane-parallel atmosphere by successive orders of scattering.

    Parameters
    ----------
    d_tau : numpy.ndarray
        Shape (n_layers, C): extinction optical depth of each layer, top layer first [-].
    ssa : numpy.ndarray
        Shape (n_layers, C): single-scattering albedo of the layer's mixture [-].
    scattering_fractions : numpy.ndarray
        Shape (K, n_layers, C): share of the layer's scattering done by each of K components (molecules,
        aerosol, ...) [-], summing to 1 over K.
    mu0 : numpy.ndarray
        Shape (n_s,): cosines of the solar zenith angle [-], nonzero; > 0 without ``beam_edges``.
    surface_albedo : array_like
        Shape (C,): Lambertian surface albedo [-].
    phase_functions : sequence of callable
        K functions cos θ -> P(θ), mean 1 over the sphere, grey or with a last axis of C channels.
    n_half, n_phi : int
        Gauss cosines per hemisphere and azimuth nodes over [0, pi].
    tolerance : float
        Stop when the newest order adds less than this fraction of the accumulated field.
    max_orders : int
    beam_edges : numpy.ndarray, optional
        Shape (n_layers + 1, n_s, C): the direct beam at the layer edges relative to E_TOA [-], for a
        pseudo-spherical beam (the sun's transmittance through the spherical shell); default exp(-tau / mu0).
        A sun below the horizon (mu0 < 0) lights the levels where it is nonzero, its beam travelling upward.

    Returns
    -------
    dict
        ``mu``, ``phi``, ``weight`` (n_q,): the propagation directions (mu > 0 upward; phi relative to the
        azimuth of the beam's propagation) and weights; ``radiance`` (n_layers + 1, n_q, n_s, C): diffuse
        L' [-] at the layer edges (top first); ``orders``.

    References
    ----------
    Lenoble, J. et al. (2007), JQSRT 106, 243-265, doi:10.1016/j.jqsrt.2007.01.005 (SOS method);
    Albers et al. (2020), Eq. 2 (L' units).
    """
    d_tau = np.asarray(d_tau, float)
    n_l, n_c = d_tau.shape
    fractions = np.asarray(scattering_fractions, float)
    mu0 = np.atleast_1d(np.asarray(mu0, float))
    albedo = np.broadcast_to(np.asarray(surface_albedo, float), (n_c,))
    mu_q, phi_q, w_q = _direction_grid(n_half, n_phi)
    n_q = mu_q.size
    kernels = [_channel_kernels(p, mu_q, phi_q, mu_q, phi_q, w_q, n_c, symmetric=True) for p in phase_functions]

    if beam_edges is None and np.any(mu0 <= 0):
        raise ValueError("a plane-parallel beam needs mu0 > 0; a sun at or below the horizon needs beam_edges")
    e_edges, source = _single_scattering_source(d_tau, ssa, fractions, mu0, phase_functions, mu_q, phi_q, w_q,
                                                beam_edges)
    w_ssa = ssa[:, None, None, :]

    # the downward directions' flux weights (the grid lists them first)
    flux_w = (w_q * np.abs(mu_q) / (4 * np.pi))[:n_q // 2]
    direct_ground = np.maximum(mu0, 0.0)[:, None] * e_edges[-1]  # (n_s, C) horizontal direct irradiance at the ground
    x = d_tau[:, None, :] / np.abs(mu_q)[None, :, None]  # (n_l, n_q, C)
    att = np.exp(-x)[:, :, None, :]
    mean_fac = np.where(x > 1e-9, -np.expm1(-x) / np.maximum(x, 1e-300), 1.0)[:, :, None, :]

    total = np.zeros((n_l + 1, n_q, mu0.size, n_c))
    order = 0
    previous_ratio = 0.0
    for order in range(1, max_orders + 1):
        edges, mean = _sweep_order(source, att, mean_fac, flux_w, direct_ground if order == 1 else 0.0, albedo,
                                   mu0.size)
        total += edges
        added = float(np.abs(edges).max())
        scale = float(np.abs(total).max())
        ratio = added / max(previous_ratio, 1e-300) if order > 1 else 0.0
        previous_ratio = added
        if scale == 0.0 or added < tolerance * scale:
            if 0.0 < ratio < 1.0:
                total += edges * (ratio / (1.0 - ratio))
            break
        source = w_ssa * _scattered(fractions, kernels, mean)  # the next order's, from this order's layer means
    else:
        log.warning("successive orders did not converge in %d orders", max_orders)
    return {"mu": mu_q, "phi": phi_q, "weight": w_q, "radiance": total, "orders": order}


def diffuse_source_table(heights_m, extinctions, ssas, phase_functions, surface_albedo, top_m, n_u=41, n_s=19,
                         n_v=33, n_phi=13, n_half=10, n_phi_quad=12, absorption=None, beam_transmittance=None):
    """Build the :class:`DiffuseSourceTable` of a clear atmosphere.

    Parameters
    ----------
    heights_m : numpy.ndarray
        Shape (n_h,): heights of the extinction profiles [m], from 0 to ``top_m``.
    extinctions : sequence of numpy.ndarray
        K arrays (n_h, C): extinction coefficient of each component (molecules, aerosol, ...) [m-1].
    ssas : sequence of array_like
        K arrays (C,): single-scattering albedo of each component [-].
    phase_functions : sequence of callable
        K phase functions (mean 1), grey or with a last axis of C channels.
    surface_albedo : array_like
        Shape (C,): Lambertian ground albedo [-] (the scene mean).
    top_m : float
        Top of the atmosphere [m].
    n_u, n_s, n_v, n_phi : int
        Table sizes in sqrt-height, the sun coordinate t = sign(mu_s) sqrt(|mu_s|) from
        :data:`swim.constants.DIFFUSE_SUN_T_MIN` to 1, view cosine and relative azimuth.
    n_half, n_phi_quad : int
        Direction quadrature of the SOS solution.
    absorption : numpy.ndarray, optional
        Shape (n_h, C): absorption coefficient of pure absorbers (ozone, :mod:`swim.optics.ozone`) [m-1] on
        ``heights_m``; it adds to each layer's optical depth and lowers its single-scattering albedo, with no
        source channel of its own.
    beam_transmittance : callable, optional
        ``(heights [m] (n,), mu_s [-] (m,)) -> (n, m, C)``: the sun's transmittance from each height towards a sun
        of each cosine, through the spherical shell (zero in the earth's shadow). Given, the beam is
        pseudo-spherical and the rows of a sun at or below the horizon are solved too (module docstring); else
        the beam is plane-parallel and those rows hold zero.

    Returns
    -------
    DiffuseSourceTable
        With ``source`` channels ordered component by component, C each.
    """
    phase_functions = [tabulated_phase_function(p) for p in phase_functions]
    extinctions = [np.asarray(b, float) for b in extinctions]
    n_c = extinctions[0].shape[1]
    u = np.linspace(0.0, 1.0, n_u)
    edges_h = top_m * u[::-1] ** 2  # top first

    def layer_tau(beta):
        """Optical depth of each layer between the edges (trapezoid on the fine profile)."""
        seg = 0.5 * (beta[1:] + beta[:-1]) * np.diff(heights_m)[:, None]
        above = np.concatenate([np.cumsum(seg[::-1], axis=0)[::-1], np.zeros((1, n_c))])
        column = np.stack([np.interp(edges_h, heights_m, above[:, c]) for c in range(n_c)], axis=-1)
        # Edges run top first, so the column above grows down the stack.
        return np.maximum(np.diff(column, axis=0), 0.0)

    # Components without extinction (e.g. no stratospheric aerosol) get zero source and cost nothing.
    active = [k for k, b in enumerate(extinctions) if np.any(b > 0)] or [0]
    taus = np.stack([layer_tau(extinctions[k]) for k in active])  # (K', n_l, C)
    scats = taus * np.stack([np.broadcast_to(np.asarray(ssas[k], float), (n_c,)) for k in active])[:, None, :]
    d_tau = taus.sum(axis=0)
    if absorption is not None and np.any(np.asarray(absorption) > 0):
        d_tau = d_tau + layer_tau(np.asarray(absorption, float))
    scat = scats.sum(axis=0)
    ssa = np.where(d_tau > 0, scat / np.maximum(d_tau, 1e-300), 1.0)
    fractions = np.where(scat > 0, scats / np.maximum(scat, 1e-300), 1.0 / len(active))

    t_s = np.linspace(DIFFUSE_SUN_T_MIN, 1.0, n_s)
    mu_all = np.sign(t_s) * t_s**2
    beam = None
    if beam_transmittance is None:
        lit = mu_all > 0  # a plane-parallel sun at or below the horizon lights nothing
    else:
        beam = np.asarray(beam_transmittance(edges_h, mu_all), float)  # (n_edges, n_s, C), top first
        lit = np.any(beam > 0, axis=(0, 2))  # rows of a sun so low that the whole shell is in shadow stay zero
        beam = beam[:, lit]
    mu0 = mu_all[lit]
    sol = successive_orders_plane_parallel(d_tau, ssa, fractions, mu0, surface_albedo,
                                           [phase_functions[k] for k in active], n_half=n_half, n_phi=n_phi_quad,
                                           beam_edges=beam)
    rad = sol["radiance"][::-1]  # (n_u, n_q, n_lit, C), ground first like u
    mu_q, w_q = sol["mu"], sol["weight"]

    # Source for view directions: the light seen travels along -view, i.e. propagation mu = -mu_v.
    mu_v = np.linspace(-1.0, 1.0, n_v)
    phi_deg = np.linspace(0.0, 180.0, n_phi)
    MV, PH = np.meshgrid(mu_v, np.radians(phi_deg), indexing="ij")
    n_k = len(phase_functions)
    source = np.zeros((n_s, n_v * n_phi, n_u, n_k * n_c))
    for k in active:
        kern = _channel_kernels(phase_functions[k], -MV.ravel(), PH.ravel(), mu_q, sol["phi"], w_q, n_c)
        source[lit, ..., k * n_c:(k + 1) * n_c] = np.stack(
            [np.einsum("oq,uqs->sou", kern[c], rad[..., c], optimize=True) for c in range(n_c)], axis=-1)
    source = source.reshape(n_s, n_v, n_phi, n_u, n_k * n_c)

    down = mu_q < 0
    diffuse_down = np.zeros((n_u, n_s, n_c))
    diffuse_down[:, lit] = np.einsum("q,uqsc->usc", (w_q * np.abs(mu_q) / (4 * np.pi))[down], rad[:, down])
    scalar = np.zeros((n_u, n_s, n_c))
    scalar[:, lit] = np.einsum("q,uqsc->usc", w_q / (4 * np.pi), rad)
    log.debug("diffuse source table: %d orders, tau = %s", sol["orders"], d_tau.sum(axis=0))
    return DiffuseSourceTable(u=u, t_s=t_s, mu_v=mu_v, phi_deg=phi_deg, source=source.astype(np.float32),
                              diffuse_down=diffuse_down, scalar_diffuse=scalar, orders=sol["orders"])


def aerosol_layer_albedo(tau, ssa, phase_function, mu0, n_layers=None, n_half=24, max_orders=400):
    """Plane albedo of an isolated aerosol layer and its multiple-scattering albedo omega' (Eqs. 30-31).

    The layer (no gas, black ground) is solved by successive orders of scattering; its albedo a is the
    reflected flux over the incident flux mu0 E. Eq. 31 writes a = omega' b tau / (1 + b tau), where
    b tau / (1 + b tau) is the albedo of the same layer without absorption (Eq. 6); omega' is therefore the
    ratio of the absorbing layer's albedo to the conservative one's. It tends to omega for a thin layer
    (Eq. 30: absorption acts once per scattering) and falls as tau grows (each of the more numerous
    scatterings may absorb), while a itself tends to the albedo of a semi-infinite layer, 0.3-0.5 for smoke
    and dust according to the paper.

    The renderer does not use this function: it gets the same physics, per column, from the
    successive-orders tables of :func:`swim.rt.gas.build_gas_tables` (column classes); this is the
    diagnostic that reports a and omega' for a layer (docs/aerosols.md §8).

    Parameters
    ----------
    tau : float
        Optical depth of the layer [-], > 0.
    ssa : array_like
        Shape (C,) or scalar: single-scattering albedo omega [-], in (0, 1].
    phase_function : callable
        cos θ -> P(θ), mean 1 over the sphere, grey or with a last axis of C channels.
    mu0 : float
        Cosine of the solar zenith angle [-], in (0, 1].
    n_layers : int, optional
        Sub-layers (thinner at the top, where the single-scattering source varies fastest); default
        4 tau, at least 24 and at most 120.
    n_half : int
        Gauss cosines per hemisphere (24 resolves the forward peak of dust, g ~ 0.86, to ~1 % of DISORT's
        flux; the renderer's tables use 10).
    max_orders : int
        Orders of scattering at most (a geometric tail is added on convergence).

    Returns
    -------
    dict
        ``albedo`` (C,): plane albedo a [-]; ``albedo_conservative`` (C,): the same layer with omega = 1;
        ``omega_prime`` (C,): a / albedo_conservative [-] (Eq. 31).

    Raises
    ------
    ValueError
        tau <= 0, ssa outside (0, 1] or mu0 outside (0, 1].

    References
    ----------
    Albers et al. (2020), Sect. 3.5.4, Eqs. 30-31, doi:10.5194/amt-13-3235-2020.
    """
    ssa = np.atleast_1d(np.asarray(ssa, dtype=float))
    if not (np.isfinite(tau) and tau > 0):
        raise ValueError(f"aerosol layer optical depth must be > 0, got {tau}")
    if np.any(~(ssa > 0)) or np.any(ssa > 1):
        raise ValueError(f"single-scattering albedo must be in (0, 1], got {ssa}")
    if not (0 < mu0 <= 1):
        raise ValueError(f"mu0 must be in (0, 1], got {mu0}")
    n_c = ssa.size
    n_layers = int(np.clip(np.ceil(4 * tau), 24, 120)) if n_layers is None else int(n_layers)
    edges = tau * np.linspace(0.0, 1.0, n_layers + 1) ** 2  # top first, thin layers near the top
    d_tau = np.repeat(np.diff(edges)[:, None], n_c, axis=1)
    phase = tabulated_phase_function(phase_function)

    def albedo(omega):
        sol = successive_orders_plane_parallel(d_tau, np.broadcast_to(omega, d_tau.shape), np.ones((1,) + d_tau.shape),
                                               np.array([mu0]), np.zeros(n_c), [phase], n_half=n_half,
                                               max_orders=max_orders)
        up = sol["mu"] > 0
        flux = np.einsum("q,qc->c", (sol["weight"] * sol["mu"] / (4 * np.pi))[up], sol["radiance"][0, up, 0])
        return flux / mu0

    a = albedo(ssa)
    a_cons = albedo(np.ones(n_c))
    return {"albedo": a, "albedo_conservative": a_cons, "omega_prime": a / a_cons}
