"""The "filmic" display transform: highlights roll off to neutral white, a well-exposed sky keeps its colour, and
the exposure controls (a shift in stops, auto exposure from the image's luminance).

Colours are judged in CIELAB (D65, the sRGB display's white) with colour-science: chroma C*ab for neutrality and
CIEDE2000 for a colour's change.
"""

import colour
import numpy as np
import pytest

import swim.color as sc
from swim.color.display import auto_white_level, exposure_white_level, filmic_tone
from swim.errors import SwimInputError

D65 = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]


def lab_of_codes(codes):
    """CIELAB (D65) of 8-bit sRGB codes (..., 3)."""
    rgb = colour.cctf_decoding(np.asarray(codes, float) / 255.0, function="sRGB")
    return colour.XYZ_to_Lab(colour.RGB_to_XYZ(rgb, "sRGB"), D65)


def chroma(lab):
    return np.hypot(lab[..., 1], lab[..., 2])


def radiance_of_XYZ(xyz):
    """The three-wavelength L' whose colour stage gives ``xyz`` (the XYZ map is linear and invertible here)."""
    m = np.stack([sc.solar_relative_to_XYZ(e) for e in np.eye(3)], axis=1)
    return np.linalg.solve(m, np.asarray(xyz, float))


@pytest.mark.parametrize("white_level", [sc.DEFAULT_WHITE_LEVEL, sc.SPACE_WHITE_LEVEL])
def test_a_d65_white_three_stops_over_is_neutral(white_level):
    """A D65 white (bluer than the sun's white, which the display shows as white) shown 3 EV over its exposure: the
    shoulder takes it to neutral white, C*ab < 5; the hue-keeping mapping left it tinted."""
    xyz = colour.xy_to_XYZ(D65) * white_level  # Y = white level: display white before the exposure shift
    rad = radiance_of_XYZ(xyz)
    w = exposure_white_level(white_level, 3.0)
    filmic = lab_of_codes(sc.solar_relative_to_srgb8(rad, w))
    assert chroma(filmic) < 5.0
    assert filmic[0] > 99.0
    kept_hue = lab_of_codes(sc.solar_relative_to_srgb8(rad, w, gamut="preserve_hue"))
    assert chroma(kept_hue) > 5.0


def test_the_sun_disc_through_smoke_is_neutral_white():
    """The sun's disc seen through smoke (AOD 2 at 550 nm, Angstrom exponent 1.8, sun zenith 60 deg): reddened, and
    ~10^3 times brighter than white. The old mapping showed it orange; the shoulder shows it white."""
    from swim.color.spectrum import solar_relative_to_XYZ  # noqa: F401  (the colour stage's own spectrum)

    wavelengths = np.array([615.0, 546.0, 450.0])
    tau = 2.0 * (wavelengths / 550.0) ** -1.8 + np.array([0.055, 0.090, 0.217])  # smoke and Rayleigh
    solid_angle = 6.8e-5  # the sun's disc [sr]
    rad = 4.0 * np.pi / solid_angle * np.exp(-tau / 0.5) / (4.0 * np.pi) * np.pi  # L' = pi E / (Omega E_TOA)
    assert rad[0] > 10 * rad[2] and rad.min() > 50.0
    filmic = lab_of_codes(sc.solar_relative_to_srgb8(rad))
    assert chroma(filmic) < 5.0
    old = lab_of_codes(sc.solar_relative_to_srgb8(rad, gamut="preserve_hue"))
    assert chroma(old) > 40.0  # the orange disc


@pytest.mark.parametrize("sky", [[0.07, 0.12, 0.25], [0.05, 0.09, 0.19], [0.12, 0.17, 0.30], [0.20, 0.26, 0.38]],
                         ids=["zenith-30", "zenith-60", "horizon", "hazy"])
