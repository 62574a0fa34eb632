"""Chapter 3, Tables 3.3-3.7: the chapter's benchmark grid, tidy results, thesis-beside-reproduced tables
with the Welch bolding, and one verdict per claim of the thesis's text (§3.3); Figs 3.4-3.8 build on it
(:mod:`thesis_repro.figures.ch3_curves`).

Every item merges Fig 3.3's scale blocks (``scales.yaml``), and a learner's training config depends only on
(algorithm, task, seed, budget, overrides), so one run serves every item that uses it (the same for the
evaluation jobs: same σ grid, rollouts and testing seeds). A learner in ``skip_algos`` is one the scale
cannot afford: its cells keep the thesis's numbers and say "not run at this scale"; claims that need it are
``NOT_RUN``. Statistics live in :mod:`thesis_repro.evaluation.tables`.

Tidy frames: ``returns`` (``env, method, seed, test, sigma, rollout, return``), ``aucs`` (``env, method,
seed, test, rollout, value``: Eq 3.6 per testing rollout, so a cell is mean ± std over seeds × rollouts as the
thesis averages) and cells (``env, test, method, mean, std, n``).

>>> s = settings("table-3.4", "small")
>>> learners(s), skipped(s)
(['ppo', 'trpo'], ['ddpg', 'sac'])
>>> noisy_learners()
{'obs': 'ppo-obsnoise', 'act': 'ppo-actnoise', 'env': 'ppo-envnoise', 'dom': 'ppo-mdl'}
"""

from __future__ import annotations

import textwrap
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro import reference, report
from thesis_repro.backends import run_jobs
from thesis_repro.cache import Job, Result
from thesis_repro.envs.registry import short_name
from thesis_repro.evaluation import Benchmark, tables
from thesis_repro.evaluation.metrics import auc
from thesis_repro.figures import FIGURES, budget_note, register
from thesis_repro.figures import settings as _figure_settings
from thesis_repro.figures.ch3 import benchmark, timesteps_for
from thesis_repro.learners import hyperparams
from thesis_repro.validation import check_choice

#: Thesis CSV of each table item (``data/thesis``).
THESIS_TABLES: dict[str, str] = {
    "table-3.4": "table3_4",
    "table-3.5": "table3_5",
    "table-3.6": "table3_6",
    "table-3.7": "table3_7",
}
#: Relative gain below which a benefit is "not clear" (Table 3.3 claim iii; our reading of the text).
CLEAR_GAIN: float = 0.10
ROW = list(tables.ROW)


def settings(item: str, scale: str, **overrides: Any) -> dict[str, Any]:
    """Resolved settings of a chapter-3 item (``"table-3.4"``, ``"3.5"``, ...), checked for consistency."""
    s = _figure_settings(item, scale, **overrides)
    unknown = [a for a in s["skip_algos"] if a not in s["algos"]]
    if unknown:
        raise ValueError(f"skip_algos {unknown} of {item} are not in its algos {s['algos']}")
    return s


# ---------------------------------------------------------------- settings -> learners, tasks, overrides
def learners(settings: Mapping[str, Any]) -> list[str]:
    """The learners an item trains at its scale: ``algos`` minus ``skip_algos``."""
    return [a for a in settings["algos"] if a not in settings["skip_algos"]]


def skipped(settings: Mapping[str, Any]) -> list[str]:
    """Learners of the item that its scale cannot afford (shown as "not run at this scale")."""
    return [a for a in settings["algos"] if a in settings["skip_algos"]]


def overrides(settings: Mapping[str, Any], algo: str) -> dict[str, Any]:
    """Training overrides of ``algo``: its ``algo_overrides`` entry if any, else the item's ``train_overrides``;
    plus the scale's training ``protocol``."""
    per = settings.get("algo_overrides") or {}
    return {**dict(per[algo] if algo in per else settings["train_overrides"] or {}), "protocol": settings["protocol"]}


def item_envs(settings: Mapping[str, Any]) -> list[str]:
    """Tasks of an item: its single ``env`` (Fig 3.4, Table 3.3) or the chapter's ``envs``."""
    return [settings["env"]] if settings.get("env") else list(settings["envs"])


def noisy_learners() -> dict[str, str]:
    """Test type -> the learner trained with that perturbation at σ_tr > 0 (Table 3.5's columns, read from
    ``hyperparams.yaml``): the noisy-training partner of each test in Table 3.3."""
    out = {}
    for algo in reference.load("table3_5")["method"].unique():
        hp = hyperparams(algo)
        if hp["perturbation"] != "none" and hp["sigma"] > 0:
            out[hp["perturbation"]] = algo
    return out


