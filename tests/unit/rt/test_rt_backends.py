"""The march's one entry point, swim.rt.backends.march(rays, tables, settings): the registry of backends, its image
against the chunk dispatcher's rays, and the pipeline's calls into the march."""

import ast
from pathlib import Path

import numpy as np
import pytest

import swim
from swim.rt import backends
from swim.rt.march import trace_rays
from swim.rt.march_settings import ExecutionSettings, MarchSettings

PAPER = dict(cloud_scattering="albers2020")


def _captured_call(monkeypatch, **kw):
    """The (rays, tables, settings) of a small render of the built-in scene, and the render's image."""
    calls = []
    march = backends.march

    def capture(rays, tables, settings, **options):
        calls.append((rays, tables, settings))
        return march(rays, tables, settings, **options)

    monkeypatch.setattr(swim.pipeline.chain, "march", capture)
    image = swim.render(swim.default_scene(), camera_options={"size": 21}, sun_zenith=35.0, sun_azimuth=140.0, **kw)
    (call,) = calls
    return call, image


def test_every_backend_has_a_module_and_the_resolved_backend_picks_it():
    assert set(backends.BACKEND_MODULES) == {"numba", "jax"}
    assert MarchSettings(execution=ExecutionSettings(backend="numba")).resolved().execution.backend == "numba"


def test_the_host_backend_scatters_what_the_dispatcher_marches(monkeypatch):
    (rays, tables, settings), image = _captured_call(
        monkeypatch, settings=MarchSettings(**PAPER, execution=ExecutionSettings(backend="numba")))
    assert settings.execution.backend == "numba" and isinstance(rays, backends.CameraRays)
    marched = backends.march(rays, tables, settings)
    dirs = rays.directions[rays.valid_pixels]
    direct = trace_rays(np.broadcast_to(rays.observer, dirs.shape), dirs, tables.constants, tables.geometry,
                        tables.phase, settings)
    radiance = marched.planes["radiance"].reshape(3, -1)
    np.testing.assert_array_equal(radiance[:, rays.valid_pixels], direct["radiance"].T)
    assert np.isnan(radiance[:, ~rays.valid.reshape(-1)]).all()
    assert marched.traced.sum() == rays.valid.sum() and marched.samples == int(direct["steps"].sum())
    assert marched.rgb is None and {"tau_clear", "surface", "steps"} <= set(marched.sun)
    # the render's radiance is the march's, but at the few pixels of the sun's disk, which it adds
    rendered = image["radiance"].values.reshape(3, -1)
    changed = np.any(rendered[:, rays.valid_pixels] != radiance[:, rays.valid_pixels], axis=0)
    assert 1 <= np.count_nonzero(changed) <= 9
    assert np.all(rendered[:, rays.valid_pixels][:, changed] > radiance[:, rays.valid_pixels][:, changed])


@pytest.mark.full  # the JAX kernel's programs compile for tens of seconds on an empty cache: the full tier
def test_the_jax_backend_without_a_ray_table_marches_on_the_host(monkeypatch):
    (rays, tables, settings), _ = _captured_call(
        monkeypatch, settings=MarchSettings(**PAPER, execution=ExecutionSettings(backend="jax", ray_table=False)))
    assert settings.execution.backend == "jax" and settings.execution.ray_table is False
    jax_image = backends.march(rays, tables, settings)
    numba_image = backends.march(rays, tables, settings.with_execution(backend="numba"))
    np.testing.assert_allclose(jax_image.planes["radiance"], numba_image.planes["radiance"], rtol=2e-3, atol=1e-5)


def test_the_pipeline_calls_no_kernel_but_through_march():
    """swim.pipeline imports from swim.rt.backends (the march) and from no kernel or dispatcher module."""
    pipeline = Path(swim.pipeline.__file__).parent
    kernels = {"swim.rt.march", "swim.rt.march_cpu", "swim.rt.march_jax", "swim.rt.march_pallas", "swim.rt.ray_table",
               "swim.rt.backends.host", "swim.rt.backends.device", "swim.rt.image_sampling_device"}
    imported = set()
    for path in pipeline.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level:
                package = "swim." if node.level == 2 else "swim.pipeline."
                imported.add(package + (node.module or ""))
    assert "swim.rt.backends" in imported and not imported & kernels, imported & kernels
