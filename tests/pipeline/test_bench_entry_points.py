"""`make bench` runs every bench/bench_*.py through bench.run_all, which calls each module's
``main()`` with no arguments: a benchmark whose main needs an argument would fail there with a
TypeError (three did) and only a full `make bench` would show it."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench"


def _main_def(path: Path) -> ast.FunctionDef | None:
    # parsed, not imported: importing a benchmark pulls torch, mitsuba or pyrender
    tree = ast.parse(path.read_text(), filename=str(path))
    return next((n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "main"), None)


@pytest.mark.parametrize("path", sorted(BENCH.glob("bench_*.py")), ids=lambda p: p.stem)
def test_bench_main_runs_without_arguments(path: Path):
    main = _main_def(path)
    assert main is not None, f"{path.name} has no main() for bench.run_all"
    args = main.args
    positional = args.posonlyargs + args.args
    required = len(positional) - len(args.defaults)
    kw_required = [a.arg for a, d in zip(args.kwonlyargs, args.kw_defaults) if d is None]
    assert required == 0 and not kw_required, (
        f"{path.name}: main() needs {[a.arg for a in positional[:required]] + kw_required}; run_all passes none")
