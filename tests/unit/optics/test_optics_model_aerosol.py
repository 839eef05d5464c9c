"""swim.optics.model_aerosol: CAMS/IFS species and WRF-Chem/HRRR smoke to extinction, ω, g and one aerosol type."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from swim.errors import SwimInputError
from swim.io.scene import scene_from_arrays
from swim.optics.model_aerosol import (
    CAMS_SPECIES_12,
    IFS_AEROSOL_TYPE_MAP_49R1,
    SMOKE_MASS_EXTINCTION_EFFICIENCY,
    IfsAerosolOpticsTable,
    add_smoke_aerosol,
    cams_aerosol_optics,
    cams_scene_aerosol,
    effective_aerosol_type,
    read_ifs_aerosol_optics,
    relative_humidity_liquid,
    scene_with_aerosol_extinction,
    smoke_extinction,
    wrf_chem_smoke_mass_content,
)

RH_LOWER = np.array([0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.95])


def _toy_table():
    """One hydrophilic species whose mass extinction is 1000 (k + 1) m2 kg-1 in RH bin k, and two hydrophobic
    ones (ω 0.5, g 0.5 and ω 1, g 0.9), spectrally flat."""
    n = RH_LOWER.size
    philic_ke = (1000.0 * (np.arange(n) + 1.0))[None, :, None].repeat(4, axis=-1)
    return IfsAerosolOpticsTable(
        wavelength_nm=np.array([615.0, 546.0, 450.0, 550.0]), rh_lower=RH_LOWER,
        philic_mass_ext=philic_ke, philic_ssa=np.full((1, n, 4), 0.9), philic_g=np.full((1, n, 4), 0.7),
        phobic_mass_ext=np.array([[2000.0] * 4, [6000.0] * 4]), phobic_ssa=np.array([[0.5] * 4, [1.0] * 4]),
        phobic_g=np.array([[0.5] * 4, [0.9] * 4]), philic_codes=("SU",), phobic_codes=("BC", "DD"), source="toy")


@pytest.fixture(scope="module")
def ifs_table(shared_data):
    return read_ifs_aerosol_optics(shared_data / "ecrad" / "aerosol_ifs_49R1.nc")


# ------------------------------------------------------------------------------------------------------------
# the IFS table
# ------------------------------------------------------------------------------------------------------------
def test_table_matches_the_file_at_its_nearest_wavelength(ifs_table, shared_data):
    """550 nm lies 0.15 % in wavelength from the table's 550.8 nm: the interpolated values must be within 1 % of the
    file's there, and between its 526.1 and 550.8 nm values."""
    with xr.open_dataset(shared_data / "ecrad" / "aerosol_ifs_49R1.nc") as ds:
        lam = ds["wavelength"].values * 1e9
        j = int(np.argmin(np.abs(lam - 550.0)))
        phobic = ds["mass_ext_hydrophobic"].values[:, j]
        philic = ds["mass_ext_hydrophilic"].values[:, :, j]
        g_philic = ds["asymmetry_hydrophilic"].values[:, :, j]
    np.testing.assert_allclose(ifs_table.phobic_mass_ext[:, 3], phobic, rtol=0.01)
    np.testing.assert_allclose(ifs_table.philic_mass_ext[:, :, 3], philic, rtol=0.01)
    np.testing.assert_allclose(ifs_table.philic_g[:, :, 3], g_philic, atol=0.005)
    assert ifs_table.phobic_codes[:3] == ("DD", "DD", "DD") and ifs_table.philic_codes[4] == "SU"


