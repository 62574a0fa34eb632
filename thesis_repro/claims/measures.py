"""What each claim measures: the page's per-seed numbers turned into units of contrasts (:mod:`.stats`).

A measure is ``fn(data, spec) -> {group: [Unit, ...]}``; ``data`` maps frame names to the per-seed frames a
notebook saved (:func:`thesis_repro.claims.ledger.judge_page`), ``spec`` is the claim's registry entry.
Values are always one number per training seed (rollouts and episodes averaged inside the seed first).
A measure raises :class:`NotRun` when the scale did not train a learner the claim needs, and
:class:`Inconclusive` when the data cannot answer the claim (e.g. every kl_avg run diverged).

>>> import pandas as pd
>>> aucs = pd.DataFrame({"env": "Hopper", "test": "obs", "method": ["a"] * 3 + ["b"] * 3,
...                      "seed": [0, 1, 2] * 2, "value": [5.0, 5.2, 5.1, 1.0, 1.1, 0.9]})
>>> [u.outcome() for u in better_rows(aucs, [("a", "b")])]
['yes']
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro.claims.stats import Contrast, Unit

Data = Mapping[str, pd.DataFrame]
Groups = dict[str, list[Unit]]
Measure = Callable[[Data, Mapping[str, Any]], Groups]

#: Every measure by name (``rule.measure`` in the registry).
MEASURES: dict[str, Measure] = {}
ROW = ("env", "test")
NOISY = {"obs": "ppo-obsnoise", "act": "ppo-actnoise", "env": "ppo-envnoise", "dom": "ppo-mdl"}
PENDULUMS = ("InvertedPendulum", "InvertedDoublePendulum")


#: Measures whose one value per unit pools every training seed (a statistic of the seed means), with the frame
#: whose ``seed`` column counts them: no replication, so at most indicative however many seeds there are.
POOLED: dict[str, str] = {"mean_selection": "points"}


def pooled_seeds(name: str, frames: Mapping[str, pd.DataFrame]) -> int:
    """How many training seeds measure ``name`` pools into each unit's one value; 0 if it does not pool.

    >>> pooled_seeds("mean_selection", {"points": pd.DataFrame({"seed": [0, 0, 1, 2]})})
    3
    >>> pooled_seeds("correlation", {"points": pd.DataFrame({"seed": [0, 1]})})
    0
    """
    frame = frames.get(POOLED.get(name, ""))
    return 0 if frame is None or "seed" not in frame.columns else int(frame["seed"].nunique())


class NotRun(Exception):
    """The claim needs a learner / run this scale does not train."""


class Inconclusive(Exception):
    """The data cannot answer the claim (the reason is the message)."""


def measure(name: str) -> Callable[[Measure], Measure]:
    """Register a measure under ``name``."""

    def deco(fn: Measure) -> Measure:
        MEASURES[name] = fn
        return fn

    return deco


# ---------------------------------------------------------------- helpers
def per_seed(frame: pd.DataFrame, value: str = "value", **where: Any) -> tuple[float, ...]:
    """One value per seed (mean inside the seed) of the rows matching ``where``, by increasing seed."""
    sel = np.ones(len(frame), dtype=bool)
    for k, v in where.items():
        sel &= (frame[k].isin(v) if isinstance(v, (list, tuple)) else frame[k] == v).to_numpy()
    sub = frame[sel]
    if sub.empty:
        return ()
    return tuple(float(x) for x in sub.groupby("seed")[value].mean().sort_index())


def _needs(frame: pd.DataFrame, col: str, names: Sequence[str]) -> None:
    missing = [n for n in names if n not in set(frame[col])]
    if missing:
        raise NotRun(f"{', '.join(missing)} not run at this scale")


def rows_of(frame: pd.DataFrame, envs: Sequence[str] | None = None, tests: Sequence[str] | None = None) -> list:
    """``(env, test)`` rows of a frame in order of appearance, optionally filtered."""
    rows = list(dict.fromkeys(zip(frame["env"], frame["test"], strict=True)))
    return [(e, t) for e, t in rows if (envs is None or e in envs) and (tests is None or t in tests)]


def better_rows(
    aucs: pd.DataFrame, pairs: Sequence[tuple[str, str]], rows: Sequence[tuple[str, str]] | None = None, sign: int = 1
) -> list[Unit]:
    """One unit per row and pair ``(a, b)``: ``a``'s per-seed AUC above ``b``'s (Welch across seeds)."""
    out = []
    for env, test in rows_of(aucs) if rows is None else rows:
        for a, b in pairs:
            va = per_seed(aucs, env=env, test=test, method=a)
            vb = per_seed(aucs, env=env, test=test, method=b)
            if va and vb:
                word = ">" if sign > 0 else "<"
                out.append(Unit(f"{env}/{test}: {a} {word} {b}", (Contrast(f"{a} - {b}", va, vb, sign=sign),)))
    return out


def best_rows(aucs: pd.DataFrame, members: Sequence[str], rows: Sequence[tuple[str, str]]) -> list[Unit]:
    """Per row: some member of ``members`` above every learner outside them (each Welch across seeds)."""
    out = []
    for env, test in rows:
        here = aucs[(aucs["env"] == env) & (aucs["test"] == test)]
        methods = list(dict.fromkeys(here["method"]))
        ins = [m for m in members if m in methods]
        outs = [m for m in methods if m not in members]
        if not ins or not outs:
            continue
        groups = tuple(
            tuple(Contrast(f"{m} - {x}", per_seed(here, method=m), per_seed(here, method=x)) for x in outs) for m in ins
        )
        out.append(Unit(f"{env}/{test}: best in {{{', '.join(ins)}}}", (), groups=groups))
    return out


def degrade_units(returns: pd.DataFrame, keys: Sequence[tuple[str, str, str]], min_drop: float = 0.0) -> list[Unit]:
    """Per (env, method, test): the seed's return at the largest σ below its return at σ = 0 (paired); with
    ``min_drop`` > 0, by more than that fraction of the σ = 0 return (a relative drop, e.g. 0.25 = a quarter).

    >>> r = pd.DataFrame({"env": "H", "method": "ppo", "test": "obs", "seed": [0, 1, 2] * 2,
    ...                   "sigma": [0.0] * 3 + [0.8] * 3, "return": [100.0, 102, 98, 90, 91, 89]})
    >>> degrade_units(r, [("H", "ppo", "obs")])[0].outcome(), degrade_units(r, [("H", "ppo", "obs")], 0.25)[0].outcome()
    ('yes', 'no')
    """
    out = []
    for env, method, test in keys:
        sub = returns[(returns["env"] == env) & (returns["method"] == method) & (returns["test"] == test)]
        if sub.empty or sub["sigma"].nunique() < 2:
            continue
        lo, hi = sub["sigma"].min(), sub["sigma"].max()
        a, b = per_seed(sub, "return", sigma=hi), per_seed(sub, "return", sigma=lo)
        if min_drop > 0:
            label = f"return(σ={hi:g}) / return(σ={lo:g}) - 1 (drop beyond {min_drop:g})"
            c = Contrast(label, a, b, sign=-1, paired=True, relative=True, margin=min_drop)
        else:
            c = Contrast(f"return(σ={hi:g}) - return(σ={lo:g})", a, b, sign=-1, paired=True)
        out.append(Unit(f"{env}/{method}/{test}", (c,)))
    return out


def _keys(returns: pd.DataFrame, envs=None, methods=None, tests=None) -> list[tuple[str, str, str]]:
    k = list(dict.fromkeys(zip(returns["env"], returns["method"], returns["test"], strict=True)))
    return [
        x
        for x in k
        if (envs is None or x[0] in envs) and (methods is None or x[1] in methods) and (tests is None or x[2] in tests)
    ]


def _methods(frame: pd.DataFrame, col: str = "method") -> list[str]:
    return list(dict.fromkeys(frame[col]))


# ---------------------------------------------------------------- chapter 3: AUC tables (Tables 3.4-3.7, Figs 3.5-3.8)
@measure("better")
def _better(data: Data, spec: Mapping[str, Any]) -> Groups:
    """``pairs`` (a, b): a's AUC above b's per row (``tests``/``envs`` filter rows); ``sign`` -1: below."""
    aucs = data["aucs"]
    pairs = [tuple(p) for p in spec["pairs"]]
    _needs(aucs, "method", sorted({m for p in pairs for m in p}))
    rows = rows_of(aucs, spec.get("envs"), spec.get("tests"))
    return {"": better_rows(aucs, pairs, rows, sign=int(spec.get("sign", 1)))}


@measure("better_per_test")
def _better_per_test(data: Data, spec: Mapping[str, Any]) -> Groups:
    """One group per test type: a's AUC above b's on each task (e.g. MDL vs PPO per noise type)."""
    aucs = data["aucs"]
    a, b = spec["pairs"][0]
    _needs(aucs, "method", [a, b])
    return {t: better_rows(aucs, [(a, b)], rows_of(aucs, tests=[t])) for t in spec["tests"]}


@measure("groups_better")
def _groups_better(data: Data, spec: Mapping[str, Any]) -> Groups:
    """One group per pair (a, b): rows with a's AUC above b's (``sign`` -1: below)."""
    aucs = data["aucs"]
    out: Groups = {}
    for a, b in spec["pairs"]:
        _needs(aucs, "method", [a, b])
        out[f"{a} vs {b}"] = better_rows(aucs, [(a, b)], rows_of(aucs), sign=int(spec.get("sign", 1)))
    return out


@measure("matching_noise")
def _matching(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Each noisy learner vs PPO on every row (Fig 3.5: positive bars)."""
    aucs = data["aucs"]
    _needs(aucs, "method", ["ppo", *NOISY.values()])
    return {"": better_rows(aucs, [(m, "ppo") for m in NOISY.values()])}