def note(settings: Mapping[str, Any]) -> str:
    """The budget sentence of :func:`thesis_repro.figures.budget_note` for the item's own tasks and learners."""
    t = settings["timesteps"]
    if isinstance(t, Mapping):
        per = {e: timesteps_for(t, e) for e in item_envs(settings)}
        t = next(iter(per.values())) if len(set(per.values())) == 1 else per
    return budget_note({**settings, "timesteps": t}, n_algos=len(learners(settings)))


def describe(settings: Mapping[str, Any], width: int = 100) -> str:
    """For the notebook: this scale's budget beside the thesis's and what it does not run, wrapped at
    ``width`` characters (a book page shows printed text as is: one long line would scroll sideways)."""
    miss = skipped(settings)
    tail = f" Not run at this scale (thesis numbers shown): {', '.join(miss)}." if miss else ""
    return textwrap.fill(note(settings) + tail, width=width)


# ---------------------------------------------------------------- job grids
def benchmarks(
    settings: Mapping[str, Any], algos: Sequence[str] | None = None, envs: Sequence[str] | None = None
) -> list[Benchmark]:
    """One :func:`thesis_repro.figures.ch3.benchmark` per learner (overrides differ per learner class)."""
    algos = learners(settings) if algos is None else list(algos)
    envs = item_envs(settings) if envs is None else list(envs)
    return [
        benchmark(
            [a],
            envs,
            list(range(int(settings["train_seeds"]))),
            settings["timesteps"],
            settings["tests"],
            sigmas=settings["sigmas"],
            n_rollouts=int(settings["test_rollouts"]),
            max_episode_steps=int(settings["max_episode_steps"]),
            train_overrides=overrides(settings, a),
        )
        for a in algos
    ]


def grid(settings: Mapping[str, Any]) -> list[Job]:
    """Every job of a table/curve item: training jobs, then noise/shift evaluation jobs."""
    benches = benchmarks(settings)
    train = [j for b in benches for j in b.train_jobs]
    evals = [j for b in benches for jobs in b.eval_jobs.values() for j in jobs]
    return train + evals


for _id, _title in [
    ("table-3.3", "Improving Walker2d-PPO generalisation by training with noise"),
    ("table-3.4", "Generalisation of the basic learners (AUC), Welch-bolded"),
    ("table-3.5", "Training with noisy and multiple environments (AUC), Welch-bolded"),
    ("table-3.6", "Algorithms and architectures (AUC), Welch-bolded"),
    ("table-3.7", "Multi-domain training methods (AUC), Welch-bolded"),
]:
    register(_id, _title)(grid)


# ---------------------------------------------------------------- running and tidy results
@dataclass
class Results:
    """Tidy results of an item: per-σ ``returns``, per-rollout ``aucs`` and the last training ``episodes``."""

    returns: pd.DataFrame
    aucs: pd.DataFrame
    episodes: pd.DataFrame


def identity(cfg: Mapping[str, Any]) -> dict[str, Any]:
    """``env, method, seed`` of a training config (the identity columns of the tidy frames)."""
    return {"env": short_name(cfg["env"]), "method": cfg["algorithm"], "seed": int(cfg["seed"])}


def _episodes(cfg: Mapping[str, Any], train: Result) -> pd.DataFrame:
    """The training episodes behind a run's reported training return (last ``train_return_episodes``)."""
    rets = train.get("episode_returns")
    k = train.get("train_return_episodes")
    if rets is None or not k:
        return pd.DataFrame(columns=["env", "method", "seed", "value"])
    last = np.asarray(rets, dtype=float)[-int(k) :]
    return pd.DataFrame({**identity(cfg), "value": last})


def run(settings: Mapping[str, Any], n_jobs: int | None = None) -> Results:
    """Train (or load) every run of an item, evaluate it (cached), and return the tidy :class:`Results`."""
    benches = benchmarks(settings)
    train_jobs = [j for b in benches for j in b.train_jobs]
    trained = run_jobs(train_jobs, n_jobs=n_jobs, desc="train")
    episodes = [_episodes(j.config, t) for j, t in zip(train_jobs, trained, strict=True)]
    evals = [(b, name, j) for b in benches for name, jobs in b.eval_jobs.items() for j in jobs]
    done = run_jobs([j for _, _, j in evals], n_jobs=n_jobs, desc="evaluate")
    ret_parts, auc_parts = [], []
    for (b, name, job), res in zip(evals, done, strict=True):
        sig = np.asarray(b.tests[name]["sigmas"], dtype=float)
        r = np.asarray(res["returns"], dtype=float)  # (sigmas, rollouts)
        ident = {**identity(job.config["train"]), "test": name}
        si, ri = np.indices(r.shape).reshape(2, -1)
        ret_parts.append(pd.DataFrame({**ident, "sigma": sig[si], "rollout": ri, "return": r.reshape(-1)}))
        if len(sig) > 1:
            per_rollout = auc(r, sig, axis=0)
            auc_parts.append(pd.DataFrame({**ident, "rollout": np.arange(r.shape[1]), "value": per_rollout}))
    return Results(
        returns=pd.concat(ret_parts, ignore_index=True),
        aucs=pd.concat(auc_parts, ignore_index=True) if auc_parts else pd.DataFrame(),
        episodes=pd.concat(episodes, ignore_index=True),
    )


