"""Hostile scene specs through the CLI, generated with hypothesis (issue 14).

A tiny valid spec (conftest.TINY_SCENE at 32 x 24 pixels, 2 train + 1 test views) is mutated:
wrong types, missing keys, NaN/inf/negative/zero numbers, huge image sizes and counts, empty
lists, mesh and texture files that are missing, a folder or garbage, hostile and unicode view
names, and whole files that are not a mapping, alias bombs, duplicate keys or not UTF-8. Every
case runs ``lumigraph capture`` (some ``lumigraph reference --spp 1 --size 16 12``) and must

- exit 0 with finite images (every linear EXR of the stage read back finite), or
- exit 2 with ONE stderr line that names the spec file and a field (or the file's line),
  with nothing written: no ``--out``, no partial folder, nothing anywhere else;
- never anything else (exit 1 is a traceback), within a per-case time limit.

Generated cases run through ``pipeline.cli.main`` in this process (a subprocess costs ~3-5 s of
imports), with Python- and descriptor-level stderr and warnings captured; a fixed subset, with
exit-0 and exit-2 cases, runs through the real process under ``RLIMIT_AS`` (bounded memory).
The counts (cases, exit 0, exit 2, other) and the seed are printed (``pytest -s`` shows them).
"""
from __future__ import annotations

import contextlib
import copy
import io
import math
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import warnings
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

from pipeline.cli import main

from .conftest import TINY_SCENE

SEED = 20_140_614
MAX_EXAMPLES = 150
CASE_TIMEOUT_S = 60  # one generated case, in process
PROCESS_TIMEOUT_S = 120  # one subprocess case (imports included)
ADDRESS_SPACE_LIMIT = 3 * 2 ** 30  # RLIMIT_AS of the subprocess cases

BASE = copy.deepcopy(TINY_SCENE)
BASE["cameras"]["intrinsics"].update(width=32, height=24)
BASE["cameras"]["train"][0]["ring"]["count"] = 2
BASE["cameras"]["test"][0]["ring"]["count"] = 1

SPEC_NAME = "scene.yaml"
NAN, INF = float("nan"), float("inf")
#: what follows "<spec file>: " in a one-line error: a field path, a line of the file, or a
#: statement about the file as a whole
_NAMES_A_FIELD = re.compile(r"^(line \d+\b|[^\s:]+: |(up|name|seed) |a scene spec must be a YAML mapping|"
                            r"the scene file|not UTF-8|the spec file|the YAML document|not a valid YAML|"
                            r"the document is nested)")

COUNTS: Counter = Counter()


# ---------------------------------------------------------------- mutations
def _paths(node, prefix=()):
    """Every path into the base spec (containers and leaves)."""
    yield prefix
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for k, v in items:
        yield from _paths(v, prefix + (k,))


PATHS = [p for p in _paths(BASE) if p]


def _get(path):
    node = BASE
    for k in path:
        node = node[k]
    return node


#: every number of the base spec (vector components included): where NaN and infinities go
NUMBER_PATHS = [p for p in PATHS if isinstance(_get(p), (int, float)) and not isinstance(_get(p), bool)]

hostile_scalars = st.sampled_from([NAN, INF, -INF, 0, -1, -0.0, 1e-300, 1e10, 1e308, 10 ** 30, -(10 ** 30), 2.5,
                                   "abc", "", None, True, [], {}, [1, 2], [[]], [NAN, 0, 0], [0, 0, 0], [1e10, 0, 0],
                                   "../../x", "\x00", "é漢字🙂", "1e999", "mirror"])
hostile_values = st.one_of(hostile_scalars, st.floats(), st.integers(min_value=-2 ** 70, max_value=2 ** 70),
                           st.text(max_size=12), st.lists(st.floats(), max_size=4))
