"""The README's and the docs' examples run, and their figures name the command that prints them
(issue 14, item 10): documentation that drifts from the code fails here.

The reference is a site in docs/ built by MkDocs (mkdocs.yml; issue 31, item 6); README.md keeps
what a newcomer needs first. Every check below runs over README.md and every docs/*.md page, so
an example moved from one to the other still runs.
"""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
import unicodedata
from pathlib import Path

import pytest

from samples import SAMPLES

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = ROOT / "docs"
#: every page whose examples must run: the README first, then the site's pages
PAGES = [README, *sorted(DOCS.glob("*.md"))]
#: README.md stays an introduction: the reference lives in docs/
README_MAX_LINES = 300
#: placeholder names the examples use, and the bundled sample each stands for
PLACEHOLDERS = {
    "target.msh": "cylinder.msh", "target.vtu": "cylinder.msh", "cylinder.msh": "cylinder.msh",
    "cyl.msh": "cylinder.msh", "points.csv": "plate.csv", "plate.csv": "plate.csv",
    "plate.vtu": "plate.vtu", "plate_and_cylinder.msh": "plate_and_cylinder.msh",
    "part.stl": "cylinder_tri.stl", "contactors.csv": "plate.csv", "torus.msh": "torus.msh",
}


def name(page: Path) -> str:
    return page.relative_to(ROOT).as_posix()


def text(page: Path) -> str:
    return page.read_text(encoding="utf-8")


