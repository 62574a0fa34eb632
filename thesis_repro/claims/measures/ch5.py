"""Chapter 5's measures: the arm's catch, transfer strategies, costs and curriculum (Figs 5.3-5.6, §5.4)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from thesis_repro.claims.measures.common import Data, Groups, NotRun, _needs, measure, per_seed
from thesis_repro.claims.seeds import Seeded
from thesis_repro.claims.stats import Contrast, Unit


def _succ(summary: pd.DataFrame, **where: Any) -> Seeded:
    return per_seed(summary, "success_rate", **where)


@measure("catch")
def _catch(data: Data, spec: Mapping[str, Any]) -> Groups:
    """Fig 5.3: share of CMA-ES seeds whose movement catches the ball after taut and slack phases (> 0)."""
    c = data["catch"]
    ok = Seeded((float(s and t) for s, t in zip(c["success"], c["taut_and_slack"], strict=True)), c["seed"])
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
        got = _succ(sub)
        ok = Seeded((float(x > 0) for x in got), got.seeds)
        return {"": [Unit("reach→bic", (Contrast("share of seeds succeeding", ok, proportion=True, kind="share"),))]}
    return {"": [Unit("reach→bic", (Contrast("success rate", _succ(sub)),))]}


def _cost_means(s: pd.DataFrame, strategies: Sequence[str]) -> dict[str, Seeded]:
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
