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

    python -m thesis_repro.runs.pilots ch4-readings [--steps 300000] [--algos kl-avg-ls ...]  # train what is missing
    python -m thesis_repro.runs.pilots ch4-readings --summary                                # only write the summary
    python -m thesis_repro.runs.pilots ch4-readings --grid [--price] [--until HH:MM] [--jobs 2] [--commit]

``--grid`` makes the readings' grid runs (:func:`readings_grid_jobs`): every reading whose pilot trains and differs from
params_avg (:func:`grid_algos`), on every chapter-4 item that judges the readings, at `small`'s seeds, through the
reference-run generator (resumable, shipped as they land); ``--price`` prints their cost instead. The items list
them once they are shipped (``algos`` in ``config/scales.yaml``), so no page trains them.

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

from thesis_repro import figures
from thesis_repro.core import paths
from thesis_repro.core.cache import Job, RunCache
from thesis_repro.core.validation import check_choice
from thesis_repro.figures import ch4
from thesis_repro.learners import hyperparams
from thesis_repro.mdl.aggregate import LINE_SEARCH_FRACTIONS
from thesis_repro.mdl.readings import READINGS, Reading, reading_ids
from thesis_repro.runs.generator import Queued

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
#: Differences of log σ at most this (float64 rounding, amplified by CG) show as "rounding" on the page.
ROUNDING = 1e-12
#: A reading "reduces to params_avg" when its median step fraction is at most this, or when its median departure from
#: params_avg (its KL from params_avg over the sub-policies' mean KL to params_avg) is at most
#: :data:`SAME_AS_PARAMS_AVG`: then its aggregate is params_avg to float32 rounding, whatever fraction it took.
REDUCES_BELOW = 0.01
SAME_AS_PARAMS_AVG = 1e-6
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


#: The chapter-4 items whose claims are judged per reading (Fig 4.2's claim is visual).
GRID_ITEMS: tuple[str, ...] = ("4.1", "4.3", "4.4", "4.5", "4.6", "4.7")


def grid_algos(doc: Mapping[str, Any]) -> list[str]:
    """The readings of pilot summary ``doc`` that go to the grid: those that train and do not reduce to params_avg
    (:func:`pilot_table`), less the learners every chapter-4 item already trains (a reading listed on the items
    whose runs are all shipped stays in the grid until every item lists it: the generator skips what is shipped)."""
    table = pilot_table(doc)
    have = set.intersection(*(set(figures.get(f).settings("small").get("algos", ())) for f in GRID_ITEMS))
    keep = table[(table["trains"] == "yes") & (table["reduces to params_avg"] == False)]  # noqa: E712 (None: n/a)
    return [a for a in keep["learner"] if a in reading_ids() and a not in have]


def readings_grid_jobs(scale: str, algos: Sequence[str]) -> list[Queued]:
    """The jobs of ``algos`` on every :data:`GRID_ITEMS` item at ``scale`` (the item's own settings and seeds, so
    each is the job the item makes once it lists the learner), deduplicated; the training runs item by item, the
    items with the fewest runs first (an item is judged once all its runs are shipped), each item's runs cheapest
    first; then the evaluations. Items the figure registry does not hold are left out; no ``algos``, no jobs."""
    held = [f for f in GRID_ITEMS if f in figures.ids()] if algos else []
    out: dict[str, Queued] = {}
    for fid in held:
        for job in figures.jobs(fid, scale, algos=list(algos)):
            out.setdefault(job.key, Queued(job)).figures.append(figures.get(fid).notebook_id)
    items = [figures.get(f).notebook_id for f in held]
    runs = {f: sum(p.job.kind == "train" and p.figures[0] == f for p in out.values()) for f in items}
    first = {f: (n, i) for i, (f, n) in enumerate(runs.items())}
    return sorted(out.values(), key=lambda p: (p.job.kind != "train", first[p.figures[0]], p.cost, p.job.label))


def summary_path(name: str) -> Path:
    """Where pilot set ``name``'s summary is kept: ``data/reference/pilots/<name>.json``."""
    return paths.reference() / "pilots" / f"{name}.json"


def _compact(values: Any) -> list[float | None]:
    """A curve as JSON numbers with 8 significant digits, float32's precision (None where not finite)."""
    return [float(f"{v:.8g}") if np.isfinite(v) else None for v in np.asarray(values, dtype=float).ravel()]


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


