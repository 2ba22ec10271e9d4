"""Presets (`--preset fast|default|accurate`): expansion, explicit options winning, --help.

The engine options a command ends up with are read from the log line `build_target` writes
("frame: ...; basis B, weight W, support S") and, where the log cannot tell (radius, k), from
the command's resolved options (`options.resolve`) or from the result's support counts.
"""
from __future__ import annotations

import csv
import io
import re

import click
import numpy as np
import pytest
from click.testing import CliRunner

from diffsurf_cli.cli import options
from diffsurf_cli.cli import main
from diffsurf_cli.mls.surface import DEFAULT_RADIUS

from conftest import CYLINDER, PLATE_CSV
from conftest import run as _run
ENGINE_KEYS = {"basis", "weight", "support", "radius", "k", "frame", "recentre"}


def run(*args):
    return _run(*args, catch_exceptions=False)


def engine_line(stderr: str) -> dict:
    m = re.search(r"basis (\w+), weight (\w+), support (\w+)", stderr)
    assert m, stderr
    return dict(zip(("basis", "weight", "support"), m.groups()))


def supports(stdout: str) -> np.ndarray:
    rows = list(csv.DictReader(io.StringIO(stdout)))
    return np.array([int(r["support"]) for r in rows if r["status"] not in ("outside", "failed")])


def test_presets_are_complete_and_default_is_todays_defaults():
    assert set(options.PRESETS) == {"fast", "default", "accurate"}
    for name, preset in options.PRESETS.items():
        assert set(preset) == ENGINE_KEYS, name
    assert options.PRESETS["default"] == options.DEFAULTS
    assert options.DEFAULTS["radius"] is None and DEFAULT_RADIUS["quadratic"] == 2.0
    # the presets differ: each one is a real choice
    assert len({tuple(sorted(p.items())) for p in options.PRESETS.values()}) == 3


def resolved(args):
    """The engine options `options.resolve` gives for these command-line arguments."""
    seen = {}

    @click.command()
    @options.engine
    def cmd(zone, flip_normals, **engine):
        seen.update(options.resolve(click.get_current_context(), engine))

    result = CliRunner().invoke(cmd, list(args), catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return seen


@pytest.mark.parametrize("name", ["fast", "default", "accurate"])
def test_preset_expands(name):
    assert resolved(["--preset", name]) == options.PRESETS[name]


def test_no_preset_is_default():
    assert resolved([]) == options.PRESETS["default"]


def test_explicit_option_overrides_preset_and_only_that_option():
    fast = options.PRESETS["fast"]
    got = resolved(["--preset", "fast", "--basis", "cubic"])
    assert got["basis"] == "cubic"
    assert {k: v for k, v in got.items() if k != "basis"} == \
        {k: v for k, v in fast.items() if k != "basis"}
    # an explicit value equal to the built-in default still wins over the preset
    accurate = options.PRESETS["accurate"]
    assert accurate["basis"] != "quadratic"
    got = resolved(["--preset", "accurate", "--basis", "quadratic"])
    assert got["basis"] == "quadratic" and got["radius"] == accurate["radius"]


def test_environment_counts_as_explicit(monkeypatch):
    seen = {}

    @click.command(context_settings={"auto_envvar_prefix": "DIFFSURF"})
    @options.engine
    def cmd(zone, flip_normals, **engine):
        seen.update(options.resolve(click.get_current_context(), engine))

    monkeypatch.setenv("DIFFSURF_WEIGHT", "gauss")
    result = CliRunner().invoke(cmd, ["--preset", "fast"], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    assert seen["weight"] == "gauss" and seen["support"] == options.PRESETS["fast"]["support"]


def test_project_uses_the_preset():
    fast = options.PRESETS["fast"]
    assert fast["support"] == "knn"
    result = run("project", CYLINDER, PLATE_CSV, "--preset", "fast")
    assert result.exit_code == 0, result.stderr
    assert engine_line(result.stderr)["support"] == "knn"
    # the 12 nearest nodes: every projected point's support is k (weights > 0 inside 1.2x the
    # farthest), or more where nodes tie with the 12th (the regular sample mesh: all of them
    # count, no tie-break decides), unlike the radius support of the default
    got = np.asarray(supports(result.stdout))
    assert got.min() == fast["k"] and np.mean(got == fast["k"]) > 0.5, np.unique(got)
    default = run("project", CYLINDER, PLATE_CSV)
    assert engine_line(default.stderr)["support"] == "radius"
    assert len(set(supports(default.stdout))) > 1


def test_project_explicit_basis_wins_over_fast():
    result = run("project", CYLINDER, PLATE_CSV, "--preset", "fast", "--basis", "cubic")
    assert result.exit_code == 0, result.stderr
    line = engine_line(result.stderr)
    assert line["basis"] == "cubic" and line["support"] == "knn"


def test_smooth_uses_the_preset(tmp_path):
    out = tmp_path / "s.vtu"
    result = run("smooth", CYLINDER, "-o", str(out), "--preset", "accurate")
    assert result.exit_code == 0, result.stderr
    assert engine_line(result.stderr)["basis"] == options.PRESETS["accurate"]["basis"]


def test_bad_preset_is_a_usage_error():
    result = CliRunner().invoke(main, ["project", CYLINDER, PLATE_CSV, "--preset", "fastest"])
    assert result.exit_code == 2
    assert "fastest" in result.output


@pytest.mark.parametrize("command", ["project", "smooth"])
def test_help_lists_the_presets_and_their_expansion(command):
    result = run(command, "--help")
    assert result.exit_code == 0
    text = " ".join(result.output.split())
    assert "--preset [fast|default|accurate]" in text
    for name, preset in options.PRESETS.items():
        assert f"{name} = {preset['basis']}, {preset['weight']}," in text
