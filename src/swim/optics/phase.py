"""Phase functions, thin/thick-cloud effective phase functions and cloud-top reflectance of SWIm.

Source: Albers et al. (2020), Atmos. Meas. Tech. 13, 3235-3261, doi:10.5194/amt-13-3235-2020 ("the paper"),
Sects. 3.4.1-3.4.3, 3.5.1 and Appendix B. Every decision taken where the printed equations are ambiguous or
non-physical is listed, with the numerical checks behind it, in docs/phase-functions.md.

Conventions
-----------
* ``cos_theta`` is cos θ of the scattering angle, ``dot(sun_dir, view_dir)`` (θ = 0 forward, looking at the
  sun; see :mod:`swim.frames`).
* Every *phase function* is normalised to a mean of 1 over the sphere (integral over 4π sr equals 4π), as the
  paper states below its Eq. 9. The thick-cloud terms (Eqs. 19-21) and the reflectance factor (Eq. 25) are
  empirical radiance factors, not normalised phase functions.
* All functions compute in the array library of their inputs (:mod:`swim.arrays`): numpy for numpy input,
  ``jax.numpy`` where any input is a JAX array or tracer, on which they run inside ``jax.jit`` (float32 by
  default) and are differentiable. They accept inputs of any broadcastable shapes and return an array of that
  library. They do no input validation (values cannot be inspected under tracing); callers validate user input.
"""

from __future__ import annotations

from ..arrays import array_namespace
from ..constants import SPECIES

#: Asymmetry parameters g_λ of the cloud-liquid forward peak at the SWIm reference wavelengths 615, 546 and
#: 450 nm, i.e. in the order of :data:`swim.constants.WAVELENGTHS_NM` (paper Eq. 16).
G_LIQUID = (0.945, 0.950, 0.955)
#: Largest Venus phase angle of the Mallama et al. (2006) observations and of their fit [deg]; the thick-cloud
#: phase function is held constant for smaller scattering angles (θ < 1°) instead of diverging.
VENUS_MAX_PHASE_ANGLE_DEG = 179.0
#: Phase angle [deg] where the Mallama et al. (2006) fit switches from the quartic to the quadratic branch.
VENUS_BRANCH_PHASE_ANGLE_DEG = 163.7
#: Absolute V magnitude of Venus at full phase, 1 AU from sun and observer (Mallama et al. 2006) [mag].
VENUS_V10 = -4.384
#: Coefficients of α, α², α³, α⁴ [mag deg^-k] of the Mallama et al. (2006) fit below
#: :data:`VENUS_BRANCH_PHASE_ANGLE_DEG` (:func:`venus_magnitude_mallama2006`).
VENUS_NEAR_COEFFICIENTS = (-1.044e-3, 3.687e-4, -2.814e-6, 8.938e-9)
#: Coefficients of 1, α, α² [mag deg^-k] of its branch beyond, relative to full phase (236.05828 - V(1, 0)).
VENUS_FAR_COEFFICIENTS = (236.05828 - VENUS_V10, -2.81914, 8.39034e-3)
#: Normalising numerator of the thick, sunlit cloud phase function (paper Eq. 19) [-].
THICK_HIGH_NUMERATOR = 1.94
#: Coefficients b1, b2 of the Kokhanovsky (2004) reflectance factor, paper Eq. 25 and Sect. 3.4.3 [-].
KOKHANOVSKY_B1, KOKHANOVSKY_B2 = 1.48, 7.76
#: Double Henyey-Greenstein parameters g, f_b of the cloud phase function in the reflectance factor (water cloud,
#: paper Sect. 3.4.3) [-].
ARF_DHG_G, ARF_DHG_FB = 0.7, 0.4
#: Floor on cos z + cos z0 in the reflectance factor, to keep it finite at grazing sun and view [-].
ARF_MIN_MU_SUM = 1e-3
#: Floor on mu0 in :func:`diffuse_transmission_factor`: at low sun the skylight, whose transmitted flux does
#: not scale with mu0, is ~10-20 % of the scalar irradiance (D / (t + 2D) with the clear-sky tables) [-].
DIFFUSE_TRANSMISSION_MIN_MU0 = 0.15
#: Fraction f of the light scattered by a hydrometeor that goes into its narrow forward (diffraction) peak
#: and so stays in the beam: for particles much larger than the wavelength the extinction efficiency tends to
#: 2, half of it diffraction into a cone of ~lambda / (pi D) (0.5° for 10 um droplets at 546 nm); used to
#: delta-scale the view-path attenuation of the thin-cloud term (:func:`delta_scaled_path_factor`) [-].
FORWARD_PEAK_FRACTION = 0.5
#: Lobes of the thin-cloud phase functions of ice, rain and snow (paper Eqs. B1-B3; ice with the sign of its
#: isotropic term fixed, docs/phase-functions.md), in the argument order of :func:`_thin_lobes`: forward weight,
#: forward g (raised to τ'), middle weight, middle g (raised to τ'), isotropic weight, back weight, back g.
#: Graupel takes the rain form. One table for the array functions here and the CPU composition
#: (:mod:`swim.rt.compose_cpu`).
THIN_LOBES = {
    "cloud_ice": (0.50, 0.999, 0.21, 0.991, 0.25, 0.04, -0.2),
    "rain": (0.10, 0.99, 1.05, 0.75, -0.35, 0.20, -0.2),
    "snow": (0.50, 0.999, 0.45, 0.991, 0.03, 0.02, -0.2),
}
THIN_LOBES["graupel"] = THIN_LOBES["rain"]
#: Cloud liquid's forward-peak weight f1 = 0.8^τ' (paper Eq. 17 as interpreted, docs/phase-functions.md) [-].
LIQUID_FORWARD_WEIGHT_BASE = 0.8
#: The other lobes of cloud liquid's thin phase function (paper Eq. 18): the forward and middle weights' sum
#: (the middle weight is 1.06 - f1), middle g (raised to τ'), isotropic weight, back weight, back g.
LIQUID_THIN_LOBES = (1.06, 0.6, -0.08, 0.02, -0.6)


