"""The device sampler (swim.rt.image_sampling_device) against the host's (swim.rt.image_sampling): the same traced
pixels and the same image, on analytic images of several shapes and settings and on a rendered scene."""

import numpy as np
import pytest

from swim.errors import SwimInputError
from swim.rt.image_sampling import AdaptiveSampling, sample_image_adaptive
from swim.rt.image_sampling_device import bucket_size, quadtree_levels, sample_image_adaptive_device


#: The device sampler runs the JAX kernel, whose programs compile for minutes on an empty cache: the full tier.
pytestmark = pytest.mark.full

@pytest.fixture(autouse=True)
def _no_exports(monkeypatch, request):
    """The device sampler's programs jitted as usual in these tests: exporting each image shape's programs (what a
    render does once, for later processes) would cost the suite ~1.5x their tracing; one test exports them."""
    if "exports" not in request.node.name:
        monkeypatch.setenv("SWIM_JAX_EXPORT", "0")


def analytic_image(shape, seed=0):
    """Outputs of every pixel of a (ny, nx) image: smooth gradients, sharp-edged "clouds" whose radiance and optical
    depth jump, air in front of them, the ground below a skyline, integer step counts; pixels outside a disk invalid."""
    ny, nx = shape
    y, x = np.mgrid[0:ny, 0:nx].astype(float)
    rng = np.random.default_rng(seed)
    cloud = np.sin(x / 6.3 + rng.uniform(0, 6)) * np.cos(y / 8.1) > 0.45
    radiance = np.stack([0.3 + 0.002 * x + 0.4 * cloud, 0.35 + 0.001 * y + 0.45 * cloud,
                         0.5 + 0.3 * cloud + 0.1 * np.sin(x * y / 400.0)], -1).astype(np.float32)
    tau = (25.0 * cloud * (1.0 + np.sin(x / 4.0))).astype(np.float32)
    clear = (0.2 * radiance + (0.01 * cloud * (x > nx / 2))[..., None]).astype(np.float32)
    surface = y > 0.8 * ny + 3 * np.sin(x / 5.0)
    valid = (y - (ny - 1) / 2) ** 2 + (x - (nx - 1) / 2) ** 2 <= (0.52 * max(ny, nx)) ** 2
    steps = (7 + x + 2 * y).astype(np.int32)
    full = {"radiance": radiance.reshape(-1, 3), "tau_hydrometeor": tau.reshape(-1),
            "radiance_clear": clear.reshape(-1, 3), "surface": surface.reshape(-1), "steps": steps.reshape(-1)}
    return full, valid


def lookup(full, calls=None):
    def trace(flat):
        if calls is not None:
            calls.append(np.array(flat))
        return {key: value[flat] for key, value in full.items()}

    return trace


def test_a_batch_s_padding_rows_are_not_used():
    """The repeats that fill a batch up to its bucket may come back as anything (the pipeline marches them as rays
    that start stopped): the image and the traced pixels are those of a trace that returns the repeated pixel's
    values."""
    full, valid = analytic_image((64, 64), seed=3)
    sampling = AdaptiveSampling()

    def padding_garbage(flat):
        own = int(np.argmax(flat == flat[-1])) + 1  # the batch's own pixels; then its last one repeated
        out = {key: value[flat].copy() for key, value in full.items()}
        if own < flat.size:
            out["radiance"][own:] = 1e30
            out["tau_hydrometeor"][own:] = np.nan
            out["surface"][own:] = ~out["surface"][own:]
        return out

    expected, expected_traced = sample_image_adaptive_device(lookup(full), valid, sampling, outside=np.nan, chunk=1024)
    calls = []
    values, traced = sample_image_adaptive_device(lambda p: calls.append(p) or padding_garbage(p), valid, sampling,
                                                  outside=np.nan, chunk=1024)
    assert any(int(np.argmax(p == p[-1])) + 1 < p.size for p in calls), "some batch must be padded"
    np.testing.assert_array_equal(np.asarray(traced), np.asarray(expected_traced))
    for key, value in expected.items():
        np.testing.assert_array_equal(np.asarray(values[key]), np.asarray(value), err_msg=key)


