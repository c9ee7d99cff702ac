"""`make bench`: run every bench/bench_*.py in turn; each writes bench/results/<name>.json."""
from __future__ import annotations

import importlib
import sys
import time
from pathlib import Path


def main(argv: list[str]) -> int:
    names = argv or sorted(p.stem for p in Path(__file__).parent.glob("bench_*.py"))
    failed = []
    for name in names:
        print(f"== {name}", flush=True)
        t0 = time.perf_counter()
        saved = sys.argv
        sys.argv = [f"bench.{name}"]  # a benchmark's argparse must see its defaults, not run_all's names
        try:
            importlib.import_module(f"bench.{name}").main()
        except (Exception, SystemExit) as exc:  # keep going: one broken benchmark must not hide the others
            print(f"{name} failed: {type(exc).__name__}: {exc}", file=sys.stderr)
            failed.append(name)
        finally:
            sys.argv = saved
        print(f"== {name} done in {time.perf_counter() - t0:.1f} s", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
