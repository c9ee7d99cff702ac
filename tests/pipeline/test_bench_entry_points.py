"""`make bench` runs every bench/bench_*.py through bench.run_all, which calls each module's
``main()`` with no arguments: a benchmark whose main needs an argument would fail there with a
TypeError (three did) and only a full `make bench` would show it."""
from __future__ import annotations

import ast
import json
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


_PROBE = r"""
import contextlib, importlib, io, json, sys
out = {}
for name in sys.argv[1:]:
    mod = importlib.import_module(f"bench.{name}")
    out[name] = []
    for argv in (["--help"], ["--no-such-option"]):
        err = io.StringIO()
        with contextlib.redirect_stdout(io.StringIO()) as shown, contextlib.redirect_stderr(err):
            try:
                mod.main(argv)
                code = "returned"  # main ran its work instead of answering
            except SystemExit as e:
                code = e.code
        out[name].append([code, shown.getvalue()[:300], err.getvalue()[-300:]])
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def option_answers() -> dict:
    """Every benchmark's ``main(["--help"])`` and ``main(["--no-such-option"])``, in one process
    (importing them all once: torch, mitsuba); a main that read its options by hand would start
    its run here, and the timeout ends the test."""
    names = [p.stem for p in sorted(BENCH.glob("bench_*.py"))]
    proc = subprocess.run([sys.executable, "-c", _PROBE, *names], cwd=BENCH.parent, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("path", sorted(BENCH.glob("bench_*.py")), ids=lambda p: p.stem)
def test_bench_answers_help_and_refuses_unknown_options_before_any_work(option_answers, path: Path):
    """`--help` once started the 20-minute equal-time run, and six benchmarks read their options by
    hand (anything misspelt was ignored and the default run started): each now answers --help with
    its usage and refuses an unknown option with argparse's exit 2 before doing anything."""
    (help_code, help_out, _), (bad_code, _, bad_err) = option_answers[path.stem]
    assert help_code == 0 and "usage: python -m bench." + path.stem in help_out
    assert bad_code == 2 and "unrecognized arguments: --no-such-option" in bad_err


def test_equal_time_bench_refuses_a_reference_of_no_samples():
    run = subprocess.run([sys.executable, "-m", "bench.bench_mitsuba_equal_time", "--ref-spp", "0"], cwd=BENCH.parent,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "--ref-spp must be at least 1, got 0" in run.stderr