def henyey_greenstein(cos_theta, g):
    """Henyey-Greenstein phase function, mean 1 over the sphere (paper Eq. 9).

    Parameters
    ----------
    cos_theta : array_like
        cos θ of the scattering angle [-], any shape.
    g : array_like
        Asymmetry parameter [-], -1 < g < 1, broadcastable with ``cos_theta``.

    Returns
    -------
    numpy.ndarray or jax.Array
        p(θ, g) = (1 - g²) / (1 + g² - 2 g cos θ)^{3/2} [-], shape ``broadcast(cos_theta, g)``.
        |g| = 1 gives inf/NaN at the peak.

    Notes
    -----
    The denominator is evaluated as (1 - g)² + 2 g (1 - cos θ), algebraically identical but free of the float32
    cancellation of 1 + g² - 2 g cos θ near the forward peak (g = 0.999 peaks at 2e6).

    Source: Henyey, L. G. and Greenstein, J. L. (1941), Astrophys. J. 93, 70-83, doi:10.1086/144246;
    paper Eq. 9.
    """
    xp = array_namespace(cos_theta, g)
    mu = xp.asarray(cos_theta)
    g = xp.asarray(g)
    d = (1.0 - g) ** 2 + 2.0 * g * (1.0 - mu)
    return (1.0 - g * g) / (d * xp.sqrt(d))


def double_henyey_greenstein(cos_theta, g, fb):
    """Double Henyey-Greenstein (DHG) phase function of Louedec et al. (2012), mean 1 over the sphere (Eq. 27).

    Parameters
    ----------
    cos_theta : array_like
        cos θ [-], any shape.
    g : array_like
        Asymmetry parameter of the forward lobe [-], -1 < g < 1.
    fb : array_like
        Backscatter-lobe parameter f_b [-] (0 ... 1 keeps the function positive for all g in [0, 0.99]).

    Returns
    -------
    numpy.ndarray or jax.Array
        P(θ) = (1 - g²) [ (1 + g² - 2 g cos θ)^{-3/2} + f_b (3 cos²θ - 1) / (2 (1 + g²)^{3/2}) ],
        broadcast shape.

    Notes
    -----
    The paper's Eq. 27 omits the exponent 3/2 of the first denominator; as printed its mean over the sphere is
    0.63 for g = 0.7 (0.15 for g = 0.962), not 1. With the exponent the first term is the Henyey-Greenstein
    function (mean 1) and the second a Legendre P2 term (mean 0), so the mean is exactly 1 for any f_b,
    matching the paper's claim of unit normalisation. Decision recorded in docs/phase-functions.md.

    Source: paper Eq. 27 and Sect. 3.5.1, after Louedec et al. (2012) as cited there (the form with the 3/2
    exponent is the one whose normalisation the paper asserts).
    """
    xp = array_namespace(cos_theta, g, fb)
    mu = xp.asarray(cos_theta)
    g = xp.asarray(g)
    one_g2 = 1.0 + g * g
    backlobe = xp.asarray(fb) * (3.0 * mu * mu - 1.0) / (2.0 * one_g2 * xp.sqrt(one_g2))
    return henyey_greenstein(mu, g) + (1.0 - g * g) * backlobe


def two_term_double_henyey_greenstein(cos_theta, g1, g2, fb, fc):
    """Mixture of two DHG functions for bimodal (fine + coarse) aerosol (paper Eq. 28).

    Parameters
    ----------
    cos_theta : array_like
        cos θ [-].
    g1, g2 : array_like
        Asymmetry parameters of the first and second DHG [-].
    fb : array_like
        Backscatter parameter shared by both DHGs [-].
    fc : array_like
        Fraction of the photons in the first DHG [-], 0 ... 1.

    Returns
    -------
    numpy.ndarray or jax.Array
        f_c P(θ, g1, f_b) + (1 - f_c) P(θ, g2, f_b), mean 1 over the sphere; broadcast shape.

    Source: paper Eq. 28 (with the Eq. 27 decision of :func:`double_henyey_greenstein`).
    """
    xp = array_namespace(cos_theta, g1, g2, fb, fc)
    mu = xp.asarray(cos_theta)
    fc = xp.asarray(fc)
    return fc * double_henyey_greenstein(mu, g1, fb) + (1.0 - fc) * double_henyey_greenstein(mu, g2, fb)


