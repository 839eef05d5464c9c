"""Shared fixtures: the real-data folder ../shared/data resolved from this file; JAX's compiled programs dropped
when a worker nears its limit of memory mappings."""

from importlib.util import find_spec
from pathlib import Path

import pytest

if find_spec("pyproj") is not None:
    # PROJ's libraries must load before ecCodes' (eccodeslib wheels): the other way round pyproj finds no database
    # and the process aborts at exit. A worker may open a GRIB file (xarray loads cfgrib, hence ecCodes, whenever
    # it guesses an engine) before a test imports xwrf, which imports pyproj.
    import pyproj  # noqa: F401

SHARED_DATA = (Path(__file__).resolve().parents[1] / ".." / "shared" / "data").resolve()


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Inspections of compiled code (``perf``: assembly, LLVM IR, PTX) run in the full tier: before ``-m``
    selects, each gets the ``full`` marker too."""
    for item in items:
        if item.get_closest_marker("perf") and not item.get_closest_marker("full"):
            item.add_marker(pytest.mark.full)


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path of ../shared/data; the test is skipped where the folder is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data folder not found: {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture(scope="session", autouse=True)
def _no_drops_inside_a_render_of_a_test():
    """Only the check between tests drops programs: one at the end of a render could change what a later assertion
    of the same test sees (e.g. a jitted function's cache size)."""
    import swim.pipeline as pipeline

    pipeline.chain.COMPILED_PROGRAMS_CHECK_S = float("inf")
    yield


@pytest.fixture(autouse=True)
def _drop_compiled_programs_near_the_mapping_limit():
    """A pytest worker compiles thousands of JAX programs, ~3 memory mappings each, and JAX keeps them all: at
    vm.max_map_count XLA cannot map the next one and the worker later dies of a segmentation fault
    (swim.memory, docs/decisions/0010-memory.md). Checked after each test, at most every 5 s (a count takes
    ~1 ms per 1 000 mappings)."""
    yield
    from swim.memory import release_compiled_programs

    release_compiled_programs(min_interval_s=5.0)
