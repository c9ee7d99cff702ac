"""The hard-case catalogue (scripts/hard_cases.py -> docs/hard_cases.md) agrees with the tests: every
registered test exists (with the parameter it names), every test that calls itself a hard case is
registered, the cases issue 14 asked for are there, and the doc is what the script writes now."""
from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _catalogue():
    spec = importlib.util.spec_from_file_location("hard_cases", REPO / "scripts" / "hard_cases.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("hard_cases", module)
    spec.loader.exec_module(module)
    return module


def test_the_registry_and_the_tests_agree():
    problems = _catalogue().problems()
    assert not problems, "\n".join(problems)


def test_the_doc_is_not_stale():
    hc = _catalogue()
    assert hc.DOC.read_text(encoding="utf-8") == hc.render_doc(), "docs/hard_cases.md is stale: run python scripts/hard_cases.py"


def test_the_script_checks_through_its_process(tmp_path):
    """`python scripts/hard_cases.py --check` exits 0 on this tree, and 1 with a line saying so
    on a doc that lost its last table row."""
    cmd = [sys.executable, "scripts/hard_cases.py", "--check"]
    assert subprocess.run(cmd, cwd=REPO, capture_output=True, timeout=60).returncode == 0
    stale = tmp_path / "hard_cases.md"
    stale.write_text(_catalogue().render_doc().rstrip("\n").rsplit("\n", 1)[0] + "\n", encoding="utf-8")
    run = subprocess.run(cmd + ["--doc", str(stale)], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert run.returncode == 1 and "stale" in run.stderr
