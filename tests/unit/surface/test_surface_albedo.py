"""Unit tests of swim.surface.landuse and swim.surface.albedo (spectral albedo builders)."""

import logging

import numpy as np
import pytest

from swim.constants import WAVELENGTHS_NM
from swim.errors import SwimInputError
from swim.surface.albedo import (
    DEFAULT_SNOW_ALBEDO,
    DEFAULT_SNOW_SHORTWAVE_ALBEDO,
    VISIBLE_WEIGHTS,
    albedo_to_fraction,
    blend_snow,
    effective_snow_cover,
    load_image,
    regrid_image_to_scene,
    shortwave_albedo_from_landuse,
    shortwave_albedo_from_landuse_fractions,
    snow_cover_from_swe,
    snow_ice_fraction_from_landuse,
    spectral_albedo_from_broadband,
    spectral_albedo_from_image,
    spectral_albedo_from_landuse,
    spectral_albedo_from_landuse_fractions,
    spectral_albedo_from_rgb,
    srgb_to_linear,
    surface_from_model_fields,
    visible_mean,
)
from swim.surface.landuse import (
    CERES_SARB_BAND_WEIGHTS,
    CERES_SARB_SPECTRAL_ALBEDO,
    CERES_SARB_WAVELENGTHS_NM,
    LANDUSE_SCHEMES,
    landuse_classes,
    landuse_scheme,
    reference_spectral_albedo,
    scheme_from_attrs,
)

USGS = "USGS"
IGBP = "MODIFIED_IGBP_MODIS_NOAH"


# ----------------------------------------------------------------------------------------------------- class tables


@pytest.mark.parametrize(
    "scheme, water, snow, urban, desert, forest",
    [(USGS, (16, 28), 24, 1, 19, 14), (IGBP, (17, 21), 15, 13, 16, 1)],
)
def test_class_kinds_and_ordering(scheme, water, snow, urban, desert, forest):
    classes = landuse_classes(scheme)
    for w in water:
        assert classes[w].kind == "water"
    assert classes[snow].kind == "snow_ice"
    assert classes[urban].kind == "urban"
    assert classes[forest].kind == "land" and classes[desert].kind == "land"
    kinds = {c.kind for c in classes.values()}
    assert kinds == {"land", "water", "snow_ice", "urban"}
    g = 1  # 546 nm
    assert classes[snow].albedo[g] > classes[desert].albedo[g] > classes[forest].albedo[g]
    assert classes[snow].albedo[g] > 0.9
    for w in water:
        assert max(classes[w].albedo) < 0.1


def test_scheme_sizes_and_every_class_in_range():
    assert sorted(LANDUSE_SCHEMES[USGS]) == list(range(1, 29))
    assert sorted(LANDUSE_SCHEMES[IGBP]) == list(range(1, 22))
    for classes in LANDUSE_SCHEMES.values():
        for c in classes.values():
            a = np.array(c.albedo)
            assert a.shape == (3,) and np.all(np.isfinite(a))
            assert np.all((a >= 0.0) & (a <= 1.0)), c
            assert 0.0 < c.shortwave_albedo <= 1.0
            assert c.name


def test_interpolation_to_swim_wavelengths():
    # barren/desert (type 16): 0.179 at 467.5, 0.263 at 546.25, 0.331 at 642.3, 0.144 at 397.5 nm
    a = reference_spectral_albedo(16)
    assert a[0] == pytest.approx(0.263 + (615.0 - 546.25) / (642.3 - 546.25) * (0.331 - 0.263))
    assert a[1] == pytest.approx(0.263 - 0.25 / 78.75 * (0.263 - 0.179))
    assert a[2] == pytest.approx(0.144 + (450.0 - 397.5) / 70.0 * (0.179 - 0.144))
    # USGS Irrigated Cropland carries CMAQ's factor 1.0588 on the cropland spectrum
    crop = landuse_classes(USGS)
    np.testing.assert_allclose(np.array(crop[3].albedo), 1.0588 * np.array(crop[2].albedo))


