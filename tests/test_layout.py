"""The package's layers (issue 20): only the command line imports click, nothing but the
`diffsurf` entry point imports the command line, the faceted target does not import the
diffuse one, and no script edits sys.path; the shared scenes say how to get gmsh. One dispatch
(issue 31): the surfaces do not import the contact elements, and no modules import each other
in a circle, imports inside functions counted."""
from __future__ import annotations

import ast
import re
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


def test_the_surfaces_do_not_import_the_elements():
    """Surfaces answer geometric questions; the element package builds elements from their
    answers (`element.contact` dispatches on the surface's type): nothing in mls/, facet/ or
    patches/ imports element/, not even inside a function."""
    for path in _sources("diffsurf_cli/mls", "diffsurf_cli/facet", "diffsurf_cli/patches"):
        names = _imports(path)
        assert not any(n == "diffsurf_cli.element" or n.startswith("diffsurf_cli.element.")
                       for n in names), path


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


#: `from X import names` and `import X` of a compiled module's Python level (not cimport)
_PYX_FROM = re.compile(r"^[ \t]*from[ \t]+(\.*[\w.]*)[ \t]+import[ \t]+(\([^)]*\)|[^\n#]*)", re.M)
_PYX_IMPORT = re.compile(r"^[ \t]*import[ \t]+([\w.]+)", re.M)


def _pyx_imports(text: str):
    """(level, module, names) of each Python import of a .pyx file (`ast` cannot parse it)."""
    for source, names in _PYX_FROM.findall(text):
        level = len(source) - len(source.lstrip("."))
        names = [n.split(" as ")[0].strip() for n in names.strip("()").split(",")]
        yield level, source.lstrip(".") or None, [n for n in names if n]
    for module in _PYX_IMPORT.findall(text):
        yield 0, module, None


def _module_imports(path: Path, modules: set) -> set:
    """The package's modules `path` imports anywhere in it (in a function too): `from X
    import a` is an import of module X.a where there is one, else of X; `import X.Y` of
    X.Y."""
    package = list(path.relative_to(ROOT).parts[:-1])
    if path.suffix == ".pyx":
        found = list(_pyx_imports(path.read_text(encoding="utf-8")))
    else:
        found = []
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                found += [(0, alias.name, None) for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                found.append((node.level, node.module, [a.name for a in node.names]))
    out = set()
    for level, module, names in found:
        base = package[:len(package) - (level - 1)] if level else []
        source = ".".join(base + ([module] if module else []))
        if names is None:
            out.add(source)
            continue
        for name in names:
            out.add(f"{source}.{name}" if f"{source}.{name}" in modules else source)
    return out & modules


def test_no_modules_import_each_other_in_a_circle():
    """No circle of imports among the package's modules (compiled ones' Python imports too),
    counting the imports inside functions: one that only a function's import keeps from
    failing at import time is still a circle (issue 31: element/ and the surfaces were one
    of six modules)."""
    paths = sorted(PACKAGE.rglob("*.py")) + sorted(PACKAGE.rglob("*.pyx"))
    modules = {_module_name(p) for p in paths}
    graph = {_module_name(p): set() for p in paths}
    for path in paths:
        graph[_module_name(path)] |= _module_imports(path, modules) - {_module_name(path)}
    # depth-first search; a module met again on the current path closes a circle
    state, path, circles = {}, [], []

    def visit(module):
        state[module] = "open"
        path.append(module)
        for other in sorted(graph[module]):
            if state.get(other) == "open":
                circles.append(path[path.index(other):] + [other])
            elif other not in state:
                visit(other)
        path.pop()
        state[module] = "done"

    for module in sorted(graph):
        if module not in state:
            visit(module)
    assert not circles, "import circles: " + "; ".join(" -> ".join(c) for c in circles)


def test_no_script_edits_the_import_path():
    edits = ("sys.path." + "insert", "sys.path" + "[:0]", "sys.path." + "append")
    for path in _sources("tests", "benchmarks", "examples", "sample_meshes"):
        text = path.read_text(encoding="utf-8")
        assert not any(edit in text for edit in edits), path


def test_gmsh_scenes_say_how_to_get_gmsh(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "gmsh", None)  # as if gmsh were not installed
    with pytest.raises(ImportError, match=r"needs gmsh: pip install 'diffsurf\[test\]'"):
        gmsh_scenes.box(tmp_path / "box.msh")