def seed_frames(res: Results) -> dict[str, pd.DataFrame]:
    """Per-seed numbers for the claims layer: ``aucs`` (env, test, method, seed, value), ``returns`` (env,
    method, test, sigma, seed, return) and ``train`` (env, method, seed, value: the training return), each the
    mean over testing rollouts / training episodes INSIDE the seed (the unit of replication is the seed)."""
    aucs = res.aucs.groupby(["env", "test", "method", "seed"], as_index=False, sort=False)["value"].mean()
    rets = res.returns.groupby(["env", "method", "test", "sigma", "seed"], as_index=False, sort=False)["return"].mean()
    train = res.episodes.groupby(["env", "method", "seed"], as_index=False, sort=False)["value"].mean()
    return {"aucs": aucs, "returns": rets, "train": train}


# ---------------------------------------------------------------- cells: ours and the thesis's
def our_cells(res: Results) -> pd.DataFrame:
    """AUC cells ``env, test, method, mean, std, n`` over seeds × testing rollouts."""
    return tables.cells(res.aucs)


def thesis_cells(name: str | None = None) -> pd.DataFrame:
    """The thesis's AUC cells (``n`` = :func:`~thesis_repro.evaluation.tables.thesis_n`): one table, or all of
    Tables 3.4-3.7 (PPO and PPO-MDL appear in several, with identical numbers)."""
    names = [name] if name else list(THESIS_TABLES.values())
    frames = [reference.load(check_choice(n, list(THESIS_TABLES.values()), "thesis AUC table")) for n in names]
    t = pd.concat(frames).drop_duplicates(subset=[*ROW, "method"])
    return t[[*ROW, "method", "mean", "std"]].assign(n=tables.thesis_n()).reset_index(drop=True)


def wide(cells: pd.DataFrame, value: str = "mean", index: Sequence[str] = tuple(ROW)) -> pd.DataFrame:
    """``cells`` as rows × methods (rows keep their order of appearance)."""
    idx = list(index)
    out = cells.pivot_table(index=idx, columns="method", values=value, sort=False, dropna=False)
    rows = cells[idx].drop_duplicates()
    return out.reindex(pd.MultiIndex.from_frame(rows) if len(idx) > 1 else rows[idx[0]])


def _fmt(m: float, s: float) -> str:
    if not np.isfinite(m):
        return ""
    return f"{m:.1f} ± {s:.1f}" if np.isfinite(s) else f"{m:.1f}"


@dataclass
class Comparison:
    """One AUC table, thesis beside reproduced: bolded cells of both and the agreement of the bolding."""

    item: str
    thesis: pd.DataFrame  # cells + bold (the thesis's rule on all its columns: what the thesis shows)
    ours: pd.DataFrame  # cells + bold (the rule on our samples)
    agreement: dict[str, int]  # ours vs the thesis's bolding recomputed on the same methods and rows

    def text(self) -> tuple[pd.DataFrame, pd.DataFrame]:
        """Display frame of "mean ± std" strings (rows env × test, columns method × source) and its bold mask."""
        methods = list(dict.fromkeys(self.thesis["method"]))
        th = self.thesis.set_index([*ROW, "method"])
        ours = self.ours.set_index([*ROW, "method"])
        rows = list(self.thesis[ROW].drop_duplicates().itertuples(index=False, name=None))
        cols = pd.MultiIndex.from_product([methods, ["thesis", "reproduced"]], names=["method", "source"])
        index = pd.MultiIndex.from_tuples(rows, names=ROW)
        text = pd.DataFrame("", index=index, columns=cols)
        mask = pd.DataFrame(False, index=index, columns=cols)
        for env, test in rows:
            for m in methods:
                t = th.loc[(env, test, m)]
                text.loc[(env, test), (m, "thesis")] = _fmt(t["mean"], t["std"])
                mask.loc[(env, test), (m, "thesis")] = bool(t["bold"])
                if (env, test, m) in ours.index:
                    o = ours.loc[(env, test, m)]
                    text.loc[(env, test), (m, "reproduced")] = _fmt(o["mean"], o["std"])
                    mask.loc[(env, test), (m, "reproduced")] = bool(o["bold"])
                else:
                    text.loc[(env, test), (m, "reproduced")] = report.NOT_RUN
        return text, mask

    def style(self, caption: str = "") -> Any:
        """The table as a pandas ``Styler`` (bold cells in bold; unrun cells greyed) for the notebook/book."""
        text, mask = self.text()
        css = np.where(mask.to_numpy(), "font-weight: bold", "")
        css = np.where(text.to_numpy() == report.NOT_RUN, "color: #888; font-style: italic", css)
        return (
            text.style.apply(lambda _: pd.DataFrame(css, index=text.index, columns=text.columns), axis=None)
            .set_caption(caption)
            .set_table_styles([{"selector": "td, th", "props": "padding: 2px 6px; font-size: 0.8em"}])
        )