def test_band_weights_are_astm_g173_global():
    pvlib = pytest.importorskip("pvlib")
    ref = pvlib.spectrum.get_reference_spectra()
    wl = ref.index.values.astype(float)
    e = ref["global"].values

    def band(a, b):
        a, b = max(a, wl[0]), min(b, wl[-1])
        if b <= a:
            return 0.0
        g = np.linspace(a, b, 20001)
        return np.trapezoid(np.interp(g, wl, e), g)

    c = CERES_SARB_WAVELENGTHS_NM
    edges = np.concatenate([[0.0], 0.5 * (c[1:] + c[:-1]), [1e9]])
    w = np.array([band(edges[i], edges[i + 1]) for i in range(c.size)])
    np.testing.assert_allclose(CERES_SARB_BAND_WEIGHTS, w / w.sum(), atol=2e-4)
    vis = np.array([band(580.5, 700.0), band(498.0, 580.5), band(400.0, 498.0)])
    np.testing.assert_allclose(VISIBLE_WEIGHTS, vis / vis.sum(), atol=1e-3)
    assert VISIBLE_WEIGHTS.sum() == pytest.approx(1.0)


def test_shortwave_albedo_of_snow_below_its_visible_albedo():
    # snow is bright in the visible and dark beyond 1.4 um: the shortwave albedo is lower; forest the opposite
    snow = landuse_classes(USGS)[24]
    forest = landuse_classes(USGS)[14]
    assert snow.shortwave_albedo < visible_mean(np.array(snow.albedo))
    assert forest.shortwave_albedo > visible_mean(np.array(forest.albedo))
    assert snow.shortwave_albedo == pytest.approx(float(CERES_SARB_BAND_WEIGHTS @ CERES_SARB_SPECTRAL_ALBEDO[14]))


def test_scheme_names_and_errors(caplog):
    assert landuse_scheme(b" usgs ") == USGS
    assert landuse_scheme("MODI-RUC") == IGBP
    with pytest.raises(SwimInputError, match="MMINLU='NLCD40'"):
        landuse_scheme("NLCD40")
    with caplog.at_level(logging.WARNING, logger="swim.surface.landuse"):
        assert scheme_from_attrs({"MMINLU": "USGS", "ISWATER": 17}, "test file") == USGS
    assert "ISWATER=17" in caplog.text
    assert scheme_from_attrs({}, "x") is None
    assert scheme_from_attrs({"MMINLU": "SiB"}, "x") is None


# ----------------------------------------------------------------------------------------------------- land use


def test_spectral_albedo_from_landuse_shape_and_values():
    lu = np.array([[14, 16, 24], [19, 7, 1]])
    a = spectral_albedo_from_landuse(lu, USGS)
    assert a.shape == (3, 2, 3)
    np.testing.assert_allclose(a[:, 0, 2], landuse_classes(USGS)[24].albedo)
    np.testing.assert_allclose(a[:, 1, 0], landuse_classes(USGS)[19].albedo)
    sw = shortwave_albedo_from_landuse(lu, USGS)
    assert sw[0, 1] == landuse_classes(USGS)[16].shortwave_albedo
    with pytest.raises(SwimInputError, match=r"LU_INDEX.*\[25\].*1-21"):
        spectral_albedo_from_landuse(np.array([1, 25]), IGBP)
    with pytest.raises(SwimInputError, match="LU_INDEX.*integer"):
        spectral_albedo_from_landuse(np.array([1.5]), IGBP)


def test_landusef_weighting():
    ny, nx, ncat = 2, 2, 24
    f = np.zeros((ncat, ny, nx))
    f[13, 0, 0] = 1.0  # class 14 only
    f[13, 0, 1], f[15, 0, 1] = 0.3, 0.7  # 30 % forest, 70 % water
    f[18, 1, :] = 0.5  # fractions summing to less than 1 are renormalised
    a = spectral_albedo_from_landuse_fractions(f, USGS)
    forest = np.array(landuse_classes(USGS)[14].albedo)
    water = np.array(landuse_classes(USGS)[16].albedo)
    np.testing.assert_allclose(a[:, 0, 0], forest)
    np.testing.assert_allclose(a[:, 0, 1], 0.3 * forest + 0.7 * water)
    np.testing.assert_allclose(a[:, 1, 1], landuse_classes(USGS)[19].albedo)
    sw = shortwave_albedo_from_landuse_fractions(f, USGS)
    c = landuse_classes(USGS)
    assert sw[0, 1] == pytest.approx(0.3 * c[14].shortwave_albedo + 0.7 * c[16].shortwave_albedo)
    # class axis last
    np.testing.assert_allclose(spectral_albedo_from_landuse_fractions(np.moveaxis(f, 0, -1), USGS, axis=-1), a)
    with pytest.raises(SwimInputError, match="all class fractions 0"):
        spectral_albedo_from_landuse_fractions(np.zeros((ncat, 1, 1)), USGS)
    with pytest.raises(SwimInputError, match="LANDUSEF.*outside"):
        spectral_albedo_from_landuse_fractions(f * 100.0, USGS)


