"""`make bench` runs every bench/bench_*.py through bench.run_all, which calls each module's
``main()`` with no arguments: a benchmark whose main needs an argument would fail there with a
TypeError (three did) and only a full `make bench` would show it."""
from __future__ import annotations

import ast
import subprocess
import sys
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


def _positional_without_default(main: ast.FunctionDef) -> list[str]:
    """argparse positionals in ``main`` that have no default (no ``nargs`` of "?" or "*")."""
    found = []
    for node in ast.walk(main):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "add_argument"
                and node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)
                and not node.args[0].value.startswith("-")):
            nargs = next((k.value.value for k in node.keywords if k.arg == "nargs" and isinstance(k.value, ast.Constant)),
                         None)
            if nargs not in ("?", "*"):
                found.append(node.args[0].value)
    return found


@pytest.mark.parametrize("path", sorted(BENCH.glob("bench_*.py")), ids=lambda p: p.stem)
def test_bench_argparse_has_a_default_for_every_positional(path: Path):
    """run_all gives a benchmark no command-line arguments: a required positional would end the
    whole `make bench` with argparse's SystemExit (bench_nerf_fullres and bench_nerf_inference did)."""
    main = _main_def(path)
    assert main is not None
    assert not _positional_without_default(main), f"{path.name}: positionals without a default"


def test_run_all_keeps_going_past_a_benchmark_that_exits(monkeypatch, capsys):
    """A benchmark that calls sys.exit (argparse does on bad arguments) is recorded as failed and the
    next one still runs; each sees an argv of its own name only, not run_all's arguments."""
    import importlib
    import sys
    import types

    from bench import run_all

    seen = {}

    def module(name, exits):
        m = types.ModuleType(name)

        def main():
            seen[name] = list(sys.argv)
            if exits:
                sys.exit(2)
        m.main = main
        return m

    fakes = {"bench.bench_a": module("bench.bench_a", True), "bench.bench_b": module("bench.bench_b", False)}
    monkeypatch.setattr(importlib, "import_module", lambda n: fakes[n])
    monkeypatch.setattr(sys, "argv", ["run_all", "bench_a", "bench_b"])
    assert run_all.main(["bench_a", "bench_b"]) == 1
    assert seen == {"bench.bench_a": ["bench.bench_a"], "bench.bench_b": ["bench.bench_b"]}
    assert "bench_a failed: SystemExit" in capsys.readouterr().err
    assert sys.argv == ["run_all", "bench_a", "bench_b"]


def test_equal_time_bench_refuses_unknown_options_before_any_work():
    """`--help` once started the whole 20-minute run (the options were read by hand and anything
    else ignored): argparse now answers --help and refuses a misspelt option with exit 2."""
    root = BENCH.parent
    run = lambda *a: subprocess.run([sys.executable, "-m", "bench.bench_mitsuba_equal_time", *a], cwd=root,
                                    capture_output=True, text=True, timeout=120)
    shown = run("--help")
    assert shown.returncode == 0 and "--skip-variants" in shown.stdout
    refused = run("--skip-variant")
    assert refused.returncode == 2 and "unrecognized arguments: --skip-variant" in refused.stderr
