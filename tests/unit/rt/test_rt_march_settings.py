"""MarchSettings (what the march computes) and ExecutionSettings (how and where it runs): the split, the deprecated
keywords and attributes of the old single object, the validation and the resolution for the hardware."""

import dataclasses
import pickle
import warnings

import pytest

import swim
from swim.errors import SwimInputError
from swim.pipeline import settings_attributes
from swim.rt.march_settings import EXECUTION_FIELDS, ExecutionSettings, MarchSettings


def test_execution_fields_are_not_march_settings_fields():
    physics = {field.name for field in dataclasses.fields(MarchSettings)}
    assert physics.isdisjoint(EXECUTION_FIELDS) and "execution" in physics
    assert set(EXECUTION_FIELDS) == {field.name for field in dataclasses.fields(ExecutionSettings)}
    assert swim.ExecutionSettings is ExecutionSettings


def test_old_keywords_still_work_with_a_deprecation_warning():
    with pytest.warns(DeprecationWarning, match="backend=, chunk="):
        settings = MarchSettings(n_grid=64, backend="numba", chunk=512)
    assert settings == MarchSettings(n_grid=64, execution=ExecutionSettings(backend="numba", chunk=512))
    with pytest.warns(DeprecationWarning, match="MarchSettings.chunk is deprecated"):
        assert settings.chunk == 512
    with pytest.warns(DeprecationWarning):
        moved = dataclasses.replace(settings, fused_fma=True)
    assert moved.execution.fused_fma and moved.execution.chunk == 512 and moved.n_grid == 64


def test_new_keywords_warn_nothing_and_survive_copies():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        settings = MarchSettings(tau_refine=0.5, execution=ExecutionSettings(backend="numba", chunk=256))
        assert settings.with_execution(chunk=128).execution.chunk == 128
        assert pickle.loads(pickle.dumps(settings)) == settings and hash(settings) == hash(dataclasses.replace(settings))
        with pytest.raises(AttributeError):
            settings.no_such_field  # noqa: B018


@pytest.mark.parametrize("kind, field, value, expected", [
    (ExecutionSettings, "backend", "cuda", "ExecutionSettings.backend must be one of"),
    (ExecutionSettings, "chunk", 0, "ExecutionSettings.chunk must be an integer >= 1"),
    (ExecutionSettings, "ray_table", "yes", "ExecutionSettings.ray_table must be True, False or None"),
    (ExecutionSettings, "fused_fma", 1, "ExecutionSettings.fused_fma must be True or False"),
    (ExecutionSettings, "fused_max_registers", 300, "fused_max_registers must be None or an integer in"),
    (MarchSettings, "n_grid", -1, "MarchSettings.n_grid must be an integer >= 0"),
    (MarchSettings, "stop_tau", 3.0, "MarchSettings.stop_tau must be 0 \\(off\\) or a finite optical depth >= 40"),
    (MarchSettings, "surface", "mirror", "MarchSettings.surface must be one of"),
    (MarchSettings, "execution", "numba", "MarchSettings.execution must be an ExecutionSettings"),
])
def test_bad_values_are_named(kind, field, value, expected):
    with pytest.raises(SwimInputError, match=expected):
        kind(**{field: value})


def test_resolved_settings_ask_the_hardware_once_and_keep_their_answers():
    resolved = MarchSettings().resolved()
    execution = resolved.execution
    assert execution.backend in ("numba", "jax") and isinstance(execution.chunk, int)
    assert all(isinstance(getattr(execution, name), bool)
               for name in ("ray_table", "step1a_on_device", "device_sampling", "device_image"))
    assert resolved.resolved() == resolved
    assert resolved.resolved_backend() == MarchSettings().resolved_backend()
    assert resolved.resolved_chunk() == MarchSettings().resolved_chunk()


def test_netcdf_attributes_keep_the_execution_fields_names():
    attrs = settings_attributes(MarchSettings(execution=ExecutionSettings(backend="numba", chunk=64)))
    assert attrs["settings_backend"] == "numba" and attrs["settings_chunk"] == 64
    assert attrs["settings_fused_fma"] == 0 and attrs["settings_n_grid"] == 128
    assert "settings_execution" not in attrs
