"""Benchmark helpers: machine description, median timing, JSON output.

Benchmarks compare against a baseline measured in the same run (these machines are shared and
noisy): report medians and ratios, never absolute thresholds.
"""
from __future__ import annotations

import json
import os
import platform
import statistics
import time
from pathlib import Path

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def machine() -> dict:
    """What the figures were measured on."""
    info = {"platform": platform.platform(), "python": platform.python_version(),
            "processor": platform.processor() or platform.machine(), "cpus": os.cpu_count()}
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    info["cpu_model"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return info


def median_time(fn, repeats: int = 5, warmup: int = 1) -> tuple[float, list[float]]:
    """Run ``fn()`` ``warmup`` times, then ``repeats`` timed times; return (median s, all s)."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times


def write_result(name: str, figures: dict) -> Path:
    """Write ``bench/results/<name>.json`` with the machine and the figures; print it."""
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    out = RESULTS_DIR / f"{name}.json"
    payload = {"benchmark": name, "machine": machine(), "time": time.strftime("%Y-%m-%dT%H:%M:%S"), **figures}
    out.write_text(json.dumps(payload, indent=2))
    print(json.dumps(payload, indent=2))
    return out


def parse_flags(module: str, description: str, argv, flags: dict[str, str]):
    """A benchmark's on/off options (``flags``: option -> help) read with argparse: ``--help``
    answers, and an unknown or misspelt option exits 2 before any work starts (read by hand,
    ``--help`` once started a 20-minute run). argv None or empty: every flag off, as
    bench.run_all calls each ``main()``."""
    import argparse

    p = argparse.ArgumentParser(prog=f"python -m bench.{module}", description=description, allow_abbrev=False)
    for flag, text in flags.items():
        p.add_argument(flag, action="store_true", help=text)
    return p.parse_args(list(argv or []))
