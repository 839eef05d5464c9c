"""Datasets from the xarray ecosystem accepted directly: unit-aware (pint) values, as pint-xarray's and MetPy's
``quantify()`` make them (both hold pint quantities), and WRF output post-processed by xwrf. Each is compared with the
plain reading of the same real file."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import xarray as xr

from swim.errors import SwimInputError
from swim.io import read_wrf, validate_scene
from swim.io.quantities import dequantified, has_quantities
from swim.io.scene import as_scene, scene_from_arrays
from swim.io.wrf_postprocessed import is_xwrf_dataset, raw_wrf_layout

pytest.importorskip("pint_xarray")  # registers the .pint accessor
TIME = "2005-08-28T18:00"


@pytest.fixture(scope="module")
def katrina(shared_data):
    path = shared_data / "wrf_katrina" / "ci_test_file.nc"
    with xr.open_dataset(path) as ds:
        yield ds.load()


@pytest.fixture(scope="module")
def katrina_scene(katrina):
    return read_wrf(katrina, time=TIME)


def _quantified(ds, names):
    """``ds`` with ``names`` as pint quantities in their canonical units (pint spells them its own way)."""
    from swim.io.quantities import PINT_SPELLING

    units = {n: PINT_SPELLING.get(ds[n].attrs["units"], ds[n].attrs["units"]) for n in names}
    plain = ds.copy()
    for n in plain.variables:
        plain[n].attrs.pop("units", None)
    return plain.pint.quantify(units)


def _small_scene():
    z = np.array([500.0, 1500.0, 2500.0])
    x = y = np.array([-1000.0, 0.0, 1000.0])
    lwc = np.zeros((3, 3, 3))
    lwc[1, 1, 1] = 4e-4
    return scene_from_arrays(x=x, y=y, z=z, reference_lat=40.0, reference_lon=-105.0, cloud_liquid_content=lwc)


def test_plain_dataset_is_returned_as_it_is():
    scene = _small_scene()
    assert dequantified(scene) is scene
    assert as_scene(scene) is scene


def test_quantified_scene_in_other_units_is_converted_to_si():
    scene = _small_scene()
    q = _quantified(scene, ["cloud_liquid_content", "height", "lat"])
    assert has_quantities(q)
    q["cloud_liquid_content"] = q["cloud_liquid_content"].pint.to("g / m**3")  # 0.4 g m-3
    q["height"] = q["height"].pint.to("km")
    out = validate_scene(q)
    assert not has_quantities(out)
    assert out["cloud_liquid_content"].attrs["units"] == "kg m-3"
    np.testing.assert_allclose(out["cloud_liquid_content"].values, scene["cloud_liquid_content"].values, rtol=1e-12)
    np.testing.assert_allclose(out["height"].values, scene["height"].values, rtol=1e-12)


def test_quantity_of_the_wrong_dimension_is_refused_by_name():
    q = _quantified(_small_scene(), ["cloud_liquid_content", "height"])
    q["cloud_liquid_content"] = q["cloud_liquid_content"] * q["height"]
    with pytest.raises(SwimInputError, match="cloud_liquid_content.*expected kg m-3"):
        validate_scene(q)


def test_quantified_wrf_reads_like_the_file(katrina, katrina_scene):
    q = _quantified(katrina, ["P", "PB", "PH", "PHB", "T", "QCLOUD", "QVAPOR", "HGT"])
    q["P"] = q["P"].pint.to("hPa")  # perturbation pressure in hPa: converted back, not misread
    out = read_wrf(q, time=TIME)
    for name in katrina_scene.data_vars:
        np.testing.assert_allclose(out[name].values, katrina_scene[name].values, rtol=1e-6, atol=1e-15)  # float32 hPa


def test_xwrf_postprocessed_wrf_reads_like_the_file(katrina, katrina_scene):
    xwrf = pytest.importorskip("xwrf")  # noqa: F841 (registers the accessor)
    one_time = katrina.sel(Time=[2]).xwrf.postprocess()  # 18 UTC; xwrf keeps one XLAT/XLONG per file
    assert is_xwrf_dataset(one_time) and not is_xwrf_dataset(katrina)
    out = as_scene(one_time, TIME)
    np.testing.assert_array_equal(out["lat"].values, katrina_scene["lat"].values)
    np.testing.assert_allclose(out["height"].values, katrina_scene["height"].values, atol=1e-3)  # float32 sums
    for name in ("cloud_liquid_content", "rain_content", "snow_content", "cloud_ice_content"):
        np.testing.assert_allclose(out[name].values, katrina_scene[name].values, rtol=1e-5, atol=1e-12)


def test_xwrf_moving_nest_warns(katrina, caplog):
    pytest.importorskip("xwrf")
    with caplog.at_level(logging.WARNING, logger="swim.io.wrf_postprocessed"):
        raw_wrf_layout(katrina.xwrf.postprocess())
    assert "moving nest" in caplog.text


def test_xwrf_without_potential_temperature_is_refused(katrina):
    pytest.importorskip("xwrf")
    ds = katrina.sel(Time=[2]).xwrf.postprocess().drop_vars("air_potential_temperature")
    with pytest.raises(SwimInputError, match="air_potential_temperature"):
        read_wrf(ds)
