"""Unit tests of the colour stage (swim.color; paper Sect. 3.8).

Reference numbers: CIE 1931 2-degree colour matching functions (CIE 015:2018, Table 1), the
IEC 61966-2-1 sRGB transfer function constants, the paper's Rayleigh-sky chromaticity
(x = y = 0.235) and its Eq. 36 matrix, and analytic limits (flat spectra, linearity).
"""

from __future__ import annotations

import numpy as np
import pytest

import swim.color as sc
from swim.color._tables import import_colour
from swim.constants import WAVELENGTHS_NM
from swim.errors import SwimInputError

GRID = sc.SPECTRAL_GRID_NM
colour = import_colour()  # the reference library (a render itself does not import it)


def _grid_index(wavelength_nm: float) -> int:
    return int(round((wavelength_nm - GRID[0]) / sc.SPECTRAL_STEP_NM))


def _xy(xyz):
    xyz = np.asarray(xyz, dtype=float)
    return xyz[..., :2] / xyz.sum(axis=-1, keepdims=True)


def _brute_force_xyz(radiance):
    """XYZ from the explicit spectrum (no fast path): sum over the grid of L_lambda * CMF, normalised."""
    spec = sc.solar_relative_to_spectrum(radiance)
    cmf = sc.cie_1931_cmfs_on_grid()
    norm = (sc.solar_irradiance_on_grid() / (4.0 * np.pi)) @ cmf[:, 1]
    return spec @ cmf / norm


# --------------------------------------------------------------------------------------------------
# Reference tables
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("wavelength", "expected"),
    [
        # CIE 015:2018 Table 1 (CIE 1931 2-degree observer), 5 nm rows.
        (450.0, (0.33620, 0.03800, 1.77211)),
        (555.0, (0.51205, 1.00000, 0.00575)),
        (600.0, (1.06220, 0.63100, 0.00080)),
        (700.0, (0.011359, 0.004102, 0.0)),
    ],
)
def test_cmfs_match_cie_table(wavelength, expected):
    cmf = sc.cie_1931_cmfs_on_grid()
    assert cmf.shape == (GRID.size, 3)
    np.testing.assert_allclose(cmf[_grid_index(wavelength)], expected, atol=6e-6)


def test_cmfs_integral_and_equal_energy_white():
    wl, xyz_bar = sc.cie_1931_cmfs()
    assert wl[0] == 360.0 and wl[-1] == 830.0 and xyz_bar.shape == (471, 3)
    sums = xyz_bar.sum(axis=0)  # 1 nm steps
    # Sum of y-bar over 360-830 nm at 1 nm: 106.857 (the normalising constant of CIE 1931 colorimetry
    # with a 1 nm equal-energy spectrum; 683 lm/W x 106.857 nm = 72 983 lm per W/nm).
    assert sums[1] == pytest.approx(106.857, abs=1e-3)
    # Equal-energy illuminant E is at x = y = 1/3 (to the table's rounding).
    np.testing.assert_allclose(_xy(sums), [1 / 3, 1 / 3], atol=1e-4)


def test_grid_is_380_780_in_5nm():
    assert GRID[0] == 380.0 and GRID[-1] == 780.0 and GRID.size == 81
    np.testing.assert_allclose(np.diff(GRID), 5.0)
    assert sc.SPECTRAL_STEP_NM == 5.0


def test_solar_spectrum_on_grid_is_band_mean_of_g173():
    wl, e = sc.astm_g173_extraterrestrial()
    assert wl[0] == 280.0 and wl[-1] == 4000.0
    band = sc.solar_irradiance_on_grid()
    assert band.shape == (81,) and np.all(band > 0.5)
    # 5 nm band means integrate to the G173 integral over 377.5-782.5 nm (rescaled to 1362 W m-2).
    fine = np.arange(377.5, 782.5 + 1e-9, 0.1)
    expected = np.trapezoid(np.interp(fine, wl, e), fine) * 1362.0 / 1366.1
    assert band.sum() * 5.0 == pytest.approx(expected, rel=1e-5)
    # Visible peak of the extraterrestrial spectrum ~ 1.9-2.1 W m-2 nm-1 near 450-500 nm.
    assert 1.8 < band.max() < 2.2 and 440.0 <= GRID[np.argmax(band)] <= 500.0