#: edits that keep the spec valid (the exit-0 side): extreme but allowed values, sensor effects
VALID_EDITS = [
    (("lights", 0, "intensity"), [0, 0, 0]), (("lights", 0, "intensity"), [1e9, 1e9, 1e9]),
    (("lights", 0, "inner_deg"), 28), (("background",), [0.2, 0.1, 0.0]), (("seed",), 2 ** 63 - 1),
    (("materials", "grey", "albedo"), [0, 0, 0]), (("materials", "grey", "albedo"), [1, 1, 1]),
    (("cameras", "train", 0, "ring", "elevation_deg"), -89), (("cameras", "train", 0, "ring", "distance"), 1e-3),
    (("cameras", "intrinsics", "fov_y_deg"), 179), (("cameras", "intrinsics", "dist"), [-0.3, 0.1, 0.001, 0, 0]),
    (("objects", 0, "shape", "box", "size"), [1e-6, 1e-6, 1e-6]), (("up",), [0, 0, 1e-6]),
    (("sensor",), {"noise": [1e6, 3], "exposure": 1e6}), (("sensor",), {"vignetting": [-0.9, 0], "distortion": True}),
    (("sensor",), {"noise": [1e-3, 0]}), (("effects",), ["direct"]), (("effects",), None),
    (("textures", "board", "charuco", "dictionary"), "DICT_APRILTAG_16h5"),
]
hostile_names = st.one_of(
    st.sampled_from(["../../../escaped_view", "/tmp/abs", ".", "..", ".hidden", "a/b", "a\\b", "x" * 101,
                     "train_000", "test_000", "ok_name", "vue_été_视图", "nul\x00", "new\nline", "with space", ""]),
    st.text(max_size=20), st.from_regex(r"[A-Za-z0-9_\-éß视図]{1,12}", fullmatch=True))
# a view's eye and target: the first of each (where hypothesis starts and shrinks to) make a valid view
eyes = st.sampled_from([[0.6, -0.5, 0.4], [-0.4, 0.5, 0.3], [0, 0, 1.0], [0, 0, 0.05], [NAN, 0, 0], [1e10, 0, 0]])
targets = st.sampled_from([[0, 0, 0.05], [0.05, 0, 0], [0, 0, 0.05], [0.6, -0.5, 0.4], [0, INF, 0]])
image_sizes = st.sampled_from([(0, 24), (-1, 24), (16385, 24), (100_000, 100_000), (5000, 5000), ("abc", 24),
                               (32.5, 24), (1, 1), (3, 2), (48, 8)])
counts = st.sampled_from([0, -1, 1, 3, 20_001, 10 ** 7, 10 ** 12, 2.5, "many", None])
MESH_FILES = ["tetra.obj", "missing.obj", "folder.obj", "garbage.obj", "nan.obj", "flat.obj", "noface.obj",
              "huge.obj", "", "nul\x00.obj", "/etc/hostname"]
TEXTURE_FILES = ["valid.png", "missing.png", "folder.png", "garbage.png", "truncated.png", "wide.png",
                 "skimage:download_all", "skimage:camera"]
EMPTY_PATHS = [("objects",), ("lights",), ("materials",), ("textures",), ("cameras", "train"), ("cameras", "test")]

structural = st.one_of(
    st.tuples(st.just("set"), st.sampled_from(PATHS), hostile_values),
    st.tuples(st.just("set"), st.sampled_from(NUMBER_PATHS), st.sampled_from([NAN, INF, -INF])),
    st.builds(lambda edit: ("set", *edit), st.sampled_from(VALID_EDITS)),
    st.tuples(st.just("delete"), st.sampled_from(PATHS)),
    st.tuples(st.just("image_size"), image_sizes),
    st.tuples(st.just("count"), st.sampled_from(["train", "test"]), counts),
    st.tuples(st.just("empty"), st.lists(st.sampled_from(EMPTY_PATHS), min_size=1, max_size=2)),
    st.tuples(st.just("mesh"), st.sampled_from(MESH_FILES), st.sampled_from([0.1, 1e-3, 1, 0, -1, NAN, INF, 1e9])),
    st.tuples(st.just("texture"), st.sampled_from(TEXTURE_FILES)),
    st.tuples(st.just("view"), hostile_names, eyes, targets),
)
RAW_KINDS = ["list", "scalar", "null", "empty", "comment", "bomb", "recursive", "duplicate_top", "duplicate_nested",
             "not_utf8", "tab_indent", "oversized", "bigint", "two_documents", "python_tag"]
cases = st.tuples(st.lists(structural, min_size=1, max_size=2),
                  st.one_of(st.none(), st.none(), st.none(), st.sampled_from(RAW_KINDS)),
                  st.sampled_from(["capture", "capture", "capture", "reference"]),
                  st.binary(min_size=1, max_size=256))


