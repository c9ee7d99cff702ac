"""The import graph of our packages: no cycles, no importlib dispatch in render, no upward imports.

The graph is built from the source with ``ast`` (nothing is imported): every ``.py`` under
render/ rig/ recon/ pipeline/ is a node (a package is its ``__init__``); ``import a.b`` and
``from a import b`` (relative ones resolved against the importing module's package) are edges,
at module level and inside functions alike, to the most specific module of ours they name
(``from pkg import mod`` is an edge to ``pkg.mod``, ``from mod import name`` to ``mod``).
Python's implicit import of a module's parent packages is not an edge (a package's ``__init__``
importing its own submodules is the registry pattern, not a cycle).

Layers (DESIGN.md): render imports nothing of ours; rig and recon import render and never each
other; only pipeline imports pipeline.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("render", "rig", "recon", "pipeline")
#: what each layer may import of ours (besides itself)
ALLOWED = {"render": set(), "rig": {"render"}, "recon": {"render"}, "pipeline": {"render", "rig", "recon"}}


def module_files(root: Path, packages=PACKAGES) -> dict[str, Path]:
    """Dotted module name -> file, for every .py under the packages (``__init__`` -> the package)."""
    out = {}
    for pkg in packages:
        for f in sorted((root / pkg).rglob("*.py")):
            parts = list(f.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = f
    return out


def _imports(tree: ast.AST, module: str, is_package: bool, known: set[str]) -> set[str]:
    """Modules of ours that ``module`` imports anywhere in its source."""
    package = module if is_package else module.rpartition(".")[0]
    edges = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                name = alias.name
                while name and name not in known:  # `import a.b.c` of a name inside a module
                    name = name.rpartition(".")[0]
                if name:
                    edges.add(name)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                full = ".".join(base + ([node.module] if node.module else []))
            else:
                full = node.module or ""
            for alias in node.names:
                sub = f"{full}.{alias.name}"
                if sub in known:
                    edges.add(sub)
                elif full in known:
                    edges.add(full)
    edges.discard(module)
    return edges


def import_graph(root: Path = ROOT, packages=PACKAGES) -> dict[str, set[str]]:
    """module -> the modules of ours it imports (see the module docstring)."""
    files = module_files(root, packages)
    known = set(files)
    return {m: _imports(ast.parse(f.read_text(encoding="utf-8"), str(f)), m, f.name == "__init__.py", known)
            for m, f in files.items()}


def _reach(graph: dict[str, set[str]], start: str) -> set[str]:
    seen, todo = {start}, [start]
    while todo:
        for nxt in graph.get(todo.pop(), ()):
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every group of modules that import each other (directly or through others): the
    strongly connected components of more than one module, each sorted, in name order."""
    reverse = {m: set() for m in graph}
    for m, deps in graph.items():
        for d in deps:
            reverse.setdefault(d, set()).add(m)
    out, done = [], set()
    for m in sorted(graph):
        if m in done:
            continue
        scc = _reach(graph, m) & _reach(reverse, m)
        done |= scc
        if len(scc) > 1:
            out.append(sorted(scc))
    return out


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    """'a -> b' for every import that crosses the layers the wrong way."""
    bad = []
    for m, deps in sorted(graph.items()):
        layer = m.split(".")[0]
        for d in sorted(deps):
            other = d.split(".")[0]
            if other != layer and other not in ALLOWED[layer]:
                bad.append(f"{m} -> {d}")
    return bad


def importlib_uses(root: Path = ROOT, package: str = "render") -> list[str]:
    """'module: line' for every importlib import or __import__ call under ``package``."""
    out = []
    for m, f in module_files(root, (package,)).items():
        for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "__import__":
                names = ["__import__"]
            if any(n == "__import__" or n.split(".")[0] == "importlib" for n in names):
                out.append(f"{m}: {node.lineno}")
    return out


def test_no_import_cycles():
    cycles = import_cycles(import_graph())
    assert cycles == [], "modules importing each other: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_layers_import_downwards_only():
    assert upward_imports(import_graph()) == []


def test_render_dispatches_without_importlib():
    assert importlib_uses() == []


def test_the_graph_sees_what_it_must(tmp_path):
    """The checker itself: relative, function-level and package imports are edges; a cycle
    through them, an upward import and importlib are all reported."""
    pkg = tmp_path / "render" / "integrators"
    pkg.mkdir(parents=True)
    (tmp_path / "render" / "__init__.py").write_text("")
    (tmp_path / "render" / "film.py").write_text("def f():\n    from .integrators import path\n")
    (pkg / "__init__.py").write_text("from . import path\n")
    (pkg / "path.py").write_text("from ..film import f\nimport importlib\n")
    (tmp_path / "rig").mkdir()
    (tmp_path / "rig" / "__init__.py").write_text("")
    (tmp_path / "rig" / "capture.py").write_text("from recon.nerf import x\n")
    (tmp_path / "recon").mkdir()
    (tmp_path / "recon" / "__init__.py").write_text("")
    (tmp_path / "recon" / "nerf.py").write_text("import render.integrators.path\n")
    g = import_graph(tmp_path, ("render", "rig", "recon"))
    assert g["render.integrators"] == {"render.integrators.path"}
    assert g["render.film"] == {"render.integrators.path"}
    assert g["recon.nerf"] == {"render.integrators.path"}
    assert import_cycles(g) == [["render.film", "render.integrators.path"]]
    assert upward_imports(g) == ["rig.capture -> recon.nerf"]
    assert importlib_uses(tmp_path) == ["render.integrators.path: 2"]
    (tmp_path / "render" / "film.py").write_text("")
    assert import_cycles(import_graph(tmp_path, ("render", "rig", "recon"))) == []


@pytest.mark.parametrize("package", PACKAGES)
def test_every_package_has_modules(package):
    """A renamed or emptied package would make the checks above vacuous."""
    assert len(module_files(ROOT, (package,))) > 3
