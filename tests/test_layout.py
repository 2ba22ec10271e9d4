"""The package's layers (issue 20): only the command line imports click, nothing but the
`diffsurf` entry point imports the command line, the faceted target does not import the
diffuse one, and no script edits sys.path; the shared scenes say how to get gmsh."""
from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

from diffsurf_cli.testing import gmsh_scenes

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "diffsurf_cli"


def _imports(path: Path) -> list[str]:
    """The modules `path` imports, absolute (relative imports resolved in the package)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = list(path.relative_to(ROOT).parts[:-1])  # a module's, or an __init__'s, package
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - (node.level - 1)] if node.level else []
            module = ".".join(base + ([node.module] if node.module else []))
            names += [module] + [f"{module}.{alias.name}" for alias in node.names]
    return names


def _sources(*folders: str) -> list[Path]:
    return sorted(p for folder in folders for p in (ROOT / folder).rglob("*.py"))


def test_only_the_command_line_imports_click_and_only_the_entry_point_imports_it():
    for path in _sources("diffsurf_cli"):
        inside = path.is_relative_to(PACKAGE / "cli")
        names = _imports(path)
        if not inside:
            assert not any(n == "click" or n.startswith("click.") for n in names), path
        if not inside and path != PACKAGE / "__main__.py":
            assert not any(n.startswith("diffsurf_cli.cli") for n in names), path
    for path in _sources("tests", "benchmarks", "examples"):
        # the entry point itself (`main`, run with click's CliRunner), nothing else of cli/
        cli = {n for n in _imports(path) if n.startswith("diffsurf_cli.cli")}
        assert cli <= {"diffsurf_cli.cli", "diffsurf_cli.cli.main"}, (path, cli)


def test_the_facet_method_does_not_import_the_diffuse_one():
    for path in _sources("diffsurf_cli/facet"):
        assert not any(n.startswith("diffsurf_cli.mls") for n in _imports(path)), path


def test_no_script_edits_the_import_path():
    edits = ("sys.path." + "insert", "sys.path" + "[:0]", "sys.path." + "append")
    for path in _sources("tests", "benchmarks", "examples", "sample_meshes"):
        text = path.read_text(encoding="utf-8")
        assert not any(edit in text for edit in edits), path


def test_gmsh_scenes_say_how_to_get_gmsh(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "gmsh", None)  # as if gmsh were not installed
    with pytest.raises(ImportError, match=r"needs gmsh: pip install 'diffsurf\[test\]'"):
        gmsh_scenes.box(tmp_path / "box.msh")
