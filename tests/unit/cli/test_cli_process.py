"""The ``swim`` console command's process handling (swim.cli.main.run): the cyclic garbage collector paused while
the command's modules load, then frozen (docs/decisions/0008-cold-start.md)."""

import gc
import subprocess
import sys
from importlib.metadata import entry_points

import pytest

from swim.cli import main as cli


@pytest.fixture
def collector_restored():
    enabled, paused = gc.isenabled(), cli._GC_PAUSED
    gc.enable()
    gc.unfreeze()
    yield
    gc.unfreeze()
    (gc.enable if enabled else gc.disable)()
    cli._GC_PAUSED = paused


def test_run_pauses_the_collector_until_the_modules_are_loaded(monkeypatch, collector_restored):
    seen = []

    def command():  # what a command does: its imports, then modules_loaded(), then its work; Typer exits
        seen.append(("importing", gc.isenabled(), gc.get_freeze_count()))
        cli.modules_loaded()
        seen.append(("working", gc.isenabled(), gc.get_freeze_count() > 0))
        raise SystemExit(0)

    monkeypatch.setattr(cli, "app", command)
    with pytest.raises(SystemExit):
        cli.run()
    assert seen == [("importing", False, 0), ("working", True, True)]
    assert gc.isenabled()
    assert not cli._GC_PAUSED
    frozen = gc.get_freeze_count()
    cli.modules_loaded()  # a second call (no pause any more): nothing more is frozen
    assert gc.get_freeze_count() == frozen


def test_run_freezes_before_exit_even_after_an_error(monkeypatch, collector_restored):
    def failing():
        raise SystemExit(2)  # a bad option: Typer exits before any command ran

    monkeypatch.setattr(cli, "app", failing)
    with pytest.raises(SystemExit):
        cli.run()
    assert gc.get_freeze_count() > 0


def test_modules_loaded_leaves_the_collector_of_a_library_process_alone(collector_restored):
    cli._GC_PAUSED = False
    cli.modules_loaded()
    assert gc.isenabled()
    assert gc.get_freeze_count() == 0


def test_console_script_is_run():
    (script,) = [e for e in entry_points(group="console_scripts") if e.name == "swim"]
    assert script.value == "swim.cli.main:run"


def test_run_renders_and_reports_bad_input_without_a_traceback(tmp_path):
    out = tmp_path / "small.png"
    code = ("import sys; from swim.cli.main import run; sys.argv = ['swim', 'render', '--size', '15', "
            f"'--cloud-scattering', 'albers2020', '--out', {str(out)!r}]; run()")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    assert out.stat().st_size > 0
    bad = subprocess.run([sys.executable, "-c", code.replace("'--size', '15'", "'--lazy'")], capture_output=True,
                         text=True, timeout=600)
    assert bad.returncode == 2
    assert "--lazy needs a scene file" in bad.stdout + bad.stderr and "Traceback" not in bad.stderr
