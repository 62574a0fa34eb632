"""Are a scale's training runs in the trained regime? Learning-curve statistics of every training run.

The trained-regime rule: at ``small`` a policy should be near its plateau, i.e. its training return at least ~70 %
of what the same learner reaches at the thesis's 4e6 steps, or of the thesis's own reported training
return where it gives one (Table 3.3a: Walker2d, PPO and its noise-trained variants). Where the thesis
gives no training return we cannot afford 4e6-step runs to compare with, so the return at 4e6 is
extrapolated from the run's own curve, log-linearly: the growth between half the budget and the end
continues for every further doubling of the steps (:func:`extrapolate`). Learning curves saturate, so
this over-estimates the 4e6 return and the judgement errs towards "still learning".

``python -m thesis_repro budgets --scale small`` prints one row per training run that is cached or
shipped (nothing is trained), read from its recorded curve. With ``--spread [--protocol thesis] [--at 1000000]
[--algos ppo sac] [--shipped-only]`` it prints the seed spread instead (:func:`spread`, :func:`render_spread`):
mean ± sd across training seeds per learner, task and setting, beside other projects' published numbers
(``data/public``).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro import figures
from thesis_repro.core import paths, thesis_numbers
from thesis_repro.core.cache import Job, RunCache
from thesis_repro.core.validation import check_choice
from thesis_repro.figures.ch3 import training_return_at
from thesis_repro.learners.config import ALGORITHMS, IDENTITY, PROTOCOLS, THESIS_PROTOCOL_KEYS, train_config
from thesis_repro.runs import layer as runs
from thesis_repro.runs.needs import needed
from thesis_repro.runs.study import study_jobs
from thesis_repro.runs.throughput import cost

#: Table 3.3a's rows (``noise_type``) as the kit's learner ids: the thesis's Walker2d training returns.
TABLE_3_3A_ALGOS: dict[str, str] = {
    "none": "ppo",
    "obs": "ppo-obsnoise",
    "act": "ppo-actnoise",
    "env": "ppo-envnoise",
    "mdl": "ppo-mdl",
}
#: Fraction of the thesis's training return that counts as trained.
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
    table = thesis_numbers.load("table3_3a")
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


def training_verdict(
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

    >>> training_verdict(2500.0, 2000.0, 1e6, 3128.6)[1], training_verdict(1500.0, 1000.0, 1e6, None)
    ('trained', (0.6, 'still learning'))
    >>> training_verdict(2800.0, 5100.0, 1e6, None, peak=9000.0)
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


def ordered_training_jobs(scale: str, figure_ids: Iterable[str] | None = None) -> list[Job]:
    """The deduplicated ``train`` jobs of the figures (all by default) at ``scale``, figure by figure
    (:func:`thesis_repro.runs.needs.needed`, the reference-run generator's own list, in its order: figure by
    figure, each figure's cheapest first)."""
    needs = needed(scale, figure_ids, kinds=("train",))
    return [n.job for n in sorted(needs, key=lambda n: (n.first, cost(n.job), n.job.kind, n.job.label, n.job.key))]


def table(scale: str, figure_ids: Iterable[str] | None = None, cache: RunCache | None = None) -> pd.DataFrame:
    """One row per training run of ``scale`` with a cached or shipped result: algo, env, seed, timesteps,
    source, ``half``/``final`` return, ``gain``, the thesis's training return (where given), the
    ``fraction`` of the 4e6 return reached (thesis's, else extrapolated) and the verdict. Runs not trained
    yet are listed with ``source="missing"``."""
    cache = cache or RunCache()
    thesis = thesis_training_returns()
    rows = []
    for job in ordered_training_jobs(scale, figure_ids):
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
        fraction, verdict = training_verdict(stats["final"], stats["half"], row["timesteps"], ref, stats["peak"], bound)
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


#: Columns naming a row's learner in the per-seed frames pages save for the claims layer (Fig 3.3 / Table 3.3).
LEARNER_COLUMNS: tuple[str, ...] = ("algo", "method")


def mark_trained(frames: Mapping[str, pd.DataFrame], runs_table: pd.DataFrame) -> dict[str, pd.DataFrame]:
    """``frames`` with a bool ``trained`` column on every frame that names its training run (a learner column of
    :data:`LEARNER_COLUMNS`, ``env`` and ``seed``): True when :func:`table` (``runs_table``) calls that run
    ``"trained"``; False when it is still learning, fell from its peak, or was not judged (a run listed several
    times, e.g. at two budgets, counts as trained only if every listing does). Other frames are unchanged.

    >>> runs_table = pd.DataFrame({"algo": ["ppo", "ppo"], "env": ["Hopper"] * 2, "seed": [0, 1],
    ...                            "verdict": ["trained", "still learning"]})
    >>> f = pd.DataFrame({"method": ["ppo"] * 3, "env": ["Hopper"] * 3, "seed": [0, 1, 2], "value": 1.0})
    >>> mark_trained({"train": f, "other": pd.DataFrame({"x": [1]})}, runs_table)["train"]["trained"].tolist()
    [True, False, False]
    """
    ok: dict[tuple[str, str, int], bool] = {}
    for _, r in runs_table.iterrows():  # a run not trained yet has no verdict: not trained
        key = (str(r["algo"]), str(r["env"]), int(r["seed"]))
        ok[key] = ok.get(key, True) and r.get("verdict") == "trained"
    out = {}
    for name, frame in frames.items():
        learner = next((c for c in LEARNER_COLUMNS if c in frame.columns), None)
        if learner is None or not {"env", "seed"} <= set(frame.columns):
            out[name] = frame
            continue
        keys = zip(frame[learner].astype(str), frame["env"].astype(str), frame["seed"].astype(int), strict=True)
        out[name] = frame.assign(trained=[ok.get(k, False) for k in keys])
    return out


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


def format_table(frame: pd.DataFrame) -> str:
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


# ---------------------------------------------------------------- seed spread
#: Episodes averaged for the training return at ``at`` env steps in :func:`spread`: the last 100 training
#: episodes finished by then (:func:`thesis_repro.figures.ch3.training_return_at`), the window openrlbenchmark
#: averages per seed for CleanRL's published table (``data/public``).
AT_WINDOW = 100
#: Columns that identify one row of :func:`spread` (the runs of one setting, one per training seed).
SPREAD_GROUP: tuple[str, ...] = ("protocol", "algorithm", "env", "setting", "timesteps")


def _flat(cfg: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in cfg.items():
        if isinstance(v, Mapping) and k != "net_arch":
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def config_protocols(cfg: Mapping[str, Any]) -> tuple[str, ...]:
    """The training protocols (:data:`~thesis_repro.learners.config.PROTOCOLS`) under which ``cfg`` is a run's
    config: those whose default config of the learner holds the same protocol settings (``lr_schedule``, ...,
    :data:`~thesis_repro.learners.config.THESIS_PROTOCOL_KEYS`); none for a config without them.

    >>> from thesis_repro.learners import train_config
    >>> [config_protocols(train_config(a, "Hopper", 0, 1000)) for a in ("ppo", "trpo")]
    [('thesis',), ('thesis',)]
    """

    def present(c: Mapping[str, Any]) -> set[str]:
        flat = _flat(c)
        return {k for k in THESIS_PROTOCOL_KEYS if k in flat}

    mine = present(cfg)
    found = []
    for protocol in PROTOCOLS:
        default = train_config(cfg["algorithm"], cfg["env"], int(cfg["seed"]), int(cfg["timesteps"]), protocol=protocol)
        if present(default) == mine:
            found.append(protocol)
    return tuple(found)


def config_setting(cfg: Mapping[str, Any], protocol: str) -> str:
    """How ``cfg`` differs from its learner's default config under ``protocol`` (seed and budget aside):
    ``"key=value"`` pairs, sorted, ``""`` for none.

    >>> from thesis_repro.learners import train_config
    >>> config_setting(train_config("ppo", "Hopper", 1, 1000, protocol="thesis", lr_schedule="constant"), "thesis")
    'lr_schedule=constant'
    """
    default = _flat(
        train_config(cfg["algorithm"], cfg["env"], int(cfg["seed"]), int(cfg["timesteps"]), protocol=protocol)
    )
    mine = _flat(cfg)
    keys = sorted(k for k in set(default) | set(mine) if k not in IDENTITY and default.get(k) != mine.get(k))
    return ", ".join(f"{k}={mine.get(k)}" for k in keys)


def shipped_cache() -> RunCache:
    """A read-only view of the shipped runs alone (``data/reference``): its local root is ``/dev/null``, so no
    local run is read and nothing can be written (a corrupt shipped entry is skipped, never removed)."""
    return RunCache(os.devnull, reference=paths.reference())


def spread_jobs(scale: str, figure_ids: Iterable[str] | None = None) -> list[Job]:
    """Every ``train`` job of the figures (all by default) at ``scale`` and (for all figures) the protocol studies'
    runs (:func:`thesis_repro.runs.study.study_jobs`), deduplicated by key."""
    jobs: dict[str, Job] = {j.key: j for j in ordered_training_jobs(scale, figure_ids)}
    if figure_ids is None:
        jobs.update((j.key, j) for j in study_jobs())
    return list(jobs.values())


def seed_runs(
    scale: str,
    protocol: str | None = None,
    at: int | None = None,
    cache: RunCache | None = None,
    figure_ids: Iterable[str] | None = None,
    algos: Iterable[str] | None = None,
) -> pd.DataFrame:
    """One row per training run of :func:`spread_jobs` that is cached or shipped (nothing is trained): the columns
    of :data:`SPREAD_GROUP` (``protocol``: those the run belongs to, :func:`config_protocols`, joined by ", ";
    ``setting``: :func:`config_setting`), ``seed``, ``key``, ``final`` (the return of the episodes that ended in
    the last 10 % of the budget, as :func:`table`'s) and with ``at`` the return ``at_return`` of the last
    :data:`AT_WINDOW` training episodes finished by ``at`` env steps (NaN if the run did not get that far).
    ``protocol`` keeps only the runs of that protocol, ``algos`` those of these learners (a ``ValueError`` names
    the valid ones)."""
    if protocol is not None:
        check_choice(protocol, PROTOCOLS, "protocol")
    keep = None if algos is None else {check_choice(a, ALGORITHMS, "algorithm") for a in algos}
    cache = cache or RunCache()
    rows = []
    for job in spread_jobs(scale, figure_ids):
        c = job.config
        if keep is not None and c["algorithm"] not in keep:
            continue
        protocols = config_protocols(c)
        if protocol is not None and protocol not in protocols:
            continue
        base = protocols[0] if protocols else PROTOCOLS[0]  # a config of no protocol: shown against the first
        result = cache.load(job)
        if result is None:
            continue
        t, r = _curve(result)
        try:
            done = int(result["timesteps_done"])
        except KeyError:
            done = int(c["timesteps"])
        reached = at is not None and done >= at and len(t) > 0
        episodes = {"episode_timesteps": t, "episode_returns": r}
        rows.append(
            {
                "protocol": ", ".join(protocols) or "none",
                "algorithm": c["algorithm"],
                "env": c["env"],
                "setting": config_setting(c, base),
                "timesteps": int(c["timesteps"]),
                "seed": int(c["seed"]),
                "key": job.key,
                "final": curve_stats(t, r, total=int(c["timesteps"]))["final"],
                "at_return": float(training_return_at(episodes, [at], AT_WINDOW)[0]) if reached else float("nan"),
            }
        )
    columns = [*SPREAD_GROUP, "seed", "key", "final", "at_return"]
    return pd.DataFrame(rows, columns=columns)


def aggregate_seeds(runs_frame: pd.DataFrame) -> pd.DataFrame:
    """Per row of :data:`SPREAD_GROUP`: the ``seeds`` (sorted tuple), ``n`` and mean and sample sd (ddof 1, NaN for
    one seed) of ``final`` and ``at_return`` across the seeds (NaN if any seed lacks the value).

    >>> f = pd.DataFrame({"protocol": "thesis", "algorithm": "ppo", "env": "Hopper", "setting": "", "timesteps": 10,
    ...                   "seed": [0, 1, 2], "final": [1.0, 2.0, 6.0], "at_return": float("nan")})
    >>> aggregate_seeds(f)[["seeds", "n", "final_mean", "final_sd"]].values.tolist()
    [[(0, 1, 2), 3, 3.0, 2.6457513110645907]]
    """
    out = []
    for group, g in runs_frame.groupby(list(SPREAD_GROUP), sort=False, dropna=False):
        seeds = sorted(int(s) for s in g["seed"])
        if len(set(seeds)) != len(seeds):
            raise ValueError(f"several runs of one seed in {dict(zip(SPREAD_GROUP, group, strict=True))}: {seeds}")
        row: dict[str, Any] = dict(zip(SPREAD_GROUP, group, strict=True))
        row.update(seeds=tuple(seeds), n=len(seeds))
        for col, name in (("final", "final"), ("at_return", "at")):
            vals = g[col].astype(float)
            row[f"{name}_mean"] = float(vals.mean(skipna=False))
            row[f"{name}_sd"] = float(vals.std(ddof=1, skipna=False)) if len(vals) > 1 else float("nan")
        out.append(row)
    columns = [*SPREAD_GROUP, "seeds", "n", "final_mean", "final_sd", "at_mean", "at_sd"]
    return pd.DataFrame(out, columns=columns)


def spread(runs: pd.DataFrame) -> pd.DataFrame:
    """Seed spread of the training return of every learner and task of the per-run frame ``runs`` of
    :func:`seed_runs` (cached or shipped runs only, nothing is trained): one row per setting
    (:data:`SPREAD_GROUP`) with the seeds found, ``n`` and mean ± sd (ddof 1) of the final training return
    (episodes ending in the last 10 % of the budget) and, where ``runs`` has it, of the return at ``at`` steps
    (:func:`aggregate_seeds`); rows sorted by protocol, learner (``hyperparams.yaml`` order), task, budget and
    setting. The lr-schedule study's runs are rows of their own (1M steps; ``setting="lr_schedule=constant"``
    for its constant arm)."""
    frame = aggregate_seeds(runs)
    envs = list(thesis_numbers.ENVS)
    order = frame.assign(
        _a=frame["algorithm"].map(lambda a: ALGORITHMS.index(a) if a in ALGORITHMS else len(ALGORITHMS)),
        _e=frame["env"].map(lambda e: envs.index(e) if e in envs else len(envs)),
    )
    order = order.sort_values(["protocol", "_a", "_e", "timesteps", "setting"], kind="stable")
    return order.drop(columns=["_a", "_e"]).reset_index(drop=True)


def steps_label(steps: float) -> str:
    """Env steps as a short label.

    >>> [steps_label(s) for s in (1_000_000, 2_000_000, 200_000, 1_500_000, 4096)]
    ['1M', '2M', '200k', '1.5M', '4,096']
    """
    if steps >= 1e6 and steps % 1e5 == 0:
        return f"{steps / 1e6:g}M"
    if steps >= 1e3 and steps % 1e3 == 0:
        return f"{steps / 1e3:g}k"
    return f"{int(steps):,}"


def _mean_sd(mean: float, sd: float, n: int) -> str:
    """``mean ± sd`` across seeds on one line (no-break spaces: a short cell of a table), ``(1 seed)`` without
    spread, ``-`` when missing."""
    if not np.isfinite(mean):
        return "-"
    if n == 1 or not np.isfinite(sd):
        text = f"{mean:,.0f} (1 seed)" if n == 1 else f"{mean:,.0f}"
    else:
        text = f"{mean:,.0f} ± {sd:,.0f}"
    return text.replace(" ", NBSP)


#: A no-break space: the short cells of the spread tables keep to one line.
NBSP = "\u00a0"


def published_cell(algorithm: str, env: str, table: pd.DataFrame, steps: Iterable[int] | None = None) -> str:
    """The published results (:func:`thesis_repro.core.thesis_numbers.published`) of learner ``algorithm`` on ``env``:
    ``mean ± std (source, env version, steps)``, ``; ``-joined, ``""`` if none. With ``steps``, only results
    published at one of those step counts (a number is set beside ours at equal steps only).

    >>> table = thesis_numbers.published()
    >>> published_cell("ppo", "Hopper", table)
    '2,383 ± 272 (CleanRL, v4, 1M)'
    >>> published_cell("sac", "Walker2d", table), published_cell("ppo-16", "Hopper", table)
    ('3,863 (rl-baselines3-zoo, v3, 1M)', '')
    >>> published_cell("ppo", "InvertedPendulum", table, steps=[200_000])
    ''
    """
    rows = table[(table["algo"] == algorithm) & (table["env"] == env)]
    if steps is not None:
        rows = rows[rows["steps"].isin([int(s) for s in steps])]
    cells = []
    for _, r in rows.iterrows():
        value = f"{r['mean']:,.0f}" + (f" ± {r['std']:,.0f}" if np.isfinite(r["std"]) else "")
        cells.append(f"{value} ({r['source']}, {r['env_version']}, {steps_label(r['steps'])})")
    return "; ".join(cells)


def render_spread(frame: pd.DataFrame, at: int | None = None, published: pd.DataFrame | None = None) -> str:
    """:func:`spread` as markdown tables: learner (with its ``[setting]``) and task in one cell (``ppo, Hopper``),
    protocol, seeds, steps, final training return mean ± sd, with ``at`` the return at ``at`` steps; then, for the
    rows with one, the published results of the same learner on the task at equal steps (:func:`published_cell`;
    ``published`` defaults to :func:`thesis_repro.core.thesis_numbers.published`) in a second table (learner and task,
    steps, published): two short tables read at a laptop's width, one wide one squeezes its columns. ``(1 seed)``
    marks a row without spread, ``-`` a missing value."""
    published = thesis_numbers.published() if published is None else published
    head = ["learner, task", "protocol", "seeds", "steps", "final return"]
    if at is not None:
        head.append(f"at {steps_label(at)}")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    beside = []
    for _, r in frame.iterrows():
        learner = r["algorithm"] + (f" [{r['setting']}]" if r["setting"] else "")
        seeds = f",{NBSP}".join(str(s) for s in r["seeds"])
        cells = [f"{learner}, {r['env']}", r["protocol"], seeds, steps_label(r["timesteps"])]
        cells.append(_mean_sd(r["final_mean"], r["final_sd"], r["n"]))
        if at is not None:
            cells.append(_mean_sd(r["at_mean"], r["at_sd"], r["n"]))
        lines.append("| " + " | ".join(cells) + " |")
        equal = [int(r["timesteps"])] + ([int(at)] if at is not None and np.isfinite(r["at_mean"]) else [])
        cell = published_cell(r["algorithm"], r["env"], published, steps=equal)
        if cell:
            beside.append(f"| {learner}, {r['env']} | {steps_label(r['timesteps'])} | {cell} |")
    if beside:
        lines += ["", "| learner, task | steps | published (source, version, steps) |", "|---|---|---|", *beside]
    return "\n".join(lines)