def assert_same_sampling(full, valid, sampling, chunk=None):
    host_values, host_traced = sample_image_adaptive(lookup(full), valid, sampling, outside=np.nan)
    device_values, device_traced = sample_image_adaptive_device(lookup(full), valid, sampling, outside=np.nan,
                                                                chunk=chunk)
    np.testing.assert_array_equal(np.asarray(device_traced), host_traced)
    assert set(device_values) == set(host_values)
    for key, host in host_values.items():
        host = host.reshape(host.shape[0], -1)
        device = np.asarray(device_values[key])
        assert device.shape == host.shape and device.dtype == host.dtype, key
        if host.dtype.kind == "f":
            np.testing.assert_array_equal(np.isnan(device), np.isnan(host))
            # the interpolation's weights rounded in float32 where the host rounds them once from float64
            np.testing.assert_allclose(device, host, rtol=2e-6, atol=1e-7, equal_nan=True, err_msg=key)
        else:
            np.testing.assert_array_equal(device, host, err_msg=key)
    return host_traced


# each image shape and sampling compiles the device sampler's programs anew (seconds on 2 cores): four pairs
@pytest.mark.parametrize("shape, sampling", [
    ((130, 101), AdaptiveSampling()),
    ((41, 41), AdaptiveSampling(coarse_spacing=4, edge_test_size=0)),
    ((64, 97), AdaptiveSampling(coarse_spacing=16, edge_test_size=8, clear_tolerance=0.0)),
    ((64, 97), AdaptiveSampling(coarse_spacing=5, tolerance=0.05))],
    ids=["130x101-defaults", "41x41-spacing4-centres", "64x97-spacing16-no-clear", "64x97-spacing5-loose"])
def test_the_device_sampler_traces_the_host_samplers_pixels_and_gives_its_image(shape, sampling):
    full, valid = analytic_image(shape)
    traced = assert_same_sampling(full, valid, sampling)
    # the test is not vacuous: the image has smooth cells that are interpolated and features that are refined
    assert 0.1 * valid.sum() < traced.sum() < 0.9 * valid.sum()


def test_a_rendered_scene_is_sampled_alike():
    """Real input: every pixel of the built-in scene's all-sky image traced by swim.render, then both samplers."""
    import swim
    from swim.io.default_scene import default_scene

    kept = {}

    def keep(trace, valid, sampling, *args, **kwargs):
        values, traced = sample_image_adaptive(trace, valid, sampling, *args, **kwargs)
        kept.update(valid=valid.copy(), **{key: np.array(values[key]) for key in
                                           ("radiance", "radiance_clear", "tau_hydrometeor", "surface", "steps")})
        return values, traced

    original = swim.rt.backends.host.sample_image_adaptive
    swim.rt.backends.host.sample_image_adaptive = keep
    try:
        swim.render(default_scene(), sampling=AdaptiveSampling(coarse_spacing=10**6), camera_options={"size": 97})
    finally:
        swim.rt.backends.host.sample_image_adaptive = original
    valid = kept.pop("valid")
    assert np.isfinite(kept["radiance"][valid.reshape(-1)]).all()
    traced = assert_same_sampling(kept, valid, AdaptiveSampling())
    assert traced.sum() < valid.sum()


@pytest.mark.parametrize("shape, sampling", [
    ((33, 33), AdaptiveSampling(coarse_spacing=16, edge_test_size=8)),
    ((40, 53), AdaptiveSampling(coarse_spacing=16, edge_test_size=8, tolerance=0.05)),
    ((37, 29), AdaptiveSampling(coarse_spacing=8, edge_test_size=2))], ids=["33x33-16-8", "40x53-16-8", "37x29-8-2"])