# --------------------------------------------------------------------------------------------------
# Spectral reconstruction
# --------------------------------------------------------------------------------------------------


def test_interpolation_matrix_is_lagrange_basis():
    b = sc.interpolation_matrix()
    assert b.shape == (81, 3)
    np.testing.assert_allclose(b.sum(axis=1), 1.0, atol=1e-12)
    # Rows at the nodes 615 and 450 nm (on the grid) pick out the node's value.
    np.testing.assert_allclose(b[_grid_index(615.0)], [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(b[_grid_index(450.0)], [0.0, 0.0, 1.0], atol=1e-12)


def test_quadratic_is_reproduced_exactly():
    def q(lam):
        return 0.4 + 1e-3 * (lam - 500.0) + 2e-6 * (lam - 500.0) ** 2

    spec = sc.solar_relative_to_spectrum(q(WAVELENGTHS_NM))
    expected = q(GRID) * sc.solar_irradiance_on_grid() / (4.0 * np.pi)
    np.testing.assert_allclose(spec, expected, rtol=1e-12)


def test_flat_spectrum_is_solar_spectrum_over_4pi():
    spec = sc.solar_relative_to_spectrum(np.full(3, 4.0))
    # Paper Eq. 2: L' = 4 pi L / E  =>  L = L' E / (4 pi).
    np.testing.assert_allclose(spec, 4.0 * sc.solar_irradiance_on_grid() / (4.0 * np.pi), rtol=1e-12)


def test_spectrum_is_clipped_at_zero():
    # Strongly red: the extrapolated parabola goes negative in the blue/violet.
    spec = sc.solar_relative_to_spectrum([1.5, 0.3, 0.01])
    b = sc.interpolation_matrix() @ np.array([1.5, 0.3, 0.01])
    assert np.any(b < 0)
    assert np.all(spec >= 0.0)
    np.testing.assert_array_equal(spec[b < 0], 0.0)


def test_spectrum_with_other_wavelengths():
    spec = sc.solar_relative_to_spectrum(np.array([1.0, 2.0]), wavelengths_nm=[400.0, 700.0])
    lin = np.interp(GRID, [400.0, 700.0], [1.0, 2.0], left=np.nan, right=np.nan)
    ok = ~np.isnan(lin)
    np.testing.assert_allclose(spec[ok], lin[ok] * sc.solar_irradiance_on_grid()[ok] / (4 * np.pi), rtol=1e-12)


# --------------------------------------------------------------------------------------------------
# XYZ
# --------------------------------------------------------------------------------------------------


def test_sun_chromaticity_matches_independent_cie_integration():
    # Independent: trapezoid over the 1 nm CIE table with the native G173 spectrum.
    wl, xyz_bar = sc.cie_1931_cmfs()
    swl, se = sc.astm_g173_extraterrestrial()
    ref = np.trapezoid(np.interp(wl, swl, se)[:, None] * xyz_bar, wl, axis=0)
    xy_ref = _xy(ref)
    np.testing.assert_allclose(xy_ref, [0.3234, 0.3327], atol=1e-4)  # ASTM G173 extraterrestrial
    white = sc.sun_white_XYZ()
    assert white[1] == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(_xy(white), xy_ref, atol=3e-4)
    # The paper's 5780 K black body is within ~0.003 of it.
    bb = colour.sd_to_XYZ(colour.sd_blackbody(5780.0))
    np.testing.assert_allclose(_xy(bb), xy_ref, atol=0.004)


@pytest.mark.parametrize("level", [0.0, 0.07, 1.0, 2.5, 4.0, 1e3])
def test_flat_radiance_gives_sun_chromaticity_and_Y_equal_level(level):
    xyz = sc.solar_relative_to_XYZ(np.full(3, level))
    assert xyz[1] == pytest.approx(level, rel=1e-12, abs=1e-15)
    np.testing.assert_allclose(xyz, level * sc.sun_white_XYZ(), rtol=1e-12, atol=1e-15)


def test_xyz_is_linear_where_not_clipped():
    a = np.array([0.07, 0.12, 0.25])
    b = np.array([2.0, 1.9, 1.7])
    np.testing.assert_allclose(
        sc.solar_relative_to_XYZ(0.3 * a + 2.0 * b),
        0.3 * sc.solar_relative_to_XYZ(a) + 2.0 * sc.solar_relative_to_XYZ(b),
        rtol=1e-12,
    )


def test_fast_path_equals_spectral_sum_including_clipped_pixels():
    rng = np.random.default_rng(42)
    rad = rng.uniform(0.0, 2.0, size=(3, 40, 50))
    rad[:, :5] *= np.array([1.0, 0.2, 0.01])[:, None, None]  # strongly red: clipped in the blue
    rad[:, 5:10] *= np.array([0.01, 0.2, 1.0])[:, None, None]  # strongly blue: clipped in the red
    b = sc.interpolation_matrix()
    clipped = (np.einsum("kn,n...->...k", b, rad) < 0).any(axis=-1)
    assert 0 < clipped.sum() < clipped.size
    np.testing.assert_allclose(sc.solar_relative_to_XYZ(rad), _brute_force_xyz(rad), rtol=1e-12, atol=1e-14)


def test_clear_sky_is_blue():
    xy = _xy(sc.solar_relative_to_XYZ([0.07, 0.12, 0.25]))
    white = _xy(sc.sun_white_XYZ())
    assert xy[0] < white[0] - 0.05 and xy[1] < white[1] - 0.05


# --------------------------------------------------------------------------------------------------
# Rayleigh sky (paper: x = y = 0.235)
# --------------------------------------------------------------------------------------------------


def test_rayleigh_sky_spectral_matches_paper():
    xy = sc.rayleigh_sky_chromaticity("spectral")
    assert xy.shape == (2,)
    np.testing.assert_allclose(xy, [0.2343, 0.2343], atol=1e-4)  # measured
    np.testing.assert_allclose(xy, [0.235, 0.235], atol=0.002)  # paper, Sect. 3.8


def test_rayleigh_sky_three_wavelengths_close_to_spectral():
    xy3 = sc.rayleigh_sky_chromaticity("three_wavelengths")
    np.testing.assert_allclose(xy3, [0.2346, 0.2365], atol=1e-4)  # measured
    np.testing.assert_allclose(xy3, [0.235, 0.235], atol=0.002)  # paper, Sect. 3.8
    np.testing.assert_allclose(xy3, sc.rayleigh_sky_chromaticity("spectral"), atol=0.0025)


def test_rayleigh_bad_method():
    with pytest.raises(SwimInputError, match="method"):
        sc.rayleigh_sky_chromaticity("planck")


# --------------------------------------------------------------------------------------------------
# Display RGB
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("transform", ["Bradford", "CAT02", "Von Kries"])
def test_display_matrix_maps_sun_to_white(transform):
    m = sc.display_matrix(transform)
    np.testing.assert_allclose(m @ sc.sun_white_XYZ(), 1.0, atol=1e-12)
    # Small per-channel renormalisation only: close to sRGB matrix @ CAT.
    srgb = np.asarray(colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB)
    cat = colour.adaptation.matrix_chromatic_adaptation_VonKries(
        sc.sun_white_XYZ(), colour.xy_to_XYZ(colour.RGB_COLOURSPACES["sRGB"].whitepoint), transform=transform
    )
    np.testing.assert_allclose(m, srgb @ cat, rtol=1e-3, atol=1e-4)


def test_display_matrix_bad_transform():
    with pytest.raises(SwimInputError, match="transform"):
        sc.display_matrix("nope")


def test_paper_eq36_is_srgb_like():
    inv = np.linalg.inv(sc.PAPER_EQ36_MATRIX)
    primaries = _xy(inv.T)  # columns of the inverse: XYZ of R, G, B
    np.testing.assert_allclose(primaries, colour.RGB_COLOURSPACES["sRGB"].primaries, atol=0.011)
    # Its white (RGB = 1, 1, 1) is a warm white, CCT ~ 5640 K, near the paper's 5780 K.
    white = _xy(inv @ np.ones(3))
    np.testing.assert_allclose(white, [0.3292, 0.3449], atol=1e-4)
    assert 5500.0 < colour.xy_to_CCT(white) < 5800.0
    # Red and green rows agree with our sun-white sRGB matrix to 0.025; the blue row's Z weight
    # differs (1.2244 vs 1.114): Eq. 36's white has less blue than the G173 sun.
    m = sc.display_matrix()
    np.testing.assert_allclose(m[:2], sc.PAPER_EQ36_MATRIX[:2], atol=0.025)
    np.testing.assert_allclose(m[2, :2], sc.PAPER_EQ36_MATRIX[2, :2], atol=0.01)
    assert sc.PAPER_EQ36_MATRIX[2, 2] - m[2, 2] == pytest.approx(0.110, abs=0.005)


@pytest.mark.parametrize("white_level", [0.5, sc.DEFAULT_WHITE_LEVEL, 4.0])
def test_flat_white_level_maps_to_display_white(white_level):
    """Without the tone curve a flat L' equal to the white level is display white; the "filmic" curve shows it as
    the neutral grey of its shoulder at 1 and keeps everything below the knee linear."""
    xyz = sc.solar_relative_to_XYZ(np.full(3, white_level))
    for gamut in ("preserve_hue", "clip"):
        np.testing.assert_allclose(sc.XYZ_to_display_rgb(xyz, white_level, gamut=gamut), [1.0] * 3, atol=1e-12)
        np.testing.assert_array_equal(sc.solar_relative_to_srgb8(np.full(3, white_level), white_level, gamut=gamut),
                                      [255, 255, 255])
    tone_1 = 0.6 + 0.4 * (1.0 - np.exp(-1.0))
    np.testing.assert_allclose(sc.XYZ_to_display_rgb(xyz, white_level), [tone_1] * 3, atol=1e-12)
    np.testing.assert_allclose(sc.XYZ_to_display_rgb(0.3 * xyz, white_level), [0.3, 0.3, 0.3], atol=1e-12)


def test_default_exposure_shows_sky_blue_unsaturated_and_sunlit_cloud_white():
    # A white Lambertian surface facing the sun has L' = 4 (Eq. 2): it must be display white.
    np.testing.assert_array_equal(sc.solar_relative_to_srgb8(np.full(3, 4.0)), [255, 255, 255])
    # A single-scattering clear-sky zenith at 30 deg solar zenith (Rayleigh tau 0.06/0.10/0.22):
    # blue, unsaturated, neither black nor white.
    r, g, b = sc.solar_relative_to_srgb8(np.array([0.07, 0.12, 0.25])).astype(int)
    assert b > g > r and 60 < b < 250


@pytest.mark.parametrize("level", [0.01, 0.1, 0.5, 1.0, 2.0])
def test_flat_radiance_is_neutral_grey(level):
    rgb8 = sc.solar_relative_to_srgb8(np.full(3, level))
    assert rgb8[0] == rgb8[1] == rgb8[2]


def test_brightness_proportional_and_monotonic():
    levels = np.linspace(0.0, 5.0, 201)
    rad = np.broadcast_to(np.array([0.07, 0.12, 0.25])[:, None], (3, levels.size)) * levels / 0.25
    rgb = sc.XYZ_to_display_rgb(sc.solar_relative_to_XYZ(rad), gamut="none")
    # Linear: rgb proportional to level.
    np.testing.assert_allclose(rgb, rgb[-1] * (levels / levels[-1])[:, None], rtol=1e-12, atol=1e-15)
    enc = sc.solar_relative_to_srgb8(rad).astype(int)
    assert np.all(np.diff(enc, axis=0) >= 0)


def test_gamut_preserve_hue_desaturates_out_of_gamut_colours():
    # Monochromatic 520 nm light lies far outside the sRGB triangle.
    wl, xyz_bar = sc.cie_1931_cmfs()
    xyz = 0.5 * xyz_bar[wl == 520.0][0] / xyz_bar[wl == 520.0][0][1]
    raw = sc.XYZ_to_display_rgb(xyz, 1.0, gamut="none")
    assert raw.min() < 0.0
    mapped = sc.XYZ_to_display_rgb(xyz, 1.0)
    assert mapped.min() == pytest.approx(0.0, abs=1e-12)
    lum = np.linalg.inv(sc.display_matrix())[1]
    assert lum.sum() == pytest.approx(1.0, abs=1e-12)
    y = raw @ lum
    assert mapped @ lum == pytest.approx(y, rel=1e-12)  # luminance kept
    # Hue kept: the offset from the neutral axis is parallel to the original one.
    d0, d1 = raw - y, mapped - y
    assert np.dot(d0, d1) / (np.linalg.norm(d0) * np.linalg.norm(d1)) == pytest.approx(1.0, abs=1e-12)


def test_gamut_preserve_hue_scales_over_range():
    xyz = sc.solar_relative_to_XYZ([3.0, 1.2, 0.2])  # bright, orange (sunset-lit cloud)
    raw = sc.XYZ_to_display_rgb(xyz, 1.0, gamut="none")
    assert raw.max() > 1.0 and raw.min() >= 0.0
    mapped = sc.XYZ_to_display_rgb(xyz, 1.0, gamut="preserve_hue")
    np.testing.assert_allclose(mapped, raw / raw.max(), rtol=1e-12)
    clipped = sc.XYZ_to_display_rgb(xyz, 1.0, gamut="clip")
    np.testing.assert_allclose(clipped, np.clip(raw, 0, 1), rtol=1e-12)


def test_gamut_results_in_unit_cube():
    rng = np.random.default_rng(1)
    xyz = rng.uniform(-0.2, 3.0, size=(1000, 3))
    for gamut in ("filmic", "preserve_hue", "clip"):
        rgb = sc.XYZ_to_display_rgb(xyz, 1.0, gamut=gamut)
        assert rgb.min() >= 0.0 and rgb.max() <= 1.0 + 1e-12


def test_display_rgb_bad_arguments():
    with pytest.raises(SwimInputError, match="white_level"):
        sc.XYZ_to_display_rgb(np.ones(3), 0.0)
    with pytest.raises(SwimInputError, match="white_level"):
        sc.XYZ_to_display_rgb(np.ones(3), np.nan)
    with pytest.raises(SwimInputError, match="gamut"):
        sc.XYZ_to_display_rgb(np.ones(3), gamut="stretch")
    with pytest.raises(SwimInputError, match="XYZ"):
        sc.XYZ_to_display_rgb(np.ones((3, 4)))


# --------------------------------------------------------------------------------------------------
# sRGB encoding
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(), (7,), (3, 5, 3)])
def test_oetf_srgb_is_colour_sciences(shape):
    """swim's sRGB OETF (written out, so that a render need not import colour-science) is colour-science's
    eotf_inverse_sRGB, on both branches, at the joint, outside [0, 1] and for NaN, over several array shapes."""
    rng = np.random.default_rng(5)
    x = rng.uniform(-0.05, 1.2, shape)
    if x.ndim:
        x.flat[0], x.flat[-1] = 0.0031308, np.nan
    np.testing.assert_allclose(sc.oetf_srgb(x), colour.models.eotf_inverse_sRGB(x), rtol=1e-15, atol=1e-16)
    assert np.shape(sc.oetf_srgb(x)) == shape