@measure("arpl")
def _arpl(data: Data, spec: Mapping[str, Any]) -> Groups:
    """(iii) ARPL sometimes above PPO and often below it: two groups of rows."""
    aucs = data["aucs"]
    _needs(aucs, "method", ["ppo", "ppo-arpl"])
    return {
        "sometimes improves": better_rows(aucs, [("ppo-arpl", "ppo")]),
        "often worsens": better_rows(aucs, [("ppo", "ppo-arpl")]),
    }


@measure("best_in")
def _best_in(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Rows (``envs`` filter) whose best learner is one of ``members`` (significantly above every other)."""
    aucs = data["aucs"]
    _needs(aucs, "method", spec.get("needs", spec["members"]))
    return {"": best_rows(aucs, spec["members"], rows_of(aucs, spec.get("envs"), spec.get("tests")))}


@measure("reversals")
def _reversals(data: Data, spec: Mapping[str, Any]) -> Groups:
    """No consistent winner: per learner pair, a task where A beats B and another where B beats A (task AUC =
    the seed's mean over tests)."""
    aucs = data["aucs"]
    per = aucs.groupby(["env", "method", "seed"], as_index=False)["value"].mean()
    envs = list(dict.fromkeys(per["env"]))
    methods = [m for m in _methods(per) if m in spec.get("methods", _methods(per))]
    if len(envs) < 2 or len(methods) < 2:
        raise Inconclusive("needs two tasks and two learners")
    units = []
    for a, b in itertools.combinations(methods, 2):
        groups = []
        for t1, t2 in itertools.permutations(envs, 2):
            c1 = Contrast(f"{t1}: {a} - {b}", per_seed(per, env=t1, method=a), per_seed(per, env=t1, method=b))
            c2 = Contrast(f"{t2}: {b} - {a}", per_seed(per, env=t2, method=b), per_seed(per, env=t2, method=a))
            groups.append((c1, c2))
        units.append(Unit(f"{a} vs {b}: reversal across tasks", (), groups=tuple(groups)))
    return {"": units}


@measure("no_winner")
def _no_winner(data: Data, spec: Mapping[str, Any]) -> Groups:
    """No consistent winner across all environments: per learner, some task where another learner's task AUC
    (the seed's mean over tests) is above it (Welch across seeds); a learner is a consistent winner when no
    other learner beats it anywhere.

    >>> aucs = pd.DataFrame({"env": ["A"] * 6 + ["B"] * 6, "test": "obs", "method": (["a"] * 3 + ["b"] * 3) * 2,
    ...                      "seed": [0, 1, 2] * 4, "value": [5, 5.1, 4.9, 1, 1.1, 0.9, 1, 1.1, 0.9, 5, 5.1, 4.9]})
    >>> [u.outcome() for u in _no_winner({"aucs": aucs}, {})[""]]
    ['yes', 'yes']
    """
    aucs = data["aucs"]
    per = aucs.groupby(["env", "method", "seed"], as_index=False)["value"].mean()
    envs = list(dict.fromkeys(per["env"]))
    methods = [m for m in _methods(per) if m in spec.get("methods", _methods(per))]
    if len(envs) < 2 or len(methods) < 2:
        raise Inconclusive("needs two tasks and two learners")
    units = []
    for m in methods:
        parts = tuple(
            Contrast(f"{t}: {o} - {m}", per_seed(per, env=t, method=o), per_seed(per, env=t, method=m))
            for t in envs
            for o in methods
            if o != m
        )
        units.append(Unit(f"{m} beaten on some task", parts, combine="any"))
    return {"": units}


# ---------------------------------------------------------------- chapter 3: curves and heat maps
@measure("degrade")
def _degrade(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Return at the largest σ below σ = 0, per (task, learner, test) curve; ``by_method``: a group each."""
    ret = data["returns"]
    keys = _keys(ret, spec.get("envs"), spec.get("methods"), spec.get("tests"))
    if spec.get("by_method"):
        run = _methods(ret)
        missing = [m for m in spec["by_method"] if m not in run]
        drop = float(spec.get("min_drop", 0.0))
        out = {m: degrade_units(ret, [k for k in keys if k[1] == m], drop) for m in spec["by_method"] if m in run}
        if missing and out:
            out["(not run: " + ", ".join(missing) + ")"] = []
        if not out:
            raise NotRun(f"{', '.join(missing)} not run at this scale")
        return out
    return {"": degrade_units(ret, keys, float(spec.get("min_drop", 0.0)))}


@measure("obs_most_sensitive")
def _obs(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Per learner: min(act, env) AUC above the obs AUC, paired within the seed."""
    aucs = data["aucs"]
    units = []
    for env in dict.fromkeys(aucs["env"]):
        for m in _methods(aucs[aucs["env"] == env]):
            sub = aucs[(aucs["env"] == env) & (aucs["method"] == m)]
            w = sub.pivot_table(index="seed", columns="test", values="value")
            if not {"obs", "act", "env"} <= set(w.columns):
                continue
            a = tuple(np.minimum(w["act"], w["env"]).astype(float))
            units.append(Unit(f"{env}/{m}", (Contrast("min(act, env) - obs AUC", a, tuple(w["obs"]), paired=True),)))
    return {"": units}


@measure("heat")
def _heat(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Heat maps per learner: ``ring`` (centre above the outer ring) or ``axes`` (row-factor drop above the
    column-factor drop), paired within the seed."""
    heat = data["heat"]
    units = []
    for m in _methods(heat):
        h = heat[heat["method"] == m]
        d = max(h["row_shift"].abs().max(), h["col_shift"].abs().max())
        rows = []
        for _, g in h.groupby("seed"):
            c = g.groupby(["row_shift", "col_shift"])["return"].mean()
            centre = c.get((0.0, 0.0), np.nan)
            ring = c[[i for i in c.index if max(abs(i[0]), abs(i[1])) == d]].mean()
            row = c[[i for i in c.index if i[1] == 0.0 and abs(i[0]) == d]].mean()
            col = c[[i for i in c.index if i[0] == 0.0 and abs(i[1]) == d]].mean()
            rows.append((centre, ring, centre - row, centre - col))
        r = np.array(rows, dtype=float)
        if spec["kind"] == "ring":
            c = Contrast("centre - outer ring", tuple(r[:, 0]), tuple(r[:, 1]), paired=True)
        else:
            c = Contrast("row-factor drop - column-factor drop", tuple(r[:, 2]), tuple(r[:, 3]), paired=True)
        units.append(Unit(m, (c,)))
    return {"": units}


# ---------------------------------------------------------------- chapter 3: Figs 3.2, 3.3 and Table 3.3
@measure("overfit")
def _overfit(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 3.2 per seed: early / middle / late quarters of the snapshots (windows fixed by position, no peak
    picking): AUC and training return rise early -> middle; AUC falls middle -> late while the training
    return does not fall by more than 5 %."""
    cur = data["curve"]
    vals: dict[str, list[list[float]]] = {k: [] for k in ("ae", "am", "al", "te", "tm", "tl")}
    for _, g in cur.sort_values("iteration").groupby("seed"):
        g = g.dropna(subset=["train_return", "test_auc"])
        n = len(g)
        if n < 4:
            continue
        q = max(1, n // 4)
        mid = slice(max(0, n // 2 - q // 2), max(0, n // 2 - q // 2) + q)
        for tag, col in (("a", "test_auc"), ("t", "train_return")):
            v = g[col].to_numpy(float)
            vals[tag + "e"].append(float(v[:q].mean()))
            vals[tag + "m"].append(float(v[mid].mean()))
            vals[tag + "l"].append(float(v[-q:].mean()))
    if not vals["ae"]:
        raise Inconclusive("fewer than 4 usable snapshots per seed")
    t = {k: tuple(v) for k, v in vals.items()}
    return {
        "in tandem at first": [
            Unit("AUC rises early -> middle", (Contrast("AUC middle - early", t["am"], t["ae"], paired=True),)),
            Unit("return rises early -> middle", (Contrast("return middle - early", t["tm"], t["te"], paired=True),)),
        ],
        "then overfitting": [
            Unit("AUC falls middle -> late", (Contrast("AUC late - middle", t["al"], t["am"], sign=-1, paired=True),)),
            Unit(
                "return keeps (>= -5 %)",
                (Contrast("return late / middle - 1", t["tl"], t["tm"], paired=True, relative=True, margin=-0.05),),
            ),
        ],
    }


def _corr_per_seed(points: pd.DataFrame, env: str, test: str) -> tuple[float, ...]:
    out = []
    for _, g in points[(points["env"] == env) & (points["test"] == test)].groupby("seed"):
        g = g.dropna(subset=["train_return", "auc"])
        if len(g) >= 3 and g["train_return"].std() > 0 and g["auc"].std() > 0:
            out.append(float(np.corrcoef(g["train_return"], g["auc"])[0, 1]))
    return tuple(out)


def _cells(points: pd.DataFrame) -> list[tuple[str, str]]:
    return list(dict.fromkeys(zip(points["env"], points["test"], strict=True)))


@measure("correlation")
def _correlation(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Per (task, test) cell (``panels`` only, if given): the seed's Pearson r of testing AUC vs training return
    across variants below 0 (t-interval across seeds)."""
    points = data["points"]
    cells = [tuple(p) for p in spec["panels"]] if spec.get("panels") else _cells(points)
    units = []
    for env, test in cells:
        r = _corr_per_seed(points, env, test)
        if r:
            units.append(Unit(f"{env}/{test}", (Contrast("r across variants", r, sign=-1, kind="r"),)))
    return {"": units}


@measure("mean_selection")
def _mean_selection(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Per cell: r of the seed-MEAN training return vs seed-mean AUC across variants below 0 (one number per
    cell from all seeds: no replication, so at most indicative). With one training seed the seed mean IS that seed,
    the same number as the per-seed claim judges, so the claim cannot be told apart: inconclusive."""
    points = data["points"]
    if "seed" in points.columns and points["seed"].nunique() < 2:
        raise Inconclusive(
            "one training seed: the average across seeds is that seed's own numbers (judged by the per-seed claim)"
        )
    units = []
    for env, test in _cells(points):
        g = points[(points["env"] == env) & (points["test"] == test)].groupby("algo")[["train_return", "auc"]].mean()
        g = g.dropna()
        if len(g) >= 3 and g["train_return"].std() > 0 and g["auc"].std() > 0:
            r = float(np.corrcoef(g["train_return"], g["auc"])[0, 1])
            units.append(Unit(f"{env}/{test}", (Contrast("r of seed means", (r,), sign=-1, kind="r"),)))
    return {"": units}


@measure("least_robust")
def _least_robust(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Per cell and seed: AUC percentile (0 lowest, 1 highest) of the variant with the best training return;
    the claim: below the median 0.5 (t-interval across seeds)."""
    points = data["points"]
    units = []
    for env, test in _cells(points):
        pct = []
        for _, g in points[(points["env"] == env) & (points["test"] == test)].groupby("seed"):
            g = g.dropna(subset=["train_return", "auc"])
            if len(g) >= 3:
                top = g["train_return"].idxmax()
                pct.append(float((g["auc"] < g.loc[top, "auc"]).sum() / (len(g) - 1)))
        if pct:
            units.append(
                Unit(
                    f"{env}/{test}",
                    (
                        Contrast(
                            "AUC percentile of the top-training variant - 0.5",
                            tuple(pct),
                            sign=-1,
                            ref=0.5,
                            kind="share",
                        ),
                    ),
                )
            )
    return {"": units}


def _t33_test(ret: pd.DataFrame, test: str, method: str, sigma: float) -> tuple[float, ...]:
    sub = ret[(ret["test"] == test) & (ret["method"] == method) & np.isclose(ret["sigma"], sigma)]
    return per_seed(sub, "return")


@measure("table33")
def _table33(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Table 3.3 (Walker2d PPO vs noise-trained), per seed: ``i`` training return, ``ii``/``iii`` testing
    return at σ_te > 0, ``iv`` the fraction return(0.4) / return(0.2) kept."""
    part = spec["part"]
    ret, train = data["returns"], data["train"]
    _needs(ret, "method", ["ppo", *NOISY.values()])
    sig = [s for s in spec.get("sigma_te", [0.2, 0.4])]
    units = []
    if part == "i":
        det = per_seed(train, method="ppo")
        for test, algo in NOISY.items():
            noisy = per_seed(train, method=algo)
            if test == "env":  # not significantly lower: at most 10 % below deterministic (non-inferiority)
                c = Contrast("noisy / deterministic - 1", noisy, det, relative=True, margin=-0.10)
            else:
                c = Contrast("noisy - deterministic training return", noisy, det, sign=-1)
            units.append(Unit(f"{test} ({algo})", (c,)))
    elif part in ("ii", "iii"):
        for test in ("obs", "act") if part == "ii" else ("env", "dom"):
            for s in sig:
                y, d = _t33_test(ret, test, NOISY[test], s), _t33_test(ret, test, "ppo", s)
                if part == "ii":
                    c = Contrast("noisy - deterministic", y, d)
                else:  # no clear benefit: relative gain below +10 %
                    c = Contrast("gain (noisy / deterministic - 1)", y, d, sign=-1, relative=True, margin=-0.10)
                units.append(Unit(f"{test}@σ_te={s:g}", (c,)))
    else:
        lo, hi = min(sig), max(sig)
        for test in ("obs", "act"):
            kept = {}
            for m in (NOISY[test], "ppo"):
                a, b = np.array(_t33_test(ret, test, m, hi)), np.array(_t33_test(ret, test, m, lo))
                kept[m] = tuple(a / np.where(b > 0, b, np.nan)) if a.size and a.size == b.size else ()
            units.append(
                Unit(
                    test,
                    (Contrast(f"kept η({hi:g})/η({lo:g}): noisy - deterministic", kept[NOISY[test]], kept["ppo"]),),
                )
            )
    return {"": units}


# ---------------------------------------------------------------- chapter 4
BASELINES = ("params_avg", "joint")


def _vs_baselines(
    frame: pd.DataFrame,
    value: str,
    ours: str,
    label: str,
    margin: float = 0.0,
    relative: bool = False,
    sign: int = 1,
    **where: Any,
) -> Unit:
    """``ours`` above each baseline present (Welch across seeds); non-inferiority with a negative margin.

    Each contrast's label names the quantity compared (:func:`quantity_label`)."""
    base = [b for b in BASELINES if b in set(frame["algo"])]
    a = per_seed(frame, value, algo=ours, **where)
    parts = tuple(
        Contrast(
            quantity_label(value, ours, b, relative),
            a,
            per_seed(frame, value, algo=b, **where),
            sign=sign,
            margin=margin,
            relative=relative,
        )
        for b in base
    )
    return Unit(label, parts)


#: How a contrast label names each per-seed quantity that :func:`_vs_baselines` compares.
QUANTITIES = {
    "return": "",  # the default quantity: no prefix
    "retained": "retained fraction",
    "spread": "spread over conditions",
    "entropy": "entropy",
}


def quantity_label(value: str, ours: str, base: str, relative: bool = False) -> str:
    """The label of ``ours`` against ``base`` on quantity ``value``, saying what the number is (a return
    difference, the default, has no prefix; a relative one says so).

    >>> quantity_label("retained", "kl_avg", "joint")
    'retained fraction: kl_avg - joint'
    >>> quantity_label("return", "kl_exact", "params_avg", relative=True)
    '(kl_exact - params_avg) / |params_avg|'
    """
    diff = f"({ours} - {base}) / |{base}|" if relative else f"{ours} - {base}"
    name = QUANTITIES.get(value, value)
    return f"{name}: {diff}" if name else diff


def _late(curves: pd.DataFrame) -> pd.DataFrame:
    """Per (algo, panel, seed): mean training return over the last third of the iterations."""
    n_it = int(curves["iteration"].max())
    late = curves[curves["iteration"] > n_it - max(1, n_it // 3)]
    return late.groupby(["algo", "panel", "seed"], as_index=False)["return"].mean()


def _retained(frame: pd.DataFrame, nominal: Callable[[pd.DataFrame], pd.Series], by: Sequence[str]) -> pd.DataFrame:
    """Per (by..., algo, panel, seed): mean return off the nominal point / return at it (own nominal)."""
    rows = []
    for key, g in frame.groupby([*by, "algo", "panel", "seed"]):
        at = nominal(g)
        nom = float(g.loc[at, "return"].mean()) if at.any() else float("nan")
        off = float(g.loc[~at, "return"].mean()) if (~at).any() else float("nan")
        key = key if isinstance(key, tuple) else (key,)
        rows.append(
            {
                **dict(zip([*by, "algo", "panel", "seed"], key, strict=True)),
                "retained": off / nom if nom > 0 else float("nan"),
            }
        )
    return pd.DataFrame(rows)


def learned_only(retained: pd.DataFrame, curves: pd.DataFrame | None, ours: str | None = None) -> pd.DataFrame:
    """``retained`` with the value of every run that diverged in training (:func:`diverged`, Fig 4.7's rule)
    set to NaN, so its unit is *undecided*: what a diverged policy keeps of its own near-zero nominal return
    says nothing about generalisation. Without ``curves``: ``retained`` as is. With ``ours``: inconclusive
    when no run of ``ours`` is left to judge.

    >>> r = pd.DataFrame({"algo": ["a", "b"], "panel": "p", "seed": 0, "retained": [0.9, 0.5]})
    >>> c = pd.DataFrame({"algo": ["a"] * 9 + ["b"] * 9, "panel": "p", "seed": 0, "iteration": [*range(9)] * 2,
    ...                   "return": [100.0, 500] + [1000] * 7 + [900] * 3 + [-5] * 6, "entropy": 1.0})
    >>> learned_only(r, c, "a")["retained"].tolist()
    [0.9, nan]
    """
    if curves is None:
        return retained
    keys = ["algo", "panel", "seed"]
    div = diverged(curves)
    bad = {tuple(k) for k in div.loc[div["diverged"], keys].astype(str).itertuples(index=False)}
    hit = [tuple(k) in bad for k in retained[keys].astype(str).itertuples(index=False)]
    out = retained.copy()
    out.loc[hit, "retained"] = float("nan")
    mine = out["algo"] == ours
    if ours is not None and mine.any() and out.loc[mine, "retained"].isna().all():
        n = len(out.loc[mine, ["panel", "seed"]].drop_duplicates())
        raise Inconclusive(
            f"every {ours} run ({n}) diverged in training (late return below half its peak) or has no positive "
            "nominal return: how much of it a policy keeps off its nominal point is not judged"
        )
    return out


def wind_retained(wind: pd.DataFrame) -> pd.DataFrame:
    """Fig 4.3/4.4a: mean return over the winds other than ξ = 0, over the return at ξ = 0."""
    return _retained(wind, lambda g: np.isclose(g["value"], 0.0), [])


def heat_retained(heat: pd.DataFrame) -> pd.DataFrame:
    """Figs 4.4b/4.5: off-centre mean return over the centre's (mass = friction = 1)."""
    return _retained(heat, lambda g: np.isclose(g["mass"], 1.0) & np.isclose(g["friction"], 1.0), [])


def noise_retained(noise: pd.DataFrame) -> pd.DataFrame:
    """Fig 4.6: mean return at σ > 0 over the return at σ = 0, per noise type."""
    return _retained(noise, lambda g: np.isclose(g["value"], 0.0), ["noise"])


def _panel_groups(frame: pd.DataFrame, value: str, ours: str, easy: Sequence[str], tol: float) -> Groups:
    out: Groups = {"easy: similar": [], "harder: better": []}
    for p in sorted(set(frame["panel"])):
        if p in easy:
            out["easy: similar"].append(_vs_baselines(frame, value, ours, f"panel {p}", -tol, True, panel=p))
        else:
            out["harder: better"].append(_vs_baselines(frame, value, ours, f"panel {p}", panel=p))
    return {k: v for k, v in out.items() if v}


def _ours(frame: pd.DataFrame, spec: Mapping[str, Any]) -> str:
    ours = spec.get("ours", "kl_avg")
    if ours not in set(frame["algo"]):
        raise NotRun(f"{ours} not run at this scale")
    return ours


@measure("ch4_training")
def _ch4_training(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 4.1: late training return, similar (>= -10 %) in the easy panel (a), above the baselines in the others."""
    late = _late(data["curves"])
    return _panel_groups(late, "return", _ours(late, spec), spec.get("easy", ["a"]), 0.10)


@measure("ch4_insensitive")
def _ch4_insensitive(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 4.1: spread of the late return over the training conditions ((max - min) / |mean|, per seed index)
    below each baseline's."""
    late = _late(data["curves"])
    ours = _ours(late, spec)
    if late["panel"].nunique() < 2:
        raise Inconclusive("needs two training conditions or more")
    spread = late.groupby(["algo", "seed"])["return"].agg(lambda r: (r.max() - r.min()) / max(abs(r.mean()), 1e-9))
    spread = spread.rename("spread").reset_index()
    return {"": [_vs_baselines(spread, "spread", ours, "spread over conditions", sign=-1)]}


@measure("ch4_wind")
def _ch4_wind(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 4.3: wind degradation relative to the policy's own ξ = 0 return; similar in panel a, better elsewhere."""
    r = wind_retained(data["wind"])
    ours = _ours(r, spec)
    r = learned_only(r, data.get("curves"), ours)
    return _panel_groups(r, "retained", ours, spec.get("easy", ["a"]), 0.10)


@measure("ch4_hopper")
def _ch4_hopper(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 4.4: retained return under unseen winds (a) and mass x friction (b) above each baseline."""
    w, h = wind_retained(data["wind"]), heat_retained(data["heat"])
    ours = _ours(w, spec)
    w, h = learned_only(w, data.get("curves"), ours), learned_only(h, data.get("curves"), ours)
    return {
        "": [_vs_baselines(w, "retained", ours, "(a) wind"), _vs_baselines(h, "retained", ours, "(b) mass x friction")]
    }


@measure("ch4_heat")
def _ch4_heat(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 4.5: per condition, the off-centre return relative to the centre above each baseline's."""
    h = heat_retained(data["heat"])
    ours = _ours(h, spec)
    h = learned_only(h, data.get("curves"), ours)
    return {"": [_vs_baselines(h, "retained", ours, f"panel {p}", panel=p) for p in sorted(set(h["panel"]))]}


@measure("ch4_noise")
def _ch4_noise(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 4.6: per noise type and condition, return at σ > 0 relative to σ = 0 above each baseline's."""
    r = noise_retained(data["noise"])
    ours = _ours(r, spec)
    r = learned_only(r, data.get("curves"), ours)
    keys = sorted(set(zip(r["noise"], r["panel"], strict=True)))
    return {"": [_vs_baselines(r, "retained", ours, f"{k} panel {p}", noise=k, panel=p) for k, p in keys]}


def diverged(curves: pd.DataFrame, fraction: float = 0.5) -> pd.DataFrame:
    """Per (algo, panel, seed): did the run diverge (late return below ``fraction`` of its own peak, smoothed
    over 5 iterations, or a non-finite return / entropy)?"""
    rows = []
    for (algo, panel, seed), g in curves.sort_values("iteration").groupby(["algo", "panel", "seed"]):
        r = g["return"].rolling(5, min_periods=1).mean().to_numpy(float)
        bad = not np.isfinite(g["entropy"]).all() or not np.isfinite(r).all()
        n = len(r)
        late = float(np.mean(r[-max(1, n // 3) :])) if n else float("nan")
        peak = float(np.nanmax(r)) if n else float("nan")
        bad = bad or (peak > 0 and late < fraction * peak)
        rows.append({"algo": algo, "panel": panel, "seed": seed, "diverged": bool(bad)})
    return pd.DataFrame(rows)


@measure("ch4_entropy")
def _ch4_entropy(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 4.7: final policy entropy above each baseline's, over runs that did not diverge only."""
    cur = data["curves"]
    ours = _ours(cur, spec)
    div = diverged(cur)
    ok = div[~div["diverged"]][["algo", "panel", "seed"]]
    final = cur[cur["iteration"] == cur["iteration"].max()].merge(ok, on=["algo", "panel", "seed"])
    if ours not in set(final["algo"]):
        n = int(div[div["algo"] == ours]["diverged"].sum())
        raise Inconclusive(f"all {n} {ours} run(s) diverged (late return below half its peak): not judged")
    return {"": [_vs_baselines(final, "entropy", ours, "final entropy (non-diverged runs)")]}


@measure("contribution4")
def _contribution4(data: Data, spec: Mapping[str, Any]) -> Groups:
    """§6 contribution 4: on Walker (Figs 4.1, 4.3) and Hopper (Fig 4.4), training return and retained testing
    return of kl_avg above each baseline (Walker: per seed, mean over the training conditions)."""
    units = []
    ours = spec.get("ours", "kl_avg")
    for task, cur_key, wind_key in (
        ("Walker2d", "curves@fig-4.1", "wind@fig-4.3"),
        ("Hopper", "curves@fig-4.4", "wind@fig-4.4"),
    ):
        curves = data.get(cur_key)
        if curves is not None:
            late = _late(curves).groupby(["algo", "seed"], as_index=False)["return"].mean()
            if ours in set(late["algo"]):
                units.append(_vs_baselines(late, "return", ours, f"{task}: training return"))
        if wind_key in data:
            w = learned_only(wind_retained(data[wind_key]), curves)  # a diverged run: NaN, so is its seed's mean
            w = w.groupby(["algo", "seed"], as_index=False)["retained"].agg(lambda v: float(np.mean(v.to_numpy())))
            if ours in set(w["algo"]):
                units.append(_vs_baselines(w, "retained", ours, f"{task}: retained return under unseen winds"))
    if not units:
        raise NotRun(f"{ours} runs of Figs 4.1/4.3/4.4 not in this build")
    return {"": units}


# ---------------------------------------------------------------- chapter 5
def _succ(summary: pd.DataFrame, **where: Any) -> tuple[float, ...]:
    return per_seed(summary, "success_rate", **where)


@measure("catch")
def _catch(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 5.3: share of CMA-ES seeds whose movement catches the ball after taut and slack phases (> 0)."""
    c = data["catch"]
    ok = tuple(float(s and t) for s, t in zip(c["success"], c["taut_and_slack"], strict=True))
    return {"": [Unit("seeds catching", (Contrast("share of seeds", ok, proportion=True, kind="share"),))]}


@measure("scratch")
def _scratch(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 5.4 (i): scratch's success rate (per seed, over sources and targets) above 0 on Reach and Throw,
    below 0.5 on BIC and Cast."""
    s = data["summary"]
    _needs(s, "strategy", ["scratch"])
    sc = s[s["strategy"] == "scratch"]
    out: Groups = {"feasible (Reach, Throw)": [], "mostly fails (BIC, Cast)": []}
    for fam in ("reach", "throw"):
        if fam in set(sc["target"]):
            out["feasible (Reach, Throw)"].append(
                Unit(fam, (Contrast("success rate", _succ(sc, target=fam), kind="share"),))
            )
    for fam in ("bic", "cast"):
        if fam in set(sc["target"]):
            out["mostly fails (BIC, Cast)"].append(
                Unit(fam, (Contrast("success rate - 0.5", _succ(sc, target=fam), sign=-1, ref=0.5, kind="share"),))
            )
    return {k: v for k, v in out.items() if v}


@measure("reach_bic")
def _reach_bic(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 5.4: tensor transfer Reach -> BIC reaches a success rate above 0."""
    s = data["summary"]
    sub = s[(s["strategy"] == "tensor") & (s["source"] == "reach") & (s["target"] == "bic")]
    if sub.empty:
        raise NotRun("the Reach -> BIC tensor pair is not run at this scale")
    if spec.get("proportion"):  # v2: the share of seeds with any success, Clopper-Pearson (as Fig 5.3's)
        ok = tuple(float(x > 0) for x in _succ(sub))
        return {"": [Unit("reach→bic", (Contrast("share of seeds succeeding", ok, proportion=True, kind="share"),))]}
    return {"": [Unit("reach→bic", (Contrast("success rate", _succ(sub)),))]}


def _cost_means(s: pd.DataFrame, strategies: Sequence[str]) -> dict[str, tuple[float, ...]]:
    return {m: per_seed(s, "total_cost", strategy=m) for m in strategies}


@measure("order")
def _order(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 5.4 (ii): total cost (per seed, mean over pairs) tensor < matrix < direct."""
    s = data["summary"]
    _needs(s, "strategy", ["tensor", "matrix", "direct"])
    c = _cost_means(s, ["tensor", "matrix", "direct"])
    return {
        "": [
            Unit("tensor < matrix", (Contrast("tensor - matrix", c["tensor"], c["matrix"], sign=-1),)),
            Unit("matrix < direct", (Contrast("matrix - direct", c["matrix"], c["direct"], sign=-1),)),
        ]
    }


@measure("tensor_solves")
def _tensor_solves(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 5.4 (iii): per (source, target) pair, tensor's success rate above 0.5."""
    s = data["summary"]
    _needs(s, "strategy", ["tensor"])
    t = s[s["strategy"] == "tensor"]
    return {
        "": [
            Unit(p, (Contrast("success rate - 0.5", _succ(t, pair=p), ref=0.5, kind="share"),))
            for p in dict.fromkeys(t["pair"])
        ]
    }


@measure("competitors")
def _competitors(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 5.5 (b): tensor's total cost below each competitor's on average (per seed, mean over pairs) and per pair."""
    s = data["summary"]
    comp = [m for m in spec["competitors"] if m in set(s["strategy"])]
    _needs(s, "strategy", ["tensor", *spec["competitors"]])
    c = _cost_means(s, ["tensor", *comp])
    avg = [Unit(f"tensor < {m} (average)", (Contrast(f"tensor - {m}", c["tensor"], c[m], sign=-1),)) for m in comp]
    pairs = []
    for p in dict.fromkeys(s["pair"]):
        t = per_seed(s, "total_cost", strategy="tensor", pair=p)
        parts = tuple(
            Contrast(f"tensor - {m}", t, per_seed(s, "total_cost", strategy=m, pair=p), sign=-1) for m in comp
        )
        pairs.append(Unit(p, parts))
    return {"on average": avg, "most pairs": pairs}


def _convergence(cost: np.ndarray, tol: float = 0.1) -> float:
    """First trial index whose cost is within ``tol`` of the range above the final cost (last 5 points)."""
    final = float(np.mean(cost[-5:]))
    span = float(np.max(cost) - np.min(cost)) or 1.0
    hit = np.nonzero(cost <= final + tol * span)[0]
    return float(hit[0]) if hit.size else float(len(cost))


@measure("cast_bic")
def _cast_bic(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 5.5 (a), Cast -> BIC per seed: cost of the first 5 points, trials to converge, cost of the last 5:
    tensor below each competitor."""
    cur = data["curves"]
    src = "cast" if "cast" in set(cur["source"]) else sorted(set(cur["source"]))[0]
    tgt = "bic" if "bic" in set(cur["target"]) else sorted(set(cur["target"]))[-1]
    d = cur[(cur["source"] == src) & (cur["target"] == tgt)]
    comp = [m for m in spec["competitors"] if m in set(d["strategy"])]
    _needs(d, "strategy", ["tensor", *spec["competitors"]])
    rows = []
    for (m, seed), g in d.sort_values("trials").groupby(["strategy", "seed"]):
        c = g["cost"].to_numpy(float)
        rows.append(
            {"strategy": m, "seed": seed, "start": c[:5].mean(), "converge": _convergence(c), "end": c[-5:].mean()}
        )
    r = pd.DataFrame(rows)
    out: Groups = {}
    for key, name in (("start", "starts better"), ("converge", "converges quicker"), ("end", "better asymptote")):
        t = per_seed(r, key, strategy="tensor")
        out[name] = [
            Unit(
                f"{src}→{tgt}", tuple(Contrast(f"tensor - {m}", t, per_seed(r, key, strategy=m), sign=-1) for m in comp)
            )
        ]
    return out


@measure("curriculum")
def _curriculum(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 5.6: the curriculum's final BIC success rate above 0.5 (solved) and above no curriculum's."""
    f = data["final"]
    cl, nc = per_seed(f, "final_success", condition="CL"), per_seed(f, "final_success", condition="NC")
    return {
        "solved": [Unit("CL success > 0.5", (Contrast("CL success - 0.5", cl, ref=0.5, kind="share"),))],
        "better than NC": [Unit("CL > NC", (Contrast("CL - NC success", cl, nc, kind="share"),))],
    }


@measure("transfer_gain")
def _transfer_gain(data: Data, spec: Mapping[str, Any]) -> Groups:
    """§5.4: tensor transfer vs scratch, per seed over all pairs: total cost lower (speed), success higher."""
    s = data["summary"]
    _needs(s, "strategy", ["tensor", "scratch"])
    c = _cost_means(s, ["tensor", "scratch"])
    sr = {m: per_seed(s, "success_rate", strategy=m) for m in ("tensor", "scratch")}
    return {
        "": [
            Unit("speed: total cost", (Contrast("tensor - scratch", c["tensor"], c["scratch"], sign=-1),)),
            Unit("asymptotic success", (Contrast("tensor - scratch", sr["tensor"], sr["scratch"], kind="share"),)),
        ]
    }
