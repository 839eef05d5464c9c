"""The differentiable forward operator's cost: a gradient of an image misfit against a forward run and a render.

Usage::

    python benchmarks/bench_assimilation.py                                # both RICO scenes, all-sky 256, 3 repeats
    python benchmarks/bench_assimilation.py --scenes rico_small --size 64 --repeats 5
    python benchmarks/bench_assimilation.py --cases forward gradient --timeout 3600

For each scene, the RICO shallow-cumulus LES (``les/rico122x106x39.txt``, and ``les/rico32x37x26.txt`` as a
smaller second scene; read with :func:`swim.read_shdom_les` at 17.5 N 62 W), one view: an all-sky camera of
``--size`` pixels 2 m above the ground at the scene's reference point, the sun at 30 deg zenith and 120 deg azimuth,
float32, default settings. The cases:

======================  ==============================================================================================
case                    what is timed
======================  ==============================================================================================
``forward``             ``op(x)``: :class:`swim.assimilation.ForwardOperator`'s images of the reference state x
``gradient``            ``op.value_and_grad(loss, x)`` with ``loss = rmse(images, observed, op.masks)`` and the
                        observed images ``op(0.8 x)``, made (and compiled) before the first timed call
``render_numba``        ``swim.render`` of the same view and sun (``sun_zenith``, ``sun_azimuth``), default settings:
                        the numba kernel on the CPU
``render_jax``          the same render with ``MarchSettings().with_execution(backend="jax")``: the JAX forward render
``render_jax_operator`` the JAX render with the operator's own settings (no refinement, no stop in opaque cloud, the
                        paper's cloud composition, the lockstep kernel: ``swim.assimilation.setup.DIFFERENTIABLE``):
                        the images the operator makes, as a render makes them
======================  ==============================================================================================

Each case runs in a fresh process (JAX keeps its compiled programs and swim its stages in a process, so the first
call's time and the peak memory are the case's own): the scene is read (``scene_s``), the operator built
(``setup_s``: its fixed set-up, the step placement and the tables; not part of the calls' times), then one
``cold_s`` call (JAX's tracing and compilation and numba's, the render's stages, the first run) and ``--repeats``
warm calls (``warm_s``: their median; ``warm_runs``). JAX's compiled programs are not read from swim's disk cache
(``SWIM_JAX_CACHE=0``; ``--disk-caches`` reads them), so the first call compiles and its memory counts; numba's
kernels come from their on-disk cache where they are there. A warm render repeats its frame, so its optical volume,
Step 1a and tables come from the stage cache; ``new_state_s`` (renders only) is the median of as many renders with
the stage cache emptied first (``swim.pipeline.caches.STATE.forget``): what a render of a changed state costs, as the
operator's every call does (its Step 1a is part of each call). Memory: ``peak_rss_mb``, the case process's
``ru_maxrss`` (JAX, its compiled programs and the scene included), ``peak_rss_tree_mb`` the largest resident memory
of its process tree seen by the parent, ``scene_rss_mb`` the resident memory after reading the scene (and building
the operator).

The ratios of each scene: the gradient's warm time to the operator's forward run (``gradient_per_forward``), to the
JAX render (``gradient_per_render_jax``; the goal: <= 5, with the gradient's peak memory <= 4 GB, GB = 2^30 bytes),
to the JAX render with the operator's settings (``gradient_per_render_jax_operator``) and to the default numba render
(``gradient_per_render_numba``, reported). Results go to ``results/assimilation-latest.json`` (overwritten) and the
headline figures to ``results/history.csv`` (kind ``assimilation``, appended; ``history.assimilation_rows``); a
Markdown table is printed.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import resource
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import history  # noqa: E402  (benchmarks/)

RESULTS = ROOT / "benchmarks" / "results"
DATA = ROOT.parent / "shared" / "data"

#: The scenes: the LES file under ``les/`` of the shared data and its reference point (lat, lon) [deg].
SCENES = {"rico": ("rico122x106x39.txt", (17.5, -62.0)), "rico_small": ("rico32x37x26.txt", (17.5, -62.0))}
CASES = ("forward", "gradient", "render_numba", "render_jax", "render_jax_operator")
#: The view: observer height [m], sun zenith and azimuth [deg].
HEIGHT, SUN_ZENITH, SUN_AZIMUTH = 2.0, 30.0, 120.0
#: The goals: the gradient's warm time at most this many JAX renders' of the same image, its peak memory [GB].
GOAL_RATIO, GOAL_GB = 5.0, 4.0


# ---------------------------------------------------------------------------------------------------------------------
# child: one case in its own process


def _rss_mb():
    """This process's resident memory now [MB]."""
    status = Path("/proc/self/status").read_text()
    return next(int(line.split()[1]) for line in status.splitlines() if line.startswith("VmRSS")) / 1024


