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

import numpy as np

from ..arrays import array_namespace
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
            cos θ of the scattering angle [-] (θ = 0 forward), any shape; numpy, JAX array or tracer.

        Returns
        -------
        numpy.ndarray or jax.Array
            P(θ) = f_c P_DHG(θ, g1, f_b) + (1 - f_c) P_DHG(θ, g2, f_b) [-], shape ``cos_theta.shape + (3,)``
            (last axis 615, 546, 450 nm); mean 1 over the sphere at each wavelength, positive for all θ.

        Notes
        -----
        Computes in the array library of ``cos_theta`` (:mod:`swim.arrays`): numpy for numpy input; for JAX
        input it runs under ``jax.jit`` (the type is a frozen, hashable dataclass and may be a static argument),
        float32 unless x64 is enabled. No validation of ``cos_theta``.

        Source: paper Eqs. 27-28 (DHG with the 3/2 exponent, see docs/phase-functions.md, decision D1).
        """
        xp = array_namespace(cos_theta)
        mu = xp.asarray(cos_theta)[..., None]
        return two_term_double_henyey_greenstein(
            mu, xp.asarray(self.g1), xp.asarray(self.g2), xp.asarray(self.fb), xp.asarray(self.fc)
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


def _triplet(value, field, name):
    """A scalar or 3 values (615, 546, 450 nm) as 3 floats (checked by :class:`AerosolType`)."""
    v = np.atleast_1d(np.asarray(value, dtype=float)) if not isinstance(value, str) else None
    if v is None or v.ndim != 1 or v.size not in (1, 3):
        raise SwimInputError(f"aerosol {name!r}: {field} must be one number or three (615, 546, 450 nm); got {value!r}")
    return tuple(float(x) for x in np.broadcast_to(v, (3,)))


@dataclass(frozen=True)
class TabulatedAerosolType(AerosolType):
    """An aerosol type whose phase function is a table of scattering angle and value (user optics).

    The DHG parameters it inherits hold the Henyey-Greenstein function of the table's asymmetry parameter (g1 = g2
    = g, f_c = 1, f_b = 0), for the code that needs a parametric stand-in; :meth:`phase_function` and
    :meth:`asymmetry_parameter` are the table's.

    Attributes
    ----------
    table_cos_theta : tuple of float
        cos θ of the table's scattering angles, increasing [-].
    table_values : tuple of tuple of float
        P at each cos θ for 615, 546, 450 nm (n, 3) [-], normalised to mean 1 over the sphere.
    """

    table_cos_theta: tuple = ()
    table_values: tuple = ()

    def phase_function(self, cos_theta):
        """The table's phase function, linear in cos θ between its angles (mean 1 over the sphere), shape
        ``cos_theta.shape + (3,)``, in the array library of ``cos_theta`` (numpy or JAX, :mod:`swim.arrays`)."""
        xp = array_namespace(cos_theta)
        mu = xp.clip(xp.asarray(cos_theta), -1.0, 1.0)
        nodes = xp.asarray(self.table_cos_theta)
        values = xp.asarray(self.table_values)
        return xp.stack([xp.interp(mu, nodes, values[:, c]) for c in range(3)], axis=-1)

    def asymmetry_parameter(self):
        """Mean cos θ of the table's phase function (3,) [-]."""
        mu = np.asarray(self.table_cos_theta)
        values = np.asarray(self.table_values)
        return np.array([np.trapezoid(mu * values[:, c], mu) / np.trapezoid(values[:, c], mu) for c in range(3)])