def _multiple_scattering_order(tau_o):
    """Exponent τ' = max(τ_o, 1) of the effective asymmetry parameters g' = g^τ' (paper Sect. 3.4.2 text)."""
    xp = array_namespace(tau_o)
    return xp.maximum(xp.asarray(tau_o), 1.0)


def _thin_lobes(mu, tp, forward, g_forward, middle, g_middle, isotropic, back, g_back):
    """Common form of Eqs. 18 and B1-B3: two HG lobes broadened as g^τ', an isotropic term (p(θ, 0) = 1) and a
    fixed back lobe: ``forward p(g_forward^τ') + middle p(g_middle^τ') + isotropic + back p(g_back)``."""
    xp = array_namespace(mu, tp, forward, g_forward)
    return (
        forward * henyey_greenstein(mu, xp.asarray(g_forward) ** tp)
        + middle * henyey_greenstein(mu, g_middle**tp)
        + isotropic
        + back * henyey_greenstein(mu, g_back)
    )


def phase_thin_cloud_liquid(cos_theta, tau_o, g_lambda):
    """Effective phase function of an optically thin liquid cloud (paper Eqs. 16-18, as interpreted).

    Parameters
    ----------
    cos_theta : array_like
        cos θ [-].
    tau_o : array_like
        Optical thickness τ_o along the backward ray from the observer [-], ≥ 0.
    g_lambda : array_like
        Asymmetry parameter of the forward (corona) peak at the wavelength [-]: 0.945, 0.950, 0.955 at 615,
        546, 450 nm (:data:`G_LIQUID`, Eq. 16).

    Returns
    -------
    numpy.ndarray or jax.Array
        P_thin = f1 p(θ, g_λ^τ') + (1.06 - f1) p(θ, 0.6^τ') + 0.02 p(θ, -0.6) - 0.08 p(θ, 0), with
        τ' = max(τ_o, 1) and f1 = 0.8^τ'; mean 1 over the sphere and ≥ 0.015 for all θ and τ_o ≥ 0.

    Notes
    -----
    Printed literally (f1 = 0.8 × τ_o and g^τ_o) Eqs. 17-18 are non-physical: at τ_o → 0 the peak g^τ_o → 1
    becomes a delta function while its weight f1 → 0, and for τ_o > 1.325 the weight 1.06 - f1 turns
    negative. Following the text ("When τ_o > 1, we consider g' = g^τ_o") the exponent is τ' = max(τ_o, 1),
    and f1 = 0.8^τ' (the forward-peak weight decays as the scattering order grows) as in the SWIm reference
    code (LAPS ``get_cloud_pf.f90``: ``clwc_bin1a = 0.80**sco`` with ``sco = max(tau, 1)``); see
    docs/phase-functions.md for the comparison with the alternative f1 = 0.8 min(τ_o, 1).

    Source: paper Eqs. 16-18 and Sect. 3.4.2.
    """
    xp = array_namespace(cos_theta, tau_o, g_lambda)
    mu = xp.asarray(cos_theta)
    tp = _multiple_scattering_order(xp.asarray(tau_o))
    f1 = LIQUID_FORWARD_WEIGHT_BASE**tp
    total, g_middle, isotropic, back, g_back = LIQUID_THIN_LOBES
    return _thin_lobes(mu, tp, f1, g_lambda, total - f1, g_middle, isotropic, back, g_back)


def phase_thin_rain(cos_theta, tau_o):
    """Effective phase function of optically thin rain (paper Eq. B1).

    Parameters
    ----------
    cos_theta : array_like
        cos θ [-].
    tau_o : array_like
        Optical thickness τ_o along the backward ray [-], ≥ 0.

    Returns
    -------
    numpy.ndarray or jax.Array
        0.10 p(θ, 0.99^τ') + 1.05 p(θ, 0.75^τ') - 0.35 p(θ, 0) + 0.20 p(θ, -0.2), τ' = max(τ_o, 1); mean 1,
        ≥ 0.027 for all θ and τ_o ≥ 0.

    Notes
    -----
    The paper's ``p(θ 0.99^τ0)`` means p(θ, g = 0.99^τ_o); the exponent is τ' = max(τ_o, 1) as for liquid.

    Source: paper Eq. B1.
    """
    xp = array_namespace(cos_theta, tau_o)
    mu = xp.asarray(cos_theta)
    tp = _multiple_scattering_order(xp.asarray(tau_o))
    return _thin_lobes(mu, tp, *THIN_LOBES["rain"])


