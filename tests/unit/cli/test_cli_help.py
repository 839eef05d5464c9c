"""The CLI's help texts: the defaults they quote are the settings classes' own.

The CLI imports the renderer lazily (a fast ``swim --help``), so an option whose default is the settings class's
takes None and its help quotes the class's value as written text ("default: MarchSettings().tau_refine, 0.25");
this holds the text to the class when a default changes.
"""

import re
from dataclasses import fields

import typer
from typer.testing import CliRunner

from swim.cli.main import app
from swim.rt.image_sampling import AdaptiveSampling
from swim.rt.march_settings import MarchSettings

SETTINGS = {"MarchSettings": MarchSettings, "AdaptiveSampling": AdaptiveSampling}
QUOTED = re.compile(r"(MarchSettings|AdaptiveSampling)\(\)\.(\w+), ([0-9.e+-]+)")


def test_quoted_defaults_are_the_settings_classes_own():
    quoted = []
    for command in typer.main.get_command(app).commands.values():
        for param in command.params:
            for cls_name, field, value in QUOTED.findall(" ".join((getattr(param, "help", None) or "").split())):
                defaults = {f.name: f.default for f in fields(SETTINGS[cls_name])}
                assert field in defaults, f"--{param.name}'s help quotes {cls_name}().{field}, which does not exist"
                assert float(value) == float(defaults[field]), (
                    f"--{param.name}'s help quotes {cls_name}().{field} as {value}, the class's default is "
                    f"{defaults[field]}")
                quoted.append(field)
    # the options that quote a class default (a help text reworded so that the pattern misses it fails here)
    assert {"n_grid", "n_probe", "probe_spacing", "tau_refine", "stop_tau", "tau_tolerance",
            "clear_tolerance"} <= set(quoted)


def test_the_render_help_puts_the_users_options_first_and_hides_the_gpu_tuning():
    from swim.cli.main import GPU_TUNING_OPTIONS

    text = CliRunner().invoke(app, ["render", "--help"], env={"COLUMNS": "200"}).output
    options = [line.split()[0] for line in text.splitlines() if line.startswith("  --")]
    assert options.index("--out") < options.index("--steps") and options.index("--cloud-scattering") < options.index(
        "--backend")
    epilog = re.sub(r"-\n\s+", "-", text.split("Show this message and exit.")[-1])  # unwrapped at hyphens
    for hidden in GPU_TUNING_OPTIONS:
        assert hidden not in options and hidden in epilog  # named in the epilog, not listed
    assert "section" not in text