def test_a_render_needs_no_colour_science():
    """The colour stage runs on the tables shipped with swim: a process encodes an image without importing
    colour-science (~0.6-1.2 s and ~100 MB)."""
    import subprocess
    import sys

    script = ("import sys, numpy as np; from swim.color import solar_relative_to_srgb8; "
              "rgb = solar_relative_to_srgb8(np.linspace(0.01, 3.0, 96).reshape(3, 4, 8)); "
              "print(int('colour' in sys.modules), rgb.tobytes().hex())")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True).stdout.split()
    assert out[0] == "0"
    np.testing.assert_array_equal(np.frombuffer(bytes.fromhex(out[1]), np.uint8).reshape(4, 8, 3),
                                  sc.solar_relative_to_srgb8(np.linspace(0.01, 3.0, 96).reshape(3, 4, 8)))


def test_the_shipped_colour_tables_are_colour_sciences():
    """src/swim/data/colour_tables.npz (scripts/make_colour_tables.py) holds colour-science's CIE 1931 colour matching
    functions, sRGB matrix and D65 white, and every chromatic adaptation transform's matrix, exactly."""
    from swim.color._tables import colour_science_data

    data = colour_science_data()
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    np.testing.assert_array_equal(data["cmfs_wavelength_nm"], cmfs.wavelengths)
    np.testing.assert_array_equal(data["cmfs"], cmfs.values)
    srgb = colour.RGB_COLOURSPACES["sRGB"]
    np.testing.assert_array_equal(data["srgb_XYZ_to_RGB"], srgb.matrix_XYZ_to_RGB)
    np.testing.assert_array_equal(data["srgb_whitepoint_XYZ"], colour.xy_to_XYZ(srgb.whitepoint))
    for name, matrix in colour.CHROMATIC_ADAPTATION_TRANSFORMS.items():
        np.testing.assert_array_equal(colour_science_data(name)["cat"], matrix)
    with pytest.raises(SwimInputError, match="Bradford"):
        colour_science_data("Brad")


