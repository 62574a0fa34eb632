"""Your agent under the thesis's protocol: beside the shipped learners, and single runs in rl-baselines3-zoo's shape.

* :func:`compare_with_shipped`: a :func:`~thesis_repro.evaluation.score.score_model` result beside every learner
  the kit ships (or has cached) on the same task, scale, σ grid and testing seeds: a table of AUCs with 95 % CIs
  across training seeds, and a Fig 3.4-style figure (testing return vs σ per test type, CI bands).
  :meth:`Comparison.versus` tests your agent against one learner, paired by testing rollout.
* :func:`train_run`: one chapter-3 training run (learner, task, seed, scale) through the run cache, the same
  job the book trains or loads (``python -m thesis_repro train ppo Hopper --seed 0 --scale small``), or one of
  your budget (``timesteps``); :func:`train_cost` prices it and :func:`showing_progress` shows its progress.
* :func:`thesis_repro.book.clips.enjoy` (its own module, with the book's clips): one episode of a shipped or cached
  policy, optionally perturbed, rendered offscreen to a video.
* :func:`load_sb3`: an SB3 ``.zip`` as a model (``python -m thesis_repro score model.zip --task Hopper``).

:data:`README_EXAMPLE` is the README's five lines (``tests/test_agent.py`` runs them as written).
"""

from __future__ import annotations

import contextlib
import zipfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro.core.cache import Job, Result, RunCache
from thesis_repro.core.validation import check_choice
from thesis_repro.envs import ENVS, TESTS, short_name
from thesis_repro.evaluation import tables
from thesis_repro.evaluation.score import Scores, book_grid, score_model

#: Your agent beside the shipped learners in five lines (the README's "use it on your own agent").
README_EXAMPLE = """\
from stable_baselines3 import PPO
from thesis_repro.book.agent import compare_with_shipped, score_model
model = PPO("MlpPolicy", "InvertedPendulum-v5", seed=0).learn(2048)
scores = score_model(model, "InvertedPendulum", scale="small")  # the book's σ grid, rollouts and testing seeds
print(scores, compare_with_shipped(scores), sep="\\n\\n")  # AUCs with 95 % CIs beside every shipped learner
"""

#: The chapter-3 items whose learners the comparison and the single-run commands draw on (first match wins).
ITEMS: tuple[str, ...] = ("table-3.4", "table-3.5", "table-3.6", "table-3.7", "3.3")


def _item_settings(item: str, scale: str) -> dict[str, Any]:
    from thesis_repro.figures import ch3_tables

    return ch3_tables.checked_settings(item, scale)


def _learners(task: str, scale: str) -> dict[str, dict[str, Any]]:
    """Learner -> the settings of the first chapter-3 item that runs it on ``task`` at ``scale``."""
    from thesis_repro.figures import ch3_tables

    out: dict[str, dict[str, Any]] = {}
    for item in ITEMS:
        s = _item_settings(item, scale)
        if task not in ch3_tables.item_envs(s):
            continue
        for a in ch3_tables.learners(s):
            out.setdefault(a, s)
    return out


def learner_names(task: str, scale: str = "small") -> list[str]:
    """The chapter-3 learners the book runs on ``task`` at ``scale`` (those :func:`compare_with_shipped` can draw).

    >>> learner_names("Hopper")[:4]
    ['ppo', 'trpo', 'ddpg', 'sac']
    """
    return list(_learners(match_task(task), scale))


def _benchmark(
    settings: dict[str, Any], algo: str, task: str, seeds: Sequence[int], timesteps: int | None = None
) -> Any:
    from thesis_repro.figures import ch3, ch3_tables

    return ch3.benchmark(
        [algo],
        [task],
        list(seeds),
        ch3.learner_timesteps(settings, algo) if timesteps is None else int(timesteps),
        settings["tests"],
        sigmas=settings["sigmas"],
        n_rollouts=int(settings["test_rollouts"]),
        max_episode_steps=int(settings["max_episode_steps"]),
        train_overrides=ch3_tables.overrides(settings, algo),
    )


#: The "Score your own agent" guide's stand-in agent per scale: SB3 PPO's training steps and the PPO settings
#: (seconds at ``smoke``; about a minute per seed at ``small``, where the learners beside it are shipped).
GUIDE_PPO: dict[str, dict[str, Any]] = {
    "smoke": {"timesteps": 256, "ppo": {"n_steps": 64, "batch_size": 32}},
    "small": {"timesteps": 20480, "ppo": {}},
    "full": {"timesteps": 20480, "ppo": {}},
}