def test_a_well_exposed_blue_sky_keeps_its_colour(sky):
    """Clear-sky radiances (single-scattering zenith at sun zenith 30 and 60 deg, a brighter horizon, a hazy sky)
    at the default exposure: below the knee, so the new mapping changes them by CIEDE2000 < 2 against the linear
    one."""
    new = lab_of_codes(sc.solar_relative_to_srgb8(np.array(sky)))
    old = lab_of_codes(sc.solar_relative_to_srgb8(np.array(sky), gamut="clip"))
    assert colour.delta_E(new, old, method="CIE 2000") < 2.0
    assert new[2] < -10.0  # still blue


def test_sunlit_cloud_tops_keep_their_gradation():
    """Sunlit cloud tops (L' 2-4 at the default white level 1.5) clipped to one white before; the shoulder keeps
    them apart, rising with L', and neutral."""
    levels = np.array([1.0, 1.5, 2.0, 2.5, 3.0])
    codes = sc.solar_relative_to_srgb8(np.broadcast_to(levels, (3, levels.size)))
    assert np.all(codes[:, 0] == codes[:, 1]) and np.all(codes[:, 1] == codes[:, 2])
    assert np.all(np.diff(codes[:, 0].astype(int)) > 0)
    clipped = sc.solar_relative_to_srgb8(np.broadcast_to(levels, (3, levels.size)), gamut="clip")
    assert np.all(clipped[1:] == 255)


def test_the_tone_curve_is_linear_to_the_knee_smooth_and_below_white():
    y = np.linspace(0.0, 20.0, 20001)
    tone, share = filmic_tone(y)
    below = y <= sc.FILMIC_KNEE
    np.testing.assert_array_equal(tone[below], y[below])
    assert np.all(np.diff(tone) >= 0.0) and tone.max() <= 1.0 and tone[y < 5.0].max() < 1.0
    slope = np.gradient(tone, y)
    assert np.abs(np.diff(slope)).max() < 1e-2  # no kink at the knee
    assert share[below].min() == 1.0 and share[-1] < 1e-6 and np.all(np.diff(share) <= 0.0)


def test_filmic_keeps_luminance_and_hue_where_it_only_fits_the_gamut():
    """Below the knee, an out-of-gamut colour (monochromatic 520 nm light) loses chroma at its own luminance and hue,
    as the hue-keeping mapping does."""
    wl, xyz_bar = sc.cie_1931_cmfs()
    xyz = 0.4 * xyz_bar[wl == 520.0][0] / xyz_bar[wl == 520.0][0][1]
    np.testing.assert_allclose(sc.XYZ_to_display_rgb(xyz, 1.0),
                               sc.XYZ_to_display_rgb(xyz, 1.0, gamut="preserve_hue"), atol=1e-12)


def test_exposure_in_stops():
    assert exposure_white_level(1.5, 1.0) == pytest.approx(0.75)
    assert exposure_white_level(1.5, -2.0) == pytest.approx(6.0)
    for bad in (np.nan, "bright", 25.0):
        with pytest.raises(SwimInputError, match="exposure"):
            exposure_white_level(1.5, bad)
    with pytest.raises(SwimInputError, match="white_level"):
        exposure_white_level(0.0, 1.0)


def test_auto_exposure_meters_the_log_average():
    """The log-average luminance goes to the key (0.18 of white); the sun's few pixels barely move it; NaN pixels
    (outside the fisheye circle) are left out."""
    rng = np.random.default_rng(0)
    sky = np.broadcast_to(np.array([0.07, 0.12, 0.25])[:, None, None], (3, 64, 64)) * rng.uniform(0.5, 2.0, (64, 64))
    y = sc.solar_relative_to_XYZ(sky)[..., 1]
    w = auto_white_level(sky)
    assert w == pytest.approx(np.exp(np.log(y).mean()) / 0.18, rel=1e-12)
    with_sun = np.array(sky)
    with_sun[:, :2, :2] = 1e4
    with_sun[:, -1, :] = np.nan
    assert auto_white_level(with_sun) == pytest.approx(w, rel=0.1)
    with pytest.raises(SwimInputError, match="luminance"):
        auto_white_level(np.zeros((3, 4, 4)))
    with pytest.raises(SwimInputError, match="key"):
        auto_white_level(sky, key=1.5)
