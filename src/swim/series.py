"""Many frames: a time series, several sites or a fly-through, rendered in this process or on a dask.distributed
cluster, each frame written to its own file as it is done.

:func:`render_series` takes one scene (or a scene per frame: hourly model output) and a list of frames, each a set of
:func:`swim.render` arguments (a time, a vantage point, a camera). In this process the frames run one after the other
and share the optical volume of their scene (:mod:`swim.pipeline`'s stage cache). With a ``dask.distributed`` client
(or ``workers=N``, a local cluster of N processes) each frame is a task: an in-memory scene is sent to every worker
once, a scene file is opened by each worker once, and each worker writes its own frames. Each file is written whole
or not at all (:func:`swim.io.atomic.atomic_write`). Throughput on this project's 2-core machine: docs/rendering.md,
"Many frames".
"""

from __future__ import annotations

import functools
import logging
import numbers
import os
import socket
import threading
import time as wall_clock
from pathlib import Path

import pandas as pd
import xarray as xr

from .errors import SwimInputError

log = logging.getLogger(__name__)

#: Columns of :func:`render_series`'s table, in order.
COLUMNS = ("time", "png", "netcdf", "sun_zenith_deg", "sun_azimuth_deg", "traced_pixels", "seconds", "worker")


def series_times(start, end, every_minutes: float) -> pd.DatetimeIndex:
    """UTC instants from ``start`` to ``end`` (both included where ``end`` falls on the step) every ``every_minutes``.

    Parameters
    ----------
    start, end : str, datetime or pandas.Timestamp
        First and last instant (UTC; a time zone is converted).
    every_minutes : float
        Step [min] > 0.

    Returns
    -------
    pandas.DatetimeIndex
        Timezone-naive UTC instants.

    Raises
    ------
    SwimInputError
        If a time cannot be parsed, ``end`` is before ``start`` or the step is not > 0.
    """
    try:
        first, last = (_utc(t) for t in (start, end))
    except (TypeError, ValueError) as err:
        raise SwimInputError(f"series start and end must be ISO 8601 UTC times; got {start!r}, {end!r} ({err})") from None
    if (isinstance(every_minutes, bool) or not isinstance(every_minutes, numbers.Real)
            or not 0 < every_minutes < float("inf")):
        raise SwimInputError(f"series step every_minutes must be a number of minutes > 0; got {every_minutes!r}")
    if last < first:
        raise SwimInputError(f"series end {last} UTC is before its start {first} UTC")
    return pd.date_range(first, last, freq=pd.Timedelta(minutes=every_minutes))


def _utc(value) -> pd.Timestamp:
    stamp = pd.Timestamp(value)
    if stamp is pd.NaT:
        raise ValueError("not a time")
    return stamp.tz_convert("UTC").tz_localize(None) if stamp.tzinfo is not None else stamp


def _frame_list(frames) -> list[dict]:
    """Frames as dicts of :func:`swim.render` arguments (plus "scene"); bare times become ``{"time": t}``."""
    if isinstance(frames, (str, bytes, dict)) or not hasattr(frames, "__iter__"):
        raise SwimInputError("frames must be a sequence of times or of dicts of swim.render arguments")
    out = []
    for i, frame in enumerate(frames):
        if isinstance(frame, dict):
            out.append(dict(frame))
        elif isinstance(frame, (numbers.Number, bool)):  # pandas would read a number as nanoseconds since 1970
            raise SwimInputError(f"frame {i}: {frame!r} is neither a time nor a dict of swim.render arguments")
        else:
            try:
                out.append({"time": _utc(frame)})
            except (TypeError, ValueError):
                raise SwimInputError(f"frame {i}: {frame!r} is neither a time nor a dict of swim.render arguments") \
                    from None
    if not out:
        raise SwimInputError("frames is empty: nothing to render")
    return out


