"""``swim compare``: score a simulated image against a real camera image (docs/comparison.md).

A thin layer over :func:`swim.diagnostics.compare.compare_images` and
:func:`swim.diagnostics.cloud_mask.compare_cloud_masks`. Register it on the main Typer app with
``app.command()(compare)``.
"""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from ..errors import SwimInputError

__all__ = ["compare", "FitKind", "QuantityKind", "WeightingKind", "CloudMethod"]


class FitKind(str, Enum):
    none = "none"
    gain = "gain"
    gain_offset = "gain_offset"


class QuantityKind(str, Enum):
    linear_rgb = "linear_rgb"
    srgb = "srgb"
    radiance = "radiance"


class WeightingKind(str, Enum):
    solid_angle = "solid_angle"
    pixel = "pixel"


class CloudMethod(str, Enum):
    ratio = "ratio"
    difference = "difference"


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.4f}"


def compare(
    simulated: Path = typer.Argument(..., help="Simulated image: netCDF written by 'swim render --netcdf'."),
    camera_image: Path = typer.Argument(..., help="Camera image (JPEG/PNG)."),
    camera_model: Path = typer.Option(..., "--camera-model", help="Camera model TOML (docs/comparison.md)."),
    sun_exclusion: float = typer.Option(5.0, "--sun-exclusion", help="Exclude pixels within this angle of the sun "
                                        "in deg (paper: 5; Table 4: 12)."),
    fit: FitKind = typer.Option(FitKind.none, "--fit", help="Brightness fit of the simulation onto the camera per "
                                "channel (RMSE/bias after it; r is unaffected)."),
    min_elevation: float = typer.Option(0.0, "--min-elevation", help="Exclude pixels below this elevation in deg."),
    quantity: QuantityKind = typer.Option(QuantityKind.linear_rgb, "--quantity", help="What is compared: "
                                          "linearised RGB, display-encoded sRGB, or simulated radiance vs "
                                          "linearised camera RGB."),
    weighting: WeightingKind = typer.Option(WeightingKind.solid_angle, "--weighting", help="Pixel weights: solid "
                                            "angle, or equal (Eq. 37 literally)."),
    exclude_saturated: bool = typer.Option(False, "--exclude-saturated", help="Also exclude saturated camera "
                                           "pixels."),
    cloud_method: CloudMethod = typer.Option(CloudMethod.ratio, "--cloud-method", help="Cloud mask test: R/B "
                                             "ratio or B-R difference."),
    cloud_threshold: Optional[float] = typer.Option(None, "--cloud-threshold", help="Cloud mask threshold (default "
                                                    "0.8 for the ratio, 30 counts for the difference)."),
    sun_zenith: Optional[float] = typer.Option(None, "--sun-zenith", help="Override the sun zenith angle in deg "
                                               "(default: from the simulated image)."),
    sun_azimuth: Optional[float] = typer.Option(None, "--sun-azimuth", help="Override the sun azimuth in deg."),
    downsample: int = typer.Option(1, "--downsample", help="Compare on pixels N times larger (the camera image "
                                   "averaged over N x N blocks): a 2048^2 image by 4 in a sixteenth of the time."),
    diff: Optional[Path] = typer.Option(None, "--diff", help="Write a difference image (PNG) here."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Write the scores (JSON) here."),
):
    """Compare a simulated image with a camera image: Pearson r per channel and r-bar (Eq. 37), RMSE, cloud masks."""
    # xarray and the cloud masks load here, before modules_loaded(), though the helpers use them
    import xarray  # noqa: F401

    from ..diagnostics.cloud_mask import compare_cloud_masks  # noqa: F401
    from ..diagnostics.compare import (
        block_mean_codes,
        compare_images,
        read_camera_image,
        reproject,
        scores_dict,
        write_difference_png,
        write_json,
    )
    from ..geometry.fisheye import FisheyeCameraModel
    from .main import modules_loaded

    modules_loaded()
    err = Console(stderr=True)
    out = Console()
    try:
        if (sun_zenith is None) != (sun_azimuth is None):
            raise SwimInputError("give both --sun-zenith and --sun-azimuth [deg], or neither")
        model = FisheyeCameraModel.from_toml(Path(camera_model))
        sim = _read_simulated(simulated)
        obs = read_camera_image(camera_image, model)
        projected = reproject(sim, model.downsampled(downsample))
        result = compare_images(projected, obs, model, sun_azimuth_deg=sun_azimuth, sun_zenith_deg=sun_zenith,
                                sun_exclusion_deg=sun_exclusion, fit=fit.value, min_elevation_deg=min_elevation,
                                quantity=quantity.value, weighting=weighting.value,
                                exclude_saturated=exclude_saturated, downsample=downsample)
        obs = block_mean_codes(obs, downsample)
        mask = result["mask"].values
        weights = projected["solid_angle"].values if weighting is WeightingKind.solid_angle else None
        clouds = _cloud_scores(projected["rgb"].values, obs, mask, cloud_method, cloud_threshold, weights)
        scores = scores_dict(result)
        scores["clouds"] = clouds
        scores["simulated"] = str(simulated)
        scores["camera_image"] = str(camera_image)
        scores["camera_model"] = str(camera_model)
        if diff is not None:
            write_difference_png(result, diff)
        if json_out is not None:
            write_json(scores, json_out)
    except SwimInputError as exc:
        err.print(f"[red]error:[/red] {escape(str(exc))}", soft_wrap=True)  # one line, however long
        raise typer.Exit(code=2) from None
    _print_scores(out, scores, quantity, fit, weighting, sun_exclusion, min_elevation)
    written = [str(p) for p in (diff, json_out) if p is not None]
    if written:
        out.print("wrote " + " and ".join(written))


def _read_simulated(simulated):
    """The simulated image's netCDF file, loaded."""
    import xarray as xr

    try:
        with xr.open_dataset(simulated) as ds:
            return ds.load()
    except (OSError, ValueError) as exc:
        raise SwimInputError(f"simulated image {str(simulated)!r} cannot be read as netCDF: {exc}") from None


def _cloud_scores(simulated_rgb, obs, mask, cloud_method, cloud_threshold, weights):
    """The cloud masks' contingency table and scores (:func:`swim.diagnostics.cloud_mask.compare_cloud_masks`), NaN
    as None (JSON null)."""
    from ..diagnostics.cloud_mask import compare_cloud_masks

    clouds = compare_cloud_masks(simulated_rgb, obs, mask, method=cloud_method.value,
                                 threshold=cloud_threshold, weights=weights)
    scores = {
        "method": clouds["method"], "threshold": clouds["threshold"], **clouds["table"], **clouds["scores"],
        "simulated_cloud_fraction": clouds["simulated_cloud_fraction"],
        "observed_cloud_fraction": clouds["observed_cloud_fraction"],
    }
    return {k: (None if isinstance(v, float) and v != v else v) for k, v in scores.items()}


def _print_scores(out, scores, quantity, fit, weighting, sun_exclusion, min_elevation):
    """The scores per channel as a table, then r-bar and the cloud masks' scores."""
    table = Table(title=f"simulated vs camera ({quantity.value}, fit {fit.value}, {weighting.value} weights)")
    table.add_column("channel")
    for name in ("r", "gain", "offset", "rmse", "bias"):
        table.add_column(name, justify="right")
    for i, ch in enumerate(scores["channels"]):
        table.add_row(ch, *(_fmt(scores[name][i]) for name in ("r", "gain", "offset", "rmse", "bias")))
    table.add_row("mean", _fmt(scores["r_mean"]), "", "", "", "")
    out.print(table)
    c = scores["clouds"]
    out.print(f"r-bar = {_fmt(scores['r_mean'])} over {scores['n_pixels']} pixels "
              f"({scores['solid_angle_sr']:.3f} sr; sun exclusion {sun_exclusion:g} deg, min elevation "
              f"{min_elevation:g} deg)")
    out.print(f"cloud masks ({c['method']}, threshold {c['threshold']:g}): POD {_fmt(c['pod'])}, FAR {_fmt(c['far'])}, "
              f"CSI {_fmt(c['csi'])}, frequency bias {_fmt(c['frequency_bias'])}, accuracy {_fmt(c['accuracy'])}")
