"""Chapter 4's measures: the multi-domain learner against its baselines (Figs 4.1, 4.3-4.7, contribution 4),
with the retained-return and divergence helpers the pages share."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro.claims.measures.common import Data, Groups, Inconclusive, NotRun, measure, per_seed
from thesis_repro.claims.stats import Contrast, Unit

BASELINES = ("params_avg", "joint")

#: The one wording of a learner whose every run diverged, for every chapter-4 claim (design v3).
DIVERGED = "diverged, not judged"


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
            f"{DIVERGED}: every {ours} run ({n}) diverged in training (late return below half its peak) or has no "
            "positive nominal return: how much of it a policy keeps off its nominal point is not judged"
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


def learned_curves(curves: pd.DataFrame, ours: str) -> pd.DataFrame:
    """``curves`` without the runs that diverged in training (:func:`diverged`, Fig 4.7's rule), for every learner:
    a claim reads no diverged run (design v3's ``drop_diverged``). Inconclusive, worded :data:`DIVERGED`, when no
    run of ``ours`` is left.

    >>> c = pd.DataFrame({"algo": ["a"] * 9 + ["b"] * 9, "panel": "p", "seed": 0, "iteration": [*range(9)] * 2,
    ...                   "return": [100.0, 500] + [1000] * 7 + [900] * 3 + [-5] * 6, "entropy": 1.0})
    >>> sorted(set(learned_curves(c, "a")["algo"]))
    ['a']
    """
    div = diverged(curves)
    ok = div.loc[~div["diverged"], ["algo", "panel", "seed"]]
    out = curves.merge(ok, on=["algo", "panel", "seed"])
    if ours not in set(out["algo"]):
        n = int(div[div["algo"] == ours]["diverged"].sum())
        raise Inconclusive(f"{DIVERGED}: all {n} {ours} run(s) diverged in training (late return below half its peak)")
    return out


def _curves(data: Data, spec: Mapping[str, Any]) -> pd.DataFrame:
    """Fig 4.1's curves, without diverged runs when the rule says ``drop_diverged``."""
    cur = data["curves"]
    return learned_curves(cur, spec.get("ours", "kl_avg")) if spec.get("drop_diverged") else cur


@measure("ch4_training")
def _ch4_training(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 4.1: late training return, similar (>= -10 %) in the easy panel (a), above the baselines in the others."""
    late = _late(_curves(data, spec))
    return _panel_groups(late, "return", _ours(late, spec), spec.get("easy", ["a"]), 0.10)


@measure("ch4_insensitive")
def _ch4_insensitive(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 4.1: spread of the late return over the training conditions ((max - min) / |mean|, per seed index)
    below each baseline's."""
    late = _late(_curves(data, spec))
    ours = _ours(late, spec)
    if late["panel"].nunique() < 2:
        raise Inconclusive("needs two training conditions or more")
    if spec.get("drop_diverged"):  # a spread over conditions needs every condition's run of that seed
        full = late.groupby(["algo", "seed"])["panel"].transform("nunique") == late["panel"].nunique()
        late = late[full]
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
        raise Inconclusive(f"{DIVERGED}: all {n} {ours} run(s) diverged in training (late return below half its peak)")
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
        if curves is not None and spec.get("drop_diverged"):
            curves = learned_curves(curves, ours)
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