def test_oetf_srgb_published_constants():
    # IEC 61966-2-1: linear segment 12.92 L up to 0.0031308, where both branches give 0.04045.
    assert sc.oetf_srgb(0.0031308) == pytest.approx(12.92 * 0.0031308, rel=1e-12)
    assert 1.055 * 0.0031308 ** (1 / 2.4) - 0.055 == pytest.approx(0.04045, abs=1e-5)
    assert sc.oetf_srgb(0.0031308) == pytest.approx(0.04045, abs=1e-5)
    assert sc.oetf_srgb(0.001) == pytest.approx(0.01292, rel=1e-12)
    assert sc.oetf_srgb(0.18) == pytest.approx(1.055 * 0.18 ** (1 / 2.4) - 0.055, rel=1e-12)
    np.testing.assert_allclose(sc.oetf_srgb([0.0, 1.0]), [0.0, 1.0], atol=1e-12)
    # Roughly the paper's gamma 2.2 in the mid tones.
    assert sc.oetf_srgb(0.2) == pytest.approx(0.2 ** (1 / 2.2), abs=0.01)


def test_encode_srgb8_values_and_monotonic():
    x = np.linspace(0.0, 1.0, 10001)
    enc = sc.encode_srgb8(x)
    assert enc.dtype == np.uint8 and enc.shape == x.shape
    assert enc[0] == 0 and enc[-1] == 255
    assert np.all(np.diff(enc.astype(int)) >= 0)
    assert set(np.unique(enc)) == set(range(256))
    # 18 % grey -> 118 (0.4614 * 255 = 117.7).
    assert sc.encode_srgb8(0.18) == 118
    # Round trip through the sRGB EOTF within half a code value.
    np.testing.assert_allclose(colour.models.eotf_sRGB(enc / 255.0), x, atol=2.5 * 0.5 / 255)  # max EOTF slope ~2.3