def _output_paths(pattern, frames, what) -> list[Path | None]:
    """``pattern`` formatted for each frame (its arguments merged with the common ones) with ``index``, ``time`` (a
    pandas.Timestamp: ``{time:%Y%m%dT%H%M}``), ``lat``, ``lon`` and ``height``; distinct paths or a clear error."""
    if pattern is None:
        return [None] * len(frames)
    pattern = str(pattern)
    paths = []
    for i, frame in enumerate(frames):
        fields = {"index": i, "lat": frame.get("lat"), "lon": frame.get("lon"), "height": frame.get("height"),
                  "time": frame.get("time")}  # a pandas.Timestamp or None (_frame_list)
        try:
            # absolute: a worker of a cluster writes relative to its own folder otherwise
            paths.append(Path(pattern.format(**fields)).absolute())
        except (KeyError, IndexError, ValueError, TypeError, AttributeError) as err:
            raise SwimInputError(f"{what} pattern {pattern!r} cannot name frame {i} ({err!r}); it may use {{index}}, "
                                 "{time:%Y%m%dT%H%M} (frames with a time), {lat}, {lon} and {height}") from None
    seen = {}
    for i, path in enumerate(paths):
        if path in seen:
            raise SwimInputError(f"{what} pattern {pattern!r} names frames {seen[path]} and {i} alike ({path}); "
                                 "add {index} or {time:%Y%m%dT%H%M%S}")
        seen[path] = i
    # every frame's file checked before the first frame is rendered: its format and its folder
    from .io.atomic import check_output_path
    from .pipeline import image_format

    for path in paths:
        if what == "out":
            image_format(path, what)
        check_output_path(path, what)
    return paths


#: One opening of a scene file at a time in a process (:func:`_opened`).
_OPEN_LOCK = threading.Lock()


def _opened(path: str, opening: tuple):
    """A scene file opened once per process and version of the file (a worker's frames share it and its optical
    volume; a file rewritten under the same name, such as an hourly "latest" forecast, is opened again)."""
    try:
        stat = os.stat(path)
    except OSError:
        raise SwimInputError(f"scene file not found: {path}") from None
    # One thread at a time: a worker's threads (dask's threads_per_worker) would otherwise all miss the cache and
    # open the file at once, and netCDF-C/HDF5 calls from two threads crashed the process (a segmentation fault in
    # 2 of 8 runs of tests/system/test_series.py's cluster test) or failed with "NetCDF: HDF error"
    with _OPEN_LOCK:
        return _opened_version(path, opening, stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=2)
def _opened_version(path: str, opening: tuple, mtime_ns: int, size: int):
    return _open(path, opening)


def _open(path: str, opening: tuple):
    """:func:`swim.open_scene` with ``opening`` = (lazy, the reader's options as sorted (name, value) pairs)."""
    from .io.scene import open_scene

    lazy, options = opening
    return open_scene(path, lazy=lazy, **dict(options))


def _render_frame(index, scene, opening, kwargs, png, netcdf):
    """One frame, in this process or on a dask worker: render, write, and return its row of the table."""
    from .pipeline import render, write_outputs

    started = wall_clock.perf_counter()
    if isinstance(scene, (str, os.PathLike)):
        scene = _opened(str(scene), opening)
    image = render(scene, **kwargs)
    write_outputs(image, png, netcdf)
    attrs = image.attrs
    return {"index": index, "time": _utc(attrs["time"]) if attrs.get("time") else pd.NaT,
            "png": None if png is None else str(png), "netcdf": None if netcdf is None else str(netcdf),
            "sun_zenith_deg": float(attrs["sun_zenith_deg"]), "sun_azimuth_deg": float(attrs["sun_azimuth_deg"]),
            "traced_pixels": int(attrs.get("traced_pixels", -1)), "seconds": wall_clock.perf_counter() - started,
            "worker": f"{socket.gethostname()}:{os.getpid()}"}


def _frame_error(index, frame, err) -> SwimInputError:
    when = f" at {_utc(frame['time'])} UTC" if frame.get("time") is not None else ""
    return SwimInputError(f"frame {index}{when}: {err}")