def guide_settings(scale: str, task: str = "InvertedPendulum", timesteps: int | None = None) -> dict[str, Any]:
    """The settings of the guide page ``notebooks/guide-score-agent.py`` at ``scale``: the task's gymnasium id,
    the stand-in PPO's ``timesteps`` (``None``: :data:`GUIDE_PPO`'s) and ``ppo`` keyword arguments, and whether
    the learners beside it are computed when neither shipped nor cached (``compute_missing``: only at ``smoke``,
    seconds; at ``small`` they are the shipped runs), with a one-line ``note``.

    >>> g = guide_settings("smoke")
    >>> g["gym_id"], g["timesteps"], g["compute_missing"]
    ('InvertedPendulum-v5', 256, True)
    """
    from thesis_repro.core import scales

    scales.check_scale(scale)
    task = short_name(task)
    base = GUIDE_PPO[scale]
    steps = base["timesteps"] if timesteps is None else int(timesteps)
    if steps < 1:
        raise ValueError(f"timesteps must be an integer >= 1 or None, got {timesteps!r}")
    compute = scale == "smoke"
    beside = "trained now if not cached (smoke: seconds)" if compute else "the shipped (or cached) runs, none trained"
    return {
        "task": task,
        "gym_id": ENVS[task],
        "timesteps": steps,
        "ppo": dict(base["ppo"]),
        "compute_missing": compute,
        "note": f"scale {scale}: your agent = SB3 PPO, {steps:,} steps per seed on {task}; the learners beside it: "
        f"{beside}",
    }


# ---------------------------------------------------------------- comparison with the shipped learners
#: The thesis's plain learners (Table 3.4): drawn in colour beside your agent, with the best of the others.
PLAIN: tuple[str, ...] = ("ppo", "trpo", "ddpg", "sac")