def test_encode_srgb8_clips_and_handles_nan():
    np.testing.assert_array_equal(sc.encode_srgb8([-0.5, 2.0, np.nan, np.inf]), [0, 255, 0, 255])


# --------------------------------------------------------------------------------------------------
# Whole chain: shapes, NaN, errors
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("shape", "out"), [((3,), (3,)), ((3, 5), (5, 3)), ((3, 4, 6), (4, 6, 3))])
def test_shapes(shape, out):
    rng = np.random.default_rng(0)
    rad = rng.uniform(0.0, 3.0, size=shape)
    assert sc.solar_relative_to_spectrum(rad).shape == out[:-1] + (81,)
    xyz = sc.solar_relative_to_XYZ(rad)
    assert xyz.shape == out
    assert sc.XYZ_to_display_rgb(xyz).shape == out
    rgb8 = sc.solar_relative_to_srgb8(rad)
    assert rgb8.shape == out and rgb8.dtype == np.uint8
    # Each pixel equals the single-pixel result.
    flat = rad.reshape(3, -1)
    for j in range(flat.shape[1]):
        np.testing.assert_array_equal(rgb8.reshape(-1, 3)[j], sc.solar_relative_to_srgb8(flat[:, j]))
        np.testing.assert_allclose(xyz.reshape(-1, 3)[j], sc.solar_relative_to_XYZ(flat[:, j]), rtol=1e-12)


