"""The render's aerosol argument: a type name, an AerosolType (a model aerosol's effective type) or an
AerosolBackground, with or without a 3-D aerosol field in the scene."""

from __future__ import annotations

import pytest

from swim.errors import SwimInputError
from swim.optics.aerosol_types import aerosol_type, custom_aerosol_type
from swim.io import default_scene
from swim.pipeline import render
from swim.pipeline.arguments import background_aerosol
from swim.rt.gas import AerosolBackground


def test_aerosol_type_keeps_the_default_profile_without_a_scene_field():
    t = custom_aerosol_type("smoke", ssa=0.9, g=0.6)
    got = background_aerosol(t, {"height"})
    assert got.optics is t and got.aod_550 == AerosolBackground().aod_550


def test_aerosol_type_applies_to_the_scene_field_alone():
    t = aerosol_type("sea_salt")
    got = background_aerosol(t, {"height", "aerosol_extinction"})
    assert got.optics is t and got.aod_550 == 0.0


def test_other_aerosol_arguments_are_refused_by_name():
    with pytest.raises(SwimInputError, match="aerosol must be None.*AerosolType"):
        render(default_scene(), aerosol=0.3, camera_options={"size": 9})


def test_a_scene_of_smoke_alone_renders_with_the_smoke_type():
    got = background_aerosol(None, {"height", "smoke_mass_content"})
    assert got.type_name == "smoke" and got.aod_550 == 0.0
    mixed = background_aerosol(None, {"height", "smoke_mass_content", "aerosol_extinction"})
    assert mixed.type_name == AerosolBackground().type_name and mixed.aod_550 == 0.0