def _apply(spec: dict, mutation: tuple) -> None:
    kind = mutation[0]
    if kind in ("set", "delete"):
        parent = spec
        for k in mutation[1][:-1]:
            if not isinstance(parent, (dict, list)) or (isinstance(parent, list) and not
                                                         (isinstance(k, int) and k < len(parent))) or \
                    (isinstance(parent, dict) and k not in parent):
                return  # an earlier mutation removed or replaced this path
            parent = parent[k]
        last = mutation[1][-1]
        if isinstance(parent, dict) or (isinstance(parent, list) and isinstance(last, int) and last < len(parent)):
            if kind == "set":
                parent[last] = copy.deepcopy(mutation[2])
            elif isinstance(parent, dict):
                parent.pop(last, None)
            else:
                del parent[last]
    elif kind == "image_size":
        spec.setdefault("cameras", {})
        if isinstance(spec["cameras"], dict) and isinstance(spec["cameras"].get("intrinsics"), dict):
            spec["cameras"]["intrinsics"].update(width=mutation[1][0], height=mutation[1][1])
    elif kind == "count":
        try:
            spec["cameras"][mutation[1]][0]["ring"]["count"] = mutation[2]
        except (KeyError, IndexError, TypeError):
            pass
    elif kind == "empty":
        for path in mutation[1]:
            parent = spec
            for k in path[:-1]:
                parent = parent.get(k, {}) if isinstance(parent, dict) else {}
            if isinstance(parent, dict):
                parent[path[-1]] = {} if path[-1] in ("materials", "textures") else []
    elif kind == "mesh":
        if isinstance(spec.get("objects"), list):
            spec["objects"].append({"name": "mesh", "material": "grey", "subject": True, "shape": {"mesh": {
                "file": mutation[1], "scale": mutation[2], "translate": [0, 0, 0.05]}}})
    elif kind == "texture":
        if isinstance(spec.get("textures"), dict):
            spec["textures"]["photo"] = mutation[1]
    elif kind == "view":
        cams = spec.get("cameras")
        if isinstance(cams, dict) and isinstance(cams.get("test", []), list):
            cams.setdefault("test", []).append({"view": {"name": mutation[1], "eye": mutation[2],
                                                         "target": mutation[3]}})