def read_phase_function_table(path):
    """A phase-function table from a text file: columns scattering angle [deg] and P, or P at 615, 546, 450 nm.

    Lines starting with ``#`` and a header line of text are skipped; commas or whitespace separate the columns.

    Returns
    -------
    angles_deg : numpy.ndarray
        (n,) scattering angles [deg].
    values : numpy.ndarray
        (n,) or (n, 3) phase function [-] (any normalisation).

    Raises
    ------
    SwimInputError
        A missing file, fewer than 2 or more than 4 columns, or text where numbers belong.
    """
    from pathlib import Path

    p = Path(path)
    if not p.is_file():
        raise SwimInputError(f"aerosol phase-function table not found: {p}")
    rows = []
    for number, line in enumerate(p.read_text(errors="replace").splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        fields = line.replace(",", " ").split()
        try:
            rows.append([float(v) for v in fields])
        except ValueError:
            if rows:  # text after the numbers began: not a header
                raise SwimInputError(f"{p}, line {number}: expected numbers (angle [deg], P), got {line[:60]!r}") from None
            continue
    if not rows or len({len(r) for r in rows}) != 1 or len(rows[0]) not in (2, 4):
        raise SwimInputError(f"{p}: expected rows of 2 columns (angle [deg], P) or 4 (angle, P at 615, 546, 450 nm)")
    table = np.array(rows)
    return table[:, 0], (table[:, 1] if table.shape[1] == 2 else table[:, 1:])


def custom_aerosol_type(base="continental", *, ssa=None, g=None, angstrom_exponent=None, phase_function=None,
                        name=None) -> AerosolType:
    """An aerosol type of the user's own optics: a named type with some of its properties replaced.

    Parameters
    ----------
    base : str or AerosolType
        The type whose properties are kept where none is given (:func:`aerosol_type`).
    ssa : float or sequence of 3 floats, optional
        Single-scattering albedo [-], 0 < ω ≤ 1, one value or one at each of 615, 546, 450 nm.
    g : float or sequence of 3 floats, optional
        Asymmetry parameter [-], 0 ≤ g < 1: the phase function becomes Henyey-Greenstein with it.
    angstrom_exponent : float, optional
        Extinction Ångström exponent α [-]: β(λ) = β_550 (λ / 550 nm)^-α.
    phase_function : tuple of (angles_deg, values), optional
        A tabulated phase function: scattering angles [deg] (0 and 180 included, increasing) and P (n,) or at
        615, 546, 450 nm (n, 3), any normalisation (it is normalised to mean 1 over the sphere); exclusive with
        ``g``. See :func:`read_phase_function_table`.
    name : str, optional
        The type's name in the image's attributes; default ``"<base>+custom"``.

    Returns
    -------
    AerosolType
        A :class:`TabulatedAerosolType` with ``phase_function``.

    Raises
    ------
    SwimInputError
        Values out of range, both ``g`` and ``phase_function``, or a table that does not cover 0-180 deg or has
        negative values.

    References
    ----------
    Henyey, L. G. and Greenstein, J. L. (1941), Astrophys. J. 93, 70-83, doi:10.1086/144246.
    """
    t = base if isinstance(base, AerosolType) else aerosol_type(base)
    label = name if name is not None else f"{t.name}+custom"
    if g is not None and phase_function is not None:
        raise SwimInputError(f"aerosol {label!r}: give an asymmetry parameter g or a phase-function table, not both")
    fields = {"name": label, "g1": t.g1, "g2": t.g2, "fc": t.fc, "fb": t.fb, "ssa": t.ssa,
              "angstrom_exponent": t.angstrom_exponent, "description": f"{t.description} (user optics)",
              "reference": "user-supplied optics"}
    if ssa is not None:
        fields["ssa"] = _triplet(ssa, "ssa", label)
    if angstrom_exponent is not None:
        try:
            fields["angstrom_exponent"] = float(angstrom_exponent)
        except (TypeError, ValueError):
            raise SwimInputError(f"aerosol {label!r}: angstrom_exponent must be a number; got {angstrom_exponent!r}") from None
        if not -1.0 <= fields["angstrom_exponent"] <= 4.0:
            raise SwimInputError(f"aerosol {label!r}: angstrom_exponent must lie in [-1, 4] [-]; got {angstrom_exponent!r}")
    if g is not None:
        gg = _triplet(g, "g", label)
        fields.update(g1=gg, g2=gg, fc=(1.0, 1.0, 1.0), fb=(0.0, 0.0, 0.0))
    if phase_function is None:
        return AerosolType(**fields)
    return _tabulated(fields, *phase_function)


def _tabulated(fields, angles_deg, values):
    label = fields["name"]
    angles = np.asarray(angles_deg, dtype=float)
    p = np.asarray(values, dtype=float)
    p = np.repeat(p[:, None], 3, axis=1) if p.ndim == 1 else p
    if angles.ndim != 1 or angles.size < 2 or p.shape != (angles.size, 3):
        raise SwimInputError(f"aerosol {label!r}: the phase-function table needs n >= 2 angles and n values (or n x 3)")
    if not (np.all(np.isfinite(angles)) and np.all(np.isfinite(p))) or np.any(p < 0):
        raise SwimInputError(f"aerosol {label!r}: the phase-function table must be finite and not negative")
    if np.any(np.diff(angles) <= 0) or abs(angles[0]) > 1e-6 or abs(angles[-1] - 180.0) > 1e-6:
        raise SwimInputError(f"aerosol {label!r}: the table's angles must increase from 0 to 180 deg; got "
                             f"{angles[0]:g} ... {angles[-1]:g}")
    mu = np.cos(np.radians(angles))[::-1]  # increasing cos theta
    p = p[::-1]
    mean = np.array([np.trapezoid(p[:, c], mu) / 2.0 for c in range(3)])  # (1 / 4 pi) int P dOmega
    if np.any(mean <= 0):
        raise SwimInputError(f"aerosol {label!r}: the phase-function table is zero everywhere")
    p = p / mean
    g = [float(np.trapezoid(mu * p[:, c], mu) / 2.0) for c in range(3)]
    g = tuple(min(max(v, 0.0), 0.999) for v in g)
    fields.update(g1=g, g2=g, fc=(1.0, 1.0, 1.0), fb=(0.0, 0.0, 0.0))
    return TabulatedAerosolType(**fields, table_cos_theta=tuple(float(x) for x in mu),
                                table_values=tuple(tuple(float(v) for v in row) for row in p))