# ----------------------------------------------------------------------------------------------------- broadband, snow


def test_broadband_scaling_preserves_visible_mean_and_shape():
    cls = np.array(landuse_classes(USGS)[7].albedo)
    big = np.array([[0.05, 0.10], [0.15, 0.2]])
    a = spectral_albedo_from_broadband(big, cls)
    assert a.shape == (3, 2, 2)
    np.testing.assert_allclose(visible_mean(a), big)
    np.testing.assert_allclose(a[:, 1, 0] / cls, 0.15 / visible_mean(cls))  # the class's spectral shape
    # with the class's shortwave albedo as reference: a = a_c A / A_c
    sw = landuse_classes(USGS)[7].shortwave_albedo
    b = spectral_albedo_from_broadband(big, cls, sw)
    np.testing.assert_allclose(b[:, 0, 1], cls * 0.10 / sw)


def test_broadband_percent_and_fraction():
    cls = np.array(landuse_classes(USGS)[14].albedo)
    frac = spectral_albedo_from_broadband(0.134, cls)
    np.testing.assert_allclose(spectral_albedo_from_broadband(13.4, cls, units="%"), frac)
    np.testing.assert_allclose(spectral_albedo_from_broadband(13.4, cls, units="percent"), frac)
    np.testing.assert_allclose(spectral_albedo_from_broadband(13.4, cls), frac)  # no units, > 1: percent
    np.testing.assert_allclose(albedo_to_fraction([50.0], "%"), [0.5])
    with pytest.raises(SwimInputError, match=r"albedo_broadband.*outside \[0, 1\].*percent"):
        spectral_albedo_from_broadband(13.4, cls, units="1")
    with pytest.raises(SwimInputError, match="units 'W m-2'"):
        albedo_to_fraction(0.1, "W m-2", "ALBEDO")
    # clipping to 1: a bright broadband albedo on a snow-shaped class
    snow = np.array(landuse_classes(USGS)[24].albedo)
    assert spectral_albedo_from_broadband(0.99, snow, 0.5).max() == 1.0
    # a black class gets the broadband value at every wavelength
    np.testing.assert_allclose(spectral_albedo_from_broadband(0.2, np.zeros(3)), 0.2)


def test_blend_snow_limits():
    base = np.stack([np.full((2, 2), v) for v in (0.1, 0.08, 0.05)])
    np.testing.assert_array_equal(blend_snow(base, 0.0), base)
    one = blend_snow(base, np.ones((2, 2)))
    np.testing.assert_allclose(one, np.broadcast_to(DEFAULT_SNOW_ALBEDO[:, None, None], base.shape))
    half = blend_snow(base, 0.5)
    np.testing.assert_allclose(half, 0.5 * base + 0.5 * DEFAULT_SNOW_ALBEDO[:, None, None])
    # SNOALB rescales the snow spectrum: the default snow's own shortwave albedo leaves it unchanged
    np.testing.assert_allclose(blend_snow(base, 1.0, snow_broadband=DEFAULT_SNOW_SHORTWAVE_ALBEDO), one)
    pct = blend_snow(base, 1.0, snow_broadband=43.5)  # percent, as in met_em SNOALB
    expect = DEFAULT_SNOW_ALBEDO[:, None, None] * 0.435 / DEFAULT_SNOW_SHORTWAVE_ALBEDO
    np.testing.assert_allclose(pct, np.broadcast_to(expect, base.shape))
    with pytest.raises(SwimInputError, match=r"snow_cover.*outside \[0, 1\]"):
        blend_snow(base, 50.0)