def test_a_smooth_cell_s_quarters_are_not_quartered_again(shape, sampling):
    """A smooth image whose first level's cells are smooth and test their edges, with quarters big enough to test
    theirs too: the quarters are interpolated from the cell's traced corners, edge midpoints and centre, not quartered
    again at points that no level traced (a review found NaN, the outside value, in every untraced pixel)."""
    ny, nx = shape
    y, x = np.mgrid[0:ny, 0:nx].astype(float)
    v = (1 + 0.001 * x + 0.002 * y + 0.0005 * np.sin(x * y / 50.0)).astype(np.float32)
    full = {"radiance": np.stack([v, 0.9 * v, 0.8 * v], -1).reshape(-1, 3), "tau_hydrometeor": v.reshape(-1),
            "surface": np.ones(v.size, bool), "steps": np.ones(v.size, np.int32)}
    valid = np.ones(shape, bool)
    traced = assert_same_sampling(full, valid, sampling)
    assert traced.sum() < 0.5 * valid.sum(), "the image must be mostly interpolated"
    values, _ = sample_image_adaptive_device(lookup(full), valid, sampling, outside=np.nan)
    assert np.isfinite(np.asarray(values["radiance"])).all() and np.asarray(values["surface"]).all()


def test_batches_are_padded_to_the_marchs_buckets_with_the_last_pixel():
    full, valid = analytic_image((90, 90))
    calls = []
    sample_image_adaptive_device(lookup(full, calls), valid, AdaptiveSampling(), chunk=1024)
    assert len(calls) >= 3
    for pixels in calls:
        real = np.flatnonzero(np.diff(pixels) > 0).size + 1  # increasing, then the last one repeated
        assert np.all(np.diff(pixels[:real]) > 0) and np.all(pixels[real:] == pixels[real - 1])
        assert pixels.size == bucket_size(real, 1024)
        assert valid.reshape(-1)[pixels].all()


def test_progress_counts_each_batch_s_new_pixels_without_asking_the_device():
    """After each batch: the pixels traced so far (each batch's are new), ending at the traced mask's count, as the
    host counts them (the device's count would wait for the batch's march)."""
    full, valid = analytic_image((90, 90))
    calls, reports = [], []
    _, traced = sample_image_adaptive_device(lookup(full, calls), valid, AdaptiveSampling(), chunk=1024,
                                             progress=lambda done, total: reports.append((done, total)))
    assert len(reports) == len(calls) >= 3
    real = [np.unique(pixels).size for pixels in calls]  # each batch's distinct pixels (its padding repeats one)
    assert [done for done, _ in reports] == list(np.cumsum(real))
    assert reports[-1][0] == int(np.asarray(traced).sum()) and {t for _, t in reports} == {int(valid.sum())}


@pytest.mark.parametrize("m, chunk, expected", [(1, 1024, 256), (300, 1024, 512), (1024, 1024, 1024),
                                                (1025, 1024, 1024 + 256), (5000, 1024, 4 * 1024 + 1024)])
def test_bucket_size_is_the_marchs_padding(m, chunk, expected):
    assert bucket_size(m, chunk) == expected
    assert bucket_size(m, chunk) >= m