def read_scene(data, name):
    import swim

    file, (lat, lon) = SCENES[name]
    return swim.read_shdom_les(Path(data) / "les" / file, reference_lat=lat, reference_lon=lon)


def _timed(call, repeats, before=None):
    """The wall times [s] of one first call and of ``repeats`` more (each after ``before()``, untimed)."""
    t0 = time.perf_counter()
    call()
    cold = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        if before is not None:
            before()
        t0 = time.perf_counter()
        call()
        runs.append(time.perf_counter() - t0)
    return cold, runs


def operator_case(spec, scene):
    """``forward`` or ``gradient``: the operator's calls (module docstring)."""
    import jax
    import jax.numpy as jnp

    from swim.assimilation import ForwardOperator, Observer, rmse

    t0 = time.perf_counter()
    op = ForwardOperator(scene, [Observer(height=HEIGHT, camera="allsky", camera_options={"size": spec["size"]})],
                         sun_zenith=SUN_ZENITH, sun_azimuth=SUN_AZIMUTH)
    out = {"setup_s": time.perf_counter() - t0, "rays": int(op.setup.n_rays), "chunks": len(op.setup.chunks),
           "state_shape": list(op.setup.state_shape), "scene_rss_mb": _rss_mb()}
    x = jnp.asarray(op.reference_state)
    if spec["case"] == "forward":
        def call():
            jax.block_until_ready(op(x))
    else:
        t0 = time.perf_counter()
        observed = jax.block_until_ready(op(0.8 * x))
        out["observed_s"] = time.perf_counter() - t0  # the forward run's compilation and first run

        def loss(images):
            return rmse(images, observed, op.masks)

        def call():
            value, gradient = jax.block_until_ready(op.value_and_grad(loss, x))
            out["loss"], out["gradient_finite"] = float(value), bool(jnp.all(jnp.isfinite(gradient)))
    out["cold_s"], out["warm_runs"] = _timed(call, spec["repeats"])
    return out


def render_case(spec, scene):
    """``render_*``: ``swim.render`` of the view, warm (the same frame) and with the stage cache emptied."""
    import swim
    from swim.assimilation.setup import DIFFERENTIABLE
    from swim.pipeline.caches import STATE
    from swim.rt.march_settings import MarchSettings

    settings = MarchSettings()
    if spec["case"] == "render_jax":
        settings = settings.with_execution(backend="jax")
    elif spec["case"] == "render_jax_operator":
        settings = MarchSettings(**DIFFERENTIABLE).with_execution(backend="jax", grid_kernel="lockstep")
    out = {"scene_rss_mb": _rss_mb()}

    def call():
        image = swim.render(scene, height=HEIGHT, camera="allsky", camera_options={"size": spec["size"]},
                            sun_zenith=SUN_ZENITH, sun_azimuth=SUN_AZIMUTH, settings=settings)
        out.update(march_backend=image.attrs.get("march_backend"), traced_pixels=int(image.attrs["traced_pixels"]),
                   march_samples=int(image.attrs["march_samples"]))
    out["cold_s"], out["warm_runs"] = _timed(call, spec["repeats"])
    _, out["new_state_runs"] = _timed(call, spec["repeats"], before=STATE.forget) if spec["repeats"] else (0, [])
    out["new_state_s"] = statistics.median(out["new_state_runs"]) if out["new_state_runs"] else None
    return out