def _bomb() -> str:
    lines = ["lol0: &lol0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    lines += [f"lol{i}: &lol{i} [" + ", ".join([f"*lol{i - 1}"] * 10) + "]" for i in range(1, 10)]
    return "\n".join(lines) + "\n"


def _raw(text: str, kind: str | None) -> bytes:
    """The spec file's bytes: the dumped spec, or a whole-file transformation of it."""
    replaced = {"list": "- a\n- b\n", "scalar": "42\n", "null": "~\n", "empty": "", "comment": "# nothing\n"}
    if kind in replaced:
        return replaced[kind].encode()
    extra = {
        "bomb": lambda t: _bomb() + t,
        "recursive": lambda t: "loop: &loop [*loop]\n" + t,
        "duplicate_top": lambda t: t + "name: again\n",
        "duplicate_nested": lambda t: t.replace("type: lambertian", "type: lambertian\n    type: mirror", 1),
        "tab_indent": lambda t: t.replace("\n  ", "\n\t", 1),
        "oversized": lambda t: t + "description: '" + "x" * (4 * 2 ** 20) + "'\n",
        "bigint": lambda t: t + "seed: " + "9" * 5000 + "\n",
        "two_documents": lambda t: t + "---\n" + t,
        "python_tag": lambda t: t + "description: !!python/object/apply:os.system [echo]\n",
    }
    if kind == "not_utf8":
        return text.encode() + b"description: caf\xe9\n"
    return (extra[kind](text) if kind else text).encode()


def must_refuse(mutations, raw_kind) -> str | None:
    """Why the case's spec must be refused (exit 2), judged independently of rig.spec; None when
    it may be valid. Every whole-file transformation is refusable; so is a NaN or an infinity
    anywhere in the document (no field of a spec accepts one), and a view name that is a path."""
    if raw_kind is not None:
        return f"whole-file {raw_kind}"
    spec = copy.deepcopy(BASE)
    for m in mutations:
        _apply(spec, m)

    def walk(node):
        if isinstance(node, float) and not math.isfinite(node):
            yield f"non-finite number {node}"
        elif isinstance(node, dict):
            for k, v in node.items():
                if k == "name" and isinstance(v, str) and isinstance(node.get("eye"), list) and \
                        ("/" in v or "\\" in v or v.startswith(".") or v == "" or "\x00" in v):
                    yield f"view name {v!r} is a path"
                yield from walk(v)
        elif isinstance(node, list):
            for v in node:
                yield from walk(v)

    return next(walk(spec), None)


def write_case(folder: Path, mutations, raw_kind, garbage: bytes) -> Path:
    """The case's scene folder: the spec file and the files it may name."""
    from PIL import Image

    scene = folder / "scene"
    scene.mkdir(parents=True)
    (scene / "folder.obj").mkdir()
    (scene / "folder.png").mkdir()
    (scene / "garbage.obj").write_bytes(garbage)
    (scene / "garbage.png").write_bytes(garbage)
    (scene / "tetra.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    (scene / "nan.obj").write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    (scene / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    (scene / "noface.obj").write_text("v 0 0 0\n")
    (scene / "huge.obj").write_text("v 0 0 0\nv 1e300 0 0\nv 0 1 0\nf 1 2 3\n")
    Image.new("RGB", (8, 8), (200, 100, 50)).save(scene / "valid.png")
    (scene / "truncated.png").write_bytes((scene / "valid.png").read_bytes()[:40])
    Image.new("1", (9000, 1)).save(scene / "wide.png")
    spec = copy.deepcopy(BASE)
    for m in mutations:
        _apply(spec, m)
    text = yaml.safe_dump(spec, sort_keys=False, allow_unicode=True)
    (scene / SPEC_NAME).write_bytes(_raw(text, raw_kind))
    return scene / SPEC_NAME


# ---------------------------------------------------------------- running a case
class _CaseTimeout(BaseException):
    pass


@contextlib.contextmanager
def _time_limit(seconds: float):
    """Interrupt the case when the interpreter next runs Python after ``seconds``."""
    def expire(signum, frame):
        raise _CaseTimeout(f"case ran longer than {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


@contextlib.contextmanager
def _stderr_lines():
    """Everything written to stderr, by Python (sys.stderr, warnings) or native code (fd 2)."""
    lines: list[str] = []
    sys.stderr.flush()
    saved = os.dup(2)
    text = io.StringIO()
    with tempfile.TemporaryFile() as native, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        os.dup2(native.fileno(), 2)
        try:
            with contextlib.redirect_stderr(text), contextlib.redirect_stdout(io.StringIO()):
                yield lines
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            native.seek(0)
            out = text.getvalue() + native.read().decode("utf-8", "replace")
            lines += [ln for ln in out.splitlines() if ln.strip()]
            lines += [f"{w.category.__name__}: {w.message}" for w in caught]


def _args(command: str, spec: Path, out: Path) -> list[str]:
    if command == "reference":
        return ["reference", str(spec), "--spp", "1", "--size", "16", "12", "--out", str(out), "--quiet",
                "--workers", "0"]
    return ["capture", str(spec), "--out", str(out), "--quiet", "--workers", "0"]


def run_in_process(args: list[str]) -> tuple[int | str, list[str]]:
    """(exit code, or 'exception: ...' for what the real CLI would exit 1 with; stderr lines)."""
    with _stderr_lines() as lines:
        try:
            with _time_limit(CASE_TIMEOUT_S):
                rc = main(args)
        except KeyboardInterrupt:
            raise
        except BaseException as exc:
            rc = f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]}"
    return rc, lines


def _limit_memory():
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE_LIMIT, ADDRESS_SPACE_LIMIT))


def run_process(args: list[str]) -> tuple[int | str, list[str]]:
    """The real ``lumigraph`` process, its address space bounded by ADDRESS_SPACE_LIMIT."""
    env = {**os.environ, "PYOPENGL_PLATFORM": os.environ.get("PYOPENGL_PLATFORM", "egl")}
    try:
        proc = subprocess.run([sys.executable, "-m", "pipeline", *args], capture_output=True, text=True,
                              timeout=PROCESS_TIMEOUT_S, preexec_fn=_limit_memory, env=env)
    except subprocess.TimeoutExpired:
        return f"timeout after {PROCESS_TIMEOUT_S} s", []
    return proc.returncode, [ln for ln in proc.stderr.splitlines() if ln.strip()]


