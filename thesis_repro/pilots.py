"""Pilot runs: one seed of each candidate learner, trained part of the way, before any grid run is priced.

``ch4-readings`` (:data:`PILOTS`): every reading of chapter 4's aggregation step
(:data:`thesis_repro.mdl.readings.READINGS`) and its comparator params_avg, on Fig 4.1's panel a (Walker2d, c_a =
0.001, ξ ~ U(-0.5, 0.5)) at training seed 0 and every other setting of the `small` scale, for the first ``steps``
env steps of `small`'s run (the config's ``stop_at``: the learning-rate and clip-range schedules still run over
`small`'s budget, so a pilot is the start of the grid run, not a shorter run with a faster annealing).

Pilots are not grid runs and are never shipped: they are ordinary ``train`` jobs of the local run cache
(``THESIS_REPRO_DATA``). What is kept is a compact summary, ``data/reference/pilots/<name>.json``
(:func:`summary_path`): per pilot its config, provenance (commit, timesteps, seed, wall time) and the learner's
per-iteration diagnostics. :func:`pilot_table` turns it into the book's table.

    python -m thesis_repro.pilots ch4-readings [--steps 300000] [--algos kl-avg-ls ...]  # train what is missing
    python -m thesis_repro.pilots ch4-readings --summary                                # only write the summary

>>> [c["algorithm"] for c in pilot_configs("ch4-readings", 300_000)][:2]
['kl-avg', 'kl-avg-ls']
>>> pilot_configs("ch4-readings", 300_000)[0]["stop_at"], pilot_configs("ch4-readings", 300_000)[0]["seed"]
(300000, 0)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro import figures, paths
from thesis_repro.cache import Job, RunCache
from thesis_repro.figures import ch4
from thesis_repro.mdl.readings import READINGS, reading_ids
from thesis_repro.validation import check_choice

#: Pilot sets: name -> (figure, scale, panel, seed, learner ids).
PILOTS: dict[str, tuple[str, str, str, int, tuple[str, ...]]] = {
    "ch4-readings": ("4.1", "small", "a", 0, (*reading_ids(), "params-avg")),
}
#: The learner statistics kept per iteration (``curve_<name>`` of a training run), where the learner logs them.
SERIES: tuple[str, ...] = (
    "return",
    "entropy",
    "eq47",
    "eq47_params_avg",
    "step_fraction_mean",
    "step_fraction",
    "kl_params_avg",
    "cg_residual",
    "kl_bound",
    "kl_old",
)
#: A reading "reduces to params_avg" when its median step fraction is at most this.
REDUCES_BELOW = 0.01
#: Diverged: the late-third mean of the 5-iteration smoothed return below this fraction of its own peak, or a
#: non-finite return or entropy (the rule the chapter-4 claims use for a diverged run).
DIVERGED_FRACTION = 0.5


def pilot_configs(name: str, steps: int, algos: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """The training configs of pilot set ``name``: its figure's run config at its scale, stopped at ``steps``."""
    check_choice(name, list(PILOTS), "pilot set")
    figure, scale, panel, seed, all_algos = PILOTS[name]
    for a in algos or ():
        check_choice(a, all_algos, f"learner of pilot set {name!r}")
    settings = figures.settings(figure, scale)
    (cond,) = ch4.conditions(figure, [panel])
    return [ch4.run_config(settings, a, cond, seed, stop_at=int(steps)) for a in (algos or all_algos)]


def summary_path(name: str) -> Path:
    """Where pilot set ``name``'s summary is kept: ``data/reference/pilots/<name>.json``."""
    return paths.reference() / "pilots" / f"{name}.json"


def _compact(values: Any) -> list[float | None]:
    """A curve as JSON numbers with 6 significant digits (None where not finite)."""
    return [float(f"{v:.6g}") if np.isfinite(v) else None for v in np.asarray(values, dtype=float).ravel()]


def _entry(result: Any, cfg: Mapping[str, Any]) -> dict[str, Any]:
    prov = result.provenance
    series = {"timesteps": [int(t) for t in result["curve_timesteps"]]}
    series.update({s: _compact(result[f"curve_{s}"]) for s in SERIES if f"curve_{s}" in result})
    return {
        "algo": cfg["algorithm"],
        "key": result.key,
        "config": dict(cfg),
        "provenance": {
            "git_commit": prov.get("git_commit"),
            "git_dirty": prov.get("git_dirty"),
            "seed": cfg["seed"],
            "timesteps": int(result["timesteps_done"]),
            "stop_at": cfg.get("stop_at"),
            "wall_time": result.measured("wall_time"),
            "packages": prov.get("packages"),
        },
        "series": series,
    }