def test_snow_cover_from_swe():
    f = snow_cover_from_swe(np.array([0.0, 1.0, 10.0, 39.999, 40.0, 500.0]))
    assert f[0] == 0.0 and f[-1] == 1.0 and f[-2] == 1.0
    assert f[3] == pytest.approx(1.0, abs=1e-4)  # continuous at the threshold
    assert np.all(np.diff(f) >= 0)
    r = 10.0 / 40.0
    assert f[2] == pytest.approx(1.0 - (np.exp(-2.6 * r) - r * np.exp(-2.6)))
    with pytest.raises(SwimInputError, match="SNOW"):
        snow_cover_from_swe([-1.0])


def test_model_fields_snow_free_albedo_and_snow_cover():
    lu = np.full((1, 3), 14)  # evergreen needleleaf forest
    forest = landuse_classes(USGS)[14]
    f = np.array([[0.0, 0.5, 1.0]])
    # ALBBCK-like (excludes snow): the class spectrum scaled by A / A_forest; snow cover passed on unchanged
    a, snow = surface_from_model_fields(np.full((1, 3), 0.12), lu_index=lu, scheme=USGS, snow_cover=f)
    np.testing.assert_allclose(a, np.broadcast_to(np.array(forest.albedo)[:, None, None] * 0.12 / forest.shortwave_albedo, a.shape))
    np.testing.assert_array_equal(snow, f)
    # WRF ALBEDO (includes snow): A_0 = (A - f A_snow) / (1 - f) is given the forest shape; f = 1 hides it
    big = np.array([[0.12, 0.5 * 0.12 + 0.5 * DEFAULT_SNOW_SHORTWAVE_ALBEDO, 0.7]])
    b, _ = surface_from_model_fields(big, lu_index=lu, scheme=USGS, snow_cover=f, includes_snow=True)
    np.testing.assert_allclose(b[:, 0, 1], b[:, 0, 0])
    np.testing.assert_allclose(b[:, 0, 2], forest.albedo)
    # visible matching instead of shortwave
    c, _ = surface_from_model_fields(np.full((1, 1), 0.12), lu_index=np.full((1, 1), 14), scheme=USGS, band="visible")
    assert visible_mean(c)[0, 0] == pytest.approx(0.12)
    # no land use: flat; nothing: None
    flat, none = surface_from_model_fields(np.full((1, 1), 18.0), units="%")
    np.testing.assert_allclose(flat, 0.18)
    assert none is None
    assert surface_from_model_fields(None) == (None, None)
    with pytest.raises(SwimInputError, match="albedo_band"):
        surface_from_model_fields(np.full((1, 1), 0.1), band="infrared")


def test_snow_ice_classes_count_as_snow_cover():
    lu = np.array([[24, 14]])
    np.testing.assert_array_equal(snow_ice_fraction_from_landuse(USGS, lu_index=lu), [[1.0, 0.0]])
    f = np.zeros((21, 1, 2))
    f[14, 0, 0], f[0, 0, 0] = 0.25, 0.75  # IGBP 15 (snow and ice) 25 %
    f[16, 0, 1] = 1.0  # water
    np.testing.assert_allclose(snow_ice_fraction_from_landuse(IGBP, landusef=f), [[0.25, 0.0]])
    _, snow = surface_from_model_fields(np.full((1, 2), 0.5), lu_index=lu, scheme=USGS,
                                        snow_cover=np.array([[0.0, 0.3]]))
    np.testing.assert_array_equal(snow, [[1.0, 0.3]])
    _, none = surface_from_model_fields(np.full((1, 1), 0.1), lu_index=np.full((1, 1), 14), scheme=USGS)
    assert none is None


def test_effective_snow_cover_reproduces_snoalb_blend():
    a = np.array(landuse_classes(USGS)[14].albedo)[:, None] * np.ones((3, 4))
    f = np.array([0.0, 0.3, 1.0, 1.0])
    snoalb = np.array([0.4, 0.4, 0.4, 0.9])
    eff = effective_snow_cover(f, a, snoalb)
    target = visible_mean(blend_snow(a, f, snow_broadband=snoalb))
    np.testing.assert_allclose(visible_mean((1 - eff) * a + eff * DEFAULT_SNOW_ALBEDO[:, None])[:3], target[:3])
    assert eff[0] == 0.0 and 0.0 < eff[1] < 0.3 and eff[2] < 0.6  # a snowy conifer forest is far from white
    assert eff[3] == 1.0  # SNOALB above the default snow's shortwave albedo: capped at the snow cover
    # the default snow's own shortwave albedo leaves the snow cover unchanged
    np.testing.assert_allclose(effective_snow_cover(f, a, DEFAULT_SNOW_SHORTWAVE_ALBEDO), f)
    np.testing.assert_allclose(effective_snow_cover(f, a, 100.0 * snoalb, snow_units="%"), eff)