def shipped_start(result: Any, cfg: Mapping[str, Any], cache: RunCache) -> dict[str, Any] | None:
    """How a pilot compares with the full run of the same config (without ``stop_at``) where that run is cached or
    shipped: its key, the iterations both have and the largest absolute difference of the training return and of
    Eq 4.7 over them (0: the pilot is that run's start, bit for bit). None when there is no such run."""
    full = {k: v for k, v in cfg.items() if k != "stop_at"}
    other = cache.load(Job("train", full))
    if other is None:
        return None
    mine, theirs = np.asarray(result["curve_timesteps"]), np.asarray(other["curve_timesteps"])
    common, i, j = np.intersect1d(mine, theirs, return_indices=True)
    diffs = {}
    for stat in ("return", "eq47"):
        if f"curve_{stat}" in result and f"curve_{stat}" in other:
            a, b = np.asarray(result[f"curve_{stat}"])[i], np.asarray(other[f"curve_{stat}"])[j]
            diffs[f"max_abs_diff_{stat}"] = float(np.nanmax(np.abs(a - b))) if len(common) else None
    return {"key": other.key, "source": other.source, "iterations": int(len(common)), **diffs}


def write_summary(name: str, configs: Sequence[Mapping[str, Any]], cache: RunCache | None = None) -> Path:
    """Write pilot set ``name``'s summary from the finished runs of ``configs`` in the cache (others skipped)."""
    cache = cache or RunCache()
    figure, scale, panel, seed, _ = PILOTS[name]
    entries = []
    for cfg in configs:
        result = cache.load(Job("train", dict(cfg)))
        if result is not None:
            entries.append({**_entry(result, cfg), "full_run": shipped_start(result, cfg, cache)})
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
        raise FileNotFoundError(
            f"no pilot summary {paths.shown(path)}; run `python -m thesis_repro.runs.pilots {name}`"
        )
    return json.loads(path.read_text())