def child(spec_path, out_path):
    """Run the case of ``spec_path`` (JSON) and write its result to ``out_path``."""
    logging.basicConfig(level=logging.ERROR)
    spec = json.loads(Path(spec_path).read_text())
    result = {}
    try:
        t0 = time.perf_counter()
        scene = read_scene(spec["data"], spec["scene"])
        result["scene_s"] = time.perf_counter() - t0
        runner = operator_case if spec["case"] in ("forward", "gradient") else render_case
        result.update(runner(spec, scene))
        result["warm_s"] = statistics.median(result["warm_runs"]) if result["warm_runs"] else None
        result["status"] = "ok"
    except BaseException as exc:  # MemoryError, compile failures: the reason goes into the table
        result.update(status="not run", reason=f"{type(exc).__name__}: {exc}"[:400],
                      traceback=traceback.format_exc()[-3000:])
    result["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    Path(out_path).write_text(json.dumps(result, default=float))


# ---------------------------------------------------------------------------------------------------------------------
# parent


def _tree_rss_mb(pid):
    """Resident memory [MB] of a process and its descendants, 0 once it is gone."""
    total, pids = 0, [pid]
    while pids:
        p = pids.pop()
        try:
            status = Path(f"/proc/{p}/status").read_text()
            total += next(int(line.split()[1]) for line in status.splitlines() if line.startswith("VmRSS"))
            for task in Path(f"/proc/{p}/task").iterdir():
                pids.extend(int(c) for c in (task / "children").read_text().split())
        except (OSError, StopIteration, ValueError):
            continue
    return total / 1024


def run_case(spec, timeout):
    """One case in a fresh process (its own session, killed at the timeout); its result with the parent's view."""
    env = dict(os.environ)
    if not spec["disk_caches"]:
        env["SWIM_JAX_CACHE"] = "0"  # no compiled programs from disk: the first call compiles, as in a first-ever run
    with tempfile.TemporaryDirectory(prefix="swim-assim-") as tmp:
        spec_path, out_path, log_path = (Path(tmp) / n for n in ("spec.json", "result.json", "log.txt"))
        spec_path.write_text(json.dumps(spec))
        with open(log_path, "w") as log:
            proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--child", str(spec_path),
                                     str(out_path)], stdout=log, stderr=subprocess.STDOUT, env=env,
                                    start_new_session=True)
            t0, peak, killed = time.monotonic(), 0.0, None
            while proc.poll() is None:
                peak = max(peak, _tree_rss_mb(proc.pid))
                if time.monotonic() - t0 > timeout:
                    killed = f"timeout after {timeout:.0f} s"
                    os.killpg(proc.pid, signal.SIGKILL)  # the session this call started: the child alone
                    proc.wait()
                    break
                time.sleep(0.2)
        wall = time.monotonic() - t0
        if out_path.is_file() and not killed:
            result = json.loads(out_path.read_text())
        else:
            reason = killed or (f"killed by signal {-proc.returncode}" if proc.returncode < 0
                                else f"exited with code {proc.returncode} without a result")
            result = {"status": "not run", "reason": reason,
                      "log_tail": log_path.read_text(errors="replace").strip().splitlines()[-15:]}
    result.update(case=spec["case"], scene=spec["scene"], wall_s=wall, peak_rss_tree_mb=peak)
    return result


def ratios(rows):
    """The gradient's warm time over the other cases' and the goals' verdicts, of one scene's ``rows``."""
    warm = {case: r.get("warm_s") for case, r in rows.items() if r.get("status") == "ok"}
    out = {}
    for case, key in (("forward", "gradient_per_forward"), ("render_jax", "gradient_per_render_jax"),
                      ("render_jax_operator", "gradient_per_render_jax_operator"),
                      ("render_numba", "gradient_per_render_numba")):
        out[key] = warm["gradient"] / warm[case] if warm.get("gradient") and warm.get(case) else None
    grad = rows.get("gradient", {})
    out["gradient_peak_gb"] = grad["peak_rss_mb"] / 1024 if grad.get("status") == "ok" else None
    per_render = out["gradient_per_render_jax"]
    out["goal_time_met"] = None if per_render is None else per_render <= GOAL_RATIO
    out["goal_memory_met"] = None if out["gradient_peak_gb"] is None else out["gradient_peak_gb"] <= GOAL_GB
    return out