def phase_thin_cloud_ice(cos_theta, tau_o):
    """Effective phase function of an optically thin ice cloud (paper Eq. B2, sign of the isotropic term fixed).

    Parameters
    ----------
    cos_theta : array_like
        cos θ [-].
    tau_o : array_like
        Optical thickness τ_o along the backward ray [-], ≥ 0.

    Returns
    -------
    numpy.ndarray or jax.Array
        0.50 p(θ, 0.999^τ') + 0.21 p(θ, 0.991^τ') + 0.25 p(θ, 0) + 0.04 p(θ, -0.2), τ' = max(τ_o, 1); mean 1,
        ≥ 0.28 for all θ and τ_o ≥ 0; asymmetry parameter 0.70 for τ_o ≤ 1.

    Notes
    -----
    As printed (0.71 p(0.991) - 0.25 p(0)) Eq. B2 is negative over most of the sphere for every τ_o < 79.5
    (minimum -0.21 at θ = 74°, 19 % of the energy in the negative part) and its asymmetry parameter would be
    1.19 > 1, impossible for a non-negative phase function; clipping at zero would leave thin cirrus
    invisible at scattering angles beyond 23° (for τ_o ≤ 1). The SWIm reference code (LAPS
    ``get_scat_pf.f90``) adds the isotropic ice term with a positive weight (+0.25) and gives the second lobe
    the remainder 1 - (0.50 + 0.25 + 0.04) = 0.21. We adopt these weights with the paper's lobes: same
    normalisation, non-negative everywhere.

    Source: paper Eq. B2 (corrected, see docs/phase-functions.md).
    """
    xp = array_namespace(cos_theta, tau_o)
    mu = xp.asarray(cos_theta)
    tp = _multiple_scattering_order(xp.asarray(tau_o))
    return _thin_lobes(mu, tp, *THIN_LOBES["cloud_ice"])


def phase_thin_snow(cos_theta, tau_o):
    """Effective phase function of optically thin snow (paper Eq. B3).

    Parameters
    ----------
    cos_theta : array_like
        cos θ [-].
    tau_o : array_like
        Optical thickness τ_o along the backward ray [-], ≥ 0.

    Returns
    -------
    numpy.ndarray or jax.Array
        0.50 p(θ, 0.999^τ') + 0.45 p(θ, 0.991^τ') + 0.03 p(θ, 0) + 0.02 p(θ, -0.2), τ' = max(τ_o, 1); mean 1,
        ≥ 0.05 for all θ and τ_o ≥ 0.

    Source: paper Eq. B3.
    """
    xp = array_namespace(cos_theta, tau_o)
    mu = xp.asarray(cos_theta)
    tp = _multiple_scattering_order(xp.asarray(tau_o))
    return _thin_lobes(mu, tp, *THIN_LOBES["snow"])


def phase_thin_graupel(cos_theta, tau_o):
    """Effective phase function of optically thin graupel: the rain form (paper Eq. B1).

    Parameters
    ----------
    cos_theta : array_like
        cos θ [-].
    tau_o : array_like
        Optical thickness τ_o along the backward ray [-], ≥ 0.

    Returns
    -------
    numpy.ndarray or jax.Array
        :func:`phase_thin_rain` (cos_theta, tau_o); mean 1, non-negative.

    Notes
    -----
    The paper gives no graupel phase function ("Graupel has yet to be tested in SWIm", Sect. 3.4.3). Graupel
    particles are mm-sized, near-spherical rimed ice, optically closer to large drops than to pristine
    crystals, so we use the rain form B1 (also the forward peak of B2/B3, g = 0.999, is a signature of
    pristine plates that graupel lacks).

    Source: paper Eq. B1 (project decision, docs/phase-functions.md).
    """
    return phase_thin_rain(cos_theta, tau_o)


def venus_magnitude_mallama2006(phase_angle_deg):
    """V-band magnitude of Venus relative to full phase, m(α) = V(1, α) - V(1, 0) (Mallama et al. 2006).

    Parameters
    ----------
    phase_angle_deg : array_like
        Phase angle α = 180° - θ [deg]; the fit covers the observed 2.2° ... 179° (it extrapolates to
        m(0) = 0).

    Returns
    -------
    numpy.ndarray or jax.Array
        m(α) [mag], broadcast shape: -1.044e-3 α + 3.687e-4 α² - 2.814e-6 α³ + 8.938e-9 α⁴ for α < 163.7°,
        240.44228 - 2.81914 α + 8.39034e-3 α² (that is 236.05828 - ... + 4.384) beyond.

    Notes
    -----
    Published absolute form: V(1, α) = -4.384 + m(α). The two branches differ by 0.0076 mag at 163.7°.
    The phase integral q = 2 ∫ 10^(-0.4 m(α)) sin α dα of this fit is 1.349, the 1.35 of the paper's
    abstract. Coefficients verified against Mallama and Hilton (2018), Astron. Comput. 25, 10-24,
    doi:10.1016/j.ascom.2018.08.002, which reproduces them.

    Source: Mallama, A., Wang, D. and Howard, R. A. (2006), Venus phase function and forward scattering from
    H2SO4, Icarus 182, 10-22, doi:10.1016/j.icarus.2005.12.014.
    """
    xp = array_namespace(phase_angle_deg)
    a = xp.asarray(phase_angle_deg)
    c1, c2, c3, c4 = VENUS_NEAR_COEFFICIENTS
    f0, f1, f2 = VENUS_FAR_COEFFICIENTS
    near = a * (c1 + a * (c2 + a * (c3 + a * c4)))
    far = f0 + a * (f1 + a * f2)
    return xp.where(a < VENUS_BRANCH_PHASE_ANGLE_DEG, near, far)