def _srgb8_by_numpy_chain(rad, white_level, gamut):
    """The colour stage as the chain of the public NumPy functions (solar_relative_to_srgb8's documented steps)."""
    rad = np.asarray(rad, dtype=float)
    invalid = np.isnan(rad).any(axis=0)
    rgb = sc.XYZ_to_display_rgb(sc.solar_relative_to_XYZ(np.where(invalid, 0.0, rad)), white_level, gamut=gamut)
    out = sc.encode_srgb8(rgb)
    out[invalid] = 0
    return out


@pytest.mark.parametrize("gamut", sc.GAMUT_MAPPINGS)
@pytest.mark.parametrize("shape", [(3,), (3, 7), (3, 64, 48)])
def test_the_compiled_colour_stage_gives_the_numpy_chains_codes(shape, gamut):
    """solar_relative_to_srgb8 runs one compiled pass per pixel (swim.color.srgb_cpu) and sends the pixels whose
    quadratic spectrum needs clipping to the clipped spectral sum: every code as the chain of the NumPy functions,
    over skies, overexposed clouds, saturated colours outside the sRGB gamut, spectra that dip below 0, NaN."""
    rng = np.random.default_rng(len(shape) * 7 + sc.GAMUT_MAPPINGS.index(gamut))
    n = int(np.prod(shape[1:]))
    kinds = [rng.uniform(0.0, 0.3, (3, n)) * [[0.4], [0.7], [1.0]],   # blue skies
             rng.uniform(0.5, 8.0, (3, n)),                            # clouds, overexposed at the white level
             rng.uniform(0.0, 1.5, (3, n)) ** 3,                       # saturated: out of gamut, dipping spectra
             np.abs(rng.normal(0.0, 1.0, (3, n)))]
    for rad in kinds:
        rad = rad.reshape(shape)
        if n > 1:
            rad[(1,) + (0,) * (len(shape) - 1)] = np.nan
        for white_level in (1.5, 4.0):
            np.testing.assert_array_equal(sc.solar_relative_to_srgb8(rad, white_level, gamut=gamut),
                                          _srgb8_by_numpy_chain(rad, white_level, gamut))
    # both branches of the compiled pass were taken: pixels that need the clipped sum, and pixels that do not
    from swim.color.spectrum import _DEFAULT_WAVELENGTHS, _may_clip_quadratic, _monomial_solve

    coefficients = kinds[2].T @ _monomial_solve(_DEFAULT_WAVELENGTHS).T
    assert 0 < _may_clip_quadratic(coefficients).sum() < n or n < 8