@dataclass
class Comparison:
    """Your agent beside the shipped learners: ``table`` (one row per test and learner: ``env, test, method,
    seed_mean, ci_lo, ci_hi, n_seeds``, the AUC across training seeds), the tidy ``returns`` behind it, what the
    intervals are (``ci_label``) and a Fig 3.4-style ``figure``; ``str()`` / :meth:`wide` give the table as text,
    with each learner's training budget (``budgets``: env steps per run); :meth:`versus` tests your agent against
    one learner. ``aucs`` holds the per-rollout AUCs behind ``table``."""

    table: pd.DataFrame
    returns: pd.DataFrame
    ci_label: str
    scores: Scores
    title: str
    aucs: pd.DataFrame | None = None
    budgets: dict[str, int | None] = field(default_factory=dict)

    @property
    def learners(self) -> list[str]:
        """The shipped learners beside your agent, in the table's order."""
        return [m for m in dict.fromkeys(self.table["method"]) if m != self.scores.label]

    def best_other(self) -> str | None:
        """The learner outside :data:`PLAIN` with the highest AUC averaged over the tests (``None``: no such one)."""
        others = self.table[self.table["method"].isin([m for m in self.learners if m not in PLAIN])]
        return None if others.empty else str(others.groupby("method")["seed_mean"].mean().idxmax())

    @cached_property
    def figure(self) -> Any:
        """The Fig 3.4-style figure (drawn on first access): testing return vs σ per test type, your agent in black,
        the plain learners (:data:`PLAIN`) and the best of the others in colour, the rest faded; line: mean over
        training seeds, band: the 95 % t-interval across seeds."""
        best = self.best_other()
        highlight = [m for m in self.learners if m in PLAIN or m == best]
        return _figure(self.returns, self.scores, self.title, highlight, self.budgets)

    def wide(self) -> pd.DataFrame:
        """AUC mean [95 % CI] (seeds) per learner (rows) and test (columns), as text, and each learner's training
        budget (``train steps``) where known."""
        t = self.table.assign(
            text=[tables.fmt_ci(r.seed_mean, r.ci_lo, r.ci_hi, r.n_seeds) for r in self.table.itertuples()]
        )
        out = t.pivot(index="method", columns="test", values="text").reindex(
            index=list(dict.fromkeys(self.table["method"])), columns=list(dict.fromkeys(self.table["test"]))
        )
        if self.budgets:
            out["train steps"] = [_steps(self.budgets.get(m)) for m in out.index]
        return out

    def versus(self, learner: str) -> pd.DataFrame:
        """Your agent against ``learner``, per test: each side's AUC averaged over its training seeds, paired by
        testing rollout (both are scored on the same σ grid and episode seeds, so rollout i meets the same
        perturbations), the mean difference (yours minus theirs) with its 95 % t-interval over the rollouts, and
        Welch's p across training seeds (NaN below two seeds a side). The interval holds the testing noise; the
        p-value the spread of training."""
        check_choice(learner, self.learners, "learner")
        if self.aucs is None:
            raise ValueError("this comparison has no per-rollout AUCs (made by compare_with_shipped)")
        rows = []
        for test in dict.fromkeys(self.table["test"]):
            side = {}
            for who in (self.scores.label, learner):
                a = self.aucs[(self.aucs["method"] == who) & (self.aucs["test"] == test)]
                side[who] = a
            mine = side[self.scores.label].groupby("rollout")["value"].mean()
            theirs = side[learner].groupby("rollout")["value"].mean()
            diff = (mine - theirs).dropna()
            if diff.empty:
                continue
            m, lo, hi, n = tables.t_interval(diff.to_numpy())
            p = tables.welch_p(*(side[w].groupby("seed")["value"].mean().to_numpy() for w in side))
            rows.append(
                {
                    "test": test,
                    "yours": float(mine.mean()),
                    learner: float(theirs.mean()),
                    "difference": m,
                    "ci_lo": lo,
                    "ci_hi": hi,
                    "rollouts": n,
                    "welch_p": p,
                }
            )
        return pd.DataFrame(rows)

    def versus_text(self, learner: str) -> str:
        """:meth:`versus` as text: one line per test."""
        lines = [f"{self.scores.label} minus {learner}, testing AUC paired by rollout (95 % CI over rollouts):"]
        for r in self.versus(learner).to_dict("records"):
            ci = f"[{r['ci_lo']:+.1f}, {r['ci_hi']:+.1f}]" if np.isfinite(r["ci_lo"]) else "(no interval)"
            p = f"; Welch p across training seeds {r['welch_p']:.3f}" if np.isfinite(r["welch_p"]) else ""
            lines.append(
                f"  {r['test']:4s} {r['yours']:8.1f} vs {r[learner]:8.1f}: {r['difference']:+.1f} {ci}"
                f" over {r['rollouts']} rollouts{p}"
            )
        return "\n".join(lines)

    def __str__(self) -> str:
        return f"testing AUC, {self.ci_label}\n{self.wide().to_string()}"


def _steps(n: int | None) -> str:
    """Env steps as a short count: ``2M``, ``300k``, ``512``; ``?`` when unknown.

    >>> _steps(2_000_000), _steps(300_000), _steps(512), _steps(None)
    ('2M', '300k', '512', '?')
    """
    if n is None:
        return "?"
    if n >= 1_000_000:
        return f"{n / 1e6:.3g}M"
    return f"{n / 1e3:.3g}k" if n >= 1000 else str(n)