def phase_thick_high(cos_theta):
    """Effective phase function of a thick, directly sunlit cloud surface from the Venus phase law (Eq. 19).

    Parameters
    ----------
    cos_theta : array_like
        cos θ [-].

    Returns
    -------
    numpy.ndarray or jax.Array
        P_thick,h = 1.94 · 10^(-0.4 m(α)) / ((1 - cos θ)/2), α = 180° - θ, with the relative magnitude m of
        :func:`venus_magnitude_mallama2006`; 1.94 at θ = 180°, 1.04 at 90°, 351 at θ ≤ 1°.

    Notes
    -----
    With the relative magnitude P_thick,h(180°) = 1.94, so 2 P_thick,h ≈ 3.9 ≈ 4, the L' of a white Lambertian
    surface facing the sun (paper Eq. 2 remark); with absolute magnitudes Eq. 19 would give ~110. The
    illuminated fraction (1 - cos θ)/2 → 0 as θ → 0: we hold α ≤ 179° (the end of Mallama's data), i.e.
    θ ≥ 1°, where P_thick,h = 351; the SWIm reference code caps it at 600 instead, reached only for θ < 0.8°.
    The fraction is evaluated as sin²(θ/2) to avoid float32 cancellation.

    Source: paper Eq. 19; Mallama et al. (2006), doi:10.1016/j.icarus.2005.12.014.
    """
    xp = array_namespace(cos_theta)
    mu = xp.clip(xp.asarray(cos_theta), -1.0, 1.0)
    theta_deg = xp.degrees(xp.arccos(mu))
    alpha = xp.clip(180.0 - theta_deg, 0.0, VENUS_MAX_PHASE_ANGLE_DEG)
    illuminated_fraction = xp.sin(xp.radians(180.0 - alpha) / 2.0) ** 2
    return THICK_HIGH_NUMERATOR * 10.0 ** (-0.4 * venus_magnitude_mallama2006(alpha)) / illuminated_fraction


def phase_thick_low(cos_view_zenith):
    """Effective phase function of a thick, indirectly lit (dark) cloud base (paper Eq. 20).

    Parameters
    ----------
    cos_view_zenith : array_like
        cos z of the view direction's zenith angle at the observer [-] (1 looking straight up).

    Returns
    -------
    numpy.ndarray or jax.Array
        P_thick,l = (1 + 2 max(cos z, 0)) / 3 [-]: 1 at zenith, 1/3 at and below the horizon.

    Notes
    -----
    Eq. 20 has (1 + 2 cos z)/3 while the prose of Sect. 3.4.2 writes (1 + 4 cos z)/3; the equation is
    implemented (the reference code has the prose form with a factor 2 instead of 4 in Eq. 21; see
    docs/phase-functions.md). For downward views (cos z < 0, e.g. from aircraft) cos z is clipped to 0, the
    horizon value, instead of letting the brightness fall below the horizon's or turn negative.

    Source: paper Eq. 20.
    """
    xp = array_namespace(cos_view_zenith)
    return (1.0 + 2.0 * xp.maximum(xp.asarray(cos_view_zenith), 0.0)) / 3.0


def blend_coefficient(tau_o, irradiance_ratio):
    """Thin/thick blending weight c1 = c3 = exp(-(τ_o/10)²) E/E_TOA (paper Eqs. 14 and 22).

    Parameters
    ----------
    tau_o : array_like
        Optical thickness τ_o along the backward ray [-].
    irradiance_ratio : array_like
        Scalar irradiance at the scattering point relative to the TOA irradiance, E_λ/E_TOA,λ [-] (Eq. 8).

    Returns
    -------
    numpy.ndarray or jax.Array
        c [-] in 0 ... 1, broadcast shape.

    Notes
    -----
    E/E_TOA is clipped to 0 ... 1 (Eq. 8 bounds it so; the guard keeps c2 = 1 - c1 non-negative).

    Source: paper Eqs. 14, 15, 22, 23.
    """
    xp = array_namespace(tau_o, irradiance_ratio)
    tau = xp.asarray(tau_o)
    return xp.exp(-((tau / 10.0) ** 2)) * xp.clip(xp.asarray(irradiance_ratio), 0.0, 1.0)


