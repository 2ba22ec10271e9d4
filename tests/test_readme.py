"""The README's examples run, and its figures name the command that prints them (issue 14,
item 10): a README that drifts from the code fails here."""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from samples import SAMPLES

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text(encoding="utf-8")
#: placeholder names the README's examples use, and the bundled sample each stands for
PLACEHOLDERS = {
    "target.msh": "cylinder.msh", "target.vtu": "cylinder.msh", "cylinder.msh": "cylinder.msh",
    "cyl.msh": "cylinder.msh", "points.csv": "plate.csv", "plate.csv": "plate.csv",
    "plate.vtu": "plate.vtu", "plate_and_cylinder.msh": "plate_and_cylinder.msh",
    "part.stl": "cylinder_tri.stl", "contactors.csv": "plate.csv",
}


def blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", README, flags=re.S)


def commands() -> list[str]:
    """Every diffsurf command line of the README's shell blocks after the set-up block."""
    lines = [line.strip() for block in blocks("sh")[1:] for line in block.splitlines()]
    return [line for line in lines if re.match(r"^(diffsurf |cat \S+ \| diffsurf )", line)
            and "--scheduler" not in line]  # a cluster of one's own: tests/test_cluster.py


def _workdir(tmp_path: Path) -> Path:
    for name, sample in PLACEHOLDERS.items():
        shutil.copy(SAMPLES / sample, tmp_path / name)
    if "cloud.parquet" in README:
        import numpy as np
        import polars as pl

        pts = np.loadtxt(SAMPLES / "plate.csv", delimiter=",", skiprows=1)[:, 1:]
        cloud = pl.DataFrame({"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2]})
        cloud.write_parquet(tmp_path / "cloud.parquet")
        (tmp_path / "cloud").mkdir()  # partitions
        cloud[:100].write_parquet(tmp_path / "cloud" / "part-0.parquet")
        cloud[100:].write_parquet(tmp_path / "cloud" / "part-1.parquet")
    if "target.vtu" in README:  # a real .vtu, not a renamed .msh
        import meshio

        meshio.write(tmp_path / "target.vtu", meshio.read(SAMPLES / "cylinder.msh"))
    return tmp_path


def _shell(line: str, cwd: Path) -> subprocess.CompletedProcess:
    # `diffsurf` as the installed command does, whatever the PATH of the test run
    script = f'diffsurf() {{ "{sys.executable}" -m diffsurf_cli "$@"; }}\nset -o pipefail\n{line}\n'
    return subprocess.run(["bash", "-c", script], cwd=cwd, capture_output=True, text=True,
                          timeout=300)


def test_setup_is_two_commands_and_ci_runs_the_second():
    setup = blocks("sh")[0].strip().splitlines()
    assert len(setup) == 2, setup
    install, tests = setup
    assert "pip install" in install and "diffsurf project sample_meshes/" in install
    assert 'pip install -e ".[test]"' in tests and "pytest" in tests
    assert tests in (ROOT / ".ci" / "run").read_text()


def test_the_first_setup_command_runs(tmp_path):
    line = blocks("sh")[0].strip().splitlines()[0]
    run = line.split("&&", 1)[1].strip()  # what follows the install
    result = _shell(run, ROOT)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("id,x,y,z,gap")


@pytest.mark.parametrize("line", commands())
def test_shell_example_runs(line, tmp_path):
    result = _shell(line, _workdir(tmp_path))
    assert result.returncode == 0, f"{line}\n{result.stderr}"


@pytest.mark.parametrize("code", blocks("python"))
def test_python_example_runs(code, monkeypatch):
    monkeypatch.chdir(ROOT)
    exec(compile(code, "README.md", "exec"), {})


def test_every_figure_names_a_command_that_exists():
    # each row of a table of measured figures names the benchmark that prints it
    rows = [line for line in README.splitlines()
            if line.startswith("|") and re.search(r"\d", line) and "benchmarks/" in line]
    assert rows, "no measured figures?"
    for row in rows:
        for script in re.findall(r"python3? (benchmarks/\w+\.py)", row):
            assert (ROOT / script).exists(), row
    speed = README.split("## Speed", 1)[1].split("\n## ", 1)[0]
    for line in speed.splitlines():
        if line.startswith("|") and re.search(r"\d", line) and not line.startswith("|---"):
            assert "benchmarks/" in line, f"a figure without its command: {line}"