def pilot_diverged(returns: Sequence[float | None], entropy: Sequence[float | None]) -> bool:
    """:data:`DIVERGED_FRACTION`'s rule on one run's per-iteration return and entropy.

    >>> pilot_diverged([1.0, 50.0, 100.0, 120.0, 130.0, 140.0], [1.0] * 6)
    False
    >>> pilot_diverged([50.0, 100, 90] + [1.0] * 9, [1.0] * 12)
    True
    """
    r = pd.Series(np.asarray(returns, dtype=float)).rolling(5, min_periods=1).mean().to_numpy()
    ent = np.asarray(entropy, dtype=float)
    if not len(r) or not np.isfinite(r).all() or not np.isfinite(ent).all():
        return True
    late, peak = float(np.mean(r[-max(1, len(r) // 3) :])), float(np.max(r))
    return bool(peak > 0 and late < DIVERGED_FRACTION * peak)


def _median(values: Sequence[float | None] | None) -> float:
    """Median of the finite values (NaN when there are none or no series)."""
    arr = np.asarray([np.nan if v is None else v for v in values or []], dtype=float)
    return float(np.median(arr[np.isfinite(arr)])) if np.isfinite(arr).any() else float("nan")


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
        departure = float("nan")
        if "kl_params_avg" in s:  # KL(params_avg ‖ aggregate) over the sub-policies' mean KL to params_avg
            kl = np.asarray([np.nan if v is None else v for v in s["kl_params_avg"]], dtype=float)
            spread = np.asarray([np.nan if v is None else v for v in s["eq47_params_avg"]], dtype=float)
            spread = spread / int(p["config"]["n_envs"])
            departure = _median(list(np.where(spread > 0, kl / np.where(spread > 0, spread, 1.0), np.nan)))
        limits = ((median_frac, REDUCES_BELOW), (departure, SAME_AS_PARAMS_AVG))
        small = [v <= limit for v, limit in limits if np.isfinite(v)]
        bad = pilot_diverged(s["return"], s["entropy"])
        full = p.get("full_run")
        same = None
        if full is not None:
            gaps = [v for k, v in full.items() if k.startswith("max_abs_diff_")]
            same = bool(full["iterations"]) and all(g == 0 for g in gaps)
        rows.append(
            {
                "learner": p["algo"],
                "reading": names.get(p["algo"], "comparator"),
                "trains": "diverged" if bad else "yes",
                "step fraction (median)": median_frac,
                "departure from params_avg (median)": departure,
                "reduces to params_avg": any(small) if small else None,
                "Eq 4.7 vs params_avg (median)": float(np.median(ratio - 1.0)) if len(ratio) else float("nan"),
                "Eq 4.7 vs params_avg (max)": float(np.max(ratio - 1.0)) if len(ratio) else float("nan"),
                "share of iterations with Eq 4.7 ≤ params_avg's": float(np.mean(ratio <= 1.0))
                if len(ratio)
                else float("nan"),
                "max Eq 4.7 (nats)": float(np.nanmax(eq47)) if np.isfinite(eq47).any() else float("nan"),
                "final return": s["return"][-1],
                "env steps": p["provenance"]["timesteps"],
                "wall time (min)": (p["provenance"]["wall_time"] or float("nan")) / 60,
                "= start of the full run": same,
            }
        )
    return pd.DataFrame(rows)


def update_text(reading: Reading) -> str:
    """A reading's ``update`` with its learner's settings filled in (``hyperparams.yaml``; the line search's
    smallest fraction from :data:`~thesis_repro.mdl.aggregate.LINE_SEARCH_FRACTIONS`).

    >>> update_text(READINGS[0])[:30]
    'Eq 4.11 by 10 CG iterations, d'
    """
    smallest = min(f for f in LINE_SEARCH_FRACTIONS if f > 0)
    return reading.update.format(**hyperparams(reading.algo)["sb3"], smallest_fraction=f"2^{int(np.log2(smallest))}")


#: The book page each pilot set's summary is rendered into (a static section of its chapter, see ``book.write_toc``).
PAGES: dict[str, str] = {"ch4-readings": "chapter-4-readings.md"}


def _fmt(value: Any, digits: int = 3) -> str:
    """A table cell: numbers with ``digits`` significant digits, NaN as an em dash, booleans as yes/no."""
    if value is None:
        return "—"
    if isinstance(value, bool | np.bool_):
        return "yes" if value else "no"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        return "—" if not np.isfinite(value) else f"{value:.{digits}g}"
    return str(value)


def _markdown(frame: pd.DataFrame, columns: Mapping[str, str] | None = None) -> str:
    """``frame`` as a Markdown table; ``columns``: only these columns, each under its shorter header (a table of a
    few short columns reads at a laptop's width without a column squeezed to a word)."""
    if columns is not None:
        frame = frame[list(columns)].rename(columns=dict(columns))
    head = "| " + " | ".join(frame.columns) + " |\n|" + "---|" * len(frame.columns) + "\n"
    return head + "".join("| " + " | ".join(_fmt(v) for v in row) + " |\n" for row in frame.itertuples(index=False))


#: The pilot table (:func:`pilot_table`) shown as three short tables: its columns under their headers on the page.
PILOT_VIEWS: tuple[tuple[str, dict[str, str]], ...] = (
    (
        "How each pilot trains, and how far its aggregate moves from params_avg:",
        {
            "learner": "learner",
            "trains": "trains",
            "step fraction (median)": "step fraction",
            "departure from params_avg (median)": "departure",
            "reduces to params_avg": "reduces to params_avg",
        },
    ),
    (
        "Eq 4.7 against params_avg's (the objective's ratio minus 1 over iterations, and its largest value):",
        {
            "learner": "learner",
            "Eq 4.7 vs params_avg (median)": "median",
            "Eq 4.7 vs params_avg (max)": "largest",
            "share of iterations with Eq 4.7 ≤ params_avg's": "share ≤ params_avg's",
            "max Eq 4.7 (nats)": "largest Eq 4.7 (nats)",
        },
    ),
    (
        "The runs:",
        {
            "learner": "learner",
            "final return": "final return",
            "env steps": "env steps",
            "wall time (min)": "wall time (min)",
            "= start of the full run": "= start of the full run",
        },
    ),
)


def reading_list() -> str:
    """The readings, one entry each: learner id and name, the thesis lines, the basis in the text and the update
    (a list: the basis and the update are sentences, which a table column would squeeze)."""
    return "".join(
        f"- `{r.algo}`, *{r.name}* (thesis l. {r.lines})\n  - basis in the text: {r.basis}\n"
        f"  - the update: {update_text(r)}\n"
        for r in READINGS
    )


def _at_steps(doc: Mapping[str, Any], marks: Sequence[int]) -> pd.DataFrame:
    """Per pilot, the training return and Eq 4.7 over params_avg's, minus 1, at the iterations nearest ``marks``."""
    rows = []
    for p in doc["pilots"]:
        s = p["series"]
        ts = np.asarray(s["timesteps"])
        row: dict[str, Any] = {"learner": p["algo"]}
        for m in marks:
            i = int(np.argmin(np.abs(ts - m)))
            ratio = np.nan
            if s.get("eq47") and s.get("eq47_params_avg"):
                e, r = s["eq47"][i], s["eq47_params_avg"][i]
                ratio = e / r - 1.0 if e is not None and r else np.nan
            row[f"return at {ts[i] // 1000}k"] = float("nan") if s["return"][i] is None else s["return"][i]
            row[f"Eq 4.7 vs params_avg at {ts[i] // 1000}k"] = ratio
        rows.append(row)
    return pd.DataFrame(rows)


def render_page(name: str, doc: Mapping[str, Any]) -> str:
    """The book page of pilot set ``name`` (``ch4-readings``), every number from ``doc`` or computed here."""
    from thesis_repro.mdl.readings import log_std_gaps  # local: the page's one computation (torch, seconds)

    check_choice(name, list(PAGES), "pilot set with a page")
    table = pilot_table(doc)
    names = {r.algo for r in READINGS}
    if doc["pilots"]:
        cfg = doc["pilots"][0]["config"]
        setting = (
            f"Fig {doc['figure']} panel {doc['panel']}: {cfg['env']}, c_a = {cfg['c_a']:g}, "
            f"wind ξ ~ U({cfg['wind'][0]:g}, {cfg['wind'][1]:g}), training seed {doc['seed']}, "
            f"the first {_fmt(cfg['stop_at'])} env steps of "
            f"`{doc['scale']}`'s {_fmt(cfg['timesteps'])}-step run (the same learning-rate and clip-range schedules), "
            f"N = {cfg['n_envs']} domains × T = {cfg['sb3']['n_steps']} steps per iteration"
        )
    else:
        setting = "no pilot has finished yet"
    commits = sorted({str(p["provenance"]["git_commit"])[:10] for p in doc["pilots"]})
    dirty = any(p["provenance"].get("git_dirty") for p in doc["pilots"])
    made_by = (", ".join(f"`{c}`" for c in commits) or "—") + (" (with uncommitted changes)" if dirty else "")
    verdicts = []
    groups: dict[str, list[str]] = {}
    comparator = table[~table["learner"].isin(names)]["max Eq 4.7 (nats)"]
    reference = float(comparator.iloc[0]) if len(comparator) else float("nan")
    for _, row in table.iterrows():
        if row["learner"] not in names:  # the comparator
            continue
        frac, change = row["step fraction (median)"], row["Eq 4.7 vs params_avg (median)"]
        took = f" (median step fraction {_fmt(frac)})" if np.isfinite(frac) else ""
        if row["trains"] != "yes":
            what = f"diverged{took}: not judged on its runs"
        elif row["reduces to params_avg"]:
            what = f"trains{took}, and reduces to params_avg (its claims are judged on params_avg's runs)"
        elif row["reduces to params_avg"] is None:
            what = "trains, and is not an Eq 4.11 step"
        else:
            what = f"trains{took}, and is distinct from params_avg"
        if row["trains"] == "yes" and not row["reduces to params_avg"]:
            what += (
                f"; its Eq 4.7 relative to params_avg's: {change:+.3g} (median), "
                f"{row['Eq 4.7 vs params_avg (max)']:+.3g} (largest); its largest Eq 4.7 "
                f"{_fmt(row['max Eq 4.7 (nats)'])} nats"
                + (f" (params_avg's pilot: {_fmt(reference)})" if np.isfinite(reference) else "")
            )
        verdicts.append(f"- `{row['learner']}` ({row['reading']}): {what}.")
        kind = "diverged" if row["trains"] != "yes" else "params_avg" if row["reduces to params_avg"] else "distinct"
        groups.setdefault(kind, []).append(f"`{row['learner']}`")
    heads = {
        "distinct": "train and differ from params_avg",
        "params_avg": "train but reduce to params_avg",
        "diverged": "diverge",
    }
    answer = "; ".join(f"{heads[k]}: {', '.join(groups[k])}" for k in heads if k in groups)
    answer = f"**The pilots (one seed each): {answer or 'none has finished yet'}.**"
    gaps = log_std_gaps()
    gap_rows = pd.DataFrame(
        [
            {"aggregate": k, "largest difference of log σ from params_avg's": "rounding" if v <= ROUNDING else v}
            for k, v in gaps.items()
        ]
    )
    marks = [100_000, 200_000, 300_000]
    along = _at_steps(doc, marks)
    returns = {c: c.removeprefix("return at ") for c in along.columns if c.startswith("return at ")}
    objective = {c: c.removeprefix("Eq 4.7 vs params_avg at ") for c in along.columns if c.startswith("Eq 4.7")}
    pilots_md = "\n".join(f"{head}\n\n{_markdown(table, cols)}" for head, cols in PILOT_VIEWS)
    return f"""# Chapter 4: readings of the update

{answer}

Chapter 4's method aggregates N sub-policies into the policy closest to them in KL (Eq 4.7, thesis l. 809),
replaces each KL by its quadratic expansion (Eq 4.8, l. 813) and solves that by conjugate gradient (Eq 4.10/4.11,
l. 855-859). The text leaves open the damping, the CG iterations, any step size, line search or trust region for
the aggregate, and whether log σ belongs to θ. Each reading below is a learner id of
`thesis_repro/config/hyperparams.yaml` that the kit trains like any other (`thesis_repro.mdl.readings`).

Generated by `python -m thesis_repro.runs.pilots {name} --summary` from `data/reference/pilots/{name}.json`
(the pilots' configs, provenance and per-iteration diagnostics); do not edit by hand.

## The readings and their basis in the thesis

{reading_list()}
Readings considered and not trained:

- *log σ outside θ* (l. 861 applies the update to "policy networks, of which the outputs are probabilistic
  distributions"): the same aggregate as every Fisher reading above, by the log-σ argument below.
- *Eq 4.10 undamped, CG to convergence*: the closed form of l. 855 read without the CG truncation of l. 859;
  the analysis page (why the literal Eq 4.11 does not beat parameter averaging) computes it and finds it further
  from the Eq 4.7 optimum than the damped step, so it is not piloted.

## The log-σ argument

The policy's log σ is a parameter independent of the state. Its block of the Fisher matrix (Eq 4.9) is 2·1 in
every sub-policy (Eq 4.9, l. 817), with no cross term to the mean network's parameters
(I = E_s[J_μᵀ Σ⁻¹ J_μ + 2 J_ℓᵀ J_ℓ]). So Eq
4.10/4.11 leave log σ at the sub-policies' plain mean, params_avg's, for any damping: Eq 4.11 cannot move the
policy's entropy away from params_avg's (the effect l. 956 reports). The line search and the diagonal Fisher keep
that log σ; the trust region's lies between θ_old's and it (a fraction of the same step). Only the exact
Eq 4.7 minimiser (kl_exact), which matches the sub-policies' moments, changes σ. Computed now on a small float64
policy (`thesis_repro.mdl.readings.log_std_gaps`; checked exactly in
`tests/test_ch4_readings.py::test_log_std_of_eq_4_11_is_params_avg_exactly`):

{_markdown(gap_rows)}
{{doc}}`Figure 4.7 <executed/fig-4.7>` checks the argument on the trained runs: a Fisher reading that takes full
steps should end at params_avg's entropy, and a trust region's entropy moves only by its step fraction.

## Pilots: one seed each, past the literal reading's collapse

Setting: {setting}. Kit commit(s): {made_by}.
Pilots are not grid runs and are not shipped: they stay in the local run cache (train them again with
`python -m thesis_repro.runs.pilots {name}`).

How to read the tables (wall times are of the shared development machine, beside other work):

- *trains*: "diverged" when the last third of the iterations' return (smoothed over 5 iterations) falls below
  half its own peak, or a return or entropy is not finite (the rule the chapter-4 claims use for a diverged run).
- *step fraction*: the median over iterations of the fraction of the reading's full Eq 4.11 step it took
  (the iteration's mean over its aggregations). The literal reading always takes the whole step (1); the line
  search's is the fraction of the Eq 4.11 correction added to params_avg (0: params_avg itself); the trust
  region's is the fraction of the step from θ_old to the Eq 4.11 aggregate (0: θ_old). The diagonal Fisher and
  kl_exact take no fraction of an Eq 4.11 step (—).
- *reduces to params_avg*: a median step fraction at most {_fmt(REDUCES_BELOW)}, or a median departure from
  params_avg (below) at most {_fmt(SAME_AS_PARAMS_AVG)}, i.e. params_avg to float32 rounding.
- *departure from params_avg*: the median over iterations of E_s KL(π_params_avg ‖ π_aggregate), logged by the
  readings the kit added, over the sub-policies' own mean KL to params_avg (Eq 4.7 at params_avg / N): how far
  the aggregate moves from params_avg, in units of how far the sub-policies are from it (0: it is params_avg).
- *= start of the full run*: where the `{doc["scale"]}` run of the same config is shipped or cached, whether the
  pilot's return and Eq 4.7 equal that run's at every iteration both have (— : no such run). A pilot is the start
  of its grid run, not a shorter run.
- *Eq 4.7 vs params_avg*: the true Eq 4.7 objective of the aggregate over params_avg's, minus 1, on the same
  sub-policies and states at the iteration's last aggregation (above 0: farther from the sub-policies than
  params_avg; the median and the largest over iterations).

{pilots_md}
Training return (mean of the last 100 episodes) along the way, at the env steps shown:

{_markdown(along, {"learner": "learner", **returns})}
Eq 4.7 against params_avg's (ratio minus 1) at the same steps:

{_markdown(along, {"learner": "learner", **objective})}
What the pilots say, reading by reading:

{chr(10).join(verdicts) or "- no pilot has finished yet."}
"""


def write_pilot_page(name: str) -> Path:
    """Render pilot set ``name``'s page from its summary into ``book/`` (:data:`PAGES`)."""
    out = paths.BOOK / PAGES[name]
    out.write_text(render_page(name, load_summary(name)))
    return out


def main(argv: list[str] | None = None) -> int:
    """Train the missing pilots of a set one after another (``--summary``: none), then write its summary."""
    parser = argparse.ArgumentParser(prog="python -m thesis_repro.runs.pilots", description=__doc__.split("\n")[0])
    parser.add_argument("name", help=f"pilot set: {', '.join(PILOTS)}")
    parser.add_argument("--steps", type=int, default=300_000, help="env steps of each pilot (default 300000)")
    parser.add_argument("--algos", nargs="+", default=None, help="only these learners of the set")
    parser.add_argument("--summary", action="store_true", help="write the summary of the finished pilots only")
    parser.add_argument("--grid", action="store_true", help="make the stable, distinct readings' grid runs instead")
    parser.add_argument("--price", action="store_true", help="with --grid: print the grid's cost, train nothing")
    parser.add_argument("--until", default=None, help="with --grid: start only jobs expected to end by HH:MM")
    parser.add_argument("--jobs", type=int, default=1, help="with --grid: jobs at a time (default 1)")
    parser.add_argument("--commit", action="store_true", help="with --grid: commit each run as it lands")
    args = parser.parse_args(argv)
    if args.grid:
        return _grid(args)
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
    if args.name in PAGES:
        print(paths.shown(write_pilot_page(args.name)))
    return 0


def _grid(args: argparse.Namespace) -> int:
    """``--grid``: price or make the readings' grid runs (:func:`readings_grid_jobs`) at `small`."""
    from thesis_repro.core.provenance import claims_design, platform_info
    from thesis_repro.runs import costs, generator, throughput
    from thesis_repro.runs.budget_study import check_design

    check_choice(args.name, tuple(PILOTS), "pilot set")
    if not args.price:
        check_design(claims_design())  # judged under design v3, frozen before the first grid run
    algos = grid_algos(load_summary(args.name))
    planned = readings_grid_jobs("small", algos)
    rates = throughput.shipped_rates(by_env=True, machine=platform_info())
    if args.price:
        print(f"readings to the grid (stable and distinct in their pilots): {', '.join(algos) or 'none'}")
        grid = costs.plan_jobs(f"{args.name} grid", [p.job for p in planned], "small", 2, rates, RunCache())
        print(costs.cost_report(grid, rates))
        return 0
    if not planned:
        print(f"the {args.name} grid is done: every chapter-4 item lists each stable, distinct reading")
        return 0
    until = generator.parse_until(args.until) if args.until is not None else None
    kinds = ("train", "evaluate")
    generator.generate("small", None, kinds, commit=args.commit, n_jobs=args.jobs, until=until, jobs=planned)
    return 0


if __name__ == "__main__":
    sys.exit(main())
