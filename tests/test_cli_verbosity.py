"""-v and -q work on either side of the command name (issue 14, item 1): they are declared
once (cli/options.py) on the group and on every command."""
from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from diffsurf_cli.cli import main

SAMPLES = Path(__file__).resolve().parents[1] / "sample_meshes"
TARGET, POINTS = str(SAMPLES / "cylinder.msh"), str(SAMPLES / "plate.csv")


def _run(*args):
    return CliRunner().invoke(main, list(args))


@pytest.mark.parametrize("where", ["before", "after"])
def test_quiet_on_either_side_of_the_command(where):
    args = ["project", TARGET, POINTS]
    result = _run(*(["-q", *args] if where == "before" else [*args, "-q"]))
    assert result.exit_code == 0, result.output
    assert result.stderr == ""
    assert result.stdout.startswith("id,x,y,z,gap")
    loud = _run(*args)
    assert "contactors" in loud.stderr  # the log line -q silenced


@pytest.mark.parametrize("command", [["project", TARGET, POINTS], ["smooth", TARGET, "-o", "x.vtu"],
                                     ["tune", TARGET]])
def test_every_command_takes_verbosity_options(command):
    result = _run(*command, "--help")
    assert result.exit_code == 0
    assert "-q, --quiet" in result.stdout and "-v, --verbose" in result.stdout


def test_verbose_after_the_command_shows_the_traceback(tmp_path):
    missing = str(tmp_path / "missing.msh")
    short = _run("project", missing, POINTS)
    assert short.exit_code == 1 and short.exception is not None
    assert isinstance(short.exception, SystemExit)  # one line, no traceback
    verbose = _run("project", missing, POINTS, "-v")
    assert verbose.exit_code == 1
    assert not isinstance(verbose.exception, SystemExit)  # the original error propagates