def blocks(page: Path, lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", text(page), flags=re.S)


def commands() -> list:
    """Every diffsurf command line of the pages' shell blocks (the set-up lines start with
    `python3 -m pip`, not with `diffsurf`), each once, named by the first page that shows it."""
    seen = {}
    for page in PAGES:
        for block in blocks(page, "sh"):
            for line in (line.strip() for line in block.splitlines()):
                if (re.match(r"^(diffsurf |cat \S+ \| diffsurf )", line)
                        and "--scheduler" not in line):  # a cluster of one's own: test_cluster.py
                    seen.setdefault(line, name(page))
    return [pytest.param(line, id=f"{page}: {line}") for line, page in seen.items()]


def python_blocks() -> list:
    return [pytest.param(page, code, id=f"{name(page)}[{i}]")
            for page in PAGES for i, code in enumerate(blocks(page, "python"))]


def table_rows(page: Path) -> list[tuple[list[str], str]]:
    """(the header's cells, the row) of every data row of every table of `page`."""
    rows, header = [], None
    for line in text(page).splitlines():
        if not line.startswith("|"):
            header = None
        elif header is None:
            header = [cell.strip().lower() for cell in line.strip("|").split("|")]
        elif not line.startswith("|---"):
            rows.append((header, line))
    return rows


def slug(heading: str) -> str:
    """A heading's anchor, as MkDocs (Python-Markdown's toc) makes it."""
    value = unicodedata.normalize("NFKD", heading).encode("ascii", "ignore").decode("ascii")
    value = re.sub(r"[^\w\s-]", "", value).strip().lower()
    return re.sub(r"[-\s]+", "-", value)


def anchors(page: Path) -> set[str]:
    body = re.sub(r"```.*?```", "", text(page), flags=re.S)  # a `# comment` is no heading
    return {slug(h) for h in re.findall(r"^#+ (.+)$", body, flags=re.M)}


def _workdir(tmp_path: Path, line: str) -> Path:
    for placeholder, sample in PLACEHOLDERS.items():
        shutil.copy(SAMPLES / sample, tmp_path / placeholder)
    if "cloud" in line:
        import numpy as np
        import polars as pl

        pts = np.loadtxt(SAMPLES / "plate.csv", delimiter=",", skiprows=1)[:, 1:]
        cloud = pl.DataFrame({"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2]})
        cloud.write_parquet(tmp_path / "cloud.parquet")
        (tmp_path / "cloud").mkdir()  # partitions
        cloud[:100].write_parquet(tmp_path / "cloud" / "part-0.parquet")
        cloud[100:].write_parquet(tmp_path / "cloud" / "part-1.parquet")
    if "target.vtu" in line:  # a real .vtu, not a renamed .msh
        import meshio

        meshio.write(tmp_path / "target.vtu", meshio.read(SAMPLES / "cylinder.msh"))
    return tmp_path


def _shell(line: str, cwd: Path) -> subprocess.CompletedProcess:
    # `diffsurf` as the installed command does, whatever the PATH of the test run
    script = f'diffsurf() {{ "{sys.executable}" -m diffsurf_cli "$@"; }}\nset -o pipefail\n{line}\n'
    return subprocess.run(["bash", "-c", script], cwd=cwd, capture_output=True, text=True,
                          timeout=300)


def test_setup_is_two_commands_and_ci_runs_the_second():
    setup = blocks(README, "sh")[0].strip().splitlines()
    assert len(setup) == 2, setup
    install, tests = setup
    assert "pip install" in install and "diffsurf project sample_meshes/" in install
    assert 'pip install -e ".[test]"' in tests and "pytest" in tests
    assert tests in (ROOT / ".ci" / "run").read_text()
    # the site's home page shows the same two commands
    assert blocks(DOCS / "index.md", "sh")[0].strip().splitlines() == setup


def test_the_first_setup_command_runs(tmp_path):
    line = blocks(README, "sh")[0].strip().splitlines()[0]
    run = line.split("&&", 1)[1].strip()  # what follows the install
    result = _shell(run, ROOT)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("id,x,y,z,gap")


@pytest.mark.parametrize("line", commands())
def test_shell_example_runs(line, tmp_path):
    result = _shell(line, _workdir(tmp_path, line))
    assert result.returncode == 0, f"{line}\n{result.stderr}"


@pytest.mark.parametrize(("page", "code"), python_blocks())
def test_python_example_runs(page, code, monkeypatch):
    monkeypatch.chdir(ROOT)
    exec(compile(code, name(page), "exec"), {})


@pytest.mark.parametrize("page", PAGES, ids=name)
def test_every_figure_names_a_command_that_exists(page):
    for header, row in table_rows(page):
        if not re.search(r"\d", row):
            continue
        # each row of a table of measured figures names the benchmark that prints it
        for script in re.findall(r"python3? (benchmarks/\w+\.py)", row):
            assert (ROOT / script).exists(), f"{name(page)}: {row}"
        if "command" in header:
            assert "benchmarks/" in row, f"{name(page)}: a figure without its command: {row}"


def test_the_measured_figures_are_checked():
    # the check above is not vacuous: the speed page's table names a command on every row
    rows = [row for header, row in table_rows(DOCS / "speed.md") if "command" in header]
    assert len(rows) >= 5, rows
    assert all(re.search(r"python3? benchmarks/\w+\.py", row) for row in rows), rows


def test_the_readme_is_an_introduction():
    lines = text(README).splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines: move it to docs/"


def test_the_readme_links_every_page_and_every_link_resolves():
    links = re.findall(r"\]\(([^)\s]+)\)", text(README))
    local = [link for link in links if not re.match(r"[a-z]+://", link)]
    for link in local:
        path, _, anchor = link.partition("#")
        target = (ROOT / path).resolve()
        assert target.exists(), f"README.md links to {link}: no such file"
        if anchor:
            assert anchor in anchors(target), f"README.md links to {link}: no such heading"
    linked = {(ROOT / link.partition("#")[0]).resolve() for link in local}
    missing = [name(page) for page in PAGES[1:] if page.resolve() not in linked]
    assert not missing, f"docs pages the README does not link to: {missing}"


def test_the_status_and_reason_codes_are_the_engines():
    from diffsurf_cli import REASONS, STATUS

    rows = {}
    for header, row in table_rows(DOCS / "outputs.md"):
        if header[0] == "code":
            code, word = (cell.strip().strip("`") for cell in row.strip("|").split("|")[:2])
            rows.setdefault(header[1], []).append((int(code), word))
    assert rows["status"] == list(enumerate(STATUS))
    assert rows["reason"] == list(enumerate(REASONS))


def test_the_docs_site_builds_without_a_warning(tmp_path):
    pytest.importorskip("mkdocs")
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path)],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert "WARNING" not in result.stderr, result.stderr
    built = {page.relative_to(tmp_path).parent.as_posix() for page in tmp_path.rglob("index.html")}
    for page in PAGES[1:]:
        assert (page.stem if page.stem != "index" else ".") in built, name(page)
