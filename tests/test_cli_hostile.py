"""Issue 32 ("A newcomer's third hour"): a hostile tester's command lines.

Bad numbers for float options (NaN, inf, negative, 0), closed standard streams, Ctrl-C,
options that would be silently ignored, help text naming options a command does not have, and
a resumed cluster job with nothing left to do.
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time

import pytest

from diffsurf_cli.cli import main
from samples import CYLINDER, PLATE_CSV, run

COMMAND = [sys.executable, "-m", "diffsurf_cli"]


def clean_failure(res, code: int) -> str:
    """The stderr of a run (CliRunner) that failed cleanly with `code`: no traceback, nothing
    on stdout, a SystemExit (not an uncaught exception the runner turned into exit 1)."""
    assert res.exit_code == code, (res.exit_code, res.stdout, res.stderr, res.exception)
    assert res.stdout == ""
    assert "Traceback" not in res.stderr
    assert isinstance(res.exception, SystemExit), res.exception
    return res.stderr


def shell(redirect: str, *args, timeout=120):
    """`python -m diffsurf_cli ARGS REDIRECT` through sh, for a redirection the subprocess
    module cannot make (a closed descriptor: '<&-', '>&-', '2>&-')."""
    return subprocess.run(["sh", "-c", f'exec "$@" {redirect}', "sh", *COMMAND, *map(str, args)],
                          capture_output=True, text=True, timeout=timeout)


# -------------------------------------------------------------------------------------------
# item 5, 6: every float option refuses NaN, inf, negative and 0 (where 0 is not meaningful)
# -------------------------------------------------------------------------------------------

FLOAT_OPTIONS = {  # command -> its float options and the values each refuses
    "project": {"--radius": ["nan", "inf", "-inf", "0", "-1"],
                "--penalty": ["nan", "inf", "-inf", "0", "-1"],
                "--feature-angle": ["nan", "inf", "-inf", "-1"]},
    "smooth": {"--radius": ["nan", "inf", "-inf", "0", "-1"],
               "--edge-length": ["nan", "inf", "-inf", "0", "-1"],
               "--feature-angle": ["nan", "inf", "-inf", "-1"]},
    "tune": {"--feature-angle": ["nan", "inf", "-inf", "-1"]},
}
BAD_FLOATS = [(cmd, opt, value) for cmd, opts in FLOAT_OPTIONS.items()
              for opt, values in opts.items() for value in values]


def test_every_float_option_is_listed():
    """FLOAT_OPTIONS covers every float option of every command (a new one is tested too)."""
    import click

    for name, command in main.commands.items():
        floats = {p.opts[0] for p in command.params
                  if isinstance(p.type, click.types.FloatParamType)}
        assert floats == set(FLOAT_OPTIONS.get(name, {})), (name, floats)


@pytest.mark.parametrize("cmd,opt,value", BAD_FLOATS,
                         ids=[f"{c}{o}={v}" for c, o, v in BAD_FLOATS])
def test_float_option_refuses_non_finite_and_out_of_range(cmd, opt, value, tmp_path):
    """`smooth --edge-length nan` ended in a ValueError traceback; `--penalty nan` and
    `--penalty inf` ran and wrote K full of NaN; `--feature-angle nan` and `--radius inf`
    ran. Each is now refused as click refuses a bad option (exit 2, the option named), before
    any work, nothing written."""
    out = tmp_path / "out"
    args = {"project": ["project", CYLINDER, PLATE_CSV, "-o", f"{out}.csv"],
            "smooth": ["smooth", CYLINDER, "-o", f"{out}.vtu"],
            "tune": ["tune", CYLINDER, "--sample", "5"]}[cmd]
    if opt == "--penalty":
        args += ["--tangent", tmp_path / "K.mtx"]
    res = run(*args, f"{opt}={value}")
    err = clean_failure(res, 2)
    line = err.strip().splitlines()[-1]
    assert line.startswith(f"Error: Invalid value for '{opt}'"), err
    assert value.lstrip("-") in line.lower(), err
    assert os.listdir(tmp_path) == []


def test_tune_refuses_a_negative_seed():
    """`tune --seed -1` measured for nothing, then failed with 'TARGET: expected non-negative
    integer' (numpy's words, laid on the target file, exit 1). It is a bad option."""
    err = clean_failure(run("tune", CYLINDER, "--sample", "5", "--seed", "-1"), 2)
    assert err.strip().splitlines()[-1].startswith("Error: Invalid value for '--seed'"), err


def test_finite_float_options_still_run(tmp_path):
    """The finite values on the edge of the ranges still run: --feature-angle 0 and 180."""
    for angle in ("0", "180"):
        res = run("-q", "project", CYLINDER, PLATE_CSV, "--feature-angle", angle,
                  "-o", tmp_path / f"a{angle}.csv")
        assert res.exit_code == 0, res.stderr
    res = run("-q", "smooth", CYLINDER, "--edge-length", "1e300", "-o", tmp_path / "s.vtu")
    assert res.exit_code == 0, res.stderr


# -------------------------------------------------------------------------------------------
# item 5: closed stdin, stdout, stderr
# -------------------------------------------------------------------------------------------


def _one_error(res, message: str) -> None:
    assert res.returncode == 1, (res.returncode, res.stderr)
    assert "Traceback" not in res.stderr, res.stderr
    assert res.stderr.strip().splitlines() == [f"diffsurf: error: {message}"], res.stderr


def test_closed_stdin():
    """`project TARGET - <&-` ended in AttributeError (sys.stdin is None)."""
    res = shell("<&-", "-q", "project", CYLINDER, "-")
    _one_error(res, "-: stdin is closed, expected CSV on it (or a file name for POINTS)")
    assert res.stdout == ""
    res = shell("<&-", "-q", "tune", CYLINDER, "-")
    _one_error(res, "-: stdin is closed, expected CSV on it (or a file name for POINTS)")


def test_closed_stdout(tmp_path):
    """`project TARGET POINTS >&-` ended in AttributeError (sys.stdout is None) after all the
    work; tune printed nothing and exited 0. Both now stop before any work."""
    _one_error(shell(">&-", "-q", "project", CYLINDER, PLATE_CSV),
               "stdout is closed: use -o FILE")
    _one_error(shell(">&-", "-q", "tune", CYLINDER, "--sample", "5"),
               "stdout is closed: tune prints its table there")
    # -o FILE needs no stdout
    res = shell(">&-", "-q", "project", CYLINDER, PLATE_CSV, "-o", tmp_path / "r.csv")
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "r.csv").read_text().startswith("id,x,y,z,gap,")


def test_closed_stderr(tmp_path):
    """With stderr closed (sys.stderr is None) a run longer than one chunk asked it whether it
    was a terminal (for the progress bar) and failed with exit 1, its traceback lost. It now
    runs; an error still exits 1."""
    import numpy as np

    rng = np.random.default_rng(0)
    n = 20_000  # more than one chunk: the progress bar is considered
    pts = np.c_[rng.uniform(23, 42, n), rng.uniform(19, 21, n), rng.uniform(0, 5, n)]
    cloud = tmp_path / "cloud.csv"
    np.savetxt(cloud, pts, delimiter=",", header="x,y,z", comments="")
    res = shell("2>&-", "project", CYLINDER, cloud, "-o", tmp_path / "r.csv")
    assert res.returncode == 0
    assert len((tmp_path / "r.csv").read_text().splitlines()) == n + 1
    res = shell("2>&-", "smooth", CYLINDER, "--levels", "4", "-o", tmp_path / "s.vtu")
    assert res.returncode == 0 and (tmp_path / "s.vtu").exists()
    assert shell("2>&-", "project", CYLINDER, tmp_path / "missing.csv").returncode == 1


# -------------------------------------------------------------------------------------------
# item 9: Ctrl-C exits 130, quietly under -q, leaving nothing
# -------------------------------------------------------------------------------------------


def _interrupted(tmp_path, *flags):
    """`project` reading POINTS from a FIFO whose writer stays open (the run cannot finish),
    interrupted by SIGINT once it reads: (exit status, stderr, files left in the output
    directory)."""
    fifo = tmp_path / "points.csv"
    os.mkfifo(fifo)
    out = tmp_path / "out"
    out.mkdir()
    job = subprocess.Popen([*COMMAND, *flags, "project", CYLINDER, str(fifo),
                            "-o", str(out / "r.csv")],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    writer = None
    try:
        deadline = time.monotonic() + 60
        while writer is None and job.poll() is None and time.monotonic() < deadline:
            try:  # opens once the reader has it open (ENXIO before)
                writer = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
            except OSError:
                time.sleep(0.02)
        assert writer is not None, job.communicate(timeout=30)
        os.write(writer, b"x,y,z\n30,20,1\n")
        time.sleep(0.5)  # the reader waits for the rest
        assert job.poll() is None
        job.send_signal(signal.SIGINT)
        _, err = job.communicate(timeout=60)
    finally:
        if writer is not None:
            os.close(writer)
        if job.poll() is None:
            job.kill()
            job.wait()
    return job.returncode, err, sorted(os.listdir(out))


def test_ctrl_c_exits_130_quietly_under_q(tmp_path):
    """Ctrl-C ended with 'Aborted!' and exit 1, even under -q; a signal exits 128 + its
    number (README), as SIGTERM and SIGHUP already did."""
    code, err, left = _interrupted(tmp_path, "-q")
    assert code == 128 + signal.SIGINT, (code, err)
    assert err == ""
    assert left == []


def test_ctrl_c_says_interrupted(tmp_path):
    code, err, left = _interrupted(tmp_path)
    assert code == 130, (code, err)
    assert "Aborted!" not in err and "Traceback" not in err, err
    assert err.strip().splitlines()[-1] == "diffsurf: interrupted", err
    assert left == []


# -------------------------------------------------------------------------------------------
# item 13: options that would be silently ignored are refused
# -------------------------------------------------------------------------------------------

IGNORED = {  # name -> (arguments, words of the error)
    "k_without_knn": (["project", CYLINDER, PLATE_CSV, "-k", "20"],
                      ["-k applies to --support knn"]),
    "k_with_preset_radius": (["project", CYLINDER, PLATE_CSV, "--preset", "normals", "-k", "20"],
                             ["-k applies to --support knn"]),
    "radius_with_knn": (["project", CYLINDER, PLATE_CSV, "--support", "knn", "--radius", "5"],
                        ["--radius applies to --support radius"]),
    "radius_with_fast": (["project", CYLINDER, PLATE_CSV, "--preset", "fast", "--radius", "5"],
                         ["--radius applies to --support radius", "--preset fast"]),
    "smooth_k": (["smooth", CYLINDER, "-o", "s.vtu", "-k", "20"],
                 ["-k applies to --support knn"]),
    "smooth_radius": (["smooth", CYLINDER, "-o", "s.vtu", "--support", "knn", "--radius", "5"],
                      ["--radius applies to --support radius"]),
    "facet_basis": (["project", CYLINDER, PLATE_CSV, "--method", "facet", "--basis", "cubic"],
                    ["--basis applies to the diffuse method only"]),
    "facet_k": (["project", CYLINDER, PLATE_CSV, "--method", "facet", "-k", "20"],
                ["-k applies to the diffuse method only"]),
    "facet_preset": (["project", CYLINDER, PLATE_CSV, "--method", "facet", "--preset", "fast"],
                     ["--preset applies to the diffuse method only"]),
    "facet_many": (["project", CYLINDER, PLATE_CSV, "--method", "facet", "--radius", "3",
                    "--weight", "gauss", "--feature-angle", "30"],
                   ["--weight, --radius, --feature-angle apply to the diffuse method only"]),
    "penalty_alone": (["project", CYLINDER, PLATE_CSV, "--penalty", "1e3"],
                      ["--penalty applies to the contact element",
                       "--residual, --tangent or --elements"]),
    "resume_overwrite": (["project", CYLINDER, PLATE_CSV, "--workers", "2", "--resume",
                          "--overwrite"], ["--resume and --overwrite exclude each other"]),
    "tune_overwrite": (["tune", CYLINDER, "--overwrite"],
                       ["--overwrite applies to the --plot file"]),
}


@pytest.mark.parametrize("case", list(IGNORED))
def test_ignored_option_is_refused(case, tmp_path, monkeypatch):
    """`-k 20` without `--support knn`, `--radius 5` with it, engine options with
    `--method facet`, `--penalty` without an element output, `--resume` with `--overwrite`
    (which projected everything again), `tune --overwrite` without `--plot`: each output was
    byte-identical to the run without the option. Each is refused
    as the options --pairs fixes are (exit 2, the option named with what it needs)."""
    monkeypatch.chdir(tmp_path)
    args, words = IGNORED[case]
    if args[0] == "project":
        args = [*args, "-o", "r.csv"]
    err = clean_failure(run(*args), 2)
    for w in words:
        assert w in err, err
    assert os.listdir(tmp_path) == []


def test_options_that_apply_still_run(tmp_path):
    """The same options where they apply: -k with knn (given or from the preset), --radius
    with a radius support (given or from the preset), --penalty with --elements."""
    for extra in (["--support", "knn", "-k", "20"], ["--preset", "fast", "-k", "20"],
                  ["--preset", "normals", "--radius", "2.5"],
                  ["--preset", "fast", "--support", "radius", "--radius", "2.5"],
                  ["--method", "facet", "--flip-normals", "--zone", "cylinder"],
                  ["--penalty", "1e3", "--elements", tmp_path / "E.npz", "--overwrite"]):
        target = CYLINDER if "--zone" not in extra else CYLINDER.replace(
            "cylinder.msh", "plate_and_cylinder.msh")
        res = run("-q", "project", target, PLATE_CSV, *extra, "-o", tmp_path / "r.csv",
                  "--overwrite")
        assert res.exit_code == 0, (extra, res.stderr)


# -------------------------------------------------------------------------------------------
# item 14: each command's help names only its own options
# -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["project", "smooth", "tune"])
def test_help_names_only_the_commands_options(name):
    """smooth --help and tune --help described --feature-angle with --penalty, --elements,
    --rigid-target, --save-pairs and --pairs, which they do not have."""
    command = main.commands[name]
    have = {o for p in command.params for o in (*p.opts, *p.secondary_opts)} | {"--help"}
    res = run(name, "--help")
    assert res.exit_code == 0
    named = set(re.findall(r"(?<![\w-])--[a-z][a-z-]*[a-z]", res.stdout))
    assert named and named <= have, sorted(named - have)


# -------------------------------------------------------------------------------------------
# item 16c: --resume with nothing left to do
# -------------------------------------------------------------------------------------------


def test_resume_with_nothing_to_do(tmp_path):
    """`--workers 2 --resume` with every partition done printed 'status: ' (empty) and
    '0 per second', after starting a cluster for nothing. It now says so in one line and
    starts no cluster."""
    pytest.importorskip("distributed")
    parts, out = tmp_path / "in", tmp_path / "out"
    parts.mkdir()
    out.mkdir()
    with open(PLATE_CSV) as fh:
        lines = fh.read().splitlines()
    for i, rows in enumerate((lines[1:100], lines[100:])):
        (parts / f"p{i}.csv").write_text("\n".join([lines[0], *rows]) + "\n")
        res = run("-q", "project", CYLINDER, parts / f"p{i}.csv", "-o", out / f"p{i}.csv")
        assert res.exit_code == 0, res.stderr
    before = {p: p.read_bytes() for p in out.iterdir()}
    res = run("project", CYLINDER, parts, "-o", f"{out}/", "--workers", "2", "--resume")
    assert res.exit_code == 0, res.stderr
    err = res.stderr.splitlines()
    assert "diffsurf: all 2 partitions already done; nothing to project" in err, res.stderr
    for word in ("status: ", "per second", "dask:"):
        assert word not in res.stderr, res.stderr
    assert {p: p.read_bytes() for p in out.iterdir()} == before