def compare(item: str, ours: pd.DataFrame, settings: Mapping[str, Any]) -> Comparison:
    """Thesis beside reproduced AUC cells, both bolded, and the agreement of our bolding with the thesis's
    recomputed on the learners and rows we ran.

    Tables show every row and column of the thesis's table (its bolding over all its columns, as printed);
    figures show the thesis's cells of their learners (Tables 3.4-3.7) on their tasks.
    """
    check_choice(item, [i for i in FIGURES if i.startswith(("3.", "table-3."))], "chapter-3 item")
    if item in THESIS_TABLES:
        thesis = thesis_cells(THESIS_TABLES[item])
    else:
        thesis = thesis_cells()
        thesis = thesis[thesis["method"].isin(settings["algos"]) & thesis["env"].isin(item_envs(settings))]
        order = {m: i for i, m in enumerate(settings["algos"])}
        thesis = thesis.sort_values("method", key=lambda c: c.map(order), kind="stable")
        thesis = thesis.sort_values(ROW, key=lambda c: c.map(_row_order(c.name)), kind="stable")
    b_thesis = tables.bold(thesis)
    b_ours = tables.bold(ours) if not ours.empty else ours.assign(bold=False)
    same = tables.bold(thesis.merge(b_ours[[*ROW, "method"]], on=[*ROW, "method"]))
    agreement = tables.bold_agreement(b_ours, same)
    return Comparison(item, b_thesis.reset_index(drop=True), b_ours, agreement)


def _row_order(column: str) -> dict[str, int]:
    values = reference.ENVS if column == "env" else reference.TESTS
    return {v: i for i, v in enumerate(values)}


# ---------------------------------------------------------------- claims and verdicts
Stat = Callable[[pd.DataFrame], tuple[int, int]]
Rule = Callable[[int, int], tuple[bool, bool]]


def majority(k: int, n: int) -> tuple[bool, bool]:
    """Holds if more than half; partly if any.

    >>> majority(3, 5), majority(1, 4), majority(0, 4)
    ((True, True), (False, True), (False, False))
    """
    return k > n / 2, k > 0


def every(k: int, n: int) -> tuple[bool, bool]:
    """Holds if all; partly if any."""
    return k == n, k > 0


@dataclass(frozen=True)
class Claim:
    """A claim of the thesis's text as a count ``stat(wide) -> (k, n)`` over rows and a ``rule(k, n)``."""

    text: str
    needs: tuple[str, ...]
    stat: Stat
    unit: str  # what is counted: "rows with ..." (shown as "k/n rows with ...") or a template with {k}, {n}
    rule: Rule = majority

    def count(self, k: int, n: int) -> str:
        """``k/n unit``, or the ``unit`` template filled in."""
        return self.unit.format(k=k, n=n) if "{" in self.unit else f"{k}/{n} {self.unit}"

    def short(self, k: int, n: int) -> str:
        """``k/n``, or the ``unit`` template filled in."""
        return self.unit.format(k=k, n=n) if "{" in self.unit else f"{k}/{n}"


def better(a: str, b: str) -> Stat:
    """Rows where ``a``'s mean exceeds ``b``'s (rows where both were run)."""

    def stat(w: pd.DataFrame) -> tuple[int, int]:
        if a not in w or b not in w:
            return 0, 0
        ok = w[[a, b]].dropna()
        return int((ok[a] > ok[b]).sum()), int(len(ok))

    return stat


def all_better(pairs: Sequence[tuple[str, str]]) -> Stat:
    """Sum of :func:`better` over several (a, b) pairs (e.g. each noisy learner vs PPO)."""

    def stat(w: pd.DataFrame) -> tuple[int, int]:
        counts = [better(a, b)(w) for a, b in pairs]
        return sum(k for k, _ in counts), sum(n for _, n in counts)

    return stat


def best_in(methods: Sequence[str], rows: Callable[[pd.DataFrame], pd.DataFrame] | None = None) -> Stat:
    """Rows whose best mean (among the methods run) is one of ``methods``."""

    def stat(w: pd.DataFrame) -> tuple[int, int]:
        w = rows(w) if rows else w
        w = w.dropna(how="all")
        if w.empty:
            return 0, 0
        return int(w.idxmax(axis=1).isin(list(methods)).sum()), int(len(w))

    return stat