def _f(value, fmt):
    return "" if value is None else format(value, fmt)


def table(results):
    lines = ["| scene | case | cold [s] | warm [s] | new state [s] | peak [GB] | set-up [s] | rays | status |",
             "| --- " * 9 + "|"]
    for scene, res in results.items():
        for case, r in res["cases"].items():
            status = "ok" if r.get("status") == "ok" else f"not run: {r.get('reason', '')}"
            lines.append(f"| {scene} | {case} | {_f(r.get('cold_s'), '.2f')} | {_f(r.get('warm_s'), '.2f')} | "
                         f"{_f(r.get('new_state_s'), '.2f')} | {_f(r.get('peak_rss_mb', 0) / 1024, '.2f')} | "
                         f"{_f(r.get('setup_s'), '.1f')} | {r.get('rays') or r.get('traced_pixels') or ''} | "
                         f"{status} |")
    lines += ["", "| scene | gradient / forward | gradient / JAX render | gradient / JAX render (operator's settings) "
              "| gradient / numba render | gradient peak [GB] | goal <= 5x JAX render | goal <= 4 GB |",
              "| --- " * 8 + "|"]
    for scene, res in results.items():
        q = res["ratios"]
        lines.append(f"| {scene} | {_f(q['gradient_per_forward'], '.2f')} | {_f(q['gradient_per_render_jax'], '.2f')} "
                     f"| {_f(q['gradient_per_render_jax_operator'], '.2f')} | "
                     f"{_f(q['gradient_per_render_numba'], '.2f')} | {_f(q['gradient_peak_gb'], '.2f')} | "
                     f"{q['goal_time_met']} | {q['goal_memory_met']} |")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--child", nargs=2, metavar=("SPEC", "OUT"), help=argparse.SUPPRESS)
    parser.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--size", type=int, default=256, help="all-sky image size [pixels] (default 256)")
    parser.add_argument("--repeats", type=int, default=3, help="warm calls per case (default 3)")
    parser.add_argument("--timeout", type=float, default=2400.0, help="per case [s] (default 2400)")
    parser.add_argument("--disk-caches", action="store_true",
                        help="let JAX read compiled programs from swim's disk cache (default: off, SWIM_JAX_CACHE=0)")
    parser.add_argument("--data", type=Path, default=DATA, help="the shared data (les/)")
    parser.add_argument("--out", type=Path, default=RESULTS / "assimilation-latest.json")
    parser.add_argument("--no-history", action="store_true", help="do not append to results/history.csv")
    args = parser.parse_args(argv)
    if args.child:
        child(*args.child)
        return 0
    results = {}
    for scene in args.scenes:
        rows = {}
        for case in args.cases:
            spec = {"scene": scene, "case": case, "size": args.size, "repeats": args.repeats,
                    "data": str(args.data), "disk_caches": args.disk_caches}
            rows[case] = run_case(spec, args.timeout)
            r = rows[case]
            print(f"{scene} {case}: {r.get('status')} cold {_f(r.get('cold_s'), '.2f')} s, warm "
                  f"{_f(r.get('warm_s'), '.2f')} s, peak {r.get('peak_rss_mb', 0) / 1024:.2f} GB "
                  f"{r.get('reason', '')}", flush=True)
        results[scene] = {"file": SCENES[scene][0], "cases": rows, "ratios": ratios(rows)}
    doc = {"created": history.now(), "argv": sys.argv[1:], "size": args.size, "repeats": args.repeats,
           "disk_caches": args.disk_caches,
           "view": {"height_m": HEIGHT, "camera": "allsky", "sun_zenith_deg": SUN_ZENITH,
                    "sun_azimuth_deg": SUN_AZIMUTH},
           "goals": {"gradient_per_render_jax": GOAL_RATIO, "gradient_peak_gb": GOAL_GB},
           "machine": history.machine_label(), "commit": history.commit_label(), "results": results}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1, default=float))
    print(f"\n{table(results)}\n\nwrote {args.out}")
    if not args.no_history:
        history.append("assimilation", history.assimilation_rows(doc), date=doc["created"],
                       source="bench_assimilation.py")
    ok = all(r.get("status") == "ok" for res in results.values() for r in res["cases"].values())
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
