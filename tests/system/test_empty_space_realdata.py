"""Empty-space skipping on real broken cloud: the RICO cumulus LES, where most rays of an all-sky view see no cloud."""

import numpy as np

from swim import MarchSettings, read_shdom_les, render


def test_empty_steps_keep_the_rico_all_sky_as_accurate(shared_data):
    """Against a fine march (1024 grid steps, no limit on the empty ones), the default limit of 32 steps in empty
    space (docs/decisions/0004-step-placement.md) must leave the error of the default march where it was, although most
    rays now take a quarter of the grid steps."""
    scene = read_shdom_les(shared_data / "les" / "rico122x106x39.txt")
    view = {"sun_zenith": 30.0, "sun_azimuth": 135.0, "height": 2.0, "camera_options": {"size": 63}}
    fine = render(scene, settings=MarchSettings(n_grid=1024, n_after=96, n_before=48, empty_steps=0), **view)
    images = {empty: render(scene, settings=MarchSettings(empty_steps=empty), **view) for empty in (0, None)}
    ref = fine["radiance"].values
    ok = np.isfinite(ref) & (ref > 0)
    errors = {empty: np.abs(image["radiance"].values[ok] / ref[ok] - 1) for empty, image in images.items()}
    clear_rays = np.mean(fine["tau_hydrometeor"].values[np.isfinite(fine["tau_hydrometeor"].values)] == 0)
    assert clear_rays > 0.5, "most rays of this view must cross clear air only"
    for q in (50, 99):
        assert np.percentile(errors[None], q) <= np.percentile(errors[0], q) * 1.1 + 2e-4, q
    assert np.percentile(errors[None], 99) < 0.01
    changed = ~np.isclose(images[None]["radiance"].values[ok], images[0]["radiance"].values[ok], rtol=1e-6)
    assert changed.mean() > 0.2, "the limit must reach the rays through clear air"