def diffuse_transmission_factor(cos_sun_zenith):
    """Factor turning the Step 1a irradiance of a cloud base into its diffusely transmitted radiance (Eq. 21, c4 term).

    Parameters
    ----------
    cos_sun_zenith : array_like
        mu0 = cos z0 of the sun [-].

    Returns
    -------
    numpy.ndarray or jax.Array
        (9/7) max(mu0, :data:`DIFFUSE_TRANSMISSION_MIN_MU0`) [-]: 1.11 at z0 = 30°, 0.64 at 60°.

    Notes
    -----
    T of Eqs. 4-6 is Stephens' (1978) *flux* transmittance: the cloud passes the horizontal flux
    F = mu0 T E_TOA (direct + diffuse; the ground term of the renderer uses it so). Below a thick cloud the
    diffuse light leaves the base with the angular distribution of the escape function,
    K(mu) = (3/7)(1 + 2 mu), normalised to 2 int K mu dmu = 1 (the (1 + 2 cos z)/3 of Eq. 20 is exactly this
    shape), so L' = 4 pi I / E_TOA = 4 (F / E_TOA) K(mu) = 4 [(9/7) mu0 T] (1 + 2 cos z)/3. Eq. 21 as printed
    multiplies 4 P_thick,l(z) by E/E_TOA ~ T instead, i.e. without the factor (9/7) mu0: 56 % too bright at
    z0 = 60° and 11 % too dark at z0 = 30° against DISORT under a uniform stratus (docs/rendering.md,
    "Overcast accuracy"; the paper's own overcast GHI was ~50 % too high). The skylight share of the
    illumination does not scale with mu0; the floor keeps cloud bases lit at low sun.

    Source: escape function of the asymptotic theory of thick layers (e.g. van de Hulst 1980, Multiple Light
    Scattering, Vol. 2; Kokhanovsky 2006, Cloud Optics, Sect. 4); Stephens (1978), J. Atmos. Sci. 35, 2123.
    """
    xp = array_namespace(cos_sun_zenith)
    return (9.0 / 7.0) * xp.maximum(xp.asarray(cos_sun_zenith), DIFFUSE_TRANSMISSION_MIN_MU0)


def delta_scaled_path_factor(tau_o, forward_fraction=FORWARD_PEAK_FRACTION):
    """Singly scattered light of a path of optical depth τ_o with the forward peak kept in the beam.

    Parameters
    ----------
    tau_o : array_like
        Optical thickness along the backward (view) ray [-], ≥ 0.
    forward_fraction : array_like, optional
        Fraction f of the scattered light in the narrow forward peak (:data:`FORWARD_PEAK_FRACTION`).

    Returns
    -------
    numpy.ndarray or jax.Array
        (1 - e^{-(1 - f) τ_o}) / (1 - f) [-]: τ_o for τ_o ≪ 1, 1/(1 - f) for τ_o → ∞; replaces Eq. 12's
        1 - e^{-τ_o} in the thin-cloud term (c1 P_thin) of the renderer.

    Notes
    -----
    Eq. 12 attenuates the light scattered towards the observer by e^{-τ_o}, i.e. it counts everything the
    hydrometeors scatter as lost from the view ray. Light scattered into the diffraction peak (θ ≲ 1°) is
    not lost: it goes on in nearly the same direction. The delta-M / delta-Eddington scaling (Joseph et al.
    1976; Wiscombe 1977) writes P = 2f δ(1 - cos θ) + (1 - f) P*, τ* = (1 - f) τ, ω* τ* P* = τ P outside the
    peak, so the single-scattering line integral along the view ray is ∫ P E e^{-(1 - f) τ} dτ =
    P Ē (1 - e^{-(1 - f) τ_o}) / (1 - f). The thick-cloud term (Eqs. 19-21) is an empirical radiance factor
    calibrated with Eq. 12's factor → 1 and keeps it. Numerical evidence (DISORT, uniform stratus):
    docs/rendering.md, "Overcast accuracy".

    Source: Joseph, Wiscombe and Weinman (1976), doi:10.1175/1520-0469(1976)033<2452:TDEAFR>2.0.CO;2;
    Wiscombe (1977), J. Atmos. Sci. 34, 1408-1422, doi:10.1175/1520-0469(1977)034<1408:TDMRYA>2.0.CO;2.
    """
    xp = array_namespace(tau_o, forward_fraction)
    tau = xp.asarray(tau_o)
    one_f = 1.0 - xp.asarray(forward_fraction)
    return -xp.expm1(-one_f * tau) / one_f


def phase_thick(cos_theta, cos_view_zenith, c3, low_irradiance_factor=1.0):
    """Effective phase function of an optically thick cloud (paper Eq. 21).

    Parameters
    ----------
    cos_theta : array_like
        cos θ [-].
    cos_view_zenith : array_like
        cos z of the view direction at the observer [-].
    c3 : array_like
        Weight of the sunlit part, :func:`blend_coefficient` [-], 0 ... 1.
    low_irradiance_factor : array_like, optional
        Multiplies the indirectly lit term, e.g. :func:`diffuse_transmission_factor` for views from below
        [-]; default 1 (Eq. 21 as printed).

    Returns
    -------
    numpy.ndarray or jax.Array
        P_thick = 2 c3 P_thick,h(θ) + 4 (1 - c3) f P_thick,l(z), broadcast shape.

    Source: paper Eqs. 21-23.
    """
    xp = array_namespace(cos_theta, cos_view_zenith, c3, low_irradiance_factor)
    c3 = xp.asarray(c3)
    low = 4.0 * (1.0 - c3) * xp.asarray(low_irradiance_factor) * phase_thick_low(xp.asarray(cos_view_zenith))
    return 2.0 * c3 * phase_thick_high(xp.asarray(cos_theta)) + low


