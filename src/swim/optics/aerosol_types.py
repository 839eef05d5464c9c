"""Named aerosol types: two-term DHG phase function, single-scattering albedo and Ångström exponent.

Source: Albers et al. (2020), Atmos. Meas. Tech. 13, 3235-3261, doi:10.5194/amt-13-3235-2020 ("the paper"),
Sect. 3.5.1-3.5.2 (Eqs. 27-29), Table 3 and Appendix A. The two paper cases (``colorado_dust``,
``saudi_mixed``) are Table 3 verbatim; the other types are built from AERONET / OPAC climatology values of
the asymmetry parameter, single-scattering albedo and Ångström exponent (sources on each type). Every
choice, with the numbers behind it, is listed in docs/aerosols.md.

Conventions
-----------
* Spectral tuples are at the SWIm reference wavelengths 615, 546, 450 nm, in the order of
  :data:`swim.constants.WAVELENGTHS_NM`.
* ``fc`` is the fraction of the scattered photons in the *first* DHG, the one with ``g1`` (paper Eq. 28 and
  the sentence before it). In Table 3 the first DHG is the broad (fine-mode) lobe, g1 ≈ 0.6 or 0.27, and the
  second the narrow (coarse-mode, diffraction) lobe, g2 ≈ 0.9; we keep that reading for all types.
* Phase functions have mean 1 over the sphere (paper, below Eq. 9 and Eq. 27, with the 3/2 exponent of
  :func:`swim.optics.phase.double_henyey_greenstein`).
* The extinction at wavelength λ is β_550 (λ / 550 nm)^-α (Ångström law, Sect. 3.5.1).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from .aerosol import angstrom_extinction
from ..errors import SwimInputError
from .phase import two_term_double_henyey_greenstein

#: Reference wavelength of the aerosol optical depth and of the Ångström law [nm].
ANGSTROM_REFERENCE_WAVELENGTH_NM = 550.0

#: Extinction Ångström exponents of the two PMF factors of the AERONET Capo Verde record (paper Appendix A):
#: dust (coarse) factor 0.0905, urban/industrial (fine, absorbing) factor 1.164 [-].
APPENDIX_A_EAE_DUST = 0.0905
APPENDIX_A_EAE_FINE = 1.164

_DUBOVIK2002 = (
    "Dubovik, O. et al. (2002), Variability of absorption and optical properties of key aerosol types observed "
    "in worldwide locations, J. Atmos. Sci. 59, 590-608, doi:10.1175/1520-0469(2002)059<0590:VOAAOP>2.0.CO;2"
)
_OPAC = (
    "Hess, M., Koepke, P. and Schult, I. (1998), Optical properties of aerosols and clouds: the software "
    "package OPAC, Bull. Am. Meteorol. Soc. 79, 831-844, doi:10.1175/1520-0477(1998)079<0831:OPOAAC>2.0.CO;2"
)
_SMIRNOV2002 = (
    "Smirnov, A. et al. (2002), Optical properties of atmospheric aerosol in maritime environments, "
    "J. Atmos. Sci. 59, 501-523, doi:10.1175/1520-0469(2002)059<0501:OPOAAI>2.0.CO;2"
)
_PAPER = "Albers et al. (2020), AMT 13, 3235-3261, doi:10.5194/amt-13-3235-2020"


def _fine_fraction_angstrom(fc_546):
    """Ångström exponent of a fine + dust mixture whose fine (broad-lobe) share of extinction is ``fc_546``.

    α of a sum of components is the extinction-weighted mean of their α at the reference wavelength; with a
    common ω the scattered-photon fraction fc equals the extinction fraction. Component α: paper Appendix A.
    """
    return fc_546 * APPENDIX_A_EAE_FINE + (1.0 - fc_546) * APPENDIX_A_EAE_DUST


def _check_triplet(name, field, values, low, high, low_open=False, high_open=False):
    """Validate a 3-tuple of finite floats within [low, high] (bounds open where asked)."""
    if len(values) != 3:
        raise SwimInputError(f"aerosol type {name!r}: {field} needs 3 values (615, 546, 450 nm); got {values!r}")
    v = np.asarray(values, dtype=float)
    bad = ~np.isfinite(v) | (v <= low if low_open else v < low) | (v >= high if high_open else v > high)
    if np.any(bad):
        lo, hi = ("(" if low_open else "["), (")" if high_open else "]")
        raise SwimInputError(f"aerosol type {name!r}: {field} must lie in {lo}{low}, {high}{hi} [-]; got {values!r}")
    return tuple(float(x) for x in v)


@dataclass(frozen=True)
class AerosolType:
    """Optical properties of one aerosol type at the three SWIm reference wavelengths (paper Sect. 3.5).

    Attributes
    ----------
    name : str
        Canonical name (lower case, underscores).
    g1, g2 : tuple of float
        Asymmetry parameters of the first and second DHG at 615, 546, 450 nm [-], 0 ≤ g < 1 (paper Eq. 28).
    fc : tuple of float
        Fraction of the scattered photons in the first DHG (the one with ``g1``) [-], 0 ... 1 (Eq. 28).
    fb : tuple of float
        Backscatter-lobe parameter f_b of both DHGs [-], 0 ... 1 (keeps the phase function positive; Eq. 27).
    ssa : tuple of float
        Single-scattering albedo ω [-], 0 < ω ≤ 1 (Sect. 3.5.1).
    angstrom_exponent : float
        Extinction Ångström exponent α [-]: β(λ) = β_550 (λ / 550 nm)^-α (Sect. 3.5.1).
    description : str
        What the type represents.
    reference : str
        Source of the numbers (paper table or literature with DOI).

    Raises
    ------
    SwimInputError
        On construction, for a parameter that is not 3 finite values in its range or a non-finite α.
    """

    name: str
    g1: tuple[float, float, float]
    g2: tuple[float, float, float]
    fc: tuple[float, float, float]
    fb: tuple[float, float, float]
    ssa: tuple[float, float, float]
    angstrom_exponent: float
    description: str
    reference: str

    def __post_init__(self):
        n = self.name
        object.__setattr__(self, "g1", _check_triplet(n, "g1", self.g1, 0.0, 1.0, high_open=True))
        object.__setattr__(self, "g2", _check_triplet(n, "g2", self.g2, 0.0, 1.0, high_open=True))
        object.__setattr__(self, "fc", _check_triplet(n, "fc", self.fc, 0.0, 1.0))
        object.__setattr__(self, "fb", _check_triplet(n, "fb", self.fb, 0.0, 1.0))
        object.__setattr__(self, "ssa", _check_triplet(n, "ssa", self.ssa, 0.0, 1.0, low_open=True))
        if not np.isfinite(self.angstrom_exponent):
            raise SwimInputError(
                f"aerosol type {n!r}: angstrom_exponent must be finite [-]; got {self.angstrom_exponent!r}"
            )
        object.__setattr__(self, "angstrom_exponent", float(self.angstrom_exponent))

    def phase_function(self, cos_theta):
        """Two-term DHG phase function at the three reference wavelengths (paper Eq. 28).

        Parameters
        ----------
        cos_theta : array_like
            cos θ of the scattering angle [-] (θ = 0 forward), any shape; numpy, jax array or tracer.

        Returns
        -------
        jax.Array
            P(θ) = f_c P_DHG(θ, g1, f_b) + (1 - f_c) P_DHG(θ, g2, f_b) [-], shape ``cos_theta.shape + (3,)``
            (last axis 615, 546, 450 nm); mean 1 over the sphere at each wavelength, positive for all θ.

        Notes
        -----
        Runs under ``jax.jit`` (the type is a frozen, hashable dataclass and may be a static argument); no
        validation of ``cos_theta``. Float32 unless x64 is enabled.

        Source: paper Eqs. 27-28 (DHG with the 3/2 exponent, see docs/phase-functions.md, decision D1).
        """
        mu = jnp.asarray(cos_theta)[..., None]
        return two_term_double_henyey_greenstein(
            mu, jnp.asarray(self.g1), jnp.asarray(self.g2), jnp.asarray(self.fb), jnp.asarray(self.fc)
        )

    def asymmetry_parameter(self):
        """Overall asymmetry parameter at 615, 546, 450 nm (paper Eq. 29).

        Returns
        -------
        numpy.ndarray
            g = f_c g1 + (1 - f_c) g2 [-], shape (3,). Equal to the mean cos θ of :meth:`phase_function`
            (the P2 back lobe of Eq. 27 has zero mean cos θ).

        Source: paper Eq. 29.
        """
        fc = np.asarray(self.fc)
        return fc * np.asarray(self.g1) + (1.0 - fc) * np.asarray(self.g2)

    def extinction_factor(self, wavelength_nm):
        """Ångström spectral scaling of the extinction relative to 550 nm.

        Parameters
        ----------
        wavelength_nm : array_like
            Wavelength [nm], finite and > 0, any shape.

        Returns
        -------
        numpy.ndarray
            (λ / 550 nm)^-α [-], shape of ``wavelength_nm``; multiply a 550-nm extinction coefficient or optical
            depth by it.

        Raises
        ------
        SwimInputError
            For a non-finite or non-positive wavelength.

        Source: paper Sect. 3.5.1; Ångström, A. (1929), Geogr. Ann. 11, 156-166,
        doi:10.1080/20014422.1929.11880498.
        """
        lam = np.asarray(wavelength_nm, dtype=float)
        if np.any(~np.isfinite(lam)) or np.any(lam <= 0.0):
            raise SwimInputError(f"wavelength_nm must be finite and > 0 [nm]; got {wavelength_nm!r}")
        return np.asarray(angstrom_extinction(1.0, lam, self.angstrom_exponent), dtype=float)


_TYPES = (
    AerosolType(
        name="colorado_dust",
        g1=(0.59, 0.60, 0.61),
        g2=(0.895, 0.900, 0.905),
        fc=(0.12, 0.12, 0.12),
        fb=(0.550, 0.550, 0.550),
        ssa=(0.935, 0.92, 0.86),
        angstrom_exponent=_fine_fraction_angstrom(0.12),
        description=(
            "Semi-empirical fit for dusty days in Boulder, Colorado: bimodal, condensed aureole from large dust "
            "particles (narrow lobe g2 = 0.9 with 88 % of the photons), blue absorption of hematite. "
            "alpha = 0.12 * 1.164 + 0.88 * 0.0905 = 0.219 (fine/dust mix of Appendix A EAEs, project choice)."
        ),
        reference=f"{_PAPER}, Table 3 row 1 and Sect. 3.5.1-3.5.2 (alpha: Appendix A EAEs)",
    ),
    AerosolType(
        name="saudi_mixed",
        g1=(0.23, 0.27, 0.29),
        g2=(0.915, 0.925, 0.933),
        fc=(0.58, 0.54, 0.53),
        fb=(0.562, 0.558, 0.558),
        ssa=(0.96, 0.96, 0.96),
        angstrom_exponent=_fine_fraction_angstrom(0.54),
        description=(
            "Mixed dust and pollution over Saudi Arabia: DHG pair fitted to a Mie phase function from AERONET "
            "retrievals; spectrally flat omega. alpha = 0.54 * 1.164 + 0.46 * 0.0905 = 0.670 (project choice)."
        ),
        reference=f"{_PAPER}, Table 3 row 2, Sect. 3.5.2 and Appendix A",
    ),
    AerosolType(
        name="smoke",
        g1=(0.61, 0.64, 0.67),
        g2=(0.61, 0.64, 0.67),
        fc=(1.0, 1.0, 1.0),
        fb=(0.55, 0.55, 0.55),
        ssa=(0.86, 0.88, 0.90),
        angstrom_exponent=1.9,
        description=(
            "Biomass-burning smoke: fine mode, single DHG (g1 = g2), g 0.64 at 546 nm rising to the blue, "
            "omega 0.86-0.90 decreasing towards the red (black carbon), alpha 1.9."
        ),
        reference=f"AERONET biomass-burning climatology, {_DUBOVIK2002}",
    ),
    AerosolType(
        name="continental",
        g1=(0.66, 0.68, 0.70),
        g2=(0.66, 0.68, 0.70),
        fc=(1.0, 1.0, 1.0),
        fb=(0.55, 0.55, 0.55),
        ssa=(0.94, 0.95, 0.96),
        angstrom_exponent=1.4,
        description=(
            "Continental background / urban-industrial haze: fine-mode dominated, single DHG (g1 = g2), g 0.68 at "
            "546 nm, weakly absorbing (omega 0.94-0.96), alpha 1.4. Alias 'haze'."
        ),
        reference=f"AERONET urban-industrial climatology, {_DUBOVIK2002}; OPAC continental models, {_OPAC}",
    ),
    AerosolType(
        name="stratospheric_sulfate",
        g1=(0.69, 0.70, 0.71),
        g2=(0.69, 0.70, 0.71),
        fc=(1.0, 1.0, 1.0),
        fb=(0.55, 0.55, 0.55),
        ssa=(1.0, 1.0, 1.0),
        angstrom_exponent=1.0,
        description=(
            "Stratospheric sulfuric-acid droplets of a volcanic (Junge) layer, effective radius ~0.4 um: single "
            "DHG with g 0.70 at 546 nm, non-absorbing at visible wavelengths (omega 1), alpha 1.0. The default "
            "type of the stratospheric 1-D aerosol of Step 2. Alias 'volcanic'."
        ),
        reference=("Russell et al. (1996), J. Geophys. Res. 101, 18745 (Pinatubo aerosol size and optics); "
                   "Stenchikov et al. (1998), J. Geophys. Res. 103, 13837"),
    ),
    AerosolType(
        name="sea_salt",
        g1=(0.59, 0.60, 0.61),
        g2=(0.895, 0.900, 0.905),
        fc=(0.43, 0.43, 0.43),
        fb=(0.55, 0.55, 0.55),
        ssa=(0.99, 0.99, 0.99),
        angstrom_exponent=0.4,
        description=(
            "Maritime / sea-salt aerosol: coarse, non-absorbing; the lobes of Table 3's Colorado dust with "
            "fc = 0.43 so that Eq. 29 gives g = 0.764, 0.771, 0.778; omega 0.99, alpha 0.4. Alias 'maritime'."
        ),
        reference=f"AERONET oceanic climatology, {_DUBOVIK2002}; {_SMIRNOV2002}; OPAC maritime models, {_OPAC}",
    ),
)

#: The named aerosol types by canonical name.
AEROSOL_TYPES: dict[str, AerosolType] = {t.name: t for t in _TYPES}

#: Alternative names accepted by :func:`aerosol_type`, mapped to canonical names.
AEROSOL_TYPE_ALIASES: dict[str, str] = {
    "haze": "continental",
    "urban": "continental",
    "maritime": "sea_salt",
    "marine": "sea_salt",
    "biomass_burning": "smoke",
    "volcanic": "stratospheric_sulfate",
    "sulfate": "stratospheric_sulfate",
}


def aerosol_type(name: str) -> AerosolType:
    """Look up a named aerosol type.

    Parameters
    ----------
    name : str
        Type name or alias, case-insensitive; '-' and ' ' are read as '_' (``"Sea-Salt"`` → ``sea_salt``).

    Returns
    -------
    AerosolType
        The entry of :data:`AEROSOL_TYPES`.

    Raises
    ------
    SwimInputError
        For a non-string or unknown name; the message lists the valid names and aliases.
    """
    key = name.strip().lower().replace("-", "_").replace(" ", "_") if isinstance(name, str) else None
    key = AEROSOL_TYPE_ALIASES.get(key, key)
    if key not in AEROSOL_TYPES:
        valid = ", ".join(sorted(AEROSOL_TYPES))
        aliases = ", ".join(f"{a} -> {c}" for a, c in sorted(AEROSOL_TYPE_ALIASES.items()))
        raise SwimInputError(f"unknown aerosol type {name!r}; valid types: {valid} (aliases: {aliases})")
    return AEROSOL_TYPES[key]