def test_table_physics_against_literature(ifs_table):
    """Published orders of magnitude: black carbon k_e ≈ 9-13 m2 g-1 and ω ≈ 0.2-0.3 at 550 nm (Bond and
    Bergstrom 2006, doi:10.1080/02786820500421521: MAC 7.5 m2 g-1); sulfate's extinction grows 2.5-4x from dry
    to RH 90 % (Kotchenruther et al. 1999, doi:10.1029/1998JD100105; Bozzo et al. 2020, Fig. 2); coarse dust
    and sea salt extinguish less per mass and are spectrally flatter than the fine species."""
    bc = ifs_table.phobic_mass_ext[10, 3]  # Black carbon, OPAC (type map entry 11)
    assert 8e3 < bc < 14e3 and 0.15 < ifs_table.phobic_ssa[10, 3] < 0.35
    su = ifs_table.philic_mass_ext[4, :, 3]  # ammonium sulfate
    assert 2.5 < su[10] / su[0] < 4.5
    assert np.all(np.diff(su) >= 0)
    dust3 = ifs_table.phobic_mass_ext[8]  # dust bin 3, 0.9-20 µm
    assert dust3[3] < 0.5e3
    alpha = lambda ke: np.log(ke[2] / ke[0]) / np.log(615.0 / 450.0)  # noqa: E731
    assert abs(alpha(dust3)) < 0.3 and alpha(ifs_table.philic_mass_ext[4, 0]) > 1.0


def test_missing_table_raises(tmp_path):
    with pytest.raises(SwimInputError, match="not found"):
        read_ifs_aerosol_optics(tmp_path / "none.nc")


# ------------------------------------------------------------------------------------------------------------
# mixing and RH
# ------------------------------------------------------------------------------------------------------------
def test_rh_bins_follow_ecrad():
    """ecRad takes the bin whose lower bound is the largest one below RH: 0.85 is still the 0.80-0.85 bin."""
    t = _toy_table()
    for rh, k in [(0.0, 0), (0.05, 0), (0.1, 0), (0.1001, 1), (0.849, 8), (0.85, 8), (0.851, 9), (0.99, 11),
                  (1.2, 11)]:
        out = cams_aerosol_optics([[1e-9]], [rh], 1.0, t, type_map=(-1,))
        np.testing.assert_allclose(out["extinction"][0, 3], 1e-9 * 1000.0 * (k + 1), rtol=1e-12, err_msg=str(rh))


def test_rh_linear_between_bin_centres():
    t = _toy_table()
    out = cams_aerosol_optics([[1e-9, 1e-9]], [0.1, 0.875], 1.0, t, type_map=(-1,), rh_interpolation="linear")
    # 0.1 is halfway between the centres 0.05 (bin 0) and 0.15 (bin 1); 0.875 is the centre of bin 9
    np.testing.assert_allclose(out["extinction"][:, 3], [1.5e-6, 10e-6], rtol=1e-9)
    with pytest.raises(SwimInputError, match="rh_interpolation"):
        cams_aerosol_optics([[1e-9]], [0.5], 1.0, t, type_map=(-1,), rh_interpolation="cubic")


def test_external_mixture_rules():
    """β = ρ Σ q k_e; ω extinction-weighted; g scattering-weighted (by hand for two hydrophobic species)."""
    t = _toy_table()
    mmr = np.array([[1e-8], [1e-8]])  # 1e-8 kg/kg each
    out = cams_aerosol_optics(mmr, 0.5, 1.2, t, type_map=(1, 2))
    b1, b2 = 1.2e-8 * 2000.0, 1.2e-8 * 6000.0
    np.testing.assert_allclose(out["extinction"][0], b1 + b2)
    np.testing.assert_allclose(out["ssa"][0], (0.5 * b1 + b2) / (b1 + b2))
    np.testing.assert_allclose(out["g"][0], (0.5 * b1 * 0.5 + b2 * 0.9) / (0.5 * b1 + b2))
    # no aerosol: finite ω and g
    empty = cams_aerosol_optics(np.zeros((2, 1)), 0.5, 1.2, t, type_map=(1, 2))
    assert np.all(empty["extinction"] == 0) and np.all(np.isfinite(empty["ssa"]))


def test_species_axis_and_bad_input():
    t = _toy_table()
    mmr = np.zeros((5, 2, 7))  # (column, species, level) like ecRad
    mmr[:, 1] = 1e-9
    out = cams_aerosol_optics(mmr, np.full((5, 7), 0.3), np.ones((5, 7)), t, type_map=(1, 2), species_axis=1,
                              return_species=True)
    assert out["extinction"].shape == (5, 7, 4) and out["species_extinction"].shape == (2, 5, 7, 4)
    with pytest.raises(SwimInputError, match="species"):
        cams_aerosol_optics(mmr, 0.3, 1.0, t, type_map=(1, 2, 1), species_axis=1)
    with pytest.raises(SwimInputError, match="mmr"):
        cams_aerosol_optics(-mmr - 1e-9, 0.3, 1.0, t, type_map=(1, 2), species_axis=1)
    with pytest.raises(SwimInputError, match="air_density"):
        cams_aerosol_optics(mmr, 0.3, 0.0, t, type_map=(1, 2), species_axis=1)
    with pytest.raises(SwimInputError, match="hydrophobic"):
        cams_aerosol_optics(mmr, 0.3, 1.0, t, type_map=(1, 3), species_axis=1)


