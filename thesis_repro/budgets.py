"""Are a scale's training runs in the trained regime? Learning-curve statistics of every training run.

Issue 7's rule: at ``small`` a policy should be near its plateau, i.e. its training return at least ~70 %
of what the same learner reaches at the thesis's 4e6 steps, or of the thesis's own reported training
return where it gives one (Table 3.3a: Walker2d, PPO and its noise-trained variants). Where the thesis
gives no training return we cannot afford 4e6-step runs to compare with, so the return at 4e6 is
extrapolated from the run's own curve, log-linearly: the growth between half the budget and the end
continues for every further doubling of the steps (:func:`extrapolate`). Learning curves saturate, so
this over-estimates the 4e6 return and the judgement errs towards "still learning".

``python -m thesis_repro budgets --scale small`` prints one row per training run that is cached or
shipped (nothing is trained), read from its recorded curve.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro import figures, reference, runs
from thesis_repro.cache import Job, RunCache

#: Table 3.3a's rows (``noise_type``) as the kit's learner ids: the thesis's Walker2d training returns.
TABLE_3_3A_ALGOS: dict[str, str] = {
    "none": "ppo",
    "obs": "ppo-obsnoise",
    "act": "ppo-actnoise",
    "env": "ppo-envnoise",
    "mdl": "ppo-mdl",
}
#: Fraction of the thesis's training return that counts as trained (issue 7).
TRAINED_FRACTION = 0.7
#: Largest reward of one step where the task bounds it (Gymnasium v5): InvertedPendulum +1 per step alive;
#: InvertedDoublePendulum its alive bonus 10 minus non-negative distance/velocity penalties. An episode
#: cannot return more than this times its length, so extrapolations are capped there.
REWARD_BOUND: dict[str, float] = {"InvertedPendulum": 1.0, "InvertedDoublePendulum": 10.0}
#: The thesis's training budget of every chapter-3/4 run (read from the ``full`` scale of Fig 3.3).
THESIS_STEPS: int = figures.thesis_budget("3.3")


def thesis_training_returns() -> dict[tuple[str, str], float]:
    """``{(algo, env): mean training return}`` the thesis reports (Table 3.3a, Walker2d at 4e6 steps).

    >>> thesis_training_returns()[("ppo", "Walker2d")]
    3128.6
    """
    table = reference.load("table3_3a")
    return {(TABLE_3_3A_ALGOS[r.noise_type], "Walker2d"): float(r["mean"]) for _, r in table.iterrows()}


def window_mean(t: np.ndarray, r: np.ndarray, lo: float, hi: float) -> float:
    """Mean of the returns ``r`` of the episodes that ended at ``lo < t <= hi`` (NaN if none).

    >>> window_mean(np.array([1, 2, 3, 4]), np.array([10.0, 20.0, 30.0, 40.0]), 1, 3)
    25.0
    """
    t, r = np.asarray(t, float), np.asarray(r, float)
    sel = (t > lo) & (t <= hi) & np.isfinite(r)
    return float(r[sel].mean()) if sel.any() else float("nan")


def curve_stats(t: np.ndarray, r: np.ndarray, total: float, window: float = 0.1) -> dict[str, float]:
    """Return over the last ``window`` of the budget (``final``), over the window ending at half the budget
    (``half``), the relative growth between them (``gain`` = (final - half) / |final|) and the best return
    of any of the budget's ``window``-wide stretches (``peak``).

    >>> s = curve_stats(np.arange(1, 101), np.minimum(np.arange(1, 101), 50.0), 100)
    >>> s["final"], s["half"], s["gain"], s["peak"]
    (50.0, 45.5, 0.09, 50.0)
    """
    final = window_mean(t, r, (1 - window) * total, total)
    half = window_mean(t, r, (0.5 - window) * total, 0.5 * total)
    gain = (final - half) / abs(final) if np.isfinite(final) and np.isfinite(half) and final != 0 else float("nan")
    n = int(round(1 / window))
    stretches = [window_mean(t, r, k * window * total, (k + 1) * window * total) for k in range(n)]
    peak = max((v for v in stretches if np.isfinite(v)), default=float("nan"))
    return {"final": final, "half": half, "gain": gain, "peak": peak}


def extrapolate(final: float, half: float, steps: float, target: float = THESIS_STEPS) -> float:
    """Log-linear estimate of the return at ``target`` steps from the returns at ``steps / 2`` and ``steps``:
    the growth of the last doubling repeats for each of the log2(target / steps) doublings left (no
    growth assumed when the curve fell; ``final`` itself once ``steps >= target``).

    >>> extrapolate(1500.0, 1000.0, 1e6, 4e6)  # two more doublings of +500
    2500.0
    >>> extrapolate(1000.0, 1000.0, 2e5, 4e6), extrapolate(900.0, 1000.0, 1e6, 4e6)
    (1000.0, 900.0)
    """
    if not (np.isfinite(final) and np.isfinite(half)) or steps >= target:
        return float(final)
    return float(final + max(final - half, 0.0) * np.log2(target / steps))


def judge(
    final: float,
    half: float,
    steps: float,
    thesis: float | None,
    peak: float = float("nan"),
    ceiling: float = float("inf"),
) -> tuple[float, str]:
    """Fraction of the 4e6 return reached and the verdict: ``"trained"`` (>= :data:`TRAINED_FRACTION`),
    ``"still learning"``, or ``"fell from its peak"`` (the run once did better: PPO's collapses).

    The 4e6 return is the thesis's where given; else the larger of :func:`extrapolate` and the run's own
    ``peak`` (a learner given more steps does at least as well as it already did), at most ``ceiling``
    (the task's largest possible return).

    >>> judge(2500.0, 2000.0, 1e6, 3128.6)[1], judge(1500.0, 1000.0, 1e6, None)
    ('trained', (0.6, 'still learning'))
    >>> judge(2800.0, 5100.0, 1e6, None, peak=9000.0)
    (0.3111111111111111, 'fell from its peak')
    """
    if thesis is not None and np.isfinite(thesis):
        reference, fell = thesis, False
    else:
        grown = min(extrapolate(final, half, steps), ceiling)
        fell = bool(np.isfinite(peak) and peak > grown)
        reference = peak if fell else grown
    if not (np.isfinite(final) and np.isfinite(reference)) or reference <= 0:
        return float("nan"), "still learning"
    fraction = float(final / reference)
    if fraction >= TRAINED_FRACTION:
        return fraction, "trained"
    return fraction, "fell from its peak" if fell else "still learning"


def _curve(result: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    for t, r in (("episode_timesteps", "episode_returns"), ("curve_timesteps", "curve_return")):
        try:
            return np.asarray(result[t]), np.asarray(result[r])
        except KeyError:
            continue
    return np.array([]), np.array([])


def training_jobs(scale: str, figure_ids: Iterable[str] | None = None) -> list[Job]:
    """The deduplicated ``train`` jobs of the figures (all by default) at ``scale``, figure by figure
    (:func:`thesis_repro.runs.plan`, the reference-run generator's own list)."""
    return [p.job for p in runs.plan(scale, figure_ids, kinds=("train",), by_figure=True)]


def table(scale: str, figure_ids: Iterable[str] | None = None, cache: RunCache | None = None) -> pd.DataFrame:
    """One row per training run of ``scale`` with a cached or shipped result: algo, env, seed, timesteps,
    source, ``half``/``final`` return, ``gain``, the thesis's training return (where given), the
    ``fraction`` of the 4e6 return reached (thesis's, else extrapolated) and the verdict. Runs not trained
    yet are listed with ``source="missing"``."""
    cache = cache or RunCache()
    thesis = thesis_training_returns()
    rows = []
    for job in training_jobs(scale, figure_ids):
        c = job.config
        row: dict[str, Any] = {
            "algo": c["algorithm"],
            "env": c["env"],
            "seed": c["seed"],
            "timesteps": int(c["timesteps"]),
            "c_a": c.get("c_a"),
            "wind": None if c.get("wind") is None else tuple(c["wind"]),
        }
        result = cache.load(job)
        ref = thesis.get((c["algorithm"], c["env"])) if c.get("c_a") is None else None
        if result is None:
            rows.append({**row, "source": "missing"})
            continue
        stats = curve_stats(*_curve(result), total=row["timesteps"])
        bound = REWARD_BOUND.get(c["env"], float("inf")) * int(c.get("max_episode_steps") or 1000)
        fraction, verdict = judge(stats["final"], stats["half"], row["timesteps"], ref, stats["peak"], bound)
        rows.append(
            {
                **row,
                "source": result.source,
                **stats,
                "thesis_train": ref,
                "fraction": fraction,
                "verdict": verdict,
                "wall_s": runs.wall_seconds(result),
            }
        )
    return pd.DataFrame(rows)


def retrain_cost(scale: str, figure_ids: Iterable[str] | None = None, cache: RunCache | None = None) -> pd.DataFrame:
    """What ``RETRAIN=1`` costs per figure: its training runs, how many are finished (cached or shipped) and
    the sum of their measured wall times in core-hours (one core per run; measured while other work shared
    the machine, so upper bounds)."""
    cache = cache or RunCache()
    rows = []
    for fid in figure_ids or figures.ids():
        jobs = [j for j in figures.jobs(fid, scale) if j.kind == "train"]
        if not jobs:
            continue
        results = [cache.load(j) for j in jobs]
        done = [r for r in results if r is not None]
        rows.append(
            {
                "figure": figures.get(fid).notebook_id,
                "runs": len(jobs),
                "finished": len(done),
                "env_steps": sum(int(j.config["timesteps"]) for j in jobs),
                "core_hours": sum(runs.wall_seconds(r) for r in done) / 3600 if done else float("nan"),
            }
        )
    return pd.DataFrame(rows)


def render(frame: pd.DataFrame) -> str:
    """The table as aligned text (``-`` for missing values), with a one-line count of the verdicts."""
    if frame.empty:
        return "no training runs"
    shown = frame.copy()
    for col in ("half", "final", "peak", "thesis_train", "wall_s"):
        if col in shown:
            shown[col] = shown[col].map(lambda v: "-" if v is None or not np.isfinite(v) else f"{v:,.0f}")
    for col in ("gain", "fraction"):
        if col in shown:
            shown[col] = shown[col].map(lambda v: "-" if v is None or not np.isfinite(v) else f"{v:.0%}")
    text = shown.fillna("-").drop(columns=[c for c in ("c_a", "wind") if shown[c].isna().all()]).to_string(index=False)
    counts = frame["verdict"].value_counts().to_dict() if "verdict" in frame else {}
    missing = int((frame["source"] == "missing").sum())
    summary = ", ".join(f"{n} {v}" for v, n in sorted(counts.items())) or "none judged"
    return f"{text}\n{len(frame)} training runs: {summary}, {missing} not trained yet"