def test_the_compiled_colour_stage_takes_float32_and_any_layout():
    rng = np.random.default_rng(3)
    rad = rng.uniform(0.0, 2.0, (3, 40, 30)).astype(np.float32)
    expected = _srgb8_by_numpy_chain(rad, 1.5, "filmic")
    np.testing.assert_array_equal(sc.solar_relative_to_srgb8(rad), expected)
    np.testing.assert_array_equal(sc.solar_relative_to_srgb8(rad[:, 10:20]), expected[10:20])
    np.testing.assert_array_equal(sc.solar_relative_to_srgb8(np.asfortranarray(rad)), expected)


def test_nan_pixels_are_black_and_do_not_leak():
    rad = np.full((3, 4, 5), 1.0)
    rad[:, 0, 0] = np.nan
    rad[1, 2, 3] = np.nan  # one channel only
    rgb8 = sc.solar_relative_to_srgb8(rad)
    np.testing.assert_array_equal(rgb8[0, 0], [0, 0, 0])
    np.testing.assert_array_equal(rgb8[2, 3], [0, 0, 0])
    good = np.ones((4, 5), dtype=bool)
    good[0, 0] = good[2, 3] = False
    np.testing.assert_array_equal(rgb8[good], np.broadcast_to(sc.solar_relative_to_srgb8(np.ones(3)), (18, 3)))
    assert np.all(rgb8[good] > 0)
    # Lower-level functions propagate NaN instead.
    assert np.all(np.isnan(sc.solar_relative_to_XYZ(rad)[0, 0]))
    np.testing.assert_array_equal(sc.solar_relative_to_srgb8(np.full(3, np.nan)), [0, 0, 0])


def test_bad_radiance_inputs():
    with pytest.raises(SwimInputError, match="radiance"):
        sc.solar_relative_to_XYZ(np.ones((4, 2)))
    with pytest.raises(SwimInputError, match="radiance"):
        sc.solar_relative_to_srgb8(np.ones((2, 3)))
    with pytest.raises(SwimInputError, match="radiance"):
        sc.solar_relative_to_spectrum(np.float64(1.0))
    with pytest.raises(SwimInputError, match="infinite"):
        sc.solar_relative_to_srgb8(np.array([np.inf, 1.0, 1.0]))
    with pytest.raises(SwimInputError, match="wavelengths_nm"):
        sc.solar_relative_to_spectrum(np.ones(3), wavelengths_nm=[500.0, 500.0, 600.0])
    with pytest.raises(SwimInputError, match="white_level"):
        sc.solar_relative_to_srgb8(np.ones(3), white_level=-1.0)