def test_cams_type_map_is_ecrad_49r1():
    """ecRad test/ifs/configCY49R1.nam: i_aerosol_type_map = -1,-2,-3,7,8,9,-4,10,11,11,-5,14."""
    assert IFS_AEROSOL_TYPE_MAP_49R1 == (-1, -2, -3, 7, 8, 9, -4, 10, 11, 11, -5, 14)
    assert len(CAMS_SPECIES_12) == 12


def test_relative_humidity_against_tabulated_saturation():
    """At 20 °C, e_s = 2339 Pa (WMO-No. 8, Annex 4.B); q for e = e_s / 2 at 1000 hPa must give RH 0.5."""
    e = 0.5 * 2339.0
    q = 0.622 * e / (1e5 - 0.378 * e)
    np.testing.assert_allclose(relative_humidity_liquid(q, 293.15, 1e5), 0.5, rtol=0.003)
    assert relative_humidity_liquid(0.05, 293.15, 1e5) == 1.0  # supersaturated: clipped
    with pytest.raises(SwimInputError):
        relative_humidity_liquid(-1e-3, 293.15, 1e5)


def test_cams_columns_aod_in_climatological_range(ifs_table, shared_data):
    """The 32 IFS columns of ecrad_meridian.nc: AOD 550 nm 0.05-0.4 everywhere (CAMS / MODIS January climatology
    along 135° E), the largest in the subtropics, and Ångström exponents 0.3-1.5 (maritime to mixed)."""
    from swim.io.grib import moist_air_density

    with xr.open_dataset(shared_data / "ecrad" / "ecrad_meridian.nc") as ds:
        ph, th, q, mmr = (ds[v].values for v in ("pressure_hl", "temperature_hl", "q", "aerosol_mmr"))
        lat = ds["lat"].values
    p, t = 0.5 * (ph[:, 1:] + ph[:, :-1]), 0.5 * (th[:, 1:] + th[:, :-1])
    rh = relative_humidity_liquid(q, t, p)
    rho = moist_air_density(p, t, rh)
    out = cams_aerosol_optics(mmr, rh, rho, ifs_table, species_axis=1)
    dz = np.diff(ph, axis=1) / (9.80665 * rho)
    aod = (out["extinction"] * dz[..., None]).sum(axis=1)
    assert np.all((aod[:, 3] > 0.05) & (aod[:, 3] < 0.4))
    assert abs(lat[np.argmax(aod[:, 3])]) < 40.0
    alpha = np.log(aod[:, 2] / aod[:, 0]) / np.log(615.0 / 450.0)
    assert np.all((alpha > 0.3) & (alpha < 1.5))
    assert np.all((out["ssa"] > 0.5) & (out["ssa"] <= 1.0)) and np.all((out["g"] > 0.4) & (out["g"] < 0.9))


# ------------------------------------------------------------------------------------------------------------
# one type per scene
# ------------------------------------------------------------------------------------------------------------
def test_effective_type_weights_and_angstrom():
    beta550 = np.array([1e-4, 3e-4])
    spectral = (np.array([615.0, 546.0, 450.0, 550.0]) / 550.0) ** -1.5
    beta = beta550[:, None] * spectral[None, :]
    ssa = np.array([[0.8] * 4, [1.0] * 4])
    g = np.array([[0.6] * 4, [0.8] * 4])
    t = effective_aerosol_type(beta, ssa, g, weights=[2.0, 1.0])
    w = np.array([2e-4, 3e-4])  # β w at 550
    np.testing.assert_allclose(t.ssa, (w * [0.8, 1.0]).sum() / w.sum())
    np.testing.assert_allclose(t.asymmetry_parameter(), (w * [0.8, 1.0] * [0.6, 0.8]).sum() / (w * [0.8, 1.0]).sum())
    np.testing.assert_allclose(t.angstrom_exponent, 1.5, atol=1e-9)
    np.testing.assert_allclose(t.extinction_factor(450.0), (450.0 / 550.0) ** -1.5)
    with pytest.raises(SwimInputError, match="no aerosol"):
        effective_aerosol_type(np.zeros((2, 4)), ssa, g)