def effective_phase_function(cos_theta, cos_view_zenith, tau_o, irradiance_ratio, species_weights, g_liquid,
                             low_irradiance_factor=1.0):
    """Effective (multiple-scattering) phase function of a hydrometeor mixture (paper Eq. 13).

    Parameters
    ----------
    cos_theta : array_like
        cos θ [-], shape S (any, broadcastable with the other per-sample arguments).
    cos_view_zenith : array_like
        cos z of the view direction at the observer [-], broadcastable with S.
    tau_o : array_like
        Optical thickness τ_o along the backward ray [-], broadcastable with S.
    irradiance_ratio : array_like
        E_λ/E_TOA,λ at the scattering point [-], broadcastable with S.
    species_weights : array_like
        Shape S + (5,): τ-weighted fractions of the species in the order of :data:`swim.constants.SPECIES`
        (cloud_liquid, cloud_ice, rain, snow, graupel); they sum to 1 where there is cloud.
    g_liquid : array_like
        Cloud-liquid forward-peak asymmetry parameter at the wavelength (:data:`G_LIQUID`).
    low_irradiance_factor : array_like, optional
        Passed to :func:`phase_thick` (default 1: Eq. 21 as printed).

    Returns
    -------
    numpy.ndarray or jax.Array
        P = c1 Σ_s w_s P_thin,s(θ, τ_o) + (1 - c1) P_thick(θ, z, c3), c1 = c3 = :func:`blend_coefficient`;
        shape S.

    Notes
    -----
    The paper's "interpolate between the results of Eqs. (18) and (B1)" for mixtures is this τ-weighted mean of
    the per-species thin functions, which keeps the thin part normalised and non-negative. All species see the
    same τ_o (the total along the ray) in their exponents τ' = max(τ_o, 1). Where all weights are 0 the thin
    part vanishes and P = (1 - c1) P_thick.

    Source: paper Eqs. 13-15, 18, 21 and B1-B3.
    """
    xp = array_namespace(cos_theta, cos_view_zenith, tau_o, irradiance_ratio, species_weights, g_liquid,
                         low_irradiance_factor)
    mu = xp.asarray(cos_theta)
    tau = xp.asarray(tau_o)
    c1 = blend_coefficient(tau, irradiance_ratio)
    p_thin = phase_thin_mixture(mu, tau, species_weights, g_liquid)
    return c1 * p_thin + (1.0 - c1) * phase_thick(mu, cos_view_zenith, c1, low_irradiance_factor)


def phase_thin_mixture(cos_theta, tau_o, species_weights, g_liquid):
    """τ-weighted mean of the per-species thin-cloud phase functions (Eqs. 18 and B1-B3), P_thin of Eq. 13.

    Parameters
    ----------
    cos_theta, tau_o : array_like
        cos θ [-] and the optical thickness along the backward ray [-], broadcastable (shape S).
    species_weights : array_like
        Shape S + (5,): τ-weighted species fractions in the order of :data:`swim.constants.SPECIES`.
    g_liquid : array_like
        Cloud-liquid forward-peak asymmetry parameter (:data:`G_LIQUID`).

    Returns
    -------
    numpy.ndarray or jax.Array
        Σ_s w_s P_thin,s(θ, τ_o), shape S; mean 1 over the sphere where the weights sum to 1.

    Source: paper Eqs. 13, 18 and B1-B3 (see :func:`effective_phase_function`).
    """
    xp = array_namespace(cos_theta, tau_o, species_weights, g_liquid)
    mu = xp.asarray(cos_theta)
    tau = xp.asarray(tau_o)
    thin_by_species = {
        "cloud_liquid": lambda: phase_thin_cloud_liquid(mu, tau, g_liquid),
        "cloud_ice": lambda: phase_thin_cloud_ice(mu, tau),
        "rain": lambda: phase_thin_rain(mu, tau),
        "snow": lambda: phase_thin_snow(mu, tau),
        "graupel": lambda: phase_thin_graupel(mu, tau),
    }
    thin = xp.stack(xp.broadcast_arrays(*[thin_by_species[s]() for s in SPECIES]), axis=-1)
    return xp.sum(xp.asarray(species_weights) * thin, axis=-1)


