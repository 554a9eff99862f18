"""``python -m bench [NAME ...] [OPTIONS]``: run every benchmark module (or the named ones) in
turn. A name may leave out ``bench_``; the options (from the first ``-``) go to each one named."""

from __future__ import annotations

import importlib
import pkgutil
import sys
import time
from pathlib import Path


def main(argv: list[str]) -> int:
    here = Path(__file__).parent
    cut = next((k for k, a in enumerate(argv) if a.startswith("-")), len(argv))
    given, options = argv[:cut], argv[cut:]
    names = ["bench_" + n.removeprefix("bench.").removeprefix("bench_") for n in given] or sorted(
        m.name for m in pkgutil.iter_modules([str(here)]) if m.name.startswith("bench_")
    )
    for name in names:
        print(f"\n=== {name} ===", flush=True)
        start = time.perf_counter()
        module = importlib.import_module(f"bench.{name}")
        sys.argv = [f"bench.{name}", *options]  # its own parser sees the options, not the names
        module.main()
        print(f"({name}: {time.perf_counter() - start:.1f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