# ----------------------------------------------------------------------------------------------------- RGB images


def test_srgb_decoding():
    v = np.linspace(0.0, 1.0, 101)
    colour = pytest.importorskip("colour")
    np.testing.assert_allclose(srgb_to_linear(v), colour.cctf_decoding(v, function="sRGB"), atol=1e-12)
    assert srgb_to_linear(0.5) == pytest.approx(0.214041, abs=1e-6)
    assert srgb_to_linear(0.04045) == pytest.approx(0.04045 / 12.92)


def test_rgb_white_black_monotonic():
    white = np.full((2, 3, 3), 255, dtype=np.uint8)
    np.testing.assert_allclose(spectral_albedo_from_rgb(white), 1.0)
    np.testing.assert_allclose(spectral_albedo_from_rgb(white, scale=0.8), 0.8)
    np.testing.assert_array_equal(spectral_albedo_from_rgb(np.zeros((4, 3), dtype=np.uint8)), 0.0)
    grey = np.repeat(np.arange(256, dtype=np.uint8)[:, None], 3, axis=1)
    a = spectral_albedo_from_rgb(grey, scale=0.9)
    assert a.shape == (3, 256)
    assert np.all(np.diff(a, axis=1) > 0)
    np.testing.assert_allclose(a[0], a[2])  # grey: the same albedo at every wavelength


def test_rgb_channels_to_modis_bands():
    # linear encoding, one channel at a time: 615 nm lies 2/3 of the way from 555 to 645 nm
    red = spectral_albedo_from_rgb(np.array([1.0, 0.0, 0.0]), encoding="linear")
    np.testing.assert_allclose(red, [60.0 / 90.0, 0.0, 0.0])
    green = spectral_albedo_from_rgb(np.array([0.0, 0.5, 0.0]), encoding="linear")
    np.testing.assert_allclose(green, [0.5 * 30.0 / 90.0, 0.5 * 77.0 / 86.0, 0.0])  # 450 nm clipped at 0
    blue = spectral_albedo_from_rgb(np.array([0.0, 0.0, 0.5]), encoding="linear")
    np.testing.assert_allclose(blue, [0.0, 0.5 * 9.0 / 86.0, 0.5 * (1.0 + 19.0 / 86.0)])
    per_channel = spectral_albedo_from_rgb(np.array([1.0, 1.0, 1.0]), scale=(0.5, 0.5, 0.5), encoding="linear")
    np.testing.assert_allclose(per_channel, 0.5)
    with pytest.raises(SwimInputError, match="image"):
        spectral_albedo_from_rgb(np.array([1.5, 0.0, 0.0]))
    with pytest.raises(SwimInputError, match="scale"):
        spectral_albedo_from_rgb(np.array([1.0, 0.0, 0.0]), scale=0.0)


def _lonlat_image(rows=18, cols=36):
    lat = 90.0 - (np.arange(rows) + 0.5) * 180.0 / rows
    lon = -180.0 + (np.arange(cols) + 0.5) * 360.0 / cols
    glon, glat = np.meshgrid(lon, lat)
    return np.stack([glon, glat, np.ones_like(glon)], axis=-1)


def test_regrid_bilinear_reproduces_linear_field_and_nearest():
    img = _lonlat_image()
    lat = np.array([[10.0, -33.3], [61.0, 0.0]])
    lon = np.array([[-100.0, 12.5], [150.2, 0.0]])
    out = regrid_image_to_scene(img, lat, lon)
    assert out.shape == (2, 2, 3)
    np.testing.assert_allclose(out[..., 0], lon, atol=1e-9)
    np.testing.assert_allclose(out[..., 1], lat, atol=1e-9)
    near = regrid_image_to_scene(img, np.array([12.0]), np.array([-101.0]), method="nearest")
    np.testing.assert_allclose(near[0, :2], [-105.0, 15.0])  # the 10-degree pixel that contains the point
    # the same with a GDAL geotransform, and longitudes given in 0..360
    gt = (-180.0, 10.0, 0.0, 90.0, 0.0, -10.0)
    np.testing.assert_allclose(regrid_image_to_scene(img, lat, lon + 360.0, geotransform=gt), out, atol=1e-9)