@pytest.mark.parametrize("shape, spacing", [((64, 64), 8), ((41, 97), 8), ((30, 33), 4), ((9, 9), 2)])
def test_quadtree_levels_split_every_interval_at_its_middle_down_to_single_pixels(shape, spacing):
    levels = quadtree_levels(*shape, spacing)
    first = levels[0]
    assert first.ys[0] == 0 and first.ys[-1] == shape[0] - 1 and np.all(np.diff(first.ys) <= spacing)
    for before, level in zip(levels[:-1], levels[1:]):
        for bounds_before, bounds, parents in ((before.ys, level.ys, level.parent_rows),
                                               (before.xs, level.xs, level.parent_cols)):
            assert set(bounds_before) <= set(bounds)
            for a, (lo, hi) in enumerate(zip(bounds[:-1], bounds[1:])):
                p = parents[a]
                assert bounds_before[p] <= lo < hi <= bounds_before[p + 1]
            # an interval of two or more pixels splits at (lo + hi) // 2, one of a pixel stays
            for lo, hi in zip(bounds_before[:-1], bounds_before[1:]):
                inside = bounds[(bounds > lo) & (bounds < hi)]
                assert list(inside) == ([(lo + hi) // 2] if hi - lo >= 2 else [])
    assert np.diff(levels[-1].ys).max() == 1 and np.diff(levels[-1].xs).max() == 1


def test_without_valid_pixels_nothing_is_traced_and_the_outputs_keep_the_outside_value():
    full, _ = analytic_image((20, 20))
    values, traced = sample_image_adaptive_device(lookup(full), np.zeros((20, 20), bool), outside=np.nan)
    assert not np.asarray(traced).any()
    assert np.isnan(np.asarray(values["radiance"])).all() and not np.asarray(values["surface"]).any()


def test_valid_pixels_off_the_first_lattice_are_found_by_splitting():
    """No valid pixel in the first batch: every cell splits, as in the host's sampler, until the valid ones are
    traced."""
    full, _ = analytic_image((20, 20))
    valid = np.zeros((20, 20), bool)
    valid[1:3, 1:3] = True
    traced = assert_same_sampling(full, valid, AdaptiveSampling())
    np.testing.assert_array_equal(traced, valid)


def test_a_tested_pixel_at_its_tolerance_decides_as_on_the_host():
    """The tests in float64, as the host's: a centre within a float32 rounding of the tolerance refines there and
    here (in float32 the device called this cell smooth)."""
    full, _ = analytic_image((20, 20))
    valid = np.ones((20, 20), bool)
    radiance = np.full((400, 3), np.float32(1.4620143), np.float32)
    radiance[4 * 20 + 4] = np.float32(1.4746488)  # the centre of the cell (0..8, 0..8)
    full = {**full, "radiance": radiance, "radiance_clear": np.zeros_like(radiance),
            "tau_hydrometeor": np.zeros(400, np.float32), "surface": np.zeros(400, bool)}
    sampling = AdaptiveSampling(edge_test_size=0)
    traced = assert_same_sampling(full, valid, sampling)
    assert traced[4, 4] and traced.sum() > 25


def test_a_spacing_beyond_the_image_traces_every_valid_pixel():
    full, valid = analytic_image((12, 15))
    values, traced = sample_image_adaptive_device(lookup(full), valid, AdaptiveSampling(coarse_spacing=64))
    np.testing.assert_array_equal(np.asarray(traced), valid)
    np.testing.assert_array_equal(np.asarray(values["radiance"])[valid.reshape(-1)],
                                  full["radiance"][valid.reshape(-1)])


def test_bad_input_is_named():
    full, valid = analytic_image((20, 20))
    with pytest.raises(SwimInputError, match="valid"):
        sample_image_adaptive_device(lookup(full), valid.astype(int))
    with pytest.raises(SwimInputError, match="tau_hydrometeor"):
        sample_image_adaptive_device(lambda p: {"radiance": full["radiance"][p], "surface": full["surface"][p]}, valid)
    with pytest.raises(SwimInputError, match="rows"):
        sample_image_adaptive_device(lambda p: {key: value[p[:-1]] for key, value in full.items()}, valid)


def test_a_render_with_device_sampling_gives_the_host_samplers_image():
    """swim.render with the JAX kernel and the camera's rays on the device: MarchSettings.device_sampling traces the
    same pixels and gives the same image as the host's sampler, and the sun's disk takes the same direct
    transmittance."""
    import swim
    from swim.rt import ray_table
    from swim.rt.march_settings import ExecutionSettings, MarchSettings

    scene = swim.default_scene()
    ray_table.forget_ray_tables()
    try:
        for sun_zenith in (70.0,):
            images = [swim.render(scene, camera="allsky", camera_options={"size": 64}, sun_zenith=sun_zenith,
                                  sun_azimuth=120.0, sampling=AdaptiveSampling(),
                                  settings=MarchSettings(cloud_scattering="albers2020",
                                                         execution=ExecutionSettings(backend="jax", chunk=1024,
                                                                                     ray_table=True, device_sampling=on_device)))  # its device path
                      for on_device in (False, True)]
            host, device = images
            # (at 64 pixels across the scene's cumulus leave few cells smooth: the test is that some are)
            assert device.attrs["traced_pixels"] == host.attrs["traced_pixels"] < int(
                np.isfinite(host["view_zenith"].values).sum())
            assert device.attrs["march_samples"] == host.attrs["march_samples"]
            np.testing.assert_allclose(device.attrs["direct_transmittance"], host.attrs["direct_transmittance"],
                                       rtol=1e-6)
            for key in ("radiance", "radiance_clear", "radiance_cloud", "radiance_surface", "tau_hydrometeor"):
                x, y = host[key].values, device[key].values
                np.testing.assert_array_equal(np.isnan(x), np.isnan(y), err_msg=key)
                np.testing.assert_allclose(y, x, rtol=2e-5, atol=1e-7, equal_nan=True, err_msg=key)
            assert np.abs(device["rgb"].values.astype(int) - host["rgb"].values.astype(int)).max() <= 1
            assert all(device[key].values.flags.writeable for key in device.data_vars)
    finally:
        ray_table.forget_ray_tables()


def test_device_sampling_is_not_a_kernel_setting():
    """The switch is the sampler's, not the kernel's: a compiled kernel serves either value."""
    from swim.rt.march_settings import ExecutionSettings, MarchSettings

    on = MarchSettings(execution=ExecutionSettings(device_sampling=True))
    assert on.kernel_settings() == MarchSettings().kernel_settings()
    with pytest.raises(SwimInputError, match="device_sampling"):
        MarchSettings(execution=ExecutionSettings(device_sampling="yes"))


def test_a_new_process_reads_the_exported_programs_and_samples_alike(tmp_path, monkeypatch):
    """The level programs kept on disk (swim.compilation.jax_export): a new process (the programs forgotten) reads them
    instead of tracing them, and samples as before. (Its name holds "exports": the fixture above leaves them on.)"""
    pytest.importorskip("flatbuffers")
    from swim.rt import image_sampling_device as device

    monkeypatch.setenv("SWIM_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("SWIM_JAX_CACHE", raising=False)
    monkeypatch.delenv("SWIM_JAX_EXPORT", raising=False)
    programs = (device._first_wanted, device._test_level, device._wanted_after_split, device._fill, device._scatter)
    for program in programs:
        program.forget_programs()
    full, valid = analytic_image((37, 45), seed=3)
    first_values, first_traced = sample_image_adaptive_device(lookup(full), valid)
    assert all(program.exported >= 1 and program.loaded == 0 for program in programs)
    for program in programs:
        program.forget_programs()
    values, traced = sample_image_adaptive_device(lookup(full), valid)
    assert all(program.loaded >= 1 and program.exported == 0 for program in programs)
    np.testing.assert_array_equal(np.asarray(traced), np.asarray(first_traced))
    for key, value in first_values.items():
        np.testing.assert_array_equal(np.asarray(values[key]), np.asarray(value), err_msg=key)


def test_a_cell_that_tested_its_edges_is_interpolated_by_its_quarters_as_on_the_host():
    """The smooth cells that tested their edges are interpolated from their traced centre and edge midpoints too
    (each quarter from its four traced corners, :func:`swim.rt.image_sampling.quarters_of_edged_cells`): a field that
    is bilinear on each quarter of each 8 x 8 cell, but not on the cell, comes out exact, on the device as on the
    host."""
    shape = (33, 41)
    y, x = np.mgrid[0:shape[0], 0:shape[1]].astype(float)

    def tent(t):
        return 1.0 - np.abs(np.mod(t, 8) - 4) / 4

    value = 1.0 + 0.004 * tent(y) * tent(x)  # the centres 0.4 % above their corners: within the tolerance
    full = {"radiance": np.stack([value, 0.8 * value, 0.6 * value], -1).reshape(-1, 3).astype(np.float32),
            "tau_hydrometeor": (3.0 * value).reshape(-1).astype(np.float32),
            "surface": np.zeros(value.size, bool), "steps": np.ones(value.size, np.int32)}
    valid = np.ones(shape, bool)
    traced = assert_same_sampling(full, valid, AdaptiveSampling())
    assert traced.sum() < 0.2 * traced.size  # the cells were smooth
    device_values, _ = sample_image_adaptive_device(lookup(full), valid, AdaptiveSampling())
    got = np.asarray(device_values["radiance"]).reshape(*shape, 3)[:, :33]  # the whole 8 x 8 cells
    np.testing.assert_allclose(got, full["radiance"].reshape(*shape, 3)[:, :33], rtol=1e-6)
