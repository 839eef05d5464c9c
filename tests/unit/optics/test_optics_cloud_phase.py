"""The hydrometeors' phase functions of the 3-D cloud scattering (swim.optics.cloud_phase)."""

import math

import numpy as np
import pytest

from swim.constants import SPECIES
from swim.errors import SwimInputError
from swim.optics.cloud_phase import (
    ICE_ASYMMETRY,
    angles_deg,
    cloud_optics,
    henyey_greenstein,
    legendre_moments,
    mie_liquid_phase,
    resolve_phase_spec,
    roughened_aggregate_phase,
    split_phase_function,
)


def _mean(p):
    mu = np.cos(np.radians(angles_deg()))[::-1]
    return 0.5 * np.trapezoid(np.asarray(p)[::-1], mu, axis=0)


@pytest.mark.parametrize("radius_um", [3.0, 10.0, 17.5, 40.0])
def test_mie_phase_functions_are_normalised_and_forward_peaked(radius_um):
    p = mie_liquid_phase(radius_um * 1e-6)
    assert p.shape == (angles_deg().size, 3) and np.all(p > 0)
    np.testing.assert_allclose(_mean(p), 1.0, rtol=1e-9)
    assert np.all(p[0] > 100 * p[angles_deg().size // 2])


def test_mie_asymmetry_of_cloud_droplets():
    """Water droplets of r_e 10 um (v_e 0.1) in the visible: g ~ 0.86, the value used for such clouds since
    Hansen and Travis (1974), doi:10.1007/BF00168069; it grows with the radius."""
    g = {r: legendre_moments(mie_liquid_phase(r * 1e-6), 1)[1, 1] for r in (5.0, 10.0, 20.0)}
    assert 0.855 <= g[10.0] <= 0.875
    assert g[5.0] < g[10.0] < g[20.0]


def test_mie_has_the_rainbow():
    """The primary rainbow of droplets: a maximum of the phase function near 138-142 deg at 546 nm."""
    theta = angles_deg()
    p = mie_liquid_phase(20e-6)[:, 1]
    window = (theta > 120) & (theta < 160)
    peak = theta[window][np.argmax(p[window])]
    assert 135 < peak < 145


def test_ice_model_has_its_asymmetry_and_no_halo():
    p = roughened_aggregate_phase(34e-6)
    np.testing.assert_allclose(_mean(p), 1.0, rtol=1e-9)
    g = legendre_moments(p, 1)[1]
    np.testing.assert_allclose(g, ICE_ASYMMETRY, atol=0.01)
    theta = angles_deg()
    side = p[(theta > 10) & (theta < 60), 1]
    assert np.max(side[1:] / side[:-1]) < 1.002  # featureless: no 22 or 46 deg halo (a halo's peak is ~x2)


def test_henyey_greenstein_moments_are_powers_of_g():
    p = henyey_greenstein(np.cos(np.radians(angles_deg())), 0.7)[:, None]
    chi = legendre_moments(p / _mean(p), 4)[:, 0]
    np.testing.assert_allclose(chi, 0.7 ** np.arange(5), atol=2e-3)


@pytest.mark.parametrize("spec", ["physical", {"liquid": ("hg", 0.85)}])
def test_split_parts_add_up_and_carry_the_truncated_share(spec):
    """P = (P - Pi) + Pi, Pi's energy is the delta-M share f, split into its narrow (aureole) part and the rest."""
    optics = cloud_optics(spec, 2)
    for n in range(len(SPECIES)):
        p, f = optics.phase[n], optics.truncation[n]
        a, b, narrow = split_phase_function(p, optics.moments[n, :3], f)
        assert np.all(a >= 0) and np.all(b >= 0)
        removed = _mean(p - a)
        np.testing.assert_allclose(removed[1], f, rtol=0.03)
        np.testing.assert_allclose(_mean(b)[1] + narrow, removed[1], rtol=1e-6)


def test_the_scaled_beams_phase_function_is_continuous_at_the_aureoles_edge():
    """P - Pi (the part that scatters the scaled beam) has no step at the aureole's edge and is flat inside it: a step
    there drew a dark disc with a bright rim about the sun behind thick cloud, whose aureole light is dimmed away
    (e^-(1 - f_a) tau). Pi keeps the energy f."""
    from swim.optics.cloud_phase import AUREOLE_HALF_ANGLE_RAD

    optics = cloud_optics("physical", 2)
    theta = np.radians(angles_deg())
    edge = int(np.searchsorted(theta, AUREOLE_HALF_ANGLE_RAD))
    for n in range(len(SPECIES)):
        p, f = optics.phase[n], optics.truncation[n]
        a, _, _ = split_phase_function(p, optics.moments[n, :3], f)
        inside, outside = a[edge - 1], a[edge]
        # at 546 nm, one angle step apart on the steep peak (the ice models' blue channel is noisy from step to step)
        np.testing.assert_allclose(inside[1], outside[1], rtol=0.08)
        np.testing.assert_allclose(a[: edge - 1], np.broadcast_to(inside, a[: edge - 1].shape), rtol=1e-6)
        np.testing.assert_allclose(_mean(p - a), f, rtol=1e-3)


def test_optics_truncation_and_scaled_moments():
    optics = cloud_optics("physical", 2)
    f = optics.truncation
    np.testing.assert_allclose(f, optics.moments[:, 3, 1])
    np.testing.assert_allclose(optics.scaled_moments[:, 0], 1.0)
    np.testing.assert_allclose(optics.scaled_moments * (1 - f[:, None, None]) + f[:, None, None],
                               optics.moments[:, :3])
    # a diffraction peak is narrow, a Henyey-Greenstein forward lobe is not
    liquid = SPECIES.index("cloud_liquid")
    assert optics.narrow[liquid] > 0.3
    assert cloud_optics({"liquid": ("hg", 0.85)}, 2).narrow[liquid] < 0.02
    phases = optics.phase_at(np.cos(np.radians([0.0, 5.0, 90.0])), [liquid])
    assert phases.shape == (3, 1, 6) and phases.dtype == np.float32


def test_phase_specifications_are_checked():
    assert resolve_phase_spec({"ice": ("hg", 0.75)})["snow"] == ("hg", 0.75)
    for bad in ("mie", {"water": ("hg", 0.8)}, {"liquid": ("hg", 1.2)}, {"liquid": ("hg",)},
                {"liquid": ("mie", 10)}, 3):
        with pytest.raises(SwimInputError):
            cloud_optics(bad, 2)
    with pytest.raises(SwimInputError):
        cloud_optics("physical", 0)
    assert math.isclose(float(henyey_greenstein(1.0, 0.0)), 1.0)