def _scene(nz=4):
    x = np.linspace(-1000.0, 1000.0, 3)
    z = np.linspace(100.0, 1600.0, nz)
    return scene_from_arrays(x=x, y=x, z=z, reference_lat=40.0, reference_lon=-105.0,
                             cloud_liquid_content=np.zeros((nz, 3, 3)))


def test_cams_scene_aerosol_puts_extinction_and_type():
    t = _toy_table()
    scene = _scene()
    mmr = np.zeros((2, 4, 3, 3))
    mmr[1] = 1e-8
    out, typ = cams_scene_aerosol(scene, mmr, 0.5, 1.0, t, type_map=(1, 2))
    np.testing.assert_allclose(out["aerosol_extinction"].values, 6000.0 * 1e-8)
    np.testing.assert_allclose(typ.ssa, 1.0)
    np.testing.assert_allclose(typ.asymmetry_parameter(), 0.9)
    assert "aerosol_extinction" not in scene  # the input is not modified


def test_scene_with_aerosol_extinction_checks():
    scene = _scene()
    with pytest.raises(SwimInputError, match="shape"):
        scene_with_aerosol_extinction(scene, np.zeros((3, 3, 3)))
    with pytest.raises(SwimInputError, match="0.05"):
        scene_with_aerosol_extinction(scene, np.full((4, 3, 3), 0.1))  # km-1 given as m-1


# ------------------------------------------------------------------------------------------------------------
# smoke
# ------------------------------------------------------------------------------------------------------------
def test_smoke_extinction_against_observed_pm25_aod():
    """A 1.5 km mixed layer of 100 µg m-3 of smoke PM2.5 has an AOD at 550 nm of about 0.5-0.8 (AERONET
    and surface PM2.5 during western-US fires; Reid et al. 2005: 3.5-5 m2 g-1)."""
    aod = smoke_extinction(100e-9) * 1500.0
    assert 0.5 < aod < 0.8
    assert SMOKE_MASS_EXTINCTION_EFFICIENCY == pytest.approx(4.5e3)
    with pytest.raises(SwimInputError):
        smoke_extinction(-1e-9)
    with pytest.raises(SwimInputError, match="mass_extinction_efficiency"):
        smoke_extinction(1e-9, mass_extinction_efficiency=4.5)  # m2 g-1 given as m2 kg-1


def test_wrf_chem_units():
    np.testing.assert_allclose(wrf_chem_smoke_mass_content(50.0, "ug kg-1", air_density=1.2), 60e-9)
    np.testing.assert_allclose(wrf_chem_smoke_mass_content(50.0, "ug m-3"), 50e-9)
    with pytest.raises(SwimInputError, match="air_density"):
        wrf_chem_smoke_mass_content(50.0, "ug kg-1")
    with pytest.raises(SwimInputError, match="units"):
        wrf_chem_smoke_mass_content(50.0, "ppb")


def test_add_smoke_aerosol_adds_to_existing_field():
    scene = _scene()
    scene = scene_with_aerosol_extinction(scene, np.full((4, 3, 3), 1e-5))
    scene["smoke_mass_content"] = (("z", "y", "x"), np.full((4, 3, 3), 20e-9), {"units": "kg m-3"})
    out, typ = add_smoke_aerosol(scene)
    np.testing.assert_allclose(out["aerosol_extinction"].values, 1e-5 + 4.5e3 * 20e-9)
    assert typ.name == "smoke"
    assert "smoke_mass_content" not in out  # else the optical volume would add its extinction a second time
    with pytest.raises(SwimInputError, match="smoke_mass_content"):
        add_smoke_aerosol(_scene())