def render_series(scene, frames, *, out=None, netcdf=None, client=None, workers: int | None = None, lazy: bool = False,
                  open_options: dict | None = None, progress=None, **render_kwargs) -> pd.DataFrame:
    """Render many frames of one scene (or of a scene per frame) and write each to its own file.

    Parameters
    ----------
    scene : xarray.Dataset, str or os.PathLike
        The canonical scene of every frame, or a scene file (:func:`swim.open_scene`; opened once per process). A
        frame's own ``"scene"`` replaces it (e.g. one WRF file per hour).
    frames : sequence
        Times (str, datetime or pandas.Timestamp, UTC; e.g. :func:`series_times`) or dicts of :func:`swim.render`
        arguments (``time``, ``lat``, ``lon``, ``height``, ``camera_options``, ...; and ``"scene"``), one per frame.
        A dict's arguments override ``render_kwargs``.
    out : str or os.PathLike, optional
        PNG path pattern (made absolute against this process's folder), formatted per frame with ``index`` (0, 1, ...), ``time`` (a pandas.Timestamp, UTC: e.g.
        ``"frames/{time:%Y%m%dT%H%M}.png"``), ``lat``, ``lon`` and ``height`` (the frame's arguments or the common
        ones; None where neither gives one). Folders are created.
    netcdf : str or os.PathLike, optional
        The same for CF netCDF files of the radiance (:func:`swim.write_netcdf`).
    client : dask.distributed.Client, optional
        Render the frames as tasks on this cluster (each worker writes its own files, so the paths must be on a
        file system that the workers share with the caller).
    workers : int, optional
        Without ``client``: start a local dask cluster of this many single-threaded worker processes for the
        series, each marching on ``cores // workers`` threads (``SWIM_NUM_THREADS``). None or 0: in this process.
        dask starts the workers by spawning fresh interpreters, so a script that uses it needs the usual
        ``if __name__ == "__main__":`` guard.
    lazy : bool
        Open scene files lazily (canonical netCDF only; :func:`swim.open_scene`).
    open_options : dict, optional
        The reader's options for scene files (:func:`swim.open_scene`'s keywords, e.g. ``{"time": "2005-08-28T18:00"}``
        for a WRF file of several times, ``reference_lat``/``reference_lon`` for an LES file); hashable values.
    progress : callable, optional
        Called with (frames done, frames total) after each frame.
    **render_kwargs
        :func:`swim.render` arguments common to every frame (``camera``, ``camera_options``, ``aerosol``,
        ``settings``, ``sampling``, ``white_level``, ...).

    Returns
    -------
    pandas.DataFrame
        One row per frame, indexed by frame number, with :data:`COLUMNS`: its ``time`` (UTC), ``png`` and
        ``netcdf`` paths, the sun's zenith and azimuth [deg], the pixels traced, the frame's wall time
        ``seconds`` [s] and the ``worker`` (host:pid) that rendered it.

    Raises
    ------
    SwimInputError
        Before any frame: no frames, a frame that is neither a time nor a dict or whose time is not one, no output
        pattern, output patterns that name two frames alike or use a field a frame lacks, ``out`` and ``netcdf``
        naming one file, ``workers`` < 0, both ``client`` and ``workers``, or dask.distributed missing for
        ``workers``. During the series: the
        first frame that fails, by number and time. The frames written before it are complete files; on a cluster
        the frames not yet started are cancelled, and those already running may still write theirs.
    """
    frames = _frame_list(frames)
    if out is None and netcdf is None:
        raise SwimInputError("render_series needs out (a PNG path pattern) or netcdf: the frames would be lost")
    merged = [{**render_kwargs, **frame} for frame in frames]
    for i, frame in enumerate(merged):  # a frame's own time or the common one: UTC, for the file names and the table
        if frame.get("time") is not None:
            try:
                frame["time"] = _utc(frame["time"])
            except (TypeError, ValueError):
                raise SwimInputError(f"frame {i}: time {frame['time']!r} is not an ISO 8601 UTC time") from None
    pngs = _output_paths(out, merged, "out")
    ncs = _output_paths(netcdf, merged, "netcdf")
    both = set(pngs) & set(ncs) - {None}
    if both:
        raise SwimInputError(f"out and netcdf name the same file {sorted(both)[0]}")
    if scene is None and any("scene" not in f for f in frames):
        raise SwimInputError("render_series: no scene for the frames without their own 'scene'")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 0):
        raise SwimInputError(f"workers must be a number of processes >= 0; got {workers!r}")
    if workers and client is not None:
        raise SwimInputError("give either client (a running cluster) or workers (a local one), not both")
    try:
        opening = (bool(lazy), tuple(sorted((open_options or {}).items())))
        hash(opening)
    except (AttributeError, TypeError):
        raise SwimInputError(f"open_options must be a dict of swim.open_scene keywords with plain values; got "
                             f"{open_options!r}") from None
    jobs = []
    for i, frame in enumerate(merged):
        kwargs = {k: v for k, v in frame.items() if k not in ("scene", "open_options")}
        given = frame.get("scene", scene)
        if isinstance(given, (str, os.PathLike)):
            given = Path(given).absolute()  # as the output paths: the same file on every worker
        elif not isinstance(given, xr.Dataset):
            raise SwimInputError(f"frame {i}: the scene must be an xarray.Dataset or a scene file path; got "
                                 f"{type(given).__name__}")
        own = frame.get("open_options")  # a frame's own reader options (its model time), over the common ones
        frame_opening = opening if own is None else (opening[0], tuple(sorted({**dict(opening[1]), **own}.items())))
        jobs.append((i, given, kwargs, pngs[i], ncs[i], frame_opening))
    if client is None and workers:
        return _on_local_cluster(jobs, merged, workers, progress)
    if client is None:
        return _in_this_process(jobs, merged, progress)
    return _on_cluster(client, jobs, merged, progress)


