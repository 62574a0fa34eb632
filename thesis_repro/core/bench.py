"""Registry of throughput benchmarks run by ``make bench`` (``python -m thesis_repro bench``).

A benchmark is a zero-argument function named by ``"package.module:function"`` in :data:`BENCHMARKS`.
It may print its own lines and returns a dict of measured values (printed as ``name.key = value``) or
``None``. Entries whose module is not importable yet are reported as missing, never as failures.
To add yours, add one line to :data:`BENCHMARKS` (small edit) or call :func:`register_benchmark` at import time.
Each benchmark lives beside what it measures, so a ``bench`` module is always a throughput benchmark:
``learners/bench.py`` (training, the multi-domain learners too), ``arm/bench.py`` (the arm simulator)
and ``evaluation/bench.py`` (the evaluator); this module only registers and runs them.

>>> run_benchmarks(["nope"])  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
ValueError: unknown benchmark 'nope'; valid benchmarks are: ...
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from thesis_repro.core.validation import check_choice

#: name -> "module:function". Order = run order.
BENCHMARKS: dict[str, str] = {
    "evaluation": "thesis_repro.evaluation.bench:bench_evaluation",  # chapter 3: batched evaluator vs predict/raw
    "training": "thesis_repro.learners.bench:bench_training",  # chapter 3: PPO training throughput
    "generator-path": "thesis_repro.learners.bench:bench_generator_path",  # SAC/DDPG: the training job's extras
    "sac-stack": "thesis_repro.learners.bench:bench_sac_stack",  # SAC: one stacked actor forward vs two
    "multidomain": "thesis_repro.learners.bench:bench_multidomain",  # chapter 4: multi-domain iteration vs PPO
    "arm": "thesis_repro.arm.bench:bench_arm",  # chapter 5: vectorised arm simulator
}


#: the target lines (:func:`target_line`) printed during the current :func:`run_benchmarks`, repeated as its summary
TARGET_LINES: list[str] = []


def target_line(label: str, measured: str, ratio: float, target: float) -> float:
    """Print and record one ``label: measured = ratio (target >= t: met | NOT met)`` line; returns ``ratio``.

    >>> r = target_line("PPO", "30 vs 10 steps/s", 3.0, 3.0)
      PPO: 30 vs 10 steps/s = 3.00x (target >= 3x: met)
    >>> _ = TARGET_LINES.pop()
    """
    met = "met" if ratio >= target else "NOT met"
    line = f"{label}: {measured} = {ratio:.2f}x (target >= {target:g}x: {met})"
    print(f"  {line}", flush=True)
    TARGET_LINES.append(line)
    return float(ratio)


def register_benchmark(name: str, target: str) -> None:
    """Add (or replace) benchmark ``name`` -> ``"module:function"``."""
    if ":" not in target:
        raise ValueError(f"benchmark target must look like 'package.module:function', got {target!r}")
    BENCHMARKS[name] = target


def benchmark_function(name: str) -> Callable[[], Mapping[str, Any] | None] | None:
    """The benchmark function, or ``None`` if its module (or function) does not exist yet."""
    module, func = BENCHMARKS[check_choice(name, BENCHMARKS, "benchmark")].split(":")
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as err:
        if err.name and module.startswith(err.name):  # the benchmark's own module is missing, not a dependency
            return None
        raise
    return getattr(mod, func, None)


def run_benchmarks(names: Iterable[str] | None = None) -> dict[str, Mapping[str, Any] | None]:
    """Run the named benchmarks (default: all) and print their results; missing ones get one clear line."""
    names = list(BENCHMARKS) if names is None else list(names)
    for n in names:
        check_choice(n, BENCHMARKS, "benchmark")
    results: dict[str, Mapping[str, Any] | None] = {}
    TARGET_LINES.clear()
    for name in names:
        fn = benchmark_function(name)
        if fn is None:
            print(f"[{name}] MISSING: {BENCHMARKS[name]} is not implemented yet (skipped)\n", flush=True)
            continue
        print(f"[{name}] {BENCHMARKS[name]}", flush=True)
        t0 = time.perf_counter()
        out = fn()
        results[name] = out
        for key, value in (out or {}).items():
            text = f"{value:,.3f}" if isinstance(value, float) else str(value)
            print(f"  {name}.{key} = {text}")
        print(f"[{name}] done in {time.perf_counter() - t0:.1f}s\n", flush=True)
    if TARGET_LINES:
        print("Targets (steps per CPU-second, ratios):")
        for line in TARGET_LINES:
            print(f"  {line}")
    return results
