"""The package's layers (pyproject.toml, ``[tool.importlinter]``; docs/architecture.md): each module imports only from
layers below its own, function-level imports included, so that there are no import cycles between packages."""

import logging
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def _loggers_kept():
    """import-linter configures logging with ``disable_existing_loggers``: the loggers that were enabled are enabled
    again afterwards, so that later tests in the process still capture what the library logs."""
    enabled = [lg for lg in logging.root.manager.loggerDict.values()
               if isinstance(lg, logging.Logger) and not lg.disabled]
    yield
    for lg in enabled:
        lg.disabled = False


def test_the_layers_hold(monkeypatch):
    from importlinter.cli import lint_imports

    monkeypatch.chdir(ROOT)
    assert lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True, no_logo=True) == 0


def test_a_layer_broken_is_reported(monkeypatch, tmp_path):
    """The contract can fail: the same layers with swim.rt put below swim.optics, which it imports."""
    from importlinter.cli import lint_imports

    text = (ROOT / "pyproject.toml").read_text()
    broken = text.replace('    "swim.rt",\n    "swim.optics | swim.color",\n', '    "swim.optics | swim.color",\n    "swim.rt",\n')
    assert broken != text
    config = tmp_path / "pyproject.toml"
    config.write_text(broken)
    monkeypatch.chdir(ROOT)
    assert lint_imports(config_filename=str(config), no_cache=True, no_logo=True) == 1