def _tree(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def check_outcome(rc, lines: list[str], spec: Path, out: Path, root: Path, before: set[str], command: str,
                  refuse: str | None = None) -> str:
    """Judge one case (assert); ``refuse``: why it must exit 2 (must_refuse). Returns "exit 0" or "exit 2"."""
    after = _tree(root)
    assert rc in (0, 2), f"exit {rc!r} (a traceback in the real CLI); stderr: {lines[-3:]}"
    assert rc == 2 or refuse is None, f"exit 0 although the spec has a {refuse}"
    if rc == 2:
        assert len(lines) == 1, f"exit 2 must print one line, got {lines}"
        prefix = f"lumigraph: error: {spec}: "
        assert lines[0].startswith(prefix), f"the line must name the spec file: {lines[0]!r}"
        assert _NAMES_A_FIELD.match(lines[0][len(prefix):]), f"the line must name a field: {lines[0]!r}"
        assert after == before, f"exit 2 wrote {sorted(after - before)[:5]}"
        return "exit 2"
    written = {str(p) for p in after - before}
    outside = {p for p in written if not (root / p).resolve().is_relative_to(out.resolve())}
    assert not outside, f"written outside --out: {sorted(outside)[:5]}"
    check_finite_stage(out, command)
    return "exit 0"


def check_finite_stage(out: Path, command: str) -> None:
    """Every view of the finished stage has a finite linear image (and variance for a reference)."""
    import json

    from render.image_io import read_exr

    names = [c["name"] for c in json.loads((out / "cameras.json").read_text())["cameras"]] \
        if command == "capture" else [p.stem for p in (out / "linear").glob("*.exr")]
    assert names, "a finished stage with no views"
    kinds = ("linear", "depth") if command == "capture" else ("linear", "variance")
    for name in names:
        for kind in kinds:
            image = read_exr(out / kind / f"{name}.exr")
            assert np.all(np.isfinite(image)), f"{kind}/{name}.exr is not finite"


def _case_dir(root: Path, index: int) -> Path:
    # three levels deep, so '../../../x' from <out>/images still lands inside ``root``
    return root / "l1" / "l2" / f"case_{index}"


# ---------------------------------------------------------------- the generated cases
@pytest.fixture(scope="module")
def fuzz_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzz")
    yield root
    print(f"\nfuzz_specs: seed {SEED}, {COUNTS['cases']} cases tried (in process {COUNTS['in process']}, "
          f"subprocess {COUNTS['subprocess']}): exit 0 {COUNTS['exit 0']}, exit 2 {COUNTS['exit 2']}, "
          f"other {COUNTS['other']}")


@seed(SEED)
@settings(max_examples=MAX_EXAMPLES, deadline=None, database=None, print_blob=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                 HealthCheck.data_too_large, HealthCheck.large_base_example])
@given(case=cases)
def test_generated_specs_exit_0_with_finite_images_or_2_with_one_line(fuzz_root, case):
    mutations, raw_kind, command, garbage = case
    index = COUNTS["cases"]
    folder = _case_dir(fuzz_root, index)
    spec = write_case(folder, mutations, raw_kind, garbage)
    out = folder / "out"
    before = _tree(fuzz_root)
    COUNTS["cases"] += 1
    COUNTS["in process"] += 1
    COUNTS["other"] += 1  # until judged
    rc, lines = run_in_process(_args(command, spec, out))
    if os.environ.get("FUZZ_VERBOSE"):  # one line per case, to see what the seed generates
        print(f"\n{command} exit {rc} {lines[:1]} <- {mutations} {raw_kind}"[:500])
    try:
        COUNTS[check_outcome(rc, lines, spec, out, fuzz_root, before, command, must_refuse(mutations, raw_kind))] += 1
        COUNTS["other"] -= 1
    finally:
        shutil.rmtree(folder.parent.parent, ignore_errors=True)
        for p in fuzz_root.iterdir():  # anything a broken case left behind
            shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink()


