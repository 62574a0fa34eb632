"""``python -m thesis_repro.bench [NAME ...] [--list]`` (= ``make bench``): run the registered benchmarks."""

from __future__ import annotations

import argparse
import sys

from thesis_repro.bench import BENCHMARKS, run


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m thesis_repro.bench", description=__doc__)
    parser.add_argument("names", nargs="*", help=f"benchmarks to run (default: all of {', '.join(BENCHMARKS)})")
    parser.add_argument("--list", action="store_true", help="list the registered benchmarks and exit")
    args = parser.parse_args(argv)
    if args.list:
        for name, target in BENCHMARKS.items():
            print(f"{name:12s} {target}")
        return 0
    try:
        results = run(args.names or None)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    from thesis_repro.throughput import write_throughput  # the cost plan (`python -m thesis_repro plan`) reads it

    written = write_throughput(results)
    if written is not None:
        print(f"throughput per learner family (steps per CPU-second) -> {written}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