def test_typical_scene_colours():
    """Clear sky is blue and darker than cloud; sunlit cloud tops are near white at the default exposure."""
    sky = sc.solar_relative_to_srgb8([0.07, 0.12, 0.25]).astype(int)
    base = sc.solar_relative_to_srgb8([1.0, 1.0, 1.0]).astype(int)
    top = sc.solar_relative_to_srgb8([3.0, 3.0, 3.0]).astype(int)
    assert sky[2] > sky[1] > sky[0]
    assert sky.max() < base.min() and base.max() < top.min()
    assert top[0] == top[1] == top[2] >= 250


def test_the_code_tables_hold_the_exact_steps_of_the_srgb_encoding():
    """swim.color.srgb_cpu.code_tables: each step is the first float64 at which the pow-based encoding (the
    compiled _encode, IEC 61966-2-1's transfer function rounded to 0-255) gives the next code, and the float
    before it still the code below; the steps rise, and each bin of the start table holds at most one."""
    from swim.color.srgb_cpu import CODE_BINS, _encode, code_tables

    steps, start = code_tables()
    assert steps.shape == (257,) and start.shape == (CODE_BINS + 1,)
    assert steps[0] == -np.inf and steps[-1] == np.inf and np.all(np.diff(steps) > 0)
    for k in range(255):
        assert _encode(steps[k + 1]) == k + 1
        assert _encode(np.nextafter(steps[k + 1], 0.0)) == k
    # at most one step between a bin's first value and the next bin's
    assert np.diff(start).max() == 1
    # 12.92 * 255 codes per unit of linear value at the steepest: the first step, at half a code
    assert steps[1] == pytest.approx(0.5 / 255 / 12.92, rel=1e-12)


@pytest.mark.parametrize("draw", ["uniform", "cubed", "tiny", "out of range", "at the steps"])
def test_the_table_encoding_gives_the_pow_encodings_codes(draw):
    """The colour kernel's branch-free table lookup (swim.color.srgb_cpu._encode_by_table) against the pow-based
    encoding it replaced, value for value: uniform and dark-weighted values, values near 0 (the linear segment),
    values outside [0, 1] and NaN, and every step with the 3 floats on either side."""
    from numba import njit

    from swim.color.srgb_cpu import _encode, _encode_by_table, code_tables

    steps, start = code_tables()
    rng = np.random.default_rng(len(draw))
    if draw == "uniform":
        v = rng.random(200_000)
    elif draw == "cubed":
        v = rng.random(200_000) ** 3
    elif draw == "tiny":
        v = 10.0 ** rng.uniform(-12, -2, 200_000)
    elif draw == "out of range":
        v = np.concatenate([rng.uniform(-2, 0, 1000), rng.uniform(1, 5, 1000), [0.0, -0.0, 1.0, np.nan, np.inf,
                                                                              -np.inf, 1e308, -1e308]])
    else:
        v = steps[1:256, None].copy()
        v = np.concatenate([v, *(np.nextafter(v, side) for side in (-1.0, 2.0))], axis=1)
        v = np.concatenate([v, np.nextafter(v[:, 1:2], -1.0), np.nextafter(np.nextafter(v[:, 1:2], -1.0), -1.0),
                            np.nextafter(v[:, 2:3], 2.0), np.nextafter(np.nextafter(v[:, 2:3], 2.0), 2.0)], axis=1)
        v = v.reshape(-1)

    @njit
    def both(v, steps, start, by_pow, by_table):
        for i in range(v.size):
            by_pow[i] = _encode(v[i]) if v[i] == v[i] else 0  # NaN: black, as the kernel's caller makes it
            by_table[i] = _encode_by_table(v[i], steps, start)

    by_pow, by_table = np.empty(v.size, np.uint8), np.empty(v.size, np.uint8)
    both(v, steps, start, by_pow, by_table)
    np.testing.assert_array_equal(by_table, by_pow)
    assert len(np.unique(by_pow)) > {"out of range": 1, "tiny": 20}.get(draw, 100)  # up to 0.01: codes 0-25