def distinct_winners(w: pd.DataFrame) -> tuple[int, int]:
    """(number of different best methods over the rows, number of rows)."""
    w = w.dropna(how="all")
    return (int(w.idxmax(axis=1).nunique()), int(len(w))) if not w.empty else (0, 0)


def two_or_more(k: int, n: int) -> tuple[bool, bool]:
    """Holds if at least two different winners (so no single consistent winner)."""
    return k >= 2, False


def often_not_always(k: int, n: int) -> tuple[bool, bool]:
    """Holds if ``k`` is at least a quarter of the rows but not all of them ("sometimes ..., often ...")."""
    return 0 < k < n and k >= n / 4, k > 0


def judge(
    item: str, claim: Claim, ours: pd.DataFrame, thesis: pd.DataFrame, settings: Mapping[str, Any], extra: str = ""
) -> report.Verdict:
    """One verdict: ``claim`` counted on our wide table and on the thesis's (same rows), status from ours."""
    not_run = [m for m in claim.needs if m in settings["skip_algos"] or m not in settings["algos"]]
    same_rows = thesis.loc[thesis.index.intersection(ours.index)] if len(ours) else thesis.iloc[:0]
    kt, nt = claim.stat(same_rows)
    ka, na = claim.stat(thesis)
    thesis_text = f"thesis: {claim.short(kt, nt)} on the rows run here ({claim.short(ka, na)} in its full table)"
    tail = f"; {extra}" if extra else ""
    if not_run:
        ev = f"{', '.join(not_run)} not run at this scale (skip_algos); {thesis_text}{tail}"
        return report.Verdict(item, claim.text, report.NOT_RUN, ev)
    k, n = claim.stat(ours)
    holds, partly = claim.rule(k, n) if n else (None, False)
    ev = f"reproduced: {claim.count(k, n)}; {thesis_text}{tail}"
    return report.Verdict(item, claim.text, report.status(holds, settings["scale"], partly), ev)


def bold_verdict(item: str, comp: Comparison, settings: Mapping[str, Any]) -> report.Verdict:
    """Agreement of our Welch bolding with the thesis's (the same rule on its numbers, n = 240)."""
    a = comp.agreement
    claim = "The best learner of each row (bold, Welch p >= alpha) is the thesis's"
    ev = (
        f"best learner the same in {a['best_same']}/{a['rows']} rows; bold/not-bold agrees in {a['same']}/"
        f"{a['cells']} cells ({a['bold_both']} bold in both; {a['bold_ours']} bold reproduced, "
        f"{a['bold_thesis']} bold thesis, on the learners run); thesis bolding derived from its mean ± std with "
        f"n = {tables.thesis_n()}, alpha = {tables.significance_level()}"
    )
    holds = None if not a["rows"] else a["best_same"] > a["rows"] / 2
    status = report.status(holds, settings["scale"], partly=a["best_same"] > 0)
    return report.Verdict(item, claim, status, ev)


def _pendulums(w: pd.DataFrame) -> pd.DataFrame:
    envs = w.index.get_level_values("env")
    return w[envs.isin(["InvertedPendulum", "InvertedDoublePendulum"])]


def _walker(w: pd.DataFrame) -> pd.DataFrame:
    return w[w.index.get_level_values("env") == "Walker2d"]


def _bold_counts(stat_methods: Sequence[str], rows: Callable | None = None) -> Stat:
    """Rows (optionally filtered) in which every one of ``stat_methods`` is bold; needs a bold wide frame."""

    def stat(w: pd.DataFrame) -> tuple[int, int]:
        w = rows(w) if rows else w
        cols = [m for m in stat_methods if m in w]
        if not cols or w.empty:
            return 0, 0
        return int(w[cols].fillna(False).astype(bool).all(axis=1).sum()), int(len(w))

    return stat