def test_regrid_wraps_the_dateline_and_rejects_outside_points():
    img = _lonlat_image()
    out = regrid_image_to_scene(img, np.array([0.0, 0.0]), np.array([179.0, -179.0]))
    # between the last column (175) and the first (-175 = 185): linear in the unwrapped longitude
    assert out[0, 0] == pytest.approx(175.0 + 0.4 * (-175.0 - 175.0))
    assert out[1, 0] == pytest.approx(175.0 + 0.6 * (-175.0 - 175.0))
    part = img[:9, :18]  # lon -180..0, lat 0..90
    with pytest.raises(SwimInputError, match="outside the image"):
        regrid_image_to_scene(part, np.array([45.0]), np.array([30.0]), bounds=(-180.0, 0.0, 0.0, 90.0))
    with pytest.raises(SwimInputError, match="bounds"):
        regrid_image_to_scene(img, np.array([0.0]), np.array([0.0]), bounds=(10.0, -10.0, -90.0, 90.0))
    with pytest.raises(SwimInputError, match="method"):
        regrid_image_to_scene(img, np.array([0.0]), np.array([0.0]), method="cubic")


def test_image_file_to_scene_albedo(tmp_path):
    from PIL import Image

    rgb = np.zeros((90, 180, 3), dtype=np.uint8)
    rgb[:, :90] = (255, 255, 255)  # western hemisphere white
    rgb[:, 90:] = (0, 0, 0)  # eastern black
    path = tmp_path / "earth.png"
    Image.fromarray(rgb).save(path)
    np.testing.assert_array_equal(load_image(path), rgb)
    lat = np.array([[40.0, 40.0]])
    lon = np.array([[-100.0, 100.0]])
    a = spectral_albedo_from_image(path, lat, lon, scale=0.9)
    assert a.shape == (3, 1, 2)
    np.testing.assert_allclose(a[:, 0, 0], 0.9)
    np.testing.assert_allclose(a[:, 0, 1], 0.0)
    with pytest.raises(SwimInputError, match="not found"):
        load_image(tmp_path / "missing.png")
    assert WAVELENGTHS_NM.tolist() == [615.0, 546.0, 450.0]


def test_scene_albedo_from_image_and_cli(tmp_path):
    """A user's RGB image replaces the scene albedo (library and `swim render --albedo-image`)."""
    from PIL import Image
    from typer.testing import CliRunner

    from swim.cli.main import app
    from swim.io.scene import scene_from_arrays
    from swim.surface.albedo import scene_with_albedo_from_image, spectral_albedo_from_rgb

    rgb = np.zeros((90, 180, 3), dtype=np.uint8)
    rgb[:, :] = (120, 160, 60)  # uniform green
    path = tmp_path / "earth.png"
    Image.fromarray(rgb).save(path)
    x = np.linspace(-20e3, 20e3, 5)
    scene = scene_from_arrays(x=x, y=x, z=np.linspace(100.0, 5000.0, 6), reference_lat=40.0, reference_lon=-105.0,
                              land_mask=1.0)
    out = scene_with_albedo_from_image(scene, path, scale=0.5)
    expected = spectral_albedo_from_rgb(np.array([120, 160, 60]) / 255.0, scale=0.5)
    np.testing.assert_allclose(out["surface_albedo"].values, np.broadcast_to(expected[:, None, None], (3, 5, 5)),
                               rtol=1e-6)
    assert out["surface_albedo"].values[1, 0, 0] > out["surface_albedo"].values[0, 0, 0]  # green > red
    result = CliRunner().invoke(app, ["render", "--albedo-image", str(path), "--albedo-image-bounds", "0,1,0,1",
                                      "--out", str(tmp_path / "x.png")])
    assert result.exit_code == 2 and "albedo" in result.output.lower()
    assert not (tmp_path / "x.png").exists()