def write_summary(name: str, configs: Sequence[Mapping[str, Any]], cache: RunCache | None = None) -> Path:
    """Write pilot set ``name``'s summary from the finished runs of ``configs`` in the cache (others skipped)."""
    cache = cache or RunCache()
    figure, scale, panel, seed, _ = PILOTS[name]
    entries = []
    for cfg in configs:
        result = cache.load(Job("train", dict(cfg)))
        if result is not None:
            entries.append(_entry(result, cfg))
    doc = {"name": name, "figure": figure, "scale": scale, "panel": panel, "seed": seed, "pilots": entries}
    out = summary_path(name)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=None, separators=(",", ":")) + "\n")
    return out


def load_summary(name: str) -> dict[str, Any]:
    """The summary of pilot set ``name`` (``FileNotFoundError`` naming the command that writes it)."""
    check_choice(name, list(PILOTS), "pilot set")
    path = summary_path(name)
    if not path.exists():
        raise FileNotFoundError(f"no pilot summary {paths.shown(path)}; run `python -m thesis_repro.pilots {name}`")
    return json.loads(path.read_text())


def diverged(returns: Sequence[float | None], entropy: Sequence[float | None]) -> bool:
    """:data:`DIVERGED_FRACTION`'s rule on one run's per-iteration return and entropy.

    >>> diverged([1.0, 50.0, 100.0, 120.0, 130.0, 140.0], [1.0] * 6), diverged([50.0, 100, 90] + [1.0] * 9, [1.0] * 12)
    (False, True)
    """
    r = pd.Series(np.asarray(returns, dtype=float)).rolling(5, min_periods=1).mean().to_numpy()
    ent = np.asarray(entropy, dtype=float)
    if not len(r) or not np.isfinite(r).all() or not np.isfinite(ent).all():
        return True
    late, peak = float(np.mean(r[-max(1, len(r) // 3) :])), float(np.max(r))
    return bool(peak > 0 and late < DIVERGED_FRACTION * peak)


def pilot_table(doc: Mapping[str, Any]) -> pd.DataFrame:
    """One row per pilot of a summary: reading, whether it trains, its step fraction, its Eq 4.7 against
    params_avg's at the same iterations, its return at the end and its wall time."""
    names = {r.algo: r.name for r in READINGS}
    rows = []
    for p in doc["pilots"]:
        s = p["series"]
        eq47, ref = np.asarray(s.get("eq47", []), dtype=float), np.asarray(s.get("eq47_params_avg", []), dtype=float)
        ok = np.isfinite(eq47) & np.isfinite(ref) & (ref > 0)
        ratio = eq47[ok] / ref[ok]
        frac = np.asarray(s.get("step_fraction_mean", s.get("step_fraction", [])), dtype=float)
        frac = frac[np.isfinite(frac)]
        median_frac = float(np.median(frac)) if len(frac) else float("nan")
        bad = diverged(s["return"], s["entropy"])
        rows.append(
            {
                "learner": p["algo"],
                "reading": names.get(p["algo"], "comparator"),
                "trains": "diverged" if bad else "yes",
                "step fraction (median)": median_frac,
                "reduces to params_avg": bool(len(frac)) and median_frac <= REDUCES_BELOW,
                "Eq 4.7 / params_avg (median)": float(np.median(ratio)) if len(ratio) else float("nan"),
                "Eq 4.7 / params_avg (max)": float(np.max(ratio)) if len(ratio) else float("nan"),
                "iterations Eq 4.7 ≤ params_avg": float(np.mean(ratio <= 1.0)) if len(ratio) else float("nan"),
                "max Eq 4.7 (nats)": float(np.nanmax(eq47)) if np.isfinite(eq47).any() else float("nan"),
                "final return": s["return"][-1],
                "env steps": p["provenance"]["timesteps"],
                "wall time (min)": (p["provenance"]["wall_time"] or float("nan")) / 60,
            }
        )
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> int:
    """Train the missing pilots of a set one after another (``--summary``: none), then write its summary."""
    parser = argparse.ArgumentParser(prog="python -m thesis_repro.pilots", description=__doc__.split("\n")[0])
    parser.add_argument("name", help=f"pilot set: {', '.join(PILOTS)}")
    parser.add_argument("--steps", type=int, default=300_000, help="env steps of each pilot (default 300000)")
    parser.add_argument("--algos", nargs="+", default=None, help="only these learners of the set")
    parser.add_argument("--summary", action="store_true", help="write the summary of the finished pilots only")
    args = parser.parse_args(argv)
    try:
        configs = pilot_configs(args.name, args.steps, args.algos)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    everything = pilot_configs(args.name, args.steps)
    cache = RunCache()
    if not args.summary:
        for cfg in configs:
            t0 = time.time()
            res = cache.run(Job("train", cfg))
            print(f"{cfg['algorithm']}: {res.source}, {time.time() - t0:.0f} s", flush=True)
            write_summary(args.name, everything, cache)
    print(paths.shown(write_summary(args.name, everything, cache)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