#: The claims of §3.3.2-3.3.4 behind each AUC table (ours vs the thesis's, counted the same way).
TABLE_CLAIMS: dict[str, list[Claim]] = {
    "table-3.4": [
        Claim(
            "SAC is usually the most robust basic learner on Walker2d (§3.3.2)",
            ("sac",),
            best_in(["sac"], _walker),
            "Walker2d rows with SAC best",
        ),
        Claim(
            "There is no consistent winner in robustness across environments (§3.3.2)",
            (),
            distinct_winners,
            "{k} different best learners over {n} rows",
            two_or_more,
        ),
    ],
    "table-3.5": [
        Claim(
            "Training with a noise type improves testing under the same noise type (obs, act, env; MDL for dom)",
            ("ppo", *noisy_learners().values()),
            lambda w: _matching(w),
            "rows (task × matching test) better than PPO",
        ),
        Claim(
            "Training with noisy environments improves generalisation over deterministic PPO overall (§3.3.3)",
            ("ppo", *noisy_learners().values()),
            all_better([(a, "ppo") for a in noisy_learners().values()]),
            "cells better than PPO",
        ),
        Claim(
            "MDL training improves robustness to novel domains and also to obs/act/env noise (§3.3.3)",
            ("ppo", "ppo-mdl"),
            better("ppo-mdl", "ppo"),
            "rows with PPO-MDL above PPO",
        ),
        Claim(
            "Observation-noise training improves action-noise and MDL (dom) testing in HalfCheetah (§3.3.3)",
            ("ppo", "ppo-obsnoise"),
            lambda w: better("ppo-obsnoise", "ppo")(
                w[
                    (w.index.get_level_values("env") == "HalfCheetah")
                    & w.index.get_level_values("test").isin(["act", "dom"])
                ]
            ),
            "HalfCheetah act/dom rows with PPO-ObsNoise above PPO",
            every,
        ),
    ],
    "table-3.6": [
        Claim(
            "(i) The smaller PPO-16 often surpasses PPO in generalisation, and SCN-16 surpasses SCN",
            ("ppo", "ppo-16", "ppo-scn", "ppo-scn-16"),
            all_better([("ppo-16", "ppo"), ("ppo-scn-16", "ppo-scn")]),
            "rows (PPO-16 vs PPO plus SCN-16 vs SCN) with the smaller net above",
        ),
        Claim(
            "(ii) Entropy-regularised PPO usually surpasses vanilla PPO",
            ("ppo", "ppo-ent"),
            better("ppo-ent", "ppo"),
            "rows with PPO-Ent above PPO",
        ),
        Claim(
            "(iii) PPO-ARPL sometimes improves, but often worsens vanilla PPO",
            ("ppo", "ppo-arpl"),
            better("ppo", "ppo-arpl"),
            "rows with PPO-ARPL below PPO (claim: at least a quarter, not all)",
            often_not_always,
        ),
        Claim(
            "(iv) The best performing model is either PPO-16, SCN-16 or PPO-Ent",
            ("ppo-16", "ppo-scn-16", "ppo-ent"),
            best_in(["ppo-16", "ppo-scn-16", "ppo-ent"]),
            "rows whose best learner is one of them",
        ),
    ],
    "table-3.7": [
        Claim(
            "(i) EPOpt does not generalise as well as PPO-MDL in most cases",
            ("ppo-mdl", "ppo-epopt"),
            better("ppo-mdl", "ppo-epopt"),
            "rows with PPO-EPOpt below PPO-MDL",
        ),
        Claim(
            "(ii) MAML-DG and Reptile-DG learn more generalisable policies than PPO-MDL",
            ("ppo-mdl", "ppo-maml-dg", "ppo-reptile-dg"),
            all_better([("ppo-maml-dg", "ppo-mdl"), ("ppo-reptile-dg", "ppo-mdl")]),
            "rows (MAML-DG and Reptile-DG, each vs PPO-MDL) above PPO-MDL",
        ),
    ],
}

#: Claims judged on the bolding (the wide frame holds booleans): PPO leads on the pendulums (Table 3.4).
BOLD_CLAIMS: dict[str, list[Claim]] = {
    "table-3.4": [
        Claim(
            "PPO performs better in InvertedPendulum and InvertedDoublePendulum (§3.3.2)",
            ("ppo",),
            _bold_counts(["ppo"], _pendulums),
            "pendulum rows with PPO bold (best or not significantly different)",
        )
    ]
}


def _matching(w: pd.DataFrame) -> tuple[int, int]:
    """Rows (task, test) where the learner trained with the test's own perturbation beats PPO."""
    k = n = 0
    for test, algo in noisy_learners().items():
        sub = w[w.index.get_level_values("test") == test]
        dk, dn = better(algo, "ppo")(sub)
        k, n = k + dk, n + dn
    return k, n


def table_verdicts(item: str, comp: Comparison, settings: Mapping[str, Any]) -> list[report.Verdict]:
    """Every claim of an AUC table (Tables 3.4-3.7), then the bolding agreement."""
    text = note(settings)
    ours_w, thesis_w = wide(comp.ours), wide(comp.thesis)
    out = [judge(item, c, ours_w, thesis_w, settings, text) for c in TABLE_CLAIMS.get(item, [])]
    bold_o, bold_t = wide(comp.ours, "bold"), wide(comp.thesis, "bold")
    out += [judge(item, c, bold_o, bold_t, settings, text) for c in BOLD_CLAIMS.get(item, [])]
    return [*out, bold_verdict(item, comp, settings)]


# ---------------------------------------------------------------- Table 3.3: Walker2d PPO, noisy training
def _test_sigmas() -> list[float]:
    """σ_te of Table 3.3(b) (``chapter3_settings.csv``)."""
    s = reference.load("chapter3_settings")
    return sorted(float(v) for v in s[s["parameter"] == "test_sigma"]["value"])