def scene_file_times(path) -> list[pd.Timestamp]:
    """The model times (UTC) a scene file holds: a WRF file's (``Times``/``XTIME``), a canonical scene's or a WPS
    file's ``time``; empty for a file without one (an LES file, a geogrid file), whose fields have no time."""
    from .io.files import open_netcdf
    from .io.scene import _LES_SUFFIXES, _is_wrf
    from .io.wrf import wrf_times

    p = Path(path)
    if p.suffix.lower() in _LES_SUFFIXES:
        return []
    with open_netcdf(p, "scene file") as ds:
        if _is_wrf(ds):
            return [pd.Timestamp(t) for t in (wrf_times(ds) or [])]
        if "time" in ds.variables:
            return [pd.Timestamp(t) for t in pd.to_datetime(ds["time"].values.ravel())]
    return []


def model_time_frames(path, times, open_options=None, freeze_fields=False) -> list[dict]:
    """The frames of a series of ``times`` from a scene file of one or more model times: each frame rendered from the
    file's time nearest to it (a frame's own ``open_options``), which must lie within the readers' tolerance of 90 min
    (:data:`swim.io.wrf.TIME_TOLERANCE`), as for a single render.

    Parameters
    ----------
    path : str or os.PathLike
        The scene file (:func:`swim.open_scene`).
    times : sequence
        The frames' times (UTC; e.g. :func:`series_times`).
    open_options : dict, optional
        The reader's other options (``time`` is set per frame).
    freeze_fields : bool
        Render every frame from the model time nearest to the first frame, however far the others lie from it
        (clouds frozen while the sun moves).

    Returns
    -------
    list of dict
        ``{"time": t, "scene": path, "open_options": {..., "time": model time}}`` per frame; without model times in the
        file (LES), ``{"time": t, "scene": path}``.

    Raises
    ------
    SwimInputError
        If a frame lies more than 90 min from every model time of the file (and ``freeze_fields`` is False).
    """
    from .io.wrf import TIME_TOLERANCE

    stamps = [_utc(t) for t in times]
    model = sorted(scene_file_times(path))
    base = dict(open_options or {})
    base.pop("time", None)
    if not model:
        return [{"time": t, "scene": str(path), **({"open_options": base} if base else {})} for t in stamps]
    nearest = [min(model, key=lambda m, t=t: abs(m - t)) for t in stamps]
    if freeze_fields:
        nearest = [nearest[0]] * len(stamps)
    else:
        for i, (t, m) in enumerate(zip(stamps, nearest)):
            if abs(m - t) > TIME_TOLERANCE:
                raise SwimInputError(
                    f"frame {i} at {t:%Y-%m-%d %H:%M} UTC is {abs(m - t)} from the nearest model time of {Path(path).name} "
                    f"(it holds {model[0]:%Y-%m-%d %H:%M} to {model[-1]:%Y-%m-%d %H:%M} UTC); a frame may be 90 min "
                    f"from one (--freeze-fields renders every frame from one model time)")
    return [{"time": t, "scene": str(path), "open_options": {**base, "time": m.isoformat()}}
            for t, m in zip(stamps, nearest)]