# ---------------------------------------------------------------- a fixed subset, through the real process
SUBPROCESS_CASES = {
    "valid capture": ([], None, "capture", 0),
    "valid reference": ([], None, "reference", 0),
    "unicode view name": ([("view", "vue_été_视图", [0.6, -0.5, 0.4], [0, 0, 0.05])], None, "capture", 0),
    "NaN box centre": ([("set", ("objects", 0, "shape", "box", "center"), [NAN, 0, 0.05])], None, "capture", 2),
    "100000 x 100000 image": ([("image_size", (100_000, 100_000))], None, "reference", 2),
    "ring of 10^7 views": ([("count", "train", 10 ** 7)], None, "capture", 2),
    "garbage mesh": ([("mesh", "garbage.obj", 0.1)], None, "capture", 2),
    "alias bomb": ([], "bomb", "capture", 2),
    "not UTF-8": ([], "not_utf8", "reference", 2),
    "duplicate key": ([], "duplicate_nested", "capture", 2),
}


@pytest.mark.parametrize("name", list(SUBPROCESS_CASES))
def test_fixed_hostile_specs_through_the_real_process(fuzz_root, name):
    mutations, raw_kind, command, expected = SUBPROCESS_CASES[name]
    root = fuzz_root / f"proc_{name.replace(' ', '_').replace('^', '')}"
    folder = _case_dir(root, 0)
    spec = write_case(folder, mutations, raw_kind, b"\x00garbage\xff" * 20)
    out = folder / "out"
    before = _tree(root)
    COUNTS["cases"] += 1
    COUNTS["subprocess"] += 1
    rc, lines = run_process(_args(command, spec, out)[:-2])  # default workers, as a user runs it
    try:
        outcome = check_outcome(rc, lines, spec, out, root, before, command, must_refuse(mutations, raw_kind))
    except AssertionError:
        COUNTS["other"] += 1
        raise
    COUNTS[outcome] += 1
    assert outcome == f"exit {expected}"


# ---------------------------------------------------------------- path traversal through view names
@pytest.mark.parametrize("command", ["capture", "reference"])
@pytest.mark.parametrize("view_name", ["../../../escaped_view", "/tmp/abs"])
def test_view_name_cannot_write_outside_or_inside_out(tmp_path, command, view_name):
    """A view named like a path used to make capture and reference write '<that path>.png/.exr'
    and exit 0. Now the spec refuses it when it loads: exit 2, one line naming the field,
    nothing written outside or inside --out."""
    folder = _case_dir(tmp_path, 0)
    spec = write_case(folder, [("view", view_name, [0.6, -0.5, 0.4], [0, 0, 0.05])], None, b"x")
    out = folder / "out"
    absolute = [Path(view_name + suffix) for suffix in (".png", ".exr")] if view_name.startswith("/") else []
    existed = {p: p.exists() and p.stat().st_mtime_ns for p in absolute}
    before = _tree(tmp_path)
    rc, lines = run_process(_args(command, spec, out)[:-2])  # default workers, as a user runs it
    assert rc == 2, lines
    assert len(lines) == 1 and "cameras.test.1.view.name" in lines[0] and SPEC_NAME in lines[0], lines
    assert _tree(tmp_path) == before and not out.exists()
    assert {p: p.exists() and p.stat().st_mtime_ns for p in absolute} == existed


def test_spec_at_its_sensor_and_radiometric_bounds_captures_finite_images(tmp_path):
    """Every bound at once, all allowed: noise gain 1e6 photons per unit radiance, exposure 1e6,
    intensity 1e9. Photon means reach ~1e20, past numpy's Poisson sampler (~9.2e18): the sensor
    draws the Gaussian limit there instead of failing (exit 1 before)."""
    spec = copy.deepcopy(BASE)
    spec["sensor"] = {"noise": [1e6, 3], "exposure": 1e6}
    spec["lights"][0]["intensity"] = [1e9, 1e9, 1e9]
    path = tmp_path / "scene" / SPEC_NAME
    path.parent.mkdir()
    path.write_text(yaml.safe_dump(spec))
    rc, lines = run_in_process(_args("capture", path, tmp_path / "out"))
    assert rc == 0, (rc, lines)
    check_finite_stage(tmp_path / "out", "capture")