def table33(res: Results, settings: Mapping[str, Any]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Our Table 3.3: (a) training-return cells ``noise_type, train_sigma, mean, std, n`` and (b) testing-return
    cells ``noise_type, sigma_te, train_sigma, mean, std, n`` (seeds × rollouts), labelled like the thesis."""
    env = short_name(settings["env"])
    sig_te = _test_sigmas()
    grid = sorted(set(res.returns["sigma"]))
    missing = [s for s in sig_te if not np.isclose(grid, s).any()]
    if missing:
        raise ValueError(f"Table 3.3 tests at σ_te {sig_te}; the σ grid {grid} lacks {missing} (set sigmas)")
    a_label = dict(zip(reference.TESTS, reference.load("table3_3a")["noise_type"].iloc[1:], strict=True))
    rows_a, rows_b = [], []
    ep = res.episodes[res.episodes["env"] == env]
    det = "ppo"
    if (ep["method"] == det).any():
        m, s, n = tables.mean_std(ep[ep["method"] == det]["value"])
        rows_a.append({"noise_type": "none", "train_sigma": 0.0, "mean": m, "std": s, "n": n})
    for test, algo in noisy_learners().items():
        sub = ep[ep["method"] == algo]
        if len(sub):
            m, s, n = tables.mean_std(sub["value"])
            rows_a.append(
                {"noise_type": a_label[test], "train_sigma": hyperparams(algo)["sigma"], "mean": m, "std": s, "n": n}
            )
        for method in (det, algo):
            r = res.returns[
                (res.returns["env"] == env) & (res.returns["method"] == method) & (res.returns["test"] == test)
            ]
            for st in sig_te:
                vals = r[np.isclose(r["sigma"], st)]["return"]
                if len(vals):
                    m, s, n = tables.mean_std(vals)
                    row = {"noise_type": test, "sigma_te": st, "train_sigma": hyperparams(method)["sigma"]}
                    rows_b.append({**row, "mean": m, "std": s, "n": n})
    cols_a = ["noise_type", "train_sigma", "mean", "std", "n"]
    cols_b = ["noise_type", "sigma_te", "train_sigma", "mean", "std", "n"]
    return pd.DataFrame(rows_a, columns=cols_a), pd.DataFrame(rows_b, columns=cols_b)


def thesis33() -> tuple[pd.DataFrame, pd.DataFrame]:
    """The thesis's Table 3.3 (a, b) as cells with ``n`` = :func:`~thesis_repro.evaluation.tables.thesis_n`."""
    a = reference.load("table3_3a")[["noise_type", "train_sigma", "mean", "std"]].assign(n=tables.thesis_n())
    b = reference.load("table3_3b")[["noise_type", "sigma_te", "train_sigma", "mean", "std"]].assign(
        n=tables.thesis_n()
    )
    return a, b


def table33_text(ours: tuple[pd.DataFrame, pd.DataFrame]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Display frames of Table 3.3 (a) and (b), thesis beside reproduced ("mean ± std")."""
    out = []
    for o, t, index, cols in (
        (ours[0], thesis33()[0], ["noise_type"], ["train_sigma"]),
        (ours[1], thesis33()[1], ["noise_type", "sigma_te"], ["train_sigma"]),
    ):
        both = pd.concat([t.assign(source="thesis"), o.assign(source="reproduced")])
        both["cell"] = [_fmt(m, s) for m, s in zip(both["mean"], both["std"], strict=True)]
        w = both.pivot_table(index=index, columns=[*cols, "source"], values="cell", aggfunc="first", sort=False)
        sigmas = sorted(set(t["train_sigma"]))
        w = w.reindex(columns=pd.MultiIndex.from_product([sigmas, ["thesis", "reproduced"]], names=w.columns.names))
        for ts in sigmas:  # a cell the thesis has but we lack is "not run"; one the thesis lacks stays empty
            missing = w[(ts, "thesis")].notna() & w[(ts, "reproduced")].isna()
            w.loc[missing, (ts, "reproduced")] = report.NOT_RUN
        out.append(w.fillna(""))
    return out[0], out[1]


def _cell(frame: pd.DataFrame, **where: Any) -> tuple[float, float, int] | None:
    sel = np.ones(len(frame), dtype=bool)
    for k, v in where.items():
        sel &= np.isclose(frame[k], v) if isinstance(v, float) else (frame[k] == v).to_numpy()
    row = frame[sel]
    return None if row.empty else (float(row["mean"].iloc[0]), float(row["std"].iloc[0]), int(row["n"].iloc[0]))


def _p(a: tuple[float, float, int], b: tuple[float, float, int]) -> float:
    return tables.welch_p_from_stats(a[0], a[1], a[2], b[0], b[1], b[2])


def table33_claims(cells: tuple[pd.DataFrame, pd.DataFrame]) -> dict[str, tuple[int, int, str]]:
    """The four findings of §3.3.3 counted on one source's Table 3.3: ``claim -> (k, n, detail)``.

    (i) noisy training return below deterministic (Welch p < alpha) for every noise type but ``env``;
    (ii) obs/act: noisy training better at every σ_te > 0 (p < alpha); (iii) env/dom: gain below
    :data:`CLEAR_GAIN` at every σ_te > 0; (iv) obs/act: the fraction η(σ_max)/η(σ_min > 0) kept is higher
    with noisy training.
    """
    a, b = cells
    alpha = tables.significance_level()
    sig_hi = [s for s in _test_sigmas() if s > 0]
    noisy_sigma = max(set(b["train_sigma"]) | set(a["train_sigma"]))
    label = dict(zip(reference.TESTS, reference.load("table3_3a")["noise_type"].iloc[1:], strict=True))
    out: dict[str, tuple[int, int, str]] = {}

    hits, parts = [], []
    det = _cell(a, noise_type="none")
    for test in reference.TESTS:
        noisy = _cell(a, noise_type=label[test])
        if det and noisy:
            p = _p(noisy, det)
            hits.append((noisy[0] < det[0] and p < alpha) == (test != "env"))
            parts.append(f"{label[test]} {noisy[0]:.0f} vs {det[0]:.0f} (p={p:.2g})")
    out["i"] = (sum(hits), len(hits), "; ".join(parts))

    def gain(d: tuple[float, float, int], y: tuple[float, float, int]) -> float:
        return (y[0] - d[0]) / abs(d[0]) if d[0] else float("nan")

    for key, tests_, check in (
        ("ii", ("obs", "act"), lambda d, y: y[0] > d[0] and _p(y, d) < alpha),
        ("iii", ("env", "dom"), lambda d, y: gain(d, y) < CLEAR_GAIN),
    ):
        hits, parts = [], []
        for test in tests_:
            for st in sig_hi:
                d = _cell(b, noise_type=test, sigma_te=st, train_sigma=0.0)
                y = _cell(b, noise_type=test, sigma_te=st, train_sigma=noisy_sigma)
                if d and y:
                    hits.append(bool(check(d, y)))
                    parts.append(f"{test}@{st:g} {y[0]:.0f} vs {d[0]:.0f} ({gain(d, y):+.0%}, p={_p(y, d):.2g})")
        out[key] = (sum(hits), len(hits), "; ".join(parts))

    hits, parts = [], []
    lo, hi = sig_hi[0], sig_hi[-1]
    for test in ("obs", "act"):
        kept = {}
        for ts in (0.0, noisy_sigma):
            c_lo = _cell(b, noise_type=test, sigma_te=lo, train_sigma=ts)
            c_hi = _cell(b, noise_type=test, sigma_te=hi, train_sigma=ts)
            if c_lo and c_hi and c_lo[0]:
                kept[ts] = c_hi[0] / c_lo[0]
        if len(kept) == 2:
            hits.append(kept[noisy_sigma] > kept[0.0])
            parts.append(f"{test}: η({hi:g})/η({lo:g}) {kept[noisy_sigma]:.2f} noisy vs {kept[0.0]:.2f} deterministic")
    out["iv"] = (sum(hits), len(hits), "; ".join(parts))
    return out


#: Table 3.3's findings (§3.3.3, thesis l. 598).
TABLE33_CLAIMS: dict[str, str] = {
    "i": "(i) Training with noise lowers the training return significantly, except with environment noise",
    "ii": "(ii) For observation and action noise, training with noise improves testing under that noise",
    "iii": f"(iii) No clear benefit (gain < {CLEAR_GAIN:.0%}) under environment noise or novel domains",
    "iv": "(iv) Under stronger testing noise than trained for (σ_te 0.4), noisy training ameliorates the degradation",
}


def table33_verdicts(ours: tuple[pd.DataFrame, pd.DataFrame], settings: Mapping[str, Any]) -> list[report.Verdict]:
    """The four findings of §3.3.3 (Table 3.3), ours beside the thesis's, each needing every finding's cells."""
    mine, theirs = table33_claims(ours), table33_claims(thesis33())
    text = note(settings)
    out = []
    for key, claim in TABLE33_CLAIMS.items():
        kt, nt, dt = theirs[key]
        k, n, d = mine[key]
        if skipped(settings):
            status, ev = report.NOT_RUN, f"{', '.join(skipped(settings))} not run at this scale; thesis {kt}/{nt}: {dt}"
        else:
            holds = None if not n else k == n
            status = report.status(holds, settings["scale"], partly=k > 0)
            ev = f"reproduced {k}/{n}: {d}; thesis {kt}/{nt}: {dt}; {text}"
        out.append(report.Verdict("table-3.3", claim, status, ev))
    return out