def shipped_results(
    task: str, scale: str = "small", cache: RunCache | None = None, *, compute_missing: bool = False
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The shipped (or locally cached) evaluations of every chapter-3 learner on ``task`` at ``scale``: tidy
    ``returns`` (``env, method, seed, test, sigma, rollout, return``) and per-rollout ``aucs`` (``env, method,
    seed, test, rollout, value``). Nothing is trained or evaluated (a learner without evaluations is left out)
    unless ``compute_missing``: then the missing runs are trained and evaluated through the run cache, the
    book's own jobs (seconds at ``smoke``; never at ``small``, whose runs are shipped)."""
    from thesis_repro.evaluation.metrics import auc

    task = short_name(task)
    cache = cache or RunCache()
    ret_parts, auc_parts = [], []
    for algo, s in _learners(task, scale).items():
        bench = _benchmark(s, algo, task, range(int(s["train_seeds"])))
        for test, jobs in bench.eval_jobs.items():
            sig = np.asarray(bench.tests[test]["sigmas"], dtype=float)
            for seed, job in zip(bench.seeds, jobs, strict=True):
                res = cache.run(job) if compute_missing else cache.load(job)
                if res is None:
                    continue
                r = np.asarray(res["returns"], dtype=float)  # (sigmas, rollouts)
                ident = {"env": task, "method": algo, "seed": seed, "test": test}
                si, ri = np.indices(r.shape).reshape(2, -1)
                ret_parts.append(pd.DataFrame({**ident, "sigma": sig[si], "rollout": ri, "return": r.reshape(-1)}))
                per = auc(r, sig, axis=0)
                auc_parts.append(pd.DataFrame({**ident, "rollout": np.arange(r.shape[1]), "value": per}))
    if not ret_parts:
        from thesis_repro.core import paths

        if (note := paths.reference_note()) is not None:
            raise ValueError(note)
        raise ValueError(
            f"no shipped or cached chapter-3 evaluations of {task} at scale {scale!r} (the kit ships scale 'small'; "
            f"score with scale='small', or run the book at {scale!r} first)"
        )
    return pd.concat(ret_parts, ignore_index=True), pd.concat(auc_parts, ignore_index=True)


def compare_with_shipped(
    scores: Scores,
    task: str | None = None,
    *,
    cache: RunCache | None = None,
    title: str | None = None,
    compute_missing: bool = False,
    timesteps: int | None = None,
) -> Comparison:
    """Your agent's :class:`~thesis_repro.evaluation.score.Scores` beside every learner shipped on ``task``
    (default: the scores' task) at the scores' scale, with 95 % CIs across training seeds, and a Fig 3.4-style
    figure. The scores must use that scale's book grid (``score_model(..., scale=...)`` without overrides), so
    that every number comes from the same σ grid, rollouts and testing seeds. ``compute_missing`` trains and
    evaluates the learners neither shipped nor cached first (:func:`shipped_results`; for ``smoke``).
    ``timesteps``: your agent's training steps, shown beside the shipped learners' budgets.

    >>> cmp = compare_with_shipped(score_model(model, "Hopper", "small"))  # doctest: +SKIP
    >>> print(cmp); cmp.figure.savefig("hopper.png")  # doctest: +SKIP
    """
    if not isinstance(scores, Scores):
        raise ValueError(f"scores must be what score_model returns (a Scores), got {type(scores).__name__}")
    task = scores.task if task is None else short_name(task)
    if task != scores.task:
        raise ValueError(f"the scores are on task {scores.task!r}, not {task!r}")
    if scores.scale is None:
        raise ValueError("the scores have no scale (scale=None): score with scale='small' to compare with the book")
    grid = book_grid(scores.scale)
    if list(scores.sigmas) != grid["sigmas"] or scores.n_rollouts != grid["n_rollouts"] or scores.seed != 0:
        raise ValueError(
            f"the scores use σ {list(scores.sigmas)}, {scores.n_rollouts} rollouts, testing seed {scores.seed}; the "
            f"book at scale {scores.scale!r} uses σ {grid['sigmas']}, {grid['n_rollouts']} rollouts, seed 0: score "
            "with score_model(..., scale=...) and no grid overrides"
        )
    rets, aucs = shipped_results(task, scores.scale, cache, compute_missing=compute_missing)
    if scores.label in set(rets["method"]):
        raise ValueError(f"label {scores.label!r} is a shipped learner's name; score with another label=")
    keep = rets["test"].isin(scores.tests)
    rets = pd.concat([scores.returns_frame(), rets[keep]], ignore_index=True)
    aucs = pd.concat([scores.aucs(), aucs[aucs["test"].isin(scores.tests)]], ignore_index=True)
    table = tables.seed_ci(aucs)
    label = tables.ci_label(table["n_seeds"])
    title = title or f"{scores.label} beside the shipped learners on {task}"
    budgets: dict[str, int | None] = {scores.label: timesteps}
    for algo, s in _learners(task, scores.scale).items():
        if algo in set(table["method"]):  # the budget of the runs compared: their training job's env steps
            budgets[algo] = int(_benchmark(s, algo, task, [0]).train_jobs[0].config["timesteps"])
    return Comparison(table=table, returns=rets, ci_label=label, scores=scores, title=title, aucs=aucs, budgets=budgets)


def _figure(
    rets: pd.DataFrame,
    scores: Scores,
    title: str,
    highlight: Sequence[str] | None = None,
    budgets: dict[str, int | None] | None = None,
) -> Any:
    """Fig 3.4's top row for this task: testing return vs σ, one panel per test type, a line per learner (the
    mean over training seeds of each seed's mean over its rollouts) with its 95 % t-interval band across seeds;
    your agent in black, on top; the learners of ``highlight`` (default: all) in colour, the others faded grey;
    each name in the legend with its training budget in env steps where ``budgets`` has it."""
    import matplotlib.pyplot as plt
    import seaborn as sns

    per_seed = tables.seed_means(rets, "return", ["env", "method", "test", "sigma"])
    order = list(dict.fromkeys(rets["method"]))
    others = order[1:]
    shown = [m for m in others if highlight is None or m in highlight]
    faded = [m for m in others if m not in shown]
    palette = dict(zip(shown, sns.color_palette("tab10", len(shown)), strict=True))
    palette.update({m: (0.6, 0.6, 0.6) for m in faded})
    palette[scores.label] = (0.0, 0.0, 0.0)
    tests = scores.tests

    def named(method: str) -> str:
        steps = (budgets or {}).get(method)
        return method if steps is None else f"{method} ({_steps(steps)} steps)"

    fig, axes = plt.subplots(1, len(tests), figsize=(3.2 * len(tests) + 2.0, 3.6), squeeze=False, sharey=True)
    for j, test in enumerate(tests):
        ax = axes[0, j]
        d = per_seed[per_seed["test"] == test]
        for method in [*faded, *shown, scores.label]:
            m = d[d["method"] == method]
            mine, dim = method == scores.label, method in faded
            sns.lineplot(
                m,
                x="sigma",
                y="return",
                errorbar=None if dim else tables.t_errorbar,
                color=palette[method],
                alpha=0.35 if dim else 1.0,
                linewidth=2.4 if mine else (0.7 if dim else 1.2),
                marker=None if dim else "o",
                markersize=4 if mine else 2.5,
                label=(f"others ({len(faded)}, faded)" if method == faded[0] else "_") if dim else named(method),
                ax=ax,
                zorder=3 if mine else (1 if dim else 2),
            )
        ax.set_title(f"{scores.task} — {test}", fontsize=9)
        ax.set(xlabel="σ (Σ for dom)", ylabel="testing return" if j == 0 else "")
        if ax.get_legend() is not None:
            ax.get_legend().remove()
    handles, labels = axes[0, 0].get_legend_handles_labels()
    keep = [(h, lab) for h, lab in zip(handles, labels, strict=True) if not lab.startswith("_")]
    dims = [k for k in keep if k[1].startswith("others (")]
    keep = keep[-1:] + [k for k in keep[:-1] if k not in dims] + dims  # your agent, the highlighted, the faded
    fig.legend(*zip(*keep, strict=True), loc="center left", bbox_to_anchor=(0.87, 0.5), fontsize=7, frameon=False)
    n = per_seed.groupby(["method", "test", "sigma"])["seed"].nunique()
    band = f"band: {tables.ci_label(n)}" if n.max() > 1 else "no band: 1 training seed"
    fig.suptitle(f"{title} (scale {scores.scale})\nline: mean over training seeds; {band}", fontsize=9)
    fig.tight_layout(rect=(0, 0, 0.87, 1))
    return fig


# ---------------------------------------------------------------- single runs
def match_task(task: str) -> str:
    """The short name of ``task`` matched case-insensitively (a short name or a Gymnasium id); a one-line
    ``ValueError`` with the closest name ("did you mean") and the valid ones otherwise.

    >>> match_task("hopper"), match_task("walker2d-v5")
    ('Hopper', 'Walker2d')
    >>> match_task("Hoper")
    Traceback (most recent call last):
    ...
    ValueError: unknown env 'Hoper'; did you mean 'Hopper'? valid envs are: 'InvertedPendulum', \
'InvertedDoublePendulum', 'Walker2d', 'Hopper', 'HalfCheetah'
    """
    import difflib

    names = {**{k.lower(): k for k in ENVS}, **{v.lower(): k for k, v in ENVS.items()}}
    if isinstance(task, str) and task.lower() in names:
        return names[task.lower()]
    close = difflib.get_close_matches(str(task).lower(), names, n=1)
    hint = f"; did you mean {names[close[0]]!r}?" if close else ";"
    listed = ", ".join(repr(k) for k in ENVS)
    raise ValueError(f"unknown env {task!r}{hint} valid envs are: {listed}")


def training_job(algo: str, task: str, seed: int = 0, scale: str = "small", timesteps: int | None = None) -> Job:
    """The chapter-3 training job of ``algo`` on ``task`` with training seed ``seed`` at ``scale``: the one the
    book trains or loads (same config, same cache key), or with ``timesteps`` env steps instead of the book's
    budget (another run, cached under its own key). ``task`` and ``algo`` match case-insensitively; a
    ``ValueError`` names the valid learners of the task."""
    from thesis_repro.core import scales

    scales.check_scale(scale)
    task = match_task(task)
    algo = algo.lower() if isinstance(algo, str) else algo
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if timesteps is not None and (isinstance(timesteps, bool) or not isinstance(timesteps, int) or timesteps < 1):
        raise ValueError(f"timesteps must be an integer >= 1 or None, got {timesteps!r}")
    learners = _learners(task, scale)
    check_choice(algo, list(learners), "learner")
    return _benchmark(learners[algo], algo, task, [int(seed)], timesteps).train_jobs[0]


def train_cost(job: Job) -> tuple[int, float]:
    """The env steps of training ``job`` and its expected wall time in seconds on one core, at the pace of the
    kit's benchmarks (``make bench``) or its documented defaults."""
    from thesis_repro.runs import throughput

    steps = throughput.work(job)
    rate = throughput.job_rate(job, throughput.load_rates())
    return int(steps), steps / rate if rate else float("nan")


def train_run(
    algo: str,
    task: str,
    seed: int = 0,
    scale: str = "small",
    cache: RunCache | None = None,
    timesteps: int | None = None,
) -> Result:
    """Train (or load, when shipped or cached) one chapter-3 run through the run cache; returns its entry."""
    job = training_job(algo, task, seed, scale, timesteps)
    return (cache or RunCache()).run(job)


@contextlib.contextmanager
def showing_progress(label: str) -> Iterator[None]:
    """While inside, every training run of this process shows a progress line with an ETA on stderr
    (:data:`thesis_repro.learners.train.OBSERVERS`); a run loaded from the cache shows none."""
    from stable_baselines3.common.callbacks import BaseCallback

    from thesis_repro.core.terminal import Progress
    from thesis_repro.learners import train as learner_train

    bars: list[Progress] = []

    class Watch(BaseCallback):
        def __init__(self, total: int):
            super().__init__()
            self.bar = Progress(label, total, "env steps")
            bars.append(self.bar)

        def _on_step(self) -> bool:
            self.bar.update(self.num_timesteps)
            return True

    learner_train.OBSERVERS.append(Watch)
    try:
        yield
    finally:
        learner_train.OBSERVERS.remove(Watch)
        for bar in bars:
            bar.close()


# ---------------------------------------------------------------- SB3 zips
#: SB3 algorithm classes tried, in order, on a zip without ``--algo``.
SB3_ALGOS: tuple[str, ...] = ("ppo", "sac", "td3", "ddpg", "a2c", "trpo", "tqc")


def _sb3_class(name: str) -> Any:
    import sb3_contrib
    import stable_baselines3

    check_choice(name, SB3_ALGOS, "SB3 algorithm")
    return getattr(stable_baselines3, name.upper(), None) or getattr(sb3_contrib, name.upper())


def load_sb3(path: str | Path, algo: str | None = None) -> Any:
    """An SB3 model from a ``.zip`` saved with ``model.save`` (``algo``: its class, e.g. ``"ppo"``; default: the
    first of :data:`SB3_ALGOS` that loads it). A missing or unreadable file is a one-line ``ValueError``."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"no such model file: {str(path)!r} (an SB3 .zip saved with model.save)")
    if not zipfile.is_zipfile(p):
        raise ValueError(f"{str(path)!r} is not an SB3 model .zip (saved with model.save)")
    names = [algo] if algo is not None else list(SB3_ALGOS)
    errors = []
    for name in names:
        cls = _sb3_class(name)
        try:
            return cls.load(str(p), device="cpu")
        except Exception as err:  # noqa: BLE001 - the wrong class fails in many ways; try the next
            errors.append(f"{name}: {type(err).__name__}")
    raise ValueError(f"cannot load {str(path)!r} as an SB3 model ({'; '.join(errors)})")


def tasks() -> list[str]:
    """The five tasks (for the command line's choices)."""
    return list(ENVS)


__all__ = [
    "ITEMS",
    "README_EXAMPLE",
    "SB3_ALGOS",
    "TESTS",
    "Comparison",
    "compare_with_shipped",
    "guide_settings",
    "learner_names",
    "load_sb3",
    "match_task",
    "score_model",
    "shipped_results",
    "showing_progress",
    "tasks",
    "train_cost",
    "training_job",
    "train_run",
]