def _table(rows) -> pd.DataFrame:
    return pd.DataFrame(rows).set_index("index").sort_index().loc[:, list(COLUMNS)]


def _in_this_process(jobs, frames, progress):
    rows = []
    opened = (None, None)  # the last scene file (and options) and its scene: held for the series only, not after it
    for i, given, kwargs, png, nc, opening in jobs:
        try:
            if isinstance(given, (str, os.PathLike)):
                if opened[0] != (str(given), opening):
                    opened = (None, None)  # the previous scene goes before the next is read
                    opened = ((str(given), opening), _open(str(given), opening))
                given = opened[1]
            rows.append(_render_frame(i, given, opening, kwargs, png, nc))
        except SwimInputError as err:
            raise _frame_error(i, frames[i], err) from None
        log.info("frame %d of %d in %.2f s", i + 1, len(jobs), rows[-1]["seconds"])
        if progress is not None:
            progress(len(rows), len(jobs))
    return _table(rows)


def _on_cluster(client, jobs, frames, progress):
    from dask.distributed import as_completed

    remote = {}  # in-memory scenes, sent to every worker once each
    futures = {}
    rows = []
    try:
        for i, given, kwargs, png, nc, opening in jobs:
            if isinstance(given, xr.Dataset):
                if id(given) not in remote:
                    remote[id(given)] = client.scatter(given, broadcast=True)
                given = remote[id(given)]
            else:
                given = str(given)
            futures[client.submit(_render_frame, i, given, opening, kwargs, png, nc, pure=False)] = i
        for future in as_completed(futures):
            i = futures[future]
            try:
                rows.append(future.result())
            except SwimInputError as err:
                raise _frame_error(i, frames[i], err) from None
            log.info("frame %d done on %s (%d of %d)", i, rows[-1]["worker"], len(rows), len(jobs))
            if progress is not None:
                progress(len(rows), len(jobs))
    finally:
        if len(rows) < len(jobs):
            client.cancel(list(futures))
        client.cancel(list(remote.values()))  # the scattered scenes
        if any(isinstance(job[1], Path) for job in jobs):
            try:  # the workers' open scene files, which a long-lived cluster would otherwise keep
                client.run(_forget_scenes)
            except Exception as err:  # only memory is at stake
                log.info("the workers kept their open scene files (%s)", err)
    return _table(rows)


def _forget_scenes():
    _opened_version.cache_clear()


def local_cluster(workers: int):
    """A local dask.distributed cluster of ``workers`` single-threaded worker processes, each marching on
    ``cores // workers`` threads (``SWIM_NUM_THREADS``), so that the frames do not oversubscribe the cores.

    Raises
    ------
    SwimInputError
        If dask.distributed is not installed (``pip install "swim-imagery[scale]"``).
    """
    try:
        from dask.distributed import LocalCluster
    except ImportError:
        raise SwimInputError('workers= needs dask.distributed: pip install "swim-imagery[scale]"') from None
    from .workers import threads

    per_worker = max(1, threads() // workers)
    return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, memory_limit=0,
                        dashboard_address=None, env={"SWIM_NUM_THREADS": str(per_worker)})


def _on_local_cluster(jobs, frames, workers, progress):
    from dask.distributed import Client

    with local_cluster(workers) as cluster, Client(cluster) as client:
        return _on_cluster(client, jobs, frames, progress)