def forward_peak_mixture(cos_theta, tau_o, species_weights, g_liquid):
    """The forward-peak lobes of :func:`phase_thin_mixture` alone (the first term of Eqs. 18, B1-B3).

    Returns
    -------
    numpy.ndarray or jax.Array
        Σ_s w_s f_s p(θ, g_s^τ'), shape S; its mean over the sphere is Σ_s w_s f_s.
    """
    xp = array_namespace(cos_theta, tau_o, species_weights, g_liquid)
    mu = xp.asarray(cos_theta)
    tp = _multiple_scattering_order(xp.asarray(tau_o))
    lobes = []
    for s in SPECIES:
        if s == "cloud_liquid":
            f, g = LIQUID_FORWARD_WEIGHT_BASE**tp, g_liquid
        else:
            f, g = THIN_LOBES[s][:2]
        lobes.append(f * henyey_greenstein(mu, xp.asarray(g) ** tp))
    peak = xp.stack(xp.broadcast_arrays(*lobes), axis=-1)
    return xp.sum(xp.asarray(species_weights) * peak, axis=-1)


def cloud_albedo_stephens1978(tau, b):
    """Albedo of a non-absorbing cloud layer over a dark surface, a = bτ / (1 + bτ) (paper Eq. 24).

    Parameters
    ----------
    tau : array_like
        Optical thickness along the slant path from the sun, τ_s [-], ≥ 0.
    b : array_like
        Backscatter fraction [-] (:data:`swim.constants.BACKSCATTER_FRACTION`).

    Returns
    -------
    numpy.ndarray or jax.Array
        a [-] in 0 ... 1, broadcast shape; a ≈ bτ for τ ≪ 1/b.

    Source: Stephens, G. L. (1978), J. Atmos. Sci. 35, 2123-2132,
    doi:10.1175/1520-0469(1978)035<2123:RPIEWC>2.0.CO;2; paper Eq. 24.
    """
    xp = array_namespace(tau, b)
    bt = xp.asarray(b) * xp.asarray(tau)
    return bt / (1.0 + bt)


def anisotropic_reflectance_factor_kokhanovsky2004(
    cos_view_zenith, cos_sun_zenith, cos_theta, b1=KOKHANOVSKY_B1, b2=KOKHANOVSKY_B2, g=ARF_DHG_G, fb=ARF_DHG_FB
):
    """Anisotropic reflectance factor of a thick (semi-infinite, non-absorbing) cloud (paper Eq. 25, corrected).

    Parameters
    ----------
    cos_view_zenith : array_like
        cos z of the observer's zenith angle seen from the cloud top [-] (clipped to 0 ... 1).
    cos_sun_zenith : array_like
        cos z0 of the solar zenith angle at the cloud top [-] (clipped to 0 ... 1).
    cos_theta : array_like
        cos θ of the scattering angle [-] (θ = 180° for the sun behind the observer).
    b1, b2 : array_like, optional
        Coefficients, default 1.48 and 7.76 (paper Sect. 3.4.3).
    g, fb : array_like, optional
        DHG parameters of the cloud phase function, default 0.7 and 0.4 (water cloud, paper Sect. 3.4.3).

    Returns
    -------
    numpy.ndarray or jax.Array
        ARF = (b1 + b2 cos z cos z0 + P_DHG(θ; g, f_b)) / (4 (cos z + cos z0)) [-], broadcast shape; it is the
        reflection function R = π I / (μ0 F0) of the cloud (1 for a white Lambertian surface): 1.18 at
        z = z0 = 0.

    Notes
    -----
    The paper prints the denominator as 4 cos z cos z0. That gives ARF = 2.36 at z = z0 = 0, against the
    paper's own "ARF remains close to 1 when the zenith angles are small", and a hemispherical (plane) albedo
    of 2.8 (z0 = 0) to 7.3 (z0 = 78°) for a non-absorbing cloud, violating energy conservation. Kokhanovsky's
    semi-infinite reflection function has 4 (μ + μ0) (snow/cloud form R0 = (A + B(μ + μ0) + C μ μ0 + p(θ)) /
    (4 (μ + μ0))); with it the plane albedo is 1.00 (z0 = 0), 0.97 (37°), 0.93 (60°, 78°), as it must be
    (≈ 1). The sum is floored at :data:`ARF_MIN_MU_SUM` so grazing geometry stays finite; the approximation
    is meant for z, z0 ≲ 75°.

    Source: paper Eqs. 25 and 27, after Kokhanovsky, A. A. (2004), Reflection of light from nonabsorbing
    semi-infinite cloudy media: a simple approximation, J. Quant. Spectrosc. Radiat. Transfer 85, 25-33
    (DOI not verified here); the (A, B, C) form is the one used in Kokhanovsky's snow retrievals.
    """
    xp = array_namespace(cos_view_zenith, cos_sun_zenith, cos_theta, b1, b2, g, fb)
    mu = xp.clip(xp.asarray(cos_view_zenith), 0.0, 1.0)
    mu0 = xp.clip(xp.asarray(cos_sun_zenith), 0.0, 1.0)
    numerator = b1 + b2 * mu * mu0 + double_henyey_greenstein(xp.asarray(cos_theta), g, fb)
    return numerator / (4.0 * xp.maximum(mu + mu0, ARF_MIN_MU_SUM))
